"""Sun position from a site and a local date and time, by NREL's Solar Position Algorithm.

SPA (I. Reda and A. Andreas, "Solar position algorithm for solar radiation applications",
Solar Energy 76(5):577-589, 2004; NREL/TP-560-34302, revised 2008) gives the topocentric solar
zenith and azimuth to +-0.0003 degrees for the years -2000..6000. hirad does not implement it:
it calls pvlib's ``pvlib.solarposition.spa_python`` (the NREL SPA in numpy). The zenith returned
here is SPA's topocentric zenith angle with the atmospheric refraction correction (pvlib's
``apparent_zenith``, SPA's "topocentric zenith angle" of Table A5.1); the azimuth is measured
eastward from north (SPA's Phi, 0..360 degrees).

SPA's published example (Table A5.1): 2003-10-17 12:30:30 local time, UTC-7, latitude
39.742476, longitude -105.1786, elevation 1830.14 m, pressure 820 mbar, temperature 11 deg C,
Delta T 67 s, atmospheric refraction at sunrise 0.5667 deg: topocentric zenith 50.11162 deg,
topocentric azimuth 194.34024 deg (the test suite checks it).

A site is (latitude deg north, longitude deg east, elevation m, time zone): the time zone is
a UTC offset in hours (e.g. -7) or an IANA name (e.g. "America/Denver"); a local date and time
without a zone is read in the site's zone. Impossible values raise ValueError naming the field.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass

import numpy as np

from .patches import directions


@dataclass(frozen=True)
class Site:
    """latitude (deg, -90..90, north positive), longitude (deg, -180..180, east positive),
    elevation (m above sea level, -500..9000), timezone (UTC offset in hours, -12..14, or an
    IANA zone name)."""

    latitude: float
    longitude: float
    elevation: float = 0.0
    timezone: float | str = 0.0

    def __post_init__(self):
        for name, lo, hi in (("latitude", -90.0, 90.0), ("longitude", -180.0, 180.0),
                             ("elevation", -500.0, 9000.0)):
            v = getattr(self, name)
            try:
                f = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"site {name} = {v!r}: not a number") from None
            if not (math.isfinite(f) and lo <= f <= hi):
                unit = "m" if name == "elevation" else "degrees"
                raise ValueError(f"site {name} = {v!r}: must be within [{lo:g}, {hi:g}] {unit}")
        self.tzinfo()  # validates

    def tzinfo(self) -> _dt.tzinfo:
        tz = self.timezone
        if isinstance(tz, str):
            from zoneinfo import ZoneInfo, ZoneInfoNotFoundError
            try:
                return ZoneInfo(tz)
            except (ZoneInfoNotFoundError, ValueError):
                raise ValueError(f"site timezone = {tz!r}: not a known IANA time zone "
                                 "(or give a UTC offset in hours)") from None
        try:
            h = float(tz)
        except (TypeError, ValueError):
            raise ValueError(f"site timezone = {tz!r}: not a UTC offset in hours nor a zone name") from None
        if not (math.isfinite(h) and -12.0 <= h <= 14.0):
            raise ValueError(f"site timezone = {tz!r}: a UTC offset must be within [-12, 14] hours")
        return _dt.timezone(_dt.timedelta(hours=h))


@dataclass(frozen=True)
class SunPosition:
    """Topocentric sun angles in degrees: zenith (refraction-corrected), azimuth (from north
    towards east), elevation = 90 - zenith; and the time (aware datetime)."""

    zenith: float
    azimuth: float
    time: _dt.datetime

    @property
    def elevation(self) -> float:
        return 90.0 - self.zenith

    def direction(self, up="Y", north=None) -> np.ndarray:
        """Unit vector towards the sun in the scene frame (hirad.daylight.patches.frame)."""
        return directions(math.radians(self.elevation), math.radians(self.azimuth), up, north)


def _localize(site: Site, when) -> _dt.datetime:
    if isinstance(when, str):
        try:
            when = _dt.datetime.fromisoformat(when)
        except ValueError:
            raise ValueError(f"time = {when!r}: not an ISO date and time") from None
    if not isinstance(when, _dt.datetime):
        raise ValueError(f"time = {when!r}: must be a datetime or an ISO string")
    if when.tzinfo is None:
        when = when.replace(tzinfo=site.tzinfo())
    return when


def sun_position(site: Site, when, pressure: float = 101325.0, temperature: float = 12.0,
                 delta_t: float = 67.0, atmos_refract: float = 0.5667) -> SunPosition:
    """The sun at ``site`` at local time ``when`` (datetime or ISO string; naive = the site's
    zone). ``pressure`` Pa, ``temperature`` deg C (for refraction), ``delta_t`` s (TT - UT)."""
    import pandas as pd
    import pvlib

    t = _localize(site, when)
    if not (math.isfinite(pressure) and 0 < pressure < 2e5):
        raise ValueError(f"pressure = {pressure!r} Pa: must be in (0, 200000)")
    if not (math.isfinite(temperature) and -100 < temperature < 100):
        raise ValueError(f"temperature = {temperature!r} deg C: must be in (-100, 100)")
    idx = pd.DatetimeIndex([pd.Timestamp(t)])
    sp = pvlib.solarposition.spa_python(idx, site.latitude, site.longitude,
                                        altitude=site.elevation, pressure=pressure,
                                        temperature=temperature, delta_t=delta_t,
                                        atmos_refract=atmos_refract, how="numpy")
    return SunPosition(float(sp["apparent_zenith"].iloc[0]), float(sp["azimuth"].iloc[0]), t)


def sun_positions(site: Site, times, pressure: float = 101325.0, temperature: float = 12.0,
                  delta_t: float = 67.0):
    """Vectorised: (zenith, azimuth) arrays in degrees for a pandas DatetimeIndex (tz-aware;
    naive is read in the site's zone)."""
    import pandas as pd
    import pvlib

    idx = pd.DatetimeIndex(times)
    if idx.tz is None:
        idx = idx.tz_localize(site.tzinfo())
    sp = pvlib.solarposition.spa_python(idx, site.latitude, site.longitude,
                                        altitude=site.elevation, pressure=pressure,
                                        temperature=temperature, delta_t=delta_t, how="numpy")
    return sp["apparent_zenith"].to_numpy(), sp["azimuth"].to_numpy()
