"""Luminaire tables: USD lights, IES files and config point lights as the engine's luminaires.

A luminaire (``hirad._engine.Luminaire``, pipeline/geometry/luminaire.h) is a candela table
I(C, gamma) in the light's own frame, emitted from a few weighted points over its luminous
opening. This module builds those tables from closed-form profiles and from IES files, as
:class:`LuminaireSpec` objects (pure numpy; :meth:`LuminaireSpec.to_engine` makes the engine
object), and the report's luminaire schedule (:func:`schedule`).

Axes (exactly hirad.photometry.ies's)
-------------------------------------
gamma = 0 is the light's local -Z, gamma = 180 its +Z; C = 0 is local +X, C = 90 local +Y;
local direction (gamma, C) = (sin gamma cos C, sin gamma sin C, -cos gamma). ``frame`` rows are
the local X, Y, Z axes in world space (orthonormal, right-handed).

Tables
------
``candela`` is (nc, ng): I at C_i = 360 i / nc (periodic) and gamma_j = 180 j / (ng - 1),
bilinear in (C, gamma) between the nodes. Defaults: ng = 361 (0.5 degree); nc = 1 for a
rotationally symmetric profile and nc = 360 (1 degree) otherwise. 360 rather than 720: the
C direction of real files is measured at 5-22.5 degree steps and of the closed forms here it is
smooth (or a kink, the cylinder's axis), so 1 degree already resolves it; the table's flux is
exact whatever the step (below); and 360 x 361 doubles are 1 MB per light, which a hall of
a few hundred luminaires can afford, where 720 would double it.

Every node is the *hat-weighted average* of the profile over the node's bilinear basis
function (its neighbouring cells), weighted by the solid angle sin(gamma) dgamma dC:

    T_ij = integral phi_i(C) phi_j(gamma) I(gamma, C) dOmega / integral phi_i phi_j dOmega,

computed by Gauss-Legendre quadrature inside every 0.5 degree cell (cells split at the
profile's known jumps, e.g. a hard cone edge). Since the basis functions sum to 1, the exact
flux of the bilinear table, sum_ij T_ij integral(phi_i phi_j dOmega), *is* the profile's flux:
a hard cone cut, the cylinder's kink on its axis or an IES file's steep beam lose nothing to
the table (point sampling would miss up to ~1.5 % of a 30 degree cone at 0.5 degrees). For a
smooth profile a node differs from the point value by O(h^2) (h = 0.5 degree: ~1e-5 relative).
:func:`table_flux` is that exact integral (the same formula as luminaire.h):

    flux = sum_i dC_i sum_j T_ij w_j,   w_j = integral phi_j(gamma) sin(gamma) dgamma
    (on a cell [a, b] of width h: node a gets cos a - (sin b - sin a) / h,
     node b gets (sin b - sin a) / h - cos b).

Light types and their formulas (UsdLux of OpenUSD 25.05+, as documented in the schema.usda
that ships with usd-core 26.11, pxr/usdLux/resources/usdLux/schema.usda, UsdLuxLightAPI
"Quantities and Units" and UsdLuxShapingAPI; the same text is published at
https://openusd.org/release/api/class_usd_lux_light_a_p_i.html,
https://openusd.org/release/api/class_usd_lux_shaping_a_p_i.html,
https://openusd.org/release/api/class_usd_lux_sphere_light.html and
https://openusd.org/dev/user_guides/schemas/usdLux/LightAPI.html; it came with OpenUSD pull
request 3182, "[UsdLux] Add explanation of UsdLux quantities and behavior"):

* emission L = inputs:intensity x 2^inputs:exposure x inputs:color (x the blackbody colour of
  inputs:colorTemperature when enabled) is a luminance in nits (cd/m^2); ``inputs:normalize``
  divides it by the world-space surface area of the light ("sizeFactor_area =
  worldSpaceSurfaceArea(light)").
* SphereLight, radius r > 0: a Lambertian sphere of luminance L has the intensity of its
  projected disk in every direction, I = L pi r^2 (isotropic), flux 4 pi^2 r^2 L (= pi L x its
  area 4 pi r^2), exact for a fully visible sphere; one point at the centre. Area for normalize:
  4 pi r^2.
* SphereLight with treatAsPoint: the schema defines treatAsPoint as "a hint that this light can
  be treated as a 'point' light (effectively, a zero-radius sphere) by renderers that benefit
  from non-area lighting. Renderers that only support area lights can disregard this"; it
  defines no other unit for it. So a hint must not change the light's power: hirad emits the
  sphere's own light from its centre, I = L pi r^2 (with normalize L/(4 pi r^2) x pi r^2 = L/4).
* SphereLight of radius 0: a zero-area sphere, I = L pi 0^2 = 0: it emits nothing (a warning
  says so) unless normalize is on, whose limit r -> 0 is finite, I = L/4 cd (flux pi L), or
  ``photometric:power`` gives its flux.
* CylinderLight (major axis local X, inputs:length l, inputs:radius r, "does not emit light from
  the flat end-caps"): the lateral surface seen at angle alpha from the axis projects 2 r l
  sin(alpha), so I(alpha) = 2 r l L sin(alpha), flux 2 pi^2 r l L; in table angles
  cos(alpha) = d_x = sin(gamma) cos(C). Emitted from k >= 8 points along the axis (weight 1/k)
  for the near field. Area for normalize: the emitting lateral surface 2 pi r l.
* RectLight (w x h) and DiskLight (radius r) with shaping: Lambertian toward local -Z,
  I = L A cos(gamma) for gamma < 90 and 0 above, times the shaping factor, from a stratified
  grid of equal-weight points over the opening. Without shaping they stay area emitters
  (hirad.usd.scene), unchanged.
* ShapingAPI (schema text of inputs:shaping:*; the light axis is local -Z, theta = gamma):
  - focus (values < 0 ignored): focusFactor = |cos gamma|^focus; focusTint t (clamped to [0, 1]):
    L_c x lerp(focusFactor, t_c, 1) = L_c (t_c + focusFactor (1 - t_c)). A grey tint is one
    scalar profile; a coloured tint is two luminaires at the same points (colour L t and
    profile x 1, colour L (1 - t) and profile x focusFactor), exact, one schedule row.
  - cone: theta > cone:angle -> 0; softness s clamped to [0, 1]: smoothStart = angle (1 - s),
    factor 1 - smoothstep(theta, smoothStart, angle), smoothstep(x, e0, e1) = t^2 (3 - 2t),
    t = clamp((x - e0)/(e1 - e0), 0, 1). An *unauthored* cone angle (fallback 90) does not cut:
    the focus doc says sphere and cylinder lights emit behind the light unless the cone angle is
    set to 90 or less.
  - ies:angleScale a: theta_ies = theta / a (a > 0), theta (a = 0), (theta - 180)/(-a) + 180
    (a < 0).
  - ies:file, two modes (``photometry.ies_mode`` in the config, recorded in every spec):
    ``absolute`` (default; how Radiance's ies2rad and AGi32 read a file): I = the file's candela
    x multiplier x ballast factor (x the ballast-lamp factor where the version defines it) x
    cone x focus, and the light's L (intensity x 2^exposure x colour) is a dimmer, 1 by
    default; the shape only places the points and inputs:normalize does not apply.
    ``usdlux``: the UsdLux formula, L_color = iesSample x L_color on the light's own profile
    (I = base(L) x iesSample x cone x focus). With ies:normalize the schema says the sample "is
    scaled by the overall power of the IES profile ... preserving the overall energy output"; hirad
    divides, so that the IES-shaped light emits exactly the flux of the unshaped light
    (base x ies x Phi_base / integral(base x ies) dOmega), then cone and focus apply.
* ``photometric:power`` (lm, authored on a light, in the spirit of PhotometricAreaLightAPI):
  the colour is scaled so the luminous flux, Y = 0.2126 R + 0.7152 G + 0.0722 B (Rec.709) of
  the table flux x colour, is exactly that.
* A config point light (``lights:``): an isotropic point of ``intensity`` cd (or ``flux`` lm,
  I = flux / 4 pi), or an IES file aimed by ``aim``/``c0`` or ``rotation`` (absolute: intensity
  is the dimmer; usdlux: the profile keeps the flux 4 pi x intensity of the isotropic light).

Units: cd and lm in photometric scenes (RGB = candela x colour); the same numbers are W/sr and
W in the radiometric reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Iterable, Optional, Sequence

import numpy as np

NG_DEFAULT = 361  # gamma nodes: 0.5 degree
NC_ASYMMETRIC = 360  # C nodes of a profile that is not rotationally symmetric: 1 degree
QUAD = 3  # Gauss-Legendre points per 0.5 degree cell and direction (the integrand is smooth in a cell)
IES_MODES = ("absolute", "usdlux")
Y_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])  # Rec.709 luminance of linear RGB
GRID_POINTS = 8  # points along the longer side of a shaped rectangle or disk (8 x 8 on a square)
CYLINDER_POINTS_MIN = 8
CYLINDER_POINTS_MAX = 64


class LuminaireError(ValueError):
    """A luminaire that cannot be built (the message names it and the problem)."""


# ----------------------------------------------------------------------------------------------
# profiles: I(gamma, C) on tensor grids, degrees -> cd
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Profile:
    """A luminous intensity distribution in the light's frame.

    ``func(gamma, c)`` takes 1-D arrays of degrees and returns the (len(gamma), len(c)) grid of
    candela; ``axial`` says it does not depend on C; ``breaks`` are gamma values (degrees) where
    it jumps (the quadrature splits its cells there)."""

    func: Callable[[np.ndarray, np.ndarray], np.ndarray]
    axial: bool
    breaks: tuple = ()

    def __call__(self, gamma, c) -> np.ndarray:
        g = np.atleast_1d(np.asarray(gamma, dtype=float))
        cc = np.atleast_1d(np.asarray(c, dtype=float))
        out = np.asarray(self.func(g, cc), dtype=float)
        return np.broadcast_to(out, (g.size, cc.size))

    def __mul__(self, other: "Profile") -> "Profile":
        a, b = self, other
        return Profile(lambda g, c: a(g, c) * b(g, c), a.axial and b.axial, tuple(sorted(set(a.breaks + b.breaks))))

    def scaled(self, k: float) -> "Profile":
        a = self
        return Profile(lambda g, c: k * a(g, c), a.axial, a.breaks)


def _axial(f, breaks=()) -> Profile:
    return Profile(lambda g, c: f(g)[:, None] * np.ones((1, c.size)), True, tuple(breaks))


def isotropic(i0: float) -> Profile:
    """I = i0 in every direction."""
    return _axial(lambda g: np.full(g.shape, float(i0)))


def lambertian(i0: float) -> Profile:
    """I = i0 cos(gamma) toward the lower hemisphere (local -Z), 0 above: a flat Lambertian
    emitter of luminance L and area A has i0 = L A."""
    return cos_power(i0, 1.0)


def cos_power(i0: float, n: float) -> Profile:
    """I = i0 cos^n(gamma) for gamma <= 90, 0 above (flux 2 pi i0 / (n + 1))."""
    return _axial(lambda g: float(i0) * np.cos(np.radians(np.minimum(g, 90.0))) ** n * (g <= 90.0),
                  () if n > 0 else (90.0,))


def cylinder(i_perp: float) -> Profile:
    """A cylinder along local X: I = i_perp sin(alpha), alpha from the axis; cos(alpha) =
    sin(gamma) cos(C). A Lambertian cylinder of luminance L, radius r, length l: i_perp = 2 r l L."""
    def f(g, c):
        cos_a = np.sin(np.radians(g))[:, None] * np.cos(np.radians(c))[None, :]
        return float(i_perp) * np.sqrt(np.maximum(0.0, 1.0 - cos_a * cos_a))
    return Profile(f, False)


def smoothstep(x, e0, e1):
    """GLSL smoothstep: t^2 (3 - 2 t), t = clamp((x - e0) / (e1 - e0), 0, 1); a step at e0 = e1."""
    x = np.asarray(x, dtype=float)
    if e1 <= e0:
        return (x >= e1).astype(float)
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def cone_factor(angle: float, softness: float = 0.0) -> Profile:
    """UsdLuxShapingAPI cone: 0 beyond ``angle`` degrees off the -Z axis, and 1 - smoothstep(
    theta, angle (1 - s), angle) inside, s = softness clamped to [0, 1]."""
    s = min(1.0, max(0.0, float(softness)))
    angle = float(angle)
    start = angle * (1.0 - s)
    if s == 0.0:
        return _axial(lambda g: (g <= angle).astype(float), (angle,) if 0 < angle < 180 else ())
    return _axial(lambda g: (g <= angle) * (1.0 - smoothstep(g, start, angle)))


def focus_factor(focus: float) -> Profile:
    """UsdLuxShapingAPI focus: |cos(theta)|^focus (focus < 0 is ignored: 1)."""
    f = max(0.0, float(focus))
    return _axial(lambda g: np.abs(np.cos(np.radians(g))) ** f)


def angle_scaled(gamma, angle_scale: float):
    """theta_ies of UsdLuxShapingAPI's inputs:shaping:ies:angleScale (degrees)."""
    g = np.asarray(gamma, dtype=float)
    a = float(angle_scale)
    if a > 0:
        return g / a
    if a < 0:
        return (g - 180.0) / (-a) + 180.0
    return g


def ies_profile(photometry, angle_scale: float = 0.0, ballast: bool = True) -> Profile:
    """The IES file's candela (x multiplier x ballast factors) from hirad.photometry.ies's smooth
    interpolant, with UsdLux's angleScale applied to the vertical angle."""
    p = photometry
    axial = p.photometric_type == "C" and p.symmetry.startswith("axial")
    factor = p.output_factor if ballast else 1.0

    def f(g, c):
        gi = angle_scaled(g, angle_scale)
        if p.photometric_type == "C":
            grid = p._grid()
            if axial:
                return grid.evaluate_grid(gi, np.zeros(1)) * factor
            return grid.evaluate_grid(gi, c) * factor
        from .ies import angles_to_direction
        out = np.zeros((gi.size, c.size))
        inside = (gi >= 0) & (gi <= 180)
        if inside.any():
            d = angles_to_direction(gi[inside][:, None], c[None, :])
            out[inside] = np.asarray(p.intensity(d.reshape(-1, 3), ballast=ballast)).reshape(d.shape[:2])
        return out

    # the measured range's ends (a file of 0-90 degrees stops at 90) are jumps: as the light's
    # angles (the inverse of angleScale) they split the quadrature's cells
    breaks = []
    if p.photometric_type == "C":
        a = float(angle_scale)
        for v in p.vertical_range:
            t = v * a if a > 0 else (v - 180.0) * (-a) + 180.0 if a < 0 else v
            if 0.0 < t < 180.0:
                breaks.append(float(t))
    return Profile(f, axial, tuple(sorted(set(breaks))))


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------

_GL = {n: np.polynomial.legendre.leggauss(n) for n in (1, 2, 3, 4, 6, 8)}


def gamma_nodes(ng: int = NG_DEFAULT) -> np.ndarray:
    return np.linspace(0.0, 180.0, ng)


def c_nodes(nc: int) -> np.ndarray:
    return 360.0 * np.arange(nc) / nc


def gamma_weights(ng: int) -> np.ndarray:
    """w_j = integral of the hat function of node j times sin(gamma) dgamma (radians)."""
    g = np.radians(gamma_nodes(ng))
    a, b = g[:-1], g[1:]
    h = b - a
    ds = (np.sin(b) - np.sin(a)) / h
    w = np.zeros(ng)
    np.add.at(w, np.arange(ng - 1), np.cos(a) - ds)
    np.add.at(w, np.arange(1, ng), ds - np.cos(b))
    return w


def table_flux(candela) -> float:
    """The exact flux of a bilinear (nc, ng) table over the sphere (lm for cd)."""
    t = np.asarray(candela, dtype=float)
    nc, ng = t.shape
    return float((2.0 * math.pi / nc) * (t.sum(axis=0) @ gamma_weights(ng)))


def _quadrature_gamma(ng: int, breaks: Iterable[float], n: int):
    """Points (degrees), and the (ng, npts) matrix of hat x sin(gamma) x weight (radians)."""
    nodes = gamma_nodes(ng)
    h = nodes[1] - nodes[0]
    x, w = _GL[n]
    pts, rows, vals = [], [], []
    brk = sorted(b for b in breaks if 0.0 < b < 180.0)
    for j in range(ng - 1):
        a, b = nodes[j], nodes[j + 1]
        edges = [a] + [v for v in brk if a < v < b] + [b]
        for lo, hi in zip(edges[:-1], edges[1:]):
            mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            xs = mid + half * x
            ws = half * w * math.radians(1.0) * np.sin(np.radians(xs))
            k0 = len(pts)
            pts.extend(xs)
            rows.append((j, k0, (b - xs) / h * ws))
            rows.append((j + 1, k0, (xs - a) / h * ws))
    m = np.zeros((ng, len(pts)))
    for j, k0, v in rows:
        m[j, k0:k0 + len(v)] += v
    return np.array(pts), m


def _quadrature_c(nc: int, n: int):
    if nc == 1:
        return np.zeros(1), np.full((1, 1), 2.0 * math.pi)
    d = 360.0 / nc
    x, w = _GL[n]
    xs = (np.arange(nc)[:, None] * d + 0.5 * d * (1.0 + x)[None, :]).ravel()  # cell i = [C_i, C_i+1]
    ws = np.tile(0.5 * d * w * math.radians(1.0), nc)
    cell = np.repeat(np.arange(nc), len(x))
    t = (xs - cell * d) / d
    m = np.zeros((nc, xs.size))
    m[cell, np.arange(xs.size)] += (1.0 - t) * ws
    m[(cell + 1) % nc, np.arange(xs.size)] += t * ws
    return xs, m


def sample_table(profile: Profile, ng: int = NG_DEFAULT, nc: Optional[int] = None, quad: int = QUAD) -> np.ndarray:
    """The (nc, ng) table of `profile` (hat-weighted node averages, module docstring): its exact
    flux is the profile's flux. nc defaults to 1 for an axial profile, NC_ASYMMETRIC otherwise."""
    if nc is None:
        nc = 1 if profile.axial else NC_ASYMMETRIC
    if ng < 2 or nc < 1:
        raise LuminaireError(f"a table needs ng >= 2 and nc >= 1, got ng = {ng}, nc = {nc}")
    gp, mg = _quadrature_gamma(ng, profile.breaks, quad)
    cp, mc = _quadrature_c(nc, quad)
    vals = profile(gp, cp)  # (npg, npc)
    num = mg @ vals @ mc.T  # (ng, nc)
    den = mg.sum(axis=1)[:, None] * mc.sum(axis=1)[None, :]
    table = (num / den).T
    return np.ascontiguousarray(np.maximum(table, 0.0))


def profile_flux(profile: Profile, ng: int = NG_DEFAULT, nc: Optional[int] = None, quad: int = QUAD) -> float:
    """The flux of a profile by the quadrature :func:`sample_table` uses (so, to rounding, the
    flux of its table; ies:normalize scales by it)."""
    if nc is None:
        nc = 1 if profile.axial else NC_ASYMMETRIC
    gp, mg = _quadrature_gamma(ng, profile.breaks, quad)
    cp, mc = _quadrature_c(nc, quad)
    return float(mg.sum(axis=0) @ profile(gp, cp) @ mc.sum(axis=0))


def table_intensity(candela, frame, directions) -> np.ndarray:
    """Bilinear table value toward world directions (n, 3) (per unit colour): numpy's reading of
    what the engine evaluates (tests, reports)."""
    t = np.asarray(candela, dtype=float)
    nc, ng = t.shape
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    local = d @ np.asarray(frame, dtype=float).T
    gamma = np.degrees(np.arccos(np.clip(-local[:, 2], -1.0, 1.0)))
    c = np.mod(np.degrees(np.arctan2(local[:, 1], local[:, 0])), 360.0)
    gj = gamma / 180.0 * (ng - 1)
    j0 = np.clip(np.floor(gj).astype(int), 0, ng - 2)
    fg = gj - j0
    if nc == 1:
        return t[0, j0] * (1 - fg) + t[0, j0 + 1] * fg
    ci = c / 360.0 * nc
    i0 = np.floor(ci).astype(int) % nc
    fc = ci - np.floor(ci)
    i1 = (i0 + 1) % nc
    v0 = t[i0, j0] * (1 - fg) + t[i0, j0 + 1] * fg
    v1 = t[i1, j0] * (1 - fg) + t[i1, j0 + 1] * fg
    return v0 * (1 - fc) + v1 * fc


# ----------------------------------------------------------------------------------------------
# frames and points
# ----------------------------------------------------------------------------------------------


def frame_from_axes(x_axis, y_axis, z_axis):
    """(frame, mirrored, irregular) from the images of the local axes (rows of a USD matrix):
    Gram-Schmidt from Z (the emission axis) then X; a mirroring transform (det < 0) keeps X and Z
    and reverses Y (the profile is mirrored in C to match: :func:`mirror_c`); `irregular` is True
    when the axes were not orthogonal (shear)."""
    x, y, z = (np.asarray(v, dtype=float) for v in (x_axis, y_axis, z_axis))
    lengths = [np.linalg.norm(v) for v in (x, y, z)]
    if min(lengths) <= 0 or not all(math.isfinite(v) for v in lengths):
        raise LuminaireError("the light's transform collapses an axis (zero scale)")
    xn, yn, zn = x / lengths[0], y / lengths[1], z / lengths[2]
    irregular = max(abs(xn @ yn), abs(xn @ zn), abs(yn @ zn)) > 1e-6
    mirrored = float(np.dot(np.cross(xn, yn), zn)) < 0
    ez = zn
    ex = xn - (xn @ ez) * ez
    if np.linalg.norm(ex) < 1e-9:
        ex = yn - (yn @ ez) * ez
    ex /= np.linalg.norm(ex)
    ey = np.cross(ez, ex)
    return np.stack([ex, ey, ez]), mirrored, irregular


def mirror_c(candela) -> np.ndarray:
    """The table of the mirror image about the local XZ plane: T'(C) = T(-C)."""
    t = np.asarray(candela)
    nc = t.shape[0]
    return np.ascontiguousarray(t[(-np.arange(nc)) % nc])


def rect_points(w: float, h: float, n_long: int = GRID_POINTS):
    """Stratified cell centres over a w x h rectangle centred at the origin in the XY plane
    (local units), equal weights."""
    m = max(w, h)
    nx = max(1, math.ceil(n_long * w / m - 1e-9))
    ny = max(1, math.ceil(n_long * h / m - 1e-9))
    xs = (np.arange(nx) + 0.5) / nx * w - w / 2
    ys = (np.arange(ny) + 0.5) / ny * h - h / 2
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    return pts, np.full(len(pts), 1.0 / len(pts))


def disk_points(r: float, n: int = GRID_POINTS):
    """Equal-area stratified points over a disk of radius r (Shirley-Chiu concentric map of an
    n x n grid of cell centres), equal weights."""
    u = (np.arange(n) + 0.5) / n * 2 - 1
    a, b = np.meshgrid(u, u, indexing="ij")
    a, b = a.ravel(), b.ravel()
    use_a = np.abs(a) > np.abs(b)
    rr = np.where(use_a, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(use_a, (math.pi / 4) * (b / a), (math.pi / 2) - (math.pi / 4) * (a / b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    pts = np.stack([r * rr * np.cos(phi), r * rr * np.sin(phi), np.zeros(a.size)], axis=1)
    return pts, np.full(len(pts), 1.0 / len(pts))


def line_points(length: float, radius: float = 0.0):
    """Midpoints of k equal segments of the local X axis (k >= 8, ~one per diameter, <= 64)."""
    k = CYLINDER_POINTS_MIN
    if radius > 0:
        k = int(min(CYLINDER_POINTS_MAX, max(CYLINDER_POINTS_MIN, math.ceil(length / (2 * radius)))))
    xs = (np.arange(k) + 0.5) / k * length - length / 2
    pts = np.stack([xs, np.zeros(k), np.zeros(k)], axis=1)
    return pts, np.full(k, 1.0 / k)


# ----------------------------------------------------------------------------------------------
# specs
# ----------------------------------------------------------------------------------------------


@dataclass
class LuminaireSpec:
    """One luminaire as the engine takes it, with where it came from.

    ``source``: the prim path or the config key (``lights[2]``); ``kind``: SphereLight,
    CylinderLight, RectLight, DiskLight or point (config); ``label``: the schedule's type text;
    ``ies``: the IES file or None and ``ies_mode`` 'absolute' | 'usdlux' (None without a file);
    ``group``: parts of one light (a coloured focus tint) share it and make one schedule row."""

    name: str
    kind: str
    source: str
    points: np.ndarray
    weights: np.ndarray
    frame: np.ndarray
    candela: np.ndarray
    colour: np.ndarray
    ies: Optional[str] = None
    ies_mode: Optional[str] = None
    count: int = 1
    notes: list = field(default_factory=list)
    label: str = ""
    group: Optional[str] = None

    def __post_init__(self):
        self.points = np.ascontiguousarray(np.asarray(self.points, dtype=np.float64).reshape(-1, 3))
        self.weights = np.ascontiguousarray(np.asarray(self.weights, dtype=np.float64).reshape(-1))
        self.frame = np.ascontiguousarray(np.asarray(self.frame, dtype=np.float64).reshape(3, 3))
        self.candela = np.ascontiguousarray(np.asarray(self.candela, dtype=np.float64))
        self.colour = np.ascontiguousarray(np.asarray(self.colour, dtype=np.float64).reshape(3))
        self.validate()

    def validate(self) -> None:
        where = f"luminaire {self.name} ({self.source})"
        if self.candela.ndim != 2 or self.candela.shape[1] < 2 or self.candela.shape[0] < 1:
            raise LuminaireError(f"{where}: candela must be (nc >= 1, ng >= 2), got {self.candela.shape}")
        if not (np.isfinite(self.candela).all() and (self.candela >= 0).all()):
            raise LuminaireError(f"{where}: candela must be finite and not negative")
        if len(self.points) == 0 or len(self.points) != len(self.weights):
            raise LuminaireError(f"{where}: {len(self.points)} points and {len(self.weights)} weights")
        if not (np.isfinite(self.points).all() and np.isfinite(self.weights).all() and (self.weights >= 0).all()):
            raise LuminaireError(f"{where}: points and weights must be finite, weights not negative")
        if abs(self.weights.sum() - 1.0) > 1e-9:
            raise LuminaireError(f"{where}: weights sum to {self.weights.sum():.12g}, not 1")
        f = self.frame
        if not (np.allclose(f @ f.T, np.eye(3), atol=1e-9) and np.linalg.det(f) > 0):
            raise LuminaireError(f"{where}: frame rows must be orthonormal and right-handed")
        if not (np.isfinite(self.colour).all() and (self.colour >= 0).all()):
            raise LuminaireError(f"{where}: colour must be finite and not negative")

    # --- what it emits ---------------------------------------------------------------------
    @property
    def table_flux(self) -> float:
        """The table's exact flux per unit colour (lm)."""
        return table_flux(self.candela)

    @property
    def flux(self) -> np.ndarray:
        """(3,) RGB flux: table flux x colour (lm, or W radiometric)."""
        return self.table_flux * self.colour

    @property
    def lumens(self) -> float:
        """Luminous flux, Rec.709 Y of the RGB flux, times nothing else (one luminaire)."""
        return float(self.flux @ Y_WEIGHTS)

    def intensity(self, world_directions) -> np.ndarray:
        """(n, 3) RGB intensity toward world directions (numpy; the engine's Luminaire.intensity
        evaluates the same bilinear table)."""
        return table_intensity(self.candela, self.frame, world_directions)[:, None] * self.colour[None, :]

    def scale_to_lumens(self, lumens: float) -> None:
        """Scale the colour so :attr:`lumens` is exactly `lumens`."""
        now = self.lumens
        if not now > 0:
            raise LuminaireError(f"luminaire {self.name} ({self.source}): emits no light to scale to {lumens:g} lm")
        self.colour = self.colour * (float(lumens) / now)

    def to_engine(self):
        """The engine's ``hirad._engine.Luminaire``."""
        from hirad import _engine
        args = (self.name, self.points, self.weights, self.frame, self.candela)
        try:
            return _engine.Luminaire(*args, np.ascontiguousarray(self.colour.reshape(1, 3)))
        except (ValueError, TypeError):
            return _engine.Luminaire(*args, np.ascontiguousarray(self.colour))


def scale_group_to_lumens(specs: Sequence[LuminaireSpec], lumens: float) -> None:
    """Scale all parts of one light together so their lumens sum to `lumens`."""
    total = sum(s.lumens for s in specs)
    if not total > 0:
        names = ", ".join(s.source for s in specs)
        raise LuminaireError(f"{names}: emits no light to scale to {lumens:g} lm")
    for s in specs:
        s.colour = s.colour * (float(lumens) / total)


def schedule(specs: Sequence[LuminaireSpec]) -> list[dict]:
    """The report's luminaire schedule: one row per luminaire type (same label, IES file, mode
    and lumens to 4 significant digits), keys type, count, lumens (per luminaire), ies, ies_mode,
    name (the names, comma-separated). Parts of one light (``group``) count as one luminaire."""
    lights: dict[str, dict] = {}
    order: list[str] = []
    for s in specs:
        key = s.group or s.name
        if key not in lights:
            lights[key] = {"type": s.label or s.kind, "lumens": 0.0, "ies": s.ies, "ies_mode": s.ies_mode,
                           "count": s.count, "name": key}
            order.append(key)
        lights[key]["lumens"] += s.lumens
    rows: list[dict] = []
    index: dict[tuple, dict] = {}
    for key in order:
        li = lights[key]
        sig = (li["type"], li["ies"], li["ies_mode"], float(f"{li['lumens']:.4g}"))
        if sig in index:
            row = index[sig]
            row["count"] += li["count"]
            row["name"] += ", " + li["name"]
            continue
        row = {"type": li["type"], "count": li["count"], "lumens": li["lumens"], "ies": li["ies"],
               "ies_mode": li["ies_mode"], "name": li["name"]}
        index[sig] = row
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------
# building a light's profile (shared by USD lights and config lights)
# ----------------------------------------------------------------------------------------------


@dataclass
class Shaping:
    """UsdLuxShapingAPI values as authored (None = not authored)."""

    cone_angle: Optional[float] = None
    cone_softness: float = 0.0
    focus: float = 0.0
    focus_tint: Optional[np.ndarray] = None
    ies_file: Optional[str] = None
    ies_angle_scale: float = 0.0
    ies_normalize: bool = False

    def shape_factor(self) -> Optional[Profile]:
        """The cone factor when the cone angle is authored, else None (focus: shaped_parts)."""
        out = None
        if self.cone_angle is not None:
            out = cone_factor(self.cone_angle, self.cone_softness)
        return out

    def cone_is_identity(self, upper_hemisphere: bool) -> bool:
        if self.cone_angle is None:
            return True
        s = min(1.0, max(0.0, self.cone_softness))
        start = self.cone_angle * (1.0 - s)
        return start >= (180.0 if upper_hemisphere else 90.0)

    def focus_active(self) -> bool:
        tint = np.zeros(3) if self.focus_tint is None else np.asarray(self.focus_tint, dtype=float)
        return self.focus > 0 and not np.all(tint == 1.0)

    def is_identity(self, upper_hemisphere: bool) -> bool:
        return self.ies_file is None and not self.focus_active() and self.cone_is_identity(upper_hemisphere)


def shaped_parts(base: Profile, base_colour: np.ndarray, shaping: Shaping, photometry=None,
                 ies_mode: str = "absolute") -> list[tuple[Profile, np.ndarray]]:
    """(profile, colour) parts of a shaped light: base (the light's own profile per unit
    colour) and base_colour (its L colour, RGB); with an IES file the mode decides (module
    docstring); then cone, then focus (a coloured tint gives two parts)."""
    colour = np.asarray(base_colour, dtype=float)
    prof = base
    if photometry is not None:
        ies = ies_profile(photometry, shaping.ies_angle_scale)
        if ies_mode == "absolute":
            prof = ies
        elif ies_mode == "usdlux":
            prof = base * ies
            if shaping.ies_normalize:
                shaped = profile_flux(prof)
                plain = profile_flux(base)
                if shaped > 0:
                    prof = prof.scaled(plain / shaped)
        else:
            raise LuminaireError(f"IES mode must be one of {', '.join(IES_MODES)}, got {ies_mode!r}")
    cone = shaping.shape_factor()
    if cone is not None:
        prof = prof * cone
    if not shaping.focus_active():
        return [(prof, colour)]
    tint = np.zeros(3) if shaping.focus_tint is None else np.clip(np.asarray(shaping.focus_tint, float), 0.0, 1.0)
    focused = prof * focus_factor(shaping.focus)
    if np.all(tint == tint[0]):
        t = float(tint[0])
        if t == 0.0:
            return [(focused, colour)]
        mixed = Profile(lambda g, c: t * prof(g, c) + (1 - t) * focused(g, c), prof.axial,
                        prof.breaks)
        return [(mixed, colour)]
    return [(prof, colour * tint), (focused, colour * (1.0 - tint))]


# ----------------------------------------------------------------------------------------------
# config point lights
# ----------------------------------------------------------------------------------------------


def rotate_xyz(degrees) -> np.ndarray:
    """USD's xformOp:rotateXYZ as a (3, 3) row-vector matrix (p' = p M: X first, then Y, then Z);
    its rows are the images of the local X, Y, Z axes."""
    def row_rot(axis, deg):
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        if axis == 0:
            return np.array([[1, 0, 0], [0, c, s], [0, -s, c]], dtype=float)
        if axis == 1:
            return np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]], dtype=float)
        return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]], dtype=float)
    rx, ry, rz = (float(v) for v in degrees)
    return row_rot(0, rx) @ row_rot(1, ry) @ row_rot(2, rz)


def frame_from_aim(aim=None, c0=None, up_axis: str = "Z") -> np.ndarray:
    """The frame whose -Z is `aim` (default: down the scene's up axis) and whose +X is `c0` made
    perpendicular to it (default world X, or world Y when aim is along X)."""
    up = np.array([0.0, 1.0, 0.0]) if up_axis == "Y" else np.array([0.0, 0.0, 1.0])
    a = -up if aim is None else np.asarray(aim, dtype=float)
    if not np.linalg.norm(a) > 0:
        raise LuminaireError("aim must be a non-zero direction")
    ez = -a / np.linalg.norm(a)
    if c0 is None:
        c = np.array([1.0, 0.0, 0.0])
        if np.linalg.norm(np.cross(c, ez)) < 1e-6:
            c = np.array([0.0, 1.0, 0.0])
    else:
        c = np.asarray(c0, dtype=float)
    ex = c - (c @ ez) * ez
    if not np.linalg.norm(ex) > 1e-9 * max(1.0, np.linalg.norm(c)):
        raise LuminaireError("c0 is parallel to aim: it cannot orient the C planes")
    ex /= np.linalg.norm(ex)
    return np.stack([ex, np.cross(ez, ex), ez])


def luminaires_from_config(lights, up_axis: str = "Z", ies_mode: str = "absolute",
                           warnings_out: Optional[list] = None) -> list[LuminaireSpec]:
    """LuminaireSpecs of the config's ``lights:`` (hirad.config.schema.LightConfig items, or
    anything with the same attributes). `up_axis` ('Y' or 'Z', the scene's) gives the default
    aim (straight down); `ies_mode` is photometry.ies_mode, used where a light gives none. IES
    warnings are appended to `warnings_out` (named by the light)."""
    import warnings as _w

    from .ies import IesWarning, read_ies

    out: list[LuminaireSpec] = []
    for i, lc in enumerate(lights):
        source = f"lights[{i}]"
        name = str(lc.name)
        if getattr(lc, "rotation", None) is not None:
            frame = rotate_xyz(lc.rotation)
            frame, _, _ = frame_from_axes(frame[0], frame[1], frame[2])
        else:
            frame = frame_from_aim(getattr(lc, "aim", None), getattr(lc, "c0", None), up_axis)
        colour = np.asarray(getattr(lc, "colour", (1.0, 1.0, 1.0)), dtype=float)
        intensity = getattr(lc, "intensity", None)
        flux = getattr(lc, "flux", None)
        ies_file = getattr(lc, "ies", None)
        mode = getattr(lc, "ies_mode", None) or ies_mode
        notes: list[str] = []
        if ies_file is not None:
            with _w.catch_warnings(record=True) as caught:
                _w.simplefilter("always", IesWarning)
                p = read_ies(ies_file)
            if warnings_out is not None:
                warnings_out.extend(f"{source} ({name}): IES file: {w.message}" for w in caught
                                    if issubclass(w.category, IesWarning))
            dimmer = 1.0 if intensity is None else float(intensity)
            shaping = Shaping(ies_file=str(ies_file), ies_normalize=True)
            parts = shaped_parts(isotropic(dimmer if mode == "usdlux" else 1.0), colour * (1.0 if mode == "usdlux"
                                 else dimmer), shaping, p, mode)
            label = f"point light (config), IES ({mode})"
        else:
            i0 = float(intensity) if intensity is not None else float(flux) / (4.0 * math.pi)
            parts = [(isotropic(i0), colour)]
            label = "point light (config), isotropic"
        (prof, col), = parts
        spec = LuminaireSpec(name=name, kind="point", source=source,
                             points=np.asarray(lc.position, dtype=float).reshape(1, 3), weights=np.ones(1),
                             frame=frame, candela=sample_table(prof), colour=col,
                             ies=None if ies_file is None else str(ies_file),
                             ies_mode=None if ies_file is None else mode, notes=notes, label=label)
        if flux is not None:
            if float(flux) == 0.0:
                spec.colour = spec.colour * 0.0
            else:
                spec.scale_to_lumens(float(flux))
            spec.notes.append(f"scaled to flux = {float(flux):g} lm")
        out.append(spec)
    return out


def with_config_lights(scene, config) -> list[LuminaireSpec]:
    """The scene's luminaires (hirad.usd.SceneArrays.luminaires) followed by the config's
    ``lights:`` (aimed by the scene's up axis, ``photometry.ies_mode`` where a light gives no
    mode); IES warnings of the config lights go to ``scene.warnings``."""
    specs = list(getattr(scene, "luminaires", []) or [])
    lights = list(getattr(config, "lights", []) or [])
    if lights:
        mode = config.photometry.ies_mode if getattr(config, "photometry", None) is not None else "absolute"
        specs += luminaires_from_config(lights, up_axis=getattr(scene, "up_axis", "Z"), ies_mode=mode,
                                        warnings_out=scene.warnings)
    return specs
