"""Evaluating grids with any engine: ``evaluate_grids(study, evaluate)``.

``evaluate(points (K, 3), normals (K, 3)) -> (K,)`` is the illuminance in lux on a small plane
at each point facing its unit normal (direct light from every luminaire plus the indirect light
gathered from the solution, at the point itself). It is called once per grid with all of that
grid's sensors; each grid point's value is its sensors' weighted sum (see
:mod:`hirad.studies.grids`). What the evaluator returns is checked: the shape, finite values
(a NaN never becomes a number in a report) and no negative illuminance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Optional, Sequence, Union

import numpy as np

from .grids import Grid, build_grid
from .spec import GridSpec, StudyConfig, StudyError
from .stats import GridStats, grid_stats

Evaluator = Callable[[np.ndarray, np.ndarray], np.ndarray]

# an evaluator's value below this (lux) counts as negative, not as rounding
_NEGATIVE_TOLERANCE = 1e-9


@dataclass
class GridResult:
    """One evaluated grid: the grid, its point values (lux, new installation), the maintained
    values (MF x values) and the statistics."""

    grid: Grid
    values: np.ndarray
    maintained: np.ndarray
    stats: GridStats

    @property
    def name(self) -> str:
        return self.grid.name


def evaluate_grid(grid: Grid, evaluate: Evaluator, maintenance_factor: float = 1.0) -> GridResult:
    """Evaluates one built grid."""
    k = len(grid.sensor_points)
    raw = evaluate(grid.sensor_points.copy(), grid.sensor_normals.copy())
    e = np.asarray(raw, dtype=np.float64)
    if e.shape != (k,):
        raise StudyError(f"grid {grid.name}: the evaluator returned shape {e.shape} for {k} sensor points (expected ({k},))")
    bad = ~np.isfinite(e)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise StudyError(f"grid {grid.name}: the evaluator gave {e[i]} lux at sensor {i} "
                         f"(point {grid.sensor_points[i].tolist()}, normal {grid.sensor_normals[i].tolist()}); "
                         f"{int(bad.sum())} of {k} values are not finite")
    neg = e < -_NEGATIVE_TOLERANCE * max(1.0, float(np.abs(e).max()))
    if neg.any():
        i = int(np.flatnonzero(neg)[0])
        raise StudyError(f"grid {grid.name}: the evaluator gave a negative illuminance {e[i]} lux at sensor {i} "
                         f"(point {grid.sensor_points[i].tolist()})")
    values = grid.combine(np.maximum(e, 0.0))
    stats = grid_stats(values, grid.weights, maintenance_factor, grid.name)
    return GridResult(grid=grid, values=values, maintained=maintenance_factor * values, stats=stats)


def build_grids(study: Union[StudyConfig, Mapping[str, GridSpec]], *, up_axis: Optional[str] = None,
                base_dir=None, rooms: Optional[Mapping[str, Sequence]] = None) -> list[Grid]:
    """Every grid of a study, in the order given. `rooms` maps a grid's `room` prim path to its
    floor polygons (hirad.studies.grids.resolve_room)."""
    if isinstance(study, StudyConfig):
        specs, up_axis = study.grids, up_axis or study.up_axis
    else:
        specs = study
    up_axis = up_axis or "Z"
    rooms = rooms or {}
    out = []
    for name, spec in specs.items():
        polygons = None
        room = getattr(spec, "room", None)
        if room is not None and getattr(spec, "polygon", None) is None and getattr(spec, "polygons", None) is None:
            polygons = rooms.get(room)
        out.append(build_grid(name, spec, up_axis=up_axis, base_dir=base_dir, polygons=polygons))
    return out


def evaluate_grids(specs: Union[StudyConfig, Mapping[str, GridSpec], Sequence[Grid]], evaluate: Evaluator, *,
                   maintenance_factor: Optional[float] = None, up_axis: Optional[str] = None, base_dir=None,
                   rooms: Optional[Mapping[str, Sequence]] = None) -> list[GridResult]:
    """Builds (unless given built) and evaluates every grid. The maintenance factor is the
    study's unless given (1.0 for a plain mapping of specs)."""
    if isinstance(specs, StudyConfig):
        mf = specs.maintenance_factor if maintenance_factor is None else maintenance_factor
        grids = build_grids(specs, up_axis=up_axis, base_dir=base_dir, rooms=rooms)
    elif isinstance(specs, Mapping):
        mf = 1.0 if maintenance_factor is None else maintenance_factor
        grids = build_grids(specs, up_axis=up_axis, base_dir=base_dir, rooms=rooms)
    else:
        mf = 1.0 if maintenance_factor is None else maintenance_factor
        grids = list(specs)
    if not (0 < mf <= 1):
        raise StudyError(f"maintenance factor {mf} is not in (0, 1]")
    return [evaluate_grid(g, evaluate, mf) for g in grids]
