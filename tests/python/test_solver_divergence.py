"""A solve that diverges is a failed run (exit 4), not an internal error (exit 1); the
hierarchical solvers keep every element to the gain limit, so they no longer diverge.

The scene: a closed unit box of reflectance 0.999 (hirad's most) that emits E everywhere, its
links estimated with one sample: the sampled form factors of a patch or element sum above 1, so
rho x F has a spectral radius above 1.
* The flat method's Jacobi grows until the radiosity is no longer finite: `hirad bake` must exit
  with 4 (the run failed), say that the solve diverged, name the likely cause and the config
  keys to change (the meshes whose reflectance is near 1, formfactors.samples with its value),
  and leave no output directory or staging directory behind.
* The hierarchical method scales the gather of the elements whose rho F exceeds 0.999
  (hierarchical_solver.h, kGainLimit): it converges, says how many elements it limited, and its
  radiosity keeps the contraction's bound: B = E + rho s H with every leaf's rho s F <= 0.999
  gives max B <= E / (1 - 0.999) = 1000 E, the exact furnace value E / (1 - rho).
* The same box at reflectance 0.5 converges with the same settings and limits nothing.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

pytest.importorskip("hirad._engine")

from hirad_e2e_helpers import BOX_WALLS, assert_no_output, furnace_box, run_cli, write_config  # noqa: E402

EXIT_FAILED = 4


def _config(tmp_path: Path, reflectance: float, method: str = "flat", solver: str = "jacobi") -> tuple[Path, Path]:
    scene = furnace_box(tmp_path / f"box{reflectance}.usda", reflectance=reflectance)
    out = tmp_path / f"out{reflectance}{method}"
    links = ({"hierarchy": {"samples": 1, "epsilon": 1e-3, "min_area": 0.05}} if method == "hierarchical" else
             {"formfactors": {"method": "raycast", "samples": 1}})
    cfg = write_config(tmp_path / f"box{reflectance}{method}.yaml", scene, out, method=method, **links,
                       solver={"method": solver, "tolerance": 1e-6, "max_iterations": 100000},
                       outputs={"lightmaps": {"enabled": False}, "preview": {"enabled": False}})
    return cfg, out


def test_a_diverging_solve_exits_4_with_its_cause_and_leaves_no_output(tmp_path):
    cfg, out = _config(tmp_path, 0.999)
    r = run_cli("bake", cfg, "--quiet")
    assert r.returncode == EXIT_FAILED, (r.returncode, r.stderr)
    err = r.stderr
    assert err.startswith("hirad: error: ") and err.count("\n") == 1, err  # one line
    assert "internal error" not in err
    assert str(cfg) in err and "diverge" in err
    assert "reflectance near 1" in err and "link" in err
    # the config keys and the meshes to change, with their current values
    assert "formfactors.samples (now 1)" in err
    for wall in BOX_WALLS:
        assert f"/World/{wall} (0.999)" in err, wall
    assert_no_output(out)


def test_a_diverging_solve_in_json(tmp_path):
    cfg, out = _config(tmp_path, 0.999)
    r = run_cli("bake", cfg, "--json")
    assert r.returncode == EXIT_FAILED
    err = json.loads(r.stdout)["error"]
    assert err["exit_code"] == EXIT_FAILED and err["kind"] == "failed" and "diverge" in err["message"]
    assert_no_output(out)


@pytest.mark.parametrize("solver", ["jacobi", "gauss_seidel", "southwell", "block_southwell"])
def test_the_hierarchical_solve_keeps_the_gain_limit_and_converges(tmp_path, solver):
    """In memory (Jacobi, Gauss-Seidel, Southwell) and streamed out of core (block Southwell)."""
    cfg, out = _config(tmp_path, 0.999, "hierarchical", solver)
    r = run_cli("bake", cfg, "--quiet")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["solver"]["converged"]
    limited = report["hierarchy"]["limited_leaves"]
    assert limited > 0
    assert any(f"{limited} elements have reflectance x (the sum of their link estimates) above 0.999" in w for w in report["warnings"])
    radiance = _layer_radiance(out)  # B / pi per vertex
    exitance = 1.0  # the box's E, W/m^2
    assert radiance.max() * np.pi <= exitance / (1 - 0.999) * (1 + 1e-9)
    assert radiance.min() * np.pi > exitance  # it reflects: more than its emission


@pytest.mark.parametrize("method", ["flat", "hierarchical"])
def test_the_same_settings_converge_at_a_lower_reflectance(tmp_path, method):
    cfg, out = _config(tmp_path, 0.5, method)
    r = run_cli("bake", cfg, "--quiet")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["solver"]["converged"]
    if method == "hierarchical":
        assert report["hierarchy"]["limited_leaves"] == 0


def _layer_radiance(out: Path) -> np.ndarray:
    """B / pi of every element (the layer's hirad:patchRadiance of all solved meshes), W/(m^2 sr)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out / "solution.usda"))
    values = [np.asarray(UsdGeom.PrimvarsAPI(p).GetPrimvar("hirad:patchRadiance").Get(), dtype=np.float64)
              for p in stage.GetPrimAtPath("/World/HiradSolution").GetChildren() if p.IsA(UsdGeom.Mesh)]
    assert values
    return np.concatenate(values)
