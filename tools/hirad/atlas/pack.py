"""Packing: an author's islands moved rigidly, xatlas's packer for generated charts, and mesh blocks onto pages by a skyline packer."""

from __future__ import annotations

import math

import numpy as np
from .base import _Block, _areas2, _density
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


# ----------------------------------------------------------------------------------------
# Pages: every island of every mesh packed together by xatlas


def _snap_islands(islands: list[np.ndarray]) -> list[np.ndarray]:
    """Each island moved to the origin with extents that xatlas keeps.

    xatlas's packer rounds every chart's extents up to whole texels (ceil) and stretches the
    chart to them. Our islands already have whole-texel extents up to float noise (xatlas
    made them, or we did), and ceil(5.0001) = 6 would stretch a chart by a texel; so an
    extent within 1e-3 texel of an integer is snapped to it and shrunk by one part in 1e6,
    which xatlas's ceil and stretch turn back into exactly that integer."""
    out = []
    for uv in islands:
        lo = uv.reshape(-1, 2).min(axis=0)
        ext = uv.reshape(-1, 2).max(axis=0) - lo
        near = np.rint(ext)
        target = np.where((np.abs(ext - near) < 1e-3) & (near >= 1), near, ext)
        scale = np.where(ext > 0, target / np.where(ext > 0, ext, 1.0), 1.0) * (1 - 1e-6)
        out.append((uv - lo) * scale)
    return out


def _pot_ceil(n: float) -> int:
    return 1 << max(0, math.ceil(math.log2(max(float(n), 1.0))))


def _pot_floor(n: float) -> int:
    return 1 << max(0, math.floor(math.log2(max(float(n), 1.0))))


# Share of a full page that xatlas's packer fills with footprints (covered texels dilated by
# its padding, see _footprint). Only used to choose page sizes; what fits is always decided
# by packing.
_UTILISATION = 0.9
_MIN_PAGE = 16
_FULL = 0.98  # footprints a page is offered, over its area inside the margin
_GROW_TRIES = 6  # units tried in a settled page's holes


def _pack_units(units: list[tuple[list[np.ndarray], bool]], max_page: int, padding: int, margin: int,
                fallback: list[np.ndarray | None] | None = None):
    """Packs units onto square power-of-two pages of at most max_page texels.

    A unit is (islands, rigid): a mesh's charts (texel units, v up), which xatlas may place
    apart from one another but only all on one page (an engine gives a renderer one
    lightmap index), or, rigid, a rectangle given as one island (an instance's or an
    authored layout's bounding box) that is only translated.

    xatlas's packer places charts, largest first, each at a free spot of its rasterised
    footprint dilated by the padding, and opens a new page when a chart fits nowhere; left
    to itself it spreads a mesh's small charts over every page. So the units are put on
    pages by us and each page is packed by xatlas alone: a page's size S is the power of two
    at or below sqrt(remaining footprint / _UTILISATION) (rounded down, so the page
    overflows and fills up), at least what the largest remaining unit needs; units join it,
    largest first, while their footprints (_footprint) stay within _FULL of the page; if
    xatlas spills charts over, the smallest spilled units leave for a later page, until one
    page holds them. Every page but the last few is nearly full; the last are small.
    Charts keep ceil(padding/2) texels from the page edges (`margin`), so the padding also
    holds across a wrapping edge.

    A unit that does not fit a max_page page even alone (xatlas's packer fills a bounded
    page less tightly than it packed the mesh's own block) is packed as its `fallback`
    instead, a rectangle (one island: the block the mesh was charted into, which fits by
    construction).

    Returns (page size per page, per unit its page, per unit its islands' uv in page
    texels, the units packed as their fallback)."""
    pp = (padding + 1) // 2
    snapped = [_snap_islands(isl) for isl, _ in units]
    feet = [np.array([_footprint(u, pp) for u in isl], float) for isl in snapped]
    foot = np.array([float(f.sum()) for f in feet])
    ext = [np.array([u.reshape(-1, 2).max(axis=0) for u in isl]) if isl else np.zeros((0, 2)) for isl in snapped]
    for e in ext:
        if len(e) and float(e.max()) > max_page - 2 * margin - 1:
            raise ValueError(f"a chart of {float(e.max()):.0f} texels cannot fit a {max_page} page")
    need = np.array([max(_MIN_PAGE, _pot_ceil(float(e.max()) + 2 + 2 * margin) if len(e) else 1,
                         _pot_ceil(math.sqrt(f / _UTILISATION) + 2 * margin)) for e, f in zip(ext, foot)])
    need = np.minimum(need, max_page)
    units = list(units)
    fell_back: set[int] = set()
    sizes: list[int] = []
    unit_page = [-1] * len(units)
    unit_uv: list[list[np.ndarray] | None] = [None] * len(units)
    remaining = sorted((i for i in range(len(units)) if len(snapped[i])), key=lambda i: (-need[i], -foot[i], i))
    while remaining:
        remaining.sort(key=lambda i: (-need[i], -foot[i], i))
        total = float(foot[remaining].sum())
        size = int(min(max_page, max(_pot_floor(math.sqrt(total / _UTILISATION) + 2 * margin),
                                     int(need[remaining[0]]))))
        room = (size - 2 * margin) ** 2 * _FULL
        members, used = [], 0.0
        for i in remaining:
            if need[i] <= size and (not members or used + foot[i] <= room):
                members.append(i)
                used += foot[i]
        fits = False
        while True:  # smallest spilled unit out, one at a time, until one page holds them
            pages, uvs = _xatlas_pack_pages([snapped[i] for i in members], [units[i][1] for i in members],
                                            size - 2 * margin, pp)
            fits = all(max(p) == 0 for p in pages)
            if fits or len(members) == 1:
                break
            spilled = [(foot[i], -i, i) for k, i in enumerate(members) if max(pages[k]) != 0 and k > 0]
            drop = min(spilled)[2] if spilled else members[-1]  # the first spilled: a companion less
            members = [i for i in members if i != drop]
        if not fits:  # the first unit alone needs a larger page
            i = members[0]
            if size < max_page:
                need[i] = 2 * size
            elif fallback is not None and fallback[i] is not None and i not in fell_back:
                fell_back.add(i)
                units[i] = ([fallback[i]], True)
                snapped[i] = _snap_islands([fallback[i]])
                feet[i] = np.array([_footprint(snapped[i][0], pp)], float)
                foot[i] = float(feet[i].sum())
            else:
                raise ValueError(f"a mesh's charts do not fit one {max_page} page")
            continue
        left = room - float(foot[members].sum())
        tries = 0
        for i in sorted((i for i in remaining if i not in set(members)), key=lambda i: (-foot[i], i)):
            if tries >= _GROW_TRIES:
                break
            if need[i] > size or foot[i] > left:
                continue
            tries += 1  # a unit more in the holes, if xatlas finds room
            more = members + [i]
            p2, u2 = _xatlas_pack_pages([snapped[j] for j in more], [units[j][1] for j in more],
                                        size - 2 * margin, pp)
            if all(max(p) == 0 for p in p2):
                members, pages, uvs, left = more, p2, u2, left - foot[i]
        for k, i in enumerate(members):
            unit_page[i] = len(sizes)
            unit_uv[i] = [u + margin for u in uvs[k]]
        sizes.append(size)
        done = set(members)
        remaining = [i for i in remaining if i not in done]
    _merge_last_pages(sizes, unit_page, unit_uv, snapped, units, foot, max_page, margin, pp)
    return sizes, unit_page, unit_uv, fell_back


def _merge_last_pages(sizes, unit_page, unit_uv, snapped, units, foot, max_page, margin, pp) -> None:
    """The last pages the rule above opens are small and can be many (a small scene: five
    64 pages). The trailing k pages (largest k first) are packed again onto one page of the
    power of two their footprints ask for, kept when that page is no larger in texels than
    the k pages were: fewer pages (textures, lightmap indices) for no more memory. In place."""
    n = len(sizes)
    for k in range(n, 1, -1):
        tail = list(range(n - k, n))
        members = [i for i in range(len(unit_page)) if unit_page[i] in tail]
        area = sum(sizes[j] ** 2 for j in tail)
        size = min(max_page, _pot_ceil(math.sqrt(float(foot[members].sum()) / _UTILISATION) + 2 * margin))
        size = max(size, max(sizes[j] for j in tail))
        if size * size > area:
            continue
        pages, uvs = _xatlas_pack_pages([snapped[i] for i in members], [units[i][1] for i in members],
                                        size - 2 * margin, pp)
        if not all(max(p) == 0 for p in pages):
            continue
        for m, i in enumerate(members):
            unit_page[i] = n - k
            unit_uv[i] = [u + margin for u in uvs[m]]
        del sizes[n - k:]
        sizes.append(size)
        return


def _split_to_fit(uv: np.ndarray, tris: list[np.ndarray], padding: int, margin: int,
                  poly: np.ndarray | None = None) -> list[np.ndarray]:
    """A mesh's charts (triangle sets `tris` of block uv `uv`, texel units) cut where one
    chart alone would need a larger page than the whole mesh's footprint does.

    A page holds a mesh whole, so a long chart (a 21 m wall at 16 texels/m is 341 texels)
    forces a page of the next power of two (512) even when the mesh's texels fill a quarter
    of it; the page then stays mostly empty or holds everything else at low fill. Any set of
    a chart's triangles, moved rigidly, is a valid island, so such a chart is halved across
    its longer side, by triangle centroids, until every piece fits half the page the
    footprint asks for ((S - 2 margin) / 2 - 2 texels, S = _pot_ceil(sqrt(footprint /
    _UTILISATION))): pieces of up to a whole page's width could still not share it (two
    170 x 160 pieces do not fit a 254 x 254 square). The cuts are new seams (stitched like
    xatlas's); a single triangle is never cut, and with `poly` (the source polygon of each
    triangle) neither is a polygon: cuts go by polygon centres, between polygons."""
    pp = (padding + 1) // 2
    if not tris:
        return tris
    foot = sum(_footprint(_snap_islands([uv[t]])[0], pp) for t in tris)
    size = max(_MIN_PAGE, _pot_ceil(math.sqrt(foot / _UTILISATION) + 2 * margin))
    longest = max(float(np.ptp(uv[t].reshape(-1, 2), axis=0).max()) for t in tris)
    if _pot_ceil(longest + 2 + 2 * margin) <= size:  # no chart asks for more than the mesh
        return tris
    cap = (size - 2 * margin) // 2 - 2
    from .charts import uv_islands

    out = []
    for chart in tris:
        pieces, work = [], [chart]
        while work:
            t = work.pop()
            pts = uv[t].reshape(-1, 2)
            ext = np.ptp(pts, axis=0)
            if float(ext.max()) <= cap:
                pieces.append(t)
                continue
            group = np.arange(len(t)) if poly is None else np.unique(poly[t], return_inverse=True)[1].reshape(-1)
            if group.max() == 0:  # one triangle (or polygon) longer than the cap: the chart stays whole
                pieces = None
                break
            axis = int(np.argmax(ext))
            centre = uv[t].mean(axis=1)[:, axis]
            centre = (np.bincount(group, centre) / np.bincount(group))[group]  # per polygon
            low = centre < pts[:, axis].min() + 0.5 * float(ext[axis])
            if low.all() or not low.any():
                centres = np.bincount(group, centre) / np.bincount(group)
                order = np.argsort(centres, kind="stable")
                low = np.isin(group, order[:len(order) // 2])
            work += [t[~low], t[low]]
        if pieces is None or len(pieces) == 1:
            out.append(chart)
            continue
        for t in pieces:  # xatlas would pack the UV-disconnected parts of a piece apart
            part = uv_islands(uv[t])
            out += [t[part == k] for k in range(int(part.max()) + 1)]
    return sorted(out, key=lambda t: int(t[0]))


def _footprint(uv: np.ndarray, pp: int) -> int:
    """Texels an island takes in xatlas's packer: its covered texels (bounding box starting
    at a texel centre, as xatlas places it) dilated by pp texels over the 8 neighbours, as
    xatlas dilates its chart images; the dilated images of two charts never overlap."""
    from scipy.ndimage import binary_dilation

    ext = uv.reshape(-1, 2).max(axis=0)
    w, h = (np.ceil(ext).astype(int) + 1 + 2 * pp).tolist()
    _, lin = _covered_texels(uv + 0.5 + pp, w, h)
    mask = np.zeros(w * h, bool)
    mask[lin] = True
    if pp > 0:
        mask = binary_dilation(mask.reshape(h, w), np.ones((3, 3), bool), iterations=pp)
    return int(mask.sum())


def _place_degenerate(units, islands, bounds, page, uvt) -> None:
    """Islands xatlas's packer leaves off every page, put on one. In place.

    The packer skips a chart of no UV area (a triangle of no area in space charts to a
    point; the kitchen has hundreds): it gets no page (-1) and a uv at the origin. Such an
    island covers no texel, so it may sit anywhere on its mesh's page; it is put, as a
    point, at the centroid of the mesh's largest placed triangle, so a renderer that still
    interpolates across it reads a texel of the mesh's own light. An island of a texel or
    more left off is the packer failing, not a degenerate chart, and is an error."""
    k = 0
    for unit in units:
        span = slice(bounds[k], bounds[k + len(unit)])
        lost = page[span] < 0
        if lost.any():
            area = np.zeros(len(unit))
            for j in range(len(unit)):
                lo, hi = bounds[k + j], bounds[k + j + 1]
                if (page[lo:hi] < 0).any():
                    area[j] = float(np.abs(_areas2(islands[k + j])).sum())
            if area.max() >= 1.0:
                raise RuntimeError(f"xatlas's packer left an island of {area.max():.1f} texels off every page")
            tri = np.flatnonzero(~lost)
            if len(tri):
                best = tri[int(np.argmax(np.abs(_areas2(uvt[span][tri]))))]
                at, on = uvt[span][best].mean(axis=0), int(page[span][best])
            else:  # every island of the mesh is degenerate: its page is the first
                at, on = np.array([0.5, 0.5]), 0
            where = np.flatnonzero(lost) + bounds[k]
            uvt[where] = at
            page[where] = on
        k += len(unit)


def _xatlas_pack_pages(units: list[list[np.ndarray]], rigid: list[bool], resolution: int, padding: int):
    """One xatlas pack of every island of the units (texel units, each at the origin) onto
    pages of resolution^2 texels: (per unit its islands' pages, per unit its islands' uv in
    page texels). Charts turn by 90 degrees (xatlas swaps u and v) unless a rigid unit is
    in the pack: a rectangle's scale/offset cannot express the swap."""
    import xatlas

    islands = [u for unit in units for u in unit]
    tri_island = np.concatenate([np.full(len(u), k, np.int64) for k, u in enumerate(islands)])
    corners = np.concatenate(islands).reshape(-1, 2)
    # One vertex per (corner uv, island); the island as material keeps islands apart.
    keys = np.concatenate([corners, np.repeat(tri_island, 3)[:, None].astype(np.float64)], axis=1)
    verts, inverse = np.unique(keys, axis=0, return_inverse=True)
    a = xatlas.Atlas()
    a.add_uv_mesh(verts[:, :2].astype(np.float32), inverse.reshape(-1, 3).astype(np.uint32),
                  tri_island.astype(np.uint32).reshape(-1, 1))
    po = xatlas.PackOptions()
    po.texels_per_unit = 1.0
    po.padding = int(padding)
    po.resolution = int(resolution)
    po.blockAlign = False
    po.bilinear = False
    po.rotate_charts = not any(rigid)
    po.rotate_charts_to_axis = False
    po.bruteForce = True  # every position tried: a page filled to 0.9 packs where random tries fail
    a.generate(xatlas.ChartOptions(), po)
    _, idx, uv = a[0]
    page_of_vertex, _ = a.get_mesh_vertex_assignment(0)
    idx = idx.astype(np.int64)
    if idx.shape != (len(tri_island), 3):
        raise RuntimeError("xatlas's packer dropped or reordered triangles")
    w, h = int(a.width), int(a.height)
    if (w, h) != (resolution, resolution):
        raise RuntimeError(f"xatlas made {w}x{h} pages for {resolution}")
    uvt = uv.astype(np.float64)[idx] * float(resolution)
    page = page_of_vertex.astype(np.int64)[idx[:, 0]]
    page[page == 0xFFFFFFFF] = -1
    bounds = np.cumsum([0] + [len(u) for u in islands])
    _place_degenerate(units, islands, bounds, page, uvt)
    out_pages, out_uv, k = [], [], 0
    for unit in units:
        out_pages.append([int(page[bounds[k + j]]) for j in range(len(unit))])
        placed = [uvt[bounds[k + j]:bounds[k + j + 1]] for j in range(len(unit))]
        for j, (src, dst) in enumerate(zip(unit, placed)):  # xatlas only moves (and turns) islands
            e_in = np.sort(np.ceil(src.reshape(-1, 2).max(axis=0) - 1e-9))
            e_out = np.sort(np.ptp(dst.reshape(-1, 2), axis=0))
            if np.abs(e_in - e_out).max() > 1e-2 and (np.ptp(src.reshape(-1, 2), axis=0) > 0).all():
                raise RuntimeError(f"xatlas resized an island ({e_in} -> {e_out})")
        out_uv.append(placed)
        k += len(unit)
    return out_pages, out_uv
