"""Calculation-grid read-out: a 10,000-point work plane on a stored Modern Hall bake.

    python bench/grids.py [--points 10000] [--check 200] [--epsilon 1e-5] [--min-area 0.005]

1. Bakes ../shared/data/modern_hall (hierarchical, the bench/hierarchy.py hall settings,
   outputs off) once, in process.
2. Times SurfaceField.illuminance (hirad.solution: exact direct light of the emitter patches,
   gathered indirect light) on a regular work plane of --points sensors 0.80 m above the
   floor, facing up, and prints Em / Emin / Emax of it.
3. Checks --check of those read-outs against the Monte Carlo reference (`hirad reference`'s
   engine call) at upward-facing points: sensors 1 mm above reflecting leaves, whose reference
   irradiance is (pi L - E) / rho of the reference's exitant radiance L there. Prints the
   relative error of the photometric Y (Rec.709 weights) and the reference's own standard
   error.
Every timing line states the 1-minute load average at its start (the machine may be shared).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
HALL = ROOT.parent / "shared/data/modern_hall/usd/modern_hall.usda"
LUM = np.array([0.2126, 0.7152, 0.0722])


def load() -> str:
    return f"load {os.getloadavg()[0]:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10000)
    ap.add_argument("--check", type=int, default=200)
    ap.add_argument("--rays", type=int, default=512)
    ap.add_argument("--epsilon", type=float, default=1e-5)
    ap.add_argument("--min-area", type=float, default=0.005)
    ap.add_argument("--paths", type=int, default=4096, help="reference paths per check point")
    args = ap.parse_args()
    if not HALL.exists():
        raise SystemExit(f"{HALL} is absent: nothing to measure")
    import tempfile

    from hirad import _engine
    from hirad.bake import bake
    from hirad.config import config_from_dict

    with tempfile.TemporaryDirectory() as tmp:
        cfg = config_from_dict({
            "scene": str(HALL), "output": str(Path(tmp) / "out"), "method": "hierarchical",
            "hierarchy": {"epsilon": args.epsilon, "min_area": args.min_area, "samples": 16},
            "solver": {"method": "jacobi", "tolerance": 1e-4},
            "outputs": {"usd": False, "lightmaps": {"enabled": False}, "preview": {"enabled": False}, "report": True}})
        ld = load()
        t0 = time.perf_counter()
        res = bake(cfg, keep_hierarchy=True)  # (res.gather)
        print(f"bake: {time.perf_counter() - t0:.1f} s ({ld}), {len(res.patches['area'])} leaves")
    p = res.patches
    emitted = np.ascontiguousarray(p["emission"] / np.pi)
    corner_rad = np.ascontiguousarray(np.repeat((res.patch_radiosity / np.pi)[:, None, :], 4, axis=1))
    field = _engine.SurfaceField(np.ascontiguousarray(p["corners"]), p["nv"].astype(np.int32), corner_rad, corner_rad)
    up = 2 if res.up_axis == "Z" else 1
    normal = np.zeros(3)
    normal[up] = 1
    facing_up = p["normal"][:, up] > 0.99
    # the floor: the lowest height (1 cm bins) holding a tenth of the upward-facing area
    heights = np.round(p["centroid"][:, up] / 0.01).astype(np.int64)
    levels, inverse = np.unique(heights[facing_up], return_inverse=True)
    area_at = np.bincount(inverse, weights=p["area"][facing_up])
    floor_bin = levels[np.flatnonzero(area_at >= 0.1 * area_at.sum())[0]]
    floor = facing_up & (heights == floor_bin)
    floor_level = float(p["centroid"][floor, up].max())
    print(f"up axis {res.up_axis}; floor at {floor_level:.3f} m: {int(floor.sum())} leaves, "
          f"{p['area'][floor].sum():.1f} m^2; {int((emitted.max(axis=1) > 0).sum())} emitter leaves")
    lo, hi = p["corners"][floor].reshape(-1, 3).min(0), p["corners"][floor].reshape(-1, 3).max(0)
    axes = [a for a in range(3) if a != up]
    n_side = int(np.ceil(np.sqrt(args.points)))
    u = np.linspace(lo[axes[0]], hi[axes[0]], n_side + 2)[1:-1]
    v = np.linspace(lo[axes[1]], hi[axes[1]], n_side + 2)[1:-1]
    uu, vv = np.meshgrid(u, v)
    pts = np.zeros((uu.size, 3))
    pts[:, axes[0]], pts[:, axes[1]], pts[:, up] = uu.ravel(), vv.ravel(), floor_level + 0.80
    pts = np.ascontiguousarray(pts[:args.points])
    nrm = np.ascontiguousarray(np.tile(normal, (len(pts), 1)))
    ld = load()
    t0 = time.perf_counter()
    field.illuminance(pts, nrm, emitted, rays=0, seed=1)
    print(f"  direct light alone: {time.perf_counter() - t0:.2f} s ({ld})")
    ld = load()
    t0 = time.perf_counter()
    e = field.illuminance(pts, nrm, emitted, rays=args.rays, seed=1)
    dt = time.perf_counter() - t0
    y = (np.asarray(e.direct) + np.asarray(e.indirect)) @ LUM
    print(f"work plane 0.80 m, {len(pts)} sensors, {args.rays} rays each: {dt:.2f} s ({ld}); "
          f"Em {y.mean():.4g}, Emin {y.min():.4g}, Emax {y.max():.4g} (scene units, Y)")

    # the check against the Monte Carlo reference, at floor points
    rng = np.random.default_rng(7)
    # check points: upward-facing leaves that reflect (the reference reads irradiance as
    # (pi L - E) / rho, which needs rho > 0), anywhere in the hall
    candidates = np.flatnonzero(facing_up & (p["reflectance"].min(axis=1) > 0.02) & (p["emission"].max(axis=1) == 0))
    idx = rng.choice(candidates, size=min(args.check, len(candidates)), replace=False)
    centres = np.ascontiguousarray(p["centroid"][idx])
    fn = np.ascontiguousarray(p["normal"][idx])
    ld = load()
    t0 = time.perf_counter()
    ref = res._model.reference_at(centres, fn, _engine.ReferenceOptions(paths=args.paths, seed=3), 1e-3)
    t_ref = time.perf_counter() - t0
    lref, se = np.asarray(ref.radiance), np.asarray(ref.standard_error)
    rho = p["reflectance"][idx]
    e_ref = ((np.pi * lref - p["emission"][idx]) / rho) @ LUM
    e_ref_se = (np.pi * se / rho) @ LUM
    t0 = time.perf_counter()
    mine = field.illuminance(np.ascontiguousarray(centres + fn * 1e-3), fn, emitted, rays=args.rays, seed=1)
    t_mine = time.perf_counter() - t0
    y_mine = (np.asarray(mine.direct) + np.asarray(mine.indirect)) @ LUM
    # the same points by the bake's own final gather (its links re-evaluated at the point):
    # what the solution says there, so that the read-out's error and the solution's separate
    g = res.gather(centres, fn, rays=16)
    y_gather = np.asarray(g["irradiance"]) @ LUM
    ok = e_ref > 0
    print(f"check at {len(idx)} upward-facing points ({int((~ok).sum())} unlit in the reference dropped): reference "
          f"{args.paths} paths {t_ref:.1f} s ({ld}), hirad illuminance {t_mine:.2f} s")
    print(f"  reference's own relative standard error (mean) {(e_ref_se[ok] / e_ref[ok]).mean():.3%}; "
          f"direct share {(np.asarray(mine.direct) @ LUM)[ok].sum() / y_mine[ok].sum():.1%}")
    for name, y_ in (("illuminance (the grids' read-out)", y_mine), ("final gather (the bake's links)", y_gather)):
        rel = (y_[ok] - e_ref[ok]) / e_ref[ok]
        print(f"  {name}: Y error vs reference mean {rel.mean():+.3%}, median |.| {np.median(np.abs(rel)):.3%}, "
              f"summed {y_[ok].sum() / e_ref[ok].sum() - 1:+.3%}")

if __name__ == "__main__":
    main()
