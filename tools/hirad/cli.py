"""The `hirad` command: a thin layer over the Python API (hirad.bake, hirad.load_solution)."""

from __future__ import annotations

import csv
import json
import os
import sys
from pathlib import Path
from typing import Optional

import numpy as np
import typer

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="hirad: radiosity for USD scenes. Units: radiance W/(m^2 sr), irradiance W/m^2.")


def _fail(message: str, code: int = 2) -> None:
    print(f"hirad: error: {message}", file=sys.stderr)
    raise typer.Exit(code)


def _run_guarded(fn):
    """Turns every expected failure into one clear line on stderr and a non-zero exit."""
    from .bake import BakeError
    from .config import ConfigError
    from .usd import SceneError

    try:
        return fn()
    except ConfigError as e:
        _fail(str(e))
    except (SceneError, BakeError) as e:
        _fail(str(e))
    except (ValueError, RuntimeError, OSError) as e:
        _fail(f"{type(e).__name__}: {e}", 1)


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
                                               "refinement settings; new materials), computing no form factor")):
    """Solve a scene and write its outputs (USD layer, lightmaps, preview, report)."""
    from .bake import bake as run

    result = _run_guarded(lambda: run(config, quiet=quiet or as_json, threads=threads, snapshots=snapshots,
                                      resume=resume, reuse_links=reuse_links))
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
           width: int = typer.Option(512, min=16), height: int = typer.Option(512, min=16),
           samples: int = typer.Option(4, min=1, help="Samples per pixel"),
           output: Optional[Path] = typer.Option(None, "--output", "-o", help="PNG or EXR [render.png beside the solution]"),
           exposure: Optional[float] = typer.Option(None, help="Fixed exposure for PNG (default: automatic)"),
           lightmaps: bool = typer.Option(False, "--lightmaps",
                                          help="Show the baked lightmaps (albedo x lightmap + emission, as a game "
                                               "engine does) instead of the solution's own surface values")):
    """Render a stored solution from any view, without solving again."""
    from . import _engine
    from .outputs import images
    from .bake import load_solution

    def go():
        sol = load_solution(solution)
        if lightmaps:
            from .outputs import lightmap_render
            from .bake import BakeError
            try:
                img = lightmap_render.render(solution, sol.view(camera), width, height)
            except lightmap_render.LightmapError as e:
                raise BakeError(str(e)) from None
        else:
            img = sol.render(camera, width, height, samples)
        out = output or solution.parent / "render.png"
        if out.suffix.lower() == ".exr":
            _engine.write_exr(str(out), np.ascontiguousarray(img, dtype=np.float32),
                              [("hirad:units", "exitant radiance W/(m^2 sr)")])
        else:
            images.write_png(out, img, exposure)
        print(out)

    _run_guarded(go)


@app.command()
def info(scene: Path = typer.Argument(..., help="USD scene")):
    """Meshes, faces, patches-to-be, emitters, bounds and units of a scene."""
    from . import usd

    def go():
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
        for c in s.cameras:
            print(f"camera: {c.path} fov {c.vertical_fov_degrees:.2f} deg")
        for w in s.warnings:
            print(f"warning: {w}")

    _run_guarded(go)


@app.command()
def probe(solution: Path = typer.Argument(..., help="solution.usda written by `hirad bake`"),
          points: Path = typer.Argument(..., help="CSV of x,y,z[,nx,ny,nz] in metres (a header line is allowed)"),
          output: Optional[Path] = typer.Option(None, "--output", "-o", help="CSV to write [stdout]"),
          max_distance: float = typer.Option(0.05, help="Farthest surface accepted for a point, metres")):
    """Irradiance and exitant radiance at sensor points on the surfaces of a stored solution."""
    from .bake import BakeError, load_solution

    def go():
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
            tmp = output.with_name(output.name + ".partial")
            with open(tmp, "w", newline="") as f:
                csv.writer(f).writerows(rows)
            os.replace(tmp, output)
        else:
            csv.writer(sys.stdout).writerows(rows)

    _run_guarded(go)


@app.command()
def reference(scene: Path = typer.Argument(..., help="USD scene, or a YAML config (its scene)"),
              points: Path = typer.Argument(..., help="CSV of x,y,z[,nx,ny,nz] in metres (a header line is allowed)"),
              paths: int = typer.Option(1024, "--paths", min=1, help="Paths per point"),
              seed: int = typer.Option(1, "--seed", min=0, help="Random seed"),
              output: Optional[Path] = typer.Option(None, "--output", "-o", help="CSV to write [stdout]"),
              max_distance: float = typer.Option(0.05, help="Farthest surface accepted for a point, metres")):
    """Path-traced reference radiance (with standard errors) at sensor points; no radiosity."""
    from .reference import write_reference_csv

    _run_guarded(lambda: write_reference_csv(scene, points, output, paths, seed, max_distance, sys.stdout))


def _read_points(path: Path):
    from .reference import read_points

    return read_points(path)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
