"""The live picture of a dispatcher, for its web page (`dispatch.web`): plain data, no HTTP.

`DispatchLive` listens to what already tells: the knowledge base's subscriptions (every
batch that changed facts, with who made it: ``sensing``, ``dispatcher``, a client; and
every goal change), the dispatcher's watchers (sessions, rounds, turns sent, each turn's
record with its reward) and the handlers' watchers (each action's start and end). It
keeps:

* the knowledge base's state fluents: every grounding that is not false, and every one
  that changed since the start, each with the turn, time and source of its last change
  (a fact is marked *changed* while its change is at most one turn old: it changed since
  the planner was sent the state before the last one);
* the goal and whether it holds;
* the session (its state, round and turn, whether the planner is thinking);
* the actions running now with their handler's state, and the last ones that ended;
* sensing's counts (messages, batches, values refused per stream, the last errors);
* failures (actions that did not succeed, refused effects, contradictions), replans and
  the rewards so far (total and per turn, the last `KEPT` turns).

`snapshot()` is the whole picture as a JSON-able dict; `subscribe(callback)` hears every
change as a small JSON-able event (``{"type": "facts" | "goal" | "session" |
"turn-sent" | "turn" | "action" | "sensing" | "note", ...}``). The knowledge base may be
written from other threads (a robot's driver threads): every method takes one lock and
callbacks run after it is released, in the thread of the change. `tick()` (the web page
calls it every second) tells sensing's counts when they moved.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from ..kb import KnowledgeBase
from ..kb.store import Change
from ..web.pages import Listeners
from .actions import Handlers
from .dispatcher import Dispatcher

__all__ = ["DispatchLive", "EventCallback"]

log = logging.getLogger(__name__)

EventCallback = Callable[[dict[str, Any]], None]

#: Turns, ended actions and notes kept for the page (the result store has every one).
KEPT = 500
#: Sensing errors shown.
ERRORS_SHOWN = 10


def _fact_key(fluent: str, args: tuple[str, ...] | list[str]) -> str:
    return f"{fluent}({','.join(args)})"


def _plain(value: Any) -> Any:
    """A knowledge-base value as JSON takes it (numpy scalars and the like as text)."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return str(value)


class DispatchLive:
    """What a dispatcher is doing, as data (see the module doc)."""

    def __init__(self, dispatcher: Dispatcher, *, clock: Callable[[], float] = time.time) -> None:
        self.d = dispatcher
        self.kb: KnowledgeBase = dispatcher.kb
        self._now = clock
        self._lock = threading.Lock()
        self._listeners = Listeners("dispatch live view")
        self._seq = 0
        self.started_at = clock()
        self._sent = 0  # turns sent to the planner: the facts' change epochs
        self._facts: dict[str, dict[str, Any]] = {}
        for (fluent, args), value in self.kb.facts().items():
            if value is not False:
                self._facts[_fact_key(fluent, args)] = self._fact(fluent, args, value, None)
        self._session: dict[str, Any] = {
            "state": "waiting",
            "sessions": 0,
            "seed": None,
            "round": 0,
            "turn": None,
            "thinking": False,
        }
        self._running: dict[int, dict[str, Any]] = {}
        # every row the actions table ever had, counted: ("action" | "noop", status)
        self._counts: Counter[tuple[str, str]] = Counter()
        self._order = 0  # the rows' order (a dispatch's id, or a refused action's turn)
        self._reached: dict[str, Any] = {"turn": None, "version": None}
        self._ended: deque[dict[str, Any]] = deque(maxlen=KEPT)
        self._turns: deque[dict[str, Any]] = deque(maxlen=KEPT)
        self._notes: deque[dict[str, Any]] = deque(maxlen=KEPT)
        self._sensing_seen: dict[str, Any] | None = None
        self._seen_replans = dispatcher.stats.replans
        self._notes_made = 0
        self._goal = self._goal_now()
        self._stops = [
            self.kb.subscribe(self._on_facts),
            self.kb.subscribe_goal(self._on_goal),
            dispatcher.watch(self._on_dispatcher),
            dispatcher.handlers.watch(self._on_action),
        ]

    def close(self) -> None:
        """Stop listening."""
        for stop in self._stops:
            stop()
        self._stops = []

    # ----------------------------------------------------------- listening

    def subscribe(self, callback: EventCallback) -> Callable[[], None]:
        """Call `callback(event)` for every change; returns the function that stops it."""
        return self._listeners.subscribe(callback)

    def _emit(self, events: list[dict[str, Any]]) -> None:
        self._listeners.emit(events)

    def _event(self, kind: str, **data: Any) -> dict[str, Any]:
        """Under the lock: the next event."""
        self._seq += 1
        return {"type": kind, "seq": self._seq, "time": self._now(), **data}

    def _note(self, kind: str, text: str, **data: Any) -> dict[str, Any]:
        """Under the lock: a note (a failure, a replan, a contradiction) kept and told."""
        self._notes_made += 1
        note = {"id": self._notes_made, "kind": kind, "text": text, "time": self._now(), **data}
        self._notes.append(note)
        return self._event("note", note=note)

    # ----------------------------------------------------------- the hooks

    def _fact(
        self, fluent: str, args: tuple[str, ...] | list[str], value: Any, source: str | None
    ) -> dict[str, Any]:
        return {
            "key": _fact_key(fluent, args),
            "fluent": fluent,
            "args": list(args),
            "value": _plain(value),
            "source": source,
            "changed_at": None if source is None else self._now(),
            "epoch": None if source is None else self._sent,
        }

    def _on_facts(self, changes: list[Change], source: str) -> None:
        facts = []
        with self._lock:
            for ch in changes:
                if not self.kb.is_state_fluent(ch.fluent):
                    continue  # a non-fluent (distances written at start-up)
                fact = self._fact(ch.fluent, tuple(ch.args), ch.new, source)
                fact["old"] = _plain(ch.old)
                self._facts[fact["key"]] = fact
                facts.append(fact)
            events = [self._event("facts", source=source, facts=facts, epoch=self._sent)]
        if facts:
            self._emit(events)
        holds = self._goal_now()["holds"]
        if holds != self._goal["holds"]:
            with self._lock:
                self._goal["holds"] = holds
                events = [self._event("goal", goal=self._goal_view())]
            self._emit(events)

    def _goal_now(self) -> dict[str, Any]:
        try:
            goal = self.kb.goal()
            holds = self.kb.goal_holds()
        except Exception as err:  # noqa: BLE001 - a goal that cannot be decided is shown so
            return {"facts": [], "holds": None, "version": None, "error": str(err)}
        if goal is None:
            return {"facts": [], "holds": holds, "version": None}
        return {
            "facts": [str(f) for f in goal.facts],
            "holds": holds,
            "version": goal.version,
        }

    def _on_goal(self, goal: Any, source: str) -> None:
        now = self._goal_now()
        with self._lock:
            if now.get("version") != self._goal.get("version"):
                self._reached = {"turn": None, "version": None}  # a new goal
            self._goal = now
            events = [self._event("goal", goal=self._goal_view(), source=source)]
        self._emit(events)

    def _goal_view(self) -> dict[str, Any]:
        """Under the lock: the goal, whether it holds now, and the turn after which it
        first held (the run's outcome: `DispatchStats.goal_reached`)."""
        return {**self._goal, "reached_turn": self._reached["turn"]}

    def _on_dispatcher(self, kind: str, data: dict[str, Any]) -> None:
        stats = self.d.stats
        with self._lock:
            s = self._session
            events = []
            if kind == "session-opened":
                s.update(state="open", seed=data.get("seed"), round=0, turn=None, thinking=False)
                s["sessions"] += 1
                events.append(self._event("session", session=dict(s)))
            elif kind == "session-closed":
                s.update(state="closed", thinking=False)
                events.append(self._event("session", session=dict(s)))
                for running in list(self._running.values()):
                    ended = {**running, "status": "interrupted", "message": "the session closed"}
                    self._ended.append(ended)
                    self._counts[(ended["kind"], "interrupted")] += 1
                    events.append(self._event("action", action=ended, counts=self._count_view()))
                self._running.clear()
            elif kind == "round":
                s.update(round=data["round"])
                events.append(self._event("session", session=dict(s)))
            elif kind == "turn-sent":
                self._sent += 1
                s.update(turn=data["turn"], round=data["round"], thinking=True)
                events.append(self._event("turn-sent", session=dict(s), epoch=self._sent))
            elif kind == "turn":
                s.update(thinking=False)
                failed = [a for a in data.get("actions", []) if a.get("outcome") != "succeeded"]
                turn = {
                    "round": data.get("round"),
                    "turn": data.get("turn"),
                    "reward": float(data.get("reward", 0.0)),
                    "actions": [
                        {k: _plain(v) for k, v in a.items()} for a in data.get("actions", [])
                    ],
                    "goal": data.get("goal"),
                }
                self._turns.append(turn)
                for k, a in enumerate(data.get("actions", [])):
                    if a.get("outcome") != "precondition-false":
                        continue
                    # never dispatched (no handler saw it): a row of the table all the same
                    self._order += 1
                    entry = {
                        "id": f"{turn['turn']}.{k}",
                        "order": self._order,
                        "kind": "action",
                        "turn": turn["turn"],
                        "action": a.get("action"),
                        "status": "precondition-false",
                        "message": a.get("message") or "",
                        "duration": 0.0,
                        "started_at": None,
                        "ended_at": self._now(),
                    }
                    self._ended.append(entry)
                    self._counts[("action", "precondition-false")] += 1
                    events.append(self._event("action", action=entry, counts=self._count_view()))
                if data.get("goal") and self._reached["turn"] is None:
                    self._reached = {"turn": turn["turn"], "version": self._goal.get("version")}
                    events.append(self._event("goal", goal=self._goal_view()))
                for a in failed:
                    text = f"turn {turn['turn']}: {a.get('action')} {a.get('outcome')}"
                    if a.get("message"):
                        text += f": {a['message']}"
                    events.append(self._note("failure", text, turn=turn["turn"]))
                if data.get("effects_refused"):
                    text = f"turn {turn['turn']}: effects refused: {data['effects_refused']}"
                    events.append(self._note("refused", text, turn=turn["turn"]))
                for c in data.get("contradictions", ()):
                    text = (
                        f"turn {turn['turn']}: sensing contradicts the model: "
                        f"{_fact_key(c['fluent'], c['args'])} expected {c['expected']}, "
                        f"sensed {c['sensed']}"
                    )
                    events.append(self._note("contradiction", text, turn=turn["turn"]))
                if stats.replans > self._seen_replans:
                    text = f"turn {turn['turn']}: replanned after an action that did not succeed"
                    events.append(self._note("replan", text, turn=turn["turn"]))
                self._seen_replans = stats.replans
                events.append(self._event("turn", turn=turn, stats=self._stats(), session=dict(s)))
        self._emit(events)

    def _on_action(self, kind: str, data: dict[str, Any]) -> None:
        # a noop dispatched on a turn where no action ran (the dispatcher's, not the planner's)
        what = "noop" if data.get("action") == f"{Handlers.NOOP}()" else "action"
        with self._lock:
            if kind == "action-started":
                self._order += 1
                entry = {
                    **data,
                    "order": self._order,
                    "kind": what,
                    "status": "running",
                    "started_at": self._now(),
                }
                self._running[data["id"]] = entry
            else:
                start = self._running.pop(data["id"], None)
                if start is None:
                    self._order += 1
                entry = {
                    **data,
                    "order": start["order"] if start else self._order,
                    "kind": what,
                    "started_at": start["started_at"] if start else None,
                    "ended_at": self._now(),
                    "timeout": start.get("timeout") if start else None,
                }
                self._ended.append(entry)
                self._counts[(what, str(data.get("status")))] += 1
            events = [self._event("action", action=dict(entry), counts=self._count_view())]
        self._emit(events)

    def _count_view(self) -> dict[str, Any]:
        """Under the lock: the actions table's rows, counted (every row it ever had)."""
        ended = {k: v for k, v in self._counts.items() if k[0] == "action"}
        running = sum(1 for a in self._running.values() if a["kind"] == "action")
        return {
            # the planner's actions: dispatched or refused (`DispatchStats.executed_total`
            # once their turn is over)
            "actions": sum(ended.values()) + running,
            "running": running,
            "succeeded": ended.get(("action", "succeeded"), 0),
            # of them, those that ended otherwise (`DispatchStats.failed_actions`)
            "not_succeeded": sum(n for (_, st), n in ended.items() if st != "succeeded"),
            "by_status": {st: n for (_, st), n in sorted(ended.items())},
            "noop": sum(n for (k, _), n in self._counts.items() if k == "noop")
            + sum(1 for a in self._running.values() if a["kind"] == "noop"),
            "noop_not_succeeded": sum(
                n for (k, st), n in self._counts.items() if k == "noop" and st != "succeeded"
            ),
        }

    def tick(self) -> None:
        """Tell sensing's counts when they moved since the last tick."""
        counts = self._sensing()
        with self._lock:
            if counts == self._sensing_seen:
                return
            self._sensing_seen = counts
            events = [self._event("sensing", sensing=counts)]
        self._emit(events)

    def running(self) -> list[dict[str, Any]]:
        """The actions running now (as the snapshot lists them)."""
        with self._lock:
            return [dict(a) for a in self._running.values()]

    def _sensing(self) -> dict[str, Any] | None:
        sensing = self.d.sensing
        if sensing is None:
            return None
        return {
            "messages": sensing.messages,
            "batches": sensing.batches,
            "refused": dict(sensing.refused),
            "errors": list(sensing.errors)[-ERRORS_SHOWN:],
            "streams": sorted(sensing.streams()),
        }

    def _stats(self) -> dict[str, Any]:
        st = self.d.stats
        return {
            "turns": st.turns,
            "rounds": st.rounds,
            "reward": st.reward,
            "replans": st.replans,
            "failed_actions": st.failed_actions,
            "executed": st.executed_total,
            "contradictions": st.contradictions,
            "goal_reached": st.goal_reached,
            "planning_seconds": st.planning_seconds,
            "execution_seconds": st.execution_seconds,
        }

    # ----------------------------------------------------------- reading

    def snapshot(self) -> dict[str, Any]:
        """The whole picture (JSON-able; `seq` is the last event's number)."""
        sensing = self._sensing()
        with self._lock:
            facts = sorted(self._facts.values(), key=lambda f: (f["fluent"], f["args"]))
            return {
                "type": "snapshot",
                "seq": self._seq,
                "time": self._now(),
                "instance": self.d.name,
                "domain": self.d.model.domain_name,
                "started_at": self.started_at,
                "epoch": self._sent,
                "facts": [
                    {
                        **f,
                        "changed": f["epoch"] is not None and f["epoch"] >= self._sent - 1,
                    }
                    for f in facts
                ],
                "goal": self._goal_view(),
                "counts": self._count_view(),
                "session": dict(self._session),
                "running": [dict(a) for a in self._running.values()],
                "ended": [dict(a) for a in self._ended][-50:],
                "turns": list(self._turns),
                "notes": list(self._notes)[-100:],
                "sensing": sensing,
                "stats": self._stats(),
                "handlers": self.d.handlers.names(),
            }
