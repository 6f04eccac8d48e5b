"""The simulator's public types: `State`, `Step`, `Prepared` and
`SimulationError`, and `_make_step` (a `Step` built fast).

Owns nothing but these containers; imports only numpy and `ippc.rddl.sim_types`, where
`State` and `SimulationError` live (the legal-action solver, `ippc.rddl.legal`, uses them
too, and imports nothing of this package). Every other module of the package may use them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..sim_types import SimulationError, State

__all__ = ["Prepared", "SimulationError", "State", "Step"]

Array = np.ndarray


@dataclass(frozen=True)
class Step:
    """The outcome of `Simulator.step` for a batch."""

    next_state: State
    reward: Array  # (batch,)
    observation: dict[str, Array] | None  # observ fluents, POMDPs only
    done: Array  # (batch,) bool: termination holds in the next state


class Prepared:
    """The part of one state's next step that its actions do not decide
    (`Simulator.prepare`), waiting for them (`Simulator.finish`)."""

    __slots__ = ("state", "values", "rng_state")

    def __init__(self, state: State, values: tuple[Any, ...], rng_state: Any):
        self.state = state
        self.values = values
        self.rng_state = rng_state  # the bit generator's state before the draws


_new = object.__new__


def _make_step(
    nxt: dict[str, Array], reward: Array, obs: dict[str, Array] | None, done: Array
) -> Step:
    # what Step(State(nxt), reward, obs, done) makes, without the frozen
    # dataclass's setattr calls: a step is short
    out = _new(Step)
    fields = out.__dict__
    fields["next_state"] = State(nxt)
    fields["reward"] = reward
    fields["observation"] = obs
    fields["done"] = done
    return out
