"""CIE 171:2006 daylight cases 5.9-5.12 through the engine: the sky component (and, in the façade
cases, the externally reflected component of a ground of reflectance 0.30) at the published
points of a black 4 x 4 x 3 m room, with unglazed and glazed (6 mm clear glass) roof and façade
openings, for CIE skies. The expected values are the oracle's (cie171_daylight.py): the sky's
luminance integrated over each opening by Gauss-Legendre quadrature, independently of hirad's
sky code, patches and engine. The engine sees the sky as distant lights over Reinhart patches
(hirad.daylight.sources) and the openings through Embree rays, glass with its angular
transmittance (hirad.daylight.glazing); SC = 100 E / E_h with E_h the same sky lights' value on
an unobstructed horizontal plane. Allowance: 2 % of the value (the issue's), plus 0.02 SC points
where the value is small (a point that sees the opening at grazing incidence).
"""

from __future__ import annotations

import functools
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

_engine = pytest.importorskip("hirad._engine")

import cie171_daylight as oracle  # noqa: E402
from hirad.daylight import skies  # noqa: E402
from hirad.daylight.glazing import angular_table  # noqa: E402
from hirad.daylight.sources import sky_lights  # noqa: E402

Y = np.array([0.2126, 0.7152, 0.0722])


def _quad(o, u, v):
    o, u, v = (np.asarray(x, float) for x in (o, u, v))
    return np.array([o, o + u, o + u + v, o + v])


def _frame_with_hole(origin, a, b, la, lb, hole_lo, hole_hi):
    """A rectangle origin + s a + t b (s in [0, la], t in [0, lb]) less the hole [hole_lo,
    hole_hi] (in (s, t)), as up to 4 quads facing along a x b; and the hole as one quad."""
    a, b, o = (np.asarray(x, float) for x in (a, b, origin))
    (s0, t0), (s1, t1) = hole_lo, hole_hi
    out = []
    for (sa, ta, sb, tb) in ((0, 0, la, t0), (0, t1, la, lb), (0, t0, s0, t1), (s1, t0, la, t1)):
        if sb > sa and tb > ta:
            out.append(_quad(o + a * sa + b * ta, a * (sb - sa), b * (tb - ta)))
    hole = _quad(o + a * s0 + b * t0, a * (s1 - s0), b * (t1 - t0))
    return out, hole


def _room(case: str, opening: str):
    """The black room (faces facing inwards) with its opening: (quads, transmittance per quad)."""
    W, D, H = oracle.ROOM
    floor = _quad([0, 0, 0], [W, 0, 0], [0, D, 0])
    north = _quad([0, D, 0], [W, 0, 0], [0, 0, H])          # faces -y (south, inwards)
    west = _quad([0, 0, 0], [0, D, 0], [0, 0, H])           # faces +x
    east = _quad([W, 0, 0], [0, 0, H], [0, D, 0])           # faces -x
    op = oracle.cie171_cases()[case]["openings"][opening]
    c, e1, e2 = (np.asarray(x, float) for x in (op.corner, op.e1, op.e2))
    if case in ("5.9", "5.10"):
        # ceiling (faces down = b x a with a = +y, b = +x) with the hole
        ring, hole = _frame_with_hole([0, 0, H], [0, 1, 0], [1, 0, 0], D, W,
                                      (c[1], c[0]), (c[1] + e2[1], c[0] + e1[0]))
        walls = [floor, north, west, east, _quad([0, 0, 0], [0, 0, H], [W, 0, 0])] + ring
    else:
        # the south wall (y = 0, facing +y: a = +z, b = +x) with the hole
        ring, hole = _frame_with_hole([0, 0, 0], [0, 0, 1], [1, 0, 0], H, W,
                                      (c[2], c[0]), (c[2] + e2[2], c[0] + e1[0]))
        walls = [floor, north, west, east, _quad([0, 0, H], [0, D, 0], [W, 0, 0])] + ring
    quads = walls
    tau = [0.0] * len(walls)
    if oracle.cie171_cases()[case]["glazed"]:
        quads = walls + [hole]
        tau = tau + [oracle.CLEAR_6MM_TAU0]
    return np.array(quads), np.array(tau)


def _sky(sky_type: int):
    zen, azi = math.radians(90 - oracle.SUN_ELEVATION_DEG), math.pi  # due south
    if sky_type == oracle.TRADITIONAL_OVERCAST:
        return skies.CIEOvercastSky(zenith_luminance=1000.0)
    return skies.CIEGeneralSky(sky_type, zen, azi, zenith_luminance=1000.0)


@functools.lru_cache(maxsize=None)
def _lights(sky_type: int, rho_g: float):
    # Reinhart MF:6 (5,185 patches), each cut into 8 x 8 cells: 0.6 % at the grazing point A of
    # 5.9 under the clear sky (MF:4 gives 4 %); the façade points converge alike.
    return sky_lights(_sky(sky_type), "reinhart6", up="Z", ground_reflectance=rho_g, subdivisions=8)


def _engine_sc(case: str, opening: str, sky_type: int, names):
    quads, tau = _room(case, opening)
    n = len(quads)
    glazed = bool(np.any(tau > 0))
    field = _engine.SurfaceField(np.ascontiguousarray(quads), np.full(n, 4, np.int32),
                                 transmittance=tau if glazed else None,
                                 glass_angular=np.asarray(angular_table(), float) if glazed else None)
    rho_g = oracle.cie171_cases()[case]["ground_reflectance"]
    lights = _lights(sky_type, rho_g)
    field.set_luminaires([l.to_engine() for l in lights.combined])
    pts = {nm: (p, d) for nm, p, d in oracle.cie171_cases()[case]["points"]}
    P = np.array([pts[k][0] for k in names], float)
    N = np.array([pts[k][1] for k in names], float)
    # points on the room's surfaces: lifted a hair inside, as a sensor on the surface
    res = field.illuminance(P + N * 1e-6, N, np.zeros((n, 3)), 0, 1, 1)
    e = np.asarray(res.direct) @ Y
    eh = float(lights.horizontal_illuminance @ Y)
    return 100.0 * e / eh


CASES = [("5.9", "1x1"), ("5.10", "1x1"), ("5.11", "2x1"), ("5.12", "2x1")]


@pytest.mark.parametrize("case,opening", CASES)
@pytest.mark.parametrize("sky_type", [1, 12, 16])
def test_sky_component_matches_the_integral_over_the_opening(case, opening, sky_type):
    names = [nm for nm, _, _ in oracle.cie171_cases()[case]["points"]]
    got = _engine_sc(case, opening, sky_type, names)
    want = np.array([oracle.case_value(case, opening, sky_type, nm, rtol=1e-6, clamp_glass=True) for nm in names])
    assert np.all(want >= 0)
    bad = np.abs(got - want) > 0.02 * want + 0.02
    assert not bad.any(), {nm: (round(g, 4), round(w, 4)) for nm, g, w, b in zip(names, got, want, bad) if b}


def test_glass_takes_away_what_its_angular_transmittance_says():
    """5.10 against 5.9 at floor point G, which sees the roof opening at 30-45 degrees: the ratio
    of the two engine values is the oracle's ratio (glass changes nothing else)."""
    names = ["G"]
    open_ = _engine_sc("5.9", "1x1", 16, names)[0]
    glazed = _engine_sc("5.10", "1x1", 16, names)[0]
    ratio = oracle.case_value("5.10", "1x1", 16, "G", clamp_glass=True) / oracle.case_value("5.9", "1x1", 16, "G")
    assert glazed / open_ == pytest.approx(ratio, rel=5e-3)
    assert ratio < oracle.CLEAR_6MM_TAU0  # oblique rays lose more than the normal transmittance
