"""The engine's Python API (hirad._engine): typed options, the explicit step that makes a
hierarchical solve's leaves the patches, one ray-tracing scene per solution answering every
query, and the committed stub describing the module that was built."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import _engine, box_faces, make_model, quad

pytestmark = pytest.mark.skipif(_engine is None, reason="engine not built")

REPO = Path(__file__).resolve().parents[2]


def test_options_take_keywords_and_refuse_unknown_ones():
    ff = _engine.FormFactorOptions(method="hemicube", hemicube_resolution=64)
    assert (ff.method, ff.samples, ff.hemicube_resolution, ff.hemicube_points, ff.seed) == ("hemicube", 16, 64, 4, 1)
    ff.samples = 4
    assert ff.samples == 4
    with pytest.raises(TypeError):
        _engine.MeshOptions(max_area=1.0)  # the field is max_patch_area
    with pytest.raises(TypeError):
        _engine.SolveOptions(tolerance="small")


def test_stats_count_self_intersecting_faces_and_meshing_refuses_too_many_patches():
    # A unit square and a bow tie (edges 0-1 and 2-3 cross at (2 2/3, 2/3); lobes of area 4/3
    # and 1/3, so its signed area is not zero and it is not merely degenerate): the bow tie is
    # dropped and counted as self-intersecting, the square kept.
    square = quad((0, 0, 0), (1, 0, 0), (0, 1, 0))
    bow_tie = np.array([[2, 0, 0], [4, 2, 0], [4, 0, 0], [2, 1, 0]], dtype=np.float64)
    m = make_model([square, bow_tie])
    st = m.stats()
    assert (st.input_faces, st.faces, st.self_intersecting_faces, st.degenerate_faces) == (2, 1, 1, 0)
    assert _engine.MeshOptions().max_patches == 50_000_000
    # 0.1 m edges on the unit square: 10 x 10 = 100 patches, refused at a limit of 99.
    with pytest.raises(ValueError, match="more than the limit of 99"):
        m.mesh(_engine.MeshOptions(max_patch_area=1.0, max_edge_length=0.1, max_patches=99))
    m.mesh(_engine.MeshOptions(max_patch_area=1.0, max_edge_length=0.1, max_patches=100))
    assert m.num_patches == 100


def test_a_hierarchical_solve_changes_the_patches_only_when_asked():
    # The closed unit box, flat-meshed into 6 x 9 patches; a hierarchical solve leaves them
    # alone until use_leaves_as_patches(), then its leaves (one per row of its arrays) are the
    # patches, and the final gather works on them.
    m = make_model(box_faces(), 0.5, 1.0, max_area=1.0, max_edge=1 / 3)
    assert m.stats().patches == 54
    # 64 point pairs a link: with 16, an element's estimated form factors sum to 1 within about
    # +-2.5 % (seeds 1-8), too close to the furnace check's 2 %; with 64, within 0.6 %.
    r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-3, min_area=0.05, samples=64),
                             _engine.SolveOptions(method="jacobi", tolerance=1e-9))
    assert m.stats().patches == 54 and not m.leaves_are_patches
    # the gather finds its leaf through the hierarchy's faces until the leaves are published
    before = m.gather(np.array([[0.5, 0.5, 0.0]]), np.array([[0.0, 0.0, 1.0]]), _engine.GatherOptions(rays=16))
    m.use_leaves_as_patches()
    assert m.leaves_are_patches
    assert m.stats().patches == r.elements == len(r.radiosity) == len(m.patch_arrays().area)
    # A furnace: B = E / (1 - rho) = 2 everywhere, and the gather at the floor's centre sees it.
    np.testing.assert_allclose(r.radiosity, 2.0, rtol=0.02)
    g = m.gather(np.array([[0.5, 0.5, 0.0]]), np.array([[0.0, 0.0, 1.0]]), _engine.GatherOptions(rays=16))
    assert g.patch[0] >= 0
    np.testing.assert_allclose(g.irradiance[0], 2.0, rtol=0.02)
    assert before.patch[0] == g.patch[0] and np.array_equal(before.irradiance, g.irradiance)


def test_one_surface_field_answers_every_ray_query():
    # One square (half side a) facing up at z = 0, built once, queried four ways.
    a, h = 1.0, 0.5
    sq = quad([-a, -a, 0.0], [2 * a, 0, 0], [0, 2 * a, 0])
    corners = np.ascontiguousarray(sq[None], dtype=np.float64)
    nv = np.array([4], np.int32)
    L = np.array([1.0, 2.0, 3.0])
    rad = np.ascontiguousarray(np.broadcast_to(L, (1, 4, 3)))
    field = _engine.SurfaceField(corners, nv, rad, rad * math.pi)
    assert len(field) == 1
    # ray_cast: straight down from height h lands at t = h on the front face
    hit = field.ray_cast(np.array([[0.2, 0.1, h]]), np.array([[0.0, 0.0, -2.0]]))
    assert hit.patch[0] == 0 and hit.back[0] == 0
    assert hit.t[0] == pytest.approx(h)
    np.testing.assert_allclose(hit.points[0], [0.2, 0.1, 0.0], atol=1e-6)  # Embree traces in float32
    # probe: the closest point is straight below, at distance h, with the corner values
    q = field.probe(np.array([[0.2, 0.1, h]]), np.zeros((1, 3)), 10.0)
    assert q.patch[0] == 0 and q.distance[0] == pytest.approx(h)
    np.testing.assert_allclose(q.radiance[0], L)
    assert field.probe(np.array([[0.0, 0.0, 5.0]]), np.zeros((1, 3)), 1.0).patch[0] == -1
    # lift_samples: a sample on the open square is lifted by epsilon along its normal only
    lifted = field.lift_samples(np.array([[0.3, -0.2, 0.0]]), np.array([[0.0, 0.0, 1.0]]), 1e-4, 0.05)
    assert lifted.moved[0] == 0
    np.testing.assert_allclose(lifted.points[0], [0.3, -0.2, 1e-4], atol=1e-6)
    # volume_probes: from height h over the square's centre the square covers the solid
    # angle 4 arcsin(a^2 / (a^2 + h^2)); every ray that hits sees radiance L
    probes = field.volume_probes(np.array([[0.0, 0.0, h]]), 4096, 1)
    omega = 4 * math.asin(a * a / (a * a + h * h))
    assert probes.hit_fraction[0] == pytest.approx(omega / (4 * math.pi), abs=0.01)
    np.testing.assert_allclose(probes.s0[0], L * omega, rtol=0.02)
    assert probes.back_fraction[0] == 0


def test_the_committed_stub_describes_the_built_module(tmp_path):
    out = tmp_path / "_engine.pyi"
    subprocess.run([sys.executable, "-m", "nanobind.stubgen", "-q", "-m", "hirad._engine", "-o", str(out)], check=True)
    committed = (REPO / "tools" / "hirad" / "_engine.pyi").read_text()
    assert out.read_text() == committed, "tools/hirad/_engine.pyi is stale: rebuild (make engine) and commit it"
