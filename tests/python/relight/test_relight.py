"""Light groups and relighting (issue 15): each group solved alone on the shared links, the
total their sum, `hirad relight` exact and without a solve."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from scene import GROUPS, config, room  # noqa: E402

import hirad  # noqa: E402
from hirad import relight as R  # noqa: E402
from hirad.config import ConfigError  # noqa: E402

TOL = 1e-6  # the configs' solver tolerance

FLOOR_GRID = {"floor": {"kind": "rectangle", "corner": [0.1, 0.05, 0.1], "edge_u": [0.8, 0, 0],
                        "edge_v": [0, 0, 0.8], "normal": [0, 1, 0]}}


def _primvars(layer: Path) -> dict:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(layer))
    root = stage.GetPrimAtPath(stage.GetRootLayer().customLayerData["hirad:solutionRoot"])
    out = {}
    for prim in root.GetChildren():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
            name = pv.GetPrimvarName()
            if name.startswith("hirad:"):
                out[(prim.GetName(), name)] = np.array(pv.Get(), dtype=np.float64).reshape(-1, 3) \
                    if name != "hirad:lightmapUV" else np.array(pv.Get(), dtype=np.float64)
    return out


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hirad.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    d = tmp_path_factory.mktemp("relight")
    scene = room(d / "room.usda")
    grouped = hirad.bake(str(config(d / "groups.yaml", scene, d / "grouped", GROUPS, grids=FLOOR_GRID)))
    plain = hirad.bake(str(config(d / "plain.yaml", scene, d / "plain", None, grids=FLOOR_GRID)))
    return d, scene, grouped, plain


@pytest.mark.parametrize("method", ["hierarchical", "flat"])
def test_total_is_the_sum_of_the_groups_and_a_bake_without_groups(tmp_path, method):
    scene = room(tmp_path / "room.usda")
    g = hirad.bake(str(config(tmp_path / "g.yaml", scene, tmp_path / "g", GROUPS, method=method)))
    p = hirad.bake(str(config(tmp_path / "p.yaml", scene, tmp_path / "p", None, method=method)))
    assert list(g.report["light_groups"]) == ["desk", "sky", "rest"]
    assert g.report["light_groups"]["rest"]["members"] == ["/World/Lamps/Bulb"]
    assert g.report["light_groups"]["sky"]["members"] == ["/World/Lights/Sky"]
    pv = _primvars(tmp_path / "g" / "solution.usda")
    for (mesh, name), total in pv.items():
        if name not in ("hirad:radiance", "hirad:irradiance"):
            continue
        kind = name.split(":")[1]
        parts = [pv[(mesh, f"hirad:group:{k}:{kind}")] for k in ("desk", "sky", "rest")]
        assert np.abs(sum(parts) - total).max() <= 1e-6 * max(1.0, np.abs(total).max()), (mesh, name)
    # the same patches as a bake without groups (same links), the same values within the tolerance
    # (per patch: the vertex values of the total are the groups' sum, and the reconstruction
    # clamps extrapolated boundary vertices, so those may differ)
    b_g, b_p = np.asarray(g.patch_radiosity), np.asarray(p.patch_radiosity)
    assert b_g.shape == b_p.shape
    assert np.abs(b_g - b_p).max() <= 20 * TOL * np.abs(b_p).max()
    h_g, h_p = np.asarray(g.patch_irradiance), np.asarray(p.patch_irradiance)
    assert np.abs(h_g - h_p).max() <= 20 * TOL * np.abs(h_p).max()
    # every group lit something
    for k in ("desk", "sky", "rest"):
        assert max(pv[(m, n)].max() for (m, n) in pv if n == f"hirad:group:{k}:irradiance") > 0


def test_dimming_a_group_is_exact(baked, tmp_path):
    d, _, _, _ = baked
    r = _cli("relight", d / "grouped", "--set", "lights.groups.desk.dimmer=0.3", "-o", tmp_path / "dim")
    assert r.returncode == 0, r.stderr
    before = _primvars(d / "grouped" / "solution.usda")
    after = _primvars(tmp_path / "dim" / "solution.usda")
    checked = 0
    for (mesh, name), total in before.items():
        if name not in ("hirad:radiance", "hirad:irradiance"):
            continue
        kind = name.split(":")[1]
        desk = before[(mesh, f"hirad:group:desk:{kind}")]
        want = total - 0.7 * desk
        got = after[(mesh, name)]
        # float32 primvars: exact to their rounding
        assert np.abs(got - want).max() <= 4e-7 * max(1.0, np.abs(total).max()), (mesh, name)
        checked += 1
    assert checked >= 8
    # the desk really was dimmed somewhere (the test can fail)
    assert any(np.abs(after[k] - before[k]).max() > 1e-3 * np.abs(before[k]).max()
               for k in before if k[1] == "hirad:irradiance")
    report = json.loads((tmp_path / "dim" / "report.json").read_text())
    assert report["solves"] == 0 and report["groups"]["desk"]["dimmer"] == 0.3
    assert (tmp_path / "dim" / ".hirad-output").is_file()


def _grid(out: Path) -> np.ndarray:
    return np.array(json.loads((out / "grids" / "floor.json").read_text())["values_lx"], dtype=np.float64)


SETS = ("--set", "lights.groups.desk.dimmer=0.3", "--set", "lights.groups.sky.color=[1,0.9,0.8]")
RELIT_GROUPS = {"desk": {**GROUPS["desk"], "dimmer": 0.3}, "sky": {**GROUPS["sky"], "color": [1, 0.9, 0.8]}}


def test_relit_grids_equal_a_fresh_bake_with_that_dimmer(baked, tmp_path):
    d, scene, _, _ = baked
    r = _cli("relight", d / "grouped", *SETS, "-o", tmp_path / "relit")
    assert r.returncode == 0, r.stderr
    fresh = hirad.bake(str(config(tmp_path / "f.yaml", scene, tmp_path / "fresh", RELIT_GROUPS, grids=FLOOR_GRID)))
    a, b = _grid(tmp_path / "relit"), _grid(tmp_path / "fresh")
    assert a.shape == b.shape and len(a) > 4
    # the same links (refinement saw every light at full power both times), the same rays
    assert np.abs(a - b).max() <= 1e-9 * np.abs(b).max()
    base = _grid(d / "grouped")
    assert np.abs(a - base).max() > 1e-2 * np.abs(base).max()  # relighting changed the grid
    assert fresh.report["light_groups"]["desk"]["dimmer"] == 0.3
    for name in ("report.html", "floor.csv", "floor.png"):
        assert (tmp_path / "relit" / "grids" / name).is_file()


def test_relit_grids_equal_the_physically_dimmed_scene(tmp_path):
    """Flat: the links do not depend on the emission, so relighting equals baking the scene
    with the panel really dimmed and the sky really tinted, within the solver tolerance."""
    scene = room(tmp_path / "room.usda")
    hirad.bake(str(config(tmp_path / "g.yaml", scene, tmp_path / "g", GROUPS, method="flat", grids=FLOOR_GRID)))
    r = _cli("relight", tmp_path / "g", *SETS, "-o", tmp_path / "relit")
    assert r.returncode == 0, r.stderr
    scene2 = room(tmp_path / "room2.usda", desk=0.9, sky=(1.0, 1.5 * 0.9, 2.0 * 0.8))
    hirad.bake(str(config(tmp_path / "q.yaml", scene2, tmp_path / "q", None, method="flat", grids=FLOOR_GRID)))
    a, c = _grid(tmp_path / "relit"), _grid(tmp_path / "q")
    assert np.abs(a - c).max() <= 20 * TOL * np.abs(c).max()
    assert np.abs(a - _grid(tmp_path / "g")).max() > 1e-2 * np.abs(c).max()


def test_a_pattern_matching_nothing_is_named(tmp_path):
    scene = room(tmp_path / "room.usda")
    groups = {"desk": {"paths": ["/World/Lights/Desk", "/World/Nowhere/*"]}, "each": {"each": True}}
    r = hirad.bake(str(config(tmp_path / "c.yaml", scene, tmp_path / "o", groups)))
    named = [w for w in r.report["warnings"] if "/World/Nowhere/*" in w]
    assert named and "lights.groups.desk" in named[0] and "matches no light" in named[0]
    # each: the remaining lights one group each, no rest
    assert sorted(r.report["light_groups"]) == ["desk", "each_Bulb", "each_Sky"]


def test_a_bad_group_definition_is_a_located_config_error(tmp_path):
    scene = room(tmp_path / "room.usda")
    path = config(tmp_path / "c.yaml", scene, tmp_path / "o", {"desk": {"paths": ["/x"], "dimmer": -1}})
    with pytest.raises(ConfigError) as e:
        hirad.bake(str(path))
    assert e.value.key == "lights.groups.desk.dimmer" and e.value.line > 0
    assert not (tmp_path / "o").exists()
    # a group name that cannot name primvars, and `rest`
    for bad, words in (("a.b", "letters, digits"), ("rest", "reserved")):
        path = config(tmp_path / "c.yaml", scene, tmp_path / "o", {bad: {"paths": ["/x"]}})
        with pytest.raises(ConfigError) as e:
            hirad.bake(str(path))
        assert words in str(e.value)
    # the point lights of a `lights:` mapping keep their located errors
    path = tmp_path / "p.yaml"
    path.write_text(f"scene: {scene}\nlights:\n  points:\n    - {{name: a, position: [0, 0, 1], intensity: -1}}\n"
                    "  groups: {desk: {paths: ['/World/Lights/Desk']}}\n")
    with pytest.raises(ConfigError) as e:
        hirad.bake(str(path))
    assert e.value.key == "lights.points[0].intensity" and e.value.line == 4


def test_unknown_group_in_set_is_a_located_error(baked, tmp_path):
    d, _, _, _ = baked
    r = _cli("relight", d / "grouped", "--set", "lights.groups.lamp.dimmer=0.5", "-o", tmp_path / "x")
    assert r.returncode == 2
    assert "--set lights.groups.lamp.dimmer=0.5" in r.stderr and "unknown light group 'lamp'" in r.stderr
    assert "desk, sky, rest" in r.stderr
    assert not (tmp_path / "x").exists()
    r = _cli("relight", d / "grouped", "--set", "lights.groups.desk.dimmer=-2", "-o", tmp_path / "x")
    assert r.returncode == 2 and "dimmer must be a number >= 0" in r.stderr and not (tmp_path / "x").exists()


def test_relight_refuses_what_is_not_a_hirad_output(baked, tmp_path):
    d, _, _, _ = baked
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "solution.usda").write_text("#usda 1.0\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    r = _cli("relight", foreign, "--set", "lights.groups.desk.dimmer=0.5")
    assert r.returncode == 2 and "not a hirad output" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written
    # a hirad output without groups
    r = _cli("relight", d / "plain", "-o", tmp_path / "y")
    assert r.returncode == 2 and "without light groups" in r.stderr and not (tmp_path / "y").exists()
    # an output hirad did not make is never overwritten
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    r = _cli("relight", d / "grouped", "-o", mine)
    assert r.returncode == 2 and (mine / "notes.txt").read_text() == "keep"
    # nor the bake's own output
    r = _cli("relight", d / "grouped", "-o", d / "grouped")
    assert r.returncode == 2


def test_relight_twice_replaces_its_own_output(baked, tmp_path):
    d, _, _, _ = baked
    for dimmer in (0.5, 0.25):
        r = _cli("relight", d / "grouped", "--set", f"lights.groups.sky.dimmer={dimmer}", "-o", tmp_path / "r")
        assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "r" / "report.json").read_text())["groups"]["sky"]["dimmer"] == 0.25
    # a relit output relights again: dimmers are absolute, so sky back to 1 is the bake's values
    r = _cli("relight", tmp_path / "r", "--set", "lights.groups.sky.dimmer=1", "-o", tmp_path / "back")
    assert r.returncode == 0, r.stderr
    a, b = _primvars(d / "grouped" / "solution.usda"), _primvars(tmp_path / "back" / "solution.usda")
    for key, v in a.items():
        if key[1] in ("hirad:radiance", "hirad:irradiance"):
            assert np.abs(b[key] - v).max() <= 4e-7 * max(1.0, np.abs(v).max()), key


def test_relit_lightmaps_are_the_weighted_group_pages(tmp_path):
    from hirad import _engine

    scene = room(tmp_path / "room.usda", with_bulb=True)
    path = config(tmp_path / "c.yaml", scene, tmp_path / "o", GROUPS,
                  outputs={"lightmaps": {"enabled": True, "texels_per_metre": 24, "mode": "final_gather",
                                         "directional": True, "encodings": ["unity-rgbm"]}})
    hirad.bake(str(path))
    r = _cli("relight", tmp_path / "o", "--set", "lights.groups.rest.dimmer=0", "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    # the bake's directional maps and 8-bit copies are not relit: the relit manifest names none
    baked = json.loads((tmp_path / "o" / "lightmaps" / "manifest.json").read_text())
    assert "unityDirection" in baked["pages"][0] and "encoded" in baked["pages"][0]
    relit_manifest = json.loads((tmp_path / "r" / "lightmaps" / "manifest.json").read_text())
    for page in relit_manifest["pages"]:
        assert set(page) & {"encoded", "godotL1", "bakerySH", "unityDirection"} == set()
        assert (tmp_path / "r" / "lightmaps" / page["file"]).is_file()
    total = np.asarray(_engine.read_exr(str(tmp_path / "o" / "lightmaps" / "pages" / "page0.exr")), dtype=np.float64)
    relit = np.asarray(_engine.read_exr(str(tmp_path / "r" / "lightmaps" / "pages" / "page0.exr")), dtype=np.float64)
    rest = np.asarray(_engine.read_exr(str(tmp_path / "o" / "groups" / "rest" / "lightmaps" / "pages" / "page0.exr")),
                      dtype=np.float64)
    assert rest.max() > 0
    # half-float pages: equal to their rounding (2^-10 relative, a few roundings)
    assert np.abs(relit - (total - rest)).max() <= 4e-3 * total.max()
    assert np.abs(relit - total).max() > 1e-2 * total.max()


def test_out_of_core_groups_sum_to_the_total_and_relight(tmp_path):
    """block_southwell: each group streamed again over the store's final links."""
    scene = room(tmp_path / "room.usda")
    extra = {"solver": {"method": "block_southwell", "tolerance": 1e-6}}
    g = hirad.bake(str(config(tmp_path / "g.yaml", scene, tmp_path / "g", GROUPS, **extra)))
    p = hirad.bake(str(config(tmp_path / "p.yaml", scene, tmp_path / "p", None, **extra)))
    b_g, b_p = np.asarray(g.patch_radiosity), np.asarray(p.patch_radiosity)
    assert b_g.shape == b_p.shape and np.abs(b_g - b_p).max() <= 50 * TOL * np.abs(b_p).max()
    r = _cli("relight", tmp_path / "g", "--set", "lights.groups.sky.dimmer=0.3", "-o", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    before, after = _primvars(tmp_path / "g" / "solution.usda"), _primvars(tmp_path / "r" / "solution.usda")
    for (mesh, name), total in before.items():
        if name == "hirad:irradiance":
            want = total - 0.7 * before[(mesh, "hirad:group:sky:irradiance")]
            assert np.abs(after[(mesh, name)] - want).max() <= 4e-7 * max(1.0, np.abs(total).max())


@pytest.mark.parametrize("method", ["hierarchical", "flat"])
def test_group_solutions_do_not_depend_on_the_thread_count(tmp_path, method):
    scene = room(tmp_path / "room.usda")
    path = config(tmp_path / "g.yaml", scene, tmp_path / "g", GROUPS, method=method)
    one = hirad.bake(str(path), threads=1)
    vals1 = np.load(tmp_path / "g" / R.VALUES_FILE)
    a = {k: vals1[k].copy() for k in vals1.files}
    many = hirad.bake(str(path), threads=4)
    vals4 = np.load(tmp_path / "g" / R.VALUES_FILE)
    assert sorted(a) == sorted(vals4.files)
    for k in a:
        assert np.array_equal(a[k], vals4[k]), k
    assert np.array_equal(np.asarray(one.patch_radiosity), np.asarray(many.patch_radiosity))


def test_set_parsing():
    assert R.parse_sets(["lights.groups.desk.dimmer=0.3", "lights.groups.sky.color=[1, 0.9, 0.8]"],
                        ["desk", "sky"]) == {"desk": {"dimmer": 0.3}, "sky": {"color": (1.0, 0.9, 0.8)}}
    for bad, words in (("lights.groups.desk.dimmer=abc", "dimmer must be"), ("lights.groups.desk.color=[1,2]", "color"),
                       ("lights.groups.desk.intensity=2", "not a relight key"), ("threads=2", "not a relight key"),
                       ("lights.groups.Desk.dimmer=1", "did you mean 'desk'")):
        with pytest.raises(R.RelightError) as e:
            R.parse_sets([bad], ["desk", "sky"])
        assert words in str(e.value) and bad in str(e.value)
