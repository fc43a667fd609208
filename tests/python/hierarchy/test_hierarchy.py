"""Hierarchical radiosity (Engine.solve_hierarchical) against physics: the flat solution at the
same leaf resolution, the furnace, energy balance, the cost of initial linking, adaptivity, the
structure of the link hierarchy, determinism, and the method through hirad.bake."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from conftest import box_faces, make_model, quad

from hirad import _engine
from hirad.engine import build_engine, patch_dict

REPO = Path(__file__).resolve().parents[3]
CORNELL = REPO / "configs" / "scenes" / "cornell_box.usda"

# min_area just below 1/16: a unit face splits twice (1 -> 1/4 -> 1/16) and no further, so the
# leaves are the regular 4 x 4 grid that flat meshing with max_area 1/16, max_edge 0.25 gives.
GRID_MIN_AREA = 0.0624


def solve_h(m, epsilon, min_area, samples=16, seed=1, tolerance=1e-9, max_iterations=100000, max_rounds=6):
    r = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=epsilon, min_area=min_area, samples=samples, seed=seed,
                                                      max_rounds=max_rounds),
                             _engine.SolveOptions(method="jacobi", tolerance=tolerance, max_iterations=max_iterations))
    m.use_leaves_as_patches()
    return r


def accumulate_down(parent, per_node):
    """Sum of per_node over each node and all its ancestors (parents precede children)."""
    out = np.array(per_node, dtype=np.float64)
    assert np.all(parent[1:] < np.arange(1, len(parent))), "parents must precede children"
    for i in range(1, len(parent)):
        out[i] += out[parent[i]]
    return out


# ---------------------------------------------------------------------------------------------
# epsilon -> 0: the flat solution at the same resolution
# ---------------------------------------------------------------------------------------------


def coloured_box():
    """Unit box, open nowhere: coloured walls, a ceiling (z = 1) of four 0.5 x 0.5 faces of which
    one emits. Every face is 1 m^2 or 1/4 m^2, so both methods produce 0.25 x 0.25 patches."""
    faces = box_faces(omit=("z1",))  # x0, x1, y0, y1, z0
    refl = [[0.8, 0.1, 0.1], [0.1, 0.8, 0.1], [0.6, 0.6, 0.6], [0.5, 0.5, 0.7], [0.7, 0.7, 0.7]]
    emis = [[0.0] * 3] * 5
    for i in range(2):
        for j in range(2):
            faces.append(quad([i * 0.5, j * 0.5, 1.0], [0, 0.5, 0], [0.5, 0, 0]))  # facing -z
            refl.append([0.75] * 3)
            emis.append([10.0, 8.0, 6.0] if (i, j) == (1, 0) else [0.0] * 3)
    return faces, np.array(refl), np.array(emis)


def test_epsilon_zero_matches_the_flat_solution_at_the_same_leaves():
    faces, refl, emis = coloured_box()
    samples = 256  # per link on both sides; at 64 the two estimates differ by up to 1.8 %
    flat = make_model(faces, refl, emis, max_area=1 / 16, max_edge=0.25)
    flat.compute_links(_engine.FormFactorOptions(method="raycast", samples=samples, seed=1))
    fs = flat.solve(_engine.SolveOptions(method="direct", tolerance=1e-12, max_iterations=1000))
    fp = patch_dict(flat.patch_arrays())

    hm = make_model(faces, refl, emis)
    # epsilon 0: every link with any power splits down to min_area (round 1 splits the links
    # from the emitter; round 2, with B from round 1, all others).
    hs = solve_h(hm, 0.0, GRID_MIN_AREA, samples=samples)
    hp = patch_dict(hm.patch_arrays())
    assert hs.settled and hs.converged
    assert len(hp["area"]) == len(fp["area"]) == 6 * 16
    np.testing.assert_allclose(hp["area"], 1 / 16, rtol=1e-12)

    d = np.linalg.norm(fp["centroid"][:, None, :] - hp["centroid"][None, :, :], axis=2)
    match = d.argmin(axis=1)
    assert d.min(axis=1).max() < 1e-9 and len(set(match.tolist())) == len(match)
    bf, bh = fs.radiosity, hs.radiosity[match]
    assert bf.min() > 0
    rel = np.abs(bh - bf) / bf
    assert rel.max() < 0.01, f"max relative difference {rel.max():.4f} at patch {np.unravel_index(rel.argmax(), rel.shape)}"
    # Every leaf sees every leaf of the other faces: 96 x 80 links, none coarser.
    assert hs.links == 96 * 80


# ---------------------------------------------------------------------------------------------
# furnace and energy balance
# ---------------------------------------------------------------------------------------------

# Leaves of 1/64 m^2 (8 x 8 per face, 384 leaves): coarse links remain at these epsilons
# (~107k links against 384 x 320 = 122,880 leaf pairs), so the hierarchy is exercised.
# Measured max |B (1 - rho) - 1| with 144 samples: rho 0.5 at epsilon 2e-5: 0.25 %; rho 0.9 at
# epsilon 1e-4: 0.52 % (0.37 % and 0.66 % since the lowest clusters hold up to four faces, stop
# 49: links end on wider clusters). rho 0.5 needs the smaller epsilon: at 1e-4 the error is 2.3 % whatever the
# samples (256 samples: 2.3 %), i.e. it is the hierarchical approximation of the brightness-
# weighted oracle (epsilon is relative to the emitted power, and B = 2 vs B = 10 at rho 0.9
# makes links split less), not sampling noise.
FURNACE = {0.5: 2e-5, 0.9: 1e-4}
FURNACE_MIN_AREA = 0.0155
FURNACE_SAMPLES = 144


@pytest.fixture(scope="module", params=sorted(FURNACE))
def furnace(request):
    rho = request.param
    m = make_model(box_faces(), rho, 1.0)
    r = solve_h(m, FURNACE[rho], FURNACE_MIN_AREA, samples=FURNACE_SAMPLES, tolerance=1e-10)
    return rho, r, patch_dict(m.patch_arrays())


def test_furnace_radiosity_is_e_over_one_minus_rho(furnace):
    rho, r, p = furnace
    assert r.converged
    expected = 1.0 / (1.0 - rho)
    b = r.radiosity
    assert b.shape == (len(p["area"]), 3) and len(b) == 6 * 64
    err = np.abs(b / expected - 1)
    assert err.max() < 0.01, f"rho {rho}: max relative error {err.max():.4f}"
    # There are coarse links (the hierarchy is used), not only leaf-to-leaf ones.
    assert r.links < len(b) * (len(b) - 64)


def test_furnace_energy_balance_with_escaped(furnace):
    # Closed box: emitted = absorbed + escaped, and escaped ~ 0. (Fails at rho 0.9 while
    # solve_hierarchical clamps each leaf's escaped fraction at 0: the hierarchical operator
    # gives some leaves an outgoing fraction above 1 and others below, which cancel; clamping
    # keeps only the positive side, 0.23 W "escaping" from this closed box. The unclamped sum
    # balances to 1e-10; see test_links_conserve_power_in_a_closed_box.)
    # What escapes is also measured without the links: rays from every leaf, cosine
    # distributed, against the box's six faces: not one may leave (exactly zero), so the
    # box must absorb what it emits, to the couplings' estimation error (144 samples).
    from proof_helpers import escaped_power

    rho, r, p = furnace
    emitted = p["area"].sum() * 1.0
    absorbed = ((1 - rho) * r.irradiance * p["area"][:, None]).sum(axis=0)
    escaped = r.escaped.sum(axis=0)
    faces = (np.array(box_faces(), dtype=np.float64), np.full(6, 4, dtype=np.int32))
    measured, sigma, frac = escaped_power(p["corners"], p["nv"], p["normal"], r.radiosity, p["area"], 200, 1,
                                          occluders=faces)
    assert np.all(frac == 0) and np.all(measured == 0) and np.all(sigma == 0)
    assert np.all(np.abs(escaped) < 0.01 * emitted), f"closed box, escaped {escaped} of {emitted} W"
    np.testing.assert_allclose(absorbed, emitted, rtol=0.01)
    np.testing.assert_allclose(absorbed + escaped, emitted, rtol=0.01)


def test_links_conserve_power_in_a_closed_box(furnace):
    # Independent of `escaped`: the power the links carry out of the leaves (couplings of the
    # links at each leaf and at its ancestors, over their areas) equals the power gathered,
    # which in a closed box is all of sum B A.
    rho, r, p = furnace
    parent, area = r.node_parent, r.node_area
    own = np.zeros(len(parent))
    np.add.at(own, r.link_source, r.link_coupling / area[r.link_source])
    out = accumulate_down(parent, own)[r.leaf_node]
    b = r.radiosity[:, 0]
    carried = (b * p["area"] * out).sum()
    gathered = (r.irradiance[:, 0] * p["area"]).sum()
    np.testing.assert_allclose(carried, gathered, rtol=1e-6)
    np.testing.assert_allclose(gathered, (b * p["area"]).sum(), rtol=0.01)


# ---------------------------------------------------------------------------------------------
# initial linking cost
# ---------------------------------------------------------------------------------------------


def tiled_room(n, size=4.0, height=2.5):
    """A closed 4 x 4 x 2.5 m room whose floor is n x n tiles, lit by a 1 m^2 emitter 1 cm under
    the ceiling; k = n^2 + 6 input faces."""
    polys = box_faces(size, size, height, omit=("z0",))
    refl, emis = [0.6] * len(polys), [0.0] * len(polys)
    d = size / n
    for i in range(n):
        for j in range(n):
            polys.append(quad([i * d, j * d, 0], [d, 0, 0], [0, d, 0]))
            refl.append(0.5)
            emis.append(0.0)
    polys.append(quad([1.5, 1.5, height - 0.01], [0, 1, 0], [1, 0, 0]))
    refl.append(0.0)
    emis.append(10.0)
    return polys, refl, emis


def test_initial_linking_never_enumerates_all_pairs(capsys):
    rows = []
    for n in (7, 10, 15, 22, 32, 45):
        polys, refl, emis = tiled_room(n)
        k = len(polys)
        r = solve_h(make_model(polys, refl, emis), 1e-3, 1e-4, samples=16, tolerance=1e-6, max_rounds=1)
        assert r.rounds == 1 and len(r.links_per_round) == 1
        rows.append((k, r.links_per_round[0], r.link_estimates))
    with capsys.disabled():
        print("\n     k    links  links/k  estimates  est/(k log2 k)  links/k^2")
        for k, links, est in rows:
            print(f"{k:6d} {links:8d} {links / k:8.2f} {est:10d} {est / (k * math.log2(k)):14.2f} {links / k**2:10.4f}")
    (k0, l0, e0), (k1, l1, e1) = rows[0], rows[-1]
    # Links that carry power: the emitter's links to what it lights (roughly fixed with k, as
    # the emitter sees the floor through clusters) plus O(1) per tile; far fewer than k^2.
    assert l1 < k1 * k1 / 10
    assert l1 / k1 < 4 * l0 / k0
    # Work (link estimates, including links then dropped as back-facing or coplanar): starting
    # from the root's self-link, a cluster pair is split only while the clusters are close
    # compared with their size or carry power; for tiles on a plane, each of the O(log k) levels
    # of the cluster tree has O(k / 2^l) clusters with O(1) close neighbours each, and each
    # emitter/tile interaction stops at a cluster of O(1) size, so the estimates are O(k log k):
    # est / (k log k) stays bounded as k grows 37-fold (a k^2 method would grow it ~20-fold).
    assert e1 < k1 * k1 / 5
    assert (e1 / (k1 * math.log2(k1))) < 2 * (e0 / (k0 * math.log2(k0)))


# ---------------------------------------------------------------------------------------------
# adaptivity
# ---------------------------------------------------------------------------------------------


def lamp_room():
    """A closed 4 x 4 x 2 m room (one face per wall) with a 0.5 x 0.5 m emitter 1 cm below the
    ceiling, centred over (1, 1): the floor near (1, 1) is close to it, (3.5, 3.5) is far."""
    polys = box_faces(4.0, 4.0, 2.0)
    refl, emis = [0.5] * 6, [0.0] * 6
    polys.append(quad([0.75, 0.75, 1.99], [0, 0.5, 0], [0.5, 0, 0]))
    refl.append(0.0)
    emis.append(100.0)
    return polys, refl, emis


def floor_leaf_area(p, points_xy):
    """Mean area of the floor (z = 0) leaves that contain the given (x, y) points."""
    c = p["corners"]
    lo, hi = c.min(axis=1), c.max(axis=1)
    on_floor = np.abs(c[:, :, 2]).max(axis=1) < 1e-9
    areas = []
    for x, y in points_xy:
        hit = on_floor & (lo[:, 0] <= x) & (x < hi[:, 0]) & (lo[:, 1] <= y) & (y < hi[:, 1])
        assert hit.sum() == 1, (x, y, hit.sum())
        areas.append(p["area"][hit][0])
    return float(np.mean(areas))


NEAR = [(1 + dx, 1 + dy) for dx in (-0.3, 0.03, 0.3) for dy in (-0.3, 0.03, 0.3)]  # under the lamp
FAR = [(3.5 + dx, 3.5 + dy) for dx in (-0.3, 0.03, 0.3) for dy in (-0.3, 0.03, 0.3)]  # far corner


def test_refinement_adapts_to_epsilon_and_to_the_light():
    polys, refl, emis = lamp_room()
    results = {}
    for eps in (1e-2, 1e-3, 1e-4):
        m = make_model(polys, refl, emis)
        r = solve_h(m, eps, 1e-3, samples=16, tolerance=1e-6)
        results[eps] = (r, patch_dict(m.patch_arrays()))
    # Larger epsilon: fewer leaves and fewer links.
    for a, b in ((1e-2, 1e-3), (1e-3, 1e-4)):
        assert results[a][0].elements < results[b][0].elements
        assert results[a][0].links < results[b][0].links
    # Under the lamp the floor is refined more finely than in the far corner: the irradiance
    # under it is ~10x that in the corner (distance 1.99 m vs ~3.6 m, cosines 1 vs ~0.5), so
    # links there carry more power and split further (each split quarters the area).
    # At 1e-3 at least one level (a factor 4 in area); at 1e-4 the near floor stops at 1/64 m^2
    # (its links to the lamp split the larger end, the lamp, instead) while the corner catches
    # up, so only the order is asserted there (measured 0.0156 vs 0.042 m^2).
    for eps, factor in ((1e-3, 4), (1e-4, 1)):
        p = results[eps][1]
        near, far = floor_leaf_area(p, NEAR), floor_leaf_area(p, FAR)
        assert near * factor <= far and near < far, (eps, near, far)


# ---------------------------------------------------------------------------------------------
# the link hierarchy
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiled():
    # 42 input faces: enough for a cluster tree in which light leaves clusters.
    polys, refl, emis = tiled_room(6)
    return solve_h(make_model(polys, refl, emis), 3e-4, 1e-3, samples=16, tolerance=1e-7)


def test_rounds_refine_until_settled(tiled):
    r = tiled
    assert r.settled, "this scene settles within 6 rounds (in 3)"
    assert r.splits_per_round[-1] == 0
    assert all(s > 0 for s in r.splits_per_round[:-1])
    lpr = r.links_per_round
    assert len(lpr) == r.rounds >= 2
    assert all(b > a for a, b in zip(lpr, lpr[1:])), lpr
    assert r.links == lpr[-1] == len(r.link_receiver)


def test_links_join_elements_to_disjoint_nodes_once(tiled):
    r = tiled
    rec, src, parent, cluster = r.link_receiver, r.link_source, r.node_parent, r.node_cluster
    assert len(rec) == len(src) == len(r.link_coupling) > 0
    assert np.all(cluster[rec] == 0), "a link receiver is a cluster"
    assert cluster.any(), "no clusters at all"
    assert cluster[src].any(), "no link from a cluster: clustering is not used"
    # Every link can carry light: its coupling is positive, or its rays all met an occluder
    # but light can pass unoccluded (kept, so that later rounds and the gather can see it).
    g, u = r.link_coupling, r.link_unoccluded
    assert np.all(g >= 0) and np.all(u >= 0)
    assert np.all((g > 0) | (u > 0))
    pairs = rec.astype(np.int64) * len(parent) + src
    assert len(np.unique(pairs)) == len(pairs), "duplicate (receiver, source) links"
    # Depth of every node, then walk the deeper end up to the other's depth: equal -> ancestor.
    depth = np.zeros(len(parent), dtype=np.int64)
    for i in range(1, len(parent)):
        depth[i] = depth[parent[i]] + 1
    a, b = rec.astype(np.int64), src.astype(np.int64)
    swap = depth[a] < depth[b]
    a, b = np.where(swap, b, a), np.where(swap, a, b)
    while True:
        deeper = depth[a] > depth[b]
        if not deeper.any():
            break
        a = np.where(deeper, parent[a], a)
    assert not np.any(a == b), "a link joins a node to its ancestor, descendant or itself"


def test_leaves_tile_the_input_faces(tiled):
    r = tiled
    area = r.node_area
    leaves = r.leaf_node
    assert len(leaves) == r.elements
    # Total leaf area is the scene's area: floor and ceiling 16 m^2 each, four 4 x 2.5 m walls,
    # and the 1 m^2 lamp; and each leaf lies under exactly one input face (the element roots).
    np.testing.assert_allclose(area[leaves].sum(), 2 * 16 + 4 * 10 + 1, rtol=1e-12)
    assert len(np.unique(leaves)) == len(leaves)


# ---------------------------------------------------------------------------------------------
# determinism
# ---------------------------------------------------------------------------------------------


def test_deterministic_across_runs_and_threads():
    polys, refl, emis = lamp_room()

    def run():
        r = solve_h(make_model(polys, refl, emis), 1e-3, 1e-3, samples=16, tolerance=1e-7)
        return r.radiosity, r.link_receiver, r.link_source, r.link_coupling

    try:
        _engine.set_threads(2)
        a, b = run(), run()
        _engine.set_threads(1)
        c = run()
    finally:
        _engine.set_threads(0)
    for x, y, z in zip(a, b, c):
        assert np.array_equal(x, y)
        assert np.array_equal(x, z)


# ---------------------------------------------------------------------------------------------
# through the API
# ---------------------------------------------------------------------------------------------

QUIET_OUTPUTS = {"usd": False, "lightmaps": {"enabled": False}, "preview": {"enabled": False}, "report": True}


def test_bake_hierarchical_cornell(tmp_path):
    import hirad
    from hirad.config import config_from_dict

    cfg = config_from_dict({
        "scene": str(CORNELL), "output": str(tmp_path / "out"), "method": "hierarchical",
        "hierarchy": {"epsilon": 1e-3, "min_area": 0.002, "samples": 16, "max_rounds": 4},
        "solver": {"method": "jacobi", "tolerance": 1e-5}, "outputs": QUIET_OUTPUTS})
    res = hirad.bake(cfg)
    rep = res.report
    h = rep["hierarchy"]
    assert h is not None
    assert 1 <= h["rounds"] <= 4 and len(h["links_per_round"]) == h["rounds"]
    assert h["elements"] == rep["counts"]["patches"] == len(res.patch_radiosity)
    assert h["links_per_round"][-1] == rep["counts"]["links"]
    # The memory of the faces and of Embree's scene over them: at least the table's 112 bytes a
    # face and Embree's index buffer (16 a face), and Embree's peak at least what it keeps.
    faces = rep["counts"]["input_faces"]
    assert h["face_bytes"] >= 112 * faces and h["bvh_bytes"] >= 16 * faces
    assert h["bvh_peak_bytes"] >= h["bvh_bytes"]
    eb = rep["energy_balance"]
    assert eb["max_relative_error"] < 0.02
    em, ab, es = (np.array(eb[k]) for k in ("emitted_W", "absorbed_W", "escaped_W"))
    assert np.all(np.abs(ab + es - em) < 0.02 * em)
    assert (tmp_path / "out" / "report.json").is_file()


@pytest.mark.parametrize("method", ["progressive", "direct"])
def test_config_rejects_a_flat_only_solver_for_hierarchical(method):
    # The brief asked for southwell here, but southwell (and gauss_seidel) with push-pull are now
    # accepted for method: hierarchical; the flat-only solvers are still refused.
    from hirad.config import ConfigError, config_from_dict

    with pytest.raises(ConfigError) as e:
        config_from_dict({"scene": str(CORNELL), "method": "hierarchical", "solver": {"method": method}})
    text = str(e.value)
    assert "solver" in text and "method" in text and repr(method) in text


def test_mean_radiosity_does_not_depend_on_samples_per_link():
    # Each link's transport estimate is unbiased whatever its number of sample pairs, and a
    # link whose few samples happened to see nothing is split unless all it could carry is
    # below epsilon; so the area-weighted mean radiosity of the Cornell box is nearly the same
    # with 4 pairs as with 64 (0.3 % measured). Dropping every such link made the 4-sample
    # solution several per cent darker (11 % with 2 pairs).
    from hirad import usd

    s = usd.read_scene(CORNELL)
    means = {}
    for samples in (4, 64):
        m = build_engine(s)
        r = solve_h(m, 1e-5, 2e-4, samples=samples, tolerance=1e-6)
        a = patch_dict(m.patch_arrays())["area"]
        means[samples] = float((a[:, None] * r.radiosity).sum(axis=0).mean() / a.sum())
    assert abs(means[4] / means[64] - 1) < 0.005, means
