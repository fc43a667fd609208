"""Pages, instances, whole-page dilation and Unity's encodings (hirad.atlas, issue 14).

Expected values come from geometry and from the documented decode formulas, not from the
module: a rectangle's chart density from xatlas's rule of stretching each chart to whole
texels, the gaps between charts from exact polygon clipping (test_atlas's reference
coverage), Unity's RGBM and dLDR round trips from the decode formulas and 8-bit rounding.
"""

from __future__ import annotations

import glob
import math
import os
from pathlib import Path
import time

import numpy as np
import pytest

pytest.importorskip("xatlas")
from hirad import atlas as A  # noqa: E402
from test_atlas import areas2, areas3, min_gap, page_coverage, quad, unit_cube  # noqa: E402

T = 32.0
# ../shared beside the project (CI has it, a user's machine does not: the test then skips)
HALL = str(Path(__file__).resolve().parents[3].parent / "shared" / "data" / "modern_hall" / "usd")


def moved(mesh, rotation_deg=0.0, scale=1.0, shift=(0.0, 0.0, 0.0)):
    """The mesh turned about z, scaled uniformly and moved: an instance of it."""
    p, f = mesh
    c, s = math.cos(math.radians(rotation_deg)), math.sin(math.radians(rotation_deg))
    r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return (p @ r.T) * scale + np.asarray(shift), f


def is_pow2(n):
    return n > 0 and n & (n - 1) == 0


def box_pyramid(image):
    """Every level of a 2x2 box-filter mip pyramid down to 1x1 (square power-of-two input)."""
    levels = [np.asarray(image, np.float64)]
    while levels[-1].shape[0] > 1:
        a = levels[-1]
        levels.append(0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]))
    return levels


# ---------------------------------------------------------------------------------------
# Pages


def test_pages_square_power_of_two_disjoint_and_dense():
    padding = 2
    meshes = [unit_cube(), quad(1.03, 0.51), quad(2.0, 1.0), moved(unit_cube(), 30, 0.7, (3, 0, 0))]
    atlas = A.build_atlas(meshes, T, padding, 256)
    assert not atlas.warnings
    for k, (w, h) in enumerate(atlas.page_sizes):
        assert w == h and is_pow2(w) and w <= 256
        # exact coverage (polygon clipping): no texel shared by two charts, and at least
        # `padding` empty texels between charts, of one mesh or of two
        assert min_gap(page_coverage(atlas, k)) >= padding
    # every mesh whole on one page, with the identity scale/offset and local = page UVs
    for m in atlas.meshes:
        assert 0 <= m.page < len(atlas.page_sizes)
        assert m.scale_offset == (1.0, 1.0, 0.0, 0.0)
        np.testing.assert_array_equal(m.local_uvs, m.uvs)
    # Density: xatlas stretches each chart to whole texels in x and y, so a planar a x b
    # rectangle (one chart) comes out at T * sqrt(ceil(aT) ceil(bT) / (aT * bT)).
    for mesh_index, (a, b) in ((1, (1.03, 0.51)), (2, (2.0, 1.0))):
        m = atlas.meshes[mesh_index]
        w = atlas.page_sizes[m.page][0]
        expected = T * math.sqrt(math.ceil(a * T) * math.ceil(b * T) / (a * T * b * T))
        assert m.texels_per_metre == pytest.approx(expected, rel=1e-4)
        got = math.sqrt(areas2(m.uvs * w).sum() / areas3(*meshes[mesh_index]).sum())
        assert got == pytest.approx(expected, rel=1e-4)
    # the cube faces are 1 m (32 texels) and 0.7 m (22.4 -> 23 texels): per chart at most
    # the whole-texel stretch of its extents E, sqrt(E_x E_y / ((E_x - 1)(E_y - 1)))
    for mesh_index in (0, 3):
        m = atlas.meshes[mesh_index]
        w = atlas.page_sizes[m.page][0]
        uv = m.uvs * w
        p, f = meshes[mesh_index]
        for c in np.unique(m.charts):
            sel = m.charts == c
            ext = np.ptp(uv[sel].reshape(-1, 2), axis=0)
            d = math.sqrt(areas2(uv[sel]).sum() / areas3(p, f)[sel].sum())
            bound = math.sqrt(ext[0] * ext[1] / max((ext[0] - 1) * (ext[1] - 1), 1e-9))
            assert T * (1 - 1e-4) <= d <= T * bound * (1 + 1e-4)


def test_page_sizes_follow_the_footprint():
    # 40 cubes of 0.25 m at 32 texels/m: 240 faces of 8 x 8 texels, each covering 9 x 9
    # (its edges run through texel centres). xatlas pads every chart by ceil(padding / 2) =
    # 1 texel on each side, so a face takes at least 11 x 11 texels of a page: fill can be
    # at most 81 / 121 = 0.669. Pages sized to the footprint come within 80 % of that; one
    # 128 page for everything would fill 19440 / 16384 > 1 (impossible), one 256 page 0.30.
    cubes = [moved(unit_cube(), 0, 0.25, (k, 0, 0)) for k in range(40)]
    atlas = A.build_atlas(cubes, T, 1, 128)
    covered = sum(f * w * h for f, (w, h) in zip(atlas.fill, atlas.page_sizes))
    total = sum(w * h for w, h in atlas.page_sizes)
    assert all(w == h and is_pow2(w) and w <= 128 for w, h in atlas.page_sizes)
    assert covered == 40 * 6 * 81  # whatever the packing
    assert covered / total >= 0.8 * 81 / 121
    # max_size pages when asked
    full = A.build_atlas(cubes[:3], T, 1, 128, shrink_pages=False)
    assert all(s == (128, 128) for s in full.page_sizes)


# ---------------------------------------------------------------------------------------
# Instances


def test_instances_share_local_uvs_and_get_their_own_rectangles():
    padding = 2
    cube = unit_cube()
    meshes = [cube, moved(cube, 90, 1.0, (5, 0, 0)), moved(cube, 45, 2.0, (0, 4, 0)), quad(),
              moved(cube, 10, 1.5, (0, 0, 3)), moved(quad(), 0, 1.0, (9, 9, 0))]
    prototypes = ["cube", "cube", "cube", None, "cube", "q"]
    atlas = A.build_atlas(meshes, T, padding, 256, prototypes=prototypes)
    assert not atlas.warnings
    members = [0, 1, 2, 4]
    first = atlas.meshes[0]
    for i in members:
        m = atlas.meshes[i]
        assert m.prototype == "cube"
        np.testing.assert_array_equal(m.local_uvs, first.local_uvs)  # one UV2 for all
        assert m.local_uvs.min() >= 0 and m.local_uvs.max() <= 1
        sx, sy, ox, oy = m.scale_offset
        np.testing.assert_allclose(m.uvs, m.local_uvs * [sx, sy] + [ox, oy], atol=0)  # Unity's formula
    # rectangles: distinct and disjoint on a page (with the padding between their texels)
    rects = {}
    for i in members:
        m = atlas.meshes[i]
        w = atlas.page_sizes[m.page][0]
        sx, sy, ox, oy = (np.array(m.scale_offset) * w).tolist()
        rects[i] = (m.page, ox, oy, ox + sx, oy + sy)
    for i in members:
        for j in members:
            if i < j and rects[i][0] == rects[j][0]:
                a, b = rects[i][1:], rects[j][1:]
                apart = a[2] + padding <= b[0] or b[2] + padding <= a[0] or \
                    a[3] + padding <= b[1] or b[3] + padding <= a[1]
                assert apart, (i, j, a, b)
    for k in range(len(atlas.page_sizes)):
        assert min_gap(page_coverage(atlas, k)) >= padding
    # every member at the asked density: the layout is charted for the smallest member
    # (scale 1) and scaled by s_i / s_min, so all members have one density, that of the
    # unit cube's charts (32 texels per 1 m face: exactly T)
    for i in members:
        assert atlas.meshes[i].texels_per_metre == pytest.approx(T, rel=1e-6)
    # a prototype of one member is an instance all the same (rectangle, [0, 1] local UVs)
    q = atlas.meshes[5]
    assert q.prototype == "q" and q.local_uvs.min() >= 0 and q.local_uvs.max() <= 1
    assert q.texels_per_metre == pytest.approx(T, rel=1e-6)  # 64 x 32 texels: whole already
    # members must share the first member's triangles
    with pytest.raises(ValueError, match="prototype"):
        A.build_atlas([cube, quad()], T, padding, 256, prototypes=["x", "x"])


def test_a_mesh_that_fills_a_page_alone():
    # 60 separate little quads in one mesh, at a density that needs more than a 64 page:
    # the mesh is scaled down (with a warning) to fit its own block into one page, and
    # goes onto the page whole even where xatlas's page packer cannot place its charts
    # one by one as tightly as it packed the block
    rng = np.random.default_rng(1)
    points, faces = [], []
    for k in range(60):
        w, h = rng.uniform(0.05, 0.4, 2)
        points += [[k, 0, 0], [k + w, 0, 0], [k + w, h, 0], [k, h, 0]]
        faces += [[4 * k, 4 * k + 1, 4 * k + 2], [4 * k, 4 * k + 2, 4 * k + 3]]
    mesh = (np.array(points, float), np.array(faces))
    atlas = A.build_atlas([mesh], T, 2, 64)
    assert atlas.page_sizes == [(64, 64)]
    assert any("scaled down" in w for w in atlas.warnings)
    assert min_gap(page_coverage(atlas, 0)) >= 2
    texels = np.array(sorted(set().union(*page_coverage(atlas, 0).values())))
    assert texels.min() >= 1 and texels.max() <= 62  # the page border keeps ceil(2 / 2)


def test_meshes_without_area_get_no_page():
    line = (np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), np.array([[0, 1, 2]]))  # collinear
    none = (np.zeros((0, 3)), np.zeros((0, 3), int))
    atlas = A.build_atlas([line, none, quad(), line], T, 2, 256, prototypes=["l", None, None, "l"])
    assert [m.page for m in atlas.meshes] == [-1, -1, 0, -1]
    assert [len(m.uvs) for m in atlas.meshes] == [0, 0, 2, 0]
    assert any("no triangle with area" in w for w in atlas.warnings)
    assert A.build_atlas([none], T, 2, 256).page_sizes == []


def fine_square(side, n, origin=(0.0, 0.0, 0.0)):
    """A side x side square in z = 0 cut into n x n cells of two triangles each."""
    g = np.linspace(0.0, side, n + 1)
    x, y = np.meshgrid(g, g)
    p = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1) + np.asarray(origin)
    k = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    f = np.concatenate([np.stack([k, k + 1, k + n + 2], 1), np.stack([k, k + n + 2, k + n + 1], 1)])
    return p, f


def test_triangles_far_below_a_texel_are_charted():
    # 20,000 triangles of 4.5e-8 m^2 each: xatlas ignores faces under FLT_EPSILON (1.19e-7)
    # in its own units, so in metres it left every one of them out of its charts (the
    # country kitchen lost 141,284 triangles so); in texel units they are 4.6e-5 texel^2
    mesh = fine_square(0.03, 100)
    atlas = A.build_atlas([mesh, quad()], T, 2, 256)
    assert not any("out of its charts" in w for w in atlas.warnings), atlas.warnings
    layout = atlas.meshes[0]
    assert (layout.charts >= 0).all()
    w, h = atlas.page_sizes[layout.page]
    uv_area = float(np.abs(areas2(layout.uvs * [w, h])).sum())
    # the square's 0.96 x 0.96 texels, stretched by xatlas to whole texels (at most 2 x 2)
    assert (0.03 * T) ** 2 * 0.999 <= uv_area <= 4.0


def test_islands_without_uv_area_stay_on_their_mesh_page():
    # A triangle that xatlas leaves out of its charts is parked at a point: an island of no
    # UV area, which xatlas's page packer places on no page. It must stay on its mesh's
    # page as a point, not count as a chart that fits no page (41 of the country kitchen's
    # meshes had such islands, and they went onto one 4096 page, 1.2 % full)
    from hirad.atlas.pack import _pack_units

    square = np.array([[[0, 0], [20, 0], [20, 20]], [[0, 0], [20, 20], [0, 20]]], float)
    point = np.full((1, 3, 2), 7.25)
    other = square[:, :, :] * 0.5
    sizes, unit_page, unit_uv, fell_back = _pack_units([([square, point], False), ([other], False)], 1024, 2, 1)
    # the square's page is what the square alone asks for: 21 texels + padding + margins -> 32
    assert sizes[0] == 32 and unit_page[0] == 0 and not fell_back
    placed_square, placed_point = unit_uv[0]
    assert np.ptp(placed_point.reshape(-1, 2), axis=0).max() == 0.0  # still a point
    lo, hi = placed_square.reshape(-1, 2).min(axis=0), placed_square.reshape(-1, 2).max(axis=0)
    assert (lo <= placed_point[0, 0]).all() and (placed_point[0, 0] <= hi).all()  # inside its mesh's chart


def test_same_inputs_same_bits():
    cube = unit_cube()
    meshes = [cube, moved(cube, 90, 1.5, (5, 0, 0)), quad(1.03, 0.51), moved(cube, 20, 0.3, (0, 2, 0))]
    runs = [A.build_atlas(meshes, T, 2, 256, prototypes=["c", "c", None, None]) for _ in range(2)]
    assert runs[0].page_sizes == runs[1].page_sizes and runs[0].fill == runs[1].fill
    for a, b in zip(runs[0].meshes, runs[1].meshes):
        assert a.page == b.page and a.scale_offset == b.scale_offset
        np.testing.assert_array_equal(a.uvs, b.uvs)
        np.testing.assert_array_equal(a.local_uvs, b.local_uvs)


# ---------------------------------------------------------------------------------------
# Dilation


def test_whole_page_dilation_leaves_no_black_texel_at_any_mip_level():
    meshes = [unit_cube(), quad(2.0, 1.0)]
    atlas = A.build_atlas(meshes, T, 2, 256)

    def positive(points, normals, mesh, triangle):
        x = points + np.array([1.0, 2.0, 3.0])  # in [1, 5] on these meshes
        return np.stack([x[:, 0], x[:, 1] * 0.5, np.full(len(x), 1e-3)], axis=1)

    for k in range(len(atlas.page_sizes)):
        image, mask = A.bake_page(atlas, k, positive)
        w = atlas.page_sizes[k][0]
        assert image.shape[:2] == (w, w) and mask.any() and not mask.all()
        assert (image > 0).all()
        for level in box_pyramid(image):
            assert (level > 0).all()
        # the values are the charts' values: between their least and greatest
        lo, hi = image[mask].min(axis=0), image[mask].max(axis=0)
        assert ((image >= lo - 1e-6) & (image <= hi + 1e-6)).all()

    # beyond the padding rings, each texel holds the value of a nearest (Euclidean) filled one
    samples = A.rasterize(atlas, 0, 2)
    points, _ = A.sample_points(samples, atlas.geometry)
    image, mask = A.resolve(samples, positive(points, None, None, None))
    rings = A.dilate(image, mask, 2, whole_page=False)
    whole = A.dilate(image, mask, 2)
    filled = (rings > 0).any(axis=2)
    np.testing.assert_array_equal(whole[filled], rings[filled])
    ys, xs = np.nonzero(filled)
    w = atlas.page_sizes[0][0]
    for y, x in ((0, 0), (w - 1, w - 1), (0, w - 1), (w - 1, 0), (w // 2, 3)):
        if filled[y, x]:
            continue
        d = (ys - y) ** 2 + (xs - x) ** 2
        nearest = np.nonzero(d == d.min())[0]
        assert any(np.array_equal(whole[y, x], rings[ys[n], xs[n]]) for n in nearest)


# ---------------------------------------------------------------------------------------
# Encodings


def test_unity_rgbm_round_trip_within_8_bit_rounding(tmp_path):
    rng = np.random.default_rng(3)
    linear = (rng.random((32, 32, 3)) ** 4 * 40.0).astype(np.float32)  # partly above 34.49
    linear[0, 0] = 0
    q = A.encode_unity_rgbm(linear)
    assert q.dtype == np.uint8 and q.shape == (32, 32, 4)
    # Unity: gamma value g = 5 * a * rgb; linear = g^2.2 = rgb^2.2 * a^2.2 * 34.49
    r, a = q[..., :3] / 255.0, q[..., 3:4] / 255.0
    assert np.allclose(A.decode_unity_rgbm(q), (r ** 2.2) * (a ** 2.2) * 5 ** 2.2, rtol=1e-6, atol=1e-12)
    assert np.allclose(A.decode_unity_rgbm(q, "gamma"), 5 * a * r, rtol=1e-6)
    # rgb rounds to 1/255 of the stored multiplier: the gamma value is within
    # delta = 5 a / 255 / 2 of the exact one (clamped to the range), so the linear value
    # lies in [(g - delta)^2.2, (g + delta)^2.2]
    g = np.minimum(np.clip(linear, 0, None) ** (1 / 2.2), 5.0)
    delta = 5 * a / 255 / 2
    back = A.decode_unity_rgbm(q).astype(np.float64)
    assert (back >= np.clip(g - delta, 0, None) ** 2.2 * (1 - 1e-6) - 1e-9).all()
    assert (back <= (g + delta) ** 2.2 * (1 + 1e-6) + 1e-9).all()
    assert np.abs(back - g ** 2.2).max() > 0  # quantised, not stored
    assert back.max() == pytest.approx(5 ** 2.2, rel=1e-6)  # 34.49: the documented range
    path = tmp_path / "lm.png"
    A.write_png(path, linear, "unity-rgbm")
    from PIL import Image

    with Image.open(path) as im:
        assert im.mode == "RGBA" and im.text["hirad:encoding"] == "unity-rgbm"
        assert "2.2" in im.text["hirad:decode"]
    read, encoding = A.read_png(path)
    assert encoding == "unity-rgbm"
    np.testing.assert_array_equal(read, A.decode_unity_rgbm(q))


def test_unity_dldr_round_trip_within_8_bit_rounding(tmp_path):
    linear = np.linspace(0, 6.0, 3 * 200).reshape(10, 20, 3).astype(np.float32)  # past 2^2.2 = 4.59
    q = A.encode_unity_dldr(linear)
    assert q.dtype == np.uint8 and q.shape == (10, 20, 3)
    t = q / 255.0
    assert np.allclose(A.decode_unity_dldr(q), 4.594794 * t ** 2.2, rtol=1e-5)  # Unity's 4.59482 * rgb_linear
    assert np.allclose(A.decode_unity_dldr(q, "gamma"), 2 * t, rtol=1e-6)
    g = np.minimum(linear ** (1 / 2.2), 2.0)  # gamma value, clamped at 2
    h = 2 * 0.5 / 255  # 8-bit rounding of g / 2, in gamma units
    back = A.decode_unity_dldr(q).astype(np.float64)
    assert (back >= np.clip(g - h, 0, None) ** 2.2 * (1 - 1e-6) - 1e-9).all()
    assert (back <= (g + h) ** 2.2 * (1 + 1e-6)).all()
    assert back.max() == pytest.approx(2 ** 2.2, rel=1e-6)
    path = tmp_path / "lm.png"
    A.write_png(path, linear, "unity-dldr")
    read, encoding = A.read_png(path)
    assert encoding == "unity-dldr"
    np.testing.assert_array_equal(read, A.decode_unity_dldr(q))
    # hirad's own RGBM through the same writer, and an unknown name refused
    A.write_png(path, linear, "hirad-rgbm", max_range=8.0)
    read, encoding = A.read_png(path)
    assert encoding == "hirad-rgbm" and np.abs(read - linear).max() <= 8.0 / 255
    with pytest.raises(ValueError, match="unknown lightmap encoding"):
        A.write_png(path, linear, "rgbe")


# ---------------------------------------------------------------------------------------
# The Modern Hall


def hall_meshes():
    from hirad.usd.scene import read_scene

    paths = sorted(glob.glob(os.path.join(HALL, "*.usd*")))
    scene = read_scene(paths[0])
    counts = np.asarray(scene.face_vertex_counts)
    index = np.asarray(scene.face_vertex_indices)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    points = np.asarray(scene.points, dtype=np.float64)
    meshes = []
    for m in range(len(scene.meshes)):
        faces = np.nonzero(np.asarray(scene.face_mesh) == m)[0]
        tris = [(index[start[f]], index[start[f] + k], index[start[f] + k + 1])
                for f in faces for k in range(1, counts[f] - 1)]  # fans
        if not tris:
            continue
        used, local = np.unique(np.array(tris), return_inverse=True)
        meshes.append((points[used], local.reshape(-1, 3)))
    return meshes


@pytest.mark.skipif(not os.path.isdir(HALL), reason=f"the Modern Hall is not here ({HALL})")
def test_modern_hall_pages_fill():
    from scipy.ndimage import maximum_filter, minimum_filter

    from hirad.atlas.texels import _covered_texels

    meshes = hall_meshes()
    padding, density = 2, 16.0
    t0 = time.perf_counter()
    atlas = A.build_atlas(meshes, density, padding, 4096)
    seconds = time.perf_counter() - t0
    sizes = atlas.page_sizes
    covered = sum(f * w * h for f, (w, h) in zip(atlas.fill, sizes))
    fill = covered / sum(w * h for w, h in sizes)
    print(f"\nModern Hall: {len(meshes)} meshes, pages {sizes}, fill per page "
          f"{[round(f, 3) for f in atlas.fill]}, overall {fill:.3f}, {seconds:.1f} s")
    assert all(w == h and is_pow2(w) for w, h in sizes)
    assert fill >= 0.7
    # no texel of two charts, and `padding` empty texels between charts (charts of one
    # mesh and of different meshes): each covered texel's (2 padding + 1)^2 window holds
    # only its own chart
    for k, (w, _) in enumerate(sizes):
        uv, mesh_of, tri_of = atlas.page_texel_uvs(k)
        chart = np.concatenate([atlas.meshes[i].charts for i in atlas.page_meshes(k)]).astype(np.int64)
        tri, lin = _covered_texels(uv, w, w)
        label = chart[tri]
        pairs = np.unique(np.stack([lin, label], 1), axis=0)
        assert len(np.unique(pairs[:, 0])) == len(pairs)  # one chart per texel
        img_hi = np.full(w * w, -1, np.int64)
        img_hi[pairs[:, 0]] = pairs[:, 1]
        img_lo = np.where(img_hi < 0, (1 << 40), img_hi)
        img_hi, img_lo = img_hi.reshape(w, w), img_lo.reshape(w, w)
        size = 2 * padding + 1
        cov = img_hi >= 0
        assert (maximum_filter(img_hi, size=size, mode="constant", cval=-1)[cov] == img_hi[cov]).all()
        assert (minimum_filter(img_lo, size=size, mode="constant", cval=(1 << 40))[cov]
                == img_lo[cov]).all()
    for m, (p, f) in zip(atlas.meshes, meshes):
        assert 0 <= m.page < len(sizes)
        # measured density: at least the asked one (xatlas only stretches charts up)
        assert m.texels_per_metre >= density * (1 - 1e-3)


def test_a_polygon_is_never_cut_across_charts():
    """A 40 m strip of 31 quads (0.5 m wide) at 16 texels/m is longer than the page its texels
    need, so its chart is cut (pack._split_to_fit); cut by triangle centroids, one quad lands on
    both sides. With the quads given as polygons, every quad stays in one chart, connected: its
    two triangles share the diagonal's UVs (a faceVarying UV set has one UV per quad corner)."""
    n = 31
    x = np.linspace(0, 40.3, n + 1)
    pts = np.array([[xi, 0, z] for xi in x for z in (0.0, 0.5)])
    quads = [[2 * i, 2 * i + 1, 2 * i + 3, 2 * i + 2] for i in range(n)]
    tris = np.array([[q[0], q[1], q[2]] for q in quads] + [[q[0], q[2], q[3]] for q in quads])
    poly = np.array(list(range(n)) * 2)

    def apart(atlas):
        ch = atlas.meshes[0].charts
        return sum(len(set(ch[poly == k])) > 1 for k in range(n))

    plain = A.build_atlas([(pts, tris)], 16.0, 2, 4096)
    assert len(set(plain.meshes[0].charts)) > 1  # the strip was cut
    assert apart(plain) >= 1  # the case this guards against (triangles cut apart)
    whole = A.build_atlas([(pts, tris)], 16.0, 2, 4096, polygons=[poly])
    assert apart(whole) == 0
    uv = whole.meshes[0].uvs
    for k in range(n):  # the diagonal (corners 0 and 2 of the quad) has the same UVs in both triangles
        assert np.allclose(uv[k][[0, 2]], uv[n + k][[0, 1]], atol=1e-9)
