"""`hirad render` refuses an image size it could not allocate, before reading the solution."""

from __future__ import annotations

import subprocess
import sys


def test_render_of_a_huge_image_is_a_usage_error_not_an_allocation(tmp_path):
    fake = tmp_path / "solution.usda"
    fake.write_text("#usda 1.0\n")
    proc = subprocess.run([sys.executable, "-m", "hirad.cli", "render", str(fake), "--width", "100000",
                           "--height", "100000", "-o", str(tmp_path / "x.png")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "--width" in proc.stderr and "8192" in proc.stderr
    assert not (tmp_path / "x.png").exists()
