"""A solve that diverges is a failed run (exit 4), not an internal error (exit 1).

The scene: a closed unit box of reflectance 0.999 (hirad's most) that emits everywhere, refined
with one point pair per link estimate: the sampled estimates of an element's links sum above 1,
so rho x F has a spectral radius above 1 and the hierarchical solver's residual grows until the
engine stops it (hierarchical_solver.cpp: a million times over its least). `hirad bake` must
exit with 4 (the run failed), say that the solve diverged, name the likely cause and the config
keys to change (the meshes whose reflectance is near 1, hierarchy.samples with its value), and
leave no output directory or staging directory behind. The same box at reflectance 0.5
converges with the same settings (so it is the reflectance, not the settings, that fails).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

pytest.importorskip("hirad._engine")

from hirad_e2e_helpers import BOX_WALLS, assert_no_output, furnace_box, run_cli, write_config  # noqa: E402

EXIT_FAILED = 4


def _config(tmp_path: Path, reflectance: float) -> tuple[Path, Path]:
    scene = furnace_box(tmp_path / f"box{reflectance}.usda", reflectance=reflectance)
    out = tmp_path / f"out{reflectance}"
    cfg = write_config(tmp_path / f"box{reflectance}.yaml", scene, out, method="hierarchical",
                       hierarchy={"samples": 1, "epsilon": 1e-3, "min_area": 0.05},
                       solver={"method": "jacobi", "tolerance": 1e-6, "max_iterations": 100000},
                       outputs={"lightmaps": {"enabled": False}, "preview": {"enabled": False}})
    return cfg, out


def test_a_diverging_solve_exits_4_with_its_cause_and_leaves_no_output(tmp_path):
    cfg, out = _config(tmp_path, 0.999)
    r = run_cli("bake", cfg, "--quiet")
    assert r.returncode == EXIT_FAILED, (r.returncode, r.stderr)
    err = r.stderr
    assert err.startswith("hirad: error: ") and err.count("\n") == 1, err  # one line
    assert "internal error" not in err
    assert str(cfg) in err and "diverges" in err
    assert "reflectance near 1" in err and "link" in err
    # the config keys and the meshes to change, with their current values
    assert "hierarchy.samples (now 1)" in err
    for wall in BOX_WALLS:
        assert f"/World/{wall} (0.999)" in err, wall
    assert_no_output(out)


def test_a_diverging_solve_in_json(tmp_path):
    cfg, out = _config(tmp_path, 0.999)
    r = run_cli("bake", cfg, "--json")
    assert r.returncode == EXIT_FAILED
    err = json.loads(r.stdout)["error"]
    assert err["exit_code"] == EXIT_FAILED and err["kind"] == "failed" and "diverges" in err["message"]
    assert_no_output(out)


def test_the_same_settings_converge_at_a_lower_reflectance(tmp_path):
    cfg, out = _config(tmp_path, 0.5)
    r = run_cli("bake", cfg, "--quiet")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["solver"]["converged"]
