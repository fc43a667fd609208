"""`hirad grid` on a stored daylit solution sees the sun and sky through the glass as the bake did.

The bake evaluates its grids with the faces' glazing (direct light passes a glazed face with
tau0 r(cos theta)) and the sun and sky as distant lights. The solution layer holds neither; the
bake keeps them in daylight.npz beside it and `hirad grid` applies them. The example room
(configs/daylit_room.yaml: a uniform sky and a 60,000 lux sun through a glazed south window) is
baked, then `hirad grid` reads the layer at the bake grid's very points (a points file written
from the bake's CSV) with the bake's seed and rays:

* every point agrees with the bake's value within 2e-3 relative. The reasoning for the bound: the
  same points, seeds and rays meet the same surfaces, read from a layer of float32 points and
  radiance (rounding ~6e-8); a ray that grazes an edge could meet another surface once the
  geometry is rounded, which changes one of the 512 hemisphere rays, about 1/512 = 2e-3 of the
  indirect part, at most. (Measured: ~1e-9.)
* the same layer with its glass opaque (as `hirad grid` read it before) gives the points in the
  sun patch a small fraction of the bake's value: the test's sunlit points are those the bake
  gives more than three times the grid's median, and the sun through the window is what lights
  them.
* a layer that names its daylight file when the file is missing is a scene error (exit 3) and
  writes nothing.
"""

from __future__ import annotations

import csv
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

pytest.importorskip("hirad._engine")

from hirad_e2e_helpers import run_cli  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
ROOM = ROOT / "configs" / "daylit_room.yaml"
QUIET = ["outputs.lightmaps.enabled=false", "outputs.preview.enabled=false"]


def _csv(path: Path) -> dict:
    rows = list(csv.reader(path.open()))
    return {h: np.array([float(r[i]) for r in rows[1:]]) for i, h in enumerate(rows[0])}


@pytest.fixture(scope="module")
def daylit(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("glazing")
    out = tmp / "room"
    r = run_cli("bake", ROOM, "--quiet", "--set", f"output={out}", *[x for o in QUIET for x in ("--set", o)])
    assert r.returncode == 0, r.stderr
    baked = _csv(out / "grids" / "workplane.csv")
    points = tmp / "points.csv"
    with points.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "z", "nx", "ny", "nz"])
        for k in range(len(baked["x"])):  # the CSV keeps every digit (repr): the very points
            w.writerow([repr(float(baked[c][k])) for c in ("x", "y", "z", "nx", "ny", "nz")])
    study = tmp / "at_bake_points.yaml"
    study.write_text(yaml.safe_dump({"grids": {"workplane": {"kind": "points", "file": "points.csv"}}}))
    return {"tmp": tmp, "out": out, "baked": baked, "study": study}


def test_grid_on_the_layer_reads_the_bake_grid_through_the_glass(daylit):
    out = daylit["tmp"] / "read"
    r = run_cli("grid", daylit["out"] / "solution.usda", daylit["study"], "-o", out, "--seed", 1, "--rays", 512)
    assert r.returncode == 0, r.stderr
    read = _csv(out / "workplane.csv")
    baked = daylit["baked"]
    assert np.array_equal(read["x"], baked["x"]) and np.array_equal(read["y"], baked["y"])
    assert np.allclose(read["E_lx"], baked["E_lx"], rtol=2e-3, atol=0)
    assert read["E_lx"].mean() == pytest.approx(baked["E_lx"].mean(), rel=1e-4)


def test_opaque_glass_would_lose_the_sun_patch(daylit):
    """What the read-out would be with the glass opaque: the sunlit points lose most of their
    light (so the agreement above is the glazing's doing)."""
    from hirad.solution import load_solution
    from hirad.studies.usdgrids import apply_stored_daylight

    baked = daylit["baked"]
    e = baked["E_lx"]
    sunlit = e > 3 * np.median(e)
    assert 3 <= sunlit.sum() < len(e) // 2  # a patch of sun on the work plane
    pts = np.stack([baked["x"], baked["y"], baked["z"]], axis=1)[sunlit]
    nrm = np.stack([baked["nx"], baked["ny"], baked["nz"]], axis=1)[sunlit]
    sol = load_solution(daylit["out"] / "solution.usda")
    applied = apply_stored_daylight(sol, daylit["out"] / "solution.usda")
    assert applied["glazed_faces"] > 0 and applied["distant_lights"] == 2  # the sun and the sky
    through = sol.illuminance_evaluator(512, 1)(pts, nrm)
    assert np.allclose(through, e[sunlit], rtol=2e-3)
    sol.transmittance = None  # glass opaque, as the layer alone says
    sol._field = None
    opaque = sol.illuminance_evaluator(512, 1)(pts, nrm)
    assert np.all(opaque < 0.2 * e[sunlit]), (opaque, e[sunlit])


def test_a_missing_daylight_file_is_a_scene_error(daylit):
    copy = daylit["tmp"] / "copy"  # the same depth as the bake's output: its sublayer path still resolves
    shutil.copytree(daylit["out"], copy)
    (copy / "daylight.npz").unlink()
    out = daylit["tmp"] / "none"
    r = run_cli("grid", copy / "solution.usda", daylit["study"], "-o", out)
    assert r.returncode == 3, r.stderr
    assert "daylight.npz" in r.stderr and "missing" in r.stderr
    assert not out.exists()
