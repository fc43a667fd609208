"""The content key of a bake: a hash of what determines its result, and nothing else.

`Config.fingerprint()` hashes every setting as written, output path and thread count
included, so two bakes of the same scene into two directories differ there. The content key
is what a batch study compares to decide whether a finished job must run again:

- the contents of the scene file and of every file it brings in (sublayers, references,
  payloads, textures, IES profiles: pxr's UsdUtils.ComputeAllDependencies), each named by its
  path relative to the scene's folder (so a scene moved as a whole keeps its key);
- the contents of the config's own files (a light's `ies`, a points grid's `file`);
- every setting that changes what is computed or written (meshing, hierarchy, solver,
  materials, outputs, grids, lights, seed, units, ...);
- the hirad version.

Left out: `output`, `threads` (the result is the same bits whatever the thread count),
`links.store`, `links.memory_budget` and `links.checkpoint_seconds` (where links are kept
and how much of them stays in memory; the result does not depend on them).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

# settings whose value never changes a bake's result (dotted paths into Config.model_dump)
NOT_IN_CONTENT = ("output", "threads", "links.store", "links.memory_budget", "links.checkpoint_seconds")


def _file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def scene_files(scene: Path) -> list[Path]:
    """The scene and every file its composition reads (layers and assets), the scene first;
    only the scene when pxr cannot list them."""
    scene = Path(scene)
    out = [scene]
    try:
        from pxr import UsdUtils

        layers, assets, _ = UsdUtils.ComputeAllDependencies(str(scene))
        for p in [layer.realPath for layer in layers] + list(assets):
            if p and Path(p).is_file() and Path(p) not in out:
                out.append(Path(p))
    except Exception:  # an unreadable scene: the bake reports it
        pass
    return out


def _named(path: Path, base: Path) -> str:
    try:
        return os.path.relpath(path, base) if Path(path).is_relative_to(base) else str(path)
    except ValueError:
        return str(path)


def content_inputs(cfg: Any) -> dict[str, Any]:
    """What the content key hashes, as a JSON-able mapping (for a test or a debugging eye)."""
    from hirad import __version__

    settings = cfg.model_dump(mode="json")
    for dotted in NOT_IN_CONTENT:
        *parents, last = dotted.split(".")
        node = settings
        for p in parents:
            node = node.get(p, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict):
            node.pop(last, None)
    scene = Path(cfg.scene)
    base = scene.parent
    settings["scene"] = scene.name
    files = {_named(p, base): _file_digest(p) for p in scene_files(scene) if p.is_file()}
    for light in settings.get("lights") or []:
        if light.get("ies"):
            p = Path(light["ies"])
            light["ies"] = {"name": p.name, "sha256": _file_digest(p) if p.is_file() else None}
    for grid in (settings.get("grids") or {}).values():
        if isinstance(grid, dict) and grid.get("kind") == "points" and grid.get("file"):
            p = Path(grid["file"])
            grid["file"] = {"name": p.name, "sha256": _file_digest(p) if p.is_file() else None}
    return {"hirad_version": __version__, "settings": settings, "scene_files": files}


def content_key(cfg: Any) -> str:
    """SHA-256 (hex) of `content_inputs(cfg)` in canonical JSON."""
    text = json.dumps(content_inputs(cfg), sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()
