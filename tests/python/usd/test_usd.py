"""Tests for hirad.usd: reading USD stages into engine arrays and writing solution layers."""

from __future__ import annotations

import hashlib
import math
import sys
from pathlib import Path

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt  # noqa: E402

REPO = Path(__file__).resolve().parents[3]
if str(REPO / "tools") not in sys.path:
    sys.path.insert(0, str(REPO / "tools"))

from hirad import usd as hu  # noqa: E402

CORNELL = REPO / "configs" / "scenes" / "cornell_box.usda"


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------


def new_stage(tmp_path: Path, name="scene.usda", mpu=1.0, up="Y") -> tuple[Usd.Stage, Path]:
    path = tmp_path / name
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    return stage, path


def add_quad(stage, path, size=1.0, z=0.0, orientation=None, color=None):
    """Unit quad in the XY plane, counter-clockwise seen from +Z (normal +Z)."""
    m = UsdGeom.Mesh.Define(stage, path)
    s = size
    m.CreatePointsAttr([(0, 0, z), (s, 0, z), (s, s, z), (0, s, z)])
    m.CreateFaceVertexCountsAttr([4])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    if orientation:
        m.CreateOrientationAttr(orientation)
    if color is not None:
        m.CreateDisplayColorAttr([Gf.Vec3f(*color)])
    return m


def add_material(stage, path, diffuse=None, emissive=None):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    if diffuse is not None:
        sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    if emissive is not None:
        sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def bind(prim, mat):
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def mesh_faces(scene: hu.SceneArrays, k: int):
    """(list of (n,3) polygons) of scene mesh k."""
    starts = np.concatenate([[0], np.cumsum(scene.face_vertex_counts)[:-1]])
    out = []
    for f in np.nonzero(scene.face_mesh == k)[0]:
        s, n = starts[f], scene.face_vertex_counts[f]
        out.append(scene.points[scene.face_vertex_indices[s : s + n]])
    return out


def face_normal(poly):
    v = np.cross(poly - poly[0], np.roll(poly, -1, axis=0) - poly[0]).sum(axis=0)
    return v / np.linalg.norm(v)


def mesh_index(scene, path):
    for k, m in enumerate(scene.meshes):
        if m.path == path:
            return k
    raise AssertionError(f"{path} not in {[m.path for m in scene.meshes]}")


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ---------------------------------------------------------------------------------------------
# units and transforms
# ---------------------------------------------------------------------------------------------


def test_meters_per_unit_and_transforms(tmp_path):
    stage, path = new_stage(tmp_path, mpu=0.01)  # centimetres
    xf = UsdGeom.Xform.Define(stage, "/World")
    xf.AddTranslateOp().Set(Gf.Vec3d(100, 200, 300))
    xf.AddScaleOp().Set(Gf.Vec3f(2, 3, 4))
    add_quad(stage, "/World/quad", size=1.0)
    stage.Save()

    scene = hu.read_scene(path)
    assert scene.meters_per_unit == pytest.approx(0.01)
    assert scene.up_axis == "Y"
    assert len(scene.meshes) == 1
    expected = np.array([[1.0, 2.0, 3.0], [1.02, 2.0, 3.0], [1.02, 2.03, 3.0], [1.0, 2.03, 3.0]])
    np.testing.assert_allclose(scene.points, expected, atol=1e-12)
    assert scene.points.dtype == np.float64
    assert scene.face_vertex_counts.dtype == np.int32
    assert scene.face_vertex_indices.dtype == np.int32
    assert scene.face_vertex_counts.tolist() == [4]  # not triangulated
    assert scene.face_mesh.tolist() == [0] and scene.face_source.tolist() == [0]
    np.testing.assert_allclose(face_normal(mesh_faces(scene, 0)[0]), [0, 0, 1], atol=1e-12)
    assert scene.corner_uv is None


def test_up_axis_z_and_rotation(tmp_path):
    stage, path = new_stage(tmp_path, mpu=1.0, up="Z")
    xf = UsdGeom.Xform.Define(stage, "/R")
    xf.AddRotateXOp().Set(90.0)  # +Z normal -> -Y
    add_quad(stage, "/R/quad")
    stage.Save()
    scene = hu.read_scene(path)
    assert scene.up_axis == "Z"
    np.testing.assert_allclose(face_normal(mesh_faces(scene, 0)[0]), [0, -1, 0], atol=1e-9)


def test_negative_scale_flips_winding(tmp_path):
    stage, path = new_stage(tmp_path)
    xf = UsdGeom.Xform.Define(stage, "/M")
    xf.AddScaleOp().Set(Gf.Vec3f(-1, 1, 1))  # mirror: geometric normal stays +Z
    add_quad(stage, "/M/quad")
    stage.Save()
    scene = hu.read_scene(path)
    np.testing.assert_allclose(face_normal(mesh_faces(scene, 0)[0]), [0, 0, 1], atol=1e-12)


def test_double_sided_meshes_are_named_in_a_warning(tmp_path):
    # doubleSided is not honoured (faces are one-sided): said, with the meshes, never silently
    stage, path = new_stage(tmp_path)
    add_quad(stage, "/one")
    add_quad(stage, "/two").CreateDoubleSidedAttr(True)
    add_quad(stage, "/off").CreateDoubleSidedAttr(False)
    stage.Save()
    scene = hu.read_scene(path)
    said = [w for w in scene.warnings if "doubleSided" in w]
    assert len(said) == 1 and "/two" in said[0] and "/one" not in said[0] and "/off" not in said[0], scene.warnings


def test_glass_that_would_reflect_more_than_it_stops_is_lowered_and_named(tmp_path):
    # opacity 0.2 lets 0.8 through: a diffuseColor of 0.5 would make the pane create light,
    # so its reflectance becomes 0.2 with a warning; 0.1 is kept, silently
    stage, path = new_stage(tmp_path)
    for name, rho in (("bright", 0.5), ("dim", 0.1)):
        mat = add_material(stage, f"/Looks/{name}", diffuse=(rho, rho, rho))
        UsdShade.Shader(stage.GetPrimAtPath(f"/Looks/{name}/Surface")).CreateInput(
            "opacity", Sdf.ValueTypeNames.Float).Set(0.2)
        bind(add_quad(stage, f"/{name}").GetPrim(), mat)
    add_quad(stage, "/lamp", z=1.0, color=(0.5, 0.5, 0.5))
    stage.Save()
    scene = hu.read_scene(path, require_emission=False)
    for name, rho in (("bright", 0.2), ("dim", 0.1)):
        k = mesh_index(scene, f"/{name}")
        np.testing.assert_allclose(scene.face_reflectance[scene.face_mesh == k], rho, atol=1e-6)
        np.testing.assert_allclose(scene.face_transmittance[scene.face_mesh == k], 0.8, atol=1e-6)
    said = [w for w in scene.warnings if "glazed" in w]
    assert len(said) == 1 and "/bright" in said[0], scene.warnings


def test_left_handed_orientation_flips_winding(tmp_path):
    stage, path = new_stage(tmp_path)
    add_quad(stage, "/rh")
    add_quad(stage, "/lh", orientation=UsdGeom.Tokens.leftHanded)
    stage.Save()
    scene = hu.read_scene(path)
    n_rh = face_normal(mesh_faces(scene, mesh_index(scene, "/rh"))[0])
    n_lh = face_normal(mesh_faces(scene, mesh_index(scene, "/lh"))[0])
    np.testing.assert_allclose(n_rh, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(n_lh, [0, 0, -1], atol=1e-12)


# ---------------------------------------------------------------------------------------------
# instancing, visibility, purpose
# ---------------------------------------------------------------------------------------------


def test_instancing(tmp_path):
    stage, path = new_stage(tmp_path)
    # an instanceable asset referenced twice
    proto = UsdGeom.Xform.Define(stage, "/Assets/Tile")
    add_quad(stage, "/Assets/Tile/geo")
    stage.GetPrimAtPath("/Assets").SetSpecifier(Sdf.SpecifierClass)  # abstract: not traversed
    for i, x in enumerate((10.0, 20.0)):
        ref = UsdGeom.Xform.Define(stage, f"/World/tile{i}")
        ref.AddTranslateOp().Set(Gf.Vec3d(x, 0, 0))
        ref.GetPrim().GetReferences().AddInternalReference(proto.GetPath())
        ref.GetPrim().SetInstanceable(True)
    # a point instancer with 3 instances, the middle one invisible
    pi = UsdGeom.PointInstancer.Define(stage, "/World/scatter")
    pi.AddTranslateOp().Set(Gf.Vec3d(0, 100, 0))
    ball = UsdGeom.Xform.Define(stage, "/World/scatter/Protos/Ball")
    ball.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))  # prototype root transform is included
    add_quad(stage, "/World/scatter/Protos/Ball/geo")
    pi.CreatePrototypesRel().SetTargets([ball.GetPath()])
    pi.CreateProtoIndicesAttr([0, 0, 0])
    pi.CreatePositionsAttr([Gf.Vec3f(1, 0, 0), Gf.Vec3f(2, 0, 0), Gf.Vec3f(3, 0, 0)])
    pi.CreateIdsAttr([10, 11, 12])
    pi.CreateInvisibleIdsAttr([11])
    stage.Save()

    scene = hu.read_scene(path)
    paths = sorted(m.path for m in scene.meshes)
    assert paths == [
        "/World/scatter/instance_0/Ball/geo",
        "/World/scatter/instance_2/Ball/geo",
        "/World/tile0/geo",
        "/World/tile1/geo",
    ]
    names = [m.name for m in scene.meshes]
    assert len(set(names)) == len(names)
    assert all(Sdf.Path.IsValidIdentifier(n) for n in names)

    def origin(p):
        return mesh_faces(scene, mesh_index(scene, p))[0][0]

    np.testing.assert_allclose(origin("/World/tile0/geo"), [10, 0, 0])
    np.testing.assert_allclose(origin("/World/tile1/geo"), [20, 0, 0])
    np.testing.assert_allclose(origin("/World/scatter/instance_0/Ball/geo"), [1, 100, 5])
    np.testing.assert_allclose(origin("/World/scatter/instance_2/Ball/geo"), [3, 100, 5])
    hide = {m.path: m.hide_path for m in scene.meshes}
    assert hide["/World/tile0/geo"] == "/World/tile0"
    assert hide["/World/scatter/instance_0/Ball/geo"] == "/World/scatter"
    # the prototype itself is never emitted as an ordinary mesh
    assert not any(m.path.startswith("/World/scatter/Protos") for m in scene.meshes)


def test_invisible_and_guide_prims_are_skipped(tmp_path):
    stage, path = new_stage(tmp_path)
    add_quad(stage, "/keep")
    add_quad(stage, "/render_purpose").CreatePurposeAttr(UsdGeom.Tokens.render)
    hidden = UsdGeom.Xform.Define(stage, "/hidden")
    hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    add_quad(stage, "/hidden/child")
    add_quad(stage, "/guide").CreatePurposeAttr(UsdGeom.Tokens.guide)
    add_quad(stage, "/proxy").CreatePurposeAttr(UsdGeom.Tokens.proxy)
    add_quad(stage, "/self_invisible").CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    stage.Save()
    scene = hu.read_scene(path)
    assert sorted(m.path for m in scene.meshes) == ["/keep", "/render_purpose"]


# ---------------------------------------------------------------------------------------------
# materials
# ---------------------------------------------------------------------------------------------


def test_material_resolution_order(tmp_path):
    stage, path = new_stage(tmp_path)
    red = add_material(stage, "/Looks/red", diffuse=(0.8, 0.1, 0.1))
    # material bound: wins over displayColor
    bind(add_quad(stage, "/bound", color=(0.0, 0.0, 1.0)).GetPrim(), red)
    # displayColor only
    add_quad(stage, "/display", color=(0.2, 0.3, 0.4))
    # nothing: default
    add_quad(stage, "/plain")
    # over-bright displayColor is clamped below 1
    add_quad(stage, "/bright", color=(2.0, 0.0, 0.5))  # a negative one is an error (test_validation.py)
    stage.Save()
    scene = hu.read_scene(path, default_reflectance=(0.25, 0.5, 0.75))

    def refl(p):
        return scene.face_reflectance[scene.face_mesh == mesh_index(scene, p)][0]

    np.testing.assert_allclose(refl("/bound"), [0.8, 0.1, 0.1], atol=1e-6)
    np.testing.assert_allclose(refl("/display"), [0.2, 0.3, 0.4], atol=1e-6)
    np.testing.assert_allclose(refl("/plain"), [0.25, 0.5, 0.75])
    np.testing.assert_allclose(refl("/bright"), [0.999, 0.0, 0.5], atol=1e-6)
    assert np.all(scene.face_emission == 0)


def test_vertex_display_color_is_averaged_per_face(tmp_path):
    stage, path = new_stage(tmp_path)
    m = add_quad(stage, "/q")
    pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar(
        "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex
    )
    pv.Set([Gf.Vec3f(0, 0, 0), Gf.Vec3f(0.4, 0, 0), Gf.Vec3f(0.4, 0.8, 0), Gf.Vec3f(0, 0.8, 0)])
    stage.Save()
    scene = hu.read_scene(path)
    np.testing.assert_allclose(scene.face_reflectance[0], [0.2, 0.4, 0.0], atol=1e-6)


def test_geomsubset_per_face_materials(tmp_path):
    stage, path = new_stage(tmp_path)
    m = UsdGeom.Mesh.Define(stage, "/strip")
    m.CreatePointsAttr([(x, y, 0) for x in range(4) for y in range(2)])
    # three quads along x
    m.CreateFaceVertexCountsAttr([4, 4, 4])
    m.CreateFaceVertexIndicesAttr([0, 2, 3, 1, 2, 4, 5, 3, 4, 6, 7, 5])
    base = add_material(stage, "/Looks/base", diffuse=(0.5, 0.5, 0.5))
    green = add_material(stage, "/Looks/green", diffuse=(0.1, 0.7, 0.1))
    glow = add_material(stage, "/Looks/glow", diffuse=(0.3, 0.3, 0.3), emissive=(2.0, 1.0, 0.5))
    bind(m.GetPrim(), base)
    api = UsdShade.MaterialBindingAPI.Apply(m.GetPrim())
    s1 = api.CreateMaterialBindSubset("g", Vt.IntArray([1]), UsdGeom.Tokens.face)
    s2 = api.CreateMaterialBindSubset("e", Vt.IntArray([2]), UsdGeom.Tokens.face)
    bind(s1.GetPrim(), green)
    bind(s2.GetPrim(), glow)
    stage.Save()
    scene = hu.read_scene(path)
    np.testing.assert_allclose(
        scene.face_reflectance, [[0.5, 0.5, 0.5], [0.1, 0.7, 0.1], [0.3, 0.3, 0.3]], atol=1e-6
    )
    np.testing.assert_allclose(scene.face_emission[:2], 0.0)
    np.testing.assert_allclose(scene.face_emission[2], np.pi * np.array([2.0, 1.0, 0.5]), rtol=1e-6)
    assert scene.face_source.tolist() == [0, 1, 2]


def test_texture_mean_colour_srgb_scale_bias_and_fallback(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    img = np.zeros((2, 2, 3), dtype=np.uint8)
    img[0, :] = (255, 0, 0)
    img[1, :] = (0, 0, 255)
    Image.fromarray(img, "RGB").save(tmp_path / "tex.png")

    stage, path = new_stage(tmp_path)

    def textured(name, file, extra=None):
        mat = UsdShade.Material.Define(stage, f"/Looks/{name}")
        sh = UsdShade.Shader.Define(stage, f"/Looks/{name}/Surface")
        sh.CreateIdAttr("UsdPreviewSurface")
        tex = UsdShade.Shader.Define(stage, f"/Looks/{name}/Tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(file))
        for k, (tname, v) in (extra or {}).items():
            tex.CreateInput(k, tname).Set(v)
        out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(out)
        mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
        return mat

    bind(add_quad(stage, "/auto").GetPrim(), textured("auto", "./tex.png"))
    bind(
        add_quad(stage, "/raw").GetPrim(),
        textured(
            "raw",
            "./tex.png",
            {
                "sourceColorSpace": (Sdf.ValueTypeNames.Token, "raw"),
                "scale": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.5, 0.5, 0.5, 1)),
                "bias": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.1, 0.1, 0.1, 0)),
            },
        ),
    )
    bind(
        add_quad(stage, "/missing").GetPrim(),
        textured("missing", "./nope.png", {"fallback": (Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.3, 0.2, 0.1, 1))}),
    )
    stage.Save()
    scene = hu.read_scene(path)

    def refl(p):
        return scene.face_reflectance[scene.face_mesh == mesh_index(scene, p)][0]

    # half red, half blue rows (0 and 255 decode the same in sRGB and raw; see the next test)
    np.testing.assert_allclose(refl("/auto"), [0.5, 0.0, 0.5], atol=1e-6)
    np.testing.assert_allclose(refl("/raw"), [0.35, 0.1, 0.35], atol=1e-6)
    np.testing.assert_allclose(refl("/missing"), [0.3, 0.2, 0.1], atol=1e-6)
    assert any("nope.png" in w for w in scene.warnings)


def test_texture_srgb_decoding(tmp_path):
    Image = pytest.importorskip("PIL.Image")
    Image.fromarray(np.full((2, 2, 3), 128, dtype=np.uint8), "RGB").save(tmp_path / "grey.png")
    stage, path = new_stage(tmp_path)
    for name, cs in (("srgb", "auto"), ("lin", "raw")):
        mat = UsdShade.Material.Define(stage, f"/Looks/{name}")
        sh = UsdShade.Shader.Define(stage, f"/Looks/{name}/Surface")
        sh.CreateIdAttr("UsdPreviewSurface")
        tex = UsdShade.Shader.Define(stage, f"/Looks/{name}/Tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./grey.png"))
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(cs)
        out = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
        sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(out)
        mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
        bind(add_quad(stage, f"/{name}").GetPrim(), mat)
    stage.Save()
    scene = hu.read_scene(path)
    srgb = scene.face_reflectance[scene.face_mesh == mesh_index(scene, "/srgb")][0]
    lin = scene.face_reflectance[scene.face_mesh == mesh_index(scene, "/lin")][0]
    np.testing.assert_allclose(srgb, ((128 / 255 + 0.055) / 1.055) ** 2.4, atol=1e-6)
    np.testing.assert_allclose(lin, 128 / 255, atol=1e-6)


@pytest.mark.parametrize("mode", ["L", "LA", "RGB", "RGBA"])
def test_texture_mean_of_every_8_bit_layout(tmp_path, mode):
    """An 8-bit texture's mean colour (read from each channel's histogram) is the mean of its
    texels decoded one by one (IEC 61966-2-1's sRGB curve), alpha undecoded; grey layouts give
    the grey in all three channels."""
    Image = pytest.importorskip("PIL.Image")
    from hirad.usd.materials import _MaterialResolver

    rng = np.random.default_rng(7)
    channels = len(mode)
    texels = rng.integers(0, 256, size=(37, 53, channels), dtype=np.uint8)
    Image.fromarray(texels[:, :, 0] if channels == 1 else texels, mode).save(tmp_path / "t.png")
    c = texels.astype(np.float64) / 255.0
    decoded = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    colour = [0, 0, 0] if channels <= 2 else [0, 1, 2]
    alpha = c[:, :, channels - 1].mean() if channels in (2, 4) else 1.0
    resolver = object.__new__(_MaterialResolver)
    resolver._tex_cache = {}
    for space, values in (("sRGB", decoded), ("raw", c)):
        got = resolver._texture_mean(str(tmp_path / "t.png"), space)
        np.testing.assert_allclose(got, [*values[:, :, colour].reshape(-1, 3).mean(axis=0), alpha], rtol=1e-12,
                                   atol=1e-15)


def test_uv_primvars(tmp_path):
    stage, path = new_stage(tmp_path)
    a = add_quad(stage, "/a")
    UsdGeom.PrimvarsAPI(a).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (1, 0), (1, 1), (0, 1)]
    )
    b = add_quad(stage, "/b", orientation=UsdGeom.Tokens.leftHanded)
    pv = UsdGeom.PrimvarsAPI(b).CreatePrimvar(
        "uv", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying
    )
    pv.Set([(0.0, 0.0), (0.5, 0.5), (1.0, 1.0)])
    pv.SetIndices(Vt.IntArray([0, 1, 2, 2]))
    add_quad(stage, "/c")
    stage.Save()
    scene = hu.read_scene(path)
    assert scene.corner_uv is not None
    assert scene.corner_uv.shape == (12, 2)
    info = {m.path: m for m in scene.meshes}
    assert info["/a"].has_uv and info["/b"].has_uv and not info["/c"].has_uv
    starts = np.concatenate([[0], np.cumsum(scene.face_vertex_counts)[:-1]])
    fa, fb, fc = (np.nonzero(scene.face_mesh == mesh_index(scene, p))[0][0] for p in ("/a", "/b", "/c"))
    np.testing.assert_allclose(scene.corner_uv[starts[fa] : starts[fa] + 4], [(0, 0), (1, 0), (1, 1), (0, 1)])
    # left-handed: corners reversed (first kept) and the faceVarying UVs follow their corners
    np.testing.assert_allclose(scene.corner_uv[starts[fb] : starts[fb] + 4], [(0, 0), (1, 1), (1, 1), (0.5, 0.5)])
    np.testing.assert_allclose(scene.corner_uv[starts[fc] : starts[fc] + 4], 0.0)


# ---------------------------------------------------------------------------------------------
# lights
# ---------------------------------------------------------------------------------------------


def test_mesh_light_replaces_emissive_color(tmp_path):
    stage, path = new_stage(tmp_path, mpu=0.1)
    m = add_quad(stage, "/lamp", size=20.0)  # 2 m x 2 m = 4 m^2
    bind(m.GetPrim(), add_material(stage, "/Looks/l", diffuse=(0.5, 0.5, 0.5), emissive=(100, 100, 100)))
    UsdLux.MeshLightAPI.Apply(m.GetPrim())
    light = UsdLux.LightAPI(m.GetPrim())
    light.CreateIntensityAttr(2.0)
    light.CreateExposureAttr(2.0)
    light.CreateColorAttr(Gf.Vec3f(1.0, 0.5, 0.25))
    m2 = add_quad(stage, "/lamp_norm", size=20.0, z=5.0)
    UsdLux.MeshLightAPI.Apply(m2.GetPrim())
    l2 = UsdLux.LightAPI(m2.GetPrim())
    l2.CreateIntensityAttr(8.0)
    l2.CreateNormalizeAttr(True)
    stage.Save()
    scene = hu.read_scene(path)
    k = mesh_index(scene, "/lamp")
    assert scene.meshes[k].is_light
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k][0], np.pi * 8 * np.array([1, 0.5, 0.25]))
    np.testing.assert_allclose(scene.face_reflectance[scene.face_mesh == k][0], 0.5, atol=1e-6)
    k2 = mesh_index(scene, "/lamp_norm")
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k2][0], np.pi * 8 / 4.0)


def test_rect_light(tmp_path):
    stage, path = new_stage(tmp_path)
    rl = UsdLux.RectLight.Define(stage, "/Lights/rect")
    rl.AddTranslateOp().Set(Gf.Vec3d(0, 3, 0))
    rl.AddRotateXOp().Set(-90.0)  # local -Z -> world -Y (pointing down)
    rl.CreateWidthAttr(2.0)
    rl.CreateHeightAttr(0.5)
    rl.CreateIntensityAttr(3.0)
    rl.CreateExposureAttr(1.0)
    rl.CreateNormalizeAttr(True)
    rl.CreateColorAttr(Gf.Vec3f(1, 1, 1))
    add_quad(stage, "/floor")
    stage.Save()
    scene = hu.read_scene(path)
    k = mesh_index(scene, "/Lights/rect")
    info = scene.meshes[k]
    assert info.is_light and info.hide_path == "/Lights/rect"
    faces = mesh_faces(scene, k)
    assert len(faces) == 1 and len(faces[0]) == 4
    np.testing.assert_allclose(face_normal(faces[0]), [0, -1, 0], atol=1e-9)
    np.testing.assert_allclose(faces[0][:, 1], 3.0, atol=1e-9)
    ext = faces[0].max(axis=0) - faces[0].min(axis=0)
    np.testing.assert_allclose(ext, [2.0, 0.0, 0.5], atol=1e-9)
    # radiance = 3 * 2^1 / area(1 m^2) -> exitance pi * 6
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k], [[np.pi * 6] * 3])
    np.testing.assert_allclose(scene.face_reflectance[scene.face_mesh == k], 0.0)


def test_rect_light_normalize_spec_example(tmp_path):
    stage, path = new_stage(tmp_path)
    rl = UsdLux.RectLight.Define(stage, "/rect")
    rl.CreateWidthAttr(2.0)
    rl.CreateHeightAttr(0.5)
    rl.CreateIntensityAttr(3.0)
    rl.CreateExposureAttr(1.0)
    rl.CreateNormalizeAttr(True)
    un = UsdLux.RectLight.Define(stage, "/rect_unnormalized")
    un.CreateWidthAttr(2.0)
    un.CreateHeightAttr(2.0)
    un.CreateIntensityAttr(3.0)
    un.CreateExposureAttr(1.0)
    stage.Save()
    scene = hu.read_scene(path)
    k = mesh_index(scene, "/rect")
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k][0], np.pi * 3 * 2 / 1.0)
    k2 = mesh_index(scene, "/rect_unnormalized")
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k2][0], np.pi * 3 * 2)
    np.testing.assert_allclose(face_normal(mesh_faces(scene, k)[0]), [0, 0, -1], atol=1e-12)


def test_disk_light(tmp_path):
    stage, path = new_stage(tmp_path)
    dl = UsdLux.DiskLight.Define(stage, "/disk")
    dl.AddRotateYOp().Set(90.0)  # local -Z -> world -X
    dl.CreateRadiusAttr(0.5)
    dl.CreateIntensityAttr(4.0)
    dl.CreateColorAttr(Gf.Vec3f(1, 0.5, 0))
    stage.Save()
    scene = hu.read_scene(path, light_segments=24)
    faces = mesh_faces(scene, 0)
    assert len(faces) == 1 and len(faces[0]) == 24  # one polygon
    np.testing.assert_allclose(face_normal(faces[0]), [-1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(faces[0], axis=1), 0.5, atol=1e-9)
    np.testing.assert_allclose(scene.face_emission[0], np.pi * 4 * np.array([1, 0.5, 0]))


def test_sphere_light(tmp_path):
    """A SphereLight is a luminaire (issue 13): an isotropic point at its centre, I = L pi r^2, not a
    tessellated sphere (which lost ~0.9 % of the flux): flux 4 pi^2 r^2 L, with normalize pi L."""
    stage, path = new_stage(tmp_path, mpu=0.01)
    add_quad(stage, "/floor", size=100.0)
    sl = UsdLux.SphereLight.Define(stage, "/sphere")
    sl.AddTranslateOp().Set(Gf.Vec3d(0, 100, 0))  # 1 m up
    sl.CreateRadiusAttr(10.0)  # 0.1 m
    sl.CreateIntensityAttr(1.0)
    sl.CreateExposureAttr(-1.0)
    sl.CreateNormalizeAttr(True)
    stage.Save()
    scene = hu.read_scene(path)
    assert [m.path for m in scene.meshes] == ["/floor"]  # not part of the geometry
    assert len(scene.luminaires) == 1
    lum = scene.luminaires[0]
    assert lum.kind == "SphereLight" and lum.source == "/sphere"
    np.testing.assert_allclose(lum.points, [[0, 1.0, 0]], atol=1e-12)
    # L = 0.5 nit normalized by 4 pi r^2: flux = pi L x area / area = pi x 0.5 exactly
    np.testing.assert_allclose(lum.flux, math.pi * 0.5, rtol=1e-9)
    i = lum.intensity(np.array([[0, -1.0, 0], [1, 0, 0], [0.3, 0.4, -0.5]]))
    np.testing.assert_allclose(i, 0.5 / 4, rtol=1e-9)  # L/(4 pi r^2) x pi r^2 = L/4 in every direction


def test_color_temperature(tmp_path):
    stage, path = new_stage(tmp_path)
    rl = UsdLux.RectLight.Define(stage, "/warm")
    rl.CreateWidthAttr(1.0)
    rl.CreateHeightAttr(1.0)
    rl.CreateEnableColorTemperatureAttr(True)
    rl.CreateColorTemperatureAttr(2700.0)
    stage.Save()
    scene = hu.read_scene(path)
    e = scene.face_emission[0]
    assert e[0] > e[1] > e[2] > 0  # warm white


# ---------------------------------------------------------------------------------------------
# invalid geometry and errors
# ---------------------------------------------------------------------------------------------


def test_bad_faces_dropped_with_warning_and_nan_passed_through(tmp_path):
    stage, path = new_stage(tmp_path)
    m = UsdGeom.Mesh.Define(stage, "/broken")
    m.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (float("nan"), 0, 0)])
    m.CreateFaceVertexCountsAttr([3, 2, 3, 3])
    m.CreateFaceVertexIndicesAttr([0, 1, 2, 0, 1, 0, 2, 9, 0, 2, 4])
    stage.Save()
    scene = hu.read_scene(path)
    assert scene.face_source.tolist() == [0, 3]
    assert scene.face_vertex_counts.tolist() == [3, 3]
    assert np.isnan(scene.points).any()
    assert any("/broken" in w and "2 face" in w for w in scene.warnings)


def test_missing_file_raises(tmp_path):
    missing = tmp_path / "does_not_exist.usda"
    with pytest.raises(hu.SceneError, match="does_not_exist.usda"):
        hu.read_scene(missing)


def test_unreadable_file_raises(tmp_path):
    bad = tmp_path / "garbage.usda"
    bad.write_text("this is not usd\n")
    with pytest.raises(hu.SceneError, match="garbage.usda"):
        hu.read_scene(bad)


def test_no_mesh_stage_raises(tmp_path):
    stage, path = new_stage(tmp_path, name="empty_scene.usda")
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Camera.Define(stage, "/World/cam")
    stage.Save()
    with pytest.raises(hu.SceneError, match=r"empty_scene\.usda.*no meshes found"):
        hu.read_scene(path)


# ---------------------------------------------------------------------------------------------
# Cornell box
# ---------------------------------------------------------------------------------------------


def test_cornell_box_scene():
    scene = hu.read_scene(CORNELL)
    names = {m.path.rsplit("/", 1)[-1]: k for k, m in enumerate(scene.meshes)}
    assert set(names) == {
        "floor", "ceiling", "back_wall", "right_wall_green", "left_wall_red",
        "short_block", "tall_block", "light",
    }
    assert len(scene.meshes) == 8
    assert scene.meters_per_unit == pytest.approx(0.001)
    assert scene.up_axis == "Y"
    np.testing.assert_allclose(scene.points.min(axis=0), [0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(scene.points.max(axis=0), [0.556, 0.5488, 0.5592], atol=1e-6)

    expected_inward = {
        "floor": [0, 1, 0],
        "ceiling": [0, -1, 0],
        "back_wall": [0, 0, -1],
        "right_wall_green": [1, 0, 0],  # x = 0 wall
        "left_wall_red": [-1, 0, 0],  # x ~ 0.55 wall
        "light": [0, -1, 0],
    }
    for name, want in expected_inward.items():
        for f in mesh_faces(scene, names[name]):
            assert np.dot(face_normal(f), want) > 0.99, name
    for blk in ("short_block", "tall_block"):
        faces = mesh_faces(scene, names[blk])
        assert len(faces) == 5 and all(len(f) == 4 for f in faces)
        centre = np.concatenate(faces).mean(axis=0)
        for f in faces:
            assert np.dot(face_normal(f), f.mean(axis=0) - centre) > 0, blk
    # the ceiling has a hole where the light is: its faces cover the outer area minus the hole
    ceil_area = sum(
        0.5 * np.linalg.norm(np.cross(f - f[0], np.roll(f, -1, axis=0) - f[0]).sum(axis=0))
        for f in mesh_faces(scene, names["ceiling"])
    )
    assert ceil_area == pytest.approx(0.556 * 0.5592 - 0.130 * 0.105, rel=1e-5)
    light = mesh_faces(scene, names["light"])[0]
    np.testing.assert_allclose(light[:, 1], 0.5483, atol=1e-6)

    # materials: light emission pi * (17, 11.8, 4) exactly once (MeshLightAPI replaces emissive)
    k = names["light"]
    assert scene.meshes[k].is_light
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k][0], np.pi * np.array([17, 11.8, 4]), rtol=1e-6)
    np.testing.assert_allclose(scene.face_reflectance[scene.face_mesh == k][0], 0.78, atol=1e-6)
    np.testing.assert_allclose(
        scene.face_reflectance[scene.face_mesh == names["right_wall_green"]][0],
        [0.13292308, 0.3435, 0.120192304], atol=1e-6,
    )
    np.testing.assert_allclose(
        scene.face_reflectance[scene.face_mesh == names["floor"]][0],
        [0.7339231, 0.73596156, 0.69973075], atol=1e-6,
    )
    red = scene.face_reflectance[scene.face_mesh == names["left_wall_red"]][0]
    assert red[0] > 0.5 and red[1] < 0.1 and red[2] < 0.1
    assert np.all(scene.face_emission[scene.face_mesh != k] == 0)

    assert len(scene.cameras) == 1
    cam = scene.cameras[0]
    assert cam.path == "/World/Camera"
    assert cam.vertical_fov_degrees == pytest.approx(39.3077, abs=0.1)
    np.testing.assert_allclose(cam.position, [0.278, 0.273, -0.8], atol=1e-9)
    np.testing.assert_allclose(cam.forward, [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(cam.up, [0, 1, 0], atol=1e-9)
    assert cam.aspect == pytest.approx(1.0)
    assert scene.warnings == []


# ---------------------------------------------------------------------------------------------
# solution layer
# ---------------------------------------------------------------------------------------------


def _fake_solution(scene: hu.SceneArrays, with_lightmap=False):
    out = []
    starts = np.concatenate([[0], np.cumsum(scene.face_vertex_counts)[:-1]])
    rng = np.random.default_rng(1)
    for k in range(len(scene.meshes)):
        faces = np.nonzero(scene.face_mesh == k)[0]
        counts = scene.face_vertex_counts[faces]
        idx = np.concatenate([scene.face_vertex_indices[starts[f] : starts[f] + n] for f, n in zip(faces, counts)])
        used, local = np.unique(idx, return_inverse=True)
        P, F, C = len(used), len(faces), len(idx)
        out.append(
            hu.PatchMeshData(
                mesh_index=k,
                points=scene.points[used],
                face_vertex_counts=counts.copy(),
                face_vertex_indices=local.astype(np.int32),
                vertex_radiance=rng.uniform(0, 2, (P, 3)),
                vertex_irradiance=rng.uniform(0, 5, (P, 3)),
                face_radiance=rng.uniform(0, 2, (F, 3)),
                face_irradiance=rng.uniform(0, 5, (F, 3)),
                lightmap_uv=rng.uniform(0, 1, (C, 2)) if with_lightmap else None,
                lightmap_path=f"./lightmaps/{scene.meshes[k].name}.exr" if with_lightmap else None,
            )
        )
    return out


def test_write_and_read_solution_layer(tmp_path):
    src = tmp_path / "in" / "cornell.usda"
    src.parent.mkdir()
    src.write_bytes(CORNELL.read_bytes())
    before = sha(src)
    scene = hu.read_scene(src)
    patches = _fake_solution(scene, with_lightmap=True)
    out = tmp_path / "out" / "solution.usda"
    hu.write_solution_layer(src, out, scene, patches, {"hirad:version": "0.1.0", "units": "W/m2", "fingerprint": "abc"})

    assert sha(src) == before
    assert out.is_file()
    # the text root and its arrays in a crate beside it; no temporary files left
    assert sorted(p.name for p in out.parent.iterdir()) == ["solution.arrays.usdc", "solution.usda"]
    assert (out.parent / "solution.arrays.usdc").read_bytes()[:8] == b"PXR-USDC"
    assert out.read_text().startswith("#usda")

    layer = Sdf.Layer.FindOrOpen(str(out))
    assert list(layer.subLayerPaths) == ["./solution.arrays.usdc", "../in/cornell.usda"]
    arrays_in_text = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda path: arrays_in_text.append(path) if (
        path.IsPropertyPath() and layer.GetAttributeAtPath(path) and layer.GetAttributeAtPath(path).typeName.isArray)
        else None)
    assert arrays_in_text == []
    assert layer.customLayerData["hirad:version"] == "0.1.0"
    assert layer.customLayerData["fingerprint"] == "abc"

    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.001)
    # input geometry hidden, solution meshes visible, world space (no parent transform)
    assert UsdGeom.Imageable(stage.GetPrimAtPath("/World/floor")).ComputeVisibility() == UsdGeom.Tokens.invisible
    # under the input's defaultPrim, which the layer names as its own
    assert layer.defaultPrim == "World"
    root = stage.GetPrimAtPath("/World/HiradSolution")
    assert root.IsA(UsdGeom.Scope) and root.GetParent().GetPath() == "/World"
    meshes = [p for p in root.GetChildren() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == 8
    for prim, pm in zip(meshes, patches):
        mesh = UsdGeom.Mesh(prim)
        assert UsdGeom.Imageable(prim).ComputeVisibility() == UsdGeom.Tokens.inherited
        assert UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()) == Gf.Matrix4d(1)
        assert mesh.GetDoubleSidedAttr().Get() is False
        api = UsdGeom.PrimvarsAPI(prim)
        for name, interp, n in (
            ("hirad:radiance", "vertex", len(pm.points)),
            ("hirad:irradiance", "vertex", len(pm.points)),
            ("hirad:patchRadiance", "uniform", len(pm.face_vertex_counts)),
            ("hirad:patchIrradiance", "uniform", len(pm.face_vertex_counts)),
            ("displayColor", "vertex", len(pm.points)),
            ("hirad:lightmapUV", "faceVarying", len(pm.face_vertex_indices)),
        ):
            pv = api.GetPrimvar(name)
            assert pv, name
            assert pv.GetInterpolation() == interp, name
            assert len(pv.Get()) == n, name
        assert api.GetPrimvar("hirad:radiance").GetTypeName() == Sdf.ValueTypeNames.Color3fArray
        assert api.GetPrimvar("hirad:lightmapUV").GetTypeName() == Sdf.ValueTypeNames.TexCoord2fArray
        dc = np.array(api.GetPrimvar("displayColor").Get())
        assert dc.min() >= 0 and dc.max() <= 1
        mat = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        assert mat, prim.GetPath()
        surf = mat.ComputeSurfaceSource()[0]
        assert surf.GetShaderId() == "UsdPreviewSurface"
        src_attr = surf.GetInput("emissiveColor").GetValueProducingAttributes()[0]
        assert UsdShade.Shader(src_attr.GetPrim()).GetShaderId() == "UsdUVTexture"

    sol = hu.read_solution_layer(out)
    assert len(sol.meshes) == 8
    assert sol.meters_per_unit == pytest.approx(0.001)
    assert sol.metadata["fingerprint"] == "abc"
    assert len(sol.cameras) == 1 and sol.cameras[0].vertical_fov_degrees == pytest.approx(39.3077, abs=0.1)
    by_index = {m.mesh_index: m for m in sol.meshes}
    for pm in patches:
        got = by_index[pm.mesh_index]
        np.testing.assert_allclose(got.points, pm.points, atol=1e-6)
        np.testing.assert_array_equal(got.face_vertex_counts, pm.face_vertex_counts)
        np.testing.assert_array_equal(got.face_vertex_indices, pm.face_vertex_indices)
        np.testing.assert_allclose(got.vertex_radiance, pm.vertex_radiance, rtol=1e-6)
        np.testing.assert_allclose(got.vertex_irradiance, pm.vertex_irradiance, rtol=1e-6)
        np.testing.assert_allclose(got.face_radiance, pm.face_radiance, rtol=1e-6)
        np.testing.assert_allclose(got.face_irradiance, pm.face_irradiance, rtol=1e-6)
        np.testing.assert_allclose(got.lightmap_uv, pm.lightmap_uv, atol=1e-6)
        assert got.lightmap_path == pm.lightmap_path
        assert got.source_path == scene.meshes[pm.mesh_index].path
    assert sha(src) == before


def test_solution_hides_instance_roots_once(tmp_path):
    stage, path = new_stage(tmp_path, mpu=0.01)
    proto = UsdGeom.Xform.Define(stage, "/Assets/Tile")
    add_quad(stage, "/Assets/Tile/a")
    add_quad(stage, "/Assets/Tile/b", z=1.0)
    stage.GetPrimAtPath("/Assets").SetSpecifier(Sdf.SpecifierClass)
    ref = UsdGeom.Xform.Define(stage, "/World/tile")
    ref.GetPrim().GetReferences().AddInternalReference(proto.GetPath())
    ref.GetPrim().SetInstanceable(True)
    stage.Save()
    scene = hu.read_scene(path)
    assert [m.hide_path for m in scene.meshes] == ["/World/tile", "/World/tile"]
    out = tmp_path / "sol.usda"
    hu.write_solution_layer(path, out, scene, _fake_solution(scene), {})
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert layer.GetPrimAtPath("/World/tile").specifier == Sdf.SpecifierOver
    assert layer.GetPrimAtPath("/World/tile/a") is None  # never authored inside the instance
    sol = hu.read_solution_layer(out)
    # cm stage: points round-trip in metres
    np.testing.assert_allclose(sol.meshes[1].points, scene.points[scene.face_vertex_indices[4:8]], atol=1e-6)
    assert stage_visibility(out, "/World/tile") == UsdGeom.Tokens.invisible


def stage_visibility(path, prim_path):
    stage = Usd.Stage.Open(str(path))  # keep the stage alive while the prim is used
    return UsdGeom.Imageable(stage.GetPrimAtPath(prim_path)).ComputeVisibility()


def test_failed_write_leaves_no_file(tmp_path, monkeypatch):
    src = tmp_path / "cornell.usda"
    src.write_bytes(CORNELL.read_bytes())
    scene = hu.read_scene(src)
    patches = _fake_solution(scene)
    out = tmp_path / "solution.usda"
    calls = {"n": 0}
    from hirad.usd import solution as hus

    real = hus._author_patch_mesh

    def flaky(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise RuntimeError("disk on fire")
        return real(*args, **kwargs)

    monkeypatch.setattr(hus, "_author_patch_mesh", flaky)
    with pytest.raises(RuntimeError, match="disk on fire"):
        hu.write_solution_layer(src, out, scene, patches, {})
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cornell.usda"]

    # a failure at export time (after the temp file exists) also leaves nothing behind
    monkeypatch.setattr(hus, "_author_patch_mesh", real)
    monkeypatch.setattr(hus.os, "replace", lambda *a: (_ for _ in ()).throw(OSError("no space")))
    with pytest.raises(OSError, match="no space"):
        hu.write_solution_layer(src, out, scene, patches, {})
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cornell.usda"]


def test_existing_output_replaced_atomically_and_input_protected(tmp_path):
    src = tmp_path / "cornell.usda"
    src.write_bytes(CORNELL.read_bytes())
    scene = hu.read_scene(src)
    out = tmp_path / "solution.usda"
    out.write_text("old")
    hu.write_solution_layer(src, out, scene, _fake_solution(scene), {})
    assert out.read_text().startswith("#usda")
    before = sha(src)
    with pytest.raises(hu.SceneError):
        hu.write_solution_layer(src, src, scene, _fake_solution(scene), {})
    assert sha(src) == before
    # nor through the arrays' crate a text layer writes beside itself
    crate_input = tmp_path / "room.arrays.usdc"
    Sdf.Layer.FindOrOpen(str(src)).Export(str(crate_input))
    before = sha(crate_input)
    with pytest.raises(hu.SceneError, match="refusing to overwrite the input scene"):
        hu.write_solution_layer(crate_input, tmp_path / "room.usda", hu.read_scene(crate_input),
                                _fake_solution(scene), {})
    assert sha(crate_input) == before and not (tmp_path / "room.usda").exists()


def test_bad_patch_shapes_rejected_before_writing(tmp_path):
    src = tmp_path / "cornell.usda"
    src.write_bytes(CORNELL.read_bytes())
    scene = hu.read_scene(src)
    patches = _fake_solution(scene)
    patches[0].vertex_radiance = patches[0].vertex_radiance[:-1]
    out = tmp_path / "solution.usda"
    with pytest.raises(ValueError, match="vertex_radiance"):
        hu.write_solution_layer(src, out, scene, patches, {})
    assert not out.exists()


def test_read_solution_layer_rejects_plain_scene(tmp_path):
    with pytest.raises(hu.SceneError, match="cornell_box.usda.*not a hirad solution"):
        hu.read_solution_layer(CORNELL)
    with pytest.raises(hu.SceneError, match="nothing.usda"):
        hu.read_solution_layer(tmp_path / "nothing.usda")
