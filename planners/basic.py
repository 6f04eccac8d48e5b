"""The baseline planners: `noop`, `random` (rddlsim's RandomConcurrentPolicy)
and `uniform` (a uniformly drawn legal joint action)."""

from __future__ import annotations

import logging
import time
from typing import ClassVar

import numpy as np

from ..rddl.legal import LegalActions, solver_for
from ..rddl.simulator import SimulationError, Simulator, State
from ..rddl.wire import WireCodec
from .base import Observation, Planner, PlannerError, SessionInfo, WireFluent
from .budget import OneAtATime, guarded_turn, noop_legal
from .rddlsim_random import RandomConcurrentPolicy, Stuck

log = logging.getLogger(__name__)


class NoopPlanner(Planner):
    """Every action at its default, every turn (sends `<actions/>`-style noop)."""

    name: ClassVar[str] = "noop"
    options: ClassVar[dict[str, str]] = {}

    def act(self, obs: Observation) -> list[WireFluent]:
        return []


class RandomPlanner(Planner):
    """rddlsim's RandomConcurrentPolicy, choice for choice (the IPPC random
    baseline; see `ippc.planners.rddlsim_random`).

    With the same seed and the same states it sends what rddlsim's Java
    client sends with `rddl.policy.RandomConcurrentPolicy`, byte for byte:
    the action fluents in rddlsim's order, each fluent's groundings in a
    random order, each taken on a coin flip if the actions stay legal, at
    most min(20, max-nondef-actions) of them, drawn from commons-math3's
    Well19937c generator. One generator for the whole session, seeded with
    the option `seed`, else the client's `--seed`, else 0 (the Java
    client's default).

    Where rddlsim's policy gives up (no action found and noop illegal:
    "No actions satisfied state constraints, not even noop!", e.g. when a
    legal action needs several groundings at once) the planner raises
    `PlannerError` with that message and the session ends, as the Java
    client's does; with `when_stuck=legal` it sends a uniformly drawn legal
    joint action instead (`ippc.rddl.legal`) and goes on.

    POMDPs: no actions in a turn without observations (as Java); else the
    constraints are checked against the initial state, as the Java client's
    own state never leaves it.

    A turn whose choice is not made by the turn's deadline plus a margin
    (`budget.guarded_turn`) sends noop, with a warning (the choice goes on in
    the background, and the generator with it).
    """

    name: ClassVar[str] = "random"
    options: ClassVar[dict[str, str]] = {
        "seed": "integer seed of the Java generator (default: the client's --seed, else 0 as "
        "rddlsim's client)",
        "when_stuck": "stop (end the session where rddlsim's policy gives up, the default) or "
        "legal (send a uniformly drawn legal joint action there)",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self.seed: int | None = self.int_option("seed")
        stuck = (self.str_option("when_stuck", "stop") or "stop").strip().lower()
        if stuck not in ("stop", "legal"):
            raise self._option_error("when_stuck", stuck, "one of stop, legal")
        self.when_stuck = stuck
        self.policy: RandomConcurrentPolicy | None = None
        self._turns = OneAtATime("random: a turn")
        self._rng: np.random.Generator | None = None
        self._initial: State | None = None
        self._codec: WireCodec | None = None

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        seed = self.seed if self.seed is not None else (session.seed or 0)
        self.policy = RandomConcurrentPolicy(session.simulator, seed)
        self._turns = OneAtATime("random: a turn")
        self._rng = np.random.default_rng(seed)
        self._initial = session.simulator.initial_state(1)
        self._codec = WireCodec(session.simulator)

    def act(self, obs: Observation) -> list[WireFluent]:
        if self.session is None or self.policy is None or self._rng is None:
            raise PlannerError("random: act() called before start_session()")
        # (in a worker thread: where a choice takes longer than the turn, as on
        # RecSim 2023 #7's 125,000 groundings, the turn sends noop instead)
        return guarded_turn(
            self._turns,
            "random",
            obs.turn,
            obs.deadline,
            lambda: self._act(obs),
            noop_legal(self.session.simulator, obs.state),
        )

    def _act(self, obs: Observation) -> list[WireFluent]:
        assert self.session is not None and self.policy is not None
        if obs.state is not None:
            state: State | None = obs.state
        else:
            state = None if obs.fluents is None else self._initial
        try:
            return self.policy.choose(state)
        except Stuck as err:
            if self.when_stuck == "stop" or state is None:
                raise PlannerError(
                    f"random: turn {obs.turn}: {err} (rddlsim's RandomConcurrentPolicy stops "
                    "here; option when_stuck=legal sends a legal joint action instead)"
                ) from None
            log.warning(
                "random: turn %d: %s; sending a uniformly drawn legal action", obs.turn, err
            )
        assert self._codec is not None and self._rng is not None
        return _uniform_action(self.session.simulator, self._codec, state, self._rng, "random")


class UniformPlanner(Planner):
    """A joint action drawn uniformly from the legal ones, every turn
    (`ippc.rddl.legal`): a random baseline that acts wherever anything is
    legal. POMDPs: legality is judged in the initial state.

    The generator is seeded from the option `seed`, else the client's
    `--seed`, else fresh entropy.

    A draw runs in a worker thread until the turn's deadline: where drawing
    a legal joint action takes longer than the turn (RecSim 2023's 125,000
    legal joint actions), the turn sends noop, with a warning, and the late
    draw is left to finish before the next one starts."""

    name: ClassVar[str] = "uniform"
    options: ClassVar[dict[str, str]] = {
        "seed": "integer seed (default: the client's --seed, else unseeded)",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self.seed: int | None = self.int_option("seed")
        self._rng: np.random.Generator | None = None
        self._initial: State | None = None
        self._codec: WireCodec | None = None
        self._draws = OneAtATime("uniform: drawing a legal joint action")

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        self._draws = OneAtATime("uniform: drawing a legal joint action")
        self._rng = np.random.default_rng(self.seed if self.seed is not None else session.seed)
        self._initial = session.simulator.initial_state(1)
        self._codec = WireCodec(session.simulator)

    def act(self, obs: Observation) -> list[WireFluent]:
        if self.session is None or self._rng is None or self._initial is None:
            raise PlannerError("uniform: act() called before start_session()")
        state = obs.state if obs.state is not None else self._initial
        codec, rng, sim = self._codec, self._rng, self.session.simulator
        assert codec is not None
        ok, action = self._draws.call(
            lambda: _uniform_action(sim, codec, state, rng, "uniform"),
            obs.deadline - time.monotonic(),
        )
        if not ok:
            log.warning(
                "uniform: turn %d: no legal joint action drawn by the turn's deadline "
                "(%d late draws this session); sending noop",
                obs.turn,
                self._draws.late,
            )
            return []
        assert action is not None
        return action


def _uniform_action(
    sim: Simulator, codec: WireCodec, state: State, rng: np.random.Generator, who: str
) -> list[WireFluent]:
    """One uniformly drawn legal joint action of `state`, on the wire."""
    try:
        if LegalActions.supports(sim):
            arrays = solver_for(sim).sample(state, rng, 1)
        else:  # real-valued actions: coin flips (and their fallback)
            arrays = sim.random_actions(state, rng)
    except SimulationError as err:
        raise PlannerError(f"{who}: {err}") from None
    return codec.actions(arrays, index=0)
