"""Bounds on reading a config and on the values it may hold: a config is a small regular
file, its YAML aliases cannot blow up, the values fit what the engine takes, and every key
of the schema is documented.  Each error is located: ``file:line: key: problem``."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hirad.config import ConfigError, config_from_dict, load_config, schema_text
from hirad.config import describe
from hirad.config.loader import MAX_CONFIG_BYTES, MAX_YAML_NODES

REPO = Path(__file__).resolve().parents[3]


def write(directory: Path, text: str, name: str = "bake.yaml") -> Path:
    (directory / "scene.usda").write_text("#usda 1.0\n")
    path = directory / name
    path.write_text(textwrap.dedent(text).lstrip("\n"))
    return path


def load_error(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return info.value


# --------------------------------------------------------------------------------------------
# what is read: regular files of bounded size
# --------------------------------------------------------------------------------------------


def _load_in_child(path: Path, timeout: float = 20) -> subprocess.CompletedProcess:
    """load_config in a fresh interpreter, so a read that blocks or never ends fails the test
    by its timeout instead of hanging the suite."""
    code = ("import sys\nfrom hirad.config import ConfigError, load_config\n"
            "try:\n    load_config(sys.argv[1])\nexcept ConfigError as e:\n    print(e)\n    sys.exit(3)\n")
    return subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO)


def test_fifo_is_refused_without_waiting(tmp_path):
    fifo = tmp_path / "bake.yaml"
    os.mkfifo(fifo)
    start = time.perf_counter()
    run = _load_in_child(fifo)  # a writer never comes: opening it for reading would block forever
    assert run.returncode == 3, run.stderr
    assert run.stdout.strip() == f"{fifo}: config path is a FIFO (named pipe), not a regular file"
    assert time.perf_counter() - start < 20


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_dev_zero_is_refused(tmp_path):
    link = tmp_path / "bake.yaml"
    link.symlink_to("/dev/zero")  # a config that is (a link to) an endless device
    for path in (Path("/dev/zero"), link):
        run = _load_in_child(path)
        assert run.returncode == 3, run.stderr
        assert run.stdout.strip() == f"{path}: config path is a character device, not a regular file"


def test_directory_is_refused(tmp_path):
    err = load_error(tmp_path)
    assert str(err) == f"{tmp_path}: config path is a directory, not a file"


def test_config_larger_than_the_cap_is_refused_unread(tmp_path):
    path = write(tmp_path, "scene: scene.usda\n")
    with open(path, "a") as f:
        f.write("#" * MAX_CONFIG_BYTES + "\n")  # valid YAML: one long comment
    err = load_error(path)
    assert err.line == 0 and "larger than 1 MiB" in str(err) and str(err).startswith(str(path))


def test_config_just_under_the_cap_is_read(tmp_path):
    path = write(tmp_path, "scene: scene.usda\nseed: 5\n")
    pad = MAX_CONFIG_BYTES - path.stat().st_size
    with open(path, "a") as f:
        f.write("#" * (pad - 1) + "\n")
    assert path.stat().st_size == MAX_CONFIG_BYTES
    assert load_config(path).seed == 5


def test_not_utf8_is_an_error(tmp_path):
    path = tmp_path / "bake.yaml"
    path.write_bytes(b"scene: sc\xff\xfe.usda\n")
    err = load_error(path)
    assert "not UTF-8" in str(err)


# --------------------------------------------------------------------------------------------
# YAML aliases: nested expansion ("billion laughs") and recursion
# --------------------------------------------------------------------------------------------


def _laughs(levels: int, width: int) -> str:
    lines = ["scene: scene.usda", "materials:", "  uv_primvars: &a0 [" + ", ".join(["lol"] * width) + "]"]
    for i in range(1, levels + 1):
        lines.append(f"x{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def test_nine_levels_of_aliases_are_refused_at_once(tmp_path):
    # 9 levels of 9 aliases: 9^10 = 3.5e9 values if expanded. Walked node by node, each
    # alias re-visited, this took minutes; it must be refused in well under 2 s.
    path = write(tmp_path, _laughs(9, 9))
    start = time.perf_counter()
    run = _load_in_child(path, timeout=30)
    elapsed = time.perf_counter() - start
    assert run.returncode == 3, run.stderr
    assert f"aliases expand this value to more than {MAX_YAML_NODES} values" in run.stdout
    # the first level whose expansion passes the bound of 10,000: 9^5 = 59049 at x4 (line 7)
    assert MAX_YAML_NODES == 10_000
    assert run.stdout.startswith(f"{path}:7: ")
    start = time.perf_counter()
    load_error(path)
    assert time.perf_counter() - start < 2.0, f"took {time.perf_counter() - start:.1f} s (child: {elapsed:.1f} s)"


def test_aliases_within_the_bound_still_work(tmp_path):
    path = write(tmp_path, """
        scene: scene.usda
        outputs:
          preview: &p {enabled: false, width: 64, height: 32}
          lightmaps: {enabled: false}
        materials:
          uv_primvars: &uv [st, uv]
        """)
    cfg = load_config(path)
    assert cfg.materials.uv_primvars == ["st", "uv"]
    assert (cfg.outputs.preview.width, cfg.outputs.preview.height) == (64, 32)


def test_duplicate_key_inside_a_shared_alias_is_reported(tmp_path):
    # the memoised key check still finds problems inside an aliased mapping
    path = write(tmp_path, """
        scene: scene.usda
        base: &b {width: 64, width: 65}
        outputs:
          preview: *b
        """)
    err = load_error(path)
    assert err.line == 2 and "duplicate key" in str(err)


def test_recursive_alias_is_an_error_not_a_crash(tmp_path):
    path = write(tmp_path, "scene: scene.usda\nmaterials:\n  uv_primvars: &r [st, *r]\n")
    err = load_error(path)
    assert err.line == 3 and "recursive alias" in str(err)


def test_too_many_values_is_refused_while_composing(tmp_path):
    path = write(tmp_path, "scene: scene.usda\nmaterials:\n  uv_primvars: ["
                 + ", ".join(["a"] * (MAX_YAML_NODES + 10)) + "]\n")
    start = time.perf_counter()
    err = load_error(path)
    assert f"more than {MAX_YAML_NODES} values" in str(err) and err.line == 3
    assert time.perf_counter() - start < 5


def test_deep_nesting_is_an_error_not_a_crash(tmp_path):
    path = write(tmp_path, "scene: scene.usda\nx: " + "[" * 1500 + "]" * 1500 + "\n")
    err = load_error(path)
    assert "nested too deeply" in str(err)


# --------------------------------------------------------------------------------------------
# values the schema used to accept but the engine cannot take
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text, line, key, words", [
    ("links:\n  memory_budget: 99999999TB\n", 3, "links.memory_budget", "more than the largest memory size"),
    ("links:\n  memory_budget: " + "9" * 400 + "TB\n", 3, "links.memory_budget", "is not a memory size"),
    ("links:\n  memory_budget: 18446744073709551616\n", 3, "links.memory_budget", "more than the largest"),
    ("seed: 1180591620717411303424\n", 2, "seed", "less than or equal to 18446744073709551615"),
    ("seed: -1\n", 2, "seed", "greater than or equal to 0"),
    ("threads: 100000000000\n", 2, "threads", "less than or equal to 65536"),
    ("meshing:\n  max_patch_area: 1.0e-9\n", 3, "meshing.max_patch_area", "below the floor of 1e-08 m^2"),
    ("meshing:\n  max_edge_length: 1.0e-6\n", 3, "meshing.max_edge_length", "below the floor of 0.0001 m"),
    ("hierarchy:\n  min_area: 1.0e-12\n", 3, "hierarchy.min_area", "below the floor of 1e-08 m^2"),
    ("links:\n  group_faces: 4294967296\n", 3, "links.group_faces", "less than or equal to 4294967295"),
    ("solver:\n  max_iterations: 9223372036854775808\n", 3, "solver.max_iterations", "less than or equal"),
])
def test_values_beyond_what_the_engine_takes_are_located_errors(tmp_path, text, line, key, words):
    path = write(tmp_path, "scene: scene.usda\n" + text)
    err = load_error(path)
    assert (err.file, err.line, err.key) == (str(path), line, key)
    assert words in err.problem
    assert str(err).startswith(f"{path}:{line}: {key}: ")


@pytest.mark.parametrize("budget, expected", [("1PB", 1 << 50), ("1.5GB", 3 << 29), ("512MB", 512 << 20),
                                              (0, 0), (1 << 50, 1 << 50)])
def test_memory_budgets_up_to_the_bound_are_parsed(tmp_path, budget, expected):
    (tmp_path / "s.usda").write_text("#usda 1.0\n")
    cfg = config_from_dict({"scene": "s.usda", "links": {"memory_budget": budget}}, tmp_path)
    assert cfg.links.memory_budget == expected


def test_largest_seed_and_smallest_sizes_are_accepted(tmp_path):
    (tmp_path / "s.usda").write_text("#usda 1.0\n")
    cfg = config_from_dict({"scene": "s.usda", "seed": 2**64 - 1, "method": "flat",
                            "meshing": {"max_patch_area": 1e-8, "max_edge_length": 1e-4},
                            "hierarchy": {"min_area": 1e-8}}, tmp_path)
    assert cfg.seed == 2**64 - 1 and cfg.meshing.max_patch_area == 1e-8


# --------------------------------------------------------------------------------------------
# the default method, and settings a method does not read
# --------------------------------------------------------------------------------------------


def test_default_method_is_hierarchical(tmp_path):
    cfg = load_config(write(tmp_path, "scene: scene.usda\n"))
    assert cfg.method == "hierarchical"
    assert cfg.ignored_settings() == []


@pytest.mark.parametrize("name", ["cornell.yaml", "cornell_10k.yaml"])
def test_bundled_flat_configs_say_so(name):
    text = (REPO / "configs" / name).read_text()
    assert "\nmethod: flat\n" in text
    assert load_config(REPO / "configs" / name).method == "flat"


def test_flat_sections_under_the_default_method_are_named(tmp_path):
    cfg = load_config(write(tmp_path, "scene: scene.usda\nmeshing:\n  max_patch_area: 0.02\n"))
    ignored = cfg.ignored_settings()
    assert ignored == ["meshing: not used by method: hierarchical (the default); set method: flat to use it"]
    flat = load_config(write(tmp_path, "scene: scene.usda\nmethod: flat\nmeshing:\n  max_patch_area: 0.02\n"
                                       "hierarchy:\n  epsilon: 0.001\n"))
    assert flat.ignored_settings() == ["hierarchy: not used by method: flat"]


# --------------------------------------------------------------------------------------------
# every key documented
# --------------------------------------------------------------------------------------------


def test_every_key_has_a_description():
    keys = describe.keys()
    leaves = [k for k in keys if not k.section]
    assert len(leaves) >= 50  # the schema has 53 keys today; a walk that lost sections would show
    missing = [k.key for k in keys if not k.description.strip()]
    assert missing == []


def test_schema_text_names_every_key_with_type_default_and_unit():
    text = schema_text()
    lines = text.splitlines()
    for k in describe.keys():
        name = k.key.rsplit(".", 1)[-1]
        indent = "  " * k.key.count(".")
        assert any(line.startswith(f"{indent}{name}:") for line in lines), k.key
    # a few facts, as the schema states them
    block = text[text.index("  max_patch_area: number"):]
    block = block[: block.index("  max_edge_length")]
    assert "default 0.01" in block and "unit: m^2" in block and ">= 1e-08" in block
    assert "method: one of 'flat', 'hierarchical'\n    default \"hierarchical\"" in text
    assert "scene: path\n    default (required)" in text


def test_path_with_a_nul_byte_is_an_error():
    with pytest.raises(ConfigError) as info:
        load_config("bake\0.yaml")
    assert "not a usable path" in str(info.value)
