"""Texels: conservative rasterisation of the charts into texel samples, their surface points, resolving sample values into texels, dilation and seam stitching."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
from .base import Atlas, Mesh, TexelSamples, _COVER_EPS, _areas2


# ----------------------------------------------------------------------------------------
# Rasterisation


def _edge_setup(uv: np.ndarray):
    """Edge functions of (F, 3, 2) triangles, oriented so the inside is positive: e_k(p) =
    g_k . p + c_k for the edge opposite corner k, with e_k(corner k) = 2 |area|, so the
    barycentric weight of corner k is e_k(p) / (2 |area|)."""
    r = uv[:, [1, 2, 0]]
    q = uv[:, [2, 0, 1]]
    d = q - r
    area2 = 2 * _areas2(uv)
    sign = np.where(area2 < 0, -1.0, 1.0)[:, None]
    g = np.stack([-d[..., 1], d[..., 0]], axis=-1) * sign[..., None]
    c = -(g * r).sum(-1)
    return g, c, np.abs(area2)


def _candidates(uv: np.ndarray, width: int, height: int, tri_ids: np.ndarray):
    """Every (triangle, texel) whose squares meet the triangle's bounding box."""
    lo = np.floor(uv[tri_ids].min(axis=1)).astype(np.int64)
    hi = np.ceil(uv[tri_ids].max(axis=1)).astype(np.int64) - 1
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    n = np.maximum(hi - lo + 1, 0)
    count = n[:, 0] * n[:, 1]
    tri = np.repeat(tri_ids, count)
    first = np.repeat(np.cumsum(count) - count, count)
    k = np.arange(len(tri)) - first
    nx = np.repeat(n[:, 0], count)
    ix = np.repeat(lo[:, 0], count) + k % np.maximum(nx, 1)
    iy = np.repeat(lo[:, 1], count) + k // np.maximum(nx, 1)
    return tri, ix, iy


def _touch(g, c, tri, ix, iy):
    """Edge values at the texel centres and whether the texel square and the triangle
    overlap in positive area (separating axes: the bounding box already overlaps)."""
    gt = g[tri]
    centre = np.stack([ix + 0.5, iy + 0.5], axis=-1)
    e = (gt * centre[:, None, :]).sum(-1) + c[tri]
    reach = 0.5 * np.abs(gt).sum(-1)
    return e, (e + reach > _COVER_EPS * np.abs(gt).sum(-1)).all(axis=1)


def _chunks(weights: np.ndarray, budget: int):
    """Splits triangle indices into runs whose candidate counts stay within a budget."""
    if len(weights) == 0:
        return
    cum = np.cumsum(weights)
    start = 0
    while start < len(weights):
        base = cum[start - 1] if start else 0
        stop = int(np.searchsorted(cum, base + budget, side="right"))
        stop = max(stop, start + 1)
        yield np.arange(start, stop)
        start = stop


def _bbox_counts(uv, width, height):
    lo = np.maximum(np.floor(uv.min(axis=1)), 0)
    hi = np.minimum(np.ceil(uv.max(axis=1)) - 1, [width - 1, height - 1])
    n = np.maximum(hi - lo + 1, 0)
    return (n[:, 0] * n[:, 1]).astype(np.int64)


def _covered_texels(uv: np.ndarray, width: int, height: int):
    """(triangle, linear texel id v-up row-major) for every covering pair."""
    g, c, area = _edge_setup(uv)
    live = np.nonzero(area > 1e-12)[0]
    counts = _bbox_counts(uv[live], width, height)
    tris, lins = [], []
    for part in _chunks(counts, 2_000_000):
        tri, ix, iy = _candidates(uv, width, height, live[part])
        _, hit = _touch(g, c, tri, ix, iy)
        tris.append(tri[hit])
        lins.append(iy[hit] * width + ix[hit])
    if not tris:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(tris), np.concatenate(lins)


def rasterize(atlas: Atlas, page: int, supersample: int = 2) -> TexelSamples:
    """Sample points of every texel a triangle of `page` covers.

    Each texel is split into supersample x supersample strata and a sub-sample is taken at
    every stratum centre that lies inside a triangle (a point on an edge two triangles
    share counts once). A covered texel with no such point (a sliver, a chart's corner)
    gets one sample at the closest point of the nearest covering triangle to its centre,
    so thin triangles are never lost and every covered texel has a value.
    """
    s = int(supersample)
    if s < 1:
        raise ValueError("supersample must be >= 1")
    width, height = atlas.page_sizes[page]
    uv, mesh_of, tri_of = atlas.page_texel_uvs(page)
    g, c, area = _edge_setup(uv)
    live = np.nonzero(area > 1e-12)[0]
    grid = np.stack(np.meshgrid(np.arange(s), np.arange(s), indexing="xy"), -1).reshape(-1, 2)
    offs = (grid + 0.5) / s - 0.5  # stratum centres relative to the texel centre

    keys, s_tri, s_bary = [], [], []
    cand_tri, cand_lin, cand_e = [], [], []
    counts = _bbox_counts(uv[live], width, height)
    for part in _chunks(counts, max(10_000, 1_500_000 // (s * s))):
        tri, ix, iy = _candidates(uv, width, height, live[part])
        e, hit = _touch(g, c, tri, ix, iy)
        tri, ix, iy, e = tri[hit], ix[hit], iy[hit], e[hit]
        lin = iy * width + ix
        cand_tri.append(tri)
        cand_lin.append(lin)
        cand_e.append(e)
        es = e[:, None, :] + np.einsum("jd,nkd->njk", offs, g[tri])  # (n, s*s, 3)
        # closed test with a hair of slack: a point on an edge two triangles share must not
        # be lost to rounding on both sides (duplicates are removed below)
        slack = -1e-7 * np.abs(g[tri]).sum(-1)[:, None, :]
        inside = (es >= slack).all(axis=2)
        n_idx, j_idx = np.nonzero(inside)
        keys.append(lin[n_idx] * (s * s) + j_idx)
        s_tri.append(tri[n_idx])
        s_bary.append(es[n_idx, j_idx] / area[tri[n_idx], None])

    if cand_tri:
        cand_tri, cand_lin, cand_e = map(np.concatenate, (cand_tri, cand_lin, cand_e))
        keys, s_tri, s_bary = map(np.concatenate, (keys, s_tri, s_bary))
    else:
        cand_tri = cand_lin = keys = s_tri = np.zeros(0, np.int64)
        cand_e = np.zeros((0, 3))
        s_bary = np.zeros((0, 3))
    keys, first = np.unique(keys, return_index=True)
    s_tri, s_bary = s_tri[first], s_bary[first]
    s_lin = keys // (s * s)

    # Covered texels without a sub-sample: the closest point of a covering triangle.
    lonely = ~np.isin(cand_lin, s_lin)
    f_tri, f_lin, f_bary = _closest_samples(uv, g, area, cand_tri[lonely], cand_lin[lonely], width)

    all_lin = np.concatenate([s_lin, f_lin])
    all_tri = np.concatenate([s_tri, f_tri])
    all_bary = np.concatenate([s_bary, f_bary])
    texels, texel_of = np.unique(all_lin, return_inverse=True)
    order = np.argsort(texel_of, kind="stable")
    texel_of, all_tri, all_bary = texel_of[order], all_tri[order], all_bary[order]
    conservative = np.isin(texels, f_lin)
    all_bary = np.clip(all_bary, 0.0, None)
    all_bary /= all_bary.sum(axis=1, keepdims=True)
    return TexelSamples(
        page=page, width=width, height=height, supersample=s,
        x=(texels % width).astype(np.int32),
        y=(height - 1 - texels // width).astype(np.int32),
        conservative=conservative,
        texel=texel_of.astype(np.int32),
        mesh=mesh_of[all_tri].astype(np.int32),
        triangle=tri_of[all_tri].astype(np.int32),
        bary=all_bary)


def _closest_samples(uv, g, area, tri, lin, width, chunk: int = 250_000):
    """For each texel in `lin`, the closest point to its centre over the candidate
    triangles touching it: (triangle, texel, barycentrics), one per texel. Candidates are
    measured `chunk` at a time, so the working arrays stay small whatever the page (a
    1M-triangle scene's border texels: several million candidates)."""
    if len(tri) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    best = np.empty((len(tri), 2))
    best_d = np.empty(len(tri))
    for lo in range(0, len(tri), chunk):
        part = slice(lo, lo + chunk)
        tp, lp = tri[part], lin[part]
        centre = np.stack([lp % width + 0.5, lp // width + 0.5], axis=-1).astype(np.float64)
        v = uv[tp]  # (n, 3, 2)
        pb = centre.copy()
        pd = np.full(len(tp), np.inf)
        e = (g[tp] * centre[:, None, :]).sum(-1) + (-(g[tp] * v[:, [1, 2, 0]]).sum(-1))
        inside = (e >= 0).all(axis=1)
        pd[inside] = 0.0
        for k in range(3):
            a, b = v[:, k], v[:, (k + 1) % 3]
            d = b - a
            t = np.clip(((centre - a) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
            pt = a + t[:, None] * d
            dist = np.linalg.norm(pt - centre, axis=1)
            better = (dist < pd) & ~inside
            pb[better], pd[better] = pt[better], dist[better]
        best[part], best_d[part] = pb, pd
    order = np.lexsort((best_d, lin))
    lin_s = lin[order]
    keep = order[np.r_[True, lin_s[1:] != lin_s[:-1]]]
    pts = best[keep]
    tk = tri[keep]
    c = -(g[tk] * uv[tk][:, [1, 2, 0]]).sum(-1)
    bary = ((g[tk] * pts[:, None, :]).sum(-1) + c) / area[tk, None]
    return tk, lin[keep], bary


def sample_points(samples: TexelSamples, meshes: Sequence[Mesh]) -> tuple[np.ndarray, np.ndarray]:
    """3D points (K, 3) and unit geometric normals (K, 3) of the samples (the normal follows
    the triangle's winding: (b - a) x (c - a))."""
    points = np.zeros((len(samples), 3))
    normals = np.zeros((len(samples), 3))
    for m in np.unique(samples.mesh):
        sel = samples.mesh == m
        p, t = meshes[int(m)]
        p = np.asarray(p, dtype=np.float64)
        corners = p[np.asarray(t)[samples.triangle[sel]]]  # (k, 3, 3)
        points[sel] = np.einsum("kc,kcd->kd", samples.bary[sel], corners)
        n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals[sel] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return points, normals


def resolve(samples: TexelSamples, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The page image: each covered texel is the mean of its samples' values.
    Returns (image (H, W, C) float32, mask (H, W) bool of covered texels)."""
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    if len(values) != len(samples):
        raise ValueError(f"{len(values)} values for {len(samples)} samples")
    t = len(samples.x)
    count = np.bincount(samples.texel, minlength=t).astype(np.float64)
    image = np.zeros((samples.height, samples.width, values.shape[1]), np.float32)
    mask = np.zeros((samples.height, samples.width), bool)
    for ch in range(values.shape[1]):
        image[samples.y, samples.x, ch] = np.bincount(samples.texel, values[:, ch], minlength=t) / count
    mask[samples.y, samples.x] = True
    return image, mask


def dilate(image: np.ndarray, mask: np.ndarray, texels: int, *, whole_page: bool = True) -> np.ndarray:
    """Fills the texels no chart covers, so bilinear filtering and every mip level read
    chart values, never black. Covered texels are not changed.

    First `texels` rings (the padding) grow from the charts one ring per pass, each new
    texel the mean of its already filled 8-neighbours: the padding continues the charts'
    border values smoothly. Then, with `whole_page` (the default), every texel still empty
    takes the value of its nearest filled texel (Euclidean distance between texel centres,
    scipy.ndimage.distance_transform_edt's feature transform; ties broken by its fixed
    scan order, so the result is deterministic). Every texel then holds a value some chart
    texel holds, so a page whose covered texels are all positive has no texel <= 0 anywhere,
    and neither has any level of its mip pyramid: a box (or any non-negative) filter of
    positive values is positive. A page with no covered texel is returned as it is."""
    out = np.array(image, dtype=np.float32, copy=True)
    filled = np.array(mask, dtype=bool, copy=True)
    h, w = filled.shape
    vals = out if out.ndim == 3 else out[..., None]
    for _ in range(int(texels)):
        total = np.zeros(vals.shape, np.float64)
        count = np.zeros((h, w), np.float64)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx == 0 and dy == 0:
                    continue
                dst = (slice(max(0, dy), h + min(0, dy)), slice(max(0, dx), w + min(0, dx)))
                src = (slice(max(0, -dy), h + min(0, -dy)), slice(max(0, -dx), w + min(0, -dx)))
                m = filled[src]
                total[dst] += vals[src] * m[..., None]
                count[dst] += m
        grow = ~filled & (count > 0)
        if not grow.any():
            break
        vals[grow] = (total[grow] / count[grow][:, None]).astype(np.float32)
        filled |= grow
    if whole_page and filled.any() and not filled.all():
        from scipy.ndimage import distance_transform_edt

        _, (iy, ix) = distance_transform_edt(~filled, return_indices=True)
        empty = ~filled
        vals[empty] = vals[iy[empty], ix[empty]]
    return out


# ----------------------------------------------------------------------------------------
# Seams


def seam_pairs(atlas: Atlas, page: int, crease_angle: float = 30.0) -> np.ndarray:
    """Texel pairs across UV seams of `page`: (P, 4) int32 rows (x_a, y_a, x_b, y_b), image
    coordinates (column, row from the top).

    Only seams across which the surface is smooth: the two triangles' normals within
    `crease_angle` degrees (the display mesh's rule, reconstruction.crease_angle). Across a
    crease the light itself changes (a floor and the wall standing on it see different
    hemispheres), so the two sides' texels differ and are left so: averaging them moved a
    floor texel at the edge of the Modern Hall's recess 22 % towards the recess's wall.

    For every 3D edge two triangles share (vertices welded by position) whose corner UVs
    differ on the two sides, the edge is walked from texel border to texel border (the
    borders of both sides' grids): each piece between two crossings lies in one texel on
    side a and one on side b, which show the same 3D points and should hold the same value.
    Where the two grids line up (same density, same texel phase, as xatlas's charts of a
    box) this pairs texels one to one; elsewhere a texel pairs with the two it overlaps.
    """
    w, h = atlas.page_sizes[page]
    scale = np.array([w, h], float)
    out = []
    for mi in atlas.page_meshes(page):
        p, t = atlas.geometry[mi]
        layout = atlas.meshes[mi]
        uv = layout.uvs * scale
        usable = (layout.charts >= 0) & (np.abs(_areas2(uv)) > 1e-12)
        _, weld = np.unique(p, axis=0, return_inverse=True)
        tv = weld.reshape(-1)[t]
        f_idx = np.nonzero(usable)[0]
        if len(f_idx) == 0:
            continue
        k0 = np.tile(np.arange(3), len(f_idx))
        faces = np.repeat(f_idx, 3)
        k1 = (k0 + 1) % 3
        va, vb = tv[faces, k0], tv[faces, k1]
        key = np.minimum(va, vb) * (int(weld.max()) + 1) + np.maximum(va, vb)
        order = np.argsort(key, kind="stable")
        key_s = key[order]
        starts = np.r_[True, key_s[1:] != key_s[:-1]]
        group = np.cumsum(starts) - 1
        size = np.bincount(group)
        two = size[group] == 2  # manifold edges only
        first = order[starts & two]
        second = order[np.r_[starts[1:], True] & ~starts & two]
        if len(first) == 0:
            continue
        fa, ka = faces[first], k0[first]
        fb, kb = faces[second], k0[second]
        # Side a runs corner ka -> ka+1; find the same 3D endpoints on side b.
        a0, a1 = uv[fa, ka], uv[fa, (ka + 1) % 3]
        same_dir = tv[fb, kb] == tv[fa, ka]
        b0 = np.where(same_dir[:, None], uv[fb, kb], uv[fb, (kb + 1) % 3])
        b1 = np.where(same_dir[:, None], uv[fb, (kb + 1) % 3], uv[fb, kb])
        seam = (np.abs(a0 - b0).max(axis=1) > 1e-3) | (np.abs(a1 - b1).max(axis=1) > 1e-3)
        if not seam.any():
            continue
        # smooth seams only (see above): the triangles' geometric normals within crease_angle
        e1, e2 = p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]
        nrm = np.cross(e1, e2)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        seam &= np.einsum("ij,ij->i", nrm[fa], nrm[fb]) >= np.cos(np.radians(crease_angle)) - 1e-9
        if not seam.any():
            continue
        fa, fb, a0, a1, b0, b1 = fa[seam], fb[seam], a0[seam], a1[seam], b0[seam], b1[seam]
        # Split each edge where it crosses a texel border on either side: every piece then
        # lies in one texel of side a and one of side b, and that texel pair shares it.
        # Pieces shorter than 1/100 texel are float noise between grids that line up.
        length = np.maximum(np.linalg.norm(a1 - a0, axis=1), np.linalg.norm(b1 - b0, axis=1))
        cuts = [np.zeros(len(fa)), np.ones(len(fa))]
        owners = [np.arange(len(fa)), np.arange(len(fa))]
        for q0, q1 in ((a0, a1), (b0, b1)):
            for d in range(2):
                lo, hi = np.minimum(q0[:, d], q1[:, d]), np.maximum(q0[:, d], q1[:, d])
                k0 = np.floor(lo).astype(np.int64) + 1
                n = np.maximum(np.ceil(hi).astype(np.int64) - k0, 0)
                e = np.repeat(np.arange(len(fa)), n)
                k = k0[e] + np.arange(len(e)) - np.repeat(np.cumsum(n) - n, n)
                cuts.append((k - q0[e, d]) / (q1[e, d] - q0[e, d]))
                owners.append(e)
        cut, own = np.concatenate(cuts), np.concatenate(owners)
        order = np.lexsort((cut, own))
        cut, own = cut[order], own[order]
        same = own[1:] == own[:-1]
        piece = (cut[1:] - cut[:-1]) * length[own[:-1]]
        keep = same & (piece > 1e-2)
        e_id = own[:-1][keep]
        tt = 0.5 * (cut[1:] + cut[:-1])[keep]
        ca, cb = uv[fa].mean(axis=1), uv[fb].mean(axis=1)

        def texel(q0, q1, cen):
            # The piece's midpoint, moved a hair into its triangle: an edge lying on a texel
            # border then picks the texel the triangle covers.
            pt = q0[e_id] + tt[:, None] * (q1 - q0)[e_id]
            towards = cen[e_id] - pt
            pt = pt + 1e-3 * towards / np.maximum(np.linalg.norm(towards, axis=1, keepdims=True), 1e-300)
            ij = np.floor(pt).astype(np.int64)
            return np.clip(ij, 0, [w - 1, h - 1])

        ta, tb = texel(a0, a1, ca), texel(b0, b1, cb)
        rows = np.stack([ta[:, 0], h - 1 - ta[:, 1], tb[:, 0], h - 1 - tb[:, 1]], axis=1)
        out.append(rows[(rows[:, :2] != rows[:, 2:]).any(axis=1)])
    if not out:
        return np.zeros((0, 4), np.int32)
    return np.unique(np.concatenate(out), axis=0).astype(np.int32)


def stitch(image: np.ndarray, pairs: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Moves each seam pair towards its average: every texel in a pair takes the mean of
    the averages of its pairs, `iterations` times (a texel can pair with two texels on the
    other side when the texel grids are offset, so one pass is not enough)."""
    out = np.array(image, dtype=np.float32, copy=True)
    if len(pairs) == 0:
        return out
    h, w = out.shape[:2]
    vals = out.reshape(h * w, -1)
    a = pairs[:, 1].astype(np.int64) * w + pairs[:, 0]
    b = pairs[:, 3].astype(np.int64) * w + pairs[:, 2]
    both = np.concatenate([a, b])
    count = np.bincount(both, minlength=h * w)
    touched = count > 0
    for _ in range(int(iterations)):
        mean = 0.5 * (vals[a].astype(np.float64) + vals[b])
        acc = np.zeros(vals.shape, np.float64)
        np.add.at(acc, both, np.concatenate([mean, mean]))
        vals[touched] = (acc[touched] / count[touched, None]).astype(np.float32)
    return out


# ----------------------------------------------------------------------------------------
# One call for the bake


def evaluate_adaptive(samples: TexelSamples, points: np.ndarray, normals: np.ndarray,
                      evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray], stride: int,
                      tolerance: float, floor: float = 0.02) -> tuple[np.ndarray, dict]:
    """Per-sample values of a page from `evaluate(points, normals, texel)` called on fewer texels:
    the texel lattice is evaluated coarse to fine, and a texel between already evaluated ones is
    interpolated from them where the light agrees, else evaluated itself.

    The first pass evaluates every texel whose column and row are multiples of `stride` (a power
    of two), together with every texel that cannot be interpolated: a conservative texel (its
    one sample is the closest point of a touching triangle, not on the lattice) and a texel
    whose samples lie on more than one mesh or plane. Then for h = stride/2, ..., 1 each texel
    at a multiple of h not yet valued has its parents on the 2h lattice: the two texels h
    away along the row or column (an edge midpoint) or the four diagonal ones (a cell centre).
    It takes their mean (bilinear interpolation on the lattice) when all of them
    - exist (covered by the page) and are interpolable texels of the same mesh and normal,
    - lie where an affine chart puts them: the texel's surface point (the mean of its samples)
      is their mean point, within 1e-3 of its distance to them (two charts side by side in
      the page but apart in space fail this, and so does a texel the chart covers only in
      part, whose samples' mean is off its centre),
    - and either agree: per colour channel (the first three values), max - min <= tolerance x
      max(their mean, floor x the page's mean of the first pass), or vary smoothly: the
      valued lattice texels on the lines through them (two steps on from each parent, along
      the row or column; for a cell centre both rows and both columns) give second differences
      whose linear-interpolation error, |second difference| / 8 per line (the larger of a
      row's two, a row's plus a column's for a centre), is within the same bound. A gradient
      is interpolated however steep; a shadow edge between the parents shows as a second
      difference as large as the edge itself;
    otherwise it is evaluated. What is missed is light that varies between lattice points by
    more than the tolerance without showing at them (a shadow narrower than 2 h texels whose
    ends all fall between them): `stride` bounds that size. Deterministic: the texels each
    pass evaluates depend only on the page and the values, not on threads.

    Returns ((K, C) values per sample, as `evaluate` on every sample would; an interpolated
    texel's samples all take its value) and counts of texels: "evaluated", "interpolated", and
    why texels were evaluated: "lattice" (the first pass), "not_interpolable", "apart" (a parent
    missing, of another mesh, plane or chart) and "disagree" (the parents' values)."""
    stride = int(stride)
    if stride < 1 or stride & (stride - 1):
        raise ValueError(f"stride must be a power of two, not {stride}")
    tex = np.asarray(samples.texel, dtype=np.int64)
    n_tex = len(samples.x)
    x = np.asarray(samples.x, dtype=np.int64)
    y = np.asarray(samples.y, dtype=np.int64)
    count = np.bincount(tex, minlength=n_tex).astype(np.float64)
    first = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)  # samples are grouped by texel
    centre = np.stack([np.bincount(tex, points[:, c], minlength=n_tex) for c in range(3)], 1) / count[:, None]
    nrm = normals[first]
    mesh = np.asarray(samples.mesh)[first]
    same = (np.asarray(samples.mesh) == mesh[tex]) & (np.abs(normals - nrm[tex]).max(axis=1) < 1e-9)
    interpolable = (np.bincount(tex, (~same).astype(np.float64), minlength=n_tex) == 0) & ~samples.conservative
    # texel lookup by position, sorted keys rather than an (H, W) array (a 4096 page's would be
    # 128 MB)
    key = y * samples.width + x
    by_key = np.argsort(key, kind="stable")
    sorted_key = key[by_key]

    def texel_at(px: np.ndarray, py: np.ndarray) -> np.ndarray:
        """The texel at each page position (column px, row py from the top), -1 where the
        position is off the page or no texel is covered there."""
        inside = (px >= 0) & (px < samples.width) & (py >= 0) & (py < samples.height)
        k = np.where(inside, py * samples.width + px, -1)
        pos = np.minimum(np.searchsorted(sorted_key, k), max(n_tex - 1, 0))
        return np.where(inside & (sorted_key[pos] == k), by_key[pos], -1)

    values = None
    texel_value = None
    done = np.zeros(n_tex, bool)
    own = np.zeros(n_tex, bool)  # evaluated itself (its samples keep their own values)
    evaluated = 0

    def run(which: np.ndarray) -> None:
        nonlocal values, texel_value, evaluated
        if not len(which):
            return
        mark = np.zeros(n_tex, bool)
        mark[which] = True
        sel = np.nonzero(mark[tex])[0]
        v = np.asarray(evaluate(np.ascontiguousarray(points[sel]), np.ascontiguousarray(normals[sel]), tex[sel]),
                       dtype=np.float64)
        v = v[:, None] if v.ndim == 1 else v
        if values is None:
            values = np.zeros((len(tex), v.shape[1]))
            texel_value = np.zeros((n_tex, v.shape[1]))
        values[sel] = v
        for ch in range(v.shape[1]):
            texel_value[which, ch] = (np.bincount(tex[sel], v[:, ch], minlength=n_tex) / count)[which]
        done[which] = True
        own[which] = True
        evaluated += len(which)

    lattice = (x % stride == 0) & (y % stride == 0)
    run(np.nonzero(lattice | ~interpolable)[0])
    why = {"lattice": int(lattice.sum()), "not_interpolable": int((~lattice & ~interpolable).sum()), "apart": 0,
           "disagree": 0}
    if values is None:
        return np.zeros((0, 3)), {"evaluated": 0, "interpolated": 0, **why}
    scale = floor * np.maximum(texel_value[done, :3].mean(axis=0), 1e-300)
    interpolated = 0

    def same_surface(q: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Per row of texels q (-1: none), whether every one is valued, interpolable and of the
        mesh and normal of texel c."""
        ok = (q >= 0).all(axis=1)
        q = np.where(q >= 0, q, 0)
        ok &= done[q].all(axis=1) & interpolable[q].all(axis=1)
        ok &= (mesh[q] == mesh[c, None]).all(axis=1)
        return ok & (np.abs(nrm[q] - nrm[c, None, :]).max(axis=2) < 1e-9).all(axis=1)

    def line_curvature(c: np.ndarray, ox: int, oy: int, dx: int, dy: int) -> tuple[np.ndarray, np.ndarray]:
        """Along the line through texel position (x[c] + ox, y[c] + oy) in direction (dx, dy):
        the four lattice texels at -3, -1, 1 and 3 steps, whether they are usable (valued,
        interpolable, the texel's mesh and normal, equally spaced on a straight line in
        space), and |second difference| / 8 per colour channel, the larger of the two
        (points 1-3 and 2-4): the error of the linear interpolation at the line's centre for
        light with that curvature."""
        k = np.array([-3, -1, 1, 3])
        q = texel_at(x[c, None] + ox + k * dx, y[c, None] + oy + k * dy)
        usable = same_surface(q, c)
        q = np.where(q >= 0, q, 0)
        pq = centre[q]
        step = np.linalg.norm(pq[:, 2] - pq[:, 1], axis=1)
        for a in (0, 1):
            usable &= np.linalg.norm(pq[:, a] - 2 * pq[:, a + 1] + pq[:, a + 2], axis=1) <= 1e-3 * step
        v = texel_value[q][:, :, :3]
        d = np.maximum(np.abs(v[:, 0] - 2 * v[:, 1] + v[:, 2]), np.abs(v[:, 1] - 2 * v[:, 2] + v[:, 3]))
        return usable, d / 8.0

    h = stride // 2
    while h >= 1:
        cand = np.nonzero(~done & (x % h == 0) & (y % h == 0))[0]
        mx, my = x[cand] % (2 * h) != 0, y[cand] % (2 * h) != 0
        redo = []
        for kind, offsets in (((mx & ~my), ((-h, 0), (h, 0))), ((~mx & my), ((0, -h), (0, h))),
                              ((mx & my), ((-h, -h), (h, -h), (-h, h), (h, h)))):
            c = cand[kind]
            if not len(c):
                continue
            dx = np.array([o[0] for o in offsets])
            dy = np.array([o[1] for o in offsets])
            pid = texel_at(x[c, None] + dx, y[c, None] + dy)
            ok = same_surface(pid, c) & interpolable[c]
            p = np.where(pid >= 0, pid, 0)
            mean_point = centre[p].mean(axis=1)
            reach = np.linalg.norm(centre[p] - centre[c, None, :], axis=2).mean(axis=1)
            ok &= np.linalg.norm(centre[c] - mean_point, axis=1) <= 1e-3 * reach
            why["apart"] += int((~ok).sum())
            vp = texel_value[p]
            mean = vp.mean(axis=1)
            allowed = tolerance * np.maximum(mean[:, :3], scale)
            spread = vp[:, :, :3].max(axis=1) - vp[:, :, :3].min(axis=1)
            agree = (spread <= allowed).all(axis=1)
            if len(offsets) == 2:  # an edge midpoint: the line through its parents
                usable, err = line_curvature(c, 0, 0, offsets[1][0], offsets[1][1])
            else:  # a cell centre: the two rows and the two columns through its parents
                u1, e1 = line_curvature(c, 0, -h, h, 0)
                u2, e2 = line_curvature(c, 0, h, h, 0)
                u3, e3 = line_curvature(c, -h, 0, 0, h)
                u4, e4 = line_curvature(c, h, 0, 0, h)
                usable, err = u1 & u2 & u3 & u4, np.maximum(e1, e2) + np.maximum(e3, e4)
            smooth = usable & (err <= allowed).all(axis=1)
            why["disagree"] += int((ok & ~agree & ~smooth).sum())
            ok &= agree | smooth
            take = c[ok]
            texel_value[take] = mean[ok]
            done[take] = True
            interpolated += len(take)
            redo.append(c[~ok])
        run(np.concatenate(redo) if redo else np.zeros(0, np.int64))
        h //= 2
    taken = ~own[tex]
    values[taken] = texel_value[tex[taken]]
    return values, {"evaluated": evaluated, "interpolated": interpolated, **why}


def bake_page(atlas: Atlas, page: int,
              evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray],
              supersample: int = 2, dilate_texels: int | None = None,
              stitch_iterations: int = 4, crease_angle: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """rasterize -> evaluate(points, normals, mesh, triangle) -> (K, C) values -> resolve
    -> stitch seams -> dilate (by the atlas padding unless told). The callback is where the
    engine answers (irradiance at points, say); this module never calls the engine."""
    samples = rasterize(atlas, page, supersample)
    points, normals = sample_points(samples, atlas.geometry)
    values = np.asarray(evaluate(points, normals, samples.mesh, samples.triangle))
    image, mask = resolve(samples, values)
    if stitch_iterations > 0:
        image = stitch(image, seam_pairs(atlas, page, crease_angle), stitch_iterations)
    ring = atlas.padding if dilate_texels is None else dilate_texels
    return dilate(image, mask, max(int(ring), 1)), mask
