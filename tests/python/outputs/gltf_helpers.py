"""Helpers for the glTF export tests: the Khronos validator and three.js in headless Chromium
(tests/web/, installed by `make test` through the Makefile's .stamp-web), and reading a GLB's
JSON chunk. Not a test module."""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[3]
WEB = REPO / "tests" / "web"


def _node() -> str:
    node = shutil.which("node")
    assert node, "node is missing: `make test` installs it (Makefile .stamp-web)"
    for pkg in ("three", "gltf-validator", "playwright-core"):
        assert (WEB / "node_modules" / pkg / "package.json").exists(), \
            f"tests/web/node_modules/{pkg} is missing: run `make test` (npm ci in tests/web)"
    return node


def validate(glb: Path) -> dict:
    """The Khronos glTF Validator's report of one GLB (tests/web/validate.mjs)."""
    r = subprocess.run([_node(), str(WEB / "validate.mjs"), str(glb)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def render(glb: Path, out_json: Path, width: int, height: int, mode: str = "lightmap",
           camera: str | None = None, png: Path | None = None, exposure: float = 1.0,
           specular: bool = False) -> tuple[np.ndarray, dict]:
    """three.js render of the GLB in headless Chromium: linear RGB floats (H, W, 3), stats."""
    assert Path("/usr/bin/chromium").exists(), "Debian's chromium is missing: run `make test` (Makefile .stamp-web)"
    cmd = [_node(), str(WEB / "render.mjs"), str(glb), str(out_json), "--width", str(width),
           "--height", str(height), "--mode", mode]
    if camera:
        cmd += ["--camera", camera]
    if png:
        cmd += ["--png", str(png), "--exposure", str(exposure)]
    if specular:
        cmd += ["--specular"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr + r.stdout
    data = json.loads(Path(out_json).read_text())
    img = np.asarray(data["rgb"], dtype=np.float64).reshape(height, width, 3)
    return img, data["stats"]


def glb_json(glb: Path) -> dict:
    """The JSON chunk of a GLB (glTF 2.0 section 4.4: 12-byte header, then chunks)."""
    b = Path(glb).read_bytes()
    magic, version, length = struct.unpack_from("<4sII", b, 0)
    assert magic == b"glTF" and version == 2 and length == len(b)
    n, kind = struct.unpack_from("<II", b, 12)
    assert kind == 0x4E4F534A
    return json.loads(b[20:20 + n])
