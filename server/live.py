"""The live picture of rddl-server's sessions, for its web view (`server.web`): plain
data and the result store's stand-in, no HTTP.

The sessions already tell the result store everything as it happens (session started,
round started, each step, round ended, session ended). `LiveStore` stands in front of
the store (or of no store, without --db), passes every call on unchanged and notes it in
a `SessionBoard`: the live picture of every session, kept in memory. Noting a step is a
few assignments; nothing is formatted, encoded or sent on the session's path (a turn's
state is formatted when a viewer or a worker's flush asks for it: its true fluents and
those that changed since the turn before).

The board also counts the connections that never became a session it shows: refused
by the listener (the caps, --allow), or closed before a session began (an unknown
instance, no session-request), from the `Notices` of the services it watches
(`watch_notices`), which count every one of them by cause.

Worker processes (`--workers N`): each worker has its own board; its flush sends the
changed records to the main process over a socket of its own (one datagram a session,
never waiting: when the socket is full the records stay marked changed for the next
flush), and the main process merges them into its board. A worker that dies leaves its
sessions marked interrupted, as in the database.
"""

from __future__ import annotations

import json
import logging
import math
import socket
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import trio

from ..web import fmt_number

log = logging.getLogger(__name__)

# seconds between two flushes of the board: a viewer's update costs the
# loop a send to its socket (~0.1-0.4 ms on loopback, measured with 100
# viewers), so twice a second, not at every change
FLUSH_INTERVAL = 0.5
KEEP_SESSIONS = 1000  # sessions the board remembers (the oldest ended ones go first)
KEEP_ROUNDS = 1000  # rounds of a session it remembers (the last ones)
LAST_TURNS = 20  # turns of a session shown on its page
_TEXT = 300  # characters of a turn's actions shown
STATE_TEXT = 2000  # characters of a turn's state (true fluents, changes) shown at most
_DATAGRAM = 60_000  # bytes of one record sent by a worker at most

FAILED = {"dropped", "interrupted"}


def state_of(status: str) -> str:
    """running, finished or failed (the row's colour) for a store status."""
    if status == "running":
        return "running"
    return "failed" if status in FAILED else "finished"


def _value_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return fmt_number(value)
    return str(value)


def _name(name: Any, args: Iterable[Any]) -> str:
    args = tuple(args)
    return f"{name}({', '.join(map(str, args))})" if args else str(name)


def _join(items: Sequence[Any], show: Callable[[Any], str], limit: int) -> str:
    """`show(item)` of the items, joined by spaces; past `limit` characters the rest
    is counted, not formatted (a turn's state can have thousands of fluents)."""
    out: list[str] = []
    size = 0
    for k, item in enumerate(items):
        text = show(item)
        if out and size + len(text) + 1 > limit:
            return " ".join(out) + f" \u2026 and {len(items) - k} more"
        out.append(text)
        size += len(text) + 1
    return " ".join(out)


def _show_fluent(item: Any) -> str:
    try:
        name, args, value = item
    except (TypeError, ValueError):
        return str(item)
    return f"{_name(name, args)}={_value_text(value)}"


def _fluents(items: Iterable[Any], limit: int = _TEXT) -> str:
    """`name(a, b)=value ...`, at most about `limit` characters (the rest counted)."""
    return _join(list(items), _show_fluent, limit)


def _is_true(value: Any) -> bool:
    """What the state column lists: true, a number that is not 0, an enum's value."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int | float):
        return value != 0
    return value is not None


def _triples(state: Any) -> list[Any]:
    # (the sessions' states are lists of (name, args, value) already)
    return state if isinstance(state, list) else list(state or ())


def _show_true(t: tuple[Any, Any, Any]) -> str:
    return _name(t[0], t[1]) if t[2] is True else f"{_name(t[0], t[1])}={_value_text(t[2])}"


def _show_change(change: tuple[Any, Any, Any, Any]) -> str:
    name, args, old, new = change
    return f"{_name(name, args)}: {_value_text(old)} \u2192 {_value_text(new)}"


_ABSENT = object()


def _changes(before: list[tuple[Any, Any, Any]], now: list[tuple[Any, Any, Any]]) -> list[Any]:
    """(name, args, old, new) of what differs; the turns of a round list the same
    fluents in the same order, so they are compared in place (by name otherwise)."""
    if len(before) == len(now):
        out = []
        for (n0, a0, v0), (n, a, v) in zip(before, now, strict=True):
            if n0 != n or a0 != a:
                break
            if v0 != v:
                out.append((n, a, v0, v))
        else:
            return out
    old = {(str(n), tuple(a)): v for n, a, v in before}
    out = [
        (n, a, old.get((str(n), tuple(a)), "(absent)"), v)
        for n, a, v in now
        if old.get((str(n), tuple(a)), _ABSENT) != v
    ]
    seen = {(str(n), tuple(a)) for n, a, _ in now}
    out += [(n, a, v, "(absent)") for (n, a), v in old.items() if (n, a) not in seen]
    return out


def state_texts(state: Any, before: Any | None) -> tuple[str, str]:
    """A turn's state as the session page shows it: its true (or non-zero) fluents, and
    what changed since `before` (the state of the turn before in the same round; None:
    the round's first turn), as ``name(args): old \u2192 new``."""
    now = _triples(state)
    try:
        shown = [t for t in now if t[2] is True or (t[2] is not False and _is_true(t[2]))]
        true = _join(shown, _show_true, STATE_TEXT) or "(none)"
        if before is None:
            return true, "(the round's first turn)"
        changed = _changes(_triples(before), now)
    except (TypeError, ValueError, IndexError):  # not (name, args, value) triples
        return _fluents(now, STATE_TEXT), ""
    return true, _join(changed, _show_change, STATE_TEXT) or "(no change)"


def refusal_kind(cause: str) -> str | None:
    """What the page counts a `Notices` cause as: a connection refused by the
    listener (``address not in --allow``, ``cap of ... reached``), or closed before it
    became a session the page shows (an unknown instance, no session-request); None
    for the rest (a session the page shows already, an accept failure)."""
    what, _, why = cause.partition(": ")
    if what == "connections refused":
        return why or what
    if what == "connections closed before a session-request":
        return f"closed before a session-request: {why}" if why else what
    if what == "sessions closed":
        if why.startswith("unknown instance"):
            return "unknown instance"
        if why.startswith("problem-name"):
            return "not an instance name"
        if why.startswith("instance ") and why.endswith("does not check"):
            return "instance does not check"
        if why.startswith("input-language"):
            return "input-language not served"
    return None


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
    # (round, turn, reward, actions, state): raw until formatted (`turn_texts`); from a
    # worker, (round, turn, reward, actions, true fluents, changes) as text
    last_turns: deque[tuple[Any, ...]] = field(default_factory=lambda: deque(maxlen=LAST_TURNS))
    # the turn that left `last_turns` last (the state the oldest kept one is compared to)
    before: tuple[Any, ...] | None = None
    _texts: dict[tuple[int, int], tuple[Any, ...]] = field(default_factory=dict, repr=False)

    def turn_texts(self) -> list[tuple[Any, ...]]:
        """`last_turns` as (round, turn, reward, actions, true fluents, changes), the texts
        the session page shows (formatted once a turn)."""
        out = []
        prev = self.before
        cache: dict[tuple[int, int], tuple[Any, ...]] = {}
        for t in self.last_turns:
            if len(t) == 6:  # a worker's, as text
                out.append(t)
                prev = None
                continue
            key = (t[0], t[1])
            got = self._texts.get(key)
            if got is None:
                same = (
                    prev is not None and len(prev) == 5 and prev[0] == t[0] and prev[1] == t[1] - 1
                )
                true, changed = state_texts(t[4], prev[4] if same and prev is not None else None)
                actions = t[3] if isinstance(t[3], str) else _fluents(t[3] or ())
                got = (t[0], t[1], t[2], actions, true, changed)
            cache[key] = got
            out.append(got)
            prev = t
        self._texts = cache
        return out

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
            "last_turns": [[a, b, _num(c), d, e, f] for a, b, c, d, e, f in self.turn_texts()],
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
            (int(t[0]), int(t[1]), _float(t[2]), *(str(x) for x in t[3:6]))
            for t in data.get("last_turns", ())
            if len(t) == 6
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
        # connections that never became a session shown here, by kind (`refusal_kind`):
        # this process's, and each worker's as it last sent them
        self.refused: Counter[str] = Counter()
        self._workers_refused: dict[object, dict[str, int]] = {}
        self.refused_version = 0  # moves at every refusal counted
        self._refused_sent: int | None = None  # (a worker: the version it last sent)

    def watch_notices(self, notices: Any) -> None:
        """Count the refusals `notices` (a `server.limits.Notices`) is told of."""
        notices.watchers.append(self._noted)

    def _noted(self, cause: str) -> None:
        kind = refusal_kind(cause)
        if kind is not None:
            self.refused[kind] += 1
            self.refused_version += 1

    def refusals(self) -> dict[str, int]:
        """Connections refused or closed before a session began, by kind (this
        process's and its workers'), most first."""
        total = Counter(self.refused)
        for counts in self._workers_refused.values():
            total.update(counts)
        return dict(total.most_common())

    def merge_refusals(self, source: object, counts: Mapping[str, int]) -> None:
        """A worker's counts (`source` names the worker's channel)."""
        self._workers_refused[source] = {str(k): int(v) for k, v in counts.items()}
        self.refused_version += 1

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
        turns = rec.last_turns
        if len(turns) == LAST_TURNS:
            rec.before = turns[0]  # (what the oldest kept turn's changes are to)
        turns.append((rec.round, turn, reward, actions, state))
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
    process, without waiting (what does not fit now goes next time); its
    refusals' counts as one more when they moved."""
    if board._refused_sent != board.refused_version:
        data = json.dumps({"refused": dict(board.refused)}, separators=(",", ":")).encode()
        try:
            sock.send(data[:_DATAGRAM])
            board._refused_sent = board.refused_version
        except (BlockingIOError, InterruptedError):
            pass  # (next time)
        except OSError:
            return  # the main process is gone
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
            record = json.loads(data)
            if "refused" in record:
                board.merge_refusals(sock, record["refused"])
            else:
                board.merge(record)
        except (ValueError, KeyError, TypeError) as err:
            bad += 1
            if bad == 1:
                log.error("web view: a worker's record could not be read: %s", err)


__all__ = [
    "FAILED",
    "FLUSH_INTERVAL",
    "LAST_TURNS",
    "LiveStore",
    "SessionBoard",
    "SessionRecord",
    "forward_records",
    "receive_records",
    "refusal_kind",
    "send_records",
    "state_of",
    "state_texts",
]
