"""Units labels: the per-grid CSV header, the JSON and the picture legends say lux and cd/m^2
(photometric) or W/m^2 and W/(m^2 sr) (radiometric), and the report's tables follow."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from hirad.studies import StudyError, evaluate_grids, study_from_dict
from hirad.studies.outputs import CSV_HEADER, csv_header, grid_record, write_grid_csv, write_grid_json
from hirad.studies.pictures import camera_luminance, camera_luminance_picture, grid_picture, luminance_picture
from hirad.studies.report import RADIOMETRIC_TEXT, UNITS_TEXT, Study, render_html, units_text, write_study

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def result():
    study = study_from_dict({"maintenance_factor": 0.8, "grids": {
        "office": {"kind": "workplane", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]], "spacing": 0.5}}})
    (r,) = evaluate_grids(study, lambda p, n: 100.0 + p[:, 0] + 10 * p[:, 1])
    return r


@pytest.fixture
def labels(monkeypatch):
    """Every colour-bar label and axes title matplotlib is given, and the isolux labels' text."""
    from matplotlib.axes import Axes
    from matplotlib.colorbar import Colorbar

    seen = {"colorbar": [], "title": [], "clabel": []}
    cb_set, title_set, clabel = Colorbar.set_label, Axes.set_title, Axes.clabel

    def set_label(self, label, *a, **k):
        seen["colorbar"].append(label)
        return cb_set(self, label, *a, **k)

    def set_title(self, label, *a, **k):
        seen["title"].append(label)
        return title_set(self, label, *a, **k)

    def clabel_(self, cs, *a, **k):
        fmt = k.get("fmt")
        if callable(fmt):
            seen["clabel"] += [fmt(v) for v in cs.levels]
        return clabel(self, cs, *a, **k)

    monkeypatch.setattr(Colorbar, "set_label", set_label)
    monkeypatch.setattr(Axes, "set_title", set_title)
    monkeypatch.setattr(Axes, "clabel", clabel_)
    return seen


def test_csv_header_per_unit_system(tmp_path, result):
    assert csv_header() == CSV_HEADER == "x,y,z,nx,ny,nz,weight,E_lx,E_maintained_lx"
    assert csv_header("radiometric") == "x,y,z,nx,ny,nz,weight,E_W_m2,E_maintained_W_m2"
    for units, col in (("photometric", "E_lx"), ("radiometric", "E_W_m2")):
        path = tmp_path / f"{units}.csv"
        write_grid_csv(result, path, units)
        rows = list(csv.DictReader(path.open()))
        assert col in rows[0]
        assert np.array_equal([float(r[col]) for r in rows], result.values)
    with pytest.raises(StudyError, match="units 'imperial'"):
        csv_header("imperial")


def test_json_units_block(tmp_path, result):
    write_grid_json(result, tmp_path / "p.json")
    write_grid_json(result, tmp_path / "r.json", "radiometric")
    p, r = json.loads((tmp_path / "p.json").read_text()), json.loads((tmp_path / "r.json").read_text())
    assert p["units"]["system"] == "photometric" and p["units"]["illuminance"] == "lx" and p["units"]["values"] == "lx"
    assert p["values_lx"] == result.values.tolist() and "values_W_m2" not in p
    assert r["units"]["system"] == "radiometric" and r["units"]["irradiance"] == "W/m2"
    assert r["units"]["values"] == "W/m2" and "illuminance" not in r["units"]
    assert r["values_W_m2"] == result.values.tolist() and r["maintained_W_m2"] == result.maintained.tolist()
    assert "values_lx" not in r and "0.2126" in r["units"]["quantity"]
    assert grid_record(result)["stats"] == grid_record(result, "radiometric")["stats"]


def test_grid_picture_legend(labels, result):
    assert grid_picture(result).startswith(PNG)
    assert labels["colorbar"][-1] == "illuminance (lx)"
    assert labels["title"][-1].endswith("U0 " + f"{result.stats.u0:.3f}") and " lx," in labels["title"][-1]
    assert labels["clabel"] and all(s.endswith(" lx") for s in labels["clabel"])
    labels["clabel"].clear()
    grid_picture(result, units="radiometric", maintained=True)
    assert labels["colorbar"][-1] == "maintained irradiance (W/m²)"
    assert " W/m²," in labels["title"][-1] and "lx" not in labels["title"][-1]
    assert labels["clabel"] and all(s.endswith(" W/m²") for s in labels["clabel"])


def test_luminance_picture_legend(labels):
    img = np.linspace(0.0, 40.0, 64).reshape(8, 8)
    luminance_picture(img)
    assert labels["colorbar"][-1] == "luminance (cd/m²)"
    luminance_picture(img, units="radiometric")
    assert labels["colorbar"][-1] == "radiance (W/(m² sr))"


class _FakeResult:
    """A stand-in for a bake's Result: render() gives a constant linear RGB image."""

    cameras = []

    def __init__(self, rgb):
        self.rgb = np.asarray(rgb, dtype=np.float64)
        self.calls = []

    def render(self, camera, width, height, samples):
        self.calls.append((camera, width, height, samples))
        return np.broadcast_to(self.rgb, (height, width, 3)).astype(np.float32)


def test_camera_luminance_is_rec709_y_of_the_render(labels):
    fake = _FakeResult([10.0, 20.0, 40.0])
    lum = camera_luminance(fake, "/World/Cam", width=6, height=4, samples=3)
    assert fake.calls == [("/World/Cam", 6, 4, 3)]
    assert lum.shape == (4, 6)
    np.testing.assert_allclose(lum, 0.2126 * 10 + 0.7152 * 20 + 0.0722 * 40, rtol=1e-6)
    png = camera_luminance_picture(fake, "/World/Cam", width=6, height=4, samples=1)
    assert png.startswith(PNG)
    assert labels["colorbar"][-1] == "luminance (cd/m²)"
    assert "/World/Cam" in labels["title"][-1] and "cd/m²" in labels["title"][-1]
    camera_luminance_picture(fake, None, width=6, height=4, units="radiometric")
    assert labels["colorbar"][-1] == "radiance (W/(m² sr))"
    assert "the default view" in labels["title"][-1]
    with pytest.raises(StudyError, match="width"):
        camera_luminance(fake, None, width=0)


def test_report_labels_follow_the_unit_system(tmp_path, labels, result):
    assert units_text("photometric") == UNITS_TEXT and units_text("radiometric") == RADIOMETRIC_TEXT
    photometric = render_html(Study(results=[result], maintenance_factor=0.8))
    assert "Em (lx)" in photometric and "W/m²" not in photometric
    for study in (Study(results=[result], maintenance_factor=0.8, unit_system="radiometric"),
                  Study(results=[result], maintenance_factor=0.8, units="Radiometric units: W/m² ...")):
        assert study.unit_system == "radiometric"
        text = render_html(study)
        assert "Em (W/m²)" in text and "maintained Emax (W/m²)" in text and "(lx)" not in text
    assert Study(results=[result], maintenance_factor=0.8, unit_system="radiometric").units == RADIOMETRIC_TEXT
    with pytest.raises(StudyError):
        Study(results=[result], maintenance_factor=0.8, unit_system="imperial")
    written = write_study(Study(results=[result], maintenance_factor=0.8, unit_system="radiometric"),
                          tmp_path / "out", pdf=True, engine="matplotlib")
    names = sorted(p.name for p in written["files"])
    assert names == ["office.csv", "office.json", "office.png", "report.html", "report.pdf"]
    assert (tmp_path / "out" / "office.csv").read_text().splitlines()[0].endswith("E_W_m2,E_maintained_W_m2")
    assert json.loads((tmp_path / "out" / "office.json").read_text())["units"]["system"] == "radiometric"
    assert "irradiance (W/m²)" in labels["colorbar"]
