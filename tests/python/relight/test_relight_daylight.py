"""Light groups and relighting with daylight (issue 16): the sun and the sky are emitters a group
can select (by their DistantLight and DomeLight prims, or daylight.sun and daylight.sky for the
config's sky models), relit like any luminaire, and whatever a relight does not redo is named.

The example room (configs/daylit_room.yaml: the scene's uniform DomeLight and 60,000 lux sun
through a glazed south window) with `daylight.usd_ground: dome` (the sky's lower half as its
ground, so the ground does not reflect the sun):

* with the sun and the sky in groups of their own, the bake's grid is the bake without groups
  (the groups' sum, each solved to the solver's tolerance 1e-4 on the same links: 1e-3 per
  point). Before, the groups left daylight out and the grid was 0 lx.
* relit with the sun's dimmer 0, the grid is a fresh bake of the sky alone (sun disabled) within
  1 % on the mean and 3 % per point: the direct light is exact in both, the fresh bake's links
  are refined for the sky alone (epsilon is a fraction of the emitted power), which moves the
  indirect part a little (measured: 0.2 % mean, 1.4 % worst point). The sun is more than a third
  of the grid's light, so keeping it would fail both bounds.
* `hirad grid` on the relit layer reads the relit sun (daylight.npz is relit with the groups).
* with the default ground (daylight.usd_ground: reflectance) the ground in the sky's light
  reflects the sun, so the sun and the sky in different groups are refused (exit 2) before
  anything runs.
* the daylight factor grids are not relit: a warning names them.
* an output baked when light groups left the sun and sky out is refused.
"""

from __future__ import annotations

import csv
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

pytest.importorskip("hirad._engine")

from hirad_e2e_helpers import assert_no_output, run_cli  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
ROOM = ROOT / "configs" / "daylit_room.yaml"
DF = ROOT / "configs" / "daylight_factor.yaml"
QUIET = ["outputs.lightmaps.enabled=false", "outputs.preview.enabled=false"]
APART = "lights={groups: {sky: {paths: [/Room/Sky]}, sun: {paths: [/Room/Sun]}}}"


def _sets(*overrides) -> list[str]:
    return [x for o in (*QUIET, *overrides) for x in ("--set", o)]


def _grid(path: Path) -> np.ndarray:
    return np.array([float(r["E_lx"]) for r in csv.DictReader(path.open())])


@pytest.fixture(scope="module")
def bakes(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("daylight_groups")
    outs = {}
    for name, extra in (("plain", []), ("grouped", [APART]), ("sky_only", ["daylight.sun.enabled=false"])):
        outs[name] = tmp / name
        r = run_cli("bake", ROOM, "--quiet", "--set", f"output={outs[name]}",
                    *_sets("daylight.usd_ground=dome", *extra))
        assert r.returncode == 0, (name, r.stderr)
    return tmp, outs


def test_grouped_daylight_total_is_the_bake_without_groups(bakes):
    _, outs = bakes
    report = json.loads((outs["grouped"] / "report.json").read_text())
    assert report["light_groups"]["sun"]["members"] == ["/Room/Sun"]
    assert report["light_groups"]["sky"]["members"] == ["/Room/Sky"]
    grouped, plain = _grid(outs["grouped"] / "grids" / "workplane.csv"), _grid(outs["plain"] / "grids" / "workplane.csv")
    assert plain.min() > 100
    assert np.allclose(grouped, plain, rtol=1e-3, atol=0)


def test_relit_without_the_sun_is_the_sky_alone(bakes):
    tmp, outs = bakes
    relit = tmp / "no_sun"
    r = run_cli("relight", outs["grouped"], "--set", "lights.groups.sun.dimmer=0", "-o", relit)
    assert r.returncode == 0, r.stderr
    e = _grid(relit / "grids" / "workplane.csv")
    sky = _grid(outs["sky_only"] / "grids" / "workplane.csv")
    total = _grid(outs["grouped"] / "grids" / "workplane.csv")
    assert total.mean() > 1.5 * sky.mean()  # the sun matters: keeping it would fail the bounds below
    assert e.mean() == pytest.approx(sky.mean(), rel=1e-2)
    assert np.allclose(e, sky, rtol=3e-2, atol=0)
    # hirad grid on the relit layer sees the relit sun and sky (daylight.npz relit), at the same points
    study = tmp / "workplane.yaml"
    spec = yaml.safe_load(ROOM.read_text())["grids"]
    study.write_text(yaml.safe_dump({"grids": spec}))
    r = run_cli("grid", relit / "solution.usda", study, "-o", tmp / "no_sun_read")
    assert r.returncode == 0, r.stderr
    assert np.allclose(_grid(tmp / "no_sun_read" / "workplane.csv"), e, rtol=2e-3, atol=0)


def test_sun_and_sky_apart_over_a_ground_that_reflects_the_sun_are_refused(tmp_path):
    out = tmp_path / "apart"
    r = run_cli("bake", ROOM, "--quiet", "--set", f"output={out}", *_sets(APART))  # usd_ground: reflectance
    assert r.returncode == 2, r.stderr
    for text in ("lights.groups", "/Room/Sun in group sun", "/Room/Sky in group sky", "daylight.usd_ground"):
        assert text in r.stderr, text
    assert_no_output(out)


def test_daylight_factor_is_named_as_not_relit(tmp_path):
    out = tmp_path / "df"
    r = run_cli("bake", DF, "--quiet", "--set", f"output={out}",
                *_sets("lights={groups: {overcast: {paths: [daylight.sky]}}}"))
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "report.json").read_text())["light_groups"]["overcast"]["members"] == ["daylight.sky"]
    assert (out / "grids" / "daylight_factor" / "workplane.csv").is_file()
    relit = tmp_path / "df-half"
    r = run_cli("relight", out, "--set", "lights.groups.overcast.dimmer=0.5", "-o", relit)
    assert r.returncode == 0, r.stderr
    assert "warning" in r.stderr and "grids/daylight_factor not relit" in r.stderr
    assert json.loads((relit / "report.json").read_text())["not_relit"] == ["grids/daylight_factor"]
    assert not (relit / "grids" / "daylight_factor").exists()
    half, full = _grid(relit / "grids" / "workplane.csv"), _grid(out / "grids" / "workplane.csv")
    assert np.allclose(half, 0.5 * full, rtol=1e-9)  # the sky alone lights it: exactly half


def test_an_output_whose_groups_left_daylight_out_is_refused(bakes, tmp_path):
    """Before the sun and sky could join groups, a daylit bake with groups kept them in
    luminaires.npz without their light (zero candela) and its group solutions had none of it."""
    from hirad import _engine
    from hirad.solution import save_luminaires

    _, outs = bakes
    old = tmp_path / "old"
    shutil.copytree(outs["grouped"], old)
    sun = _engine.Luminaire.distant("/Room/Sun", np.array([[0.0, -0.7071, 0.7071]]), np.array([1.0]), 60000.0,
                                    np.ones((1, 3)))
    save_luminaires([sun], old / "luminaires.npz")  # what the older bake wrote
    out = tmp_path / "old-relit"
    r = run_cli("relight", old, "--set", "lights.groups.sun.dimmer=0.5", "-o", out)
    assert r.returncode == 2 and "left out the sun and sky" in r.stderr and "/Room/Sun" in r.stderr, r.stderr
    assert_no_output(out)
