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

    # One ray through each pixel centre of a pinhole camera.
    fwd = view.forward / np.linalg.norm(view.forward)
    right = np.cross(fwd, view.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = np.tan(np.radians(view.vertical_fov_degrees) / 2)
    ys, xs = np.mgrid[0:height, 0:width]
    px = ((xs + 0.5) / width * 2 - 1) * t * width / height
    py = (1 - (ys + 0.5) / height * 2) * t
    dirs = fwd + px[..., None] * right + py[..., None] * up
    dirs = np.ascontiguousarray(dirs.reshape(-1, 3))
    origins = np.ascontiguousarray(np.broadcast_to(np.asarray(view.position, float), dirs.shape))
    hit = _engine.SurfaceField(quads, np.full(len(quads), 3, np.int32)).ray_cast(origins, dirs)

    image = np.zeros((height * width, 3))
    patch = hit.patch
    seen = (patch >= 0) & (hit.back == 0)   # back faces show nothing, as in images.render
    tri = patch[seen]
    p = hit.points[seen]
    a, b, c = corners[tri, 0], corners[tri, 1], corners[tri, 2]
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = np.where(np.abs(d00 * d11 - d01 * d01) > 0, d00 * d11 - d01 * d01, 1.0)
    wb, wc = (d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den
    uv = uvs[tri, 0] * (1 - wb - wc)[:, None] + uvs[tri, 1] * wb[:, None] + uvs[tri, 2] * wc[:, None]
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
