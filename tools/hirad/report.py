"""Progress and the run report: stage timings, warnings, the energy balance and report.json."""

from __future__ import annotations

import json
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import numpy as np



# --------------------------------------------------------------------------------------
# progress reporting
# --------------------------------------------------------------------------------------


class Reporter:
    """Stage timings, plus rich progress bars unless quiet."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.timings: dict[str, float] = {}
        self.warnings: list[str] = []
        self._progress = None
        if not quiet:
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(TextColumn("{task.description:<22}"), BarColumn(),
                                      TextColumn("{task.fields[detail]}"), TimeElapsedColumn(),
                                      console=Console(stderr=True), transient=False)

    def __enter__(self):
        if self._progress:
            self._progress.start()
        return self

    def __exit__(self, *exc):
        if self._progress:
            self._progress.stop()

    @contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[Callable[..., None]]:
        """Times a stage; yields update(completed, detail='') for its progress bar."""
        task = self._progress.add_task(name, total=total, detail="") if self._progress else None
        start = time.perf_counter()

        def update(completed: float | None = None, detail: str = "") -> None:
            if task is not None:
                self._progress.update(task, completed=completed, detail=detail)

        try:
            yield update
        finally:
            self.timings[name] = round(time.perf_counter() - start, 4)
            if task is not None:
                self._progress.update(task, total=total or 1, completed=total or 1)

    def warn(self, message: str) -> None:
        self.warnings.append(message)
        if not self.quiet:
            import sys

            print(f"hirad: warning: {message}", file=sys.stderr)


def energy_balance(patches: dict, b: np.ndarray, h: np.ndarray, escaped: np.ndarray) -> dict:
    """Emitted power against absorbed plus escaped (through openings), per channel, in W."""
    area = patches["area"][:, None]
    emitted = (patches["emission"] * area).sum(axis=0)
    absorbed = ((1 - patches["reflectance"]) * h * area).sum(axis=0)
    lost = escaped.sum(axis=0)
    scale = np.where(emitted > 0, emitted, 1.0)
    error = np.abs(emitted - absorbed - lost) / scale
    return {"emitted_W": emitted.tolist(), "absorbed_W": absorbed.tolist(), "escaped_W": lost.tolist(),
            "relative_error": error.tolist(), "max_relative_error": float(error.max())}


def write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)


def scene_fingerprint(scene) -> str:
    """sha256 of what the light depends on: the scene's geometry, reflectance and emission
    (not paths or output settings, so the same scene baked twice gives identical files)."""
    import hashlib

    h = hashlib.sha256()
    for a in (scene.points, scene.face_vertex_counts, scene.face_vertex_indices, scene.face_reflectance,
              scene.face_emission):
        arr = np.ascontiguousarray(a)
        h.update(str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()
