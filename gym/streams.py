"""One random stream per state of a batch, in one batched step: `PerStateGenerator`.

`Simulator.step` takes one `numpy.random.Generator` for the whole batch, and
the draws of state b of a batch of n are not those a batch of one would make
with the same generator. So that environment i of a VectorEnv makes exactly
the draws of a single RDDLEnv seeded as it is (and the VectorEnv's
trajectories are those of n single environments), the VectorEnv gives the
step a stand-in for the generator: it answers each draw the step asks for
with the draws of n generators, one per state, laid out where the batched
step reads them, so that state b's values are what generator b alone would
give a batch of one.

This follows the simulator's documented layout of draws (`ippc.rddl.sim`'s
docstring): the uniforms of every Bernoulli come first, in one request for
slots x n raw 32-bit numbers laid out (slot, state) and read from raw 64-bit
outputs cut in two; `standard_normal` is drawn batch last, (*scope, n); every
other draw (`random` and the distributions of `sim.samplers`) batch first,
(n, *scope), with its parameters broadcast to that shape. A draw made any
other way raises `TypeError` naming it. `tests/gym/test_vector.py` holds the
batched step to these rules against single environments, for the
distributions the corpus uses.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np

__all__ = ["PerStateGenerator"]

# Generator methods the simulator's samplers call with a batch-first size
# as their last argument (and parameters before it, broadcast to that size)
_BATCH_FIRST = frozenset(
    {
        "random",
        "uniform",
        "exponential",
        "poisson",
        "gamma",
        "weibull",
        "beta",
        "binomial",
        "negative_binomial",
        "pareto",
        "gumbel",
        "laplace",
        "standard_cauchy",
        "geometric",
        "standard_t",
        "chisquare",
    }
)


class _RawStreams:
    """The `bit_generator` of a `PerStateGenerator`: `random_raw` for the
    Bernoulli uniforms."""

    def __init__(self, owner: PerStateGenerator) -> None:
        self.owner = owner

    def random_raw(self, size: int) -> np.ndarray:
        gens = self.owner.generators
        n = len(gens)
        # the step asked for ceil(slots * n / 2) outputs: slots is the one
        # multiple of n in [2 * size - 1, 2 * size]
        slots = (2 * size) // n
        if not 2 * size - 1 <= slots * n <= 2 * size:
            raise TypeError(f"random_raw({size}) is not a request for whole slots of {n} states")
        raw = self.owner.take((slots + 1) >> 1)  # (n, per_state) outputs
        # (state, slot) -> (slot, state), the layout of the batched step
        flat = np.ascontiguousarray(raw.view(np.uint32)[:, :slots].T).reshape(-1)
        if flat.size & 1:
            flat = np.concatenate([flat, np.zeros(1, dtype=np.uint32)])
        return flat.view(np.uint64)


class PerStateGenerator:
    """Stands in for a `numpy.random.Generator` in `Simulator.step` on a batch
    of `len(generators)` states: state b draws from `generators[b]` exactly
    what a batch of one would draw from it."""

    def __init__(self, generators: Sequence[np.random.Generator], ahead: int = 32) -> None:
        self.generators = list(generators)
        self._bitgens = [g.bit_generator for g in self.generators]
        self._raw = [bg.random_raw for bg in self._bitgens]
        # raw outputs are drawn for `ahead` steps at once (a call per
        # generator per step costs more than the step), while the steps draw
        # nothing else; PCG64 can be put back where the draws made so far
        # leave it (`sync`)
        self.ahead = ahead if all(type(bg) is np.random.PCG64 for bg in self._bitgens) else 0
        self._buffer: np.ndarray | None = None
        self._used = 0
        self._saved: list[dict[str, Any]] = []
        self.bit_generator = _RawStreams(self)

    def take(self, per_state: int) -> np.ndarray:
        """The next `per_state` raw outputs of every generator, (n, per_state)."""
        if not self.ahead:
            return np.stack([f(per_state) for f in self._raw])
        buffer = self._buffer
        if buffer is None or self._used + per_state > buffer.shape[1]:
            self.sync()
            self._saved = [dict(bg.state) for bg in self._bitgens]
            buffer = self._buffer = np.stack([f(per_state * self.ahead) for f in self._raw])
        out = buffer[:, self._used : self._used + per_state]
        self._used += per_state
        return out

    def sync(self) -> None:
        """Put every generator where the draws taken so far leave it (the raw
        outputs drawn ahead and not taken are given back). Called before
        anything else draws from the generators."""
        buffer, self._buffer = self._buffer, None
        used, self._used = self._used, 0
        if buffer is None or used == buffer.shape[1]:
            return  # (every output drawn was taken: the generators are there)
        for bg, saved in zip(self._bitgens, self._saved, strict=True):
            bg.state = saved
            if used:
                cast(np.random.PCG64, bg).advance(used)
                if saved["has_uint32"]:  # (advance drops a buffered 32-bit half)
                    state = dict(bg.state)
                    state["has_uint32"], state["uinteger"] = 1, saved["uinteger"]
                    bg.state = state

    def standard_normal(self, size: Any = None) -> np.ndarray:
        self.sync()
        self.ahead = 0  # (the steps draw otherwise too: no drawing ahead)
        shape = _shape(size)
        n = len(self.generators)
        if not shape or shape[-1] != n:
            raise TypeError(f"standard_normal{shape}: expected the batch ({n}) last")
        out = np.empty(shape)
        for b, g in enumerate(self.generators):
            out[..., b] = g.standard_normal(shape[:-1])
        return out

    def __getattr__(self, name: str) -> Callable[..., np.ndarray]:
        if name not in _BATCH_FIRST:
            raise AttributeError(f"PerStateGenerator has no per-state {name!r} draw")

        def draw(*args: Any) -> np.ndarray:
            self.sync()
            self.ahead = 0
            *params, size = args
            shape = _shape(size)
            n = len(self.generators)
            if not shape or shape[0] != n:
                raise TypeError(f"{name}(..., {shape}): expected the batch ({n}) first")
            full = [np.broadcast_to(np.asarray(p), shape) for p in params]
            parts = [
                getattr(g, name)(*(p[b] for p in full), shape[1:])
                for b, g in enumerate(self.generators)
            ]
            return np.stack([np.asarray(x) for x in parts])

        return draw


def _shape(size: Any) -> tuple[int, ...]:
    if size is None:
        return ()
    if isinstance(size, int | np.integer):
        return (int(size),)
    return tuple(int(s) for s in size)
