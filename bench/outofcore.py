"""Out of core: link store size, peak memory against the budget, streaming throughput.

    python bench/outofcore.py [--scene PATH] [--epsilon E] [--min-area A] [--group-faces G]
                              [--budget BYTES]

Default scene: the Modern Hall (../shared/data/modern_hall; skipped with a message when
absent). One child process per bake (peak RSS from wait4). Steps:
  1. bake with the links on disk (2 threads, then 1 thread: link generation speed-up);
  2. --reuse-links solves (no refinement) of the stored links: with the budget, the page cache
     dropped first when this process may (cold), with the budget again (warm), with an
     unlimited budget (links decoded once, then in memory), and with the budget on 1 thread;
  3. this machine's memory bandwidth (numpy copy of 512 MiB) in the same run.
Figures are printed, not asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
HALL = ROOT.parent / "shared/data/modern_hall/usd/modern_hall.usda"
OFF = {"usd": False, "lightmaps": {"enabled": False}, "preview": {"enabled": False}, "report": True}


def bake(cfg: dict, tmp: Path, *flags: str, threads: int = 0) -> dict:
    path = tmp / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    cmd = [sys.executable, "-m", "hirad.cli", "bake", str(path), "--json", "--quiet", "--threads", str(threads), *flags]
    t0 = time.perf_counter()
    with open(tmp / "report.json", "w") as f:
        proc = subprocess.Popen(cmd, stdout=f)
        _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise SystemExit(f"bake failed (status {status}): {' '.join(cmd)}")
    r = json.loads((tmp / "report.json").read_text())
    r["peak_rss"] = usage.ru_maxrss * 1024
    r["wall"] = time.perf_counter() - t0
    return r


def drop_page_cache() -> bool:
    try:
        os.sync()
        Path("/proc/sys/vm/drop_caches").write_text("3\n")
        return True
    except OSError:
        return False


def bandwidth() -> float:
    a = np.ones(64 << 20)          # 512 MiB of float64
    b = np.empty_like(a)
    best = 0.0
    for _ in range(5):
        t0 = time.perf_counter()
        np.copyto(b, a)
        best = max(best, 2 * a.nbytes / (time.perf_counter() - t0))   # read + write
    return best


def mib(x: float) -> str:
    return f"{x / 2 ** 20:,.1f} MiB"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=HALL)
    ap.add_argument("--epsilon", type=float, default=1e-6)
    ap.add_argument("--min-area", type=float, default=4e-3)
    ap.add_argument("--group-faces", type=int, default=128)
    ap.add_argument("--budget", type=str, default=None, help="bytes; default: the smallest the solver takes + 10 %%")
    ap.add_argument("--no-one-thread-bake", action="store_true",
                    help="skip the 1-thread bake (the link generation speed-up), the longest step")
    args = ap.parse_args()
    if not args.scene.exists():
        print(f"{args.scene} is absent: out-of-core benchmark skipped")
        return
    print(f"[{time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}] "
          f"{args.scene.name}: epsilon {args.epsilon:g}, min_area {args.min_area:g}, group_faces {args.group_faces}")
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        store = tmp / "links"
        cfg = {"scene": str(args.scene), "output": str(tmp / "out"), "method": "hierarchical",
               "hierarchy": {"epsilon": args.epsilon, "min_area": args.min_area, "samples": 16},
               "solver": {"method": "block_southwell", "tolerance": 1e-4},
               "links": {"store": str(store), "memory_budget": 0, "group_faces": args.group_faces,
                         "checkpoint_seconds": 0}, "outputs": OFF}
        r2 = bake(cfg, tmp, threads=2)
        lk, h = r2["links"], r2["hierarchy"]
        links = r2["counts"]["links"]
        store_bytes = sum(p.stat().st_size for p in store.rglob("*") if p.is_file() and "round-" in str(p))
        st = lk["last_solve"]
        minimum = st["minimum_budget"]
        decoded = st["decoded_bytes"]          # what a solve holds of every link, decoded
        budget = int(args.budget) if args.budget else int(minimum * 1.1)
        print(f"links {links:,} ({lk['source_groups']} source groups, largest chunk {mib(st['largest_chunk_bytes'])} "
              f"decoded), elements {h['elements']:,}, nodes {h['nodes']:,}; store on disk {mib(store_bytes)} = "
              f"{store_bytes / links:.2f} bytes/link, of which transport sections {lk['transport_bytes'] / links:.2f} "
              f"bytes/link (decoded for a solve: {mib(decoded)}, whole links {mib(24 * links)}); "
              f"solver state {mib(st['state_bytes'])}")
        gen2 = sum(h["refine_seconds"])
        print(f"bake, 2 threads: refinement {gen2:.1f} s, {h['link_estimates']:,} link estimates "
              f"({h['link_estimates'] / gen2 / 1e6:.2f} M/s), solves {sum(h['solve_seconds']):.1f} s, "
              f"wall {r2['wall']:.1f} s, peak RSS {mib(r2['peak_rss'])}")
        # The 1-thread bake runs within the budget: its peak RSS is link generation's and the
        # solve's with the budget (the first bake's solve kept every chunk decoded).
        cfg1 = dict(cfg, links=dict(cfg["links"], store=str(tmp / "links1"), memory_budget=budget))
        r1 = None if args.no_one_thread_bake else bake(cfg1, tmp, threads=1)
        if r1 is not None:
            gen1 = sum(r1["hierarchy"]["refine_seconds"])
            held = r1["links"]["peak_refine_links"]
            print(f"bake, 1 thread, within the budget: refinement {gen1:.1f} s -> link generation speed-up 1 -> 2 "
                  f"threads {gen1 / gen2:.2f}x; same links: {r1['counts']['links'] == links}; link generation held at "
                  f"most {held:,} links ({mib(24 * held)} as 24-byte links, {held / links:.2%} of them); "
                  f"peak RSS {mib(r1['peak_rss'])}")
        print(f"budget {budget:,} bytes ({mib(budget)}): the store is {store_bytes / budget:.1f}x the budget "
              f"(decoded for a solve {decoded / budget:.1f}x)")

        def solve(b: int, threads: int, label: str, cold: bool = False) -> dict:
            c = dict(cfg, links=dict(cfg["links"], memory_budget=b))
            dropped = drop_page_cache() if cold else False
            r = bake(c, tmp, "--reuse-links", threads=threads)
            s = r["links"]["last_solve"]
            secs = sum(r["hierarchy"]["solve_seconds"])
            rate = s["links_shot"] / secs
            print(f"  {label:<34} solve {secs:6.2f} s, {s['links_shot']:,} links shot = {rate / 1e6:6.2f} M links/s, "
                  f"chunk reads {s['chunk_reads']:,}, from memory {s['chunk_hits']:,}, reader wait {s['read_wait_seconds']:.2f} s, "
                  f"peak RSS {mib(r['peak_rss'])}{'' if not cold else (' (page cache dropped)' if dropped else ' (could not drop the page cache: warm)')}")
            return {"rate": rate, "secs": secs, "r": r}

        print("re-solves of the stored links (--reuse-links, no refinement):")
        cold = solve(budget, 2, "budget, cold cache", cold=True)
        warm = solve(budget, 2, "budget, warm cache")
        mem = solve(0, 2, "unlimited budget (in memory)")
        one = solve(budget, 1, "budget, warm, 1 thread")
        bw = bandwidth()
        print(f"out of core / in memory, links shot per second: warm {warm['rate'] / mem['rate']:.2f}, "
              f"cold {cold['rate'] / mem['rate']:.2f} (target >= 0.7 warm)")
        print(f"solve speed-up 1 -> 2 threads (budget, warm): {one['secs'] / warm['secs']:.2f}x")
        per_link = decoded / links                # bytes of decoded transport per link
        print(f"memory bandwidth (numpy copy, read + write): {bw / 1e9:.2f} GB/s; solver throughput in decoded link "
              f"bytes ({per_link:.2f} per link): out of core {warm['rate'] * per_link / 1e9:.3f} GB/s = "
              f"{warm['rate'] * per_link / bw:.1%} of it, in memory {mem['rate'] * per_link / 1e9:.3f} GB/s = "
              f"{mem['rate'] * per_link / bw:.1%}; file bytes read out of core {warm['rate'] * store_bytes / links / 1e9:.3f} GB/s")
        print(f"peak RSS out of core {mib(warm['r']['peak_rss'])} against budget {mib(budget)} (+ the scene, the "
              f"hierarchy, Python and usd-core: in memory the same bake peaks at {mib(mem['r']['peak_rss'])})")


if __name__ == "__main__":
    main()
