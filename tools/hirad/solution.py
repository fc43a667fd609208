"""A baked solution as Python sees it: values at points, renders, the final gather; from a bake or from a stored solution.usda."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from . import _engine, usd
from .outputs import images
from .errors import BakeError


# The farthest surface a point's value is taken from, metres: `hirad probe --max-distance`'s
# default, and the API's.
PROBE_MAX_DISTANCE = 0.05

# Rec.709 / sRGB primaries: the photometric Y of linear RGB (the grids report Y).
REC709_Y = np.array([0.2126, 0.7152, 0.0722])
# Hemisphere rays per sensor point for the indirect light of `illuminance` (the grids' default).
ILLUMINANCE_RAYS = 512


def luminance_y(rgb) -> np.ndarray:
    """Y = 0.2126 R + 0.7152 G + 0.0722 B of linear Rec.709 RGB (..., 3) -> (...)."""
    return np.asarray(rgb, dtype=np.float64) @ REC709_Y


# --------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------


class SurfaceSolution:
    """Radiance and irradiance over the solved surfaces, queryable at any point.

    The surface is held in one of two forms. Spelled out per face: `corners` (P,4,3) metres,
    `nv` (P,) 3 or 4, and per corner `corner_radiance` (exitant, W/(m^2 sr)) and
    `corner_irradiance` (W/m^2), each (P,4,3); triangles repeat corner 2 as corner 3. Or
    indexed, as a display mesh holds it (keywords `points` (V,3), `faces` (P,4) of point
    indices, `point_radiance` and `point_irradiance` (V,3)): 16 bytes a face and 72 a point
    instead of 288 bytes a face (a bake's Result: one floor of the bench building, 623k faces,
    holds 55 MB instead of 171). Both forms answer every query with the same bits; in the
    indexed one `corners`, `corner_radiance` and `corner_irradiance` are made when read (use
    `face_count` for their length).
    Also: `cameras`, `up_axis`; `emitted_radiance` (P,3) the self-emitted radiance E/pi of each
    face (0 for non-emitters; None when unknown: a solution layer written before hirad stored
    primvars:hirad:emission); `luminaires` (hirad._engine.Luminaire) whose exact direct light
    illuminance and the volume probes add, stored beside the layer as luminaires.npz
    (save_luminaires); `transmittance` (P,) per face the normal transmittance of direct light
    through glazing (None: all opaque), so that the luminaires' and the sun's and sky's direct
    light reaches grid points through windows; `source`, the solution layer this was read from,
    for messages."""

    def __init__(self, corners: np.ndarray | None = None, nv: np.ndarray | None = None,
                 corner_radiance: np.ndarray | None = None, corner_irradiance: np.ndarray | None = None,
                 cameras: list | None = None, up_axis: str = "Y", emitted_radiance: np.ndarray | None = None,
                 luminaires: list | None = None, transmittance: np.ndarray | None = None, source: str | None = None,
                 *, points: np.ndarray | None = None, faces: np.ndarray | None = None,
                 point_radiance: np.ndarray | None = None, point_irradiance: np.ndarray | None = None):
        if nv is None:
            raise TypeError("SurfaceSolution needs nv")
        if (corners is None) == (points is None or faces is None):
            raise TypeError("SurfaceSolution takes either corners or points and faces")
        self._corners, self._corner_radiance, self._corner_irradiance = corners, corner_radiance, corner_irradiance
        self.points, self.faces = points, faces
        self.point_radiance, self.point_irradiance = point_radiance, point_irradiance
        self.nv = nv
        self.cameras = list(cameras) if cameras is not None else []
        self.up_axis = up_axis
        self.emitted_radiance = emitted_radiance
        self.luminaires = list(luminaires) if luminaires is not None else []
        self.transmittance = transmittance
        self.source = source
        self._field = None

    @property
    def indexed(self) -> bool:
        return self._corners is None

    @property
    def face_count(self) -> int:
        return len(self.nv)

    def _per_corner(self, spelled, per_point):
        if not self.indexed:
            return spelled
        return None if per_point is None else np.ascontiguousarray(per_point[self.faces])

    @property
    def corners(self) -> np.ndarray:
        """(P,4,3) the faces' corners, metres (made from the points when indexed)."""
        return self._per_corner(self._corners, self.points)

    @property
    def corner_radiance(self) -> np.ndarray | None:
        """(P,4,3) exitant radiance W/(m^2 sr) at the faces' corners."""
        return self._per_corner(self._corner_radiance, self.point_radiance)

    @property
    def corner_irradiance(self) -> np.ndarray | None:
        """(P,4,3) irradiance W/m^2 at the faces' corners."""
        return self._per_corner(self._corner_irradiance, self.point_irradiance)

    @property
    def field(self) -> "_engine.SurfaceField":
        if self._field is None:
            glass = {}
            if self.transmittance is not None and np.any(self.transmittance > 0):
                from .daylight.glazing import angular_table
                glass = {"transmittance": np.ascontiguousarray(self.transmittance, dtype=np.float64),
                         "glass_angular": np.ascontiguousarray(angular_table(), dtype=np.float64)}
            nv = np.ascontiguousarray(self.nv, dtype=np.int32)
            if self.indexed:
                self._field = _engine.SurfaceField(
                    points=np.ascontiguousarray(self.points, dtype=np.float64),
                    faces=np.ascontiguousarray(self.faces, dtype=np.int32), nv=nv,
                    point_radiance=None if self.point_radiance is None else np.ascontiguousarray(
                        self.point_radiance, dtype=np.float64),
                    point_irradiance=None if self.point_irradiance is None else np.ascontiguousarray(
                        self.point_irradiance, dtype=np.float64), **glass)
            else:
                self._field = _engine.SurfaceField(self.corners, nv, self.corner_radiance, self.corner_irradiance,
                                                   **glass)
            if self.luminaires:
                self._field.set_luminaires(list(self.luminaires))
        return self._field

    def query(self, points, normals=None, max_distance: float = PROBE_MAX_DISTANCE) -> dict:
        """Values at the surface point nearest to each of `points` (metres), looked for within
        `max_distance` metres only (default 0.05, as `hirad probe`), among the surfaces facing
        along `normals` when given (within 60 degrees). Returns a dict of arrays: patch (its
        index, -1 where no surface is that near), distance (metres, NaN where none),
        irradiance (W/m^2, RGB) and radiance (exitant, W/(m^2 sr), RGB), both NaN where no
        surface is within `max_distance`: a point is never given the value of a surface
        farther away. `max_distance` must be a positive number (math.inf searches
        everywhere)."""
        md = float(max_distance)
        if not md > 0:  # also NaN
            raise ValueError(f"max_distance must be a positive number of metres, not {max_distance!r}")
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        nrm = np.zeros_like(pts) if normals is None else np.ascontiguousarray(
            np.asarray(normals, dtype=np.float64).reshape(-1, 3))
        if nrm.shape != pts.shape:
            raise ValueError(f"normals: {len(nrm)} rows for {len(pts)} points")
        res = self.field.probe(pts, nrm, min(md, 1e30))
        q = {k: np.asarray(getattr(res, k)) for k in ("patch", "distance", "irradiance", "radiance")}
        none = q["patch"] < 0
        if none.any():
            for key in ("irradiance", "radiance"):
                q[key] = np.array(q[key], dtype=np.float64)
                q[key][none] = np.nan
            q["distance"] = np.array(q["distance"], dtype=np.float64)
            q["distance"][none] = np.nan
        return q

    def irradiance_at(self, points, normals=None, max_distance: float = PROBE_MAX_DISTANCE) -> np.ndarray:
        """Irradiance (W/m^2, RGB) at the surface point nearest to each of `points` (facing
        along `normals` when given); NaN for a point with no surface within `max_distance`
        metres (default 0.05, as `hirad probe`). See `query`."""
        return self.query(points, normals, max_distance)["irradiance"]

    def radiance_at(self, points, normals=None, max_distance: float = PROBE_MAX_DISTANCE) -> np.ndarray:
        """Exitant radiance (W/(m^2 sr), RGB) at the surface point nearest to each of
        `points`; NaN for a point with no surface within `max_distance` metres (default 0.05,
        as `hirad probe`). See `query`."""
        return self.query(points, normals, max_distance)["radiance"]

    def illuminance(self, points, normals, rays: int = ILLUMINANCE_RAYS, seed: int = 1,
                    emitter_samples: int = 4) -> np.ndarray:
        """Illuminance (W/m^2 per RGB channel; lux read photometrically) on small planes at
        `points` (K,3) facing the unit `normals` (K,3), at the points themselves (no snapping
        to a surface): the direct light of the emitting patches exactly (contour integrals,
        with visibility) plus the indirect light of every other surface by `rays` hemisphere
        rays (seeded: the same seed gives the same values). Returns (K,3) direct + indirect."""
        if self.emitted_radiance is None:
            from .usd import SceneError

            where = f"{self.source}: " if self.source else ""
            raise SceneError(f"{where}the solution layer predates primvars:hirad:emission (the emission of each "
                             "face, which tells the emitters from the lit surfaces); bake the scene again with this "
                             "hirad to evaluate grids on it")
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
        if nrm.shape != pts.shape:
            raise ValueError(f"normals: {len(nrm)} rows for {len(pts)} points")
        emitted = np.ascontiguousarray(self.emitted_radiance, dtype=np.float64)
        if emitted.shape != (self.face_count, 3):
            raise ValueError(f"emitted_radiance has shape {emitted.shape}, expected ({self.face_count}, 3)")
        res = self.field.illuminance(pts, nrm, emitted, int(rays), int(seed), int(emitter_samples))
        return np.asarray(res.direct, dtype=np.float64) + np.asarray(res.indirect, dtype=np.float64)

    def illuminance_evaluator(self, rays: int = ILLUMINANCE_RAYS, seed: int = 1):
        """`evaluate(points, normals) -> (K,)`, Rec.709 Y of `illuminance`, for
        hirad.studies.evaluate_grids."""
        def evaluate(points, normals):
            return luminance_y(self.illuminance(points, normals, rays=rays, seed=seed))
        return evaluate

    def render(self, camera: str | None = None, width: int = 512, height: int = 512,
               samples: int = 4) -> np.ndarray:
        """Renders exitant radiance from a scene camera (by prim path) or a default view."""
        return images.render(self.field, self.view(camera), width, height, samples)

    def view(self, camera: str | None) -> images.View:
        if camera:
            for cam in self.cameras:
                if cam.path == camera:
                    return images.view_from_camera(cam)
            known = ", ".join(c.path for c in self.cameras) or "none"
            raise BakeError(f"camera {camera} not found (cameras in the scene: {known})")
        if self.cameras:
            return images.view_from_camera(self.cameras[0])
        if self.indexed:  # the faces' points, not their corners spelled out (96 bytes a face)
            used = np.zeros(len(self.points), dtype=bool)
            used[np.asarray(self.faces).reshape(-1)] = True
            return images.default_view(np.asarray(self.points)[used], self.up_axis)
        return images.default_view(self.corners.reshape(-1, 3), self.up_axis)

    def _copy_into(self, cls):
        """This solution as an instance of `cls` (a subclass), sharing its arrays and field."""
        other = cls.__new__(cls)
        other.__dict__.update(self.__dict__)
        return other


class Result(SurfaceSolution):
    """What `bake` returns: the solution in memory plus where its outputs were written:
    `output_dir`, `report`; per patch (the solution's elements) `patch_radiosity` B and
    `patch_irradiance` H (P,3) W/m^2, and `patches` (their arrays); the engine model, kept for
    the final gather; whether the bake was hierarchical."""

    def __init__(self, *args, output_dir: Path | None = None, report: dict | None = None,
                 patch_radiosity: np.ndarray | None = None, patch_irradiance: np.ndarray | None = None,
                 patches: dict | None = None, _model: object = None, hierarchical: bool = False, **kwargs):
        super().__init__(*args, **kwargs)
        self.output_dir = output_dir
        self.report = report if report is not None else {}
        self.patch_radiosity = patch_radiosity
        self.patch_irradiance = patch_irradiance
        self.patches = patches if patches is not None else {}
        self._model = _model
        self.hierarchical = hierarchical

    def gather(self, points, normals, *, rays: int = 4, cluster_samples: int = 8,
               seed: int = 1, directional: bool = False, importance: float = 0.0,
               second_bounce: float = 1.0) -> dict:
        """Final gather at surface points: hierarchical bakes re-evaluate every link that
        reaches a point's element at the point itself (exact point-to-polygon form factors,
        Embree visibility); flat bakes gather from every patch, O(patches) a point. Returns
        dict of patch (-1 if no surface faces along the normal), irradiance (W/m^2) and
        radiance (W/(m^2 sr)); with `directional` (hierarchical bakes) also l0 (n, 3) = the
        integral of L dw and l1 (n, 3 channels, 3 axes) = the integral of L w dw over the
        point's hemisphere (W/m^2; hirad.outputs.directional). `importance` > 0 (hierarchical):
        per element, its weakest links, together at most that share of its light, are taken at
        their mean instead of at each point (not emitters, not close sources; GatherOptions).
        `second_bounce` (hierarchical): a source element nearer than this times its diagonal
        has its radiosity gathered again at points drawn where the point sees it (contact
        shadows; 0: every source at its element's radiosity; pipeline/hierarchy/gather.h)."""
        if self._model is None:
            raise BakeError("gather needs the bake's engine model (a Result of hirad.bake)")
        if self.hierarchical and not self._model.has_hierarchy:
            raise BakeError("gather: this bake let go of its solved hierarchy once no output needed it (about 0.7 "
                            "GB on a 1M-triangle scene); hirad.bake(..., keep_hierarchy=True) keeps it")
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
        if self.hierarchical:
            return hierarchical_gather(self._model, pts, nrm, rays=rays, cluster_samples=cluster_samples, seed=seed,
                                       directional=directional, importance=importance, second_bounce=second_bounce)
        if directional:
            raise BakeError("a directional gather needs a hierarchical bake (method: hierarchical)")
        g = self._model.gather_flat(pts, nrm, np.ascontiguousarray(self.patch_radiosity), rays, seed)
        return {k: getattr(g, k) for k in ("patch", "irradiance", "radiance")}


def hierarchical_gather(model, points: np.ndarray, normals: np.ndarray, *, rays: int = 4, cluster_samples: int = 8,
                        seed: int = 1, directional: bool = False, importance: float = 0.0,
                        second_bounce: float = 1.0) -> dict:
    """The engine's final gather at (n, 3) points and normals, as
    Result.gather returns it: the bake's final-gather lightmaps call it before the Result
    exists (they run right after the solve, while the hierarchy is held anyway)."""
    points = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    normals = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    g = model.gather(points, normals, _engine.GatherOptions(rays=rays, cluster_samples=cluster_samples, seed=seed,
                                                            directional=bool(directional),
                                                            importance=float(importance),
                                                            second_bounce=float(second_bounce)))
    keys = ("patch", "irradiance", "radiance") + (("l0", "l1") if directional else ())
    return {k: getattr(g, k) for k in keys}


LUMINAIRES_FILE = "luminaires.npz"
_LUMINAIRE_ARRAYS = ("points", "weights", "frame", "candela", "colour")


def save_luminaires(luminaires, path) -> None:
    """The engine luminaires as one .npz (arrays l<k>_<name>, names in `names`), so that
    `hirad grid` on a stored bake evaluates their direct light exactly as the bake did."""
    import io

    from .files import write_bytes

    arrays = {"names": np.array([l.name for l in luminaires], dtype=object).astype(str)}
    for k, l in enumerate(luminaires):
        for a in _LUMINAIRE_ARRAYS:
            arrays[f"l{k}_{a}"] = np.asarray(getattr(l, a), dtype=np.float64)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    write_bytes(Path(path), buf.getvalue())


def load_luminaires(path) -> list:
    """The luminaires save_luminaires wrote (a BakeError naming the file if it is not one)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            names = [str(n) for n in z["names"]]
            out = []
            for k, name in enumerate(names):
                a = {n: np.ascontiguousarray(z[f"l{k}_{n}"], dtype=np.float64) for n in _LUMINAIRE_ARRAYS}
                out.append(_engine.Luminaire(name, a["points"], a["weights"], a["frame"], a["candela"],
                                             a["colour"].reshape(1, 3)))
            return out
    except (OSError, KeyError, ValueError) as e:
        raise BakeError(f"{path}: not a hirad luminaires file ({e})") from None


def load_solution(path: str | os.PathLike) -> SurfaceSolution:
    """Opens a solution layer written by a bake, for rendering or probing without solving."""
    data = usd.read_solution_layer(path)
    points, faces, nv, rad, irr, emitted = [], [], [], [], [], []
    has_emission = all(m.face_emission is not None for m in data.meshes)
    base = 0
    for m in data.meshes:
        counts = np.asarray(m.face_vertex_counts, dtype=np.int64)
        bad = np.nonzero((counts != 3) & (counts != 4))[0]
        if len(bad):
            raise BakeError(f"{path}: {m.name}: face {int(bad[0])} has {int(counts[bad[0]])} corners; hirad writes "
                            "triangles and quads")
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        idx = np.asarray(m.face_vertex_indices, dtype=np.int64)
        if len(idx) != counts.sum() or (len(idx) and (idx.min() < 0 or idx.max() >= len(m.points))):
            raise BakeError(f"{path}: {m.name}: its faceVertexIndices do not index its {len(m.points)} points")
        # per face its corners' points; a triangle repeats its last as its fourth
        four = idx[first[:, None] + np.minimum(np.arange(4)[None, :], counts[:, None] - 1)]
        faces.append(four + base)
        base += len(m.points)
        points.append(np.asarray(m.points, dtype=np.float64))
        rad.append(np.asarray(m.vertex_radiance, dtype=np.float64))
        irr.append(np.asarray(m.vertex_irradiance, dtype=np.float64))
        nv.append(counts)
        if has_emission:
            emitted.append(np.asarray(m.face_emission, dtype=np.float64) / np.pi)
    if not faces or sum(len(f) for f in faces) == 0:
        raise BakeError(f"{path}: the solution has no faces")
    if base > np.iinfo(np.int32).max:
        raise BakeError(f"{path}: the solution has {base:,} points, more than hirad indexes")
    return SurfaceSolution(nv=np.concatenate(nv).astype(np.int32),
                           points=np.ascontiguousarray(np.concatenate(points)),
                           faces=np.ascontiguousarray(np.concatenate(faces), dtype=np.int32),
                           point_radiance=np.ascontiguousarray(np.concatenate(rad)),
                           point_irradiance=np.ascontiguousarray(np.concatenate(irr)),
                           cameras=data.cameras, up_axis=data.up_axis,
                           emitted_radiance=np.ascontiguousarray(np.concatenate(emitted)) if has_emission else None,
                           luminaires=_stored_luminaires(path, data), source=str(path))


def _stored_luminaires(path, data) -> list:
    """The luminaires a bake stored beside its layer (the layer names the file); none when
    the layer names none. A named file that is missing is an error: its light would be lost."""
    name = (getattr(data, "metadata", None) or {}).get("hirad:luminaires")
    if not name:
        return []
    from .usd import SceneError

    file = Path(path).parent / str(name)
    if not file.is_file():
        raise SceneError(f"{path}: names its luminaires file {name}, which is missing beside it (their light "
                         "would be lost)")
    try:
        return load_luminaires(file)
    except BakeError as e:
        raise SceneError(str(e)) from None
