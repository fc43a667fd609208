"""Radiosity against the Monte Carlo reference on the Cornell box: per-surface mean radiance.

For every surface (input mesh) of configs/cornell.yaml, the bake's area-weighted mean of
B/pi is compared with a path-traced estimate of the mean exitant radiance over the same
surface (a random point in every patch, weighted by its area, each with many paths;
`Engine.reference_at`). Prints both, the
relative difference in luminance and the reference's standard error. Usage:

    python bench/reference_cornell.py [CONFIG.yaml] [--points 64] [--paths 1024]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import hirad
from hirad import _engine, usd
from hirad.config import load_config
from hirad.engine import build_engine

ROOT = Path(__file__).resolve().parent.parent
LUM = np.array([0.2126, 0.7152, 0.0722])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("config", nargs="?", type=Path, default=ROOT / "configs/cornell.yaml")
    ap.add_argument("--points", type=int, default=64, help="points per patch = points // 64, at least 1")
    ap.add_argument("--paths", type=int, default=1024)
    args = ap.parse_args()

    cfg = load_config(args.config)
    with tempfile.TemporaryDirectory() as tmp:
        cfg.output = Path(tmp) / "out"
        cfg.outputs.lightmaps.enabled = cfg.outputs.preview.enabled = cfg.outputs.usd = False
        t0 = time.perf_counter()
        result = hirad.bake(cfg)
        bake_s = time.perf_counter() - t0
    p = result.patches
    b = result.patch_radiosity

    # The reference runs on the input faces (it needs no meshing): a random point in every
    # patch of the bake, repeated points // 64 times, each weighted by its patch's area.
    scene = usd.read_scene(cfg.scene)
    model = build_engine(scene)
    model.mesh(_engine.MeshOptions(max_patch_area=1e9, max_edge_length=1e9))
    rng = np.random.default_rng(1)
    reps = max(1, args.points // 64)
    ids = np.tile(np.arange(len(b)), reps)
    s, t = rng.random(ids.size), rng.random(ids.size)
    c = p["corners"][ids]
    tri = p["nv"][ids] == 3
    fold = tri & (s + t > 1)
    s, t = np.where(fold, 1 - s, s), np.where(fold, 1 - t, t)
    quad_pts = (c[:, 0] * ((1 - s) * (1 - t))[:, None] + c[:, 1] * (s * (1 - t))[:, None]
                + c[:, 2] * (s * t)[:, None] + c[:, 3] * ((1 - s) * t)[:, None])
    tri_pts = c[:, 0] + (c[:, 1] - c[:, 0]) * s[:, None] + (c[:, 2] - c[:, 0]) * t[:, None]
    points = np.ascontiguousarray(np.where(tri[:, None], tri_pts, quad_pts))
    owner = p["mesh"][ids]
    weight = p["area"][ids]
    t0 = time.perf_counter()
    r = model.reference_at(points, np.ascontiguousarray(p["normal"][ids]),
                           _engine.ReferenceOptions(paths=args.paths, min_bounces=3, seed=7), 1e-4)
    ref = {"radiance": r.radiance, "standard_error": r.standard_error}
    ref_s = time.perf_counter() - t0

    print(f"bake {bake_s:.1f} s ({len(b)} patches); reference {ref_s:.1f} s "
          f"({ids.size} points x {args.paths} paths)")
    print(f"{'surface':<28}{'radiosity L':>13}{'reference L':>13}{'std err':>10}{'diff':>9}")
    worst = 0.0
    for m in np.unique(owner):
        mine = np.nonzero(p["mesh"] == m)[0]
        l_rad = (b[mine] / np.pi * p["area"][mine, None]).sum(axis=0) / p["area"][mine].sum()
        sel = owner == m
        w = weight[sel] / weight[sel].sum()
        l_ref = (ref["radiance"][sel] * w[:, None]).sum(axis=0)
        # Standard error of the weighted mean, from the per-point path errors (the points are
        # stratified over the patches, so spatial variation adds little).
        err = np.sqrt(((ref["standard_error"][sel] * w[:, None]) ** 2).sum(axis=0))
        a, r, e = l_rad @ LUM, l_ref @ LUM, err @ LUM
        diff = a / r - 1
        if not scene.meshes[m].is_light and scene.face_emission[scene.face_mesh == m].max() == 0:
            worst = max(worst, abs(diff))
        print(f"{scene.meshes[m].name:<28}{a:>13.4f}{r:>13.4f}{e:>10.4f}{diff:>+9.2%}")
    print(f"largest difference on a reflecting surface: {worst:.2%}")


if __name__ == "__main__":
    main()
