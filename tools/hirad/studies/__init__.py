"""Lighting studies: calculation grids, their statistics and the study's outputs, independent
of the engine that evaluates the illuminance.

* :mod:`.spec`: the grid definitions (pydantic models, for the config's ``grids:``).
* :mod:`.grids`: the points of a grid (EN 12464-1 spacing, border band) and every measure
  (planar, vertical, cylindrical, semi-cylindrical) as planar sensors.
* :mod:`.stats`: Em, Emin, Emax, U0, Ud, maintained values.
* :mod:`.evaluate`: ``evaluate_grids(study, evaluate)`` with ``evaluate(points, normals) -> lux``.
* :mod:`.outputs`: per-point CSV and JSON; :mod:`.pictures`: false-colour PNGs;
  :mod:`.report`: the study report (HTML, PDF).
"""

from .evaluate import GridResult, build_grids, evaluate_grid, evaluate_grids
from .grids import Grid, build_grid, cells_along, en12464_dimension, en12464_spacing, read_points_csv, resolve_room
from .spec import (
    CorridorGrid,
    Measure,
    PointsGrid,
    RectangleGrid,
    StudyConfig,
    StudyError,
    WorkplaneGrid,
    load_study,
    study_from_dict,
)
from .stats import GridStats, grid_stats

__all__ = [
    "CorridorGrid", "Grid", "GridResult", "GridStats", "Measure", "PointsGrid", "RectangleGrid", "StudyConfig",
    "StudyError", "WorkplaneGrid", "build_grid", "build_grids", "cells_along", "en12464_dimension",
    "en12464_spacing", "evaluate_grid", "evaluate_grids", "grid_stats", "load_study", "read_points_csv",
    "resolve_room", "study_from_dict",
]
