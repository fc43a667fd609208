"""The shared daylight scenes baked with their authored lights: ../shared/data/classroom (a
uniform DomeLight and a DistantLight sun through open windows) and ../shared/data/living_room
(a latlong-textured DomeLight through glass). Prints, per scene: triangles, elements, links,
the time of each stage, peak RSS, the energy balance and the number of distant-light directions.

    python bench/daylight_scenes.py [--epsilon 1e-3] [--scenes classroom living_room]

Each bake runs in a child process (wait4 gives its peak RSS). The scenes are not in the
project (they are CC BY data in ../shared/data): the bench says so and stops when they are
absent.

    python bench/daylight_scenes.py --df [--epsilon 1e-5 --min-area 0.02 --relative 0 --rounds 3 --patches reinhart2
        --subdivisions 2] [--height 0.8 --spacing 0.5] [--ab 8 --ad 4096 --as 1024 --aa 0.1
        --ar 2048 --lw 1e-4] [--sky-ad 65536] [--fine-sky reinhart8] [--processes 2] [--keep DIR]

--df (issue 16): the daylight factor of the classroom against Radiance rtrace on the same
points. hirad bakes the classroom with the bake settings above but two: epsilon 1e-5 (epsilon
is a fraction of the light the faces receive, which the 222 m ground plane outside dominates;
at 1e-3 the ground's elements of 16-32 m^2 straddle the classroom's walls and the floor inside
gets the outside's light) and the sky of configs/daylight_factor.yaml, Reinhart MF:2 x 2^2
directions (Tregenza x 2^2 puts the sky component 5.5 % low on average, 20 % RMS per point,
against Reinhart MF:8). The sky is `daylight.sky.model: cie_overcast` (10,000 lx, ground 0.2,
no sun: the config's sky replaces the scene's DomeLight and DistantLight), with
`daylight.daylight_factor` on a work plane over the classroom's floor (inside the walls x
-4.20..3.94 m, z -5.93..5.93 m, Y up; 0.5 m border; --height, --spacing: 330 points at 0.8 m
and 0.5 m), in a child process timed whole (bench/daylight.py's hirad_bake). Radiance sees the
scene as bench/daylight.py writes it (write_room of `hirad.usd.read_scene(daylight=True)`:
plastic of each face's RGB reflectance, two-sided; the classroom has no glass: its windows are
open), turned Z up (`xform -rx 90`: (x, y, z) -> (x, -z, y)), under `gensky 3 21 12 -c -B
55.866` with the glow sky and ground hemispheres, and `rtrace -I` at the points of hirad's
grid CSV facing up (one ambient file for -n processes; -lr -12). DF = 100 E / E_h,out on each
side (Radiance: 179 (0.265, 0.670, 0.065) and its sky's own E_h,out; hirad: Rec.709 Y and its
report's E_h,out). Locating a difference: the sky component (Radiance: -ab 1 with every
surface black, -aa 0; hirad: the `direct` part of the stored solution's illuminance at the
same points, with the sky's distant lights made again from the config; and with the sky cut
finer, --fine-sky, on the same solution), the rest (interreflected), and the irradiance of the
surface under each grid point (the floor, the platform or a seat, found by rtrace -oL straight
down; hirad: its elements' value, SurfaceSolution.query; Radiance: rtrace -I 1 mm over it).
Per-point figures go to DIR/points.csv with --keep. Points with something within 1 m above
them (desks, the lectern: rtrace -oL straight up) are reported apart. Each timing states the
1-minute load average at its start (the machine may be shared).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
SCENES = {"classroom": DATA / "classroom" / "usd" / "classroom.usdc",
          "living_room": DATA / "living_room" / "usd" / "living_room.usdc"}


# the classroom's floor inside its walls (world metres, Y up): the walls' inner faces are at
# x = -4.20 and 3.94, z = -5.93 and 5.93; the floor is the scene's ground plane, y = 0
CLASSROOM_FLOOR = [[-4.20, 0.0, -5.93], [3.94, 0.0, -5.93], [3.94, 0.0, 5.93], [-4.20, 0.0, 5.93]]


def hierarchy_settings(epsilon: float, min_area: float = 0.02, relative: float = 0.0, rounds: int = 3) -> dict:
    return {"hierarchy": {"epsilon": epsilon, "min_area": min_area, "samples": 4, "max_rounds": rounds,
                          "relative_epsilon": relative},
            "solver": {"method": "jacobi", "tolerance": 1e-3}}


def bake(scene: Path, epsilon: float, tmp: Path) -> dict:
    cfg = {"scene": str(scene), "output": str(tmp / "out"), "method": "hierarchical",
           **hierarchy_settings(epsilon),
           "daylight": {"sky": {"model": "usd"}, "patches": "tregenza", "subdivisions": 2},
           "outputs": {"usd": True, "lightmaps": {"enabled": False},
                       "preview": {"enabled": True, "width": 480, "height": 320}, "report": True}}
    path = tmp / "bake.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with open(tmp / "report.json", "w") as f:
        proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "bake", str(path), "--json"], stdout=f)
        _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise SystemExit(f"bake of {scene} failed (status {status})")
    report = json.loads((tmp / "report.json").read_text())
    report["peak_rss_mib"] = usage.ru_maxrss / 1024
    return report


# ---------------------------------------------------------------------------------------------
# --df: the classroom's daylight factor, hirad against Radiance rtrace
# ---------------------------------------------------------------------------------------------


def df_config(a) -> dict:
    return {"scene": str(SCENES["classroom"]), "method": "hierarchical", **hierarchy_settings(a.epsilon, a.min_area, a.relative, a.rounds),
            "daylight": {"sky": {"model": "cie_overcast", "horizontal_illuminance": 10000.0},
                         "sun": {"enabled": False}, "patches": a.patches, "subdivisions": a.subdivisions,
                         "daylight_factor": True},
            "grids": {"workplane": {"kind": "workplane", "polygon": CLASSROOM_FLOOR, "height": a.height,
                                    "border": 0.5, "spacing": a.spacing}},
            "outputs": {"usd": True, "lightmaps": {"enabled": False}, "preview": {"enabled": False}, "report": True}}


def to_z_up(p: np.ndarray) -> np.ndarray:
    """World Y-up points as Radiance's Z-up ones, the turn `xform -rx 90` makes: (x, -z, y)."""
    return np.stack([p[:, 0], -p[:, 2], p[:, 1]], axis=1)


def classroom_df(a) -> None:
    import dataclasses
    import time

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from daylight import (EFFICACY, RAD_RGB, REC709, hirad_bake, oconv, points_text, read_csv,  # noqa: E402
                          rtrace_irradiance, run, write_room)
    from radiance import radiance_env  # noqa: E402

    from hirad import usd
    from hirad.bake import daylight_inputs, load_solution
    from hirad.config.loader import load_config
    from hirad.solution import luminance_y

    def load() -> str:
        return f"load {os.getloadavg()[0]:.2f}"

    scene_path = SCENES["classroom"]
    if not scene_path.exists():
        print(f"classroom: {scene_path} is absent (shared data not on this machine); skipped")
        return
    env = radiance_env()
    version = subprocess.run(["rtrace", "-version"], capture_output=True, env=env, text=True).stdout.strip()
    print(f"machine: nproc {os.cpu_count()}, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at the "
          f"start; {version}")
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = a.keep if a.keep is not None else Path(tmp_)
        tmp.mkdir(parents=True, exist_ok=True)

        # hirad: the bake, timed whole
        cfg = tmp / "classroom_df.yaml"
        cfg.write_text(yaml.safe_dump(df_config(a)))
        out = tmp / "hirad"
        ld_h = load()
        t_bake = hirad_bake(cfg, out, [])
        rep = json.loads((out / "report.json").read_text())
        eh_h = float(rep["grids"]["daylight_factor"]["outside_horizontal_illuminance_lux"])
        tab = read_csv(out / "grids/daylight_factor/workplane.csv")
        pts = np.stack([tab["x"], tab["y"], tab["z"]], axis=1)
        df_h = tab["df_percent"]
        c, h, st = rep["counts"], rep["hierarchy"], rep.get("timings_s", {})
        print(f"hirad bake: {t_bake:.1f} s wall ({ld_h}; report: total {st.get('total', 0):.1f} s, hierarchical "
              f"solve {st.get('hierarchical solve', 0):.1f} s (refine {h['refine_seconds']}, solve "
              f"{h['solve_seconds']}), grids {st.get('grids', 0):.1f} s); {h['elements']} elements, {c['links']} "
              f"links; epsilon {a.epsilon:g}, min_area {a.min_area:g}, relative_epsilon {a.relative:g}, "
              f"{a.rounds} rounds at most, {a.patches} x {a.subdivisions}^2 directions; "
              f"{len(pts)} points at {a.height:g} m, spacing {a.spacing:g} m; E_h,out {eh_h:.1f} lx")
        # hirad's own split at the same points: direct (the sky component) and the rest. The
        # sky's distant lights are made again from the config (the stored solution keeps only
        # the luminaires that are not distant)
        scene = usd.read_scene(str(scene_path), daylight=True)
        day_lights, _ = daylight_inputs(load_config(cfg), scene)
        sol = load_solution(out / "solution.usda")
        sol.field.set_luminaires([d.to_engine() for d in day_lights])
        nrm = np.tile([0.0, 1.0, 0.0], (len(pts), 1))
        res = sol.field.illuminance(np.ascontiguousarray(pts), np.ascontiguousarray(nrm),
                                    np.ascontiguousarray(sol.emitted_radiance), 512, 1, 4)
        sc_h = 100.0 * luminance_y(np.asarray(res.direct)) / eh_h
        ir_h = 100.0 * luminance_y(np.asarray(res.indirect)) / eh_h
        # the same sky cut finer (--fine-sky, 2 x 2 directions a patch), on the same solution:
        # what the sky's discretisation does to the sky component
        fine, _ = daylight_inputs(load_config(cfg, [f"daylight.patches={a.fine_sky}"]), scene)
        sol.field.set_luminaires([d.to_engine() for d in fine])
        res = sol.field.illuminance(np.ascontiguousarray(pts), np.ascontiguousarray(nrm),
                                    np.ascontiguousarray(sol.emitted_radiance), 16, 1, 4)
        sc_fine = 100.0 * luminance_y(np.asarray(res.direct)) / eh_h
        print(f"hirad's solution at the points: sky component (direct) {sc_h.mean():.3f} % + the rest "
              f"{ir_h.mean():.3f} % = {sc_h.mean() + ir_h.mean():.3f} % (the CSV: {df_h.mean():.3f} %, largest "
              f"|difference| {np.abs(sc_h + ir_h - df_h).max():.4f} pp)")

        # Radiance: the same faces, turned Z up; a black copy for the sky component
        nglass = int((scene.face_transmittance > 0).sum()) if scene.face_transmittance is not None else 0
        cnt = write_room(scene, tmp / "room_y.rad")
        write_room(dataclasses.replace(scene, face_reflectance=np.zeros_like(scene.face_reflectance)),
                   tmp / "black_y.rad")
        for name in ("room", "black"):
            with open(tmp / f"{name}.rad", "wb") as f:
                run(["xform", "-rx", "90", str(tmp / f"{name}_y.rad")], env, tmp, stdout=f)
        print(f"Radiance scene: {cnt['faces']} polygons ({nglass} glass: the windows are open), "
              f"{cnt['materials']} materials, from hirad.usd.read_scene, turned Z up (xform -rx 90)")
        b = 10000.0 / EFFICACY
        sky_txt = run(["gensky", "3", "21", "12", "-c", "-B", f"{b:.6f}"], env, tmp).decode()
        (tmp / "overcast.rad").write_text(
            sky_txt + "\nskyfunc glow sky_glow\n0\n0\n4 1 1 1 0\n\nsky_glow source sky\n0\n0\n4 0 0 1 180\n\n"
            "skyfunc glow ground_glow\n0\n0\n4 1 1 1 0\n\nground_glow source ground\n0\n0\n4 0 0 -1 180\n")
        oconv([tmp / "room.rad", tmp / "overcast.rad"], tmp / "df.oct", env, tmp)
        oconv([tmp / "black.rad", tmp / "overcast.rad"], tmp / "black.oct", env, tmp)
        oconv([tmp / "overcast.rad"], tmp / "sky_only.oct", env, tmp)
        e_out = np.frombuffer(run(["rtrace", "-h", "-I+", "-ab", "1", "-ad", "65536", "-aa", "0", "-lw", "1e-6",
                                   "-fad", str(tmp / "sky_only.oct")], env, tmp, stdin=b"0 0 0 0 0 1\n"),
                              dtype=np.float64)
        eh_r = EFFICACY * float(e_out @ RAD_RGB)
        zpts = to_z_up(pts)
        # what is straight above each point (a desk 4 cm over it, the lectern): rtrace -oL
        up = np.frombuffer(run(["rtrace", "-h", "-ab", "0", "-oL", "-fad", str(tmp / "df.oct")], env, tmp,
                               stdin=points_text(zpts)), dtype=np.float64)
        covered = (up > 0) & (up < 1.0)
        # the surface straight below each point (the floor, the platform, a chair's seat), 1 mm over
        # it: its irradiance, hirad's (its elements, SurfaceSolution.query) and Radiance's
        down = np.frombuffer(run(["rtrace", "-h", "-ab", "0", "-oL", "-fad", str(tmp / "df.oct")], env, tmp,
                                 stdin=points_text(zpts).replace(b" 0 0 1\n", b" 0 0 -1\n")), dtype=np.float64)
        down = np.where((down > 0) & (down < a.height + 0.01), down, a.height)
        floor = pts.copy()
        floor[:, 1] -= down - 1e-3
        floor_h = luminance_y(sol.query(floor, nrm)["irradiance"])  # lux (photometric scene units)

        opts = ["-ab", str(a.ab), "-ad", str(a.ad), "-as", str(a.as_), "-aa", f"{a.aa:g}", "-ar", str(a.ar),
                "-lw", f"{a.lw:g}", "-lr", "-12", "-dj", "0", "-st", "0"]
        ld_r = load()
        rgb, t_rtrace = rtrace_irradiance(env, tmp, "df.oct", opts, points_text(zpts), len(pts), a.processes)
        df_r = 100.0 * EFFICACY * (rgb @ RAD_RGB) / eh_r
        df_r709 = 100.0 * (rgb @ REC709) / float(e_out @ REC709)
        # the sky component: every surface black, one bounce (the glow), no cache
        sk_opts = ["-ab", "1", "-ad", str(a.sky_ad), "-as", "0", "-aa", "0", "-lw", "1e-7", "-dj", "0", "-st", "0"]
        ld_s = load()
        t0 = time.perf_counter()
        raw = run(["rtrace", "-h", "-I+", "-fad", *sk_opts, "-n", str(a.processes), str(tmp / "black.oct")], env,
                  tmp, stdin=points_text(zpts))
        t_sky = time.perf_counter() - t0
        sc_r = 100.0 * EFFICACY * (np.frombuffer(raw, dtype=np.float64).reshape(-1, 3) @ RAD_RGB) / eh_r
        # the floor under the points, with the same ambient file
        zfloor = to_z_up(floor)
        ld_f = load()
        t0 = time.perf_counter()
        raw = run(["rtrace", "-h", "-I+", "-fad", *opts, "-af", str(amb), "-n", str(a.processes),
                   str(tmp / "df.oct")], env, tmp, stdin=points_text(zfloor))
        t_floor = time.perf_counter() - t0
        floor_r = EFFICACY * (np.frombuffer(raw, dtype=np.float64).reshape(-1, 3) @ RAD_RGB)

        print(f"Radiance: gensky 3 21 12 -c -B {b:.4f} (zenith {sky_txt.split()[-2]} W/(m^2 sr), ground "
              f"{sky_txt.split()[-1]}); E_h,out by rtrace on the sky alone {eh_r:.1f} lx")
        print(f"rtrace -I {' '.join(opts)} -af -n {a.processes}: {t_rtrace:.1f} s wall ({ld_r}); sky component "
              f"rtrace -I {' '.join(sk_opts)} on the black scene: {t_sky:.1f} s ({ld_s}); floor points: "
              f"{t_floor:.1f} s ({ld_f})")
        print()
        print(f"{'':10s} {'mean DF %':>10s} {'min DF %':>9s} {'max DF %':>9s} {'wall s':>8s}")
        print(f"{'hirad':10s} {df_h.mean():10.3f} {df_h.min():9.3f} {df_h.max():9.3f} {t_bake:8.1f}   (the whole bake, "
              f"{ld_h} at its start)")
        print(f"{'Radiance':10s} {df_r.mean():10.3f} {df_r.min():9.3f} {df_r.max():9.3f} {t_rtrace:8.1f}   (rtrace "
              f"only, {ld_r} at its start)")
        def rel(x, y) -> str:
            r = x / y - 1.0
            return f"mean {r.mean():+.2%}, RMS {np.sqrt(np.mean(r ** 2)):.2%}, largest |.| {np.abs(r).max():.2%}"

        # a point inside a closed object (the lectern's body) gets no light in Radiance: left out
        inside = df_r < 0.01
        free, cov = ~covered & ~inside, covered & ~inside
        print(f"{int(inside.sum())} points lie inside a closed object (Radiance DF < 0.01 %; hirad there: largest "
              f"{df_h[inside].max() if inside.any() else 0:.3f} %): left out below")
        for label, m in ((f"the other {int((~inside).sum())} points", ~inside),
                         (f"the {int(free.sum())} with nothing within 1 m above", free),
                         (f"the {int(cov.sum())} under a desk or the lectern", cov)):
            if m.any():
                i = np.flatnonzero(m)[np.argmax(np.abs(df_h[m] / df_r[m] - 1))]
                print(f"{label}: mean DF hirad {df_h[m].mean():.3f} %, Radiance {df_r[m].mean():.3f} % "
                      f"({df_h[m].mean() / df_r[m].mean() - 1:+.2%}); per point (hirad - Radiance) / Radiance: "
                      f"{rel(df_h[m], df_r[m])} (at x {pts[i, 0]:.2f}, z {pts[i, 2]:.2f}: {df_h[i]:.3f} against "
                      f"{df_r[i]:.3f} %)")
        m = sc_r > 0.1
        print(f"sky component (direct light of sky and ground through the openings): mean hirad {sc_h.mean():.3f} %, "
              f"Radiance {sc_r.mean():.3f} % ({sc_h.mean() / sc_r.mean() - 1:+.2%}); per point where Radiance's "
              f"is above 0.1 % ({int(m.sum())}): {rel(sc_h[m], sc_r[m])}")
        print(f"hirad's sky component with the sky cut into {a.fine_sky} x 2^2 directions (same solution): mean "
              f"{sc_fine.mean():.3f} % ({sc_fine.mean() / sc_r.mean() - 1:+.2%} against Radiance; per point "
              f"{rel(sc_fine[m], sc_r[m])}); {a.patches} x {a.subdivisions}^2 against it: per point "
              f"{rel(sc_h[m], sc_fine[m])}")
        ir_r = df_r - sc_r
        m = ~inside
        print(f"the rest (interreflected light): mean hirad {ir_h[m].mean():.3f} %, Radiance {ir_r[m].mean():.3f} % "
              f"({ir_h[m].mean() / ir_r[m].mean() - 1:+.2%})")
        ok = np.isfinite(floor_h) & (floor_r > 0)
        print(f"irradiance of the surface under the points (the floor, or the platform or a seat; lux, {int(ok.sum())} "
              f"points): hirad's elements mean {floor_h[ok].mean():.1f} (min {floor_h[ok].min():.1f}, max "
              f"{floor_h[ok].max():.1f}), Radiance {floor_r[ok].mean():.1f} (min {floor_r[ok].min():.1f}, max "
              f"{floor_r[ok].max():.1f}) ({floor_h[ok].mean() / floor_r[ok].mean() - 1:+.2%}); per point "
              f"{rel(floor_h[ok], floor_r[ok])}")
        # by distance from the west wall (x = -4.2 m, its windows open to the outside)
        x = pts[:, 0]
        parts = []
        for lo, hi in ((-4.2, -2.0), (-2.0, 0.0), (0.0, 2.0), (2.0, 4.0)):
            m = (x >= lo) & (x < hi) & ~inside
            parts.append(f"x {lo:g}..{hi:g} m ({int(m.sum())}): hirad {df_h[m].mean():.2f} %, Radiance "
                         f"{df_r[m].mean():.2f} % ({df_h[m].mean() / df_r[m].mean() - 1:+.1%})")
        print("by x (west windows at x = -4.2 m, hallway windows at x = 3.94 m): " + "; ".join(parts))
        print(f"Radiance with Rec.709 weights: mean DF {df_r709.mean():.3f} % ({df_r709.mean() / df_r.mean() - 1:+.2%})"
              f"; with the nominal 10,000 lx: {df_r.mean() * eh_r / 10000.0:.3f} %")
        print(f"speed: rtrace takes {t_rtrace / t_bake:.2f}x the wall time of hirad's whole bake (both on "
              f"{os.cpu_count()} cores)")
        np.savetxt(tmp / "points.csv", np.column_stack([pts, df_h, df_r, sc_h, sc_r, sc_fine, ir_h, floor_h, floor_r,
                                                        up, down]),
                   delimiter=",", header="x,y,z,df_hirad,df_radiance,sky_hirad,sky_radiance,sky_hirad_fine,rest_hirad,"
                   "below_lx_hirad,below_lx_radiance,up_distance,down_distance", comments="")
    print(f"total wall time {time.perf_counter() - t_all:.1f} s; load average at the end "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epsilon", type=float, default=None,
                    help="hierarchy.epsilon (default 1e-3; with --df 1e-5: the classroom's ground plane)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--df", action="store_true", help="the classroom's daylight factor against Radiance rtrace")
    ap.add_argument("--min-area", type=float, default=0.02, help="--df: hierarchy.min_area")
    ap.add_argument("--relative", type=float, default=0.0, help="--df: hierarchy.relative_epsilon")
    ap.add_argument("--rounds", type=int, default=3, help="--df: hierarchy.max_rounds")
    ap.add_argument("--patches", default="reinhart2", help="--df: daylight.patches")
    ap.add_argument("--subdivisions", type=int, default=2, help="--df: daylight.subdivisions")
    ap.add_argument("--height", type=float, default=0.8, help="--df: work plane height over the floor (m)")
    ap.add_argument("--spacing", type=float, default=0.5, help="--df: grid spacing (m)")
    ap.add_argument("--ab", type=int, default=8, help="--df: rtrace -ab")
    ap.add_argument("--ad", type=int, default=4096, help="--df: rtrace -ad")
    ap.add_argument("--as", dest="as_", type=int, default=1024, help="--df: rtrace -as")
    ap.add_argument("--aa", type=float, default=0.1, help="--df: rtrace -aa")
    ap.add_argument("--ar", type=int, default=2048, help="--df: rtrace -ar (the scene is 222 m wide: its ground)")
    ap.add_argument("--lw", type=float, default=1e-4, help="--df: rtrace -lw (Russian roulette below it, -lr -12)")
    ap.add_argument("--sky-ad", type=int, default=65536, help="--df: -ad of the sky-component rtrace")
    ap.add_argument("--processes", type=int, default=os.cpu_count() or 1, help="--df: rtrace -n")
    ap.add_argument("--keep", type=Path, default=None, help="--df: work in this directory and keep it")
    ap.add_argument("--fine-sky", default="reinhart8", help="--df: the finer sky of the sky-component check")
    a = ap.parse_args()
    if a.epsilon is None:
        a.epsilon = 1e-5 if a.df else 1e-3
    if a.df:
        classroom_df(a)
        return
    print(f"nproc {os.cpu_count()}, load {open('/proc/loadavg').read().split()[:3]}")
    for name in a.scenes:
        scene = SCENES[name]
        if not scene.exists():
            print(f"{name}: {scene} is absent (shared data not on this machine); skipped")
            continue
        with tempfile.TemporaryDirectory() as tmp:
            r = bake(scene, a.epsilon, Path(tmp))
        c, h, eb = r["counts"], r["hierarchy"], r["energy_balance"]
        print(f"{name}: {c['input_faces']} input faces, {h['elements']} elements, {c['links']} links, "
              f"{h['link_estimates']} link estimates, {c['rays']} rays; peak RSS {r['peak_rss_mib']:.0f} MiB; "
              f"energy balance {eb['max_relative_error']:.2e}; direct light received {eb['direct_received_W'][1]:.4g}")
        print(f"  stages (s): {json.dumps(r['timings_s'])}; refine {h['refine_seconds']}, solve {h['solve_seconds']}")
        print(f"  warnings: {len(r.get('warnings', []))}")


if __name__ == "__main__":
    main()
