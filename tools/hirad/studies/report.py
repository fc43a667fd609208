"""The study report: one self-contained HTML page (and a PDF of it) per study.

The page holds the luminaire schedule, every grid's statistics (Em, Emin, Emax, U0, Ud and the
maintained Em, Emin, Emax) with its false-colour picture, further pictures (a luminance view),
the units, the maintenance factor, hirad's version and the solver's figures (residual, energy
balance). A daylight bake adds its daylight factor grids (mean, least and greatest DF, U0 =
DFmin/DFmean, the area with DF >= 2 %, the outside illuminance, each grid's DF picture) and its
annual results (the weather file, the site, the hours counted; per grid sDA300/50 %,
ASE1000/250 h, mean DA300, the three UDI bands, the EN 17037 level, with the DA300, UDI and
direct-sun heat maps): :func:`daylight_parts` reads them from the bake's grids directory. Pictures are embedded as base64 ``data:`` URIs and the style sheet is inline: the file
needs nothing else, offline or mailed to a client. Every text from the caller is HTML-escaped.
No clock is read: the same study gives the same bytes (a date, if wanted, is the caller's
``subtitle`` or a ``solver`` entry).

PDF (:func:`write_report_pdf`): WeasyPrint renders the very same HTML (engine "weasyprint",
the default when it imports; it fetches no URL but ``data:``; the font subsets' timestamps are
pinned by SOURCE_DATE_EPOCH=0 for the call, so the bytes are reproducible). Without it, engine
"matplotlib" draws the same tables and pictures on pages with matplotlib's PdfPages.
"""

from __future__ import annotations

import base64
import html
import io
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Optional, Sequence

from hirad import __version__
from hirad.files import atomic_path, write_text

from .evaluate import GridResult
from .outputs import UNIT_SYSTEMS, unit_system
from .pictures import grid_picture
from .spec import StudyError

LUMINAIRE_COLUMNS = (("type", "Type"), ("count", "Count"), ("lumens", "Lumens per luminaire (lm)"),
                     ("ies", "IES file"))
UNITS_TEXT = ("Illuminance E in lux (lx = lm/m²), luminance in cd/m², luminous flux in lumens (lm), "
              "lengths in metres (m). Maintained values are the maintenance factor × the values of the new "
              "installation; U0 = Emin/Em and Ud = Emin/Emax are ratios.")
RADIOMETRIC_TEXT = ("Radiometric units: irradiance E in W/m², radiance in W/(m² sr), exitance in W/m², lengths in "
                    "metres (m). Each value is Y = 0.2126 R + 0.7152 G + 0.0722 B of the linear Rec.709 channels. "
                    "Maintained values are the maintenance factor × the values of the new installation; "
                    "U0 = Emin/Em and Ud = Emin/Emax are ratios.")


def units_text(units: str) -> str:
    """The report's units paragraph for "photometric" or "radiometric"."""
    unit_system(units)
    return UNITS_TEXT if units == "photometric" else RADIOMETRIC_TEXT


def stat_rows(units: str = "photometric") -> tuple:
    """(key, label) of the statistics, labels in the unit system's unit."""
    u = unit_system(units)["unit_text"]
    return (("em", f"Em ({u})"), ("emin", f"Emin ({u})"), ("emax", f"Emax ({u})"), ("u0", "U0 = Emin/Em"),
            ("ud", "Ud = Emin/Emax"), ("em_maintained", f"maintained Em ({u})"),
            ("emin_maintained", f"maintained Emin ({u})"), ("emax_maintained", f"maintained Emax ({u})"))


STAT_ROWS = stat_rows("photometric")
LUMINANCE_FILE = "luminance.camera.png"  # the camera luminance image beside the grids


@dataclass
class Study:
    """What a report shows. `luminaires`: dicts with type, count, lumens, ies (other keys
    become further columns); `solver`: the solver's figures (residual, energy_balance, and
    anything else to show), values numbers or text; `pictures`: extra (caption, PNG bytes).
    `unit_system`: "photometric" (lux, cd/m^2) or "radiometric" (W/m^2, W/(m^2 sr)): the labels
    of the tables, the grid pictures' legends and the per-grid CSV and JSON; None reads it from
    `units` (a text starting "Radiometric" is radiometric), and `units` left at its default
    follows `unit_system`. `luminance`: an optional (caption, PNG bytes) luminance image of a
    camera view (pictures.camera_luminance_picture), shown after the grids."""

    results: Sequence[GridResult]
    maintenance_factor: float
    luminaires: Sequence[Mapping[str, Any]] = ()
    solver: Mapping[str, Any] = field(default_factory=dict)
    title: str = "Lighting study"
    subtitle: str = ""
    units: str = UNITS_TEXT
    pictures: Sequence[tuple[str, bytes]] = ()
    version: str = __version__
    grid_pictures: Optional[Mapping[str, bytes]] = None  # name -> PNG; drawn when absent
    unit_system: Optional[str] = None
    luminance: Optional[tuple[str, bytes]] = None
    # daylight (daylight_parts): report.json's grids.daylight_factor with "pictures" {grid: PNG},
    # and grids.annual with "pictures" {grid: [(caption, PNG)]} and per grid "udi_bands"
    daylight_factor: Optional[Mapping[str, Any]] = None
    annual: Optional[Mapping[str, Any]] = None

    def __post_init__(self):
        if self.unit_system is None:
            self.unit_system = "radiometric" if str(self.units).lstrip().lower().startswith("radiometric") else "photometric"
        unit_system(self.unit_system)
        if self.units == UNITS_TEXT and self.unit_system == "radiometric":
            self.units = RADIOMETRIC_TEXT
        if self.luminance is not None:
            if (not isinstance(self.luminance, (tuple, list)) or len(self.luminance) != 2
                    or not isinstance(self.luminance[1], (bytes, bytearray))):
                raise StudyError("report: luminance must be (caption, PNG bytes)")

    @property
    def unit(self) -> str:
        return UNIT_SYSTEMS[self.unit_system]["unit_text"]

    def picture_of(self, result: GridResult) -> bytes:
        if self.grid_pictures and result.name in self.grid_pictures:
            return self.grid_pictures[result.name]
        return grid_picture(result, units=self.unit_system)

    def all_pictures(self) -> list[tuple[str, bytes]]:
        """The luminance image (if any) and then the extra pictures, as (caption, PNG)."""
        out = [tuple(self.luminance)] if self.luminance is not None else []
        return out + [tuple(p) for p in self.pictures]


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return f"{v:,}".replace(",", " ")
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e7):
            return f"{v:.4g}"
        return f"{v:.4g}" if abs(v) < 1 else f"{v:.2f}" if abs(v) < 1e4 else f"{v:.0f}"
    return str(v)


def _esc(v: Any) -> str:
    return html.escape(_fmt(v), quote=True)


def _data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _luminaire_columns(luminaires) -> list[tuple[str, str]]:
    cols = list(LUMINAIRE_COLUMNS)
    known = {k for k, _ in cols}
    for row in luminaires:
        for k in row:
            if k not in known:
                known.add(k)
                cols.append((k, str(k)))
    return cols


def _check(study: Study) -> None:
    if not (0 < study.maintenance_factor <= 1):
        raise StudyError(f"report: maintenance factor {study.maintenance_factor} is not in (0, 1]")
    for r in study.results:
        if abs(r.stats.maintenance_factor - study.maintenance_factor) > 1e-12:
            raise StudyError(f"report: grid {r.name} was evaluated with maintenance factor "
                             f"{r.stats.maintenance_factor}, the report states {study.maintenance_factor}")
    for i, row in enumerate(study.luminaires):
        if not isinstance(row, Mapping):
            raise StudyError(f"report: luminaire {i} is not a mapping of type, count, lumens, ies")


def grid_summary(result: GridResult) -> list[tuple[str, str]]:
    """(label, value) lines describing a grid (kind, measure, points, spacing, area)."""
    g = result.grid
    m = g.measure
    measure = m.type.replace("_", "-")
    if m.azimuth is not None:
        measure += f", facing azimuth {m.azimuth:g}°"
    if m.type in ("cylindrical", "semi_cylindrical"):
        measure += f", {m.azimuths} azimuths"
    rows = [("kind", g.kind), ("measure", measure), ("points", _fmt(len(g.points)))]
    if g.spacing:
        rows.append(("spacing (m)", f"{g.spacing[0]:.4g} × {g.spacing[1]:.4g}"))
    if g.rule:
        rows.append(("EN 12464-1 rule", f"d = {g.rule['d']:.4g} m, p = {g.rule['p']:.4g} m"))
    if g.area is not None:
        rows.append(("evaluation area (m²)", f"{g.area:.4g}"))
    if g.source:
        rows.append(("points from", g.source))
    return rows


_SHORT_LABELS = ("Em", "Emin", "Emax", "U0", "Ud", "Em maint.", "Emin maint.", "Emax maint.")

_CSS = """
body{font-family:DejaVu Sans,Helvetica,Arial,sans-serif;font-size:10pt;margin:2em;color:#222}
h1{font-size:18pt;margin-bottom:0.2em} h2{font-size:13pt;margin-top:1.6em;border-bottom:1px solid #999}
h3{font-size:11pt} table{border-collapse:collapse;margin:0.5em 0} th,td{border:1px solid #bbb;padding:3px 8px}
th{background:#eee;text-align:left} td.n{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%} .grid{page-break-inside:avoid} .sub{color:#555}
#grid-summary{font-size:8.5pt} #grid-summary td,#grid-summary th{padding:2px 5px}
@page{size:A4;margin:15mm} @media print{body{margin:0}}
"""


def render_html(study: Study) -> str:
    """The report as one self-contained HTML document."""
    _check(study)
    out = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
           f"<title>{html.escape(study.title)}</title>", f"<style>{_CSS}</style></head><body>",
           f"<h1>{html.escape(study.title)}</h1>"]
    if study.subtitle:
        out.append(f'<p class="sub">{html.escape(study.subtitle)}</p>')
    out.append("<table>")
    out.append(f'<tr><th>maintenance factor</th><td class="n" id="maintenance-factor">{_esc(study.maintenance_factor)}</td></tr>')
    out.append(f'<tr><th>hirad version</th><td id="hirad-version">{html.escape(study.version)}</td></tr>')
    out.append(f"<tr><th>grids</th><td class=\"n\">{len(study.results)}</td></tr></table>")
    out.append(f'<h2>Units</h2><p id="units">{html.escape(study.units)}</p>')

    out.append("<h2>Luminaire schedule</h2>")
    if study.luminaires:
        cols = _luminaire_columns(study.luminaires)
        out.append('<table id="luminaires"><tr>' + "".join(f"<th>{html.escape(t)}</th>" for _, t in cols) + "</tr>")
        total = 0.0
        for row in study.luminaires:
            out.append("<tr>" + "".join(
                f'<td{" class=n" if isinstance(row.get(k), (int, float)) else ""}>{_esc(row.get(k))}</td>' for k, _ in cols) + "</tr>")
            c, lm = row.get("count"), row.get("lumens")
            if isinstance(c, (int, float)) and isinstance(lm, (int, float)):
                total += c * lm
        out.append("</table>")
        out.append(f'<p>Total luminous flux of the luminaires: <span id="total-lumens">{_esc(total)}</span> lm.</p>')
    else:
        out.append("<p>No luminaires given.</p>")

    out.append("<h2>Solver</h2>")
    solver = dict(study.solver)
    out.append('<table id="solver">')
    for key, label in (("residual", "relative residual"), ("energy_balance", "energy balance")):
        out.append(f"<tr><th>{label}</th><td class=\"n\">{_esc(solver.pop(key)) if key in solver else 'not given'}</td></tr>")
    for k, v in solver.items():
        out.append(f"<tr><th>{html.escape(str(k))}</th><td>{_esc(v)}</td></tr>")
    out.append("</table>")

    rows = stat_rows(study.unit_system)
    out.append("<h2>Grids</h2>")
    out.append('<table id="grid-summary"><tr><th>grid</th>' + "".join(f"<th>{t}</th>" for _, t in rows) + "</tr>")
    for r in study.results:
        st = r.stats.as_dict()
        out.append(f"<tr><td>{html.escape(r.name)}</td>" + "".join(f'<td class="n">{_esc(st[k])}</td>' for k, _ in rows) + "</tr>")
    out.append("</table>")
    for r in study.results:
        st = r.stats.as_dict()
        gid = html.escape(r.name, quote=True)
        out.append(f'<div class="grid" id="grid-{gid}"><h3>{html.escape(r.name)}</h3><table>')
        for label, value in grid_summary(r):
            out.append(f"<tr><th>{html.escape(label)}</th><td>{html.escape(value)}</td></tr>")
        for k, label in rows:
            out.append(f'<tr><th>{label}</th><td class="n" data-key="{k}">{_esc(st[k])}</td></tr>')
        out.append("</table>")
        what = UNIT_SYSTEMS[study.unit_system]["quantity"]
        out.append(f'<img alt="false-colour {what} of {gid}" src="{_data_uri(study.picture_of(r))}">')
        out.append("</div>")
    out += _daylight_factor_html(study.daylight_factor)
    out += _annual_html(study.annual)
    if study.luminance is not None:
        caption, png = study.luminance
        out.append(f'<h2>Luminance</h2><div class="grid" id="luminance"><h3>{html.escape(caption)}</h3>'
                   f'<img alt="{html.escape(caption, quote=True)}" src="{_data_uri(png)}"></div>')
    for caption, png in study.pictures:
        out.append(f'<div class="grid"><h3>{html.escape(caption)}</h3>'
                   f'<img alt="{html.escape(caption, quote=True)}" src="{_data_uri(png)}"></div>')
    out.append("</body></html>")
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------------------
# daylight: daylight factor and annual results (hirad.daylight.study writes them)
# ---------------------------------------------------------------------------------------------

#: (key, label, kind) of a daylight factor grid's row: kind "df" a DF in %, "ratio", "fraction"
DF_ROWS = (("em", "mean DF (%)", "df"), ("emin", "least DF, DFmin (%)", "df"), ("emax", "greatest DF (%)", "df"),
           ("u0", "uniformity U0 = DFmin / DFmean", "ratio"),
           ("area_fraction_df_2", "area with DF ≥ 2 %", "fraction"))
#: (key, label, kind) of an annual grid's row
ANNUAL_ROWS = (("sDA300/50%", "sDA300/50 % (area with DA300 ≥ 50 %)", "fraction"),
               ("ASE1000/250h", "ASE1000/250 h (area with direct sun > 1000 lx over 250 occupied hours)", "fraction"),
               ("mean_DA300", "mean DA300 (occupied hours ≥ 300 lx)", "fraction"),
               ("udi_below_100", "UDI < 100 lx (fell short), mean", "fraction"),
               ("mean_UDI_100_3000", "UDI 100–3000 lx (useful), mean", "fraction"),
               ("udi_above_3000", "UDI > 3000 lx (exceeded), mean", "fraction"),
               ("EN17037_level", "EN 17037 daylight provision (illuminance method)", "text"),
               ("EN17037_minimum_met", "EN 17037 minimum level met", "text"),
               ("occupied_hours", "occupied hours counted", "count"))
ANNUAL_PICTURES = (("da300", "Daylight autonomy DA300 (% of occupied hours)"),
                   ("udi", "Useful daylight illuminance 100–3000 lx (% of occupied hours)"),
                   ("sunlit_hours", "Occupied hours of direct sun above 1000 lx"))
_UDI_COLUMNS = ("udi_below_100", "udi_100_3000", "udi_above_3000")


def _value_text(v: Any, kind: str) -> str:
    if v is None:
        return "–"
    if kind == "df" and isinstance(v, (int, float)):
        return f"{v:.2f} %"
    if kind == "fraction" and isinstance(v, (int, float)) and not isinstance(v, bool):
        return f"{100 * v:.1f} %"
    if kind == "ratio" and isinstance(v, (int, float)):
        return f"{v:.3f}"
    if kind == "text" and v is None:
        return "none met"
    return _fmt(v)


def _value_cell(grid: str, key: str, v: Any, kind: str) -> str:
    """A table cell with the value shown and its full value in data-value (repr of a float)."""
    data = "" if v is None else (repr(float(v)) if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v))
    text = _value_text(v, kind) if not (kind == "text" and v is None) else "none met"
    return (f'<td class="n" data-grid="{html.escape(grid, quote=True)}" data-key="{html.escape(key, quote=True)}" '
            f'data-value="{html.escape(data, quote=True)}">{html.escape(text)}</td>')


def _daylight_factor_html(df: Optional[Mapping[str, Any]]) -> list[str]:
    if not df:
        return []
    grids = df.get("grids") or {}
    pictures = df.get("pictures") or {}
    out = ['<h2>Daylight factor</h2>',
           f'<p>{html.escape(str(df.get("formula", "DF = 100 E / E_h,out")))}: E is the illuminance at a point '
           'under the overcast sky without sun (direct sky light through the openings and the interreflected '
           'light), E_h,out the same sky\'s illuminance on an unobstructed horizontal plane outside: '
           f'<span id="df-outside" data-value="{df.get("outside_horizontal_illuminance_lux")!r}">'
           f'{_esc(df.get("outside_horizontal_illuminance_lux"))}</span> lx.</p>',
           '<table id="daylight-factor-summary"><tr><th>grid</th>'
           + "".join(f"<th>{html.escape(label)}</th>" for _, label, _ in DF_ROWS) + "</tr>"]
    for name, st in grids.items():
        out.append(f"<tr><td>{html.escape(name)}</td>"
                   + "".join(_value_cell(name, k, st.get(k), kind) for k, _, kind in DF_ROWS) + "</tr>")
    out.append("</table>")
    out.append('<p id="df-en17037">EN 17037 daylight factor targets (D_T over 50 % and D_TM over 95 % of the '
               "reference plane, from the site's median external diffuse illuminance) are not computed for a "
               "daylight factor study: the sky here has no site; the annual study states the EN 17037 level by the "
               "illuminance method.</p>")
    for name, st in grids.items():
        gid = html.escape(name, quote=True)
        out.append(f'<div class="grid" id="df-{gid}"><h3>Daylight factor: {html.escape(name)}</h3><table>')
        if st.get("points") is not None:
            out.append(f'<tr><th>points</th><td class="n">{_esc(st.get("points"))}</td></tr>')
        for k, label, kind in DF_ROWS:
            out.append(f"<tr><th>{html.escape(label)}</th>{_value_cell(name, k, st.get(k), kind)}</tr>")
        out.append("</table>")
        if name in pictures:
            out.append(f'<img alt="daylight factor of {gid}" src="{_data_uri(pictures[name])}">')
        out.append("</div>")
    return out


def _site_text(site: Optional[Mapping[str, Any]]) -> str:
    if not site:
        return "not stated"
    lat, lon = site.get("latitude"), site.get("longitude")
    parts = []
    if isinstance(lat, (int, float)) and isinstance(lon, (int, float)):
        parts.append(f"latitude {lat:.4f}°, longitude {lon:.4f}°")
    if isinstance(site.get("elevation"), (int, float)):
        parts.append(f"elevation {site['elevation']:g} m")
    tz = site.get("timezone")
    if isinstance(tz, (int, float)) and not isinstance(tz, bool):
        parts.append(f"UTC{tz:+g} h")
    elif isinstance(tz, str) and tz:
        parts.append(f"time zone {tz}")
    if site.get("from"):
        parts.append(f"from {site['from']}")
    return ", ".join(parts) or "not stated"


def _annual_html(an: Optional[Mapping[str, Any]]) -> list[str]:
    if not an:
        return []
    grids = an.get("grids") or {}
    pictures = an.get("pictures") or {}
    occ = an.get("occupied_hours_of_day") or []
    occ_text = f"{occ[0]:g}:00–{occ[1]:g}:00 every day (IES LM-83)" if len(occ) == 2 else "–"
    out = ["<h2>Annual daylight</h2>", '<table id="annual-context">']
    rows = (("weather file", "weather", html.escape(str(an.get("weather", "–")))),
            ("site", "site", html.escape(_site_text(an.get("site")))),
            ("hours in the year", "hours", _esc(an.get("hours"))),
            ("daytime hours (sun above the horizon)", "daytime_hours", _esc(an.get("daytime_hours"))),
            ("occupied hours of the day", "occupied_hours_of_day", html.escape(occ_text)),
            ("sky patches", "sky_patches", _esc(an.get("sky_patches"))),
            ("method", "method", html.escape(str(an.get("method", "–")))))
    for label, key, text in rows:
        v = an.get(key)
        data = "" if v is None or isinstance(v, (dict, list)) else html.escape(str(v), quote=True)
        extra = ""
        if key == "site" and isinstance(v, Mapping):  # the full values, as for the tables' numbers
            extra = "".join(f' data-{k}="{html.escape(repr(v[k]) if isinstance(v[k], float) else str(v[k]), quote=True)}"'
                            for k in ("latitude", "longitude", "elevation", "timezone") if v.get(k) is not None)
        out.append(f'<tr><th>{html.escape(label)}</th><td data-key="{key}" data-value="{data}"{extra}>{text}</td></tr>')
    out.append("</table>")
    out.append('<table id="annual-summary"><tr><th>grid</th>'
               + "".join(f"<th>{html.escape(label)}</th>" for _, label, _ in ANNUAL_ROWS) + "</tr>")
    for name, g in grids.items():
        out.append(f"<tr><td>{html.escape(name)}</td>"
                   + "".join(_value_cell(name, k, _annual_value(g, k), kind) for k, _, kind in ANNUAL_ROWS) + "</tr>")
    out.append("</table>")
    for name, g in grids.items():
        gid = html.escape(name, quote=True)
        out.append(f'<div class="grid" id="annual-{gid}"><h3>Annual daylight: {html.escape(name)}</h3><table>')
        for k, label, kind in ANNUAL_ROWS:
            out.append(f"<tr><th>{html.escape(label)}</th>{_value_cell(name, k, _annual_value(g, k), kind)}</tr>")
        out.append("</table>")
        for caption, png in pictures.get(name, []):
            out.append(f'<img alt="{html.escape(caption, quote=True)}: {gid}" src="{_data_uri(png)}">')
        out.append("</div>")
    return out


def _annual_value(g: Mapping[str, Any], key: str) -> Any:
    if key in ("udi_below_100", "udi_above_3000"):
        return (g.get("udi_bands") or {}).get(key)
    return g.get(key)


def _read_png(path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise StudyError(f"{path}: cannot read the picture for the report: {e.strerror or e}") from None


def _weighted_columns(path, columns, weights, name: str) -> dict:
    """The weighted means of CSV columns (a StudyError naming the file when it does not fit)."""
    import csv

    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
        head = rows[0]
        data = {c: [float(r[head.index(c)]) for r in rows[1:]] for c in columns}
    except (OSError, IndexError, ValueError) as e:
        raise StudyError(f"{path}: cannot read the grid {name}'s {', '.join(columns)} for the report ({e})") from None
    import numpy as np

    w = np.ones(len(rows) - 1) if weights is None else np.asarray(weights, dtype=np.float64)
    if len(w) != len(rows) - 1 or not w.sum() > 0:
        raise StudyError(f"{path}: {len(rows) - 1} points, the grid {name} has {len(w)}")
    return {c: float(np.average(np.asarray(v), weights=w)) for c, v in data.items()}


def daylight_parts(grids_dir, daylight_factor: Optional[Mapping[str, Any]] = None,
                   annual: Optional[Mapping[str, Any]] = None, results: Sequence[GridResult] = ()) -> dict:
    """Study's `daylight_factor` and `annual` from what a daylight bake wrote into `grids_dir`
    (hirad.daylight.study): report.json's parts with each grid's pictures read from
    daylight_factor/NAME.png and annual/NAME_{da300,udi,sunlit_hours}.png, and the annual grids' UDI
    bands (below 100, above 3000 lx) as the mean of annual/NAME.csv weighted as the grid's points
    (`results`). A missing file is a StudyError naming it."""
    from pathlib import Path

    out: dict = {}
    d = Path(grids_dir)
    weights = {r.name: r.grid.weights for r in results}
    if daylight_factor:
        part = dict(daylight_factor)
        part["pictures"] = {name: _read_png(d / "daylight_factor" / f"{name}.png") for name in part.get("grids", {})}
        out["daylight_factor"] = part
    if annual:
        part = dict(annual)
        grids = {}
        pictures = {}
        for name, g in (annual.get("grids") or {}).items():
            means = _weighted_columns(d / "annual" / f"{name}.csv", _UDI_COLUMNS, weights.get(name), name)
            grids[name] = {**g, "udi_bands": {"udi_below_100": means["udi_below_100"],
                                              "udi_above_3000": means["udi_above_3000"]}}
            pictures[name] = [(caption, _read_png(d / "annual" / f"{name}_{suffix}.png"))
                              for suffix, caption in ANNUAL_PICTURES]
        part["grids"], part["pictures"] = grids, pictures
        out["annual"] = part
    return out


def write_report_html(study: Study, path) -> str:
    """Writes the HTML report atomically; returns its text."""
    text = render_html(study)
    write_text(path, text)
    return text


def pdf_engine(engine: str = "auto") -> str:
    """The PDF engine that `engine` names: "weasyprint", "matplotlib", or "auto" (WeasyPrint
    when it imports and finds its Pango library, else matplotlib)."""
    if engine not in ("auto", "weasyprint", "matplotlib"):
        raise StudyError(f"report PDF engine {engine!r}: auto, weasyprint or matplotlib")
    if engine != "auto":
        return engine
    try:
        import weasyprint  # noqa: F401
    except (ImportError, OSError):  # not installed, or its Pango library missing
        return "matplotlib"
    return "weasyprint"


def write_report_pdf(study: Study, path, engine: str = "auto") -> str:
    """Writes the PDF report atomically; returns the engine used."""
    engine = pdf_engine(engine)
    if engine == "weasyprint":
        data = _pdf_weasyprint(render_html(study))
    else:
        data = _pdf_matplotlib(study)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return engine


def _pdf_weasyprint(text: str) -> bytes:
    try:
        import weasyprint
    except (ImportError, OSError) as e:
        raise StudyError(f"report PDF: WeasyPrint cannot be used here ({e}); use engine 'matplotlib'") from None
    kwargs = {}
    try:
        from weasyprint.urls import URLFetcher

        kwargs["url_fetcher"] = URLFetcher(allowed_protocols={"data"}, fail_on_errors=True)
    except (ImportError, TypeError):
        pass
    # fontTools stamps the embedded font subsets with the clock unless SOURCE_DATE_EPOCH is set:
    # set it (to 0) for the call when the caller has not, so the same study gives the same bytes
    import os

    had = "SOURCE_DATE_EPOCH" in os.environ
    if not had:
        os.environ["SOURCE_DATE_EPOCH"] = "0"
    try:
        return weasyprint.HTML(string=text, **kwargs).write_pdf()
    finally:
        if not had:
            os.environ.pop("SOURCE_DATE_EPOCH", None)


def _pdf_matplotlib(study: Study) -> bytes:
    _check(study)
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure
    from matplotlib.image import imread

    buf = io.BytesIO()
    a4 = (8.27, 11.69)

    def table(ax, rows, cols=None, fontsize=8):
        ax.axis("off")
        if not rows:
            return
        t = ax.table(cellText=rows, colLabels=cols, loc="upper left", cellLoc="left")
        t.auto_set_font_size(False)
        t.set_fontsize(fontsize)
        t.scale(1.0, 1.3)

    with PdfPages(buf, metadata={"Creator": f"hirad {study.version}", "CreationDate": None}) as pdf:
        fig = Figure(figsize=a4)
        fig.text(0.08, 0.95, study.title, fontsize=16, weight="bold")
        if study.subtitle:
            fig.text(0.08, 0.925, study.subtitle, fontsize=9, color="#555")
        fig.text(0.08, 0.895, f"maintenance factor {_fmt(study.maintenance_factor)}    hirad {study.version}", fontsize=9)
        fig.text(0.08, 0.87, "Units: " + study.units, fontsize=7, wrap=True)
        cols = _luminaire_columns(study.luminaires)
        ax = fig.add_axes((0.08, 0.62, 0.84, 0.2))
        ax.set_title("Luminaire schedule", loc="left", fontsize=11)
        table(ax, [[_fmt(r.get(k)) for k, _ in cols] for r in study.luminaires] or [["no luminaires given"]],
              [t for _, t in cols] if study.luminaires else None)
        solver = dict(study.solver)
        srows = [["relative residual", _fmt(solver.pop("residual")) if "residual" in solver else "not given"],
                 ["energy balance", _fmt(solver.pop("energy_balance")) if "energy_balance" in solver else "not given"]]
        srows += [[str(k), _fmt(v)] for k, v in solver.items()]
        ax = fig.add_axes((0.08, 0.38, 0.84, 0.2))
        ax.set_title("Solver", loc="left", fontsize=11)
        table(ax, srows)
        ax = fig.add_axes((0.08, 0.05, 0.84, 0.28))
        ax.set_title("Grids", loc="left", fontsize=11)
        rows = stat_rows(study.unit_system)
        table(ax, [[r.name] + [_fmt(r.stats.as_dict()[k]) for k, _ in rows] for r in study.results],
              ["grid"] + list(_SHORT_LABELS), fontsize=6)
        ax.text(0.0, -0.02, f"Em, Emin, Emax in {study.unit}; maint. = maintained (MF x the new installation's value)",
                transform=ax.transAxes, fontsize=6, va="top")
        pdf.savefig(fig)
        for r in study.results:
            fig = Figure(figsize=a4)
            fig.text(0.08, 0.95, f"Grid {r.name}", fontsize=14, weight="bold")
            st = r.stats.as_dict()
            ax = fig.add_axes((0.08, 0.62, 0.84, 0.3))
            table(ax, [[a, b] for a, b in grid_summary(r)] + [[t, _fmt(st[k])] for k, t in rows])
            ax = fig.add_axes((0.05, 0.04, 0.9, 0.55))
            ax.imshow(imread(io.BytesIO(study.picture_of(r)), format="png"))
            ax.axis("off")
            pdf.savefig(fig)
        _daylight_pages(pdf, study, table, a4)
        for caption, png in study.all_pictures():
            fig = Figure(figsize=a4)
            fig.text(0.08, 0.95, caption, fontsize=14, weight="bold")
            ax = fig.add_axes((0.05, 0.3, 0.9, 0.6))
            ax.imshow(imread(io.BytesIO(png), format="png"))
            ax.axis("off")
            pdf.savefig(fig)
    return buf.getvalue()


def _daylight_pages(pdf, study: Study, table, a4) -> None:
    """The matplotlib PDF's daylight factor and annual pages (as the HTML shows them)."""
    from matplotlib.figure import Figure
    from matplotlib.image import imread

    df = study.daylight_factor or {}
    for name, st in (df.get("grids") or {}).items():
        fig = Figure(figsize=a4)
        fig.text(0.08, 0.95, f"Daylight factor: {name}", fontsize=14, weight="bold")
        fig.text(0.08, 0.92, f"{df.get('formula', 'DF = 100 E / E_h,out')}, E_h,out = "
                             f"{_fmt(df.get('outside_horizontal_illuminance_lux'))} lx", fontsize=8)
        ax = fig.add_axes((0.08, 0.66, 0.84, 0.22))
        table(ax, [[label, _value_text(st.get(k), kind)] for k, label, kind in DF_ROWS])
        png = (df.get("pictures") or {}).get(name)
        if png:
            ax = fig.add_axes((0.05, 0.04, 0.9, 0.58))
            ax.imshow(imread(io.BytesIO(png), format="png"))
            ax.axis("off")
        pdf.savefig(fig)
    an = study.annual or {}
    for name, g in (an.get("grids") or {}).items():
        fig = Figure(figsize=a4)
        fig.text(0.08, 0.95, f"Annual daylight: {name}", fontsize=14, weight="bold")
        fig.text(0.08, 0.925, f"weather {an.get('weather', '-')}", fontsize=7)
        fig.text(0.08, 0.905, f"site: {_site_text(an.get('site'))}; {_fmt(an.get('hours'))} hours, "
                              f"{_fmt(an.get('daytime_hours'))} daytime", fontsize=7)
        ax = fig.add_axes((0.08, 0.66, 0.84, 0.22))
        table(ax, [[label, "none met" if kind == "text" and _annual_value(g, k) is None
                    else _value_text(_annual_value(g, k), kind)] for k, label, kind in ANNUAL_ROWS], fontsize=7)
        pics = (an.get("pictures") or {}).get(name, [])
        for i, (caption, png) in enumerate(pics):
            ax = fig.add_axes((0.03 + i * 0.32, 0.25, 0.31, 0.35))
            ax.imshow(imread(io.BytesIO(png), format="png"))
            ax.set_title(caption, fontsize=6)
            ax.axis("off")
        pdf.savefig(fig)


def write_study(study: Study, out_dir, *, pdf: bool = True, engine: str = "auto") -> dict:
    """Writes every output of a study into the directory `out_dir` (made if missing), each
    file atomically: per grid NAME.csv, NAME.json and NAME.png (in the study's unit system);
    luminance.camera.png when the study has a luminance image; report.html and (if `pdf`) report.pdf.
    Returns {"files": [paths], "pdf_engine": name or None}."""
    from pathlib import Path

    from .outputs import write_grid_csv, write_grid_json
    from .pictures import write_png

    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise StudyError(f"{out}: cannot make the directory: {e.strerror or e}") from None
    pictures = dict(study.grid_pictures or {})
    files = []
    for r in study.results:
        png = pictures.get(r.name) or grid_picture(r, units=study.unit_system)
        pictures[r.name] = png
        for suffix, write in (("csv", write_grid_csv), ("json", write_grid_json)):
            write(r, out / f"{r.name}.{suffix}", study.unit_system)
            files.append(out / f"{r.name}.{suffix}")
        write_png(out / f"{r.name}.png", png)
        files.append(out / f"{r.name}.png")
    if study.luminance is not None:
        if any(f"{r.name}.png" == LUMINANCE_FILE for r in study.results):
            raise StudyError(f"report: a grid named {LUMINANCE_FILE[:-4]!r} would overwrite the luminance image; rename the grid")
        write_png(out / LUMINANCE_FILE, study.luminance[1])
        files.append(out / LUMINANCE_FILE)
    drawn = Study(**{**study.__dict__, "grid_pictures": pictures})
    write_report_html(drawn, out / "report.html")
    files.append(out / "report.html")
    used = None
    if pdf:
        used = write_report_pdf(drawn, out / "report.pdf", engine)
        files.append(out / "report.pdf")
    return {"files": files, "pdf_engine": used}
