"""`hirad bake CONFIG --set KEY=VALUE` (validated by the schema, errors naming the --set
argument) and the content key (what determines a bake's result, not where it goes)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

from hirad_e2e_helpers import COARSE, CORNELL, run_cli, write_config

from hirad.config import ConfigError, load_config

PREVIEW = {"camera": "/World/Camera", "width": 32, "height": 32, "samples": 1}


def cfg_file(tmp_path: Path, scene: Path = CORNELL, **sections) -> Path:
    sections.setdefault("meshing", COARSE)
    sections.setdefault("outputs", {"preview": PREVIEW})
    return write_config(tmp_path / "c.yaml", scene, tmp_path / "out", **sections)


# ---------------------------------------------------------------------------------------------
# --set through the loader
# ---------------------------------------------------------------------------------------------


def test_set_overrides_dotted_keys_with_yaml_values(tmp_path):
    c = cfg_file(tmp_path)
    cfg = load_config(c, ["meshing.max_patch_area=2e-2", "materials.default_reflectance=[0.1, 0.2, 0.3]",
                          "outputs.preview.enabled=false", "seed=7", "solver.method=jacobi"])
    assert cfg.meshing.max_patch_area == 0.02
    assert cfg.meshing.max_edge_length == COARSE["max_edge_length"]  # the file's sibling key stays
    assert tuple(cfg.materials.default_reflectance) == (0.1, 0.2, 0.3)
    assert cfg.outputs.preview.enabled is False and cfg.seed == 7 and cfg.solver.method == "jacobi"


def test_set_later_wins_and_makes_missing_sections(tmp_path):
    c = cfg_file(tmp_path)
    cfg = load_config(c, ["hierarchy.epsilon=1e-3", "hierarchy.epsilon=1e-2"])
    assert cfg.hierarchy.epsilon == 0.01
    assert load_config(c).hierarchy.epsilon != 0.01


def test_set_list_index(tmp_path):
    c = cfg_file(tmp_path, lights=[{"name": "a", "position": [0.0, 1.0, 0.0], "intensity": 1.0}])
    cfg = load_config(c, ["lights[0].intensity=5", "lights[0].position=[0.1, 1.0, 0.2]"])
    assert cfg.lights[0].intensity == 5.0 and tuple(cfg.lights[0].position) == (0.1, 1.0, 0.2)
    with pytest.raises(ConfigError) as e:
        load_config(c, ["lights[3].intensity=5"])
    assert e.value.file == "--set lights[3].intensity=5" and "1 entries" in e.value.problem


@pytest.mark.parametrize("arg, key, words", [
    ("meshing.max_patch_area=-1", "meshing.max_patch_area", "greater than 0"),
    ("meshing.max_patch_aera=0.02", "meshing.max_patch_aera", "did you mean 'max_patch_area'"),
    ("meshing.max_patch_area='0.02'", "meshing.max_patch_area", "remove the quotes"),
    ("nosuch=1", "nosuch", "unknown key"),
    ("meshing=[1", "meshing", "malformed YAML value"),
    ("meshing.max_patch_area.x=1", "meshing.max_patch_area.x", "is not a mapping"),
    ("solver.method=lu", "solver.method", "Input should be"),
])
def test_set_errors_name_the_argument(tmp_path, arg, key, words):
    c = cfg_file(tmp_path)
    with pytest.raises(ConfigError) as e:
        load_config(c, [arg])
    assert e.value.file == f"--set {arg}", e.value
    assert e.value.line == 0 and e.value.key == key
    assert words in e.value.problem, e.value.problem
    assert str(e.value).startswith(f"--set {arg}: {key}: ")


@pytest.mark.parametrize("arg", ["novalue", "=3", "a..b=1", "[0]=1"])
def test_set_malformed_arguments(tmp_path, arg):
    with pytest.raises(ConfigError) as e:
        load_config(cfg_file(tmp_path), [arg])
    assert e.value.file == f"--set {arg}"


def test_file_errors_keep_their_line_beside_a_set(tmp_path):
    c = cfg_file(tmp_path)
    text = c.read_text().replace("max_edge_length: 0.1", "max_edge_length: -0.1")
    c.write_text(text)
    line = next(i for i, l in enumerate(text.splitlines(), 1) if "max_edge_length" in l)
    with pytest.raises(ConfigError) as e:
        load_config(c, ["meshing.max_patch_area=0.02"])
    assert (e.value.file, e.value.line, e.value.key) == (str(c), line, "meshing.max_edge_length")
    # the --set fixes it
    assert load_config(c, ["meshing.max_edge_length=0.2"]).meshing.max_edge_length == 0.2


def test_cli_set_bakes_with_the_override_and_errors_exit_2(tmp_path):
    c = cfg_file(tmp_path)
    bad = run_cli("bake", c, "--set", "meshing.max_patch_area=-1", "--quiet")
    assert bad.returncode == 2
    assert bad.stderr.strip().startswith("hirad: error: --set meshing.max_patch_area=-1: meshing.max_patch_area:")
    assert not (tmp_path / "out").exists()
    ok = run_cli("bake", c, "--set", "meshing={max_patch_area: 0.04, max_edge_length: 0.2}", "--set", "outputs.preview.enabled=false",
                 "--json")
    assert ok.returncode == 0, ok.stderr
    rep = json.loads(ok.stdout)
    assert rep["overrides"] == ["meshing={max_patch_area: 0.04, max_edge_length: 0.2}", "outputs.preview.enabled=false"]
    assert not (tmp_path / "out" / "preview.png").exists()
    plain = json.loads((tmp_path / "out" / "report.json").read_text())
    assert plain["counts"]["patches"] < json.loads(run_cli("bake", c, "--json").stdout)["counts"]["patches"]


# ---------------------------------------------------------------------------------------------
# the content key
# ---------------------------------------------------------------------------------------------


def test_content_key_ignores_output_threads_and_store(tmp_path):
    c = cfg_file(tmp_path)
    k = load_config(c).content_key()
    assert load_config(c, ["output=elsewhere", "threads=3", "links.memory_budget=64MB",
                           "links.store=st"]).content_key() == k
    # while the fingerprint changes with the output and the threads
    assert load_config(c, ["threads=3"]).fingerprint() != load_config(c).fingerprint()
    for arg in ("seed=2", "meshing.max_patch_area=0.02", "outputs.preview.width=40", "solver.tolerance=1e-3"):
        assert load_config(c, [arg]).content_key() != k, arg


def test_content_key_follows_scene_contents_and_sublayers(tmp_path):
    scenes = tmp_path / "s"
    scenes.mkdir()
    sub = scenes / "box.usda"
    shutil.copy(CORNELL, sub)
    top = scenes / "top.usda"
    top.write_text('#usda 1.0\n(\n    subLayers = [@./box.usda@]\n)\n')
    c = cfg_file(tmp_path, scene=top)
    k = load_config(c).content_key()
    # the same files elsewhere: the same key
    moved = tmp_path / "m"
    shutil.copytree(scenes, moved)
    c2 = write_config(tmp_path / "c2.yaml", moved / "top.usda", tmp_path / "o2",
                      **{k2: v for k2, v in yaml.safe_load(c.read_text()).items() if k2 not in ("scene", "output")})
    assert load_config(c2).content_key() == k
    # a change in the sublayer (not the file named as the scene) changes it
    sub.write_text(sub.read_text() + "\n# edited\n")
    assert load_config(c).content_key() != k


def test_report_carries_content_key(tmp_path):
    c = cfg_file(tmp_path, outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}})
    a = run_cli("bake", c, "--json", "--set", "threads=1")
    b = run_cli("bake", c, "--json", "--set", "threads=2", "--set", f"output={tmp_path / 'other'}")
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    ra, rb = json.loads(a.stdout), json.loads(b.stdout)
    assert ra["content_key"] == rb["content_key"] == load_config(c).content_key()
    assert ra["config_fingerprint"] != rb["config_fingerprint"]
