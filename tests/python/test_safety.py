"""hirad never harms the user's files and never reports success it did not have (issue 11).

Each test plants the bad situation (an output that holds the inputs, a planted link, a link
store full of someone's files, a signal mid-bake, a full disk...), hashes every file that must
survive before and after, and checks the clear error, the exit code and that nothing is left.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from hirad_e2e_helpers import (CORNELL, REPO, furnace_box, run_cli, sha256, tree_hashes, write_config,
                               write_points_csv)

from hirad import files
from hirad.bake import OptionError, bake
from hirad.files import OUTPUT_MARKER, STORE_MARKER, UnsafePathError, WriteError

# A flat Cornell bake of about a second: coarse patches, no lightmaps, no preview.
FAST = {"method": "flat", "meshing": {"max_patch_area": 0.01, "max_edge_length": 0.1},
        "outputs": {"lightmaps": {"enabled": False}, "preview": {"enabled": False}}}
# The same out of core (hierarchical, block Southwell, links in a store), a few seconds.
OUT_OF_CORE = {"method": "hierarchical",
               "hierarchy": {"epsilon": 1e-3, "min_area": 0.01, "samples": 4, "max_rounds": 2},
               "solver": {"method": "block_southwell", "tolerance": 1e-3},
               "links": {"memory_budget": "16MB", "group_faces": 4},
               "outputs": {"lightmaps": {"enabled": False}, "preview": {"enabled": False}}}


def copy_scene(directory: Path) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    scene = directory / "cornell_box.usda"
    shutil.copyfile(CORNELL, scene)
    return scene


def config(path: Path, scene: Path, output: Path, **sections) -> Path:
    merged = {**FAST, **sections}
    return write_config(path, scene, output, **merged)


def partials(parent: Path) -> list[str]:
    return sorted(p.name for p in Path(parent).iterdir() if ".partial" in p.name or ".old-" in p.name)


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ---------------------------------------------------------------------------------------------
# 1. the one atomic write
# ---------------------------------------------------------------------------------------------


def _fixed_tokens(monkeypatch, *tokens):
    it = iter(tokens)
    monkeypatch.setattr(files.secrets, "token_hex", lambda n: next(it))


def test_atomic_write_follows_no_link_planted_at_the_temporary_name(tmp_path, monkeypatch):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    before = sha256(victim)
    target = tmp_path / "report.json"
    planted = tmp_path / f".report.{os.getpid()}-aaaa.tmp.json"
    planted.symlink_to(victim)
    _fixed_tokens(monkeypatch, "aaaa", "bbbb")
    files.write_json(target, {"a": 1})
    assert sha256(victim) == before
    assert planted.is_symlink() and os.readlink(planted) == str(victim)
    assert json.loads(target.read_text()) == {"a": 1}
    assert not (tmp_path / f".report.{os.getpid()}-bbbb.tmp.json").exists()


def test_atomic_write_replaces_a_link_at_the_target_not_its_target(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    before = sha256(victim)
    target = tmp_path / "out.txt"
    target.symlink_to(victim)
    files.write_text(target, "new\n")
    assert sha256(victim) == before
    assert not target.is_symlink() and target.read_text() == "new\n"


def test_atomic_write_failure_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "data.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="half way"):
        with files.atomic_file(target) as f:
            f.write(b"new, but only")
            raise RuntimeError("half way")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.bin"]


def test_atomic_path_refuses_a_link_swapped_in_for_its_temporary(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    before = sha256(victim)
    target = tmp_path / "page.png"
    with pytest.raises(WriteError, match="page.png"):
        with files.atomic_path(target) as tmp:
            assert tmp.suffix == ".png" and tmp.parent == tmp_path and tmp.stat().st_size == 0
            tmp.unlink()
            tmp.symlink_to(victim)
    assert sha256(victim) == before and not target.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["victim.txt"]


def test_atomic_write_error_names_the_file(tmp_path):
    (tmp_path / "ro").mkdir()
    target = tmp_path / "ro" / "x.json"
    target.mkdir()  # a directory where the file should go: the rename fails
    with pytest.raises(WriteError, match=r"x\.json: cannot write"):
        files.write_json(target, {})
    assert sorted(p.name for p in (tmp_path / "ro").iterdir()) == ["x.json"]


def test_new_files_follow_the_umask(tmp_path):
    old = os.umask(0o027)
    try:
        files.write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o640


# ---------------------------------------------------------------------------------------------
# 2. the output directory
# ---------------------------------------------------------------------------------------------


@pytest.fixture()
def project(tmp_path):
    """A user's folder: the scene, the config and an unrelated file, side by side."""
    d = tmp_path / "project"
    scene = copy_scene(d)
    (d / "notes.txt").write_text("my notes\n")
    return d, scene


def test_output_dot_is_refused_and_every_file_survives(project):
    d, scene = project
    cfg = d / "bake.yaml"
    cfg.write_text(yaml.safe_dump({"scene": "cornell_box.usda", "output": ".", **FAST}))
    before = tree_hashes(d)
    proc = run_cli("bake", cfg, cwd=d)
    assert proc.returncode == 2, proc.stderr
    assert "contains the scene" in proc.stderr and str(scene) in proc.stderr
    assert "Traceback" not in proc.stderr
    assert tree_hashes(d) == before
    assert partials(d.parent) == [] and partials(d) == []


def test_output_containing_the_config_is_refused(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    configs = tmp_path / "configs"
    configs.mkdir()
    cfg = config(configs / "bake.yaml", scene, configs)
    before = tree_hashes(tmp_path)
    proc = run_cli("bake", cfg)
    assert proc.returncode == 2 and "contains the config" in proc.stderr, proc.stderr
    assert tree_hashes(tmp_path) == before


def test_non_empty_directory_hirad_did_not_make_is_refused(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "results"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work\n")
    (out / "solution.usda").write_text("#usda 1.0\n")  # looks like hirad's, is not
    cfg = config(tmp_path / "c.yaml", scene, out)
    before = tree_hashes(tmp_path)
    with pytest.raises(UnsafePathError, match="did not make and is not empty"):
        bake(cfg)
    assert tree_hashes(tmp_path) == before
    assert partials(tmp_path) == []


def test_empty_directory_and_own_output_are_replaced(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    out.mkdir()
    cfg = config(tmp_path / "c.yaml", scene, out)
    bake(cfg)
    marker = json.loads((out / OUTPUT_MARKER).read_text())
    assert marker["format"] == "hirad-output" and marker["complete"] is True
    assert "solution.usda" in marker["files"] and "report.json" in marker["files"]
    first = sha256(out / "solution.usda")
    bake(cfg)  # hirad's own output: replaced
    assert sha256(out / "solution.usda") == first
    assert partials(tmp_path) == []


def test_a_file_added_to_hirads_output_is_not_deleted(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out)
    bake(cfg)
    (out / "my_render.exr").write_bytes(b"not hirad's")
    (out / "sub").mkdir()
    (out / "sub" / "keep.txt").write_text("mine\n")
    before = tree_hashes(out)
    proc = run_cli("bake", cfg, "-q")
    assert proc.returncode == 2, proc.stderr
    assert "holds files hirad did not write" in proc.stderr and "my_render.exr" in proc.stderr
    assert tree_hashes(out) == before
    assert partials(tmp_path) == []


def test_output_holding_a_layer_of_the_scene_is_refused(tmp_path):
    """A shot that sublayers a previous bake's solution.usda, baked into that same output,
    would delete its own input."""
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    bake(config(tmp_path / "first.yaml", scene, out))
    shot = tmp_path / "shot.usda"
    shot.write_text(f'#usda 1.0\n(\n    subLayers = [@{out / "solution.usda"}@]\n)\n')
    before = tree_hashes(out)
    with pytest.raises(UnsafePathError, match="contains the scene layer"):
        bake(config(tmp_path / "shot.yaml", shot, out))
    assert tree_hashes(out) == before


def test_output_that_is_a_link_is_refused(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "data.txt").write_text("x\n")
    out = tmp_path / "out"
    out.symlink_to(elsewhere)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(yaml.safe_dump({"scene": str(scene), "output": "out", **FAST}))  # not resolved
    before = tree_hashes(elsewhere)
    with pytest.raises(UnsafePathError, match="symbolic link"):
        bake(cfg)
    assert tree_hashes(elsewhere) == before and out.is_symlink()


def test_output_that_is_a_file_is_refused(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    out.write_text("a file\n")
    with pytest.raises(UnsafePathError, match="not a directory"):
        bake(config(tmp_path / "c.yaml", scene, out))
    assert out.read_text() == "a file\n"


def test_stale_staging_of_killed_bakes_is_removed_only_when_hirads_and_dead(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    dead, dead2 = dead_pid(), dead_pid()
    stale = tmp_path / f".out.partial-{dead}"
    stale.mkdir()
    (stale / OUTPUT_MARKER).write_text(json.dumps({"format": "hirad-output", "complete": False}))
    (stale / "solution.usda").write_text("half\n")
    old_aside = tmp_path / f".out.old-{dead}-abc123"
    old_aside.mkdir()
    (old_aside / OUTPUT_MARKER).write_text(json.dumps({"format": "hirad-output", "complete": True}))
    foreign = tmp_path / f".out.partial-{dead2}"   # no marker: not hirad's, never removed
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine\n")
    try:
        alive = tmp_path / f".out.partial-{sleeper.pid}"  # a bake still running
        alive.mkdir()
        (alive / OUTPUT_MARKER).write_text(json.dumps({"format": "hirad-output", "complete": False}))
        bake(config(tmp_path / "c.yaml", scene, out))
        assert not stale.exists() and not old_aside.exists()
        assert (foreign / "keep.txt").read_text() == "mine\n"
        assert (alive / OUTPUT_MARKER).exists()
    finally:
        sleeper.kill()
        sleeper.wait()


def test_files_hirad_writes_into_its_output_do_not_block_the_next_bake(tmp_path):
    """`hirad render` writes render.png beside the solution by default, and probe -o may write
    there too: hirad notes them in the output's marker, so the next bake replaces them."""
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out)
    bake(cfg)
    assert run_cli("render", out / "solution.usda", "--width", 32, "--height", 32).returncode == 0
    points = write_points_csv(tmp_path / "p.csv", [(0.03, 0.0, 0.03, 0, 1, 0)])
    assert run_cli("probe", out / "solution.usda", points, "-o", out / "probes" / "p.csv").returncode != 0
    (out / "probes").mkdir()
    assert run_cli("probe", out / "solution.usda", points, "-o", out / "probes" / "p.csv").returncode == 0
    listed = json.loads((out / OUTPUT_MARKER).read_text())["files"]
    assert "render.png" in listed and "probes/p.csv" not in listed  # probes/ is the user's directory
    (out / "probes" / "p.csv").unlink()
    (out / "probes").rmdir()
    assert run_cli("probe", out / "solution.usda", points, "-o", out / "p.csv").returncode == 0
    assert "p.csv" in json.loads((out / OUTPUT_MARKER).read_text())["files"]
    proc = run_cli("bake", cfg, "-q")
    assert proc.returncode == 0, proc.stderr
    assert not (out / "render.png").exists() and not (out / "p.csv").exists()


def test_two_bakes_of_one_process_never_share_a_staging_directory(tmp_path):
    a, b = files.make_staging(tmp_path / "out"), files.make_staging(tmp_path / "out")
    assert a != b and a.name.startswith(f".out.partial-{os.getpid()}-")
    assert (a / OUTPUT_MARKER).is_file() and (b / OUTPUT_MARKER).is_file()
    assert files.remove_stale_staging(tmp_path / "out") == []  # this process is alive


def test_failed_bake_keeps_the_previous_output_whole(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out)
    bake(cfg)
    before = tree_hashes(out)
    bad = config(tmp_path / "bad.yaml", scene, out, outputs={"preview": {"camera": "/World/NoSuchCamera"},
                                                             "lightmaps": {"enabled": False}})
    proc = run_cli("bake", bad, "-q")
    assert proc.returncode != 0 and "NoSuchCamera" in proc.stderr
    assert tree_hashes(out) == before
    assert partials(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# 3. the link store
# ---------------------------------------------------------------------------------------------


def _user_store(d: Path) -> Path:
    d.mkdir(parents=True)
    for name in ("round-1", "refined-2", "solved-3", "checkpoint", "draft.tmp", "letter.txt"):
        (d / name).write_text(f"the user's {name}\n")
    return d


def test_store_in_a_directory_hirad_did_not_make_is_refused(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    store = _user_store(tmp_path / "mine")
    before = tree_hashes(store)
    cfg = config(tmp_path / "c.yaml", scene, tmp_path / "out", **OUT_OF_CORE)
    data = yaml.safe_load(cfg.read_text())
    data["links"]["store"] = str(store)
    cfg.write_text(yaml.safe_dump(data))
    proc = run_cli("bake", cfg, "-q")
    assert proc.returncode == 2, proc.stderr
    assert f"links.store {store}" in proc.stderr and "did not make" in proc.stderr
    assert tree_hashes(store) == before
    assert not (tmp_path / "out").exists() and partials(tmp_path) == []


def test_planted_default_store_link_is_refused(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    victim = _user_store(tmp_path / "victim")
    before = tree_hashes(victim)
    (tmp_path / "out.links").symlink_to(victim)
    with pytest.raises(UnsafePathError, match="symbolic link"):
        bake(config(tmp_path / "c.yaml", scene, tmp_path / "out", **OUT_OF_CORE))
    assert tree_hashes(victim) == before


@pytest.mark.parametrize("where", ["output", "inside output", "holds output", "holds scene"])
def test_store_overlapping_the_output_or_the_scene_is_refused(tmp_path, where):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "work" / "out"
    store = {"output": out, "inside output": out / "links", "holds output": tmp_path / "work",
             "holds scene": tmp_path / "scenes"}[where]
    sections = {**OUT_OF_CORE, "links": {**OUT_OF_CORE["links"], "store": str(store)}}
    cfg = config(tmp_path / "c.yaml", scene, out, **sections)
    before = tree_hashes(tmp_path)
    with pytest.raises(UnsafePathError, match="links.store"):
        bake(cfg)
    assert tree_hashes(tmp_path) == before


def test_store_hirad_made_is_marked_and_accepted_again(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out, **OUT_OF_CORE)
    first = bake(cfg)
    store = tmp_path / "out.links"
    assert json.loads((store / STORE_MARKER).read_text())["format"] == "hirad-linkstore"
    assert any(p.name.startswith("round-") for p in store.iterdir())
    again = bake(cfg, reuse_links=True)  # the store hirad made is accepted, and used
    assert again.report["links"]["reused"]
    assert again.report["links"]["form_factors_computed"] == 0 < first.report["links"]["form_factors_computed"]


def test_resume_removes_the_staging_a_killed_bake_left(tmp_path):
    """A SIGKILLed out-of-core bake leaves its staging directory (no handler runs) and its store;
    `--resume` accepts the store hirad made and removes the dead bake's staging directory."""
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out, **OUT_OF_CORE)
    env = {**os.environ, "COLUMNS": "200"}
    proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "bake", str(cfg), "-q"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    store = tmp_path / "out.links"
    end = time.monotonic() + 120
    while not (store / STORE_MARKER).exists() and proc.poll() is None and time.monotonic() < end:
        time.sleep(0.01)
    proc.kill()
    proc.communicate()
    left = [p for p in tmp_path.iterdir() if p.name.startswith(".out.partial-")]
    if not left:  # the bake won the race and finished: leave a dead bake's staging by hand
        stale = tmp_path / f".out.partial-{dead_pid()}"
        stale.mkdir()
        (stale / OUTPUT_MARKER).write_text(json.dumps({"format": "hirad-output", "complete": False}))
        left = [stale]
    assert all((p / OUTPUT_MARKER).exists() for p in left)
    proc = run_cli("bake", cfg, "-q", "--resume")
    assert proc.returncode == 0, proc.stderr
    assert partials(tmp_path) == [] and (out / "solution.usda").exists()


def test_resume_and_reuse_on_a_bake_without_a_store_are_errors(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out)
    proc = run_cli("bake", cfg, "--resume")
    assert proc.returncode == 2 and "--resume" in proc.stderr and "method: flat" in proc.stderr, proc.stderr
    assert not out.exists() and partials(tmp_path) == []
    hier = config(tmp_path / "h.yaml", scene, out, method="hierarchical",
                  hierarchy={"epsilon": 1e-3, "min_area": 0.01, "max_rounds": 2})
    with pytest.raises(OptionError, match="--reuse-links"):
        bake(hier, reuse_links=True)
    assert not out.exists() and partials(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# 4. signals
# ---------------------------------------------------------------------------------------------


def _slow_config(tmp_path: Path) -> tuple[Path, Path]:
    """A flat Cornell bake of ~3,000 patches on one thread: its form factors (68 M rays) take
    well over ten seconds on any machine."""
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "slow.yaml", scene, out, threads=1,
                 meshing={"max_patch_area": 0.0009, "max_edge_length": 0.038})
    return cfg, out


def _wait_for_staging(parent: Path, proc: subprocess.Popen, timeout: float = 60) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if any(".partial-" in p.name for p in parent.iterdir()):
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    raise AssertionError("the bake never made its staging directory")


@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_during_a_bake_removes_the_partial_output(tmp_path, signum, code):
    cfg, out = _slow_config(tmp_path)
    env = {**os.environ, "COLUMNS": "200"}
    proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "bake", str(cfg)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_staging(tmp_path, proc)
    time.sleep(2.0)
    assert proc.poll() is None, "the bake finished before the signal: make the config slower"
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert "partial output removed" in err and "Traceback" not in err
    assert not out.exists()
    assert partials(tmp_path) == []


def test_signal_while_python_runs_is_handled_in_the_main_thread(tmp_path):
    """The other path: the main thread is in Python (here a stand-in stage that sleeps), the
    handler raises Interrupted, the bake's cleanup removes the staging directory."""
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out)
    script = (
        "import sys, time\n"
        "import hirad.bake\n"
        "b = sys.modules['hirad.bake']\n"
        "def slow(cfg, staging, rep, *a, **k):\n"
        "    (staging / 'half.usda').write_text('x')\n"
        "    print('started', flush=True)\n"
        "    while True:\n"
        "        time.sleep(0.01)\n"
        "b._run = slow\n"
        f"sys.argv = ['hirad', 'bake', {str(cfg)!r}]\n"
        "from hirad.cli import main\n"
        "main()\n")
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "started"
    assert partials(tmp_path) != []
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    # the main thread's message (the watchdog's says "during an engine call")
    assert "interrupted by SIGINT; partial output removed" in err and "Traceback" not in err
    assert partials(tmp_path) == [] and not out.exists()


# ---------------------------------------------------------------------------------------------
# 5. render -o, probe -o and their options
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def baked(tmp_path_factory):
    root = tmp_path_factory.mktemp("baked")
    scene = copy_scene(root / "scenes")
    out = root / "out"
    sections = {**FAST, "outputs": {"lightmaps": {"enabled": True, "texels_per_metre": 16},
                                    "preview": {"enabled": False}}}
    bake(write_config(root / "c.yaml", scene, out, **sections))
    # on the floor (y = 0, normal +Y) clear of the blocks, and on the back wall (z = 559.2 mm)
    points = write_points_csv(root / "points.csv", [(0.03, 0.0, 0.03, 0, 1, 0), (0.30, 0.40, 0.5592, 0, 0, -1)])
    return {"root": root, "scene": scene, "out": out, "solution": out / "solution.usda", "points": points}


@pytest.mark.parametrize("command", ["probe", "render", "reference"])
def test_planted_partial_link_is_not_followed(baked, tmp_path, command):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    before = sha256(victim)
    target = tmp_path / ("view.png" if command == "render" else f"{command}.csv")
    for name in (target.name + ".partial", f".{target.name}.partial"):
        (tmp_path / name).symlink_to(victim)
    args = {"probe": [baked["solution"], baked["points"]],
            "render": [baked["solution"], "--width", 32, "--height", 32],
            "reference": [baked["scene"], baked["points"], "--paths", 4]}[command]
    proc = run_cli(command, *args, "-o", target)
    assert proc.returncode == 0, proc.stderr
    assert sha256(victim) == before
    assert target.is_file() and not target.is_symlink() and target.stat().st_size > 0
    if command == "render":
        assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("command, which", [("probe", "solution"), ("probe", "points"), ("probe", "scene"),
                                            ("render", "page")])
def test_output_equal_to_an_input_is_refused(baked, command, which):
    if which == "page":
        target = baked["out"] / "lightmaps" / "pages" / "page0.exr"  # a texture the solution binds
    else:
        target = baked[which]
    before = tree_hashes(baked["root"])
    args = [baked["solution"], baked["points"]] if command == "probe" else [baked["solution"], "--lightmaps",
                                                                            "--width", 32, "--height", 32]
    proc = run_cli(command, *args, "-o", target)
    assert proc.returncode == 2, proc.stderr
    assert "never overwrites an input" in proc.stderr and str(target) in proc.stderr
    assert tree_hashes(baked["root"]) == before


def test_render_jpeg_is_jpeg(baked, tmp_path):
    from PIL import Image

    target = tmp_path / "view.jpg"
    proc = run_cli("render", baked["solution"], "--width", 32, "--height", 24, "-o", target)
    assert proc.returncode == 0, proc.stderr
    assert target.read_bytes()[:3] == b"\xff\xd8\xff"
    with Image.open(target) as im:
        assert im.format == "JPEG" and im.size == (32, 24)


@pytest.mark.parametrize("args, message", [
    (["-o", "{tmp}/view.tiff"], "unknown image type '.tiff'"),
    (["-o", "{tmp}/view"], "unknown image type"),
    (["--exposure", "nan", "-o", "{tmp}/a.png"], "--exposure must be a finite number above 0, got nan"),
    (["--exposure", "-1", "-o", "{tmp}/a.png"], "--exposure"),
    (["--exposure", "inf", "-o", "{tmp}/a.png"], "--exposure"),
])
def test_render_bad_options_are_refused(baked, tmp_path, args, message):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    proc = run_cli("render", baked["solution"], "--width", 32, "--height", 32, *args)
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["-1", "nan", "0", "inf"])
@pytest.mark.parametrize("command", ["probe", "reference"])
def test_max_distance_must_be_finite_and_positive(baked, value, command):
    first = baked["solution"] if command == "probe" else baked["scene"]
    proc = run_cli(command, first, baked["points"], "--max-distance", value)
    assert proc.returncode == 2, proc.stderr
    assert "--max-distance must be a finite number above 0" in proc.stderr


def test_reference_output_equal_to_the_points_is_refused(baked):
    before = sha256(baked["points"])
    proc = run_cli("reference", baked["scene"], baked["points"], "--paths", 4, "-o", baked["points"])
    assert proc.returncode == 2 and "never overwrites an input" in proc.stderr, proc.stderr
    assert sha256(baked["points"]) == before


# ---------------------------------------------------------------------------------------------
# 6. errors: one line, the file, the exit code of the kind
# ---------------------------------------------------------------------------------------------


def _limit_file_size(limit: int):
    def pre():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


def test_disk_full_on_the_output_names_the_file(tmp_path):
    """A write that fails like a full disk (RLIMIT_FSIZE: EFBIG past 20 kB) while the
    solution layer is written: exit 4, one line naming the file, no USD dump, no output."""
    scene = copy_scene(tmp_path / "scenes")
    out = tmp_path / "out"
    cfg = config(tmp_path / "c.yaml", scene, out)
    env = {**os.environ, "COLUMNS": "200"}
    proc = subprocess.run([sys.executable, "-m", "hirad.cli", "bake", str(cfg), "-q"], env=env,
                          capture_output=True, text=True, preexec_fn=_limit_file_size(20_000), timeout=300)
    assert proc.returncode == 4, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("hirad: error: "), proc.stderr
    # the layer's arrays are written first (the crate beside solution.usda)
    assert lines[0].startswith(f"hirad: error: {out / 'solution.arrays.usdc'}: could not write"), lines[0]
    assert ".partial" not in lines[0] and ".tmp" not in lines[0]
    assert "ErrorException" not in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists() and partials(tmp_path) == []


def test_unexpected_exception_is_one_line_and_exit_1(tmp_path):
    """Whatever escapes (here a nanobind-style TypeError from the engine) is one line naming the
    stage, exit 1; HIRAD_DEBUG=1 shows the traceback."""
    scene = copy_scene(tmp_path / "scenes")
    cfg = config(tmp_path / "c.yaml", scene, tmp_path / "out")
    script = (
        "import sys\n"
        "import hirad.bake\n"
        "b = sys.modules['hirad.bake']\n"
        "from hirad import report\n"
        "def broken(cfg, staging, rep, *a, **k):\n"
        "    with rep.stage('build scene'):\n"
        "        raise TypeError('Engine(): incompatible function arguments. The following argument types are "
        "supported:\\n    1. (self, seed: int) -> None\\n\\nInvoked with: 1180591620717411303424')\n"
        "b._run = broken\n"
        f"sys.argv = ['hirad', 'bake', '-q', {str(cfg)!r}]\n"
        "from hirad.cli import main\n"
        "main()\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "during 'build scene'" in lines[0] and "incompatible function arguments" in lines[0]
    assert "HIRAD_DEBUG=1" in lines[0]
    assert partials(tmp_path) == []
    debug = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                           env={**os.environ, "HIRAD_DEBUG": "1"})
    assert debug.returncode == 1 and "Traceback" in debug.stderr


@pytest.mark.parametrize("key, value", [("seed", 2 ** 70), ("links", {"memory_budget": "99999999TB"})])
def test_values_beyond_the_engine_end_in_one_line(tmp_path, key, value):
    scene = copy_scene(tmp_path / "scenes")
    sections = dict(OUT_OF_CORE) if key == "links" else {}
    if key == "links":
        sections["links"] = {**OUT_OF_CORE["links"], **value}
    else:
        sections[key] = value
    cfg = config(tmp_path / "c.yaml", scene, tmp_path / "out", **sections)
    proc = run_cli("bake", cfg, "-q")
    assert proc.returncode in (2, 4), proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hirad: error: "), proc.stderr
    assert "Traceback" not in proc.stderr and "TypeError" not in proc.stderr
    assert not (tmp_path / "out").exists() and partials(tmp_path) == []


def test_exit_codes_by_kind(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    bad_yaml = tmp_path / "bad.yaml"
    bad_yaml.write_text("scene: [unclosed\n")
    assert run_cli("bake", bad_yaml).returncode == 2
    garbage = tmp_path / "garbage.usda"
    garbage.write_text("this is not USD\n")
    proc = run_cli("bake", config(tmp_path / "g.yaml", garbage, tmp_path / "out"))
    assert proc.returncode == 3 and "garbage.usda" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
    assert run_cli("render", tmp_path / "missing.usda").returncode == 3
    assert run_cli("bake", config(tmp_path / "ok.yaml", scene, tmp_path / "out2"), "-q").returncode == 0


# ---------------------------------------------------------------------------------------------
# 7. progress, --version, help, config --schema
# ---------------------------------------------------------------------------------------------


def test_progress_lines_when_stderr_is_not_a_terminal(tmp_path):
    scene = copy_scene(tmp_path / "scenes")
    cfg = config(tmp_path / "c.yaml", scene, tmp_path / "out")
    env = {**os.environ, "HIRAD_PROGRESS_SECONDS": "0"}
    env.pop("COLUMNS", None)
    proc = subprocess.run([sys.executable, "-m", "hirad.cli", "bake", str(cfg)], env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert "\x1b[" not in proc.stderr  # no terminal control codes
    assert any(ln.startswith("hirad: [") and "form factors ..." in ln for ln in lines)
    assert any("form factors" in ln and "%" in ln and "patches" in ln for ln in lines)
    assert any("form factors done in" in ln for ln in lines)
    elapsed = [float(ln.split("[")[1].split("s]")[0]) for ln in lines if ln.startswith("hirad: [")]
    assert elapsed == sorted(elapsed)


def test_progress_lines_are_rate_limited_and_never_cut():
    import io

    from hirad.report import Reporter

    buf = io.StringIO()
    rep = Reporter(stream=buf, interval=3600)
    with rep:
        with rep.stage("form factors", total=100) as update:
            for k in range(1000):
                update(k % 100, f"{k}/1000 patches")
        rep.warn("w" * 300)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 3, lines  # start, done, the warning: no update within the hour
    assert lines[0].endswith("form factors ...") and lines[1].endswith("form factors done in 0.0 s")
    assert lines[2] == "hirad: warning: " + "w" * 300
    buf = io.StringIO()
    rep = Reporter(stream=buf, interval=0)
    with rep.stage("solve", total=1.0) as update:
        update(0.25, "iteration 7, residual " + "9" * 200)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 3 and lines[1].endswith("solve 25% iteration 7, residual " + "9" * 200)
    assert Reporter(quiet=True, stream=buf)._log is False
    from hirad import report

    buf = io.StringIO()
    rep = Reporter(stream=buf, interval=0)
    with pytest.raises(ValueError):
        with rep.stage("lightmaps"):
            raise ValueError("x")
    assert buf.getvalue().splitlines()[-1].endswith("lightmaps stopped after 0.0 s")
    assert report.current_stage == "lightmaps"  # what the CLI names in an unexpected error
    with rep.stage("preview"):
        pass
    assert report.current_stage is None


def test_version():
    from hirad import __version__

    proc = run_cli("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"hirad {__version__}"


def test_help_keeps_bracketed_defaults():
    proc = run_cli("render", "--help")
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())  # help lines wrap at the terminal width
    assert "[render.png beside the solution]" in text and "[automatic]" in text
    text = " ".join(run_cli("probe", "--help").stdout.split())
    assert "CSV to write [stdout]" in text and "above 0 [0.05]" in text


def test_config_schema():
    proc = run_cli("config", "--schema")
    try:
        from hirad.config.describe import schema_text  # noqa: F401
    except ImportError:
        pytest.skip("hirad.config.describe is not there yet (PY-VALIDATION)")
    assert proc.returncode == 0, proc.stderr
    for key in ("max_patch_area", "memory_budget", "output"):
        assert key in proc.stdout
    assert run_cli("config").returncode == 2
