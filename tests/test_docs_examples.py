"""The examples of README.md and docs/*.md are true: every console example that shows
output is run here and its output compared (what changes from run to run left out), every
python block is run (and its output compared with the `text output` block after it), and
every pycon block is run as a doctest. An example that is not checked must say it is
illustrative next to it."""

from __future__ import annotations

import doctest
import io
import os
import re
import shlex
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import pytest

from .docs import REPO, Block, blocks, doc_pages

BIN = Path(sys.executable).parent
#: What changes from run to run, in both the page and the output.
VARYING = [
    (re.compile(r"127\.0\.0\.1:\d+"), "127.0.0.1:PORT"),
    (re.compile(r"^(\s+\d+\s+-?\d+\.\d{4}\s+\d+\s+)\d+\.\d{3}"), r"\1S"),  # a round's seconds
    (re.compile(r"\(\d+\.\d+ s\)$"), "(S s)"),  # a session's seconds
    (re.compile(r"^steps per second\s+\d+$"), "steps per second  N"),
    (re.compile(r'"steps_per_second": [0-9.e+-]+'), '"steps_per_second": N'),
]


@dataclass(frozen=True)
class Console:
    """How to run one console block: `run` (the commands in a shell), `server` (a server
    started, read to its listening line, stopped), `client` (the commands against a
    server started with `server_args` on a free port), `make` (the Makefile's target)."""

    kind: str = "run"
    server_args: tuple[str, ...] = ()


#: The console blocks that show output, by page and first command.
CONSOLE: dict[tuple[str, str], Console] = {
    ("README.md", "make demo"): Console("make"),
    ("docs/cli.md", "rddl check domains/"): Console(),
    ("docs/cli.md", "rddl sim domains/print_jobs/domain.rddl"): Console(),
    ("docs/cli.md", "SYSADMIN=$(python -c"): Console(),
    ("docs/cli.md", "rddl-server domains/ --port 2323"): Console("server"),
    ("docs/web.md", "rddl-server domains/ --port 2323 --web 0"): Console("server"),
    ("docs/cli.md", "rddl-client --port 2323 --instance print_jobs_inst_1"): Console(
        "client", ("domains/", "--rounds", "3")
    ),
}

#: Pages whose examples a test of their own runs as the page shows them (not run twice).
CHECKED_BY: dict[str, str] = {
    "docs/robot.md": "tests/dispatch/test_docs_robot.py",
    # one session across its python blocks, and a JSON-lines transcript replayed
    "docs/knowledge-base.md": "tests/kb/test_docs.py",
}


def _all_blocks() -> list[tuple[str, int, Block, str]]:
    """(page, index, block, page text) for every fenced block of every page."""
    out = []
    for page in doc_pages():
        text = page.read_text(encoding="utf-8")
        rel = page.relative_to(REPO).as_posix()
        out += [(rel, i, b, text) for i, b in enumerate(blocks(text))]
    return out


BLOCKS = _all_blocks()


def commands(block: Block) -> list[str]:
    return [line[2:] for line in block.text.splitlines() if line.startswith("$ ")]


def expected_output(block: Block) -> list[str]:
    return [ln for ln in block.text.splitlines() if ln.strip() and not ln.startswith("$ ")]


def illustrative(text: str, block: Block) -> bool:
    """Whether the prose next to a block (three lines before it, two after) calls it
    illustrative."""
    lines = text.splitlines()
    start = block.line - 1
    end = start + block.text.count("\n") + 2
    near = [ln for ln in lines[max(0, start - 3) : start] if ln.strip()]
    near += [ln for ln in lines[end : end + 3] if ln.strip()][:2]
    return any("illustrative" in ln.lower() for ln in near)


def _key(page: str, block: Block) -> tuple[str, str] | None:
    cmds = commands(block)
    for (p, first), _ in CONSOLE.items():
        if p == page and cmds and cmds[0].startswith(first):
            return (p, first)
    return None


def normalise(line: str) -> str:
    line = line.rstrip()
    for pattern, repl in VARYING:
        line = pattern.sub(repl, line)
    return line


def same_output(expected: list[str], actual: list[str]) -> bool:
    """Whether `actual` is what `expected` shows: a line that is only `...` stands for any
    lines (none included), `...` within a line for any characters."""
    exp = [normalise(e) for e in expected]
    act = [normalise(a) for a in actual if a.strip()]

    def line_ok(e: str, a: str) -> bool:
        if "..." not in e:
            return e == a
        return re.fullmatch(".*".join(map(re.escape, e.split("..."))), a) is not None

    def match(i: int, j: int) -> bool:
        if i == len(exp):
            return j == len(act)
        if exp[i].strip() == "...":
            return any(match(i + 1, k) for k in range(j, len(act) + 1))
        return j < len(act) and line_ok(exp[i], act[j]) and match(i + 1, j + 1)

    return match(0, 0)


def test_same_output() -> None:
    assert same_output(["a", "...", "z"], ["a", "b", "c", "z"])
    assert same_output(["a", "   ...", "z"], ["a", "z"])
    assert same_output(['{"x": 1, ...}'], ['{"x": 1, "y": 2}'])
    assert same_output(["steps per second  10016"], ["steps per second  9"])
    assert not same_output(["a", "z"], ["a", "b", "z"])
    assert not same_output(["mean return  -20.5580"], ["mean return  -20.2100"])


def test_every_example_is_checked_or_illustrative() -> None:
    """A console block that shows output is in CONSOLE or says it is illustrative (python and
    pycon blocks are all run below, unless they say so)."""
    for page, test in CHECKED_BY.items():
        assert (REPO / test).exists(), f"{page}'s examples: {test} is gone"
    unchecked = []
    for page, _, block, text in BLOCKS:
        if page in CHECKED_BY:
            continue
        # (sh blocks are scripts: commands only; a console block shows a prompt and output)
        if block.lang == "console" and expected_output(block):
            if _key(page, block) is None and not illustrative(text, block):
                unchecked.append(f"{page}:{block.line}: {block.text.splitlines()[0]}")
    assert not unchecked, "examples neither checked nor marked illustrative:\n" + "\n".join(
        unchecked
    )


@contextmanager
def _scratch(tmp_path: Path) -> Iterator[Path]:
    """A working folder where the pages' relative paths (domains/, tests/) resolve and what
    the commands write (results.db, run.json) stays out of the repository."""
    for name in ("domains", "tests"):
        (tmp_path / name).symlink_to(REPO / name, target_is_directory=True)
    yield tmp_path


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    env.pop("PYTHONPATH", None)
    return env


def _shell(script: str, cwd: Path, timeout: float = 120.0) -> list[str]:
    proc = subprocess.run(
        ["bash", "-c", script],
        cwd=cwd,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=timeout,
    )
    return proc.stdout.splitlines()


def _start_server(args: list[str], cwd: Path) -> tuple[subprocess.Popen[str], list[str], int]:
    """An rddl-server on a free port: the process, the lines it printed up to its listening
    line (stderr included), and the port."""
    proc = subprocess.Popen(
        [str(BIN / "rddl-server"), *args, "--port", "0"],
        cwd=cwd,
        env=_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert proc.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line.rstrip("\n"))
        m = re.match(r"listening on .*:(\d+)$", line.strip())
        if m:
            return proc, lines, int(m.group(1))
    proc.kill()
    proc.wait()
    raise AssertionError(f"rddl-server {args} did not start: {lines}")


def _stop(proc: subprocess.Popen[str]) -> list[str]:
    """Stop a server from `_start_server`; the lines it printed after its listening line."""
    proc.terminate()
    try:
        rest, _ = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        rest, _ = proc.communicate()
    return rest.splitlines()


def _console_block(page: str, first: str) -> Block:
    found = [b for p, _, b, _ in BLOCKS if p == page and _key(p, b) == (page, first)]
    assert len(found) == 1, f"{page}: {len(found)} console blocks start with {first!r}"
    return found[0]


def _console_params() -> list[object]:
    # make demo starts a server with a worker per core and three clients: the longest
    # example (5-15 s), so `make test` runs it and `make test-fast` leaves it out
    return [
        pytest.param(p, c, marks=pytest.mark.slow) if CONSOLE[p, c].kind == "make" else (p, c)
        for p, c in CONSOLE
    ]


@pytest.mark.parametrize("page,first", _console_params(), ids=[f"{p}:{c}" for p, c in CONSOLE])
def test_console_example(page: str, first: str, tmp_path: Path) -> None:
    check = CONSOLE[(page, first)]
    block = _console_block(page, first)
    cmds = commands(block)
    with _scratch(tmp_path) as cwd:
        if check.kind == "make":
            assert cmds == ["make demo"]
            make = shutil.which("make")
            assert make, "make is needed (the project's commands are make targets)"
            # the target's own commands, with this interpreter's scripts, without
            # re-installing (the Makefile's own BIN when that is where they are: it is
            # relative, and a path with spaces cannot be handed to make)
            own = BIN.resolve() == (REPO / ".venv" / "bin").resolve()
            bin_arg = "" if own else f" BIN={shlex.quote(str(BIN))}"
            actual = _shell(f"{shlex.quote(make)} -s -o install demo{bin_arg}", REPO)
        elif check.kind == "server":
            (cmd,) = cmds
            args = cmd.split()[1:]
            port_at = args.index("--port")
            del args[port_at : port_at + 2]
            proc, actual, _ = _start_server(args, cwd)
            # what it prints on the way up (the instances it serves come after the
            # listening line, on stderr), not what it logs when stopped
            guard = threading.Timer(60, proc.kill)  # readline cannot hang the test
            guard.start()
            try:
                assert proc.stdout is not None
                while len(actual) < len(expected_output(block)):
                    line = proc.stdout.readline()
                    if not line:
                        break
                    actual.append(line.rstrip("\n"))
            finally:
                guard.cancel()
                _stop(proc)
        elif check.kind == "client":
            proc, _, port = _start_server([*check.server_args, "--workers", "1", "-q"], cwd)
            try:
                actual = _shell(
                    "\n".join(c.replace("--port 2323", f"--port {port}") for c in cmds), cwd
                )
            finally:
                _stop(proc)
        else:
            actual = _shell("\n".join(cmds), cwd)
    expected = expected_output(block)
    assert same_output(expected, actual), (
        f"{page}:{block.line}: the page shows\n"
        + "\n".join(expected)
        + "\nbut the commands print\n"
        + "\n".join(actual)
    )


PYTHON = [
    (p, i, b)
    for p, i, b, text in BLOCKS
    if b.lang == "python"
    and not illustrative(text, b)
    and "class GreedyPlanner" not in b.text
    and p not in CHECKED_BY
]


@pytest.mark.parametrize("page,index,block", PYTHON, ids=[f"{p}:{b.line}" for p, _, b in PYTHON])
def test_python_block(page: str, index: int, block: Block, monkeypatch: pytest.MonkeyPatch) -> None:
    """The block runs from the repository's root; its printout is the `text output` block
    after it, if there is one. (docs/planners.md's GreedyPlanner is run by
    tests/planners/test_example.py.)"""
    monkeypatch.chdir(REPO)
    out = io.StringIO()
    with redirect_stdout(out):
        exec(compile(block.text, f"{page}:{block.line}", "exec"), {"__name__": "__main__"})
    page_blocks = [b for p, _, b, _ in BLOCKS if p == page]
    after = page_blocks[index + 1] if index + 1 < len(page_blocks) else None
    if after is not None and after.lang == "text" and after.info == "output":
        assert out.getvalue() == after.text, f"{page}:{after.line}"


PYCON_PAGES = sorted({p for p, _, b, _ in BLOCKS if b.lang == "pycon" and p not in CHECKED_BY})


@pytest.mark.parametrize("page", PYCON_PAGES)
def test_pycon_blocks(page: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A page's pycon blocks are one doctest session, run from the repository's root."""
    monkeypatch.chdir(REPO)
    text = "\n".join(b.text for p, _, b, _ in BLOCKS if p == page and b.lang == "pycon")
    test = doctest.DocTestParser().get_doctest(text, {"__name__": "docs"}, page, page, 0)
    assert test.examples
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    report = io.StringIO()
    result = runner.run(test, out=report.write)
    assert result.failed == 0, report.getvalue()
