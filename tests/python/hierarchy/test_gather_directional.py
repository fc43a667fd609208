"""The final gather's radiance moments (GatherOptions(directional=True): PointValues.l0, l1) against
closed forms and independent quadrature, and tools/hirad/outputs/directional.py (Godot, Bakery
and Unity directional lightmaps) against the engines' documented decoders.

l0 = integral L dw and l1 = integral L w dw over the receiver's hemisphere (W/m^2). Oracles:
- a Lambertian emitter of radiance L seen from x: l0 = L Omega, l1 = L integral w dw, E = L pi F,
  with Omega and F of a parallel rectangle in closed form (the corner formulas, inclusion and
  exclusion) and the vector integral by a dense midpoint quadrature over the emitter's area
  (dw = cos theta_y / r^2 dA), an independent computation;
- a point luminaire of intensity I at distance r: l0 = I / r^2, l1 = I / r^2 d, E = I cos / r^2;
  a distant light of normal illuminance E_perp along d: l0 = E_perp, l1 = E_perp d;
- a closed box whose every wall emits radiosity B (reflecting nothing): L = B / pi over the whole
  hemisphere of any wall point, so l0 = 2 pi L = 2 B, l1 = pi L n = B n, E = B.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import box_faces, make_model, quad
from test_gather import corner_form_factor, solve  # the same solve and closed form as the plain gather's tests

from hirad import _engine
from hirad.outputs import directional as dl

DEG = np.pi / 180


def corner_solid_angle(a, b, c):
    """Solid angle of an a x b rectangle seen from a point at distance c below one corner."""
    return np.arctan(a * b / (c * np.sqrt(a * a + b * b + c * c)))


def offset_rectangle(corner_fn, x0, x1, y0, y1, c):
    """A corner formula for the rectangle [x0,x1] x [y0,y1] at height c seen from the origin,
    by inclusion and exclusion of the rectangles that reach the foot of the point."""
    def g(x, y):
        return np.sign(x) * np.sign(y) * corner_fn(abs(x), abs(y), c)
    return g(x1, y1) - g(x0, y1) - g(x1, y0) + g(x0, y0)


def quadrature_moments(x, n, corners, radiance, count=600):
    """l0, l1 and E of a Lambertian parallelogram (corners p0, p1, p2, p3) of radiance L seen
    from x with normal n, by the midpoint rule over its area, only the part above x's plane."""
    p0, p1, _, p3 = (np.asarray(c, dtype=float) for c in corners)
    u, v = p1 - p0, p3 - p0
    normal = np.cross(u, v)
    area = np.linalg.norm(normal)
    normal /= area
    s = (np.arange(count) + 0.5) / count
    y = p0 + s[:, None, None] * u + s[None, :, None] * v
    d = y - x
    r = np.linalg.norm(d, axis=-1)
    w = d / r[..., None]
    dw = np.clip(-(w @ normal), 0, None) / r ** 2 * (area / count ** 2)
    up = (w @ n) > 0
    dw = np.where(up, dw, 0.0)
    l0 = radiance * dw.sum()
    l1 = radiance * (dw[..., None] * w).sum(axis=(0, 1))
    e = radiance * (dw * (w @ n)).sum()
    return l0, l1, e


def angle_between(a, b):
    return np.arccos(np.clip(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1))


def gather(m, pts, nrm, directional=True, rays=16):
    return m.gather(np.ascontiguousarray(pts, dtype=float), np.ascontiguousarray(nrm, dtype=float),
                    _engine.GatherOptions(rays=rays, directional=directional))


def test_small_emitter_moments_are_the_closed_forms_and_point_at_it():
    # A black floor [-2,2]^2 at z = 0 under a small square emitter (side 0.05, B = pi, L = 1) at
    # z = 0.8 facing down: one bounce, nothing reflects, so the moments at a floor point are
    # exactly those of the emitter's polygon.
    s, h = 0.05, 0.8
    cx, cy = 0.5, 0.3
    emitter = quad([cx - s / 2, cy - s / 2, h], [0, s, 0], [s, 0, 0])
    floor = quad([-2, -2, 0], [4, 0, 0], [0, 4, 0])
    m = make_model([floor, emitter], reflectance=[[0.0] * 3, [0.0] * 3], emission=[[0.0] * 3, [np.pi] * 3])
    solve(m, 1e-3, 0.01)
    pts = np.array([[0.0, 0.0, 0.0], [0.5, 0.3, 0.0], [-0.7, 1.1, 0.0], [1.6, -1.5, 0.0]])
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    g = gather(m, pts, nrm)
    assert g.l0.shape == (4, 3) and g.l1.shape == (4, 3, 3)
    for k, x in enumerate(pts):
        x0, x1, y0, y1 = cx - s / 2 - x[0], cx + s / 2 - x[0], cy - s / 2 - x[1], cy + s / 2 - x[1]
        f = offset_rectangle(corner_form_factor, x0, x1, y0, y1, h)
        omega = offset_rectangle(corner_solid_angle, x0, x1, y0, y1, h)
        np.testing.assert_allclose(g.irradiance[k], np.pi * f, rtol=1e-9)      # L pi F, L = 1
        np.testing.assert_allclose(g.l0[k], omega, rtol=1e-9)                  # L Omega
        q0, q1, qe = quadrature_moments(x, nrm[k], emitter, 1.0)
        np.testing.assert_allclose(q0, omega, rtol=1e-5)                       # the quadrature itself
        for c in range(3):
            np.testing.assert_allclose(g.l1[k, c], q1, rtol=1e-5, atol=1e-9 * omega)
            # the direction: at the emitter's centre within 0.05 degrees (a 0.05 m square)
            assert angle_between(g.l1[k, c], [cx - x[0], cy - x[1], h]) < 0.05 * DEG
            # n . l1 = E: the cosine-weighted first moment is the irradiance
            np.testing.assert_allclose(g.l1[k, c] @ nrm[k], g.irradiance[k, c], rtol=1e-9)


def test_tilted_receiver_sees_a_large_emitter_cut_by_its_horizon():
    # A 1 m square emitter (L = 2) at z = 0.5 facing down, over a small receiver tilted 40 degrees
    # about y at the origin: the receiver's tangent plane cuts the emitter at x = -0.5 cot 40 deg,
    # so only part of it is above the horizon, seen from 0.5 m (the gather splits it into its
    # children there). A per-sample dE / cos rule would weight grazing samples by 1 / cos; the
    # exact polygon moments need no such guard. Quadrature (600^2 points) is the oracle.
    t = 40 * DEG
    n = np.array([np.sin(t), 0.0, np.cos(t)])
    e1 = np.array([np.cos(t), 0.0, -np.sin(t)])
    receiver = quad(-0.05 * e1 - [0, 0.05, 0], 0.1 * e1, [0, 0.1, 0])
    emitter = quad([-0.8, -0.5, 0.5], [0, 1, 0], [1, 0, 0])
    m = make_model([receiver, emitter], reflectance=[[0.0] * 3, [0.0] * 3], emission=[[0.0] * 3, [2 * np.pi] * 3])
    solve(m, 1e-4, 0.002)
    pts = np.array([[0.0, 0.0, 0.0], 0.03 * e1 + [0, 0.02, 0], -0.04 * e1 - [0, 0.03, 0]])
    g = gather(m, pts, np.tile(n, (3, 1)))
    for k, x in enumerate(pts):
        q0, q1, qe = quadrature_moments(x, n, emitter, 2.0, count=1200)
        # E: the gather's own estimate keeps the emitter points below the receiver's horizon in
        # its visibility mean (they count as blocked): 0.08 % low here (gather.h); the moments
        # average over the points above the horizon only.
        assert qe * (1 - 2e-3) <= g.irradiance[k].min() and g.irradiance[k].max() <= qe * (1 + 2e-4)
        np.testing.assert_allclose(g.l0[k], q0, rtol=2e-4)
        for c in range(3):
            np.testing.assert_allclose(g.l1[k, c], q1, rtol=2e-4, atol=2e-4 * q0)


def test_luminaire_moments_are_the_point_and_distant_closed_forms():
    # A black floor, an isotropic point light (I = 3 cd per unit colour, colour (1, 2, 0.5)) at
    # (0.4, -0.2, 1.5) and a two-direction distant light (E_perp = 7 split 0.25 / 0.75).
    floor = quad([-2, -2, 0], [4, 0, 0], [0, 4, 0])
    m = make_model([floor], reflectance=[[0.0] * 3], emission=[[0.0] * 3])
    p, intensity, colour = np.array([0.4, -0.2, 1.5]), 3.0, np.array([1.0, 2.0, 0.5])
    point = _engine.Luminaire("bulb", p[None, :], np.ones(1), np.eye(3), np.full((1, 2), intensity), colour[None, :])
    dirs = np.array([[0.3, 0.1, 1.0], [-0.5, 0.4, 0.6]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    sun = _engine.Luminaire.distant("sun", dirs, np.array([0.25, 0.75]), 7.0, np.ones((1, 3)))
    m.set_luminaires([point, sun])
    solve(m, 1e-3, 0.05)
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0]])
    nrm = np.tile([0.0, 0.0, 1.0], (2, 1))
    g = gather(m, pts, nrm)
    for k, x in enumerate(pts):
        d = p - x
        r2 = d @ d
        d /= np.sqrt(r2)
        l0 = intensity / r2 * colour + 7.0 * np.ones(3)
        l1 = np.outer(intensity / r2 * colour, d) + 7.0 * (0.25 * dirs[0] + 0.75 * dirs[1])[None, :]
        e = intensity / r2 * d[2] * colour + 7.0 * (0.25 * dirs[0, 2] + 0.75 * dirs[1, 2])
        np.testing.assert_allclose(g.irradiance[k], e, rtol=1e-9)
        np.testing.assert_allclose(g.l0[k], l0, rtol=1e-9)
        np.testing.assert_allclose(g.l1[k], l1, rtol=1e-9, atol=1e-12)


def test_uniform_hemisphere_in_an_emitting_box():
    # Every wall of the unit box emits B = 1 and reflects nothing: each wall point sees
    # L = 1 / pi over its whole hemisphere: l0 = 2, l1 = n, E = 1. Points at the floor's centre,
    # near a corner (where the side walls meet the horizon) and on a wall. Cluster sources are
    # sampled (faces drawn by area), the tolerance is that of the furnace test (1 %).
    m = make_model(box_faces(), 0.0, 1.0)
    solve(m, 1e-4, 0.0155, samples=64)
    pts = np.array([[0.5, 0.5, 0.0], [0.05, 0.93, 0.0], [0.0, 0.3, 0.6], [0.7, 0.2, 1.0]])
    nrm = np.array([[0, 0, 1.0], [0, 0, 1.0], [1.0, 0, 0], [0, 0, -1.0]])
    g = gather(m, pts, nrm)
    np.testing.assert_allclose(g.irradiance, 1.0, rtol=0.01)
    np.testing.assert_allclose(g.l0, 2.0, rtol=0.01)
    for c in range(3):
        np.testing.assert_allclose(g.l1[:, c, :], nrm, atol=0.01)
    # L1 SH irradiance for the normal: l0/4 + n.l1/2 = 1/2 + 1/2, exact for a uniform hemisphere
    np.testing.assert_allclose(dl.sh_l1_irradiance(g.l0, g.l1, nrm), g.irradiance, rtol=0.01)


def test_sh_irradiance_of_random_normals_and_in_a_lit_room():
    # (a) Small emitter above a floor point: the L1 SH reconstruction for random normals n' equals
    #     l0/4 + n'.l1/2 of the quadrature's moments, and is within l0/4 of the true irradiance
    #     of n' from the same radiance (the L1 truncation bound, module docstring of directional).
    s, h = 0.05, 0.8
    emitter = quad([0.45, 0.25, h], [0, s, 0], [s, 0, 0])
    floor = quad([-2, -2, 0], [4, 0, 0], [0, 4, 0])
    m = make_model([floor, emitter], reflectance=[[0.0] * 3, [0.0] * 3], emission=[[0.0] * 3, [np.pi] * 3])
    solve(m, 1e-3, 0.01)
    x = np.array([0.1, -0.2, 0.0])
    g = gather(m, x[None, :], [[0.0, 0.0, 1.0]])
    q0, q1, _ = quadrature_moments(x, np.array([0, 0, 1.0]), emitter, 1.0)
    rng = np.random.default_rng(11)
    normals = rng.normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    l0 = np.repeat(g.l0, 200, axis=0)
    l1 = np.repeat(g.l1, 200, axis=0)
    e1 = dl.sh_l1_irradiance(l0, l1, normals)[:, 0]
    np.testing.assert_allclose(e1, q0 / 4 + normals @ q1 / 2, rtol=1e-5, atol=1e-8)
    # true irradiance of n' (the emitter is tiny: its radiance arrives from one direction)
    d = np.array([0.475, 0.275, h]) - x
    d /= np.linalg.norm(d)
    true = q0 * np.clip(normals @ d, 0, None)
    assert np.all(np.abs(e1 - true) <= q0 / 4 * (1 + 1e-6))
    # and for one direction the truncation error is exactly |c/2 - 1/4| l0 with c = n'.d (up to
    # the emitter's 2 degree extent)
    np.testing.assert_allclose(np.abs(e1 - true), np.abs(np.clip(normals @ d, 0, None) - 0.25 - (normals @ d) / 2) * q0,
                               atol=2e-3 * q0)

    # (b) An open room with colour bleeding, occlusion and cluster links (test_gather's Monte
    #     Carlo room): at every point n.l1 = E, |l1| <= l0, E <= l0, and the L1 SH irradiance for
    #     the surface normal is within l0/4 of E.
    faces = box_faces(omit=("z1",))
    em = quad([0.25, 0.25, 0.95], [0, 0.5, 0], [0.5, 0, 0])
    refl = [[0.7, 0.2, 0.2], [0.2, 0.7, 0.2], [0.6, 0.6, 0.6], [0.6, 0.6, 0.6], [0.7, 0.7, 0.7], [0.0] * 3]
    emis = [[0.0] * 3] * 5 + [[10.0] * 3]
    m = make_model(faces + [em], refl, emis)
    solve(m, 3e-5, 0.002)
    pts = np.c_[rng.uniform(0.05, 0.95, (30, 2)), np.zeros(30)]
    pts = np.r_[pts, np.c_[np.zeros(20), rng.uniform(0.05, 0.95, (20, 2))]]
    nrm = np.r_[np.tile([0.0, 0, 1], (30, 1)), np.tile([1.0, 0, 0], (20, 1))]
    g = gather(m, pts, nrm)
    e, l0, l1 = g.irradiance, g.l0, g.l1
    assert np.all(e > 0)
    # n.l1 = E but where a partly visible source straddles a point's horizon (gather.h): there
    # the moments drop the points below the horizon that E counts as blocked, so n.l1 >= E.
    ndotl1 = np.einsum("qca,qa->qc", l1, nrm)
    assert np.all(ndotl1 >= e * (1 - 1e-9)) and np.all(ndotl1 <= e * 1.01)
    assert np.mean(np.abs(ndotl1 / e - 1) < 1e-9) > 0.5
    assert np.all(np.linalg.norm(l1, axis=-1) <= l0 * (1 + 1e-9))
    assert np.all(e <= l0 * (1 + 1e-9))
    assert np.all(np.abs(dl.sh_l1_irradiance(l0, l1, nrm) - e) <= l0 / 4 * (1 + 1e-9))
    # the floor sees the emitter and the coloured walls: not a uniform hemisphere (l1 != n l0/2)
    assert np.abs(np.einsum("qca,qa->qc", l1[:30], nrm[:30]) / l0[:30] - 0.5).max() > 0.05


def test_flag_off_is_the_same_irradiance_bit_for_bit_and_thread_independent():
    faces = box_faces(omit=("z1",))
    em = quad([0.25, 0.25, 0.95], [0, 0.5, 0], [0.5, 0, 0])
    m = make_model(faces + [em], [[0.6] * 3] * 5 + [[0.0] * 3], [[0.0] * 3] * 5 + [[10.0] * 3])
    solve(m, 1e-4, 0.004)
    rng = np.random.default_rng(2)
    pts = np.c_[rng.random((200, 2)), np.zeros(200)]
    nrm = np.tile([0.0, 0, 1], (200, 1))
    off = gather(m, pts, nrm, directional=False, rays=4)
    on = gather(m, pts, nrm, directional=True, rays=4)
    assert off.l0.shape == (0, 3) and off.l1.shape == (0, 3, 3)
    assert np.array_equal(off.irradiance, on.irradiance) and np.array_equal(off.radiance, on.radiance)
    assert on.irradiance.max() > 0
    try:
        _engine.set_threads(1)
        one = gather(m, pts, nrm, directional=True, rays=4)
    finally:
        _engine.set_threads(0)
    assert np.array_equal(one.l0, on.l0) and np.array_equal(one.l1, on.l1)


# --- directional.py against the engines' decoders ----------------------------------------------

def _random_texels(rng, count):
    """Per texel a normal and a radiance made of a uniform hemisphere part and a few directional
    parts above it (exact moments), in RGB; returns E, l0, l1, normals and the radiance model."""
    n = rng.normal(size=(count, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    l0 = np.zeros((count, 3))
    l1 = np.zeros((count, 3, 3))
    amb = rng.uniform(0, 1, (count, 3))                  # uniform hemisphere radiance per channel
    l0 += 2 * np.pi * amb
    l1 += np.pi * amb[:, :, None] * n[:, None, :]
    for _ in range(3):                                   # deltas: power P from direction d above n
        d = rng.normal(size=(count, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        d = np.where((np.sum(d * n, axis=1) < 0)[:, None], -d, d)
        p = rng.uniform(0, 2, (count, 3))
        l0 += p
        l1 += p[:, :, None] * d[:, None, :]
    e = np.einsum("qca,qa->qc", l1, n)
    return e, l0, l1, n


def test_directional_formats_decode_to_the_l1_sh_irradiance():
    rng = np.random.default_rng(5)
    e, l0, l1, n = _random_texels(rng, 500)
    other = rng.normal(size=(500, 3))
    other /= np.linalg.norm(other, axis=1, keepdims=True)
    for normals in (n, other):
        target = dl.sh_l1_irradiance(l0, l1, normals) / np.pi     # what each engine should show
        for packed in (True, False):
            layers = dl.godot_directional_layers(l0, l1, packed=packed)
            assert layers.shape == (4, 500, 3) and layers.dtype == np.float32
            if packed:
                assert layers[1:].min() >= 0.25 - 1e-6 and layers[1:].max() <= 0.75 + 1e-6
            # float32 storage (6e-8 of each term, terms up to l0 / pi) and, unpacked, Godot's
            # 0.32573 for (2/3) 0.488603 = 0.3257353 (1.6e-5 of the L1 term, <= l0 / (2 pi))
            bound = 1e-6 * l0 / np.pi + (0 if packed else 2e-5 * l0 / (2 * np.pi))
            err = np.abs(dl.godot_directional_decode(layers, normals, packed=packed) - target)
            assert np.all(err <= bound), (packed, (err / bound).max())
        tex = dl.bakery_sh_textures(l0, l1)
        assert all(0 <= tex[f"RNM{a}"].min() and tex[f"RNM{a}"].max() <= 1 for a in range(3))
        np.testing.assert_allclose(dl.bakery_sh_decode(tex, normals), target, rtol=1e-5, atol=1e-6 * l0.max())
    # the SH coefficients: c00 = Y00 l0, c1m = 0.488603 l1_(y,z,x)
    c00, c1 = dl.sh_l1_coefficients(l0, l1)
    np.testing.assert_allclose(c00, 0.282095 * l0, rtol=1e-6)
    np.testing.assert_allclose(c1, 0.488603 * l1[..., [1, 2, 0]], rtol=1e-6)


def test_frame_change_rotates_directions_not_values():
    # Z-up right-handed into Y-up (Godot): (x, y, z) -> (x, z, -y). The decoded ambient for a normal
    # expressed in the engine frame must equal the one for the same normal in hirad's frame.
    rng = np.random.default_rng(6)
    e, l0, l1, n = _random_texels(rng, 50)
    r = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    ref = dl.godot_directional_decode(dl.godot_directional_layers(l0, l1), n)
    got = dl.godot_directional_decode(dl.godot_directional_layers(l0, l1, to_engine=r), n @ r.T)
    np.testing.assert_allclose(got, ref, rtol=1e-5)
    with pytest.raises(ValueError, match="orthogonal"):
        dl.godot_directional_layers(l0, l1, to_engine=np.diag([1.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match="l1: expected shape"):
        dl.godot_directional_layers(l0, l1[:, :2])


def test_unity_dominant_direction_round_trip_and_reconstruction():
    rng = np.random.default_rng(8)
    e, l0, l1, n = _random_texels(rng, 400)
    colour, d = dl.unity_dominant_direction(e, l0, l1, n)
    assert colour.shape == (400, 3) and d.shape == (400, 4) and d.min() >= 0 and d.max() <= 1
    # the texel's own normal: exactly the plain lightmap E / pi (the rebalancing factor's purpose)
    np.testing.assert_allclose(dl.unity_decode_directional(colour, d, n), e / np.pi, rtol=1e-5)
    # the direction is the luminance-weighted first moment over l0 (shortened to 1/2)
    y = np.array([0.2126, 0.7152, 0.0722])
    v = np.einsum("c,qca->qa", y, l1) / (l0 @ y)[:, None]
    length = np.linalg.norm(v, axis=1)
    short = length <= 0.5
    assert short.any() and (~short).any()
    np.testing.assert_allclose(d[short, :3] - 0.5, v[short], atol=1e-6)
    np.testing.assert_allclose(d[~short, :3] - 0.5, 0.5 * v[~short] / length[~short, None], atol=1e-6)
    # direction round trip: the decoded direction is the moment's direction (within float32)
    stored = d[:, :3].astype(np.float64) - 0.5
    angle = np.arctan2(np.linalg.norm(np.cross(stored, v), axis=1), np.sum(stored * v, axis=1))
    assert np.all(angle < 0.01 * DEG), angle.max() / DEG
    # where v is not shortened, a tilted normal decodes to E1(n') / E1(n) x E / pi: grey light
    # (all channels alike) so that one direction serves the three channels exactly
    grey_l0, grey_l1 = np.repeat((l0 @ y)[:, None], 3, axis=1), np.repeat(np.einsum("c,qca->qa", y, l1)[:, None, :], 3, axis=1)
    grey_e = np.einsum("qca,qa->qc", grey_l1, n)
    colour, d = dl.unity_dominant_direction(grey_e, grey_l0, grey_l1, n)
    tilted = rng.normal(size=(400, 3))
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    want = dl.sh_l1_irradiance(grey_l0, grey_l1, tilted) / dl.sh_l1_irradiance(grey_l0, grey_l1, n) * grey_e / np.pi
    np.testing.assert_allclose(dl.unity_decode_directional(colour, d, tilted)[short], want[short], rtol=1e-4,
                               atol=1e-6 * grey_e.max())


def test_unity_uniform_hemisphere_is_exact_half_lambert():
    # Uniform radiance L over the hemisphere of n: v = n / 2, a = 1, and the decode on a tilted
    # normal n' is pi L (1 + n.n') / 2 / pi, the exact irradiance of a plane tilted under it.
    L = np.array([[0.3, 0.6, 0.9]])
    n = np.array([[0.0, 0.0, 1.0]])
    l0 = 2 * np.pi * L
    l1 = np.pi * L[:, :, None] * n[:, None, :]
    colour, d = dl.unity_dominant_direction(np.pi * L, l0, l1, n)
    np.testing.assert_allclose(d, [[0.5, 0.5, 1.0, 1.0]], atol=1e-7)
    for tilt in (0, 30, 75, 120):
        t = tilt * DEG
        n2 = np.array([[np.sin(t), 0, np.cos(t)]])
        exact = np.pi * L * (1 + np.cos(t)) / 2          # E of a plane tilted by t under a uniform sky
        np.testing.assert_allclose(dl.unity_decode_directional(colour, d, n2), exact / np.pi, rtol=1e-6)
