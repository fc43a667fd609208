"""The solution layer survives composition: it sits under the input's defaultPrim (which it
names as its own), so a stage that references solution.usda shows the baked meshes where
they were solved and moves them with the referencing prim's transform; every solution mesh
has a material that only emits the baked light (a viewer must not light it again); and the
colour space of what it writes is stated."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade  # noqa: E402

import hirad  # noqa: E402
from hirad import usd as hu  # noqa: E402
from hirad.config import config_from_dict  # noqa: E402
from hirad.usd.solution import COLOR_SPACE, arrays_path, find_solution_root, merge_arrays  # noqa: E402

REPO = Path(__file__).resolve().parents[3]
CORNELL = REPO / "configs" / "scenes" / "cornell_box.usda"
TIME = Usd.TimeCode.Default()


def _bake(tmp_path, lightmaps: bool):
    out = tmp_path / "out"
    cfg = config_from_dict({
        "scene": str(CORNELL), "output": str(out), "method": "flat",
        "meshing": {"max_patch_area": 0.01, "max_edge_length": 0.12},
        "formfactors": {"samples": 4},
        "solver": {"tolerance": 1e-3},
        "outputs": {"lightmaps": {"enabled": lightmaps, "texels_per_metre": 32},
                    "preview": {"enabled": False}},
    }, tmp_path)
    hirad.bake(cfg)
    return out / "solution.usda"


@pytest.fixture(scope="module")
def unlit_bake(tmp_path_factory):
    """A bake with lightmaps off (the case where no lightmap material exists)."""
    return _bake(tmp_path_factory.mktemp("nolightmaps"), lightmaps=False)


def _world_points(prim) -> np.ndarray:
    pts = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(TIME), dtype=np.float64)
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(TIME)).reshape(4, 4)
    return pts @ m[:3, :3] + m[3, :3]


def _solution_meshes(stage, under: str):
    return [p for p in Usd.PrimRange(stage.GetPrimAtPath(under))
            if p.IsA(UsdGeom.Mesh) and p.HasAttribute("primvars:hirad:radiance")]


def _reference_into_shot(tmp_path, solution: Path, placement: Gf.Matrix4d | None = None):
    shot_path = tmp_path / "shot.usda"
    shot = Usd.Stage.CreateNew(str(shot_path))
    UsdGeom.SetStageMetersPerUnit(shot, UsdGeom.GetStageMetersPerUnit(Usd.Stage.Open(str(solution))))
    UsdGeom.Xform.Define(shot, "/Shot")
    room = UsdGeom.Xform.Define(shot, "/Shot/Room")
    if placement is not None:
        room.AddTransformOp().Set(placement)
    room.GetPrim().GetReferences().AddReference(str(solution))
    shot.GetRootLayer().Save()
    return Usd.Stage.Open(str(shot_path))


def test_referenced_solution_shows_the_baked_meshes(unlit_bake, tmp_path):
    layer = Sdf.Layer.FindOrOpen(str(unlit_bake))
    assert layer.defaultPrim == "World"  # the input's defaultPrim, named by the layer itself
    own = Usd.Stage.Open(str(unlit_bake))
    expected = {p.GetName() for p in _solution_meshes(own, "/")}
    assert len(expected) == 8  # one per input mesh of the Cornell box

    shot = _reference_into_shot(tmp_path, unlit_bake)
    found = _solution_meshes(shot, "/Shot/Room")
    assert {p.GetName() for p in found} == expected
    for prim in found:
        assert UsdGeom.Imageable(prim).ComputeVisibility(TIME) == UsdGeom.Tokens.inherited, prim.GetPath()
        assert len(UsdGeom.PrimvarsAPI(prim).GetPrimvar("hirad:radiance").Get()) > 0
    # ... and the input meshes it replaces stay hidden in the shot
    for name in ("floor", "ceiling", "back_wall", "tall_block"):
        hidden = shot.GetPrimAtPath(f"/Shot/Room/{name}")
        assert hidden and UsdGeom.Imageable(hidden).ComputeVisibility(TIME) == UsdGeom.Tokens.invisible


def test_referenced_solution_lands_on_the_geometry_it_replaces(unlit_bake, tmp_path):
    # A shot that places the room somewhere else (rotated, scaled, moved): every baked mesh
    # must cover exactly the region its hidden input mesh covers there.
    placement = (Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(0, 1, 0), 30.0))
                 * Gf.Matrix4d().SetScale(2.0) * Gf.Matrix4d().SetTranslate(Gf.Vec3d(1000, 0, -500)))
    shot = _reference_into_shot(tmp_path, unlit_bake, placement)
    found = _solution_meshes(shot, "/Shot/Room")
    assert found
    for prim in found:
        source = prim.GetCustomDataByKey("hirad:sourcePath")  # e.g. /World/floor
        original = shot.GetPrimAtPath("/Shot/Room" + source[len("/World"):])
        assert original, source
        got, want = _world_points(prim), _world_points(original)
        np.testing.assert_allclose(got.min(axis=0), want.min(axis=0), atol=1e-2)  # stage units (mm)
        np.testing.assert_allclose(got.max(axis=0), want.max(axis=0), atol=1e-2)


def test_every_mesh_has_an_emission_only_material_without_lightmaps(unlit_bake):
    stage = Usd.Stage.Open(str(unlit_bake))
    meshes = _solution_meshes(stage, "/")
    assert meshes
    for prim in meshes:
        mat = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        assert mat and mat.GetPrim().IsValid(), f"{prim.GetPath()}: no material bound"
        surf = mat.ComputeSurfaceSource()[0]
        assert surf.GetShaderId() == "UsdPreviewSurface"
        # nothing a renderer could light: black diffuse, black specular
        assert tuple(surf.GetInput("diffuseColor").Get()) == (0, 0, 0)
        assert surf.GetInput("useSpecularWorkflow").Get() == 1
        assert tuple(surf.GetInput("specularColor").Get()) == (0, 0, 0)
        # the emission is the baked radiance primvar, read per point
        src = surf.GetInput("emissiveColor").GetConnectedSources()[0]
        assert src, f"{prim.GetPath()}: emissiveColor not connected"
        reader = UsdShade.Shader(src[0].source.GetPrim())
        assert reader.GetShaderId() == "UsdPrimvarReader_float3"
        assert reader.GetInput("varname").Get() == "hirad:radiance"
        assert UsdGeom.PrimvarsAPI(prim).HasPrimvar("hirad:radiance")


def test_colour_space_is_stated(unlit_bake):
    stage = Usd.Stage.Open(str(unlit_bake))
    assert Gf.ColorSpaceNames.LinearRec709 == COLOR_SPACE
    assert "Rec.709" in stage.GetRootLayer().customLayerData["hirad:colorSpace"]
    for prim in _solution_meshes(stage, "/"):
        for name in ("hirad:radiance", "hirad:irradiance", "hirad:patchRadiance", "hirad:patchIrradiance"):
            attr = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name).GetAttr()
            assert attr.GetColorSpace() == COLOR_SPACE, (prim.GetPath(), name)
        # and inherited by everything under the solution root
        assert Usd.ColorSpaceAPI.ComputeColorSpaceName(prim, Usd.ColorSpaceHashCache()) == COLOR_SPACE


def test_lightmap_material_reads_linear_data(tmp_path):
    solution = _bake(tmp_path, lightmaps=True)
    stage = Usd.Stage.Open(str(solution))
    meshes = _solution_meshes(stage, "/")
    assert len(meshes) == 8
    for prim in meshes:
        mat = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()[0]
        tex = UsdShade.Shader(mat.GetPrim().GetChild("Lightmap"))
        assert tex.GetShaderId() == "UsdUVTexture", prim.GetPath()
        assert tex.GetInput("sourceColorSpace").Get() == "raw"
        assert str(tex.GetInput("file").Get().path).endswith(".exr")
        surf = mat.ComputeSurfaceSource()[0]
        assert tuple(surf.GetInput("diffuseColor").Get()) == (0, 0, 0)
    # the layer reads back with the lightmap of every mesh
    sol = hu.read_solution_layer(solution)
    assert all(m.lightmap_path for m in sol.meshes)


# ---------------------------------------------------------------------------------------------
# written from hand-made inputs (no solve)
# ---------------------------------------------------------------------------------------------


def _quad_scene(tmp_path, default_prim: str | None, world_xform: Gf.Matrix4d | None = None):
    path = tmp_path / "room.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    if world_xform is not None:
        world.AddTransformOp().Set(world_xform)
    for k, z in enumerate((0.0, 50.0)):
        m = UsdGeom.Mesh.Define(stage, f"/World/q{k}")
        m.CreatePointsAttr([(0, 0, z), (100, 0, z), (100, 100, z), (0, 100, z)])
        m.CreateFaceVertexCountsAttr([4])
        m.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    if default_prim:
        stage.SetDefaultPrim(stage.GetPrimAtPath(default_prim))
    stage.GetRootLayer().Save()
    return path


def _patches_of(scene):
    out = []
    starts = np.concatenate([[0], np.cumsum(scene.face_vertex_counts)[:-1]])
    for k in range(len(scene.meshes)):
        faces = np.nonzero(scene.face_mesh == k)[0]
        idx = np.concatenate([scene.face_vertex_indices[starts[f]:starts[f] + scene.face_vertex_counts[f]]
                              for f in faces])
        used, local = np.unique(idx, return_inverse=True)
        P, F = len(used), len(faces)
        out.append(hu.PatchMeshData(mesh_index=k, points=scene.points[used],
                                    face_vertex_counts=scene.face_vertex_counts[faces].copy(),
                                    face_vertex_indices=local.astype(np.int32),
                                    vertex_radiance=np.full((P, 3), 0.5), vertex_irradiance=np.full((P, 3), 1.5),
                                    face_radiance=np.full((F, 3), 0.5), face_irradiance=np.full((F, 3), 1.5)))
    return out


def test_transformed_default_prim_keeps_the_solution_in_place(tmp_path):
    # /World scaled and moved: the solution's points are written in /World's frame, so the
    # composed stage puts them where the input's meshes are, and reading the layer back gives
    # the world metres the scene reader gave.
    xf = Gf.Matrix4d().SetScale(Gf.Vec3d(2.0, 1.0, 0.5)) * Gf.Matrix4d().SetTranslate(Gf.Vec3d(10, 20, 30))
    src = _quad_scene(tmp_path, "/World", xf)
    scene = hu.read_scene(src)
    out = tmp_path / "out" / "solution.usda"
    hu.write_solution_layer(src, out, scene, _patches_of(scene), {})
    stage = Usd.Stage.Open(str(out))
    assert stage.GetRootLayer().defaultPrim == "World"
    for prim in _solution_meshes(stage, "/World/HiradSolution"):
        original = stage.GetPrimAtPath(prim.GetCustomDataByKey("hirad:sourcePath"))
        np.testing.assert_allclose(_world_points(prim), _world_points(original), atol=1e-4)
    sol = hu.read_solution_layer(out)
    assert len(sol.meshes) == 2
    for m in sol.meshes:
        want = scene.points[np.unique(scene.face_vertex_indices[4 * m.mesh_index:4 * m.mesh_index + 4])]
        np.testing.assert_allclose(m.points, want, atol=1e-6)


def test_input_without_default_prim_gets_a_solution_root_of_its_own(tmp_path):
    src = _quad_scene(tmp_path, None)
    scene = hu.read_scene(src)
    out = tmp_path / "solution.usda"
    hu.write_solution_layer(src, out, scene, _patches_of(scene), {})
    layer = Sdf.Layer.FindOrOpen(str(out))
    assert layer.defaultPrim == "HiradSolution"
    shot = _reference_into_shot(tmp_path, out)
    found = _solution_meshes(shot, "/Shot/Room")
    assert len(found) == 2
    assert all(UsdGeom.Imageable(p).ComputeVisibility(TIME) == UsdGeom.Tokens.inherited for p in found)
    assert len(hu.read_solution_layer(out).meshes) == 2


def test_layers_with_the_old_root_still_read(tmp_path):
    # Layers written before the move kept /HiradSolution at the root and did not record it.
    src = _quad_scene(tmp_path, "/World")
    scene = hu.read_scene(src)
    out = tmp_path / "solution.usda"
    hu.write_solution_layer(src, out, scene, _patches_of(scene), {})
    # ... in one file, its arrays in it
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.TransferContent(Sdf.Layer.FindOrOpen(str(out)))
    assert merge_arrays(layer, out)
    layer.subLayerPaths.remove("./" + arrays_path(out).name)
    data = dict(layer.customLayerData)
    del data["hirad:solutionRoot"]
    layer.customLayerData = data
    old = tmp_path / "old.usda"
    edit = Sdf.Layer.CreateNew(str(old))
    edit.TransferContent(layer)
    Sdf.CopySpec(layer, "/World/HiradSolution", edit, "/HiradSolution")
    del edit.GetPrimAtPath("/World").nameChildren["HiradSolution"]
    edit.Save()
    stage = Usd.Stage.Open(str(old))
    assert find_solution_root(stage).GetPath() == "/HiradSolution"
    assert len(hu.read_solution_layer(old).meshes) == 2


def test_merge_reads_the_arrays_as_written_not_a_layer_held_open(tmp_path):
    # A stage a user keeps open on an earlier bake's output holds its crate layer; the solution
    # written again at the same path must be read as it is on disk, not as that layer was.
    from pxr import Vt

    from hirad.usd.solution import export_solution

    def layer_with(x: float) -> Sdf.Layer:
        layer = Sdf.Layer.CreateAnonymous(".usda")
        prim = Sdf.CreatePrimInLayer(layer, "/World/Mesh")
        prim.specifier, prim.typeName = Sdf.SpecifierDef, "Mesh"
        Sdf.AttributeSpec(prim, "points", Sdf.ValueTypeNames.Point3fArray).default = \
            Vt.Vec3fArray([Gf.Vec3f(x, 0, 0)] * 3)
        return layer

    out = tmp_path / "solution.usda"
    export_solution(layer_with(1.0), out, [])
    held = Sdf.Layer.FindOrOpen(str(arrays_path(out)))
    assert held.GetAttributeAtPath("/World/Mesh.points").default[0][0] == 1.0
    export_solution(layer_with(2.0), out, [])
    merged = Sdf.Layer.CreateAnonymous(".usda")
    merged.TransferContent(Sdf.Layer.OpenAsAnonymous(str(out)))
    assert merge_arrays(merged, out)
    assert merged.GetAttributeAtPath("/World/Mesh.points").default[0][0] == 2.0
