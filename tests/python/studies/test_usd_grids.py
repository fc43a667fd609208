"""Calculation surfaces authored in USD (hirad.studies.usdgrids.grids_from_stage): a Plane and
a Mesh with hirad:grid attributes become grids on their surfaces; bad attributes are errors
naming the prim and the attribute."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from hirad.studies import StudyError, build_grids, study_from_dict
from hirad.studies.usdgrids import grids_from_stage


def _stage(up="Z", mpu=1.0):
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up == "Z" else UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.Xform.Define(stage, "/World")
    return stage


def _set(prim, name, type_name, value):
    prim.CreateAttribute(name, type_name).Set(value)


def _plane(stage, path, width, length, axis="Z", translate=None, rotate_x=None, **attrs):
    p = UsdGeom.Plane.Define(stage, path)
    p.CreateWidthAttr(width)
    p.CreateLengthAttr(length)
    p.CreateAxisAttr(axis)
    if translate is not None:  # xformOpOrder [translate, rotateX]: rotated, then moved
        p.AddTranslateOp().Set(Gf.Vec3d(*translate))
    if rotate_x is not None:
        p.AddRotateXOp().Set(rotate_x)
    prim = p.GetPrim()
    _set(prim, "hirad:grid", Sdf.ValueTypeNames.Bool, True)
    types = {str: Sdf.ValueTypeNames.String, float: Sdf.ValueTypeNames.Double, int: Sdf.ValueTypeNames.Int}
    for k, v in attrs.items():
        tn = Sdf.ValueTypeNames.Token if k in ("measure", "rounding") else types[type(v)]
        _set(prim, f"hirad:grid:{k}", tn, v)
    return prim


def _mesh(stage, path, points, counts, indices, **attrs):
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in points]))
    m.CreateFaceVertexCountsAttr(list(counts))
    m.CreateFaceVertexIndicesAttr(list(indices))
    prim = m.GetPrim()
    types = {str: Sdf.ValueTypeNames.String, float: Sdf.ValueTypeNames.Double, int: Sdf.ValueTypeNames.Int}
    for k, v in attrs.items():
        tn = Sdf.ValueTypeNames.Token if k in ("measure", "rounding") else types[type(v)]
        _set(prim, f"hirad:grid:{k}", tn, v)
    return prim


def test_plane_is_the_same_grid_as_a_rectangle_spec():
    stage = _stage()
    _plane(stage, "/World/Desk", 1.6, 0.8, translate=(2.0, 1.0, 0.75), name="desk", spacing=0.2)
    (g,) = grids_from_stage(stage)
    assert g.name == "desk" and g.kind == "plane" and g.source == "/World/Desk"
    # the rectangle of the config with the same corner, edges and spacing
    spec = study_from_dict({"grids": {"desk": {"kind": "rectangle", "corner": [1.2, 0.6, 0.75],
                                               "edge_u": [1.6, 0.0, 0.0], "edge_v": [0.0, 0.8, 0.0],
                                               "spacing": 0.2}}})
    (ref,) = build_grids(spec)
    assert np.allclose(g.points, ref.points, atol=1e-12)
    assert np.allclose(g.normals, [0, 0, 1])
    assert len(g.points) == 8 * 4 and g.area == pytest.approx(1.28)
    assert np.allclose(g.points[:, 2], 0.75)
    assert g.points[:, 0].min() == pytest.approx(1.3) and g.points[:, 0].max() == pytest.approx(2.7)


def test_plane_axis_transform_offset_and_meters_per_unit():
    # centimetres; a Y-axis plane (in the xz plane, normal +Y) turned 90 deg about X: its
    # normal +Y goes to +Z; 40 cm offset along it
    stage = _stage(up="Z", mpu=0.01)
    _plane(stage, "/World/P", 200.0, 100.0, axis="Y", rotate_x=90.0, translate=(0.0, 0.0, 50.0),
           spacing=25.0, offset=40.0)
    (g,) = grids_from_stage(stage)
    assert g.name == "P"
    assert np.allclose(g.normals, [0, 0, 1], atol=1e-9)
    # 2 m x 1 m in metres at z = 0.5 + 0.4 m; spacing 0.25 m: 8 x 4 points
    assert len(g.points) == 32 and g.area == pytest.approx(2.0)
    assert np.allclose(g.points[:, 2], 0.9)
    assert g.points[:, 0].min() == pytest.approx(-0.875) and g.points[:, 0].max() == pytest.approx(0.875)
    assert g.points[:, 1].min() == pytest.approx(-0.375) and g.points[:, 1].max() == pytest.approx(0.375)


def test_planar_mesh_union_of_faces_with_shared_edges_and_border():
    # an L-shaped floor of three unit squares at z = 0.8, two faces sharing an edge: the union
    stage = _stage()
    pts = [(0, 0, .8), (1, 0, .8), (2, 0, .8), (0, 1, .8), (1, 1, .8), (2, 1, .8), (0, 2, .8), (1, 2, .8)]
    _mesh(stage, "/World/Floor", pts, [4, 4, 4], [0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 7, 6], spacing=0.25)
    (g,) = grids_from_stage(stage)
    assert g.kind == "mesh" and g.name == "Floor"
    assert len(g.points) == 48  # 3 unit squares x 16 cells of 0.25 m
    assert g.area == pytest.approx(3.0)
    assert np.allclose(g.normals, [0, 0, 1]) and np.allclose(g.points[:, 2], 0.8)
    assert not ((g.points[:, 0] > 1) & (g.points[:, 1] > 1)).any()  # the L's notch
    assert g.layout is not None and g.layout.nu == 8 and g.layout.nv == 8
    # a 0.25 m border: nothing within 0.25 m of the outline (the shared edge is inside)
    stage2 = _stage()
    _mesh(stage2, "/World/Floor", pts, [4, 4, 4], [0, 1, 4, 3, 1, 2, 5, 4, 3, 4, 7, 6], spacing=0.25,
          border=0.25)
    (b,) = grids_from_stage(stage2)
    x, y = b.points[:, 0], b.points[:, 1]
    assert (x >= 0.25).all() and (y >= 0.25).all() and (x <= 1.75).all() and (y <= 1.75).all()
    # both sides of the edge x = 1 the two lower faces share (not outline: no border there)
    assert (np.isclose(x, 0.875) & (y < 1)).any() and (np.isclose(x, 1.125) & (y < 1)).any()


def test_wall_mesh_faces_its_normal_and_measures_vertical():
    # a wall in the plane y = 3 facing -Y (winding), measured as vertical illuminance facing -Y
    stage = _stage()
    _mesh(stage, "/World/Wall", [(0, 3, 0), (0, 3, 2), (4, 3, 2), (4, 3, 0)], [4], [0, 3, 2, 1],
          spacing=0.5, offset=0.01, measure="vertical", azimuth=270.0)
    (g,) = grids_from_stage(stage)
    assert np.allclose(g.normals, [0, -1, 0], atol=1e-12)
    assert np.allclose(g.sensor_normals, [0, -1, 0], atol=1e-12)
    assert np.allclose(g.points[:, 1], 2.99)
    assert len(g.points) == 8 * 4


def test_curved_mesh_gets_points_per_face_weighted_by_area():
    # a folded strip: two unit squares at 90 degrees (floor and wall), not one plane
    stage = _stage()
    _mesh(stage, "/World/Fold", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (1, 0, 1), (1, 1, 1)],
          [4, 4], [0, 1, 2, 3, 1, 4, 5, 2], spacing=0.5, measure="planar")
    (g,) = grids_from_stage(stage)
    assert len(g.points) == 8
    up = g.normals[:, 2] > 0.99
    side = g.normals[:, 0] < -0.99  # (1,0,0),(1,0,1),(1,1,1): normal -X
    assert up.sum() == 4 and side.sum() == 4
    assert g.weights.sum() == pytest.approx(2.0) and g.area == pytest.approx(2.0)
    assert np.allclose(g.points[side, 0], 1.0)


def test_unmarked_and_disabled_prims_are_not_grids():
    stage = _stage()
    UsdGeom.Plane.Define(stage, "/World/Plain")
    p = _plane(stage, "/World/Off", 1.0, 1.0)
    p.GetAttribute("hirad:grid").Set(False)
    assert grids_from_stage(stage) == []


@pytest.mark.parametrize("attr, type_name, value, words", [
    ("hirad:grid:spacing", Sdf.ValueTypeNames.Double, -0.5, "spacing"),
    ("hirad:grid:spacing", Sdf.ValueTypeNames.String, "dense", "spacing"),
    ("hirad:grid:measure", Sdf.ValueTypeNames.Token, "spherical", "measure"),
    ("hirad:grid:azimuth", Sdf.ValueTypeNames.Double, 30.0, "azimuth"),  # planar takes no azimuth
    ("hirad:grid:border", Sdf.ValueTypeNames.Double, -1.0, "border"),
    ("hirad:grid:name", Sdf.ValueTypeNames.String, "a/b", "name"),
    ("hirad:grid:spacingg", Sdf.ValueTypeNames.Double, 0.5, "not a hirad grid attribute"),
    ("hirad:grid", Sdf.ValueTypeNames.Int, 1, "bool"),
])
def test_bad_attributes_name_the_prim_and_attribute(attr, type_name, value, words):
    stage = _stage()
    p = UsdGeom.Plane.Define(stage, "/World/Bad").GetPrim()
    _set(p, attr, type_name, value)
    with pytest.raises(StudyError) as e:
        grids_from_stage(stage)
    msg = str(e.value)
    assert "/World/Bad" in msg and attr in msg and words in msg, msg


def test_vertical_needs_azimuth_named():
    stage = _stage()
    _plane(stage, "/World/V", 1.0, 1.0, measure="vertical")
    with pytest.raises(StudyError, match=r"/World/V: attribute hirad:grid:azimuth"):
        grids_from_stage(stage)


def test_duplicate_names_and_wrong_prim_type():
    stage = _stage()
    _plane(stage, "/World/A", 1.0, 1.0, name="g")
    _plane(stage, "/World/B", 1.0, 1.0, name="g")
    with pytest.raises(StudyError, match=r"/World/B: attribute hirad:grid:name: 'g' is also the grid of /World/A"):
        grids_from_stage(stage)
    stage = _stage()
    s = UsdGeom.Sphere.Define(stage, "/World/S").GetPrim()
    _set(s, "hirad:grid", Sdf.ValueTypeNames.Bool, True)
    with pytest.raises(StudyError, match=r"/World/S: .*Mesh or a Plane"):
        grids_from_stage(stage)


def test_from_a_file_path_and_y_up(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "s.usda"))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.Xform.Define(stage, "/World")
    _plane(stage, "/World/Floor", 2.0, 2.0, axis="Y", translate=(0.0, 0.8, 0.0), spacing=0.5, measure="cylindrical")
    stage.GetRootLayer().Save()
    (g,) = grids_from_stage(tmp_path / "s.usda")
    assert len(g.points) == 16 and np.allclose(g.points[:, 1], 0.8)
    # cylindrical in a Y-up scene: horizontal sensors (no Y component), 25 per point
    assert len(g.sensor_points) == 16 * 25 and np.allclose(g.sensor_normals[:, 1], 0.0)
    with pytest.raises(StudyError, match="cannot open"):
        grids_from_stage(tmp_path / "missing.usda")
