"""Clear glazing: how the transmittance of a clear glass pane falls with the angle of incidence.

The model
---------
A glazed opening passes a ray of light arriving at incidence angle theta (between the ray and
the pane's normal) with the directional transmittance

    tau(theta) = tau0 * r(cos theta),

tau0 the transmittance at normal incidence (the glazing's datasheet light transmittance, e.g.
0.88 for 6 mm clear float) and r the *relative* transmittance, 1 at normal incidence and 0 at
grazing incidence. Glass has no preferred azimuth, so r depends on cos(theta) alone, and the
pane transmits the same both ways (light going out through a window obeys the same law as light
coming in). Transmittance is a ratio of luminous fluxes: it has no unit.

The Tregenza-Sharples polynomial
--------------------------------
For clear glass, r is taken from the fit of P. Tregenza and S. Sharples, "Daylighting
Algorithms" (ETSU S 1350, 1993; IEA SHC Task 21 subtask C2), algorithm 2.34, "Directional
transmittance of clear glass". Their fit gives the absolute transmittance of 6 mm clear glass as
a quintic in c = cos(theta):

    T(c) = -0.028378 + 3.156075 c - 3.058376 c^2 - 1.428919 c^3 + 4.014235 c^4 - 1.775827 c^5

(:data:`TREGENZA_SHARPLES_COEFFS`, lowest power first). At normal incidence T(1) = 0.878810
(:data:`TREGENZA_SHARPLES_TAU0`), the light transmittance of 6 mm clear float. CIE 171:2006,
"Test cases to assess the accuracy of lighting computer programs", uses this formula for the
6 mm clear glazing of its daylight test cases 5.10 and 5.12 (see docs/daylight_cie171.md).

Here the curve is made relative and clamped:

    r(c) = clip(T(c) / T(1), 0, 1).

The clamp acts at both ends. Near grazing incidence T(c) < 0 for c < 0.0090 (theta > 89.48
degrees), an artefact of the fit, and r is held at 0 there. Near normal incidence the quintic
rises slightly above T(1): its slope at c = 1 is -0.0696, so it peaks at c = 0.959 (theta = 16.6
degrees) at T = 0.8802, 0.15 % above T(1), and comes back to T(1) at c = 0.910 (theta = 24.5
degrees). Real uncoated glass transmits a little *less* at every oblique angle than at normal
incidence, so the clamp holds r at 1 for theta < 24.5 degrees. That moves r by at most 0.0016,
well inside the accuracy of the fit. With the clamp, r is non-increasing in theta.

Sample values of r: 1 up to 24.5 degrees, then 0.997 at 30 degrees, 0.977 at 45, 0.912 at 60,
0.777 at 70, 0.482 at 80 and 0 at 90 degrees.

Diffuse (hemispherical) transmittance
-------------------------------------
Light that arrives from a uniform (Lambertian) hemisphere is transmitted in the proportion

    tau_d = integral over the hemisphere of tau(theta) cos(theta) d omega / pi
          = 2 integral_0^{pi/2} tau(theta) cos(theta) sin(theta) d theta
          = tau0 integral_0^1 r(c) 2c dc

(:func:`hemispherical_transmittance`). For the clamped curve above, tau_d / tau0 = 0.9165, so
6 mm clear glass with tau0 = 0.8788 has tau_d = 0.805 (the unclamped quintic gives 0.9167).
An angle-independent glass (r = 1) would have tau_d = tau0 exactly.

Validity
--------
The fit is for uncoated clear soda-lime glass of about 6 mm. For other thicknesses of clear
glass the *shape* of r changes little (it is mostly Fresnel reflection at the two faces), so
scaling r by the pane's own tau0 is the usual approximation. It does not describe coated
(low-e, solar control), laminated, tinted or multiple glazing; those need their own angular
data (e.g. from LBNL WINDOW/Optics). The curve is photometric (it describes visible light).

The engine's table
------------------
:func:`angular_table` samples r at cos(theta) = k / (n - 1), k = 0 .. n - 1 (91 values by
default). The C++ engine takes this table and interpolates it linearly in cos(theta). With
h = 1/90 the interpolation error is at most h^2 max|r''| / 8 = 1.2e-4 (max|r''| = 7.4) where r is
smooth. The two table intervals that hold a kink of the clamp add up to h |jump of r'| / 4 more:
1.0e-2 in the grazing interval (0 <= c <= 1/90; the actual error there peaks at 6e-3, and r
itself is below 0.01) and 2e-4 in the interval at 24.5 degrees.

Radiance's glass
----------------
Radiance's ``glass`` material is parameterised by its *transmissivity* tn, the fraction that
survives one pass through the glass body, not by its transmittance Tn. It computes the angular
behaviour from the Fresnel equations (refractive index 1.52) with multiple internal reflections,
not from this polynomial. For an uncoated pane the two are related by

    Tn = (1 - rn)^2 tn / (1 - rn^2 tn^2),      rn = ((n - 1) / (n + 1))^2 = 0.04258 for n = 1.52,

and inverting this gives

    tn = (sqrt((1 - rn)^4 + 4 rn^2 Tn^2) - (1 - rn)^2) / (2 rn^2 Tn)

(Radiance's ray/src/cal/cal/trans.cal). See :func:`radiance_transmissivity`. The Radiance
reference manual (and "Rendering with Radiance") gives it with the numbers worked out for n = 1.52:

    tn = (sqrt(0.8402528435 + 0.0072522239 Tn^2) - 0.9166530661) / 0.0036261119 / Tn,

so Tn = 0.88 gives tn = 0.9584. (The IES VE manual quotes the same formula with the third
constant cut to 0.916653006. That changes tn by 4e-4 relative at Tn = 0.2.) Use it only to
build a matching Radiance scene (bench/). The engine itself uses tau0 r(cos theta).
"""

from __future__ import annotations

import math

import numpy as np

#: a0 .. a5 of T(c) = sum a_k c^k, the absolute transmittance of 6 mm clear glass at
#: c = cos(incidence angle) (Tregenza and Sharples 1993, algorithm 2.34)
TREGENZA_SHARPLES_COEFFS = (-0.028378, 3.156075, -3.058376, -1.428919, 4.014235, -1.775827)

#: T(1): the normal transmittance of the glass the polynomial describes (6 mm clear float)
TREGENZA_SHARPLES_TAU0 = float(sum(TREGENZA_SHARPLES_COEFFS))

#: refractive index of soda-lime glass assumed by Radiance's ``glass`` material
GLASS_INDEX = 1.52


def _poly(c):
    """T(c), the raw (unclamped) Tregenza-Sharples quintic, by Horner's rule."""
    c = np.asarray(c, dtype=np.float64)
    t = np.zeros_like(c)
    for a in reversed(TREGENZA_SHARPLES_COEFFS):
        t = t * c + a
    return t


def relative_transmittance(cos_theta):
    """tau(theta) / tau(0) of clear glass at incidence cos(theta). Vectorised; cos_theta is
    clipped to [0, 1], and the result lies in [0, 1]. It is 1 at normal incidence (and up to
    24.5 degrees) and 0 at grazing incidence (see the module docstring)."""
    c = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
    return np.clip(_poly(c) / TREGENZA_SHARPLES_TAU0, 0.0, 1.0)


def angular_table(n: int = 91) -> np.ndarray:
    """r sampled at cos(theta) = k / (n - 1), k = 0 .. n - 1: the table the engine interpolates
    linearly in cos(theta). Entry 0 is grazing incidence (0) and entry n - 1 is normal
    incidence (1)."""
    n = int(n)
    if n < 2:
        raise ValueError(f"n = {n}: the table needs at least 2 entries (grazing and normal)")
    return relative_transmittance(np.arange(n, dtype=np.float64) / (n - 1))


def _curve_breakpoints() -> list[float]:
    """Where the clamped curve has kinks, in c: the root of T near grazing (r reaches 0) and
    the point below normal incidence where T comes back to T(1) (r reaches 1)."""
    a = np.array(TREGENZA_SHARPLES_COEFFS, dtype=np.float64)
    pts = []
    for shift in (0.0, TREGENZA_SHARPLES_TAU0):
        b = a.copy()
        b[0] -= shift
        roots = np.roots(b[::-1])
        pts += [float(r.real) for r in roots if abs(r.imag) < 1e-12 and 0.0 < r.real < 1.0 - 1e-9]
    return sorted(pts)


def hemispherical_transmittance(tau0: float, relative=None, panels: int = 64,
                                order: int = 16) -> float:
    """Diffuse transmittance tau0 * integral_0^1 r(c) 2c dc: the fraction of the light from a
    uniform hemisphere of directions that the glass transmits (2 integral tau(theta) cos(theta)
    sin(theta) d theta).

    ``relative`` is r (default :func:`relative_transmittance`), a vectorised callable of
    cos(theta). The integral is composite Gauss-Legendre in c (``panels`` equal panels of
    ``order`` nodes). For the default curve the panels are also split at its two kinks, which
    makes the rule exact to rounding. For any smooth r it converges fast."""
    tau0 = float(tau0)
    if not (math.isfinite(tau0) and 0.0 <= tau0 <= 1.0):
        raise ValueError(f"tau0 = {tau0!r}: a transmittance must be in [0, 1]")
    fn = relative_transmittance if relative is None else relative
    edges = set(np.linspace(0.0, 1.0, int(panels) + 1).tolist())
    if relative is None:
        edges.update(_curve_breakpoints())
    edges = np.array(sorted(edges))
    x, w = np.polynomial.legendre.leggauss(int(order))
    lo, hi = edges[:-1, None], edges[1:, None]
    c = 0.5 * (hi - lo) * x[None, :] + 0.5 * (hi + lo)
    wc = 0.5 * (hi - lo) * w[None, :]
    r = np.broadcast_to(np.asarray(fn(c), dtype=np.float64), c.shape)
    return tau0 * float(np.sum(r * 2.0 * c * wc))


def glass_reflectivity(index: float = GLASS_INDEX) -> float:
    """Single-surface normal reflectivity ((n - 1) / (n + 1))^2 of a dielectric of index n."""
    return ((index - 1.0) / (index + 1.0)) ** 2


def pane_transmittance(transmissivity, index: float = GLASS_INDEX):
    """Normal transmittance Tn = (1 - rn)^2 tn / (1 - rn^2 tn^2) of an uncoated pane whose body
    transmits the fraction tn per pass, with all internal reflections summed."""
    rn = glass_reflectivity(index)
    tn = np.asarray(transmissivity, dtype=np.float64)
    return (1.0 - rn) ** 2 * tn / (1.0 - (rn * tn) ** 2)


def radiance_transmissivity(transmittance, index: float = GLASS_INDEX):
    """The transmissivity tn that Radiance's ``glass`` needs for a pane of normal
    transmittance Tn (the inverse of :func:`pane_transmittance`). Radiance's trans.cal gives
    it as tn = (sqrt((1 - rn)^4 + 4 rn^2 Tn^2) - (1 - rn)^2) / (2 rn^2 Tn). Tn must be in
    (0, (1 - rn) / (1 + rn)]: an uncoated pane transmits at most that much (0.9183 for
    n = 1.52)."""
    rn = glass_reflectivity(index)
    tt = np.asarray(transmittance, dtype=np.float64)
    tmax = (1.0 - rn) / (1.0 + rn)
    if np.any(tt <= 0.0) or np.any(tt > tmax * (1.0 + 1e-12)):
        raise ValueError(f"transmittance {transmittance!r}: must be in (0, {tmax:.6f}] for an "
                         f"uncoated pane of index {index}")
    q = (1.0 - rn) ** 2
    return (np.sqrt(q * q + 4.0 * (rn * tt) ** 2) - q) / (2.0 * rn * rn * tt)
