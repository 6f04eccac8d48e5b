"""What a session plays against: the `Environment` interface.

A session (`server.session.Session`) owns the protocol: the messages, the
session clock and budget, the rounds, the result store. An environment owns
the state: what a turn lists and what the actions do. rddl-server serves
simulated environments (`SimulatedEpisode`, the instance's simulator seeded
per session, as rddlsim plays it); rddl-dispatch serves a robot's knowledge
base (`ippc.dispatch`), where actions are executed by handlers and the next
state comes from sensing.

Per session the server calls `Environment.open(seed)` once and gets an
`Episode`; per round `Episode.start_round()`; per turn `turn()` (what the
turn lists), `thinking()` while the client decides (work that does not need
the actions: the simulator draws its next step here), then `act(actions)`,
whose `Outcome` says the reward, whether the actions were illegal (the
round ends, as in rddlsim), whether the round or the whole session ends
after this step, and what to record beyond rddlsim's fields.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..protocol import Actions, encode
from ..protocol.values import parse_value
from ..rddl.simulator import Prepared, SimulationError, Simulator, State
from ..rddl.wire import DecodedActions, WireCodec, WireError, WireFluent, value_kind

if TYPE_CHECKING:
    from ..rddl.model import Model

__all__ = [
    "Environment",
    "Environments",
    "Episode",
    "Outcome",
    "SessionDropped",
    "SimulatedEpisode",
    "StepFailed",
    "TurnLister",
    "decode_actions",
]


class SessionDropped(Exception):
    """The session cannot go on; the message says why (for the log)."""


class StepFailed(Exception):
    """The environment cannot take the step (a simulation error); the
    session is dropped with the round and turn added to the message."""


@dataclass(slots=True)
class Outcome:
    """What one `Episode.act` did."""

    #: the reward of the transition (0.0 when the actions were illegal)
    reward: float
    #: why the actions are illegal (the round ends, the session goes on), or None
    illegal: str | None = None
    #: the round's status when it ends after this step ("terminal"), or None
    end: str | None = None
    #: True: no further round; session-end follows this round's round-end
    stop: bool = False
    #: what happened, as JSON-able data for the store (None for a simulated step)
    record: Any = None
    #: seconds the actions took to execute (None for a simulated step)
    execution_seconds: float | None = None


class Episode(ABC):
    """One session's play against an environment."""

    @abstractmethod
    def start_round(self) -> None:
        """A round begins (round-init is being sent)."""

    @abstractmethod
    def turn(self) -> tuple[list[WireFluent] | None, str | None]:
        """What the next turn lists: the wire fluents (for the store) and
        their observed-fluent elements (None, None: `<no-observed-fluents/>`)."""

    def thinking(self) -> None:  # noqa: B027 - optional hook, nothing to do by default
        """The turn is sent and the client is deciding: do what does not
        need its actions."""

    @abstractmethod
    async def act(self, actions: Actions) -> Outcome:
        """Carry out the client's actions. Raises `SessionDropped` for
        actions that cannot be read at all (rddlsim drops the session),
        `StepFailed` when the step cannot be taken."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """The session is over (however it ended)."""


class Environment(ABC):
    """Something sessions are played against, under one instance name."""

    name: str
    task: bytes  # session-init's task
    model: Model

    @property
    def horizon(self) -> int | None:
        return self.model.horizon

    @abstractmethod
    async def open(self, seed: int) -> Episode:
        """A new episode for a session seeded with `seed`."""


class Environments(Protocol):
    """What a server serves: environments by instance name (a `Registry`)."""

    def get(self, name: str) -> Environment:
        """The environment called `name`; `UnknownInstance` says why not."""
        ...


class TurnLister(Protocol):
    """What a `SimulatedEpisode` asks of its instance (a `Registry`'s `Instance`, which
    imports this module): a turn's fluents and their elements, written once per state."""

    def turn_fluents(
        self, codec: WireCodec, state: State, observation: Mapping[str, np.ndarray] | None
    ) -> tuple[list[WireFluent] | None, str | None]:
        """What a turn lists in `state` (MDP) or with `observation` (POMDP)."""
        ...


def decode_actions(codec: WireCodec, actions: Actions) -> DecodedActions:
    """Received actions -> arrays, with rddlsim's reading of values; what
    rddlsim drops the session for raises `SessionDropped`."""
    model = codec.model
    typed: list[WireFluent] = []
    for a in actions.actions:
        p = model.pvariables.get(a.name)
        if p is None:
            raise SessionDropped(f"unknown action {a.name!r} in {show_actions(actions)}")
        try:
            value = parse_value(str(a.value), value_kind(model, p))
        except ValueError:
            raise SessionDropped(
                f"action {a.name!r}: value {a.value!r} is not a {p.range}"
            ) from None
        typed.append((a.name, tuple(a.args), value))
    try:
        return codec.actions_from(typed)
    except WireError as err:
        raise SessionDropped(f"{err} in {show_actions(actions)}") from None


def show_actions(actions: Actions, limit: int = 200) -> str:
    """An actions message as text for a log line (cut at `limit`)."""
    text = encode(actions, declaration=False).decode("ascii", "replace")
    return text if len(text) <= limit else text[:limit] + "..."


class SimulatedEpisode(Episode):
    """rddlsim's environment: the instance's simulator with the session's
    generator (not reseeded between rounds), the state reset at every round.

    While the client thinks, the draws of the next step and everything the
    state alone decides are computed ahead (`Simulator.prepare`), and given
    back if the actions turn out illegal."""

    __slots__ = (
        "instance",
        "sim",
        "codec",
        "rng",
        "state",
        "observation",
        "_prepared",
        "_noop",
        "_invariants",
    )

    def __init__(self, instance: TurnLister, sim: Simulator, codec: WireCodec, seed: int):
        self.instance = instance
        self.sim = sim
        self.codec = codec
        self.rng = np.random.default_rng(seed)
        self.state: State = sim.initial_state(1)
        self.observation: dict[str, np.ndarray] | None = None
        self._prepared: Prepared | None = None
        # what a noop decodes to, the same every turn (stepped as None: the
        # simulator's own cached defaults)
        self._noop = codec.actions_from(())
        self._invariants = bool(sim._invariants)

    def start_round(self) -> None:
        self.state = self.sim.initial_state(1)
        self.observation = None

    def turn(self) -> tuple[list[WireFluent] | None, str | None]:
        return self.instance.turn_fluents(self.codec, self.state, self.observation)

    def thinking(self) -> None:
        self._prepared = self.sim.prepare(self.state, self.rng)

    async def act(self, actions: Actions) -> Outcome:
        prepared, self._prepared = self._prepared, None
        codec = self.codec
        # (actions that cannot be read drop the session: no draws to give back)
        decoded = decode_actions(codec, actions) if actions.actions else self._noop
        why = codec.check(self.state, decoded)
        if why is not None:
            if prepared is not None:
                self.sim.unprepare(prepared, self.rng)  # this step never happens
            return Outcome(0.0, illegal=why)
        try:
            # the constraints were checked above; the step checks the
            # invariants (and keeps numpy's floating-point warnings quiet)
            arrays = None if decoded is self._noop else decoded.arrays
            if prepared is not None:
                step = self.sim.finish(prepared, arrays, check=self._invariants)
            else:
                step = self.sim.step(self.state, arrays, self.rng, check=self._invariants)
        except SimulationError as err:
            raise StepFailed(str(err)) from None
        self.state = step.next_state
        self.observation = step.observation
        if bool(step.done[0]):
            return Outcome(float(step.reward[0]), end="terminal")
        return Outcome(float(step.reward[0]))
