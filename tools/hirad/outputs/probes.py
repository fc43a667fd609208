"""L2 spherical-harmonic light probes: conversions to game engines' layouts, the files
probes.json and probes.bin written beside volume.vdb, and their reader.

The method
----------
A probe at x in empty space stores the projection of the incident radiance L(x, w) onto the
9 real spherical harmonics of bands l = 0, 1, 2 ("L2 SH"), orthonormal over the sphere:

    c_k = integral over the sphere of L(w) Y_k(w) dw        (k = l (l + 1) + m, 0..8)

with Y_k the real SH of Ramamoorthi & Hanrahan, "An efficient representation for irradiance
environment maps", SIGGRAPH 2001, eq. 3 (all constants positive, no Condon-Shortley phase),
for a unit direction w = (x, y, z) pointing from the probe towards where the light comes from:

    Y_0 = 0.282095            Y_1 = 0.488603 y          Y_2 = 0.488603 z
    Y_3 = 0.488603 x          Y_4 = 1.092548 x y        Y_5 = 1.092548 y z
    Y_6 = 0.315392 (3z^2 - 1) Y_7 = 1.092548 x z        Y_8 = 0.546274 (x^2 - y^2)

(1/2 sqrt(1/pi), 1/2 sqrt(3/pi), 1/2 sqrt(15/pi), 1/4 sqrt(5/pi), 1/4 sqrt(15/pi)). The engine
integrates them with the volume's stratified rays (pipeline/outputs/volume.h). c has the units
of irradiance (W/m^2, or lm/m^2 = lux when photometric) per unit of Y; RGB, linear Rec.709.

Irradiance on a surface facing the unit normal n follows by convolving with the clamped cosine
(R&H eq. 7-8; Funk-Hecke): band l is scaled by A_0 = pi, A_1 = 2 pi / 3, A_2 = pi / 4:

    E(n) = sum_k A_l(k) c_k Y_k(n)                                      (irradiance())

accurate to about 3 % on average and 9 % at worst for any lighting (R&H section 3). A white
Lambertian surface facing n reflects the radiance E(n) / pi.

Frames
------
The plain coefficients and positions are in hirad's world frame: metres, the stage's axes
(its up axis is recorded). Engine layouts are in the engine's frame: the positions and the
radiance function are carried over by the same orthogonal matrix M (engine = M world), and
the coefficients by the matching 9 x 9 block rotation (rotate_sh2):
  - Godot 4 (and glTF): right-handed, +Y up. A Y-up stage is taken as is; a Z-up stage turns
    by -90 degrees about X: (x, y, z) -> (x, z, -y).
  - Unity: left-handed, +Y up: Godot's frame with X negated (x -> -x), the mirror that UnityGLTF
    applies to glTF (SchemaExtensions.CoordinateSpaceConversionScale = (-1, 1, 1)). Positions in probes.json "unity" use it too.

Engine layouts
--------------
Unity, SphericalHarmonicsL2 (docs: Rendering.SphericalHarmonicsL2.this[int, int]: the first
index is the RGB channel 0..2, the second 0..8 "the single 0th degree term, the three 1st
degree terms, the five 2nd degree terms"): per probe [rgb][9], coefficient order as above.
Unity stores the coefficients already convolved with the clamped cosine and divided by pi,
with the basis constants folded in, so that the shader (ShadeSH9 and the SRP's evaluation)
computes E(n) / pi = (u0 - u6) + u3 x + u1 y + u2 z + u4 xy + u5 yz + 3 u6 z^2 + u7 xz +
u8 (x^2 - y^2). This is documented in Unity's own SRP source (Unity-Technologies/Graphics,
SphericalHarmonicMath: "invNormConsts", the inverse of SphericalHarmonicsL2::kNormalization-
Constants, {1/c0, -1/c1, 1/c1, -1/c1, 1/c2, -1/c2, 1/c3, -1/c2, 1/c4} with c0 = 1/2 sqrt(1/pi),
c1 = 1/3 sqrt(3/pi), c2 = 1/8 sqrt(15/pi), c3 = 1/16 sqrt(5/pi), c4 = 1/16 sqrt(15/pi), mapping
Unity's stored values to canonical SH with the Condon-Shortley signs of its basis; the signs
cancel against the R&H basis used here). So
    unity_k = c_k * Y-constant_k * A_l / pi = c_k * (c0, c1, c1, c1, c2, c2, c3, c2, c4)_k.
AddAmbientLight(colour) adding colour to coefficient 0 (uniform radiance colour -> E/pi =
colour) is the same convention.

Godot 4, LightmapGI probes (LightmapGIData's probe_data["sh"], a PackedColorArray of 9 Colors
per point of probe_data["points"], scene/3d/lightmap_gi.cpp): per probe [9][rgb], the same order as R&H (l0, l1n1 y, l1n0 z, l1p1 x, l2n2 xy, l2n1 yz, l20, l2p1 xz,
l2p2). Godot's lightmapper (modules/lightmapper_rd, lm_compute.glsl MODE_LIGHT_PROBES)
accumulates L Y_k over uniform sphere rays times 4 / N, i.e. c_k / pi, and its scene shader
evaluates c[0] sh0 + c[1] (sh1 y + sh2 z + sh3 x) + c[2] (sh4 xy + sh5 yz + sh7 xz) +
c[3] sh6 (3z^2 - 1) + c[4] sh8 (x^2 - y^2) with c = (0.886227, 1.023327, 0.858086, 0.247708,
0.429043) = Y-constants x A_l: E(n) / pi again. So godot_k = c_k / pi.

Files
-----
probes.json: {"format": "hirad-probes", "version": 1, "units", "up_axis", "conventions":
{...}, "count", "plain": {"positions": [[x, y, z], ...], "sh2": [[[r, g, b] x 9], ...]},
"unity": {"positions", "coefficients": [[[9] x 3], ...]}, "godot": {"positions",
"coefficients": [[[r, g, b] x 9], ...]}}. Values are the float32 numbers of probes.bin,
written with 9 significant digits (enough for any float32), so both files read back to the
same bits.

probes.bin, little-endian throughout:
    offset  size  field
    0       8     magic b"HIRADSH2"
    8       4     uint32 version (1)
    12      4     uint32 header size in bytes (64)
    16      8     uint64 n, the probe count
    24      4     uint32 coefficients per channel (9)
    28      4     uint32 channels (3)
    32      8     float64 lattice spacing, m
    40      4     uint32 units: 0 radiometric (W/m^2), 1 photometric (lm/m^2)
    44      4     uint32 stage up axis: 1 Y, 2 Z
    48      8     uint64 payload size in bytes (= 360 n)
    56      4     uint32 CRC-32 (zlib) of the payload
    60      4     uint32 CRC-32 of header bytes 0..59
    64      ...   payload, float32, in order:
                  plain positions (n, 3), plain sh2 (n, 9, 3) [probe][k][rgb],
                  unity positions (n, 3), unity coefficients (n, 3, 9) [probe][rgb][k],
                  godot positions (n, 3), godot coefficients (n, 9, 3) [probe][k][rgb]
"""

from __future__ import annotations

import json
import math
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BakeError

MAGIC = b"HIRADSH2"
VERSION = 1
HEADER = struct.Struct("<8sIIQIIdIIQII")  # 64 bytes
assert HEADER.size == 64

# Real orthonormal SH constants (R&H 2001): Y_k = K[k] * poly_k(x, y, z).
_K0, _K1 = 0.5 * math.sqrt(1 / math.pi), 0.5 * math.sqrt(3 / math.pi)
_K2, _K3, _K4 = 0.5 * math.sqrt(15 / math.pi), 0.25 * math.sqrt(5 / math.pi), 0.25 * math.sqrt(15 / math.pi)
SH_CONSTANTS = np.array([_K0, _K1, _K1, _K1, _K2, _K2, _K3, _K2, _K4])
BAND = np.array([0, 1, 1, 1, 2, 2, 2, 2, 2])
# The clamped cosine's convolution weights per band (R&H eq. 8).
COSINE_LOBE = np.array([math.pi, 2 * math.pi / 3, math.pi / 4])[BAND]
# Unity's stored value per unit plain coefficient: Y-constant x A_l / pi (see the docstring).
UNITY_SCALE = SH_CONSTANTS * COSINE_LOBE / math.pi
GODOT_SCALE = np.full(9, 1 / math.pi)

CONVENTIONS = {
    "basis": "real spherical harmonics, bands 0-2, orthonormal over the sphere; Ramamoorthi & Hanrahan 2001 "
             "(An efficient representation for irradiance environment maps) eq. 3, no Condon-Shortley phase",
    "order": ["Y00 = 0.282095", "Y1-1 = 0.488603 y", "Y10 = 0.488603 z", "Y11 = 0.488603 x",
              "Y2-2 = 1.092548 xy", "Y2-1 = 1.092548 yz", "Y20 = 0.315392 (3z^2-1)", "Y21 = 1.092548 xz",
              "Y22 = 0.546274 (x^2-y^2)"],
    "plain": "sh2[k][rgb] = integral of incident radiance L(w) Y_k(w) dw over the sphere, w towards the light; "
             "world frame (metres, stage axes); irradiance E(n) = sum_k A_l c_k Y_k(n), A = (pi, 2pi/3, pi/4)",
    "unity": "UnityEngine.Rendering.SphericalHarmonicsL2 [rgb][k], same k order, value = c_k * Y-constant_k * "
             "A_l / pi (cosine-convolved, divided by pi, basis constants folded in: Unity's shader evaluates "
             "E(n)/pi = (u0-u6) + u3 x + u1 y + u2 z + u4 xy + u5 yz + 3 u6 z^2 + u7 xz + u8 (x^2-y^2)); "
             "Unity frame: left-handed, +Y up (Godot/glTF frame with x negated)",
    "godot": "Godot 4 LightmapGI probe SH, 9 Color [k][rgb], same k order, value = c_k / pi (as Godot's "
             "lightmapper stores them; its shader's constants 0.886227, 1.023327, 0.858086, 0.247708, 0.429043 "
             "give E(n)/pi); Godot frame: right-handed, +Y up (as glTF)",
    "frames": "a Y-up stage maps to Godot/glTF as is; a Z-up stage by (x, y, z) -> (x, z, -y); Unity then negates x "
              "(as UnityGLTF does); positions and coefficients of a layout are in that layout's frame",
}


def sh2_basis(directions) -> np.ndarray:
    """The 9 real SH at unit directions (m, 3): (m, 9)."""
    d = np.asarray(directions, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    poly = np.stack([np.ones_like(x), y, z, x, x * y, y * z, 3 * z * z - 1, x * z, x * x - y * y], axis=-1)
    return poly * SH_CONSTANTS


def irradiance(sh2, normals) -> np.ndarray:
    """Irradiance E(n) (units of the coefficients) on surfaces facing unit `normals` (m, 3), from
    plain L2 coefficients sh2 (9, 3) or (p, 9, 3): E(n) = sum_k A_l c_k Y_k(n), A_l = pi, 2pi/3,
    pi/4 (R&H 2001 eq. 7-8). Returns (m, 3) or (p, m, 3)."""
    c = np.asarray(sh2, dtype=np.float64)
    if c.shape[-2:] != (9, 3):
        raise ValueError(f"sh2 must have shape (..., 9, 3), not {c.shape}")
    y = sh2_basis(normals) * COSINE_LOBE  # (m, 9)
    return np.einsum("mk,...kc->...mc", y, c)


def rotation_matrix(m) -> np.ndarray:
    """The 9 x 9 matrix R with c' = R c for a change of frame w' = M w (M orthogonal, 3 x 3,
    a rotation or a mirror): the radiance L'(w') = L(M^T w') of the new frame. Band l maps to
    itself (the degree-l polynomials restricted to the sphere are closed under orthogonal maps),
    so R is found exactly from Y(M w_s) = R Y(w_s) at a few directions w_s (least squares over an
    over-determined, well-conditioned set)."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape != (3, 3) or not np.allclose(m @ m.T, np.eye(3), atol=1e-12):
        raise ValueError("the frame change must be an orthogonal 3 x 3 matrix")
    golden = math.pi * (3 - math.sqrt(5))
    i = np.arange(64) + 0.5
    z = 1 - 2 * i / 64
    r = np.sqrt(1 - z * z)
    w = np.stack([r * np.cos(golden * i), r * np.sin(golden * i), z], axis=1)
    a, b = sh2_basis(w), sh2_basis(w @ m.T)  # (s, 9): Y(w_s) and Y(M w_s)
    rt, *_ = np.linalg.lstsq(a, b, rcond=None)  # a @ R^T = b
    rot = rt.T
    rot[np.abs(rot) < 1e-13] = 0.0
    return rot


def rotate_sh2(sh2, m) -> np.ndarray:
    """Plain coefficients (..., 9, 3) carried into the frame w' = M w."""
    return np.einsum("jk,...kc->...jc", rotation_matrix(m), np.asarray(sh2, dtype=np.float64))


def engine_frame(up_axis: str, engine: str) -> np.ndarray:
    """The matrix M (engine = M world) from a stage with `up_axis` ("Y" or "Z") to the frame of
    `engine` ("godot" or "gltf": right-handed +Y up; "unity": left-handed +Y up, x negated)."""
    up = str(up_axis).upper()
    if up == "Y":
        to_y = np.eye(3)
    elif up == "Z":
        to_y = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # (x, y, z) -> (x, z, -y)
    else:
        raise ValueError(f"up axis must be Y or Z, not {up_axis!r}")
    if engine in ("godot", "gltf"):
        return to_y
    if engine == "unity":
        return np.diag([-1.0, 1.0, 1.0]) @ to_y
    raise ValueError(f"engine must be godot, gltf or unity, not {engine!r}")


def to_unity(sh2, up_axis: str) -> np.ndarray:
    """Plain world coefficients (n, 9, 3) -> Unity SphericalHarmonicsL2 values (n, 3, 9) [rgb][k]."""
    c = rotate_sh2(sh2, engine_frame(up_axis, "unity")) * UNITY_SCALE[:, None]
    return np.ascontiguousarray(np.swapaxes(c, -1, -2))


def to_godot(sh2, up_axis: str) -> np.ndarray:
    """Plain world coefficients (n, 9, 3) -> Godot 4 LightmapGI probe SH (n, 9, 3) [k][rgb]."""
    return rotate_sh2(sh2, engine_frame(up_axis, "godot")) * GODOT_SCALE[:, None]


@dataclass
class Probes:
    """L2 probes as read back: positions and coefficients per layout (float32 as stored)."""
    path: str
    units: str                 # "radiometric" or "photometric"
    up_axis: str               # the stage's up axis, "Y" or "Z"
    spacing: float             # lattice spacing, m
    positions: np.ndarray      # (n, 3) world, m
    sh2: np.ndarray            # (n, 9, 3) plain coefficients [k][rgb], world frame
    unity_positions: np.ndarray
    unity: np.ndarray          # (n, 3, 9) [rgb][k]
    godot_positions: np.ndarray
    godot: np.ndarray          # (n, 9, 3) [k][rgb]
    conventions: dict = field(default_factory=dict)

    def irradiance(self, normals) -> np.ndarray:
        """E(n) at every probe for unit normals (m, 3) in the world frame: (n, m, 3)."""
        return irradiance(self.sh2.astype(np.float64), normals)


_UNITS = {"radiometric": 0, "photometric": 1}
_AXES = {"Y": 1, "Z": 2}


def _layouts(positions, sh2, up_axis):
    pos = np.asarray(positions, dtype=np.float64)
    c = np.asarray(sh2, dtype=np.float64)
    f32 = lambda a: np.ascontiguousarray(a, dtype="<f4")  # noqa: E731
    return [f32(pos), f32(c),
            f32(pos @ engine_frame(up_axis, "unity").T), f32(to_unity(c, up_axis)),
            f32(pos @ engine_frame(up_axis, "godot").T), f32(to_godot(c, up_axis))]


def _json_array(a: np.ndarray) -> str:
    """A float32 array as nested JSON lists, each value with 9 significant digits (enough for
    every float32 to read back exactly)."""
    if not np.isfinite(a).all():
        raise ValueError("probe values must be finite")
    items = list(map("{:.9g}".format, a.ravel().tolist()))
    for dim in reversed(a.shape[1:]):
        items = ["[" + ",".join(items[i:i + dim]) + "]" for i in range(0, len(items), dim)]
    return "[" + ",".join(items) + "]"


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def write_probes(directory, positions, sh2, *, units: str, up_axis: str, spacing: float,
                 extra: dict | None = None) -> dict:
    """probes.json and probes.bin in `directory` (each written to a temporary name, then renamed):
    positions (n, 3) world metres, sh2 (n, 9, 3) plain coefficients (see the module docstring)."""
    directory = Path(directory)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    sh2 = np.asarray(sh2, dtype=np.float64)
    n = len(positions)
    if sh2.shape != (n, 9, 3):
        raise ValueError(f"sh2 must have shape ({n}, 9, 3), not {sh2.shape}")
    if units not in _UNITS or str(up_axis).upper() not in _AXES:
        raise ValueError(f"units {units!r} / up axis {up_axis!r} not known")
    up = str(up_axis).upper()
    blocks = _layouts(positions, sh2, up)
    payload = b"".join(b.tobytes() for b in blocks)
    head = HEADER.pack(MAGIC, VERSION, HEADER.size, n, 9, 3, float(spacing), _UNITS[units], _AXES[up],
                       len(payload), zlib.crc32(payload), 0)
    head = head[:60] + struct.pack("<I", zlib.crc32(head[:60]))
    _atomic_write(directory / "probes.bin", head + payload)
    # JSON: each float32 with 9 significant digits, which reads back to the same float32.
    arrays = {("plain", "positions"): blocks[0], ("plain", "sh2"): blocks[1], ("unity", "positions"): blocks[2],
              ("unity", "coefficients"): blocks[3], ("godot", "positions"): blocks[4],
              ("godot", "coefficients"): blocks[5]}
    doc = {"format": "hirad-probes", "version": VERSION, "units": units, "up_axis": up, "spacing": float(spacing),
           "count": n, "conventions": CONVENTIONS}
    if extra:
        doc["metadata"] = extra
    for layout, key in arrays:
        doc.setdefault(layout, {})[key] = f"@{layout}.{key}@"
    text = json.dumps(doc, separators=(",", ":"))
    for (layout, key), a in arrays.items():
        text = text.replace(f'"@{layout}.{key}@"', _json_array(a), 1)
    _atomic_write(directory / "probes.json", text.encode())
    return {"json": "probes.json", "binary": "probes.bin", "probes": n, "binary_bytes": len(head) + len(payload),
            "conventions": CONVENTIONS}


def _read_bin(path: Path) -> Probes:
    data = path.read_bytes()
    if len(data) < HEADER.size:
        raise BakeError(f"{path}: {len(data)} bytes, shorter than the {HEADER.size}-byte probes header (truncated)")
    magic, version, hsize, n, nk, nc, spacing, units, up, size, crc, hcrc = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise BakeError(f"{path}: not a hirad probes file (magic {magic!r}, expected {MAGIC!r})")
    if zlib.crc32(data[:60]) != hcrc:
        raise BakeError(f"{path}: header checksum mismatch (the header is corrupted)")
    if version != VERSION or hsize != HEADER.size or (nk, nc) != (9, 3):
        raise BakeError(f"{path}: version {version}, header {hsize} bytes, {nk} x {nc} coefficients: "
                        f"this reader knows version {VERSION}, {HEADER.size} bytes, 9 x 3")
    if size != 360 * n or len(data) != HEADER.size + size:
        raise BakeError(f"{path}: payload is {len(data) - HEADER.size} bytes, the header says {size} "
                        f"for {n} probes ({360 * n} expected): the file is truncated or padded")
    payload = memoryview(data)[HEADER.size:]
    if zlib.crc32(payload) != crc:
        raise BakeError(f"{path}: payload checksum mismatch (the data is corrupted)")
    if units not in _UNITS.values() or up not in _AXES.values():
        raise BakeError(f"{path}: units code {units} / up axis code {up} not known")
    shapes = [(n, 3), (n, 9, 3), (n, 3), (n, 3, 9), (n, 3), (n, 9, 3)]
    arrays, at = [], 0
    for s in shapes:
        count = int(np.prod(s))
        arrays.append(np.frombuffer(payload, dtype="<f4", count=count, offset=at).reshape(s).copy())
        at += 4 * count
    return Probes(str(path), {v: k for k, v in _UNITS.items()}[units], {v: k for k, v in _AXES.items()}[up],
                  spacing, *arrays, conventions=dict(CONVENTIONS))


def _read_json(path: Path) -> Probes:
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise BakeError(f"{path}: not readable JSON ({e})") from e
    if not isinstance(doc, dict) or doc.get("format") != "hirad-probes" or doc.get("version") != VERSION:
        raise BakeError(f"{path}: not a hirad probes file of version {VERSION} (format/version keys)")
    n = doc.get("count")
    try:
        shapes = {("plain", "positions"): (n, 3), ("plain", "sh2"): (n, 9, 3), ("unity", "positions"): (n, 3),
                  ("unity", "coefficients"): (n, 3, 9), ("godot", "positions"): (n, 3),
                  ("godot", "coefficients"): (n, 9, 3)}
        arrays = []
        for (layout, key), shape in shapes.items():
            a = np.asarray(doc[layout][key], dtype=np.float64).astype(np.float32)
            if a.size == 0:
                a = a.reshape(shape)
            if a.shape != shape:
                raise BakeError(f"{path}: {layout}.{key} has shape {a.shape}, expected {shape}")
            arrays.append(a)
        return Probes(str(path), doc["units"], doc["up_axis"], float(doc["spacing"]), *arrays,
                      conventions=doc.get("conventions", {}))
    except (KeyError, TypeError, ValueError) as e:
        raise BakeError(f"{path}: malformed probes JSON ({type(e).__name__}: {e})") from e


def read_probes(path) -> Probes:
    """Read probes.bin or probes.json (or the directory holding them: the binary is read) written
    by a bake with the irradiance volume enabled. Refuses truncated or corrupted files with a
    BakeError naming the file and the problem."""
    p = Path(path)
    if p.is_dir():
        p = p / "probes.bin"
    if not p.is_file():
        raise BakeError(f"{p}: no such probes file")
    return _read_json(p) if p.suffix.lower() == ".json" else _read_bin(p)
