"""Lightmap UV atlases for game engines, and the texel sampling that bakes into them.

Game engines want one lightmap texture (a *page*) per renderer, a UV set that maps every
triangle into a chart of that page without overlaps, and a density that matches what the
artists asked for. This module is pure Python + numpy + xatlas and knows nothing of USD or
of the engine: the bake gives it triangle meshes in metres and gets back UVs, texel sample
positions to evaluate, and images to write. Values reach it through arrays (or the
`evaluate` callback of `bake_page`), never through the solver.

Conventions (all of them on purpose):

- Page UVs are USD ``texCoord2f``: v up, origin at the bottom-left corner of the page.
  Images are numpy arrays (H, W, ...) whose row 0 is the *top* of the page, as written to
  PNG/EXR; texel coordinates returned here are (x = column, y = row from the top).
- Texel (i, j) covers [i, i+1] x [j, j+1] in texel units (u * W, v * H); its centre is at
  (i + 1/2, j + 1/2).
- Chart bounding boxes start at texel *centres* (integer + 1/2), for every chart: xatlas
  places its charts that way and we keep that phase for existing UV layouts too. Chart
  edges along the axes then run through texel centres rather than along texel borders, so
  float noise in the UVs never flips whether a border texel is covered, and a bilinear
  lookup on such an edge reads only texels the chart covers (elsewhere the dilated
  padding supplies the neighbours).
- A mesh lives on exactly one page (a renderer has one lightmap index and one
  scale/offset), so the unit that must fit a page is a mesh's block of charts; a mesh too
  big for a page is scaled down as a whole and its achieved density is recorded.
- Who packs what: xatlas charts a mesh without UVs and packs its charts into the mesh's
  block (its packer is bitmap based and tight). It also stretches every chart by less than a
  texel so the chart's extents are whole texels, so generated charts come out slightly
  denser than asked (small charts the most); the density is measured, not assumed. An
  author's islands must move rigidly, so they, and the mesh blocks onto pages (which
  xatlas cannot keep together on one page), go through our own skyline packer.
- "Covered" means the texel square and a triangle overlap in a set of positive area
  (conservative rasterisation without the zero-area touches).
"""

from __future__ import annotations

import json
import math
import os
import pickle
import signal
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Literal, Sequence

import numpy as np

Mesh = tuple[np.ndarray, np.ndarray]
"""(positions float (N, 3) in metres, triangles int (M, 3))."""

_NO_CHART = 0xFFFFFFFF  # xatlas's chart index for faces it could not chart (degenerate)
_COVER_EPS = 1e-6  # texels: overlaps thinner than this count as touching only

# xatlas grows a chart at a cost super-quadratic in its faces (for a curved 100k-triangle
# surface on 2 cores: one chart, minutes; charts of ~6000 triangles, 20 s; of ~500, 2-3 s;
# planar regions are charted by a fast path whatever the bound). Meshes of up to
# _FREE_TRIANGLES triangles are charted without an area bound. Larger ones get charts that
# may grow to _CHART_TEXELS x _CHART_TEXELS texels at the asked density (smaller charts
# waste their padding, and xatlas rounds each chart up to whole texels, so tiny charts come
# out denser than asked), but to no more than _CHART_TRIANGLES[1] average triangles and to
# no fewer than _CHART_TRIANGLES[0].
_FREE_TRIANGLES = 4096
_CHART_TEXELS = 16
_CHART_TRIANGLES = (512, 1024)


# ----------------------------------------------------------------------------------------
# Data


@dataclass
class MeshLayout:
    """Where one mesh went in the atlas.

    `uvs` are final: per triangle corner, in [0, 1] of page `page`. `scale_offset` is
    Unity's lightmapScaleOffset (scale.x, scale.y, offset.x, offset.y): page_uv =
    mesh_uv * scale + offset. It is only meaningful when the mesh's own lightmap UVs were
    kept as one layout (source "existing"); otherwise the UVs were re-laid out and it is
    the identity (1, 1, 0, 0).
    """

    page: int
    uvs: np.ndarray  # (M, 3, 2) float64
    scale_offset: tuple[float, float, float, float]
    texels_per_metre: float  # achieved: sqrt(UV area in texels^2 / 3D area)
    source: Literal["generated", "existing", "existing-repacked", "empty"]
    charts: np.ndarray  # (M,) int32 atlas-wide chart id; -1 for triangles with no area
    block: tuple[int, int, int, int]  # x, y (from the bottom), width, height in page texels


@dataclass
class Atlas:
    """One or more pages holding every mesh's charts.

    `page_sizes` are (width, height) in texels; `fill[p]` is covered texels over page
    texels. `geometry` keeps the meshes as given (seams and sample positions need them).
    `warnings` says where the request could not be honoured exactly (a mesh scaled down to
    fit a page, existing UVs that could not be used).
    """

    page_sizes: list[tuple[int, int]]
    meshes: list[MeshLayout]
    fill: list[float]
    texels_per_metre: float
    padding: int
    names: list[str]
    geometry: list[Mesh] = field(repr=False)
    warnings: list[str] = field(default_factory=list)

    def page_meshes(self, page: int) -> list[int]:
        """Indices of the meshes on `page`."""
        return [i for i, m in enumerate(self.meshes) if m.page == page]

    def page_texel_uvs(self, page: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All triangles of a page in texel units (v up): (uv (F, 3, 2), mesh (F,), triangle (F,))."""
        w, h = self.page_sizes[page]
        ids = self.page_meshes(page)
        if not ids:
            return np.zeros((0, 3, 2)), np.zeros(0, np.int32), np.zeros(0, np.int32)
        uv = np.concatenate([self.meshes[i].uvs for i in ids]) * np.array([w, h], float)
        mesh = np.concatenate([np.full(len(self.meshes[i].uvs), i, np.int32) for i in ids])
        tri = np.concatenate([np.arange(len(self.meshes[i].uvs), dtype=np.int32) for i in ids])
        return uv, mesh, tri


@dataclass
class TexelSamples:
    """The sample points of one page.

    Texels are listed once each (`x` column, `y` row from the top); every sample belongs to
    one texel (`texel` indexes x/y) and lies on triangle `triangle` of mesh `mesh` at
    barycentrics `bary` (weights of the triangle's corners 0, 1, 2). `conservative[t]` is
    True when no stratified sub-sample of texel t fell inside a triangle, so its one sample
    is the closest point of the nearest touching triangle to the texel centre.
    """

    page: int
    width: int
    height: int
    supersample: int
    x: np.ndarray  # (T,) int32
    y: np.ndarray  # (T,) int32
    conservative: np.ndarray  # (T,) bool
    texel: np.ndarray  # (K,) int32
    mesh: np.ndarray  # (K,) int32
    triangle: np.ndarray  # (K,) int32
    bary: np.ndarray  # (K, 3) float64

    def __len__(self) -> int:
        return len(self.texel)


@dataclass
class _Block:
    """A mesh's charts laid out in a rectangle of its own, before it is put on a page."""

    width: int
    height: int
    uv: np.ndarray  # (M, 3, 2) texel units inside the block, v up
    charts: np.ndarray  # (M,) local chart ids, -1 none
    density: float
    source: str
    layout: tuple[float, float, float] | None = None  # (s, ox, oy): block uv = mesh uv * s + o
    scaled: bool = False  # density lowered so the block fits a page


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


def _round_up(n: int, m: int) -> int:
    return -(-int(n) // m) * m


def _areas3(p: np.ndarray, t: np.ndarray) -> np.ndarray:
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _areas2(uv: np.ndarray) -> np.ndarray:
    """Signed areas of (..., 3, 2) triangles."""
    d1, d2 = uv[..., 1, :] - uv[..., 0, :], uv[..., 2, :] - uv[..., 0, :]
    return 0.5 * (d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0])


def _density(uv_texels: np.ndarray, area3: np.ndarray) -> float:
    a3 = float(area3.sum())
    return math.sqrt(float(np.abs(_areas2(uv_texels)).sum()) / a3) if a3 > 0 else 0.0


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


def _isolated(fn, *args):
    """fn(*args) computed in a forked child process, its result returned through a pipe.

    xatlas's task scheduler can lose the wake-up it sends its worker threads when an Atlas is
    destroyed (the notify is sent without the worker's mutex, so it can fall between the
    worker's predicate check and its wait), and the destructor then joins that worker
    forever. The child never destroys its Atlas: it writes the result and leaves with
    os._exit, which runs no destructors. The child's exception is raised here; a child that
    dies without a result is an error."""
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
    try:
        with os.fdopen(read_fd, "rb") as result:
            data = result.read()
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise
    _, status = os.waitpid(pid, 0)
    if not data:
        raise RuntimeError(f"the xatlas child process ended without a result (wait status {status})")
    ok, value = pickle.loads(data)
    if not ok:
        raise value
    return value


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


def _closest_samples(uv, g, area, tri, lin, width):
    """For each texel in `lin`, the closest point to its centre over the candidate
    triangles touching it: (triangle, texel, barycentrics), one per texel."""
    if len(tri) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    centre = np.stack([lin % width + 0.5, lin // width + 0.5], axis=-1).astype(np.float64)
    v = uv[tri]  # (n, 3, 2)
    best = np.broadcast_to(centre, (len(tri), 2)).copy()
    best_d = np.full(len(tri), np.inf)
    e = (g[tri] * centre[:, None, :]).sum(-1) + (-(g[tri] * v[:, [1, 2, 0]]).sum(-1))
    inside = (e >= 0).all(axis=1)
    best_d[inside] = 0.0
    for k in range(3):
        a, b = v[:, k], v[:, (k + 1) % 3]
        d = b - a
        t = np.clip(((centre - a) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
        pt = a + t[:, None] * d
        dist = np.linalg.norm(pt - centre, axis=1)
        better = (dist < best_d) & ~inside
        best[better], best_d[better] = pt[better], dist[better]
    order = np.lexsort((best_d, lin))
    lin_s = lin[order]
    keep = order[np.r_[True, lin_s[1:] != lin_s[:-1]]]
    pts = best[keep]
    tk = tri[keep]
    c = -(g[tk] * v[keep][:, [1, 2, 0]]).sum(-1)
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


def dilate(image: np.ndarray, mask: np.ndarray, texels: int) -> np.ndarray:
    """Fills empty texels from their covered 8-neighbours, one ring per pass, `texels`
    rings: the padding then holds the charts' border values, so bilinear filtering and
    mipmaps do not pull black into the charts. Covered texels are not changed."""
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
    return out


# ----------------------------------------------------------------------------------------
# Seams


def seam_pairs(atlas: Atlas, page: int) -> np.ndarray:
    """Texel pairs across UV seams of `page`: (P, 4) int32 rows (x_a, y_a, x_b, y_b), image
    coordinates (column, row from the top).

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


def bake_page(atlas: Atlas, page: int,
              evaluate: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray],
              supersample: int = 2, dilate_texels: int | None = None,
              stitch_iterations: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """rasterize -> evaluate(points, normals, mesh, triangle) -> (K, C) values -> resolve
    -> stitch seams -> dilate (by the atlas padding unless told). The callback is where the
    engine answers (irradiance at points, say); this module never calls the engine."""
    samples = rasterize(atlas, page, supersample)
    points, normals = sample_points(samples, atlas.geometry)
    values = np.asarray(evaluate(points, normals, samples.mesh, samples.triangle))
    image, mask = resolve(samples, values)
    if stitch_iterations > 0:
        image = stitch(image, seam_pairs(atlas, page), stitch_iterations)
    ring = atlas.padding if dilate_texels is None else dilate_texels
    return dilate(image, mask, max(int(ring), 1)), mask


# ----------------------------------------------------------------------------------------
# Writers


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Writes through a temporary sibling and renames it into place: a reader never sees a
    half-written file, and a failure leaves the old file (or none)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


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
