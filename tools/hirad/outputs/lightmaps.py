"""Lightmaps: the atlas pages baked from the solution (interpolated or final-gathered texel samples), written as EXR pages, per-mesh crops, RGBM PNGs and a manifest."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .. import __version__, _engine
from ..report import scene_fingerprint
from ..errors import BakeError
from .meshes import corner_uv, lightmap_units_label, triangulate


def _default_density(lm, patches) -> float:
    """texels_per_metre, or the density that gives a median patch texels_per_patch texels a side."""
    if lm.texels_per_metre is not None:
        return float(lm.texels_per_metre)
    area = np.asarray(patches["area"], dtype=np.float64)
    area = area[area > 0]
    return float(lm.texels_per_patch / np.sqrt(np.median(area))) if area.size else float(lm.texels_per_patch)


def _lift(result, points: np.ndarray, normals: np.ndarray, texel: np.ndarray, epsilon: float,
          reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Leak prevention for texel samples (all of them lie on their own triangles).

    Every sample is lifted `epsilon` along its geometric normal. Then short rays (length
    `reach`, one texel) go out along the normal and 8 tangent directions; when one of them
    first meets the *back* of a surface, the sample is inside or behind geometry (a floor
    texel under a wall standing on it, under a block without a bottom, inside the joint of
    two slabs) and is moved just past that surface and lifted again. Which surface: the one
    in the direction of the texel's samples that are not inside anything (so a texel that
    straddles a wall one texel thick keeps its samples on the side it shows, instead of
    sending half of them through to the far side), else the nearest. Returns (points, moved)."""
    if len(points) == 0:
        return points, np.zeros(0, bool)
    field = result.field  # the solution's one ray-tracing scene
    pts = np.ascontiguousarray(points, dtype=np.float64)
    nrm = np.ascontiguousarray(normals, dtype=np.float64)
    first = field.lift_samples(pts, nrm, float(epsilon), float(reach))
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
    again = field.lift_samples(np.ascontiguousarray(pts[sel]), np.ascontiguousarray(nrm[sel]),
                               float(epsilon), float(reach), np.ascontiguousarray(anchor[t[sel]]))
    out = first_points.copy()
    out[sel] = again.points
    return out, moved


def _bake_page(atlas, page: int, evaluate, supersample: int):
    """hirad.atlas.bake_page, with each sample's texel passed to `evaluate` (for _lift):
    rasterize -> evaluate -> resolve -> stitch seams -> dilate into the padding."""
    from .. import atlas as A

    samples = A.rasterize(atlas, page, supersample)
    points, normals = A.sample_points(samples, atlas.geometry)
    values = np.asarray(evaluate(points, normals, samples.texel))
    image, mask = A.resolve(samples, values)
    image = A.stitch(image, A.seam_pairs(atlas, page))
    return A.dilate(image, mask, max(int(atlas.padding), 1)), mask


def write_lightmaps(cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces,
                     staging: Path, result=None, warn=None) -> tuple[list[str], dict]:
    """Lightmaps on an atlas: every mesh's display faces (what the USD layer shows) go into
    one atlas of pages (hirad.atlas): the mesh's own lightmap UVs when it has them, else
    xatlas charts, at outputs.lightmaps.texels_per_metre with `padding`. Each texel holds
    the incident radiance H/pi at its supersampled surface points (after leak-preventing
    lifting, see _lift), from the display mesh's vertex irradiance ('interpolate') or a
    final gather from the hierarchy ('final_gather'); seams are stitched and the padding
    dilated. Writes lightmaps/pages/page<k>.exr (half float), optional RGBM PNGs,
    lightmaps/manifest.json, and (mesh_files) lightmaps/<mesh>.exr cut out of the pages.
    Each PatchMeshData gets its page file and faceVarying lightmap UVs for the USD layer.
    Returns (per-mesh files or pages, atlas summary for the report)."""
    from .. import atlas as A

    lm = cfg.outputs.lightmaps
    if lm.mode == "final_gather" and (result is None or not result.hierarchical):
        raise BakeError("outputs.lightmaps.mode: final_gather needs a hierarchical bake (method: hierarchical); "
                        "use mode: interpolate for flat bakes")
    t_start = time.perf_counter()
    fingerprint = scene_fingerprint(scene)
    lm_dir = staging / "lightmaps"
    (lm_dir / "pages").mkdir(parents=True)
    density = _default_density(lm, patches)
    nv_all = patches["nv"]

    geometry, existing, names, tri_info, pms = [], [], [], [], []
    for pm, fids in zip(meshes, mesh_faces):
        info = scene.meshes[pm.mesh_index]
        counts = np.asarray(pm.face_vertex_counts)
        tris, face_of, slots = triangulate(counts, np.asarray(pm.face_vertex_indices))
        geometry.append((np.asarray(pm.points, dtype=np.float64), tris))
        if info.has_uv:
            # the mesh's own UV set, carried through the patches to the display corners
            corner = np.array([
                corner_uv(patches["uv"][display["face_patch"][f]], int(nv_all[display["face_patch"][f]]),
                           int(display["face_code"][f][c]))
                for f in fids for c in range(display["face_nv"][f])]).reshape(-1, 2)
            existing.append(corner[slots])
        else:
            existing.append(None)
        names.append(info.name)
        tri_info.append((face_of, slots, int(counts.sum())))
        pms.append(pm)

    atlas = A.build_atlas(geometry, density, lm.padding, lm.max_size, existing_uvs=existing, names=names,
                          existing_layout=lm.existing_layout)
    rep_warnings = list(atlas.warnings)

    # faceVarying lightmap UVs per display face corner, from the triangles' corners
    for k, (pm, layout) in enumerate(zip(pms, atlas.meshes)):
        face_of, slots, n_corners = tri_info[k]
        uv = np.zeros((n_corners, 2))
        if len(layout.uvs):
            flat_slots = slots.reshape(-1)
            flat_uv = layout.uvs.reshape(-1, 2)
            uv[flat_slots] = flat_uv  # a corner shared by two triangles of a quad: same chart, same UV
            again = np.zeros_like(uv)
            again[flat_slots[::-1]] = flat_uv[::-1]
            w, h = atlas.page_sizes[layout.page]
            if np.abs((again - uv) * [w, h]).max() > 1e-3:
                rep_warnings.append(f"{names[k]}: a quad's triangles were charted apart; its lightmap UVs "
                                    "follow the first triangle")
        pm.lightmap_uv = uv

    mode = lm.mode
    field = result.field if result is not None else None

    def evaluate(points, normals, texel):
        reach = 1.0 / density
        lifted, moved = _lift(result, points, normals, texel, lm.sample_offset, reach)
        evaluate.moved += int(moved.sum())
        if mode == "final_gather":
            g = result.gather(lifted, normals, rays=lm.gather_rays)
            values = g["irradiance"] / np.pi
            miss = g["patch"] < 0
        else:
            q = field.probe(np.ascontiguousarray(lifted), np.ascontiguousarray(normals, dtype=np.float64), 1e30)
            values = q.irradiance / np.pi
            miss = q.patch < 0
        if miss.any():  # no surface facing along the normal: take the nearest one
            q = field.probe(np.ascontiguousarray(lifted[miss]), np.zeros((int(miss.sum()), 3)), 1e30)
            values[miss] = q.irradiance / np.pi
        evaluate.samples += len(points)
        return values

    evaluate.moved = 0
    evaluate.samples = 0

    lightmap_units = lightmap_units_label(cfg.units)
    meta_base = [("hirad:units", lightmap_units), ("hirad:version", __version__),
                 ("hirad:sceneFingerprint", fingerprint), ("hirad:texelsPerMetre", f"{density:.9g}"),
                 ("hirad:lightmapMode", mode)]
    page_files, page_images, page_masks, png_files = [], [], [], []
    for page in range(len(atlas.page_sizes)):
        image, mask = _bake_page(atlas, page, evaluate, lm.supersample)
        image = np.ascontiguousarray(image[..., :3], dtype=np.float32)
        rel = f"pages/page{page}.exr"
        _engine.write_exr(str(lm_dir / rel), image, meta_base + [("hirad:page", str(page))])
        page_files.append(rel)
        page_images.append(image)
        page_masks.append(mask)
        if lm.rgbm:
            top = float(lm.rgbm_range) if lm.rgbm_range is not None else float(max(image.max(), 1e-6))
            png = f"pages/page{page}.png"
            A.write_rgbm_png(lm_dir / png, image, top)
            png_files.append({"file": png, "rgbm_range": top})
    elapsed = time.perf_counter() - t_start

    written = []
    for k, (pm, layout) in enumerate(zip(pms, atlas.meshes)):
        info = scene.meshes[pm.mesh_index]
        if layout.page < 0:
            pm.lightmap_uv = None
            continue
        pm.lightmap_path = f"lightmaps/{page_files[layout.page]}"
        of_mesh = patches["mesh"] == pm.mesh_index
        area = patches["area"][of_mesh][:, None]
        if area.sum() > 0:
            pm.lightmap_albedo = tuple((patches["reflectance"][of_mesh] * area).sum(axis=0) / area.sum())
            emitted = (patches["emission"][of_mesh] * area).sum(axis=0) / area.sum() / np.pi
            pm.lightmap_emission = tuple(emitted) if emitted.max() > 0 else None
        if lm.mesh_files:
            w, h = atlas.page_sizes[layout.page]
            bx, by, bw, bh = layout.block
            crop = page_images[layout.page][h - (by + bh):h - by, bx:bx + bw]
            name = f"lightmaps/{info.name}.exr"
            _engine.write_exr(str(staging / name), np.ascontiguousarray(crop, dtype=np.float32),
                              meta_base + [("hirad:mesh", info.path), ("hirad:page", str(layout.page)),
                                           ("hirad:pageBlock", f"{bx} {by} {bw} {bh}")])
            written.append(name)

    texels = sum(w * h for w, h in atlas.page_sizes)
    covered = int(sum(int(m.sum()) for m in page_masks))
    summary = {
        "manifest": "lightmaps/manifest.json",
        "pages": [f"lightmaps/{f}" for f in page_files],
        "page_sizes": [list(s) for s in atlas.page_sizes],
        "mode": mode,
        "texels_per_metre": density,
        "padding": lm.padding,
        "supersample": lm.supersample,
        "fill": [round(f, 6) for f in atlas.fill],
        "covered_texels": covered,
        "samples": evaluate.samples,
        "moved_samples": evaluate.moved,
        "page_bytes_half_rgb": texels * 6,
        "seconds": round(elapsed, 4),
        "texels_per_second": round(covered / elapsed, 1) if elapsed > 0 else None,
        "warnings": rep_warnings,
    }
    extra = {"hirad:version": __version__, "units": lightmap_units, "sceneFingerprint": fingerprint,
             "mode": mode, "supersample": lm.supersample,
             "uvPrimvar": "hirad:lightmapUV (texCoord2f, faceVarying, on the <defaultPrim>/HiradSolution meshes)"}
    if png_files:
        extra["rgbm"] = {"pages": png_files, "decode": "linear = rgb/255 * a/255 * rgbm_range"}
    if lm.mesh_files:
        extra["meshFiles"] = {scene.meshes[pm.mesh_index].name: f"{scene.meshes[pm.mesh_index].name}.exr"
                              for pm, layout in zip(pms, atlas.meshes) if layout.page >= 0}
    A.write_manifest(lm_dir / "manifest.json", atlas, page_files, extra)
    if warn is not None:
        for w in rep_warnings:
            warn(f"outputs.lightmaps: {w}")
    return (written if lm.mesh_files else summary["pages"]), summary
