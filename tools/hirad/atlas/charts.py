"""Charting: each mesh's lightmap UVs, its own set when usable (non-overlapping, not folded), else xatlas charts; one forked child per atlas isolates xatlas."""

from __future__ import annotations

import math
import os
import pickle
import signal
from typing import Hashable, Literal, Sequence

import numpy as np
from .base import Atlas, Mesh, MeshLayout, _Block, _CHART_COST, _CHART_TEXELS, _CHART_TRIANGLES, _FREE_TRIANGLES, _NO_CHART, _areas2, _areas3, _density
from .pack import _island_gap, _pack_islands, _pack_units, _repack_islands, _split_to_fit
from .texels import _covered_texels


# ----------------------------------------------------------------------------------------
# Building the atlas


def build_atlas(meshes: Sequence[Mesh], texels_per_metre: float, padding: int, max_size: int, *,
                existing_uvs: Sequence[np.ndarray | None] | None = None,
                names: Sequence[str] | None = None,
                existing_layout: Literal["keep", "repack"] = "keep",
                shrink_pages: bool = True,
                prototypes: Sequence[Hashable | None] | None = None,
                chart_cost: float = _CHART_COST,
                polygons: Sequence[np.ndarray | None] | None = None) -> Atlas:
    """Lays every mesh out on square power-of-two pages of at most max_size texels a side.

    Charts: a mesh without UVs gets charts from xatlas at `texels_per_metre`; a mesh with
    its own lightmap UVs (per triangle corner, (M, 3, 2)) keeps them, scaled by one factor
    to the requested density (3D area over UV area), either where the author put them
    (`existing_layout="keep"`: the layout is one rectangle on a page and `scale_offset` maps
    the author's UVs to it, as Unity's lightmapScaleOffset) or island by island
    (`"repack"`, tighter; scale/offset is the identity).

    Instances: `prototypes` gives each mesh a hashable prototype id or None. Meshes with the
    same id must have the same triangles (same order, corners and topology) in their own
    space, their positions differing by a rigid motion and a uniform scale. They share ONE
    local layout, charted once from the first member (at the density the smallest member
    needs, so no member's charts are scaled down), and each member gets its own rectangle
    on a page, scaled by its size relative to the smallest (side ratio
    s_i / s_min, s_i = sqrt(area_i / area_first)), so every member has the requested
    density. When the members' sizes differ, the shared layout is charted with one more
    texel of padding on each side: scaling by s_i / s_min >= 1 moves charts off the texel
    grid, and a chart's conservative coverage can then grow by one texel on either side
    (see _instance_units).

    Pages: every mesh's charts go onto pages together (xatlas's bitmap packer: it places
    every chart in the first free spot of its rasterised footprint, dilated by the padding),
    a mesh's charts all on one page (a renderer has one lightmap index). Page sizes are
    powers of two chosen by `_pack_units` so every page but the last is nearly full and the
    last is small; `shrink_pages=False` makes every page max_size.

    `padding` is the least number of empty texels between texels covered by different
    charts, and between different meshes; pages keep ceil(padding/2) texels at their
    borders so the rule also holds across a wrapping edge. Chart growth is bounded on large
    meshes (see _CHART_TEXELS: xatlas's cost is super-quadratic in the faces of one chart);
    `chart_cost` is xatlas's maxCost (see base._CHART_COST: larger means fewer, slightly
    more stretched charts, less padding). A chart longer than the page its mesh's footprint
    needs is cut along its triangles (pack._split_to_fit).

    Polygons: `polygons` gives, per mesh, the source polygon of each triangle (or None: each
    triangle its own). A polygon's triangles always end up in one chart, connected in UV
    space: a faceVarying UV set on the author's polygons (one UV per polygon corner) can
    only express that. xatlas charts triangles and may cut a polygon along its diagonal (a
    large quad when chart growth is bounded, a polygon at a cost boundary); such polygons
    are taken out of their charts and each charted whole by projection onto its plane, and
    chart cuts (pack._split_to_fit) go between polygons.

    Same inputs, same bits: xatlas's packer runs on one thread with its fixed random seed.
    """
    if not texels_per_metre > 0:
        raise ValueError("texels_per_metre must be positive")
    if int(padding) != padding or padding < 0:
        raise ValueError("padding must be a non-negative integer")
    padding = int(padding)
    margin = (padding + 1) // 2
    page_max = 1 << int(math.floor(math.log2(max(int(max_size), 1))))  # pages are powers of two
    limit = page_max - 2 * margin
    if limit < 4:
        raise ValueError(f"max_size {max_size} leaves no room with padding {padding}")
    if existing_uvs is not None and len(existing_uvs) != len(meshes):
        raise ValueError("existing_uvs needs one entry (or None) per mesh")
    names = [f"mesh_{i}" for i in range(len(meshes))] if names is None else list(names)
    if len(names) != len(meshes):
        raise ValueError("names needs one entry per mesh")
    if prototypes is not None and len(prototypes) != len(meshes):
        raise ValueError("prototypes needs one entry (an id or None) per mesh")
    if polygons is not None and len(polygons) != len(meshes):
        raise ValueError("polygons needs one entry (an array or None) per mesh")

    geometry: list[Mesh] = [(np.asarray(p, dtype=np.float64).reshape(-1, 3),
                             np.asarray(t, dtype=np.int64).reshape(-1, 3)) for p, t in meshes]
    if polygons is not None:
        polygons = [None if q is None else np.asarray(q, dtype=np.int64).reshape(-1) for q in polygons]
        for i, q in enumerate(polygons):
            if q is not None and len(q) != len(geometry[i][1]):
                raise ValueError(f"{names[i]}: polygons has {len(q)} entries for {len(geometry[i][1])} triangles")
    groups = _prototype_groups(geometry, prototypes, names)
    warnings: list[str] = []
    if page_max != int(max_size):
        warnings.append(f"max_size {max_size} is not a power of two: pages are at most {page_max}")
    # Charting and packing in one child process (see _isolated): one fork per atlas.
    triangles = sum(len(t) for _, t in geometry)
    sizes, layouts, more = _isolated(_layout_all, geometry, existing_uvs, names, float(texels_per_metre),
                                     padding, page_max, existing_layout, groups, bool(shrink_pages),
                                     float(chart_cost), polygons, scale=max(1.0, triangles / _ATTEMPT_TRIANGLES))
    warnings += more
    for i, layout in enumerate(layouts):
        layout.prototype = None if prototypes is None else prototypes[i]
    atlas = Atlas([(s, s) for s in sizes], layouts, [], float(texels_per_metre), padding, names, geometry,
                  warnings)
    for k, s in enumerate(sizes):
        uv, mesh_of, _ = atlas.page_texel_uvs(k)
        tri, lin = _covered_texels(uv, s, s)
        atlas.fill.append(len(np.unique(lin)) / float(s * s))
        for mi in atlas.page_meshes(k):
            mine = mesh_of[tri] == mi
            problem = _overlap_check(uv[mesh_of == mi], layouts[mi].charts, len(np.unique(lin[mine])))
            if problem:
                warnings.append(f"{names[mi]}: {problem}")
    return atlas


def _prototype_groups(geometry, prototypes, names) -> list[tuple[list[int], list[float]]]:
    """Members of each prototype (first member first) and their linear sizes relative to
    the first member, s_i = sqrt(area_i / area_first); checks that the members share the
    first member's triangles."""
    if prototypes is None:
        return []
    order: dict = {}
    for i, pid in enumerate(prototypes):
        if pid is not None:
            order.setdefault(pid, []).append(i)
    groups = []
    for pid, members in order.items():
        first = members[0]
        a0 = float(_areas3(*geometry[first]).sum())
        scales = []
        for i in members:
            p, t = geometry[i]
            if not np.array_equal(t, geometry[first][1]) or len(p) != len(geometry[first][0]):
                raise ValueError(f"{names[i]}: prototype {pid!r} member has triangles other than "
                                 f"its first member {names[first]}'s")
            a = float(_areas3(p, t).sum())
            scales.append(math.sqrt(a / a0) if a0 > 0 else 1.0)
        groups.append((members, scales))
    return groups


def _layout_all(geometry, existing_uvs, names, texels_per_metre, padding, page_max, existing_layout, groups,
                shrink_pages, chart_cost=None, polygons=None):
    """Every mesh's charts, then all of them onto pages: (page sizes, MeshLayouts, warnings).
    Run through _isolated: xatlas is called here."""
    margin = (padding + 1) // 2
    limit = page_max - 2 * margin
    member_of = {i: (g, k) for g, (members, _) in enumerate(groups) for k, i in enumerate(members)}
    triangles = sum(len(t) for _, t in geometry)
    workers = len(os.sched_getaffinity(0)) if triangles >= _PARALLEL_TRIANGLES else 1
    blocks, warnings = _mesh_blocks(geometry, existing_uvs, names, texels_per_metre, padding, limit,
                                    existing_layout, page_max, member_of, groups, chart_cost, polygons,
                                    workers=workers)
    units, owners, fallback = [], [], []  # owners: (mesh, kind, data)
    for i, b in enumerate(blocks):
        if b is None or b.width == 0:
            continue
        if i in member_of:
            continue
        if not (b.charts >= 0).any():  # no triangle with area: no texels, no page
            warnings.append(f"{names[i]}: no triangle with area; it gets no lightmap")
            continue
        if b.source == "generated":
            tris = [np.nonzero(b.charts == c)[0] for c in np.unique(b.charts[b.charts >= 0])]
            tris = _split_to_fit(b.uv, tris, padding, margin, None if polygons is None else polygons[i])
            units.append(([b.uv[t] for t in tris], False))
            owners.append((i, "free", tris))
            fallback.append(_proxy(b.uv[b.charts >= 0]) if (b.charts >= 0).any() else None)
        else:  # an authored layout, kept or repacked: one rectangle
            units.append(([_proxy(b.uv[b.charts >= 0] if (b.charts >= 0).any() else b.uv)], True))
            owners.append((i, "rect", 1.0))
            fallback.append(None)
    for g, (members, scales) in enumerate(groups):
        b = blocks[members[0]]
        if b is None or b.width == 0:
            continue
        if not (b.charts >= 0).any():
            warnings += [f"{names[i]}: no triangle with area; it gets no lightmap" for i in members]
            continue
        s_min = min(scales)
        for i, s in zip(members, scales):
            k = s / s_min
            lo, ext = _content_box(b)
            if float((ext * k).max()) > limit - 1:  # the member alone is larger than a page
                k = (limit - 1) / float(ext.max()) * (1 - 1e-6)
                warnings.append(f"{names[i]}: scaled down to fit one {page_max} page")
            units.append(([_proxy(None, ext * k)], True))
            owners.append((i, "instance", k))
            fallback.append(None)

    sizes, unit_page, unit_uv, fell_back = _pack_units(units, page_max, padding, margin, fallback)
    for u in fell_back:  # packed as the block xatlas charted the mesh into: one rectangle
        owners[u] = (owners[u][0], "block", None)
    if not shrink_pages:
        sizes = [page_max] * len(sizes)  # same placements; charts keep their texel positions

    layouts: list[MeshLayout | None] = [None] * len(geometry)
    chart_base = 0
    for u, (i, kind, data) in enumerate(owners):
        page, size = unit_page[u], sizes[unit_page[u]]
        b = blocks[i] if kind != "instance" else blocks[groups[member_of[i][0]][0][0]]
        uv_texels = np.full_like(b.uv, 0.5 + margin)  # triangles without charts: no area
        chart_ids = b.charts
        if kind == "free":
            chart_ids = np.full(len(b.charts), -1, np.int32)  # a cut chart's pieces are charts
            for c, (t, placed) in enumerate(zip(data, unit_uv[u])):
                uv_texels[t] = placed
                chart_ids[t] = c
            local, so = None, (1.0, 1.0, 0.0, 0.0)
        else:
            lo, ext = _content_box(b)
            corner = unit_uv[u][0].reshape(-1, 2).min(axis=0)
            origin = np.floor(corner) + 0.5  # xatlas puts the box's corner on a texel centre
            if np.abs(corner - origin).max() > 1e-2:
                raise RuntimeError(f"xatlas placed a rectangle off the texel centres ({corner})")
            if kind == "instance":
                k = float(data)
                unit_ext = np.where(ext > 0, ext, 1.0)
                # in [0, 1]^2 (clipped: triangles without area are parked off the charts)
                local = np.clip(np.where(ext > 0, (b.uv - lo) / unit_ext, 0.0), 0.0, 1.0)
                scale = unit_ext * k
                uv_texels = local * scale + origin
                so = (scale[0] / size, scale[1] / size, origin[0] / size, origin[1] / size)
            elif b.layout is not None:  # kept authored layout: block uv = uv * s + o
                s, ox, oy = b.layout
                local = np.asarray(existing_uvs[i], dtype=np.float64)
                shift = origin - lo
                uv_texels = local * s + np.array([ox, oy]) + shift
                so = (s / size, s / size, (ox + shift[0]) / size, (oy + shift[1]) / size)
            else:  # repacked authored islands, or a mesh's whole block: moved as one piece
                uv_texels = b.uv - lo + origin
                local, so = None, (1.0, 1.0, 0.0, 0.0)
            uv_texels = np.where((b.charts >= 0)[:, None, None], uv_texels, 0.5 + margin)
        uvs = uv_texels / float(size)
        if local is None:
            local = uvs
        else:
            uvs = local * np.array(so[:2]) + np.array(so[2:])  # exactly what the engine computes
            uvs = np.where((b.charts >= 0)[:, None, None], uvs, (0.5 + margin) / size)
        charts = np.where(chart_ids >= 0, chart_ids + chart_base, -1).astype(np.int32)
        chart_base += int(chart_ids.max()) + 1 if (chart_ids >= 0).any() else 0
        ok = b.charts >= 0
        if ok.any():
            lo_t = np.floor(uv_texels[ok].reshape(-1, 2).min(axis=0)).astype(int)
            hi_t = np.ceil(uv_texels[ok].reshape(-1, 2).max(axis=0)).astype(int)
            block = (int(lo_t[0]), int(lo_t[1]), int(hi_t[0] - lo_t[0]), int(hi_t[1] - lo_t[1]))
        else:
            block = (0, 0, 0, 0)
        p, t = geometry[i]
        area3 = _areas3(p, t)
        density = _density(uvs[ok] * size, area3[ok]) if ok.any() else 0.0
        layouts[i] = MeshLayout(page, uvs, so, density, b.source, charts, block, local)
    for i in range(len(geometry)):
        if layouts[i] is None:
            layouts[i] = MeshLayout(-1, np.zeros((0, 3, 2)), (1.0, 1.0, 0.0, 0.0), 0.0, "empty",
                                    np.zeros(0, np.int32), (0, 0, 0, 0), np.zeros((0, 3, 2)))
    return sizes, layouts, warnings


def _content_box(b: _Block) -> tuple[np.ndarray, np.ndarray]:
    """Lower corner and extent (texels) of a block's charted triangles."""
    ok = b.charts >= 0
    pts = (b.uv[ok] if ok.any() else b.uv).reshape(-1, 2)
    lo = pts.min(axis=0)
    return lo, pts.max(axis=0) - lo


def _proxy(uv: np.ndarray | None, ext: np.ndarray | None = None) -> np.ndarray:
    """A rectangle as two triangles (texel units) covering the bounding box of `uv`, or of
    [0, ext]: what the page packer sees of a layout that must move as one piece."""
    if ext is None:
        pts = uv.reshape(-1, 2)
        ext = pts.max(axis=0) - pts.min(axis=0)
    w, h = max(float(ext[0]), 1e-3), max(float(ext[1]), 1e-3)
    return np.array([[[0, 0], [w, 0], [w, h]], [[0, 0], [w, h], [0, h]]], float)


def _overlap_check(uv: np.ndarray, charts: np.ndarray, covered: int) -> str | None:
    """Cheap evidence of UVs that overlap: triangles folded against their chart's
    orientation, or more UV area than the texels covered (impossible without overlap).
    xatlas can return such charts (a finely tessellated sphere came back as one chart
    folded onto itself); authored layouts can stack islands."""
    area = _areas2(uv)
    ok = charts >= 0
    if not ok.any():
        return None
    c = charts[ok]
    pos = np.bincount(c, weights=(area[ok] > 0).astype(float))
    neg = np.bincount(c, weights=(area[ok] < 0).astype(float))
    flipped = int(np.minimum(pos, neg).sum())
    total = float(np.abs(area).sum())
    if flipped == 0 and total <= covered * (1 + 1e-9):
        return None
    return (f"UVs overlap ({flipped} triangle(s) folded within their chart, {total:.0f} texels of "
            f"UV area on {covered} covered texels): texels there mix different surfaces")


def chart_area_bound(area: np.ndarray, texels_per_metre: float) -> float:
    """xatlas's max_chart_area (m^2) for a mesh with these triangle areas; 0 = no bound."""
    good = area > 0
    if int(good.sum()) <= _FREE_TRIANGLES:
        return 0.0
    mean = float(area[good].mean())
    target = (_CHART_TEXELS / texels_per_metre) ** 2
    return float(np.clip(target, mean * _CHART_TRIANGLES[0], mean * _CHART_TRIANGLES[1]))


def _mesh_blocks(geometry, existing_uvs, names, texels_per_metre, padding, limit, existing_layout, max_size,
                 member_of=None, groups=(), chart_cost=None, polygons=None, workers: int = 1):
    """Each mesh's block of charts, and the warnings; None for a prototype's members after
    the first (they share its layout). Run through _isolated: xatlas is called here. With
    `workers` > 1 the meshes are shared out, balanced by triangles, among that many forked
    children: each mesh's block depends on the mesh alone, so the result is the same bits."""
    args = (geometry, existing_uvs, names, texels_per_metre, padding, limit, existing_layout, max_size,
            member_of, groups, chart_cost, polygons)
    n = len(geometry)
    if workers <= 1 or n < 2:
        tagged = _tagged_blocks(*args, range(n))
    else:
        parts: list[list[int]] = [[] for _ in range(min(workers, n))]
        loads = [0] * len(parts)
        for i in sorted(range(n), key=lambda i: (-len(geometry[i][1]), i)):
            k = loads.index(min(loads))
            parts[k].append(i)
            loads[k] += len(geometry[i][1])
        tagged = {}
        for part in _forked_each([(_tagged_blocks, (*args, sorted(part))) for part in parts]):
            tagged.update(part)
    blocks = [tagged[i][0] for i in range(n)]
    warnings = [w for i in range(n) for w in tagged[i][1]]
    return blocks, warnings


def _forked_each(calls):
    """fn(*args) of each call in a forked child of its own, all running at once; their results
    in call order. A child that outlives this process (its parent killed by _isolated's time
    limit) is killed with it."""
    import ctypes
    import select

    children = []
    for fn, args in calls:
        read_fd, write_fd = os.pipe()
        pid = os.fork()
        if pid == 0:
            os.close(read_fd)
            try:
                ctypes.CDLL(None).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
            except (OSError, AttributeError):
                pass
            _child_send(fn, args, write_fd)
        os.close(write_fd)
        children.append((pid, os.fdopen(read_fd, "rb", buffering=0)))
    chunks: list[list[bytes]] = [[] for _ in children]
    open_ = {k for k in range(len(children))}
    while open_:  # read all pipes as they fill, so that no child blocks on a full one
        ready, _, _ = select.select([children[k][1] for k in open_], [], [])
        for k in list(open_):
            if children[k][1] in ready:
                chunk = children[k][1].read(1 << 20)
                if chunk:
                    chunks[k].append(chunk)
                else:
                    open_.discard(k)
    results = []
    for k, (pid, pipe) in enumerate(children):
        pipe.close()
        _, status = os.waitpid(pid, 0)
        results.append(_child_result(b"".join(chunks[k]), status))
    return results


def _child_send(fn, args, write_fd: int) -> None:
    """In a forked child: fn(*args) (or the exception it raised) pickled to `write_fd`, then
    leave without any teardown (os._exit: no destructor runs, see _isolated)."""
    code = 0
    try:
        try:
            payload = pickle.dumps((True, fn(*args)), protocol=pickle.HIGHEST_PROTOCOL)
        except BaseException as error:  # noqa: BLE001 - every failure goes to the parent
            try:  # the exception itself when it pickles, so the caller sees what it would
                payload = pickle.dumps((False, error))
            except Exception:  # noqa: BLE001
                payload = pickle.dumps((False, RuntimeError(f"{type(error).__name__}: {error}")))
        with os.fdopen(write_fd, "wb") as out:
            out.write(payload)
    except BaseException:  # noqa: BLE001 - the parent sees the missing result
        code = 1
    os._exit(code)


def _child_result(data: bytes, status: int):
    """What _child_send sent: its value, or its exception raised here."""
    if not data:
        raise RuntimeError(f"the xatlas child process ended without a result (wait status {status})")
    ok, value = pickle.loads(data)
    if not ok:
        raise value
    return value


def _tagged_blocks(geometry, existing_uvs, names, texels_per_metre, padding, limit, existing_layout, max_size,
                   member_of, groups, chart_cost, polygons, indices) -> dict:
    """{mesh index: (block, its warnings)} for the meshes `indices` (see _mesh_blocks)."""
    member_of = member_of or {}
    out: dict = {}
    for i in indices:
        p, t = geometry[i]
        warnings: list[str] = []
        out[i] = (_one_block(i, p, t, existing_uvs, names, texels_per_metre, padding, limit, existing_layout,
                             max_size, member_of, groups, chart_cost, polygons, warnings), warnings)
    return out


def _one_block(i, p, t, existing_uvs, names, texels_per_metre, padding, limit, existing_layout, max_size,
               member_of, groups, chart_cost, polygons, warnings):
    """Mesh i's block (see _mesh_blocks), its warnings appended to `warnings`."""
    uv = None if existing_uvs is None else existing_uvs[i]
    density, pad = texels_per_metre, padding
    if i in member_of:
        g, k = member_of[i]
        if k > 0:
            return None
        scales = groups[g][1]
        density = texels_per_metre * min(scales)  # the first member's size is 1
        if max(scales) > min(scales) * (1 + 1e-9):
            pad = padding + 2  # one texel more each side, see build_atlas
    if len(t) == 0:
        return _Block(0, 0, np.zeros((0, 3, 2)), np.zeros(0, np.int32), 0.0, "empty")
    block = None
    if uv is not None:
        block = _existing_block(p, t, np.asarray(uv, dtype=np.float64), density, pad,
                                limit, existing_layout, names[i], warnings)
    if block is None:
        block = _generated_block(p, t, density, pad, limit, names[i], warnings, chart_cost,
                                 None if polygons is None else polygons[i])
    if block.scaled:
        warnings.append(f"{names[i]}: scaled down to {block.density:.4g} texels/m "
                        f"(asked {density:g}) to fit one {max_size} page")
    return block


# Seconds each forked attempt may take before it is killed and started again (the last has no
# limit): xatlas's scheduler can also lose a wake-up while it computes, and a child stuck that
# way would block the bake forever. The result is deterministic, so a retry gives the same bits.
# The limits are for up to _ATTEMPT_TRIANGLES triangles and grow in proportion beyond: charting
# the 1M-triangle country kitchen takes over 5 minutes, and fixed limits killed two sound
# attempts (after 30 and 120 s) before the third could finish; limits scaled per 100k
# triangles still killed the first after 315 s.
_ATTEMPT_SECONDS = (30.0, 120.0, 600.0, None)
# Atlases of at least this many triangles are charted by one child per core (_mesh_blocks).
_PARALLEL_TRIANGLES = 10_000
_ATTEMPT_TRIANGLES = 20_000


def _isolated(fn, *args, scale: float = 1.0):
    """fn(*args) computed in a forked child process, its result returned through a pipe.

    xatlas's task scheduler can lose the wake-up it sends its worker threads when an Atlas is
    destroyed (the notify is sent without the worker's mutex, so it can fall between the
    worker's predicate check and its wait), and the destructor then joins that worker
    forever. The child never destroys its Atlas: it writes the result and leaves with
    os._exit, which runs no destructors. A child that gives no result within its attempt's
    time (_ATTEMPT_SECONDS times `scale`) is killed and the work started again. The child's exception is
    raised here; a child that dies without a result is an error."""
    for limit in _ATTEMPT_SECONDS:
        done, value = _attempt(fn, args, None if limit is None else limit * scale)
        if done:
            return value
    raise AssertionError("unreachable: the last attempt has no time limit")


def _attempt(fn, args, limit):
    import select
    import time

    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: compute, send, leave without any teardown
        os.close(read_fd)
        _child_send(fn, args, write_fd)
    os.close(write_fd)
    chunks = []
    try:
        with os.fdopen(read_fd, "rb", buffering=0) as result:
            deadline = None if limit is None else time.monotonic() + limit
            while True:
                wait = None if deadline is None else max(0.0, deadline - time.monotonic())
                ready, _, _ = select.select([result], [], [], wait)
                if not ready:  # no result in time: a stuck child
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)
                    return False, None
                chunk = result.read(1 << 20)
                if not chunk:
                    break
                chunks.append(chunk)
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise
    _, status = os.waitpid(pid, 0)
    return True, _child_result(b"".join(chunks), status)


def _xatlas_chart(positions, faces, max_chart_area, max_boundary_length, density, padding, max_cost=None):
    """xatlas charts and packs one mesh: (width, height, vertex map, indices, uv, chart of
    each output vertex). Lengths in metres, density in texels per metre.

    xatlas is given the mesh in texel units (positions times the density). It ignores a
    face whose area is below FLT_EPSILON in its units and merges vertices closer than 1e-4:
    in metres that dropped every triangle under 0.12 mm^2 from the charts (141,284 of the
    country kitchen's, whole meshes of fine detail); in texels both bounds are a fixed,
    negligible share of a texel whatever the scene's scale. The scale is exact for the
    packer: texels per unit 1 on positions scaled by the density."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh((np.asarray(positions, np.float64) * density).astype(np.float32), faces)
    co = xatlas.ChartOptions()
    co.max_chart_area = max_chart_area * density * density
    co.max_boundary_length = max_boundary_length * density
    co.max_cost = _CHART_COST if max_cost is None else float(max_cost)
    po = xatlas.PackOptions()
    po.texels_per_unit = 1.0
    po.padding = padding
    po.resolution = 0
    po.bilinear = False
    po.blockAlign = False  # it rounds chart sizes up to 4 texels: a density change
    atlas.generate(co, po)
    vmap, idx, uv = atlas[0]
    _, chart_of_vertex = atlas.get_mesh_vertex_assignment(0)
    return int(atlas.width), int(atlas.height), vmap, idx, uv, chart_of_vertex


def _generated_block(p: np.ndarray, t: np.ndarray, texels_per_metre: float, padding: int, limit: int,
                     name: str, warnings: list[str], chart_cost: float | None = None,
                     poly: np.ndarray | None = None) -> _Block:
    """xatlas charts and packs the mesh into a block of its own at the given density; if the
    block is larger than a page, the density is lowered and it is done again."""
    area3 = _areas3(p, t)
    good = area3 > 0
    if not good.any():
        return _Block(1, 1, np.full((len(t), 3, 2), 0.5), np.full(len(t), -1, np.int32), 0.0, "generated")
    total = float(area3.sum())
    density = float(texels_per_metre)
    # xatlas packs at roughly 60-70 % utilisation; start below the page if clearly needed, so
    # the expensive charting rarely runs twice.
    estimate = math.sqrt(total / 0.55) * density
    if estimate > limit:
        density *= limit / estimate
    centred = (p - 0.5 * (p.min(axis=0) + p.max(axis=0)))
    faces = t.astype(np.uint32)
    pack_padding = (padding + 1) // 2  # xatlas pads each chart, so gaps are twice this
    for _attempt in range(8):
        # Bound chart growth twice: by area (cost, see chart_area_bound) and by boundary
        # length, so a chart's extent (at most half its perimeter) fits a page.
        w, h, vmap, idx, uv, chart_of_vertex = _xatlas_chart(
            centred, faces, chart_area_bound(area3, density),
            float(2.0 * 0.95 * (limit - 2) / density), float(density), int(pack_padding), chart_cost)
        if max(w, h) <= limit:
            break
        density *= (limit - 1) / max(w, h) * 0.99
    else:
        raise RuntimeError(f"xatlas could not fit the mesh in {limit} texels")
    idx = idx.astype(np.int64)
    if idx.shape != t.shape or not np.array_equal(vmap[idx], t):
        raise RuntimeError("xatlas reordered faces or corners; cannot map its UVs back")
    local = uv.astype(np.float64)[idx] * np.array([w, h], float)
    chart = chart_of_vertex[idx[:, 0]].astype(np.int64)
    chart = np.where(chart == _NO_CHART, -1, chart).astype(np.int32)
    lost = int(((chart < 0) & good).sum())
    if lost:
        warnings.append(f"{name}: xatlas left {lost} triangle(s) with area out of its charts; "
                        "they get no lightmap texels")
    if (chart < 0).any():  # park them at a texel centre: no area, they never rasterise
        local[chart < 0] = 0.5
    folded = _folded_charts(local, chart)
    if folded.size:
        # xatlas's planar-region pass compares neighbouring faces only, so on a smooth and
        # finely tessellated surface it can chain a whole sphere into one "planar" chart
        # folded onto itself; those faces are charted again by box projection.
        redo = np.isin(chart, folded)
        box_uv, box_id = _box_islands(p, t[redo])
        a3 = np.bincount(box_id, weights=area3[redo])
        auv = np.bincount(box_id, weights=np.abs(_areas2(box_uv)))
        scale = density * np.sqrt(a3 / np.maximum(auv, 1e-300))
        keep = (chart >= 0) & ~redo
        uvt = np.concatenate([local[keep], box_uv * scale[box_id, None, None]])
        ids = np.concatenate([chart[keep], box_id + int(chart.max()) + 1])
        packed = _pack_islands(uvt, ids, padding, limit, rigid=False)
        if packed is not None:
            new_local, w, h, factor = packed
            density *= factor
            faces = np.concatenate([np.nonzero(keep)[0], np.nonzero(redo)[0]])
            local[faces] = new_local
            chart[faces] = np.unique(ids, return_inverse=True)[1]
            warnings.append(f"{name}: xatlas folded {folded.size} chart(s) onto themselves; "
                            f"{int(redo.sum())} triangles re-charted by box projection")
    apart = _polygons_apart(poly, chart) if poly is not None else np.zeros(0, np.int64)
    if apart.size:
        # A polygon cut by a chart boundary cannot carry one UV per corner: each such polygon
        # becomes a chart of its own, its triangles projected onto the polygon's plane.
        redo = np.isin(poly, apart) & (chart >= 0)
        plane_uv, plane_id = _polygon_islands(p, t[redo], poly[redo], density)
        keep = (chart >= 0) & ~redo
        uvt = np.concatenate([local[keep], plane_uv])
        ids = np.concatenate([chart[keep], plane_id + int(chart.max()) + 1])
        packed = _pack_islands(uvt, ids, padding, limit, rigid=False)
        if packed is None:
            raise RuntimeError(f"{name}: could not pack its charts after charting {apart.size} polygon(s) whole")
        new_local, w, h, factor = packed
        density *= factor
        faces = np.concatenate([np.nonzero(keep)[0], np.nonzero(redo)[0]])
        local[faces] = new_local
        chart[faces] = np.unique(ids, return_inverse=True)[1]
        warnings.append(f"{name}: xatlas cut {apart.size} polygon(s) across charts; each was charted whole by "
                        "projection onto its plane")
    got = _density(local[chart >= 0], area3[chart >= 0])
    if abs(got / density - 1) > 0.05:  # xatlas rounds charts up to whole texels, distorts curved ones
        warnings.append(f"{name}: xatlas charts came out at {got:.4g} texels/m for {density:.4g} asked")
    return _Block(w, h, local, chart, got, "generated", scaled=density < texels_per_metre)


def _polygons_apart(poly: np.ndarray, chart: np.ndarray) -> np.ndarray:
    """Polygons whose charted triangles lie in more than one chart."""
    ok = chart >= 0
    if not ok.any():
        return np.zeros(0, np.int64)
    pairs = np.unique(np.stack([poly[ok], chart[ok]], axis=1), axis=0)
    ids, counts = np.unique(pairs[:, 0], return_counts=True)
    return ids[counts > 1]


def _polygon_islands(p: np.ndarray, t: np.ndarray, poly: np.ndarray, density: float):
    """Triangles of whole polygons, each polygon one island: its corners projected onto the
    polygon's plane (the area-weighted normal of its triangles, Newell's normal for a planar
    polygon) in texel units at `density`, oriented so the island keeps the polygon's winding.
    Returns (uv (M, 3, 2), island id per triangle, 0..)."""
    ids, island = np.unique(poly, return_inverse=True)
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    cross = np.cross(b - a, c - a)
    normal = np.zeros((len(ids), 3))
    np.add.at(normal, island, cross)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(length > 0, normal / np.maximum(length, 1e-300), [0.0, 0.0, 1.0])
    # a tangent: the axis least aligned with the normal, made orthogonal
    axis = np.eye(3)[np.argmin(np.abs(normal), axis=1)]
    u = axis - (axis * normal).sum(axis=1, keepdims=True) * normal
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normal, u)
    corners = p[t]  # (M, 3, 3)
    origin = corners.reshape(-1, 3)[::3][0] if len(t) else np.zeros(3)
    rel = corners - origin
    uv = np.stack([(rel * u[island, None, :]).sum(-1), (rel * v[island, None, :]).sum(-1)], axis=-1)
    return uv * float(density), island.astype(np.int64)


def _folded_charts(uv: np.ndarray, chart: np.ndarray) -> np.ndarray:
    """Charts holding triangles of both orientations (folded onto themselves)."""
    ok = chart >= 0
    if not ok.any():
        return np.zeros(0, np.int64)
    area = _areas2(uv[ok])
    pos = np.bincount(chart[ok], weights=(area > 0).astype(float))
    neg = np.bincount(chart[ok], weights=(area < 0).astype(float))
    return np.nonzero((pos > 0) & (neg > 0))[0]


def _existing_block(p, t, uv, texels_per_metre, padding, limit, layout, name, warnings) -> _Block | None:
    """The mesh's own UVs, scaled by one factor to the requested density."""
    if uv.shape != (len(t), 3, 2) or not np.isfinite(uv).all():
        warnings.append(f"{name}: lightmap UVs of shape {uv.shape} (need ({len(t)}, 3, 2), finite); "
                        "charts generated instead")
        return None
    area3 = _areas3(p, t)
    area_uv = float(np.abs(_areas2(uv)).sum())
    if area_uv <= 0 or area3.sum() <= 0:
        warnings.append(f"{name}: lightmap UVs have no area; charts generated instead")
        return None
    s = texels_per_metre * math.sqrt(float(area3.sum()) / area_uv)  # texels per UV unit
    islands = uv_islands(uv)
    if layout == "repack":
        block = _repack_islands(uv, islands, s, padding, limit, area3)
        if block is not None:
            return block
        warnings.append(f"{name}: UV islands could not be packed in one page; layout kept as authored")
    lo = uv.reshape(-1, 2).min(axis=0)
    extent = float((uv.reshape(-1, 2).max(axis=0) - lo).max())
    scaled = s * extent + 1 > limit
    if scaled:  # the layout alone is larger than a page
        s = (limit - 1) / extent
    offset = 0.5 - lo * s  # bounding box starts at a texel centre, like xatlas's charts
    local = uv * s + offset
    w, h = (np.floor(local.reshape(-1, 2).max(axis=0)).astype(int) + 1).tolist()
    gap = _island_gap(local, islands, w, h, padding)
    if gap is not None:
        warnings.append(f"{name}: UV islands only {gap} texel(s) apart at this density "
                        f"(padding {padding}): light may bleed between them")
    return _Block(int(w), int(h), local, islands, _density(local, area3), "existing",
                  (float(s), float(offset[0]), float(offset[1])), scaled)


def _box_islands(p: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fallback charts: faces grouped by the axis their normal is closest to (six groups,
    normals within 55 degrees of the axis), each connected group projected on its axis
    plane. Crude but never folded on the surfaces xatlas folds (smooth, finely tessellated
    height fields). Returns (uv in metres (M, 3, 2), island id per face)."""
    tri = p[t]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    axis = np.argmax(np.abs(n), axis=1)
    group = axis * 2 + (n[np.arange(len(n)), axis] < 0)
    plane = np.array([[1, 2], [2, 0], [0, 1]])[axis]  # right-handed: front faces keep their winding
    uv = np.take_along_axis(tri, plane[:, None, :], axis=2)
    m = len(t)
    _, node = np.unique(t * 6 + group[:, None], return_inverse=True)
    node = node.reshape(-1, 3) + m
    faces = np.repeat(np.arange(m), 3)
    comp = _components(int(node.max()) + 1 if m else 0, faces, node.reshape(-1))
    return uv, np.unique(comp[:m], return_inverse=True)[1]


def uv_islands(uv: np.ndarray) -> np.ndarray:
    """Island id per triangle: connected components of triangles that share a corner UV
    (bit-identical values, as per-corner UVs from an indexed primvar are)."""
    corners = uv.reshape(-1, 2)
    _, vid = np.unique(corners, axis=0, return_inverse=True)
    vid = vid.reshape(-1, 3)
    n = int(vid.max()) + 1 if vid.size else 0
    edges = np.concatenate([vid[:, [0, 1]], vid[:, [1, 2]]])
    comp = _components(n, edges[:, 0], edges[:, 1])
    return np.unique(comp[vid[:, 0]], return_inverse=True)[1].astype(np.int32)


def _components(n: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Connected components of an undirected graph: hooking roots onto smaller roots, then
    pointer jumping (a handful of vectorised rounds instead of a Python union-find)."""
    parent = np.arange(n)
    while True:
        pu, pv = parent[u], parent[v]
        lo, hi = np.minimum(pu, pv), np.maximum(pu, pv)
        diff = lo != hi
        if not diff.any():
            return parent
        np.minimum.at(parent, hi[diff], lo[diff])
        while True:
            nxt = parent[parent]
            if np.array_equal(nxt, parent):
                break
            parent = nxt
