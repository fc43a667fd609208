"""Relighting against baking: `hirad relight` of a variant (one panel of the office dimmed to 0.3,
the other tinted) against a full `hirad bake` of the same variant (the config with those
dimmers), both as CLI processes, plus the relight alone in-process (no Python start-up).

    python bench/relight.py [CONFIG] [--repeat N]
    python bench/relight.py --hall [--epsilon E]   # the Modern Hall, solve only (USD output, no
                                                   # lightmaps or grids): spots / panels / rest

CONFIG defaults to configs/office_room.yaml with `lights.groups: {panel: {each: true}}` and a
work-plane grid added; outputs go to a temporary directory. Prints the times; nothing is asserted.
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

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))


def _cli(*args) -> float:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "hirad.cli", *map(str, args)], capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"hirad {args[0]} failed ({r.returncode}): {r.stderr.strip()}")
    return time.perf_counter() - t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", default=str(REPO / "configs" / "office_room.yaml"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--hall", action="store_true", help="the Modern Hall (../shared/data), solve and USD only")
    ap.add_argument("--epsilon", type=float, default=1e-4, help="--hall: hierarchy.epsilon")
    args = ap.parse_args()
    if args.hall:
        return hall(args)
    base = yaml.safe_load(Path(args.config).read_text())
    base_dir = Path(args.config).resolve().parent
    base["scene"] = str((base_dir / base["scene"]).resolve())
    with tempfile.TemporaryDirectory(prefix="hirad_relight_") as tmp:
        tmp = Path(tmp)
        groups = {"panel": {"each": True}}
        cfg = dict(base, output=str(tmp / "bake"), lights={"groups": groups})
        cfg.setdefault("grids", {"desk": {"kind": "workplane", "polygon": [[0.5, 0.5], [4.5, 0.5], [4.5, 3.5],
                                                                             [0.5, 3.5]], "height": 0.75}})
        (tmp / "groups.yaml").write_text(yaml.safe_dump(cfg))
        t_bake = _cli("bake", tmp / "groups.yaml", "--quiet")
        doc = json.loads((tmp / "bake" / "groups" / "groups.json").read_text())
        names = [g["name"] for g in doc["groups"]]
        sets = ["--set", f"lights.groups.{names[0]}.dimmer=0.3"]
        if len(names) > 1:
            sets += ["--set", f"lights.groups.{names[1]}.color=[1,0.9,0.8]"]
        # the variant as a full bake: the same config with those dimmers on the expanded groups
        variant = dict(cfg, output=str(tmp / "variant"))
        variant["lights"] = {"groups": {n: {"paths": [m for m in g["members"]]} for n, g in
                                        ((g["name"], g) for g in doc["groups"]) if n != "rest"}}
        variant["lights"]["groups"][names[0]]["dimmer"] = 0.3
        if len(names) > 1:
            variant["lights"]["groups"][names[1]]["color"] = [1, 0.9, 0.8]
        (tmp / "variant.yaml").write_text(yaml.safe_dump(variant))
        bakes = [_cli("bake", tmp / "variant.yaml", "--quiet") for _ in range(args.repeat)]
        plain_cfg = dict(cfg, output=str(tmp / "plain"))
        plain_cfg.pop("lights")
        (tmp / "plain.yaml").write_text(yaml.safe_dump(plain_cfg))
        plains = [_cli("bake", tmp / "plain.yaml", "--quiet") for _ in range(args.repeat)]
        relights = [_cli("relight", tmp / "bake", *sets, "-o", tmp / "relit") for _ in range(args.repeat)]
        from hirad.relight import relight

        inproc = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            relight(tmp / "bake", sets[1::2], tmp / "relit2")
            inproc.append(time.perf_counter() - t)
        rep = json.loads((tmp / "bake" / "report.json").read_text())
        print(f"config: {args.config}; groups: {', '.join(names)}; nproc {os.cpu_count()}; "
              f"load {os.getloadavg()[0]:.2f}")
        print(f"bake with groups (first):     {t_bake:8.2f} s  (patches {rep['counts']['patches']}, "
              f"links {rep['counts']['links']}, group solves {doc['group_solve_seconds']:.2f} s)")
        print(f"bake of the variant:          {min(bakes):8.2f} s  (best of {args.repeat})")
        print(f"bake without groups:          {min(plains):8.2f} s  (best of {args.repeat}; one gather per texel)")
        print(f"hirad relight (CLI):          {min(relights):8.2f} s  (best of {args.repeat})")
        print(f"relight() in-process:         {min(inproc):8.2f} s  (best of {args.repeat})")
        print(f"speed-up (CLI):               {min(bakes) / min(relights):8.1f} x the variant's bake, "
              f"{min(plains) / min(relights):.1f} x a bake without groups")
        timings = rep["timings_s"]
        print("bake with groups, stages:     " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
    return 0


def hall(args) -> int:
    scene = REPO.parent / "shared" / "data" / "modern_hall" / "usd" / "modern_hall.usda"
    if not scene.exists():
        print(f"{scene} is absent: nothing to measure")
        return 0
    groups = {"spots": {"paths": ["/World/Geom/disk_*"]}, "panels": {"paths": ["/World/Geom/rectangle_*"]}}
    base = {"scene": str(scene), "method": "hierarchical",
            "hierarchy": {"epsilon": args.epsilon, "min_area": 0.01, "samples": 8},
            "solver": {"method": "jacobi", "tolerance": 1e-4},
            "outputs": {"usd": True, "lightmaps": {"enabled": False}, "volume": {"enabled": False},
                        "preview": {"enabled": False}, "report": True}}
    with tempfile.TemporaryDirectory(prefix="hirad_relight_") as tmp:
        tmp = Path(tmp)
        plain = dict(base, output=str(tmp / "plain"))
        grouped = dict(base, output=str(tmp / "bake"), lights={"groups": groups})
        variant = dict(base, output=str(tmp / "variant"),
                       lights={"groups": {"spots": dict(groups["spots"], dimmer=0.3), "panels": groups["panels"]}})
        for name, cfg in (("plain", plain), ("groups", grouped), ("variant", variant)):
            (tmp / f"{name}.yaml").write_text(yaml.safe_dump(cfg))
        t_plain = min(_cli("bake", tmp / "plain.yaml", "--quiet") for _ in range(args.repeat))
        t_groups = _cli("bake", tmp / "groups.yaml", "--quiet")
        t_variant = min(_cli("bake", tmp / "variant.yaml", "--quiet") for _ in range(args.repeat))
        sets = ["--set", "lights.groups.spots.dimmer=0.3"]
        t_relight = min(_cli("relight", tmp / "bake", *sets, "-o", tmp / "relit") for _ in range(args.repeat))
        from hirad.relight import relight

        inproc = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            relight(tmp / "bake", sets[1::2], tmp / "relit2")
            inproc.append(time.perf_counter() - t)
        rep = json.loads((tmp / "bake" / "report.json").read_text())
        doc = json.loads((tmp / "bake" / "groups" / "groups.json").read_text())
        print(f"Modern Hall, epsilon {args.epsilon:g}; groups: {', '.join(g['name'] for g in doc['groups'])}; "
              f"nproc {os.cpu_count()}; load {os.getloadavg()[0]:.2f}")
        print(f"elements {rep['hierarchy']['elements']}, links {rep['counts']['links']}; hierarchical solve stage "
              f"{rep['timings_s']['hierarchical solve']:.2f} s of which group solves {doc['group_solve_seconds']:.2f} s")
        print(f"bake without groups:          {t_plain:8.2f} s  (best of {args.repeat})")
        print(f"bake with groups:             {t_groups:8.2f} s")
        print(f"bake of the variant:          {t_variant:8.2f} s  (best of {args.repeat})")
        print(f"hirad relight (CLI):          {t_relight:8.2f} s  (best of {args.repeat})")
        print(f"relight() in-process:         {min(inproc):8.2f} s  (best of {args.repeat})")
        print(f"speed-up (CLI):               {t_variant / t_relight:8.1f} x the variant's bake")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
