"""Lightmaps on an atlas (outputs.lightmaps), checked from the outputs alone: the page EXRs,
the manifest, and the solution layer's faceVarying hirad:lightmapUV on each solved mesh.

The scene: a ground plane (4 m x 4 m, with its own `st` UVs), a hollow box whose walls are
one texel thick (outer cube faces out, inner cube faces in, one mesh), an open cylinder (a
curved surface xatlas must cut: UV seams on a smooth surface), and an emitter overhead. Every
texel centre is mapped back to 3D here, by brute force over the solved faces' UV polygons,
without the bake's own atlas code."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("xatlas")
from hirad_e2e_helpers import add_material, add_mesh, new_stage, write_config  # noqa: E402
from pxr import Usd, UsdGeom, UsdShade  # noqa: E402

from hirad import __version__, _engine  # noqa: E402
from hirad.config import ConfigError
from hirad.bake import BakeError, bake  # noqa: E402

TPM = 20.0  # texels per metre
PADDING = 2
THICK = 1.0 / TPM  # the box's walls: one texel
BOX_C = np.array([-0.9, 0.65, 0.0])
BOX_H = 0.5  # outer half size


def cube(centre, half, outward):
    """8 shared corners and 6 quads, wound to face outwards (or inwards)."""
    c = np.asarray(centre, float)
    p = np.array([c + half * np.array([x, y, z]) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    out = []
    for q in quads:
        a, b, cc = p[q[0]], p[q[1]], p[q[2]]
        n = np.cross(b - a, cc - a)
        centre_of_face = p[q].mean(axis=0)
        facing_out = np.dot(n, centre_of_face - c) > 0
        out.append(q if facing_out == outward else q[::-1])
    return p, out


def build_scene(path: Path) -> Path:
    stage = new_stage(path)
    grey = add_material(stage, "/World/Looks/grey", (0.6, 0.6, 0.6))
    lamp = add_material(stage, "/World/Looks/lamp", (0.0, 0.0, 0.0), (10.0, 10.0, 10.0))
    # ground, facing +Y, with authored lightmap UVs
    g = np.array([[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]], float)
    ground = add_mesh(stage, "/World/ground", g, [4], [0, 1, 2, 3], grey)
    st = UsdGeom.PrimvarsAPI(ground).CreatePrimvar("st", Sdf_tex2(), UsdGeom.Tokens.vertex)
    st.Set([((2 - z) / 4, (x + 2) / 4) for x, _, z in g])
    # hollow box: outer faces out, inner faces in, one mesh
    po, qo = cube(BOX_C, BOX_H, True)
    pi_, qi = cube(BOX_C, BOX_H - THICK, False)
    pts = np.concatenate([po, pi_])
    quads = qo + [[k + 8 for k in q] for q in qi]
    add_mesh(stage, "/World/shell", pts, [4] * 12, [k for q in quads for k in q], grey)
    # open cylinder, outward
    n, r, c = 24, 0.4, np.array([0.9, 0.0, 0.3])
    ring = [c + [r * math.cos(2 * math.pi * k / n), 0, r * math.sin(2 * math.pi * k / n)] for k in range(n)]
    cyl = [p + [0, 0.02, 0] for p in ring] + [p + [0, 1.0, 0] for p in ring]
    faces = []
    for k in range(n):
        q = [k, (k + 1) % n, n + (k + 1) % n, n + k]
        a, b, cc = (np.asarray(cyl[i]) for i in q[:3])
        if np.dot(np.cross(b - a, cc - a), a - c - [0, a[1], 0]) < 0:
            q = q[::-1]
        faces.append(q)
    add_mesh(stage, "/World/cylinder", cyl, [4] * n, [k for q in faces for k in q], grey)
    # emitter overhead, facing down
    e = np.array([[-0.75, 2.5, -0.75], [0.75, 2.5, -0.75], [0.75, 2.5, 0.75], [-0.75, 2.5, 0.75]])
    add_mesh(stage, "/World/lamp", e, [4], [0, 1, 2, 3], lamp)
    stage.GetRootLayer().Save()
    return path


def Sdf_tex2():
    from pxr import Sdf

    return Sdf.ValueTypeNames.TexCoord2fArray


# the ground's `st` is its lightmap set here: the config names it (never by default)
LIGHTMAPS = {"texels_per_metre": TPM, "padding": PADDING, "max_size": 128, "supersample": 2, "uv_primvars": ["st"]}
MESHING = {"max_patch_area": 0.0625, "max_edge_length": 0.25}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("lightmaps")
    return root, build_scene(root / "scene.usda")


@pytest.fixture(scope="module")
def flat(scene):
    root, path = scene
    cfg = write_config(root / "flat.yaml", path, root / "flat", meshing=MESHING,
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {**LIGHTMAPS, "mode": "interpolate", "rgbm": True}})
    return bake(cfg), root / "flat"


@pytest.fixture(scope="module")
def gathered(scene):
    root, path = scene
    cfg = write_config(root / "hier.yaml", path, root / "hier", method="hierarchical",
                       hierarchy={"epsilon": 1e-3, "min_area": 0.01, "samples": 8, "max_rounds": 3},
                       solver={"method": "jacobi", "tolerance": 1e-3},
                       outputs={"preview": {"enabled": False}, "lightmaps": {**LIGHTMAPS, "mode": "final_gather"}})
    return bake(cfg), root / "hier"


def strided_config(scene, name: str):
    """The `gathered` bake's config with gather_stride 4, writing into root / name."""
    root, path = scene
    return write_config(root / f"{name}.yaml", path, root / name, method="hierarchical",
                        hierarchy={"epsilon": 1e-3, "min_area": 0.01, "samples": 8, "max_rounds": 3},
                        solver={"method": "jacobi", "tolerance": 1e-3},
                        outputs={"preview": {"enabled": False},
                                 "lightmaps": {**LIGHTMAPS, "mode": "final_gather", "gather_stride": 4}})


@pytest.fixture(scope="module")
def strided(scene):
    """The `gathered` bake with gather_stride 4: the same solve (deterministic), texels
    interpolated between gathered ones where they agree."""
    return bake(strided_config(scene, "strided")), scene[0] / "strided"


# ---------------------------------------------------------------------------------------
# reading the outputs back


def solved_meshes(out: Path) -> dict:
    """name -> points, faces (list of corner index arrays), uv per face corner, texture file."""
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    meshes = {}
    for prim in stage.GetPrimAtPath("/World/HiradSolution").GetChildren():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("hirad:lightmapUV")
        assert pv and pv.GetTypeName().role == "TextureCoordinate" and pv.GetInterpolation() == "faceVarying"
        mat = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        tex = UsdShade.Shader(mat.GetPrim().GetChild("Lightmap"))
        assert tex.GetIdAttr().Get() == "UsdUVTexture"
        reader = UsdShade.Shader(mat.GetPrim().GetChild("LightmapUV"))
        assert reader.GetInput("varname").Get() == "hirad:lightmapUV"
        asset = tex.GetInput("file").Get()
        scale = tex.GetInput("scale")
        bias = tex.GetInput("bias")
        counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
        idx = np.array(mesh.GetFaceVertexIndicesAttr().Get())
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        meshes[prim.GetName()] = {
            "points": np.array(mesh.GetPointsAttr().Get(), dtype=np.float64),
            "faces": [idx[s:s + c] for s, c in zip(starts, counts)],
            "uv": [np.array(pv.Get(), dtype=np.float64)[s:s + c] for s, c in zip(starts, counts)],
            "texture": (out / asset.path).resolve(),
            "scale": None if not scale else tuple(scale.Get()),
            "bias": None if not bias else tuple(bias.Get()),
        }
    return meshes


def texel_centres(mesh, width, height, margin=-1e-7):
    """Texel centres inside the mesh's UV faces (barycentrics > margin; chart edges run
    through texel centres, so the default takes those on an edge, once): (x, row, point,
    normal, face) arrays."""
    xs, rows, pts, nrm, fid, jac = [], [], [], [], [], []
    for f, (face, uv) in enumerate(zip(mesh["faces"], mesh["uv"])):
        p3 = mesh["points"][face]
        n = np.cross(p3[1] - p3[0], p3[2] - p3[0])
        n /= np.linalg.norm(n)
        t = uv * [width, height]
        for k in range(1, len(face) - 1):
            tri, tri3 = t[[0, k, k + 1]], p3[[0, k, k + 1]]
            lo = np.floor(tri.min(axis=0)).astype(int)
            hi = np.ceil(tri.max(axis=0)).astype(int)
            gx, gy = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]))
            cen = np.stack([gx.ravel() + 0.5, gy.ravel() + 0.5], axis=1)
            m = np.array([tri[1] - tri[0], tri[2] - tri[0]]).T
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            l12 = np.linalg.solve(m, (cen - tri[0]).T).T
            bary = np.column_stack([1 - l12.sum(axis=1), l12])
            inside = (bary > margin).all(axis=1)
            xs.append(gx.ravel()[inside])
            rows.append(height - 1 - gy.ravel()[inside])
            pts.append(bary[inside] @ tri3)
            # the affine map of this triangle, texel coords -> 3D, for points near the centre
            minv = np.linalg.inv(m)
            jac.append(np.broadcast_to((np.array([tri3[1] - tri3[0], tri3[2] - tri3[0]]).T @ minv), (inside.sum(), 3, 2)))
            nrm.append(np.broadcast_to(n, (inside.sum(), 3)))
            fid.append(np.full(inside.sum(), f))
    cat = np.concatenate
    x, row, pts, nrm, fid, jac = cat(xs), cat(rows), cat(pts), cat(nrm), cat(fid), cat(jac)
    _, first = np.unique(np.stack([x, row], axis=1), axis=0, return_index=True)
    first = np.sort(first)
    texel_centres.jacobian = jac[first]  # (T, 3, 2): d(3D)/d(texel coords, v up)
    return x[first], row[first], pts[first], nrm[first], fid[first]


def charts_of(mesh):
    """Chart id per face: faces joined where they share a corner UV (and that corner)."""
    parent = list(range(len(mesh["faces"])))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    seen = {}
    for f, (face, uv) in enumerate(zip(mesh["faces"], mesh["uv"])):
        for v, c in zip(face, uv):
            key = (tuple(np.round(mesh["points"][v], 5)), tuple(np.round(c, 6)))
            if key in seen:
                parent[find(f)] = find(seen[key])
            else:
                seen[key] = f
    return np.array([find(f) for f in range(len(mesh["faces"]))])


def load_pages(out):
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    pages = {}
    for p in manifest["pages"]:
        path = (out / "lightmaps" / p["file"]).resolve()
        pages[path] = _engine.read_exr(str(path))
    return manifest, pages


# ---------------------------------------------------------------------------------------
# tests


def test_manifest_files_and_metadata(flat):
    import OpenEXR

    result, out = flat
    manifest, pages = load_pages(out)
    assert manifest["format"] == "hirad-lightmap-atlas" and manifest["hirad:version"] == __version__
    assert manifest["texelsPerMetre"] == TPM and manifest["padding"] == PADDING
    assert len(manifest["pages"]) >= 2  # 128-texel pages cannot hold the 4 m ground and the rest
    for p, (path, img) in zip(manifest["pages"], pages.items()):
        assert img.shape[:2] == (p["height"], p["width"]) and max(img.shape[:2]) <= 128
        header = OpenEXR.File(str(path)).header()
        assert "incident" in header["hirad:units"] and "H/pi" in header["hirad:units"]
        assert header["hirad:version"] == __version__
        assert header["hirad:sceneFingerprint"] == manifest["sceneFingerprint"] and len(manifest["sceneFingerprint"]) == 64
        png, rng = __import__("hirad.atlas", fromlist=["read_rgbm_png"]).read_rgbm_png(
            path.with_suffix(".png"))
        np.testing.assert_allclose(png, img, atol=rng / 255 * 1.01 + 1e-3)  # RGBM is 8-bit
    meshes = manifest["meshes"]
    assert set(meshes) == {"World_ground", "World_shell", "World_cylinder", "World_lamp"}
    solved = solved_meshes(out)
    for name, m in meshes.items():
        assert (out / "lightmaps" / m["file"]).is_file()
        assert solved[name]["texture"] == (out / "lightmaps" / m["file"]).resolve()
        assert m["texelsPerMetre"] == pytest.approx(TPM, rel=0.05)
    # a viewer shows albedo x lightmap (+ emitted radiance on the lamp): UsdUVTexture scale / bias
    np.testing.assert_allclose(solved["World_shell"]["scale"], (0.6, 0.6, 0.6, 1.0), rtol=1e-6)
    assert solved["World_shell"]["bias"] is None
    np.testing.assert_allclose(solved["World_lamp"]["bias"][:3], 10.0, rtol=1e-5)  # E/pi = authored radiance
    assert meshes["World_ground"]["uvSource"] == "existing"
    assert meshes["World_shell"]["uvSource"] == meshes["World_cylinder"]["uvSource"] == "generated"
    assert meshes["World_shell"]["scaleOffset"] == [1.0, 1.0, 0.0, 0.0]
    # lightmapScaleOffset maps the ground's own st to its page UVs (st = ((2-z)/4, (x+2)/4))
    sx, sy, ox, oy = meshes["World_ground"]["scaleOffset"]
    g = solved["World_ground"]
    for face, uv in zip(g["faces"], g["uv"]):
        p = g["points"][face]
        st = np.stack([(2 - p[:, 2]) / 4, (p[:, 0] + 2) / 4], axis=1)
        np.testing.assert_allclose(st * [sx, sy] + [ox, oy], uv, atol=1e-6)
    assert sorted(result.report["outputs"]["lightmaps"]) == sorted(
        f"lightmaps/{n}.exr" for n in meshes)  # per-mesh cut-outs as well
    assert result.report["outputs"]["lightmap_atlas"]["texels_per_metre"] == TPM


def test_texel_density_and_padding(flat):
    _, out = flat
    manifest, pages = load_pages(out)
    solved = solved_meshes(out)
    by_page = {}
    for name, mesh in solved.items():
        img = pages[mesh["texture"]]
        h, w = img.shape[:2]
        chart = charts_of(mesh)
        area3 = np.zeros(chart.max() + 1)
        area2 = np.zeros(chart.max() + 1)
        for f, (face, uv) in enumerate(zip(mesh["faces"], mesh["uv"])):
            p, t = mesh["points"][face], uv * [w, h]
            for k in range(1, len(face) - 1):
                area3[chart[f]] += 0.5 * np.linalg.norm(np.cross(p[k] - p[0], p[k + 1] - p[0]))
                d1, d2 = t[k] - t[0], t[k + 1] - t[0]
                area2[chart[f]] += 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])
        used = area3 > 1e-9
        density = np.sqrt(area2[used] / area3[used])
        # xatlas rounds each chart's extent up to whole texels: denser by less than a texel
        assert (density > TPM * 0.999).all() and (density < TPM * 1.1).all(), (name, density)
        x, row, _, _, f = texel_centres(mesh, w, h)
        for c in np.unique(chart[f]):
            by_page.setdefault(mesh["texture"], []).append(
                {(int(a), int(b)) for a, b in zip(x[chart[f] == c], row[chart[f] == c])})
    measured = 0
    for path, charts in by_page.items():
        if len(charts) < 2:
            continue  # a page holding one chart (the ground)
        measured += 1
        gaps = []
        for i in range(len(charts)):
            a = np.array(sorted(charts[i]))
            for j in range(i + 1, len(charts)):
                b = np.array(sorted(charts[j]))
                gaps.append(int(np.abs(a[:, None] - b[None]).max(axis=2).min()) - 1)
        # texels whose centre a chart covers are a subset of the texels it touches, so the
        # gap seen this way is the padding asked for, or up to a texel more on each side
        assert PADDING <= min(gaps) <= PADDING + 2, (path.name, min(gaps))
    assert measured >= 1


def test_texel_centres_match_the_solution(flat):
    result, out = flat
    _, pages = load_pages(out)
    checked = 0
    for name, mesh in solved_meshes(out).items():
        img = pages[mesh["texture"]]
        h, w = img.shape[:2]
        x, row, pts, nrm, f = texel_centres(mesh, w, h)
        chart = charts_of(mesh)[f]
        # away from chart borders (seam stitching moves those): all 8 neighbours in the chart
        key = {(a, b): c for a, b, c in zip(x, row, chart)}
        interior = np.array([all(key.get((a + dx, b + dy)) == c for dx in (-1, 0, 1) for dy in (-1, 0, 1))
                             for a, b, c in zip(x, row, chart)])
        # the texel is the mean of H/pi over its 2 x 2 strata (the centre value when
        # supersample is 1): their 3D points from the texel's own affine UV map
        jac = texel_centres.jacobian[interior]
        offsets = np.array([[-0.25, -0.25], [0.25, -0.25], [-0.25, 0.25], [0.25, 0.25]])
        expected = np.mean([result.irradiance_at(pts[interior] + jac @ o, nrm[interior]) for o in offsets],
                           axis=0) / math.pi
        at_centre = result.irradiance_at(pts[interior], nrm[interior]) / math.pi
        got = img[row[interior], x[interior]]
        smooth = np.abs(expected - at_centre).max(axis=1) <= 0.005 * np.abs(at_centre).max(axis=1) + 1e-6
        assert smooth.mean() > 0.9
        # and where the solution is smooth across the texel, that is the centre value
        np.testing.assert_allclose(got[smooth], at_centre[smooth], rtol=0.02, atol=1e-3 * max(1e-6, float(at_centre.max())))
        scale = max(1e-6, float(expected.max()))
        np.testing.assert_allclose(got, expected, rtol=0.02, atol=1e-3 * scale, err_msg=name)
        checked += int(interior.sum())
    assert checked > 3000


def test_no_light_leaks_into_the_closed_box(flat, gathered, strided):
    for result, out in (flat, gathered, strided):
        _, pages = load_pages(out)
        shell = solved_meshes(out)["World_shell"]
        img = pages[shell["texture"]]
        h, w = img.shape[:2]
        x, row, pts, nrm, f = texel_centres(shell, w, h)
        inner = np.einsum("kd,kd->k", nrm, pts - BOX_C) < 0  # faces looking at the box centre
        top = ~inner & (nrm[:, 1] > 0.9)
        assert inner.sum() > 6 * 17 * 17 and top.sum() > 19 * 19
        lit = float(img[row[top], x[top]].mean())
        assert lit > 0.05  # the lamp (radiance 10) lights the box's top
        dark = img[row[inner], x[inner]]
        assert float(dark.max()) <= 1e-3 * lit, (out.name, float(dark.max()), lit)


def face_normal(corners: np.ndarray) -> np.ndarray:
    """Newell's normal of a polygon, unit length."""
    n = np.cross(corners, np.roll(corners, -1, axis=0)).sum(axis=0)
    return n / np.linalg.norm(n)


def test_seams_are_continuous(flat):
    """Across UV seams of a smooth surface (the cylinder's 15-degree facets, normals within the
    default crease_angle of 30 degrees) both sides read the same light within 2 %."""
    _, out = flat
    _, pages = load_pages(out)
    worst, pairs = 0.0, 0
    for name in ("World_cylinder", "World_shell"):
        mesh = solved_meshes(out)[name]
        img = pages[mesh["texture"]]
        h, w = img.shape[:2]
        edges = {}
        for f, (face, uv) in enumerate(zip(mesh["faces"], mesh["uv"])):
            for k in range(len(face)):
                a, b = mesh["points"][face[k]], mesh["points"][face[(k + 1) % len(face)]]
                key = tuple(sorted([tuple(np.round(a, 5)), tuple(np.round(b, 5))]))
                edges.setdefault(key, []).append((f, uv[k], uv[(k + 1) % len(face)], a))
        for key, sides in edges.items():
            if len(sides) != 2:
                continue
            (fa, a0, a1, pa), (fb, b0, b1, pb) = sides
            if not np.allclose(pa, pb, atol=1e-5):  # make side b run the same way as side a
                b0, b1 = b1, b0
            if np.abs(a0 - b0).max() < 1e-6 and np.abs(a1 - b1).max() < 1e-6:
                continue  # not a seam
            na, nb = mesh["faces"][fa], mesh["faces"][fb]
            if np.dot(face_normal(mesh["points"][na]), face_normal(mesh["points"][nb])) < math.cos(math.radians(30)):
                continue  # a crease (the shell's edges): each side keeps its own light, not a seam to hide
            ca, cb = mesh["uv"][fa].mean(axis=0), mesh["uv"][fb].mean(axis=0)
            n_t = int(np.ceil(max(np.linalg.norm((a1 - a0) * [w, h]), 1.0))) * 2
            for t in (np.arange(n_t) + 0.5) / n_t:
                def at(u0, u1, cen):
                    p = (u0 + t * (u1 - u0)) * [w, h]
                    p += 1e-3 * (cen * [w, h] - p) / np.linalg.norm(cen * [w, h] - p)
                    return img[h - 1 - int(np.floor(p[1])), int(np.floor(p[0]))]
                va, vb = at(a0, a1, ca), at(b0, b1, cb)
                local = max(float(np.abs(va).max()), float(np.abs(vb).max()), 1e-6)
                worst = max(worst, float(np.abs(va - vb).max()) / local)
                pairs += 1
    assert pairs > 100
    assert worst < 0.02, worst


def test_final_gather_needs_a_hierarchy(scene):
    root, path = scene
    cfg = write_config(root / "bad.yaml", path, root / "bad", meshing=MESHING,
                       outputs={"preview": {"enabled": False}, "lightmaps": {**LIGHTMAPS, "mode": "final_gather"}})
    # Refused when the config is read, before anything is solved.
    with pytest.raises(ConfigError, match="final_gather needs method: hierarchical"):
        bake(cfg)
    assert not (root / "bad").exists()


def test_throughput_is_reported(flat, gathered):
    for result, _ in (flat, gathered):
        info = result.report["outputs"]["lightmap_atlas"]
        assert info["covered_texels"] > 0 and info["texels_per_second"] > 0
        assert all(0 < f <= 1 for f in info["fill"])
        print(f"\n{info['mode']}: {info['texels_per_second']:.0f} texels/s, fill {info['fill']}, "
              f"{info['page_bytes_half_rgb']} bytes, moved samples {info['moved_samples']}")


def test_a_strided_gather_matches_the_gather_of_every_texel(gathered, strided):
    """gather_stride 4 interpolates most texels, and the pages stay those of the full gather:
    the texels it interpolates lie between gathered ones that agree within gather_tolerance
    (5 %), so they may differ from their own gather by about that, plus the gather's noise,
    which both bakes have (another seed per texel)."""
    info = strided[0].report["outputs"]["lightmap_atlas"]
    assert info["gather_stride"] == 4 and info["gather_tolerance"] == 0.05
    assert info["interpolated_texels"] > 0.25 * info["covered_texels"], info
    assert info["samples"] < 0.75 * gathered[0].report["outputs"]["lightmap_atlas"]["samples"]
    m_full, p_full = load_pages(gathered[1])
    m_strided, p_strided = load_pages(strided[1])
    assert [p["file"] for p in m_full["pages"]] == [p["file"] for p in m_strided["pages"]]
    rel = []
    for (a_path, a), b in zip(p_full.items(), p_strided.values()):
        la, lb = np.asarray(a)[..., :3].mean(axis=2), np.asarray(b)[..., :3].mean(axis=2)
        lit = la > 0.05 * la.max()
        rel.append(np.abs(lb[lit] / la[lit] - 1.0))
    rel = np.concatenate(rel)
    print(f"\nstrided vs every texel: {len(rel)} lit texels, mean |diff| {rel.mean():.3%}, "
          f"p95 {np.quantile(rel, 0.95):.3%}, max {rel.max():.3%}; interpolated {info['interpolated_texels']} of "
          f"{info['covered_texels']}")
    assert len(rel) > 1000
    assert rel.mean() < 0.02
    assert np.mean(rel > 0.10) < 0.01


def test_a_strided_gather_is_the_same_bits_on_one_thread(scene, strided):
    """Which texels a strided gather interpolates depends on the gathered values alone, and
    those do not depend on the threads: one thread writes the same pages, byte for byte."""
    root = scene[0]
    one = bake(strided_config(scene, "strided1"), threads=1)
    assert one.report["threads"] == 1
    a = sorted((strided[1] / "lightmaps" / "pages").glob("*.exr"))
    b = sorted((root / "strided1" / "lightmaps" / "pages").glob("*.exr"))
    assert a and [p.name for p in a] == [p.name for p in b]
    for pa, pb in zip(a, b):
        assert pa.read_bytes() == pb.read_bytes(), pa.name
    assert one.report["outputs"]["lightmap_atlas"]["gathered_texels"] == \
        strided[0].report["outputs"]["lightmap_atlas"]["gathered_texels"]


# ---------------------------------------------------------------------------------------
# a room standing on the ground: walls and roof one texel thick, the ground running under
# the walls into the room (the common cause of leaks: floor texels that reach under a wall)

ROOM_TPM = 16.0
ROOM_T = 1.0 / ROOM_TPM
ROOM = (-1.5, -0.5, -0.5, 0.5)  # outer footprint x0, x1, z0, z1 (on the hierarchy's element grid)
ROOM_TOP = 0.6


def open_box(x0, x1, y0, y1, z0, z1, outward):
    """Five faces (no bottom) of a box with shared corners, facing out or in."""
    c = np.array([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2])
    p, quads = cube(c, 1.0, outward)
    p = np.array([[x0 if q[0] < c[0] else x1, y0 if q[1] < c[1] else y1, z0 if q[2] < c[2] else z1] for q in p])
    keep = [q for q in quads if not (p[q][:, 1] == y0).all()]
    return p, keep


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("room")
    stage = new_stage(root / "room.usda")
    grey = add_material(stage, "/World/Looks/grey", (0.6, 0.6, 0.6))
    lamp = add_material(stage, "/World/Looks/lamp", (0.0, 0.0, 0.0), (10.0, 10.0, 10.0))
    g = np.array([[-2, 0, -2], [-2, 0, 2], [2, 0, 2], [2, 0, -2]], float)
    add_mesh(stage, "/World/ground", g, [4], [0, 1, 2, 3], grey)
    x0, x1, z0, z1 = ROOM
    po, qo = open_box(x0, x1, 0.0, ROOM_TOP + ROOM_T, z0, z1, True)
    pi_, qi = open_box(x0 + ROOM_T, x1 - ROOM_T, 0.0, ROOM_TOP, z0 + ROOM_T, z1 - ROOM_T, False)
    quads = qo + [[k + 8 for k in q] for q in qi]
    add_mesh(stage, "/World/room", np.concatenate([po, pi_]), [4] * len(quads), [k for q in quads for k in q], grey)
    e = np.array([[-0.75, 2.5, -0.75], [0.75, 2.5, -0.75], [0.75, 2.5, 0.75], [-0.75, 2.5, 0.75]])
    add_mesh(stage, "/World/lamp", e, [4], [0, 1, 2, 3], lamp)
    stage.GetRootLayer().Save()
    # The ordinary tolerance of 1e-3: the first rounds' coarse links (to ground elements
    # reaching under the walls into the room) put light inside that the final links no longer
    # carry. When each round's solve started from the last round's radiosity, a solve stopped at
    # 1e-3 left that light there (inner walls at 0.4 % of the ground outside); every round now
    # starts from the emission, so no light is inside unless a final link carries it.
    cfg = write_config(root / "room.yaml", root / "room.usda", root / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-5, "min_area": 0.005, "samples": 16, "max_rounds": 6},
                       solver={"method": "jacobi", "tolerance": 1e-3},
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {"texels_per_metre": ROOM_TPM, "padding": 2, "max_size": 256,
                                              "supersample": 2, "mode": "final_gather"}})
    return bake(cfg, keep_hierarchy=True), root / "out"  # (result.gather below)


def test_no_light_under_the_walls_of_a_room(room):
    result, out = room
    _, pages = load_pages(out)
    ground = solved_meshes(out)["World_ground"]
    img = pages[ground["texture"]]
    h, w = img.shape[:2]
    x, row, pts, _, _ = texel_centres(ground, w, h)
    x0, x1, z0, z1 = ROOM
    inside = ((pts[:, 0] > x0 + ROOM_T) & (pts[:, 0] < x1 - ROOM_T) & (pts[:, 2] > z0 + ROOM_T)
              & (pts[:, 2] < z1 - ROOM_T))
    outside = (pts[:, 0] < x0 - 0.25) | (pts[:, 0] > x1 + 0.25) | (np.abs(pts[:, 2]) > z1 + 0.25)
    assert inside.sum() >= 13 * 13
    lit = float(img[row[outside], x[outside]].mean())
    assert lit > 0.05
    # samples under the walls were found and moved (to the room side of their texels)
    assert result.report["outputs"]["lightmap_atlas"]["moved_samples"] > 100
    dark = img[row[inside], x[inside]]
    # Physics: no light reaches the inside of a closed room, and the path-traced reference
    # (hirad.reference, on the scene as authored) says so exactly at points on its floor,
    # walls and ceiling; the lightmap may differ from it only by what the solve's residual
    # leaves: nothing, since a solve from the emission puts light only where links carry it.
    from hirad.reference import reference_at

    cx, cz = (x0 + x1) / 2, (z0 + z1) / 2
    probes = np.array([[cx, 0.0, cz], [cx - 0.2, 0.0, cz + 0.2], [x0 + ROOM_T, 0.3, cz], [cx, 0.3, z1 - ROOM_T],
                       [cx, ROOM_TOP, cz]])
    probe_normals = np.array([[0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 0, -1], [0, -1, 0]], dtype=float)
    ref = reference_at(out.parent / "room.usda", probes, probe_normals, paths=4096, seed=2, max_distance=1e-3)
    assert np.all(ref["radiance"] == 0) and np.all(ref["standard_error"] == 0)
    outside_ref = reference_at(out.parent / "room.usda", [[x1 + 0.5, 0.0, 0.0]], [[0, 1, 0]], paths=1024, seed=2)
    assert outside_ref["radiance"].min() > 0.05  # ... while the reference sees the light outside
    print(f"\nroom: lit {lit:.4g}, darkest-room max {float(dark.max()):.3g}")
    assert float(dark.max()) <= 1e-6 * lit, (float(dark.max()), lit)
    # The other side of the same problem: outside texels half under a wall (their centres
    # on the wall's outer face: the ground's chart starts at a texel centre and the walls
    # stand on the texel grid) would average in the dark under the wall and draw a black
    # line at its foot (about half their value). Their samples under the wall are moved out
    # to the wall's foot, so they keep the value of their visible half (the gathered mean
    # over the 2 x 2 strata outside the wall) within 20 % (the wall's own shadow has a
    # steep gradient there).
    jac = texel_centres.jacobian
    offsets = np.array([[-0.25, -0.25], [0.25, -0.25], [-0.25, 0.25], [0.25, 0.25]])
    step = 1.0 / ROOM_TPM
    ratios = []
    for k, p in enumerate(pts):
        on_x = abs(p[0] - x0) < 1e-4 and z0 + step < p[2] < z1 - step
        on_z = abs(p[2] - z1) < 1e-4 and x0 + step < p[0] < x1 - step
        if not (on_x or on_z):
            continue
        strata = p + offsets @ jac[k].T
        visible = strata[(strata[:, 0] < x0) if on_x else (strata[:, 2] > z1)]
        assert len(visible) == 2
        g = result.gather(visible + [0, 1e-4, 0], np.tile([0.0, 1.0, 0.0], (2, 1)))
        expected = float(g["irradiance"].mean()) / math.pi
        ratios.append(float(img[row[k], x[k]].mean()) / expected)
    assert len(ratios) > 20
    assert min(ratios) > 0.8, sorted(ratios)[:5]
    assert max(ratios) < 1.2, sorted(ratios)[-5:]




def test_final_gather_pages_come_before_the_display_and_the_hierarchy_goes_first(scene, monkeypatch):
    """A bake with final-gather lightmaps bakes their pages right after the solve, from the
    engine's hierarchy, and lets the hierarchy go before the display mesh, the Result and the
    per-mesh output arrays are made (the 1M-triangle kitchen's peak: 4,396 -> 3,093 MiB); the
    pages are tied to the output meshes afterwards. The order is recorded as it happens."""
    import sys

    B = sys.modules["hirad.bake"]
    root, path = scene
    events = []
    real_bake, real_attach, real_display = B.bake_lightmaps, B.attach_lightmaps, B.display_dict

    def bake_pages(*a, tracer=None, **k):
        events.append(("pages", tracer.has_hierarchy))
        events.append(("model", tracer))
        return real_bake(*a, tracer=tracer, **k)

    def display(mesh):
        events.append(("display", None))
        return real_display(mesh)

    def attach(*a, **k):
        events.append(("attach", None))
        return real_attach(*a, **k)

    monkeypatch.setattr(B, "bake_lightmaps", bake_pages)
    monkeypatch.setattr(B, "attach_lightmaps", attach)
    monkeypatch.setattr(B, "display_dict", display)
    cfg = write_config(root / "order.yaml", path, root / "order", method="hierarchical",
                       hierarchy={"epsilon": 1e-3, "min_area": 0.01, "samples": 8, "max_rounds": 3},
                       solver={"method": "jacobi", "tolerance": 1e-3},
                       outputs={"preview": {"enabled": False}, "lightmaps": {**LIGHTMAPS, "mode": "final_gather"}})
    result = bake(cfg)
    names = [e[0] for e in events]
    assert names == ["pages", "model", "display", "attach"], names
    assert events[0][1] is True  # the pages gathered from the solved hierarchy
    model = events[1][1]
    assert model is result._model and not model.has_hierarchy  # let go, and before the display:
    timings = list(result.report["timings_s"])
    assert timings.index("lightmaps") < timings.index("reconstruct") < timings.index("lightmap layout")
    # the layout tied to the meshes afterwards: every instance on a written, lit page
    manifest, pages = load_pages(root / "order")
    assert manifest["mode"] == "final_gather" and manifest["instances"]
    for img in pages.values():
        img = np.asarray(img)
        assert np.isfinite(img).all() and img.max() > 0


def test_final_gather_lightmaps_lift_against_the_engines_own_scene(room):
    """A final gather's lightmaps lift their samples with the engine's patches and BVH
    (lightmaps._tracer), not with a SurfaceField built for it: the same faces, so the same
    samples found inside geometry and the same lifted points, while the field (650 MB on the
    1M-triangle kitchen) is never built by the lightmap stage."""
    from hirad.outputs.lightmaps import _tracer

    result, _ = room
    assert _tracer(result) is result._model
    rng = np.random.default_rng(5)
    x0, x1, z0, z1 = ROOM
    # ground samples inside, outside and under the walls, facing up; wall samples both ways
    n = 4000
    ground = np.column_stack([rng.uniform(x0 - 0.5, x1 + 0.5, n), np.zeros(n), rng.uniform(z0 - 0.5, z1 + 0.5, n)])
    wall = np.column_stack([np.full(n, x0 + ROOM_T), rng.uniform(0, ROOM_TOP, n), rng.uniform(z0, z1, n)])
    points = np.concatenate([ground, wall])
    normals = np.concatenate([np.tile([0.0, 1.0, 0.0], (n, 1)), np.tile([1.0, 0.0, 0.0], (n, 1))])
    reach = 1.0 / ROOM_TPM
    anchors = points + rng.normal(0, 0.05, points.shape)
    for extra in ({}, {"anchors": anchors}):
        mine = result._model.lift_samples(points, normals, 1e-4, reach, **extra)
        field = result.field.lift_samples(points, normals, 1e-4, reach, **extra)
        assert np.asarray(mine.moved).sum() > 100  # samples under the walls were found
        np.testing.assert_array_equal(np.asarray(mine.moved), np.asarray(field.moved))
        # (the two BVHs hold the same faces, one from the leaves and one from the display mesh's
        # welded corners: a hit distance may differ in its last float bits, nanometres)
        np.testing.assert_allclose(np.asarray(mine.points), np.asarray(field.points), rtol=0, atol=1e-7)
    # The vertex gather's enclosure test casts its rays the same way (Engine.ray_cast): rays from
    # the same samples along the normals and 45 degrees off them meet the same surfaces, from
    # the same side, at the same distance (the engine's patches are the leaves, the field's the
    # display faces: their indices differ, their planes do not).
    dirs = np.concatenate([normals, normals + rng.normal(0, 0.5, normals.shape)])
    origins = np.concatenate([points, points]) + 1e-3 * dirs
    mine, field = result._model.ray_cast(origins, dirs), result.field.ray_cast(origins, dirs)
    hit = np.asarray(field.patch) >= 0
    assert hit.sum() > 1000 and (~hit).sum() > 100
    np.testing.assert_array_equal(np.asarray(mine.patch) >= 0, hit)
    np.testing.assert_array_equal(np.asarray(mine.back)[hit], np.asarray(field.back)[hit])
    assert np.asarray(mine.back)[hit].sum() > 100  # samples under the walls see their backs
    # (Embree's single-precision distances: a float's last bit, 1.2e-7 of a metre or so)
    np.testing.assert_allclose(np.asarray(mine.t)[hit], np.asarray(field.t)[hit], rtol=1e-6, atol=1e-7)
    # without the hierarchy kept, it is the field's
    from hirad.solution import Result

    plain = Result(result.corners, result.nv, result.corner_radiance, result.corner_irradiance)
    assert isinstance(_tracer(plain), _engine.SurfaceField)


def test_a_mesh_too_big_for_a_page_is_scaled_down_and_reported(scene):
    root, path = scene
    cfg = write_config(root / "small.yaml", path, root / "small", meshing=MESHING,
                       outputs={"preview": {"enabled": False}, "usd": False,
                                "lightmaps": {**LIGHTMAPS, "max_size": 64}})
    result = bake(cfg)
    manifest = json.loads((root / "small" / "lightmaps" / "manifest.json").read_text())
    # 4 m of ground at 20 texels/m needs 81 texels; a 64 page has 62 inside its border
    assert manifest["meshes"]["World_ground"]["texelsPerMetre"] <= 61 / 4
    assert all(max(p["width"], p["height"]) <= 64 for p in manifest["pages"])
    assert any("World_ground" in w and "scaled down" in w for w in result.report["warnings"])
    assert manifest["meshes"]["World_lamp"]["texelsPerMetre"] == pytest.approx(TPM, rel=0.05)  # 31 texels: fits
