"""Luminaires through a whole bake (issue 13): USD SphereLight as a point, a spot (ShapingAPI
cone), a config `lights:` entry with an IES file, read by the bake's calculation grids and by
`hirad grid` on the stored bake; the energy balance with the luminaires' exact flux.

Closed forms: an isotropic point of intensity I at height h over a black floor gives
E = I h / d^3 at a floor point at distance d; a hard cone cuts it to 0 outside; a profile
read at one of its own nodes gamma gives E = I(gamma) cos(gamma) / d^2. A closed room of
uniform reflectance absorbs everything the luminaires emit.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from hirad_e2e_helpers import assert_no_output, run_cli, write_config

from hirad.bake import bake

H = 3.0
FLOOR_POINTS = [(0.0, 0.0), (1.0, 0.0), (0.0, 2.0), (1.5, 1.5), (3.0, 0.0)]


def _usda(body: str, floor_rgb=(0.0, 0.0, 0.0), closed=False) -> str:
    """A Z-up stage in metres: a 12 x 12 m floor of the given displayColor (and, `closed`, the
    5 other faces of a 12 x 12 x 6 box around it, facing in) plus `body` (lights)."""
    r, g, b = floor_rgb
    faces = "[(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)]"
    counts, idx = "[4]", "[0, 1, 2, 3]"
    if closed:
        faces = ("[(-6,-6,0),(6,-6,0),(6,6,0),(-6,6,0),(-6,-6,6),(6,-6,6),(6,6,6),(-6,6,6)]")
        counts = "[4, 4, 4, 4, 4, 4]"
        idx = "[0,1,2,3, 4,7,6,5, 0,4,5,1, 1,5,6,2, 2,6,7,3, 3,7,4,0]"
    return f"""#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Z"
)
def Xform "World"
{{
    def Mesh "Floor"
    {{
        int[] faceVertexCounts = {counts}
        int[] faceVertexIndices = {idx}
        point3f[] points = {faces}
        color3f[] primvars:displayColor = [({r}, {g}, {b})]
        uniform token subdivisionScheme = "none"
    }}
{body}
}}
"""


def _sphere(name: str, intensity: float, radius: float, extra: str = "", apis: str = "") -> str:
    schemas = f'prepend apiSchemas = [{apis}]' if apis else ""
    return f"""    def SphereLight "{name}" (
        {schemas}
    )
    {{
        float inputs:intensity = {intensity}
        float inputs:radius = {radius}
        bool treatAsPoint = 1
        double3 xformOp:translate = (0, 0, {H})
        uniform token[] xformOpOrder = ["xformOp:translate"]
{extra}
    }}
"""


def _points_grid(root: Path) -> dict:
    (root / "floor.csv").write_text("x,y,z,nx,ny,nz\n" + "".join(f"{x},{y},0.0005,0,0,1\n" for x, y in FLOOR_POINTS))
    return {"floor": {"kind": "points", "file": "floor.csv"}}


def _grid_values(out: Path, name: str = "floor") -> np.ndarray:
    with open(out / "grids" / f"{name}.csv", newline="") as f:
        return np.array([float(r["E_lx"]) for r in csv.DictReader(f)])


def _bake(root: Path, usda: str, **extra):
    scene = root / "scene.usda"
    scene.write_text(usda)
    sections = {"meshing": {"max_patch_area": 0.5, "max_edge_length": 1.0},
                "outputs": {"preview": {"enabled": False}, "lightmaps": {"enabled": False},
                            "volume": {"enabled": False}},
                "grids": _points_grid(root)}
    sections.update(extra)
    cfg = write_config(root / "c.yaml", scene, root / "out", **sections)
    return cfg, bake(cfg, quiet=True)


def _isotropic_e(i: float, x: float, y: float, z: float = 0.0005) -> float:
    d2 = x * x + y * y + (H - z) ** 2
    return i * (H - z) / d2 ** 1.5


def test_sphere_light_as_a_point_over_a_black_floor(tmp_path):
    """SphereLight r = 0.05 m, treatAsPoint, L = 1000 / (pi r^2) nits: an isotropic 1000 cd
    point (I = L pi r^2, the sphere's own power). The grid reads I h / d^3 within 1e-4; the
    report's energy balance carries its exact flux 4 pi 1000 lm; the luminaire schedule names it."""
    i = 1000.0
    lum = i / (math.pi * 0.05 ** 2)
    cfg, result = _bake(tmp_path, _usda(_sphere("Bulb", lum, 0.05)))
    out = tmp_path / "out"
    got = _grid_values(out)
    want = np.array([_isotropic_e(i, x, y) for x, y in FLOOR_POINTS])
    np.testing.assert_allclose(got, want, rtol=1e-4)
    report = json.loads((out / "report.json").read_text())
    flux = report["energy_balance"]["luminaire_flux_W"]
    assert flux == pytest.approx([4 * math.pi * i] * 3, rel=1e-6)  # float32 USD attributes
    html = (out / "grids" / "report.html").read_text()
    assert "Bulb" in html and f"{4 * math.pi * i:.0f}"[:4] in html.replace(",", "")
    assert (out / "luminaires.npz").is_file()


def test_hirad_grid_on_the_stored_bake_keeps_the_luminaires(tmp_path):
    """`hirad grid` reads luminaires.npz beside the layer: the same closed-form values; with
    the file gone it fails (exit 3) and writes nothing, instead of losing the light."""
    i = 500.0
    cfg, _ = _bake(tmp_path, _usda(_sphere("Bulb", i / (math.pi * 0.05 ** 2), 0.05)))
    out = tmp_path / "out"
    (tmp_path / "g.yaml").write_text("grids:\n  floor:\n    kind: points\n    file: floor.csv\n")
    proc = run_cli("grid", out / "solution.usda", tmp_path / "g.yaml", "--output", tmp_path / "g_out")
    assert proc.returncode == 0, proc.stderr
    with open(next((tmp_path / "g_out").rglob("floor.csv")), newline="") as f:
        got = np.array([float(r["E_lx"]) for r in csv.DictReader(f)])
    np.testing.assert_allclose(got, [_isotropic_e(i, x, y) for x, y in FLOOR_POINTS], rtol=1e-4)
    (out / "luminaires.npz").unlink()
    proc = run_cli("grid", out / "solution.usda", tmp_path / "g.yaml", "--output", tmp_path / "g_out2")
    assert proc.returncode == 3 and "luminaires" in proc.stderr, proc.stderr
    assert_no_output(tmp_path / "g_out2")


def test_spot_cone_cuts_the_light_outside_its_angle(tmp_path):
    """ShapingAPI inputs:shaping:cone:angle = 30 (no softness) on the point, aimed down (-Z): floor
    points within 30 degrees of the nadir read I h / d^3, points beyond read 0."""
    i = 800.0
    extra = "        float inputs:shaping:cone:angle = 30\n        float inputs:shaping:cone:softness = 0"
    cfg, _ = _bake(tmp_path, _usda(_sphere("Spot", i / (math.pi * 0.05 ** 2), 0.05, extra, '"ShapingAPI"')))
    got = _grid_values(tmp_path / "out")
    for (x, y), e in zip(FLOOR_POINTS, got):
        angle = math.degrees(math.atan2(math.hypot(x, y), H))
        if angle < 29:
            assert e == pytest.approx(_isotropic_e(i, x, y), rel=2e-3), (x, y)
        elif angle > 31:
            assert e == 0.0, (x, y, e)


IES = """IESNA:LM-63-2002
[TEST] hirad test profile
TILT=NONE
1 -1 1 3 1 1 2 0 0 0
1 1 10
0 45 90
0
1000 707.1 0
"""


def test_config_light_with_an_ies_file_absolute_photometry(tmp_path):
    """A `lights:` entry at (0, 0, 3) with an IES file (absolute photometry, lumens -1) aimed
    down: at the nadir E = 1000 / h^2 and at 45 degrees (a node of the file) E = 707.1
    cos(45) / d^2, on a floor the USD scene leaves unlit (it has no light of its own)."""
    (tmp_path / "down.ies").write_text(IES)
    cfg, _ = _bake(tmp_path, _usda(""), lights=[{"name": "downlight", "position": [0.0, 0.0, H],
                                                 "ies": "down.ies"}])
    got = _grid_values(tmp_path / "out")
    h = H - 0.0005
    assert got[0] == pytest.approx(1000.0 / h ** 2, rel=1e-4)
    # (3, 0): 45 degrees from the nadir (to 1e-4 rad for the sensor's 0.5 mm lift)
    d2 = 9.0 + h * h
    assert got[4] == pytest.approx(707.1 * (h / math.sqrt(d2)) / d2, rel=2e-3)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert "downlight" in (tmp_path / "out" / "grids" / "report.html").read_text()
    assert report["energy_balance"]["luminaire_flux_W"][1] > 0


def test_no_light_at_all_is_a_clear_error(tmp_path):
    scene = tmp_path / "dark.usda"
    scene.write_text(_usda(""))
    cfg = write_config(tmp_path / "c.yaml", scene, tmp_path / "out",
                       outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}})
    proc = run_cli("bake", "-q", cfg)
    assert proc.returncode == 3 and "nothing emits light" in proc.stderr, proc.stderr
    assert_no_output(tmp_path / "out")


@pytest.mark.parametrize("method", ["flat", "hierarchical"])
def test_energy_balance_closes_with_a_luminaire_in_a_closed_grey_room(tmp_path, method):
    """A 12 x 12 x 6 m closed box of reflectance 0.5 lit by a 1000 cd point: the report's
    emitted power is the luminaire's exact flux and absorbed + escaped match it within 1 %."""
    i = 1000.0
    extra = {"method": method}
    if method == "hierarchical":
        extra["hierarchy"] = {"epsilon": 1e-4, "min_area": 0.05}
    cfg, _ = _bake(tmp_path, _usda(_sphere("Bulb", i / (math.pi * 0.05 ** 2), 0.05), floor_rgb=(0.5, 0.5, 0.5),
                                   closed=True), **extra)
    bal = json.loads((tmp_path / "out" / "report.json").read_text())["energy_balance"]
    assert bal["emitted_W"][1] == pytest.approx(4 * math.pi * i, rel=1e-6)  # float32 USD attributes
    assert bal["luminaire_received_W"][1] == pytest.approx(4 * math.pi * i, rel=0.005)
    assert bal["max_relative_error"] < 0.01


def test_hirad_info_lists_the_luminaires_with_their_flux(tmp_path):
    scene = tmp_path / "scene.usda"
    scene.write_text(_usda(_sphere("Bulb", 100.0 / (math.pi * 0.05 ** 2), 0.05)))
    proc = run_cli("info", scene)
    assert proc.returncode == 0, proc.stderr
    line = next(l for l in proc.stdout.splitlines() if l.startswith("luminaires:"))
    assert line.startswith("luminaires: 1,") and float(line.split(",")[1].split()[0]) == pytest.approx(
        4 * math.pi * 100.0, rel=1e-5)
    assert "/World/Bulb" in proc.stdout
