"""Luminaires in the engine (issue 13): a candela table on points, its light an exact first
bounce in the flat, hierarchical and out-of-core methods, in the final gather, the reference,
the calculation-grid read-out and the volume probes. Every expected value is a closed form or
a published CIE 171:2006 figure.

Closed forms used:
* the table's flux: for I linear in gamma from a (nadir) to b (zenith), 2 pi (a + b), because
  the integral of gamma sin(gamma) over [0, pi] is pi;
* CIE 171:2006 5.2: a downward Lambertian point source I = 1000 cos(gamma) cd at h = 3 m over a
  floor: E = 1000 h^2 / d^4 lux (d the distance to the source);
* 5.4: an isotropic 10,000 lm source in a closed black room: all of its flux is absorbed;
* a closed room of uniform reflectance rho lit by a source of flux Phi: every bounce lands, so
  sum(H A) = Phi + sum(B A) and sum(B A) = rho sum(H A), hence sum(B A) = rho Phi / (1 - rho).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

_engine = pytest.importorskip("hirad._engine")

import cie171_scenes as cie  # noqa: E402
from hirad.engine import build_engine, patch_dict  # noqa: E402

NG = cie.NG
GAMMA = cie.GAMMA
UP = np.array([0.0, 0.0, 1.0])
luminaire = cie.point_luminaire
isotropic = cie.isotropic_point
lambertian_down = cie.lambertian_point
box = cie.closed_box


def received(patches) -> float:
    return float(cie.luminous((patches["direct"] * patches["area"][:, None]).sum(axis=0)))


# ---- the table -------------------------------------------------------------------------------

def test_table_flux_is_exact_for_a_linear_profile():
    a, b = 300.0, 50.0
    lum = luminaire([0, 0, 0], [[a, b]])
    assert lum.table_flux == pytest.approx(2 * math.pi * (a + b), rel=1e-12)
    # and for a refined table of the same line, still exact (the interpolant is the line)
    fine = luminaire([0, 0, 0], (a + (b - a) * GAMMA / math.pi)[None, :])
    assert fine.table_flux == pytest.approx(2 * math.pi * (a + b), rel=1e-12)


def test_cos_power_flux_within_1e_4():
    for n in (1, 2, 5):
        lum = luminaire([0, 0, 0], np.where(GAMMA <= math.pi / 2, 1000 * np.cos(GAMMA) ** n, 0.0)[None, :])
        assert lum.table_flux == pytest.approx(2 * math.pi * 1000 / (n + 1), rel=1e-4), n


def test_axes_a_profile_lit_at_c90_lights_plus_y():
    """C = 90 is the light's +Y (hirad.photometry.ies): a table lit only in the C90 plane sends
    its light toward +Y, and a frame turned 90 degrees about Z turns it toward -X."""
    cd = np.zeros((4, NG))
    cd[1] = 500.0 * np.sin(GAMMA)  # C = 90 only (C planes 0, 90, 180, 270)
    lit = luminaire([0, 0, 0], cd)
    toward = lambda d: float(lit.intensity(np.array([d], float))[0, 1])
    assert toward([0, 1, 0]) == pytest.approx(500.0)
    assert toward([0, -1, 0]) == 0.0 and toward([1, 0, 0]) == 0.0 and toward([-1, 0, 0]) == 0.0
    turned = luminaire([0, 0, 0], cd, frame=np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1.0]]))
    assert float(turned.intensity(np.array([[-1.0, 0, 0]]))[0, 1]) == pytest.approx(500.0)
    assert float(turned.intensity(np.array([[0, 1.0, 0]]))[0, 1]) == 0.0


def test_bad_luminaires_are_refused_by_name():
    with pytest.raises(ValueError, match="luminaire 'bad'.*weights sum"):
        _engine.Luminaire("bad", np.zeros((2, 3)), np.array([0.5, 0.4]), np.eye(3), np.ones((1, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="negative"):
        luminaire([0, 0, 0], [[-1.0, 1.0]], name="neg")
    with pytest.raises(ValueError, match="right-handed"):
        luminaire([0, 0, 0], [[1.0, 1.0]], frame=np.diag([1.0, 1.0, -1.0]))


# ---- CIE 171:2006 5.2: point source over a floor ----------------------------------------------

def test_cie_5_2_point_source_grid_in_free_space_matches_the_table_and_the_closed_form():
    """The sensors of a grid at floor height, read by SurfaceField.illuminance with nothing
    else in the scene but a far-off black sheet below them (free space): every point within
    1 % of CIE 171:2006 Table 5.2 and within 1e-4 of 1000 h^2 / d^4 (the 0.5 degree table)."""
    for name, table, closed, value in cie.run_case_52():
        assert value == pytest.approx(table, rel=0.01), name
        assert value == pytest.approx(closed, rel=1e-4), name


def test_cie_5_2_on_a_black_floor_through_the_bake_path():
    """The same source over a black 3 x 3 m floor meshed flat: the floor's final gather at the
    published points (the bake's lightmap path) reads 1000 h^2 / d^4 within 1e-4."""
    h = 3.0
    scene = cie.scene_of([cie.rect(2, 0.0, (-1.5, -1.5), (1.5, 1.5), +1)], 0.0, 0.0)
    engine = build_engine(scene)
    engine.set_luminaires([lambertian_down([0, 0, h])])
    engine.mesh(_engine.MeshOptions(max_patch_area=0.05, max_edge_length=0.25))
    n = engine.num_patches
    pts = np.array([[x, y, 0.0] for x, y, _ in cie.CASE_52.values()])
    g = engine.gather_flat(pts, np.tile(UP, (len(pts), 1)), np.zeros((n, 3)), 4, 1)
    for (name, (x, y, _t)), value in zip(cie.CASE_52.items(), cie.luminous(g.irradiance)):
        assert value == pytest.approx(1000 * h * h / (x * x + y * y + h * h) ** 2, rel=1e-4), name


# ---- CIE 171:2006 5.4: flux conservation ------------------------------------------------------

def test_cie_5_4_isotropic_source_in_a_black_room_flux_is_absorbed_within_0_2_percent():
    """A 10,000 lm isotropic source at (2, 2, 2) in a black 4 x 4 x 3 m room: the flux the
    surfaces receive (sum of direct x area) is 10,000 lm within 0.2 %, flat, hierarchical and
    out of core; the table's flux itself is exact."""
    assert cie.luminous(isotropic([2.0, 2.0, 2.0], 10000.0).flux)[0] == pytest.approx(10000.0, rel=1e-12)
    for method in ("flat", "hierarchical", "out_of_core"):
        lumens, got, elements = cie.run_case_54(method)
        assert got == pytest.approx(lumens, rel=0.002), method
        # the hierarchy's elements were split where the light varies: more than the 6 faces
        assert elements > 100, method


def test_closed_grey_room_total_exitance_is_rho_phi_over_one_minus_rho():
    """Every bounce lands in a closed room: sum(B A) = rho Phi / (1 - rho), flat (direct solve)
    within 0.5 %, hierarchical within 1 %."""
    rho, phi = 0.5, 10000.0
    expect = rho * phi / (1 - rho)
    flat = build_engine(box(4, 4, 3, rho))
    flat.set_luminaires([isotropic([1.0, 2.5, 2.2], phi)])
    flat.mesh(_engine.MeshOptions(max_patch_area=0.08, max_edge_length=0.3))
    ff = _engine.FormFactorOptions(method="raycast", samples=16, seed=1)
    flat.compute_links(ff)
    b = np.asarray(flat.solve(_engine.SolveOptions(method="direct"), ff).radiosity)
    p = patch_dict(flat.patch_arrays())
    assert float(cie.luminous((b * p["area"][:, None]).sum(axis=0))) == pytest.approx(expect, rel=0.005)
    e = build_engine(box(4, 4, 3, rho))
    e.set_luminaires([isotropic([1.0, 2.5, 2.2], phi)])
    r = e.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-5, min_area=0.02),
                             _engine.SolveOptions(method="gauss_seidel", tolerance=1e-7))
    e.use_leaves_as_patches()
    p = patch_dict(e.patch_arrays())
    total = float(cie.luminous((np.asarray(r.radiosity) * p["area"][:, None]).sum(axis=0)))
    assert total == pytest.approx(expect, rel=0.01)


def test_reference_agrees_with_the_flat_solution_under_a_luminaire():
    """The Monte Carlo reference (luminaires evaluated at its path vertices, not through the
    patches) and the flat direct solve agree at floor and wall points within 3 standard errors
    plus 3 % (the patches' piecewise-constant light)."""
    rho = 0.5
    e = build_engine(box(4, 4, 3, rho))
    e.set_luminaires([isotropic([2.0, 2.0, 2.5], 5000.0)])
    e.mesh(_engine.MeshOptions(max_patch_area=0.04, max_edge_length=0.2))
    ff = _engine.FormFactorOptions(method="raycast", samples=16, seed=1)
    e.compute_links(ff)
    b = np.asarray(e.solve(_engine.SolveOptions(method="direct"), ff).radiosity)
    pts = np.array([[1.0, 1.0, 0.0], [3.0, 2.0, 0.0], [0.0, 2.0, 1.5], [2.0, 4.0, 0.5]])
    nrm = np.array([[0, 0, 1.0], [0, 0, 1.0], [1.0, 0, 0], [0, -1.0, 0]])
    ref = e.reference_at(pts, nrm, _engine.ReferenceOptions(paths=4096, seed=3), 0.01)
    g = e.gather_flat(pts, nrm, b, 16, 1)
    want = cie.luminous(ref.radiance)
    se = cie.luminous(ref.standard_error)
    got = cie.luminous(g.radiance)
    for k in range(len(pts)):
        assert abs(got[k] - want[k]) <= 3 * se[k] + 0.03 * want[k], (k, got[k], want[k], se[k])


def test_same_bits_whatever_the_thread_count():
    out = []
    for threads in (1, 2):
        _engine.set_threads(threads)
        try:
            e = build_engine(box(4, 4, 3, 0.6))
            e.set_luminaires([isotropic([1.2, 2.0, 2.0], 1000.0), lambertian_down([3.0, 3.0, 2.9], 200.0)])
            r = e.solve_hierarchical(_engine.HierarchyOptions(epsilon=1e-4, min_area=0.02),
                                     _engine.SolveOptions(method="southwell"))
            out.append(np.asarray(r.radiosity))
        finally:
            _engine.set_threads(0)
    assert out[0].shape == out[1].shape and np.array_equal(out[0], out[1])


def test_out_of_core_reuses_and_resumes_with_luminaires(tmp_path):
    """The luminaires split the hierarchy before any link; a second bake with --reuse-links
    semantics on the same store replays that split and solves the same links to the same bits."""
    def run(**kw):
        e = build_engine(box(4, 4, 3, 0.5))
        e.set_luminaires([isotropic([2.0, 2.0, 2.0], 1000.0)])
        r = e.solve_out_of_core(_engine.HierarchyOptions(epsilon=1e-4, min_area=0.02),
                                _engine.SolveOptions(method="southwell"),
                                _engine.OutOfCoreOptions(store=str(tmp_path / "links"), **kw))
        return np.asarray(r.radiosity), r
    first, _ = run()
    again, r = run(reuse_links=True)
    assert r.reused_links
    assert np.array_equal(first, again)


def test_volume_probes_see_a_point_source():
    """A probe in free space 2 m from a 1000 cd isotropic source: s0 = I / r^2 = 250 (nothing
    else shines), s1 points at the source with the same magnitude."""
    sheet = np.array([[[-50, -50, -10], [50, -50, -10], [50, 50, -10], [-50, 50, -10]]], dtype=np.float64)
    field = _engine.SurfaceField(sheet, np.array([4], np.int32), np.zeros((1, 4, 3)), np.zeros((1, 4, 3)))
    field.set_luminaires([isotropic([0.0, 0.0, 2.0], 4 * math.pi * 1000.0)])
    v = field.volume_probes(np.array([[0.0, 0.0, 0.0]]), 64, 1)
    assert float(np.asarray(v.s0)[0, 1]) == pytest.approx(250.0, rel=1e-9)
    s1 = np.asarray(v.s1)[0]  # (3 axes, 3 channels)
    assert s1[2, 1] == pytest.approx(250.0, rel=1e-9) and abs(s1[0, 1]) < 1e-9
