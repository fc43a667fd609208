"""Reading a YAML config: located errors (file, line, key), unknown keys with suggestions, YAML 1.2 numbers, relative paths resolved against the config's folder."""

from __future__ import annotations

import difflib
import os
import re
from pathlib import Path
from typing import Any, Optional, Union

import yaml
from pydantic import (
    BaseModel,
    ValidationError,
)
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode
from .errors import ConfigError, DICT_SOURCE
from .schema import Config


# --------------------------------------------------------------------------
# YAML reading
# --------------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats without a dot (``1e-4``)."""


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


def _check_keys(node: Optional[Node], loc: tuple[Any, ...], found: list[tuple[int, str, str]]) -> None:
    """Find duplicate and non-string mapping keys, which validation cannot see."""
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
            _check_keys(value_node, loc + (name,), found)
    elif isinstance(node, SequenceNode):
        for i, item in enumerate(node.value):
            _check_keys(item, loc + (i,), found)


def _model_at(loc: tuple[Any, ...]) -> Optional[type[BaseModel]]:
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
        model = _model_at(loc[:-1])
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
    data: Any, *, file: str, root: Optional[Node], base_dir: Path, name: Optional[str]
) -> Config:
    if not isinstance(data, dict):
        line = _line(root) if root is not None else (1 if file != DICT_SOURCE else 0)
        got = "nothing" if data is None else type(data).__name__
        raise ConfigError(file, line, "", f"the config must be a mapping of keys to values, got {got}")
    problems: list[ConfigError] = []
    try:
        config = Config.model_validate(data, context={"base_dir": base_dir, "name": name})
    except ValidationError as exc:
        for err in exc.errors(include_url=False):
            loc = tuple(err["loc"])
            line = _locate(root, loc) if root is not None else 0
            problems.append(ConfigError(file, line, _format_key(loc), _describe(err)))
        problems.sort(key=lambda e: e.line)
        first = problems[0]
        first.errors = problems
        raise first from None
    return config


# --------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------


def load_config(path: Union[str, os.PathLike[str]]) -> Config:
    """Read and validate a YAML config file.

    Raises :class:`ConfigError` for an unreadable file, malformed YAML, unknown
    keys, wrong types, out-of-range values, missing required keys and a scene
    file that does not exist.
    """
    file = os.fspath(path)
    config_path = Path(file)
    try:
        text = config_path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(file, 0, "", "config file not found") from None
    except IsADirectoryError:
        raise ConfigError(file, 0, "", "config path is a directory, not a file") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(file, 0, "", f"config file is not UTF-8 text ({exc.reason})") from None
    except OSError as exc:
        raise ConfigError(file, 0, "", f"cannot read config file: {exc.strerror or exc}") from None

    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        data = loader.construct_document(root) if root is not None else None
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
    return _validate(data, file=file, root=root, base_dir=base_dir, name=config_path.stem)


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
