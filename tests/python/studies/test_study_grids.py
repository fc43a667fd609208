"""Calculation grids: the EN 12464-1 spacing rule, the border band, floors made of several
polygons, frames, rooms from USD, measures (planar, vertical, cylindrical, semi-cylindrical)
against closed forms, and the CIE 171:2006 test case 5.2 through the CSV-grid plumbing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hirad.studies import (
    StudyError,
    build_grid,
    cells_along,
    en12464_dimension,
    en12464_spacing,
    evaluate_grids,
    resolve_room,
    study_from_dict,
)
from hirad.studies.grids import horizontal


def _grid(spec: dict, name="g", up_axis="Z", **kw):
    study = study_from_dict({"up_axis": up_axis, "grids": {name: spec}})
    return build_grid(name, study.grids[name], up_axis=up_axis, **kw)


# ------------------------------------------------------------------------------------
# EN 12464-1 spacing
# ------------------------------------------------------------------------------------

# p = 0.2 * 5^log10(d) = 0.2 * d^log10(5) (5^log10 d = 10^(log10 5 * log10 d) = d^log10 5)
LOG10_5 = 0.69897000433601880479


@pytest.mark.parametrize("d, p_expected, n_expected", [
    (1.0, 0.2, 5),               # 0.2 * 1
    (5.0, 0.2 * 5 ** LOG10_5, 9),  # 0.2 * 3.0824 = 0.61648 m; 5 / 0.61648 = 8.11 -> 9
    (10.0, 1.0, 10),             # 0.2 * 5
    (50.0, 0.2 * 50 ** LOG10_5, 17),  # 0.2 * 15.41 = 3.0824 m; 50 / 3.0824 = 16.2 -> 17
    (100.0, 5.0, 20),            # 0.2 * 25
])
def test_en12464_spacing_and_point_count(d, p_expected, n_expected):
    p = en12464_spacing(d)
    assert p == pytest.approx(p_expected, rel=1e-12)
    n = cells_along(d, p)
    assert n == n_expected
    assert d / n <= p  # the spacing never exceeds p
    assert d / (n - 1) > p  # and one cell fewer would


def test_en12464_spacing_published_values():
    # 0.2 * 5^0.699 = 0.6165 (the brief's form) and the 10 m cap: d = 1000 gives 0.2 * 125 = 25 -> 10
    assert en12464_spacing(5.0) == pytest.approx(0.2 * 5 ** 0.699, rel=1e-4)
    assert en12464_spacing(1000.0) == 10.0
    assert en12464_spacing(0.5) == pytest.approx(0.2 * 0.5 ** LOG10_5)
    with pytest.raises(StudyError, match="positive"):
        en12464_spacing(0.0)


def test_rounding_nearest_and_cell_aspect_ratio():
    room = [[0, 0], [5, 0], [5, 4], [0, 4]]
    # 5 x 4 m, no band: d = 5, p = 0.61648 m; ceil: 9 x 7 cells; nearest: round(8.11) x round(6.49) = 8 x 6
    g = _grid({"kind": "workplane", "polygon": room, "border": 0})
    assert (g.layout.nu, g.layout.nv) == (9, 7)
    g = _grid({"kind": "workplane", "polygon": room, "border": 0, "rounding": "nearest"})
    assert (g.layout.nu, g.layout.nv) == (8, 6) and g.rule["rounding"] == "nearest"
    # with ceil the cells stay within the standard's aspect ratio 0.5 .. 2 for areas of any shape
    for a, b in [(5, 4), (10, 1), (3, 2.9), (40, 3), (1, 0.3), (100, 49), (7, 3.4)]:
        g = _grid({"kind": "workplane", "polygon": [[0, 0], [a, 0], [a, b], [0, b]], "border": 0})
        du, dv = g.spacing
        assert 0.5 <= du / dv <= 2.0, (a, b, du, dv)
        assert max(du, dv) <= g.rule["p"]


def test_en12464_dimension_long_narrow_rule():
    assert en12464_dimension(10.0, 6.0) == 10.0  # the longer side
    assert en12464_dimension(6.0, 10.0) == 10.0
    assert en12464_dimension(10.0, 5.0) == 5.0  # ratio 2: the shorter side
    assert en12464_dimension(30.0, 2.0) == 2.0


# ------------------------------------------------------------------------------------
# work planes and the border band
# ------------------------------------------------------------------------------------


def test_rectangle_with_border_band_points_inside_reduced_rectangle_at_the_spacing():
    g = _grid({"kind": "workplane", "polygon": [[0, 0], [6, 0], [6, 4], [0, 4]]})
    # reduced rectangle [0.5, 5.5] x [0.5, 3.5]: 5 x 3 m, d = 5 (5 < 2 * 3), p = 0.61648 m,
    # cells ceil(5 / p) = 9 along x (0.5556 m) and ceil(3 / p) = 5 along y (0.6 m)
    assert g.rule["d"] == 5.0
    assert g.layout.nu == 9 and g.layout.nv == 5
    assert len(g.points) == 45
    xs = np.sort(np.unique(np.round(g.points[:, 0], 12)))
    ys = np.sort(np.unique(np.round(g.points[:, 1], 12)))
    np.testing.assert_allclose(xs, 0.5 + (np.arange(9) + 0.5) * 5 / 9, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ys, 0.5 + (np.arange(5) + 0.5) * 0.6, rtol=0, atol=1e-12)
    assert (g.points[:, 0] > 0.5).all() and (g.points[:, 0] < 5.5).all()
    assert (g.points[:, 1] > 0.5).all() and (g.points[:, 1] < 3.5).all()
    np.testing.assert_array_equal(g.points[:, 2], 0.8)  # the default 0.80 m work plane
    np.testing.assert_array_equal(g.normals, np.tile([0, 0, 1.0], (45, 1)))
    np.testing.assert_allclose(g.weights, (5 / 9) * 0.6, rtol=1e-14)
    assert g.area == pytest.approx(15.0, rel=1e-12)  # the reduced rectangle's area


def test_explicit_spacing_is_an_upper_bound():
    g = _grid({"kind": "workplane", "polygon": [[0, 0], [6, 0], [6, 4], [0, 4]], "spacing": 0.5, "border": 0.0})
    assert (g.layout.nu, g.layout.nv) == (12, 8)  # an exact fit: 6 / 0.5, 4 / 0.5
    g = _grid({"kind": "workplane", "polygon": [[0, 0], [6.1, 0], [6.1, 4], [0, 4]], "spacing": 0.5, "border": 0.0})
    assert g.layout.nu == 13 and g.spacing[0] == pytest.approx(6.1 / 13) and g.spacing[0] <= 0.5


def test_corridor_is_at_floor_level_and_3d_polygons_carry_the_floor():
    g = _grid({"kind": "corridor", "polygon": [[0, 0], [10, 0], [10, 2], [0, 2]], "border": 0.0})
    np.testing.assert_array_equal(g.points[:, 2], 0.0)
    # 10 x 2 m: ratio 5, so d = 2 m (the shorter side), p = 0.2 * 2^0.699 = 0.3249 m
    assert g.rule["d"] == 2.0
    assert g.layout.nv == math.ceil(2 / (0.2 * 2 ** LOG10_5))
    g = _grid({"kind": "workplane", "polygon": [[0, 0, 2.0], [4, 0, 2.0], [4, 4, 2.0], [0, 4, 2.0]]})
    np.testing.assert_allclose(g.points[:, 2], 2.8)
    with pytest.raises(StudyError, match="not horizontal"):
        _grid({"kind": "workplane", "polygon": [[0, 0, 0], [4, 0, 0], [4, 4, 0.5]]})


def test_floor_of_several_polygons_shares_its_inner_edges():
    one = _grid({"kind": "workplane", "polygon": [[0, 0], [6, 0], [6, 4], [0, 4]]})
    # the same floor as two triangles and as four tiles: the shared edges are not border
    tri = _grid({"kind": "workplane", "polygons": [[[0, 0], [6, 0], [6, 4]], [[0, 0], [6, 4], [0, 4]]]})
    tiles = _grid({"kind": "workplane", "polygons": [
        [[0, 0], [3, 0], [3, 2], [0, 2]], [[3, 0], [6, 0], [6, 2], [3, 2]],
        [[0, 2], [3, 2], [3, 4], [0, 4]], [[3, 2], [6, 2], [6, 4], [3, 4]]]})
    for g in (tri, tiles):
        assert len(g.points) == len(one.points)
        np.testing.assert_allclose(np.sort(g.points, axis=0), np.sort(one.points, axis=0), atol=1e-12)


def test_border_band_of_an_l_shaped_floor_keeps_points_half_a_metre_from_every_wall():
    poly = [[0, 0], [6, 0], [6, 2], [2, 2], [2, 5], [0, 5]]
    g = _grid({"kind": "workplane", "polygon": poly, "spacing": 0.1})
    x, y = g.points[:, 0], g.points[:, 1]
    # distance to the complement of the L: the outer walls, and the reflex corner's quadrant
    # x >= 2, y >= 2 (a point with x < 2 and y < 2 is sqrt((2-x)^2 + (2-y)^2) from it)
    inside_arm = (y < 2) | (x < 2)
    assert inside_arm.all()
    d_walls = np.minimum.reduce([x, y, np.where(y < 2, 6 - x, np.inf), 5 - y, np.where(x > 2, 2 - y, np.inf),
                                 np.where(y > 2, 2 - x, np.inf)])
    d_corner = np.where((x < 2) & (y < 2), np.hypot(2 - x, 2 - y), np.inf)
    assert (np.minimum(d_walls, d_corner) >= 0.5 - 1e-12).all()
    # and every cell centre of the full 0.1 m lattice that is that far is kept: count them
    nu, nv = g.layout.nu, g.layout.nv
    assert (nu, nv) == (50, 40)  # the box [0.5, 5.5] x [0.5, 4.5] at 0.1 m
    uu, vv = np.meshgrid(0.5 + (np.arange(nu) + 0.5) * 0.1, 0.5 + (np.arange(nv) + 0.5) * 0.1, indexing="ij")
    uu, vv = uu.ravel(), vv.ravel()
    ok = (vv < 1.5) | (uu < 1.5) | (((uu < 2) & (vv < 2)) & (np.hypot(2 - uu, 2 - vv) >= 0.5))
    ok &= ~((uu > 1.5) & (vv > 1.5) & ~((uu < 2) & (vv < 2)))
    assert len(g.points) == int(ok.sum())


def test_y_up_frame():
    e = horizontal([0.0, 90.0], "Y")
    np.testing.assert_allclose(e, [[1, 0, 0], [0, 0, -1]], atol=1e-15)
    g = _grid({"kind": "workplane", "polygon": [[0, 0], [2, 0], [2, 1], [0, 1]], "border": 0, "spacing": 1.0},
              up_axis="Y")
    np.testing.assert_allclose(np.sort(g.points, axis=0), [[0.5, 0.8, -0.5], [1.5, 0.8, -0.5]])
    np.testing.assert_array_equal(g.normals, [[0, 1.0, 0]] * 2)


def test_rotated_grid_axis():
    # a 4 x 2 m floor turned by 30 degrees, grid rows along it: every point at the cell centres
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    corners = [[0, 0], [4, 0], [4, 2], [0, 2]]
    poly = [[c * x - s * y, s * x + c * y] for x, y in corners]
    g = _grid({"kind": "workplane", "polygon": poly, "axis": 30.0, "spacing": 1.0, "border": 0.0})
    assert len(g.points) == 8
    local = np.stack([g.points[:, 0] * c + g.points[:, 1] * s, -g.points[:, 0] * s + g.points[:, 1] * c], 1)
    np.testing.assert_allclose(np.sort(local[:, 0]), np.repeat([0.5, 1.5, 2.5, 3.5], 2), atol=1e-12)


def test_rectangle_grid_wall():
    g = _grid({"kind": "rectangle", "corner": [0, 4, 0], "edge_u": [6, 0, 0], "edge_v": [0, 0, 3],
               "normal": [0, -2, 0], "spacing": 1.0, "offset": 0.01})
    assert len(g.points) == 18
    np.testing.assert_allclose(g.points[:, 1], 3.99)
    np.testing.assert_array_equal(g.normals, [[0, -1.0, 0]] * 18)
    np.testing.assert_allclose(sorted(set(np.round(g.points[:, 2], 12))), [0.5, 1.5, 2.5])


def test_room_from_usd_floor_faces():
    from pxr import Gf, Usd, UsdGeom

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)  # centimetres
    room = UsdGeom.Xform.Define(stage, "/Room")
    room.AddTranslateOp().Set(Gf.Vec3d(100, 0, 50))
    mesh = UsdGeom.Mesh.Define(stage, "/Room/Shell")
    # floor (two quads, up), ceiling (down), one wall (vertical), in cm
    pts = [(0, 0, 0), (300, 0, 0), (600, 0, 0), (600, 400, 0), (300, 400, 0), (0, 400, 0),
           (0, 0, 300), (600, 0, 300), (600, 400, 300), (0, 400, 300)]
    mesh.CreatePointsAttr(pts)
    mesh.CreateFaceVertexCountsAttr([4, 4, 4, 4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 4, 5, 1, 2, 3, 4, 6, 9, 8, 7, 0, 2, 7, 6])
    polys = resolve_room(stage, "/Room")
    assert len(polys) == 2
    g = _grid({"kind": "workplane", "room": "/Room"}, polygons=polys)
    ref = _grid({"kind": "workplane", "polygon": [[1, 0, 0.5], [7, 0, 0.5], [7, 4, 0.5], [1, 4, 0.5]]})
    np.testing.assert_allclose(np.sort(g.points, axis=0), np.sort(ref.points, axis=0), atol=1e-9)
    np.testing.assert_allclose(g.points[:, 2], 1.3)  # 50 cm floor + 0.80 m
    with pytest.raises(StudyError, match="not been resolved"):
        _grid({"kind": "workplane", "room": "/Room"})
    with pytest.raises(StudyError, match="no such prim"):
        resolve_room(stage, "/Nope")


# ------------------------------------------------------------------------------------
# measures against closed forms
# ------------------------------------------------------------------------------------


def beam(e_n: float, azimuth_deg: float, elevation_deg: float = 0.0):
    """A distant source: illuminance e_n on a surface normal to it, light arriving FROM the
    direction s (azimuth, elevation); E(n) = e_n max(0, n . s)."""
    a, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    s = np.array([math.cos(a) * math.cos(el), math.sin(a) * math.cos(el), math.sin(el)])
    return lambda p, n: e_n * np.maximum(0.0, n @ s)


def quadrature_bound(n: int) -> float:
    """Worst relative error of the N-azimuth mean of a clipped cosine max(0, cos phi): its
    Fourier series is 1/pi + cos(phi)/2 + sum over even m of 2 (-1)^(m/2+1) / (pi (m^2 - 1)) cos(m phi),
    and the uniform N-point rule aliases exactly the harmonics m that N divides, so the error
    relative to the mean 1/pi is at most sum 2/(m^2 - 1) over the even multiples m of N. With
    sum_k 1/(k^2 - x^2) = (1 - pi x cot(pi x)) / (2 x^2): 1 - (pi/2N) cot(pi/2N) for odd N
    (m = 2kN), 1 - (pi/N) cot(pi/N) for even N (m = kN)."""
    x = math.pi / (2 * n) if n % 2 else math.pi / n
    return 1.0 - x / math.tan(x)


def test_quadrature_bound_is_the_fourier_sum():
    for n in (7, 24, 25):
        ms = [m for m in range(n, 20000 * n, n) if m % 2 == 0]
        assert quadrature_bound(n) == pytest.approx(sum(2.0 / (m * m - 1) for m in ms), rel=1e-4)


def _point_grid(tmp_path, measure, pts=((0.0, 0.0, 0.0),)):
    f = tmp_path / "p.csv"
    f.write_text("".join(f"{x},{y},{z}\n" for x, y, z in pts))
    return {"kind": "points", "file": str(f), "measure": measure}


@pytest.mark.parametrize("azimuths", [25, 24, 7])
@pytest.mark.parametrize("source_az", [0.0, 3.6, 7.2, 33.0, 90.0, 200.0])
def test_cylindrical_illuminance_of_a_horizontal_beam_is_en_over_pi(tmp_path, azimuths, source_az):
    e_n = 1000.0
    spec = _point_grid(tmp_path, {"type": "cylindrical", "azimuths": azimuths})
    (r,) = evaluate_grids({"c": study_from_dict({"grids": {"c": spec}}).grids["c"]}, beam(e_n, source_az))
    exact = e_n / math.pi
    bound = quadrature_bound(azimuths)
    assert abs(r.values[0] - exact) <= bound * exact * (1 + 1e-9)
    if azimuths == 25:
        assert bound < 0.0014  # the documented 0.13 %
        if source_az == 90.0:  # every aliased harmonic adds up with one sign: the bound is attained
            assert r.values[0] == pytest.approx(exact * (1 - bound), rel=1e-9)


def test_cylindrical_illuminance_at_an_elevation(tmp_path):
    spec = _point_grid(tmp_path, {"type": "cylindrical", "azimuths": 101})
    (r,) = evaluate_grids({"c": study_from_dict({"grids": {"c": spec}}).grids["c"]}, beam(500.0, 10.0, 40.0))
    assert r.values[0] == pytest.approx(500.0 * math.cos(math.radians(40)) / math.pi, rel=1e-4)
    np.testing.assert_array_equal(r.grid.normals, [[0, 0, 1.0]])  # a cylinder's axis


@pytest.mark.parametrize("delta, factor", [(0.0, 2.0), (90.0, 1.0), (-90.0, 1.0), (180.0, 0.0),
                                           (60.0, 1.5), (135.0, 1 - math.sqrt(0.5))])
def test_semi_cylindrical_illuminance(tmp_path, delta, factor):
    # E_sc = E_n cos(alpha) (1 + cos delta) / pi; facing the source 2 E_n / pi
    facing = 30.0
    spec = _point_grid(tmp_path, {"type": "semi_cylindrical", "azimuth": facing})
    (r,) = evaluate_grids({"s": study_from_dict({"grids": {"s": spec}}).grids["s"]}, beam(1000.0, facing + delta))
    exact_z = 1000.0 / math.pi
    assert abs(r.values[0] - factor * 1000.0 / math.pi) <= quadrature_bound(25) * exact_z * (1 + 1e-9)
    assert r.values[0] >= 0.0
    np.testing.assert_allclose(r.grid.normals[0], horizontal(facing), atol=1e-15)


def test_vertical_illuminance(tmp_path):
    spec = _point_grid(tmp_path, {"type": "vertical", "azimuth": 90.0})
    (r,) = evaluate_grids({"v": study_from_dict({"grids": {"v": spec}}).grids["v"]}, beam(800.0, 150.0, 20.0))
    # normal (0, 1, 0); s = (cos150 cos20, sin150 cos20, sin20): n.s = 0.5 cos 20
    assert r.values[0] == pytest.approx(800.0 * 0.5 * math.cos(math.radians(20)), rel=1e-12)


# ------------------------------------------------------------------------------------
# CIE 171:2006 test case 5.2 through a CSV grid
# ------------------------------------------------------------------------------------

# (x, y) in m under the source, published illuminance (lx)
CIE_5_2 = {"A": (0.0, 0.0, 111.11), "B": (0.5, 0.0, 105.21), "C": (1.0, 0.0, 90.02), "D": (1.5, 0.0, 71.11),
           "E": (0.5, 0.5, 99.73), "F": (1.0, 0.5, 85.64), "G": (1.5, 0.5, 68.06), "H": (1.0, 1.0, 74.36),
           "I": (1.5, 1.0, 59.98), "J": (1.5, 1.5, 49.39)}


def point_source_evaluator(source, intensity):
    """Illuminance from a point source of intensity(direction) cd: E = I cos(incidence) / r^2."""
    source = np.asarray(source, dtype=np.float64)

    def evaluate(points, normals):
        v = source - points
        r = np.linalg.norm(v, axis=1)
        u = v / r[:, None]  # towards the source
        return intensity(-u) * np.maximum(0.0, np.sum(normals * u, axis=1)) / r ** 2

    return evaluate


def test_cie171_case_5_2_point_source_through_a_csv_grid(tmp_path):
    h = 3.0
    f = tmp_path / "cie52.csv"
    f.write_text("x,y,z,nx,ny,nz\n# CIE 171:2006 5.2, points A..J\n" +
                 "".join(f"{x},{y},0,0,0,1\n" for x, y, _ in CIE_5_2.values()))
    study = study_from_dict({"grids": {"cie52": {"kind": "points", "file": "cie52.csv"}}})
    lambertian_down = lambda d: 1000.0 * np.maximum(0.0, -d[:, 2])  # I = 1000 cos(theta) cd
    (r,) = evaluate_grids(study, point_source_evaluator((0.0, 0.0, h), lambertian_down), base_dir=tmp_path)
    assert r.grid.source == str(tmp_path / "cie52.csv")
    for (name, (x, y, published)), got in zip(CIE_5_2.items(), r.values):
        assert got == pytest.approx(published, rel=0.01), name
        assert got == pytest.approx(1000.0 * h * h / (x * x + y * y + h * h) ** 2, rel=1e-12), name
    assert r.stats.emax == pytest.approx(111.11, rel=1e-4) and r.stats.emin == pytest.approx(49.39, rel=0.01)
