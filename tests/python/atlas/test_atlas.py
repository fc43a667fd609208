"""Lightmap atlas and texel sampling (hirad.atlas): density, padding, grid alignment, pages,
existing UVs, rasterisation, dilation, seams, RGBM and the manifest.

Coverage here is computed independently of the module: a texel is covered by a triangle when
clipping the triangle to the texel square leaves positive area (Sutherland-Hodgman below),
which is the definition the module promises."""

from __future__ import annotations

import json
import math
import os
import time

import numpy as np
import pytest

pytest.importorskip("xatlas")
from hirad import atlas as A  # noqa: E402

T = 32.0  # texels per metre used throughout


# ---------------------------------------------------------------------------------------
# Geometry


def unit_cube():
    """8 shared corners, 12 triangles wound outwards: xatlas must cut it into charts."""
    p = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return p, f


def quad(w=2.0, h=1.0):
    return np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]], float), np.array([[0, 1, 2], [0, 2, 3]])


def cube_uv_layout(cell=1 / 3, island=0.3):
    """Author lightmap UVs of `unit_cube`: each face (2 triangles) an island x island square
    (island may be one size per face) in a 3x2 grid of cells; corners of a face share UVs,
    so a face is one island."""
    sizes = np.broadcast_to(np.asarray(island, float), (6,))
    p, f = unit_cube()
    uv = np.zeros((len(f), 3, 2))
    for face in range(6):
        tris = f[2 * face:2 * face + 2]
        corners = np.unique(tris)
        pts = p[corners]
        axes = [k for k in range(3) if np.ptp(pts[:, k]) > 0]
        origin = np.array([(face % 3) * cell, (face // 3) * cell]) + (cell - sizes[face]) / 2
        lookup = {int(c): origin + sizes[face] * pts[i, axes] for i, c in enumerate(corners)}
        for j, tri in enumerate(tris):
            uv[2 * face + j] = [lookup[int(c)] for c in tri]
    return uv


def areas3(p, f):
    a, b, c = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def areas2(uv):
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


# ---------------------------------------------------------------------------------------
# Reference coverage: exact clipping


def _clip(poly, axis, bound, keep_above):
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        ia = a[axis] >= bound if keep_above else a[axis] <= bound
        ib = b[axis] >= bound if keep_above else b[axis] <= bound
        if ia:
            out.append(a)
        if ia != ib:
            t = (bound - a[axis]) / (b[axis] - a[axis])
            out.append(a + t * (b - a))
    return out


def clipped_area(tri, x, y):
    poly = [np.asarray(v, float) for v in tri]
    for axis, bound, above in ((0, x, True), (0, x + 1, False), (1, y, True), (1, y + 1, False)):
        poly = _clip(poly, axis, bound, above)
        if len(poly) < 3:
            return 0.0
    q = np.array(poly)
    return 0.5 * abs(np.dot(q[:, 0], np.roll(q[:, 1], -1)) - np.dot(q[:, 1], np.roll(q[:, 0], -1)))


def covered_by(tri, width, height):
    """Texels (ix, iy v-up) the triangle (3, 2) in texel units covers with positive area."""
    lo = np.maximum(np.floor(tri.min(axis=0)).astype(int), 0)
    hi = np.minimum(np.ceil(tri.max(axis=0)).astype(int) - 1, [width - 1, height - 1])
    if (hi < lo).any() or areas2(tri[None])[0] < 1e-12:
        return set()
    xs, ys = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
    xs, ys = xs.ravel(), ys.ravel()
    corners = np.stack([np.stack([xs + dx, ys + dy], -1) for dx in (0, 1) for dy in (0, 1)], 1)  # (n, 4, 2)
    d1, d2 = tri[1] - tri[0], tri[2] - tri[0]
    sign = 1.0 if d1[0] * d2[1] - d1[1] * d2[0] > 0 else -1.0
    inside_all = np.ones(len(xs), bool)
    outside_one = np.zeros(len(xs), bool)
    for k in range(3):
        a, b = tri[k], tri[(k + 1) % 3]
        e = sign * ((b[0] - a[0]) * (corners[..., 1] - a[1]) - (b[1] - a[1]) * (corners[..., 0] - a[0]))
        inside_all &= (e >= 0).all(axis=1)
        outside_one |= (e <= 0).all(axis=1)
    out = {(int(x), int(y)) for x, y in zip(xs[inside_all], ys[inside_all])}
    for x, y in zip(xs[~inside_all & ~outside_one], ys[~inside_all & ~outside_one]):
        if clipped_area(tri, x, y) > 1e-9:
            out.add((int(x), int(y)))
    return out


def page_coverage(atlas, page):
    """{chart id: set of texels (ix, iy v-up)} for every chart on the page."""
    w, h = atlas.page_sizes[page]
    charts: dict[int, set] = {}
    for m in atlas.page_meshes(page):
        layout = atlas.meshes[m]
        uv = layout.uvs * [w, h]
        for tri, c in zip(uv, layout.charts):
            if c >= 0:
                charts.setdefault(int(c), set()).update(covered_by(tri, w, h))
    return charts


def min_gap(charts):
    """Least number of empty texels between texels of two different charts (Chebyshev).
    Only texels on a chart's rim are compared: stepping from an inner texel towards the
    other chart never increases the distance, so the closest pair lies on the rims."""
    def rim(s):
        return np.array(sorted(t for t in s if any((t[0] + dx, t[1] + dy) not in s
                                                    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)))))
    sets = [rim(s) for s in charts.values() if s]
    best = math.inf
    for i in range(len(sets)):
        for j in range(i + 1, len(sets)):
            d = np.abs(sets[i][:, None, :] - sets[j][None, :, :]).max(axis=2).min()
            best = min(best, int(d) - 1)
    return best


# ---------------------------------------------------------------------------------------
# Fixtures


@pytest.fixture(scope="module")
def cube_quad():
    cube, q = unit_cube(), quad()
    return A.build_atlas([cube, q], T, 2, 256, names=["cube", "quad"])


# ---------------------------------------------------------------------------------------
# Density, padding, alignment, overlaps


@pytest.mark.parametrize("padding", [1, 2, 3])
def test_density_and_padding(padding):
    meshes = [unit_cube(), quad()]
    atlas = A.build_atlas(meshes, T, padding, 256)
    assert len(atlas.page_sizes) == 1 and not atlas.warnings
    w, h = atlas.page_sizes[0]
    for (p, f), layout in zip(meshes, atlas.meshes):
        uv = layout.uvs * [w, h]
        a3 = areas3(p, f)
        for c in np.unique(layout.charts):
            sel = layout.charts == c
            measured = math.sqrt(areas2(uv[sel]).sum() / a3[sel].sum())
            assert measured == pytest.approx(T, rel=0.05)
        whole = math.sqrt(areas2(uv).sum() / a3.sum())
        assert layout.texels_per_metre == pytest.approx(whole, rel=1e-9)
    charts = page_coverage(atlas, 0)
    assert len(charts) >= 7  # a cube cannot be one flat chart; the quad is one
    assert min_gap(charts) >= padding


def test_charts_on_grid_disjoint_and_fill(cube_quad):
    atlas = cube_quad
    w, h = atlas.page_sizes[0]
    assert w <= 256 and h <= 256 and w % 4 == 0 and h % 4 == 0
    for layout in atlas.meshes:
        assert layout.page == 0 and layout.source == "generated"
        assert layout.scale_offset == (1.0, 1.0, 0.0, 0.0)
        assert (layout.uvs >= 0).all() and (layout.uvs <= 1).all()
        uv = layout.uvs * [w, h]
        for c in np.unique(layout.charts):
            lo = uv[layout.charts == c].reshape(-1, 2).min(axis=0)
            # the promise: every chart's bounding box starts at a texel centre
            np.testing.assert_allclose(lo % 1.0, 0.5, atol=2e-3)
    charts = page_coverage(atlas, 0)
    seen: dict = {}
    for c, texels in charts.items():
        for t in texels:
            assert seen.setdefault(t, c) == c, f"texel {t} covered by charts {seen[t]} and {c}"
    # fill: covered texels over page texels, and the rasterizer's coverage is the same set
    assert atlas.fill[0] == pytest.approx(len(seen) / (w * h), abs=1e-12)
    samples = A.rasterize(atlas, 0, 2)
    got = set(zip(samples.x.tolist(), (h - 1 - samples.y).tolist()))
    assert got == set(seen)


def test_multiple_pages_and_oversized_mesh():
    cubes = [unit_cube() for _ in range(4)]
    padding, max_size = 2, 128
    atlas = A.build_atlas(cubes, T, padding, max_size)
    # six 32 x 32 texel faces (33 covered) with padding: at least 6 * 35^2 = 7350 texels a
    # cube, 29400 for four, more than the 15876 inside one 128 page's border
    assert len(atlas.page_sizes) >= 2
    assert not atlas.warnings
    for k, (w, h) in enumerate(atlas.page_sizes):
        assert w == h and w <= max_size and w & (w - 1) == 0
        assert min_gap(page_coverage(atlas, k)) >= padding
    for m in atlas.meshes:
        assert 0 <= m.page < len(atlas.page_sizes)
        assert m.texels_per_metre == pytest.approx(T, rel=0.05)

    # Squares of 62 texels cover 63: two side by side need 63 + 2 + 63 = 128 texels, two
    # more than the 126 inside a 128 page's border, so each takes a page; every covered
    # texel keeps the border (half the padding) from the page edges.
    side = 62 / T
    tight = A.build_atlas([quad(side, side) for _ in range(3)], T, padding, max_size)
    assert len(tight.page_sizes) == 3
    margin = (padding + 1) // 2
    for k, (w, h) in enumerate(tight.page_sizes):
        texels = np.array(sorted(set().union(*page_coverage(tight, k).values())))
        assert np.ptp(texels[:, 0]) + 1 == 63 and np.ptp(texels[:, 1]) + 1 == 63
        assert texels.min() >= margin
        assert (texels[:, 0] <= w - 1 - margin).all() and (texels[:, 1] <= h - 1 - margin).all()

    # A 2 m x 1 m quad needs 2 * 32 + 1 texels; a 32 page has 30 inside its border, so the
    # mesh must be scaled to at most 29 texels / 2 m, and says so. max_size 48 is not a
    # power of two: its pages are 32, with a warning.
    for size in (32, 48):
        small = A.build_atlas([quad()], T, padding, size)
        m = small.meshes[0]
        w, h = small.page_sizes[0]
        assert w == h == 32
        uv = m.uvs * [w, h]
        measured = math.sqrt(areas2(uv).sum() / areas3(*quad()).sum())
        assert m.texels_per_metre == pytest.approx(measured, rel=1e-9)
        assert 0.8 * 29 / 2 <= m.texels_per_metre <= 29 / 2
        assert np.ptp(uv[..., 0]) <= 29
        assert any("scaled down" in wmsg for wmsg in small.warnings)
        assert (size == 48) == any("not a power of two" in wmsg for wmsg in small.warnings)


def test_existing_uvs_keep_layout():
    p, f = unit_cube()
    uv = cube_uv_layout()
    atlas = A.build_atlas([(p, f), quad()], T, 2, 256, existing_uvs=[uv, None])
    m = atlas.meshes[0]
    w, h = atlas.page_sizes[m.page]
    assert m.source == "existing" and not atlas.warnings
    sx, sy, ox, oy = m.scale_offset
    # scale/offset applied to the author's UVs gives the atlas UVs
    np.testing.assert_allclose(uv * [sx, sy] + [ox, oy], m.uvs, atol=1e-12)
    # one isotropic scale in texels, set by 3D area over UV area
    s = T * math.sqrt(areas3(p, f).sum() / areas2(uv).sum())
    assert sx * w == pytest.approx(s, rel=1e-12) and sy * h == pytest.approx(s, rel=1e-12)
    assert m.texels_per_metre == pytest.approx(T, rel=1e-9)
    # the layout's bounding box starts at a texel centre
    np.testing.assert_allclose((m.uvs * [w, h]).reshape(-1, 2).min(axis=0) % 1, 0.5, atol=1e-9)
    assert len(np.unique(m.charts)) == 6
    # islands are 0.1/3 UV apart: 0.0333 * s texels; padding 6 asks more and is warned about
    gap = (1 / 3 - 0.3) * s
    assert 2 < gap < 6
    loose = A.build_atlas([(p, f)], T, 6, 256, existing_uvs=[uv])
    assert any("UV islands only" in wmsg for wmsg in loose.warnings)
    assert min_gap(page_coverage(atlas, 0)) >= 2  # the quad keeps its distance from the block
    # all six faces stacked on one square: kept as authored, and reported as overlapping
    stacked = cube_uv_layout(cell=0, island=1)
    assert not any("overlap" in wmsg for wmsg in atlas.warnings)
    overlapping = A.build_atlas([(p, f)], T, 2, 256, existing_uvs=[stacked])
    assert any("overlap" in wmsg for wmsg in overlapping.warnings)


def test_existing_uvs_repacked_islands():
    p, f = unit_cube()
    # islands of two sizes, so their extents in texels are not whole numbers (xatlas's own
    # packer would stretch each to whole texels: not rigid)
    uv = cube_uv_layout(island=[0.3, 0.2, 0.3, 0.2, 0.3, 0.2])
    padding = 4
    atlas = A.build_atlas([(p, f)], T, padding, 256, existing_uvs=[uv], existing_layout="repack")
    m = atlas.meshes[0]
    w, h = atlas.page_sizes[0]
    assert m.source == "existing-repacked" and m.scale_offset == (1.0, 1.0, 0.0, 0.0)
    s = T * math.sqrt(areas3(p, f).sum() / areas2(uv).sum())
    got = m.uvs * [w, h]
    islands = A.uv_islands(uv)
    assert len(np.unique(islands)) == 6
    for k in np.unique(islands):
        sel = islands == k
        shift = got[sel] - uv[sel] * s  # same scale for all islands, one translation each
        np.testing.assert_allclose(shift, np.broadcast_to(shift[0, 0], shift.shape), atol=1e-2)
    assert m.texels_per_metre == pytest.approx(T, rel=1e-9)
    assert min_gap(page_coverage(atlas, 0)) >= padding
    for k in np.unique(islands):  # bounding boxes start at texel centres
        np.testing.assert_allclose(got[islands == k].reshape(-1, 2).min(axis=0) % 1, 0.5, atol=1e-9)


def test_smooth_dense_sphere_has_no_folded_charts():
    # 100k triangles on a unit sphere (open at the poles and along one meridian). xatlas
    # 0.0.11 takes it for one planar region and returns a single chart folded onto itself;
    # the atlas must re-chart such charts and end with none folded and no overlap.
    n = 224
    th, ph = np.meshgrid(np.linspace(0.01, np.pi - 0.01, n + 1), np.linspace(0, 2 * np.pi, n + 1))
    p = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1).reshape(-1, 3)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + n + 1], 1)])
    atlas = A.build_atlas([(p, f)], T, 2, 1024)
    m = atlas.meshes[0]
    w, h = atlas.page_sizes[0]
    uvt = m.uvs * [w, h]
    d1, d2 = uvt[:, 1] - uvt[:, 0], uvt[:, 2] - uvt[:, 0]
    signed = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    for c in np.unique(m.charts):
        s = signed[m.charts == c]
        assert (s > 0).all() or (s < 0).all(), f"chart {c} is folded"
    assert not any("overlap" in wmsg for wmsg in atlas.warnings)
    assert m.texels_per_metre == pytest.approx(T, rel=0.05)
    # no overlap: UV area cannot exceed the texels covered
    samples = A.rasterize(atlas, 0, 1)
    assert areas2(uvt).sum() <= len(samples.x)


def test_charting_shared_among_children_gives_the_same_bits(monkeypatch, tmp_path):
    # Large atlases chart one child per core (charts._mesh_blocks). Each mesh's block depends on
    # that mesh alone, so sharing the meshes out must change nothing: blocks, warnings and order.
    from hirad.atlas import charts

    rng = np.random.default_rng(3)
    meshes = [unit_cube(), quad(3.0, 1.0), (unit_cube()[0] * 2.5, unit_cube()[1]), quad(0.5, 40.0)]
    for k in range(4):  # jittered grids: xatlas cuts them differently
        g = np.stack(np.meshgrid(np.arange(6.0), np.arange(5.0)), -1).reshape(-1, 2)
        pts = np.c_[g, rng.random(len(g)) * 0.3 * (k + 1)]
        i = (np.arange(4)[:, None] * 6 + np.arange(5)[None, :]).ravel()
        meshes.append((pts, np.concatenate([np.stack([i, i + 1, i + 7], 1), np.stack([i, i + 7, i + 6], 1)])))
    names = [f"m{k}" for k in range(len(meshes))]
    args = ([(np.asarray(p, float), np.asarray(f, np.int64)) for p, f in meshes], None, names, T, 2, 250,
            "keep", 256)
    one, w1 = charts._mesh_blocks(*args, workers=1)
    two, w2 = charts._mesh_blocks(*args, workers=2)
    three, w3 = charts._mesh_blocks(*args, workers=3)
    assert w1 == w2 == w3 and any("scaled down" in w for w in w1)  # the 40 m strip does not fit
    for a, b, c in zip(one, two, three):
        assert (a.width, a.height, a.density, a.source) == (b.width, b.height, b.density, b.source) \
            == (c.width, c.height, c.density, c.source)
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.uv, c.uv)
        assert np.array_equal(a.charts, b.charts) and np.array_equal(a.charts, c.charts)
    # build_atlas takes the shared path above the threshold (it runs in a forked child: the
    # workers are noted in a file): the same atlas either way
    log = tmp_path / "workers"
    real = charts._mesh_blocks

    def noted(*a, **k):
        with open(log, "a") as out:
            out.write(f"{k.get('workers')}\n")
        return real(*a, **k)

    monkeypatch.setattr(charts, "_mesh_blocks", noted)
    monkeypatch.setattr(charts, "_PARALLEL_TRIANGLES", 10)
    shared = A.build_atlas(meshes, T, 2, 256)
    monkeypatch.setattr(charts, "_PARALLEL_TRIANGLES", 10**9)
    alone = A.build_atlas(meshes, T, 2, 256)
    assert log.read_text().split() == [str(len(os.sched_getaffinity(0))), "1"]
    assert shared.page_sizes == alone.page_sizes and shared.warnings == alone.warnings
    for a, b in zip(shared.meshes, alone.meshes):
        assert np.array_equal(a.uvs, b.uvs) and a.page == b.page


# ---------------------------------------------------------------------------------------
# Rasterize, resolve, dilate


def linear(points):
    return np.stack([1 + 0.5 * points[:, 0] - 0.25 * points[:, 1] + 2 * points[:, 2],
                     3 - points[:, 0] + points[:, 1], 0.5 + points[:, 2]], axis=1)


def containing_point(atlas, page, centres):
    """3D point at each texel centre (v-up texel units) found by brute force over the page's
    triangles, and whether the centre is inside some triangle by a margin."""
    w, h = atlas.page_sizes[page]
    pts = np.full((len(centres), 3), np.nan)
    for mi in atlas.page_meshes(page):
        p, f = atlas.geometry[mi]
        uv = atlas.meshes[mi].uvs * [w, h]
        for tri_uv, tri in zip(uv, f):
            m = np.array([tri_uv[1] - tri_uv[0], tri_uv[2] - tri_uv[0]]).T
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            l12 = np.linalg.solve(m, (centres - tri_uv[0]).T).T
            bary = np.column_stack([1 - l12.sum(1), l12])
            inside = (bary > 1e-6).all(axis=1)
            pts[inside] = bary[inside] @ p[tri]
    return pts


def test_rasterize_resolve_linear_function(cube_quad):
    atlas = cube_quad
    w, h = atlas.page_sizes[0]
    samples = A.rasterize(atlas, 0, 1)
    pts, normals = A.sample_points(samples, atlas.geometry)
    image, mask = A.resolve(samples, linear(pts))
    assert mask.sum() == len(samples.x)
    centres = np.column_stack([samples.x + 0.5, h - 1 - samples.y + 0.5])
    truth = containing_point(atlas, 0, centres)
    inside = ~np.isnan(truth[:, 0])
    assert inside.sum() > 0.8 * len(samples.x)
    np.testing.assert_allclose(image[samples.y[inside], samples.x[inside]], linear(truth[inside]),
                               rtol=1e-5, atol=1e-5)
    # normals are the faces' unit normals: a cube has six, all axis-aligned
    np.testing.assert_allclose(np.abs(normals).max(axis=1), 1.0, atol=1e-12)

    # S = 2 on the quad: where all four sub-samples are inside, their mean is the centre value
    samples2 = A.rasterize(atlas, 0, 2)
    full = np.bincount(samples2.texel) == 4
    pts2, _ = A.sample_points(samples2, atlas.geometry)
    image2, _ = A.resolve(samples2, linear(pts2))
    centres2 = np.column_stack([samples2.x + 0.5, h - 1 - samples2.y + 0.5])[full]
    truth2 = containing_point(atlas, 0, centres2)
    ok = ~np.isnan(truth2[:, 0])
    assert ok.sum() > 0.8 * full.sum()
    np.testing.assert_allclose(image2[samples2.y[full][ok], samples2.x[full][ok]], linear(truth2[ok]),
                               rtol=1e-5, atol=1e-5)


def test_conservative_coverage_of_a_sliver():
    # a 1 m x 1 cm needle, its own UVs rotated by 30 degrees: at 32 texels/m it is 32 texels
    # long and at most 0.32 texel wide, so most texels it crosses have no sub-sample inside
    p = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0.01, 0]], float)
    f = np.array([[0, 1, 2]])
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    uv = (p[:, :2] @ np.array([[c, s], [-s, c]]))[f]
    atlas = A.build_atlas([(p, f)], T, 1, 64, existing_uvs=[uv])
    w, h = atlas.page_sizes[0]
    tri = atlas.meshes[0].uvs[0] * [w, h]
    samples = A.rasterize(atlas, 0, 2)
    got = set(zip(samples.x.tolist(), (h - 1 - samples.y).tolist()))
    assert got == covered_by(tri, w, h)
    assert samples.conservative.sum() > len(samples.x) / 2
    counts = np.bincount(samples.texel)
    assert (counts[samples.conservative] == 1).all()
    # the conservative sample is the closest point of the triangle to the texel centre
    dense = np.random.default_rng(1).dirichlet([1, 1, 1], 20000)
    edges = np.linspace(0, 1, 4001)[:, None]
    cloud = np.concatenate([dense @ tri] + [tri[k] + edges * (tri[(k + 1) % 3] - tri[k]) for k in range(3)])
    for t in np.nonzero(samples.conservative)[0]:
        k = np.nonzero(samples.texel == t)[0][0]
        at = samples.bary[k] @ tri
        centre = np.array([samples.x[t] + 0.5, h - 1 - samples.y[t] + 0.5])
        nearest = np.linalg.norm(cloud - centre, axis=1).min()
        assert np.linalg.norm(at - centre) <= nearest + 1e-9
        assert np.linalg.norm(at - centre) >= nearest - 2e-3  # the cloud's spacing
        assert (samples.bary[k] >= 0).all() and samples.bary[k].sum() == pytest.approx(1)


def window_any(mask, r):
    """Whether any covered texel lies within Chebyshev distance r (summed-area table)."""
    h, w = mask.shape
    sat = np.zeros((h + 1, w + 1), np.int64)
    sat[1:, 1:] = mask.astype(np.int64).cumsum(0).cumsum(1)
    y, x = np.mgrid[0:h, 0:w]
    y0, y1 = np.clip(y - r, 0, h), np.clip(y + r + 1, 0, h)
    x0, x1 = np.clip(x - r, 0, w), np.clip(x + r + 1, 0, w)
    return (sat[y1, x1] - sat[y0, x1] - sat[y1, x0] + sat[y0, x0]) > 0


def test_dilate_fills_rings_and_keeps_covered(cube_quad):
    samples = A.rasterize(cube_quad, 0, 2)
    pts, _ = A.sample_points(samples, cube_quad.geometry)
    image, mask = A.resolve(samples, linear(pts))
    rings = 2
    out = A.dilate(image, mask, rings, whole_page=False)
    np.testing.assert_array_equal(out[mask], image[mask])
    near = window_any(mask, rings) & ~mask
    far = ~window_any(mask, rings)
    assert near.any() and far.any()
    lo, hi = image[mask].min(axis=0), image[mask].max(axis=0)
    assert ((out[near] >= lo - 1e-6) & (out[near] <= hi + 1e-6)).all()
    assert (out[near].max(axis=1) > 0).all()  # linear() is positive on the unit cube
    assert (out[far] == 0).all()
    # the default also fills the rest of the page, each texel from its nearest filled one
    whole = A.dilate(image, mask, rings)
    np.testing.assert_array_equal(whole[mask], image[mask])
    np.testing.assert_array_equal(whole[near], out[near])
    assert ((whole >= lo - 1e-6) & (whole <= hi + 1e-6)).all()


def test_rasterize_100k_triangles():
    n = 224  # 2 * 224^2 = 100352 triangles on a flat 4 m square, its own UVs = xy / 4
    x, y = np.meshgrid(np.linspace(0, 4, n + 1), np.linspace(0, 4, n + 1))
    p = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    i = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n + 2], 1), np.stack([i, i + n + 2, i + n + 1], 1)])
    uv = (p[:, :2] / 4)[f]
    atlas = A.build_atlas([(p, f)], T, 2, 1024, existing_uvs=[uv])
    t0 = time.perf_counter()
    samples = A.rasterize(atlas, 0, 2)
    elapsed = time.perf_counter() - t0
    print(f"\nrasterize {len(f)} triangles, supersample 2: {elapsed:.2f} s, "
          f"{len(samples.x)} texels, {len(samples)} samples, fill {atlas.fill[0]:.3f}")
    side = 4 * T  # the square spans 128 texels from a texel centre: 129 texels a side
    assert len(samples.x) == (side + 1) ** 2
    # sub-samples sit every half texel; inside the square there are (2 * 128)^2 of them
    assert len(samples) == (2 * side) ** 2
    assert not samples.conservative.any()


# ---------------------------------------------------------------------------------------
# Seams


def smooth(points):
    return np.stack([np.exp(2 * points.sum(1)), 1 + np.exp(2 * points[:, 0] + points[:, 2]),
                     2 + np.sin(3 * points[:, 1])], axis=1)


def test_seam_stitching_on_a_cube():
    """The stitching itself, on every chart border (crease_angle 180: the cube's edges are all
    creases, which the default leaves alone, test below), with a field smooth in 3D."""
    atlas = A.build_atlas([unit_cube()], T, 2, 256)
    samples = A.rasterize(atlas, 0, 4)
    pts, _ = A.sample_points(samples, atlas.geometry)
    image, mask = A.resolve(samples, smooth(pts))
    assert len(A.seam_pairs(atlas, 0)) == 0  # 90 degrees: creases, not seams of a smooth surface
    pairs = A.seam_pairs(atlas, 0, crease_angle=180.0)
    # charts joining the 6 faces can keep at most 5 of the 12 edges uncut (a tree), so at
    # least 7 edges are seams; each is 32 texels long, a pair per texel (ends may be shared)
    assert len(pairs) >= 7 * 31
    assert mask[pairs[:, 1], pairs[:, 0]].all() and mask[pairs[:, 3], pairs[:, 2]].all()
    # both texels of a pair hold samples of the same 3D points (within half a texel)
    index = {(int(x), int(y)): k for k, (x, y) in enumerate(zip(samples.x, samples.y))}
    order = np.argsort(samples.texel, kind="stable")
    bounds = np.searchsorted(samples.texel[order], np.arange(len(samples.x) + 1))
    def texel_points(x, y):
        k = index[(int(x), int(y))]
        return pts[order[bounds[k]:bounds[k + 1]]]
    for xa, ya, xb, yb in pairs:
        pa, pb = texel_points(xa, ya), texel_points(xb, yb)
        assert np.linalg.norm(pa[:, None] - pb[None], axis=2).min() < 0.5 / T
    def worst(img):
        a, b = img[pairs[:, 1], pairs[:, 0]], img[pairs[:, 3], pairs[:, 2]]
        return float((np.abs(a - b) / np.maximum(np.abs(a), np.abs(b))).max())
    # Before stitching: a seam texel's samples lie in the half texel on its own face, their
    # mean 1/4 texel = 1/128 m from the edge; across an edge where one face's inward
    # direction is +axis and the other's -axis, exp(2(x+y+z)) differs by about 2*2/128 = 3 %.
    assert worst(image) > 0.02
    stitched = A.stitch(image, pairs)
    assert worst(stitched) < 0.02
    assert (stitched[~mask] == 0).all()
    # a single flat chart has no seams
    assert len(A.seam_pairs(A.build_atlas([quad()], T, 2, 256), 0)) == 0


def folded_strip(bend: float):
    """Two 1 m squares sharing the edge x = 0 (z from 0 to 1): a floor facing +y at x in [0, 1],
    and a face bent `bend` degrees up from the floor's plane on the other side (90: a wall
    facing +x), each its own island of authored lightmap UVs, so the shared edge is a seam."""
    c, s_ = math.cos(math.radians(bend)), math.sin(math.radians(bend))
    p = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0], [1, 0, 1], [-c, s_, 0], [-c, s_, 1]], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [0, 4, 5], [0, 5, 1]])
    uv = np.array([[[0.05, 0.05], [0.45, 0.05], [0.45, 0.45]], [[0.05, 0.05], [0.45, 0.45], [0.05, 0.45]],
                   [[0.55, 0.05], [0.95, 0.05], [0.95, 0.45]], [[0.55, 0.05], [0.95, 0.45], [0.55, 0.45]]])
    return (p, f), uv


@pytest.mark.parametrize("bend", [10.0, 90.0])
def test_seams_are_stitched_only_where_the_surface_is_smooth(bend):
    """Across a crease the light itself changes (a floor and the wall on it see different
    hemispheres): texels there keep their own surface's value. Across a shallow fold (within
    crease_angle, 30 degrees by default, the display mesh's rule) the seam is stitched."""
    mesh, uv = folded_strip(bend)
    normals = np.cross(mesh[0][mesh[1][:, 1]] - mesh[0][mesh[1][:, 0]], mesh[0][mesh[1][:, 2]] - mesh[0][mesh[1][:, 0]])
    np.testing.assert_allclose(normals[0] / np.linalg.norm(normals[0]), [0, 1, 0], atol=1e-12)
    atlas = A.build_atlas([mesh], T, 2, 256, existing_uvs=[uv])
    every = A.seam_pairs(atlas, 0, crease_angle=180.0)
    assert len(every) >= 0.8 * T  # the shared 1 m edge
    default = A.seam_pairs(atlas, 0)
    if bend < 30:
        np.testing.assert_array_equal(default, every)
    else:
        assert len(default) == 0

    def own_light(points, normals, mesh, triangle):  # floor 1, the other face 0.2, uniform on each
        return np.repeat(np.where(normals[:, 1:2] > 0.99, 1.0, 0.2), 3, axis=1)

    floor, other = np.float32(1.0), np.float32(0.2)
    image, mask = A.bake_page(atlas, 0, own_light)
    values = image[mask][:, 0]
    mixed = ~np.isin(values, [floor, other])
    if bend < 30:
        assert mixed.sum() >= 0.8 * T  # the seam's texels on both sides moved to their average
    else:
        assert not mixed.any()  # every texel its own face's light
        stitched, _ = A.bake_page(atlas, 0, own_light, crease_angle=180.0)
        assert (~np.isin(stitched[mask][:, 0], [floor, other])).sum() >= 0.8 * T  # (what the default avoids)


def test_bake_page_degenerate_triangles_and_fallbacks():
    p, f = unit_cube()
    f_bad = np.concatenate([f, [[0, 0, 0], [0, 1, 1]]])  # two triangles without area
    q = quad()
    atlas = A.build_atlas([(p, f_bad), q], T, 2, 256,
                          existing_uvs=[None, np.zeros((3, 3, 2))])  # wrong shape: charts made
    assert atlas.meshes[1].source == "generated" and any("shape" in w for w in atlas.warnings)
    assert (atlas.meshes[0].charts[-2:] == -1).all() and (atlas.meshes[0].charts[:-2] >= 0).all()
    seen = {}

    def evaluate(points, normals, mesh, triangle):
        seen["args"] = (points, normals, mesh, triangle)
        return linear(points)

    image, mask = A.bake_page(atlas, 0, evaluate, supersample=2)
    points, normals, mesh, triangle = seen["args"]
    assert not np.isin(triangle[mesh == 0], [12, 13]).any()  # no samples on the degenerate ones
    samples = A.rasterize(atlas, 0, 2)
    ref, ref_mask = A.resolve(samples, linear(A.sample_points(samples, atlas.geometry)[0]))
    np.testing.assert_array_equal(mask, ref_mask)
    expected = A.dilate(A.stitch(ref, A.seam_pairs(atlas, 0)), ref_mask, atlas.padding)
    np.testing.assert_array_equal(image, expected)


# ---------------------------------------------------------------------------------------
# Writers


def test_rgbm_png_round_trip(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(7)
    max_range = 8.0
    image = (rng.random((16, 24, 3)) ** 3 * max_range).astype(np.float32)
    image[0, 0] = 0
    image[0, 1] = [max_range, 0, 0.001]
    path = tmp_path / "page0.png"
    A.write_rgbm_png(path, image, max_range)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["page0.png"]
    with Image.open(path) as im:
        assert im.mode == "RGBA"
        assert float(im.text["hirad:rgbm_range"]) == max_range
    back, rng_read = A.read_rgbm_png(path)
    assert rng_read == max_range
    # rgb is rounded to 1/255 of the multiplier M = a/255, and M <= max/range + 1/255
    bound = 0.5 / 255 * (image.max(axis=2, keepdims=True) + max_range / 255) + 1e-6
    err = np.abs(back - image)
    assert (err <= bound).all()
    assert err.max() > 0.1 * bound.min()  # it is quantised, not stored exactly
    over = image.copy()
    over[1, 1] = [3 * max_range, 0, 0]
    A.write_rgbm_png(path, over, max_range)
    assert A.read_rgbm_png(path)[0][1, 1, 0] == pytest.approx(max_range)


def test_manifest(tmp_path):
    p, f = unit_cube()
    atlas = A.build_atlas([(p, f), quad()], T, 2, 256, existing_uvs=[cube_uv_layout(), None],
                          names=["box", "floor"])
    path = tmp_path / "lightmaps.json"
    files = [f"lm{k}.png" for k in range(len(atlas.page_sizes))]
    with pytest.raises(ValueError, match="page files"):
        A.write_manifest(path, atlas, files + ["extra.png"])
    A.write_manifest(path, atlas, files, {"hirad:version": "test"})
    data = json.loads(path.read_text())
    assert data["hirad:version"] == "test"
    assert data["pages"] == [{"file": f"lm{k}.png", "width": w, "height": h, "fill": round(atlas.fill[k], 6)}
                             for k, (w, h) in enumerate(atlas.page_sizes)]
    box, floor = data["meshes"]["box"], data["meshes"]["floor"]
    assert box["file"] == files[atlas.meshes[0].page] and floor["file"] == files[atlas.meshes[1].page]
    assert box["scaleOffset"] == list(atlas.meshes[0].scale_offset) and box["uvSource"] == "existing"
    assert floor["scaleOffset"] == [1.0, 1.0, 0.0, 0.0] and floor["uvSource"] == "generated"
    assert box["texelsPerMetre"] == pytest.approx(T)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["lightmaps.json"]


def _raise_value_error():
    raise ValueError("bad chart")


def _die_without_result():
    import os
    os._exit(3)


def test_isolated_returns_the_childs_result_and_reports_its_failures():
    # xatlas runs in a forked child (its scheduler can hang when an Atlas is destroyed); the
    # child's result, its exception and its death without a result must all reach the caller.
    assert A._isolated(np.add, np.arange(3), 1).tolist() == [1, 2, 3]
    with pytest.raises(ValueError, match="bad chart"):
        A._isolated(_raise_value_error)
    with pytest.raises(RuntimeError, match="ended without a result"):
        A._isolated(_die_without_result)


def _stuck_once(flag, x):
    """Sleeps far past its attempt's time limit the first time (as a lost xatlas wake-up
    would hang), answers at once after."""
    import os
    import time

    if not os.path.exists(flag):
        open(flag, "w").close()
        time.sleep(30)
    return 2 * x


def test_a_stuck_charting_child_is_killed_and_the_work_done_again(tmp_path, monkeypatch):
    import time

    from hirad.atlas import charts

    monkeypatch.setattr(charts, "_ATTEMPT_SECONDS", (0.5, None))
    t0 = time.monotonic()
    assert charts._isolated(_stuck_once, str(tmp_path / "flag"), 21) == 42
    assert time.monotonic() - t0 < 10  # the first child was killed, not waited for


def test_the_attempts_time_limits_grow_with_the_triangles(tmp_path, monkeypatch):
    # A child that takes 1.5 s is killed under a 0.5 s limit and finishes under 0.5 s x 4.
    import time

    from hirad.atlas import charts

    seen = []
    monkeypatch.setattr(charts, "_ATTEMPT_SECONDS", (0.5, None))
    real = charts._attempt
    monkeypatch.setattr(charts, "_attempt", lambda fn, args, limit: seen.append(limit) or real(fn, args, limit))
    assert charts._isolated(time.sleep, 1.5, scale=4.0) is None
    assert seen == [2.0]
    seen.clear()
    assert charts._isolated(time.sleep, 1.5) is None
    assert seen == [0.5, None]
