"""Flat spaces for the libraries that take only Box, Discrete, MultiBinary and
MultiDiscrete (stable-baselines3 among them): `FlatSpaces` and `FlatRDDLEnv`.

Observations become one `Box` of float32, one entry per key of the Dict
observation, in its order (a Discrete key's value, a Box key's number); the
bounds are the keys' bounds.

Actions become one of three spaces, chosen by `actions` ("auto" picks the
first that applies):

* "discrete": `Discrete(k)` over the legal joint actions, noop first. It
  applies where the constraints (action-preconditions, state-action
  constraints) read no state fluent, so that the legal joint actions are the
  same in every state: they are enumerated once, by `ippc.rddl.legal` (its
  constraint solver, with max-nondef-actions as a budget of non-default
  values), and the space applies only where that enumeration is exact and has
  at most `max_actions` members (4096 by default). Every index is then legal
  in every state. Noop comes first (where it is legal); the others follow by
  their number of non-default values, then by which keys (in the Dict's
  order) they set and to what.
* "multibinary": `MultiBinary(n)`, one bit per action grounding, where every
  action fluent is a bool.
* "box": `Box(low, high, (n,), float32)`, one entry per action grounding:
  a bool, enum, object or int entry is rounded to the nearest integer, and
  every entry is clipped to its key's bounds.

A MultiBinary or Box action that the constraints forbid in the current state
(more non-default values than max-nondef-actions, a precondition broken) is
not stepped: the environment's `illegal_actions` decides what happens
instead (noop by default), and `info["illegal_action"]` says it happened.
"""

from __future__ import annotations

import logging
import os
from typing import Any, SupportsFloat

import gymnasium
import numpy as np
from gymnasium import spaces

from ..rddl.legal import LegalActions, solver_for
from ..rddl.model import Model
from .env import RDDLEnv, _Instance

__all__ = ["ACTION_SPACES", "MAX_ACTIONS", "FlatRDDLEnv", "FlatSpaces"]

log = logging.getLogger(__name__)

#: The flat action spaces, in the order "auto" tries them.
ACTION_SPACES = ("discrete", "multibinary", "box")
#: The most joint actions a Discrete action space enumerates by default.
MAX_ACTIONS = 4096


def _bounds(space: spaces.Space[Any]) -> tuple[float, float]:
    """The lowest and highest value of one key's space."""
    if isinstance(space, spaces.Discrete):
        return float(space.start), float(space.start + space.n - 1)
    assert isinstance(space, spaces.Box)
    return float(space.low), float(space.high)


class FlatSpaces:
    """The flat observation and action spaces of an instance, and the
    translation between them and the Dict values of `RDDLEnv` (one value) and
    `RDDLVectorEnv` (a batch)."""

    def __init__(
        self, inst: _Instance, actions: str = "auto", max_actions: int = MAX_ACTIONS
    ) -> None:
        if actions != "auto" and actions not in ACTION_SPACES:
            raise ValueError(
                f"actions must be 'auto' or one of {', '.join(ACTION_SPACES)}, not {actions!r}"
            )
        if max_actions < 1:
            raise ValueError(f"max_actions must be at least 1, not {max_actions}")
        self.obs_keys = list(inst.obs_codec.keys)
        obs_spaces = inst.obs_codec.space.spaces
        low, high = zip(*(_bounds(obs_spaces[k]) for k in self.obs_keys), strict=True)
        self.observation_space = spaces.Box(
            np.array(low, dtype=np.float32),
            np.array(high, dtype=np.float32),
            shape=(len(self.obs_keys),),
            dtype=np.float32,
        )
        self.act_keys = list(inst.act_codec.keys)
        act_spaces = inst.act_codec.space.spaces
        self._act_low, self._act_high = (
            np.array(b, dtype=np.float64)
            for b in zip(*(_bounds(act_spaces[k]) for k in self.act_keys), strict=True)
        )
        real = {g for f in inst.act_codec.fluents if f.p.range == "real" for g in f.keys}
        self._integral = np.array([k not in real for k in self.act_keys])
        all_bool = all(f.p.range == "bool" for f in inst.act_codec.fluents)
        self.table: dict[str, np.ndarray] = {}
        """Discrete: each key's value in each of the joint actions (keys whose
        value is the default in all of them are left out)."""
        self.why_not_discrete = ""
        kind = actions
        if actions in ("auto", "discrete"):
            self.why_not_discrete = self._enumerate(inst, max_actions)
            if not self.why_not_discrete:
                kind = "discrete"
            elif actions == "discrete":
                raise ValueError(f"no Discrete action space: {self.why_not_discrete}")
            else:
                kind = "multibinary" if all_bool else "box"
        if kind == "multibinary" and not all_bool:
            raise ValueError("a MultiBinary action space needs every action fluent to be a bool")
        self.kind = kind
        self.action_space: spaces.Space[Any]
        if kind == "discrete":
            self.action_space = spaces.Discrete(self.size)
        elif kind == "multibinary":
            self.action_space = spaces.MultiBinary(len(self.act_keys))
        else:
            self.action_space = spaces.Box(
                self._act_low.astype(np.float32),
                self._act_high.astype(np.float32),
                shape=(len(self.act_keys),),
                dtype=np.float32,
            )

    def _enumerate(self, inst: _Instance, max_actions: int) -> str:
        """Fill `table` with the legal joint actions; or say why they cannot be."""
        sim = inst.sim
        if not LegalActions.supports(sim):
            return "real-valued action fluents cannot be enumerated"
        solver = solver_for(sim)
        if solver.reads:
            return (
                "the legal joint actions depend on the state (the constraints read "
                + ", ".join(solver.reads)
                + ")"
            )
        state = sim.initial_state(1)
        space = solver.space(state)
        if not space.exact:
            return "the legal joint actions cannot be counted exactly"
        if space.count > max_actions:
            return f"{space.count} legal joint actions, more than max_actions={max_actions}"
        arrays = solver.enumerate(state, limit=max_actions)
        self.size = int(next(iter(arrays.values())).shape[0]) if arrays else 1
        if self.size == 0:
            return "no joint action is legal"
        noop = sim.noop(1)
        columns: list[tuple[str, np.ndarray, int]] = []
        for f in inst.act_codec.fluents:
            if f.p.name not in arrays:
                continue
            values = np.asarray(arrays[f.p.name]).reshape(self.size, -1).astype(np.int64)
            default = np.asarray(noop[f.p.name]).reshape(-1).astype(np.int64)
            for j, key in enumerate(f.keys):
                if (values[:, j] != default[j]).any():
                    columns.append((key, values[:, j], int(default[j])))
        # a fixed order, whatever the solver's: noop first, then by the number of
        # non-default values, then by which keys (in the Dict's order) and their values
        changed = [
            tuple((c, int(v[r])) for c, (_, v, d) in enumerate(columns) if v[r] != d)
            for r in range(self.size)
        ]
        order = sorted(range(self.size), key=lambda r: (len(changed[r]), changed[r]))
        self.table = {key: v[order].copy() for key, v, _ in columns}
        # each index's Dict action with its non-default values only (the others
        # take their default): what one step decodes
        defaults = {key: d for key, _, d in columns}
        self._sparse = [
            {k: int(v[i]) for k, v in self.table.items() if v[i] != defaults[k]}
            for i in range(self.size)
        ]
        return ""

    size: int = 0
    """The number of joint actions of a Discrete action space."""
    _sparse: list[dict[str, int]] = []

    # -- observations -----------------------------------------------------

    def observation(self, obs: dict[str, Any]) -> np.ndarray:
        """The flat observation of one Dict observation."""
        return np.array([obs[k] for k in self.obs_keys], dtype=np.float32)

    def observations(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The (n, d) flat observations of a batched Dict observation."""
        return np.stack([np.asarray(obs[k]) for k in self.obs_keys], axis=1).astype(np.float32)

    # -- actions ---------------------------------------------------------

    def _matrix(self, action: Any, n: int | None) -> np.ndarray:
        """A MultiBinary or Box action (or a batch of n) as (n, keys) values."""
        a = np.asarray(action, dtype=np.float64)
        want = (len(self.act_keys),) if n is None else (n, len(self.act_keys))
        if a.shape != want:
            raise ValueError(f"an action of this space has shape {want}, not {a.shape}")
        if np.isnan(a).any():
            raise ValueError("an action holds NaN")
        a = np.clip(a, self._act_low, self._act_high)
        if self.kind == "multibinary":
            if ((a != 0) & (a != 1)).any():
                raise ValueError("a MultiBinary action holds values other than 0 and 1")
        a = np.where(self._integral, np.rint(a), a)
        return a.reshape(-1, len(self.act_keys))

    def _index(self, action: Any, n: int | None) -> np.ndarray:
        if n is None and type(action) is int and 0 <= action < self.size:
            return np.array([action])  # (the common case, without numpy's checks)
        a = np.asarray(action)
        want = () if n is None else (n,)
        integral = np.issubdtype(a.dtype, np.integer) or (
            np.issubdtype(a.dtype, np.floating) and bool(np.all(a == np.rint(a)))
        )
        if a.shape not in (want, (*want, 1)) or not integral:
            raise ValueError(
                f"an action of Discrete({self.size}) is an integer"
                + ("" if n is None else f" per environment, shape ({n},)")
                + f", not {action!r}"
            )
        a = a.reshape(-1).astype(np.int64)
        if ((a < 0) | (a >= self.size)).any():
            raise ValueError(f"an action of Discrete({self.size}) is in 0..{self.size - 1}")
        return a

    def action(self, action: Any) -> dict[str, Any]:
        """The Dict action of one flat action (of a Discrete index: its non-default
        values only, the keys left out taking their default)."""
        if self.kind == "discrete":
            return dict(self._sparse[int(self._index(action, None)[0])])
        row = self._matrix(action, None)[0]
        return {
            k: (int(v) if integral else float(v))
            for k, v, integral in zip(self.act_keys, row, self._integral, strict=True)
        }

    def actions(self, action: Any, n: int) -> dict[str, np.ndarray]:
        """The batched Dict action of n flat actions."""
        if self.kind == "discrete":
            idx = self._index(action, n)
            return {k: v[idx] for k, v in self.table.items()}
        mat = self._matrix(action, n)
        return {k: mat[:, j] for j, k in enumerate(self.act_keys)}


class FlatRDDLEnv(gymnasium.Env[np.ndarray, Any]):
    """An `RDDLEnv` with flat spaces (see the module docstring).

    >>> env = FlatRDDLEnv("SysAdmin_MDP_ippc2011", "1")
    >>> env.action_space, env.observation_space.shape
    (Discrete(11), (10,))

    `domain` and `instance` are `RDDLEnv`'s (or `domain` an `RDDLEnv`);
    `actions` is "auto", "discrete", "multibinary" or "box"; `max_actions`
    caps the size of a Discrete action space. `info["illegal_action"]` is
    `RDDLEnv`'s, and `action_masks()` says which Discrete actions are legal in
    the current state (all of them, where the space is Discrete).
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}

    def __init__(
        self,
        domain: str | os.PathLike[str] | Model | RDDLEnv,
        instance: str | int | None = None,
        *,
        actions: str = "auto",
        max_actions: int = MAX_ACTIONS,
        illegal_actions: str = "noop",
        render_mode: str | None = None,
    ) -> None:
        if isinstance(domain, RDDLEnv):
            self.env = domain
        else:
            self.env = RDDLEnv(
                domain, instance, illegal_actions=illegal_actions, render_mode=render_mode
            )
        self.render_mode = self.env.render_mode
        self.flat = FlatSpaces(self.env._inst, actions, max_actions)
        self.observation_space = self.flat.observation_space
        self.action_space = self.flat.action_space
        self.horizon = self.env.horizon

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        # one generator: the Dict environment's, which every step draws from
        self._np_random = self.env.np_random
        self._np_random_seed = self.env.np_random_seed
        return self.flat.observation(obs), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(self.flat.action(action))
        return self.flat.observation(obs), reward, terminated, truncated, info

    def action_masks(self) -> np.ndarray:
        """Which actions of a Discrete action space are legal in the current
        state (the interface of sb3-contrib's MaskablePPO)."""
        if self.flat.kind != "discrete":
            raise TypeError(f"action_masks() needs a Discrete action space, not {self.flat.kind}")
        inst = self.env._inst
        batch, _ = inst.act_codec.decode_batch(self.flat.table, self.flat.size)
        state = self.env.state[[0] * self.flat.size]
        return np.asarray(inst.legal(state, batch), dtype=bool)

    def render(self) -> str | None:  # type: ignore[override]
        return self.env.render()
