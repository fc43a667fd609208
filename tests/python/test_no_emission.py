"""A scene that emits nothing is an error for a bake: non-zero exit, a clear message, no output."""

from __future__ import annotations

import subprocess
import sys

from hirad_e2e_helpers import CORNELL, write_config


def test_a_dark_scene_is_refused_before_any_work(tmp_path):
    text = CORNELL.read_text()
    # the bundled box's only emitter is the light mesh (MeshLightAPI and an emissive material)
    import re

    dark, n = re.subn(r"(color3f inputs:emissiveColor = )\([^)]*\)", r"\1(0, 0, 0)", text)
    dark, m = re.subn(r"float inputs:intensity = 1\b", "float inputs:intensity = 0", dark)
    assert n >= 1 and m >= 1, "the fixture's emitter was not found"
    scene = tmp_path / "dark.usda"
    scene.write_text(dark)
    out = tmp_path / "out"
    cfg = write_config(tmp_path / "c.yaml", scene, out, method="flat")
    proc = subprocess.run([sys.executable, "-m", "hirad.cli", "bake", str(cfg)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 3, proc.stderr
    assert "nothing emits light" in proc.stderr and str(scene) in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.partial")]
