"""Launcher for the PROST planner (github.com/prost-planner/prost).

PROST is an `ExternalPlanner`: its `search` program connects to the server
itself, plays the whole session and prints what it did. How it is called
(from PROST's src/search/main.cc and ipc_client.cc)::

    search <instance> [-h <host>] [-p <port>] [--parser-options <opts>] <config>

where everything from the first argument that starts with `[` on is the
planner configuration, e.g. `[Prost -s 1 -se [IPC2014]]`. After the
session-init it writes the decoded task to `./parser_in_<pid>.rddl` and runs
`./rddl-parser-release` (a debug build: `./rddl-parser-debug`) through the
shell *from its working directory*, so the working directory must hold the
parser under that name. Errors go to stderr as `ERROR: <message>` and PROST
then exits with status 0 (`SystemUtils::abort`), so the exit status alone
says nothing; a server that closes the connection mid-round makes it crash.

What it prints and this module reads (`parse_prost_output`)::

    >>> END OF ROUND 1 -- REWARD RECEIVED: 312.250000
    >>> END OF SESSION  -- TOTAL REWARD: 1619.750000

Theory of operation: `ProstPlanner` resolves the binary, the parser and the
working directory when it is made (so a missing binary fails before the
client connects). `run_session` starts PROST in a new session (its own
process group), with stdout and stderr going straight into the log file,
and polls for its exit without reaping it (`waitid(WNOWAIT)`), so the
group id stays reserved until the group is killed. Whatever happens (PROST
exits, the timeout passes, `cancel()` is called, an exception or
KeyboardInterrupt arrives), the whole group then gets SIGTERM, SIGKILL after
a grace period, and only then is PROST reaped.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shlex
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from .base import ExternalPlanner, ExternalResult, PlannerError

log = logging.getLogger(__name__)

DEFAULT_CONFIG = "[Prost -s 1 -se [IPC2014]]"
"""The IPC 2014 configuration (UCT* with IDS initialisation)."""

PROST_BIN_ENV = "PROST_BIN"

# The names under which PROST's search program runs its parser (release and
# debug builds), relative to the working directory.
PARSER_NAMES = ("rddl-parser-release", "rddl-parser-debug")

# Where to look inside a folder given as the binary: the layout prost.py
# makes (copies named -release) and PROST's own build tree.
_BINARY_CANDIDATES = (
    "search-release",
    "search",
    "builds/release/search/search",
    "search-debug",
    "builds/debug/search/search",
)

_POLL = 0.02  # seconds between checks on the process
_KILL_WAIT = 10.0  # seconds to wait for the group's members to die after SIGKILL

_ROUND_RE = re.compile(r"^>>> END OF ROUND (\d+) -- REWARD RECEIVED: (\S+)\s*$")
_TOTAL_RE = re.compile(r"^>>> END OF SESSION\s+-- TOTAL REWARD: (\S+)\s*$")
_AVERAGE_RE = re.compile(r"^>>> END OF SESSION\s+-- AVERAGE REWARD: (\S+)\s*$")
_ERROR_RE = re.compile(r"^ERROR: (.*?)\s*$")
_UNKNOWN_OPTION_RE = re.compile(r"^Unknown option: .*$")


@dataclass(frozen=True)
class ProstOutput:
    """What PROST's output says about the session."""

    rounds: list[float]  # round rewards in the order PROST printed them
    total_reward: float | None
    average_reward: float | None
    errors: list[str]  # the text after `ERROR: ` (and `Unknown option: ...` lines)


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def parse_prost_output(text: str) -> ProstOutput:
    """Round rewards, session total and errors from PROST's stdout+stderr."""
    rounds: list[float] = []
    total: float | None = None
    average: float | None = None
    errors: list[str] = []
    for line in text.splitlines():
        if line.startswith(">>> "):
            if m := _ROUND_RE.match(line):
                value = _number(m.group(2))
                if value is not None:
                    rounds.append(value)
            elif m := _TOTAL_RE.match(line):
                total = _number(m.group(1))
            elif m := _AVERAGE_RE.match(line):
                average = _number(m.group(1))
        elif m := _ERROR_RE.match(line):
            errors.append(m.group(1))
        elif _UNKNOWN_OPTION_RE.match(line):
            errors.append(line.strip())
    return ProstOutput(rounds, total, average, errors)


def prost_command(
    binary: Path | str,
    instance: str,
    host: str,
    port: int,
    config: str = DEFAULT_CONFIG,
    parser_options: str | None = None,
) -> list[str]:
    """PROST's argument vector (the configuration as one argument: PROST
    joins everything from the first `[` on anyway)."""
    cmd = [str(binary), instance, "-h", host, "-p", str(port)]
    if parser_options:
        cmd += ["--parser-options", parser_options]
    cmd.append(config)
    return cmd


def check_config(config: str) -> str:
    """The configuration string, trimmed, or `PlannerError` when PROST would
    not read it as one (it must be one bracketed expression)."""
    text = config.strip()
    if not text.startswith("[") or not text.endswith("]"):
        raise PlannerError(
            f"prost: option 'config' must be a bracketed PROST configuration such as "
            f"'{DEFAULT_CONFIG}', got '{config}'"
        )
    depth = 0
    for i, ch in enumerate(text):
        depth += {"[": 1, "]": -1}.get(ch, 0)
        if depth < 0 or (depth == 0 and i != len(text) - 1):
            raise PlannerError(f"prost: option 'config' has unbalanced brackets: '{config}'")
    if depth != 0:
        raise PlannerError(f"prost: option 'config' has unbalanced brackets: '{config}'")
    return text


def _executable(path: Path) -> bool:
    return path.is_file() and os.access(path, os.X_OK)


def resolve_binary(text: str) -> Path:
    """PROST's search program from a path, a command on PATH, or a folder
    (the PROST checkout or a folder prost.py-style copies live in). The
    result is absolute but symlinks are kept: PROST's folder is where the
    link is."""
    if not text.strip():
        raise PlannerError("prost: the PROST binary path is empty")
    path = Path(text.strip()).expanduser()
    if os.sep not in text and not path.exists():
        found = shutil.which(text.strip())
        if found:
            path = Path(found)
    if path.is_dir():
        for cand in _BINARY_CANDIDATES:
            if _executable(path / cand):
                path = path / cand
                break
        else:
            raise PlannerError(
                f"prost: no PROST search program in the folder {path} "
                f"(looked for {', '.join(_BINARY_CANDIDATES)}; build PROST with ./build.py)"
            )
    if not path.exists():
        raise PlannerError(f"prost: PROST binary not found: {path}")
    if not path.is_file():
        raise PlannerError(f"prost: PROST binary is not a file: {path}")
    if not os.access(path, os.X_OK):
        raise PlannerError(f"prost: PROST binary is not executable: {path} (chmod +x?)")
    return Path(os.path.abspath(path))


def _proc_group_members(pgid: int, exclude: int) -> list[int] | None:
    """Live (non-zombie) processes of a process group, from /proc; None
    where /proc cannot tell."""
    proc = Path("/proc")
    if not (proc / "self" / "stat").exists():
        return None
    members = []
    for entry in os.listdir(proc):
        if not entry.isdigit() or int(entry) == exclude:
            continue
        try:
            stat = (proc / entry / "stat").read_text()
        except OSError:
            continue  # gone meanwhile
        # pid (comm) state ppid pgrp ...: comm may hold spaces and parens
        fields = stat[stat.rfind(")") + 2 :].split()
        if len(fields) >= 3 and int(fields[2]) == pgid and fields[0] not in ("Z", "X"):
            members.append(int(entry))
    return members


class ProstPlanner(ExternalPlanner):
    """Runs an external PROST binary for one session (see the module doc)."""

    name: ClassVar[str] = "prost"
    options: ClassVar[dict[str, str]] = {
        "binary": f"PROST's search program (or its checkout folder); default ${PROST_BIN_ENV}",
        "config": f"PROST configuration string (default '{DEFAULT_CONFIG}', the IPC 2014 preset)",
        "parser": "PROST's rddl-parser (default: rddl-parser-release beside the binary, or "
        "rddl-parser there or in ../rddl_parser/ of PROST's build tree)",
        "parser_options": "passed to PROST as --parser-options",
        "workdir": "working directory for PROST; it must hold ./rddl-parser-release "
        "(default: the binary's folder if the parser is there, else a temporary folder "
        "with a link to the parser)",
        "log": "file for PROST's stdout and stderr (default: a temporary file)",
        "grace": "seconds between SIGTERM and SIGKILL when stopping PROST (default 2)",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        text = self.str_option("binary") or os.environ.get(PROST_BIN_ENV, "")
        if not text.strip():
            raise PlannerError(
                f"prost: no PROST binary given: pass its search program with --prost PATH "
                f"(planner option 'binary') or set {PROST_BIN_ENV}"
            )
        self.binary: Path = resolve_binary(text)
        self.config: str = check_config(self.str_option("config", DEFAULT_CONFIG) or "")
        self.parser_options: str | None = self.str_option("parser_options")
        self.log_file: Path | None = self.path_option("log")
        self.grace: float = self.float_option("grace", 2.0, minimum=0.0) or 0.0
        self.workdir, self.parser_link = self._plan_workdir()

    # -- where PROST runs --------------------------------------------

    def _plan_workdir(self) -> tuple[Path | None, Path | None]:
        """(working directory, parser to link) -- a None directory means a
        fresh temporary one holding links to the parser."""
        workdir = self.path_option("workdir")
        if workdir is not None:
            if not workdir.is_dir():
                raise PlannerError(f"prost: option 'workdir' is not a folder: {workdir}")
            if not any((workdir / n).exists() for n in PARSER_NAMES):
                log.warning(
                    "PROST's working directory %s holds no %s: PROST will fail to parse the task",
                    workdir,
                    " or ".join(PARSER_NAMES),
                )
            return workdir.absolute(), None
        parser = self.path_option("parser")
        if parser is not None:
            if not _executable(parser):
                raise PlannerError(f"prost: option 'parser' is not an executable file: {parser}")
            return None, Path(os.path.abspath(parser))
        folder = self.binary.parent
        if any(_executable(folder / n) for n in PARSER_NAMES):
            return folder, None
        candidates = [folder / "rddl-parser", folder.parent / "rddl_parser" / "rddl-parser"]
        for cand in candidates:
            if _executable(cand):
                return None, Path(os.path.abspath(cand))
        looked = [str(folder / n) for n in PARSER_NAMES] + [str(c) for c in candidates]
        raise PlannerError(
            "prost: PROST runs its rddl-parser from its working directory, but none was found "
            f"(looked for {', '.join(looked)}); give the parser with the planner option "
            "parser=PATH, or a folder holding rddl-parser-release with workdir=DIR"
        )

    # -- the run -----------------------------------------------------

    def run_session(
        self,
        *,
        host: str,
        port: int,
        instance: str,
        client_name: str | None = None,
        timeout: float | None = None,
        log_path: Path | None = None,
    ) -> ExternalResult:
        """Run PROST against host:port for `instance` until it exits, the
        timeout (seconds) passes or `cancel()` is called; PROST's whole
        process group is gone when this returns or raises."""
        if client_name not in (None, "prost"):
            log.warning(
                "PROST always names itself 'prost' in its session request, not %r", client_name
            )
        path = log_path or self.log_file
        if path is None:
            fd, name = tempfile.mkstemp(prefix=f"prost-{_safe(instance)}-", suffix=".log")
            os.close(fd)
            path = Path(name)
        cmd = prost_command(self.binary, instance, host, port, self.config, self.parser_options)
        temp_dir: str | None = None
        start = time.monotonic()
        try:
            if self.workdir is not None:
                cwd = self.workdir
            else:
                assert self.parser_link is not None
                temp_dir = tempfile.mkdtemp(prefix="prost-work-")
                for n in PARSER_NAMES:
                    os.symlink(self.parser_link, os.path.join(temp_dir, n))
                cwd = Path(temp_dir)
            log.info("starting PROST: %s (in %s; log %s)", shlex.join(cmd), cwd, path)
            try:
                out = open(path, "wb")  # closed by the with below
            except OSError as err:
                raise PlannerError(f"prost: cannot write the log file {path}: {err}") from err
            with out:
                try:
                    proc = subprocess.Popen(
                        cmd,
                        cwd=cwd,
                        stdin=subprocess.DEVNULL,
                        stdout=out,
                        stderr=subprocess.STDOUT,
                        start_new_session=True,
                    )
                except OSError as err:
                    raise PlannerError(f"prost: cannot start {self.binary}: {err}") from err
                try:
                    stopped = self._wait(proc, start, timeout)
                finally:
                    self._stop_group(proc)
            seconds = time.monotonic() - start
        finally:
            if temp_dir is not None:
                shutil.rmtree(temp_dir, ignore_errors=True)
            self._cancelled.clear()
        return self._result(proc.returncode, stopped, timeout, seconds, path)

    def _wait(
        self, proc: subprocess.Popen[bytes], start: float, timeout: float | None
    ) -> str | None:
        """Block until PROST exits (None), the timeout passes ('timeout') or
        cancel() is called ('cancelled'), without reaping PROST."""
        deadline = None if timeout is None else start + timeout
        while not _exited(proc):
            if deadline is not None and time.monotonic() >= deadline:
                return "timeout"
            if self._cancelled.wait(_POLL):
                return "cancelled"
        return None

    def _stop_group(self, proc: subprocess.Popen[bytes]) -> None:
        """SIGTERM to PROST's process group; SIGKILL once PROST and every
        other member are gone or the grace period is over; then reap PROST."""
        pgid = proc.pid  # start_new_session: PROST leads its own group

        def others() -> list[int] | None:
            return _proc_group_members(pgid, exclude=proc.pid)

        _killpg(pgid, signal.SIGTERM)
        _poll_until(lambda: _exited(proc) and not others(), self.grace)
        # PROST is unreaped here (waitid with WNOWAIT), so the group id is
        # still ours: this cannot hit a stranger.
        _killpg(pgid, signal.SIGKILL)
        # A SIGKILL takes effect when the kernel next runs its target, which on a
        # busy machine may be after killpg returns: wait (bounded) until no member
        # is left alive, so that none outlives this call.
        if not _poll_until(lambda: not others(), _KILL_WAIT):
            log.error(
                "PROST's process group %d: %s still alive %g s after SIGKILL",
                pgid,
                others(),
                _KILL_WAIT,
            )
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            log.error("PROST (pid %d) did not die after SIGKILL", proc.pid)

    def _result(
        self,
        code: int | None,
        stopped: str | None,
        timeout: float | None,
        seconds: float,
        path: Path,
    ) -> ExternalResult:
        try:
            text = path.read_text(errors="replace")
        except OSError as err:
            text = ""
            log.error("cannot read PROST's log %s: %s", path, err)
        out = parse_prost_output(text)
        exit_code = code if code is not None else -int(signal.SIGKILL)
        problems: list[str] = []
        if stopped == "timeout":
            problems.append(
                f"PROST did not finish within {timeout:g} s; its process group was killed"
            )
        elif stopped == "cancelled":
            problems.append("PROST was stopped before it finished (cancelled)")
        if out.errors:
            more = f" (and {len(out.errors) - 1} more)" if len(out.errors) > 1 else ""
            problems.append(f"PROST reported an error: {out.errors[0]}{more}")
        if stopped is None:
            if exit_code < 0:
                problems.append(f"PROST was killed by signal {_signal_name(-exit_code)}")
            elif exit_code != 0:
                problems.append(f"PROST exited with status {exit_code}")
            elif out.total_reward is None and not out.errors:
                problems.append("PROST exited without reporting the session's total reward")
        error = f"{'; '.join(problems)} (log: {path})" if problems else None
        if error:
            log.error("%s", error)
        else:
            log.info(
                "PROST finished in %.1f s: %d rounds, total reward %s",
                seconds,
                len(out.rounds),
                out.total_reward,
            )
        return ExternalResult(
            exit_code=exit_code,
            rounds=out.rounds,
            total_reward=out.total_reward,
            seconds=seconds,
            log_path=path,
            error=error,
        )


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", text)[:60]


def _signal_name(num: int) -> str:
    try:
        return signal.Signals(num).name
    except ValueError:
        return str(num)


def _poll_until(done: Callable[[], bool], seconds: float) -> bool:
    """Check `done` every `_POLL` seconds until it holds (True) or
    `seconds` have passed (False)."""
    end = time.monotonic() + seconds
    while not done():
        if time.monotonic() >= end:
            return False
        time.sleep(_POLL)
    return True


def _killpg(pgid: int, sig: signal.Signals) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(pgid, sig)


def _exited(proc: subprocess.Popen[bytes]) -> bool:
    """Whether the process has exited, leaving it unreaped where the OS
    allows (so its pid and group id are not reused before we kill the
    group)."""
    if proc.returncode is not None:
        return True
    if hasattr(os, "waitid"):
        try:
            info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            return proc.poll() is not None
        return info is not None
    return proc.poll() is not None
