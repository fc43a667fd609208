"""Charting: each mesh's lightmap UVs, its own set when usable (non-overlapping, not folded), else xatlas charts; one forked child per atlas isolates xatlas."""

from __future__ import annotations

import math
import os
import pickle
import signal
from typing import Literal, Sequence

import numpy as np
from .base import Atlas, Mesh, MeshLayout, _Block, _CHART_TEXELS, _CHART_TRIANGLES, _FREE_TRIANGLES, _NO_CHART, _areas2, _areas3, _density, _round_up
from .pack import _island_gap, _pack_blocks, _pack_islands, _repack_islands
from .texels import _covered_texels


# ----------------------------------------------------------------------------------------
# Building the atlas


def build_atlas(meshes: Sequence[Mesh], texels_per_metre: float, padding: int, max_size: int, *,
                existing_uvs: Sequence[np.ndarray | None] | None = None,
                names: Sequence[str] | None = None,
                existing_layout: Literal["keep", "repack"] = "keep",
                shrink_pages: bool = True) -> Atlas:
    """Lays every mesh out on pages of at most max_size x max_size texels.

    A mesh without UVs gets charts from xatlas at `texels_per_metre`; a mesh with its own
    lightmap UVs (per triangle corner, (M, 3, 2)) keeps them: its UV islands are scaled by
    one factor so the mesh has the requested density (3D area over UV area), and either
    stay where the author put them (`existing_layout="keep"`, then `scale_offset` maps the
    mesh's UVs to the page, as Unity's lightmapScaleOffset) or are packed again one by one
    by xatlas (`"repack"`, tighter, and scale/offset is the identity).

    `padding` is the least number of empty texels between texels covered by different
    charts, and between different meshes; pages keep ceil(padding/2) texels at their
    borders so the rule also holds across a wrapping edge. Chart growth is bounded on large
    meshes (see _CHART_TEXELS: xatlas's cost is super-quadratic in the faces of one chart).
    Pages are cropped to what they hold (a multiple of 4 texels) unless `shrink_pages` is
    False.
    """
    if not texels_per_metre > 0:
        raise ValueError("texels_per_metre must be positive")
    if int(padding) != padding or padding < 0:
        raise ValueError("padding must be a non-negative integer")
    padding = int(padding)
    margin = (padding + 1) // 2
    limit = int(max_size) - 2 * margin
    if limit < 4:
        raise ValueError(f"max_size {max_size} leaves no room with padding {padding}")
    if existing_uvs is not None and len(existing_uvs) != len(meshes):
        raise ValueError("existing_uvs needs one entry (or None) per mesh")
    names = [f"mesh_{i}" for i in range(len(meshes))] if names is None else list(names)
    if len(names) != len(meshes):
        raise ValueError("names needs one entry per mesh")

    geometry: list[Mesh] = [(np.asarray(p, dtype=np.float64).reshape(-1, 3),
                             np.asarray(t, dtype=np.int64).reshape(-1, 3)) for p, t in meshes]
    # Every mesh's charts in one child process (see _isolated): one fork per atlas.
    blocks, warnings = _isolated(_mesh_blocks, geometry, existing_uvs, names, texels_per_metre, padding, limit,
                                 existing_layout, max_size)

    placed, pages = _pack_blocks([(b.width, b.height) for b in blocks], int(max_size), padding, margin)
    sizes = []
    for k, members in enumerate(pages):
        if shrink_pages:
            used_w = max(placed[i][1] + blocks[i].width for i in members) + margin
            used_h = max(placed[i][2] + blocks[i].height for i in members) + margin
            sizes.append((min(int(max_size), _round_up(used_w, 4)), min(int(max_size), _round_up(used_h, 4))))
        else:
            sizes.append((int(max_size), int(max_size)))

    layouts = []
    chart_base = 0
    for i, b in enumerate(blocks):
        page, bx, by = placed[i]
        if page < 0:
            layouts.append(MeshLayout(-1, np.zeros((0, 3, 2)), (1.0, 1.0, 0.0, 0.0), 0.0, "empty",
                                      np.zeros(0, np.int32), (0, 0, 0, 0)))
            continue
        w, h = sizes[page]
        uvs = (b.uv + np.array([bx, by], float)) / np.array([w, h], float)
        charts = np.where(b.charts >= 0, b.charts + chart_base, -1).astype(np.int32)
        chart_base += int(b.charts.max()) + 1 if (b.charts >= 0).any() else 0
        if b.layout is not None:
            s, ox, oy = b.layout
            so = (s / w, s / h, (bx + ox) / w, (by + oy) / h)
        else:
            so = (1.0, 1.0, 0.0, 0.0)
        layouts.append(MeshLayout(page, uvs, so, b.density, b.source, charts, (bx, by, b.width, b.height)))

    atlas = Atlas(sizes, layouts, [], float(texels_per_metre), padding, names, geometry, warnings)
    for k in range(len(sizes)):
        uv, mesh_of, _ = atlas.page_texel_uvs(k)
        tri, lin = _covered_texels(uv, *sizes[k])
        atlas.fill.append(len(np.unique(lin)) / float(sizes[k][0] * sizes[k][1]))
        for mi in atlas.page_meshes(k):
            mine = mesh_of[tri] == mi
            problem = _overlap_check(uv[mesh_of == mi], layouts[mi].charts, len(np.unique(lin[mine])))
            if problem:
                warnings.append(f"{names[mi]}: {problem}")
    return atlas


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


def _mesh_blocks(geometry, existing_uvs, names, texels_per_metre, padding, limit, existing_layout, max_size):
    """Each mesh's block of charts, and the warnings. Run through _isolated: xatlas is called
    here."""
    blocks: list[_Block] = []
    warnings: list[str] = []
    for i, (p, t) in enumerate(geometry):
        uv = None if existing_uvs is None else existing_uvs[i]
        if len(t) == 0:
            blocks.append(_Block(0, 0, np.zeros((0, 3, 2)), np.zeros(0, np.int32), 0.0, "empty"))
            continue
        block = None
        if uv is not None:
            block = _existing_block(p, t, np.asarray(uv, dtype=np.float64), texels_per_metre, padding,
                                    limit, existing_layout, names[i], warnings)
        if block is None:
            block = _generated_block(p, t, texels_per_metre, padding, limit, names[i], warnings)
        if block.scaled:
            warnings.append(f"{names[i]}: scaled down to {block.density:.4g} texels/m "
                            f"(asked {texels_per_metre:g}) to fit one {max_size} page")
        blocks.append(block)
    return blocks, warnings


# Seconds each forked attempt may take before it is killed and started again (the last has no
# limit): xatlas's scheduler can also lose a wake-up while it computes, and a child stuck that
# way would block the bake forever. The result is deterministic, so a retry gives the same bits.
_ATTEMPT_SECONDS = (30.0, 120.0, 600.0, None)


def _isolated(fn, *args):
    """fn(*args) computed in a forked child process, its result returned through a pipe.

    xatlas's task scheduler can lose the wake-up it sends its worker threads when an Atlas is
    destroyed (the notify is sent without the worker's mutex, so it can fall between the
    worker's predicate check and its wait), and the destructor then joins that worker
    forever. The child never destroys its Atlas: it writes the result and leaves with
    os._exit, which runs no destructors. A child that gives no result within its attempt's
    time is killed and the work started again (_ATTEMPT_SECONDS). The child's exception is
    raised here; a child that dies without a result is an error."""
    for limit in _ATTEMPT_SECONDS:
        done, value = _attempt(fn, args, limit)
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
    data = b"".join(chunks)
    if not data:
        raise RuntimeError(f"the xatlas child process ended without a result (wait status {status})")
    ok, value = pickle.loads(data)
    if not ok:
        raise value
    return True, value


def _xatlas_chart(positions, faces, max_chart_area, max_boundary_length, density, padding):
    """xatlas charts and packs one mesh: (width, height, vertex map, indices, uv, chart of
    each output vertex)."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(positions, faces)
    co = xatlas.ChartOptions()
    co.max_chart_area = max_chart_area
    co.max_boundary_length = max_boundary_length
    po = xatlas.PackOptions()
    po.texels_per_unit = density
    po.padding = padding
    po.resolution = 0
    po.bilinear = False
    po.blockAlign = False  # it rounds chart sizes up to 4 texels: a density change
    atlas.generate(co, po)
    vmap, idx, uv = atlas[0]
    _, chart_of_vertex = atlas.get_mesh_vertex_assignment(0)
    return int(atlas.width), int(atlas.height), vmap, idx, uv, chart_of_vertex


def _generated_block(p: np.ndarray, t: np.ndarray, texels_per_metre: float, padding: int, limit: int,
                     name: str, warnings: list[str]) -> _Block:
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
    centred = (p - 0.5 * (p.min(axis=0) + p.max(axis=0))).astype(np.float32)
    faces = t.astype(np.uint32)
    pack_padding = (padding + 1) // 2  # xatlas pads each chart, so gaps are twice this
    for _attempt in range(8):
        # Bound chart growth twice: by area (cost, see chart_area_bound) and by boundary
        # length, so a chart's extent (at most half its perimeter) fits a page.
        w, h, vmap, idx, uv, chart_of_vertex = _xatlas_chart(
            centred, faces, chart_area_bound(area3, density),
            float(2.0 * 0.95 * (limit - 2) / density), float(density), int(pack_padding))
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
    got = _density(local[chart >= 0], area3[chart >= 0])
    if abs(got / density - 1) > 0.05:  # xatlas rounds charts up to whole texels, distorts curved ones
        warnings.append(f"{name}: xatlas charts came out at {got:.4g} texels/m for {density:.4g} asked")
    return _Block(w, h, local, chart, got, "generated", scaled=density < texels_per_metre)


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
