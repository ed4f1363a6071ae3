#!/usr/bin/env python3
"""Module dependency picture of the Rust crates and the Python package, with a cycle check.

Reads the sources only (no build, no imports), so anyone can run it with a bare Python 3:

    python3 scripts/module-graph.py            # rewrite docs/architecture.md
    python3 scripts/module-graph.py --check    # exit 1 on a cycle or a stale docs/architecture.md

A Rust module is a file (`commands/model.rs` is `commands::model`); an edge `a -> b` means `a`
names an item of `b` through `crate::`, `super::`, `self::` or a child module's name. A parent
declaring its children (`mod x;`) is ownership, not an edge; unit tests are left out. A Python module is a file of
`cnfmp`; every import counts, also the ones inside functions that keep start-up light, because
a lazy import is still a dependency. Each graph is checked at two levels: files, and the top
level (the first path segment), where `serve -> commands -> serve` is a cycle even when no two
files import each other.
"""
from __future__ import annotations

import argparse
import ast
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "architecture.md"
#: Each Rust crate's source folder and library name (its binary names the library's items
#: through that name rather than `crate::`).
RUST_CRATES = {"orchestrator": (ROOT / "orchestrator" / "src", "cnfmp"),
               "segmenter-bridge": (ROOT / "segmenter-bridge" / "src", "segmenter_bridge")}
PYTHON_PACKAGE = ROOT / "python" / "cnfmp"


@dataclass
class Graph:
    """Directed graph of module names (`a::b` or `a.b`)."""

    name: str
    separator: str
    nodes: set[str] = field(default_factory=set)
    edges: set[tuple[str, str]] = field(default_factory=set)

    def add(self, source: str, target: str) -> None:
        if source != target and target in self.nodes:
            self.edges.add((source, target))

    def top_level(self) -> "Graph":
        """The graph of first path segments; a parent and its children merge."""
        head = lambda node: node.split(self.separator)[0]  # noqa: E731
        graph = Graph(self.name + " (top level)", self.separator, {head(n) for n in self.nodes})
        for source, target in self.edges:
            graph.add(head(source), head(target))
        return graph

    def cycles(self) -> list[list[str]]:
        """Strongly connected components with more than one node (Tarjan), each sorted."""
        index: dict[str, int] = {}
        low: dict[str, int] = {}
        stack: list[str] = []
        on_stack: set[str] = set()
        found: list[list[str]] = []
        successors = {n: sorted(t for s, t in self.edges if s == n) for n in self.nodes}

        def visit(node: str) -> None:
            index[node] = low[node] = len(index)
            stack.append(node)
            on_stack.add(node)
            for nxt in successors[node]:
                if nxt not in index:
                    visit(nxt)
                    low[node] = min(low[node], low[nxt])
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))

        for node in sorted(self.nodes):
            if node not in index:
                visit(node)
        return sorted(found)

    def mermaid(self) -> str:
        ident = lambda node: re.sub(r"\W", "_", node) or "root"  # noqa: E731
        lines = ["```mermaid", "flowchart LR"]
        lines += [f'  {ident(n)}["{n}"]' for n in sorted(self.nodes)]
        lines += [f"  {ident(s)} --> {ident(t)}" for s, t in sorted(self.edges)]
        lines.append("```")
        return "\n".join(lines)


# ----------------------------------------------------------------------------------------- Rust

_RUST_COMMENT = re.compile(r"//[^\n]*|/\*.*?\*/", re.S)
_RUST_STRING = re.compile(r'"(?:\\.|[^"\\])*"')
_MOD_DECL = re.compile(r"^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(\w+)\s*;", re.M)
_PATH = re.compile(r"\b(crate|super|self)((?:::\w+)+)")
_USE_GROUP = re.compile(r"\buse\s+(crate|super|self)::([^;]*\{[^;]*);", re.S)


def _rust_module(path: Path, src: Path) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    if parts[-1] in ("mod", "lib"):
        parts.pop()
    return "::".join(parts) if parts != ["main"] else "main"


def _expand_use_group(text: str) -> list[str]:
    """`a::{b, c::{d, e}}` -> ["a::b", "a::c::d", "a::c::e"]."""
    text = re.sub(r"\s+", "", text)
    if "{" not in text:
        return [text]
    head, rest = text.split("{", 1)
    body = rest[: rest.rfind("}")]
    items, depth, current = [], 0, ""
    for char in body:
        if char == "," and depth == 0:
            items.append(current)
            current = ""
            continue
        depth += (char == "{") - (char == "}")
        current += char
    items.append(current)
    return [head + part for item in items if item for part in _expand_use_group(item)]


def rust_graph(crate: str, src: Path, library: str) -> Graph:
    files = {_rust_module(p, src): p for p in sorted(src.rglob("*.rs"))}
    graph = Graph(crate, "::", {m for m in files if m})  # the crate root is not a node
    for module, path in files.items():
        text = _RUST_STRING.sub('""', _RUST_COMMENT.sub("", path.read_text()))
        text = re.sub(rf"\b{library}::", "crate::", text)
        # Unit tests (`#[cfg(test)] mod tests`, last in a file) use their file through `super::`.
        text = text.split("#[cfg(test)]")[0]
        if not module:
            continue
        own = module.split("::")  # `self::` is the module itself, `super::` its parent
        references: list[list[str]] = []
        for anchor, group in _USE_GROUP.findall(text):
            references += [[anchor] + p.split("::") for p in _expand_use_group(group)]
        references += [[anchor] + rest.strip(":").split("::") for anchor, rest in _PATH.findall(text)]
        for child in _MOD_DECL.findall(text):
            if re.search(rf"(?<!::)\b{child}::", text):
                references.append(["self", child])
        for anchor, *rest in references:
            base = {"crate": [], "super": own[:-1], "self": own}[anchor]
            target = _longest_module(base + rest, graph.nodes)
            if target:
                graph.add(module, target)
    return graph


def _longest_module(path: list[str], modules: set[str]) -> str | None:
    for end in range(len(path), 0, -1):
        candidate = "::".join(path[:end])
        if candidate in modules:
            return candidate
    return None


# --------------------------------------------------------------------------------------- Python

def python_graph(package: Path) -> Graph:
    def name_of(path: Path) -> str:
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)

    files = {name_of(p): p for p in sorted(package.rglob("*.py"))}
    graph = Graph("cnfmp (Python)", ".", set(files))
    for module, path in files.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    anchor = module.split(".")
                    anchor = anchor[: len(anchor) - node.level + (1 if is_package else 0)]
                    base = ".".join(anchor + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                targets = [f"{base}.{alias.name}" for alias in node.names]
            else:
                continue
            for target in targets:
                parts = target.split(".")
                for end in range(len(parts), 0, -1):
                    if ".".join(parts[:end]) in files:
                        graph.add(module, ".".join(parts[:end]))
                        break
    return graph


# ------------------------------------------------------------------------------------- the page

def graphs() -> list[Graph]:
    return [rust_graph(c, s, lib) for c, (s, lib) in RUST_CRATES.items()] + [python_graph(PYTHON_PACKAGE)]


def render(all_graphs: list[Graph]) -> str:
    out = [
        "# Module dependencies",
        "",
        "Generated by `python3 scripts/module-graph.py` from the sources; do not edit by hand.",
        "An arrow `a --> b` means that `a` uses `b`. `python3 scripts/module-graph.py --check`",
        "(run by the tests) fails on any cycle, at the level of files or of top-level modules,",
        "and on this page being out of date.",
        "",
    ]
    for graph in all_graphs:
        top = graph.top_level()
        out += [f"## {graph.name}", "", "Top level:", "", top.mermaid(), "",
                "<details><summary>Every module</summary>", "", graph.mermaid(), "", "</details>", ""]
    return "\n".join(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true",
                        help="do not write; exit 1 on a cycle or a stale page")
    args = parser.parse_args()
    all_graphs = graphs()
    failed = False
    for graph in all_graphs:
        for level in (graph, graph.top_level()):
            for cycle in level.cycles():
                print(f"cycle in {level.name}: {' <-> '.join(cycle)}", file=sys.stderr)
                failed = True
    page = render(all_graphs)
    if args.check:
        if not DOC.exists() or DOC.read_text() != page:
            print(f"{DOC.relative_to(ROOT)} is out of date: run python3 scripts/module-graph.py",
                  file=sys.stderr)
            failed = True
    else:
        DOC.write_text(page)
        print(f"wrote {DOC.relative_to(ROOT)}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
