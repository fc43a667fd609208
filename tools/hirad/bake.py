"""The bake: scene -> patches -> links -> solution -> outputs, as one function.

Units (hirad.units; the config's `units`): photometric by default, following UsdLux's
physical-lighting semantics: emission and radiosity B are luminous exitance in lm/m^2,
irradiance H is illuminance in lux, exitant B/pi and incident H/pi are luminances in cd/m^2,
luminaires are candela tables with their flux in lm; USD light intensities and emissiveColor
are luminances (nits). `units: radiometric` reads the same numbers as W/m^2, W/(m^2 sr), W.
RGB is carried throughout; the photometric value is Y = 0.2126 R + 0.7152 G + 0.0722 B.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np

from . import __version__, _engine, files, interrupts, units, usd
from .engine import PatchTable, build_engine, display_dict, patch_dict, streaming_dict
from .estimate import estimate as estimate_cost, memory_warning
from .outputs import images
from .config import Config, load_config
from .errors import BakeError  # noqa: F401
from .outputs.lightmaps import attach_lightmaps, bake_lightmaps, lightmap_sources, write_lightmaps
from .photometry.luminaires import with_config_lights
from .outputs.meshes import patch_meshes
from .outputs.volume import write_volume
from .report import (MAPPED_FROM_LARGE, MAPPED_FROM_SMALL, Reporter, energy_balance, map_blocks_from,
                     release_free_memory, scene_fingerprint, write_json)
from .solution import LUMINAIRES_FILE, Result, SurfaceSolution, load_solution, luminance_y, save_luminaires  # noqa: F401  (the API: hirad.bake.load_solution)
from .studies import StudyError, build_grids, evaluate_grids, resolve_room


# --------------------------------------------------------------------------------------
# the bake
# --------------------------------------------------------------------------------------


class OptionError(BakeError):
    """An option that does not apply to this config (the CLI exits with 2, a usage error)."""


# From this many input faces a bake keeps glibc's mapping threshold at 128 KiB, below it at 32
# MiB (report.map_blocks_from): memory first for large scenes, time for small ones.
MAPPED_BLOCKS_FACES = 200_000


def bake(config: Config | str | os.PathLike, *, quiet: bool = True, threads: int | None = None,
         snapshots: int | None = None, resume: bool = False, reuse_links: bool = False,
         overrides: tuple[str, ...] | list[str] = (), progress: str = "auto", scheduler: str | None = None,
         link_threads: int = 1, keep_hierarchy: bool = False) -> Result:
    """Runs the whole pipeline for a config (a Config or a YAML path) and writes its outputs.

    Outputs are assembled in a hidden sibling directory (`.NAME.partial-PID-X/`) and moved into
    place only when complete, so an interrupted or failed bake never leaves a directory that
    looks complete, and the previous output stays until the new one is in place. hirad only
    replaces an output directory it made (hirad.files): an output that is or contains the
    scene, one of its layers or the config, a link, or a non-empty directory hirad did not make
    (or to which other files were added) is refused with an UnsafePathError, before anything
    runs; so is a link store that overlaps the output or the inputs, or that hirad did not make.
    After a successful bake, staging directories of the same output left by killed bakes are
    removed. Out of core (method: hierarchical, solver.method: block_southwell), `resume`
    continues what a killed bake with the same inputs left in the link store, and `reuse_links`
    solves on the stored links of the same geometry and refinement settings (new materials)
    without computing any form factor; for any other bake they are an error. `overrides`
    (`KEY=VALUE` strings, `hirad bake --set`) are set on the config file's values before
    validation (hirad.config.load_config). `progress` is hirad.report.Reporter's mode (auto,
    bar, plain, jsonl, none). `scheduler` (a Dask scheduler's address; out of core, from a config
    file) spreads link generation over the cluster's workers, `link_threads` engine threads in
    each task (hirad.batch.links): the same bits as a bake on this machine. A hierarchical bake
    lets go of its solved hierarchy once no output gathers from it any more (memory), so the
    returned Result's `gather` works only with `keep_hierarchy` (or when an output gathered last:
    light groups, daylight coefficients).
    """
    map_blocks_from(MAPPED_FROM_SMALL)  # freed arrays go back to the system (report.py)
    source = None if isinstance(config, Config) else Path(config).absolute()
    cfg = config if isinstance(config, Config) else load_config(config, overrides)
    if overrides and isinstance(config, Config):
        raise OptionError("overrides (--set) apply to a config file, not to a Config object")
    if threads is not None:
        cfg.threads = threads
    if snapshots is not None:
        if snapshots > 0 and cfg.solver.method != "progressive":
            raise OptionError("--snapshots needs solver.method: progressive")
        cfg.solver.snapshots = snapshots
    out_of_core = cfg.method == "hierarchical" and cfg.solver.method == "block_southwell"
    if (resume or reuse_links) and not out_of_core:
        flags = " and ".join(f for f, on in (("--resume", resume), ("--reuse-links", reuse_links)) if on)
        raise OptionError(f"{flags}: only an out-of-core bake keeps links and state between runs (method: "
                        f"hierarchical with solver.method: block_southwell); this config bakes method: {cfg.method} "
                        f"with solver.method: {cfg.solver.method}, so there is nothing to "
                        f"{'resume' if resume else 'reuse'}")
    if scheduler is not None:
        if not out_of_core:
            raise OptionError(f"--scheduler: distributed link generation is for an out-of-core bake (method: "
                              f"hierarchical with solver.method: block_southwell); this config bakes method: "
                              f"{cfg.method} with solver.method: {cfg.solver.method}")
        if source is None:
            raise OptionError("--scheduler: the workers read the config from its file; give a path, not a Config")
        if reuse_links:
            raise OptionError("--scheduler with --reuse-links: reused links are not generated, so there is nothing "
                              "to distribute")
    out_dir = Path(cfg.output)
    store = cfg.link_store() if out_of_core else None
    # The inputs an output or store must not hold. The scene's layers are looked up only when
    # there is an existing directory that could hold them; _run takes them over (held_layers)
    # and keeps them until the scene's content key and calculation surfaces are read, so
    # nothing is parsed twice and nothing is held through the solve.
    inputs: list[tuple[str, Path]] = [("scene", Path(cfg.scene))] + ([("config", source)] if source else [])
    inputs += [("grid points file", Path(spec.file)) for spec in cfg.grids.values() if spec.kind == "points"]
    held_layers: list = []
    if os.path.lexists(out_dir) or (store is not None and os.path.lexists(store)):
        layer_paths, scene_layers = files.scene_files(cfg.scene)
        held_layers.append(scene_layers)
        del scene_layers
        inputs += [("scene layer", p) for p in layer_paths[1:]]
    files.check_output(out_dir, inputs)
    if store is not None:
        files.check_link_store(store, out_dir, inputs)
    remote = None
    if scheduler is not None:  # before anything is made: an unreachable scheduler is a usage error
        from .batch import links

        try:
            remote = links.DistributedLinks(links.connect(scheduler), source, tuple(overrides), threads=link_threads)
        except links.SchedulerError as e:
            raise OptionError(str(e)) from None
    _engine.set_threads(cfg.threads)
    staging = files.make_staging(out_dir, __version__)
    try:
        with files.removed_on_failure(staging):
            if store is not None:
                files.make_link_store(store, __version__)
            with Reporter(quiet, mode=progress) as rep:
                try:
                    result = _run(cfg, staging, rep, source, resume, reuse_links, tuple(overrides), remote,
                                  keep_hierarchy, held_layers)
                finally:
                    if remote is not None:
                        remote.close()
            files.finish_staging(staging, __version__)
            with interrupts.deferred():
                files.replace_output(staging, out_dir, inputs)
    except files.WriteError as e:
        # name the file where the user will look for it, not in the hidden staging directory
        raise files.WriteError(str(e).replace(str(staging), str(out_dir))) from None
    files.remove_stale_staging(out_dir)
    result.output_dir = out_dir
    return result


def read_inputs(cfg: Config):
    """(scene, luminaire specs): the config's scene read, and its luminaires with the config's
    `lights:` (photometry.luminaires). A distributed bake's workers read theirs the same way."""
    sky_model = cfg.daylight.sky.model != "usd"  # the config's sky lights the scene
    scene = usd.read_scene(cfg.scene, default_reflectance=tuple(cfg.materials.default_reflectance),
                           uv_primvars=tuple(cfg.materials.uv_primvars),
                           require_emission=not cfg.lights and not sky_model,
                           ies_mode=cfg.photometry.ies_mode, daylight=True,
                           lightmap_uv_primvars=tuple(cfg.outputs.lightmaps.uv_primvars)
                           if cfg.outputs.lightmaps.enabled else ())
    return scene, with_config_lights(scene, cfg)


def daylight_inputs(cfg: Config, scene, source: Path | None = None):
    """(distant lights, daylight-coefficient groups): the sun and sky of the scene's DomeLight and
    DistantLight prims or of the config's sky model (hirad.daylight.sources), and with
    daylight.annual one unit-luminance light per sky patch and the ground. Errors name the
    daylight key (and its line when the config came from a file)."""
    from .config import ConfigError
    from .config.errors import DICT_SOURCE
    from .config.loader import config_line
    from .daylight.patches import reinhart_patches
    from .daylight.sources import DaylightError, daylight_luminaires, daylight_patch_groups, sun_bin_lights

    dl = cfg.daylight

    def located(key: tuple, message: str):
        line = config_line(source, key) if source is not None else 0
        return ConfigError(str(source) if source is not None else DICT_SOURCE, line, ".".join(key), message)

    try:
        lights = daylight_luminaires(scene, cfg) if (scene.daylight or dl.sky.model != "usd") else []
        groups = []
        if dl.annual is not None:  # sky patches and ground of unit luminance, then 1-lux suns at the patch centres
            from .daylight.weather import WeatherFileError, read_weather

            try:
                read_weather(dl.annual.weather)  # a bad line stops the bake now, naming the file and line
            except WeatherFileError as e:
                raise located(("daylight", "annual", "weather"), str(e)) from None
            north = None if dl.north is None else tuple(dl.north)
            groups = daylight_patch_groups(scene, cfg) + sun_bin_lights(reinhart_patches(dl.reinhart_mf()),
                                                                        scene.up_axis, north)
    except DaylightError as e:
        raise located(("daylight",), str(e)) from None
    if dl.annual is not None:
        if cfg.method != "hierarchical":
            raise located(("daylight", "annual"), "annual daylight coefficients need method: hierarchical")
        if cfg.light_groups:
            raise located(("daylight", "annual"), "daylight.annual and light_groups cannot be baked together (the "
                                                  "sky patches are the bake's light groups)")
        if not cfg.grids:
            raise located(("daylight", "annual"), "annual metrics are computed on grids: give at least one grid")
    if dl.daylight_factor:
        if any(l.kind == "sun" for l in lights):
            raise located(("daylight", "daylight_factor"), "a daylight factor needs a sky without a sun (set "
                                                           "daylight.sun.enabled: false)")
        if not lights:
            raise located(("daylight", "daylight_factor"), "no sky: the scene has no DomeLight and "
                                                           "daylight.sky.model is usd")
        if not cfg.grids:
            raise located(("daylight", "daylight_factor"), "a daylight factor is computed on grids: give at least "
                                                           "one grid")
    return lights, groups


def hierarchy_options(cfg: Config) -> "_engine.HierarchyOptions":
    hc = cfg.hierarchy
    return _engine.HierarchyOptions(epsilon=hc.epsilon, min_area=hc.min_area, samples=hc.samples, seed=cfg.seed,
                                    max_rounds=hc.max_rounds, relative=hc.relative_epsilon,
                                    spread=hc.spread_epsilon, cluster_receivers=hc.cluster_receivers,
                                    closure_reflectance=hc.closure_reflectance)


def out_of_core_options(cfg: Config, resume: bool = False, reuse_links: bool = False) -> "_engine.OutOfCoreOptions":
    lc = cfg.links
    return _engine.OutOfCoreOptions(store=str(cfg.link_store()), memory_budget=lc.memory_budget,
                                    group_faces=lc.group_faces, checkpoint_seconds=lc.checkpoint_seconds,
                                    resume=resume, reuse_links=reuse_links)


def _run(cfg: Config, staging: Path, rep: Reporter, source: Path | None = None, resume: bool = False,
         reuse_links: bool = False, overrides: tuple[str, ...] = (), remote=None,
         keep_hierarchy: bool = False, held_layers: list | None = None) -> Result:
    wall = time.perf_counter()
    with rep.stage("read scene"):
        # The scene's layers are held until its content key and calculation surfaces are read
        # as well, so that each layer is parsed once, not three times (the scene family's 1.3 M
        # faces in one .usda: 1.7 GB more at the content key, after the solve, than the bake's
        # own peak).
        scene_layers = held_layers.pop() if held_layers else files.scene_files(cfg.scene)[1]
        scene, specs = read_inputs(cfg)
        content_key = cfg.content_key()
        day_lights, day_groups = daylight_inputs(cfg, scene, source)  # its warnings join the scene's
    for w in scene.warnings:
        rep.warn(w)
    for w in cfg.ignored_settings():
        rep.warn(w)
    if len(scene.face_mesh) < MAPPED_BLOCKS_FACES:
        map_blocks_from(MAPPED_FROM_LARGE)  # time, not memory, is what limits a bake this small
    est = estimate_cost(scene, cfg)  # a bake expected not to fit says so before it starts
    if est.get("machine_bytes") and est["memory_bytes"] > est["machine_bytes"]:
        rep.warn(memory_warning(est))
    grids = _build_config_grids(cfg, scene, source)
    del scene_layers

    with rep.stage("build scene"):
        model = build_engine(scene)
        stats = model.stats()
        scene.corner_uv = None  # the engine has them; nothing else reads them (the kitchen: 137 MB)
    luminaires = [s.to_engine() for s in specs] + [d.to_engine() for d in day_lights]
    if luminaires:
        model.set_luminaires(luminaires)
    if day_groups:  # daylight coefficients: each sky patch and the ground solved alone on the links
        # (their lights interleaved over the elements' points as one sky: luminaire.h)
        model.set_light_groups([[] for _ in day_groups], [[g.to_engine(interleave=True)] for g in day_groups])
    light_groups = None
    if cfg.light_groups:  # hirad.relight: each group solved alone on the shared links
        from . import relight
        light_groups = relight.resolve_groups(cfg, scene, specs, rep.warn, day_lights)  # the sun and sky too
        group_luminaires = [[luminaires[i] for i in g.luminaires] for g in light_groups]
        model.set_light_groups([g.meshes for g in light_groups], group_luminaires)
    skipped = {k: getattr(stats, k) for k in ("degenerate_faces", "nonfinite_faces", "self_intersecting_faces",
                                              "nonmanifold_edges") if getattr(stats, k)}
    if skipped:
        rep.warn(f"{cfg.scene}: " + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in skipped.items())
                 + " (degenerate, non-finite and self-intersecting faces skipped; non-manifold edges kept)")
    if stats.faces == 0:
        raise BakeError(f"{cfg.scene}: no usable faces (all {stats.input_faces} were degenerate, not finite "
                        "or self-intersecting)")
    # The report's count and the scene's fingerprint, taken now: without grids or light groups
    # nothing after this reads the faces' materials, and without lightmaps nothing reads the
    # scene's per-face and per-corner arrays at all (the engine holds its own copy), so they are
    # let go (the kitchen: about 150 MB).
    emitter_meshes = sum(1 for m in scene.meshes if m.is_light) + len({
        int(scene.face_mesh[f]) for f in np.nonzero(scene.face_emission.max(axis=1) > 0)[0]
        if not scene.meshes[int(scene.face_mesh[f])].is_light})
    scene_fingerprint(scene)  # kept on the scene: the volume's and the lightmaps' files name it
    if not (grids or cfg.light_groups or day_groups):
        # (lightmaps read the faces' corners, meshes and source faces, not their materials: 56
        # bytes a face, the kitchen's 59 MB)
        geometry = ("points", "face_vertex_counts", "face_vertex_indices", "face_mesh", "face_source")
        for k in ("face_reflectance", "face_emission", "face_transmittance") + (
                () if cfg.outputs.lightmaps.enabled else geometry):
            setattr(scene, k, None)

    values = cfg.reconstruction.values
    if values == "auto":
        values = "final_gather" if cfg.method == "hierarchical" else "patches"
    # The solved hierarchy (its nodes, faces, BVH and links: about 0.7 GB on the 1M-triangle
    # kitchen) is kept only while an output still gathers from it: the vertex gather and
    # final-gather lightmaps, until they are done; light groups and daylight coefficients
    # throughout; or the caller's Result.gather (keep_hierarchy).
    gathering = {"vertex gather": values == "final_gather" and not cfg.light_groups,
                 "lightmaps": cfg.outputs.lightmaps.enabled and cfg.outputs.lightmaps.mode == "final_gather"}

    # Light groups and daylight coefficients solve on after the bake's solve, and a caller's kept
    # hierarchy may: then the input faces and the hierarchy stay.
    solves_again = bool(keep_hierarchy or light_groups or day_groups)

    def hierarchy_unneeded() -> bool:
        return cfg.method == "hierarchical" and not solves_again and not any(gathering.values())

    def done_gathering(stage: str | None = None) -> None:
        if stage:
            gathering[stage] = False
        if hierarchy_unneeded() and model.has_hierarchy:
            model.release_hierarchy()
            release_free_memory()

    # Final-gather lightmaps are baked right after the solve, before the leaves are published as
    # the patches and before the reconstruction: the pages need the source meshes and the
    # hierarchy, which is held for them anyway, and the gather finds its leaves through the
    # hierarchy's own faces and BVH. The published leaves (a second copy of the surfaces and
    # their BVH), the patch arrays, the display mesh, the Result and the per-mesh output arrays
    # then come after the hierarchy and its links are let go (the 1M-triangle kitchen end to
    # end: peak 4,396 -> 3,093 MiB with the reconstruction after the pages, bench/README.md).
    early_lightmaps = (cfg.outputs.lightmaps.enabled and not light_groups and cfg.method == "hierarchical"
                       and cfg.outputs.lightmaps.mode == "final_gather")
    early_pages = None
    if cfg.method == "hierarchical":
        # (hierarchy_unneeded: let go as soon as the leaves are the patches, when nothing gathers;
        # the input faces as soon as the hierarchy holds its copy, when nothing solves again)
        solved, patches = _solve_hierarchical(cfg, model, rep, resume, reuse_links, remote, hierarchy_unneeded,
                                              publish=not early_lightmaps, release_scene=not solves_again)
        b, h, escaped = solved.radiosity, solved.irradiance, solved.escaped
        snapshot_cb = None
        glazing = solved  # the backs of glazed faces and what passes through glass
        if early_lightmaps:
            with rep.stage("lightmaps"):
                leaves = model.leaf_arrays()
                early_pages = bake_lightmaps(cfg, scene, {"mesh": leaves.mesh, "area": leaves.area}, staging,
                                             **lightmap_sources(cfg, model=model))
                del leaves
                # The pages are done: the hierarchy goes as soon as the leaves are copied out of
                # it, before the patch arrays are made (unless another output still gathers), and
                # within the stage, whose held memory is then without it.
                gathering["lightmaps"] = False
                patches = _publish_leaves(model, solved, hierarchy_unneeded)
    else:
        solved, patches, b, h, escaped, snapshot_cb = _solve_flat(cfg, model, scene, staging, rep)
        glazing = None
        if np.any(patches["transmittance"] > 0):
            rep.warn(f"{cfg.scene}: method: flat treats glass as opaque to interreflected light (the sun's and "
                     f"sky's direct light still passes it); method: hierarchical passes it in direction")
    # The irradiance from the surfaces plus the luminaires' direct light (their first bounce).
    h = np.asarray(h) + patches["direct"]
    grouped = None
    if light_groups:
        with rep.stage("light groups"):
            grouped = relight.group_solutions(cfg, model, solved, patches, light_groups)
        grouped.luminaires = group_luminaires
        # The total is the groups' weighted sum (dimmer x color), so relighting is exact.
        b_solved = np.asarray(b)
        b, h = grouped.total(grouped.radiosity), grouped.total(grouped.irradiance)
        escaped = np.divide(np.asarray(escaped) * b, b_solved, out=np.zeros_like(b), where=b_solved != 0)
        patches = dict(patches, emission=grouped.total(grouped.emission))
        base_specs = specs
        specs = relight.weighted_specs(specs, light_groups)
        luminaires = [s.to_engine() for s in specs] + [
            d.to_engine() for d in relight.weighted_day_lights(day_lights, light_groups, len(specs))]
    n = model.num_patches
    method = cfg.solver.method
    ff = cfg.formfactors
    if not solved.converged:
        rep.warn(f"solver stopped after {solved.iterations} iterations at residual "
                 f"{solved.residual:.3e}, above the tolerance {cfg.solver.tolerance:g}")
    if day_lights:
        # Daylight has no flux of its own: what enters is the direct light the surfaces receive
        # (sun and sky through the openings, and the luminaires' received part).
        balance = energy_balance(patches, b, h, escaped, received_as_emitted=True, glazing=glazing)
    else:
        balance = energy_balance(patches, b, h, escaped,
                                 luminaire_flux=(np.asarray(model.luminaire_flux)[0] if not grouped else
                                                 np.sum([s.flux for s in specs], axis=0)) if luminaires else None,
                                 glazing=glazing)

    with rep.stage("reconstruct"):
        display = display_dict(model.display_arrays(cfg.reconstruction.crease_angle))
        vertex_radiance = model.vertex_values(b) / np.pi
        vertex_irradiance = model.vertex_values(h)
        if grouped:
            # The reconstruction clamps (extrapolated boundary vertices): the total's vertex
            # values are the groups' weighted sum, as relighting makes them.
            grouped.vertex = [(model.vertex_values(bg) / np.pi, model.vertex_values(hg))
                              for bg, hg in zip(grouped.radiosity, grouped.irradiance)]
            vertex_radiance = grouped.total([v[0] for v in grouped.vertex])
            vertex_irradiance = grouped.total([v[1] for v in grouped.vertex])
    faces = display["faces"]

    def make_result(v_radiance, v_irradiance):  # indexed: the display mesh's points, faces and vertex values
        return Result(nv=display["face_nv"].astype(np.int32), points=display["points"],
                      faces=np.asarray(faces, dtype=np.int32), point_radiance=v_radiance, point_irradiance=v_irradiance,
                      cameras=scene.cameras, up_axis=scene.up_axis, patch_radiosity=b, patch_irradiance=h,
                      patches=PatchTable(patches, display["points"], display["corners"]), _model=model,
                      hierarchical=cfg.method == "hierarchical",
                      emitted_radiance=np.ascontiguousarray(patches["emission"][display["face_patch"]] / np.pi),
                      luminaires=luminaires,
                      transmittance=np.ascontiguousarray(patches["transmittance"][display["face_patch"]]))

    # The Result holds the display mesh indexed (about 90 bytes a face; its corners and corner
    # values spelled out took 288): the one the bake keeps is made after the engine's patches are
    # let go, and the one the vertex gather reads is dropped before it (one floor of the bench
    # building: the write-USD stage held both the engine's patches and the spelled-out one, 193
    # MiB over the reconstruction).
    result = None
    display_info = None
    if values == "final_gather" and grouped:
        rep.warn("reconstruction.values: final_gather is not applied to bakes with light groups yet: their vertex "
                 "values are the patches' (the seed's vertex rule); the lightmaps' final gather is per group")
    elif values == "final_gather":
        from .outputs.vertex_values import gathered_vertex_values

        rc = cfg.reconstruction
        refine = rc.refine_levels if not day_groups else 0  # daylight coefficients read the engine's mesh
        with rep.stage("vertex gather"):
            display, g_rad, g_irr, gathered = gathered_vertex_values(
                make_result(vertex_radiance, vertex_irradiance), display, patches, rays=rc.gather_rays,
                importance=rc.gather_importance, sample_offset=cfg.outputs.lightmaps.sample_offset, refine_levels=refine,
                refine_tolerance=rc.refine_tolerance, second_bounce=rc.gather_second_bounce)
        n_old = len(vertex_radiance)
        if len(display["points"]) > n_old:  # refinement's new points: their face's patch, by the vertex rule's
            owner = np.zeros(len(display["points"]), np.int64)        # fallback where a gather found nothing
            owner[np.asarray(display["faces"]).reshape(-1)] = np.repeat(display["face_patch"], 4)
            vertex_radiance = np.concatenate([vertex_radiance, np.asarray(b)[owner[n_old:]] / np.pi])
            vertex_irradiance = np.concatenate([vertex_irradiance, np.asarray(h)[owner[n_old:]]])
        faces = display["faces"]
        found = np.isfinite(g_rad).all(axis=1)
        vertex_radiance = np.where(found[:, None], g_rad, vertex_radiance)
        vertex_irradiance = np.where(found[:, None], g_irr, vertex_irradiance)
        if gathered["unfound"]:
            rep.warn(f"reconstruction.values: final_gather: {gathered['unfound']} display points found no surface to "
                     f"gather on ({gathered['unfilled']} vertices kept the patches' values)")
        display_info = gathered
    done_gathering("vertex gather")
    if cfg.method == "hierarchical" and not (model.has_hierarchy or grouped or day_groups):
        # Every output from here on reads the Result's and the per-mesh arrays, not the engine's
        # patches: they, their BVH and the display mesh go before the layer and the preview's
        # field are made (the 1M-triangle kitchen: 0.45 GB less at the preview).
        model.release_patches()
        release_free_memory()
    result = make_result(vertex_radiance, vertex_irradiance)

    outputs: dict[str, object] = {}
    meshes, mesh_faces = patch_meshes(scene, patches, display, vertex_radiance, vertex_irradiance, b, h)
    for pm, fids in zip(meshes, mesh_faces):  # the emitters, for `hirad grid` on the stored layer
        pm.face_emission = patches["emission"][display["face_patch"][fids]]
    if grouped:
        group_store = _group_meshes(model, scene, patches, display, grouped, meshes)
    lightmaps_info = None
    if cfg.outputs.lightmaps.enabled and grouped:
        with rep.stage("lightmaps"):
            outputs["lightmaps"], outputs["lightmap_atlas"], lightmaps_info = _group_lightmaps(
                cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces, staging, result, rep.warn,
                model, grouped, group_store)
    elif early_pages is not None:
        with rep.stage("lightmap layout"):  # the pages' UVs on the output meshes, the manifest
            outputs["lightmaps"], outputs["lightmap_atlas"] = attach_lightmaps(
                early_pages, cfg, scene, patches, display, meshes, mesh_faces, staging, rep.warn)
        early_pages = None
    elif cfg.outputs.lightmaps.enabled:
        with rep.stage("lightmaps"):
            outputs["lightmaps"], outputs["lightmap_atlas"] = write_lightmaps(
                cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces, staging, result, rep.warn)
    done_gathering("lightmaps")
    if cfg.outputs.volume.enabled:
        with rep.stage("irradiance volume"):
            outputs["volume"] = write_volume(cfg, result, scene, staging)
    if cfg.outputs.usd:
        with rep.stage("write USD"):
            path = staging / "solution.usda"
            meta = {"hirad:version": __version__, "hirad:config": cfg.fingerprint(),
                    "hirad:units": units.layer_units(cfg.units)}
            if any(not l.is_distant for l in luminaires):  # the sun and sky go to daylight.npz
                save_luminaires([l for l in luminaires if not l.is_distant], staging / LUMINAIRES_FILE)
                meta["hirad:luminaires"] = LUMINAIRES_FILE
            from .studies.usdgrids import save_stored_daylight  # glazing, sun and sky, for `hirad grid`
            meta.update(save_stored_daylight(staging, day_lights, result.transmittance, result.corners, result.nv,
                                             mesh_faces, groups=light_groups, n_specs=len(specs)))
            usd.write_solution_layer(cfg.scene, path, scene, meshes, meta, view=cfg.outputs.usd_view)
            outputs["usd"] = "solution.usda"
            outputs["usd_arrays"] = usd.solution.arrays_path(path).name  # its arrays, sublayered
    if not grouped:  # only the light groups' files read the per-mesh arrays after this
        meshes = mesh_faces = None
        release_free_memory()
    if cfg.outputs.gltf:  # the config requires usd and lightmaps with it
        from .outputs.gltf import write_glb

        with rep.stage("glTF"):
            outputs["gltf"] = write_glb(staging, uv_set=cfg.outputs.lightmaps.uv_set, warn=rep.warn).name
    if cfg.outputs.preview.enabled:
        with rep.stage("preview"):
            pv = cfg.outputs.preview
            try:
                img = result.render(pv.camera, pv.width, pv.height, pv.samples)
            except BakeError as e:
                raise BakeError(f"outputs.preview.camera: {e}") from None
            _engine.write_exr(str(staging / "preview.exr"), np.ascontiguousarray(img, dtype=np.float32),
                              [("hirad:units", "exitant " + units.label(cfg.units, "radiance"))])
            images.write_png(staging / "preview.png", img)
            outputs["preview"] = ["preview.png", "preview.exr"]
    if snapshot_cb:
        outputs["snapshots"] = "snapshots/"
    grid_report = None
    grids_info = None
    if grids:
        with rep.stage("grids", total=len(grids)) as update:
            if grouped:
                evaluator, grids_info = _group_grid_evaluator(cfg, scene, grids, result, grouped, group_store)
            else:
                evaluator = result.illuminance_evaluator(cfg.grid_rays, cfg.seed)
            results = evaluate_grids(grids, evaluator, maintenance_factor=cfg.maintenance_factor)
            update(len(grids), f"{len(grids)} grids")
        daylight = {}  # before the study report, which shows them
        if cfg.daylight.daylight_factor:
            from .daylight import study as daylight_study

            with rep.stage("daylight factor"):
                daylight["daylight_factor"] = daylight_study.daylight_factor(
                    results, day_lights, scene.up_axis, staging / "grids" / "daylight_factor")
        if day_groups:
            with rep.stage("annual daylight"):
                daylight["annual"] = _annual_daylight(cfg, scene, model, solved, result, display, grids, day_groups,
                                                      staging / "grids" / "annual")
        with rep.stage("grid report"):
            grid_report = write_grid_study(
                results, staging / "grids", units=cfg.units, maintenance_factor=cfg.maintenance_factor,
                seed=cfg.seed, rays=cfg.grid_rays, title=f"Lighting study: {Path(cfg.scene).name}",
                solver={"method": f"{cfg.method}, {method}", "iterations": solved.iterations,
                        "residual": solved.residual, "tolerance": cfg.solver.tolerance,
                        "energy balance (max relative error)": balance.get("max_relative_error")},
                warn=rep.warn, luminaires=_luminaire_schedule(specs, patches),
                luminance=_luminance_image(cfg, result, scene, rep.warn), daylight=daylight)
        outputs["grids"] = "grids/"
        if grids_info is not None:
            grids_info.update(units=cfg.units, maintenance_factor=cfg.maintenance_factor, seed=cfg.seed,
                              rays=cfg.grid_rays, title=f"Lighting study: {Path(cfg.scene).name}",
                              solver={"method": f"{cfg.method}, {method}", "iterations": solved.iterations,
                                      "residual": solved.residual, "tolerance": cfg.solver.tolerance},
                              luminaires=_luminaire_schedule(specs, patches))
    if grouped:
        relight.save_groups(staging, light_groups, meshes, group_store["per_group"], grids_info=grids_info,
                            lightmaps_info=lightmaps_info, units=cfg.units, version=__version__,
                            preview=None if not cfg.outputs.preview.enabled else {
                                k: getattr(cfg.outputs.preview, k) for k in ("camera", "width", "height", "samples")},
                            seconds=grouped.solve_seconds, specs=base_specs,
                            names=[scene.meshes[pm.mesh_index].name for pm in meshes])
        outputs["light_groups"] = [relight.GROUPS_FILE, relight.VALUES_FILE]

    stats = model.stats()
    hierarchical = cfg.method == "hierarchical"
    report = {
        "hirad_version": __version__,
        "method": cfg.method,
        "config": str(source) if source is not None else None,
        "config_fingerprint": cfg.fingerprint(),
        # what determines the result (scene files' contents, the settings but not the output
        # path nor the thread count): hirad.config.content
        "content_key": content_key,
        "overrides": list(overrides),
        "scene": str(cfg.scene),
        "threads": cfg.thread_count(),
        "timings_s": {**rep.timings, "total": round(time.perf_counter() - wall, 4)},
        "peak_rss_mib": dict(rep.peak_rss_mib),
        "held_rss_mib": dict(rep.held_rss_mib),
        "counts": {
            "meshes": len(scene.meshes),
            "input_faces": stats.input_faces,
            "faces": stats.faces,
            "patches": n,
            "emitter_patches": int(np.count_nonzero(patches["emission"].max(axis=1) > 0)),
            "emitter_meshes": emitter_meshes,
            "links": solved.links if hierarchical else stats.links,
            "link_bytes": stats.link_bytes,
            "rays": stats.rays + (solved.rays if hierarchical else 0),
            "skipped": {k: getattr(stats, k) for k in ("degenerate_faces", "nonfinite_faces",
                                                       "self_intersecting_faces")},
            "nonmanifold_edges": stats.nonmanifold_edges,
        },
        "solver": {
            "method": method,
            "form_factors": ("hierarchical links" if cfg.method == "hierarchical"
                             else ff.method if method != "progressive" else "raycast, on the fly"),
            "iterations": solved.iterations,
            "residual": solved.residual,
            "tolerance": cfg.solver.tolerance,
            "converged": solved.converged,
            "rows_computed": 0 if hierarchical else solved.rows_computed,
            # The relative residual per iteration, thinned to at most 200 (iteration, residual)
            # pairs so long shooting runs stay readable; the last iteration is always kept.
            "residual_history": _thin(solved.residual_history, 200),
        },
        "hierarchy": None if cfg.method != "hierarchical" else {
            **{k: getattr(solved, k) for k in ("rounds", "settled", "elements", "clusters", "nodes", "links_per_round",
                                     "splits_per_round", "link_estimates", "refine_seconds", "solve_seconds",
                                     "epsilon_watts", "balance_splits", "limited_leaves",
                                     "normalised_leaves", "face_bytes", "bvh_bytes", "bvh_peak_bytes")},
            # Links that end on clusters (hierarchy.cluster_receivers); None out of core (not counted).
            "links_on_clusters": solved.links_on_clusters if solved.links_on_clusters >= 0 else None},
        "links": None if not (hierarchical and solved.out_of_core) else {
            "store": str(cfg.link_store()),
            "reused": solved.reused_links,
            "form_factors_computed": solved.link_estimates,
            "resumed_from_round": solved.resumed_from_round,
            "source_groups": solved.source_groups,
            "memory_budget_bytes": cfg.links.memory_budget,
            "store_bytes": solved.store_bytes,
            "bytes_per_link": solved.store_bytes / max(1, solved.links),
            "transport_bytes": solved.transport_bytes,
            "peak_refine_links": solved.peak_refine_links,
            "last_solve": streaming_dict(solved.streaming),
            "distributed": None if remote is None else dict(remote.summary(),
                                                            merge_seconds=list(solved.merge_seconds)),
        },
        "energy_balance": balance,
        # the written display mesh; with values: final_gather, its gather's counts (vertex_values.py)
        "display": {"values": "final_gather" if display_info is not None else "patches",
                    "faces": int(len(display["face_nv"])), "points": int(len(display["points"])),
                    **(display_info or {})},
        "light_groups": None if not grouped else {
            g.name: {"dimmer": g.dimmer, "color": list(g.color), "members": g.members, "residual": r}
            for g, r in zip(light_groups, grouped.residuals)},
        "grids": grid_report,
        "outputs": outputs,
        "warnings": rep.warnings,
    }
    if cfg.outputs.report:
        write_json(staging / "report.json", report)
    result.report = report
    return result


# --------------------------------------------------------------------------------------
# calculation grids
# --------------------------------------------------------------------------------------

# Hemisphere rays per sensor point for the grids' indirect light: hirad grid --rays's default (the
# config's grid_rays has the same default).
GRID_RAYS = 512
UNITS = {
    "photometric": {"illuminance": "lx", "luminance": "cd/m2", "exitance": "lm/m2"},
    "radiometric": {"illuminance": "W/m2", "luminance": "W/(m2 sr)", "exitance": "W/m2"},
}

def _build_config_grids(cfg: Config, scene, source: Path | None) -> list:
    """The config's grids, built before anything is solved (in the scene's up axis); a grid
    that cannot be built is a ConfigError at its key (`grids.NAME`)."""
    from .config import ConfigError
    from .config.errors import DICT_SOURCE
    from .config.loader import config_line

    rooms = {}
    out = []
    for name, spec in cfg.grids.items():
        try:
            room = getattr(spec, "room", None)
            if room is not None and spec.polygon is None and spec.polygons is None and room not in rooms:
                rooms[room] = _room_polygons(cfg.scene, room, scene.up_axis)
            out += build_grids({name: spec}, up_axis=scene.up_axis, rooms=rooms)
        except StudyError as e:
            line = config_line(source, ("grids", name)) if source is not None else 0
            raise ConfigError(str(source) if source is not None else DICT_SOURCE, line, f"grids.{name}",
                              str(e)) from None
    # the scene's own calculation surfaces (hirad:grid on a Mesh or a Plane: studies/usdgrids.py)
    from .studies.usdgrids import grids_from_stage

    try:
        stage_grids = grids_from_stage(str(cfg.scene), scene.up_axis)
    except StudyError as e:
        raise BakeError(f"{cfg.scene}: {e}") from None
    for g in stage_grids:
        if g.name in cfg.grids:
            raise BakeError(f"{cfg.scene}: the calculation surface {g.source} is named {g.name!r}, as the config's "
                            f"grids.{g.name}; rename one of them (hirad:grid:name)")
    return out + stage_grids


def _luminance_image(cfg: Config, result, scene, warn=None):
    """(caption, PNG) of the preview camera's view in cd/m^2 (W/(m^2 sr) radiometric), for the
    study report."""
    from .studies.pictures import camera_luminance_picture

    pv = cfg.outputs.preview
    view = pv.camera or (scene.cameras[0].path if scene.cameras else "the default view")
    unit = "cd/m²" if cfg.units == "photometric" else "W/(m² sr)"
    try:
        png = camera_luminance_picture(result, pv.camera, width=pv.width, height=pv.height, samples=pv.samples,
                                       units=cfg.units)
    except StudyError as e:
        if warn is not None:
            warn(f"grids: no luminance image ({e})")
        return None
    return (f"Luminance of {view} ({unit})", png)


def _room_polygons(stage_path, room: str, up_axis: str) -> list:
    from pxr import Usd

    stage = Usd.Stage.Open(str(stage_path))
    if stage is None:
        raise StudyError(f"room {room}: cannot open {stage_path}")
    return resolve_room(stage, room, up_axis)


def write_grid_study(results, out_dir: Path, *, units: str, maintenance_factor: float, seed: int, rays: int,
                     title: str, solver: dict, subtitle: str = "", warn=None, luminaires=(), luminance=None,
                     daylight=None) -> dict:
    """Writes the evaluated grids into `out_dir` (per grid NAME.csv, NAME.json, NAME.png;
    report.html and, when WeasyPrint works, report.pdf) and returns what report.json says of
    them: units, maintenance factor, seed, rays and each grid's statistics, and `daylight`
    (daylight_factor, annual: written into out_dir already), which the report shows too."""
    from .studies.report import Study, daylight_parts, pdf_engine, units_text, write_report_pdf, write_study

    study = Study(results=results, maintenance_factor=maintenance_factor, title=title, subtitle=subtitle,
                  luminaires=list(luminaires),
                  units=units_text(units), unit_system=units, luminance=luminance,
                  solver={**solver, "units": units, "grid seed": seed, "rays per point": rays},
                  **daylight_parts(out_dir, **(daylight or {}), results=results))
    written = write_study(study, out_dir, pdf=False)
    pdf = None
    if pdf_engine("auto") == "weasyprint":
        try:
            pdf = write_report_pdf(study, out_dir / "report.pdf", "weasyprint")
        except (StudyError, OSError) as e:
            if isinstance(e, files.WriteError):
                raise
            if warn is not None:
                warn(f"grids: report.pdf not written ({e})")
    names = [Path(f).name for f in written["files"]] + (["report.pdf"] if pdf else [])
    return {
        "units": units,
        "quantity": "Y = 0.2126 R + 0.7152 G + 0.0722 B of the illuminance (linear Rec.709)",
        "unit": UNITS[units]["illuminance"],
        "maintenance_factor": maintenance_factor,
        "seed": seed,
        "rays": rays,
        "files": names,
        "grids": {r.name: r.stats.as_dict() for r in results},
        **(daylight or {}),
    }


def _annual_daylight(cfg: Config, scene, model, solved, result, display, grids, groups, out_dir: Path) -> dict:
    """Daylight coefficients of every grid from the sky-patch and sun-bin groups' solutions, then
    the weather file's year by matrix products and the annual metrics (hirad.daylight.study)."""
    from .daylight import study as daylight_study
    from .daylight.sun import Site

    t0 = time.perf_counter()
    y = np.array([0.2126, 0.7152, 0.0722])
    vertex = np.stack([(model.vertex_values(np.asarray(g.radiosity)) / np.pi) @ y for g in solved.groups], axis=1)
    faces = np.ascontiguousarray(display["faces"])
    nv = np.ascontiguousarray(display["face_nv"])
    n_sky = sum(1 for g in groups if g.kind != "sun")  # sky patches and the ground, then the sun bins
    dc_sky, sun_indirect = {}, {}
    for g in grids:
        direct, total = daylight_study.grid_coefficients(result.field, faces, nv, g, vertex, groups, cfg.grid_rays,
                                                         cfg.seed)
        dc_sky[g.name] = total[:, :n_sky]
        sun_indirect[g.name] = total[:, n_sky:] - direct[:, n_sky:]
    t_dc = time.perf_counter() - t0
    dl = cfg.daylight
    tau = np.ascontiguousarray(patches_transmittance(result))
    daylight_study.save_coefficients(
        out_dir / "coefficients.npz",
        {**{f"sky_{k}": v for k, v in dc_sky.items()}, **{f"sun_indirect_{k}": v for k, v in sun_indirect.items()}},
        groups, grids, (np.ascontiguousarray(result.corners), np.ascontiguousarray(result.nv), tau),
        {"patches_mf": dl.reinhart_mf(), "ground_reflectance": dl.ground_reflectance, "up_axis": scene.up_axis,
         "north": None if dl.north is None else list(dl.north),
         "occupied": [dl.annual.occupied_from, dl.annual.occupied_to], "grid_rays": cfg.grid_rays, "seed": cfg.seed})
    site = None
    if dl.site.latitude is not None and dl.site.longitude is not None:
        site = Site(dl.site.latitude, dl.site.longitude, dl.site.elevation, dl.site.timezone)
    north = None if dl.north is None else tuple(dl.north)
    info = daylight_study.annual_results(dc_sky, sun_indirect, {g.name: g for g in grids}, str(dl.annual.weather),
                                         site, dl.reinhart_mf(), dl.ground_reflectance, scene.up_axis, north,
                                         result.field, out_dir, occupied=(dl.annual.occupied_from,
                                                                          dl.annual.occupied_to))
    info["seconds"]["coefficients"] = t_dc
    site_from = "daylight.site" if site is not None else "weather file"
    if site is None:  # the weather file's, as annual_results takes it
        from .daylight.weather import read_weather

        w = read_weather(dl.annual.weather)
        site = Site(float(w.latitude), float(w.longitude), float(w.elevation), w.timezone)
    info["site"] = {"latitude": site.latitude, "longitude": site.longitude, "elevation": site.elevation,
                    "timezone": site.timezone, "from": site_from}
    info["light_groups"] = len(groups)
    info["seconds"]["group_solves"] = float(sum(getattr(g, "seconds", 0.0) for g in solved.groups))
    return info


def patches_transmittance(result) -> np.ndarray:
    """The glazing of a result's display faces (0 where it has none)."""
    t = getattr(result, "transmittance", None)
    return np.zeros(result.face_count) if t is None else np.asarray(t, dtype=np.float64)


def _luminaire_schedule(specs, patches: dict) -> list[dict]:
    """The report's luminaire schedule: the luminaires by type (photometry.luminaires.schedule)
    and the area emitters (emissive surfaces, Rect/Disk/Mesh lights) as one row with their flux."""
    from .photometry.luminaires import schedule

    rows = schedule(specs) if specs else []
    emitting = (patches["emission"] > 0).any(axis=1)
    if emitting.any():
        flux = float(luminance_y((patches["emission"][emitting] * patches["area"][emitting, None]).sum(axis=0)))
        rows.append({"type": "area emitters (Lambertian surfaces)", "count": 1, "lumens": flux, "ies": None,
                     "name": "emissive surfaces"})
    return rows


def _group_meshes(model, scene, patches, display, grouped, meshes) -> dict:
    """Each light group's values on the solution meshes: its primvars (pm.group_values) and the
    arrays relighting keeps (vertex and face radiance and irradiance, face emission)."""
    per_group = {}
    corners = {}
    faces = display["faces"]
    for k, g in enumerate(grouped.groups):
        b_g, h_g, e_g = grouped.radiosity[k], grouped.irradiance[k], grouped.emission[k]
        vr, vi = grouped.vertex[k]
        corners[g.name] = (vr[faces], vi[faces])
        pms, fids_of = patch_meshes(scene, patches, display, vr, vi, b_g, h_g)
        rows = []
        for pm, pm_g, fids in zip(meshes, pms, fids_of):
            pm.group_values = dict(pm.group_values or {})
            pm.group_values[g.name] = (pm_g.vertex_radiance, pm_g.vertex_irradiance)
            rows.append({"vertex_radiance": pm_g.vertex_radiance, "vertex_irradiance": pm_g.vertex_irradiance,
                         "face_radiance": pm_g.face_radiance, "face_irradiance": pm_g.face_irradiance,
                         "face_emission": e_g[display["face_patch"][fids]]})
        per_group[g.name] = {"meshes": rows}
    return {"per_group": per_group, "corners": corners, "face_patch": display["face_patch"]}


def _group_lightmaps(cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces, staging, result, warn,
                     model, grouped, store):
    """The lightmaps with light groups: each group's pages into OUT/groups/<name>/lightmaps/ (for
    hirad relight), then the total's, whose final gather replays the groups' weighted sum."""
    from . import relight

    records = []
    corners = result.corners  # made once from the indexed Result, shared by the groups
    for k, g in enumerate(grouped.groups):
        vr_c, vi_c = store["corners"][g.name]
        emitted = np.ascontiguousarray(grouped.emission[k][display["face_patch"]] / np.pi)
        lums = grouped.luminaires[k]  # the group's own, unweighted
        res_g = relight.group_result(result, model, k, np.ascontiguousarray(vr_c), np.ascontiguousarray(vi_c),
                                     emitted, lums, corners=corners)
        records.append(relight.recording_gather(res_g))
        out_g = staging / relight.GROUPS_DIR / g.name
        out_g.mkdir(parents=True, exist_ok=True)
        vi_g = grouped.vertex[k][1]
        write_lightmaps(cfg, scene, dict(patches, emission=grouped.emission[k]), display, vi_g, meshes, mesh_faces,
                        out_g, res_g, None)
    total = relight.replay_result(result, records, grouped.weights) if cfg.outputs.lightmaps.mode == "final_gather" \
        else result
    written, atlas = write_lightmaps(cfg, scene, patches, display, vertex_irradiance, meshes, mesh_faces, staging,
                                     total, warn)
    from .outputs.meshes import lightmap_units_label

    emission = {}
    for pm in meshes:
        of_mesh = patches["mesh"] == pm.mesh_index
        area = patches["area"][of_mesh][:, None]
        if pm.lightmap_emission is not None and area.sum() > 0:
            emission[scene.meshes[pm.mesh_index].name] = [
                ((e[of_mesh] * area).sum(axis=0) / area.sum() / np.pi).tolist() for e in grouped.emission]
    info = {"pages": atlas["pages"], "mode": atlas["mode"], "emission": emission,
            "metadata": [("hirad:units", lightmap_units_label(cfg.units)), ("hirad:version", __version__),
                         ("hirad:texelsPerMetre", f"{atlas['texels_per_metre']:.9g}"),
                         ("hirad:lightmapMode", atlas["mode"])]}
    return written, atlas, info


def _group_grid_evaluator(cfg, scene, grids, result, grouped, store):
    """The grids with light groups: each group's sensor RGB evaluated alone (kept for hirad
    relight), the total their weighted sum (illuminance is linear in the radiance, the emission
    and the luminaires, and the seeded rays are the same for every group)."""
    import json as _json

    from . import relight
    from .solution import SurfaceSolution

    sols = []
    corners = result.corners  # made once from the indexed Result, shared by the groups
    for k, g in enumerate(grouped.groups):
        vr_c, vi_c = store["corners"][g.name]
        sols.append(SurfaceSolution(corners, result.nv, np.ascontiguousarray(vr_c), np.ascontiguousarray(vi_c),
                                    cameras=result.cameras, up_axis=result.up_axis,
                                    emitted_radiance=np.ascontiguousarray(
                                        grouped.emission[k][store["face_patch"]] / np.pi),
                                    luminaires=list(grouped.luminaires[k]), transmittance=result.transmittance))
    calls = {"k": 0}

    def evaluate(points, normals):
        rgbs = [s.illuminance(points, normals, rays=cfg.grid_rays, seed=cfg.seed) for s in sols]
        for g, rgb in zip(grouped.groups, rgbs):
            store["per_group"][g.name].setdefault("grids", []).append(rgb)
        calls["k"] += 1
        return luminance_y(relight.weighted_sum(rgbs, grouped.weights))

    rooms = {}
    for name, spec in cfg.grids.items():
        room = getattr(spec, "room", None)
        if room is not None and room not in rooms:
            rooms[room] = _json.loads(_json.dumps(_room_polygons(cfg.scene, room, scene.up_axis),
                                                  default=lambda o: np.asarray(o).tolist()))
    info = {"specs": {name: spec.model_dump(mode="json") for name, spec in cfg.grids.items()}, "rooms": rooms,
            "up_axis": scene.up_axis}
    return evaluate, info


def _thin(history: list, most: int) -> list:
    n = len(history)
    keep = sorted(set(np.linspace(0, n - 1, min(n, most)).round().astype(int).tolist())) if n else []
    return [[i + 1, history[i]] for i in keep]


def _solve_flat(cfg: Config, model, scene, staging: Path, rep: Reporter):
    """The classic method: patches from `meshing`, links between every pair that can exchange
    light, the configured solver, then irradiance and escaped power per patch."""
    with rep.stage("mesh patches"):
        model.mesh(_engine.MeshOptions(max_patch_area=cfg.meshing.max_patch_area,
                                       max_edge_length=cfg.meshing.max_edge_length))
        patches = patch_dict(model.patch_arrays())
    n = model.num_patches
    method = cfg.solver.method
    ff = cfg.formfactors
    ff_options = _engine.FormFactorOptions(method=ff.method, samples=ff.samples,
                                           hemicube_resolution=ff.hemicube_resolution,
                                           hemicube_points=ff.hemicube_points, seed=cfg.seed)
    if method != "progressive":
        with rep.stage("form factors", total=n) as update:
            model.compute_links(ff_options, lambda done: update(done, f"{done}/{n} patches"))

    snapshot_cb = None
    if method == "progressive" and cfg.solver.snapshots > 0:
        snapshot_dir = staging / "snapshots"
        snapshot_dir.mkdir()
        snap_corners = model.display_mesh(cfg.reconstruction.crease_angle).corners

        def snapshot_cb(shot: int, display: np.ndarray) -> None:
            # The image displayed at each iteration: B + rho * ambient, as Cohen et al. show it.
            radiance = (model.vertex_values(display) / np.pi)[snap_corners]
            sol = SurfaceSolution(patches["corners"], patches["nv"], radiance, radiance,
                                  cameras=scene.cameras, up_axis=scene.up_axis)
            img = sol.render(cfg.outputs.preview.camera, 256, 256, 1)
            images.write_png(snapshot_dir / f"shot_{shot:08d}.png", img)

    with rep.stage("solve", total=1.0) as update:
        solved = model.solve(_engine.SolveOptions(method=method, tolerance=cfg.solver.tolerance,
                                                  max_iterations=cfg.solver.max_iterations,
                                                  snapshot_every=cfg.solver.snapshots),
                             ff_options, snapshot_cb, _solve_progress(cfg, update))
    b = solved.radiosity
    with rep.stage("irradiance"):
        transport = model.transport(b, ff_options)
    return solved, patches, b, transport.irradiance, transport.escaped, snapshot_cb


def _solve_hierarchical(cfg: Config, model, rep: Reporter, resume: bool = False, reuse_links: bool = False,
                        remote=None, let_go=None, publish: bool = True, release_scene: bool = False):
    """Hierarchical radiosity with clustering: refine, solve with push-pull, refine again;
    the leaf elements become the model's patches (with `publish`; otherwise the caller
    publishes them with _publish_leaves, and the patches returned are None)."""
    hc = cfg.hierarchy
    with rep.stage("hierarchical solve", total=1.0) as update:
        solve_progress = _solve_progress(cfg, update)

        def on_progress(round_: int, links: int, iteration: int, residual: float, linked: int = 0,
                        groups: int = 0) -> None:
            if round_ == 0 and links == 0:  # before round 1 (or before a reused store's solve)
                update(None, "preparing the hierarchy" + (" and reading the link store" if resume or reuse_links else ""))
            elif groups and linked < groups:
                update(None, f"round {round_}: linking, {linked}/{groups} source groups, {links:,} links so far")
            elif groups:
                update(None, f"round {round_}: {links:,} links made, solving")
            else:
                solve_progress(iteration, residual, f"round {round_}, {links:,} links, ")

        hierarchy = hierarchy_options(cfg)
        hierarchy.release_scene = release_scene
        solve = _engine.SolveOptions(method=cfg.solver.method, tolerance=cfg.solver.tolerance,
                                     max_iterations=cfg.solver.max_iterations)
        if cfg.solver.method == "block_southwell":
            store = cfg.link_store()
            out_of_core = out_of_core_options(cfg, resume, reuse_links)
            if remote is not None:
                remote.on_event = lambda e: update(None, f"round {e['round']}: links on the cluster, "
                                                         f"{e['done']}/{e['ranges']} ranges of source groups")
            try:
                solved = model.solve_out_of_core(hierarchy, solve, out_of_core, on_progress, remote)
            except RuntimeError as e:
                raise BakeError(f"link store {store}: {e}") from None
        else:
            if resume or reuse_links:
                raise BakeError("--resume and --reuse-links need the out-of-core solver (solver.method: block_southwell)")
            solved = model.solve_hierarchical(hierarchy, solve, on_progress)
    if solved.reused_links:
        rep.warn(f"links reused from {cfg.link_store()}: {solved.links} links, no form factor computed")
    if not solved.settled and solved.rounds >= hc.max_rounds:
        rep.warn(f"hierarchy.max_rounds ({hc.max_rounds}) reached while links still wanted to split")
    if solved.limited_leaves:
        rep.warn(f"{solved.limited_leaves} elements have reflectance x (the sum of their link estimates) above 0.999 "
                 f"(sampled estimates can sum above the hemisphere's 1), where the solve would not converge: their "
                 f"gathered light was scaled to that limit (raise hierarchy.samples, or lower reflectances near 1)")
    return solved, (_publish_leaves(model, solved, let_go) if publish else None)


def _publish_leaves(model, solved, let_go=None) -> dict:
    """The leaves become the engine's patches (the outputs reconstruct, gather and probe on
    them); when `let_go()` says nothing gathers any more, the hierarchy goes as soon as they
    are copied out of it. Returns the patch arrays."""
    release = bool(let_go is not None and let_go())
    model.use_leaves_as_patches(release_hierarchy=release)
    if release:
        release_free_memory()
    # per leaf, the share of its area outside other geometry: its B, H and direct light are that
    # part's, so its powers are over open x area (energy balance). No output of a hierarchical
    # bake reads the leaves' corners: the Result's PatchTable makes them from the display mesh.
    arrays = patch_dict(model.patch_arrays())
    del arrays["corners"]
    return dict(arrays, open=np.asarray(solved.open, dtype=np.float64))


def _solve_progress(cfg: Config, update):
    """Progress of an iterative solve as the fraction of the way, in log residual, to the
    tolerance."""
    def on_progress(iteration: int, residual: float, prefix: str = "") -> None:
        if residual <= 0:
            done = 1.0
        else:
            done = 0.0 if residual >= 1 else min(1.0, np.log(residual) / np.log(cfg.solver.tolerance))
        update(done, f"{prefix}iteration {iteration}, residual {residual:.2e}")
    return on_progress


