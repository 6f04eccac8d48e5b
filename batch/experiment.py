"""Experiment files: TOML that names planners, instances, rounds, seeds and budgets.

An experiment file looks like this (every key but ``instances`` has a default)::

    name = "ippc2011"       # default: the file's stem
    rounds = 30             # rounds per session (rddlsim's default)
    timeout = 1080          # seconds per session (the session budget the server enforces)
    seed = 0                # base of every job's server and planner seed
    jobs = 2                # sessions played at once
    instances = ["domains/print_fetch/", "SysAdmin_MDP_ippc2011:1-5"]

    [planners.mcts]
    planner = "mcts"                     # a registered planner ...
    options = { time_per_step = "0.1" }

    [planners.prost]                     # ... or a program that connects by itself
    command = "rddl-client --host {host} --port {port} --instance {instance} --prost PATH"

A planner table may say ``optional = true``: a registered planner that cannot be made
(PROST without a binary) is then left out with a warning instead of stopping the file.

``noop`` and ``random`` always run: they are the baselines of the IPPC scores. Every
problem of a file is reported at once, each with its line and column
(`ExperimentError`), before anything runs; instances are checked by `batch.instances`
the same way (its `check_experiment` does both and reports every problem of both).
"""

from __future__ import annotations

import logging
import re
import shlex
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "BASELINES",
    "COMMAND_PLACEHOLDERS",
    "Experiment",
    "ExperimentError",
    "PlannerSpec",
    "load_experiment",
    "parse_experiment",
]

#: The planners every experiment runs, as the IPPC's normalisation needs them.
BASELINES: tuple[str, ...] = ("noop", "random")

#: What an external command may contain; each is filled in per session.
COMMAND_PLACEHOLDERS = ("host", "port", "instance", "seed", "rounds", "timeout", "name")

log = logging.getLogger(__name__)

_TOP_KEYS = {"name", "rounds", "timeout", "seed", "jobs", "instances", "planners"}
_PLANNER_KEYS = {"planner", "options", "command", "timeout", "optional"}
_LABEL = re.compile(r"^[A-Za-z0-9_.\-]+$")


class ExperimentError(ValueError):
    """An experiment file that cannot run; ``problems`` holds one line per problem,
    each starting with ``file:line:column:``. ``partial`` is the experiment as far as
    it could be read (bad values replaced by their defaults), so that its instances can
    be checked too and every problem reported at once; None when the file is not
    TOML."""

    def __init__(self, problems: list[str], partial: Experiment | None = None) -> None:
        super().__init__("\n".join(problems))
        self.problems = problems
        self.partial = partial


Place = tuple[int, int]  # (line, column), 1-based


def sort_problems(problems: list[str], where: str) -> list[str]:
    """`problems` of one file in the order of their places (``where:line:col:``);
    others (no place) first, in their order."""

    def place(problem: str) -> tuple[int, int]:
        m = (
            re.match(r"(\d+):(\d+):", problem[len(where) + 1 :])
            if problem.startswith(where)
            else None
        )
        return (int(m.group(1)), int(m.group(2))) if m else (0, 0)

    return sorted(problems, key=place)


@dataclass(frozen=True)
class PlannerSpec:
    """One planner of an experiment: a registered planner with options, or a command."""

    label: str  # the table name, e.g. "mcts" for [planners.mcts]
    planner: str | None = None  # registered planner name (None for a command)
    options: dict[str, str] = field(default_factory=dict)
    command: tuple[str, ...] | None = None  # argv with {placeholders}
    timeout: float | None = None  # seconds per session, overriding the experiment's

    @property
    def external_command(self) -> bool:
        return self.command is not None


@dataclass(frozen=True)
class Experiment:
    """A checked experiment file (instances are still specs; see `batch.instances`)."""

    name: str
    path: Path | None
    rounds: int
    timeout: float
    seed: int
    jobs: int
    instances: tuple[str, ...]
    planners: tuple[PlannerSpec, ...]
    # where each instance spec was written, (line, column), for errors found later
    instance_lines: tuple[Place, ...] = ()

    @property
    def base_dir(self) -> Path:
        """Relative instance paths are read from here (the file's folder)."""
        return self.path.parent if self.path is not None else Path.cwd()

    def planner(self, label: str) -> PlannerSpec:
        for spec in self.planners:
            if spec.label == label:
                return spec
        raise KeyError(label)


class _Lines:
    """Finds where a key or a value is in the TOML text (tomllib reports no places
    after parsing): (line, column), 1-based."""

    def __init__(self, text: str) -> None:
        self.lines = text.splitlines()

    def table(self, dotted: str) -> Place:
        pattern = re.compile(
            r"^\s*(\[)\s*" + r"\s*\.\s*".join(map(re.escape, dotted.split("."))) + r"\s*\]"
        )
        for i, line in enumerate(self.lines, 1):
            m = pattern.match(line)
            if m:
                return i, m.start(1) + 1
        return self.key(dotted.split(".")[-1])

    def key(self, key: str, table: str | None = None) -> Place:
        """Where `key` is first assigned (inside `[table]` when given), else the
        table's header (or 1:1)."""
        start = self.table(table) if table else (1, 1)
        pattern = re.compile(r"^\s*(" + re.escape(key) + r")\s*=")
        inline = re.compile(r"[{,]\s*(" + re.escape(key) + r")\s*=")
        for i in range(start[0], len(self.lines) + 1):
            line = self.lines[i - 1]
            if table and i > start[0] and line.lstrip().startswith("["):
                break
            m = pattern.match(line) or inline.search(line)
            if m:
                return i, m.start(1) + 1
        return start

    def value(self, text: str, after: Place = (1, 1)) -> Place:
        """Where the string `text` is first written (its opening quote) at or after
        `after`; `after` itself when it is not found."""
        quoted = [f'"{text}"', f"'{text}'"]
        line, col = after
        for i in range(line, len(self.lines) + 1):
            start = col - 1 if i == line else 0
            found = [c for c in (self.lines[i - 1].find(q, start) for q in quoted) if c >= 0]
            if found:
                return i, min(found) + 1
        return after

    def value_part(self, text: str, where: Place) -> Place:
        """Where `text` stands on the line of `where` (a key), else `where`."""
        col = self.lines[where[0] - 1].find(text) if where[0] <= len(self.lines) else -1
        return (where[0], col + 1) if col >= 0 else where

    def end(self) -> Place:
        """Just after the last character of the text."""
        if not self.lines:
            return 1, 1
        return len(self.lines), len(self.lines[-1]) + 1


def load_experiment(path: str | Path) -> Experiment:
    """Read and check an experiment file; `ExperimentError` lists every problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise ExperimentError([f"{path}: cannot read the experiment file: {err}"]) from None
    return parse_experiment(text, path)


def parse_experiment(text: str, path: Path | None = None) -> Experiment:
    """Check the TOML text of an experiment (``path`` names it in errors and anchors
    relative instance paths)."""
    where = str(path) if path is not None else "<experiment>"
    lines = _Lines(text)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        # tomllib's message ends with "(at line L, column C)" or "(at end of document)"
        m = re.search(r"\(at line (\d+), column (\d+)\)", str(err))
        line, col = (int(m.group(1)), int(m.group(2))) if m else lines.end()
        msg = re.sub(r"\s*\(at (line \d+, column \d+|end of document)\)", "", str(err))
        raise ExperimentError([f"{where}:{line}:{col}: not valid TOML: {msg}"]) from None
    problems: list[str] = []

    def bad(place: Place, message: str) -> None:
        problems.append(f"{where}:{place[0]}:{place[1]}: {message}")

    for key in sorted(set(data) - _TOP_KEYS):
        bad(lines.key(key), f"unknown key '{key}' (known: {', '.join(sorted(_TOP_KEYS))})")

    def integer(key: str, default: int, minimum: int) -> int:
        value = data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            bad(lines.key(key), f"'{key}' must be an integer >= {minimum}, got {value!r}")
            return default
        return value

    rounds = integer("rounds", 30, 1)
    seed = integer("seed", 0, 0)
    jobs = integer("jobs", 1, 1)
    timeout_value = data.get("timeout", 1080)
    timeout = 1080.0
    if (
        isinstance(timeout_value, bool)
        or not isinstance(timeout_value, int | float)
        or timeout_value <= 0
    ):
        bad(
            lines.key("timeout"),
            f"'timeout' must be a positive number of seconds, got {timeout_value!r}",
        )
    else:
        timeout = float(timeout_value)
    name = data.get("name", path.stem if path is not None else "experiment")
    if not isinstance(name, str) or not name.strip():
        bad(lines.key("name"), f"'name' must be a non-empty string, got {name!r}")
        name = "experiment"

    instances: list[str] = []
    instance_lines: list[Place] = []
    raw_instances = data.get("instances")
    if raw_instances is None:
        bad(
            (1, 1),
            "no 'instances': list the instance files, folders, globs or rddlrepository names",
        )
    elif isinstance(raw_instances, str):
        raw_instances = [raw_instances]
    if isinstance(raw_instances, list):
        first = lines.key("instances")
        after = first
        for item in raw_instances:
            if not isinstance(item, str) or not item.strip():
                bad(first, f"'instances' must hold strings, got {item!r}")
                continue
            after = lines.value(item, after)
            instances.append(item.strip())
            instance_lines.append(after)
            after = (after[0], after[1] + 1)  # the next spec is further on
        if not raw_instances:
            bad(first, "'instances' is empty")
    elif raw_instances is not None:
        bad(lines.key("instances"), f"'instances' must be a list of strings, got {raw_instances!r}")

    planners = _planners(data.get("planners", {}), lines, bad)
    experiment = Experiment(
        name=name.strip(),
        path=path,
        rounds=rounds,
        timeout=timeout,
        seed=seed,
        jobs=jobs,
        instances=tuple(instances),
        planners=tuple(planners),
        instance_lines=tuple(instance_lines),
    )
    if problems:
        raise ExperimentError(sort_problems(problems, where), experiment)
    return experiment


def _planners(raw: Any, lines: _Lines, bad: Any) -> list[PlannerSpec]:
    from ..planners.base import ExternalPlanner, PlannerError, find_planner

    out: list[PlannerSpec] = []
    if not isinstance(raw, dict):
        bad(lines.key("planners"), "'planners' must be a table of tables ([planners.NAME])")
        return out
    labels = set(raw)
    for label, table in raw.items():
        line = lines.table(f"planners.{label}")
        if not _LABEL.match(label):
            bad(line, f"planner name '{label}' may hold only letters, digits, '_', '-' and '.'")
            continue
        if not isinstance(table, dict):
            bad(line, f"'planners.{label}' must be a table")
            continue
        for key in sorted(set(table) - _PLANNER_KEYS):
            bad(
                lines.key(key, f"planners.{label}"),
                f"planners.{label}: unknown key '{key}' (known: {', '.join(sorted(_PLANNER_KEYS))})",
            )
        name = table.get("planner")
        command = table.get("command")
        optional = table.get("optional", False)
        if not isinstance(optional, bool):
            bad(
                lines.key("optional", f"planners.{label}"),
                f"planners.{label}: 'optional' must be true or false",
            )
            optional = False
        timeout = table.get("timeout")
        if timeout is not None and (
            isinstance(timeout, bool) or not isinstance(timeout, int | float) or timeout <= 0
        ):
            bad(
                lines.key("timeout", f"planners.{label}"),
                f"planners.{label}: 'timeout' must be a positive number",
            )
            timeout = None
        if (name is None) == (command is None):
            bad(
                line,
                f"planners.{label}: give exactly one of 'planner' (a registered planner) or 'command'",
            )
            continue
        options: dict[str, str] = {}
        raw_options = table.get("options", {})
        if not isinstance(raw_options, dict):
            bad(
                lines.key("options", f"planners.{label}"),
                f"planners.{label}: 'options' must be a table",
            )
            raw_options = {}
        for key, value in raw_options.items():
            if isinstance(value, bool):
                options[key] = "true" if value else "false"
            elif isinstance(value, int | float | str):
                options[key] = str(value)
            else:
                bad(
                    lines.key(key, f"planners.{label}"),
                    f"planners.{label}: option '{key}' must be a string, number or boolean",
                )
        if command is not None:
            if raw_options:
                bad(
                    lines.key("options", f"planners.{label}"),
                    f"planners.{label}: 'options' are for registered planners; put a command's options in the command",
                )
            argv = _command(label, command, lines, lines.key("command", f"planners.{label}"), bad)
            if argv is not None:
                out.append(
                    PlannerSpec(label, None, {}, argv, None if timeout is None else float(timeout))
                )
            continue
        if not isinstance(name, str):
            bad(
                lines.key("planner", f"planners.{label}"),
                f"planners.{label}: 'planner' must be a string",
            )
            continue
        try:
            cls = find_planner(name)
            # make one now, so that a bad option or a missing binary fails before anything runs
            cls(**options)
        except PlannerError as err:
            if optional:
                # e.g. PROST when no binary is given: the experiment runs without it
                log.warning("planners.%s left out (optional): %s", label, err)
                continue
            # point at the option the planner refused, when it names one
            named = re.search(r"option '([^']+)'", str(err))
            key = named.group(1) if named and named.group(1) in raw_options else "planner"
            bad(lines.key(key, f"planners.{label}"), f"planners.{label}: {err}")
            continue
        if issubclass(cls, ExternalPlanner) and "seed" in options:
            bad(lines.key("seed", f"planners.{label}"), f"planners.{label}: {name} takes no seed")
        out.append(
            PlannerSpec(label, name, options, None, None if timeout is None else float(timeout))
        )
    by_label = {spec.label: spec for spec in out}
    for base in BASELINES:
        spec = by_label.get(base)
        if spec is not None and spec.planner != base:
            bad(
                lines.table(f"planners.{base}"),
                f"planners.{base}: the label '{base}' is kept for the {base} baseline",
            )
        elif base not in labels:
            out.insert(BASELINES.index(base), PlannerSpec(base, base))
    return out


def _command(
    label: str, command: Any, lines: _Lines, line: Place, bad: Any
) -> tuple[str, ...] | None:
    if isinstance(command, str):
        try:
            argv = shlex.split(command)
        except ValueError as err:
            bad(line, f"planners.{label}: 'command' cannot be split into words: {err}")
            return None
    elif isinstance(command, list) and all(isinstance(a, str) for a in command):
        argv = list(command)
    else:
        bad(line, f"planners.{label}: 'command' must be a string or a list of strings")
        return None
    if not argv:
        bad(line, f"planners.{label}: 'command' is empty")
        return None
    for word in argv:
        for field_name in re.findall(r"\{([^{}]*)\}", word):
            if field_name not in COMMAND_PLACEHOLDERS:
                at = lines.value_part("{" + field_name + "}", line)
                bad(
                    at,
                    f"planners.{label}: unknown placeholder {{{field_name}}} in 'command' "
                    f"(known: {', '.join('{' + p + '}' for p in COMMAND_PLACEHOLDERS)})",
                )
                return None
    if not any("{port}" in w for w in argv):
        bad(
            line,
            f"planners.{label}: 'command' must contain {{port}} (the port of the session's server)",
        )
        return None
    return tuple(argv)


def fill_command(argv: tuple[str, ...], values: dict[str, object]) -> list[str]:
    """The command's words with its placeholders filled in (other braces are kept)."""
    out = []
    for word in argv:
        out.append(
            re.sub(
                r"\{(" + "|".join(COMMAND_PLACEHOLDERS) + r")\}",
                lambda m: str(values[m.group(1)]),
                word,
            )
        )
    return out
