"""Episodes of a policy on the simulator, all episodes stepped as one batch."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .model import Model
from .simulator import SimulationError, Simulator

POLICIES = ("noop", "random")


@dataclass(frozen=True)
class EpisodeStats:
    instance: str
    episodes: int
    returns: np.ndarray  # (episodes,) discounted return, as rddlsim's round reward
    steps: int  # transitions simulated, over all episodes
    seconds: float

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))

    @property
    def std_return(self) -> float:
        return float(np.std(self.returns, ddof=1)) if len(self.returns) > 1 else 0.0

    @property
    def steps_per_second(self) -> float:
        return self.steps / self.seconds if self.seconds > 0 else float("inf")

    def as_dict(self) -> dict[str, object]:
        return {
            "instance": self.instance,
            "episodes": self.episodes,
            "mean_return": self.mean_return,
            "std_return": self.std_return,
            "steps": self.steps,
            "steps_per_second": self.steps_per_second,
        }


def run_episodes(
    model: Model,
    policy: str = "noop",
    episodes: int = 1,
    seed: int = 0,
    horizon: int | None = None,
    simulator: Simulator | None = None,
) -> EpisodeStats:
    """Run `episodes` episodes of `policy` to the horizon (or termination).

    Raises `SimulationError` when the policy's actions are illegal or the
    domain cannot be simulated (the message says where and why).
    """
    if policy not in POLICIES:
        raise ValueError(f"unknown policy '{policy}' (choose from {', '.join(POLICIES)})")
    steps_to_run = horizon if horizon is not None else model.horizon
    if steps_to_run is None:
        raise SimulationError(f"instance '{model.name}' has no finite horizon; give one")
    sim = simulator or Simulator(model)
    rng = np.random.default_rng(seed)
    state = sim.initial_state(episodes)
    returns = np.zeros(episodes)
    alive = np.ones(episodes, dtype=bool)
    discount = 1.0
    steps = 0
    start = time.perf_counter()
    for _ in range(steps_to_run):
        # (noop: no arrays at all, every action takes its default)
        actions = None if policy == "noop" else sim.random_actions(state, rng)
        out = sim.step(state, actions, rng)
        returns += np.where(alive, discount * out.reward, 0.0)
        steps += int(alive.sum())
        alive &= ~out.done
        discount *= model.discount
        state = out.next_state
        if not alive.any():
            break
    seconds = time.perf_counter() - start
    return EpisodeStats(model.name, episodes, returns, steps, seconds)
