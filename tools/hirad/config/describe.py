"""The config schema as text: every key with its type, default, unit, allowed range and
description, read from the pydantic models themselves (so it cannot drift from what is
validated).  `hirad config --schema` prints :func:`schema_text`.
"""

from __future__ import annotations

import json
import textwrap
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator, Literal, Optional, Union

from annotated_types import Ge, Gt, Le, Lt, MaxLen, MinLen
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from .schema import Config

_WIDTH = 92


@dataclass
class KeyInfo:
    """One key of the schema, as :func:`keys` lists it."""

    key: str  # dotted path, e.g. "meshing.max_patch_area"
    section: bool  # a mapping of further keys
    type: str
    default: str  # YAML text of the default; "(required)" when there is none
    unit: str
    limits: str  # e.g. "> 0, <= 4096"
    description: str


def _is_model(annotation: Any) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, BaseModel)


def _metadata_limits(metadata: list) -> list[str]:
    out = []
    for m in metadata:
        if isinstance(m, Gt):
            out.append(f"> {m.gt:g}" if isinstance(m.gt, float) else f"> {m.gt}")
        elif isinstance(m, Ge):
            out.append(f">= {m.ge:g}" if isinstance(m.ge, float) else f">= {m.ge}")
        elif isinstance(m, Lt):
            out.append(f"< {m.lt:g}" if isinstance(m.lt, float) else f"< {m.lt}")
        elif isinstance(m, Le):
            out.append(f"<= {m.le:g}" if isinstance(m.le, float) else f"<= {m.le}")
        elif isinstance(m, MinLen):
            out.append(f"at least {m.min_length} items")
        elif isinstance(m, MaxLen):
            out.append(f"at most {m.max_length} items")
        elif isinstance(m, FieldInfo):
            out += _metadata_limits(list(m.metadata))
    return out


def _type_name(annotation: Any) -> str:
    """A YAML-minded name of a (possibly Annotated, Optional, Literal) type."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Annotated:
        inner = _type_name(args[0])
        limits = _metadata_limits(list(args[1:]))
        return f"{inner} ({', '.join(limits)})" if limits else inner
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in args)
    if origin in (Union, types.UnionType):
        names = [_type_name(a) for a in args if a is not type(None)]
        text = " or ".join(names)
        return text + " or null" if type(None) in args else text
    if origin is tuple:
        return "[" + ", ".join(_type_name(a) for a in args) + "]"
    if origin is list:
        return f"list of {_type_name(args[0])}" if args else "list"
    return {int: "integer", float: "number", bool: "true or false", str: "string", Path: "path"}.get(
        annotation, getattr(annotation, "__name__", str(annotation)))


def _default_text(field: FieldInfo) -> str:
    if field.is_required():
        return "(required)"
    if field.default_factory is not None:
        value = field.default_factory()
    else:
        value = field.default
    if value is PydanticUndefined:
        return "(required)"
    if isinstance(value, BaseModel):
        return "(section)"
    if value is None:
        return "null"
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, tuple):
        value = list(value)
    return json.dumps(value)


def _limits(field: FieldInfo, extra: dict) -> str:
    limits = _metadata_limits(list(field.metadata))
    floor = extra.get("at_least")
    if floor is not None:  # a floor checked by a validator replaces the bare "> 0"
        limits = [x for x in limits if not x.startswith((">", ">="))]
        limits.insert(0, f">= {floor:g}")
    return ", ".join(limits)


def _walk(model: type[BaseModel], prefix: str) -> Iterator[KeyInfo]:
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
        if _is_model(field.annotation):
            yield KeyInfo(key, True, "section", "", "", "", field.description or "")
            yield from _walk(field.annotation, key + ".")
            continue
        yield KeyInfo(
            key=key,
            section=False,
            type=_type_name(field.annotation),
            default=_default_text(field),
            unit=str(extra.get("unit", "")),
            limits=_limits(field, extra),
            description=field.description or "",
        )


def keys() -> list[KeyInfo]:
    """Every key of the config schema, sections first then their keys, in schema order."""
    return list(_walk(Config, ""))


def _section_doc(key: str) -> str:
    model: Any = Config
    for part in key.split("."):
        model = model.model_fields[part].annotation
    return (model.__doc__ or "").strip()


def schema_text(width: int = _WIDTH) -> str:
    """The whole schema as plain text: one block per key (type, default, unit, range,
    description), grouped by section as the YAML nests them."""
    doc = (Config.__doc__ or "").strip().splitlines()[0]
    lines = [f"hirad config schema: {doc}", "Only `scene` is required; every other key has the default shown.",
             "Lengths are metres, areas square metres; relative paths resolve against the config's folder.", ""]
    for k in keys():
        depth = k.key.count(".")
        pad = "  " * depth
        name = k.key.rsplit(".", 1)[-1]
        body_pad = pad + "    "
        if k.section:
            lines.append(f"{pad}{name}:")
            text = _section_doc(k.key) or k.description
            for para in text.split("\n\n"):
                lines += textwrap.wrap(" ".join(para.split()), width, initial_indent=body_pad,
                                       subsequent_indent=body_pad)
            continue
        head = f"{pad}{name}: {k.type}"
        lines.append(head)
        facts = [f"default {k.default}"]
        if k.unit:
            facts.append(f"unit: {k.unit}")
        if k.limits:
            facts.append(f"range: {k.limits}")
        lines += textwrap.wrap("; ".join(facts), width, initial_indent=body_pad, subsequent_indent=body_pad)
        lines += textwrap.wrap(k.description, width, initial_indent=body_pad, subsequent_indent=body_pad)
    return "\n".join(lines) + "\n"


__all__ = ["KeyInfo", "keys", "schema_text"]
