"""The solution meshes: the display mesh's faces and vertex values per scene mesh, as written to the USD layer."""

from __future__ import annotations


import numpy as np

from .. import usd


def patch_meshes(scene, patches, display, vertex_radiance, vertex_irradiance, b, h):
    """One PatchMeshData per input mesh from the display faces (patches, or fans of triangles
    where a patch has T-vertices), its points re-indexed; with each, its display faces."""
    faces, face_nv, face_patch = display["faces"], display["face_nv"], display["face_patch"]
    face_mesh = patches["mesh"][face_patch]
    out, faces_of = [], []
    order = np.argsort(face_mesh, kind="stable")
    bounds = np.searchsorted(face_mesh[order], np.arange(len(scene.meshes) + 1))
    for m in range(len(scene.meshes)):
        fids = order[bounds[m]:bounds[m + 1]]
        if fids.size == 0:
            continue
        counts = face_nv[fids].astype(np.int32)
        # each face's first nv corners, face after face: the faces' rows masked, in row order
        # (a list of per-face slices held ~230 bytes a face at once: the USD stage's peak)
        nv = face_nv[fids]
        flat = faces[fids][np.arange(faces.shape[1])[None, :] < nv[:, None]]
        used, local = np.unique(flat, return_inverse=True)
        pids = face_patch[fids]
        out.append(usd.PatchMeshData(
            mesh_index=m, points=display["points"][used], face_vertex_counts=counts,
            face_vertex_indices=local.astype(np.int32), vertex_radiance=vertex_radiance[used],
            vertex_irradiance=vertex_irradiance[used], face_radiance=b[pids] / np.pi, face_irradiance=h[pids]))
        faces_of.append(fids)
    return out, faces_of


def corner_uv(uv: np.ndarray, nv: int, code: int) -> np.ndarray:
    """UV of a display face corner from its patch's corner UVs (see DisplayMesh::face_code)."""
    if code < 4:
        return uv[code]
    if code < 8:
        k = code - 4
        return 0.5 * (uv[k] + uv[(k + 1) % nv])
    return uv[:nv].mean(axis=0)


def lightmap_units_label(units: str) -> str:
    """The lightmaps' hirad:units: H/pi read in the config's unit system."""
    from ..units import label

    return f"{label(units, 'incident')}; final colour = albedo x lightmap"
