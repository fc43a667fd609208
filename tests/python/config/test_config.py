"""Tests for hirad.config: schema defaults, the example configs, and error reports."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from hirad.config import Config, ConfigError, config_from_dict, load_config

REPO = Path(__file__).resolve().parents[3]
CONFIGS = REPO / "configs"


def write(directory: Path, text: str, name: str = "bake.yaml") -> Path:
    """Write a config file (dedented) next to an empty scene file."""
    (directory / "scene.usda").write_text("#usda 1.0\n")
    path = directory / name
    path.write_text(textwrap.dedent(text).lstrip("\n"))
    return path


def load_error(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    return info.value


# --- defaults and examples -------------------------------------------------


def test_defaults(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, "scene: scene.usda\n"))
    assert cfg.scene == tmp_path / "scene.usda"
    assert cfg.output == tmp_path / "out" / "bake"
    assert cfg.threads == 0
    assert cfg.seed == 1
    assert cfg.materials.default_reflectance == (0.5, 0.5, 0.5)
    assert cfg.materials.uv_primvars == ["st", "uv", "UVMap", "st0", "map1"]
    assert cfg.meshing.max_patch_area == 0.01
    assert cfg.meshing.max_edge_length == 0.1
    assert cfg.formfactors.method == "raycast"
    assert cfg.formfactors.samples == 16
    assert cfg.formfactors.hemicube_resolution == 128
    assert cfg.formfactors.hemicube_points == 4
    assert cfg.solver.method == "southwell"
    assert cfg.solver.tolerance == 1e-4
    assert cfg.solver.max_iterations == 100_000_000
    assert cfg.solver.snapshots == 0
    assert cfg.reconstruction.crease_angle == 30.0
    assert cfg.outputs.usd is True
    assert cfg.outputs.report is True
    assert cfg.outputs.lightmaps.enabled is True
    assert cfg.outputs.lightmaps.texels_per_patch == 4
    assert cfg.outputs.lightmaps.max_size == 4096
    assert cfg.outputs.preview.enabled is True
    assert cfg.outputs.preview.camera is None
    assert (cfg.outputs.preview.width, cfg.outputs.preview.height) == (512, 512)
    assert cfg.outputs.preview.samples == 4


def test_every_field_is_documented() -> None:
    def models(model: type) -> list[type]:
        found = [model]
        for field in model.model_fields.values():
            if isinstance(field.annotation, type) and hasattr(field.annotation, "model_fields"):
                found += models(field.annotation)
        return found

    for model in models(Config):
        for name, field in model.model_fields.items():
            assert field.description, f"{model.__name__}.{name} has no description"


@pytest.mark.parametrize(
    ("name", "area", "edge", "samples", "output"),
    [
        ("cornell.yaml", 0.0009, 0.038, 16, "cornell"),
        ("cornell_10k.yaml", 0.00026, 0.021, 8, "cornell_10k"),
    ],
)
def test_example_configs_load(name: str, area: float, edge: float, samples: int, output: str) -> None:
    cfg = load_config(CONFIGS / name)
    assert cfg.scene == CONFIGS / "scenes" / "cornell_box.usda"
    assert cfg.scene.is_file()
    assert cfg.output == REPO / "out" / output
    assert cfg.meshing.max_patch_area == area
    assert cfg.meshing.max_edge_length == edge
    assert cfg.formfactors.method == "raycast"
    assert cfg.formfactors.samples == samples
    assert cfg.solver.method == "southwell"
    assert cfg.solver.tolerance == 1e-4
    assert cfg.outputs.usd and cfg.outputs.report
    assert cfg.outputs.lightmaps.enabled and cfg.outputs.preview.enabled
    assert cfg.outputs.preview.camera == "/World/Camera"


def test_game_engines_example_loads() -> None:
    cfg = load_config(CONFIGS / "game_engines.yaml")
    assert cfg.scene.is_file() and cfg.output == REPO / "out" / "game_engines"
    lm = cfg.outputs.lightmaps
    assert cfg.outputs.gltf and cfg.outputs.usd_view == "source" and cfg.outputs.volume.enabled
    assert lm.mode == "final_gather" and lm.directional and lm.encodings == ["unity-rgbm", "unity-dldr"]


# --- error reports ---------------------------------------------------------


def test_missing_config_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.yaml"
    err = load_error(path)
    assert err.line == 0
    assert err.key == ""
    assert str(err) == f"{path}: config file not found"


def test_unknown_nested_key_line_and_dotted_key(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        """
        scene: scene.usda
        outputs:
          usd: true
          preview:
            width: 256
            camera_path: /World/Cam
        """,
    )
    err = load_error(path)
    assert (err.line, err.key) == (6, "outputs.preview.camera_path")
    assert "unknown key" in err.problem
    assert "camera" in err.problem  # suggests the right spelling
    assert str(err) == f"{path}:6: outputs.preview.camera_path: {err.problem}"


def test_unknown_top_level_key(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "scene: scene.usda\nmesing:\n  max_patch_area: 0.1\n"))
    assert (err.line, err.key) == (2, "mesing")
    assert "meshing" in err.problem


def test_string_where_number_expected(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        """
        scene: scene.usda
        meshing:
          max_edge_length: 0.05
          max_patch_area: "0.01"
        """,
    )
    err = load_error(path)
    assert (err.line, err.key) == (4, "meshing.max_patch_area")
    assert "number" in err.problem


@pytest.mark.parametrize(
    ("text", "line", "key"),
    [
        ("scene: scene.usda\nthreads: 2.5\n", 2, "threads"),
        ("scene: scene.usda\noutputs:\n  usd: 1\n", 3, "outputs.usd"),
        ("scene: scene.usda\nformfactors:\n  method: 3\n", 3, "formfactors.method"),
        ("scene: scene.usda\nmeshing: 0.1\n", 2, "meshing"),
        ("scene: scene.usda\nmaterials:\n  default_reflectance:\n    - 0.2\n    - '0.3'\n    - 0.4\n",
         5, "materials.default_reflectance[1]"),
    ],
)
def test_wrong_types(tmp_path: Path, text: str, line: int, key: str) -> None:
    err = load_error(write(tmp_path, text))
    assert (err.line, err.key) == (line, key)


def test_malformed_yaml_line(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        """
        scene: scene.usda
        solver:
          method: [southwell
          tolerance: 1.0e-3
        """,
    )
    err = load_error(path)
    assert err.line == 4
    assert "malformed YAML" in err.problem
    assert str(err).startswith(f"{path}:4: ")


def test_bad_indentation_line(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "scene: scene.usda\nsolver:\n  method: jacobi\n tolerance: 0.1\n"))
    assert err.line == 4


def test_missing_scene_file(tmp_path: Path) -> None:
    path = write(tmp_path, "seed: 3\n\nscene: scenes/missing_box.usda\nthreads: 1\n")
    err = load_error(path)
    assert (err.line, err.key) == (3, "scene")
    assert str(tmp_path / "scenes" / "missing_box.usda") in err.problem
    assert "not found" in err.problem


def test_missing_required_scene_key(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "# a comment\nseed: 3\n"))
    assert err.key == "scene"
    assert err.line == 2  # the top-level mapping starts on line 2
    assert "missing" in err.problem


def test_missing_key_in_tuple_reports_parent_line(tmp_path: Path) -> None:
    err = load_error(
        write(tmp_path, "scene: scene.usda\nmaterials:\n  default_reflectance: [0.2, 0.3]\n")
    )
    assert err.line == 3
    assert err.key.startswith("materials.default_reflectance")


@pytest.mark.parametrize(
    ("text", "line", "key"),
    [
        ("scene: scene.usda\nformfactors:\n  samples: 0\n", 3, "formfactors.samples"),
        ("scene: scene.usda\nformfactors:\n  samples: 4097\n", 3, "formfactors.samples"),
        ("scene: scene.usda\nsolver:\n  tolerance: 2\n", 3, "solver.tolerance"),
        ("scene: scene.usda\nsolver:\n  tolerance: 0\n", 3, "solver.tolerance"),
        ("scene: scene.usda\nmeshing:\n  max_patch_area: -1.0e-3\n", 3, "meshing.max_patch_area"),
        ("scene: scene.usda\nmeshing:\n  max_edge_length: .inf\n", 3, "meshing.max_edge_length"),
        ("scene: scene.usda\nthreads: -1\n", 2, "threads"),
        ("scene: scene.usda\nreconstruction: {crease_angle: 181}\n", 2, "reconstruction.crease_angle"),
        ("scene: scene.usda\nmaterials:\n  default_reflectance: [0.5, 1.0, 0.5]\n",
         3, "materials.default_reflectance[1]"),
        ("scene: scene.usda\noutputs:\n  lightmaps:\n    max_size: 32\n", 4, "outputs.lightmaps.max_size"),
        ("scene: scene.usda\noutputs:\n  preview:\n    camera: World/Camera\n", 4, "outputs.preview.camera"),
        ("scene: scene.usda\nsolver:\n  method: conjugate_gradient\n", 3, "solver.method"),
        ("scene: scene.usda\nhierarchy:\n  relative_epsilon: 1.0\n", 3, "hierarchy.relative_epsilon"),
        ("scene: scene.usda\nhierarchy:\n  relative_epsilon: -0.1\n", 3, "hierarchy.relative_epsilon"),
        ("scene: scene.usda\nhierarchy:\n  spread_epsilon: 1.5\n", 3, "hierarchy.spread_epsilon"),
        ("scene: scene.usda\nhierarchy:\n  spread_epsilon: -1.0e-3\n", 3, "hierarchy.spread_epsilon"),
        ("scene: scene.usda\noutputs:\n  lightmaps:\n    encodings: [unity-rgbm, png]\n", 4,
         "outputs.lightmaps.encodings[1]"),
        ("scene: scene.usda\noutputs:\n  lightmaps:\n    uv_set: 'st 1'\n", 4, "outputs.lightmaps.uv_set"),
    ],
)
def test_out_of_range(tmp_path: Path, text: str, line: int, key: str) -> None:
    err = load_error(write(tmp_path, text))
    assert (err.line, err.key) == (line, key)


def test_directional_lightmaps_need_the_gather_and_gltf_needs_its_sources(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "scene: scene.usda\noutputs:\n  lightmaps:\n    mode: interpolate\n"
                                     "    directional: true\n"))
    assert err.key == "outputs.lightmaps" and "final_gather" in err.problem
    err = load_error(write(tmp_path, "scene: scene.usda\noutputs:\n  gltf: true\n  lightmaps:\n"
                                     "    enabled: false\n"))
    assert err.key == "outputs" and "lightmaps.enabled" in err.problem
    cfg = load_config(write(tmp_path, "scene: scene.usda\nmethod: hierarchical\noutputs:\n  gltf: true\n"
                                      "  lightmaps:\n    mode: final_gather\n    directional: true\n"))
    assert cfg.outputs.gltf and cfg.outputs.lightmaps.directional


def test_gather_stride_is_a_power_of_two_and_needs_the_gather(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "scene: scene.usda\nmethod: hierarchical\noutputs:\n  lightmaps:\n"
                                     "    mode: final_gather\n    gather_stride: 3\n"))
    assert (err.line, err.key) == (6, "outputs.lightmaps.gather_stride") and "power of two" in err.problem
    err = load_error(write(tmp_path, "scene: scene.usda\noutputs:\n  lightmaps:\n    gather_stride: 4\n"))
    assert err.key == "outputs.lightmaps" and "final_gather" in err.problem
    err = load_error(write(tmp_path, "scene: scene.usda\nmethod: hierarchical\noutputs:\n  lightmaps:\n"
                                     "    mode: final_gather\n    gather_tolerance: 0\n"))
    assert err.key == "outputs.lightmaps.gather_tolerance"
    cfg = load_config(write(tmp_path, "scene: scene.usda\nmethod: hierarchical\noutputs:\n  lightmaps:\n"
                                      "    mode: final_gather\n    gather_stride: 8\n"))
    assert cfg.outputs.lightmaps.gather_stride == 8 and cfg.outputs.lightmaps.gather_tolerance == 0.05


def test_cluster_receivers_need_a_solver_that_gathers_at_clusters(tmp_path: Path) -> None:
    # Gauss-Seidel and Southwell on the hierarchy work face by face; links that end on clusters
    # are solved by Jacobi and the streaming block Southwell only. Southwell is the default.
    err = load_error(write(tmp_path, "scene: scene.usda\nhierarchy:\n  cluster_receivers: true\n"))
    assert err.key == "solver" and "cluster_receivers" in err.problem and "jacobi" in err.problem
    err = load_error(write(tmp_path, "scene: scene.usda\nhierarchy:\n  cluster_receivers: true\n"
                                     "solver:\n  method: gauss_seidel\n"))
    assert err.key == "solver" and "'gauss_seidel'" in err.problem
    for method in ("jacobi", "block_southwell"):
        cfg = load_config(write(tmp_path, f"scene: scene.usda\nhierarchy:\n  cluster_receivers: true\n"
                                          f"solver:\n  method: {method}\n"))
        assert cfg.hierarchy.cluster_receivers


def test_snapshots_need_progressive(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "scene: scene.usda\nsolver:\n  method: jacobi\n  snapshots: 10\n"))
    assert (err.line, err.key) == (4, "solver.snapshots")
    assert "progressive" in err.problem

    # Default method (southwell) is not progressive either.
    with pytest.raises(ConfigError):
        config_from_dict({"scene": "scene.usda", "solver": {"snapshots": 1}}, tmp_path)

    cfg = load_config(
        write(tmp_path, "scene: scene.usda\nmethod: flat\nsolver:\n  method: progressive\n  snapshots: 10\n")
    )
    assert cfg.solver.snapshots == 10


def test_duplicate_key(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "scene: scene.usda\nseed: 1\nthreads: 2\nseed: 2\n"))
    assert (err.line, err.key) == (4, "seed")
    assert "line 2" in err.problem


def test_all_problems_collected(tmp_path: Path) -> None:
    err = load_error(
        write(tmp_path, "scene: scene.usda\nseed: x\nsolver:\n  tolerance: 5\nthreads: -2\n")
    )
    assert [(e.line, e.key) for e in err.errors] == [(2, "seed"), (4, "solver.tolerance"), (5, "threads")]
    assert err.errors[0] is err


# --- values and paths ------------------------------------------------------


def test_numbers_in_exponent_notation(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, "scene: scene.usda\nsolver:\n  tolerance: 1e-5\n"))
    assert cfg.solver.tolerance == 1e-5


def test_int_accepted_for_float(tmp_path: Path) -> None:
    cfg = load_config(write(tmp_path, "scene: scene.usda\nreconstruction:\n  crease_angle: 45\n"))
    assert cfg.reconstruction.crease_angle == 45.0
    assert isinstance(cfg.reconstruction.crease_angle, float)


def test_relative_paths_resolve_against_config_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    config_dir = tmp_path / "configs"
    (config_dir / "scenes").mkdir(parents=True)
    (config_dir / "scenes" / "box.usda").write_text("#usda 1.0\n")
    path = config_dir / "run.yaml"
    path.write_text("scene: scenes/box.usda\noutput: ../out/run\n")

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    cfg = load_config(Path("..") / "configs" / "run.yaml")
    assert cfg.scene.is_absolute() and cfg.output.is_absolute()
    assert cfg.scene == config_dir / "scenes" / "box.usda"
    assert cfg.output == tmp_path / "out" / "run"


def test_absolute_paths_kept(tmp_path: Path) -> None:
    scene = tmp_path / "abs.usda"
    scene.write_text("#usda 1.0\n")
    sub = tmp_path / "sub"
    sub.mkdir()
    path = sub / "c.yaml"
    path.write_text(f"scene: {scene}\noutput: {tmp_path / 'o'}\n")
    cfg = load_config(path)
    assert cfg.scene == scene
    assert cfg.output == tmp_path / "o"


def test_fingerprint_stable_across_key_order(tmp_path: Path) -> None:
    a = write(
        tmp_path,
        "scene: scene.usda\nseed: 7\nsolver:\n  method: jacobi\n  tolerance: 1.0e-3\n",
        "a.yaml",
    )
    b = write(
        tmp_path,
        "solver: {tolerance: 0.001, method: jacobi}\n# same settings, other order\nseed: 7\n"
        "scene: ./scene.usda\noutput: out/a\n",
        "b.yaml",
    )
    fa, fb = load_config(a).fingerprint(), load_config(b).fingerprint()
    assert fa == fb
    assert len(fa) == 64 and int(fa, 16) >= 0

    c = write(
        tmp_path,
        "scene: scene.usda\nseed: 7\nsolver:\n  method: jacobi\n  tolerance: 2.0e-3\n",
        "a.yaml",
    )
    assert load_config(c).fingerprint() != fa


def test_fingerprint_changes_with_nested_value(tmp_path: Path) -> None:
    base = {"scene": "scene.usda", "output": "out"}
    write(tmp_path, "scene: scene.usda\n")
    f0 = config_from_dict(base, tmp_path).fingerprint()
    f1 = config_from_dict({**base, "outputs": {"preview": {"width": 640}}}, tmp_path).fingerprint()
    assert f0 != f1
    assert config_from_dict(dict(reversed(list(base.items()))), tmp_path).fingerprint() == f0


def test_config_from_dict(tmp_path: Path) -> None:
    write(tmp_path, "scene: scene.usda\n")
    cfg = config_from_dict(
        {"scene": "scene.usda", "meshing": {"max_patch_area": 0.002}, "materials": {"default_reflectance": (0.1, 0.2, 0.3)}},
        base_dir=tmp_path,
    )
    assert cfg.scene == tmp_path / "scene.usda"
    assert cfg.output == tmp_path / "out" / "scene"
    assert cfg.meshing.max_patch_area == 0.002
    assert cfg.materials.default_reflectance == (0.1, 0.2, 0.3)

    named = config_from_dict({"scene": "scene.usda"}, base_dir=tmp_path, name="study")
    assert named.output == tmp_path / "out" / "study"

    with pytest.raises(ConfigError) as info:
        config_from_dict({"scene": "scene.usda", "formfactors": {"samples": "16"}}, base_dir=tmp_path)
    err = info.value
    assert (err.file, err.line, err.key) == ("<dict>", 0, "formfactors.samples")
    assert str(err).startswith("<dict>: formfactors.samples: ")

    with pytest.raises(ConfigError) as info:
        config_from_dict({"scene": "gone.usda"}, base_dir=tmp_path)
    assert info.value.key == "scene" and "gone.usda" in info.value.problem

    with pytest.raises(ConfigError) as info:
        config_from_dict({"scene": "scene.usda", "extra": 1}, base_dir=tmp_path)
    assert info.value.key == "extra"


def test_assignment_is_validated(tmp_path: Path) -> None:
    write(tmp_path, "scene: scene.usda\n")
    cfg = config_from_dict({"scene": "scene.usda"}, tmp_path)
    cfg.threads = 4
    assert cfg.thread_count() == 4
    with pytest.raises(ValueError):
        cfg.threads = -1


def test_top_level_not_a_mapping(tmp_path: Path) -> None:
    err = load_error(write(tmp_path, "- scene.usda\n"))
    assert err.line == 1
    assert "mapping" in err.problem
    err = load_error(write(tmp_path, "# nothing here\n"))
    assert "mapping" in err.problem


def test_closure_reflectance_is_a_reflectance_and_reaches_the_engine(tmp_path: Path) -> None:
    # hierarchy.closure_reflectance: leaves of at least this reflectance are normalised to their
    # closure (Hierarchy::closure); a reflectance, so in [0, 1], named with its line when not.
    from hirad.bake import hierarchy_options

    err = load_error(write(tmp_path, "scene: scene.usda\nhierarchy:\n  closure_reflectance: 1.5\n"))
    assert err.key == "hierarchy.closure_reflectance" and err.line == 3
    cfg = load_config(write(tmp_path, "scene: scene.usda\nhierarchy:\n  closure_reflectance: 0.0\n"))
    assert hierarchy_options(cfg).closure_reflectance == 0.0
    assert hierarchy_options(load_config(write(tmp_path, "scene: scene.usda\n"))).closure_reflectance == 0.95
