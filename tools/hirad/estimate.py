"""What a config will cost on a scene, before anything runs (`hirad info SCENE CONFIG`).

Nothing here meshes or solves: the figures come from the scene's faces and the config's
settings, by the rules the engine applies, and from throughputs measured on this project's
reference machine (2 cores; bench/README.md). They are estimates, said as such:

- Flat method. A face becomes a grid of patches within `max_patch_area` and
  `max_edge_length` (pipeline/geometry/patches.cpp), so a face of area A whose longest
  edges are l_u and l_v makes about max(A / max_patch_area, ceil(l_u / e) * ceil(l_v / e))
  patches (exact for rectangles within a few percent). Every pair of patches is a link at
  most, n (n - 1) / 2 of them, 8 bytes each in memory (column and coupling), and form
  factors cast `samples` rays per pair: the form factor stage is quadratic in the patches.
- Hierarchical method. Elements are bounded by the surface area over `min_area` (the
  quadtree's leaves, 4/3 of them counting inner nodes) and are far fewer in practice;
  links per element were 50 to 160 on the measured scenes. Link generation estimates about
  2.4 links for every link it keeps.
- Hierarchical with clusters that receive (`hierarchy.cluster_receivers`): links no longer
  grow with the input faces but with the surface the lighting resolves. Per element that
  area/min_area x 4/3 allows, the measured scenes at epsilon 1e-4 had 14 (the Modern Hall,
  min_area 0.02, spread_epsilon 0: 1.10 M links), 33 (the generated family room, from 1k to
  328k faces alike) and 108 (the country kitchen, 1.05M faces, min_area 0.005: 14.0 M links)
  links; link generation made 3.2 estimates per kept link at 0.34 M a second (the kitchen:
  44.5 M estimates in 132 s). Solving in memory adds about a fifth of that (the Hall: 7.7 s of
  linking, 1.4 s of solving); the out-of-core streaming solve (block_southwell) reads every
  link once a round, about 7.1 us a link (the kitchen: 98 s a round at 13.7 M links), over the
  rounds after the first (the first round's links are few).
- Out of core: the link store takes about 13.7 bytes per link (the kitchen: 183 MiB for
  14.0 M links), and as much again of the run's other files while it runs.
- Final-gather lightmaps are not in the time: their cost per texel varied tenfold between the
  measured scenes (0.19 ms on the Hall, 1.4 ms on the kitchen, wall time on 2 cores).
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np

# Throughputs measured on the reference machine (2 cores), from bench/README.md.
FLAT_RAYS_PER_S = 5.5e6          # form factor rays per second (cornell, cornell_10k: 5.3-5.7 M)
LINK_ESTIMATES_PER_S = 0.4e6     # hierarchical link estimates per second (0.37-0.83 M)
ESTIMATES_PER_KEPT_LINK = 2.4    # cornell_hierarchical: 943,192 estimates for 399,739 links
LINKS_PER_ELEMENT = (50.0, 160.0)
# Clusters that receive: links per element of the area bound, and the measured rates (above).
CLUSTER_LINKS_PER_AREA_ELEMENT = (14.0, 110.0)
CLUSTER_ESTIMATES_PER_KEPT_LINK = 3.2
CLUSTER_LINK_ESTIMATES_PER_S = 0.34e6
CLUSTER_SOLVE_PER_LINKING = 0.2       # in memory (Jacobi, Gauss-Seidel, Southwell)
STREAMED_SECONDS_PER_LINK_ROUND = 7.1e-6  # block_southwell: each round after the first
STORE_BYTES_PER_LINK = 13.7
FLAT_LINK_BYTES = 8.0
# Memory besides the links (bench/README.md): the process and its libraries about 170 MB; the
# scene, the hierarchy and its BVH, the leaves, the solver's state and the outputs about 1.3 KB
# per input face (the country kitchen end to end, 1,050,937 input faces, 2026-12-07: its solve
# stage peaked at 1,457 MiB with a 2 GB budget, 1,290 bytes a face over the process, the
# streaming solver's state and chunks in it; one floor of the bench building, 615,054 faces,
# 842 MiB for the whole bake with a 4 GB budget, 1,160 bytes a face), and 1.9 KB with
# final-gather lightmaps, whose gather (with its table of the links) is then the bake's peak
# (the kitchen: 2,065 MiB, 1,900 bytes a face). The links' part is the budget counted whole out
# of core, so the sum is a bound (the kitchen's solve used about a quarter of its 2 GB).
PROCESS_BYTES = 170e6
FACE_BYTES = 1.3e3
FACE_BYTES_GATHERED_LIGHTMAPS = 1.9e3

# Beyond these a setting is called out in a warning.
SLOW_SECONDS = 3600.0
MANY_FLAT_PATCHES = 20_000


def _face_geometry(scene, block: int = 1 << 18):
    """Per face: area (m^2) and the two longest edge lengths (m). Computed `block` faces at a
    time: the corners and their temporaries in float64 are some 400 bytes a face, 4 GB at 10M
    faces if made for all of them at once (each face's numbers are its own, so the blocks give
    the same values)."""
    counts = np.asarray(scene.face_vertex_counts)
    pts = np.asarray(scene.points, dtype=np.float64)
    idx_all = np.asarray(scene.face_vertex_indices)
    nf = len(counts)
    ends = np.cumsum(counts, dtype=np.int64)
    area = np.zeros(nf)
    lu = np.zeros(nf)
    lv = np.zeros(nf)
    for f0 in range(0, nf, block):
        f1 = min(nf, f0 + block)
        c = counts[f0:f1].astype(np.int64)
        first = int(ends[f0] - c[0])  # the block's first corner
        starts = ends[f0:f1] - c - first
        idx = idx_all[first:int(ends[f1 - 1])].astype(np.int64)
        for n in np.unique(c):
            if n < 3:
                continue
            local = np.nonzero(c == n)[0]
            sel = local + f0
            corners = pts[idx[starts[local][:, None] + np.arange(n)[None, :]]]          # (F, n, 3)
            nxt = np.roll(corners, -1, axis=1)
            x, y, z = corners[..., 0], corners[..., 1], corners[..., 2]
            u, v, w = nxt[..., 0], nxt[..., 1], nxt[..., 2]
            # Newell: half the norm of the sum of corner cross products (np.cross is 4x slower here)
            nx, ny, nz = (y * w - z * v).sum(axis=1), (z * u - x * w).sum(axis=1), (x * v - y * u).sum(axis=1)
            a = 0.5 * np.sqrt(nx * nx + ny * ny + nz * nz)
            area[sel] = a
            edges = np.linalg.norm(nxt - corners, axis=2)
            if n == 4:
                # the engine's grid directions: u along edges 0-1 and 3-2, v along 0-3 and 1-2
                lu[sel] = np.maximum(edges[:, 0], edges[:, 2])
                lv[sel] = np.maximum(edges[:, 1], edges[:, 3])
            else:
                # the longest edge and the height over it
                long = edges.max(axis=1)
                lu[sel] = long
                lv[sel] = np.where(long > 0, 2 * a / np.where(long > 0, long, 1), 0)
    ok = np.isfinite(area) & np.isfinite(lu) & np.isfinite(lv)
    return np.where(ok, area, 0.0), np.where(ok, lu, 0.0), np.where(ok, lv, 0.0)


def _patches_per_face(area, lu, lv, max_area, max_edge):
    """The engine's grid rule: nu x nv cells from the edge limit, then the coarser direction
    refined until a cell is within max_area (cells of a face taken as equal)."""
    nu = np.maximum(1.0, np.ceil(np.minimum(lu / max_edge, 1e9)))
    nv = np.maximum(1.0, np.ceil(np.minimum(lv / max_edge, 1e9)))
    full = lu * lv  # the face's extent; area / full is its fill (1 for a rectangle, 1/2 a triangle)
    fill = np.where(full > 0, np.clip(area / np.where(full > 0, full, 1), 0, 1), 1)
    for _ in range(64):
        big = (area / (nu * nv) > max_area) & (nu * nv < 1e12)
        if not big.any():
            break
        u_coarser = lu / nu >= lv / nv
        # jump close to the answer, then step as the engine does
        need = np.ceil(area / max_area)
        scale = np.sqrt(np.maximum(need / (nu * nv), 1.0))
        nu = np.where(big & u_coarser, np.maximum(nu + 1, np.floor(nu * scale)), nu)
        nv = np.where(big & ~u_coarser, np.maximum(nv + 1, np.floor(nv * scale)), nv)
    cells = nu * nv
    return np.maximum(1.0, np.where(fill < 0.75, cells * 4.0 / 3.0, cells))


def estimate(scene, cfg) -> dict:
    """Counts, memory, disk and time a bake of `scene` with `cfg` is expected to take."""
    area, lu, lv = _face_geometry(scene)
    total_area = float(area.sum())
    out: dict = {"input_faces": int(len(area)), "surface_area_m2": total_area, "method": cfg.method,
                 "warnings": []}
    if cfg.method == "flat":
        m = cfg.meshing
        e = m.max_edge_length
        n = float(_patches_per_face(area, lu, lv, m.max_patch_area, e)[area > 0].sum())
        links = n * (n - 1) / 2
        rays = links * cfg.formfactors.samples if cfg.formfactors.method == "raycast" else n * 5 * 6 * 128 ** 2 / 2
        out.update(patches=n, links_at_most=links, memory_bytes=links * FLAT_LINK_BYTES * 2,
                   seconds=rays / FLAT_RAYS_PER_S, disk_bytes=0.0)
        if n > MANY_FLAT_PATCHES:
            out["warnings"].append(
                f"method flat makes about {n:,.0f} patches: up to {links:.3g} links "
                f"({_bytes(links * FLAT_LINK_BYTES * 2)} in memory) and form factors quadratic in the patches; "
                "use method: hierarchical for a scene this size")
    else:
        h = cfg.hierarchy
        bound = max(float(len(area)), total_area / h.min_area * 4.0 / 3.0)
        lo, hi = len(area) * LINKS_PER_ELEMENT[0], bound * LINKS_PER_ELEMENT[1]
        # the typical case: the measured scenes had 4 % (a box-filled room) to 40 % (the Cornell
        # box) of the bound; the geometric middle of that range
        typical_elements = max(float(len(area)), bound * 0.13)
        typical_links = typical_elements * math.sqrt(LINKS_PER_ELEMENT[0] * LINKS_PER_ELEMENT[1])
        secs = typical_links * ESTIMATES_PER_KEPT_LINK / LINK_ESTIMATES_PER_S
        if h.cluster_receivers:
            by_area = total_area / h.min_area * 4.0 / 3.0
            lo, hi = (by_area * k for k in CLUSTER_LINKS_PER_AREA_ELEMENT)
            typical_links = by_area * math.sqrt(CLUSTER_LINKS_PER_AREA_ELEMENT[0] * CLUSTER_LINKS_PER_AREA_ELEMENT[1])
            secs = typical_links * CLUSTER_ESTIMATES_PER_KEPT_LINK / CLUSTER_LINK_ESTIMATES_PER_S
            if cfg.solver.method == "block_southwell":
                secs += typical_links * STREAMED_SECONDS_PER_LINK_ROUND * max(1, h.max_rounds - 1)
            else:
                secs *= 1 + CLUSTER_SOLVE_PER_LINKING
        out.update(elements_at_most=bound, elements_typical=typical_elements, links_range=(lo, hi),
                   links_typical=typical_links, seconds=secs,
                   memory_bytes=typical_links * 24.0, disk_bytes=0.0)
        if cfg.solver.method == "block_southwell":
            out["disk_bytes"] = typical_links * STORE_BYTES_PER_LINK
            out["memory_bytes"] = float(cfg.links.memory_budget) if cfg.links.memory_budget else typical_links * 6.4
            store = cfg.link_store() if hasattr(cfg, "link_store") else None
            if store is not None:
                probe = Path(store)
                while not probe.exists() and probe != probe.parent:
                    probe = probe.parent
                free = shutil.disk_usage(probe).free
                out["disk_free_bytes"] = float(free)
                if out["disk_bytes"] > free:
                    out["warnings"].append(
                        f"the link store is expected to take {_bytes(out['disk_bytes'])} on disk, "
                        f"{_bytes(free)} are free at {probe}")
        if total_area / h.min_area > 5e7:
            out["warnings"].append(
                f"hierarchy.min_area {h.min_area:g} m^2 on {total_area:,.1f} m^2 of surface allows "
                f"{bound:.3g} elements; raise min_area unless the lighting needs that detail")
    # the links' part (the solver's budget out of core) and the scene's and outputs' part
    lm = getattr(getattr(cfg, "outputs", None), "lightmaps", None)
    gathered = (cfg.method == "hierarchical" and lm is not None and lm.enabled and lm.mode == "final_gather")
    scene_bytes = PROCESS_BYTES + len(area) * (FACE_BYTES_GATHERED_LIGHTMAPS if gathered else FACE_BYTES)
    out["gathered_lightmaps"] = bool(gathered)
    out["memory_parts"] = {"links": out["memory_bytes"], "scene_and_outputs": scene_bytes}
    out["memory_bytes"] = out["memory_bytes"] + scene_bytes
    if out["seconds"] > SLOW_SECONDS:
        out["warnings"].append(f"expected to take about {_duration(out['seconds'])} on 2 cores")
    try:
        import os

        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        out["machine_bytes"] = float(ram)
        if out["memory_bytes"] > ram:
            out["warnings"].append(memory_warning(out))
    except (ValueError, OSError, AttributeError):
        pass
    return out


def memory_warning(est: dict) -> str:
    """What a bake expected not to fit says before it starts, with the numbers."""
    parts = est["memory_parts"]
    return (f"expected to need about {_bytes(est['memory_bytes'])} of memory (links "
            f"{_bytes(parts['links'])}, the scene, its hierarchy and the outputs {_bytes(parts['scene_and_outputs'])}, "
            f"{est['input_faces']:,} input faces), this machine has {_bytes(est['machine_bytes'])}"
            + (": lower links.memory_budget, or raise hierarchy.min_area" if est["method"] == "hierarchical" else ""))


def _bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:,.1f} {unit}" if unit != "B" else f"{n:,.0f} B"
        n /= 1024
    return f"{n:g}"


def _duration(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 2 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


def describe(est: dict) -> list[str]:
    """The estimate as lines for `hirad info`."""
    lines = [f"estimate for method {est['method']} (before anything runs; see hirad/estimate.py for how):"]
    if est["method"] == "flat":
        lines.append(f"  patches: about {est['patches']:,.0f}; links: at most {est['links_at_most']:,.0f} "
                     f"({_bytes(est['memory_bytes'])} in memory)")
    else:
        lo, hi = est["links_range"]
        lines.append(f"  elements: at most {est['elements_at_most']:,.0f}, typically about {est['elements_typical']:,.0f}")
        parts = est["memory_parts"]
        lines.append(f"  links: about {est['links_typical']:,.0f} (range {lo:,.0f} to {hi:,.0f}); "
                     f"memory about {_bytes(est['memory_bytes'])} (links {_bytes(parts['links'])}, the scene, "
                     f"its hierarchy and the outputs {_bytes(parts['scene_and_outputs'])})")
        if est["disk_bytes"]:
            lines.append(f"  link store on disk: about {_bytes(est['disk_bytes'])}")
    lines.append(f"  time on 2 cores: about {_duration(est['seconds'])}"
                 + (" for the solve (final-gather lightmaps not included)" if est.get("gathered_lightmaps") else ""))
    lines += [f"warning: {w}" for w in est["warnings"]]
    return lines
