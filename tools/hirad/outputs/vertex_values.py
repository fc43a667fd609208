"""The display mesh's vertex values from the final gather (reconstruction.values: final_gather).

The seed's vertex rules average the patches (elements) around a vertex: each element holds one
value, the mean of its light, so a vertex between a lit and a shadowed element gets their mean,
and the value along a wall's foot is that of the coarse elements there (on an independent
path-traced Cornell box, 1.3-3.7 % off on average and up to 30-88 % at single points beside
the blocks, issue 12). Here every display face corner is gathered instead: a point just inside
the face (`INSET` of the way to its centroid, so that no point sits on a polygon edge where the
point-to-polygon form factor of the neighbouring surface is singular), lifted out of geometry
like the lightmaps' texel samples, and gathered from the solution (hierarchical: the links of
its element's chain, flat: every patch). A vertex's value is the mean over the corners that
share it (the faces of one smoothing group, reconstruction.crease_angle). What a renderer then
interpolates between vertices is the gathered field, sampled at the display mesh's vertices.
"""

from __future__ import annotations

import numpy as np

INSET = 0.01   # of the way from a corner to its face's centroid


def gathered_vertex_values(result, display: dict, patches: dict, *, rays: int, importance: float,
                           sample_offset: float) -> tuple[np.ndarray, np.ndarray, int]:
    """(vertex radiance W/(m^2 sr), vertex irradiance W/m^2, corners that found no surface) per
    display vertex, from result.gather at every face corner. Vertices all of whose corners
    found no surface (none in practice) get NaN; the caller keeps its vertex-rule values there."""
    from .lightmaps import _lift

    nv = np.asarray(display["face_nv"], dtype=np.int64)
    quads = np.asarray(display["faces"], dtype=np.int64).reshape(len(nv), -1)  # (F, 4): triangles pad the 4th
    faces = quads[np.arange(quads.shape[1])[None, :] < nv[:, None]]          # their corners, face by face
    points = np.asarray(display["points"], dtype=np.float64)
    nvert = len(points)
    face_of = np.repeat(np.arange(len(nv)), nv)
    corners = points[faces]
    centroid = np.stack([np.bincount(face_of, corners[:, c], minlength=len(nv)) for c in range(3)], axis=1)
    centroid /= np.maximum(nv, 1)[:, None]
    q = corners + INSET * (centroid[face_of] - corners)
    normals = np.asarray(patches["normal"], dtype=np.float64)[np.asarray(display["face_patch"])][face_of]
    # out of geometry (a floor vertex under a block's wall): within a tenth of the face's size
    edge = np.linalg.norm(corners - centroid[face_of], axis=1)
    reach = float(max(1e-4, 0.1 * np.median(edge))) if len(edge) else 1e-3
    lifted, _ = _lift(result, q, normals, faces, sample_offset, reach)
    g = result.gather(lifted, normals, rays=rays, importance=importance)
    hit = np.asarray(g["patch"]) >= 0
    radiance = np.asarray(g["radiance"], dtype=np.float64)
    irradiance = np.asarray(g["irradiance"], dtype=np.float64)
    w = hit.astype(np.float64)
    count = np.bincount(faces, w, minlength=nvert)
    out_r = np.full((nvert, 3), np.nan)
    out_h = np.full((nvert, 3), np.nan)
    some = count > 0
    for c in range(3):
        out_r[some, c] = np.bincount(faces, radiance[:, c] * w, minlength=nvert)[some] / count[some]
        out_h[some, c] = np.bincount(faces, irradiance[:, c] * w, minlength=nvert)[some] / count[some]
    return out_r, out_h, int((~hit).sum())
