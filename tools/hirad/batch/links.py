"""Distributed link generation for one out-of-core bake: `hirad bake CONFIG --scheduler ADDRESS`.

The engine refines each round's links source group by source group (pipeline/engine/rounds.h).
With a scheduler, every refinement is handed to the Dask cluster instead: the groups are cut
into contiguous ranges, each range is one task, and a task (`refine_part`, on a worker) builds
the engine from the same config, reads the round's starting state from the run store (the
hierarchy as the previous round refined it, and its solution) and writes its range's links and
subdivisions into the store's spill directory. When every range is there, the driver merges
them in group order into the round's chunks and manifest, solves the round itself, and the next
refinement goes out again. The result is bit-identical to a bake on one machine, however many
workers and ranges (the engine's design, tested in tests/python/outofcore/test_distributed.py).

What the workers must share with the driver: the config file, the scene and its layers, the
IES files and grid files it names, and the link store directory, at the same paths (a network
file system); the workers write only under `<store>/spill-<round>/`. A worker that sees other
files (another scene or config) is caught when the driver merges its spill: its fingerprint is
another run's.

A worker killed mid-task loses its task, which the scheduler gives to another worker; a range
whose spill is already complete is not refined again. A task that fails (a bad scene on the
worker, a full disk) is retried `retries` times and then fails the bake, naming the range and
the worker.
"""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path
from typing import Callable

# One engine per worker process, for the bake it is working on: a bake's refinements reuse it
# (the scene is read once per worker, not once per task).
_CACHE: dict = {}


class SchedulerError(Exception):
    """The scheduler cannot be reached (the CLI exits 2, before anything runs)."""


def connect(address: str, timeout: float = 10):
    """A Dask client of the scheduler at `address`."""
    try:
        from distributed import Client
    except ImportError:
        raise SchedulerError("--scheduler needs Dask distributed (pip install distributed; make installs it)") from None
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as e:
        raise SchedulerError(f"--scheduler {address}: cannot reach the Dask scheduler ({e})") from None


def _engine_for(spec: dict):
    from ..bake import read_inputs
    from ..config import load_config
    from ..engine import build_engine

    key = (spec["bake"], spec["config"], tuple(spec["overrides"]))
    if key not in _CACHE:
        _CACHE.clear()
        cfg = load_config(spec["config"], spec["overrides"])
        scene, specs = read_inputs(cfg)
        model = build_engine(scene)
        if specs:
            model.set_luminaires([s.to_engine() for s in specs])
        _CACHE[key] = (cfg, model)
    return _CACHE[key]


def refine_part(spec: dict) -> dict:
    """One task, on a worker: round spec['round']'s refinement of groups [begin, end)."""
    from .. import _engine
    from ..bake import hierarchy_options, out_of_core_options

    t0 = time.perf_counter()
    cfg, model = _engine_for(spec)
    loaded = time.perf_counter() - t0
    _engine.set_threads(spec["threads"])
    t1 = time.perf_counter()
    log = model.refine_groups(hierarchy_options(cfg), out_of_core_options(cfg), spec["round"], spec["begin"],
                              spec["end"])
    try:
        from distributed import get_worker

        worker = get_worker().address
    except Exception:
        worker = f"pid {os.getpid()}"
    return {"round": spec["round"], "begin": spec["begin"], "end": spec["end"], "worker": worker,
            "load_seconds": round(loaded, 4), "seconds": round(time.perf_counter() - t1, 4),
            "group_seconds": list(log.group_seconds), "group_links": list(log.group_links),
            "link_estimates": log.link_estimates, "subdivisions": log.subdivisions}


class DistributedLinks:
    """The engine's refine_groups hook: each refinement's groups as Dask tasks.

    `ranges_per_thread` ranges are made per worker thread of the cluster (more ranges balance
    the load; each costs one engine build per worker and bake). `threads` is the engine's thread
    count inside each task (0: all cores of the worker)."""

    def __init__(self, client, config: Path, overrides: tuple[str, ...] = (), *, threads: int = 1,
                 ranges_per_thread: int = 2, retries: int = 2, on_event: Callable[[dict], None] | None = None):
        self.client, self.config, self.overrides = client, str(Path(config).absolute()), tuple(overrides)
        self.threads, self.ranges_per_thread, self.retries = threads, ranges_per_thread, retries
        self.on_event = on_event or (lambda e: None)
        self.bake = uuid.uuid4().hex[:12]
        self.tasks: list[dict] = []
        self.round_seconds: list[float] = []

    def workers(self) -> int:
        return max(1, sum(self.client.nthreads().values()))

    def ranges(self, groups: int) -> list[tuple[int, int]]:
        n = max(1, min(groups, self.workers() * self.ranges_per_thread))
        cuts = [groups * k // n for k in range(n + 1)]
        return [(b, e) for b, e in zip(cuts, cuts[1:]) if b < e]

    def __call__(self, round_: int, groups: int) -> None:
        from distributed import as_completed

        t0 = time.perf_counter()
        ranges = self.ranges(groups)
        base = {"bake": self.bake, "config": self.config, "overrides": list(self.overrides), "round": round_,
                "threads": self.threads}
        futures = {self.client.submit(refine_part, dict(base, begin=b, end=e),
                                      key=f"hirad-links-{self.bake}-r{round_}-{b}-{e}", pure=False,
                                      retries=self.retries): (b, e) for b, e in ranges}
        self.on_event({"event": "links", "round": round_, "ranges": len(ranges), "done": 0})
        done = 0
        try:
            for fut in as_completed(list(futures), loop=self.client.loop):
                b, e = futures[fut]
                try:
                    self.tasks.append(fut.result())
                except Exception as err:
                    raise RuntimeError(f"groups [{b}, {e}) of round {round_} failed on the cluster: "
                                       f"{type(err).__name__}: {err}") from None
                done += 1
                self.on_event({"event": "links", "round": round_, "ranges": len(ranges), "done": done})
        except BaseException:
            self.client.cancel(list(futures))
            raise
        self.round_seconds.append(round(time.perf_counter() - t0, 4))

    def summary(self) -> dict:
        """What the report records: the cluster, and per round its tasks."""
        return {"scheduler": self.client.scheduler.address, "worker_threads": self.workers(),
                "engine_threads_per_task": self.threads, "round_seconds": self.round_seconds,
                "tasks": sorted(self.tasks, key=lambda t: (t["round"], t["begin"]))}

    def close(self) -> None:
        try:
            self.client.close(timeout=10)
        except Exception:
            pass
