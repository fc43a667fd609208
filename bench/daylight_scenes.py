"""The shared daylight scenes baked with their authored lights: ../shared/data/classroom (a
uniform DomeLight and a DistantLight sun through open windows) and ../shared/data/living_room
(a latlong-textured DomeLight through glass). Prints, per scene: triangles, elements, links,
the time of each stage, peak RSS, the energy balance and the number of distant-light directions.

    python bench/daylight_scenes.py [--epsilon 1e-3] [--scenes classroom living_room]

Each bake runs in a child process (wait4 gives its peak RSS). The scenes are not in the
project (they are CC BY data in ../shared/data): the bench says so and stops when they are
absent.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
SCENES = {"classroom": DATA / "classroom" / "usd" / "classroom.usdc",
          "living_room": DATA / "living_room" / "usd" / "living_room.usdc"}


def bake(scene: Path, epsilon: float, tmp: Path) -> dict:
    cfg = {"scene": str(scene), "output": str(tmp / "out"), "method": "hierarchical",
           "hierarchy": {"epsilon": epsilon, "min_area": 0.02, "samples": 4, "max_rounds": 3},
           "solver": {"method": "jacobi", "tolerance": 1e-3},
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epsilon", type=float, default=1e-3)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    a = ap.parse_args()
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
