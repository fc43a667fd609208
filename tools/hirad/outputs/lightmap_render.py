"""Rendering a baked solution from its lightmaps, as a game engine shows them: each visible
surface point reads its mesh's lightmap page through the `hirad:lightmapUV` primvar
(bilinear), and its colour is albedo x lightmap + emitted radiance, the UsdUVTexture scale
and bias the solution layer stores. It is how a person checks the lightmaps themselves
(seams, leaks, resolution), independently of the solution's own display mesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _engine, usd
from .images import View


class LightmapError(Exception):
    pass


def _texture_terms(solution: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per solution mesh name: (scale RGB, bias RGB) of its lightmap texture."""
    from pxr import Usd, UsdShade

    stage = Usd.Stage.Open(str(solution))
    out = {}
    from ..usd.solution import find_solution_root

    root = find_solution_root(stage)
    for prim in root.GetChildren() if root else []:
        mat = UsdShade.MaterialBindingAPI(prim).GetDirectBinding().GetMaterial()
        tex = mat.GetPrim().GetChild("Lightmap") if mat and mat.GetPrim().IsValid() else None
        scale, bias = np.ones(3), np.zeros(3)
        if tex:
            shader = UsdShade.Shader(tex)
            for name, target in (("scale", scale), ("bias", bias)):
                inp = shader.GetInput(name)
                if inp and inp.Get() is not None:
                    target[:] = np.asarray(inp.Get(), dtype=np.float64)[:3]
        out[prim.GetName()] = (scale, bias)
    return out


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Samples an (H, W, 3) image at UVs (v up, origin bottom-left), clamped at the edges."""
    h, w = image.shape[:2]
    x = np.clip(uv[:, 0] * w - 0.5, 0, w - 1)
    y = np.clip((1.0 - uv[:, 1]) * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return ((image[y0, x0] * (1 - fx) + image[y0, x1] * fx) * (1 - fy)
            + (image[y1, x0] * (1 - fx) + image[y1, x1] * fx) * fy)


def render(solution: str | Path, view: View, width: int, height: int) -> np.ndarray:
    """Radiance (W/(m^2 sr)) seen through `view` from the solution's lightmaps, (H, W, 3)."""
    solution = Path(solution)
    data = usd.read_solution_layer(solution)
    terms = _texture_terms(solution)
    corners, uvs, owner = [], [], []
    for k, m in enumerate(data.meshes):
        if m.lightmap_uv is None or m.lightmap_path is None:
            raise LightmapError(f"{solution}: mesh {m.name} has no lightmap (bake with outputs.lightmaps.enabled)")
        start = 0
        for c in m.face_vertex_counts:
            idx = m.face_vertex_indices[start:start + c]
            for j in range(1, c - 1):   # fan triangles, faceVarying corners start, start+j, start+j+1
                slots = [start, start + j, start + j + 1]
                corners.append(m.points[idx[[0, j, j + 1]]])
                uvs.append(m.lightmap_uv[slots])
                owner.append(k)
            start += c
    corners = np.asarray(corners, dtype=np.float64)
    uvs, owner = np.asarray(uvs, dtype=np.float64), np.asarray(owner)
    quads = np.ascontiguousarray(np.concatenate([corners, corners[:, 2:3]], axis=1))

    # One ray through each pixel centre of the render's own pinhole camera, and the lightmap
    # UV at each hit read by the render's own rule (barycentric on these triangles).
    field = _engine.SurfaceField(quads, np.full(len(quads), 3, np.int32))
    hit = field.camera_rays(list(map(float, view.position)), list(map(float, view.forward)),
                            list(map(float, view.up)), float(view.vertical_fov_degrees), width, height)
    image = np.zeros((height * width, 3))
    patch = hit.patch
    seen = (patch >= 0) & (hit.back == 0)   # back faces show nothing, as in images.render
    tri = patch[seen]
    corner_uv = np.zeros((len(tri), 4, 3))
    corner_uv[:, :3, :2] = uvs[tri]
    corner_uv[:, 3, :2] = uvs[tri, 2]
    uv = _engine.interpolate_corners(np.full(len(tri), 3, np.int32), corner_uv,
                                     np.ascontiguousarray(hit.u[seen]), np.ascontiguousarray(hit.v[seen]))[:, :2]
    pages: dict[str, np.ndarray] = {}
    colour = np.zeros((len(tri), 3))
    for k, m in enumerate(data.meshes):
        sel = owner[tri] == k
        if not sel.any():
            continue
        page = str((solution.parent / m.lightmap_path).resolve())
        if page not in pages:
            if not Path(page).exists():
                raise LightmapError(f"{solution}: lightmap {m.lightmap_path} of mesh {m.name} is missing")
            pages[page] = np.asarray(_engine.read_exr(page), dtype=np.float64)
        scale, bias = terms.get(m.name, (np.ones(3), np.zeros(3)))
        colour[sel] = _bilinear(pages[page], uv[sel]) * scale + bias
    image[seen] = colour
    return image.reshape(height, width, 3).astype(np.float32)
