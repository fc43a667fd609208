"""The one place Python builds the engine's scene, and turns the engine's result structs into the
plain data the outputs and the report take.

`build_engine(scene)` makes a ``hirad._engine.Engine`` from :class:`hirad.usd.SceneArrays` (or
anything with the same arrays: points, face_vertex_counts, face_vertex_indices, face_mesh,
face_source, face_reflectance, face_emission, corner_uv, and optionally face_transmittance for
glazing); the bake, the reference, the
estimate and the tests all use it. The engine's API (option structs, result structs, every
signature) is in ``hirad/_engine.pyi``, generated from the bindings.
"""

from __future__ import annotations

import numpy as np

from . import _engine

# (the patches' corner UVs are not among them: nothing reads them after the mesh, 64 bytes a
# patch, 68 MB on the 1M-triangle kitchen)
PATCH_FIELDS = ("corners", "area", "normal", "centroid", "reflectance", "emission", "direct", "nv", "mesh", "face",
                "source_face", "transmittance")
DISPLAY_FIELDS = ("points", "point_mesh", "corners", "boundary", "faces", "face_nv", "face_patch", "face_code",
                  "anchored")
STREAMING_FIELDS = ("rounds", "groups_shot", "links_shot", "chunk_reads", "chunk_hits", "resident_bytes_peak",
                    "state_bytes", "largest_chunk_bytes", "chunks_in_flight", "minimum_budget", "decoded_bytes",
                    "checkpoints", "resumed", "read_wait_seconds", "shoot_seconds",
                    "checkpoint_write_seconds")


def build_engine(scene, *, face_source=None, with_uv: bool = True) -> "_engine.Engine":
    """The engine's scene from the USD arrays (metres, W/m^2). `face_source` overrides the
    authored face index per face (default: the scene's own); `with_uv=False` leaves the
    texture coordinates out (patches then carry none)."""
    def f64(a):
        return np.ascontiguousarray(a, dtype=np.float64)

    def i32(a):
        return np.ascontiguousarray(a, dtype=np.int32)

    source = scene.face_source if face_source is None else face_source
    uv = getattr(scene, "corner_uv", None) if with_uv else None
    # Glazing (hirad.daylight.glazing): faces that let direct light through, with clear glass's
    # relative angular transmittance.
    tau = getattr(scene, "face_transmittance", None)
    glazed = tau is not None and bool(np.any(np.asarray(tau) > 0))
    angular = None
    if glazed:
        from .daylight.glazing import angular_table
        angular = f64(angular_table())
    return _engine.Engine(f64(scene.points), i32(scene.face_vertex_counts), i32(scene.face_vertex_indices),
                          i32(scene.face_mesh), i32(source), f64(scene.face_reflectance), f64(scene.face_emission),
                          None if uv is None else f64(uv), transmittance=f64(tau) if glazed else None,
                          glass_angular=angular)


def patch_dict(arrays: "_engine.PatchArrays") -> dict:
    """The patches as {name: array}, moved out of `arrays` (which is left empty): a million
    patches' 330 MB are held once, not copied."""
    taken = arrays.take()
    return {k: taken[k] for k in PATCH_FIELDS}


class PatchTable(dict):
    """The patches' arrays (patch_dict) held without their corners, a third of their bytes (96
    of about 290 a patch: 57 MiB on one floor of the bench building, 623k leaves). Reading
    `table["corners"]` makes them from the display mesh's points and each patch's corner points
    (DisplayMesh.corners): the same bits, the display mesh's points being the patches' welded
    corners; triangles repeat their third corner as their fourth, as patch_dict's do."""

    def __init__(self, arrays: dict, points: np.ndarray, corner_points: np.ndarray):
        super().__init__((k, v) for k, v in arrays.items() if k != "corners")
        self._points, self._corner_points = points, corner_points

    def _corners(self) -> np.ndarray:
        idx = np.array(self._corner_points, dtype=np.int64)
        idx[:, 3] = np.where(np.asarray(self["nv"]) == 3, idx[:, 2], idx[:, 3])
        return np.asarray(self._points, dtype=np.float64)[idx]

    def __missing__(self, key):
        if key == "corners":
            return self._corners()
        raise KeyError(key)

    def __contains__(self, key) -> bool:
        return key == "corners" or super().__contains__(key)

    def get(self, key, default=None):
        return self[key] if key in self else default


def display_dict(mesh: "_engine.DisplayMesh | dict") -> dict:
    """The display mesh as {name: array}, from a DisplayMesh or Engine.display_arrays' dict."""
    if isinstance(mesh, dict):
        return {k: mesh[k] for k in DISPLAY_FIELDS}
    return {k: getattr(mesh, k) for k in DISPLAY_FIELDS}


def streaming_dict(stats: "_engine.StreamingStats") -> dict:
    """The last streaming solve's counters, for report.json."""
    return {k: getattr(stats, k) for k in STREAMING_FIELDS}
