"""Statistics of a grid's illuminances (lux), EN 12464-1 terms.

* Em: the mean illuminance over the grid, WEIGHTED by each point's weight: the cell area for
  the regular grids (work planes, rectangles), so Em is the area-weighted mean over the cells
  (each cell's value taken at its centre); all cells of a regular grid are equal, so this is
  also the arithmetic mean of its points. Points read from a file all weigh 1: Em is their
  arithmetic mean.
* Emin, Emax: the least and the greatest point value.
* U0 = Emin / Em (EN 12464-1 "illuminance uniformity"), Ud = Emin / Emax ("diversity"); both
  undefined (None) when the denominator is 0.
* maintained values (EN 12464-1 "maintained illuminance" Ebar_m): MF x Em, MF x Emin, MF x Emax
  with the maintenance factor MF of the study; U0 and Ud are ratios and do not change.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Optional

import numpy as np

from .spec import StudyError


@dataclass(frozen=True)
class GridStats:
    """Em, Emin, Emax (lux), U0, Ud, and the maintained Em, Emin, Emax (lux) for factor MF."""

    points: int
    em: float
    emin: float
    emax: float
    u0: Optional[float]
    ud: Optional[float]
    maintenance_factor: float
    em_maintained: float
    emin_maintained: float
    emax_maintained: float

    def as_dict(self) -> dict:
        return asdict(self)


def grid_stats(values, weights=None, maintenance_factor: float = 1.0, name: str = "grid") -> GridStats:
    """The statistics of point values (lux) with their weights (default: all 1)."""
    e = np.asarray(values, dtype=np.float64).ravel()
    if e.size == 0:
        raise StudyError(f"grid {name}: no values")
    if not np.isfinite(e).all():
        k = int(np.flatnonzero(~np.isfinite(e))[0])
        raise StudyError(f"grid {name}: value {k} is {e[k]} (not finite)")
    w = np.ones_like(e) if weights is None else np.asarray(weights, dtype=np.float64).ravel()
    if w.shape != e.shape or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise StudyError(f"grid {name}: weights must be {e.size} finite non-negative numbers, not all 0")
    mf = float(maintenance_factor)
    if not (0 < mf <= 1):
        raise StudyError(f"grid {name}: maintenance factor {mf} is not in (0, 1]")
    emin, emax = float(e.min()), float(e.max())
    # a weighted mean lies between the least and the greatest value; the clip only removes
    # rounding (a uniform field has Em = Emin exactly, U0 = 1)
    em = min(max(float(np.sum(w * e) / np.sum(w)), emin), emax)
    return GridStats(points=int(e.size), em=em, emin=emin, emax=emax,
                     u0=emin / em if em > 0 else None, ud=emin / emax if emax > 0 else None,
                     maintenance_factor=mf, em_maintained=mf * em, emin_maintained=mf * emin,
                     emax_maintained=mf * emax)
