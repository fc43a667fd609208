"""The solution layer: writing the baked meshes with their radiosity primvars (radiance W/(m^2 sr), irradiance W/m^2) over the input, and reading such a layer back without solving."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdShade, Vt
from .common import _LOOKS_NAME, SceneError, _mat, _open_stage, _stage_time, _transform_points
from .scene import CameraInfo, MeshInfo, SceneArrays, read_cameras


SOLUTION_NAME = "HiradSolution"
# Where the solution goes when the input has no defaultPrim it can sit under (and where layers
# written before the solution moved under the defaultPrim keep it): a root prim, which the
# solution layer then names as its defaultPrim.
SOLUTION_ROOT = "/" + SOLUTION_NAME
# The colour space of every colour hirad writes: linear Rec.709 primaries, scene referred (the
# values are physical radiance and irradiance per channel, not display values).
COLOR_SPACE = "lin_rec709_scene"


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
    # (F,3) self-emitted exitance E of each face, W/m^2 (primvars:hirad:emission, uniform):
    # what `hirad grid` needs to tell the emitters from the rest; None in layers written before
    face_emission: np.ndarray | None = None
    # light groups (lights.groups): name -> (vertex radiance (P,3), vertex irradiance (P,3)) of
    # that group's solution alone, written as primvars:hirad:group:<name>:radiance / :irradiance
    group_values: dict | None = None
    # the lightmap on the original mesh prim (hirad.outputs.lightmaps): "uv" (authored corners,
    # 2) the mesh's own lightmap UVs or None, "uv_set" the primvar name, "page", "file" (asset
    # path relative to the layer), "scale_offset" (Unity order), "author_path" the prim that can
    # carry the UVs (None inside a native instance), "prim" the mesh's path, "prototype"
    source_lightmap: dict | None = None


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
    if pm.face_emission is not None:
        shape(pm.face_emission, F, "face_emission")
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


def _unlit_surface(stage: Usd.Stage, mat: UsdShade.Material) -> UsdShade.Shader:
    """A UsdPreviewSurface that only emits: no diffuse and no specular lobe (specular workflow
    with a black specular colour), so a viewer shows the emissive colour as it is and never
    lights the baked light a second time."""
    surf = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("PreviewSurface"))
    surf.CreateIdAttr("UsdPreviewSurface")
    surf.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    surf.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    surf.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    surf.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0)
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    return surf


def _bind_lightmap_material(stage: Usd.Stage, looks: Sdf.Path, prim: Usd.Prim, pm: PatchMeshData):
    """Shows albedo x lightmap (+ emission) through the hirad:lightmapUV primvar."""
    mat = UsdShade.Material.Define(stage, looks.AppendChild(prim.GetName()))
    surf = _unlit_surface(stage, mat)
    reader = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("LightmapUV"))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("hirad:lightmapUV")
    reader_out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("Lightmap"))
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(pm.lightmap_path))
    # linear half-float EXR data: no transfer function to undo
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
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def _bind_radiance_material(stage: Usd.Stage, looks: Sdf.Path, prim: Usd.Prim):
    """Shows the baked exitant radiance (primvars:hirad:radiance, interpolated over the faces)
    as the surface's emission, unlit."""
    mat = UsdShade.Material.Define(stage, looks.AppendChild(prim.GetName()))
    surf = _unlit_surface(stage, mat)
    reader = UsdShade.Shader.Define(stage, mat.GetPath().AppendChild("Radiance"))
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("hirad:radiance")
    reader.CreateInput("fallback", Sdf.ValueTypeNames.Float3).Set(Gf.Vec3f(0, 0, 0))
    out = reader.CreateOutput("result", Sdf.ValueTypeNames.Float3)
    surf.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(out)
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def _author_patch_mesh(stage: Usd.Stage, mesh_path: Sdf.Path, pm: PatchMeshData, info: MeshInfo, mpu: float,
                       world_to_parent: np.ndarray | None = None):
    """One solution mesh. Points are world metres in `pm`; they are written in stage units in
    the frame of the solution root's parent (`world_to_parent`, row vectors; None: the world)."""
    mesh = UsdGeom.Mesh.Define(stage, mesh_path)
    pts = np.asarray(pm.points, dtype=np.float64) / mpu
    if world_to_parent is not None:
        pts = _transform_points(pts, world_to_parent)
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
        pv.GetAttr().SetColorSpace(COLOR_SPACE)

    color_pv("hirad:radiance", pm.vertex_radiance, UsdGeom.Tokens.vertex)
    color_pv("hirad:irradiance", pm.vertex_irradiance, UsdGeom.Tokens.vertex)
    color_pv("hirad:patchRadiance", pm.face_radiance, UsdGeom.Tokens.uniform)
    color_pv("hirad:patchIrradiance", pm.face_irradiance, UsdGeom.Tokens.uniform)
    if pm.face_emission is not None:
        color_pv("hirad:emission", pm.face_emission, UsdGeom.Tokens.uniform)
    for group, (g_radiance, g_irradiance) in (pm.group_values or {}).items():
        color_pv(f"hirad:group:{group}:radiance", g_radiance, UsdGeom.Tokens.vertex)
        color_pv(f"hirad:group:{group}:irradiance", g_irradiance, UsdGeom.Tokens.vertex)
    color_pv("displayColor", np.clip(np.nan_to_num(np.asarray(pm.vertex_radiance)), 0.0, 1.0), UsdGeom.Tokens.vertex)

    prim = mesh.GetPrim()
    prim.SetCustomDataByKey("hirad:meshIndex", int(pm.mesh_index))
    prim.SetCustomDataByKey("hirad:sourcePath", info.path)
    prim.SetCustomDataByKey("hirad:isLight", bool(info.is_light))

    looks = mesh_path.GetParentPath().AppendChild(_LOOKS_NAME)
    UsdGeom.Scope.Define(stage, looks)
    if pm.lightmap_uv is not None:
        pv = api.CreatePrimvar("hirad:lightmapUV", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec2fArray.FromNumpy(np.asarray(pm.lightmap_uv, dtype=np.float32).reshape(-1, 2)))
    if pm.lightmap_uv is not None and pm.lightmap_path:
        _bind_lightmap_material(stage, looks, prim, pm)
    else:
        _bind_radiance_material(stage, looks, prim)
    return mesh


def _author_source_lightmaps(stage: Usd.Stage, patch_meshes: Sequence[PatchMeshData]) -> None:
    """The lightmap on the input's own mesh prims, as overs in this layer (the input file is
    never touched): the mesh's lightmap UVs as primvars:<uv_set> (texCoord2f[], faceVarying, one
    per authored faceVertexIndices entry, in the mesh's own [0, 1] layout), and its page
    (hirad:lightmap:page, hirad:lightmap:file) and Unity-order scale/offset
    (hirad:lightmap:scaleOffset: page_uv = uv * xy + zw). Copies of one prototype (the meshes
    of a PointInstancer prototype) share one UV set on the prototype mesh; each copy's page
    and rectangle are in lightmaps/manifest.json ("instances"), as a prim cannot hold one per
    copy. Meshes inside native instances (instance proxies, which no layer can author over)
    get the UV set on the mesh their instances reference when that is in the input's own layer
    stack (an internal reference: the over composes into the prototype, instancing is kept), and
    each instance root gets its meshes' pages and rectangles as arrays
    (hirad:lightmap:meshes, relative paths; :pages; :files; :scaleOffsets). Other native
    instances (another file's prototype, nested instances) are made non-instanceable here, so
    their meshes are ordinary prims that carry their own UV set (lightmaps.py warns)."""
    by_path: dict[str, list[dict]] = {}
    by_root: dict[str, list[dict]] = {}
    roots: set[str] = set()
    for pm in patch_meshes:
        sl = pm.source_lightmap
        if sl is None or sl.get("uv") is None or not sl.get("author_path") or "file" not in sl:
            continue
        by_path.setdefault(sl["author_path"], []).append(sl)
        roots.update(sl.get("deinstance", ()))
        if sl.get("instance_root") and not sl.get("deinstance"):
            by_root.setdefault(sl["instance_root"], []).append(sl)
    for root in sorted(roots, key=lambda r: Sdf.Path(r).pathElementCount):  # outer ones first
        stage.OverridePrim(root).SetInstanceable(False)
    for path, copies in by_path.items():
        over = stage.OverridePrim(path)
        first = copies[0]
        pv = UsdGeom.PrimvarsAPI(over).CreatePrimvar(first["uv_set"], Sdf.ValueTypeNames.TexCoord2fArray,
                                                     UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(first["uv"], dtype=np.float32)))
        if len(copies) > 1 or (first.get("prototype") is not None and not first.get("deinstance")):
            over.CreateAttribute("hirad:lightmap:copies", Sdf.ValueTypeNames.Int, True).Set(len(copies))
            continue
        over.CreateAttribute("hirad:lightmap:page", Sdf.ValueTypeNames.Int, True).Set(int(first["page"]))
        over.CreateAttribute("hirad:lightmap:file", Sdf.ValueTypeNames.Asset, True).Set(
            Sdf.AssetPath("./" + first["file"]))
        over.CreateAttribute("hirad:lightmap:scaleOffset", Sdf.ValueTypeNames.Float4, True).Set(
            Gf.Vec4f(*(float(v) for v in first["scale_offset"])))
    for root, members in by_root.items():
        members = sorted(members, key=lambda m: m["prim"])
        over = stage.OverridePrim(root)
        attrs = (("meshes", Sdf.ValueTypeNames.StringArray,
                  [str(Sdf.Path(m["prim"]).MakeRelativePath(Sdf.Path(root))) for m in members]),
                 ("pages", Sdf.ValueTypeNames.IntArray, [int(m["page"]) for m in members]),
                 ("files", Sdf.ValueTypeNames.AssetArray, [Sdf.AssetPath("./" + m["file"]) for m in members]),
                 ("scaleOffsets", Sdf.ValueTypeNames.Float4Array,
                  [Gf.Vec4f(*(float(v) for v in m["scale_offset"])) for m in members]))
        for name, type_name, value in attrs:
            over.CreateAttribute(f"hirad:lightmap:{name}", type_name, True).Set(value)


def _solution_parent(input_path: Path, hidden: set[str]) -> tuple[str | None, np.ndarray | None]:
    """The input's defaultPrim path the solution can sit under, and the matrix taking world
    coordinates (stage units, row vectors) into that prim's frame (None when it is the
    identity). (None, None) when the input has no defaultPrim, or one the solution cannot go
    under: a gprim (gprims do not nest), an instance (its children are not composed), or a
    prim the layer hides (the solution would be hidden with it)."""
    try:
        in_layer = Sdf.Layer.FindOrOpen(str(input_path))
    except Tf.ErrorException:
        return None, None
    if in_layer is None or not in_layer.defaultPrim:
        return None, None
    path = Sdf.Path.absoluteRootPath.AppendChild(in_layer.defaultPrim)
    for h in hidden:
        if path.HasPrefix(Sdf.Path(h)):
            return None, None
    try:
        stage = Usd.Stage.OpenMasked(in_layer, Usd.StagePopulationMask([path]), Usd.Stage.LoadNone)
    except Tf.ErrorException:
        return None, None
    prim = stage.GetPrimAtPath(path)
    if not prim or not prim.IsActive() or prim.IsA(UsdGeom.Gprim) or prim.IsInstance():
        return None, None
    m = np.eye(4)
    if prim.IsA(UsdGeom.Xformable):
        m = _mat(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(_stage_time(stage)))
    if np.array_equal(m, np.eye(4)):
        return str(path), None
    if not np.isfinite(m).all() or abs(np.linalg.det(m[:3, :3])) < 1e-300:
        return None, None
    return str(path), np.linalg.inv(m)


def write_solution_layer(
    input_path: str | Path,
    output_path: str | Path,
    scene: SceneArrays,
    patch_meshes: Sequence[PatchMeshData],
    metadata: dict | None = None,
    view: str = "solution",
) -> Path:
    """Write the solution layer atomically to ``output_path``; the input file is never modified.
    `view` "solution" hides the input's meshes and shows the solved ones; "source" leaves the
    input's meshes visible and hides the solved scope (kept for hirad's own read-back)."""
    if view not in ("solution", "source"):
        raise ValueError(f"view must be 'solution' or 'source', not {view!r}")
    input_path = Path(input_path)
    output_path = Path(output_path)
    for written in [output_path] + ([arrays_path(output_path)] if _splits(output_path) else []):
        if written.resolve() == input_path.resolve():
            raise SceneError(f"{written}: refusing to overwrite the input scene")
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

    hidden: set[str] = set()
    for info in scene.meshes:
        if view == "source":  # the input shows as it is, lights included
            break
        if info.hide_path in hidden or not info.hide_path:
            continue
        hidden.add(info.hide_path)
        over = stage.OverridePrim(info.hide_path)
        over.CreateAttribute("visibility", Sdf.ValueTypeNames.Token, False, Sdf.VariabilityVarying).Set(
            UsdGeom.Tokens.invisible
        )

    # The solution sits under the input's defaultPrim, so a stage that references this layer
    # (which brings in the defaultPrim only) shows it; the points are written in that prim's
    # frame, so they land where they were solved and follow any transform the referencing
    # stage puts on the prim.
    parent, world_to_parent = _solution_parent(input_path, hidden)
    if parent is None:
        root = Sdf.Path(SOLUTION_ROOT)
        layer.defaultPrim = SOLUTION_NAME
    else:
        stage.OverridePrim(parent)
        root = Sdf.Path(parent).AppendChild(SOLUTION_NAME)
        layer.defaultPrim = Sdf.Path(parent).name
    scope = UsdGeom.Scope.Define(stage, root)
    Usd.ColorSpaceAPI.Apply(scope.GetPrim()).CreateColorSpaceNameAttr(COLOR_SPACE)
    if view == "source":
        scope.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    used: set[str] = {_LOOKS_NAME}
    for pm in patch_meshes:
        info = scene.meshes[pm.mesh_index]
        name, k = info.name, 1
        while name in used:
            name = f"{info.name}_{k}"
            k += 1
        used.add(name)
        _author_patch_mesh(stage, root.AppendChild(name), pm, info, mpu, world_to_parent)

    _author_source_lightmaps(stage, patch_meshes)

    md = {"hirad:metersPerUnit": mpu, "hirad:input": sub, "hirad:solutionRoot": str(root),
          "hirad:colorSpace": f"{COLOR_SPACE}: linear Rec.709 primaries, D65, scene referred; every colour "
                              "is a physical value per channel (radiance W/(m^2 sr), irradiance W/m^2)"}
    md.update(metadata or {})
    layer.customLayerData = _to_vt_value(md)
    arrays = f"its arrays in {arrays_path(output_path).name} and " if _splits(output_path) else ""
    layer.comment = (f"hirad radiosity solution under {root}; sublayers {arrays}the input scene; colours are "
                     "linear Rec.709 (lin_rec709_scene), radiance W/(m^2 sr)")
    del stage  # release the authoring stage so adding the sublayer composes nothing
    # sublayer last so the authoring above never composes (or touches) the input
    export_solution(layer, output_path, [sub])
    return output_path


# The arrays of a text solution layer go to a binary (crate) layer beside it, which the text
# layer sublayers above the input: `solution.usda` and `solution.arrays.usdc`. usd-core formats
# each array of a text layer into one string before it reaches the file: about 100 bytes of
# transient memory per element of the largest array (measured, usd-core 26.11: 2M colour triples
# +204 MiB, 4M +331 MiB), and text about three times the size of the crate and twelve times
# slower to write (one floor of the bench building: 124 MB in 3.4 s against 36 MB in 0.28 s).
# The crate writer writes the arrays as they are. The text
# root keeps what a person reads (what is hidden, the meshes, their materials, the bake's
# metadata); a stage opened on it composes both, so no reader needs to know of the split.
ARRAYS_SUFFIX = ".arrays.usdc"


def _splits(output_path: Path) -> bool:
    """Whether a solution written to `output_path` is text (.usda, the default for another
    suffix), whose arrays go to arrays_path(output_path); .usdc and .usd are crates already."""
    return output_path.suffix not in (".usdc", ".usd")


def arrays_path(layer_path: str | Path) -> Path:
    """The crate layer that holds the arrays of the text solution layer at `layer_path`."""
    p = Path(layer_path)
    return p.with_name(p.stem + ARRAYS_SUFFIX)


def _array_attributes(layer: Sdf.Layer) -> list[Sdf.Path]:
    """Every attribute spec of `layer` whose default value is an array, in traversal order."""
    found: list[Sdf.Path] = []

    def visit(path: Sdf.Path):
        if path.IsPropertyPath():
            spec = layer.GetAttributeAtPath(path)
            if spec and spec.typeName.isArray and spec.HasDefaultValue():
                found.append(path)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found


def _copy_attributes(src: Sdf.Layer, dst: Sdf.Layer, paths: Sequence[Sdf.Path]) -> None:
    """Copies the attribute specs at `paths` from `src` into `dst`, making `over` prims for
    their prims where `dst` has none (arrays are shared, not copied: VtArray is copy on write)."""
    for path in paths:
        Sdf.CreatePrimInLayer(dst, path.GetPrimPath())
        if not Sdf.CopySpec(src, path, dst, path):
            raise RuntimeError(f"could not copy {path} between the solution's layers")


def merge_arrays(layer: Sdf.Layer, layer_path: str | Path) -> bool:
    """Copies into `layer` (the content of the text solution layer at `layer_path`) the arrays
    its crate layer holds (read from the file, never from a layer already open in this process),
    so that it can be edited as one layer and written again with :func:`export_solution`.
    False when there is no crate layer (a layer written before the split, or a .usdc solution:
    its arrays are in it already)."""
    crate = arrays_path(layer_path)
    if not crate.is_file():
        return False
    # Read from the file as it is now: FindOrOpen would give a layer this process already holds
    # (a stage a user keeps open on an earlier bake's output), stale once the file is rewritten.
    arrays = Sdf.Layer.OpenAsAnonymous(str(crate))
    if arrays is None:
        raise SceneError(f"{crate}: cannot open the solution's arrays")
    _copy_attributes(arrays, layer, _array_attributes(arrays))
    return True


def is_arrays_sublayer(sublayer: str, layer_path: str | Path) -> bool:
    """Whether `sublayer` (as a solution layer at `layer_path` names it) is its crate layer."""
    return (Path(layer_path).parent / sublayer).resolve() == arrays_path(layer_path).resolve()


def export_solution(layer: Sdf.Layer, output_path: str | Path, sublayers: Sequence[str]) -> list[Path]:
    """Writes the solution `layer` (anonymous, holding everything, no sublayers) to
    `output_path` with `sublayers` below it. A text output (.usda) moves its arrays to
    arrays_path(output_path), written first and sublayered strongest; a binary one (.usdc,
    .usd) keeps them. Each file is written under a temporary name and renamed when complete.
    Returns the files written, the arrays' first."""
    from ..files import WriteError, atomic_path

    output_path = Path(output_path)
    suffix = ".usda" if _splits(output_path) else output_path.suffix
    targets: list[tuple[Sdf.Layer, Path, str, str]] = []
    if _splits(output_path):
        arrays = Sdf.Layer.CreateAnonymous(ARRAYS_SUFFIX)
        moving = _array_attributes(layer)
        _copy_attributes(layer, arrays, moving)
        for path in moving:
            layer.GetPrimAtPath(path.GetPrimPath()).RemoveProperty(layer.GetAttributeAtPath(path))
        layer.subLayerPaths.append("./" + arrays_path(output_path).name)
        targets.append((arrays, arrays_path(output_path), ".usdc", "the solution layer's arrays"))
    for s in sublayers:
        layer.subLayerPaths.append(s)
    targets.append((layer, output_path, suffix, "the solution layer"))
    for target, path, ext, what in targets:
        try:
            with atomic_path(path, ext) as tmp:
                if not target.Export(str(tmp)):
                    raise WriteError(f"{path}: could not write {what}")
        except Tf.ErrorException as exc:
            raise WriteError(f"{path}: could not write {what} ({_usd_reason(exc)}; is the disk full?)") from None
    return [path for _, path, _, _ in targets]


def _usd_reason(exc: Exception) -> str:
    """The last diagnostic of a Tf.ErrorException, without USD's source location and with the
    temporary's path dropped: "Error in '...' at line N in file F : 'Could not close /x/.tmp'"
    becomes "Could not close"."""
    import re

    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    last = lines[-1] if lines else "unknown USD error"
    m = re.search(r"(?: : | -- )'?(.*?)'?$", last)
    what = m.group(1) if m else last
    return re.sub(r"\s*\S*\.tmp\.usd[ac]?\S*", "", what).strip() or what


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


def find_solution_root(stage: Usd.Stage) -> Usd.Prim | None:
    """The prim holding a solution layer's meshes: the path the layer records, else
    `<defaultPrim>/HiradSolution`, else `/HiradSolution` (layers written before the solution
    moved under the defaultPrim); None when there is none."""
    candidates = []
    recorded = stage.GetRootLayer().customLayerData.get("hirad:solutionRoot")
    if isinstance(recorded, str) and Sdf.Path.IsValidPathString(recorded):
        candidates.append(Sdf.Path(recorded))
    default = stage.GetDefaultPrim()
    if default:
        candidates.append(default.GetPath().AppendChild(SOLUTION_NAME))
    candidates.append(Sdf.Path(SOLUTION_ROOT))
    for c in candidates:
        if not c.IsAbsolutePath() or not c.IsPrimPath():
            continue
        prim = stage.GetPrimAtPath(c)
        if prim and prim.IsValid():
            return prim
    return None


def read_solution_layer(path: str | Path) -> SolutionData:
    """Load a layer written by :func:`write_solution_layer` (plus the input's cameras); points
    in world metres."""
    stage = _open_stage(path)
    time = Usd.TimeCode.Default()
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    root = find_solution_root(stage)
    meshes: list[PatchMeshData] = []
    if root is not None:
        for prim in root.GetChildren():
            if not prim.IsA(UsdGeom.Mesh):
                continue
            m = UsdGeom.Mesh(prim)
            pts = np.array(m.GetPointsAttr().Get(time) or [], dtype=np.float64).reshape(-1, 3)
            to_world = _mat(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time))
            if not np.array_equal(to_world, np.eye(4)):
                pts = _transform_points(pts, to_world)
            pts = pts * mpu
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
                    face_emission=_get_array(prim, "hirad:emission", time, 3),
                    lightmap_uv=_get_array(prim, "hirad:lightmapUV", time, 2),
                    lightmap_path=lm_path,
                    name=prim.GetName(),
                    source_path=prim.GetCustomDataByKey("hirad:sourcePath"),
                )
            )
    if not meshes:
        where = root.GetPath() if root is not None else f"<defaultPrim>/{SOLUTION_NAME} or {SOLUTION_ROOT}"
        raise SceneError(f"{path}: not a hirad solution (no meshes under {where})")
    md = dict(stage.GetRootLayer().customLayerData)
    return SolutionData(
        meshes=meshes,
        cameras=read_cameras(stage),
        meters_per_unit=mpu,
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        metadata=md,
        path=str(path),
    )
