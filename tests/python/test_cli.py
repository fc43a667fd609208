"""End-to-end tests of the `hirad` command (run as `python -m hirad.cli` in a subprocess)."""

from __future__ import annotations

import csv
import io
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from hirad_e2e_helpers import (COARSE, CORNELL, all_nan_scene, assert_no_output, furnace_box,
                               mesh_points_by_path, no_mesh_scene, run_cli, sha256, write_config,
                               write_points_csv)
from pxr import Usd, UsdGeom, UsdLux

from hirad import _engine
from hirad.bake import bake as api_bake

PREVIEW = {"camera": "/World/Camera", "width": 64, "height": 64, "samples": 2}


def cornell_config(tmp: Path, scene: Path, output: Path, name="cornell.yaml", **sections) -> Path:
    sections.setdefault("meshing", COARSE)
    sections.setdefault("outputs", {"preview": PREVIEW})
    return write_config(tmp / name, scene, output, **sections)


def parse_probe(stdout: str) -> dict[str, np.ndarray]:
    rows = list(csv.reader(io.StringIO(stdout)))
    header, body = rows[0], np.array([[float(v) for v in r] for r in rows[1:]])
    return {name: body[:, i] for i, name in enumerate(header)}


# ---------------------------------------------------------------------------------------------
# a Cornell bake through the CLI, shared by the tests that only read its outputs
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cli_bake(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli_bake")
    scene_dir = root / "scene"
    scene_dir.mkdir()
    scene = scene_dir / "cornell_box.usda"
    shutil.copyfile(CORNELL, scene)
    before = {p.name: sha256(p) for p in scene_dir.iterdir()}
    out = root / "out"
    cfg = cornell_config(root, scene, out)
    proc = run_cli("bake", cfg, "--json", cwd=root)
    return {"root": root, "scene": scene, "scene_dir": scene_dir, "before": before, "out": out,
            "cfg": cfg, "proc": proc}


def test_bake_succeeds_and_writes_every_output(cli_bake):
    proc, out = cli_bake["proc"], cli_bake["out"]
    assert proc.returncode == 0, proc.stderr
    for name in ("solution.usda", "preview.png", "preview.exr", "report.json"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    # one lightmap per scene mesh (the UsdLux mesh light included)
    n_meshes = len(mesh_points_by_path(cli_bake["scene"]))
    exrs = sorted((out / "lightmaps").glob("*.exr"))
    assert len(exrs) == n_meshes == 8
    report = json.loads((out / "report.json").read_text())
    assert sorted(report["outputs"]["lightmaps"]) == sorted(f"lightmaps/{p.name}" for p in exrs)
    # nothing else is left next to the output (no staging directory)
    assert sorted(p.name for p in out.parent.iterdir()) == sorted(["scene", "out", cli_bake["cfg"].name])


def test_bake_json_is_the_report(cli_bake):
    proc, out = cli_bake["proc"], cli_bake["out"]
    assert proc.returncode == 0, proc.stderr
    printed = json.loads(proc.stdout)
    assert printed == json.loads((out / "report.json").read_text())
    assert Path(printed["config"]) == cli_bake["cfg"].resolve()
    assert Path(printed["scene"]) == cli_bake["scene"].resolve()
    # Peak memory so far at each stage's end: one per timed stage, never falling, and no
    # more than this process tree's peak (getrusage of the finished children: the bake's).
    import resource

    peaks = printed["peak_rss_mib"]
    assert list(peaks) == [k for k in printed["timings_s"] if k != "total"]
    assert list(peaks.values()) == sorted(peaks.values()) and min(peaks.values()) > 10
    assert max(peaks.values()) <= resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024 + 1


def test_bake_energy_balance_and_emitted_power(cli_bake):
    report = json.loads(cli_bake["proc"].stdout)
    eb = report["energy_balance"]
    assert eb["max_relative_error"] < 0.01
    emitted, absorbed, escaped = (np.array(eb[k]) for k in ("emitted_W", "absorbed_W", "escaped_W"))
    np.testing.assert_array_less(np.abs(emitted - absorbed - escaped) / emitted, 0.01)
    assert (escaped > 0).all()  # the Cornell box is open at the front
    # emitted power from the scene itself: pi * L * area of the (planar) light quad
    stage = Usd.Stage.Open(str(cli_bake["scene"]))
    light = stage.GetPrimAtPath("/World/light")
    radiance = np.array(UsdLux.LightAPI(light).GetColorAttr().Get(), dtype=np.float64)
    pts = mesh_points_by_path(cli_bake["scene"])["/World/light"]
    area = 0.5 * np.linalg.norm(np.cross(pts[2] - pts[0], pts[3] - pts[1]))
    np.testing.assert_allclose(emitted, math.pi * radiance * area, rtol=1e-5)


def test_bake_leaves_the_input_untouched(cli_bake):
    assert cli_bake["proc"].returncode == 0, cli_bake["proc"].stderr
    after = {p.name: sha256(p) for p in cli_bake["scene_dir"].iterdir()}
    assert after == cli_bake["before"]


def test_bake_quiet_prints_nothing(tmp_path):
    out = tmp_path / "out"
    cfg = cornell_config(tmp_path, CORNELL, out)
    proc = run_cli("bake", cfg, "--quiet", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    assert proc.stderr == ""
    assert (out / "report.json").is_file()


def test_bake_default_prints_a_summary(tmp_path):
    out = tmp_path / "out"
    cfg = cornell_config(tmp_path, CORNELL, out)
    proc = run_cli("bake", cfg, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "report.json").read_text())
    assert f"{report['counts']['patches']} patches" in proc.stdout
    assert str(out) in proc.stdout


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------


def bake_fails(tmp_path: Path, cfg: Path, out: Path, *args) -> str:
    proc = run_cli("bake", cfg, *args, cwd=tmp_path)
    assert proc.returncode != 0
    assert proc.stdout == ""
    assert "Traceback" not in proc.stderr
    assert_no_output(out)
    errors = [line for line in proc.stderr.splitlines() if line.startswith("hirad: error: ")]
    assert len(errors) == 1, proc.stderr
    return errors[0]


def test_missing_scene_file(tmp_path):
    out = tmp_path / "out"
    missing = tmp_path / "no_such_scene.usda"
    cfg = write_config(tmp_path / "c.yaml", missing, out)
    msg = bake_fails(tmp_path, cfg, out)
    assert str(missing) in msg
    assert "c.yaml:1: scene:" in msg  # scene is the first key of the file
    assert "not found" in msg


def test_missing_config_file(tmp_path):
    missing = tmp_path / "nope.yaml"
    msg = bake_fails(tmp_path, missing, tmp_path / "out" / "nope")
    assert str(missing) in msg and "not found" in msg


def test_malformed_yaml_names_file_and_line(tmp_path):
    out = tmp_path / "out"
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(f"scene: {CORNELL}\noutput: {out}\nmeshing: max_patch_area: 0.01\n")  # line 3
    msg = bake_fails(tmp_path, cfg, out)
    assert f"{cfg}:3:" in msg
    assert "malformed YAML" in msg


def test_unknown_key_names_line_and_key(tmp_path):
    out = tmp_path / "out"
    cfg = tmp_path / "typo.yaml"
    cfg.write_text(f"scene: {CORNELL}\noutput: {out}\nmeshing:\n  max_patch_aera: 0.01\n")  # line 4
    msg = bake_fails(tmp_path, cfg, out)
    assert f"{cfg}:4: meshing.max_patch_aera:" in msg
    assert "unknown key" in msg and "max_patch_area" in msg  # the suggestion


def test_scene_without_meshes(tmp_path):
    out = tmp_path / "out"
    scene = no_mesh_scene(tmp_path / "empty.usda")
    msg = bake_fails(tmp_path, write_config(tmp_path / "c.yaml", scene, out), out)
    assert str(scene) in msg and "no meshes" in msg


def test_scene_whose_points_are_all_nan(tmp_path):
    out = tmp_path / "out"
    scene = all_nan_scene(tmp_path / "nan.usda")
    msg = bake_fails(tmp_path, write_config(tmp_path / "c.yaml", scene, out), out)
    assert str(scene) in msg and "no usable faces" in msg


def test_info_on_all_nan_scene_is_not_a_crash(tmp_path):
    scene = all_nan_scene(tmp_path / "nan.usda")
    proc = run_cli("info", scene)
    assert proc.returncode == 0, proc.stderr
    assert "bounds (m): none" in proc.stdout
    assert "/World/bad: 1 faces" in proc.stdout


def test_some_nan_faces_are_skipped_and_counted(tmp_path):
    out = tmp_path / "out"
    scene = furnace_box(tmp_path / "box.usda", nan_faces_in_floor=3)
    cfg = write_config(tmp_path / "c.yaml", scene, out, meshing={"max_patch_area": 0.25, "max_edge_length": 0.5},
                       outputs={"preview": {"width": 16, "height": 16, "samples": 1}})
    proc = run_cli("bake", cfg, "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["counts"]["skipped"]["nonfinite_faces"] == 3
    assert report["counts"]["skipped"]["self_intersecting_faces"] == 0
    assert report["counts"]["input_faces"] == 6 + 3
    assert report["counts"]["faces"] == 6
    warned = [w for w in report["warnings"] if "3 nonfinite faces" in w]
    assert len(warned) == 1 and str(scene) in warned[0]
    assert (out / "solution.usda").is_file()


def test_snapshots_need_the_progressive_solver(tmp_path):
    out = tmp_path / "out"
    cfg = cornell_config(tmp_path, CORNELL, out, solver={"method": "southwell"})
    msg = bake_fails(tmp_path, cfg, out, "--snapshots", "5")
    assert "snapshots" in msg and "progressive" in msg


def test_progressive_snapshots(tmp_path):
    out = tmp_path / "out"
    every = 100
    cfg = cornell_config(tmp_path, CORNELL, out, solver={"method": "progressive", "tolerance": 1e-3})
    proc = run_cli("bake", cfg, "--quiet", "--snapshots", every, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["solver"]["method"] == "progressive"
    iterations = report["solver"]["iterations"]
    shots = sorted((out / "snapshots").glob("shot_*.png"))
    assert iterations >= every
    assert len(shots) == iterations // every
    numbers = [int(re.fullmatch(r"shot_(\d+)\.png", p.name).group(1)) for p in shots]
    assert numbers == [every * (k + 1) for k in range(len(shots))]


# ---------------------------------------------------------------------------------------------
# info
# ---------------------------------------------------------------------------------------------


def test_info_on_cornell():
    proc = run_cli("info", CORNELL)
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    stage = Usd.Stage.Open(str(CORNELL))
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    assert f"metersPerUnit {mpu:g}" in text and f"upAxis {UsdGeom.GetStageUpAxis(stage)}" in text
    # bounds, compared with the points read here
    meshes = mesh_points_by_path(CORNELL)
    allpts = np.concatenate(list(meshes.values()))
    m = re.search(r"bounds \(m\): \[([^\]]*)\] \.\. \[([^\]]*)\]", text)
    assert m, text
    lo, hi = (np.array([float(v) for v in g.split(",")]) for g in m.groups())
    np.testing.assert_allclose(lo, allpts.min(axis=0), atol=1e-4)
    np.testing.assert_allclose(hi, allpts.max(axis=0), atol=1e-4)
    # every mesh listed; the light, and only the light, marked as emitter
    listed = dict(re.findall(r"^  (/\S+): (.*)$", text, flags=re.M))
    assert set(listed) == set(meshes)
    assert [p for p, rest in listed.items() if "(emitter)" in rest] == ["/World/light"]
    assert "camera: /World/Camera" in text


def test_info_with_a_config_estimates_before_running(tmp_path):
    """`info SCENE CONFIG` and `info CONFIG` (its scene) add the estimate; nothing is written."""
    scene_dir = tmp_path / "s"
    scene_dir.mkdir()
    scene = scene_dir / "cornell_box.usda"
    shutil.copyfile(CORNELL, scene)
    cfg = write_config(tmp_path / "c.yaml", scene, tmp_path / "out", method="flat", meshing=COARSE)
    with_both = run_cli("info", scene, cfg)
    config_only = run_cli("info", cfg)
    for proc in (with_both, config_only):
        assert proc.returncode == 0, proc.stderr
        assert f"scene: {scene}" in proc.stdout and "estimate for method flat" in proc.stdout
        assert re.search(r"patches: about [\d,]+", proc.stdout)
    assert not (tmp_path / "out").exists()
    assert "estimate" not in run_cli("info", scene).stdout


# ---------------------------------------------------------------------------------------------
# render and probe a stored solution
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def api_cornell(tmp_path_factory):
    """A Cornell bake through the API: the in-memory Result next to its solution.usda."""
    root = tmp_path_factory.mktemp("api_cornell")
    out = root / "out"
    result = api_bake(cornell_config(root, CORNELL, out))
    return root, out, result


def test_render_png_without_solving(api_cornell, tmp_path):
    _, out, _ = api_cornell
    png = tmp_path / "x.png"
    proc = run_cli("render", out / "solution.usda", "--camera", "/World/Camera", "-o", png,
                   "--width", 48, "--height", 40, "--samples", 1)
    assert proc.returncode == 0, proc.stderr
    from PIL import Image

    with Image.open(png) as im:
        assert im.size == (48, 40)
        assert np.asarray(im).max() > 0  # not a black image
    assert "solve" not in proc.stderr


def test_render_exr_matches_the_api(api_cornell, tmp_path):
    _, out, result = api_cornell
    exr = tmp_path / "x.exr"
    proc = run_cli("render", out / "solution.usda", "--camera", "/World/Camera", "-o", exr,
                   "--width", 40, "--height", 32, "--samples", 2)
    assert proc.returncode == 0, proc.stderr
    img = _engine.read_exr(str(exr))
    expected = result.render("/World/Camera", 40, 32, 2)
    assert img.shape == expected.shape == (32, 40, 3)
    assert expected.max() > 1.0  # the light is in view (radiance 17 W/(m^2 sr) in red)
    # stored as half floats: relative precision 2^-11
    np.testing.assert_allclose(img, expected, rtol=2 ** -10, atol=1e-6)


def test_render_unknown_camera(api_cornell, tmp_path):
    _, out, _ = api_cornell
    png = tmp_path / "x.png"
    proc = run_cli("render", out / "solution.usda", "--camera", "/World/NoSuchCamera", "-o", png)
    assert proc.returncode != 0
    assert "/World/NoSuchCamera" in proc.stderr and "not found" in proc.stderr
    assert "/World/Camera" in proc.stderr  # lists the cameras there are
    assert "Traceback" not in proc.stderr
    assert not png.exists()


# points on the Cornell floor (y = 0, normal +Y) clear of the blocks, and on the back wall
# (z = 559.2 mm, normal -Z)
FLOOR = [(0.03, 0.0, 0.03), (0.52, 0.0, 0.04), (0.04, 0.0, 0.52), (0.52, 0.0, 0.53), (0.05, 0.0, 0.3)]
BACK = [(0.10, 0.10, 0.5592), (0.30, 0.40, 0.5592), (0.45, 0.20, 0.5592)]


def probe_points():
    pts = np.array(FLOOR + BACK)
    nrm = np.array([(0, 1, 0)] * len(FLOOR) + [(0, 0, -1)] * len(BACK), dtype=np.float64)
    return pts, nrm


def test_probe_matches_the_api(api_cornell, tmp_path):
    _, out, result = api_cornell
    pts, nrm = probe_points()
    points_csv = write_points_csv(tmp_path / "points.csv", np.hstack([pts, nrm]))
    proc = run_cli("probe", out / "solution.usda", points_csv)
    assert proc.returncode == 0, proc.stderr
    got = parse_probe(proc.stdout)
    np.testing.assert_array_equal(np.column_stack([got["x"], got["y"], got["z"]]), pts)
    irr = np.column_stack([got[f"irradiance_{c}"] for c in "rgb"])
    rad = np.column_stack([got[f"radiance_{c}"] for c in "rgb"])
    expected = result.query(pts, nrm)
    assert (expected["irradiance"] > 0).all()  # all points are lit
    # float32 storage in USD and 6 significant digits in the CSV
    np.testing.assert_allclose(irr, result.irradiance_at(pts, nrm), rtol=2e-5)
    np.testing.assert_allclose(rad, result.radiance_at(pts, nrm), rtol=2e-5)
    np.testing.assert_allclose(got["distance"], 0.0, atol=1e-6)


def test_probe_writes_csv_file(api_cornell, tmp_path):
    _, out, result = api_cornell
    pts, nrm = probe_points()
    points_csv = write_points_csv(tmp_path / "points.csv", np.hstack([pts, nrm]))
    target = tmp_path / "probed.csv"
    proc = run_cli("probe", out / "solution.usda", points_csv, "-o", target)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    got = parse_probe(target.read_text())
    np.testing.assert_allclose(got["irradiance_g"], result.irradiance_at(pts, nrm)[:, 1], rtol=2e-5)
    assert [p.name for p in tmp_path.iterdir() if "partial" in p.name] == []


def test_probe_far_point_names_the_csv_line(api_cornell, tmp_path):
    _, out, _ = api_cornell
    rows = [(*FLOOR[0], 0, 1, 0), (*FLOOR[1], 0, 1, 0), (5.0, 5.0, 5.0, 0, 1, 0)]
    points_csv = write_points_csv(tmp_path / "points.csv", rows)  # header on line 1, far point on 4
    target = tmp_path / "probed.csv"
    proc = run_cli("probe", out / "solution.usda", points_csv, "-o", target)
    assert proc.returncode != 0
    assert f"{points_csv}:4:" in proc.stderr and "no surface" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not target.exists()


def test_probe_malformed_line_names_file_and_line(api_cornell, tmp_path):
    _, out, _ = api_cornell
    points_csv = tmp_path / "points.csv"
    points_csv.write_text("x,y,z\n0.1,0,0.1\n0.2,zero,0.2\n")
    proc = run_cli("probe", out / "solution.usda", points_csv)
    assert proc.returncode != 0
    assert f"{points_csv}:3:" in proc.stderr
    assert "Traceback" not in proc.stderr
    points_csv.write_text("0.1,0,0.1\n0.2,0.1\n")  # two values
    proc = run_cli("probe", out / "solution.usda", points_csv)
    assert proc.returncode != 0
    assert f"{points_csv}:2:" in proc.stderr


def test_probe_furnace_through_the_cli(tmp_path):
    """Closed box, rho = 0.5, E = 1 W/m^2: B = E / (1 - rho) = 2 and H = B = 2 everywhere."""
    out = tmp_path / "out"
    scene = furnace_box(tmp_path / "box.usda")
    cfg = write_config(tmp_path / "c.yaml", scene, out,
                       meshing={"max_patch_area": 0.04, "max_edge_length": 0.25},
                       formfactors={"method": "raycast", "samples": 256},
                       outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}})
    assert run_cli("bake", cfg, "--quiet").returncode == 0
    rng = np.random.default_rng(7)
    pts = rng.uniform(0.0, 1.0, size=(24, 3))
    axis = rng.integers(0, 3, size=24)
    side = rng.integers(0, 2, size=24)
    pts[np.arange(24), axis] = side
    nrm = np.zeros((24, 3))
    nrm[np.arange(24), axis] = np.where(side == 1, -1.0, 1.0)
    points_csv = write_points_csv(tmp_path / "points.csv", np.hstack([pts, nrm]))
    proc = run_cli("probe", out / "solution.usda", points_csv)
    assert proc.returncode == 0, proc.stderr
    got = parse_probe(proc.stdout)
    for c in "rgb":
        np.testing.assert_allclose(got[f"irradiance_{c}"], 2.0, rtol=0.01)
        np.testing.assert_allclose(got[f"radiance_{c}"], 2.0 / math.pi, rtol=0.01)
