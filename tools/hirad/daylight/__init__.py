"""Daylight for hirad: sun and sky as distant lights, glazing, daylight factor and annual
climate-based metrics (README, "Daylight"). The modules, in the order data flows:

* ``skies``: sky luminance models (the 15 CIE general skies, the traditional CIE overcast sky,
  Perez all-weather with Perez 1990 luminous efficacy, uniform);
* ``patches``: Tregenza and Reinhart MF:n sky patches, their solid angles and mean luminance;
* ``sun``: the sun's position (NREL SPA via pvlib); ``weather``: EPW and TMY3 files (pvlib);
* ``sources``: UsdLux DomeLight/DistantLight and the config's sky as the engine's distant lights;
* ``glazing``: clear glass's angular transmittance (Tregenza-Sharples);
* ``coefficients``: daylight coefficients at grid sensors from light-group solutions;
* ``annual``: hourly sky matrices and the annual metrics (DA, sDA, ASE, UDI, EN 17037);
* ``study``: what a bake writes (daylight factor grids, the annual study).

Submodules are imported on use: ``from hirad.daylight import skies, patches, sun, weather``.
"""
