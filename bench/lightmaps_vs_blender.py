"""hirad's lightmap bake against Blender's Cycles bake, side by side in one run (issue 14, Figures).

    .venv/bin/python bench/lightmaps_vs_blender.py                      # the Modern Hall, 16 texels/m
    .venv/bin/python bench/lightmaps_vs_blender.py --scene configs/scenes/cornell_box.usda --density 128
    .venv/bin/python bench/lightmaps_vs_blender.py --calibrate          # only Blender's unit checks (below)

What is compared
----------------
Both tools bake the same quantity into the same texels:

* hirad (`hirad bake`, hierarchical radiosity, `outputs.lightmaps.mode: final_gather`) writes
  pages whose texels hold the incident radiance H/pi in W/(m^2 sr) (H the irradiance, W/m^2),
  on its own lightmap UVs `primvars:st1` of the original meshes (page_uv = st1 * scaleOffset.xy +
  scaleOffset.zw; see tools/hirad/outputs/lightmaps.py and the manifest).
* Blender 3.4 (Debian's `blender`, headless `blender -b --python`) bakes type 'DIFFUSE' with
  pass_filter {'DIRECT', 'INDIRECT'} and the COLOR pass off. Cycles' diffuse bake with colour off
  divides the diffuse BSDF's albedo out: what is left is the cosine-weighted incident radiance
  (1/pi) * integral L_i cos(theta) d(omega) = H/pi, the same quantity. Blender has no USD importer
  in 3.4, so the scene is handed over as raw arrays: this script reads the USD with hirad's own
  scene reader (`hirad.usd.read_scene`: world-space metres, the faces hirad bakes, their
  reflectance and emission) and the lightmap UVs hirad wrote (`primvars:st1` in the bake's
  solution.usda, mapped into page UVs by each instance's scaleOffset), and builds one Blender
  object per lightmap page with those page UVs. So every Blender texel is the same texel, on the
  same surface, as hirad's: the two bakes are compared texel for texel at identical density.
* Units. A Cycles Emission shader of strength 1 and colour c makes the surface's radiance c in
  the scene's units (mesh emission is not converted: lamps' Watts are, meshes' strengths are
  not). hirad's reader gives a face's emission as exitance M (W/m^2) of a Lambertian emitter, so
  the Blender colour is M/pi. Cycles emits from both sides of a mesh; hirad's (and the USD's
  MeshLightAPI) emitters emit on their front side only, so the strength is 1 - Backfacing.
  `--calibrate` checks all this in Blender itself (an emitting box around a small plane, see
  `blender_calibrate`): radiance L on every inner wall gives exactly L at the plane whatever the
  plane's albedo (H = pi L inside a closed uniform emitter); walls facing outwards give 0; walls
  that also reflect rho give L / (1 - rho) (a furnace: every bounce), which checks INDIRECT and the
  bounce count. Materials: a Lambertian Diffuse BSDF (roughness 0) of hirad's reflectance (a
  texture counts by its mean colour, as in hirad) on the front side only, black on the back
  (hirad's faces, and its reference's, absorb on the back; Cycles' diffuse reflects on both
  sides, which put Blender 5-7 % above the reference on the Modern Hall, whose meshes face out
  of the room in places); no glossy (the scene's "roughconductor"/"dielectric" materials are
  diffuse in hirad too). Glass (hirad's face transmittance tau0 > 0: the Hall's balustrade) is
  a Transparent BSDF of colour tau0 r(|cos theta|), r the Tregenza-Sharples curve hirad uses,
  plus its reflectance, as `hirad reference` traces it; calibration (d) checks it against
  the closed form. World: black.
* Cycles settings: samples per texel from `--samples` (a ladder, each a full bake, timed on its
  own), adaptive sampling and denoising off, clamping off, light-sampling threshold 0, diffuse
  and total bounces `--bounces` (32: with a mean albedo near 0.75 what is cut is about 1e-4;
  Cycles' Russian roulette ends most paths much earlier), fixed seed, `--threads` threads.

Error
-----
Texel sample points: N texels drawn at random (seed) by area on the baked, non-emitting faces:
a uniform point on a face's fan triangle, moved to the centre of the page texel it falls in
(redrawn when that centre is outside the triangle), so the point is both on the surface and at
a texel centre. Each point's reference is the path-traced exitant radiance from `hirad
reference` (tools/hirad/reference.py: Embree path tracing with next-event estimation and
Russian roulette, no radiosity and no meshing) at that point and face normal. A bake's texel T
(H/pi) gives the exitant radiance rho * T; the error is the relative error of its luminance
(Rec. 709 weights) against the reference's, per point; mean (signed) and RMS over the points.
Points whose reference is unlit (luminance below 1 % of the median) or noisy (relative standard
error above `--max-se`) are dropped before the first N are kept, and the RMS is also given with
the reference's own mean squared relative standard error removed in quadrature.

Texel lookup: hirad's page EXR has row 0 at the top (v = 1), so texel (i, j) (j counted from
v = 0) is row H-1-j; Blender's Image.pixels is stored bottom row first, so it is row j.

Times and memory: each tool runs as a child process, one after the other (the machine has 2
cores; running them at the same time would make each slower by the other), with the 1-minute
load average at each start; peak RSS from wait4's rusage of that child. hirad's time is the whole
bake (read, hierarchical solve, final gather of every texel, writing the pages and layer);
Blender's per-bake time is bpy.ops.object.bake alone (building the scene is timed apart).
Texels per second count the covered texels (fill x page area, from hirad's manifest).

The figures go to stdout and, with --json, to a file; bench/README.md quotes a run.
"""

from __future__ import annotations

import array
import json
import os
import sys
import time

try:  # inside Blender: this same file is the Blender-side script
    import bpy  # type: ignore
    IN_BLENDER = True
except ImportError:
    IN_BLENDER = False


# ============================================================================================
# Blender side (runs under Blender's own Python 3.11; no numpy there, only array and json)

def _read_bin(path: str, code: str) -> array.array:
    a = array.array(code)
    with open(path, "rb") as f:
        a.frombytes(f.read())
    return a


def _cycles_settings(scene, samples: int, bounces: int, threads: int) -> None:
    c = scene.cycles
    scene.render.engine = "CYCLES"
    c.device = "CPU"
    c.samples = samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = bounces
    c.diffuse_bounces = bounces
    c.glossy_bounces = 0
    c.transmission_bounces = 0
    c.volume_bounces = 0
    c.transparent_max_bounces = 16  # panes of glass one ray may pass (hirad's reference: 16)
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.caustics_reflective = False
    c.caustics_refractive = False
    c.light_sampling_threshold = 0.0
    c.seed = 1
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0, 0, 0, 1)
    scene.world = world


# Tregenza and Sharples' T(c) of 6 mm clear glass (hirad.daylight.glazing), whose ratio to T(1),
# clamped to [0, 1], is the relative angular transmittance r hirad's glass uses.
_TS_COEFFS = (-0.028378, 3.156075, -3.058376, -1.428919, 4.014235, -1.775827)


def _glass(nt, tau0: float, rho):
    """Glass as hirad's reference traces it: straight through with T = tau0 r(|cos theta|)
    (a Transparent BSDF of that colour, theta between the ray and the face) plus the
    reflectance rho, diffuse, on whichever side is met (both sides: glass is a sheet)."""
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    dot = nt.nodes.new("ShaderNodeVectorMath")
    dot.operation = "DOT_PRODUCT"
    nt.links.new(geo.outputs["Incoming"], dot.inputs[0])
    nt.links.new(geo.outputs["True Normal"], dot.inputs[1])
    c = nt.nodes.new("ShaderNodeMath")
    c.operation = "ABSOLUTE"
    nt.links.new(dot.outputs["Value"], c.inputs[0])
    acc = None  # Horner: ((a5 c + a4) c + a3) ...
    for a in reversed(_TS_COEFFS[:-1]):
        node = nt.nodes.new("ShaderNodeMath")
        node.operation = "MULTIPLY_ADD"
        nt.links.new(c.outputs[0], node.inputs[0])
        if acc is None:
            node.inputs[1].default_value = _TS_COEFFS[-1]
        else:
            nt.links.new(acc.outputs[0], node.inputs[1])
        node.inputs[2].default_value = a
        acc = node
    rel = nt.nodes.new("ShaderNodeMath")
    rel.operation = "MULTIPLY"
    rel.use_clamp = True
    nt.links.new(acc.outputs[0], rel.inputs[0])
    rel.inputs[1].default_value = 1.0 / sum(_TS_COEFFS)
    t = nt.nodes.new("ShaderNodeMath")
    t.operation = "MULTIPLY"
    nt.links.new(rel.outputs[0], t.inputs[0])
    t.inputs[1].default_value = tau0
    through = nt.nodes.new("ShaderNodeBsdfTransparent")
    nt.links.new(t.outputs[0], through.inputs["Color"])
    dif = nt.nodes.new("ShaderNodeBsdfDiffuse")
    dif.inputs["Color"].default_value = (rho[0], rho[1], rho[2], 1.0)
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(through.outputs[0], add.inputs[0])
    nt.links.new(dif.outputs[0], add.inputs[1])
    return add.outputs[0]


def _material(name: str, rho, radiance=None, image=None, tau0: float = 0.0):
    """Lambertian diffuse of reflectance rho; plus, for an emitter, an Emission of colour
    `radiance` (W/(m^2 sr)) and strength 1 - Backfacing (front side only); with an image, an
    Image Texture node made active: the bake's target. tau0 > 0: glass (_glass)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    if tau0 > 0:
        nt.links.new(_glass(nt, tau0, rho), out.inputs["Surface"])
        if image is not None:
            tex = nt.nodes.new("ShaderNodeTexImage")
            tex.image = image
            nt.nodes.active = tex
        return mat
    dif = nt.nodes.new("ShaderNodeBsdfDiffuse")
    dif.inputs["Color"].default_value = (rho[0], rho[1], rho[2], 1.0)
    dif.inputs["Roughness"].default_value = 0.0
    # Front side only: Cycles' Diffuse BSDF reflects on both sides of a face, hirad's surfaces
    # (and its reference's) absorb on the back. The Modern Hall has single-sided meshes that
    # face out of the room; reflecting on their backs put Blender 5-7 % above the reference.
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    black = nt.nodes.new("ShaderNodeBsdfDiffuse")
    black.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    sided = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(geo.outputs["Backfacing"], sided.inputs[0])
    nt.links.new(dif.outputs[0], sided.inputs[1])
    nt.links.new(black.outputs[0], sided.inputs[2])
    shader = sided.outputs[0]
    if radiance is not None and max(radiance) > 0:
        em = nt.nodes.new("ShaderNodeEmission")
        em.inputs["Color"].default_value = (radiance[0], radiance[1], radiance[2], 1.0)
        front = nt.nodes.new("ShaderNodeMath")
        front.operation = "SUBTRACT"
        front.inputs[0].default_value = 1.0
        nt.links.new(geo.outputs["Backfacing"], front.inputs[1])
        nt.links.new(front.outputs[0], em.inputs["Strength"])
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(sided.outputs[0], add.inputs[0])
        nt.links.new(em.outputs[0], add.inputs[1])
        shader = add.outputs[0]
    nt.links.new(shader, out.inputs["Surface"])
    if image is not None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = image
        for n in nt.nodes:
            n.select = False
        tex.select = True
        nt.nodes.active = tex
    return mat


def _object(name: str, verts, faces, mats, face_mat, loop_uv=None):
    """A mesh object from world-space vertices (list of (x, y, z)), faces (lists of vertex
    indices, corner order kept), its materials and per-face material index; loop_uv: per corner,
    in face order, (u, v) page coordinates."""
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    for m in mats:
        me.materials.append(m)
    me.polygons.foreach_set("material_index", face_mat)
    if loop_uv is not None:
        layer = me.uv_layers.new(name="st1")
        layer.data.foreach_set("uv", loop_uv)
    me.validate(clean_customdata=False)  # drops degenerate faces (with their loops' UVs)
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _bake(objs, margin: int) -> float:
    for o in bpy.context.scene.objects:
        o.select_set(False)
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]
    t0 = time.perf_counter()
    bpy.ops.object.bake(type="DIFFUSE", pass_filter={"DIRECT", "INDIRECT"}, margin=margin, use_clear=True,
                        target="IMAGE_TEXTURES")
    return time.perf_counter() - t0


def _pixels(img) -> array.array:
    px = array.array("f", bytes(4 * len(img.pixels)))
    img.pixels.foreach_get(px)
    return px


def blender_bake(spec_path: str) -> None:
    """Builds the scene described by spec.json (+ its .bin arrays), then bakes every page at each
    sample count of the ladder; writes <out>/blender_s<samples>_page<k>.f32 (RGBA float32, bottom
    row first) and <out>/blender.json (times)."""
    t_start = time.perf_counter()
    with open(spec_path) as f:
        spec = json.load(f)
    d = os.path.dirname(spec_path)
    scene = bpy.context.scene
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    _cycles_settings(scene, spec["samples"][0], spec["bounces"], spec["threads"])
    pts = _read_bin(os.path.join(d, "points.f64"), "d")
    images = [bpy.data.images.new(f"page{k}", w, h, alpha=False, float_buffer=True)
              for k, (w, h) in enumerate(spec["pages"])]
    bake_objs = []
    for g in spec["groups"]:
        counts = _read_bin(os.path.join(d, g["counts"]), "i")
        idx = _read_bin(os.path.join(d, g["indices"]), "i")
        fmat = _read_bin(os.path.join(d, g["face_material"]), "i")
        used = sorted(set(idx))
        local = {v: k for k, v in enumerate(used)}
        verts = [(pts[3 * v], pts[3 * v + 1], pts[3 * v + 2]) for v in used]
        faces, s = [], 0
        for c in counts:
            faces.append([local[v] for v in idx[s:s + c]])
            s += c
        img = images[g["page"]] if g["page"] >= 0 else None
        mats = [_material(f"{g['name']}_m{k}", m["rho"], m.get("radiance"), img, m.get("tau", 0.0))
                for k, m in enumerate(g["materials"])]
        uv = _read_bin(os.path.join(d, g["uv"]), "f") if g.get("uv") else None
        ob = _object(g["name"], verts, faces, mats, fmat, uv)
        if g["page"] >= 0:
            bake_objs.append(ob)
    t_build = time.perf_counter() - t_start
    print(f"blender: scene built in {t_build:.1f} s, {len(bake_objs)} objects to bake", flush=True)
    times = []
    for n in spec["samples"]:
        scene.cycles.samples = n
        t = _bake(bake_objs, spec["margin"])
        times.append(t)
        print(f"blender: {n} samples per texel: bake {t:.1f} s", flush=True)
        for k, img in enumerate(images):
            with open(os.path.join(d, f"blender_s{n}_page{k}.f32"), "wb") as f:
                _pixels(img).tofile(f)
        with open(os.path.join(d, "blender.json.tmp"), "w") as f:  # after every bake: partial runs count
            json.dump({"build_s": t_build, "samples": spec["samples"][:len(times)], "bake_s": times,
                       "version": bpy.app.version_string}, f)
        os.replace(os.path.join(d, "blender.json.tmp"), os.path.join(d, "blender.json"))


def blender_calibrate(samples: int = 256) -> None:
    """Unit checks of the conventions above, in Blender: a 10 m box of emitting walls (radiance L)
    around two 1 m plates at its centre (albedo 0.2 and 0.9), baked 'DIFFUSE' DIRECT+INDIRECT,
    colour off. (a) walls facing in, black: H/pi = L on both plates (closed uniform emitter: H = pi L;
    colour off removes the plate's albedo). (b) walls facing out: 0 (front-side emission only).
    (c) walls facing in and reflecting rho = 0.5: L / (1 - rho) = 2 L (a furnace, up to the plates'
    own small share of the enclosure)."""
    L = (1.0, 0.5, 0.25)
    scene = bpy.context.scene
    results = []
    # (d) as (a) with a pane of glass (tau0 0.6, rho 0) just above the plates across the whole
    # box: H/pi = L tau0 2 int_0^1 r(mu) mu dmu (the glass's angular curve, integrated here).
    m = 20000
    r = [min(1.0, max(0.0, sum(a * ((k + 0.5) / m) ** j for j, a in enumerate(_TS_COEFFS)) / sum(_TS_COEFFS)))
         for k in range(m)]
    hemi = 2 * sum(rk * (k + 0.5) / m for k, rk in enumerate(r)) / m
    for case, inward, rho_w, expect in (("a", True, 0.0, 1.0), ("b", False, 0.0, 0.0), ("c", True, 0.5, 2.0),
                                        ("d", True, 0.0, 0.6 * hemi)):
        for ob in list(bpy.data.objects):
            bpy.data.objects.remove(ob)
        _cycles_settings(scene, samples, 64, 2)
        s = 5.0
        v = [(x, y, z) for x in (-s, s) for y in (-s, s) for z in (-s, s)]
        # cube faces with outward winding (counter-clockwise seen from outside)
        quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
        if inward:
            quads = [list(reversed(q)) for q in quads]
        _object(f"walls_{case}", v, quads, [_material(f"wall_{case}", (rho_w,) * 3, L)], [0] * 6)
        if case == "d":
            h = 0.01
            _object("pane_d", [(-s, -s, h), (s, -s, h), (s, s, h), (-s, s, h)], [[0, 1, 2, 3]],
                    [_material("pane_d", (0.0,) * 3, None, None, 0.6)], [0])
        img = bpy.data.images.new(f"cal_{case}", 32, 32, alpha=False, float_buffer=True)
        plates = []
        for k, rho in enumerate((0.2, 0.9)):
            x0 = -1.2 + 1.4 * k
            pv = [(x0, -0.5, 0.0), (x0 + 1, -0.5, 0.0), (x0 + 1, 0.5, 0.0), (x0, 0.5, 0.0)]
            uv = array.array("f", [0.5 * k, 0, 0.5 * k + 0.45, 0, 0.5 * k + 0.45, 1, 0.5 * k, 1])
            plates.append(_object(f"plate_{case}{k}", pv, [[0, 1, 2, 3]],
                                  [_material(f"plate_{case}{k}", (rho,) * 3, None, img)], [0], uv))
        _bake(plates, 0)
        px = _pixels(img)
        for k in range(2):  # texel centres well inside each plate
            vals = [[px[4 * (j * 32 + i) + c] for j in range(4, 28) for i in range(16 * k + 2, 16 * k + 12)]
                    for c in range(3)]
            mean = [sum(vs) / len(vs) for vs in vals]
            results.append({"case": case, "plate_albedo": (0.2, 0.9)[k], "measured": mean,
                            "expected": [expect * l for l in L]})
            print(f"calibrate ({case}) walls {'in' if inward else 'out'}ward, wall albedo {rho_w}, plate albedo "
                  f"{(0.2, 0.9)[k]}: baked {[round(m, 4) for m in mean]}, expected {[expect * l for l in L]}",
                  flush=True)
    out = os.environ.get("HIRAD_CALIBRATION_JSON")
    if out:
        with open(out, "w") as f:
            json.dump(results, f)


if IN_BLENDER:
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    if argv and argv[0] == "calibrate":
        blender_calibrate(int(argv[1]) if len(argv) > 1 else 256)
    elif argv and argv[0] == "bake":
        blender_bake(argv[1])
    else:
        raise SystemExit("lightmaps_vs_blender.py under Blender: expected '-- calibrate' or '-- bake SPEC'")
    raise SystemExit(0)


# ============================================================================================
# hirad side (the project's .venv Python)

import argparse  # noqa: E402
import csv  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
HALL = ROOT.parent / "shared/data/modern_hall/usd/modern_hall.usda"
LUM = np.array([0.2126, 0.7152, 0.0722])
HIRAD = [sys.executable, "-m", "hirad.cli"]


def load() -> float:
    return os.getloadavg()[0]


def run_child(cmd: list[str], log: Path, env=None, timeout: float | None = None) -> dict:
    """Runs cmd (niced by 10) with output to log; wall time, peak RSS (wait4) and the load
    average at its start. A failure prints the log's tail and stops; past `timeout` seconds the
    child is killed and the result says so (its partial outputs may still be read)."""
    ld = load()
    t0 = time.perf_counter()
    killed = False
    with open(log, "w") as f:
        proc = subprocess.Popen(["nice", "-n", "10", *cmd], stdout=f, stderr=subprocess.STDOUT, env=env)
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if timeout is not None and time.perf_counter() - t0 > timeout and not killed:
                proc.kill()
                killed = True
            time.sleep(0.5)
    wall = time.perf_counter() - t0
    if killed:
        return {"wall_s": wall, "peak_rss_mib": usage.ru_maxrss / 1024, "load_at_start": ld, "killed_after_s": timeout}
    if status != 0:
        sys.stderr.write(log.read_text()[-4000:])
        raise SystemExit(f"{' '.join(map(str, cmd[:4]))} ... failed (status {status}); log {log}")
    return {"wall_s": wall, "peak_rss_mib": usage.ru_maxrss / 1024, "load_at_start": ld}


def blender_version() -> str:
    out = subprocess.run(["blender", "--version"], capture_output=True, text=True).stdout
    return out.splitlines()[0].strip() if out else "?"


# --------------------------------------------------------------------------------------------
# 1. hirad's bake

def hirad_bake(scene: Path, density: float, work: Path, args) -> tuple[dict, Path]:
    out = work / "hirad_out"
    cfg = {"scene": str(scene), "output": str(out), "method": "hierarchical",
           "hierarchy": {"epsilon": args.epsilon, "min_area": args.min_area, "samples": args.link_samples,
                         "max_rounds": args.max_rounds,
                         **({} if args.spread is None else {"spread_epsilon": args.spread}),
                         **({"cluster_receivers": True} if args.cluster_receivers else {})},
           "solver": {"method": "jacobi", "tolerance": 1e-4},
           "outputs": {"usd": True,
                       "lightmaps": {"enabled": True, "texels_per_metre": density, "padding": 2, "max_size": 4096,
                                     "supersample": args.supersample, "mode": args.mode,
                                     **({"gather_stride": args.gather_stride, "gather_tolerance": args.gather_tolerance,
                                         **({} if args.gather_second_bounce is None else
                                            {"gather_second_bounce": args.gather_second_bounce})}
                                        if args.mode == "final_gather" else {})},
                       "preview": {"enabled": False}, "report": True}}
    path = work / "hirad.yaml"
    record = work / "hirad_run.json"
    if args.reuse_hirad and record.exists() and yaml.safe_load(path.read_text()) == cfg:
        run = json.loads(record.read_text())
        run["reused_from_earlier_run"] = True
        print(f"hirad bake: REUSED from an earlier run in {work} (its figures, not this run's)")
        return run, out
    path.write_text(yaml.safe_dump(cfg))
    run = run_child([*HIRAD, "bake", str(path), "--quiet"], work / "hirad.log")
    report = json.loads((out / "report.json").read_text()) if (out / "report.json").exists() else {}
    run["report_timings_s"] = report.get("timings_s", {})
    run["when_utc"] = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    record.write_text(json.dumps(run))
    return run, out


# --------------------------------------------------------------------------------------------
# 2. The scene for Blender, with hirad's page UVs

def source_uvs(scene, out: Path) -> tuple[dict, list]:
    """Per scene corner, its page UV, and per face its page (-1: not baked): from each
    instance of the manifest (its prim, the mesh whose st1 it uses, page, scaleOffset) and
    primvars:st1 on that mesh in the bake's solution layer (faceVarying, authored corner order;
    corner_source maps the reader's corners to authored slots)."""
    from pxr import Usd
    manifest = json.loads((out / "lightmaps" / "manifest.json").read_text())
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    uv_set = manifest.get("uvSet", "st1")
    by_prim = {inst["prim"]: inst for inst in manifest["instances"]}
    counts = np.asarray(scene.face_vertex_counts, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    corner_uv = np.full((int(counts.sum()), 2), np.nan)
    face_page = np.full(len(counts), -1, np.int64)
    face_mesh = np.asarray(scene.face_mesh)
    for m, info in enumerate(scene.meshes):
        inst = by_prim.get(info.path)
        if inst is None:
            continue
        faces = np.nonzero(face_mesh == m)[0]
        corners = np.concatenate([np.arange(starts[f], starts[f] + counts[f]) for f in faces])
        st = stage.GetPrimAtPath(inst.get("mesh", info.path)).GetAttribute(f"primvars:{uv_set}").Get()
        if st is None or info.corner_source is None:
            print(f"warning: {info.path}: no primvars:{uv_set} or corner map: left out of the comparison")
            continue
        st = np.asarray(st, float)
        so = np.asarray(inst["scaleOffset"], float)
        corner_uv[corners] = st[np.asarray(info.corner_source)] * so[:2] + so[2:]
        face_page[faces] = inst["page"]
    return {"corner_uv": corner_uv, "face_page": face_page}, manifest["pages"]


def write_blender_input(scene, uvs: dict, pages: list, work: Path, args) -> Path:
    """spec.json + raw arrays: one group (Blender object) per page of baked faces (their page
    UVs, materials by reflectance), one of emitters, one of the rest (not baked: occluders and
    reflectors only)."""
    d = work / "blender"
    d.mkdir(exist_ok=True)
    np.asarray(scene.points, "<f8").tofile(d / "points.f64")
    counts = np.asarray(scene.face_vertex_counts, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    idx = np.asarray(scene.face_vertex_indices, np.int64)
    rho = np.asarray(scene.face_reflectance, float)
    radiance = np.asarray(scene.face_emission, float) / np.pi  # exitance -> Lambertian radiance
    tau = np.asarray(scene.face_transmittance, float).reshape(-1, 1)  # glazing's tau0 (0: opaque)
    emits = radiance.max(axis=1) > 0
    page = uvs["face_page"]
    groups = []
    selections = [(f"page{p}", (page == p) & ~emits, p) for p in range(len(pages))]
    selections += [("emitters", emits, -1), ("unbaked", (page < 0) & ~emits, -1)]
    for name, sel, p in selections:
        faces = np.nonzero(sel)[0]
        if not len(faces):
            continue
        key = np.concatenate([rho[faces], radiance[faces], tau[faces]], axis=1)
        mats, fmat = np.unique(key, axis=0, return_inverse=True)
        corners = np.concatenate([np.arange(starts[f], starts[f] + counts[f]) for f in faces])
        g = {"name": name, "page": int(p), "counts": f"{name}_counts.i32", "indices": f"{name}_indices.i32",
             "face_material": f"{name}_fmat.i32",
             "materials": [{"rho": m[:3].tolist(), "radiance": m[3:6].tolist(), "tau": float(m[6])} for m in mats]}
        counts[faces].astype("<i4").tofile(d / g["counts"])
        idx[corners].astype("<i4").tofile(d / g["indices"])
        fmat.reshape(-1).astype("<i4").tofile(d / g["face_material"])
        if p >= 0:
            uv = uvs["corner_uv"][corners]
            if not np.all(np.isfinite(uv)):
                raise SystemExit(f"{name}: corners without a lightmap UV")
            g["uv"] = f"{name}_uv.f32"
            uv.astype("<f4").tofile(d / g["uv"])
        groups.append(g)
    spec = {"pages": [[pg["width"], pg["height"]] for pg in pages], "groups": groups,
            "samples": args.samples, "bounces": args.bounces, "threads": args.threads, "margin": 2}
    (d / "spec.json").write_text(json.dumps(spec, indent=1))
    return d / "spec.json"


# --------------------------------------------------------------------------------------------
# 3. Texel sample points

def texel_points(scene, uvs: dict, pages: list, n: int, seed: int) -> dict:
    """n points, each at the centre of a page texel and on a baked non-emitting face: a uniform
    point on a fan triangle (by area) moved to the centre of its texel; redrawn when that centre
    lies outside the triangle in UV. Returns points, normals, page, texel (i, j) (j from v = 0),
    reflectance."""
    rng = np.random.default_rng(seed)
    counts = np.asarray(scene.face_vertex_counts, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    idx = np.asarray(scene.face_vertex_indices, np.int64)
    P = np.asarray(scene.points, float)
    ok = (uvs["face_page"] >= 0) & (np.asarray(scene.face_emission).max(1) == 0) & \
         (np.asarray(scene.face_reflectance).max(1) > 0)
    ntri = np.where(ok, counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    c = np.stack([starts[face], starts[face] + k, starts[face] + k + 1], axis=1)
    xyz, uv = P[idx[c]], uvs["corner_uv"][c]
    area = 0.5 * np.linalg.norm(np.cross(xyz[:, 1] - xyz[:, 0], xyz[:, 2] - xyz[:, 0]), axis=1)
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    uv_area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    area = np.where(uv_area > 0, area, 0.0)
    out = {"points": [], "normals": [], "page": [], "texel": [], "rho": []}
    size = np.array([[pg["width"], pg["height"]] for pg in pages], float)
    while len(out["points"]) < n:
        t = rng.choice(len(area), p=area / area.sum())
        r1, r2 = rng.random(2)
        s = np.sqrt(r1)
        b = np.array([1 - s, s * (1 - r2), s * r2])
        p = int(uvs["face_page"][face[t]])
        wh = size[p]
        texel = np.floor((b @ uv[t]) * wh).astype(int)
        centre = (texel + 0.5) / wh
        # barycentrics of the texel centre in the UV triangle
        e1, e2, q = uv[t, 1] - uv[t, 0], uv[t, 2] - uv[t, 0], centre - uv[t, 0]
        det = e1[0] * e2[1] - e1[1] * e2[0]
        v = (q[0] * e2[1] - q[1] * e2[0]) / det
        w = (e1[0] * q[1] - e1[1] * q[0]) / det
        if min(v, w, 1 - v - w) < 1e-6:
            continue
        bc = np.array([1 - v - w, v, w])
        nrm = np.cross(xyz[t, 1] - xyz[t, 0], xyz[t, 2] - xyz[t, 0])
        out["points"].append(bc @ xyz[t])
        out["normals"].append(nrm / np.linalg.norm(nrm))
        out["page"].append(p)
        out["texel"].append(texel)
        out["rho"].append(np.asarray(scene.face_reflectance)[face[t]])
    return {k: np.array(v) for k, v in out.items()}


def reference(scene_path: Path, pts: dict, work: Path, paths: int, seed: int, tag: str) -> tuple[dict, dict]:
    csv_in, csv_out = work / "points.csv", work / f"reference_{tag}.csv"
    with open(csv_in, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "z", "nx", "ny", "nz"])
        for p, n in zip(pts["points"], pts["normals"]):
            w.writerow([repr(float(x)) for x in (*p, *n)])
    run = run_child([*HIRAD, "reference", str(scene_path), str(csv_in), "--paths", str(paths), "--seed", str(seed),
                     "-o", str(csv_out)], work / f"reference_{tag}.log")
    rows = list(csv.DictReader(open(csv_out)))
    rad = np.array([[float(r[f"radiance_{c}"]) for c in "rgb"] for r in rows])
    se = np.array([[float(r[f"stderr_{c}"]) for c in "rgb"] for r in rows])
    return {"radiance": rad, "standard_error": se}, run


# --------------------------------------------------------------------------------------------
# 4. Lookups and errors

def texel_values(pages_rgb: list[np.ndarray], pts: dict, top_row_first: bool) -> np.ndarray:
    vals = np.zeros((len(pts["page"]), 3))
    for k, (p, (i, j)) in enumerate(zip(pts["page"], pts["texel"])):
        img = pages_rgb[p]
        row = img.shape[0] - 1 - j if top_row_first else j
        vals[k] = img[row, i, :3]
    return vals


def errors(texel_h_over_pi: np.ndarray, rho: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Relative error of the exitant radiance's luminance: rho * T against the reference."""
    return ((rho * texel_h_over_pi) @ LUM) / (ref @ LUM) - 1.0


def coverage(scene, uvs: dict, pages: list) -> list[np.ndarray]:
    """Per page, (H, W) bool, bottom row first: texels whose centre lies inside a baked face's
    fan triangle in page UV (the texels both tools bake from the surface, not from dilation)."""
    masks = [np.zeros((pg["height"], pg["width"]), bool) for pg in pages]
    counts = np.asarray(scene.face_vertex_counts, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for f in np.nonzero(uvs["face_page"] >= 0)[0]:
        p = int(uvs["face_page"][f])
        H, W = masks[p].shape
        for j in range(1, counts[f] - 1):
            uv = uvs["corner_uv"][[starts[f], starts[f] + j, starts[f] + j + 1]] * (W, H)
            lo, hi = np.floor(uv.min(0)).astype(int), np.ceil(uv.max(0)).astype(int)
            xs, ys = np.meshgrid(np.arange(max(lo[0], 0), min(hi[0] + 1, W)), np.arange(max(lo[1], 0), min(hi[1] + 1, H)))
            q = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1) - uv[0]
            e1, e2 = uv[1] - uv[0], uv[2] - uv[0]
            det = e1[0] * e2[1] - e1[1] * e2[0]
            if det == 0:
                continue
            v = (q[:, 0] * e2[1] - q[:, 1] * e2[0]) / det
            w = (e1[0] * q[:, 1] - e1[1] * q[:, 0]) / det
            ins = (v >= 0) & (w >= 0) & (v + w <= 1)
            masks[p][ys.ravel()[ins], xs.ravel()[ins]] = True
    return masks


def page_agreement(hirad_pages: list[np.ndarray], blender_pages: list[np.ndarray], masks: list[np.ndarray]) -> dict:
    """Texel for texel over whole pages: the ratio of luminances hirad / Blender at the covered
    texels (`coverage`) where both are above zero: median, and the fraction off by more than 50 %."""
    r = []
    for h, b, m in zip(hirad_pages, blender_pages, masks):
        hl, bl = h[::-1, :, :3] @ LUM, b[:, :, :3] @ LUM  # hirad's row 0 is the top: flip to bottom-first
        ok = m & (hl > 0) & (bl > 0)
        r.append(hl[ok] / bl[ok])
    r = np.concatenate(r) if r else np.zeros(0)
    if not len(r):
        return {"texels": 0}
    return {"texels": int(len(r)), "median_ratio": float(np.median(r)),
            "fraction_off_50pct": float(np.mean((r > 1.5) | (r < 1 / 1.5)))}


def summary(e: np.ndarray, ref_rse: np.ndarray) -> dict:
    ms = float(np.mean(e ** 2))
    return {"mean": float(np.mean(e)), "rms": float(np.sqrt(ms)),
            "rms_minus_ref_noise": float(np.sqrt(max(0.0, ms - float(np.mean(ref_rse ** 2))))),
            "median_abs": float(np.median(np.abs(e))), "p90_abs": float(np.quantile(np.abs(e), 0.9))}


# --------------------------------------------------------------------------------------------

def machine_state() -> dict:
    def cmd(c):
        try:
            return subprocess.run(c, capture_output=True, text=True, cwd=ROOT).stdout.strip()
        except OSError:
            return "?"
    cpu = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "?")
    import hirad
    return {"nproc": int(cmd(["nproc"]) or 0), "cpu": cpu, "loadavg": os.getloadavg(),
            "date_utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "hirad": hirad.__version__,
            "commit": cmd(["git", "rev-parse", "--short", "HEAD"]), "blender": blender_version(),
            "python": platform.python_version()}


def calibrate(work: Path) -> list:
    env = dict(os.environ, HIRAD_CALIBRATION_JSON=str(work / "calibration.json"))
    run_child(["blender", "-b", "--factory-startup", "--python", str(Path(__file__).resolve()), "--", "calibrate"],
              work / "calibration.log", env=env)
    res = json.loads((work / "calibration.json").read_text())
    for r in res:
        exp, got = np.array(r["expected"]), np.array(r["measured"])
        dev = np.abs(got - exp).max() / max(exp.max(), 1e-9) if exp.max() > 0 else np.abs(got).max()
        r["max_relative_deviation"] = float(dev)
        print(f"  Blender calibration ({r['case']}), plate albedo {r['plate_albedo']}: baked "
              f"{np.round(got, 4).tolist()} expected {exp.tolist()} (max deviation {dev:.2%})")
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", type=Path, default=HALL)
    ap.add_argument("--density", type=float, default=16.0, help="texels per metre (both tools)")
    ap.add_argument("--points", type=int, default=200, help="texel sample points compared")
    ap.add_argument("--seed", type=int, default=14)
    ap.add_argument("--candidates", type=int, default=None, help="texel points drawn before selection [1.3 N + 10]")
    ap.add_argument("--ref-paths", type=int, default=8192, help="hirad reference paths per point")
    ap.add_argument("--select-paths", type=int, default=2048, help="paths per point of the run that chooses points")
    ap.add_argument("--max-se", type=float, default=0.05,
                    help="drop points whose selection run's relative standard error is above this")
    ap.add_argument("--samples", type=lambda s: [int(x) for x in s.split(",")], default=[4, 16, 64],
                    help="Cycles samples per texel, a ladder of full bakes")
    ap.add_argument("--bounces", type=int, default=32)
    ap.add_argument("--blender-timeout", type=float, default=None, help="seconds; then the finished bakes count")
    ap.add_argument("--mode", choices=["final_gather", "interpolate"], default="final_gather",
                    help="hirad's outputs.lightmaps.mode")
    ap.add_argument("--threads", type=int, default=2, help="Blender threads (hirad uses all cores)")
    ap.add_argument("--epsilon", type=float, default=1e-5)
    ap.add_argument("--min-area", type=float, default=1e-3)
    ap.add_argument("--spread", type=float, default=None,
                    help="hierarchy.spread_epsilon (default: the config's; 0 is the fast setting for lamp-lit rooms)")
    ap.add_argument("--supersample", type=int, default=2)
    ap.add_argument("--gather-stride", type=int, default=1,
                    help="outputs.lightmaps.gather_stride (final_gather: 1 gathers every texel)")
    ap.add_argument("--gather-tolerance", type=float, default=0.05, help="outputs.lightmaps.gather_tolerance")
    ap.add_argument("--gather-second-bounce", type=float, default=None,
                    help="outputs.lightmaps.gather_second_bounce (default: the config's, 1; 0: off)")
    ap.add_argument("--cluster-receivers", action="store_true", help="hierarchy.cluster_receivers: true")
    ap.add_argument("--link-samples", type=int, default=16, help="hierarchy.samples")
    ap.add_argument("--max-rounds", type=int, default=6, help="hierarchy.max_rounds")
    ap.add_argument("--calibrate", action="store_true", help="only Blender's unit checks")
    ap.add_argument("--no-calibration", action="store_true", help="skip Blender's unit checks (debugging)")
    ap.add_argument("--reuse-blender", action="store_true",
                    help="use Blender's bakes already in --work (same spec) instead of baking again; stated in the output")
    ap.add_argument("--reuse-hirad", action="store_true",
                    help="use the hirad bake already in --work (same config) instead of baking again; stated in the output")
    ap.add_argument("--work", type=Path, default=None, help="keep intermediate files here")
    ap.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = ap.parse_args()
    if shutil.which("blender") is None:
        raise SystemExit("blender not found: apt-get install -y blender (Debian 12: 3.4.1)")
    work = args.work or Path(tempfile.mkdtemp(prefix="hirad_vs_blender_"))
    work.mkdir(parents=True, exist_ok=True)
    state = machine_state()
    print(f"machine: {state['nproc']} cores ({state['cpu']}), load {state['loadavg']}, {state['date_utc']}; "
          f"hirad {state['hirad']} ({state['commit']}), {state['blender']}")
    cal = None if args.no_calibration else calibrate(work)
    if args.calibrate:
        return
    scene_path = args.scene.resolve()
    print(f"scene {scene_path}, {args.density:g} texels/m, hirad lightmaps.mode {args.mode} (gather_stride {args.gather_stride}, tolerance {args.gather_tolerance:g}, second bounce "
          f"{'default' if args.gather_second_bounce is None else args.gather_second_bounce}), hierarchy "
          f"{'cluster_receivers, ' if args.cluster_receivers else ''}epsilon "
          f"{args.epsilon:g}, min_area {args.min_area:g}; work files in {work}")

    from hirad import _engine, usd
    run_h, out = hirad_bake(scene_path, args.density, work, args)
    print(f"hirad bake: {run_h['wall_s']:.1f} s wall (load {run_h['load_at_start']:.1f} at start), "
          f"peak RSS {run_h['peak_rss_mib']:.0f} MiB; stages {run_h['report_timings_s']}")
    scene = usd.read_scene(scene_path)
    uvs, pages = source_uvs(scene, out)
    texels = sum(pg["fill"] * pg["width"] * pg["height"] for pg in pages)
    page_area = sum(pg["width"] * pg["height"] for pg in pages)
    print(f"pages: {len(pages)} ({', '.join(str(pg['width']) + 'x' + str(pg['height']) for pg in pages)}), fill "
          f"{texels / page_area:.3f}, {texels:,.0f} covered texels")

    pts = texel_points(scene, uvs, pages, args.candidates or int(args.points * 1.3) + 10, args.seed)
    # Two independent reference runs: the first chooses the points, the second gives their values.
    # Choosing by a run's own relative standard error would keep the points whose estimate missed
    # the rare bright paths (a low mean with a low standard error): a reference biased low.
    ref_s, run_s = reference(scene_path, pts, work, args.select_paths, 7, "select")
    lum_s = ref_s["radiance"] @ LUM
    rse_s = np.where(lum_s > 0, (ref_s["standard_error"] @ LUM) / np.maximum(lum_s, 1e-300), np.inf)
    keep = np.nonzero((lum_s > 0.01 * np.median(lum_s)) & (rse_s <= args.max_se))[0][: args.points]
    ref, run_r = reference(scene_path, {k: v[keep] for k, v in pts.items()}, work, args.ref_paths, 8, "value")
    lum = ref["radiance"] @ LUM
    rse = np.where(lum > 0, (ref["standard_error"] @ LUM) / np.maximum(lum, 1e-300), np.inf)
    print(f"reference: {len(pts['page'])} texel points; selection run {args.select_paths} paths each "
          f"({run_s['wall_s']:.1f} s): {len(keep)} kept (lit, relative standard error <= {args.max_se:.0%}); value run "
          f"(another seed) {args.ref_paths} paths each ({run_r['wall_s']:.1f} s): mean relative standard error "
          f"{np.mean(rse):.2%}")
    sel = {k: v[keep] for k, v in pts.items()}
    ref_k, rse_k = ref["radiance"], rse

    hirad_pages = [np.asarray(_engine.read_exr(str(out / "lightmaps" / pg["file"])), float) for pg in pages]
    v_h = texel_values(hirad_pages, sel, top_row_first=True)

    previous = (work / "blender" / "spec.json").read_text() if (work / "blender" / "spec.json").exists() else None
    spec = write_blender_input(scene, uvs, pages, work, args)
    record = work / "blender_run.json"
    if args.reuse_blender and previous == spec.read_text() and record.exists() and (spec.parent / "blender.json").exists():
        run_b = json.loads(record.read_text())
        run_b["reused_from_earlier_run"] = True
        print(f"Blender bakes: REUSED from an earlier run in {work} (same scene, pages and settings; its figures)")
    else:
        run_b = run_child(["blender", "-b", "--factory-startup", "--python", str(Path(__file__).resolve()), "--",
                           "bake", str(spec)], work / "blender.log", timeout=args.blender_timeout)
        record.write_text(json.dumps(run_b))
    if "killed_after_s" in run_b:
        print(f"Blender killed after {args.blender_timeout:.0f} s: the sample counts it finished are below")
    bj = json.loads((spec.parent / "blender.json").read_text())
    v_b = []
    for n in bj["samples"]:
        imgs = [np.fromfile(spec.parent / f"blender_s{n}_page{k}.f32", "<f4").reshape(pg["height"], pg["width"], 4)
                for k, pg in enumerate(pages)]
        v_b.append(texel_values(imgs, sel, top_row_first=False))
    # A texel a tool left at exactly 0 where the reference is lit was not baked (a face Blender's
    # mesh validation dropped, a centre its rasteriser does not cover): a coverage failure, not
    # an error of the light. Such points leave the comparison for both tools, counted.
    unbaked = np.zeros(len(ref_k), bool)
    for v in [v_h, *v_b]:
        unbaked |= np.all(np.asarray(v)[:, :3] == 0, axis=1)
    if unbaked.any():
        print(f"points left out: {int(unbaked.sum())} whose texel a tool did not bake (0 where the reference is lit): "
              f"hirad {int(np.all(v_h[:, :3] == 0, axis=1).sum())}, Blender "
              f"{[int(np.all(np.asarray(v)[:, :3] == 0, axis=1).sum()) for v in v_b]} per sample count")
    ok = ~unbaked
    e_h = errors(v_h[ok], sel["rho"][ok], ref_k[ok])
    s_h = summary(e_h, rse_k[ok])
    rows = []
    for n, t, v in zip(bj["samples"], bj["bake_s"], v_b):
        e_b = errors(v[ok], sel["rho"][ok], ref_k[ok])
        rows.append({"samples": n, "bake_s": t, "texels_per_s": texels / t, **summary(e_b, rse_k[ok])})

    agree = None
    if rows:
        n = rows[-1]["samples"]
        imgs = [np.fromfile(spec.parent / f"blender_s{n}_page{k}.f32", "<f4").reshape(pg["height"], pg["width"], 4)
                for k, pg in enumerate(pages)]
        agree = page_agreement(hirad_pages, imgs, coverage(scene, uvs, pages))
        if agree["texels"]:
            print(f"whole pages, texel for texel against Blender {n} spp ({agree['texels']:,} texels whose centre is on a baked face): median "
                  f"hirad/Blender {agree['median_ratio']:.3f}, {agree['fraction_off_50pct']:.1%} off by more than 50 %")
    print(f"\nBlender process: {run_b['wall_s']:.1f} s wall (load {run_b['load_at_start']:.1f} at start; scene build "
          f"{bj['build_s']:.1f} s), peak RSS {run_b['peak_rss_mib']:.0f} MiB, {args.threads} threads, "
          f"{args.bounces} bounces")
    print(f"\n{'tool':<26}{'time s':>9}{'texels/s':>11}{'mean err':>10}{'RMS err':>9}{'RMS-noise':>10}"
          f"{'|err| p90':>10}")
    print(f"{'hirad (whole bake)':<26}{run_h['wall_s']:>9.1f}{texels / run_h['wall_s']:>11,.0f}{s_h['mean']:>+10.2%}"
          f"{s_h['rms']:>9.2%}{s_h['rms_minus_ref_noise']:>10.2%}{s_h['p90_abs']:>10.2%}")
    for r in rows:
        print(f"{'Blender ' + str(r['samples']) + ' spp (bake op)':<26}{r['bake_s']:>9.1f}{r['texels_per_s']:>11,.0f}"
              f"{r['mean']:>+10.2%}{r['rms']:>9.2%}{r['rms_minus_ref_noise']:>10.2%}{r['p90_abs']:>10.2%}")
    # Blender's time at hirad's error: log-log interpolation of time against RMS error
    match = None
    er, tm = np.array([r["rms"] for r in rows]), np.array([r["bake_s"] for r in rows])
    if len(rows) >= 2 and er.min() <= s_h["rms"] <= er.max():
        o = np.argsort(er)
        match = float(np.exp(np.interp(np.log(s_h["rms"]), np.log(er[o]), np.log(tm[o]))))
        print(f"\nBlender's bake time at hirad's RMS error ({s_h['rms']:.2%}), interpolated: {match:.1f} s; hirad "
              f"{run_h['wall_s']:.1f} s: ratio {match / run_h['wall_s']:.2f}x")
    elif rows:
        print(f"\nhirad's RMS error {s_h['rms']:.2%} is outside Blender's range "
              f"{er.min():.2%}..{er.max():.2%}: no interpolated time")
    extrapolated = None
    if rows and match is None and s_h["rms_minus_ref_noise"] < rows[-1]["rms_minus_ref_noise"]:
        # Monte Carlo noise falls as 1/sqrt(samples) and the bake time grows with them: from the
        # largest bake, the time at which Blender's noise (reference noise removed) would reach
        # hirad's. An estimate, not a measurement: it assumes Blender has no bias left.
        last = rows[-1]
        extrapolated = float(last["bake_s"] * (last["rms_minus_ref_noise"] / max(s_h["rms_minus_ref_noise"], 1e-9)) ** 2)
        print(f"Blender's bake time at hirad's error (RMS less reference noise {s_h['rms_minus_ref_noise']:.2%}), "
              f"EXTRAPOLATED from {last['samples']} spp as 1/sqrt(samples): {extrapolated:.0f} s; hirad "
              f"{run_h['wall_s']:.1f} s: ratio {extrapolated / run_h['wall_s']:.1f}x (an estimate)")
    figures = {"machine": state, "end_load": os.getloadavg(), "calibration": cal, "scene": str(scene_path),
               "density": args.density, "mode": args.mode, "gather_stride": args.gather_stride, "gather_tolerance": args.gather_tolerance, "gather_second_bounce": args.gather_second_bounce, "cluster_receivers": args.cluster_receivers, "epsilon": args.epsilon, "min_area": args.min_area, "pages": [{k: pg[k] for k in ("width", "height", "fill")} for pg in pages],
               "covered_texels": texels, "points": len(keep), "points_unbaked_left_out": int(unbaked.sum()), "ref_paths": args.ref_paths, "select_paths": args.select_paths, "selection_run": run_s,
               "ref_mean_rse": float(np.mean(rse_k)), "hirad": {**run_h, **s_h}, "reference_run": run_r,
               "blender": {"process": run_b, "build_s": bj["build_s"], "rows": rows, "bounces": args.bounces,
                           "threads": args.threads, "version": bj["version"]},
               "blender_time_at_hirad_error_s": match, "blender_time_at_hirad_error_extrapolated_s": extrapolated,
               "page_agreement": agree}
    if args.json:
        tmp = args.json.with_suffix(".tmp")
        tmp.write_text(json.dumps(figures, indent=1, default=float))
        os.replace(tmp, args.json)
    print(f"\nend: load {os.getloadavg()}")


if __name__ == "__main__":
    main()
