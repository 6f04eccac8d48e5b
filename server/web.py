"""rddl-server's web view (`rddl-server ... --web PORT`).

Theory of operation. The sessions already tell the result store everything
as it happens (session started, round started, each step, round ended,
session ended). `LiveStore` stands in front of the store (or of no store,
without --db), passes every call on unchanged and notes it in a
`SessionBoard`: the live picture of every session, kept in memory. Noting a
step is a few assignments; nothing is formatted, encoded or sent on the
session's path. A task flushes the board every `FLUSH_INTERVAL` seconds
(the view: every `ServerView.interval()`, longer with many viewers): the
sessions that changed since the last flush become JSON records.

- One process: `ServerView.run` takes the changed records and publishes
  them to the web feed (`ippc.web.Feed`), whose viewers each have a bounded
  queue; a viewer that falls behind is dropped, never waited for.
- Worker processes (`--workers N`): each worker has its own board; its
  flush sends the changed records to the main process over a socket of its
  own (one datagram a session, never waiting: when the socket is full the
  records stay marked changed for the next flush), and the main process
  merges them into its board, which feeds the view as above. A worker that
  dies leaves its sessions marked interrupted, as in the database.

The pages: `/` every session (client, instance, round, turn, rewards so
far, time used of the budget, state and reason, a sparkline of its round
rewards), live; `/session/ID` one session: its facts, the chart of its
round rewards, its rounds and its last turns. Every name is text (see
`ippc.web.html`).
"""

from __future__ import annotations

import json
import logging
import math
import socket
import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import trio

from ..web import (
    JSON,
    SVG,
    EventStream,
    Feed,
    Markup,
    Request,
    Response,
    Routes,
    fields_event,
    fmt_number,
    h,
    line_chart,
    live_table,
    not_found,
    page,
    rows_event,
    sparkline,
    to_json,
)
from ..web import (
    field as page_field,
)

log = logging.getLogger(__name__)

# seconds between two flushes of the board: a viewer's update costs the
# loop a send to its socket (~0.1-0.4 ms on loopback, measured with 100
# viewers), so twice a second, not at every change
FLUSH_INTERVAL = 0.5
# what one update to one viewer costs the loop, rounded up (a send on
# loopback took 0.1-0.4 ms on the loaded 2-core test machine; bench/web.py
# --loop-only; see `ServerView.interval`)
VIEWER_SEND = 0.001
KEEP_SESSIONS = 1000  # sessions the board remembers (the oldest ended ones go first)
KEEP_ROUNDS = 1000  # rounds of a session it remembers (the last ones)
LAST_TURNS = 20  # turns of a session shown on its page
_TEXT = 300  # characters of a turn's actions or state shown
_DATAGRAM = 60_000  # bytes of one record sent by a worker at most

FAILED = {"dropped", "interrupted"}


def state_of(status: str) -> str:
    """running, finished or failed (the row's colour) for a store status."""
    if status == "running":
        return "running"
    return "failed" if status in FAILED else "finished"


def _fluents(items: Iterable[Any]) -> str:
    """`name(a, b)=value ...`, cut to `_TEXT` characters."""
    out: list[str] = []
    size = 0
    for item in items:
        try:
            name, args, value = item
            text = f"{name}({', '.join(map(str, args))})={value}" if args else f"{name}={value}"
        except (TypeError, ValueError):
            text = str(item)
        out.append(text)
        size += len(text) + 1
        if size > _TEXT:
            break
    joined = " ".join(out)
    return joined if len(joined) <= _TEXT else joined[: _TEXT - 1] + "…"


@dataclass
class SessionRecord:
    """What the board knows of one session (JSON-able through `to_json`)."""

    id: int
    client: str = "?"
    instance: str = "?"
    peer: str = ""
    seed: int = 0
    num_rounds: int = 0
    budget: float = 0.0  # seconds
    started_at: float = 0.0
    ended_at: float | None = None
    status: str = "running"
    reason: str | None = None
    round: int = 0  # the round being played (or the last one)
    counted: bool = True  # the round is a counted one (not practice)
    turn: int = 0  # turns of that round so far
    turns_total: int = 0
    round_reward: float = 0.0  # that round's rewards so far (undiscounted sum)
    total_reward: float = 0.0  # the counted rounds that ended (discounted, as recorded)
    rounds_total: int = 0  # rounds ended (practice included)
    # (round, counted, reward, turns, status) of the last KEEP_ROUNDS rounds that ended
    rounds: deque[tuple[int, bool, float, int, str]] = field(
        default_factory=lambda: deque(maxlen=KEEP_ROUNDS)
    )
    # (round, turn, reward, actions, state): raw until formatted by to_json
    last_turns: deque[tuple[int, int, float, Any, Any]] = field(
        default_factory=lambda: deque(maxlen=LAST_TURNS)
    )

    @property
    def round_rewards(self) -> list[float]:
        """The rewards of the counted rounds that were played out (not those
        a failure cut short), in order."""
        return [r[2] for r in self.rounds if r[1] and r[4] not in FAILED]

    def elapsed(self, now: float) -> float:
        end = self.ended_at if self.ended_at is not None else now
        return max(0.0, end - self.started_at)

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "client": self.client,
            "instance": self.instance,
            "peer": self.peer,
            "seed": self.seed,
            "num_rounds": self.num_rounds,
            "budget": self.budget,
            "started_at": self.started_at,
            "ended_at": self.ended_at,
            "status": self.status,
            "reason": self.reason,
            "round": self.round,
            "counted": self.counted,
            "turn": self.turn,
            "turns_total": self.turns_total,
            "round_reward": _num(self.round_reward),
            "total_reward": _num(self.total_reward),
            "rounds_total": self.rounds_total,
            "rounds": [[n, c, _num(r), t, s] for n, c, r, t, s in self.rounds],
            "last_turns": [
                t
                if isinstance(t[3], str)
                else [t[0], t[1], _num(t[2]), _fluents(t[3]), _fluents(t[4])]
                for t in self.last_turns
            ],
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> SessionRecord:
        rec = cls(id=int(data["id"]))
        for name in (
            "client",
            "instance",
            "peer",
            "seed",
            "num_rounds",
            "budget",
            "started_at",
            "ended_at",
            "status",
            "reason",
            "round",
            "counted",
            "turn",
            "turns_total",
            "rounds_total",
        ):
            if name in data:
                setattr(rec, name, data[name])
        rec.round_reward = _float(data.get("round_reward"))
        rec.total_reward = _float(data.get("total_reward"))
        rec.rounds.extend(
            (int(n), bool(c), _float(r), int(t), str(s)) for n, c, r, t, s in data.get("rounds", ())
        )
        rec.last_turns.extend(
            (int(a), int(b), _float(c), str(d), str(e))
            for a, b, c, d, e in data.get("last_turns", ())
        )
        return rec


def _num(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _float(x: Any) -> float:
    return float("nan") if x is None else float(x)


class SessionBoard:
    """The live picture of a server's sessions, kept from the result store's
    calls (`LiveStore`) or from a worker's records (`merge`)."""

    def __init__(self) -> None:
        self.sessions: dict[int, SessionRecord] = {}
        self._dirty: set[int] = set()
        self._removed: set[int] = set()
        self._by_store: dict[int, SessionRecord] = {}  # store's session ids
        self._by_round: dict[int, SessionRecord] = {}  # store's round ids
        self.turns = 0  # turns played in all sessions (this board's)
        self.changes = 0  # flushes that had something (for tests)

    def wrap(self, store: Any) -> LiveStore:
        """The store the sessions are given (`store` may be None)."""
        return LiveStore(store, self)

    # -- from the sessions (through LiveStore)

    def session_started(self, key: int, **kw: Any) -> None:
        rec = SessionRecord(
            id=int(kw.get("server_session_id", key)),
            client=str(kw.get("client_name", "?")),
            instance=str(kw.get("instance", "?")),
            peer=str(kw.get("peer", "")),
            seed=int(kw.get("seed", 0)),
            num_rounds=int(kw.get("num_rounds", 0)),
            budget=float(kw.get("time_allowed_ms", 0.0)) / 1000.0,
            started_at=float(kw.get("started_at", time.time())),
        )
        self._by_store[key] = rec
        self._add(rec)

    def _add(self, rec: SessionRecord) -> None:
        self.sessions[rec.id] = rec
        self._dirty.add(rec.id)
        self._removed.discard(rec.id)
        if len(self.sessions) > KEEP_SESSIONS:
            ended = [s for s in self.sessions.values() if s.status != "running"]
            ended.sort(key=lambda s: s.ended_at or 0.0)
            for old in ended[: len(self.sessions) - KEEP_SESSIONS]:
                del self.sessions[old.id]
                self._dirty.discard(old.id)
                self._removed.add(old.id)

    def round_started(
        self, session_key: int, round_key: int, round_num: int, counted: bool
    ) -> None:
        rec = self._by_store.get(session_key)
        if rec is None:
            return
        self._by_round[round_key] = rec
        rec.round = round_num
        rec.counted = counted
        rec.turn = 0
        rec.round_reward = 0.0
        self._dirty.add(rec.id)

    def step(self, round_key: int, turn: int, reward: float, actions: Any, state: Any) -> None:
        rec = self._by_round.get(round_key)
        if rec is None:
            return
        rec.turn = turn
        rec.turns_total += 1
        rec.round_reward += reward
        rec.last_turns.append((rec.round, turn, reward, actions, state))
        self.turns += 1
        self._dirty.add(rec.id)

    def round_ended(self, round_key: int, reward: float, turns: int, status: str) -> None:
        rec = self._by_round.pop(round_key, None)
        if rec is None:
            return
        rec.turn = turns
        rec.rounds_total += 1
        rec.rounds.append((rec.round, rec.counted, reward, turns, status))
        if rec.counted:
            rec.total_reward += reward
        self._dirty.add(rec.id)

    def session_ended(
        self, session_key: int, total: float, status: str, reason: str | None, ended_at: float
    ) -> None:
        rec = self._by_store.pop(session_key, None)
        if rec is None:
            return
        for k in [k for k, r in self._by_round.items() if r is rec]:
            del self._by_round[k]
        rec.total_reward = total
        rec.status = status
        rec.reason = reason
        rec.ended_at = ended_at
        self._dirty.add(rec.id)

    def interrupt_running(
        self, reason: str, ended_at: float, ids: Iterable[int] | None = None
    ) -> int:
        """Mark running sessions (all, or those of `ids`) interrupted."""
        wanted = None if ids is None else set(ids)
        n = 0
        for rec in self.sessions.values():
            if rec.status == "running" and (wanted is None or rec.id in wanted):
                rec.status = "interrupted"
                rec.reason = reason
                rec.ended_at = ended_at
                self._dirty.add(rec.id)
                n += 1
        if wanted is None:
            self._by_store.clear()
            self._by_round.clear()
        return n

    # -- flushing

    def flush(self) -> tuple[list[SessionRecord], list[int]]:
        """The sessions changed since the last flush, and those forgotten."""
        changed = [self.sessions[i] for i in sorted(self._dirty) if i in self.sessions]
        removed = sorted(self._removed)
        self._dirty.clear()
        self._removed.clear()
        if changed or removed:
            self.changes += 1
        return changed, removed

    def mark(self, ids: Iterable[int]) -> None:
        """Flush these again next time (they could not be sent)."""
        self._dirty.update(i for i in ids if i in self.sessions)

    def merge(self, data: dict[str, Any]) -> None:
        """A record from a worker process."""
        rec = SessionRecord.from_json(data)
        old = self.sessions.get(rec.id)
        if old is not None:
            self.turns += max(0, rec.turns_total - old.turns_total)
        else:
            self.turns += rec.turns_total
        self._add(rec)


class LiveStore:
    """The result store as the sessions see it when the web view is on:
    every call goes to the real store (if any) unchanged, and is noted in
    the board. Ids are the real store's, or counted here without one."""

    def __init__(self, store: Any, board: SessionBoard):
        self.store = store
        self.board = board
        self._next = 0

    def _id(self, real: Any) -> int:
        if real is not None:
            return int(real)
        self._next += 1
        return self._next

    def start_session(self, **kw: Any) -> int:
        key = self._id(self.store.start_session(**kw) if self.store is not None else None)
        self.board.session_started(key, **kw)
        return key

    def start_round(self, session: int, *, round_num: int, counted: bool, started_at: float) -> int:
        real = (
            self.store.start_round(
                session, round_num=round_num, counted=counted, started_at=started_at
            )
            if self.store is not None
            else None
        )
        key = self._id(real)
        self.board.round_started(session, key, round_num, counted)
        return key

    def record_step(self, round_: int, **kw: Any) -> None:
        if self.store is not None:
            self.store.record_step(round_, **kw)
        self.board.step(
            round_, kw["turn_num"], float(kw["reward"]), kw.get("actions"), kw.get("state")
        )

    def end_round(
        self, round_: int, *, reward: float, turns_used: int, status: str, ended_at: float
    ) -> None:
        if self.store is not None:
            self.store.end_round(
                round_, reward=reward, turns_used=turns_used, status=status, ended_at=ended_at
            )
        self.board.round_ended(round_, float(reward), turns_used, status)

    def end_session(
        self,
        session: int,
        *,
        total_reward: float,
        rounds_used: int,
        status: str,
        reason: str | None,
        ended_at: float,
    ) -> None:
        if self.store is not None:
            self.store.end_session(
                session,
                total_reward=total_reward,
                rounds_used=rounds_used,
                status=status,
                reason=reason,
                ended_at=ended_at,
            )
        self.board.session_ended(session, float(total_reward), status, reason, ended_at)

    def interrupt_open(self, reason: str, ended_at: float, *, every_owner: bool = False) -> int:
        n = self.board.interrupt_running(reason, ended_at)
        if self.store is not None:
            return int(self.store.interrupt_open(reason, ended_at, every_owner=every_owner))
        return n

    def close(self) -> None:
        if self.store is not None:
            self.store.close()

    def __getattr__(self, name: str) -> Any:
        # what else a store offers (queries), from the real one
        if name == "store":
            raise AttributeError(name)
        if self.store is None:
            raise AttributeError(f"no result store (--db) for {name!r}")
        return getattr(self.store, name)


# ------------------------------------------------------------- worker processes


def send_records(sock: socket.socket, board: SessionBoard) -> None:
    """A worker's flush: each changed session as one datagram to the main
    process, without waiting (what does not fit now goes next time)."""
    changed, _ = board.flush()
    for k, rec in enumerate(changed):
        data = json.dumps(rec.to_json(), separators=(",", ":")).encode()
        if len(data) > _DATAGRAM:  # a session with very many long rounds: its last ones
            payload = rec.to_json()
            while len(data) > _DATAGRAM and payload["rounds"]:
                payload["rounds"] = payload["rounds"][len(payload["rounds"]) // 2 :]
                data = json.dumps(payload, separators=(",", ":")).encode()
        try:
            sock.send(data)
        except (BlockingIOError, InterruptedError):
            board.mark(r.id for r in changed[k:])
            return
        except OSError:
            return  # the main process is gone


async def forward_records(sock: socket.socket, board: SessionBoard) -> None:
    """A worker's task: flush the board to the main process until cancelled
    (a last flush on the way out)."""
    sock.setblocking(False)
    try:
        while True:
            await trio.sleep(FLUSH_INTERVAL)
            send_records(sock, board)
    finally:
        send_records(sock, board)


async def receive_records(sock: socket.socket, board: SessionBoard) -> None:
    """The main process's task for one worker: merge its records until its
    socket closes."""
    sock.setblocking(False)
    bad = 0
    while True:
        try:
            data = sock.recv(_DATAGRAM + 1024)
        except (BlockingIOError, InterruptedError):
            await trio.lowlevel.wait_readable(sock)
            continue
        except OSError:
            return
        if not data:
            return
        try:
            board.merge(json.loads(data))
        except (ValueError, KeyError, TypeError) as err:
            bad += 1
            if bad == 1:
                log.error("web view: a worker's record could not be read: %s", err)


# ------------------------------------------------------------- the pages


class ServerView:
    """rddl-server's pages over a board; `run` publishes its changes."""

    def __init__(self, board: SessionBoard, feed: Feed | None = None):
        self.board = board
        self.feed = feed or Feed()
        self.routes = Routes()
        self._published_turns: dict[int, int] = {}  # session id -> turns_total sent
        self._published_rounds: dict[int, int] = {}  # session id -> rounds_total sent
        self.routes.add("/", self.index)
        self.routes.add("/events", self.events)
        self.routes.add("/session/{id}", self.session_page)
        self.routes.add("/session/{id}/events", self.session_events)
        self.routes.add("/chart/session/{id}.svg", self.spark_svg)
        self.routes.add("/chart/session/{id}/rewards.svg", self.rewards_svg)
        self.routes.add("/sessions.json", self.sessions_json)

    # -- publishing

    async def run(self) -> None:
        """Publish the board's changes until cancelled (the running
        sessions' clocks at least every second), every `interval()` seconds."""
        last_clock = trio.current_time()
        while True:
            await trio.sleep(self.interval())
            now = trio.current_time()
            clock = now - last_clock >= 0.99
            if clock:
                last_clock = now
            self.publish(clock=clock)

    def interval(self) -> float:
        """Seconds between two updates: FLUSH_INTERVAL, longer with many
        viewers, so that their sends take about a tenth of the loop at most
        (VIEWER_SEND seconds each) whatever their number: 0.5 s up to 50
        viewers, 1 s with 100."""
        return max(FLUSH_INTERVAL, 10 * VIEWER_SEND * self.feed.viewers)

    def publish(self, clock: bool = False) -> None:
        changed, removed = self.board.flush()
        now = time.time()
        feed = self.feed
        if clock:
            ids = {r.id for r in changed}
            changed += [
                r for r in self.board.sessions.values() if r.status == "running" and r.id not in ids
            ]
        if feed.watched("sessions") and (changed or removed):
            rows = [("sessions", r.id, self.cells(r, now)) for r in changed]
            event = rows_event(rows)
            event["rows"] += [{"table": "sessions", "key": str(i), "remove": True} for i in removed]
            feed.publish(event, "sessions")
            feed.publish(fields_event(self.totals()), "sessions")
        for rec in changed:
            topic = f"session:{rec.id}"
            if not feed.watched(topic):
                self._published_turns.pop(rec.id, None)
                self._published_rounds.pop(rec.id, None)
                continue
            feed.publish(fields_event(self.facts(rec, now)), topic)
            new = list(self._new_rows(rec))
            if new:
                feed.publish(rows_event(new), topic)
        for i in removed:
            self._published_turns.pop(i, None)
            self._published_rounds.pop(i, None)

    def _new_rows(self, rec: SessionRecord) -> Iterator[tuple[str, str, dict[str, Any]]]:
        """The rounds and turns of `rec` not published yet (and the round in play)."""
        sent_rounds = self._published_rounds.get(rec.id, 0)
        new_rounds = min(rec.rounds_total - sent_rounds, len(rec.rounds))
        if new_rounds > 0:
            yield from self.round_rows(rec, list(rec.rounds)[-new_rounds:])
        self._published_rounds[rec.id] = rec.rounds_total
        sent_turns = self._published_turns.get(rec.id, 0)
        new_turns = min(rec.turns_total - sent_turns, len(rec.last_turns))
        if new_turns > 0:
            yield from self.turn_rows(list(rec.last_turns)[-new_turns:])
        self._published_turns[rec.id] = rec.turns_total

    # -- what the pages show

    def totals(self) -> dict[str, Any]:
        states = [state_of(r.status) for r in self.board.sessions.values()]
        return {
            "running": states.count("running"),
            "finished": states.count("finished"),
            "failed": states.count("failed"),
            "turns": self.board.turns,
        }

    @staticmethod
    def cells(rec: SessionRecord, now: float) -> dict[str, Any]:
        rewards = rec.round_rewards
        last = rewards[-1] if rewards else None
        running = rec.status == "running"
        return {
            "id": rec.id,
            "client": rec.client,
            "instance": rec.instance,
            "round": f"{rec.round} / {rec.num_rounds}" + ("" if rec.counted else " (practice)"),
            "turn": rec.turn,
            "turns": rec.turns_total,
            "reward": fmt_number(rec.total_reward + (rec.round_reward if running else 0.0)),
            "last": fmt_number(last),
            "time": _time_used(rec, now),
            "state": state_of(rec.status),
            "status": rec.status + (f": {rec.reason}" if rec.reason else ""),
            "rounds": rec.rounds_total,
        }

    def facts(self, rec: SessionRecord, now: float) -> dict[str, Any]:
        cells = self.cells(rec, now)
        cells.update(
            peer=rec.peer,
            seed=rec.seed,
            round_reward=fmt_number(rec.round_reward),
            total=fmt_number(rec.total_reward),
            started=time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(rec.started_at)),
        )
        return cells

    @staticmethod
    def round_rows(
        rec: SessionRecord, rounds: Iterable[tuple[int, bool, float, int, str]]
    ) -> Iterator[tuple[str, str, dict[str, Any]]]:
        for n, counted, reward, turns, status in rounds:
            key = f"{n}" if counted else f"p{n}"
            yield (
                "rounds",
                key,
                {
                    "round": n if counted else f"{n} (practice)",
                    "reward": fmt_number(reward),
                    "turns": turns,
                    "status": status,
                    "state": "failed" if status in FAILED else "finished",
                },
            )

    @staticmethod
    def turn_rows(
        turns: Iterable[tuple[int, int, float, Any, Any]],
    ) -> Iterator[tuple[str, str, dict[str, Any]]]:
        for rnd, turn, reward, actions, state in turns:
            yield (
                "turns",
                f"{rnd}.{turn}",
                {
                    "round": rnd,
                    "turn": turn,
                    "reward": fmt_number(reward),
                    "actions": actions if isinstance(actions, str) else _fluents(actions or ()),
                    "state": state if isinstance(state, str) else _fluents(state or ()),
                },
            )

    # -- routes

    NAV = {"sessions": "/"}
    COLUMNS = (
        ("id", "session"),
        ("client", "client"),
        ("instance", "instance"),
        ("round", "round"),
        ("turn", "turn"),
        ("reward", "reward so far"),
        ("last", "last round"),
        ("chart", "round rewards"),
        ("time", "time used"),
        ("status", "state"),
    )

    def _session(self, request: Request) -> SessionRecord:
        try:
            rec = self.board.sessions.get(int(request.params["id"]))
        except ValueError:
            rec = None
        if rec is None:
            raise not_found(f"session {request.params['id']}")
        return rec

    def index(self, request: Request) -> Response:
        now = time.time()
        recs = sorted(self.board.sessions.values(), key=lambda r: r.id)
        totals = self.totals()
        body = [
            h(
                "p",
                page_field("running", totals["running"]),
                " running, ",
                page_field("finished", totals["finished"]),
                " finished, ",
                page_field("failed", totals["failed"]),
                " failed; ",
                page_field("turns", totals["turns"]),
                " turns played.",
            ),
            self._sessions_table(recs, now),
            h(
                "p",
                "Rewards are a session's counted rounds so far; the round in play adds its rewards as they come.",
                class_="muted",
            ),
        ]
        return Response(page("rddl-server: sessions", *body, events="/events", nav=self.NAV))

    def _sessions_table(self, recs: list[SessionRecord], now: float) -> Markup:
        return live_table(
            "sessions",
            self.COLUMNS,
            [(str(r.id), self.cells(r, now)) for r in recs],
            links={"id": "/session/{key}"},
            charts={"chart": ("/chart/session/{key}.svg", "rounds")},
            newest_first=True,
        )

    def events(self, request: Request) -> EventStream:
        def snapshot() -> list[dict[str, Any]]:
            now = time.time()
            rows = [("sessions", r.id, self.cells(r, now)) for r in self.board.sessions.values()]
            rows.sort(key=lambda row: int(row[1]))
            return [rows_event(rows, reset=True), fields_event(self.totals())]

        return EventStream(self.feed, ["sessions"], snapshot)

    def session_page(self, request: Request) -> Response:
        rec = self._session(request)
        now = time.time()
        facts = self.facts(rec, now)
        labels = (
            ("client", "client"),
            ("instance", "instance"),
            ("peer", "peer"),
            ("seed", "seed"),
            ("status", "state"),
            ("round", "round"),
            ("turn", "turn"),
            ("turns", "turns played"),
            ("round_reward", "this round so far"),
            ("total", "counted rounds' reward"),
            ("time", "time used"),
            ("started", "started"),
        )
        dl = h(
            "dl",
            [(h("dt", label), h("dd", page_field(name, facts[name]))) for name, label in labels],
            class_="facts",
        )
        chart = h(
            "img",
            src=f"/chart/session/{rec.id}/rewards.svg?v={rec.rounds_total}",
            alt="round rewards",
            data_page_chart=f"/chart/session/{rec.id}/rewards.svg",
            data_version="rounds",
            data_v=rec.rounds_total,
        )
        rounds = live_table(
            "rounds",
            (("round", "round"), ("reward", "reward"), ("turns", "turns"), ("status", "status")),
            [(k, c) for _, k, c in self.round_rows(rec, rec.rounds)],
            newest_first=True,
        )
        turns = live_table(
            "turns",
            (
                ("round", "round"),
                ("turn", "turn"),
                ("reward", "reward"),
                ("actions", "actions"),
                ("state", "state sent"),
            ),
            [(k, c) for _, k, c in self.turn_rows(rec.last_turns)],
            limit=LAST_TURNS,
            newest_first=True,
            state_field=None,
        )
        title = f"session {rec.id}: {rec.client} on {rec.instance}"
        body = [
            dl,
            h("h2", "Round rewards"),
            chart,
            h("h2", "Rounds"),
            rounds,
            h("h2", f"Last {LAST_TURNS} turns"),
            turns,
        ]
        return Response(page(title, *body, events=f"/session/{rec.id}/events", nav=self.NAV))

    def session_events(self, request: Request) -> EventStream:
        rec = self._session(request)

        def snapshot() -> list[dict[str, Any]]:
            now = time.time()
            rows = list(self.round_rows(rec, rec.rounds)) + list(self.turn_rows(rec.last_turns))
            if rec.id not in self._published_turns:
                # the first viewer: `publish` goes on from here (for a later
                # one it goes on from the last publish: rows its snapshot has
                # already come again, and replace themselves)
                self._published_rounds[rec.id] = rec.rounds_total
                self._published_turns[rec.id] = rec.turns_total
            return [rows_event(rows, reset=True), fields_event(self.facts(rec, now))]

        return EventStream(self.feed, [f"session:{rec.id}"], snapshot)

    def spark_svg(self, request: Request) -> Response:
        rec = self._session(request)
        svg = sparkline(rec.round_rewards, label=f"session {rec.id}: round rewards")
        return Response(svg, content_type=SVG)

    def rewards_svg(self, request: Request) -> Response:
        rec = self._session(request)
        first = next((r[0] for r in rec.rounds if r[1] and r[4] not in FAILED), 1)
        svg = line_chart(
            {f"{rec.client} on {rec.instance}": rec.round_rewards},
            title=f"session {rec.id}: reward per round",
            x_start=first,
        )
        return Response(svg, content_type=SVG)

    def sessions_json(self, request: Request) -> Response:
        data = [r.to_json() for r in sorted(self.board.sessions.values(), key=lambda r: r.id)]
        return Response(to_json(data), content_type=JSON)


def _time_used(rec: SessionRecord, now: float) -> str:
    used = rec.elapsed(now)
    if rec.budget > 0:
        return f"{used:.1f} s of {rec.budget:g} s ({100 * used / rec.budget:.0f} %)"
    return f"{used:.1f} s"


__all__ = [
    "FLUSH_INTERVAL",
    "LiveStore",
    "ServerView",
    "SessionBoard",
    "SessionRecord",
    "forward_records",
    "receive_records",
    "send_records",
    "state_of",
]
