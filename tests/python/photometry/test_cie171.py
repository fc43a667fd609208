"""CIE 171:2006 ("Test cases to assess the accuracy of lighting computer programs") analytical
test cases, engine level (issue 13): scenes built in code (cie171_scenes.py), solved by the
engine, illuminance read by SurfaceField.illuminance or from the solve's per-patch
irradiance. Expected values are the report's published figures or closed forms, never
hirad's output. Values are photometric Y of RGB (white light: every channel equal).

Elsewhere: 5.2 and 5.4 (point sources: luminaires) in test_luminaire_engine.py; 5.6 and 5.7
in test_cie171_56_57.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

pytest.importorskip("hirad._engine")

import cie171_scenes as cie  # noqa: E402


@pytest.fixture(scope="module")
def case_53():
    return cie.run_case_53()


def test_5_3_area_source_in_a_black_room_matches_the_published_table(case_53):
    """5.3: black 4 x 4 x 3 m room (reflectance 0), a 1 x 1 m Lambertian panel of 1000 cd/m^2
    at the ceiling's centre facing down. Wall y = 0 at x = 2, z = 2.75 ... 0.25 (A-F, facing
    +y); floor at x = 2, y = 0.25 ... 3.75 (G-N, facing +z). Sensors sit 1 mm off their
    surface, into the room (the published points are on it; by Lambert's formula 1 mm moves
    the values by 0.02-0.15 %, most at A, nearest the ceiling). Within 1 % of the CIE
    171:2006 table; nothing is reflected, so the indirect part is zero."""
    for name, expected, got, _direct, indirect in case_53:
        assert got == pytest.approx(expected, rel=0.01), name
        assert abs(indirect) < 1e-9 * expected, name


def test_5_3_is_symmetric_about_the_room_centre(case_53):
    """The floor row is symmetric about y = 2 (G/N, H/M, I/L, J/K), as the table is."""
    got = {name: value for name, _e, value, _d, _i in case_53}
    for a, b in (("G", "N"), ("H", "M"), ("I", "L"), ("J", "K")):
        assert got[a] == pytest.approx(got[b], rel=1e-6)


def test_illuminance_on_the_axis_of_a_square_panel_matches_lamberts_closed_form():
    """Free space: one 1 x 1 m panel of 1000 cd/m^2, sensors on its axis facing it at
    h = 0.05 ... 4 m. E = 4 L s atan(s), s = a / (2 sqrt(a^2/4 + h^2)) (four corner
    rectangles, Lambert's differential-to-rectangle form factor; see
    cie171_scenes.square_axis_illuminance). Within 0.5 %."""
    for h, expected, got in cie.run_free_square():
        assert got == pytest.approx(expected, rel=0.005), h


@pytest.mark.parametrize("method", ["flat", "hierarchical"])
@pytest.mark.parametrize("rho", cie.REFLECTANCES_58)
def test_5_8_mean_illuminance_of_a_closed_cube(rho, method):
    """5.8 (interreflections): a closed 4 x 4 x 4 m cube (A_T = 96 m^2), every surface a
    uniform diffuser of reflectance rho, lit by a 1 x 1 m panel (A_e) of L = 1000 cd/m^2 at
    the ceiling's centre. The area-weighted mean illuminance over all surfaces is checked.

    Derivation. The enclosure is closed, so all flux leaving any surface lands on some
    surface. Let Phi = pi L A_e be the emitted flux and Phi_in the total flux incident on all
    surfaces. What leaves the surfaces is Phi plus the reflected rho Phi_in, and all of it is
    incident: Phi_in = Phi + rho Phi_in, so Phi_in = Phi / (1 - rho) and the mean
    illuminance is E_mean = Phi_in / A_T = Phi / (A_T (1 - rho)), whatever the geometry.
    This needs every surface, the panel too, to reflect rho, which is how the scene is
    built (the panel emits and reflects). With a black panel instead, Phi_in = (Phi - rho
    Phi_e) / (1 - rho) with Phi_e the flux landing on the panel, which depends on the
    geometry (no closed form); under the integrating-sphere assumption of uniform
    irradiance it is E_mean = Phi / (A_T (1 - rho) + rho A_e), 1 % or less away here.

    The mean is read from the solve's per-patch irradiance H (flat: engine.transport; the
    hierarchical solve: its per-leaf irradiance) weighted by patch area. Within 1 % for
    every rho, flat and hierarchical."""
    expected, got, _patches = cie.run_case_58(rho, method)
    assert expected == pytest.approx(cie.case_58_expected(rho))
    assert got == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("rho", [0.25, 0.5, 0.75])
def test_5_8_mean_of_the_illuminance_binding_over_the_cube_loosely(rho):
    """The same closed-form mean read through SurfaceField.illuminance instead of the
    solve's H: one sensor 1 mm off each flat patch's centroid (384, 0.5 m patches), direct
    (exact contour integrals of the panel) plus indirect (256 hemisphere rays over the
    flat-shaded radiosity), averaged by patch area. The patch-centre sampling is a midpoint
    rule, so only within 2 %."""
    expected, got, _sensors = cie.run_case_58_sensors(rho)
    assert got == pytest.approx(expected, rel=0.02)
