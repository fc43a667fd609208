"""Reflectance and emission of the surfaces: the bound UsdPreviewSurface (textures by their mean colour), else primvars:displayColor, else the config's default."""

from __future__ import annotations

import os

import numpy as np

from pxr import Sdf, Usd, UsdGeom, UsdShade
from .common import _srgb_to_linear, _vec3


_MAX_REFLECTANCE = 0.999


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
