"""SIGINT and SIGTERM for the `hirad` command: the partial output is removed and the process
exits with the conventional code, 128 + the signal number (130 for SIGINT, 143 for SIGTERM).

Two paths, because the engine runs in C++ with the GIL released and Python runs its signal
handlers only when the main thread is back in the interpreter:

- the Python handler raises `Interrupted` in the main thread; the bake's try/except removes
  its staging directory and the CLI exits with `exit_code`. This is the path whenever the main
  thread runs Python (between stages, in a progress callback, while writing outputs).
- a watchdog thread wakes on the signal at once (signal.set_wakeup_fd); if the main thread
  has not finished after `grace` seconds (it is inside a long engine call), the watchdog
  removes every directory registered with `hirad.files.removed_on_failure` and ends the
  process with os._exit(128 + signum). The engine's own files in the link store are left as
  they are, for `--resume`.

A signal during the swap of a finished output waits for the swap (the cleanup lock); a second
signal while the first is handled is ignored by the main thread (cleanup is never cut short).
The Python API (hirad.bake) installs nothing: there an interrupt is a KeyboardInterrupt, and the
staging directory goes once control is back in Python.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Iterator

from . import files

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
    """The process got SIGINT or SIGTERM (a BaseException, so no `except Exception` eats it)."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        super().__init__(f"interrupted by {signal.Signals(self.signum).name}")

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


_received: list[int] = []
_finished = threading.Event()
_installed = False
_deferred = 0
_raised = False


def received() -> int | None:
    """The first signal received, if any."""
    return _received[0] if _received else None


def _raise_once() -> None:
    global _raised
    if _received and not _raised and not _deferred:
        _raised = True
        raise Interrupted(_received[0])


def _handler(signum, frame) -> None:
    _received.append(signum)
    _raise_once()


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A block a signal does not cut short (the swap of a finished output): the Interrupted is
    raised when it ends, and the watchdog's cleanup waits for it."""
    global _deferred
    with files.cleanup_lock():
        _deferred += 1
        try:
            yield
        finally:
            _deferred -= 1
    _raise_once()


_patience: list[float] = []


@contextlib.contextmanager
def patient(seconds: float) -> Iterator[None]:
    """A block whose cleanup after a signal takes longer than the watchdog's grace (`hirad
    batch` cancelling its jobs and closing its cluster): the watchdog waits `seconds` before
    it steps in."""
    _patience.append(float(seconds))
    try:
        yield
    finally:
        _patience.pop()


def _watchdog(fd: int, grace: float) -> None:
    while True:
        try:
            data = os.read(fd, 64)
        except InterruptedError:
            continue
        except OSError:
            return
        signums = [b for b in data if b in SIGNALS]
        if not signums:
            continue
        if _finished.wait(max([grace] + _patience)):
            return
        signum = received() or signums[0]
        try:
            files.run_cleanups()
            os.write(2, f"hirad: {signal.Signals(signum).name} during an engine call; partial output "
                        "removed\n".encode())
        finally:
            os._exit(128 + signum)


def install(grace: float = 1.0) -> None:
    """Installs the handlers and the watchdog (main thread only; once per process)."""
    global _installed
    if _installed:
        return
    r, w = os.pipe()
    os.set_blocking(w, False)
    signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    for s in SIGNALS:
        signal.signal(s, _handler)
    threading.Thread(target=_watchdog, args=(r, grace), name="hirad-signals", daemon=True).start()
    _installed = True


def finished() -> None:
    """The main thread has cleaned up after a signal: the watchdog need not step in."""
    _finished.set()
