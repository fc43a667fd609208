"""Calculation grids wired into the config and the bake, and `hirad grid` on a stored bake:
the files, the statistics against the CSV values, located config errors, the same values from
the stored solution as from the bake (same seed). Physics checks are tests/python/photometry."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from hirad_e2e_helpers import COARSE, CORNELL, assert_no_output, run_cli, write_config

from hirad.bake import bake, load_solution
from hirad.config import ConfigError, load_config
from hirad.solution import luminance_y

# Cornell box (Y up, metres after metersPerUnit 0.001): floor x 0..0.556, z 0..0.559; the
# horizontal frame for Y up is (e1, e2) = (+X, -Z). A work plane 0.40 m over the floor (above
# both blocks, below the ceiling at 0.5488 m).
GRIDS = {
    "plane": {"kind": "workplane", "polygon": [[0.0, 0.0], [0.55, 0.0], [0.55, -0.55], [0.0, -0.55]],
              "height": 0.40, "border": 0.05, "spacing": 0.15},
    "sensors": {"kind": "points", "file": "sensors.csv"},
}
SENSORS = "x,y,z,nx,ny,nz\n0.1,0.2,0.1,0,1,0\n0.45,0.2,0.5,0,1,0\n0.278,0.3,0.3,0,0,-1\n"


def _config(root: Path, out: Path, **extra) -> Path:
    (root / "sensors.csv").write_text(SENSORS)
    return write_config(root / "c.yaml", CORNELL, out, meshing=COARSE,
                        outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}},
                        grids=GRIDS, maintenance_factor=0.8, **extra)


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    root = tmp_path_factory.mktemp("grids_bake")
    out = root / "out"
    result = bake(_config(root, out))
    return {"root": root, "out": out, "result": result}


def _csv(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def test_config_reads_grids_units_and_resolves_files(baked):
    cfg = load_config(baked["root"] / "c.yaml")
    assert cfg.units == "photometric" and cfg.maintenance_factor == 0.8
    assert set(cfg.grids) == {"plane", "sensors"}
    assert Path(cfg.grids["sensors"].file) == (baked["root"] / "sensors.csv").absolute()


def test_bake_writes_grid_files_and_stats(baked):
    gdir = baked["out"] / "grids"
    for name in ("plane", "sensors"):
        for suffix in ("csv", "json", "png"):
            assert (gdir / f"{name}.{suffix}").is_file(), f"{name}.{suffix}"
    assert (gdir / "report.html").is_file()
    html = (gdir / "report.html").read_text()
    assert "lux" in html or "lx" in html
    report = json.loads((baked["out"] / "report.json").read_text())
    assert report["outputs"]["grids"] == "grids/"
    g = report["grids"]
    assert g["units"] == "photometric" and g["unit"] == "lx" and g["maintenance_factor"] == 0.8
    for name in ("plane", "sensors"):
        st = g["grids"][name]
        values = _csv(gdir / f"{name}.csv")
        e, w = values["E_lx"], values["weight"]
        assert st["points"] == len(e)
        assert st["emin"] == pytest.approx(e.min(), rel=1e-12) and st["emax"] == pytest.approx(e.max(), rel=1e-12)
        assert st["em"] == pytest.approx(np.sum(w * e) / np.sum(w), rel=1e-12)
        assert st["u0"] == pytest.approx(e.min() / st["em"], rel=1e-12)
        assert st["ud"] == pytest.approx(e.min() / e.max(), rel=1e-12)
        assert st["em_maintained"] == pytest.approx(0.8 * st["em"], rel=1e-12)
        assert np.allclose(values["E_maintained_lx"], 0.8 * e, rtol=1e-12)
        assert e.min() > 0  # every point sees the light or lit walls
    assert g["grids"]["plane"]["points"] == 9  # 0.45 m / 0.15 m: 3 x 3 cells


def test_grid_values_are_y_of_the_illuminance_at_the_points(baked):
    r = baked["result"]
    vals = _csv(baked["out"] / "grids" / "sensors.csv")
    pts = np.c_[vals["x"], vals["y"], vals["z"]]
    nrm = np.c_[vals["nx"], vals["ny"], vals["nz"]]
    e = luminance_y(r.illuminance(pts, nrm, seed=1))
    assert np.allclose(e, vals["E_lx"], rtol=1e-12)
    assert r.emitted_radiance.shape == (len(r.corners), 3) and (r.emitted_radiance.max(axis=1) > 0).any()


def test_pdf_report_when_weasyprint_works(baked):
    from hirad.studies.report import pdf_engine

    pdf = baked["out"] / "grids" / "report.pdf"
    if pdf_engine("auto") == "weasyprint":
        assert pdf.read_bytes()[:5] == b"%PDF-"


def test_located_error_for_a_bad_grid_key(tmp_path):
    cfg = _config(tmp_path, tmp_path / "out")
    data = yaml.safe_load(cfg.read_text())
    data["grids"]["plane"]["spaceing"] = 0.1
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError) as ei:
        load_config(cfg)
    err = ei.value
    assert err.key == "grids.plane.spaceing" and "did you mean 'spacing'" in err.problem
    assert cfg.read_text().splitlines()[err.line - 1].strip().startswith("spaceing:")
    proc = run_cli("bake", cfg)
    assert proc.returncode == 2 and "grids.plane.spaceing" in proc.stderr
    assert_no_output(tmp_path / "out")


def test_located_error_for_a_missing_points_file(tmp_path):
    cfg = _config(tmp_path, tmp_path / "out")
    (tmp_path / "sensors.csv").unlink()
    with pytest.raises(ConfigError) as ei:
        load_config(cfg)
    assert ei.value.key == "grids.sensors.file" and "not found" in ei.value.problem
    assert cfg.read_text().splitlines()[ei.value.line - 1].strip().startswith("file:")


def test_a_grid_with_no_point_fails_the_bake_with_nothing_written(tmp_path):
    cfg = _config(tmp_path, tmp_path / "out")
    data = yaml.safe_load(cfg.read_text())
    data["grids"]["plane"]["border"] = 0.4  # wider than half the floor: no evaluation area
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    proc = run_cli("bake", "-q", cfg)
    assert proc.returncode == 2, proc.stderr
    assert "grids.plane" in proc.stderr
    assert_no_output(tmp_path / "out")


def test_hirad_grid_on_the_stored_solution_gives_the_bake_values(baked):
    study = baked["root"] / "study.yaml"
    study.write_text(yaml.safe_dump({"maintenance_factor": 0.8, "grids": GRIDS}, sort_keys=False))
    solution = baked["out"] / "solution.usda"
    proc = run_cli("grid", solution, study, "--seed", "1")
    assert proc.returncode == 0, proc.stderr
    gdir = baked["out"] / "grids-study"
    assert (gdir / "plane.png").is_file() and (gdir / "report.html").is_file()
    for name in ("plane", "sensors"):
        stored, baked_values = _csv(gdir / f"{name}.csv"), _csv(baked["out"] / "grids" / f"{name}.csv")
        assert np.allclose(stored["x"], baked_values["x"], rtol=0, atol=1e-12)
        # the layer holds float32 points and radiance: the same rays hit the same surfaces
        assert np.allclose(stored["E_lx"], baked_values["E_lx"], rtol=2e-3), name
    summary = json.loads((gdir / "grids.json").read_text())
    assert summary["grids"]["plane"]["u0"] == pytest.approx(
        json.loads((baked["out"] / "report.json").read_text())["grids"]["grids"]["plane"]["u0"], rel=5e-3)
    # a second run replaces hirad's own directory; a directory hirad did not make is refused
    assert run_cli("grid", solution, study).returncode == 0
    foreign = baked["root"] / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    proc = run_cli("grid", solution, study, "--output", foreign)
    assert proc.returncode == 2 and (foreign / "notes.txt").read_text() == "mine"


def test_hirad_grid_refuses_a_layer_without_emission(baked, tmp_path):
    from pxr import Sdf, Usd

    from hirad.usd.solution import arrays_path, merge_arrays

    src = baked["out"] / "solution.usda"
    old = tmp_path / "old.usda"
    # a layer as hirad wrote it before the emission primvar (and before the arrays' crate)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.TransferContent(Sdf.Layer.FindOrOpen(str(src)))
    assert merge_arrays(layer, src)
    layer.subLayerPaths.remove("./" + arrays_path(src).name)
    layer.Export(str(old))
    stage = Usd.Stage.Open(str(old))
    for prim in stage.Traverse():
        attr = prim.GetAttribute("primvars:hirad:emission")
        if attr:
            prim.RemoveProperty("primvars:hirad:emission")
    stage.GetRootLayer().Save()
    assert load_solution(old).emitted_radiance is None
    study = tmp_path / "s.yaml"
    study.write_text(yaml.safe_dump({"grids": {"plane": GRIDS["plane"]}}))
    proc = run_cli("grid", old, study)
    assert proc.returncode == 3 and "predates primvars:hirad:emission" in proc.stderr
    assert not (tmp_path / "grids-s").exists()


def test_study_report_states_units_version_residual_and_balance(baked):
    from hirad import __version__

    html = (baked["out"] / "grids" / "report.html").read_text()
    for text in (__version__, "residual", "energy balance", "lux"):
        assert text in html, text


def test_radiometric_units_and_a_bad_study_key(baked, tmp_path):
    solution = baked["out"] / "solution.usda"
    study = tmp_path / "r.yaml"
    study.write_text(yaml.safe_dump({"maintenance_factor": 0.8, "grids": {"plane": GRIDS["plane"]}}))
    proc = run_cli("grid", solution, study, "--units", "radiometric", "--output", tmp_path / "r")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "r" / "grids.json").read_text())
    assert summary["units"] == "radiometric" and summary["unit"] == "W/m2"
    assert "W/m²" in (tmp_path / "r" / "report.html").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"grids": {"plane": {**GRIDS["plane"], "heigth": 1.0}}}))
    proc = run_cli("grid", solution, bad, "--output", tmp_path / "b")
    assert proc.returncode == 2 and "grids.plane.heigth" in proc.stderr
    assert not (tmp_path / "b").exists()


def test_grid_rays_key_is_validated_and_unused_without_grids(tmp_path):
    """`grid_rays` sets the grids' hemisphere rays (the report says which); below 16 it is a
    located error; without grids it is named as unused."""
    cfg = _config(tmp_path, tmp_path / "out", grid_rays=8)
    with pytest.raises(ConfigError) as ei:
        load_config(cfg)
    assert ei.value.key == "grid_rays"
    data = yaml.safe_load(cfg.read_text())
    data["grid_rays"] = 64
    del data["grids"]
    del data["maintenance_factor"]
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    assert any(w.startswith("grid_rays:") for w in load_config(cfg).ignored_settings())
