"""The online dispatcher: an IPPC environment whose state is the knowledge base.

Theory of operation. `Dispatcher` is a `server.environment.Environment`:
rddl-server's session code plays the protocol (same bytes as rddl-server,
both framings, the session clock, the result store), and every turn it
asks the dispatcher's episode what to send and what the actions do:

1. `turn()`: the knowledge base's state (`kb.to_state()`), every grounding
   of every state fluent, written as rddl-server writes a turn.
2. `act(actions)`: the planner's answer, read as rddl-server reads it
   (unreadable actions drop the session, as in rddlsim). Each action's
   preconditions (action-preconditions and state-action constraints, and
   max-nondef-actions for the set) are checked on the state that was sent;
   an action that fails them is not dispatched and is reported
   precondition-false with the constraint that failed. The others are
   dispatched to their handlers, all at once (a turn's actions run
   concurrently when max-nondef-actions allows several), each within the
   action timeout.
3. What the succeeded actions change is applied to the knowledge base for
   the fluents that are *not sensed* and whose cpf draws nothing (exactly,
   by the model: the simulator steps the sent state with the succeeded
   actions and the changed groundings of those fluents are written, source
   "dispatcher"). A sensed fluent, or one whose cpf is stochastic, is never
   written by the dispatcher: what happened comes from sensing. A sensed
   fluent whose value the model would have known and that sensing
   contradicts is logged (`contradictions` in the step's record).
4. Sensing settles (`Sensing.settle`), then the goal is checked: when it
   holds (and the domain has one) the round ends and session-end follows.
   At the horizon the round ends and, if rounds are left, the next one
   starts from the knowledge base's state as it is (the world does not
   reset). A failed action is logged and the next turn is planned from the
   sensed state.

The reward sent with the next turn is the model's R(s, a) for the state sent
and the actions dispatched. Everything a turn did is in `Outcome.record`,
which the session stores with the step (`steps.outcome` in the result
store) and which `executed` keeps for the report.

Watchers (`Dispatcher.watch`, the web page's `dispatch.live`) hear of each
session opened and closed, each round, each turn sent and each turn's
record with its reward, as plain data, in the event loop's thread.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trio

from ..kb import KBError, KnowledgeBase, Update
from ..protocol import Actions, ObservedFluentsWriter
from ..rddl import ast as A
from ..rddl.model import DERIVED, INTERM, STATE, Model, PVariable, Value
from ..rddl.simulator import SimulationError, Simulator, State
from ..rddl.wire import WireCodec, WireFluent
from ..server.environment import Environment, Episode, Outcome, decode_actions
from ..server.limits import Notices
from ..server.registry import UnknownInstance, build_task
from .actions import Dispatch, GroundAction, Handlers, Result, Status, parameter_keys
from .clock import Clock, WallClock
from .sensing import Sensing

__all__ = [
    "Dispatcher",
    "DispatcherError",
    "ExecutedAction",
    "changed_groundings",
    "draw_free_fluents",
]

log = logging.getLogger(__name__)

SOURCE = "dispatcher"

#: The outcome recorded for an action cancelled because the dispatcher stopped.
INTERRUPTED = "interrupted"


class DispatcherError(ValueError):
    """An instance the dispatcher cannot serve (a partially observed one)."""


def draw_free_fluents(model: Model) -> frozenset[str]:
    """The state fluents whose next value the model decides from the state
    and the actions alone: their cpf samples nothing, nor does any interm,
    derived or next-state fluent it reads (transitively)."""
    cpfs = model.cpfs
    memo: dict[str, bool] = {}

    def free(name: str, stack: frozenset[str]) -> bool:
        if name in memo:
            return memo[name]
        cpf = cpfs.get(name)
        if cpf is None:
            return True
        if name in stack:  # a cycle the checker let through: be careful
            return False
        result = not A.has_draws(cpf.expr)
        if result:
            reads = {(n.name, n.primed) for n in A.walk(cpf.expr) if isinstance(n, A.PVar)}
            for other, primed in sorted(reads):
                p = model.pvariables.get(other)
                if p is None:
                    continue
                if (p.kind in (INTERM, DERIVED) or (primed and p.kind == STATE)) and not free(
                    other, stack | {name}
                ):
                    result = False
                    break
        memo[name] = result
        return result

    return frozenset(p.name for p in model.fluents(STATE) if free(p.name, frozenset()))


def decode_code(model: Model, p: PVariable, x: Any) -> Value:
    """A simulator array element of `p` as a knowledge-base value."""
    if p.range == "bool":
        return bool(x)
    if p.range == "int":
        return int(x)
    if p.range == "real":
        return float(x)
    return model.types[p.range].members[int(x)]


def changed_groundings(
    model: Model, p: PVariable, before: State, after: State
) -> list[tuple[tuple[str, ...], Value]]:
    """The groundings of `p` whose value differs between two 1-states, with
    the value in `after`."""
    a = before.values[p.name][0]
    b = after.values[p.name][0]
    out: list[tuple[tuple[str, ...], Value]] = []
    for idx in np.argwhere(a != b):
        t = tuple(int(i) for i in idx)
        args = tuple(model.types[ty].members[i] for ty, i in zip(p.params, t, strict=True))
        out.append((args, decode_code(model, p, b[t])))
    return out


@dataclass(frozen=True)
class ExecutedAction:
    """One dispatched action, as the executed plan lists it."""

    round: int
    turn: int
    action: str
    outcome: str
    message: str = ""
    seconds: float = 0.0
    cost: float | None = None

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "round": self.round,
            "turn": self.turn,
            "action": self.action,
            "outcome": self.outcome,
            "seconds": self.seconds,
        }
        if self.message:
            d["message"] = self.message
        if self.cost is not None:
            d["cost"] = self.cost
        return d


#: A watcher of a dispatcher: called with the event's kind and its JSON-able data.
Watcher = Callable[[str, dict[str, Any]], None]

#: Dispatched actions a dispatcher keeps for its report (the last ones); the
#: result store has every one. A dispatcher that runs for a shift must not
#: grow with the number of turns it played.
EXECUTED_KEPT = 1000


@dataclass
class DispatchStats:
    """What the dispatcher did over its life (all sessions)."""

    turns: int = 0
    rounds: int = 0
    reward: float = 0.0  # undiscounted sum of the turns' rewards
    planning_seconds: float = 0.0  # wall seconds between a turn sent and its actions
    execution_seconds: float = 0.0  # on the dispatcher's clock, dispatch to settled
    goal_reached: bool = False
    replans: int = 0  # turns planned after an action that did not succeed
    contradictions: int = 0  # sensed values that contradicted what the model knew
    #: the last `EXECUTED_KEPT` dispatched actions
    executed: deque[ExecutedAction] = field(default_factory=lambda: deque(maxlen=EXECUTED_KEPT))
    executed_total: int = 0  # every dispatched action
    failed_actions: int = 0  # of them, those that did not succeed
    _cost: float = 0.0
    _costed: int = 0

    def record(self, action: ExecutedAction) -> None:
        self.executed.append(action)
        self.executed_total += 1
        if action.outcome != Status.SUCCEEDED.value:
            self.failed_actions += 1
        if action.cost is not None:
            self._cost += action.cost
            self._costed += 1

    @property
    def cost(self) -> float | None:
        return self._cost if self._costed else None


class Dispatcher(Environment):
    """Serves a knowledge base's state to IPPC planners and executes their
    actions through handlers (see the module doc). Also its own registry:
    `get(name)` is itself for its instance's name."""

    def __init__(
        self,
        kb: KnowledgeBase,
        handlers: Handlers,
        sensing: Sensing | None = None,
        *,
        clock: Clock | None = None,
        action_timeout: float | None = None,
        settle_limit: float = 2.0,
        stop_at_goal: bool = True,
        task: bytes | None = None,
    ):
        model = kb.model
        if model.is_pomdp:
            raise DispatcherError(
                f"{model.name} is partially observed: the dispatcher serves the knowledge "
                "base's state, so only MDP domains"
            )
        self.kb = kb
        self.model = model
        self.name = model.name
        self.task = build_task(model) if task is None else task
        self.handlers = handlers
        self.sensing = sensing
        self.clock = clock or handlers.clock or WallClock()
        self.action_timeout = handlers.timeout if action_timeout is None else action_timeout
        self.settle_limit = settle_limit
        self.stop_at_goal = stop_at_goal
        # the knowledge base's simulator: its non-fluents are the current ones
        # (a client may write distances at start-up); see `refresh`
        self.sim: Simulator = kb.simulator()
        self.codec = WireCodec(self.sim)
        self.draw_free = draw_free_fluents(model)
        self.stats = DispatchStats()
        # warnings about sensing that contradicts the model, once per cause
        # and then counted (flushed by `notices.run` in a dispatcher's run)
        self.notices = Notices(log)
        self._writer: ObservedFluentsWriter | None = None
        self._next_id = 0
        self._keys = {p.name: parameter_keys(model, p.name) for p in self.sim.action_fluents}
        self._state_vars: dict[str, PVariable] = {p.name: p for p in model.fluents(STATE)}
        self._watchers: list[Watcher] = []
        stochastic = sorted(
            n for n in self._state_vars if n not in self.draw_free and not kb.is_sensed(n)
        )
        if stochastic:
            log.warning(
                "stochastic fluents that nothing senses (the knowledge base learns their "
                "values only from whoever writes them): %s",
                ", ".join(stochastic),
            )

    # -- watchers

    def watch(self, watcher: Watcher) -> Callable[[], None]:
        """Call `watcher(kind, data)` for each session ("session-opened",
        "session-closed"), round ("round"), turn sent ("turn-sent") and turn
        played ("turn": its record and reward); returns the function that
        stops it."""
        self._watchers.append(watcher)

        def unwatch() -> None:
            if watcher in self._watchers:
                self._watchers.remove(watcher)

        return unwatch

    def tell(self, kind: str, data: dict[str, Any]) -> None:
        """Tell the watchers; one that raises is logged and the others still hear."""
        for watcher in list(self._watchers):
            try:
                watcher(kind, data)
            except Exception:
                log.exception("a dispatcher watcher failed on %s", kind)

    # -- Environments (the server's registry)

    def get(self, name: str) -> Dispatcher:
        if name != self.name:
            raise UnknownInstance(
                f"unknown instance {name!r} (this dispatcher serves {self.name!r})"
            )
        return self

    async def open(self, seed: int) -> Episode:
        self.tell("session-opened", {"seed": seed})
        return DispatchEpisode(self, seed)

    def refresh(self) -> None:
        """Follow the knowledge base's non-fluents (its simulator is rebuilt
        when one changes)."""
        sim = self.kb.simulator()
        if sim is not self.sim:
            self.sim = sim
            self.codec = WireCodec(sim)

    # -- what a turn sends

    def listing(self, state: State) -> tuple[list[WireFluent], str]:
        sent = self.codec.state(state)
        writer = self._writer
        if writer is None or len(writer) != len(sent):
            writer = self._writer = ObservedFluentsWriter([(n, a) for n, a, _ in sent])
        return sent, writer.write([v for _, _, v in sent])

    def new_id(self) -> int:
        self._next_id += 1
        return self._next_id

    def params_of(self, action: GroundAction) -> dict[str, str]:
        keys = self._keys.get(action.name, ())
        return dict(zip(keys, action.args, strict=False))

    # -- the model's view of a turn

    def arrays(self, actions: Sequence[GroundAction]) -> dict[str, np.ndarray]:
        return self.codec.actions_from([(a.name, a.args, a.value) for a in actions]).arrays

    def why_illegal(self, state: State, actions: Sequence[GroundAction]) -> str | None:
        decoded = self.codec.actions_from([(a.name, a.args, a.value) for a in actions])
        return self.codec.check(state, decoded)

    def model_step(
        self, state: State, actions: Sequence[GroundAction], rng: np.random.Generator
    ) -> tuple[State | None, float]:
        """The model's next state and reward for `actions` in `state` (draws
        from the dispatcher's own generator stand in for what is sensed)."""
        try:
            step = self.sim.step(state, self.arrays(actions), rng, check=False)
        except SimulationError as err:
            log.warning("the model cannot step the knowledge base's state: %s", err)
            return None, 0.0
        return step.next_state, float(step.reward[0])

    def changes(self, before: State, after: State, fluents: Sequence[str]) -> list[Update]:
        """Updates for the groundings of `fluents` that differ between the states."""
        return [
            Update("set", name, args, value)
            for name in fluents
            for args, value in changed_groundings(self.model, self._state_vars[name], before, after)
        ]


class DispatchEpisode(Episode):
    """One planner session against the dispatcher."""

    def __init__(self, dispatcher: Dispatcher, seed: int):
        self.d = dispatcher
        self.rng = np.random.default_rng(seed)
        self.round = 0
        self.turn_num = 0
        self.snapshot: State | None = None
        self._sent_at = 0.0
        self._last_failed = False

    def start_round(self) -> None:
        self.round += 1
        self.d.stats.rounds += 1
        self.d.tell("round", {"round": self.round})

    def turn(self) -> tuple[list[WireFluent] | None, str | None]:
        self.d.refresh()
        self.snapshot = self.d.kb.to_state()
        listing = self.d.listing(self.snapshot)
        self.d.tell("turn-sent", {"round": self.round, "turn": self.d.stats.turns + 1})
        return listing

    def close(self) -> None:
        self.d.tell("session-closed", {"rounds": self.round})

    async def act(self, actions: Actions) -> Outcome:
        outcome = await self._act(actions)
        self.d.tell("turn", {**outcome.record, "reward": outcome.reward})
        return outcome

    def thinking(self) -> None:
        self._sent_at = time.perf_counter()

    async def _act(self, actions: Actions) -> Outcome:
        d = self.d
        stats = d.stats
        stats.planning_seconds += time.perf_counter() - self._sent_at
        decoded = decode_actions(d.codec, actions)  # unreadable: the session is dropped
        state = self.snapshot if self.snapshot is not None else d.kb.to_state()
        stats.turns += 1
        self.turn_num = stats.turns  # counted over the dispatcher's life: unique
        if self._last_failed:
            stats.replans += 1
        wanted = [GroundAction(n, tuple(a), v) for n, a, v in d.codec.actions(decoded.arrays)]
        extra = [f"{i}" for i in decoded.ignored]
        if d.stop_at_goal and d.kb.goal_holds():
            stats.goal_reached = True
            done = {"round": self.round, "turn": self.turn_num, "actions": [], "goal": True}
            return Outcome(0.0, end="terminal", stop=True, record=done, execution_seconds=0.0)
        started = d.clock.now()
        # preconditions on the state sent: alone, then together
        refused: dict[GroundAction, str] = {}
        for a in wanted:
            why = d.why_illegal(state, [a])
            if why is not None:
                refused[a] = why
        legal = [a for a in wanted if a not in refused]
        if legal:
            why = d.why_illegal(state, legal)
            if why is not None:
                for a in legal:
                    refused[a] = why
                legal = []
        for a, why in refused.items():
            log.info("turn %d: %s not dispatched: precondition false: %s", self.turn_num, a, why)
        results: dict[GroundAction, Result] = {
            a: Result(Status.PRECONDITION_FALSE, why, duration=0.0) for a, why in refused.items()
        }
        if legal:
            try:
                results.update(await self._dispatch(legal, started))
            except trio.Cancelled:
                # the dispatcher is stopping (a signal): the actions in
                # progress are cancelled, and the report says so
                for a in legal:
                    stats.record(
                        ExecutedAction(
                            self.round,
                            self.turn_num,
                            str(a),
                            INTERRUPTED,
                            "cancelled: the dispatcher was stopped while it ran",
                            max(0.0, d.clock.now() - started),
                        )
                    )
                raise
        elif Handlers.NOOP in d.handlers:
            # nothing runs this turn (no action, or every one refused): time passes
            # for the robot as on a noop turn (the simulated world steps)
            await self._dispatch([GroundAction(Handlers.NOOP)], started, noop=True)
        succeeded = [a for a in legal if results[a].succeeded]
        for a in legal:
            r = results[a]
            if not r.succeeded:
                log.warning("turn %d: %s %s: %s", self.turn_num, a, r.status, r.message)
        # the model: reward of what was attempted, effects of what succeeded
        next_all, reward = d.model_step(state, legal, self.rng)
        expected = next_all if succeeded == legal else d.model_step(state, succeeded, self.rng)[0]
        applied = 0
        refused_effects: str | None = None
        if expected is not None:
            writable = [n for n in sorted(d.draw_free) if not d.kb.is_sensed(n)]
            updates = d.changes(state, expected, writable)
            if updates:
                try:
                    applied = len(d.kb.apply(updates, SOURCE))
                except KBError as err:
                    # the state moved on while the actions ran (sensing, a
                    # client) and the effects no longer fit it (a state
                    # invariant): nothing is written, the next turn is
                    # planned from what the knowledge base holds
                    refused_effects = str(err)
                    log.warning("turn %d: the actions' effects refused: %s", self.turn_num, err)
        sensed = 0
        if d.sensing is not None:
            sensed = len(await d.sensing.settle(d.settle_limit))
        contradictions = self._contradictions(expected, succeeded) if expected is not None else []
        seconds = d.clock.now() - started
        stats.execution_seconds += seconds
        stats.reward += reward
        self._last_failed = len(succeeded) < len(wanted)
        executed = []
        for a in wanted:
            r = results[a]
            entry = ExecutedAction(
                self.round,
                self.turn_num,
                str(a),
                r.status.value,
                r.message,
                float(r.duration or 0.0),
                r.cost,
            )
            stats.record(entry)
            executed.append(entry.as_dict())
        goal = d.kb.goal_holds()
        record: dict[str, Any] = {
            "round": self.round,
            "turn": self.turn_num,
            "actions": executed,
            "applied": applied,
            "sensed": sensed,
            "goal": goal,
        }
        if extra:
            record["ignored"] = extra
        if refused_effects is not None:
            record["effects_refused"] = refused_effects
        if contradictions:
            record["contradictions"] = contradictions
            stats.contradictions += len(contradictions)
        if goal:
            # reached, whether the run stops there or goes on (--no-stop-at-goal):
            # the report and the web page say so alike
            stats.goal_reached = True
        if goal and d.stop_at_goal:
            return Outcome(
                reward, end="terminal", stop=True, record=record, execution_seconds=seconds
            )
        return Outcome(reward, record=record, execution_seconds=seconds)

    async def _dispatch(
        self, actions: list[GroundAction], started: float, noop: bool = False
    ) -> dict[GroundAction, Result]:
        d = self.d
        results: dict[GroundAction, Result] = {}
        together = () if noop else tuple(actions)

        async def one(a: GroundAction) -> None:
            dispatch = Dispatch(
                d.new_id(),
                self.turn_num,
                a,
                d.params_of(a),
                started,
                d.action_timeout,
                together,
            )
            results[a] = await d.handlers.run(dispatch)

        if len(actions) == 1:
            await one(actions[0])
        else:
            async with trio.open_nursery() as nursery:
                for a in actions:
                    nursery.start_soon(one, a)
        return results

    def _contradictions(
        self, expected: State, succeeded: Sequence[GroundAction]
    ) -> list[dict[str, Any]]:
        """Sensed groundings the model knew the value of, that sensing says
        otherwise (the robot sensed in a room no transition reaches): one
        WARNING per turn with what was sensed and what the model allowed,
        repeated ones counted (`Dispatcher.notices`)."""
        d = self.d
        out: list[dict[str, Any]] = []
        sensed = [n for n in sorted(d.draw_free) if d.kb.is_sensed(n)]
        if not sensed:
            return out
        now = d.kb.to_state()
        for up in d.changes(now, expected, sensed):
            got = d.kb.get(up.fluent, up.args)
            out.append(
                {"fluent": up.fluent, "args": list(up.args), "expected": up.value, "sensed": got}
            )
        if out:

            def show(c: dict[str, Any], key: str) -> str:
                return f"{c['fluent']}({', '.join(c['args'])}) = {_text(c[key])}"

            after = ", ".join(str(a) for a in succeeded) or "no action"
            d.notices.note(
                "turns where sensing contradicts the model's transitions",
                f"turn {self.turn_num}: sensing contradicts the model after {after}: sensed "
                + ", ".join(show(c, "sensed") for c in out)
                + "; the model allowed "
                + ", ".join(show(c, "expected") for c in out),
            )
        return out
        now = d.kb.to_state()
        for up in d.changes(now, expected, sensed):
            got = d.kb.get(up.fluent, up.args)
            out.append(
                {"fluent": up.fluent, "args": list(up.args), "expected": up.value, "sensed": got}
            )
            log.info(
                "sensing contradicts the model: %s(%s) expected %s, sensed %s",
                up.fluent,
                ",".join(up.args),
                up.value,
                got,
            )
        return out


def _text(value: Any) -> str:
    """A value as RDDL writes it (true/false, numbers, enum values)."""
    if value is True:
        return "true"
    if value is False:
        return "false"
    return str(value)
