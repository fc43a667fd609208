"""glTF export (hirad.outputs.gltf.write_glb): the GLB of the original meshes with their
lightmaps passes the Khronos glTF Validator, and three.js in headless Chromium, lit only by the
lightmaps, shows what the physics says it must.

The render test builds its own stage: one 1 x 1 quad of albedo rho facing a pinhole camera,
whose lightmap UVs (st1) map it onto a quarter of a synthetic 32 x 32 page through a
scale/offset; that quarter holds four quadrants of known incident radiance L_q = H/pi, the rest
of the page a decoy colour. For a Lambertian surface the exitant radiance is rho * H / pi =
rho * L_q, so the pixel whose camera ray meets the quad at (u, v) must show rho * L_q(u, v),
with (u, v) from the pinhole's closed form (no renderer involved). A wrong V flip swaps the
quadrants top for bottom, a wrong rectangle shows the decoy, a wrong intensity scales all."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

from gltf_helpers import glb_json, render, validate
from hirad import _engine
from hirad.outputs import gltf

ALBEDO = np.array([0.8, 0.6, 0.4])
# incident radiance H/pi (W/(m^2 sr)) of the four quadrants of the quad, (qu, qv) -> RGB
QUAD_L = {(0, 0): (0.9, 0.7, 0.5), (1, 0): (1.5, 1.0, 0.5), (0, 1): (0.2, 0.3, 0.25), (1, 1): (3.0, 2.5, 2.0)}
DECOY = (4.0, 0.0, 4.0)
SCALE_OFFSET = (0.5, 0.5, 0.5, 0.0)   # USD order: page_uv = st1 * xy + zw (bottom-right quarter)
PAGE = 32
DIST = 4.0            # camera distance, stage units
TAN_HALF = 0.2        # vertical aperture 20 mm / (2 x focal 50 mm)


def _page() -> np.ndarray:
    """The page image, row 0 = top (v = 1)."""
    img = np.tile(np.asarray(DECOY, np.float32), (PAGE, PAGE, 1))
    half, q = PAGE // 2, PAGE // 4
    for (qu, qv), val in QUAD_L.items():
        # page u in [0.5 + qu/4, 0.5 + (qu+1)/4) -> columns; page v in [qv/4, (qv+1)/4) -> rows from the bottom
        c0 = half + qu * q
        r1 = PAGE - qv * q
        img[r1 - q:r1, c0:c0 + q] = val
    return img


def _stage(tmp_path, up_axis="Z", mpu=0.5) -> "Path":
    """input.usda (a quad, a camera, a material) and OUT/solution.usda over it with the
    lightmap contract's primvars:st1 and hirad:lightmap:* attributes, plus the page EXR."""
    out = tmp_path / "out"
    (out / "lightmaps" / "pages").mkdir(parents=True)
    stage = Usd.Stage.CreateNew(str(tmp_path / "input.usda"))
    UsdGeom.SetStageUpAxis(stage, up_axis)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    up = np.array([0, 0, 1.0]) if up_axis == "Z" else np.array([0, 1.0, 0])
    depth = np.array([0, 1.0, 0]) if up_axis == "Z" else np.array([0, 0, -1.0])   # away from the camera
    right = np.cross(depth, up)
    assert np.allclose(right, [1, 0, 0])
    corners = [np.zeros(3), right, right + up, up]        # counter-clockwise seen from -depth
    mesh = UsdGeom.Mesh.Define(stage, "/World/quad")
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, c)) for c in corners]))
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mat = UsdShade.Material.Define(stage, "/World/Looks/paint")
    sh = UsdShade.Shader.Define(stage, "/World/Looks/paint/surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*ALBEDO))
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    sh.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(50.0)
    cam.CreateVerticalApertureAttr(20.0)
    cam.CreateHorizontalApertureAttr(20.0)
    eye = 0.5 * right + 0.5 * up - DIST * depth
    m = Gf.Matrix4d(*right, 0, *up, 0, *(-depth), 0, *eye, 1)   # rows: local X, Y, Z, origin
    cam.AddTransformOp().Set(m)
    stage.GetRootLayer().Save()

    layer = Sdf.Layer.CreateNew(str(out / "solution.usda"))
    layer.subLayerPaths.append("../input.usda")
    sol = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(sol, up_axis)          # as hirad's solution layer: the input's metadata
    UsdGeom.SetStageMetersPerUnit(sol, mpu)
    over = sol.OverridePrim("/World/quad")
    pv = UsdGeom.PrimvarsAPI(over).CreatePrimvar("st1", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray([Gf.Vec2f(0, 0), Gf.Vec2f(1, 0), Gf.Vec2f(1, 1), Gf.Vec2f(0, 1)]))
    over.CreateAttribute("hirad:lightmap:page", Sdf.ValueTypeNames.Int, True).Set(0)
    over.CreateAttribute("hirad:lightmap:file", Sdf.ValueTypeNames.Asset, True).Set(
        Sdf.AssetPath("./lightmaps/pages/page0.exr"))
    over.CreateAttribute("hirad:lightmap:scaleOffset", Sdf.ValueTypeNames.Float4, True).Set(Gf.Vec4f(*SCALE_OFFSET))
    layer.Save()
    _engine.write_exr(str(out / "lightmaps" / "pages" / "page0.exr"), np.ascontiguousarray(_page()), [])
    return out


def _expected(width: int, height: int, margin: float):
    """Pinhole closed form: the quad's (u, v) under each pixel centre, the expected radiance
    rho * L_q, and a mask of the pixels at least `margin` (in u, v) from the quad's edges and
    from the quadrant lines (where bilinear filtering mixes two texels)."""
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    x_ndc, y_ndc = 2 * j / width - 1, 1 - 2 * i / height
    u = 0.5 + x_ndc * TAN_HALF * (width / height) * DIST
    v = 0.5 + y_ndc * TAN_HALF * DIST
    inside = (u > 0) & (u < 1) & (v > 0) & (v < 1)
    clear = inside & (np.minimum.reduce([u, 1 - u, v, 1 - v, abs(u - 0.5), abs(v - 0.5)]) > margin)
    expect = np.zeros((height, width, 3))
    for (qu, qv), val in QUAD_L.items():
        sel = inside & ((u >= 0.5) == bool(qu)) & ((v >= 0.5) == bool(qv))
        expect[sel] = ALBEDO * np.asarray(val)
    return expect, inside, clear


def test_rgbm_round_trip_error_bound():
    """value = rgb/255 * a/255 * range with a the smallest code covering the texel's largest
    component: the rounding error of rgb is at most half a step, a * range / 255^2 / 2, which is
    at most 1/255 of the largest component when a >= 2, and range/(2 * 255^2) below that."""
    rng = np.random.default_rng(7)
    v = 10.0 ** rng.uniform(-4, 1, size=(64, 64, 3))
    img, top = gltf.encode_rgbm(v)
    assert top == pytest.approx(v.max())
    back = gltf.decode_rgbm(img, top)
    a = img[..., 3].astype(np.float64)
    bound = 0.5 * a * top / 255.0 ** 2 * (1 + 1e-9)
    assert (np.abs(back - v) <= bound[..., None]).all()
    big = v.max(axis=2) > 2 * top / 255
    assert (np.abs(back - v).max(axis=2)[big] <= v.max(axis=2)[big] / 255).all()


@pytest.mark.parametrize("up_axis", ["Z", "Y"])
def test_glb_structure_and_validator(tmp_path, up_axis):
    out = _stage(tmp_path, up_axis=up_axis)
    path = gltf.write_glb(out)
    assert path == out / "scene.glb" and not list(out.glob(".*partial*"))
    doc = glb_json(path)
    report = validate(path)
    assert report["numErrors"] == 0, report["messages"]
    (mesh_node,) = [n for n in doc["nodes"] if "mesh" in n]
    prim = doc["meshes"][mesh_node["mesh"]]["primitives"][0]
    assert {"POSITION", "NORMAL", "TEXCOORD_0", "TEXCOORD_1"} <= set(prim["attributes"])
    pos = doc["accessors"][prim["attributes"]["POSITION"]]
    # metres (metersPerUnit 0.5: the unit quad is 0.5 m a side), +Y up in glTF whatever the stage's axis
    assert np.allclose(pos["min"], [0, 0, 0], atol=1e-6) and np.allclose(pos["max"], [0.5, 0.5, 0], atol=1e-6)
    lm = mesh_node["extras"]["hirad_lightmap"]
    # the rectangle for glTF's top-left UVs: (sx, sy, ox, 1 - sy - oy)
    assert lm["scaleOffset"] == pytest.approx([0.5, 0.5, 0.5, 0.5]) and lm["texCoord"] == 1
    assert lm["scaleOffsetUsd"] == pytest.approx(SCALE_OFFSET) and lm["encoding"] == "RGBM"
    assert lm["range"] == pytest.approx(max(DECOY))
    mat = doc["materials"][prim["material"]]
    assert mat["pbrMetallicRoughness"]["baseColorFactor"][:3] == pytest.approx(ALBEDO, rel=1e-6)
    assert mat["emissiveTexture"]["texCoord"] == 1
    assert mat["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"] == pytest.approx(max(DECOY))
    (cam,) = doc["cameras"]
    assert cam["perspective"]["yfov"] == pytest.approx(2 * math.atan(TAN_HALF))


def test_faceVarying_corners_are_split_and_merged(tmp_path):
    """A cube of 8 points with flat (computed) normals is 24 glTF vertices (each point appears
    on three faces with three normals), 12 triangles; with smooth vertex normals and no
    faceVarying data it stays 8 vertices; a faceVarying st splits a point where its faces give
    it different UVs, and only there."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "input.usda"))
    UsdGeom.SetStageUpAxis(stage, "Y")
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    pts = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    for name, smooth, st in (("flat", False, False), ("smooth", True, False), ("smooth_st", True, True)):
        m = UsdGeom.Mesh.Define(stage, f"/{name}")
        m.CreatePointsAttr([Gf.Vec3f(*p) for p in pts])
        m.CreateFaceVertexCountsAttr([4] * 6)
        m.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
        if smooth:
            m.CreateNormalsAttr([Gf.Vec3f(*(np.subtract(p, 0.5) / np.linalg.norm(np.subtract(p, 0.5)))) for p in pts])
            m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        if st:
            UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
                [Gf.Vec2f(*c) for _ in faces for c in ((0, 0), (1, 0), (1, 1), (0, 1))])
    stage.GetRootLayer().Save()
    out = tmp_path / "out"
    out.mkdir()
    layer = Sdf.Layer.CreateNew(str(out / "solution.usda"))
    layer.subLayerPaths.append("../input.usda")
    layer.Save()
    path = gltf.write_glb(out)
    doc = glb_json(path)
    counts = {}
    for node in doc["nodes"]:
        p = doc["meshes"][node["mesh"]]["primitives"][0]
        counts[node["name"]] = (doc["accessors"][p["attributes"]["POSITION"]]["count"],
                                doc["accessors"][p["indices"]]["count"] // 3)
    # the per-face st pattern puts the same st on some point from two of its faces: those
    # corners are one vertex; count the distinct (point, st) pairs independently
    st_corners = [(i, c) for f in faces for i, c in zip(f, ((0, 0), (1, 0), (1, 1), (0, 1)))]
    distinct = len(set(st_corners))
    assert 8 < distinct < 24
    assert counts == {"/flat": (24, 12), "/smooth": (8, 12), "/smooth_st": (distinct, 12)}
    report = validate(path)
    assert report["numErrors"] == 0, report["messages"]


@pytest.mark.parametrize("mode,tol", [("lightmap", 0.01), ("emissive", 0.02)])
def test_threejs_render_of_the_lightmap_matches_the_closed_form(tmp_path, mode, tol):
    """lightmap: RGBM decoded, three.js lightMap on TEXCOORD_1, lightMapIntensity = pi (RGBM
    and half-float rounding < 0.4 %); emissive: the GLB as loaded, no script (8-bit sRGB
    rounding of value/4: < 1.6 % at the darkest quadrant, 0.05 of the page maximum)."""
    out = _stage(tmp_path)
    path = gltf.write_glb(out)
    w = h = 64
    img, stats = render(path, tmp_path / "r.json", w, h, mode=mode, camera="/World/Camera")
    expect, inside, clear = _expected(w, h, margin=1.5 / 16)
    assert clear.sum() > 0.1 * w * h   # the quad covers 62.5 % of the width and height
    # nothing but the quad: black around it
    ring = ~inside
    assert np.abs(img[ring]).max() < 1e-6
    rel = np.abs(img[clear] / expect[clear] - 1)
    assert rel.max() < tol, (rel.max(), stats)
    # every quadrant is seen (a swapped V flip would put qv=0's light on top)
    for (qu, qv), val in QUAD_L.items():
        j, i = int(w * (0.5 + (qu - 0.5) * 0.3)), int(h * (0.5 - (qv - 0.5) * 0.3))
        assert img[i, j] == pytest.approx(ALBEDO * np.asarray(val), rel=tol)


def test_cornell_box_glb_in_threejs_matches_hirads_lightmap_render(tmp_path):
    """End to end on the bundled Cornell box (a small bake): the GLB passes the validator, and
    three.js, lit only by the lightmaps (RGBM pages decoded, lightMap on TEXCOORD_1, intensity
    pi, Lambertian: the specular lobe's share taken out of the diffuse by three.js's standard
    material is not in hirad's transport), rendered from the scene camera, shows the same
    picture as hirad's own render from the same lightmaps (outputs/lightmap_render.py: albedo x
    bilinear lightmap + emission at each camera ray's hit). Both read the same texels through
    two different rasterisations, UV conventions and filters; mean and median of the lit pixels'
    luminance within 3 %, and the no-script emissive mapping too."""
    from hirad_e2e_helpers import CORNELL, write_config

    from hirad.bake import bake, load_solution
    from hirad.outputs import lightmap_render

    out = tmp_path / "out"
    cfg = write_config(tmp_path / "c.yaml", CORNELL, out, method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 1e-3, "samples": 8, "max_rounds": 3},
                       solver={"method": "jacobi", "tolerance": 1e-3},
                       outputs={"preview": {"enabled": False}, "volume": {"enabled": False},
                                "lightmaps": {"enabled": True, "texels_per_metre": 64, "supersample": 1,
                                              "mode": "final_gather"}})
    bake(cfg)
    with pytest.warns(gltf.GltfExportWarning, match="emits light"):
        path = gltf.write_glb(out)
    report = validate(path)
    assert report["numErrors"] == 0, report["messages"]
    doc = glb_json(path)
    meshes = [n for n in doc["nodes"] if "mesh" in n]
    assert len(meshes) == 8 and all("hirad_lightmap" in n["extras"] for n in meshes)

    w = h = 96
    sol = load_solution(out / "solution.usda")
    ref = lightmap_render.render(out / "solution.usda", sol.view("/World/Camera"), w, h)
    lum = np.array([0.2126, 0.7152, 0.0722])
    b = ref @ lum
    lit = b > 0
    assert lit.mean() > 0.5
    for mode in ("lightmap", "emissive"):
        img, stats = render(path, tmp_path / f"{mode}.json", w, h, mode=mode, camera="/World/Camera")
        a = img @ lum
        assert abs(a[lit].mean() / b[lit].mean() - 1) < 0.03, (mode, a[lit].mean(), b[lit].mean())
        assert abs(np.median(a[lit]) / np.median(b[lit]) - 1) < 0.03, (mode, np.median(a[lit]), np.median(b[lit]))
        # the same silhouettes: black where nothing is hit, in both
        assert np.mean((a > 0) != lit) < 0.01
        if mode == "lightmap":
            # pixel by pixel: the same texels at the same surface points, apart from RGBM's
            # rounding (< 0.4 %), half floats and pixels on silhouettes, where a ray and a
            # rasteriser may pick different surfaces; a lightmap UV set that disagrees with the
            # page (a face's st1 in the wrong corner order) moves whole faces
            rel = np.abs(a[lit] / b[lit] - 1)
            assert np.median(rel) < 0.01 and np.quantile(rel, 0.9) < 0.03, (np.median(rel), np.quantile(rel, 0.9))


def test_copies_share_the_uv_set_and_get_their_own_rectangles(tmp_path):
    """A copy whose manifest entry names another mesh's UV set (a prototype's) gets that UV set
    as TEXCOORD_1 and its own rectangle (extras and the emissive mapping's texture transform),
    the manifest's rectangle taking precedence over the prim's attributes."""
    import json

    from pxr import Usd as _Usd

    out = _stage(tmp_path)
    src = _Usd.Stage.Open(str(tmp_path / "input.usda"))
    copy = UsdGeom.Mesh.Define(src, "/World/copy")
    for name in ("points", "faceVertexCounts", "faceVertexIndices"):
        copy.GetPrim().GetAttribute(name).Set(src.GetPrimAtPath("/World/quad").GetAttribute(name).Get())
    copy.AddTranslateOp().Set(Gf.Vec3d(2, 0, 0))
    UsdShade.MaterialBindingAPI.Apply(copy.GetPrim()).Bind(UsdShade.Material(src.GetPrimAtPath("/World/Looks/paint")))
    src.GetRootLayer().Save()
    manifest = {"version": 2, "instances": [
        {"prim": "/World/quad", "mesh": "/World/quad", "page": 0, "file": "pages/page0.exr",
         "scaleOffset": [0.5, 0.5, 0.5, 0.0], "uvSet": "st1"},
        {"prim": "/World/copy", "mesh": "/World/quad", "page": 0, "file": "pages/page0.exr",
         "scaleOffset": [0.25, 0.25, 0.0, 0.5], "uvSet": "st1"}]}
    (out / "lightmaps" / "manifest.json").write_text(json.dumps(manifest))
    doc = glb_json(gltf.write_glb(out))
    nodes = {n["extras"]["hirad_path"]: n for n in doc["nodes"] if "mesh" in n}
    assert set(nodes) == {"/World/quad", "/World/copy"}
    so = {k: n["extras"]["hirad_lightmap"]["scaleOffset"] for k, n in nodes.items()}
    assert so["/World/quad"] == pytest.approx([0.5, 0.5, 0.5, 0.5])
    assert so["/World/copy"] == pytest.approx([0.25, 0.25, 0.0, 1 - 0.25 - 0.5])
    prims = {k: doc["meshes"][n["mesh"]]["primitives"][0] for k, n in nodes.items()}
    uv_bytes = {}
    blob = (out / "scene.glb").read_bytes()
    bin_start = 20 + int.from_bytes(blob[12:16], "little") + 8
    for k, p in prims.items():
        acc = doc["accessors"][p["attributes"]["TEXCOORD_1"]]
        bv = doc["bufferViews"][acc["bufferView"]]
        uv_bytes[k] = np.frombuffer(blob[bin_start + bv.get("byteOffset", 0):][:bv["byteLength"]], np.float32)
        tt = doc["materials"][p["material"]]["emissiveTexture"]["extensions"]["KHR_texture_transform"]
        assert tt["scale"] == pytest.approx(so[k][:2]) and tt["offset"] == pytest.approx(so[k][2:])
    assert np.array_equal(np.sort(uv_bytes["/World/quad"]), np.sort(uv_bytes["/World/copy"]))
    assert prims["/World/quad"]["material"] != prims["/World/copy"]["material"]
    assert validate(out / "scene.glb")["numErrors"] == 0


def test_texture_material_and_texture_uvs(tmp_path):
    """A diffuseColor read from a UsdUVTexture (a PNG) becomes baseColorTexture on TEXCOORD_0,
    the image embedded byte for byte; TEXCOORD_0 is st with V flipped (glTF's origin is the
    top-left); the emissive mapping's albedo is the texture's mean linear colour."""
    from PIL import Image

    out = _stage(tmp_path)
    tex = np.zeros((4, 4, 3), np.uint8)
    tex[:, :2] = (255, 0, 0)
    tex[:, 2:] = (0, 0, 255)
    Image.fromarray(tex).save(tmp_path / "albedo.png")
    src = Usd.Stage.Open(str(tmp_path / "input.usda"))
    t = UsdShade.Shader.Define(src, "/World/Looks/paint/albedo")
    t.CreateIdAttr("UsdUVTexture")
    t.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./albedo.png"))
    sh = UsdShade.Shader(src.GetPrimAtPath("/World/Looks/paint/surface"))
    sh.GetInput("diffuseColor").ConnectToSource(t.ConnectableAPI(), "rgb")
    UsdGeom.PrimvarsAPI(src.GetPrimAtPath("/World/quad")).CreatePrimvar(
        "st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
        [Gf.Vec2f(0, 0), Gf.Vec2f(2, 0), Gf.Vec2f(2, 2), Gf.Vec2f(0, 2)])
    src.GetRootLayer().Save()
    path = gltf.write_glb(out)
    doc = glb_json(path)
    (node,) = [n for n in doc["nodes"] if "mesh" in n]
    prim = doc["meshes"][node["mesh"]]["primitives"][0]
    mat = doc["materials"][prim["material"]]
    info = mat["pbrMetallicRoughness"]["baseColorTexture"]
    assert info["texCoord"] == 0
    image = doc["images"][doc["textures"][info["index"]]["source"]]
    assert image["mimeType"] == "image/png"
    blob = path.read_bytes()
    bin_start = 20 + int.from_bytes(blob[12:16], "little") + 8
    bv = doc["bufferViews"][image["bufferView"]]
    assert blob[bin_start + bv.get("byteOffset", 0):][:bv["byteLength"]] == (tmp_path / "albedo.png").read_bytes()
    acc = doc["accessors"][prim["attributes"]["TEXCOORD_0"]]
    bv = doc["bufferViews"][acc["bufferView"]]
    uv0 = np.frombuffer(blob[bin_start + bv.get("byteOffset", 0):][:bv["byteLength"]], np.float32).reshape(-1, 2)
    assert {tuple(r) for r in uv0} == {(0.0, 1.0), (2.0, 1.0), (2.0, -1.0), (0.0, -1.0)}
    # half the texels red, half blue: mean linear colour (0.5, 0, 0.5)
    assert mat["emissiveFactor"] == pytest.approx([0.5, 0.0, 0.5])
    assert validate(path)["numErrors"] == 0
