"""Grids in a bake, against the furnace closed form, and the camera luminance image.

The furnace room: a closed 2 m cube, faces inward, every face reflectance rho = 0.5 and
emitted exitance E = 1 W/m^2 (emissiveColor E/pi). Its radiosity is uniform, B = E/(1 - rho)
= 2, and so is the radiance B/pi on every surface, so the illuminance on a small plane at any
point inside, facing any way, is pi x B/pi = B: Em = 2, U0 = Emin/Em = 1, whatever the grid.

Tolerances, from what the read-out does (SurfaceSolution.illuminance) and what was measured.
The direct half (E of B = 2) is the exact contour integral of every emitting element (all of
them here) times its E/pi: nothing occludes and the elements close the room, so those form
factors sum to 1 and give E to rounding. The indirect half is 512 hemisphere rays, each
returning the reflected radiance (B - E)/pi of the element it hits: exact for a uniform field
whatever the directions, so the error is only how far the solved elements depart from B = 2.
The hierarchical solve (eps 1e-5, 16 point-pair samples per link, Gauss-Seidel to 1e-6)
leaves single elements up to 4.2 % off (link sampling noise; area-weighted mean +0.11 %), but
each point's rays average over hundreds of elements: measured over the work plane, a wall
grid and every measure, |Em/B - 1| <= 1.4e-3 and 1 - U0 <= 4.8e-4 (a flat bake, 0.04 m^2
patches: 6.9e-4 and 7.4e-4). TOL = 3e-3 is twice the worst of those, and a read-out that
mishandles emitters fails it by two orders of magnitude (the direct part lost: Em = 1;
emission counted again as reflected light: Em = 3; a grid snapped to the elements: 1 - U0
about 0.04).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom

from hirad_e2e_helpers import furnace_box, write_config

from hirad.bake import bake
from hirad.studies import build_grids, evaluate_grids, resolve_room, study_from_dict
from hirad.studies.pictures import camera_luminance, camera_luminance_picture
from hirad.studies.report import LUMINANCE_FILE, Study, render_html, write_study
from hirad.studies.usdgrids import grids_from_stage

RHO, E, SIZE = 0.5, 1.0, 2.0
B = E / (1 - RHO)
PNG = b"\x89PNG\r\n\x1a\n"
TOL = 3e-3

GRIDS = {
    # the work plane over the room's floor, found by the room prim (resolve_room): every
    # upward-facing mesh face under /World is the floor (y = 0, Y up); 0.80 m default height,
    # 0.5 m border: the 1 x 1 m middle of the 2 x 2 m floor
    "room": {"kind": "workplane", "room": "/World", "spacing": 0.25},
    # a vertical wall grid 0.2 m in front of the x = 0 wall, facing +X (into the room)
    "wall": {"kind": "rectangle", "corner": [0.2, 0.3, 1.7], "edge_u": [0.0, 0.0, -1.4],
             "edge_v": [0.0, 1.4, 0.0], "normal": [1.0, 0.0, 0.0], "spacing": 0.35},
}


def _scene(root: Path) -> Path:
    scene = furnace_box(root / "furnace.usda", size=SIZE, reflectance=RHO, exitance=E)
    stage = Usd.Stage.Open(str(scene))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    cam = UsdGeom.Camera.Define(stage, "/World/Cam")  # looks down its -Z: at the z = 0 wall
    cam.AddTranslateOp().Set(Gf.Vec3d(1.0, 1.0, 1.9))
    # calculation surfaces: a Plane (never baked: hirad bakes Meshes) and an invisible Mesh
    # (skipped as geometry, read as a grid)
    desk = UsdGeom.Plane.Define(stage, "/World/Desk")
    desk.CreateAxisAttr("Y")
    desk.CreateWidthAttr(1.2)
    desk.CreateLengthAttr(0.6)
    desk.AddTranslateOp().Set(Gf.Vec3d(1.0, 0.75, 1.0))
    desk.GetPrim().CreateAttribute("hirad:grid", Sdf.ValueTypeNames.Bool).Set(True)
    desk.GetPrim().CreateAttribute("hirad:grid:spacing", Sdf.ValueTypeNames.Double).Set(0.2)
    sensor = UsdGeom.Mesh.Define(stage, "/World/Sensor")
    sensor.CreatePointsAttr([(1.8, 0.5, 0.5), (1.8, 0.5, 1.5), (1.8, 1.5, 1.5), (1.8, 1.5, 0.5)])
    sensor.CreateFaceVertexCountsAttr([4])
    sensor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])  # normal -X: facing into the room
    sensor.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    sensor.GetPrim().CreateAttribute("hirad:grid:name", Sdf.ValueTypeNames.String).Set("sensor")
    sensor.GetPrim().CreateAttribute("hirad:grid:spacing", Sdf.ValueTypeNames.Double).Set(0.25)
    sensor.GetPrim().CreateAttribute("hirad:grid:measure", Sdf.ValueTypeNames.Token).Set("cylindrical")
    stage.GetRootLayer().Save()
    return scene


@pytest.fixture(scope="module")
def furnace(tmp_path_factory):
    root = tmp_path_factory.mktemp("furnace_grids")
    scene = _scene(root)
    cfg = write_config(root / "c.yaml", scene, root / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-5, "min_area": 0.01, "samples": 16},
                       solver={"method": "gauss_seidel", "tolerance": 1e-6},
                       outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}},
                       grids=GRIDS, maintenance_factor=0.8)
    result = bake(cfg)
    return {"root": root, "scene": scene, "out": root / "out", "result": result}


def _csv(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_solved_radiosity_is_the_closed_form(furnace):
    res = furnace["result"]
    b = res.patch_radiosity @ np.array([0.2126, 0.7152, 0.0722])
    area = res.patches["area"]
    assert float(np.sum(b * area) / area.sum()) == pytest.approx(B, rel=TOL)
    assert np.abs(b / B - 1).max() < 0.1  # single elements: link sampling noise (4.2 % measured)


def test_room_work_plane_in_the_bake(furnace):
    """The bake's own grid over the named room: the points where resolve_room puts them, and
    the furnace's value at each."""
    gdir = furnace["out"] / "grids"
    values = _csv(gdir / "room.csv")
    # 1 x 1 m middle of the floor at spacing 0.25: 16 cell centres 0.625 .. 1.375, at y = 0.8
    assert len(values["x"]) == 16
    assert np.allclose(values["y"], 0.8) and np.allclose(values["ny"], 1.0)
    assert np.allclose(sorted(set(np.round(values["x"], 9))), [0.625, 0.875, 1.125, 1.375])
    assert np.allclose(sorted(set(np.round(values["z"], 9))), [0.625, 0.875, 1.125, 1.375])
    np.testing.assert_allclose(values["E_lx"], B, rtol=TOL)
    np.testing.assert_allclose(values["E_maintained_lx"], 0.8 * values["E_lx"], rtol=1e-12)
    report = json.loads((furnace["out"] / "report.json").read_text())
    st = report["grids"]["grids"]["room"]
    assert st["em"] == pytest.approx(B, rel=TOL)
    assert 1.0 - TOL <= st["u0"] <= 1.0 and 1.0 - TOL <= st["ud"] <= 1.0


def test_room_resolves_to_the_floor_only(furnace):
    stage = Usd.Stage.Open(str(furnace["scene"]))
    polys = resolve_room(stage, "/World", "Y")
    assert len(polys) == 1  # the floor; the ceiling faces down, the walls sideways
    assert np.allclose(polys[0][:, 1], 0.0)


@pytest.mark.parametrize("measure", [{"type": "planar"}, {"type": "vertical", "azimuth": 30.0},
                                     {"type": "cylindrical"}, {"type": "semi_cylindrical", "azimuth": 200.0}])
def test_furnace_u0_is_one_for_every_measure(furnace, measure):
    """Any orientation sees B: planar facing the wall, vertical, cylindrical (mean of vertical
    illuminances: B) and semi-cylindrical (the cylinder plus (E_v - E_v') / pi = B + 0)."""
    res = furnace["result"]
    grids = build_grids({"g": study_from_dict({"grids": {"g": {**GRIDS["wall"], "measure": measure}}}).grids["g"]},
                        up_axis="Y")
    (r,) = evaluate_grids(grids, res.illuminance_evaluator(512, 1))
    assert r.stats.em == pytest.approx(B, rel=TOL)
    assert 1.0 - TOL <= r.stats.u0 <= 1.0


def test_camera_luminance_of_the_furnace(furnace):
    """Every surface the camera sees has radiance B/pi: the luminance image is uniform."""
    res = furnace["result"]
    lum = camera_luminance(res, "/World/Cam", width=32, height=24, samples=2)
    assert lum.shape == (24, 32)
    np.testing.assert_allclose(lum, B / math.pi, rtol=2 * TOL)  # vertex-interpolated: 2.0e-3 measured
    png = camera_luminance_picture(res, "/World/Cam", width=32, height=24, samples=2)
    assert png.startswith(PNG)


def test_report_with_the_luminance_image(furnace, tmp_path):
    res = furnace["result"]
    grids = build_grids(study_from_dict({"grids": {"wall": GRIDS["wall"]}}), up_axis="Y")
    results = evaluate_grids(grids, res.illuminance_evaluator(64, 1), maintenance_factor=0.8)
    png = camera_luminance_picture(res, "/World/Cam", width=40, height=30, samples=1)
    study = Study(results=results, maintenance_factor=0.8, luminance=("Luminance of /World/Cam (cd/m²)", png))
    text = render_html(study)
    assert 'id="luminance"' in text and "Luminance of /World/Cam (cd/m²)" in text
    written = write_study(study, tmp_path / "s", pdf=False)
    assert (tmp_path / "s" / LUMINANCE_FILE).read_bytes() == png
    assert tmp_path / "s" / LUMINANCE_FILE in written["files"]


def test_usd_calculation_surfaces_in_the_furnace(furnace):
    """The scene's own calculation surfaces (a Plane and an invisible Mesh with hirad:grid
    attributes), evaluated with the bake's read-out: on them too Em = B and U0 = 1; neither
    was baked as geometry (the six walls are the only meshes)."""
    res = furnace["result"]
    report = json.loads((furnace["out"] / "report.json").read_text())
    assert report["counts"]["meshes"] == 6
    grids = {g.name: g for g in grids_from_stage(furnace["scene"])}
    assert set(grids) == {"Desk", "sensor"}
    assert len(grids["Desk"].points) == 6 * 3 and np.allclose(grids["Desk"].points[:, 1], 0.75)
    assert np.allclose(grids["sensor"].normals, [0, 1, 0])  # cylindrical: the point's direction is up
    assert len(grids["sensor"].points) == 16 and np.allclose(grids["sensor"].points[:, 0], 1.8)
    for r in evaluate_grids(list(grids.values()), res.illuminance_evaluator(512, 1)):
        assert r.stats.em == pytest.approx(B, rel=TOL), r.name
        assert 1.0 - TOL <= r.stats.u0 <= 1.0, r.name
