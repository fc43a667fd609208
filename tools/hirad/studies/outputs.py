"""Per-point values of an evaluated grid as CSV and JSON, written atomically (hirad.files).

CSV columns: ``x,y,z`` (m), ``nx,ny,nz`` (the measure's direction, see Grid), ``weight`` (m^2
cell area, or 1 for file points), ``E_lx`` (illuminance of the new installation, lux),
``E_maintained_lx`` (MF x E_lx, lux). Floats are written with Python's shortest round-trip
repr, so reading the file back gives the same bits.
"""

from __future__ import annotations

import io
import math

from hirad import __version__
from hirad.files import write_json, write_text

from .evaluate import GridResult

CSV_HEADER = "x,y,z,nx,ny,nz,weight,E_lx,E_maintained_lx"


def _num(x: float):
    x = float(x)
    return x if math.isfinite(x) else None


def grid_csv_text(result: GridResult) -> str:
    g = result.grid
    buf = io.StringIO()
    buf.write(CSV_HEADER + "\n")
    for p, n, w, e, m in zip(g.points, g.normals, g.weights, result.values, result.maintained):
        buf.write(",".join(repr(float(v)) for v in (*p, *n, w, e, m)) + "\n")
    return buf.getvalue()


def grid_record(result: GridResult) -> dict:
    """Everything about one evaluated grid as JSON-ready data."""
    g = result.grid
    return {
        "format": "hirad-grid",
        "version": 1,
        "hirad_version": __version__,
        "grid": g.name,
        "kind": g.kind,
        "measure": g.measure.model_dump(),
        "units": {"position": "m", "illuminance": "lx", "weight": "m2" if g.area is not None else "1"},
        "maintenance_factor": result.stats.maintenance_factor,
        "stats": {k: (_num(v) if isinstance(v, float) else v) for k, v in result.stats.as_dict().items()},
        "area_m2": g.area,
        "spacing_m": list(g.spacing) if g.spacing else None,
        "en12464_rule": g.rule,
        "source": g.source,
        "points": g.points.tolist(),
        "normals": g.normals.tolist(),
        "weights": g.weights.tolist(),
        "values_lx": result.values.tolist(),
        "maintained_lx": result.maintained.tolist(),
    }


def write_grid_csv(result: GridResult, path) -> None:
    write_text(path, grid_csv_text(result))


def write_grid_json(result: GridResult, path) -> None:
    write_json(path, grid_record(result))
