"""The solution layer: writing the baked meshes with their radiosity primvars (radiance W/(m^2 sr), irradiance W/m^2) over the input, and reading such a layer back without solving."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdShade, Vt
from .common import _LOOKS_NAME, SceneError, _open_stage
from .scene import CameraInfo, MeshInfo, SceneArrays, read_cameras


SOLUTION_ROOT = "/HiradSolution"


@dataclass
class PatchMeshData:
    """Solved geometry of one scene mesh (what the solution layer stores per mesh)."""

    mesh_index: int
    points: np.ndarray  # (P,3) metres, world
    face_vertex_counts: np.ndarray  # (F,)
    face_vertex_indices: np.ndarray  # (sum counts,)
    vertex_radiance: np.ndarray  # (P,3) exitant radiance W/(m^2 sr)
    vertex_irradiance: np.ndarray  # (P,3) W/m^2
    face_radiance: np.ndarray  # (F,3)
    face_irradiance: np.ndarray  # (F,3)
    lightmap_uv: np.ndarray | None = None  # (sum counts,2) faceVarying
    lightmap_path: str | None = None  # asset path relative to the solution layer
    # filled in by read_solution_layer
    name: str | None = None
    source_path: str | None = None
    # the lightmap shown as albedo x lightmap + emitted radiance (UsdUVTexture scale / bias):
    # the mesh's (area-weighted) reflectance and emitted radiance E/pi, RGB
    lightmap_albedo: tuple[float, float, float] | None = None
    lightmap_emission: tuple[float, float, float] | None = None


@dataclass
class SolutionData:
    meshes: list[PatchMeshData]
    cameras: list[CameraInfo]
    meters_per_unit: float
    up_axis: str
    metadata: dict
    path: str


# ----------------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------------


def _to_vt_value(v: Any):
    if isinstance(v, dict):
        out = {}
        for k, x in v.items():
            c = _to_vt_value(x)
            if c is not None:
                out[str(k)] = c
        return out
    if isinstance(v, np.ndarray):
        return _to_vt_value(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, (list, tuple)):
        items = [_to_vt_value(x) for x in v if x is not None]
        if items and all(isinstance(x, str) for x in items):
            return Vt.StringArray(items)
        if items and all(isinstance(x, bool) for x in items):
            return Vt.BoolArray(items)
        if items and all(isinstance(x, int) and not isinstance(x, bool) for x in items):
            return Vt.Int64Array(items)
        if items and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in items):
            return Vt.DoubleArray([float(x) for x in items])
        return Vt.StringArray([str(x) for x in items])
    if v is None:
        return None
    if isinstance(v, (bool, int, float, str)):
        return v
    return str(v)


def _check_patch(pm: PatchMeshData, n_meshes: int):
    P = len(pm.points)
    F = len(pm.face_vertex_counts)
    C = int(np.sum(pm.face_vertex_counts)) if F else 0

    def shape(a, n, what):
        a = np.asarray(a)
        if a.shape != (n, 3):
            raise ValueError(f"patch mesh {pm.mesh_index}: {what} has shape {a.shape}, expected ({n}, 3)")

    if not 0 <= pm.mesh_index < n_meshes:
        raise ValueError(f"patch mesh index {pm.mesh_index} out of range (scene has {n_meshes} meshes)")
    shape(pm.points, P, "points")
    if len(pm.face_vertex_indices) != C:
        raise ValueError(f"patch mesh {pm.mesh_index}: face_vertex_indices length != sum of counts")
    shape(pm.vertex_radiance, P, "vertex_radiance")
    shape(pm.vertex_irradiance, P, "vertex_irradiance")
    shape(pm.face_radiance, F, "face_radiance")
    shape(pm.face_irradiance, F, "face_irradiance")
    if pm.lightmap_uv is not None and np.asarray(pm.lightmap_uv).shape != (C, 2):
        raise ValueError(f"patch mesh {pm.mesh_index}: lightmap_uv must have shape ({C}, 2)")


def _relative_asset(target: Path, from_dir: Path) -> str:
    try:
        rel = os.path.relpath(target, from_dir)
    except ValueError:  # different drives on Windows
        return target.as_posix()
    rel = Path(rel).as_posix()
    if not rel.startswith("."):
        rel = "./" + rel
    return rel


def _author_patch_mesh(stage: Usd.Stage, mesh_path: Sdf.Path, pm: PatchMeshData, info: MeshInfo, mpu: float):
    mesh = UsdGeom.Mesh.Define(stage, mesh_path)
    pts = np.asarray(pm.points, dtype=np.float64) / mpu
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(pm.face_vertex_counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(pm.face_vertex_indices, dtype=np.int32)))
    mesh.CreateDoubleSidedAttr(False)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    finite = pts[np.isfinite(pts).all(axis=1)]
    if len(finite):
        mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*finite.min(axis=0)), Gf.Vec3f(*finite.max(axis=0))]))
    api = UsdGeom.PrimvarsAPI(mesh)

    def color_pv(name, data, interp):
        pv = api.CreatePrimvar(name, Sdf.ValueTypeNames.Color3fArray, interp)
        pv.Set(Vt.Vec3fArray.FromNumpy(np.asarray(data, dtype=np.float32).reshape(-1, 3)))

    color_pv("hirad:radiance", pm.vertex_radiance, UsdGeom.Tokens.vertex)
    color_pv("hirad:irradiance", pm.vertex_irradiance, UsdGeom.Tokens.vertex)
    color_pv("hirad:patchRadiance", pm.face_radiance, UsdGeom.Tokens.uniform)
    color_pv("hirad:patchIrradiance", pm.face_irradiance, UsdGeom.Tokens.uniform)
    color_pv("displayColor", np.clip(np.nan_to_num(np.asarray(pm.vertex_radiance)), 0.0, 1.0), UsdGeom.Tokens.vertex)

    prim = mesh.GetPrim()
    prim.SetCustomDataByKey("hirad:meshIndex", int(pm.mesh_index))
    prim.SetCustomDataByKey("hirad:sourcePath", info.path)
    prim.SetCustomDataByKey("hirad:isLight", bool(info.is_light))

    if pm.lightmap_uv is not None:
        pv = api.CreatePrimvar("hirad:lightmapUV", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec2fArray.FromNumpy(np.asarray(pm.lightmap_uv, dtype=np.float32).reshape(-1, 2)))
        if pm.lightmap_path:
            looks = Sdf.Path(SOLUTION_ROOT).AppendChild(_LOOKS_NAME)
            UsdGeom.Scope.Define(stage, looks)
            mat = UsdShade.Material.Define(stage, looks.AppendChild(mesh_path.name))
            surf = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("PreviewSurface"))
            surf.CreateIdAttr("UsdPreviewSurface")
            surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
            surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
            reader = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("LightmapUV"))
            reader.CreateIdAttr("UsdPrimvarReader_float2")
            reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("hirad:lightmapUV")
            reader_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
            tex = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("Lightmap"))
            tex.CreateIdAttr("UsdUVTexture")
            tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(pm.lightmap_path))
            tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
            tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
            tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
            tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader_out)
            if pm.lightmap_albedo is not None:
                # texels hold incident radiance H/pi: the surface shows albedo x H/pi (+ E/pi)
                r, g, b = (float(v) for v in pm.lightmap_albedo)
                tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(r, g, b, 1.0))
            if pm.lightmap_emission is not None:
                r, g, b = (float(v) for v in pm.lightmap_emission)
                tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(r, g, b, 0.0))
            rgb = tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
            surf.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
            mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
            UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)
    return mesh


def write_solution_layer(
    input_path: str | Path,
    output_path: str | Path,
    scene: SceneArrays,
    patch_meshes: Sequence[PatchMeshData],
    metadata: dict | None = None,
) -> Path:
    """Write the solution layer atomically to ``output_path``; the input file is never modified."""
    input_path = Path(input_path)
    output_path = Path(output_path)
    if output_path.resolve() == input_path.resolve():
        raise SceneError(f"{output_path}: refusing to overwrite the input scene")
    for pm in patch_meshes:
        _check_patch(pm, len(scene.meshes))
    out_dir = output_path.resolve().parent
    out_dir.mkdir(parents=True, exist_ok=True)
    mpu = float(scene.meters_per_unit)
    if not mpu > 0:
        raise ValueError("scene.meters_per_unit must be positive")

    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    sub = _relative_asset(input_path.resolve(), out_dir)
    # stage-level metadata only comes from the root layer: copy the input's
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if scene.up_axis.upper() == "Y" else UsdGeom.Tokens.z)
    try:
        in_layer = Sdf.Layer.FindOrOpen(str(input_path))
        if in_layer is not None and in_layer.defaultPrim:
            layer.defaultPrim = in_layer.defaultPrim
    except Tf.ErrorException:
        pass

    hidden: set[str] = set()
    for info in scene.meshes:
        if info.hide_path in hidden or not info.hide_path:
            continue
        hidden.add(info.hide_path)
        over = stage.OverridePrim(info.hide_path)
        over.CreateAttribute("visibility", Sdf.ValueTypeNames.Token, False, Sdf.VariabilityVarying).Set(
            UsdGeom.Tokens.invisible
        )

    UsdGeom.Scope.Define(stage, SOLUTION_ROOT)
    root = Sdf.Path(SOLUTION_ROOT)
    used: set[str] = {_LOOKS_NAME}
    for pm in patch_meshes:
        info = scene.meshes[pm.mesh_index]
        name, k = info.name, 1
        while name in used:
            name = f"{info.name}_{k}"
            k += 1
        used.add(name)
        _author_patch_mesh(stage, root.AppendChild(name), pm, info, mpu)

    md = {"hirad:metersPerUnit": mpu, "hirad:input": sub}
    md.update(metadata or {})
    layer.customLayerData = _to_vt_value(md)
    layer.comment = "hirad radiosity solution; sublayers the input scene"
    del stage  # release the authoring stage so adding the sublayer composes nothing
    # sublayer last so the authoring above never composes (or touches) the input
    layer.subLayerPaths.append(sub)

    suffix = output_path.suffix if output_path.suffix in (".usda", ".usdc", ".usd") else ".usda"
    fd, tmp = tempfile.mkstemp(prefix=f".{output_path.stem}.", suffix=".tmp" + suffix, dir=str(out_dir))
    os.close(fd)
    try:
        if not layer.Export(tmp):
            raise SceneError(f"{output_path}: could not write the solution layer")
        # mkstemp makes the file private (0600); give it the permissions any other new file gets.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, output_path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return output_path


# ----------------------------------------------------------------------------------------------
# reading a solution back
# ----------------------------------------------------------------------------------------------


def _get_array(prim: Usd.Prim, name: str, time, cols: int) -> np.ndarray | None:
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasAuthoredValue():
        return None
    v = pv.ComputeFlattened(time)
    if v is None:
        return None
    return np.array(v, dtype=np.float64).reshape(-1, cols)


def read_solution_layer(path: str | Path) -> SolutionData:
    """Load a layer written by :func:`write_solution_layer` (plus the input's cameras)."""
    stage = _open_stage(path)
    time = Usd.TimeCode.Default()
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    root = stage.GetPrimAtPath(SOLUTION_ROOT)
    meshes: list[PatchMeshData] = []
    if root and root.IsValid():
        for prim in root.GetChildren():
            if not prim.IsA(UsdGeom.Mesh):
                continue
            m = UsdGeom.Mesh(prim)
            pts = np.array(m.GetPointsAttr().Get(time) or [], dtype=np.float64).reshape(-1, 3) * mpu
            counts = np.array(m.GetFaceVertexCountsAttr().Get(time) or [], dtype=np.int32)
            idx = np.array(m.GetFaceVertexIndicesAttr().Get(time) or [], dtype=np.int32)
            P, F = len(pts), len(counts)

            def arr(name, n, cols=3):
                a = _get_array(prim, name, time, cols)
                return a if a is not None else np.zeros((n, cols))

            lm_path = None
            binding = UsdShade.MaterialBindingAPI(prim).GetDirectBinding().GetMaterial()
            if binding and binding.GetPrim().IsValid():
                tex = binding.GetPrim().GetChild("Lightmap")
                if tex:
                    f = UsdShade.Shader(tex).GetInput("file")
                    if f and f.Get() is not None:
                        lm_path = f.Get().path
            meshes.append(
                PatchMeshData(
                    mesh_index=int(prim.GetCustomDataByKey("hirad:meshIndex") or 0),
                    points=pts,
                    face_vertex_counts=counts,
                    face_vertex_indices=idx,
                    vertex_radiance=arr("hirad:radiance", P),
                    vertex_irradiance=arr("hirad:irradiance", P),
                    face_radiance=arr("hirad:patchRadiance", F),
                    face_irradiance=arr("hirad:patchIrradiance", F),
                    lightmap_uv=_get_array(prim, "hirad:lightmapUV", time, 2),
                    lightmap_path=lm_path,
                    name=prim.GetName(),
                    source_path=prim.GetCustomDataByKey("hirad:sourcePath"),
                )
            )
    if not meshes:
        raise SceneError(f"{path}: not a hirad solution (no meshes under {SOLUTION_ROOT})")
    md = dict(stage.GetRootLayer().customLayerData)
    return SolutionData(
        meshes=meshes,
        cameras=read_cameras(stage),
        meters_per_unit=mpu,
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        metadata=md,
        path=str(path),
    )
