"""Daylight as distant lights: the sun, sky patches, the ground and USD domes, for the engine's
``Luminaire.distant`` (issue 16).

The distant light
-----------------
A distant light is a set of k unit world directions d_k pointing *toward* the light (from the
scene to the sky), weights w_k >= 0 summing to 1, a scalar ``illuminance`` and an RGB
``colour``. A receiver of unit normal n gets

    H = colour x illuminance x sum_k w_k max(0, n . d_k) T_k

with T_k the visibility to infinity along d_k (the engine's rays; :meth:`DistantLightSpec.
irradiance` is the same sum without occlusion). Colours are normalised to a Rec.709 luminance
Y = 0.2126 R + 0.7152 G + 0.0722 B of 1 wherever a light has one colour, so ``illuminance`` is
lux in photometric scenes (hirad.units); white is (1, 1, 1).

* **A patch of sky** of mean luminance L and solid angle Omega: ``illuminance`` = Y(L) Omega and
  directions at the centres of n x n cells of equal solid angle inside the patch (equal
  weights). Cells are equal steps of sin(altitude) and of azimuth (d omega = d(sin h) d phi), and
  each centre sits at the middle of its cell's sin(altitude) range, so for an upward normal
  sum_k w_k (n . d_k) is the patch's mean sin(altitude) *exactly*: an unobstructed horizontal
  plane receives exactly sum_p L_p integral_p cos(theta) d omega. The zenith cap is n rings of
  3 n sectors (n = 1: one direction, the zenith).
* **The sun**, a disk of angular diameter a about the direction c: k directions stratified over
  the disk with equal solid angle each (a Vogel spiral: cos(theta_i) = 1 - (i + 1/2)/k (1 - cos
  a/2), azimuth i x the golden angle), equal weights; ``illuminance`` is chosen so that a plane
  facing c receives exactly the given illuminance E: illuminance = E / sum_k w_k (c . d_k). Angle
  0 is one direction.
* **A whole sky** is one light whose weights are L_c Omega_c / sum(L Omega) over all cells c and
  whose illuminance is sum(L Omega) (three lights, one per RGB channel, when the patches do not
  all have one chromaticity: a textured dome).

The frame
---------
The stage's up axis (USD ``upAxis``, Y or Z; hirad.usd.scene keeps the stage's axes) is the
zenith. North is a direction perpendicular to it: by default -Z for Y-up and +Y for Z-up, and
east = north x up = +X for both (hirad.daylight.patches.frame). With x = east, y = north,
z = up this is the right-handed east-north-up frame, so azimuth measured from north towards east
(pvlib/SPA, hirad.daylight.sun) turns clockwise seen from above, as on a map. Patches are laid
in this frame (hirad.daylight.patches: Tregenza, Reinhart MF:n, azimuth 0 = north).

The ground
----------
Below the horizon, config skies (and USD domes with ``usd_ground: reflectance``) have a uniform
Lambertian ground of reflectance rho_g (0.2 by default) lit by the sky's and the sun's horizontal
illuminance E_h: luminance rho_g E_h / pi, in every direction below the horizon. E_h is what the
discrete sources give an unobstructed upward plane (the sky patches exactly, as above, plus the
sun's disk). The ground is sampled with the sky's cells mirrored through the horizontal plane.
A USD dome (``usd_ground: dome``, the default) emits below the horizon what it says there: its
uniform luminance, or its texture's lower half, per mirrored patch (UsdLux: a dome emits from
every direction).

USD domes
---------
A DomeLight's latlong texture follows the OpenEXR latitude-longitude convention that UsdLux
adopts (usdLux schema, DomeLight): in the dome's frame +Y is the pole; longitude 0 at latitude 0
points along +Z and longitude +pi/2 along +X; the image's left column is longitude +pi and its
right column -pi, its top row latitude +pi/2 and its bottom row -pi/2. A DomeLight_1 with
poleAxis Z (or "scene" on a Z-up stage) has +Z as its pole and longitude 0 along -Y: the Y-pole
frame turned +90 degrees about X. The dome's transform then orients it (rotation only). With
the default north, longitude 0 faces south in both cases. Texels are read as areas: texel (i, j)
of a W x H image spans longitudes pi - 2 pi [i, i + 1] / W and latitudes pi/2 - pi [j, j + 1] / H,
its solid angle (2 pi / W)(sin lat_top - sin lat_bottom); a patch's mean is the solid-angle
weighted mean of the texels whose centres fall in it (the texel nearest its centre when none
does). Texel values multiply the dome's intensity x 2^exposure x colour; UsdLux defines the
emission so that a texel of 1 at intensity 1 is 1 nit, so no luminous efficacy (683 lm/W)
enters in photometric scenes: the numbers are read as the scene's own units (hirad.units).

Textures are read with OpenImageIO (PyPI ``openimageio``): OpenEXR and Radiance HDR, and any
other format it reads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from . import patches as _patches
from .patches import SkyPatches, altitude_azimuth, frame, reinhart_patches

Y_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])  # Rec.709 luminance of linear RGB (hirad.units)
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
SUN_ANGULAR_DIAMETER = 0.53  # degrees (UsdLux DistantLight's fallback)
DEFAULT_SUN_SAMPLES = 16
DEFAULT_SUBDIVISIONS = 2


class DaylightError(ValueError):
    """Daylight settings that cannot be turned into lights (the message names the config key)."""


def _texture_error(message: str):
    from hirad.usd.common import SceneError

    return SceneError(message)


# ----------------------------------------------------------------------------------------------
# the distant light
# ----------------------------------------------------------------------------------------------


@dataclass
class DistantLightSpec:
    """One distant light for ``hirad._engine.Luminaire.distant`` (see the module docstring).

    ``kind``: sun, sky (a whole sky), sky patch, ground, ground patch; ``source``: the USD prim or
    config key it comes from; ``notes``: what a report may say about it."""

    name: str
    directions: np.ndarray
    weights: np.ndarray
    illuminance: float
    colour: np.ndarray = field(default_factory=lambda: np.ones(3))
    kind: str = "sun"
    source: str = ""
    notes: list = field(default_factory=list)
    # optional (k, 3): per direction a colour factor times `colour` (a sky of varying colour in
    # one light, its weights carrying the luminance Y and its tints Y = 1)
    tints: np.ndarray | None = None

    def __post_init__(self):
        d = np.asarray(self.directions, dtype=np.float64).reshape(-1, 3)
        w = np.asarray(self.weights, dtype=np.float64).reshape(-1)
        where = f"distant light {self.name}" + (f" ({self.source})" if self.source else "")
        if len(d) == 0 or len(d) != len(w):
            raise DaylightError(f"{where}: {len(d)} directions and {len(w)} weights")
        norm = np.linalg.norm(d, axis=1)
        if not (np.isfinite(d).all() and (norm > 0).all()):
            raise DaylightError(f"{where}: directions must be finite and non-zero")
        if not (np.isfinite(w).all() and (w >= 0).all() and w.sum() > 0):
            raise DaylightError(f"{where}: weights must be finite, not negative and not all 0")
        self.directions = np.ascontiguousarray(d / norm[:, None])
        self.weights = np.ascontiguousarray(w / w.sum())
        e = float(self.illuminance)
        if not (math.isfinite(e) and e >= 0):
            raise DaylightError(f"{where}: illuminance {e!r} must be finite and not negative")
        self.illuminance = e
        c = np.asarray(self.colour, dtype=np.float64).reshape(-1)
        if c.size == 1:
            c = np.repeat(c, 3)
        if c.size != 3 or not (np.isfinite(c).all() and (c >= 0).all()):
            raise DaylightError(f"{where}: colour must be 3 finite numbers >= 0, got {self.colour!r}")
        self.colour = np.ascontiguousarray(c)
        if self.tints is not None:
            t = np.asarray(self.tints, dtype=np.float64).reshape(-1, 3)
            if len(t) != len(d) or not (np.isfinite(t).all() and (t >= 0).all()):
                raise DaylightError(f"{where}: tints must be one finite RGB >= 0 per direction")
            self.tints = np.ascontiguousarray(t)

    @property
    def count(self) -> int:
        return int(self.directions.shape[0])

    @property
    def rgb_illuminance(self) -> np.ndarray:
        """(3,) colour x illuminance: the illuminance of a plane every direction reaches at normal
        incidence (for a sun: about the perpendicular illuminance)."""
        return self.colour * self.illuminance

    def irradiance(self, normals) -> np.ndarray:
        """(n, 3) unoccluded colour x illuminance x sum_k w_k max(0, n . d_k) for unit normals
        (n, 3) (or one normal (3,)): the engine's formula with every T_k = 1."""
        n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        if self.tints is not None:
            cos = (np.maximum(n @ self.directions.T, 0.0) * self.weights[None, :]) @ self.tints
            return cos * self.illuminance * self.colour[None, :]
        cos = np.maximum(n @ self.directions.T, 0.0) @ self.weights
        return cos[:, None] * self.illuminance * self.colour[None, :]

    def to_engine(self, interleave: bool = False):
        """The engine's ``hirad._engine.Luminaire.distant``; ``interleave``: one of many lights that
        cut one sky (daylight coefficients' groups), lit on elements together as one sky."""
        from hirad import _engine

        return _engine.Luminaire.distant(self.name, self.directions, self.weights, float(self.illuminance),
                                         np.ascontiguousarray(self.colour.reshape(1, 3)), tints=self.tints,
                                         interleave=interleave)


def _unit(v, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.size != 3 or not np.isfinite(a).all() or np.linalg.norm(a) == 0:
        raise DaylightError(f"{what} = {v!r}: must be a finite, non-zero 3-vector")
    return a / np.linalg.norm(a)


def _split_rgb(rgb) -> tuple[float, np.ndarray]:
    """(Y, colour with Y = 1) of an RGB value; white (1, 1, 1) for black."""
    c = np.asarray(rgb, dtype=np.float64).reshape(-1)
    if c.size == 1:
        c = np.repeat(c, 3)
    y = float(c @ Y_WEIGHTS)
    return (y, c / y) if y > 0 else (0.0, np.ones(3))


def _basis(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing c to a right-handed orthonormal frame (t, b, c)."""
    helper = np.eye(3)[int(np.argmin(np.abs(c)))]
    t = np.cross(helper, c)
    t /= np.linalg.norm(t)
    return t, np.cross(c, t)


def disk_directions(direction, angular_diameter_deg: float, samples: int) -> np.ndarray:
    """(k, 3) unit directions over a disk (spherical cap) of the given angular diameter about
    `direction`, equal solid angle each (Vogel spiral, deterministic); one direction for angle
    0 or one sample."""
    c = _unit(direction, "direction")
    a = float(angular_diameter_deg)
    if not (math.isfinite(a) and 0.0 <= a < 360.0):
        raise DaylightError(f"angular diameter = {angular_diameter_deg!r} degrees: must be in [0, 360)")
    if isinstance(samples, bool) or int(samples) != samples or samples < 1:
        raise DaylightError(f"samples = {samples!r}: must be an integer >= 1")
    k = int(samples)
    theta_max = min(math.radians(a) / 2.0, math.pi)
    if theta_max == 0.0 or k == 1:
        return c[None, :].copy()
    i = np.arange(k, dtype=np.float64)
    cos_t = 1.0 - (i + 0.5) / k * (1.0 - math.cos(theta_max))
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = i * GOLDEN_ANGLE
    t, b = _basis(c)
    d = cos_t[:, None] * c + sin_t[:, None] * (np.cos(phi)[:, None] * t + np.sin(phi)[:, None] * b)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def sun_light(direction_to_sun, illuminance_lux: float, angular_diameter_deg: float = SUN_ANGULAR_DIAMETER,
              colour=(1.0, 1.0, 1.0), samples: int = DEFAULT_SUN_SAMPLES, name: str = "sun",
              source: str = "") -> DistantLightSpec:
    """The sun (or any disk of uniform luminance) as a distant light: `illuminance_lux` is the
    illuminance of a plane facing `direction_to_sun` (per unit colour; E_perp), `samples`
    directions over the disk (see the module docstring); angle 0 is one direction."""
    e = float(illuminance_lux)
    if not (math.isfinite(e) and e >= 0):
        raise DaylightError(f"sun illuminance = {illuminance_lux!r} lux: must be finite and not negative")
    c = _unit(direction_to_sun, "sun direction")
    dirs = disk_directions(c, angular_diameter_deg, samples)
    w = np.full(len(dirs), 1.0 / len(dirs))
    facing = float(np.maximum(dirs @ c, 0.0) @ w)
    spec = DistantLightSpec(name=name, directions=dirs, weights=w, illuminance=e / facing, colour=colour,
                            kind="sun", source=source)
    spec.notes.append(f"disk {float(angular_diameter_deg):g} deg, {len(dirs)} direction(s), "
                      f"E_perp = {e:.6g} per unit colour")
    return spec


# ----------------------------------------------------------------------------------------------
# sky patches as cells
# ----------------------------------------------------------------------------------------------


@dataclass
class PatchCells:
    """Sub-cells of a patch layout: per cell its centre's altitude and azimuth (radians), its
    solid angle (sr), its patch, and its bounds (altitudes, azimuth centre and width); cells of
    one patch are contiguous."""

    altitude: np.ndarray
    azimuth: np.ndarray
    solid_angle: np.ndarray
    owner: np.ndarray
    alt_lo: np.ndarray
    alt_hi: np.ndarray
    az_center: np.ndarray
    az_width: np.ndarray

    @property
    def count(self) -> int:
        return int(self.altitude.shape[0])

    def as_patches(self) -> SkyPatches:
        """The cells as a SkyPatches (for their exact solid angles and mean luminances)."""
        return SkyPatches(0, self.alt_lo, self.alt_hi, self.az_center, self.az_width)

    def directions(self, up="Y", north=None, below: bool = False) -> np.ndarray:
        """(M, 3) cell directions; `below`: mirrored through the horizontal plane (the ground)."""
        alt = -self.altitude if below else self.altitude
        return _patches.directions(alt, self.azimuth, up, north)


def patch_cells(sky_patches: SkyPatches, subdivisions: int = DEFAULT_SUBDIVISIONS) -> PatchCells:
    """n x n cells of equal solid angle per band patch (steps of sin(altitude) and azimuth), n
    rings x 3 n sectors for the zenith cap (n = 1: the zenith); centres at the middle of each
    cell's sin(altitude) and azimuth ranges."""
    if isinstance(subdivisions, bool) or int(subdivisions) != subdivisions or subdivisions < 1:
        raise DaylightError(f"subdivisions = {subdivisions!r}: must be an integer >= 1")
    n = int(subdivisions)
    p = sky_patches
    cap = p.az_width >= 2 * math.pi - 1e-12
    cols: dict[str, list] = {k: [] for k in ("alt", "az", "om", "own", "lo", "hi", "azc", "azw")}
    s_lo, s_hi = np.sin(p.alt_lo), np.sin(p.alt_hi)
    omega = p.solid_angle
    for idx in range(p.count):
        rings, sectors = (n, 3 * n) if cap[idx] else (n, n)
        if cap[idx] and n == 1:
            rings, sectors = 1, 1
        edges = np.linspace(s_lo[idx], s_hi[idx], rings + 1)
        mid = 0.5 * (edges[:-1] + edges[1:])
        width = p.az_width[idx] / sectors
        offs = ((np.arange(sectors) + 0.5) / sectors - 0.5) * p.az_width[idx]
        alt = np.repeat(np.arcsin(np.clip(mid, -1.0, 1.0)), sectors)
        if cap[idx] and n == 1:
            alt = np.array([math.pi / 2])  # the cap's centre, the zenith
        cols["alt"].append(alt)
        cols["az"].append(np.tile(np.mod(p.az_center[idx] + offs, 2 * math.pi), rings))
        cols["om"].append(np.full(rings * sectors, omega[idx] / (rings * sectors)))
        cols["own"].append(np.full(rings * sectors, idx))
        cols["lo"].append(np.repeat(np.arcsin(np.clip(edges[:-1], -1.0, 1.0)), sectors))
        cols["hi"].append(np.repeat(np.arcsin(np.clip(edges[1:], -1.0, 1.0)), sectors))
        cols["azc"].append(np.tile(p.az_center[idx] + offs, rings))
        cols["azw"].append(np.full(rings * sectors, width))
    c = {k: np.concatenate(v) for k, v in cols.items()}
    return PatchCells(c["alt"], c["az"], c["om"], c["own"].astype(np.int64), c["lo"], c["hi"], c["azc"], c["azw"])


def _patches_of(sky_patches) -> SkyPatches:
    if sky_patches is None:
        return reinhart_patches(1)
    if isinstance(sky_patches, SkyPatches):
        return sky_patches
    if isinstance(sky_patches, (int, np.integer)) and not isinstance(sky_patches, bool):
        return reinhart_patches(int(sky_patches))
    if isinstance(sky_patches, str):
        text = sky_patches.strip().lower()
        if text == "tregenza":
            return reinhart_patches(1)
        if text.startswith("reinhart") and text[8:].isdigit():
            return reinhart_patches(int(text[8:]))
    raise DaylightError(f"patches = {sky_patches!r}: 'tregenza', 'reinhartN', an MF number or SkyPatches")


class _FunctionSky:
    def __init__(self, fn: Callable):
        self.fn = fn

    def luminance(self, theta, phi):
        return np.asarray(self.fn(theta, phi), dtype=np.float64)


def _rgb_rows(values, n: int, what: str) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if a.ndim == 1 and a.shape[0] == n:
        a = np.repeat(a[:, None], 3, axis=1)
    if a.shape != (n, 3):
        raise DaylightError(f"{what}: expected {n} values or ({n}, 3) RGB, got shape {a.shape}")
    if not (np.isfinite(a).all() and (a >= 0).all()):
        raise DaylightError(f"{what}: luminances must be finite and not negative")
    return a


def patch_luminance(luminance, sky_patches: SkyPatches, order: int = 8) -> np.ndarray:
    """(N, 3) RGB patch-mean luminance of a sky object (``.luminance(theta, phi)``: the skies of
    hirad.daylight.skies), a function (theta, phi) -> luminance, or given values ((N,) or (N, 3))."""
    if hasattr(luminance, "luminance"):
        return _rgb_rows(sky_patches.mean_luminance(luminance, order), sky_patches.count, "sky luminance")
    if callable(luminance):
        return _rgb_rows(sky_patches.mean_luminance(_FunctionSky(luminance), order), sky_patches.count,
                         "sky luminance")
    return _rgb_rows(luminance, sky_patches.count, "patch luminances")


def _cell_specs(name: str, kind: str, source: str, dirs: np.ndarray, omega: np.ndarray,
                lum: np.ndarray) -> list[DistantLightSpec]:
    """One light for cells of RGB luminance `lum` (M, 3) and solid angles `omega` (M,): its weights
    the cells' luminance Y x solid angle, and, when the cells differ in chromaticity, each cell's
    own as its tint (RGB / Y); none when all are black. A cell with colour but Y = 0 (possible
    only for negative-weight primaries, so never here) would be dropped."""
    flux = lum * omega[:, None]  # (M, 3) L Omega per channel
    y = flux @ Y_WEIGHTS
    if not (flux > 0).any():
        return []
    lit = y > 0
    chroma = flux[lit] / y[lit][:, None]
    if np.allclose(chroma, chroma[0], rtol=1e-9, atol=1e-12) and np.allclose(flux[~lit], 0.0):
        keep = y > 0
        return [DistantLightSpec(name=name, directions=dirs[keep], weights=y[keep], illuminance=float(y.sum()),
                                 colour=chroma[0], kind=kind, source=source)]
    keep = y > 0
    return [DistantLightSpec(name=name, directions=dirs[keep], weights=y[keep], illuminance=float(y.sum()),
                             colour=np.ones(3), kind=kind, source=source, tints=flux[keep] / y[keep][:, None],
                             notes=["a sky of varying colour: one tint per direction"])]


@dataclass
class SkyLights:
    """A sky and its ground as distant lights.

    ``patches``: one light per sky patch (index = patch index; black patches have illuminance 0);
    ``ground``: one uniform ground light, or one per mirrored patch (a dome's lower half);
    ``combined``: the sky and the ground together (one light, tinted per direction for a sky whose patches
    differ in colour) - what a point-in-time bake uses; ``patch_luminance`` (N, 3),
    ``ground_luminance`` (3,) or (N, 3); ``horizontal_illuminance`` (3,): the sky's (without the
    sun) on an unobstructed upward plane; ``ground_illuminance`` (3,): the E_h (sky and sun) that
    lit a reflectance ground (None otherwise)."""

    patches: list
    ground: list
    combined: list
    patch_luminance: np.ndarray
    ground_luminance: np.ndarray
    horizontal_illuminance: np.ndarray
    sky_patches: SkyPatches
    cells: PatchCells
    ground_illuminance: np.ndarray | None = None

    @property
    def lights(self) -> list:
        """What lights the scene: :attr:`combined`."""
        return list(self.combined)


def _sequence(sun) -> list:
    if sun is None:
        return []
    if isinstance(sun, DistantLightSpec):
        return [sun]
    return list(sun)


def sky_lights(luminance, sky_patches=None, up="Y", north=None, ground_reflectance: float = 0.2,
               subdivisions: int = DEFAULT_SUBDIVISIONS, sun=None, ground=None, name: str = "sky",
               source: str = "", order: int = 8) -> SkyLights:
    """The sky of `luminance` (a sky object of hirad.daylight.skies, a function (theta, phi), or
    per-patch values (N,) or (N, 3) RGB) over `sky_patches` (SkyPatches, 'tregenza', 'reinhartN'
    or an MF number; default Tregenza) as distant lights in the frame (`up`, `north`), with the
    ground below the horizon:

    * `ground` None: a Lambertian ground of `ground_reflectance` lit by the sky and by `sun` (a
      DistantLightSpec or a list of them): luminance rho_g E_h / pi (module docstring);
    * `ground` a luminance (a number or RGB (3,)): a uniform ground of that luminance;
    * `ground` (N,) or (N, 3): the luminance of each patch mirrored below the horizon.

    Each patch and the ground are sampled at the cells of :func:`patch_cells` (`subdivisions`).
    A patch's own light spreads its mean luminance evenly over its cells (the daylight-coefficient
    basis); the combined light gives each cell its own mean luminance when the sky is a function
    (Gauss-Legendre over the cell, order/2 nodes each way), the patch's when values are given."""
    sp = _patches_of(sky_patches)
    cells = patch_cells(sp, subdivisions)
    if hasattr(luminance, "luminance") or callable(luminance):
        sky = luminance if hasattr(luminance, "luminance") else _FunctionSky(luminance)
        cell_order = max(2, order // 2)
        cell_lum = _rgb_rows(cells.as_patches().mean_luminance(sky, cell_order), cells.count, "sky luminance")
        lum = np.stack([np.bincount(cells.owner, weights=cell_lum[:, ch] * cells.solid_angle, minlength=sp.count)
                        for ch in range(3)], axis=1) / sp.solid_angle[:, None]
    else:
        lum = _rgb_rows(luminance, sp.count, "patch luminances")
        cell_lum = lum[cells.owner]
    up_v, _, _ = frame(up, north)
    dirs = cells.directions(up, north)
    gdirs = cells.directions(up, north, below=True)
    omega = cells.solid_angle

    def per_patch(label: str, kind: str, cell_dirs: np.ndarray, values: np.ndarray) -> list:
        """One light per patch: its cells' directions by solid angle, illuminance L_p Omega_p."""
        out = []
        for p in range(sp.count):
            sel = cells.owner == p
            y, colour = _split_rgb(values[p])
            out.append(DistantLightSpec(name=f"{name} {label} {p}", directions=cell_dirs[sel], weights=omega[sel],
                                        illuminance=y * float(sp.solid_angle[p]), colour=colour, kind=kind,
                                        source=source))
        return out

    patch_specs = per_patch("patch", "sky patch", dirs, lum)
    # what the sky's cells give an unobstructed upward plane
    e_sky = (cell_lum * (omega * np.maximum(dirs @ up_v, 0.0))[:, None]).sum(axis=0)

    e_lit = None
    if ground is None:
        r = float(ground_reflectance)
        if not (math.isfinite(r) and 0.0 <= r <= 1.0):
            raise DaylightError(f"ground reflectance = {ground_reflectance!r}: must be in [0, 1]")
        e_lit = e_sky.copy()
        for s in _sequence(sun):
            e_lit += s.irradiance(up_v)[0]
        g_lum = r * e_lit / math.pi
    else:
        g = np.asarray(ground, dtype=np.float64)
        if g.ndim == 0 or g.shape == (3,):
            g_lum = np.broadcast_to(g, (3,)).astype(np.float64)
            if not (np.isfinite(g_lum).all() and (g_lum >= 0).all()):
                raise DaylightError("ground luminance must be finite and not negative")
        else:
            g_lum = _rgb_rows(g, sp.count, "ground luminances")
            if np.allclose(g_lum, g_lum[0]):
                g_lum = g_lum[0].copy()

    if g_lum.ndim == 1:
        y, colour = _split_rgb(g_lum)
        ground_specs = [DistantLightSpec(name=f"{name} ground", directions=gdirs, weights=omega,
                                         illuminance=y * 2.0 * math.pi, colour=colour, kind="ground", source=source)]
        g_cells = np.repeat(g_lum[None, :], len(omega), axis=0)
        if e_lit is not None:
            ground_specs[0].notes.append(f"rho_g = {float(ground_reflectance):g}, E_h = {float(e_lit @ Y_WEIGHTS):.6g}")
    else:
        ground_specs = per_patch("ground patch", "ground patch", gdirs, g_lum)
        g_cells = g_lum[cells.owner]

    combined = _cell_specs(name, "sky", source, np.concatenate([dirs, gdirs]), np.concatenate([omega, omega]),
                           np.concatenate([cell_lum, g_cells]))
    return SkyLights(patches=patch_specs, ground=ground_specs, combined=combined, patch_luminance=lum,
                     ground_luminance=g_lum, horizontal_illuminance=e_sky, sky_patches=sp, cells=cells,
                     ground_illuminance=e_lit)


# ----------------------------------------------------------------------------------------------
# daylight coefficients
# ----------------------------------------------------------------------------------------------


def sky_patch_groups(sky_patches=None, up="Y", north=None, subdivisions: int = DEFAULT_SUBDIVISIONS,
                     ground: bool = True, name: str = "sky") -> list[DistantLightSpec]:
    """Per-patch lights of unit luminance (1 cd/m^2: illuminance = the patch's solid angle,
    white), one per sky patch in patch order, then (`ground`) the whole ground hemisphere of
    unit luminance (illuminance 2 pi): solved once each, they are the daylight coefficients. An
    hour's light is then sum_p L_p x result_p + L_g x result_ground with L_p the hour's
    patch-mean luminances and L_g = rho_g E_h / pi (:func:`sky_coefficients`)."""
    sp = _patches_of(sky_patches)
    unit = np.ones(sp.count)
    lights = sky_lights(unit, sp, up, north, subdivisions=subdivisions, ground=1.0, name=name)
    return lights.patches + (lights.ground if ground else [])


def sky_coefficients(luminance, sky_patches=None, up="Y", north=None, ground_reflectance: float = 0.2,
                     subdivisions: int = DEFAULT_SUBDIVISIONS, sun=None, order: int = 8) -> np.ndarray:
    """(N + 1, 3) the multipliers of :func:`sky_patch_groups`' lights for one sky: its patch-mean
    luminances, then the ground's rho_g E_h / pi (E_h of the sky and `sun`)."""
    lights = sky_lights(luminance, sky_patches, up, north, ground_reflectance, subdivisions, sun=sun, order=order)
    return np.concatenate([lights.patch_luminance, lights.ground_luminance[None, :]])


def sun_bin_lights(sky_patches=None, up="Y", north=None, angular_diameter_deg: float = 0.0,
                   samples: int = 1, name: str = "sun bin") -> list[DistantLightSpec]:
    """One sun of unit perpendicular illuminance (1 lux) at the centre of each patch (the sun
    positions of the daylight-coefficient method's direct sun): an hour's sun of direct normal
    illuminance E in patch p then contributes E x result_p."""
    sp = _patches_of(sky_patches)
    dirs = sp.directions(up, north)
    return [sun_light(d, 1.0, angular_diameter_deg, samples=samples, name=f"{name} {p}")
            for p, d in enumerate(dirs)]


# ----------------------------------------------------------------------------------------------
# dome textures
# ----------------------------------------------------------------------------------------------


def read_texture(path, prim: str = "") -> np.ndarray:
    """(H, W, 3) float64 linear RGB of an image file, top row first (OpenImageIO). Errors name
    the file and `prim` (who uses it)."""
    import os

    who = f"{prim}: " if prim else ""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise _texture_error(f"{who}sky texture not found: {path}")
    try:
        import OpenImageIO as oiio
    except ImportError:  # pragma: no cover - a dependency of hirad
        raise _texture_error(f"{who}{path}: reading sky textures needs OpenImageIO (pip install openimageio)") from None
    inp = oiio.ImageInput.open(path)
    if inp is None:
        why = oiio.geterror().strip() or "unknown format"
        raise _texture_error(f"{who}{path}: cannot read the sky texture ({why})")
    try:
        spec = inp.spec()
        nch = int(spec.nchannels)
        pixels = inp.read_image(0, 0, 0, nch, "float")
        err = inp.geterror() if pixels is None else ""
    finally:
        inp.close()
    if pixels is None or not hasattr(pixels, "shape"):
        raise _texture_error(f"{who}{path}: cannot read the sky texture's pixels ({(err or oiio.geterror()).strip()})")
    px = np.asarray(pixels, dtype=np.float64).reshape(spec.height, spec.width, nch)
    names = [str(c) for c in spec.channelnames]
    if nch == 1:
        rgb = np.repeat(px, 3, axis=2)
    elif nch == 2:
        raise _texture_error(f"{who}{path}: {nch} channels ({', '.join(names)}): a sky texture is RGB or grey")
    else:
        idx = [names.index(c) for c in ("R", "G", "B")] if all(c in names for c in "RGB") else [0, 1, 2]
        rgb = px[:, :, idx]
    if spec.width < 2 or spec.height < 1:
        raise _texture_error(f"{who}{path}: {spec.width} x {spec.height} pixels is no sky texture")
    bad = ~np.isfinite(rgb)
    if bad.any():
        raise _texture_error(f"{who}{path}: {int(bad.any(axis=2).sum())} texel(s) are not finite (NaN or infinity)")
    return rgb


def latlong_directions(height: int, width: int, pole_axis: str = "Y", rotation=None) -> np.ndarray:
    """(H, W, 3) world directions of the texel centres of a latlong map (module docstring): the
    UsdLux/OpenEXR frame (+Y pole, longitude 0 = +Z, longitude pi/2 = +X), turned for pole Z,
    then by `rotation` (3, 3) rows = the dome's local axes in world space."""
    lon = math.pi - 2.0 * math.pi * (np.arange(width) + 0.5) / width
    lat = 0.5 * math.pi - math.pi * (np.arange(height) + 0.5) / height
    cl = np.cos(lat)[:, None]
    d = np.stack([cl * np.sin(lon)[None, :], np.repeat(np.sin(lat)[:, None], width, axis=1),
                  cl * np.cos(lon)[None, :]], axis=-1)
    d = _pole(d, pole_axis)
    if rotation is not None:
        d = d @ np.asarray(rotation, dtype=np.float64).reshape(3, 3)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return d


def _pole(d: np.ndarray, pole_axis: str) -> np.ndarray:
    if pole_axis == "Y":
        return d
    if pole_axis == "Z":  # +90 degrees about X: +Y -> +Z, +Z -> -Y
        return np.stack([d[..., 0], -d[..., 2], d[..., 1]], axis=-1)
    raise DaylightError(f"pole axis {pole_axis!r}: must be 'Y' or 'Z'")


def latlong_texel(directions, height: int, width: int, pole_axis: str = "Y", rotation=None):
    """(row, column) of the texel a world direction (n, 3) falls in: the inverse of
    :func:`latlong_directions`."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if rotation is not None:
        d = d @ np.asarray(rotation, dtype=np.float64).reshape(3, 3).T
    if pole_axis == "Z":
        d = np.stack([d[:, 0], d[:, 2], -d[:, 1]], axis=-1)
    elif pole_axis != "Y":
        raise DaylightError(f"pole axis {pole_axis!r}: must be 'Y' or 'Z'")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    lat = np.arcsin(np.clip(d[:, 1], -1.0, 1.0))
    lon = np.arctan2(d[:, 0], d[:, 2])
    col = np.floor((math.pi - lon) / (2.0 * math.pi) * width).astype(np.int64) % width
    row = np.clip(np.floor((0.5 * math.pi - lat) / math.pi * height).astype(np.int64), 0, height - 1)
    return row, col


def latlong_solid_angles(height: int, width: int) -> np.ndarray:
    """(H,) the solid angle of one texel of each row: (2 pi / W)(sin lat_top - sin lat_bottom)."""
    edges = 0.5 * math.pi - math.pi * np.arange(height + 1) / height
    return (2.0 * math.pi / width) * (np.sin(edges[:-1]) - np.sin(edges[1:]))


def patch_index(sky_patches: SkyPatches, altitude, azimuth) -> np.ndarray:
    """The patch of each (altitude >= 0, azimuth) direction (radians; -1 below the horizon)."""
    sp = sky_patches
    alt = np.asarray(altitude, dtype=np.float64)
    az = np.mod(np.asarray(azimuth, dtype=np.float64), 2 * math.pi)
    band_lo, first = np.unique(sp.alt_lo, return_index=True)
    counts = np.diff(np.append(first, sp.count))
    b = np.clip(np.searchsorted(band_lo, alt, side="right") - 1, 0, len(band_lo) - 1)
    width = 2 * math.pi / counts[b]
    j = np.floor(az / width + 0.5).astype(np.int64) % counts[b]
    out = first[b] + j
    return np.where(alt >= 0, out, -1)


def dome_texture_luminance(path, sky_patches=None, *, up="Y", north=None, pole_axis: str = "Y", rotation=None,
                           texture_format: str = "latlong", prim: str = "",
                           warnings: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Patch-mean RGB texel values of a latlong dome texture: (upper (N, 3), lower (N, 3)), the
    lower for the patches mirrored below the horizon; texels averaged by solid angle (module
    docstring). `pole_axis` 'Y' or 'Z' (a DomeLight_1's poleAxis, "scene" resolved by the
    reader), `rotation` the dome's (3, 3) (DomeLightInfo.rotation). `texture_format` 'latlong'
    takes any image; 'automatic' needs a 2:1 image (what OpenEXR asks of a latlong map). A
    missing, unreadable or corrupt texture is an error naming the file and `prim`; negative
    texels are read as 0 and named in `warnings`."""
    sp = _patches_of(sky_patches)
    rgb = read_texture(path, prim)
    h, w = rgb.shape[:2]
    who = f"{prim}: " if prim else ""
    if texture_format == "automatic" and w != 2 * h:
        raise _texture_error(f"{who}{path}: {w} x {h} texels is not a 2:1 latlong map, and inputs:texture:format "
                             "is automatic: set it to latlong if the texture is one")
    if texture_format not in ("latlong", "automatic"):
        raise _texture_error(f"{who}{path}: texture format {texture_format!r}: hirad reads latlong maps only")
    neg = rgb < 0
    if neg.any():
        if warnings is not None:
            warnings.append(f"{who}{path}: {int(neg.any(axis=2).sum())} texel(s) have negative values; read as 0")
        rgb = np.maximum(rgb, 0.0)
    dirs = latlong_directions(h, w, pole_axis, rotation).reshape(-1, 3)
    omega = np.repeat(latlong_solid_angles(h, w), w)
    alt, az = altitude_azimuth(dirs, up, north)
    flat = rgb.reshape(-1, 3)
    centre_dirs = sp.directions(up, north)
    out = []
    for sign in (1.0, -1.0):
        a = sign * alt
        idx = patch_index(sp, a, az)
        keep = idx >= 0
        wsum = np.bincount(idx[keep], weights=omega[keep], minlength=sp.count)
        mean = np.stack([np.bincount(idx[keep], weights=flat[keep, c] * omega[keep], minlength=sp.count)
                         for c in range(3)], axis=1)
        empty = wsum <= 0
        mean[~empty] /= wsum[~empty, None]
        if empty.any():  # patches smaller than a texel: the texel at the patch's centre
            cd = centre_dirs[empty].copy()
            if sign < 0:
                u, _, _ = frame(up, north)
                cd = cd - 2.0 * (cd @ u)[:, None] * u[None, :]
            r, c = latlong_texel(cd, h, w, pole_axis, rotation)
            mean[empty] = rgb[r, c]
        out.append(mean)
    return out[0], out[1]


# ----------------------------------------------------------------------------------------------
# a bake's daylight
# ----------------------------------------------------------------------------------------------


def _daylight_config(config):
    return getattr(config, "daylight", config)


def config_sun_position(dl):
    """The SunPosition of a DaylightConfig's site and time (hirad.daylight.sun)."""
    from .sun import Site, sun_position

    site = dl.site
    if site.latitude is None or site.longitude is None or dl.time is None:
        raise DaylightError("daylight.site (latitude, longitude) and daylight.time are needed for the sun's position")
    try:
        return sun_position(Site(site.latitude, site.longitude, site.elevation, site.timezone), dl.time)
    except ValueError as exc:
        raise DaylightError(f"daylight: {exc}") from None


def config_sky(dl, up="Y", north=None):
    """(sky object, list of sun lights) of a DaylightConfig's sky model (not usd). Values are
    photometric (cd/m^2, lux); a sky model that follows the sun needs it above the horizon."""
    from . import skies

    m = dl.sky.model
    sky_cfg, sun_cfg = dl.sky, dl.sun
    position = None
    wants_sun = sun_cfg.enabled is not False and sun_cfg.direct_normal_illuminance is not None
    if m in ("cie_general", "perez") or wants_sun:
        position = config_sun_position(dl)
    if m in ("cie_general", "perez") and position.elevation <= 0:
        raise DaylightError(f"daylight.time: the sun is {-position.elevation:.2f} degrees below the horizon at "
                            f"{position.time.isoformat()} at the site: sky model {m} needs it above the horizon")
    eh = sky_cfg.horizontal_illuminance
    lz = sky_cfg.zenith_luminance
    if eh is None and lz is None:
        from hirad.config.schema import DEFAULT_SKY_ILLUMINANCE
        eh = DEFAULT_SKY_ILLUMINANCE
    direct = sun_cfg.direct_normal_illuminance
    if m == "cie_overcast":
        sky = skies.CIEOvercastSky(zenith_luminance=lz, horizontal_illuminance=eh)
    elif m == "uniform":
        sky = skies.UniformSky(lz if lz is not None else eh / math.pi)
    elif m == "cie_general":
        sky = skies.CIEGeneralSky(sky_cfg.type, math.radians(position.zenith), math.radians(position.azimuth),
                                  zenith_luminance=lz, horizontal_illuminance=eh)
    elif m == "perez":
        sky = skies.PerezSky(sky_cfg.dni, sky_cfg.dhi, math.radians(position.zenith), math.radians(position.azimuth),
                             position.time.timetuple().tm_yday, sky_cfg.dew_point)
        direct = sky.direct_normal_illuminance if sky_cfg.dni > 0 else None
    else:
        raise DaylightError(f"daylight.sky.model {m!r} is not a sky model (usd: the scene's lights)")
    suns = []
    if sun_cfg.enabled is not False and direct is not None and direct > 0:
        if position.elevation <= 0:
            if sun_cfg.enabled:
                raise DaylightError(f"daylight.sun: the sun is below the horizon at {position.time.isoformat()} "
                                    "at the site")
        else:
            angle = SUN_ANGULAR_DIAMETER if sun_cfg.angular_diameter is None else sun_cfg.angular_diameter
            s = sun_light(position.direction(up, north), direct, angle, samples=sun_cfg.samples, name="sun",
                          source="daylight.sun")
            s.notes.append(f"elevation {position.elevation:.3f} deg, azimuth {position.azimuth:.3f} deg at "
                           f"{position.time.isoformat()}")
            suns.append(s)
    return sky, suns


def _usd_daylight(scene, dl, sp, up, north, warnings) -> list[DistantLightSpec]:
    from hirad.usd.scene import DistantLightInfo, DomeLightInfo

    suns = []
    for info in scene.daylight:
        if not isinstance(info, DistantLightInfo):
            continue
        if dl.sun.enabled is False:
            warnings.append(f"{info.path}: DistantLight switched off by daylight.sun.enabled: false")
            continue
        y, colour = _split_rgb(info.illuminance)
        s = sun_light(info.direction, y, info.angle, colour, samples=dl.sun.samples, name=info.path, source=info.path)
        s.notes.append("UsdLux DistantLight" + (", normalize" if info.normalize else ""))
        suns.append(s)
    domes = [d for d in scene.daylight if isinstance(d, DomeLightInfo)]
    if not domes:
        return suns
    upper = np.zeros((sp.count, 3))
    lower = np.zeros((sp.count, 3))
    textured = False
    where = scene.source_path
    for d in domes:
        if d.texture is None:
            upper += d.radiance
            lower += d.radiance
            continue
        textured = True
        up_t, lo_t = dome_texture_luminance(d.texture, sp, up=up, north=north, pole_axis=d.pole_axis,
                                            rotation=d.rotation, texture_format=d.texture_format,
                                            prim=f"{where}: {d.path}" if where else d.path, warnings=warnings)
        upper += up_t * d.radiance
        lower += lo_t * d.radiance
    if dl.usd_ground == "dome":
        ground = lower if textured else lower[0]
    else:
        ground = None
    name = domes[0].path if len(domes) == 1 else "domes"
    lights = sky_lights(upper, sp, up, north, dl.ground_reflectance, dl.subdivisions, sun=suns, ground=ground,
                        name=name, source=", ".join(d.path for d in domes))
    return suns + lights.combined


def daylight_luminaires(scene_arrays, config, warnings: list | None = None) -> list[DistantLightSpec]:
    """The distant lights of a bake's daylight, from ``config.daylight`` (a Config or a
    DaylightConfig) and the scene (SceneArrays read with ``daylight=True``):

    * sky.model usd: each DistantLight a sun (unless sun.enabled is false), the DomeLights one sky
      (uniform or textured, summed) with their lower half (usd_ground: dome) or a reflectance
      ground below the horizon;
    * a sky model: that sky and its sun (site and time), replacing the scene's DomeLight and
      DistantLight prims (named in a warning).

    Suns first, then the sky (one light, tinted per direction when its colour varies). Warnings go to
    `warnings` (default: the scene's own list)."""
    dl = _daylight_config(config)
    if warnings is None:
        warnings = scene_arrays.warnings
    up = scene_arrays.up_axis
    north = None if dl.north is None else tuple(dl.north)
    try:
        frame(up, north)
    except ValueError as exc:
        raise DaylightError(f"daylight.north: {exc} (the scene's up axis is {up})") from None
    sp = reinhart_patches(dl.reinhart_mf())
    if dl.sky.model == "usd":
        return _usd_daylight(scene_arrays, dl, sp, up, north, warnings)
    for info in scene_arrays.daylight:
        warnings.append(f"{info.path}: {info.kind} replaced by daylight.sky.model {dl.sky.model}; ignored")
    sky, suns = config_sky(dl, up, north)
    lights = sky_lights(sky, sp, up, north, dl.ground_reflectance, dl.subdivisions, sun=suns,
                        name=f"sky ({dl.sky.model})", source="daylight.sky")
    return suns + lights.combined


def daylight_patch_groups(scene_arrays, config) -> list[DistantLightSpec]:
    """:func:`sky_patch_groups` in a scene's frame with a config's patches and subdivisions."""
    dl = _daylight_config(config)
    north = None if dl.north is None else tuple(dl.north)
    return sky_patch_groups(reinhart_patches(dl.reinhart_mf()), scene_arrays.up_axis, north, dl.subdivisions)


__all__ = [
    "DaylightError", "DistantLightSpec", "PatchCells", "SkyLights", "config_sky", "config_sun_position",
    "daylight_luminaires", "daylight_patch_groups", "disk_directions", "dome_texture_luminance",
    "latlong_directions", "latlong_solid_angles", "latlong_texel", "patch_cells", "patch_index", "patch_luminance",
    "read_texture", "sky_coefficients", "sky_lights", "sky_patch_groups", "sun_bin_lights", "sun_light",
]
