"""Grid statistics (Em, Emin, Emax, U0, Ud, maintained values) and the clear errors of bad grid
definitions, bad CSV files and bad evaluators."""

from __future__ import annotations

import numpy as np
import pytest

from hirad.studies import StudyError, build_grid, evaluate_grids, grid_stats, load_study, study_from_dict


ROOM = [[0, 0], [6, 0], [6, 4], [0, 4]]


def test_uniform_field_has_u0_and_ud_of_one():
    study = study_from_dict({"maintenance_factor": 0.8, "grids": {
        "office": {"kind": "workplane", "polygon": ROOM},
        "wall": {"kind": "rectangle", "corner": [0, 4, 0], "edge_u": [6, 0, 0], "edge_v": [0, 0, 3]},
        "faces": {"kind": "workplane", "polygon": ROOM, "height": 1.2, "measure": {"type": "cylindrical"}}}})
    # a furnace: the same illuminance on every plane, every way it faces
    results = evaluate_grids(study, lambda p, n: np.full(len(p), 300.0))
    assert [r.name for r in results] == ["office", "wall", "faces"]
    for r in results:
        assert r.stats.u0 == 1.0 and r.stats.ud == 1.0
        assert r.stats.em == pytest.approx(300.0, rel=1e-14)
        assert r.stats.em_maintained == pytest.approx(240.0, rel=1e-14)
        np.testing.assert_allclose(r.maintained, 240.0, rtol=1e-14)
        assert r.stats.maintenance_factor == 0.8


def test_statistics_closed_forms():
    s = grid_stats([100.0, 200.0, 300.0, 400.0], maintenance_factor=0.5)
    assert (s.em, s.emin, s.emax) == (250.0, 100.0, 400.0)
    assert s.u0 == pytest.approx(0.4) and s.ud == pytest.approx(0.25)
    assert (s.em_maintained, s.emin_maintained, s.emax_maintained) == (125.0, 50.0, 200.0)
    # the area-weighted mean: a cell 3 times as large counts 3 times
    assert grid_stats([100.0, 300.0], [3.0, 1.0]).em == pytest.approx(150.0)
    dark = grid_stats([0.0, 0.0])
    assert dark.u0 is None and dark.ud is None


def test_linear_field_on_a_regular_grid_has_the_area_mean():
    # E = 100 + 10 x over the reduced rectangle [0.5, 5.5]: its mean is 100 + 10 * 3 = 130 lx,
    # and the cell centres of equal cells give it exactly; Emin/Emax at the outermost centres
    study = study_from_dict({"grids": {"o": {"kind": "workplane", "polygon": ROOM}}})
    (r,) = evaluate_grids(study, lambda p, n: 100.0 + 10.0 * p[:, 0])
    assert r.stats.em == pytest.approx(130.0, rel=1e-12)
    dx = 5.0 / 9
    assert r.stats.emin == pytest.approx(100 + 10 * (0.5 + dx / 2), rel=1e-12)
    assert r.stats.emax == pytest.approx(100 + 10 * (5.5 - dx / 2), rel=1e-12)
    assert r.stats.u0 == pytest.approx(r.stats.emin / 130.0, rel=1e-12)


# ------------------------------------------------------------------------------------
# bad definitions
# ------------------------------------------------------------------------------------


@pytest.mark.parametrize("grid, key, words", [
    ({"kind": "workplane", "polygon": ROOM, "spacing": -0.5}, "grids.office.spacing", "positive"),
    ({"kind": "workplane", "polygon": ROOM, "spacing": 0}, "grids.office.spacing", "positive"),
    ({"kind": "workplane", "polygon": [[0, 0], [1, 0]]}, "grids.office.polygon", "at least 3 corners"),
    ({"kind": "workplane", "polygon": [[0, 0], [1, 0], [1, 1, 1, 1]]}, "grids.office.polygon", "corner 2"),
    ({"kind": "workplane", "polygons": [ROOM, [[0, 0], [1, 1]]]}, "grids.office.polygons", "polygon 1"),
    ({"kind": "workplane"}, "grids.office", "polygon, polygons or room"),
    ({"kind": "workplane", "polygon": ROOM, "height": -1}, "grids.office.height", "greater than or equal"),
    ({"kind": "workplane", "polygon": ROOM, "border": -0.1}, "grids.office.border", "greater than or equal"),
    ({"kind": "workplane", "polygon": ROOM, "colour": 1}, "grids.office.colour", "Extra inputs"),
    ({"kind": "workplane", "polygon": ROOM, "measure": {"type": "vertical"}}, "grids.office.measure", "needs an azimuth"),
    ({"kind": "workplane", "polygon": ROOM, "measure": {"type": "planar", "azimuth": 3.0}}, "grids.office.measure",
     "takes no azimuth"),
    ({"kind": "workplane", "polygon": ROOM, "measure": {"type": "cylindrical", "azimuths": 2}},
     "grids.office.measure.azimuths", "greater than or equal to 3"),
    ({"kind": "floor", "polygon": ROOM}, "grids.office", "kind"),
    ({"kind": "rectangle", "corner": [0, 0, 0], "edge_u": [1, 0, 0], "edge_v": [1, 1, 0]}, "grids.office",
     "not perpendicular"),
    ({"kind": "rectangle", "corner": [0, 0, 0], "edge_u": [1, 0, 0], "edge_v": [0, 1, 0], "normal": [1, 0, 0]},
     "grids.office", "normal is not perpendicular"),
    ({"kind": "points"}, "grids.office.file", "Field required"),
    ({"kind": "workplane", "polygon": ROOM, "height": "0.8"}, "grids.office.height", "valid number"),
])
def test_bad_grid_definitions_name_the_key(grid, key, words):
    with pytest.raises(StudyError) as e:
        study_from_dict({"grids": {"office": grid}}, source="study.yaml")
    msg = str(e.value)
    assert msg.startswith(f"study.yaml: {key}"), msg
    assert words in msg, msg


def test_bad_top_level():
    with pytest.raises(StudyError, match=r"study.yaml: maintenance_factor: .*less than or equal to 1"):
        study_from_dict({"maintenance_factor": 1.5}, source="study.yaml")
    with pytest.raises(StudyError, match=r"grid name 'a/b'"):
        study_from_dict({"grids": {"a/b": {"kind": "workplane", "polygon": ROOM}}})


def test_load_study_from_yaml(tmp_path):
    f = tmp_path / "grids.yaml"
    f.write_text("maintenance_factor: 0.7\ngrids:\n  office:\n    kind: workplane\n    polygon: [[0, 0], [6, 0], [6, 4], [0, 4]]\n    spacing: -1\n")
    with pytest.raises(StudyError, match=rf"{f}: grids.office.spacing: spacing -1"):
        load_study(f)
    f.write_text("grids: [\n")
    with pytest.raises(StudyError, match="not YAML"):
        load_study(f)
    with pytest.raises(StudyError, match="cannot read"):
        load_study(tmp_path / "missing.yaml")


def _points(tmp_path, text: str):
    f = tmp_path / "pts.csv"
    f.write_text(text)
    study = study_from_dict({"grids": {"p": {"kind": "points", "file": "pts.csv"}}})
    return f, lambda: build_grid("p", study.grids["p"], base_dir=tmp_path)


@pytest.mark.parametrize("text, line, words", [
    ("x,y,z\n0,0,0\n1,0,abc\n", 3, "'abc' is not a number"),
    ("0,0,0\n\n# comment\n1,2\n", 4, "2 values"),
    ("0,0,0,0,0,1\n1,1,1,0,0,0\n", 2, "no direction"),
    ("0,0,0\n1,1,nan\n", 2, "not finite"),
    ("0,0,0\nx,y,z\n", 2, "'x' is not a number"),  # names only on the first line
])
def test_bad_csv_line_names_file_and_line(tmp_path, text, line, words):
    f, build = _points(tmp_path, text)
    with pytest.raises(StudyError) as e:
        build()
    assert str(e.value).startswith(f"{f}:{line}: "), str(e.value)
    assert words in str(e.value)


def test_csv_empty_missing_and_not_utf8(tmp_path):
    f, build = _points(tmp_path, "# nothing\n")
    with pytest.raises(StudyError, match=rf"{f}: no points"):
        build()
    f.write_bytes(b"0,0,0\n1,1,\xff\n")
    with pytest.raises(StudyError, match=rf"{f}:2: not UTF-8"):
        build()
    f.unlink()
    with pytest.raises(StudyError, match=rf"grid p: {f}: cannot read"):
        build()


def test_csv_normals_and_default_normal(tmp_path):
    f, build = _points(tmp_path, "x,y,z,nx,ny,nz\n1,2,3,0,0,-2\n")
    g = build()
    np.testing.assert_array_equal(g.points, [[1, 2, 3]])
    np.testing.assert_array_equal(g.normals, [[0, 0, -1]])
    np.testing.assert_array_equal(g.weights, [1.0])


def test_border_band_that_leaves_nothing():
    study = study_from_dict({"grids": {"tiny": {"kind": "workplane", "polygon": [[0, 0], [0.8, 0], [0.8, 3], [0, 3]]}}})
    with pytest.raises(StudyError, match=r"grid tiny: the border band of 0.5 m leaves no area"):
        build_grid("tiny", study.grids["tiny"])


def test_too_many_points_refused():
    study = study_from_dict({"grids": {"big": {"kind": "workplane", "polygon": [[0, 0], [1000, 0], [1000, 1000], [0, 1000]],
                                               "spacing": 0.001}}})
    with pytest.raises(StudyError, match=r"grid big: .* points exceed the limit"):
        build_grid("big", study.grids["big"])


def test_too_many_sensors_refused():
    study = study_from_dict({"grids": {"hall": {"kind": "workplane", "polygon": [[0, 0], [100, 0], [100, 100], [0, 100]],
                                                "spacing": 0.4, "measure": {"type": "cylindrical", "azimuths": 720}}}})
    # 100 m less the 0.5 m band: 99 m, ceil(99 / 0.4) = 248 cells a side, 248^2 = 61504 points
    with pytest.raises(StudyError, match=r"grid hall: 61504 points x 720 azimuths exceed the limit"):
        build_grid("hall", study.grids["hall"])


@pytest.mark.parametrize("evaluate, words", [
    (lambda p, n: np.full(len(p), np.nan), "not finite"),
    (lambda p, n: np.full(len(p) - 1, 1.0), "shape"),
    (lambda p, n: np.full(len(p), -5.0), "negative illuminance"),
])
def test_bad_evaluator_output_is_an_error_naming_the_grid(evaluate, words):
    study = study_from_dict({"grids": {"office": {"kind": "workplane", "polygon": ROOM}}})
    with pytest.raises(StudyError, match=rf"grid office: .*{words}"):
        evaluate_grids(study, evaluate)
