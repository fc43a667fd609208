"""Lightmaps on the artist's meshes (issue 14): every input mesh gets a lightmap UV set of its own,
written as primvars:st1 (faceVarying, authored corner order) on the ORIGINAL prim in the output
layer, with its page and Unity-order scaleOffset; the input file is never touched.

Everything here is read back from the outputs (solution.usda composed over the input, the page
EXRs, the manifest) and checked against the bake's own final gather evaluated at 3D points that
the test finds itself from st1: a texel's value must be the light at the surface point the
artist's mesh puts at that texel.

The scene: a room-sized floor of two quads whose texture set `st` maps both quads onto the same
square (overlapping: never usable as lightmap UVs), a box with a pentagon face (fans of n-gons),
a left-handed mesh (reversed corner order), a wall carrying its own `st1` (kept as authored), and
an emitter overhead."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("xatlas")
from hirad_e2e_helpers import add_crate_instancer, add_crate_mesh, add_material, add_pentagon_box, add_mesh, new_stage, write_config  # noqa: E402
from pxr import Sdf, Usd, UsdGeom  # noqa: E402

from hirad.bake import bake  # noqa: E402
from hirad.outputs.lightmap_render import _bilinear  # noqa: E402  (the engines' bilinear read, v up)

TPM = 24.0


def _tex2():
    return Sdf.ValueTypeNames.TexCoord2fArray


def build_scene(path: Path) -> Path:
    stage = new_stage(path)
    grey = add_material(stage, "/World/Looks/grey", (0.6, 0.6, 0.6))
    red = add_material(stage, "/World/Looks/red", (0.6, 0.2, 0.2))
    lamp = add_material(stage, "/World/Looks/lamp", (0.0, 0.0, 0.0), (20.0, 20.0, 20.0))
    # floor: two quads, facing +Y; `st` maps both onto the unit square (they overlap)
    f = np.array([[-1.5, 0, -1.5], [-1.5, 0, 1.5], [0, 0, 1.5], [0, 0, -1.5], [1.5, 0, 1.5], [1.5, 0, -1.5]], float)
    floor = add_mesh(stage, "/World/floor", f, [4, 4], [0, 1, 2, 3, 3, 2, 4, 5], grey)
    st = UsdGeom.PrimvarsAPI(floor).CreatePrimvar("st", _tex2(), UsdGeom.Tokens.faceVarying)
    st.Set([(0, 0), (0, 1), (1, 1), (1, 0)] * 2)
    # box 0.6 m, 5 cm above the floor (its bottom sees the floor's light: no texel is black), its
    # top a pentagon (one corner cut off the top square: a 5-gon and a triangle)
    add_pentagon_box(stage, "/World/box", (0.6, 0.0, 0.4), 0.3, 0.05, red)
    # a left-handed plinth (corners authored clockwise: USD flips them)
    lh = np.array([[-0.9, 0, -0.3], [-0.3, 0, -0.3], [-0.3, 0.2, -0.3], [-0.9, 0.2, -0.3]], float)
    # corners 0, 3, 2, 1 wind clockwise seen from +z; left-handed, the face looks towards +z
    m = add_mesh(stage, "/World/plinth", lh, [4], [0, 3, 2, 1], grey)
    m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    # back wall with its own lightmap UVs (st1), kept as authored
    w = np.array([[-1.5, 0, -1.5], [1.5, 0, -1.5], [1.5, 2.0, -1.5], [-1.5, 2.0, -1.5]], float)
    wall = add_mesh(stage, "/World/wall", w, [4], [0, 1, 2, 3], grey)
    st1 = UsdGeom.PrimvarsAPI(wall).CreatePrimvar("st1", _tex2(), UsdGeom.Tokens.faceVarying)
    st1.Set([(0.1, 0.1), (0.9, 0.1), (0.9, 0.7), (0.1, 0.7)])
    # emitter overhead, facing down
    e = np.array([[-0.4, 2.2, -0.4], [0.4, 2.2, -0.4], [0.4, 2.2, 0.4], [-0.4, 2.2, 0.4]])
    add_mesh(stage, "/World/lamp", e, [4], [0, 1, 2, 3], lamp)
    stage.GetRootLayer().Save()
    return path


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    root = tmp_path_factory.mktemp("source_lightmaps")
    scene = build_scene(root / "scene.usda")
    before = hashlib.sha256(scene.read_bytes()).hexdigest()
    cfg = write_config(root / "bake.yaml", scene, root / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 0.005, "samples": 8, "max_rounds": 4},
                       solver={"method": "jacobi", "tolerance": 1e-4},
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {"texels_per_metre": TPM, "padding": 2, "max_size": 512,
                                              "supersample": 2, "mode": "final_gather", "gather_rays": 16,
                                              "uv_primvars": ["st1", "st"],
                                              "encodings": ["unity-rgbm", "unity-dldr"]}})
    result = bake(cfg, keep_hierarchy=True)  # (result.gather)
    return root, scene, before, result, root / "out"


def _read_exr(path: Path) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGB" in ch:
            return np.asarray(ch["RGB"].pixels, dtype=np.float64)
        return np.stack([np.asarray(ch[c].pixels, dtype=np.float64) for c in "RGB"], axis=-1)


def _nearest_texel(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    h, w = image.shape[:2]
    x = np.clip(np.floor(uv[:, 0] * w).astype(int), 0, w - 1)
    y = np.clip(np.floor((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)
    return image[y, x]


def _originals(out: Path) -> dict:
    """Per original mesh prim of the composed output: world points, authored faces, st1, page file and
    scaleOffset, all as a game-engine importer would read them."""
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    xfc = UsdGeom.XformCache()
    found = {}
    for name in ("floor", "box", "plinth", "wall", "lamp"):
        prim = stage.GetPrimAtPath(f"/World/{name}")
        mesh = UsdGeom.Mesh(prim)
        m = np.array(xfc.GetLocalToWorldTransform(prim), dtype=np.float64)
        pts = np.array(mesh.GetPointsAttr().Get(), dtype=np.float64)
        pts = pts @ m[:3, :3] + m[3, :3]
        counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
        idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st1")
        entry = {"points": pts, "counts": counts, "indices": idx, "prim": prim, "stage": stage,
                 "left": mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded}
        if pv and pv.HasAuthoredValue():
            entry.update(st1=np.array(pv.Get(), dtype=np.float64), interp=pv.GetInterpolation(),
                         type=str(pv.GetTypeName()), page=prim.GetAttribute("hirad:lightmap:page").Get(),
                         file=prim.GetAttribute("hirad:lightmap:file").Get(),
                         so=np.array(prim.GetAttribute("hirad:lightmap:scaleOffset").Get(), dtype=np.float64))
        found[name] = entry
    return found


def _corner_points(entry) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fan triangles of the authored faces: (3D corners (T,3,3), page UVs (T,3,2), normal (T,3)) with
    the normal the side the mesh shows (orientation honoured)."""
    counts, idx, pts = entry["counts"], entry["indices"], entry["points"]
    uv = entry["st1"] * entry["so"][:2] + entry["so"][2:]
    tris_p, tris_uv, normals = [], [], []
    s = 0
    for c in counts:
        for k in range(1, c - 1):
            slots = [s, s + k, s + k + 1]
            tp = pts[idx[slots]]
            n = np.cross(tp[1] - tp[0], tp[2] - tp[0])
            n = -n if entry["left"] else n
            tris_p.append(tp)
            tris_uv.append(uv[slots])
            normals.append(n / np.linalg.norm(n))
        s += c
    return np.array(tris_p), np.array(tris_uv), np.array(normals)


def test_st1_is_written_on_the_original_prims_and_the_input_is_untouched(baked):
    root, scene, before, result, out = baked
    assert hashlib.sha256(scene.read_bytes()).hexdigest() == before
    orig = _originals(out)
    src = Usd.Stage.Open(str(scene))
    for name, e in orig.items():
        if name == "lamp":
            continue  # an emitter: baked too, checked below with the others' manifest entries
        assert "st1" in e, f"{name}: no st1 on the original prim"
        assert e["interp"] == UsdGeom.Tokens.faceVarying and e["type"] == "texCoord2f[]"
        assert len(e["st1"]) == len(e["indices"]), name
        assert (e["st1"] >= -1e-6).all() and (e["st1"] <= 1 + 1e-6).all(), name
        assert (out / e["file"].path).is_file(), e["file"]
        # the original geometry, texture UVs and orientation compose unchanged
        sp = UsdGeom.Mesh(src.GetPrimAtPath(f"/World/{name}"))
        assert np.array_equal(np.array(sp.GetFaceVertexIndicesAttr().Get()), e["indices"])
        assert np.array_equal(np.array(sp.GetPointsAttr().Get()),
                              np.array(UsdGeom.Mesh(e["prim"]).GetPointsAttr().Get()))
    st = UsdGeom.PrimvarsAPI(orig["floor"]["prim"]).GetPrimvar("st")
    assert np.array_equal(np.array(st.Get()), np.array([(0, 0), (0, 1), (1, 1), (1, 0)] * 2, dtype=np.float32))
    # the layer adds only st1, the lightmap attributes and (already before) visibility to them
    layer = Sdf.Layer.FindOrOpen(str(out / "solution.usda"))
    for name in ("floor", "box", "plinth", "wall"):
        spec = layer.GetPrimAtPath(f"/World/{name}")
        assert spec.specifier == Sdf.SpecifierOver
        added = set(spec.properties.keys())
        assert added <= {"primvars:st1", "hirad:lightmap:page", "hirad:lightmap:file",
                         "hirad:lightmap:scaleOffset", "visibility"}, added
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    assert manifest["version"] == 2 and manifest["uvSet"] == "st1"
    by_prim = {i["prim"]: i for i in manifest["instances"]}
    for name in ("floor", "box", "plinth", "wall"):
        i = by_prim[f"/World/{name}"]
        assert i["page"] == orig[name]["page"]
        assert np.allclose(i["scaleOffset"], orig[name]["so"], rtol=1e-6, atol=1e-7)


def test_texture_set_that_overlaps_is_charted_and_an_authored_st1_is_kept(baked):
    root, scene, before, result, out = baked
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    by_prim = {i["prim"]: i for i in manifest["instances"]}
    # st is listed in uv_primvars for this bake, but both floor quads map onto one square
    assert by_prim["/World/floor"]["uvSource"] == "generated"
    assert any("floor" in w for w in manifest["warnings"]), manifest["warnings"]
    assert by_prim["/World/wall"]["uvSource"] == "existing"
    wall = _originals(out)["wall"]
    assert np.allclose(wall["st1"], [(0.1, 0.1), (0.9, 0.1), (0.9, 0.7), (0.1, 0.7)], atol=1e-6)


def test_texels_at_chart_centres_match_the_final_gather(baked):
    """Through st1 and scaleOffset, as an engine reads them: the texel under each triangle's
    centroid holds the light the final gather finds at that texel's centre on the surface."""
    root, scene, before, result, out = baked
    orig = _originals(out)
    rel_errors = []
    for name in ("floor", "box", "plinth", "wall"):
        e = orig[name]
        page = _read_exr(out / e["file"].path)
        h, w = page.shape[:2]
        tp, tuv, tn = _corner_points(e)
        cuv = tuv.mean(axis=1)
        # the texel containing the centroid, and its centre mapped back onto the triangle
        tx = np.floor(cuv[:, 0] * w) + 0.5
        ty = np.floor(cuv[:, 1] * h) + 0.5
        centre_uv = np.stack([tx / w, ty / h], axis=1)
        a, b, c = tuv[:, 0], tuv[:, 1], tuv[:, 2]
        m = np.stack([b - a, c - a], axis=2)  # (T, 2, 2)
        lam = np.linalg.solve(m, (centre_uv - a)[..., None])[..., 0]
        inside = (lam >= 0.05).all(axis=1) & (lam.sum(axis=1) <= 0.95)
        x = tp[:, 0] + lam[:, :1] * (tp[:, 1] - tp[:, 0]) + lam[:, 1:] * (tp[:, 2] - tp[:, 0])
        x, n, cu = x[inside], tn[inside], centre_uv[inside]
        assert len(x) >= 1, name
        g = result.gather(x + 1e-4 * n, n, rays=256, seed=7)
        expect = g["irradiance"] / math.pi
        got = _nearest_texel(page, cu)
        lum = np.array([0.2126, 0.7152, 0.0722])
        dark = expect @ lum <= 0  # faces lying on the floor: nothing reaches them
        assert (got[dark] @ lum == 0).all(), f"{name}: light in texels of unlit faces"
        rel = np.abs(got[~dark] @ lum - expect[~dark] @ lum) / (expect[~dark] @ lum)
        rel_errors.extend(rel.tolist())
    rel_errors = np.array(rel_errors)
    assert len(rel_errors) >= 12
    assert rel_errors.max() < 0.02, f"texel vs gather: max {rel_errors.max():.4f}, mean {rel_errors.mean():.4f}"


def test_no_texel_is_black(baked):
    """No texel anywhere on a page is black: the page is dilated outward over all its empty
    texels. (The box's chart borders are all creases, where each side keeps its own light:
    seams are stitched only on smooth surfaces, tested on the cylinder of test_lightmaps.py and
    the folds of test_atlas.py.)"""
    root, scene, before, result, out = baked
    for f in sorted((out / "lightmaps" / "pages").glob("page*.exr")):
        image = _read_exr(f)
        assert (image.max(axis=-1) > 0).all(), f"{f.name}: {(image.max(axis=-1) <= 0).sum()} black texels"


def test_source_view_shows_the_input_meshes_and_keeps_the_solution_for_hirad(tmp_path):
    """outputs.usd_view: source: the input's meshes stay visible (their materials, their st1), the
    solved meshes are a hidden scope that hirad itself still reads back."""
    from hirad import usd as hirad_usd

    scene = build_scene(tmp_path / "scene.usda")
    cfg = write_config(tmp_path / "bake.yaml", scene, tmp_path / "out",
                       meshing={"max_patch_area": 0.1, "max_edge_length": 0.5},
                       outputs={"preview": {"enabled": False}, "usd_view": "source", "gltf": True,
                                "lightmaps": {"texels_per_metre": 8.0, "mode": "interpolate"}})
    result = bake(cfg, keep_hierarchy=True)  # (result.gather)
    # outputs.gltf: the GLB is part of the bake, with every original mesh
    import pygltflib

    glb = pygltflib.GLTF2().load(str(tmp_path / "out" / "scene.glb"))
    assert result.report["outputs"]["gltf"] == "scene.glb"
    assert len(glb.meshes) >= 5 and any("TEXCOORD_1" in p.attributes.__dict__ and p.attributes.TEXCOORD_1
                                        is not None for m in glb.meshes for p in m.primitives)
    stage = Usd.Stage.Open(str(tmp_path / "out" / "solution.usda"))
    for name in ("floor", "box", "plinth", "wall", "lamp"):
        prim = stage.GetPrimAtPath(f"/World/{name}")
        assert UsdGeom.Imageable(prim).ComputeVisibility() == UsdGeom.Tokens.inherited, name
        assert UsdGeom.PrimvarsAPI(prim).GetPrimvar("st1").HasAuthoredValue(), name
    solution = stage.GetPrimAtPath("/World/HiradSolution")
    assert UsdGeom.Imageable(solution).ComputeVisibility() == UsdGeom.Tokens.invisible
    data = hirad_usd.read_solution_layer(tmp_path / "out" / "solution.usda")
    assert {m.source_path for m in data.meshes} >= {f"/World/{n}" for n in ("floor", "box", "plinth", "wall")}


def _lit_floor(path: Path):
    """A new stage with a 4 m grey floor (y = 0, facing up) and a 0.6 m lamp 2 m above its centre,
    facing down: (stage, the grey material)."""
    stage = new_stage(path)
    grey = add_material(stage, "/World/Looks/grey", (0.5, 0.5, 0.5))
    lamp = add_material(stage, "/World/Looks/lamp", (0.0, 0.0, 0.0), (20.0, 20.0, 20.0))
    add_mesh(stage, "/World/floor", np.array([[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]], float), [4],
             [0, 1, 2, 3], grey)
    add_mesh(stage, "/World/lamp", np.array([[-0.3, 2.0, -0.3], [0.3, 2.0, -0.3], [0.3, 2.0, 0.3], [-0.3, 2.0, 0.3]]),
             [4], [0, 1, 2, 3], lamp)
    return stage, grey


def _instanced_scene(path: Path) -> Path:
    """A floor, a lamp, and a PointInstancer with two copies of one cube prototype: one under the
    lamp, one off in a corner (a different light on each)."""
    stage, grey = _lit_floor(path)
    add_crate_instancer(stage, "/World/crates", 0.2, [(0.0, 0.0, 0.0), (1.6, 0.0, 1.6)], grey)
    stage.GetRootLayer().Save()
    return path


def test_instances_share_one_uv_set_and_get_their_own_rectangles(tmp_path):
    scene = _instanced_scene(tmp_path / "scene.usda")
    cfg = write_config(tmp_path / "bake.yaml", scene, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 0.005, "samples": 8, "max_rounds": 4},
                       solver={"method": "jacobi", "tolerance": 1e-4},
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {"texels_per_metre": 32.0, "padding": 2, "max_size": 512,
                                              "mode": "final_gather", "gather_rays": 16}})
    result = bake(cfg, keep_hierarchy=True)  # (result.gather)
    out = tmp_path / "out"
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    copies = [i for i in manifest["instances"] if i["mesh"] == "/World/crates/Prototypes/crate"]
    assert len(copies) == 2 and copies[0]["prim"] != copies[1]["prim"]
    # distinct, non-overlapping rectangles on their pages
    (a, b) = copies
    ra = np.array(a["scaleOffset"])
    rb = np.array(b["scaleOffset"])
    assert not np.allclose(ra, rb)
    if a["page"] == b["page"]:
        apart_x = ra[2] + ra[0] <= rb[2] + 1e-9 or rb[2] + rb[0] <= ra[2] + 1e-9
        apart_y = ra[3] + ra[1] <= rb[3] + 1e-9 or rb[3] + rb[1] <= ra[3] + 1e-9
        assert apart_x or apart_y, (ra, rb)
    # one UV set, on the prototype mesh
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    proto = stage.GetPrimAtPath("/World/crates/Prototypes/crate")
    st1 = np.array(UsdGeom.PrimvarsAPI(proto).GetPrimvar("st1").Get(), dtype=np.float64)
    idx = np.array(UsdGeom.Mesh(proto).GetFaceVertexIndicesAttr().Get())
    pts = np.array(UsdGeom.Mesh(proto).GetPointsAttr().Get(), dtype=np.float64)
    assert len(st1) == len(idx) and (st1 >= 0).all() and (st1 <= 1).all()
    # the top face (+y) of each copy, through its own rectangle: different light, each right
    offsets = np.array([(0.0, 0.0, 0.0), (1.6, 0.0, 1.6)])
    lum = np.array([0.2126, 0.7152, 0.0722])
    got, expect = [], []
    for copy, off in zip(copies, offsets):
        k = int(copy["prim"].split("instance_")[1].split("/")[0])
        page = _read_exr(out / "lightmaps" / copy["file"])
        so = np.array(copy["scaleOffset"])
        face = next(f for f in range(6) if np.allclose(pts[idx[4 * f:4 * f + 4], 1], 2 * 0.2))
        corners = slice(4 * face, 4 * face + 4)
        uv = st1[corners].mean(axis=0) * so[:2] + so[2:]
        x = pts[idx[corners]].mean(axis=0) + offsets[k]
        g = result.gather((x + [0, 1e-4, 0])[None], np.array([[0.0, 1.0, 0.0]]), rays=256, seed=3)
        got.append(float(_bilinear(page, uv[None])[0] @ lum))
        expect.append(float(g["irradiance"][0] @ lum / math.pi))
    got, expect = np.array(got), np.array(expect)
    assert expect[0] > 1.5 * expect[1]  # the lamp is right above the first copy
    assert np.all(np.abs(got - expect) / expect < 0.02), (got, expect)


def _native_instances_scene(root: Path) -> tuple[Path, Path]:
    """A floor, a lamp over the origin, and two pairs of native instances of a cube: inst0/inst1
    reference a `class` prim of the same file (an internal reference), ext0/ext1 another file."""
    crate_file = root / "crate.usda"
    cs = new_stage(crate_file)
    cs.RemovePrim("/World")
    crate = UsdGeom.Xform.Define(cs, "/Crate")
    cs.SetDefaultPrim(crate.GetPrim())
    add_crate_mesh(cs, "/Crate/crate", 0.2, add_material(cs, "/Crate/Looks/grey", (0.5, 0.5, 0.5)))
    cs.GetRootLayer().Save()
    path = root / "scene.usda"
    stage, grey = _lit_floor(path)
    UsdGeom.Xform.Define(stage, "/Assets/Crate")
    add_crate_mesh(stage, "/Assets/Crate/crate", 0.2, grey)
    stage.GetPrimAtPath("/Assets").SetSpecifier(Sdf.SpecifierClass)  # abstract: not drawn itself
    for name, at, ref in (("inst0", (0.0, 0.0, 0.0), None), ("inst1", (1.6, 0.0, 1.6), None),
                          ("ext0", (-1.6, 0.0, 1.6), "./crate.usda"), ("ext1", (-1.6, 0.0, -1.6), "./crate.usda")):
        x = UsdGeom.Xform.Define(stage, f"/World/{name}")
        x.AddTranslateOp().Set(at)
        refs = x.GetPrim().GetReferences()
        refs.AddReference(ref) if ref else refs.AddInternalReference("/Assets/Crate")
        x.GetPrim().SetInstanceable(True)
    stage.GetRootLayer().Save()
    return path, crate_file


def test_native_instances_get_st1_and_their_own_rectangles(tmp_path):
    """Meshes inside native instances: an over on the internally referenced prototype mesh gives
    every instance the one UV set (instancing kept), and each instance root lists its meshes'
    rectangles; instances of another file's prototype are de-instanced in the output layer (with
    a warning) and carry st1 and their rectangle on their own prims. Every copy's top-face texel
    holds the gathered light at that copy; the inputs are untouched."""
    scene, crate_file = _native_instances_scene(tmp_path)
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (scene, crate_file)}
    cfg = write_config(tmp_path / "bake.yaml", scene, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 0.005, "samples": 8, "max_rounds": 4},
                       solver={"method": "jacobi", "tolerance": 1e-4},
                       outputs={"preview": {"enabled": False}, "gltf": True,
                                "lightmaps": {"texels_per_metre": 32.0, "padding": 2, "max_size": 512,
                                              "mode": "final_gather", "gather_rays": 16}})
    result = bake(cfg, keep_hierarchy=True)  # (result.gather)
    out = tmp_path / "out"
    # the GLB export finds every copy's lightmap UVs (it warns of a mesh with a page and no st1)
    warnings = json.loads((out / "report.json").read_text())["warnings"]
    assert not any("no primvars:st1" in w for w in warnings), warnings
    assert {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (scene, crate_file)} == before
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    by_prim = {i["prim"]: i for i in manifest["instances"]}
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    # internal: still instances, one UV set held by the referenced mesh and seen through both
    assert stage.GetPrimAtPath("/World/inst0").IsInstance() and stage.GetPrimAtPath("/World/inst1").IsInstance()
    held = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Assets/Crate/crate")).GetPrimvar("st1")
    assert held and held.GetInterpolation() == UsdGeom.Tokens.faceVarying
    seen = [np.array(UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(f"/World/inst{k}/crate")).GetPrimvar("st1").Get())
            for k in (0, 1)]
    np.testing.assert_array_equal(seen[0], seen[1])
    assert by_prim["/World/inst0/crate"]["mesh"] == "/Assets/Crate/crate"
    # external: de-instanced, named in a warning, st1 and the rectangle on each copy's prim
    for k in (0, 1):
        assert not stage.GetPrimAtPath(f"/World/ext{k}").IsInstance()
        assert stage.GetPrimAtPath(f"/World/ext{k}/crate").GetAttribute("hirad:lightmap:scaleOffset").Get() is not None
    assert any("/World/ext0" in w and "non-instanceable" in w for w in manifest["warnings"]), manifest["warnings"]

    def rectangle(name):
        """(page file, scaleOffset, st1, mesh) as an engine importer reads them from the USD alone."""
        prim = stage.GetPrimAtPath(f"/World/{name}/crate")
        st1 = np.array(UsdGeom.PrimvarsAPI(prim).GetPrimvar("st1").Get(), dtype=np.float64)
        if name.startswith("inst"):
            root = stage.GetPrimAtPath(f"/World/{name}")
            meshes = list(root.GetAttribute("hirad:lightmap:meshes").Get())
            k = meshes.index("crate")
            so = np.array(root.GetAttribute("hirad:lightmap:scaleOffsets").Get()[k], dtype=np.float64)
            f = root.GetAttribute("hirad:lightmap:files").Get()[k].path
        else:
            so = np.array(prim.GetAttribute("hirad:lightmap:scaleOffset").Get(), dtype=np.float64)
            f = prim.GetAttribute("hirad:lightmap:file").Get().path
        np.testing.assert_allclose(so, by_prim[f"/World/{name}/crate"]["scaleOffset"], rtol=1e-6)
        return out / f, so, st1, UsdGeom.Mesh(prim)

    lum = np.array([0.2126, 0.7152, 0.0722])
    got, expect, rects = [], [], []
    xfc = UsdGeom.XformCache()
    for name in ("inst0", "inst1", "ext0", "ext1"):
        page_file, so, st1, mesh = rectangle(name)
        rects.append(so)
        idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
        m = np.array(xfc.GetLocalToWorldTransform(mesh.GetPrim()), dtype=np.float64)
        pts = np.array(mesh.GetPointsAttr().Get(), dtype=np.float64) @ m[:3, :3] + m[3, :3]
        face = next(f for f in range(6) if np.allclose(pts[idx[4 * f:4 * f + 4], 1], 0.4))
        corners = slice(4 * face, 4 * face + 4)
        x = pts[idx[corners]].mean(axis=0)
        g = result.gather((x + [0, 1e-4, 0])[None], np.array([[0.0, 1.0, 0.0]]), rays=256, seed=3)
        got.append(float(_bilinear(_read_exr(page_file), (st1[corners].mean(axis=0) * so[:2] + so[2:])[None])[0] @ lum))
        expect.append(float(g["irradiance"][0] @ lum / math.pi))
    assert len({tuple(r) for r in rects}) == 4  # a rectangle each
    got, expect = np.array(got), np.array(expect)
    assert expect[0] > 1.5 * expect[1]  # the lamp is over inst0 only
    assert np.all(np.abs(got - expect) / expect < 0.02), (got, expect)


def test_instances_of_a_drawn_mesh_are_deinstanced_and_the_original_keeps_its_own_st1(tmp_path):
    """Instances that reference a mesh the scene also draws (its own light, its own rectangle):
    one st1 over that mesh would be shared with the original, so the instances are made
    non-instanceable (named in a warning) and all three carry their own st1 and rectangle."""
    path = tmp_path / "scene.usda"
    stage, grey = _lit_floor(path)
    UsdGeom.Xform.Define(stage, "/World/original")
    add_crate_mesh(stage, "/World/original/crate", 0.2, grey)
    for name, at in (("copy0", (1.2, 0.0, 0.0)), ("copy1", (-1.2, 0.0, 0.0))):
        x = UsdGeom.Xform.Define(stage, f"/World/{name}")
        x.AddTranslateOp().Set(at)
        x.GetPrim().GetReferences().AddInternalReference("/World/original")
        x.GetPrim().SetInstanceable(True)
    stage.GetRootLayer().Save()
    cfg = write_config(tmp_path / "bake.yaml", path, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 0.005, "samples": 8, "max_rounds": 4},
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {"texels_per_metre": 32.0, "max_size": 512, "mode": "final_gather"}})
    bake(cfg)
    out = tmp_path / "out"
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    by_prim = {i["prim"]: i for i in manifest["instances"]}
    solved = Usd.Stage.Open(str(out / "solution.usda"))
    rects = []
    for name in ("original", "copy0", "copy1"):
        prim = solved.GetPrimAtPath(f"/World/{name}/crate")
        assert not solved.GetPrimAtPath(f"/World/{name}").IsInstance()
        assert by_prim[f"/World/{name}/crate"]["mesh"] == f"/World/{name}/crate"
        assert UsdGeom.PrimvarsAPI(prim).GetPrimvar("st1").HasAuthoredValue()
        rects.append(tuple(prim.GetAttribute("hirad:lightmap:scaleOffset").Get()))
    assert len(set(rects)) == 3
    assert any("/World/copy0" in w and "non-instanceable" in w for w in manifest["warnings"]), manifest["warnings"]
    assert not any("/World/original" in w and "non-instanceable" in w for w in manifest["warnings"])


def test_each_polygon_is_one_piece_of_its_chart(baked):
    """A faceVarying st1 has one UV per polygon corner, so a polygon must lie whole in one chart:
    for every planar polygon, the affine map that takes its first fan triangle to UV takes
    every other corner to its st1 (in texels, within 1e-3), i.e. no polygon is cut by a seam."""
    root, scene, before, result, out = baked
    worst = 0.0
    polygons = 0
    for name, e in _originals(out).items():
        if "st1" not in e:
            continue
        page = _read_exr(out / e["file"].path)
        size = np.array(page.shape[1::-1], float)
        uv = (e["st1"] * e["so"][:2] + e["so"][2:]) * size
        s = 0
        for c in e["counts"]:
            if c > 3:
                x = e["points"][e["indices"][s:s + c]]
                a, b, d = x[0], x[1], x[2]
                e1, e2 = b - a, d - a
                gram = np.array([[e1 @ e1, e1 @ e2], [e1 @ e2, e2 @ e2]])
                lam = np.linalg.solve(gram, np.stack([(x - a) @ e1, (x - a) @ e2]))  # (2, c)
                predicted = uv[s] + np.outer(lam[0], uv[s + 1] - uv[s]) + np.outer(lam[1], uv[s + 2] - uv[s])
                worst = max(worst, float(np.abs(predicted - uv[s:s + c]).max()))
                polygons += 1
            s += c
    assert polygons >= 8
    assert worst < 1e-3, f"a polygon's corners leave its first triangle's chart by {worst:.3g} texels"


@pytest.mark.parametrize("stride", [1, 4])
def test_directional_maps_decode_to_the_gathered_light(tmp_path, stride):
    """directional: true. At chart-centre texels of the floor and the box, each engine's own decode
    (hirad.outputs.directional: Godot's packed L1 shader, Unity's DecodeDirectionalLightmap) for
    normals tilted 35 degrees four ways gives the light a fresh directional gather at that point
    predicts for the tilted normal (E1(n') = l0/4 + n'.l1/2, within 2 % of the light at the
    texel's own normal); Unity's decode at the
    texel's own normal is the plain lightmap (within 8-bit rounding); and on the floor under the
    lamp the dominant direction points at the lamp. With gather_stride 4 the texels interpolated
    between gathered ones carry all 18 channels' means (E, l0, l1 and the normal alike), so the
    decodes still hold at every texel; the chart-centre texels here stay within the same 2 %
    (a texel may differ from its own gather by up to the tolerance, 5 %, where the light bends
    between lattice points; measured 1.3 % at most)."""
    from PIL import Image

    from hirad.outputs import directional as D
    from hirad.outputs.probes import engine_frame

    scene = build_scene(tmp_path / "scene.usda")
    cfg = write_config(tmp_path / "bake.yaml", scene, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 0.005, "samples": 8, "max_rounds": 4},
                       solver={"method": "jacobi", "tolerance": 1e-4},
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {"texels_per_metre": TPM, "padding": 2, "max_size": 512,
                                              "mode": "final_gather", "gather_rays": 16, "directional": True,
                                              "gather_stride": stride}})
    result = bake(cfg, keep_hierarchy=True)  # (result.gather)
    if stride > 1:
        assert result.report["outputs"]["lightmap_atlas"]["interpolated_texels"] > 0
    out = tmp_path / "out"
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    godot_m, unity_m = engine_frame("Y", "godot"), engine_frame("Y", "unity")
    lum = np.array([0.2126, 0.7152, 0.0722])
    errors, own, angles = [], [], []
    orig = _originals(out)
    for name in ("floor", "box"):
        e = orig[name]
        entry = manifest["pages"][e["page"]]
        page = _read_exr(out / "lightmaps" / entry["file"])
        layers = np.stack([_read_exr(out / "lightmaps" / f) for f in entry["godotL1"]["layers"]])
        with Image.open(out / "lightmaps" / entry["unityDirection"]) as im:
            udir = np.asarray(im.convert("RGBA"), dtype=np.float64) / 255
        h, w = page.shape[:2]
        tp, tuv, tn = _corner_points(e)
        cuv = tuv.mean(axis=1)
        tx, ty = np.floor(cuv[:, 0] * w) + 0.5, np.floor(cuv[:, 1] * h) + 0.5
        centre_uv = np.stack([tx / w, ty / h], axis=1)
        a, b, c = tuv[:, 0], tuv[:, 1], tuv[:, 2]
        lam = np.linalg.solve(np.stack([b - a, c - a], axis=2), (centre_uv - a)[..., None])[..., 0]
        inside = (lam >= 0.05).all(axis=1) & (lam.sum(axis=1) <= 0.95)
        x = (tp[:, 0] + lam[:, :1] * (tp[:, 1] - tp[:, 0]) + lam[:, 1:] * (tp[:, 2] - tp[:, 0]))[inside]
        n, cu = tn[inside], centre_uv[inside]
        g = result.gather(x + 1e-4 * n, n, rays=256, seed=5, directional=True)
        px = np.clip(np.floor(cu[:, 0] * w).astype(int), 0, w - 1)
        py = np.clip(np.floor((1 - cu[:, 1]) * h).astype(int), 0, h - 1)
        lit = g["irradiance"] @ lum > 0
        for k in np.nonzero(lit)[0]:
            t1 = np.cross(n[k], [1.0, 0, 0] if abs(n[k][0]) < 0.9 else [0, 0, 1.0])
            t1 /= np.linalg.norm(t1)
            t2 = np.cross(n[k], t1)
            for t in (t1, -t1, t2, -t2):
                tilted = math.cos(math.radians(35)) * n[k] + math.sin(math.radians(35)) * t
                expect = (g["l0"][k] / 4 + g["l1"][k] @ tilted / 2) / math.pi
                got = D.godot_directional_decode(layers[:, py[k], px[k]], godot_m @ tilted, packed=True)
                # relative to the light at the texel's own normal (a tilt away from the light
                # can leave little, and the error is the texel average's, on the whole light)
                level = (g["l0"][k] / 4 + g["l1"][k] @ n[k] / 2) @ lum / math.pi
                errors.append(abs(got @ lum - expect @ lum) / level)
            plain = page[py[k], px[k]]
            unity = D.unity_decode_directional(plain, udir[py[k], px[k]], unity_m @ n[k])
            own.append(abs(unity @ lum - plain @ lum) / (plain @ lum))
        if name == "floor":  # floor points near the lamp's foot, read through st1
            for q in ([-0.3, 0.0, -0.3], [-0.3, 0.0, 0.2], [0.1, 0.0, -0.3]):
                q = np.array(q)
                for tri_p, tri_uv in zip(tp, tuv):
                    m = np.stack([tri_p[1] - tri_p[0], tri_p[2] - tri_p[0]], axis=1)[[0, 2]]
                    bl = np.linalg.solve(m, (q - tri_p[0])[[0, 2]])
                    if bl.min() >= 0 and bl.sum() <= 1:
                        quv = tri_uv[0] + bl[0] * (tri_uv[1] - tri_uv[0]) + bl[1] * (tri_uv[2] - tri_uv[0])
                        d = udir[int((1 - quv[1]) * h), int(quv[0] * w)]
                        v = np.linalg.inv(unity_m) @ (d[:3] - 0.5)
                        to_lamp = np.array([0.0, 2.2, 0.0]) - q
                        cosang = v @ to_lamp / np.linalg.norm(v) / np.linalg.norm(to_lamp)
                        angles.append(math.degrees(math.acos(min(1.0, cosang))))
                        break
    print(f"\nstride {stride}: {len(errors)} tilted decodes, p95 {np.quantile(errors, 0.95):.4f}, max {max(errors):.4f}")
    assert len(errors) >= 40 and len(angles) >= 2
    assert max(errors) < 0.02, f"Godot decode vs gather: max {max(errors):.4f}"
    assert max(own) < 0.01, f"Unity decode at the normal vs the lightmap: max {max(own):.4f}"
    assert max(angles) < 20, f"dominant direction vs the lamp: {angles}"


def test_unity_encodings_decode_to_the_page_by_unitys_formulas(baked):
    """Unity RGBM and dLDR PNGs beside each page, named in the manifest, decoded by Unity's documented
    formulas (Lightmaps: Technical information; EntityLighting.hlsl): RGBM linear = (5 a rgb)^2.2,
    dLDR linear = (2 rgb)^2.2, texels as 8-bit fractions. Each texel is the EXR's value up to the
    rounding of one 8-bit step in gamma space: |dec - v| <= v ((1 + dg/g)^2.2 - 1), dg the half step
    (RGBM 2.5 a / 255, dLDR 1 / 255), g = v^(1/2.2), and the EXR's half-float rounding."""
    from PIL import Image

    root, scene, before, result, out = baked
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    assert set(manifest["encodings"]) == {"unity-rgbm", "unity-dldr"}
    for entry in manifest["pages"]:
        v = _read_exr(out / "lightmaps" / entry["file"])
        for enc, rng, dg_of in (("unity-rgbm", 34.493242, lambda a: 2.5 * a / 255),
                                ("unity-dldr", 4.594794, lambda a: 1.0 / 255)):
            with Image.open(out / "lightmaps" / entry["encoded"][enc]["file"]) as im:
                q = np.asarray(im, dtype=np.float64) / 255
            if enc == "unity-rgbm":
                a = q[..., 3:4]
                dec = (5 * a * q[..., :3]) ** 2.2
            else:
                a = np.ones(q.shape[:2] + (1,))
                dec = (2 * q[..., :3]) ** 2.2
            assert q.shape[:2] == v.shape[:2]
            inside = v < rng * 0.999  # beyond the range both clamp
            g = np.maximum(v, 1e-12) ** (1 / 2.2)
            # plus the EXR's own half-float rounding (2^-11 relative) of the value encoded
            bound = v * ((1 + dg_of(a) / g) ** 2.2 - 1) + v * 2.0 ** -11 + 1e-6
            bad = (np.abs(dec - v) > bound) & inside
            assert not bad.any(), (enc, v[bad][:5], dec[bad][:5], bound[bad][:5])


def _quads(origins):
    """Unit UV squares (two triangles each) at the given lower-left corners: (M, 3, 2)."""
    tri = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
    return np.concatenate([tri + np.asarray(o, float) for o in origins])


def test_uv_overlap_of_stacked_and_laid_out_sets():
    # The share of the covered UV area covered twice, from the layouts' geometry: squares
    # side by side overlap nowhere; a tiled texture set (every quad on the same square) is
    # covered twice everywhere; that stack beside one square of its own is doubled on half
    # the covered area. The stacked sets are large enough that their grid is coarsened
    # (4,000 triangles each spanning the layout), which must not change those answers
    # beyond a grid cell's share (1/16 of the side at the coarsest).
    from hirad.outputs.lightmaps import _uv_overlap

    grid = _quads([(i, j) for i in range(40) for j in range(50)])
    assert _uv_overlap(grid) == 0.0
    stacked = _quads([(0, 0)] * 2000)
    assert _uv_overlap(stacked) == 1.0
    beside = np.concatenate([stacked, _quads([(1, 0)])])
    assert abs(_uv_overlap(beside) - 0.5) <= 1 / 16
    mirrored = np.concatenate([grid, grid[:, ::-1, :]])  # the same islands again, wound the other way
    assert _uv_overlap(mirrored) == 1.0
