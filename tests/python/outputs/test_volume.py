"""The irradiance volume (outputs.volume -> volume.vdb): the file opens with the engine's
OpenVDB reader with its named grids and metadata, and the probe at the centre of the Cornell
box matches a Monte Carlo reference of the same quantity.

The reference: the volume stores at a point x the scalar irradiance s0 = integral over the
sphere of the incident radiance L(x, w) dw, and s1 = integral of L w dw. L(x, w) is the
exitant radiance of the first surface the ray x + t w meets. The engine has no Monte Carlo
estimate at points in space, but it has one at surface points (Engine.reference_at, path
tracing, independent of the radiosity solution): so we shoot our own stratified directions
from the probe, find where they land (ray_cast), and average the path-traced exitant radiance
there, times 4 pi / N. That integrates the same L as the probe with independent directions
and an independent radiance estimate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hirad_e2e_helpers import CORNELL, write_config

from hirad import __version__, _engine
from hirad.bake import bake

SPACING = 0.0925  # 3 x spacing = 0.2775 m: a lattice point within 5 mm of the box centre
CENTRE = np.array([0.278, 0.2744, 0.2796])  # centre of the Cornell box's bounds, metres


@pytest.fixture(scope="module")
def cornell_volume(tmp_path_factory):
    root = tmp_path_factory.mktemp("volume")
    cfg = write_config(root / "c.yaml", CORNELL, root / "out", method="hierarchical",
                       hierarchy={"epsilon": 1e-4, "min_area": 0.002, "samples": 8, "max_rounds": 4},
                       solver={"method": "jacobi", "tolerance": 1e-4},
                       outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False},
                                "volume": {"enabled": True, "spacing": SPACING, "rays": 4096}})
    result = bake(cfg, keep_hierarchy=True)  # (the engine's patches kept, for its reference_at below)
    return result, _engine.read_vdb(str(root / "out" / "volume.vdb")), cfg


def sphere_directions(n_side: int, seed: int) -> np.ndarray:
    """Stratified equal-area directions (z uniform, phi uniform), n_side^2 of them."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij")
    z = 1 - 2 * (i.ravel() + rng.random(i.size)) / n_side
    phi = 2 * np.pi * (j.ravel() + rng.random(i.size)) / n_side
    r = np.sqrt(np.maximum(0, 1 - z * z))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def test_vdb_has_named_grids_and_metadata(cornell_volume):
    from hirad.bake import read_inputs
    from hirad.config import load_config
    from hirad.report import scene_fingerprint

    result, vdb, cfg = cornell_volume
    assert set(vdb["grids"]) == {"irradiance", "direction", "sh1_x", "sh1_y", "sh1_z"} | {f"sh2_{k}" for k in range(9)}
    assert vdb["metadata"]["hirad:version"] == __version__
    assert float(vdb["metadata"]["hirad:spacing"]) == pytest.approx(SPACING)
    # the scene's own fingerprint, though a bake without lightmaps lets its arrays go before the
    # volume is written (it was a hash of None pointers then, different in every process)
    scene, _ = read_inputs(load_config(cfg))
    assert vdb["metadata"]["hirad:sceneFingerprint"] == scene_fingerprint(scene)
    scene.face_reflectance = scene.face_reflectance * 0.5
    scene.fingerprint = None
    assert scene_fingerprint(scene) != vdb["metadata"]["hirad:sceneFingerprint"]
    irr = vdb["grids"]["irradiance"]
    assert irr["metadata"]["units"] == "illuminance lx (lm/m^2)" and float(irr["metadata"]["spacing"]) == pytest.approx(SPACING)
    assert irr["metadata"]["hirad:version"] == __version__
    assert irr["voxel_size"] == pytest.approx(SPACING) and np.allclose(irr["origin"], 0)
    n = len(irr["coords"])
    assert n == result.report["outputs"]["volume"]["probes"] > 50
    for name in ("direction", "sh1_x", "sh1_y", "sh1_z"):
        g = vdb["grids"][name]
        # same lattice points in every grid
        assert sorted(map(tuple, g["coords"])) == sorted(map(tuple, irr["coords"]))
    # sparse and near surfaces: every probe within max_distance of a surface, none inside the
    # walls' backs (the box is open at the front only, so probes behind the walls are gone)
    world = irr["coords"] * SPACING
    d = result.query(world, None, 1e30)["distance"]
    assert (d <= 3 * SPACING + 1e-9).all() and (d > 0).all()
    lo, hi = result.corners.reshape(-1, 3).min(axis=0), result.corners.reshape(-1, 3).max(axis=0)
    inside_xy = ((world[:, :2] > lo[:2]) & (world[:, :2] < hi[:2])).all(axis=1)
    level = (world[:, 2] > lo[2]) & (world[:, 2] < hi[2])
    assert inside_xy[level].all(), "probes beside the walls, under the floor or over the ceiling see their backs"
    assert level.sum() > 0.5 * n and (~level).any()  # most are inside; some in front of the opening
    # energy: irradiance is positive, directions are unit vectors
    assert (irr["values"] > 0).all()
    np.testing.assert_allclose(np.linalg.norm(vdb["grids"]["direction"]["values"], axis=1), 1, atol=1e-5)


def test_centre_probe_matches_monte_carlo(cornell_volume):
    result, vdb, _ = cornell_volume
    irr = vdb["grids"]["irradiance"]
    world = irr["coords"] * SPACING + np.asarray(irr["origin"])
    k = int(np.argmin(np.linalg.norm(world - CENTRE, axis=1)))
    x = world[k]
    assert np.linalg.norm(x - CENTRE) < 0.006
    s0 = irr["values"][k].astype(np.float64)
    s1 = np.stack([vdb["grids"][f"sh1_{a}"]["values"][k] for a in "xyz"]).astype(np.float64)  # (axis, rgb)

    dirs = sphere_directions(64, seed=5)  # 4096 directions
    hits = result.field.ray_cast(np.ascontiguousarray(np.broadcast_to(x, dirs.shape)), np.ascontiguousarray(dirs))
    front = (hits.patch >= 0) & (hits.back == 0)
    assert front.mean() > 0.7  # the box is open at the front only
    ref = result._model.reference_at(np.ascontiguousarray(hits.points[front]),
                                     np.ascontiguousarray(hits.normals[front]),
                                     _engine.ReferenceOptions(paths=32, min_bounces=3, seed=17), 1e-3)
    radiance = np.zeros((len(dirs), 3))
    radiance[front] = ref.radiance
    w = 4 * math.pi / len(dirs)
    s0_ref = radiance.sum(axis=0) * w
    s1_ref = (dirs[:, :, None] * radiance[:, None, :]).sum(axis=0) * w
    err = np.sqrt((ref.standard_error ** 2).sum(axis=0)) * w
    print(f"\ncentre probe s0 {s0} reference {s0_ref} (+- {err}); s1 {s1[1]} reference {s1_ref[1]}")
    assert (err < 0.01 * s0_ref).all()  # the reference itself is good to 1 %
    np.testing.assert_allclose(s0, s0_ref, rtol=0.05)
    # the light is overhead: the first moment points up, and agrees with the reference's
    lum = np.array([0.2126, 0.7152, 0.0722])
    up, up_ref = s1 @ lum, s1_ref @ lum
    assert up[1] > 0.9 * np.linalg.norm(up)
    cos = up @ up_ref / (np.linalg.norm(up) * np.linalg.norm(up_ref))
    assert cos > math.cos(math.radians(5))
    assert np.linalg.norm(up) == pytest.approx(np.linalg.norm(up_ref), rel=0.1)
    # the stored direction is that moment's unit vector
    np.testing.assert_allclose(vdb["grids"]["direction"]["values"][k], up / np.linalg.norm(up), atol=1e-5)


def test_probe_moments_in_a_uniform_box():
    """Inside a closed box of uniform exitant radiance L every ray sees L: s0 = 4 pi L
    exactly and s1 = 0 (up to the stratification's jitter); a probe outside sees only the
    backs of the (one-sided, inward) walls and nothing else counts."""
    from conftest import box_faces

    faces = np.array(box_faces(), dtype=np.float64)  # (6, 4, 3), facing inwards
    nv = np.full(6, 4, np.int32)
    L = np.array([1.0, 2.0, 0.5])
    rad = np.ascontiguousarray(np.broadcast_to(L, (6, 4, 3)))
    pts = np.array([[0.5, 0.5, 0.5], [0.2, 0.7, 0.9], [1.5, 0.5, 0.5]])
    m = _engine.SurfaceField(np.ascontiguousarray(faces), nv, rad).volume_probes(pts, 1024, 3)
    np.testing.assert_allclose(m.s0[:2], np.broadcast_to(4 * math.pi * L, (2, 3)), rtol=1e-12)
    assert np.abs(m.s1[:2]).max() < 0.05 * 4 * math.pi * L.max()
    np.testing.assert_allclose(m.hit_fraction[:2], 1.0)
    assert (m.back_fraction[:2] == 0).all()
    # outside: about half the directions meet the box's back faces, and they count nothing
    assert m.back_fraction[2] == m.hit_fraction[2] and 0.1 < m.hit_fraction[2] < 0.5
    assert (m.s0[2] == 0).all()
    # the nearest hit of the off-centre probe: the wall at z = 1, 0.1 away (within a ray spacing)
    assert 0.1 - 1e-9 <= m.nearest[1] < 0.11
