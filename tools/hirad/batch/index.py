"""The study index: one SQLite file (`<study output>/study.sqlite`, stdlib sqlite3).

One row per job: its content key, status, attempts, timings, exit status, error and output;
one row per `hirad batch` run. Every change is one transaction (`with conn:`), so a batch
killed at any point leaves the file consistent: a job is `done` only once its bake exited 0
and its output was checked complete with the same key; a job still `queued` or `running`
when its batch died is shown as `interrupted` and runs again on the next batch.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from pathlib import Path
from typing import Any, Iterable

from .. import files

STATUSES = ("pending", "queued", "running", "done", "failed", "cancelled")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    name TEXT PRIMARY KEY,
    key TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('pending', 'queued', 'running', 'done', 'failed', 'cancelled')),
    overrides TEXT NOT NULL,
    output TEXT NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0,
    runs INTEGER NOT NULL DEFAULT 0,
    exit_code INTEGER,
    error TEXT,
    worker TEXT,
    batch INTEGER,
    queued_at REAL,
    started_at REAL,
    finished_at REAL,
    seconds REAL,
    done_key TEXT
);
CREATE TABLE IF NOT EXISTS batches (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    pid INTEGER NOT NULL,
    host TEXT,
    scheduler TEXT,
    dashboard TEXT,
    started_at REAL NOT NULL,
    finished_at REAL,
    status TEXT NOT NULL,
    jobs_run INTEGER DEFAULT 0,
    jobs_skipped INTEGER DEFAULT 0,
    jobs_failed INTEGER DEFAULT 0
);
"""


class Index:
    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.conn = sqlite3.connect(str(self.path), timeout=30, isolation_level=None)
        self.conn.row_factory = sqlite3.Row
        self.conn.execute("PRAGMA journal_mode=DELETE")
        self.conn.execute("PRAGMA synchronous=FULL")
        with self._tx() as c:
            for stmt in filter(str.strip, _SCHEMA.split(";")):
                c.execute(stmt)

    def _tx(self):
        conn = self.conn

        class _T:
            def __enter__(self):
                conn.execute("BEGIN IMMEDIATE")
                return conn

            def __exit__(self, kind, *_):
                conn.execute("COMMIT" if kind is None else "ROLLBACK")
                return False

        return _T()

    def close(self) -> None:
        self.conn.close()

    # --- batches ----------------------------------------------------------------------

    def start_batch(self, scheduler: str) -> int:
        with self._tx() as c:
            cur = c.execute("INSERT INTO batches (pid, host, scheduler, started_at, status) VALUES (?, ?, ?, ?, 'running')",
                            (os.getpid(), os.uname().nodename, scheduler, time.time()))
            return int(cur.lastrowid)

    def set_dashboard(self, batch: int, dashboard: str | None) -> None:
        with self._tx() as c:
            c.execute("UPDATE batches SET dashboard = ? WHERE id = ?", (dashboard, batch))

    def finish_batch(self, batch: int, status: str, run: int, skipped: int, failed: int) -> None:
        with self._tx() as c:
            c.execute("UPDATE batches SET finished_at = ?, status = ?, jobs_run = ?, jobs_skipped = ?, jobs_failed = ? "
                      "WHERE id = ?", (time.time(), status, run, skipped, failed, batch))
            if status != "done":
                c.execute("UPDATE jobs SET status = 'cancelled', finished_at = ? WHERE batch = ? AND status IN "
                          "('queued', 'running')", (time.time(), batch))

    def batches(self) -> list[dict]:
        return [dict(r) for r in self.conn.execute("SELECT * FROM batches ORDER BY id")]

    # --- jobs -------------------------------------------------------------------------

    def sync_jobs(self, jobs: Iterable[Any]) -> None:
        """Every job of the study has a row with its current key; a job whose key changed is
        pending again (its previous result is no longer its result); jobs no longer in the
        study are removed."""
        jobs = list(jobs)
        with self._tx() as c:
            names = {r["name"]: dict(r) for r in c.execute("SELECT * FROM jobs")}
            for j in jobs:
                row = names.get(j.name)
                over = json.dumps(j.overrides)
                if row is None:
                    c.execute("INSERT INTO jobs (name, key, status, overrides, output) VALUES (?, ?, 'pending', ?, ?)",
                              (j.name, j.key, over, str(j.output)))
                elif row["key"] != j.key or row["output"] != str(j.output):
                    c.execute("UPDATE jobs SET key = ?, status = 'pending', overrides = ?, output = ?, exit_code = NULL,"
                              " error = NULL WHERE name = ?", (j.key, over, str(j.output), j.name))
            keep = {j.name for j in jobs}
            for name in names:
                if name not in keep:
                    c.execute("DELETE FROM jobs WHERE name = ?", (name,))

    def job(self, name: str) -> dict | None:
        r = self.conn.execute("SELECT * FROM jobs WHERE name = ?", (name,)).fetchone()
        return dict(r) if r else None

    def jobs(self) -> list[dict]:
        return [dict(r) for r in self.conn.execute("SELECT * FROM jobs ORDER BY rowid")]

    def queued(self, name: str, batch: int) -> None:
        with self._tx() as c:
            c.execute("UPDATE jobs SET status = 'queued', batch = ?, queued_at = ?, started_at = NULL, finished_at = NULL,"
                      " seconds = NULL, exit_code = NULL, error = NULL, attempts = 0, worker = NULL WHERE name = ?",
                      (batch, time.time(), name))

    def finished(self, name: str, *, ok: bool, exit_code: int | None, error: str | None, attempts: int,
                 started_at: float | None, seconds: float | None, worker: str | None, key: str,
                 cancelled: bool = False) -> None:
        status = "done" if ok else ("cancelled" if cancelled else "failed")
        with self._tx() as c:
            c.execute("UPDATE jobs SET status = ?, exit_code = ?, error = ?, attempts = ?, runs = runs + 1, "
                      "started_at = ?, finished_at = ?, seconds = ?, worker = ?, done_key = ? WHERE name = ?",
                      (status, exit_code, error, attempts, started_at, time.time(), seconds, worker,
                       key if ok else None, name))


def _pid_alive(pid: int, host: str | None) -> bool:
    if host and host != os.uname().nodename:
        return True  # cannot tell: assume it runs
    return files.pid_alive(pid)


def status_rows(index: Index) -> list[dict]:
    """The jobs as `hirad batch status` shows them: a queued or running job of a batch whose
    process is gone is `interrupted`."""
    batches = {b["id"]: b for b in index.batches()}
    rows = []
    for j in index.jobs():
        status = j["status"]
        b = batches.get(j["batch"])
        if status in ("queued", "running") and b is not None and (b["finished_at"] is not None or
                                                                  not _pid_alive(b["pid"], b["host"])):
            status = "interrupted"
        attempts = j["attempts"]
        if status in ("queued", "running", "interrupted"):  # the attempts so far, from the jobs' own file
            try:
                text = (index.path.parent / "logs" / f"{j['name']}.attempts").read_text(encoding="utf-8")
                attempts = sum(1 for line in text.splitlines() if line.strip())
            except OSError:
                pass
        rows.append({"name": j["name"], "status": status, "key": j["key"], "attempts": attempts,
                     "runs": j["runs"], "exit_code": j["exit_code"], "error": j["error"], "seconds": j["seconds"],
                     "started_at": j["started_at"], "finished_at": j["finished_at"], "worker": j["worker"],
                     "output": j["output"], "overrides": json.loads(j["overrides"])})
    return rows
