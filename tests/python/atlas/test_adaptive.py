"""Coarse-to-fine texel evaluation (hirad.atlas.evaluate_adaptive, outputs.lightmaps.gather_stride).

The light here is an analytic function of the sample's 3D point, so the exact page is known:
evaluating every texel. The adaptive pass must reproduce it where its rules say it can:
- a field linear in space is interpolated exactly (the mean of a texel's lattice parents is
  the value at its centre on an affine chart), from about 1 / stride^2 of the texels;
- a steep but smooth one mostly too, each texel within the tolerance (its curvature is small);
- a shadow edge, and a shadow stripe as wide as the stride, come out exactly: every texel
  whose parents straddle them is evaluated itself;
- two charts side by side in the page but apart in space are never interpolated across, even
  with a tolerance that lets any values through."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("xatlas")
from hirad import atlas as A  # noqa: E402

T = 32.0  # texels per metre


def plate(w=2.0, h=1.0, z=0.0, x0=0.0):
    p = np.array([[x0, 0, z], [x0 + w, 0, z], [x0 + w, h, z], [x0, h, z]], float)
    return p, np.array([[0, 1, 2], [0, 2, 3]])


def page_samples(meshes, supersample=1, padding=2):
    atlas = A.build_atlas(meshes, T, padding, 1024)
    assert len(atlas.page_sizes) == 1
    s = A.rasterize(atlas, 0, supersample)
    points, normals = A.sample_points(s, atlas.geometry)
    return s, points, normals


def run(field, s, points, normals, stride, tolerance):
    calls = []

    def evaluate(p, n, texel):
        calls.append(len(p))
        return field(p)

    values, counts = A.evaluate_adaptive(s, points, normals, evaluate, stride, tolerance)
    assert counts["evaluated"] + counts["interpolated"] == len(s.x)
    assert counts["lattice"] + counts["not_interpolable"] + counts["apart"] + counts["disagree"] == counts["evaluated"]
    full, _ = A.resolve(s, field(points))
    got, _ = A.resolve(s, values)
    return got, full, counts, calls


def linear(p):
    return np.stack([1 + 0.3 * p[:, 0] + 0.2 * p[:, 1], 2 - 0.1 * p[:, 0], 0.5 + 0.4 * p[:, 1]], axis=1)


@pytest.mark.parametrize("supersample", [1, 2])
@pytest.mark.parametrize("stride", [2, 4, 8])
def test_a_linear_field_is_interpolated_exactly_from_few_texels(supersample, stride):
    s, points, normals = page_samples([plate()], supersample)
    got, full, counts, calls = run(linear, s, points, normals, stride, 0.5)
    np.testing.assert_allclose(got, full, rtol=1e-9, atol=1e-12)
    n = len(s.x)
    # the lattice, the chart's border texels (their parents leave the chart) and nothing more
    lattice = n / stride**2
    border = 2 * (64 + 32) * stride
    assert counts["evaluated"] <= lattice + border, (counts, n)
    assert counts["interpolated"] >= n - lattice - border
    # one evaluate call per level, the first one included
    assert len(calls) <= int(np.log2(stride)) + 1


def test_a_steep_smooth_gradient_is_interpolated_within_the_tolerance():
    """Light rising fivefold across the plate: neighbouring lattice texels differ by far more
    than 2 %, but the curvature is small, so the second differences let most texels be
    interpolated, each within the tolerance of its own value."""
    s, points, normals = page_samples([plate()], 1)

    def field(p):
        v = 1.0 + 2.0 * p[:, 0] + 0.8 * p[:, 0] ** 2 + 0.5 * p[:, 1] ** 2
        return np.stack([v, 1.5 * v, 0.5 * v], axis=1)

    got, full, counts, _ = run(field, s, points, normals, 4, 0.02)
    lit = full[..., 0] > 0
    rel = np.abs(got[lit] / full[lit] - 1.0)
    assert rel.max() <= 0.02, rel.max()
    assert counts["interpolated"] > 0.6 * len(s.x), counts


def shadow_edge(p):
    v = np.where(p[:, 0] < 0.77, 1.0, 0.1)
    return np.stack([v, 0.5 * v, v], axis=1)


def shadow_stripe(width):
    def f(p):
        v = np.where((p[:, 0] > 0.61) & (p[:, 0] < 0.61 + width), 0.05, 1.0)
        return np.stack([v, v, v], axis=1)
    return f


@pytest.mark.parametrize("stride", [2, 4])
def test_shadows_at_least_a_stride_wide_come_out_exactly(stride):
    s, points, normals = page_samples([plate()], 1)
    for field in (shadow_edge, shadow_stripe(stride / T), shadow_stripe(3 * stride / T)):
        got, full, counts, _ = run(field, s, points, normals, stride, 0.05)
        np.testing.assert_array_equal(got, full)
        assert counts["interpolated"] > 0.5 * len(s.x)


def test_charts_side_by_side_are_not_interpolated_across():
    # one mesh of two plates 3 m apart, facing the same way: two charts packed next to each
    # other, one tenth as bright as the other
    a, fa = plate(0.5, 0.5, 0.0)
    b, fb = plate(0.5, 0.5, 0.0, x0=3.0)
    mesh = (np.concatenate([a, b]), np.concatenate([fa, fb + 4]))
    s, points, normals = page_samples([mesh], 1, padding=1)

    def field(p):
        v = np.where(p[:, 0] < 2.0, 1.0, 0.1)
        return np.stack([v, v, v], axis=1)

    got, full, counts, _ = run(field, s, points, normals, 4, 1.0)
    np.testing.assert_array_equal(got, full)
    assert counts["interpolated"] > 0


def test_meshes_and_planes_are_not_mixed():
    # two meshes, and a plate folded at a right angle along x = 1 (one mesh, two planes, and
    # likely one chart: it unfolds flat); the light has a kink along the fold
    fold = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1, 0, 1], [1, 1, 1]], float)
    folded = (fold, np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]]))
    s, points, normals = page_samples([plate(z=5.0), folded], 1, padding=1)

    def field(p):
        v = 1.0 + 2.0 * p[:, 2]  # 11 on the plate; 1 on the fold's first half, rising on its second
        return np.stack([v, v, v], axis=1)

    got, full, _, _ = run(field, s, points, normals, 4, 1.0)
    np.testing.assert_array_equal(got, full)


def test_stride_one_and_bad_strides():
    s, points, normals = page_samples([plate()], 1)
    got, full, counts, calls = run(linear, s, points, normals, 1, 0.05)
    np.testing.assert_array_equal(got, full)
    assert counts["interpolated"] == 0 and len(calls) == 1
    for bad in (0, 3, 6):
        with pytest.raises(ValueError, match="power of two"):
            A.evaluate_adaptive(s, points, normals, lambda p, n, t: linear(p), bad, 0.05)
