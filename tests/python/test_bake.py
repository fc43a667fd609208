"""End-to-end tests of the Python API: hirad.bake.bake, Result and load_solution."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hirad_e2e_helpers import (BOX_WALLS, COARSE, CORNELL, REPO, assert_no_output, furnace_box, l_shape,
                               mesh_points_by_path, sha256, write_config)
from pxr import Sdf, Usd, UsdGeom

from hirad import _engine
from hirad.bake import BakeError, Result, bake, load_solution
from hirad.config import ConfigError, load_config

PREVIEW = {"camera": "/World/Camera", "width": 48, "height": 48, "samples": 1}


def cornell_config(path: Path, output: Path, scene: Path = CORNELL, **sections) -> Path:
    sections.setdefault("meshing", COARSE)
    sections.setdefault("outputs", {"preview": PREVIEW})
    return write_config(path, scene, output, **sections)


@pytest.fixture(scope="module")
def cornell(tmp_path_factory):
    root = tmp_path_factory.mktemp("bake_cornell")
    scene = root / "scene" / "cornell_box.usda"
    scene.parent.mkdir()
    scene.write_bytes(CORNELL.read_bytes())
    digest = sha256(scene)
    out = root / "out"
    result = bake(cornell_config(root / "c.yaml", out, scene))
    return {"root": root, "scene": scene, "digest": digest, "out": out, "result": result}


# ---------------------------------------------------------------------------------------------
# the package entry points
# ---------------------------------------------------------------------------------------------


def test_package_level_api_as_documented():
    """`import hirad; hirad.bake(...)` as the package docstring shows (fresh interpreter)."""
    code = ("import hirad, sys; "
            "assert callable(hirad.bake) and not isinstance(hirad.bake, type(sys)), hirad.bake; "
            "assert callable(hirad.load_solution); assert hirad.Result.__name__ == 'Result'")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_result_type(cornell):
    r = cornell["result"]
    assert isinstance(r, Result)
    assert r.output_dir == cornell["out"]
    n = r.report["counts"]["patches"]
    assert r.patch_radiosity.shape == r.patch_irradiance.shape == (n, 3)
    assert r.corners.shape == (n, 4, 3)


def test_report_carries_the_residual_per_iteration(cornell):
    solver = cornell["result"].report["solver"]
    history = solver["residual_history"]
    assert 1 < len(history) <= 200
    assert history[-1] == [solver["iterations"], solver["residual"]]
    assert history[0][0] == 1 and history[0][1] > solver["tolerance"]
    assert solver["residual"] <= solver["tolerance"]
    assert [i for i, _ in history] == sorted({i for i, _ in history})


# ---------------------------------------------------------------------------------------------
# bad input through the API: exceptions, and nothing left behind
# ---------------------------------------------------------------------------------------------


def test_missing_scene_raises_config_error(tmp_path):
    out = tmp_path / "out"
    cfg = write_config(tmp_path / "c.yaml", tmp_path / "missing.usda", out)
    with pytest.raises(ConfigError) as e:
        bake(cfg)
    assert e.value.key == "scene" and e.value.line == 1
    assert str(tmp_path / "missing.usda") in str(e.value)
    assert_no_output(out)


def test_no_usable_faces_raises_bake_error(tmp_path):
    from hirad_e2e_helpers import all_nan_scene

    out = tmp_path / "out"
    scene = all_nan_scene(tmp_path / "nan.usda")
    with pytest.raises(BakeError, match="no usable faces") as e:
        bake(write_config(tmp_path / "c.yaml", scene, out))
    assert str(scene) in str(e.value)
    assert_no_output(out)


def test_failed_bake_keeps_the_previous_output(tmp_path):
    """A failing bake neither removes nor half-overwrites an earlier complete output."""
    out = tmp_path / "out"
    cfg = cornell_config(tmp_path / "c.yaml", out)
    bake(cfg)
    before = {p.relative_to(out): sha256(p) for p in out.rglob("*") if p.is_file()}
    bad = cornell_config(tmp_path / "c.yaml", out, outputs={"preview": {**PREVIEW, "camera": "/World/Nope"}})
    with pytest.raises(BakeError, match="/World/Nope"):
        bake(bad)
    after = {p.relative_to(out): sha256(p) for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert [p.name for p in tmp_path.iterdir() if ".partial" in p.name] == []


# ---------------------------------------------------------------------------------------------
# geometry
# ---------------------------------------------------------------------------------------------


def test_concave_polygon_patch_area(tmp_path):
    scene, _ = l_shape(tmp_path / "ell.usda")
    pts = mesh_points_by_path(scene)["/World/ell"]  # as stored (float32) in the file
    x, z = pts[:, 0], pts[:, 2]
    area = 0.5 * abs(np.dot(x, np.roll(z, -1)) - np.dot(z, np.roll(x, -1)))
    assert area == pytest.approx(1.875, rel=1e-12)  # 1.5 x 0.5 plus 0.75 x 1.5, exact in binary
    result = bake(write_config(tmp_path / "c.yaml", scene, tmp_path / "out",
                               meshing={"max_patch_area": 0.05, "max_edge_length": 0.3}))
    patches = result.patches
    assert len(patches["area"]) >= 1.875 / 0.05  # really subdivided
    assert patches["area"].max() <= 0.05 * (1 + 1e-9)
    assert patches["area"].sum() == pytest.approx(area, rel=1e-9)
    # every patch lies inside the L (no patch covers the notch x > 0.75, z > 0.5)
    centroids = patches["centroid"]
    assert not ((centroids[:, 0] > 0.75) & (centroids[:, 2] > 0.5)).any()
    # an emitter alone in the void: all of its power escapes
    eb = result.report["energy_balance"]
    np.testing.assert_allclose(eb["escaped_W"], eb["emitted_W"], rtol=1e-9)
    np.testing.assert_allclose(eb["emitted_W"], math.pi * 1.0 * area, rtol=1e-6)
    assert result.report["warnings"] == []


def test_leaves_corners_are_made_from_the_display_mesh_to_the_bit(tmp_path):
    # A hierarchical bake holds its leaves without their corners (a third of their bytes); the
    # Result's patches make them from the display mesh: the engine's own leaves' corners, bit for
    # bit, triangles (the L's ear-clipped pieces) repeating their third corner.
    from hirad.engine import patch_dict

    ell, _ = l_shape(tmp_path / "ell.usda")
    # (the box's display mesh refined where its vertex gather varies: new points after the leaves')
    for name, scene, nv, values in (("box", CORNELL, 4, "final_gather"), ("ell", ell, 3, "patches")):
        result = bake(write_config(tmp_path / f"{name}.yaml", scene, tmp_path / name, method="hierarchical",
                                   hierarchy={"epsilon": 1e-4, "min_area": 1e-3, "samples": 4},
                                   reconstruction={"values": values},
                                   outputs={"preview": {"enabled": False}}), keep_hierarchy=True)
        if values == "final_gather":
            assert result.report["display"]["split"] > 0
        engine = patch_dict(result._model.patch_arrays())
        assert (engine["nv"] == nv).sum() >= 4  # the box's leaves are mostly quads, the L's triangles
        assert not dict.__contains__(result.patches, "corners") and "corners" in result.patches
        assert np.array_equal(result.patches["corners"], engine["corners"]), name
        assert np.array_equal(result.patches.get("corners"), engine["corners"]), name
        assert np.array_equal(result.patches["centroid"], engine["centroid"]), name


# ---------------------------------------------------------------------------------------------
# determinism and threads
# ---------------------------------------------------------------------------------------------


def _numbers(report: dict) -> dict:
    return {"residual": report["solver"]["residual"], "iterations": report["solver"]["iterations"],
            "links": report["counts"]["links"], "rays": report["counts"]["rays"],
            "patches": report["counts"]["patches"], "energy": report["energy_balance"]}


def test_two_bakes_are_identical(cornell, tmp_path):
    first = cornell["result"]
    second = bake(cornell_config(tmp_path / "c.yaml", tmp_path / "out", cornell["scene"]))
    assert _numbers(second.report) == _numbers(first.report)
    assert first.report["solver"]["iterations"] > 0 and first.report["counts"]["rays"] > 0
    np.testing.assert_array_equal(second.patch_radiosity, first.patch_radiosity)
    np.testing.assert_array_equal(second.patch_irradiance, first.patch_irradiance)
    a = sorted((cornell["out"] / "lightmaps").glob("*.exr"))
    b = sorted((tmp_path / "out" / "lightmaps").glob("*.exr"))
    assert [p.name for p in a] == [p.name for p in b] and len(a) == 8
    for pa, pb in zip(a, b):
        assert pa.read_bytes() == pb.read_bytes(), pa.name


def test_thread_count_does_not_change_the_result(tmp_path):
    cfg = cornell_config(tmp_path / "c.yaml", tmp_path / "out", outputs={"preview": {"enabled": False}})
    one = bake(cfg, threads=1)
    two = bake(cfg, threads=2)
    assert one.report["threads"] == 1 and two.report["threads"] == 2
    np.testing.assert_array_equal(one.patch_radiosity, two.patch_radiosity)
    np.testing.assert_array_equal(one.patch_irradiance, two.patch_irradiance)
    assert _numbers(one.report) == _numbers(two.report)


def test_the_hierarchy_is_let_go_once_nothing_gathers(tmp_path):
    """A hierarchical bake whose outputs do not gather frees its solved hierarchy after the
    solve (memory: about 0.7 GB on a 1M-triangle scene). The outputs are the same bits as a bake
    that keeps it, and Result.gather then says how to keep it."""
    hier = {"method": "hierarchical", "hierarchy": {"epsilon": 1e-3, "min_area": 2e-3, "samples": 4},
            "solver": {"method": "block_southwell"}, "outputs": {"preview": PREVIEW, "lightmaps": {"enabled": False}}}
    let_go = bake(cornell_config(tmp_path / "a.yaml", tmp_path / "a", **hier))
    kept = bake(cornell_config(tmp_path / "b.yaml", tmp_path / "b", **hier), keep_hierarchy=True)
    assert not let_go._model.has_hierarchy and kept._model.has_hierarchy
    assert (tmp_path / "a" / "preview.exr").read_bytes() == (tmp_path / "b" / "preview.exr").read_bytes()
    a, b = load_solution(tmp_path / "a" / "solution.usda"), load_solution(tmp_path / "b" / "solution.usda")
    np.testing.assert_array_equal(a.corner_radiance, b.corner_radiance)
    np.testing.assert_array_equal(a.corner_irradiance, b.corner_irradiance)
    pts, nrm = np.array([[0.28, 0.0, 0.28]]), np.array([[0.0, 1.0, 0.0]])
    assert kept.gather(pts, nrm)["patch"][0] >= 0
    with pytest.raises(BakeError, match="keep_hierarchy=True"):
        let_go.gather(pts, nrm)
    with pytest.raises(ValueError, match="input faces were let go"):  # and so were the input faces
        let_go._model.mesh(_engine.MeshOptions())
    with pytest.raises(ValueError, match="patches were let go"):  # and, every output made, the patches
        let_go._model.patch_arrays()
    # What the patch arrays read of the input faces is kept when those go (the leaves may be
    # published after release_scene): the same arrays before and after.
    before = kept._model.patch_arrays()
    kept._model.release_scene()
    after = kept._model.patch_arrays()
    for k in ("emission", "source_face", "transmittance", "area", "mesh", "corners"):
        np.testing.assert_array_equal(getattr(before, k), getattr(after, k))
    assert np.asarray(after.emission).max() > 0
    assert let_go._model.stats().faces == kept._model.stats().faces > 0
    # an output that gathers keeps it until it is done: the vertex gather, then let go
    gathered = bake(cornell_config(tmp_path / "c.yaml", tmp_path / "c", **hier,
                                   reconstruction={"values": "final_gather", "refine_levels": 0}))
    assert not gathered._model.has_hierarchy and gathered.report["display"]["samples"] > 0


# ---------------------------------------------------------------------------------------------
# stored solutions
# ---------------------------------------------------------------------------------------------


def test_stored_solution_renders_like_the_result(cornell):
    r = cornell["result"]
    stored = load_solution(cornell["out"] / "solution.usda")
    a = r.render("/World/Camera", 64, 48, 2)
    b = stored.render("/World/Camera", 64, 48, 2)
    assert a.shape == (48, 64, 3) and a.max() > 1.0
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6 * a.max())


def test_stored_solution_probes_like_the_result(cornell):
    r = cornell["result"]
    stored = load_solution(cornell["out"] / "solution.usda")
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(0.02, 0.53, 20), np.zeros(20), rng.uniform(0.02, 0.54, 20)])
    nrm = np.tile([0.0, 1.0, 0.0], (20, 1))
    np.testing.assert_allclose(stored.irradiance_at(pts, nrm), r.irradiance_at(pts, nrm), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(stored.radiance_at(pts, nrm), r.radiance_at(pts, nrm), rtol=1e-5, atol=1e-9)


def test_indexed_and_spelled_out_surfaces_answer_alike(cornell):
    # The bake's Result holds its display mesh indexed (points, faces, values per point); a
    # solution spelled out per face corner from it must render, probe and measure illuminance
    # to the same bits, and so must a stored layer's indexed solution and its spelled-out twin.
    from hirad import SurfaceSolution

    def spelled_out(s):
        return SurfaceSolution(s.corners, s.nv, s.corner_radiance, s.corner_irradiance, cameras=s.cameras,
                               up_axis=s.up_axis, emitted_radiance=s.emitted_radiance, luminaires=s.luminaires,
                               transmittance=s.transmittance)

    rng = np.random.default_rng(5)
    pts = rng.uniform([0.01, 0.0, 0.01], [0.54, 0.54, 0.55], (200, 3))
    pts[:100, 1] = 0.0  # on the floor
    nrm = np.tile([0.0, 1.0, 0.0], (200, 1))
    nrm[100:] = rng.normal(size=(100, 3))
    nrm[100:] /= np.linalg.norm(nrm[100:], axis=1, keepdims=True)
    for s in (cornell["result"], load_solution(cornell["out"] / "solution.usda")):
        assert s.indexed and not spelled_out(s).indexed
        t = spelled_out(s)
        assert np.array_equal(s.render("/World/Camera", 48, 32, 2), t.render("/World/Camera", 48, 32, 2))
        # the default view (no camera) frames the faces' bounds: from the points the faces use
        # when indexed, from the corners spelled out otherwise; a point no face uses moves nothing
        bare = SurfaceSolution(None, s.nv, points=s.points, faces=s.faces, point_radiance=s.point_radiance,
                               up_axis=s.up_axis)
        bare_t = SurfaceSolution(s.corners, s.nv, s.corner_radiance, up_axis=s.up_axis)
        far = SurfaceSolution(None, s.nv, points=np.vstack([s.points, [[50.0, 50.0, 50.0]]]), faces=s.faces,
                              point_radiance=np.vstack([s.point_radiance, [[1.0, 1.0, 1.0]]]), up_axis=s.up_axis)
        for u in (bare_t, far):
            a, b = vars(bare.view(None)), vars(u.view(None))
            assert all(np.array_equal(a[k], b[k]) for k in a), (a, b)
        assert np.array_equal(bare.render(None, 24, 16, 1), bare_t.render(None, 24, 16, 1))
        for key in ("patch", "irradiance", "radiance"):
            assert np.array_equal(s.query(pts[:100], nrm[:100])[key], t.query(pts[:100], nrm[:100])[key]), key
        assert np.array_equal(s.illuminance(pts, nrm, rays=32), t.illuminance(pts, nrm, rays=32))
    # what the indexed Result holds, against its corners and two corner values spelled out
    r = cornell["result"]
    held = sum(a.nbytes for a in (r.points, r.faces, r.point_radiance, r.point_irradiance))
    assert held < 0.5 * (r.corners.nbytes + r.corner_radiance.nbytes + r.corner_irradiance.nbytes)


def test_unknown_camera_in_api_render(cornell):
    with pytest.raises(BakeError, match="/World/Nope"):
        cornell["result"].render("/World/Nope", 16, 16, 1)


def test_solution_layer(cornell):
    out, scene, r = cornell["out"], cornell["scene"], cornell["result"]
    path = out / "solution.usda"
    layer = Sdf.Layer.FindOrOpen(str(path))
    assert layer is not None
    # sublayers its arrays' crate, then the input scene
    assert len(layer.subLayerPaths) == 2
    assert (out / layer.subLayerPaths[0]).resolve() == (out / "solution.arrays.usdc").resolve()
    assert (out / layer.subLayerPaths[1]).resolve() == scene.resolve()
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageMetersPerUnit(stage) == pytest.approx(0.001)
    inputs = mesh_points_by_path(scene)
    # every input mesh is overridden invisible by this layer
    for mesh_path in inputs:
        spec = layer.GetPrimAtPath(mesh_path)
        assert spec is not None and spec.specifier == Sdf.SpecifierOver, mesh_path
        assert spec.attributes["visibility"].default == UsdGeom.Tokens.invisible
        prim = stage.GetPrimAtPath(mesh_path)
        assert UsdGeom.Imageable(prim).ComputeVisibility() == UsdGeom.Tokens.invisible
    # one solved mesh per input mesh, visible, with the radiosity primvars
    solved = [p for p in stage.GetPrimAtPath("/World/HiradSolution").GetChildren() if p.IsA(UsdGeom.Mesh)]
    assert len(solved) == len(inputs)
    assert {p.GetCustomDataByKey("hirad:sourcePath") for p in solved} == set(inputs)
    radiance_by_mesh = {}
    for prim in solved:
        mesh = UsdGeom.Mesh(prim)
        assert UsdGeom.Imageable(prim).ComputeVisibility() == UsdGeom.Tokens.inherited
        n_points = len(mesh.GetPointsAttr().Get())
        n_faces = len(mesh.GetFaceVertexCountsAttr().Get())
        api = UsdGeom.PrimvarsAPI(prim)
        for name, interp, n in (("hirad:radiance", "vertex", n_points), ("hirad:irradiance", "vertex", n_points),
                                ("hirad:patchRadiance", "uniform", n_faces)):
            pv = api.GetPrimvar(name)
            assert pv and pv.GetInterpolation() == interp, name
            assert len(pv.Get()) == n, name
        radiance_by_mesh[prim.GetCustomDataByKey("hirad:meshIndex")] = np.array(
            api.GetPrimvar("hirad:patchRadiance").Get(), dtype=np.float64)
    # patch radiance = B / pi of the patches of each mesh, in patch order
    mesh_of_patch = r.patches["mesh"]
    for index, stored in radiance_by_mesh.items():
        expected = r.patch_radiosity[mesh_of_patch == index] / math.pi
        np.testing.assert_allclose(stored, expected, rtol=1e-6, atol=1e-12)
    # the input file itself is untouched and its meshes stay visible on their own
    assert sha256(scene) == cornell["digest"]
    alone = Usd.Stage.Open(str(scene))
    for mesh_path in inputs:
        assert UsdGeom.Imageable(alone.GetPrimAtPath(mesh_path)).ComputeVisibility() == UsdGeom.Tokens.inherited
    assert not alone.GetPrimAtPath("/World/HiradSolution")


def test_output_files_follow_the_umask(cornell, tmp_path):
    """Every output file gets the permissions a plain new file gets (no 0600 temp-file modes)."""
    probe = tmp_path / "plain"
    probe.write_text("")
    expected = probe.stat().st_mode & 0o777
    modes = {str(p.relative_to(cornell["out"])): p.stat().st_mode & 0o777
             for p in cornell["out"].rglob("*") if p.is_file()}
    assert "solution.usda" in modes
    assert {k: oct(v) for k, v in modes.items() if v != expected} == {}


# ---------------------------------------------------------------------------------------------
# physics: the furnace
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def furnace(tmp_path_factory):
    """Closed unit cube, every face rho = 0.5 and E = 1 W/m^2: B = E / (1 - rho) = 2 and,
    since every surface sees only surfaces with B = 2, H = 2 everywhere.  256 form-factor
    samples keep the Monte Carlo error of the form-factor row sums well below 1 %."""
    root = tmp_path_factory.mktemp("furnace")
    scene = furnace_box(root / "box.usda")
    cfg = write_config(root / "c.yaml", scene, root / "out",
                       meshing={"max_patch_area": 0.04, "max_edge_length": 0.25},
                       formfactors={"method": "raycast", "samples": 256},
                       outputs={"preview": {"width": 32, "height": 32, "samples": 1}})
    return root, bake(cfg)


def random_wall_points(n: int, seed: int):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0.0, 1.0, size=(n, 3))
    axis = rng.integers(0, 3, size=n)
    side = rng.integers(0, 2, size=n)
    pts[np.arange(n), axis] = side
    nrm = np.zeros((n, 3))
    nrm[np.arange(n), axis] = np.where(side == 1, -1.0, 1.0)  # inward
    return pts, nrm


def test_furnace_patches(furnace):
    _, r = furnace
    assert len(r.patch_radiosity) >= 6 / 0.04
    np.testing.assert_allclose(r.patch_radiosity, 2.0, rtol=0.01)
    np.testing.assert_allclose(r.patch_irradiance, 2.0, rtol=0.01)
    assert r.report["energy_balance"]["max_relative_error"] < 0.01
    eb = r.report["energy_balance"]
    np.testing.assert_allclose(eb["emitted_W"], 6.0, rtol=1e-6)  # 6 m^2 x 1 W/m^2
    # Closed box: nothing escapes.  "escaped" is the per-patch deficit of the estimated
    # form-factor row sums (A_i - sum_j G_ij) B_i, so sampling noise leaves a little.
    np.testing.assert_array_less(np.array(eb["escaped_W"]) / 6.0, 0.005)
    np.testing.assert_allclose(eb["absorbed_W"], 6.0, rtol=0.005)  # all of it is absorbed


def test_furnace_probe(furnace):
    root, r = furnace
    pts, nrm = random_wall_points(200, seed=11)
    for source in (r, load_solution(root / "out" / "solution.usda")):
        q = source.query(pts, nrm)
        assert (q["patch"] >= 0).all()
        np.testing.assert_allclose(q["distance"], 0.0, atol=1e-6)
        np.testing.assert_allclose(q["irradiance"], 2.0, rtol=0.01)
        np.testing.assert_allclose(q["radiance"], 2.0 / math.pi, rtol=0.01)


def test_furnace_lightmaps(furnace):
    import OpenEXR

    root, r = furnace
    exrs = sorted((root / "out" / "lightmaps").glob("*.exr"))
    assert sorted(p.stem for p in exrs) == sorted(f"World_{w}" for w in BOX_WALLS)
    for path in exrs:
        rgb = _engine.read_exr(str(path))
        covered = (rgb > 0).any(axis=-1)
        assert covered.mean() > 0.5, path.name
        # incident radiance H / pi
        np.testing.assert_allclose(rgb[covered], 2.0 / math.pi, rtol=0.01, err_msg=path.name)
        f = OpenEXR.File(str(path), separate_channels=True)
        header = f.header()
        assert "incident" in header["hirad:units"] and "H/pi" in header["hirad:units"]
        channels = f.channels()
        assert sorted(channels) == ["B", "G", "R"]
        for name, ch in channels.items():
            assert ch.type() == OpenEXR.HALF, (path.name, name)
            assert ch.pixels.dtype == np.float16
        # the engine's reader returns the same pixels
        np.testing.assert_array_equal(rgb[..., 0], channels["R"].pixels.astype(np.float32))
