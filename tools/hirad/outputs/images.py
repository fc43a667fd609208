"""Preview images: cameras, rendering a stored surface field, tone mapping to PNG."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _engine


@dataclass
class View:
    """A pinhole view in metres: where the eye is, where it looks, which way is up."""

    position: np.ndarray
    forward: np.ndarray
    up: np.ndarray
    vertical_fov_degrees: float


def default_view(points: np.ndarray, up_axis: str) -> View:
    """Looks at the scene's bounding box from outside, along the horizontal axis that keeps
    the box in frame (the Cornell convention: camera on the open side)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, extent = (lo + hi) / 2, hi - lo
    up = np.array([0.0, 0.0, 1.0]) if up_axis == "Z" else np.array([0.0, 1.0, 0.0])
    forward = np.array([0.0, 1.0, 0.0]) if up_axis == "Z" else np.array([0.0, 0.0, 1.0])
    fov = 40.0
    radius = 0.5 * float(np.linalg.norm(extent))
    distance = radius / np.tan(np.radians(fov / 2)) + 0.5 * float(np.dot(np.abs(forward), extent))
    return View(centre - forward * distance, forward, up, fov)


def view_from_camera(camera) -> View:
    return View(np.asarray(camera.position, float), np.asarray(camera.forward, float),
                np.asarray(camera.up, float), float(camera.vertical_fov_degrees))


def render(field: "_engine.SurfaceField", view: View, width: int, height: int, samples: int) -> np.ndarray:
    """Exitant radiance (W/(m^2 sr)) seen through `view`, shape (height, width, 3)."""
    return field.render(list(map(float, view.position)), list(map(float, view.forward)),
                        list(map(float, view.up)), view.vertical_fov_degrees, width, height, samples)


def _srgb_thresholds() -> np.ndarray:
    """The linear values at which the 8-bit sRGB code steps up: code k for x in
    [t[k-1], t[k]). Computed once with the scalar libm (math.pow), so that the codes depend
    on exact comparisons only, never on which SIMD kernels numpy picks for the machine's CPU
    (numpy's vectorised power differs in the last bit between AVX2 and AVX-512)."""
    import math

    out = []
    for k in range(255):
        c = (k + 0.5) / 255  # the sRGB value halfway between codes k and k + 1
        out.append(c / 12.92 if c <= 0.04045 else math.pow((c + 0.055) / 1.055, 2.4))
    return np.asarray(out, dtype=np.float64)


_SRGB_THRESHOLDS = _srgb_thresholds()


def tonemap(radiance: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """8-bit sRGB for looking at: a fixed exposure that maps the 97th percentile of the lit
    pixels' luminance to 0.9 (or the given exposure), then the sRGB curve. The luminance is
    summed channel by channel (not a BLAS product) and the curve read from thresholds, so the
    bytes are the same on every CPU."""
    radiance = np.asarray(radiance, dtype=np.float64)
    lum = radiance[..., 0] * 0.2126 + radiance[..., 1] * 0.7152 + radiance[..., 2] * 0.0722
    if exposure is None:
        lit = lum[lum > 0]
        exposure = 0.9 / float(np.percentile(lit, 97)) if lit.size else 1.0
    x = np.clip(radiance * exposure, 0.0, 1.0)
    return np.searchsorted(_SRGB_THRESHOLDS, x, side="right").astype(np.uint8)


def write_png(path: Path, radiance: np.ndarray, exposure: float | None = None) -> None:
    """8-bit sRGB PNG of exitant radiance (tone mapped as `tonemap`), written atomically."""
    _write_ldr(path, radiance, exposure, "PNG")


def write_jpeg(path: Path, radiance: np.ndarray, exposure: float | None = None, quality: int = 95) -> None:
    """8-bit sRGB JPEG of exitant radiance (tone mapped as `tonemap`), written atomically."""
    _write_ldr(path, radiance, exposure, "JPEG", quality=quality)


def _write_ldr(path: Path, radiance: np.ndarray, exposure: float | None, fmt: str, **options) -> None:
    from PIL import Image

    from ..files import atomic_file

    image = Image.fromarray(tonemap(radiance, exposure), "RGB")
    with atomic_file(path) as f:
        image.save(f, format=fmt, **options)
