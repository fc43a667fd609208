"""`hirad ies FILE [--plot]`: the report of an analytic profile, and a bad file's located error."""

from __future__ import annotations

import math
import re
import subprocess
import sys

import numpy as np


def _cos_n_file(path, n: int, i0: float = 1000.0):
    gammas = np.arange(0.0, 90.0 + 1e-9, 0.5)
    cd = i0 * np.cos(np.radians(gammas)) ** n
    lines = ["IESNA:LM-63-2002", "[TEST] cos^n", "TILT=NONE",
             f"1 -1 1 {len(gammas)} 1 1 2 0 0 0", "1 1 0",
             " ".join(f"{g:g}" for g in gammas), "0", " ".join(f"{v:.9g}" for v in cd)]
    path.write_text("\r\n".join(lines) + "\r\n")


def _hirad(*args):
    return subprocess.run([sys.executable, "-m", "hirad.cli", "ies", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_ies_command_reports_the_closed_form_flux_and_writes_the_plot(tmp_path):
    n = 3
    f = tmp_path / "cos3.ies"
    _cos_n_file(f, n)
    proc = _hirad(f, "--plot", tmp_path / "polar.png")
    assert proc.returncode == 0, proc.stderr
    m = re.search(r"lumens \(zonal integration[^)]*\): ([\d.]+) lm", proc.stdout)
    assert m, proc.stdout
    assert abs(float(m.group(1)) - 2 * math.pi * 1000.0 / (n + 1)) <= 1e-3 * 2 * math.pi * 1000.0 / (n + 1)
    assert (tmp_path / "polar.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ies_command_on_a_bad_file_names_file_and_line_and_exits_non_zero(tmp_path):
    f = tmp_path / "bad.ies"
    f.write_text("IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 x\n")
    proc = _hirad(f)
    assert proc.returncode == 3
    assert f"{f}: line 3:" in proc.stderr
    assert "Traceback" not in proc.stderr
