"""Out-of-core hierarchical radiosity (solver.method: block_southwell): links in the on-disk
store, the streaming block-Southwell solver within a memory budget, checkpoints and resume,
reuse of stored links, and damaged stores. Each result is checked against physics (furnace,
energy balance, linearity in the emission) or bit for bit against the same bake done another
way (budget, threads, memory or disk, interrupted or not)."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import box_faces, make_model, quad
from hirad_e2e_helpers import CORNELL, run_cli, write_config

from hirad import _engine, usd
from hirad.engine import build_engine

ARGS = dict(epsilon=1e-5, min_area=4e-4, samples=16, seed=1, tolerance=1e-6, max_iterations=100000, max_rounds=4)


def cornell_model():
    return build_engine(usd.read_scene(CORNELL))


def solve(model, store="", budget=0, group_faces=1, resume=False, reuse=False, **kw):
    a = dict(ARGS, **kw)
    r = model.solve_out_of_core(
        _engine.HierarchyOptions(epsilon=a["epsilon"], min_area=a["min_area"], samples=a["samples"], seed=a["seed"],
                                 max_rounds=a["max_rounds"]),
        _engine.SolveOptions(tolerance=a["tolerance"], max_iterations=a["max_iterations"]),
        _engine.OutOfCoreOptions(store=str(store), memory_budget=budget, group_faces=group_faces, resume=resume,
                                 reuse_links=reuse))
    model.use_leaves_as_patches()
    return r


@pytest.fixture(scope="module")
def unlimited(tmp_path_factory):
    """The Cornell box out of core with an unlimited budget, links on disk."""
    store = tmp_path_factory.mktemp("ooc") / "links"
    return store, solve(cornell_model(), store)


def test_same_bits_whatever_the_budget_the_threads_and_where_links_live(tmp_path):
    # Finer than ARGS: enough links (~0.5 M) that the budget can be far below their size.
    fine = dict(epsilon=3e-6)
    store = tmp_path / "unlimited"
    ref = solve(cornell_model(), store, **fine)
    s = ref.streaming
    decoded = s.decoded_bytes
    assert decoded >= 6 * ref.links  # a coupling and a receiver delta per link, at least
    # The smallest budget the solver accepts: its state and the chunks in flight.
    minimum = s.state_bytes + s.chunks_in_flight * s.largest_chunk_bytes
    assert s.minimum_budget == minimum
    budget = minimum + decoded // 50
    assert budget < 0.3 * decoded, "the test needs a budget well below the links' size"
    try:
        _engine.set_threads(1)
        small = solve(cornell_model(), tmp_path / "small", budget=budget, **fine)
    finally:
        _engine.set_threads(0)
    memory = solve(cornell_model(), "", **fine)
    for other in (small, memory):
        assert np.array_equal(other.radiosity, ref.radiosity)
        assert np.array_equal(other.irradiance, ref.irradiance)
        assert other.links == ref.links
    # The small budget really streamed: chunks were read again and again.
    chunks = len(list(_final_round(store).glob("chunk-*.hlc")))
    assert chunks >= ref.source_groups
    assert small.streaming.chunk_reads > 2 * chunks
    # Unlimited: every chunk read once, then kept decoded.
    assert ref.streaming.chunk_reads == chunks
    assert small.streaming.resident_bytes_peak + s.state_bytes <= budget
    assert small.streaming.chunks_in_flight >= 2
    # The report's solver history is the last solve's, one residual a shooting round.
    assert ref.streaming.rounds > 0 and ref.iterations == ref.streaming.rounds
    assert len(ref.residual_history) == ref.streaming.rounds


def test_budget_below_the_minimum_is_a_clear_error(tmp_path):
    with pytest.raises(RuntimeError, match="memory_budget of 1000 bytes is below what the solver needs"):
        solve(cornell_model(), tmp_path / "links", budget=1000)


def test_agrees_with_the_in_memory_hierarchical_solve(unlimited):
    # Different link sets (out of core, links start at the source groups, not the root), the
    # same physics: area-weighted mean radiosity and energy balance.
    _, ooc = unlimited
    m = cornell_model()
    jac = m.solve_hierarchical(_engine.HierarchyOptions(epsilon=ARGS["epsilon"], min_area=ARGS["min_area"],
                                                        samples=ARGS["samples"], seed=1, max_rounds=ARGS["max_rounds"]),
                               _engine.SolveOptions(method="jacobi", tolerance=1e-6, max_iterations=100000))
    m.use_leaves_as_patches()
    assert ooc.converged
    # Weighted by area (the leaves differ): the power the surfaces reflect.
    m_ooc = cornell_model()
    solve(m_ooc, "")  # the same links in memory: the same leaves as `ooc`
    a_ooc, a_jac = m_ooc.patch_arrays().area, m.patch_arrays().area
    assert len(a_ooc) == len(ooc.radiosity) and len(a_jac) == len(jac.radiosity)
    mean_ooc = (a_ooc[:, None] * ooc.radiosity).sum(axis=0) / a_ooc.sum()
    mean_jac = (a_jac[:, None] * jac.radiosity).sum(axis=0) / a_jac.sum()
    np.testing.assert_allclose(mean_ooc, mean_jac, rtol=2e-3)


@pytest.mark.parametrize("rho", [0.5, 0.9])
def test_furnace(rho, tmp_path):
    m = make_model(box_faces(), rho, 1.0)
    r = solve(m, tmp_path / "links", epsilon={0.5: 2e-5, 0.9: 1e-4}[rho], min_area=0.0155, samples=144,
              tolerance=1e-9)
    assert r.converged
    err = np.abs(r.radiosity * (1 - rho) - 1)
    assert err.max() < 0.01, f"rho {rho}: max relative error {err.max():.4f}"


def test_reuse_links_for_new_emission_computes_no_form_factor_and_is_linear(unlimited, tmp_path):
    # B is linear in E: doubling every emitter doubles every radiosity (to the solver's
    # tolerance: the bake's last solve started from the previous round's solution, this one
    # from the emission).
    store, ref = unlimited
    s = usd.read_scene(CORNELL)
    m2 = build_engine(dataclasses.replace(s, face_emission=2 * s.face_emission))
    r2 = solve(m2, store, reuse=True)
    assert r2.reused_links and r2.link_estimates == 0 and r2.links == ref.links
    np.testing.assert_allclose(r2.radiosity, 2 * ref.radiosity, rtol=1e-4, atol=1e-9)
    # Reflectance too: a new solve on the same links, converged.
    m3 = build_engine(dataclasses.replace(s, face_reflectance=0.5 * s.face_reflectance))
    r3 = solve(m3, store, reuse=True)
    assert r3.reused_links and r3.link_estimates == 0 and r3.converged
    assert r3.radiosity.mean() < ref.radiosity.mean()


def test_reuse_without_a_store_of_this_scene_is_refused(tmp_path):
    with pytest.raises(RuntimeError, match="no final links of this geometry"):
        solve(cornell_model(), tmp_path / "links", reuse=True)
    # Another refinement setting: the stored links are not this bake's.
    solve(cornell_model(), tmp_path / "links")
    with pytest.raises(RuntimeError, match="no final links of this geometry"):
        solve(cornell_model(), tmp_path / "links", reuse=True, epsilon=1e-4)


def _final_round(store: Path) -> Path:
    rounds = sorted(store.glob("round-*"), key=lambda p: int(p.name.split("-")[1]))
    return rounds[-1]


def test_link_generation_holds_a_bounded_part_of_the_links(tmp_path):
    # The whole Cornell box as one source group: link generation takes the links to judge a
    # batch at a time, depth first, and hands the kept ones to the store a part at a time,
    # so it never holds the group's links at once (it did: all of them, here).
    store = tmp_path / "links"
    r = solve(cornell_model(), store, epsilon=3e-6, group_faces=32)
    assert r.source_groups == 1 and r.links > 400_000
    assert r.peak_refine_links < r.links / 3
    # The group's links are parts of 16,384 (the last one shorter), the same as in memory.
    chunks = sorted(_final_round(store).glob("chunk-*.hlc"))
    assert len(chunks) == -(-r.links // 16384)
    memory = solve(cornell_model(), "", epsilon=3e-6, group_faces=32)
    assert np.array_equal(memory.radiosity, r.radiosity)


@pytest.mark.parametrize("damage", ["flip", "truncate", "manifest"])
def test_damaged_store_is_detected_with_the_file_named(damage, tmp_path):
    store = tmp_path / "links"
    solve(cornell_model(), store)
    final = _final_round(store)
    chunk = sorted(final.glob("chunk-*.hlc"))[3]
    if damage == "flip":
        data = bytearray(chunk.read_bytes())
        data[len(data) // 2] ^= 0x10
        chunk.write_bytes(bytes(data))
        expect = f"{chunk}: chunk .*checksum"
    elif damage == "truncate":
        chunk.write_bytes(chunk.read_bytes()[:-7])
        expect = f"{chunk}: chunk .*truncated"
    else:
        (final / "manifest").unlink()
        expect = "never committed"
    with pytest.raises(RuntimeError, match=expect):
        solve(cornell_model(), store, reuse=True)


def test_cli_damaged_store_exits_non_zero_naming_the_chunk(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 3e-5, "min_area": 4e-4},
                       solver={"method": "block_southwell"}, links={"group_faces": 2},
                       outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}})
    assert run_cli("bake", cfg, "--quiet").returncode == 0
    chunk = sorted(_final_round(tmp_path / "out.links").glob("chunk-*.hlc"))[0]
    data = bytearray(chunk.read_bytes())
    data[100] ^= 1
    chunk.write_bytes(bytes(data))
    before = sorted(p.name for p in tmp_path.iterdir())
    r = run_cli("bake", cfg, "--quiet", "--reuse-links")
    assert r.returncode != 0
    assert chunk.name in r.stderr and "checksum" in r.stderr, r.stderr
    # The earlier output is still there, unchanged in name; no staging directory is left.
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_linking_prints_its_progress_by_source_group(tmp_path):
    # A farm's log must show what an out-of-core bake is doing while it links (the country
    # kitchen's first round linked for over an hour printing "iteration 0" only).
    cfg = write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", method="hierarchical",
                       hierarchy={"epsilon": 3e-5, "min_area": 1e-3, "max_rounds": 2},
                       solver={"method": "block_southwell"}, links={"group_faces": 1},
                       outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}})
    env = {**os.environ, "HIRAD_PROGRESS_SECONDS": "0"}
    proc = subprocess.run([sys.executable, "-m", "hirad.cli", "bake", str(cfg)], env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    groups = {}
    for line in proc.stderr.splitlines():
        if ": linking, " in line:
            round_ = int(line.split("round ")[1].split(":")[0])
            done, total = line.split("linking, ")[1].split(" source groups")[0].split("/")
            links = int(line.split("groups, ")[1].split(" links")[0].replace(",", ""))
            groups.setdefault(round_, []).append((int(done), int(total), links))
    # (Polled every 100 ms: a round that links faster may show no line.)
    assert groups and set(groups) <= {1, 2}, proc.stderr
    report = __import__("json").loads((tmp_path / "out" / "report.json").read_text())
    for round_, seen in groups.items():
        totals = {t for _, t, _ in seen}
        assert len(totals) == 1 and totals.pop() > 1
        assert [d for d, _, _ in seen] == sorted(d for d, _, _ in seen)  # groups counted up
        assert [n for _, _, n in seen] == sorted(n for _, _, n in seen)  # links never counted down
    if 2 in groups:
        assert max(n for _, _, n in groups[2]) <= report["counts"]["links"]  # the last round is the one kept
    assert any("round 2, " in ln and " links, iteration " in ln for ln in proc.stderr.splitlines())


# ---------------------------------------------------------------------------------------------
# kill -9 and resume
# ---------------------------------------------------------------------------------------------

KILL_CONFIG = dict(method="hierarchical", hierarchy={"epsilon": 1e-5, "min_area": 2e-4, "max_rounds": 3},
                   solver={"method": "block_southwell", "tolerance": 1e-11},
                   links={"group_faces": 1, "memory_budget": "12MB", "checkpoint_seconds": 0.0001},
                   outputs={"preview": {"enabled": False}, "lightmaps": {"enabled": False}})


def _patch_radiance(out: Path) -> np.ndarray:
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(out / "solution.usda"))
    values = []
    for prim in stage.Traverse():
        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("hirad:patchRadiance") if prim.IsA(UsdGeom.Mesh) else None
        if pv and pv.Get() is not None:
            values.append(np.asarray(pv.Get(), dtype=np.float64))
    assert values, "no hirad:patchRadiance primvar in the solution"
    return np.concatenate(values)


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("clean")
    cfg = write_config(tmp / "c.yaml", CORNELL, tmp / "out", **KILL_CONFIG)
    r = run_cli("bake", cfg, "--quiet")
    assert r.returncode == 0, r.stderr
    return _patch_radiance(tmp / "out")


def _kill_when(cfg: Path, ready, timeout=120.0) -> None:
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, "-m", "hirad.cli", "bake", str(cfg), "--quiet"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t0 = time.time()
    try:
        while not ready():
            assert proc.poll() is None, "the bake finished before it could be killed"
            assert time.time() - t0 < timeout
            time.sleep(0.002)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()


@pytest.mark.parametrize("when", ["link generation", "solve"])
def test_kill_9_then_resume_gives_the_clean_result(when, clean_run, tmp_path):
    cfg = write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", **KILL_CONFIG)
    store = tmp_path / "out.links"
    if when == "link generation":
        # During round 2's refinement: round 1 solved, round 2's chunks being written.
        ready = lambda: (store / "round-2").exists() and any((store / "round-2").glob("chunk-*"))
    else:
        # During round 2's solve: its links committed, its checkpoint written, not yet solved.
        ready = lambda: (store / "refined-2").exists() and (store / "checkpoint").exists()
    _kill_when(cfg, ready)
    assert not (tmp_path / "out").exists() and not (store / "final").exists()
    r = run_cli("bake", cfg, "--quiet", "--json", "--resume")
    assert r.returncode == 0, r.stderr
    import json
    report = json.loads(r.stdout)
    assert report["links"]["resumed_from_round"] >= 1
    if when == "solve":
        assert report["links"]["last_solve"]["resumed"] or report["links"]["resumed_from_round"] >= 2
    assert np.array_equal(_patch_radiance(tmp_path / "out"), clean_run)


# ---------------------------------------------------------------------------------------------
# resume in every phase, and state files that say what they belong to
# ---------------------------------------------------------------------------------------------


def _finished_store(tmp_path: Path, name: str, emission_scale: float = 1.0):
    """A finished out-of-core run's store and its radiosity (emission scaled for a foreign run)."""
    store = tmp_path / name
    scene = usd.read_scene(CORNELL)
    if emission_scale != 1.0:
        scene.face_emission = scene.face_emission * emission_scale
    r = solve(build_engine(scene), store)
    rounds = sorted(int(p.name.split("-")[1]) for p in store.glob("solved-*"))
    assert len(rounds) == 1, rounds
    return store, np.asarray(r.radiosity), rounds[0]


def test_resume_killed_during_a_solve_before_any_checkpoint_gives_the_same_bits(tmp_path):
    """The phase between refined-k and solved-k with no checkpoint yet: round k is solved again,
    from the emission as every round is, and must give exactly the uninterrupted run's values."""
    store, clean, last = _finished_store(tmp_path, "links")
    # what a kill at that moment leaves: round `last` refined and committed, not solved, not final
    (store / "final").unlink()
    (store / f"solved-{last}").unlink()
    assert not (store / "checkpoint").exists()
    resumed = solve(cornell_model(), store, resume=True)
    assert resumed.resumed_from_round == last
    assert np.array_equal(np.asarray(resumed.radiosity), clean)


def test_resume_refuses_a_state_file_of_another_run(tmp_path):
    store, _, last = _finished_store(tmp_path, "links")
    other, _, other_last = _finished_store(tmp_path, "other", emission_scale=2.0)
    assert other_last == last  # the same links: only the materials differ
    (store / "final").unlink()
    (store / f"solved-{last}").write_bytes((other / f"solved-{last}").read_bytes())
    with pytest.raises(RuntimeError, match=rf"solved-{last}: belongs to another run"):
        solve(cornell_model(), store, resume=True)


def test_resume_refuses_a_renamed_state_file(tmp_path):
    store, _, last = _finished_store(tmp_path, "links")
    (store / "final").unlink()
    # round `last`'s refinement state put where its solution belongs
    (store / f"solved-{last}").write_bytes((store / f"refined-{last}").read_bytes())
    with pytest.raises(RuntimeError, match=rf"solved-{last}: holds the refined state of round {last}"):
        solve(cornell_model(), store, resume=True)


def test_clusters_that_receive_agree_out_of_core_and_in_memory(tmp_path):
    # A 2 m room whose floor is 12 x 12 tiles, lit by its ceiling: with hierarchy.
    # cluster_receivers the floor's tiles take light through links that end on clusters. The
    # streaming solve (links on disk) and Jacobi in memory are different link sets of the same
    # physics: the same area-weighted mean radiosity, both energy balances closed.
    faces = box_faces(2, 2, 2, omit=("y0",))
    n = 12
    for i in range(n):
        for j in range(n):
            faces.append(quad([2 * i / n, 0, 2 * j / n], [0, 0, 2 / n], [2 / n, 0, 0]))
    ceiling = [k for k, f in enumerate(faces) if np.all(np.asarray(f)[:, 1] == 2)]
    assert len(ceiling) == 1 and len(faces) == 5 + n * n
    emission = np.zeros(len(faces))
    emission[ceiling[0]] = 10.0
    ho = _engine.HierarchyOptions(epsilon=1e-4, min_area=0.05, samples=16, seed=1, max_rounds=3,
                                  cluster_receivers=True)
    m_mem = make_model(faces, reflectance=0.6, emission=emission)
    mem = m_mem.solve_hierarchical(ho, _engine.SolveOptions(method="jacobi", tolerance=1e-7, max_iterations=100000))
    m_mem.use_leaves_as_patches()
    assert mem.links_on_clusters > 0
    m_ooc = make_model(faces, reflectance=0.6, emission=emission)
    ooc = m_ooc.solve_out_of_core(ho, _engine.SolveOptions(tolerance=1e-7, max_iterations=100000),
                                  _engine.OutOfCoreOptions(store=str(tmp_path / "links"), group_faces=8))
    m_ooc.use_leaves_as_patches()
    assert ooc.converged and mem.converged
    assert ooc.links_on_clusters == -1  # out of core: not counted
    a_mem, a_ooc = m_mem.patch_arrays().area, m_ooc.patch_arrays().area
    mean_mem = (a_mem[:, None] * mem.radiosity).sum(axis=0) / a_mem.sum()
    mean_ooc = (a_ooc[:, None] * ooc.radiosity).sum(axis=0) / a_ooc.sum()
    np.testing.assert_allclose(mean_ooc, mean_mem, rtol=5e-3)
    # The face-by-face solvers refuse such links with a clear message.
    with pytest.raises(ValueError, match="cannot solve links that end on clusters"):
        make_model(faces, reflectance=0.6, emission=emission).solve_hierarchical(
            ho, _engine.SolveOptions(method="southwell", tolerance=1e-6, max_iterations=100000))
