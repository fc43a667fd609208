"""`hirad batch` on a real 2-worker Dask LocalCluster: a multi-variant Cornell study, its
index, resumption by content key, a worker killed with kill -9, failing jobs, bad studies,
SIGTERM to the batch."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from hirad_e2e_helpers import COARSE, CORNELL, run_cli

from hirad.bake import bake

pytest.importorskip("distributed")

BASE = {"scene": str(CORNELL), "method": "flat", "meshing": COARSE,
        "outputs": {"preview": {"enabled": False}, "lightmaps": {"max_size": 256}}}
VARIANTS = [
    {"name": "ref"},
    {"name": "tight", "set": {"solver.tolerance": 1e-5}},
    {"name": "jacobi", "set": {"solver": {"method": "jacobi"}}},
    {"name": "lm16", "set": {"outputs.lightmaps.texels_per_metre": 16.0, "grid_rays": 16,
                             "grids": {"floor": {"kind": "rectangle", "corner": [0.1, 0.01, 0.1],
                                                 "edge_u": [0.35, 0.0, 0.0], "edge_v": [0.0, 0.0, 0.35],
                                                 "normal": [0.0, 1.0, 0.0]}}}},
    {"name": "seed7", "set": {"seed": 7, "formfactors.samples": 4}},
] + [  # a matrix-like sweep to the 12 variants a study of the issue has: reflectance x seed
    {"name": f"rho{int(rho * 100)}-s{seed}", "set": {"materials.default_reflectance": [rho] * 3, "seed": seed,
                                                     "formfactors.samples": 4}}
    for rho, seed in ((0.3, 2), (0.3, 3), (0.5, 2), (0.5, 3), (0.7, 2), (0.7, 3), (0.9, 2))
]
N = len(VARIANTS)  # 12


def write_study(root: Path, variants=VARIANTS, base=BASE, name="study.yaml", **extra) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / "base.yaml").write_text(yaml.safe_dump(base, sort_keys=False))
    data = {"base": "base.yaml", "variants": variants, "workers": 2, "threads": 1, **extra}
    (root / name).write_text(yaml.safe_dump(data, sort_keys=False))
    return root / name


def batch(*args, timeout=300):
    return run_cli("batch", *args, timeout=timeout)


def primvars(solution: Path) -> dict[str, np.ndarray]:
    """Every hirad attribute's array in a solution layer (independently of hirad)."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(solution))
    out = {}
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            n = attr.GetName()
            if n.startswith("primvars:hirad:") or n.startswith("hirad:patch"):
                v = attr.Get()
                if v is not None:
                    out[f"{prim.GetPath()}.{n}"] = np.asarray(v)
    assert out, f"no hirad primvars in {solution}"
    return out


def assert_same_primvars(a: Path, b: Path) -> None:
    pa, pb = primvars(a), primvars(b)
    assert sorted(pa) == sorted(pb)
    for k in pa:
        assert pa[k].dtype == pb[k].dtype and pa[k].shape == pb[k].shape, k
        assert pa[k].tobytes() == pb[k].tobytes(), f"{k} differs"


def index_rows(study_out: Path) -> dict[str, dict]:
    con = sqlite3.connect(str(study_out / "study.sqlite"))
    con.row_factory = sqlite3.Row
    try:
        return {r["name"]: dict(r) for r in con.execute("SELECT * FROM jobs")}
    finally:
        con.close()


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("study")
    path = write_study(root)
    t = time.monotonic()
    proc = batch(path, "--json")
    return {"root": root, "path": path, "out": root / "out" / "study", "proc": proc,
            "seconds": time.monotonic() - t}


def test_every_job_done_and_indexed(study):
    proc = study["proc"]
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads(proc.stdout)
    assert (res["run"], res["done"], res["failed"], res["skipped"]) == (N, N, 0, 0)
    assert "dashboard http://" in proc.stderr and "LocalCluster (2 workers" in proc.stderr
    rows = index_rows(study["out"])
    assert sorted(rows) == sorted(v["name"] for v in VARIANTS)
    workers = set()
    for name, r in rows.items():
        assert r["status"] == "done" and r["exit_code"] == 0 and r["error"] is None, r
        assert r["attempts"] == 1 and r["runs"] == 1
        assert r["seconds"] > 0 and r["finished_at"] >= r["started_at"] > 0
        assert r["done_key"] == r["key"] and len(r["key"]) == 64
        out = Path(r["output"])
        assert out == study["out"] / "jobs" / name
        rep = json.loads((out / "report.json").read_text())
        assert rep["content_key"] == r["key"]
        workers.add(r["worker"])
    assert len(workers) == 2, f"the jobs ran on {workers}, not on both workers"
    # the variants are different bakes
    reps = {n: json.loads((Path(r["output"]) / "report.json").read_text()) for n, r in rows.items()}
    assert reps["jacobi"]["solver"]["method"] == "jacobi"
    assert reps["tight"]["solver"]["residual"] <= 1e-5 < reps["ref"]["solver"]["residual"]
    assert len({r["key"] for r in rows.values()}) == N


def test_outputs_identical_to_baking_each_variant_alone(study, tmp_path):
    from hirad.batch import load_study

    s = load_study(study["path"])
    for job in s.jobs:
        alone = tmp_path / job.name
        over = [o for o in job.overrides if not o.startswith("output=")] + [f"output={alone}", "threads=2"]
        bake(study["root"] / "base.yaml", overrides=over)
        assert_same_primvars(job.output / "solution.usda", alone / "solution.usda")
        a, b = (json.loads((d / "report.json").read_text()) for d in (job.output, alone))
        assert a["content_key"] == b["content_key"] == job.key  # not the output path nor the threads
        assert a["energy_balance"] == b["energy_balance"]


def test_status_table_and_json(study):
    st = batch("status", study["path"], "--json")
    assert st.returncode == 0, st.stderr
    data = json.loads(st.stdout)
    assert {j["name"]: j["status"] for j in data["jobs"]} == {v["name"]: "done" for v in VARIANTS}
    assert data["batches"][-1]["status"] == "done" and data["batches"][-1]["jobs_run"] == N
    table = batch("status", study["path"])
    assert table.returncode == 0 and f"{N} done" in table.stdout
    for v in VARIANTS:
        assert v["name"] in table.stdout


def test_summary_csv_and_html(study):
    import csv

    rows = list(csv.DictReader((study["out"] / "summary.csv").open()))
    assert [r["job"] for r in rows] == [v["name"] for v in VARIANTS]
    by = {r["job"]: r for r in rows}
    rep = json.loads((study["out"] / "jobs" / "lm16" / "report.json").read_text())
    assert float(by["lm16"]["texels"]) == rep["outputs"]["lightmap_atlas"]["covered_texels"]
    assert float(by["lm16"]["texels"]) < float(by["ref"]["texels"])
    assert float(by["ref"]["energy_balance_error"]) == pytest.approx(
        json.loads((study["out"] / "jobs" / "ref" / "report.json").read_text())["energy_balance"]["max_relative_error"],
        rel=1e-5)
    assert by["tight"]["variant"] == "solver.tolerance=1e-05"
    floor = rep["grids"]["grids"]["floor"]
    assert float(by["lm16"]["floor Em (lx)"]) == pytest.approx(floor["em"], rel=1e-5)
    assert float(by["lm16"]["floor U0"]) == pytest.approx(floor["u0"], rel=1e-5, abs=1e-12)
    assert by["ref"]["floor Em (lx)"] == ""  # a variant without the grid
    page = (study["out"] / "summary.html").read_text()
    assert page.count("<tr>") == 1 + len(VARIANTS) and "energy_balance_error" in page


def test_rerun_runs_nothing_then_one_changed_variant_exactly(study):
    out = study["out"]
    before = {n: (Path(r["output"]) / "report.json").stat().st_mtime_ns for n, r in index_rows(out).items()}
    t = time.monotonic()
    again = batch(study["path"], "--json")
    assert again.returncode == 0, again.stderr
    res = json.loads(again.stdout)
    assert (res["run"], res["skipped"]) == (0, N)
    assert "LocalCluster" not in again.stderr  # no cluster for no work
    assert time.monotonic() - t < study["seconds"]
    # change one variant: only it runs
    data = yaml.safe_load(study["path"].read_text())
    data["variants"][3]["set"]["outputs.lightmaps.texels_per_metre"] = 20.0
    study["path"].write_text(yaml.safe_dump(data, sort_keys=False))
    third = batch(study["path"], "--json")
    assert third.returncode == 0, third.stderr
    res = json.loads(third.stdout)
    assert (res["run"], res["done"], res["skipped"]) == (1, 1, N - 1)
    rows = index_rows(out)
    after = {n: (Path(r["output"]) / "report.json").stat().st_mtime_ns for n, r in rows.items()}
    assert [n for n in before if before[n] != after[n]] == ["lm16"]
    assert rows["lm16"]["runs"] == 2 and rows["ref"]["runs"] == 1
    assert json.loads((out / "jobs" / "lm16" / "report.json").read_text())["content_key"] == rows["lm16"]["key"]
    # an output removed by hand: that job runs again, although the index says done
    import shutil

    shutil.rmtree(out / "jobs" / "ref")
    fourth = batch(study["path"], "--json")
    assert json.loads(fourth.stdout)["run"] == 1 and (out / "jobs" / "ref" / "report.json").exists()


# ---------------------------------------------------------------------------------------------
# bad studies: errors before any job starts
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("variants, words", [
    ([{"name": "a"}, {"name": "b", "set": {"meshing.max_patch_aera": 0.02}}],
     ["variants[1]", "job 'b'", "--set meshing.max_patch_aera=0.02", "unknown key", "did you mean 'max_patch_area'"]),
    ([{"name": "a", "set": {"meshing": {"max_patch_area": -1}}}],
     ["variants[0]", "--set meshing.max_patch_area=-1", "greater than 0"]),
    ([{"name": "a", "colour": 1}], ["variants[0].colour", "unknown study key"]),
    ([{"name": "a"}, {"name": "a"}], ["two jobs are named 'a'"]),
    ([{"name": "a/b"}], ["job name 'a/b'"]),
])
def test_bad_studies_fail_before_any_job(tmp_path, variants, words):
    path = write_study(tmp_path, variants)
    proc = batch(path)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert err.startswith(f"hirad: error: {path}:"), err
    line = int(err.split(f"{path}:")[1].split(":")[0])
    assert line > 0
    for w in words:
        assert w in err, err
    assert not (tmp_path / "out").exists()  # nothing ran, no index


def test_unreachable_scheduler(tmp_path):
    path = write_study(tmp_path, [{"name": "a"}])
    t = time.monotonic()
    proc = batch(path, "--scheduler", "tcp://127.0.0.1:9")
    assert proc.returncode == 2, proc.stderr
    assert "cannot reach the Dask scheduler" in proc.stderr and "tcp://127.0.0.1:9" in proc.stderr
    assert time.monotonic() - t < 60
    assert not (tmp_path / "out" / "study" / "jobs").exists()
    rows = index_rows(tmp_path / "out" / "study")
    assert [r["status"] for r in rows.values()] == ["pending"]


def test_failing_job_is_retried_marked_failed_and_the_batch_carries_on(tmp_path):
    path = write_study(tmp_path, [{"name": "good"},
                                  {"name": "bad", "set": {"outputs.preview": {"enabled": True, "camera": "/NoSuch"}}}],
                       retries=1)
    proc = batch(path, "--progress", "jsonl")
    assert proc.returncode == 5, proc.stderr
    rows = index_rows(tmp_path / "out" / "study")
    assert rows["good"]["status"] == "done"
    bad = rows["bad"]
    assert bad["status"] == "failed" and bad["done_key"] is None
    assert bad["attempts"] == 2 and bad["exit_code"] == 4
    assert "/NoSuch" in bad["error"]
    assert not (tmp_path / "out" / "study" / "jobs" / "bad").exists()
    events = [json.loads(l) for l in proc.stderr.splitlines() if l.startswith("{")]
    assert {e["event"] for e in events} >= {"plan", "cluster", "job"}
    assert all("elapsed" in e for e in events)
    # a rerun retries the failed job only
    again = batch(path, "--json")
    assert again.returncode == 5 and json.loads(again.stdout)["run"] == 1


# ---------------------------------------------------------------------------------------------
# a worker killed with kill -9 during a job; SIGTERM to the batch
# ---------------------------------------------------------------------------------------------

SLOW = {**BASE, "meshing": {"max_patch_area": 0.0025, "max_edge_length": 0.05}}


def _bake_processes(marker: str) -> list[tuple[int, int]]:
    """(pid, parent pid) of the running bakes whose command line holds `marker`."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().split(b"\0")
            stat = (d / "stat").read_text()
        except OSError:
            continue
        text = b" ".join(cmd).decode(errors="replace")
        if "hirad.cli bake" in text and marker in text:
            out.append((int(d.name), int(stat.rsplit(")", 1)[1].split()[1])))
    return out


def _wait_for_bakes(marker: str, proc: subprocess.Popen, n: int = 1, timeout: float = 120):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        found = _bake_processes(marker)
        if len(found) >= n:
            return found
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.1)
    raise AssertionError("no bake started")


def _partials(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if ".partial-" in p.name]


def test_worker_killed_mid_job_is_retried_with_the_same_bits(tmp_path):
    path = write_study(tmp_path, [{"name": "k1"}, {"name": "k2", "set": {"meshing": COARSE}}], base=SLOW)
    out = tmp_path / "out" / "study"
    proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "batch", str(path), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    bakes = _wait_for_bakes(str(out / "jobs" / "k1"), proc)
    time.sleep(1.5)  # well into the bake
    bake_pid, worker_pid = bakes[0]
    os.kill(worker_pid, signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr[-3000:]
    rows = index_rows(out)
    assert rows["k1"]["status"] == "done" and rows["k2"]["status"] == "done"
    assert rows["k1"]["attempts"] == 2, rows["k1"]  # the index shows the retry
    assert rows["k2"]["attempts"] == 1
    # the killed attempt's bake went with its worker, and left nothing behind
    for _ in range(50):
        if not Path(f"/proc/{bake_pid}").exists():
            break
        time.sleep(0.1)
    assert not Path(f"/proc/{bake_pid}").exists() or \
        Path(f"/proc/{bake_pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    assert _partials(tmp_path) == []
    # the same bits as a clean bake of the variant
    clean = tmp_path / "clean"
    bake(tmp_path / "base.yaml", overrides=[f"output={clean}", "threads=2"])
    assert_same_primvars(out / "jobs" / "k1" / "solution.usda", clean / "solution.usda")


def test_sigterm_cancels_the_batch_cleanly(tmp_path):
    path = write_study(tmp_path, [{"name": f"s{i}", "set": {"seed": i + 1}} for i in range(4)], base=SLOW)
    out = tmp_path / "out" / "study"
    proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "batch", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    bakes = _wait_for_bakes(str(out / "jobs"), proc, n=2)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-3000:]
    assert "cancelling" in err
    for pid, _ in bakes:  # the bakes were stopped, not left running
        for _ in range(100):
            if not Path(f"/proc/{pid}").exists():
                break
            time.sleep(0.1)
        assert not Path(f"/proc/{pid}").exists(), f"bake {pid} still runs"
    assert _partials(tmp_path) == []
    rows = index_rows(out)
    assert all(r["status"] in ("cancelled", "done") for r in rows.values()), rows
    assert any(r["status"] == "cancelled" for r in rows.values())
    for r in rows.values():
        if r["status"] == "cancelled":
            assert not Path(r["output"]).exists() and r["done_key"] is None
    st = json.loads(batch("status", path, "--json").stdout)
    assert st["batches"][-1]["status"] == "cancelled"
    assert not list(out.glob(".cancel-*"))


# ---------------------------------------------------------------------------------------------
# share_links: out-of-core jobs of one geometry and refinement share one link store
# ---------------------------------------------------------------------------------------------

OOC = {"scene": str(CORNELL), "method": "hierarchical",
       "hierarchy": {"epsilon": 1e-3, "min_area": 0.002, "samples": 4, "max_rounds": 3},
       "solver": {"method": "block_southwell", "tolerance": 1e-4}, "links": {"group_faces": 4},
       "outputs": {"preview": {"enabled": False}, "lightmaps": {"max_size": 256, "texels_per_metre": 32.0}}}


def test_share_links_computes_links_once_per_geometry(tmp_path):
    variants = [{"name": "a"},
                {"name": "b", "set": {"outputs.lightmaps.texels_per_metre": 16.0}},
                {"name": "c", "set": {"outputs.lightmaps.enabled": False}},
                {"name": "other", "set": {"hierarchy.epsilon": 2e-3}}]
    path = write_study(tmp_path, variants, base=OOC, share_links=True)
    proc = batch(path, "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = tmp_path / "out" / "study"
    reps = {n: json.loads((out / "jobs" / n / "report.json").read_text()) for n in ("a", "b", "c", "other")}
    assert reps["a"]["links"]["reused"] is False and reps["a"]["links"]["form_factors_computed"] > 0
    assert reps["other"]["links"]["reused"] is False
    for n in ("b", "c"):
        assert reps[n]["links"]["reused"] is True and reps[n]["links"]["form_factors_computed"] == 0
        assert reps[n]["links"]["store"] == reps["a"]["links"]["store"]
    assert reps["other"]["links"]["store"] != reps["a"]["links"]["store"]
    assert len(list((out / "links").iterdir())) == 2
    # the links' owner is the bake alone, bit for bit; a reusing job solves the same links
    alone = tmp_path / "alone"
    bake(tmp_path / "base.yaml", overrides=[f"output={alone}"])
    assert_same_primvars(out / "jobs" / "a" / "solution.usda", alone / "solution.usda")
    pa, pb = primvars(out / "jobs" / "a" / "solution.usda"), primvars(out / "jobs" / "b" / "solution.usda")
    radiance = [k for k in pa if k.endswith("primvars:hirad:radiance")]
    assert radiance and all(pa[k].tobytes() == pb[k].tobytes() for k in radiance)
    # rerun: nothing; one reusing variant changed: only it runs, on the stored links
    assert json.loads(batch(path, "--json").stdout)["run"] == 0
    data = yaml.safe_load(path.read_text())
    data["variants"][1]["set"]["outputs.lightmaps.texels_per_metre"] = 20.0
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    again = batch(path, "--json")
    assert again.returncode == 0 and json.loads(again.stdout)["run"] == 1
    rows = index_rows(out)
    assert rows["b"]["runs"] == 2 and rows["a"]["runs"] == 1
    assert json.loads((out / "jobs" / "b" / "report.json").read_text())["links"]["reused"] is True


def test_existing_cluster_through_scheduler_address(tmp_path):
    """`--scheduler tcp://...` on a LocalCluster this test starts (2 worker processes): the jobs
    run on its workers, the cluster outlives the batch."""
    import logging

    from distributed import Client, LocalCluster

    path = write_study(tmp_path, [{"name": "x"}, {"name": "y", "set": {"seed": 9}}])
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        proc = batch(path, "--scheduler", cluster.scheduler_address, "--json")
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert cluster.scheduler_address in proc.stderr
        rows = index_rows(tmp_path / "out" / "study")
        assert {r["status"] for r in rows.values()} == {"done"}
        workers = set(client.scheduler_info()["workers"])
        assert len(workers) == 2 and {r["worker"] for r in rows.values()} <= workers
    assert json.loads(batch(path, "--json").stdout)["run"] == 0


def test_batch_killed_with_kill_9_leaves_a_consistent_index(tmp_path):
    path = write_study(tmp_path, [{"name": f"d{i}", "set": {"seed": i + 1}} for i in range(3)], base=SLOW)
    out = tmp_path / "out" / "study"
    proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "batch", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    bakes = _wait_for_bakes(str(out / "jobs"), proc, n=2)
    time.sleep(1.0)
    proc.kill()
    proc.communicate(timeout=60)
    for pid, _ in bakes:  # the workers, and their bakes, go with the batch
        for _ in range(200):
            if not Path(f"/proc/{pid}").exists():
                break
            time.sleep(0.1)
        assert not Path(f"/proc/{pid}").exists(), f"bake {pid} outlived its batch"
    assert _partials(tmp_path) == []
    con = sqlite3.connect(str(out / "study.sqlite"))
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()
    st = json.loads(batch("status", path, "--json").stdout)
    for j in st["jobs"]:
        assert j["status"] in ("done", "interrupted"), j
        if j["status"] == "done":
            assert (Path(j["output"]) / "report.json").exists()
        else:
            assert not Path(j["output"]).exists()
    interrupted = [j["name"] for j in st["jobs"] if j["status"] == "interrupted"]
    assert interrupted and sum(j["attempts"] >= 1 for j in st["jobs"] if j["status"] == "interrupted") >= 2
    again = batch(path, "--json")
    assert again.returncode == 0, again.stderr[-2000:]
    assert json.loads(again.stdout)["run"] == len(interrupted)
    assert {j["status"] for j in json.loads(batch("status", path, "--json").stdout)["jobs"]} == {"done"}
