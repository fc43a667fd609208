"""The display mesh of a hierarchical solution has no cracks: after 2:1 balancing and fanning
patches around T-vertices, every edge of every output mesh is a boundary edge or is shared
by exactly two faces, no vertex sits inside another face's edge, and values are continuous
there (a T-vertex carries the value the coarse edge interpolates)."""

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import hirad
from hirad import usd
from hirad.config import config_from_dict

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def solution(tmp_path_factory):
    out = tmp_path_factory.mktemp("display") / "out"
    cfg = config_from_dict({
        "scene": str(ROOT / "configs/scenes/cornell_box.usda"), "output": str(out),
        "method": "hierarchical",
        # A coarse threshold on purpose: leaves of very different sizes side by side.
        "hierarchy": {"epsilon": 1e-4, "min_area": 2e-4, "samples": 16, "max_rounds": 4},
        "solver": {"method": "jacobi", "tolerance": 1e-4},
        "outputs": {"lightmaps": {"enabled": False}, "preview": {"enabled": False}},
    }, ROOT)
    result = hirad.bake(cfg)
    return result, usd.read_solution_layer(out / "solution.usda")


def _edges(mesh):
    counts = np.asarray(mesh.face_vertex_counts)
    idx = np.asarray(mesh.face_vertex_indices)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    edges = Counter()
    for f in range(len(counts)):
        ids = idx[offsets[f]:offsets[f + 1]]
        for k in range(len(ids)):
            a, b = int(ids[k]), int(ids[(k + 1) % len(ids)])
            edges[(min(a, b), max(a, b))] += 1
    return edges


def test_leaves_differ_in_size(solution):
    result, _ = solution
    area = result.patches["area"]
    assert area.max() / area.min() >= 16  # at least two levels apart somewhere


def test_every_edge_is_a_boundary_or_shared_by_two_faces(solution):
    _, sol = solution
    for mesh in sol.meshes:
        uses = Counter(_edges(mesh).values())
        assert set(uses) <= {1, 2}, (mesh.name, uses)


def test_no_vertex_lies_inside_a_boundary_edge(solution):
    # A T-junction shows as a vertex in the middle of an edge used by one face only.
    _, sol = solution
    for mesh in sol.meshes:
        pts = mesh.points
        scale = np.ptp(pts, axis=0).max()
        for (a, b), n in _edges(mesh).items():
            if n != 1:
                continue
            ab = pts[b] - pts[a]
            t = (pts - pts[a]) @ ab / (ab @ ab)
            off = np.linalg.norm(pts - pts[a] - np.outer(t, ab), axis=1)
            inside = (t > 1e-6) & (t < 1 - 1e-6) & (off < 1e-7 * scale)
            assert not inside.any(), (mesh.name, a, b, np.nonzero(inside)[0])


def test_values_are_continuous_at_t_vertices():
    # A room lit by a small emitter, refined unevenly; for every patch that was fanned, the
    # display vertex at the midpoint of its edge k carries the mean of the values at the
    # edge's ends, so the coarse side and the fine side agree along the whole edge.
    from conftest import box_faces, make_model, quad

    # A 2 x 2 x 1 m room and a 0.2 m square light facing down near the ceiling.
    faces = box_faces(2.0, 2.0, 1.0) + [quad([0.2, 0.2, 0.95], [0, 0.2, 0], [0.2, 0, 0])]
    refl = [[0.6, 0.6, 0.6]] * 6 + [[0.0, 0.0, 0.0]]
    em = [[0, 0, 0]] * 6 + [[20, 20, 20]]
    m = make_model(faces, reflectance=refl, emission=em)
    from hirad import _engine

    solved = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=3e-4, min_area=0.004, samples=16, seed=1,
                                                           max_rounds=4),
                                  _engine.SolveOptions(method="jacobi", tolerance=1e-6, max_iterations=1000))
    m.use_leaves_as_patches()
    pa = m.patch_arrays()
    assert np.all(pa.normal[pa.emission[:, 0] > 0][:, 2] == -1.0)  # the light faces down
    display = m.display_mesh(30.0)
    values = m.vertex_values(solved.radiosity)
    faces, codes, owner = display.faces, display.face_code, display.face_patch
    corners, nv = display.corners, pa.nv
    checked = 0
    for f in range(len(faces)):
        for c in range(display.face_nv[f]):
            code = int(codes[f][c])
            if 4 <= code < 8:
                p, k = owner[f], code - 4
                a, b = corners[p][k], corners[p][(k + 1) % nv[p]]
                np.testing.assert_allclose(values[faces[f][c]], (values[a] + values[b]) / 2, rtol=1e-12, atol=1e-15)
                checked += 1
    assert checked > 0
    # ... and every T-vertex is a vertex of the fine faces on the other side of the edge: the
    # fan's own faces and at least one more use that very vertex (no duplicate point), unless
    # the finer neighbour lies across a crease (an edge of the room, sharper than the display
    # mesh's crease angle of 30 degrees), where vertices are split on purpose: then a vertex of
    # the other side sits at exactly the same position, on a face turned by more than 30 degrees.
    users = {}
    for f in range(len(faces)):
        for c in range(display.face_nv[f]):
            users.setdefault(int(faces[f][c]), []).append(f)
    normal = pa.normal[owner]
    points = display.points
    mids = {int(faces[f][c]): f for f in range(len(faces)) for c in range(display.face_nv[f])
            if 4 <= int(codes[f][c]) < 8}
    across_creases = 0
    for v, fan_face in mids.items():
        if len(users[v]) >= 3:
            continue
        twins = [w for w in np.nonzero(np.linalg.norm(points - points[v], axis=1) == 0)[0] if w != v]
        turned = [f for w in twins for f in users.get(int(w), [])
                  if float(normal[f] @ normal[fan_face]) < np.cos(np.radians(30.0))]
        assert turned, f"T-vertex {v} at {points[v].tolist()} is used by {len(users[v])} faces only, " \
                       "and no face across a crease meets it: a crack"
        across_creases += 1
    assert across_creases < len(mids)  # some T-vertices are inside a face, where the test is strict
