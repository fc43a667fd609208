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

Modules, in the order a bake uses them: `base` (the data), `charts` (UVs per mesh),
`pack` (islands and blocks onto pages), `texels` (rasterisation, sampling, dilation,
stitching), `files` (RGBM PNGs and the manifest).
"""

from .base import Atlas, Mesh, MeshLayout, TexelSamples
from .charts import _isolated, build_atlas, chart_area_bound, uv_islands
from .files import (ENCODINGS, decode, decode_rgbm, decode_unity_dldr, decode_unity_rgbm, encode, encode_rgbm,
                    encode_unity_dldr, encode_unity_rgbm, manifest_entry, read_png, read_rgbm_png, write_manifest,
                    write_png, write_rgbm_png)
from .texels import bake_page, dilate, rasterize, resolve, sample_points, seam_pairs, stitch

__all__ = ["Atlas", "Mesh", "MeshLayout", "TexelSamples", "build_atlas", "chart_area_bound", "uv_islands",
           "ENCODINGS", "decode", "decode_rgbm", "decode_unity_dldr", "decode_unity_rgbm", "encode", "encode_rgbm",
           "encode_unity_dldr", "encode_unity_rgbm", "manifest_entry", "read_png", "read_rgbm_png",
           "write_manifest", "write_png", "write_rgbm_png",
           "bake_page", "dilate", "rasterize", "resolve", "sample_points", "seam_pairs", "stitch"]
