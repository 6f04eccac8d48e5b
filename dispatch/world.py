"""A simulated world for the robot side: the whole loop without a robot.

`SimulatedWorld` holds the true state of an RDDL instance and steps it with
the instance's own model (`ippc.rddl.simulator`) and its own seeded
generator, so outcomes are drawn with the instance's probabilities. It
plays both ends that a robot would:

* the action handlers (`handlers()`): every action name, and "noop" (a turn
  without actions still lets one step of the world pass). The first
  dispatch of a turn steps the world with every action of the turn at once
  (`Dispatch.concurrent`), as RDDL steps a joint action; each handler then
  waits, on the simulated clock, until its action's duration has passed
  since the turn began, and reports its outcome;
* the sensors: after each step, the changed groundings of the sensed
  fluents are published on the streams `world/<fluent>` (one message per
  fluent, `{"values": {"a:b": value, ...}}`, or `{"value": v}` for a fluent
  without parameters), which `sensing_config()` tells sensing how to read.
  By default the sensed fluents are those the world changes stochastically
  (their cpf samples something); every other fluent the dispatcher knows
  from the model.

An action's outcome: precondition-false when the true state refuses it
(the knowledge base was wrong); failed when an injected failure hits it
(`failures`: a probability per action name, or a function deciding; the
action then does not happen) or when it had no effect (the world's next
state is the one it would have reached without that action, with the same
draws: wait_load at a printer where nobody is); succeeded otherwise.
`durations` and `costs` give each action's simulated seconds and its cost
(a number, a number per action name, "noop" for a turn without actions, or
a function of the action and the world, called after the step:
`world.previous_state` is the state it started from, `world.outcomes` how
each action ended).

Two hooks for experiments whose world is not the model's: `exogenous(world,
before, after, actions)` returns the true next state (called on the
initial state too, with `before` None), e.g. to force who is where;
`observe(world, state)` returns what the sensors report, `{fluent: {args:
value}}`, published after every step (and on the initial state) whether or
not it changed, e.g. sensors that see only where the robot stands. The
step's reward is the model's, before `exogenous`.

Time is the `SimulatedClock`'s: nothing sleeps, a run takes the time its
computation takes.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from ..rddl.model import STATE, Model, PVariable, Value
from ..rddl.simulator import Simulator, State
from ..rddl.wire import WireCodec
from .actions import Dispatch, GroundAction, Handlers, Result, Status
from .clock import SimulatedClock
from .config import SensingConfig
from .dispatcher import changed_groundings, decode_code, draw_free_fluents

__all__ = ["STREAM_PREFIX", "SimulatedWorld"]

log = logging.getLogger(__name__)

STREAM_PREFIX = "world/"

PerAction = float | Mapping[str, float] | Callable[[GroundAction, "SimulatedWorld"], float]
FailureRule = Mapping[str, float] | Callable[[Dispatch, "SimulatedWorld"], bool | str]
#: fn(world, before (None for the initial state), after, actions) -> the true next state
Exogenous = Callable[["SimulatedWorld", State | None, State, list[GroundAction]], State]
#: fn(world, state) -> {fluent: {args: value}}, what the sensors report in `state`
Observe = Callable[["SimulatedWorld", State], Mapping[str, Mapping[tuple[str, ...], Value]]]


class SimulatedWorld:
    """The true state of one instance, stepped by its model."""

    def __init__(
        self,
        model: Model,
        seed: int = 0,
        *,
        clock: SimulatedClock | None = None,
        sensed: Iterable[str] | None = None,
        durations: PerAction = 1.0,
        costs: PerAction | None = None,
        failures: FailureRule | None = None,
        exogenous: Exogenous | None = None,
        observe: Observe | None = None,
    ):
        self.model = model
        self.sim = Simulator(model)
        self.codec = WireCodec(self.sim)
        self.rng = np.random.default_rng(seed)
        # injected failures draw from their own stream: the world's draws
        # (and so its trajectory) do not depend on whether failures are injected
        self.failure_rng = np.random.default_rng([seed, 1])
        self.clock = clock or SimulatedClock()
        self.state: State = self.sim.initial_state(1)
        self._vars: dict[str, PVariable] = {p.name: p for p in model.fluents(STATE)}
        if sensed is None:
            free = draw_free_fluents(model)
            self.sensed = frozenset(n for n in self._vars if n not in free)
        else:
            self.sensed = frozenset(sensed)
            unknown = sorted(self.sensed - set(self._vars))
            if unknown:
                raise ValueError(f"not state fluents of {model.name}: {', '.join(unknown)}")
        self.durations = durations
        self.costs = costs
        self.failures = failures
        self.exogenous = exogenous
        self.observe = observe
        #: the state the last step started from (None before the first step)
        self.previous_state: State | None = None
        #: how each action of the last step ended (durations and costs may read it)
        self.outcomes: dict[GroundAction, Status] = {}
        self._initial = self.state
        if exogenous is not None:
            self.state = exogenous(self, None, self.state, [])
        self.reward = 0.0  # undiscounted sum of the rewards of the world's steps
        self.steps = 0
        self._publish: Callable[[str, Any], Any] | None = None
        self._turn: int | None = None
        self._results: dict[GroundAction, Result] = {}

    def resume(self, state: State) -> None:
        """Go on from `state` (a restarted run's, journaled): the world is
        there now, and its sensors see it as the start."""
        self.state = state
        self._initial = state

    # -- wiring

    def sensing_config(self, rate: float = 10.0) -> SensingConfig:
        """How sensing reads the world's streams (one sensor per sensed fluent)."""
        sensors: dict[str, Any] = {}
        for name in sorted(self.sensed):
            p = self._vars[name]
            sensors[name] = {
                "stream": STREAM_PREFIX + name,
                "params": ["*"] * p.arity,
                "value": "msg.values" if p.arity else "msg.value",
            }
        return SensingConfig.from_dict(
            {"rate": rate, "sensors": sensors}, self.model, source="<simulated world>"
        )

    def connect(self, publish: Callable[[str, Any], Any]) -> None:
        """Publish sensor messages through `publish(stream, msg)` (e.g.
        `Sensing.feed`), starting with what the sensors see in the initial
        state: with `observe`, its report; else the sensed groundings where
        the true initial state differs from the instance's (an `exogenous`
        hook changed them)."""
        self._publish = publish
        if self.observe is not None:
            self._publish_observation(self.state)
        else:
            self._publish_changes(self._initial, self.state)

    def handlers(self, timeout: float | None = 60.0) -> Handlers:
        """Handlers for every action of the domain and for noop, on the
        world's clock."""
        handlers = Handlers(clock=self.clock, timeout=timeout)
        for p in self.sim.action_fluents:
            handlers.register(p.name, self.execute)
        handlers.register(Handlers.NOOP, self.execute)
        return handlers

    # -- executing

    async def execute(self, dispatch: Dispatch) -> Result:
        """The handler of every action (see the module doc)."""
        if self._turn != dispatch.turn:
            self._turn = dispatch.turn
            self._results = self._step(dispatch)
        result = self._results.get(dispatch.action)
        if result is None:  # an action the dispatcher did not list with the turn
            result = Result(Status.FAILED, f"{dispatch.action} is not one of this turn's actions")
        await self.clock.sleep_until(dispatch.started + (result.duration or 0.0))
        return result

    def _per_action(self, rule: PerAction | None, action: GroundAction) -> float | None:
        if rule is None:
            return None
        if isinstance(rule, int | float):
            return float(rule)
        if isinstance(rule, Mapping):
            value = rule.get(action.name)
            return None if value is None else float(value)
        return float(rule(action, self))

    def _injected(self, dispatch: Dispatch, action: GroundAction) -> str | None:
        rule = self.failures
        if rule is None:
            return None
        if isinstance(rule, Mapping):
            p = rule.get(action.name)
            if p is not None and self.failure_rng.random() < float(p):
                return f"injected failure (p = {float(p):g})"
            return None
        one = Dispatch(
            dispatch.id,
            dispatch.turn,
            action,
            {},
            dispatch.started,
            dispatch.timeout,
            dispatch.concurrent,
        )
        verdict = rule(one, self)
        if verdict:
            return verdict if isinstance(verdict, str) else "injected failure"
        return None

    def _arrays(self, actions: Iterable[GroundAction]) -> dict[str, np.ndarray]:
        return self.codec.actions_from([(a.name, a.args, a.value) for a in actions]).arrays

    def _why_illegal(self, actions: Iterable[GroundAction]) -> str | None:
        decoded = self.codec.actions_from([(a.name, a.args, a.value) for a in actions])
        return self.codec.check(self.state, decoded)

    def _step(self, dispatch: Dispatch) -> dict[GroundAction, Result]:
        actions = list(dispatch.concurrent)
        messages: dict[GroundAction, tuple[Status, str]] = {}
        for a in actions:
            why = self._injected(dispatch, a)
            if why is not None:
                messages[a] = (Status.FAILED, why)
        for a in actions:
            if a not in messages:
                why = self._why_illegal([a])
                if why is not None:
                    messages[a] = (Status.PRECONDITION_FALSE, f"in the world: {why}")
        happening = [a for a in actions if a not in messages]
        if happening and (why := self._why_illegal(happening)) is not None:
            for a in happening:
                messages[a] = (Status.PRECONDITION_FALSE, f"in the world: {why}")
            happening = []
        before = self.state
        bitgen = self.rng.bit_generator
        saved = bitgen.state
        step = self.sim.step(before, self._arrays(happening), self.rng, check=False)
        after = bitgen.state
        for a in happening:
            # the same draws without `a`: if nothing differs, `a` did nothing
            bitgen.state = saved
            others = [b for b in happening if b != a]
            without = self.sim.step(before, self._arrays(others), self.rng, check=False)
            if _same(without.next_state, step.next_state):
                messages[a] = (Status.FAILED, "it had no effect in the world")
        bitgen.state = after
        nxt = step.next_state
        if self.exogenous is not None:
            nxt = self.exogenous(self, before, nxt, happening)
        self.previous_state = before
        self.state = nxt
        self.reward += float(step.reward[0])
        self.steps += 1
        if self.observe is not None:
            self._publish_observation(nxt)
        else:
            self._publish_changes(before, nxt)
        self.outcomes = {a: messages.get(a, (Status.SUCCEEDED, ""))[0] for a in actions}
        results: dict[GroundAction, Result] = {}
        for a in actions:
            status, message = messages.get(a, (Status.SUCCEEDED, ""))
            duration = self._per_action(self.durations, a) or 0.0
            cost = (
                self._per_action(self.costs, a) if status is not Status.PRECONDITION_FALSE else None
            )
            results[a] = Result(status, message, cost, duration)
        if not actions:  # a noop turn: one step of the world passes
            noop = GroundAction(Handlers.NOOP)
            results[noop] = Result(
                Status.SUCCEEDED, "", None, self._per_action(self.durations, noop)
            )
        return results

    def _publish_observation(self, state: State) -> None:
        if self._publish is None or self.observe is None:
            return
        report = self.observe(self, state)
        for name in sorted(report):
            if name not in self.sensed:
                raise ValueError(
                    f"observe reported {name!r}, which is not sensed "
                    f"(sensed: {', '.join(sorted(self.sensed))}); pass sensed=[...]"
                )
            values = report[name]
            if not values:
                continue
            if not self._vars[name].arity:
                self._publish(STREAM_PREFIX + name, {"value": values[()]})
            else:
                self._publish(
                    STREAM_PREFIX + name,
                    {"values": {":".join(args): v for args, v in values.items()}},
                )

    def _publish_changes(self, before: State, after: State) -> None:
        if self._publish is None:
            return
        for name in sorted(self.sensed):
            p = self._vars[name]
            changed = changed_groundings(self.model, p, before, after)
            if not changed:
                continue
            if not p.arity:
                self._publish(STREAM_PREFIX + name, {"value": changed[0][1]})
            else:
                self._publish(
                    STREAM_PREFIX + name, {"values": {":".join(args): v for args, v in changed}}
                )

    def value(self, fluent: str, args: tuple[str, ...] = ()) -> Value:
        """The true value of one grounding."""
        p = self._vars[fluent]
        codes = [self.model.types[t].members.index(a) for t, a in zip(p.params, args, strict=True)]
        return decode_code(self.model, p, self.state.values[fluent][(0, *codes)])


def _same(a: State, b: State) -> bool:
    return all(np.array_equal(a.values[k], b.values[k]) for k in a.values)
