"""`hirad render --lightmaps`: the view rebuilt from the lightmap pages (albedo x lightmap +
emission through the lightmap UVs) must show the same light as the solution's own surface
values, since in interpolate mode every texel holds the solution's incident radiance."""

from __future__ import annotations

import numpy as np

from hirad_e2e_helpers import CORNELL, run_cli, write_config

from hirad import _engine
from hirad.outputs import lightmap_render
from hirad.bake import bake, load_solution


def test_lightmap_view_matches_the_solution_view(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 3e-5, "min_area": 4e-4}, solver={"method": "jacobi"},
                       outputs={"preview": {"enabled": False},
                                "lightmaps": {"texels_per_metre": 200, "supersample": 2, "mode": "interpolate"}})
    bake(cfg)
    sol = load_solution(tmp_path / "out" / "solution.usda")
    view = sol.view("/World/Camera")
    from_maps = lightmap_render.render(tmp_path / "out" / "solution.usda", view, 96, 96)
    direct = sol.render("/World/Camera", 96, 96, 1)
    lum = np.array([0.2126, 0.7152, 0.0722])
    a, b = from_maps @ lum, direct @ lum
    lit = b > 0.05 * np.median(b[b > 0])
    assert lit.mean() > 0.5
    # The same light on average (texel filtering and dilation move little energy) and pixel
    # by pixel away from the blocks' silhouettes (where a texel straddles an edge).
    assert abs(a[lit].mean() / b[lit].mean() - 1) < 0.03
    rel = np.abs(a[lit] / b[lit] - 1)
    assert np.median(rel) < 0.03 and np.quantile(rel, 0.9) < 0.15
    # Black where nothing is hit, in both.
    assert np.array_equal(a == 0, b == 0) or np.mean((a == 0) != (b == 0)) < 0.01


def test_cli_render_lightmaps_and_a_missing_page(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 1e-3}, solver={"method": "jacobi"},
                       outputs={"preview": {"enabled": False}, "lightmaps": {"texels_per_metre": 64}})
    assert run_cli("bake", cfg, "--quiet").returncode == 0
    out = tmp_path / "view.exr"
    r = run_cli("render", tmp_path / "out" / "solution.usda", "--lightmaps", "--width", "32", "--height", "32",
                "-o", out)
    assert r.returncode == 0, r.stderr
    img = _engine.read_exr(str(out))
    assert img.shape == (32, 32, 3) and img.max() > 0
    for page in (tmp_path / "out" / "lightmaps" / "pages").glob("*.exr"):
        page.unlink()
    r = run_cli("render", tmp_path / "out" / "solution.usda", "--lightmaps", "-o", tmp_path / "v2.png")
    assert r.returncode != 0 and "is missing" in r.stderr
