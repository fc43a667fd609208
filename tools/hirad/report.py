"""Progress and the run report: stage timings, warnings, the energy balance and report.json."""

from __future__ import annotations

import os
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import numpy as np


# --------------------------------------------------------------------------------------
# progress reporting
# --------------------------------------------------------------------------------------



def _status_mib(key: str) -> float | None:
    """A /proc/self/status memory line (VmHWM, VmRSS), MiB; None where there is none."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except OSError:
        pass
    return None


def _peak_rss_mib() -> float:
    """The process's peak resident set so far, MiB: /proc/self/status VmHWM where there is one
    (getrusage's ru_maxrss carries the parent's peak across fork + exec: a bake spawned by a
    process holding 1.9 GB reported 1.9 GB from its first stage), else getrusage (KiB on Linux)."""
    peak = _status_mib("VmHWM")
    if peak is not None:
        return peak
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)


def release_free_memory() -> None:
    """Hand the heap's freed pages back to the system (glibc malloc_trim; a no-op elsewhere), so
    that what one stage freed does not stay resident, fragmented, under the next."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


# glibc's mallopt parameter for the size from which a block is its own mapping (malloc.h).
_M_MMAP_THRESHOLD = -3
# glibc's own starting threshold, and the most its rising threshold reaches (64-bit).
MAPPED_FROM_SMALL = 128 * 1024
MAPPED_FROM_LARGE = 32 * 1024 * 1024


def map_blocks_from(size: int) -> None:
    """Blocks of `size` bytes or more get a mapping of their own, returned to the system when
    freed (glibc mallopt M_MMAP_THRESHOLD; a no-op elsewhere); glibc then stops moving the
    threshold itself. It starts at 128 KiB and rises to the size of each mapped block freed (up
    to 32 MiB), after which arrays of that size come from the heap, whose freed space the process
    keeps: a bake frees and makes again arrays of many megabytes from stage to stage, and so kept
    far more than it held. On one floor of the bench building (615,054 triangles) the peak RSS was
    864 MiB with the threshold rising and 723 MiB with it fixed at 128 KiB, in the same time; the
    price is page faults, a freed block's pages mapped and zeroed again for the next, which made
    the Cornell box's final-gather lightmaps about 7 % slower (bench/README.md, stop 48). So
    hirad.bake fixes it at 128 KiB (MAPPED_FROM_SMALL) before it reads the scene, and at 32 MiB
    (MAPPED_FROM_LARGE: the heap reused as before) for a scene of fewer than
    bake.MAPPED_BLOCKS_FACES faces."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(_M_MMAP_THRESHOLD, int(size))
    except (OSError, AttributeError):
        pass


class Reporter:
    """Stage timings and warnings; progress on stderr unless quiet.

    On a terminal, rich progress bars. Otherwise (a log file, a pipe, CI) plain lines, never cut
    to a width: one when a stage starts, one when it ends, and in between at most one every
    `interval` seconds (default 5, or HIRAD_PROGRESS_SECONDS), each with the time since the bake
    started, the stage, its fraction done when known and the engine's detail, e.g.
    `hirad: [   12.3 s] form factors 45% 1200/2600 patches`.

    `mode` chooses: "auto" (bars on a terminal, plain lines otherwise), "bar", "plain", "none"
    (as quiet) or "jsonl": one JSON object a line, for a farm's log parser, e.g.
    `{"event": "progress", "stage": "form factors", "fraction": 0.45, "elapsed": 12.3,
    "stage_elapsed": 4.1, "eta": 5.0, "detail": "1200/2600 patches"}` (events `stage`,
    `progress` at most every `interval` seconds (1 s when not set), `stage_done`, `warning`;
    `fraction` and `eta`, the seconds the stage still needs at its pace so far, are null when
    the stage's total is not known).
    """

    def __init__(self, quiet: bool = False, stream=None, interval: float | None = None, mode: str = "auto"):
        if mode not in ("auto", "bar", "plain", "jsonl", "none"):
            raise ValueError(f"progress mode {mode!r}: auto, bar, plain, jsonl or none")
        quiet = quiet or mode == "none"
        self.quiet = quiet
        self._jsonl = mode == "jsonl" and not quiet
        if self._jsonl and interval is None and "HIRAD_PROGRESS_SECONDS" not in os.environ:
            interval = 1.0
        self.timings: dict[str, float] = {}
        # The process's peak resident memory so far at the end of each stage (MiB): where a
        # bake's memory rises (report.json's peak_rss_mib).
        self.peak_rss_mib: dict[str, float] = {}
        # What stays resident after each stage (VmRSS once its freed pages are handed back):
        # what the next stages start from (report.json's held_rss_mib; Linux only).
        self.held_rss_mib: dict[str, float] = {}
        self.warnings: list[str] = []
        self.stream = stream if stream is not None else sys.stderr
        if interval is None:
            try:
                interval = float(os.environ.get("HIRAD_PROGRESS_SECONDS", "5"))
            except ValueError:
                interval = 5.0
        self.interval = interval if interval == interval and interval >= 0 else 5.0
        self._start = time.perf_counter()
        self._lock = threading.Lock()
        self._progress = None
        interactive = not quiet and not self._jsonl and mode != "plain" and (mode == "bar" or _is_terminal(self.stream))
        if interactive:
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self._progress = Progress(TextColumn("{task.description:<22}", markup=False), BarColumn(),
                                      TextColumn("{task.fields[detail]}", markup=False), TimeElapsedColumn(),
                                      console=Console(file=self.stream), transient=False)
        self._log = not quiet and not interactive and not self._jsonl

    def _event(self, event: str, **fields) -> None:
        import json

        elapsed = round(time.perf_counter() - self._start, 3)
        print(json.dumps({"event": event, "elapsed": elapsed, **fields}, allow_nan=False), file=self.stream,
              flush=True)

    def __enter__(self):
        if self._progress:
            self._progress.start()
        return self

    def __exit__(self, *exc):
        if self._progress:
            self._progress.stop()

    def _line(self, text: str) -> None:
        elapsed = time.perf_counter() - self._start
        print(f"hirad: [{elapsed:7.1f} s] {text}", file=self.stream, flush=True)

    @contextmanager
    def stage(self, name: str, total: float | None = None) -> Iterator[Callable[..., None]]:
        """Times a stage; yields update(completed, detail='') for its progress."""
        global current_stage
        current_stage = name
        task = self._progress.add_task(name, total=total, detail="") if self._progress else None
        start = time.perf_counter()
        last = [start]
        if self._log:
            self._line(f"{name} ...")
        if self._jsonl:
            self._event("stage", stage=name, total=total)

        def due(now: float) -> bool:  # one line or event per `interval` at most
            with self._lock:
                if now - last[0] < self.interval:
                    return False
                last[0] = now
                return True

        def update(completed: float | None = None, detail: str = "") -> None:
            if self._jsonl:
                now = time.perf_counter()
                if not due(now):
                    return
                fraction = eta = None
                if completed is not None and total:
                    fraction = min(1.0, max(0.0, float(completed) / float(total)))
                    eta = round((now - start) * (1.0 - fraction) / fraction, 3) if fraction > 0 else None
                self._event("progress", stage=name, fraction=None if fraction is None else round(fraction, 4),
                            stage_elapsed=round(now - start, 3), eta=eta, detail=detail or None)
                return
            if task is not None:
                self._progress.update(task, completed=completed, detail=detail)
            elif self._log:
                now = time.perf_counter()
                if not due(now):
                    return
                parts = [name]
                if completed is not None and total:
                    parts.append(f"{100.0 * min(1.0, max(0.0, completed / total)):.0f}%")
                if detail:
                    parts.append(detail)
                self._line(" ".join(parts))

        ok = False
        try:
            yield update
            ok = True
            current_stage = None  # (kept when the stage raises: the CLI names it)
        finally:
            self.timings[name] = round(time.perf_counter() - start, 4)
            # VmHWM can read lower than a moment before: the kernel updates the mark lazily,
            # and pages handed back by malloc_trim leave the current RSS below an unrecorded peak
            self.peak_rss_mib[name] = max([_peak_rss_mib(), *self.peak_rss_mib.values()])
            release_free_memory()
            held = _status_mib("VmRSS")
            if held is not None:
                self.held_rss_mib[name] = held
            if task is not None:
                self._progress.update(task, total=total or 1, completed=total or 1)
            elif self._log:
                self._line(f"{name} {'done in' if ok else 'stopped after'} {time.perf_counter() - start:.1f} s")
            elif self._jsonl:
                self._event("stage_done", stage=name, ok=ok, seconds=round(time.perf_counter() - start, 4))

    def warn(self, message: str) -> None:
        self.warnings.append(message)
        if self._jsonl:
            self._event("warning", message=message)
        elif not self.quiet:
            if self._progress:
                self._progress.console.print(f"hirad: warning: {message}", markup=False, highlight=False,
                                             soft_wrap=True)
            else:
                print(f"hirad: warning: {message}", file=self.stream, flush=True)


# The stage a bake is in (for an error that escapes it: the CLI names where it happened).
current_stage: str | None = None


def _is_terminal(stream) -> bool:
    try:
        return stream.isatty() and os.environ.get("TERM", "") != "dumb"
    except (AttributeError, ValueError):
        return False


def energy_balance(patches: dict, b: np.ndarray, h: np.ndarray, escaped: np.ndarray, luminaire_flux=None,
                   received_as_emitted: bool = False, glazing=None) -> dict:
    """Emitted power against absorbed plus escaped (through openings), per channel, in W (lm
    when photometric). `h` is the whole irradiance (from the surfaces and the luminaires).
    With luminaires, their exact flux is emitted too, and what of it reaches no surface (the
    flux less the direct light the patches receive, sum of direct x area) escapes: in a closed
    room that part is the discretisation's error of the direct light alone.
    `received_as_emitted` (daylight: sun and sky have no flux of their own): the direct light the
    patches receive (sum of direct x area) counts as what entered.
    Glazed faces (patches' `transmittance` > 0) take in only the direct light they reflect,
    rho D (what they let through is counted where it lands, as D there), and take (1 - rho) of
    the interreflected light H - D they receive: what they absorb and what they let through
    together, reported apart as `glazing.glass_took_W`. Clear glass lets interreflected light
    through in direction (hierarchical bakes, visibility.h), so what reaches other surfaces is
    counted again where it lands, and the light of the surfaces that sent it through the glass
    is missing from their escaped part by as much (per link the power sent is the power
    received): the sum closes, while `escaped_W` is net of what glass passed on to surfaces
    and `glass_took_W` includes it. `glazing` (a hierarchical result): the unpublished backs of
    glazed faces (their rho D in, what they take, their light that reaches no surface)."""
    # hierarchical bakes: a leaf's B, H and direct light are those of its part outside other
    # geometry (patches["open"], the engine's Hierarchy::open), which alone sends and absorbs
    area = (patches["area"] * patches["open"] if "open" in patches else patches["area"])[:, None]
    rho = patches["reflectance"]
    direct = patches["direct"]
    tau = patches.get("transmittance")
    glass = (np.asarray(tau) > 0) if tau is not None else np.zeros(len(area), dtype=bool)
    emitted = (patches["emission"] * area).sum(axis=0)
    absorbed = ((np.where(glass[:, None], 0.0, (1 - rho) * h)) * area).sum(axis=0)
    glass_took = ((np.where(glass[:, None], (1 - rho) * (h - direct), 0.0)) * area).sum(axis=0)
    lost = np.asarray(escaped).sum(axis=0)
    out = {}
    # the direct light that enters the surfaces' exchange (glass: only what it reflects)
    received = (np.where(glass[:, None], rho * direct, direct) * area).sum(axis=0)
    if received_as_emitted:
        emitted = emitted + received
        out = {"direct_received_W": received.tolist()}
    elif luminaire_flux is not None:
        flux = np.asarray(luminaire_flux, dtype=np.float64).reshape(3)
        emitted = emitted + flux
        lost = lost + (flux - received)  # glass's absorption of direct light among it
        out = {"luminaire_flux_W": flux.tolist(), "luminaire_received_W": received.tolist(),
               "luminaire_unreceived_W": (flux - received).tolist()}
    if glazing is not None and np.any(glass):
        back_in = np.asarray(glazing.glass_back_entered)
        if received_as_emitted:
            emitted = emitted + back_in
        else:
            lost = lost - back_in  # the luminaires' light the backs reflect was not lost
        glass_took = glass_took + np.asarray(glazing.glass_back_absorbed)
        lost = lost + np.asarray(glazing.glass_back_escaped)
        out["glazing"] = {"back_direct_reflected_W": back_in.tolist(),
                          "back_took_W": np.asarray(glazing.glass_back_absorbed).tolist(),
                          "back_escaped_W": np.asarray(glazing.glass_back_escaped).tolist()}
    if np.any(glass):
        out.setdefault("glazing", {})["glass_took_W"] = glass_took.tolist()
    scale = np.where(emitted > 0, emitted, 1.0)
    error = np.abs(emitted - absorbed - glass_took - lost) / scale
    return {"emitted_W": emitted.tolist(), "absorbed_W": absorbed.tolist(), "escaped_W": lost.tolist(),
            "relative_error": error.tolist(), "max_relative_error": float(error.max()), **out}


def write_json(path: Path, data: dict) -> None:
    from .files import write_json as atomic_write_json

    atomic_write_json(path, data)


def scene_fingerprint(scene) -> str:
    """sha256 of what the light depends on: the scene's geometry, reflectance and emission
    (not paths or output settings, so the same scene baked twice gives identical files).
    Taken once and kept on the scene (`fingerprint`): a bake lets the arrays go when no
    output reads them, and asks for it later (the volume)."""
    import hashlib

    if getattr(scene, "fingerprint", None):
        return scene.fingerprint
    if scene.points is None:
        raise ValueError("scene_fingerprint: the scene's arrays were let go before its fingerprint was taken")

    h = hashlib.sha256()
    tau = getattr(scene, "face_transmittance", None)
    glazing = (tau,) if tau is not None and np.any(np.asarray(tau) > 0) else ()  # opaque scenes: as before
    for a in (scene.points, scene.face_vertex_counts, scene.face_vertex_indices, scene.face_reflectance,
              scene.face_emission, *glazing):
        arr = np.ascontiguousarray(a)
        h.update(str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(arr.reshape(-1).view(np.uint8))  # the bytes in place, not a copy of them
    scene.fingerprint = h.hexdigest()
    return scene.fingerprint
