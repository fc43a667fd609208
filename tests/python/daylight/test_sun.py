"""Sun position: SPA's published test vector and site validation."""

import math

import numpy as np
import pytest

from hirad.daylight import sun


def test_spa_reference_vector():
    """Reda & Andreas (2004/2008), NREL/TP-560-34302 Table A5.1: topocentric zenith 50.11162,
    azimuth 194.34024 degrees."""
    site = sun.Site(39.742476, -105.1786, 1830.14, -7)
    p = sun.sun_position(site, "2003-10-17T12:30:30", pressure=82000.0, temperature=11.0, delta_t=67.0)
    assert p.zenith == pytest.approx(50.11162, abs=0.01)
    assert p.azimuth == pytest.approx(194.34024, abs=0.01)
    # same instant through an IANA zone (MST in October 2003 was UTC-6: daylight time) gives
    # the same angles one hour later in local clock time
    site2 = sun.Site(39.742476, -105.1786, 1830.14, "America/Denver")
    p2 = sun.sun_position(site2, "2003-10-17T13:30:30", pressure=82000.0, temperature=11.0, delta_t=67.0)
    assert p2.zenith == pytest.approx(p.zenith, abs=1e-6)


def test_direction_in_scene_frame():
    site = sun.Site(39.742476, -105.1786, 1830.14, -7)
    p = sun.sun_position(site, "2003-10-17T12:30:30")
    d = p.direction(up="Y")
    assert np.linalg.norm(d) == pytest.approx(1.0)
    assert d[1] == pytest.approx(math.cos(math.radians(p.zenith)))
    # azimuth ~194 deg: south-south-west; north is -Z so south is +Z, west is -X
    assert d[2] > 0 and d[0] < 0
    dz = p.direction(up="Z")
    assert dz[2] == pytest.approx(d[1]) and dz[1] < 0


@pytest.mark.parametrize("kw,field", [
    (dict(latitude=91, longitude=0), "latitude"),
    (dict(latitude=0, longitude=-181), "longitude"),
    (dict(latitude=0, longitude=0, timezone=15), "timezone"),
    (dict(latitude=0, longitude=0, timezone="Mars/Olympus"), "timezone"),
    (dict(latitude=float("nan"), longitude=0), "latitude"),
    (dict(latitude=0, longitude=0, elevation=20000), "elevation"),
])
def test_impossible_sites(kw, field):
    with pytest.raises(ValueError, match=field):
        sun.Site(**kw)


def test_bad_time():
    with pytest.raises(ValueError, match="time"):
        sun.sun_position(sun.Site(0, 0), "yesterday noon")
