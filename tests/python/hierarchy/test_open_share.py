"""Elements partly inside other geometry (Hierarchy::open): a floor modelled as one quad runs on
under a block standing on it. The part under the block receives nothing; an element straddling
the block's foot must show (and pass on) the light of its open part, not that light diluted by
the hidden area.

Checks: the measured open share against the footprint's exact area; a furnace (every surface
emits 1 and reflects 0.5, closed) in which every open point has B = E / (1 - rho) = 2, the
straddling elements included (they came out near 1 + 0.5 x 2 x open before: -25 % at half
hidden); and the energy balance over the open areas."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import box_faces, make_model, quad

from hirad import _engine
from hirad.engine import patch_dict

# The block: x 0.3 .. 0.6, y 0.35 .. 0.65, z 0 .. 0.3, outward faces, no bottom (it stands on
# the floor z = 0, which runs on under it). Its edges are off the leaves' 1/8 m grid, so leaves
# straddle its foot.
BLOCK = [
    quad((0.3, 0.35, 0.3), (0.3, 0, 0), (0, 0.3, 0)),   # top, +z
    quad((0.3, 0.35, 0), (0, 0, 0.3), (0, 0.3, 0)),     # -x
    quad((0.6, 0.35, 0), (0, 0.3, 0), (0, 0, 0.3)),     # +x
    quad((0.3, 0.35, 0), (0.3, 0, 0), (0, 0, 0.3)),     # -y
    quad((0.3, 0.65, 0), (0, 0, 0.3), (0.3, 0, 0)),     # +y
]
FOOTPRINT = 0.3 * 0.3
RHO = 0.5


@pytest.fixture(scope="module")
def furnace_with_block():
    m = make_model(box_faces() + BLOCK, RHO, 1.0)
    r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=2e-5, min_area=1 / 64, samples=64, seed=1, max_rounds=6),
                             _engine.SolveOptions(method="jacobi", tolerance=1e-10, max_iterations=100000))
    m.use_leaves_as_patches()
    return r, patch_dict(m.patch_arrays())


def floor_leaves(p):
    return (np.abs(p["normal"][:, 2] - 1) < 1e-9) & (np.abs(p["centroid"][:, 2]) < 1e-9)


def test_open_share_measures_the_footprint(furnace_with_block):
    r, p = furnace_with_block
    open_ = np.asarray(r.open)
    floor = floor_leaves(p)
    hidden = (p["area"][floor] * (1 - open_[floor])).sum()
    # 64 stratified points per leaf: the hidden area within 2 % of the footprint's
    assert hidden == pytest.approx(FOOTPRINT, rel=0.02)
    # every other surface is wholly open, and leaves straddle the foot
    assert np.all(open_[~floor] == 1.0)
    straddling = floor & (open_ > 0) & (open_ < 1)
    assert straddling.sum() >= 8


def test_furnace_with_a_block_on_the_floor(furnace_with_block):
    r, p = furnace_with_block
    assert r.converged
    open_ = np.asarray(r.open)
    b = np.asarray(r.radiosity)[:, 0]
    seen = open_ > 0
    expected = 1.0 / (1.0 - RHO)
    whole = seen & (open_ == 1)
    straddling = seen & (open_ < 1)
    err_whole = np.abs(b[whole] / expected - 1)
    err_straddling = np.abs(b[straddling] / expected - 1)
    # Wholly open leaves: the furnace test's own tolerance (test_hierarchy: 1 %). Straddling
    # leaves carry the error of their measured open share too (64 points: a few %), so 5 %;
    # the diluted value they had (1 + rho x 2 x open) is off by 25 % at half hidden.
    assert err_whole.max() < 0.01, f"max error {err_whole.max():.4f} on wholly open leaves"
    assert err_straddling.max() < 0.05, f"max error {err_straddling.max():.4f} on straddling leaves"
    # mean over the straddlers, area weighted: no dark bias left
    w = p["area"][straddling] * open_[straddling]
    assert abs(np.sum(w * (b[straddling] / expected - 1)) / w.sum()) < 0.01


def test_energy_balance_over_open_areas(furnace_with_block):
    # Emitted from the open parts = absorbed there + escaped (the links' shortfall), in W.
    r, p = furnace_with_block
    area = p["area"] * np.asarray(r.open)
    emitted = area.sum() * 1.0
    absorbed = ((1 - RHO) * np.asarray(r.irradiance)[:, 0] * area).sum()
    escaped = np.asarray(r.escaped)[:, 0].sum()
    assert (absorbed + escaped) == pytest.approx(emitted, rel=1e-6)
    # closed: what escapes is the couplings' estimation error only
    assert abs(escaped) < 0.01 * emitted
