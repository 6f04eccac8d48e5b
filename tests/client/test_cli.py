"""`rddl-client` as a user runs it: a subprocess against our server, which
runs as a subprocess too (`rddl-server` on the bundled domains, 2 rounds,
with a result database to check the client's JSON against)."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from ippc.server.store import ResultStore

from .loopback import REPO, Server

CLIENT = Path(sys.executable).parent / "rddl-client"
FAKES = REPO / "tests" / "fakes"
FAKE_PROST = FAKES / "fake_prost.py"
FAKE_PARSER = FAKES / "fake_rddl_parser.py"
INSTANCE = "corridor_enum_inst_1"  # horizon 15
HORIZON = 15

REQUIRED = {"instance", "planner", "client_name", "total_reward", "mean_round_reward", "rounds"}
ROUND_KEYS = {"round", "reward", "turns", "seconds", "training"}


def client_env(**extra: str) -> dict[str, str]:
    env = {
        k: v for k, v in os.environ.items() if k != "PROST_BIN" and not k.startswith("FAKE_PROST_")
    }
    env["FAKE_PROST_MAX_SECONDS"] = "30"  # a fake PROST stops by itself whatever happens
    env.update(extra)
    return env


def rddl_client(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(CLIENT), *args],
        capture_output=True,
        text=True,
        timeout=60,
        env=env or client_env(),
        cwd=REPO,
    )


def stored(db: Path, client_name: str) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The one finished session of `client_name` in the server's database
    (waits a little: the server closes the row just after session-end)."""
    deadline = time.monotonic() + 10
    while True:
        with ResultStore(db) as store:
            rows = [s for s in store.sessions() if s["client_name"] == client_name]
            if len(rows) == 1 and rows[0]["status"] != "open":
                return rows[0], store.rounds(rows[0]["id"])
        assert time.monotonic() < deadline, rows
        time.sleep(0.05)


def check_json(
    data: dict[str, Any],
    *,
    planner: str,
    client_name: str,
    rounds: list[dict[str, Any]],
    total: float,
) -> None:
    # Today the JSON also has session_id and seconds (driven planners) or
    # exit_code and error (external planners), and ended_early per round of
    # a driven planner: extra keys are allowed.
    assert REQUIRED <= set(data)
    assert data["instance"] == INSTANCE
    assert data["planner"] == planner
    assert data["client_name"] == client_name
    assert data["total_reward"] == total
    assert [set(r) >= ROUND_KEYS for r in data["rounds"]] == [True] * len(rounds)
    assert [(r["round"], r["reward"], r["training"]) for r in data["rounds"]] == [
        (r["round_num"], r["reward"], False) for r in rounds
    ]
    assert data["mean_round_reward"] == pytest.approx(
        sum(r["reward"] for r in rounds) / len(rounds)
    )


def test_session_with_json_out(server: Server, tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    proc = rddl_client(
        "--port",
        str(server.port),
        "--instance",
        INSTANCE,
        "--name",
        "cli-json",
        "--json-out",
        str(out),
        "--timeout",
        "20",
    )
    assert proc.returncode == 0, proc.stderr
    row, rounds = stored(server.db, "cli-json")
    assert row["status"] == "finished" and row["no_header"] is False
    data = json.loads(out.read_text())
    check_json(
        data, planner="noop", client_name="cli-json", rounds=rounds, total=row["total_reward"]
    )
    assert [r["turns"] for r in data["rounds"]] == [HORIZON, HORIZON]
    assert all(isinstance(r["seconds"], float) and r["seconds"] >= 0 for r in data["rounds"])
    assert data["total_reward"] == data["rounds"][0]["reward"] + data["rounds"][1]["reward"]
    # the table on stdout
    assert f"{INSTANCE}  planner noop  client cli-json" in proc.stdout
    assert re.search(rf"^\s+1\s+{data['rounds'][0]['reward']:.4f}\s+{HORIZON}\s", proc.stdout, re.M)
    assert f"total reward {data['total_reward']}" in proc.stdout


def test_random_planner_no_header_and_seed(server: Server, tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    proc = rddl_client(
        "--port",
        str(server.port),
        "--instance",
        INSTANCE,
        "--planner",
        "random",
        "--seed",
        "5",
        "--no-header",
        "--name",
        "cli-random",
        "--json-out",
        str(out),
        "-q",
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # -q: no log lines
    row, rounds = stored(server.db, "cli-random")
    assert row["no_header"] is True
    check_json(
        json.loads(out.read_text()),
        planner="random",
        client_name="cli-random",
        rounds=rounds,
        total=row["total_reward"],
    )


def test_seed_with_a_planner_without_seed_option(server: Server) -> None:
    """--seed reaches SessionInfo.seed for every planner; it is passed as the
    planner option `seed` only to planners that declare one (noop does not)."""
    proc = rddl_client(
        "--port",
        str(server.port),
        "--instance",
        INSTANCE,
        "--seed",
        "3",
        "--name",
        "cli-noop-seed",
        "-q",
    )
    assert proc.returncode == 0, proc.stderr
    row, _ = stored(server.db, "cli-noop-seed")
    assert row["status"] == "finished"


@pytest.mark.parametrize(
    "planner,options",
    [("mcts", ["time_per_step=0.05", "seed=4"]), ("replan", ["time_per_step=0.05", "seed=4"])],
)
def test_planners_that_plan_from_the_command_line(
    server: Server, tmp_path: Path, planner: str, options: list[str]
) -> None:
    """mcts and replan by name from rddl-client, with options, walk the
    corridor to its goal: noop scores -15 a round there (15 steps away from
    the goal); walking right takes about 7 steps (moves slip 20% of the time
    and go the wrong way 5%), about -7.5 a round."""
    out = tmp_path / "result.json"
    option_args = [arg for option in options for arg in ("--planner-option", option)]
    proc = rddl_client(
        "--port", str(server.port), "--instance", INSTANCE, "--planner", planner,
        *option_args, "--name", f"cli-{planner}", "--json-out", str(out), "-q",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    row, rounds = stored(server.db, f"cli-{planner}")
    data = json.loads(out.read_text())
    check_json(data, planner=planner, client_name=f"cli-{planner}", rounds=rounds,
               total=row["total_reward"])  # fmt: skip
    assert data["mean_round_reward"] > -12.0, data["rounds"]


def test_exact_planner_from_the_command_line(server: Server, tmp_path: Path) -> None:
    """`--planner exact` solves print_jobs_inst_1 (480 reachable states,
    optimum 12.53 a round) and plays it; noop scores -20 a round there. On
    the corridor, whose termination it does not enumerate, it stops before
    playing with the reason."""
    out = tmp_path / "result.json"
    proc = rddl_client(
        "--port", str(server.port), "--instance", "print_jobs_inst_1", "--planner", "exact",
        "--name", "cli-exact", "--json-out", str(out), "-q",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    assert data["planner"] == "exact" and len(data["rounds"]) == 2
    assert data["mean_round_reward"] > 0.0, data["rounds"]
    proc = rddl_client("--port", str(server.port), "--instance", INSTANCE, "--planner", "exact")
    assert proc.returncode == 1
    assert "planner exact: cannot solve corridor_enum_inst_1: a termination condition" in (
        proc.stderr
    )


@pytest.mark.parametrize(
    "option,code,message",
    [
        ("foo", 2, "Invalid value for --planner-option: 'foo' is not KEY=VALUE"),
        ("=1", 2, "Invalid value for --planner-option: '=1' is not KEY=VALUE"),
        (
            "foo=1",
            1,
            "Error: planner 'random' has no option 'foo' (valid options: seed, when_stuck)",
        ),
        ("seed=abc", 1, "Error: planner 'random': option 'seed' must be an integer, got 'abc'"),
    ],
)
def test_bad_planner_option(option: str, code: int, message: str) -> None:
    # no server needed: the options are checked before connecting (port 9 is
    # never reached)
    proc = rddl_client(
        "--port", "9", "--instance", INSTANCE, "--planner", "random", "--planner-option", option
    )
    assert proc.returncode == code
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr


def test_unknown_planner_lists_the_known_ones() -> None:
    proc = rddl_client("--port", "9", "--instance", INSTANCE, "--planner", "nosuch")
    assert proc.returncode == 1
    assert "unknown planner 'nosuch'" in proc.stderr
    for name in ("noop", "random", "prost"):
        assert name in proc.stderr
    assert "Traceback" not in proc.stderr


def test_closed_port() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound, nobody listens
        proc = rddl_client("--port", str(port), "--instance", INSTANCE, "--timeout", "5")
    assert proc.returncode == 1
    assert f"Error: cannot connect to 127.0.0.1:{port}" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_stalling_server_times_out() -> None:
    """A listener that never answers (the kernel completes the connection,
    nobody reads it): --timeout, then a clear error."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        t0 = time.monotonic()
        proc = rddl_client(
            "--port", str(s.getsockname()[1]), "--instance", INSTANCE, "--timeout", "0.5"
        )
        elapsed = time.monotonic() - t0
    assert proc.returncode == 1
    assert (
        "Error: no answer from the server for 0.5 s while waiting for session-init" in proc.stderr
    )
    assert elapsed < 10


def test_unknown_instance(server: Server) -> None:
    proc = rddl_client(
        "--port", str(server.port), "--instance", "no_such_instance", "--timeout", "10"
    )
    assert proc.returncode == 1
    assert "Error: the server closed the connection while we waited for session-init" in proc.stderr


# ------------------------------------------------------------------- PROST


def test_prost_without_a_parser_beside_the_fake(server: Server) -> None:
    """PROST runs ./rddl-parser-release from its working directory; there is
    none beside tests/fakes/fake_prost.py, so the launcher refuses before
    connecting and says what to do."""
    proc = rddl_client(
        "--port",
        str(server.port),
        "--instance",
        INSTANCE,
        "--planner",
        "prost",
        "--prost",
        str(FAKE_PROST),
    )
    assert proc.returncode == 1
    assert "rddl-parser" in proc.stderr and "parser=PATH" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_prost_binary_not_found(tmp_path: Path) -> None:
    proc = rddl_client(
        "--port",
        "9",
        "--instance",
        INSTANCE,
        "--planner",
        "prost",
        "--prost",
        str(tmp_path / "nope"),
    )
    assert proc.returncode == 1
    assert "PROST binary not found" in proc.stderr


def test_fake_prost_with_parser_option(server: Server, tmp_path: Path) -> None:
    """The fake PROST through the launcher: it plays the session itself (no
    header, client name prost), the client reports what it printed."""
    out = tmp_path / "result.json"
    log = tmp_path / "prost.log"
    proc = rddl_client(
        "--port",
        str(server.port),
        "--instance",
        INSTANCE,
        "--planner",
        "prost",
        "--prost",
        str(FAKE_PROST),
        "--planner-option",
        f"parser={FAKE_PARSER}",
        "--planner-option",
        f"log={log}",
        "--json-out",
        str(out),
        "--timeout",
        "30",
    )
    assert proc.returncode == 0, proc.stderr
    row, rounds = stored(server.db, "prost")
    assert row["no_header"] is True and row["status"] == "finished"
    data = json.loads(out.read_text())
    check_json(data, planner="prost", client_name="prost", rounds=rounds, total=row["total_reward"])
    # an external planner reports no turns or times per round
    assert [(r["turns"], r["seconds"]) for r in data["rounds"]] == [(None, None), (None, None)]
    assert data["exit_code"] == 0 and data["error"] is None
    assert ">>> END OF SESSION  -- TOTAL REWARD: " in log.read_text()
    assert f"total reward {row['total_reward']}" in proc.stdout


def test_fake_prost_in_a_prost_folder_from_prost_bin(server: Server, tmp_path: Path) -> None:
    """PROST's own layout (search and rddl-parser-release side by side),
    found through $PROST_BIN."""
    folder = tmp_path / "prost"
    folder.mkdir()
    os.symlink(FAKE_PROST, folder / "search")
    os.symlink(FAKE_PARSER, folder / "rddl-parser-release")
    log = tmp_path / "prost.log"
    env = client_env(PROST_BIN=str(folder / "search"))
    # a second session of client "prost" on the same server: count before
    with ResultStore(server.db) as store:
        before = len([s for s in store.sessions() if s["client_name"] == "prost"])
    proc = rddl_client(
        "--port",
        str(server.port),
        "--instance",
        INSTANCE,
        "--planner",
        "prost",
        "--planner-option",
        f"log={log}",
        "--timeout",
        "30",
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    m = re.findall(r"round\s+(\d+)\s+reward\s+(\S+)", proc.stdout)
    assert [int(n) for n, _ in m] == [1, 2]
    deadline = time.monotonic() + 10
    while True:
        with ResultStore(server.db) as store:
            rows = [s for s in store.sessions() if s["client_name"] == "prost"]
            if len(rows) == before + 1 and rows[-1]["status"] != "open":
                stored_rounds = store.rounds(rows[-1]["id"])
                break
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert [float(r) for _, r in m] == [r["reward"] for r in stored_rounds]
    # the parser's temporary files are gone
    assert sorted(p.name for p in folder.iterdir()) == ["rddl-parser-release", "search"]
