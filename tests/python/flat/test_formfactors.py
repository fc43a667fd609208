"""Form factors against closed forms and conservation laws.

Oracles: Howell's catalogue of configuration factors (C-11 parallel rectangles, C-14
perpendicular rectangles with a common edge, B-3 differential element to a parallel
rectangle), the same differential cases derived by Lambert's contour integral, Gauss-Legendre
quadrature of cos(t1) cos(t2) / (pi r^2), reciprocity A_i F_ij = A_j F_ji and the
enclosure rule sum_j F_ij = 1.
"""

from __future__ import annotations

from math import atan, pi, sqrt

import numpy as np
import pytest

pytest.importorskip("hirad._engine")

from conftest import BIG, _engine, box_faces, make_model, parallel_squares, perpendicular_squares, quad

F_PARALLEL_UNIT = 0.199825   # Howell C-11, unit squares at distance 1
F_PERPENDICULAR_UNIT = 0.20004  # Howell C-14, unit squares with a common edge


# --------------------------------------------------------------------------------------
# closed forms
# --------------------------------------------------------------------------------------


def test_parallel_rectangles_closed_form_matches_catalogue():
    ff = _engine.parallel_rectangles_form_factor
    assert ff(1, 1, 1) == pytest.approx(F_PARALLEL_UNIT, abs=1e-5)
    assert ff(1, 1, 0.5) == pytest.approx(0.415253, abs=1e-5)
    # Limits: far apart -> A / (pi c^2); touching -> 1.
    assert ff(1, 1, 100) == pytest.approx(1 / (pi * 100**2), rel=1e-3)
    assert ff(1, 1, 1e-4) == pytest.approx(1.0, abs=1e-3)
    # Symmetric in the two sides.
    assert ff(1, 3, 0.7) == pytest.approx(ff(3, 1, 0.7), rel=1e-12)


def test_perpendicular_rectangles_closed_form_matches_catalogue():
    # Arguments (l, h, w) as in Howell C-14: l is the COMMON edge, w the width of the
    # source, h the height of the receiver (H = h/l, W = w/l).
    ff = _engine.perpendicular_rectangles_form_factor
    assert ff(1, 1, 1) == pytest.approx(F_PERPENDICULAR_UNIT, abs=1e-5)
    assert ff(1, 2, 1) == pytest.approx(0.232853, abs=1e-5)
    assert ff(2, 1, 1) == pytest.approx(0.240636, abs=1e-5)
    # Reciprocity between the two rectangles: (w l) F(l, h, w) = (h l) F(l, w, h).
    for l, h, w in [(1, 2, 1), (2, 1, 3), (0.5, 1.5, 0.7)]:
        assert w * l * ff(l, h, w) == pytest.approx(h * l * ff(l, w, h), rel=1e-10)
    # A very long common edge tends to the 2D value by crossed strings: (1 + 1 - sqrt 2) / 2.
    assert ff(1e4, 1, 1) == pytest.approx((2 - sqrt(2)) / 2, rel=1e-3)


# --------------------------------------------------------------------------------------
# differential element to polygon (Lambert's contour integral)
# --------------------------------------------------------------------------------------


def corner_parallel(a: float, b: float, c: float) -> float:
    """Element at distance c below a corner of a parallel a x b rectangle (Howell B-3)."""
    A, B = a / c, b / c
    return (A / sqrt(1 + A * A) * atan(B / sqrt(1 + A * A)) + B / sqrt(1 + B * B) * atan(A / sqrt(1 + B * B))) / (
        2 * pi)


def perpendicular_from_edge_line(b: float, d: float, h: float) -> float:
    """Element at the origin, normal +z, to the rectangle x = d, 0 <= y <= b, 0 <= z <= h.
    Lambert's contour integral: only the two edges parallel to y contribute, the one at
    z = 0 with angle atan(b/d) and normal component 1, the one at z = h with angle
    atan(b / sqrt(d^2 + h^2)) and normal component -d / sqrt(d^2 + h^2)."""
    r = sqrt(d * d + h * h)
    return (atan(b / d) - d / r * atan(b / r)) / (2 * pi)


def quadrature_ff(x, n, origin, u, v, order: int = 48) -> float:
    """Gauss-Legendre quadrature of cos(t1) cos(t2) / (pi r^2) over the parallelogram
    origin + s u + t v (front side along u x v), from the point x with normal n."""
    g, w = np.polynomial.legendre.leggauss(order)
    s = 0.5 * (g + 1)
    ws = 0.5 * w
    origin, u, v, x, n = (np.asarray(a, dtype=np.float64) for a in (origin, u, v, x, n))
    normal = np.cross(u, v)
    area = np.linalg.norm(normal)
    normal /= area
    p = origin + s[:, None, None] * u + s[None, :, None] * v  # (order, order, 3)
    r = p - x
    r2 = np.einsum("ijk,ijk->ij", r, r)
    cos1 = np.clip(r @ n, 0, None) / np.sqrt(r2)
    cos2 = np.clip(-(r @ normal), 0, None) / np.sqrt(r2)
    return float(np.einsum("i,j,ij->", ws, ws, cos1 * cos2 / (pi * r2)) * area)


def rect_above(a: float, b: float, c: float, x0: float = 0.0, y0: float = 0.0) -> np.ndarray:
    """[x0, x0+a] x [y0, y0+b] at height c, facing down."""
    return quad([x0, y0, c], [0, b, 0], [a, 0, 0])


UP = [0.0, 0.0, 1.0]
ORIGIN = [0.0, 0.0, 0.0]


@pytest.mark.parametrize("a,b,c", [(1, 1, 1), (2, 0.5, 1), (0.3, 1.7, 0.25), (5, 5, 0.1)])
def test_point_below_rectangle_corner(a, b, c):
    got = _engine.point_polygon_form_factor(ORIGIN, UP, rect_above(a, b, c))
    assert got == pytest.approx(corner_parallel(a, b, c), abs=1e-9)


def test_corner_formula_agrees_with_quadrature():
    # Guards the transcription of the catalogue formula used as the oracle above.
    for a, b, c in [(1, 1, 1), (2, 0.5, 1.5)]:
        q = quadrature_ff(ORIGIN, UP, [0, 0, c], [0, b, 0], [a, 0, 0], order=64)
        assert q == pytest.approx(corner_parallel(a, b, c), abs=1e-9)


def test_point_under_rectangle_centre_is_four_corners():
    a, b, c = 1.0, 0.6, 0.8
    got = _engine.point_polygon_form_factor([a / 2, b / 2, 0], UP, rect_above(a, b, c))
    assert got == pytest.approx(4 * corner_parallel(a / 2, b / 2, c), abs=1e-9)
    # Tilting the receiver's normal moves the value; the oracle must notice the normal.
    tilted = _engine.point_polygon_form_factor([a / 2, b / 2, 0], [0.3, 0, 1], rect_above(a, b, c))
    assert abs(tilted - got) > 1e-3


def test_triangle_halves_sum_to_rectangle():
    # Additivity of the contour integral: the two triangles of a rectangle (both facing down).
    a, b, c = 1.3, 0.9, 0.7
    p = rect_above(a, b, c)
    t1, t2 = p[[0, 1, 2]], p[[0, 2, 3]]
    f = [_engine.point_polygon_form_factor([0.2, 0.1, 0], UP, t) for t in (p, t1, t2)]
    assert f[1] > 0 and f[2] > 0
    assert f[1] + f[2] == pytest.approx(f[0], abs=1e-12)


def test_back_side_and_below_horizon_give_zero():
    p = rect_above(1, 1, 1)
    # The receiver facing away: the rectangle is entirely below its tangent plane.
    assert _engine.point_polygon_form_factor(ORIGIN, [0, 0, -1], p) == 0.0
    # The emitter facing away (winding reversed): surfaces emit from their front only.
    assert _engine.point_polygon_form_factor(ORIGIN, UP, p[::-1].copy()) == 0.0


@pytest.mark.parametrize("b,d,h,below", [(1, 1, 1, 0.5), (2, 0.5, 1, 1.0), (0.7, 1.2, 0.4, 3.0)])
def test_polygon_crossing_the_tangent_plane_is_clipped(b, d, h, below):
    """A rectangle perpendicular to the receiver, straddling its tangent plane: the part
    below (z < 0) contributes nothing, so the value is the closed form for 0 <= z <= h."""
    expected = perpendicular_from_edge_line(b, d, h)
    straddling = quad([d, 0, -below], [0, 0, h + below], [0, b, 0])  # facing -x, towards the origin
    got = _engine.point_polygon_form_factor(ORIGIN, UP, straddling)
    assert got == pytest.approx(expected, abs=1e-9)
    # And the closed form itself against quadrature of the unclipped upper part.
    assert quadrature_ff(ORIGIN, UP, [d, 0, 0], [0, 0, h], [0, b, 0], order=64) == pytest.approx(expected, abs=1e-9)
    # Only the part below: nothing.
    assert _engine.point_polygon_form_factor(ORIGIN, UP, quad([d, 0, -below], [0, 0, below], [0, b, 0])) == 0.0


def test_clipping_a_corner_by_splitting():
    """A quad with one corner below the tangent plane (clipped to a pentagon) equals the sum
    of the quad and triangle the part above splits into, computed without clipping."""
    # Receiver at the origin facing +z; a vertical quad in the plane x = 1 from z = -0.5 at
    # one corner to z > 0 elsewhere (a parallelogram tilted in y-z), facing -x.
    p0, p1, p2, p3 = (np.array(v, dtype=float) for v in ([1, 0, -0.5], [1, 0, 1], [1, 1, 1.2], [1, 1, 0.3]))
    poly = np.array([p0, p1, p2, p3])
    assert np.dot(np.cross(p1 - p0, p2 - p0), [1, 0, 0]) < 0  # faces the origin
    full = _engine.point_polygon_form_factor(ORIGIN, UP, poly)
    # Crossings of z = 0 on the edges p0-p1 and p3-p0.
    q01 = p0 + (p1 - p0) * (0.5 / 1.5)
    q30 = p3 + (p0 - p3) * (0.3 / 0.8)
    quad_part = np.array([q01, p1, p2, p3])
    tri_part = np.array([q01, p3, q30])
    parts = sum(_engine.point_polygon_form_factor(ORIGIN, UP, x) for x in (quad_part, tri_part))
    assert full > 0
    assert full == pytest.approx(parts, abs=1e-12)


# --------------------------------------------------------------------------------------
# patch to patch: ray casting and hemicube against the closed forms
# --------------------------------------------------------------------------------------


def one_patch_each(polys):
    m = make_model(polys, max_area=BIG, max_edge=BIG)
    assert m.num_patches == len(polys)
    return m


PAIRS = {
    "parallel": (parallel_squares, lambda: _engine.parallel_rectangles_form_factor(1, 1, 1)),
    "perpendicular": (perpendicular_squares, lambda: _engine.perpendicular_rectangles_form_factor(1, 1, 1)),
}


@pytest.mark.parametrize("pair", PAIRS)
def test_raycast_unit_squares(pair):
    build, closed = PAIRS[pair]
    m = one_patch_each(build())
    exact = closed()
    for samples in (256, 1024):
        for seed in (1, 2):
            assert m.form_factor(0, 1, samples, seed) == pytest.approx(exact, rel=0.01)
            assert m.form_factor(1, 0, samples, seed) == pytest.approx(exact, rel=0.01)
    # Through the stored links: H_0 with B = 1 on patch 1 only is F_01.
    m.compute_links(_engine.FormFactorOptions(method="raycast", samples=1024, seed=1))
    b = np.zeros((2, 3))
    b[1] = 1.0
    h = m.transport(b, _engine.FormFactorOptions(samples=1024, seed=1)).irradiance
    assert h[0] == pytest.approx([exact] * 3, rel=0.01)
    assert h[1] == pytest.approx([0.0] * 3, abs=0)


@pytest.mark.parametrize("pair", PAIRS)
def test_hemicube_unit_squares(pair):
    build, closed = PAIRS[pair]
    m = one_patch_each(build())
    # 64 eye points per patch (an 8 x 8 midpoint rule over the source); with 16 points the
    # midpoint rule alone is 0.96 % high on the parallel pair.
    assert m.hemicube_row(0, 256, 64)[1] == pytest.approx(closed(), rel=0.01)
    assert m.hemicube_row(1, 256, 64)[0] == pytest.approx(closed(), rel=0.01)


def test_hemicube_single_eye_matches_point_form_factor():
    # One eye point at the centre of the lower square: the hemicube's own discretisation
    # against the exact differential form factor, 4 corners of a 0.5 x 0.5 rectangle.
    m = one_patch_each(parallel_squares())
    exact = 4 * corner_parallel(0.5, 0.5, 1.0)
    for res in (64, 256):
        assert m.hemicube_row(0, res, 1)[1] == pytest.approx(exact, rel=2e-3)


def test_subdivided_parallel_squares():
    """Each square as 4 x 4 patches: the area-weighted mean over the source patches of
    F(patch -> whole target square) is F between the squares."""
    m = make_model(parallel_squares(), max_area=BIG, max_edge=0.25)
    pa = m.patch_arrays()
    assert m.num_patches == 32
    target = pa.centroid[:, 2] > 0.5
    source = ~target
    area = pa.area
    b = np.zeros((m.num_patches, 3))
    b[target] = 1.0
    exact = _engine.parallel_rectangles_form_factor(1, 1, 1)
    for method in ("raycast", "hemicube"):
        m.compute_links(_engine.FormFactorOptions(method=method, samples=16, hemicube_resolution=128,
                                                  hemicube_points=16, seed=3))
        h = m.transport(b, _engine.FormFactorOptions(samples=16, seed=3)).irradiance[:, 0]
        mean = np.sum(h[source] * area[source]) / area[source].sum()
        assert mean == pytest.approx(exact, rel=0.01), method
        # By symmetry every source patch sees the target from its own position: the corner
        # patches see less than the central ones.
        assert h[source].min() < 0.9 * h[source].max()


# --------------------------------------------------------------------------------------
# enclosures and reciprocity
# --------------------------------------------------------------------------------------


BOXES = {"cube 3x3 per face": ((1, 1, 1), 1 / 3, 54), "box 1x2x0.5": ((1, 2, 0.5), 0.25, 112)}


@pytest.mark.parametrize("box", BOXES)
@pytest.mark.parametrize("method", ["raycast", "hemicube"])
def test_row_sums_in_closed_box(box, method):
    dims, edge, count = BOXES[box]
    m = make_model(box_faces(*dims), max_area=BIG, max_edge=edge)
    n = m.num_patches
    assert n == count
    m.compute_links(_engine.FormFactorOptions(method=method, samples=256, hemicube_resolution=128,
                                              hemicube_points=16, seed=1))
    tr = m.transport(np.ones((n, 3)), _engine.FormFactorOptions(samples=256, seed=1))
    rows = tr.irradiance[:, 0]
    np.testing.assert_allclose(rows, 1.0, rtol=0, atol=0.01)
    total_area = m.patch_arrays().area.sum()
    assert tr.escaped.sum() <= 0.01 * 3 * total_area
    if method == "hemicube":
        # Each raw hemicube row (not yet symmetrised) covers the whole hemisphere.
        for i in range(0, n, 5):
            assert m.hemicube_row(i, 128, 4).sum() == pytest.approx(1.0, abs=1e-3)


def test_row_sums_drop_below_one_in_open_box():
    # The same cube without its top: the enclosure rule must notice the missing face.
    m = make_model(box_faces(omit=("z1",)), max_area=BIG, max_edge=1 / 3)
    n = m.num_patches
    m.compute_links(_engine.FormFactorOptions(method="raycast", samples=256, seed=1))
    tr = m.transport(np.ones((n, 3)), _engine.FormFactorOptions(samples=256, seed=1))
    pa = m.patch_arrays()
    floor = pa.normal[:, 2] > 0.5
    rows = tr.irradiance[:, 0]
    # Each floor patch sees the missing unit square at distance 1 with F ~ 0.2 (0.12 to 0.28
    # over the 3 x 3 patches), so its row sum is about 0.8.
    assert np.all(rows[floor] < 0.9) and np.all(rows[floor] > 0.7)
    assert tr.escaped.sum() > 0.1


def test_reciprocity_unequal_patches():
    # 1 x 1 at z = 0 facing up; 2 x 1 at z = 0.7 facing down, offset in x and y.
    polys = [quad([0, 0, 0], [1, 0, 0], [0, 1, 0]), quad([0.5, 0.3, 0.7], [0, 1, 0], [2, 0, 0])]
    m = one_patch_each(polys)
    a = m.patch_arrays().area
    assert a == pytest.approx([1.0, 2.0])
    f01, f10 = m.form_factor(0, 1, 1024, 5), m.form_factor(1, 0, 1024, 5)
    assert f01 > 0.1 and f10 > 0.05
    assert a[0] * f01 == pytest.approx(a[1] * f10, rel=0.02)
    h01, h10 = m.hemicube_row(0, 256, 64)[1], m.hemicube_row(1, 256, 64)[0]
    assert a[0] * h01 == pytest.approx(a[1] * h10, rel=0.02)
    # The two methods agree on each direction too.
    assert h01 == pytest.approx(f01, rel=0.02)
    assert h10 == pytest.approx(f10, rel=0.02)
    # The stored coupling is symmetric by construction and close to both estimates.
    m.compute_links(_engine.FormFactorOptions(method="raycast", samples=1024, seed=5))
    b = np.zeros((2, 3))
    b[1] = 1.0
    g01 = m.transport(b, _engine.FormFactorOptions(samples=1024, seed=5)).irradiance[0, 0] * a[0]
    assert g01 == pytest.approx(a[0] * f01, rel=0.02)
