"""The batch's live model (batch.live), without HTTP: a real run with the observer, its
snapshot and events against what `rddl-batch score` computes from the same database."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any

import pytest
from ippc.batch import BatchStore, load_experiment, run_batch, score
from ippc.batch.live import BatchLive

from ..conftest import REPO

TINY = f"""
name = "tiny-live"
rounds = 2
timeout = 120
seed = 3
instances = ["{REPO / "domains" / "print_jobs" / "instance1.rddl"}"]

[planners.mcts]
planner = "mcts"
options = {{ iterations = "2", batch = "16" }}
"""


class Recorder:
    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []
        self.threads: set[str] = set()
        self.lock = threading.Lock()

    def __call__(self, event: dict[str, Any]) -> None:
        json.dumps(event)  # every event is JSON-able
        with self.lock:
            self.events.append(event)
            self.threads.add(threading.current_thread().name)

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [e for e in self.events if e["type"] == kind]


def run_tiny(folder: Path, jobs: int = 1) -> tuple[BatchLive, Recorder, Path]:
    path = folder / "tiny.toml"
    path.write_text(TINY)
    db = folder / "tiny.sqlite"
    live = BatchLive("ippc2014")
    rec = Recorder()
    live.subscribe(rec)
    summary = run_batch(load_experiment(path), db, jobs=jobs, observer=live)
    assert (summary.finished, summary.failed) == (3, 0)
    return live, rec, db


def expected_scores(db: Path) -> dict[str, Any]:
    with BatchStore(db) as store:
        return score(
            store.round_records("tiny-live"), "ippc2014", expected=store.expected()
        ).as_json()


def test_a_serial_run_seen_live(tmp_path: Path) -> None:
    live, rec, db = run_tiny(tmp_path)
    snap = live.snapshot()
    json.dumps(snap)
    assert snap["experiment"] == "tiny-live" and snap["state"] == "finished"
    assert snap["planners"] == ["noop", "random", "mcts"]
    assert [i["name"] for i in snap["instances"]] == ["print_jobs_inst_1"]
    assert {j["key"]: j["status"] for j in snap["jobs"]} == {
        "noop@print_jobs_inst_1": "finished",
        "random@print_jobs_inst_1": "finished",
        "mcts@print_jobs_inst_1": "finished",
    }
    assert all(j["rounds"] == 2 and j["attempts"] == 1 for j in snap["jobs"])
    assert snap["counts"]["finished"] == 3 and snap["counts"]["total"] == 3
    # the scores are rddl-batch score's, from the same database
    assert snap["scores"] == expected_scores(db)
    curves = snap["figures"]["reward_per_round"]["print_jobs_inst_1"]
    assert sorted(curves) == ["mcts", "noop", "random"]
    assert [p[0] for p in curves["noop"]] == [1, 2]
    per_turn = snap["figures"]["time_per_turn"]
    with BatchStore(db) as store:
        times = store.turn_times("tiny-live")
    noop = [t for p, _, _, t in times if p == "noop"]
    key = f"{times[0][2]}|noop"
    assert per_turn[key]["turns"] == len(noop)
    assert per_turn[key]["mean"] == pytest.approx(sum(noop) / len(noop))
    assert set(snap["figures"]["score_per_instance"]["print_jobs_inst_1"]) == {
        "noop",
        "random",
        "mcts",
    }
    # events: each job started and ended, progress turn by turn, scores after each job
    jobs = rec.of("job")
    assert [e["job"]["status"] for e in jobs] == ["running", "finished"] * 3
    progress = [e for e in rec.of("progress") if e["key"] == "mcts@print_jobs_inst_1"]
    assert [(e["round"], e["turn"]) for e in progress][:2] == [(1, None), (1, 1)]
    assert {e["round"] for e in progress} == {1, 2}
    assert len(rec.of("scores")) == 1 + 3  # at the start, then after each job
    assert rec.of("batch")[-1]["state"] == "finished"
    seqs = [e["seq"] for e in rec.events]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert snap["seq"] == seqs[-1]


def test_a_resumed_run_starts_from_the_database(tmp_path: Path) -> None:
    _, _, db = run_tiny(tmp_path)
    live = BatchLive("ippc2011")
    rec = Recorder()
    live.subscribe(rec)
    summary = run_batch(load_experiment(tmp_path / "tiny.toml"), db, jobs=1, observer=live)
    assert summary.skipped == 3
    snap = live.snapshot()
    assert [j["status"] for j in snap["jobs"]] == ["finished"] * 3
    assert all(j["rounds"] == 2 and j["mean"] is not None for j in snap["jobs"])
    with BatchStore(db) as store:
        want = score(store.round_records(), "ippc2011", expected=store.expected()).as_json()
    assert snap["scores"] == want
    assert snap["figures"]["time_per_turn"]  # read back from the steps
    assert not rec.of("job")


@pytest.mark.alone  # worker processes
def test_a_pool_run_reports_rounds_and_turns_from_the_workers(tmp_path: Path) -> None:
    live, rec, db = run_tiny(tmp_path, jobs=2)
    progress = rec.of("progress")
    assert {e["key"] for e in progress} == {
        "noop@print_jobs_inst_1",
        "random@print_jobs_inst_1",
        "mcts@print_jobs_inst_1",
    }
    assert any(e["turn"] is not None for e in progress)
    # from the threads that watch the jobs' processes
    assert any(t.startswith("batch-job") for t in rec.threads), rec.threads
    assert live.snapshot()["scores"] == expected_scores(db)


def test_an_observer_that_fails_never_stops_the_batch(tmp_path: Path) -> None:
    class Broken(BatchLive):
        def job_ended(self, result: Any) -> None:
            raise RuntimeError("boom")

    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    live = Broken()
    summary = run_batch(load_experiment(path), tmp_path / "db.sqlite", jobs=1, observer=live)
    assert summary.finished == 3
    assert live.snapshot()["state"] == "finished"


def test_unknown_rules_are_refused() -> None:
    from ippc.batch import ScoreError

    with pytest.raises(ScoreError, match="unknown rules 'ippc1999'"):
        BatchLive("ippc1999")
