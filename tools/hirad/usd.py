"""USD input and output for hirad.

Reading (:func:`read_scene`) flattens a USD stage into the flat numpy arrays the C++ engine
consumes: world-space polygons in metres, per-face reflectance and emitted exitance, per-corner
UVs, plus the cameras of the stage.  Writing (:func:`write_solution_layer`) produces a small layer
that sublayers the input, hides the input geometry and adds one mesh per solved scene mesh under
``/HiradSolution`` carrying the radiosity as primvars.  :func:`read_solution_layer` loads such a
layer back without re-solving.

Conventions
-----------
* Lengths returned by this module are metres; the stage's ``metersPerUnit`` is applied on read
  and undone on write.
* Faces are polygons as authored (no triangulation) with counter-clockwise = front under the
  right-hand rule; left-handed meshes and mirrored transforms are flipped on read.
* ``face_emission`` is emitted exitance M = pi * L in W/m^2; radiance values written to the
  solution layer are W/(m^2 sr), irradiance W/m^2.
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade, Vt

__all__ = [
    "SceneError",
    "MeshInfo",
    "CameraInfo",
    "SceneArrays",
    "PatchMeshData",
    "SolutionData",
    "read_scene",
    "read_cameras",
    "write_solution_layer",
    "read_solution_layer",
    "SOLUTION_ROOT",
]

SOLUTION_ROOT = "/HiradSolution"
_LOOKS_NAME = "HiradLooks"  # material scope under SOLUTION_ROOT; reserved as a mesh name
_MAX_REFLECTANCE = 0.999


class SceneError(Exception):
    """The input (or a solution layer) cannot be used; the message names the file."""


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


@dataclass
class PatchMeshData:
    """Solved geometry of one scene mesh (what the solution layer stores per mesh)."""

    mesh_index: int
    points: np.ndarray  # (P,3) metres, world
    face_vertex_counts: np.ndarray  # (F,)
    face_vertex_indices: np.ndarray  # (sum counts,)
    vertex_radiance: np.ndarray  # (P,3) exitant radiance W/(m^2 sr)
    vertex_irradiance: np.ndarray  # (P,3) W/m^2
    face_radiance: np.ndarray  # (F,3)
    face_irradiance: np.ndarray  # (F,3)
    lightmap_uv: np.ndarray | None = None  # (sum counts,2) faceVarying
    lightmap_path: str | None = None  # asset path relative to the solution layer
    # filled in by read_solution_layer
    name: str | None = None
    source_path: str | None = None
    # the lightmap shown as albedo x lightmap + emitted radiance (UsdUVTexture scale / bias):
    # the mesh's (area-weighted) reflectance and emitted radiance E/pi, RGB
    lightmap_albedo: tuple[float, float, float] | None = None
    lightmap_emission: tuple[float, float, float] | None = None


@dataclass
class SolutionData:
    meshes: list[PatchMeshData]
    cameras: list[CameraInfo]
    meters_per_unit: float
    up_axis: str
    metadata: dict
    path: str


# ----------------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------------


def _open_stage(path: str | Path) -> Usd.Stage:
    p = Path(path)
    if not p.is_file():
        raise SceneError(f"{p}: file not found")
    try:
        stage = Usd.Stage.Open(str(p))
    except Tf.ErrorException as exc:  # pragma: no cover - message depends on USD version
        msg = str(exc).strip().splitlines()
        raise SceneError(f"{p}: cannot open USD stage ({msg[-1] if msg else 'unknown error'})") from None
    if stage is None:
        raise SceneError(f"{p}: cannot open USD stage")
    return stage


def _stage_time(stage: Usd.Stage) -> Usd.TimeCode:
    if stage.HasAuthoredTimeCodeRange():
        return Usd.TimeCode(stage.GetStartTimeCode())
    return Usd.TimeCode.EarliestTime()


def _mat(m: Gf.Matrix4d) -> np.ndarray:
    """Gf matrix (row-vector convention: p' = p @ M) to numpy (4,4) float64."""
    return np.array(m, dtype=np.float64).reshape(4, 4)


def _transform_points(pts: np.ndarray, m: np.ndarray) -> np.ndarray:
    return pts @ m[:3, :3] + m[3, :3]


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


def _identifier(text: str) -> str:
    ident = Tf.MakeValidIdentifier(text.strip("/").replace("/", "_") or "mesh")
    return ident


class _Names:
    def __init__(self, reserved: Iterable[str] = ()):
        self.used = set(reserved)

    def make(self, path: str) -> str:
        base = _identifier(path)
        name, k = base, 1
        while name in self.used:
            name = f"{base}_{k}"
            k += 1
        self.used.add(name)
        return name


def _vec3(value, default=(0.0, 0.0, 0.0)) -> np.ndarray:
    if value is None:
        return np.array(default, dtype=np.float64)
    arr = np.array(value, dtype=np.float64).reshape(-1)
    if arr.size == 1:
        return np.repeat(arr, 3)
    return arr[:3]


# ----------------------------------------------------------------------------------------------
# materials
# ----------------------------------------------------------------------------------------------


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# UsdPreviewSurface itself and its MaterialX node definition share inputs and meaning.
_PREVIEW_SURFACE_IDS = ("UsdPreviewSurface", "ND_UsdPreviewSurface_surfaceshader")


class _MaterialResolver:
    """Evaluates bound UsdPreviewSurface materials into constant colours (with caching)."""

    def __init__(self, time: Usd.TimeCode, warnings: list[str]):
        self.time = time
        self.warnings = warnings
        self._tex_cache: dict[tuple, tuple[np.ndarray, np.ndarray] | None] = {}
        self._mat_cache: dict[str, tuple[np.ndarray | None, np.ndarray | None]] = {}

    # --- public ---------------------------------------------------------------------------
    def material_colors(self, material: UsdShade.Material | None):
        """(diffuse or None, emissive radiance or None) of a material's UsdPreviewSurface."""
        if material is None or not material.GetPrim().IsValid():
            return None, None
        key = str(material.GetPath())
        if key in self._mat_cache:
            return self._mat_cache[key]
        result: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
        shader = self._surface_shader(material)
        if shader is not None and shader.GetShaderId() in _PREVIEW_SURFACE_IDS:
            diffuse = self._eval_color_input(shader, "diffuseColor", key)
            emissive = self._eval_color_input(shader, "emissiveColor", key)
            result = (diffuse, emissive)
        else:
            kind = shader.GetShaderId() if shader is not None else "no universal or MaterialX surface"
            self.warnings.append(f"{key}: material '{kind}' is not UsdPreviewSurface; "
                                 "its meshes use displayColor or the default reflectance")
        self._mat_cache[key] = result
        return result

    # --- internals -------------------------------------------------------------------------
    @staticmethod
    def _surface_shader(material: UsdShade.Material) -> UsdShade.Shader | None:
        try:
            # The universal output first, then MaterialX's (a MaterialX UsdPreviewSurface node).
            src = material.ComputeSurfaceSource()
            if not (src[0] if isinstance(src, (tuple, list)) else src):
                src = material.ComputeSurfaceSource("mtlx")
        except Exception:  # pragma: no cover
            return None
        shader = src[0] if isinstance(src, (tuple, list)) else src
        if shader and shader.GetPrim().IsValid():
            return UsdShade.Shader(shader.GetPrim())
        return None

    def _eval_color_input(self, shader: UsdShade.Shader, name: str, where: str) -> np.ndarray | None:
        inp = shader.GetInput(name)
        if not inp:
            return None
        for attr in inp.GetValueProducingAttributes():
            if UsdShade.Output.IsOutput(attr):
                src = UsdShade.Shader(attr.GetPrim())
                out_name = attr.GetBaseName()
                if src and src.GetShaderId() == "UsdUVTexture":
                    return self._texture_color(src, out_name, where)
                self.warnings.append(
                    f"{where}: {name} is connected to unsupported shader "
                    f"{attr.GetPrim().GetPath()} ({src.GetShaderId() if src else '?'}); ignored"
                )
                return None
            value = attr.Get(self.time)
            if value is not None:
                return _vec3(value)
        return None

    def _input_value(self, shader: UsdShade.Shader, name: str):
        inp = shader.GetInput(name)
        if not inp:
            return None
        for attr in inp.GetValueProducingAttributes():
            if not UsdShade.Output.IsOutput(attr):
                v = attr.Get(self.time)
                if v is not None:
                    return v, attr
        return None

    @staticmethod
    def _resolve_asset(asset: Sdf.AssetPath, attr: Usd.Attribute) -> str:
        if asset.resolvedPath:
            return asset.resolvedPath
        raw = asset.path
        if not raw:
            return ""
        if os.path.isabs(raw):
            return raw
        for spec in attr.GetPropertyStack(Usd.TimeCode.Default()):
            layer = spec.layer
            if layer and not layer.anonymous:
                return layer.ComputeAbsolutePath(raw)
        return raw

    def _texture_color(self, tex: UsdShade.Shader, out_name: str, where: str) -> np.ndarray | None:
        fallback = self._input_value(tex, "fallback")
        fb = np.array(fallback[0], dtype=np.float64).reshape(-1) if fallback else None
        file_v = self._input_value(tex, "file")
        path = ""
        if file_v is not None:
            path = self._resolve_asset(file_v[0], file_v[1])
        cs_v = self._input_value(tex, "sourceColorSpace")
        colorspace = str(cs_v[0]) if cs_v else "auto"
        mean_rgba = self._texture_mean(path, colorspace) if path else None
        if mean_rgba is None:
            self.warnings.append(
                f"{where}: texture {file_v[0].path if file_v else '(no file)'} of "
                f"{tex.GetPath()} could not be read; using "
                + ("its fallback" if fb is not None else "the default colour")
            )
            if fb is None:
                return None
            rgba = np.concatenate([fb, np.zeros(max(0, 4 - fb.size))])[:4]
        else:
            rgba = mean_rgba.copy()
            scale_v = self._input_value(tex, "scale")
            bias_v = self._input_value(tex, "bias")
            if scale_v is not None:
                rgba = rgba * np.array(scale_v[0], dtype=np.float64).reshape(-1)[:4]
            if bias_v is not None:
                rgba = rgba + np.array(bias_v[0], dtype=np.float64).reshape(-1)[:4]
        if out_name in ("r", "g", "b", "a"):
            return np.repeat(rgba["rgba".index(out_name)], 3)
        return rgba[:3]

    def _texture_mean(self, path: str, colorspace: str) -> np.ndarray | None:
        key = (path, colorspace)
        if key in self._tex_cache:
            return self._tex_cache[key]
        result = None
        try:
            from PIL import Image

            with Image.open(path) as img:
                img.load()
                eight_bit = img.mode in ("1", "L", "LA", "P", "RGB", "RGBA", "CMYK", "YCbCr", "PA")
                if img.mode in ("P", "PA", "CMYK", "YCbCr", "1"):
                    img = img.convert("RGBA")
                arr = np.asarray(img)
            linearise = colorspace == "sRGB" or (colorspace == "auto" and eight_bit)
            if arr.dtype == np.uint8:
                data = arr.astype(np.float64) / 255.0
            elif arr.dtype == np.uint16 or img.mode.startswith("I;16"):
                data = arr.astype(np.float64) / 65535.0
            elif np.issubdtype(arr.dtype, np.integer):
                data = arr.astype(np.float64) / 65535.0  # Pillow "I" images from 16-bit files
            else:
                data = arr.astype(np.float64)
            if data.ndim == 2:
                data = data[:, :, None]
            ch = data.shape[2]
            if ch == 1:
                rgb, alpha = np.repeat(data, 3, axis=2), None
            elif ch == 2:
                rgb, alpha = np.repeat(data[:, :, :1], 3, axis=2), data[:, :, 1]
            else:
                rgb, alpha = data[:, :, :3], (data[:, :, 3] if ch >= 4 else None)
            if linearise:
                rgb = _srgb_to_linear(rgb)
            mean_rgb = rgb.reshape(-1, 3).mean(axis=0)
            mean_a = float(alpha.mean()) if alpha is not None else 1.0
            result = np.array([*mean_rgb, mean_a], dtype=np.float64)
        except Exception:
            result = None
        self._tex_cache[key] = result
        return result


def _display_color_per_face(prim: Usd.Prim, time, counts: np.ndarray, indices: np.ndarray) -> np.ndarray | None:
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    if not pv or not pv.HasAuthoredValue():
        return None
    vals = pv.ComputeFlattened(time)
    if vals is None or len(vals) == 0:
        return None
    vals = np.array(vals, dtype=np.float64).reshape(-1, 3)
    interp = pv.GetInterpolation()
    nf = len(counts)
    if interp == UsdGeom.Tokens.constant or len(vals) == 1:
        return np.repeat(vals[:1], nf, axis=0)
    if interp == UsdGeom.Tokens.uniform:
        if len(vals) < nf:
            return None
        return vals[:nf]
    if interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        if indices.size and indices.max() >= len(vals):
            return None
        corner = vals[indices]
    elif interp == UsdGeom.Tokens.faceVarying:
        if len(vals) < len(indices):
            return None
        corner = vals[: len(indices)]
    else:
        return None
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    sums = np.add.reduceat(corner, starts, axis=0) if len(counts) else np.zeros((0, 3))
    return sums / np.maximum(counts, 1)[:, None]


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

    def _corner_uv(self, prim: Usd.Prim, counts, indices, n_points) -> np.ndarray | None:
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

        uv_all = self._corner_uv(prim, counts, indices, n_pts) if len(indices) >= total else None
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


# ----------------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------------


def _to_vt_value(v: Any):
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            c = _to_vt_value(x)
            if c is not None:
                out[str(k)] = c
        return out
    if isinstance(v, np.ndarray):
        return _to_vt_value(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, (list, tuple)):
        items = [_to_vt_value(x) for x in v if x is not None]
        if items and all(isinstance(x, str) for x in items):
            return Vt.StringArray(items)
        if items and all(isinstance(x, bool) for x in items):
            return Vt.BoolArray(items)
        if items and all(isinstance(x, int) and not isinstance(x, bool) for x in items):
            return Vt.Int64Array(items)
        if items and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in items):
            return Vt.DoubleArray([float(x) for x in items])
        return Vt.StringArray([str(x) for x in items])
    if v is None:
        return None
    if isinstance(v, (bool, int, float, str)):
        return v
    return str(v)


def _check_patch(pm: PatchMeshData, n_meshes: int):
    P = len(pm.points)
    F = len(pm.face_vertex_counts)
    C = int(np.sum(pm.face_vertex_counts)) if F else 0

    def shape(a, n, what):
        a = np.asarray(a)
        if a.shape != (n, 3):
            raise ValueError(f"patch mesh {pm.mesh_index}: {what} has shape {a.shape}, expected ({n}, 3)")

    if not 0 <= pm.mesh_index < n_meshes:
        raise ValueError(f"patch mesh index {pm.mesh_index} out of range (scene has {n_meshes} meshes)")
    shape(pm.points, P, "points")
    if len(pm.face_vertex_indices) != C:
        raise ValueError(f"patch mesh {pm.mesh_index}: face_vertex_indices length != sum of counts")
    shape(pm.vertex_radiance, P, "vertex_radiance")
    shape(pm.vertex_irradiance, P, "vertex_irradiance")
    shape(pm.face_radiance, F, "face_radiance")
    shape(pm.face_irradiance, F, "face_irradiance")
    if pm.lightmap_uv is not None and np.asarray(pm.lightmap_uv).shape != (C, 2):
        raise ValueError(f"patch mesh {pm.mesh_index}: lightmap_uv must have shape ({C}, 2)")


def _relative_asset(target: Path, from_dir: Path) -> str:
    try:
        rel = os.path.relpath(target, from_dir)
    except ValueError:  # different drives on Windows
        return target.as_posix()
    rel = Path(rel).as_posix()
    if not rel.startswith("."):
        rel = "./" + rel
    return rel


def _author_patch_mesh(stage: Usd.Stage, mesh_path: Sdf.Path, pm: PatchMeshData, info: MeshInfo, mpu: float):
    mesh = UsdGeom.Mesh.Define(stage, mesh_path)
    pts = np.asarray(pm.points, dtype=np.float64) / mpu
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(pm.face_vertex_counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(pm.face_vertex_indices, dtype=np.int32)))
    mesh.CreateDoubleSidedAttr(False)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    finite = pts[np.isfinite(pts).all(axis=1)]
    if len(finite):
        mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*finite.min(axis=0)), Gf.Vec3f(*finite.max(axis=0))]))
    api = UsdGeom.PrimvarsAPI(mesh)

    def color_pv(name, data, interp):
        pv = api.CreatePrimvar(name, Sdf.ValueTypeNames.Color3fArray, interp)
        pv.Set(Vt.Vec3fArray.FromNumpy(np.asarray(data, dtype=np.float32).reshape(-1, 3)))

    color_pv("hirad:radiance", pm.vertex_radiance, UsdGeom.Tokens.vertex)
    color_pv("hirad:irradiance", pm.vertex_irradiance, UsdGeom.Tokens.vertex)
    color_pv("hirad:patchRadiance", pm.face_radiance, UsdGeom.Tokens.uniform)
    color_pv("hirad:patchIrradiance", pm.face_irradiance, UsdGeom.Tokens.uniform)
    color_pv("displayColor", np.clip(np.nan_to_num(np.asarray(pm.vertex_radiance)), 0.0, 1.0), UsdGeom.Tokens.vertex)

    prim = mesh.GetPrim()
    prim.SetCustomDataByKey("hirad:meshIndex", int(pm.mesh_index))
    prim.SetCustomDataByKey("hirad:sourcePath", info.path)
    prim.SetCustomDataByKey("hirad:isLight", bool(info.is_light))

    if pm.lightmap_uv is not None:
        pv = api.CreatePrimvar("hirad:lightmapUV", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec2fArray.FromNumpy(np.asarray(pm.lightmap_uv, dtype=np.float32).reshape(-1, 2)))
        if pm.lightmap_path:
            looks = Sdf.Path(SOLUTION_ROOT).AppendChild(_LOOKS_NAME)
            UsdGeom.Scope.Define(stage, looks)
            mat = UsdShade.Material.Define(stage, looks.AppendChild(mesh_path.name))
            surf = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("PreviewSurface"))
            surf.CreateIdAttr("UsdPreviewSurface")
            surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
            surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
            reader = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("LightmapUV"))
            reader.CreateIdAttr("UsdPrimvarReader_float2")
            reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("hirad:lightmapUV")
            reader_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
            tex = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("Lightmap"))
            tex.CreateIdAttr("UsdUVTexture")
            tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(pm.lightmap_path))
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
            tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
            tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
            tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader_out)
            if pm.lightmap_albedo is not None:
                # texels hold incident radiance H/pi: the surface shows albedo x H/pi (+ E/pi)
                r, g, b = (float(v) for v in pm.lightmap_albedo)
                tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(r, g, b, 1.0))
            if pm.lightmap_emission is not None:
                r, g, b = (float(v) for v in pm.lightmap_emission)
                tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(r, g, b, 0.0))
            rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
            surf.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
            mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
            UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)
    return mesh


def write_solution_layer(
    input_path: str | Path,
    output_path: str | Path,
    scene: SceneArrays,
    patch_meshes: Sequence[PatchMeshData],
    metadata: dict | None = None,
) -> Path:
    """Write the solution layer atomically to ``output_path``; the input file is never modified."""
    input_path = Path(input_path)
    output_path = Path(output_path)
    if output_path.resolve() == input_path.resolve():
        raise SceneError(f"{output_path}: refusing to overwrite the input scene")
    for pm in patch_meshes:
        _check_patch(pm, len(scene.meshes))
    out_dir = output_path.resolve().parent
    out_dir.mkdir(parents=True, exist_ok=True)
    mpu = float(scene.meters_per_unit)
    if not mpu > 0:
        raise ValueError("scene.meters_per_unit must be positive")

    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    sub = _relative_asset(input_path.resolve(), out_dir)
    # stage-level metadata only comes from the root layer: copy the input's
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if scene.up_axis.upper() == "Y" else UsdGeom.Tokens.z)
    try:
        in_layer = Sdf.Layer.FindOrOpen(str(input_path))
        if in_layer is not None and in_layer.defaultPrim:
            layer.defaultPrim = in_layer.defaultPrim
    except Tf.ErrorException:
        pass

    hidden: set[str] = set()
    for info in scene.meshes:
        if info.hide_path in hidden or not info.hide_path:
            continue
        hidden.add(info.hide_path)
        over = stage.OverridePrim(info.hide_path)
        over.CreateAttribute("visibility", Sdf.ValueTypeNames.Token, False, Sdf.VariabilityVarying).Set(
            UsdGeom.Tokens.invisible
        )

    UsdGeom.Scope.Define(stage, SOLUTION_ROOT)
    root = Sdf.Path(SOLUTION_ROOT)
    used: set[str] = {_LOOKS_NAME}
    for pm in patch_meshes:
        info = scene.meshes[pm.mesh_index]
        name, k = info.name, 1
        while name in used:
            name = f"{info.name}_{k}"
            k += 1
        used.add(name)
        _author_patch_mesh(stage, root.AppendChild(name), pm, info, mpu)

    md = {"hirad:metersPerUnit": mpu, "hirad:input": sub}
    md.update(metadata or {})
    layer.customLayerData = _to_vt_value(md)
    layer.comment = "hirad radiosity solution; sublayers the input scene"
    del stage  # release the authoring stage so adding the sublayer composes nothing
    # sublayer last so the authoring above never composes (or touches) the input
    layer.subLayerPaths.append(sub)

    suffix = output_path.suffix if output_path.suffix in (".usda", ".usdc", ".usd") else ".usda"
    fd, tmp = tempfile.mkstemp(prefix=f".{output_path.stem}.", suffix=".tmp" + suffix, dir=str(out_dir))
    os.close(fd)
    try:
        if not layer.Export(tmp):
            raise SceneError(f"{output_path}: could not write the solution layer")
        # mkstemp makes the file private (0600); give it the permissions any other new file gets.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, output_path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return output_path


# ----------------------------------------------------------------------------------------------
# reading a solution back
# ----------------------------------------------------------------------------------------------


def _get_array(prim: Usd.Prim, name: str, time, cols: int) -> np.ndarray | None:
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasAuthoredValue():
        return None
    v = pv.ComputeFlattened(time)
    if v is None:
        return None
    return np.array(v, dtype=np.float64).reshape(-1, cols)


def read_solution_layer(path: str | Path) -> SolutionData:
    """Load a layer written by :func:`write_solution_layer` (plus the input's cameras)."""
    stage = _open_stage(path)
    time = Usd.TimeCode.Default()
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    root = stage.GetPrimAtPath(SOLUTION_ROOT)
    meshes: list[PatchMeshData] = []
    if root and root.IsValid():
        for prim in root.GetChildren():
            if not prim.IsA(UsdGeom.Mesh):
                continue
            m = UsdGeom.Mesh(prim)
            pts = np.array(m.GetPointsAttr().Get(time) or [], dtype=np.float64).reshape(-1, 3) * mpu
            counts = np.array(m.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int32)
            idx = np.array(m.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int32)
            P, F = len(pts), len(counts)

            def arr(name, n, cols=3):
                a = _get_array(prim, name, time, cols)
                return a if a is not None else np.zeros((n, cols))

            lm_path = None
            binding = UsdShade.MaterialBindingAPI(prim).GetDirectBinding().GetMaterial()
            if binding and binding.GetPrim().IsValid():
                tex = binding.GetPrim().GetChild("Lightmap")
                if tex:
                    f = UsdShade.Shader(tex).GetInput("file")
                    if f and f.Get() is not None:
                        lm_path = f.Get().path
            meshes.append(
                PatchMeshData(
                    mesh_index=int(prim.GetCustomDataByKey("hirad:meshIndex") or 0),
                    points=pts,
                    face_vertex_counts=counts,
                    face_vertex_indices=idx,
                    vertex_radiance=arr("hirad:radiance", P),
                    vertex_irradiance=arr("hirad:irradiance", P),
                    face_radiance=arr("hirad:patchRadiance", F),
                    face_irradiance=arr("hirad:patchIrradiance", F),
                    lightmap_uv=_get_array(prim, "hirad:lightmapUV", time, 2),
                    lightmap_path=lm_path,
                    name=prim.GetName(),
                    source_path=prim.GetCustomDataByKey("hirad:sourcePath"),
                )
            )
    if not meshes:
        raise SceneError(f"{path}: not a hirad solution (no meshes under {SOLUTION_ROOT})")
    md = dict(stage.GetRootLayer().customLayerData)
    return SolutionData(
        meshes=meshes,
        cameras=read_cameras(stage),
        meters_per_unit=mpu,
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        metadata=md,
        path=str(path),
    )
