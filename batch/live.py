"""The live picture of a batch run, for its web page (`batch.web`): plain data, no HTTP.

`BatchLive` is a `BatchObserver` (`batch.progress`): `run_batch` tells it when the run
starts (with its jobs and the result database), when each job is handed out, how far a
job's session got (round and turn, when the executor reports them: serial and local-pool
runs do, a Dask cluster does not), and when each job's result is in the database. It
keeps:

* the planner x instance grid: each job's status (pending, running, finished, timeout,
  failed, interrupted), its reason, its round and turn while it runs, and its rounds and
  mean round reward once done;
* the IPPC scores so far, computed as ``rddl-batch score`` computes them (`score` over
  the database's `round_records` and `expected` jobs), again after every job;
* the numbers of the three figures ``rddl-batch report`` draws: the score per instance,
  each planner's running mean of the round rewards per instance (`reward_curves`), and
  the seconds per turn per domain and planner.

`snapshot()` is the whole picture as a JSON-able dict; `subscribe(callback)` hears every
change as a small JSON-able event (``{"type": "job", ...}``, ``{"type": "scores", ...}``,
``{"type": "batch", ...}``). The run loop calls the observer methods from its thread
while a web server reads snapshots from another: every method takes one lock, and
callbacks run after it is released, in the run loop's thread (keep them short: the web
layer hands the event to its own loop and returns).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from ..web.pages import Listeners
from .jobs import Job, JobResult
from .report import reward_curves
from .results import DONE, BatchStore, RoundRecord
from .scoring import RULES, ScoreError, score

__all__ = ["BatchLive", "EventCallback"]

log = logging.getLogger(__name__)

EventCallback = Callable[[dict[str, Any]], None]

#: Job statuses, in the order the page's legend lists them.
STATUSES = ("pending", "running", "finished", "timeout", "failed", "interrupted")
#: The statuses whose jobs the scores so far count (as `BatchStore.round_records` reads
#: them); a job that failed counts as 0 where it played no round, as in FinalEval.
SCORED = ("finished", "timeout", "failed")
#: What the page keeps of a session (the database has everything).
SESSION_FACTS = (
    "server_session_id",
    "client_name",
    "seed",
    "num_rounds",
    "time_allowed_ms",
    "started_at",
    "ended_at",
    "status",
    "reason",
    "total_reward",
    "rounds_used",
)


@dataclass
class _Turns:
    """Seconds per turn of one job's session (Welford's running mean and variance)."""

    domain: str
    planner: str
    n: int = 0
    mean: float = 0.0
    m2: float = 0.0

    def add(self, x: float) -> None:
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self.m2 += d * (x - self.mean)


def _merge(parts: Iterable[_Turns]) -> tuple[int, float, float]:
    """(n, mean, sum of squared deviations) of several parts together (Chan et al.)."""
    n, mean, m2 = 0, 0.0, 0.0
    for p in parts:
        if p.n == 0:
            continue
        total = n + p.n
        d = p.mean - mean
        mean += d * p.n / total
        m2 += p.m2 + d * d * n * p.n / total
        n = total
    return n, mean, m2


class BatchLive:
    """What a batch run is doing, as data (see the module doc)."""

    def __init__(self, rules: str = "ippc2014", *, rounds: int | None = None) -> None:
        if rules not in RULES:
            raise ScoreError(f"unknown rules {rules!r} (known: {', '.join(RULES)})")
        self.rules = rules
        self.rounds = rounds  # N of the scores (None: the sessions' rounds)
        self._lock = threading.Lock()
        self._listeners = Listeners("batch live view")
        self._seq = 0
        self._store: BatchStore | None = None
        self.experiment = ""
        self.state = "starting"
        self.started_at = time.time()
        self.ended_at: float | None = None
        self._planners: list[str] = []
        self._instances: dict[str, str] = {}  # instance -> domain, in the experiment's order
        self._jobs: dict[str, dict[str, Any]] = {}
        self._turns: dict[str, _Turns] = {}  # job key -> its turn times
        self._scores: dict[str, Any] = {"error": "no rounds to score"}
        self._figures: dict[str, Any] = _empty_figures()
        # job key -> its session as the database has it (facts and rounds), once done
        self._sessions: dict[str, dict[str, Any]] = {}
        self.kept: str | None = None  # why the page stays up after the run (see BatchWeb)

    # ----------------------------------------------------------- listening

    def subscribe(self, callback: EventCallback) -> Callable[[], None]:
        """Call `callback(event)` for every change; returns the function that stops it."""
        return self._listeners.subscribe(callback)

    def _emit(self, events: list[dict[str, Any]]) -> None:
        self._listeners.emit(events)

    def _event(self, kind: str, **data: Any) -> dict[str, Any]:
        """Under the lock: the next event."""
        self._seq += 1
        return {"type": kind, "seq": self._seq, **data}

    # ----------------------------------------------------- the run's hooks

    def batch_started(self, experiment: str, jobs: list[Job], store: BatchStore) -> None:
        """The run begins: its jobs (registered in `store`) and what is there already."""
        rows = {r.job_key: r for r in store.jobs(experiment)}
        records = store.round_records(experiment)
        turn_rows = store.turn_times(experiment)
        sessions = _stored_sessions(store, experiment)
        with self._lock:
            self._store = store
            self.experiment = experiment
            self.state = "running"
            self.started_at = time.time()
            self._planners = list(dict.fromkeys(j.planner.label for j in jobs))
            self._instances = {j.instance: j.domain for j in jobs}
            self._jobs = {}
            for job in jobs:
                row = rows.get(job.key)
                self._jobs[job.key] = {
                    "key": job.key,
                    "planner": job.planner.label,
                    "instance": job.instance,
                    "domain": job.domain,
                    "status": row.status if row is not None else "pending",
                    "reason": row.reason if row is not None else None,
                    "attempts": row.attempts if row is not None else 0,
                    "round": None,
                    "turn": None,
                    "rounds": None,
                    "mean": None,
                    "started_at": None,
                    "ended_at": None,
                }
            _round_stats(self._jobs, records)
            self._sessions = {k: v for k, v in sessions.items() if k in self._jobs}
            self._turns = {}
            keys = {(j.planner.label, j.instance): j.key for j in jobs}
            for planner, instance, domain, seconds in turn_rows:
                key = keys.get((planner, instance))
                if key is not None:
                    self._turns.setdefault(key, _Turns(domain, planner)).add(seconds)
        self._rescore(records, "batch")

    def job_started(self, job: Job) -> None:
        """A job is handed out (to this process, a worker or the cluster)."""
        with self._lock:
            entry = self._jobs.get(job.key)
            if entry is None:
                return
            entry.update(
                status="running",
                reason=None,
                round=None,
                turn=None,
                started_at=time.time(),
                ended_at=None,
            )
            entry["attempts"] += 1
            events = [self._event("job", job=dict(entry), counts=self._counts())]
        self._emit(events)

    def job_progress(self, key: str, round_num: int, turn: int | None) -> None:
        """A running job's session is in round `round_num`, turn `turn` (None: the round
        just began)."""
        with self._lock:
            entry = self._jobs.get(key)
            if entry is None or entry["status"] != "running":
                return
            if (entry["round"], entry["turn"]) == (round_num, turn):
                return
            entry["round"], entry["turn"] = round_num, turn
            events = [self._event("progress", key=key, round=round_num, turn=turn)]
        self._emit(events)

    def job_ended(self, result: JobResult) -> None:
        """A job's result is in the database (`BatchStore.import_result` returned)."""
        turns = None
        for rnd in result.rounds:
            for step in rnd.get("steps", ()):
                sent, received = step.get("turn_sent_at"), step.get("actions_received_at")
                if sent is None or received is None:
                    continue
                if turns is None:
                    entry = self._jobs.get(result.key)
                    domain = entry["domain"] if entry else ""
                    planner = entry["planner"] if entry else ""
                    turns = _Turns(domain, planner)
                turns.add(float(received) - float(sent))
        store = self._store
        records = store.round_records(self.experiment) if store is not None else []
        with self._lock:
            entry = self._jobs.get(result.key)
            if entry is None:
                return
            entry.update(
                status=result.status,
                reason=result.reason,
                round=None,
                turn=None,
                started_at=result.started_at,
                ended_at=result.ended_at,
            )
            if turns is not None:
                self._turns[result.key] = turns
            else:
                self._turns.pop(result.key, None)
            self._sessions[result.key] = _result_session(result)
            _round_stats({result.key: entry}, records)
            events = [self._event("job", job=dict(entry), counts=self._counts())]
        self._emit(events)
        self._rescore(records, "scores")

    def jobs_interrupted(self, keys: Iterable[str], reason: str) -> None:
        """Jobs stopped without a result (Ctrl-C)."""
        events = []
        with self._lock:
            for key in keys:
                entry = self._jobs.get(key)
                if entry is None or entry["status"] in DONE:
                    continue
                entry.update(status="interrupted", reason=reason, ended_at=time.time())
                events.append(self._event("job", job=dict(entry), counts=self._counts()))
        self._emit(events)

    def batch_ended(self, interrupted: bool) -> None:
        """The run is over (every job done, or stopped)."""
        with self._lock:
            self.state = "interrupted" if interrupted else "finished"
            self.ended_at = time.time()
            self._store = None  # closed by the run
            events = [self._event("batch", state=self.state, ended_at=self.ended_at)]
        self._emit(events)

    def page_kept(self, text: str) -> None:
        """The run is over and its page stays up (`text` says until when)."""
        with self._lock:
            self.kept = text
            events = [self._event("batch", state=self.state, kept=text)]
        self._emit(events)

    # ----------------------------------------------------------- reading

    def snapshot(self) -> dict[str, Any]:
        """The whole picture (JSON-able; `seq` is the last event's number)."""
        with self._lock:
            return {
                "type": "snapshot",
                "seq": self._seq,
                "experiment": self.experiment,
                "state": self.state,
                "kept": self.kept,
                "rules": self.rules,
                "started_at": self.started_at,
                "ended_at": self.ended_at,
                "planners": list(self._planners),
                "instances": [{"name": i, "domain": d} for i, d in self._instances.items()],
                "jobs": [dict(e) for e in self._jobs.values()],
                "counts": self._counts(),
                "scores": self._scores,
                "figures": self._figures,
            }

    def planners(self) -> list[str]:
        """The planners' labels, in the grid's order."""
        with self._lock:
            return list(self._planners)

    def job(self, key: str) -> dict[str, Any] | None:
        """One job's entry as the snapshot has it (None: no such job)."""
        with self._lock:
            entry = self._jobs.get(key)
            return None if entry is None else dict(entry)

    def jobs(self) -> list[dict[str, Any]]:
        """Every job's entry, in the experiment's order."""
        with self._lock:
            return [dict(e) for e in self._jobs.values()]

    def scores(self) -> dict[str, Any]:
        """The scores so far (as the snapshot has them)."""
        with self._lock:
            return self._scores

    def session(self, key: str) -> dict[str, Any] | None:
        """The session of a job that is done, as the database has it: ``{"session":
        {...}, "rounds": [{"round", "counted", "reward", "turns", "status", "seconds"}]}``
        (None: not done, or no session: a job that failed before it played)."""
        with self._lock:
            got = self._sessions.get(key)
            return (
                None
                if got is None
                else {"session": dict(got["session"]), "rounds": list(got["rounds"])}
            )

    def _counts(self) -> dict[str, int]:
        counts = dict.fromkeys(STATUSES, 0)
        for e in self._jobs.values():
            counts[e["status"]] = counts.get(e["status"], 0) + 1
        counts["total"] = len(self._jobs)
        return counts

    def _rescore(self, records: list[RoundRecord], why: str) -> None:
        """Scores and figures from `records` (the database's rounds of the experiment)."""
        with self._lock:
            # only the jobs that are over: a running or pending job is not a 0 (the
            # page shows it as running or pending beside the scores)
            expected = [
                (e["planner"], e["instance"], e["domain"])
                for e in self._jobs.values()
                if e["status"] in SCORED
            ]
            not_over = {
                (e["planner"], e["instance"])
                for e in self._jobs.values()
                if e["status"] not in SCORED
            }
            turns = dict(self._turns)
        try:
            table = score(records, self.rules, expected_rounds=self.rounds, expected=expected)
        except ScoreError as err:
            scores: dict[str, Any] = {"error": str(err)}
            per_instance: dict[str, dict[str, float | None]] = {}
        else:
            # `score` gives every planner a score on every instance (0 where it has no
            # round, as FinalEval does at the end): so far, a job not over has none yet
            table.instances = [
                s for s in table.instances if (s.planner, s.instance) not in not_over
            ]
            scores = table.as_json()
            got = {(s.instance, s.planner): s.score for s in table.instances}
            planners = table.planners()
            per_instance = {
                i: {p: got.get((i, p)) for p in planners}
                for i in dict.fromkeys(s.instance for s in table.instances)
            }
        curves = reward_curves(records, self.rules == "ippc2018")
        by: dict[tuple[str, str], list[_Turns]] = {}
        for t in turns.values():
            by.setdefault((t.domain, t.planner), []).append(t)
        per_turn = {}
        for (domain, planner), parts in by.items():
            n, mean, m2 = _merge(parts)
            if n == 0:
                continue
            band = 1.96 * math.sqrt(m2 / (n - 1)) / math.sqrt(n) if n > 1 else None
            per_turn[f"{domain}|{planner}"] = {
                "domain": domain,
                "planner": planner,
                "mean": mean,
                "ci95": band,
                "turns": n,
            }
        figures = {
            "score_per_instance": per_instance,
            "reward_per_round": curves,
            "time_per_turn": per_turn,
        }
        with self._lock:
            self._scores = scores
            self._figures = figures
            events = [self._event("scores", why=why, scores=scores, figures=figures)]
        self._emit(events)


def _empty_figures() -> dict[str, Any]:
    return {"score_per_instance": {}, "reward_per_round": {}, "time_per_turn": {}}


def _round_stats(jobs: dict[str, dict[str, Any]], records: list[RoundRecord]) -> None:
    """Each job's rounds played and mean round reward, from the database's rounds."""
    by: dict[tuple[str, str], list[float]] = {}
    for r in records:
        by.setdefault((r.planner, r.instance), []).append(r.reward)
    for entry in jobs.values():
        rewards = by.get((entry["planner"], entry["instance"]))
        if rewards:
            entry["rounds"] = len(rewards)
            entry["mean"] = sum(rewards) / len(rewards)


def _round_row(rnd: Any) -> dict[str, Any]:
    started, ended = rnd.get("started_at"), rnd.get("ended_at")
    return {
        "round": rnd.get("round_num"),
        "counted": bool(rnd.get("counted", True)),
        "reward": rnd.get("reward"),
        "turns": rnd.get("turns_used"),
        "status": rnd.get("status"),
        "seconds": None if started is None or ended is None else float(ended) - float(started),
    }


def _result_session(result: JobResult) -> dict[str, Any]:
    """What the page keeps of a job's session, from its result."""
    facts = {k: (result.session or {}).get(k) for k in SESSION_FACTS}
    return {"session": facts, "rounds": [_round_row(r) for r in result.rounds]}


def _stored_sessions(store: BatchStore, experiment: str) -> dict[str, dict[str, Any]]:
    """The sessions of the experiment's jobs already in the database (a resumed run)."""
    cols = ", ".join(f"s.{c}" for c in SESSION_FACTS)
    rows = store.raw(
        f"SELECT j.job_key, s.id AS sid, {cols} FROM jobs j JOIN sessions s ON s.id = j.session_id"
        " WHERE j.experiment = ? ORDER BY j.id",
        (experiment,),
    )
    out: dict[str, dict[str, Any]] = {}
    by_sid: dict[int, dict[str, Any]] = {}
    for r in rows:
        entry = {"session": {c: r[c] for c in SESSION_FACTS}, "rounds": []}
        out[r["job_key"]] = entry
        by_sid[int(r["sid"])] = entry
    if by_sid:
        marks = ", ".join("?" * len(by_sid))
        for r in store.raw(
            "SELECT session_id, round_num, counted, started_at, ended_at, status, reward,"
            f" turns_used FROM rounds WHERE session_id IN ({marks}) ORDER BY id",
            tuple(by_sid),
        ):
            by_sid[int(r["session_id"])]["rounds"].append(_round_row(dict(r)))
    return out
