"""Packing: an author's islands moved rigidly, xatlas's packer for generated charts, and mesh blocks onto pages by a skyline packer."""

from __future__ import annotations

import math

import numpy as np
from .base import _Block, _density
from .texels import _covered_texels


def _repack_islands(uv, islands, s, padding, limit, area3) -> _Block | None:
    """Packs the islands of a UV layout one by one, each moved rigidly."""
    packed = _pack_islands(uv * s, islands, padding, limit, rigid=True)
    if packed is None:
        return None
    local, w, h, factor = packed
    return _Block(w, h, local, islands.astype(np.int32), _density(local, area3), "existing-repacked",
                  scaled=factor < 1)


def _pack_islands(uvt: np.ndarray, islands: np.ndarray, padding: int, limit: int, rigid: bool):
    """Packs UV islands (texel units) into one block, scaling all of them down together if
    the block would pass `limit`. Returns (uv in the block, width, height, scale factor).

    xatlas's packer (rigid=False) stretches every chart by up to a texel so its extents are
    whole texels, in x and y separately; fine for charts we make, not for an author's
    islands, so those (rigid=True) go through our skyline packer of bounding rectangles,
    which only translates them (bounding boxes again start at texel centres)."""
    islands = np.unique(np.asarray(islands), return_inverse=True)[1].reshape(-1)
    factor = 1.0
    for _attempt in range(8):
        placed = (_pack_rigid if rigid else _pack_xatlas)(uvt * factor, islands, padding)
        if placed is None:
            return None
        local, w, h = placed
        if max(w, h) <= limit:
            return local, w, h, factor
        factor *= (limit - 1) / max(w, h) * 0.99
    return None


def _pack_rigid(uvt, islands, padding):
    n = int(islands.max()) + 1
    corners = uvt.reshape(-1, 2)
    owner = np.repeat(islands, 3)
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, owner, corners)
    np.maximum.at(hi, owner, corners)
    size = (np.floor(hi - lo + 0.5) + 1).astype(np.int64)  # texels covered from a centre start
    foot = size + padding
    width = int(max(foot[:, 0].max(), math.ceil(math.sqrt(float((foot[:, 0] * foot[:, 1]).sum())) * 1.15)))
    sky = np.zeros(width, np.int64)
    pos = np.zeros((n, 2), np.int64)
    for i in sorted(range(n), key=lambda k: (-foot[k, 1], -foot[k, 0], k)):
        pos[i] = _skyline_fit(sky, int(foot[i, 0]), int(foot[i, 1]), np.iinfo(np.int64).max // 2)
    local = uvt - lo[islands][:, None, :] + 0.5 + pos[islands][:, None, :]
    w, h = (pos + size).max(axis=0).tolist()
    return local, int(w), int(h)


def _pack_xatlas(uvt, islands, padding):
    corners = uvt.reshape(-1, 2)
    # One vertex per (corner uv, island): xatlas finds charts by shared vertices, and the
    # island id as material keeps islands that only touch apart.
    keys = np.concatenate([corners, np.repeat(islands, 3)[:, None].astype(np.float64)], axis=1)
    verts, inverse = np.unique(keys, axis=0, return_inverse=True)
    origin = verts[:, :2].min(axis=0)
    out, idx, w, h = _xatlas_pack((verts[:, :2] - origin).astype(np.float32),
                               inverse.reshape(-1, 3).astype(np.uint32),
                               islands.astype(np.uint32).reshape(-1, 1), int((padding + 1) // 2))
    return out.astype(np.float64)[idx.astype(np.int64)] * np.array([w, h], float), w, h


def _xatlas_pack(uv, faces, materials, padding):
    """xatlas packs existing UV islands: (uv, indices, width, height)."""
    import xatlas

    a = xatlas.Atlas()
    a.add_uv_mesh(uv, faces, materials)
    po = xatlas.PackOptions()
    po.texels_per_unit = 1.0
    po.padding = padding
    po.resolution = 0
    po.blockAlign = False
    a.generate(xatlas.ChartOptions(), po)
    _, idx, out = a[0]
    return out, idx, int(a.width), int(a.height)


def _island_gap(local, islands, w, h, padding) -> int | None:
    """The smallest gap in texels between two islands of a kept layout, if below padding."""
    if padding == 0 or islands.max() == 0:
        return None
    tri, lin = _covered_texels(local, w, h)
    owner = np.full(w * h, -1, np.int64)
    clash = np.zeros(w * h, bool)
    ids = islands[tri]
    owner[lin] = ids
    clash[lin[owner[lin] != ids]] = True  # texels two islands share
    if clash.any():
        return 0
    img = owner.reshape(h, w)
    for d in range(1, padding + 1):
        for dy in range(-d, d + 1):
            for dx in range(-d, d + 1):
                if max(abs(dx), abs(dy)) != d:
                    continue
                a = img[max(0, dy):h + min(0, dy), max(0, dx):w + min(0, dx)]
                b = img[max(0, -dy):h + min(0, -dy), max(0, -dx):w + min(0, -dx)]
                if ((a >= 0) & (b >= 0) & (a != b)).any():
                    return d - 1
    return None


def _pack_blocks(sizes: list[tuple[int, int]], max_size: int, padding: int, margin: int):
    """Puts the mesh blocks on pages: bottom-left skyline packing, tallest first, each block
    on the first page where it fits. Blocks are separated by `padding` texels and keep
    `margin` from the page borders; positions are integers, so the texel phase of every
    chart in a block is kept."""
    cap = max_size - 2 * margin + padding  # each footprint carries its trailing padding
    order = sorted(range(len(sizes)), key=lambda i: (-sizes[i][1], -sizes[i][0], i))
    skylines: list[np.ndarray] = []
    pages: list[list[int]] = []
    placed: list[tuple[int, int, int]] = [(-1, 0, 0)] * len(sizes)
    for i in order:
        w, h = sizes[i]
        if w == 0 or h == 0:
            continue
        fw, fh = w + padding, h + padding
        if fw > cap or fh > cap:
            raise ValueError(f"block {w}x{h} cannot fit a {max_size} page")
        for k, sky in enumerate(skylines):
            spot = _skyline_fit(sky, fw, fh, cap)
            if spot is not None:
                break
        else:
            skylines.append(np.zeros(cap, np.int64))
            pages.append([])
            k, spot = len(skylines) - 1, _skyline_fit(skylines[-1], fw, fh, cap)
        x, y = spot
        placed[i] = (k, margin + x, margin + y)
        pages[k].append(i)
    return placed, pages


def _skyline_fit(sky: np.ndarray, fw: int, fh: int, cap: int):
    """Lowest (then leftmost) position of a fw x fh footprint on a column-height skyline."""
    rest = np.lib.stride_tricks.sliding_window_view(sky, fw).max(axis=1)
    ok = rest + fh <= cap
    if not ok.any():
        return None
    x = int(np.argmin(np.where(ok, rest, np.iinfo(np.int64).max)))
    y = int(rest[x])
    sky[x:x + fw] = y + fh
    return x, y
