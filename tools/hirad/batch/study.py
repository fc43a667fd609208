"""The study file of `hirad batch`.

    base: cornell.yaml              # the base config (relative to this file)
    output: out/cornell-study       # where the jobs' outputs go [out/<study name> beside this file]
    set:                            # overrides for every job (dotted keys, as hirad bake --set)
      outputs.preview.enabled: false
    variants:                       # a list of jobs: each a name and its overrides...
      - name: dark
        set: {materials.default_reflectance: [0.2, 0.2, 0.2]}
      - name: overlay
        config: brighter.yaml       # ...and/or a YAML overlay file (a mapping of config keys)
    matrix:                         # every combination of these values (crossed with the variants)
      hierarchy.epsilon: [1.0e-3, 1.0e-4]
    workers: 2                      # LocalCluster worker processes
    jobs_per_worker: 1              # Dask threads per worker: bakes one worker runs at once
    threads: 1                      # the engine threads of each bake (--threads) [cores / workers]
    retries: 2                      # a failed run of a job is tried again this many times
    timeout: 3600                   # seconds a job may run [none]
    share_links: false              # out-of-core jobs of one geometry share one link store
    cluster: local                  # local | slurm | pbs | sge (dask-jobqueue) | scheduler address
    cluster_options: {}             # for dask-jobqueue: queue, account, cores, memory, walltime...

A job's overrides are the study's `set`, then its variant's `config` and `set`, then its
matrix values, then `output` (the study's output/jobs/<name>); each job is validated by the
config schema (hirad.config.load_config) before any job starts.
"""

from __future__ import annotations

import itertools
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional, Union

import yaml
from pydantic import BaseModel, ConfigDict, Field, Strict, ValidationError
from typing_extensions import Annotated

from ..config import ConfigError, load_config
from ..config.loader import _Loader, _describe, _format_key, _locate, _read_text, parse_key

_NAME = re.compile(r"^[A-Za-z0-9_.=+-]+$")


class StudyFileError(Exception):
    """A problem with a study file, located: `file:line: key: problem`."""

    def __init__(self, file: str, line: int, key: str, problem: str):
        self.file, self.line, self.key, self.problem = file, line, key, problem
        where = f"{file}:{line}" if line > 0 else file
        super().__init__(f"{where}: {key}: {problem}" if key else f"{where}: {problem}")


_MODEL = ConfigDict(extra="forbid", allow_inf_nan=False)
PosInt = Annotated[int, Strict(), Field(ge=1)]


class VariantSpec(BaseModel):
    model_config = _MODEL
    name: Optional[Annotated[str, Strict()]] = Field(default=None, description="The job's name (its output folder)")
    set: dict[str, Any] = Field(default_factory=dict, description="Config overrides (dotted keys or nested)")
    config: Optional[Path] = Field(default=None, description="A YAML overlay file (config keys), relative to the study")


class StudySpec(BaseModel):
    model_config = _MODEL
    base: Path = Field(description="The base config, relative to the study file")
    output: Optional[Path] = Field(default=None, description="The study's output directory")
    set: dict[str, Any] = Field(default_factory=dict)
    variants: list[VariantSpec] = Field(default_factory=list)
    matrix: dict[str, list[Any]] = Field(default_factory=dict)
    workers: PosInt = 2
    jobs_per_worker: PosInt = 1
    threads: Optional[Annotated[int, Strict(), Field(ge=0)]] = None
    retries: Annotated[int, Strict(), Field(ge=0, le=100)] = 2
    timeout: Optional[Annotated[float, Strict(), Field(gt=0)]] = Field(default=None, description="seconds a job may run")
    share_links: Annotated[bool, Strict()] = Field(
        default=False, description="Out-of-core jobs of the same geometry and refinement settings share one link "
                                   "store: the first bakes it, the others run after it with --reuse-links")
    cluster: Annotated[str, Strict()] = "local"
    cluster_options: dict[str, Any] = Field(default_factory=dict)


@dataclass
class Job:
    name: str
    overrides: list[str]          # KEY=VALUE, in order, `output=` last
    output: Path
    key: str                      # the content key (hirad.config.content)
    where: str                    # the study's place that made it (for messages)
    threads: Optional[int] = None
    report_key: str = ""          # the content key its report.json carries (the bake's own)
    after: Optional[str] = None   # share_links: the job whose links it reuses (runs after it)
    reuse_links: bool = False


@dataclass
class Study:
    path: Path
    name: str
    base: Path
    output: Path
    spec: StudySpec
    jobs: list[Job] = field(default_factory=list)

    @property
    def index_path(self) -> Path:
        return self.output / "study.sqlite"

    def job(self, name: str) -> Job:
        return next(j for j in self.jobs if j.name == name)


def _flatten(value: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """A (possibly nested) overlay mapping as dotted (key, value) pairs; lists are values."""
    if isinstance(value, dict) and not value and not prefix:
        return []
    if isinstance(value, dict) and value:
        out = []
        for k, v in value.items():
            out += _flatten(v, f"{prefix}.{k}" if prefix else str(k))
        return out
    return [(prefix, value)]


def _override(key: str, value: Any) -> str:
    return f"{key}={json.dumps(value, ensure_ascii=False, allow_nan=False)}"


def _label(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))
    return re.sub(r"[^A-Za-z0-9_.+-]+", "_", str(text)).strip("_") or "x"


def load_study(path: Union[str, os.PathLike], *, validate: bool = True) -> Study:
    """Reads a study file and builds its jobs; every job's config is validated (errors name the
    study file's line and the variant) unless `validate` is false."""
    file = os.fspath(path)
    try:
        text = _read_text(file)
    except ConfigError as e:  # missing, unreadable, too big: the loader's words
        raise StudyFileError(file, 0, "", e.problem) from None
    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        data = loader.construct_document(root) if root is not None else None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise StudyFileError(file, mark.line + 1 if mark else 0, "", f"malformed YAML: {getattr(exc, 'problem', exc)}") \
            from None
    finally:
        loader.dispose()
    if not isinstance(data, dict):
        raise StudyFileError(file, 1, "", "a study is a mapping with `base:` (a config) and `variants:` or `matrix:`")
    try:
        spec = StudySpec.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        loc = tuple(err["loc"])
        problem = _describe(err)
        if err["type"] == "extra_forbidden":
            model = VariantSpec if loc[:1] == ("variants",) else StudySpec
            problem = "unknown study key; expected one of: " + ", ".join(model.model_fields)
        raise StudyFileError(file, _locate(root, loc), _format_key(loc), problem) from None
    here = Path(file).absolute().parent
    base = (here / spec.base).resolve()
    out = (here / spec.output).resolve() if spec.output else here / "out" / Path(file).stem
    study = Study(Path(file).absolute(), Path(file).stem, base, Path(os.path.normpath(out)), spec)

    def located(loc: tuple, problem: str, key: str | None = None) -> StudyFileError:
        return StudyFileError(file, _locate(root, loc), key if key is not None else _format_key(loc), problem)

    if not base.is_file():
        raise located(("base",), f"base config not found: {base}")
    # each key must be a key (its value is checked with the config)
    for loc0, mapping in [(("set",), spec.set), (("matrix",), spec.matrix)] + \
            [(("variants", i, "set"), v.set) for i, v in enumerate(spec.variants)]:
        for k, _ in _flatten(mapping):
            try:
                parse_key(k, file)
            except ConfigError as e:
                raise located(loc0 + (k.split(".")[0],), e.problem, f"{_format_key(loc0)}.{k}") from None
    for k, values in spec.matrix.items():
        if not values:
            raise located(("matrix", k), "a matrix key needs at least one value")

    variants: list[tuple[str, list[str], tuple]] = []
    for i, v in enumerate(spec.variants):
        pairs: list[tuple[str, Any]] = []
        if v.config is not None:
            overlay = (here / v.config).resolve()
            try:
                odata = yaml.load(_read_text(str(overlay)), Loader=_Loader)
            except ConfigError as e:
                raise located(("variants", i, "config"), f"{overlay}: {e.problem}") from None
            except yaml.YAMLError as e:
                raise located(("variants", i, "config"), f"{overlay}: malformed YAML: {e}") from None
            if not isinstance(odata, dict):
                raise located(("variants", i, "config"), f"{overlay}: an overlay is a mapping of config keys")
            pairs += _flatten(odata)
        pairs += _flatten(v.set) if v.set else []
        variants.append((v.name or f"v{i}", [_override(k, x) for k, x in pairs], ("variants", i)))
    if not variants:
        variants = [("", [], ())]
    jobs_src = []
    mkeys = list(spec.matrix)
    combos = list(itertools.product(*(spec.matrix[k] for k in mkeys))) if mkeys else [()]
    for vname, vover, vloc in variants:
        for combo in combos:
            parts = [vname] if vname else []
            parts += [f"{k.split('.')[-1]}={_label(x)}" for k, x in zip(mkeys, combo)]
            name = "-".join(parts) or "base"
            over = vover + [_override(k, x) for k, x in zip(mkeys, combo)]
            jobs_src.append((name, over, vloc if vloc else (("matrix",) if mkeys else ())))
    seen: dict[str, tuple] = {}
    common = [_override(k, x) for k, x in _flatten(spec.set)] if spec.set else []
    for name, over, loc in jobs_src:
        if not _NAME.match(name):
            raise located(loc + ("name",) if loc[:1] == ("variants",) else loc,
                          f"job name {name!r}: use letters, digits and _ . = + - (it names a folder)")
        if name in seen:
            raise located(loc, f"two jobs are named {name!r}; give the variants different names")
        seen[name] = loc
        output = study.output / "jobs" / name
        overrides = common + over + [_override("output", str(output))]
        study.jobs.append(Job(name, overrides, output, "", _format_key(loc) or "base", spec.threads))
    if validate:
        for job, (_, _, loc) in zip(study.jobs, jobs_src):
            try:
                cfg = load_config(base, job.overrides)
            except ConfigError as e:
                raise located(loc, f"job {job.name!r}: {e}", _format_key(loc) or "base") from None
            job.key = job.report_key = cfg.content_key()
            job._links_key = link_key(cfg) if spec.share_links else None
        if spec.share_links:
            _share_links(study)
    return study


def link_key(cfg) -> Optional[str]:
    """What an out-of-core bake's links depend on (the engine's store fingerprints: the scene's
    geometry and luminaires, hierarchy.*, seed, links.group_faces), conservatively: the scene
    files' whole contents, the config's lights and those settings; None for a bake that keeps
    no links."""
    import hashlib

    from .. import __version__
    from ..config.content import content_inputs

    if not (cfg.method == "hierarchical" and cfg.solver.method == "block_southwell"):
        return None
    inputs = content_inputs(cfg)
    settings = inputs["settings"]
    keep = {"hierarchy": settings["hierarchy"], "seed": settings["seed"], "lights": settings.get("lights"),
            "group_faces": settings["links"]["group_faces"], "scene": settings["scene"],
            "photometry": settings.get("photometry")}
    text = json.dumps({"v": __version__, "files": inputs["scene_files"], "settings": keep}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _share_links(study: Study) -> None:
    """Jobs of one link key share `<output>/links/<key>`: the first bakes the links, each of the
    others runs after the previous one with --reuse-links (one store is never written by two
    bakes at once). A reusing job's key covers the links' job's key (its result depends on
    which links it solves on)."""
    import hashlib

    previous: dict[str, Job] = {}
    for job in study.jobs:
        lk = getattr(job, "_links_key", None)
        if lk is None:
            continue
        store = study.output / "links" / lk[:16]
        job.overrides.insert(len(job.overrides) - 1, _override("links.store", str(store)))
        first = previous.get(lk)
        if first is not None:
            owner = next(j for j in study.jobs if getattr(j, "_links_key", None) == lk)
            job.after, job.reuse_links = first.name, True
            job.key = hashlib.sha256(f"{job.report_key}+links:{owner.key}".encode()).hexdigest()
        previous[lk] = job
