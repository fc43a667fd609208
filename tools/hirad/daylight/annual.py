"""Annual (climate-based) daylight: hourly sky matrices from a weather file, annual illuminance
from daylight coefficients, and the annual metrics (DA, sDA, ASE, UDI, EN 17037 daylight
provision) with a heat-map picture.

The sky matrix
--------------
:func:`sky_matrix` does what Radiance's gendaymtx does, with hirad's own sky models: for every
hour of a weather file (hirad.daylight.weather.Weather) it builds the Perez all-weather sky
(hirad.daylight.skies, Perez et al. 1993 distribution with the Perez et al. 1990 luminous
efficacies, precipitable water from the file's dew point) and stores its patch-mean luminance
(cd/m^2) over a Reinhart MF:n sky (hirad.daylight.patches; Tregenza = MF:1), plus one ground
patch. The result is an array ``values`` of shape (hours, N + 1):

* columns 0 .. N-1: the sky patches in hirad.daylight.patches' order (band by band from the
  horizon up, azimuth from north towards east, the zenith cap last);
* column N (``SkyMatrix.ground_index``): the ground, a uniform lower hemisphere of luminance
  rho_g E_h,global / pi, where E_h,global = E_vd + E_dn cos Z is the Perez global horizontal
  illuminance (diffuse E_vd = K_d DHI plus direct E_dn cos Z, E_dn = K_b DNI). The ground is
  always lit by sun and sky, whatever ``include_sun``/``include_sky`` say, because it stands
  for the ground's diffuse reflection, which no direct-sun pass covers; give
  ``ground_reflectance=0`` for a matrix without it. (Radiance puts its ground first, column 0;
  here it is last.)

Daylight coefficients multiply in the same column order: ``annual_illuminance(dc, sky)`` with
``dc`` of shape (points, N + 1) in lux per cd/m^2.

Which hours: an hour is *daytime* when the sun's centre is above the horizon (the apparent,
refraction-corrected zenith of hirad.daylight.sun < 90 degrees) and its DNI or DHI is > 0;
every other row is zero (twilight diffuse light with the sun below the horizon is dropped).
An hour with DHI = 0 but DNI > 0 has no sky (the Perez sky needs a diffuse part); its sun is
kept, with the efficacy of the clearest bin.

Time stamps: weather files label each hour by its end (EPW hour 1 and TMY3's 01:00 are the
hour 00:00-01:00), so by default (``timestamp_position="end"``) the sun, the day of the year
and the occupancy of an hour are taken at its middle, the label minus half an hour (as
gendaymtx takes the sun at the half hour). "start" and "center" are the other conventions.
Times are the file's own (standard time, no daylight saving for EPW/TMY3).

Normalisation: each hour's Perez distribution lv(theta, gamma) (the function of
skies.PerezSky.relative, with the parameters of skies.perez_parameters) is integrated over the
patches with the patches' own Gauss-Legendre nodes (SkyPatches.quadrature(order)); those nodes
tile the hemisphere, so their cosine-weighted sum is the horizontal illuminance of lv, and the
sky is scaled so that it equals E_vd = K_d DHI. This is the normalisation of skies.PerezSky
(which integrates adaptively, up to seconds an hour) done on the quadrature that the patch
means use anyway; the two agree to the quadrature's accuracy (the test suite checks a clear and
an overcast hour, and TMY3 hours against patch means on 48 x 48 nodes a patch).

How it is computed: all daytime hours at once with numpy, in blocks of hours (about 2^17
hour-node pairs a block, 2 MiB of scratch a thread; the blocks shared by up to two threads,
``threads``). Per node it is one arccos and one exp, for the indicatrix
1 + c exp(d gamma) + e cos^2 gamma, with cos gamma the dot product of the node's and the sun's
directions; the gradation 1 + a exp(b / max(cos theta, 0.01)) is evaluated once per distinct
zenith angle of the nodes. A TMY3 year on MF:1 at order 8 is about 4400 hours with a sky times
9280 nodes, 4 * 10^7 node evaluations. The rows are those of an hour-by-hour evaluation to
rounding (on a TMY3 year, within 3e-13 of the matrix's maximum for every patch set, option
and site tried).

The sun: with ``include_sun=True`` the sun's direct normal illuminance E_dn (lux) is put into
the sky patches so that sum_i L_i Omega_i over the sun's share equals E_dn (a small source of
illuminance E_dn seen as a patch of luminance E_dn / Omega). ``sun_spread=1`` (default) puts
it all into the patch that contains the sun's direction; ``sun_spread=k`` (2..4) spreads it
over the k patches whose centres are nearest to the sun, in shares proportional to the inverse
of the angle from the sun to each centre (the angle held at >= 0.001 rad), which smooths the
hour-to-hour jumps of a coarse sky. For exact direct-sun work (ASE, sun-only passes) use
``SkyMatrix.sun`` / :func:`sun_series`: the sun's unit direction per hour and E_dn.

Sun directions are in a world frame given by ``up`` and ``north``
(hirad.daylight.patches.frame): default here ``up="Z"`` (north +Y, east +X); pass ``up="Y"``
for a Y-up scene (north -Z by default, east +X) or vectors. A direction of altitude h and
azimuth phi (from north towards east) is cos h (cos phi north + sin phi east) + sin h up.

The metrics
-----------
E is an hourly illuminance matrix (hours x points, lux); ``occupied`` a boolean mask of the
hours (rows) that count. :func:`occupied_hours` makes the IES LM-83-12 default, 8:00 to 18:00
local (file) time every day: an hour counts when its middle lies in [8, 18), ten hours a day,
3650 in a 365-day year. Points may carry area weights (default equal); "fraction of points"
is then a fraction of the weight.

* daylight autonomy DA_x per point: the fraction of occupied hours with E >= x (300 lx);
* spatial daylight autonomy sDA_x/y%: the fraction of points whose DA_x >= y (0.5);
* annual sunlight exposure ASE_1000,250h (IES LM-83): from a direct-sun-only matrix, the
  fraction of points with E_direct > 1000 lx in more than 250 occupied hours (251 or more);
* useful daylight illuminance (Nabil and Mardaljevic 2005, with the 3000 lx upper limit):
  the fractions of occupied hours with E < 100 (fell short), 100 <= E <= 3000 (UDI-a,
  useful) and E > 3000 (exceeded) per point; the three add up to 1;
* EN 17037:2018 daylight provision by the illuminance method (Annex A, method 2): a room meets
  a level when, for at least half of the *daylight hours* (F_time = 50 %), the target
  illuminance E_T is reached on at least 50 % of the reference plane and the minimum target
  illuminance E_TM on at least 95 % of it (levels for vertical and inclined openings:
  minimum 300/100 lx, medium 500/300 lx, high 750/500 lx, :data:`EN17037_LEVELS`). What is
  implemented: the daylight hours are the half of the year's hours (4380 of 8760; half the
  rows, rounded down, in general) with the highest external diffuse horizontal illuminance,
  the reading the standard's daylight-factor method also uses (its median external diffuse
  illuminance E_v,d,med is the median of those 4380 hours) and the one ClimateStudio
  documents; ties go to the earlier hour. The diffuse illuminance is the Perez K_d DHI of the
  sky matrix (``SkyMatrix.diffuse_horizontal_illuminance``). For each daylight hour the
  area-weighted fraction of points with E >= E_T (>= E_TM) is compared with 50 % (95 %); the
  criterion is met when the hours that pass are at least 50 % of the daylight hours. A
  caller's own daylight-hour mask can be given instead.

Comparisons with fractions (sDA's 50 %, EN 17037's 50 % and 95 %) allow a relative 1e-12 for
rounding, so that e.g. 19 of 20 equal points count as 95 %.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from . import patches as _patches
from . import skies as _skies

# ---------------------------------------------------------------------------------------------
# time stamps
# ---------------------------------------------------------------------------------------------

_POSITIONS = {"end": -0.5, "start": 0.5, "center": 0.0, "centre": 0.0}


def sample_times(times, timestamp_position: str = "end", step_minutes: float = 60.0):
    """The middle of each interval (a pandas DatetimeIndex): the labels shifted by half a step
    back ("end": labels mark the interval's end, the weather-file convention), forward
    ("start") or not at all ("center")."""
    import pandas as pd

    if timestamp_position not in _POSITIONS:
        raise ValueError(f"timestamp_position = {timestamp_position!r}: 'end', 'start' or 'center'")
    if not (math.isfinite(step_minutes) and step_minutes > 0):
        raise ValueError(f"step_minutes = {step_minutes!r}: must be > 0")
    idx = pd.DatetimeIndex(times)
    return idx + pd.Timedelta(minutes=_POSITIONS[timestamp_position] * step_minutes)


def occupied_hours(times, start_hour: float = 8.0, end_hour: float = 18.0, weekdays=None,
                   timestamp_position: str = "end", step_minutes: float = 60.0) -> np.ndarray:
    """Boolean mask of the occupied hours: the interval's middle (see :func:`sample_times`),
    in the times' own zone, has a clock time in [start_hour, end_hour) and (when ``weekdays``
    is given, a collection of 0 = Monday .. 6 = Sunday) falls on one of those days. The default
    is IES LM-83's 8:00-18:00 every day (10 hours a day)."""
    if not (0.0 <= start_hour <= 24.0 and 0.0 <= end_hour <= 24.0 and start_hour < end_hour):
        raise ValueError(f"occupied hours [{start_hour!r}, {end_hour!r}): need 0 <= start < end <= 24")
    mid = sample_times(times, timestamp_position, step_minutes)
    clock = (mid.hour.to_numpy() + mid.minute.to_numpy() / 60.0
             + mid.second.to_numpy() / 3600.0)
    mask = (clock >= start_hour) & (clock < end_hour)
    if weekdays is not None:
        days = {int(d) for d in weekdays}
        if not days <= set(range(7)):
            raise ValueError(f"weekdays = {weekdays!r}: 0 (Monday) .. 6 (Sunday)")
        mask &= np.isin(mid.day_of_week.to_numpy(), sorted(days))
    return mask


# ---------------------------------------------------------------------------------------------
# hourly sun and Perez quantities
# ---------------------------------------------------------------------------------------------


@dataclass
class SunSeries:
    """Per hour of a weather file (arrays of length H): the sun and the Perez illuminances.

    ``times``: the file's labels; ``sample_times``: the instants used (interval middles);
    ``zenith``, ``azimuth``: apparent topocentric sun angles in degrees (azimuth from north
    towards east); ``daytime``: sun above the horizon and DNI or DHI > 0; ``direction``:
    (H, 3) unit vectors towards the sun in the (up, north) frame, zero rows at night;
    ``direct_normal_illuminance`` E_dn = K_b DNI and ``diffuse_horizontal_illuminance``
    E_vd = K_d DHI (lux, 0 at night); ``clearness``, ``brightness``, ``sky_bin``: Perez's
    eps, Delta and bin (NaN/0 at night); ``precipitable_water`` (cm); ``up``, ``north``,
    ``east``: the frame's unit vectors.
    """

    times: object
    sample_times: object
    zenith: np.ndarray
    azimuth: np.ndarray
    daytime: np.ndarray
    direction: np.ndarray
    direct_normal_illuminance: np.ndarray
    diffuse_horizontal_illuminance: np.ndarray
    clearness: np.ndarray
    brightness: np.ndarray
    sky_bin: np.ndarray
    precipitable_water: np.ndarray
    up: np.ndarray
    north: np.ndarray
    east: np.ndarray

    @property
    def hours(self) -> int:
        return int(self.zenith.shape[0])

    @property
    def direct_horizontal_illuminance(self) -> np.ndarray:
        """E_dn cos Z (lux)."""
        cz = np.where(self.daytime, np.cos(np.radians(self.zenith)), 0.0)
        return self.direct_normal_illuminance * np.maximum(cz, 0.0)

    @property
    def global_horizontal_illuminance(self) -> np.ndarray:
        """E_vd + E_dn cos Z (lux)."""
        return self.diffuse_horizontal_illuminance + self.direct_horizontal_illuminance


def _clean(a, n: int, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    if a.shape[0] != n:
        raise ValueError(f"weather {name}: {a.shape[0]} values for {n} time stamps")
    if np.any(a < 0):
        raise ValueError(f"weather {name}: negative irradiance at row {int(np.argmax(a < 0))}")
    return np.where(np.isfinite(a), a, 0.0)


def _site_of(weather, site):
    from .sun import Site

    if site is not None:
        return site
    return Site(float(weather.latitude), float(weather.longitude), float(weather.elevation),
                float(weather.timezone))


def sun_series(weather, site=None, up="Z", north=None, timestamp_position: str = "end",
               step_minutes: float = 60.0) -> SunSeries:
    """Sun positions (hirad.daylight.sun, SPA) and Perez illuminances for every hour of
    ``weather`` (a hirad.daylight.weather.Weather, or anything with ``times``, ``dni``,
    ``dhi``, ``dew_point`` and, when ``site`` is None, latitude/longitude/elevation/timezone).
    See the module docstring for the conventions."""
    from .sun import sun_positions

    site = _site_of(weather, site)
    times = weather.times
    n = len(times)
    dni = _clean(weather.dni, n, "dni")
    dhi = _clean(weather.dhi, n, "dhi")
    dew = np.asarray(getattr(weather, "dew_point", np.full(n, np.nan)), dtype=np.float64).reshape(-1)
    if dew.shape[0] != n:
        raise ValueError(f"weather dew_point: {dew.shape[0]} values for {n} time stamps")
    mid = sample_times(times, timestamp_position, step_minutes)
    if mid.tz is None:
        mid = mid.tz_localize(site.tzinfo())
    zen, azi = sun_positions(site, mid)
    zen = np.asarray(zen, dtype=np.float64)
    azi = np.asarray(azi, dtype=np.float64)
    daytime = (zen < 90.0) & ((dni > 0) | (dhi > 0))
    doy = mid.day_of_year.to_numpy()

    u, nv, e = _patches.frame(up, north)
    direction = np.zeros((n, 3))
    direction[daytime] = _patches.directions(np.radians(90.0 - zen[daytime]),
                                             np.radians(azi[daytime]), up, north)
    e_dn = np.zeros(n)
    e_vd = np.zeros(n)
    eps = np.full(n, np.nan)
    delta = np.full(n, np.nan)
    sky_bin = np.zeros(n, dtype=np.int64)
    water = np.full(n, np.nan)
    # the Perez quantities of all daytime hours at once (skies' array variants: the same
    # formulas, elementwise)
    day = np.flatnonzero(daytime)
    z = np.radians(zen[day])
    dw = dew[day]
    w = np.full(day.size, 2.0)                       # skies.precipitable_water(None)
    known = np.isfinite(dw)
    w[known] = np.exp(0.07 * dw[known] - 0.075)
    water[day] = w
    lit = dhi[day] > 0
    eps_d = np.full(day.size, math.inf)              # a beam without diffuse light: the
    delta_d = np.zeros(day.size)                     # clearest bin, no brightness
    eps_d[lit] = _skies.perez_clearness(dni[day][lit], dhi[day][lit], z[lit])
    delta_d[lit] = _skies.perez_brightness(dhi[day][lit], z[lit], doy[day][lit])
    eps[day], delta[day] = eps_d, delta_d
    sky_bin[day] = _skies.perez_bins(eps_d)
    kd, kb, _ = _skies.perez_efficacies_array(eps_d, delta_d, z, w)
    e_vd[day] = np.where(0.0 > kd, 0.0, kd) * dhi[day]  # max(K_d, 0) DHI
    e_dn[day] = kb * dni[day]
    return SunSeries(times, mid, zen, azi, daytime, direction, e_dn, e_vd, eps, delta, sky_bin,
                     water, u, nv, e)


# ---------------------------------------------------------------------------------------------
# the sky matrix
# ---------------------------------------------------------------------------------------------


@dataclass
class SkyMatrix:
    """Hourly sky vectors: ``values`` (H, N + 1) in cd/m^2, sky patches then the ground (column
    ``ground_index`` = N); ``patches`` the SkyPatches; ``sun`` the SunSeries (times, daytime,
    sun directions and illuminances); ``ground_reflectance``; ``include_sky``,
    ``include_sun``, ``sun_spread``, ``order`` as built; ``skipped``: daytime rows whose sky
    could not be normalised (non-positive integral), left without sky."""

    values: np.ndarray
    patches: _patches.SkyPatches
    sun: SunSeries
    ground_reflectance: float
    include_sky: bool
    include_sun: bool
    sun_spread: int
    order: int
    skipped: list = field(default_factory=list)

    @property
    def times(self):
        return self.sun.times

    @property
    def daytime(self) -> np.ndarray:
        return self.sun.daytime

    @property
    def ground_index(self) -> int:
        return self.patches.count

    @property
    def diffuse_horizontal_illuminance(self) -> np.ndarray:
        return self.sun.diffuse_horizontal_illuminance

    @property
    def global_horizontal_illuminance(self) -> np.ndarray:
        return self.sun.global_horizontal_illuminance

    @property
    def direct_normal_illuminance(self) -> np.ndarray:
        return self.sun.direct_normal_illuminance

    def sun_directions(self) -> np.ndarray:
        """(H, 3) unit vectors towards the sun (zero rows at night)."""
        return self.sun.direction


def _as_patches(p) -> _patches.SkyPatches:
    if isinstance(p, _patches.SkyPatches):
        return p
    if isinstance(p, str):
        key = p.strip().lower()
        if key == "tregenza":
            return _patches.tregenza_patches()
        if key.startswith("mf:") or key.startswith("mf"):
            return _patches.reinhart_patches(int(key.split(":")[-1] if ":" in key else key[2:]))
        raise ValueError(f"patches = {p!r}: 'tregenza', 'MF:n', an integer n or a SkyPatches")
    return _patches.reinhart_patches(p)


def _containing_patch(p: _patches.SkyPatches, altitude: float, azimuth: float) -> int:
    """Index of the patch whose band and azimuth range hold the direction (radians)."""
    top = p.alt_hi >= math.pi / 2 - 1e-12
    in_band = (altitude >= p.alt_lo) & ((altitude < p.alt_hi) | top)
    d = np.mod(azimuth - p.az_center + math.pi, 2 * math.pi) - math.pi
    hit = np.flatnonzero(in_band & (np.abs(d) <= 0.5 * p.az_width + 1e-12))
    if hit.size == 0:  # below the lowest band by rounding: the nearest centre
        return int(np.argmax(p.directions("Z") @ _patches.directions(altitude, azimuth, "Z")))
    return int(hit[0])


def sun_patch_shares(p: _patches.SkyPatches, altitude: float, azimuth: float,
                     spread: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(patch indices, shares summing to 1) that receive the sun at altitude/azimuth (radians):
    the containing patch for ``spread`` = 1, else the ``spread`` nearest patch centres with
    shares proportional to 1 / max(angle to the centre, 0.001 rad)."""
    if spread == 1:
        return np.array([_containing_patch(p, altitude, azimuth)]), np.array([1.0])
    if not (isinstance(spread, (int, np.integer)) and 1 <= spread <= 4):
        raise ValueError(f"sun_spread = {spread!r}: 1, 2, 3 or 4 patches")
    s = _patches.directions(altitude, azimuth, "Z")
    ang = np.arccos(np.clip(p.directions("Z") @ s, -1.0, 1.0))
    idx = np.argsort(ang, kind="stable")[:spread]
    w = 1.0 / np.maximum(ang[idx], 1e-3)
    return idx, w / w.sum()


#: (hour, patch or quadrature node) pairs per block of the vectorised sky matrix: 2^17 float64
#: values are 1 MiB an array, small enough to stay in cache
_BLOCK = 1 << 17


def _sun_patch_shares_many(p: _patches.SkyPatches, altitude: np.ndarray, azimuth: np.ndarray,
                           spread: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sun_patch_shares` for H suns at once: (H, spread) patch indices and shares."""
    altitude = np.asarray(altitude, dtype=np.float64)
    azimuth = np.asarray(azimuth, dtype=np.float64)
    h = altitude.shape[0]
    idx = np.zeros((h, spread), dtype=np.int64)
    share = np.ones((h, spread))
    step = max(1, _BLOCK // p.count)
    if spread == 1:
        top = p.alt_hi >= math.pi / 2 - 1e-12
        for r0 in range(0, h, step):
            al, az = altitude[r0:r0 + step, None], azimuth[r0:r0 + step, None]
            in_band = (al >= p.alt_lo) & ((al < p.alt_hi) | top)
            d = np.mod(az - p.az_center + math.pi, 2 * math.pi) - math.pi
            hit = in_band & (np.abs(d) <= 0.5 * p.az_width + 1e-12)
            first = np.argmax(hit, axis=1)
            for k in np.flatnonzero(~hit[np.arange(first.shape[0]), first]):
                first[k] = _containing_patch(p, float(al[k, 0]), float(az[k, 0]))  # no hit
            idx[r0:r0 + step, 0] = first
        return idx, share
    centres = p.directions("Z")
    for r0 in range(0, h, step):
        s = _patches.directions(altitude[r0:r0 + step], azimuth[r0:r0 + step], "Z")
        ang = np.arccos(np.clip(s @ centres.T, -1.0, 1.0))
        near = np.argsort(ang, axis=1, kind="stable")[:, :spread]
        w = 1.0 / np.maximum(np.take_along_axis(ang, near, axis=1), 1e-3)
        idx[r0:r0 + step] = near
        share[r0:r0 + step] = w / w.sum(axis=1, keepdims=True)
    return idx, share


class _PatchQuadrature:
    """The patches' Gauss-Legendre nodes (SkyPatches.quadrature) arranged for evaluating the
    Perez distribution of many hours at once.

    Patch p has order x order nodes (i, j): i runs over ``order`` zenith angles theta_pi (nodes
    in sin h), j over ``order`` azimuths, with weights ws_pi wp_pj, wp_pj = (dphi_p / 2) w_j
    (w_j the Gauss-Legendre weights). lv = G(theta) F(gamma) is the gradation G = 1 + a
    exp(b / max(cos theta, 0.01)) times the indicatrix F = 1 + c exp(d gamma) + e cos^2 gamma,
    so a patch's integral of lv is sum_i G(theta_pi) ws_pi (dphi_p / 2) sum_j w_j F_pij. G is
    evaluated once per distinct theta (order x bands of them), F at every node; cos gamma is
    the dot product of the node's and the sun's unit vectors, components (up, north, east)."""

    def __init__(self, p: _patches.SkyPatches, order: int):
        th, ph, _ = p.quadrature(order)
        n, k = p.count, int(order)
        self.count, self.order = n, k
        self.gl_weights = np.polynomial.legendre.leggauss(k)[1]
        theta = th.reshape(n, k, k)[:, :, 0]                                  # (N, k): theta_pi
        s0, s1 = np.sin(p.alt_lo)[:, None], np.sin(p.alt_hi)[:, None]
        ws = (s1 - s0) * 0.5 * self.gl_weights[None, :]
        self.row_weight = ws * (0.5 * p.az_width)[:, None]                     # ws_pi dphi_p / 2
        self._row_cos = np.cos(theta).reshape(-1)                             # cos theta_pi
        self._ones = np.ones(k)
        self.theta, inverse = np.unique(theta.reshape(-1), return_inverse=True)
        self.row_of_theta = inverse.reshape(-1)                               # (N k,) -> distinct
        self.gradation_cos = np.maximum(np.cos(self.theta), 0.01)
        st, ct = np.sin(th).reshape(-1), np.cos(th).reshape(-1)
        self.nodes = (ct, st * np.cos(ph.reshape(-1)), st * np.sin(ph.reshape(-1)))
        self.node_count = n * k * k

    def workspace(self, hours: int) -> np.ndarray:
        """Scratch for :meth:`integrals` of up to ``hours`` hours (one per thread)."""
        return np.empty((2, hours * self.node_count))

    def integrals(self, zenith, azimuth, params, rows: slice, work: np.ndarray):
        """For the hours ``rows`` of zenith, azimuth (radians) and params (5, H): the integral
        of lv over each patch, sum_nodes lv w (h, N), and its horizontal illuminance
        sum_nodes lv cos(theta) w (h,). ``work``: a :meth:`workspace` of at least h hours;
        the (hours x nodes) arrays are computed in place there (fresh MiB-sized temporaries
        at every step, each a new memory mapping to fault in, took twice as long)."""
        z, az = zenith[rows, None], azimuth[rows, None]
        a, b, c, d, e = (params[q, rows, None] for q in range(5))
        h, k, n = z.shape[0], self.order, self.count
        m = h * self.node_count
        cg, f = work[0, :m].reshape(h, -1), work[1, :m].reshape(h, -1)
        # cos gamma = cos theta cos Z + sin theta sin Z cos(phi - phi_s), clipped as skies does
        sz = np.sin(z)
        np.multiply(self.nodes[0], np.cos(z), out=cg)
        np.multiply(self.nodes[1], sz * np.cos(az), out=f)
        cg += f
        np.multiply(self.nodes[2], sz * np.sin(az), out=f)
        cg += f
        np.clip(cg, -1.0, 1.0, out=cg)
        # F = 1 + c exp(d gamma) + e cos^2 gamma at every node
        np.arccos(cg, out=f)
        f *= d
        np.exp(f, out=f)
        f *= c
        f += 1.0
        np.square(cg, out=cg)
        cg *= e
        f += cg
        # sum_j w_j F_pij, then the gradation at the distinct zenith angles on every (p, i) row
        fj = np.matmul(f.reshape(-1, k), self.gl_weights, out=cg.reshape(-1)[:m // k])
        g = b / self.gradation_cos
        np.exp(g, out=g)
        g *= a
        g += 1.0
        q = np.take(g, self.row_of_theta, axis=1).reshape(h, n, k)
        q *= fj.reshape(h, n, k)
        q *= self.row_weight                               # G ws (dphi / 2) sum_j w_j F
        return (q.reshape(-1, k) @ self._ones).reshape(h, n), q.reshape(h, -1) @ self._row_cos


def sky_matrix(weather, site=None, patches=1, ground_reflectance: float = 0.2,
               include_sun: bool = True, include_sky: bool = True, sun_spread: int = 1,
               order: int = 8, up="Z", north=None, timestamp_position: str = "end",
               step_minutes: float = 60.0, threads: int | None = None) -> SkyMatrix:
    """The hourly sky matrix of ``weather`` (see the module docstring).

    ``site``: a hirad.daylight.sun.Site (default: the weather file's location and UTC offset);
    ``patches``: a SkyPatches, an MF number (1 = Tregenza), "tregenza" or "MF:n";
    ``ground_reflectance`` rho_g in [0, 1]; ``include_sky``/``include_sun``: the sky's
    patch-mean luminance and the sun's spread luminance (the ground is lit by both either
    way); ``sun_spread`` 1-4; ``order``: Gauss-Legendre nodes per patch and direction for the
    patch means; ``up``/``north``: the frame of the sun directions; ``timestamp_position``:
    what the weather's time labels mark ("end", "start", "center"); ``threads``: how many
    threads share the sky's blocks of hours (default: up to 2, as many as there are CPUs;
    every hour is computed the same way whatever the count, so the matrix does not depend
    on it).
    """
    p = _as_patches(patches)
    rho = float(ground_reflectance)
    if not (math.isfinite(rho) and 0.0 <= rho <= 1.0):
        raise ValueError(f"ground_reflectance = {ground_reflectance!r}: must be in [0, 1]")
    if not (isinstance(order, (int, np.integer)) and order >= 1):
        raise ValueError(f"order = {order!r}: an integer >= 1")
    if not (isinstance(sun_spread, (int, np.integer)) and 1 <= sun_spread <= 4):
        raise ValueError(f"sun_spread = {sun_spread!r}: 1, 2, 3 or 4 patches")
    if threads is None:
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        threads = min(2, cpus or 1)
    if not (isinstance(threads, (int, np.integer)) and threads >= 1):
        raise ValueError(f"threads = {threads!r}: an integer >= 1")
    sun = sun_series(weather, site, up, north, timestamp_position, step_minutes)
    n_p = p.count
    values = np.zeros((sun.hours, n_p + 1))
    skipped = []
    omega = p.solid_angle
    dhi = _clean(weather.dhi, sun.hours, "dhi")
    zen = np.radians(sun.zenith)
    azi = np.radians(sun.azimuth)
    e_vd = sun.diffuse_horizontal_illuminance
    e_dn = sun.direct_normal_illuminance

    if include_sky:
        # every daytime hour with a diffuse part at once, by blocks of hours: the hour's Perez
        # shape (skies.perez_parameters_array) integrated over the patches' quadrature
        rows = np.flatnonzero(sun.daytime & (dhi > 0) & (e_vd > 0))
        params = _skies.perez_parameters_array(sun.clearness[rows], sun.brightness[rows],
                                               zen[rows])
        quad = _PatchQuadrature(p, order)
        z, a = zen[rows], azi[rows]
        step = max(1, _BLOCK // quad.node_count)
        blocks = [slice(r0, min(r0 + step, rows.size)) for r0 in range(0, rows.size, step)]
        patch_sum = np.empty((rows.size, n_p))
        rel_eh = np.empty(rows.size)
        threads = min(threads, len(blocks))

        def run(t):  # thread t takes blocks t, t + threads, ...
            work = quad.workspace(step)
            for block in blocks[t::threads]:
                patch_sum[block], rel_eh[block] = quad.integrals(z, a, params, block, work)

        if threads > 1:  # numpy's ufuncs release the GIL; each thread in the caller's context
            import contextvars                # (np.errstate)
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(threads) as pool:
                done = [pool.submit(contextvars.copy_context().run, run, t) for t in range(threads)]
                for job in done:
                    job.result()
        elif blocks:
            run(0)
        ok = (rel_eh > 0) & np.isfinite(rel_eh)
        scale = e_vd[rows[ok]] / rel_eh[ok]
        values[rows[ok], :n_p] = scale[:, None] * patch_sum[ok] / omega
        skipped = [int(i) for i in rows[~ok]]
    if include_sun:
        rows = np.flatnonzero(sun.daytime & (e_dn > 0))
        idx, share = _sun_patch_shares_many(p, math.pi / 2 - zen[rows], azi[rows], sun_spread)
        values[rows[:, None], idx] += share * e_dn[rows, None] / omega[idx]
    day = sun.daytime
    values[day, n_p] = rho * sun.global_horizontal_illuminance[day] / math.pi
    return SkyMatrix(values, p, sun, rho, bool(include_sky), bool(include_sun), int(sun_spread),
                     int(order), skipped)


# ---------------------------------------------------------------------------------------------
# annual illuminance
# ---------------------------------------------------------------------------------------------


def annual_illuminance(dc, sky, chunk_hours: int = 512, dtype=None) -> np.ndarray:
    """E = sky @ dc.T (hours x points, lux), by chunks of ``chunk_hours`` rows with numpy's
    matmul. ``dc``: (points, patches) daylight coefficients in lux per cd/m^2, in the sky's
    column order (sky patches, then the ground); ``sky``: a SkyMatrix (its night rows are
    skipped, left 0) or an (hours, patches) array. ``dtype`` of the result: default float64
    (float32 when both inputs are float32)."""
    rows = None
    if isinstance(sky, SkyMatrix):
        rows = np.flatnonzero(np.any(sky.values != 0, axis=1))
        s = sky.values
    else:
        s = np.asarray(sky)
    dc = np.asarray(dc)
    if s.ndim != 2 or dc.ndim != 2:
        raise ValueError(f"annual_illuminance: sky {s.shape} and dc {dc.shape} must both be 2-D")
    if s.shape[1] != dc.shape[1]:
        raise ValueError(f"annual_illuminance: the sky has {s.shape[1]} columns (patches"
                         f"{' + ground' if isinstance(sky, SkyMatrix) else ''}) but dc has "
                         f"{dc.shape[1]}")
    if not (isinstance(chunk_hours, (int, np.integer)) and chunk_hours >= 1):
        raise ValueError(f"chunk_hours = {chunk_hours!r}: an integer >= 1")
    if dtype is None:
        dtype = np.float32 if (s.dtype == np.float32 and dc.dtype == np.float32) else np.float64
    out = np.zeros((s.shape[0], dc.shape[0]), dtype=dtype)
    dct = dc.T.astype(dtype, copy=False)
    if rows is None:
        for r0 in range(0, s.shape[0], chunk_hours):
            r1 = min(r0 + chunk_hours, s.shape[0])
            np.matmul(s[r0:r1].astype(dtype, copy=False), dct, out=out[r0:r1])
    else:
        for c0 in range(0, rows.size, chunk_hours):
            r = rows[c0:c0 + chunk_hours]
            out[r] = np.matmul(s[r].astype(dtype, copy=False), dct)
    return out


# ---------------------------------------------------------------------------------------------
# metrics
# ---------------------------------------------------------------------------------------------

_RTOL = 1e-12


def _matrix(E, name: str = "E") -> np.ndarray:
    a = np.asarray(E, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise ValueError(f"{name}: expected hours x points, got shape {a.shape}")
    return a


def _occupied(occupied, hours: int) -> np.ndarray:
    if occupied is None:
        return np.ones(hours, dtype=bool)
    m = np.asarray(occupied, dtype=bool).reshape(-1)
    if m.shape[0] != hours:
        raise ValueError(f"occupied: {m.shape[0]} flags for {hours} hours")
    if not m.any():
        raise ValueError("occupied: no hour is occupied")
    return m


def _weights(weights, points: int) -> np.ndarray:
    if weights is None:
        return np.ones(points)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape[0] != points:
        raise ValueError(f"weights: {w.shape[0]} for {points} points")
    if not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError("weights: must be finite, >= 0 and not all 0")
    return w


def _weighted_fraction(flags: np.ndarray, w: np.ndarray) -> float:
    return float(np.sum(w * flags) / np.sum(w))


def hours_at_or_above(E, threshold: float, occupied=None) -> np.ndarray:
    """Per point, the number of occupied hours with E >= threshold."""
    a = _matrix(E)
    m = _occupied(occupied, a.shape[0])
    return np.count_nonzero(a[m] >= threshold, axis=0)


def daylight_autonomy(E, occupied=None, threshold: float = 300.0) -> np.ndarray:
    """DA per point: the fraction of occupied hours with E >= ``threshold`` (lux)."""
    a = _matrix(E)
    m = _occupied(occupied, a.shape[0])
    return np.count_nonzero(a[m] >= threshold, axis=0) / float(np.count_nonzero(m))


def spatial_daylight_autonomy(da, fraction: float = 0.5, weights=None) -> float:
    """sDA: the (weighted) fraction of points whose DA >= ``fraction`` (sDA300/50% from DA300)."""
    d = np.asarray(da, dtype=np.float64).reshape(-1)
    w = _weights(weights, d.shape[0])
    return _weighted_fraction(d >= fraction * (1 - _RTOL), w)


def sunlit_hours(E_direct, occupied=None, threshold: float = 1000.0) -> np.ndarray:
    """Per point, the number of occupied hours with direct-sun illuminance > ``threshold``."""
    a = _matrix(E_direct, "E_direct")
    m = _occupied(occupied, a.shape[0])
    return np.count_nonzero(a[m] > threshold, axis=0)


def annual_sunlight_exposure(E_direct, occupied=None, threshold: float = 1000.0,
                             hours: int = 250, weights=None) -> float:
    """ASE_threshold,hours (IES LM-83): the (weighted) fraction of points whose direct-sun
    illuminance exceeds ``threshold`` lux in more than ``hours`` occupied hours."""
    n = sunlit_hours(E_direct, occupied, threshold)
    return _weighted_fraction(n > hours, _weights(weights, n.shape[0]))


@dataclass
class UDI:
    """Useful daylight illuminance per point (fractions of occupied hours): ``below``
    (E < lower), ``useful`` (lower <= E <= upper, UDI-a), ``above`` (E > upper)."""

    below: np.ndarray
    useful: np.ndarray
    above: np.ndarray
    lower: float
    upper: float


def useful_daylight_illuminance(E, occupied=None, lower: float = 100.0,
                                upper: float = 3000.0) -> UDI:
    """UDI per point over the occupied hours (see :class:`UDI`)."""
    if not lower < upper:
        raise ValueError(f"UDI limits {lower!r}, {upper!r}: need lower < upper")
    a = _matrix(E)
    m = _occupied(occupied, a.shape[0])
    x = a[m]
    n = float(x.shape[0])
    below = np.count_nonzero(x < lower, axis=0) / n
    above = np.count_nonzero(x > upper, axis=0) / n
    useful = np.count_nonzero((x >= lower) & (x <= upper), axis=0) / n
    return UDI(below, useful, above, float(lower), float(upper))


#: EN 17037:2018 Table A.1, vertical and inclined openings: level -> (E_T, E_TM) in lux, with
#: E_T over 50 % and E_TM over 95 % of the reference plane for 50 % of the daylight hours
EN17037_LEVELS = {"minimum": (300.0, 100.0), "medium": (500.0, 300.0), "high": (750.0, 500.0)}


def en17037_daylight_hours(diffuse_illuminance, count: int | None = None) -> np.ndarray:
    """Boolean mask of EN 17037's daylight hours: the ``count`` hours (default half of all
    rows, rounded down: 4380 of 8760) with the highest external diffuse horizontal
    illuminance; ties go to the earlier hour."""
    d = np.asarray(diffuse_illuminance, dtype=np.float64).reshape(-1)
    n = d.shape[0] // 2 if count is None else int(count)
    if not (1 <= n <= d.shape[0]):
        raise ValueError(f"count = {count!r}: between 1 and {d.shape[0]} hours")
    d = np.where(np.isfinite(d), d, -np.inf)
    order = np.argsort(-d, kind="stable")
    mask = np.zeros(d.shape[0], dtype=bool)
    mask[order[:n]] = True
    return mask


@dataclass
class EN17037Provision:
    """EN 17037 daylight provision by illuminance (see the module docstring).

    ``target_area_fraction``/``minimum_area_fraction``: per daylight hour, the weighted
    fraction of points at or above E_T / E_TM; ``target_time_fraction`` /
    ``minimum_time_fraction``: the fraction of daylight hours whose area fraction reaches
    ``target_area`` / ``minimum_area``; ``target_met``, ``minimum_met``: those >= ``time``;
    ``met``: both.
    """

    target: float
    minimum: float
    target_area: float
    minimum_area: float
    time: float
    daylight_hours: int
    target_area_fraction: np.ndarray
    minimum_area_fraction: np.ndarray
    target_time_fraction: float
    minimum_time_fraction: float

    @property
    def target_met(self) -> bool:
        return self.target_time_fraction >= self.time * (1 - _RTOL)

    @property
    def minimum_met(self) -> bool:
        return self.minimum_time_fraction >= self.time * (1 - _RTOL)

    @property
    def met(self) -> bool:
        return self.target_met and self.minimum_met


def en17037_provision(E, daylight_hours, target: float = 300.0, minimum: float = 100.0,
                      target_area: float = 0.5, minimum_area: float = 0.95, time: float = 0.5,
                      weights=None) -> EN17037Provision:
    """EN 17037 daylight provision of one room's reference plane: ``E`` (hours x points, lux),
    ``daylight_hours`` a boolean mask (:func:`en17037_daylight_hours`), thresholds E_T
    ``target`` over ``target_area`` and E_TM ``minimum`` over ``minimum_area`` of the
    (weighted) points for at least ``time`` of the daylight hours."""
    a = _matrix(E)
    m = _occupied(daylight_hours, a.shape[0])
    w = _weights(weights, a.shape[1])
    x = a[m]
    ft = (x >= target) @ w / w.sum()
    fm = (x >= minimum) @ w / w.sum()
    n = float(x.shape[0])
    tt = np.count_nonzero(ft >= target_area * (1 - _RTOL)) / n
    tm = np.count_nonzero(fm >= minimum_area * (1 - _RTOL)) / n
    return EN17037Provision(float(target), float(minimum), float(target_area),
                            float(minimum_area), float(time), int(x.shape[0]), ft, fm, tt, tm)


def en17037_level(E, daylight_hours, weights=None) -> str | None:
    """The highest EN 17037 level ("high", "medium", "minimum") whose E_T/E_TM pair is met
    (vertical and inclined openings, :data:`EN17037_LEVELS`), or None."""
    for name in ("high", "medium", "minimum"):
        t, mn = EN17037_LEVELS[name]
        if en17037_provision(E, daylight_hours, t, mn, weights=weights).met:
            return name
    return None


def annual_metrics(E, times, E_direct=None, diffuse_illuminance=None, weights=None,
                   start_hour: float = 8.0, end_hour: float = 18.0, weekdays=None,
                   timestamp_position: str = "end") -> dict:
    """All metrics at their usual thresholds with the LM-83 schedule (8:00-18:00 every day
    unless given): a dict with per-point ``da300``, ``udi`` (UDI), ``sda300_50`` and, when
    ``E_direct`` is given, per-point ``sunlit_hours_1000`` and ``ase1000_250``; when
    ``diffuse_illuminance`` (per hour, lux) is given, ``en17037`` (EN17037Provision at the
    minimum level) and ``en17037_level``."""
    occ = occupied_hours(times, start_hour, end_hour, weekdays, timestamp_position)
    da = daylight_autonomy(E, occ, 300.0)
    out = {"occupied_hours": int(np.count_nonzero(occ)), "da300": da,
           "sda300_50": spatial_daylight_autonomy(da, 0.5, weights),
           "udi": useful_daylight_illuminance(E, occ)}
    if E_direct is not None:
        out["sunlit_hours_1000"] = sunlit_hours(E_direct, occ, 1000.0)
        out["ase1000_250"] = annual_sunlight_exposure(E_direct, occ, 1000.0, 250, weights)
    if diffuse_illuminance is not None:
        dh = en17037_daylight_hours(diffuse_illuminance)
        out["en17037"] = en17037_provision(E, dh, weights=weights)
        out["en17037_level"] = en17037_level(E, dh, weights)
    return out


# ---------------------------------------------------------------------------------------------
# heat map
# ---------------------------------------------------------------------------------------------


def _grid_axis(c: np.ndarray) -> tuple[np.ndarray, float]:
    u = np.unique(np.round(c, 9))
    if u.size == 1:
        return u, 1.0
    step = float(np.min(np.diff(u)))
    return u, step


def heatmap_png(path, values, xy, title: str = "", units: str = "", grid: bool = False,
                vmin: float | None = None, vmax: float | None = None, cmap: str = "viridis",
                figsize: tuple[float, float] = (6.0, 5.0), dpi: int = 100,
                point_size: float | None = None, xlabel: str = "x (m)",
                ylabel: str = "y (m)") -> None:
    """A per-point picture of ``values`` (one per point) at plan positions ``xy`` (P, 2), as
    coloured points (default) or, with ``grid=True``, a raster of cells (the points taken as
    the centres of a regular grid whose spacing is the smallest gap between distinct
    coordinates; cells without a point are blank), with a colour bar labelled ``units`` and
    the ``title``. Written through hirad.files.write_bytes (a temporary beside ``path``,
    renamed over it)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    import io

    from hirad.files import write_bytes

    v = np.asarray(values, dtype=np.float64).reshape(-1)
    p = np.asarray(xy, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] != v.shape[0]:
        raise ValueError(f"heatmap_png: xy {p.shape} must be ({v.shape[0]}, 2) for {v.shape[0]} values")
    if v.size == 0:
        raise ValueError("heatmap_png: no points")
    fin = v[np.isfinite(v)]
    lo = float(np.min(fin)) if vmin is None and fin.size else (0.0 if vmin is None else float(vmin))
    hi = float(np.max(fin)) if vmax is None and fin.size else (1.0 if vmax is None else float(vmax))
    if not hi > lo:
        hi = lo + 1.0

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    if grid:
        xs, dx = _grid_axis(p[:, 0])
        ys, dy = _grid_axis(p[:, 1])
        nx = int(round((xs[-1] - xs[0]) / dx)) + 1
        ny = int(round((ys[-1] - ys[0]) / dy)) + 1
        img = np.full((ny, nx), np.nan)
        ix = np.rint((p[:, 0] - xs[0]) / dx).astype(int)
        iy = np.rint((p[:, 1] - ys[0]) / dy).astype(int)
        img[iy, ix] = v
        art = ax.imshow(img, origin="lower", cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest",
                        extent=(xs[0] - dx / 2, xs[0] + (nx - 0.5) * dx,
                                ys[0] - dy / 2, ys[0] + (ny - 0.5) * dy))
    else:
        s = point_size if point_size is not None else max(4.0, min(200.0, 4000.0 / max(v.size, 1)))
        art = ax.scatter(p[:, 0], p[:, 1], c=v, s=s, marker="s", cmap=cmap, vmin=lo, vmax=hi,
                         linewidths=0)
    ax.set_aspect("equal")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    bar = fig.colorbar(art, ax=ax)
    if units:
        bar.set_label(units)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    write_bytes(path, buf.getvalue())
