"""IES LM-63 photometric files: reading, evaluating, integrating, plotting.

Pure Python and numpy (matplotlib only for :func:`polar_plot`, imported when called).

Axes (hirad's convention, tested in tests/python/photometry/test_ies.py)
--------------------------------------------------------------------------
Every distribution is evaluated in the light's LOCAL frame, right-handed, Z up:

* IES vertical angle 0 (gamma = 0, nadir) is the light's **-Z**; gamma = 180 is +Z.
* Horizontal angle C = 0 is **+X**, C = 90 is **+Y** (C grows counter-clockwise seen from
  above, +Z), C = 180 is -X, C = 270 is -Y.
* direction(gamma, C) = (sin gamma cos C, sin gamma sin C, -cos gamma).

Some renderers have shipped profiles along -Y or with C turning the other way; in hirad a
profile lit only around C90 lights +Y.

Photometric types (LM-63 field "photometric type": 1 = C, 2 = B, 3 = A)
-----------------------------------------------------------------------
* **Type C** (architectural): the polar axis is the luminaire's vertical axis; C planes are
  half-planes about it, gamma is measured in a plane from nadir. Used as above.
* **Type B** (floodlights): the polar axis is horizontal, perpendicular to the photometric
  axis. The vertical angle V names a plane through the polar axis (its tilt about that
  axis); the horizontal angle H is measured inside that plane from the photometric axis
  towards the polar axis (H is a latitude, V a longitude; CIE's B-beta system, B = V,
  beta = H). In the local frame the photometric axis (H = V = 0) is -Z, the polar axis is Y
  (H = +90 is +Y) and positive V turns the axis from -Z towards +X::

      d_B(H, V) = (cos H sin V,  sin H,  -cos H cos V)
      inverse:    H = asin(d_y),  V = atan2(d_x, -d_z)

* **Type A** (automotive): the polar axis is vertical, perpendicular to the photometric
  axis; H names a plane through it (a longitude about the polar axis) and V is measured in
  that plane (a latitude; CIE's A-alpha system, A = H, alpha = V). Local frame: photometric
  axis -Z, polar axis X (V = +90 is +X), positive H turns the axis from -Z towards +Y::

      d_A(H, V) = (sin V,  cos V sin H,  -cos V cos H)
      inverse:    V = asin(d_x),  H = atan2(d_y, -d_z)

  Near the photometric axis both reduce to d ~ (V, H, -1) in radians, so a small positive H
  is towards +Y (like C90) and a small positive V towards +X (like C0) in types A and B; the
  C0-C180 plane of the local frame is the type-B plane H = 0 (V sweeps it) and the C90-C270
  plane is the type-B cone V = 0 (H sweeps it). Types A and B are evaluated on their own grid
  (no resampling to type C), so no accuracy is lost in a conversion. The LM-63-1986 format
  used photometric type 1 for type A data too; such a file cannot be told apart and is read
  as type C.

Versions
--------
The first line carries the version tag: none (LM-63-1986: the label starts at once),
``IESNA91`` (1991), ``IESNA:LM-63-1995``, ``IESNA:LM-63-2002``, ``IES:LM-63-2019``. Keyword
lines ``[KEYWORD] text`` (``[MORE]`` continues the one before) up to ``TILT=``; the 1986
label is free text. ``TILT=NONE`` or ``TILT=INCLUDE`` (lamp-to-luminaire geometry, number of
angles, the angles, the multiplying factors, read into :class:`Tilt`); ``TILT=<file name>``
is refused (an :class:`IesError` naming the file and line: separate tilt files are not
supported, and LM-63-2019 no longer allows them). After that the values are free-format
tokens, separated by blanks, commas or line ends, in any number per line.

The second numeric record is ``<ballast factor> <X> <input watts>``; what X is depends on the
version, and only where it is a photometric factor does it multiply the candela:

* 1986 (no tag): ballast-lamp photometric factor -> multiplies (``ballast_lamp_factor``).
* 1991 (IESNA91): ballast-lamp photometric factor -> multiplies.
* 1995: "future use" (to be 1) -> read, ignored, a warning if it is not 1.
* 2002: "future use" (to be 1) -> read, ignored, a warning if it is not 1.
* 2019: "file generation type", a code 1.xxxxx (undefined, simulation, unaccredited or
  accredited lab, lumen scaled, interpolated angles) -> decoded into ``file_generation``,
  never a multiplier. The code table is LM-63-2019 Table 2 as public parsers transcribe it
  (the standard itself was not at hand); an unknown code is reported, not guessed.

The ballast factor multiplies the candela in every version. Lumens per lamp = -1 means
absolute photometry (the candela are the luminaire's own); a positive value is relative
photometry (candela for lamps of that rated flux; :meth:`Photometry.efficiency` compares).

Luminous opening: width, length, height with their sign codes (negative = round shapes),
decoded per version (1986/1991, 1995, 2002/2019 tables; LM-63-2002 Table 1 for 2002 and
2019), sizes converted to metres (units 1 = feet x 0.3048, 2 = metres). Length runs along the
photometric horizontal (C0-C180, local X), width across it (C90-C270, local Y), height along Z.

Symmetry (type C horizontal angles): a single angle (0) = axial; 0-90 = quadrilateral;
0-180 = bilateral about the C0-C180 plane, I(C) = I(360 - C); 90-270 (LM-63-1995) =
bilateral about the C90-C270 plane, I(C) = I(180 - C) (mirrored, not rotated); 0 to more
than 180 (up to 360) = none, wrapped at 360 (a 360 column must equal the 0 column: it is
dropped, with a warning if it differs). Vertical angles 0-90, 90-180 or 0-180 (any range
inside 0-180 is read, a non-standard one with a warning); no light outside the measured range.
Types A/B: horizontal 0-90 = laterally symmetric, I(-H) = I(H); -90-90 = none; vertical
-90-90 or 0-90.

Interpolation
-------------
Angles are in DEGREES everywhere in this module's interface. The interpolant is a tensor
product of local monotone cubic Hermite (PCHIP, Fritsch-Carlson slopes, non-uniform steps):
C1 in both angles, no overshoot, never negative, exact at the measured points. The C axis is
periodic (the 360 wrap uses the neighbours across 0); at the poles (gamma = 0 and 180) the
values of all C are first made one value (their mean, a warning if they differed by more
than 0.1 % of the peak) and the stencil continues over the pole into the opposite plane
C + 180, so the surface is smooth through the pole. Outside the measured vertical range the
intensity is 0. Type A/B poles (H = +-90 in type B, V = +-90 in type A) are made single
values the same way.

Flux
----
:func:`lumens` integrates the interpolant, Phi = integral of I dOmega, with 6-point
Gauss-Legendre rules inside every cell of the (expanded) angle grid (sin gamma dgamma dC for
type C, cos(latitude) for types A/B), so it is the flux of the very surface that
:meth:`Photometry.intensity` evaluates, not a coarse zonal sum.

Errors
------
A file that cannot be read raises :class:`IesError` naming the file, the line and the problem
(missing lines or values, non-numeric tokens, counts that do not fit, a TILT file name,
angles not increasing, negative candela, out-of-range codes). Usable oddities are warnings
(:class:`IesWarning`, also kept in ``Photometry.warnings``): a non-UTF-8 file is decoded as
Latin-1 with a warning naming the first such byte's line (real files carry e.g. 0xB0 or 0xA0
in keyword text); CRLF line ends are what LM-63 prescribes and are read silently, as are LF
and CR alone; values left over after the candela table are a warning.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FOOT = 0.3048  # metres

VERSIONS = (1986, 1991, 1995, 2002, 2019)

# LM-63-2019 Table 2 (file generation type), as transcribed by public parsers
FILE_GENERATION_TYPES = {
    "1.00001": "undefined",
    "1.00010": "computer simulation",
    "1.00000": "test at an unaccredited lab",
    "1.00100": "test at an unaccredited lab, lumen scaled",
    "1.01000": "test at an unaccredited lab, interpolated angle set",
    "1.01100": "test at an unaccredited lab, interpolated angle set, lumen scaled",
    "1.10000": "test at an accredited lab",
    "1.10100": "test at an accredited lab, lumen scaled",
    "1.11000": "test at an accredited lab, interpolated angle set",
    "1.11100": "test at an accredited lab, interpolated angle set, lumen scaled",
}

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")
_SPLIT = re.compile(r"[,\s]+")
_LINES = re.compile(r"\r\n|\r|\n")


class IesError(ValueError):
    """An IES file that cannot be read: ``path``, ``line`` (1-based, None if not one line)
    and ``problem``; the message is "<path>: line <n>: <problem>"."""

    def __init__(self, path, line: int | None, problem: str):
        self.path = str(path)
        self.line = line
        self.problem = problem
        where = f"{self.path}: line {line}" if line is not None else self.path
        super().__init__(f"{where}: {problem}")


class IesWarning(UserWarning):
    """A usable IES file with an oddity (named by file and line)."""


@dataclass
class Tilt:
    """TILT=INCLUDE data: lamp-to-luminaire geometry (1 vertical base up/down, 2 horizontal and
    stays horizontal when tilted, 3 horizontal and tilts with the luminaire), tilt angles in
    degrees and their candela multiplying factors."""

    geometry: int
    angles: np.ndarray
    factors: np.ndarray

    def factor(self, angle_deg):
        """Multiplying factor at a tilt angle (linear between the tabulated angles, the end
        values held outside them)."""
        return np.interp(np.asarray(angle_deg, dtype=float), self.angles, self.factors)


@dataclass
class Opening:
    """Luminous opening: ``shape`` (e.g. "point", "rectangular", "circular", "sphere",
    "vertical cylinder", ...), the absolute sizes in metres (width along local Y, length along
    local X, height along Z; a diameter sits in the fields the table names), and the raw
    signed values and unit code of the file."""

    shape: str
    width_m: float
    length_m: float
    height_m: float
    raw: tuple[float, float, float]
    units: int

    @property
    def units_name(self) -> str:
        return "feet" if self.units == 1 else "metres"


@dataclass
class PlaneAngles:
    """Beam (50 % of the plane's peak) and field (10 %) angles in one plane, degrees, with
    the plane's peak candela; None where the plane has no light."""

    plane: str
    peak_cd: float
    beam_deg: float | None
    field_deg: float | None


@dataclass
class Photometry:
    """One IES LM-63 file, read.

    ``vertical_angles`` (nv,) and ``horizontal_angles`` (nh,) in degrees as in the file;
    ``candela_raw`` (nv, nh) as in the file (vertical x horizontal), ``candela`` the same
    times the candela multiplier. The emitted intensity that :meth:`intensity` evaluates is
    ``candela`` x ``ballast_factor`` x ``ballast_lamp_factor`` (``output_factor``), unless
    asked without the ballast factors.
    """

    path: str
    version: int
    version_tag: str
    keywords: dict[str, list[str]]
    label: list[str]
    tilt_mode: str
    tilt: Tilt | None
    n_lamps: int
    lumens_per_lamp: float
    multiplier: float
    photometric_type: str
    units: int
    opening: Opening
    ballast_factor: float
    ballast_lamp_factor: float
    second_field: float
    second_field_meaning: str
    file_generation: str | None
    input_watts: float
    vertical_angles: np.ndarray
    horizontal_angles: np.ndarray
    candela_raw: np.ndarray
    candela: np.ndarray
    symmetry: str
    warnings: list[str] = field(default_factory=list)
    _interp: object = field(default=None, repr=False)
    _interp_key: tuple = field(default=(), repr=False)

    # ---- derived facts -------------------------------------------------------------------
    @property
    def absolute(self) -> bool:
        """Absolute photometry (lumens per lamp = -1)."""
        return self.lumens_per_lamp < 0

    @property
    def lamp_lumens(self) -> float | None:
        """Rated lamp lumens of the file (lamps x lumens per lamp), None for absolute."""
        return None if self.absolute else self.n_lamps * self.lumens_per_lamp

    @property
    def output_factor(self) -> float:
        return self.ballast_factor * self.ballast_lamp_factor

    def efficiency(self) -> float | None:
        """Luminaire flux / rated lamp flux (light output ratio) for relative photometry,
        None for absolute; the ballast factors are left out (they scale the lamps)."""
        lamp = self.lamp_lumens
        return None if not lamp else lumens(self, ballast=False) / lamp

    @property
    def vertical_range(self) -> tuple[float, float]:
        return float(self.vertical_angles[0]), float(self.vertical_angles[-1])

    # ---- evaluation ----------------------------------------------------------------------
    def _grid(self):
        key = (id(self.candela), self.photometric_type)
        if self._interp is None or self._interp_key != key:
            self._interp = _build_interpolant(self)
            self._interp_key = key
        return self._interp

    def native_candela(self, vertical, horizontal, ballast: bool = True):
        """Candela at the file's own angles (degrees; type C: gamma, C; types A/B: V, H),
        broadcast together."""
        v, h = np.broadcast_arrays(np.asarray(vertical, float), np.asarray(horizontal, float))
        out = self._grid().evaluate(v.ravel(), h.ravel()).reshape(v.shape)
        out = out * (self.output_factor if ballast else 1.0)
        return out if out.ndim else float(out)

    def candela_at(self, gamma, c, ballast: bool = True):
        """Candela toward the local-frame direction with vertical angle ``gamma`` (from -Z)
        and horizontal angle ``c`` (from +X toward +Y), degrees, numpy-broadcast. For types
        A/B the direction is converted to the file's (H, V) first."""
        g, cc = np.broadcast_arrays(np.asarray(gamma, float), np.asarray(c, float))
        if self.photometric_type == "C":
            out = self._grid().evaluate(g.ravel(), cc.ravel()).reshape(g.shape)
            out = out * (self.output_factor if ballast else 1.0)
            return out if out.ndim else float(out)
        return self.intensity(angles_to_direction(g, cc), ballast=ballast)

    # the brief's name: candela(gamma, c); ``candela`` is the grid, so this is the function
    def intensity(self, direction, ballast: bool = True):
        """Candela toward ``direction`` (..., 3) in the light's local frame (need not be unit
        length; a zero vector is an error)."""
        d = np.asarray(direction, dtype=float)
        if d.shape[-1:] != (3,):
            raise ValueError(f"direction must have 3 components, got shape {d.shape}")
        flat = d.reshape(-1, 3)
        n = np.linalg.norm(flat, axis=1)
        if np.any(n == 0) or not np.all(np.isfinite(n)):
            raise ValueError("direction must be a finite non-zero vector")
        flat = flat / n[:, None]
        if self.photometric_type == "C":
            g, c = direction_to_angles(flat)
            out = self._grid().evaluate(g, c)
        elif self.photometric_type == "B":
            hh = np.degrees(np.arcsin(np.clip(flat[:, 1], -1.0, 1.0)))
            vv = np.degrees(np.arctan2(flat[:, 0], -flat[:, 2]))
            out = self._grid().evaluate(vv, hh)
        else:  # A
            vv = np.degrees(np.arcsin(np.clip(flat[:, 0], -1.0, 1.0)))
            hh = np.degrees(np.arctan2(flat[:, 1], -flat[:, 2]))
            out = self._grid().evaluate(vv, hh)
        out = out * (self.output_factor if ballast else 1.0)
        out = out.reshape(d.shape[:-1])
        return out if out.ndim else float(out)


def candela(p: Photometry, gamma, c, ballast: bool = True):
    """Interpolated candela of ``p`` toward local (gamma, C), degrees, numpy-broadcast
    (gamma from -Z, C from +X toward +Y; see the module docstring)."""
    return p.candela_at(gamma, c, ballast=ballast)


def direction_to_angles(d):
    """(gamma, C) in degrees of local-frame directions (..., 3): gamma from -Z (0..180),
    C from +X toward +Y (0..360)."""
    d = np.asarray(d, dtype=float)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    gamma = np.degrees(np.arctan2(np.hypot(x, y), -z))
    c = np.mod(np.degrees(np.arctan2(y, x)), 360.0)
    return gamma, c


def angles_to_direction(gamma, c):
    """Unit local-frame directions (..., 3) of (gamma, C) in degrees."""
    g = np.radians(np.asarray(gamma, dtype=float))
    cc = np.radians(np.asarray(c, dtype=float))
    g, cc = np.broadcast_arrays(g, cc)
    return np.stack([np.sin(g) * np.cos(cc), np.sin(g) * np.sin(cc), -np.cos(g)], axis=-1)


# ===================================================================== reading


def read_ies(path) -> Photometry:
    """Reads an IES LM-63 file (any version). Raises IesError naming file, line and problem."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as e:
        raise IesError(p, None, f"cannot read the file: {e.strerror or e}") from None
    return parse_ies(data, path=str(p))


def _decode(data: bytes, path: str, warn) -> str:
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if b"\x00" in data:
        line = data[: data.index(b"\x00")].count(b"\n") + 1
        raise IesError(path, line, "a NUL byte: this is not a text file")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        warn(line, f"byte 0x{data[e.start]:02X} is not UTF-8; the file is read as Latin-1")
        return data.decode("latin-1")


class _Tokens:
    """Free-format numeric tokens with their line numbers."""

    def __init__(self, lines: list[str], first_line: int, path: str):
        self.path = path
        self.tok: list[str] = []
        self.line: list[int] = []
        for k, text in enumerate(lines):
            for t in _SPLIT.split(text.strip()):
                if t:
                    self.tok.append(t)
                    self.line.append(first_line + k)
        self.pos = 0
        # where the file ends: its last line with text (the TILT line when none follows)
        self.last_line = self.line[-1] if self.line else first_line - 1
        self.context = ""

    def _line_now(self) -> int:
        return self.line[self.pos] if self.pos < len(self.tok) else self.last_line

    def number(self, what: str) -> float:
        if self.pos >= len(self.tok):
            raise IesError(self.path, self.last_line,
                           f"the file ends (after line {self.last_line}) while reading "
                           f"{what}{self.context}")
        t, ln = self.tok[self.pos], self.line[self.pos]
        if not _NUMBER.match(t):
            raise IesError(self.path, ln, f"'{t}' is not a number (reading {what}){self.context}")
        self.pos += 1
        return float(t)

    def integer(self, what: str) -> int:
        ln = self._line_now()
        v = self.number(what)
        if abs(v - round(v)) > 1e-9:
            raise IesError(self.path, ln, f"{what} must be a whole number, found {v:g}")
        return int(round(v))

    def array(self, n: int, what: str) -> tuple[np.ndarray, np.ndarray]:
        start = self.pos
        vals = np.empty(n)
        for k in range(n):
            vals[k] = self.number(f"{what} (value {k + 1} of {n})")
        return vals, np.asarray(self.line[start:start + n], dtype=int)


def _version_of(first: str) -> tuple[int | None, str]:
    s = first.strip().upper().replace(" ", "")
    if s.startswith("IESNA91"):
        return 1991, first.strip()
    m = re.match(r"^IES(NA)?:?LM-63-(\d{4})", s)
    if m:
        return int(m.group(2)), first.strip()
    return None, ""


def _opening(version: int, w: float, l: float, h: float, units: int, warn, line: int) -> Opening:
    sg = tuple(int(np.sign(v)) for v in (w, l, h))
    aw, al, ah = abs(w), abs(l), abs(h)
    f = FOOT if units == 1 else 1.0

    def eq(a, b):
        return abs(a - b) <= 1e-6 * max(a, b, 1e-12)

    table = {(0, 0, 0): "point", (1, 1, 0): "rectangular",
             (1, 1, 1): "rectangular with luminous sides",
             (1, 0, 1): "vertical rectangle", (0, 1, 1): "vertical rectangle"}
    shape = table.get(sg)
    if shape is None:
        if version in (1986, 1991):
            shape = {(-1, 0, 0): "circular", (-1, 0, 1): "vertical cylinder",
                     (-1, 1, 0): "ellipse", (-1, 1, 1): "ellipsoid"}.get(sg)
        elif version == 1995:
            shape = {(-1, 0, 0): "circular", (-1, 0, -1): "sphere",
                     (-1, 0, 1): "vertical cylinder",
                     (0, 1, -1): "horizontal cylinder along photometric horizontal",
                     (1, 0, -1): "horizontal cylinder perpendicular to photometric horizontal",
                     (1, -1, 1): "vertical elliptical cylinder",
                     (-1, 1, 1): "vertical elliptical cylinder",
                     (1, -1, -1): "ellipsoid", (-1, 1, -1): "ellipsoid"}.get(sg)
            if shape == "sphere" and not eq(aw, ah):
                warn(line, f"sphere with width {w:g} and height {h:g}: the width is taken "
                           "as its diameter")
        else:  # 2002, 2019 (LM-63-2002 Table 1)
            if sg == (-1, -1, 0):
                shape = "circular" if eq(aw, al) else "ellipse"
            elif sg == (-1, -1, 1):
                shape = "vertical cylinder" if eq(aw, al) else "vertical ellipsoidal cylinder"
            elif sg == (-1, -1, -1):
                shape = "sphere" if eq(aw, al) and eq(aw, ah) else "ellipsoidal spheroid"
            elif sg == (-1, 1, -1):
                shape = ("horizontal cylinder along photometric horizontal" if eq(aw, ah)
                         else "horizontal ellipsoidal cylinder along photometric horizontal")
            elif sg == (1, -1, -1):
                shape = ("horizontal cylinder perpendicular to photometric horizontal"
                         if eq(al, ah) else
                         "horizontal ellipsoidal cylinder perpendicular to photometric horizontal")
            elif sg == (-1, 0, -1):
                shape = ("vertical circle facing photometric horizontal" if eq(aw, ah)
                         else "vertical ellipse facing photometric horizontal")
            elif sg == (-1, 0, 0):
                shape = "circular"
                warn(line, "circular opening written the LM-63-1995 way (negative width, "
                           "length 0) in a newer file; read as a circle of that diameter")
        if shape is None:
            shape = "unknown"
            warn(line, f"luminous opening signs ({w:g}, {l:g}, {h:g}) match no shape of the "
                       f"LM-63-{version} table; the absolute sizes are kept")
    return Opening(shape, aw * f, al * f, ah * f, (w, l, h), units)


def parse_ies(data: bytes | str, path: str = "<string>") -> Photometry:
    """Parses IES LM-63 text (bytes or str). ``path`` names the file in messages."""
    warned: list[str] = []

    def warn(line, msg):
        text = f"{path}: line {line}: {msg}" if line is not None else f"{path}: {msg}"
        warned.append(text)
        warnings.warn(IesWarning(text), stacklevel=3)

    text = data if isinstance(data, str) else _decode(data, path, warn)
    if text.startswith("\ufeff"):
        text = text[1:]
    lines = _LINES.split(text)
    if not text.strip():
        raise IesError(path, 1, "the file is empty")

    version, tag = _version_of(lines[0])
    start = 1
    if version is None:
        version, start = 1986, 0
    elif version not in VERSIONS:
        known = max([v for v in VERSIONS if v <= version] or [1986])
        warn(1, f"unknown version tag '{tag}'; read as LM-63-{known}")
        version = known

    keywords: dict[str, list[str]] = {}
    label: list[str] = []
    tilt_line = None
    last_key = None
    for k in range(start, len(lines)):
        s = lines[k].strip()
        m = re.match(r"^TILT\s*=\s*(.*)$", s, flags=re.IGNORECASE)
        if m:
            tilt_line, tilt_spec = k, m.group(1).strip()
            break
        label.append(lines[k])
        km = re.match(r"^\[([^\]]*)\]\s*(.*)$", s)
        if km:
            key, val = km.group(1).strip().upper(), km.group(2).rstrip()
            if key == "MORE" and last_key is not None:
                keywords[last_key][-1] += "\n" + val
            else:
                keywords.setdefault(key, []).append(val)
                last_key = key
        elif s and version >= 1991:
            warn(k + 1, f"label line without a [KEYWORD]: '{s[:40]}'")
    if tilt_line is None:
        raise IesError(path, len(lines),
                       "no TILT= line: the file ends before its photometric data "
                       "(every LM-63 file has TILT=NONE, TILT=INCLUDE or TILT=<file>)")

    tok = _Tokens(lines[tilt_line + 1:], tilt_line + 2, path)
    tilt = None
    spec = tilt_spec.upper()
    if spec == "NONE":
        mode = "NONE"
    elif spec == "INCLUDE":
        mode = "INCLUDE"
        ln = tok._line_now()
        geom = tok.integer("the tilt lamp-to-luminaire geometry")
        if geom not in (1, 2, 3):
            raise IesError(path, ln, f"tilt lamp-to-luminaire geometry must be 1, 2 or 3, "
                                     f"found {geom}")
        ln = tok._line_now()
        nt = tok.integer("the number of tilt angles")
        if nt < 1:
            raise IesError(path, ln, f"number of tilt angles must be at least 1, found {nt}")
        ta, tl = tok.array(nt, "the tilt angles")
        tf, fl = tok.array(nt, "the tilt multiplying factors")
        bad = np.nonzero(np.diff(ta) <= 0)[0]
        if bad.size:
            i = bad[0] + 1
            raise IesError(path, int(tl[i]), f"tilt angles must increase: {ta[i]:g} follows "
                                             f"{ta[i - 1]:g}")
        if np.any(tf < 0):
            i = int(np.nonzero(tf < 0)[0][0])
            raise IesError(path, int(fl[i]), f"negative tilt factor {tf[i]:g}")
        tilt = Tilt(geom, ta, tf)
    else:
        raise IesError(path, tilt_line + 1,
                       f"TILT={tilt_spec}: the tilt data are in a separate file "
                       f"'{tilt_spec}', which hirad does not read (not supported; LM-63-2019 "
                       "no longer allows it): put them in the file with TILT=INCLUDE")

    head_line = tok._line_now()
    n_lamps = tok.integer("the number of lamps")
    lumens_per_lamp = tok.number("the lumens per lamp")
    ln_mult = tok._line_now()
    multiplier = tok.number("the candela multiplier")
    ln_nv = tok._line_now()
    nv = tok.integer("the number of vertical angles")
    ln_nh = tok._line_now()
    nh = tok.integer("the number of horizontal angles")
    ln_type = tok._line_now()
    ptype = tok.integer("the photometric type")
    ln_units = tok._line_now()
    units = tok.integer("the units type")
    ln_open = tok._line_now()
    w = tok.number("the luminous opening width")
    l_ = tok.number("the luminous opening length")
    h = tok.number("the luminous opening height")
    ln_bf = tok._line_now()
    ballast = tok.number("the ballast factor")
    ln_second = tok._line_now()
    second = tok.number("the ballast-lamp photometric factor / future use / file generation "
                        "type")
    watts = tok.number("the input watts")

    if n_lamps < 1:
        warn(head_line, f"number of lamps is {n_lamps}")
    if lumens_per_lamp != -1 and lumens_per_lamp <= 0:
        warn(head_line, f"lumens per lamp {lumens_per_lamp:g} is neither -1 (absolute "
                        "photometry) nor positive; read as absolute photometry")
        lumens_per_lamp = -1.0
    if not multiplier > 0:
        raise IesError(path, ln_mult, f"candela multiplier must be positive, found "
                                      f"{multiplier:g}")
    if nv < 2:
        raise IesError(path, ln_nv, f"number of vertical angles must be at least 2, found {nv}")
    if nh < 1:
        raise IesError(path, ln_nh, f"number of horizontal angles must be at least 1, "
                                    f"found {nh}")
    if ptype not in (1, 2, 3):
        raise IesError(path, ln_type, f"photometric type must be 1 (C), 2 (B) or 3 (A), "
                                      f"found {ptype}")
    if units not in (1, 2):
        raise IesError(path, ln_units, f"units type must be 1 (feet) or 2 (metres), "
                                       f"found {units}")
    if not ballast > 0:
        raise IesError(path, ln_bf, f"ballast factor must be positive, found {ballast:g}")
    type_name = {1: "C", 2: "B", 3: "A"}[ptype]

    blp, file_gen = 1.0, None
    if version in (1986, 1991):
        meaning = "ballast-lamp photometric factor"
        if not second > 0:
            raise IesError(path, ln_second, f"ballast-lamp photometric factor must be "
                                            f"positive, found {second:g}")
        blp = second
    elif version in (1995, 2002):
        meaning = "future use"
        if second != 1:
            warn(ln_second, f"the 'future use' field of LM-63-{version} is {second:g}, not 1; "
                            "ignored (it is no photometric factor in this version)")
    else:
        meaning = "file generation type"
        code = f"{second:.5f}"
        file_gen = FILE_GENERATION_TYPES.get(code)
        if file_gen is None:
            file_gen = f"unknown code {second:g}"
            warn(ln_second, f"file generation type {second:g} is not a code of LM-63-2019 "
                            "Table 2")

    opening = _opening(version, w, l_, h, units, warn, ln_open)

    counts = (f" (line {head_line} declares {nv} vertical and {nh} horizontal angles)")
    tok.context = counts
    va, vl = tok.array(nv, "the vertical angles")
    ha, hl = tok.array(nh, "the horizontal angles")
    for arr, lns, what in ((va, vl, "vertical"), (ha, hl, "horizontal")):
        bad = np.nonzero(np.diff(arr) <= 0)[0]
        if bad.size:
            i = bad[0] + 1
            raise IesError(path, int(lns[i]),
                           f"{what} angles must increase: {arr[i]:g} follows {arr[i - 1]:g}"
                           f"{counts}")
    cand = np.empty((nh, nv))
    cand_lines = np.empty((nh, nv), dtype=int)
    for j in range(nh):
        row, rl = tok.array(nv, f"the candela values for horizontal angle {ha[j]:g}")
        cand[j], cand_lines[j] = row, rl
    if tok.pos < len(tok.tok):
        extra = len(tok.tok) - tok.pos
        warn(tok.line[tok.pos], f"{extra} value(s) after the candela table are ignored "
                                f"(first '{tok.tok[tok.pos]}'){counts}")
    neg = np.argwhere(cand < 0)
    if neg.size:
        j, i = neg[0]
        raise IesError(path, int(cand_lines[j, i]),
                       f"negative candela {cand[j, i]:g} at vertical {va[i]:g}, horizontal "
                       f"{ha[j]:g} ({len(neg)} negative value(s) in all)")

    # ranges and symmetry
    if type_name == "C":
        if va[0] < 0 or va[-1] > 180:
            raise IesError(path, int(vl[0] if va[0] < 0 else vl[-1]),
                           f"type C vertical angles must lie in 0..180, found "
                           f"{va[0]:g}..{va[-1]:g}")
        if (va[0], va[-1]) not in ((0, 90), (90, 180), (0, 180)):
            warn(int(vl[0]), f"vertical angles run {va[0]:g}..{va[-1]:g}, not 0-90, 90-180 or "
                             "0-180; no light is assumed outside them")
        symmetry = _type_c_symmetry(ha, hl, path)
    else:
        if va[0] < -90 or va[-1] > 90:
            raise IesError(path, int(vl[0] if va[0] < -90 else vl[-1]),
                           f"type {type_name} vertical angles must lie in -90..90, found "
                           f"{va[0]:g}..{va[-1]:g}")
        if ha[0] < -90 or ha[-1] > 90:
            raise IesError(path, int(hl[0] if ha[0] < -90 else hl[-1]),
                           f"type {type_name} horizontal angles must lie in -90..90, found "
                           f"{ha[0]:g}..{ha[-1]:g}")
        if nh == 1:
            raise IesError(path, int(hl[0]), f"type {type_name} needs at least 2 horizontal "
                                             "angles")
        if ha[0] == 0:
            symmetry = "laterally symmetric (H 0..%g mirrored to -H)" % ha[-1]
        elif ha[0] == -ha[-1] or ha[0] < 0:
            symmetry = "none (H %g..%g)" % (ha[0], ha[-1])
        else:
            raise IesError(path, int(hl[0]), f"type {type_name} horizontal angles must start at "
                                             f"0 or below, found {ha[0]:g}")

    phot = Photometry(
        path=path, version=version, version_tag=tag, keywords=keywords, label=label,
        tilt_mode=mode, tilt=tilt, n_lamps=n_lamps, lumens_per_lamp=lumens_per_lamp,
        multiplier=multiplier, photometric_type=type_name, units=units, opening=opening,
        ballast_factor=ballast, ballast_lamp_factor=blp, second_field=second,
        second_field_meaning=meaning, file_generation=file_gen, input_watts=watts,
        vertical_angles=va, horizontal_angles=ha, candela_raw=cand.T.copy(),
        candela=cand.T * multiplier, symmetry=symmetry, warnings=warned)
    phot._interp = _build_interpolant(phot, warn)
    phot._interp_key = (id(phot.candela), phot.photometric_type)
    return phot


def _type_c_symmetry(ha, hl, path) -> str:
    first, last = ha[0], ha[-1]
    if len(ha) == 1:
        if first != 0:
            warn_line = int(hl[0])
            raise IesError(path, warn_line, f"a single horizontal angle must be 0 (axial "
                                            f"symmetry), found {first:g}")
        return "axial (C 0)"
    if first == 0 and last == 90:
        return "quadrilateral (C 0-90)"
    if first == 0 and last == 180:
        return "bilateral about C0-C180 (C 0-180)"
    if first == 90 and last == 270:
        return "bilateral about C90-C270 (C 90-270)"
    if first == 0 and 180 < last <= 360:
        return "none (C 0-%g)" % last
    if first < 0 or last > 360:
        raise IesError(path, int(hl[0] if first < 0 else hl[-1]),
                       f"type C horizontal angles must lie in 0..360, found {first:g}..{last:g}")
    raise IesError(path, int(hl[-1]),
                   f"horizontal angles {first:g}..{last:g} are no LM-63 symmetry (0; 0-90; "
                   "0-180; 90-270; 0 to more than 180 up to 360)")


# ===================================================================== interpolation


def _pchip_slopes(h0, h1, s0, s1):
    """Fritsch-Carlson (Brodlie weighted harmonic mean) slope at the node between an interval
    of width h0 and slope s0 and one of width h1 and slope s1."""
    w1 = 2.0 * h1 + h0
    w2 = h1 + 2.0 * h0
    same = (s0 * s1) > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        d = (w1 + w2) / (w1 / np.where(same, s0, 1.0) + w2 / np.where(same, s1, 1.0))
    return np.where(same, d, 0.0)


def _hermite4(x4, y4, x):
    """Monotone cubic on [x4[:,1], x4[:,2]] from the 4-node stencil; y4 (N,4) or (N,4,K)."""
    if y4.ndim == 3:
        x4 = x4[:, :, None]
        x = x[:, None]
    h0 = x4[:, 1] - x4[:, 0]
    h1 = x4[:, 2] - x4[:, 1]
    h2 = x4[:, 3] - x4[:, 2]
    s0 = (y4[:, 1] - y4[:, 0]) / h0
    s1 = (y4[:, 2] - y4[:, 1]) / h1
    s2 = (y4[:, 3] - y4[:, 2]) / h2
    d1 = _pchip_slopes(h0, h1, s0, s1)
    d2 = _pchip_slopes(h1, h2, s1, s2)
    t = (x - x4[:, 1]) / h1
    t2, t3 = t * t, t * t * t
    return ((2 * t3 - 3 * t2 + 1) * y4[:, 1] + (t3 - 2 * t2 + t) * h1 * d1
            + (-2 * t3 + 3 * t2) * y4[:, 2] + (t3 - t2) * h1 * d2)


class _Grid2D:
    """Tensor PCHIP on padded nodes. Axis u is bounded (zero outside [u_lo, u_hi]); axis w is
    bounded too or periodic (360). ``up`` (nu+2,) and ``wp`` have one ghost node in front
    and one (bounded) or two (periodic) behind; ``vals`` is (len(up), len(wp))."""

    def __init__(self, up, wp, vals, w_periodic: bool):
        self.up, self.wp, self.vals = up, wp, vals
        self.w_periodic = w_periodic
        self.nu = len(up) - 2  # real u nodes
        self.nw = len(wp) - (3 if w_periodic else 2)  # real w nodes
        self.u_lo, self.u_hi = up[1], up[self.nu]
        self.w_lo = wp[1]
        self.w_hi = wp[self.nw] if not w_periodic else wp[1] + 360.0
        self.peak = float(vals[1:self.nu + 1, 1:self.nw + 1].max()) if vals.size else 0.0

    def evaluate(self, u, w):
        u = np.asarray(u, dtype=float).ravel()
        w = np.asarray(w, dtype=float).ravel()
        out = np.zeros(u.shape)
        if self.w_periodic:
            w = self.w_lo + np.mod(w - self.w_lo, 360.0)
            inside = (u >= self.u_lo - 1e-9) & (u <= self.u_hi + 1e-9)
        else:
            inside = ((u >= self.u_lo - 1e-9) & (u <= self.u_hi + 1e-9)
                      & (w >= self.w_lo - 1e-9) & (w <= self.w_hi + 1e-9))
        idx = np.nonzero(inside)[0]
        for s in range(0, idx.size, 65536):
            k = idx[s:s + 65536]
            out[k] = self._eval(np.clip(u[k], self.u_lo, self.u_hi),
                                np.clip(w[k], self.w_lo, self.w_hi))
        return np.maximum(out, 0.0)

    def evaluate_grid(self, uq, wq):
        """The same interpolant on the tensor grid uq x wq, (len(uq), len(wq)), by two 1-D
        passes (along u for every node column, then along w): identical values, far less
        work than point by point."""
        uq = np.asarray(uq, dtype=float)
        wq = np.asarray(wq, dtype=float)
        out = np.zeros((uq.size, wq.size))
        ui = (uq >= self.u_lo - 1e-9) & (uq <= self.u_hi + 1e-9)
        if self.w_periodic:
            wq = self.w_lo + np.mod(wq - self.w_lo, 360.0)
            wi = np.ones(wq.shape, dtype=bool)
        else:
            wi = (wq >= self.w_lo - 1e-9) & (wq <= self.w_hi + 1e-9)
        if not ui.any() or not wi.any():
            return out
        u = np.clip(uq[ui], self.u_lo, self.u_hi)
        w = np.clip(wq[wi], self.w_lo, self.w_hi)
        ureal = self.up[1:self.nu + 1]
        i = np.clip(np.searchsorted(ureal, u, side="right") - 1, 0, self.nu - 2)
        r = i[:, None] + np.arange(4)[None, :]
        cols = _hermite4(self.up[r], self.vals[r], u)  # (nuq, all padded columns)
        if self.w_periodic:
            wreal = self.wp[1:self.nw + 2]
            j = np.clip(np.searchsorted(wreal, w, side="right") - 1, 0, self.nw - 1)
        else:
            wreal = self.wp[1:self.nw + 1]
            j = np.clip(np.searchsorted(wreal, w, side="right") - 1, 0, self.nw - 2)
        c = j[:, None] + np.arange(4)[None, :]  # (nwq, 4)
        y = cols[:, c]  # (nuq, nwq, 4)
        nuq, nwq = y.shape[0], y.shape[1]
        x4 = np.broadcast_to(self.wp[c][None], (nuq, nwq, 4)).reshape(-1, 4)
        xw = np.broadcast_to(w[None, :], (nuq, nwq)).ravel()
        res = _hermite4(x4, y.reshape(-1, 4), xw).reshape(nuq, nwq)
        out[np.ix_(ui, wi)] = np.maximum(res, 0.0)
        return out

    def _eval(self, u, w):
        ureal = self.up[1:self.nu + 1]
        i = np.clip(np.searchsorted(ureal, u, side="right") - 1, 0, self.nu - 2)
        if self.w_periodic:
            wreal = self.wp[1:self.nw + 2]  # includes the wrap node w_lo + 360
            j = np.clip(np.searchsorted(wreal, w, side="right") - 1, 0, self.nw - 1)
        else:
            wreal = self.wp[1:self.nw + 1]
            j = np.clip(np.searchsorted(wreal, w, side="right") - 1, 0, self.nw - 2)
        r = i[:, None] + np.arange(4)[None, :]
        c = j[:, None] + np.arange(4)[None, :]
        v = self.vals[r[:, :, None], c[:, None, :]]  # (N,4,4)
        col = _hermite4(self.up[r], v, u)  # (N,4): along u for each of 4 w nodes
        return _hermite4(self.wp[c], col, w)


def _lin_ghost(x0, x1, y0, y1):
    return 2 * x0 - x1, 2 * y0 - y1


def _pole_mean(vals, axis_index, along_axis, warn, line_hint, what, peak):
    """Makes the pole row/column one value (the mean), warning if it varied."""
    sl = [slice(None), slice(None)]
    sl[along_axis] = axis_index
    row = vals[tuple(sl)]
    spread = float(row.max() - row.min()) if row.size else 0.0
    if warn is not None and peak > 0 and spread > 1e-3 * peak:
        warn(line_hint, f"the candela at {what} differ by {spread:g} cd between planes; a pole "
                        "is one direction, their mean is used")
    vals[tuple(sl)] = row.mean()


def _build_interpolant(p: Photometry, warn=None) -> _Grid2D:
    va = p.vertical_angles.astype(float)
    ha = p.horizontal_angles.astype(float)
    T = p.candela.astype(float).copy()  # (nv, nh)
    peak = float(T.max()) if T.size else 0.0
    if p.photometric_type == "C":
        C, T = _expand_type_c(ha, T, warn, peak)
        # poles: one value
        if va[0] == 0:
            _pole_mean(T, 0, 0, warn, None, "gamma = 0 (nadir)", peak)
        if va[-1] == 180:
            _pole_mean(T, -1, 0, warn, None, "gamma = 180 (zenith)", peak)
        m = len(C)
        # periodic w padding: one ghost before, two after
        wp = np.concatenate([[C[-1] - 360.0], C, [C[0] + 360.0, C[1 % m] + 360.0 if m > 1
                                                  else C[0] + 720.0]])
        Tw = np.concatenate([T[:, -1:], T, T[:, :1], T[:, 1 % m:1 % m + 1]], axis=1)

        def opposite(row):  # values at C + 180 of a row given on C (periodic linear)
            cc = np.concatenate([C, [C[0] + 360.0]])
            rr = np.concatenate([row, row[:1]])
            q = C[0] + np.mod(wp + 180.0 - C[0], 360.0)
            return np.interp(q, cc, rr)

        if va[0] == 0:
            g_lo, row_lo = -va[1], opposite(T[1])
        else:
            g_lo, row_lo = _lin_ghost(va[0], va[1], Tw[0], Tw[1])
        if va[-1] == 180:
            g_hi, row_hi = 360.0 - va[-2], opposite(T[-2])
        else:
            g_hi, row_hi = _lin_ghost(va[-1], va[-2], Tw[-1], Tw[-2])
        up = np.concatenate([[g_lo], va, [g_hi]])
        vals = np.vstack([row_lo, Tw, row_hi])
        return _Grid2D(up, wp, vals, w_periodic=True)

    # types A and B: rows V, columns H (lateral symmetry mirrored)
    if ha[0] == 0:
        H = np.concatenate([-ha[:0:-1], ha])
        T = np.concatenate([T[:, :0:-1], T], axis=1)
    else:
        H = ha
    if p.photometric_type == "B":  # poles at H = +-90
        for k in (0, len(H) - 1):
            if abs(H[k]) == 90:
                _pole_mean(T, k, 1, warn, None, f"H = {H[k]:g} (the polar axis)", peak)
    else:  # A: poles at V = +-90
        for k in (0, len(va) - 1):
            if abs(va[k]) == 90:
                _pole_mean(T, k, 0, warn, None, f"V = {va[k]:g} (the polar axis)", peak)
    gw0, cw0 = _lin_ghost(H[0], H[1], T[:, 0], T[:, 1])
    gw1, cw1 = _lin_ghost(H[-1], H[-2], T[:, -1], T[:, -2])
    wp = np.concatenate([[gw0], H, [gw1]])
    Tw = np.column_stack([cw0, T, cw1])
    gu0, ru0 = _lin_ghost(va[0], va[1], Tw[0], Tw[1])
    gu1, ru1 = _lin_ghost(va[-1], va[-2], Tw[-1], Tw[-2])
    up = np.concatenate([[gu0], va, [gu1]])
    vals = np.vstack([ru0, Tw, ru1])
    return _Grid2D(up, wp, vals, w_periodic=False)


def _expand_type_c(ha, T, warn, peak):
    """Full-circle C nodes in [0, 360) (or [90, 450) for 90-270 data) and their columns."""
    first, last = ha[0], ha[-1]
    if len(ha) == 1:
        C = np.array([0.0, 90.0, 180.0, 270.0])
        return C, np.repeat(T, 4, axis=1)
    if first == 0 and last == 90:
        C = np.concatenate([ha, 180.0 - ha[-2::-1]])
        T = np.concatenate([T, T[:, -2::-1]], axis=1)
        first, last = 0.0, 180.0
        ha = C
    if first == 0 and last == 180:
        C = np.concatenate([ha, 360.0 - ha[-2:0:-1]])
        T = np.concatenate([T, T[:, -2:0:-1]], axis=1)
        return C, T
    if first == 90 and last == 270:
        # mirror about the C90-C270 plane: I(C) = I(180 - C); C' = 180 - C in (-90, 90)
        C = np.concatenate([ha, 180.0 - ha[-2:0:-1] + 360.0])  # (270, 450) for C in (90,270)
        T = np.concatenate([T, T[:, -2:0:-1]], axis=1)
        order = np.argsort(C)
        return C[order], T[:, order]
    # none: 0 .. (180, 360]
    if last == 360:
        d = float(np.abs(T[:, -1] - T[:, 0]).max())
        if warn is not None and peak > 0 and d > 1e-3 * peak:
            warn(None, f"the C360 column differs from C0 by up to {d:g} cd; C0 is used")
        return ha[:-1], T[:, :-1]
    return ha, T


# ===================================================================== results

_GL_X, _GL_W = np.polynomial.legendre.leggauss(6)


def _cells(nodes, per=6):
    a, b = nodes[:-1], nodes[1:]
    mid, half = 0.5 * (a + b), 0.5 * (b - a)
    x = (mid[:, None] + half[:, None] * _GL_X[None, :]).ravel()
    wgt = (half[:, None] * _GL_W[None, :]).ravel()
    return x, wgt


def lumens(p: Photometry, ballast: bool = True) -> float:
    """Luminous flux (lm) of the interpolated distribution, Phi = integral of I dOmega, by
    Gauss-Legendre quadrature inside every cell of the expanded grid."""
    g = p._grid()
    if p.photometric_type == "C":
        u = p.vertical_angles.astype(float)
        wn = np.concatenate([g.wp[1:g.nw + 1], [g.wp[1] + 360.0]])
    else:
        u = p.vertical_angles.astype(float)
        wn = g.wp[1:g.nw + 1]
    xu, wu = _cells(u)
    xw, ww = _cells(wn)
    vals = g.evaluate_grid(xu, xw)
    if p.photometric_type == "C":
        jac_u = np.sin(np.radians(xu))  # sin(gamma)
        jac_w = np.ones_like(xw)
    elif p.photometric_type == "B":  # dOmega = cos H dH dV ; u = V, w = H
        jac_u = np.ones_like(xu)
        jac_w = np.cos(np.radians(xw))
    else:  # A: dOmega = cos V dV dH
        jac_u = np.cos(np.radians(xu))
        jac_w = np.ones_like(xw)
    total = float(np.einsum("i,ij,j->", wu * jac_u, vals, ww * jac_w))
    total *= (math.pi / 180.0) ** 2
    return total * (p.output_factor if ballast else 1.0)


def peak_candela(p: Photometry, ballast: bool = True) -> tuple[float, float, float]:
    """(peak candela, gamma, C) of the distribution: the monotone interpolant never exceeds
    the largest tabulated value, so the peak is that value; its direction in local (gamma, C)
    degrees."""
    g = p._grid()  # the nodes after symmetry expansion and pole averaging
    T = g.vals[1:g.nu + 1, 1:g.nw + 1]
    iv, ih = np.unravel_index(int(np.argmax(T)), T.shape)
    v, h = float(g.up[1 + iv]), float(g.wp[1 + ih]) % 360.0
    if p.photometric_type == "C":
        g, c = v, h
    elif p.photometric_type == "B":
        hr, vr = math.radians(h), math.radians(v)
        d = np.array([math.cos(hr) * math.sin(vr), math.sin(hr), -math.cos(hr) * math.cos(vr)])
        g, c = (float(a) for a in direction_to_angles(d))
    else:
        hr, vr = math.radians(h), math.radians(v)
        d = np.array([math.sin(vr), math.cos(vr) * math.sin(hr), -math.cos(vr) * math.cos(hr)])
        g, c = (float(a) for a in direction_to_angles(d))
    return float(T.max()) * (p.output_factor if ballast else 1.0), g, c


def plane_curve(p: Photometry, plane: str, step: float = 0.05, ballast: bool = True):
    """(theta, candela) along a plane through the Z axis: ``plane`` "C0-C180" (theta > 0 on
    the C0 side, +X) or "C90-C270" (theta > 0 on the C90 side, +Y); theta in degrees from
    nadir, -180..180."""
    theta = np.arange(-180.0, 180.0 + step / 2, step)
    t = np.radians(theta)
    if plane == "C0-C180":
        d = np.stack([np.sin(t), np.zeros_like(t), -np.cos(t)], axis=1)
    elif plane == "C90-C270":
        d = np.stack([np.zeros_like(t), np.sin(t), -np.cos(t)], axis=1)
    else:
        raise ValueError(f"plane must be 'C0-C180' or 'C90-C270', got {plane!r}")
    return theta, np.asarray(p.intensity(d, ballast=ballast))


def _spread(theta, vals, frac):
    peak = float(vals.max())
    if peak <= 0:
        return None
    thr = frac * peak
    above = np.nonzero(vals >= thr)[0]
    a, b = above[0], above[-1]
    if a == 0 and b == len(vals) - 1:
        return 360.0

    def cross(i_out, i_in):  # linear crossing between an outside and an inside sample
        y0, y1 = vals[i_out], vals[i_in]
        f = (thr - y0) / (y1 - y0) if y1 != y0 else 0.0
        return theta[i_out] + f * (theta[i_in] - theta[i_out])

    lo = theta[a] if a == 0 else cross(a - 1, a)
    hi = theta[b] if b == len(vals) - 1 else cross(b + 1, b)
    return float(hi - lo)


def beam_field_angles(p: Photometry) -> list[PlaneAngles]:
    """Beam (50 % of the plane's peak) and field (10 %) angles in the C0-C180 and C90-C270
    planes: the angle between the outermost directions of the plane at that fraction
    (crossings interpolated linearly between 0.05 degree samples of the interpolant)."""
    out = []
    for plane in ("C0-C180", "C90-C270"):
        theta, vals = plane_curve(p, plane)
        out.append(PlaneAngles(plane, float(vals.max()), _spread(theta, vals, 0.5),
                               _spread(theta, vals, 0.1)))
    return out


def polar_plot(p: Photometry, out_path, title: str | None = None) -> Path:
    """Polar candela diagram (PNG): the C0-C180 plane (solid; C0 to the right) and the
    C90-C270 plane (dashed; C90 to the right), nadir at the bottom. Needs matplotlib."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise RuntimeError("the polar plot needs matplotlib (pip install matplotlib)") from e
    out = Path(out_path)
    fig = plt.figure(figsize=(6.4, 6.4), dpi=110)
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("S")
    ax.set_theta_direction(1)
    for plane, style in (("C0-C180", "-"), ("C90-C270", "--")):
        theta, vals = plane_curve(p, plane, step=0.25)
        ax.plot(np.radians(theta), vals, style, label=plane)
    ticks = np.arange(0, 360, 30)
    ax.set_thetagrids(ticks, [f"{t if t <= 180 else 360 - t}\u00b0" for t in ticks])
    from matplotlib.ticker import MaxNLocator
    ax.yaxis.set_major_locator(MaxNLocator(4))
    ax.set_rlabel_position(100)
    ax.set_title(title or Path(p.path).name, pad=18)
    ax.legend(loc="upper right", bbox_to_anchor=(1.12, 1.1))
    ax.text(1.0, 0.0, "right: C0 / C90 \u2192", transform=ax.transAxes, ha="right")
    ax.text(0.0, 0.0, "\u2190 left: C180 / C270", transform=ax.transAxes, ha="left")
    ax.text(0.5, -0.1, "candela (cd); 0\u00b0 = nadir (local -Z)", transform=ax.transAxes,
            ha="center")
    fig.tight_layout()
    fig.savefig(out, format="png")
    plt.close(fig)
    return out


def _fmt(a):
    return "-" if a is None else f"{a:.1f} deg"


def ies_command(path, plot: Path | None = None) -> str:
    """The text report of ``hirad ies FILE.ies [--plot out.png]``. Raises IesError for a bad
    file (the CLI turns it into a non-zero exit)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IesWarning)
        p = read_ies(path)
    phi = lumens(p)
    phi_nb = lumens(p, ballast=False)
    pk, pg, pc = peak_candela(p)
    down = _flux_part(p, 0.0, 90.0)
    lines = [
        f"IES file: {p.path}",
        f"version: LM-63-{p.version}" + (f" ({p.version_tag})" if p.version_tag else
                                          " (no tag: 1986)"),
        f"photometric type: {p.photometric_type}",
        f"symmetry: {p.symmetry}",
        f"angles: vertical {p.vertical_angles[0]:g}..{p.vertical_angles[-1]:g} "
        f"({len(p.vertical_angles)}), horizontal {p.horizontal_angles[0]:g}.."
        f"{p.horizontal_angles[-1]:g} ({len(p.horizontal_angles)})",
        "photometry: " + ("absolute (lumens per lamp -1)" if p.absolute else
                           f"relative, {p.n_lamps} lamp(s) x {p.lumens_per_lamp:g} lm"),
        f"candela multiplier: {p.multiplier:g}; ballast factor: {p.ballast_factor:g}; "
        f"{p.second_field_meaning}: {p.second_field:g}"
        + (f" ({p.file_generation})" if p.file_generation else ""),
        f"luminous opening: {p.opening.shape}, width {p.opening.width_m:.4g} m, length "
        f"{p.opening.length_m:.4g} m, height {p.opening.height_m:.4g} m "
        f"(file in {p.opening.units_name})",
        f"tilt: {p.tilt_mode}",
        f"lumens (zonal integration of the interpolated distribution): {phi:.2f} lm"
        + (f" ({phi_nb:.2f} lm before the ballast factors)" if p.output_factor != 1 else ""),
        f"  downward (gamma 0-90): {down:.2f} lm, upward: {phi - down:.2f} lm",
    ]
    if not p.absolute and p.lamp_lumens:
        lines.append(f"  luminaire efficiency: {100.0 * phi_nb / p.lamp_lumens:.1f} % of "
                     f"{p.lamp_lumens:g} rated lamp lumens")
    lines.append(f"peak candela: {pk:.1f} cd at gamma {pg:.1f}, C {pc:.1f} (local frame)")
    for a in beam_field_angles(p):
        lines.append(f"{a.plane} plane: peak {a.peak_cd:.1f} cd, beam angle (50 %) "
                     f"{_fmt(a.beam_deg)}, field angle (10 %) {_fmt(a.field_deg)}")
    lines.append("axes: gamma 0 = local -Z (nadir), C0 = +X, C90 = +Y")
    if p.warnings:
        lines.append("warnings:")
        lines += [f"  {w}" for w in p.warnings]
    if plot is not None:
        out = polar_plot(p, plot)
        lines.append(f"polar plot: {out}")
    return "\n".join(lines) + "\n"


def _flux_part(p: Photometry, g0: float, g1: float) -> float:
    """Flux into the zone gamma in [g0, g1] of the local frame (with the ballast factors).
    Types A and B span V and H of at most +-90 degrees, which is the lower hemisphere
    (d_z = -cos H cos V <= 0): there the zone 0-90 holds all the flux and 90-180 none."""
    if p.photometric_type != "C":
        return lumens(p) if (g0, g1) == (0.0, 90.0) else 0.0 if (g0, g1) == (90.0, 180.0) \
            else float("nan")
    g = p._grid()
    u = p.vertical_angles.astype(float)
    u = np.unique(np.clip(np.concatenate([u, [g0, g1]]), g0, g1))
    wn = np.concatenate([g.wp[1:g.nw + 1], [g.wp[1] + 360.0]])
    xu, wu = _cells(u)
    xw, ww = _cells(wn)
    vals = g.evaluate_grid(xu, xw)
    return float(np.einsum("i,ij,j->", wu * np.sin(np.radians(xu)), vals, ww)
                 * (math.pi / 180.0) ** 2) * p.output_factor
