"""The simulator's public types: `State`, `Step`, `Prepared` and
`SimulationError`, and `_make_step` (a `Step` built fast).

Owns nothing but these containers; imports only numpy. Every other module
of the package may use them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

Array = np.ndarray


class SimulationError(Exception):
    """A step cannot be taken: a constraint is violated, or a distribution
    was given parameters outside its domain. The message names the
    constraint (with its place in the file), the grounding and the actions."""


class State:
    """A batch of states: one array per state fluent, batch axis first.

    Cheap to copy (`copy`) and to index (`state[i]`, `state[mask]`).
    """

    __slots__ = ("values",)

    def __init__(self, values: dict[str, Array]):
        self.values = values

    @property
    def batch(self) -> int:
        for v in self.values.values():
            return v.shape[0]  # type: ignore[no-any-return]
        return 1

    def copy(self) -> State:
        return State({k: v.copy() for k, v in self.values.items()})

    def __getitem__(self, index: Any) -> State:
        out = {}
        for k, v in self.values.items():
            x = v[index]
            if isinstance(index, (int, np.integer)):
                x = x[None]
            out[k] = x
        return State(out)

    def __repr__(self) -> str:
        return f"State(batch={self.batch}, fluents={len(self.values)})"


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
