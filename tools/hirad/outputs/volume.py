"""The irradiance volume: probes in the empty space near surfaces, written as OpenVDB grids."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .. import __version__, _engine
from ..report import scene_fingerprint
from ..errors import BakeError
from ..units import label
from . import probes as probes_mod


_VOLUME_DEFINITION = ("irradiance = integral over the sphere of incident radiance L dw (scalar irradiance, "
                      "W/m^2, RGB); sh1_x/y/z = integral of L w_x/y/z dw (W/m^2, RGB, the L1 spherical "
                      "harmonics band); irradiance on a surface facing n ~ irradiance/4 + (n . sh1)/2; "
                      "direction = unit vector of the luminance of sh1 (dominant incoming direction, "
                      "pointing towards the light)")

_SH2_DEFINITION = ("sh2_<k> = integral over the sphere of incident radiance L(w) Y_k(w) dw (RGB, units of "
                   "irradiance), Y_k the real orthonormal L2 spherical harmonics of Ramamoorthi & Hanrahan 2001 "
                   "(k = 0..8: 0.282095; 0.488603 y, z, x; 1.092548 xy, yz; 0.315392 (3z^2-1); 1.092548 xz; "
                   "0.546274 (x^2-y^2)), world axes; irradiance on a surface facing n ~ sum_k A_l sh2_k Y_k(n), "
                   "A = pi, 2pi/3, pi/4 by band; the engines' layouts are in probes.json / probes.bin")


def write_volume(cfg, result, scene, staging: Path) -> dict:
    """The irradiance volume (volume.vdb): probes on the lattice spacing * (i, j, k) (world
    origin), kept where a surface lies within max_distance (but not closer than spacing/1000:
    a point on a surface is no probe) and the probe is in empty space
    (at most 10 % of the surfaces its rays meet are seen from the back: not inside a solid,
    not behind one-sided walls). Each probe integrates the solution's exitant radiance over the full
    sphere with `rays` stratified directions in the engine (Embree): s0, s1 and the L2 spherical
    harmonics sh2, also written as probes.json / probes.bin in Unity's and Godot's layouts
    (probes.py)."""
    vc = cfg.outputs.volume
    s = float(vc.spacing)
    reach = float(vc.max_distance) if vc.max_distance is not None else 3.0 * s
    pts = result.corners.reshape(-1, 3)
    lo = np.floor((pts.min(axis=0) - reach) / s).astype(np.int64)
    hi = np.ceil((pts.max(axis=0) + reach) / s).astype(np.int64)
    dims = hi - lo + 1
    total = int(np.prod(dims))
    if total > vc.max_probes:
        raise BakeError(f"outputs.volume.spacing: {s:g} m gives {total} lattice points over the scene "
                        f"(outputs.volume.max_probes is {vc.max_probes}); raise the spacing")
    t0 = time.perf_counter()
    grid = np.stack(np.meshgrid(*[np.arange(lo[a], hi[a] + 1) for a in range(3)], indexing="ij"), -1).reshape(-1, 3)
    world = grid * s
    near = result.query(world, None, reach)
    keep = (near["patch"] >= 0) & (near["distance"] > 1e-3 * s)  # not on a surface itself
    grid, world = grid[keep], world[keep]
    probes = result.field.volume_probes(np.ascontiguousarray(world), int(vc.rays), int(cfg.seed))
    # Behind or inside geometry: more than a tenth of what the probe sees is the back of a
    # surface (outside a closed room, inside a solid, behind a one-sided wall).
    empty = (probes.back_fraction <= 0.1 * probes.hit_fraction) & (probes.nearest > 1e-6)
    grid, world = grid[empty], world[empty]
    s0, s1, sh2 = probes.s0[empty], probes.s1[empty], probes.sh2[empty]
    lum = np.array([0.2126, 0.7152, 0.0722])
    vec = s1 @ lum  # (n, 3): luminance of each axis moment
    norm = np.linalg.norm(vec, axis=1, keepdims=True)
    direction = np.where(norm > 0, vec / np.maximum(norm, 1e-300), 0.0)
    coords = np.ascontiguousarray(grid, dtype=np.int32)
    unit = label(cfg.units, "irradiance")
    common = [("units", unit), ("spacing", f"{s:.9g}"), ("hirad:version", __version__),
              ("hirad:rays", str(int(vc.rays)))]
    grids = [("irradiance", coords, np.ascontiguousarray(s0, dtype=np.float32),
              common + [("definition", _VOLUME_DEFINITION)]),
             ("direction", coords, np.ascontiguousarray(direction, dtype=np.float32),
              [("units", "unit vector"), ("spacing", f"{s:.9g}"), ("hirad:version", __version__)])]
    for a, axis in enumerate("xyz"):
        grids.append((f"sh1_{axis}", coords, np.ascontiguousarray(s1[:, a, :], dtype=np.float32), common))
    # L2 spherical harmonics (probes.py): sh2_<k> = integral of L Y_k dw, RGB, world frame.
    for k in range(9):
        grids.append((f"sh2_{k}", coords, np.ascontiguousarray(sh2[:, k, :], dtype=np.float32),
                      common + [("definition", _SH2_DEFINITION), ("sh2:basis", probes_mod.CONVENTIONS["order"][k])]))
    meta = [("hirad:version", __version__), ("hirad:sceneFingerprint", scene_fingerprint(scene)),
            ("hirad:units", unit), ("hirad:spacing", f"{s:.9g}"), ("hirad:definition", _VOLUME_DEFINITION),
            ("hirad:worldUnits", "metres (the stage's metersPerUnit applied), stage up axis " + str(scene.up_axis))]
    _engine.write_vdb(str(staging / "volume.vdb"), grids, s, [0.0, 0.0, 0.0], meta)
    # The same probes as L2 SH in the engines' layouts, beside the volume.
    l2 = probes_mod.write_probes(staging, world, sh2, units=cfg.units, up_axis=scene.up_axis, spacing=s,
                                 extra={"hirad:version": __version__, "hirad:sceneFingerprint": scene_fingerprint(scene),
                                        "units": unit, "rays": int(vc.rays), "volume": "volume.vdb"})
    return {"file": "volume.vdb", "probes": int(len(coords)), "candidates": total, "spacing": s,
            "max_distance": reach, "rays": int(vc.rays), "grids": [g[0] for g in grids],
            "l2_probes": {k: l2[k] for k in ("json", "binary", "probes", "binary_bytes")},
            "seconds": round(time.perf_counter() - t0, 4)}
