"""Distributed link generation of one out-of-core bake: the Modern Hall (../shared/data) baked
on this machine and with `--scheduler` on a LocalCluster of 1 and of 2 worker processes (one
engine thread each, so a worker stands for one machine), in one run; the stores are checked to
be the same bytes. Then a model of 8 and 64 machines from what was measured.

    python bench/distributed_links.py [--epsilon E] [--group-faces N] [--link-threads T]

The model: a refinement round on M machines takes the driver's dispatch and merge (measured)
plus the longest machine's share, the round's groups dealt out as contiguous ranges (2 per
machine, as hirad does) with each group costing its measured time (1-worker run, whose tasks
ran one at a time), plus a per-task engine load (measured) the first time a machine works on
the bake. Network bytes: each worker writes its spill (its range's chunks, the sizes of the
final store's chunks stand for them) to the shared store and reads the previous round's chunks
of its groups; the driver reads every spill once and writes the round's store. Printed; nothing
is asserted.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO.parent / "shared" / "data" / "modern_hall" / "usd" / "modern_hall.usda"


def bake(cfg: Path, *extra) -> float:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "hirad.cli", "bake", str(cfg), "--quiet", *map(str, extra)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"hirad bake failed ({r.returncode}): {r.stderr.strip()}")
    return time.perf_counter() - t


def digest(store: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(store.glob("round-*/*")):
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()[:16]


def model(machines: int, tasks: list, merge: list, load: float, group_bytes: dict) -> tuple[float, float]:
    """(seconds of link generation, network bytes) on `machines` machines."""
    seconds = 0.0
    net = 0.0
    rounds = sorted({t["round"] for t in tasks})
    for i, rnd in enumerate(rounds):
        per_group = []
        for t in sorted((t for t in tasks if t["round"] == rnd), key=lambda t: t["begin"]):
            per_group += t["group_seconds"]
        n = len(per_group)
        k = max(1, min(n, 2 * machines))
        cuts = [n * j // k for j in range(k + 1)]
        ranges = sorted((sum(per_group[b:e]) for b, e in zip(cuts, cuts[1:])), reverse=True)
        share = [0.0] * machines
        for r in ranges:  # longest first onto the least loaded machine (what the scheduler does)
            share[share.index(min(share))] += r
        seconds += max(share) + (load if i == 0 else 0.0) + (merge[i] if i < len(merge) else 0.0)
        spill = sum(group_bytes.values())
        net += 2 * spill + (spill if i > 0 else 0)  # workers write, driver reads; workers read round - 1
    return seconds, net


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epsilon", type=float, default=1e-4)
    ap.add_argument("--group-faces", type=int, default=1024)
    ap.add_argument("--link-threads", type=int, default=1)
    args = ap.parse_args()
    if not SCENE.exists():
        print(f"{SCENE} is absent: nothing to measure")
        return 0
    from distributed import LocalCluster

    with tempfile.TemporaryDirectory(prefix="hirad_dist_") as tmp:
        tmp = Path(tmp)
        base = {"scene": str(SCENE), "method": "hierarchical",
                "hierarchy": {"epsilon": args.epsilon, "min_area": 0.01, "samples": 8, "max_rounds": 3},
                "solver": {"method": "block_southwell", "tolerance": 1e-4},
                "links": {"group_faces": args.group_faces}, "threads": args.link_threads,
                "outputs": {"usd": True, "lightmaps": {"enabled": False}, "volume": {"enabled": False},
                            "preview": {"enabled": False}, "report": True}}
        runs = {}
        for name in ("local", "w1", "w2"):
            (tmp / f"{name}.yaml").write_text(yaml.safe_dump(dict(base, output=str(tmp / name))))
        runs["local"] = bake(tmp / "local.yaml")
        for n in (1, 2):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
            try:
                runs[f"w{n}"] = bake(tmp / f"w{n}.yaml", "--scheduler", cluster.scheduler_address,
                                     "--link-threads", args.link_threads)
            finally:
                cluster.close()
        reps = {k: json.loads((tmp / k / "report.json").read_text()) for k in runs}
        same = len({digest(tmp / f"{k}.links") for k in runs}) == 1
        print(f"Modern Hall, epsilon {args.epsilon:g}, group_faces {args.group_faces}, {args.link_threads} engine "
              f"thread(s) per task; nproc {os.cpu_count()}; load {os.getloadavg()[0]:.2f}")
        r0 = reps["local"]
        print(f"links {r0['counts']['links']}, source groups {r0['links']['source_groups']}, rounds "
              f"{r0['hierarchy']['rounds']}; stores identical in all three runs: {same}")
        print(f"{'run':<22}{'bake s':>9}{'refine s':>10}{'solve s':>9}{'merge s':>9}")
        for k, label in (("local", "this machine"), ("w1", "1 worker"), ("w2", "2 workers")):
            h = reps[k]["hierarchy"]
            d = reps[k]["links"]["distributed"]
            merge = sum(d["merge_seconds"]) if d else 0.0
            print(f"{label:<22}{runs[k]:9.2f}{sum(h['refine_seconds']):10.2f}{sum(h['solve_seconds']):9.2f}"
                  f"{merge:9.2f}")
        r1, r2 = reps["w1"]["hierarchy"], reps["w2"]["hierarchy"]
        print(f"refinement speed-up 1 -> 2 workers: {sum(r1['refine_seconds']) / sum(r2['refine_seconds']):.2f}x; "
              f"whole bake {runs['w1'] / runs['w2']:.2f}x")
        d1 = reps["w1"]["links"]["distributed"]
        tasks, merge = d1["tasks"], d1["merge_seconds"]
        load = max(t["load_seconds"] for t in tasks)
        store = tmp / "w1.links"
        group_bytes = {}
        for p in store.glob("round-*/chunk-*.hlc"):
            group_bytes[p.name] = p.stat().st_size
        print(f"per-task engine load (first task of a worker) {load:.2f} s; final store {sum(group_bytes.values())} "
              f"bytes in {len(group_bytes)} chunks")
        measured = sum(sum(t["group_seconds"]) for t in tasks)
        print(f"measured group refinement, all rounds (1 worker): {measured:.2f} s; merges {sum(merge):.2f} s")
        for m in (1, 2, 8, 64):
            s, net = model(m, tasks, merge, load, group_bytes)
            print(f"model, {m:>2} machines: link generation {s:8.2f} s, network {net / 1e6:8.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
