"""Lightmap files: RGBM PNG encoding and the manifest that maps each mesh to its page and lightmapScaleOffset."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from .base import Atlas


# ----------------------------------------------------------------------------------------
# Writers


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Writes through hirad's one atomic write (hirad.files: an exclusive temporary sibling,
    fsynced and renamed into place): a reader never sees a half-written file, and a failure
    leaves the old file (or none)."""
    from ..files import atomic_path

    with atomic_path(path) as tmp:
        write(tmp)


def encode_rgbm(image: np.ndarray, max_range: float) -> np.ndarray:
    """8-bit RGBM of linear values: value = rgb/255 * (a/255) * max_range. The multiplier
    is rounded up, so rgb never clips; values above max_range are clamped to it."""
    x = np.clip(np.asarray(image, dtype=np.float64)[..., :3] / float(max_range), 0.0, 1.0)
    m = np.clip(x.max(axis=-1), 1.0 / 255, 1.0)
    a = np.clip(np.ceil(m * 255 - 1e-9), 1, 255)
    rgb = np.clip(np.rint(x / (a / 255)[..., None] * 255), 0, 255)
    return np.concatenate([rgb, a[..., None]], axis=-1).astype(np.uint8)


def decode_rgbm(rgbm: np.ndarray, max_range: float) -> np.ndarray:
    q = np.asarray(rgbm, dtype=np.float64)
    return (q[..., :3] / 255 * (q[..., 3:4] / 255) * float(max_range)).astype(np.float32)


def write_rgbm_png(path: str | Path, image: np.ndarray, max_range: float) -> None:
    """An 8-bit RGBM PNG (linear, see `encode_rgbm`); the range and the decoding rule are in
    the PNG's text chunks, so a reader needs nothing else."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_text("hirad:encoding", "RGBM")
    info.add_text("hirad:rgbm_range", repr(float(max_range)))
    info.add_text("hirad:decode", "linear value = R/255 * A/255 * range (same for G, B)")
    pixels = Image.fromarray(encode_rgbm(image, max_range), mode="RGBA")
    _atomic(Path(path), lambda tmp: pixels.save(tmp, format="PNG", pnginfo=info))


def read_rgbm_png(path: str | Path) -> tuple[np.ndarray, float]:
    """The linear image and range of a PNG from `write_rgbm_png`."""
    from PIL import Image

    with Image.open(path) as im:
        max_range = float(im.text["hirad:rgbm_range"])
        data = np.asarray(im.convert("RGBA"))
    return decode_rgbm(data, max_range), max_range


def manifest_entry(atlas: Atlas, mesh: int, page_files: Sequence[str]) -> dict:
    """What an engine importer needs for one mesh: its page file, Unity-style scale/offset
    and the density it got."""
    m = atlas.meshes[mesh]
    return {
        "page": m.page if m.page >= 0 else None,
        "file": page_files[m.page] if m.page >= 0 else None,
        "scaleOffset": [float(v) for v in m.scale_offset],
        "texelsPerMetre": float(m.texels_per_metre),
        "uvSource": m.source,
    }


def write_manifest(path: str | Path, atlas: Atlas, page_files: Sequence[str],
                   extra: dict | None = None) -> dict:
    """JSON: each mesh name to its page file, scale/offset and density, plus the pages."""
    if len(page_files) != len(atlas.page_sizes):
        raise ValueError(f"{len(page_files)} page files for {len(atlas.page_sizes)} pages")
    if len(set(atlas.names)) != len(atlas.names):
        raise ValueError("mesh names must be unique in a manifest")
    data = {
        "format": "hirad-lightmap-atlas",
        "version": 1,
        "uvConvention": "USD texCoord2f: v up, origin bottom-left; page_uv = uv * scale + offset",
        "texelsPerMetre": atlas.texels_per_metre,
        "padding": atlas.padding,
        "pages": [{"file": f, "width": w, "height": h, "fill": round(fill, 6)}
                  for f, (w, h), fill in zip(page_files, atlas.page_sizes, atlas.fill)],
        "meshes": {name: manifest_entry(atlas, i, page_files) for i, name in enumerate(atlas.names)},
        "warnings": list(atlas.warnings),
        **(extra or {}),
    }
    _atomic(Path(path), lambda tmp: tmp.write_text(json.dumps(data, indent=2) + "\n"))
    return data
