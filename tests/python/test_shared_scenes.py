"""Reading and baking the real scenes in ../shared/data (skipped, with a message, where that
folder is absent: it sits beside the project on developer machines and in CI only)."""

from pathlib import Path

import numpy as np
import pytest

from hirad import usd
from hirad.config import config_from_dict

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared test data not found at {DATA}")


def _emitted_power(scene) -> np.ndarray:
    counts = scene.face_vertex_counts
    offsets = np.concatenate([[0], np.cumsum(counts)])
    power = np.zeros(3)
    for f in np.nonzero(scene.face_emission.max(axis=1) > 0)[0]:
        poly = scene.points[scene.face_vertex_indices[offsets[f]:offsets[f + 1]]]
        n = sum(np.cross(poly[k], poly[(k + 1) % len(poly)]) for k in range(len(poly)))
        power += scene.face_emission[f] * 0.5 * np.linalg.norm(n)
    return power


def test_bundled_cornell_box_emits_like_the_measured_one():
    # Same light (130 x 105 mm, radiance (17, 11.8, 4)): the same emitted power, in watts.
    ours = usd.read_scene(ROOT / "configs/scenes/cornell_box.usda")
    measured = usd.read_scene(DATA / "cornell_box_measured/usd/cornell_box_measured.usda")
    expected = np.pi * np.array([17, 11.8, 4]) * 0.130 * 0.105
    np.testing.assert_allclose(_emitted_power(ours), expected, rtol=1e-6)
    np.testing.assert_allclose(_emitted_power(measured), expected, rtol=1e-3)
    lo, hi = ours.points.min(axis=0), ours.points.max(axis=0)
    mlo, mhi = measured.points.min(axis=0), measured.points.max(axis=0)
    np.testing.assert_allclose(lo, mlo, atol=1e-4)
    np.testing.assert_allclose(hi, mhi, atol=1e-3)


def test_material_variants_agree():
    # The MaterialX-in-UsdShade variant of the same box reads as the UsdPreviewSurface one.
    base = usd.read_scene(DATA / "cornell_box_usd/cornell-box/usdpreviewsurface/cornell-box.usda")
    other = usd.read_scene(DATA / "cornell_box_usd/cornell-box/mtlx-usdshade/cornell-box.usda")
    np.testing.assert_allclose(other.face_reflectance, base.face_reflectance)
    np.testing.assert_allclose(other.face_emission, base.face_emission)
    assert np.count_nonzero(other.face_emission.max(axis=1) > 0) == 1


def test_unsupported_material_is_reported():
    scene = usd.read_scene(DATA / "cornell_box_usd/cornell-box/mdl/cornell-box.usda")
    assert any("not UsdPreviewSurface" in w for w in scene.warnings)


def test_shared_cornell_box_bakes_with_energy_balance(tmp_path):
    # The 10x-size Z-up variant: metres, a closed-but-for-the-front box lit by its ceiling light.
    scene = DATA / "cornell_box_usd/cornell-box/usdpreviewsurface/cornell-box.usda"
    cfg = config_from_dict({
        "scene": str(scene), "output": str(tmp_path / "out"), "method": "flat",
        "meshing": {"max_patch_area": 1.0, "max_edge_length": 1.0},
        "formfactors": {"samples": 16},
        "solver": {"tolerance": 1e-6},
        "outputs": {"lightmaps": {"enabled": False}, "preview": {"enabled": False}},
    }, tmp_path)
    import hirad

    result = hirad.bake(cfg)
    balance = result.report["energy_balance"]
    # emitted - absorbed against the power that leaves through the open front, measured by
    # rays against the scene as authored (proof_helpers.escaped_power: no coupling used),
    # within 3 sigma, the residual's bound and the couplings' quadrature allowance at 16
    # samples (0.2 %, see test_proof.QUADRATURE)
    from proof_helpers import escaped_power, scene_polygons

    p = result.patches
    area = p["area"][:, None]
    emitted = (p["emission"] * area).sum(axis=0)
    absorbed = ((1 - p["reflectance"]) * result.patch_irradiance * area).sum(axis=0)
    # The boxes have no bottoms and the light sits at the ceiling's height: the floor under
    # the boxes and the ceiling over the light send part of their power onto back faces,
    # which the system loses as it loses what escapes (the report counts both as escaped).
    escaped, sigma, _, back, back_sigma = escaped_power(
        p["corners"], p["nv"], p["normal"], result.patch_radiosity, p["area"], 1000, 1,
        occluders=scene_polygons(usd.read_scene(scene)), with_back=True)
    residual = result.report["solver"]["residual"] * np.linalg.norm(p["emission"]) * np.linalg.norm(p["area"])
    allowed = 3 * np.hypot(sigma, back_sigma) + residual + 2e-3 * emitted
    gap = emitted - absorbed - escaped - back
    assert np.all(np.abs(gap) <= allowed), (gap, allowed)
    print(f"\nshared Cornell box: emitted {emitted.round(3)}, absorbed {absorbed.round(3)}, escaped {escaped.round(3)}"
          f" +- {sigma.round(3)}, onto back faces {back.round(3)} +- {back_sigma.round(3)}")
    np.testing.assert_allclose(balance["absorbed_W"], absorbed, rtol=1e-9)
    # Light leaves through the open front: a real share, not a rounding error.
    assert np.all(escaped > 0.05 * emitted)
    assert (result.output_dir / "solution.usda").is_file()
