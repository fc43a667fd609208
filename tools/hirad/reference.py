"""Monte Carlo reference radiance at surface points, independent of any radiosity solution.

The scene's faces are used as they are (no meshing into patches), and the exitant radiance at
the surface point closest to each query point is estimated by path tracing
(`Engine.reference_at`), with its standard error. This is the ground truth that flat and
hierarchical bakes can be compared with (`hirad reference` on the command line).
"""

from __future__ import annotations

import csv
import io
import os
import re
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from . import _engine, usd
from .engine import build_engine
from .bake import BakeError
from .config import load_config
from .photometry.luminaires import with_config_lights

MIN_BOUNCES = 3  # bounces before Russian roulette may end a path
UNSPLIT = 1e9    # meshing limits that keep every face as one patch


def read_points(path: Path):
    """Points (n,3), normals (n,3) (zeros where not given) and the line of each, from a CSV of
    x,y,z[,nx,ny,nz] in metres; a header line, blank lines and '#' comments are skipped.
    Anything else (binary data, text that is not UTF-8, a NUL byte, a FIFO) is a BakeError
    naming the file and, where there is one, the line."""
    path = Path(path)
    if not path.exists():
        raise BakeError(f"{path}: file not found")
    if not path.is_file():
        raise BakeError(f"{path}: not a regular file (a CSV of x,y,z[,nx,ny,nz] is expected)")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BakeError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        start = exc.start + (3 if data.startswith(b"\xef\xbb\xbf") else 0)
        line = data.count(b"\n", 0, start) + 1
        raise BakeError(f"{path}:{line}: not UTF-8 text (byte 0x{data[start]:02x} at offset {start}): expected a CSV"
                        " of x,y,z[,nx,ny,nz]") from None
    if "\0" in text:
        line = text.count("\n", 0, text.index("\0")) + 1
        raise BakeError(f"{path}:{line}: a NUL byte: not a text CSV of x,y,z[,nx,ny,nz]")
    pts, nrm, lines = [], [], []
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        for row in reader:
            line_no = reader.line_num
            cells = [c.strip() for c in row if c.strip()]
            if not cells or cells[0].startswith("#"):
                continue
            try:
                values = [float(c) for c in cells]
            except ValueError:
                if line_no == 1:
                    continue  # header
                raise BakeError(f"{path}:{line_no}: not a number in {row}") from None
            if len(values) not in (3, 6) or not np.all(np.isfinite(values)):
                raise BakeError(f"{path}:{line_no}: expected x,y,z or x,y,z,nx,ny,nz (finite numbers)")
            pts.append(values[:3])
            nrm.append(values[3:] if len(values) == 6 else [0.0, 0.0, 0.0])
            lines.append(line_no)
    except csv.Error as exc:
        raise BakeError(f"{path}:{reader.line_num}: not a CSV of x,y,z[,nx,ny,nz] ({exc})") from None
    if not pts:
        raise BakeError(f"{path}: no points")
    return np.array(pts), np.array(nrm), lines


def scene_of(path: str | os.PathLike) -> usd.SceneArrays:
    """The scene of a USD file, or of a YAML config's `scene` (with its materials settings, its
    IES mode and its `lights:`, added to the scene's luminaires)."""
    path = Path(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        cfg = load_config(path)
        scene = usd.read_scene(cfg.scene, default_reflectance=tuple(cfg.materials.default_reflectance),
                               uv_primvars=tuple(cfg.materials.uv_primvars), ies_mode=cfg.photometry.ies_mode)
        scene.luminaires = with_config_lights(scene, cfg)
        return scene
    return usd.read_scene(path)


def unsplit_model(scene: usd.SceneArrays):
    """An engine of the scene's faces, each face one patch."""
    model = build_engine(scene, with_uv=False)
    if model.stats().faces == 0:
        raise BakeError(f"{scene.source_path or 'scene'}: no usable faces")
    specs = list(getattr(scene, "luminaires", None) or [])
    if specs:  # evaluated exactly at every path vertex (pipeline/reference/reference.h)
        model.set_luminaires([s.to_engine() for s in specs])
    model.mesh(_engine.MeshOptions(max_patch_area=UNSPLIT, max_edge_length=UNSPLIT))
    return model


def reference_at(scene_path: str | os.PathLike, points, normals=None, paths: int = 1024, seed: int = 1,
                 max_distance: float = 0.05, lines: Optional[Sequence[int]] = None,
                 points_file: Optional[str] = None) -> dict:
    """Path-traced exitant radiance W/(m^2 sr) at the surface closest to each point (within
    max_distance metres, facing along its normal when one is given): dict radiance (n,3) and
    standard_error (n,3). `lines` and `points_file` only name the points in errors."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    nrm = (np.zeros_like(pts) if normals is None
           else np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3)))
    if nrm.shape != pts.shape:
        raise ValueError(f"normals: expected shape {pts.shape}, got {nrm.shape}")
    if paths < 1:
        raise ValueError(f"paths must be >= 1, got {paths}")
    model = unsplit_model(scene_of(scene_path))
    try:
        ref = model.reference_at(pts, nrm, _engine.ReferenceOptions(paths=int(paths), min_bounces=MIN_BOUNCES,
                                                                    seed=int(seed)), float(max_distance))
    except ValueError as e:
        m = re.match(r"point (\d+): (.*)", str(e))
        if not m:
            raise
        k = int(m.group(1))
        where = f"{points_file}:{lines[k]}" if points_file and lines else f"point {k}"
        raise BakeError(f"{where}: {m.group(2)} ({pts[k].tolist()})") from None
    return {"radiance": ref.radiance, "standard_error": ref.standard_error}


def write_reference_csv(scene_path: Path, points_path: Path, output: Optional[Path], paths: int, seed: int,
                        max_distance: float, stream=None) -> None:
    """`hirad reference`: reads the points, estimates, writes x,y,z,radiance_rgb,stderr_rgb to
    `output` (hirad.files.atomic_file: exclusive temporary, fsync, rename) or to `stream`."""
    pts, nrm, lines = read_points(points_path)
    ref = reference_at(scene_path, pts, nrm, paths, seed, max_distance, lines, str(points_path))
    rows = [["x", "y", "z", "radiance_r", "radiance_g", "radiance_b", "stderr_r", "stderr_g", "stderr_b"]]
    for k in range(len(pts)):
        rows.append([*map(repr, pts[k].tolist()), *(f"{v:.6g}" for v in ref["radiance"][k]),
                     *(f"{v:.3g}" for v in ref["standard_error"][k])])
    if output:
        from .files import atomic_file

        with atomic_file(output, "w", newline="") as f:
            csv.writer(f).writerows(rows)
    else:
        csv.writer(stream).writerows(rows)
