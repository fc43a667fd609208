"""Shared scene builders for the engine tests: polygons in, hirad._engine.Engine out.

Polygons are lists of 3D corners, counter-clockwise seen from their front (emitting) side.
Reflectance and emission are a scalar, an RGB triple, or one of those per polygon.
"""

from __future__ import annotations

import numpy as np
import pytest

try:
    from hirad import _engine
except ImportError:  # engine not built: the tests that need it skip themselves
    _engine = None

BIG = 1e9  # meshing limit that keeps every face as one patch


def _per_face(value, n: int) -> np.ndarray:
    """Broadcasts a scalar, an RGB triple (a length-3 list is always read as RGB), a per-face
    list of scalars, or an (n, 3) array to shape (n, 3)."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 0 or a.shape == (3,):
        a = np.broadcast_to(a, (n, 3))
    elif a.ndim == 1 and a.shape[0] == n:
        a = np.repeat(a[:, None], 3, axis=1)
    if a.shape != (n, 3):
        raise ValueError(f"expected a scalar, an RGB triple or {n} rows, got shape {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float64)


def make_model(polys, reflectance=0.5, emission=0.0, max_area: float | None = None,
               max_edge: float | None = None, transmittance=None, glass_angular=None):
    """An engine of the polygons (one mesh); meshed when max_area/max_edge are given
    (either one alone: the other is unlimited). `transmittance`: per polygon (or a scalar) the
    glazing's normal transmittance; `glass_angular`: its relative angular table."""
    polys = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in polys]
    n = len(polys)
    points = np.ascontiguousarray(np.concatenate(polys))
    counts = np.array([len(p) for p in polys], dtype=np.int32)
    indices = np.arange(points.shape[0], dtype=np.int32)
    m = _engine.Engine(points, counts, indices, np.zeros(n, np.int32), np.arange(n, dtype=np.int32),
                       _per_face(reflectance, n), _per_face(emission, n),
                       transmittance=None if transmittance is None else
                       np.ascontiguousarray(np.broadcast_to(np.asarray(transmittance, float), (n,))),
                       glass_angular=None if glass_angular is None else np.asarray(glass_angular, float))
    if max_area is not None or max_edge is not None:
        m.mesh(_engine.MeshOptions(max_patch_area=max_area or BIG, max_edge_length=max_edge or BIG))
    return m


def polygon_normal(poly) -> np.ndarray:
    """Unit normal by Newell's method (the side the corners turn counter-clockwise around)."""
    p = np.asarray(poly, dtype=np.float64)
    n = np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)
    return n / np.linalg.norm(n)


def quad(origin, u, v) -> np.ndarray:
    """The parallelogram origin, origin+u, origin+u+v, origin+v (front side along u x v)."""
    o, u, v = (np.asarray(x, dtype=np.float64) for x in (origin, u, v))
    return np.array([o, o + u, o + u + v, o + v])


def box_faces(sx: float = 1.0, sy: float = 1.0, sz: float = 1.0, omit: tuple[str, ...] = ()) -> list:
    """The six faces of [0,sx]x[0,sy]x[0,sz] facing inwards, in the order
    -x, +x, -y, +y, -z, +z (named by the wall's side: 'x0', 'x1', 'y0', 'y1', 'z0', 'z1');
    faces named in `omit` are left out (an open box)."""
    centre = np.array([sx, sy, sz]) / 2
    size = np.array([sx, sy, sz], dtype=np.float64)
    faces = []
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        for side in (0, 1):
            if f"{'xyz'[axis]}{side}" in omit:
                continue
            o = np.zeros(3)
            o[axis] = side * size[axis]
            u = np.zeros(3)
            u[a] = size[a]
            v = np.zeros(3)
            v[b] = size[b]
            q = quad(o, u, v)
            if np.dot(polygon_normal(q), centre - q.mean(axis=0)) < 0:
                q = q[::-1].copy()
            faces.append(q)
    return faces


def parallel_squares(d: float = 1.0, a: float = 1.0) -> list:
    """Two a x a squares facing each other at distance d: [0,a]^2 at z=0 (up) and at z=d (down)."""
    return [quad([0, 0, 0], [a, 0, 0], [0, a, 0]), quad([0, 0, d], [0, a, 0], [a, 0, 0])]


def perpendicular_squares(a: float = 1.0) -> list:
    """Two a x a squares at a right angle sharing the edge x=0, z=0, 0<=y<=a:
    [0,a]^2 in the plane z=0 facing +z, and [0,a]^2 in the plane x=0 facing +x."""
    return [quad([0, 0, 0], [a, 0, 0], [0, a, 0]), quad([0, 0, 0], [0, a, 0], [0, 0, a])]
