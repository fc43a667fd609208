"""Throughput and memory of a whole bake, one child process per config.

Prints, per config: patches, links, rays, the time of each stage, rays per second and
form factors (links) per second in the form factor stage, solver iterations per second and
the child's peak resident memory (from wait4's rusage). Usage:

    python bench/run.py [CONFIG.yaml ...] [--threads N]

With no configs it runs configs/cornell.yaml and configs/cornell_10k.yaml.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def run(config: Path, threads: int | None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "report.json"
        cmd = [sys.executable, "-m", "hirad.cli", "bake", str(config), "--json"]
        if threads is not None:
            cmd += ["--threads", str(threads)]
        with open(out, "w") as f:
            proc = subprocess.Popen(cmd, stdout=f)
            _, status, usage = os.wait4(proc.pid, 0)
        if status != 0:
            raise SystemExit(f"bake of {config} failed (status {status})")
        report = json.loads(out.read_text())
    report["peak_rss_mib"] = usage.ru_maxrss / 1024  # ru_maxrss is in KiB on Linux
    return report


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("configs", nargs="*", type=Path)
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    configs = args.configs or [ROOT / "configs/cornell.yaml", ROOT / "configs/cornell_10k.yaml"]
    print(f"{'config':<22}{'patches':>9}{'links':>12}{'rays':>13}{'ff s':>8}{'Mrays/s':>9}"
          f"{'Mlinks/s':>10}{'solve s':>9}{'iter/s':>10}{'total s':>9}{'RSS MiB':>9}")
    for config in configs:
        r = run(config, args.threads)
        t = r["timings_s"]
        ff = t.get("form factors", 0.0)
        # Flat bakes time "solve"; hierarchical ones "hierarchical solve" (refinement included).
        solve = t.get("solve", t.get("hierarchical solve", 0.0))
        c = r["counts"]
        it = r["solver"]["iterations"]
        print(f"{config.stem:<22}{c['patches']:>9}{c['links']:>12}{c['rays']:>13}{ff:>8.2f}"
              f"{(c['rays'] / ff / 1e6 if ff else 0):>9.2f}{(c['links'] / ff / 1e6 if ff else 0):>10.2f}"
              f"{solve:>9.2f}{(it / solve if solve else 0):>10.0f}{t['total']:>9.2f}{r['peak_rss_mib']:>9.0f}")
        print(f"  stages: {json.dumps(t)}")
        print(f"  solver: {r['solver']['method']} {it} iterations, residual {r['solver']['residual']:.2e}; "
              f"energy balance {r['energy_balance']['max_relative_error']:.2e}; threads {r['threads']}")


if __name__ == "__main__":
    main()
