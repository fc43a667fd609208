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
  places its charts that way and we keep that phase for existing UV layouts and instance
  rectangles too (not inside an instance scaled up from its prototype's smallest member,
  whose layout was charted with one more texel of padding for that reason). Chart
  edges along the axes then run through texel centres rather than along texel borders, so
  float noise in the UVs never flips whether a border texel is covered, and a bilinear
  lookup on such an edge reads only texels the chart covers (elsewhere the dilated
  padding supplies the neighbours).
- Pages are square powers of two up to max_size (floor to a power of two). A mesh lives on
  exactly one page (a renderer has one lightmap index and one scale/offset), so the unit
  that must fit a page is a mesh's set of charts; a mesh too big for a page is scaled down
  as a whole and its achieved density is recorded.
- Who packs what: xatlas charts each mesh (bitmap packer, tight), then every mesh's charts
  go onto pages together through xatlas's UV-mesh packer (`pack._pack_units` chooses each
  page's size and which meshes share it; xatlas places the charts). It stretches every
  chart by less than a texel so the chart's extents are whole texels, so generated charts
  come out slightly denser than asked (small charts the most); the density is measured, not
  assumed. Layouts that must move as one piece (an author's kept layout, an instance of a
  prototype, an author's islands repacked by our skyline packer) go onto pages as one
  rectangle; an engine maps the mesh's own UVs (`MeshLayout.local_uvs`) onto the page by
  `MeshLayout.scale_offset` (Unity's lightmapScaleOffset order).
- Dilation fills the whole page (the padding rings smoothly, the rest from the nearest
  filled texel), so bilinear filtering and every mip level read chart values.
- "Covered" means the texel square and a triangle overlap in a set of positive area
  (conservative rasterisation without the zero-area touches).

Modules, in the order a bake uses them: `base` (the data), `charts` (UVs per mesh),
`pack` (islands and blocks onto pages), `texels` (rasterisation, sampling, dilation,
stitching), `files` (8-bit encodings: hirad RGBM, Unity RGBM and dLDR; the manifest).
"""

from .base import Atlas, Mesh, MeshLayout, TexelSamples
from .charts import _isolated, build_atlas, chart_area_bound, uv_islands
from .files import (ENCODINGS, decode, decode_rgbm, decode_unity_dldr, decode_unity_rgbm, encode, encode_rgbm,
                    encode_unity_dldr, encode_unity_rgbm, manifest_entry, read_png, read_rgbm_png, write_manifest,
                    write_png, write_rgbm_png)
from .texels import bake_page, dilate, evaluate_adaptive, rasterize, resolve, sample_points, seam_pairs, stitch

__all__ = ["Atlas", "Mesh", "MeshLayout", "TexelSamples", "build_atlas", "chart_area_bound", "uv_islands",
           "ENCODINGS", "decode", "decode_rgbm", "decode_unity_dldr", "decode_unity_rgbm", "encode", "encode_rgbm",
           "encode_unity_dldr", "encode_unity_rgbm", "manifest_entry", "read_png", "read_rgbm_png",
           "write_manifest", "write_png", "write_rgbm_png",
           "bake_page", "dilate", "evaluate_adaptive", "rasterize", "resolve", "sample_points", "seam_pairs", "stitch"]
