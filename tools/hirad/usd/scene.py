"""Reading a USD stage into the flat arrays the engine consumes: world-space polygons in metres, per-face reflectance and emitted exitance (W/m^2, M = pi L), per-corner UVs, emitters (mesh lights and UsdLux area lights), luminaires (sphere, cylinder and shaped lights, IES profiles: hirad.photometry.luminaires) and cameras."""

from __future__ import annotations

import math
import os
import re
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from pxr import Usd, UsdGeom, UsdLux, UsdShade, Vt
from .common import (_LOOKS_NAME, SceneError, _Names, _PrimError, _mat, _open_stage, _stage_time, _transform_points,
                     _value_type, _vec3)
from .materials import (_MAX_REFLECTANCE, MAX_RADIANCE, _MaterialResolver, _checked_emission, _checked_reflectance, _colour,
                        _display_color_per_face)
from hirad.photometry import luminaires as _lum


# Coordinates (in metres, after metersPerUnit and the transforms) beyond this are refused: no
# scene a radiosity bake can mesh is that large, and meshing such a face would never end.
MAX_COORDINATE_M = 1e15

_POINT_ARRAYS = (Vt.Vec3fArray, Vt.Vec3dArray, Vt.Vec3hArray)
_INDEX_ARRAYS = (Vt.IntArray, Vt.UIntArray, Vt.Int64Array, Vt.UInt64Array)

# Light attributes whose meaning hirad reproduces; any other authored light attribute that
# changes the light (a value other than the schema's fallback) is named in a warning.
_HONOURED_LIGHT_ATTRS = {"inputs:intensity", "inputs:exposure", "inputs:color", "inputs:normalize",
                         "inputs:enableColorTemperature", "inputs:colorTemperature"}
# UsdLuxShapingAPI, honoured on the light types that become luminaires (not on DomeLight,
# DistantLight or a MeshLightAPI, where it is named in the warning).
_SHAPING_ATTRS = {"inputs:shaping:focus", "inputs:shaping:focusTint", "inputs:shaping:cone:angle",
                  "inputs:shaping:cone:softness", "inputs:shaping:ies:file", "inputs:shaping:ies:angleScale",
                  "inputs:shaping:ies:normalize"}
_SHAPE_ATTRS = {"RectLight": {"inputs:width", "inputs:height"} | _SHAPING_ATTRS,
                "DiskLight": {"inputs:radius"} | _SHAPING_ATTRS,
                "SphereLight": {"inputs:radius", "treatAsPoint"} | _SHAPING_ATTRS,
                "CylinderLight": {"inputs:length", "inputs:radius", "treatAsLine"} | _SHAPING_ATTRS}
# A light's authored total luminous flux in lumens (PhotometricAreaLightAPI style): the light is
# scaled so that it emits exactly this (Rec.709 Y of its RGB flux).
PHOTOMETRIC_POWER = "photometric:power"
# Namespaces of light attributes and relationships (UsdLuxLightAPI, ShapingAPI, ShadowAPI, the
# light types, light linking); other attributes of a mesh light are the mesh's own.
_LIGHT_NAMESPACES = ("inputs:", "light:", "shaping:", "shadow:", "collection:lightLink", "collection:shadowLink",
                     "collection:filterLink", "treatAsPoint", "treatAsLine", "portals", "filters")


# ----------------------------------------------------------------------------------------------
# data classes
# ----------------------------------------------------------------------------------------------


@dataclass
class MeshInfo:
    path: str  # prim path (proxy path for instance proxies, synthesised for PointInstancer copies)
    name: str  # unique, valid USD identifier
    hide_path: str  # prim to make invisible in the solution layer
    is_light: bool = False
    has_uv: bool = False
    # The source topology, for lightmap UVs written back onto the original prim: per corner
    # of the mesh's faces as read (SceneArrays order), the index of that corner in the prim's
    # authored faceVertexIndices (a faceVarying primvar's slot); the authored corner count.
    corner_source: np.ndarray | None = None
    authored_corners: int = 0
    # The mesh's own lightmap UV set (a primvar named in outputs.lightmaps.uv_primvars), per
    # corner as read; None when it has none. Never the texture set unless the config names it.
    lightmap_uv: np.ndarray | None = None
    lightmap_uv_name: str | None = None
    # Meshes that are copies of one prototype (instance proxies of one prototype prim, one
    # PointInstancer prototype mesh) share this key: they share one lightmap UV layout.
    prototype: str | None = None
    # Where a lightmap UV set can be authored in a layer over the input: the prim itself, the
    # PointInstancer prototype mesh, or, inside a native instance (proxies are read-only), the
    # mesh in the prim the instances reference (see _native_instance_author).
    author_path: str | None = None
    # Instance roots (outermost first) the output layer makes non-instanceable so that this
    # mesh can carry its own UV set: a native instance whose prototype the layer cannot reach.
    deinstance: tuple[str, ...] = ()
    # The native instance root this mesh is in (None outside native instances).
    instance_root: str | None = None


@dataclass
class CameraInfo:
    path: str
    position: np.ndarray  # (3,) metres, world
    forward: np.ndarray  # (3,) unit
    up: np.ndarray  # (3,) unit, orthogonal to forward
    vertical_fov_degrees: float
    aspect: float  # width / height


@dataclass
class DistantLightInfo:
    """A UsdLux DistantLight read as daylight (a sun): ``direction`` is the unit world vector
    toward the light (its world +Z: the light travels along its -Z), ``angle`` its angular
    diameter in degrees (inputs:angle clipped to [0, 360)), ``illuminance`` the RGB illuminance
    (lux in photometric scenes) it gives a surface facing it, by the UsdLux rules (see
    :meth:`_Builder._distant_light`), ``luminance`` the RGB luminance of its disk (None for a
    parallel light, angle 0)."""

    path: str
    direction: np.ndarray
    angle: float
    illuminance: np.ndarray
    luminance: np.ndarray | None
    normalize: bool
    kind: str = "DistantLight"


@dataclass
class DomeLightInfo:
    """A UsdLux DomeLight (or DomeLight_1) read as daylight: the dome emits inward from every
    direction. ``radiance`` is intensity x 2^exposure x colour (RGB; the luminance of a uniform
    dome, the multiplier of the texels of a textured one); ``texture`` the resolved path of
    inputs:texture:file (None: uniform); ``texture_format`` latlong or automatic; ``pole_axis``
    "Y" or "Z" (DomeLight: always Y; DomeLight_1: poleAxis, "scene" resolved to the stage's up
    axis); ``rotation`` (3, 3) rows = the dome's local X, Y, Z axes in world space (the rotation
    of its transform; translation and scale do not orient a dome)."""

    path: str
    radiance: np.ndarray
    texture: str | None
    texture_format: str
    pole_axis: str
    rotation: np.ndarray
    kind: str = "DomeLight"


@dataclass
class SceneArrays:
    points: np.ndarray  # (V,3) float64 metres
    face_vertex_counts: np.ndarray  # (F,) int32
    face_vertex_indices: np.ndarray  # (sum counts,) int32
    face_mesh: np.ndarray  # (F,) int32 into meshes
    face_source: np.ndarray  # (F,) int32 authored face index within its mesh
    face_reflectance: np.ndarray  # (F,3) float64 in [0, 0.999]
    face_emission: np.ndarray  # (F,3) float64 exitance W/m^2
    corner_uv: np.ndarray | None  # (sum counts,2) float64 or None
    meshes: list[MeshInfo]
    cameras: list[CameraInfo]
    meters_per_unit: float
    up_axis: str
    warnings: list[str] = field(default_factory=list)
    source_path: str = ""
    # lights that are not Lambertian surfaces (hirad.photometry.luminaires.LuminaireSpec):
    # SphereLight, CylinderLight, RectLight/DiskLight with ShapingAPI; not in the geometry
    luminaires: list = field(default_factory=list)
    # daylight (read_scene(daylight=True)): DistantLightInfo and DomeLightInfo, in stage order;
    # hirad.daylight.sources turns them into distant lights
    daylight: list = field(default_factory=list)
    # glazing: per face the normal transmittance of direct light (0 opaque; hirad:transmittance or
    # UsdPreviewSurface opacity < 1), its reflectance at most 1 - transmittance
    face_transmittance: np.ndarray | None = None
    # sha256 of the arrays the light depends on (hirad.report.scene_fingerprint), once taken
    fingerprint: str | None = None

    @property
    def num_faces(self) -> int:
        return int(self.face_vertex_counts.shape[0])


def _corner_order(starts: np.ndarray, counts: np.ndarray, flip: bool) -> np.ndarray:
    """Indices of the corners of the given faces, in order; reversed (first corner kept) if flip."""
    counts = np.asarray(counts, dtype=np.int64)
    if len(counts) == 0:
        return np.zeros(0, dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    offset = np.arange(int(counts.sum()), dtype=np.int64) - np.repeat(first, counts)
    if flip:
        offset = np.where(offset == 0, 0, np.repeat(counts, counts) - offset)
    return np.repeat(np.asarray(starts, dtype=np.int64), counts) + offset


def _polygon_areas(points: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Area of each polygon (half the norm of its vector area; fine for non-planar polygons)."""
    counts = np.asarray(counts, dtype=np.int64)
    if len(counts) == 0:
        return np.zeros(0)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    cur = points[indices]
    nxt_corner = np.arange(len(indices)) + 1
    face_end = np.repeat(first + counts, counts)
    nxt_corner = np.where(nxt_corner == face_end, np.repeat(first, counts), nxt_corner)
    origin = np.repeat(points[indices[first]], counts, axis=0)
    cross = np.cross(cur - origin, points[indices[nxt_corner]] - origin)
    vec_area = np.add.reduceat(cross, first, axis=0)
    return 0.5 * np.linalg.norm(vec_area, axis=1)


def _finite_area(points: np.ndarray, counts: np.ndarray, indices: np.ndarray) -> float:
    a = _polygon_areas(points, counts, indices)
    return float(a[np.isfinite(a)].sum())


# ----------------------------------------------------------------------------------------------
# reading
# ----------------------------------------------------------------------------------------------


class _Builder:
    def __init__(self, default_reflectance, uv_primvars, time, warnings, ies_mode="absolute", daylight=False,
                 up_axis="Y"):
        self.default_reflectance = _checked_reflectance(_vec3(default_reflectance), "materials.default_reflectance",
                                                        warnings)
        self.uv_primvars = tuple(uv_primvars)
        self.lightmap_uv_primvars: tuple[str, ...] = ()
        self.time = time
        self.warnings = warnings
        self.materials = _MaterialResolver(time, warnings)
        self.names = _Names(reserved=[_LOOKS_NAME])
        self.meshes: list[MeshInfo] = []
        self.points: list[np.ndarray] = []
        self.counts: list[np.ndarray] = []
        self.indices: list[np.ndarray] = []
        self.face_source: list[np.ndarray] = []
        self.reflectance: list[np.ndarray] = []
        self.emission: list[np.ndarray] = []
        self.transmittance: list[np.ndarray] = []
        self.uvs: list[np.ndarray | None] = []
        self.n_points = 0
        self.unread_lights: list[str] = []  # lights that emit nothing in the bake, with why
        self.double_sided: list[str] = []   # meshes authored doubleSided (not honoured)
        self.instance_targets: dict = {}     # per native prototype, the prim its instances reference
        if ies_mode not in _lum.IES_MODES:
            raise SceneError(f"IES mode must be one of {', '.join(_lum.IES_MODES)}, got {ies_mode!r}")
        self.ies_mode = ies_mode
        self.luminaires: list = []
        self.daylight = bool(daylight)
        self.up_axis = up_axis
        self.daylight_lights: list = []
        self._ies_cache: dict = {}
        self._table_cache: dict = {}

    # --- geometry ------------------------------------------------------------------------------
    def _append(self, info, pts, counts, idx, source, refl, emis, uv, tau=None):
        finite = pts[np.isfinite(pts).all(axis=1)] if len(pts) else pts
        reach = float(np.abs(finite).max()) if len(finite) else 0.0
        if reach > MAX_COORDINATE_M:
            raise _PrimError(f"{info.path}: coordinates reach {reach:.3g} m (after metersPerUnit and transforms), "
                             f"beyond the {MAX_COORDINATE_M:g} m hirad can mesh; check the units "
                             "(metersPerUnit) and the transforms")
        if len(emis) and not (np.isfinite(emis).all() and emis.max() <= math.pi * MAX_RADIANCE):
            raise _PrimError(f"{info.path}: emitted exitance {float(np.nanmax(emis)):.3g} W/m^2 is not finite or beyond "
                             f"pi x {MAX_RADIANCE:g} (normalize over a tiny area?)")
        k = len(self.meshes)
        self.meshes.append(info)
        self.points.append(pts)
        self.counts.append(counts.astype(np.int32))
        self.indices.append((idx + self.n_points).astype(np.int32))
        self.face_source.append(source.astype(np.int32))
        tau = np.zeros(len(counts)) if tau is None else np.asarray(tau, dtype=np.float64)
        # glazing reflects at most what it does not let through
        over = np.nonzero((refl > (1.0 - tau)[:, None] + 1e-12).any(axis=1))[0] if len(tau) else []
        if len(over):
            self.warnings.append(
                f"{info.path}: {len(over)} glazed face(s) reflect more than they do not transmit (reflectance "
                f"{float(refl[over].max()):.3g} with transmittance {float(tau[over].max()):.3g}): reflectance lowered to "
                "1 - transmittance so that glass creates no light")
        refl = np.minimum(refl, (1.0 - tau)[:, None]) if len(tau) else refl
        self.reflectance.append(np.clip(refl, 0.0, _MAX_REFLECTANCE))
        self.emission.append(emis)
        self.transmittance.append(tau)
        self.uvs.append(uv)
        self.n_points += len(pts)
        return k

    def corner_uv(self, prim: Usd.Prim, counts, indices, n_points, names=None) -> np.ndarray | None:
        api = UsdGeom.PrimvarsAPI(prim)
        self.uv_name = None
        for name in (self.uv_primvars if names is None else names):
            pv = api.GetPrimvar(name)
            if not pv or not pv.HasAuthoredValue():
                continue
            vals = pv.ComputeFlattened(self.time)
            if vals is None or len(vals) == 0:
                continue
            try:
                arr = np.array(vals, dtype=np.float64)
            except (TypeError, ValueError):
                arr = np.zeros(0)
            if arr.ndim != 2 or arr.shape[1] < 2:
                self.warnings.append(f"{prim.GetPath()}: primvar {name} is {_value_type(vals)}, not texCoord2f[]; "
                                     "ignored")
                continue
            arr = arr[:, :2]
            interp = pv.GetInterpolation()
            self.uv_name = name
            if interp == UsdGeom.Tokens.faceVarying and len(arr) >= len(indices):
                return arr[: len(indices)]
            if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and len(arr) >= n_points:
                safe = np.clip(indices, 0, len(arr) - 1)
                return arr[safe]
            if interp == UsdGeom.Tokens.uniform and len(arr) >= len(counts):
                return np.repeat(arr[: len(counts)], counts, axis=0)
            if interp == UsdGeom.Tokens.constant:
                return np.repeat(arr[:1], len(indices), axis=0)
            self.uv_name = None
            self.warnings.append(
                f"{prim.GetPath()}: primvar {name} has {len(arr)} values, too few for "
                f"{interp} interpolation; ignored"
            )
        return None

    def add_mesh(self, prim: Usd.Prim, world: np.ndarray, mpu: float, path: str, hide_path: str,
                 prototype: str | None = None, author_path: str | None = None, deinstance: tuple[str, ...] = (),
                 instance_root: str | None = None):
        mesh = UsdGeom.Mesh(prim)
        t = self.time
        if mesh.GetDoubleSidedAttr().Get(t):
            self.double_sided.append(path)
        pts = _typed(mesh.GetPointsAttr(), t, _POINT_ARRAYS, "point3f[]", path)
        counts = _typed(mesh.GetFaceVertexCountsAttr(), t, _INDEX_ARRAYS, "int[]", path)
        indices = _typed(mesh.GetFaceVertexIndicesAttr(), t, _INDEX_ARRAYS, "int[]", path)
        if pts is None or counts is None or indices is None or len(counts) == 0:
            self.warnings.append(f"{path}: mesh has no points or faces; skipped")
            return
        pts = np.array(pts, dtype=np.float64).reshape(-1, 3)
        counts = np.array(counts, dtype=np.int64)
        indices = np.array(indices, dtype=np.int64)
        n_pts = len(pts)

        # validate faces
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        total = int(counts.sum()) if len(counts) else 0
        keep = np.ones(len(counts), dtype=bool)
        if total > len(indices) or (counts < 0).any():
            # truncated index array: faces whose corners run past the end are dropped
            keep &= (starts + np.maximum(counts, 0)) <= len(indices)
            counts = np.maximum(counts, 0)
        keep &= counts >= 3
        bad_index = (indices < 0) | (indices >= n_pts)
        if bad_index.any():
            corner_face = np.repeat(np.arange(len(counts)), counts)[: len(indices)]
            bad_faces = np.unique(corner_face[bad_index[: len(corner_face)]])
            keep[bad_faces] = False
        n_dropped = int((~keep).sum())
        if n_dropped:
            self.warnings.append(
                f"{path}: dropped {n_dropped} face(s) with fewer than 3 vertices or "
                f"out-of-range indices"
            )
        if not keep.any():
            self.warnings.append(f"{path}: no valid faces; skipped")
            return

        # orientation
        flip = mesh.GetOrientationAttr().Get(t) == UsdGeom.Tokens.leftHanded
        if np.linalg.det(world[:3, :3]) < 0:
            flip = not flip

        kept_faces = np.nonzero(keep)[0]
        kept_counts = counts[kept_faces]
        corner_src = _corner_order(starts[kept_faces], kept_counts, flip)
        new_indices = indices[corner_src]

        world_pts = _transform_points(pts, world) * mpu

        # per-face material (over all authored faces, then select kept ones)
        n_faces = len(counts)
        valid_idx = np.where(bad_index, 0, indices) if len(indices) else indices
        refl, emis, tau = self._face_materials(prim, path, n_faces, counts, valid_idx, total, n_pts)
        refl, emis, tau = refl[kept_faces], emis[kept_faces], tau[kept_faces]

        is_light = False
        if prim.HasAPI(UsdLux.MeshLightAPI):
            self._warn_unhonoured(prim, path, "MeshLightAPI", set())
            radiance = self._light_radiance(prim, path)
            if radiance is not None:
                if UsdLux.LightAPI(prim).GetNormalizeAttr().Get(t):
                    area = _finite_area(world_pts, kept_counts, new_indices)
                    radiance = radiance / area if area > 0 else radiance * 0.0
                power = self._photometric_power(prim, path)
                if power is not None:
                    radiance = self._radiance_for_power(path, radiance, power,
                                                        _finite_area(world_pts, kept_counts, new_indices))
                emis = np.repeat((math.pi * radiance)[None, :], len(kept_faces), axis=0)
                is_light = True

        uv_all = self.corner_uv(prim, counts, indices, n_pts) if len(indices) >= total else None
        uv = uv_all[corner_src] if uv_all is not None else None

        lm_uv, lm_name = None, None
        if self.lightmap_uv_primvars and len(indices) >= total and not is_light:
            lm_all = self.corner_uv(prim, counts, indices, n_pts, self.lightmap_uv_primvars)
            if lm_all is not None:
                lm_uv, lm_name = lm_all[corner_src], self.uv_name

        name = self.names.make(path)
        info = MeshInfo(path=path, name=name, hide_path=hide_path, is_light=is_light, has_uv=uv is not None,
                        corner_source=corner_src.astype(np.int32), authored_corners=int(len(indices)),
                        lightmap_uv=lm_uv, lightmap_uv_name=lm_name, prototype=prototype,
                        author_path=author_path, deinstance=deinstance, instance_root=instance_root)
        self._append(info, world_pts, kept_counts, new_indices, kept_faces, refl, emis, uv, tau)

    def _face_materials(self, prim, path, n_faces, counts, indices, total, n_points):
        """Per-face reflectance, exitance and glazing transmittance: the bound material's (per
        GeomSubset), else the displayColor, else the default (opaque); displayColor is read (and
        checked) only where it is used."""
        refl = np.repeat(self.default_reflectance[None, :], n_faces, axis=0)
        emis = np.zeros((n_faces, 3))
        tau = np.zeros(n_faces)
        read: list = []

        def display_color():
            if not read:
                read.append(_display_color_per_face(prim, self.time, counts, indices[:total], n_points, self.warnings)
                            if total <= len(indices) else None)
            return read[0]

        binding = UsdShade.MaterialBindingAPI(prim)
        mat = binding.ComputeBoundMaterial()[0]
        diffuse, emissive = self.materials.material_colors(mat)
        if diffuse is not None:
            refl[:] = diffuse
        elif display_color() is not None:
            refl = display_color().copy()
        if emissive is not None:
            emis[:] = math.pi * emissive
        t = self.materials.material_transmittance(mat)
        if t is not None:
            tau[:] = t
        try:
            subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        except Exception:  # pragma: no cover
            subsets = []
        for subset in subsets:
            sub_mat = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0]
            if not sub_mat or not sub_mat.GetPrim().IsValid():
                continue
            faces = _typed(subset.GetIndicesAttr(), self.time, _INDEX_ARRAYS, "int[]", str(subset.GetPath()))
            if faces is None:
                continue
            faces = np.array(faces, dtype=np.int64)
            faces = faces[(faces >= 0) & (faces < n_faces)]
            s_diffuse, s_emissive = self.materials.material_colors(sub_mat)
            if s_diffuse is not None:
                refl[faces] = s_diffuse
            elif display_color() is not None:
                refl[faces] = display_color()[faces]
            else:
                refl[faces] = self.default_reflectance
            emis[faces] = math.pi * s_emissive if s_emissive is not None else 0.0
            s_tau = self.materials.material_transmittance(sub_mat)
            tau[faces] = 0.0 if s_tau is None else s_tau
        return refl, emis, tau

    # --- lights ------------------------------------------------------------------------------
    def _light_radiance(self, prim: Usd.Prim, path: str) -> np.ndarray:
        """intensity x 2^exposure x color (x the blackbody colour when enabled), checked: a
        negative or non-finite intensity, colour or result is an error naming the attribute."""
        light = UsdLux.LightAPI(prim)
        t = self.time
        intensity = _number(light.GetIntensityAttr(), t, path, 1.0)
        exposure = _number(light.GetExposureAttr(), t, path, 0.0)
        color_attr = light.GetColorAttr()
        color = color_attr.Get(t)
        color = np.ones(3) if color is None else _colour(color, f"{path}.{color_attr.GetName()}")
        if not math.isfinite(intensity) or intensity < 0:
            raise _PrimError(f"{path}.inputs:intensity: {intensity:g} is not a light intensity "
                             "(it must be finite and not negative)")
        if not math.isfinite(exposure):
            raise _PrimError(f"{path}.inputs:exposure: {exposure:g} is not finite")
        _checked_emission(color, f"{path}.inputs:color", "colour")
        with np.errstate(over="ignore", invalid="ignore"):
            scale = 2.0 ** exposure if exposure < 1024 else math.inf
            radiance = intensity * scale * color
        if not (np.isfinite(radiance).all() and radiance.max() <= MAX_RADIANCE):
            raise _PrimError(f"{path}.inputs:exposure: intensity {intensity:g} x 2^{exposure:g} = "
                             f"{intensity * scale:.3g} W/(m^2 sr) is not a finite radiance hirad can represent "
                             f"(at most {MAX_RADIANCE:g})")
        if light.GetEnableColorTemperatureAttr().Get(t):
            temp = _number(light.GetColorTemperatureAttr(), t, path, 6500.0)
            if not math.isfinite(temp) or temp <= 0:
                raise _PrimError(f"{path}.inputs:colorTemperature: {temp:g} K is not a temperature")
            radiance = radiance * _vec3(UsdLux.BlackbodyTemperatureAsRgb(temp))
        return radiance

    def _warn_unhonoured(self, prim: Usd.Prim, path: str, kind: str, shape: set[str]) -> None:
        """One warning naming every authored light attribute or relationship hirad does not
        reproduce (shaping, shadows, textures, light linking, filters, diffuse/specular
        multipliers...) whose value differs from the schema's fallback."""
        definition = prim.GetPrimDefinition()
        ignored = []
        for attr in prim.GetAuthoredAttributes():
            name = attr.GetName()
            if not name.startswith(_LIGHT_NAMESPACES) or name in _HONOURED_LIGHT_ATTRS or name in shape:
                continue
            value = attr.Get(self.time)
            if value is None:
                continue
            fallback = definition.GetAttributeFallbackValue(name) if definition else None
            if fallback is not None and _same(value, fallback):
                continue
            ignored.append(f"{name} = {_short(value)}")
        for rel in prim.GetAuthoredRelationships():
            name = rel.GetName()
            if name.startswith(_LIGHT_NAMESPACES) and rel.GetTargets():
                ignored.append(f"{name} -> {', '.join(str(t) for t in rel.GetTargets())}")
        if ignored:
            self.warnings.append(f"{path}: {kind}: not honoured by hirad (ignored): " + "; ".join(ignored))

    def add_light(self, prim: Usd.Prim, world: np.ndarray, mpu: float, segments: int):
        path = str(prim.GetPath())
        kind = prim.GetTypeName() or "light"
        t = self.time
        if self.daylight and prim.IsA(UsdLux.DistantLight):
            return self._distant_light(prim, path, kind, world)
        if self.daylight and (prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1)):
            return self._dome_light(prim, path, kind, world)
        read = (UsdLux.RectLight, UsdLux.DiskLight, UsdLux.SphereLight, UsdLux.CylinderLight)
        if not any(prim.IsA(k) for k in read):
            shaping = [f"{a.GetName()} = {_short(a.Get(t))}" for a in prim.GetAuthoredAttributes()
                       if a.GetName().startswith(("inputs:shaping:", "shaping:")) and a.Get(t) is not None]
            self.warnings.append(f"{path}: {kind} is a light type hirad does not read (only RectLight, DiskLight, "
                                 "SphereLight, CylinderLight and MeshLightAPI emit); ignored, it emits nothing in the "
                                 "bake" + (f" (its shaping is not honoured either: {'; '.join(shaping)})"
                                           if shaping else ""))
            self.unread_lights.append(f"{path} ({kind})")
            return
        shaping = self._shaping(prim, path)
        if prim.IsA(UsdLux.RectLight):
            lt = UsdLux.RectLight(prim)
            w = _finite_size(path, "inputs:width", _number(lt.GetWidthAttr(), t, path, 0.0))
            h = _finite_size(path, "inputs:height", _number(lt.GetHeightAttr(), t, path, 0.0))
            if not (w > 0 and h > 0):
                self.warnings.append(f"{path}: RectLight of size {w:g} x {h:g} has no area; ignored")
                self.unread_lights.append(f"{path} (RectLight of zero size)")
                return
            if shaping.is_identity(upper_hemisphere=False):
                # counter-clockwise seen from -Z, so the right-hand normal is local -Z
                local = np.array([[-w / 2, -h / 2, 0], [-w / 2, h / 2, 0], [w / 2, h / 2, 0], [w / 2, -h / 2, 0]])
                return self._area_light(prim, path, kind, world, mpu, local, np.array([4]), np.arange(4))
        elif prim.IsA(UsdLux.DiskLight):
            lt = UsdLux.DiskLight(prim)
            r = _finite_size(path, "inputs:radius", _number(lt.GetRadiusAttr(), t, path, 0.0))
            if not r > 0:
                self.warnings.append(f"{path}: DiskLight of radius {r:g} has no area; ignored")
                self.unread_lights.append(f"{path} (DiskLight of zero radius)")
                return
            if shaping.is_identity(upper_hemisphere=False):
                n = max(3, int(segments))
                ang = -2.0 * math.pi * np.arange(n) / n  # clockwise from +Z => normal -Z
                local = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros(n)], axis=1)
                return self._area_light(prim, path, kind, world, mpu, local, np.array([n]), np.arange(n))
        self._luminaire(prim, path, kind, world, mpu, shaping)

    def _area_light(self, prim, path, kind, world, mpu, local, counts, idx):
        """A RectLight or DiskLight without shaping: an emitting polygon (M = pi L)."""
        self._warn_unhonoured(prim, path, kind, _SHAPE_ATTRS.get(kind, set()))
        radiance = self._light_radiance(prim, path)
        world_pts = _transform_points(local, world) * mpu
        if np.linalg.det(world[:3, :3]) < 0:
            idx = _flip_faces(counts, idx)
        area = _finite_area(world_pts, counts, idx)
        if UsdLux.LightAPI(prim).GetNormalizeAttr().Get(self.time):
            radiance = radiance / area if area > 0 else radiance * 0.0
        power = self._photometric_power(prim, path)
        if power is not None:
            radiance = self._radiance_for_power(path, radiance, power, area)
        nf = len(counts)
        emis = np.repeat((math.pi * radiance)[None, :], nf, axis=0)
        refl = np.zeros((nf, 3))
        name = self.names.make(path)
        info = MeshInfo(path=path, name=name, hide_path=path, is_light=True, has_uv=False)
        self._append(info, world_pts, counts, idx, np.arange(nf), refl, emis, None)

    # --- daylight ------------------------------------------------------------------------------
    def _distant_light(self, prim: Usd.Prim, path: str, kind: str, world: np.ndarray):
        """A DistantLight as a sun (DistantLightInfo), by the UsdLux rules (usdLux schema,
        LightAPI inputs:normalize and DistantLight inputs:angle):

        * the light travels along its -Z: the direction toward it is the world image of +Z;
        * its disk has angular radius theta_max = clamp(radians(angle) / 2, 0, pi) and a uniform
          luminance L = intensity x 2^exposure x colour / sizeFactor, where sizeFactor = 1 without
          ``normalize`` or for angle 0, pi sin^2(theta_max) for 0 < theta_max <= pi/2 and
          (2 - sin^2(theta_max)) pi beyond;
        * a surface facing the light receives E = L x pi sin^2(theta_max) (the cosine-weighted
          solid angle of the disk; pi beyond a hemisphere, where only the front half reaches
          it), so with ``normalize`` and theta_max <= pi/2, E = intensity x 2^exposure x colour:
          the intensity is the perpendicular illuminance in lux, whatever the angle;
        * angle 0 is a parallel light whose intensity x 2^exposure x colour is that illuminance
          (normalize or not)."""
        t = self.time
        lt = UsdLux.DistantLight(prim)
        angle = _number(lt.GetAngleAttr(), t, path, 0.53)
        if not math.isfinite(angle):
            raise _PrimError(f"{path}.inputs:angle: {angle:g} is not a finite angle")
        if not 0.0 <= angle < 360.0:
            clipped = min(max(angle, 0.0), math.nextafter(360.0, 0.0))
            self.warnings.append(f"{path}: DistantLight inputs:angle = {angle:g} degrees is outside [0, 360); "
                                 f"clipped to {clipped:g} as UsdLux says")
            angle = clipped
        self._warn_unhonoured(prim, path, kind, {"inputs:angle"})
        radiance = self._light_radiance(prim, path)
        normalize = bool(UsdLux.LightAPI(prim).GetNormalizeAttr().Get(t))
        direction = np.asarray(world[2, :3], dtype=np.float64)
        norm = float(np.linalg.norm(direction))
        if not (math.isfinite(norm) and norm > 0):
            raise _PrimError(f"{path}: the transform collapses the light's Z axis: it has no direction")
        direction = direction / norm
        theta = min(max(math.radians(angle) / 2.0, 0.0), math.pi)
        if theta == 0.0:
            illuminance, luminance = radiance.copy(), None
        else:
            s2 = math.sin(theta) ** 2
            size = 1.0
            if normalize:
                size = math.pi * s2 if theta <= math.pi / 2 else (2.0 - s2) * math.pi
            luminance = radiance / size
            illuminance = luminance * (math.pi * s2 if theta <= math.pi / 2 else math.pi)
        self.daylight_lights.append(DistantLightInfo(path=path, direction=direction, angle=float(angle),
                                                     illuminance=illuminance, luminance=luminance,
                                                     normalize=normalize, kind=kind))

    def _dome_light(self, prim: Usd.Prim, path: str, kind: str, world: np.ndarray):
        """A DomeLight or DomeLight_1 (DomeLightInfo): uniform, or a latlong texture (checked to
        exist here; read by hirad.daylight.sources). ``normalize`` does not apply to domes
        (UsdLux: sizeFactor 1)."""
        t = self.time
        honoured = {"inputs:texture:file", "inputs:texture:format", "poleAxis"}
        self._warn_unhonoured(prim, path, kind, honoured)
        radiance = self._light_radiance(prim, path)
        texture = None
        tex_attr = prim.GetAttribute("inputs:texture:file")
        if tex_attr and tex_attr.HasAuthoredValue() and tex_attr.Get(t) is not None:
            texture = self._asset_path(tex_attr, path, "sky texture")
        fmt_attr = prim.GetAttribute("inputs:texture:format")
        fmt = fmt_attr.Get(t) if fmt_attr else None
        fmt = "automatic" if fmt is None else str(fmt)
        if texture is not None and fmt not in ("latlong", "automatic"):
            raise _PrimError(f"{path}.inputs:texture:format: {fmt!r}: hirad reads latlong dome textures only "
                             "(latlong, or automatic on a 2:1 latlong image); convert the texture")
        pole = "Y"
        if prim.IsA(UsdLux.DomeLight_1):
            a = prim.GetAttribute("poleAxis")
            token = str(a.Get(t)) if a and a.Get(t) is not None else "scene"
            if token not in ("scene", "Y", "Z"):
                raise _PrimError(f"{path}.poleAxis: {token!r}: must be scene, Y or Z")
            pole = self.up_axis if token == "scene" else token
        else:
            a = prim.GetAttribute("poleAxis")
            if a and a.HasAuthoredValue() and str(a.Get(t)) not in ("Y", "scene"):
                self.warnings.append(f"{path}: {kind}: poleAxis = {a.Get(t)} is a DomeLight_1 attribute; a "
                                     "DomeLight's pole is always +Y (UsdLux): not honoured (ignored)")
        self.daylight_lights.append(DomeLightInfo(path=path, radiance=radiance, texture=texture, texture_format=fmt,
                                                  pole_axis=pole, rotation=self._rotation(path, kind, world),
                                                  kind=kind))

    def _rotation(self, path: str, kind: str, world: np.ndarray) -> np.ndarray:
        """The orthogonal part of the transform's 3 x 3 (polar decomposition; a mirror stays a
        mirror), rows = local axes in world space; a shear or non-uniform scale is named."""
        m = np.asarray(world[:3, :3], dtype=np.float64)
        if not np.isfinite(m).all():
            raise _PrimError(f"{path}: the transform is not finite")
        u, sv, vt = np.linalg.svd(m)
        if not sv[-1] > 1e-12 * max(sv[0], 1e-300):
            raise _PrimError(f"{path}: the transform is singular: the {kind} has no orientation")
        if sv[0] - sv[-1] > 1e-6 * sv[0]:
            self.warnings.append(f"{path}: {kind} under a non-uniform scale or shear: oriented by the transform's "
                                 "rotation alone")
        return u @ vt

    def _asset_path(self, attr: Usd.Attribute, path: str, what: str) -> str | None:
        """An asset attribute's file, resolved (USD's resolver, else relative to the layer that
        authors it); a missing file is an error naming the prim, the attribute and the file."""
        value = attr.Get(self.time)
        where = f"{path}.{attr.GetName()}"
        authored = getattr(value, "path", None)
        if authored is None:
            raise _PrimError(f"{where}: is {_value_type(value)} {_short(value)}, expected an asset path (@file@)")
        if not authored:
            return None
        resolved = getattr(value, "resolvedPath", "") or ""
        layer_dir = ""
        if not resolved:
            try:
                spec = attr.GetPropertyStack(self.time)[0]
                layer_path = spec.layer.realPath or spec.layer.identifier
                layer_dir = os.path.dirname(os.path.abspath(layer_path)) if layer_path else ""
            except Exception:  # pragma: no cover - anonymous layers
                layer_dir = ""
            resolved = authored if os.path.isabs(authored) else os.path.join(layer_dir or os.getcwd(), authored)
        if not os.path.isfile(resolved):
            rel = f", relative to {layer_dir}" if layer_dir else ""
            raise _PrimError(f"{where}: {what} not found: {resolved} (authored @{authored}@{rel})")
        return os.path.normpath(resolved)

    # --- luminaires ----------------------------------------------------------------------------
    def _shaping(self, prim: Usd.Prim, path: str) -> "_lum.Shaping":
        """The authored UsdLuxShapingAPI values (read by name, applied schema or not), checked."""
        t = self.time
        sh = _lum.Shaping()

        def authored(name):
            a = prim.GetAttribute(name)
            return a if a and a.HasAuthoredValue() and a.Get(t) is not None else None

        def finite(name, default):
            a = authored(name)
            if a is None:
                return None
            v = _number(a, t, path, default)
            if not math.isfinite(v):
                raise _PrimError(f"{path}.{name}: {v:g} is not finite")
            return v

        sh.cone_angle = finite("inputs:shaping:cone:angle", 90.0)
        sh.cone_softness = finite("inputs:shaping:cone:softness", 0.0) or 0.0
        sh.focus = finite("inputs:shaping:focus", 0.0) or 0.0
        sh.ies_angle_scale = finite("inputs:shaping:ies:angleScale", 0.0) or 0.0
        a = authored("inputs:shaping:focusTint")
        if a is not None:
            sh.focus_tint = _colour(a.Get(t), f"{path}.inputs:shaping:focusTint")
            _checked_emission(sh.focus_tint, f"{path}.inputs:shaping:focusTint", "colour")
        a = authored("inputs:shaping:ies:normalize")
        if a is not None:
            v = a.Get(t)
            if not isinstance(v, bool):
                raise _PrimError(f"{path}.inputs:shaping:ies:normalize: is {_value_type(v)} {_short(v)}, expected a bool")
            sh.ies_normalize = v
        a = authored("inputs:shaping:ies:file")
        if a is not None:
            sh.ies_file = self._ies_path(a, path)
        return sh

    def _ies_path(self, attr: Usd.Attribute, path: str) -> str | None:
        """The IES file of inputs:shaping:ies:file, resolved (USD's resolver, else relative to
        the layer that authors it); a missing file is an error naming the prim and the file."""
        return self._asset_path(attr, path, "IES file")

    def _photometry(self, ies_file: str, path: str):
        from hirad.photometry import IesError, IesWarning, read_ies
        st = os.stat(ies_file)
        key = (ies_file, st.st_mtime_ns, st.st_size)
        if key not in self._ies_cache:
            with _warnings.catch_warnings(record=True) as caught:
                _warnings.simplefilter("always", IesWarning)
                try:
                    p = read_ies(ies_file)
                except IesError as exc:
                    raise _PrimError(f"{path}.inputs:shaping:ies:file: {exc}") from None
                except OSError as exc:
                    raise _PrimError(f"{path}.inputs:shaping:ies:file: {ies_file}: cannot be read "
                                     f"({exc.strerror or exc})") from None
            self._ies_cache[key] = (p, [str(w.message) for w in caught if issubclass(w.category, IesWarning)])
            for text in self._ies_cache[key][1]:
                self.warnings.append(f"{path}: IES file: {text}")
        return self._ies_cache[key][0], key

    def _photometric_power(self, prim: Usd.Prim, path: str):
        a = prim.GetAttribute(PHOTOMETRIC_POWER)
        if not a or not a.HasAuthoredValue():
            return None
        v = _number(a, self.time, path, 0.0)
        if not (math.isfinite(v) and v >= 0):
            raise _PrimError(f"{path}.{PHOTOMETRIC_POWER}: {v:g} lm is not a luminous flux (finite, not negative)")
        return v

    def _radiance_for_power(self, path, radiance, power, area):
        """The radiance whose Lambertian flux pi A Y(L) is `power` lumens."""
        y = math.pi * area * float(np.asarray(radiance) @ _lum.Y_WEIGHTS)
        if not y > 0:
            raise _PrimError(f"{path}.{PHOTOMETRIC_POWER}: {power:g} lm on a light that emits nothing (its "
                             "intensity, colour or area is 0): nothing to scale")
        return radiance * (power / y)

    def _luminaire(self, prim: Usd.Prim, path: str, kind: str, world: np.ndarray, mpu: float, shaping):
        """SphereLight, CylinderLight, shaped RectLight/DiskLight: LuminaireSpec(s) (formulas in
        hirad.photometry.luminaires)."""
        t = self.time
        light = UsdLux.LightAPI(prim)
        axes = world[:3, :3]
        sx, sy, sz = (float(np.linalg.norm(axes[k])) for k in range(3))
        try:
            frame, mirrored, irregular = _lum.frame_from_axes(axes[0], axes[1], axes[2])
        except _lum.LuminaireError as exc:
            raise _PrimError(f"{path}: {exc}") from None
        notes: list[str] = []
        if irregular:
            self.warnings.append(f"{path}: the transform shears the light's axes; its profile is oriented by "
                                 "the orthonormalised frame (Z, then X)")
        normalize = bool(light.GetNormalizeAttr().Get(t))
        power = self._photometric_power(prim, path)
        origin = world[3, :3] * mpu
        size_area = None  # world area for normalize
        if prim.IsA(UsdLux.SphereLight):
            lt = UsdLux.SphereLight(prim)
            r = _finite_size(path, "inputs:radius", _number(lt.GetRadiusAttr(), t, path, 0.0))
            if r < 0:
                raise _PrimError(f"{path}.inputs:radius: {r:g} is not a radius (negative)")
            if max(sx, sy, sz) - min(sx, sy, sz) > 1e-6 * max(sx, sy, sz):
                self.warnings.append(f"{path}: SphereLight under a non-uniform scale ({sx:g}, {sy:g}, {sz:g}) is read "
                                     "as a sphere of the mean scale (their geometric mean)")
            rw = r * (sx * sy * sz) ** (1.0 / 3.0) * mpu
            point = bool(lt.GetTreatAsPointAttr().Get(t))
            pts, wts = origin[None, :], np.ones(1)
            if rw > 0:
                base, size_area = _lum.isotropic(math.pi * rw * rw), 4.0 * math.pi * rw * rw
                label = f"SphereLight r = {rw:.4g} m" + (" (treatAsPoint)" if point else "")
                base_key = ("sphere", rw)
            elif normalize or power is not None or shaping.ies_file is not None:
                # the zero-radius limit: L / (4 pi r^2) x pi r^2 = L / 4 cd with normalize
                base = _lum.isotropic(0.25 if normalize else 1.0)
                label, base_key = "SphereLight r = 0 (point)", ("sphere0", normalize)
                notes.append("radius 0: " + ("I = L/4 cd, the limit of the normalized sphere" if normalize
                                             else "an isotropic point whose flux photometric:power or the IES "
                                                  "file gives"))
            else:
                self.warnings.append(f"{path}: SphereLight of radius {r:g} (a point light) has no area: its "
                                     "emission L x pi r^2 is 0 (set inputs:normalize for I = L/4 cd, or "
                                     f"{PHOTOMETRIC_POWER}); ignored")
                self.unread_lights.append(f"{path} (SphereLight of zero radius: a point light)")
                return
        elif prim.IsA(UsdLux.CylinderLight):
            lt = UsdLux.CylinderLight(prim)
            length = _finite_size(path, "inputs:length", _number(lt.GetLengthAttr(), t, path, 0.0))
            r = _finite_size(path, "inputs:radius", _number(lt.GetRadiusAttr(), t, path, 0.0))
            if not length > 0 or r < 0:
                self.warnings.append(f"{path}: CylinderLight of length {length:g} and radius {r:g} has no area; "
                                     "ignored")
                self.unread_lights.append(f"{path} (CylinderLight of zero size)")
                return
            if abs(sy - sz) > 1e-6 * max(sy, sz):
                self.warnings.append(f"{path}: CylinderLight under a non-uniform scale of its cross-section "
                                     f"({sy:g}, {sz:g}) is read as a round cylinder of their geometric mean")
            lw, rw = length * sx * mpu, r * math.sqrt(sy * sz) * mpu
            local, wts = _lum.line_points(length, r)
            pts = _transform_points(local, world) * mpu
            if rw > 0:
                base, size_area = _lum.cylinder(2.0 * rw * lw), 2.0 * math.pi * rw * lw
                base_key = ("cylinder", rw * lw)
            elif normalize or power is not None or shaping.ies_file is not None:
                base = _lum.cylinder(1.0 / math.pi if normalize else 1.0)  # limit: L sin(alpha) / pi
                base_key = ("cylinder0", normalize)
            else:
                self.warnings.append(f"{path}: CylinderLight of radius 0 (a line) has no area: its emission is 0 "
                                     f"(set inputs:normalize or {PHOTOMETRIC_POWER}); ignored")
                self.unread_lights.append(f"{path} (CylinderLight of zero radius: a line)")
                return
            label = f"CylinderLight {lw:.4g} m x r {rw:.4g} m"
        elif prim.IsA(UsdLux.RectLight):
            lt = UsdLux.RectLight(prim)
            w = _number(lt.GetWidthAttr(), t, path, 0.0)
            h = _number(lt.GetHeightAttr(), t, path, 0.0)
            size_area = w * h * float(np.linalg.norm(np.cross(axes[0], axes[1]))) * mpu * mpu
            base, base_key = _lum.lambertian(size_area), ("lambert", size_area)
            local, wts = _lum.rect_points(w, h)
            pts = _transform_points(local, world) * mpu
            label = f"RectLight {w * sx * mpu:.4g} x {h * sy * mpu:.4g} m"
        else:
            lt = UsdLux.DiskLight(prim)
            r = _number(lt.GetRadiusAttr(), t, path, 0.0)
            size_area = math.pi * r * r * float(np.linalg.norm(np.cross(axes[0], axes[1]))) * mpu * mpu
            base, base_key = _lum.lambertian(size_area), ("lambert", size_area)
            local, wts = _lum.disk_points(r)
            pts = _transform_points(local, world) * mpu
            label = f"DiskLight r = {r * math.sqrt(sx * sy) * mpu:.4g} m"
        self._warn_unhonoured(prim, path, kind, _SHAPE_ATTRS.get(kind, set()))
        radiance = self._light_radiance(prim, path)
        photometry, ies_key = (None, None)
        mode = self.ies_mode
        if shaping.ies_file is not None:
            photometry, ies_key = self._photometry(shaping.ies_file, path)
        colour = radiance
        if photometry is not None and mode == "absolute":
            base_key = None  # the file's candela replace the shape's profile
            if normalize:
                notes.append("inputs:normalize does not apply to an absolute IES profile")
        elif normalize and size_area:
            colour = radiance / size_area
        shape_desc = []
        if shaping.cone_angle is not None:
            shape_desc.append(f"cone {shaping.cone_angle:g} deg" + (f" softness {shaping.cone_softness:g}"
                                                                    if shaping.cone_softness else ""))
        if shaping.focus_active():
            shape_desc.append(f"focus {shaping.focus:g}")
        if photometry is not None:
            shape_desc.append(f"IES ({mode})" + (f" angleScale {shaping.ies_angle_scale:g}"
                                                 if shaping.ies_angle_scale else ""))
        if shape_desc:
            label += ", " + ", ".join(shape_desc)
        tint = None if shaping.focus_tint is None else tuple(float(v) for v in shaping.focus_tint)
        key = (base_key, shaping.cone_angle, shaping.cone_softness, shaping.focus if shaping.focus_active() else 0.0,
               tint, ies_key, shaping.ies_angle_scale, shaping.ies_normalize, mode if photometry is not None else None)
        parts = _lum.shaped_parts(base, colour, shaping, photometry, mode)
        if key not in self._table_cache:
            tables = [_lum.sample_table(prof) for prof, _ in parts]
            for table in tables:
                table.setflags(write=False)  # shared by every light of the same kind
            self._table_cache[key] = tables
        tables = self._table_cache[key]
        specs = []
        for k, ((_, col), table) in enumerate(zip(parts, tables)):
            specs.append(_lum.LuminaireSpec(
                name=path if k == 0 else f"{path} (focus tint)", kind=kind, source=path, points=pts, weights=wts,
                frame=frame, candela=_lum.mirror_c(table) if mirrored else table, colour=np.maximum(col, 0.0),
                ies=shaping.ies_file, ies_mode=mode if photometry is not None else None, notes=list(notes),
                label=label, group=path if len(parts) > 1 else None))
        if power is not None:
            try:
                _lum.scale_group_to_lumens(specs, power)
            except _lum.LuminaireError:
                raise _PrimError(f"{path}.{PHOTOMETRIC_POWER}: {power:g} lm on a light that emits nothing (its "
                                 "intensity or colour is 0): nothing to scale") from None
            for s in specs:
                s.notes.append(f"scaled to {PHOTOMETRIC_POWER} = {power:g} lm")
        self.luminaires.extend(specs)

    # --- result --------------------------------------------------------------------------------
    def build(self, cameras, mpu, up_axis, source) -> SceneArrays:
        # Each per-mesh list is emptied as soon as its whole array is made, so that the lists
        # and the whole arrays are never all held at once (the read's peak).
        def whole(parts: list, dtype) -> np.ndarray:
            out = np.concatenate(parts).astype(dtype, copy=False)
            parts.clear()
            return out

        has_uv = any(u is not None for u in self.uvs)
        corner_uv = None
        if has_uv:
            corner_uv = whole([u if u is not None else np.zeros((len(i), 2)) for u, i in zip(self.uvs, self.indices)],
                              np.float64)
        self.uvs.clear()
        face_mesh = np.concatenate([np.full(len(c), k, dtype=np.int32) for k, c in enumerate(self.counts)])
        arrays = dict(points=whole(self.points, np.float64), face_vertex_counts=whole(self.counts, np.int32),
                      face_vertex_indices=whole(self.indices, np.int32), face_source=whole(self.face_source, np.int32),
                      face_reflectance=whole(self.reflectance, np.float64),
                      face_emission=whole(self.emission, np.float64),
                      face_transmittance=whole(self.transmittance, np.float64))
        return SceneArrays(
            **arrays,
            face_mesh=face_mesh,
            corner_uv=corner_uv,
            meshes=self.meshes,
            cameras=cameras,
            meters_per_unit=mpu,
            up_axis=up_axis,
            warnings=self.warnings,
            source_path=source,
            luminaires=self.luminaires,
            daylight=self.daylight_lights,
        )


def _typed(attr: Usd.Attribute, time, types: tuple, expected: str, path: str):
    """The attribute's value, None when it has none; a value of another type (``int[] points``)
    is an error naming the prim, the attribute and both types."""
    value = attr.Get(time)
    if value is None or isinstance(value, types):
        return value
    raise _PrimError(f"{path}.{attr.GetName()}: is {_value_type(value)}, expected {expected}")


def _number(attr: Usd.Attribute, time, path: str, default: float) -> float:
    """A scalar light attribute as a float (`default` when it has no value); anything that is not
    one number is an error naming the attribute."""
    value = attr.Get(time)
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _PrimError(f"{path}.{attr.GetName()}: is {_value_type(value)} {_short(value)}, expected a number")
    return float(value)


def _finite_size(path: str, name: str, value: float) -> float:
    if not math.isfinite(value):
        raise _PrimError(f"{path}.{name}: {value:g} is not a finite size")
    return value


def _same(a, b) -> bool:
    try:
        return bool(a == b)
    except Exception:  # pragma: no cover - exotic value types
        return False


def _short(value) -> str:
    text = repr(value) if isinstance(value, str) else str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _flip_faces(counts: np.ndarray, idx: np.ndarray) -> np.ndarray:
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return np.asarray(idx)[_corner_order(first, counts, True)]


def _camera_info(prim: Usd.Prim, world: np.ndarray, mpu: float, time) -> CameraInfo:
    cam = UsdGeom.Camera(prim)
    focal = float(cam.GetFocalLengthAttr().Get(time) or 50.0)
    v_ap = float(cam.GetVerticalApertureAttr().Get(time) or 15.2908)
    h_ap = float(cam.GetHorizontalApertureAttr().Get(time) or 20.955)
    pos = world[3, :3] * mpu
    fwd = -world[2, :3]
    up = world[1, :3]
    fwd = fwd / np.linalg.norm(fwd)
    up = up - np.dot(up, fwd) * fwd
    up = up / np.linalg.norm(up)
    fov = math.degrees(2.0 * math.atan(0.5 * v_ap / focal)) if focal > 0 else 60.0
    return CameraInfo(
        path=str(prim.GetPath()),
        position=np.array(pos, dtype=np.float64),
        forward=fwd,
        up=up,
        vertical_fov_degrees=fov,
        aspect=h_ap / v_ap if v_ap > 0 else 1.0,
    )


def read_cameras(stage: Usd.Stage) -> list[CameraInfo]:
    """All UsdGeom.Camera prims of a stage (world transform applied, metres)."""
    time = _stage_time(stage)
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    xfc = UsdGeom.XformCache(time)
    out = []
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        if prim.IsA(UsdGeom.Camera):
            out.append(_camera_info(prim, _mat(xfc.GetLocalToWorldTransform(prim)), mpu, time))
    return out


def _skip_imageable(prim: Usd.Prim, time) -> bool:
    if not prim.IsA(UsdGeom.Imageable):
        return False
    img = UsdGeom.Imageable(prim)
    if img.ComputeVisibility(time) == UsdGeom.Tokens.invisible:
        return True
    return img.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)


def _nearest_instance_root(prim: Usd.Prim) -> Usd.Prim:
    p = prim
    while p and p.IsInstanceProxy():
        p = p.GetParent()
    return p if p and p.IsInstance() else prim


def _instance_roots(prim: Usd.Prim) -> list[Usd.Prim]:
    """Every instance root above an instance proxy (nested instances), outermost first."""
    roots = []
    p = prim.GetParent()
    while p and not p.IsPseudoRoot():
        if p.IsInstance():
            roots.append(p)
        p = p.GetParent()
    return roots[::-1]


def _native_instance_author(prim: Usd.Prim, targets: dict) -> tuple[str | None, tuple[str, ...]]:
    """Where the lightmap UV set of `prim`, a mesh inside a native instance, can be authored.

    No layer can author over an instance proxy: a prototype is composed from the arcs of its
    instances' root, not from opinions below the root. But when the instances reference a prim
    of the stage's own layer stack (an internal reference, typically to a `class` or `over` that
    is not drawn itself), an over on the referenced mesh in a layer of that stack composes into
    the prototype and so into every instance: the UV set is shared, as a prototype's must be,
    and instancing is kept. Returns (that mesh's path, ()) then. Otherwise (a reference to
    another file, several arcs, nested instances) returns (the proxy's own path, the instance
    roots to make non-instanceable): the output layer de-instances them and each copy carries
    its own UV set; the caller names them in a warning. `targets` caches per prototype the
    prim its instances reference (None: none the layer can reach): instances of one prototype
    share their arcs, so the composition is queried once per prototype, not once per copy."""
    roots = _instance_roots(prim)
    own = (str(prim.GetPath()), tuple(str(r.GetPath()) for r in roots))
    if len(roots) != 1:
        return own
    root = roots[0]
    stage = prim.GetStage()
    key = str(root.GetPrototype().GetPath())
    if key not in targets:
        arcs = Usd.PrimCompositionQuery.GetDirectReferences(root).GetCompositionArcs()
        node = arcs[0].GetTargetNode() if len(arcs) == 1 else None
        targets[key] = node.path if node is not None and node.layerStack.identifier.rootLayer == stage.GetRootLayer() \
            else None
    if targets[key] is None:
        return own
    target = targets[key].AppendPath(prim.GetPath().MakeRelativePath(root.GetPath()))
    held = stage.GetPrimAtPath(target)
    if not held or held.IsInstanceProxy() or not held.IsA(UsdGeom.Mesh):
        return own
    return str(target), ()


def _is_light_prim(prim: Usd.Prim) -> bool:
    return prim.HasAPI(UsdLux.LightAPI) or prim.IsA(UsdLux.BoundableLightBase) or prim.IsA(UsdLux.NonboundableLightBase)


def _composition_warnings(stage: Usd.Stage, path) -> list[str]:
    """USD's composition errors (a missing sublayer or reference, a reference cycle...), which
    USD itself only prints on stderr, as warnings; each distinct one once."""
    out: list[str] = []
    try:
        errors = stage.GetCompositionErrors()
    except Exception:  # pragma: no cover - older USD
        return out
    for err in errors:
        text = " ".join(str(err).split())
        text = re.sub(r",?@anon:[^@]*@", "", text)  # the session layer's address differs per run
        line = f"{path}: USD composition: {text}"
        if line not in out:
            out.append(line)
    return out


def read_scene(
    path: str | Path,
    default_reflectance=(0.5, 0.5, 0.5),
    uv_primvars: Sequence[str] = ("st", "uv", "UVMap", "st0", "map1"),
    light_segments: int = 32,
    require_emission: bool = False,
    ies_mode: str = "absolute",
    daylight: bool = False,
    lightmap_uv_primvars: Sequence[str] = (),
) -> SceneArrays:
    """Flatten a USD stage into :class:`SceneArrays` (see module docstring for conventions).

    The scene is checked as it is read, and every problem names the prim and the attribute:

    * errors (:class:`SceneError`): ``metersPerUnit`` not finite and positive, ``upAxis`` other
      than Y or Z, coordinates beyond ``MAX_COORDINATE_M`` metres, geometry attributes of the
      wrong type (``int[] points``), a negative or non-finite light intensity, colour or
      colour temperature, an exposure whose radiance is not finite, a negative or non-finite
      reflectance (diffuseColor, displayColor) or emissiveColor;
    * warnings (``SceneArrays.warnings``): a reflectance above 0.999, clamped to 0.999; a
      displayColor whose size does not fit its interpolation; USD composition errors (a
      missing sublayer or reference, a reference cycle); light types hirad does not read
      (PortalLight, GeometryLight, ...; DomeLight and DistantLight without `daylight`) and
      authored light attributes it does not
      honour (shadows, light linking, textures, ``inputs:diffuse`` or ``inputs:specular`` other
      than 1, shaping on a MeshLightAPI or a light type hirad does not read).

    Lights: MeshLightAPI meshes and RectLight/DiskLight without shaping are emitting polygons
    (``face_emission``); SphereLight, CylinderLight and RectLight/DiskLight with any
    UsdLuxShapingAPI attribute authored are luminaires (``SceneArrays.luminaires``, a list of
    hirad.photometry.luminaires.LuminaireSpec, not part of the geometry: such a light reflects
    and occludes nothing), with the formulas of that module. `ies_mode` ('absolute' or 'usdlux',
    the config's ``photometry.ies_mode``) is how ``inputs:shaping:ies:file`` profiles are read; an
    IES file that is missing or unreadable is an error naming the prim, the file (and the line).
    ``photometric:power`` (lm) on a light scales it to emit exactly that luminous flux.

    With `require_emission` (a bake), a scene in which nothing emits light (no emitting face and
    no luminaire with a positive flux) is an error; reading a dark scene is fine otherwise
    (``hirad info``, tests).

    With `daylight` (a reader whose caller lights the scene with hirad.daylight.sources), a
    DistantLight (a sun) and a DomeLight or DomeLight_1 (a sky) are read into
    ``SceneArrays.daylight`` (DistantLightInfo, DomeLightInfo: direction, angle and illuminance by
    the UsdLux normalize rules; uniform or latlong-textured dome with its orientation and
    poleAxis), count as emission for `require_emission`, and their attributes hirad does not
    honour are named in a warning; a dome texture that is missing or not latlong is an error
    naming the prim and the file. Without it (the default) they are named as light types the
    bake does not read, as before.
    """
    stage = _open_stage(path)
    time = _stage_time(stage)
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (math.isfinite(mpu) and mpu > 0):
        raise SceneError(f"{path}: metersPerUnit = {mpu:g}: must be a positive, finite number of metres per unit")
    if mpu > MAX_COORDINATE_M:
        raise SceneError(f"{path}: metersPerUnit = {mpu:g}: a unit longer than {MAX_COORDINATE_M:g} m is beyond "
                         "what hirad can mesh")
    up_axis = str(UsdGeom.GetStageUpAxis(stage))
    if up_axis not in ("Y", "Z"):
        raise SceneError(f"{path}: upAxis = {up_axis!r}: USD allows only \"Y\" or \"Z\"")
    xfc = UsdGeom.XformCache(time)
    warnings: list[str] = _composition_warnings(stage, path)
    cameras: list[CameraInfo] = []
    try:
        b = _Builder(default_reflectance, uv_primvars, time, warnings, ies_mode=ies_mode, daylight=daylight,
                     up_axis=up_axis)
        b.lightmap_uv_primvars = tuple(lightmap_uv_primvars)
        it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()))
        for prim in it:
            if _skip_imageable(prim, time):
                it.PruneChildren()
                continue
            if prim.IsA(UsdGeom.PointInstancer):
                _add_point_instancer(b, prim, xfc, mpu, time)
                it.PruneChildren()
                continue
            if prim.IsA(UsdGeom.Camera):
                cameras.append(_camera_info(prim, _mat(xfc.GetLocalToWorldTransform(prim)), mpu, time))
                continue
            if prim.IsA(UsdGeom.Mesh):
                world = _mat(xfc.GetLocalToWorldTransform(prim))
                proxy = prim.IsInstanceProxy()
                hide = _nearest_instance_root(prim) if proxy else prim
                author, deinstance = (_native_instance_author(prim, b.instance_targets) if proxy
                                      else (str(prim.GetPath()), ()))
                b.add_mesh(prim, world, mpu, str(prim.GetPath()), str(hide.GetPath()),
                           prototype=str(prim.GetPrimInPrototype().GetPath()) if proxy else None,
                           author_path=author, deinstance=deinstance,
                           instance_root=str(hide.GetPath()) if proxy else None)
            elif _is_light_prim(prim):
                b.add_light(prim, _mat(xfc.GetLocalToWorldTransform(prim)), mpu, light_segments)
            elif prim.IsA(UsdLux.LightFilter):
                warnings.append(f"{prim.GetPath()}: {prim.GetTypeName()} (a light filter) is not honoured; ignored")
    except _PrimError as exc:
        raise SceneError(f"{path}: {exc}") from None

    if not b.meshes:
        raise SceneError(f"{path}: no meshes found")
    if b.double_sided:
        shown = ", ".join(b.double_sided[:3]) + (f" and {len(b.double_sided) - 3} more" if len(b.double_sided) > 3 else "")
        warnings.append(f"{path}: doubleSided is not honoured ({shown}): every face is one-sided in hirad, its "
                        "front (the side its corners turn counter-clockwise around, orientation honoured) "
                        "reflecting and emitting and its back absorbing, as for USD's default doubleSided = 0")
    if not any(m for m in b.meshes if not m.is_light) and b.meshes:
        warnings.append(f"{path}: the stage contains only lights, no surfaces")
    _settle_instance_authors(b.meshes)
    scene = b.build(cameras, mpu, up_axis, str(path))
    lit = any(np.any(lum.flux > 0) for lum in scene.luminaires) or any(
        np.any((d.illuminance if isinstance(d, DistantLightInfo) else d.radiance) > 0) for d in scene.daylight)
    if require_emission and not np.any(scene.face_emission > 0) and not lit:
        found = "; ".join(b.unread_lights) if b.unread_lights else "no light of any kind"
        kinds = "RectLight, DiskLight, SphereLight, CylinderLight" + (", DistantLight, DomeLight" if daylight else "")
        raise SceneError(f"{path}: nothing emits light: no emissive material, MeshLightAPI or supported UsdLux "
                         f"light ({kinds}) with a positive intensity "
                         f"(found: {found})")
    return scene


def _settle_instance_authors(meshes: list[MeshInfo]) -> None:
    """A referenced prototype mesh can hold the UV set of one prototype only: when it is also
    drawn itself (an ordinary mesh at that path) or several prototypes reference it (different
    variant selections, say), its instances fall back to being de-instanced."""
    own = {m.author_path for m in meshes if m.instance_root is None and m.prototype is None}
    keys: dict[str, set] = {}
    for m in meshes:
        if m.instance_root is not None and not m.deinstance:
            keys.setdefault(m.author_path, set()).add(m.prototype)
    for m in meshes:
        if m.instance_root is None or m.deinstance:
            continue
        if m.author_path in own or len(keys[m.author_path]) > 1:
            m.author_path, m.deinstance = m.path, (m.instance_root,)


def _add_point_instancer(b: _Builder, prim: Usd.Prim, xfc: UsdGeom.XformCache, mpu: float, time):
    """Every mesh copy of a PointInstancer into the builder (point_instancer_copies)."""
    path = str(prim.GetPath())
    for copy_path, p, world in point_instancer_copies(prim, xfc, time, b.warnings, b.unread_lights):
        author, deinstance = (_native_instance_author(p, b.instance_targets) if p.IsInstanceProxy()
                              else (str(p.GetPath()), ()))
        b.add_mesh(p, world, mpu, copy_path, path, prototype=str(p.GetPath()), author_path=author,
                   deinstance=deinstance)


def point_instancer_copies(prim: Usd.Prim, xfc: UsdGeom.XformCache, time, warnings: list,
                           unread_lights: list | None = None) -> list:
    """The mesh copies a PointInstancer places: (copy path "<instancer>/instance_<k>/<path of the
    mesh relative to its prototype's parent>", prototype mesh prim, its world matrix (row
    vectors, stage units)), in instance order; masked and out-of-range instances skipped,
    invisible and guide/proxy parts of a prototype pruned. What is not honoured (nested
    instancers, lights in prototypes, missing prototypes or transforms) goes to `warnings`."""
    unread_lights = [] if unread_lights is None else unread_lights
    copies: list = []
    pi = UsdGeom.PointInstancer(prim)
    path = str(prim.GetPath())
    targets = pi.GetPrototypesRel().GetTargets()
    proto_idx = pi.GetProtoIndicesAttr().Get(time)
    if proto_idx is None or len(proto_idx) == 0 or not targets:
        return copies
    stage = prim.GetStage()
    pi_time = time if not time.IsEarliestTime() else Usd.TimeCode.Default()
    xforms = pi.ComputeInstanceTransformsAtTime(
        pi_time, pi_time, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask
    )
    if xforms is None or len(xforms) != len(proto_idx):
        # positions may only be authored as time samples: fall back to the first sample
        times = pi.GetPositionsAttr().GetTimeSamples()
        t0 = Usd.TimeCode(times[0]) if times else Usd.TimeCode.Default()
        xforms = pi.ComputeInstanceTransformsAtTime(
            t0, t0, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask
        )
    if xforms is None or len(xforms) != len(proto_idx):
        warnings.append(f"{path}: PointInstancer instance transforms could not be computed; ignored")
        return copies
    mask = pi.ComputeMaskAtTime(time)
    inst_world = _mat(xfc.GetLocalToWorldTransform(prim))

    # flatten each used prototype once: (mesh prim, transform relative to the prototype's parent)
    proto_meshes: dict[int, list[tuple[Usd.Prim, np.ndarray, str]]] = {}
    for j, tgt in enumerate(targets):
        proto = stage.GetPrimAtPath(tgt)
        if not proto or not proto.IsValid():
            warnings.append(f"{path}: prototype {tgt} not found")
            proto_meshes[j] = []
            continue
        proto_inv = np.linalg.inv(_mat(xfc.GetLocalToWorldTransform(proto)))
        proto_parent = proto.GetPath().GetParentPath()
        lst = []
        rng = iter(Usd.PrimRange(proto, Usd.TraverseInstanceProxies()))
        for p in rng:
            if p.IsA(UsdGeom.Imageable):
                img = UsdGeom.Imageable(p)
                # visibility/purpose of the prototype subtree itself (not of its ancestors)
                vis = img.GetVisibilityAttr().Get(time)
                if vis == UsdGeom.Tokens.invisible or img.GetPurposeAttr().Get(time) in (
                    UsdGeom.Tokens.guide,
                    UsdGeom.Tokens.proxy,
                ):
                    rng.PruneChildren()
                    continue
            if p.IsA(UsdGeom.PointInstancer):
                warnings.append(f"{p.GetPath()}: nested PointInstancer not supported; ignored")
                rng.PruneChildren()
                continue
            if p.IsA(UsdGeom.Mesh):
                rel = _mat(xfc.GetLocalToWorldTransform(p)) @ proto_inv
                lst.append((p, rel, str(p.GetPath().MakeRelativePath(proto_parent))))
            elif _is_light_prim(p):
                warnings.append(f"{p.GetPath()}: {p.GetTypeName() or 'light'} in a PointInstancer prototype is not "
                                  "read (only meshes are instanced); ignored, it emits nothing in the bake")
                unread_lights.append(f"{p.GetPath()} ({p.GetTypeName() or 'light'} in a PointInstancer prototype)")
        proto_meshes[j] = lst

    for k, j in enumerate(proto_idx):
        if mask and not mask[k]:
            continue
        if j < 0 or j >= len(targets):
            continue
        inst = _mat(xforms[k]) @ inst_world
        for p, rel, relpath in proto_meshes.get(int(j), []):
            copies.append((f"{path}/instance_{k}/{relpath}", p, rel @ inst))
    return copies
