"""Lightmap files: 8-bit PNG encodings of linear lightmaps (hirad's RGBM, Unity's RGBM and
Unity's dLDR) and the manifest that maps each mesh to its page and lightmapScaleOffset.

Unity's two 8-bit lightmap encodings, as its manual states them ("Lightmaps: Technical
information" / "Lightmap data format", docs.unity3d.com/Manual/Lightmaps-TechnicalInformation.html,
2017.4 to 6000.x) and as its shaders decode them (the Scriptable Render Pipeline core
library's EntityLighting.hlsl: LIGHTMAP_RGBM_MAX_GAMMA = 5.0, LIGHTMAP_RGBM_MAX_LINEAR =
34.493242 = 5^2.2, UnpackLightmapRGBM, UnpackLightmapDoubleLDR):

- The values stored in an encoded lightmap are always in *gamma* space; with the linear
  colour space the texture is marked sRGB, so the sampler returns rgb already raised to
  ~2.2, and the shader works in linear space. Unity's model of gamma is the pure power 2.2
  (34.493242 = 5^2.2, 4.59 = 2^2.2); we encode and decode with exactly that power. A GPU's
  sRGB decode follows the piecewise sRGB curve instead: it agrees with x^2.2 within 2 % for
  8-bit values from 85/255 up, within 10 % from 58/255, and is far brighter in the toe (the
  curve is linear below 0.04045: at 1/255 it gives 59 times 1/255^2.2). Unity's shaders
  live with the same difference; decode_* here follow Unity's stated formulas.
- RGBM: colour in RGB, a multiplier M in A; range 0..5 in gamma space, 0..34.49 in linear.
  Gamma-space decode: value = rgb * a * 5. Linear-space decode: value = rgb_linear *
  a^2.2 * 34.493242 with rgb_linear = rgb^2.2 (the sRGB sampler's work; alpha is never
  converted), i.e. value = (5 * a * rgb)^2.2.
- dLDR ("double low dynamic range", mobile): [0, 2] in gamma space mapped to [0, 1];
  larger values clamp. Decode: value = 2 * rgb in gamma space, 4.59482 (= 2^2.2) *
  rgb_linear in linear space, i.e. value = (2 * rgb)^2.2.

Encoders here take *linear* values (what hirad bakes: H/pi) and return 8-bit arrays; the
decoders return linear values by the formulas above (or gamma-space ones on request).
"""

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


# ----------------------------------------------------------------------------------------
# Unity's encodings (see the module docstring for the sources)

UNITY_GAMMA = 2.2
UNITY_RGBM_RANGE_GAMMA = 5.0
UNITY_RGBM_RANGE_LINEAR = UNITY_RGBM_RANGE_GAMMA ** UNITY_GAMMA  # 34.493242
UNITY_DLDR_RANGE_GAMMA = 2.0
UNITY_DLDR_RANGE_LINEAR = UNITY_DLDR_RANGE_GAMMA ** UNITY_GAMMA  # 4.594794


def _to_gamma(image: np.ndarray) -> np.ndarray:
    """Linear values -> Unity's gamma space (pure power 1/2.2); negatives become 0."""
    return np.clip(np.asarray(image, dtype=np.float64)[..., :3], 0.0, None) ** (1.0 / UNITY_GAMMA)


def encode_unity_rgbm(image: np.ndarray) -> np.ndarray:
    """Unity RGBM (H, W, 4) uint8 of linear values: g = value^(1/2.2) / 5 in [0, 1] (values
    above 34.49 clamp), A = ceil(255 max(g)) (at least 1, so the multiplier never hides a
    channel), RGB = round(255 g / (A/255)). Rounding A up keeps RGB <= 255."""
    x = np.clip(_to_gamma(image) / UNITY_RGBM_RANGE_GAMMA, 0.0, 1.0)
    a = np.clip(np.ceil(x.max(axis=-1) * 255 - 1e-9), 1, 255)
    rgb = np.clip(np.rint(x / (a / 255)[..., None] * 255), 0, 255)
    return np.concatenate([rgb, a[..., None]], axis=-1).astype(np.uint8)


def decode_unity_rgbm(rgbm: np.ndarray, space: str = "linear") -> np.ndarray:
    """Unity's decode of RGBM texels: linear (5 * a * rgb)^2.2 = rgb^2.2 * a^2.2 * 34.49,
    or the gamma-space value 5 * a * rgb with space="gamma"."""
    q = np.asarray(rgbm, dtype=np.float64)
    g = q[..., :3] / 255 * (q[..., 3:4] / 255) * UNITY_RGBM_RANGE_GAMMA
    return (g if space == "gamma" else g ** UNITY_GAMMA).astype(np.float32)


def encode_unity_dldr(image: np.ndarray) -> np.ndarray:
    """Unity dLDR (H, W, 3) uint8 of linear values: RGB = round(255 value^(1/2.2) / 2),
    values above 2^2.2 = 4.59 clamp."""
    x = np.clip(_to_gamma(image) / UNITY_DLDR_RANGE_GAMMA, 0.0, 1.0)
    return np.rint(x * 255).astype(np.uint8)


def decode_unity_dldr(rgb: np.ndarray, space: str = "linear") -> np.ndarray:
    """Unity's decode of dLDR texels: linear (2 * rgb)^2.2 = 4.59 * rgb^2.2, or the
    gamma-space value 2 * rgb with space="gamma"."""
    g = np.asarray(rgb, dtype=np.float64)[..., :3] / 255 * UNITY_DLDR_RANGE_GAMMA
    return (g if space == "gamma" else g ** UNITY_GAMMA).astype(np.float32)


# What each encoding is called in PNG text chunks and manifests, and how to decode it.
ENCODINGS = {
    "hirad-rgbm": {"channels": "RGBA", "colorSpace": "linear",
                   "decode": "linear = R/255 * A/255 * range (same for G, B)"},
    "unity-rgbm": {"channels": "RGBA", "colorSpace": "gamma (import as sRGB)",
                   "decode": "linear = (5 * R/255 * A/255)^2.2 = rgb_linear * a^2.2 * 34.493242; "
                             "gamma = 5 * R/255 * A/255",
                   "rangeLinear": UNITY_RGBM_RANGE_LINEAR},
    "unity-dldr": {"channels": "RGB", "colorSpace": "gamma (import as sRGB)",
                   "decode": "linear = (2 * R/255)^2.2 = 4.594794 * rgb_linear; gamma = 2 * R/255",
                   "rangeLinear": UNITY_DLDR_RANGE_LINEAR},
}


def encode(image: np.ndarray, encoding: str, max_range: float | None = None) -> np.ndarray:
    """8-bit texels of linear `image` in one of ENCODINGS (hirad-rgbm needs max_range)."""
    if encoding == "hirad-rgbm":
        if max_range is None:
            raise ValueError("hirad-rgbm needs max_range")
        return encode_rgbm(image, max_range)
    if encoding == "unity-rgbm":
        return encode_unity_rgbm(image)
    if encoding == "unity-dldr":
        return encode_unity_dldr(image)
    raise ValueError(f"unknown lightmap encoding {encoding!r} (known: {', '.join(ENCODINGS)})")


def decode(texels: np.ndarray, encoding: str, max_range: float | None = None) -> np.ndarray:
    """Linear values of 8-bit texels in one of ENCODINGS."""
    if encoding == "hirad-rgbm":
        return decode_rgbm(texels, max_range)
    if encoding == "unity-rgbm":
        return decode_unity_rgbm(texels)
    if encoding == "unity-dldr":
        return decode_unity_dldr(texels)
    raise ValueError(f"unknown lightmap encoding {encoding!r} (known: {', '.join(ENCODINGS)})")


def write_png(path: str | Path, image: np.ndarray, encoding: str, max_range: float | None = None) -> None:
    """An 8-bit PNG of linear `image` in `encoding` (see ENCODINGS), named with its decoding
    rule in the PNG's text chunks (hirad:encoding, hirad:decode, and hirad:rgbm_range for
    hirad-rgbm), written atomically."""
    from PIL import Image, PngImagePlugin

    texels = encode(image, encoding, max_range)
    info = PngImagePlugin.PngInfo()
    info.add_text("hirad:encoding", encoding)
    info.add_text("hirad:decode", ENCODINGS[encoding]["decode"])
    info.add_text("hirad:colorSpace", ENCODINGS[encoding]["colorSpace"])
    if encoding == "hirad-rgbm":
        info.add_text("hirad:rgbm_range", repr(float(max_range)))
    pixels = Image.fromarray(texels, mode="RGBA" if texels.shape[-1] == 4 else "RGB")
    _atomic(Path(path), lambda tmp: pixels.save(tmp, format="PNG", pnginfo=info))


def read_png(path: str | Path) -> tuple[np.ndarray, str]:
    """The linear image and the encoding of a PNG from `write_png` (or `write_rgbm_png`)."""
    from PIL import Image

    with Image.open(path) as im:
        text = dict(im.text)
        encoding = text.get("hirad:encoding")
        if encoding == "RGBM":  # write_rgbm_png's name for hirad-rgbm
            encoding = "hirad-rgbm"
        if encoding not in ENCODINGS:
            raise ValueError(f"{path}: no known hirad:encoding text chunk (found {encoding!r})")
        data = np.asarray(im.convert(ENCODINGS[encoding]["channels"]))
    max_range = float(text["hirad:rgbm_range"]) if encoding == "hirad-rgbm" else None
    return decode(data, encoding, max_range), encoding


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
        **({"prototype": str(m.prototype)} if m.prototype is not None else {}),
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
