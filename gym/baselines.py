"""`SB3VecEnv`: an `RDDLVectorEnv` behind stable-baselines3's `VecEnv`
interface, with the flat spaces of `FlatSpaces`, so that SB3's algorithms
train on n states stepped in one batched simulator call.

SB3's VecEnv resets an environment in the step where its episode ends: the
step returns the first observation of the next episode, and the info of that
environment holds the last one (`terminal_observation`) and whether the
horizon cut the episode (`TimeLimit.truncated`). That is Gymnasium's
same-step autoreset, which the RDDLVectorEnv underneath runs in.

This module needs stable-baselines3 (`pip install 'ippc[rl]'`); `ippc.gym`
does not import it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)

from ..rddl.model import Model
from .flat import MAX_ACTIONS, FlatSpaces
from .vector import RDDLVectorEnv

__all__ = ["SB3VecEnv"]


class SB3VecEnv(VecEnv):
    """n states of one RDDL instance as a stable-baselines3 `VecEnv`.

    >>> envs = SB3VecEnv("SysAdmin_MDP_ippc2011", "1", num_envs=8)
    >>> model = stable_baselines3.PPO("MlpPolicy", VecMonitor(envs))

    `domain` and `instance` are `RDDLVectorEnv`'s (or `domain` an
    `RDDLVectorEnv` made with `autoreset_mode=AutoresetMode.SAME_STEP`);
    `actions` and `max_actions` choose the flat action space (`FlatSpaces`).
    The n environments are one object: `get_attr` and `env_method` reach the
    RDDLVectorEnv, once per index asked for.
    """

    def __init__(
        self,
        domain: str | os.PathLike[str] | Model | RDDLVectorEnv,
        instance: str | int | None = None,
        *,
        num_envs: int = 1,
        actions: str = "auto",
        max_actions: int = MAX_ACTIONS,
        illegal_actions: str = "noop",
        streams: str = "per_state",
    ) -> None:
        if isinstance(domain, RDDLVectorEnv):
            if domain.autoreset_mode != AutoresetMode.SAME_STEP:
                raise ValueError(
                    "SB3VecEnv needs an RDDLVectorEnv made with "
                    "autoreset_mode=AutoresetMode.SAME_STEP (SB3 resets in the step that ends)"
                )
            self.vector_env = domain
        else:
            self.vector_env = RDDLVectorEnv(
                domain,
                instance,
                num_envs=num_envs,
                illegal_actions=illegal_actions,
                autoreset_mode=AutoresetMode.SAME_STEP,
                streams=streams,
            )
        self.flat = FlatSpaces(self.vector_env._inst, actions, max_actions)
        self.render_mode = None
        super().__init__(
            self.vector_env.num_envs, self.flat.observation_space, self.flat.action_space
        )
        self._actions: dict[str, np.ndarray] | None = None

    def reset(self) -> VecEnvObs:
        seeds = list(self._seeds)
        seed: list[int | None] | None = None if all(s is None for s in seeds) else seeds
        obs, _ = self.vector_env.reset(seed=seed)
        self._reset_seeds()
        self._reset_options()
        return self.flat.observations(obs)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = self.flat.actions(actions, self.num_envs)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        obs, rewards, terminated, truncated, info = self.vector_env.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        illegal = np.asarray(info.get("illegal_action", np.zeros(self.num_envs, bool)))
        infos: list[dict[str, Any]] = [
            {"illegal_action": bool(illegal[i]), "TimeLimit.truncated": False}
            for i in range(self.num_envs)
        ]
        if dones.any():
            final_obs = info["final_obs"]
            final_illegal = info["final_info"]["illegal_action"]
            for i in np.flatnonzero(dones):
                infos[i] = {
                    "illegal_action": bool(final_illegal[i]),
                    "TimeLimit.truncated": bool(truncated[i] and not terminated[i]),
                    "terminal_observation": self.flat.observation(final_obs[i]),
                }
        return (
            self.flat.observations(obs),
            np.asarray(rewards, dtype=np.float32),
            dones,
            infos,
        )

    def close(self) -> None:
        self.vector_env.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.vector_env, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.vector_env, attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        method = getattr(self.vector_env, method_name)
        return [method(*method_args, **method_kwargs) for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        # the environments are not gymnasium.Env objects, so no wrapper wraps them
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
