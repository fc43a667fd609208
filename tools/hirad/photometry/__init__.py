"""Photometry: luminaire intensity distributions (IES LM-63 files) and what follows from them.

``hirad.photometry.ies`` reads every LM-63 version, evaluates the candela distribution in the
light's local frame, integrates its flux and reports beam and field angles; see its docstring
for the axes, the versions and the interpolation.
"""

from __future__ import annotations

from .ies import (
    IesError,
    IesWarning,
    Opening,
    Photometry,
    PlaneAngles,
    Tilt,
    angles_to_direction,
    beam_field_angles,
    candela,
    direction_to_angles,
    ies_command,
    lumens,
    parse_ies,
    peak_candela,
    polar_plot,
    read_ies,
)

__all__ = [
    "IesError",
    "IesWarning",
    "Opening",
    "Photometry",
    "PlaneAngles",
    "Tilt",
    "angles_to_direction",
    "beam_field_angles",
    "candela",
    "direction_to_angles",
    "ies_command",
    "lumens",
    "parse_ies",
    "peak_candela",
    "polar_plot",
    "read_ies",
]
