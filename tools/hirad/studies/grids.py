"""Calculation grids: the points of a grid spec, and every measure reduced to planar sensors.

Spacing (EN 12464-1:2011, "grid system")
----------------------------------------
The maximum grid size is ``p = 0.2 x 5^log10(d)`` metres (equivalently 0.2 d^0.699), and
p <= 10 m, where d is the longer dimension of the calculation area in metres -- but the shorter
one when the longer is at least twice the shorter (the standard's rule for long, narrow areas).
The spacing must not EXCEED p: each side L of the area gets ``n = ceil(L / p)`` cells (at least
1; the 2011 wording is "the nearest whole number greater than d/p") and the actual spacing is
``L / n <= p``; the two sides are counted separately with the same p (cells need not be
square). ``ceil`` is taken with a relative tolerance of 1e-9 so that an exact fit (d = 10 m:
p = 1 m, 10 cells) is not pushed to one more cell by rounding. With ceil every side at least p
long gets cells in (p/2, p], so the cells' length-to-width ratio stays within the standard's
0.5 to 2. Some tools read the 2021 edition as rounding to the nearest whole number instead,
which lets the spacing exceed p a little: ``rounding: nearest`` does that (n = round(L / p),
at least 1; not checked against the 2021 text). An explicit ``spacing: s`` is always an upper
bound: n = ceil(L / s), spacing L / n <= s. Points are at the CENTRES (centroids) of the cells,
as the standard places them, so the outermost points are half a spacing inside the evaluation
area.

Evaluation area of a work plane
-------------------------------
The floor polygon(s) less the border band: a point is kept when it lies inside the union of
the polygons (crossing parity over the union's boundary edges: an edge shared by two of the
polygons, as between the faces of a floor mesh, is not boundary; polygons must not overlap) and
is at least ``border`` metres from every boundary edge. The cells are laid over the bounding
box of the polygons (in the grid's axes, turned by ``axis`` degrees) shrunk by ``border`` on
every side, and d for the spacing rule is the longer side of that box: for a rectangle
(axis-aligned in the grid's axes) this is exactly the rectangle less its band, and every cell
centre is kept. Each kept point carries its cell's area as weight.

Measures reduced to planar illuminances
----------------------------------------
An evaluator needs only E(points, normals), the illuminance on a small plane at a point facing
a normal (lux). Each grid point becomes one or more SENSORS (point, normal, weight) and the
point's value is the weighted sum of its sensors' illuminances:

* planar: one sensor, the grid's normal (up for a work plane), weight 1.
* vertical: one sensor facing the horizontal direction ``azimuth``, weight 1.
* cylindrical (the International Lighting Vocabulary's "cylindrical illuminance at a point",
  CIE S 017, formerly CIE 17.4: the flux on the curved surface of a very small vertical cylinder
  divided by that surface's area; EN 12464-1's "mean cylindrical illuminance" is its mean over
  an area, i.e. Em of a cylindrical grid). The element of the cylinder facing azimuth phi receives the vertical
  illuminance E_v(phi), so ``E_z = (1 / 2 pi) integral_0^2pi E_v(phi) dphi``; in terms of the
  luminance L arriving from direction omega at angle theta from the vertical this is
  ``E_z = (1/pi) integral L sin(theta) domega`` (the mean of max(0, cos) over a circle is 1/pi).
  Evaluated as the mean of N vertical illuminances at phi_k = 2 pi k / N, weights 1/N. The
  uniform rule integrates every Fourier harmonic of E_v(phi) exactly except multiples of N;
  E_v of one collimated beam is a clipped cosine whose only odd harmonic is the first (the even
  ones are 2 (-1)^(m/2+1) / (pi (m^2 - 1))), so for odd N the relative error is at most
  sum_k 2/((2kN)^2 - 1) = 1 - (pi/2N) cot(pi/2N) (about 0.82/N^2: 0.132 % for the default
  N = 25, attained for a beam from azimuth 90 deg), for even N at most
  sum_k 2/((kN)^2 - 1) = 1 - (pi/N) cot(pi/N) (about 3.3/N^2). Smoother (diffuse) light does
  better.
  For a horizontal beam of normal illuminance E_n: E_z = E_n/pi; at elevation alpha,
  E_n cos(alpha)/pi.
* semi-cylindrical (the vocabulary's "semi-cylindrical illuminance at a point", used by the
  outdoor and sports lighting standards EN 12464-2 and EN 12193: the flux on the curved surface
  of a very small vertical HALF-cylinder facing azimuth phi0, divided by that surface's area):
  ``E_sc = (1/pi) integral_{phi0-pi/2}^{phi0+pi/2} E_v(phi) dphi``. For a beam from azimuth
  phi0 + delta at elevation alpha this is E_n cos(alpha) (1 + cos delta) / pi (the published
  cos-weighted form). Since cos(alpha) cos(delta) = omega . h0 (h0 the horizontal unit vector
  facing phi0) is linear in the direction, the half-cylinder splits EXACTLY into the full
  cylinder plus the horizontal vector illuminance:
  ``E_sc = E_z + (E_v(phi0) - E_v(phi0 + pi)) / pi``.
  Sensors: the N cylinder sensors (weights 1/N) and two planar ones facing phi0 (+1/pi) and
  phi0 + pi (-1/pi); only the cylinder part carries quadrature error. Facing a horizontal beam
  E_sc = 2 E_n/pi, side-on E_n/pi, facing away 0. A sum below 0 (quadrature error only) is
  reported as 0.

Frames: see :mod:`hirad.studies.spec` (e1, e2, up; azimuth counter-clockwise from e1 seen from
above).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from .spec import (
    MAX_GRID_POINTS,
    MAX_SENSORS,
    CorridorGrid,
    GridSpec,
    Measure,
    PointsGrid,
    RectangleGrid,
    StudyError,
    WorkplaneGrid,
)

_CEIL_TOLERANCE = 1e-9
_KEY_DIGITS = 9  # shared polygon edges are matched on corners rounded to 1 nm


# --------------------------------------------------------------------------------------
# the spacing rule
# --------------------------------------------------------------------------------------


def en12464_spacing(d: float) -> float:
    """EN 12464-1 maximum grid spacing p = 0.2 x 5^log10(d) metres, capped at 10 m; d > 0 m."""
    if not (isinstance(d, (int, float)) and math.isfinite(d) and d > 0):
        raise StudyError(f"EN 12464-1 spacing: the area's dimension d = {d!r} m must be a positive length")
    return min(0.2 * 5.0 ** math.log10(d), 10.0)


def en12464_dimension(side_a: float, side_b: float) -> float:
    """The d of the spacing rule for an area of sides a and b: the longer side, or the shorter
    one when the longer is at least twice the shorter."""
    longer, shorter = max(side_a, side_b), min(side_a, side_b)
    return shorter if longer >= 2.0 * shorter and shorter > 0 else longer


def cells_along(length: float, spacing: float) -> int:
    """Number of cells n = ceil(length / spacing) (at least 1), so length / n <= spacing."""
    if not (length > 0 and spacing > 0):
        raise StudyError(f"cells along {length!r} m at spacing {spacing!r} m: both must be positive")
    return max(1, math.ceil(length / spacing * (1.0 - _CEIL_TOLERANCE)))


# --------------------------------------------------------------------------------------
# frames
# --------------------------------------------------------------------------------------


def frame(up_axis: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(e1, e2, up) world unit vectors for the scene's up axis ("Z" or "Y"), right-handed."""
    if up_axis == "Z":
        return np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])
    if up_axis == "Y":
        return np.array([1.0, 0, 0]), np.array([0, 0, -1.0]), np.array([0, 1.0, 0])
    raise StudyError(f"up_axis {up_axis!r}: only 'Z' or 'Y'")


def horizontal(azimuth_deg, up_axis: str = "Z") -> np.ndarray:
    """Unit horizontal direction(s) at azimuth (degrees, counter-clockwise from e1 seen from above)."""
    e1, e2, _ = frame(up_axis)
    a = np.radians(np.asarray(azimuth_deg, dtype=np.float64))
    return np.cos(a)[..., None] * e1 + np.sin(a)[..., None] * e2


# --------------------------------------------------------------------------------------
# the grid
# --------------------------------------------------------------------------------------


@dataclass
class Layout:
    """A regular, cell-centred grid in a plane (for pictures): local coordinates (u, v) in
    metres, world = origin + u axis_u + v axis_v. Point k is cell index[k] = (i, j), centre
    (u0 + i du, v0 + j dv)."""

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    nu: int
    nv: int
    du: float
    dv: float
    u0: float
    v0: float
    index: np.ndarray
    outlines: list = field(default_factory=list)  # (K, 2) local polygons: the area's boundary
    evaluation_box: tuple = ()  # (umin, umax, vmin, vmax) of the cells

    def uv(self) -> tuple[np.ndarray, np.ndarray]:
        return self.u0 + self.index[:, 0] * self.du, self.v0 + self.index[:, 1] * self.dv


@dataclass
class Grid:
    """The points of one named grid and their sensors.

    points (M, 3) m, normals (M, 3) (the measure's own direction: the plane's normal, the
    vertical plane's or semi-cylinder's facing, up for a cylinder), weights (M,) (cell areas in
    m^2 for regular grids, 1 for points from a file: Em is the weighted mean). Sensors: points,
    normals and weights, owner[k] the grid point sensor k belongs to.
    """

    name: str
    kind: str
    measure: Measure
    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    sensor_points: np.ndarray
    sensor_normals: np.ndarray
    sensor_weights: np.ndarray
    sensor_owner: np.ndarray
    layout: Optional[Layout] = None
    area: Optional[float] = None  # m^2 (sum of the kept cells), None for file points
    spacing: Optional[tuple[float, float]] = None  # actual (du, dv), metres
    rule: Optional[dict] = None  # {"d": m, "p": m} when the EN 12464-1 rule set the spacing
    source: Optional[str] = None  # the CSV file of a points grid

    def combine(self, sensor_values) -> np.ndarray:
        """The grid points' values from their sensors' illuminances (lux)."""
        e = np.asarray(sensor_values, dtype=np.float64)
        out = np.bincount(self.sensor_owner, weights=self.sensor_weights * e, minlength=len(self.points))
        return np.maximum(out, 0.0) if self.measure.type == "semi_cylindrical" else out


def _sensors(name: str, measure: Measure, points: np.ndarray, normals: np.ndarray, up_axis: str):
    """(point normals, sensor points, sensor normals, sensor weights, owner) for a measure."""
    m = len(points)
    idx = np.arange(m)
    up = frame(up_axis)[2]
    t = measure.type
    if t == "planar":
        return normals, points, normals, np.ones(m), idx
    if t == "vertical":
        n = np.broadcast_to(horizontal(measure.azimuth, up_axis), (m, 3)).copy()
        return n, points, n, np.ones(m), idx
    k = measure.azimuths
    if m * (k + 2) > MAX_SENSORS:
        raise StudyError(f"grid {name}: {m} points x {k} azimuths exceed the limit of {MAX_SENSORS} sensors; "
                         "use fewer azimuths or a larger spacing")
    ring = horizontal(360.0 * np.arange(k) / k, up_axis)  # (k, 3)
    sp = np.repeat(points, k, axis=0)
    sn = np.tile(ring, (m, 1))
    sw = np.full(m * k, 1.0 / k)
    so = np.repeat(idx, k)
    if t == "cylindrical":
        return np.broadcast_to(up, (m, 3)).copy(), sp, sn, sw, so
    if t == "semi_cylindrical":
        h0 = horizontal(measure.azimuth, up_axis)
        face = np.broadcast_to(h0, (m, 3))
        sp = np.concatenate([sp, points, points])
        sn = np.concatenate([sn, face, -face])
        sw = np.concatenate([sw, np.full(m, 1.0 / math.pi), np.full(m, -1.0 / math.pi)])
        so = np.concatenate([so, idx, idx])
        return face.copy(), sp, sn, sw, so
    raise StudyError(f"grid {name}: unknown measure type {t!r}")


def _check_count(name: str, n: int) -> None:
    if n > MAX_GRID_POINTS:
        raise StudyError(f"grid {name}: {n} points exceed the limit of {MAX_GRID_POINTS}; use a larger spacing")


def _cells(name: str, lu: float, lv: float, spacing, rounding: str = "ceil") -> tuple[int, int, Optional[dict]]:
    if spacing == "en12464":
        d = en12464_dimension(lu, lv)
        p = en12464_spacing(d)
        rule = {"d": float(d), "p": float(p), "rounding": rounding}
    else:
        p, rule, rounding = float(spacing), None, "ceil"
    if rounding == "nearest":
        nu, nv = max(1, round(lu / p)), max(1, round(lv / p))
    else:
        nu, nv = cells_along(lu, p), cells_along(lv, p)
    _check_count(name, nu * nv)
    return nu, nv, rule


def _segment_distance(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of 2D points (M, 2) to the segment a-b."""
    ab = b - a
    ll = float(ab @ ab)
    t = np.zeros(len(pts)) if ll == 0 else np.clip((pts - a) @ ab / ll, 0.0, 1.0)
    return np.hypot(*(pts - (a + t[:, None] * ab)).T)


def boundary_edges(polygons: Sequence[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The edges of a set of 2D polygons that lie on the boundary of their union: an edge met
    an even number of times (in either direction, corners matched to 1 nm) is shared, hence
    inside; degenerate edges are dropped. Edges come back in the polygons' order."""
    polys = [np.asarray(p, dtype=np.float64) for p in polygons]
    a = np.concatenate(polys)
    b = np.concatenate([np.concatenate([p[1:], p[:1]]) for p in polys])
    ka, kb = np.round(a, _KEY_DIGITS), np.round(b, _KEY_DIGITS)
    keep = (ka != kb).any(axis=1)
    a, b, ka, kb = a[keep], b[keep], ka[keep], kb[keep]
    swap = (ka[:, 0] > kb[:, 0]) | ((ka[:, 0] == kb[:, 0]) & (ka[:, 1] > kb[:, 1]))
    lo = np.where(swap[:, None], kb, ka)
    hi = np.where(swap[:, None], ka, kb)
    keys = np.concatenate([lo, hi], axis=1) + 0.0  # -0.0 and 0.0 alike
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    odd = counts[inverse.ravel()] % 2 == 1
    return [(a[i], b[i]) for i in np.flatnonzero(odd)]


def _inside(pts: np.ndarray, edges) -> np.ndarray:
    """Crossing parity of 2D points against edges (half-open in v: a point on a shared
    horizontal line is counted once)."""
    inside = np.zeros(len(pts), dtype=bool)
    x, y = pts[:, 0], pts[:, 1]
    for a, b in edges:
        (xa, ya), (xb, yb) = a, b
        if ya == yb:
            continue
        crosses = (ya > y) != (yb > y)
        xc = xa + (y - ya) * (xb - xa) / (yb - ya)
        inside ^= crosses & (x < xc)
    return inside


def _floor_polygons(name: str, spec: WorkplaneGrid, up_axis: str,
                    polygons: Optional[Sequence] = None) -> tuple[list[np.ndarray], float]:
    """2D (e1, e2) polygons and the floor level."""
    e1, e2, up = frame(up_axis)
    raw = polygons if polygons is not None else (spec.polygons if spec.polygons is not None else
                                                 ([spec.polygon] if spec.polygon is not None else None))
    if raw is None:
        raise StudyError(f"grid {name}: room {spec.room!r} has not been resolved into floor polygons "
                         "(hirad.studies.grids.resolve_room, or give polygon)")
    out, levels = [], []
    for k, poly in enumerate(raw):
        try:
            a = np.asarray(poly, dtype=np.float64)
        except (TypeError, ValueError):
            raise StudyError(f"grid {name}: polygon {k}: corners must be lists of 2 or 3 numbers") from None
        if a.ndim != 2 or a.shape[1] not in (2, 3) or len(a) < 3:
            raise StudyError(f"grid {name}: polygon {k}: needs at least 3 corners of 2 or 3 coordinates, "
                             f"got shape {a.shape}")
        if not np.isfinite(a).all():
            raise StudyError(f"grid {name}: polygon {k}: a corner is not finite")
        if a.shape[1] == 3:
            levels.append(a @ up)
            a = np.stack([a @ e1, a @ e2], axis=1)
        out.append(a)
        nxt = np.concatenate([a[1:], a[:1]])
        twice_area = float(np.sum(a[:, 0] * nxt[:, 1] - nxt[:, 0] * a[:, 1]))
        if abs(twice_area) <= 1e-12:
            raise StudyError(f"grid {name}: polygon {k} has no area")
    if levels:
        if len(levels) != len(out):
            raise StudyError(f"grid {name}: mix of 2D and 3D polygons; give all in one form")
        lv = np.concatenate(levels)
        if lv.max() - lv.min() > 1e-6:
            raise StudyError(f"grid {name}: the 3D floor polygon is not horizontal (its corners lie between "
                             f"{lv.min():g} and {lv.max():g} m along {up_axis})")
        floor = float(lv.mean())
    else:
        floor = spec.floor
    return out, floor


def plane_lattice(name: str, local, border: float, spacing, rounding: str, *, no_area: str, no_point: str):
    """The cell centres of a regular lattice over 2D outlines `local` (polygons in a plane's
    (u, v) metres), kept inside them and at least `border` from their boundary: the cells
    span the outlines' box less the border on each side, their number by `spacing` (metres,
    or "en12464") and `rounding` (_cells). Returns (uv (k, 2), ii, jj (k) the kept cells'
    indices, (nu, nv, du, dv, rule), (umin, umax, vmin, vmax) the evaluation box). StudyError
    `no_area` (formatted with span_u, span_v: the outlines' box) when the border leaves no box,
    `no_point` when no cell centre is kept."""
    allp = np.concatenate(local)
    umin, vmin = allp.min(axis=0) + border
    umax, vmax = allp.max(axis=0) - border
    if not (umax > umin and vmax > vmin):
        raise StudyError(no_area.format(span_u=umax - umin + 2 * border, span_v=vmax - vmin + 2 * border))
    lu, lv = umax - umin, vmax - vmin
    nu, nv, rule = _cells(name, lu, lv, spacing, rounding)
    du, dv = float(lu / nu), float(lv / nv)
    ii, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    uv = np.stack([umin + (ii + 0.5) * du, vmin + (jj + 0.5) * dv], axis=1)
    edges = boundary_edges(local)
    keep = _inside(uv, edges)
    if border > 0:
        dmin = np.full(len(uv), np.inf)
        for a, b in edges:
            dmin = np.minimum(dmin, _segment_distance(uv, a, b))
        keep &= dmin >= border * (1.0 - 1e-12)
    if not keep.any():
        raise StudyError(no_point)
    return uv[keep], ii[keep], jj[keep], (nu, nv, du, dv, rule), (umin, umax, vmin, vmax)


def _workplane(name: str, spec: WorkplaneGrid, up_axis: str, polygons=None):
    polys, floor = _floor_polygons(name, spec, up_axis, polygons)
    e1, e2, up = frame(up_axis)
    c, s = math.cos(math.radians(spec.axis)), math.sin(math.radians(spec.axis))
    # local (u, v): the grid's rows along u = c e1 + s e2
    rot = np.array([[c, s], [-s, c]])
    local = [p @ rot.T for p in polys]
    uv, ii, jj, (nu, nv, du, dv, rule), (umin, umax, vmin, vmax) = plane_lattice(
        name, local, spec.border, spec.spacing, spec.rounding,
        no_area=f"grid {name}: the border band of {spec.border:g} m leaves no area (the floor spans "
                "{span_u:g} x {span_v:g} m)",
        no_point=f"grid {name}: no grid point lies inside the floor less its {spec.border:g} m border band")
    axis_u = c * e1 + s * e2
    axis_v = -s * e1 + c * e2
    origin = (floor + spec.height) * up
    pts = origin + uv[:, :1] * axis_u + uv[:, 1:] * axis_v
    normals = np.broadcast_to(up, pts.shape).copy()
    layout = Layout(origin=origin, axis_u=axis_u, axis_v=axis_v, nu=nu, nv=nv, du=du, dv=dv,
                    u0=umin + 0.5 * du, v0=vmin + 0.5 * dv, index=np.stack([ii, jj], axis=1),
                    outlines=local, evaluation_box=(umin, umax, vmin, vmax))
    w = np.full(len(pts), du * dv)
    return pts, normals, w, layout, float(w.sum()), (du, dv), rule


def _unit(v, what: str, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if not (n > 0 and math.isfinite(n)):
        raise StudyError(f"grid {name}: {what} has no length")
    return a / n


def _rectangle(name: str, spec: RectangleGrid):
    corner = np.asarray(spec.corner, dtype=np.float64)
    u, v = np.asarray(spec.edge_u, dtype=np.float64), np.asarray(spec.edge_v, dtype=np.float64)
    lu0, lv0 = float(np.linalg.norm(u)), float(np.linalg.norm(v))
    au, av = u / lu0, v / lv0
    normal = _unit(spec.normal if spec.normal is not None else np.cross(au, av), "normal", name)
    lu, lv = lu0 - 2 * spec.border, lv0 - 2 * spec.border
    if not (lu > 0 and lv > 0):
        raise StudyError(f"grid {name}: the border band of {spec.border:g} m leaves no area of the "
                         f"{lu0:g} x {lv0:g} m rectangle")
    nu, nv, rule = _cells(name, lu, lv, spec.spacing, spec.rounding)
    du, dv = float(lu / nu), float(lv / nv)
    ii, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    uu = spec.border + (ii + 0.5) * du
    vv = spec.border + (jj + 0.5) * dv
    origin = corner + spec.offset * normal
    pts = origin + uu[:, None] * au + vv[:, None] * av
    outline = np.array([[0, 0], [lu0, 0], [lu0, lv0], [0, lv0]], dtype=np.float64)
    layout = Layout(origin=origin, axis_u=au, axis_v=av, nu=nu, nv=nv, du=du, dv=dv,
                    u0=spec.border + 0.5 * du, v0=spec.border + 0.5 * dv, index=np.stack([ii, jj], axis=1),
                    outlines=[outline], evaluation_box=(spec.border, lu0 - spec.border, spec.border, lv0 - spec.border))
    w = np.full(len(pts), du * dv)
    return pts, np.broadcast_to(normal, pts.shape).copy(), w, layout, float(w.sum()), (du, dv), rule


def read_points_csv(path, default_normal=(0.0, 0.0, 1.0), name: str = "points") -> tuple[np.ndarray, np.ndarray]:
    """Points (M, 3) and unit normals (M, 3) from a CSV: ``x,y,z`` or ``x,y,z,nx,ny,nz`` a line
    (metres). Blank lines and lines starting with '#' are skipped, and so is a first line of
    names (such as ``x,y,z,nx,ny,nz``). Errors name the file and the line."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise StudyError(f"grid {name}: {path}: cannot read: {e.strerror or e}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise StudyError(f"{path}:{line}: not UTF-8 text (byte 0x{raw[e.start]:02x})") from None
    dn = _unit(default_normal, "normal", name)
    pts, nrm = [], []
    seen_data = False
    for lineno, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        cells = [c.strip() for c in row]
        if not cells or all(c == "" for c in cells) or cells[0].startswith("#"):
            continue
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if not seen_data and all(c.replace("_", "").isalpha() for c in cells):
                seen_data = True  # the header
                continue
            bad = next(c for c in cells if not _is_float(c))
            raise StudyError(f"{path}:{lineno}: {bad!r} is not a number (a line is x,y,z or x,y,z,nx,ny,nz in metres)") from None
        seen_data = True
        if len(values) not in (3, 6):
            raise StudyError(f"{path}:{lineno}: {len(values)} values; a line is x,y,z or x,y,z,nx,ny,nz")
        if not all(math.isfinite(x) for x in values):
            raise StudyError(f"{path}:{lineno}: a value is not finite")
        pts.append(values[:3])
        if len(values) == 6:
            n = np.asarray(values[3:])
            ln = float(np.linalg.norm(n))
            if ln == 0:
                raise StudyError(f"{path}:{lineno}: the normal (0, 0, 0) has no direction")
            nrm.append(n / ln)
        else:
            nrm.append(dn)
        if len(pts) > MAX_GRID_POINTS:
            raise StudyError(f"{path}:{lineno}: more than {MAX_GRID_POINTS} points")
    if not pts:
        raise StudyError(f"{path}: no points (a line is x,y,z or x,y,z,nx,ny,nz in metres)")
    return np.asarray(pts, dtype=np.float64), np.asarray(nrm, dtype=np.float64)


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def build_grid(name: str, spec: GridSpec, *, up_axis: str = "Z", base_dir=None,
               polygons: Optional[Sequence] = None) -> Grid:
    """The points and sensors of one grid spec. `base_dir` resolves a points grid's relative
    file; `polygons` (2D or 3D floor polygons) stand in for a work plane's `room`."""
    layout = area = spacing = rule = source = None
    if isinstance(spec, (WorkplaneGrid, CorridorGrid)):
        pts, nrm, w, layout, area, spacing, rule = _workplane(name, spec, up_axis, polygons)
    elif isinstance(spec, RectangleGrid):
        pts, nrm, w, layout, area, spacing, rule = _rectangle(name, spec)
    elif isinstance(spec, PointsGrid):
        f = Path(spec.file)
        if not f.is_absolute() and base_dir is not None:
            f = Path(base_dir) / f
        pts, nrm = read_points_csv(f, spec.normal, name)
        w = np.ones(len(pts))
        source = str(f)
    else:
        raise StudyError(f"grid {name}: not a grid spec ({type(spec).__name__})")
    normals, sp, sn, sw, so = _sensors(name, spec.measure, pts, nrm, up_axis)
    return Grid(name=name, kind=spec.kind, measure=spec.measure, points=pts, normals=normals, weights=w,
                sensor_points=np.ascontiguousarray(sp), sensor_normals=np.ascontiguousarray(sn),
                sensor_weights=sw, sensor_owner=so, layout=layout, area=area, spacing=spacing,
                rule=rule, source=source)


def resolve_room(stage, prim_path: str, up_axis: Optional[str] = None, *, max_tilt_deg: float = 1.0) -> list[np.ndarray]:
    """The floor polygons of a room prim: the faces of every Mesh at or under `prim_path`
    (instance proxies included) whose world normal points up (within max_tilt_deg), in world metres (metersPerUnit
    applied), as 3D polygons for a work plane's `polygons`. Errors name the prim."""
    from pxr import Usd, UsdGeom

    prim = stage.GetPrimAtPath(prim_path)
    if not prim or not prim.IsValid():
        raise StudyError(f"room {prim_path}: no such prim in the stage")
    up_axis = up_axis or str(UsdGeom.GetStageUpAxis(stage))
    up = frame(up_axis)[2]
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    cos_tilt = math.cos(math.radians(max_tilt_deg))
    out = []
    for p in Usd.PrimRange(prim, Usd.TraverseInstanceProxies()):
        if not p.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(p)
        points = mesh.GetPointsAttr().Get()
        counts = mesh.GetFaceVertexCountsAttr().Get()
        indices = mesh.GetFaceVertexIndicesAttr().Get()
        if points is None or counts is None or indices is None:
            continue
        xf = np.asarray(mesh.ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64)
        pts = np.asarray(points, dtype=np.float64)
        world = (np.c_[pts, np.ones(len(pts))] @ xf)[:, :3] * mpu  # USD matrices act on row vectors
        flip = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
        start = 0
        for c in counts:
            face = world[np.asarray(indices[start:start + c])]
            start += c
            if c < 3:
                continue
            n = np.zeros(3)
            for i in range(c):  # Newell
                a, b = face[i], face[(i + 1) % c]
                n += np.cross(a, b)
            ln = np.linalg.norm(n)
            if ln == 0:
                continue
            n = -n / ln if flip else n / ln
            if n @ up >= cos_tilt:
                out.append(face)
    if not out:
        raise StudyError(f"room {prim_path}: no upward-facing mesh face (a floor) at or under the prim")
    return out
