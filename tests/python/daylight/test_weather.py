"""Weather files: pvlib's shipped TMY3, an EPW written from it, and a broken EPW."""

import os

import numpy as np
import pytest

pvlib = pytest.importorskip("pvlib")
from hirad.daylight import weather  # noqa: E402

TMY3 = os.path.join(os.path.dirname(pvlib.__file__), "data", "723170TYA.CSV")


def write_epw(path, w):
    """A syntactically complete EPW of the TMY3 data (other fields are plausible constants)."""
    lines = [f"LOCATION,Test,NC,USA,TMY3,723170,{w.latitude},{w.longitude},{w.timezone},{w.elevation}",
             "DESIGN CONDITIONS,0", "TYPICAL/EXTREME PERIODS,0", "GROUND TEMPERATURES,0",
             "HOLIDAYS/DAYLIGHT SAVINGS,No,0,0,0", "COMMENTS 1,test", "COMMENTS 2,test",
             "DATA PERIODS,1,1,Data,Sunday, 1/ 1,12/31"]
    for i in range(8760):
        month, day, hour = w.times[i].month, w.times[i].day, w.times[i].hour
        hour = 24 if hour == 0 else hour
        f = [1999, month, day, hour, 60, "?9?9?9", 20.0, 10.0, 50, 101000, 0, 0, 300,
             w.ghi[i], w.dni[i], w.dhi[i], 0, 0, 0, 0, 180, 2.0, 5, 5, 10.0, 77777, 9, 999999999,
             10, 0.1, 0, 88, 0.2, 0.0, 0.0]
        lines.append(",".join(str(x) for x in f))
    path.write_text("\n".join(lines) + "\n")


def test_tmy3_from_pvlib():
    w = weather.read_weather(TMY3)
    assert len(w.dni) == 8760
    assert np.all(w.dni >= 0) and np.all(w.dhi >= 0)
    assert 35 < w.latitude < 37  # Greensboro NC
    # annual global horizontal irradiation of a US site: 1.2-2.2 MWh/m^2
    assert 1200 < w.ghi.sum() / 1000 < 2200
    # closure GHI ~ DHI + DNI cos Z at noon in summer is for pvlib's data; here only night = 0
    assert w.ghi[0:5].max() == 0


def test_epw_roundtrip(tmp_path):
    w = weather.read_tmy3(TMY3)
    p = tmp_path / "site.epw"
    write_epw(p, w)
    e = weather.read_weather(p)
    assert len(e.dni) == 8760
    assert np.allclose(e.dni, w.dni) and np.allclose(e.ghi, w.ghi)
    assert e.latitude == pytest.approx(w.latitude)


@pytest.mark.parametrize("mutate,problem", [
    (lambda f: f[:20], "20 fields"),
    (lambda f: f[:14] + ["abc"] + f[15:], "field 15 = 'abc'"),
    (lambda f: f[:1] + ["13"] + f[2:], "out of range"),
    (lambda f: f[:15] + ["-40"] + f[16:], "DHI"),
])
def test_bad_epw_line_is_located(tmp_path, mutate, problem):
    w = weather.read_tmy3(TMY3)
    p = tmp_path / "bad.epw"
    write_epw(p, w)
    lines = p.read_text().splitlines()
    k = 8 + 100  # 0-based index of a data line: file line 109
    lines[k] = ",".join(mutate(lines[k].split(",")))
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(weather.WeatherFileError) as err:
        weather.read_epw(p)
    msg = str(err.value)
    assert str(p) in msg and ":109:" in msg and problem in msg
