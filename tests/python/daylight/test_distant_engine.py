"""Distant lights and glazing in the engine (issue 16): the sun and sky patches as luminaires
whose points are directions, and glass that lets direct light through with tau0 r(cos theta).

Closed forms used:
* a surface facing n under a distant light of perpendicular illuminance E from unit direction
  d receives E max(0, n . d) (Lambert's cosine law), and reflects rho times that;
* glass of normal transmittance tau0 and relative angular transmittance r passes
  tau0 r(|cos theta|) of a ray, theta from the glass's normal; panes in series multiply;
* a uniform sky of luminance L seen through a horizontal opening of area A sends
  Phi = A L tau0 integral over the hemisphere of r(cos theta) cos theta d omega
    = 2 pi A L tau0 integral_0^1 r(mu) mu d mu
  into the room below it (each direction's flux is L d omega times the opening's projected
  area A cos theta); with r linear in mu, r = mu, the integral is 1/3;
* a closed room: all light that enters (the direct light on its faces) is absorbed by its
  faces, glass included (what glass does not reflect, it absorbs or lets out):
  sum (1 - rho) (D + H) A = sum D A.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

_engine = pytest.importorskip("hirad._engine")

from conftest import make_model, quad  # noqa: E402

UP = np.array([0.0, 0.0, 1.0])


def sun(direction, e=1000.0, name="sun"):
    d = np.asarray(direction, float).reshape(1, 3)
    return _engine.Luminaire.distant(name, d, np.array([1.0]), e, np.ones((1, 3)))


def sheet(z, size=10.0):
    """A horizontal pane (facing down) at height z, much wider than the test floor."""
    h = size / 2
    return quad([-h, -h, z], [0, size, 0], [size, 0, 0])


FLOOR = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])


def floor_direct(model):
    pa = model.patch_arrays()
    return pa.direct[pa.face == 0]


@pytest.mark.parametrize("zenith", [0.0, 30.0, 75.0])
def test_distant_light_on_an_open_floor_follows_the_cosine_law(zenith):
    t = math.radians(zenith)
    m = make_model([FLOOR], 0.5, max_area=0.05)
    m.set_luminaires([sun([0, math.sin(t), math.cos(t)])])
    d = floor_direct(m)
    assert np.allclose(d, 1000 * math.cos(t), rtol=1e-12)


def test_light_from_below_the_horizon_of_a_face_does_not_reach_it():
    m = make_model([FLOOR], 0.5, max_area=0.05)
    m.set_luminaires([sun([0, 1, -0.2])])
    assert np.all(floor_direct(m) == 0)


def test_hierarchical_radiosity_of_a_sunlit_floor_is_rho_e_cos():
    t = math.radians(40)
    m = make_model([FLOOR], 0.6)
    m.set_luminaires([sun([math.sin(t), 0, math.cos(t)], 800.0)])
    r = m.solve_hierarchical(_engine.HierarchyOptions(), _engine.SolveOptions(method="jacobi"))
    assert np.allclose(r.radiosity, 0.6 * 800 * math.cos(t), rtol=1e-12)


def test_an_opaque_roof_casts_a_full_shadow():
    m = make_model([FLOOR, sheet(1.0)], 0.5, max_area=0.05)
    m.set_luminaires([sun([0, 0.3, 1])])
    assert np.all(floor_direct(m) == 0)


@pytest.mark.parametrize("zenith", [0.0, 35.0, 60.0])
def test_glass_passes_tau0_times_its_angular_transmittance(zenith):
    t = math.radians(zenith)
    d = [0, math.sin(t), math.cos(t)]
    # flat angular response
    m = make_model([FLOOR, sheet(1.0)], [[0.5] * 3, [0.08] * 3], max_area=0.05, transmittance=[0, 0.85])
    m.set_luminaires([sun(d)])
    assert np.allclose(floor_direct(m), 1000 * math.cos(t) * 0.85, rtol=1e-6)
    # r(mu) = mu^2 tabulated at 201 cosines (linear between: error below 1/(8 200^2))
    mu = np.linspace(0, 1, 201)
    m = make_model([FLOOR, sheet(1.0)], [[0.5] * 3, [0.08] * 3], max_area=0.05, transmittance=[0, 0.85],
                   glass_angular=mu ** 2)
    m.set_luminaires([sun(d)])
    assert np.allclose(floor_direct(m), 1000 * math.cos(t) * 0.85 * math.cos(t) ** 2, rtol=1e-5, atol=1e-6)


def test_panes_in_series_multiply_and_a_pane_counts_once_at_shared_edges():
    # The panes are meshed into 0.01 m^2 patches; rays from the floor's grid points straight up
    # cross them exactly at patch corners and edges, where several patches of one pane meet.
    panes = [FLOOR, sheet(1.0), sheet(1.7)]
    m = make_model(panes, [[0.5] * 3, [0.1] * 3, [0.1] * 3], max_area=0.01, transmittance=[0, 0.8, 0.5])
    pts = np.array([[0.5, 0.5, 0.0], [0.3, 0.3, 0.0], [0.25, 0.7, 0.0]])
    dirs = np.array([[0, 0, 1.0], [0, 1, 1.0], [1, 0, -1.0]])
    t = m.direct_transmittance(pts, np.tile(UP, (3, 1)), dirs)
    assert np.allclose(t[:, 0], 0.4, rtol=1e-6)
    assert np.allclose(t[:, 1], 0.4 / math.sqrt(2), rtol=1e-6)
    assert np.all(t[:, 2] == 0)


def test_glass_passes_interreflected_light_in_direction():
    """Clear glass is a thin sheet to interreflected light too: a ray through it keeps its
    direction and carries tau0 r(cos theta) of its light. An emitting floor under a wide pane
    (r = 1: every ray through it carries tau0), a ceiling square above the floor or 3 m aside:
    either way the ceiling receives tau0 times what it receives with no pane (a pane that
    re-emitted what it passes diffusely would light the two ceilings in another ratio). Opaque
    glass passes nothing."""
    tau0 = 0.8

    def ceiling_receives(ceiling, tau):
        polys = [FLOOR, ceiling] + ([sheet(1.0)] if tau is not None else [])
        m = make_model(polys, [[0.0] * 3] * len(polys), transmittance=[0, 0, tau] if tau is not None else None,
                       emission=[[100.0] * 3] + [[0.0] * 3] * (len(polys) - 1))
        r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-6, min_area=0.01, samples=16),
                                 _engine.SolveOptions(method="jacobi", tolerance=1e-9))
        m.use_leaves_as_patches()
        pa = m.patch_arrays()
        on = pa.face == 1
        return float(np.asarray(r.irradiance)[on, 1] @ pa.area[on])

    for ceiling in (quad([0, 0, 2.0], [0, 1, 0], [1, 0, 0]), quad([3, 0, 2.0], [0, 1, 0], [1, 0, 0])):
        open_air = ceiling_receives(ceiling, None)
        assert open_air > 0
        assert ceiling_receives(ceiling, tau0) == pytest.approx(tau0 * open_air, rel=0.02)
        assert ceiling_receives(ceiling, 0.0) == 0


def _box(w, d, h):
    """A closed box [0, w] x [0, d] x [0, h], faces facing inwards: floor, ceiling, 4 walls."""
    return [
        quad([0, 0, 0], [w, 0, 0], [0, d, 0]),        # floor, up
        quad([0, 0, h], [0, d, 0], [w, 0, 0]),        # ceiling, down
        quad([0, 0, 0], [0, 0, h], [w, 0, 0]),        # y = 0 wall, +y
        quad([0, d, 0], [w, 0, 0], [0, 0, h]),        # y = d wall, -y
        quad([0, 0, 0], [0, d, 0], [0, 0, h]),        # x = 0 wall, +x
        quad([w, 0, 0], [0, 0, h], [0, d, 0]),        # x = w wall, -x
    ]


def _roof_with_opening(w, d, h, o):
    """The ceiling of _box as a frame around a central o x o glazed opening (last polygon)."""
    x0, x1 = (w - o) / 2, (w + o) / 2
    y0, y1 = (d - o) / 2, (d + o) / 2
    ring = [
        quad([0, 0, h], [0, y0, 0], [w, 0, 0]),
        quad([0, y1, h], [0, d - y1, 0], [w, 0, 0]),
        quad([0, y0, h], [0, o, 0], [x0, 0, 0]),
        quad([x1, y0, h], [0, o, 0], [w - x1, 0, 0]),
    ]
    glass = quad([x0, y0, h], [0, o, 0], [o, 0, 0])
    return ring, glass


def _uniform_sky(luminance, n_mu=24, n_phi=48):
    """A uniform sky as equal-solid-angle directions (midpoints in mu = cos theta and phi)."""
    mu = (np.arange(n_mu) + 0.5) / n_mu
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * math.pi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M ** 2)
    dirs = np.stack([s * np.cos(P), s * np.sin(P), M], axis=-1).reshape(-1, 3)
    w = np.full(len(dirs), 1.0 / len(dirs))
    return _engine.Luminaire.distant("sky", dirs, w, luminance * 2 * math.pi, np.ones((1, 3))), dirs


def test_glazed_opening_transmits_the_integral_of_tau_over_the_sky():
    w, d, h, o = 2.0, 2.0, 1.5, 0.6
    L, tau0 = 1000.0, 0.8
    ring, glass = _roof_with_opening(w, d, h, o)
    walls = _box(w, d, h)
    polys = [walls[0]] + walls[2:] + ring + [glass]
    mu = np.linspace(0, 1, 101)
    rho = [[0.5] * 3] * (len(polys) - 1) + [[0.1] * 3]
    tau = [0.0] * (len(polys) - 1) + [tau0]
    m = make_model(polys, rho, max_area=0.01, transmittance=tau, glass_angular=mu)
    sky, dirs = _uniform_sky(L)
    m.set_luminaires([sky])
    pa = m.patch_arrays()
    inside = pa.face != len(polys) - 1
    received = float((pa.direct[inside, 1] * pa.area[inside]).sum())
    # The same quadrature of the sky, exact over the opening: sum_k L dOmega A mu_k tau0 r(mu_k)
    mu_k = dirs[:, 2]
    quadrature = float((L * 2 * math.pi / len(dirs)) * o * o * (mu_k * tau0 * mu_k).sum())
    closed_form = 2 * math.pi * o * o * L * tau0 / 3
    assert quadrature == pytest.approx(closed_form, rel=1e-3)
    # The floor and walls see the opening's light with 9 points per 0.01 m^2 patch.
    assert received == pytest.approx(quadrature, rel=0.01)


def _glazing_balance(r, pa):
    """Entering and leaving power (green channel, W) of a hierarchical solve with glazing, by
    the accounting of hirad.report.energy_balance: opaque faces take in their direct light D and
    absorb (1 - rho)(D + H); a glazed face's sides (the published front and the back, which the
    result sums) take in only the direct light they reflect, rho D (what they let through lands
    elsewhere as D), and take (1 - rho) H of the interreflected light (absorbed or let through:
    what reaches other surfaces through the glass is missing from the escaped light of the
    surfaces that sent it); light that reaches no surface escapes."""
    D, H = pa.direct[:, 1], np.asarray(r.irradiance)[:, 1]
    rho, A = pa.reflectance[:, 1], pa.area
    glass = pa.transmittance > 0
    entering = float(np.where(glass, rho * D, D) @ A) + r.glass_back_entered[1]
    absorbed = float(np.where(glass, (1 - rho) * H, (1 - rho) * (D + H)) @ A) + r.glass_back_absorbed[1]
    escaped = float(np.asarray(r.escaped)[:, 1].sum()) + r.glass_back_escaped[1]
    return entering, absorbed, escaped


def test_energy_balance_closes_with_a_glazed_opening():
    """A closed room lit by the sun through a glazed roof opening: the sun's light enters, and the
    room's interreflected light partly leaves again through the glass, in direction, to the sky.
    By the report's accounting (hirad.report.energy_balance) the glass's inner side takes
    (1 - rho)(H - D) of the interreflected light it receives, what it absorbs and what it lets
    out together (what it lets through to other surfaces is counted again where it lands, and
    the escaped light of the surfaces that sent it is less by as much: per link the power sent
    is the power received, so the sum closes): what enters is what the surfaces absorb, plus
    what the glass takes, plus what escapes."""
    w, d, h, o = 2.0, 2.0, 1.5, 0.6
    ring, glass = _roof_with_opening(w, d, h, o)
    walls = _box(w, d, h)
    polys = [walls[0]] + walls[2:] + ring + [glass]
    rho = np.array([[0.6] * 3] * (len(polys) - 1) + [[0.08] * 3])
    tau = [0.0] * (len(polys) - 1) + [0.85]
    m = make_model(polys, rho, transmittance=tau)
    t = math.radians(30)
    m.set_luminaires([sun([0.2 * math.sin(t), math.sin(t), math.cos(t)], 50000.0)])
    r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-3, min_area=0.02, samples=16),
                             _engine.SolveOptions(method="jacobi", tolerance=1e-7))
    m.use_leaves_as_patches()
    pa = m.patch_arrays()
    entering, absorbed, escaped = _glazing_balance(r, pa)
    assert entering > 0
    # the glass's inner side takes a visible share of the room's light (the opening is 6 % of
    # the ceiling, and lets 85 % of it out)
    glass_side = pa.transmittance > 0
    H = np.asarray(r.irradiance)[:, 1]  # from the links (the direct light apart)
    took = float(((1 - pa.reflectance[glass_side, 1]) * H[glass_side]) @ pa.area[glass_side])
    assert took > 0.01 * entering
    # the outer side sees only the sky: what it reflects of the sun escapes, all but the share
    # of the room-facing clusters' light that the balance books to every leaf below a cluster
    # source in proportion to its B A (the total is exact, the split between leaves is not).
    # How much depends on how many room-facing faces share the back's clusters: with up to four
    # faces under the lowest clusters (hierarchy.h) 6.3 % of what it reflects is booked to them
    # (stop 49; the total below closes to 2e-7).
    assert r.glass_back_escaped[1] == pytest.approx(r.glass_back_entered[1], rel=0.08)
    assert r.glass_back_escaped[1] <= r.glass_back_entered[1]
    # what the couplings' quadrature allows (tests/python/test_proof.py: 0.4 %)
    assert absorbed + escaped == pytest.approx(entering, rel=0.004)


def _parallel_squares(x: float, y: float) -> float:
    """F between directly opposed parallel rectangles of sides a, b at distance c, X = a / c,
    Y = b / c (Howell's catalogue, C-11)."""
    a, b = 1 + x * x, 1 + y * y
    return 2 / (math.pi * x * y) * (math.log(math.sqrt(a * b / (a + b - 1))) + x * math.sqrt(b) * math.atan(x / math.sqrt(b))
                                    + y * math.sqrt(a) * math.atan(y / math.sqrt(a)) - x * math.atan(x) - y * math.atan(y))


def _mean_through_pane(height: float, power: int, n: int = 14) -> float:
    """(1 / A) int int cos^power(theta) cos theta cos theta' / (pi r^2) dA dA' between two unit
    squares `height` apart, one over the other (theta from the vertical: cos = height / r at
    both ends and at any horizontal pane between them), by Gauss-Legendre in four dimensions."""
    g, w = np.polynomial.legendre.leggauss(n)
    u, wu = (g + 1) / 2, w / 2
    X1, Y1, X2, Y2 = np.meshgrid(u, u, u, u, indexing="ij")
    W = wu[:, None, None, None] * wu[None, :, None, None] * wu[None, None, :, None] * wu[None, None, None, :]
    r2 = (X1 - X2) ** 2 + (Y1 - Y2) ** 2 + height ** 2
    c = height / np.sqrt(r2)
    return float((W * c ** (power + 2) / (np.pi * r2)).sum())


def test_the_closed_forms_of_the_pane_test():
    # C-11 against the quadrature it stands for, and the unit squares 1 m apart of Howell's table
    assert _parallel_squares(1.0, 1.0) == pytest.approx(0.199825, abs=2e-6)
    assert _mean_through_pane(2.0, 0) == pytest.approx(_parallel_squares(0.5, 0.5), rel=1e-6)


@pytest.mark.parametrize("solver", ["jacobi", "gauss_seidel", "southwell", "block_southwell"])
def test_clear_glass_passes_interreflected_light_in_direction(solver):
    """An emitting panel (exitance E = 1, facing down) over a glass pane over a floor, three unit
    squares 1 m apart, everything black. Every ray from the panel to the floor crosses the pane
    (its midpoint lies over the same square), and carries tau0 r(cos theta) there, theta from
    the vertical: the floor's mean irradiance is E tau0 F with F of unit squares 2 m apart
    (Howell C-11, X = Y = 1/2: 0.0686) with no angular table, and E tau0 times the mean of
    cos(theta) weighted by the kernel with r = mu (Gauss-Legendre quadrature). The pane reflects
    nothing and passes nothing diffusely: its radiosity is 0. Opaque glass lets nothing through.
    Every hierarchical solver, in memory and streamed out of core."""
    floor = quad([0, 0, 0], [1, 0, 0], [0, 1, 0])          # up
    pane = quad([0, 0, 1], [0, 1, 0], [1, 0, 0])           # front down, towards the floor
    panel = quad([0, 0, 2], [0, 1, 0], [1, 0, 0])          # down
    emission = np.array([[0.0] * 3, [0.0] * 3, [1.0] * 3])
    cases = ((0.8, None, 0.8 * _parallel_squares(0.5, 0.5)), (0.8, [0.0, 1.0], 0.8 * _mean_through_pane(2.0, 1)),
             (0.0, None, 0.0))
    for tau0, table, expected in cases:
        m = make_model([floor, pane, panel], 0.0, emission=emission, transmittance=[0.0, tau0, 0.0],
                       glass_angular=table)
        ho = _engine.HierarchyOptions(epsilon=1e-6, min_area=0.01, samples=16)
        if solver == "block_southwell":
            r = m.solve_out_of_core(ho, _engine.SolveOptions(method=solver, tolerance=1e-9), _engine.OutOfCoreOptions())
        else:
            r = m.solve_hierarchical(ho, _engine.SolveOptions(method=solver, tolerance=1e-9))
        m.use_leaves_as_patches()
        pa = m.patch_arrays()
        on_floor = pa.face == 0
        H = np.asarray(r.irradiance)[:, 1]
        mean_floor = float(H[on_floor] @ pa.area[on_floor])
        assert mean_floor == pytest.approx(expected, rel=0.03, abs=1e-12), (tau0, table)
        on_pane = pa.face == 1
        assert np.all(np.asarray(r.radiosity)[on_pane] == 0)


def test_what_reads_the_surface_sees_through_clear_glass():
    """The read-outs trace through panes too: a sensor under a wide pane (tau0, r = 1) reads
    tau0 times the direct light of an emitting square above it and tau0 times the indirect
    light of a lit square beside it (the same rays, each with the factor tau0 once), and a
    picture looking up through the pane shows tau0 times the square's radiance."""
    tau0 = 0.7
    lamp = quad([0, 0, 2.0], [0, 1, 0], [1, 0, 0])           # emits, facing down
    lit = quad([1.5, 0, 2.0], [0, 1, 0], [1, 0, 0])          # reflects, facing down
    pane = sheet(1.0)

    def field(with_pane):
        polys = [lamp, lit] + ([pane] if with_pane else [])
        corners = np.ascontiguousarray(np.stack(polys))
        rad = np.zeros((len(polys), 4, 3))
        rad[0], rad[1] = 10.0, 2.0
        tau = np.array([0.0, 0.0, tau0])[: len(polys)] if with_pane else None
        return _engine.SurfaceField(corners, np.full(len(polys), 4, np.int32), rad, rad * math.pi,
                                    transmittance=tau), rad

    pts = np.array([[0.5, 0.5, 0.0], [1.2, 0.4, 0.0]])
    up = np.tile(UP, (2, 1))
    readings = []
    for with_pane in (False, True):
        f, rad = field(with_pane)
        emitted = np.zeros((len(rad), 3))
        emitted[0] = 10.0
        ill = f.illuminance(pts, up, emitted, rays=256, seed=3)
        picture = f.render([0.5, 0.5, 0.0], [0, 0, 1.0], [0, 1.0, 0], 20.0, 8, 8, 1)
        readings.append((np.asarray(ill.direct), np.asarray(ill.indirect), picture))
    (d0, i0, p0), (d1, i1, p1) = readings
    assert np.all(d0[:, 1] > 0) and np.all(i0[:, 1] > 0)
    np.testing.assert_allclose(d1, tau0 * d0, rtol=1e-6)
    np.testing.assert_allclose(i1, tau0 * i0, rtol=1e-6)
    assert np.all(p0 == 10.0)
    np.testing.assert_allclose(p1, tau0 * p0, rtol=1e-6)


def test_bad_distant_lights_are_refused_by_name():
    with pytest.raises(ValueError, match="luminaire 'sky'.*weights sum"):
        _engine.Luminaire.distant("sky", np.array([[0, 0, 1.0], [0, 1, 1.0]]), np.array([0.5, 0.4]), 1.0,
                                  np.ones((1, 3)))
    with pytest.raises(ValueError, match="illuminance"):
        _engine.Luminaire.distant("sun", np.array([[0, 0, 1.0]]), np.array([1.0]), -5.0, np.ones((1, 3)))
    with pytest.raises(ValueError, match="direction 0"):
        _engine.Luminaire.distant("sun", np.array([[0, 0, 0.0]]), np.array([1.0]), 5.0, np.ones((1, 3)))


def test_glazing_values_are_checked():
    with pytest.raises(ValueError, match="transmittance"):
        make_model([FLOOR], 0.5, transmittance=[1.2])
    with pytest.raises(ValueError, match="transmittance"):
        make_model([FLOOR], 0.5, transmittance=[0.6])  # 0.5 + 0.6 > 1
    with pytest.raises(ValueError, match="angular"):
        make_model([FLOOR], 0.1, transmittance=[0.8], glass_angular=[0.5])


def test_no_ray_slips_between_the_patches_of_a_closed_room():
    """A closed 6 x 4 x 3 m room meshed into 0.5 m patches; points on the lattice of the patch
    corners, rays along the lattice's axes and diagonals and straight up (the sky patch centres
    at azimuths of multiples of 45 degrees): rays that run exactly along shared patch edges and
    through shared corners. The room must stop every one (watertight traversal)."""
    m = make_model(_box(6.0, 4.0, 3.0), 0.5, max_edge=0.5)
    xs, ys = np.meshgrid(np.arange(0.5, 6.0, 0.5), np.arange(0.5, 4.0, 0.5))
    pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 1.0)], axis=1)
    dirs = []
    for alt in (26.565051177, 45.0, 63.434948823, 90.0):  # slopes 1/2, 1, 2 and vertical
        for az in range(0, 360, 45):
            a, z = math.radians(alt), math.radians(az)
            dirs.append([math.cos(a) * math.sin(z), math.cos(a) * math.cos(z), math.sin(a)])
    t = m.direct_transmittance(pts, np.tile(UP, (len(pts), 1)), np.array(dirs))
    assert np.count_nonzero(t) == 0


def _sky_directions(count, seed=3):
    """`count` unit directions over the upper hemisphere towards -y (z > 0.3, y <= 0),
    reproducible."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(count, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.3
    d[:, 1] = -np.abs(d[:, 1])
    return d / np.linalg.norm(d, axis=1)[:, None]


def _patch_groups(directions, per_group, interleave):
    groups = []
    for k in range(0, len(directions), per_group):
        d = directions[k:k + per_group]
        groups.append(_engine.Luminaire.distant(f"patch {k}", d, np.full(len(d), 1.0 / len(d)), 100.0 + k,
                                                np.ones((1, 3)), interleave=interleave))
    return groups


def test_interleaved_sky_groups_see_each_direction_once_and_sum_to_the_whole_sky():
    """A sky cut into 100 groups of 3 directions (more groups than one batch lights together),
    over a floor half under a shading sheet. Each direction of an interleaved group is seen from
    one of an element's 3 x 3 points with 9 times its weight (luminaire.h), so:
    * on the open part of the floor every group's direct light is exactly E sum_k w_k (n . d_k)
      (Lambert's cosine law; no point sees a shadow);
    * the groups' sum on every patch is the whole sky as one light of 300 directions, which
      the engine interleaves over the same points in the same order (to rounding);
    * the groups cost the floor one ray per direction and patch, a ninth of seeing every
      direction from every point."""
    dirs = _sky_directions(300)
    floor = quad([0, 0, 0], [2, 0, 0], [0, 1, 0])
    shade = quad([0, 0.5, 0.3], [0, 0.5, 0], [2, 0, 0])  # over y in [0.5, 1], facing down
    groups = _patch_groups(dirs, 3, interleave=True)
    e = np.array([g.illuminance for g in groups])
    whole = _engine.Luminaire.distant("sky", dirs, np.repeat(e, 3) / np.repeat(e, 3).sum(),
                                      float(np.repeat(e, 3).sum() / 3), np.ones((1, 3)))

    def model(lights_groups):
        m = make_model([floor, shade], 0.0, max_area=0.05)
        m.set_luminaires([whole])
        m.set_light_groups([[] for _ in lights_groups], [[g] for g in lights_groups])
        m.compute_links(_engine.FormFactorOptions(method="raycast", samples=4, seed=1))
        return m

    m = model(groups)
    before = m.rays_cast()
    sol = m.solve_groups(_engine.SolveOptions(method="jacobi", tolerance=1e-9))
    interleaved_rays = m.rays_cast() - before
    pa = m.patch_arrays()
    on_floor = pa.face == 0
    direct = np.stack([np.asarray(s.direct)[:, 0] for s in sol])  # (groups, patches)
    exact = np.array([g.illuminance * (np.maximum(g.points @ UP, 0) @ g.weights) for g in groups])
    # A patch is unshaded when no direction's shadow of the sheet (the sheet's rectangle moved by
    # -0.3 (dx, dy) / dz onto the floor) overlaps the patch's rectangle.
    lo, hi = pa.corners[:, :, :2].min(axis=1), pa.corners[:, :, :2].max(axis=1)
    sx, sy = -0.3 * dirs[:, 0] / dirs[:, 2], -0.3 * dirs[:, 1] / dirs[:, 2]
    overlap = ((lo[:, None, 0] < 2 + sx[None]) & (hi[:, None, 0] > sx[None]) &
               (lo[:, None, 1] < 1 + sy[None]) & (hi[:, None, 1] > 0.5 + sy[None]))
    unshaded = on_floor & ~overlap.any(axis=1)
    assert unshaded.sum() >= 4
    assert np.allclose(direct[:, unshaded], exact[:, None], rtol=1e-12, atol=0)
    # the sum is the whole sky's light on every patch (shaded ones too)
    assert np.allclose(direct.sum(axis=0)[on_floor], np.asarray(pa.direct)[on_floor, 0], rtol=1e-9, atol=1e-9)
    assert (np.asarray(pa.direct)[on_floor, 0].min() < 0.8 * np.asarray(pa.direct)[on_floor, 0].max())  # a shadow

    m2 = model(_patch_groups(dirs, 3, interleave=False))
    before = m2.rays_cast()
    m2.solve_groups(_engine.SolveOptions(method="jacobi", tolerance=1e-9))
    whole_rays = m2.rays_cast() - before
    assert whole_rays > 7 * interleaved_rays
