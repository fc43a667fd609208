"""The Monte Carlo reference (Model.reference) against cases with known answers: it must
agree within its own stated standard error (and a small absolute margin)."""

import numpy as np

from conftest import BIG, _engine, box_faces, make_model, parallel_squares, quad


def _within(estimate, error, expected, sigmas=4.0, rel=2e-3):
    """|estimate - expected| within `sigmas` standard errors plus a small relative margin."""
    diff = np.abs(np.asarray(estimate) - expected)
    assert np.all(diff <= sigmas * np.asarray(error) + rel * np.abs(expected)), (estimate, error, expected)


def test_furnace_box_radiance_is_e_over_pi_one_minus_rho():
    # Closed box, every face rho = 0.5 and E = 1 W/m^2: B = E / (1 - rho) = 2, L = B / pi.
    m = make_model(box_faces(), reflectance=0.5, emission=1.0, max_area=BIG, max_edge=BIG)
    ids = np.arange(6, dtype=np.int32)
    st = np.full((6, 2), 0.37)
    ref = m.reference(ids, st, _engine.ReferenceOptions(paths=4096, min_bounces=3, seed=11))
    _within(ref.radiance, ref.standard_error, 2.0 / np.pi)
    assert np.all(ref.standard_error > 0)


def _corner_form_factor(a, b, c):
    """Point below the corner of an a x b rectangle at distance c, parallel (closed form)."""
    A, B = a / c, b / c
    return (A / np.sqrt(1 + A * A) * np.arctan(B / np.sqrt(1 + A * A))
            + B / np.sqrt(1 + B * B) * np.arctan(A / np.sqrt(1 + B * B))) / (2 * np.pi)


def test_radiance_under_a_square_emitter_matches_the_closed_form():
    # Bottom square (rho = 0.5) lit by the top square emitting E = pi (radiance 1) that reflects
    # nothing; bottom light escapes or reaches the black emitter, so there is one bounce only.
    polys = parallel_squares(1.0)
    m = make_model(polys, reflectance=[[0.5] * 3, [0.0] * 3], emission=[[0.0] * 3, [np.pi] * 3],
                   max_area=BIG, max_edge=BIG)
    # At the centre: H = E * F(point -> square) with F = 4 x corner(0.5, 0.5, 1).
    ref = m.reference(np.array([0], dtype=np.int32), np.array([[0.5, 0.5]]),
                      _engine.ReferenceOptions(paths=20000, min_bounces=3, seed=3))
    expected = 0.5 / np.pi * np.pi * 4 * _corner_form_factor(0.5, 0.5, 1.0)
    _within(ref.radiance[0], ref.standard_error[0], expected)


def test_mean_over_the_receiver_matches_the_area_form_factor():
    # Mean exitant radiance of the bottom square: (rho / pi) E F_12 with F_12 = 0.199825.
    m = make_model(parallel_squares(1.0), reflectance=[[0.5] * 3, [0.0] * 3],
                   emission=[[0.0] * 3, [np.pi] * 3], max_area=BIG, max_edge=BIG)
    g = 16
    s, t = np.meshgrid((np.arange(g) + 0.5) / g, (np.arange(g) + 0.5) / g)
    st = np.ascontiguousarray(np.stack([s.ravel(), t.ravel()], axis=1))
    ref = m.reference(np.zeros(g * g, dtype=np.int32), st,
                      _engine.ReferenceOptions(paths=512, min_bounces=3, seed=5))
    mean = ref.radiance.mean(axis=0)
    err = np.sqrt((ref.standard_error ** 2).sum(axis=0)) / (g * g)
    expected = 0.5 * _engine.parallel_rectangles_form_factor(1, 1, 1)
    # The midpoint rule over a 16 x 16 grid adds well under 0.5 % here.
    _within(mean, err, expected, rel=5e-3)


def test_reference_is_deterministic_for_a_seed():
    m = make_model(box_faces(), reflectance=0.5, emission=1.0, max_area=BIG, max_edge=BIG)
    ids, st = np.arange(6, dtype=np.int32), np.full((6, 2), 0.5)
    a = m.reference(ids, st, _engine.ReferenceOptions(paths=64, min_bounces=3, seed=1)).radiance
    b = m.reference(ids, st, _engine.ReferenceOptions(paths=64, min_bounces=3, seed=1)).radiance
    c = m.reference(ids, st, _engine.ReferenceOptions(paths=64, min_bounces=3, seed=2)).radiance
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


# ---------------------------------------------------------------------------------------------
# glass: passed straight with T(theta) = tau0 r(cos theta), reflecting rho on the side met
# ---------------------------------------------------------------------------------------------


def test_light_through_a_pane_is_its_transmittance_times_the_unobstructed():
    # The closed form above with a large pane halfway (tau0 = 0.6, rho 0): every direction from
    # the bottom centre to the emitter is within 19.5 deg of the pane's normal, where clear
    # glass's relative angular transmittance is exactly 1 (hirad.daylight.glazing), so the
    # next-event rays pass with T = 0.6: L = rho tau0 F (radiance 1 of the emitter).
    from hirad.daylight.glazing import angular_table

    d = 4.0
    pane = quad([-10, -10, d / 2], [20, 0, 0], [0, 20, 0])
    m = make_model(parallel_squares(d) + [pane], reflectance=[[0.5] * 3, [0.0] * 3, [0.0] * 3],
                   emission=[[0.0] * 3, [np.pi] * 3, [0.0] * 3], max_area=BIG, max_edge=BIG,
                   transmittance=[0.0, 0.0, 0.6], glass_angular=angular_table())
    ref = m.reference(np.array([0], dtype=np.int32), np.array([[0.5, 0.5]]),
                      _engine.ReferenceOptions(paths=20000, min_bounces=3, seed=5))
    f = 4 * _corner_form_factor(0.5, 0.5, d)
    _within(ref.radiance[0], ref.standard_error[0], 0.5 * 0.6 * f)


def test_a_lossless_pane_inside_a_furnace_keeps_it_a_furnace():
    # A closed box, every wall E = 1 and rho = 0.5, split by a pane that absorbs nothing
    # (tau0 = 0.6 straight through at every angle, rho = 0.4 diffuse): radiance stays uniform,
    # L = E / (pi (1 - rho)) on both sides. Glass that stopped the light it does not reflect
    # (absorbing 0.6 of it) would make the walls darker.
    pane = quad([0.5, 0, 0], [0, 1, 0], [0, 0, 1])
    walls = box_faces()
    n = len(walls)
    m = make_model(walls + [pane], reflectance=[0.5] * n + [0.4], emission=[1.0] * n + [0.0],
                   max_area=BIG, max_edge=BIG, transmittance=[0.0] * n + [0.6])
    ids = np.arange(n, dtype=np.int32)
    st = np.array([[0.3, 0.7]] * n)  # off the pane's line on the walls it meets
    ref = m.reference(ids, st, _engine.ReferenceOptions(paths=8192, min_bounces=3, seed=12))
    _within(ref.radiance, ref.standard_error, 2.0 / np.pi)
