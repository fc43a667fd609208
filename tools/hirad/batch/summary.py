"""The study's summary: `summary.csv` and `summary.html` in the study's output, one row per job,
comparing the variants' headline numbers from each finished job's report.json: the overrides
that make the variant, the bake's timings, patch/link/texel counts, the energy balance, and
each calculation grid's Em and U0."""

from __future__ import annotations

import csv
import html
import io
import json
from pathlib import Path
from typing import Any

from .. import files
from .index import Index, status_rows
from .study import Study

STAGES = ("read scene", "form factors", "links", "refine", "solve", "lightmaps", "grids", "total")


def _report(path: Path) -> dict | None:
    try:
        return json.loads((Path(path) / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def summary_rows(study: Study, index: Index) -> tuple[list[str], list[dict[str, Any]]]:
    rows, grid_cols, stage_cols = [], [], []
    for r in status_rows(index):
        rep = _report(r["output"]) if r["status"] == "done" else None
        row: dict[str, Any] = {"job": r["name"], "status": r["status"], "attempts": r["attempts"],
                               "variant": " ".join(o for o in r["overrides"] if not o.startswith("output=")
                                                   and o not in _shared(study)),
                               "job_seconds": r["seconds"]}
        if rep:
            t = rep.get("timings_s", {})
            for k, v in t.items():
                row[f"time {k} (s)"] = v
                if f"time {k} (s)" not in stage_cols:
                    stage_cols.append(f"time {k} (s)")
            c = rep.get("counts", {})
            row.update({"patches": c.get("patches"), "links": c.get("links"), "rays": c.get("rays")})
            atlas = (rep.get("outputs") or {}).get("lightmap_atlas") or {}
            row["texels"] = atlas.get("covered_texels")
            row["texels_per_metre"] = atlas.get("texels_per_metre")
            eb = rep.get("energy_balance") or {}
            row["energy_balance_error"] = eb.get("max_relative_error")
            sol = rep.get("solver") or {}
            row["iterations"], row["residual"] = sol.get("iterations"), sol.get("residual")
            g = rep.get("grids") or {}
            unit = g.get("unit", "")
            for name, st in (g.get("grids") or {}).items():
                for k, label in (("em", f"Em ({unit})"), ("u0", "U0")):
                    col = f"{name} {label}"
                    row[col] = st.get(k)
                    if col not in grid_cols:
                        grid_cols.append(col)
        rows.append(row)
    cols = ["job", "status", "attempts", "variant", "job_seconds", "patches", "links", "rays", "texels",
            "texels_per_metre", "iterations", "residual", "energy_balance_error"] + grid_cols + stage_cols
    return cols, rows


def _shared(study: Study) -> set[str]:
    """Overrides every job has (the study's `set`): not what tells the variants apart."""
    sets = [set(j.overrides) for j in study.jobs]
    return set.intersection(*sets) if sets else set()


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def write_summary(study: Study, index: Index) -> tuple[Path, Path]:
    cols, rows = summary_rows(study, index)
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(cols)
    for r in rows:
        w.writerow([_fmt(r.get(c)) for c in cols])
    csv_path, html_path = study.output / "summary.csv", study.output / "summary.html"
    files.write_text(csv_path, buf.getvalue())
    numeric = [c for c in cols if any(isinstance(r.get(c), (int, float)) and not isinstance(r.get(c), bool)
                                      for r in rows) and c not in ("attempts",)]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = []
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c)
            cls = ""
            if c in numeric and isinstance(v, (int, float)):
                vals = [x.get(c) for x in rows if isinstance(x.get(c), (int, float))]
                if len(set(vals)) > 1:
                    cls = " class='min'" if v == min(vals) else " class='max'" if v == max(vals) else ""
            if c == "status":
                cls = f" class='{html.escape(str(v))}'"
            cells.append(f"<td{cls}>{html.escape(_fmt(v))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>Study {html.escape(study.name)}</title>
<style>
body {{ font-family: sans-serif; margin: 2em; }}
table {{ border-collapse: collapse; font-size: 13px; }}
th, td {{ border: 1px solid #ccc; padding: 3px 6px; text-align: right; white-space: nowrap; }}
th {{ background: #eee; position: sticky; top: 0; }}
td:nth-child(1), td:nth-child(4) {{ text-align: left; }}
td.min {{ background: #dde9ff; }} td.max {{ background: #ffe3d6; }}
td.failed, td.cancelled, td.interrupted {{ background: #f8c0c0; }} td.done {{ background: #d4f0d4; }}
</style></head><body>
<h1>Study {html.escape(study.name)}</h1>
<p>{len(rows)} jobs from {html.escape(str(study.path))} (base config {html.escape(str(study.base))});
shared overrides: {html.escape(' '.join(sorted(o for o in _shared(study) if not o.startswith('output='))) or 'none')}.
Smallest value of a column in blue, largest in orange. Times in seconds.</p>
<table><thead><tr>{head}</tr></thead><tbody>
{chr(10).join(body)}
</tbody></table></body></html>
"""
    files.write_text(html_path, page)
    return csv_path, html_path
