"""The atlas's data: meshes in metres, per-mesh layouts, pages, texel samples, and the small area and density helpers everything here shares."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

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
# xatlas's ChartOptions.maxCost: how much a chart may cost (its normal deviation, roundness,
# straightness and seam terms summed) before it stops growing; xatlas's default is 2. With 2
# the Modern Hall's stepped seating (924 triangles of small planar faces) comes out as 378
# charts whose padding is a third of their footprint (63.7k texels at 16 texels/m and
# padding 2: more than a 256 page holds, so it needs a 512 page of its own and the Hall's
# pages fill 0.66); with 4 it is 126 charts (43.2k texels) and the Hall fills 0.73. The
# price is stretch inside the merged charts: on the seating the area-weighted 95th
# percentile of the texel density goes from 16.9 to 18.8 texels/m (asked 16; median 16.5
# both), over the whole Hall from 16.52 to 16.53. build_atlas(chart_cost=...) overrides it.
_CHART_COST = 4.0
_CHART_TEXELS = 16
_CHART_TRIANGLES = (512, 1024)


# ----------------------------------------------------------------------------------------
# Data


@dataclass
class MeshLayout:
    """Where one mesh went in the atlas.

    `uvs` are final: per triangle corner, in [0, 1] of page `page`. `local_uvs` are the
    mesh's own lightmap UVs (the UV2 an engine stores on the mesh) and `scale_offset` is
    Unity's lightmapScaleOffset (scale.x, scale.y, offset.x, offset.y) that maps them onto
    the page: uvs = local_uvs * (sx, sy) + (ox, oy), exactly.

    - A mesh whose charts were packed among everyone else's (source "generated" without a
      prototype, "existing-repacked"): local_uvs = uvs and scale_offset = (1, 1, 0, 0).
    - A mesh placed as one rectangle: an instance of a prototype (`prototype` set; local_uvs
      are the prototype's layout in [0, 1]^2, shared bit for bit by every instance, and the
      rectangle is the instance's own), or an authored layout kept as it is (source
      "existing"; local_uvs are the author's UVs).
    """

    page: int
    uvs: np.ndarray  # (M, 3, 2) float64
    scale_offset: tuple[float, float, float, float]
    texels_per_metre: float  # achieved: sqrt(UV area in texels^2 / 3D area)
    source: Literal["generated", "existing", "existing-repacked", "empty"]
    charts: np.ndarray  # (M,) int32 atlas-wide chart id; -1 for triangles with no area
    block: tuple[int, int, int, int]  # x, y (from the bottom), width, height in page texels
    local_uvs: np.ndarray | None = None  # (M, 3, 2) float64, see above
    prototype: object = None  # the prototype id given to build_atlas, None for a mesh of its own


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
