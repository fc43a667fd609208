"""hirad info's estimate of what a config costs, before anything runs (tools/hirad/estimate.py)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hirad.config import config_from_dict
from hirad.estimate import describe, estimate


def _quads(rects):
    """Axis-aligned rectangles in the z = 0 plane, (w, h) each, as flat scene arrays."""
    pts, counts, idx = [], [], []
    for k, (w, h) in enumerate(rects):
        base = len(pts)
        x0 = 10.0 * k
        pts += [[x0, 0, 0], [x0 + w, 0, 0], [x0 + w, h, 0], [x0, h, 0]]
        counts.append(4)
        idx += [base, base + 1, base + 2, base + 3]
    return SimpleNamespace(points=np.array(pts, float), face_vertex_counts=np.array(counts),
                           face_vertex_indices=np.array(idx))


def _cfg(tmp_path, **sections):
    (tmp_path / "s.usda").write_text("#usda 1.0\n")
    return config_from_dict({"scene": "s.usda", **sections}, base_dir=tmp_path)


def test_face_geometry_in_blocks_is_each_faces_own_closed_form():
    """The per-face areas and edge lengths are made a block of faces at a time (their float64
    temporaries were 4 GB at 10M faces): at every block size, each face gets its closed form,
    faces of fewer than three corners none."""
    from hirad.estimate import _face_geometry

    pts, counts, idx, want = [], [], [], []
    rng = np.random.default_rng(7)
    for k in range(40):
        kind = k % 5
        s = 0.5 + rng.random()  # the face's size, m
        x0 = 3.0 * k
        if kind == 0:  # a rectangle s x 2s: u along 0-1, v along 0-3
            ring = [[0, 0], [s, 0], [s, 2 * s], [0, 2 * s]]
            want.append((2 * s * s, s, 2 * s))
        elif kind == 1:  # a right triangle with legs s and 2s: longest edge and the height over it
            ring = [[0, 0], [s, 0], [0, 2 * s]]
            hyp = s * np.sqrt(5.0)
            want.append((s * s, hyp, 2 * s * s / hyp))
        elif kind == 2:  # a regular pentagon of circumradius s
            ang = 2 * np.pi * np.arange(5) / 5
            ring = np.c_[s * np.cos(ang), s * np.sin(ang)].tolist()
            side = 2 * s * np.sin(np.pi / 5)
            area = 2.5 * s * s * np.sin(2 * np.pi / 5)
            want.append((area, side, 2 * area / side))
        elif kind == 3:  # two corners: not a face
            ring = [[0, 0], [s, 0]]
            want.append((0.0, 0.0, 0.0))
        else:  # a square tilted out of the plane, side s
            ring = None
            base = len(pts)
            c, si = np.cos(0.3), np.sin(0.3)
            pts += [[x0, 0, 0], [x0 + s * c, 0, s * si], [x0 + s * c, s, s * si], [x0, s, 0]]
            counts.append(4)
            idx += list(range(base, base + 4))
            want.append((s * s, s, s))
        if ring is not None:
            base = len(pts)
            pts += [[x0 + x, y, 0.0] for x, y in ring]
            counts.append(len(ring))
            idx += list(range(base, base + len(ring)))
    scene = SimpleNamespace(points=np.array(pts), face_vertex_counts=np.array(counts, dtype=np.int32),
                            face_vertex_indices=np.array(idx, dtype=np.int32))
    want = np.array(want)
    whole = _face_geometry(scene)
    for got in (whole, _face_geometry(scene, block=1), _face_geometry(scene, block=7)):
        for k in range(3):
            np.testing.assert_allclose(got[k], want[:, k], rtol=1e-12, atol=1e-15)
            assert got[k].tobytes() == whole[k].tobytes()  # the same bits whatever the block


def test_flat_patch_count_of_a_square_is_its_grid(tmp_path):
    # 1 m x 1 m with cells of at most 0.01 m^2 and edges of at most 0.1 m: exactly 10 x 10
    cfg = _cfg(tmp_path, method="flat", meshing={"max_patch_area": 0.01, "max_edge_length": 0.1})
    est = estimate(_quads([(1.0, 1.0)]), cfg)
    assert est["patches"] == 100
    assert est["links_at_most"] == 100 * 99 / 2


def test_flat_patch_count_bound_by_area_when_edges_allow_more(tmp_path):
    # 2 m x 0.5 m, edge limit 10 m (no effect), area limit 0.1 m^2: at least 10 cells
    cfg = _cfg(tmp_path, method="flat", meshing={"max_patch_area": 0.1, "max_edge_length": 10.0})
    est = estimate(_quads([(2.0, 0.5)]), cfg)
    assert 10 <= est["patches"] <= 12


def test_flat_on_a_large_scene_warns_and_says_why(tmp_path):
    # 200 m^2 of surface at 1e-3 m^2 patches: 200,000 patches, 2e10 links
    cfg = _cfg(tmp_path, method="flat", meshing={"max_patch_area": 1e-3, "max_edge_length": 1.0})
    est = estimate(_quads([(10.0, 10.0), (10.0, 10.0)]), cfg)
    assert est["patches"] >= 200_000
    text = "\n".join(describe(est))
    assert "use method: hierarchical" in text
    assert "warning:" in text


def test_hierarchical_element_bound_is_area_over_min_area(tmp_path):
    cfg = _cfg(tmp_path, method="hierarchical", hierarchy={"min_area": 0.01})
    est = estimate(_quads([(1.0, 1.0)]), cfg)
    assert est["elements_at_most"] == pytest.approx(100 * 4 / 3)
    lo, hi = est["links_range"]
    assert lo <= est["links_typical"] <= hi


def test_with_clusters_that_receive_links_follow_the_area_not_the_faces(tmp_path):
    # The same 4 m^2 cut into 4 or into 40,000 faces: with element receivers every face is
    # linked on its own (at least 50 links each); with clusters that receive the links follow
    # the surface the lighting resolves, whatever its faces (bench/README.md: the family room
    # from 1k to 328k faces), so the estimate must not grow with them.
    def cut(n):
        return _quads([(2.0 / n, 2.0 / n)] * (n * n))
    base = {"method": "hierarchical", "hierarchy": {"min_area": 0.01, "cluster_receivers": True},
            "solver": {"method": "jacobi"}}
    coarse, fine = estimate(cut(2), _cfg(tmp_path, **base)), estimate(cut(200), _cfg(tmp_path, **base))
    assert fine["links_typical"] == pytest.approx(coarse["links_typical"])
    assert fine["links_range"][0] < 50 * 40_000
    off = estimate(cut(200), _cfg(tmp_path, method="hierarchical", hierarchy={"min_area": 0.01}))
    assert off["links_range"][0] >= 50 * 40_000


def test_hirad_info_with_a_config_estimates_the_bundled_box_near_its_real_patch_count():
    """The estimate against the engine's own meshing of the same scene and limits."""
    import re
    import subprocess
    import sys
    from pathlib import Path

    from hirad import _engine, usd
    from hirad.config import load_config

    repo = Path(__file__).resolve().parents[2]
    proc = subprocess.run([sys.executable, "-m", "hirad.cli", "info", str(repo / "configs" / "cornell.yaml")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    m = re.search(r"patches: about ([\d,]+)", proc.stdout)
    assert m, proc.stdout
    estimated = int(m.group(1).replace(",", ""))
    cfg = load_config(repo / "configs" / "cornell.yaml")
    actual = _meshed_patch_count(_engine, usd.read_scene(cfg.scene), cfg)
    assert abs(estimated - actual) <= 0.25 * actual, (estimated, actual)


def _meshed_patch_count(_engine, scene, cfg) -> int:
    """The engine's meshing of the same faces with the same limits."""
    from hirad.engine import build_engine

    model = build_engine(scene)
    model.mesh(_engine.MeshOptions(max_patch_area=cfg.meshing.max_patch_area,
                                   max_edge_length=cfg.meshing.max_edge_length))
    return int(model.num_patches)


def test_memory_counts_the_scene_besides_the_links_and_grows_with_its_faces(tmp_path):
    # An out-of-core bake's links take at most the budget; the scene, its hierarchy and the
    # outputs take memory of their own, in proportion to the input faces (the kitchen's
    # 1.3-1.9 KB a face): the same surface cut into 100 times more faces needs more memory,
    # the links' part unchanged, and final-gather lightmaps more again.
    def cut(n):
        return _quads([(2.0 / n, 2.0 / n)] * (n * n))
    base = {"method": "hierarchical", "hierarchy": {"min_area": 0.01, "cluster_receivers": True},
            "solver": {"method": "block_southwell"}, "links": {"memory_budget": "1GB"},
            "outputs": {"lightmaps": {"enabled": False}}}
    coarse, fine = estimate(cut(20), _cfg(tmp_path, **base)), estimate(cut(200), _cfg(tmp_path, **base))
    assert coarse["memory_parts"]["links"] == fine["memory_parts"]["links"] == 2 ** 30
    grown = fine["memory_parts"]["scene_and_outputs"] - coarse["memory_parts"]["scene_and_outputs"]
    assert grown > (40_000 - 400) * 1000  # at least a kilobyte a face
    assert fine["memory_bytes"] == fine["memory_parts"]["links"] + fine["memory_parts"]["scene_and_outputs"]
    lit = estimate(cut(200), _cfg(tmp_path, **{**base, "outputs": {"lightmaps": {"enabled": True,
                                                                                  "mode": "final_gather"}}}))
    assert lit["memory_parts"]["scene_and_outputs"] > fine["memory_parts"]["scene_and_outputs"]
    assert any("the scene, its hierarchy and the outputs" in line for line in describe(fine))


def test_a_bake_expected_not_to_fit_says_so_before_it_starts(tmp_path):
    """A budget larger than the machine: the bake warns, with the numbers (the links' part and
    the scene's, the faces, the machine's memory), and still runs; within the machine's
    memory nothing is said."""
    import json

    from hirad_e2e_helpers import CORNELL, write_config

    from hirad.bake import bake

    def baked(name: str, budget: str):
        cfg = write_config(tmp_path / f"{name}.yaml", CORNELL, tmp_path / name, method="hierarchical",
                           hierarchy={"epsilon": 1e-3, "min_area": 0.01, "samples": 4, "max_rounds": 1},
                           solver={"method": "block_southwell"},
                           links={"memory_budget": budget, "store": str(tmp_path / f"{name}.links")},
                           outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False},
                                    "volume": {"enabled": False}})
        return bake(cfg), json.loads((tmp_path / name / "report.json").read_text())["warnings"]

    result, warnings = baked("huge", "1PB")
    said = [w for w in warnings if w.startswith("expected to need about")]
    assert len(said) == 1, warnings
    assert "links 1.0 PiB" in said[0] and "this machine has" in said[0]
    assert "input faces" in said[0] and "links.memory_budget" in said[0]
    assert result.patch_radiosity is not None and len(result.patch_radiosity) > 0
    # within what the machine has, nothing is said
    _, warnings = baked("small", "64MB")
    assert not [w for w in warnings if w.startswith("expected to need")], warnings


def test_the_links_of_a_real_bake_fall_in_the_estimated_range(tmp_path):
    """The estimate's range of links (per element of the area bound, from the measured scenes)
    against a real bake of the bundled box with clusters that receive, and its store's bytes
    per link against the estimate's."""
    from pathlib import Path

    from hirad import usd
    from hirad.bake import bake
    from hirad.config import load_config

    repo = Path(__file__).resolve().parents[2]
    cfg = load_config(repo / "configs" / "cornell_outofcore.yaml")
    cfg.output = tmp_path / "out"
    cfg.links.store = tmp_path / "out.links"
    cfg.hierarchy.cluster_receivers = True
    cfg.outputs.lightmaps.enabled = cfg.outputs.volume.enabled = cfg.outputs.preview.enabled = False
    est = estimate(usd.read_scene(cfg.scene), cfg)
    links = bake(cfg).report["counts"]["links"]
    lo, hi = est["links_range"]
    assert lo <= links <= hi, (lo, links, hi)
    assert est["links_typical"] / 3 <= links <= 3 * est["links_typical"], (est["links_typical"], links)
