"""Writes the engine's API from its bindings: tools/hirad/_engine.pyi (nanobind's stubgen) and
docs/engine-api.md (rendered from that stub's signatures and docstrings).

    python tools/gen_engine_api.py                       # uses the installed hirad._engine
    python tools/gen_engine_api.py --module-dir DIR      # the _engine built in DIR (CMake does this)

The build runs it after every build of the module (CMakeLists.txt), so both files always
describe the module that was built; a change in the bindings shows as a change in them.
"""

from __future__ import annotations

import argparse
import ast
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
STUB = REPO / "tools" / "hirad" / "_engine.pyi"
DOC = REPO / "docs" / "engine-api.md"


def write_stub(module_dir: str | None) -> str:
    """Runs nanobind.stubgen on the module; returns the stub's text."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "_engine.pyi"
        if module_dir:
            cmd = [sys.executable, "-m", "nanobind.stubgen", "-q", "-i", module_dir, "-m", "_engine", "-o", str(out)]
        else:
            cmd = [sys.executable, "-m", "nanobind.stubgen", "-q", "-m", "hirad._engine", "-o", str(out)]
        subprocess.run(cmd, check=True)
        text = out.read_text()
    _write_if_changed(STUB, text)
    return text


def _write_if_changed(path: Path, text: str) -> None:
    if not path.exists() or path.read_text() != text:
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(path)


def _signature(fn: ast.FunctionDef, drop_self: bool) -> str:
    args = fn.args.args[1:] if drop_self else fn.args.args
    defaults = [None] * (len(args) - len(fn.args.defaults)) + list(fn.args.defaults)
    parts = []
    for a, d in zip(args, defaults):
        text = a.arg
        if a.annotation is not None:
            text += ": " + _short(ast.unparse(a.annotation))
        if d is not None:
            text += " = " + ast.unparse(d)
        parts.append(text)
    ret = "" if fn.returns is None else " -> " + _short(ast.unparse(fn.returns))
    return f"{fn.name}({', '.join(parts)}){ret}"


def _short(annotation: str) -> str:
    # Annotated[NDArray[numpy.float64], dict(...)] -> ndarray[float64]
    if annotation.startswith("Annotated[NDArray[numpy."):
        return "ndarray[" + annotation[len("Annotated[NDArray[numpy."):].split("]", 1)[0] + "]"
    if annotation.startswith("NDArray[numpy."):
        return "ndarray[" + annotation[len("NDArray[numpy."):].split("]", 1)[0] + "]"
    return annotation


def _doc(node) -> str:
    d = ast.get_docstring(node)
    return " ".join(d.split()) if d else ""


def render(stub: str) -> str:
    tree = ast.parse(stub)
    lines = ["# hirad engine API (module `hirad._engine`)", "",
             "Generated from the bindings by `tools/gen_engine_api.py` (the build runs it); do not edit. "
             "The same API with full types: `tools/hirad/_engine.pyi`. The C++ side: "
             "`pipeline/engine/engine.h` (the engine), `pipeline/engine/ray_scene.h` (SurfaceField), "
             "`pipeline/engine/rounds.h` (the refine -> solve loop).", "",
             "Conventions: arrays are C-contiguous numpy, float64 for geometry and colours, int32 for indices; "
             "metres, m^2; radiosity, irradiance and emission in W/m^2 per RGB channel, radiance in "
             "W/(m^2 sr). Result structs return a fresh numpy copy on every attribute access.", ""]
    functions = [n for n in tree.body if isinstance(n, ast.FunctionDef)]
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    if _doc(tree):
        lines += [_doc(tree), ""]
    lines += ["## Functions", ""]
    for fn in functions:
        lines.append(f"- `{_signature(fn, False)}`: {_doc(fn)}")
    lines.append("")
    for cls in classes:
        lines += [f"## {cls.name}", ""]
        if _doc(cls):
            lines += [_doc(cls), ""]
        seen = set()
        for item in cls.body:
            if not isinstance(item, ast.FunctionDef) or item.name in seen:
                continue
            decorators = [ast.unparse(d) for d in item.decorator_list]
            if any(d.endswith(".setter") for d in decorators):
                continue
            seen.add(item.name)
            if "property" in decorators:
                writable = any(isinstance(o, ast.FunctionDef) and
                               any(ast.unparse(d) == f"{item.name}.setter" for d in o.decorator_list)
                               for o in cls.body)
                kind = "" if writable else " (read-only)"
                ret = "" if item.returns is None else ": " + _short(ast.unparse(item.returns))
                lines.append(f"- `{item.name}{ret}`{kind}: {_doc(item)}".rstrip(": "))
            elif item.name == "__init__":
                lines.append(f"- `{cls.name}{_signature(item, True)[len('__init__'):]}`: {_doc(item)}".rstrip(": "))
            elif not item.name.startswith("_") or item.name == "__len__":
                lines.append(f"- `{_signature(item, True)}`: {_doc(item)}".rstrip(": "))
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--module-dir", help="directory holding the built _engine module (default: import hirad._engine)")
    args = ap.parse_args()
    stub = write_stub(args.module_dir)
    _write_if_changed(DOC, render(stub))


if __name__ == "__main__":
    main()
