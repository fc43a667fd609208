"""Elements much larger than the room they light: a 4 x 4 x 3 m closed room whose floor is part
of one 200 x 200 m polygon (as scenes model a ground plane that runs under the building), lit
by a 1 m^2 panel under its ceiling. Seen from the ceiling, the room's floor is 0.04 % of that
polygon's area and a third of its form factor.

The oracle is the Monte Carlo path tracer (Model.reference, independent of links and
meshing). Before link estimates drew their visibility points by the kernel
(sample_polygon_by_form_factor) and before close pairs were judged by the bound
min(A_R, A_S), the ceiling came out 49 % dark at epsilon 1e-2: the floor was never split
(its few area-drawn points all landed far outside, so the panel's link to it looked
negligible) and, seen from the ceiling, only 0.04 % of it looked visible.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import _engine, make_model, quad

G, W, D, H = 100.0, 4.0, 4.0, 3.0
POLYS = [
    quad([-G, -G, 0], [2 * G, 0, 0], [0, 2 * G, 0]),          # the ground, up
    quad([0, 0, H], [0, D, 0], [W, 0, 0]),                     # ceiling, down
    quad([0, 0, 0], [0, 0, H], [W, 0, 0]),                     # the four walls, inwards
    quad([0, D, 0], [W, 0, 0], [0, 0, H]),
    quad([W, 0, 0], [0, 0, H], [0, D, 0]),
    quad([0, 0, 0], [0, D, 0], [0, 0, H]),
    quad([1.5, 1.5, H - 0.01], [0, 1, 0], [1, 0, 0]),          # the panel, down, black
]
RHO = [[0.5] * 3] * 6 + [[0.0] * 3]
EMISSION = [[0.0] * 3] * 6 + [[100.0] * 3]


def _model():
    return make_model(POLYS, RHO, emission=EMISSION, max_area=1e9, max_edge=1e9)


def _grid(g, lo_hi):
    u = [(lo + (np.arange(g) + 0.5) / g * (hi - lo)) for lo, hi in lo_hi]
    s, t = np.meshgrid(*u)
    return np.ascontiguousarray(np.stack([s.ravel(), t.ravel()], 1))


@pytest.fixture(scope="module")
def reference():
    """Mean exitant radiance (green) of the ceiling and of the room's part of the floor."""
    m = _model()
    g = 8
    opts = _engine.ReferenceOptions(paths=2048, min_bounces=3, seed=5)
    ceiling = m.reference(np.full(g * g, 1, np.int32), _grid(g, [(0, 1), (0, 1)]), opts)
    lo, hi = G / (2 * G), (G + W) / (2 * G)                    # the room in the ground's (s, t)
    floor = m.reference(np.zeros(g * g, np.int32), _grid(g, [(lo, hi), (lo, hi)]), opts)
    out = {}
    for name, r in (("ceiling", ceiling), ("floor", floor)):
        mean = float(np.asarray(r.radiance)[:, 1].mean())
        se = float(np.sqrt((np.asarray(r.standard_error)[:, 1] ** 2).sum())) / (g * g)
        assert se < 0.01 * mean
        out[name] = mean
    return out


def _solve(epsilon, relative=0.0, with_links=False, **options):
    m = _model()
    r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=epsilon, min_area=0.01, samples=4, relative=relative,
                                                      **options),
                             _engine.SolveOptions(method="jacobi", tolerance=1e-8))
    m.use_leaves_as_patches()
    pa = m.patch_arrays()
    B = np.asarray(r.radiosity)[:, 1]
    c = np.asarray(pa.centroid)
    ceiling = pa.face == 1
    floor = (pa.face == 0) & (c[:, 0] > 0) & (c[:, 0] < W) & (c[:, 1] > 0) & (c[:, 1] < D)
    mean = lambda mask: float(B[mask] @ pa.area[mask]) / float(pa.area[mask].sum()) / math.pi  # noqa: E731
    return (mean(ceiling), mean(floor), r.links) if with_links else (mean(ceiling), mean(floor))


@pytest.mark.parametrize("epsilon, ceiling_within, floor_within", [(1e-2, 0.20, 0.10), (1e-4, 0.06, 0.02)])
def test_a_room_on_a_ground_plane_much_larger_than_it_is_lit_like_the_path_tracer(
        reference, epsilon, ceiling_within, floor_within):
    # Coarse epsilon: the ground is split around the panel and the ceiling sees the floor
    # (what is left: floor elements that straddle the walls spread the room's light outside).
    # Fine epsilon: within the discretisation error of the room alone.
    ceiling, floor = _solve(epsilon)
    assert ceiling == pytest.approx(reference["ceiling"], rel=ceiling_within)
    assert floor == pytest.approx(reference["floor"], rel=floor_within)


def test_the_relative_rule_splits_more_and_moves_the_coarse_solution_towards_the_path_tracer(reference):
    # epsilon 1e-2 is 1 W here; the ceiling gathers about 21 W, so its links stay coarse.
    # relative_epsilon 0.1 also splits, from round 2 on, every link that could carry more than
    # a tenth of its receiver's light: more links, and the ceiling no further from the oracle.
    # The spread rule (tested below) is off here, so that this measures the relative rule alone.
    c0, f0, n0 = _solve(1e-2, 0.0, with_links=True, spread=0.0)
    c1, f1, n1 = _solve(1e-2, 0.1, with_links=True, spread=0.0)
    assert n1 > 2 * n0
    assert abs(c1 / reference["ceiling"] - 1) <= abs(c0 / reference["ceiling"] - 1)
    assert c1 == pytest.approx(reference["ceiling"], rel=0.20)


# ---- uneven sources: a daylit room on the ground plane ------------------------------------------
# A 4 x 4 x 3 m room on a 60 x 60 m ground plane with a 2 x 1 m window in its x = 0 wall, under
# a uniform sky (8 x 16 equal-solid-angle directions). The ground outside is sunlit by the whole
# sky; inside, the same polygon is the room's floor, lit only through the window. Links from the
# ceiling to ground elements that hold both carry the elements' mean radiosity, mostly the
# outside's, into the room: hidden or far from the ceiling, that part is seen through little of G.

DG = 30.0
Y0, Y1, Z0, Z1 = 1.0, 3.0, 0.9, 1.9        # the window in the x = 0 wall
DAYLIT = [
    quad([-DG, -DG, 0], [2 * DG, 0, 0], [0, 2 * DG, 0]),     # the ground, up
    quad([0, 0, H], [0, D, 0], [W, 0, 0]),                   # ceiling, down
    quad([0, 0, 0], [0, 0, H], [W, 0, 0]),                   # walls y = 0, y = D, x = W, inwards
    quad([0, D, 0], [W, 0, 0], [0, 0, H]),
    quad([W, 0, 0], [0, 0, H], [0, D, 0]),
    quad([0, 0, 0], [0, Y0, 0], [0, 0, H]),                  # the x = 0 wall around the window
    quad([0, Y1, 0], [0, D - Y1, 0], [0, 0, H]),
    quad([0, Y0, 0], [0, Y1 - Y0, 0], [0, 0, Z0]),
    quad([0, Y0, Z1], [0, Y1 - Y0, 0], [0, 0, H - Z1]),
]


def _daylit_model():
    m = make_model(DAYLIT, 0.5, max_area=1e9, max_edge=1e9)
    mu = (np.arange(8) + 0.5) / 8
    phi = (np.arange(16) + 0.5) / 16 * 2 * math.pi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M ** 2)
    dirs = np.stack([s * np.cos(P), s * np.sin(P), M], axis=-1).reshape(-1, 3)
    # Radiance 1000 / (2 pi) W/(m^2 sr) per unit solid angle weight: E_h = 500 on open ground.
    sky = _engine.Luminaire.distant("sky", dirs, np.full(len(dirs), 1.0 / len(dirs)), 1000.0, np.ones((1, 3)))
    m.set_luminaires([sky])
    return m


@pytest.fixture(scope="module")
def daylit_ceiling():
    """The path tracer's mean exitant radiance (green) of the daylit room's ceiling."""
    g = 8
    r = _daylit_model().reference(np.full(g * g, 1, np.int32), _grid(g, [(0, 1), (0, 1)]),
                                  _engine.ReferenceOptions(paths=2048, min_bounces=3, seed=5))
    mean = float(np.asarray(r.radiance)[:, 1].mean())
    se = float(np.sqrt((np.asarray(r.standard_error)[:, 1] ** 2).sum())) / (g * g)
    assert se < 0.01 * mean
    return mean


def _daylit_ceiling(**options):
    m = _daylit_model()
    r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-3, min_area=0.05, samples=16, **options),
                             _engine.SolveOptions(method="jacobi", tolerance=1e-8))
    m.use_leaves_as_patches()
    pa = m.patch_arrays()
    B = np.asarray(r.radiosity)[:, 1]
    c = pa.face == 1
    return float(B[c] @ pa.area[c]) / float(pa.area[c].sum()) / math.pi, r.links


def test_uneven_ground_elements_seen_in_part_no_longer_bring_the_outside_into_the_room(daylit_ceiling):
    # Without the rule the ceiling is lit as if the floor were half outside (+22 % when this was
    # written); with it (the default, spread 1e-3 of epsilon) it is within the room's own
    # discretisation error of the path tracer. epsilon 1e-3 is about 3 W here, and the ceiling
    # gathers about 1.4 kW over some 14,000 links: no single link is large, their error is.
    off, n_off = _daylit_ceiling(spread=0.0)
    on, n_on = _daylit_ceiling()
    assert off > 1.12 * daylit_ceiling
    assert on == pytest.approx(daylit_ceiling, rel=0.06)
    assert n_on > n_off


def test_sources_of_even_radiosity_are_never_split_for_their_spread():
    # A closed box of equal emitters and reflectance: every radiosity is the same (E / (1 - rho)),
    # B_max = B_min under every node, and the rule adds no link however small its threshold.
    box = [quad([0, 0, 0], [0, 2, 0], [2, 0, 0]), quad([0, 0, 2], [2, 0, 0], [0, 2, 0]),
           quad([0, 0, 0], [2, 0, 0], [0, 0, 2]), quad([0, 2, 0], [0, 0, 2], [2, 0, 0]),
           quad([0, 0, 0], [0, 0, 2], [0, 2, 0]), quad([2, 0, 0], [0, 2, 0], [0, 0, 2])]
    counts = []
    for spread in (0.0, 1e-3, 1.0):
        m = make_model(box, 0.5, emission=1.0, max_area=1e9, max_edge=1e9)
        r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-4, min_area=0.01, samples=4, spread=spread),
                                 _engine.SolveOptions(method="jacobi", tolerance=1e-8))
        counts.append(r.links)
    assert counts[0] == counts[1] == counts[2]


@pytest.mark.parametrize("spread", [-1e-3, 1.5, float("nan")])
def test_a_spread_outside_0_1_is_refused(spread):
    m = _daylit_model()
    with pytest.raises(ValueError, match="spread must be in"):
        m.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-3, min_area=0.05, spread=spread),
                             _engine.SolveOptions(method="jacobi"))
