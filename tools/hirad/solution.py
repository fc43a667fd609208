"""A baked solution as Python sees it: values at points, renders, the final gather; from a bake or from a stored solution.usda."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
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


@dataclass
class SurfaceSolution:
    """Radiance and irradiance over the solved surfaces, queryable at any point."""

    corners: np.ndarray          # (P,4,3) patch corners, metres
    nv: np.ndarray               # (P,) 3 or 4
    corner_radiance: np.ndarray  # (P,4,3) exitant radiance W/(m^2 sr)
    corner_irradiance: np.ndarray  # (P,4,3) W/m^2
    cameras: list = field(default_factory=list)
    up_axis: str = "Y"
    # (P,3) self-emitted radiance E/pi of each patch, W/(m^2 sr), 0 for non-emitters; None when
    # unknown (a solution layer written before hirad stored primvars:hirad:emission)
    emitted_radiance: np.ndarray | None = None
    # the luminaires (hirad._engine.Luminaire) whose exact direct light illuminance and the
    # volume probes add; stored beside the layer as luminaires.npz (save_luminaires)
    luminaires: list = field(default_factory=list)
    # glazing: per patch the normal transmittance of direct light (None: all opaque), so that
    # the luminaires' and the sun's and sky's direct light reaches grid points through windows
    transmittance: np.ndarray | None = None
    _field: object = None
    source: str | None = None  # the solution layer this was read from, for messages

    @property
    def field(self) -> "_engine.SurfaceField":
        if self._field is None:
            glass = {}
            if self.transmittance is not None and np.any(self.transmittance > 0):
                from .daylight.glazing import angular_table
                glass = {"transmittance": np.ascontiguousarray(self.transmittance, dtype=np.float64),
                         "glass_angular": np.ascontiguousarray(angular_table(), dtype=np.float64)}
            self._field = _engine.SurfaceField(self.corners, self.nv.astype(np.int32),
                                               self.corner_radiance, self.corner_irradiance, **glass)
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
        if emitted.shape != (len(self.corners), 3):
            raise ValueError(f"emitted_radiance has shape {emitted.shape}, expected ({len(self.corners)}, 3)")
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
        return images.default_view(self.corners.reshape(-1, 3), self.up_axis)


@dataclass
class Result(SurfaceSolution):
    """What `bake` returns: the solution in memory plus where its outputs were written."""

    output_dir: Path | None = None
    report: dict = field(default_factory=dict)
    patch_radiosity: np.ndarray | None = None   # (P,3) B, W/m^2
    patch_irradiance: np.ndarray | None = None  # (P,3) H, W/m^2
    patches: dict = field(default_factory=dict)
    _model: object = None   # the engine model, kept for the final gather
    hierarchical: bool = False

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
    corners, nv, rad, irr, emitted = [], [], [], [], []
    has_emission = all(m.face_emission is not None for m in data.meshes)
    for m in data.meshes:
        counts = np.asarray(m.face_vertex_counts)
        offsets = np.concatenate([[0], np.cumsum(counts)])
        idx = np.asarray(m.face_vertex_indices)
        for f, c in enumerate(counts):
            if c not in (3, 4):
                raise BakeError(f"{path}: {m.name}: face {f} has {c} corners; hirad writes triangles and quads")
            ids = idx[offsets[f]:offsets[f + 1]]
            ids4 = np.append(ids, ids[-1]) if c == 3 else ids
            corners.append(m.points[ids4])
            rad.append(m.vertex_radiance[ids4])
            irr.append(m.vertex_irradiance[ids4])
            nv.append(c)
            if has_emission:
                emitted.append(m.face_emission[f] / np.pi)
    if not corners:
        raise BakeError(f"{path}: the solution has no faces")
    return SurfaceSolution(np.ascontiguousarray(corners, dtype=np.float64), np.asarray(nv, dtype=np.int32),
                           np.ascontiguousarray(rad, dtype=np.float64), np.ascontiguousarray(irr, dtype=np.float64),
                           cameras=data.cameras, up_axis=data.up_axis,
                           emitted_radiance=np.ascontiguousarray(emitted, dtype=np.float64) if has_emission else None,
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
