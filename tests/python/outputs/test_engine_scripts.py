"""The engine import scripts (tools/engines/) against a real bake's manifest and pages.

Neither Godot 4 nor Unity can run here (Debian ships godot3 3.2 only; Unity is proprietary), so
the scripts themselves are not executed. What is checked is what they depend on, read out of the
scripts' own text so that a change on either side shows up here:

1. Keys. Every manifest key the scripts read goes through one accessor (GDScript
   ``_req(obj, "key", "kind", where)``, C# ``Req(obj, "key", "kind", where)`` or ``Opt(...)``);
   the test finds those calls with a regular expression, resolves ``obj`` (the script's variable
   for the manifest, a page, an instance, engines, engines.godot / engines.unity) to the real
   manifest's objects and asserts each required key exists in every one of them with the kind
   the script converts it to. The conventions the scripts refuse to work without (manifest
   version, uvOrigin bottom-left, Godot flipV true, Unity flipV false) are read from the scripts
   and checked against the manifest too.

2. Godot's rectangle. Godot samples its lightmap at ``UV2 * uv_scale.size + uv_scale.position``
   in slice UVs with the origin at the top-left; its UV2 is glTF's TEXCOORD_1 = (u, 1 - v) of the
   mesh's st1. From hirad's convention (page_uv = st1 * (sx, sy) + (ox, oy), origin bottom-left,
   image row 0 at the top) the test derives the Rect2 itself (the page's top-left texel corner at
   slice (0, 0) when a smaller page sits in a larger slice) and checks that

   a. every authored st1 corner of every original prim lands, through the flip and the Rect2,
      on the slice pixel of the page texel hirad's own convention names, for the slice size the
      script uses (the largest page) and for a slice twice that size;
   b. the GLB's TEXCOORD_1 (hirad's glTF export, what Godot reads into UV2; for PointInstancer
      copies, which the GLB leaves out, st1 with the flip), interpolated to the centroid of
      every face of hirad's solution meshes, lands on the same pixel as that face's own page
      UVs (the solution layer's ``hirad:lightmapUV``, found by hirad locating each display
      corner in its source face): an independent route to the same texels. Exact only where a
      polygon's lightmap UVs are one affine map (the scene's faces are charted whole);
   c. the script's own Rect2 expression (the ``return Rect2(...)`` of ``godot_uv_scale``,
      evaluated) equals the derived one.

3. Unity uses scaleOffset as written (no flip): checked through (a) in Unity's convention, where
   page_uv = uv2 * xy + zw is bottom-left like USD.

4. Names: the characters the Godot script drops before comparing node names (read from it)
   keep every GLB node's name distinct, and each prim maps to its own node.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("xatlas")
pytest.importorskip("pygltflib")
from hirad_e2e_helpers import add_crate_instancer, add_material, add_pentagon_box, add_mesh, new_stage, write_config  # noqa: E402
from pxr import Sdf, Usd, UsdGeom  # noqa: E402

from hirad.bake import bake  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
GODOT = ROOT / "tools" / "engines" / "godot" / "hirad_lightmap_import.gd"
UNITY = ROOT / "tools" / "engines" / "unity" / "Editor" / "HiradLightmapImporter.cs"
UNITY_RUNTIME = ROOT / "tools" / "engines" / "unity" / "Runtime" / "HiradLightmaps.cs"

TPM = 16.0
MAX_SIZE = 64  # small pages: the floor and the wall cannot share one, so there are several


def build_scene(path: Path) -> Path:
    """A floor of two quads, a wall, a box whose top is a pentagon and a triangle (n-gon fans), a
    left-handed plinth, an emitter, a panel with its own st1 and two PointInstancer copies of a
    crate: Y up, metres."""
    stage = new_stage(path)
    grey = add_material(stage, "/World/Looks/grey", (0.6, 0.6, 0.6))
    red = add_material(stage, "/World/Looks/red", (0.6, 0.2, 0.2))
    lamp = add_material(stage, "/World/Looks/lamp", (0.0, 0.0, 0.0), (20.0, 20.0, 20.0))
    f = np.array([[-1.5, 0, -1.5], [-1.5, 0, 1.5], [0, 0, 1.5], [0, 0, -1.5], [1.5, 0, 1.5], [1.5, 0, -1.5]], float)
    add_mesh(stage, "/World/floor", f, [4, 4], [0, 1, 2, 3, 3, 2, 4, 5], grey)
    add_pentagon_box(stage, "/World/Props/box", (0.6, 0.0, 0.4), 0.3, 0.0, red)
    lh = np.array([[-0.9, 0, -0.3], [-0.3, 0, -0.3], [-0.3, 0.2, -0.3], [-0.9, 0.2, -0.3]], float)
    m = add_mesh(stage, "/World/Props/plinth", lh, [4], [0, 3, 2, 1], grey)
    m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    w = np.array([[-1.5, 0, -1.5], [1.5, 0, -1.5], [1.5, 2.0, -1.5], [-1.5, 2.0, -1.5]], float)
    add_mesh(stage, "/World/wall", w, [4], [0, 1, 2, 3], grey)
    e = np.array([[-0.4, 2.2, -0.4], [0.4, 2.2, -0.4], [0.4, 2.2, 0.4], [-0.4, 2.2, 0.4]])
    add_mesh(stage, "/World/lamp", e, [4], [0, 1, 2, 3], lamp)
    # a panel with its own lightmap set st1 (kept: its rectangle is a real scale and offset)
    q = np.array([[1.4, 0.2, -1.0], [1.4, 0.2, 0.2], [1.4, 1.0, 0.2], [1.4, 1.0, -1.0]], float)
    panel = add_mesh(stage, "/World/Props/panel", q, [4], [0, 3, 2, 1], grey)
    st1 = UsdGeom.PrimvarsAPI(panel).CreatePrimvar("st1", Sdf.ValueTypeNames.TexCoord2fArray,
                                                   UsdGeom.Tokens.faceVarying)
    st1.Set([(0.1, 0.2), (0.1, 0.7), (0.9, 0.7), (0.9, 0.2)])
    # two copies of one crate prototype (PointInstancer): one UV set, two rectangles
    add_crate_instancer(stage, "/World/crates", 0.15, [(-1.0, 0.0, 1.0), (0.0, 0.0, 1.0)], grey)
    stage.GetRootLayer().Save()
    return path


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    from hirad.outputs.gltf import write_glb

    root = tmp_path_factory.mktemp("engine_scripts")
    scene = build_scene(root / "scene.usda")
    cfg = write_config(root / "bake.yaml", scene, root / "out", method="flat",
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {"texels_per_metre": TPM, "padding": 2, "max_size": MAX_SIZE,
                                              "supersample": 1, "mode": "interpolate",
                                              "uv_primvars": ["st1"]}})
    bake(cfg)
    out = root / "out"
    glb = write_glb(out)
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    return out, manifest, Path(glb)


# ------------------------------------------------------------------------------------------
# 1. keys

ACCESSOR = re.compile(r'\b(_req|_opt|Req|Opt)\(\s*(\w+)\s*,\s*"([^"]+)"\s*,\s*"(\w+)"')


def _accessors(path: Path) -> list[tuple[str, str, str, str]]:
    text = path.read_text()
    # comments out: a key named in prose is not a key read
    if path.suffix == ".gd":
        text = "\n".join(line.split("#", 1)[0] if not line.lstrip().startswith("##") else "" for line in
                         text.splitlines())
    else:
        text = "\n".join(line.split("//", 1)[0] for line in text.splitlines())
    return [m.groups() for m in ACCESSOR.finditer(text)]


def _is_kind(v, kind: str) -> bool:
    num = isinstance(v, (int, float)) and not isinstance(v, bool)
    return {
        "string": isinstance(v, str),
        "bool": isinstance(v, bool),
        "number": num,
        "int": num and float(v) == int(v),
        "array": isinstance(v, list),
        "dict": isinstance(v, dict),
        "number4": isinstance(v, list) and len(v) == 4
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v),
    }[kind]


def _objects(manifest: dict, engine: str) -> dict[str, list[dict]]:
    """The scripts' variable names -> the manifest objects they stand for."""
    engines = manifest.get("engines", {})
    return {
        "manifest": [manifest],
        "engines": [engines],
        engine: [engines.get(engine, {})],
        "page": list(manifest.get("pages", [])),
        "inst": list(manifest.get("instances", [])),
    }


@pytest.mark.parametrize("script,engine", [(GODOT, "godot"), (UNITY, "unity")])
def test_every_manifest_key_a_script_reads_exists_with_its_kind(baked, script, engine):
    out, manifest, _ = baked
    calls = _accessors(script)
    read = {(var, key) for _, var, key, _ in calls}
    # the regex must be finding the reads, not nothing
    for need in [("inst", "prim"), ("inst", "page"), ("inst", "scaleOffset"), ("page", "file"),
                 ("page", "width"), ("page", "height"), ("manifest", "version"), ("manifest", "uvOrigin"),
                 ("manifest", "pages"), ("manifest", "instances"), (engine, "flipV")]:
        assert need in read, f"{script.name}: no accessor for {need[0]}.{need[1]} (found {sorted(read)})"
    objects = _objects(manifest, engine)
    assert manifest["instances"] and manifest["pages"]
    for fn, var, key, kind in calls:
        assert var in objects, f"{script.name}: {fn}({var}, \"{key}\"): unknown manifest object '{var}'"
        for k, obj in enumerate(objects[var]):
            if fn in ("_req", "Req"):
                assert key in obj, f"{script.name} requires {var}[{k}].{key}; the manifest has {sorted(obj)}"
            if key in obj:
                assert _is_kind(obj[key], kind), \
                    f"{script.name} reads {var}[{k}].{key} as {kind}; the manifest has {obj[key]!r}"


def test_the_conventions_the_scripts_insist_on_hold(baked):
    out, manifest, _ = baked
    gd, cs = GODOT.read_text(), UNITY.read_text()
    assert int(re.search(r"const MANIFEST_VERSION := (\d+)", gd).group(1)) == manifest["version"]
    assert int(re.search(r"const int ManifestVersion = (\d+);", cs).group(1)) == manifest["version"]
    origin_gd = re.search(r'begins_with\("([^"]+)"\)', gd).group(1)
    origin_cs = re.search(r'StartsWith\("([^"]+)"', cs).group(1)
    assert manifest["uvOrigin"].startswith(origin_gd) and manifest["uvOrigin"].startswith(origin_cs)
    # Godot refuses a manifest that does not ask for the flip; Unity one that does
    assert "flip != true" in gd and manifest["engines"]["godot"]["flipV"] is True
    assert 'Req(unity, "flipV", "bool"' in cs and manifest["engines"]["unity"]["flipV"] is False
    # every page file and every instance's page exist
    for page in manifest["pages"]:
        assert (out / "lightmaps" / page["file"]).is_file(), page["file"]
    for inst in manifest["instances"]:
        assert 0 <= inst["page"] < len(manifest["pages"])
    # the runtime component the editor script fills has the fields it sets
    runtime = UNITY_RUNTIME.read_text()
    for field in re.findall(r"holder\.(\w+) =", cs):
        assert re.search(rf"public [\w\[\]]+ {field}\b", runtime), f"HiradLightmaps has no field {field}"


# ------------------------------------------------------------------------------------------
# 2. the rectangle


def derived_rect(so, page_size, slice_size) -> np.ndarray:
    """Godot's Rect2 (position x, y, size x, y) for hirad's scaleOffset, derived here:
    a corner with st1 = (u, v) is at page UV P = (sx u + ox, sy v + oy) (origin bottom-left);
    in the page image (origin top-left) at (P.x, 1 - P.y); the page sits unscaled at the slice's
    top-left, so in slice UVs at (P.x w / W, (1 - P.y) h / H). Godot's UV2 is (u, t), t = 1 - v,
    and it samples at UV2 * size + position, so
        x: sx w/W u + ox w/W                 -> size.x = sx w/W, position.x = ox w/W
        y: (1 - sy (1 - t) - oy) h/H          -> size.y = sy h/H, position.y = (1 - sy - oy) h/H."""
    sx, sy, ox, oy = (float(v) for v in so)
    kx, ky = page_size[0] / slice_size[0], page_size[1] / slice_size[1]
    return np.array([ox * kx, (1.0 - sy - oy) * ky, sx * kx, sy * ky])


def _godot_pixel(uv2: np.ndarray, rect: np.ndarray, slice_size) -> np.ndarray:
    """Slice pixel coordinates (x right, y down from the top-left) of Godot's lookup."""
    g = uv2 * rect[2:] + rect[:2]
    return g * np.asarray(slice_size, float)


def _hirad_pixel(page_uv: np.ndarray, page_size) -> np.ndarray:
    """Page pixel coordinates of hirad's page UVs (origin bottom-left, row 0 the top)."""
    w, h = page_size
    return np.stack([page_uv[:, 0] * w, (1.0 - page_uv[:, 1]) * h], axis=1)


def _original_st1(out: Path) -> dict[str, np.ndarray]:
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    found = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st1")
        if pv and pv.HasAuthoredValue():
            found[str(prim.GetPath())] = np.array(pv.Get(), dtype=np.float64)
    return found


def test_st1_corners_land_on_hirads_texels_through_godots_rect_and_unitys_scale_offset(baked):
    out, manifest, _ = baked
    sizes = [(p["width"], p["height"]) for p in manifest["pages"]]
    slice_size = (max(w for w, _ in sizes), max(h for _, h in sizes))
    st1 = _original_st1(out)
    checked = 0
    for inst in manifest["instances"]:
        uv = st1[inst["mesh"]]
        so = np.asarray(inst["scaleOffset"], float)
        page_size = sizes[inst["page"]]
        page_uv = uv * so[:2] + so[2:]             # hirad's convention, USD (and Unity) UVs
        expect = _hirad_pixel(page_uv, page_size)  # the texel position in the page image
        assert (page_uv >= -1e-6).all() and (page_uv <= 1 + 1e-6).all(), inst["prim"]
        uv2 = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)  # glTF TEXCOORD_1 = Godot UV2
        for sl in (slice_size, (2 * slice_size[0], 2 * slice_size[1])):
            got = _godot_pixel(uv2, derived_rect(so, page_size, sl), sl)
            # the page sits at the slice's top-left: its pixel (x, y) is the slice's (x, y)
            assert np.abs(got - expect).max() < 1e-6 * max(sl), (inst["prim"], sl)
        # Unity: lightmapScaleOffset = scaleOffset, uv2 = st1 (bottom-left), Unity's texture
        # row for v is (1 - v) * h from the top, as hirad's: the same pixel with no flip
        unity = _hirad_pixel(uv * so[:2] + so[2:], page_size)
        assert np.abs(unity - expect).max() == 0.0
        checked += len(uv)
    assert checked > 0
    # the bake made pages of more than one size, or at least several pages
    assert len(sizes) >= 2, sizes


def test_the_scripts_rect_expression_is_the_derived_one(baked):
    _, manifest, _ = baked
    gd = GODOT.read_text()
    body = gd[gd.index("static func godot_uv_scale"):]
    expr = re.search(r"return (Rect2\(.*\))\n", body).group(1)
    rng = np.random.default_rng(7)
    cases = [inst["scaleOffset"] for inst in manifest["instances"]] + rng.uniform(0.01, 0.5, (20, 4)).tolist()
    for so in cases:
        for page, sl in (((64, 64), (64, 64)), ((32, 64), (64, 128)), ((16, 16), (128, 64))):
            kx, ky = page[0] / sl[0], page[1] / sl[1]
            ns = {"Rect2": lambda *a: np.array(a, float), "sx": so[0], "sy": so[1], "ox": so[2], "oy": so[3],
                  "kx": kx, "ky": ky, "__builtins__": {}}
            got = eval(expr, ns)  # noqa: S307 - the script's own arithmetic, with no builtins
            assert np.allclose(got, derived_rect(so, page, sl), rtol=0, atol=1e-12), (expr, so, page, sl)


def _glb_lightmap_meshes(glb: Path) -> dict[str, dict]:
    """Per node with a lightmap (by extras.hirad_path): world positions (the GLB is Y up, metres,
    as the test scene), TEXCOORD_1 and triangles."""
    import pygltflib

    g = pygltflib.GLTF2().load(str(glb))
    blob = g.binary_blob()

    def read(idx):
        acc = g.accessors[idx]
        view = g.bufferViews[acc.bufferView]
        comps = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc.type]
        dtype = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}[acc.componentType]
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        stride = view.byteStride or comps * np.dtype(dtype).itemsize
        raw = np.frombuffer(blob, dtype=np.uint8, count=stride * (acc.count - 1) + comps * np.dtype(dtype).itemsize,
                            offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, shape=(acc.count, comps * np.dtype(dtype).itemsize),
                                               strides=(stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(acc.count, comps).astype(np.float64)

    found = {}
    for node in g.nodes:
        extras = node.extras or {}
        if node.mesh is None or "hirad_lightmap" not in extras:
            continue
        prim = g.meshes[node.mesh].primitives[0]
        assert prim.attributes.TEXCOORD_1 is not None, node.name
        assert node.matrix is None and node.translation is None and node.rotation is None and node.scale is None
        found[extras["hirad_path"]] = {
            "name": node.name,
            "pos": read(prim.attributes.POSITION),
            "uv1": read(prim.attributes.TEXCOORD_1),
            "tri": read(prim.indices).astype(np.int64).reshape(-1, 3),
            "extras": extras["hirad_lightmap"],
        }
    return found


def _solution_faces(out: Path) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Per source prim: (face centroid in world metres, the face's mean hirad:lightmapUV) of every
    face of hirad's solution meshes."""
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    xfc = UsdGeom.XformCache()
    faces: dict[str, list] = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("hirad:lightmapUV")
        src = prim.GetCustomDataByKey("hirad:sourcePath")
        if not pv or not pv.HasAuthoredValue() or src is None:
            continue
        mesh = UsdGeom.Mesh(prim)
        m = np.array(xfc.GetLocalToWorldTransform(prim), dtype=np.float64)
        pts = np.array(mesh.GetPointsAttr().Get(), dtype=np.float64) @ m[:3, :3] + m[3, :3]
        counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
        idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
        uv = np.array(pv.Get(), dtype=np.float64)
        assert len(uv) == len(idx)
        s = 0
        for c in counts:
            faces.setdefault(str(src), []).append((pts[idx[s:s + c]].mean(axis=0), uv[s:s + c].mean(axis=0)))
            s += c
    return faces


def _locate(points: np.ndarray, tri: np.ndarray, tri_uv: np.ndarray, what: str) -> np.ndarray:
    """The UV at each point (N, 3), interpolated in the triangle (T, 3, 3) it lies in."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    d00, d01, d11 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    den = d00 * d11 - d01 * d01
    out = np.empty((len(points), 2))
    tol = 1e-5 * max(1.0, float(np.abs(tri).max()))  # float32 coordinates in the files
    for k, x in enumerate(points):
        d = x - tri[:, 0]
        off_plane = np.abs(np.einsum("ij,ij->i", d, n)) / np.linalg.norm(n, axis=1)
        d20, d21 = (d * e1).sum(1), (d * e2).sum(1)
        b1 = (d11 * d20 - d01 * d21) / den
        b2 = (d00 * d21 - d01 * d20) / den
        b0 = 1 - b1 - b2
        inside = (off_plane < tol) & (b0 > -1e-5) & (b1 > -1e-5) & (b2 > -1e-5)
        assert inside.any(), (what, x)
        t = int(np.flatnonzero(inside)[0])
        out[k] = b0[t] * tri_uv[t, 0] + b1[t] * tri_uv[t, 1] + b2[t] * tri_uv[t, 2]
    return out


def _usd_uv2_triangles(out: Path, inst: dict) -> tuple[np.ndarray, np.ndarray]:
    """World triangles of the instance (fans of its authored faces) and Godot's UV2 at their
    corners: the prototype's st1 with glTF's flip, (u, 1 - v). A PointInstancer copy is the
    prototype moved by its position (the test scene's copies are translations only)."""
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    proto = stage.GetPrimAtPath(inst["mesh"])
    mesh = UsdGeom.Mesh(proto)
    m = np.array(UsdGeom.XformCache().GetLocalToWorldTransform(proto), dtype=np.float64)
    pts = np.array(mesh.GetPointsAttr().Get(), dtype=np.float64) @ m[:3, :3] + m[3, :3]
    copy = re.search(r"/instance_(\d+)/", inst["prim"])
    if inst["prim"] != inst["mesh"]:
        assert copy, inst
        instancer = UsdGeom.PointInstancer(stage.GetPrimAtPath(inst["prim"][:inst["prim"].index("/instance_")]))
        pts = pts + np.array(instancer.GetPositionsAttr().Get()[int(copy.group(1))], dtype=np.float64)
    counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
    idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
    st1 = np.array(UsdGeom.PrimvarsAPI(proto).GetPrimvar("st1").Get(), dtype=np.float64)
    uv2 = np.stack([st1[:, 0], 1.0 - st1[:, 1]], axis=1)
    tris, uvs = [], []
    s0 = 0
    for c in counts:
        for k in range(1, c - 1):
            slots = [s0, s0 + k, s0 + k + 1]
            tris.append(pts[idx[slots]])
            uvs.append(uv2[slots])
        s0 += c
    return np.array(tris), np.array(uvs)


def test_uv2_through_godots_rect_meets_the_solution_meshes_page_uvs(baked):
    """Two routes to Godot's UV2 (the GLB's TEXCOORD_1 where the GLB has the node; st1 on the
    original prims with the flip, for every instance, PointInstancer copies included), each
    through the derived Rect2, against hirad's page UVs of its solution meshes."""
    out, manifest, glb = baked
    sizes = [(p["width"], p["height"]) for p in manifest["pages"]]
    slice_size = (max(w for w, _ in sizes), max(h for _, h in sizes))
    glb_meshes = _glb_lightmap_meshes(glb)
    faces = _solution_faces(out)
    compared = {"glb": 0, "usd": 0}
    nontrivial = 0
    for inst in manifest["instances"]:
        prim = inst["prim"]
        assert prim in faces, f"{prim}: no solution mesh carries its lightmap UVs"
        centroids = np.array([c for c, _ in faces[prim]])
        expect = _hirad_pixel(np.array([uv for _, uv in faces[prim]]), sizes[inst["page"]])
        rect = derived_rect(inst["scaleOffset"], sizes[inst["page"]], slice_size)
        nontrivial += not np.allclose(inst["scaleOffset"], [1, 1, 0, 0])
        routes = {"usd": _usd_uv2_triangles(out, inst)}
        # hirad's GLB exports every mesh, a PointInstancer's copies each as a node of its own
        assert prim in glb_meshes, f"{prim}: not in the GLB"
        if True:
            gm = glb_meshes[prim]
            # hirad's GLB names each node by its prim path: the scripts' name rules start from that
            assert gm["name"] == prim
            routes["glb"] = (gm["pos"][gm["tri"]], gm["uv1"][gm["tri"]])
            # the GLB's own rectangle is the page rectangle in glTF's flip (no slice embedding)
            page_rect = derived_rect(inst["scaleOffset"], sizes[inst["page"]], sizes[inst["page"]])
            assert np.allclose(gm["extras"]["scaleOffset"], page_rect[[2, 3, 0, 1]], atol=1e-7)
        for route, (tri, tri_uv) in routes.items():
            uv2 = _locate(centroids, tri, tri_uv, f"{prim} ({route})")
            got = _godot_pixel(uv2, rect, slice_size)
            # float32 UVs in the files: well under a hundredth of a texel
            err = np.abs(got - expect).max()
            assert err < 1e-2, (prim, route, err)
            compared[route] += len(centroids)
    assert compared["glb"] >= 20 and compared["usd"] == compared["glb"], compared
    assert nontrivial >= 2, "the scene must give some instances a real scale and offset"


def test_the_godot_name_rule_tells_the_glb_nodes_apart(baked):
    """Godot drops some characters from node names (String.validate_node_name); the script
    compares names with those (and "_") removed. The characters are read from the script's
    _canonical; every lightmapped GLB node must still have a name of its own after that, and the
    instance's prim must map to its own node."""
    _, manifest, glb = baked
    gd = GODOT.read_text()
    body = gd[gd.index("static func _canonical"):]
    chars = re.findall(r'"((?:\\.|[^"\\])+)"', body[:body.index("return out")])
    chars = [c.encode().decode("unicode_escape") for c in chars]
    assert set(chars) >= {".", ":", "@", "/", '"', "%"}, chars

    def canonical(name: str) -> str:
        for c in chars:
            name = name.replace(c, "")
        return name

    nodes = _glb_lightmap_meshes(glb)
    names = [canonical(n["name"]) for n in nodes.values()]
    assert len(set(names)) == len(names), sorted(names)
    for inst in manifest["instances"]:
        if inst["prim"] in nodes:
            assert canonical(inst["prim"]) == canonical(nodes[inst["prim"]]["name"])
            assert sum(canonical(inst["prim"]) == n for n in names) == 1
