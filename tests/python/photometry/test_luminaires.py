"""Luminaire tables (hirad.photometry.luminaires) and the lights that become luminaires
(hirad.usd.scene: SphereLight, CylinderLight, shaped RectLight/DiskLight, IES files; the
config's point lights).

Oracles are closed forms: an isotropic point of I cd emits 4 pi I lm; I0 cos^n(gamma) over the
lower hemisphere 2 pi I0 / (n + 1); a Lambertian sphere of luminance L and radius r 4 pi^2 r^2 L;
a Lambertian cylinder without caps 2 pi^2 r l L; a Lambertian panel L A cos(gamma) cut by a hard
cone at theta_c pi L A sin^2(theta_c), and with focus f 2 pi L A / (f + 2); the reference lumen
totals of the shared IES files (../shared/data/ies: Photometric Toolbox's totals, the BEGA files'
[LAMP] line, the manufacturer's [_ABSOLUTELUMENS]).
"""

from __future__ import annotations

import math
import re
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pxr")

from hirad import usd as hu  # noqa: E402
from hirad.config import ConfigError, load_config  # noqa: E402
from hirad.photometry import IesWarning, lumens, read_ies  # noqa: E402
from hirad.photometry import luminaires as L  # noqa: E402

SHARED_IES = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "ies"
Y = np.array([0.2126, 0.7152, 0.0722])


def engine_luminaire():
    try:
        from hirad import _engine
    except ImportError:
        return None
    return getattr(_engine, "Luminaire", None)


needs_engine = pytest.mark.skipif(engine_luminaire() is None,
                                  reason="hirad._engine has no Luminaire (build the engine: make engine)")


# ----------------------------------------------------------------------------- helpers

FLOOR = """
def Mesh "floor" {
    point3f[] points = [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
}
"""


def write_scene(tmp_path: Path, body: str, name="scene.usda", up="Z", mpu=1) -> Path:
    path = tmp_path / name
    path.write_text(f'#usda 1.0\n(\n    metersPerUnit = {mpu}\n    upAxis = "{up}"\n)\n' + FLOOR
                    + textwrap.dedent(body))
    return path


def light(kind, name="lamp", attrs="", schemas="", xform="double3 xformOp:translate = (0, 0, 2)",
          order='"xformOp:translate"'):
    meta = f'(\n    prepend apiSchemas = [{schemas}]\n)' if schemas else ""
    return f"""
def {kind} "{name}" {meta}
{{
    {attrs}
    {xform}
    uniform token[] xformOpOrder = [{order}]
}}
"""


def ies_text(v, h, cand, lumens_per_lamp=-1, mult=1.0, ballast=1.0):
    """An LM-63-2002 type C file; cand is (len(v), len(h))."""
    cand = np.asarray(cand, dtype=float)
    lines = ["IESNA:LM-63-2002", "[TEST] hirad luminaire test", "TILT=NONE",
             f"1 {lumens_per_lamp:g} {mult:g} {len(v)} {len(h)} 1 2 0 0 0", f"{ballast:g} 1 10"]
    lines.append(" ".join(f"{x:.10g}" for x in v))
    lines.append(" ".join(f"{x:.10g}" for x in h))
    for j in range(len(h)):
        lines.append(" ".join(f"{x:.10g}" for x in cand[:, j]))
    return "\n".join(lines) + "\n"


def c90_profile_file(tmp_path, name="c90.ies"):
    """Light only around C90 at gamma 90 (a lobe toward local +Y); nothing elsewhere."""
    v = np.arange(0.0, 181.0, 5.0)
    h = np.arange(0.0, 361.0, 10.0)
    gv = np.exp(-((v - 90.0) / 20.0) ** 2)
    dc = np.minimum(np.abs(h - 90.0), 360 - np.abs(h - 90.0))
    hc = np.exp(-(dc / 25.0) ** 2)
    cand = 1000.0 * gv[:, None] * hc[None, :]
    cand[cand < 1e-6] = 0.0
    path = tmp_path / name
    path.write_text(ies_text(v, h, cand))
    return path


def cos_n_file(tmp_path, n, i0=1000.0, name=None, **kw):
    v = np.arange(0.0, 180.5, 0.5)
    col = i0 * np.where(v <= 90, np.cos(np.radians(np.minimum(v, 90))) ** n, 0.0)
    path = tmp_path / (name or f"cos{n}.ies")
    path.write_text(ies_text(v, [0.0], col[:, None], **kw))
    return path


def only(scene):
    assert len(scene.luminaires) == 1, [s.name for s in scene.luminaires]
    return scene.luminaires[0]


def dense_integral(f, a, b, n=200001):
    """Composite Simpson on n points (the oracle for soft cones: independent of the module)."""
    x = np.linspace(a, b, n)
    y = f(x)
    h = (b - a) / (n - 1)
    return h / 3 * (y[0] + y[-1] + 4 * y[1:-1:2].sum() + 2 * y[2:-1:2].sum())


# ----------------------------------------------------------------------------- tables


def test_isotropic_point_flux_is_4_pi_i():
    t = L.sample_table(L.isotropic(123.0))
    assert t.shape == (1, L.NG_DEFAULT)
    assert L.table_flux(t) == pytest.approx(4 * math.pi * 123.0, rel=1e-12)
    np.testing.assert_allclose(t, 123.0, rtol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 5, 20])
def test_cos_n_profile_flux(n):
    t = L.sample_table(L.cos_power(1000.0, n))
    assert abs(L.table_flux(t) / (2 * math.pi * 1000.0 / (n + 1)) - 1) < 1e-3
    # the node averages stay the profile within O(h^2): the peak within 0.05 %
    assert t[0, 0] == pytest.approx(1000.0, rel=5e-4)
    assert t[0, -1] == 0.0


def test_table_flux_is_the_bilinear_integral():
    """table_flux against a brute-force midpoint integration of the bilinear table."""
    rng = np.random.default_rng(3)
    t = rng.uniform(0, 10, size=(12, 19))
    g = np.radians(np.linspace(0, 180, 4001)[:-1] + 180 / 8000)
    c = np.linspace(0, 360, 2401)[:-1] + 360 / 4800
    gg, cc = np.meshgrid(np.degrees(g), c, indexing="ij")
    d = np.stack([np.sin(np.radians(gg)) * np.cos(np.radians(cc)), np.sin(np.radians(gg)) * np.sin(np.radians(cc)),
                  -np.cos(np.radians(gg))], axis=-1).reshape(-1, 3)
    vals = L.table_intensity(t, np.eye(3), d).reshape(gg.shape)
    brute = (vals * np.sin(g)[:, None]).sum() * (math.pi / 4000) * (2 * math.pi / 2400)
    assert L.table_flux(t) == pytest.approx(brute, rel=1e-5)


def test_hard_cone_loses_nothing_to_the_table():
    """A 30 degree hard cone on a Lambertian panel: pi L A sin^2(30); point sampling at 0.5
    degrees would be ~1.5 % off, the hat averages are exact."""
    t = L.sample_table(L.lambertian(2.0) * L.cone_factor(30.0))
    assert L.table_flux(t) == pytest.approx(math.pi * 2.0 * 0.25, rel=1e-9)


@needs_engine
@pytest.mark.parametrize("profile", [L.isotropic(7.0), L.cos_power(100.0, 3), L.cylinder(2.5)])
def test_engine_flux_and_intensity_agree_with_numpy(profile):
    spec = L.LuminaireSpec(name="t", kind="test", source="test", points=[[1, 2, 3]], weights=[1.0],
                           frame=L.rotate_xyz((20, 30, 40)), candela=L.sample_table(profile),
                           colour=[1.0, 0.5, 0.25])
    eng = spec.to_engine()
    np.testing.assert_allclose(np.asarray(eng.flux).reshape(3), spec.flux, rtol=1e-10)
    d = np.random.default_rng(1).normal(size=(200, 3))
    np.testing.assert_allclose(np.asarray(eng.intensity(d)), spec.intensity(d), rtol=1e-9, atol=1e-12)


# ----------------------------------------------------------------------------- USD lights


def test_sphere_light_flux_is_exact(tmp_path):
    attrs = "float inputs:radius = 0.15\n float inputs:intensity = 200\n color3f inputs:color = (1, 0.5, 0.25)"
    scene = hu.read_scene(write_scene(tmp_path, light("SphereLight", attrs=attrs)), require_emission=True)
    lum = only(scene)
    r = np.float32(0.15)
    np.testing.assert_allclose(lum.flux, 4 * math.pi ** 2 * r * r * 200 * np.array([1, 0.5, 0.25]), rtol=1e-6)
    np.testing.assert_allclose(lum.points, [[0, 0, 2]])
    assert not np.any(scene.face_emission > 0) and [m.path for m in scene.meshes] == ["/floor"]


def test_point_lights_radius_zero(tmp_path):
    body = (light("SphereLight", "norm", "float inputs:radius = 0\n float inputs:intensity = 40\n"
                                         " bool inputs:normalize = 1")
            + light("SphereLight", "plain", "float inputs:radius = 0\n float inputs:intensity = 40")
            + light("SphereLight", "power", "float inputs:radius = 0\n float photometric:power = 800"))
    scene = hu.read_scene(write_scene(tmp_path, body))
    by = {s.source: s for s in scene.luminaires}
    assert set(by) == {"/norm", "/power"}
    np.testing.assert_allclose(by["/norm"].intensity(np.array([[0, 0, -1.0], [1, 0, 0]])), 10.0, rtol=1e-12)
    assert by["/power"].lumens == pytest.approx(800.0, rel=1e-12)
    assert any(w.startswith("/plain:") and "radius 0" in w and "ignored" in w for w in scene.warnings)


def test_cylinder_light_flux_and_axis(tmp_path):
    attrs = "float inputs:length = 1.2\n float inputs:radius = 0.02\n float inputs:intensity = 5000"
    xform = "double3 xformOp:translate = (0, 0, 2)\n    float xformOp:rotateZ = 90"
    scene = hu.read_scene(write_scene(tmp_path, light("CylinderLight", attrs=attrs, xform=xform,
                                                      order='"xformOp:translate", "xformOp:rotateZ"')))
    lum = only(scene)
    r, length = float(np.float32(0.02)), float(np.float32(1.2))
    assert lum.flux[0] / (2 * math.pi ** 2 * r * length * 5000) == pytest.approx(1.0, abs=1e-3)
    # the points run along the axis, local X rotated to world Y
    assert len(lum.points) >= 8
    np.testing.assert_allclose(lum.points[:, [0, 2]], [[0, 2]] * len(lum.points), atol=1e-9)
    assert lum.points[:, 1].min() == pytest.approx(-0.6 + 0.6 / len(lum.points), rel=1e-6)
    i = lum.intensity(np.array([[0, 1.0, 0], [1.0, 0, 0], [0, 0, -1.0]]))[:, 0]
    assert i[0] < 1e-2 * i[1]  # along the axis: nothing (the node average of the kink: < 1 %)
    assert i[1] == pytest.approx(2 * r * length * 5000, rel=1e-4)
    assert i[2] == pytest.approx(2 * r * length * 5000, rel=1e-4)


@pytest.mark.parametrize("softness", [0.0, 0.25, 1.0])
def test_cone_shaped_rect_light_flux(tmp_path, softness):
    angle = 35.0
    attrs = (f"float inputs:width = 0.6\n float inputs:height = 0.3\n float inputs:intensity = 1000\n"
             f" float inputs:shaping:cone:angle = {angle}\n float inputs:shaping:cone:softness = {softness}")
    scene = hu.read_scene(write_scene(tmp_path, light("RectLight", attrs=attrs, schemas='"ShapingAPI"')))
    lum = only(scene)
    area = float(np.float32(0.6)) * float(np.float32(0.3))
    tc = math.radians(angle)
    if softness == 0:
        ref = math.pi * 1000 * area * math.sin(tc) ** 2
    else:
        ts = tc * (1 - softness)

        def f(th):
            t = np.clip((th - ts) / (tc - ts), 0, 1)
            return np.cos(th) * np.sin(th) * (1 - t * t * (3 - 2 * t))
        ref = 2 * math.pi * 1000 * area * dense_integral(f, 0.0, tc)
    assert lum.flux[0] / ref == pytest.approx(1.0, abs=1e-6)
    assert len(lum.points) == 8 * 4  # 8 along the longer side
    assert not np.any(scene.face_emission > 0)


def test_focus_and_focus_tint(tmp_path):
    """I = L A cos^(1+f) -> 2 pi L A / (f + 2); a tint t per channel: t/2 + (1 - t)/(f + 2)."""
    attrs = ("float inputs:radius = 0.25\n float inputs:intensity = 100\n float inputs:shaping:focus = 3\n"
             " color3f inputs:shaping:focusTint = (0.5, 0.25, 0)")
    scene = hu.read_scene(write_scene(tmp_path, light("DiskLight", attrs=attrs, schemas='"ShapingAPI"')))
    assert len(scene.luminaires) == 2 and {s.group for s in scene.luminaires} == {"/lamp"}
    total = sum(s.flux for s in scene.luminaires)
    la = 100 * math.pi * 0.25 ** 2
    tint = np.array([0.5, 0.25, 0.0])
    np.testing.assert_allclose(total, 2 * math.pi * la * (tint / 2 + (1 - tint) / 5), rtol=1e-6)
    rows = L.schedule(scene.luminaires)
    assert len(rows) == 1 and rows[0]["count"] == 1
    assert rows[0]["lumens"] == pytest.approx(float(total @ Y), rel=1e-12)


def test_rect_light_without_shaping_stays_an_area_emitter(tmp_path):
    attrs = "float inputs:width = 0.5\n float inputs:height = 0.5\n float inputs:intensity = 10"
    scene = hu.read_scene(write_scene(tmp_path, light("RectLight", attrs=attrs)))
    assert scene.luminaires == [] and any(m.path == "/lamp" and m.is_light for m in scene.meshes)


# ----------------------------------------------------------------------------- photometric:power


@pytest.mark.parametrize("kind, attrs, schemas", [
    ("SphereLight", "float inputs:radius = 0.1", ""),
    ("CylinderLight", "float inputs:length = 1\n float inputs:radius = 0.03", ""),
    ("RectLight", "float inputs:width = 1\n float inputs:height = 0.5\n float inputs:shaping:cone:angle = 40",
     '"ShapingAPI"'),
    ("DiskLight", "float inputs:radius = 0.2\n float inputs:shaping:focus = 2\n"
                  " color3f inputs:shaping:focusTint = (0.2, 0.5, 0.9)", '"ShapingAPI"'),
])
def test_photometric_power_gives_exactly_that_flux(tmp_path, kind, attrs, schemas):
    attrs += "\n float inputs:intensity = 37\n color3f inputs:color = (1, 0.8, 0.3)\n float photometric:power = 1500"
    scene = hu.read_scene(write_scene(tmp_path, light(kind, attrs=attrs, schemas=schemas)))
    assert sum(s.lumens for s in scene.luminaires) == pytest.approx(1500.0, rel=1e-12)
    # the colour's chromaticity is kept
    rgb = sum(s.flux for s in scene.luminaires)
    if kind != "DiskLight":
        np.testing.assert_allclose(rgb / rgb[0], [1, 0.8, 0.3], rtol=1e-6)


def test_photometric_power_on_an_area_emitter(tmp_path):
    attrs = ("float inputs:width = 2\n float inputs:height = 0.5\n color3f inputs:color = (1, 0.5, 0.5)\n"
             " float photometric:power = 1000")
    scene = hu.read_scene(write_scene(tmp_path, light("RectLight", attrs=attrs)))
    k = [i for i, m in enumerate(scene.meshes) if m.path == "/lamp"][0]
    exitance = scene.face_emission[scene.face_mesh == k][0]
    assert float(exitance @ Y) * 1.0 == pytest.approx(1000.0, rel=1e-9)  # M x A, A = 1 m^2


def test_photometric_power_on_a_dark_light_is_an_error(tmp_path):
    attrs = "float inputs:radius = 0.1\n float inputs:intensity = 0\n float photometric:power = 100"
    with pytest.raises(hu.SceneError) as info:
        hu.read_scene(write_scene(tmp_path, light("SphereLight", attrs=attrs)))
    assert "/lamp.photometric:power" in str(info.value)


# ----------------------------------------------------------------------------- IES files


def _reference_lumens():
    refs = {}
    table = SHARED_IES / "rab" / "ies_summary_reference_lumens.md"
    header = None
    for line in table.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None and "file name" in cells:
            header = cells
            continue
        if header and cells and re.match(r"^\d+\.ies$", cells[0], re.IGNORECASE):
            refs[f"rab/{cells[0].split('.')[0]}.IES"] = (float(cells[header.index("Photometric Toolbox lumen")]), 0.005)
    for f in sorted((SHARED_IES / "ieslibrary").glob("*.ies")):
        m = re.search(r"^\[LAMP\]\s*([\d.]+)\s*lm", f.read_text(encoding="utf-8", errors="replace"), re.MULTILINE)
        if m:
            refs[f"ieslibrary/{f.name}"] = (float(m.group(1)), 0.005)
    # the lab's integer keyword; this type B file's published angles integrate 0.52 % above it
    # with every interpolant (tests/python/photometry/test_ies.py), so 1 % here
    refs["rab/flood_2.1.IES"] = (10601.0, 0.01)
    return refs


def _shared_files():
    if not SHARED_IES.is_dir():
        return []
    return sorted(p.relative_to(SHARED_IES).as_posix() for p in SHARED_IES.glob("*/*") if p.suffix.lower() == ".ies")


SKIP_SHARED = pytest.mark.skipif(not SHARED_IES.is_dir(), reason=f"{SHARED_IES} is absent: the shared IES data set "
                                 "(../shared/data/ies beside the project) is not on this machine")


@SKIP_SHARED
@pytest.mark.parametrize("name", _shared_files())
def test_shared_ies_table_flux(name):
    """Every shared file: the table's flux is ies.lumens() (the interpolant's flux) to 1e-6, and
    the published total to 0.5 % where one is stated."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IesWarning)
        p = read_ies(SHARED_IES / name)
    t = L.sample_table(L.ies_profile(p))
    got = L.table_flux(t)
    assert got == pytest.approx(lumens(p), rel=1e-6)
    # the nodes are the interpolant's (Photometry.candela_at) local averages: within 0.5 % of the
    # peak (the narrow BEGA spot's 39,296 cd peak differs by 0.15 %)
    nc, ng = t.shape
    point = np.asarray(p.candela_at(L.gamma_nodes(ng)[None, :], L.c_nodes(nc)[:, None]))
    assert np.abs(t - point).max() <= 5e-3 * point.max()
    refs = _reference_lumens()
    if name in refs:
        ref, tol = refs[name]
        assert abs(got / ref - 1) <= tol, f"{name}: table {got:.2f} lm, reference {ref}"


@SKIP_SHARED
def test_every_shared_reference_is_used():
    assert len(_reference_lumens()) == 15 and len(_shared_files()) == 19


@SKIP_SHARED
def test_usd_light_with_a_shared_ies_file_absolute(tmp_path):
    src = SHARED_IES / "rab" / "7.IES"
    (tmp_path / "ies").mkdir()
    (tmp_path / "ies" / "down.ies").write_bytes(src.read_bytes())
    attrs = ("float inputs:radius = 0.05\n float inputs:intensity = 2\n asset inputs:shaping:ies:file = @ies/down.ies@\n"
             " bool inputs:normalize = 1")
    scene = hu.read_scene(write_scene(tmp_path, light("SphereLight", attrs=attrs, schemas='"ShapingAPI"')))
    lum = only(scene)
    assert lum.ies_mode == "absolute" and Path(lum.ies) == (tmp_path / "ies" / "down.ies")
    assert lum.lumens == pytest.approx(2 * 531.98, rel=5e-3)  # intensity 2 dims the file's candela
    (row,) = L.schedule(scene.luminaires)
    assert row["ies"] == lum.ies and row["ies_mode"] == "absolute" and row["count"] == 1


def test_ies_modes(tmp_path):
    cos_n_file(tmp_path, 2, i0=500.0)
    attrs = "float inputs:radius = 0.125\n float inputs:intensity = 1000\n asset inputs:shaping:ies:file = @cos2.ies@"
    body = (light("SphereLight", "plain", attrs, '"ShapingAPI"')
            + light("SphereLight", "norm", attrs + "\n bool inputs:shaping:ies:normalize = 1", '"ShapingAPI"'))
    path = write_scene(tmp_path, body)
    absolute = {s.source: s for s in hu.read_scene(path).luminaires}
    usdlux = {s.source: s for s in hu.read_scene(path, ies_mode="usdlux").luminaires}
    phi_file = 2 * math.pi * 500 / 3
    # absolute: the file's candela x the dimmer (intensity 1000), the sphere's size plays no part
    assert absolute["/plain"].flux[0] == pytest.approx(1000 * phi_file, rel=1e-4)
    # usdlux: L pi r^2 x the sample; normalize keeps the sphere's own flux 4 pi^2 r^2 L
    assert usdlux["/plain"].flux[0] == pytest.approx(1000 * math.pi * 0.125 ** 2 * phi_file, rel=1e-4)
    assert usdlux["/norm"].flux[0] == pytest.approx(4 * math.pi ** 2 * 0.125 ** 2 * 1000, rel=1e-9)
    assert usdlux["/norm"].ies_mode == "usdlux"


def test_ies_angle_scale(tmp_path):
    """angleScale 0.5 halves the angles: a cos profile becomes cos(2 gamma) inside 45 degrees."""
    cos_n_file(tmp_path, 1, i0=100.0)
    attrs = "float inputs:radius = 0.1\n asset inputs:shaping:ies:file = @cos1.ies@\n float inputs:shaping:ies:angleScale = 0.5"
    lum = only(hu.read_scene(write_scene(tmp_path, light("SphereLight", attrs=attrs, schemas='"ShapingAPI"'))))
    ref = 2 * math.pi * 100 * dense_integral(lambda g: np.cos(2 * g) * np.sin(g), 0.0, math.pi / 4)
    assert lum.flux[0] == pytest.approx(ref, rel=1e-4)


def test_bad_ies_path_is_a_located_error(tmp_path):
    attrs = "float inputs:radius = 0.1\n asset inputs:shaping:ies:file = @nowhere/spot.ies@"
    path = write_scene(tmp_path, light("SphereLight", "spot", attrs=attrs, schemas='"ShapingAPI"'))
    with pytest.raises(hu.SceneError) as info:
        hu.read_scene(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: /spot.inputs:shaping:ies:file: IES file not found")
    assert str(tmp_path / "nowhere" / "spot.ies") in msg


def test_bad_ies_content_names_prim_file_and_line(tmp_path):
    text = ies_text([0, 90], [0], [[10], [0]]).replace("0 90", "0 ninety")
    (tmp_path / "bad.ies").write_text(text)
    attrs = "float inputs:radius = 0.1\n asset inputs:shaping:ies:file = @bad.ies@"
    with pytest.raises(hu.SceneError) as info:
        hu.read_scene(write_scene(tmp_path, light("SphereLight", "spot", attrs=attrs, schemas='"ShapingAPI"')))
    msg = str(info.value)
    assert "/spot.inputs:shaping:ies:file" in msg and str(tmp_path / "bad.ies") in msg and "line 6" in msg


# ----------------------------------------------------------------------------- axes


def test_axes_profile_lit_at_c90_lights_world_plus_y(tmp_path):
    f = c90_profile_file(tmp_path)
    p = read_ies(f)
    t = L.sample_table(L.ies_profile(p))
    dirs = np.array([[0, 1.0, 0], [1.0, 0, 0], [-1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    i = L.table_intensity(t, np.eye(3), dirs)
    assert i[0] == pytest.approx(1000.0, rel=1e-3) and np.all(i[1:] < 1e-3 * i[0])
    # a light turned 90 degrees about Z: its +Y is world -X
    frame = L.rotate_xyz((0, 0, 90))
    i = L.table_intensity(t, frame, dirs)
    assert i[2] == pytest.approx(1000.0, rel=1e-3) and i[0] < 1e-3 * i[2]


def test_axes_of_usd_lights_with_an_ies_profile(tmp_path):
    c90_profile_file(tmp_path)
    attrs = "float inputs:radius = 0.1\n asset inputs:shaping:ies:file = @c90.ies@"
    turned = ("double3 xformOp:translate = (0, 0, 2)\n    float xformOp:rotateZ = 90", '"xformOp:translate", "xformOp:rotateZ"')
    mirrored = ("double3 xformOp:translate = (0, 0, 2)\n    float3 xformOp:scale = (1, -1, 1)",
                '"xformOp:translate", "xformOp:scale"')
    body = (light("SphereLight", "plain", attrs, '"ShapingAPI"')
            + light("SphereLight", "turned", attrs, '"ShapingAPI"', *turned)
            + light("SphereLight", "mirrored", attrs, '"ShapingAPI"', *mirrored))
    by = {s.source: s for s in hu.read_scene(write_scene(tmp_path, body)).luminaires}
    dirs = np.array([[0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0]])
    peak = {k: int(np.argmax(s.intensity(dirs)[:, 0])) for k, s in by.items()}
    assert peak == {"/plain": 0, "/turned": 1, "/mirrored": 2}
    for s in by.values():
        assert np.linalg.det(s.frame) > 0


@needs_engine
def test_engine_axes(tmp_path):
    t = L.sample_table(L.ies_profile(read_ies(c90_profile_file(tmp_path))))
    eng = L.LuminaireSpec(name="c90", kind="test", source="test", points=[[0, 0, 0]], weights=[1.0], frame=np.eye(3),
                          candela=t, colour=[1, 1, 1]).to_engine()
    i = np.asarray(eng.intensity(np.array([[0, 1.0, 0], [0, -1.0, 0], [1.0, 0, 0]])))[:, 0]
    assert i[0] == pytest.approx(1000.0, rel=1e-3) and i[1] < 1e-3 * i[0] and i[2] < 1e-3 * i[0]


# ----------------------------------------------------------------------------- warnings


def test_unhonoured_light_attributes_are_named(tmp_path):
    attrs = ("float inputs:width = 1\n float inputs:height = 1\n float inputs:shaping:cone:angle = 45\n"
             " asset inputs:texture:file = @sky.exr@\n bool inputs:shadow:enable = 0")
    scene = hu.read_scene(write_scene(tmp_path, light("RectLight", attrs=attrs, schemas='"ShapingAPI", "ShadowAPI"')))
    (w,) = [w for w in scene.warnings if w.startswith("/lamp:")]
    assert "inputs:texture:file" in w and "inputs:shadow:enable" in w and "shaping" not in w
    assert len(scene.luminaires) == 1


def test_a_scene_lit_only_by_luminaires_is_accepted_for_a_bake(tmp_path):
    body = light("CylinderLight", attrs="float inputs:length = 1\n float inputs:radius = 0.05")
    scene = hu.read_scene(write_scene(tmp_path, body), require_emission=True)
    assert len(scene.luminaires) == 1 and not np.any(scene.face_emission > 0)


# ----------------------------------------------------------------------------- schedule


def test_schedule_counts_identical_luminaires(tmp_path):
    a = "float inputs:radius = 0.05\n float inputs:intensity = 3000"
    body = (light("SphereLight", "a1", a) + light("SphereLight", "a2", a, xform="double3 xformOp:translate = (1, 0, 2)")
            + light("SphereLight", "b", "float inputs:radius = 0.05\n float inputs:intensity = 100"))
    rows = L.schedule(hu.read_scene(write_scene(tmp_path, body)).luminaires)
    assert [r["count"] for r in rows] == [2, 1]
    assert rows[0]["name"] == "/a1, /a2" and rows[0]["ies"] is None
    r = float(np.float32(0.05))
    assert rows[0]["lumens"] == pytest.approx(4 * math.pi ** 2 * r * r * 3000, rel=1e-9)
    assert set(rows[0]) >= {"type", "count", "lumens", "ies", "name"}


# ----------------------------------------------------------------------------- config lights


def write_config(tmp_path, lights_yaml: str) -> Path:
    write_scene(tmp_path, "")
    path = tmp_path / "study.yaml"
    path.write_text("scene: scene.usda\nlights:\n" + textwrap.indent(textwrap.dedent(lights_yaml), "  "))
    return path


def test_config_point_lights(tmp_path):
    cos_n_file(tmp_path, 1, i0=1000.0, name="down.ies")
    cfg = load_config(write_config(tmp_path, """\
        - name: bulb
          position: [1, 2, 3]
          intensity: 100
        - name: lamp
          position: [0, 0, 2.5]
          flux: 1200
          colour: [1, 0.5, 0.5]
        - name: wallwash
          position: [0, 0, 2]
          ies: down.ies
          intensity: 0.5
          aim: [1, 0, 0]
        - name: tilted
          position: [0, 0, 2]
          ies: down.ies
          ies_mode: usdlux
          intensity: 10
          rotation: [90, 0, 0]
        """))
    specs = L.luminaires_from_config(cfg.lights, up_axis="Z", ies_mode=cfg.photometry.ies_mode)
    by = {s.name: s for s in specs}
    assert by["bulb"].flux[0] == pytest.approx(4 * math.pi * 100, rel=1e-12)
    np.testing.assert_allclose(by["bulb"].points, [[1, 2, 3]])
    assert by["lamp"].lumens == pytest.approx(1200.0, rel=1e-12)
    assert by["wallwash"].ies_mode == "absolute" and by["wallwash"].source == "lights[2]"
    assert by["wallwash"].flux[0] == pytest.approx(0.5 * math.pi * 1000, rel=1e-4)
    i = by["wallwash"].intensity(np.array([[1.0, 0, 0], [0, 0, -1.0]]))[:, 0]
    assert i[0] == pytest.approx(500.0, rel=1e-3) and i[1] < 2e-3 * i[0]  # aimed along +X (gamma 90: the node average)
    # usdlux: the profile keeps the isotropic light's flux; rotateXYZ (90, 0, 0) turns -Z to +Y
    assert by["tilted"].flux[0] == pytest.approx(4 * math.pi * 10, rel=1e-9)
    i = by["tilted"].intensity(np.array([[0, 1.0, 0], [0, 0, -1.0]]))[:, 0]
    assert i[0] > 100 * max(i[1], 1e-12)


def test_config_light_default_aim_follows_the_up_axis(tmp_path):
    cos_n_file(tmp_path, 1, name="down.ies")
    cfg = load_config(write_config(tmp_path, "- {name: d, position: [0, 3, 0], ies: down.ies}\n"))
    (spec,) = L.luminaires_from_config(cfg.lights, up_axis="Y")
    i = spec.intensity(np.array([[0, -1.0, 0], [0, 0, -1.0]]))[:, 0]
    assert i[0] == pytest.approx(1000.0, rel=1e-3) and i[1] < 2e-3 * i[0]


@pytest.mark.parametrize("yaml_text, line, key, words", [
    ("- {name: a, position: [0, 0, 1], intensity: 1, flux: 2}\n", 3, "lights[0]", "not both"),
    ("- {name: a, position: [0, 0, 1]}\n", 3, "lights[0]", "needs `intensity`"),
    ("- {name: a, position: [0, 0], intensity: 1}\n", 3, "lights[0].position[2]", "too few values"),
    ("- {name: a, position: [0, 0, 1], intensity: -1}\n", 3, "lights[0].intensity", "greater than or equal"),
    ("- name: a\n  position: [0, 0, 1]\n  ies: missing.ies\n", 5, "lights[0].ies", "IES file not found"),
    ("- {name: a, position: [0, 0, 1], intensity: 1}\n- {name: a, position: [0, 0, 2], intensity: 1}\n", 2,
     "lights", "given twice"),
    ("- {name: a, position: [0, 0, 1], ies: down.ies, aim: [0, 0, -1], rotation: [0, 0, 0]}\n", 3, "lights[0]",
     "not both"),
])
def test_config_light_errors_are_located(tmp_path, yaml_text, line, key, words):
    cos_n_file(tmp_path, 1, name="down.ies")
    with pytest.raises(ConfigError) as info:
        load_config(write_config(tmp_path, yaml_text))
    err = info.value
    assert (err.line, err.key) == (line, key), str(err)
    assert words in err.problem


def test_config_light_bad_ies_file_names_file_and_line(tmp_path):
    (tmp_path / "bad.ies").write_text(ies_text([0, 90], [0], [[10], [0]]).replace("0 90", "0 ninety"))
    with pytest.raises(ConfigError) as info:
        load_config(write_config(tmp_path, "- {name: a, position: [0, 0, 1], ies: bad.ies}\n"))
    assert info.value.key == "lights[0].ies" and "bad.ies: line 6" in info.value.problem


def test_photometric_power_on_a_mesh_light(tmp_path):
    mesh = FLOOR.replace('"floor"', '"panel" (prepend apiSchemas = ["MeshLightAPI"])').replace(
        "int[] faceVertexIndices = [0, 1, 2, 3]", "int[] faceVertexIndices = [0, 1, 2, 3]\n"
        "    float inputs:intensity = 5\n    float photometric:power = 2500")
    scene = hu.read_scene(write_scene(tmp_path, mesh))
    k = [i for i, m in enumerate(scene.meshes) if m.path == "/panel"][0]
    assert float(scene.face_emission[scene.face_mesh == k][0] @ Y) * 100.0 == pytest.approx(2500.0, rel=1e-9)


def test_with_config_lights_appends_them_to_the_scene_lights(tmp_path):
    cfg_path = write_config(tmp_path, "- {name: bulb, position: [0, 0, 2], flux: 100}\n")
    scene_path = write_scene(tmp_path, light("SphereLight", attrs="float inputs:radius = 0.1"))
    cfg = load_config(cfg_path)
    specs = L.with_config_lights(hu.read_scene(scene_path, ies_mode=cfg.photometry.ies_mode), cfg)
    assert [s.source for s in specs] == ["/lamp", "lights[0]"]
    assert specs[1].lumens == pytest.approx(100.0, rel=1e-12)


@needs_engine
def test_every_kind_of_usd_luminaire_goes_to_the_engine(tmp_path):
    c90_profile_file(tmp_path)
    body = (light("SphereLight", "s", "float inputs:radius = 0.1")
            + light("CylinderLight", "c", "float inputs:length = 1\n float inputs:radius = 0.02")
            + light("RectLight", "r", "float inputs:shaping:cone:angle = 20", '"ShapingAPI"')
            + light("DiskLight", "d", "float inputs:shaping:focus = 1\n color3f inputs:shaping:focusTint = (0, 1, 0)",
                    '"ShapingAPI"')
            + light("SphereLight", "m", "asset inputs:shaping:ies:file = @c90.ies@", '"ShapingAPI"',
                    "double3 xformOp:translate = (0, 0, 2)\n    float3 xformOp:scale = (-1, 1, 1)",
                    '"xformOp:translate", "xformOp:scale"'))
    specs = hu.read_scene(write_scene(tmp_path, body)).luminaires
    assert len(specs) == 6
    d = np.random.default_rng(2).normal(size=(64, 3))
    for s in specs:
        eng = s.to_engine()
        np.testing.assert_allclose(np.asarray(eng.flux).reshape(3), s.flux, rtol=1e-10)
        np.testing.assert_allclose(np.asarray(eng.intensity(d)), s.intensity(d), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("scale, lo, hi", [(0.0, 0, 90), (0.7, 0, 63), (1.3, 0, 117), (-0.6, 72, 126)])
def test_angle_scale_moves_the_edge_of_a_hemisphere_file(tmp_path, scale, lo, hi):
    """A flat 100 cd file measured over 0-90 degrees: under angleScale a the light is between
    the mapped ends of that range, flux 200 pi (cos lo - cos hi), the edge a jump the table keeps."""
    v = np.arange(0.0, 90.1, 2.5)
    (tmp_path / "flat.ies").write_text(ies_text(v, [0.0], np.full((len(v), 1), 100.0)))
    t = L.sample_table(L.ies_profile(read_ies(tmp_path / "flat.ies"), scale))
    ref = 200 * math.pi * (math.cos(math.radians(lo)) - math.cos(math.radians(hi)))
    assert L.table_flux(t) == pytest.approx(ref, rel=1e-9)
