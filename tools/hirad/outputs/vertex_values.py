"""The display mesh's vertex values from the final gather (reconstruction.values: final_gather),
and the display mesh refined where the gathered light varies.

The seed's vertex rules average the patches (elements) around a vertex: each element holds one
value, the mean of its light, so a vertex between a lit and a shadowed element gets their mean,
and the value along a wall's foot is that of the coarse elements there (on an independent
path-traced Cornell box, 1.3-3.7 % off on average and up to 30-88 % at single points beside
the blocks, issue 12). Here every display face corner is gathered instead: a point just inside
the face (`INSET` of the way to its centroid, so that no point sits on a polygon edge where the
point-to-polygon form factor of the neighbouring surface is singular), lifted out of geometry
like the lightmaps' texel samples, and gathered from the solution (hierarchical: the links of
its element's chain, flat: every patch). A vertex's value is the mean over the corners that
share it (the faces of one smoothing group, reconstruction.crease_angle). What a renderer then
interpolates between vertices is the gathered field, sampled at the display mesh's vertices.

Two things then keep that interpolation honest:

- **Corners inside geometry.** A floor that runs on under a block has display vertices under
  the block. Gathered there, they see the block's inside (backs of faces, no light) and read
  near zero, and a renderer's interpolation drags the visible part of every face that straddles
  the block's foot towards that zero (-37 % at a point 0.2 mm from the tall block's foot).
  A sample is *enclosed* when the ray along its normal and most of four rays tilted 45 degrees
  from it meet the back of a surface; enclosed samples are left out, and a vertex with none
  but enclosed samples takes the mean of its neighbours along the mesh's edges (repeated
  outwards from the visible ones): the visible field, extended flat under the block.
- **Refinement** (reconstruction.refine_levels, refine_tolerance). A face's corners cannot show
  a shadow edge or a contact shadow that crosses it. Each face is gathered at its edge
  midpoints and its centre too; where one of them differs from what the renderer would
  interpolate there (the mean of the edge's two vertices, or of the face's corners) by more
  than the tolerance, relative to the larger of the two (and to at least `FLOOR` of the scene's
  median vertex luminance, so that noise in the dark does not split), the face is split in
  four at exactly those points, whose gathered values become its new vertices' values. The
  children are tested the same way, `refine_levels` times. A face left whole beside split
  ones has vertices on its edges (T-vertices); it is drawn as a fan of triangles around its
  gathered centre, so the written mesh has no T-junctions and shows every gathered value.

The vertex values are then fitted, by least squares, to all the samples gathered on the way
(`_fit`): those of faces that stayed whole lie inside faces, where the renderer interpolates.

Where the faces on both sides of an edge lie in one plane, their samples at its midpoint differ
only by the inset, a hundredth of the way to each face's centre, so one of them is gathered
and stands for both (`_one_per_plane`): on the Cornell box at epsilon 1e-4 the vertex gather
took 0.75-0.81 s instead of 1.12 s, and the written values' mean error against the path
tracer moved from 1.58 to 1.59 % (bench/README.md). Corners are still gathered one per face:
gathering one corner per vertex where its faces are coplanar cut the gather further (0.59 s)
but took the finer setting (1e-5, min_area 5e-4) from 1.00 to 1.08 %, which we read as the
gather's noise: a vertex's four corners average four independent sets of 16 rays to each
emitter.
"""

from __future__ import annotations

import numpy as np

INSET = 0.01   # of the way from a corner (or an edge's midpoint) to its face's centroid
FLOOR = 0.01   # of the median vertex luminance: below it, differences do not split a face
LUM = np.array([0.2126, 0.7152, 0.0722])
_TILT = np.sqrt(0.5)  # the enclosure test's four tilted rays: 45 degrees from the normal


def _enclosed(tracer, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Samples inside geometry: the normal's ray and at least two of four rays tilted 45 degrees
    from it (along the tangent frame's four half-axes) meet the back of a surface. `tracer`:
    the surfaces and their BVH (lightmaps._tracer: the engine's own while it holds the
    hierarchy, so that the gather builds no SurfaceField of the display mesh)."""
    n = len(points)
    if n == 0:
        return np.zeros(0, bool)
    nrm = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(nrm, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nrm, t1)
    dirs = np.stack([nrm, _TILT * (nrm + t1), _TILT * (nrm - t1), _TILT * (nrm + t2), _TILT * (nrm - t2)], axis=1)
    origins = np.repeat(points, 5, axis=0)
    hits = tracer.ray_cast(np.ascontiguousarray(origins), np.ascontiguousarray(dirs.reshape(-1, 3)))
    back = (np.asarray(hits.back, dtype=bool) & (np.asarray(hits.patch) >= 0)).reshape(n, 5)
    return back[:, 0] & (back.sum(axis=1) >= 3)


class _Sampler:
    """Gathers the solution at sample points on display faces: lifted out of geometry (as the
    lightmaps' texel samples; `groups` share the lift's anchor), enclosed ones flagged."""

    def __init__(self, result, normal_of_patch: np.ndarray, *, rays: int, importance: float,
                 sample_offset: float, reach: float, second_bounce: float = 1.0):
        self.result, self.normal_of_patch = result, normal_of_patch
        self.rays, self.importance, self.offset, self.reach = rays, importance, sample_offset, reach
        self.second_bounce = second_bounce
        self.samples = self.unfound = self.enclosed = 0

    def __call__(self, points: np.ndarray, patch: np.ndarray, groups: np.ndarray):
        from .lightmaps import _lift, _tracer

        if len(points) == 0:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool)
        normals = np.ascontiguousarray(self.normal_of_patch[patch])
        lifted, _ = _lift(_tracer(self.result), np.ascontiguousarray(points), normals, groups, self.offset, self.reach)
        g = self.result.gather(lifted, normals, rays=self.rays, importance=self.importance,
                               second_bounce=self.second_bounce)
        found = np.asarray(g["patch"]) >= 0
        inside = _enclosed(_tracer(self.result), lifted, normals)
        ok = found & ~inside
        self.samples += len(points)
        self.unfound += int((~found).sum())
        self.enclosed += int((found & inside).sum())
        return (np.asarray(g["radiance"], dtype=np.float64), np.asarray(g["irradiance"], dtype=np.float64), ok)


def _one_per_plane(group: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Which samples to gather: in a group (an edge's two sides) whose normals all equal its
    first's, only that first; in any other group, all of them."""
    if len(group) == 0:
        return np.zeros(0, bool)
    _, first, inv = np.unique(group, return_index=True, return_inverse=True)
    same = np.einsum("ij,ij->i", normals, normals[first][inv]) > 1 - 1e-9
    planar = np.bincount(inv, ~same, minlength=len(first)) == 0
    keep = ~planar[inv]
    keep[first[planar]] = True
    return keep


def _mean_by(index: np.ndarray, values: np.ndarray, ok: np.ndarray, n: int):
    """Per target 0..n-1: the mean of the ok values that map to it (NaN where none)."""
    w = ok.astype(np.float64)
    count = np.bincount(index, w, minlength=n)
    out = np.full((n, values.shape[1]), np.nan)
    some = count > 0
    for c in range(values.shape[1]):
        out[some, c] = np.bincount(index, values[:, c] * w, minlength=n)[some] / count[some]
    return out


def _fill_from_neighbours(values: list[np.ndarray], valid: np.ndarray, edges: np.ndarray, sweeps: int = 256):
    """Vertices without a value take the mean of their neighbours that have one, sweep after
    sweep outwards from the valid ones (in place). Returns the vertices still without one."""
    valid = valid.copy()
    a, b = edges[:, 0], edges[:, 1]
    n = len(valid)
    for _ in range(sweeps):
        if valid.all():
            break
        src = np.concatenate([a, b])
        dst = np.concatenate([b, a])
        use = valid[src] & ~valid[dst]
        if not use.any():
            break
        count = np.bincount(dst[use], minlength=n)
        newly = count > 0
        for v in values:
            for c in range(v.shape[1]):
                s = np.bincount(dst[use], v[src[use], c], minlength=n)
                v[newly, c] = s[newly] / count[newly]
        valid |= newly
    return ~valid


KEY = 1 << 31  # an edge's key: min(a, b) * KEY + max(a, b), vertex ids below 2^31


def _edge_keys(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.minimum(a, b) * KEY + np.maximum(a, b)


def _edges(cells: np.ndarray, nv: np.ndarray):
    """Per cell slot k < nv: its edge (cell[k], cell[k+1 mod nv]); returns (has (n,4), next (n,4))."""
    k4 = np.arange(4)[None, :]
    has = k4 < nv[:, None]
    nxt = np.where(k4 + 1 < nv[:, None], np.roll(cells, -1, axis=1), cells[:, :1])
    return has, nxt


def _centroids(P: np.ndarray, cells: np.ndarray, has: np.ndarray, nv: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ijk->ik", has.astype(np.float64), P[cells]) / nv[:, None]


def _off(gathered: np.ndarray, interpolated: np.ndarray, known: np.ndarray, tol: float, floor: float) -> np.ndarray:
    """Where the gathered luminance differs from the interpolated by more than tol of the larger."""
    out = np.zeros(len(known), bool)
    g, i = gathered[known], interpolated[known]
    out[known] = np.abs(g - i) > tol * np.maximum(np.maximum(g, i), floor)
    return out


class _Mesh:
    """The display mesh while it is refined: points and their values, cells (triangles and quads,
    a triangle's 4th slot repeats its 3rd) with their patch, and the edges split so far."""

    def __init__(self, display: dict):
        self.nv = np.asarray(display["face_nv"], dtype=np.int64)
        self.cells = np.asarray(display["faces"], dtype=np.int64).reshape(len(self.nv), 4)
        self.patch = np.asarray(display["face_patch"], dtype=np.int64)
        self.P = np.asarray(display["points"], dtype=np.float64)
        self.R = self.H = None
        self.valid = None
        self.leaf = np.ones(len(self.nv), bool)
        self.centre = np.full((len(self.nv), 7), np.nan)   # gathered at the centroid: R, H, ok
        self.mid_key = np.zeros(0, np.int64)                # split edges, sorted, and their midpoints
        self.mid_vertex = np.zeros(0, np.int64)
        # Gathered samples that no vertex holds, for the least-squares fit (_fit): edges tested
        # and left whole (keys, R, H), and split triangles' centres, which are their middle
        # child's centroid (that child's cell, R, H).
        self.edge_samples: list = []
        self.middle_samples: list = []

    def add_points(self, p, r, h, ok) -> np.ndarray:
        first = len(self.P)
        self.P = np.concatenate([self.P, p])
        self.R = np.concatenate([self.R, np.where(ok[:, None], r, np.nan)])
        self.H = np.concatenate([self.H, np.where(ok[:, None], h, np.nan)])
        self.valid = np.concatenate([self.valid, ok])
        return first + np.arange(len(p))

    def add_cells(self, cells, nv, patch) -> np.ndarray:
        first = len(self.nv)
        self.cells = np.concatenate([self.cells, cells])
        self.nv = np.concatenate([self.nv, nv])
        self.patch = np.concatenate([self.patch, patch])
        self.leaf = np.concatenate([self.leaf, np.ones(len(nv), bool)])
        self.centre = np.concatenate([self.centre, np.full((len(nv), 7), np.nan)])
        return first + np.arange(len(nv))

    def midpoint(self, a, b) -> np.ndarray:
        return self.mid_vertex[np.searchsorted(self.mid_key, _edge_keys(a, b))]


def _refine_level(mesh: _Mesh, candidates: np.ndarray, sampler, tol: float, floor: float) -> np.ndarray:
    """Tests the candidate cells at their edge midpoints and centroids; splits those that need it
    in four (the tested points becoming the new vertices). Returns the children."""
    C, n_c, p_c = mesh.cells[candidates], mesh.nv[candidates], mesh.patch[candidates]
    has, nxt = _edges(C, n_c)
    ea, eb = C[has], nxt[has]
    e_cell = np.nonzero(has)[0]
    cen = _centroids(mesh.P, C, has, n_c)
    keys = _edge_keys(ea, eb)
    ukeys, inv = np.unique(keys, return_inverse=True)
    side = _one_per_plane(keys, sampler.normal_of_patch[p_c[e_cell]])   # both sides of an edge, or one
    s_ea, s_eb, s_cell = ea[side], eb[side], e_cell[side]
    mid = 0.5 * (mesh.P[s_ea] + mesh.P[s_eb])
    pts = np.concatenate([mid + INSET * (cen[s_cell] - mid), cen])
    s_rad, s_irr, s_ok = sampler(pts, np.concatenate([p_c[s_cell], p_c]),
                                 np.concatenate([s_cell, np.arange(len(C))]))
    ne = len(s_ea)
    e_rad = _mean_by(inv[side], s_rad[:ne], s_ok[:ne], len(ukeys))
    e_irr = _mean_by(inv[side], s_irr[:ne], s_ok[:ne], len(ukeys))
    c_rad, c_irr, c_ok = s_rad[ne:], s_irr[ne:], s_ok[ne:]
    mesh.centre[candidates] = np.concatenate([c_rad, c_irr, c_ok[:, None]], axis=1)
    # against what a renderer interpolates there
    R, V = mesh.R, mesh.valid
    g_edge = e_rad[inv] @ LUM
    e_off = _off(g_edge, 0.5 * (R[ea] + R[eb]) @ LUM, V[ea] & V[eb] & np.isfinite(g_edge), tol, floor)
    corners_valid = np.where(has, V[C], True).all(axis=1)
    i_cen = np.einsum("ij,ijk->ik", has.astype(np.float64), np.nan_to_num(R[C])) / n_c[:, None]
    c_off = _off(c_rad @ LUM, i_cen @ LUM, corners_valid & c_ok, tol, floor)
    split = c_off | (np.bincount(e_cell, e_off, minlength=len(C)) > 0)
    whole = ~np.isin(ukeys, keys[split[e_cell]]) & ~np.isin(ukeys, mesh.mid_key) & np.isfinite(e_rad).all(axis=1)
    mesh.edge_samples.append((ukeys[whole], e_rad[whole], e_irr[whole]))
    if not split.any():
        return np.zeros(0, np.int64)
    # new vertices: the split cells' edge midpoints (shared with neighbours) and quads' centres
    new_keys = np.unique(keys[split[e_cell]])
    new_keys = new_keys[~np.isin(new_keys, mesh.mid_key)]
    pos = np.searchsorted(ukeys, new_keys)
    ok = np.isfinite(e_rad[pos]).all(axis=1)
    ids = mesh.add_points(0.5 * (mesh.P[new_keys // KEY] + mesh.P[new_keys % KEY]), e_rad[pos], e_irr[pos], ok)
    order = np.argsort(np.concatenate([mesh.mid_key, new_keys]), kind="stable")
    mesh.mid_key = np.concatenate([mesh.mid_key, new_keys])[order]
    mesh.mid_vertex = np.concatenate([mesh.mid_vertex, ids])[order]
    sc = np.nonzero(split)[0]
    quad = n_c[sc] == 4
    centre_id = np.full(len(sc), -1, np.int64)
    sq = sc[quad]
    centre_id[quad] = mesh.add_points(cen[sq], c_rad[sq], c_irr[sq], c_ok[sq])
    # children, in the parent's winding
    Cs = C[sc]
    a, b, c = Cs[:, 0], Cs[:, 1], Cs[:, 2]
    d = np.where(quad, Cs[:, 3], a)
    m_ab, m_bc, m_cd = mesh.midpoint(a, b), mesh.midpoint(b, c), mesh.midpoint(c, d)
    m_da = m_cd.copy()
    m_da[quad] = mesh.midpoint(d[quad], a[quad])
    o = centre_id
    tri = np.stack([np.stack([a, m_ab, m_cd, m_cd], 1), np.stack([m_ab, b, m_bc, m_bc], 1),
                    np.stack([m_cd, m_bc, c, c], 1), np.stack([m_ab, m_bc, m_cd, m_cd], 1)], 1)
    qd = np.stack([np.stack([a, m_ab, o, m_da], 1), np.stack([m_ab, b, m_bc, o], 1),
                   np.stack([o, m_bc, c, m_cd], 1), np.stack([m_da, o, m_cd, d], 1)], 1)
    kids = np.where(quad[:, None, None], qd, tri).reshape(-1, 4)
    mesh.leaf[candidates[sc]] = False
    children = mesh.add_cells(kids, np.repeat(n_c[sc], 4), np.repeat(p_c[sc], 4))
    mid_tri = ~quad & c_ok[sc]
    mesh.middle_samples.append((children.reshape(-1, 4)[mid_tri, 3], c_rad[sc][mid_tri], c_irr[sc][mid_tri]))
    return children


def _conforming(mesh: _Mesh, sampler) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The leaf cells as faces: whole, or as a fan of triangles around their gathered centroid
    where split neighbours left vertices on their edges. Returns faces, nv, patch, fans."""
    leaf = np.nonzero(mesh.leaf)[0]
    C, n_c, p_c = mesh.cells[leaf], mesh.nv[leaf], mesh.patch[leaf]
    has, nxt = _edges(C, n_c)
    fan = (np.isin(_edge_keys(C, nxt), mesh.mid_key) & has).any(axis=1)
    faces, nv, patch = [np.where(has, C, C[:, 2:3])[~fan]], [n_c[~fan]], [p_c[~fan]]
    fi = np.nonzero(fan)[0]
    if fi.size:
        cells = leaf[fi]
        cen = _centroids(mesh.P, C[fi], has[fi], n_c[fi])
        todo = np.nonzero(np.isnan(mesh.centre[cells, 6]))[0]   # made at the last level: not tested
        if todo.size:
            r, h, ok = sampler(cen[todo], p_c[fi][todo], np.arange(todo.size))
            mesh.centre[cells[todo]] = np.concatenate([r, h, ok[:, None]], axis=1)
        ctr = mesh.centre[cells]
        ids = mesh.add_points(cen, ctr[:, :3], ctr[:, 3:6], ctr[:, 6] > 0)
        lookup = dict(zip(mesh.mid_key.tolist(), mesh.mid_vertex.tolist()))

        def ring_of(a: int, b: int, out: list) -> None:
            m = lookup.get(min(a, b) * KEY + max(a, b))
            if m is None:
                out.append(a)
            else:
                ring_of(a, m, out)
                ring_of(m, b, out)

        tris, tri_patch = [], []
        for j, cid in zip(fi, ids):
            ring: list[int] = []
            k = int(n_c[j])
            for s in range(k):
                ring_of(int(C[j, s]), int(C[j, (s + 1) % k]), ring)
            for s in range(len(ring)):
                tris.append((cid, ring[s], ring[(s + 1) % len(ring)], ring[(s + 1) % len(ring)]))
            tri_patch += [p_c[j]] * len(ring)
        faces.append(np.array(tris, np.int64))
        nv.append(np.full(len(tris), 3, np.int64))
        patch.append(np.array(tri_patch, np.int64))
    return np.concatenate(faces), np.concatenate(nv), np.concatenate(patch), int(fi.size)


def _fit(mesh: _Mesh) -> None:
    """Least-squares vertex values (Kavan, Bargteil and Sloan 2011, "Least squares vertex
    baking"), in place on mesh.R and mesh.H. A renderer interpolates the vertex values
    linearly (bilinearly on quads); where the light is curved across a face, values exact at
    the vertices leave the face's inside off by the curvature, one way (under a field brightest
    mid-way, too dark). Refinement gathered every tested face at its edge midpoints and centre;
    where the face stayed whole those samples are not vertices, and here they join the
    vertices' own: the values x minimise sum over samples (interpolation of x at the sample -
    gathered)^2, each vertex's gather one sample, and one each for every whole edge's midpoint,
    every whole leaf's centre and every split triangle's centre (the centroid of its middle
    child, while that child is a whole leaf). Vertices without a valid value (inside geometry)
    are left out, as are the samples that would interpolate them; they are filled from their
    neighbours afterwards. On the Cornell box (388 points against the path tracer,
    bench/README.md) the written values' mean |error| went from 1.59 to 1.51 % at epsilon 1e-4
    and from 1.01 to 0.89 % at 1e-5 (min_area 5e-4), the signed mean from -0.95 to -0.85 % and
    from -0.60 to -0.49 %; the rest of that dark shift is not the interpolation's (the gather
    at the same points reads -0.43 % at 1e-4). Normal equations by conjugate gradients
    (Jacobi-preconditioned, from the gathered values; deterministic): 14 iterations, 0.02 s.
    A channel whose iteration does not converge keeps its gathered values."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import LinearOperator, cg

    valid = mesh.valid
    if not mesh.edge_samples or not valid.any():
        return
    rows, cols, vals, rhs = [], [], [], []
    count = 0

    def add(verts: np.ndarray, r: np.ndarray, h: np.ndarray) -> None:
        nonlocal count
        ok = valid[verts].all(axis=1)
        verts, r, h = verts[ok], r[ok], h[ok]
        k, m = verts.shape
        rows.append(np.repeat(count + np.arange(k), m))
        cols.append(verts.reshape(-1))
        vals.append(np.full(verts.size, 1.0 / m))   # the sample's interpolation: the mean of its corners
        rhs.append(np.concatenate([r, h], axis=1))
        count += k

    vv = np.nonzero(valid)[0]
    add(vv[:, None], mesh.R[vv], mesh.H[vv])
    for keys, r, h in mesh.edge_samples:
        add(np.stack([keys // KEY, keys % KEY], 1), r, h)
    has, nxt = _edges(mesh.cells, mesh.nv)
    whole = mesh.leaf & ~(np.isin(_edge_keys(mesh.cells, nxt), mesh.mid_key) & has).any(axis=1)  # not fanned
    for cells, r, h in mesh.middle_samples:
        keep = whole[cells]
        add(mesh.cells[cells[keep], :3], r[keep], h[keep])
    tested = whole & (mesh.centre[:, 6] > 0)
    for k in (3, 4):
        sel = np.nonzero(tested & (mesh.nv == k))[0]
        add(mesh.cells[sel, :k], mesh.centre[sel, :3], mesh.centre[sel, 3:6])
    A = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(count, len(mesh.P))).tocsr()[:, vv]
    M = (A.T @ A).tocsr()
    g = np.concatenate(rhs)
    inv_diag = 1.0 / M.diagonal()
    pre = LinearOperator(M.shape, matvec=lambda x: inv_diag * x)
    for c in range(6):
        x, info = cg(M, A.T @ g[:, c], x0=g[: len(vv), c].copy(), rtol=1e-10, atol=0.0, maxiter=1000, M=pre)
        if info == 0:
            (mesh.R if c < 3 else mesh.H)[vv, c % 3] = np.maximum(x, 0.0)


def gathered_vertex_values(result, display: dict, patches: dict, *, rays: int, importance: float,
                           sample_offset: float, refine_levels: int = 0,
                           refine_tolerance: float = 0.02,
                           second_bounce: float = 1.0, fit: bool = True) -> tuple[dict, np.ndarray, np.ndarray, dict]:
    """The display mesh (refined up to `refine_levels` times where its gathered values need it)
    and its vertex radiance W/(m^2 sr) and irradiance W/m^2 from the final gather, with counts:
    `samples` (points gathered), `unfound` (samples that found no surface to gather on),
    `enclosed` (samples inside geometry), `unfilled` (vertices left without a value: NaN, the
    caller keeps its vertex-rule values there), `split` (faces split) and `fans` (faces drawn
    as fans around their centre). `fit`: the vertex values fitted by least squares to every
    sample gathered (_fit; with refine_levels 0 there are only the vertices' own)."""
    mesh = _Mesh(display)
    nvert0, nface0 = len(mesh.P), len(mesh.nv)
    has, _ = _edges(mesh.cells, mesh.nv)
    cf = mesh.cells[has]                     # corner -> vertex
    face_of = np.nonzero(has)[0]             # corner -> face
    centroid = _centroids(mesh.P, mesh.cells, has, mesh.nv)
    corners = mesh.P[cf]
    edge = np.linalg.norm(corners - centroid[face_of], axis=1)
    reach = float(max(1e-4, 0.1 * np.median(edge))) if len(edge) else 1e-3  # a floor vertex under a wall
    sampler = _Sampler(result, np.asarray(patches["normal"], dtype=np.float64), rays=rays, importance=importance,
                       sample_offset=sample_offset, reach=reach, second_bounce=second_bounce)
    g_rad, g_irr, ok = sampler(corners + INSET * (centroid[face_of] - corners), mesh.patch[face_of], cf)
    mesh.R, mesh.H = _mean_by(cf, g_rad, ok, nvert0), _mean_by(cf, g_irr, ok, nvert0)
    mesh.valid = np.isfinite(mesh.R).all(axis=1)
    stats = {"split": 0, "fans": 0}
    faces, nv, face_patch = mesh.cells, mesh.nv, mesh.patch
    if refine_levels > 0 and nface0:
        lum = mesh.R[mesh.valid] @ LUM
        floor = FLOOR * float(np.median(lum)) if lum.size else 0.0
        candidates = np.arange(nface0)
        for _ in range(refine_levels):
            if candidates.size == 0:
                break
            n_before = int((~mesh.leaf).sum())
            candidates = _refine_level(mesh, candidates, sampler, refine_tolerance, floor)
            stats["split"] += int((~mesh.leaf).sum()) - n_before
        if stats["split"]:
            faces, nv, face_patch, stats["fans"] = _conforming(mesh, sampler)
        if fit:
            _fit(mesh)
    # vertices inside geometry (or that found no surface): from their neighbours along edges
    has, nxt = _edges(faces, nv)
    mesh.valid = mesh.valid & np.isfinite(mesh.R).all(axis=1)
    unfilled = _fill_from_neighbours([mesh.R, mesh.H], mesh.valid, np.stack([faces[has], nxt[has]], axis=1))
    mesh.R[unfilled] = np.nan
    mesh.H[unfilled] = np.nan
    out = dict(display)
    if stats["split"]:
        point_mesh = np.zeros(len(mesh.P), dtype=np.asarray(display["point_mesh"]).dtype)
        point_mesh[faces.reshape(-1)] = np.repeat(np.asarray(patches["mesh"])[face_patch], 4)
        point_mesh[:nvert0] = display["point_mesh"]
        out = {"points": mesh.P, "point_mesh": point_mesh,
               "faces": faces.astype(np.asarray(display["faces"]).dtype),
               "face_nv": nv.astype(np.asarray(display["face_nv"]).dtype),
               "face_patch": face_patch.astype(np.asarray(display["face_patch"]).dtype),
               "corners": display["corners"]}  # the patches' corner points: the first points, kept
    stats.update(samples=sampler.samples, unfound=sampler.unfound, enclosed=sampler.enclosed,
                 unfilled=int(unfilled.sum()))
    return out, mesh.R, mesh.H, stats
