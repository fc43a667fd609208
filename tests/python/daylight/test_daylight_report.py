"""The client report (grids/report.html and report.pdf) of a daylight bake shows its daylight
factor and annual results as it shows the illuminance grids.

Two bakes of the example room (configs/scenes/daylit_room.usda): configs/daylight_factor.yaml (CIE
overcast sky, DF grids) and configs/daylit_room.yaml with pvlib's TMY3 weather file (annual
metrics, at the config's own settings). Every value the report states is computed here again,
independently, from the CSVs the bake wrote (DF per point, DA300, UDI bands and direct-sun hours per
point, the grid's weights) or from the weather file read with pvlib, and found in the HTML (each
number's full value is in its cell's data-value; the CSVs keep 6 significant digits, so means agree
to 1e-5 and the fractions of the area exactly). The pictures are the files the bake wrote (their
bytes, base64, in the page), and the PDF embeds them. The EN 17037 level is not derivable from the
CSVs: it is checked against report.json.
"""

from __future__ import annotations

import base64
import csv
import html
import json
import re
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

pytest.importorskip("hirad._engine")
pvlib = pytest.importorskip("pvlib")

from hirad_e2e_helpers import run_cli  # noqa: E402
from test_daylight_bake import DF, QUIET, ROOM, TMY3  # noqa: E402

NOT_USD = [*QUIET]  # no lightmaps, no preview, no layer: the grids and their report are what is tested


def _csv(path: Path) -> dict:
    rows = list(csv.reader(path.open()))
    return {h: np.array([float(r[i]) for r in rows[1:]]) for i, h in enumerate(rows[0])}


def _value(page: str, grid: str, key: str) -> str:
    m = re.search(rf'data-grid="{re.escape(grid)}" data-key="{re.escape(html.escape(key, quote=True))}" '
                  r'data-value="([^"]*)"', page)
    assert m, f"{grid} {key} not in the report"
    return html.unescape(m.group(1))


def _png_size(png: bytes) -> tuple[int, int]:
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", png[16:24])


def _in_pdf(pdf: bytes, png: bytes) -> bool:
    """An image of the PNG's size embedded in the PDF (image XObjects are streams, never
    compressed into object streams, so their dictionaries are plain text)."""
    w, h = _png_size(png)
    return re.search(rb"/Width %d\s*/Height %d" % (w, h), pdf) is not None


def _bake(tmp_path_factory, name: str, config: Path, *sets: str) -> Path:
    out = tmp_path_factory.mktemp(name) / "out"
    r = run_cli("bake", config, "--quiet", "--set", f"output={out}", *[x for o in (*NOT_USD, *sets) for x in ("--set", o)])
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def df_bake(tmp_path_factory):
    return _bake(tmp_path_factory, "df_report", DF)


@pytest.fixture(scope="module")
def annual_bake(tmp_path_factory):
    return _bake(tmp_path_factory, "annual_report", ROOM, f"daylight.annual.weather={TMY3}")


def test_report_shows_the_daylight_factor(df_bake):
    grids = df_bake / "grids"
    page = (grids / "report.html").read_text()
    df = _csv(grids / "daylight_factor" / "workplane.csv")
    plane = _csv(grids / "workplane.csv")
    assert np.array_equal(df["x"], plane["x"]) and np.array_equal(df["y"], plane["y"])
    w, d = plane["weight"], df["df_percent"]
    mean = float(np.sum(w * d) / np.sum(w))
    assert "<h2>Daylight factor</h2>" in page
    assert float(_value(page, "workplane", "em")) == pytest.approx(mean, rel=1e-5)
    assert float(_value(page, "workplane", "emin")) == pytest.approx(d.min(), rel=1e-5)
    assert float(_value(page, "workplane", "emax")) == pytest.approx(d.max(), rel=1e-5)
    assert float(_value(page, "workplane", "u0")) == pytest.approx(d.min() / mean, rel=2e-5)
    # the area with DF >= 2 %, bracketed by the CSV's rounding
    lo, hi = (float(w[d >= 2.0 + e].sum() / w.sum()) for e in (1e-5, -1e-5))
    assert lo <= float(_value(page, "workplane", "area_fraction_df_2")) <= hi
    # the outside horizontal illuminance: E / DF x 100 at every point
    eh = float(re.search(r'id="df-outside" data-value="([^"]+)"', page).group(1))
    assert np.allclose(100 * df["lux"] / d, eh, rtol=2e-5)
    assert "EN 17037" in page  # what is and is not computed for DF is stated
    png = (grids / "daylight_factor" / "workplane.png").read_bytes()
    assert base64.b64encode(png).decode() in page
    pdf_path = grids / "report.pdf"
    if pdf_path.exists() or "report.pdf" in json.loads((df_bake / "report.json").read_text())["grids"]["files"]:
        pdf = pdf_path.read_bytes()
        assert pdf.startswith(b"%PDF") and _in_pdf(pdf, png)


def test_report_shows_the_annual_metrics(annual_bake):
    grids = annual_bake / "grids"
    page = (grids / "report.html").read_text()
    info = json.loads((annual_bake / "report.json").read_text())["grids"]["annual"]
    an = _csv(grids / "annual" / "workplane.csv")
    plane = _csv(grids / "workplane.csv")
    assert np.array_equal(an["x"], plane["x"]) and np.array_equal(an["y"], plane["y"])
    w = plane["weight"] / plane["weight"].sum()
    assert "<h2>Annual daylight</h2>" in page
    assert float(_value(page, "workplane", "sDA300/50%")) == pytest.approx(float(w[an["da300"] >= 0.5].sum()), abs=1e-12)
    assert float(_value(page, "workplane", "ASE1000/250h")) == pytest.approx(
        float(w[an["sunlit_hours_1000"] > 250].sum()), abs=1e-12)
    ase = float(_value(page, "workplane", "ASE1000/250h"))
    assert 0 < ase < 1  # a south window: part of the plane gets the sun, not all of it
    assert float(_value(page, "workplane", "mean_DA300")) == pytest.approx(float(w @ an["da300"]), rel=1e-5)
    for key, column in (("udi_below_100", "udi_below_100"), ("mean_UDI_100_3000", "udi_100_3000"),
                        ("udi_above_3000", "udi_above_3000")):
        assert float(_value(page, "workplane", key)) == pytest.approx(float(w @ an[column]), rel=1e-5, abs=1e-7), key
    level = info["grids"]["workplane"]["EN17037_level"]
    assert _value(page, "workplane", "EN17037_level") == ("" if level is None else level)
    # the weather file, the site and the hours counted, against the file read with pvlib
    data, meta = pvlib.iotools.read_tmy3(TMY3, map_variables=True)
    assert html.escape(TMY3) in page
    assert re.search(r'data-key="hours" data-value="(\d+)"', page).group(1) == str(len(data))
    days = len(data) // 24
    assert float(_value(page, "workplane", "occupied_hours")) == 10 * days  # 8:00-18:00 every day
    site = re.search(r'data-key="site"[^>]*data-latitude="([^"]+)" data-longitude="([^"]+)"', page)
    assert float(site.group(1)) == pytest.approx(meta["latitude"]) and float(site.group(2)) == pytest.approx(
        meta["longitude"])
    assert re.search(r'data-key="daytime_hours" data-value="(\d+)"', page).group(1) == str(info["daytime_hours"])
    pngs = [(grids / "annual" / f"workplane_{s}.png").read_bytes() for s in ("da300", "udi", "sunlit_hours")]
    for png in pngs:
        assert base64.b64encode(png).decode() in page
    pdf_path = grids / "report.pdf"
    if pdf_path.exists():
        pdf = pdf_path.read_bytes()
        assert pdf.startswith(b"%PDF") and all(_in_pdf(pdf, png) for png in pngs)


def test_matplotlib_pdf_has_the_daylight_pages(df_bake, annual_bake, tmp_path):
    """Without WeasyPrint the PDF is drawn with matplotlib: one more page per daylight factor
    grid and per annual grid."""
    from hirad.studies.report import Study, daylight_parts, write_report_pdf

    def _pages(pdf: bytes) -> int:  # as tests/python/studies/test_study_report.py counts them
        return pdf.count(b"/Type /Page\n") + pdf.count(b"/Type /Page>") + pdf.count(b"/Type /Page/") + \
            pdf.count(b"/Type /Page ") - pdf.count(b"/Type /Pages ")

    def pages(**parts) -> int:
        out = tmp_path / f"r{len(parts)}.pdf"
        write_report_pdf(Study(results=[], maintenance_factor=1.0, **parts), out, engine="matplotlib")
        return _pages(out.read_bytes())

    df = json.loads((df_bake / "report.json").read_text())["grids"]["daylight_factor"]
    an = json.loads((annual_bake / "report.json").read_text())["grids"]["annual"]
    with_both = {**daylight_parts(df_bake / "grids", daylight_factor=df),
                 **daylight_parts(annual_bake / "grids", annual=an)}
    assert pages(**with_both) == pages() + len(df["grids"]) + len(an["grids"])


def test_a_missing_daylight_picture_is_named(df_bake, tmp_path):
    from hirad.studies import StudyError
    from hirad.studies.report import daylight_parts

    df = json.loads((df_bake / "report.json").read_text())["grids"]["daylight_factor"]
    with pytest.raises(StudyError, match=r"daylight_factor/workplane\.png"):
        daylight_parts(tmp_path, daylight_factor=df)
