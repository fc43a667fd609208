"""Reflectance and emission of the surfaces: the bound UsdPreviewSurface (textures by their mean colour), else primvars:displayColor, else the config's default."""

from __future__ import annotations

import os

import numpy as np

from pxr import Sdf, Usd, UsdGeom, UsdShade
from .common import _PrimError, _srgb_to_linear, _value_type


# Reflectance is clamped to this (a closed room of reflectance 1 never converges).  Values
# from the scene are checked where they are read: a non-finite or negative reflectance or
# emission is an error naming the prim and attribute; a reflectance above this maximum is
# clamped to it with a warning naming the prim and attribute.
_MAX_REFLECTANCE = 0.999

# Emitted radiance beyond this, W/(m^2 sr), is refused: the solution is written as 32-bit floats
# (at most 3.4e38) and the solver's norms square it; the sun's disc is about 2e7.
MAX_RADIANCE = 1e30


def _colour(value, where: str) -> np.ndarray:
    """An authored colour (or scalar, repeated) as an RGB float64 triple; anything that is not
    numbers is an error naming `where`."""
    try:
        arr = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _PrimError(f"{where}: expected a colour (3 numbers), got {_value_type(value)} {value!r}") from None
    if arr.size == 1:
        return np.repeat(arr, 3)
    if arr.size < 3:
        raise _PrimError(f"{where}: expected a colour (3 numbers), got {arr.size} value(s)")
    return arr[:3]


def _checked_reflectance(rgb: np.ndarray, where: str, warnings: list[str]) -> np.ndarray:
    """Reflectance read at `where`: non-finite or negative is an error; above _MAX_REFLECTANCE
    is clamped to it, with a warning (rgb may be (3,) or (n,3))."""
    rgb = np.asarray(rgb, dtype=np.float64)
    if not np.isfinite(rgb).all():
        bad = rgb[~np.isfinite(rgb).all(axis=-1)] if rgb.ndim == 2 else rgb
        raise _PrimError(f"{where}: reflectance is not finite ({np.asarray(bad).reshape(-1, 3)[0].tolist()})")
    if (rgb < 0).any():
        raise _PrimError(f"{where}: reflectance is negative (smallest {float(rgb.min()):g}); it must be in "
                         f"[0, {_MAX_REFLECTANCE}]")
    if (rgb > _MAX_REFLECTANCE).any():
        warnings.append(f"{where}: reflectance {float(rgb.max()):g} above the maximum {_MAX_REFLECTANCE} "
                        f"clamped to {_MAX_REFLECTANCE}")
        rgb = np.minimum(rgb, _MAX_REFLECTANCE)
    return rgb


def _checked_emission(rgb: np.ndarray, where: str, what: str = "emitted radiance") -> np.ndarray:
    """Emission read at `where`: non-finite or negative is an error."""
    rgb = np.asarray(rgb, dtype=np.float64)
    if not np.isfinite(rgb).all():
        raise _PrimError(f"{where}: {what} is not finite ({rgb.reshape(-1, 3)[0].tolist()})")
    if (rgb < 0).any():
        raise _PrimError(f"{where}: {what} is negative ({rgb.reshape(-1, 3)[0].tolist()}); light cannot be negative")
    if (rgb > MAX_RADIANCE).any():
        raise _PrimError(f"{where}: {what} {float(rgb.max()):.3g} is beyond the {MAX_RADIANCE:g} W/(m^2 sr) hirad "
                         "can represent")
    return rgb


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
            diffuse, d_where = self._eval_color_input(shader, "diffuseColor", key)
            emissive, e_where = self._eval_color_input(shader, "emissiveColor", key)
            if diffuse is not None:
                diffuse = _checked_reflectance(diffuse, d_where, self.warnings)
            if emissive is not None:
                emissive = _checked_emission(emissive, e_where, "emissive radiance")
            result = (diffuse, emissive)
        else:
            kind = shader.GetShaderId() if shader is not None else "no universal or MaterialX surface"
            self.warnings.append(f"{key}: material '{kind}' is not UsdPreviewSurface; "
                                 "its meshes use displayColor or the default reflectance")
        self._mat_cache[key] = result
        return result

    def material_transmittance(self, material: UsdShade.Material | None) -> float | None:
        """Glazing: the normal transmittance of direct light through a material's surface, or None
        (opaque). `hirad:transmittance` (a float on the material prim, 0..1) wins; else a
        UsdPreviewSurface whose constant `opacity` is below 1 transmits 1 - opacity. An opacity
        under a positive `opacityThreshold` is a cut-out, not glass: it is named in a warning and
        the surface stays opaque; so is an opacity connected to a texture."""
        if material is None or not material.GetPrim().IsValid():
            return None
        key = str(material.GetPath())
        cache = self.__dict__.setdefault("_tau_cache", {})
        if key in cache:
            return cache[key]
        tau = None
        attr = material.GetPrim().GetAttribute("hirad:transmittance")
        if attr and attr.HasAuthoredValue():
            value = attr.Get(self.time)
            try:
                tau = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"{attr.GetPath()}: hirad:transmittance must be a number in [0, 1], got {value!r}")
            if not (0.0 <= tau <= 1.0):
                raise ValueError(f"{attr.GetPath()}: hirad:transmittance must be in [0, 1], got {tau}")
        else:
            shader = self._surface_shader(material)
            if shader is not None and shader.GetShaderId() in _PREVIEW_SURFACE_IDS:
                inp = shader.GetInput("opacity")
                if inp:
                    connected = any(UsdShade.Output.IsOutput(a) for a in inp.GetValueProducingAttributes())
                    got = self._input_value(shader, "opacity")
                    if connected:
                        self.warnings.append(f"{key}: opacity connected to a texture is not honoured; the surface "
                                             "is opaque (set hirad:transmittance on the material for glass)")
                    elif got is not None and float(got[0]) < 1.0:
                        opacity, oattr = float(got[0]), got[1]
                        if not (0.0 <= opacity <= 1.0):
                            raise ValueError(f"{oattr.GetPath()}: opacity must be in [0, 1], got {opacity}")
                        thr = self._input_value(shader, "opacityThreshold")
                        if thr is not None and float(thr[0]) > 0:
                            self.warnings.append(f"{key}: opacity {opacity:g} under opacityThreshold "
                                                 f"{float(thr[0]):g} is a cut-out, which hirad does not honour; "
                                                 "the surface is opaque")
                        else:
                            tau = 1.0 - opacity
        cache[key] = tau
        return tau

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

    def _eval_color_input(self, shader: UsdShade.Shader, name: str, where: str) -> tuple[np.ndarray | None, str]:
        """(the input's constant colour or texture mean, or None; the attribute it came from)."""
        inp = shader.GetInput(name)
        if not inp:
            return None, ""
        for attr in inp.GetValueProducingAttributes():
            if UsdShade.Output.IsOutput(attr):
                src = UsdShade.Shader(attr.GetPrim())
                out_name = attr.GetBaseName()
                if src and src.GetShaderId() == "UsdUVTexture":
                    color = self._texture_color(src, out_name, where)
                    return color, f"{inp.GetAttr().GetPath()} (mean of texture {src.GetPath()})"
                self.warnings.append(
                    f"{where}: {name} is connected to unsupported shader "
                    f"{attr.GetPrim().GetPath()} ({src.GetShaderId() if src else '?'}); ignored"
                )
                return None, ""
            value = attr.Get(self.time)
            if value is not None:
                return _colour(value, str(attr.GetPath())), str(attr.GetPath())
        return None, ""

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
        fb = _numbers(fallback, "inputs:fallback", tex) if fallback else None
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
                rgba = rgba * _numbers(scale_v, "inputs:scale", tex)[:4]
            if bias_v is not None:
                rgba = rgba + _numbers(bias_v, "inputs:bias", tex)[:4]
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
            plane = arr[:, :, None] if arr.ndim == 2 else arr
            if plane.dtype == np.uint8:
                # 8 bits: each channel's mean from its histogram of 256 values, each value
                # decoded once (the Modern Hall's three textures: 0.76 -> 0.1 s)
                level = np.arange(256, dtype=np.float64) / 255.0
                decoded = _srgb_to_linear(level) if linearise else level
                count = float(plane.shape[0] * plane.shape[1])

                def channel_mean(c: int, colour: bool) -> float:
                    hist = np.bincount(plane[:, :, c].reshape(-1), minlength=256)
                    return float(hist @ (decoded if colour else level) / count)
            else:
                scale = 65535.0 if np.issubdtype(plane.dtype, np.integer) else 1.0  # 16-bit and "I" images

                def channel_mean(c: int, colour: bool) -> float:
                    v = plane[:, :, c].astype(np.float64) / scale
                    return float((_srgb_to_linear(v) if colour and linearise else v).mean())

            ch = plane.shape[2]  # 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA
            grey = channel_mean(0, True) if ch <= 2 else None
            mean_rgb = np.array([grey] * 3 if ch <= 2 else [channel_mean(c, True) for c in range(3)])
            mean_a = channel_mean(ch - 1, False) if ch in (2, 4) else 1.0
            result = np.array([*mean_rgb, mean_a], dtype=np.float64)
        except Exception:
            result = None
        self._tex_cache[key] = result
        return result


def _numbers(value_attr, name: str, prim) -> np.ndarray:
    value = value_attr[0]
    try:
        return np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise _PrimError(f"{prim.GetPath()}.{name}: expected numbers, got {_value_type(value)} {value!r}") from None


def _display_color_per_face(prim: Usd.Prim, time, counts: np.ndarray, indices: np.ndarray, n_points: int,
                            warnings: list[str]) -> np.ndarray | None:
    """Per-face mean of ``primvars:displayColor`` (reflectance, checked), or None when it is not
    authored.  A displayColor whose number of values does not fit its interpolation is named in a
    warning: too few values and it is not used, more than needed and the leading ones are."""
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    if not pv or not pv.HasAuthoredValue():
        return None
    where = f"{prim.GetPath()}.primvars:displayColor"
    raw = pv.ComputeFlattened(time)
    if raw is None or len(raw) == 0:
        return None
    try:
        vals = np.array(raw, dtype=np.float64)
    except (TypeError, ValueError):
        vals = np.zeros((0,))
    if vals.ndim != 2 or vals.shape[1] != 3:
        raise _PrimError(f"{where}: is {_value_type(raw)}, expected color3f[]")
    interp = pv.GetInterpolation()
    nf = len(counts)
    expected = {UsdGeom.Tokens.constant: 1, UsdGeom.Tokens.uniform: nf, UsdGeom.Tokens.vertex: n_points,
                UsdGeom.Tokens.varying: n_points, UsdGeom.Tokens.faceVarying: len(indices)}.get(interp)
    what = {UsdGeom.Tokens.constant: "", UsdGeom.Tokens.uniform: " (one per face)",
            UsdGeom.Tokens.faceVarying: " (one per face corner)"}.get(interp, " (one per point)")
    if expected is None:
        warnings.append(f"{where}: unknown interpolation {interp!r}; displayColor not used")
        return None
    if len(vals) != expected:
        if len(vals) == 1:
            used = "the single value is used for every face"
        elif len(vals) < expected:
            used = "displayColor not used"
        else:
            used = f"the first {expected} are used"
        warnings.append(f"{where}: {len(vals)} values for {interp} interpolation, which needs {expected}{what}; "
                        f"{used}")
        if len(vals) < expected and len(vals) != 1:
            return None
    if interp == UsdGeom.Tokens.constant or len(vals) == 1:
        per_face = np.repeat(vals[:1], nf, axis=0)
    elif interp == UsdGeom.Tokens.uniform:
        per_face = vals[:nf]
    else:
        if interp == UsdGeom.Tokens.faceVarying:
            corner = vals[: len(indices)]
        else:
            corner = vals[indices]
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        sums = np.add.reduceat(corner, starts, axis=0) if len(counts) else np.zeros((0, 3))
        per_face = sums / np.maximum(counts, 1)[:, None]
    return _checked_reflectance(per_face, where, warnings)
