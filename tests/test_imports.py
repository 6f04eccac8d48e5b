"""Imports run one way: no module of the ippc packages imports itself back through any
chain of imports (docs/architecture.md, "Imports within a package").

What counts as an import of module A by module B, read from B's source with `ast`:

- every `import` and `from ... import` statement anywhere in the file: at the top, inside
  functions and methods (an import hidden in a function still ties the two modules), and
  under `if TYPE_CHECKING:` (a module whose annotations need another module's class cannot
  be read or checked without it);
- relative imports resolve against B's package, and the folders are the `ippc.*`
  subpackages that pyproject's `[tool.setuptools.package-dir]` maps;
- `from P import name` imports the module `P.name` when that file exists, otherwise the
  package `P` itself, that is P's `__init__.py`;
- a package's `__init__.py` counts as a module, with its re-exports: importing `P.x` or
  `from P import y` from outside package P runs P's `__init__.py` first, so it is an import
  of P as well. `from ippc.rddl.sim import X` (or `from ippc.rddl.sim.actions import X`) in
  rddl/legal/ therefore imports rddl/sim/__init__.py, and with it every module that file
  imports. A module inside P does not import P by importing its siblings (Python has P
  already in hand), but it does when it takes a name from P's `__init__.py`.

The test fails on every circle it finds, naming the modules and the file and line of
each import in it. docs/architecture.md lists each package's modules in layers, each
importing only modules of its package on the lines above it; the last tests check that the
page lists every module and that the code keeps to its order.
"""

from __future__ import annotations

import ast
import re
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "architecture.md"
SECTION = "Imports within a package"


@dataclass(frozen=True)
class Edge:
    """One import: module `source` imports module `target` at `file`:`line`, by the
    statement that names module `named` (`target` itself, or a module inside package
    `target`, whose `__init__.py` runs first)."""

    source: str
    target: str
    file: str
    line: int
    named: str


def package_folders(repo: Path = REPO) -> dict[str, Path]:
    """{'ippc.rddl': repo/'rddl', ...}: the folders pyproject maps to ippc subpackages."""
    meta = tomllib.loads((repo / "pyproject.toml").read_text(encoding="utf-8"))
    dirs = meta["tool"]["setuptools"]["package-dir"]
    return {name: repo / folder for name, folder in dirs.items()}


def modules(folders: dict[str, Path]) -> dict[str, Path]:
    """{dotted module name: file} of every module under the package folders; a package's
    name maps to its __init__.py."""
    found: dict[str, Path] = {}
    for package, folder in folders.items():
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join([package, *parts])] = path
    return found


def _ancestors(name: str) -> list[str]:
    """'a.b.c' -> ['a', 'a.b']."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def module_imports(name: str, path: Path, known: Iterable[str]) -> list[tuple[str, int, str]]:
    """(imported module, line, module the statement names) for every import in module `name` (file `path`) of a module
    in `known`, as the module docstring defines it."""
    known = set(known)
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    targets: list[tuple[str, int, str]] = []

    def add(target: str, line: int) -> None:
        # importing a.b.c from outside package a.b runs a.b's (and a's) __init__ first
        for outer in _ancestors(target):
            if outer in known and not (name == outer or name.startswith(outer + ".")):
                targets.append((outer, line, target))
        if target in known:
            targets.append((target, line, target))

    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                origin = ".".join([*base, *([node.module] if node.module else [])])
            else:
                origin = node.module or ""
            for alias in node.names:
                sub = f"{origin}.{alias.name}"
                if sub in known:
                    add(sub, node.lineno)
                else:
                    add(origin, node.lineno)
    return [(t, line, named) for t, line, named in targets if t != name]


def import_graph(repo: Path = REPO) -> dict[str, dict[str, Edge]]:
    """{module: {imported module: the first such import}} over every package module."""
    found = modules(package_folders(repo))
    graph: dict[str, dict[str, Edge]] = {m: {} for m in found}
    for name, path in found.items():
        for target, line, named in module_imports(name, path, found):
            rel = str(path.relative_to(repo))
            graph[name].setdefault(target, Edge(name, target, rel, line, named))
    return graph


def strongly_connected(graph: dict[str, dict[str, Edge]]) -> list[list[str]]:
    """The sets of modules that reach each other (Tarjan), those of more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0

    for root in sorted(graph):
        if root in index:
            continue
        # iterative DFS: (node, iterator over its successors)
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            for nxt in successors:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        out.append(sorted(component))
    return sorted(out)


def shortest_circle(graph: dict[str, dict[str, Edge]], members: list[str]) -> list[Edge]:
    """One shortest circle through the first of `members`, inside `members`, as its edges."""
    inside = set(members)
    start = members[0]
    came: dict[str, Edge] = {}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for nxt, edge in sorted(graph[node].items()):
                if nxt not in inside:
                    continue
                if nxt == start:
                    path = [edge]
                    while path[0].source != start:
                        path.insert(0, came[path[0].source])
                    return path
                if nxt not in came:
                    came[nxt] = edge
                    following.append(nxt)
        frontier = following
    raise AssertionError(f"no circle through {start}")  # a component always has one


def describe(graph: dict[str, dict[str, Edge]], members: list[str]) -> str:
    circle = shortest_circle(graph, members)
    names = " -> ".join([e.source for e in circle] + [circle[0].source])
    where = "\n".join(
        f"    {e.file}:{e.line} imports {e.target}"
        + (f" (through {e.named}, which runs its __init__.py)" if e.named != e.target else "")
        for e in circle
    )
    return f"circle of {len(members)} modules ({', '.join(members)}):\n  {names}\n{where}"


def test_reading_imports(tmp_path: Path) -> None:
    """The reader resolves relative imports, names from __init__, submodules, and imports
    in functions and under TYPE_CHECKING; and it finds and names a circle."""
    (tmp_path / "pyproject.toml").write_text(
        '[tool.setuptools.package-dir]\n"ippc.a" = "a"\n"ippc.b" = "b"\n'
    )
    files = {
        "a/__init__.py": "from .m import f\n",
        "a/m.py": "def f():\n    from ..b import g\n",
        "a/n.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import ippc.b.s\n",
        "b/__init__.py": "from . import s\ng = 1\n",
        "b/s.py": "from . import g\n",
        "b/t.py": "from ippc.a import m\nfrom . import s\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(exist_ok=True)
        (tmp_path / rel).write_text(text)
    graph = import_graph(tmp_path)
    assert {m: set(t) for m, t in graph.items()} == {
        "ippc.a": {"ippc.a.m"},
        "ippc.a.m": {"ippc.b"},  # `from ..b import g`: g is a name of b/__init__.py
        "ippc.a.n": {"ippc.b", "ippc.b.s"},  # b.s from outside b runs b/__init__.py too
        "ippc.b": {"ippc.b.s"},
        "ippc.b.s": {"ippc.b"},  # a name of its own package's __init__.py
        "ippc.b.t": {"ippc.a", "ippc.a.m", "ippc.b.s"},  # a sibling: not ippc.b
    }
    assert graph["ippc.a.n"]["ippc.b"].named == "ippc.b.s"  # (line 3, under TYPE_CHECKING)
    assert graph["ippc.a.n"]["ippc.b"].line == 3
    assert strongly_connected(graph) == [["ippc.b", "ippc.b.s"]]
    message = describe(graph, ["ippc.b", "ippc.b.s"])
    assert "ippc.b -> ippc.b.s -> ippc.b" in message
    assert "b/s.py:1 imports ippc.b" in message and "b/__init__.py:1" in message


def test_no_import_circles() -> None:
    graph = import_graph()
    assert len(graph) > 100  # the reader found the packages
    circles = [describe(graph, members) for members in strongly_connected(graph)]
    assert not circles, "modules that import each other:\n" + "\n".join(circles)


def documented_layers(text: str) -> dict[str, list[list[str]]]:
    """{folder: its modules' files by layer, lowest first} from the page's section
    "Imports within a package": a `### `folder/`` heading per package, then a numbered
    line per layer naming files (`rddl/ast.py`)."""
    section = text.split(f"\n## {SECTION}\n", 1)[1].split("\n## ", 1)[0]
    out: dict[str, list[list[str]]] = {}
    folder = None
    for line in section.splitlines():
        if m := re.fullmatch(r"### `([a-z_]+)/`", line.strip()):
            folder = m.group(1)
            out[folder] = []
        elif folder is not None and re.match(r"\d+\. ", line):
            out[folder].append(re.findall(r"`([a-z_/]+\.py)`", line))
    return out


def module_file(name: str, folders: dict[str, Path]) -> str:
    """'ippc.rddl.sim' -> 'rddl/sim/__init__.py', as the page names modules."""
    for path in (m for n, m in modules(folders).items() if n == name):
        return str(path.relative_to(REPO))
    raise KeyError(name)


def test_the_page_lists_every_module_in_one_way_layers() -> None:
    """Every module of every package is on one line of its package's list in
    docs/architecture.md, and imports only modules of its package listed above it."""
    folders = package_folders()
    files = {n: str(p.relative_to(REPO)) for n, p in modules(folders).items()}
    layers = documented_layers(PAGE.read_text(encoding="utf-8"))
    line_of = {f: i for rows in layers.values() for i, row in enumerate(rows, 1) for f in row}
    problems = []
    for named in sorted(line_of):
        if named not in files.values():
            problems.append(f"{named} is listed but is not a module")
    graph = import_graph()
    for name, file in sorted(files.items()):
        folder = file.split("/", 1)[0]
        inside = sorted(
            (e for t, e in graph[name].items() if files[t].split("/", 1)[0] == folder),
            key=lambda e: e.line,
        )
        if folder not in layers:
            problems.append(f"{folder}/ has no list (a `### `{folder}/`` heading and layers)")
        elif file not in line_of:
            below = ", ".join(sorted({files[e.target] for e in inside}))
            where = f"on a line below {below}" if below else "on any line (it imports none)"
            problems.append(f"{file} is not listed; list it {where}")
        else:
            for e in inside:
                if line_of.get(files[e.target], 10**9) >= line_of[file]:
                    problems.append(
                        f"{e.file}:{e.line} imports {files[e.target]}, which is not listed "
                        f"above {file} (line {line_of[file]} of {folder}/)"
                    )
    assert not problems, f"docs/architecture.md, {SECTION!r}:\n" + "\n".join(
        dict.fromkeys(problems)
    )
