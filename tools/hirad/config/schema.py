"""The config schema: one pydantic model per section, strict types, units and defaults in each field's description."""

from __future__ import annotations

import hashlib
import json
import os
import re
from fractions import Fraction
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationInfo,
    field_validator,
    model_validator,
)

from hirad.studies.spec import GridSpec, PointsGrid
from hirad.studies.spec import _NAME as _GRID_NAME


# --------------------------------------------------------------------------
# Schema
# --------------------------------------------------------------------------

# Scalars are strict (no str -> number, no number -> bool); a strict float
# still accepts an integer, so `crease_angle: 30` is fine.  Containers are
# lax so that a YAML list can fill a tuple and a Python tuple a list.
StrictInt = Annotated[int, Strict()]
StrictFloat = Annotated[float, Strict()]
StrictBool = Annotated[bool, Strict()]
StrictStr = Annotated[str, Strict()]
Reflectance = Annotated[float, Strict(), Field(ge=0.0, lt=1.0)]

# Bounds of what the engine can take (its integer types) and floors below which a setting
# would only allocate without bound: the schema cannot know the scene, so these are the
# smallest values any real scene needs, not estimates of a particular bake's cost.
UINT32_MAX = 2**32 - 1
UINT64_MAX = 2**64 - 1
INT64_MAX = 2**63 - 1
MAX_THREADS = 65536
MAX_MEMORY_BUDGET = 1 << 50  # 1 PiB
MIN_PATCH_AREA = 1e-8  # m^2: a 0.1 mm square
MIN_EDGE_LENGTH = 1e-4  # m: 0.1 mm
MIN_ELEMENT_AREA = 1e-8  # m^2


def _at_least(value: float, floor: float, unit: str, what: str) -> float:
    if value < floor:
        raise ValueError(f"{value:g} {unit} is below the floor of {floor:g} {unit} ({what}): finer than that, the"
                         " number of patches or elements would grow beyond any memory for a real scene")
    return value

_MODEL_CONFIG = ConfigDict(
    extra="forbid",
    allow_inf_nan=False,
    validate_assignment=True,
    validate_default=False,
)


class MaterialsConfig(BaseModel):
    """How surface materials are read from the scene."""

    model_config = _MODEL_CONFIG

    default_reflectance: tuple[Reflectance, Reflectance, Reflectance] = Field(
        default=(0.5, 0.5, 0.5),
        description=(
            "Diffuse reflectance [r, g, b] for surfaces without a readable material;"
            " each channel in [0, 1) (1 would never converge)."
        ),
    )
    uv_primvars: list[StrictStr] = Field(
        default_factory=lambda: ["st", "uv", "UVMap", "st0", "map1"],
        description=(
            "Names of mesh primvars holding texture coordinates, tried in order;"
            " the first one present on a mesh is used for its texture lookups."
        ),
    )


NonNegative = Annotated[float, Strict(), Field(ge=0.0)]
Vector3 = tuple[StrictFloat, StrictFloat, StrictFloat]
IES_MODE_TEXT = (
    "'absolute' (the architectural default, as Radiance and AGi32 read a file: the file's candela x"
    " its multiplier x its ballast factor, the light's intensity x 2^exposure x colour a dimmer, the"
    " light's shape only placing the emitting points) or 'usdlux' (UsdLuxShapingAPI: the candela scale"
    " the light's own emission, and shaping:ies:normalize keeps the unshaped light's flux)"
)


class PhotometryConfig(BaseModel):
    """How luminaire photometry (IES profiles) is read."""

    model_config = _MODEL_CONFIG

    ies_mode: Literal["absolute", "usdlux"] = Field(
        default="absolute",
        description="How IES files (USD inputs:shaping:ies:file and the lights' `ies`) are read: " + IES_MODE_TEXT
                    + ". Stated in every luminaire's schedule row.",
    )


class LightConfig(BaseModel):
    """A point light given in the config (added to the scene's lights): an isotropic point, or an
    IES profile aimed in the scene."""

    model_config = _MODEL_CONFIG

    name: StrictStr = Field(description="The light's name (letters, digits, _ . -), unique among `lights`.")
    position: Vector3 = Field(
        json_schema_extra={"unit": "m"},
        description="Where it is, in metres, in the scene's world axes (after metersPerUnit).",
    )
    intensity: Optional[NonNegative] = Field(
        default=None,
        json_schema_extra={"unit": "cd"},
        description=(
            "Luminous intensity in candela of an isotropic light; with an `ies` file the dimmer of"
            " the file's candela in mode absolute (default 1), the isotropic intensity whose flux"
            " (4 pi x intensity) the profile keeps in mode usdlux. Not together with `flux`."
        ),
    )
    flux: Optional[NonNegative] = Field(
        default=None,
        json_schema_extra={"unit": "lm"},
        description=(
            "Luminous flux in lumens (Rec.709 Y of the RGB flux): the light is scaled to emit exactly"
            " this. Not together with `intensity`."
        ),
    )
    colour: tuple[NonNegative, NonNegative, NonNegative] = Field(
        default=(1.0, 1.0, 1.0),
        description="Linear RGB colour multiplying the intensity per channel.",
    )
    ies: Optional[Path] = Field(
        default=None,
        description="An IES LM-63 file (relative to the config file's directory) giving the light's profile.",
    )
    ies_mode: Optional[Literal["absolute", "usdlux"]] = Field(
        default=None,
        description="How `ies` is read (null: photometry.ies_mode): " + IES_MODE_TEXT + ".",
    )
    aim: Optional[Vector3] = Field(
        default=None,
        description=(
            "World direction of the profile's nadir (gamma 0, the light's local -Z); null: straight"
            " down the scene's up axis. Not together with `rotation`."
        ),
    )
    c0: Optional[Vector3] = Field(
        default=None,
        description=(
            "World direction of the profile's C0 plane (the light's local +X), made perpendicular"
            " to `aim`; null: world X (world Y when `aim` is along X). Not together with `rotation`."
        ),
    )
    rotation: Optional[Vector3] = Field(
        default=None,
        json_schema_extra={"unit": "degrees"},
        description=(
            "The light's frame as USD's xformOp:rotateXYZ [rx, ry, rz] in degrees applied to the"
            " world axes (local -Z = nadir, +X = C0): instead of `aim` and `c0`."
        ),
    )

    @field_validator("name")
    @classmethod
    def _light_name(cls, value: str) -> str:
        if not _GRID_NAME.match(value):
            raise ValueError(f"light name {value!r}: use letters, digits, '_', '.' and '-'")
        return value

    @field_validator("aim")
    @classmethod
    def _aim_not_zero(cls, value):
        if value is not None and not any(value):
            raise ValueError("aim must be a non-zero direction")
        return value

    @model_validator(mode="after")
    def _consistent(self) -> "LightConfig":
        if self.intensity is not None and self.flux is not None:
            raise ValueError("give `intensity` (cd) or `flux` (lm), not both")
        if self.ies is None and self.intensity is None and self.flux is None:
            raise ValueError("a light without an `ies` file needs `intensity` (cd) or `flux` (lm)")
        if self.rotation is not None and (self.aim is not None or self.c0 is not None):
            raise ValueError("give `rotation` or `aim`/`c0`, not both")
        if self.c0 is not None:
            if not any(self.c0):
                raise ValueError("c0 must be a non-zero direction")
            if self.aim is not None:
                a = [float(v) for v in self.aim]
                c = [float(v) for v in self.c0]
                cross = (a[1] * c[2] - a[2] * c[1], a[2] * c[0] - a[0] * c[2], a[0] * c[1] - a[1] * c[0])
                na = sum(v * v for v in a) ** 0.5
                nc = sum(v * v for v in c) ** 0.5
                if sum(v * v for v in cross) ** 0.5 <= 1e-9 * na * nc:
                    raise ValueError("c0 is parallel to aim: it cannot orient the C planes")
        if self.flux is not None and self.flux > 0:
            y = 0.2126 * self.colour[0] + 0.7152 * self.colour[1] + 0.0722 * self.colour[2]
            if not y > 0:
                raise ValueError("a colour without luminance (Y = 0) cannot be scaled to a flux")
        return self


# A light group's name: it names primvars (primvars:hirad:group:NAME:irradiance) and
# `hirad relight --set lights.groups.NAME.dimmer=...` keys, so no dots or colons.
LIGHT_GROUP_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_-]*$")
REST_GROUP = "rest"


class LightGroupConfig(BaseModel):
    """A light group (`lights.groups.NAME`): lights and emitters chosen by prim path patterns or a
    UsdCollectionAPI collection, solved alone on the shared links so that `hirad relight` can
    dim and tint it without solving."""

    model_config = _MODEL_CONFIG

    paths: list[StrictStr] = Field(
        default_factory=list,
        description=(
            "fnmatch patterns on the prim paths of lights and emitting meshes (luminaires: the USD"
            " prim path, config lights: `lights.points[NAME]`'s name); a pattern matching nothing"
            " is named in a warning."
        ),
    )
    collection: Optional[StrictStr] = Field(
        default=None,
        description="A UsdCollectionAPI collection path (</World/Lights.collection:desk>) whose members are the group.",
    )
    each: StrictBool = Field(
        default=False,
        description=(
            "Every matching light its own group, named NAME_<prim name> (without paths or collection:"
            " every light of the scene)."
        ),
    )
    dimmer: Annotated[float, Strict(), Field(ge=0.0)] = Field(
        default=1.0, description="Multiplies the group's light (0: off)."
    )
    color: Optional[tuple[NonNegative, NonNegative, NonNegative]] = Field(
        default=None, description="Linear RGB multiplier of the group's light (null: white)."
    )


class MeshingConfig(BaseModel):
    """How scene surfaces are subdivided into radiosity patches."""

    model_config = _MODEL_CONFIG

    max_patch_area: StrictFloat = Field(
        json_schema_extra={"unit": "m^2", "at_least": MIN_PATCH_AREA},
        default=0.01,
        gt=0.0,
        description=(
            f"Largest patch area, in square metres; smaller means more patches. At least {MIN_PATCH_AREA:g} m^2"
            " (a 0.1 mm square)."
        ),
    )
    max_edge_length: StrictFloat = Field(
        json_schema_extra={"unit": "m", "at_least": MIN_EDGE_LENGTH},
        default=0.1,
        gt=0.0,
        description=f"Longest patch edge, in metres; bounds sliver patches. At least {MIN_EDGE_LENGTH:g} m.",
    )

    @field_validator("max_patch_area")
    @classmethod
    def _area_floor(cls, value: float) -> float:
        return _at_least(value, MIN_PATCH_AREA, "m^2", "a 0.1 mm square")

    @field_validator("max_edge_length")
    @classmethod
    def _edge_floor(cls, value: float) -> float:
        return _at_least(value, MIN_EDGE_LENGTH, "m", "0.1 mm")


class FormFactorConfig(BaseModel):
    """How patch-to-patch form factors are computed."""

    model_config = _MODEL_CONFIG

    method: Literal["raycast", "hemicube"] = Field(
        default="raycast",
        description="'raycast' (stratified area sampling) or 'hemicube' (rasterised hemicubes).",
    )
    samples: StrictInt = Field(
        json_schema_extra={"unit": "points per patch"},
        default=16,
        ge=1,
        le=4096,
        description="Stratified sample points per patch for the raycast method.",
    )
    hemicube_resolution: StrictInt = Field(
        json_schema_extra={"unit": "pixels"},
        default=128,
        ge=8,
        le=2048,
        description="Pixels along the top face of each hemicube (hemicube method).",
    )
    hemicube_points: StrictInt = Field(
        json_schema_extra={"unit": "hemicubes per patch"},
        default=4,
        ge=1,
        le=64,
        description="Hemicubes placed per patch, averaged (hemicube method).",
    )

    @field_validator("hemicube_resolution")
    @classmethod
    def _even_resolution(cls, value: int) -> int:
        # The side faces are resolution x resolution/2 cells.
        if value % 2:
            raise ValueError(f"must be even, got {value}")
        return value


class HierarchyConfig(BaseModel):
    """Hierarchical radiosity with clustering (used when method is 'hierarchical')."""

    model_config = _MODEL_CONFIG

    epsilon: StrictFloat = Field(
        json_schema_extra={"unit": "fraction of the emitted power"},
        default=1e-5,
        ge=0.0,
        lt=1.0,
        description=(
            "Refinement threshold: a link is split while the power it carries exceeds this"
            " fraction of the scene's emitted power (0 refines every link to min_area)."
        ),
    )
    min_area: StrictFloat = Field(
        json_schema_extra={"unit": "m^2", "at_least": MIN_ELEMENT_AREA},
        default=1e-3,
        gt=0.0,
        description=(
            f"Smallest element area, in m^2; elements are not split below it. At least {MIN_ELEMENT_AREA:g} m^2."
        ),
    )
    samples: StrictInt = Field(
        json_schema_extra={"unit": "point pairs per link"},
        default=16, ge=1, le=4096, description="Point pairs per link estimate (rounded to a square)."
    )
    max_rounds: StrictInt = Field(
        json_schema_extra={"unit": "rounds"},
        default=6,
        ge=1,
        le=100,
        description="Most refine-solve rounds; rounds stop earlier once no link wants to split.",
    )
    relative_epsilon: StrictFloat = Field(
        json_schema_extra={"unit": "fraction of the receiver's light"},
        default=0.0,
        ge=0.0,
        lt=1.0,
        description=(
            "From the second round on, a link is also split while it could carry more than this"
            " fraction of the light its receiver gathers, so dim rooms in bright scenes (a"
            " classroom on a large sunlit ground) are resolved like the rest (0: off)."
        ),
    )
    spread_epsilon: StrictFloat = Field(
        json_schema_extra={"unit": "fraction of epsilon"},
        default=1e-3,
        ge=0.0,
        le=1.0,
        description=(
            "A link carries its source's mean radiosity. Where the source is partly hidden from the"
            " receiver, or close to it, the part the receiver sees can be far brighter or darker"
            " than that mean (a ground plane that is the room's floor inside and sunlit outside),"
            " and the error has one sign over many links. Such a link is split at its source while"
            " the source's radiosity range times the link's unoccluded transfer exceeds this"
            " fraction of epsilon's power (0: off)."
        ),
    )

    closure_reflectance: StrictFloat = Field(
        json_schema_extra={"unit": "reflectance"},
        default=0.95,
        ge=0.0,
        le=1.0,
        description=(
            "A leaf whose link is kept at an ancestor takes that ancestor's mean form factor, so"
            " leaf by leaf the form factors do not sum to what each leaf's hemisphere sees (in a"
            " closed room 0.95 to 1.3 around a mean of 1), and every bounce loses or adds light."
            " Leaves of at least this reflectance have what they inherit scaled so that their sum"
            " comes to their closure, measured by rays. 0.95 (the default) keeps rooms of white"
            " walls in power balance; 0 normalises every leaf, which took the country kitchen's"
            " final gather from a mean error of -3.9 % to +0.4 % but the Modern Hall's RMS error"
            " from 8.6 % to 10.2 % (its walls, rho 0.89, brightened in the dark corners;"
            " bench/README.md); 1: none."
        ),
    )

    cluster_receivers: StrictBool = Field(
        default=False,
        description=(
            "Let clusters receive as well as send (Sillion 1995; Willmott, Heckbert and Garland"
            " 1999): a cluster all of whose faces see a source from their front takes that"
            " source's light as a whole and shares it among its faces by their orientation, and any"
            " cluster takes a link that carries little (its power bound within 1 % of epsilon's"
            " power), evenly if its faces face several ways, so links grow with the lighting, not"
            " with the number of faces. Solved by"
            " solver.method jacobi or block_southwell (the face-by-face solvers cannot)."
        ),
    )

    @field_validator("min_area")
    @classmethod
    def _element_floor(cls, value: float) -> float:
        return _at_least(value, MIN_ELEMENT_AREA, "m^2", "a 0.1 mm square")


class SolverConfig(BaseModel):
    """How the radiosity system (I - R F) B = E is solved."""

    model_config = _MODEL_CONFIG

    method: Literal["southwell", "progressive", "jacobi", "gauss_seidel", "direct", "block_southwell"] = Field(
        default="southwell",
        description=(
            "Solver: 'southwell' (shoot the largest unshot energy), 'progressive'"
            " (shooting with preview snapshots), 'jacobi', 'gauss_seidel' or 'direct'"
            " (dense factorisation; small scenes only); for method: hierarchical also"
            " 'block_southwell': links in the on-disk store of `links`, streamed through a"
            " memory budget (out of core)."
        ),
    )
    tolerance: StrictFloat = Field(
        json_schema_extra={"unit": "relative residual"},
        default=1e-4,
        gt=0.0,
        lt=1.0,
        description="Stop when the relative residual ||E - M B|| / ||E|| falls below this.",
    )
    max_iterations: StrictInt = Field(
        json_schema_extra={"unit": "iterations"},
        default=100_000_000,
        ge=1,
        le=INT64_MAX,
        description="Upper bound on iterations (shots for shooting methods, sweeps otherwise).",
    )
    snapshots: StrictInt = Field(
        json_schema_extra={"unit": "shots"},
        default=0,
        ge=0,
        le=INT64_MAX,
        description=(
            "Progressive solver only: write a preview image every this many shots;"
            " 0 writes none."
        ),
    )

    @field_validator("snapshots")
    @classmethod
    def _snapshots_need_progressive(cls, value: int, info: ValidationInfo) -> int:
        method = info.data.get("method")
        if value > 0 and method is not None and method != "progressive":
            raise ValueError(
                f"snapshots are only written by the progressive solver, not {method!r};"
                " set solver.method: progressive or snapshots: 0"
            )
        return value


class LinksConfig(BaseModel):
    """The on-disk link store of out-of-core hierarchical bakes (solver.method: block_southwell)."""

    model_config = _MODEL_CONFIG

    store: Optional[Path] = Field(
        default=None,
        description=(
            "Directory of the link store (chunk files, manifest, checkpoints); relative to the"
            " config; default: the output directory's name with '.links' beside it. Kept"
            " between bakes, for --resume and --reuse-links."
        ),
    )
    memory_budget: Union[StrictInt, str] = Field(
        json_schema_extra={"unit": "bytes (or '512MB', '2GB')"},
        default=1 << 30,
        description=(
            "Memory for the solver's state and the link chunks it keeps decoded, e.g. '512MB',"
            " '2GB' (or bytes; default 1GB; at most 1PB); 0 = unlimited. The result does not depend on it."
        ),
    )
    group_faces: StrictInt = Field(
        json_schema_extra={"unit": "input faces"},
        default=1024,
        ge=1,
        le=UINT32_MAX,
        description=(
            "Input faces per source group: the links of one group form one chunk, refined and"
            " shot together. Part of the refinement settings (changing it changes the links)."
        ),
    )
    checkpoint_seconds: StrictFloat = Field(
        json_schema_extra={"unit": "s"},
        default=60.0,
        ge=0.0,
        description=("Write the solver's state this often (0: never), or less often where a checkpoint is slow to"
                     " write: the next waits at least 19 times as long as the last took, so that writing them stays"
                     " under a twentieth of the solve; `hirad bake --resume` continues from it."),
    )

    @field_validator("memory_budget")
    @classmethod
    def _budget(cls, value):
        return parse_bytes(value)

    @field_validator("store", mode="after")
    @classmethod
    def _absolute_store(cls, value: Optional[Path], info: ValidationInfo) -> Optional[Path]:
        return None if value is None else _absolute(value, info)


def parse_bytes(value) -> int:
    """'512MB', '2 GiB', '1.5GB', '1PB', 1048576 -> bytes (powers of 1024: GB means GiB), at most
    MAX_MEMORY_BUDGET (1 PiB: beyond any machine, and within the engine's 64-bit sizes)."""
    if isinstance(value, int):
        if value < 0:
            raise ValueError("a memory size cannot be negative")
        size = value
    else:
        m = re.fullmatch(r"\s*([0-9]{1,30}(?:\.[0-9]{1,30})?)\s*([kKmMgGtTpP]?)i?[bB]?\s*", str(value))
        if not m:
            shown = repr(value) if len(str(value)) <= 40 else repr(str(value)[:37]) + "..."
            raise ValueError(f"{shown} is not a memory size (e.g. 512MB, 2GB, or a number of bytes)")
        scale = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40, "p": 1 << 50}[m.group(2).lower()]
        size = int(Fraction(m.group(1)) * scale)
    if size > MAX_MEMORY_BUDGET:
        shown = value if isinstance(value, str) else f"{value} bytes"
        raise ValueError(f"{shown} is more than the largest memory size hirad takes, 1PB ({MAX_MEMORY_BUDGET} bytes)")
    return size


def _gather_importance(description: str):
    """The final gather's importance threshold (GatherOptions.importance), as both the vertex
    values and the lightmaps take it."""
    return Field(json_schema_extra={"unit": "fraction of an element's light"}, default=0.02, ge=0.0, lt=1.0,
                 description=description)


def _gather_second_bounce(description: str):
    """The final gather's second bounce for close sources (GatherOptions.second_bounce), as both
    the vertex values and the lightmaps take it."""
    return Field(json_schema_extra={"unit": "fraction of a source element's diagonal"}, default=1.0, ge=0.0,
                 le=4.0, description=description)


class ReconstructionConfig(BaseModel):
    """How per-patch radiosity is turned into smooth per-vertex values."""

    model_config = _MODEL_CONFIG

    crease_angle: StrictFloat = Field(
        json_schema_extra={"unit": "degrees"},
        default=30.0,
        ge=0.0,
        le=180.0,
        description=(
            "Degrees; neighbouring patches whose normals differ by more than this"
            " are not blended across their shared edge, nor lightmap texels across a chart seam there."
        ),
    )
    values: Literal["auto", "final_gather", "patches"] = Field(
        default="patches",
        description=(
            "What the display mesh's vertices hold (the USD primvars, the preview, interpolated"
            " lightmaps). 'final_gather': each vertex gathered from the solution at the faces"
            " around it (hierarchical: its element's links, flat: every patch, O(patches) a"
            " point), as accurate as the lightmaps' final gather; 'patches': the seed's rule, the"
            " mean of the patches around it (fast; each patch holds one value, so a vertex beside"
            " a contact shadow shows the coarse patches' mean; the default while light-group bakes"
            " cannot gather per group, so that a grouped bake's total and a bake without groups"
            " agree). 'auto': final_gather for method: hierarchical, patches for method: flat."
        ),
    )
    gather_rays: StrictInt = Field(
        json_schema_extra={"unit": "rays per link"},
        default=4, ge=1, le=256,
        description=(
            "Visibility rays per partly visible link for values: final_gather (as the lightmaps'"
            " gather_rays). 4: on the Cornell box (epsilon 1e-5, min_area 5e-4, 16 samples) 0.99 %"
            " mean error in a 1.3 s vertex gather, where 16 rays gave 1.02 % in 2.2 s (bench/README.md)."
        ),
    )
    gather_importance: StrictFloat = _gather_importance(
        "values: final_gather on a hierarchical bake: the weakest links, together at most this"
        " share of an element's light, at their mean (outputs.lightmaps.gather_importance)."
    )
    gather_second_bounce: StrictFloat = _gather_second_bounce(
        "values: final_gather on a hierarchical bake: a source element nearer to the point than"
        " this times its diagonal (a wall at a floor point beside its foot) has its radiosity"
        " gathered again at points drawn where the point sees it, instead of taken as its one"
        " mean: contact shadows (outputs.lightmaps.gather_second_bounce). 0: off."
    )
    refine_levels: StrictInt = Field(
        default=2, ge=0, le=6,
        description=(
            "values: final_gather: how many times a display face may be split in four where its"
            " gathered light varies more than its corners show (a contact shadow at an object's"
            " foot, a shadow edge crossing it); each level gathers every tested face at its edge"
            " midpoints and centre. 0: the solution's elements as they are. Not applied to bakes"
            " with daylight coefficients (their annual results read the elements' mesh)."
        ),
    )
    refine_tolerance: StrictFloat = Field(
        json_schema_extra={"unit": "fraction"},
        default=0.02, gt=0.0, le=1.0,
        description=(
            "values: final_gather with refine_levels: a face is split where the light gathered at"
            " an edge midpoint or its centre differs from what its vertices interpolate there by"
            " more than this fraction of the larger (differences below 1 % of the median vertex"
            " luminance never split)."
        ),
    )


class LightmapOutputConfig(BaseModel):
    """Baked lightmap textures: incident radiance H/pi on a UV atlas of pages.

    Lightmaps are baked on the source meshes (the input's own faces, not hirad's patches). A
    mesh keeps its own lightmap UV set when it has one under a name in ``uv_primvars`` (never
    the texture set ``st`` unless that list names it, and never when its islands overlap: then
    it is charted), else xatlas charts it; every mesh is packed onto pages of at most
    ``max_size`` texels a side at ``texels_per_metre`` with ``padding`` empty texels between
    charts. The output layer writes each mesh's lightmap UVs as the ``uv_set`` primvar on the
    original mesh prim, beside its page and Unity-order scale/offset.
    """

    model_config = _MODEL_CONFIG

    enabled: StrictBool = Field(default=True, description="Write lightmap textures.")
    texels_per_metre: Optional[StrictFloat] = Field(
        json_schema_extra={"unit": "texels/m"},
        default=None,
        gt=0.0,
        le=1.0e5,
        description=(
            "Texel density on the surfaces; null derives it from texels_per_patch"
            " (texels_per_patch / sqrt(median patch area))."
        ),
    )
    texels_per_patch: StrictInt = Field(
        json_schema_extra={"unit": "texels"},
        default=4,
        ge=1,
        le=64,
        description=(
            "Texels along the side of a median patch; only used when texels_per_metre is null."
        ),
    )
    padding: StrictInt = Field(
        json_schema_extra={"unit": "texels"},
        default=2,
        ge=0,
        le=64,
        description="Empty texels between charts (and between meshes), filled by dilation.",
    )
    max_size: StrictInt = Field(
        json_schema_extra={"unit": "texels"},
        default=4096,
        ge=64,
        le=16384,
        description="Largest lightmap atlas page side, in texels.",
    )
    supersample: StrictInt = Field(
        json_schema_extra={"unit": "samples per texel side"},
        default=2,
        ge=1,
        le=8,
        description="Samples per texel along each axis (supersample^2 per texel).",
    )
    mode: Literal["interpolate", "final_gather"] = Field(
        default="interpolate",
        description=(
            "'interpolate': from the solution's vertices (fast); 'final_gather': a one-bounce"
            " gather per sample from the solved hierarchy with Embree visibility"
            " (method: hierarchical only)."
        ),
    )
    gather_rays: StrictInt = Field(
        json_schema_extra={"unit": "rays per link"},
        default=4, ge=1, le=256, description="Visibility rays per link in final_gather mode."
    )
    gather_importance: StrictFloat = _gather_importance(
        "final_gather: per element, its weakest links, together at most this share of the light"
        " it gathers, are taken at their mean over the receiver instead of at every sample (links"
        " from emitters and from close sources always at the sample). No bias, a bounded local"
        " error; 0.02 is about twice as fast as 0 on the Cornell box at the same error (0: every"
        " link at every sample). Directional lightmaps evaluate every link."
    )
    gather_stride: StrictInt = Field(
        json_schema_extra={"unit": "texels"},
        default=1, ge=1, le=16,
        description=(
            "final_gather: 1 gathers every texel. A power of two s gathers the texels on every s-th"
            " row and column first, then each texel between gathered ones (of its mesh, plane and"
            " chart) is interpolated from them where they agree, or vary smoothly, within"
            " gather_tolerance and gathered itself where not (hirad.atlas.evaluate_adaptive)."
            " On the Modern Hall 4 halved the lightmap stage at the same error. Light that varies"
            " within s texels without showing at the lattice is missed: keep s texels below the"
            " smallest shadow that matters."
        ),
    )
    gather_tolerance: StrictFloat = Field(
        json_schema_extra={"unit": "fraction"},
        default=0.05, gt=0.0, le=1.0,
        description=(
            "final_gather with gather_stride > 1: a texel is interpolated between gathered ones"
            " whose values differ by at most this fraction of their mean (per colour channel), or"
            " whose rows and columns' second differences put the interpolation's error within it."
        ),
    )
    gather_second_bounce: StrictFloat = _gather_second_bounce(
        "final_gather: a source element nearer to the sample than this times its diagonal has its"
        " radiosity gathered again where the sample sees it, instead of taken as its one mean"
        " (contact shadows at the foot of objects; reconstruction.gather_second_bounce). 0: off."
    )
    sample_offset: StrictFloat = Field(
        json_schema_extra={"unit": "m"},
        default=1.0e-4,
        ge=0.0,
        le=1.0,
        description=(
            "Metres: texel samples are lifted this far along their normal, and moved out of"
            " geometry they are found inside (see hirad.bake._lift)."
        ),
    )
    existing_layout: Literal["keep", "repack"] = Field(
        default="keep",
        description=(
            "Meshes with their own lightmap UVs: 'keep' the author's layout (scaled to the"
            " density; lightmapScaleOffset maps it to the page) or 'repack' its islands."
        ),
    )
    uv_set: StrictStr = Field(
        default="st1",
        pattern=r"^[A-Za-z_][A-Za-z0-9_]*$",
        description=(
            "Name of the lightmap UV primvar written on the original mesh prims (texCoord2f[],"
            " faceVarying; the mesh's own [0, 1] layout, scaleOffset maps it to its page)."
        ),
    )
    uv_primvars: list[StrictStr] = Field(
        default_factory=lambda: ["st1", "lightmapUV", "uv2", "map2"],
        description=(
            "Primvars read as a mesh's own lightmap UV set, first found wins. The texture set"
            " (st) is used only when listed here."
        ),
    )
    mesh_files: StrictBool = Field(
        default=True,
        description=(
            "Also write lightmaps/<mesh>.exr: each mesh's block cut out of its page."
        ),
    )
    rgbm: StrictBool = Field(
        default=False, description="Also write each page as an 8-bit RGBM PNG."
    )
    rgbm_range: Optional[StrictFloat] = Field(
        json_schema_extra={"unit": "W/(m^2 sr)"},
        default=None,
        gt=0.0,
        description="RGBM range (value = rgb * a * range); null uses each page's maximum.",
    )
    encodings: list[Literal["hirad-rgbm", "unity-rgbm", "unity-dldr"]] = Field(
        default_factory=list,
        description=(
            "8-bit PNG copies of each page besides the half-float EXR: 'hirad-rgbm' (linear, the"
            " range in the PNG; same as rgbm: true), 'unity-rgbm' (Unity's RGBM: range 5 in gamma"
            " space, 34.49 linear) and 'unity-dldr' (Unity's double LDR: 2 in gamma space)."
        ),
    )
    directional: StrictBool = Field(
        default=False,
        description=(
            "Also write directional lightmaps from the final gather (mode: final_gather): per page"
            " Godot 4's four L1 SH layers, Bakery's SH textures and Unity's dominant-direction map."
        ),
    )

    @field_validator("gather_stride")
    @classmethod
    def _stride_power_of_two(cls, value: int) -> int:
        if value & (value - 1):
            raise ValueError(f"must be a power of two (1, 2, 4, 8 or 16), got {value}")
        return value

    @model_validator(mode="after")
    def _directional_needs_the_gather(self) -> "LightmapOutputConfig":
        if self.directional and self.mode != "final_gather":
            raise ValueError("directional: true needs mode: final_gather (the directions come from the gather)")
        if self.gather_stride > 1 and self.mode != "final_gather":
            raise ValueError(f"gather_stride: {self.gather_stride} needs mode: final_gather (the interpolate mode "
                             "reads every texel from the solution's vertices anyway)")
        return self


class VolumeOutputConfig(BaseModel):
    """An irradiance volume (OpenVDB) for lighting dynamic objects."""

    model_config = _MODEL_CONFIG

    enabled: StrictBool = Field(default=False, description="Write volume.vdb.")
    spacing: StrictFloat = Field(
        json_schema_extra={"unit": "m"},
        default=0.25, gt=0.0, description="Metres between probes (the lattice's voxel size)."
    )
    max_distance: Optional[StrictFloat] = Field(
        json_schema_extra={"unit": "m"},
        default=None,
        gt=0.0,
        description=(
            "Metres: only lattice points this close to a surface get a probe; null means"
            " 3 x spacing."
        ),
    )
    rays: StrictInt = Field(
        json_schema_extra={"unit": "directions per probe"},
        default=1024, ge=16, le=65536, description="Stratified directions per probe."
    )
    max_probes: StrictInt = Field(
        json_schema_extra={"unit": "probes"},
        default=2_000_000,
        ge=1,
        description="Refuse lattices with more candidate points than this (raise the spacing).",
    )


class PreviewOutputConfig(BaseModel):
    """A rendered preview image of the solved scene."""

    model_config = _MODEL_CONFIG

    enabled: StrictBool = Field(default=True, description="Render a preview image.")
    camera: Optional[StrictStr] = Field(
        default=None,
        description=(
            "USD prim path of the camera to render from, e.g. '/World/Camera';"
            " null uses the first camera in the scene, or a default view if it has none."
        ),
    )
    width: StrictInt = Field(
        default=512, ge=16, le=8192, description="Image width, in pixels.", json_schema_extra={"unit": "pixels"}
    )
    height: StrictInt = Field(
        default=512, ge=16, le=8192, description="Image height, in pixels.", json_schema_extra={"unit": "pixels"}
    )
    samples: StrictInt = Field(
        json_schema_extra={"unit": "samples per pixel"},
        default=4, ge=1, le=256, description="Anti-aliasing samples per pixel."
    )

    @field_validator("camera")
    @classmethod
    def _camera_is_prim_path(cls, value: Optional[str]) -> Optional[str]:
        if value is not None and not value.startswith("/"):
            raise ValueError(f"must be an absolute USD prim path starting with '/', got {value!r}")
        return value


class OutputsConfig(BaseModel):
    """What a bake writes into the output directory."""

    model_config = _MODEL_CONFIG

    usd: StrictBool = Field(
        default=True, description="Write a USD layer with radiosity as vertex primvars."
    )
    usd_view: Literal["solution", "source"] = Field(
        default="solution",
        description=(
            "What the USD layer shows: 'solution' hides the input's meshes and shows hirad's solved"
            " meshes (radiance primvars, the lightmaps through hirad:lightmapUV); 'source' keeps the"
            " input's meshes visible with their own materials (and the lightmap UV set an engine"
            " reads) and keeps the solved meshes as a hidden debug scope."
        ),
    )
    gltf: StrictBool = Field(
        default=False,
        description=(
            "Also write scene.glb (glTF 2.0): the input's meshes with their materials, TEXCOORD_1 ="
            " the lightmap UVs and the lightmap pages (needs usd and lightmaps)."
        ),
    )
    lightmaps: LightmapOutputConfig = Field(
        default_factory=LightmapOutputConfig, description="Lightmap texture settings."
    )
    volume: VolumeOutputConfig = Field(
        default_factory=VolumeOutputConfig, description="Irradiance volume settings."
    )
    preview: PreviewOutputConfig = Field(
        default_factory=PreviewOutputConfig, description="Preview image settings."
    )
    report: StrictBool = Field(
        default=True, description="Write a report of timings, statistics and settings."
    )

    @model_validator(mode="after")
    def _gltf_needs_its_sources(self) -> "OutputsConfig":
        if self.gltf and not (self.usd and self.lightmaps.enabled):
            raise ValueError("gltf: true needs usd: true and lightmaps.enabled: true (the GLB is written from "
                             "the solution layer and the lightmap pages)")
        return self


# --------------------------------------------------------------------------
# Daylight (hirad.daylight.sources reads this section)
# --------------------------------------------------------------------------

SKY_MODELS = ("usd", "cie_overcast", "cie_general", "perez", "uniform")
# sky models whose luminance follows the sun: they need daylight.site and daylight.time
_SUN_SKIES = ("cie_general", "perez")
DEFAULT_SKY_ILLUMINANCE = 10000.0  # lux: the CIE overcast design sky of daylight-factor studies
PATCHES_PATTERN = re.compile(r"^(tregenza|reinhart([1-9][0-9]?))$")
MAX_REINHART = 16


class DaylightSiteConfig(BaseModel):
    """Where the building is: for the sun's position (NREL SPA through pvlib) of sky models that
    follow the sun (cie_general, perez) and of a config sun."""

    model_config = _MODEL_CONFIG

    latitude: Optional[Annotated[float, Strict(), Field(ge=-90.0, le=90.0)]] = Field(
        default=None, json_schema_extra={"unit": "degrees"},
        description="Latitude in degrees, north positive, -90 to 90.",
    )
    longitude: Optional[Annotated[float, Strict(), Field(ge=-180.0, le=180.0)]] = Field(
        default=None, json_schema_extra={"unit": "degrees"},
        description="Longitude in degrees, east positive, -180 to 180.",
    )
    elevation: Annotated[float, Strict(), Field(ge=-500.0, le=9000.0)] = Field(
        default=0.0, json_schema_extra={"unit": "m"},
        description="Elevation above sea level in metres, -500 to 9000.",
    )
    timezone: Union[StrictFloat, StrictStr] = Field(
        default=0.0, json_schema_extra={"unit": "hours or zone name"},
        description=(
            "The time zone of daylight.time: a UTC offset in hours (-12 to 14; -7 = UTC-7) or an IANA"
            " zone name (Europe/Berlin: daylight saving time follows the date)."
        ),
    )

    @field_validator("timezone")
    @classmethod
    def _known_zone(cls, value):
        from hirad.daylight.sun import Site

        Site(0.0, 0.0, 0.0, value)  # raises ValueError naming the problem
        return value

    def located(self) -> bool:
        return self.latitude is not None and self.longitude is not None


class DaylightSkyConfig(BaseModel):
    """The sky: the scene's own DomeLight and DistantLight prims, or a sky model."""

    model_config = _MODEL_CONFIG

    model: Literal["usd", "cie_overcast", "cie_general", "perez", "uniform"] = Field(
        default="usd",
        description=(
            "'usd': the scene's DomeLight (uniform or latlong texture) and DistantLight prims (suns),"
            " by the UsdLux rules; 'cie_overcast': the traditional CIE overcast sky L = Lz (1 + 2 cos"
            " theta) / 3; 'cie_general': CIE general sky `type` 1-15 (ISO 15469), with the sun of"
            " daylight.site and daylight.time; 'perez': the Perez all-weather sky from `dni` and `dhi`"
            " with the sun of site and time (Perez 1990 luminous efficacy); 'uniform': a sky of one"
            " luminance. A sky model replaces the scene's DomeLight and DistantLight prims (named in a"
            " warning). Model values are photometric (cd/m^2, lux)."
        ),
    )
    type: Optional[Annotated[int, Strict(), Field(ge=1, le=15)]] = Field(
        default=None, description="The CIE general sky's type, 1-15 (model cie_general only; 12: CIE clear sky)."
    )
    zenith_luminance: Optional[NonNegative] = Field(
        default=None, json_schema_extra={"unit": "cd/m^2"},
        description=(
            "The zenith luminance Lz of a cie_overcast or cie_general sky, the luminance of a uniform"
            " sky. Not with `horizontal_illuminance`; neither: horizontal illuminance 10000 lux."
        ),
    )
    horizontal_illuminance: Optional[NonNegative] = Field(
        default=None, json_schema_extra={"unit": "lux"},
        description=(
            "The sky's illuminance on an unobstructed horizontal plane (without the sun), for"
            " cie_overcast, cie_general and uniform skies. Not with `zenith_luminance`."
        ),
    )
    dni: Optional[NonNegative] = Field(
        default=None, json_schema_extra={"unit": "W/m^2"},
        description="Direct normal irradiance (model perez only).",
    )
    dhi: Optional[Annotated[float, Strict(), Field(gt=0.0)]] = Field(
        default=None, json_schema_extra={"unit": "W/m^2"},
        description="Diffuse horizontal irradiance, > 0 (model perez only).",
    )
    dew_point: Optional[Annotated[float, Strict(), Field(ge=-100.0, le=60.0)]] = Field(
        default=None, json_schema_extra={"unit": "deg C"},
        description="Dew point for the Perez efficacy's precipitable water (model perez only; null: 2 cm of water).",
    )

    @model_validator(mode="after")
    def _consistent(self) -> "DaylightSkyConfig":
        m = self.model
        if self.zenith_luminance is not None and self.horizontal_illuminance is not None:
            raise ValueError("give zenith_luminance or horizontal_illuminance, not both")
        if m == "cie_general" and self.type is None:
            raise ValueError("model cie_general needs `type` (1-15)")
        if m != "cie_general" and self.type is not None:
            raise ValueError(f"`type` is for model cie_general, not {m}")
        if m == "perez":
            missing = [k for k in ("dni", "dhi") if getattr(self, k) is None]
            if missing:
                raise ValueError(f"model perez needs {' and '.join(missing)} (W/m^2)")
            if self.zenith_luminance is not None or self.horizontal_illuminance is not None:
                raise ValueError("model perez is absolute from dni and dhi: no zenith_luminance or "
                                 "horizontal_illuminance")
        else:
            given = [k for k in ("dni", "dhi", "dew_point") if getattr(self, k) is not None]
            if given:
                raise ValueError(f"{', '.join(given)}: only for model perez, not {m}")
        if m == "usd" and (self.zenith_luminance is not None or self.horizontal_illuminance is not None):
            raise ValueError("model usd takes the scene's lights as authored: no zenith_luminance or "
                             "horizontal_illuminance")
        return self


class DaylightSunConfig(BaseModel):
    """The sun: on or off, and how it is sampled."""

    model_config = _MODEL_CONFIG

    enabled: Optional[StrictBool] = Field(
        default=None,
        description=(
            "Sun on or off. null: as the sky says: model usd the scene's DistantLights, perez the sun of"
            " dni when it is above the horizon, cie_general a sun when `direct_normal_illuminance` is"
            " given, cie_overcast and uniform none. false: no sun (a daylight-factor study)."
        ),
    )
    direct_normal_illuminance: Optional[NonNegative] = Field(
        default=None, json_schema_extra={"unit": "lux"},
        description=(
            "The sun's illuminance on a plane facing it, for a sun with cie_general, cie_overcast or"
            " uniform skies (perez derives it from dni; usd from the DistantLight)."
        ),
    )
    angular_diameter: Optional[Annotated[float, Strict(), Field(ge=0.0, le=10.0)]] = Field(
        default=None, json_schema_extra={"unit": "degrees"},
        description=(
            "The sun disk's angular diameter (null: 0.53, the sun's; 0: parallel light). Not for model"
            " usd, where each DistantLight's inputs:angle gives it."
        ),
    )
    samples: Annotated[int, Strict(), Field(ge=1, le=1024)] = Field(
        default=16, json_schema_extra={"unit": "directions"},
        description="Directions spread over the sun's disk (stratified, equal solid angle each); 1 with angle 0.",
    )


class DaylightAnnualConfig(BaseModel):
    """Annual climate-based metrics from daylight coefficients (hirad.daylight.study)."""

    model_config = _MODEL_CONFIG

    weather: Path = Field(
        description=(
            "The weather file: EPW (EnergyPlus) or TMY3 CSV, hourly (relative to the config file's"
            " directory). Its site is the file's unless daylight.site gives one."
        ),
    )
    occupied_from: Annotated[float, Strict(), Field(ge=0.0, le=24.0)] = Field(
        default=8.0, json_schema_extra={"unit": "hour"}, description="Occupied hours start (IES LM-83: 8).")
    occupied_to: Annotated[float, Strict(), Field(ge=0.0, le=24.0)] = Field(
        default=18.0, json_schema_extra={"unit": "hour"}, description="Occupied hours end (IES LM-83: 18).")

    @field_validator("weather", mode="after")
    @classmethod
    def _weather_exists(cls, value: Path, info: ValidationInfo) -> Path:
        path = _absolute(value, info)
        if not path.is_file():
            raise ValueError(f"weather file not found: {path}")
        return path

    @model_validator(mode="after")
    def _hours(self) -> "DaylightAnnualConfig":
        if not self.occupied_from < self.occupied_to:
            raise ValueError(f"occupied_from ({self.occupied_from:g}) must be before occupied_to ({self.occupied_to:g})")
        return self


class DaylightConfig(BaseModel):
    """Daylight (hirad.daylight.sources): sun and sky as distant lights, seen through the scene's
    openings. World frame: the stage's up axis (upAxis Y or Z) is the zenith; `north` a direction
    perpendicular to it (default -Z for Y-up, +Y for Z-up, east = north x up = +X for both);
    azimuths run from north towards east (pvlib/SPA)."""

    model_config = _MODEL_CONFIG

    site: DaylightSiteConfig = Field(default_factory=DaylightSiteConfig,
                                     description="The site (for the sun's position).")
    time: Optional[StrictStr] = Field(
        default=None,
        description=(
            "The point in time: local date and time in ISO form (2024-06-21T12:00:00; a YAML timestamp"
            " too), in site.timezone unless it carries an offset."
        ),
    )
    sky: DaylightSkyConfig = Field(default_factory=DaylightSkyConfig, description="The sky model.")
    sun: DaylightSunConfig = Field(default_factory=DaylightSunConfig, description="The sun.")
    ground_reflectance: Annotated[float, Strict(), Field(ge=0.0, le=1.0)] = Field(
        default=0.2,
        description=(
            "Reflectance rho_g of the ground: below the horizon a uniform hemisphere of luminance"
            " rho_g E_h / pi, E_h the sky's and sun's horizontal illuminance (sky models; model usd when"
            " usd_ground is reflectance)."
        ),
    )
    usd_ground: Literal["dome", "reflectance"] = Field(
        default="dome",
        description=(
            "Below the horizon with model usd: 'dome' (UsdLux: a dome emits from every direction, its"
            " texture's lower half or its uniform luminance) or 'reflectance' (ground_reflectance)."
        ),
    )
    patches: StrictStr = Field(
        default="tregenza",
        description=(
            "The sky's discretisation: 'tregenza' (145 patches) or 'reinhartN' (Reinhart MF:N, 144 N^2"
            " + 1 patches; reinhart1 = tregenza), N 1-16; the ground mirrors it."
        ),
    )
    subdivisions: Annotated[int, Strict(), Field(ge=1, le=8)] = Field(
        default=2, json_schema_extra={"unit": "per patch side"},
        description=(
            "Sub-directions per patch: n x n cells of equal solid angle (3 n^2 for the zenith cap; n = 1:"
            " the patch centre)."
        ),
    )
    north: Optional[Vector3] = Field(
        default=None,
        description="World direction of north, made perpendicular to the up axis (null: -Z for Y-up, +Y for Z-up).",
    )
    daylight_factor: StrictBool = Field(
        default=False,
        description=(
            "Also give every grid as daylight factor DF = 100 E / E_h,out (E_h,out: the sky's illuminance on"
            " an unobstructed horizontal plane), in grids/daylight_factor/; needs a sky without a sun"
            " (the CIE overcast sky, sun.enabled false)."
        ),
    )
    annual: Optional[DaylightAnnualConfig] = Field(
        default=None,
        description=(
            "Annual metrics (DA300, sDA300/50%, ASE1000/250h, UDI, EN 17037) from daylight coefficients:"
            " every sky patch and the ground solved as a light group on the bake's links, the weather"
            " file's hourly skies by matrix products; in grids/annual/."
        ),
    )

    @field_validator("time", mode="before")
    @classmethod
    def _time_text(cls, value):
        import datetime as _dt

        if isinstance(value, _dt.datetime):
            return value.isoformat()
        if isinstance(value, _dt.date):
            raise ValueError(f"{value.isoformat()} is a date without a time of day; give both "
                             "(2024-06-21T12:00:00)")
        return value

    @field_validator("time")
    @classmethod
    def _time_iso(cls, value):
        import datetime as _dt

        if value is not None:
            try:
                _dt.datetime.fromisoformat(value)
            except ValueError:
                raise ValueError(f"{value!r} is not an ISO date and time (2024-06-21T12:00:00)") from None
        return value

    @field_validator("sky")
    @classmethod
    def _sky_sun_position(cls, value: DaylightSkyConfig, info: ValidationInfo):
        if value.model in _SUN_SKIES:
            site = info.data.get("site")
            missing = []
            if site is not None and not site.located():
                missing.append("daylight.site.latitude and longitude")
            if "time" in info.data and info.data.get("time") is None:
                missing.append("daylight.time")
            if missing:
                raise ValueError(f"model {value.model} follows the sun: it needs {' and '.join(missing)}")
        return value

    @field_validator("sun")
    @classmethod
    def _sun_source(cls, value: DaylightSunConfig, info: ValidationInfo):
        sky = info.data.get("sky")
        if sky is None:
            return value
        m = sky.model
        if value.direct_normal_illuminance is not None and m in ("usd", "perez"):
            raise ValueError(f"direct_normal_illuminance: model {m} gives the sun's illuminance "
                             f"({'the DistantLight' if m == 'usd' else 'K_b x dni'})")
        if value.angular_diameter is not None and m == "usd":
            raise ValueError("angular_diameter: with model usd each DistantLight's inputs:angle gives it")
        if value.enabled and m in ("cie_overcast", "cie_general", "uniform"):
            if value.direct_normal_illuminance is None:
                raise ValueError(f"a sun with model {m} needs direct_normal_illuminance (lux)")
            site = info.data.get("site")
            if (site is not None and not site.located()) or info.data.get("time") is None:
                raise ValueError("a sun needs daylight.site (latitude, longitude) and daylight.time for its position")
        if value.enabled is None and value.direct_normal_illuminance is not None and m in ("cie_overcast", "uniform"):
            site = info.data.get("site")
            if (site is not None and not site.located()) or info.data.get("time") is None:
                raise ValueError("a sun needs daylight.site (latitude, longitude) and daylight.time for its position")
        return value

    @field_validator("patches")
    @classmethod
    def _patches_name(cls, value: str) -> str:
        m = PATCHES_PATTERN.match(value)
        if m is None or (m.group(2) is not None and not 1 <= int(m.group(2)) <= MAX_REINHART):
            raise ValueError(f"{value!r}: use 'tregenza' or 'reinhartN' with N 1-{MAX_REINHART} (reinhart2: 577 "
                             "patches)")
        return value

    @field_validator("north")
    @classmethod
    def _north_not_zero(cls, value):
        if value is not None and not any(value):
            raise ValueError("north must be a non-zero direction")
        return value

    def reinhart_mf(self) -> int:
        """The Reinhart subdivision MF of `patches` (tregenza: 1)."""
        m = PATCHES_PATTERN.match(self.patches)
        return 1 if m is None or m.group(2) is None else int(m.group(2))


class Config(BaseModel):
    """A complete hirad configuration.

    Build one with :func:`load_config` or :func:`config_from_dict`.  Fields may
    be assigned afterwards (``cfg.threads = 4``) and are validated again, but a
    relative path assigned that way resolves against the current directory.
    """

    model_config = _MODEL_CONFIG

    scene: Path = Field(
        description="USD scene to light (relative to the config file's directory); must exist.",
    )
    output: Path = Field(
        default=None,
        validate_default=True,
        description=(
            "Output directory (relative to the config file's directory);"
            " omitted or null means <config dir>/out/<config file stem>."
        ),
    )
    threads: StrictInt = Field(
        json_schema_extra={"unit": "threads"},
        default=0, ge=0, le=MAX_THREADS, description=f"Worker threads; 0 uses all cores (at most {MAX_THREADS})."
    )
    seed: StrictInt = Field(
        default=1,
        ge=0,
        le=UINT64_MAX,
        description="Random seed for all sampling, 0 to 2^64-1; equal seeds give equal results.",
    )
    materials: MaterialsConfig = Field(
        default_factory=MaterialsConfig, description="Material settings."
    )
    meshing: MeshingConfig = Field(default_factory=MeshingConfig, description="Patch subdivision.")
    formfactors: FormFactorConfig = Field(
        default_factory=FormFactorConfig, description="Form factor computation."
    )
    method: Literal["flat", "hierarchical"] = Field(
        default="hierarchical",
        description=(
            "'hierarchical' (the default, the production method): adaptive elements and cluster"
            " links from `hierarchy`; 'flat': patches from `meshing`, every pair linked (the classic"
            " method, kept as the reference)."
        ),
    )
    hierarchy: HierarchyConfig = Field(
        default_factory=HierarchyConfig, description="Hierarchical radiosity settings."
    )
    solver: SolverConfig = Field(default_factory=SolverConfig, validate_default=True, description="Radiosity solver.")
    links: LinksConfig = Field(default_factory=LinksConfig, description="Out-of-core link store.")
    reconstruction: ReconstructionConfig = Field(
        default_factory=ReconstructionConfig, description="Smoothing of patch radiosity."
    )
    outputs: OutputsConfig = Field(default_factory=OutputsConfig, description="What to write.")
    grids: dict[StrictStr, GridSpec] = Field(
        default_factory=dict,
        description=(
            "Calculation grids evaluated after the solve (hirad.studies.spec: workplane, corridor,"
            " rectangle, points), by name (letters, digits, _ . -; the name names the files in"
            " OUT/grids/). Each point's illuminance is computed at the point itself (direct light"
            " of the emitters exactly, indirect light gathered from the solution), as Rec.709 Y."
            " A points grid's `file` is relative to the config file's directory."
        ),
    )
    grid_rays: Annotated[int, Strict(), Field(ge=16, le=1_000_000)] = Field(
        default=512,
        description=(
            "Hemisphere rays per grid point for the grids' indirect light (stratified, cosine"
            " distributed; the direct light of emitters and luminaires is exact whatever this is)."
            " The indirect part's noise falls as 1/sqrt(rays)."
        ),
    )
    maintenance_factor: Annotated[float, Strict(), Field(gt=0.0, le=1.0)] = Field(
        default=1.0,
        description=(
            "Maintenance factor MF in (0, 1] of the grids: maintained illuminance = MF x the"
            " illuminance of the new installation (EN 12464-1; 1.0 reports the new values)."
        ),
    )
    photometry: PhotometryConfig = Field(
        default_factory=PhotometryConfig, description="Luminaire photometry: how IES files are read."
    )
    lights: list[LightConfig] = Field(
        default_factory=list,
        description=(
            "Point lights added to the scene's own: each `name`, `position` [m], `intensity` [cd] or"
            " `flux` [lm], `colour`, optional `ies` file (relative to the config file's directory)"
            " with `ies_mode`, aimed by `aim` (nadir direction) and `c0` (C0 direction) or by"
            " `rotation` (rotateXYZ, degrees); see hirad.photometry.luminaires."
        ),
    )
    light_groups: dict[StrictStr, LightGroupConfig] = Field(
        default_factory=dict,
        description=(
            "Written `lights: {points: [...], groups: {NAME: {...}}}` in a config (a plain list under"
            " `lights` is the points alone): light groups by prim path pattern, collection or one per"
            " light (`each: true`), each with a `dimmer` and an optional `color`; emitters in no group"
            " form the group `rest`. Each group is solved alone on the shared links and stored, so"
            " `hirad relight` changes dimmers and colours without solving."
        ),
    )
    daylight: DaylightConfig = Field(
        default_factory=DaylightConfig,
        description=(
            "Sun and sky (hirad.daylight.sources): the scene's DomeLight and DistantLight (sky.model"
            " usd, the default) or a CIE, Perez or uniform sky with a sun from site and time, sampled"
            " as sky patches and a ground of ground_reflectance."
        ),
    )
    units: Literal["photometric", "radiometric"] = Field(
        default="photometric",
        description=(
            "How the grids and the study report name the numbers: photometric (exitance lm/m^2,"
            " illuminance lux, luminance cd/m^2) or radiometric (the same numbers as W/m^2 and"
            " W/(m^2 sr)). Grids report Y = 0.2126 R + 0.7152 G + 0.0722 B of the linear RGB."
        ),
    )

    @model_validator(mode="before")
    @classmethod
    def _lights_mapping(cls, data: Any) -> Any:
        # `lights: {points: [...], groups: {...}}`: the points stay `lights`, the groups become
        # `light_groups` (errors are located under lights.groups by the loader).
        if isinstance(data, dict) and isinstance(data.get("lights"), dict):
            given = dict(data["lights"])
            extra = sorted(set(given) - {"points", "groups"})
            if extra:
                raise ValueError(f"lights: unknown key {extra[0]!r}; expected a list of point lights, or a "
                                 "mapping of `points` (the list) and `groups`")
            data = dict(data)
            data["lights"] = given.get("points") if given.get("points") is not None else []
            if "light_groups" in data:
                raise ValueError("give the light groups as lights.groups only")
            if given.get("groups") is not None:
                data["light_groups"] = given["groups"]
        return data

    @field_validator("light_groups", mode="after")
    @classmethod
    def _group_names(cls, value: dict) -> dict:
        for name in value:
            if not LIGHT_GROUP_NAME.match(name):
                raise ValueError(f"light group name {name!r}: use letters, digits, '_' and '-' (it names "
                                 "primvars and relight keys)")
            if name == REST_GROUP:
                raise ValueError(f"light group name {name!r} is reserved for the emitters in no group")
        return value

    @field_validator("grids", mode="after")
    @classmethod
    def _grid_files(cls, value: dict, info: ValidationInfo) -> dict:
        out = {}
        for name, spec in value.items():
            if not _GRID_NAME.match(name):
                raise ValueError(f"grid name {name!r}: use letters, digits, '_', '.' and '-' (it names files)")
            if isinstance(spec, PointsGrid):
                spec = spec.model_copy(update={"file": str(_absolute(Path(spec.file), info))})
            out[name] = spec
        return out

    @field_validator("lights", mode="after")
    @classmethod
    def _light_files(cls, value: list, info: ValidationInfo) -> list:
        seen: set[str] = set()
        out = []
        for i, light in enumerate(value):
            if light.name in seen:
                raise ValueError(f"lights[{i}]: the name {light.name!r} is given twice")
            seen.add(light.name)
            if light.ies is not None:
                light = light.model_copy(update={"ies": _absolute(Path(light.ies), info)})
            out.append(light)
        return out

    @field_validator("scene", mode="after")
    @classmethod
    def _scene_exists(cls, value: Path, info: ValidationInfo) -> Path:
        path = _absolute(value, info)
        if not path.exists():
            raise ValueError(f"scene file not found: {path}")
        if not path.is_file():
            raise ValueError(f"scene is not a file: {path}")
        return path

    @field_validator("solver", mode="after")
    @classmethod
    def _hierarchical_solver(cls, value: SolverConfig, info: ValidationInfo) -> SolverConfig:
        # On the hierarchy: gathering (Jacobi, Gauss-Seidel) or shooting (Southwell), with push-pull.
        hierarchical = ("jacobi", "gauss_seidel", "southwell", "block_southwell")
        if info.data.get("method") == "hierarchical" and value.method not in hierarchical:
            raise ValueError(
                "method: hierarchical solves with solver.method jacobi, gauss_seidel, southwell"
                f" (with push-pull) or block_southwell (out of core), not {value.method!r}"
            )
        if info.data.get("method") == "flat" and value.method == "block_southwell":
            raise ValueError("solver.method block_southwell streams hierarchical links: set method: hierarchical")
        hierarchy = info.data.get("hierarchy")
        if (info.data.get("method") == "hierarchical" and hierarchy is not None and hierarchy.cluster_receivers
                and value.method in ("gauss_seidel", "southwell")):
            raise ValueError(
                f"hierarchy.cluster_receivers: links that end on clusters are solved by solver.method jacobi or"
                f" block_southwell; {value.method!r} works face by face (it is also the default: set"
                " solver.method)"
            )
        return value

    @field_validator("outputs", mode="after")
    @classmethod
    def _gather_needs_hierarchy(cls, value, info: ValidationInfo):
        if value.lightmaps.enabled and value.lightmaps.mode == "final_gather" and info.data.get("method") != "hierarchical":
            raise ValueError("outputs.lightmaps.mode: final_gather needs method: hierarchical (the gather re-evaluates"
                             " the hierarchy's links); use mode: interpolate for flat bakes")
        return value

    def ignored_settings(self) -> list[str]:
        """Sections given in the config that the chosen method does not read, each with why (for
        a warning): `meshing` and `formfactors` under method: hierarchical (the default since
        it became the production method, so a config written for the flat method that does not
        say `method: flat` lands here), `hierarchy` under method: flat, `links` unless
        solver.method is block_southwell."""
        given = self.model_fields_set
        out = []
        how = "method: hierarchical" + ("" if "method" in given else " (the default)")
        if self.method == "hierarchical":
            for key in ("meshing", "formfactors"):
                if key in given:
                    out.append(f"{key}: not used by {how}; set method: flat to use it")
        else:
            if "hierarchy" in given:
                out.append("hierarchy: not used by method: flat")
        if "links" in given and self.solver.method != "block_southwell":
            out.append("links: only used by solver.method: block_southwell")
        for key in ("grid_rays", "maintenance_factor"):
            if key in given and not self.grids:
                out.append(f"{key}: only used by grids (none given)")
        return out

    def link_store(self) -> Path:
        """Where an out-of-core bake keeps its links."""
        return self.links.store or self.output.parent / (self.output.name + ".links")

    @field_validator("output", mode="before")
    @classmethod
    def _default_output(cls, value: Any, info: ValidationInfo) -> Any:
        if value is not None:
            return value
        context = info.context or {}
        name = context.get("name")
        if not name:
            scene = info.data.get("scene")
            name = Path(scene).stem if isinstance(scene, Path) else "hirad"
        return _base_dir(info) / "out" / name

    @field_validator("output", mode="after")
    @classmethod
    def _absolute_output(cls, value: Path, info: ValidationInfo) -> Path:
        return _absolute(value, info)

    def fingerprint(self) -> str:
        """SHA-256 (hex) of the canonical JSON form of every setting.

        Independent of key order and formatting in the YAML file; paths enter
        as the absolute paths stored in the model.
        """
        canonical = json.dumps(
            self.model_dump(mode="json"),
            sort_keys=True,
            separators=(",", ":"),
            ensure_ascii=False,
            allow_nan=False,
        )
        return hashlib.sha256(canonical.encode("utf-8")).hexdigest()

    def content_key(self) -> str:
        """SHA-256 (hex) of what determines the bake's result: the scene files' contents and
        the settings, not the output path, the thread count or where links are kept
        (hirad.config.content)."""
        from .content import content_key

        return content_key(self)

    def thread_count(self) -> int:
        """The number of worker threads to use: ``threads``, or all cores if 0."""
        return self.threads or (os.cpu_count() or 1)


def _base_dir(info: ValidationInfo) -> Path:
    context = info.context or {}
    base = context.get("base_dir")
    return Path(base) if base is not None else Path.cwd()


def _absolute(value: Path, info: ValidationInfo) -> Path:
    path = value.expanduser()
    if not path.is_absolute():
        path = _base_dir(info) / path
    return Path(os.path.normpath(path.absolute()))
