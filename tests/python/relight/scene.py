"""A closed grey room with three lights for the light group tests: two emissive ceiling
panels (/World/Lights/Desk, /World/Lights/Sky) and a SphereLight luminaire (/World/Lamps/Bulb),
with a collection /World.collection:sky holding the Sky panel. Not a test module."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "tests" / "python"))

from hirad_e2e_helpers import BOX_WALLS, add_material, add_mesh, box_wall, new_stage  # noqa: E402
from pxr import Gf, Sdf, Usd, UsdLux  # noqa: E402


def room(path: Path, desk: float = 3.0, sky=(1.0, 1.5, 2.0), bulb: float = 2.0, with_bulb: bool = True) -> Path:
    """`desk`, `sky`: the panels' emitted radiance (grey, RGB); `bulb`: the SphereLight's intensity."""
    stage = new_stage(path)
    grey = add_material(stage, "/World/Looks/grey", (0.5, 0.6, 0.4))
    for name, (axis, top) in BOX_WALLS.items():
        quad = box_wall(axis, 1.0 if top else 0.0, -1.0 if top else 1.0, 1.0)
        add_mesh(stage, f"/World/Room/{name}", list(quad), [4], [0, 1, 2, 3], grey)
    for name, x0, radiance in (("Desk", 0.15, (desk,) * 3), ("Sky", 0.6, tuple(sky))):
        mat = add_material(stage, f"/World/Looks/{name}", (0.0, 0.0, 0.0), radiance)
        y = 0.98
        # facing down (-Y): counter-clockwise seen from below
        pts = [(x0, y, 0.4), (x0 + 0.25, y, 0.4), (x0 + 0.25, y, 0.65), (x0, y, 0.65)]
        add_mesh(stage, f"/World/Lights/{name}", pts, [4], [0, 1, 2, 3], mat)
    if with_bulb:
        lamp = UsdLux.SphereLight.Define(stage, "/World/Lamps/Bulb")
        lamp.CreateRadiusAttr(0.02)
        lamp.CreateIntensityAttr(bulb)
        lamp.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.5, 0.5))
    coll = Usd.CollectionAPI.Apply(stage.GetPrimAtPath("/World"), "sky")
    coll.CreateIncludesRel().AddTarget(Sdf.Path("/World/Lights/Sky"))
    stage.GetRootLayer().Save()
    return path


def config(path: Path, scene: Path, output: Path, groups=None, method: str = "hierarchical", **extra) -> Path:
    data = {"scene": str(scene), "output": str(output), "method": method,
            "solver": {"method": "jacobi" if method == "hierarchical" else "gauss_seidel", "tolerance": 1e-6},
            "outputs": {"usd": True, "lightmaps": {"enabled": False}, "volume": {"enabled": False},
                        "preview": {"enabled": False}, "report": True}}
    if method == "hierarchical":
        data["hierarchy"] = {"epsilon": 1e-3, "min_area": 0.005, "samples": 4}
    else:
        data["meshing"] = {"max_patch_area": 0.02, "max_edge_length": 0.2}
    if groups is not None:
        data["lights"] = {"groups": groups}
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(data.get(k), dict):
            data[k] = {**data[k], **v}
        else:
            data[k] = v
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


GROUPS = {"desk": {"paths": ["/World/Lights/Desk"]}, "sky": {"collection": "/World.collection:sky"}}
