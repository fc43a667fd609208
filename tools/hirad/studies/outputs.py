"""Per-point values of an evaluated grid as CSV and JSON, written atomically (hirad.files).

CSV columns: ``x,y,z`` (m), ``nx,ny,nz`` (the measure's direction, see Grid), ``weight`` (m^2
cell area, or 1 for file points), ``E_lx`` (illuminance of the new installation, lux),
``E_maintained_lx`` (MF x E_lx, lux). Floats are written with Python's shortest round-trip
repr, so reading the file back gives the same bits.

Units (``units``): "photometric" (the default) names the values illuminance in lux (``E_lx``,
``values_lx``); "radiometric" names the same numbers irradiance in W/m^2 (``E_W_m2``,
``E_maintained_W_m2``, ``values_W_m2``, ``maintained_W_m2``), for a bake read in the old
radiometric sense. Either way the value is Y = 0.2126 R + 0.7152 G + 0.0722 B of the linear
Rec.709 channels, and the JSON's ``units`` block says which.
"""

from __future__ import annotations

import io
import math

from hirad import __version__
from hirad.files import write_json, write_text

from .evaluate import GridResult

CSV_HEADER = "x,y,z,nx,ny,nz,weight,E_lx,E_maintained_lx"

# units -> (quantity, unit as written in text, unit as a key suffix, luminance unit)
UNIT_SYSTEMS = {
    "photometric": {"quantity": "illuminance", "unit": "lx", "suffix": "lx", "luminance": "cd/m2",
                    "unit_text": "lx", "luminance_text": "cd/m²"},
    "radiometric": {"quantity": "irradiance", "unit": "W/m2", "suffix": "W_m2", "luminance": "W/(m2 sr)",
                    "unit_text": "W/m²", "luminance_text": "W/(m² sr)"},
}
QUANTITY_Y = "Y = 0.2126 R + 0.7152 G + 0.0722 B of the linear Rec.709 channels"


def unit_system(units: str) -> dict:
    """The names of one unit system ("photometric" or "radiometric"); StudyError otherwise."""
    try:
        return UNIT_SYSTEMS[units]
    except (KeyError, TypeError):
        from .spec import StudyError

        raise StudyError(f"units {units!r}: photometric (lux, cd/m^2) or radiometric (W/m^2, W/(m^2 sr))") from None


def csv_header(units: str = "photometric") -> str:
    """The CSV's header line for the unit system."""
    sfx = unit_system(units)["suffix"]
    return f"x,y,z,nx,ny,nz,weight,E_{sfx},E_maintained_{sfx}"


def _num(x: float):
    x = float(x)
    return x if math.isfinite(x) else None


def grid_csv_text(result: GridResult, units: str = "photometric") -> str:
    g = result.grid
    buf = io.StringIO()
    buf.write(csv_header(units) + "\n")
    for p, n, w, e, m in zip(g.points, g.normals, g.weights, result.values, result.maintained):
        buf.write(",".join(repr(float(v)) for v in (*p, *n, w, e, m)) + "\n")
    return buf.getvalue()


def grid_record(result: GridResult, units: str = "photometric") -> dict:
    """Everything about one evaluated grid as JSON-ready data."""
    g = result.grid
    us = unit_system(units)
    sfx = us["suffix"]
    return {
        "format": "hirad-grid",
        "version": 1,
        "hirad_version": __version__,
        "grid": g.name,
        "kind": g.kind,
        "measure": g.measure.model_dump(),
        "units": {"system": units, "position": "m", us["quantity"]: us["unit"], "values": us["unit"],
                  "quantity": f"{us['quantity']}: {QUANTITY_Y}",
                  "weight": "m2" if g.area is not None else "1"},
        "maintenance_factor": result.stats.maintenance_factor,
        "stats": {k: (_num(v) if isinstance(v, float) else v) for k, v in result.stats.as_dict().items()},
        "area_m2": g.area,
        "spacing_m": list(g.spacing) if g.spacing else None,
        "en12464_rule": g.rule,
        "source": g.source,
        "points": g.points.tolist(),
        "normals": g.normals.tolist(),
        "weights": g.weights.tolist(),
        f"values_{sfx}": result.values.tolist(),
        f"maintained_{sfx}": result.maintained.tolist(),
    }


def write_grid_csv(result: GridResult, path, units: str = "photometric") -> None:
    write_text(path, grid_csv_text(result, units))


def write_grid_json(result: GridResult, path, units: str = "photometric") -> None:
    write_json(path, grid_record(result, units))
