"""Lightmaps: the atlas pages baked from the solution (interpolated or final-gathered texel samples), written as EXR pages, per-mesh crops, RGBM PNGs and a manifest."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__, _engine
from ..report import scene_fingerprint
from ..errors import BakeError
from .meshes import lightmap_units_label


def _default_density(lm, patches) -> float:
    """texels_per_metre, or the density that gives a median patch texels_per_patch texels a side."""
    if lm.texels_per_metre is not None:
        return float(lm.texels_per_metre)
    area = np.asarray(patches["area"], dtype=np.float64)
    area = area[area > 0]
    return float(lm.texels_per_patch / np.sqrt(np.median(area))) if area.size else float(lm.texels_per_patch)


def _lift(tracer, points: np.ndarray, normals: np.ndarray, texel: np.ndarray, epsilon: float,
          reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Leak prevention for texel samples (all of them lie on their own triangles).

    Every sample is lifted `epsilon` along its geometric normal. Then short rays (length
    `reach`, one texel) go out along the normal and 8 tangent directions; when one of them
    first meets the *back* of a surface, the sample is inside or behind geometry (a floor
    texel under a wall standing on it, under a block without a bottom, inside the joint of
    two slabs) and is moved just past that surface and lifted again. Which surface: the one
    in the direction of the texel's samples that are not inside anything (so a texel that
    straddles a wall one texel thick keeps its samples on the side it shows, instead of
    sending half of them through to the far side), else the nearest. `tracer`: what holds the
    surfaces and their BVH (_tracer). Returns (points, moved)."""
    if len(points) == 0:
        return points, np.zeros(0, bool)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    nrm = np.ascontiguousarray(normals, dtype=np.float64)
    first = tracer.lift_samples(pts, nrm, float(epsilon), float(reach))
    moved = first.moved.astype(bool)
    first_points = first.points
    if not moved.any():
        return first_points, moved
    # anchor: mean of the texel's free samples (or of all its samples when none is free)
    t = np.asarray(texel, dtype=np.int64)
    nt = int(t.max()) + 1
    free = (~moved).astype(np.float64)
    w_free = np.bincount(t, free, minlength=nt)
    anchor = np.zeros((nt, 3))
    for c in range(3):
        a_free = np.bincount(t, pts[:, c] * free, minlength=nt)
        a_all = np.bincount(t, pts[:, c], minlength=nt) / np.maximum(np.bincount(t, minlength=nt), 1)
        anchor[:, c] = np.where(w_free > 0, a_free / np.maximum(w_free, 1e-300), a_all)
    sel = np.nonzero(moved)[0]
    again = tracer.lift_samples(np.ascontiguousarray(pts[sel]), np.ascontiguousarray(nrm[sel]),
                               float(epsilon), float(reach), np.ascontiguousarray(anchor[t[sel]]))
    out = first_points.copy()
    out[sel] = again.points
    return out, moved


def _tracer(result):
    """What _lift traces against: the engine's own patches and BVH while it holds the solved
    hierarchy for a final gather (the same faces as the display mesh: a second ray-tracing
    scene of them, the SurfaceField, cost the country kitchen's lightmaps some 650 MB), else
    the solution's SurfaceField."""
    model = getattr(result, "_model", None)
    if model is not None and result.hierarchical and model.has_hierarchy and model.leaves_are_patches:
        return model
    return result.field


def _visible_mean(values: np.ndarray, moved: np.ndarray, texel: np.ndarray) -> np.ndarray:
    """A texel's value is the mean over the part of it that is visible: samples that lay inside
    geometry (moved out by _lift) take the mean of their texel's free samples where it has
    any. Moved to a wall's foot they would read the contact itself, the darkest line of the
    texel (with the gather's second bounce: half the visible strata's mean beside a room's
    outer wall), and weigh it as half the texel."""
    moved = np.asarray(moved, dtype=bool)
    if not moved.any():
        return values
    t = np.asarray(texel, dtype=np.int64)
    nt = int(t.max()) + 1
    free = ~moved
    n_free = np.bincount(t[free], minlength=nt).astype(np.float64)
    take = moved & (n_free[t] > 0)
    if not take.any():
        return values
    out = np.array(values, dtype=np.float64, copy=True)
    for c in range(out.shape[1]):
        mean = np.bincount(t[free], out[free, c], minlength=nt) / np.maximum(n_free, 1)
        out[take, c] = mean[t[take]]
    return out


def _bake_page(atlas, page: int, evaluate, supersample: int, stride: int, tolerance: float, crease_angle: float):
    """hirad.atlas.bake_page, with each sample's texel passed to `evaluate` (for _lift):
    rasterize -> evaluate (every texel, or coarse to fine with interpolation between texels
    that agree: stride > 1, hirad.atlas.evaluate_adaptive) -> resolve -> stitch the seams of
    smooth surfaces (normals within `crease_angle` degrees) -> dilate into the padding.
    Returns (image, mask, evaluate_adaptive's counts or {})."""
    from .. import atlas as A

    samples = A.rasterize(atlas, page, supersample)
    points, normals = A.sample_points(samples, atlas.geometry)
    counts = {}
    if stride > 1:
        values, counts = A.evaluate_adaptive(samples, points, normals, evaluate, stride, tolerance)
    else:
        values = np.asarray(evaluate(points, normals, samples.texel))
    image, mask = A.resolve(samples, values)
    image = A.stitch(image, A.seam_pairs(atlas, page, crease_angle))
    return A.dilate(image, mask, max(int(atlas.padding), 1)), mask, counts


def _source_triangles(scene) -> dict:
    """The input's own faces as triangle fans, for all meshes at once: per triangle its mesh,
    its scene face and its three corners (indices into scene.face_vertex_indices, so into the
    mesh's corners as read). A face (c0, c1, ..., cn) -> (c0, ck, ck+1)."""
    counts = np.asarray(scene.face_vertex_counts, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    ntri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), ntri)
    first_tri = np.concatenate([[0], np.cumsum(ntri)[:-1]]).astype(np.int64)
    k = np.arange(int(ntri.sum()), dtype=np.int64) - np.repeat(first_tri, ntri) + 1
    s0 = starts[face]
    corners = np.stack([s0, s0 + k, s0 + k + 1], axis=1)
    return {"face": face, "corner": corners, "mesh": np.asarray(scene.face_mesh)[face],
            "first": first_tri, "count": ntri}


def _locate_in_faces(points: np.ndarray, faces: np.ndarray, fan: dict, tri_xyz: np.ndarray,
                     tri_uv: np.ndarray) -> np.ndarray:
    """UV at points lying on given source faces: each point is located in the face's fan
    triangle that contains it (the largest least barycentric coordinate, so a point on a
    shared diagonal or a hair outside after float noise still finds one) and the triangle's
    corner UVs are interpolated. Exact for planar faces (the patches subdivide the faces)."""
    first, count = fan["first"][faces], np.maximum(fan["count"][faces], 1)
    best = np.full(len(points), -np.inf)
    out = np.zeros((len(points), 2))
    for k in range(int(count.max()) if len(points) else 0):
        t = first + np.minimum(k, count - 1)
        a, b, c = tri_xyz[t, 0], tri_xyz[t, 1], tri_xyz[t, 2]
        e1, e2, d = b - a, c - a, points - a
        d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        d1, d2 = (d * e1).sum(1), (d * e2).sum(1)
        den = d11 * d22 - d12 * d12
        den = np.where(np.abs(den) > 0, den, 1.0)
        v = (d22 * d1 - d12 * d2) / den
        w = (d11 * d2 - d12 * d1) / den
        u = 1.0 - v - w
        score = np.minimum(np.minimum(u, v), w)
        better = score > best
        uv = tri_uv[t, 0] * u[:, None] + tri_uv[t, 1] * v[:, None] + tri_uv[t, 2] * w[:, None]
        out[better] = uv[better]
        best = np.where(better, score, best)
    return out


def _uv_overlap(uv: np.ndarray, cells: int = 0) -> float:
    """The fraction of a UV layout's area covered twice or more: triangles (M, 3, 2) are
    sampled at the centres of a grid over their bounding box (about 16 samples per triangle,
    64 to 2048 a side); a centre strictly inside two triangles is overlapped. Islands that
    merely touch along an edge do not count (centres on an edge are inside neither). Used to
    refuse an author's set that stacks islands (texture UVs, mirrored halves).

    The work is the grid cells under the triangles' bounding boxes. A set whose triangles
    each span the whole layout (a tiled texture set: every quad on [0, 1]^2) would make that
    M x 16 M; the grid is halved (down to 16 a side) until the cells are at most 64 per
    triangle plus 4 million. Only such stacked sets are coarsened, and there the overlap is
    everywhere (the country kitchen's 289 `st` sets, 1.05 M triangles: 77.8 s before, 2.9 s
    now, the same 18 found overlapping)."""
    t = np.asarray(uv, dtype=np.float64).reshape(-1, 3, 2)
    if not len(t):
        return 0.0
    lo, hi = t.reshape(-1, 2).min(axis=0), t.reshape(-1, 2).max(axis=0)
    n = cells or int(np.clip(math.sqrt(16 * len(t)), 64, 2048))
    span = np.maximum(hi - lo, 1e-12)
    unit = (t - lo) / span
    while True:
        g = unit * n  # grid units
        x0 = np.clip(np.floor(g[..., 0].min(axis=1) - 0.5).astype(np.int64), 0, n - 1)
        x1 = np.clip(np.ceil(g[..., 0].max(axis=1) - 0.5).astype(np.int64), 0, n - 1)
        y0 = np.clip(np.floor(g[..., 1].min(axis=1) - 0.5).astype(np.int64), 0, n - 1)
        y1 = np.clip(np.ceil(g[..., 1].max(axis=1) - 0.5).astype(np.int64), 0, n - 1)
        nx, ny = x1 - x0 + 1, y1 - y0 + 1
        if cells or n <= 16 or int((nx * ny).sum()) <= 64 * len(t) + 4_000_000:
            break
        n //= 2
    count = np.zeros(n * n, dtype=np.int32)
    inside_total = 0
    # (a million cells a chunk: some fifteen arrays of that many, about 120 MB at once)
    for chunk in np.array_split(np.arange(len(t)), max(1, int((nx * ny).sum()) // 1_000_000 + 1)):
        k = nx[chunk] * ny[chunk]
        tri = np.repeat(chunk, k)
        off = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
        cx = x0[tri] + off % nx[tri]
        cy = y0[tri] + off // nx[tri]
        px, py = cx + 0.5, cy + 0.5
        a, b, c = g[tri, 0], g[tri, 1], g[tri, 2]
        d = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        sgn = np.sign(d)
        e0 = ((b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (b[:, 1] - a[:, 1]) * (px - a[:, 0])) * sgn
        e1 = ((c[:, 0] - b[:, 0]) * (py - b[:, 1]) - (c[:, 1] - b[:, 1]) * (px - b[:, 0])) * sgn
        e2 = ((a[:, 0] - c[:, 0]) * (py - c[:, 1]) - (a[:, 1] - c[:, 1]) * (px - c[:, 0])) * sgn
        tol = 1e-9 * np.abs(d)
        inside = (e0 > tol) & (e1 > tol) & (e2 > tol) & (sgn != 0)
        np.add.at(count, (cy * n + cx)[inside], 1)
        inside_total += int(inside.sum())
    covered = int((count > 0).sum())
    return float((count > 1).sum()) / covered if covered else 0.0


def _write_directional(lm_dir: Path, page: int, baked: np.ndarray, up_axis: str, meta) -> dict:
    """A page's directional lightmaps from its 18 resolved channels (E/pi, l0, l1 (3 x 3), normal),
    in each engine's world frame (hirad.outputs.probes.engine_frame: Y up; Unity left-handed, x
    negated): Godot 4's four packed L1 SH layers (EXR, linear), Bakery's L0 and RNM0-2 (EXR) and
    Unity's dominant-direction map (8-bit RGBA PNG, linear data: import without sRGB). Returns
    the page's manifest fields."""
    from PIL import Image

    from . import directional as D
    from .probes import engine_frame

    e = baked[..., 0:3].astype(np.float64) * np.pi
    l0 = baked[..., 3:6].astype(np.float64)
    l1 = baked[..., 6:15].astype(np.float64).reshape(baked.shape[:2] + (3, 3))
    n = baked[..., 15:18].astype(np.float64)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(length > 0, n / np.maximum(length, 1e-300), [0.0, 0.0, 1.0])
    out: dict = {}
    godot = D.godot_directional_layers(l0, l1, to_engine=engine_frame(up_axis, "godot"), packed=True)
    files = []
    for j, layer in enumerate(godot):
        rel = f"pages/page{page}.godot_l1_{j}.exr"
        _engine.write_exr(str(lm_dir / rel), np.ascontiguousarray(layer, dtype=np.float32),
                          meta + [("hirad:page", str(page)), ("hirad:layer", ["L0", "L1y", "L1z", "L1x"][j])])
        files.append(rel)
    out["godotL1"] = {"layers": files, "order": "L0, L1 m=-1 (y), m=0 (z), m=1 (x)", "packed": True,
                      "frame": "Godot world (Y up, right-handed)"}
    bakery = D.bakery_sh_textures(l0, l1, to_engine=engine_frame(up_axis, "unity"))
    files = {}
    for key, texture in bakery.items():
        rel = f"pages/page{page}.bakery_{key}.exr"
        _engine.write_exr(str(lm_dir / rel), np.ascontiguousarray(texture, dtype=np.float32),
                          meta + [("hirad:page", str(page)), ("hirad:layer", key)])
        files[key] = rel
    out["bakerySH"] = {**files, "frame": "Unity world (Y up, left-handed, x negated)"}
    _, direction = D.unity_dominant_direction(e, l0, l1, n, to_engine=engine_frame(up_axis, "unity"))
    rel = f"pages/page{page}.unity_dir.png"
    texels = np.clip(np.rint(direction * 255), 0, 255).astype(np.uint8)
    from ..atlas.files import _atomic

    _atomic(lm_dir / rel, lambda tmp: Image.fromarray(texels, mode="RGBA").save(tmp, format="PNG"))
    out["unityDirection"] = rel
    return out


@dataclass
class LightmapPages:
    """What bake_lightmaps leaves for attach_lightmaps: the atlas, the pages written, and per
    atlas mesh (`mesh_index`, scene meshes with patches, in order) what the output layer needs.
    The pages depend on the source meshes, the patches and the solution only, so a final
    gather's pages are baked right after the solve, while the engine holds the hierarchy for
    them anyway; the display mesh, the per-mesh output arrays and the Result come after, when
    the hierarchy and its links are let go (the country kitchen: 1.1 GB less at the peak)."""

    atlas: object                 # hirad.atlas's Atlas
    mesh_index: list              # scene mesh of each atlas mesh
    source_lightmap: dict         # per scene mesh: its layout on the original prim, or None
    fan: dict                     # _source_triangles
    tri_uv: np.ndarray            # (T, 3, 2) page UVs of every source triangle
    density: float                # texels per metre
    mode: str
    meta_base: list               # the pages' EXR metadata
    encodings: list
    page_files: list
    page_images: list             # (h, w, 3) float32 per page, for the per-mesh crops
    page_extra: list              # per page, its manifest fields beyond the file and size
    covered: int                  # texels covered on all pages
    samples: int                  # samples evaluated (gathered or probed)
    moved: int                    # samples lifted out of geometry
    adaptive: dict                # gather_stride > 1: texels interpolated, and why others were gathered
    units: str
    fingerprint: str
    warnings: list
    seconds: float


def _atlas_meshes(patches, n_meshes: int) -> list[int]:
    """The scene meshes the atlas holds: those with patches (the ones patch_meshes makes)."""
    return [int(m) for m in np.nonzero(np.bincount(np.asarray(patches["mesh"], np.int64), minlength=n_meshes))[0]]


def bake_lightmaps(cfg, scene, patches, staging: Path, *, tracer, gather=None, field=None) -> LightmapPages:
    """The atlas of the source meshes and its pages (see write_lightmaps). Texel samples are
    lifted against `tracer` (_tracer: the engine or a SurfaceField) and read by `gather(points,
    normals, **options)` (final_gather: hirad.solution.hierarchical_gather's dict) or probed
    from `field` (interpolate). Writes the pages and their encodings; attach_lightmaps writes
    the rest."""
    from .. import atlas as A

    lm = cfg.outputs.lightmaps
    t_start = time.perf_counter()
    fingerprint = scene_fingerprint(scene)
    lm_dir = staging / "lightmaps"
    (lm_dir / "pages").mkdir(parents=True)
    density = _default_density(lm, patches)

    fan = _source_triangles(scene)
    tri_order = np.argsort(fan["mesh"], kind="stable")
    tri_bounds = np.searchsorted(fan["mesh"][tri_order], np.arange(len(scene.meshes) + 1))
    corner_start = np.concatenate([[0], np.cumsum(scene.face_vertex_counts)]).astype(np.int64)
    # each mesh's first face (a mesh's faces are contiguous): one pass, not one per mesh
    face_start = np.concatenate([[0], np.cumsum(np.bincount(np.asarray(scene.face_mesh, np.int64),
                                                            minlength=len(scene.meshes)))]).astype(np.int64)
    fvi = np.asarray(scene.face_vertex_indices, dtype=np.int64)

    mesh_index = _atlas_meshes(patches, len(scene.meshes))
    geometry, existing, names, prototypes, tri_ids, polygons = [], [], [], [], [], []
    rep_warnings: list[str] = []
    for m in mesh_index:
        info = scene.meshes[m]
        tris = tri_order[tri_bounds[m]:tri_bounds[m + 1]]
        corners = fan["corner"][tris]  # global corner slots
        used, local = np.unique(fvi[corners].reshape(-1), return_inverse=True)
        geometry.append((scene.points[used], local.reshape(-1, 3)))
        own = None
        if info.lightmap_uv is not None:
            first_corner = corner_start[face_start[m]]
            own = np.asarray(info.lightmap_uv)[corners - first_corner]
            overlap = _uv_overlap(own)
            if overlap > 0:
                rep_warnings.append(f"{info.path}: its UV set {info.lightmap_uv_name} overlaps itself "
                                    f"({100 * overlap:.3g} % of its area is covered twice): not usable as "
                                    "lightmap UVs, charts generated instead")
                own = None
        existing.append(own)
        names.append(info.name)
        prototypes.append(info.prototype)
        polygons.append(fan["face"][tris])  # a polygon's triangles stay in one chart
        tri_ids.append(tris)

    atlas = A.build_atlas(geometry, density, lm.padding, lm.max_size, existing_uvs=existing, names=names,
                          existing_layout=lm.existing_layout, polygons=polygons,
                          prototypes=prototypes if any(p is not None for p in prototypes) else None)
    del geometry, existing, polygons
    rep_warnings += list(atlas.warnings)

    # Page UVs of every source triangle, for the display corners; the mesh's own UVs per
    # authored corner, for the original prim.
    tri_uv = np.zeros((len(fan["face"]), 3, 2))
    source_lightmap: dict[int, dict | None] = {}
    deinstanced: set[str] = set()
    for k, (m, layout) in enumerate(zip(mesh_index, atlas.meshes)):
        info = scene.meshes[m]
        source_lightmap[m] = None
        if layout.page < 0 or not len(layout.uvs):
            continue
        tri_uv[tri_ids[k]] = layout.uvs
        # the mesh's own [0, 1] layout and the rectangle that puts it on its page
        local, so = np.asarray(layout.local_uvs, dtype=np.float64), tuple(float(v) for v in layout.scale_offset)
        first_corner = corner_start[face_start[m]]
        slots = (fan["corner"][tri_ids[k]] - first_corner).reshape(-1)
        n_read = int(corner_start[face_start[m + 1]] - first_corner)
        per_corner = np.zeros((n_read, 2))
        per_corner[slots] = local.reshape(-1, 2)
        again = np.zeros_like(per_corner)
        again[slots[::-1]] = local.reshape(-1, 2)[::-1]
        w, h = atlas.page_sizes[layout.page]
        if np.abs((again - per_corner) * [w * so[0], h * so[1]]).max() > 1e-3:
            rep_warnings.append(f"{info.path}: a polygon's triangles were charted apart; its lightmap UVs "
                                "follow its first triangle")
        authored = None
        if info.corner_source is not None:
            authored = np.zeros((info.authored_corners, 2))
            authored[info.corner_source] = per_corner
        source_lightmap[m] = {"uv": authored, "page": int(layout.page), "scale_offset": so,
                              "author_path": info.author_path, "prim": info.path, "prototype": info.prototype,
                              "source": layout.source, "deinstance": info.deinstance,
                              "instance_root": info.instance_root}
        for root in info.deinstance:
            if root not in deinstanced:
                deinstanced.add(root)
                rep_warnings.append(
                    f"{root}: a native instance whose prototype the output layer cannot author over (it "
                    f"references another file, is nested, or its referenced mesh is drawn itself): made "
                    f"non-instanceable in solution.usda so that its meshes carry their own {lm.uv_set}")
    del tri_ids

    mode = lm.mode

    def evaluate(points, normals, texel):
        reach = 1.0 / density
        lifted, moved = _lift(tracer, points, normals, texel, lm.sample_offset, reach)
        evaluate.moved += int(moved.sum())
        if mode == "final_gather":
            options = dict(rays=lm.gather_rays, directional=lm.directional, importance=lm.gather_importance,
                           second_bounce=lm.gather_second_bounce)
            g = gather(lifted, normals, **options)
            values = g["irradiance"] / np.pi
            miss = g["patch"] < 0
            if miss.any():  # no surface facing along the normal: gathered at the nearest one
                again = gather(np.ascontiguousarray(lifted[miss]), np.zeros((int(miss.sum()), 3)), **options)
                values[miss] = again["irradiance"] / np.pi
        else:
            q = field.probe(np.ascontiguousarray(lifted), np.ascontiguousarray(normals, dtype=np.float64), 1e30)
            values = q.irradiance / np.pi
            miss = q.patch < 0
            if miss.any():  # no surface facing along the normal: take the nearest one
                q = field.probe(np.ascontiguousarray(lifted[miss]), np.zeros((int(miss.sum()), 3)), 1e30)
                values[miss] = q.irradiance / np.pi
        evaluate.samples += len(points)
        if not lm.directional:
            return _visible_mean(values, moved, texel)
        # Per sample E/pi, the hemisphere's moments l0, l1 and the normal, resolved per texel
        # like the colour (18 channels). Where the gather found no element (read from the
        # nearest surface instead) the light is taken as uniform over the hemisphere:
        # l0 = 2 E, l1 = E n (E1 = l0/4 + n.l1/2 = E).
        l0 = np.asarray(g["l0"], dtype=np.float64).copy()
        l1 = np.asarray(g["l1"], dtype=np.float64).reshape(-1, 9).copy()
        if miss.any():
            e = np.pi * values[miss]
            l0[miss] = 2.0 * e
            l1[miss] = (e[:, :, None] * np.asarray(normals)[miss][:, None, :]).reshape(-1, 9)
        return _visible_mean(np.concatenate([values, l0, l1, np.asarray(normals, dtype=np.float64)], axis=1), moved,
                             texel)

    evaluate.moved = 0
    evaluate.samples = 0
    evaluate.texels = {}

    lightmap_units = lightmap_units_label(cfg.units)
    meta_base = [("hirad:units", lightmap_units), ("hirad:version", __version__),
                 ("hirad:sceneFingerprint", fingerprint), ("hirad:texelsPerMetre", f"{density:.9g}"),
                 ("hirad:lightmapMode", mode)]
    page_files, page_images, covered, page_extra = [], [], 0, []
    encodings = list(dict.fromkeys((["hirad-rgbm"] if lm.rgbm else []) + list(lm.encodings)))
    for page in range(len(atlas.page_sizes)):
        stride = lm.gather_stride if mode == "final_gather" else 1
        baked, mask, counts = _bake_page(atlas, page, evaluate, lm.supersample, stride, lm.gather_tolerance,
                                         cfg.reconstruction.crease_angle)
        for k, v in counts.items():
            evaluate.texels[k] = evaluate.texels.get(k, 0) + v
        image = np.ascontiguousarray(baked[..., :3], dtype=np.float32)
        rel = f"pages/page{page}.exr"
        _engine.write_exr(str(lm_dir / rel), image, meta_base + [("hirad:page", str(page))])
        page_files.append(rel)
        page_images.append(image)
        covered += int(mask.sum())
        extra_k: dict = {}
        for enc in encodings:
            top = None
            if enc == "hirad-rgbm":
                top = float(lm.rgbm_range) if lm.rgbm_range is not None else float(max(image.max(), 1e-6))
            png = f"pages/page{page}.png" if enc == "hirad-rgbm" else f"pages/page{page}.{enc}.png"
            A.write_png(lm_dir / png, image, enc, top)
            extra_k.setdefault("encoded", {})[enc] = {"file": png, **({"rgbm_range": top} if top else {})}
        if lm.directional:
            extra_k.update(_write_directional(lm_dir, page, baked, scene.up_axis, meta_base))
        page_extra.append(extra_k)
    return LightmapPages(atlas=atlas, mesh_index=mesh_index, source_lightmap=source_lightmap, fan=fan, tri_uv=tri_uv,
                         density=density, mode=mode, meta_base=meta_base, encodings=encodings,
                         page_files=page_files, page_images=page_images, page_extra=page_extra, covered=covered,
                         samples=evaluate.samples, moved=evaluate.moved, adaptive=evaluate.texels, units=lightmap_units,
                         fingerprint=fingerprint, warnings=rep_warnings, seconds=time.perf_counter() - t_start)


def attach_lightmaps(pages: LightmapPages, cfg, scene, patches, display, meshes, mesh_faces, staging: Path,
                     warn=None) -> tuple[list[str], dict]:
    """Ties baked pages to the output meshes (see write_lightmaps): each PatchMeshData's
    `source_lightmap`, its display corners' page UVs `lightmap_uv`, its page, albedo and
    emission; the per-mesh crops (mesh_files) and lightmaps/manifest.json. Returns (per-mesh
    files or pages, atlas summary for the report)."""
    from .. import atlas as A

    lm = cfg.outputs.lightmaps
    t_start = time.perf_counter()
    atlas, fan = pages.atlas, pages.fan
    layout_of = dict(zip(pages.mesh_index, atlas.meshes))
    for pm in meshes:
        if pm.mesh_index not in layout_of:
            raise BakeError(f"lightmaps: mesh {scene.meshes[pm.mesh_index].path} has display faces but no patches "
                            "in the atlas (internal error)")
    tri_xyz = np.asarray(scene.points)[np.asarray(scene.face_vertex_indices, dtype=np.int64)[fan["corner"]]]
    # faceVarying page UVs per display corner: each corner located in its source face (the
    # scene face of the patch's mesh and authored face)
    scene_key = np.asarray(scene.face_mesh, np.int64) << 32 | np.asarray(scene.face_source, np.int64)
    key_order = np.argsort(scene_key, kind="stable")
    patch_key = np.asarray(patches["mesh"], np.int64) << 32 | np.asarray(patches["source_face"], np.int64)
    patch_face = key_order[np.clip(np.searchsorted(scene_key[key_order], patch_key), 0, len(key_order) - 1)]
    written, instances = [], []
    for pm, fids in zip(meshes, mesh_faces):
        layout = layout_of[pm.mesh_index]
        info = scene.meshes[pm.mesh_index]
        pm.source_lightmap = pages.source_lightmap[pm.mesh_index]
        pm.lightmap_uv = None
        if layout.page < 0:
            continue
        if len(layout.uvs):
            counts = np.asarray(pm.face_vertex_counts)
            src_face = np.repeat(patch_face[display["face_patch"][fids]], counts)
            pts = np.asarray(pm.points)[np.asarray(pm.face_vertex_indices)]
            pm.lightmap_uv = _locate_in_faces(pts, src_face, fan, tri_xyz, pages.tri_uv)
        pm.lightmap_path = f"lightmaps/{pages.page_files[layout.page]}"
        if pm.source_lightmap is not None:
            pm.source_lightmap.update(file=pm.lightmap_path, uv_set=lm.uv_set)
        of_mesh = patches["mesh"] == pm.mesh_index
        area = patches["area"][of_mesh][:, None]
        if area.sum() > 0:
            pm.lightmap_albedo = tuple((patches["reflectance"][of_mesh] * area).sum(axis=0) / area.sum())
            emitted = (patches["emission"][of_mesh] * area).sum(axis=0) / area.sum() / np.pi
            pm.lightmap_emission = tuple(emitted) if emitted.max() > 0 else None
        if lm.mesh_files:
            w, h = atlas.page_sizes[layout.page]
            bx, by, bw, bh = layout.block
            crop = pages.page_images[layout.page][h - (by + bh):h - by, bx:bx + bw]
            name = f"lightmaps/{info.name}.exr"
            _engine.write_exr(str(staging / name), np.ascontiguousarray(crop, dtype=np.float32),
                              pages.meta_base + [("hirad:mesh", info.path), ("hirad:page", str(layout.page)),
                                                 ("hirad:pageBlock", f"{bx} {by} {bw} {bh}")])
            written.append(name)
        sl = pm.source_lightmap
        if sl is not None:
            instances.append({"prim": sl["prim"], "mesh": sl["author_path"], "prototype": sl["prototype"],
                              "page": sl["page"], "file": pages.page_files[sl["page"]],
                              "scaleOffset": [float(v) for v in sl["scale_offset"]], "uvSet": lm.uv_set,
                              "uvSource": sl["source"], "texelsPerMetre": float(layout.texels_per_metre)})

    elapsed = pages.seconds + (time.perf_counter() - t_start)
    texels = sum(w * h for w, h in atlas.page_sizes)
    rep_warnings = pages.warnings
    summary = {
        "manifest": "lightmaps/manifest.json",
        "pages": [f"lightmaps/{f}" for f in pages.page_files],
        "page_sizes": [list(s) for s in atlas.page_sizes],
        "mode": pages.mode,
        "texels_per_metre": pages.density,
        "padding": lm.padding,
        "supersample": lm.supersample,
        "fill": [round(f, 6) for f in atlas.fill],
        "covered_texels": pages.covered,
        "samples": pages.samples,
        "moved_samples": pages.moved,
        "interpolated_texels": pages.adaptive.get("interpolated", 0),
        **({"gather_stride": lm.gather_stride, "gather_tolerance": lm.gather_tolerance,
            "gathered_texels": {k: pages.adaptive.get(k, 0) for k in ("lattice", "not_interpolable", "apart",
                                                                      "disagree")}}
           if pages.mode == "final_gather" and lm.gather_stride > 1 else {}),
        "page_bytes_half_rgb": texels * 6,
        "seconds": round(elapsed, 4),
        "texels_per_second": round(pages.covered / elapsed, 1) if elapsed > 0 else None,
        "warnings": rep_warnings,
    }
    page_list = [{"file": f, "width": w, "height": h, "fill": round(fill, 6), **more}
                 for f, (w, h), fill, more in zip(pages.page_files, atlas.page_sizes, atlas.fill, pages.page_extra)]
    extra = {"version": 2, "hirad:version": __version__, "pages": page_list,
             "encodings": {e: A.ENCODINGS[e] for e in pages.encodings}, "units": pages.units,
             "sceneFingerprint": pages.fingerprint, "mode": pages.mode, "supersample": lm.supersample,
             "value": "incident radiance H/pi per texel (linear); a Lambertian surface shows albedo x value",
             "uvSet": lm.uv_set,
             "uvPrimvar": (f"primvars:{lm.uv_set} (texCoord2f, faceVarying) on each original mesh prim: the "
                           "mesh's own [0, 1] lightmap UVs; page_uv = uv * scaleOffset.xy + scaleOffset.zw. "
                           "The solution meshes carry page UVs as hirad:lightmapUV."),
             "uvOrigin": "bottom-left (USD texCoord2f, v up); image row 0 is the top of the page",
             "engines": {"unity": {"flipV": False, "scaleOffset": "lightmapScaleOffset as is"},
                         "godot": {"flipV": True, "rule": "v' = 1 - v (top-left origin)"},
                         "unreal": {"flipV": True, "rule": "v' = 1 - v (top-left origin)"},
                         "gltf": {"flipV": True, "rule": "v' = 1 - v (top-left origin)"}},
             "instances": instances, "warnings": rep_warnings}
    A.write_manifest(staging / "lightmaps" / "manifest.json", atlas, pages.page_files, extra)
    if warn is not None:
        for w in rep_warnings:
            warn(f"outputs.lightmaps: {w}")
    return (written if lm.mesh_files else summary["pages"]), summary


def write_lightmaps(cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces,
                     staging: Path, result=None, warn=None) -> tuple[list[str], dict]:
    """Lightmaps baked on the source meshes: every input mesh's own faces (triangle fans of
    the authored polygons, in world metres) go into one atlas of pages (hirad.atlas): the
    mesh's own lightmap UV set when it has one (outputs.lightmaps.uv_primvars), else xatlas
    charts, at outputs.lightmaps.texels_per_metre with `padding`. Each texel holds the
    incident radiance H/pi at its supersampled surface points (after leak-preventing
    lifting, see _lift), from the solution's vertex irradiance ('interpolate') or a final
    gather from the hierarchy ('final_gather'); seams are stitched and the page dilated.
    Writes lightmaps/pages/page<k>.exr (half float), optional RGBM PNGs,
    lightmaps/manifest.json, and (mesh_files) lightmaps/<mesh>.exr cut out of the pages.

    Each PatchMeshData gets (a) `source_lightmap`: the mesh's own UVs per authored corner
    (faceVarying on the original prim, outputs.lightmaps.uv_set), its page and scaleOffset,
    and (b) `lightmap_uv`: page UVs at its display corners, found by locating each display
    corner in its source face (the solution meshes subdivide the source faces), so the
    solution layer's meshes show the same pages. bake_lightmaps then attach_lightmaps: a bake
    with final-gather lightmaps calls them apart (the pages before the reconstruction).
    Returns (per-mesh files or pages, atlas summary for the report)."""
    pages = bake_lightmaps(cfg, scene, patches, staging, **lightmap_sources(cfg, result))
    return attach_lightmaps(pages, cfg, scene, patches, display, meshes, mesh_faces, staging, warn)


def lightmap_sources(cfg, result=None, model=None) -> dict:
    """bake_lightmaps' tracer and gather (final_gather) or field (interpolate): from a Result,
    or, for a final gather before the Result exists, from the engine model holding the solved
    hierarchy (its leaves published as the patches)."""
    from ..solution import hierarchical_gather

    lm = cfg.outputs.lightmaps
    if lm.mode == "final_gather":
        if model is None and (result is None or not result.hierarchical):
            raise BakeError("outputs.lightmaps.mode: final_gather needs a hierarchical bake (method: hierarchical); "
                            "use mode: interpolate for flat bakes")
        if model is not None:
            return {"tracer": model, "gather": lambda p, n, **o: hierarchical_gather(model, p, n, **o)}
        return {"tracer": _tracer(result), "gather": result.gather}
    return {"tracer": _tracer(result), "field": result.field}
