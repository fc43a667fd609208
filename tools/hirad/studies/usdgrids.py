"""Calculation surfaces authored in the USD scene: a Mesh or a Plane prim with ``hirad:grid``
attributes becomes a named grid whose points lie on that surface, facing its normal.

Attributes (all optional; a prim is a calculation surface when it has at least one authored
attribute named ``hirad:grid`` or ``hirad:grid:*``)::

    def Plane "Desk" (
    ) {
        uniform token axis = "Z"
        double width = 1.6
        double length = 0.8
        bool hirad:grid = true              # the marker; false turns the surface off
        string hirad:grid:name = "desk"     # the grid's name (default: the prim's name)
        double hirad:grid:spacing = 0.1     # metres (> 0), or the string "en12464" (the default)
        token hirad:grid:rounding = "ceil"  # ceil | nearest (the EN 12464-1 rule's cell count)
        token hirad:grid:measure = "planar" # planar | vertical | cylindrical | semi_cylindrical
        double hirad:grid:azimuth = 90      # degrees, for vertical and semi_cylindrical
        int hirad:grid:azimuths = 25        # for cylindrical and semi_cylindrical
        double hirad:grid:offset = 0.0      # metres in front of the surface along its normal
        double hirad:grid:border = 0.0      # metres left out along the surface's edges
    }

Lengths are in the stage's units like every other attribute of the prim, scaled to metres by
``metersPerUnit`` (and by the prim's transform, for a Plane's width and length); degrees are
degrees. A ``hirad:grid:*`` name hirad does not know is an error, never ignored.

* **Plane** (UsdGeom.Plane): the rectangle ``width`` x ``length`` centred on the prim's origin
  in the plane normal to ``axis`` (width along X for axis Z or Y, along Z for axis X; length
  along Y for axis Z or X, along Z for axis Y), normal +axis, carried to the world by the prim's
  transform: exactly a ``rectangle`` grid (the config's kind) with the same spacing rule, border
  and offset.
* **Mesh** whose faces all lie in one plane (normals within 1 degree, distances within 1 mm of
  it): the faces' union is the area, laid out like a work plane: a regular grid of equal cells
  over the union's bounding box in the plane's axes (for a horizontal face: e1, e2 of the up
  axis; otherwise u horizontal, v = n x u), the cell centres inside the union and at least
  ``border`` from its outline kept (edges shared by two faces are inside), each weighing its
  cell's area; the EN 12464-1 rule takes d from that box.
* Any other **Mesh** (curved, folded): points per face. Each face (a planar polygon, fan
  triangulated when it is convex, ear clipped otherwise) gets the centres of the cells of
  size ``spacing`` over its own bounding box in its plane that fall inside it, or its centroid
  when none does, each point weighing the face's area over its point count, facing the face's
  normal; the EN 12464-1 rule takes d from the mesh's world bounding box (the longest extent,
  the second when the longest is twice it).

A sensor-only Mesh (a work plane in the air) should be ``invisible`` or of purpose ``guide``:
the bake skips such prims as geometry, so the surface does not cast shadows, while
:func:`grids_from_stage` still reads it. A Plane is never baked (hirad bakes Meshes).

Normals follow the mesh's ``orientation`` (leftHanded flips), the faces' winding and the
prim's transform (mirror transforms included). Errors are StudyError naming the prim and the
attribute.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional, Union

import numpy as np
from pydantic import ValidationError

from .grids import Grid, Layout, _check_count, _inside, _sensors, build_grid, frame, plane_lattice
from .spec import _NAME, Measure, RectangleGrid, StudyError, _Spacing

PREFIX = "hirad:grid"
KNOWN = {"name", "spacing", "rounding", "measure", "azimuth", "azimuths", "offset", "border"}
_PLANAR_COS = math.cos(math.radians(1.0))
_PLANAR_DISTANCE = 1e-3  # m


class _SurfaceAttrs(_Spacing):
    """What the attributes say, validated as the config's grids are."""

    border: float = 0.0
    offset: float = 0.0


def _attr_name(loc) -> str:
    loc = [str(x) for x in loc if not isinstance(x, int)]
    if loc and loc[0] == "measure" and len(loc) > 1:
        loc = loc[1:]
    if loc and loc[0] == "measure":
        return f"{PREFIX}:measure"
    if loc and loc[0] == "type":
        return f"{PREFIX}:measure"
    return f"{PREFIX}:{loc[0]}" if loc else PREFIX


def _read_attrs(prim) -> Optional[tuple[str, _SurfaceAttrs]]:
    """(grid name, attributes) of a marked prim, None for an unmarked or disabled one."""
    path = str(prim.GetPath())
    values = {}
    marked = False
    enabled = True
    for attr in prim.GetAttributes():
        name = attr.GetName()
        if name != PREFIX and not name.startswith(PREFIX + ":"):
            continue
        if not attr.HasAuthoredValue():
            continue
        marked = True
        value = attr.Get()
        if name == PREFIX:
            if not isinstance(value, bool):
                raise StudyError(f"prim {path}: attribute {PREFIX}: expected a bool (true marks the prim as a "
                                 f"calculation surface), got {value!r}")
            enabled = value
            continue
        key = name[len(PREFIX) + 1:]
        if key not in KNOWN:
            raise StudyError(f"prim {path}: attribute {name}: not a hirad grid attribute (known: "
                             + ", ".join(f"{PREFIX}:{k}" for k in sorted(KNOWN)) + ")")
        if hasattr(value, "__str__") and type(value).__name__ in ("Token", "TfToken"):
            value = str(value)
        values[key] = value
    if not marked or not enabled:
        return None
    name = values.pop("name", None)
    if name is None:
        name = prim.GetName()
    elif not isinstance(name, str):
        raise StudyError(f"prim {path}: attribute {PREFIX}:name: expected a string, got {name!r}")
    if not _NAME.match(name):
        raise StudyError(f"prim {path}: attribute {PREFIX}:name: {name!r}: use letters, digits, '_', '.' and '-' "
                         "(it names files)")
    measure = {k: values.pop(k) for k in ("measure", "azimuth", "azimuths") if k in values}
    if "measure" in measure:
        measure["type"] = measure.pop("measure")
    for k in ("spacing", "offset", "border", "azimuth"):
        v = values.get(k, measure.get(k))
        if isinstance(v, int) and not isinstance(v, bool) and k != "spacing":
            (values if k in values else measure)[k] = float(v)
    try:
        m = Measure.model_validate(measure)
    except ValidationError as e:
        err = e.errors()[0]
        key = _attr_name(err["loc"]) if err["loc"] else f"{PREFIX}:measure"
        if not err["loc"]:  # a model-level check: the azimuth rule
            key = f"{PREFIX}:azimuth"
        raise StudyError(f"prim {path}: attribute {key}: {err['msg'].removeprefix('Value error, ')}") from None
    try:
        attrs = _SurfaceAttrs.model_validate({**values, "measure": m})
    except ValidationError as e:
        err = e.errors()[0]
        raise StudyError(f"prim {path}: attribute {_attr_name(err['loc'])}: "
                         f"{err['msg'].removeprefix('Value error, ')} (got {err.get('input')!r})") from None
    for k in ("offset", "border"):
        v = getattr(attrs, k)
        if not math.isfinite(v) or (k == "border" and v < 0):
            raise StudyError(f"prim {path}: attribute {PREFIX}:{k}: {v!r} (a finite length in metres"
                             f"{', not negative' if k == 'border' else ''})")
    return name, attrs


def _world(points: np.ndarray, xf: np.ndarray, mpu: float) -> np.ndarray:
    return (np.c_[points, np.ones(len(points))] @ xf)[:, :3] * mpu  # USD matrices act on row vectors


def _normal_to_world(n: np.ndarray, xf: np.ndarray) -> np.ndarray:
    lin = xf[:3, :3]  # row-vector convention: world = local @ lin
    w = n @ np.linalg.inv(lin).T
    return w / np.linalg.norm(w)


def _plane_grid(name: str, prim, attrs: _SurfaceAttrs, up_axis: str, mpu: float) -> Grid:
    from pxr import Usd, UsdGeom

    path = str(prim.GetPath())
    plane = UsdGeom.Plane(prim)
    width, length = plane.GetWidthAttr().Get(), plane.GetLengthAttr().Get()
    axis = str(plane.GetAxisAttr().Get() or "Z")
    for what, v in (("width", width), ("length", length)):
        if v is None or not (math.isfinite(v) and v > 0):
            raise StudyError(f"prim {path}: attribute {what}: {v!r} (a Plane grid needs a positive {what})")
    ax = {"X": 0, "Y": 1, "Z": 2}.get(axis)
    if ax is None:
        raise StudyError(f"prim {path}: attribute axis: {axis!r} (X, Y or Z)")
    wu = {"Z": 0, "Y": 0, "X": 2}[axis]  # width along
    lv = {"Z": 1, "X": 1, "Y": 2}[axis]  # length along
    eu, ev, en = np.eye(3)[wu] * width, np.eye(3)[lv] * length, np.eye(3)[ax]
    xf = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64)
    corner_l = -0.5 * eu - 0.5 * ev
    corner = _world(corner_l[None], xf, mpu)[0]
    edge_u = _world((corner_l + eu)[None], xf, mpu)[0] - corner
    edge_v = _world((corner_l + ev)[None], xf, mpu)[0] - corner
    normal = _normal_to_world(en, xf)
    # a sheared transform leaves the edges oblique: the rectangle grid refuses that, named here
    lu, lvn = np.linalg.norm(edge_u), np.linalg.norm(edge_v)
    if abs(edge_u @ edge_v) > 1e-6 * lu * lvn:
        raise StudyError(f"prim {path}: its transform shears the plane (the edges are not perpendicular in the "
                         "world); a Plane grid needs a rectangle")
    spec = RectangleGrid(corner=tuple(map(float, corner)), edge_u=tuple(map(float, edge_u)),
                         edge_v=tuple(map(float, edge_v)), normal=tuple(map(float, normal)),
                         spacing=attrs.spacing if attrs.spacing == "en12464" else attrs.spacing * mpu,
                         rounding=attrs.rounding, measure=attrs.measure,
                         border=attrs.border * mpu, offset=attrs.offset * mpu)
    g = build_grid(name, spec, up_axis=up_axis)
    g.kind = "plane"
    g.source = path
    return g


def _newell(face: np.ndarray) -> np.ndarray:
    return np.cross(face, np.roll(face, -1, axis=0)).sum(axis=0)


def _basis(n: np.ndarray, up_axis: str) -> tuple[np.ndarray, np.ndarray]:
    e1, e2, up = frame(up_axis)
    if abs(n @ up) >= _PLANAR_COS:
        u = e1
    else:
        u = np.cross(up, n)
        u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return u, v / np.linalg.norm(v)


def _mesh_faces(prim, mpu: float) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(world corners, unit normal, area) of each usable face."""
    from pxr import Usd, UsdGeom

    path = str(prim.GetPath())
    mesh = UsdGeom.Mesh(prim)
    points, counts, indices = (mesh.GetPointsAttr().Get(), mesh.GetFaceVertexCountsAttr().Get(),
                               mesh.GetFaceVertexIndicesAttr().Get())
    if points is None or counts is None or indices is None or len(counts) == 0:
        raise StudyError(f"prim {path}: the mesh has no faces (points, faceVertexCounts, faceVertexIndices)")
    xf = np.asarray(mesh.ComputeLocalToWorldTransform(Usd.TimeCode.Default()), dtype=np.float64)
    world = _world(np.asarray(points, dtype=np.float64), xf, mpu)
    flip = (mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded) != (np.linalg.det(xf[:3, :3]) < 0)
    idx = np.asarray(indices, dtype=np.int64)
    if len(idx) != int(np.sum(counts)) or (len(idx) and (idx.min() < 0 or idx.max() >= len(world))):
        raise StudyError(f"prim {path}: faceVertexIndices do not match faceVertexCounts and points")
    out = []
    start = 0
    for c in counts:
        face = world[idx[start:start + c]]
        start += c
        if c < 3 or not np.isfinite(face).all():
            continue
        n = _newell(face)
        ln = float(np.linalg.norm(n))
        if ln <= 1e-15:
            continue
        out.append((face, (-n if flip else n) / ln, 0.5 * ln))
    if not out:
        raise StudyError(f"prim {path}: the mesh has no face with an area")
    return out


def _planar(faces) -> Optional[tuple[np.ndarray, float]]:
    """(normal, plane offset) when every face lies in one plane, else None."""
    areas = np.array([a for _, _, a in faces])
    n = sum(a * nn for (_, nn, a) in faces)
    ln = np.linalg.norm(n)
    if ln <= 0:
        return None
    n = n / ln
    if any(nn @ n < _PLANAR_COS for _, nn, _ in faces):
        return None
    allp = np.concatenate([f for f, _, _ in faces])
    d = allp @ n
    c = float(np.sum(areas * np.array([f.mean(axis=0) @ n for f, _, _ in faces])) / areas.sum())
    if np.abs(d - c).max() > _PLANAR_DISTANCE:
        return None
    return n, c


def _grid(name, kind, measure, pts, nrm, w, up_axis, layout=None, area=None, spacing=None, rule=None, source=None):
    normals, sp, sn, sw, so = _sensors(name, measure, pts, nrm, up_axis)
    return Grid(name=name, kind=kind, measure=measure, points=pts, normals=normals, weights=w,
                sensor_points=np.ascontiguousarray(sp), sensor_normals=np.ascontiguousarray(sn),
                sensor_weights=sw, sensor_owner=so, layout=layout, area=area, spacing=spacing, rule=rule,
                source=source)


def _planar_mesh_grid(name, path, faces, n, c, attrs: _SurfaceAttrs, up_axis: str, mpu: float) -> Grid:
    u, v = _basis(n, up_axis)
    local = [np.stack([f @ u, f @ v], axis=1) for f, _, _ in faces]
    uv, ii, jj, (nu, nv, du, dv, rule), (umin, umax, vmin, vmax) = plane_lattice(
        name, local, attrs.border * mpu, attrs.spacing if attrs.spacing == "en12464" else attrs.spacing * mpu,
        attrs.rounding,
        no_area=f"prim {path}: attribute {PREFIX}:border: {attrs.border:g} leaves no area of the surface",
        no_point=f"prim {path}: no grid point lies on the surface (spacing {attrs.spacing}, border "
                 f"{attrs.border:g}); use a smaller spacing")
    origin = (c + attrs.offset * mpu) * n
    pts = origin + uv[:, :1] * u + uv[:, 1:] * v
    layout = Layout(origin=origin, axis_u=u, axis_v=v, nu=nu, nv=nv, du=du, dv=dv, u0=umin + 0.5 * du,
                    v0=vmin + 0.5 * dv, index=np.stack([ii, jj], axis=1), outlines=local,
                    evaluation_box=(umin, umax, vmin, vmax))
    w = np.full(len(pts), du * dv)
    return _grid(name, "mesh", attrs.measure, pts, np.broadcast_to(n, pts.shape).copy(), w, up_axis, layout,
                 float(w.sum()), (du, dv), rule, path)


def _triangles(poly2: np.ndarray) -> list[tuple[int, int, int]]:
    """Ear clipping of a simple 2D polygon (either winding)."""
    n = len(poly2)
    area2 = float(np.sum(poly2[:, 0] * np.roll(poly2[:, 1], -1) - np.roll(poly2[:, 0], -1) * poly2[:, 1]))
    sign = 1.0 if area2 > 0 else -1.0
    idx = list(range(n))
    out = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10 * n * n:
        guard += 1
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly2[i0], poly2[i1], poly2[i2]
            if sign * cross(a, b, c) <= 0:
                continue
            inside = False
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                p = poly2[j]
                if sign * cross(a, b, p) >= 0 and sign * cross(b, c, p) >= 0 and sign * cross(c, a, p) >= 0:
                    inside = True
                    break
            if not inside:
                out.append((i0, i1, i2))
                idx.pop(k)
                break
        else:
            break
    if len(idx) == 3:
        out.append(tuple(idx))
    return out


def _curved_mesh_grid(name, path, faces, attrs: _SurfaceAttrs, up_axis: str, mpu: float) -> Grid:
    allp = np.concatenate([f for f, _, _ in faces])
    ext = np.sort(allp.max(axis=0) - allp.min(axis=0))[::-1]
    rule = None
    if attrs.spacing == "en12464":
        from .grids import en12464_dimension, en12464_spacing

        d = en12464_dimension(float(ext[0]), float(ext[1]) if ext[1] > 0 else float(ext[0]))
        s = en12464_spacing(d)
        rule = {"d": float(d), "p": float(s), "rounding": "ceil"}
    else:
        s = attrs.spacing * mpu
    pts, nrm, w = [], [], []
    for face, n, area in faces:
        u, v = _basis(n, up_axis)
        p2 = np.stack([face @ u, face @ v], axis=1)
        lo, hi = p2.min(axis=0), p2.max(axis=0)
        nu = max(1, math.ceil((hi[0] - lo[0]) / s * (1 - 1e-9)))
        nv = max(1, math.ceil((hi[1] - lo[1]) / s * (1 - 1e-9)))
        _check_count(name, len(pts) + nu * nv)
        du, dv = (hi[0] - lo[0]) / nu, (hi[1] - lo[1]) / nv
        ii, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        uv = np.stack([lo[0] + (ii.ravel() + 0.5) * du, lo[1] + (jj.ravel() + 0.5) * dv], axis=1)
        keep = _inside(uv, list(zip(p2, np.roll(p2, -1, axis=0))))
        uv = uv[keep]
        depth = float(face.mean(axis=0) @ n)
        if len(uv):
            p3 = uv[:, :1] * u + uv[:, 1:] * v + depth * n
        else:  # a face smaller than a cell: its centroid (area-weighted over its triangles)
            tris = _triangles(p2)
            cs = np.array([face[list(t)].mean(axis=0) for t in tris]) if tris else face.mean(axis=0)[None]
            ws = np.array([0.5 * np.linalg.norm(np.cross(face[t[1]] - face[t[0]], face[t[2]] - face[t[0]]))
                           for t in tris]) if tris else np.ones(1)
            p3 = (np.sum(cs * ws[:, None], axis=0) / max(ws.sum(), 1e-300))[None]
        p3 = p3 + attrs.offset * mpu * n
        pts.append(p3)
        nrm.append(np.broadcast_to(n, p3.shape))
        w.append(np.full(len(p3), area / len(p3)))
    pts, nrm, w = np.concatenate(pts), np.concatenate(nrm).copy(), np.concatenate(w)
    _check_count(name, len(pts))
    return _grid(name, "mesh", attrs.measure, np.ascontiguousarray(pts), np.ascontiguousarray(nrm), w, up_axis,
                 None, float(w.sum()), (float(s), float(s)), rule, path)


def grids_from_stage(stage_or_path: Union["object", str, Path], up_axis: Optional[str] = None) -> list[Grid]:
    """Every calculation surface of a stage (a Usd.Stage or a path to open) as a built Grid,
    the same objects as build_grids gives, in the stage's traversal order (instance proxies
    included, inactive prims skipped). Visibility and purpose are not consulted: a sensor-only
    Mesh should be `invisible` or of purpose `guide`, so that the bake does not take it for
    geometry (hirad.usd skips those) while it still is a grid here; a Plane is never geometry.
    `up_axis` defaults to the stage's. Two surfaces of one name, a marked prim that is neither
    a Mesh nor a Plane, and bad attribute values are StudyError naming the prim and the
    attribute."""
    from pxr import Usd, UsdGeom

    if isinstance(stage_or_path, (str, Path)):
        try:
            stage = Usd.Stage.Open(str(stage_or_path))
        except Exception as e:  # noqa: BLE001 - pxr raises Tf errors of its own type
            raise StudyError(f"{stage_or_path}: cannot open the stage: {e}") from None
        if stage is None:
            raise StudyError(f"{stage_or_path}: cannot open the stage")
    else:
        stage = stage_or_path
    up_axis = up_axis or str(UsdGeom.GetStageUpAxis(stage))
    frame(up_axis)
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    out, seen = [], {}
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        read = _read_attrs(prim)
        if read is None:
            continue
        name, attrs = read
        path = str(prim.GetPath())
        if name in seen:
            raise StudyError(f"prim {path}: attribute {PREFIX}:name: {name!r} is also the grid of {seen[name]}")
        seen[name] = path
        if prim.IsA(UsdGeom.Plane):
            out.append(_plane_grid(name, prim, attrs, up_axis, mpu))
        elif prim.IsA(UsdGeom.Mesh):
            faces = _mesh_faces(prim, mpu)
            flat = _planar(faces)
            if flat is not None:
                out.append(_planar_mesh_grid(name, path, faces, flat[0], flat[1], attrs, up_axis, mpu))
            else:
                out.append(_curved_mesh_grid(name, path, faces, attrs, up_axis, mpu))
        else:
            raise StudyError(f"prim {path}: has {PREFIX} attributes but is a {prim.GetTypeName() or 'typeless prim'}; "
                             "a calculation surface is a Mesh or a Plane")
    return out


# ----------------------------------------------------------------------------------------------
# stored daylight: what `hirad grid` needs to read a daylit solution layer as the bake did
# ----------------------------------------------------------------------------------------------
#
# A bake evaluates its grids on a SurfaceField whose faces carry their glazing (the normal
# transmittance of direct light, hirad.daylight.glazing) and whose lights include the sun and
# sky as distant lights. The solution layer holds neither: the bake writes them beside it as
# `daylight.npz` (named in the layer's customLayerData `hirad:daylight`), and `hirad grid`
# applies them to the loaded solution, so that its grids see the sun and sky through the
# windows exactly as the bake's did. Contents:
#
# * `faces`: the number of faces of the layer (its meshes in order, each one's faces in order:
#   the order hirad.solution.load_solution reads them);
# * `transmittance` (faces,), when any face is glass; `glass_faces` and `glass_centroids`, the
#   glazed faces and their centroids, to check that the layer is still the one it was written
#   for;
# * per distant light k: `d<k>_directions`, `_weights`, `_illuminance`, `_colour` (unweighted),
#   `_weight` (its light group's dimmer x colour, 1 without groups; hirad relight rewrites it),
#   `_tints` (when it has them), `_kind`, `_source`, `_luminaire` (its index among the bake's
#   luminaires, as light groups name it); `names` of all.

DAYLIGHT_FILE = "daylight.npz"
DAYLIGHT_KEY = "hirad:daylight"
_DAYLIGHT_FORMAT = "hirad-stored-daylight"


def _centroids(corners: np.ndarray, nv: np.ndarray) -> np.ndarray:
    c = np.asarray(corners, dtype=np.float64)
    k = np.asarray(nv).reshape(-1, 1)
    mask = (np.arange(c.shape[1])[None, :] < k)[..., None]
    return (c * mask).sum(axis=1) / k


def day_light_weights(groups, n_specs: int, n_day: int) -> np.ndarray:
    """(n_day, 3): each distant light's group weight (dimmer x colour; 1 in no group). A bake's
    luminaire index i >= n_specs is distant light i - n_specs (hirad.relight.resolve_groups)."""
    w = np.ones((n_day, 3))
    for g in groups or ():
        for i in g.luminaires:
            if n_specs <= i < n_specs + n_day:
                w[i - n_specs] = g.weight
    return w


def save_stored_daylight(out_dir: Path, day_lights, transmittance, corners, nv, layer_faces, *, groups=None,
                         n_specs: int = 0) -> dict:
    """Writes OUT/daylight.npz when the bake has glass or distant lights (sun, sky) and returns
    the solution layer's metadata naming it ({} when there is nothing to store). `day_lights`:
    hirad.daylight.sources.DistantLightSpec, unweighted; `transmittance`, `corners`, `nv`: per
    display face; `layer_faces`: the display faces of each solution mesh, in the layer's order
    (hirad.outputs.meshes.patch_meshes); `groups`/`n_specs`: the light groups and the number of
    non-distant luminaires before the distant ones (their weights)."""
    import io

    from .. import files

    order = np.concatenate([np.asarray(f, dtype=np.int64) for f in layer_faces]) if len(layer_faces) else \
        np.zeros(0, dtype=np.int64)
    tau = None if transmittance is None else np.asarray(transmittance, dtype=np.float64)[order]
    glazed = tau is not None and bool(np.any(tau > 0))
    if not glazed and not day_lights:
        return {}
    arrays: dict = {"format": np.array(_DAYLIGHT_FORMAT), "version": np.array(1), "faces": np.array(len(order)),
                    "names": np.array([str(d.name) for d in day_lights], dtype=str)}
    if glazed:
        glass = np.flatnonzero(tau > 0)
        arrays.update(transmittance=tau, glass_faces=glass,
                      glass_centroids=_centroids(np.asarray(corners)[order][glass], np.asarray(nv)[order][glass]))
    weights = day_light_weights(groups, n_specs, len(day_lights))
    for k, d in enumerate(day_lights):
        arrays.update({f"d{k}_directions": np.asarray(d.directions, dtype=np.float64),
                       f"d{k}_weights": np.asarray(d.weights, dtype=np.float64),
                       f"d{k}_illuminance": np.array(float(d.illuminance)),
                       f"d{k}_colour": np.asarray(d.colour, dtype=np.float64).reshape(3),
                       f"d{k}_weight": weights[k], f"d{k}_kind": np.array(str(d.kind)),
                       f"d{k}_luminaire": np.array(int(n_specs) + k),
                       f"d{k}_source": np.array(str(d.source))})
        if d.tints is not None:
            arrays[f"d{k}_tints"] = np.asarray(d.tints, dtype=np.float64)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    files.write_bytes(Path(out_dir) / DAYLIGHT_FILE, buf.getvalue())
    return {DAYLIGHT_KEY: DAYLIGHT_FILE}


def read_stored_daylight(path) -> dict:
    """The arrays of a daylight.npz (a StudyError naming the file when it is not one)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        if str(arrays.get("format")) != _DAYLIGHT_FORMAT:
            raise ValueError("not a hirad stored-daylight file")
        int(arrays["faces"])
        for k in range(len(arrays["names"])):
            for a in ("directions", "weights", "illuminance", "colour", "weight"):
                arrays[f"d{k}_{a}"]
    except (OSError, KeyError, ValueError, TypeError) as e:
        raise StudyError(f"{path}: not a hirad daylight file ({e})") from None
    return arrays


def stored_day_lights(arrays: dict, path="daylight.npz") -> list:
    """The distant lights of a daylight.npz, each with its colour times its group weight."""
    from ..daylight.sources import DaylightError, DistantLightSpec

    out = []
    for k, name in enumerate(arrays["names"]):
        try:
            out.append(DistantLightSpec(
                name=str(name), directions=arrays[f"d{k}_directions"], weights=arrays[f"d{k}_weights"],
                illuminance=float(arrays[f"d{k}_illuminance"]),
                colour=np.asarray(arrays[f"d{k}_colour"]) * np.asarray(arrays[f"d{k}_weight"]),
                kind=str(arrays.get(f"d{k}_kind", "sun")), source=str(arrays.get(f"d{k}_source", "")),
                tints=arrays.get(f"d{k}_tints")))
        except DaylightError as e:
            raise StudyError(f"{path}: {e}") from None
    return out


def _layer_metadata(solution) -> dict:
    from pxr import Sdf

    layer = Sdf.Layer.OpenAsAnonymous(str(solution), True)  # its metadata only
    return dict(layer.customLayerData) if layer is not None else {}


def _old_distant(luminaires) -> list[str]:
    """Names of luminaires that are distant lights stored by a hirad that kept only their
    directions (as points on the unit sphere) and no light (all-zero candela)."""
    out = []
    for l in luminaires:
        if getattr(l, "is_distant", False):
            continue
        pts = np.asarray(l.points, dtype=np.float64)
        if not np.any(np.asarray(l.candela)) and len(pts) and np.allclose(np.linalg.norm(pts, axis=1), 1.0,
                                                                            atol=1e-9):
            out.append(str(l.name))
    return out


def apply_stored_daylight(sol, solution) -> dict:
    """Gives a loaded solution (hirad.solution.SurfaceSolution of `solution`, its layer) the
    glazing and the sun and sky its bake stored in daylight.npz, so that its illuminance is the
    bake's. Returns what was applied ({"glazed_faces", "distant_lights"}). A layer that names a
    missing or damaged file, or whose faces no longer match it, or an older daylit layer whose
    luminaires.npz kept the sun and sky without their light, is a SceneError (exit 3)."""
    from ..usd import SceneError

    name = _layer_metadata(solution).get(DAYLIGHT_KEY)
    if not name:
        old = _old_distant(sol.luminaires)
        if old:
            raise SceneError(f"{solution}: its luminaires file holds the distant lights {', '.join(old)} (sun, sky) "
                             "without their light and the layer names no daylight file (glazing): written by an "
                             "older hirad; bake the scene again to evaluate grids on it")
        return {"glazed_faces": 0, "distant_lights": 0}
    file = Path(solution).parent / str(name)
    if not file.is_file():
        raise SceneError(f"{solution}: names its daylight file {name} (the glazing, sun and sky), which is missing "
                         "beside it (their light through the windows would be lost)")
    try:
        arrays = read_stored_daylight(file)
        lights = stored_day_lights(arrays, file)
    except StudyError as e:
        raise SceneError(str(e)) from None
    faces = int(arrays["faces"])
    if faces != sol.face_count:
        raise SceneError(f"{file}: written for {faces} faces, the layer {solution} has {sol.face_count}: the layer "
                         "changed since the bake; bake again")
    glazed = 0
    if "transmittance" in arrays:
        tau = np.asarray(arrays["transmittance"], dtype=np.float64)
        glass = np.asarray(arrays["glass_faces"], dtype=np.int64)
        corners = np.asarray(sol.corners)
        at = _centroids(corners[glass], np.asarray(sol.nv)[glass])
        scale = 1.0 + float(np.abs(corners).max()) if len(corners) else 1.0
        off = np.abs(at - np.asarray(arrays["glass_centroids"])).max() if len(glass) else 0.0
        if tau.shape != (faces,) or off > 1e-5 * scale:
            raise SceneError(f"{file}: its glazed faces are not where the layer {solution} has them (off by "
                             f"{off:.3g} m): the layer changed since the bake; bake again")
        sol.transmittance = tau
        glazed = int(len(glass))
    if lights:
        keep = [l for l in sol.luminaires if not getattr(l, "is_distant", False)]
        sol.luminaires = keep + [d.to_engine() for d in lights]
    sol._field = None  # built again with the glazing and the lights
    return {"glazed_faces": glazed, "distant_lights": len(lights)}
