"""`RDDLVectorEnv`: n states of one RDDL instance as a `gymnasium.vector.VectorEnv`,
stepped together in one batched simulator call.

Its environment i behaves exactly as an `RDDLEnv` reset with the same seed
(`reset(seed=s)` seeds environment i with s + i, as Gymnasium's
`SyncVectorEnv` does): observations, rewards, terminations, truncations and
infos are those of a `SyncVectorEnv` over n `RDDLEnv`s, in each of Gymnasium's
autoreset modes (`tests/gym/test_vector.py` compares the two). With
`streams="per_state"` (the default) each state draws from its own generator
(`streams.PerStateGenerator`); `streams="batch"` draws the whole batch from
one generator (seeded by `reset(seed=s)`), a little faster on large batches,
reproducible, but no longer equal to single environments.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..rddl.model import Model
from ..rddl.simulator import State
from .env import IllegalActionError, _Instance
from .streams import PerStateGenerator

__all__ = ["STREAMS", "RDDLVectorEnv"]

STREAMS = ("per_state", "batch")


class RDDLVectorEnv(VectorEnv[dict[str, Any], dict[str, Any], np.ndarray]):
    """`num_envs` states of one RDDL instance, stepped in one batched call.

    >>> envs = RDDLVectorEnv("SysAdmin_MDP_ippc2011", "1", num_envs=256)
    >>> obs, info = envs.reset(seed=0)      # obs["running___c1"].shape == (256,)
    >>> obs, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())

    The arguments are `RDDLEnv`'s, and `num_envs`, `autoreset_mode`
    (Gymnasium's `AutoresetMode`; next-step by default) and `streams`.
    """

    metadata = {"render_modes": ["ansi"], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        domain: str | os.PathLike[str] | Model,
        instance: str | int | None = None,
        *,
        num_envs: int = 1,
        illegal_actions: str = "noop",
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        streams: str = "per_state",
        render_mode: str | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, not {num_envs}")
        if streams not in STREAMS:
            raise ValueError(f"streams must be one of {', '.join(STREAMS)}, not {streams!r}")
        if render_mode is not None and render_mode != "ansi":
            raise ValueError(f"render_mode must be None or 'ansi', not {render_mode!r}")
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = render_mode
        self.num_envs = num_envs
        self.streams = streams
        self._inst = inst = _Instance(domain, instance, illegal_actions)
        self.model = inst.model
        self.simulator = inst.sim
        self.horizon = inst.horizon
        self.single_observation_space = inst.obs_codec.space
        self.single_action_space = inst.act_codec.space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        n = num_envs
        self._initial = self.simulator.initial_state(1)
        self._state: State = self.simulator.initial_state(n)
        self._steps = np.zeros(n, dtype=np.int64)
        self._rewards = np.full(n, np.nan)  # the last reward of each, for render (nan: none yet)
        self._done = np.zeros(n, dtype=bool)  # ended: reset at the next step (next-step mode)
        self._generators: list[np.random.Generator | None] = [None] * n
        self._all: PerStateGenerator | None = None  # the generators of every state
        self._observation = (
            {k: np.repeat(v, n, axis=0) for k, v in inst.first_observation.items()}
            if inst.pomdp
            else None
        )

    @property
    def state(self) -> State:
        """The current states, a batch of `num_envs`."""
        return self._state

    # -- helpers ---------------------------------------------------------

    def _observe(self) -> dict[str, np.ndarray]:
        codec = self._inst.obs_codec
        if self._observation is not None:
            return codec.encode_batch(self._observation)
        return codec.encode_batch(self._state.values)

    def _observe_one(self, i: int) -> dict[str, Any]:
        codec = self._inst.obs_codec
        if self._observation is not None:
            return codec.encode_one(self._observation, i)
        return codec.encode_one(self._state.values, i)

    def _sync(self) -> None:
        """Before a generator is used on its own: the outputs the batch's
        streams drew ahead go back (see `streams.PerStateGenerator.sync`)."""
        if self._all is not None:
            self._all.sync()

    def _generator(self, i: int) -> np.random.Generator:
        g = self._generators[i]
        if g is None:
            g, _ = seeding.np_random(None)
            self._generators[i] = g
        return g

    def _restart(self, rows: np.ndarray) -> None:
        """Put the states `rows` (a bool mask) back at the initial state."""
        values = {}
        for k, v in self._state.values.items():
            v = v.copy()
            v[rows] = self._initial.values[k][0]
            values[k] = v
        self._state = State(values)
        if self._observation is not None:
            for k, v in self._observation.items():
                v[rows] = self._inst.first_observation[k][0]
        self._steps[rows] = 0
        self._rewards[rows] = np.nan

    # -- the API ---------------------------------------------------------

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, int | np.integer):
            super().reset(seed=int(seed))
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"{len(seeds)} seeds for {n} environments")
        rows = np.ones(n, dtype=bool)
        if options and "reset_mask" in options:
            rows = np.asarray(options["reset_mask"])
            if rows.shape != (n,) or rows.dtype != np.bool_ or not rows.any():
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({n},) with a True"
                )
        if any(seeds[i] is not None for i in np.flatnonzero(rows)):
            self._sync()
            self._all = None
        for i in np.flatnonzero(rows):
            if seeds[i] is not None:
                self._generators[i], _ = seeding.np_random(seeds[i])
        if self.streams == "batch" and seed is None and self._np_random is None:
            self._np_random, self._np_random_seed = seeding.np_random(None)
        self._restart(rows)
        self._done[rows] = False
        return self._observe(), {}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        inst = self._inst
        sim = self.simulator
        n = self.num_envs
        arrays, nondef = inst.act_codec.decode_batch(actions, n)
        mode = self.autoreset_mode
        if mode == AutoresetMode.DISABLED and self._done.any():
            raise RuntimeError(
                f"environment {int(np.argmax(self._done))} has ended: reset it first "
                "(reset(options={'reset_mask': mask}) with autoreset disabled)"
            )
        resetting = self._done.copy() if mode == AutoresetMode.NEXT_STEP else np.zeros(n, bool)
        active = ~resetting
        rewards = np.zeros(n)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        illegal = ~inst.legal(self._state, arrays, nondef) & active
        stepping = active.copy()
        if illegal.any():
            first = int(np.argmax(illegal))
            if inst.illegal_actions == "raise":
                raise IllegalActionError(
                    f"environment {first}: {inst.why_illegal(self._state, arrays, first)}"
                )
            if inst.illegal_actions == "end":
                stepping &= ~illegal
                truncated |= illegal
                self._rewards[illegal] = 0.0
            else:
                noop = sim.noop(n)
                arrays = {k: np.where(_rows(illegal, v), noop[k], v) for k, v in arrays.items()}
                nondef = np.where(illegal, 0, nondef)
                self._sync()
                for i in np.flatnonzero(~inst.legal(self._state, arrays, nondef) & illegal):
                    # noop is illegal there too: a legal action drawn as an
                    # RDDLEnv draws it, from this environment's generator
                    rng = self._generator(int(i)) if self.streams == "per_state" else self.np_random
                    try:
                        one = inst.replacement(self._state, int(i), rng)
                    except IllegalActionError as err:
                        raise IllegalActionError(f"environment {i}: {err}") from None
                    for k in arrays:
                        arrays[k][i] = one[k][0]
        if stepping.any():
            self._advance(stepping, arrays, rewards, terminated, truncated)
        if resetting.any():
            self._restart(resetting)
        ended = terminated | truncated
        infos: dict[str, Any] = {}
        if mode == AutoresetMode.SAME_STEP and ended.any():
            final = np.full(n, None, dtype=object)
            for i in np.flatnonzero(ended):
                final[i] = self._observe_one(int(i))
            infos["final_obs"], infos["_final_obs"] = final, ended.copy()
            infos["final_info"] = {
                "illegal_action": illegal & ended,
                "_illegal_action": ended.copy(),
            }
            infos["_final_info"] = ended.copy()
            self._restart(ended)
            reported = active & ~ended
        else:
            reported = active
        if reported.any():
            infos["illegal_action"] = illegal & reported
            infos["_illegal_action"] = reported
        self._done = ended if mode != AutoresetMode.SAME_STEP else np.zeros(n, dtype=bool)
        return self._observe(), rewards, terminated, truncated, infos

    def _advance(
        self,
        rows: np.ndarray,
        arrays: dict[str, np.ndarray],
        rewards: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
    ) -> None:
        """One batched step of the states `rows` (a bool mask)."""
        sim = self.simulator
        every = bool(rows.all())
        idx = np.flatnonzero(rows)
        state = self._state if every else self._state[idx]
        acts = arrays if every else {k: v[idx] for k, v in arrays.items()}
        rng: Any
        if self.streams == "per_state":
            if every:
                if self._all is None:
                    self._all = PerStateGenerator(
                        [self._generator(i) for i in range(self.num_envs)]
                    )
                rng = self._all
            else:
                self._sync()
                gens = [self._generator(int(i)) for i in idx]
                rng = gens[0] if len(gens) == 1 else PerStateGenerator(gens, ahead=0)
        else:
            rng = self.np_random
        out = sim.step(state, acts, rng, check=self._inst.check_step)
        if every:
            self._state = out.next_state
        else:
            values = {}
            for k, v in self._state.values.items():
                v = v.copy()
                v[idx] = out.next_state.values[k]
                values[k] = v
            self._state = State(values)
        if self._observation is not None and out.observation is not None:
            for k, v in self._observation.items():
                v[idx] = out.observation[k]
        self._steps[idx] += 1
        rewards[idx] = out.reward
        terminated[idx] = out.done
        if self.horizon is not None:
            truncated[idx] = ~out.done & (self._steps[idx] >= self.horizon)
        self._rewards[idx] = out.reward

    def render(self) -> tuple[str, ...] | None:  # type: ignore[override]
        if self.render_mode is None:
            return None
        return tuple(
            self._inst.render_text(
                self._state,
                i,
                int(self._steps[i]),
                None if np.isnan(self._rewards[i]) else float(self._rewards[i]),
            )
            for i in range(self.num_envs)
        )


def _rows(mask: np.ndarray, like: np.ndarray) -> np.ndarray:
    """A (batch,) mask shaped to broadcast against a batch-first array."""
    return mask.reshape(-1, *([1] * (like.ndim - 1)))
