"""The `hirad` command: a thin layer over the Python API (hirad.bake, hirad.load_solution).

Every error is one line on stderr, `hirad: error: <file or option>: <problem>`, and no
traceback (set HIRAD_DEBUG=1 to see one). Exit codes:

    0    done
    1    internal error: an exception hirad did not expect (a bug; please report it with the
         HIRAD_DEBUG=1 traceback)
    2    usage or config error: a bad option or config value, an option that does not apply,
         an output or link store hirad refuses to write (an input, a directory it did not make)
    3    scene error: the USD scene (or a solution layer) cannot be used
    4    the run failed: the bake could not finish (a solve that diverged: the message names
         the meshes of reflectance near 1 and the config keys to change), an output could not
         be written (disk full, permissions), not enough memory
    5    hirad batch: some jobs failed or were cancelled (the others are done; `hirad batch
         status STUDY.yaml` says which and why)
    130  interrupted by SIGINT (Ctrl-C); the partial output is removed
    143  terminated by SIGTERM; the partial output is removed

A link store is kept after 130/143 so that `hirad bake --resume` can continue. With `--json`
(bake, batch) an error is also one JSON object on stdout: {"error": {"exit_code", "kind",
"message", ...}}.
"""

from __future__ import annotations

import csv
import io
import math
import os
import sys
import traceback
from pathlib import Path
from typing import Optional

import numpy as np
import typer

EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_SCENE, EXIT_FAILED = 0, 1, 2, 3, 4

app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode=None,
                  pretty_exceptions_enable=False,
                  help="hirad: radiosity for USD scenes. Units: luminance cd/m^2 and illuminance lux (photometric, the default), or W/(m^2 sr) and W/m^2 (units: radiometric).")

IMAGE_SUFFIXES = {".png": "PNG", ".exr": "EXR", ".jpg": "JPEG", ".jpeg": "JPEG"}


# `--json` (bake, batch): errors also as one JSON object on stdout, where the result would be:
# {"error": {"exit_code": 2, "kind": "usage", "message": "...", ...}} (a config error adds
# file, line, key, problem and every problem found as `problems`).
_json_errors = False
_KINDS = {1: "internal", 2: "usage", 3: "scene", 4: "failed", 5: "batch_jobs_failed", 130: "interrupted",
          143: "terminated"}


def _json_error(message: str, code: int, details: dict | None = None) -> None:
    if _json_errors:
        import json

        print(json.dumps({"error": {"exit_code": code, "kind": _KINDS.get(code, "error"), "message": message,
                                    **(details or {})}}), flush=True)


def _fail(message: str, code: int = EXIT_USAGE, details: dict | None = None) -> None:
    print(f"hirad: error: {message}", file=sys.stderr, flush=True)
    _json_error(message, code, details)
    raise typer.Exit(code)


def _config_details(e) -> dict:
    one = lambda x: {"file": x.file, "line": x.line, "key": x.key, "problem": x.problem}  # noqa: E731
    return {**one(e), "problems": [one(x) for x in getattr(e, "errors", [e])]}


def _one_line(e: BaseException) -> str:
    """An exception's message on one line (nanobind's TypeError lists every overload: the
    first line says what was wrong)."""
    text = str(e).strip()
    first = text.splitlines()[0].strip() if text else ""
    if isinstance(e, TypeError) and "incompatible function arguments" in first:
        first = first.split(" The following argument types", 1)[0].rstrip(".") + \
            " (a value outside the range the engine takes)"
    return first or type(e).__name__


def _where() -> str:
    from . import report

    return f" during '{report.current_stage}'" if report.current_stage else ""


def _run_guarded(fn):
    """Turns every failure into one clear line on stderr and the exit code of its kind (see the
    module docstring); SIGINT/SIGTERM into 130/143."""
    from . import interrupts
    from .bake import BakeError, OptionError
    from .config import ConfigError
    from .files import UnsafePathError
    from .studies import StudyError
    from .usd import SceneError

    try:
        return fn()
    except (typer.Exit, SystemExit):
        raise
    except interrupts.Interrupted as e:
        interrupts.finished()
        print(f"hirad: {e}; partial output removed", file=sys.stderr, flush=True)
        _json_error(f"{e}; partial output removed", e.exit_code)
        raise typer.Exit(e.exit_code)
    except BaseException as e:
        signum = interrupts.received()
        if signum is not None:  # the interrupt arrived wrapped (through the engine)
            interrupts.finished()
            print(f"hirad: interrupted by signal {signum}; partial output removed", file=sys.stderr, flush=True)
            raise typer.Exit(128 + signum)
        if os.environ.get("HIRAD_DEBUG"):
            traceback.print_exc()
        if isinstance(e, KeyboardInterrupt):
            raise typer.Exit(130)
        if isinstance(e, ConfigError):
            _fail(str(e), EXIT_USAGE, _config_details(e))
        if isinstance(e, (UnsafePathError, OptionError, StudyError)):
            _fail(str(e), EXIT_USAGE)
        if isinstance(e, SceneError):
            _fail(str(e), EXIT_SCENE)
        if isinstance(e, BakeError):
            _fail(str(e), EXIT_FAILED)
        if isinstance(e, MemoryError):
            _fail(f"out of memory{_where()}", EXIT_FAILED)
        if isinstance(e, OSError):
            where = f"{e.filename}: " if e.filename else ""
            _fail(f"{where}{e.strerror or _one_line(e)}", EXIT_FAILED)
        if isinstance(e, Exception):
            _fail(f"internal error{_where()}: {type(e).__name__}: {_one_line(e)} "
                  "(HIRAD_DEBUG=1 shows the traceback)", EXIT_INTERNAL)
        raise


# What the engine's solvers say when a solve diverges (hierarchical_solver.cpp: the residual grew
# a million times over its best) or its radiosity stopped being finite (core/checks.h).
_DIVERGENCE_MARKERS = (": the solve diverges", "the radiosity is no longer finite")


def _diverged(e: BaseException) -> Optional[str]:
    """The engine's message when `e` is a solve that diverged (a RuntimeError from the engine, or
    the out-of-core bake's BakeError wrapping one), else None."""
    from .errors import BakeError

    if not isinstance(e, (RuntimeError, BakeError)):
        return None
    text = _one_line(e)
    return text if any(m in text for m in _DIVERGENCE_MARKERS) else None


def _divergence_advice(config: Path, sets: tuple) -> str:
    """What to change after a diverged solve: the likely cause (a reflectance near 1 where an
    element's sampled link estimates sum above 1) with the meshes whose reflectance is near 1 and
    the config keys that decide it, read from the config and its scene (best effort: a config or
    scene that cannot be read now only shortens the advice)."""
    text = (" -- the likely cause: surfaces of reflectance near 1, whose sampled link (form factor) "
            "estimates sum above 1, so that every bounce returns more light than it received")
    try:
        from . import usd
        from .config import load_config

        cfg = load_config(config, sets)
        scene = usd.read_scene(cfg.scene, default_reflectance=tuple(cfg.materials.default_reflectance),
                               uv_primvars=tuple(cfg.materials.uv_primvars), require_emission=False,
                               ies_mode=cfg.photometry.ies_mode)
    except Exception:  # the advice is a courtesy: the divergence is the error
        return text + ("; lower the reflectance of the brightest materials (at most 0.95 is physical) or "
                       "materials.default_reflectance, or raise hierarchy.samples (formfactors.samples for method: "
                       "flat) for better link estimates")
    refl = np.asarray(scene.face_reflectance, dtype=np.float64).max(axis=1) if scene.num_faces else np.zeros(0)
    high: dict[str, float] = {}
    for f in np.flatnonzero(refl >= 0.95):
        path = scene.meshes[int(scene.face_mesh[f])].path
        high[path] = max(high.get(path, 0.0), float(refl[f]))
    keys = []
    if high:
        shown = sorted(high.items(), key=lambda kv: -kv[1])
        names = ", ".join(f"{p} ({r:.3g})" for p, r in shown[:6]) + (f" and {len(shown) - 6} more" if len(shown) > 6 else "")
        keys.append(f"lower the reflectance of the materials on {names} (at most 0.95 is physical)")
    if max(cfg.materials.default_reflectance) >= 0.95:
        keys.append(f"lower materials.default_reflectance (now {list(cfg.materials.default_reflectance)})")
    if cfg.method == "flat":
        keys.append(f"raise formfactors.samples (now {cfg.formfactors.samples}) for better form factor estimates")
    else:
        keys.append(f"raise hierarchy.samples (now {cfg.hierarchy.samples}) for better link estimates")
    return text + "; " + "; or ".join(keys)


def _version(value: bool) -> None:
    if value:
        from . import __version__

        print(f"hirad {__version__}")
        raise typer.Exit()


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit")):
    """hirad: radiosity for USD scenes. Units: luminance cd/m^2 and illuminance lux (photometric, the default), or W/(m^2 sr) and W/m^2 (units: radiometric)."""


def _finite(name: str, value: float | None, positive: bool = True) -> None:
    if value is None:
        return
    if not math.isfinite(value) or (positive and value <= 0):
        _fail(f"{name} must be a finite number{' above 0' if positive else ''}, got {value!r}")


def _solution_inputs(solution: Path) -> list[tuple[str, Path]]:
    """The solution layer and every file it depends on (layers, assets such as lightmaps)."""
    out = [("solution", solution)]
    try:
        from pxr import UsdUtils

        layers, assets, _ = UsdUtils.ComputeAllDependencies(str(solution))
        out += [("layer of the solution", Path(layer.realPath)) for layer in layers if layer.realPath]
        out += [("asset of the solution", Path(a)) for a in assets if a]
    except Exception:  # an unreadable solution: loading it reports the problem
        pass
    return out


@app.command()
def bake(config: Path = typer.Argument(..., help="YAML config"),
         threads: Optional[int] = typer.Option(None, "--threads", min=0, help="Worker threads (0 = all cores)"),
         snapshots: Optional[int] = typer.Option(None, "--snapshots", min=0,
                                                 help="Progressive refinement: a preview image every N shots"),
         quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output"),
         as_json: bool = typer.Option(False, "--json", help="Print the run report as JSON on stdout"),
         resume: bool = typer.Option(False, "--resume",
                                     help="Out of core: continue what a killed bake of the same inputs left"),
         reuse_links: bool = typer.Option(False, "--reuse-links",
                                          help="Out of core: solve on the stored links (same geometry and "
                                               "refinement settings; new materials), computing no form factor"),
         sets: list[str] = typer.Option([], "--set", metavar="KEY=VALUE",
                                        help="Override a config key (dotted: meshing.max_patch_area=0.02, "
                                             "lights[0].intensity=100; the value is YAML); repeatable"),
         progress: str = typer.Option("auto", "--progress",
                                      help="Progress on stderr: auto (bars on a terminal, a plain line every few "
                                           "seconds otherwise), bar, plain, jsonl (JSON lines: stage, fraction, "
                                           "elapsed, eta) or none"),
         scheduler: Optional[str] = typer.Option(None, "--scheduler",
                                                 help="Out of core: generate the links on this Dask cluster, "
                                                      "tcp://HOST:PORT (workers must see the config, scene and "
                                                      "link store at the same paths); the same bits as without"),
         link_threads: int = typer.Option(1, "--link-threads", min=0,
                                          help="With --scheduler: engine threads per link task (0 = all of a "
                                               "worker's cores)")):
    """Solve a scene and write its outputs (USD layer, lightmaps, preview, report)."""
    import json

    from .bake import bake as run

    global _json_errors
    _json_errors = as_json
    if progress not in ("auto", "bar", "plain", "jsonl", "none"):
        _fail(f"--progress {progress!r}: auto, bar, plain, jsonl or none")
    mode = "none" if quiet or (as_json and progress == "auto") else progress

    def go():
        try:
            return run(config, quiet=mode == "none", threads=threads, snapshots=snapshots, resume=resume,
                       reuse_links=reuse_links, overrides=tuple(sets), progress=mode, scheduler=scheduler,
                       link_threads=link_threads)
        except Exception as e:
            diverged = _diverged(e)
            if diverged is None:
                raise
            from .errors import BakeError

            raise BakeError(f"{config}: {diverged}{_divergence_advice(config, tuple(sets))}") from None

    result = _run_guarded(go)
    if as_json:
        print(json.dumps(result.report, indent=2))
    elif not quiet:
        r = result.report
        eb = r["energy_balance"]["max_relative_error"]
        print(f"{r['counts']['patches']} patches, {r['counts']['links']} links, {r['counts']['rays']} rays; "
              f"{r['solver']['method']}: {r['solver']['iterations']} iterations, residual {r['solver']['residual']:.2e}; "
              f"energy balance {eb:.2e}; {r['timings_s']['total']:.1f} s -> {result.output_dir}")


@app.command()
def render(solution: Path = typer.Argument(..., help="solution.usda written by `hirad bake`"),
           camera: Optional[str] = typer.Option(None, "--camera", help="USD camera prim path"),
           width: int = typer.Option(512, min=16, max=8192, help="Image width in pixels"),
           height: int = typer.Option(512, min=16, max=8192, help="Image height in pixels"),
           samples: int = typer.Option(4, min=1, max=4096, help="Samples per pixel"),
           output: Optional[Path] = typer.Option(None, "--output", "-o",
                                                 help="PNG, JPEG or EXR, by extension [render.png beside the solution]"),
           exposure: Optional[float] = typer.Option(None, help="Fixed exposure for PNG and JPEG, above 0 "
                                                               "[automatic]"),
           lightmaps: bool = typer.Option(False, "--lightmaps",
                                          help="Show the baked lightmaps (albedo x lightmap + emission, as a game "
                                               "engine does) instead of the solution's own surface values")):
    """Render a stored solution from any view, without solving again."""
    from . import _engine, files
    from .outputs import images

    _finite("--exposure", exposure)
    out = output or solution.parent / "render.png"
    fmt = IMAGE_SUFFIXES.get(out.suffix.lower())
    if fmt is None:
        _fail(f"--output {out}: unknown image type {out.suffix or '(no extension)'!r}; "
              f"use {', '.join(IMAGE_SUFFIXES)}")

    def go():
        from .bake import BakeError, load_solution

        files.refuse_input(out, _solution_inputs(solution), "--output")
        sol = load_solution(solution)
        if lightmaps:
            from .outputs import lightmap_render

            try:
                img = lightmap_render.render(solution, sol.view(camera), width, height)
            except lightmap_render.LightmapError as e:
                raise BakeError(str(e)) from None
        else:
            img = sol.render(camera, width, height, samples)
        if fmt == "EXR":
            _engine.write_exr(str(out), np.ascontiguousarray(img, dtype=np.float32),
                              [("hirad:units", "exitant luminance cd/m^2 (photometric) or radiance W/(m^2 sr) (radiometric), as the bake's units")])
        elif fmt == "JPEG":
            images.write_jpeg(out, img, exposure)
        else:
            images.write_png(out, img, exposure)
        files.note_written(out)
        print(out)

    _run_guarded(go)


@app.command()
def info(scene: Path = typer.Argument(..., help="USD scene, or a YAML config (its scene)"),
         config: Optional[Path] = typer.Argument(None, help="YAML config whose cost on the scene to estimate")):
    """Meshes, faces, emitters, bounds and units of a scene; with a config, the patches or
    elements, links, memory, disk and time a bake will take, estimated before anything runs."""
    from . import usd

    def go():
        nonlocal scene, config
        cfg = None
        if config is None and scene.suffix.lower() in (".yaml", ".yml"):
            scene, config = None, scene
        if config is not None:
            from .config import load_config

            cfg = load_config(config)
            scene = scene or Path(cfg.scene)
        s = usd.read_scene(scene)
        pts = s.points[np.isfinite(s.points).all(axis=1)]
        emit_faces = int(np.count_nonzero(s.face_emission.max(axis=1) > 0))
        print(f"scene: {scene}")
        print(f"units: metersPerUnit {s.meters_per_unit:g}, upAxis {s.up_axis}")
        if len(pts):
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            print(f"bounds (m): {np.round(lo, 4).tolist()} .. {np.round(hi, 4).tolist()}")
        else:
            print("bounds (m): none (no finite points)")
        print(f"meshes: {len(s.meshes)} ({sum(m.is_light for m in s.meshes)} from UsdLux lights), "
              f"faces: {s.num_faces}, emitting faces: {emit_faces}")
        for i, m in enumerate(s.meshes):
            faces = int(np.count_nonzero(s.face_mesh == i))
            emits = bool((s.face_emission[s.face_mesh == i] > 0).any())
            print(f"  {m.path}: {faces} faces{' (emitter)' if emits else ''}{' uv' if m.has_uv else ''}")
        specs = list(s.luminaires)
        if cfg is not None and cfg.lights:
            from .photometry.luminaires import with_config_lights

            specs = with_config_lights(s, cfg)
        if specs:
            print(f"luminaires: {len(specs)}, {sum(l.lumens for l in specs):.6g} lm in all")
            for l in specs:
                ies = f", IES {l.ies} ({l.ies_mode})" if l.ies else ""
                print(f"  {l.source}: {l.label or l.kind}, {l.lumens:.6g} lm, {len(l.points)} points{ies}")
        for c in s.cameras:
            print(f"camera: {c.path} fov {c.vertical_fov_degrees:.2f} deg")
        for w in s.warnings:
            print(f"warning: {w}")
        if cfg is not None:
            from . import estimate

            print(f"config: {config}")
            for line in estimate.describe(estimate.estimate(s, cfg)):
                print(line)

    _run_guarded(go)


@app.command()
def probe(solution: Path = typer.Argument(..., help="solution.usda written by `hirad bake`"),
          points: Path = typer.Argument(..., help="CSV of x,y,z[,nx,ny,nz] in metres (a header line is allowed)"),
          output: Optional[Path] = typer.Option(None, "--output", "-o", help="CSV to write [stdout]"),
          max_distance: float = typer.Option(0.05, help="Farthest surface accepted for a point, metres, "
                                                        "above 0 [0.05]")):
    """Irradiance and exitant radiance at sensor points on the surfaces of a stored solution."""
    from . import files

    _finite("--max-distance", max_distance)

    def go():
        from .bake import BakeError, load_solution

        if output:
            files.refuse_input(output, _solution_inputs(solution) + [("points file", points)], "--output")
        pts, nrm, lines = _read_points(points)
        sol = load_solution(solution)
        q = sol.query(pts, nrm, max_distance)
        rows = [["x", "y", "z", "irradiance_r", "irradiance_g", "irradiance_b",
                 "radiance_r", "radiance_g", "radiance_b", "distance"]]
        for k in range(len(pts)):
            if q["patch"][k] < 0:
                raise BakeError(f"{points}:{lines[k]}: no surface within {max_distance} m of {pts[k].tolist()}")
            rows.append([*map(repr, pts[k].tolist()), *(f"{v:.6g}" for v in q["irradiance"][k]),
                         *(f"{v:.6g}" for v in q["radiance"][k]), f"{q['distance'][k]:.3g}"])
        if output:
            with files.atomic_file(output, "w", newline="") as f:
                csv.writer(f).writerows(rows)
            files.note_written(output)
        else:
            csv.writer(sys.stdout).writerows(rows)

    _run_guarded(go)


@app.command()
def reference(scene: Path = typer.Argument(..., help="USD scene, or a YAML config (its scene)"),
              points: Path = typer.Argument(..., help="CSV of x,y,z[,nx,ny,nz] in metres (a header line is allowed)"),
              paths: int = typer.Option(1024, "--paths", min=1, help="Paths per point"),
              seed: int = typer.Option(1, "--seed", min=0, help="Random seed"),
              output: Optional[Path] = typer.Option(None, "--output", "-o", help="CSV to write [stdout]"),
              max_distance: float = typer.Option(0.05, help="Farthest surface accepted for a point, metres, "
                                                            "above 0 [0.05]")):
    """Path-traced reference radiance (with standard errors) at sensor points; no radiosity."""
    from . import files
    from .reference import write_reference_csv

    _finite("--max-distance", max_distance)

    def go():
        if not output:
            return write_reference_csv(scene, points, None, paths, seed, max_distance, sys.stdout)
        inputs = [("scene", scene), ("points file", points)]
        if scene.suffix.lower() not in (".yaml", ".yml"):
            inputs += _solution_inputs(scene)[1:]
        files.refuse_input(output, inputs, "--output")
        buf = io.StringIO(newline="")
        write_reference_csv(scene, points, None, paths, seed, max_distance, buf)
        files.write_text(output, buf.getvalue())
        files.note_written(output)

    _run_guarded(go)


@app.command()
def relight(out: Path = typer.Argument(..., help="output directory of a `hirad bake` with lights.groups"),
            set_: list[str] = typer.Option([], "--set",
                                           help="lights.groups.NAME.dimmer=X or lights.groups.NAME.color=[R,G,B]"),
            output: Optional[Path] = typer.Option(None, "--output", "-o", help="Directory to write [OUT-relit]"),
            json_out: bool = typer.Option(False, "--json", help="Print the relight report as JSON")):
    """A new output from a bake's stored light group solutions, with no solve: the solution
    layer's primvars, the lightmaps and the grids with new dimmers and colours (hirad.relight)."""
    def go():
        import json

        from .relight import relight as run

        from .relight import NOT_RELIT

        report = run(out, set_, output)
        for name in report.get("not_relit", []):  # never silently left behind
            print(f"hirad: warning: {out / name} not relit, not in {report['output']}: {NOT_RELIT.get(name, '')}",
                  file=sys.stderr)
        if json_out:
            print(json.dumps(report, indent=1))
        else:
            print(f"relit {out} -> {report['output']} in {report['timings_s']['total']:.3f} s (no solve)")

    _run_guarded(go)


@app.command()
def annual(coefficients: Path = typer.Argument(..., help="grids/annual/coefficients.npz of a bake with daylight.annual"),
           weather: Path = typer.Argument(..., help="EPW or TMY3 weather file"),
           output: Optional[Path] = typer.Option(None, "--output", "-o",
                                                 help="Directory to write [annual-<weather stem> beside the coefficients]"),
           latitude: Optional[float] = typer.Option(None, "--latitude", help="Site latitude (default: the weather file's)"),
           longitude: Optional[float] = typer.Option(None, "--longitude", help="Site longitude (default: the file's)")):
    """Annual daylight metrics for another weather file (or site) from a bake's daylight
    coefficients, without solving: only the hourly matrix products and the direct sun are
    computed. Writes per grid a CSV and heat maps, and annual.json."""
    from . import __version__, files

    out = output or coefficients.parent / f"annual-{weather.stem}"

    def go():
        from .daylight import study
        from .daylight.sun import Site
        from .daylight.weather import WeatherFileError, read_weather

        inputs = [("coefficients", coefficients), ("weather file", weather)]
        files.check_output(out, inputs)
        if not coefficients.is_file():
            _fail(f"{coefficients}: no such file", EXIT_USAGE)
        try:
            w = read_weather(weather)  # a bad line is named with the file and the line
        except (WeatherFileError, OSError) as e:
            _fail(str(e), EXIT_USAGE)
        site = None
        if latitude is not None or longitude is not None:
            site = Site(w.latitude if latitude is None else latitude, w.longitude if longitude is None else longitude,
                        w.elevation, w.timezone)
        staging = files.make_staging(out, __version__)
        with files.removed_on_failure(staging):
            info = study.rerun_annual(coefficients, weather, staging, site=site)
            files.write_json(staging / "annual.json", {"hirad_version": __version__, **info})
            files.finish_staging(staging, __version__)
            files.replace_output(staging, out, inputs)
        files.remove_stale_staging(out)
        for name, g in info["grids"].items():
            print(f"{name}: sDA300/50% {g['sDA300/50%']:.3f}, ASE1000/250h {g['ASE1000/250h']:.3f}, "
                  f"mean DA300 {g['mean_DA300']:.3f}, mean UDI 100-3000 {g['mean_UDI_100_3000']:.3f}")
        print(out)

    _run_guarded(go)


@app.command()
def grid(solution: Path = typer.Argument(..., help="solution.usda written by `hirad bake`"),
         study: Path = typer.Argument(..., help="YAML of maintenance_factor, up_axis and grids: (as a config's grids)"),
         output: Optional[Path] = typer.Option(None, "--output", "-o",
                                               help="Directory to write [grids-<study stem> beside the solution]"),
         units: str = typer.Option("photometric", "--units", help="photometric (lux) or radiometric (W/m^2)"),
         rays: int = typer.Option(512, "--rays", min=1, max=65536, help="Hemisphere rays per point (indirect light)"),
         seed: int = typer.Option(1, "--seed", min=0, help="Random seed (the bake's `seed` gives the bake's values)")):
    """Calculation grids on a stored solution, without solving: per grid CSV, JSON and a
    false-colour PNG, and the study report (HTML, PDF), in lux (Rec.709 Y)."""
    from . import __version__, files

    if units not in ("photometric", "radiometric"):
        _fail(f"--units {units!r}: photometric or radiometric")
    out = output or solution.parent / f"grids-{study.stem}"

    def go():
        import json

        from .bake import write_grid_study
        from .solution import load_solution
        from .studies import build_grids, evaluate_grids, load_study, resolve_room

        spec = load_study(study)
        inputs = _solution_inputs(solution) + [("grid file", study)]
        inputs += [("grid points file", (study.parent / g.file)) for g in spec.grids.values() if g.kind == "points"]
        files.check_output(out, inputs)
        sol = load_solution(solution)
        if sol.emitted_radiance is None:
            sol.illuminance(np.zeros((0, 3)), np.zeros((0, 3)))  # the layer predates emission: say so
        # the bake's glazing, sun and sky (daylight.npz beside the layer): direct light through the
        # windows as the bake's grids had it
        from .studies.usdgrids import apply_stored_daylight

        apply_stored_daylight(sol, solution)
        up_axis = spec.up_axis if "up_axis" in spec.model_fields_set else sol.up_axis
        rooms = {}
        for g in spec.grids.values():
            room = getattr(g, "room", None)
            if room is not None and g.polygon is None and g.polygons is None and room not in rooms:
                from pxr import Usd

                rooms[room] = resolve_room(Usd.Stage.Open(str(solution)), room, up_axis)
        grids = build_grids(spec, up_axis=up_axis, base_dir=study.parent.absolute(), rooms=rooms)
        results = evaluate_grids(grids, sol.illuminance_evaluator(rays, seed),
                                 maintenance_factor=spec.maintenance_factor)
        solver = {}
        report_path = solution.parent / "report.json"
        try:
            rep = json.loads(report_path.read_text(encoding="utf-8"))
            solver = {"method": f"{rep['method']}, {rep['solver']['method']}",
                      "iterations": rep["solver"]["iterations"], "residual": rep["solver"]["residual"],
                      "tolerance": rep["solver"]["tolerance"],
                      "energy balance (max relative error)": rep["energy_balance"]["max_relative_error"],
                      "baked by hirad": rep.get("hirad_version")}
        except (OSError, ValueError, KeyError, TypeError):
            solver = {"solver figures": f"not known ({report_path} not readable)"}
        staging = files.make_staging(out, __version__)
        with files.removed_on_failure(staging):
            summary = write_grid_study(results, staging, units=units, maintenance_factor=spec.maintenance_factor,
                                       seed=seed, rays=rays, title=f"Lighting study: {study.stem}",
                                       subtitle=f"solution {solution}", solver=solver,
                                       warn=lambda w: print(f"hirad: warning: {w}", file=sys.stderr))
            files.write_json(staging / "grids.json", {"hirad_version": __version__, "solution": str(solution),
                                                      "study": str(study), **summary})
            files.finish_staging(staging, __version__)
            files.replace_output(staging, out, inputs)
        files.remove_stale_staging(out)
        for name, st in summary["grids"].items():
            u0 = "-" if st["u0"] is None else f"{st['u0']:.3f}"
            print(f"{name}: Em {st['em']:.4g} {summary['unit']}, Emin {st['emin']:.4g}, Emax {st['emax']:.4g}, "
                  f"U0 {u0}")
        print(out)

    _run_guarded(go)


@app.command()
def ies(path: Path = typer.Argument(..., help="IES LM-63 photometric file"),
        plot: Optional[Path] = typer.Option(None, "--plot", help="Polar candela plot (PNG): C0-C180 and C90-C270")):
    """A luminaire's photometry: lumens by zonal integration, peak candela, beam and field
    angles, the photometric type, symmetry and LM-63 version found."""
    def go():
        from .photometry.ies import IesError, ies_command

        try:
            print(ies_command(path, plot))
        except IesError as e:
            _fail(str(e), EXIT_SCENE)
        except OSError as e:
            _fail(f"{path}: {e.strerror or e}", EXIT_USAGE)

    _run_guarded(go)


EXIT_BATCH_FAILED = 5  # hirad batch: some jobs failed (the others are done)


def _batch_status(study_path: Path, as_json: bool) -> None:
    import json

    from .batch import load_study
    from .batch.index import Index, status_rows

    study = load_study(study_path, validate=False)
    if not study.index_path.exists():
        _fail(f"{study_path}: no index yet ({study.index_path}): run `hirad batch {study_path}` first")
    index = Index(study.index_path)
    try:
        rows, batches = status_rows(index), index.batches()
    finally:
        index.close()
    if as_json:
        print(json.dumps({"study": str(study.path), "index": str(study.index_path), "jobs": rows,
                          "batches": batches}, indent=2))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"study {study.name}: {study.index_path}")
    for col in ("job", "status", "attempts", "exit", "seconds", "key", "error"):
        table.add_column(col, overflow="fold")
    for r in rows:
        table.add_row(r["name"], r["status"], str(r["attempts"]), "" if r["exit_code"] is None else str(r["exit_code"]),
                      "" if r["seconds"] is None else f"{r['seconds']:.1f}", r["key"][:12], r["error"] or "")
    Console(width=int(os.environ.get("COLUMNS", "0")) or None).print(table)
    by = {}
    for r in rows:
        by[r["status"]] = by.get(r["status"], 0) + 1
    print(", ".join(f"{v} {k}" for k, v in sorted(by.items())) or "no jobs")


@app.command()
def batch(study: Path = typer.Argument(..., metavar="STUDY.yaml", help="The study (or `status STUDY.yaml`)"),
          status_of: Optional[Path] = typer.Argument(None, hidden=True),
          scheduler: Optional[str] = typer.Option(None, "--scheduler",
                                                  help="An existing Dask scheduler, tcp://HOST:PORT [a LocalCluster]"),
          workers: Optional[int] = typer.Option(None, "--workers", min=1, help="LocalCluster workers [the study's]"),
          force: bool = typer.Option(False, "--force", help="Run every job again, finished or not"),
          dry_run: bool = typer.Option(False, "--dry-run", help="Validate the study and list its jobs; run nothing"),
          as_json: bool = typer.Option(False, "--json", help="The result (or the status) as JSON on stdout"),
          progress: str = typer.Option("auto", "--progress", help="auto, plain, jsonl or none (events on stderr)")):
    """Run a study: a base config and its variants, each a bake of its own on Dask (a local
    cluster by default), resumable; `hirad batch status STUDY.yaml` shows its index.
    Exit 0: every job done; 5: some jobs failed; 2: a bad study or no scheduler."""
    import json
    import time

    global _json_errors
    _json_errors = as_json
    if progress not in ("auto", "plain", "jsonl", "none"):
        _fail(f"--progress {progress!r}: auto, plain, jsonl or none")
    if str(study) == "status":
        if status_of is None:
            _fail("hirad batch status STUDY.yaml: give the study")
        return _run_guarded(lambda: _guard_batch(lambda: _batch_status(status_of, as_json)))
    if status_of is not None:
        _fail(f"hirad batch: one study at a time (got {study} and {status_of})")
    t0 = time.monotonic()

    def emit(e: dict) -> None:
        if progress == "none":
            return
        if progress == "jsonl":
            print(json.dumps({"elapsed": round(time.monotonic() - t0, 3), **e}), file=sys.stderr, flush=True)
            return
        kind = e["event"]
        if kind == "plan":
            text = f"{e['jobs']} jobs: {e['to_run']} to run, {e['skipped']} finished before (index {e['index']})"
        elif kind == "cluster":
            text = f"{e['cluster']}; dashboard {e['dashboard'] or 'not available'}"
        elif kind == "job":
            text = f"job {e['name']}: {e['status']}" + (f" in {e['seconds']:.1f} s" if e.get("seconds") else "") + \
                   (f" after {e['attempts']} attempts" if e.get("attempts", 1) > 1 else "") + \
                   (f": {e['error']}" if e.get("error") and e["status"] != "done" else "")
        elif kind == "cancelling":
            text = f"cancelling {e['jobs']} jobs"
        else:
            text = json.dumps(e)
        print(f"hirad: [{time.monotonic() - t0:7.1f} s] batch: {text}", file=sys.stderr, flush=True)

    def go():
        from .batch import load_study
        from .batch.index import Index
        from .batch.runner import run_batch
        from .batch.summary import write_summary

        s = load_study(study)
        if dry_run:
            for j in s.jobs:
                reuse = f"\t(reuses the links of {j.after})" if j.after else ""
                print(f"{j.name}\t{j.key[:12]}\t{j.output}\t{' '.join(o for o in j.overrides if not o.startswith('output='))}{reuse}")
            return None
        counts = run_batch(s, scheduler=scheduler, workers=workers, force=force, emit=emit)
        index = Index(s.index_path)
        try:
            csv_path, html_path = write_summary(s, index)
        finally:
            index.close()
        return s, counts, csv_path, html_path

    got = _run_guarded(lambda: _guard_batch(go))
    if got is None:
        return
    s, counts, csv_path, html_path = got
    if as_json:
        print(json.dumps({"study": str(s.path), "index": str(s.index_path), "summary_csv": str(csv_path),
                          "summary_html": str(html_path), **counts}, indent=2))
    else:
        print(f"{len(s.jobs)} jobs: {counts['run']} run ({counts['done']} done, {counts['failed']} failed), "
              f"{counts['skipped']} finished before; index {s.index_path}; summary {html_path}")
    if counts["failed"] or counts["cancelled"]:
        raise typer.Exit(EXIT_BATCH_FAILED)


def _guard_batch(fn):
    """A study's own errors (StudyFileError, BatchError) as usage errors (exit 2)."""
    from .batch.runner import BatchError
    from .batch.study import StudyFileError

    try:
        return fn()
    except (StudyFileError, BatchError) as e:
        _fail(str(e), EXIT_USAGE)


@app.command("config")
def config_cmd(schema: bool = typer.Option(False, "--schema",
                                           help="Print every config key with its type, default and meaning")):
    """About configs: `hirad config --schema` prints every key hirad reads."""
    if not schema:
        _fail("hirad config: give --schema (prints every config key with its type, default and meaning)")

    def go():
        try:
            from .config.describe import schema_text
        except ImportError as e:
            _fail(f"hirad config --schema: the schema description is not available in this build ({e})",
                  EXIT_INTERNAL)
        text = schema_text()
        sys.stdout.write(text if text.endswith("\n") else text + "\n")

    _run_guarded(go)


def _read_points(path: Path):
    from .reference import read_points

    return read_points(path)


def main() -> None:
    from . import interrupts

    interrupts.install()
    try:
        app()
    except interrupts.Interrupted as e:  # outside a command (while starting or parsing)
        interrupts.finished()
        sys.exit(e.exit_code)


if __name__ == "__main__":
    main()
