"""Weather files: hourly direct-normal, diffuse-horizontal and global-horizontal irradiance
(W/m^2) with their timestamps, from EPW (EnergyPlus weather) and TMY3 files, read by pvlib
(``pvlib.iotools.read_epw``, ``pvlib.iotools.read_tmy3``).

EPW: 8 header lines (LOCATION first: city, state, country, source, WMO, latitude, longitude,
time zone, elevation), then one line per hour of 35 comma-separated fields: year, month, day,
hour (1-24), minute, a data-source flag string, then 29 numbers (dry bulb, dew point, ...,
GHI field 14, DNI field 15, DHI field 16 counting from 1). pvlib parses with pandas, whose
errors on a malformed line name neither the file nor the line, and a non-numeric value can slip
through as text; so every data line is checked here first, and an error names the file, the
line number (1-based, in the file) and the problem (:class:`WeatherFileError`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

EPW_FIELDS = 35
EPW_HEADER_LINES = 8


class WeatherFileError(ValueError):
    """A weather file that cannot be read: the message names the file and the line."""


@dataclass
class Weather:
    """Hourly irradiance (W/m^2) and dew point (deg C, NaN if absent) at a site."""

    times: object  # pandas DatetimeIndex, tz-aware (the file's standard time)
    dni: np.ndarray
    dhi: np.ndarray
    ghi: np.ndarray
    dew_point: np.ndarray
    latitude: float
    longitude: float
    elevation: float
    timezone: float  # UTC offset in hours
    source: str


def check_epw(path) -> None:
    """Raise :class:`WeatherFileError` at the first malformed data line of an EPW file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise WeatherFileError(f"{path}: cannot read: {e.strerror}") from None
    lines = text.splitlines()
    if len(lines) <= EPW_HEADER_LINES:
        raise WeatherFileError(f"{path}: {len(lines)} lines: an EPW file has {EPW_HEADER_LINES} header lines and then hourly data")
    if not lines[0].upper().startswith("LOCATION"):
        raise WeatherFileError(f"{path}:1: the first line must be the LOCATION header")
    for k, line in enumerate(lines[EPW_HEADER_LINES:], start=EPW_HEADER_LINES + 1):
        if not line.strip():
            continue
        fields = line.split(",")
        if len(fields) != EPW_FIELDS:
            raise WeatherFileError(f"{path}:{k}: {len(fields)} fields, an EPW data line has {EPW_FIELDS}")
        for i, f in enumerate(fields):
            if i == 5:
                continue  # data source and uncertainty flags (text)
            try:
                float(f)
            except ValueError:
                raise WeatherFileError(f"{path}:{k}: field {i + 1} = {f.strip()!r} is not a number") from None
        month, day, hour = int(float(fields[1])), int(float(fields[2])), int(float(fields[3]))
        if not (1 <= month <= 12 and 1 <= day <= 31 and 1 <= hour <= 24):
            raise WeatherFileError(f"{path}:{k}: month/day/hour = {month}/{day}/{hour} out of range")
        for i, name in ((13, "GHI"), (14, "DNI"), (15, "DHI")):
            v = float(fields[i])
            if v < 0 and v != 9999:
                raise WeatherFileError(f"{path}:{k}: {name} (field {i + 1}) = {v:g} W/m^2 is negative")


def read_epw(path) -> Weather:
    """An EPW file through pvlib.iotools.read_epw, checked line by line first."""
    import pvlib

    check_epw(path)
    try:
        data, meta = pvlib.iotools.read_epw(str(path))
    except Exception as e:  # pandas/pvlib errors name no line: the check above should have
        raise WeatherFileError(f"{path}: pvlib could not read it: {e}") from e
    return Weather(data.index, data["dni"].to_numpy(float), data["dhi"].to_numpy(float),
                   data["ghi"].to_numpy(float), data["temp_dew"].to_numpy(float),
                   float(meta["latitude"]), float(meta["longitude"]), float(meta["altitude"]),
                   float(meta["TZ"]), str(path))


def read_tmy3(path) -> Weather:
    """A TMY3 file (NSRDB CSV) through pvlib.iotools.read_tmy3."""
    import pvlib

    path = Path(path)
    if not path.is_file():
        raise WeatherFileError(f"{path}: no such file")
    try:
        data, meta = pvlib.iotools.read_tmy3(str(path), map_variables=True)
    except Exception as e:
        raise WeatherFileError(f"{path}: not a readable TMY3 file: {e}") from e
    dew = data["temp_dew"].to_numpy(float) if "temp_dew" in data else np.full(len(data), np.nan)
    return Weather(data.index, data["dni"].to_numpy(float), data["dhi"].to_numpy(float),
                   data["ghi"].to_numpy(float), dew, float(meta["latitude"]),
                   float(meta["longitude"]), float(meta["altitude"]), float(meta["TZ"]), str(path))


_READ: dict = {}  # (resolved path, size, mtime) -> Weather: a bake reads its file more than once


def read_weather(path) -> Weather:
    """EPW (``.epw``) or TMY3 (``.csv``), by extension. A file read before and not changed since
    (same size and modification time) is not parsed again."""
    p = Path(path)
    try:
        st = p.stat()
        key = (str(p.resolve()), st.st_size, st.st_mtime_ns)
    except OSError:
        key = None
    if key is not None and key in _READ:
        return _READ[key]
    w = _read_weather(p)
    if key is not None:
        _READ.clear()  # one file kept: a study reads one weather file at a time
        _READ[key] = w
    return w


def _read_weather(p: Path) -> Weather:
    if p.suffix.lower() == ".epw":
        return read_epw(p)
    if p.suffix.lower() == ".csv":
        return read_tmy3(p)
    raise WeatherFileError(f"{p}: unknown weather file type {p.suffix!r} (EPW .epw or TMY3 .csv)")
