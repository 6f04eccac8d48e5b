"""The two baseline planners: `noop` and `random`."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..rddl.simulator import SimulationError, State
from ..rddl.wire import WireCodec
from .base import Observation, Planner, PlannerError, SessionInfo, WireFluent


class NoopPlanner(Planner):
    """Every action at its default, every turn (sends `<actions/>`-style noop)."""

    name: ClassVar[str] = "noop"
    options: ClassVar[dict[str, str]] = {}

    def act(self, obs: Observation) -> list[WireFluent]:
        return []


class RandomPlanner(Planner):
    """Random legal joint actions, as rddlsim's RandomConcurrentPolicy.

    Each turn, every action fluent in turn has its groundings tried in a
    random order; each is taken with probability 1/2 (with a random
    non-default value) and kept only if max-nondef-actions, the action
    preconditions and the state-action constraints still hold in the
    current state (`Simulator.random_actions`).

    POMDPs: the planner does not see the state, so it checks the constraints
    against the instance's initial state instead. For domains whose
    preconditions do not depend on the state (the usual case) the actions
    are legal everywhere; otherwise the server may refuse some of them.

    The generator is seeded once per session from the option `seed`, else
    from the session's seed (`--seed`), else from fresh entropy.
    """

    name: ClassVar[str] = "random"
    options: ClassVar[dict[str, str]] = {
        "seed": "integer seed for the random choices (default: the client's --seed, else unseeded)",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self.seed: int | None = self.int_option("seed")
        self.rng: np.random.Generator | None = None
        self._codec: WireCodec | None = None
        self._initial: State | None = None

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        seed = self.seed if self.seed is not None else session.seed
        self.rng = np.random.default_rng(seed)
        self._codec = WireCodec(session.simulator)
        self._initial = session.simulator.initial_state(1)

    def act(self, obs: Observation) -> list[WireFluent]:
        if self.session is None or self.rng is None or self._codec is None:
            raise PlannerError("random: act() called before start_session()")
        state = obs.state if obs.state is not None else self._initial
        assert state is not None
        try:
            arrays = self.session.simulator.random_actions(state, self.rng)
        except SimulationError as err:
            raise PlannerError(f"random: no legal action to choose: {err}") from err
        return self._codec.actions(arrays, index=0)
