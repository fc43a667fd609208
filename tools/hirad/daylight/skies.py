"""Sky luminance distributions: the 15 CIE general skies, the traditional CIE overcast sky and
the Perez all-weather sky, relative and absolute, and their horizontal illuminance.

Angles
------
A sky direction is given by its zenith angle ``theta`` (0 at the zenith, pi/2 at the horizon)
and its azimuth ``phi``, both in radians, with the sun at (``sun_zenith``, ``sun_azimuth``). The
azimuth origin and sense are the caller's (hirad.daylight.patches and hirad.daylight.sun use
north = 0, east = pi/2); only the difference phi - sun_azimuth enters. The angular distance
from a sky element to the sun is

    cos chi = cos(theta) cos(Z_s) + sin(theta) sin(Z_s) cos(phi - phi_s).

Units
-----
Luminance L in cd/m^2, illuminance E in lux (lm/m^2), irradiance in W/m^2, luminous efficacy
in lm/W. The horizontal illuminance of a sky is the cosine-weighted integral of its luminance
over the upper hemisphere,

    E_h = integral L(theta, phi) cos(theta) d omega,   d omega = sin(theta) d theta d phi,

(:func:`horizontal_illuminance`); a uniform sky of luminance L gives E_h = pi L.

Every sky here is an object with ``relative(theta, phi)`` (the luminance divided by a reference
luminance: the zenith's for the CIE skies, the model's own unnormalised value for Perez),
``scale`` (cd/m^2 per relative unit) and ``luminance(theta, phi) = scale * relative``. A CIE sky
is made absolute from its zenith luminance Lz or from a horizontal illuminance E_h
(Lz = E_h / (E_h/Lz), the ratio integrated once); a Perez sky is normalised so that its
horizontal illuminance is the diffuse luminous efficacy times the diffuse horizontal
irradiance (Perez et al. 1990, below). Below the horizon (theta > pi/2) every sky is 0: the
ground is a separate source (hirad.daylight.patches.ground_luminance).

The CIE general skies (ISO 15469:2004 / CIE S 011/E:2003)
----------------------------------------------------------
L(theta, phi) / Lz = f(chi) phi(theta) / (f(Z_s) phi(0)), with the gradation

    phi(Z) = 1 + a exp(b / cos Z)          (phi(pi/2) = 1: the horizon limit; phi(0) = 1 + a e^b)

and the scattering indicatrix

    f(chi) = 1 + c (exp(d chi) - exp(d pi/2)) + e cos^2 chi.

Six gradation groups (a, b) and six indicatrix groups (c, d, e) combine into the 15 types of
:data:`CIE_GENERAL_SKIES` (type: gradation group, indicatrix group):

    gradation  I (4.0, -0.70)   II (1.1, -0.8)   III (0.0, -1.0)
               IV (-1.0, -0.55) V (-1.0, -0.32)  VI (-1.0, -0.15)
    indicatrix 1 (0, -1.0, 0)   2 (2, -1.5, 0.15)   3 (5, -2.5, 0.30)
               4 (10, -3.0, 0.45)   5 (16, -3.0, 0.30)   6 (24, -2.8, 0.15)

    1 I.1  2 I.2  3 II.1  4 II.2  5 III.1  6 III.2  7 III.3  8 III.4
    9 IV.2  10 IV.3  11 IV.4  12 V.4  13 V.5  14 VI.5  15 VI.6

Sources: ISO 15469:2004 / CIE S 011/E:2003 Table 1, as tabulated by S. Darula and R. Kittler,
"CIE general sky standard defining luminance distributions", Proc. eSim 2002 (the six groups),
and cross-checked against the per-type parameter listing of the DigitalRune engine's
CieSkyParameters (types 1-15, identical values). Type 1 is the CIE standard overcast sky's
general-sky form (steep gradation, azimuthally uniform), types 12 and 13 the CIE standard
clear sky (low turbidity, polluted). Type 5 is the sky of uniform luminance: a = 0 makes
phi = 1 and c = e = 0 make f = 1, so L = Lz everywhere and E_h = pi Lz exactly.

The traditional CIE overcast sky (Moon and Spencer 1942; CIE 1955)
------------------------------------------------------------------
L(theta) = Lz (1 + 2 cos theta) / 3, azimuthally uniform; E_h = Lz 2 pi (1/2 + 2/3) / 3
= 7 pi / 9 Lz exactly.

The Perez all-weather sky (Perez, Seals and Michalsky 1993)
-----------------------------------------------------------
From the diffuse horizontal irradiance DHI, the direct normal irradiance DNI (W/m^2), the
solar zenith Z (radians) and the day of the year:

* sky clearness  eps = ((DHI + DNI) / DHI + 1.041 Z^3) / (1 + 1.041 Z^3), in 8 bins with
  bounds 1, 1.065, 1.230, 1.500, 1.950, 2.800, 4.500, 6.200 (bin 1 overcast ... bin 8 clear);
* sky brightness Delta = DHI m / E0n, m the relative optical air mass (Kasten 1966, as in
  Perez et al. 1990; pvlib.atmosphere.get_relative_airmass), E0n the extraterrestrial normal
  irradiance of the day (Spencer 1971 through pvlib.irradiance.get_extra_radiation,
  1367 W/m^2 solar constant);
* relative luminance lv(theta, gamma) = (1 + a exp(b / cos theta)) (1 + c exp(d gamma)
  + e cos^2 gamma), gamma the angle to the sun;
* each of a, b, c, d, e is x1 + x2 Z + Delta (x3 + x4 Z) with the bin's x1..x4
  (:data:`PEREZ_COEFFICIENTS`), except in bin 1 where c = exp((Delta (c1 + c2 Z))^c3) - c4 and
  d = -exp(Delta (d1 + d2 Z)) + d3 + Delta d4.

Coefficients: Perez, Seals and Michalsky, "All-weather model for sky luminance distribution -
preliminary configuration and validation", Solar Energy 50(3):235-245 (1993), Table 1, with the
erratum Solar Energy 51(5):423 (1993); cross-checked against the table in Radiance's
gendaylit.c (NREL/Radiance src/gen/gendaylit.c) and another independent listing (bin-wise
a1 column 1.3525, -1.2219, -1.1000, -0.5484, -0.6000, -1.0156, -1.0000, -1.0500).
Like gendaylit, Delta is held at >= 0.2 in bins 2-5 (1.065 < eps < 2.8), where the fitted
coefficients give unphysical (negative or exploding) distributions at very low brightness, and
cos theta is held at >= 0.01 near the horizon (the gradation term exp(b / cos theta) with b > 0
would diverge there).

Luminous efficacy (Perez, Ineichen, Seals, Michalsky and Stewart, "Modeling daylight
availability and irradiance components from direct and global irradiance", Solar Energy
44(5):271-289, 1990, Table 4), by the same eps bins, with W the atmospheric precipitable water
in cm (W = exp(0.07 Td - 0.075), Td the dew point in deg C, Perez 1990 eq. 3; 2 cm when unknown):

* diffuse  K_d = a + b W + c cos Z + d ln(Delta)            (lm/W, :data:`PEREZ_DIFFUSE_EFFICACY`)
* direct   K_b = max(0, a + b W + c exp(5.73 Z - 5) + d Delta)   (:data:`PEREZ_DIRECT_EFFICACY`)
* global   K_g = a + b W + c cos Z + d ln(Delta)            (:data:`PEREZ_GLOBAL_EFFICACY`)

Typical values: K_d ~ 110-125 lm/W for overcast skies, K_b ~ 90-105 lm/W for a high clear sun.
The sky is scaled so that its horizontal illuminance is E_vd = K_d DHI (lux); the sun's direct
normal illuminance is E_vb = K_b DNI (lux), returned apart (the sun is a separate source).

For many hours at once (hirad.daylight.annual's sky matrix), :func:`perez_bins`,
:func:`perez_parameters_array` and :func:`perez_efficacies_array` are the same formulas
elementwise over arrays, and :func:`perez_brightness` takes arrays too.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass

import numpy as np

# ---------------------------------------------------------------------------------------------
# Quadrature
# ---------------------------------------------------------------------------------------------


def _hemisphere_rule(n_mu: int, n_phi: int):
    """Nodes and weights for integral over the upper hemisphere of g(theta, phi) d omega:
    Gauss-Legendre in mu = cos(theta) on [0, 1] (d omega = d mu d phi) times the periodic
    trapezoid (equal steps, offset by half a step) in phi on [0, 2 pi)."""
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu = 0.5 * (x + 1.0)
    wmu = 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * (2.0 * math.pi / n_phi)
    wphi = np.full(n_phi, 2.0 * math.pi / n_phi)
    theta = np.arccos(mu)
    return theta[:, None], phi[None, :], (wmu[:, None] * wphi[None, :])


def hemisphere_integral(fn, weight_cos: bool = True, rtol: float = 1e-7,
                        start: tuple[int, int] = (32, 64), max_nodes: int = 4_000_000) -> float:
    """integral over the upper hemisphere of fn(theta, phi) [cos theta] d omega, adaptive.

    ``fn`` takes broadcastable arrays of zenith angles and azimuths (radians). The rule is
    Gauss-Legendre in cos(theta) times the periodic trapezoid in phi; both node counts are
    doubled until two successive estimates agree to ``rtol`` (relative). Smooth periodic
    integrands converge exponentially in phi; the circumsolar peak exp(d chi) has a kink at the
    sun (a cone), which the doubling resolves at second order. Raises RuntimeError when
    ``max_nodes`` is reached without convergence.
    """
    n_mu, n_phi = start
    prev = None
    while True:
        theta, phi, w = _hemisphere_rule(n_mu, n_phi)
        g = np.asarray(fn(theta, phi), dtype=np.float64)
        if weight_cos:
            g = g * np.cos(theta)
        val = float(np.sum(np.broadcast_to(g, w.shape) * w))
        if prev is not None and abs(val - prev) <= rtol * max(abs(val), 1e-300):
            return val
        prev = val
        n_mu, n_phi = 2 * n_mu, 2 * n_phi
        if n_mu * n_phi > max_nodes:
            raise RuntimeError(f"hemisphere_integral: no convergence to rtol={rtol:g} within "
                               f"{max_nodes} nodes (last estimate {val:.9g})")


def horizontal_illuminance(sky, rtol: float = 1e-7) -> float:
    """E_h = integral L cos(theta) d omega over the sky hemisphere (lux), of ``sky.luminance``."""
    return hemisphere_integral(sky.luminance, weight_cos=True, rtol=rtol)


def _cos_chi(theta, phi, sun_zenith, sun_azimuth):
    """cos of the angle between the sky element (theta, phi) and the sun (radians)."""
    c = (np.cos(theta) * math.cos(sun_zenith)
         + np.sin(theta) * math.sin(sun_zenith) * np.cos(phi - sun_azimuth))
    return np.clip(c, -1.0, 1.0)


# ---------------------------------------------------------------------------------------------
# CIE general skies
# ---------------------------------------------------------------------------------------------

_GRADATION = {"I": (4.0, -0.70), "II": (1.1, -0.8), "III": (0.0, -1.0),
              "IV": (-1.0, -0.55), "V": (-1.0, -0.32), "VI": (-1.0, -0.15)}
_INDICATRIX = {1: (0.0, -1.0, 0.0), 2: (2.0, -1.5, 0.15), 3: (5.0, -2.5, 0.30),
               4: (10.0, -3.0, 0.45), 5: (16.0, -3.0, 0.30), 6: (24.0, -2.8, 0.15)}
_TYPE_GROUPS = {1: ("I", 1), 2: ("I", 2), 3: ("II", 1), 4: ("II", 2), 5: ("III", 1),
                6: ("III", 2), 7: ("III", 3), 8: ("III", 4), 9: ("IV", 2), 10: ("IV", 3),
                11: ("IV", 4), 12: ("V", 4), 13: ("V", 5), 14: ("VI", 5), 15: ("VI", 6)}

#: type -> (a, b, c, d, e) of ISO 15469:2004 / CIE S 011/E:2003 (see the module docstring)
CIE_GENERAL_SKIES: dict[int, tuple[float, float, float, float, float]] = {
    t: _GRADATION[g] + _INDICATRIX[i] for t, (g, i) in _TYPE_GROUPS.items()}

#: type -> description (ISO 15469 Table 1)
CIE_SKY_DESCRIPTIONS = {
    1: "overcast, steep luminance gradation towards zenith, azimuthal uniformity (CIE standard overcast)",
    2: "overcast, steep luminance gradation and slight brightening towards the sun",
    3: "overcast, moderately graded with azimuthal uniformity",
    4: "overcast, moderately graded and slight brightening towards the sun",
    5: "sky of uniform luminance",
    6: "partly cloudy sky, no gradation towards zenith, slight brightening towards the sun",
    7: "partly cloudy sky, no gradation towards zenith, brighter circumsolar region",
    8: "partly cloudy sky, no gradation towards zenith, distinct solar corona",
    9: "partly cloudy, with the obscured sun",
    10: "partly cloudy, with brighter circumsolar region",
    11: "white-blue sky with distinct solar corona",
    12: "CIE standard clear sky, low illuminance turbidity",
    13: "CIE standard clear sky, polluted atmosphere",
    14: "cloudless turbid sky with broad solar corona",
    15: "white-blue turbid sky with broad solar corona",
}


def _check_sun(sun_zenith: float, sun_azimuth: float) -> None:
    if not (math.isfinite(sun_zenith) and 0.0 <= sun_zenith <= math.pi / 2):
        raise ValueError(f"sun_zenith = {sun_zenith!r} rad: must be in [0, pi/2] (sun above the horizon)")
    if not math.isfinite(sun_azimuth):
        raise ValueError(f"sun_azimuth = {sun_azimuth!r} rad: must be finite")


def _absolute_scale(sky, zenith_luminance, horizontal_illuminance_lux) -> float:
    if zenith_luminance is not None and horizontal_illuminance_lux is not None:
        raise ValueError("give zenith_luminance or horizontal_illuminance, not both")
    if horizontal_illuminance_lux is not None:
        e = float(horizontal_illuminance_lux)
        if not (math.isfinite(e) and e >= 0):
            raise ValueError(f"horizontal_illuminance = {e!r} lux: must be finite and >= 0")
        return e / sky.relative_horizontal_illuminance()
    lz = 1.0 if zenith_luminance is None else float(zenith_luminance)
    if not (math.isfinite(lz) and lz >= 0):
        raise ValueError(f"zenith_luminance = {lz!r} cd/m^2: must be finite and >= 0")
    return lz


class _Sky(abc.ABC):
    scale: float = 1.0

    @abc.abstractmethod
    def relative(self, theta, phi):
        """Luminance relative to the zenith's at zenith angle theta, azimuth phi (radians)."""

    def luminance(self, theta, phi):
        """Absolute luminance (cd/m^2) at zenith angle theta, azimuth phi (radians); 0 below
        the horizon."""
        return self.scale * self.relative(theta, phi)

    def relative_horizontal_illuminance(self) -> float:
        """integral relative(theta, phi) cos(theta) d omega (for a CIE sky: E_h / Lz, sr)."""
        if getattr(self, "_rel_eh", None) is None:
            self._rel_eh = hemisphere_integral(self.relative, weight_cos=True)
        return self._rel_eh

    @property
    def horizontal_illuminance(self) -> float:
        """E_h (lux) of the absolute sky."""
        return self.scale * self.relative_horizontal_illuminance()


class CIEGeneralSky(_Sky):
    """One of the 15 CIE general skies (ISO 15469:2004 / CIE S 011/E:2003).

    ``sky_type`` 1..15, or ``params`` (a, b, c, d, e) for a custom sky; ``sun_zenith`` and
    ``sun_azimuth`` in radians. Absolute from ``zenith_luminance`` Lz (cd/m^2, default 1, so
    luminance = relative) or ``horizontal_illuminance`` E_h (lux). ``relative`` is L/Lz.
    """

    def __init__(self, sky_type: int | None, sun_zenith: float, sun_azimuth: float = 0.0,
                 zenith_luminance: float | None = None,
                 horizontal_illuminance: float | None = None,
                 params: tuple[float, float, float, float, float] | None = None):
        if params is None:
            if sky_type not in CIE_GENERAL_SKIES:
                raise ValueError(f"sky_type = {sky_type!r}: the CIE general skies are types 1-15")
            params = CIE_GENERAL_SKIES[sky_type]
        self.sky_type = sky_type
        self.a, self.b, self.c, self.d, self.e = (float(v) for v in params)
        self.sun_zenith, self.sun_azimuth = float(sun_zenith), float(sun_azimuth)
        _check_sun(self.sun_zenith, self.sun_azimuth)
        self._rel_eh = None
        # normalisation so that relative(0, .) = 1: f(Z_s) phi(0)
        self._norm = self.indicatrix(self.sun_zenith) * self.gradation(0.0)
        self.scale = _absolute_scale(self, zenith_luminance, horizontal_illuminance)

    def gradation(self, zenith):
        """phi(Z) = 1 + a exp(b / cos Z); the horizon limit (cos Z -> 0+, b < 0) is 1."""
        cz = np.cos(np.asarray(zenith, dtype=np.float64))
        with np.errstate(divide="ignore", over="ignore"):
            ex = np.where(cz > 0.0, np.exp(self.b / np.where(cz > 0.0, cz, 1.0)),
                          0.0 if self.b < 0 else np.inf)
        return 1.0 + self.a * ex

    def indicatrix(self, chi):
        """f(chi) = 1 + c (exp(d chi) - exp(d pi/2)) + e cos^2 chi."""
        chi = np.asarray(chi, dtype=np.float64)
        return (1.0 + self.c * (np.exp(self.d * chi) - math.exp(self.d * math.pi / 2))
                + self.e * np.cos(chi) ** 2)

    def relative(self, theta, phi):
        theta = np.asarray(theta, dtype=np.float64)
        chi = np.arccos(_cos_chi(theta, phi, self.sun_zenith, self.sun_azimuth))
        v = self.indicatrix(chi) * self.gradation(theta) / self._norm
        return np.where(theta <= math.pi / 2, v, 0.0)

    @property
    def zenith_luminance(self) -> float:
        return self.scale


class CIEOvercastSky(_Sky):
    """The traditional CIE overcast sky L = Lz (1 + 2 cos theta) / 3 (Moon and Spencer 1942,
    CIE 1955), E_h = 7 pi / 9 Lz. Absolute from ``zenith_luminance`` (cd/m^2, default 1) or
    ``horizontal_illuminance`` (lux)."""

    #: E_h / Lz, closed form
    RELATIVE_HORIZONTAL_ILLUMINANCE = 7.0 * math.pi / 9.0

    def __init__(self, zenith_luminance: float | None = None,
                 horizontal_illuminance: float | None = None):
        self._rel_eh = self.RELATIVE_HORIZONTAL_ILLUMINANCE
        self.scale = _absolute_scale(self, zenith_luminance, horizontal_illuminance)

    def relative(self, theta, phi):
        theta = np.asarray(theta, dtype=np.float64)
        v = (1.0 + 2.0 * np.cos(theta)) / 3.0
        return np.broadcast_to(np.where(theta <= math.pi / 2, v, 0.0),
                               np.broadcast_shapes(np.shape(theta), np.shape(phi)))

    @property
    def zenith_luminance(self) -> float:
        return self.scale


# ---------------------------------------------------------------------------------------------
# Perez all-weather sky
# ---------------------------------------------------------------------------------------------

#: lower bounds of the 8 sky clearness bins (Perez 1990, 1993); bin 8 is eps >= 6.2
PEREZ_EPSILON_BINS = (1.0, 1.065, 1.230, 1.500, 1.950, 2.800, 4.500, 6.200)

#: bin (1..8) -> ((a1..a4), (b1..b4), (c1..c4), (d1..d4), (e1..e4)), Perez et al. 1993 Table 1
PEREZ_COEFFICIENTS = {
    1: ((1.3525, -0.2576, -0.2690, -1.4366), (-0.7670, 0.0007, 1.2734, -0.1233),
        (2.8000, 0.6004, 1.2375, 1.0000), (1.8734, 0.6297, 0.9738, 0.2809),
        (0.0356, -0.1246, -0.5718, 0.9938)),
    2: ((-1.2219, -0.7730, 1.4148, 1.1016), (-0.2054, 0.0367, -3.9128, 0.9156),
        (6.9750, 0.1774, 6.4477, -0.1239), (-1.5798, -0.5081, -1.7812, 0.1080),
        (0.2624, 0.0672, -0.2190, -0.4285)),
    3: ((-1.1000, -0.2515, 0.8952, 0.0156), (0.2782, -0.1812, -4.5000, 1.1766),
        (24.7219, -13.0812, -37.7000, 34.8438), (-5.0000, 1.5218, 3.9229, -2.6204),
        (-0.0156, 0.1597, 0.4199, -0.5562)),
    4: ((-0.5484, -0.6654, -0.2672, 0.7117), (0.7234, -0.6219, -5.6812, 2.6297),
        (33.3389, -18.3000, -62.2500, 52.0781), (-3.5000, 0.0016, 1.1477, 0.1062),
        (0.4659, -0.3296, -0.0876, -0.0329)),
    5: ((-0.6000, -0.3566, -2.5000, 2.3250), (0.2937, 0.0496, -5.6812, 1.8415),
        (21.0000, -4.7656, -21.5906, 7.2492), (-3.5000, -0.1554, 1.4062, 0.3988),
        (0.0032, 0.0766, -0.0656, -0.1294)),
    6: ((-1.0156, -0.3670, 1.0078, 1.4051), (0.2875, -0.5328, -3.8500, 3.3750),
        (14.0000, -0.9999, -7.1406, 7.5469), (-3.4000, -0.1078, -1.0750, 1.5702),
        (-0.0672, 0.4016, 0.3017, -0.4844)),
    7: ((-1.0000, 0.0211, 0.5025, -0.5119), (-0.3000, 0.1922, 0.7023, -1.6317),
        (19.0000, -5.0000, 1.2438, -1.9094), (-4.0000, 0.0250, 0.3844, 0.2656),
        (1.0468, -0.3788, -2.4517, 1.4656)),
    8: ((-1.0500, 0.0289, 0.4260, 0.3590), (-0.3250, 0.1156, 0.7781, 0.0025),
        (31.0625, -14.5000, -46.1148, 55.3750), (-7.2312, 0.4050, 13.3500, 0.6234),
        (1.5000, -0.6426, 1.8564, 0.5636)),
}

#: bin -> (a, b, c, d) of K_d = a + b W + c cos Z + d ln(Delta), lm/W (Perez 1990 Table 4)
PEREZ_DIFFUSE_EFFICACY = {
    1: (97.24, -0.46, 12.00, -8.91), 2: (107.22, 1.15, 0.59, -3.95),
    3: (104.97, 2.96, -5.53, -8.77), 4: (102.39, 5.59, -13.95, -13.90),
    5: (100.71, 5.94, -22.75, -23.74), 6: (106.42, 3.83, -36.15, -28.83),
    7: (141.88, 1.90, -53.24, -14.03), 8: (152.23, 0.35, -45.27, -7.98)}
#: bin -> (a, b, c, d) of K_b = max(0, a + b W + c exp(5.73 Z - 5) + d Delta), lm/W
PEREZ_DIRECT_EFFICACY = {
    1: (57.20, -4.55, -2.98, 117.12), 2: (98.99, -3.46, -1.21, 12.38),
    3: (109.83, -4.90, -1.71, -8.81), 4: (110.34, -5.84, -1.99, -4.56),
    5: (106.36, -3.97, -1.75, -6.16), 6: (107.19, -1.25, -1.51, -26.73),
    7: (105.75, 0.77, -1.26, -34.44), 8: (101.18, 1.58, -1.10, -8.29)}
#: bin -> (a, b, c, d) of K_g = a + b W + c cos Z + d ln(Delta), lm/W
PEREZ_GLOBAL_EFFICACY = {
    1: (96.63, -0.47, 11.50, -9.16), 2: (107.54, 0.79, 1.79, -1.19),
    3: (98.73, 0.70, 4.40, -6.95), 4: (92.72, 0.56, 8.36, -8.31),
    5: (86.73, 0.98, 7.10, -10.94), 6: (88.34, 1.39, 6.06, -7.60),
    7: (78.63, 1.47, 4.93, -11.37), 8: (99.65, 1.86, -4.46, -3.15)}


def perez_clearness(dni: float, dhi: float, sun_zenith: float) -> float:
    """Sky clearness eps = ((DHI + DNI)/DHI + 1.041 Z^3) / (1 + 1.041 Z^3), Z in radians."""
    k = 1.041 * sun_zenith ** 3
    return ((dhi + dni) / dhi + k) / (1.0 + k)


def perez_bin(epsilon: float) -> int:
    """The clearness bin 1..8 of eps (eps < 1 counts as bin 1)."""
    b = 1
    for i, lo in enumerate(PEREZ_EPSILON_BINS, start=1):
        if epsilon >= lo:
            b = i
    return b


def perez_bins(epsilon) -> np.ndarray:
    """:func:`perez_bin` of an array of eps: an int array of bins 1..8 (eps < 1 and NaN count as
    bin 1)."""
    e = np.asarray(epsilon, dtype=np.float64)
    b = np.ones(e.shape, dtype=np.int64)
    for i, lo in enumerate(PEREZ_EPSILON_BINS[1:], start=2):
        b[e >= lo] = i
    return b


def extraterrestrial_normal_irradiance(day_of_year):
    """E0n (W/m^2) of the day, Spencer (1971) via pvlib, solar constant 1367 W/m^2. A float for
    one day; an array of days gives an array (the same values, pvlib evaluates elementwise)."""
    import pvlib
    if np.ndim(day_of_year) == 0:
        return float(pvlib.irradiance.get_extra_radiation(int(day_of_year), solar_constant=1367.0,
                                                          method="spencer"))
    doy = np.asarray(day_of_year).astype(np.int64)
    return np.asarray(pvlib.irradiance.get_extra_radiation(doy, solar_constant=1367.0,
                                                           method="spencer"), dtype=np.float64)


def relative_airmass(sun_zenith):
    """Relative optical air mass, Kasten (1966) via pvlib (the formula of Perez et al. 1990).
    A float for one zenith angle (radians); an array gives an array."""
    import pvlib
    if np.ndim(sun_zenith) == 0:
        return float(pvlib.atmosphere.get_relative_airmass(math.degrees(sun_zenith),
                                                           model="kasten1966"))
    z = np.degrees(np.asarray(sun_zenith, dtype=np.float64))
    return np.asarray(pvlib.atmosphere.get_relative_airmass(z, model="kasten1966"),
                      dtype=np.float64)


def perez_brightness(dhi, sun_zenith, day_of_year):
    """Sky brightness Delta = DHI m / E0n (floats, or arrays of equal length)."""
    return dhi * relative_airmass(sun_zenith) / extraterrestrial_normal_irradiance(day_of_year)


def precipitable_water(dew_point: float | None) -> float:
    """W (cm) = exp(0.07 Td - 0.075) from the dew point Td (deg C), Perez 1990; 2 cm if None."""
    return 2.0 if dew_point is None else math.exp(0.07 * float(dew_point) - 0.075)


def perez_efficacies(epsilon: float, delta: float, sun_zenith: float, w: float = 2.0):
    """(K_d, K_b, K_g) luminous efficacies in lm/W of Perez et al. 1990 (see module docstring)."""
    b = perez_bin(epsilon)
    cz = math.cos(sun_zenith)
    ld = math.log(max(delta, 1e-12))
    a, bb, c, d = PEREZ_DIFFUSE_EFFICACY[b]
    kd = a + bb * w + c * cz + d * ld
    a, bb, c, d = PEREZ_DIRECT_EFFICACY[b]
    kb = max(0.0, a + bb * w + c * math.exp(5.73 * sun_zenith - 5.0) + d * delta)
    a, bb, c, d = PEREZ_GLOBAL_EFFICACY[b]
    kg = a + bb * w + c * cz + d * ld
    return kd, kb, kg


def _table(coefficients: dict) -> np.ndarray:
    """A per-bin coefficient dict as an array indexed by bin - 1."""
    return np.array([coefficients[b] for b in range(1, 9)], dtype=np.float64)


def perez_efficacies_array(epsilon, delta, sun_zenith, w=2.0):
    """:func:`perez_efficacies` elementwise over arrays of eps, Delta, Z (radians) and W (cm):
    (K_d, K_b, K_g) arrays in lm/W, the same formulas in the same order of operations."""
    eps = np.asarray(epsilon, dtype=np.float64)
    delta = np.asarray(delta, dtype=np.float64)
    z = np.asarray(sun_zenith, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    i = perez_bins(eps) - 1
    cz = np.cos(z)
    ld = np.log(np.where(1e-12 > delta, 1e-12, delta))       # max(delta, 1e-12)
    a, bb, c, d = _table(PEREZ_DIFFUSE_EFFICACY)[i].T
    kd = a + bb * w + c * cz + d * ld
    a, bb, c, d = _table(PEREZ_DIRECT_EFFICACY)[i].T
    kb = a + bb * w + c * np.exp(5.73 * z - 5.0) + d * delta
    kb = np.where(kb > 0.0, kb, 0.0)                          # max(0, K_b)
    a, bb, c, d = _table(PEREZ_GLOBAL_EFFICACY)[i].T
    kg = a + bb * w + c * cz + d * ld
    return kd, kb, kg


def perez_parameters(epsilon: float, delta: float, sun_zenith: float):
    """(a, b, c, d, e) of the Perez 1993 distribution for eps, Delta and Z (radians)."""
    b = perez_bin(epsilon)
    if 1.065 < epsilon < 2.8:
        delta = max(delta, 0.2)
    x = PEREZ_COEFFICIENTS[b]
    z = sun_zenith

    def lin(i):
        x1, x2, x3, x4 = x[i]
        return x1 + x2 * z + delta * (x3 + x4 * z)

    a, bb, e = lin(0), lin(1), lin(4)
    if b == 1:
        c1, c2, c3, c4 = x[2]
        d1, d2, d3, d4 = x[3]
        c = math.exp((delta * (c1 + c2 * z)) ** c3) - c4
        d = -math.exp(delta * (d1 + d2 * z)) + d3 + delta * d4
    else:
        c, d = lin(2), lin(3)
    return a, bb, c, d, e


def perez_parameters_array(epsilon, delta, sun_zenith) -> np.ndarray:
    """:func:`perez_parameters` elementwise over arrays of eps, Delta and Z (radians): an array
    (5, n) of a, b, c, d, e per element, with the same bin-1 forms of c and d and the same
    Delta >= 0.2 hold in bins 2-5."""
    eps = np.asarray(epsilon, dtype=np.float64).reshape(-1)
    delta = np.asarray(delta, dtype=np.float64).reshape(-1)
    z = np.asarray(sun_zenith, dtype=np.float64).reshape(-1)
    b = perez_bins(eps)
    delta = np.where((1.065 < eps) & (eps < 2.8) & (0.2 > delta), 0.2, delta)
    x = np.array([PEREZ_COEFFICIENTS[k] for k in range(1, 9)], dtype=np.float64)[b - 1]  # (n, 5, 4)
    out = x[:, :, 0].T + x[:, :, 1].T * z + delta * (x[:, :, 2].T + x[:, :, 3].T * z)
    one = b == 1
    if np.any(one):
        (c1, c2, c3, c4), (d1, d2, d3, d4) = PEREZ_COEFFICIENTS[1][2], PEREZ_COEFFICIENTS[1][3]
        dz, zz = delta[one], z[one]
        out[2, one] = np.exp((dz * (c1 + c2 * zz)) ** c3) - c4
        out[3, one] = -np.exp(dz * (d1 + d2 * zz)) + d3 + dz * d4
    return out


class PerezSky(_Sky):
    """The Perez all-weather sky from DNI and DHI (W/m^2), the sun and the day of year.

    ``sun_zenith``, ``sun_azimuth`` in radians (sun above the horizon); ``dew_point`` in deg C
    (for the precipitable water of the efficacy model; 2 cm when None). The sky's luminance
    integrates to E_h = K_d DHI (lux); ``direct_normal_illuminance`` is K_b DNI (lux), the sun's.
    Attributes: epsilon, delta, bin, params (a..e), diffuse_efficacy, direct_efficacy,
    global_efficacy (lm/W).
    """

    def __init__(self, dni: float, dhi: float, sun_zenith: float, sun_azimuth: float,
                 day_of_year: int, dew_point: float | None = None):
        dni, dhi = float(dni), float(dhi)
        if not (math.isfinite(dhi) and dhi > 0):
            raise ValueError(f"dhi = {dhi!r} W/m^2: the Perez sky needs a positive diffuse horizontal irradiance")
        if not (math.isfinite(dni) and dni >= 0):
            raise ValueError(f"dni = {dni!r} W/m^2: must be finite and >= 0")
        if not (1 <= int(day_of_year) <= 366):
            raise ValueError(f"day_of_year = {day_of_year!r}: must be 1..366")
        self.sun_zenith, self.sun_azimuth = float(sun_zenith), float(sun_azimuth)
        _check_sun(self.sun_zenith, self.sun_azimuth)
        self.dni, self.dhi, self.day_of_year = dni, dhi, int(day_of_year)
        self.epsilon = perez_clearness(dni, dhi, self.sun_zenith)
        self.delta = perez_brightness(dhi, self.sun_zenith, self.day_of_year)
        self.bin = perez_bin(self.epsilon)
        self.params = perez_parameters(self.epsilon, self.delta, self.sun_zenith)
        self.precipitable_water = precipitable_water(dew_point)
        self.diffuse_efficacy, self.direct_efficacy, self.global_efficacy = perez_efficacies(
            self.epsilon, self.delta, self.sun_zenith, self.precipitable_water)
        self.diffuse_horizontal_illuminance = self.diffuse_efficacy * dhi
        self.direct_normal_illuminance = self.direct_efficacy * dni
        self._rel_eh = None
        self.scale = self.diffuse_horizontal_illuminance / self.relative_horizontal_illuminance()

    def relative(self, theta, phi):
        """lv(theta, gamma), the model's unnormalised relative luminance."""
        a, b, c, d, e = self.params
        theta = np.asarray(theta, dtype=np.float64)
        cg = _cos_chi(theta, phi, self.sun_zenith, self.sun_azimuth)
        gamma = np.arccos(cg)
        ct = np.maximum(np.cos(theta), 0.01)
        v = (1.0 + a * np.exp(b / ct)) * (1.0 + c * np.exp(d * gamma) + e * cg * cg)
        return np.where(theta <= math.pi / 2, v, 0.0)


@dataclass(frozen=True)
class UniformSky(_Sky):
    """A sky of uniform luminance (cd/m^2); E_h = pi L."""

    luminance_value: float = 1.0

    def relative(self, theta, phi):
        theta = np.asarray(theta, dtype=np.float64)
        return np.broadcast_to(np.where(theta <= math.pi / 2, 1.0, 0.0),
                               np.broadcast_shapes(np.shape(theta), np.shape(phi)))

    @property
    def scale(self) -> float:  # type: ignore[override]
        return self.luminance_value

    def relative_horizontal_illuminance(self) -> float:
        return math.pi
