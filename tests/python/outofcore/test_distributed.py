"""Distributed link generation (pipeline/engine/rounds.h, hirad.batch.links): each refinement's
source groups refined by workers on their own copies of the hierarchy, merged by the driver in
group order. The claim is exact: the link store (every chunk and manifest byte) and the solution
are the single-machine bake's, bit for bit, whatever the ranges, the workers and their number.

Engine-level tests play the workers in this process (another Engine of the same scene calls
refine_groups); the end-to-end test runs `hirad bake --scheduler` on a real 2-worker Dask
LocalCluster of worker processes."""

from __future__ import annotations

import hashlib
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from hirad_e2e_helpers import CORNELL, run_cli, write_config

from hirad import _engine, usd
from hirad.engine import build_engine

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "photometry"))
import cie171_scenes as cie  # noqa: E402

H = _engine.HierarchyOptions(epsilon=1e-5, min_area=4e-4, samples=16, seed=1, max_rounds=4)
S = _engine.SolveOptions(tolerance=1e-6, max_iterations=100000)


def ooc(store, group_faces=4):
    return _engine.OutOfCoreOptions(store=str(store), group_faces=group_faces)


def store_digest(store: Path) -> dict:
    """Every file of every round directory the store kept, by name: what a reader trusts."""
    return {str(p.relative_to(store)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(store.glob("round-*/*"))}


def model(luminaire=False, reflectance_scale=1.0):
    scene = usd.read_scene(CORNELL)
    if reflectance_scale != 1.0:
        scene.face_reflectance = scene.face_reflectance * reflectance_scale
    m = build_engine(scene)
    if luminaire:
        # a downward cosine spot under the ceiling: the hierarchy is split for it before linking
        m.set_luminaires([cie.lambertian_point([0.0, 1.7, 0.0], 30.0)])
    return m


def splitter(worker, store, cuts_of):
    """A refine_groups hook that plays the workers: ranges cut by cuts_of(groups)."""
    calls = []

    def hook(round_, groups):
        cuts = cuts_of(groups)
        for b, e in zip(cuts, cuts[1:]):
            log = worker.refine_groups(H, ooc(store), round_, b, e)
            calls.append((round_, b, e, log.subdivisions, sum(log.group_links)))
    return hook, calls


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    store = tmp_path_factory.mktemp("single") / "links"
    r = model().solve_out_of_core(H, S, ooc(store))
    return store, r


@pytest.mark.parametrize("cuts_of", [lambda n: [0, n], lambda n: [0, 1, n // 2, n], lambda n: list(range(n + 1))],
                         ids=["one range", "three ranges", "one group each"])
def test_merged_store_and_solution_are_the_single_machine_bits(single, tmp_path, cuts_of):
    store1, r1 = single
    store = tmp_path / "links"
    worker = model()
    hook, calls = splitter(worker, store, cuts_of)
    r = model().solve_out_of_core(H, S, ooc(store), None, hook)
    assert r1.source_groups >= 4 and r.rounds == r1.rounds and r.rounds >= 2
    # every refinement went out, and the workers made new elements of their own numbering
    assert sorted({c[0] for c in calls}) == list(range(1, r.rounds + 1)) or r.settled
    assert sum(c[3] for c in calls) > 0
    assert len(r.merge_seconds) == len({c[0] for c in calls})
    # the same store, byte for byte, and the same solution
    d1, d = store_digest(store1), store_digest(store)
    assert d1 and d == d1
    assert (r.links, r.nodes, r.elements) == (r1.links, r1.nodes, r1.elements)
    assert np.array_equal(np.asarray(r.radiosity), np.asarray(r1.radiosity))
    assert np.array_equal(np.asarray(r.irradiance), np.asarray(r1.irradiance))
    # the spills were merged and removed
    assert not list(store.glob("spill-*"))


def test_luminaire_split_hierarchy_distributes_to_the_same_bits(tmp_path):
    r1 = model(luminaire=True).solve_out_of_core(H, S, ooc(tmp_path / "a"))
    hook, calls = splitter(model(luminaire=True), tmp_path / "b", lambda n: [0, n // 3, n])
    r = model(luminaire=True).solve_out_of_core(H, S, ooc(tmp_path / "b"), None, hook)
    assert calls
    assert store_digest(tmp_path / "a") == store_digest(tmp_path / "b")
    assert np.array_equal(np.asarray(r.radiosity), np.asarray(r1.radiosity))


def test_a_group_no_worker_refined_is_an_error(tmp_path):
    worker = model()

    def partial(round_, groups):
        worker.refine_groups(H, ooc(tmp_path / "s"), round_, 0, groups - 1)

    with pytest.raises(RuntimeError, match=r"were not refined by any worker"):
        model().solve_out_of_core(H, S, ooc(tmp_path / "s"), None, partial)


def test_a_worker_with_another_scene_is_caught_at_the_merge(tmp_path):
    other = model(reflectance_scale=0.5)  # different materials: another run's fingerprint

    def hook(round_, groups):
        other.refine_groups(H, ooc(tmp_path / "s"), round_, 0, groups)

    with pytest.raises(RuntimeError, match=r"another scene or config"):
        model().solve_out_of_core(H, S, ooc(tmp_path / "s"), None, hook)


def test_the_hooks_own_error_reaches_the_caller(tmp_path):
    class Unreachable(Exception):
        pass

    def hook(round_, groups):
        raise Unreachable(f"cluster gone in round {round_}")

    with pytest.raises(Unreachable, match="round 1"):
        model().solve_out_of_core(H, S, ooc(tmp_path / "s"), None, hook)


def test_refine_groups_refuses_a_round_before_its_state_exists(tmp_path):
    with pytest.raises(RuntimeError, match=r"refined-1: missing"):
        model().refine_groups(H, ooc(tmp_path / "s"), 2, 0, 1)
    with pytest.raises(ValueError, match=r"not a range"):
        model().refine_groups(H, ooc(tmp_path / "s"), 1, 3, 3)


# ---------------------------------------------------------------------------------------------
# end to end: hirad bake --scheduler on a 2-worker LocalCluster
# ---------------------------------------------------------------------------------------------

CONFIG = dict(method="hierarchical", hierarchy={"epsilon": 1e-5, "min_area": 4e-4, "max_rounds": 3},
              solver={"method": "block_southwell", "tolerance": 1e-6}, links={"group_faces": 4},
              outputs={"preview": {"enabled": False}})


def _primvars(out: Path) -> dict:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out / "solution.usda"))
    values = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
            if pv.GetPrimvarName().startswith("hirad:") and pv.Get() is not None:
                values[f"{prim.GetPath()}.{pv.GetPrimvarName()}"] = np.asarray(pv.Get())
    assert values, "no hirad primvars in the solution"
    return values


@pytest.fixture(scope="module")
def cluster():
    import logging

    from distributed import LocalCluster

    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                     silence_logs=logging.ERROR)
    yield c
    c.close()


def test_bake_on_a_two_worker_cluster_equals_the_single_process_bake(tmp_path, cluster):
    import json

    a = write_config(tmp_path / "a.yaml", CORNELL, tmp_path / "a", **CONFIG)
    b = write_config(tmp_path / "b.yaml", CORNELL, tmp_path / "b", **CONFIG)
    r = run_cli("bake", a, "--quiet")
    assert r.returncode == 0, r.stderr
    r = run_cli("bake", b, "--quiet", "--scheduler", cluster.scheduler_address)
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "b" / "report.json").read_text())
    dist = report["links"]["distributed"]
    # both workers took part, every round's ranges tile the groups
    assert len({t["worker"] for t in dist["tasks"]}) == 2
    groups = report["links"]["source_groups"]
    for rnd in {t["round"] for t in dist["tasks"]}:
        spans = sorted((t["begin"], t["end"]) for t in dist["tasks"] if t["round"] == rnd)
        assert spans[0][0] == 0 and spans[-1][1] == groups
        assert all(x[1] == y[0] for x, y in zip(spans, spans[1:]))
    # the same link store (manifest and chunk checksums) and the same primvars, bit for bit
    assert store_digest(tmp_path / "a.links") == store_digest(tmp_path / "b.links") != {}
    pa, pb = _primvars(tmp_path / "a"), _primvars(tmp_path / "b")
    assert pa.keys() == pb.keys()
    for k in pa:
        assert np.array_equal(pa[k], pb[k]), k


def test_unreachable_scheduler_is_a_usage_error_before_anything_is_made(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", **CONFIG)
    r = run_cli("bake", cfg, "--quiet", "--scheduler", "tcp://127.0.0.1:9")
    assert r.returncode == 2
    assert "cannot reach the Dask scheduler" in r.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.links").exists()


def test_scheduler_needs_an_out_of_core_bake(tmp_path):
    cfg = write_config(tmp_path / "c.yaml", CORNELL, tmp_path / "out", method="flat")
    r = run_cli("bake", cfg, "--quiet", "--scheduler", "tcp://127.0.0.1:9")
    assert r.returncode == 2 and "out-of-core" in r.stderr
