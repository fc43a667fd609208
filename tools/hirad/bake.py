"""The bake: scene -> patches -> links -> solution -> outputs, and stored solutions.

Units: emission and radiosity B are exitance in W/m^2; irradiance H is W/m^2; exitant
radiance is B/pi and incident radiance H/pi, in W/(m^2 sr). USD light intensities and
emissiveColor are read as radiance in W/(m^2 sr).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from . import __version__, _engine, images, usd
from .config import Config, load_config


class BakeError(Exception):
    """A bake that cannot go on: the message names what and where."""


# --------------------------------------------------------------------------------------
# progress reporting
# --------------------------------------------------------------------------------------


class Reporter:
    """Stage timings, plus rich progress bars unless quiet."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.timings: dict[str, float] = {}
        self.warnings: list[str] = []
        self._progress = None
        if not quiet:
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(TextColumn("{task.description:<22}"), BarColumn(),
                                      TextColumn("{task.fields[detail]}"), TimeElapsedColumn(),
                                      console=Console(stderr=True), transient=False)

    def __enter__(self):
        if self._progress:
            self._progress.start()
        return self

    def __exit__(self, *exc):
        if self._progress:
            self._progress.stop()

    @contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[Callable[..., None]]:
        """Times a stage; yields update(completed, detail='') for its progress bar."""
        task = self._progress.add_task(name, total=total, detail="") if self._progress else None
        start = time.perf_counter()

        def update(completed: float | None = None, detail: str = "") -> None:
            if task is not None:
                self._progress.update(task, completed=completed, detail=detail)

        try:
            yield update
        finally:
            self.timings[name] = round(time.perf_counter() - start, 4)
            if task is not None:
                self._progress.update(task, total=total or 1, completed=total or 1)

    def warn(self, message: str) -> None:
        self.warnings.append(message)
        if not self.quiet:
            import sys

            print(f"hirad: warning: {message}", file=sys.stderr)


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
    _field: object = None

    @property
    def field(self) -> "_engine.SurfaceField":
        if self._field is None:
            self._field = _engine.SurfaceField(self.corners, self.nv.astype(np.int32),
                                               self.corner_radiance, self.corner_irradiance)
        return self._field

    def query(self, points, normals=None, max_distance: float = 1e30) -> dict:
        """Closest-surface lookup: dict of patch (-1 if none), distance, irradiance, radiance."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        nrm = np.zeros_like(pts) if normals is None else np.ascontiguousarray(
            np.asarray(normals, dtype=np.float64).reshape(-1, 3))
        return self.field.probe(pts, nrm, float(max_distance))

    def irradiance_at(self, points, normals=None) -> np.ndarray:
        """Irradiance (W/m^2, RGB) at the surface points nearest to `points` (facing along
        `normals` when given)."""
        return self.query(points, normals)["irradiance"]

    def radiance_at(self, points, normals=None) -> np.ndarray:
        """Exitant radiance (W/(m^2 sr), RGB) at the surface points nearest to `points`."""
        return self.query(points, normals)["radiance"]

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
               seed: int = 1) -> dict:
        """Final gather at surface points: hierarchical bakes re-evaluate every link that
        reaches a point's element at the point itself (exact point-to-polygon form factors,
        Embree visibility); flat bakes gather from every patch, O(patches) a point. Returns
        dict of patch (-1 if no surface faces along the normal), irradiance (W/m^2) and
        radiance (W/(m^2 sr))."""
        if self._model is None:
            raise BakeError("gather needs the bake's engine model (a Result of hirad.bake)")
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
        if self.hierarchical:
            return self._model.gather(pts, nrm, rays, cluster_samples, seed)
        return self._model.gather_flat(pts, nrm, np.ascontiguousarray(self.patch_radiosity), rays, seed)


def load_solution(path: str | os.PathLike) -> SurfaceSolution:
    """Opens a solution layer written by a bake, for rendering or probing without solving."""
    data = usd.read_solution_layer(path)
    corners, nv, rad, irr = [], [], [], []
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
    if not corners:
        raise BakeError(f"{path}: the solution has no faces")
    return SurfaceSolution(np.ascontiguousarray(corners, dtype=np.float64), np.asarray(nv, dtype=np.int32),
                           np.ascontiguousarray(rad, dtype=np.float64), np.ascontiguousarray(irr, dtype=np.float64),
                           cameras=data.cameras, up_axis=data.up_axis)


# --------------------------------------------------------------------------------------
# the bake
# --------------------------------------------------------------------------------------


def bake(config: Config | str | os.PathLike, *, quiet: bool = True, threads: int | None = None,
         snapshots: int | None = None, resume: bool = False, reuse_links: bool = False) -> Result:
    """Runs the whole pipeline for a config (a Config or a YAML path) and writes its outputs.

    Outputs are assembled in a hidden sibling directory and moved into place at the end, so
    an interrupted or failed bake never leaves a directory that looks complete. Out of core
    (solver.method: block_southwell), `resume` continues what a killed bake with the same
    inputs left in the link store, and `reuse_links` solves on the stored links of the same
    geometry and refinement settings (new materials) without computing any form factor.
    """
    source = None if isinstance(config, Config) else Path(config).absolute()
    cfg = config if isinstance(config, Config) else load_config(config)
    if threads is not None:
        cfg.threads = threads
    if snapshots is not None:
        if snapshots > 0 and cfg.solver.method != "progressive":
            raise BakeError("--snapshots needs solver.method: progressive")
        cfg.solver.snapshots = snapshots
    _engine.set_threads(cfg.threads)
    out_dir = Path(cfg.output)
    staging = out_dir.parent / f".{out_dir.name}.partial-{os.getpid()}"
    if staging.exists():
        shutil.rmtree(staging)
    staging.mkdir(parents=True)
    try:
        with Reporter(quiet) as rep:
            result = _run(cfg, staging, rep, source, resume, reuse_links)
        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    result.output_dir = out_dir
    return result


def _run(cfg: Config, staging: Path, rep: Reporter, source: Path | None = None, resume: bool = False,
         reuse_links: bool = False) -> Result:
    wall = time.perf_counter()
    with rep.stage("read scene"):
        scene = usd.read_scene(cfg.scene, default_reflectance=tuple(cfg.materials.default_reflectance),
                               uv_primvars=tuple(cfg.materials.uv_primvars))
    for w in scene.warnings:
        rep.warn(w)

    with rep.stage("build scene"):
        model = _engine.Model(
            np.ascontiguousarray(scene.points, dtype=np.float64),
            np.ascontiguousarray(scene.face_vertex_counts, dtype=np.int32),
            np.ascontiguousarray(scene.face_vertex_indices, dtype=np.int32),
            np.ascontiguousarray(scene.face_mesh, dtype=np.int32),
            np.ascontiguousarray(scene.face_source, dtype=np.int32),
            np.ascontiguousarray(scene.face_reflectance, dtype=np.float64),
            np.ascontiguousarray(scene.face_emission, dtype=np.float64),
            None if scene.corner_uv is None else np.ascontiguousarray(scene.corner_uv, dtype=np.float64))
        stats = model.stats()
    skipped = {k: stats[k] for k in ("degenerate_faces", "nonfinite_faces", "nonmanifold_edges") if stats[k]}
    if skipped:
        rep.warn(f"{cfg.scene}: " + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in skipped.items())
                 + " (degenerate and non-finite faces skipped; non-manifold edges kept)")
    if stats["faces"] == 0:
        raise BakeError(f"{cfg.scene}: no usable faces (all {stats['input_faces']} were degenerate or not finite)")

    if not np.any(scene.face_emission > 0):
        rep.warn(f"{cfg.scene}: nothing emits light (no emissiveColor, MeshLightAPI or UsdLux area "
                 "light): every radiosity will be zero")

    if cfg.method == "hierarchical":
        solved, patches = _solve_hierarchical(cfg, model, rep, resume, reuse_links)
        b, h, escaped = solved["radiosity"], solved["irradiance"], solved["escaped"]
    else:
        solved, patches, b, h, escaped = _solve_flat(cfg, model, scene, staging, rep)
    n = model.num_patches
    method = cfg.solver.method
    ff = cfg.formfactors
    snapshot_cb = solved.pop("snapshots_written", None)
    if not solved["converged"]:
        rep.warn(f"solver stopped after {solved['iterations']} iterations at residual "
                 f"{solved['residual']:.3e}, above the tolerance {cfg.solver.tolerance:g}")
    balance = _energy_balance(patches, b, h, escaped)

    with rep.stage("reconstruct"):
        display = model.display_mesh(cfg.reconstruction.crease_angle)
        vertex_radiance = model.vertex_values(b) / np.pi
        vertex_irradiance = model.vertex_values(h)
    faces = display["faces"]
    result = Result(np.ascontiguousarray(display["points"][faces]), display["face_nv"].astype(np.int32),
                    vertex_radiance[faces], vertex_irradiance[faces],
                    cameras=scene.cameras, up_axis=scene.up_axis, patch_radiosity=b, patch_irradiance=h,
                    patches=patches, _model=model, hierarchical=cfg.method == "hierarchical")

    outputs: dict[str, object] = {}
    meshes, mesh_faces = _patch_meshes(scene, patches, display, vertex_radiance, vertex_irradiance, b, h)
    if cfg.outputs.lightmaps.enabled:
        with rep.stage("lightmaps"):
            outputs["lightmaps"], outputs["lightmap_atlas"] = _write_lightmaps(
                cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces, staging, result, rep.warn)
    if cfg.outputs.volume.enabled:
        with rep.stage("irradiance volume"):
            outputs["volume"] = _write_volume(cfg, result, scene, staging)
    if cfg.outputs.usd:
        with rep.stage("write USD"):
            path = staging / "solution.usda"
            usd.write_solution_layer(cfg.scene, path, scene, meshes, {
                "hirad:version": __version__, "hirad:config": cfg.fingerprint(),
                "hirad:units": "radiance W/(m^2 sr), irradiance W/m^2"})
            outputs["usd"] = "solution.usda"
    if cfg.outputs.preview.enabled:
        with rep.stage("preview"):
            pv = cfg.outputs.preview
            try:
                img = result.render(pv.camera, pv.width, pv.height, pv.samples)
            except BakeError as e:
                raise BakeError(f"outputs.preview.camera: {e}") from None
            _engine.write_exr(str(staging / "preview.exr"), np.ascontiguousarray(img, dtype=np.float32),
                              [("hirad:units", "exitant radiance W/(m^2 sr)")])
            images.write_png(staging / "preview.png", img)
            outputs["preview"] = ["preview.png", "preview.exr"]
    if snapshot_cb:
        outputs["snapshots"] = "snapshots/"

    stats = model.stats()
    report = {
        "hirad_version": __version__,
        "method": cfg.method,
        "config": str(source) if source is not None else None,
        "config_fingerprint": cfg.fingerprint(),
        "scene": str(cfg.scene),
        "threads": cfg.thread_count(),
        "timings_s": {**rep.timings, "total": round(time.perf_counter() - wall, 4)},
        "counts": {
            "meshes": len(scene.meshes),
            "input_faces": stats["input_faces"],
            "faces": stats["faces"],
            "patches": n,
            "emitter_patches": int(np.count_nonzero(patches["emission"].max(axis=1) > 0)),
            "emitter_meshes": sum(1 for m in scene.meshes if m.is_light) + len({
                int(scene.face_mesh[f]) for f in np.nonzero(scene.face_emission.max(axis=1) > 0)[0]
                if not scene.meshes[int(scene.face_mesh[f])].is_light}),
            "links": solved.get("links", stats["links"]),
            "link_bytes": stats["link_bytes"],
            "rays": stats["rays"] + solved.get("rays", 0),
            "skipped": {k: stats[k] for k in ("degenerate_faces", "nonfinite_faces")},
            "nonmanifold_edges": stats["nonmanifold_edges"],
        },
        "solver": {
            "method": method,
            "form_factors": ("hierarchical links" if cfg.method == "hierarchical"
                             else ff.method if method != "progressive" else "raycast, on the fly"),
            "iterations": solved["iterations"],
            "residual": solved["residual"],
            "tolerance": cfg.solver.tolerance,
            "converged": solved["converged"],
            "rows_computed": solved.get("rows_computed", 0),
            # The relative residual per iteration, thinned to at most 200 (iteration, residual)
            # pairs so long shooting runs stay readable; the last iteration is always kept.
            "residual_history": _thin(solved["residual_history"], 200),
        },
        "hierarchy": None if cfg.method != "hierarchical" else {
            k: solved[k] for k in ("rounds", "settled", "elements", "clusters", "nodes", "links_per_round",
                                   "splits_per_round", "link_estimates", "refine_seconds", "solve_seconds",
                                   "epsilon_watts", "balance_splits")},
        "links": None if "store" not in solved else {
            "store": solved["store"],
            "reused": solved["reused_links"],
            "form_factors_computed": solved["link_estimates"],
            "resumed_from_round": solved["resumed_from_round"],
            "source_groups": solved["source_groups"],
            "memory_budget_bytes": cfg.links.memory_budget,
            "store_bytes": solved["store_bytes"],
            "bytes_per_link": solved["store_bytes"] / max(1, solved["links"]),
            "transport_bytes": solved["transport_bytes"],
            "peak_refine_links": solved["peak_refine_links"],
            "last_solve": solved["streaming"],
        },
        "energy_balance": balance,
        "outputs": outputs,
        "warnings": rep.warnings,
    }
    if cfg.outputs.report:
        _write_json(staging / "report.json", report)
    result.report = report
    return result


def _thin(history: list, most: int) -> list:
    n = len(history)
    keep = sorted(set(np.linspace(0, n - 1, min(n, most)).round().astype(int).tolist())) if n else []
    return [[i + 1, history[i]] for i in keep]


def _solve_flat(cfg: Config, model, scene, staging: Path, rep: Reporter):
    """The classic method: patches from `meshing`, links between every pair that can exchange
    light, the configured solver, then irradiance and escaped power per patch."""
    with rep.stage("mesh patches"):
        model.mesh(cfg.meshing.max_patch_area, cfg.meshing.max_edge_length)
        patches = model.patch_arrays()
    n = model.num_patches
    method = cfg.solver.method
    ff = cfg.formfactors
    if method != "progressive":
        with rep.stage("form factors", total=n) as update:
            model.compute_links(ff.method, ff.samples, ff.hemicube_resolution, ff.hemicube_points, cfg.seed,
                                lambda done: update(done, f"{done}/{n} patches"))

    snapshot_cb = None
    if method == "progressive" and cfg.solver.snapshots > 0:
        snapshot_dir = staging / "snapshots"
        snapshot_dir.mkdir()
        snap_corners = model.display_mesh(cfg.reconstruction.crease_angle)["corners"]

        def snapshot_cb(shot: int, display: np.ndarray) -> None:
            # The image displayed at each iteration: B + rho * ambient, as Cohen et al. show it.
            radiance = (model.vertex_values(display) / np.pi)[snap_corners]
            sol = SurfaceSolution(patches["corners"], patches["nv"], radiance, radiance,
                                  cameras=scene.cameras, up_axis=scene.up_axis)
            img = sol.render(cfg.outputs.preview.camera, 256, 256, 1)
            images.write_png(snapshot_dir / f"shot_{shot:08d}.png", img)

    with rep.stage("solve", total=1.0) as update:
        solved = model.solve(method, cfg.solver.tolerance, cfg.solver.max_iterations, ff.samples, cfg.seed,
                             cfg.solver.snapshots, snapshot_cb, _solve_progress(cfg, update))
    b = solved["radiosity"]
    with rep.stage("irradiance"):
        transport = model.transport(b, ff.samples, cfg.seed)
    solved["snapshots_written"] = snapshot_cb
    return solved, patches, b, transport["irradiance"], transport["escaped"]


def _solve_hierarchical(cfg: Config, model, rep: Reporter, resume: bool = False, reuse_links: bool = False):
    """Hierarchical radiosity with clustering: refine, solve with push-pull, refine again;
    the leaf elements become the model's patches."""
    hc = cfg.hierarchy
    with rep.stage("hierarchical solve", total=1.0) as update:
        def on_progress(round_: int, links: int, iteration: int, residual: float) -> None:
            _solve_progress(cfg, update)(iteration, residual)
            update(None, f"round {round_}, {links} links, iteration {iteration}, residual {residual:.2e}")

        if cfg.solver.method == "block_southwell":
            lc = cfg.links
            store = cfg.link_store()
            try:
                solved = model.solve_out_of_core(
                    hc.epsilon, hc.min_area, hc.samples, cfg.seed, cfg.solver.tolerance, cfg.solver.max_iterations,
                    hc.max_rounds, on_progress, str(store), lc.memory_budget, lc.group_faces, lc.checkpoint_seconds,
                    resume, reuse_links)
            except RuntimeError as e:
                raise BakeError(f"link store {store}: {e}") from None
            solved["store"] = str(store)
        else:
            if resume or reuse_links:
                raise BakeError("--resume and --reuse-links need the out-of-core solver (solver.method: block_southwell)")
            solved = model.solve_hierarchical(hc.epsilon, hc.min_area, hc.samples, cfg.seed, cfg.solver.tolerance,
                                              cfg.solver.max_iterations, hc.max_rounds, on_progress, cfg.solver.method)
    if solved.get("reused_links"):
        rep.warn(f"links reused from {solved['store']}: {solved['links']} links, no form factor computed")
    if not solved["settled"] and solved["rounds"] >= hc.max_rounds:
        rep.warn(f"hierarchy.max_rounds ({hc.max_rounds}) reached while links still wanted to split")
    return solved, model.patch_arrays()


def _solve_progress(cfg: Config, update):
    """Progress of an iterative solve as the fraction of the way, in log residual, to the
    tolerance."""
    def on_progress(iteration: int, residual: float) -> None:
        if residual <= 0:
            done = 1.0
        else:
            done = 0.0 if residual >= 1 else min(1.0, np.log(residual) / np.log(cfg.solver.tolerance))
        update(done, f"iteration {iteration}, residual {residual:.2e}")
    return on_progress


def _energy_balance(patches: dict, b: np.ndarray, h: np.ndarray, escaped: np.ndarray) -> dict:
    """Emitted power against absorbed plus escaped (through openings), per channel, in W."""
    area = patches["area"][:, None]
    emitted = (patches["emission"] * area).sum(axis=0)
    absorbed = ((1 - patches["reflectance"]) * h * area).sum(axis=0)
    lost = escaped.sum(axis=0)
    scale = np.where(emitted > 0, emitted, 1.0)
    error = np.abs(emitted - absorbed - lost) / scale
    return {"emitted_W": emitted.tolist(), "absorbed_W": absorbed.tolist(), "escaped_W": lost.tolist(),
            "relative_error": error.tolist(), "max_relative_error": float(error.max())}


def _patch_meshes(scene, patches, display, vertex_radiance, vertex_irradiance, b, h):
    """One PatchMeshData per input mesh from the display faces (patches, or fans of triangles
    where a patch has T-vertices), its points re-indexed; with each, its display faces."""
    faces, face_nv, face_patch = display["faces"], display["face_nv"], display["face_patch"]
    face_mesh = patches["mesh"][face_patch]
    out, faces_of = [], []
    order = np.argsort(face_mesh, kind="stable")
    bounds = np.searchsorted(face_mesh[order], np.arange(len(scene.meshes) + 1))
    for m in range(len(scene.meshes)):
        fids = order[bounds[m]:bounds[m + 1]]
        if fids.size == 0:
            continue
        counts = face_nv[fids].astype(np.int32)
        flat = np.concatenate([faces[f, :face_nv[f]] for f in fids])
        used, local = np.unique(flat, return_inverse=True)
        pids = face_patch[fids]
        out.append(usd.PatchMeshData(
            mesh_index=m, points=display["points"][used], face_vertex_counts=counts,
            face_vertex_indices=local.astype(np.int32), vertex_radiance=vertex_radiance[used],
            vertex_irradiance=vertex_irradiance[used], face_radiance=b[pids] / np.pi, face_irradiance=h[pids]))
        faces_of.append(fids)
    return out, faces_of


def _corner_uv(uv: np.ndarray, nv: int, code: int) -> np.ndarray:
    """UV of a display face corner from its patch's corner UVs (see DisplayMesh::face_code)."""
    if code < 4:
        return uv[code]
    if code < 8:
        k = code - 4
        return 0.5 * (uv[k] + uv[(k + 1) % nv])
    return uv[:nv].mean(axis=0)


_LIGHTMAP_UNITS = "incident radiance H/pi, W/(m^2 sr); final colour = albedo x lightmap"


def _triangulate(counts: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Display faces (triangles and planar quads) as triangles: (tris (M,3) of local vertex
    ids, face (M,), corners (M,3) of face corner slots). A quad (a,b,c,d) -> (a,b,c), (a,c,d)."""
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tris, face, slots = [], [], []
    for f, (s0, c) in enumerate(zip(starts, counts)):
        for k in range(1, c - 1):
            slot = (s0, s0 + k, s0 + k + 1)
            slots.append(slot)
            tris.append([indices[j] for j in slot])
            face.append(f)
    return (np.asarray(tris, np.int64).reshape(-1, 3), np.asarray(face, np.int64),
            np.asarray(slots, np.int64).reshape(-1, 3))


def _default_density(lm, patches) -> float:
    """texels_per_metre, or the density that gives a median patch texels_per_patch texels a side."""
    if lm.texels_per_metre is not None:
        return float(lm.texels_per_metre)
    area = np.asarray(patches["area"], dtype=np.float64)
    area = area[area > 0]
    return float(lm.texels_per_patch / np.sqrt(np.median(area))) if area.size else float(lm.texels_per_patch)


def scene_fingerprint(scene) -> str:
    """sha256 of what the light depends on: the scene's geometry, reflectance and emission
    (not paths or output settings, so the same scene baked twice gives identical files)."""
    import hashlib

    h = hashlib.sha256()
    for a in (scene.points, scene.face_vertex_counts, scene.face_vertex_indices, scene.face_reflectance,
              scene.face_emission):
        arr = np.ascontiguousarray(a)
        h.update(str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def _lift(result, points: np.ndarray, normals: np.ndarray, texel: np.ndarray, epsilon: float,
          reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Leak prevention for texel samples (all of them lie on their own triangles).

    Every sample is lifted `epsilon` along its geometric normal. Then short rays (length
    `reach`, one texel) go out along the normal and 8 tangent directions; when one of them
    first meets the *back* of a surface, the sample is inside or behind geometry (a floor
    texel under a wall standing on it, under a block without a bottom, inside the joint of
    two slabs) and is moved just past that surface and lifted again. Which surface: the one
    in the direction of the texel's samples that are not inside anything (so a texel that
    straddles a wall one texel thick keeps its samples on the side it shows, instead of
    sending half of them through to the far side), else the nearest. Returns (points, moved)."""
    if len(points) == 0:
        return points, np.zeros(0, bool)
    corners = np.ascontiguousarray(result.corners)
    nv = np.ascontiguousarray(result.nv, dtype=np.int32)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    nrm = np.ascontiguousarray(normals, dtype=np.float64)
    first = _engine.lift_samples(corners, nv, pts, nrm, float(epsilon), float(reach))
    moved = first["moved"].astype(bool)
    if not moved.any():
        return first["points"], moved
    # anchor: mean of the texel's free samples (or of all its samples when none is free)
    t = np.asarray(texel, dtype=np.int64)
    nt = int(t.max()) + 1
    free = (~moved).astype(np.float64)
    w_free = np.bincount(t, free, minlength=nt)
    anchor = np.zeros((nt, 3))
    for c in range(3):
        a_free = np.bincount(t, pts[:, c] * free, minlength=nt)
        a_all = np.bincount(t, pts[:, c], minlength=nt) / np.maximum(np.bincount(t, minlength=nt), 1)
        anchor[:, c] = np.where(w_free > 0, a_free / np.maximum(w_free, 1e-300), a_all)
    sel = np.nonzero(moved)[0]
    again = _engine.lift_samples(corners, nv, np.ascontiguousarray(pts[sel]), np.ascontiguousarray(nrm[sel]),
                                 float(epsilon), float(reach), np.ascontiguousarray(anchor[t[sel]]))
    out = first["points"].copy()
    out[sel] = again["points"]
    return out, moved


def _bake_page(atlas, page: int, evaluate, supersample: int):
    """hirad.atlas.bake_page, with each sample's texel passed to `evaluate` (for _lift):
    rasterize -> evaluate -> resolve -> stitch seams -> dilate into the padding."""
    from . import atlas as A

    samples = A.rasterize(atlas, page, supersample)
    points, normals = A.sample_points(samples, atlas.geometry)
    values = np.asarray(evaluate(points, normals, samples.texel))
    image, mask = A.resolve(samples, values)
    image = A.stitch(image, A.seam_pairs(atlas, page))
    return A.dilate(image, mask, max(int(atlas.padding), 1)), mask


def _write_lightmaps(cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces,
                     staging: Path, result=None, warn=None) -> tuple[list[str], dict]:
    """Lightmaps on an atlas: every mesh's display faces (what the USD layer shows) go into
    one atlas of pages (hirad.atlas): the mesh's own lightmap UVs when it has them, else
    xatlas charts, at outputs.lightmaps.texels_per_metre with `padding`. Each texel holds
    the incident radiance H/pi at its supersampled surface points (after leak-preventing
    lifting, see _lift), from the display mesh's vertex irradiance ('interpolate') or a
    final gather from the hierarchy ('final_gather'); seams are stitched and the padding
    dilated. Writes lightmaps/pages/page<k>.exr (half float), optional RGBM PNGs,
    lightmaps/manifest.json, and (mesh_files) lightmaps/<mesh>.exr cut out of the pages.
    Each PatchMeshData gets its page file and faceVarying lightmap UVs for the USD layer.
    Returns (per-mesh files or pages, atlas summary for the report)."""
    from . import atlas as A

    lm = cfg.outputs.lightmaps
    if lm.mode == "final_gather" and (result is None or not result.hierarchical):
        raise BakeError("outputs.lightmaps.mode: final_gather needs a hierarchical bake (method: hierarchical); "
                        "use mode: interpolate for flat bakes")
    t_start = time.perf_counter()
    fingerprint = scene_fingerprint(scene)
    lm_dir = staging / "lightmaps"
    (lm_dir / "pages").mkdir(parents=True)
    density = _default_density(lm, patches)
    nv_all = patches["nv"]

    geometry, existing, names, tri_info, pms = [], [], [], [], []
    for pm, fids in zip(meshes, mesh_faces):
        info = scene.meshes[pm.mesh_index]
        counts = np.asarray(pm.face_vertex_counts)
        tris, face_of, slots = _triangulate(counts, np.asarray(pm.face_vertex_indices))
        geometry.append((np.asarray(pm.points, dtype=np.float64), tris))
        if info.has_uv:
            # the mesh's own UV set, carried through the patches to the display corners
            corner = np.array([
                _corner_uv(patches["uv"][display["face_patch"][f]], int(nv_all[display["face_patch"][f]]),
                           int(display["face_code"][f][c]))
                for f in fids for c in range(display["face_nv"][f])]).reshape(-1, 2)
            existing.append(corner[slots])
        else:
            existing.append(None)
        names.append(info.name)
        tri_info.append((face_of, slots, int(counts.sum())))
        pms.append(pm)

    atlas = A.build_atlas(geometry, density, lm.padding, lm.max_size, existing_uvs=existing, names=names,
                          existing_layout=lm.existing_layout)
    rep_warnings = list(atlas.warnings)

    # faceVarying lightmap UVs per display face corner, from the triangles' corners
    for k, (pm, layout) in enumerate(zip(pms, atlas.meshes)):
        face_of, slots, n_corners = tri_info[k]
        uv = np.zeros((n_corners, 2))
        if len(layout.uvs):
            flat_slots = slots.reshape(-1)
            flat_uv = layout.uvs.reshape(-1, 2)
            uv[flat_slots] = flat_uv  # a corner shared by two triangles of a quad: same chart, same UV
            again = np.zeros_like(uv)
            again[flat_slots[::-1]] = flat_uv[::-1]
            w, h = atlas.page_sizes[layout.page]
            if np.abs((again - uv) * [w, h]).max() > 1e-3:
                rep_warnings.append(f"{names[k]}: a quad's triangles were charted apart; its lightmap UVs "
                                    "follow the first triangle")
        pm.lightmap_uv = uv

    mode = lm.mode
    field = result.field if result is not None else None

    def evaluate(points, normals, texel):
        reach = 1.0 / density
        lifted, moved = _lift(result, points, normals, texel, lm.sample_offset, reach)
        evaluate.moved += int(moved.sum())
        if mode == "final_gather":
            g = result.gather(lifted, normals, rays=lm.gather_rays)
            values = g["irradiance"] / np.pi
            miss = g["patch"] < 0
        else:
            q = field.probe(np.ascontiguousarray(lifted), np.ascontiguousarray(normals, dtype=np.float64), 1e30)
            values = q["irradiance"] / np.pi
            miss = q["patch"] < 0
        if miss.any():  # no surface facing along the normal: take the nearest one
            q = field.probe(np.ascontiguousarray(lifted[miss]), np.zeros((int(miss.sum()), 3)), 1e30)
            values[miss] = q["irradiance"] / np.pi
        evaluate.samples += len(points)
        return values

    evaluate.moved = 0
    evaluate.samples = 0

    meta_base = [("hirad:units", _LIGHTMAP_UNITS), ("hirad:version", __version__),
                 ("hirad:sceneFingerprint", fingerprint), ("hirad:texelsPerMetre", f"{density:.9g}"),
                 ("hirad:lightmapMode", mode)]
    page_files, page_images, page_masks, png_files = [], [], [], []
    for page in range(len(atlas.page_sizes)):
        image, mask = _bake_page(atlas, page, evaluate, lm.supersample)
        image = np.ascontiguousarray(image[..., :3], dtype=np.float32)
        rel = f"pages/page{page}.exr"
        _engine.write_exr(str(lm_dir / rel), image, meta_base + [("hirad:page", str(page))])
        page_files.append(rel)
        page_images.append(image)
        page_masks.append(mask)
        if lm.rgbm:
            top = float(lm.rgbm_range) if lm.rgbm_range is not None else float(max(image.max(), 1e-6))
            png = f"pages/page{page}.png"
            A.write_rgbm_png(lm_dir / png, image, top)
            png_files.append({"file": png, "rgbm_range": top})
    elapsed = time.perf_counter() - t_start

    written = []
    for k, (pm, layout) in enumerate(zip(pms, atlas.meshes)):
        info = scene.meshes[pm.mesh_index]
        if layout.page < 0:
            pm.lightmap_uv = None
            continue
        pm.lightmap_path = f"lightmaps/{page_files[layout.page]}"
        of_mesh = patches["mesh"] == pm.mesh_index
        area = patches["area"][of_mesh][:, None]
        if area.sum() > 0:
            pm.lightmap_albedo = tuple((patches["reflectance"][of_mesh] * area).sum(axis=0) / area.sum())
            emitted = (patches["emission"][of_mesh] * area).sum(axis=0) / area.sum() / np.pi
            pm.lightmap_emission = tuple(emitted) if emitted.max() > 0 else None
        if lm.mesh_files:
            w, h = atlas.page_sizes[layout.page]
            bx, by, bw, bh = layout.block
            crop = page_images[layout.page][h - (by + bh):h - by, bx:bx + bw]
            name = f"lightmaps/{info.name}.exr"
            _engine.write_exr(str(staging / name), np.ascontiguousarray(crop, dtype=np.float32),
                              meta_base + [("hirad:mesh", info.path), ("hirad:page", str(layout.page)),
                                           ("hirad:pageBlock", f"{bx} {by} {bw} {bh}")])
            written.append(name)

    texels = sum(w * h for w, h in atlas.page_sizes)
    covered = int(sum(int(m.sum()) for m in page_masks))
    summary = {
        "manifest": "lightmaps/manifest.json",
        "pages": [f"lightmaps/{f}" for f in page_files],
        "page_sizes": [list(s) for s in atlas.page_sizes],
        "mode": mode,
        "texels_per_metre": density,
        "padding": lm.padding,
        "supersample": lm.supersample,
        "fill": [round(f, 6) for f in atlas.fill],
        "covered_texels": covered,
        "samples": evaluate.samples,
        "moved_samples": evaluate.moved,
        "page_bytes_half_rgb": texels * 6,
        "seconds": round(elapsed, 4),
        "texels_per_second": round(covered / elapsed, 1) if elapsed > 0 else None,
        "warnings": rep_warnings,
    }
    extra = {"hirad:version": __version__, "units": _LIGHTMAP_UNITS, "sceneFingerprint": fingerprint,
             "mode": mode, "supersample": lm.supersample,
             "uvPrimvar": "hirad:lightmapUV (texCoord2f, faceVarying, on /HiradSolution meshes)"}
    if png_files:
        extra["rgbm"] = {"pages": png_files, "decode": "linear = rgb/255 * a/255 * rgbm_range"}
    if lm.mesh_files:
        extra["meshFiles"] = {scene.meshes[pm.mesh_index].name: f"{scene.meshes[pm.mesh_index].name}.exr"
                              for pm, layout in zip(pms, atlas.meshes) if layout.page >= 0}
    A.write_manifest(lm_dir / "manifest.json", atlas, page_files, extra)
    if warn is not None:
        for w in rep_warnings:
            warn(f"outputs.lightmaps: {w}")
    return (written if lm.mesh_files else summary["pages"]), summary


_VOLUME_DEFINITION = ("irradiance = integral over the sphere of incident radiance L dw (scalar irradiance, "
                      "W/m^2, RGB); sh1_x/y/z = integral of L w_x/y/z dw (W/m^2, RGB, the L1 spherical "
                      "harmonics band); irradiance on a surface facing n ~ irradiance/4 + (n . sh1)/2; "
                      "direction = unit vector of the luminance of sh1 (dominant incoming direction, "
                      "pointing towards the light)")


def _write_volume(cfg, result, scene, staging: Path) -> dict:
    """The irradiance volume (volume.vdb): probes on the lattice spacing * (i, j, k) (world
    origin), kept where a surface lies within max_distance (but not closer than spacing/1000:
    a point on a surface is no probe) and the probe is in empty space
    (at most 10 % of the surfaces its rays meet are seen from the back: not inside a solid,
    not behind one-sided walls). Each probe integrates the solution's exitant radiance over the full
    sphere with `rays` stratified directions in the engine (Embree)."""
    vc = cfg.outputs.volume
    s = float(vc.spacing)
    reach = float(vc.max_distance) if vc.max_distance is not None else 3.0 * s
    pts = result.corners.reshape(-1, 3)
    lo = np.floor((pts.min(axis=0) - reach) / s).astype(np.int64)
    hi = np.ceil((pts.max(axis=0) + reach) / s).astype(np.int64)
    dims = hi - lo + 1
    total = int(np.prod(dims))
    if total > vc.max_probes:
        raise BakeError(f"outputs.volume.spacing: {s:g} m gives {total} lattice points over the scene "
                        f"(outputs.volume.max_probes is {vc.max_probes}); raise the spacing")
    t0 = time.perf_counter()
    grid = np.stack(np.meshgrid(*[np.arange(lo[a], hi[a] + 1) for a in range(3)], indexing="ij"), -1).reshape(-1, 3)
    world = grid * s
    near = result.query(world, None, reach)
    keep = (near["patch"] >= 0) & (near["distance"] > 1e-3 * s)  # not on a surface itself
    grid, world = grid[keep], world[keep]
    probes = _engine.volume_probes(np.ascontiguousarray(result.corners), np.ascontiguousarray(result.nv, dtype=np.int32),
                                   np.ascontiguousarray(result.corner_radiance), np.ascontiguousarray(world),
                                   int(vc.rays), int(cfg.seed))
    # Behind or inside geometry: more than a tenth of what the probe sees is the back of a
    # surface (outside a closed room, inside a solid, behind a one-sided wall).
    empty = (probes["back_fraction"] <= 0.1 * probes["hit_fraction"]) & (probes["nearest"] > 1e-6)
    grid, world = grid[empty], world[empty]
    s0, s1 = probes["s0"][empty], probes["s1"][empty]
    lum = np.array([0.2126, 0.7152, 0.0722])
    vec = s1 @ lum  # (n, 3): luminance of each axis moment
    norm = np.linalg.norm(vec, axis=1, keepdims=True)
    direction = np.where(norm > 0, vec / np.maximum(norm, 1e-300), 0.0)
    coords = np.ascontiguousarray(grid, dtype=np.int32)
    common = [("units", "W/m^2"), ("spacing", f"{s:.9g}"), ("hirad:version", __version__),
              ("hirad:rays", str(int(vc.rays)))]
    grids = [("irradiance", coords, np.ascontiguousarray(s0, dtype=np.float32),
              common + [("definition", _VOLUME_DEFINITION)]),
             ("direction", coords, np.ascontiguousarray(direction, dtype=np.float32),
              [("units", "unit vector"), ("spacing", f"{s:.9g}"), ("hirad:version", __version__)])]
    for a, axis in enumerate("xyz"):
        grids.append((f"sh1_{axis}", coords, np.ascontiguousarray(s1[:, a, :], dtype=np.float32), common))
    meta = [("hirad:version", __version__), ("hirad:sceneFingerprint", scene_fingerprint(scene)),
            ("hirad:units", "W/m^2"), ("hirad:spacing", f"{s:.9g}"), ("hirad:definition", _VOLUME_DEFINITION),
            ("hirad:worldUnits", "metres (the stage's metersPerUnit applied), stage up axis " + str(scene.up_axis))]
    _engine.write_vdb(str(staging / "volume.vdb"), grids, s, [0.0, 0.0, 0.0], meta)
    return {"file": "volume.vdb", "probes": int(len(coords)), "candidates": total, "spacing": s,
            "max_distance": reach, "rays": int(vc.rays), "grids": [g[0] for g in grids],
            "seconds": round(time.perf_counter() - t0, 4)}


def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)
