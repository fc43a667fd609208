"""The scene is checked when it is read: physically invalid values are errors naming the file,
the prim and the attribute; what hirad clamps or does not honour is named in a warning.

Each test writes the bad input as USD text (the way a user's file would carry it) and checks
the message names the place and the value, and that a good neighbour of the same scene is
still read correctly.
"""

from __future__ import annotations

import math
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pxr")

REPO = Path(__file__).resolve().parents[3]
if str(REPO / "tools") not in sys.path:
    sys.path.insert(0, str(REPO / "tools"))

from hirad import usd as hu  # noqa: E402

QUAD = """
def Mesh "{name}" {{
    point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    {extra}
}}
"""


def quad(name="floor", extra=""):
    return QUAD.format(name=name, extra=extra)


def material(name, diffuse=None, emissive=None):
    inputs = ""
    if diffuse is not None:
        inputs += f"color3f inputs:diffuseColor = {diffuse}\n"
    if emissive is not None:
        inputs += f"color3f inputs:emissiveColor = {emissive}\n"
    return f"""
def Material "{name}" {{
    token outputs:surface.connect = </{name}/Surface.outputs:surface>
    def Shader "Surface" {{
        uniform token info:id = "UsdPreviewSurface"
        {inputs}
        token outputs:surface
    }}
}}
"""


def bound(mat):
    return f"rel material:binding = </{mat}>"


def write(tmp_path: Path, body: str, name="scene.usda", meta='metersPerUnit = 1\n    upAxis = "Z"') -> Path:
    path = tmp_path / name
    path.write_text(f"#usda 1.0\n(\n    {meta}\n)\n" + textwrap.dedent(body))
    return path


def scene_error(path: Path, **kw) -> str:
    with pytest.raises(hu.SceneError) as info:
        hu.read_scene(path, **kw)
    return str(info.value)


def light(kind="RectLight", name="lamp", attrs="float inputs:width = 1\n    float inputs:height = 1",
          schemas=""):
    meta = f'(\n    prepend apiSchemas = [{schemas}]\n)' if schemas else ""
    return f"""
def {kind} "{name}" {meta}
{{
    {attrs}
    double3 xformOp:translate = (0.5, 0.5, 2)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""


def mesh_of(scene, path):
    return [k for k, m in enumerate(scene.meshes) if m.path == path][0]


# --------------------------------------------------------------------------------------------
# lights: intensity, exposure, colour
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("value, words", [("-2", "-2"), ("nan", "nan"), ("inf", "inf")])
def test_bad_light_intensity_is_an_error_naming_prim_and_attribute(tmp_path, value, words):
    path = write(tmp_path, quad() + light(attrs=f"float inputs:width = 1\n float inputs:height = 1\n"
                                                f" float inputs:intensity = {value}"))
    msg = scene_error(path)
    assert msg.startswith(str(path) + ": ")
    assert "/lamp.inputs:intensity" in msg and words in msg


@pytest.mark.parametrize("exposure", [1000, 120])
def test_exposure_so_large_the_radiance_is_infinite_is_an_error(tmp_path, exposure):
    # 2^1000 is still finite in double precision (1.1e301), but not as the 32-bit floats of
    # the solution, and the solver's norms square it; 2^120 = 1.3e36 is beyond the 1e30 bound.
    path = write(tmp_path, quad() + light(attrs="float inputs:width = 1\n float inputs:height = 1\n"
                                                f" float inputs:exposure = {exposure}"))
    msg = scene_error(path)
    assert "/lamp.inputs:exposure" in msg and f"2^{exposure}" in msg and "finite" in msg


def test_large_but_finite_exposure_is_read_as_two_to_the_exposure(tmp_path):
    # 2^60 x intensity 3 = 3.5e18 is within the bound: it is kept, and it is what the light
    # emits (M = pi L).
    path = write(tmp_path, quad() + light(attrs="float inputs:width = 1\n float inputs:height = 1\n"
                                                " float inputs:exposure = 60\n float inputs:intensity = 3"))
    scene = hu.read_scene(path)
    k = mesh_of(scene, "/lamp")
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k][0], [math.pi * 3 * 2.0**60] * 3,
                               rtol=1e-12)


@pytest.mark.parametrize("colour", ["(1, nan, 1)", "(1, -0.5, 1)"])
def test_bad_light_colour_is_an_error(tmp_path, colour):
    path = write(tmp_path, quad() + light(attrs="float inputs:width = 1\n float inputs:height = 1\n"
                                                f" color3f inputs:color = {colour}"))
    msg = scene_error(path)
    assert "/lamp.inputs:color" in msg


def test_mesh_light_with_negative_intensity_is_an_error(tmp_path):
    path = write(tmp_path, quad() + quad("panel", "float inputs:intensity = -1").replace(
        'def Mesh "panel"', 'def Mesh "panel" (prepend apiSchemas = ["MeshLightAPI"])'))
    msg = scene_error(path)
    assert "/panel.inputs:intensity" in msg and "-1" in msg


def test_light_width_of_the_wrong_type_is_an_error(tmp_path):
    path = write(tmp_path, quad() + light(attrs='string inputs:width = "wide"\n float inputs:height = 1'))
    msg = scene_error(path)
    assert "/lamp.inputs:width" in msg and "string" in msg


# --------------------------------------------------------------------------------------------
# materials: reflectance and emission
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("diffuse, words", [("(0.5, -0.5, 0.5)", "negative"), ("(0.5, nan, 0.5)", "not finite")])
def test_bad_diffuse_color_is_an_error(tmp_path, diffuse, words):
    path = write(tmp_path, material("Mat", diffuse=diffuse) + quad(extra=bound("Mat")))
    msg = scene_error(path)
    assert "/Mat/Surface.inputs:diffuseColor" in msg and words in msg


def test_diffuse_above_the_maximum_is_clamped_with_a_warning(tmp_path):
    path = write(tmp_path, material("Mat", diffuse="(1.5, 0.25, 1)") + quad(extra=bound("Mat")))
    scene = hu.read_scene(path)
    np.testing.assert_allclose(scene.face_reflectance[0], [0.999, 0.25, 0.999], rtol=1e-6)
    hits = [w for w in scene.warnings if "/Mat/Surface.inputs:diffuseColor" in w]
    assert len(hits) == 1 and "1.5" in hits[0] and "clamped to 0.999" in hits[0]


def test_reflectance_within_range_gives_no_warning(tmp_path):
    path = write(tmp_path, material("Mat", diffuse="(0.9, 0.25, 0)") + quad(extra=bound("Mat")))
    scene = hu.read_scene(path)
    np.testing.assert_allclose(scene.face_reflectance[0], [0.9, 0.25, 0.0], rtol=1e-6)
    assert scene.warnings == []


@pytest.mark.parametrize("emissive, words", [("(1, -2, 1)", "negative"), ("(inf, 1, 1)", "not finite"),
                                             ("(1e35, 1, 1)", "beyond")])
def test_bad_emissive_color_is_an_error(tmp_path, emissive, words):
    path = write(tmp_path, material("Glow", emissive=emissive) + quad(extra=bound("Glow")))
    msg = scene_error(path)
    assert "/Glow/Surface.inputs:emissiveColor" in msg and words in msg


def test_negative_display_color_is_an_error(tmp_path):
    path = write(tmp_path, quad(extra="color3f[] primvars:displayColor = [(0.5, -0.1, 0.5)]"))
    msg = scene_error(path)
    assert "/floor.primvars:displayColor" in msg and "negative" in msg


def test_display_color_above_the_maximum_is_clamped_with_a_warning(tmp_path):
    path = write(tmp_path, quad(extra="color3f[] primvars:displayColor = [(2, 0.5, 0.5)]"))
    scene = hu.read_scene(path)
    np.testing.assert_allclose(scene.face_reflectance[0], [0.999, 0.5, 0.5], rtol=1e-6)
    assert any("/floor.primvars:displayColor" in w and "clamped" in w for w in scene.warnings)


def test_unused_display_color_is_not_checked(tmp_path):
    # the bound material decides; the displayColor beneath it is not read
    path = write(tmp_path, material("Mat", diffuse="(0.3, 0.3, 0.3)")
                 + quad(extra=bound("Mat") + "\n color3f[] primvars:displayColor = [(-1, 5, 0)]"))
    scene = hu.read_scene(path)
    np.testing.assert_allclose(scene.face_reflectance[0], [0.3] * 3, rtol=1e-6)


def test_wrong_sized_display_color_is_named_in_a_warning(tmp_path):
    # uniform needs one value per face (1 face here): two values, the first is used
    path = write(tmp_path, quad(extra='color3f[] primvars:displayColor = [(0.2, 0.2, 0.2), (0.8, 0.8, 0.8)] (\n'
                                      '        interpolation = "uniform"\n    )'))
    scene = hu.read_scene(path)
    hits = [w for w in scene.warnings if "/floor.primvars:displayColor" in w]
    assert len(hits) == 1 and "2 values" in hits[0] and "needs 1" in hits[0]
    np.testing.assert_allclose(scene.face_reflectance[0], [0.2] * 3, rtol=1e-6)


def test_too_short_vertex_display_color_is_not_used_and_named(tmp_path):
    path = write(tmp_path, quad(extra='color3f[] primvars:displayColor = [(0.2, 0.2, 0.2), (0.8, 0.8, 0.8)] (\n'
                                      '        interpolation = "vertex"\n    )'))
    scene = hu.read_scene(path, default_reflectance=(0.1, 0.2, 0.3))
    hits = [w for w in scene.warnings if "/floor.primvars:displayColor" in w]
    assert len(hits) == 1 and "2 values" in hits[0] and "needs 4" in hits[0] and "not used" in hits[0]
    np.testing.assert_allclose(scene.face_reflectance[0], [0.1, 0.2, 0.3])


def test_display_color_of_the_wrong_type_is_an_error(tmp_path):
    path = write(tmp_path, quad(extra="float[] primvars:displayColor = [0.5, 0.5]"))
    msg = scene_error(path)
    assert "/floor.primvars:displayColor" in msg and "float[]" in msg and "color3f[]" in msg


# --------------------------------------------------------------------------------------------
# geometry, units and axes
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mpu", ["0", "-1", "nan", "inf"])
def test_meters_per_unit_not_positive_and_finite_is_an_error(tmp_path, mpu):
    path = write(tmp_path, quad(), meta=f'metersPerUnit = {mpu}\n    upAxis = "Z"')
    msg = scene_error(path)
    assert msg.startswith(str(path)) and "metersPerUnit" in msg


def test_huge_meters_per_unit_is_an_error_with_the_numbers(tmp_path):
    path = write(tmp_path, quad(), meta='metersPerUnit = 1e30\n    upAxis = "Z"')
    msg = scene_error(path)
    assert "metersPerUnit = 1e+30" in msg and "1e+15" in msg


def test_coordinates_beyond_the_bound_are_an_error_naming_the_prim(tmp_path):
    body = quad("ok") + quad("far").replace("(1, 1, 0)", "(1, 1e20, 0)")
    msg = scene_error(write(tmp_path, body))
    assert "/far" in msg and "1e+20 m" in msg and "/ok" not in msg


def test_coordinates_beyond_the_bound_after_scaling_are_an_error(tmp_path):
    # 2e12 units of 1 km each: 2e15 m
    body = quad("far").replace("(1, 1, 0)", "(1, 2e12, 0)")
    msg = scene_error(write(tmp_path, body, meta='metersPerUnit = 1000\n    upAxis = "Z"'))
    assert "/far" in msg and "2e+15 m" in msg


def test_up_axis_other_than_y_or_z_is_an_error(tmp_path):
    msg = scene_error(write(tmp_path, quad(), meta='metersPerUnit = 1\n    upAxis = "W"'))
    assert "upAxis" in msg and "'W'" in msg


@pytest.mark.parametrize("attr, typed, expected", [
    ("points", "int[] points = [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0]", "point3f[]"),
    ("faceVertexCounts", "float[] faceVertexCounts = [4]", "int[]"),
    ("faceVertexIndices", 'string faceVertexIndices = "0 1 2 3"', "int[]"),
])
def test_geometry_attribute_of_the_wrong_type_is_an_error(tmp_path, attr, typed, expected):
    lines = {"points": "point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]",
             "faceVertexCounts": "int[] faceVertexCounts = [4]",
             "faceVertexIndices": "int[] faceVertexIndices = [0, 1, 2, 3]"}
    lines[attr] = typed
    body = 'def Mesh "bad" {\n    ' + "\n    ".join(lines.values()) + "\n}\n"
    msg = scene_error(write(tmp_path, body))
    assert f"/bad.{attr}" in msg and expected in msg and typed.split()[0] in msg


def test_double_precision_points_are_read(tmp_path):
    body = quad().replace("point3f[]", "double3[]")
    scene = hu.read_scene(write(tmp_path, body))
    np.testing.assert_allclose(scene.points, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])


# --------------------------------------------------------------------------------------------
# composition errors reach the warnings
# --------------------------------------------------------------------------------------------


def test_missing_sublayer_is_a_warning(tmp_path):
    path = write(tmp_path, quad(), meta='metersPerUnit = 1\n    upAxis = "Z"\n    subLayers = [@gone.usda@]')
    scene = hu.read_scene(path)
    hits = [w for w in scene.warnings if "gone.usda" in w]
    assert len(hits) == 1 and hits[0].startswith(str(path)) and "sublayer" in hits[0]
    assert "@anon:" not in hits[0]


def test_missing_reference_is_a_warning(tmp_path):
    path = write(tmp_path, quad() + 'def Xform "prop" (references = @nowhere.usda@) {}\n')
    scene = hu.read_scene(path)
    assert any("nowhere.usda" in w and "/prop" in w for w in scene.warnings)


def test_reference_cycle_is_a_warning(tmp_path):
    write(tmp_path, 'def Xform "B" (references = @scene.usda@</A>) {}\n', name="other.usda",
          meta='defaultPrim = "B"')
    path = write(tmp_path, quad() + 'def Xform "A" (references = @other.usda@</B>) {}\n')
    scene = hu.read_scene(path)
    hits = [w for w in scene.warnings if "ycle" in w]
    assert len(hits) >= 1 and "other.usda" in hits[0]
    assert len(scene.meshes) == 1  # the rest of the scene is still read


def test_clean_scene_has_no_composition_warning(tmp_path):
    write(tmp_path, quad("sub"), name="sub.usda")
    path = write(tmp_path, quad(), meta='metersPerUnit = 1\n    upAxis = "Z"\n    subLayers = [@sub.usda@]')
    scene = hu.read_scene(path)
    assert scene.warnings == [] and len(scene.meshes) == 2


# --------------------------------------------------------------------------------------------
# lights and light attributes hirad does not honour
# --------------------------------------------------------------------------------------------


def test_shaping_attributes_are_honoured_on_a_rect_light(tmp_path):
    """Issue 13: ShapingAPI on a RectLight is honoured: the light becomes a luminaire (no warning,
    no emitting polygon); see tests/python/photometry/test_luminaires.py for its flux."""
    attrs = ("float inputs:width = 1\n float inputs:height = 1\n float inputs:shaping:cone:angle = 30\n"
             " float inputs:shaping:cone:softness = 0.2\n float inputs:shaping:focus = 2\n"
             " color3f inputs:shaping:focusTint = (1, 0, 0)")
    path = write(tmp_path, quad() + light(attrs=attrs, schemas='"ShapingAPI"'))
    scene = hu.read_scene(path)
    assert scene.warnings == []
    assert [m.path for m in scene.meshes] == ["/floor"]
    assert {lum.source for lum in scene.luminaires} == {"/lamp"}


def test_shaping_on_a_mesh_light_or_dome_light_is_named(tmp_path):
    mesh_light = quad("panel", extra='float inputs:intensity = 3\n    float inputs:shaping:cone:angle = 20')
    mesh_light = mesh_light.replace('def Mesh "panel" {', 'def Mesh "panel" (prepend apiSchemas = ["MeshLightAPI", '
                                    '"ShapingAPI"]) {')
    dome = light(kind="DomeLight", name="sky", attrs="float inputs:shaping:cone:angle = 30", schemas='"ShapingAPI"')
    scene = hu.read_scene(write(tmp_path, quad() + mesh_light + dome))
    assert any(w.startswith("/panel:") and "inputs:shaping:cone:angle = 20" in w and "not honoured" in w
               for w in scene.warnings), scene.warnings
    assert any(w.startswith("/sky:") and "inputs:shaping:cone:angle = 30" in w for w in scene.warnings)


def test_shaping_at_its_fallback_value_changes_nothing_and_gives_no_warning(tmp_path):
    attrs = "float inputs:width = 1\n float inputs:height = 1\n float inputs:shaping:cone:angle = 90"
    scene = hu.read_scene(write(tmp_path, quad() + light(attrs=attrs, schemas='"ShapingAPI"')))
    assert scene.warnings == []


def test_old_style_shaping_names_are_named_too(tmp_path):
    attrs = "float inputs:width = 1\n float inputs:height = 1\n float shaping:cone:angle = 20"
    scene = hu.read_scene(write(tmp_path, quad() + light(attrs=attrs)))
    assert any("/lamp" in w and "shaping:cone:angle = 20" in w for w in scene.warnings)


@pytest.mark.parametrize("kind", ["DomeLight", "DistantLight", "PortalLight", "GeometryLight", "PluginLight"])
def test_light_types_hirad_does_not_read_are_named(tmp_path, kind):
    path = write(tmp_path, quad() + light(kind=kind, name="other", attrs="float inputs:intensity = 5"))
    scene = hu.read_scene(path)
    assert any(w.startswith("/other:") and kind in w and "ignored" in w for w in scene.warnings)
    assert not np.any(scene.face_emission > 0)


def test_sphere_light_treat_as_point_is_honoured(tmp_path):
    """treatAsPoint is a hint (UsdLux): the light is the sphere's own point, I = L pi r^2, no warning."""
    attrs = "float inputs:radius = 0.125\n bool treatAsPoint = 1"
    scene = hu.read_scene(write(tmp_path, quad() + light(kind="SphereLight", name="bulb", attrs=attrs)))
    assert scene.warnings == []
    (lum,) = scene.luminaires
    np.testing.assert_allclose(lum.flux, 4 * math.pi ** 2 * 0.125 ** 2, rtol=1e-12)


@pytest.mark.parametrize("attr", ["float inputs:diffuse = 0.5", "float inputs:specular = 0",
                                  "asset inputs:texture:file = @sky.exr@"])
def test_other_ignored_light_attributes_are_named(tmp_path, attr):
    attrs = "float inputs:width = 1\n float inputs:height = 1\n " + attr
    scene = hu.read_scene(write(tmp_path, quad() + light(attrs=attrs)))
    name = attr.split()[1]
    assert any(w.startswith("/lamp:") and name in w for w in scene.warnings), scene.warnings


def test_honoured_light_attributes_give_no_warning(tmp_path):
    attrs = ("float inputs:width = 2\n float inputs:height = 0.5\n float inputs:intensity = 4\n"
             " float inputs:exposure = 1\n color3f inputs:color = (1, 0.5, 0.25)\n bool inputs:normalize = 1\n"
             " float inputs:diffuse = 1\n float inputs:specular = 1")
    scene = hu.read_scene(write(tmp_path, quad() + light(attrs=attrs)))
    assert scene.warnings == []
    # normalize: intensity x 2^exposure x colour over the 1 m^2 area, M = pi L
    k = mesh_of(scene, "/lamp")
    np.testing.assert_allclose(scene.face_emission[scene.face_mesh == k][0], math.pi * 8 * np.array([1, 0.5, 0.25]),
                               rtol=1e-12)


def test_light_linking_is_named(tmp_path):
    attrs = ("float inputs:width = 1\n float inputs:height = 1\n"
             " rel collection:lightLink:includes = </floor>\n uniform bool collection:lightLink:includeRoot = 0")
    scene = hu.read_scene(write(tmp_path, quad() + light(attrs=attrs)))
    hit = [w for w in scene.warnings if w.startswith("/lamp:")]
    assert len(hit) == 1 and "collection:lightLink:includes -> /floor" in hit[0]


# --------------------------------------------------------------------------------------------
# a scene that emits nothing
# --------------------------------------------------------------------------------------------


def test_dark_scene_is_read_by_default(tmp_path):
    scene = hu.read_scene(write(tmp_path, quad()))
    assert not np.any(scene.face_emission > 0)


def test_dark_scene_is_an_error_when_emission_is_required(tmp_path):
    path = write(tmp_path, quad() + light(kind="DomeLight", name="sky", attrs="float inputs:intensity = 1")
                 + light(kind="SphereLight", name="dot", attrs="float inputs:radius = 0"))
    msg = scene_error(path, require_emission=True)
    assert msg.startswith(f"{path}: nothing emits light")
    assert "/sky (DomeLight)" in msg and "/dot (SphereLight of zero radius" in msg


def test_zero_intensity_scene_is_an_error_when_emission_is_required(tmp_path):
    path = write(tmp_path, quad() + light(attrs="float inputs:width = 1\n float inputs:height = 1\n"
                                                " float inputs:intensity = 0"))
    msg = scene_error(path, require_emission=True)
    assert "nothing emits light" in msg


def test_lit_scene_passes_when_emission_is_required(tmp_path):
    path = write(tmp_path, material("Glow", emissive="(1, 1, 1)") + quad(extra=bound("Glow")))
    scene = hu.read_scene(path, require_emission=True)
    np.testing.assert_allclose(scene.face_emission[0], [math.pi] * 3)


def test_light_in_a_point_instancer_prototype_is_named(tmp_path):
    body = quad() + """
def PointInstancer "scatter" {
    rel prototypes = [</scatter/Protos/Lamp>]
    int[] protoIndices = [0, 0]
    point3f[] positions = [(0, 0, 1), (1, 0, 1)]
    def Scope "Protos" {
        def Xform "Lamp" {
            def RectLight "bulb" {
                float inputs:width = 0.1
                float inputs:height = 0.1
            }
        }
    }
}
"""
    path = write(tmp_path, body)
    scene = hu.read_scene(path)
    assert any(w.startswith("/scatter/Protos/Lamp/bulb:") and "PointInstancer prototype" in w
               for w in scene.warnings), scene.warnings
    msg = scene_error(path, require_emission=True)
    assert "/scatter/Protos/Lamp/bulb (RectLight in a PointInstancer prototype)" in msg


def test_non_finite_light_size_is_an_error(tmp_path):
    path = write(tmp_path, quad() + light(kind="DiskLight", name="disk", attrs="float inputs:radius = nan"))
    msg = scene_error(path)
    assert "/disk.inputs:radius" in msg and "nan" in msg


def test_light_without_area_is_named(tmp_path):
    path = write(tmp_path, quad() + light(attrs="float inputs:width = 0\n float inputs:height = 1"))
    scene = hu.read_scene(path)
    assert any(w.startswith("/lamp:") and "size 0 x 1 has no area" in w for w in scene.warnings)


def test_scene_that_is_a_fifo_is_refused_unopened(tmp_path):
    import os

    fifo = tmp_path / "scene.usda"
    os.mkfifo(fifo)
    assert scene_error(fifo) == f"{fifo}: not a regular file (a USD file is expected)"
