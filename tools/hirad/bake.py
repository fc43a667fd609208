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
    _model: object = None   # the engine model of a hierarchical bake, kept for the final gather

    def gather(self, points, normals, *, rays: int = 4, cluster_samples: int = 8,
               seed: int = 1) -> dict:
        """Final gather at surface points from the solved hierarchy (hierarchical bakes only):
        every link that reaches a point's element is re-evaluated at the point itself, with
        exact point-to-polygon form factors and Embree visibility. Returns dict of patch
        (-1 if no surface faces along the normal), irradiance (W/m^2) and radiance
        (W/(m^2 sr))."""
        if self._model is None:
            raise BakeError("gather needs a hierarchical bake (method: hierarchical)")
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
        return self._model.gather(pts, nrm, rays, cluster_samples, seed)


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
                    patches=patches, _model=model if cfg.method == "hierarchical" else None)

    outputs: dict[str, object] = {}
    meshes, mesh_faces = _patch_meshes(scene, patches, display, vertex_radiance, vertex_irradiance, b, h)
    if cfg.outputs.lightmaps.enabled:
        with rep.stage("lightmaps"):
            outputs["lightmaps"] = _write_lightmaps(cfg, scene, patches, display, vertex_irradiance, meshes,
                                                    mesh_faces, staging)
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
            "peak_group_links": solved["peak_group_links"],
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


def _write_lightmaps(cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces,
                     staging: Path) -> list[str]:
    """One EXR per mesh of incident radiance H/pi: over the mesh's own UVs when it has them,
    else a chart per patch on a grid (texels_per_patch square, one texel of padding). Charts
    are baked per patch from its corner values, which is what anchoring gives the T-vertices
    on its edges."""
    lm = cfg.outputs.lightmaps
    (staging / "lightmaps").mkdir()
    written = []
    corners_all, nv_all = display["corners"], patches["nv"]
    for pm, fids in zip(meshes, mesh_faces):
        info = scene.meshes[pm.mesh_index]
        ids = np.unique(display["face_patch"][fids])
        values = np.ascontiguousarray(vertex_irradiance[corners_all[ids]] / np.pi)
        nv = np.ascontiguousarray(nv_all[ids], dtype=np.int32)
        if info.has_uv:
            uv = np.ascontiguousarray(patches["uv"][ids])
            size = int(min(lm.max_size, max(16, np.ceil(np.sqrt(len(ids)) * lm.texels_per_patch))))
            width = height = size
        else:
            uv, width, height = _grid_layout(nv, lm.texels_per_patch, lm.max_size)
        baked = _engine.bake_uv(uv, nv, values, width, height, 2)
        name = f"lightmaps/{info.name}.exr"
        _engine.write_exr(str(staging / name), np.ascontiguousarray(baked["rgb"], dtype=np.float32),
                          [("hirad:units", "incident radiance W/(m^2 sr)"), ("hirad:mesh", info.path),
                           ("hirad:version", __version__)])
        slot = {int(p): k for k, p in enumerate(ids)}
        pm.lightmap_uv = np.array([
            _corner_uv(uv[slot[int(display["face_patch"][f])]], int(nv_all[display["face_patch"][f]]),
                       int(display["face_code"][f][c]))
            for f in fids for c in range(display["face_nv"][f])])
        pm.lightmap_path = name
        written.append(name)
    return written


def _grid_layout(nv: np.ndarray, texels: int, max_size: int):
    """Per-patch charts on a square grid; shrinks the charts if the grid would pass max_size."""
    n = len(nv)
    cols = int(np.ceil(np.sqrt(n)))
    while texels > 1 and cols * (texels + 2) > max_size:
        texels -= 1
    cell = texels + 2
    size = cols * cell
    if size > max_size:
        raise BakeError(f"outputs.lightmaps.max_size: {n} patches need at least {size} texels a side")
    k = np.arange(n)
    x0 = (k % cols) * cell + 1
    y0 = (k // cols) * cell + 1
    unit = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    tri = np.array([[0, 0], [1, 0], [0, 1], [0, 1]], dtype=np.float64)
    local = np.where((nv == 3)[:, None, None], tri[None], unit[None])
    u = (x0[:, None] + local[:, :, 0] * texels) / size
    v = 1.0 - (y0[:, None] + (1 - local[:, :, 1]) * texels) / size
    return np.ascontiguousarray(np.stack([u, v], axis=-1)), size, size


def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)
