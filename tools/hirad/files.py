"""How hirad writes files, and the rules that keep a bake off the user's files.

One atomic write (`atomic_file`, `atomic_path`, `write_bytes`, `write_text`, `write_json`):
the new content goes to a temporary beside the target, ".<stem>.<pid>-<random>.tmp<suffix>",
created exclusively (O_CREAT | O_EXCL | O_NOFOLLOW), so it is never an existing file and never
a link planted under that name; it is fsynced, renamed over the target (a symlink at the
target is replaced, its target left alone) and the directory is fsynced. A reader sees the
old file or the new one, never part of one; a failure leaves the old file (or none) and no
temporary. Errors are `WriteError`s naming the file and the OS error.

The output directory and the link store (`check_output`, `make_staging`, `replace_output`,
`remove_stale_staging`, `check_link_store`, `make_link_store`): hirad only ever replaces or
clears a directory that carries the marker file it wrote when it made it (`.hirad-output`,
`.hirad-linkstore`). It refuses an output or store that is, contains or lies inside one of the
inputs, a symbolic link, or a non-empty directory it did not make; an output of hirad's to
which anything else was added is refused too (the marker lists what hirad wrote). Refusals
are `UnsafePathError`s (the CLI exits with 2).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import shutil
import stat
import threading
from pathlib import Path
from typing import IO, Iterable, Iterator

from .errors import BakeError

OUTPUT_MARKER = ".hirad-output"
STORE_MARKER = ".hirad-linkstore"
_OUTPUT_FORMAT = "hirad-output"
_STORE_FORMAT = "hirad-linkstore"


class WriteError(BakeError, OSError):
    """A file could not be written (disk full, permissions, a directory in the way...); an
    OSError too, so code that catches OSError around a write still does."""


class UnsafePathError(BakeError):
    """An output or store path that hirad refuses to write to, clear or replace."""


# --------------------------------------------------------------------------------------
# the atomic write
# --------------------------------------------------------------------------------------


def _describe(exc: OSError) -> str:
    return exc.strerror or str(exc)


def _fsync_directory(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _create_temporary(path: Path, suffix: str | None = None) -> tuple[int, Path]:
    """An exclusively created, empty temporary beside `path` (mode 0666 less the umask)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
    suffix = path.suffix if suffix is None else suffix
    for _ in range(100):
        tmp = path.with_name(f".{path.stem}.{os.getpid()}-{secrets.token_hex(4)}.tmp{suffix}")
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
        except OSError as e:
            raise WriteError(f"{path}: cannot create a temporary file in {path.parent}: {_describe(e)}") from None
    raise WriteError(f"{path}: no free temporary name in {path.parent}")


def _unlink_quietly(path: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


def _commit(tmp: Path, path: Path) -> None:
    os.replace(tmp, path)
    _fsync_directory(path.parent)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, mode: str = "wb", *, encoding: str | None = None,
                newline: str | None = None) -> Iterator[IO]:
    """A file object on the exclusive temporary of `path` (mode "wb" or "w"); `path` is
    replaced when the block ends without an exception, left alone otherwise."""
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_file: mode {mode!r} (only 'wb' or 'w')")
    path = Path(path)
    fd, tmp = _create_temporary(path)
    try:
        with os.fdopen(fd, mode, encoding=encoding if mode == "w" else None,
                       newline=newline if mode == "w" else None) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        _commit(tmp, path)
    except OSError as e:
        _unlink_quietly(tmp)
        raise WriteError(f"{path}: cannot write: {_describe(e)}") from None
    except BaseException:
        _unlink_quietly(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """The path of the exclusive temporary of `path`, for writers that take a file name
    (Sdf.Layer.Export, image libraries). The temporary keeps the target's suffix, so a writer
    that picks its format by extension picks the right one (or ends in `suffix` if given). `path` is replaced when the block
    ends without an exception, provided the temporary is still a regular file (a writer that
    renamed its own file over it is fine; a link put in its place is refused)."""
    path = Path(path)
    fd, tmp = _create_temporary(path, suffix)
    os.close(fd)
    try:
        yield tmp
        st = os.lstat(tmp)
        if not stat.S_ISREG(st.st_mode):
            raise WriteError(f"{path}: the temporary {tmp.name} was replaced by something that is not a file")
        fd = os.open(tmp, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        _commit(tmp, path)
    except OSError as e:
        _unlink_quietly(tmp)
        raise WriteError(f"{path}: cannot write: {_describe(e)}") from None
    except BaseException:
        _unlink_quietly(tmp)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_file(path, "wb") as f:
        f.write(data)


def write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> None:
    with atomic_file(path, "w", encoding=encoding, newline="") as f:
        f.write(text)


def write_json(path: str | os.PathLike, data) -> None:
    write_text(path, json.dumps(data, indent=2) + "\n")


# --------------------------------------------------------------------------------------
# paths that must not be touched
# --------------------------------------------------------------------------------------


def _real(path: str | os.PathLike) -> Path:
    return Path(os.path.realpath(os.path.abspath(os.fspath(path))))


def _inside(path: Path, root: Path) -> bool:
    """Whether the (real) path is root or lies under it."""
    return path == root or root in path.parents


def scene_files(scene: str | os.PathLike) -> tuple[list[Path], list]:
    """The scene file and every layer it composes (sublayers, references, payloads, found
    recursively at the layer level, without composing a stage). Returns the paths and the Sdf
    layers, which the caller may hold so that reading the stage afterwards parses nothing twice."""
    from pxr import Sdf

    root = _real(scene)
    paths, layers, todo, seen = [root], [], [str(root)], {str(root)}
    while todo:
        current = todo.pop()
        try:
            layer = Sdf.Layer.FindOrOpen(current)
        except Exception:  # an unreadable layer: reading the scene reports it
            layer = None
        if layer is None:
            continue
        layers.append(layer)
        for dep in layer.GetCompositionAssetDependencies():
            try:
                resolved = layer.ComputeAbsolutePath(dep)
            except Exception:
                continue
            if not resolved or "://" in resolved or not os.path.exists(resolved):
                continue
            real = str(_real(resolved))
            if real not in seen:
                seen.add(real)
                paths.append(Path(real))
                todo.append(real)
    return paths, layers


def _refuse_inputs(what: str, path: Path, real: Path, inputs: Iterable[tuple[str, Path]]) -> None:
    for kind, p in inputs:
        rp = _real(p)
        if rp == real:
            raise UnsafePathError(f"{what} {path} is the {kind} {p}; hirad never overwrites an input")
        if _inside(rp, real):
            raise UnsafePathError(f"{what} {path} contains the {kind} {p}; hirad replaces its whole {what}, "
                                  "so it must be a directory of its own")


def refuse_input(path: str | os.PathLike, inputs: Iterable[tuple[str, str | os.PathLike]],
                 what: str = "output") -> None:
    """Refuses a file to be written that is one of the inputs (compared after resolving links)."""
    path = Path(path)
    real = _real(path)
    for kind, p in inputs:
        if _real(p) == real:
            raise UnsafePathError(f"{what} {path} is the {kind} {p}; hirad never overwrites an input")
    if os.path.isdir(path):
        raise UnsafePathError(f"{what} {path} is a directory; give a file name")


# --------------------------------------------------------------------------------------
# the output directory
# --------------------------------------------------------------------------------------


def _read_marker(directory: Path, name: str, fmt: str) -> dict | None:
    """The marker hirad wrote in `directory`, or None if there is none (or not hirad's)."""
    p = directory / name
    try:
        st = os.lstat(p)
        if not stat.S_ISREG(st.st_mode) or st.st_size > 64 << 20:  # a listing, never this large
            return None
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("format") == fmt else None


def _entries(directory: Path) -> list[str]:
    """Every entry under `directory` (files, links, directories), relative, links not followed."""
    out = []
    for top, dirs, files in os.walk(directory, followlinks=False):
        rel = os.path.relpath(top, directory)
        for name in dirs + files:
            out.append(name if rel == "." else os.path.join(rel, name))
    return out


def _foreign_entries(directory: Path, marker: dict) -> list[str]:
    """Entries of an output that the marker does not list as hirad's."""
    known = set(marker.get("files") or [])
    for f in list(known):
        parts = Path(f).parts
        known.update(os.path.join(*parts[:k]) for k in range(1, len(parts)))
    known.add(OUTPUT_MARKER)
    # hirad writes no links: a link is always someone else's
    return sorted(rel for rel in _entries(directory) if rel not in known or (directory / rel).is_symlink())


def _directory_entries(path: Path, label: str, made: str, whose: str) -> list[str] | None:
    """The names in directory `path`, None when nothing is there; a symbolic link or a file
    there is refused (hirad makes `made` itself), named by `label` (the setting)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    if stat.S_ISLNK(st.st_mode):
        raise UnsafePathError(f"{label} {path} is a symbolic link; hirad makes {made} itself (give {whose} real path)")
    if not stat.S_ISDIR(st.st_mode):
        raise UnsafePathError(f"{label} {path} exists and is not a directory")
    return os.listdir(path)


def _shown(entries: list[str]) -> str:
    """At most five of the names, sorted, for a message."""
    return ", ".join(sorted(entries)[:5]) + (", ..." if len(entries) > 5 else "")


def check_output(out_dir: str | os.PathLike, inputs: Iterable[tuple[str, str | os.PathLike]] = ()) -> None:
    """Refuses an output directory that hirad may not replace: one that is or contains an input,
    a link, a file, or a non-empty directory that hirad did not make or to which something
    other than what hirad wrote was added."""
    out = Path(out_dir)
    real = _real(out)
    inputs = [(k, Path(p)) for k, p in inputs]
    _refuse_inputs("output", out, real, inputs)
    entries = _directory_entries(out, "output", "its output directory", "the directory's")
    if not entries:
        return
    marker = _read_marker(out, OUTPUT_MARKER, _OUTPUT_FORMAT)
    if marker is None:
        raise UnsafePathError(f"output {out} is a directory hirad did not make and is not empty "
                              f"({_shown(entries)}); hirad replaces its whole output, so give a new or empty directory")
    foreign = _foreign_entries(out, marker)
    if foreign:
        raise UnsafePathError(f"output {out} holds files hirad did not write ({_shown(foreign)}); hirad replaces its "
                              "whole output, so move them out or give another output")


def staging_prefix(out_dir: Path) -> str:
    return f".{out_dir.name}.partial-"


def make_staging(out_dir: str | os.PathLike, version: str = "") -> Path:
    """The hidden sibling `.NAME.partial-PID-X/` where a bake assembles its outputs, with the
    marker in it from the start (so a later bake knows it may remove it)."""
    out = Path(out_dir)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise WriteError(f"output {out}: cannot make its parent directory: {_describe(e)}") from None
    # the pid (for the stale check) and a token (two bakes of one process never share one)
    for _ in range(100):
        staging = out.parent / f"{staging_prefix(out)}{os.getpid()}-{secrets.token_hex(3)}"
        try:
            staging.mkdir()
            break
        except FileExistsError:
            continue
        except OSError as e:
            raise WriteError(f"{staging}: cannot make the staging directory: {_describe(e)}") from None
    else:
        raise WriteError(f"output {out}: no free staging directory name in {out.parent}")
    write_json(staging / OUTPUT_MARKER, {"format": _OUTPUT_FORMAT, "version": 1, "hirad_version": version,
                                         "complete": False, "pid": os.getpid()})
    return staging


def finish_staging(staging: Path, version: str = "") -> None:
    """The marker of a complete output: what hirad wrote there, so that a later bake replaces
    the directory only while it holds nothing else."""
    files = sorted(rel for rel in _entries(staging) if rel != OUTPUT_MARKER)
    write_json(staging / OUTPUT_MARKER, {"format": _OUTPUT_FORMAT, "version": 1, "hirad_version": version,
                                         "complete": True, "files": files})


def replace_output(staging: Path, out_dir: str | os.PathLike, inputs: Iterable = ()) -> None:
    """Moves a complete staging directory to `out_dir`: the old output (checked again) is renamed
    aside, the new one renamed in, then the old one removed."""
    out = Path(out_dir)
    check_output(out, inputs)
    aside = None
    if os.path.lexists(out):
        aside = out.parent / f".{out.name}.old-{os.getpid()}-{secrets.token_hex(3)}"
        try:
            os.rename(out, aside)
        except OSError as e:
            raise WriteError(f"output {out}: cannot move the previous output aside: {_describe(e)}") from None
    try:
        os.rename(staging, out)
    except OSError as e:
        if aside is not None:
            os.rename(aside, out)
        raise WriteError(f"output {out}: cannot move the new output into place: {_describe(e)}") from None
    with contextlib.suppress(OSError):
        _fsync_directory(out.parent)
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)


def note_written(path: str | os.PathLike) -> None:
    """Records a file hirad wrote into one of its outputs after the bake (`hirad render`'s
    render.png beside the solution, probe -o there) in that output's marker, so the next bake
    may replace it. Only files directly in the output or in directories hirad made there."""
    path = Path(os.path.abspath(path))
    for root in path.parents:
        marker = _read_marker(root, OUTPUT_MARKER, _OUTPUT_FORMAT)
        if marker is None:
            continue
        if not marker.get("complete"):
            return
        rel = os.path.relpath(path, root)
        listed = set(marker.get("files") or [])
        parents = [str(p) for p in Path(rel).parents if str(p) != "."]
        if rel in listed or any(p not in listed for p in parents):
            return
        marker["files"] = sorted(listed | {rel})
        write_json(root / OUTPUT_MARKER, marker)
        return


def pid_alive(pid: int) -> bool:
    """Whether a process of this id runs on this machine (one we may not signal counts)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_staging(out_dir: str | os.PathLike) -> list[Path]:
    """Removes what killed bakes of this output left beside it: `.NAME.partial-PID[-X]/` staging
    directories and `.NAME.old-PID-X/` previous outputs (a kill during the swap), only those
    that carry hirad's marker and whose process is gone. Returns what was removed."""
    out = Path(out_dir)
    prefixes = (staging_prefix(out), f".{out.name}.old-")
    removed = []
    try:
        names = os.listdir(out.parent)
    except OSError:
        return removed
    for name in names:
        prefix = next((p for p in prefixes if name.startswith(p)), None)
        if prefix is None:
            continue
        pid = name[len(prefix):].split("-")[0]
        if not pid.isdigit() or int(pid) == os.getpid() or pid_alive(int(pid)):
            continue
        p = out.parent / name
        if p.is_symlink() or not p.is_dir() or _read_marker(p, OUTPUT_MARKER, _OUTPUT_FORMAT) is None:
            continue
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


# --------------------------------------------------------------------------------------
# the link store
# --------------------------------------------------------------------------------------


def check_link_store(store: str | os.PathLike, out_dir: str | os.PathLike,
                     inputs: Iterable[tuple[str, str | os.PathLike]] = ()) -> None:
    """Refuses a link store the engine may not clear: one that is, lies inside or contains the
    output, contains an input, is a link, is not a directory, or is a non-empty directory hirad
    did not make."""
    store, out = Path(store), Path(out_dir)
    real, real_out = _real(store), _real(out)
    if _inside(real, real_out):
        raise UnsafePathError(f"links.store {store} is or lies inside the output {out}, which each bake "
                              "replaces; put the store beside the output")
    if _inside(real_out, real):
        raise UnsafePathError(f"links.store {store} contains the output {out}; put the store beside the output")
    _refuse_inputs("links.store", store, real, [(k, Path(p)) for k, p in inputs])
    entries = _directory_entries(store, "links.store", "its link store", "the store's")
    if entries and _read_marker(store, STORE_MARKER, _STORE_FORMAT) is None:
        raise UnsafePathError(f"links.store {store} is a directory hirad did not make and is not empty "
                              f"({_shown(entries)}); "
                              "hirad clears its store's entries, so give a new or empty directory")


def make_link_store(store: str | os.PathLike, version: str = "") -> Path:
    """Creates the store directory (if needed) with hirad's marker; call after check_link_store."""
    store = Path(store)
    try:
        store.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise WriteError(f"links.store {store}: cannot make the directory: {_describe(e)}") from None
    if _read_marker(store, STORE_MARKER, _STORE_FORMAT) is None:
        write_json(store / STORE_MARKER, {"format": _STORE_FORMAT, "version": 1, "hirad_version": version})
    return store


# --------------------------------------------------------------------------------------
# cleanup when a signal ends the process
# --------------------------------------------------------------------------------------

_cleanup_lock = threading.RLock()
_cleanups: dict[int, Path] = {}


@contextlib.contextmanager
def removed_on_failure(directory: Path) -> Iterator[None]:
    """A directory that is removed if the block raises (anything, KeyboardInterrupt and
    hirad.interrupts.Interrupted included) and, while the block runs, by hirad.interrupts'
    watchdog if a signal ends the process (the engine may hold the main thread in C++ for
    minutes). It stays registered until it is removed, so the watchdog never exits half way
    through the main thread's removal."""
    key = id(directory)
    with _cleanup_lock:
        _cleanups[key] = directory
    try:
        yield
    except BaseException:
        shutil.rmtree(directory, ignore_errors=True)
        raise
    finally:
        with _cleanup_lock:
            _cleanups.pop(key, None)


def cleanup_lock() -> threading.RLock:
    """Held while a bake swaps its output in, so that a signal's cleanup waits for the swap."""
    return _cleanup_lock


def run_cleanups() -> None:
    """Removes every registered directory (called by the signal path; idempotent)."""
    with _cleanup_lock:
        for d in list(_cleanups.values()):
            shutil.rmtree(d, ignore_errors=True)
            if os.path.lexists(d):  # a writer made something meanwhile: once more
                shutil.rmtree(d, ignore_errors=True)
        _cleanups.clear()
