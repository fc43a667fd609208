"""The Cornell box's contacts: how far off hirad is where a block stands on the floor (issue 12).

Prints, for the bundled config with the hierarchy settings given (JSON, merged into it):

1. the written primvars (values: final_gather) and the final gather at 120 floor points
   0.5-20 mm from a block's foot, against the path tracer, by distance band;
2. per solution element (leaf) touching a foot, on the floor and on the block walls, its
   radiosity B/pi against the path tracer's mean over up to 64 points of its open part: whether
   the elements themselves are off, not only the read-out.

    python bench/contacts.py                                   # the bundled config
    python bench/contacts.py '{"epsilon": 1e-6, "min_area": 2e-5}'
    python bench/contacts.py '{"samples": 64}' --no-bands

The points and the blocks' feet are those of tests/python/outputs/test_vertex_gather.py
(imported from there, so the bench and the test look at the same places).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT / "tests/python"), str(ROOT / "tests/python/outputs")]

import test_vertex_gather as T  # noqa: E402  (after the path)
from hirad_e2e_helpers import write_config  # noqa: E402

BANDS = ((5e-4, 2e-3), (2e-3, 5e-3), (5e-3, 1e-2), (1e-2, 2e-2))


def main() -> None:
    import hirad
    from hirad.reference import reference_at

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("hierarchy", nargs="?", default="{}", help="JSON merged into the config's hierarchy")
    ap.add_argument("--no-bands", action="store_true", help="skip part 1")
    ap.add_argument("--paths", type=int, default=8192, help="part 2: paths per point")
    args = ap.parse_args()
    cfg = yaml.safe_load(T.BUNDLED.read_text())
    hierarchy = {**cfg["hierarchy"], **json.loads(args.hierarchy)}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        path = write_config(tmp / "c.yaml", T.SCENE, tmp / "out", method="hierarchical", hierarchy=hierarchy,
                            solver=cfg["solver"], reconstruction={"values": "final_gather"},
                            outputs={"usd": True, "lightmaps": {"enabled": False}, "volume": {"enabled": False},
                                     "preview": {"enabled": False}, "report": True})
        r = hirad.bake(path, keep_hierarchy=True)  # (r.gather)
        rep = r.report
        print(f"hierarchy {hierarchy}: {rep['counts']['links']:,} links, {rep['hierarchy']['elements']:,} leaves, "
              f"bake {rep['timings_s']['total']:.1f} s")
        if not args.no_bands:
            tris = T.primvar_triangles(tmp / "out" / "solution.usda")
            pts, nrm, d = T.block_foot_points(120, seed=31)
            y = reference_at(T.SCENE, pts, nrm, paths=65536, seed=7, max_distance=1e-3)["radiance"] @ T.LUM
            e = T.interpolate_at(tris, pts, nrm) @ T.LUM / y - 1
            g = r.gather(pts, nrm, rays=16)["radiance"] @ T.LUM / y - 1
            print("1. floor points beside the feet: mean signed error (primvars, final gather), worst primvar")
            for lo, hi in BANDS:
                m = (d >= lo) & (d < hi)
                print(f"   {lo * 1000:4.1f}-{hi * 1000:4.1f} mm ({m.sum():3d} points): {np.mean(e[m]):+.1%}, "
                      f"{np.mean(g[m]):+.1%}; worst {np.abs(e[m]).max():.1%}")
    P = r.patches
    rng = np.random.default_rng(1)
    cen = P["corners"][:, :4].mean(axis=1)
    print(f"2. elements touching a foot: B/pi against the path tracer's mean over the element ({args.paths} paths "
          "a point)")
    for k, (a, b, out) in enumerate(T.block_feet()):
        ab = b - a
        t = np.clip((cen - a) @ ab / (ab @ ab), 0, 1)
        dist = np.linalg.norm(cen - (a + t[:, None] * ab), axis=1)
        for kind, want in (("floor", np.array([0.0, 1.0, 0.0])), ("wall", out)):
            near = (P["normal"] @ want > 0.999) & (dist < 0.75 * np.sqrt(P["area"])) & (t > 0.1) & (t < 0.9)
            for i in np.nonzero(near)[0][:3]:
                c, u, v = P["corners"][i], rng.random(64), rng.random(64)
                if P["nv"][i] == 4:
                    w = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], axis=1)
                    q = w @ c[:4]
                else:
                    f = u + v > 1
                    u[f], v[f] = 1 - u[f], 1 - v[f]
                    q = c[0] + (c[1] - c[0]) * u[:, None] + (c[2] - c[0]) * v[:, None]
                if kind == "floor":
                    q = q[(q - a) @ out > 1e-5]  # the open part, outside the block
                if len(q) < 8:
                    continue
                ref = reference_at(T.SCENE, q, np.tile(P["normal"][i], (len(q), 1)), paths=args.paths, seed=3,
                                   max_distance=1e-3)["radiance"] @ T.LUM
                got = (r.patch_radiosity[i] / np.pi) @ T.LUM
                print(f"   foot {k} {kind:5s} leaf {i:5d}: centre {dist[i] * 1000:4.1f} mm from the foot, "
                      f"{P['area'][i] * 1e4:.2f} cm^2: {got / ref.mean() - 1:+.1%}")


if __name__ == "__main__":
    main()
