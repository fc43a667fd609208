"""Fingerprints of a bake's values, for the before/after check of the redesign.

`fingerprint(out_dir)` hashes what a bake computed, and nothing of where it was put:
- every float array authored on the solution meshes (primvars and `hirad:` attributes, the
  points and the lightmap UVs), keyed by the mesh prim's *name* (its parent may move);
- the pixels of every EXR (lightmap pages, per-mesh crops), quantised;
- the grids of volume.vdb, quantised;
- every number of report.json except timings, memory figures and paths.

Run as a script to (re)write the committed reference file for the bundled configs:

    .venv/bin/python tests/python/golden.py --write

The file was first written *before* the redesign moved the engine's code (commit 2971405),
so the test that compares with it (test_golden.py) proved the move kept the physics bit for
bit: all three held through the redesign. It was written again once, on purpose, for the two
hierarchical configs when every refine round's solve began to start from the emission
(commit d67877d, the thin-wall leak fix); cornell.yaml's values are still the originals.
The EXR and volume sections were written again (commit of 2026-12-02) with values quantised to
1e-6 of each array's largest magnitude, and the preview PNG (8-bit codes of the same render as
preview.exr) left out: on an AVX-512 machine Embree's hits and numpy's SIMD power differed in
the last bits from the AVX2 machine that wrote them, flipping hashes of values read at ray hits.
The USD and report sections are still the exact hashes of before. preview.exr was left out
too (stop 19): on an AMD EPYC (Zen 4, AVX-512) machine the bundled code of 64e5bcc, engine and
Python alike, rendered a preview.exr whose quantised hash differs from the Intel machine's
that wrote the file, while every USD, lightmap, volume and report value matched: pinhole
rays that graze an edge land on either side with the CPU (a render, not a solution value).
It was written again for the two hierarchical configs when refinement began to seed its link
estimates by node keys instead of node indices (distributed link generation: a group refined
on another machine numbers its new nodes differently but must draw the same samples); the
estimates are other samples of the same integrals, so the values moved within sampling noise.
It was written again for all three configs when Embree's traversal became robust (watertight,
RTC_SCENE_FLAG_ROBUST, stop 22): rays along a shared edge of two patches had slipped between
them (the daylight bench found the sky seen through a closed ceiling along axis directions), so
form-factor and visibility rays that graze patch edges now hit; the values moved by what those
rays carried.
It was written again for the two hierarchical configs when link estimates began to draw their
visibility points on an element by the form-factor kernel instead of by area
(sample_polygon_by_form_factor) and refinement began to judge close pairs by the bound
min(A_R, A_S) (stop 24: a room on a 200 m ground plane came out 49 % dark); the estimates draw
other samples and the links split differently near contacts.
It was written again for the two hierarchical configs when close or partly visible links of
uneven sources began to be split at the source (hierarchy.spread_epsilon, default 1e-3, stop
25: links carried their sources' mean radiosity into the classroom, +91 % daylight factor); the
Cornell box's links near the boxes' shadows and the walls' contacts split further.
It was written again for all three configs when lightmaps began to be baked on the source
meshes (stop 26, issue 14: charts and texels on the input's own polygons, st1 on the original
prims, square power-of-two pages packed across meshes, whole-page dilation) and the volume
gained the L2 probe grids sh2_0..sh2_8 (report: the probe files): the lightmap pages, the
solution meshes' lightmap UVs and the report's atlas figures changed layout; the solution's
radiance and irradiance primvars did not (they are compared here too and held).
It was written again for the two hierarchical configs when elements began to be measured for
the share of their area inside other geometry (Hierarchy::open, stop 27, issues 12 and 14: the
Cornell box's floor runs on under the blocks, and the elements straddling a block's foot
averaged the dark part in and lost the light their links passed on, -1.5 % over the box, -11 %
at the tall block's foot) and the final gather began to average a source's visibility over its
part above the point's horizon only: the couplings of links to such receivers, their direct
light and every value downstream changed.
It was written again for all three configs when the solved surface's ray-tracing field (the
render, probes, interpolated lightmaps and volume probes read it) began to keep its corner
values as float instead of double (stop 32, issue 12: 100 MB less on the 1M-triangle kitchen's
preview): only EXR and volume values read through the field moved, by float rounding (6e-8
relative) across the 1e-6 quantisation; every USD and report value held bit for bit.
It was written again for all three configs (EXR sections only; USD, volume and report values
held) when the final gather gained its second bounce for close sources (a contact's radiosity
gathered again in cells where the point sees it, stop 32) and a texel's value became the mean
over its visible part (samples moved out of geometry take their texel's free samples' mean).
It was written again for cornell_hierarchical.yaml's EXR section alone (stop 35) when the final
gather's second bounce began to gather a close leaf's far links once at its centre instead of at
every cell (f636959): the lightmap texels moved within the gather's sampling; the same values
came out with the atlas changes of d3ed07c undone, and the USD, volume and report were unchanged.
It was written again for cornell_hierarchical.yaml's report section alone (stop 36) when the
final gather's lightmaps began to lift their texel samples with the engine's own patches and BVH
instead of building the SurfaceField (650 MB on the kitchen): the report's counts.rays now counts
those lift rays, which the field's scene did not; every USD, EXR and volume value held bit for bit.
It was written again for the two hierarchical configs (stop 38, issue 12's cheaper link estimates)
when a link estimate whose polygon end is far from its other end (its diagonal at most the gap
between them, RefineOptions::far) began to use the point-to-point kernel between stratified
points of both ends instead of Lambert's contour sum and Arvo's sampling: an unbiased estimate
of the same integral from other samples, so the links split a little differently and every
value moved within sampling noise. In the same stop the final gather began to take the form factor
of a reflecting (not self-emitting) source far from the point compared with its size by Gauss
quadrature of the kernel (within about 1e-3 of the contour sum, formfactors.h): of the golden
values only cornell_hierarchical.yaml's final-gather lightmap pages (its EXR section) moved.
It was written again for all three configs' EXR sections (stop 40, issue 14) when the lightmaps
stopped stitching chart borders across creases (hirad.atlas.seam_pairs: only where the two
triangles' normals are within reconstruction.crease_angle): only the texels along the blocks'
edges moved (the two blocks' per-mesh crops and page 0); USD, volume and report values held,
and the report section gained stop 39's count lightmap_atlas.interpolated_texels (0 at stride 1).
It was written again for cornell_hierarchical.yaml (stop 41, issue 12's memory) when final-gather
lightmaps began to be baked before the leaves are published: a sample's leaf is found through
the hierarchy's faces (Hierarchy::leaf_at) and samples are lifted against those faces, instead of
the published leaves and their BVH. At points inside a leaf both find that leaf and gather the
same bits (tests/python/hierarchy/test_gather.py); samples on a leaf's edge may go to either
neighbour. Page 0 kept 99.77 % of its texels to the bit, its sum within 4e-5; 26 of 18,679
samples fewer were found inside geometry; and the report's counts.rays began to count the rays
the bake's gathers cast on the hierarchy after its solve (35.3 M -> 74.4 M: before, of the
gathers' rays only the lightmap samples' lift was counted).
It was written again for cornell_hierarchical.yaml (stop 42, issue 12's accuracy) when the final
gather began to trace an emitter's links from the point whatever their estimate saw (a shadow
over a small part of a receiver is missed by the estimate's few point pairs; gather.cpp): page 0's
sum moved by 1e-4, 0.3 % of its texels by more than 1 % (at most 4.8 %); the report's ray count
grew with the rays. In the same stop an emitter's link began to take 4 x 4 rays whatever
gather_rays says (2 x 2 left a penumbra vertex 15 % off): against stop 41's page 0, 0.6 % of the
texels moved by more than 1 %, none by 5 %, the sum by -9e-5.
Two keys were taken out of cornell_outofcore.yaml's report section by hand in stop 44, nothing
rewritten: links.last_solve.state_bytes and minimum_budget, which are memory figures (the
streaming solver's per-node state lost its irradiance and area arrays) and now count as such.
It was written again for the two hierarchical configs (stop 49, issue 12's memory) when the
cluster tree stopped being binary down to single faces: clusters hold up to four faces as
children and have two to four children (hierarchy.h, kClusterFaces), a third as many clusters.
Links end on other clusters, the constructor's nodes are numbered in another order (so every
estimate seeded by a node's key draws other samples), and the open share and closure start
their rays a ray offset in from an element's edge (a floor point drawn 1.3e-7 m from a wall met
the wall at t = 0): the values moved within sampling noise and the links' granularity.
Rewrite it only for a change of the physics or of an output's layout, and say which in the commit.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
GOLDEN = Path(__file__).resolve().parent / "data" / "cornell_golden.json"
CONFIGS = ["cornell.yaml", "cornell_hierarchical.yaml", "cornell_outofcore.yaml"]

# report keys whose numbers depend on the machine or the clock, not on the physics
_VOLATILE = ("second", "time", "timing", "elapsed", "rss", "memory", "bytes_read", "wall", "peak", "path", "store",
             "version", "threads", "throughput", "per_s", "rate", "cpu", "state_bytes", "minimum_budget")


def _digest(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    h = hashlib.sha256()
    h.update(str(a.dtype).encode() + str(a.shape).encode())
    h.update(a.tobytes())
    return h.hexdigest()[:24]


def _quantised(a: np.ndarray) -> np.ndarray:
    """Values read at ray hits (renders, volume probes) to 1e-6 of the array's largest
    magnitude: Embree's kernels and numpy's SIMD loops differ in the last bits between CPUs
    (AVX2, AVX-512), and those bits are not the physics this file holds constant."""
    a = np.asarray(a, dtype=np.float64)
    scale = float(np.abs(a).max()) if a.size else 0.0
    return np.round(a / (scale * 1e-6)).astype(np.int64) if scale > 0 else np.zeros(a.shape, np.int64)


def _usd_arrays(path: Path) -> dict:
    from pxr import Usd, UsdGeom

    layer_stage = Usd.Stage.Open(str(path))
    out = {}
    for prim in layer_stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        spec_names = [a.GetName() for a in prim.GetAuthoredAttributes()]
        # only meshes hirad wrote carry its attributes
        if not any(n.startswith(("primvars:hirad:", "hirad:")) for n in spec_names):
            continue
        for attr in prim.GetAuthoredAttributes():
            name = attr.GetName()
            if not (name.startswith(("primvars:hirad:", "hirad:")) or name in ("points", "faceVertexCounts",
                                                                             "faceVertexIndices")):
                continue
            v = attr.Get()
            if v is None:
                continue
            try:
                a = np.asarray(v)
            except Exception:
                continue
            if a.dtype.kind not in "fiu":
                continue
            out[f"{prim.GetName()}.{name}"] = _digest(a)
    return out


def _exr(path: Path) -> str:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        chans = f.channels()
        parts = [np.asarray(chans[k].pixels) for k in sorted(chans)]
    return _digest(_quantised(np.stack([p.astype(np.float32) for p in parts])))


def _report_numbers(data, prefix="") -> dict:
    out = {}
    if isinstance(data, dict):
        for k, v in data.items():
            key = f"{prefix}.{k}" if prefix else str(k)
            if any(w in str(k).lower() for w in _VOLATILE):
                continue
            out.update(_report_numbers(v, key))
    elif isinstance(data, list):
        nums = [x for x in data if isinstance(x, (int, float)) and not isinstance(x, bool)]
        if nums and len(nums) == len(data):
            out[prefix] = _digest(np.asarray(nums, dtype=np.float64))
        else:
            for i, v in enumerate(data):
                out.update(_report_numbers(v, f"{prefix}[{i}]"))
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        out[prefix] = repr(float(data))
    return out


def fingerprint(out_dir: Path) -> dict:
    out_dir = Path(out_dir)
    fp: dict = {"usd": {}, "exr": {}, "vdb": {}, "report": {}}
    if (out_dir / "solution.usda").exists():
        fp["usd"] = _usd_arrays(out_dir / "solution.usda")
    for p in sorted(out_dir.rglob("*.exr")):
        if p.name == "preview.exr":
            continue
        fp["exr"][str(p.relative_to(out_dir))] = _exr(p)
    if (out_dir / "volume.vdb").exists():
        from hirad import _engine

        grids = _engine.read_vdb(str(out_dir / "volume.vdb"))["grids"]
        for name in sorted(grids):
            g = grids[name]
            order = np.lexsort(np.asarray(g["coords"]).T[::-1])
            fp["vdb"][name] = _digest(np.concatenate([np.asarray(g["coords"], np.float64)[order],
                                                      _quantised(np.asarray(g["values"], np.float64)[order])], axis=1))
    if (out_dir / "report.json").exists():
        fp["report"] = _report_numbers(json.loads((out_dir / "report.json").read_text()))
    return fp


def bake_config(name: str, out_dir: Path) -> Path:
    """Bakes a bundled config into out_dir (its link store beside it) and returns out_dir."""
    from hirad.bake import bake
    from hirad.config import load_config

    cfg = load_config(REPO / "configs" / name)
    cfg.output = Path(out_dir)
    if getattr(cfg, "links", None) is not None and getattr(cfg.links, "store", None) is not None:
        cfg.links.store = Path(str(out_dir) + ".links")
    bake(cfg, quiet=True)
    return Path(out_dir)


def main() -> int:
    import tempfile

    if "--write" not in sys.argv:
        print(__doc__)
        return 2
    golden = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in CONFIGS:
            golden[name] = fingerprint(bake_config(name, Path(tmp) / Path(name).stem))
    GOLDEN.parent.mkdir(parents=True, exist_ok=True)
    GOLDEN.write_text(json.dumps(golden, indent=1, sort_keys=True) + "\n")
    print(f"wrote {GOLDEN}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
