"""Daylight coefficients: the illuminance at grid sensors per unit luminance of each sky patch.

Why it works
------------
Radiosity is linear in its sources: with the links computed once, the solution for a sky of
patch luminances L_p (and a ground of luminance L_g) is

    B = sum_p L_p B_p + L_g B_g,

B_p the solution for patch p alone at unit luminance (1 cd/m^2, so its distant light has the
perpendicular illuminance Omega_p over directions inside the patch, hirad.daylight.sources).
The engine solves every patch as a light group on the shared final links (one refinement, one
link set, N + 1 cheap solves). The illuminance at a sensor x facing n is linear too:

    E(x) = sum_p L_p DC_p(x),   DC_p(x) = D_p(x) + I_p(x),

* D_p(x) = Omega_p sum_k w_k max(0, n . d_k) T(x, d_k): the patch's own light arriving at x
  directly (through windows with the glazing's transmittance), from the same directions the
  bake uses (SurfaceField.direct_transmittance);
* I_p(x) = pi / m sum over the m hemisphere rays of the reconstructed radiance B_p / pi at the
  ray's hit: the same cosine-distributed rays (same seed) that a point-in-time grid uses
  (SurfaceField.illuminance), traced once for all patches (SurfaceField.hemisphere_hits), the
  radiance interpolated between the display vertices as the grid read-out does.

The matrix DC (sensors x (N + 1), lux per cd/m^2) is what Radiance's rcontrib computes in the
two-phase method; an hour's illuminance is then one row of the sky matrix times DC
(hirad.daylight.annual.annual_illuminance), so 8,760 hours are a matrix product.
"""

from __future__ import annotations

import numpy as np

# Rec. 709 luminance weights (units.py); repeated here as a constant of the method.
_Y = np.array([0.2126, 0.7152, 0.0722])


def _corner_weights(nv: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 4) interpolation weights of a hit at Embree's (u, v): bilinear over quads (u along
    corner 0-1, v along 0-3), barycentric over triangles (corner 3 unused)."""
    quad = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], axis=-1)
    tri = np.stack([1 - u - v, u, v, np.zeros_like(u)], axis=-1)
    return np.where((nv == 4)[..., None], quad, tri)


class HitStencil:
    """The indirect read-out of sensors as sparse weights over display vertices: sensor s reads
    sum_j weight[s, j] x value[vertex[s, j]] (weights include pi / m)."""

    def __init__(self, field, faces: np.ndarray, nv: np.ndarray, points, normals, rays: int, seed: int):
        sensor, patch, u, v, through, m = field.hemisphere_hits(np.ascontiguousarray(points, dtype=np.float64),
                                                               np.ascontiguousarray(normals, dtype=np.float64),
                                                               int(rays), int(seed))
        # one entry per surface a ray reads (through clear glass: the panes met from the front
        # and the surface past them), `through` the glass passed before it (1 without)
        w = _corner_weights(np.asarray(nv)[patch], u, v) * (through * (np.pi / m))[:, None]
        self.sensors = len(points)
        self.row = np.repeat(sensor, 4)
        self.vertex = np.asarray(faces)[patch].reshape(-1)   # (entries * 4)
        self.weight = w.reshape(-1)
        self.rays = m
        self._matrix = None

    def matrix(self, vertices: int):
        """The read-out as a sparse (S, vertices) matrix (repeated vertices summed)."""
        from scipy import sparse

        if self._matrix is None or self._matrix.shape[1] != vertices:
            self._matrix = sparse.csr_matrix((self.weight, (self.row, self.vertex)), shape=(self.sensors, vertices))
        return self._matrix

    def apply(self, vertex_values: np.ndarray) -> np.ndarray:
        """(S, G) from vertex values (V, G) (or (V,) -> (S,))."""
        vals = np.asarray(vertex_values, dtype=np.float64)
        flat = vals.ndim == 1
        if flat:
            vals = vals[:, None]
        out = np.asarray(self.matrix(len(vals)) @ vals)
        return out[:, 0] if flat else out


def direct_coefficients(field, points, normals, lights) -> np.ndarray:
    """(S, G) the direct part: each light's luminance Y at the sensors, with visibility and
    glazing (lights: DistantLightSpec of unit luminance, hirad.daylight.sources)."""
    dirs = np.concatenate([l.directions for l in lights])
    t = field.direct_transmittance(np.ascontiguousarray(points, dtype=np.float64),
                                   np.ascontiguousarray(normals, dtype=np.float64), np.ascontiguousarray(dirs))
    out = np.empty((len(points), len(lights)))
    k = 0
    for g, l in enumerate(lights):
        n = l.count
        w = l.weights if l.tints is None else l.weights * (l.tints @ _Y)
        out[:, g] = (t[:, k:k + n].astype(np.float64) @ w) * l.illuminance * float(_Y @ l.colour)
        k += n
    return out


def daylight_coefficients(field, faces, nv, group_vertex_radiance, points, normals, lights, rays: int,
                          seed: int) -> np.ndarray:
    """(S, G) DC = direct + indirect, lux per unit luminance of each light's group.

    `group_vertex_radiance(g)` returns the display vertices' exitant radiance (V, 3) of group g's
    solution (B_g / pi, reconstructed as the bake's vertex values); `faces` (F, 4) display vertex
    ids and `nv` (F,) of the faces the field was built from (in the field's order)."""
    stencil = HitStencil(field, faces, nv, points, normals, rays, seed)
    direct = direct_coefficients(field, points, normals, lights)
    values = np.stack([np.asarray(group_vertex_radiance(g), dtype=np.float64) @ _Y for g in range(len(lights))],
                      axis=1)
    return direct + stencil.apply(values)
