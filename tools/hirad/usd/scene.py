"""Reading a USD stage into the flat arrays the engine consumes: world-space polygons in metres, per-face reflectance and emitted exitance (W/m^2, M = pi L), per-corner UVs, emitters (mesh lights and UsdLux area lights) and cameras."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from pxr import Usd, UsdGeom, UsdLux, UsdShade, Vt
from .common import (_LOOKS_NAME, SceneError, _Names, _PrimError, _mat, _open_stage, _stage_time, _transform_points,
                     _value_type, _vec3)
from .materials import (_MAX_REFLECTANCE, MAX_RADIANCE, _MaterialResolver, _checked_emission, _checked_reflectance, _colour,
                        _display_color_per_face)


# Coordinates (in metres, after metersPerUnit and the transforms) beyond this are refused: no
# scene a radiosity bake can mesh is that large, and meshing such a face would never end.
MAX_COORDINATE_M = 1e15

_POINT_ARRAYS = (Vt.Vec3fArray, Vt.Vec3dArray, Vt.Vec3hArray)
_INDEX_ARRAYS = (Vt.IntArray, Vt.UIntArray, Vt.Int64Array, Vt.UInt64Array)

# Light attributes whose meaning hirad reproduces; any other authored light attribute that
# changes the light (a value other than the schema's fallback) is named in a warning.
_HONOURED_LIGHT_ATTRS = {"inputs:intensity", "inputs:exposure", "inputs:color", "inputs:normalize",
                         "inputs:enableColorTemperature", "inputs:colorTemperature"}
_SHAPE_ATTRS = {"RectLight": {"inputs:width", "inputs:height"}, "DiskLight": {"inputs:radius"},
                "SphereLight": {"inputs:radius"}}
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


@dataclass
class CameraInfo:
    path: str
    position: np.ndarray  # (3,) metres, world
    forward: np.ndarray  # (3,) unit
    up: np.ndarray  # (3,) unit, orthogonal to forward
    vertical_fov_degrees: float
    aspect: float  # width / height


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
    def __init__(self, default_reflectance, uv_primvars, time, warnings):
        self.default_reflectance = _checked_reflectance(_vec3(default_reflectance), "materials.default_reflectance",
                                                        warnings)
        self.uv_primvars = tuple(uv_primvars)
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
        self.uvs: list[np.ndarray | None] = []
        self.n_points = 0
        self.unread_lights: list[str] = []  # lights that emit nothing in the bake, with why

    # --- geometry ------------------------------------------------------------------------------
    def _append(self, info, pts, counts, idx, source, refl, emis, uv):
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
        self.reflectance.append(np.clip(refl, 0.0, _MAX_REFLECTANCE))
        self.emission.append(emis)
        self.uvs.append(uv)
        self.n_points += len(pts)
        return k

    def corner_uv(self, prim: Usd.Prim, counts, indices, n_points) -> np.ndarray | None:
        api = UsdGeom.PrimvarsAPI(prim)
        for name in self.uv_primvars:
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
            if interp == UsdGeom.Tokens.faceVarying and len(arr) >= len(indices):
                return arr[: len(indices)]
            if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and len(arr) >= n_points:
                safe = np.clip(indices, 0, len(arr) - 1)
                return arr[safe]
            if interp == UsdGeom.Tokens.uniform and len(arr) >= len(counts):
                return np.repeat(arr[: len(counts)], counts, axis=0)
            if interp == UsdGeom.Tokens.constant:
                return np.repeat(arr[:1], len(indices), axis=0)
            self.warnings.append(
                f"{prim.GetPath()}: primvar {name} has {len(arr)} values, too few for "
                f"{interp} interpolation; ignored"
            )
        return None

    def add_mesh(self, prim: Usd.Prim, world: np.ndarray, mpu: float, path: str, hide_path: str):
        mesh = UsdGeom.Mesh(prim)
        t = self.time
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
        refl, emis = self._face_materials(prim, path, n_faces, counts, valid_idx, total, n_pts)
        refl, emis = refl[kept_faces], emis[kept_faces]

        is_light = False
        if prim.HasAPI(UsdLux.MeshLightAPI):
            self._warn_unhonoured(prim, path, "MeshLightAPI", set())
            radiance = self._light_radiance(prim, path)
            if radiance is not None:
                if UsdLux.LightAPI(prim).GetNormalizeAttr().Get(t):
                    area = _finite_area(world_pts, kept_counts, new_indices)
                    radiance = radiance / area if area > 0 else radiance * 0.0
                emis = np.repeat((math.pi * radiance)[None, :], len(kept_faces), axis=0)
                is_light = True

        uv_all = self.corner_uv(prim, counts, indices, n_pts) if len(indices) >= total else None
        uv = uv_all[corner_src] if uv_all is not None else None

        name = self.names.make(path)
        info = MeshInfo(path=path, name=name, hide_path=hide_path, is_light=is_light, has_uv=uv is not None)
        self._append(info, world_pts, kept_counts, new_indices, kept_faces, refl, emis, uv)

    def _face_materials(self, prim, path, n_faces, counts, indices, total, n_points):
        """Per-face reflectance and exitance: the bound material's (per GeomSubset), else the
        displayColor, else the default; displayColor is read (and checked) only where it is used."""
        refl = np.repeat(self.default_reflectance[None, :], n_faces, axis=0)
        emis = np.zeros((n_faces, 3))
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
        return refl, emis

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
        if prim.IsA(UsdLux.RectLight):
            lt = UsdLux.RectLight(prim)
            w = _number(lt.GetWidthAttr(), t, path, 0.0)
            h = _number(lt.GetHeightAttr(), t, path, 0.0)
            # counter-clockwise seen from -Z, so the right-hand normal is local -Z
            local = np.array([[-w / 2, -h / 2, 0], [-w / 2, h / 2, 0], [w / 2, h / 2, 0], [w / 2, -h / 2, 0]])
            counts = np.array([4])
            idx = np.arange(4)
            _finite_size(path, "inputs:width", w)
            _finite_size(path, "inputs:height", h)
            if not (w > 0 and h > 0):
                self.warnings.append(f"{path}: RectLight of size {w:g} x {h:g} has no area; ignored")
                self.unread_lights.append(f"{path} (RectLight of zero size)")
                return
        elif prim.IsA(UsdLux.DiskLight):
            lt = UsdLux.DiskLight(prim)
            r = _finite_size(path, "inputs:radius", _number(lt.GetRadiusAttr(), t, path, 0.0))
            if not r > 0:
                self.warnings.append(f"{path}: DiskLight of radius {r:g} has no area; ignored")
                self.unread_lights.append(f"{path} (DiskLight of zero radius)")
                return
            n = max(3, int(segments))
            ang = -2.0 * math.pi * np.arange(n) / n  # clockwise from +Z => normal -Z
            local = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros(n)], axis=1)
            counts = np.array([n])
            idx = np.arange(n)
        elif prim.IsA(UsdLux.SphereLight):
            lt = UsdLux.SphereLight(prim)
            r = _finite_size(path, "inputs:radius", _number(lt.GetRadiusAttr(), t, path, 0.0))
            if not r > 0:
                self.warnings.append(f"{path}: SphereLight of radius {r:g} (a point light) has no area; ignored")
                self.unread_lights.append(f"{path} (SphereLight of zero radius: a point light)")
                return
            if lt.GetTreatAsPointAttr().Get(t):
                self.warnings.append(f"{path}: SphereLight treatAsPoint is not honoured: read as a sphere of "
                                     f"radius {r:g}")
            local, counts, idx = _uv_sphere(r, max(3, int(segments)), max(2, int(segments) // 2))
        else:
            self.warnings.append(f"{path}: {kind} is a light type hirad does not read (only RectLight, DiskLight, "
                                 "SphereLight and MeshLightAPI emit); ignored, it emits nothing in the bake")
            self.unread_lights.append(f"{path} ({kind})")
            return
        self._warn_unhonoured(prim, path, kind, _SHAPE_ATTRS.get(kind, set()) | {"treatAsPoint"})
        radiance = self._light_radiance(prim, path)
        world_pts = _transform_points(local, world) * mpu
        if np.linalg.det(world[:3, :3]) < 0:
            idx = _flip_faces(counts, idx)
        if UsdLux.LightAPI(prim).GetNormalizeAttr().Get(t):
            area = _finite_area(world_pts, counts, idx)
            radiance = radiance / area if area > 0 else radiance * 0.0
        nf = len(counts)
        emis = np.repeat((math.pi * radiance)[None, :], nf, axis=0)
        refl = np.zeros((nf, 3))
        name = self.names.make(path)
        info = MeshInfo(path=path, name=name, hide_path=path, is_light=True, has_uv=False)
        self._append(info, world_pts, counts, idx, np.arange(nf), refl, emis, None)

    # --- result --------------------------------------------------------------------------------
    def build(self, cameras, mpu, up_axis, source) -> SceneArrays:
        has_uv = any(u is not None for u in self.uvs)
        corner_uv = None
        if has_uv:
            corner_uv = np.concatenate(
                [u if u is not None else np.zeros((len(i), 2)) for u, i in zip(self.uvs, self.indices)]
            ).astype(np.float64)
        face_mesh = np.concatenate([np.full(len(c), k, dtype=np.int32) for k, c in enumerate(self.counts)])
        return SceneArrays(
            points=np.concatenate(self.points).astype(np.float64),
            face_vertex_counts=np.concatenate(self.counts).astype(np.int32),
            face_vertex_indices=np.concatenate(self.indices).astype(np.int32),
            face_mesh=face_mesh,
            face_source=np.concatenate(self.face_source).astype(np.int32),
            face_reflectance=np.concatenate(self.reflectance).astype(np.float64),
            face_emission=np.concatenate(self.emission).astype(np.float64),
            corner_uv=corner_uv,
            meshes=self.meshes,
            cameras=cameras,
            meters_per_unit=mpu,
            up_axis=up_axis,
            warnings=self.warnings,
            source_path=source,
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


def _uv_sphere(r: float, n_lon: int, n_lat: int):
    """Latitude-longitude sphere: triangles at the poles, quads elsewhere, normals outward."""
    pts = [[0.0, 0.0, r]]
    for i in range(1, n_lat):
        th = math.pi * i / n_lat
        for j in range(n_lon):
            ph = 2.0 * math.pi * j / n_lon
            pts.append([r * math.sin(th) * math.cos(ph), r * math.sin(th) * math.sin(ph), r * math.cos(th)])
    pts.append([0.0, 0.0, -r])
    pts = np.array(pts)
    bottom = len(pts) - 1

    def ring(i, j):  # i in 1..n_lat-1
        return 1 + (i - 1) * n_lon + (j % n_lon)

    counts, idx = [], []
    for j in range(n_lon):
        counts.append(3)
        idx += [0, ring(1, j), ring(1, j + 1)]
    for i in range(1, n_lat - 1):
        for j in range(n_lon):
            counts.append(4)
            idx += [ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)]
    for j in range(n_lon):
        counts.append(3)
        idx += [bottom, ring(n_lat - 1, j + 1), ring(n_lat - 1, j)]
    return pts, np.array(counts), np.array(idx)


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
      (DomeLight, DistantLight, CylinderLight, PortalLight, ...) and authored light attributes
      it does not honour (shaping, shadows, light linking, ``inputs:diffuse`` or
      ``inputs:specular`` other than 1, SphereLight ``treatAsPoint``).

    With `require_emission` (a bake), a scene in which nothing emits light is an error; reading
    a dark scene is fine otherwise (``hirad info``, tests).
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
        b = _Builder(default_reflectance, uv_primvars, time, warnings)
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
                hide = _nearest_instance_root(prim) if prim.IsInstanceProxy() else prim
                b.add_mesh(prim, world, mpu, str(prim.GetPath()), str(hide.GetPath()))
            elif _is_light_prim(prim):
                b.add_light(prim, _mat(xfc.GetLocalToWorldTransform(prim)), mpu, light_segments)
            elif prim.IsA(UsdLux.LightFilter):
                warnings.append(f"{prim.GetPath()}: {prim.GetTypeName()} (a light filter) is not honoured; ignored")
    except _PrimError as exc:
        raise SceneError(f"{path}: {exc}") from None

    if not b.meshes:
        raise SceneError(f"{path}: no meshes found")
    if not any(m for m in b.meshes if not m.is_light) and b.meshes:
        warnings.append(f"{path}: the stage contains only lights, no surfaces")
    scene = b.build(cameras, mpu, up_axis, str(path))
    if require_emission and not np.any(scene.face_emission > 0):
        found = "; ".join(b.unread_lights) if b.unread_lights else "no light of any kind"
        raise SceneError(f"{path}: nothing emits light: no emissive material, MeshLightAPI or supported UsdLux "
                         f"light (RectLight, DiskLight, SphereLight) with a positive intensity (found: {found})")
    return scene


def _add_point_instancer(b: _Builder, prim: Usd.Prim, xfc: UsdGeom.XformCache, mpu: float, time):
    pi = UsdGeom.PointInstancer(prim)
    path = str(prim.GetPath())
    targets = pi.GetPrototypesRel().GetTargets()
    proto_idx = pi.GetProtoIndicesAttr().Get(time)
    if proto_idx is None or len(proto_idx) == 0 or not targets:
        return
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
        b.warnings.append(f"{path}: PointInstancer instance transforms could not be computed; ignored")
        return
    mask = pi.ComputeMaskAtTime(time)
    inst_world = _mat(xfc.GetLocalToWorldTransform(prim))

    # flatten each used prototype once: (mesh prim, transform relative to the prototype's parent)
    proto_meshes: dict[int, list[tuple[Usd.Prim, np.ndarray, str]]] = {}
    for j, tgt in enumerate(targets):
        proto = stage.GetPrimAtPath(tgt)
        if not proto or not proto.IsValid():
            b.warnings.append(f"{path}: prototype {tgt} not found")
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
                b.warnings.append(f"{p.GetPath()}: nested PointInstancer not supported; ignored")
                rng.PruneChildren()
                continue
            if p.IsA(UsdGeom.Mesh):
                rel = _mat(xfc.GetLocalToWorldTransform(p)) @ proto_inv
                lst.append((p, rel, str(p.GetPath().MakeRelativePath(proto_parent))))
            elif _is_light_prim(p):
                b.warnings.append(f"{p.GetPath()}: {p.GetTypeName() or 'light'} in a PointInstancer prototype is not "
                                  "read (only meshes are instanced); ignored, it emits nothing in the bake")
                b.unread_lights.append(f"{p.GetPath()} ({p.GetTypeName() or 'light'} in a PointInstancer prototype)")
        proto_meshes[j] = lst

    for k, j in enumerate(proto_idx):
        if mask and not mask[k]:
            continue
        if j < 0 or j >= len(targets):
            continue
        inst = _mat(xforms[k]) @ inst_world
        for p, rel, relpath in proto_meshes.get(int(j), []):
            b.add_mesh(p, rel @ inst, mpu, f"{path}/instance_{k}/{relpath}", path)
