"""Helpers for test_proof.py and the energy-balance tests: scenes built with pxr, and the
power that leaves a scene measured by rays, independently of any form factor or link.

Not a test module (no test_ prefix)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

from hirad import _engine

from conftest import box_faces


def write_box_scene(path: Path, size=(1.0, 1.5, 0.8), omit=(), reflectance=None, emission=None) -> Path:
    """A box [0,sx]x[0,sy]x[0,sz] (metres, Y up) of six quads facing inwards, named x0, x1, y0,
    y1, z0, z1 by the wall's side; `omit` leaves walls out (openings). reflectance and
    emission (radiance W/(m^2 sr), so E = pi x this) map wall names to RGB."""
    reflectance = reflectance or {}
    emission = emission or {}
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    names = [f"{'xyz'[axis]}{side}" for axis in range(3) for side in (0, 1)]
    kept = [name for name in names if name not in omit]  # box_faces' order and omissions
    for name, q in zip(kept, box_faces(*map(float, size), omit=tuple(omit)), strict=True):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        mesh.CreatePointsAttr([Gf.Vec3f(*map(float, p)) for p in q])
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        mesh.CreateSubdivisionSchemeAttr("none")
        mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Surface")
        sh.CreateIdAttr("UsdPreviewSurface")
        sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(
            Gf.Vec3f(*map(float, reflectance.get(name, (0.5, 0.5, 0.5)))))
        if name in emission:
            sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*map(float, emission[name])))
        mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()
    return path


def _ray_cast(corners, nv, origins, directions) -> tuple[np.ndarray, np.ndarray]:
    """Patch hit by each ray (-1: none) and whether its back face was hit, from the engine's
    ray casting."""
    corners = np.ascontiguousarray(corners, dtype=np.float64)
    nv = np.ascontiguousarray(nv, dtype=np.int32)
    o = np.ascontiguousarray(origins, dtype=np.float64)
    d = np.ascontiguousarray(directions, dtype=np.float64)
    r = _engine.SurfaceField(corners, nv).ray_cast(o, d)
    return np.asarray(r.patch), np.asarray(r.back).astype(bool)


def _surface_points(corners, nv, rng, owner) -> np.ndarray:
    """A point uniform by area on each listed patch (parallelograms and triangles)."""
    c = corners[owner]
    s, t = rng.random(len(owner)), rng.random(len(owner))
    tri = nv[owner] == 3
    fold = tri & (s + t > 1)
    s, t = np.where(fold, 1 - s, s), np.where(fold, 1 - t, t)
    # a parallelogram p0 + s (p1 - p0) + t (p3 - p0); a triangle p0 + s (p1 - p0) + t (p2 - p0)
    far = np.where(tri[:, None], c[:, 2], c[:, 3])
    return c[:, 0] + (c[:, 1] - c[:, 0]) * s[:, None] + (far - c[:, 0]) * t[:, None]


def escaped_power(corners, nv, normals, radiosity, area, rays_per_patch: int = 1000, seed: int = 1,
                  occluders=None, with_back: bool = False):
    """Power (W, RGB) that leaves the scene through its openings, by Monte Carlo: from every
    patch, `rays_per_patch` rays from points uniform on the patch, cosine distributed about
    its normal (the directions a diffuse surface's power leaves in); a ray that meets no
    surface carries its share of the patch's outgoing power B A away. Returns (escaped (3,),
    standard error (3,), fraction of rays escaping per patch); with `with_back`, also the
    power that meets the back of a one-sided surface (which no front side receives: the
    radiosity system loses it, as it loses what escapes) and its standard error. Only the
    geometry and B are used: no form factor, link or coupling of the solver. `occluders`
    (corners, nv): the geometry the rays are cast against (default: the patches themselves),
    e.g. the scene's input faces from scene_polygons, so the solver's meshing plays no part
    in what escapes."""
    corners = np.asarray(corners, dtype=np.float64)
    nv = np.asarray(nv, dtype=np.int32)
    normals = np.asarray(normals, dtype=np.float64)
    n_p = len(nv)
    rng = np.random.default_rng(seed)
    owner = np.repeat(np.arange(n_p), rays_per_patch)
    pts = _surface_points(corners, nv, rng, owner)
    n = normals[owner] / np.linalg.norm(normals[owner], axis=1, keepdims=True)
    # an orthonormal frame around n
    helper = np.where(np.abs(n[:, [0]]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    u1, u2 = rng.random(len(owner)), rng.random(len(owner))
    r, phi = np.sqrt(u1), 2 * math.pi * u2
    d = (t1 * (r * np.cos(phi))[:, None] + t2 * (r * np.sin(phi))[:, None] + n * np.sqrt(1 - u1)[:, None])
    # Start a little off the surface and in from the patch's edges (1e-5 of the scene's size):
    # Embree takes float32 origins, and one rounded onto a neighbouring wall's plane at a
    # corner could start outside the scene and leave through a closed box.
    scale = float(np.ptp(corners.reshape(-1, 3), axis=0).max())
    centre = corners[owner, :3].mean(axis=1)
    pts = centre + (pts - centre) * (1 - 1e-5) + n * (1e-5 * scale)
    occ_corners, occ_nv = (corners, nv) if occluders is None else occluders
    hit, back = _ray_cast(occ_corners, occ_nv, pts, d)
    power = np.asarray(radiosity, dtype=np.float64) * np.asarray(area, dtype=np.float64)[:, None]

    def share(indicator):
        x = indicator.astype(np.float64).reshape(n_p, rays_per_patch)
        frac = x.mean(axis=1)
        var = x.var(axis=1, ddof=1) / rays_per_patch  # of each patch's fraction
        return (power * frac[:, None]).sum(axis=0), np.sqrt((power ** 2 * var[:, None]).sum(axis=0)), frac

    escaped, se, frac = share(hit < 0)
    if not with_back:
        return escaped, se, frac
    lost, lost_se, _ = share((hit >= 0) & back)
    return escaped, se, frac, lost, lost_se


def scene_polygons(scene) -> tuple[np.ndarray, np.ndarray]:
    """The input faces of a hirad.usd.SceneArrays as (corners (n, 4, 3), nv (n)): triangles
    and quads as they are, larger polygons as fans of triangles (for ray casting against the
    scene as authored, not against any solver's patches)."""
    counts = np.asarray(scene.face_vertex_counts)
    idx = np.asarray(scene.face_vertex_indices)
    pts = np.asarray(scene.points, dtype=np.float64)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    corners, nv = [], []
    for f, c in enumerate(counts):
        poly = pts[idx[offsets[f]:offsets[f + 1]]]
        if c in (3, 4):
            corners.append(np.vstack([poly, poly[-1:]]) if c == 3 else poly)
            nv.append(int(c))
        else:
            for k in range(1, c - 1):
                tri = poly[[0, k, k + 1]]
                corners.append(np.vstack([tri, tri[-1:]]))
                nv.append(3)
    return np.ascontiguousarray(corners, dtype=np.float64), np.asarray(nv, dtype=np.int32)
