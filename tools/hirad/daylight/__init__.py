"""Daylight for hirad (issue 16), pure Python: sky luminance models (CIE general skies,
traditional CIE overcast, Perez all-weather with Perez 1990 luminous efficacy), sky patches
(Tregenza, Reinhart MF:n) and the ground, sun position (NREL SPA via pvlib) and weather files
(EPW, TMY3 via pvlib). See docs/daylight.md.

Submodules are imported on use: ``from hirad.daylight import skies, patches, sun, weather``.
"""
