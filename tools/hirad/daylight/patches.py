"""Sky patches: Tregenza's 145 and Reinhart's MF:n subdivisions, with exact solid angles and
patch-mean luminances, and the ground hemisphere; directions in the scene's frame.

Tregenza's sky (P. R. Tregenza, "Subdivision of the sky hemisphere for luminance
measurements", Lighting Research and Technology 19(1):13-14, 1987) has 7 bands of 12 degrees of
altitude, [0, 12), [12, 24), ..., [72, 84), with 30, 30, 24, 24, 18, 12 and 6 patches, and a
polar cap above 84 degrees: 145 patches. Reinhart's subdivision MF:n (C. Reinhart, the
reinhart.cal / reinhartb.cal sky of Radiance; MF:1 is Tregenza) splits each band into n bands of
equal altitude and each of its patches into n in azimuth, and keeps one cap: the band height is
alpha = 90 / (7 n + 0.5) degrees and the cap's angular radius alpha / 2 (for n = 1: 12 and 6
degrees), so MF:n has 144 n^2 + 1 patches (MF:2 577, MF:4 2305).

Solid angles are exact from the band limits: a patch between altitudes h0 < h1 and azimuths
spanning dphi has Omega = dphi (sin h1 - sin h0); the cap 2 pi (1 - sin h0). They sum to 2 pi.
Their cosine-weighted solid angles (the horizontal illuminance a patch of unit luminance gives)
are dphi (sin^2 h1 - sin^2 h0) / 2, summing to pi.

A patch's luminance is its *mean* over the patch, integral L d omega / Omega, by Gauss-Legendre
quadrature in sin(altitude) (where d omega = d(sin h) d phi) and in azimuth inside every patch
(``order`` nodes each way), not the value at its centre: a patch holding the circumsolar peak
is brighter on average than at its centre, and sum L_i Omega_i then equals the continuous
integral of L over the sky to the quadrature's accuracy.

Conventions
-----------
Azimuth phi is measured from north (0) towards east (pi/2), the convention of
hirad.daylight.sun (pvlib/SPA); within each band patch j of n is centred at phi = 2 pi j / n, so
the first patch of every band faces north. Patches are ordered band by band from the horizon up,
the cap last.

The scene frame: hirad works in the stage's own coordinates (metres), and USD stages are Y-up
or Z-up (``upAxis``; hirad.usd.scene honours it and does not rotate). Here ``up`` is "Y"
(default: the UsdLux convention, and the shared living_room and classroom scenes are Y-up), "Z",
or a vector; ``north`` is a vector perpendicular to up, by default -Z for Y-up and +Y for Z-up,
and east = north x up (so +X is east for both defaults, and a right-handed frame). A direction
of altitude h and azimuth phi is cos h (cos phi north + sin phi east) + sin h up.

The ground: below the horizon a uniform hemisphere of luminance rho_g E_h / pi (a Lambertian
ground of reflectance rho_g, 0.2 by default, lit by the sky's (and sun's) horizontal
illuminance E_h), one patch of 2 pi sr looking straight down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

_TREGENZA_COUNTS = (30, 30, 24, 24, 18, 12, 6)


def frame(up="Y", north=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(up, north, east) unit vectors of the scene frame (see the module docstring)."""
    if isinstance(up, str):
        key = up.upper()
        if key == "Y":
            u = np.array([0.0, 1.0, 0.0])
            default_north = np.array([0.0, 0.0, -1.0])
        elif key == "Z":
            u = np.array([0.0, 0.0, 1.0])
            default_north = np.array([0.0, 1.0, 0.0])
        else:
            raise ValueError(f"up = {up!r}: must be 'Y', 'Z' or a vector")
    else:
        u = np.asarray(up, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0:
            raise ValueError(f"up = {up!r}: must be a finite non-zero vector")
        u = u / np.linalg.norm(u)
        helper = np.array([0.0, 0.0, -1.0]) if abs(u[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
        default_north = helper - np.dot(helper, u) * u
    n = default_north if north is None else np.asarray(north, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(n)):
        raise ValueError(f"north = {north!r}: must be finite")
    n = n - np.dot(n, u) * u
    if np.linalg.norm(n) < 1e-9:
        raise ValueError(f"north = {north!r}: must not be parallel to up")
    n = n / np.linalg.norm(n)
    e = np.cross(n, u)
    return u, n, e


def directions(altitude, azimuth, up="Y", north=None) -> np.ndarray:
    """Unit vectors (..., 3) of altitude/azimuth (radians; azimuth from north towards east)."""
    u, n, e = frame(up, north)
    alt = np.asarray(altitude, dtype=np.float64)[..., None]
    az = np.asarray(azimuth, dtype=np.float64)[..., None]
    return np.cos(alt) * (np.cos(az) * n + np.sin(az) * e) + np.sin(alt) * u


def altitude_azimuth(dirs, up="Y", north=None) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`directions`: (altitude, azimuth in [0, 2 pi)) in radians."""
    u, n, e = frame(up, north)
    d = np.asarray(dirs, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    alt = np.arcsin(np.clip(d @ u, -1.0, 1.0))
    az = np.mod(np.arctan2(d @ e, d @ n), 2 * math.pi)
    return alt, az


@dataclass
class SkyPatches:
    """A discretised sky hemisphere (arrays of length N, radians and steradians).

    ``alt_lo, alt_hi``: the band's altitude limits; ``az_center, az_width``: the patch's azimuth
    centre and extent (2 pi for the cap); ``altitude``: the centre's altitude (the middle of the
    band; pi/2 for the cap); ``solid_angle`` exact; ``cos_solid_angle`` = integral cos(theta)
    d omega over the patch (exact).
    """

    mf: int
    alt_lo: np.ndarray
    alt_hi: np.ndarray
    az_center: np.ndarray
    az_width: np.ndarray

    @property
    def count(self) -> int:
        return int(self.alt_lo.shape[0])

    @property
    def altitude(self) -> np.ndarray:
        mid = 0.5 * (self.alt_lo + self.alt_hi)
        return np.where(self.alt_hi >= math.pi / 2 - 1e-12, math.pi / 2, mid)

    @property
    def zenith(self) -> np.ndarray:
        return math.pi / 2 - self.altitude

    @property
    def solid_angle(self) -> np.ndarray:
        return self.az_width * (np.sin(self.alt_hi) - np.sin(self.alt_lo))

    @property
    def cos_solid_angle(self) -> np.ndarray:
        return self.az_width * 0.5 * (np.sin(self.alt_hi) ** 2 - np.sin(self.alt_lo) ** 2)

    def directions(self, up="Y", north=None) -> np.ndarray:
        """(N, 3) centre directions in the scene frame."""
        return directions(self.altitude, self.az_center, up, north)

    def quadrature(self, order: int = 8):
        """Per patch, ``order`` x ``order`` Gauss-Legendre nodes in (sin h, phi): arrays
        (N, order^2) of zenith angle, azimuth and weight (the weights of a patch sum to its
        solid angle)."""
        x, w = np.polynomial.legendre.leggauss(order)
        s0, s1 = np.sin(self.alt_lo)[:, None], np.sin(self.alt_hi)[:, None]
        s = s0 + (s1 - s0) * 0.5 * (x[None, :] + 1.0)           # (N, k)
        ws = (s1 - s0) * 0.5 * w[None, :]
        phi = (self.az_center[:, None] + self.az_width[:, None] * 0.5 * x[None, :])
        wp = self.az_width[:, None] * 0.5 * w[None, :]
        theta = np.arccos(np.clip(s, -1.0, 1.0))                 # zenith = pi/2 - altitude
        th = np.repeat(theta[:, :, None], order, axis=2).reshape(self.count, -1)
        ph = np.repeat(phi[:, None, :], order, axis=1).reshape(self.count, -1)
        ww = (ws[:, :, None] * wp[:, None, :]).reshape(self.count, -1)
        return th, ph, ww

    def mean_luminance(self, sky, order: int = 8) -> np.ndarray:
        """Each patch's mean luminance (cd/m^2), integral L d omega / Omega, of
        ``sky.luminance(theta, phi)`` (theta the zenith angle, phi azimuth from north)."""
        th, ph, ww = self.quadrature(order)
        return np.sum(sky.luminance(th, ph) * ww, axis=1) / self.solid_angle

    def horizontal_illuminance(self, luminance: np.ndarray) -> float:
        """E_h (lux) of patch luminances, each patch treated as uniform (exact cos weights)."""
        return float(np.sum(np.asarray(luminance) * self.cos_solid_angle))


def reinhart_patches(mf: int = 1) -> SkyPatches:
    """Reinhart's MF:``mf`` sky (MF:1 = Tregenza's 145 patches): 144 mf^2 + 1 patches."""
    if not isinstance(mf, (int, np.integer)) or mf < 1:
        raise ValueError(f"mf = {mf!r}: must be an integer >= 1")
    alpha = math.radians(90.0 / (7 * mf + 0.5))
    lo, hi, azc, azw = [], [], [], []
    for band, n0 in enumerate(_TREGENZA_COUNTS):
        for sub in range(mf):
            r = band * mf + sub
            n = n0 * mf
            width = 2 * math.pi / n
            lo.extend([r * alpha] * n)
            hi.extend([(r + 1) * alpha] * n)
            azc.extend([j * width for j in range(n)])
            azw.extend([width] * n)
    lo.append(7 * mf * alpha)
    hi.append(math.pi / 2)
    azc.append(0.0)
    azw.append(2 * math.pi)
    return SkyPatches(int(mf), np.array(lo), np.array(hi), np.array(azc), np.array(azw))


def tregenza_patches() -> SkyPatches:
    """Tregenza's 145 patches (= Reinhart MF:1)."""
    return reinhart_patches(1)


def patch_arrays(mf: int = 1, up="Y", north=None) -> tuple[np.ndarray, np.ndarray]:
    """(directions (N, 3), solid angles (N,)) of the MF:``mf`` sky in the scene frame."""
    p = reinhart_patches(mf)
    return p.directions(up, north), p.solid_angle


def ground_luminance(horizontal_illuminance: float, reflectance: float = 0.2) -> float:
    """Luminance (cd/m^2) of a Lambertian ground of ``reflectance`` under E_h (lux):
    rho_g E_h / pi."""
    r = float(reflectance)
    if not (math.isfinite(r) and 0.0 <= r <= 1.0):
        raise ValueError(f"ground reflectance = {reflectance!r}: must be in [0, 1]")
    return r * float(horizontal_illuminance) / math.pi


def ground_patch(horizontal_illuminance: float, reflectance: float = 0.2, up="Y", north=None):
    """The ground hemisphere as one patch: (direction (3,) straight down, solid angle 2 pi,
    luminance rho_g E_h / pi)."""
    u, _, _ = frame(up, north)
    return -u, 2 * math.pi, ground_luminance(horizontal_illuminance, reflectance)
