"""Gymnasium spaces from an RDDL model, and the translation between their
values and the simulator's arrays: `FluentCodec`.

Every grounding of a fluent is one key of a `Dict` space, spelt as pyRDDLGym
spells grounded fluents: `name___obj1__obj2` (`name` for a fluent without
parameters). Each key's space follows the fluent's range:

    bool            Discrete(2)                          0 or 1
    enum, object    Discrete(number of values)           the value's index
    int, bounded    Discrete(high - low + 1, start=low)  the integer
    int             Box(low, high, (), int64)            int32's limits where unbounded
    real            Box(low, high, (), float64)          -inf / inf where unbounded

The bounds come from the constraints (`bounds.fluent_bounds`: preconditions
for the actions, state invariants for the states). Observations are numpy
ints for Discrete keys and 0-d arrays for Box keys, as
Gymnasium's checker expects; a batch (the VectorEnv's) holds one array of
shape (n,) per key. Actions may leave keys out: those take their default.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from ..rddl.model import Model, PVariable
from .bounds import fluent_bounds

__all__ = ["FluentCodec", "grounded_name"]

FLUENT_SEP = "___"
OBJECT_SEP = "__"
_INT_LOW = float(np.iinfo(np.int32).min)
_INT_HIGH = float(np.iinfo(np.int32).max)


def grounded_name(name: str, args: Sequence[str]) -> str:
    """pyRDDLGym's spelling of a grounded fluent: `name___obj1__obj2` (an enum
    value as an argument without its `@`)."""
    if not args:
        return name
    return name + FLUENT_SEP + OBJECT_SEP.join(a[1:] if a[:1] == "@" else a for a in args)


class _Fluent:
    """One fluent's keys, spaces and encoding."""

    __slots__ = ("p", "keys", "shape", "size", "sim_dtype", "gym_dtype", "box", "lo", "hi", "n")

    def __init__(self, p: PVariable, keys: list[str], shape: tuple[int, ...]) -> None:
        self.p = p
        self.keys = keys
        self.shape = shape
        self.size = len(keys)
        self.box = False
        self.lo = np.zeros(self.size)
        self.hi = np.ones(self.size)
        self.n = 2
        self.sim_dtype: Any = np.bool_
        self.gym_dtype: Any = np.int64


class FluentCodec:
    """The `Dict` space of some fluents of a model (the state, observ or
    action fluents) and the translation of its values from and to the
    simulator's batch-first arrays."""

    def __init__(
        self,
        model: Model,
        fluents: Iterable[PVariable],
        bounds_from: Iterable[Any] = (),
        defaults: Mapping[str, np.ndarray] | None = None,
    ) -> None:
        self.model = model
        fluents = list(fluents)
        bounds = fluent_bounds(model, bounds_from, fluents)
        self.fluents: list[_Fluent] = []
        self.where: dict[str, tuple[int, int]] = {}
        subspaces: dict[str, spaces.Space[Any]] = {}
        for p in fluents:
            shape = tuple(len(model.objects(t)) for t in p.params)
            keys = [grounded_name(p.name, args) for args in model.groundings(p)]
            f = _Fluent(p, keys, shape)
            if p.range == "bool":
                f.n = 2
            elif p.range in ("int", "real"):
                low, high = bounds[p.name]
                f.lo, f.hi = low.reshape(-1), high.reshape(-1)
                if p.range == "real":
                    f.box, f.sim_dtype, f.gym_dtype = True, np.float64, np.float64
                else:
                    f.sim_dtype = np.int64
                    f.box = not (np.isfinite(f.lo).all() and np.isfinite(f.hi).all())
                    if f.box:
                        f.lo = np.maximum(f.lo, _INT_LOW)
                        f.hi = np.minimum(f.hi, _INT_HIGH)
            else:  # enum or object: the index of the value
                f.n = len(model.objects(p.range))
                f.sim_dtype = np.int64
            if not f.box and p.range != "real" and p.range != "int":
                f.lo, f.hi = np.zeros(f.size), np.full(f.size, f.n - 1.0)
            for j, key in enumerate(keys):
                self.where[key] = (len(self.fluents), j)
                subspaces[key] = self._subspace(f, j)
            self.fluents.append(f)
        # (an OrderedDict keeps the declaration order: gymnasium sorts a plain dict's keys)
        self.space = spaces.Dict(OrderedDict(subspaces))
        self.keys = list(subspaces)
        defaults = defaults or {}
        # each fluent's defaults, flat: as the simulator holds them, and as floats
        self._defaults = [
            np.asarray(defaults[f.p.name]).reshape(-1).astype(f.sim_dtype)
            if f.p.name in defaults
            else np.zeros(f.size, dtype=f.sim_dtype)
            for f in self.fluents
        ]
        self._stage = [d.astype(np.float64) for d in self._defaults]
        self._default_values = [d.tolist() for d in self._defaults]

    @staticmethod
    def _subspace(f: _Fluent, j: int) -> spaces.Space[Any]:
        if f.p.range == "real":
            return spaces.Box(f.lo[j], f.hi[j], shape=(), dtype=np.float64)
        if f.p.range == "int":
            if f.box:
                return spaces.Box(int(f.lo[j]), int(f.hi[j]), shape=(), dtype=np.int64)
            lo, hi = int(f.lo[j]), int(f.hi[j])
            return spaces.Discrete(max(1, hi - lo + 1), start=lo)
        return spaces.Discrete(f.n)

    # -- observations ---------------------------------------------------

    def encode_one(self, arrays: Mapping[str, np.ndarray], index: int = 0) -> dict[str, Any]:
        """The Dict value of state `index` of batch-first arrays (fresh objects)."""
        out: dict[str, Any] = {}
        for f in self.fluents:
            flat = np.asarray(arrays[f.p.name][index]).reshape(-1).astype(f.gym_dtype)
            if f.box:
                for key, v in zip(f.keys, flat, strict=True):
                    out[key] = np.array(v)
            else:
                out.update(zip(f.keys, flat.tolist(), strict=True))
        return out

    def encode_batch(self, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The batched Dict value (one (n,) array per key) of batch-first arrays."""
        out: dict[str, np.ndarray] = {}
        for f in self.fluents:
            a = np.asarray(arrays[f.p.name])
            # (keys, batch): one fresh copy, each key's row a view of it
            rows = a.reshape(a.shape[0], -1).T.astype(f.gym_dtype, order="C")
            out.update(zip(f.keys, rows, strict=True))
        return out

    # -- actions --------------------------------------------------------

    def _bad(self, f: _Fluent, j: int, value: Any, env: int | None = None) -> ValueError:
        where = "" if env is None else f" (environment {env})"
        return ValueError(
            f"action {f.keys[j]!r}: {value!r} is not in {self._subspace(f, j)}{where}"
        )

    def _located(self, action: Mapping[str, Any]) -> Iterator[tuple[str, Any, tuple[int, int]]]:
        """(key, value, (fluent, grounding)) of each key of an action; a ValueError
        for something that is not a mapping or for a key that is not an action."""
        if not isinstance(action, Mapping):
            raise ValueError(
                f"an action is a dict of grounded action names to values, not {type(action).__name__}"
            )
        where = self.where
        for key, value in action.items():
            loc = where.get(key)
            if loc is None:
                raise ValueError(
                    f"unknown action {key!r} (actions: {', '.join(self.keys[:8])}, ...)"
                )
            yield key, value, loc

    def decode_one(self, action: Mapping[str, Any]) -> tuple[dict[str, np.ndarray], int]:
        """The simulator's arrays (a batch of one) of one Dict value of the
        action space, and how many of its values differ from their default.
        Keys left out take their default (and fluents with no key given are
        left out: the simulator fills in their defaults); an unknown key or a
        value outside its space is a ValueError."""
        touched: dict[int, np.ndarray] = {}
        nondef = 0
        for _key, value, (fi, j) in self._located(action):
            f = self.fluents[fi]
            try:
                if f.p.range == "real":
                    x: float | int = float(value)
                    ok = math.isfinite(x)
                else:
                    x = int(value)
                    ok = x == value and (f.box or f.lo[j] <= x <= f.hi[j])
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise self._bad(f, j, value)
            arr = touched.get(fi)
            if arr is None:
                arr = touched[fi] = self._defaults[fi].copy()
            arr[j] = x
            nondef += x != self._default_values[fi][j]
        fluents = self.fluents
        out = {fluents[fi].p.name: a.reshape(1, *fluents[fi].shape) for fi, a in touched.items()}
        return out, nondef

    def decode_batch(
        self, action: Mapping[str, Any], n: int
    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """`decode_one` for a batched Dict value (each key an array of n values,
        or one value for all n): the arrays, batch first, and the number of
        non-default values of each of the n actions."""
        touched: dict[int, np.ndarray] = {}
        for key, value, (fi, j) in self._located(action):
            s = touched.get(fi)
            if s is None:
                s = touched[fi] = np.repeat(self._stage[fi][None], n, axis=0)
            try:
                s[:, j] = value
            except (TypeError, ValueError) as err:
                raise ValueError(
                    f"action {key!r}: {value!r} is not a value of it ({err})"
                ) from None
        out = {}
        nondef = np.zeros(n, dtype=np.int64)
        for fi, s in touched.items():
            f = self.fluents[fi]
            if f.p.range == "real":
                bad = ~np.isfinite(s)
            elif f.box:
                bad = s != np.round(s)
            else:
                bad = (s != np.round(s)) | (s < f.lo) | (s > f.hi)
            if bad.any():
                b, j = (int(x[0]) for x in np.nonzero(bad))
                v = s[b, j].item()
                raise self._bad(f, j, int(v) if float(v).is_integer() else v, b)
            nondef += np.count_nonzero(s != self._stage[fi], axis=1)
            out[f.p.name] = s.astype(f.sim_dtype).reshape(n, *f.shape)
        return out, nondef
