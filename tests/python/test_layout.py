"""The engine's layout, checked: includes are rooted and acyclic, folders depend on each other
only along the pipeline (scene -> patches -> hierarchy -> links -> solution -> outputs), and the
bindings only bind (small files)."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)

# What each folder may include, besides itself (the pipeline order; formats/ stands apart and
# may use only pipeline/core, which holds plain data and the atomic write).
ALLOWED = {
    "formats": {"pipeline/core"},
    "pipeline/core": set(),
    "pipeline/geometry": {"pipeline/core"},
    "pipeline/flat": {"pipeline/core", "pipeline/geometry"},
    "pipeline/hierarchy": {"pipeline/core", "pipeline/geometry", "pipeline/flat"},
    "pipeline/outofcore": {"pipeline/core", "pipeline/geometry", "pipeline/flat", "pipeline/hierarchy", "formats"},
    "pipeline/outputs": {"pipeline/core", "pipeline/geometry"},
    "pipeline/reference": {"pipeline/core", "pipeline/geometry"},
    "pipeline/engine": {"pipeline/core", "pipeline/geometry", "pipeline/flat", "pipeline/hierarchy",
                        "pipeline/outofcore", "pipeline/outputs", "pipeline/reference", "formats"},
    "pipeline/bindings": {"pipeline/core", "pipeline/geometry", "pipeline/flat", "pipeline/hierarchy",
                          "pipeline/outofcore", "pipeline/outputs", "pipeline/reference", "pipeline/engine",
                          "pipeline/bindings", "formats"},
}


def _sources():
    for root in ("pipeline", "formats"):
        for p in sorted((REPO / root).rglob("*")):
            if p.suffix in (".h", ".cpp"):
                yield p


def _folder(rel: str) -> str:
    parts = rel.split("/")
    return parts[0] if parts[0] == "formats" else "/".join(parts[:2])


def test_includes_are_rooted_and_exist():
    for p in _sources():
        for inc in INCLUDE.findall(p.read_text()):
            assert inc.startswith(("pipeline/", "formats/")), f"{p.relative_to(REPO)}: include \"{inc}\" is not rooted"
            assert (REPO / inc).exists(), f"{p.relative_to(REPO)}: include \"{inc}\" does not exist"


def test_folders_depend_only_along_the_pipeline():
    for p in _sources():
        rel = str(p.relative_to(REPO))
        here = _folder(rel)
        for inc in INCLUDE.findall(p.read_text()):
            there = _folder(inc)
            if there != here:
                assert there in ALLOWED[here], f"{rel} includes {inc}: {here} may not depend on {there}"


def test_no_include_cycles():
    graph = {}
    for p in _sources():
        rel = str(p.relative_to(REPO))
        graph[rel] = [i for i in INCLUDE.findall(p.read_text())]
    state: dict[str, int] = {}

    def visit(node, stack):
        state[node] = 1
        for nxt in graph.get(node, []):
            if state.get(nxt) == 1:
                raise AssertionError("include cycle: " + " -> ".join(stack + [node, nxt]))
            if state.get(nxt) is None:
                visit(nxt, stack + [node])
        state[node] = 2

    for node in graph:
        if node not in state:
            visit(node, [])


def test_bindings_are_small_files():
    for p in sorted((REPO / "pipeline" / "bindings").glob("*")):
        n = p.read_text().count("\n")
        assert n <= 300, f"{p.relative_to(REPO)}: {n} lines (bindings only bind: keep each file small)"
