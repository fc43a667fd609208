"""Running a study's jobs on Dask distributed.

Each job is one Dask task whose function (`run_job`, on a worker) runs the bake as a separate
process, `python -m hirad.cli bake BASE --set ... --set output=...`, so a bake that crashes
takes neither the worker nor its other jobs down. The bake process is tied to its worker
(PR_SET_PDEATHSIG): a worker killed with kill -9 takes its bakes with it (they get SIGTERM and
remove their partial output), the scheduler hands the task to another worker, and the bake
runs again from the start (the engine is deterministic: the same bits).

A bake that fails for a reason that may pass (exit 4: the run failed; 1: internal; killed by a
signal) raises, and Dask tries the task again up to the study's `retries`; a config or scene
error (exit 2, 3) is final at once. Every attempt appends one line to the job's attempts file
(`<output>/logs/NAME.attempts`), which the index's `attempts` counts.

Cancelling (SIGINT/SIGTERM to `hirad batch`): the driver writes `<output>/.cancel-<batch>`;
every running job sees it within 0.2 s, sends SIGTERM to its bake (which removes its partial
output and exits 143) and returns `cancelled`; then the cluster is closed.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

from .. import files
from .index import Index
from .study import Job, Study

EXIT_CONFIG, EXIT_SCENE, EXIT_FAILED, EXIT_INTERNAL = 2, 3, 4, 1
FINAL = (EXIT_CONFIG, EXIT_SCENE)  # not worth a retry: the same inputs fail the same way


class BatchError(Exception):
    """A study that cannot run: no scheduler, no cluster (the CLI exits 2)."""


class JobFailed(Exception):
    """A bake that failed (raised on the worker, so that Dask retries it)."""

    def __init__(self, message: str, exit_code: int | None):
        super().__init__(message, exit_code)
        self.message, self.exit_code = message, exit_code

    def __str__(self) -> str:
        return self.message


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def _last_error(log: Path, offset: int) -> str | None:
    try:
        with open(log, "rb") as f:
            f.seek(offset)
            text = f.read().decode("utf-8", "replace")
    except OSError:
        return None
    lines = [l for l in text.splitlines() if l.strip()]
    errors = [l for l in lines if l.startswith("hirad: error:") or l.startswith("hirad: ") and "signal" in l]
    pick = errors[-1] if errors else (lines[-1] if lines else None)
    return pick[:2000] if pick else None


def bake_command(base: Path, overrides: list[str], threads: int | None, reuse_links: bool = False) -> list[str]:
    cmd = [sys.executable, "-m", "hirad.cli", "bake", str(base), "--quiet"] + (["--reuse-links"] if reuse_links else [])
    for o in overrides:
        cmd += ["--set", o]
    if threads is not None:
        cmd += ["--threads", str(threads)]
    return cmd


def run_job(spec: dict, after: Any = None) -> dict:
    """One attempt of one job, on a worker: the bake as a child process. Returns what the index
    records; raises JobFailed for a failure worth retrying. `after` is the result of the job
    whose link store this one reuses (Dask runs this one after it)."""
    if after is not None and after.get("exit_code") != 0:
        raise JobFailed(f"the job {spec.get('after')} whose links this one reuses did not finish: "
                        f"{after.get('error') or after.get('exit_code')}", None)
    try:
        from distributed import get_worker

        worker = get_worker().address
    except Exception:
        worker = f"{socket.gethostname()}:{os.getpid()}"
    log, attempts, cancel = Path(spec["log"]), Path(spec["attempts"]), Path(spec["cancel"])
    if cancel.exists():  # the batch is being cancelled: do not start
        return {"exit_code": None, "started_at": None, "seconds": None, "worker": worker, "error": "cancelled",
                "cancelled": True}
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(attempts, "a", encoding="utf-8") as f:
        f.write(json.dumps({"time": time.time(), "worker": worker, "pid": os.getpid()}) + "\n")
    started = time.time()
    env = {**os.environ, "HIRAD_PROGRESS_SECONDS": "10"}
    with open(log, "ab") as lf:
        offset = lf.tell()
        lf.write(f"--- attempt on {worker} at {time.strftime('%Y-%m-%d %H:%M:%S')}: "
                 f"{' '.join(spec['command'])}\n".encode())
        lf.flush()
        proc = subprocess.Popen(spec["command"], stdout=lf, stderr=lf, stdin=subprocess.DEVNULL, env=env,
                                preexec_fn=_die_with_parent)
        cancelled = timed_out = False
        while proc.poll() is None:
            if not cancelled and cancel.exists():
                cancelled = True
                proc.send_signal(signal.SIGTERM)
            if not timed_out and spec.get("timeout") and time.time() - started > spec["timeout"]:
                timed_out = True
                proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(0.2)
            except subprocess.TimeoutExpired:
                pass
    rc = proc.returncode
    result = {"exit_code": rc, "started_at": started, "seconds": round(time.time() - started, 3), "worker": worker,
              "error": None if rc == 0 else _last_error(log, offset), "cancelled": cancelled}
    if rc == 0 or cancelled or rc in FINAL:
        return result
    why = result["error"] or f"exit status {rc}"
    if timed_out:
        why = f"timed out after {spec['timeout']:g} s: {why}"
    raise JobFailed(why, rc)


def output_complete(job: Job) -> bool:
    """A job's output is complete: hirad's marker says so and its report carries the job's key."""
    marker = files._read_marker(job.output, files.OUTPUT_MARKER, files._OUTPUT_FORMAT)
    if not marker or not marker.get("complete"):
        return False
    report = job.output / "report.json"
    if report.exists():
        try:
            return json.loads(report.read_text(encoding="utf-8")).get("content_key") == (job.report_key or job.key)
        except (OSError, ValueError):
            return False
    return True


def jobs_to_run(study: Study, index: Index, force: bool = False) -> tuple[list[Job], list[Job]]:
    """(to run, finished): a job is finished when its index row is done with its current key
    and its output is complete."""
    run, done = [], []
    for job in study.jobs:
        row = index.job(job.name)
        if not force and row and row["status"] == "done" and row["done_key"] == job.key and output_complete(job):
            done.append(job)
        else:
            run.append(job)
    return run, done


# --------------------------------------------------------------------------------------
# the cluster
# --------------------------------------------------------------------------------------


def open_cluster(study: Study, scheduler: str | None, workers: int | None):
    """(client, cluster or None, description). An unreachable scheduler or a cluster that
    cannot start is a BatchError."""
    import logging

    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise BatchError("hirad batch runs on Dask: pip install distributed (make installs it)") from None

    spec = study.spec
    address = scheduler or (spec.cluster if "://" in spec.cluster else None)
    if address:
        try:
            client = Client(address, timeout=5, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as e:
            raise BatchError(f"--scheduler {address}: cannot reach the Dask scheduler ({e})") from None
        return client, None, address
    n = workers or spec.workers
    if spec.cluster == "local":
        try:
            cluster = LocalCluster(n_workers=n, threads_per_worker=spec.jobs_per_worker, processes=True,
                                   dashboard_address=spec.cluster_options.get("dashboard_address", ":0"),
                                   silence_logs=logging.ERROR)
        except Exception as e:
            raise BatchError(f"cannot start a local Dask cluster: {e}") from None
        return Client(cluster, set_as_default=False), cluster, f"LocalCluster ({n} workers x {spec.jobs_per_worker})"
    kinds = {"slurm": "SLURMCluster", "pbs": "PBSCluster", "sge": "SGECluster", "lsf": "LSFCluster"}
    if spec.cluster not in kinds:
        raise BatchError(f"{study.path}: cluster: {spec.cluster!r}: local, slurm, pbs, sge, lsf or a scheduler "
                         "address tcp://HOST:PORT")
    try:
        import dask_jobqueue
    except ImportError:
        raise BatchError(f"cluster: {spec.cluster} needs dask-jobqueue (pip install dask-jobqueue)") from None
    try:
        cluster = getattr(dask_jobqueue, kinds[spec.cluster])(**spec.cluster_options)
        cluster.scale(jobs=n)
    except Exception as e:
        raise BatchError(f"cluster: {spec.cluster}: cannot start ({e})") from None
    return Client(cluster, set_as_default=False), cluster, f"{kinds[spec.cluster]} ({n} jobs)"


# --------------------------------------------------------------------------------------
# the batch
# --------------------------------------------------------------------------------------


def run_batch(study: Study, *, scheduler: str | None = None, workers: int | None = None, force: bool = False,
              emit: Callable[[dict], None] = lambda e: None) -> dict:
    """Runs the jobs not yet finished; returns counts {run, skipped, done, failed, cancelled}.
    `emit` gets one event per change (the CLI prints them). A signal (hirad.interrupts) cancels
    the running jobs, records them as cancelled and closes the cluster before it ends the
    process."""
    from .. import interrupts

    with interrupts.patient(120):
        return _run_batch(study, scheduler, workers, force, emit)


def _run_batch(study: Study, scheduler, workers, force, emit) -> dict:
    index = Index(study.index_path)
    try:
        index.sync_jobs(study.jobs)
        todo, finished = jobs_to_run(study, index, force)
        emit({"event": "plan", "jobs": len(study.jobs), "to_run": len(todo), "skipped": len(finished),
              "index": str(study.index_path)})
        counts = {"run": 0, "skipped": len(finished), "done": 0, "failed": 0, "cancelled": 0}
        if not todo:
            return counts
        client, cluster, what = open_cluster(study, scheduler, workers)
        batch = index.start_batch(what)
        for stale in study.output.glob(".cancel-*"):
            stale.unlink(missing_ok=True)
        cancel = study.output / f".cancel-{batch}"
        logs = study.output / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        dashboard = getattr(client, "dashboard_link", None)
        index.set_dashboard(batch, dashboard)
        emit({"event": "cluster", "cluster": what, "dashboard": dashboard, "batch": batch})
        ncores = os.cpu_count() or 1
        futures = {}
        status = "cancelled"
        try:
            from distributed import as_completed

            by_name: dict = {}
            for job in todo:
                threads = job.threads if job.threads is not None else \
                    max(1, ncores // max(1, study.spec.workers * study.spec.jobs_per_worker))
                attempts = logs / f"{job.name}.attempts"
                attempts.write_text("")
                spec = {"name": job.name, "command": bake_command(study.base, job.overrides, threads, job.reuse_links),
                        "log": str(logs / f"{job.name}.log"), "attempts": str(attempts), "cancel": str(cancel),
                        "timeout": study.spec.timeout, "after": job.after}
                index.queued(job.name, batch)
                after = by_name.get(job.after) if job.after else None
                fut = client.submit(run_job, spec, after, key=f"hirad-{study.name}-{batch}-{job.name}", pure=False,
                                    retries=study.spec.retries)
                futures[fut] = job
                by_name[job.name] = fut
            for fut in as_completed(list(futures), loop=client.loop):
                job = futures[fut]
                _record(index, job, fut, logs, counts, emit)
            status = "done"
        except BaseException:
            # cancel: every job sees the cancel file (a running one stops its bake, which
            # removes its partial output; one not started returns at once), so each future
            # finishes soon, on a local or a remote cluster alike
            try:
                cancel.write_text("cancel\n")
                emit({"event": "cancelling", "jobs": sum(1 for f in futures if not f.done())})
                deadline = time.time() + 60
                for fut, job in futures.items():
                    while not fut.done() and time.time() < deadline:
                        time.sleep(0.1)
                    row = index.job(job.name)
                    if not row or row["status"] not in ("queued", "running"):
                        continue
                    res = None
                    if fut.status == "finished":
                        try:
                            res = fut.result()
                        except Exception:
                            res = None
                    if res is not None and not res.get("cancelled") and res["exit_code"] == 0:
                        _record(index, job, fut, logs, counts, emit)  # it finished before the cancel
                    else:
                        index.finished(job.name, ok=False, exit_code=None if res is None else res["exit_code"],
                                       error="cancelled", cancelled=True, attempts=_attempts(logs, job),
                                       started_at=None, seconds=None, worker=None, key=job.key)
                        counts["cancelled"] += 1
                client.cancel([f for f in futures if not f.done()])
            finally:
                raise
        finally:
            index.finish_batch(batch, status, counts["run"], counts["skipped"], counts["failed"])
            try:
                client.close(timeout=10)
                if cluster is not None:
                    cluster.close(timeout=20)
            except Exception:
                pass
            try:
                cancel.unlink()
            except OSError:
                pass
        return counts
    finally:
        index.close()


def _attempts(logs: Path, job: Job) -> int:
    try:
        return sum(1 for l in (logs / f"{job.name}.attempts").read_text().splitlines() if l.strip())
    except OSError:
        return 0


def _record(index: Index, job: Job, fut, logs: Path, counts: dict, emit) -> None:
    attempts = _attempts(logs, job)
    try:
        res = fut.result()
    except Exception as e:  # retries used up (JobFailed), or the worker died too often (KilledWorker)
        code = getattr(e, "exit_code", None)
        msg = str(e) if isinstance(e, JobFailed) else f"{type(e).__name__}: {e}"
        index.finished(job.name, ok=False, exit_code=code, error=msg, attempts=attempts, started_at=None,
                       seconds=None, worker=None, key=job.key)
        counts["run"] += 1
        counts["failed"] += 1
        emit({"event": "job", "name": job.name, "status": "failed", "attempts": attempts, "exit_code": code,
              "error": msg})
        return
    ok = res["exit_code"] == 0 and output_complete(job)
    error = res["error"]
    if res["exit_code"] == 0 and not ok:
        error = f"the bake exited 0 but {job.output} is not a complete output with key {job.key[:12]}"
    cancelled = bool(res.get("cancelled"))
    index.finished(job.name, ok=ok, exit_code=res["exit_code"], error=error, attempts=attempts,
                   started_at=res["started_at"], seconds=res["seconds"], worker=res["worker"], key=job.key,
                   cancelled=cancelled)
    counts["run"] += 1
    counts["done" if ok else ("cancelled" if cancelled else "failed")] += 1
    emit({"event": "job", "name": job.name, "status": "done" if ok else ("cancelled" if cancelled else "failed"),
          "attempts": attempts, "exit_code": res["exit_code"], "seconds": res["seconds"], "error": error,
          "worker": res["worker"]})
