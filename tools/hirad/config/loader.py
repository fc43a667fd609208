"""Reading a YAML config: located errors (file, line, key), unknown keys with suggestions, YAML 1.2 numbers, relative paths resolved against the config's folder."""

from __future__ import annotations

import difflib
import os
import re
import stat
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import yaml
from pydantic import (
    BaseModel,
    ValidationError,
)
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode
from .errors import ConfigError, DICT_SOURCE
from .schema import Config
from hirad.studies.spec import CorridorGrid, PointsGrid, RectangleGrid, WorkplaneGrid


# --------------------------------------------------------------------------
# YAML reading
# --------------------------------------------------------------------------


# A config is a few kilobytes; these bound what reading one may cost (PyYAML composes about
# 10,000 nodes a second and scans about 0.4 MB of comment a second, so an unbounded file or
# alias expansion could take minutes).
MAX_CONFIG_BYTES = 1 << 20  # 1 MiB
MAX_YAML_NODES = 10_000  # values in the document, aliases counted each time they are used (a config has ~200)


class _TooBig(Exception):
    def __init__(self, line: int, problem: str) -> None:
        super().__init__(problem)
        self.line = line
        self.problem = problem


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats without a dot (``1e-4``), and stops composing
    a document of more than MAX_YAML_NODES nodes."""

    _nodes = 0

    def compose_node(self, parent, index):  # noqa: D401 - PyYAML's hook
        self._nodes += 1
        if self._nodes > MAX_YAML_NODES:
            mark = self.peek_event().start_mark
            raise _TooBig(mark.line + 1, f"more than {MAX_YAML_NODES} values; a config is a short mapping")
        return super().compose_node(parent, index)


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _line(node: Node) -> int:
    return node.start_mark.line + 1


def _format_key(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def _locate(root: Optional[Node], loc: tuple[Any, ...]) -> int:
    """Line of the YAML node at `loc`, or of the deepest existing ancestor.

    For a mapping entry this is the line of its key, so a missing key is
    reported at the line that opens its section (line of ``meshing:``).
    """
    if root is None:
        return 1
    node: Node = root
    line = _line(root)
    for part in loc:
        if isinstance(node, MappingNode) and isinstance(part, str):
            for key_node, value_node in node.value:
                if isinstance(key_node, ScalarNode) and key_node.value == part:
                    line, node = _line(key_node), value_node
                    break
            else:
                return line
        elif isinstance(node, SequenceNode) and isinstance(part, int):
            if not 0 <= part < len(node.value):
                return line
            node = node.value[part]
            line = _line(node)
        else:
            return line
    return line


def _expanded_size(root: Node) -> None:
    """Refuses a document whose aliases expand to more than MAX_YAML_NODES values (nested
    aliases grow exponentially: the "billion laughs") or refer to themselves.  Each node is
    sized once (memoised by identity), so this costs one pass over the distinct nodes."""
    size: dict[int, int] = {}
    open_: set[int] = set()
    stack: list[tuple[Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children: list[Node] = []
        if isinstance(node, SequenceNode):
            children = list(node.value)
        elif isinstance(node, MappingNode):
            children = [n for pair in node.value for n in pair]
        if done:
            open_.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in children)
            if size[key] > MAX_YAML_NODES:
                raise _TooBig(_line(node), f"YAML aliases expand this value to more than {MAX_YAML_NODES} values"
                                           " (nested aliases, a 'billion laughs' document?)")
            continue
        if key in size:
            continue
        if key in open_:
            raise _TooBig(_line(node), "a YAML alias refers to the value that contains it (a recursive alias)")
        open_.add(key)
        stack.append((node, True))
        for c in children:
            if id(c) in open_:
                raise _TooBig(_line(c), "a YAML alias refers to the value that contains it (a recursive alias)")
            if id(c) not in size:
                stack.append((c, False))


def _check_keys(node: Optional[Node], loc: tuple[Any, ...], found: list[tuple[int, str, str]],
                seen_nodes: Optional[set[int]] = None) -> None:
    """Find duplicate and non-string mapping keys, which validation cannot see.  A node reached
    again through an alias is checked once (its problems are the same wherever it is used)."""
    if seen_nodes is None:
        seen_nodes = set()
    if node is None or id(node) in seen_nodes:
        return
    seen_nodes.add(id(node))
    if isinstance(node, MappingNode):
        seen: dict[str, int] = {}
        for key_node, value_node in node.value:
            if isinstance(key_node, ScalarNode) and key_node.tag == "tag:yaml.org,2002:merge":
                continue
            if not (isinstance(key_node, ScalarNode) and key_node.tag == "tag:yaml.org,2002:str"):
                text = key_node.value if isinstance(key_node, ScalarNode) else "<complex key>"
                found.append(
                    (
                        _line(key_node),
                        _format_key(loc),
                        f"key {text!r} is not a string; quote it if it is meant as a key name",
                    )
                )
                continue
            name = key_node.value
            if name in seen:
                found.append(
                    (
                        _line(key_node),
                        _format_key(loc + (name,)),
                        f"duplicate key (first given on line {seen[name]})",
                    )
                )
            else:
                seen[name] = _line(key_node)
            _check_keys(value_node, loc + (name,), found, seen_nodes)
    elif isinstance(node, SequenceNode):
        for i, item in enumerate(node.value):
            _check_keys(item, loc + (i,), found, seen_nodes)


# A grid's error location from pydantic carries the discriminator's tag after the grid's name
# (grids.office.workplane.spacing); the YAML has no such key.
_GRID_TAGS = {"workplane": WorkplaneGrid, "corridor": CorridorGrid, "rectangle": RectangleGrid, "points": PointsGrid}


def _grid_loc(loc: tuple[Any, ...]) -> tuple[tuple[Any, ...], Optional[type[BaseModel]]]:
    """`loc` without a grid's discriminator tag, and the grid model the tag names (or None)."""
    if len(loc) >= 3 and loc[0] == "grids" and loc[2] in _GRID_TAGS:
        return loc[:2] + loc[3:], _GRID_TAGS[loc[2]]
    return loc, None


def _model_at(loc: tuple[Any, ...]) -> Optional[type[BaseModel]]:
    loc, grid = _grid_loc(loc)
    if grid is not None:
        loc, model = loc[2:], grid
        for part in loc:
            field = model.model_fields.get(part) if isinstance(part, str) else None
            if field is None or not (isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel)):
                return None
            model = field.annotation
        return model
    model: Any = Config
    for part in loc:
        if not (isinstance(model, type) and issubclass(model, BaseModel)):
            return None
        field = model.model_fields.get(part) if isinstance(part, str) else None
        if field is None:
            return None
        model = field.annotation
    return model if isinstance(model, type) and issubclass(model, BaseModel) else None


def _describe(err: dict[str, Any]) -> str:
    kind = err["type"]
    loc = tuple(err["loc"])
    if kind == "missing":
        if loc and isinstance(loc[-1], int):
            return "too few values"
        return "required key is missing"
    if kind == "extra_forbidden":
        problem = "unknown key"
        model = _model_at(loc[:-1]) if not (len(loc) == 4 and loc[0] == "grids") else _GRID_TAGS.get(loc[2])
        if model is not None and isinstance(loc[-1], str):
            close = difflib.get_close_matches(loc[-1], list(model.model_fields), n=1)
            if close:
                problem += f" (did you mean {close[0]!r}?)"
            else:
                problem += "; expected one of: " + ", ".join(model.model_fields)
        return problem
    if kind == "value_error":
        return str(err.get("ctx", {}).get("error", err["msg"]))
    problem = err["msg"]
    value = err.get("input")
    if kind == "too_long":
        return problem
    if isinstance(value, (dict, list, tuple)):
        problem += f", got a {'mapping' if isinstance(value, dict) else 'list'}"
    else:
        shown = repr(value)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        problem += f", got {shown}"
        if isinstance(value, str) and kind in ("int_type", "float_type", "bool_type"):
            problem += " (a string; remove the quotes)"
    return problem


def _validate(
    data: Any, *, file: str, root: Optional[Node], base_dir: Path, name: Optional[str],
    overrides: Optional[dict[tuple[Any, ...], str]] = None,
) -> Config:
    overrides = overrides or {}

    def where(loc: tuple[Any, ...]) -> tuple[str, int]:
        """The place to name for a problem at `loc`: the --set argument that gave it (or gave a
        value inside it), else the file and line."""
        label = _override_for(overrides, loc)
        if label is not None:
            return label, 0
        return file, (_locate(root, loc) if root is not None else 0)

    if not isinstance(data, dict):
        line = _line(root) if root is not None else (1 if file != DICT_SOURCE else 0)
        got = "nothing" if data is None else type(data).__name__
        raise ConfigError(file, line, "", f"the config must be a mapping of keys to values, got {got}")
    problems: list[ConfigError] = []
    try:
        config = Config.model_validate(data, context={"base_dir": base_dir, "name": name})
    except ValidationError as exc:
        for err in exc.errors(include_url=False):
            loc = _grid_loc(tuple(err["loc"]))[0]
            if loc[:1] == ("light_groups",):  # written lights.groups (schema.Config._lights_mapping)
                loc = ("lights", "groups") + loc[1:]
            elif loc[:1] == ("lights",) and len(loc) > 1 and isinstance(data.get("lights"), dict):
                loc = ("lights", "points") + loc[1:]  # the points of a lights: mapping
            problems.append(ConfigError(*where(loc), _format_key(loc), _describe(err)))
    else:
        for loc, problem in _grid_file_problems(config) + _light_file_problems(config):
            problems.append(ConfigError(*where(loc), _format_key(loc), problem))
    if problems:
        problems.sort(key=lambda e: (e.file != file, e.line))
        first = problems[0]
        first.errors = problems
        raise first from None
    return config


def _grid_file_problems(config: Config) -> list[tuple[tuple[Any, ...], str]]:
    """Points grids whose file (resolved against the config's folder) is not a readable file."""
    out = []
    for name, spec in config.grids.items():
        if isinstance(spec, PointsGrid):
            path = Path(spec.file)
            if not path.exists():
                out.append((("grids", name, "file"), f"grid points file not found: {path}"))
            elif not path.is_file():
                out.append((("grids", name, "file"), f"grid points file is not a file: {path}"))
    return out


def _light_file_problems(config: Config) -> list[tuple[tuple[Any, ...], str]]:
    """Lights whose IES file (resolved against the config's folder) is missing or unreadable
    (the IES reader's message names the file, the line and the problem)."""
    out = []
    for i, light in enumerate(config.lights):
        if light.ies is None:
            continue
        path = Path(light.ies)
        if not path.exists():
            out.append((("lights", i, "ies"), f"IES file not found: {path}"))
        elif not path.is_file():
            out.append((("lights", i, "ies"), f"IES file is not a file: {path}"))
        else:
            import warnings

            from hirad.photometry.ies import IesError, IesWarning, read_ies
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", IesWarning)
                    read_ies(path)
            except IesError as exc:
                out.append((("lights", i, "ies"), f"bad IES file: {exc}"))
            except OSError as exc:
                out.append((("lights", i, "ies"), f"IES file cannot be read: {path} ({exc.strerror or exc})"))
    return out


def config_line(file: Union[str, os.PathLike[str]], loc: tuple[Any, ...]) -> int:
    """The line of the key at `loc` in a config file (its deepest existing ancestor's; 0 when
    the file cannot be read again), for errors found after loading (a grid that has no
    point, found when the scene's up axis is known)."""
    try:
        loader = _Loader(_read_text(os.fspath(file)))
        try:
            root = loader.get_single_node()
        finally:
            loader.dispose()
    except (ConfigError, yaml.YAMLError, _TooBig, RecursionError):
        return 0
    return _locate(root, loc) if root is not None else 0


# --------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------


_FILE_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
               (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _not_regular(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "config path is a directory, not a file"
    kind = next((name for test, name in _FILE_KINDS if test(mode)), "not a regular file")
    return f"config path is {kind}, not a regular file"


def _read_text(file: str) -> str:
    """The config file's text: a regular file of at most MAX_CONFIG_BYTES, UTF-8.  A FIFO or a
    device (``/dev/zero``) is refused before it is opened, and opened without blocking in case
    it is swapped in between; at most MAX_CONFIG_BYTES + 1 bytes are ever read."""
    try:
        mode = os.stat(file).st_mode
    except FileNotFoundError:
        raise ConfigError(file, 0, "", "config file not found") from None
    except OSError as exc:
        raise ConfigError(file, 0, "", f"cannot read config file: {exc.strerror or exc}") from None
    except ValueError as exc:  # a NUL byte in the path
        raise ConfigError(repr(file), 0, "", f"not a usable path ({exc})") from None
    if not stat.S_ISREG(mode):
        raise ConfigError(file, 0, "", _not_regular(mode))
    try:
        fd = os.open(file, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise ConfigError(file, 0, "", f"cannot read config file: {exc.strerror or exc}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise ConfigError(file, 0, "", _not_regular(mode))
        chunks, total = [], 0
        while total <= MAX_CONFIG_BYTES:
            chunk = os.read(fd, MAX_CONFIG_BYTES + 1 - total)
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    except OSError as exc:
        raise ConfigError(file, 0, "", f"cannot read config file: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if total > MAX_CONFIG_BYTES:
        raise ConfigError(file, 0, "", f"config file is larger than {MAX_CONFIG_BYTES >> 20} MiB; a config is a few"
                                       " kilobytes of YAML")
    try:
        return b"".join(chunks).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(file, 0, "", f"config file is not UTF-8 text ({exc.reason})") from None


# --------------------------------------------------------------------------
# Overrides: `hirad bake CONFIG --set key=value`
# --------------------------------------------------------------------------

_KEY_PART = re.compile(r"(?:^|\.)([^.\[\]=\s]+)|\[(\d+)\]")


def parse_key(key: str, label: str) -> tuple[Any, ...]:
    """A dotted key (`outputs.lightmaps.texels_per_metre`, `lights[0].intensity`) as a location
    tuple; a ConfigError named by `label` when it is not one."""
    key = key.strip()
    loc: list[Any] = []
    pos = 0 if not key.startswith(".") else len(key) + 1
    while pos < len(key):
        m = _KEY_PART.match(key, pos)
        if m is None or m.end() == pos:
            loc = []
            break
        loc.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    if not loc or not isinstance(loc[0], str):
        raise ConfigError(label, 0, key, "not a key: use dotted names such as meshing.max_patch_area or "
                                         "lights[0].intensity")
    return tuple(loc)


def parse_override(arg: str) -> tuple[tuple[Any, ...], Any, str]:
    """`KEY=VALUE` (VALUE read as YAML: `16`, `1e-4`, `true`, `[0.5, 0.5, 0.5]`, `{a: 1}`, a
    string) as (location, value, label); the label `--set KEY=VALUE` names it in errors."""
    label = f"--set {arg}"
    key, eq, text = arg.partition("=")
    if not eq or not key.strip():
        raise ConfigError(label, 0, "", "expected KEY=VALUE, e.g. --set meshing.max_patch_area=0.02")
    loc = parse_key(key, label)
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        value = loader.construct_document(node) if node is not None else None
    except _TooBig as exc:
        raise ConfigError(label, 0, _format_key(loc), exc.problem) from None
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(label, 0, _format_key(loc), f"malformed YAML value: {problem}") from None
    finally:
        loader.dispose()
    return loc, value, label


def apply_overrides(data: Any, overrides: list[tuple[tuple[Any, ...], Any, str]]) -> dict:
    """`data` (a config mapping, None for an empty file) with each override set in order;
    mappings on the way are made when missing. A ConfigError names the --set argument when its
    path crosses a value that is not a mapping (or a list, for an index)."""
    import copy

    data = {} if data is None else copy.deepcopy(data)
    if not isinstance(data, dict):
        return data  # _validate reports it
    for loc, value, label in overrides:
        node: Any = data
        for depth, part in enumerate(loc[:-1]):
            here = _format_key(loc[:depth + 1])
            if isinstance(part, int):
                if not isinstance(node, list):
                    raise ConfigError(label, 0, _format_key(loc), f"{_format_key(loc[:depth]) or 'the config'} is "
                                                                  "not a list")
                if part >= len(node):
                    raise ConfigError(label, 0, _format_key(loc), f"{here}: the list has {len(node)} entries")
                node = node[part]
                continue
            if not isinstance(node, dict):
                raise ConfigError(label, 0, _format_key(loc), f"{_format_key(loc[:depth])} is not a mapping")
            if node.get(part) is None:
                node[part] = [] if isinstance(loc[depth + 1], int) else {}
            node = node[part]
        last = loc[-1]
        if isinstance(last, int):
            if not isinstance(node, list):
                raise ConfigError(label, 0, _format_key(loc), f"{_format_key(loc[:-1])} is not a list")
            if last > len(node):
                raise ConfigError(label, 0, _format_key(loc), f"{_format_key(loc[:-1])} has {len(node)} entries")
            if last == len(node):
                node.append(value)
            else:
                node[last] = value
        else:
            if not isinstance(node, dict):
                raise ConfigError(label, 0, _format_key(loc), f"{_format_key(loc[:-1])} is not a mapping")
            node[last] = value
    return data


def _override_for(overrides: dict[tuple[Any, ...], str], loc: tuple[Any, ...]) -> Optional[str]:
    """The --set argument a problem at `loc` comes from: the last one that set `loc` or a key
    above it, else (for a problem of a whole section, such as two lights' settings that
    contradict) one that set a key inside it."""
    best = None
    for key, label in overrides.items():
        if loc[:len(key)] == key:
            best = label
    if best is None and loc:
        for key, label in overrides.items():
            if key[:len(loc)] == loc:
                best = label
    return best


def load_config(path: Union[str, os.PathLike[str]], overrides: Sequence[str] = ()) -> Config:
    """Read and validate a YAML config file, with `overrides` (`KEY=VALUE` strings, as
    `hirad bake --set`) applied on top before validation.

    Raises :class:`ConfigError` for an unreadable file, malformed YAML, unknown
    keys, wrong types, out-of-range values, missing required keys and a scene
    file that does not exist. A problem with a value an override gave is named by its
    ``--set KEY=VALUE`` argument instead of a file and line.
    """
    parsed = [parse_override(arg) for arg in overrides]
    file = os.fspath(path)
    config_path = Path(file)
    text = _read_text(file)

    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        if root is not None:
            _expanded_size(root)
        data = loader.construct_document(root) if root is not None else None
    except _TooBig as exc:
        raise ConfigError(file, exc.line, "", exc.problem) from None
    except RecursionError:
        raise ConfigError(file, 0, "", "malformed YAML: values nested too deeply") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else 0
        problem = ": ".join(p for p in (exc.context, exc.problem) if p) or "malformed YAML"
        raise ConfigError(file, line, "", f"malformed YAML: {problem}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(file, 0, "", f"malformed YAML: {exc}") from None
    finally:
        loader.dispose()

    key_problems: list[tuple[int, str, str]] = []
    _check_keys(root, (), key_problems)
    if key_problems:
        errors = [ConfigError(file, line, key, problem) for line, key, problem in sorted(key_problems)]
        errors[0].errors = errors
        raise errors[0]

    base_dir = config_path.expanduser().absolute().parent
    if parsed:
        data = apply_overrides(data, parsed)
    return _validate(data, file=file, root=root, base_dir=base_dir, name=config_path.stem,
                     overrides={loc: label for loc, _, label in parsed})


def config_from_dict(
    d: dict[str, Any],
    base_dir: Union[str, os.PathLike[str], None] = None,
    name: Optional[str] = None,
) -> Config:
    """Validate a config given as a Python mapping (same rules as a file).

    Relative paths resolve against `base_dir` (default: the current
    directory).  The default output directory is ``<base_dir>/out/<name>``,
    where `name` defaults to the scene file's stem.  Errors name ``"<dict>"``
    as their file, with line 0.
    """
    base = Path(base_dir).expanduser().absolute() if base_dir is not None else Path.cwd()
    return _validate(d, file=DICT_SOURCE, root=None, base_dir=base, name=name)
