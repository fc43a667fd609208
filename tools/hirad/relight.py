"""Light groups and relighting.

A config's `lights.groups` (schema.LightGroupConfig) sorts the scene's emitters (emitting meshes:
emissive materials, MeshLightAPI, Rect/Disk lights; and luminaires) into named groups, by fnmatch
patterns on their prim paths, by a UsdCollectionAPI collection, or one group per light
(`each: true`); the emitters in no group form the group `rest`. The engine solves each group alone
on the links the whole scene refined (Engine.set_light_groups; radiosity is linear in its source
term), and the bake writes the total as sum_g dimmer_g color_g B_g, each group's values as
`primvars:hirad:group:<name>:radiance` / `:irradiance`, and everything relighting needs under
`OUT/groups/` (groups.json, values.npz, the groups' lightmap pages, their grid values).

`hirad relight OUT --set lights.groups.NAME.dimmer=0.3 --set lights.groups.NAME.color=[1,0.9,0.8]`
(relight()) writes a new output from those stored solutions with no solve: the solution layer
with new primvars, the lightmap pages (when the bake had lightmaps), the grids and their report
(when it had grids) and report.json. Exact up to float rounding: dimming a group by 0.3 gives
B_total - 0.7 B_group.

Daylight: the sun (each UsdLux DistantLight, or `daylight.sun` for the config's sky model) and the
sky (the DomeLight prims, or `daylight.sky`) are emitters like the luminaires: a group selects them
by those paths (`paths: ["/Room/Sun"]`), and those no group selects join `rest`. Their light is
relit with their group's weight, and `daylight.npz` (the sun and sky `hirad grid` reads) with it.
What a relight does not redo is named in the report's `not_relit` and as warnings: the irradiance
volume, and the daylight factor grids (grids/daylight_factor/: DF is relative to the sky's own
outside illuminance, a ratio a dimmer does not change; bake again for a new sky).
"""

from __future__ import annotations

import fnmatch
import json
import math
import re
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .bake import OptionError
from .errors import BakeError

GROUPS_DIR = "groups"
GROUPS_FILE = "groups/groups.json"
VALUES_FILE = "groups/values.npz"
FORMAT = "hirad-light-groups"
# What a relight does not redo (named in its report and as warnings): the irradiance volume, and
# the daylight factor and annual daylight grids (relative to the sky, or of the weather file's
# year: bake again); the per-mesh lightmap files and RGBM PNGs are not written either.
NOT_RELIT = {
    "volume.vdb": "the irradiance volume's probes are not stored per light group; bake again for a relit volume",
    "grids/daylight_factor": "the daylight factor is the ratio to the sky's own outside illuminance, which no dimmer "
                             "changes; bake again with another sky",
    "grids/annual": "the annual metrics come from the weather file's skies, not from light groups",
}


class RelightError(OptionError):
    """A relight that cannot be done: not a hirad output with light groups, a bad --set (usage
    errors, exit 2)."""


# --------------------------------------------------------------------------------------
# groups from the config
# --------------------------------------------------------------------------------------


@dataclass
class LightGroup:
    name: str
    dimmer: float = 1.0
    color: tuple = (1.0, 1.0, 1.0)
    meshes: list = field(default_factory=list)       # input mesh indices (emitting meshes)
    luminaires: list = field(default_factory=list)   # indices into the bake's luminaire specs
    members: list = field(default_factory=list)      # prim paths (or lights.NAME), for the report

    @property
    def weight(self) -> np.ndarray:
        return self.dimmer * np.asarray(self.color, dtype=np.float64)


def day_light_path(d) -> str:
    """The path a light group selects a distant light (sun, sky) by: its USD prim (the
    DistantLight, the DomeLight) or its config key (daylight.sun, daylight.sky)."""
    src = str(getattr(d, "source", "") or "")
    return src if src else f"daylight.{d.kind}"


def _emitters(scene, specs, day_lights=()) -> list[tuple[str, str, int]]:
    """(path, kind, index) of every emitter: ("mesh", mesh index) for meshes with an emitting
    face, ("luminaire", spec index) for luminaires (config lights as lights.NAME), and the
    distant lights (sun, sky) as luminaires len(specs) + k, by day_light_path."""
    out = []
    emitting = np.zeros(len(scene.meshes), dtype=bool)
    lit = scene.face_emission.max(axis=1) > 0 if len(scene.face_emission) else np.zeros(0, dtype=bool)
    emitting[np.unique(scene.face_mesh[lit])] = True
    for m in np.nonzero(emitting)[0]:
        out.append((scene.meshes[int(m)].path, "mesh", int(m)))
    for i, s in enumerate(specs):
        path = s.source if str(s.source).startswith("/") else f"lights.{s.name}"
        out.append((path, "luminaire", i))
    for k, d in enumerate(day_lights):
        out.append((day_light_path(d), "luminaire", len(specs) + k))
    return out


def _collection_members(stage_path, collection: str, paths: list[str]) -> tuple[set[str], str | None]:
    """The paths among `paths` included by a UsdCollectionAPI collection (`/prim.collection:name`),
    and a problem (or None)."""
    from pxr import Sdf, Usd

    if ".collection:" not in collection:
        return set(), f"{collection!r} is not a collection path (/Prim.collection:name)"
    stage = Usd.Stage.Open(str(stage_path))
    if not Sdf.Path.IsValidPathString(collection):
        return set(), f"{collection!r} is not a valid collection path"
    coll = Usd.CollectionAPI.GetCollection(stage, Sdf.Path(collection))
    if not coll:
        return set(), f"no collection {collection} in the scene"
    query = coll.ComputeMembershipQuery()
    return {p for p in paths if Sdf.Path.IsValidPathString(p) and query.IsPathIncluded(Sdf.Path(p))}, None


def _safe(name: str) -> str:
    s = re.sub(r"[^A-Za-z0-9_-]", "_", name)
    return s if re.match(r"^[A-Za-z_]", s) else "_" + s


def resolve_groups(cfg, scene, specs, warn: Callable[[str], None], day_lights=()) -> list[LightGroup]:
    """The config's light groups over the scene's emitters (each emitter in the first group
    that takes it, in the config's order), then `rest` for the emitters in no group. Patterns,
    collections and groups that select nothing are named in warnings. `day_lights`: the bake's
    distant lights (sun, sky; hirad.daylight.sources.DistantLightSpec), luminaires
    len(specs) + k in the groups."""
    from .config.schema import REST_GROUP

    emitters = _emitters(scene, specs, day_lights)
    paths = [p for p, _, _ in emitters]
    taken: dict[int, str] = {}
    groups: list[LightGroup] = []

    def chosen(name, spec) -> list[int]:
        picked: set[int] = set()
        for pattern in spec.paths:
            hit = {k for k, p in enumerate(paths) if fnmatch.fnmatchcase(p, pattern)}
            if not hit:
                warn(f"lights.groups.{name}: the pattern {pattern!r} matches no light or emitter "
                     f"(emitters: {', '.join(paths[:8]) or 'none'}{', ...' if len(paths) > 8 else ''})")
            picked |= hit
        if spec.collection is not None:
            members, problem = _collection_members(cfg.scene, spec.collection, paths)
            if problem:
                warn(f"lights.groups.{name}.collection: {problem}")
            elif not members:
                warn(f"lights.groups.{name}.collection: {spec.collection} holds no light or emitter")
            picked |= {k for k, p in enumerate(paths) if p in members}
        if not spec.paths and spec.collection is None:
            if spec.each:
                picked = set(range(len(paths)))
            else:
                warn(f"lights.groups.{name}: no `paths` or `collection`: the group is empty")
        return sorted(picked)

    for name, spec in cfg.light_groups.items():
        color = tuple(float(c) for c in spec.color) if spec.color is not None else (1.0, 1.0, 1.0)
        picked = []
        for k in chosen(name, spec):
            if k in taken:
                warn(f"lights.groups.{name}: {paths[k]} is already in group {taken[k]}; it stays there")
                continue
            picked.append(k)
        parts = [[k] for k in picked] if spec.each else [picked]
        used = {g.name for g in groups} | {REST_GROUP}
        for part in parts:
            gname = name
            if spec.each:
                gname = base = _safe(f"{name}_{paths[part[0]].rstrip('/').split('/')[-1].split('.')[-1]}")
                n = 1
                while gname in used:
                    gname = f"{base}_{n}"
                    n += 1
            used.add(gname)
            g = LightGroup(gname, float(spec.dimmer), color)
            for k in part:
                taken[k] = gname
                _, kind, idx = emitters[k]
                (g.meshes if kind == "mesh" else g.luminaires).append(idx)
                g.members.append(paths[k])
            if not part and not spec.each:
                warn(f"lights.groups.{name}: selects no light or emitter; the group is kept, dark")
            if part or not spec.each:
                groups.append(g)
    rest = LightGroup(REST_GROUP)
    for k, (p, kind, idx) in enumerate(emitters):
        if k not in taken:
            (rest.meshes if kind == "mesh" else rest.luminaires).append(idx)
            rest.members.append(p)
    if rest.members:
        groups.append(rest)
    _check_sun_and_ground(cfg, groups, len(specs), day_lights)
    return groups


def _sun_lit_ground(cfg) -> bool:
    """Whether the ground below the horizon, part of the sky's light, reflects the sun: a ground
    of daylight.ground_reflectance (the config's sky models always; the scene's DomeLight with
    usd_ground: reflectance) lit by the sky and the sun (hirad.daylight.sources.sky_lights)."""
    dl = getattr(cfg, "daylight", None)
    if dl is None or not dl.ground_reflectance > 0:
        return False
    return dl.sky.model != "usd" or dl.usd_ground != "dome"


def _check_sun_and_ground(cfg, groups: Sequence[LightGroup], n_specs: int, day_lights) -> None:
    """The sun and the sky (with its ground) in different groups is exact only when the ground
    does not reflect the sun: otherwise the sky's group would carry the sun's light off the ground,
    and dimming the sun's group would leave it. Refused then (a RelightError, exit 2), naming the
    groups, the lights and the keys that decide it."""
    if not day_lights or not _sun_lit_ground(cfg):
        return
    group_of = {i: g.name for g in groups for i in g.luminaires}
    suns = {day_light_path(d): group_of.get(n_specs + k) for k, d in enumerate(day_lights) if d.kind == "sun"}
    skies = {day_light_path(d): group_of.get(n_specs + k) for k, d in enumerate(day_lights)
             if d.kind in ("sky", "ground")}
    if not suns or not skies or len(set(suns.values()) | set(skies.values())) == 1:
        return
    where = "; ".join(f"{p} in group {g}" for p, g in {**suns, **skies}.items())
    ground = ("the config's sky model" if cfg.daylight.sky.model != "usd" else "daylight.usd_ground: reflectance")
    raise RelightError(
        f"lights.groups: the sun and the sky are in different light groups ({where}), but the ground below the "
        f"horizon, which is part of the sky's light, reflects the sun ({ground}, daylight.ground_reflectance "
        f"{cfg.daylight.ground_reflectance:g}): dimming the sun's group would leave its light off the ground. Put "
        "the sun and the sky in one group, or give the sky a ground of its own (daylight.usd_ground: dome, or "
        "daylight.ground_reflectance: 0)")


def weighted_specs(specs, groups: Sequence[LightGroup]):
    """The luminaire specs with each one's colour times its group's dimmer x colour."""
    w = [np.ones(3) for _ in specs]
    for g in groups:
        for i in g.luminaires:
            if i < len(w):  # beyond: the distant lights (weighted_day_lights)
                w[i] = g.weight
    return [replace(s, colour=np.asarray(s.colour) * wi) if not np.array_equal(wi, np.ones(3)) else s
            for s, wi in zip(specs, w)]


def weighted_day_lights(day_lights, groups: Sequence[LightGroup], n_specs: int):
    """The distant lights (sun, sky) with each one's colour times its group's dimmer x colour
    (luminaire n_specs + k is day_lights[k])."""
    from .studies.usdgrids import day_light_weights

    w = day_light_weights(groups, n_specs, len(day_lights))
    return [replace(d, colour=np.asarray(d.colour) * wi) if not np.array_equal(wi, np.ones(3)) else d
            for d, wi in zip(day_lights, w)]


# --------------------------------------------------------------------------------------
# the bake's side: what is stored for relighting
# --------------------------------------------------------------------------------------


def weighted_sum(arrays, weights) -> np.ndarray:
    """sum_g weights[g] x arrays[g] (weights (G, 3) per RGB channel), in group order."""
    out = None
    for a, w in zip(arrays, weights):
        v = np.asarray(a, dtype=np.float64) * w
        out = v if out is None else out + v
    return out


def save_groups(staging: Path, groups: Sequence[LightGroup], meshes_data: list, per_group: dict, *,
                grids_info: dict | None, lightmaps_info: dict | None, units: str, version: str,
                seconds: float, specs=(), names=None, preview: dict | None = None) -> None:
    """Writes OUT/groups/groups.json and values.npz: per group and solution mesh the vertex and
    face radiance and irradiance and face emission (float64), the grid sensors' RGB."""
    from . import files

    arrays: dict[str, np.ndarray] = {}
    for gi, g in enumerate(groups):
        for mi, values in enumerate(per_group[g.name]["meshes"]):
            for key, a in values.items():
                arrays[f"g{gi}_m{mi}_{key}"] = np.asarray(a, dtype=np.float64)
        for k, rgb in enumerate(per_group[g.name].get("grids", [])):
            arrays[f"g{gi}_grid{k}"] = np.asarray(rgb, dtype=np.float64)
    if len(specs):
        arrays["lum_colour"] = np.array([np.asarray(sp.colour, dtype=np.float64) for sp in specs])
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    (staging / GROUPS_DIR).mkdir(exist_ok=True)
    files.write_bytes(staging / VALUES_FILE, buf.getvalue())
    doc = {
        "format": FORMAT, "version": 1, "hirad_version": version, "units": units,
        "groups": [{"name": g.name, "dimmer": g.dimmer, "color": list(g.color), "members": g.members,
                    "meshes": g.meshes, "luminaires": g.luminaires} for g in groups],
        "meshes": [{"name": (names[i] if names else pm.name) or "", "mesh_index": int(pm.mesh_index)}
                   for i, pm in enumerate(meshes_data)],
        "grids": grids_info,
        "lightmaps": lightmaps_info,
        "preview": preview,
        "group_solve_seconds": round(seconds, 4),
    }
    files.write_json(staging / GROUPS_FILE, doc)


# --------------------------------------------------------------------------------------
# hirad relight
# --------------------------------------------------------------------------------------

_SET = re.compile(r"^lights\.groups\.([^.=]+)\.(dimmer|color)=(.*)$", re.S)


def parse_sets(sets: Sequence[str], known: Sequence[str]) -> dict[str, dict]:
    """--set values: {group: {"dimmer": x, "color": (r, g, b)}}; a bad key, value or an
    unknown group is a RelightError naming the --set."""
    import yaml

    out: dict[str, dict] = {}
    for text in sets:
        m = _SET.match(text.strip())
        if not m:
            key = text.split("=", 1)[0]
            raise RelightError(f"--set {text}: {key!r} is not a relight key; use lights.groups.NAME.dimmer=X or "
                               "lights.groups.NAME.color=[R,G,B]")
        name, what, raw = m.group(1), m.group(2), m.group(3)
        if name not in known:
            close = [k for k in known if k.lower() == name.lower()]
            raise RelightError(f"--set {text}: unknown light group {name!r}" +
                               (f" (did you mean {close[0]!r}?)" if close else "") +
                               f"; the bake's groups: {', '.join(known)}")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise RelightError(f"--set {text}: cannot read the value {raw!r}") from None
        if what == "dimmer":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise RelightError(f"--set {text}: lights.groups.{name}.dimmer must be a number >= 0, got {raw!r}")
            out.setdefault(name, {})["dimmer"] = float(value)
        else:
            ok = (isinstance(value, (list, tuple)) and len(value) == 3 and
                  all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
                      for v in value))
            if not ok:
                raise RelightError(f"--set {text}: lights.groups.{name}.color must be [R, G, B], each a number "
                                   f">= 0, got {raw!r}")
            out.setdefault(name, {})["color"] = tuple(float(v) for v in value)
    return out


def _stored(out_dir: Path) -> tuple[dict, dict]:
    from . import files

    out_dir = Path(out_dir)
    if out_dir.is_symlink() or not out_dir.is_dir():
        raise RelightError(f"{out_dir}: not a directory (give the output directory of `hirad bake`)")
    marker = files._read_marker(out_dir, files.OUTPUT_MARKER, files._OUTPUT_FORMAT)
    if marker is None:
        raise RelightError(f"{out_dir}: not a hirad output (no {files.OUTPUT_MARKER} marker); nothing written")
    doc_path = out_dir / GROUPS_FILE
    if not doc_path.is_file() or not (out_dir / VALUES_FILE).is_file():
        raise RelightError(f"{out_dir}: a hirad output without light groups (no {GROUPS_FILE}); bake it with "
                           "lights.groups in the config to relight it; nothing written")
    try:
        doc = json.loads(doc_path.read_text())
        if doc.get("format") != FORMAT:
            raise ValueError("not a light groups file")
        with np.load(out_dir / VALUES_FILE, allow_pickle=False) as z:
            values = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError) as e:
        raise RelightError(f"{doc_path}: cannot read the stored light groups ({e}); nothing written") from None
    return doc, values


def default_output(out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    return out_dir.parent / f"{out_dir.name}-relit"


def relight(out_dir, sets: Sequence[str] = (), output=None, *, quiet: bool = True) -> dict:
    """Writes a relit copy of a bake's output into `output` (default OUT-relit) from its stored
    light group solutions, with no solve; returns the relight report."""
    from . import __version__, files, interrupts

    t0 = time.perf_counter()
    out_dir = Path(out_dir).absolute()
    doc, values = _stored(out_dir)
    old = _old_daylight(out_dir)
    if old:
        raise RelightError(f"{out_dir}: baked by a hirad whose light groups left out the sun and sky ({', '.join(old)}): "
                           "its stored group solutions hold none of their light, so it cannot be relit; bake it "
                           "again; nothing written")
    groups = doc["groups"]
    names = [g["name"] for g in groups]
    changes = parse_sets(sets, names)
    weights = []
    settings = {}
    for g in groups:
        c = changes.get(g["name"], {})
        dimmer = c.get("dimmer", g["dimmer"])
        color = c.get("color", tuple(g["color"]))
        settings[g["name"]] = {"dimmer": dimmer, "color": list(color)}
        weights.append(dimmer * np.asarray(color, dtype=np.float64))
    weights = np.asarray(weights)
    target = Path(output).absolute() if output is not None else default_output(out_dir)
    real_t, real_o = target.resolve(), out_dir.resolve()
    if real_t == real_o or real_o in real_t.parents or real_t in real_o.parents:
        raise RelightError(f"--output {target}: must not be, hold or lie inside the bake's output {out_dir} "
                           "(relight writes a new output beside it)")
    files.check_output(target, [("bake output", out_dir)])
    staging = files.make_staging(target, __version__)
    try:
        with files.removed_on_failure(staging):
            report = _write_relit(out_dir, staging, doc, values, weights, settings, __version__)
            report["timings_s"] = {"total": round(time.perf_counter() - t0, 4)}
            files.write_json(staging / "report.json", report)
            files.finish_staging(staging, __version__)
            with interrupts.deferred():
                files.replace_output(staging, target, [("bake output", out_dir)])
    except files.WriteError as e:
        raise files.WriteError(str(e).replace(str(staging), str(target))) from None
    files.remove_stale_staging(target)
    report["output"] = str(target)
    return report


def _weighted(values: dict, weights: np.ndarray, key: str) -> np.ndarray:
    out = None
    for gi, w in enumerate(weights):
        v = values[key.format(g=gi)] * w
        out = v if out is None else out + v
    return out


def _write_relit(out_dir: Path, staging: Path, doc: dict, values: dict, weights: np.ndarray, settings: dict,
                 version: str) -> dict:
    import os
    import shutil

    from pxr import Gf, Sdf, UsdGeom, Vt

    from . import _engine, files

    written = ["report.json"]
    # --- the solution layer: new primvars on the same meshes
    layer_path = out_dir / "solution.usda"
    if layer_path.is_file():
        from .usd.solution import export_solution, is_arrays_sublayer, merge_arrays

        src = Sdf.Layer.OpenAsAnonymous(str(layer_path))  # the file as it is now (see merge_arrays)
        layer = Sdf.Layer.CreateAnonymous(".usda")
        layer.TransferContent(src)
        merge_arrays(layer, layer_path)  # edited as one layer, split again when written
        subs = list(layer.subLayerPaths)
        new_subs = []
        for s in subs:
            if is_arrays_sublayer(s, layer_path):
                continue
            absolute = (out_dir / s).resolve() if not os.path.isabs(s) else Path(s)
            rel = os.path.relpath(absolute, staging)
            new_subs.append(rel if rel.startswith(".") else "./" + rel)
        layer.subLayerPaths.clear()
        stage_layer = Sdf.Layer.CreateAnonymous(".usda")
        stage_layer.TransferContent(layer)
        from pxr import Usd

        stage = Usd.Stage.Open(stage_layer)
        root_path = stage_layer.customLayerData.get("hirad:solutionRoot")
        root = stage.GetPrimAtPath(root_path) if root_path else None
        if not root:
            raise RelightError(f"{layer_path}: no solution root; nothing written")
        by_name = {m["name"]: mi for mi, m in enumerate(doc["meshes"])}
        for prim in root.GetChildren():
            if not prim.IsA(UsdGeom.Mesh) or prim.GetName() not in by_name:
                continue
            mi = by_name[prim.GetName()]
            api = UsdGeom.PrimvarsAPI(prim)

            def put(name, key):
                a = _weighted(values, weights, f"g{{g}}_m{mi}_{key}")
                api.GetPrimvar(name).Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32)))
                return a

            vr = put("hirad:radiance", "vertex_radiance")
            put("hirad:irradiance", "vertex_irradiance")
            put("hirad:patchRadiance", "face_radiance")
            put("hirad:patchIrradiance", "face_irradiance")
            if api.GetPrimvar("hirad:emission"):
                put("hirad:emission", "face_emission")
            api.GetPrimvar("displayColor").Set(Vt.Vec3fArray.FromNumpy(
                np.ascontiguousarray(np.clip(np.nan_to_num(vr), 0.0, 1.0), dtype=np.float32)))
            # the lightmap material's emitted part (bias), weighted as the emission
            lm = doc.get("lightmaps") or {}
            bias = (lm.get("emission") or {}).get(prim.GetName())
            if bias is not None:
                looks = root.GetPath().AppendChild("Looks").AppendChild(prim.GetName()).AppendChild("Lightmap")
                tex = stage.GetPrimAtPath(looks)
                if tex:
                    e = sum(np.asarray(b) * w for b, w in zip(bias, weights))
                    tex.GetAttribute("inputs:bias").Set(Gf.Vec4f(float(e[0]), float(e[1]), float(e[2]), 0.0))
        data = dict(stage_layer.customLayerData)
        data["hirad:relit"] = {k: {"dimmer": v["dimmer"], "color": Vt.DoubleArray(v["color"])}
                               for k, v in settings.items()}
        data["hirad:relitFrom"] = str(out_dir)
        stage_layer.customLayerData = data
        del stage
        written += [p.name for p in reversed(export_solution(stage_layer, staging / "solution.usda", new_subs))]
        lum = out_dir / "luminaires.npz"
        if lum.is_file():
            _relit_luminaires(lum, staging / "luminaires.npz", doc, weights, values)
            written.append("luminaires.npz")
        from .studies.usdgrids import DAYLIGHT_KEY

        day = stage_layer.customLayerData.get(DAYLIGHT_KEY)
        if day:  # the glazing, sun and sky `hirad grid` reads: the sun and sky with their new weights
            _relit_daylight(out_dir / str(day), staging / str(day), doc, weights)
            written.append(str(day))
    # --- lightmaps: the stored group pages, weighted
    lm = doc.get("lightmaps")
    if lm:
        (staging / "lightmaps" / "pages").mkdir(parents=True, exist_ok=True)
        for rel in lm["pages"]:
            img = None
            for gi, g in enumerate(doc["groups"]):
                page = np.asarray(_engine.read_exr(str(out_dir / GROUPS_DIR / g["name"] / rel)), dtype=np.float64)
                img = page * weights[gi] if img is None else img + page * weights[gi]
            meta = [(k, v) for k, v in lm.get("metadata", [])] + [("hirad:page", rel.split("page")[-1].split(".")[0]),
                                                                  ("hirad:relit", json.dumps(settings))]
            _engine.write_exr(str(staging / rel), np.ascontiguousarray(img, dtype=np.float32), meta)
            written.append(rel)
        if (out_dir / "lightmaps" / "manifest.json").is_file():
            # the relit output holds the EXR pages only: the manifest keeps no entry for the
            # 8-bit copies, directional maps or RGBM PNGs of the bake (bake again for those)
            manifest = json.loads((out_dir / "lightmaps" / "manifest.json").read_text())
            for page in manifest.get("pages", []):
                for key in ("encoded", "godotL1", "bakerySH", "unityDirection"):
                    page.pop(key, None)
            for key in ("encodings", "rgbm", "meshFiles"):
                manifest.pop(key, None)
            manifest["relit"] = {"settings": settings, "files": "the EXR pages only"}
            (staging / "lightmaps" / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
            written.append("lightmaps/manifest.json")
    # --- grids: the stored sensors' RGB, weighted, then the study as the bake writes it
    grid_report = None
    gi_doc = doc.get("grids")
    if gi_doc:
        grid_report = _relit_grids(staging, gi_doc, values, weights, doc, settings)
        written.append("grids/")
    pv = doc.get("preview")
    if pv and (staging / "solution.usda").is_file():
        from .outputs import images
        from .solution import load_solution
        from . import units as _units

        sol = load_solution(staging / "solution.usda")
        img = sol.render(pv["camera"], pv["width"], pv["height"], pv["samples"])
        _engine.write_exr(str(staging / "preview.exr"), np.ascontiguousarray(img, dtype=np.float32),
                          [("hirad:units", "exitant " + _units.label(doc.get("units", "photometric"), "radiance"))])
        images.write_png(staging / "preview.png", img)
        written += ["preview.png", "preview.exr"]
    # --- the group solutions again, with the new dimmers and colours: a relit output relights too
    src_groups = out_dir / GROUPS_DIR
    (staging / GROUPS_DIR).mkdir(exist_ok=True)
    for path in sorted(src_groups.rglob("*")):
        rel = path.relative_to(out_dir)
        if path.is_symlink():
            continue
        if path.is_dir():
            (staging / rel).mkdir(parents=True, exist_ok=True)
        elif rel.as_posix() != GROUPS_FILE:
            shutil.copyfile(path, staging / rel)
    relit_doc = dict(doc, groups=[dict(g, dimmer=settings[g["name"]]["dimmer"], color=settings[g["name"]]["color"])
                                  for g in doc["groups"]])
    files.write_json(staging / GROUPS_FILE, relit_doc)
    written.append(GROUPS_DIR + "/")
    not_relit = [n for n in NOT_RELIT if (out_dir / n).exists()]
    return {
        "hirad_version": version,
        "relit_from": str(out_dir),
        "groups": settings,
        "solves": 0,
        "outputs": written,
        "grids": grid_report,
        "not_relit": not_relit,
    }


def _relit_daylight(src: Path, dst: Path, doc: dict, weights: np.ndarray) -> None:
    """daylight.npz with each distant light's weight its group's new one (its colour is kept
    unweighted), so that `hirad grid` on the relit layer sees the relit sun and sky."""
    import io

    from . import files
    from .studies import StudyError
    from .studies.usdgrids import read_stored_daylight

    try:
        arrays = read_stored_daylight(src)
    except StudyError as e:
        raise RelightError(f"{e}; nothing written") from None
    index = {int(arrays[f"d{k}_luminaire"]): k for k in range(len(arrays["names"])) if f"d{k}_luminaire" in arrays}
    for gi, g in enumerate(doc["groups"]):
        for i in g["luminaires"]:
            if i in index:
                arrays[f"d{index[i]}_weight"] = np.asarray(weights[gi], dtype=np.float64)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    files.write_bytes(dst, buf.getvalue())


def _old_daylight(out_dir: Path) -> list[str]:
    """The distant lights (sun, sky) of an output baked before they could join light groups: its
    luminaires.npz kept them without their light (directions on the unit sphere, zero candela)."""
    lum = out_dir / "luminaires.npz"
    if not lum.is_file():
        return []
    try:
        with np.load(lum, allow_pickle=False) as z:
            names = [str(n) for n in z["names"]]
            return [n for k, n in enumerate(names)
                    if not np.any(z[f"l{k}_candela"]) and len(z[f"l{k}_points"])
                    and np.allclose(np.linalg.norm(z[f"l{k}_points"], axis=1), 1.0, atol=1e-9)]
    except (OSError, KeyError, ValueError):
        return []  # relighting it names the damage


def _relit_luminaires(src: Path, dst: Path, doc: dict, weights: np.ndarray, values: dict) -> None:
    """luminaires.npz with each luminaire's colour (stored unweighted, values.npz `lum_colour`)
    times its group's new weight, so that `hirad grid` on the relit layer sees the relit lights."""
    import io

    from . import files

    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    base = values.get("lum_colour")
    for gi, g in enumerate(doc["groups"]):
        for i in g["luminaires"]:
            key = f"l{i}_colour"
            if key in arrays and base is not None and i < len(base):  # beyond: the sun and sky (daylight.npz)
                arrays[key] = (base[i] * weights[gi]).reshape(arrays[key].shape)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    files.write_bytes(dst, buf.getvalue())


def _relit_grids(staging: Path, info: dict, values: dict, weights: np.ndarray, doc: dict, settings: dict) -> dict:
    from pydantic import TypeAdapter

    from .bake import write_grid_study
    from .solution import luminance_y
    from .studies import build_grids, evaluate_grids
    from .studies.spec import GridSpec

    adapter = TypeAdapter(GridSpec)
    specs = {name: adapter.validate_python(spec) for name, spec in info["specs"].items()}
    rooms = {k: v for k, v in (info.get("rooms") or {}).items()}
    grids = []
    for name, spec in specs.items():
        grids += build_grids({name: spec}, up_axis=info["up_axis"], rooms=rooms)
    counter = {"k": 0}

    def replay(points, normals):
        k = counter["k"]
        counter["k"] += 1
        rgb = _weighted(values, weights, f"g{{g}}_grid{k}")
        if len(rgb) != len(points):
            raise RelightError(f"grid {k}: {len(points)} sensors now, {len(rgb)} stored (its points file changed); "
                               "bake again")
        return luminance_y(rgb)

    results = evaluate_grids(grids, replay, maintenance_factor=info["maintenance_factor"])
    solver = dict(info.get("solver") or {})
    solver["relit"] = ", ".join(f"{k}: dimmer {v['dimmer']:g}, color {v['color']}" for k, v in settings.items())
    return write_grid_study(results, staging / "grids", units=info["units"],
                            maintenance_factor=info["maintenance_factor"], seed=info["seed"], rays=info["rays"],
                            title=info["title"] + " (relit)", solver=solver, luminaires=info.get("luminaires") or [])


# --------------------------------------------------------------------------------------
# the bake with light groups (called from hirad.bake._run)
# --------------------------------------------------------------------------------------


@dataclass
class GroupSolve:
    """The light groups' solutions per patch (leaf), with the weights of the config."""

    groups: list
    radiosity: list          # per group (n, 3)
    irradiance: list         # per group (n, 3): from the surfaces plus the group's direct light
    emission: list           # per group (n, 3): the group's self-emission per patch
    weights: np.ndarray      # (G, 3)
    solve_seconds: float = 0.0
    residuals: list = field(default_factory=list)
    luminaires: list = field(default_factory=list)  # per group: its engine luminaires, unweighted
    vertex: list = field(default_factory=list)      # per group: (vertex radiance, vertex irradiance)

    def total(self, arrays: list) -> np.ndarray:
        return weighted_sum(arrays, self.weights)


def group_solutions(cfg, model, solved, patches, groups, seconds: float = 0.0) -> GroupSolve:
    """Each group's B and H per patch: from the hierarchical result (HierarchicalResult.groups),
    or solved now on the flat links (Engine.solve_groups)."""
    from . import _engine

    t0 = time.perf_counter()
    if cfg.method == "hierarchical":
        sols = list(solved.groups)
    else:
        ff = cfg.formfactors
        sols = model.solve_groups(
            _engine.SolveOptions(method=cfg.solver.method, tolerance=cfg.solver.tolerance,
                                 max_iterations=cfg.solver.max_iterations),
            _engine.FormFactorOptions(method=ff.method, samples=ff.samples, hemicube_resolution=ff.hemicube_resolution,
                                      hemicube_points=ff.hemicube_points, seed=cfg.seed))
    if len(sols) != len(groups):
        raise BakeError(f"light groups: {len(sols)} solutions for {len(groups)} groups (engine)")
    mesh_of = patches["mesh"]
    emission = []
    for g in groups:
        on = np.zeros(int(mesh_of.max()) + 1 if len(mesh_of) else 0, dtype=bool)
        on[[m for m in g.meshes if m < len(on)]] = True
        emission.append(patches["emission"] * on[mesh_of][:, None])
    return GroupSolve(groups, [np.asarray(s.radiosity) for s in sols],
                      [np.asarray(s.irradiance) + np.asarray(s.direct) for s in sols], emission,
                      np.array([g.weight for g in groups]),
                      sum(float(x.seconds) for x in sols) if cfg.method == "hierarchical"
                      else seconds + time.perf_counter() - t0,
                      [float(s.residual) for s in sols])


def group_result(result, model, k: int, corner_radiance, corner_irradiance, emitted, luminaires, corners=None):
    """A copy of the bake's Result for group k alone: its corner values, emission and
    luminaires, and its final gather. `corners`: result.corners when the caller has made them
    already (an indexed Result makes them on each read)."""
    from .solution import Result

    class _GroupResult(Result):
        def gather(self, points, normals, *, rays: int = 4, cluster_samples: int = 8, seed: int = 1,
                   directional: bool = False, importance: float = 0.0, second_bounce: float = 1.0) -> dict:
            from . import _engine

            if not self.hierarchical:
                raise BakeError("light groups: a flat bake's gather is not per group")
            pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
            nrm = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
            g = self._model.gather(pts, nrm, _engine.GatherOptions(rays=rays, cluster_samples=cluster_samples,
                                                                   seed=seed, directional=bool(directional),
                                                                   importance=float(importance),
                                                                   second_bounce=float(second_bounce)), 1e30, k)
            keys = ("patch", "irradiance", "radiance") + (("l0", "l1") if directional else ())
            return {key: np.asarray(getattr(g, key)) for key in keys}

    return _GroupResult(result.corners if corners is None else corners, result.nv, corner_radiance, corner_irradiance, cameras=result.cameras,
                        up_axis=result.up_axis, patch_radiosity=None, patch_irradiance=None, patches=result.patches,
                        _model=model, hierarchical=result.hierarchical, emitted_radiance=emitted,
                        luminaires=list(luminaires), transmittance=result.transmittance)


def replay_result(result, records: list, weights: np.ndarray):
    """The bake's Result whose final gather replays the weighted sum of the groups' gathers,
    call by call (the lightmaps gather the same points in the same order for every group)."""
    from .solution import Result

    class _Replayed(Result):
        def gather(self, points, normals, **kwargs) -> dict:
            k = self._calls
            self._calls += 1
            out = {"patch": records[0][k]["patch"]}
            # every quantity is linear in the groups' emission, the hemisphere moments too
            for key in ("irradiance", "radiance", "l0"):
                if key in records[0][k]:
                    out[key] = weighted_sum([r[k][key] for r in records], weights)
            if "l1" in records[0][k]:  # (n, channel, axis): the weights go on the channel
                out["l1"] = weighted_sum([r[k]["l1"] for r in records], np.asarray(weights)[:, :, None])
            return out

    r = result._copy_into(_Replayed)
    r._calls = 0
    return r


def recording_gather(result):
    """Wraps result.gather so that every call's output is kept (a list of dicts)."""
    rec: list[dict] = []
    inner = result.gather

    def gather(points, normals, **kwargs):
        out = inner(points, normals, **kwargs)
        rec.append({k: np.array(v, copy=True) for k, v in out.items()})
        return out

    result.gather = gather
    return rec
