"""Study outputs: per-point CSV and JSON (atomic, exact round trip), the false-colour pictures
and the self-contained HTML report and its PDF."""

from __future__ import annotations

import base64
import csv
import html.parser
import json
import os

import numpy as np
import pytest

import hirad
from hirad.studies import evaluate_grids, study_from_dict
from hirad.studies.outputs import CSV_HEADER, write_grid_csv, write_grid_json
from hirad.studies.pictures import grid_picture, luminance_picture, nice_ceiling
from hirad.studies.report import Study, pdf_engine, render_html, write_report_html, write_report_pdf
from hirad.studies.spec import StudyError

PNG = b"\x89PNG\r\n\x1a\n"


def point_source(h=3.0, x0=3.0, y0=2.0, i0=1000.0):
    """A downward Lambertian point source I = i0 cos(theta) at (x0, y0, h): on a plane facing
    n, E = I(theta) max(0, n.u) / r^2."""
    s = np.array([x0, y0, h])

    def evaluate(p, n):
        v = s - p
        r = np.linalg.norm(v, axis=1)
        u = v / r[:, None]
        return i0 * np.maximum(0.0, u[:, 2]) * np.maximum(0.0, np.sum(n * u, axis=1)) / r ** 2

    return evaluate


@pytest.fixture(scope="module")
def results():
    study = study_from_dict({"maintenance_factor": 0.8, "grids": {
        "office": {"kind": "workplane", "polygon": [[0, 0], [6, 0], [6, 4], [0, 4]]},
        "wall": {"kind": "rectangle", "corner": [0, 4, 0], "edge_u": [6, 0, 0], "edge_v": [0, 0, 3],
                 "normal": [0, -1, 0], "spacing": 0.5}}})
    return evaluate_grids(study, point_source())


def test_per_point_csv_and_json_round_trip(tmp_path, results):
    r = results[0]
    c, j = tmp_path / "office.csv", tmp_path / "office.json"
    write_grid_csv(r, c)
    write_grid_json(r, j)
    assert sorted(os.listdir(tmp_path)) == ["office.csv", "office.json"]  # no temporaries left
    rows = list(csv.reader(c.open()))
    assert ",".join(rows[0]) == CSV_HEADER
    data = np.array(rows[1:], dtype=np.float64)
    assert data.shape == (45, 9)
    np.testing.assert_array_equal(data[:, :3], r.grid.points)
    np.testing.assert_array_equal(data[:, 7], r.values)  # the same bits
    np.testing.assert_array_equal(data[:, 8], 0.8 * r.values)
    # the values are the closed form at the points: E = 1000 h^2 / d^4 with h = 3 - 0.8
    p = data[:, :3]
    d2 = (p[:, 0] - 3) ** 2 + (p[:, 1] - 2) ** 2 + 2.2 ** 2
    np.testing.assert_allclose(data[:, 7], 1000 * 2.2 ** 2 / d2 ** 2, rtol=1e-12)
    rec = json.loads(j.read_text())
    assert rec["grid"] == "office" and rec["units"]["illuminance"] == "lx"
    assert rec["maintenance_factor"] == 0.8
    assert rec["values_lx"] == r.values.tolist()
    assert rec["stats"]["em"] == r.stats.em and rec["stats"]["u0"] == r.stats.u0
    assert rec["en12464_rule"]["d"] == 5.0
    assert rec["hirad_version"] == hirad.__version__


def test_grid_pictures_are_png_and_deterministic(results):
    for r in results:
        a, b = grid_picture(r), grid_picture(r)
        assert a[:8] == PNG and a == b
    assert grid_picture(results[0]) != grid_picture(results[0], maintained=True)


def test_pictures_of_points_and_single_row_grids(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("0,0,0\n1,0,0\n1,1,0\n2,1.5,0\n")
    study = study_from_dict({"grids": {
        "pts": {"kind": "points", "file": str(f)},
        "row": {"kind": "workplane", "polygon": [[0, 0], [6, 0], [6, 0.3], [0, 0.3]], "border": 0, "spacing": 0.5,
                "measure": {"type": "vertical", "azimuth": 90.0}}}})
    results = evaluate_grids(study, point_source())
    assert (results[1].grid.layout.nu, results[1].grid.layout.nv) == (12, 1)
    for r in results:
        assert grid_picture(r)[:8] == PNG


def test_luminance_picture():
    yy, xx = np.mgrid[0:40, 0:60]
    L = 250.0 * np.exp(-((xx - 30) ** 2 + (yy - 20) ** 2) / 200.0)
    L[:3, :3] = np.nan  # no surface
    for kw in ({}, {"scale": "log", "decades": 3}, {"contours": True, "maximum": 100.0, "steps": 5}):
        png = luminance_picture(L, **kw)
        assert png[:8] == PNG and png == luminance_picture(L, **kw)
    assert nice_ceiling(250.0) == 250.0 and nice_ceiling(251.0) == 500.0 and nice_ceiling(0.03) == 0.05
    with pytest.raises(StudyError, match="negative luminance"):
        luminance_picture(-L)
    with pytest.raises(StudyError, match="shape"):
        luminance_picture(L[0])
    with pytest.raises(StudyError, match="scale"):
        luminance_picture(L, scale="sqrt")


class _Sources(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.refs, self.tags = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        for k, v in attrs:
            if k in ("src", "href", "data", "srcset", "poster", "action"):
                self.refs.append((tag, k, v or ""))


def _study(results, **kw):
    lum = np.full((20, 30), 120.0)
    kw.setdefault("grid_pictures", {r.name: _picture(r) for r in results})
    return Study(results, 0.8,
                 luminaires=[{"type": "Downlight <DL-1> & co", "count": 4, "lumens": 2500.0, "ies": "dl1.ies"},
                             {"type": "Wallwasher", "count": 2, "lumens": 1200.0, "ies": "ww.ies", "mounting": "recessed"}],
                 solver={"residual": 3.2e-7, "energy_balance": 1.5e-4, "method": "hierarchical"},
                 pictures=[("camera view luminance", luminance_picture(lum))], **kw)


_PICTURES = {}


def _picture(r):
    """Each grid's picture drawn once per test run (the PDF tests render several reports)."""
    key = (r.name, r.values.tobytes())
    if key not in _PICTURES:
        _PICTURES[key] = grid_picture(r)
    return _PICTURES[key]


def _uniform_results():
    study = study_from_dict({"maintenance_factor": 0.8, "grids": {
        "hall": {"kind": "workplane", "polygon": [[0, 0], [6, 0], [6, 4], [0, 4]]},
        "board": {"kind": "rectangle", "corner": [0, 4, 0], "edge_u": [2, 0, 0], "edge_v": [0, 0, 1]}}})
    # 300 lx on the work plane and 500 lx on the board (a closed-form field per grid)
    return evaluate_grids(study, lambda p, n: np.where(n[:, 2] > 0.5, 300.0, 500.0))


def test_html_is_self_contained_and_carries_every_grid(tmp_path):
    results = _uniform_results()
    text = write_report_html(_study(results), tmp_path / "study.html")
    assert (tmp_path / "study.html").read_text() == text
    p = _Sources()
    p.feed(text)
    assert p.refs, "the pictures are there"
    for tag, attr, value in p.refs:
        assert value.startswith("data:image/png;base64,"), (tag, attr, value[:40])
        assert "http" not in value[:30]
        assert base64.b64decode(value.split(",", 1)[1])[:8] == PNG
    assert "link" not in p.tags and "script" not in p.tags and "iframe" not in p.tags
    assert "url(" not in text  # no resources from the style sheet either
    # one picture per grid plus the luminance view
    assert sum(1 for t, a, _ in p.refs if t == "img") == 3
    # each grid's numbers in its own section: Em, Emin, Emax 300 / 500 lx, maintained 240 / 400
    for name, e in (("hall", 300.0), ("board", 500.0)):
        start = text.index(f'id="grid-{name}"')
        section = text[start:text.index("</div>", start)]
        for key, value in (("em", e), ("emin", e), ("emax", e), ("em_maintained", 0.8 * e),
                           ("emin_maintained", 0.8 * e), ("u0", 1.0), ("ud", 1.0)):
            assert f'data-key="{key}">{value:.2f}<' in section or f'data-key="{key}">{value:.4g}<' in section, (name, key)
    assert 'id="maintenance-factor">0.8<' in text
    assert f'id="hirad-version">{hirad.__version__}<' in text
    assert "3.2e-07" in text and "0.00015" in text  # residual, energy balance
    assert "dl1.ies" in text and "ww.ies" in text and "recessed" in text
    assert "Downlight &lt;DL-1&gt; &amp; co" in text  # escaped
    assert 'id="total-lumens">12400<' in text  # 4 x 2500 + 2 x 1200 lm
    assert "lux" in text and "cd/m²" in text


def test_html_is_deterministic_and_refuses_a_wrong_maintenance_factor():
    results = _uniform_results()
    assert render_html(_study(results)) == render_html(_study(results))
    with pytest.raises(StudyError, match="maintenance factor"):
        render_html(Study(results, 0.9))


def test_solver_figures_missing_are_said_so():
    text = render_html(Study(_uniform_results(), 0.8))
    assert text.count("not given") == 2
    assert "No luminaires given" in text


def _pages(pdf: bytes) -> int:
    return pdf.count(b"/Type /Page\n") + pdf.count(b"/Type /Page>") + pdf.count(b"/Type /Page/") + \
        pdf.count(b"/Type /Page ") - pdf.count(b"/Type /Pages ")


def test_pdf_matplotlib(tmp_path):
    results = _uniform_results()
    out = tmp_path / "study.pdf"
    assert write_report_pdf(_study(results), out, engine="matplotlib") == "matplotlib"
    data = out.read_bytes()
    assert data[:5] == b"%PDF-"
    write_report_pdf(_study(results), tmp_path / "again.pdf", engine="matplotlib")
    assert (tmp_path / "again.pdf").read_bytes() == data  # no clock in it
    assert data.count(b"/Type /Page") - data.count(b"/Type /Pages") == 1 + 2 + 1  # summary, 2 grids, 1 picture
    assert sorted(os.listdir(tmp_path)) == ["again.pdf", "study.pdf"]


def test_pdf_weasyprint(tmp_path):
    try:
        import weasyprint  # noqa: F401
    except (ImportError, OSError) as e:  # not installed, or its Pango library missing
        pytest.skip(f"WeasyPrint cannot be used here: {e}")
    results = _uniform_results()
    out = tmp_path / "study.pdf"
    before = os.environ.get("SOURCE_DATE_EPOCH")
    assert pdf_engine("auto") == "weasyprint"
    assert write_report_pdf(_study(results), out) == "weasyprint"
    data = out.read_bytes()
    assert data[:5] == b"%PDF-"
    assert data.count(b"/Subtype /Image") >= 3 or data.count(b"/Subtype/Image") >= 3  # the three pictures
    write_report_pdf(_study(results), tmp_path / "again.pdf")
    assert (tmp_path / "again.pdf").read_bytes() == data
    assert os.environ.get("SOURCE_DATE_EPOCH") == before  # the process environment is left as it was


def test_write_study_writes_every_output(tmp_path):
    from hirad.studies.report import write_study

    results = _uniform_results()
    got = write_study(_study(results), tmp_path / "study", engine="matplotlib")
    names = sorted(os.listdir(tmp_path / "study"))
    assert names == sorted(["hall.csv", "hall.json", "hall.png", "board.csv", "board.json", "board.png",
                            "report.html", "report.pdf"])
    assert got["pdf_engine"] == "matplotlib" and len(got["files"]) == 8
    assert (tmp_path / "study" / "hall.png").read_bytes() == _picture(results[0])
    assert json.loads((tmp_path / "study" / "board.json").read_text())["stats"]["em"] == 500.0


def test_pdf_engine_names():
    with pytest.raises(StudyError, match="PDF engine 'latex'"):
        pdf_engine("latex")
