"""Study throughput: N Cornell box variants baked one after another (each `hirad bake` with
all cores) against `hirad batch` on a 2-worker Dask LocalCluster (each bake 1 thread).

    python bench/batch.py [--variants 24] [--workers 2] [--fine]

Both sides run every bake as its own `python -m hirad.cli bake ... --set ...` process (what a
batch job is), so the difference is the scheduling, not the interpreter start. The batch's
figure includes starting the cluster (printed separately). Prints the figures; asserts
nothing. Variants differ by seed (same cost each); `--fine` uses a finer meshing (about 4x
the patches) to show a bake-bound study.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
CORNELL = REPO / "configs" / "scenes" / "cornell_box.usda"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", type=int, default=24)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--fine", action="store_true")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="hirad_bench_batch_"))
    meshing = {"max_patch_area": 0.0025, "max_edge_length": 0.05} if args.fine else \
        {"max_patch_area": 0.01, "max_edge_length": 0.1}
    base = {"scene": str(CORNELL), "method": "flat", "meshing": meshing,
            "outputs": {"preview": {"enabled": False}, "lightmaps": {"max_size": 256}}}
    (root / "base.yaml").write_text(yaml.safe_dump(base))
    variants = [{"name": f"v{i:02d}", "set": {"seed": i + 1}} for i in range(args.variants)]
    (root / "study.yaml").write_text(yaml.safe_dump({"base": "base.yaml", "variants": variants,
                                                     "workers": args.workers, "threads": 1, "retries": 0}))
    cores = os.cpu_count() or 1
    print(f"{args.variants} variants of the Cornell box ({'fine' if args.fine else 'coarse'} meshing), "
          f"{cores} cores, load average {os.getloadavg()[0]:.2f} at the start")

    t = time.perf_counter()
    for v in variants:
        out = root / "seq" / v["name"]
        r = subprocess.run([sys.executable, "-m", "hirad.cli", "bake", str(root / "base.yaml"), "--quiet",
                            "--threads", str(cores), "--set", f"seed={v['set']['seed']}", "--set", f"output={out}"],
                           capture_output=True, text=True)
        if r.returncode:
            sys.exit(f"bake failed: {r.stderr}")
    seq = time.perf_counter() - t
    print(f"sequential ({cores} threads a bake): {seq:.1f} s, {args.variants / seq * 60:.1f} bakes/min, "
          f"load {os.getloadavg()[0]:.2f}")

    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "hirad.cli", "batch", str(root / "study.yaml"), "--json",
                        "--progress", "jsonl"], capture_output=True, text=True)
    wall = time.perf_counter() - t
    if r.returncode:
        sys.exit(f"batch failed ({r.returncode}): {r.stderr[-2000:]}")
    events = [json.loads(l) for l in r.stderr.splitlines() if l.startswith("{")]
    started = next(e["elapsed"] for e in events if e["event"] == "cluster")
    jobs = [e for e in events if e["event"] == "job"]
    busy = sum(e["seconds"] for e in jobs)
    print(f"hirad batch, LocalCluster {args.workers} workers x 1 thread a bake: {wall:.1f} s "
          f"({started:.1f} s to start the cluster, {wall - started:.1f} s of jobs), "
          f"{args.variants / wall * 60:.1f} bakes/min; {args.variants / max(1e-9, wall - started) * 60:.1f} bakes/min "
          f"without the start; mean job {busy / len(jobs):.2f} s; load {os.getloadavg()[0]:.2f}")
    print(f"speed-up {seq / wall:.2f}x ({seq / max(1e-9, wall - started):.2f}x without the cluster start)")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "hirad.cli", "batch", str(root / "study.yaml"), "--json"],
                       capture_output=True, text=True)
    print(f"rerun of the finished study: {time.perf_counter() - t:.2f} s, "
          f"{json.loads(r.stdout)['run']} jobs run")
    shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
