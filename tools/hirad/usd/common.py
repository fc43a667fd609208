"""What reading and writing USD share: opening a stage, its time, transforms, names, colours, and SceneError."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np

from pxr import Gf, Sdf, Tf, Usd


_LOOKS_NAME = "HiradLooks"  # material scope under SOLUTION_ROOT; reserved as a mesh name




class SceneError(Exception):
    """The input (or a solution layer) cannot be used; the message names the file."""


class _PrimError(SceneError):
    """A value of one prim cannot be used; the message names the prim and the attribute, and
    `read_scene` puts the scene file in front of it."""


def _value_type(value) -> str:
    """The USD type name of a value as authored (``int[]``, ``point3f[]``...), else its Python type."""
    try:
        name = str(Sdf.GetValueTypeNameForValue(value))
    except Exception:  # pragma: no cover - depends on the value
        name = ""
    return name or type(value).__name__


# ----------------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------------


def _open_stage(path: str | Path) -> Usd.Stage:
    p = Path(path)
    if not p.is_file():
        raise SceneError(f"{p}: " + ("not a regular file (a USD file is expected)" if p.exists() else "file not found"))
    try:
        stage = Usd.Stage.Open(str(p))
    except Tf.ErrorException as exc:  # pragma: no cover - message depends on USD version
        msg = str(exc).strip().splitlines()
        raise SceneError(f"{p}: cannot open USD stage ({msg[-1] if msg else 'unknown error'})") from None
    if stage is None:
        raise SceneError(f"{p}: cannot open USD stage")
    return stage


def _stage_time(stage: Usd.Stage) -> Usd.TimeCode:
    if stage.HasAuthoredTimeCodeRange():
        return Usd.TimeCode(stage.GetStartTimeCode())
    return Usd.TimeCode.EarliestTime()


def _mat(m: Gf.Matrix4d) -> np.ndarray:
    """Gf matrix (row-vector convention: p' = p @ M) to numpy (4,4) float64."""
    return np.array(m, dtype=np.float64).reshape(4, 4)


def _transform_points(pts: np.ndarray, m: np.ndarray) -> np.ndarray:
    return pts @ m[:3, :3] + m[3, :3]


def _identifier(text: str) -> str:
    ident = Tf.MakeValidIdentifier(text.strip("/").replace("/", "_") or "mesh")
    return ident


class _Names:
    def __init__(self, reserved: Iterable[str] = ()):
        self.used = set(reserved)

    def make(self, path: str) -> str:
        base = _identifier(path)
        name, k = base, 1
        while name in self.used:
            name = f"{base}_{k}"
            k += 1
        self.used.add(name)
        return name


def _vec3(value, default=(0.0, 0.0, 0.0)) -> np.ndarray:
    if value is None:
        return np.array(default, dtype=np.float64)
    arr = np.array(value, dtype=np.float64).reshape(-1)
    if arr.size == 1:
        return np.repeat(arr, 3)
    return arr[:3]


# ----------------------------------------------------------------------------------------------
# materials
# ----------------------------------------------------------------------------------------------


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
