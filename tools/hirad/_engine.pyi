"""
hirad's C++ engine: meshing, form factors, solvers, hierarchy, reconstruction, rendering, files
"""

from collections.abc import Sequence
from typing import Annotated, overload

import numpy
from numpy.typing import NDArray


def set_threads(threads: int) -> None:
    """Caps the engine's TBB threads (0 = all cores)."""

def parallel_rectangles_form_factor(a: float, b: float, c: float) -> float:
    """
    F between two directly opposed a x b rectangles at distance c (closed form).
    """

def perpendicular_rectangles_form_factor(l: float, h: float, w: float) -> float:
    """
    F from a w x l rectangle to an h x l one, perpendicular, sharing the edge of length l (closed form).
    """

def point_polygon_form_factor(x: Sequence[float], normal: Sequence[float], polygon: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> float:
    """
    Differential point-to-polygon form factor at x with normal (Lambert's formula); polygon (3 or 4, 3), only the part above the point's plane counts.
    """

def write_exr(path: str, rgb: Annotated[NDArray[numpy.float32], dict(order='C', device='cpu', writable=False)], metadata: Sequence[tuple[str, str]]) -> None:
    """
    Writes an (h, w, 3) float32 image as an RGB EXR with string metadata [(key, value)].
    """

def read_exr(path: str) -> NDArray[numpy.float32]:
    """An RGB EXR as (h, w, 3) float32."""

def write_vdb(path: str, grids: list, voxel_size: float, origin: Sequence[float], metadata: Sequence[tuple[str, str]]) -> None:
    """
    Writes Vec3f grids [(name, coords int32 (n, 3), values float32 (n, 3), [(key, value)])] to an OpenVDB file; voxel_size in m, origin (3) the world position of voxel (0, 0, 0).
    """

def read_vdb(path: str) -> dict:
    """
    An OpenVDB file written by write_vdb: {'metadata': {...}, 'grids': {name: {'coords', 'values', 'voxel_size', 'origin', 'metadata'}}}.
    """

class Luminaire:
    """
    A luminaire (luminaire.h): points over its luminous opening with weights, its frame and a candela table I(C, gamma), gamma 0 = local -Z, C0 = +X, C90 = +Y, bilinear between nodes.
    """

    def __init__(self, name: str, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], weights: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], frame: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], candela: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], colour: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> None:
        """
        points (k, 3) m in world space, weights (k) summing to 1, frame (3, 3) whose rows are the local X, Y, Z axes in world space, candela (nc, ng) at C_i = 360 i / nc degrees and gamma_j = 180 j / (ng - 1) degrees, colour (1, 3): channel c emits candela x colour[c]. Invalid data: ValueError.
        """

    @staticmethod
    def distant(name: str, directions: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], weights: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], illuminance: float, colour: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], tints: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, interleave: bool = False) -> Luminaire:
        """
        A distant light (luminaire.h): the sun or sky patches. directions (k, 3) towards the light (normalised), weights (k) summing to 1, illuminance E_perp per unit colour (lux or W/m^2) on a surface facing it, colour (1, 3); tints (k, 3), optional: per direction a colour factor (a sky of varying colour as one light). interleave: one part of a sky cut into many lights (daylight coefficients' patch groups): on elements, interleaved with the other such lights as one sky (luminaire.h). Invalid data: ValueError.
        """

    @property
    def name(self) -> str: ...

    @property
    def is_distant(self) -> bool:
        """True for a distant light (points are directions)."""

    @property
    def interleave(self) -> bool:
        """Distant: part of a sky interleaved over elements' points."""

    @property
    def illuminance(self) -> float:
        """Distant: E_perp per unit colour, lux (or W/m^2)."""

    @property
    def points(self) -> NDArray[numpy.float64]:
        """(k, 3) m."""

    @property
    def weights(self) -> NDArray[numpy.float64]:
        """(k) summing to 1."""

    @property
    def frame(self) -> NDArray[numpy.float64]:
        """(3, 3) rows: local X, Y, Z in world space."""

    @property
    def candela(self) -> NDArray[numpy.float64]:
        """(nc, ng) cd (or W/sr)."""

    @property
    def colour(self) -> NDArray[numpy.float64]:
        """(1, 3)."""

    @property
    def flux(self) -> NDArray[numpy.float64]:
        """
        (1, 3) the exact integral of the bilinear table times colour over the sphere, lm (or W).
        """

    @property
    def table_flux(self) -> float:
        """The table's exact flux per unit colour, lm (or W)."""

    def intensity(self, directions: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> NDArray[numpy.float64]:
        """
        Intensity (n, 3) toward world directions (n, 3), per channel, cd (or W/sr).
        """

    def irradiance(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> NDArray[numpy.float64]:
        """
        Unoccluded direct irradiance (n, 3) at points facing normals, lux (or W/m^2).
        """

class MeshOptions:
    """Flat meshing: every face is cut into patches no larger than these."""

    def __init__(self, max_patch_area: float = 0.01, max_edge_length: float = 0.1, max_patches: int = 50000000) -> None: ...

    @property
    def max_patch_area(self) -> float:
        """Largest patch area, m^2."""

    @max_patch_area.setter
    def max_patch_area(self, arg: float, /) -> None: ...

    @property
    def max_edge_length(self) -> float:
        """Longest patch edge, m."""

    @max_edge_length.setter
    def max_edge_length(self, arg: float, /) -> None: ...

    @property
    def max_patches(self) -> int:
        """
        The most patches meshing may make; more is refused (ValueError) before anything is built.
        """

    @max_patches.setter
    def max_patches(self, arg: int, /) -> None: ...

class FormFactorOptions:
    """Form factors of the flat method."""

    def __init__(self, method: str = 'raycast', samples: int = 16, hemicube_resolution: int = 128, hemicube_points: int = 4, seed: int = 1) -> None: ...

    @property
    def method(self) -> str:
        """
        'raycast' (stratified area sampling, Embree visibility) or 'hemicube' (rasterised hemicubes, rows made reciprocal: G_ij = (A_i F_ij + A_j F_ji) / 2).
        """

    @method.setter
    def method(self, arg: str, /) -> None: ...

    @property
    def samples(self) -> int:
        """
        Raycast: stratified points per patch (also the progressive solver's row samples).
        """

    @samples.setter
    def samples(self, arg: int, /) -> None: ...

    @property
    def hemicube_resolution(self) -> int:
        """Hemicube: pixels along the top face (even)."""

    @hemicube_resolution.setter
    def hemicube_resolution(self, arg: int, /) -> None: ...

    @property
    def hemicube_points(self) -> int:
        """Hemicube: hemicubes averaged per patch."""

    @hemicube_points.setter
    def hemicube_points(self, arg: int, /) -> None: ...

    @property
    def seed(self) -> int:
        """Equal seeds give equal bits, whatever the thread count."""

    @seed.setter
    def seed(self, arg: int, /) -> None: ...

class SolveOptions:
    """The solve of B = E + rho F B, or of a hierarchy's links."""

    def __init__(self, method: str = 'southwell', tolerance: float = 0.0001, max_iterations: int = 100000000, snapshot_every: int = 0) -> None: ...

    @property
    def method(self) -> str:
        """
        Flat: 'direct', 'jacobi', 'gauss_seidel', 'southwell', 'progressive'. Hierarchical in memory: 'jacobi', 'gauss_seidel', 'southwell' (push-pull). Out of core: ignored (streaming block Southwell).
        """

    @method.setter
    def method(self, arg: str, /) -> None: ...

    @property
    def tolerance(self) -> float:
        """Relative residual ||E - M B|| / ||E|| to stop at."""

    @tolerance.setter
    def tolerance(self, arg: float, /) -> None: ...

    @property
    def max_iterations(self) -> int:
        """Sweeps, or shots for shooting methods."""

    @max_iterations.setter
    def max_iterations(self, arg: int, /) -> None: ...

    @property
    def snapshot_every(self) -> int:
        """Progressive only: a snapshot every this many shots (0: none)."""

    @snapshot_every.setter
    def snapshot_every(self, arg: int, /) -> None: ...

class HierarchyOptions:
    """Hierarchical radiosity with clustering."""

    def __init__(self, epsilon: float = 1e-05, min_area: float = 0.001, samples: int = 16, seed: int = 1, max_rounds: int = 6, relative: float = 0.0, spread: float = 0.001, cluster_receivers: bool = False, closure_reflectance: float = 0.95) -> None: ...

    @property
    def epsilon(self) -> float:
        """
        A link may carry at most epsilon x the scene's emitted power (W) before it is split.
        """

    @epsilon.setter
    def epsilon(self, arg: float, /) -> None: ...

    @property
    def min_area(self) -> float:
        """Elements are not split below this area, m^2."""

    @min_area.setter
    def min_area(self, arg: float, /) -> None: ...

    @property
    def samples(self) -> int:
        """Point pairs per link estimate."""

    @samples.setter
    def samples(self, arg: int, /) -> None: ...

    @property
    def seed(self) -> int:
        """Random seed of the link estimates."""

    @seed.setter
    def seed(self, arg: int, /) -> None: ...

    @property
    def max_rounds(self) -> int:
        """Refine -> solve rounds at most (>= 1)."""

    @max_rounds.setter
    def max_rounds(self, arg: int, /) -> None: ...

    @property
    def relative(self) -> float:
        """
        After round 1, links are also split above this fraction of their receiver's light (0: off).
        """

    @relative.setter
    def relative(self, arg: float, /) -> None: ...

    @property
    def spread(self) -> float:
        """
        Close or partly visible links whose source's radiosity range could bias them by more than spread x epsilon's power are split at the source (0: off).
        """

    @spread.setter
    def spread(self, arg: float, /) -> None: ...

    @property
    def release_scene(self) -> bool:
        """
        Let the input faces go once the hierarchy holds its copy (a bake that will not mesh or solve again); what the patch arrays and light groups read of them is kept.
        """

    @release_scene.setter
    def release_scene(self, arg: bool, /) -> None: ...

    @property
    def closure_reflectance(self) -> float:
        """
        Leaves of at least this reflectance have their form factors (what they inherit from their ancestors' links) normalised to their closure, the share of their hemisphere that meets a surface (Hierarchy::closure); 1: none.
        """

    @closure_reflectance.setter
    def closure_reflectance(self, arg: float, /) -> None: ...

    @property
    def cluster_receivers(self) -> bool:
        """
        Clusters receive as well as send: faces of one orientation share a link's light as an element's children do; clusters of several orientations where every face sees the source from its front, by orientation (Hierarchy::reception); any cluster while the link carries little (its power bound, times the share its sharing may misplace, within kSlight of epsilon), then evenly if its faces face several ways. Links grow with the lighting, not with the faces; the face-by-face solvers (gauss_seidel, southwell) refuse such links.
        """

    @cluster_receivers.setter
    def cluster_receivers(self, arg: bool, /) -> None: ...

class OutOfCoreOptions:
    """The hierarchical method with links streamed through a link store."""

    def __init__(self, store: str = '', memory_budget: int = 0, group_faces: int = 1024, checkpoint_seconds: float = 0.0, resume: bool = False, reuse_links: bool = False) -> None: ...

    @property
    def store(self) -> str:
        """The link store's directory; empty: links in memory."""

    @store.setter
    def store(self, arg: str, /) -> None: ...

    @property
    def memory_budget(self) -> int:
        """
        Bytes for the solver state and decoded chunks; 0: unlimited. The result does not depend on it.
        """

    @memory_budget.setter
    def memory_budget(self, arg: int, /) -> None: ...

    @property
    def group_faces(self) -> int:
        """Input faces per source group (one chunk each)."""

    @group_faces.setter
    def group_faces(self, arg: int, /) -> None: ...

    @property
    def checkpoint_seconds(self) -> float:
        """Write the running solve's state this often (0: never)."""

    @checkpoint_seconds.setter
    def checkpoint_seconds(self, arg: float, /) -> None: ...

    @property
    def resume(self) -> bool:
        """Continue what a killed bake with the same inputs left."""

    @resume.setter
    def resume(self, arg: bool, /) -> None: ...

    @property
    def reuse_links(self) -> bool:
        """
        Solve on the store's final links (same geometry and settings, other materials).
        """

    @reuse_links.setter
    def reuse_links(self, arg: bool, /) -> None: ...

class GatherOptions:
    """The final gather at points after a hierarchical solve."""

    def __init__(self, rays: int = 4, cluster_samples: int = 8, seed: int = 1, directional: bool = False, importance: float = 0.0, second_bounce: float = 0.0) -> None: ...

    @property
    def rays(self) -> int:
        """
        Visibility rays per partly visible element source (an emitting one: always 16, traced whatever its estimate saw).
        """

    @rays.setter
    def rays(self, arg: int, /) -> None: ...

    @property
    def cluster_samples(self) -> int:
        """Faces drawn per cluster source."""

    @cluster_samples.setter
    def cluster_samples(self, arg: int, /) -> None: ...

    @property
    def seed(self) -> int:
        """Seeds each point's samples with its index."""

    @seed.setter
    def seed(self, arg: int, /) -> None: ...

    @property
    def directional(self) -> bool:
        """
        Also PointValues.l0 and l1, the moments of the arriving radiance (the irradiance is unchanged).
        """

    @directional.setter
    def directional(self, arg: bool, /) -> None: ...

    @property
    def importance(self) -> float:
        """
        0: every link of a point's chain at the point; else the weakest links, together at most this share of a leaf's light, at their mean over the receiver (not emitters, not close sources; gather.h).
        """

    @importance.setter
    def importance(self, arg: float, /) -> None: ...

    @property
    def second_bounce(self) -> float:
        """
        0: off; else leaf sources nearer than this times their diagonal have their radiosity gathered at kernel-drawn points (gather.h: contacts).
        """

    @second_bounce.setter
    def second_bounce(self, arg: float, /) -> None: ...

class ReferenceOptions:
    """The Monte Carlo path-traced reference."""

    def __init__(self, paths: int = 1024, min_bounces: int = 3, seed: int = 1) -> None: ...

    @property
    def paths(self) -> int:
        """Paths per point."""

    @paths.setter
    def paths(self, arg: int, /) -> None: ...

    @property
    def min_bounces(self) -> int:
        """Russian roulette starts after this many bounces."""

    @min_bounces.setter
    def min_bounces(self, arg: int, /) -> None: ...

    @property
    def seed(self) -> int:
        """Random seed."""

    @seed.setter
    def seed(self, arg: int, /) -> None: ...

class Stats:
    """Counts of the scene and of what has been built from it so far."""

    @property
    def input_faces(self) -> int:
        """Polygons given."""

    @property
    def faces(self) -> int:
        """Usable faces after triangulation and cleaning."""

    @property
    def degenerate_faces(self) -> int:
        """Dropped: zero area."""

    @property
    def nonfinite_faces(self) -> int:
        """Dropped: a NaN or infinite corner."""

    @property
    def self_intersecting_faces(self) -> int:
        """
        Dropped: polygons whose edges cross in their plane (bow ties, pentagrams).
        """

    @property
    def triangulated_faces(self) -> int:
        """Non-quads and non-planar or concave quads split."""

    @property
    def nonmanifold_edges(self) -> int:
        """Edges of more than two faces (kept, counted)."""

    @property
    def patches(self) -> int:
        """Current patches (flat patches, or published leaves)."""

    @property
    def links(self) -> int:
        """Flat links stored."""

    @property
    def link_bytes(self) -> int:
        """Their memory, bytes."""

    @property
    def rays(self) -> int:
        """Rays cast against the current patches."""

class LeafArrays:
    """A hierarchical solve's leaves, published or not; row k is leaf k."""

    @property
    def mesh(self) -> NDArray[numpy.int32]:
        """(n) input mesh index."""

    @property
    def area(self) -> NDArray[numpy.float64]:
        """(n) m^2."""

class PatchArrays:
    """The current patches as arrays; row k is patch k."""

    @property
    def count(self) -> int: ...

    @property
    def corners(self) -> NDArray[numpy.float64]:
        """(n, 4, 3) m; triangles repeat corner 2 as corner 3."""

    @property
    def uv(self) -> NDArray[numpy.float64]:
        """(n, 4, 2) texture coordinates."""

    @property
    def area(self) -> NDArray[numpy.float64]:
        """(n) m^2."""

    @property
    def normal(self) -> NDArray[numpy.float64]:
        """(n, 3) unit normals."""

    @property
    def centroid(self) -> NDArray[numpy.float64]:
        """(n, 3) m."""

    @property
    def reflectance(self) -> NDArray[numpy.float64]:
        """(n, 3)."""

    @property
    def emission(self) -> NDArray[numpy.float64]:
        """(n, 3) self-emitted exitance, W/m^2."""

    @property
    def direct(self) -> NDArray[numpy.float64]:
        """
        (n, 3) the luminaires' irradiance, mean over the patch, W/m^2 (the solvers' source term is emission + reflectance x direct).
        """

    @property
    def nv(self) -> NDArray[numpy.int32]:
        """(n) 3 or 4 corners."""

    @property
    def mesh(self) -> NDArray[numpy.int32]:
        """(n) input mesh index."""

    @property
    def face(self) -> NDArray[numpy.int32]:
        """(n) engine face (after triangulation)."""

    @property
    def source_face(self) -> NDArray[numpy.int32]:
        """(n) authored face within its mesh."""

    @property
    def transmittance(self) -> NDArray[numpy.float64]:
        """(n) glazing: the normal transmittance of direct light (0: opaque)."""

    def take(self) -> dict:
        """
        Every field as {name: array}, moved out (the struct is left with none): the patches held once, not twice (hirad.engine.patch_dict).
        """

class FlatSolveResult:
    """A flat solve."""

    @property
    def radiosity(self) -> NDArray[numpy.float64]:
        """(n, 3) B per patch, W/m^2."""

    @property
    def iterations(self) -> int:
        """Sweeps, or shots."""

    @property
    def residual(self) -> float:
        """Final relative residual."""

    @property
    def converged(self) -> bool: ...

    @property
    def residual_history(self) -> list[float]:
        """Residual after each iteration."""

    @property
    def rows_computed(self) -> int:
        """Progressive: coupling rows computed on the fly."""

class Transport:
    """The two terms of the flat energy balance, per patch."""

    @property
    def irradiance(self) -> NDArray[numpy.float64]:
        """(n, 3) H = F B, W/m^2."""

    @property
    def escaped(self) -> NDArray[numpy.float64]:
        """
        (n, 3) (A_i - sum_j G_ij) B_i, W: power that leaves and reaches no patch (signed).
        """

class SpillLog:
    """What a worker of a distributed refinement made of its source groups."""

    @property
    def begin(self) -> int: ...

    @property
    def end(self) -> int: ...

    @property
    def nodes(self) -> int:
        """Nodes of the hierarchy the worker started from."""

    @property
    def subdivisions(self) -> int:
        """Elements it subdivided."""

    @property
    def link_estimates(self) -> int: ...

    @property
    def splits(self) -> int: ...

    @property
    def rays(self) -> int: ...

    @property
    def held(self) -> int:
        """The most links it held at once."""

    @property
    def group_seconds(self) -> list[float]:
        """Per group: wall time of its refinement, s."""

    @property
    def group_links(self) -> list[int]:
        """Per group: links kept."""

class StreamingStats:
    """The last streaming (out-of-core) solve."""

    @property
    def rounds(self) -> int: ...

    @property
    def groups_shot(self) -> int: ...

    @property
    def links_shot(self) -> int: ...

    @property
    def chunk_reads(self) -> int:
        """Chunks read and decoded."""

    @property
    def chunk_hits(self) -> int:
        """Chunks shot from memory."""

    @property
    def resident_bytes_peak(self) -> int: ...

    @property
    def state_bytes(self) -> int: ...

    @property
    def largest_chunk_bytes(self) -> int: ...

    @property
    def chunks_in_flight(self) -> int: ...

    @property
    def minimum_budget(self) -> int:
        """The smallest memory budget taken, bytes."""

    @property
    def decoded_bytes(self) -> int: ...

    @property
    def checkpoints(self) -> int: ...

    @property
    def resumed(self) -> bool: ...

    @property
    def read_wait_seconds(self) -> float: ...

    @property
    def shoot_seconds(self) -> float: ...

    @property
    def checkpoint_write_seconds(self) -> float:
        """Time spent writing checkpoints, s."""

class GroupSolution:
    """One light group solved alone on the shared links, per patch or leaf."""

    @property
    def radiosity(self) -> NDArray[numpy.float64]:
        """(n, 3) B_g, W/m^2."""

    @property
    def irradiance(self) -> NDArray[numpy.float64]:
        """
        (n, 3) irradiance from the surfaces, W/m^2 (add `direct` for the total).
        """

    @property
    def direct(self) -> NDArray[numpy.float64]:
        """(n, 3) the group's luminaires' irradiance, W/m^2."""

    @property
    def iterations(self) -> int: ...

    @property
    def residual(self) -> float: ...

    @property
    def converged(self) -> bool: ...

    @property
    def seconds(self) -> float:
        """Wall time of its solve (with its direct light), s."""

class HierarchicalResult:
    """
    A hierarchical solve. Per-leaf arrays follow the leaves that use_leaves_as_patches() makes the engine's patches.
    """

    @property
    def radiosity(self) -> NDArray[numpy.float64]:
        """(leaves, 3) B, W/m^2."""

    @property
    def irradiance(self) -> NDArray[numpy.float64]:
        """(leaves, 3) H, W/m^2."""

    @property
    def escaped(self) -> NDArray[numpy.float64]:
        """(leaves, 3) B A (open - outgoing fraction), W, signed."""

    @property
    def open(self) -> NDArray[numpy.float64]:
        """
        (leaves,) the share of each leaf's area not inside other geometry; its B, H and direct light are that part's (power: times open x area).
        """

    @property
    def residual(self) -> float: ...

    @property
    def converged(self) -> bool: ...

    @property
    def iterations(self) -> int:
        """All rounds."""

    @property
    def residual_history(self) -> list[float]:
        """In memory: all rounds; out of core: the last solve."""

    @property
    def links(self) -> int:
        """Final links."""

    @property
    def groups(self) -> list[GroupSolution]:
        """One GroupSolution per light group (Engine.set_light_groups), per leaf."""

    @property
    def elements(self) -> int:
        """Leaves."""

    @property
    def nodes(self) -> int: ...

    @property
    def clusters(self) -> int: ...

    @property
    def links_on_clusters(self) -> int:
        """
        Final links that end on a cluster (hierarchy.cluster_receivers); -1 out of core (not counted).
        """

    @property
    def balance_splits(self) -> int:
        """Leaves split for the 2:1 balance of the display."""

    @property
    def limited_leaves(self) -> int:
        """
        Leaves whose gathered light the last solve scaled to rho F = 0.999 (their link estimates summed above the hemisphere with a reflectance near 1; hierarchical_solver.h gain limit).
        """

    @property
    def normalised_leaves(self) -> int:
        """
        Leaves of a reflectance near 1 whose inherited light the last solve scaled so that their form factors sum to their measured closure (hierarchy.h Hierarchy::closure).
        """

    @property
    def rounds(self) -> int:
        """The final round."""

    @property
    def settled(self) -> bool:
        """Refinement stopped splitting (else max_rounds ended it)."""

    @property
    def face_bytes(self) -> int:
        """Bytes of the hierarchy's input faces (FaceTable)."""

    @property
    def bvh_bytes(self) -> int:
        """Bytes Embree holds for its scene over the faces, after the build."""

    @property
    def bvh_peak_bytes(self) -> int:
        """The most bytes Embree held while building it."""

    @property
    def links_per_round(self) -> list[int]: ...

    @property
    def splits_per_round(self) -> list[int]:
        """
        In memory: each refinement after the first (a last 0 when settled); out of core: each pass that made a round, the first included.
        """

    @property
    def refine_seconds(self) -> list[float]: ...

    @property
    def solve_seconds(self) -> list[float]: ...

    @property
    def link_estimates(self) -> int:
        """Form factor estimates made by refinement."""

    @property
    def rays(self) -> int:
        """Rays cast over the hierarchy's faces."""

    @property
    def epsilon_watts(self) -> float:
        """The split threshold, W."""

    @property
    def out_of_core(self) -> bool: ...

    @property
    def reused_links(self) -> bool: ...

    @property
    def resumed_from_round(self) -> int:
        """0: started fresh."""

    @property
    def store_bytes(self) -> int:
        """Compressed link payload of the final round."""

    @property
    def transport_bytes(self) -> int: ...

    @property
    def peak_refine_links(self) -> int: ...

    @property
    def source_groups(self) -> int: ...

    @property
    def streaming(self) -> StreamingStats:
        """The last streaming solve (out of core)."""

    @property
    def glass_back_entered(self) -> NDArray[numpy.float64]:
        """
        (3,) the backs of glazed faces (unpublished): the direct light they reflect, rho D A, W.
        """

    @property
    def glass_back_absorbed(self) -> NDArray[numpy.float64]:
        """
        (3,) the backs of glazed faces: what they take of the interreflected light (absorbed or let through), (1 - rho) H A, W.
        """

    @property
    def glass_back_escaped(self) -> NDArray[numpy.float64]:
        """
        (3,) the backs of glazed faces: their light that reaches no surface, W, signed.
        """

    @property
    def merge_seconds(self) -> list[float]:
        """
        Distributed: per refinement done by workers, the driver's merge of their spills, s.
        """

    @property
    def link_receiver(self) -> NDArray[numpy.int32]: ...

    @property
    def link_source(self) -> NDArray[numpy.int32]: ...

    @property
    def link_coupling(self) -> NDArray[numpy.float64]:
        """G, m^2."""

    @property
    def link_unoccluded(self) -> NDArray[numpy.float64]:
        """G without visibility, m^2."""

    @property
    def node_parent(self) -> NDArray[numpy.int32]:
        """-1 at the root."""

    @property
    def node_area(self) -> NDArray[numpy.float64]: ...

    @property
    def node_cluster(self) -> NDArray[numpy.uint8]: ...

    @property
    def leaf_node(self) -> NDArray[numpy.int32]: ...

class PointValues:
    """Values at query points on the surfaces."""

    @property
    def patch(self) -> NDArray[numpy.int32]:
        """(n) the patch of each point (-1: none within reach)."""

    @property
    def irradiance(self) -> NDArray[numpy.float64]:
        """(n, 3) W/m^2."""

    @property
    def radiance(self) -> NDArray[numpy.float64]:
        """(n, 3) exitant, W/(m^2 sr)."""

    @property
    def l0(self) -> NDArray[numpy.float64]:
        """
        (n, 3) with GatherOptions(directional=True), else (0, 3): integral of the arriving radiance over the hemisphere, W/m^2 per channel.
        """

    @property
    def l1(self) -> NDArray[numpy.float64]:
        """
        (n, 3, 3) [q, channel, axis] with GatherOptions(directional=True), else (0, 3, 3): integral of the arriving radiance times the unit direction w (world axes), W/m^2; normal . l1 = irradiance (a little above it where a partly visible source straddles the point's horizon: gather.h).
        """

class ReferenceResult:
    """The Monte Carlo reference at points."""

    @property
    def radiance(self) -> NDArray[numpy.float64]:
        """(n, 3) exitant, W/(m^2 sr)."""

    @property
    def standard_error(self) -> NDArray[numpy.float64]:
        """(n, 3) of radiance."""

class Engine:
    """
    One scene through the pipeline: scene -> patches -> links -> solution (flat or hierarchical).
    """

    def __init__(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], face_vertex_counts: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], face_vertex_indices: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], face_mesh: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], face_source: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], reflectance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], emission: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], corner_uv: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, transmittance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, glass_angular: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None) -> None:
        """
        The scene as flat arrays in metres: points (P, 3), counts (F), indices (sum of counts), per face mesh, authored face, reflectance (F, 3), emission (F, 3) W/m^2, optional corner_uv (sum of counts, 2); glazing: optional transmittance (F) of direct light at normal incidence (0 opaque, reflectance + transmittance <= 1) and glass_angular, the relative transmittance at evenly spaced cosines 0 .. 1 (visibility.h).
        """

    def stats(self) -> Stats:
        """Counts of the scene and of what is built (Stats)."""

    def set_luminaires(self, luminaires: Sequence[Luminaire]) -> None:
        """
        Luminaires (list of Luminaire) whose light reaches the surfaces as an exact first bounce (their direct irradiance, re-emitted as rho x direct); replaces earlier ones; lights the flat patches now, a hierarchical solve from its start.
        """

    @property
    def luminaire_flux(self) -> NDArray[numpy.float64]:
        """(1, 3) the luminaires' total exact flux, lm (or W)."""

    def set_light_groups(self, meshes: Sequence[Sequence[int]], luminaires: Sequence[Sequence[Luminaire]]) -> None:
        """
        Light groups (per group: the input meshes whose faces' emission it holds, and its luminaires); replaces earlier ones. Each group is then solved alone on the shared links: solve_groups (flat), HierarchicalResult.groups (hierarchical, in memory and out of core).
        """

    @property
    def num_light_groups(self) -> int: ...

    def solve_groups(self, options: SolveOptions, form_factors: FormFactorOptions = ...) -> list[GroupSolution]:
        """
        Flat: each light group solved alone on the links (list of GroupSolution, per patch).
        """

    def mesh(self, options: MeshOptions) -> None:
        """Flat meshing: cuts every face into patches (MeshOptions)."""

    @property
    def num_patches(self) -> int: ...

    def patch_arrays(self) -> PatchArrays:
        """The current patches (PatchArrays)."""

    def compute_links(self, options: FormFactorOptions, progress: object | None = None) -> None:
        """
        Flat links between every pair of patches that exchange light; progress(rows_done).
        """

    def solve(self, options: SolveOptions, form_factors: FormFactorOptions = ..., snapshot: object | None = None, progress: object | None = None) -> FlatSolveResult:
        """
        Flat solve (FlatSolveResult); progressive solves sample rows with form_factors' samples and seed and call snapshot(shot, displayed radiosity (n, 3)); progress(iteration, residual).
        """

    def transport(self, radiosity: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], form_factors: FormFactorOptions = ...) -> Transport:
        """
        Irradiance H = F B and escaped power per patch (Transport); without links the couplings are sampled.
        """

    def residual_of(self, radiosity: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> float:
        """Relative residual ||E - M B|| / ||E|| of B over the flat links."""

    def form_factor(self, i: int, j: int, samples: int, seed: int) -> float:
        """Ray-cast F_ij."""

    def hemicube_row(self, i: int, resolution: int, points: int) -> NDArray[numpy.float64]:
        """Dense hemicube row F_i (n)."""

    def rays_cast(self) -> int: ...

    def solve_hierarchical(self, hierarchy: HierarchyOptions, solve: SolveOptions = ..., progress: object | None = None) -> HierarchicalResult:
        """
        Refine -> solve rounds in memory (HierarchicalResult); progress(round, links, iteration, residual, groups_linked, groups) (groups 0). The patches stay as they were until use_leaves_as_patches().
        """

    def solve_out_of_core(self, hierarchy: HierarchyOptions, solve: SolveOptions = ..., out_of_core: OutOfCoreOptions = ..., progress: object | None = None, refine_groups: object | None = None) -> HierarchicalResult:
        """
        Refine -> solve rounds streamed through a link store, each solved by streaming block Southwell (HierarchicalResult); resumable. The patches stay as they were until use_leaves_as_patches(). progress(round, links, iteration, residual, groups_linked, groups): while a round is linked, the source groups done and in all and the links kept so far; groups 0 while solving. refine_groups(round, groups): distributed link generation; called (with the GIL) for every refinement, it has workers run refine_groups on ranges covering [0, groups) and returns when all are complete; the result is the same bits as without.
        """

    def refine_groups(self, hierarchy: HierarchyOptions, out_of_core: OutOfCoreOptions, round: int, begin: int, end: int) -> SpillLog:
        """
        A worker's share of a distributed out-of-core bake: round `round`'s refinement of source groups [begin, end) from the link store's state, written to its spill directory (SpillLog). The scene, luminaires and options must be the driver's.
        """

    def use_leaves_as_patches(self, release_hierarchy: bool = False) -> None:
        """
        Makes the last hierarchical solve's leaves the patches, in the order of its per-leaf arrays (engine.h).
        """

    @property
    def leaves_are_patches(self) -> bool: ...

    def leaf_arrays(self) -> LeafArrays:
        """The last hierarchical solve's leaves' meshes and areas (LeafArrays)."""

    def release_hierarchy(self) -> None:
        """Lets go of the solved hierarchy (engine.h)."""

    @property
    def has_hierarchy(self) -> bool: ...

    def release_scene(self) -> None:
        """Lets go of the input faces (engine.h)."""

    def release_patches(self) -> None:
        """Lets go of the patches, their BVH, the display mesh."""

    def display_mesh(self, crease_angle: float) -> DisplayMesh:
        """
        Welded display mesh of the patches (DisplayMesh), kept for vertex_values.
        """

    def vertex_values(self, patch_values: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> NDArray[numpy.float64]:
        """
        Per-patch values (n, 3) reconstructed at the display mesh's points (points, 3).
        """

    def gather(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], options: GatherOptions = ..., max_distance: float = 1e+30, group: int = -1) -> PointValues:
        """
        Final gather after a hierarchical solve (PointValues); needs use_leaves_as_patches(). group >= 0: that light group's solution alone.
        """

    def lift_samples(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], epsilon: float, reach: float, anchors: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None) -> LiftResult:
        """
        SurfaceField.lift_samples against the current patches and their BVH (LiftResult).
        """

    def ray_cast(self, origins: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], directions: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> RayCastResult:
        """First hits of rays (RayCastResult)."""

    def direct_transmittance(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], directions: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> NDArray[numpy.float32]:
        """
        (P, D) float32: max(0, n . d) x the transmittance of the ray from each point towards each unit direction out of the scene (0 blocked; glass factors), over the current patches.
        """

    def gather_flat(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], radiosity: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], rays: int = 4, seed: int = 1) -> PointValues:
        """
        Final gather from a flat solution B (PointValues): every patch, O(patches) a point.
        """

    def reference(self, patch: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], st: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], options: ReferenceOptions = ...) -> ReferenceResult:
        """
        Monte Carlo exitant radiance at (s, t) of the given patches (ReferenceResult).
        """

    def reference_at(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], options: ReferenceOptions = ..., max_distance: float = 1e+30) -> ReferenceResult:
        """
        The reference at surface points, each on the closest patch facing along its normal within max_distance (ValueError otherwise).
        """

    def display_arrays(self, crease_angle: float) -> dict:
        """
        The display mesh display_mesh makes and keeps, as a dict of its DisplayMesh arrays.
        """

class DisplayMesh:
    """Welded display mesh of the patches (reconstruct.h)."""

    @property
    def points(self) -> NDArray[numpy.float64]:
        """(points, 3) m."""

    @property
    def point_mesh(self) -> NDArray[numpy.int32]:
        """(points) input mesh of each point."""

    @property
    def corners(self) -> NDArray[numpy.int32]:
        """(patches, 4) each patch's corner points."""

    @property
    def boundary(self) -> NDArray[numpy.uint8]:
        """(points) 1 on a boundary."""

    @property
    def faces(self) -> NDArray[numpy.int32]:
        """(faces, 4) display faces' points."""

    @property
    def face_nv(self) -> NDArray[numpy.uint8]:
        """(faces) 3 or 4."""

    @property
    def face_patch(self) -> NDArray[numpy.int32]:
        """(faces) the patch each face belongs to."""

    @property
    def face_code(self) -> NDArray[numpy.uint8]:
        """(faces, 4) corner codes (reconstruct.h)."""

    @property
    def anchored(self) -> NDArray[numpy.uint8]:
        """
        (points) 1 for T-vertices and fan centres (weighted sums of other points).
        """

class ProbeResult:
    """The closest surface point to each query point."""

    @property
    def patch(self) -> NDArray[numpy.int32]:
        """(n) patch (-1: none within max_distance)."""

    @property
    def distance(self) -> NDArray[numpy.float64]:
        """(n) m (-1: none)."""

    @property
    def irradiance(self) -> NDArray[numpy.float64]:
        """(n, 3) W/m^2."""

    @property
    def radiance(self) -> NDArray[numpy.float64]:
        """(n, 3) W/(m^2 sr)."""

class RayCastResult:
    """First hits of rays."""

    @property
    def patch(self) -> NDArray[numpy.int32]:
        """(n) patch hit (-1: escaped)."""

    @property
    def t(self) -> NDArray[numpy.float64]:
        """(n) distance along the normalised direction (-1: none)."""

    @property
    def points(self) -> NDArray[numpy.float64]:
        """(n, 3) hit points."""

    @property
    def normals(self) -> NDArray[numpy.float64]:
        """(n, 3) the hit patch's normal."""

    @property
    def back(self) -> NDArray[numpy.uint8]:
        """(n) 1 where a back face was hit."""

    @property
    def u(self) -> NDArray[numpy.float64]:
        """(n) the hit's first coordinate on its patch."""

    @property
    def v(self) -> NDArray[numpy.float64]:
        """(n) the hit's second coordinate on its patch."""

class LiftResult:
    """Lightmap sample points lifted off their surface."""

    @property
    def points(self) -> NDArray[numpy.float64]:
        """(n, 3) m."""

    @property
    def moved(self) -> NDArray[numpy.uint8]:
        """(n) 1 where a point was moved out of geometry."""

class VolumeProbes:
    """Full-sphere radiance moments at points in empty space."""

    @property
    def s0(self) -> NDArray[numpy.float64]:
        """(n, 3) integral of L over the sphere."""

    @property
    def s1(self) -> NDArray[numpy.float64]:
        """(n, 3, 3) [q, a, c]: integral of L w_a in channel c."""

    @property
    def sh2(self) -> NDArray[numpy.float64]:
        """
        (n, 9, 3) [q, k, c]: integral of L Y_k in channel c, Y_k the real orthonormal L2 spherical harmonics (Ramamoorthi & Hanrahan 2001 order and signs: 1, y, z, x, xy, yz, 3z^2-1, xz, x^2-y^2 times 0.282095, 0.488603 (x3), 1.092548, 1.092548, 0.315392, 1.092548, 0.546274), world axes.
        """

    @property
    def back_fraction(self) -> NDArray[numpy.float64]:
        """(n) rays that hit a back face."""

    @property
    def hit_fraction(self) -> NDArray[numpy.float64]:
        """(n) rays that hit anything."""

    @property
    def nearest(self) -> NDArray[numpy.float64]:
        """(n) closest hit, m (-1: none)."""

class Illuminance:
    """Illuminance at sensors, W/m^2 per RGB channel (lux when photometric)."""

    @property
    def direct(self) -> NDArray[numpy.float64]:
        """
        (n, 3) from the emitter patches (exact contour integrals, shadowed per piece) and the luminaires (exact, one shadow ray per luminaire point).
        """

    @property
    def indirect(self) -> NDArray[numpy.float64]:
        """
        (n, 3) gathered by hemisphere rays from every surface's exitant radiance less its emission.
        """

class SurfaceField:
    """
    A solved surface as one Embree scene, built once: render, probe, lift_samples, volume_probes and ray_cast query it.
    """

    @overload
    def __init__(self, corners: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], nv: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], corner_radiance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, corner_irradiance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, transmittance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, glass_angular: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None) -> None:
        """
        Patches (n, 4, 3) with nv (n) of 3 or 4; radiance W/(m^2 sr) and irradiance W/m^2 per corner (n, 4, 3), optional (zero without); glazing: transmittance (n) per patch and glass_angular (visibility.h), so that the luminaires' and distant lights' direct light passes windows.
        """

    @overload
    def __init__(self, *, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], faces: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], nv: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], point_radiance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, point_irradiance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, transmittance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None, glass_angular: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None) -> None:
        """
        The same from an indexed mesh (ray_scene.h): points (m, 3), faces (n, 4) of point indices with nv (n), radiance and irradiance per point (m, 3); the same patches and values, to the bit, as from points[faces] and the values at points[faces].
        """

    def __len__(self) -> int: ...

    def hemisphere_hits(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], rays: int, seed: int = 1) -> tuple:
        """
        The rays of illuminance's indirect part (the same for the same rays and seed), traced once: (sensor, patch, u, v, weight, rays): per entry a front-facing surface a ray of that sensor reads (through clear glass: the panes met from the front and the surface past them; weight the glass passed before it, 1 without), sensor by sensor; rays = k*k a sensor. The indirect illuminance of corner radiance L is pi / rays x the sum of weight x L interpolated at a sensor's entries.
        """

    def direct_transmittance(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], directions: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> NDArray[numpy.float32]:
        """
        (sensors, D) float32: max(0, n . d) x the transmittance of the ray from each sensor towards each direction out of the scene (0 blocked; glass factors), as illuminance's luminaires see it.
        """

    def set_luminaires(self, luminaires: Sequence[Luminaire]) -> None:
        """
        Luminaires (list of Luminaire) that illuminance (in `direct`) and volume_probes add, exactly at their points; render does not show them.
        """

    def render(self, position: Sequence[float], forward: Sequence[float], up: Sequence[float], vertical_fov: float, width: int, height: int, samples: int) -> NDArray[numpy.float32]:
        """
        Pinhole render of exitant radiance (height, width, 3) float32; vertical_fov in degrees.
        """

    def probe(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], max_distance: float = 1e+30) -> ProbeResult:
        """
        Closest surface point within max_distance, facing along the normal when it is non-zero (ProbeResult).
        """

    def lift_samples(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], epsilon: float, reach: float, anchors: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)] | None = None) -> LiftResult:
        """
        Lightmap sample points lifted epsilon (m) along their normals and moved out of geometry within reach (m) (LiftResult).
        """

    def volume_probes(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], rays: int = 256, seed: int = 1) -> VolumeProbes:
        """Full-sphere radiance moments at points in empty space (VolumeProbes)."""

    def illuminance(self, points: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], normals: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], emitted_radiance: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], rays: int = 512, seed: int = 1, emitter_samples: int = 4) -> Illuminance:
        """
        Illuminance on small planes at points (n, 3) facing unit normals (n, 3), anywhere: the direct light of the patches whose emitted_radiance (patches, 3) W/(m^2 sr) is positive, exact where unoccluded, plus the indirect light of the rest by `rays` cosine-distributed hemisphere rays (Illuminance).
        """

    def ray_cast(self, origins: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], directions: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> RayCastResult:
        """First hits of rays (RayCastResult)."""

    def camera_rays(self, position: Sequence[float], forward: Sequence[float], up: Sequence[float], vertical_fov: float, width: int, height: int) -> RayCastResult:
        """
        First hits of one ray through each pixel centre of the pinhole camera render uses, row 0 at the top (RayCastResult, height * width rows).
        """

def interpolate_corners(nv: Annotated[NDArray[numpy.int32], dict(order='C', device='cpu', writable=False)], values: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], u: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)], v: Annotated[NDArray[numpy.float64], dict(order='C', device='cpu', writable=False)]) -> NDArray[numpy.float64]:
    """
    Values (n, 4, 3) at patch corners read at patch coordinates (u, v) by the render's rule: bilinear on quads, barycentric on triangles (nv 3 or 4 per row).
    """
