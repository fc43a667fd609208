"""The final gather (Engine.gather after a hierarchical solve) against physics: closed-form
point form factors, the furnace (the links that reach a point must cover its hemisphere exactly
once), an umbra, the Monte Carlo reference, and determinism."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import box_faces, make_model, parallel_squares, quad

from hirad import _engine
from hirad.engine import patch_dict


def corner_form_factor(a, b, c):
    """Point below the corner of an a x b rectangle at distance c, parallel (closed form)."""
    A, B = a / c, b / c
    return (A / np.sqrt(1 + A * A) * np.arctan(B / np.sqrt(1 + A * A))
            + B / np.sqrt(1 + B * B) * np.arctan(A / np.sqrt(1 + B * B))) / (2 * np.pi)


def point_to_square(x, y, d, size=1.0):
    """Form factor from a point (x, y) of the plane z = 0 facing +z to the square [0,size]^2 at
    height d, parallel: the four rectangles the point's foot splits it into."""
    total = 0.0
    for w in (x, size - x):
        for h in (y, size - y):
            if w > 0 and h > 0:
                total += corner_form_factor(w, h, d)
    return total


def box_points(per_face: int, seed: int):
    """Random points on the unit box's inner faces, away from their edges, and the faces' normals."""
    rng = np.random.default_rng(seed)
    pts, nrm = [], []
    for face in box_faces():
        n = np.cross(face[1] - face[0], face[3] - face[0])
        n /= np.linalg.norm(n)
        for s, t in rng.random((per_face, 2)) * 0.96 + 0.02:
            pts.append(face[0] + (face[1] - face[0]) * s + (face[3] - face[0]) * t)
            nrm.append(n)
    return np.ascontiguousarray(pts), np.ascontiguousarray(nrm)


def solve(m, epsilon, min_area, samples=16, max_rounds=6):
    r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=epsilon, min_area=min_area, samples=samples, seed=1,
                                                      max_rounds=max_rounds),
                             _engine.SolveOptions(method="jacobi", tolerance=1e-10, max_iterations=100000))
    m.use_leaves_as_patches()
    return r


def test_gather_under_a_square_emitter_is_the_closed_form_point_form_factor():
    # Bottom square (rho 0.5) lit by a black top square emitting E = pi: one bounce, so
    # H(x) = E F(x -> top) exactly, while the bottom's elements only hold their mean.
    m = make_model(parallel_squares(1.0), reflectance=[[0.5] * 3, [0.0] * 3], emission=[[0.0] * 3, [np.pi] * 3])
    solve(m, 1e-2, 0.05)   # coarse on purpose: leaves of 1/16 m^2 or more
    xy = np.array([[0.5, 0.5], [0.1, 0.1], [0.05, 0.6], [0.83, 0.27], [0.97, 0.97]])
    pts = np.ascontiguousarray(np.c_[xy, np.zeros(len(xy))])
    nrm = np.ascontiguousarray(np.tile([0.0, 0.0, 1.0], (len(xy), 1)))
    g = m.gather(pts, nrm)
    expected = np.array([np.pi * point_to_square(x, y, 1.0) for x, y in xy])
    assert np.all(g.patch >= 0)
    np.testing.assert_allclose(g.irradiance[:, 0], expected, rtol=2e-3)
    np.testing.assert_allclose(g.radiance[:, 1], 0.5 * expected / np.pi, rtol=2e-3)
    # The element values do not resolve the fall-off from centre to corner (the test's point).
    p = patch_dict(m.patch_arrays())
    assert len(p["area"]) < 64


@pytest.mark.parametrize("rho", [0.5, 0.9])
def test_gather_in_a_furnace_sees_every_direction_once(rho):
    # Closed box, every face E = 1 and rho: B = 1 / (1 - rho) everywhere, so at any point the
    # gather is (E + rho H) / pi with H = B: only if the links reaching the point (its leaf's
    # and its ancestors') cover the hemisphere exactly once.
    m = make_model(box_faces(), rho, 1.0)
    r = solve(m, {0.5: 2e-5, 0.9: 1e-4}[rho], 0.0155, samples=144)   # test_hierarchy's furnace
    b = r.radiosity
    pts, nrm = box_points(10, seed=7)
    g = m.gather(pts, nrm, _engine.GatherOptions(rays=16))
    assert np.all(g.patch >= 0)
    # H(x) carries the solved B's own error once: within test_hierarchy's furnace bound (1 %; 0.37 %
    # and 0.66 % measured at stop 49), and the gather within 1 % with it.
    assert np.abs(b * (1 - rho) - 1).max() < 0.01
    err = np.abs(g.irradiance * (1 - rho) - 1)
    assert err.max() < 0.01, f"rho {rho}: max relative error {err.max():.4f}"
    np.testing.assert_allclose(g.radiance, (1 + rho * g.irradiance) / np.pi, rtol=1e-12)


def test_gather_in_an_umbra_is_zero_and_beside_it_the_closed_form():
    # A black emitter (E = pi) [0,1]^2 at z = 1 facing down, a black blocker [0.2,0.8]^2 at
    # z = 0.5 facing down, a white floor [-1,2]^2 at z = 0. From the floor's centre the emitter
    # spans slopes up to 0.5, the blocker up to 0.6: it hides all of it (H = 0 exactly). From
    # (-0.9, 0.5) the rays to the emitter cross z = 0.5 at x <= 0.05: it hides none of it.
    emitter = quad([0, 0, 1], [0, 1, 0], [1, 0, 0])
    blocker = quad([0.2, 0.2, 0.5], [0, 0.6, 0], [0.6, 0, 0])
    floor = quad([-1, -1, 0], [3, 0, 0], [0, 3, 0])
    m = make_model([floor, blocker, emitter], reflectance=[[0.5] * 3, [0.0] * 3, [0.0] * 3],
                   emission=[[0.0] * 3, [0.0] * 3, [np.pi] * 3])
    solve(m, 1e-3, 0.01)
    pts = np.array([[0.5, 0.5, 0.0], [-0.9, 0.5, 0.0]])
    nrm = np.array([[0.0, 0.0, 1.0]] * 2)
    g = m.gather(pts, nrm, _engine.GatherOptions(rays=16))
    assert g.irradiance[0].max() == 0.0
    # Beside it: the emitter seen from (-0.9, 0.5): rectangles of the plane shifted by x.
    far = np.pi * (corner_form_factor(1.9, 0.5, 1.0) - corner_form_factor(0.9, 0.5, 1.0)) * 2
    np.testing.assert_allclose(g.irradiance[1], far, rtol=5e-3)


def test_gather_finds_an_umbra_that_the_links_estimate_missed():
    # A small black blocker [0.9, 1.1]^2 at z = 0.5 (facing down) under a black emitter
    # [0.75, 1.25]^2 at z = 2 (E = pi), over a white floor [-1, 3]^2, with elements too large to
    # split (min_area above a quarter of the floor): the floor is one element whose link to the
    # emitter was estimated from 8 point pairs, and the shadow covers about 1 % of it, so the
    # link's estimate sees no shadow at all. Rays from (1 + u, 1 + v, 0) to the emitter cross
    # z = 0.5 at 0.75 (u, v) + (1, 1) +- 0.0625: for |u|, |v| <= 0.05 the blocker hides all of
    # the emitter (H = 0 exactly), which only rays traced from the point itself can find.
    emitter = quad([0.75, 0.75, 2], [0, 0.5, 0], [0.5, 0, 0])
    blocker = quad([0.9, 0.9, 0.5], [0, 0.2, 0], [0.2, 0, 0])
    floor = quad([-1, -1, 0], [4, 0, 0], [0, 4, 0])
    m = make_model([floor, blocker, emitter], reflectance=[[0.5] * 3, [0.0] * 3, [0.0] * 3],
                   emission=[[0.0] * 3, [0.0] * 3, [np.pi] * 3])
    solve(m, 1e-2, 5.0, samples=8)
    assert len(patch_dict(m.patch_arrays())["area"]) == 3   # nothing split: one link reaches the floor
    umbra = np.array([[1.0, 1.0], [1.04, 0.96], [0.955, 1.045], [1.02, 1.0]])
    # Lit: from (1.5, 1.0) the rays cross z = 0.5 at x >= 1.3125, beside the blocker; the
    # emitter is then two a x 0.25 rectangles at height 2 from the point's foot (x from -0.75
    # to -0.25), differences of corner rectangles.
    # Penumbra: from (1.1, 1.0) the blocker hides the emitter's x < 1.1 (the crossing is at
    # 0.825 + 0.25 x_l) and every y (0.75 + 0.25 y_l stays within [0.9, 1.1]): the visible part
    # is x in [1.1, 1.25] beside the foot, two 0.15 x 0.25 corner rectangles.
    pts = np.c_[np.r_[umbra, [[1.5, 1.0], [1.1, 1.0]]], np.zeros(len(umbra) + 2)]
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    g = m.gather(np.ascontiguousarray(pts), np.ascontiguousarray(nrm), _engine.GatherOptions(rays=16))
    assert np.all(g.irradiance[:len(umbra)] == 0.0)
    lit = np.pi * 2 * (corner_form_factor(0.75, 0.25, 2.0) - corner_form_factor(0.25, 0.25, 2.0))
    np.testing.assert_allclose(g.irradiance[len(umbra)], lit, rtol=5e-3)
    half = np.pi * 2 * corner_form_factor(0.15, 0.25, 2.0)
    # The visible share by 16 stratified rays (4 columns of 0.125: the 0.15 covers one and a
    # fifth): within one ray's share of the emitter's light, 1/16.
    full = np.pi * 2 * (corner_form_factor(0.15, 0.25, 2.0) + corner_form_factor(0.35, 0.25, 2.0))
    assert abs(g.irradiance[-1][0] - half) <= full / 16


def test_gather_agrees_with_the_monte_carlo_reference_in_an_open_room():
    # An open box (no ceiling) lit by a square emitter above it: several bounces, occlusion by
    # the walls; the reference path-traces the same polygons independently of any links.
    faces = box_faces(omit=("z1",))
    emitter = quad([0.25, 0.25, 0.95], [0, 0.5, 0], [0.5, 0, 0])
    refl = [[0.7, 0.2, 0.2], [0.2, 0.7, 0.2], [0.6, 0.6, 0.6], [0.6, 0.6, 0.6], [0.7, 0.7, 0.7], [0.0] * 3]
    emis = [[0.0] * 3] * 5 + [[10.0] * 3]
    m = make_model(faces + [emitter], refl, emis)
    solve(m, 3e-5, 0.002)
    rng = np.random.default_rng(3)
    pts = np.c_[rng.uniform(0.1, 0.9, (8, 2)), np.zeros(8)]          # floor
    pts = np.r_[pts, np.c_[np.zeros(6), rng.uniform(0.1, 0.9, (6, 2))]]  # wall x = 0
    nrm = np.r_[np.tile([0.0, 0, 1], (8, 1)), np.tile([1.0, 0, 0], (6, 1))]
    pts, nrm = np.ascontiguousarray(pts), np.ascontiguousarray(nrm)
    g = m.gather(pts, nrm, _engine.GatherOptions(rays=16))
    ref = m.reference_at(pts, nrm, _engine.ReferenceOptions(paths=20000, min_bounces=3, seed=5), 1e-4)
    lum = np.array([0.2126, 0.7152, 0.0722])
    rel = np.abs(g.radiance @ lum / (ref.radiance @ lum) - 1)
    rel_se = (ref.standard_error @ lum) / (ref.radiance @ lum)
    assert np.all(rel <= 3 * rel_se + 0.03), (rel, rel_se)


def test_gather_is_deterministic_and_needs_a_hierarchical_solve():
    m = make_model(parallel_squares(1.0), reflectance=[[0.5] * 3, [0.0] * 3], emission=[[0.0] * 3, [np.pi] * 3])
    with pytest.raises(ValueError, match="hierarchical solve"):
        m.gather(np.zeros((1, 3)), np.array([[0.0, 0, 1]]))
    solve(m, 1e-3, 0.01)
    pts = np.ascontiguousarray(np.c_[np.random.default_rng(1).random((50, 2)), np.zeros(50)])
    nrm = np.ascontiguousarray(np.tile([0.0, 0, 1], (50, 1)))
    a = m.gather(pts, nrm, _engine.GatherOptions(rays=16))
    try:
        _engine.set_threads(1)
        b = m.gather(pts, nrm, _engine.GatherOptions(rays=16))
    finally:
        _engine.set_threads(0)
    assert np.array_equal(a.irradiance, b.irradiance) and a.irradiance.max() > 0


def test_gather_before_publishing_finds_each_points_own_leaf():
    """A bake's final-gather lightmaps gather before the leaves are published, finding a
    point's leaf through the hierarchy's faces (Hierarchy::leaf_at) instead of the published
    leaves' BVH. At points drawn inside leaves (quads and triangles, split several levels) it
    must return the leaf each was drawn in, and the very bits of the gather after publishing."""
    tri = [[0.2, 0.3, 0.2], [0.8, 0.3, 0.25], [0.4, 0.35, 0.8]]  # a slanted triangle facing up
    polys = box_faces() + [tri]
    n = len(polys)
    emission = [[0.0] * 3] * n
    emission[3] = [np.pi] * 3  # the +y wall (the ceiling) emits

    def solved():
        m = make_model(polys, 0.6, emission)
        m.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-4, min_area=2e-3, samples=4, seed=1, max_rounds=3),
                             _engine.SolveOptions(method="jacobi", tolerance=1e-8, max_iterations=10000))
        return m

    m, twin = solved(), solved()
    twin.use_leaves_as_patches()
    p = patch_dict(twin.patch_arrays())
    area = m.leaf_arrays().area
    np.testing.assert_array_equal(area, p["area"])  # the same leaves in the same order
    assert (p["nv"] == 3).sum() >= 16 and len(area) > 500  # triangles split too
    rng = np.random.default_rng(5)
    k = rng.integers(0, len(area), 3000)
    c = p["corners"][k]
    s, t = rng.uniform(0.01, 0.99, (2, len(k)))  # quads: bilinear (s, t) off the edges
    bilinear = (c[:, 0] * ((1 - s) * (1 - t))[:, None] + c[:, 1] * (s * (1 - t))[:, None]
                + c[:, 2] * (s * t)[:, None] + c[:, 3] * ((1 - s) * t)[:, None])
    u = np.sqrt(s)  # triangles: uniform barycentrics, drawn 2 % towards the centroid
    w = 0.98 * np.stack([1 - u, u * (1 - t), u * t], axis=1) + 0.02 / 3
    bary = (c[:, :3] * w[:, :, None]).sum(axis=1)
    quad_ = p["nv"][k] == 4
    nrm = np.ascontiguousarray(p["normal"][k])
    pts = np.ascontiguousarray(np.where(quad_[:, None], bilinear, bary) + 1e-7 * nrm)
    before = m.gather(pts, nrm)
    assert not m.leaves_are_patches and np.array_equal(before.patch, k)
    m.use_leaves_as_patches()
    after = m.gather(pts, nrm)
    assert np.array_equal(after.patch, k)
    assert np.array_equal(before.irradiance, after.irradiance) and before.irradiance.max() > 0


def test_flat_gather_matches_the_closed_form_and_the_hierarchical_gather():
    # The same one-bounce scene solved flat (4 x 4 patches a face): at points, the flat
    # gather is the closed form too, whatever the patch size.
    m = make_model(parallel_squares(1.0), reflectance=[[0.5] * 3, [0.0] * 3], emission=[[0.0] * 3, [np.pi] * 3],
                   max_area=1 / 16, max_edge=0.25)
    m.compute_links(_engine.FormFactorOptions(method="raycast", samples=16, seed=1))
    b = m.solve(_engine.SolveOptions(method="direct", tolerance=1e-12, max_iterations=1000)).radiosity
    xy = np.array([[0.5, 0.5], [0.1, 0.1], [0.83, 0.27]])
    pts = np.ascontiguousarray(np.c_[xy, np.zeros(len(xy))])
    nrm = np.ascontiguousarray(np.tile([0.0, 0.0, 1.0], (len(xy), 1)))
    g = m.gather_flat(pts, nrm, b, rays=16)
    expected = np.array([np.pi * point_to_square(x, y, 1.0) for x, y in xy])
    np.testing.assert_allclose(g.irradiance[:, 0], expected, rtol=2e-3)


@pytest.mark.parametrize("importance", [0.02, 0.1])
def test_importance_split_keeps_the_furnace(importance):
    # GatherOptions.importance: the weakest links (together at most `importance` of an
    # element's light) are taken at their mean over the receiver instead of at the point. In
    # the furnace (B = 2 everywhere) the gather at x is B times the sum of the links' form
    # factors, exact ones for the links evaluated and receiver means for the rest; so the error
    # at a point is B times the rest's sum of (mean F - F(x)), at most `importance` of H where
    # F(x) is below its mean, and it averages out over the surfaces (the means are what the
    # points average to). The split must evaluate fewer links' worth of error than its allowance.
    m = make_model(box_faces(), 0.5, 1.0)
    solve(m, 2e-5, 0.0155, samples=144)
    pts, nrm = box_points(200, seed=11)
    full = m.gather(pts, nrm, _engine.GatherOptions(rays=16)).irradiance[:, 0] * 0.5
    split = m.gather(pts, nrm, _engine.GatherOptions(rays=16, importance=importance)).irradiance[:, 0] * 0.5
    assert np.abs(full - 1).max() < 0.01
    err = split - 1
    assert np.abs(err).max() < importance + 0.01, f"worst {np.abs(err).max():.4f}"
    assert abs(err.mean()) < 0.2 * importance + 0.002, f"mean {err.mean():+.4f}"
    assert not np.array_equal(full, split)  # the split took some links at their mean
