"""Helpers for the end-to-end tests (test_cli.py, test_bake.py): scenes built with pxr,
config files, running the CLI, and checks on output directories.

Not a test module (no test_ prefix); imported by name from the tests in this directory.
"""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[2]
if str(REPO / "tools") not in sys.path:
    sys.path.insert(0, str(REPO / "tools"))

from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt  # noqa: E402

CORNELL = REPO / "configs" / "scenes" / "cornell_box.usda"

# Coarse meshing that keeps a Cornell bake around a second.
COARSE = {"max_patch_area": 0.01, "max_edge_length": 0.1}


# ---------------------------------------------------------------------------------------------
# files
# ---------------------------------------------------------------------------------------------


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def tree_hashes(root: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file under root."""
    return {str(p.relative_to(root)): sha256(p) for p in sorted(Path(root).rglob("*")) if p.is_file()}


def write_config(path: Path, scene: Path, output: Path, **sections) -> Path:
    """A YAML config with absolute scene/output paths plus any top-level sections given (method:
    flat unless one is given: these tests were written for the flat method)."""
    data = {"scene": str(Path(scene).resolve()), "output": str(Path(output).resolve()), "method": "flat"}
    data.update(sections)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def assert_no_output(output: Path) -> None:
    """A failed bake leaves neither the output directory nor a staging directory behind."""
    output = Path(output)
    assert not output.exists(), f"{output} exists after a failed bake"
    if output.parent.exists():
        leftovers = [p.name for p in output.parent.iterdir() if ".partial" in p.name]
        assert leftovers == [], f"staging directories left behind: {leftovers}"


# ---------------------------------------------------------------------------------------------
# the CLI
# ---------------------------------------------------------------------------------------------


def run_cli(*args, cwd: Path | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.setdefault("COLUMNS", "200")
    return subprocess.run([sys.executable, "-m", "hirad.cli", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


# ---------------------------------------------------------------------------------------------
# scenes
# ---------------------------------------------------------------------------------------------


def new_stage(path: Path, mpu: float = 1.0) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, mpu)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    return stage


def add_material(stage: Usd.Stage, path: str, diffuse, emissive=None) -> UsdShade.Material:
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    if emissive is not None:
        sh.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def add_mesh(stage: Usd.Stage, path: str, points, counts, indices, material=None) -> UsdGeom.Mesh:
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in points]))
    m.CreateFaceVertexCountsAttr(list(map(int, counts)))
    m.CreateFaceVertexIndicesAttr(list(map(int, indices)))
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    if material is not None:
        UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(material)
    return m


def box_wall(axis: int, value: float, inward: float, size: float) -> np.ndarray:
    """Corners of the wall of the cube [0,size]^3 at coordinate `axis` = value, ordered
    counter-clockwise seen from inside (normal = inward * unit(axis))."""
    u, v = [a for a in range(3) if a != axis]
    quad = []
    for a, b in ((0, 0), (1, 0), (1, 1), (0, 1)):
        p = np.zeros(3)
        p[axis], p[u], p[v] = value, a * size, b * size
        quad.append(p)
    quad = np.array(quad)
    n = np.cross(quad[1] - quad[0], quad[2] - quad[0])
    if n[axis] * inward < 0:
        quad = quad[::-1].copy()
    return quad


BOX_WALLS = {  # name: (axis, at max side?)
    "floor": (1, False), "ceiling": (1, True), "left": (0, False),
    "right": (0, True), "front": (2, False), "back": (2, True),
}


def furnace_box(path: Path, size: float = 1.0, reflectance: float = 0.5, exitance: float = 1.0,
                nan_faces_in_floor: int = 0) -> Path:
    """Closed cube, faces inward, every face reflectance rho and emitted exitance E (W/m^2,
    authored as emissiveColor radiance E/pi).  Then B = E/(1 - rho) and H = B everywhere.

    nan_faces_in_floor adds that many extra triangles to the floor mesh that use a NaN point."""
    stage = new_stage(path)
    mat = add_material(stage, "/World/Looks/furnace", (reflectance,) * 3, (exitance / math.pi,) * 3)
    for name, (axis, top) in BOX_WALLS.items():
        quad = box_wall(axis, size if top else 0.0, -1.0 if top else 1.0, size)
        points, counts, indices = list(quad), [4], [0, 1, 2, 3]
        if name == "floor" and nan_faces_in_floor:
            points.append(np.full(3, np.nan))
            for k in range(nan_faces_in_floor):
                counts.append(3)
                indices += [k % 4, (k + 1) % 4, 4]
        add_mesh(stage, f"/World/{name}", points, counts, indices, mat)
    stage.GetRootLayer().Save()
    return path


def l_shape(path: Path) -> tuple[Path, float]:
    """An emissive L-shaped hexagon (concave) in the y = 0 plane facing +Y; returns its area."""
    stage = new_stage(path)
    mat = add_material(stage, "/World/Looks/lamp", (0.5, 0.5, 0.5), (1.0, 1.0, 1.0))
    # (x, z) outline counter-clockwise seen from +Y
    # coordinates exact in float32, so the stored polygon is the intended one
    outline = [(0.0, 0.0), (0.0, 2.0), (0.75, 2.0), (0.75, 0.5), (1.5, 0.5), (1.5, 0.0)]
    pts = [(x, 0.0, z) for x, z in outline]
    add_mesh(stage, "/World/ell", pts, [6], list(range(6)), mat)
    stage.GetRootLayer().Save()
    # shoelace in the (z, x) plane, whose orientation matches +Y normals
    zx = np.array([(z, x) for x, z in outline])
    area = 0.5 * abs(np.dot(zx[:, 0], np.roll(zx[:, 1], -1)) - np.dot(zx[:, 1], np.roll(zx[:, 0], -1)))
    return path, float(area)


def no_mesh_scene(path: Path) -> Path:
    stage = new_stage(path)
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    UsdGeom.Xform.Define(stage, "/World/Empty")
    stage.GetRootLayer().Save()
    return path


def all_nan_scene(path: Path) -> Path:
    stage = new_stage(path)
    mat = add_material(stage, "/World/Looks/lamp", (0.5, 0.5, 0.5), (1.0, 1.0, 1.0))
    nan = (math.nan, math.nan, math.nan)
    add_mesh(stage, "/World/bad", [nan] * 4, [4], [0, 1, 2, 3], mat)
    stage.GetRootLayer().Save()
    return path


def mesh_points_by_path(usd_path: Path) -> dict[str, np.ndarray]:
    """World-space points (metres) of every mesh in a stage, read independently of hirad."""
    stage = Usd.Stage.Open(str(usd_path))
    mpu = UsdGeom.GetStageMetersPerUnit(stage)
    cache = UsdGeom.XformCache()
    out = {}
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            m = cache.GetLocalToWorldTransform(prim)
            pts = [m.Transform(Gf.Vec3d(p)) for p in UsdGeom.Mesh(prim).GetPointsAttr().Get()]
            out[str(prim.GetPath())] = np.array(pts, dtype=np.float64) * mpu
    return out


def write_points_csv(path: Path, rows: Iterable[Sequence[float]], header: bool = True) -> Path:
    lines = ["x,y,z,nx,ny,nz"] if header else []
    lines += [",".join(repr(float(v)) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def add_crate_mesh(stage: Usd.Stage, path: str, half: float, material=None) -> UsdGeom.Mesh:
    """A cube mesh at `path`: side 2 half, resting on y = 0 around the origin, faces wound outwards."""
    p = [[x * half, y * half + half, z * half] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    faces = []
    for q in quads:
        a, b, c = (np.asarray(p[i]) for i in q[:3])
        if np.dot(np.cross(b - a, c - a), np.asarray(p)[q].mean(axis=0) - [0, half, 0]) < 0:
            q = q[::-1]
        faces.append(q)
    return add_mesh(stage, path, p, [4] * 6, [k for q in faces for k in q], material)


def add_crate_instancer(stage: Usd.Stage, path: str, half: float, positions, material=None) -> UsdGeom.PointInstancer:
    """A PointInstancer at `path` with copies of one cube prototype (`path`/Prototypes/crate, as
    add_crate_mesh) at `positions`."""
    inst = UsdGeom.PointInstancer.Define(stage, path)
    proto = f"{path}/Prototypes/crate"
    add_crate_mesh(stage, proto, half, material)
    inst.CreatePrototypesRel().SetTargets([proto])
    inst.CreateProtoIndicesAttr([0] * len(positions))
    inst.CreatePositionsAttr([tuple(map(float, x)) for x in positions])
    return inst


def add_pentagon_box(stage: Usd.Stage, path: str, centre, half: float, bottom: float, material=None) -> UsdGeom.Mesh:
    """A box of side 2 half standing at height `bottom` around `centre` (x, z), faces wound
    outwards, whose top is a pentagon and a corner triangle (one corner of the top square cut
    off through the midpoints of its two edges): n-gons for fan triangulation and faceVarying UVs."""
    c, h = np.array([centre[0], bottom, centre[2]], float), float(half)
    p = [c + [x * h, (y + 1) * h, z * h] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    p += [c + [h, 2 * h, 0.0], c + [0.0, 2 * h, h]]  # 8, 9: on the top's edges at the +x+z corner
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [0, 2, 6, 4], [1, 5, 7, 3],  # -x, +x, -y, -z, +z
             [2, 3, 9, 8, 6], [9, 7, 8]]  # top: pentagon + corner triangle (both +y)
    fixed = []
    for q in faces:
        a, b, cc = (np.asarray(p[i]) for i in q[:3])
        if np.dot(np.cross(b - a, cc - a), np.asarray(p)[q].mean(axis=0) - (c + [0, h, 0])) < 0:
            q = q[::-1]
        fixed.append(q)
    return add_mesh(stage, path, p, [len(q) for q in fixed], [k for q in fixed for k in q], material)
