"""Every goal a run pursues gets one outcome: the goal ledger.

A goal is pursued from the moment it is posed (set at run time, changed,
or the domain's own at the start) until one of four outcomes closes it:

* ``reached``: it held at the end of a session (or when it was posed), at
  the run's turn `turn`;
* ``abandoned``: `max_sessions` sessions played out without it (a WARNING
  says so, and the goal's version is not served again; a new goal is), or
  a run that serves no goals ended without it;
* ``removed``: another goal replaced it, or the goal was removed, before it
  was reached (`by`: the version of the goal that replaced it, None when
  none did);
* ``interrupted``: the run ended (a signal, `stop`) while it was pursued.

Each outcome is appended to `outcomes` (the run's report), handed to
`record` (the result store) and to `notify` (the knowledge base's socket).
The ledger lives in the trio thread; `changed` is the knowledge base's goal
subscriber and may be called from any thread.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import trio

from ..kb import Goal, KnowledgeBase
from .dispatcher import Dispatcher

log = logging.getLogger(__name__)

OUTCOMES = ("reached", "abandoned", "removed", "interrupted")


def goal_text(goal: Goal | None) -> str | None:
    """A goal as one line (None: no goal)."""
    if goal is None:
        return None
    return goal.text or " ^ ".join(str(f) for f in goal.facts) or goal.fluent


class GoalLedger:
    """The goals of one run and their outcomes (see the module's docstring)."""

    def __init__(
        self,
        dispatcher: Dispatcher,
        *,
        serving: bool,
        max_sessions: int | None = None,
        record: Callable[[dict[str, Any]], None] | None = None,
        notify: Callable[[dict[str, Any]], None] | None = None,
    ):
        self.dispatcher = dispatcher
        self.kb: KnowledgeBase = dispatcher.kb
        self.serving = serving
        self.max_sessions = max_sessions
        self.record = record
        self.notify = notify
        self.outcomes: list[dict[str, Any]] = []
        self.current: dict[str, Any] | None = None  # the goal pursued, no outcome yet
        self.abandoned: set[int] = set()  # versions not served again
        self._thread = threading.get_ident()
        self._token: trio.lowlevel.TrioToken | None = None
        self._unsubscribe: Callable[[], None] | None = None

    # -- the run's side

    def start(self) -> None:
        """Listen to the knowledge base's goal changes (in a trio run); a
        run that serves no goals pursues the goal it has now."""
        self._token = trio.lowlevel.current_trio_token()
        self._thread = threading.get_ident()
        self._unsubscribe = self.kb.subscribe_goal(self.changed)
        if not self.serving:
            goal = self.kb.goal()
            if goal is not None:
                self.open(goal)

    def stop(self) -> None:
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None

    def open(self, goal: Goal) -> dict[str, Any]:
        """Start pursuing `goal`: its record (closed at once as reached
        when it holds already)."""
        stats = self.dispatcher.stats
        if self.serving:
            stats.goal_reached = False  # (of the goal served before)
        self.current = {
            "goal": goal_text(goal),
            "version": goal.version,
            "outcome": None,
            "reached": False,
            "turn": None,
            "sessions": [],
            "turns": 0,
            "actions": 0,
            "failed_actions": 0,
            "_turns0": stats.turns,
            "_actions0": stats.executed_total,
            "_failed0": stats.failed_actions,
            "_t0": time.time(),
        }
        log.info("pursuing goal %s (version %s)", self.current["goal"], goal.version)
        if self.serving and self.kb.goal_holds() is True:
            self.close("reached")
        return self.current

    def session_ended(self, status: str, served: dict[str, Any] | None = None) -> None:
        """A session that served the goal of record `served` (default: the
        current one) ended with `status`: the goal's outcome when it is
        reached or has had its sessions (a dropped session is tried again).
        A goal closed while the session played (replaced) has its outcome
        already: its `sessions` are those that ended before."""
        rec = self.current if served is None else served
        if rec is None or rec is not self.current:
            return
        rec["sessions"].append(status)
        if status == "dropped":
            return
        if self.dispatcher.stats.goal_reached or self.kb.goal_holds() is True:
            self.close("reached")
            return
        if not self.serving:
            return
        played = sum(1 for s in rec["sessions"] if s != "dropped")
        if self.max_sessions is not None and played >= self.max_sessions:
            log.warning(
                "goal %s (version %s) abandoned: not reached in %d session(s) "
                "(--goal-sessions %d); the next goal set is served",
                rec["goal"],
                rec["version"],
                played,
                self.max_sessions,
            )
            self.abandoned.add(rec["version"])
            self.close("abandoned", reason=f"not reached in {played} session(s)")
            return
        log.warning(
            "goal %s not reached in session %d%s: served again",
            rec["goal"],
            played,
            f" of {self.max_sessions}" if self.max_sessions is not None else "",
        )

    def finish(self, interrupted: bool) -> None:
        """The run ends: the goal still pursued is reached, interrupted, or
        (a run that serves no goals, ended by itself) abandoned."""
        self.stop()
        if self.current is None:
            return
        if self.dispatcher.stats.goal_reached or self.kb.goal_holds() is True:
            self.close("reached")
        elif interrupted:
            self.close("interrupted")
        else:
            self.close("abandoned", reason="the run ended without it")

    def wanted(self, goal: Goal | None) -> bool:
        """Whether `goal` is one to serve: it exists, does not hold, and was
        not abandoned."""
        return (
            goal is not None
            and goal.version not in self.abandoned
            and self.kb.goal_holds() is False
        )

    # -- the knowledge base's side

    def changed(self, goal: Goal | None, source: str) -> None:
        """The goal subscriber: from the trio thread at once, from another
        thread through the trio loop."""
        if threading.get_ident() == self._thread or self._token is None:
            self._changed(goal, source)
            return
        try:
            self._token.run_sync_soon(self._changed, goal, source)
        except trio.RunFinishedError:
            pass

    def _changed(self, goal: Goal | None, source: str) -> None:
        rec = self.current
        version = goal.version if goal is not None else None
        if rec is not None and rec["version"] != version:
            if self.serving and self.dispatcher.stats.goal_reached:
                # reached in the session still playing, replaced before it ended
                self.close("reached")
            else:
                self.close("removed", by=version, source=source)
        if goal is not None and self.current is None:
            if self.serving and goal.version in self.abandoned:
                return
            self.open(goal)

    # -- outcomes

    def close(self, outcome: str, **extra: Any) -> dict[str, Any]:
        """Record the current goal's `outcome` (one of OUTCOMES)."""
        rec = self.current
        assert rec is not None and outcome in OUTCOMES
        stats = self.dispatcher.stats
        out = {k: v for k, v in rec.items() if not k.startswith("_")}
        out.update(
            outcome=outcome,
            reached=outcome == "reached",
            turn=stats.turns if outcome == "reached" else None,
            turns=stats.turns - rec["_turns0"],
            actions=stats.executed_total - rec["_actions0"],
            failed_actions=stats.failed_actions - rec["_failed0"],
            seconds=round(time.time() - rec["_t0"], 3),
            recorded_at=round(time.time(), 3),
            **extra,
        )
        self.current = None
        self.outcomes.append(out)
        level = logging.INFO if outcome == "reached" else logging.WARNING
        log.log(
            level,
            "goal %s %s%s: %d turns, %d actions (%d failed), %d session(s)",
            out["goal"],
            outcome,
            f" at turn {out['turn']}" if out["turn"] is not None else "",
            out["turns"],
            out["actions"],
            out["failed_actions"],
            len(out["sessions"]),
        )
        for sink in (self.record, self.notify):
            if sink is None:
                continue
            try:
                sink(out)
            except Exception:  # noqa: BLE001 - a sink's failure loses no outcome in the report
                log.exception("goal outcome of %s: a sink failed", out["goal"])
        return out


__all__ = ["OUTCOMES", "GoalLedger", "goal_text"]
