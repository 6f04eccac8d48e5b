"""The layout table of docs/architecture.md is the import rule: every module of a folder
imports only the ippc packages its row allows (and what those allow, transitively), and
every package folder has a row."""

from __future__ import annotations

import ast
import re

from .docs import REPO

PAGE = REPO / "docs" / "architecture.md"


def layout_rules(text: str) -> dict[str, set[str]]:
    """{folder: the ippc packages it may import directly}, from the page's Layout table."""
    section = text.split("\n## Layout\n", 1)[1].split("\n## ", 1)[0]
    rules: dict[str, set[str]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        m = re.fullmatch(r"`([a-z_]+)/`", cells[0]) if len(cells) == 3 else None
        if m:
            allowed = set(re.findall(r"`([a-z_]+)`", cells[2]))
            assert allowed or cells[2] == "-", f"architecture.md: cannot read {cells[2]!r}"
            rules[m.group(1)] = allowed
    return rules


def closure(rules: dict[str, set[str]], folder: str) -> set[str]:
    """What `folder` may import: its row, and the rows of those, transitively."""
    seen: set[str] = set()
    todo = [folder]
    while todo:
        for dep in rules.get(todo.pop(), set()):
            if dep not in seen:
                seen.add(dep)
                todo.append(dep)
    return seen


def ippc_imports(source: str, package: tuple[str, ...]) -> set[str]:
    """The top-level ippc packages a module imports, its own left out. `package` is the
    module's package as folders (`("rddl", "sim")` for rddl/sim/build.py), against which
    relative imports resolve."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # from ..model import x, inside rddl/sim/: ippc.rddl.model
                base = package[: len(package) - (node.level - 1)]
                target = [*base, *(node.module.split(".") if node.module else [])]
                if target:
                    found.add(target[0])
            elif node.module and node.module.startswith("ippc."):
                found.add(node.module.split(".")[1])
            elif node.module == "ippc":
                found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("ippc."):
                    found.add(alias.name.split(".")[1])
    return found - {package[0]}


def test_reading_the_rules() -> None:
    text = (
        "# A\n\n## Layout\n\n| folder | job | may import |\n|---|---|---|\n"
        "| `a/` | x | - |\n| `b/` | y | `a` |\n| `c/` | z | `b`, `d` |\n\n## Next\n| `e/` | | - |\n"
    )
    rules = layout_rules(text)
    assert rules == {"a": set(), "b": {"a"}, "c": {"b", "d"}}
    assert closure(rules, "c") == {"a", "b", "d"}
    source = "from ..a.m import f\nfrom . import g\nimport ippc.b.x\nfrom ippc.c import h\n"
    assert ippc_imports(source, ("c",)) == {"a", "b"}
    # two dots inside a subpackage stay in the package
    assert ippc_imports("from ..m import f\nfrom ...a import g\n", ("c", "sub")) == {"a"}


def test_every_package_folder_has_a_row() -> None:
    rules = layout_rules(PAGE.read_text(encoding="utf-8"))
    packages = {p.parent.name for p in REPO.glob("*/__init__.py")} - {"tests"}
    assert packages <= set(rules), f"add a row to docs/architecture.md: {packages - set(rules)}"


def test_imports_follow_the_layout() -> None:
    rules = layout_rules(PAGE.read_text(encoding="utf-8"))
    wrong = []
    for folder in sorted(rules):
        allowed = closure(rules, folder)
        for path in sorted((REPO / folder).rglob("*.py")):
            package = path.relative_to(REPO).parent.parts
            for dep in sorted(ippc_imports(path.read_text(encoding="utf-8"), package)):
                if dep not in allowed:
                    wrong.append(f"{path.relative_to(REPO)} imports ippc.{dep}")
    assert not wrong, "not allowed by docs/architecture.md's Layout table:\n" + "\n".join(wrong)


def _defined_names() -> tuple[set[str], set[tuple[str, str]]]:
    """The names defined in every package module, and every (class, method) pair, methods
    inherited from a base class of the packages included."""
    names: set[str] = set()
    methods: set[tuple[str, str]] = set()
    bases: dict[str, set[str]] = {}
    for folder in layout_rules(PAGE.read_text(encoding="utf-8")):
        for path in (REPO / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                    names.add(node.name)
                if isinstance(node, ast.ClassDef):
                    bases.setdefault(node.name, set()).update(
                        b.value.id
                        if isinstance(b, ast.Subscript) and isinstance(b.value, ast.Name)
                        else b.id
                        if isinstance(b, ast.Name)
                        else ""
                        for b in node.bases
                    )
                    for item in node.body:
                        if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef):
                            methods.add((node.name, item.name))
                elif isinstance(node, ast.Assign):
                    names.update(t.id for t in node.targets if isinstance(t, ast.Name))
                elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                    names.add(node.target.id)
    grown = True
    while grown:  # inherit, until nothing new comes down
        inherited = {(c, m) for c, bs in bases.items() for b, m in methods if b in bs}
        grown = not inherited <= methods
        methods |= inherited
    return names, methods


def test_the_request_path_names_what_exists() -> None:
    """Every file, `Class.method` and function the architecture page names is in the code
    (a rename that forgets the page fails here)."""
    text = PAGE.read_text(encoding="utf-8")
    names, methods = _defined_names()
    missing = []
    for span in re.findall(r"`([^`]+)`", text):
        if re.fullmatch(r"[a-z_]+/[a-z_/]+\.[a-z]+", span):
            if not (REPO / span).exists():
                missing.append(span)
        elif m := re.fullmatch(r"([A-Z][A-Za-z]+)\.([a-z_]+)(?:\(.*\))?", span):
            if (m.group(1), m.group(2)) not in methods:
                missing.append(span)
        elif re.fullmatch(r"_?[a-z]+_[a-z_]+|_[a-z]+", span) and span not in names:
            missing.append(span)
    assert not missing, f"docs/architecture.md names what the code does not have: {missing}"
