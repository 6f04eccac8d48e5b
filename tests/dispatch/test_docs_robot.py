"""docs/robot.md's examples, run as the page shows them: the simulated run,
the complete robot example (its files written from the page, its commands
run), and the Python block."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from .conftest import DATA

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "robot.md"
BIN = Path(sys.executable).parent

BLOCK = re.compile(r"^```(\w+)(?: (\S+))?\n(.*?)^```$", re.S | re.M)


def blocks() -> list[tuple[str, str | None, str]]:
    return [(m.group(1), m.group(2), m.group(3)) for m in BLOCK.finditer(PAGE.read_text())]


def console(index: int) -> list[tuple[str, list[str]]]:
    """The commands of the index-th console block, each with the lines it shows."""
    text = [b for b in blocks() if b[0] == "console"][index][2]
    out: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        if line.startswith("$ "):
            out.append((line[2:], []))
        else:
            out[-1][1].append(line)
    return out


def run(command: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    argv = shlex.split(command)
    assert argv[0] == "rddl-dispatch"
    argv[0] = str(BIN / "rddl-dispatch")
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def test_the_simulated_run_prints_what_the_page_shows() -> None:
    ((command, shown),) = console(0)
    done = run(command, REPO)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[:-1] == shown[:-1]
    # the last line's planning time is the machine's; the rest is the page's
    cut = shown[-1].index(", planning")
    assert lines[-1][:cut] == shown[-1][:cut]


def test_the_complete_example_runs_as_shown(tmp_path: Path) -> None:
    for name in ("courier_domain.rddl", "courier_one.rddl"):
        shutil.copy(DATA / name, tmp_path / name)
    named = {name: text for _, name, text in blocks() if name}
    assert set(named) == {"sensing.yaml", "robot.py"}
    for name, text in named.items():
        (tmp_path / name).write_text(text)
    (serve, _), (show, _) = console(1)
    done = run(serve, tmp_path)
    assert done.returncode == 0, done.stderr
    assert "goal reached: 5 turns in 1 round(s), reward -5, 0 failed action(s)" in done.stdout
    assert done.stdout.startswith("listening on 127.0.0.1:")
    plan = run(show, tmp_path)
    assert plan.returncode == 0, plan.stderr
    assert [line.split()[2:] for line in plan.stdout.splitlines()] == [
        ["move(r1,hall,office)", "succeeded"],
        ["pickup(r1)", "succeeded"],
        ["move(r1,office,hall)", "succeeded"],
        ["move(r1,hall,lab)", "succeeded"],
        ["drop(r1)", "succeeded"],
    ]


def test_the_python_block_runs(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    (code,) = [text for lang, name, text in blocks() if lang == "python" and name is None]
    monkeypatch.chdir(REPO)
    exec(compile(code, f"{PAGE}:python", "exec"), {"__name__": "docs_robot"})  # noqa: S102 - the page's own example
    turns, reward, failed, seconds = capsys.readouterr().out.split()
    assert int(turns) >= 5 and float(reward) <= -5.0 and int(failed) >= 0 and float(seconds) > 0
