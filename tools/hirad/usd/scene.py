"""Reading a USD stage into the flat arrays the engine consumes: world-space polygons in metres, per-face reflectance and emitted exitance (W/m^2, M = pi L), per-corner UVs, emitters (mesh lights and UsdLux area lights) and cameras."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from pxr import Usd, UsdGeom, UsdLux, UsdShade
from .common import _LOOKS_NAME, SceneError, _Names, _mat, _open_stage, _stage_time, _transform_points, _vec3
from .materials import _MAX_REFLECTANCE, _MaterialResolver, _display_color_per_face


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
        self.default_reflectance = np.clip(_vec3(default_reflectance), 0.0, _MAX_REFLECTANCE)
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

    # --- geometry ------------------------------------------------------------------------------
    def _append(self, info, pts, counts, idx, source, refl, emis, uv):
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
            arr = np.array(vals, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] < 2:
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
        pts = mesh.GetPointsAttr().Get(t)
        counts = mesh.GetFaceVertexCountsAttr().Get(t)
        indices = mesh.GetFaceVertexIndicesAttr().Get(t)
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
        refl, emis = self._face_materials(prim, path, n_faces, counts, valid_idx, total)
        refl, emis = refl[kept_faces], emis[kept_faces]

        is_light = False
        if prim.HasAPI(UsdLux.MeshLightAPI):
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

    def _face_materials(self, prim, path, n_faces, counts, indices, total):
        refl = np.repeat(self.default_reflectance[None, :], n_faces, axis=0)
        emis = np.zeros((n_faces, 3))
        display = None
        if total <= len(indices):
            display = _display_color_per_face(prim, self.time, counts, indices[:total])
        if display is not None:
            refl = display.copy()
        binding = UsdShade.MaterialBindingAPI(prim)
        mat = binding.ComputeBoundMaterial()[0]
        diffuse, emissive = self.materials.material_colors(mat)
        if diffuse is not None:
            refl[:] = diffuse
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
            faces = subset.GetIndicesAttr().Get(self.time)
            if faces is None:
                continue
            faces = np.array(faces, dtype=np.int64)
            faces = faces[(faces >= 0) & (faces < n_faces)]
            s_diffuse, s_emissive = self.materials.material_colors(sub_mat)
            if s_diffuse is not None:
                refl[faces] = s_diffuse
            elif display is not None:
                refl[faces] = display[faces]
            else:
                refl[faces] = self.default_reflectance
            emis[faces] = math.pi * s_emissive if s_emissive is not None else 0.0
        return refl, emis

    # --- lights ------------------------------------------------------------------------------
    def _light_radiance(self, prim: Usd.Prim, path: str) -> np.ndarray | None:
        light = UsdLux.LightAPI(prim)
        t = self.time
        intensity = light.GetIntensityAttr().Get(t)
        exposure = light.GetExposureAttr().Get(t)
        color = light.GetColorAttr().Get(t)
        intensity = 1.0 if intensity is None else float(intensity)
        exposure = 0.0 if exposure is None else float(exposure)
        color = _vec3(color, (1.0, 1.0, 1.0))
        radiance = intensity * (2.0**exposure) * color
        if light.GetEnableColorTemperatureAttr().Get(t):
            temp = light.GetColorTemperatureAttr().Get(t)
            temp = 6500.0 if temp is None else float(temp)
            radiance = radiance * _vec3(UsdLux.BlackbodyTemperatureAsRgb(temp))
        return radiance

    def add_light(self, prim: Usd.Prim, world: np.ndarray, mpu: float, segments: int):
        path = str(prim.GetPath())
        t = self.time
        if prim.IsA(UsdLux.RectLight):
            lt = UsdLux.RectLight(prim)
            w = float(lt.GetWidthAttr().Get(t) or 0.0)
            h = float(lt.GetHeightAttr().Get(t) or 0.0)
            # counter-clockwise seen from -Z, so the right-hand normal is local -Z
            local = np.array([[-w / 2, -h / 2, 0], [-w / 2, h / 2, 0], [w / 2, h / 2, 0], [w / 2, -h / 2, 0]])
            counts = np.array([4])
            idx = np.arange(4)
            if w <= 0 or h <= 0:
                self.warnings.append(f"{path}: RectLight with zero size ignored")
                return
        elif prim.IsA(UsdLux.DiskLight):
            lt = UsdLux.DiskLight(prim)
            r = float(lt.GetRadiusAttr().Get(t) or 0.0)
            if r <= 0:
                self.warnings.append(f"{path}: DiskLight with zero radius ignored")
                return
            n = max(3, int(segments))
            ang = -2.0 * math.pi * np.arange(n) / n  # clockwise from +Z => normal -Z
            local = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros(n)], axis=1)
            counts = np.array([n])
            idx = np.arange(n)
        elif prim.IsA(UsdLux.SphereLight):
            lt = UsdLux.SphereLight(prim)
            r = float(lt.GetRadiusAttr().Get(t) or 0.0)
            if r <= 0:
                self.warnings.append(f"{path}: SphereLight with zero radius (point light) ignored")
                return
            local, counts, idx = _uv_sphere(r, max(3, int(segments)), max(2, int(segments) // 2))
        else:
            self.warnings.append(f"{path}: {prim.GetTypeName()} is not supported; ignored")
            return
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


def read_scene(
    path: str | Path,
    default_reflectance=(0.5, 0.5, 0.5),
    uv_primvars: Sequence[str] = ("st", "uv", "UVMap", "st0", "map1"),
    light_segments: int = 32,
) -> SceneArrays:
    """Flatten a USD stage into :class:`SceneArrays` (see module docstring for conventions)."""
    stage = _open_stage(path)
    time = _stage_time(stage)
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    up_axis = str(UsdGeom.GetStageUpAxis(stage))
    xfc = UsdGeom.XformCache(time)
    warnings: list[str] = []
    b = _Builder(default_reflectance, uv_primvars, time, warnings)
    cameras: list[CameraInfo] = []

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

    if not b.meshes:
        raise SceneError(f"{path}: no meshes found")
    if not any(m for m in b.meshes if not m.is_light) and b.meshes:
        warnings.append(f"{path}: the stage contains only lights, no surfaces")
    return b.build(cameras, mpu, up_axis, str(path))


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
        proto_meshes[j] = lst

    for k, j in enumerate(proto_idx):
        if mask and not mask[k]:
            continue
        if j < 0 or j >= len(targets):
            continue
        inst = _mat(xforms[k]) @ inst_world
        for p, rel, relpath in proto_meshes.get(int(j), []):
            b.add_mesh(p, rel @ inst, mpu, f"{path}/instance_{k}/{relpath}", path)
