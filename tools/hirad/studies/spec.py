"""Calculation grids as config models (pydantic, strict, unknown keys refused).

A study is a maintenance factor and a set of named grids::

    maintenance_factor: 0.8
    up_axis: Z
    grids:
      office:                      # a work plane 0.80 m over a floor polygon
        kind: workplane
        polygon: [[0, 0], [6, 0], [6, 4], [0, 4]]
      corridor:                    # the same at floor level (height 0 m)
        kind: corridor
        polygon: [[6, 0], [20, 0], [20, 2], [6, 2]]
      north_wall:                  # a rectangle in 3D, its normal u x v
        kind: rectangle
        corner: [0, 4, 0]
        edge_u: [6, 0, 0]
        edge_v: [0, 0, 3]
        normal: [0, -1, 0]
      faces:                       # points from a CSV, as cylindrical illuminance
        kind: points
        file: faces.csv
        measure: {type: cylindrical}

Coordinates are metres in the scene's world frame. ``up_axis`` names the vertical; the
horizontal frame (e1, e2) is (+X, +Y) for Z-up and (+X, -Z) for Y-up, so that (e1, e2, up)
is right-handed and an azimuth turns counter-clockwise seen from above, from e1 towards e2,
in both. 2D polygon points are (e1, e2) coordinates.

The grid points themselves and the EN 12464-1 spacing rule are in :mod:`hirad.studies.grids`.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, Strict, ValidationError, field_validator, model_validator

from hirad.errors import BakeError

StrictFloat = Annotated[float, Strict()]
StrictInt = Annotated[int, Strict()]
StrictStr = Annotated[str, Strict()]
Vec3 = tuple[StrictFloat, StrictFloat, StrictFloat]

_MODEL_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=True)
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")

# Above this many points a grid is refused (a typo such as spacing 0.0001 m over a hall):
# 4 M points of cylindrical illuminance are 100 M evaluations.
MAX_GRID_POINTS = 4_000_000
MAX_SENSORS = 40_000_000  # points x sensors per point (cylindrical: N azimuths): about 2 GB of float64


class StudyError(BakeError, ValueError):
    """A grid definition, a grid file or an evaluation that cannot be used; the message names
    the grid (and the file, line or key) and the problem."""


class Measure(BaseModel):
    """What is measured at each point of a grid (every type is reduced to planar illuminances
    at sensor points with normals and weights; see :mod:`hirad.studies.grids`)."""

    model_config = _MODEL_CONFIG

    type: Literal["planar", "vertical", "cylindrical", "semi_cylindrical"] = Field(
        default="planar",
        description=(
            "planar: illuminance (lux) on the grid's surface, facing its normal; vertical: on a"
            " vertical plane facing `azimuth`; cylindrical: mean illuminance on the curved surface"
            " of a small vertical cylinder; semi_cylindrical: on the curved half of it facing"
            " `azimuth` (CIE S 017 vocabulary; see hirad.studies.grids)."
        ),
    )
    azimuth: Optional[StrictFloat] = Field(
        default=None,
        description=(
            "Degrees, counter-clockwise seen from above from the horizontal axis e1 (+X) towards"
            " e2 (+Y for Z-up, -Z for Y-up): the direction a vertical plane or a semi-cylinder"
            " faces. Required for vertical and semi_cylindrical; refused for the others."
        ),
    )
    azimuths: StrictInt = Field(
        default=25, ge=3, le=720,
        description=(
            "Number N of equally spaced vertical illuminances whose mean is the cylindrical"
            " illuminance (cylindrical and semi_cylindrical). Odd N is best: for one collimated"
            " beam the error is at most 1 - (pi/2N) cot(pi/2N), about 0.82/N^2 (0.13 % at 25);"
            " an even N aliases twice as many harmonics: 1 - (pi/N) cot(pi/N), about 3.3/N^2."
        ),
    )

    @model_validator(mode="after")
    def _azimuth_where_needed(self) -> "Measure":
        needs = self.type in ("vertical", "semi_cylindrical")
        if needs and self.azimuth is None:
            raise ValueError(f"measure type {self.type} needs an azimuth (degrees: the direction it faces)")
        if not needs and self.azimuth is not None:
            raise ValueError(f"measure type {self.type} takes no azimuth (only vertical and semi_cylindrical do)")
        return self


class _Spacing(BaseModel):
    """Shared fields: the spacing rule."""

    model_config = _MODEL_CONFIG

    spacing: Union[Literal["en12464"], Annotated[float, Strict(), Field(gt=0.0)]] = Field(
        default="en12464",
        description=(
            "Grid spacing in metres (> 0), or 'en12464': p = 0.2 x 5^log10(d) m, p <= 10 m, d the"
            " longer side of the evaluation area (the shorter one when the longer is at least twice"
            " it); n = ceil(side / p) cells per side, so the spacing side/n never exceeds p."
        ),
    )
    rounding: Literal["ceil", "nearest"] = Field(
        default="ceil",
        description=(
            "Cells per side under the 'en12464' rule: ceil (n = ceil(side / p), spacing <= p: the"
            " EN 12464-1:2011 wording, 'the nearest whole number greater than d/p') or nearest"
            " (n = round(side / p), at least 1: the spacing may exceed p by up to about 1/(2n);"
            " how some tools read the 2021 edition)."
        ),
    )
    measure: Measure = Field(default_factory=Measure, description="What is measured at each point.")

    @field_validator("spacing", mode="before")
    @classmethod
    def _spacing_words(cls, v: Any) -> Any:
        if isinstance(v, (int, float)) and not isinstance(v, bool) and not (v > 0):
            raise ValueError(f"spacing {v!r} m: a spacing must be a positive length in metres (or 'en12464')")
        if isinstance(v, int) and not isinstance(v, bool):
            return float(v)
        return v


def _check_point(p: list[float], where: str) -> None:
    if len(p) not in (2, 3):
        raise ValueError(f"{where} has {len(p)} coordinates; give (e1, e2) or (x, y, z) in metres")


class WorkplaneGrid(_Spacing):
    """A horizontal grid at a height over a floor: the area inside the polygon(s), less the
    border band, with points at the centres of equal cells."""

    kind: Literal["workplane"] = Field(default="workplane", description="A work plane (default height 0.80 m).")
    polygon: Optional[list[list[StrictFloat]]] = Field(
        default=None,
        description=(
            "The floor area: corners in metres, 2D (e1, e2) or 3D world points of one horizontal"
            " floor (their vertical coordinate is the floor level). At least 3 corners."
        ),
    )
    polygons: Optional[list[list[list[StrictFloat]]]] = Field(
        default=None,
        description=(
            "Several floor polygons whose union is the area (a floor mesh's faces, as passed for a"
            " room); edges they share are inside the area, not its border."
        ),
    )
    room: Optional[StrictStr] = Field(
        default=None,
        description=(
            "A USD prim path whose faces' horizontal extent is the floor; the caller resolves it"
            " into `polygons` (hirad.studies.grids.resolve_room) before the grid is built."
        ),
    )
    floor: StrictFloat = Field(
        default=0.0,
        description="Floor level in metres along the up axis, for 2D polygons (3D ones carry their own).",
    )
    height: StrictFloat = Field(
        default=0.80, ge=0.0,
        description="Height of the plane above the floor, metres (EN 12464-1: 0.80 m for work planes).",
    )
    border: StrictFloat = Field(
        default=0.5, ge=0.0,
        description=(
            "Width in metres of the band along the area's walls that is left out of the evaluation"
            " area (EN 12464-1: 0.5 m unless a task lies in it)."
        ),
    )
    axis: StrictFloat = Field(
        default=0.0,
        description="Direction of the grid's rows, degrees counter-clockwise from e1 seen from above.",
    )

    @field_validator("polygon")
    @classmethod
    def _polygon(cls, v):
        if v is None:
            return v
        if len(v) < 3:
            raise ValueError(f"a polygon needs at least 3 corners, this one has {len(v)}")
        for i, p in enumerate(v):
            _check_point(p, f"corner {i}")
        return v

    @field_validator("polygons")
    @classmethod
    def _polygons(cls, v):
        if v is None:
            return v
        if not v:
            raise ValueError("polygons is empty")
        for k, poly in enumerate(v):
            if len(poly) < 3:
                raise ValueError(f"polygon {k} needs at least 3 corners, it has {len(poly)}")
            for i, p in enumerate(poly):
                _check_point(p, f"polygon {k} corner {i}")
        return v

    @model_validator(mode="after")
    def _one_area(self):
        given = [k for k in ("polygon", "polygons", "room") if getattr(self, k) is not None]
        if len(given) == 0:
            raise ValueError("a work plane needs its floor: polygon, polygons or room")
        if "polygon" in given and "polygons" in given:
            raise ValueError("give polygon or polygons, not both")
        return self


class CorridorGrid(WorkplaneGrid):
    """A work plane at floor level: a corridor or circulation area (height 0 m by default)."""

    kind: Literal["corridor"] = Field(default="corridor", description="A circulation area at floor level.")
    height: StrictFloat = Field(default=0.0, ge=0.0, description="Height above the floor, metres (default 0).")


class RectangleGrid(_Spacing):
    """A rectangle in 3D (a wall, a ceiling, a board): points at the centres of equal cells,
    facing its normal."""

    kind: Literal["rectangle"] = Field(default="rectangle", description="A rectangle in 3D: walls, ceilings.")
    corner: Vec3 = Field(description="One corner, metres.")
    edge_u: Vec3 = Field(description="The edge from the corner along the grid's rows, metres.")
    edge_v: Vec3 = Field(description="The other edge from the corner, perpendicular to edge_u, metres.")
    normal: Optional[Vec3] = Field(
        default=None,
        description="The side measured (any length, perpendicular to both edges); default edge_u x edge_v.",
    )
    border: StrictFloat = Field(default=0.0, ge=0.0, description="Band along the edges left out, metres (default 0).")
    offset: StrictFloat = Field(
        default=0.0,
        description="Distance of the points in front of the rectangle along the normal, metres (default 0).",
    )

    @model_validator(mode="after")
    def _geometry(self):
        u, v = self.edge_u, self.edge_v
        lu, lv = math.sqrt(sum(c * c for c in u)), math.sqrt(sum(c * c for c in v))
        if lu <= 0 or lv <= 0:
            raise ValueError("edge_u and edge_v must have a length (metres)")
        dot = sum(a * b for a, b in zip(u, v))
        if abs(dot) > 1e-6 * lu * lv:
            raise ValueError(f"edge_u and edge_v are not perpendicular (angle {math.degrees(math.acos(max(-1, min(1, dot / (lu * lv))))):.4f} deg):"
                             " a rectangle grid needs a right angle")
        if self.normal is not None:
            n = self.normal
            ln = math.sqrt(sum(c * c for c in n))
            if ln <= 0:
                raise ValueError("normal has no length")
            if abs(sum(a * b for a, b in zip(n, u))) > 1e-6 * ln * lu or abs(sum(a * b for a, b in zip(n, v))) > 1e-6 * ln * lv:
                raise ValueError("normal is not perpendicular to the rectangle (edge_u, edge_v)")
        return self


class PointsGrid(BaseModel):
    """Points read from a CSV file: one point a line, ``x,y,z`` or ``x,y,z,nx,ny,nz`` (metres;
    the normal need not be unit length); a header line of names, blank lines and lines starting
    with '#' are skipped."""

    model_config = _MODEL_CONFIG

    kind: Literal["points"] = Field(default="points", description="Points from a CSV file.")
    file: StrictStr = Field(description="The CSV file, relative to the study's directory.")
    normal: Vec3 = Field(
        default=(0.0, 0.0, 1.0),
        description="The normal of points whose line gives none (world frame; default +Z).",
    )
    measure: Measure = Field(default_factory=Measure, description="What is measured at each point.")


GridSpec = Annotated[Union[WorkplaneGrid, CorridorGrid, RectangleGrid, PointsGrid], Field(discriminator="kind")]


class StudyConfig(BaseModel):
    """The grids of a study and what they share."""

    model_config = _MODEL_CONFIG

    maintenance_factor: Annotated[float, Strict(), Field(gt=0.0, le=1.0)] = Field(
        default=1.0,
        description=(
            "Maintenance factor MF in (0, 1]: maintained illuminance = MF x the illuminance of the"
            " new installation (EN 12464-1; 1.0 reports the new values)."
        ),
    )
    up_axis: Literal["Z", "Y"] = Field(default="Z", description="The scene's vertical axis.")
    grids: dict[StrictStr, GridSpec] = Field(
        default_factory=dict,
        description="Named grids; a name is used in file names (letters, digits, _ . -).",
    )

    @field_validator("grids")
    @classmethod
    def _names(cls, v):
        for name in v:
            if not _NAME.match(name):
                raise ValueError(f"grid name {name!r}: use letters, digits, '_', '.' and '-' (it names files)")
        return v


def _key(loc) -> str:
    loc = list(loc)
    if len(loc) >= 3 and loc[0] == "grids" and loc[2] in ("workplane", "corridor", "rectangle", "points"):
        del loc[2]  # pydantic's discriminator tag
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else ("." if out else "") + str(part)
    return out


def study_from_dict(data: Any, source: str = "<dict>") -> StudyConfig:
    """A StudyConfig from plain data; errors are one StudyError naming the source, the key
    (``grids.office.spacing``) and the problem."""
    try:
        return StudyConfig.model_validate(data)
    except ValidationError as e:
        lines = []
        for err in e.errors():
            msg = err["msg"].removeprefix("Value error, ")
            lines.append(f"{source}: {_key(err['loc']) or '(top level)'}: {msg}")
        raise StudyError("\n".join(lines)) from None


def load_study(path) -> StudyConfig:
    """A StudyConfig from a YAML file (``hirad grid SOLUTION GRID.yaml``)."""
    import yaml

    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
    except OSError as e:
        raise StudyError(f"{path}: cannot read: {e.strerror or e}") from None
    except yaml.YAMLError as e:
        raise StudyError(f"{path}: not YAML: {e}") from None
    return study_from_dict(data if data is not None else {}, str(path))
