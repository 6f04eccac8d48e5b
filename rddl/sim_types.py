"""The types the simulator (`ippc.rddl.sim`) and the legal-action solver
(`ippc.rddl.legal`) share: `State`, a batch of states as arrays, `SimulationError`, and how
the simulator reads an enum value's name as a number (`int_enum_value`).

They live outside both packages so that imports run one way: the simulator calls the
solver (its random and legal actions), and the solver reads states and the model through
this module and a small interface of the simulator (`ippc.rddl.legal.solver.SimulatorView`),
never the `ippc.rddl.sim` package. `ippc.rddl.sim.state` re-exports `State` and
`SimulationError`. Imports only numpy.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["SimulationError", "State", "int_enum_value"]

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


def int_enum_value(name: str) -> int | None:
    """The integer an enum value's name stands for in arithmetic (`@3` -> 3), or None."""
    body = name[1:]
    try:
        return int(body)
    except ValueError:
        return None
