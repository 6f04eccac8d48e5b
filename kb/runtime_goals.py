"""Goals set at run time (ROSPlan's ADD_GOAL / REMOVE_GOAL updates), the
part of `KnowledgeBase` that changes its goal: `set_goal`, `add_goal`,
`remove_goal`, `reset_goal`, `subscribe_goal`. A goal that no state can
satisfy (it breaks a state invariant whatever the other fluents are: the
robot in two rooms at once) is refused when it is posed (KBError code
"impossible-goal", naming the invariant and its grounding)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Protocol

from ..rddl.model import STATE
from .goal import Goal, GoalFact, parse_goal_fact
from .invariants import Invariants
from .store import KBError, Store

log = logging.getLogger(__name__)

GoalSubscriber = Callable[[Goal | None, str], None]
# What set_goal and its kin take: one fact or several (see `parse_goal_fact`).
GoalFacts = GoalFact | str | Mapping[str, Any] | Iterable[GoalFact | str | Mapping[str, Any]]


class GoalHost(Protocol):
    """What `RuntimeGoals` needs of the class it is mixed into (`KnowledgeBase`):
    its lock, store, invariants and goal state, its domain goal, and its
    subscription, journal and change hooks. `RuntimeGoals` subclasses it, so mypy
    checks that a host provides every one with these types."""

    _lock: threading.RLock
    _store: Store
    _invariants: Invariants
    _runtime_goal: tuple[GoalFact, ...] | None
    _goal_version: int
    _goal_subscribers: list[GoalSubscriber]

    def goal(self) -> Goal | None:
        """The goal now (None: no goal)."""
        ...

    def _listen(self, listeners: list[Any], callback: Any) -> Callable[[], None]:
        """Add `callback` to `listeners`; the function that removes it."""
        ...

    def _log(self, entry: dict[str, Any]) -> None:
        """Journal `entry`."""
        ...

    def _changed(self) -> None:
        """Under the lock: the knowledge base's state or goal changed."""
        ...


class RuntimeGoals(GoalHost):
    """The run-time goal methods of `KnowledgeBase`, which provides what
    `GoalHost` declares."""

    def set_goal(self, facts: GoalFacts, source: str = "api") -> Goal | None:
        """Make the goal the conjunction of `facts` (a `GoalFact`, a text
        such as "holding(r1)", "~present(office)" or "status == @busy", a
        `{"fluent", "args", "value"}` dict, or a list of them), in place of
        the domain's. Every fact is checked before anything changes
        (KBError naming it). Goal subscribers hear of it, and `version`
        grows, even when the facts are the ones already asked for (a new
        request). An empty list leaves no goal. The new goal."""
        new = self._goal_facts(facts, allow_empty=True)
        with self._lock:
            self._check_goal_possible(new)
            goal = self._change_goal(new, source)
        self._notify_goal(goal, source)
        return goal

    def add_goal(self, facts: GoalFacts, source: str = "api") -> Goal | None:
        """Add `facts` to the current goal's facts (the domain goal's ground
        facts when no goal was set at run time). A fact that asks the
        opposite of one in the goal is refused. The new goal."""
        extra = self._goal_facts(facts)
        with self._lock:
            current = list(self._current_goal_facts())
            known = {(f.fluent, f.args): f for f in current}
            for f in extra:
                other = known.get((f.fluent, f.args))
                if other is not None and other != f:
                    raise KBError(f"goal fact {f} contradicts {other}, in the goal", "bad-goal")
                if other is None:
                    current.append(f)
                    known[(f.fluent, f.args)] = f
            self._check_goal_possible(tuple(current))
            goal = self._change_goal(tuple(current), source)
        self._notify_goal(goal, source)
        return goal

    def remove_goal(self, facts: GoalFacts, source: str = "api") -> Goal | None:
        """Remove `facts` from the current goal's facts; one that is not in
        the goal is an error (`not-in-goal`), and nothing changes. Removing
        the last leaves no goal (`reset_goal` brings the domain's back).
        The new goal."""
        gone = self._goal_facts(facts)
        with self._lock:
            current = self._current_goal_facts()
            for f in gone:
                if f not in current:
                    listed = ", ".join(str(g) for g in current) or "nothing"
                    raise KBError(f"{f} is not in the goal (it asks for {listed})", "not-in-goal")
            goal = self._change_goal(tuple(f for f in current if f not in gone), source)
        self._notify_goal(goal, source)
        return goal

    def reset_goal(self, source: str = "api") -> Goal | None:
        """Back to the domain's own goal (the `goal` fluent's condition).
        The goal (None: the domain has none)."""
        with self._lock:
            goal = self._change_goal(None, source)
        self._notify_goal(goal, source)
        return goal

    def subscribe_goal(self, callback: GoalSubscriber) -> Callable[[], None]:
        """Call `callback(goal, source)` after every goal change (goal None:
        no goal now); returns the function that unsubscribes it."""
        return self._listen(self._goal_subscribers, callback)

    def _check_goal_possible(self, facts: tuple[GoalFact, ...]) -> None:
        """Under the lock: KBError (code "impossible-goal") naming the state
        invariant that no state with `facts` satisfies (the robot in two
        rooms at once), as far as `Invariants.impossible` can tell."""
        if not facts or not self._invariants:
            return
        fixed = {(f.fluent, f.args): f.value for f in facts}

        def free(fluent: str) -> bool:
            return self._store.pvar(fluent).range == "bool"

        broken = self._invariants.impossible(fixed, self._store.get, free)
        if broken:
            asked = " ^ ".join(str(f) for f in facts)
            raise KBError(
                f"no state has {asked}: the goal breaks the "
                + "; the ".join(str(v) for v in broken),
                "impossible-goal",
            )

    def _current_goal_facts(self) -> tuple[GoalFact, ...]:
        if self._runtime_goal is not None:
            return self._runtime_goal
        goal = self.goal()
        return () if goal is None else goal.facts

    def _change_goal(self, facts: tuple[GoalFact, ...] | None, source: str) -> Goal | None:
        """Under the lock: the new run-time goal (None: the domain's)."""
        self._runtime_goal = facts
        self._goal_version += 1
        self._changed()
        self._log(
            {
                "source": source,
                "goal": None if facts is None else [f.to_json() for f in facts],
                "version": self._goal_version,
            }
        )
        return self.goal()

    def _notify_goal(self, goal: Goal | None, source: str) -> None:
        with self._lock:
            subscribers = list(self._goal_subscribers)
        for cb in subscribers:
            try:
                cb(goal, source)
            except Exception:
                log.exception("goal subscriber %r failed on a change by %s", cb, source)

    def _goal_facts(self, items: GoalFacts, allow_empty: bool = False) -> tuple[GoalFact, ...]:
        """Checked goal facts with canonical names and values, or a KBError
        naming the first bad one."""
        if isinstance(items, (str, GoalFact, Mapping)):
            items = [items]
        out: dict[tuple[str, tuple[str, ...]], GoalFact] = {}
        n = 0
        for n, item in enumerate(items, 1):
            try:
                try:
                    fact = parse_goal_fact(item)
                except ValueError as err:
                    raise KBError(str(err), "bad-goal") from None
                with self._lock:
                    st = self._store
                    p = st.pvar(fact.fluent)
                    if p.kind != STATE:
                        raise KBError(
                            f"'{p.name}' is a non-fluent: a goal asks for state fluents",
                            "not-state",
                        )
                    idx = st.index(p, fact.args)
                    fact = GoalFact(
                        p.name, st.args_of(p, idx), st.decode(p, st.encode(p, fact.value))
                    )
                other = out.get((fact.fluent, fact.args))
                if other is not None and other != fact:
                    raise KBError(f"it contradicts {other}", "bad-goal")
            except KBError as err:
                raise KBError(f"goal fact {n} ({item}): {err}", err.code) from None
            out[(fact.fluent, fact.args)] = fact
        if n == 0 and not allow_empty:
            raise KBError("no goal facts given", "bad-goal")
        return tuple(out.values())
