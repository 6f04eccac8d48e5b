"""The PROST launcher against a replaying test server, with the fake PROST
(tests/fakes/fake_prost.py) as the binary."""

from __future__ import annotations

import _thread
import csv
import gzip
import os
import re
import shutil
import signal
import socket
import threading
import time
from pathlib import Path

import pytest
from ippc.planners import (
    DEFAULT_CONFIG,
    ExternalResult,
    PlannerError,
    ProstPlanner,
    make_planner,
    parse_prost_output,
)
from ippc.planners.prost import check_config, prost_command

from .conftest import FAKE_PARSER, FAKE_PROST
from .prost_server import ReplayServer, load_recording, recorded_actions, short_session

# PROST process groups, hangs, kills and grace periods: needs the machine to itself
pytestmark = pytest.mark.alone

INSTANCES = [
    "sysadmin_inst_mdp__1",
    "elevators_inst_mdp__1",
    "game_of_life_inst_mdp__1",
    "chromatic-dice_inst_mdp__01",
]


def recorded_rounds(transcripts: Path) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    with open(transcripts / "results.csv") as f:
        for row in csv.DictReader(f):
            out.setdefault(row["instance"], []).append(float(row["round_reward"]))
    return out


def recorded_total(script: list[tuple[str, bytes]]) -> float:
    end = [d for k, d in script if k == "s2c" and d.startswith(b"<session-end>")][-1]
    m = re.search(rb"<total-reward>([^<]+)</total-reward>", end)
    assert m
    return float(m.group(1))


def alive(pid: int) -> bool:
    """Whether a process exists and is not a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    except OSError:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True
    return stat[stat.rfind(")") + 2 :].split()[0] not in ("Z", "X")


def fake_pids(log: Path) -> tuple[int, int]:
    """The pids the fake prints in hang mode (waits for the line)."""
    for _ in range(100):
        m = re.search(r"fake-prost: pid (\d+) child (\d+)", log.read_text())
        if m:
            return int(m.group(1)), int(m.group(2))
        time.sleep(0.05)
    raise AssertionError(f"no pids in {log}: {log.read_text()!r}")


def run(
    planner: ProstPlanner, server: ReplayServer, instance: str, log: Path, **kw: object
) -> ExternalResult:
    args: dict[str, object] = dict(
        host="127.0.0.1",
        port=server.port,
        instance=instance,
        client_name=None,
        timeout=20.0,
        log_path=log,
    )
    args.update(kw)
    return planner.run_session(**args)  # type: ignore[arg-type]


# ------------------------------------------------------------------ output


@pytest.mark.parametrize("instance", INSTANCES)
def test_parse_recorded_prost_stdout(prost_transcripts: Path, instance: str) -> None:
    with gzip.open(prost_transcripts / f"{instance}.prost-stdout.txt.gz", "rt") as f:
        out = parse_prost_output(f.read())
    rounds = recorded_rounds(prost_transcripts)[instance]
    script = load_recording(prost_transcripts / f"{instance}.jsonl.gz")
    assert out.rounds == rounds
    assert out.total_reward == pytest.approx(recorded_total(script))
    assert out.total_reward == pytest.approx(sum(rounds))
    assert out.average_reward == pytest.approx(sum(rounds) / 5)
    assert out.errors == []


def test_parse_errors_and_partial_output() -> None:
    text = (
        ">>> STARTING ROUND 1 -- REMAINING TIME 30s\n"
        ">>> END OF ROUND 1 -- REWARD RECEIVED: 149.000000\n"
        "ERROR: Error: round-request response insufficient.\n"
        "Unknown option: --bogus\n"
    )
    out = parse_prost_output(text)
    assert out.rounds == [149.0]
    assert out.total_reward is None
    assert out.errors == ["Error: round-request response insufficient.", "Unknown option: --bogus"]


def test_command_line_and_config() -> None:
    assert prost_command("/p/search", "inst", "127.0.0.1", 2323) == [
        "/p/search",
        "inst",
        "-h",
        "127.0.0.1",
        "-p",
        "2323",
        DEFAULT_CONFIG,
    ]
    assert prost_command("s", "i", "h", 1, "[Prost -se [IPC2011]]", "-ipc2018 1")[-3:] == [
        "--parser-options",
        "-ipc2018 1",
        "[Prost -se [IPC2011]]",
    ]
    assert check_config("  [Prost -s 1 -se [IPC2014]] ") == "[Prost -s 1 -se [IPC2014]]"
    for bad in ("Prost -se [IPC2014]", "[Prost -se [IPC2014]", "[A] [B]", "[Prost]]"):
        with pytest.raises(PlannerError, match="config"):
            check_config(bad)


# ----------------------------------------------------------- configuration


def test_binary_from_env_and_option(prost_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(PlannerError, match="PROST_BIN"):
        ProstPlanner()
    monkeypatch.setenv("PROST_BIN", str(prost_dir / "search"))
    p = ProstPlanner()
    assert p.binary == prost_dir / "search"  # the link, not its target
    assert p.workdir == prost_dir and p.parser_link is None
    other = prost_dir.parent / "other"
    shutil.copytree(prost_dir, other, symlinks=True)
    assert ProstPlanner(binary=str(other / "search")).binary == other / "search"
    assert ProstPlanner(binary=str(prost_dir)).binary == prost_dir / "search"  # a folder


def test_missing_and_broken_binary(tmp_path: Path) -> None:
    with pytest.raises(PlannerError, match="not found: .*nothing-here"):
        ProstPlanner(binary=str(tmp_path / "nothing-here"))
    plain = tmp_path / "search"
    plain.write_text("#!/bin/sh\n")
    plain.chmod(0o644)
    with pytest.raises(PlannerError, match="not executable"):
        ProstPlanner(binary=str(plain))
    with pytest.raises(PlannerError, match="no PROST search program in the folder"):
        ProstPlanner(binary=str(tmp_path))
    plain.chmod(0o755)
    with pytest.raises(PlannerError, match="rddl-parser"):
        ProstPlanner(binary=str(plain))  # executable, but no parser anywhere near


def test_bad_options(prost_dir: Path) -> None:
    with pytest.raises(
        PlannerError, match=r"no option 'timeout' \(valid options: binary, config, "
    ):
        ProstPlanner(binary=str(prost_dir / "search"), timeout="3")
    with pytest.raises(PlannerError, match="'grace' must be a number >= 0"):
        ProstPlanner(binary=str(prost_dir / "search"), grace="-1")
    with pytest.raises(PlannerError, match="'grace' must be a number"):
        ProstPlanner(binary=str(prost_dir / "search"), grace="soon")
    with pytest.raises(PlannerError, match="'workdir' is not a folder"):
        ProstPlanner(binary=str(prost_dir / "search"), workdir=str(prost_dir / "nope"))
    with pytest.raises(PlannerError, match="'parser' is not an executable"):
        ProstPlanner(binary=str(prost_dir / "search"), parser=str(prost_dir / "nope"))
    p = make_planner("prost", {"binary": str(prost_dir / "search"), "parser-options": "-x"})
    assert isinstance(p, ProstPlanner) and p.parser_options == "-x"


# ------------------------------------------------------------ whole sessions


@pytest.mark.parametrize("instance", INSTANCES)
def test_replayed_session_bytes_and_result(
    prost_transcripts: Path,
    prost_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    instance: str,
) -> None:
    """The fake sends exactly PROST's bytes of the recorded session and
    prints PROST's output, from which the launcher reads the results."""
    script = load_recording(prost_transcripts / f"{instance}.jsonl.gz")
    actions = tmp_path / "actions.txt"
    actions.write_text(
        "\n".join(recorded_actions(prost_transcripts / f"{instance}.prost-stdout.txt.gz")) + "\n"
    )
    monkeypatch.setenv("FAKE_PROST_ACTIONS_FILE", str(actions))
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.5")
    with ReplayServer(script) as server:
        result = run(planner, server, instance, tmp_path / "prost.log")
    assert server.mismatch is None and server.error is None
    assert server.finished and server.client_closed
    assert b"".join(server.received) == (prost_transcripts / f"{instance}.c2s.raw").read_bytes()
    assert result.error is None and result.ok
    assert result.exit_code == 0
    assert result.rounds == recorded_rounds(prost_transcripts)[instance]
    assert result.total_reward == pytest.approx(recorded_total(script))
    assert result.log_path == tmp_path / "prost.log"
    assert 0 < result.seconds < 15
    # PROST's temporary parser files are gone from its working directory
    assert sorted(p.name for p in prost_dir.iterdir()) == ["rddl-parser-release", "search"]


def test_build_tree_layout_runs_in_a_temporary_folder(
    prost_transcripts: Path, tmp_path: Path
) -> None:
    """PROST's build tree (builds/release/search/search beside
    builds/release/rddl_parser/rddl-parser): given the checkout folder, the
    launcher finds both and runs PROST in a temporary folder that links the
    parser as ./rddl-parser-release; the default log is a temporary file."""
    root = tmp_path / "prost-checkout"
    (root / "builds/release/search").mkdir(parents=True)
    (root / "builds/release/rddl_parser").mkdir(parents=True)
    os.symlink(FAKE_PROST, root / "builds/release/search/search")
    os.symlink(FAKE_PARSER, root / "builds/release/rddl_parser/rddl-parser")
    planner = ProstPlanner(binary=str(root), grace="0.5")
    assert planner.workdir is None
    assert planner.parser_link == root / "builds/release/rddl_parser/rddl-parser"
    script = short_session(load_recording(prost_transcripts / "sysadmin_inst_mdp__1.jsonl.gz"))
    with ReplayServer(script) as server:
        result = run(planner, server, "sysadmin_inst_mdp__1", None)
    try:
        assert server.mismatch is None and server.finished
        assert result.error is None, result.error
        assert result.rounds == [312.25] and result.total_reward == 1619.75
        assert result.log_path is not None and result.log_path.name.startswith(
            "prost-sysadmin_inst_mdp__1-"
        )
        assert "Writing output for instance sysadmin_inst_mdp__1" in result.log_path.read_text()
    finally:
        if result.log_path is not None:
            result.log_path.unlink()


def test_workdir_without_parser_gives_prost_error(
    prost_transcripts: Path, prost_dir: Path, tmp_path: Path
) -> None:
    """PROST runs ./rddl-parser-release through the shell; when it is not
    there PROST prints an ERROR line and exits 0: the result says so."""
    empty = tmp_path / "empty"
    empty.mkdir()
    planner = ProstPlanner(binary=str(prost_dir / "search"), workdir=str(empty), grace="0.5")
    script = short_session(load_recording(prost_transcripts / "sysadmin_inst_mdp__1.jsonl.gz"))[:2]
    with ReplayServer(script, timeout=10) as server:
        result = run(planner, server, "sysadmin_inst_mdp__1", tmp_path / "prost.log")
    assert result.exit_code == 0
    assert result.error is not None
    assert "PROST reported an error: Error: ./rddl-parser-release  had an error" in result.error
    assert str(tmp_path / "prost.log") in result.error
    assert result.rounds == [] and result.total_reward is None


def test_session_cut_short_is_an_error_with_the_rounds_played(
    prost_transcripts: Path, prost_dir: Path, tmp_path: Path
) -> None:
    """As rddlsim does once the session's time is up: the second
    round-request gets session-end; PROST reports the error and exits 0."""
    script = short_session(
        load_recording(prost_transcripts / "game_of_life_inst_mdp__1.jsonl.gz"), rounds_cut=True
    )
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.5")
    with ReplayServer(script) as server:
        result = run(planner, server, "game_of_life_inst_mdp__1", tmp_path / "prost.log")
    assert server.mismatch is None and server.finished
    assert result.exit_code == 0
    assert result.rounds == [217.0]  # the first recorded round-end
    assert result.total_reward is None
    assert result.error is not None and "round-request response insufficient" in result.error


def test_server_closing_mid_round_crashes_prost(
    prost_transcripts: Path, prost_dir: Path, tmp_path: Path
) -> None:
    """PROST dereferences the missing answer and dies of SIGSEGV."""
    script = short_session(load_recording(prost_transcripts / "sysadmin_inst_mdp__1.jsonl.gz"))[:6]
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.5")
    with ReplayServer(script, linger=0) as server:
        result = run(planner, server, "sysadmin_inst_mdp__1", tmp_path / "prost.log")
    assert result.exit_code == -11
    assert result.error is not None and "killed by signal SIGSEGV" in result.error


def test_no_server_listening(prost_dir: Path, tmp_path: Path) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nobody listens there
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.5")
    result = planner.run_session(
        host="127.0.0.1",
        port=port,
        instance="x",
        client_name=None,
        timeout=10,
        log_path=tmp_path / "l",
    )
    assert result.exit_code == 0
    assert result.error is not None and "couldn't connect to server" in result.error


# ------------------------------------------------------------- fake modes


def test_error_mode_prints_error_and_exits_zero(
    prost_transcripts: Path, prost_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAKE_PROST_MODE", "error")
    script = short_session(load_recording(prost_transcripts / "sysadmin_inst_mdp__1.jsonl.gz"))[:2]
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.5")
    with ReplayServer(script, timeout=10) as server:
        result = run(planner, server, "sysadmin_inst_mdp__1", tmp_path / "prost.log")
    assert result.exit_code == 0
    assert result.error is not None
    assert (
        "PROST reported an error: Error: search engine specification is insufficient"
        in result.error
    )
    assert "ERROR: Error: search engine" in (tmp_path / "prost.log").read_text()


def test_config_without_search_engine(
    prost_transcripts: Path, prost_dir: Path, tmp_path: Path
) -> None:
    script = short_session(load_recording(prost_transcripts / "sysadmin_inst_mdp__1.jsonl.gz"))[:2]
    planner = ProstPlanner(binary=str(prost_dir / "search"), config="[Prost -s 1]", grace="0.5")
    with ReplayServer(script, timeout=10) as server:
        result = run(planner, server, "sysadmin_inst_mdp__1", tmp_path / "prost.log")
    assert (
        result.error is not None and "search engine specification is insufficient" in result.error
    )


def test_crash_mode(prost_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FAKE_PROST_MODE", "crash")
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.5")
    with ReplayServer([("c2s", b"<?xml")], timeout=10) as server:
        result = run(planner, server, "sysadmin_inst_mdp__1", tmp_path / "prost.log")
    assert result.exit_code == 3
    assert result.error is not None and result.error.startswith("PROST exited with status 3")


@pytest.mark.parametrize("ignore_term", [False, True])
def test_hang_times_out_and_kills_the_group(
    prost_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ignore_term: bool
) -> None:
    """Timeout: PROST and the child it started are gone when run_session
    returns; a group that ignores SIGTERM gets SIGKILL after the grace."""
    monkeypatch.setenv("FAKE_PROST_MODE", "hang")
    if ignore_term:
        monkeypatch.setenv("FAKE_PROST_IGNORE_TERM", "1")
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.4")
    log = tmp_path / "prost.log"
    with ReplayServer([("c2s", b"<?xml")], timeout=10) as server:
        # 3 s: the fake (a Python program) must be up, its SIGTERM handler
        # set and its child started before the timeout, even on a busy machine
        result = run(planner, server, "sysadmin_inst_mdp__1", log, timeout=3.0)
    pid, child = fake_pids(log)
    assert not alive(pid) and not alive(child)
    assert result.error is not None and result.error.startswith("PROST did not finish within 3 s")
    if ignore_term:
        assert result.exit_code == -9 and result.seconds >= 3.4
    else:
        assert result.exit_code == -15
    assert result.seconds < 8


def test_keyboard_interrupt_kills_the_group(
    prost_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAKE_PROST_MODE", "hang")
    # A process started in the background by a non-interactive shell (`make test &`)
    # inherits SIGINT ignored, and then interrupt_main does nothing: give the test
    # Python's own handler whatever the caller left.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.4")
    log = tmp_path / "prost.log"
    timer = threading.Timer(1.0, _thread.interrupt_main)
    with ReplayServer([("c2s", b"<?xml")], timeout=10) as server:
        timer.start()
        try:
            with pytest.raises(KeyboardInterrupt):
                run(planner, server, "sysadmin_inst_mdp__1", log, timeout=15.0)
        finally:
            timer.cancel()
            signal.signal(signal.SIGINT, previous)
    pid, child = fake_pids(log)
    assert not alive(pid) and not alive(child)


def test_cancel_from_another_thread(
    prost_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAKE_PROST_MODE", "hang")
    planner = ProstPlanner(binary=str(prost_dir / "search"), grace="0.4")
    log = tmp_path / "prost.log"
    timer = threading.Timer(0.8, planner.cancel)
    with ReplayServer([("c2s", b"<?xml")], timeout=10) as server:
        timer.start()
        result = run(planner, server, "sysadmin_inst_mdp__1", log, timeout=15.0)
    pid, child = fake_pids(log)
    assert not alive(pid) and not alive(child)
    assert result.error is not None and "cancelled" in result.error
    assert result.seconds < 5


def test_binary_removed_before_the_run(prost_dir: Path, tmp_path: Path) -> None:
    planner = ProstPlanner(binary=str(prost_dir / "search"))
    (prost_dir / "search").unlink()
    with pytest.raises(PlannerError, match="cannot start"):
        planner.run_session(
            host="127.0.0.1",
            port=1,
            instance="x",
            client_name=None,
            timeout=5,
            log_path=tmp_path / "l",
        )


def test_unwritable_log_file(prost_dir: Path, tmp_path: Path) -> None:
    planner = ProstPlanner(binary=str(prost_dir / "search"))
    with pytest.raises(PlannerError, match="cannot write the log file .*no-such-dir"):
        planner.run_session(
            host="127.0.0.1",
            port=1,
            instance="x",
            client_name=None,
            timeout=5,
            log_path=tmp_path / "no-such-dir" / "prost.log",
        )
