"""rddlsim's `RandomConcurrentPolicy`, choice for choice.

The IPPC random baseline is rddlsim's Java policy
`rddl.policy.RandomConcurrentPolicy` run by rddlsim's Java client; IPPC
scores are normalised by it, so a baseline that differs changes every
score. This is that policy, with its order and its random numbers
(`javarandom`: commons-math3's `Well19937c`, seeded as the Java client
seeds it, 0 unless told otherwise), so the same seed and the same states
give the same actions as the Java client sends, in the same order.

Each turn (`RandomConcurrentPolicy.choose`):

* k = min(20, max-nondef-actions) actions at most (rddlsim's
  MAX_CONCURRENT_ACTIONS = 20 for max-nondef-actions = pos-inf);
* the action fluents in rddlsim's order (`rddlsim_action_order`: Java
  HashMap order of the pvariable names), each fluent's groundings in the
  order of a random permutation (`permute`) of their row-major order;
* for each grounding a coin (`next_uniform(0, 1) < 0.5` skips it), else a
  value: true for bool (even where the default is true), an int in 0..5,
  a real in (-5, 5), one of an enum's values (any, its default included);
  the entry is kept if the list so far passes max-nondef-actions and every
  precondition and state-action constraint (entries equal to the default
  are kept too, count towards k, and are sent, as Java sends them);
* the search stops once the list holds k entries;
* an empty list when noop is illegal is rddlsim's dead end: `Stuck`
  ("No actions satisfied state constraints, not even noop!").

A turn without a state (a POMDP's first turn) gets no actions and draws no
numbers, as in Java; in a POMDP the constraints are checked against the
initial state, as the Java client's own state never changes from it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rddl.model import PVariable, Value
from ..rddl.simulator import SimulationError, Simulator, State
from ..rddl.wire import rddlsim_action_order
from .javarandom import RandomDataGenerator

MAX_CONCURRENT_ACTIONS = 20  # rddlsim's cap for max-nondef-actions = pos-inf
MAX_INT_VALUE = 5  # ints are drawn in 0..MAX_INT_VALUE
MAX_REAL_VALUE = 5.0  # reals in (-MAX_REAL_VALUE, MAX_REAL_VALUE)
_JAVA_INT_MAX = 2**31 - 1

STUCK_MESSAGE = "No actions satisfied state constraints, not even noop!"

WireFluent = tuple[str, tuple[str, ...], Value]


class Stuck(SimulationError):
    """rddlsim's policy found no legal action, not even noop (the Java
    client stops there)."""


@dataclass(frozen=True)
class _Grounding:
    args: tuple[str, ...]
    index: tuple[int, ...]


class RandomConcurrentPolicy:
    """rddlsim's RandomConcurrentPolicy over a compiled simulator."""

    def __init__(self, sim: Simulator, seed: int = 0) -> None:
        self.sim = sim
        self.rng = RandomDataGenerator(seed)
        model = sim.model
        self.order: list[tuple[PVariable, list[_Grounding]]] = []
        for p in rddlsim_action_order(model):
            members = [model.types[t].members for t in p.params]
            sizes = [range(len(m)) for m in members]
            grounds = [
                _Grounding(tuple(m[i] for m, i in zip(members, idx, strict=True)), tuple(idx))
                for idx in np.ndindex(*[len(s) for s in sizes])
            ]
            self.order.append((p, grounds))
        limit = model.max_nondef_actions
        self.k = min(MAX_CONCURRENT_ACTIONS, _JAVA_INT_MAX if limit is None else limit)
        self._codes = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }

    def _value(self, p: PVariable) -> tuple[Value, bool | int | float]:
        """A random value of `p` as Java's getRandomValue draws it: (wire
        value, array value)."""
        if p.range == "bool":
            return True, True
        if p.range == "int":
            v = self.rng.next_int(0, MAX_INT_VALUE)
            return v, v
        if p.range == "real":
            x = self.rng.next_uniform(-MAX_REAL_VALUE, MAX_REAL_VALUE)
            return x, x
        members = self.sim.model.types[p.range].members
        try:
            i = self.rng.next_int(0, len(members) - 1)
        except ValueError:
            # Java's nextInt(0, 0) throws NumberIsTooLargeException and the client dies
            raise Stuck(
                f"rddlsim's random policy cannot draw a value of '{p.name}': its type "
                f"'{p.range}' has {len(members)} value(s) (Java's nextInt(0, {len(members) - 1}) "
                "throws)"
            ) from None
        return members[i], self._codes[p.range][members[i]]

    def choose(self, state: State | None) -> list[WireFluent]:
        """The actions for a turn in `state` (batch 1), in the order the
        Java client sends them; [] for no state. Raises `Stuck` where rddlsim
        gives up."""
        if state is None:
            return []
        sim = self.sim
        arrays = sim.noop(1)
        chosen: list[WireFluent] = []
        for p, grounds in self.order:
            perm = self.rng.permute(len(grounds))
            flat = arrays[p.name]
            for i in perm:
                if self.rng.next_uniform(0.0, 1.0) < 0.5:
                    continue
                wire, value = self._value(p)
                g = grounds[i]
                at = (0, *g.index)
                before = flat[at]
                flat[at] = value
                chosen.append((p.name, g.args, wire))
                if not bool(sim.check_actions(state, arrays)[0]):
                    flat[at] = before
                    chosen.pop()
                if len(chosen) == self.k:
                    break
            if len(chosen) == self.k:
                break
        if not chosen and not bool(sim.check_actions(state, sim.noop(1))[0]):
            raise Stuck(STUCK_MESSAGE)
        return chosen
