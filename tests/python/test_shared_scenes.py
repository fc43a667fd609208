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
    assert balance["max_relative_error"] < 0.01
    # Light leaves through the open front: a real share, not a rounding error.
    assert min(balance["escaped_W"][c] / balance["emitted_W"][c] for c in range(3)) > 0.05
    assert (result.output_dir / "solution.usda").is_file()
