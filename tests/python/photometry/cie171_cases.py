"""Scenes, closed forms and runners for CIE 171:2006 test cases 5.6 (light reflection over
diffuse surfaces) and 5.7 (diffuse reflections with internal obstructions), for
test_cie171_56_57.py and bench/cie171_56_57.py. Not a test module (no test_ prefix).

Both cases measure the light one uniformly lit Lambertian surface S2 of reflectance rho sends
to points on black measurement surfaces S1, as a percentage of E / (E_2 rho), E_2 the
illuminance on S2. That ratio is the configuration factor F(dA_P -> visible S2) from the point
to S2 (see `lambert_polygon_factor`), x 100.

Geometry (metres, x across, y into the room, z up; every surface but S2 black, rho = 0):

5.6, scenario 2 (CIE 171:2006 section 5.6, Table 17):
  S2     floor, x 0..4, y 0..4, z = 0, rho = 0.30, facing up, uniformly lit.
  S1-v   wall y = 0, x 0..4, z 0.5..3 (it starts 50 cm above the floor), facing +y;
         points B..F at x = 2, z = 0.75, 1.25, 1.75, 2.25, 2.75 (A, z = 0.25, is below the
         wall: "-" in the table).
  S1-hz  ceiling z = 3, x 0..4, y 0..4, facing down; points G..N at x = 2,
         y = 0.25, 0.75, ..., 3.75.
5.7 (CIE 171:2006 section 5.7, Figs. 12-13, Table 19 as corrected):
  S2     wall y = 4, x 0..4, z 0..3, rho = 0.60, facing -y, lit by a sun at 60 degrees.
  S1-v   wall y = 0, x 0..4, z 0..3, facing +y; points A..F at x = 2,
         z = 2.75, 2.25, ..., 0.25.
  S1-hz  floor z = 0, x 0..4, y 0..2.5, facing up; points G..K at x = 2,
         y = 0.25, 0.75, ..., 2.25.
  obstruction  a black box x 0..4, y 2.5..2.7, z 0..1 (4 m x 0.2 m x 1 m).

Sources. The cases are CIE 171:2006's; the report itself was not at hand. The published
validations that list them are Dau Design and Consulting, "Validation of NVIDIA Iray against
CIE 171:2006" (2016,
https://pdfslide.us/documents/validation-of-nvidia-iray-against-cie-1712006-cie-1712006-table-of-contents.html)
and I. Ashdown, "CIE 171:2006 - Errata" (https://lightinganalysts.com/cie-1712006-errata, whose
section 1 is "Test Case 5.7: Analytical Reference, Table 19 Analysis"); only the openings of
those pages could be read here. The dimensions, reflectances and point layouts above, and the
Table 17 values, were taken from a public transcription of the Iray report (a Blender-based
CIE 171 validation project in the public code index, citing the report's Table 14, p. 24, for
the corrected Table 19). CIE's own Table 19 for 5.7 is wrong; the corrected values (A 16.07
... K 0) are those of the Iray report and of issue 13. Because that is second-hand, the
geometry is checked against the numbers themselves: the closed forms below, computed from it,
reproduce every value of Table 17 to 0.015 % and of the corrected Table 19 to its two
decimals (test_cie171_56_57.py asserts both), which a wrong dimension would not.

Light. hirad has no sun or sky (daylight is issue 16), so S2 is lit by a luminaire chosen to
give it a uniform illuminance:
  5.6  a point luminaire 1.5 m above the floor's centre with I(gamma) = E_2 h^2 / cos^3(gamma)
       (gamma from the nadir, out to 65 degrees; the floor's corners are at 62.1 degrees), so
       E = I cos(gamma) / r^2 = I cos^3(gamma) / h^2 = E_2 on the whole floor; a sun cannot do
       it here, the ceiling S1-hz covers the floor;
  5.7  "the sun": an isotropic point luminaire 10^5 m away, 60 degrees above the horizon
       behind the measurement wall; over the 4 x 3 m wall its 1/r^2 varies by < 1e-4.
Both light S2 (and the black surfaces) directly; only S2 reflects, and S2 cannot see itself,
so what a sensor receives from the surfaces is exactly one bounce: the `indirect` part of
SurfaceField.illuminance (the luminaire's direct light at the sensor is in `direct`, not used).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from hirad import _engine
from hirad.engine import build_engine, patch_dict

import cie171_scenes as cie

OFFSET = 1e-4  # m: sensors sit 0.1 mm off their surface, into the room
E2 = 1000.0  # lx: the illuminance on S2 (any value: the results are ratios)

# ---- published values, % of E / (E_2 rho) -----------------------------------------------------

# CIE 171:2006 Table 17, scenario 2 (S2 4 x 4 m, rho 0.30); as listed in the Iray report.
TABLE_17 = {"B": 35.901, "C": 27.992, "D": 21.639, "E": 16.716, "F": 12.967,
            "G": 26.80, "H": 30.94, "I": 33.98, "J": 35.57, "K": 35.57, "L": 33.98, "M": 30.94, "N": 26.80}
# CIE 171:2006 Table 19 as corrected by Dau Design's Iray report (its Table 14) and Ashdown's
# errata; CIE's printed Table 19 is wrong.
TABLE_19_CORRECTED = {"A": 16.07, "B": 16.33, "C": 15.40, "D": 13.32, "E": 10.32, "F": 7.08,
                      "G": 3.38, "H": 3.63, "I": 3.01, "J": 0.0, "K": 0.0}

RHO_56, RHO_57 = 0.30, 0.60
WALL_56 = {"B": 0.75, "C": 1.25, "D": 1.75, "E": 2.25, "F": 2.75}  # z on S1-v, x = 2
CEILING_56 = {"G": 0.25, "H": 0.75, "I": 1.25, "J": 1.75, "K": 2.25, "L": 2.75, "M": 3.25, "N": 3.75}  # y
WALL_57 = {"A": 2.75, "B": 2.25, "C": 1.75, "D": 1.25, "E": 0.75, "F": 0.25}  # z on S1-v, x = 2
FLOOR_57 = {"G": 0.25, "H": 0.75, "I": 1.25, "J": 1.75, "K": 2.25}  # y on S1-hz, x = 2
BOX_57 = ((0.0, 2.5, 0.0), (4.0, 2.7, 1.0))  # the obstruction, min and max corners
SUN_ELEVATION = math.radians(60.0)
SUN_DISTANCE = 1e5
LAMP_HEIGHT_56 = 1.5
LAMP_CUTOFF_56 = math.radians(65.0)


# ---- the closed form ---------------------------------------------------------------------------

def lambert_polygon_factor(p, n, polygon) -> float:
    """Configuration factor from a differential area at p with unit normal n to a planar
    polygon lying wholly in front of it (Lambert's contour integral):

        F = (1 / 2 pi) sum_i theta_i (n . u_i),   u_i = unit(r_i x r_(i+1)),

    r_i = v_i - p the vertices seen from p, theta_i the angle between r_i and r_(i+1). The
    illuminance a Lambertian surface of exitance M sends to p is M F, so for S2 (M = rho E_2)
    E / (E_2 rho) = F. The sign follows the polygon's winding; the absolute value is taken."""
    p, n = np.asarray(p, float), np.asarray(n, float)
    r = np.asarray(polygon, float) - p
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        c = np.cross(a, b)
        norm = np.linalg.norm(c)
        if norm < 1e-300:
            continue
        theta = math.atan2(norm, float(np.dot(a, b)))
        total += theta * float(np.dot(n, c)) / norm
    return abs(total) / (2.0 * math.pi)


def visible_s2_57(p):
    """The part of the 5.7 wall S2 (y = 4, x 0..4, z 0..3) a point p (y < 2.5, x = 2) sees
    past the box (y 2.5..2.7, z 0..1, the wall's whole width), as a polygon, or None.

    A ray from p to (x_s, 4, z_s) has height z(y) = z_p + (z_s - z_p)(y - y_p)/(4 - y_p); it
    is linear in y, so it clears the box iff z > 1 at both faces y_e = 2.5 and 2.7, i.e.
    z_s > z_p + (1 - z_p)(4 - y_p)/(y_e - y_p) for both. Its x at the box stays in 0..4 (p is
    at x = 2, x_s in 0..4), so the box always spans the shadow: the visible part is the
    rectangle z_lo < z < 3 with z_lo the larger bound (the near top edge for points below the
    box top, the far one for points above it)."""
    px, py, pz = p
    z_lo = max(pz + (1.0 - pz) * (4.0 - py) / (ye - py) for ye in (2.5, 2.7))
    z_lo = max(0.0, z_lo)
    if z_lo >= 3.0:
        return None
    return np.array([[0.0, 4.0, z_lo], [4.0, 4.0, z_lo], [4.0, 4.0, 3.0], [0.0, 4.0, 3.0]])


def closed_form_56(p, n) -> float:
    """% E / (E_2 rho) at p facing n in 5.6 scenario 2: Lambert's factor to the whole floor
    (it is unobstructed and wholly in front of every point)."""
    floor = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 4.0, 0.0], [0.0, 4.0, 0.0]])
    return 100.0 * lambert_polygon_factor(p, n, floor)


def closed_form_57(p, n) -> float:
    """% E / (E_2 rho) at p facing n in 5.7: Lambert's factor to the visible part of S2."""
    visible = visible_s2_57(p)
    return 0.0 if visible is None else 100.0 * lambert_polygon_factor(p, n, visible)


def brute_force_factor(p, n, origin, u, v, s2_normal, box=None, grid: int = 800) -> float:
    """The same factor by a midpoint rule over the rectangle origin + s u + t v (s, t in 0..1),
    each cell's ray tested against the axis-aligned box (min, max) by slabs; %. Independent of
    the closed form (which it checks)."""
    p, n, s2_normal = (np.asarray(a, float) for a in (p, n, s2_normal))
    s = (np.arange(grid) + 0.5) / grid
    S, T = np.meshgrid(s, s, indexing="ij")
    q = np.asarray(origin, float) + S[..., None] * np.asarray(u, float) + T[..., None] * np.asarray(v, float)
    d = q - p
    r2 = (d * d).sum(-1)
    r = np.sqrt(r2)
    w = np.clip(d @ n / r, 0, None) * np.clip(-(d @ s2_normal) / r, 0, None) / (math.pi * r2)
    if box is not None:
        lo, hi = (np.asarray(b, float) for b in box)
        tmin, tmax = np.zeros_like(r), np.ones_like(r)
        for k in range(3):
            dk = d[..., k]
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (lo[k] - p[k]) / dk, (hi[k] - p[k]) / dk
            flat = np.abs(dk) < 1e-15
            inside = (p[k] >= lo[k]) & (p[k] <= hi[k])
            tmin = np.maximum(tmin, np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)))
            tmax = np.minimum(tmax, np.where(flat, np.inf, np.maximum(t1, t2)))
        w = np.where(tmin <= tmax, 0.0, w)
    area = np.linalg.norm(np.asarray(u, float)) * np.linalg.norm(np.asarray(v, float))
    return 100.0 * float(w.sum()) * area / grid ** 2


# ---- the scenes --------------------------------------------------------------------------------

def points_56(offset: float = OFFSET):
    """Names, points and normals of 5.6 scenario 2 (sensors `offset` off their surface)."""
    names, pts, nrm = [], [], []
    for k, z in WALL_56.items():
        names.append(k); pts.append((2.0, offset, z)); nrm.append((0.0, 1.0, 0.0))
    for k, y in CEILING_56.items():
        names.append(k); pts.append((2.0, y, 3.0 - offset)); nrm.append((0.0, 0.0, -1.0))
    return names, np.array(pts), np.array(nrm)


def points_57(offset: float = OFFSET):
    """Names, points and normals of 5.7 (sensors `offset` off their surface)."""
    names, pts, nrm = [], [], []
    for k, z in WALL_57.items():
        names.append(k); pts.append((2.0, offset, z)); nrm.append((0.0, 1.0, 0.0))
    for k, y in FLOOR_57.items():
        names.append(k); pts.append((2.0, y, offset)); nrm.append((0.0, 0.0, 1.0))
    return names, np.array(pts), np.array(nrm)


def scene_56():
    """(scene arrays, index of S2, luminaire) of 5.6 scenario 2."""
    rect = cie.rect
    polys = [rect(2, 0.0, (0, 0), (4, 4), +1),          # S2, the floor
             rect(1, 0.0, (0.5, 0), (3, 4), +1),        # S1-v, y = 0, z 0.5..3 (axes z, x)
             rect(2, 3.0, (0, 0), (4, 4), -1)]          # S1-hz, the ceiling, facing down
    reflectance = np.array([RHO_56, 0.0, 0.0])
    h = LAMP_HEIGHT_56
    gamma = np.radians(np.linspace(0.0, 180.0, 721))   # 0.25 degree nodes
    cd = np.where(gamma <= LAMP_CUTOFF_56, E2 * h * h / np.cos(np.minimum(gamma, LAMP_CUTOFF_56)) ** 3, 0.0)
    lamp = _engine.Luminaire("uniform-floor", np.array([[2.0, 2.0, h]]), np.ones(1), np.eye(3),
                             np.ascontiguousarray(cd[None, :]), np.ones((1, 3)))
    return cie.scene_of(polys, reflectance, 0.0), 0, lamp


def sun_57():
    """The 5.7 sun: an isotropic point SUN_DISTANCE from S2's centre, SUN_ELEVATION above the
    horizon on the room's side (-y), of intensity giving E_2 on S2 (normal -y):
    E_2 = I cos(incidence) / D^2, cos(incidence) = cos(elevation)."""
    centre = np.array([2.0, 4.0, 1.5])
    towards = np.array([0.0, -math.cos(SUN_ELEVATION), math.sin(SUN_ELEVATION)])
    intensity = E2 * SUN_DISTANCE ** 2 / math.cos(SUN_ELEVATION)
    return _engine.Luminaire("sun", (centre + SUN_DISTANCE * towards)[None, :], np.ones(1), np.eye(3),
                             np.full((1, 2), intensity), np.ones((1, 3)))


def scene_57(obstruction: bool = True):
    """(scene arrays, index of S2, luminaire) of 5.7 (without the box: obstruction=False)."""
    rect = cie.rect
    (x0, y0, z0), (x1, y1, z1) = BOX_57
    polys = [rect(1, 4.0, (0, 0), (3, 4), -1),          # S2, y = 4, facing the room (axes z, x)
             rect(1, 0.0, (0, 0), (3, 4), +1),          # S1-v, y = 0
             rect(2, 0.0, (0, 0), (4, 2.5), +1),        # S1-hz, floor y 0..2.5
             rect(2, z1, (x0, y0), (x1, y1), +1),       # box top
             rect(1, y0, (z0, x0), (z1, x1), -1),       # box front (towards S1)
             rect(1, y1, (z0, x0), (z1, x1), +1),       # box back (towards S2)
             rect(0, x0, (y0, z0), (y1, z1), -1),       # box ends (axes y, z)
             rect(0, x1, (y0, z0), (y1, z1), +1)]
    if not obstruction:
        polys = polys[:3]
    reflectance = np.zeros(len(polys))
    reflectance[0] = RHO_57
    return cie.scene_of(polys, reflectance, 0.0), 0, sun_57()


# ---- the runs ----------------------------------------------------------------------------------

def solve(scene, lamp, method: str):
    """(patches, radiosity B per patch) lit by `lamp`: 'flat' (meshed at 0.25 m^2, raycast
    links, direct solve) or 'hierarchical' (leaves made the patches)."""
    engine = build_engine(scene)
    engine.set_luminaires([lamp])
    if method == "flat":
        engine.mesh(_engine.MeshOptions(max_patch_area=0.25, max_edge_length=0.5))
        ff = _engine.FormFactorOptions(method="raycast", samples=16, seed=1)
        engine.compute_links(ff)
        b = np.asarray(engine.solve(_engine.SolveOptions(method="direct", tolerance=1e-9), ff).radiosity)
    elif method == "hierarchical":
        r = engine.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-5, min_area=0.01, samples=16),
                                      _engine.SolveOptions(method="gauss_seidel", tolerance=1e-9))
        engine.use_leaves_as_patches()
        b = np.asarray(r.radiosity)
    else:
        raise ValueError(method)
    return patch_dict(engine.patch_arrays()), b


def run(case: str, method: str, rays: int = 65536, seed: int = 1, obstruction: bool = True) -> SimpleNamespace:
    """Case '5.6' or '5.7' solved by `method`: per point the published value, the closed form
    at the sensor, hirad's value (all % of E / (E_2 rho)), and S2's per-patch illuminance.
    `rays` hemisphere rays per sensor (stratified, cosine-distributed) read the reflected
    light; obstruction=False drops 5.7's box (a control: the table must then fail)."""
    if case == "5.6":
        scene, s2, lamp = scene_56()
        names, pts, nrm = points_56()
        table, closed, rho = TABLE_17, closed_form_56, RHO_56
    elif case == "5.7":
        scene, s2, lamp = scene_57(obstruction)
        names, pts, nrm = points_57()
        table, closed, rho = TABLE_19_CORRECTED, closed_form_57, RHO_57
    else:
        raise ValueError(case)
    patches, b = solve(scene, lamp, method)
    field, emitted = cie.field_of(patches, b)
    ill = field.illuminance(np.ascontiguousarray(pts), np.ascontiguousarray(nrm), emitted, rays=rays, seed=seed)
    reflected = cie.luminous(ill.indirect)
    on_s2 = patches["source_face"] == s2
    return SimpleNamespace(
        case=case, method=method, names=names, rho=rho,
        expected=np.array([table[k] for k in names]),
        closed=np.array([closed(p, n) for p, n in zip(pts, nrm)]),
        hirad=100.0 * reflected / (E2 * rho),
        s2_illuminance=cie.luminous(patches["direct"][on_s2]),
        s2_radiosity=cie.luminous(b[on_s2]),
        patches=int(len(patches["area"])), points=pts, normals=nrm)
