"""Scenes and runners for the CIE 171:2006 analytical test cases (test_cie171.py and
bench/cie171.py). Not a test module (no test_ prefix).

Everything is built in code through hirad.engine.build_engine: axis-aligned rectangles, each
one face, counter-clockwise seen from the side it emits and receives on (room surfaces face
into the room). Lengths in metres; luminance L in cd/m^2 is carried as radiance in every RGB
channel (white light), so exitance is pi L and the photometric value Y = 0.2126 R + 0.7152 G
+ 0.0722 B equals each channel.

The expected values are the published CIE 171:2006 figures or closed forms, never hirad's
output.
"""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import numpy as np

from hirad import _engine
from hirad.engine import build_engine, patch_dict

# CIE 171:2006 test case 5.3 (area source, black room): illuminance in lx at the published
# points, luminance 1000 cd/m^2 of the 1 x 1 m panel.
CASE_53_WALL = {"A": 2.75, "B": 2.25, "C": 1.75, "D": 1.25, "E": 0.75, "F": 0.25}  # z on wall y = 0, x = 2
CASE_53_WALL_LX = {"A": 32.68, "B": 75.09, "C": 81.38, "D": 69.12, "E": 53.41, "F": 39.90}
CASE_53_FLOOR = {"G": 0.25, "H": 0.75, "I": 1.25, "J": 1.75, "K": 2.25, "L": 2.75, "M": 3.25, "N": 3.75}  # y, x = 2
CASE_53_FLOOR_LX = {"G": 61.27, "H": 79.18, "I": 95.52, "J": 105.89, "K": 105.89, "L": 95.52, "M": 79.18,
                    "N": 61.27}
LUMINANCE = 1000.0  # cd/m^2
OFFSET = 1e-3  # m: sensors sit this far off their wall or floor, into the room
REFLECTANCES_58 = (0.05, 0.25, 0.5, 0.75, 0.95)


def luminous(rgb) -> np.ndarray:
    """Photometric Y of RGB rows (Rec. 709 weights)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def rect(axis: int, level: float, lo, hi, facing: int) -> np.ndarray:
    """The rectangle {x_axis = level, lo <= the other two coordinates <= hi} (lo, hi in the
    order of the axes after `axis`, cyclically), counter-clockwise seen from the side
    `facing` (+1: the +axis side, -1: the -axis side)."""
    a, b = (axis + 1) % 3, (axis + 2) % 3
    corners = []
    for s, t in ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])):
        p = np.zeros(3)
        p[axis], p[a], p[b] = level, s, t
        corners.append(p)
    q = np.array(corners)  # (b-dir x a-dir ...) : u along a, v along b: normal along +axis
    return q if facing > 0 else q[::-1].copy()


def room_with_panel(sx: float, sy: float, sz: float, panel: float):
    """A closed room [0,sx]x[0,sy]x[0,sz] facing inwards whose ceiling z = sz has a centred
    panel x panel hole filled by the panel (facing down). Returns (polygons, index of the
    panel): floor, 4 walls, 4 ceiling strips, panel."""
    cx, cy, h = sx / 2, sy / 2, panel / 2
    x0, x1, y0, y1 = cx - h, cx + h, cy - h, cy + h
    polys = [rect(2, 0.0, (0, 0), (sx, sy), +1),  # floor, up (axes after z: x, y)
             rect(0, 0.0, (0, 0), (sy, sz), +1), rect(0, sx, (0, 0), (sy, sz), -1),  # walls x (axes y, z)
             rect(1, 0.0, (0, 0), (sz, sx), +1), rect(1, sy, (0, 0), (sz, sx), -1),  # walls y (axes z, x)
             rect(2, sz, (0, 0), (sx, y0), -1), rect(2, sz, (0, y1), (sx, sy), -1),  # ceiling strips
             rect(2, sz, (0, y0), (x0, y1), -1), rect(2, sz, (x1, y0), (sx, y1), -1),
             rect(2, sz, (x0, y0), (x1, y1), -1)]  # the panel, down
    return polys, len(polys) - 1


def scene_of(polys, reflectance, emission) -> SimpleNamespace:
    """The arrays build_engine takes: one mesh, each polygon one authored face;
    reflectance and emission (exitance W/m^2) per polygon (scalars: grey)."""
    n = len(polys)
    points = np.concatenate([np.asarray(p, dtype=np.float64) for p in polys])

    def rgb(v):
        return np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64).reshape(-1, 1), (n, 3)))

    return SimpleNamespace(points=points, face_vertex_counts=np.full(n, 4, np.int32),
                           face_vertex_indices=np.arange(4 * n, dtype=np.int32),
                           face_mesh=np.zeros(n, np.int32), face_source=np.arange(n, dtype=np.int32),
                           face_reflectance=rgb(reflectance), face_emission=rgb(emission), corner_uv=None)


def field_of(patches: dict, radiosity) -> tuple:
    """The SurfaceField of solved patches, flat-shaded (every corner of a patch carries its
    B / pi), and the emitted radiance per patch (E / pi)."""
    b = np.asarray(radiosity, dtype=np.float64)
    corner_radiance = np.ascontiguousarray(np.repeat((b / math.pi)[:, None, :], 4, axis=1))
    field = _engine.SurfaceField(np.ascontiguousarray(patches["corners"]), np.ascontiguousarray(patches["nv"]),
                                 corner_radiance, np.zeros_like(corner_radiance))
    return field, np.ascontiguousarray(patches["emission"] / math.pi)


def flat_solve(scene, max_patch_area: float, max_edge: float, samples: int = 16):
    """Meshed, linked and solved (direct) flat: (engine, patches, B, H)."""
    engine = build_engine(scene)
    engine.mesh(_engine.MeshOptions(max_patch_area=max_patch_area, max_edge_length=max_edge))
    ff = _engine.FormFactorOptions(method="raycast", samples=samples, seed=1)
    engine.compute_links(ff)
    solved = engine.solve(_engine.SolveOptions(method="direct", tolerance=1e-9), ff)
    b = np.asarray(solved.radiosity)
    h = np.asarray(engine.transport(b, ff).irradiance)
    return engine, patch_dict(engine.patch_arrays()), b, h


def hierarchical_solve(scene, epsilon: float = 1e-5, min_area: float = 0.01, samples: int = 16):
    """Hierarchical solve, leaves made the patches: (engine, patches, B, H) per leaf."""
    engine = build_engine(scene)
    r = engine.solve_hierarchical(_engine.HierarchyOptions(epsilon=epsilon, min_area=min_area, samples=samples),
                                  _engine.SolveOptions(method="gauss_seidel", tolerance=1e-6))
    engine.use_leaves_as_patches()
    return engine, patch_dict(engine.patch_arrays()), np.asarray(r.radiosity), np.asarray(r.irradiance)


# ---- 5.3: area source in a black room ------------------------------------------------------

def case_53_points():
    """Names, sensor points (OFFSET into the room) and normals of test case 5.3."""
    names, pts, nrm = [], [], []
    for k, z in CASE_53_WALL.items():
        names.append(k)
        pts.append((2.0, OFFSET, z))
        nrm.append((0.0, 1.0, 0.0))
    for k, y in CASE_53_FLOOR.items():
        names.append(k)
        pts.append((2.0, y, OFFSET))
        nrm.append((0.0, 0.0, 1.0))
    return names, np.array(pts), np.array(nrm)


def run_case_53(rays: int = 64, emitter_samples: int = 4) -> list[tuple]:
    """[(point, expected lx, hirad lx, direct lx, indirect lx)] of test case 5.3: the black
    4 x 4 x 3 m room, the 1 x 1 m panel of 1000 cd/m^2 at the ceiling's centre."""
    polys, panel = room_with_panel(4.0, 4.0, 3.0, 1.0)
    emission = np.zeros(len(polys))
    emission[panel] = math.pi * LUMINANCE
    scene = scene_of(polys, 0.0, emission)
    _, patches, b, _ = flat_solve(scene, max_patch_area=0.25, max_edge=0.5, samples=4)
    field, emitted = field_of(patches, b)
    names, pts, nrm = case_53_points()
    ill = field.illuminance(pts, nrm, emitted, rays=rays, seed=1, emitter_samples=emitter_samples)
    d, i = luminous(ill.direct), luminous(ill.indirect)
    expected = {**CASE_53_WALL_LX, **CASE_53_FLOOR_LX}
    return [(n, expected[n], d[k] + i[k], d[k], i[k]) for k, n in enumerate(names)]


# ---- free space: on the axis of a square Lambertian panel ----------------------------------

def square_axis_illuminance(luminance: float, a: float, h: float) -> float:
    """E on the axis of an a x a Lambertian square of luminance L at distance h, on a plane
    facing it: four a/2 x a/2 rectangles with the point under a corner of each; Lambert's
    corner form factor F = 1/(2 pi) [X/sqrt(1+X^2) atan(Y/sqrt(1+X^2)) + Y/sqrt(1+Y^2)
    atan(X/sqrt(1+Y^2))] with X = Y = a/(2h) gives E = pi L 4 F = 4 L s atan(s),
    s = X / sqrt(1 + X^2) = a / (2 sqrt(a^2/4 + h^2))."""
    s = a / (2.0 * math.sqrt(a * a / 4.0 + h * h))
    return 4.0 * luminance * s * math.atan(s)


FREE_HEIGHTS = (0.05, 0.25, 0.5, 1.0, 2.0, 4.0)


def run_free_square(a: float = 1.0, emitter_samples: int = 4) -> list[tuple]:
    """[(height, expected lx, hirad lx)]: one a x a panel of 1000 cd/m^2 at z = 0 facing down,
    nothing else; sensors on its axis at z = -h facing up."""
    poly = rect(2, 0.0, (-a / 2, -a / 2), (a / 2, a / 2), -1)
    scene = scene_of([poly], 0.0, [math.pi * LUMINANCE])
    _, patches, b, _ = flat_solve(scene, max_patch_area=1e9, max_edge=1e9, samples=1)
    field, emitted = field_of(patches, b)
    pts = np.array([(0.0, 0.0, -h) for h in FREE_HEIGHTS])
    nrm = np.tile([0.0, 0.0, 1.0], (len(FREE_HEIGHTS), 1))
    ill = field.illuminance(pts, nrm, emitted, rays=16, seed=1, emitter_samples=emitter_samples)
    got = luminous(ill.direct) + luminous(ill.indirect)
    return [(h, square_axis_illuminance(LUMINANCE, a, h), got[k]) for k, h in enumerate(FREE_HEIGHTS)]


# ---- 5.8: interreflections in a closed 4 m cube ---------------------------------------------

def case_58_expected(rho: float, side: float = 4.0, panel: float = 1.0) -> float:
    """Area-weighted mean illuminance over every surface of the closed cube (all of
    reflectance rho, the emitting panel included): Phi / (A_T (1 - rho)), Phi = pi L A_e."""
    return math.pi * LUMINANCE * panel * panel / (6.0 * side * side * (1.0 - rho))


def run_case_58(rho: float, method: str) -> tuple:
    """(expected lx, hirad lx, patches) of the mean illuminance over all surfaces of the
    closed 4 m cube, every surface of reflectance rho, a 1 x 1 m panel of 1000 cd/m^2 at the
    ceiling's centre (which reflects rho too). method 'flat' or 'hierarchical'."""
    polys, panel = room_with_panel(4.0, 4.0, 4.0, 1.0)
    emission = np.zeros(len(polys))
    emission[panel] = math.pi * LUMINANCE
    scene = scene_of(polys, rho, emission)
    if method == "flat":
        _, patches, _, h = flat_solve(scene, max_patch_area=0.25, max_edge=0.5, samples=16)
    else:
        _, patches, _, h = hierarchical_solve(scene)
    area = patches["area"]
    mean = float((luminous(h) * area).sum() / area.sum())
    return case_58_expected(rho), mean, len(area)


def timed(fn, *args, **kwargs):
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t


def run_case_58_sensors(rho: float, rays: int = 256) -> tuple:
    """(expected lx, hirad lx, sensors): the same closed cube solved flat, then
    SurfaceField.illuminance (direct + indirect) at one sensor 1 mm off every patch's
    centroid facing its normal, averaged weighted by patch area: the binding's reading of
    the same closed-form mean (a midpoint rule over the patches, so only loosely)."""
    polys, panel = room_with_panel(4.0, 4.0, 4.0, 1.0)
    emission = np.zeros(len(polys))
    emission[panel] = math.pi * LUMINANCE
    _, patches, b, _ = flat_solve(scene_of(polys, rho, emission), max_patch_area=0.25, max_edge=0.5, samples=16)
    field, emitted = field_of(patches, b)
    pts = np.ascontiguousarray(patches["centroid"] + OFFSET * patches["normal"])
    ill = field.illuminance(pts, np.ascontiguousarray(patches["normal"]), emitted, rays=rays, seed=1)
    area = patches["area"]
    mean = float(((luminous(ill.direct) + luminous(ill.indirect)) * area).sum() / area.sum())
    return case_58_expected(rho), mean, len(area)


# ---- 5.2 and 5.4: point sources (luminaires) -------------------------------------------------

NG = 361  # gamma nodes of the test tables (0.5 degree)
GAMMA = np.radians(np.linspace(0.0, 180.0, NG))


def point_luminaire(position, candela, frame=np.eye(3), name="l"):
    """A one-point luminaire of candela table `candela` (nc, ng) or (ng,) in white light."""
    candela = np.atleast_2d(np.asarray(candela, dtype=np.float64))
    return _engine.Luminaire(name, np.array([position], dtype=np.float64), np.ones(1), np.asarray(frame, float),
                             np.ascontiguousarray(candela), np.ones((1, 3)))


def isotropic_point(position, lumens: float):
    """An isotropic point of flux `lumens` (I = lumens / 4 pi)."""
    return point_luminaire(position, np.full((1, 2), lumens / (4 * math.pi)), name="isotropic")


def lambertian_point(position, i0: float = 1000.0):
    """CIE 171 5.2's source: a downward Lambertian point, I = i0 cos(gamma) below, 0 above."""
    return point_luminaire(position, np.where(GAMMA <= math.pi / 2, i0 * np.cos(GAMMA), 0.0)[None, :],
                           name="lambertian")


def closed_box(sx: float, sy: float, sz: float, rho: float):
    """A closed room [0,sx]x[0,sy]x[0,sz], faces inward, uniform grey reflectance rho."""
    polys = [rect(2, 0.0, (0, 0), (sx, sy), +1), rect(2, sz, (0, 0), (sx, sy), -1),
             rect(0, 0.0, (0, 0), (sy, sz), +1), rect(0, sx, (0, 0), (sy, sz), -1),
             rect(1, 0.0, (0, 0), (sz, sx), +1), rect(1, sy, (0, 0), (sz, sx), -1)]
    return scene_of(polys, rho, 0.0)


# CIE 171:2006 Table (5.2): point (x, y) on the floor, 3 m below the source, and E in lux.
CASE_52 = {"A": (0, 0, 111.11), "B": (0.5, 0, 105.21), "C": (1, 0, 90.02), "D": (1.5, 0, 71.11),
           "E": (0.5, 0.5, 99.73), "F": (1, 0.5, 85.64), "G": (1.5, 0.5, 68.06), "H": (1, 1, 74.36),
           "I": (1.5, 1, 59.98), "J": (1.5, 1.5, 49.39)}
HEIGHT_52 = 3.0


def run_case_52() -> list[tuple]:
    """[(name, table lx, closed form 1000 h^2 / d^4, hirad lx)]: the points as sensors of
    SurfaceField.illuminance at floor height, in free space (a black sheet 10 m below)."""
    sheet = np.array([[[-50, -50, -10], [50, -50, -10], [50, 50, -10], [-50, 50, -10]]], dtype=np.float64)
    field = _engine.SurfaceField(sheet, np.array([4], np.int32), np.zeros((1, 4, 3)), np.zeros((1, 4, 3)))
    field.set_luminaires([lambertian_point([0, 0, HEIGHT_52])])
    pts = np.array([[x, y, 0.0] for x, y, _ in CASE_52.values()])
    e = field.illuminance(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), np.zeros((1, 3)), rays=16, seed=1)
    got = luminous(np.asarray(e.direct) + np.asarray(e.indirect))
    h2 = HEIGHT_52 ** 2
    return [(name, table, 1000 * h2 / (x * x + y * y + h2) ** 2, float(v))
            for (name, (x, y, table)), v in zip(CASE_52.items(), got)]


def run_case_54(method: str, lumens: float = 10000.0) -> tuple:
    """(lumens, received lm, elements): an isotropic source at (2, 2, 2) in a black 4 x 4 x 3 m
    room; the received flux is the sum of the elements' direct light x area (all absorbed)."""
    engine = build_engine(closed_box(4, 4, 3, 0.0))
    engine.set_luminaires([isotropic_point([2.0, 2.0, 2.0], lumens)])
    if method == "flat":
        engine.mesh(_engine.MeshOptions(max_patch_area=0.04, max_edge_length=0.2))
    else:
        ho = _engine.HierarchyOptions(epsilon=1e-4, min_area=0.01)
        so = _engine.SolveOptions(method="jacobi")
        if method == "out_of_core":
            engine.solve_out_of_core(ho, so, _engine.OutOfCoreOptions())
        else:
            engine.solve_hierarchical(ho, so)
        engine.use_leaves_as_patches()
    p = patch_dict(engine.patch_arrays())
    return lumens, float(luminous((p["direct"] * p["area"][:, None]).sum(axis=0))), len(p["area"])
