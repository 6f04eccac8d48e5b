"""`RDDLEnv`: one RDDL instance as a `gymnasium.Env`, and what it shares with
`RDDLVectorEnv` (`_Instance`: the model, simulator, codecs, the legality
check of actions and the text view of a state).
"""

from __future__ import annotations

import logging
import os
from typing import Any, SupportsFloat

import gymnasium
import numpy as np

from ..rddl.legal import LegalActionsUnsupported, NoLegalAction, solver_for
from ..rddl.model import Model
from ..rddl.simulator import SimulationError, Simulator, State
from .load import resolve_model
from .spaces import FluentCodec

__all__ = ["ILLEGAL_ACTIONS", "IllegalActionError", "RDDLEnv"]

log = logging.getLogger(__name__)

#: What an environment does with an action the constraints forbid (a
#: precondition, a state-action constraint or max-nondef-actions): step the
#: noop instead (where noop is illegal too, as in ChromaticDice, a legal joint
#: action drawn uniformly with the environment's generator), raise
#: `IllegalActionError`, or end the episode there (truncated, reward 0, the
#: state unchanged), as rddlsim's server ends the round.
ILLEGAL_ACTIONS = ("noop", "raise", "end")


class IllegalActionError(SimulationError):
    """An action the instance's constraints forbid (the message names the
    constraint, its place in the file and the actions)."""


class _Instance:
    """What an RDDLEnv and an RDDLVectorEnv share: the model, the simulator,
    the observation and action codecs, the legality check and the text view."""

    def __init__(
        self,
        domain: str | os.PathLike[str] | Model,
        instance: str | int | None,
        illegal_actions: str,
    ) -> None:
        if illegal_actions not in ILLEGAL_ACTIONS:
            raise ValueError(
                f"illegal_actions must be one of {', '.join(ILLEGAL_ACTIONS)}, not {illegal_actions!r}"
            )
        self.illegal_actions = illegal_actions
        model = self.model = resolve_model(domain, instance)
        sim = self.sim = Simulator(model)
        dom = model.domain
        self.pomdp = bool(sim.observ_fluents)
        self.observed = sim.observ_fluents if self.pomdp else sim.state_fluents
        self.obs_codec = FluentCodec(
            model, self.observed, () if self.pomdp else dom.state_invariants
        )
        self.act_codec = FluentCodec(
            model,
            sim.action_fluents,
            [*dom.action_preconditions, *dom.state_action_constraints],
            sim.noop(1),
        )
        # the observation before the first step of a POMDP: every observ
        # fluent at its default (rddlsim sends none on the first turn)
        self.first_observation = {
            p.name: np.full(
                (1, *(len(model.objects(t)) for t in p.params)),
                _code(model, p.range, model.default_of(p)),
                dtype=np.float64 if p.range == "real" else np.int64,
            )
            for p in sim.observ_fluents
        }
        self.horizon = model.horizon
        self.limit = model.max_nondef_actions
        self.preconditions = bool(dom.action_preconditions or dom.state_action_constraints)
        # the actions are checked here, before the step; the step checks the
        # state invariants (and, with them, the actions again)
        self.check_step = bool(dom.state_invariants)

    def legal(self, state: State, actions: dict[str, np.ndarray], nondef: Any = None) -> np.ndarray:
        """A (batch,) mask of the states where `actions` are legal; `nondef`,
        the number of non-default actions of each, if known."""
        if self.preconditions or nondef is None:
            return self.sim.check_actions(state, actions)
        ok = np.ones(state.batch, dtype=bool)
        if self.limit is not None:
            ok &= np.asarray(nondef) <= self.limit
        return ok

    def why_illegal(self, state: State, actions: dict[str, np.ndarray], index: int) -> str:
        """The simulator's message for the illegal actions of state `index`
        (the constraint, its place in the file, the actions)."""
        one = {k: v[index : index + 1] for k, v in actions.items()}
        try:
            # (the step checks the actions before it uses its draws; a
            # generator of its own leaves the environment's untouched)
            self.sim.step(state[index], one, np.random.default_rng(0), check=True)
        except SimulationError as err:
            return str(err)
        return "the actions are illegal"

    def replacement(
        self, state: State, index: int, rng: np.random.Generator
    ) -> dict[str, np.ndarray]:
        """The actions stepped instead of illegal ones in state `index`: noop,
        or where noop is illegal, a uniformly drawn legal joint action."""
        noop = self.sim.noop(1)
        if bool(self.legal(state[index], noop, 0)[0]):
            return noop
        try:
            return solver_for(self.sim).sample(state, rng, 1, index)
        except (NoLegalAction, LegalActionsUnsupported) as err:
            raise IllegalActionError(
                f"the action is illegal and so is noop, and no legal action was found: {err}; "
                + self.why_illegal(state, noop, 0 if state.batch == 1 else index)
            ) from None

    def render_text(self, state: State, index: int, step: int, reward: float | None) -> str:
        """The 'ansi' view: the step, the last reward, and every state fluent."""
        head = f"{self.model.name}  step {step}" + (f"/{self.horizon}" if self.horizon else "")
        if reward is not None:
            head += f"  reward {reward:g}"
        lines = [head]
        for name, value in self.sim.state_to_names(state, index).items():
            shown = ("true" if value else "false") if isinstance(value, bool) else str(value)
            lines.append(f"  {name} = {shown}")
        return "\n".join(lines) + "\n"


def _code(model: Model, range_: str, value: Any) -> Any:
    """A value as the simulator holds it (an enum or object as its index)."""
    if range_ in ("bool", "int", "real"):
        return value
    return model.objects(range_).index(value)


class RDDLEnv(gymnasium.Env[dict[str, Any], dict[str, Any]]):
    """One RDDL instance as a Gymnasium environment, over ippc's simulator.

    >>> env = RDDLEnv("SysAdmin_MDP_ippc2011", "1")
    >>> obs, info = env.reset(seed=0)
    >>> obs, reward, terminated, truncated, info = env.step({"reboot___c1": 1})

    `domain` and `instance` name the instance (see `load.resolve_model`):
    files, a folder and an instance name, an rddlrepository problem and an
    instance number, or a `Model`. Observations and actions are `Dict`s keyed
    by grounded fluent names (`spaces`); a POMDP observes its observ-fluents.
    An episode is truncated at the instance's horizon and terminated where the
    domain's `termination` holds. `illegal_actions` says what an action the
    constraints forbid does (`ILLEGAL_ACTIONS`); `info["illegal_action"]` says
    whether the action given was illegal. The random draws come from
    `np_random`, seeded by `reset(seed=...)`.
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        domain: str | os.PathLike[str] | Model,
        instance: str | int | None = None,
        *,
        illegal_actions: str = "noop",
        render_mode: str | None = None,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'ansi', not {render_mode!r}")
        self.render_mode = render_mode
        self._inst = _Instance(domain, instance, illegal_actions)
        self.model = self._inst.model
        self.simulator = self._inst.sim
        self.observation_space = self._inst.obs_codec.space
        self.action_space = self._inst.act_codec.space
        self.horizon = self._inst.horizon
        self._state: State = self.simulator.initial_state(1)
        self._step = 0
        self._reward: float | None = None
        self._over = True

    @property
    def state(self) -> State:
        """The current state (a batch of one), also in a POMDP."""
        return self._state

    def _observe(self, observation: dict[str, np.ndarray] | None) -> dict[str, Any]:
        if self._inst.pomdp:
            return self._inst.obs_codec.encode_one(observation or self._inst.first_observation)
        return self._inst.obs_codec.encode_one(self._state.values)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        self._state = self.simulator.initial_state(1)
        self._step = 0
        self._reward = None
        self._over = False
        self._last_observation = None
        return self._observe(None), {}

    def step(
        self, action: dict[str, Any]
    ) -> tuple[dict[str, Any], SupportsFloat, bool, bool, dict[str, Any]]:
        inst = self._inst
        arrays, nondef = inst.act_codec.decode_one(action)
        if self._over:
            log.warning("step() after the episode ended: call reset() first; stepping on")
        if inst.preconditions:
            illegal = not bool(inst.legal(self._state, arrays)[0])
        else:
            illegal = inst.limit is not None and nondef > inst.limit
        if illegal:
            if inst.illegal_actions == "raise":
                raise IllegalActionError(inst.why_illegal(self._state, arrays, 0))
            if inst.illegal_actions == "end":
                self._over = True
                self._reward = 0.0
                return (
                    self._observe(self._last_observation),
                    0.0,
                    False,
                    True,
                    {"illegal_action": True},
                )
            arrays = inst.replacement(self._state, 0, self.np_random)
        out = self.simulator.step(self._state, arrays, self.np_random, check=inst.check_step)
        self._state = out.next_state
        self._last_observation = out.observation
        self._step += 1
        reward = float(out.reward[0])
        self._reward = reward
        terminated = bool(out.done[0])
        truncated = not terminated and self.horizon is not None and self._step >= self.horizon
        self._over = terminated or truncated
        return (
            self._observe(out.observation),
            reward,
            terminated,
            truncated,
            {"illegal_action": illegal},
        )

    _last_observation: dict[str, np.ndarray] | None = None

    def render(self) -> str | None:  # type: ignore[override]
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() without a render_mode: make the env with render_mode='ansi'"
            )
            return None
        return self._inst.render_text(self._state, 0, self._step, self._reward)
