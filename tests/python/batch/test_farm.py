"""The plumbing a farm needs: --progress jsonl, plain lines off a terminal, --json errors,
SIGTERM during a bake (partial output removed, exit 143)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from hirad_e2e_helpers import COARSE, CORNELL, run_cli, write_config


def cfg_file(tmp_path: Path, **sections) -> Path:
    sections.setdefault("meshing", COARSE)
    sections.setdefault("outputs", {"preview": {"enabled": False}, "lightmaps": {"max_size": 256}})
    return write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", **sections)


def test_progress_jsonl(tmp_path):
    c = cfg_file(tmp_path, meshing={"max_patch_area": 0.0025, "max_edge_length": 0.05}, threads=1)
    env = {**os.environ, "HIRAD_PROGRESS_SECONDS": "0.1"}
    proc = subprocess.run([sys.executable, "-m", "hirad.cli", "bake", str(c), "--progress", "jsonl"], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    events = [json.loads(l) for l in proc.stderr.splitlines()]  # every line is JSON
    kinds = {e["event"] for e in events}
    assert {"stage", "stage_done", "progress"} <= kinds
    stages = [e["stage"] for e in events if e["event"] == "stage"]
    assert stages[0] == "read scene" and "form factors" in stages and "lightmaps" in stages
    assert [e["stage"] for e in events if e["event"] == "stage_done"] == stages
    elapsed = [e["elapsed"] for e in events]
    assert elapsed == sorted(elapsed) and elapsed[0] >= 0
    prog = [e for e in events if e["event"] == "progress" and e["stage"] == "form factors"]
    assert prog, "no progress event in the form factor stage"
    for e in prog:
        assert 0 <= e["fraction"] <= 1 and e["eta"] >= 0 and e["stage_elapsed"] > 0
    fr = [e["fraction"] for e in prog]
    assert fr == sorted(fr)
    # the summary line still goes to stdout
    assert "patches" in proc.stdout


def test_plain_lines_when_stderr_is_not_a_terminal(tmp_path):
    proc = run_cli("bake", cfg_file(tmp_path))
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert lines and all(l.startswith("hirad: [") for l in lines), lines
    assert any("form factors done in" in l for l in lines)
    assert "\x1b[" not in proc.stderr  # no terminal codes


def test_progress_none_and_bad_mode(tmp_path):
    c = cfg_file(tmp_path)
    quiet = run_cli("bake", c, "--progress", "none")
    assert quiet.returncode == 0 and quiet.stderr == ""
    bad = run_cli("bake", c, "--progress", "xml")
    assert bad.returncode == 2 and "--progress 'xml'" in bad.stderr


def test_json_errors(tmp_path):
    c = cfg_file(tmp_path)
    cfg = run_cli("bake", c, "--json", "--set", "solver.tolerance=2")
    assert cfg.returncode == 2
    err = json.loads(cfg.stdout)["error"]
    assert err["exit_code"] == 2 and err["kind"] == "usage"
    assert err["file"] == "--set solver.tolerance=2" and err["key"] == "solver.tolerance"
    text = c.read_text().replace("max_edge_length: 0.1", "max_edge_length: oops")
    c.write_text(text)
    located = json.loads(run_cli("bake", c, "--json").stdout)["error"]
    assert located["file"] == str(c) and located["line"] > 0 and located["key"] == "meshing.max_edge_length"
    c = cfg_file(tmp_path, outputs={"preview": {"camera": "/NoSuch"}})
    failed = run_cli("bake", c, "--json")
    assert failed.returncode == 4
    assert json.loads(failed.stdout)["error"]["kind"] == "failed" and "/NoSuch" in failed.stdout
    missing = run_cli("bake", tmp_path / "nope.yaml", "--json")
    assert missing.returncode == 2 and json.loads(missing.stdout)["error"]["line"] == 0
    # without --json, stdout stays empty
    assert run_cli("bake", tmp_path / "nope.yaml").stdout == ""


def test_sigterm_during_a_bake_removes_partial_output(tmp_path):
    c = cfg_file(tmp_path, meshing={"max_patch_area": 0.0016, "max_edge_length": 0.04}, threads=1)
    proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "bake", str(c), "--progress", "jsonl"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:  # wait until the bake is in its form factors
        if '"form factors"' in line:
            break
    time.sleep(0.5)
    assert proc.poll() is None
    assert [p for p in tmp_path.iterdir() if ".partial-" in p.name], "no staging directory while baking"
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=60)
    assert proc.returncode == 143
    assert not (tmp_path / "out").exists()
    assert [p for p in tmp_path.iterdir() if ".partial-" in p.name] == []
