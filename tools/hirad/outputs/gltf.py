"""glTF 2.0 (GLB) export of a baked scene: the artist's ORIGINAL meshes with their materials and
the lightmap pages, for engines and viewers that read glTF (three.js, Babylon.js, Godot, Blender).

What is read
    OUT/solution.usda composed over the input (it sublayers it), through usd-core. Every visible
    UsdGeom.Mesh (instance proxies included; guide/proxy purposes and invisible prims skipped)
    with its world transform, `orientation`, authored normals, texture UVs (`st`) and the
    lightmap UVs of the lightmap contract (`primvars:st1`, faceVarying, one value per authored
    corner, USD convention: v up, origin bottom-left), and per instance its page and Unity-order
    scaleOffset (page_uv = st1 * xy + zw) from OUT/lightmaps/manifest.json ("instances"), else
    from the prim's `hirad:lightmap:*` attributes; a copy whose entry names another mesh
    ("mesh", a prototype's) takes that mesh's UV set (a mesh inside a native instance sees the
    UV set the layer put on the mesh its instances reference, or its own where the layer
    de-instanced it; a mesh with a page and no UV set is exported without its lightmap, with a
    warning). A PointInstancer's copies are nodes of their own (the prototype mesh
    at the copy's transform, the copy's page and rectangle from the manifest entry of its path,
    the UV set the prototype's; nested instancers and lights in prototypes are named in a
    warning, as the bake reads them). Visibility is the
    input's: the solution layer hides the original meshes under its own display meshes, so its
    own visibility opinions are skipped, and its display meshes are not exported. Pages are
    OUT/lightmaps/pages/page<k>.exr, linear RGB, value = incident radiance H/pi in W/(m^2 sr)
    (H the irradiance in W/m^2), row 0 the top of the page.

Geometry
    glTF is metres, +Y up, right-handed, counter-clockwise front faces. Points are taken to world
    space (the prim's local-to-world matrix), scaled by the stage's metersPerUnit and, for a Z-up
    stage, rotated by -90 deg about X ((x, y, z) -> (x, z, -y)). Normals go through the inverse
    transpose of the same linear map. A left-handed mesh, or a mirroring transform (det < 0), has
    its winding reversed. Each polygon is fanned into triangles (exact for convex polygons; a
    concave polygon is named in a warning). glTF has one index per vertex for all attributes, so
    faceVarying data (normals, UVs) is expanded to one vertex per triangle corner and then equal
    corners (same position, normal and UVs, bit for bit) are merged again: a vertex is split
    exactly where any of its attributes differs between faces (UV seams, creases).

UVs
    glTF's UV origin is the top-left of the image (v down), USD's the bottom-left (v up), so
    TEXCOORD_n = (u, 1 - v) for both sets. TEXCOORD_0 is the texture set `st` when present;
    TEXCOORD_1 is the mesh's own lightmap set st1 (in [0, 1]^2, shared by instances of one
    prototype). The instance's rectangle on the page is a scale/offset that must follow the
    flip: with t = 1 - v, page_v_gltf = 1 - (v*sy + oy) = t*sy + (1 - sy - oy), so the glTF
    scaleOffset is (sx, sy, ox, 1 - sy - oy).

Materials (UsdPreviewSurface -> glTF metallic-roughness)
    diffuseColor (value, or a UsdUVTexture's file: PNG/JPEG embedded as is, other formats through
    Pillow to PNG) -> baseColorFactor / baseColorTexture (TEXCOORD_0); metallic, roughness ->
    metallicFactor, roughnessFactor; emissiveColor -> emissiveFactor (normalised to <= 1) times
    KHR_materials_emissive_strength (the max component), so emitters keep their radiance;
    opacity < 1 -> alphaMode BLEND; useSpecularWorkflow with a black specularColor ->
    KHR_materials_specular specularFactor 0 (a purely diffuse surface). Without a bound material
    primvars:displayColor is the base colour. A texture's scale/bias, wrap modes other than
    repeat and other shader inputs are not converted (named in a warning).

Lightmaps: two mappings of the same pages
    1. The engine-neutral lightmap (for importers and scripts): each page as an RGBM PNG, in the
       GLB's `images`; each lightmapped node's `extras.hirad_lightmap` names the image, the
       texCoord (1), the glTF scaleOffset and the USD one, and the decode
           value = (r/255) * (a/255) * range     (linear, no sRGB transfer)
       in W/(m^2 sr) (incident radiance H/pi; irradiance E = pi * value). RGBM with a per-page
       range keeps the HDR span (8 bits of mantissa over 255:1 of exponent, 65025:1 in all) where
       a plain 8-bit PNG would clip or band; it is linear RGBM, not Unity's gamma-space RGBM.
       In three.js: decode to a float texture, `material.lightMap = tex; tex.channel = 1;
       material.lightMapIntensity = Math.PI` (three.js adds texel * lightMapIntensity to the
       irradiance and shades it with BRDF_Lambert = albedo/pi), tex.offset/repeat = scaleOffset.
    2. Without any script: an emissive mapping. A second, sRGB-encoded PNG per page holds
       value/S (S = the page's largest value); the node's material gets emissiveTexture =
       that page on TEXCOORD_1 with KHR_texture_transform = the instance's rectangle,
       emissiveFactor = the material's albedo (its mean, when it is a texture) and
       KHR_materials_emissive_strength = S, so any viewer shows albedo x H/pi, the exitant
       radiance of the Lambertian surface, with no light in the scene. Limits: the albedo in
       it is the material's mean (texture detail is not multiplied in), the 8-bit sRGB code
       steps are ~0.4 % near the page maximum and a few % two decades below it, viewers' own
       lights add on top (turn them off), and a material with its own emission keeps that and
       gets no lightmap emission. The material's extras say `hirad_emissive_is_lightmap: true`
       so an importer that uses mapping 1 drops the emissive texture. glTF's occlusionTexture
       is not used: it is a [0, 1] factor on the viewer's ambient light, not light.

References: glTF 2.0 specification (Khronos, 2021) sections 3.7 (geometry), 3.9 (materials),
5.x (schema); KHR_texture_transform, KHR_materials_emissive_strength, KHR_materials_specular;
UsdPreviewSurface specification (Pixar); three.js r187 src/renderers/shaders/ShaderChunk/
lights_fragment_maps.glsl.js and common.glsl.js (BRDF_Lambert).
"""

from __future__ import annotations

import io
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BakeError

GLB_NAME = "scene.glb"


class GltfExportError(BakeError):
    """The export cannot go on: the message names the file, the prim and the problem."""


class GltfExportWarning(UserWarning):
    """A feature of the scene that the export does not honour."""


# ---------------------------------------------------------------------------------------------
# reading the composed stage
# ---------------------------------------------------------------------------------------------


def _corner_values(pv, counts: np.ndarray, indices: np.ndarray, n_points: int, where: str) -> np.ndarray | None:
    """A primvar expanded to one row per authored corner (faceVertexIndices entry)."""
    from pxr import UsdGeom

    if not pv or not pv.HasAuthoredValue():
        return None
    vals = pv.ComputeFlattened()
    if vals is None:
        return None
    vals = np.asarray(vals, dtype=np.float64)
    if vals.ndim == 1:
        vals = vals[:, None]
    return _expand(vals, pv.GetInterpolation(), counts, indices, n_points, where, pv.GetName())


def _expand(vals: np.ndarray, interp, counts: np.ndarray, indices: np.ndarray, n_points: int, where: str,
            name: str) -> np.ndarray:
    """Values of one interpolation (constant, uniform, vertex/varying, faceVarying) -> per corner."""
    from pxr import UsdGeom

    n_corners, n_faces = len(indices), len(counts)
    if interp == UsdGeom.Tokens.faceVarying:
        want, out = n_corners, vals
    elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        want = n_points
        out = vals[indices] if len(vals) == n_points else None
    elif interp == UsdGeom.Tokens.uniform:
        want = n_faces
        out = np.repeat(vals, counts, axis=0) if len(vals) == n_faces else None
    else:  # constant
        want = 1
        out = np.repeat(vals[:1], n_corners, axis=0) if len(vals) >= 1 else None
    if out is None or len(out) != n_corners:
        raise GltfExportError(f"{where}: {name} ({interp}) has {len(vals)} values, "
                              f"{want} expected")
    return out


@dataclass
class _Material:
    key: str
    base_color: np.ndarray = field(default_factory=lambda: np.array([0.18, 0.18, 0.18]))
    base_texture: Path | None = None
    opacity: float = 1.0
    metallic: float = 0.0
    roughness: float = 0.5    # UsdPreviewSurface's default
    emissive: np.ndarray = field(default_factory=lambda: np.zeros(3))
    diffuse_only: bool = False


def _shader_input(shader, name):
    """(value, connected UsdUVTexture shader or None) of a UsdPreviewSurface input."""
    from pxr import UsdShade

    inp = shader.GetInput(name)
    if not inp:
        return None, None
    if inp.HasConnectedSource():
        src = inp.GetConnectedSources()[0]
        if src:
            s = UsdShade.Shader(src[0].source.GetPrim())
            if s and s.GetIdAttr().Get() == "UsdUVTexture":
                return None, s
        vals = inp.GetValueProducingAttributes()
        if vals:
            return vals[0].Get(), None
        return None, None
    return inp.Get(), None


def _read_material(prim, stage_dir: Path, cache: dict, warn) -> _Material:
    from pxr import UsdGeom, UsdShade

    mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not mat:
        m = _Material(key="displayColor:" + str(prim.GetPath()))
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
        if pv and pv.HasAuthoredValue():
            v = np.asarray(pv.ComputeFlattened(), dtype=np.float64).reshape(-1, 3)
            if len(v):
                m.base_color = v.mean(axis=0)
                if len(v) > 1:
                    warn(f"{prim.GetPath()}: displayColor varies over the mesh; its mean is the base colour")
        m.roughness = 1.0
        m.diffuse_only = True
        return m
    key = str(mat.GetPath())
    if key in cache:
        return cache[key]
    m = _Material(key=key)
    shader = mat.ComputeSurfaceSource()[0]
    if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
        warn(f"{key}: surface shader is not a UsdPreviewSurface; exported as a grey diffuse material")
        cache[key] = m
        return m
    val, tex = _shader_input(shader, "diffuseColor")
    if tex is not None:
        asset = tex.GetInput("file").Get() if tex.GetInput("file") else None
        path = Path(asset.resolvedPath) if asset is not None and asset.resolvedPath else None
        if path is None or not path.exists():
            warn(f"{key}: diffuseColor texture {asset} cannot be resolved; the fallback colour is used")
            fb = tex.GetInput("fallback")
            if fb and fb.Get() is not None:
                m.base_color = np.asarray(fb.Get(), dtype=np.float64)[:3]
        else:
            m.base_texture = path
            for name in ("scale", "bias"):
                i = tex.GetInput(name)
                if i and i.Get() is not None and list(i.Get())[:3] != ([1.0] * 3 if name == "scale" else [0.0] * 3):
                    warn(f"{key}: the texture's {name} is not converted")
            m.base_color = np.ones(3)
    elif val is not None:
        m.base_color = np.asarray(val, dtype=np.float64)[:3]
    for name, attr in (("metallic", "metallic"), ("roughness", "roughness"), ("opacity", "opacity")):
        v, t = _shader_input(shader, name)
        if t is not None:
            warn(f"{key}: a {name} texture is not converted (its factor is kept at the default)")
        elif v is not None:
            setattr(m, attr, float(v))
    v, t = _shader_input(shader, "emissiveColor")
    if t is not None:
        warn(f"{key}: an emissiveColor texture is not converted")
    elif v is not None:
        m.emissive = np.asarray(v, dtype=np.float64)[:3]
    spec_wf, _ = _shader_input(shader, "useSpecularWorkflow")
    if spec_wf:
        sc, _ = _shader_input(shader, "specularColor")
        if sc is not None and max(sc) == 0:
            m.diffuse_only = True
        else:
            warn(f"{key}: the specular workflow's specularColor is not converted (glTF's default dielectric specular)")
    cache[key] = m
    return m


def _manifest_instances(out_dir: Path) -> dict[str, dict]:
    path = out_dir / "lightmaps" / "manifest.json"
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise GltfExportError(f"{path}: cannot be read as JSON ({exc})") from exc
    out = {}
    for k, inst in enumerate(data.get("instances", [])):
        for need in ("prim", "file", "scaleOffset"):
            if need not in inst:
                raise GltfExportError(f"{path}: instances[{k}] has no \"{need}\"")
        out[str(inst["prim"])] = inst
    return out


def _lightmap_of(prim, manifest: dict, uv_set: str, layer_dir: Path, out_dir: Path, path: str | None = None):
    """(page file Path, Unity-order scaleOffset USD convention, uv set name, the mesh holding the
    UV set) or None; `path` names a PointInstancer copy (whose prim is the prototype mesh)."""
    copy = path is not None
    path = str(prim.GetPath()) if path is None else path
    inst = manifest.get(path)
    if inst is not None:
        base = out_dir / "lightmaps"
        return ((base / inst["file"]).resolve(), np.asarray(inst["scaleOffset"], np.float64),
                inst.get("uvSet", uv_set), inst.get("mesh"))
    if copy:  # a copy's rectangle is only in the manifest
        return None
    f = prim.GetAttribute("hirad:lightmap:file")
    so = prim.GetAttribute("hirad:lightmap:scaleOffset")
    if f and f.Get() is not None and so and so.Get() is not None:
        asset = f.Get()
        p = Path(asset.resolvedPath) if asset.resolvedPath else (layer_dir / asset.path)
        return p.resolve(), np.asarray(so.Get(), np.float64), uv_set, None
    return None


def _invisible_in_input(prim, root_layer, time) -> bool:
    """Visibility as the input has it: the solution layer (the stage's root layer) hides the
    original meshes under its own display meshes, so its visibility opinions are skipped and
    the strongest opinion of the layers below decides, on the prim itself only (its ancestors
    were checked on the way down, the traversal prunes below an invisible one)."""
    from pxr import UsdGeom

    attr = UsdGeom.Imageable(prim).GetVisibilityAttr()
    if not attr:
        return False
    for spec in attr.GetPropertyStack(time):
        if spec.layer == root_layer:
            continue
        value = spec.default
        if value is not None:
            return value == UsdGeom.Tokens.invisible
    return False


def _axis_map(stage) -> np.ndarray:
    from pxr import UsdGeom

    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    c = np.eye(3) * mpu
    if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z:
        c = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]) * mpu
    return c


@dataclass
class _Primitive:
    name: str
    positions: np.ndarray   # (V,3) float32
    normals: np.ndarray     # (V,3) float32
    uv0: np.ndarray | None  # (V,2) float32, glTF convention
    uv1: np.ndarray | None
    indices: np.ndarray     # (T*3,) uint32
    material: _Material
    lightmap: tuple | None  # (page Path, scaleOffset usd)


def _mesh_primitive(prim, world: np.ndarray, axes: np.ndarray, time, uv_set: str, material: _Material,
                    lightmap, warn) -> _Primitive | None:
    from pxr import UsdGeom

    where = str(prim.GetPath())
    mesh = UsdGeom.Mesh(prim)
    pts = mesh.GetPointsAttr().Get(time)
    counts = mesh.GetFaceVertexCountsAttr().Get(time)
    idx = mesh.GetFaceVertexIndicesAttr().Get(time)
    if pts is None or counts is None or idx is None or len(pts) == 0 or len(counts) == 0:
        return None
    pts = np.asarray(pts, dtype=np.float64)
    counts = np.asarray(counts, dtype=np.int64)
    idx = np.asarray(idx, dtype=np.int64)
    if counts.sum() != len(idx) or (counts < 3).any() or idx.min() < 0 or idx.max() >= len(pts):
        raise GltfExportError(f"{where}: faceVertexCounts/faceVertexIndices are inconsistent with {len(pts)} points")
    lin = axes @ world[:3, :3].T   # USD matrices act on row vectors: p_world = p @ W[:3,:3] + W[3,:3]
    trans = axes @ world[3, :3]
    wp = pts @ lin.T + trans
    flip = mesh.GetOrientationAttr().Get(time) == UsdGeom.Tokens.leftHanded
    if np.linalg.det(lin) < 0:
        flip = not flip
    pvapi = UsdGeom.PrimvarsAPI(prim)
    normals = None
    npv = pvapi.GetPrimvar("normals")
    if npv and npv.HasAuthoredValue():
        normals = _corner_values(npv, counts, idx, len(pts), where)
    else:
        na = mesh.GetNormalsAttr()
        if na and na.HasAuthoredValue():
            normals = _expand(np.asarray(na.Get(time), dtype=np.float64).reshape(-1, 3),
                              mesh.GetNormalsInterpolation(), counts, idx, len(pts), where, "normals")
    st = _corner_values(pvapi.GetPrimvar("st"), counts, idx, len(pts), where) if pvapi.HasPrimvar("st") else None
    st1 = None
    if lightmap is not None:
        holder = pvapi
        if not pvapi.HasPrimvar(lightmap[2]) and lightmap[3] and lightmap[3] != where:
            # the manifest names the mesh whose UV set this copy shares (a prototype's)
            other = prim.GetStage().GetPrimAtPath(lightmap[3])
            holder = UsdGeom.PrimvarsAPI(other) if other else pvapi
        if holder.HasPrimvar(lightmap[2]):
            st1 = _corner_values(holder.GetPrimvar(lightmap[2]), counts, idx, len(pts), where)
        else:
            # meshes inside native instances (instance proxies) have no UV set in the layer
            warn(f"{where}: has a lightmap page but no primvars:{lightmap[2]} (an instance proxy?): "
                 "exported without its lightmap")
            lightmap = None
    # fan triangulation, corner slots in authored order
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    fan_f = np.repeat(np.arange(len(counts)), counts - 2)
    fan_j = np.arange(len(fan_f)) - np.repeat(np.concatenate([[0], np.cumsum(counts - 2)[:-1]]), counts - 2) + 1
    s0 = first[fan_f]
    tri_slots = np.stack([s0, s0 + fan_j, s0 + fan_j + 1], axis=1)
    if flip:
        tri_slots = tri_slots[:, [0, 2, 1]]
    # Newell normal per face (world space), for flat normals and the concavity check
    p_c = wp[idx]
    nxt = np.arange(len(idx)) + 1
    nxt[np.cumsum(counts) - 1] = first
    cross = np.cross(p_c, p_c[nxt])
    face_n = np.add.reduceat(cross, first, axis=0) if len(first) else np.zeros((0, 3))
    if flip:
        face_n = -face_n
    tri_n = np.cross(wp[idx[tri_slots[:, 1]]] - wp[idx[tri_slots[:, 0]]], wp[idx[tri_slots[:, 2]]] - wp[idx[tri_slots[:, 0]]])
    concave = np.einsum("ij,ij->i", tri_n, face_n[fan_f]) < -1e-12 * np.einsum("ij,ij->i", face_n[fan_f], face_n[fan_f])
    if concave.any():
        warn(f"{where}: {len(np.unique(fan_f[concave]))} concave polygon(s) fanned from their first corner "
             "(triangles may overlap)")
    if normals is not None:
        nmat = np.linalg.inv(lin).T
        n_c = normals @ nmat.T   # normals go through the inverse transpose
    else:
        n_c = face_n[np.repeat(np.arange(len(counts)), counts)]
    ln = np.linalg.norm(n_c, axis=1, keepdims=True)
    n_c = np.where(ln > 0, n_c / np.maximum(ln, 1e-300), np.array([0.0, 1.0, 0.0]))
    cols = [wp[idx], n_c]
    uv0 = uv1 = None
    if st is not None:
        uv0 = np.stack([st[:, 0], 1.0 - st[:, 1]], axis=1)
        cols.append(uv0)
    if st1 is not None:
        uv1 = np.stack([st1[:, 0], 1.0 - st1[:, 1]], axis=1)
        cols.append(uv1)
    corner = np.concatenate(cols, axis=1).astype(np.float32)
    used = tri_slots.reshape(-1)
    uniq, inverse = np.unique(corner[used], axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    o = 6
    return _Primitive(
        name=where, positions=np.ascontiguousarray(uniq[:, 0:3]), normals=np.ascontiguousarray(uniq[:, 3:6]),
        uv0=np.ascontiguousarray(uniq[:, o:o + 2]) if st is not None else None,
        uv1=np.ascontiguousarray(uniq[:, o + (2 if st is not None else 0):][:, :2]) if st1 is not None else None,
        indices=inverse.astype(np.uint32), material=material,
        lightmap=(lightmap[0], lightmap[1]) if lightmap is not None else None)


# ---------------------------------------------------------------------------------------------
# images
# ---------------------------------------------------------------------------------------------


def encode_rgbm(values: np.ndarray) -> tuple[np.ndarray, float]:
    """hirad's linear RGBM (hirad.atlas.files.encode_rgbm: value = (rgb/255) * (a/255) * range)
    with a per-image range, the page's largest component (1 for a black page). Returns the
    (H, W, 4) uint8 image and the range."""
    from ..atlas.files import encode_rgbm as encode

    v = np.maximum(np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0), 0.0)
    top = float(v.max()) if v.size else 0.0
    rng = top if top > 0 else 1.0
    return encode(v, rng), rng


def decode_rgbm(image: np.ndarray, rng: float) -> np.ndarray:
    from ..atlas.files import decode_rgbm as decode

    return decode(image, rng).astype(np.float64)


def _srgb_encode(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _png(array: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def _texture_bytes(path: Path, warn) -> tuple[bytes, str] | None:
    suffix = path.suffix.lower()
    if suffix == ".png":
        return path.read_bytes(), "image/png"
    if suffix in (".jpg", ".jpeg"):
        return path.read_bytes(), "image/jpeg"
    try:
        from PIL import Image

        with Image.open(path) as im:
            return _png(np.asarray(im.convert("RGBA" if "A" in im.mode else "RGB"))), "image/png"
    except Exception as exc:  # noqa: BLE001 - any unreadable texture is a named warning
        warn(f"{path}: texture cannot be converted to PNG ({exc}); the material's colour is used")
        return None


# ---------------------------------------------------------------------------------------------
# the writer
# ---------------------------------------------------------------------------------------------


class _Blob:
    def __init__(self):
        self.parts: list[bytes] = []
        self.size = 0

    def add(self, data: bytes) -> tuple[int, int]:
        pad = (-self.size) % 4
        if pad:
            self.parts.append(b"\0" * pad)
            self.size += pad
        off = self.size
        self.parts.append(data)
        self.size += len(data)
        return off, len(data)

    def bytes(self) -> bytes:
        out = b"".join(self.parts)
        return out + b"\0" * ((-len(out)) % 4)


def write_glb(out_dir: str | Path, *, solution: str = "solution.usda", name: str = GLB_NAME,
              uv_set: str = "st1", warn=None) -> Path:
    """Writes OUT/<name> (default scene.glb) from OUT/<solution> and OUT/lightmaps/, atomically
    (a temporary name in OUT, then a rename). `warn(message)` receives every feature not
    honoured (default: warnings.warn with GltfExportWarning). Returns the GLB's path."""
    import pygltflib as g
    from pxr import Usd, UsdGeom

    from .. import _engine
    from ..usd.scene import point_instancer_copies, read_cameras
    from ..usd.solution import find_solution_root

    out_dir = Path(out_dir)
    if warn is None:
        def warn(msg):  # noqa: E306
            warnings.warn(msg, GltfExportWarning, stacklevel=3)
    layer = out_dir / solution
    if not layer.exists():
        raise GltfExportError(f"{layer}: no solution layer to export")
    stage = Usd.Stage.Open(str(layer))
    if stage is None:
        raise GltfExportError(f"{layer}: cannot be opened as a USD stage")
    time = Usd.TimeCode.EarliestTime() if stage.HasAuthoredTimeCodeRange() else Usd.TimeCode.Default()
    axes = _axis_map(stage)
    manifest = _manifest_instances(out_dir)
    xfc = UsdGeom.XformCache(time)
    materials: dict = {}
    prims: list[_Primitive] = []
    instancers = 0
    root_layer = stage.GetRootLayer()
    sol = find_solution_root(stage)
    solution_root = sol.GetPath() if sol is not None else None
    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()))
    for prim in it:
        if solution_root is not None and prim.GetPath().HasPrefix(solution_root):
            it.PruneChildren()   # hirad's own re-tessellated meshes (the debug layer)
            continue
        if prim.IsA(UsdGeom.Imageable):
            img = UsdGeom.Imageable(prim)
            if _invisible_in_input(prim, root_layer, time) or \
                    img.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                it.PruneChildren()
                continue
        if prim.IsA(UsdGeom.PointInstancer):
            # each copy a node of its own: the prototype mesh at the copy's transform, with the
            # copy's lightmap rectangle (the manifest's entry for the copy's path)
            it.PruneChildren()
            notes: list[str] = []
            copies = point_instancer_copies(prim, xfc, time, notes)
            for note in notes:
                warn(note)
            for copy_path, proto, world in copies:
                lm = _lightmap_of(proto, manifest, uv_set, layer.parent, out_dir, path=copy_path)
                mat = _read_material(proto, layer.parent, materials, warn)
                p = _mesh_primitive(proto, np.asarray(world, dtype=np.float64), axes, time, uv_set, mat, lm, warn)
                if p is not None:
                    p.name = copy_path
                    prims.append(p)
                    instancers += 1
            continue
        if not prim.IsA(UsdGeom.Mesh):
            continue
        world = np.asarray(xfc.GetLocalToWorldTransform(prim), dtype=np.float64)
        lm = _lightmap_of(prim, manifest, uv_set, layer.parent, out_dir)
        mat = _read_material(prim, layer.parent, materials, warn)
        p = _mesh_primitive(prim, world, axes, time, uv_set, mat, lm, warn)
        if p is not None:
            prims.append(p)
    if not prims:
        raise GltfExportError(f"{layer}: no mesh to export")

    gltf = g.GLTF2(asset=g.Asset(version="2.0", generator="hirad"), scene=0)
    blob = _Blob()
    ext_used: set[str] = set()

    def view(data: bytes, target=None) -> int:
        off, n = blob.add(data)
        gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=off, byteLength=n, target=target))
        return len(gltf.bufferViews) - 1

    def accessor(arr: np.ndarray, kind: str, with_bounds=False, target=g.ARRAY_BUFFER) -> int:
        comp = g.UNSIGNED_INT if arr.dtype == np.uint32 else g.FLOAT
        bv = view(np.ascontiguousarray(arr).tobytes(), target)
        acc = g.Accessor(bufferView=bv, componentType=comp, count=len(arr), type=kind)
        if with_bounds:
            acc.min = [float(x) for x in arr.min(axis=0)]
            acc.max = [float(x) for x in arr.max(axis=0)]
        gltf.accessors.append(acc)
        return len(gltf.accessors) - 1

    def image(data: bytes, mime: str, name: str) -> int:
        gltf.images.append(g.Image(bufferView=view(data), mimeType=mime, name=name))
        gltf.textures.append(g.Texture(source=len(gltf.images) - 1, sampler=0))
        return len(gltf.textures) - 1

    gltf.samplers.append(g.Sampler(magFilter=g.LINEAR, minFilter=g.LINEAR_MIPMAP_LINEAR,
                                   wrapS=g.REPEAT, wrapT=g.REPEAT))
    gltf.samplers.append(g.Sampler(magFilter=g.LINEAR, minFilter=g.LINEAR,
                                   wrapS=g.CLAMP_TO_EDGE, wrapT=g.CLAMP_TO_EDGE))

    # lightmap pages: RGBM (mapping 1) and sRGB value/S (mapping 2)
    pages: dict[Path, dict] = {}
    for p in prims:
        if p.lightmap is None or p.lightmap[0] in pages:
            continue
        page_path = p.lightmap[0]
        if not page_path.exists():
            raise GltfExportError(f"{page_path}: lightmap page of {p.name} is missing")
        values = np.asarray(_engine.read_exr(str(page_path)), dtype=np.float64)[..., :3]
        rgbm, rng = encode_rgbm(values)
        k = len(pages)
        t_rgbm = image(_png(rgbm), "image/png", f"lightmap{k}_rgbm")
        gltf.textures[t_rgbm].sampler = 1
        srgb = np.round(_srgb_encode(values / rng) * 255.0).astype(np.uint8)
        t_emis = image(_png(srgb), "image/png", f"lightmap{k}_emissive_srgb")
        gltf.textures[t_emis].sampler = 1
        pages[page_path] = {"rgbm": t_rgbm, "emissive": t_emis, "range": rng, "index": k,
                            "file": os.path.relpath(page_path, out_dir), "size": [values.shape[1], values.shape[0]]}

    base_textures: dict[Path, int | None] = {}
    gl_materials: dict[tuple, int] = {}

    def material_index(m: _Material, lm) -> int:
        so = None if lm is None else tuple(_gltf_scale_offset(lm[1]))
        key = (m.key, None if lm is None else (str(lm[0]), so))
        if key in gl_materials:
            return gl_materials[key]
        pbr = g.PbrMetallicRoughness(baseColorFactor=[*map(float, np.clip(m.base_color, 0, 1)), float(m.opacity)],
                                     metallicFactor=float(np.clip(m.metallic, 0, 1)),
                                     roughnessFactor=float(np.clip(m.roughness, 0, 1)))
        if m.base_texture is not None:
            if m.base_texture not in base_textures:
                tb = _texture_bytes(m.base_texture, warn)
                base_textures[m.base_texture] = None if tb is None else image(tb[0], tb[1], m.base_texture.name)
            t = base_textures[m.base_texture]
            if t is not None:
                pbr.baseColorTexture = g.TextureInfo(index=t, texCoord=0)
        mat = g.Material(name=m.key, pbrMetallicRoughness=pbr, doubleSided=False, extensions={}, extras={})
        if m.opacity < 1:
            mat.alphaMode = g.BLEND
        emis = np.maximum(m.emissive, 0)
        if emis.max() > 0:
            s = float(emis.max())
            mat.emissiveFactor = [float(x) for x in emis / s]
            if s != 1.0:
                mat.extensions["KHR_materials_emissive_strength"] = {"emissiveStrength": s}
                ext_used.add("KHR_materials_emissive_strength")
            if lm is not None:
                warn(f"{m.key}: emits light; its lightmap is only in the node's extras, not in its emissive mapping")
        elif lm is not None:
            page = pages[lm[0]]
            albedo = m.base_color
            if m.base_texture is not None and base_textures.get(m.base_texture) is not None:
                albedo = _mean_texture_colour(m.base_texture)
            mat.emissiveFactor = [float(x) for x in np.clip(albedo, 0, 1)]
            mat.emissiveTexture = g.TextureInfo(index=page["emissive"], texCoord=1, extensions={
                "KHR_texture_transform": {"offset": [so[2], so[3]], "scale": [so[0], so[1]], "texCoord": 1}})
            mat.extensions["KHR_materials_emissive_strength"] = {"emissiveStrength": float(page["range"])}
            ext_used.update(("KHR_texture_transform", "KHR_materials_emissive_strength"))
            mat.extras["hirad_emissive_is_lightmap"] = True
        if m.diffuse_only:
            mat.extensions["KHR_materials_specular"] = {"specularFactor": 0.0}
            ext_used.add("KHR_materials_specular")
        if not mat.extensions:
            mat.extensions = None
        if not mat.extras:
            mat.extras = None
        gltf.materials.append(mat)
        gl_materials[key] = len(gltf.materials) - 1
        return gl_materials[key]

    root_children = []
    for p in prims:
        attrs = g.Attributes(POSITION=accessor(p.positions, g.VEC3, True), NORMAL=accessor(p.normals, g.VEC3))
        if p.uv0 is not None:
            attrs.TEXCOORD_0 = accessor(p.uv0, g.VEC2)
        if p.uv1 is not None:
            attrs.TEXCOORD_1 = accessor(p.uv1, g.VEC2)
            if p.uv0 is None:
                # sets are numbered without gaps (glTF 3.7.2.1): TEXCOORD_0 is the lightmap set too
                attrs.TEXCOORD_0 = attrs.TEXCOORD_1
        prim = g.Primitive(attributes=attrs, indices=accessor(p.indices, g.SCALAR, target=g.ELEMENT_ARRAY_BUFFER),
                           material=material_index(p.material, p.lightmap), mode=g.TRIANGLES)
        gltf.meshes.append(g.Mesh(name=p.name, primitives=[prim]))
        node = g.Node(name=p.name, mesh=len(gltf.meshes) - 1, extras={"hirad_path": p.name})
        if p.lightmap is not None:
            page = pages[p.lightmap[0]]
            node.extras["hirad_lightmap"] = {
                "image": gltf.textures[page["rgbm"]].source, "texture": page["rgbm"], "page": page["index"],
                "file": page["file"], "size": page["size"], "texCoord": 1,
                "scaleOffset": [float(x) for x in _gltf_scale_offset(p.lightmap[1])],
                "scaleOffsetUsd": [float(x) for x in p.lightmap[1]],
                "scaleOffsetOrder": "page_uv = TEXCOORD_1 * (x, y) + (z, w), glTF UVs (origin top-left)",
                "encoding": "RGBM", "range": float(page["range"]),
                "decode": "value = (r/255) * (a/255) * range, linear (no sRGB transfer)",
                "units": "W/(m^2 sr): incident radiance H/pi; irradiance E = pi * value",
                "threejs": "lightMap = decoded texture, channel = 1, lightMapIntensity = Math.PI"}
        gltf.nodes.append(node)
        root_children.append(len(gltf.nodes) - 1)

    # cameras (hirad's own reading: metres, world), taken to glTF axes
    lo = np.min([p.positions.min(axis=0) for p in prims], axis=0)
    hi = np.max([p.positions.max(axis=0) for p in prims], axis=0)
    unit_axes = axes / np.cbrt(abs(np.linalg.det(axes)))
    for cam in read_cameras(stage):
        pos = unit_axes @ np.asarray(cam.position, float)
        fwd = unit_axes @ np.asarray(cam.forward, float)
        up = unit_axes @ np.asarray(cam.up, float)
        right = np.cross(fwd, up)
        far = float(np.linalg.norm(hi - lo) + np.linalg.norm(pos - (lo + hi) / 2)) * 2.0
        mat4 = np.eye(4)
        mat4[:3, 0], mat4[:3, 1], mat4[:3, 2], mat4[:3, 3] = right, up, -fwd, pos
        gltf.cameras.append(g.Camera(type="perspective", name=cam.path, perspective=g.Perspective(
            yfov=math.radians(cam.vertical_fov_degrees), aspectRatio=float(cam.aspect),
            znear=far * 1e-4, zfar=far)))
        gltf.nodes.append(g.Node(name=cam.path, camera=len(gltf.cameras) - 1, extras={"hirad_path": cam.path},
                                 matrix=[float(x) for x in mat4.T.reshape(-1)]))
        root_children.append(len(gltf.nodes) - 1)

    gltf.scenes.append(g.Scene(name=str(layer.name), nodes=root_children))
    if ext_used:
        gltf.extensionsUsed = sorted(ext_used)
    data = blob.bytes()
    gltf.buffers.append(g.Buffer(byteLength=len(data)))
    gltf.set_binary_blob(data)
    gltf.extras = {"hirad": {"source": str(solution), "units": "metres, +Y up",
                             "lightmapPages": len(pages)}}
    target = out_dir / name
    tmp = out_dir / f".{name}.partial"
    try:
        glb = b"".join(gltf.save_to_bytes())
        with open(tmp, "wb") as fh:
            fh.write(glb)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()
    return target


def _gltf_scale_offset(so_usd) -> np.ndarray:
    """Unity-order scaleOffset in USD UVs (origin bottom-left) -> the same rectangle for glTF
    UVs (origin top-left, t = 1 - v): (sx, sy, ox, 1 - sy - oy)."""
    sx, sy, ox, oy = (float(x) for x in so_usd)
    return np.array([sx, sy, ox, 1.0 - sy - oy])


def _mean_texture_colour(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        a = np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0
    lin = np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
    return lin.reshape(-1, 3).mean(axis=0)
