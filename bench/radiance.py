"""hirad and Radiance side by side on the Modern Hall work plane: time and agreement, in one run.

    python bench/radiance.py [--points 10000] [--quick] [--solution OUT/solution.usda] [--keep DIR]
                             [--ab 5 --ad 512 --as 256 --aa 0.15 --ar 128 --lw 2e-4 --ds 0.05]

1. Reads ../shared/data/modern_hall with `hirad.usd.read_scene` (the bake's own reader and
   settings: metres, the bound materials' reflectance, area-light emission) and writes the
   very same polygons as a Radiance scene: one `polygon` per face, `plastic` (no specular,
   roughness 0) of the face's RGB reflectance, or `light` of radiance = hirad emission / pi
   per channel (hirad's emission is exitance in W/m^2, Radiance's `light` is radiance in
   W/(m^2 sr)). Both programs see identical geometry. Two rewritings that change no surface:
   the emitting triangles of one light mesh that lie in one plane and close one outline (a
   DiskLight's fan) are written as that outline polygon (one Radiance source, not 48), and
   emitter quads longer than --light-split metres (the hall's 5-13 m panels) are cut into
   equal sub-quads, so Radiance samples them finely (with -ds as well).
2. Bakes the hall with hirad (hierarchical, the bench/grids.py settings, solution.usda on,
   other outputs off; or takes --solution, a stored bake of the hall), opens the stored
   solution (`hirad.bake.load_solution`, as `hirad grid` does) and times the grid evaluation:
   `illuminance_evaluator(512 rays)`, the calculation grids' read-out (exact direct light of
   the emitter faces with visibility, indirect light gathered from the stored solution), on
   the 10,000-point work plane of bench/grids.py (a regular grid over the floor's bounding box
   0.80 m above the floor, facing up).
3. Runs `oconv` and `rtrace -I` (irradiance at each point facing its normal, W/m^2 per
   channel; `-n` processes sharing one ambient file) on the same points, timed (wall).
4. Prints both timings and the agreement of the photometric Y = 0.2126 R + 0.7152 G +
   0.0722 B (Rec.709, the weights hirad's grids use; Radiance's own `179 lm/W x (0.265, 0.670,
   0.065)` is not used, so both are the same quantity in W/m^2): mean and RMS of the per-point
   relative difference (hirad - Radiance) / Radiance, Em, Emin and U0 = Emin/Em of each, and
   the same over the points Radiance finds lit (Y > 1 % of its median).
--quick: 900 points, a coarser bake, -ab 3 -ad 256 -as 128 -aa 0.2 -ar 64.
Every timing line states the 1-minute load average at its start (the machine may be shared).
Radiance's binaries come with PyPI `pyradiance` (the `bench` extra of pyproject.toml); its
module is located, not imported (its extension modules stay out of the engine's process).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from grids import HALL, LUM, ROOT, load  # noqa: E402  (the same scene, weights and load line as bench/grids.py)


def radiance_env() -> dict:
    """The environment in which pyradiance's bundled binaries run (RAYPATH: its lib)."""
    import importlib.util

    # located, not imported: its extension modules are not wanted in the engine's process
    spec = importlib.util.find_spec("pyradiance")
    if spec is None or spec.origin is None:
        raise SystemExit("pyradiance is not installed (pip install 'pyradiance>=1.3.1', the bench extra)")
    base = Path(spec.origin).resolve().parent
    env = dict(os.environ)
    env["PATH"] = f"{base / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["RAYPATH"] = f".{os.pathsep}{base / 'lib'}"
    return env


def _split(poly: np.ndarray, most: float) -> list[np.ndarray]:
    """Equal sub-polygons of a triangle (4-split) or quad (an n x m grid, bilinear) whose edges
    are at most `most` metres; the union is the polygon."""
    edges = np.linalg.norm(poly - np.roll(poly, -1, axis=0), axis=1)
    if edges.max() <= most:
        return [poly]
    if len(poly) == 3:
        a, b, c = poly
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        return [q for t in ([a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca])
                for q in _split(np.array(t), most)]
    if len(poly) == 4:
        p0, p1, p2, p3 = poly
        nu = int(np.ceil(max(edges[0], edges[2]) / most))
        nv = int(np.ceil(max(edges[1], edges[3]) / most))

        def at(s, t):
            return (1 - s) * (1 - t) * p0 + s * (1 - t) * p1 + s * t * p2 + (1 - s) * t * p3
        return [np.array([at(i / nu, j / nv), at((i + 1) / nu, j / nv), at((i + 1) / nu, (j + 1) / nv),
                          at(i / nu, (j + 1) / nv)]) for i in range(nu) for j in range(nv)]
    return [poly]


def _outline(polys: list[np.ndarray]) -> np.ndarray | None:
    """The one boundary loop of coplanar polygons sharing edges (a light's fan of triangles),
    in their winding, or None when the union is not one simple loop."""
    edges = {}
    count = {}
    for p in polys:
        for a, b in zip(p, np.roll(p, -1, axis=0)):
            ka, kb = tuple(np.round(a, 7)), tuple(np.round(b, 7))
            key = (min(ka, kb), max(ka, kb))
            count[key] = count.get(key, 0) + 1
            edges[key] = (ka, kb, a)
    nxt = {}
    for key, n in count.items():
        if n == 1:
            ka, kb, a = edges[key]
            if ka in nxt:
                return None
            nxt[ka] = (kb, a)
    if not nxt:
        return None
    start = next(iter(nxt))
    loop, k = [], start
    for _ in range(len(nxt)):
        kb, a = nxt[k]
        loop.append(a)
        k = kb
        if k == start:
            break
    if k != start or len(loop) != len(nxt):
        return None
    return np.array(loop)


def write_rad(scene, path: Path, light_split: float, one_sided: bool = True) -> dict:
    """The scene's faces as a Radiance scene file; returns counts. The emitting faces of one
    light mesh that lie in one plane and make one simple outline (a DiskLight's fan of
    triangles) are written as that one polygon: the same emitting surface, one Radiance source
    instead of dozens (its direct-light cost grows with the number of sources). `one_sided`:
    each reflecting material is a `mixfunc` of its `plastic` on the front (Rdot > 0) and black
    on the back, as hirad's surfaces are (a patch receives and reflects on its front only; its
    back is opaque and black); Radiance's plastic alone reflects on both sides."""
    counts = scene.face_vertex_counts
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    materials: dict[tuple, str] = {}
    lines = []
    n_poly = n_light = merged = 0
    emitted_power = 0.0

    def material(key):
        name = materials.get(key)
        if name is None:
            name = materials[key] = f"m{len(materials)}"
            if key[0] == "light":
                lines.append(f"void light {name}\n0\n0\n3 {key[1]:.9g} {key[2]:.9g} {key[3]:.9g}\n")
            elif one_sided:
                if "black" not in materials.values():
                    materials[("black",)] = "black"
                    lines.append("void plastic black\n0\n0\n5 0 0 0 0 0\n")
                lines.append(f"void plastic {name}_front\n0\n0\n5 {key[1]:.6g} {key[2]:.6g} {key[3]:.6g} 0 0\n")
                lines.append(f"void mixfunc {name}\n4 {name}_front black if(Rdot,1,0) .\n0\n0\n")
            else:
                lines.append(f"void plastic {name}\n0\n0\n5 {key[1]:.6g} {key[2]:.6g} {key[3]:.6g} 0 0\n")
        return name

    def polygon(name, q):
        nonlocal n_poly
        lines.append(f"{name} polygon f{n_poly}\n0\n0\n{3 * len(q)} " + " ".join(f"{v:.9g}" for v in q.ravel()) + "\n")
        n_poly += 1

    lights: dict[tuple, list] = {}
    for f in range(scene.num_faces):
        c = int(counts[f])
        poly = scene.points[scene.face_vertex_indices[starts[f]:starts[f] + c]]
        e = scene.face_emission[f]
        if e.max() > 0:
            key = ("light",) + tuple(np.round(e / np.pi, 9))
            nrm = np.cross(poly, np.roll(poly, -1, axis=0)).sum(axis=0)
            emitted_power += 0.5 * float(np.linalg.norm(nrm)) * float(e @ LUM)
            lights.setdefault((int(scene.face_mesh[f]), key), []).append((poly, nrm / np.linalg.norm(nrm)))
            continue
        polygon(material(("plastic",) + tuple(np.round(scene.face_reflectance[f], 6))), poly)
    for (_, key), faces in lights.items():
        name = material(key)
        polys = [p for p, _ in faces]
        if len(polys) > 1 and all(n @ faces[0][1] > 1 - 1e-9 for _, n in faces):
            loop = _outline(polys)
            if loop is not None:
                polys = [loop]
                merged += len(faces)
        for poly in polys:
            pieces = _split(poly, light_split) if len(poly) <= 4 else [poly]
            n_light += len(pieces)
            for q in pieces:
                polygon(name, q)
    path.write_text("".join(lines))
    return {"polygons": n_poly, "light_polygons": n_light, "merged_light_faces": merged,
            "materials": len([k for k in materials if k != ("black",)]), "emitted_Y_W": emitted_power}


def work_plane(scene, n_points: int) -> tuple[np.ndarray, np.ndarray, float]:
    """bench/grids.py's work plane, from the scene's faces (the bake's leaves subdivide them,
    so the floor, its level and its bounding box are the same): a regular grid over the
    bounding box of the floor (the lowest 1 cm height bin holding a tenth of the upward-facing
    area), 0.80 m above it, facing up."""
    from hirad.usd.scene import _polygon_areas

    up = 2 if scene.up_axis == "Z" else 1
    counts = scene.face_vertex_counts
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    polys = [scene.points[scene.face_vertex_indices[s:s + c]] for s, c in zip(starts, counts)]
    nrm = np.array([np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0) for p in polys])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    cen = np.array([p.mean(axis=0) for p in polys])
    area = _polygon_areas(scene.points, counts, scene.face_vertex_indices)
    normal = np.zeros(3)
    normal[up] = 1
    facing_up = (nrm[:, up] > 0.99) & (area > 0)
    heights = np.round(cen[:, up] / 0.01).astype(np.int64)
    levels, inverse = np.unique(heights[facing_up], return_inverse=True)
    area_at = np.bincount(inverse, weights=area[facing_up])
    floor_bin = levels[np.flatnonzero(area_at >= 0.1 * area_at.sum())[0]]
    floor = np.flatnonzero(facing_up & (heights == floor_bin))
    floor_level = float(cen[floor, up].max())
    corners = np.concatenate([polys[i] for i in floor])
    lo, hi = corners.min(0), corners.max(0)
    axes = [a for a in range(3) if a != up]
    n_side = int(np.ceil(np.sqrt(n_points)))
    u = np.linspace(lo[axes[0]], hi[axes[0]], n_side + 2)[1:-1]
    v = np.linspace(lo[axes[1]], hi[axes[1]], n_side + 2)[1:-1]
    uu, vv = np.meshgrid(u, v)
    pts = np.zeros((uu.size, 3))
    pts[:, axes[0]], pts[:, axes[1]], pts[:, up] = uu.ravel(), vv.ravel(), floor_level + 0.80
    pts = np.ascontiguousarray(pts[:n_points])
    return pts, np.ascontiguousarray(np.tile(normal, (len(pts), 1))), floor_level


def rtrace(octree: Path, pts: np.ndarray, nrm: np.ndarray, opts: list[str], env: dict, cwd: Path) -> np.ndarray:
    text = "".join(f"{a:.9g} {b:.9g} {c:.9g} {d:.9g} {e:.9g} {f:.9g}\n" for (a, b, c), (d, e, f) in zip(pts, nrm))
    run = subprocess.run(["rtrace", "-w", "-h", "-I+", "-ov", "-fad", *opts, str(octree)], input=text.encode(),
                         capture_output=True, env=env, cwd=cwd, check=False)
    if run.returncode != 0:
        raise SystemExit(f"rtrace failed ({run.returncode}): {run.stderr.decode(errors='replace')[-2000:]}")
    out = np.frombuffer(run.stdout, dtype=np.float64).reshape(-1, 3)
    if len(out) != len(pts):
        raise SystemExit(f"rtrace returned {len(out)} values for {len(pts)} points")
    return out


def stats(y: np.ndarray) -> str:
    em = float(y.mean())
    return f"Em {em:8.4f}  Emin {float(y.min()):8.4f}  Emax {float(y.max()):8.4f}  U0 {float(y.min()) / em:.4f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10000)
    ap.add_argument("--quick", action="store_true",
                    help="a quick look: 900 points, a coarser bake (eps 1e-4, min_area 0.02), -ab 3 -ad 256 -as 128 -aa 0.2 -ar 64")
    ap.add_argument("--rays", type=int, default=512, help="hirad's hemisphere rays per point (the grids' default)")
    ap.add_argument("--epsilon", type=float, default=1e-5)
    ap.add_argument("--min-area", type=float, default=0.005)
    ap.add_argument("--ab", type=int, default=5)
    ap.add_argument("--ad", type=int, default=512)
    ap.add_argument("--as", dest="as_", type=int, default=256)
    ap.add_argument("--aa", type=float, default=0.15)
    ap.add_argument("--ar", type=int, default=128)
    ap.add_argument("--lw", type=float, default=2e-4)
    ap.add_argument("--lr", type=int, default=-12, help="rtrace -lr (negative: Russian roulette past that depth)")
    ap.add_argument("--ds", type=float, default=0.05, help="rtrace -ds (source subdivision)")
    ap.add_argument("--light-split", type=float, default=2.0, help="largest emitter edge in the Radiance scene, m")
    ap.add_argument("--solution", type=Path, default=None,
                    help="a stored solution.usda of the hall to evaluate (no bake; it must be of the same scene)")
    ap.add_argument("--keep", type=Path, default=None, help="bake into this directory and keep it (for --solution)")
    ap.add_argument("--skip-radiance", action="store_true", help="hirad only")
    ap.add_argument("--processes", type=int, default=os.cpu_count() or 1, help="rtrace -n")
    args = ap.parse_args()
    if args.quick:
        args.points, args.epsilon, args.min_area = min(args.points, 900), 1e-4, 0.02
        args.ab, args.ad, args.as_, args.aa, args.ar = 3, 256, 128, 0.2, 64
    if not HALL.exists():
        raise SystemExit(f"{HALL} is absent: nothing to measure")

    from hirad import usd
    from hirad.bake import bake, load_solution
    from hirad.config import config_from_dict

    env = radiance_env()
    version = subprocess.run(["rtrace", "-version"], capture_output=True, env=env, text=True).stdout.strip()
    print(f"machine: nproc {os.cpu_count()}, load {' '.join(f'{x:.2f}' for x in os.getloadavg())}; {version}")
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        out = args.keep if args.keep is not None else tmp / "out"
        cfg = config_from_dict({
            "scene": str(HALL), "output": str(out), "method": "hierarchical",
            "hierarchy": {"epsilon": args.epsilon, "min_area": args.min_area, "samples": 16},
            "solver": {"method": "jacobi", "tolerance": 1e-4},
            "outputs": {"usd": True, "lightmaps": {"enabled": False}, "preview": {"enabled": False}, "report": True}})
        scene = usd.read_scene(cfg.scene, default_reflectance=tuple(cfg.materials.default_reflectance),
                               uv_primvars=tuple(cfg.materials.uv_primvars), require_emission=True)
        solution = args.solution
        if solution is None:
            ld = load()
            t0 = time.perf_counter()
            res = bake(cfg)
            print(f"hirad bake: {time.perf_counter() - t0:.1f} s ({ld}), eps {args.epsilon:g}, min_area "
                  f"{args.min_area:g}, {len(res.patches['area'])} leaves, residual {res.report['solver']['residual']:.2e}")
            del res
            solution = out / "solution.usda"
        else:
            print(f"hirad: the stored bake {solution} (not baked again)")
        pts, nrm, floor = work_plane(scene, args.points)
        print(f"work plane: {len(pts)} points 0.80 m over the floor at {floor:.3f} m ({scene.up_axis} up), facing up, "
              f"x {pts[:, 0].min():.3f} .. {pts[:, 0].max():.3f}")

        ld = load()
        t0 = time.perf_counter()
        stored = load_solution(solution)
        t_load = time.perf_counter() - t0
        evaluate = stored.illuminance_evaluator(args.rays, 1)
        t0 = time.perf_counter()
        y_h = np.asarray(evaluate(pts, nrm))
        t_hirad = time.perf_counter() - t0
        print(f"hirad grid evaluation on the stored bake: {t_hirad:.2f} s ({ld}; opening solution.usda "
              f"{t_load:.2f} s more), {args.rays} rays per point")
        if args.skip_radiance:
            print(f"hirad only: {stats(y_h)}")
            return

        rad = tmp / "hall.rad"
        counts = write_rad(scene, rad, args.light_split)
        ld = load()
        t0 = time.perf_counter()
        with open(tmp / "hall.oct", "wb") as f:
            run = subprocess.run(["oconv", "-w", "-f", str(rad)], stdout=f, stderr=subprocess.PIPE, env=env, cwd=tmp)
        if run.returncode != 0:
            raise SystemExit(f"oconv failed: {run.stderr.decode(errors='replace')[-2000:]}")
        t_oconv = time.perf_counter() - t0
        opts = ["-ab", str(args.ab), "-ad", str(args.ad), "-as", str(args.as_), "-aa", f"{args.aa:g}",
                "-ar", str(args.ar), "-lw", f"{args.lw:g}", "-ds", f"{args.ds:g}", "-dj", "0",
                "-st", "0", "-lr", f"{args.lr}", "-af", str(tmp / "hall.amb"), "-n", str(args.processes)]
        print(f"Radiance scene: {counts['polygons']} polygons ({counts['light_polygons']} light polygons; "
              f"{counts['merged_light_faces']} fan triangles written as their light's outline), "
              f"{counts['materials']} materials, oconv {t_oconv:.2f} s ({ld})")
        ld = load()
        t0 = time.perf_counter()
        rgb_r = rtrace(tmp / "hall.oct", pts, nrm, opts, env, tmp)
        t_rad = time.perf_counter() - t0
        print(f"rtrace -I {' '.join(opts[:-4])} -n {args.processes}: {t_rad:.1f} s ({ld})")
    y_r = rgb_r @ LUM

    print()
    print(f"{'':10s} {'time s':>8s}   work plane, Y (W/m^2; lux when read photometrically)")
    print(f"{'hirad':10s} {t_hirad:8.2f}   {stats(y_h)}")
    print(f"{'Radiance':10s} {t_rad:8.2f}   {stats(y_r)}")
    lit = y_r > 0.01 * np.median(y_r)
    for label, m in (("all points", np.ones(len(y_r), bool)), ("lit (Y_rad > 1 % of median)", lit)):
        rel = (y_h[m] - y_r[m]) / np.where(y_r[m] > 0, y_r[m], np.nan)
        rel = rel[np.isfinite(rel)]
        print(f"{label} ({int(m.sum())}): relative difference hirad vs Radiance mean {rel.mean():+.2%}, "
              f"RMS {np.sqrt(np.mean(rel ** 2)):.2%}, median |.| {np.median(np.abs(rel)):.2%}; "
              f"Em ratio {y_h[m].mean() / y_r[m].mean() - 1:+.2%}")
    print(f"speed: hirad {t_rad / t_hirad:.1f}x faster than rtrace (both on {os.cpu_count()} cores); "
          f"load at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
