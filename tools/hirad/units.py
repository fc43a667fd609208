"""The two readings of hirad's numbers, and the labels every output carries.

hirad carries linear Rec.709 RGB throughout; the numbers are the same in both unit systems,
only their reading differs (the config's ``units``):

* ``photometric`` (the default, UsdLux physical-lighting semantics of OpenUSD 25.05+): a
  light's intensity x 2^exposure x color is a luminance in cd/m^2 (nits); radiosity and
  emission are luminous exitance in lm/m^2, irradiance is illuminance in lux (lm/m^2),
  radiance is luminance in cd/m^2, luminaire intensities are in cd and fluxes in lm. The
  photometric value of an RGB triple is its Rec.709 luminance Y = 0.2126 R + 0.7152 G +
  0.0722 B (white light: R = G = B = Y).
* ``radiometric``: the same numbers as W/m^2 (exitance, irradiance), W/(m^2 sr) (radiance),
  W/sr and W, per channel.
"""

from __future__ import annotations

UNIT_SYSTEMS = ("photometric", "radiometric")
Y_WEIGHTS = (0.2126, 0.7152, 0.0722)

_LABELS = {
    "photometric": {
        "radiance": "luminance cd/m^2",
        "irradiance": "illuminance lx (lm/m^2)",
        "exitance": "luminous exitance lm/m^2",
        "incident": "incident luminance H/pi, cd/m^2 (illuminance lx / pi)",
        "flux": "luminous flux lm",
        "intensity": "luminous intensity cd",
    },
    "radiometric": {
        "radiance": "radiance W/(m^2 sr)",
        "irradiance": "irradiance W/m^2",
        "exitance": "exitance W/m^2",
        "incident": "incident radiance H/pi, W/(m^2 sr)",
        "flux": "power W",
        "intensity": "radiant intensity W/sr",
    },
}


def label(units: str, quantity: str) -> str:
    """The label of `quantity` (radiance, irradiance, exitance, incident, flux, intensity) in
    the unit system `units`, e.g. label("photometric", "irradiance") = "illuminance lx (lm/m^2)"."""
    if units not in _LABELS:
        raise ValueError(f"units must be one of {', '.join(UNIT_SYSTEMS)}, not {units!r}")
    return _LABELS[units][quantity]


def layer_units(units: str) -> str:
    """The solution layer's hirad:units text."""
    return f"{label(units, 'radiance')}, {label(units, 'irradiance')}, emission {label(units, 'exitance')} (RGB, Y = Rec.709 luminance)"
