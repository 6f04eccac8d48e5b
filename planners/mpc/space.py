"""The action space the model-predictive planner samples from, read from the
domain: every action grounding as a column of one of three blocks.

* *numbers*: the real and int groundings, with box bounds read from the
  action preconditions (a comparison of an action with an expression of
  constants and non-fluents, at the top of a precondition, under `^` and
  under `forall`; an int is rounded after sampling);
* *flags*: the bool groundings sampled one coin each;
* *choices*: groups of groundings of which one value is picked, sampled
  from a categorical distribution: every grounding of an enum action (one of
  its members), and the bool actions that a precondition
  `forall_{?x..} [sum_{?y} b(?x.., ?y) <= 1]` (RecSim's "one item per
  consumer") lets take at most one true value per group (the option 0 is
  "none").

A precondition that is read entirely as bounds or as "at most one" holds
by construction. Every other one is *checked*: `unhandled` names them, and
the planner tests every sampled action against them (the simulator's
`check_actions`). max-nondef-actions is kept by `limit_nondefault`, which
sets back to their default the groundings that depart least.
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass

import numpy as np

from ...rddl import ast as A
from ...rddl.model import NON_FLUENT, Model, PVariable
from ...rddl.simulator import Simulator

log = logging.getLogger(__name__)

Array = np.ndarray

# groundings of a forall walked at most when reading bounds
_MAX_BINDINGS = 200_000
_FLIP = {"<=": ">=", "<": ">", ">=": "<=", ">": "<"}


@dataclass(frozen=True)
class Column:
    """One action fluent's place in a block: columns `start:start+size`."""

    fluent: PVariable
    shape: tuple[int, ...]
    start: int

    @property
    def size(self) -> int:
        return math.prod(self.shape)


@dataclass(frozen=True)
class Choice:
    """One action fluent sampled as `groups` categorical draws of `options`
    values each: `onehot` (option k > 0 sets the group's grounding k-1 true)
    or an enum (option k is the member code k)."""

    fluent: PVariable
    shape: tuple[int, ...]
    groups: int
    options: int
    onehot: bool
    default: Array  # (groups,) the option each group takes by default


@dataclass
class Samples:
    """A batch of action sequences: `numbers` (n, h, R) floats, `flags`
    (n, h, B) bools, `choices` one (n, h, G) int array per `Choice`."""

    numbers: Array
    flags: Array
    choices: list[Array]

    @property
    def count(self) -> int:
        return int(self.numbers.shape[0])

    def take(self, index: Array | int) -> Samples:
        """The sequences at `index` (an int keeps a batch axis of one)."""
        if isinstance(index, (int, np.integer)):
            index = np.array([int(index)])
        return Samples(self.numbers[index], self.flags[index], [c[index] for c in self.choices])


class ActionSpace:
    """The action fluents of one simulator as blocks of columns, their
    bounds, and the preconditions not satisfied by construction."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        model = sim.model
        self.model = model
        defaults = {k: np.asarray(v[0]) for k, v in sim.noop(1).items()}
        self._defaults = defaults
        shapes = {
            p.name: tuple(len(model.objects(t)) for t in p.params) for p in sim.action_fluents
        }
        self.low: dict[str, Array] = {}
        self.high: dict[str, Array] = {}
        for p in sim.action_fluents:
            if p.range in ("int", "real"):
                self.low[p.name] = np.full(shapes[p.name], -np.inf)
                self.high[p.name] = np.full(shapes[p.name], np.inf)
        onehot: set[str] = set()
        self.unhandled: list[str] = []
        index = {t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()}
        reader = _Reader(model, index, self.low, self.high, onehot, shapes)
        for expr in [*model.domain.action_preconditions, *model.domain.state_action_constraints]:
            if not reader.walk(expr, {}):
                self.unhandled.append(_describe(expr))
        self.numbers: list[Column] = []
        self.flags: list[Column] = []
        self.choices: list[Choice] = []
        nums = flags = 0
        for p in sim.action_fluents:
            shape = shapes[p.name]
            if p.range in ("int", "real"):
                self.numbers.append(Column(p, shape, nums))
                nums += math.prod(shape)
            elif p.range == "bool" and p.name in onehot:
                groups = math.prod(shape[:-1])
                d = defaults[p.name].reshape(groups, shape[-1])
                first = np.where(d.any(axis=1), d.argmax(axis=1) + 1, 0)
                self.choices.append(Choice(p, shape, groups, shape[-1] + 1, True, first))
            elif p.range == "bool":
                self.flags.append(Column(p, shape, flags))
                flags += math.prod(shape)
            else:  # an enum: the codes of its members
                size = len(model.objects(p.range))
                code = defaults[p.name].reshape(-1).astype(np.int64)
                self.choices.append(Choice(p, shape, code.size, size, False, code))
        self.n_numbers, self.n_flags = nums, flags
        self.lower = self._flat(self.low, nums)
        self.upper = self._flat(self.high, nums)
        self.integral = np.zeros(nums, dtype=bool)
        self.number_default = np.zeros(nums)
        for c in self.numbers:
            self.integral[c.start : c.start + c.size] = c.fluent.range == "int"
            self.number_default[c.start : c.start + c.size] = defaults[c.fluent.name].reshape(-1)
        self.flag_default = np.zeros(flags, dtype=bool)
        for c in self.flags:
            self.flag_default[c.start : c.start + c.size] = defaults[c.fluent.name].reshape(-1)
        self.limit = model.max_nondef_actions
        groundings = nums + flags + sum(ch.groups for ch in self.choices)
        if self.limit is not None and self.limit >= groundings:
            self.limit = None  # never binding

    def _flat(self, bounds: dict[str, Array], size: int) -> Array:
        out = np.zeros(size)
        for c in self.numbers:
            out[c.start : c.start + c.size] = bounds[c.fluent.name].reshape(-1)
        return out

    # -- sizes ---------------------------------------------------------

    def bytes_per_step(self) -> int:
        """Bytes one sampled step of one sequence takes, with its draws."""
        cats = sum(ch.groups * (ch.options * 9 + 8) for ch in self.choices)
        acts = sum(v.nbytes for v in self._defaults.values())
        return 8 * 3 * self.n_numbers + 9 * self.n_flags + cats + acts

    def plan_bytes_per_step(self) -> int:
        """Bytes one step of a plan takes (its means, spreads, probabilities)."""
        return 8 * (
            3 * self.n_numbers + self.n_flags + sum(ch.groups * ch.options for ch in self.choices)
        )

    # -- values --------------------------------------------------------

    def clip(self, numbers: Array) -> Array:
        """Numbers inside their bounds, ints rounded (in place)."""
        if self.integral.any():
            numbers[..., self.integral] = np.round(numbers[..., self.integral])
        np.clip(numbers, self.lower, self.upper, out=numbers)
        return numbers

    def actions(self, samples: Samples, t: int) -> dict[str, Array]:
        """Step `t` of every sequence as the simulator's action arrays."""
        n = samples.count
        out: dict[str, Array] = {}
        for c in self.numbers:
            block = samples.numbers[:, t, c.start : c.start + c.size]
            if c.fluent.range == "int":
                block = block.astype(np.int64)
            out[c.fluent.name] = block.reshape(n, *c.shape)
        for c in self.flags:
            out[c.fluent.name] = samples.flags[:, t, c.start : c.start + c.size].reshape(
                n, *c.shape
            )
        for ch, drawn in zip(self.choices, samples.choices, strict=True):
            pick = drawn[:, t]
            if ch.onehot:
                arr = np.zeros((n, ch.groups, ch.options - 1), dtype=bool)
                rows, groups = np.nonzero(pick > 0)
                arr[rows, groups, pick[rows, groups] - 1] = True
                out[ch.fluent.name] = arr.reshape(n, *ch.shape)
            else:
                out[ch.fluent.name] = pick.reshape(n, *ch.shape).astype(np.int64)
        return out

    def noop(self, n: int, h: int) -> Samples:
        """`n` sequences of `h` noops."""
        return Samples(
            np.broadcast_to(self.number_default, (n, h, self.n_numbers)).copy(),
            np.broadcast_to(self.flag_default, (n, h, self.n_flags)).copy(),
            [np.broadcast_to(ch.default, (n, h, ch.groups)).copy() for ch in self.choices],
        )

    def limit_nondefault(self, samples: Samples) -> None:
        """Keep at most max-nondef-actions groundings away from their
        default in every step (in place): those departing least go back."""
        if self.limit is None:
            return
        span = np.where(np.isfinite(self.upper - self.lower), self.upper - self.lower, 1.0)
        parts = [np.abs(samples.numbers - self.number_default) / np.maximum(span, 1e-12)]
        parts.append((samples.flags != self.flag_default).astype(float))
        parts += [
            (c != ch.default).astype(float)
            for c, ch in zip(samples.choices, self.choices, strict=True)
        ]
        score = np.concatenate(parts, axis=-1)
        over = (score > 0).sum(axis=-1) > self.limit
        if not over.any():
            return
        rank = np.argsort(np.argsort(-score, axis=-1, kind="stable"), axis=-1)
        reset = (score > 0) & (rank >= self.limit) & over[..., None]
        r, f = self.n_numbers, self.n_flags
        samples.numbers[reset[..., :r]] = np.broadcast_to(
            self.number_default, reset[..., :r].shape
        )[reset[..., :r]]
        samples.flags[reset[..., r : r + f]] = np.broadcast_to(
            self.flag_default, reset[..., r : r + f].shape
        )[reset[..., r : r + f]]
        at = r + f
        for c, ch in zip(samples.choices, self.choices, strict=True):
            part = reset[..., at : at + ch.groups]
            c[part] = np.broadcast_to(ch.default, part.shape)[part]
            at += ch.groups


def _describe(e: A.Expr) -> str:
    loc = getattr(e, "loc", None)
    where = f"{loc.file}:{loc.line}:{loc.column}" if loc is not None and loc.line else "?"
    return f"the precondition at {where}"


class _Reader:
    """Reads bounds and "at most one" groups off the preconditions; `walk`
    says whether the constraint was read entirely (holds by construction)."""

    def __init__(
        self,
        model: Model,
        index: dict[str, dict[str, int]],
        low: dict[str, Array],
        high: dict[str, Array],
        onehot: set[str],
        shapes: dict[str, tuple[int, ...]],
    ) -> None:
        self.model, self.index = model, index
        self.low, self.high, self.onehot, self.shapes = low, high, onehot, shapes

    def walk(self, e: A.Expr, env: dict[str, str]) -> bool:
        if isinstance(e, A.Aggregation) and e.op == "forall":
            if self._at_most_one(e) and not env:
                return True
            members = [self.model.objects(v.type) for v in e.params]
            if math.prod(len(m) for m in members) > _MAX_BINDINGS:
                return False
            names = [v.name for v in e.params]
            ok = True
            for combo in itertools.product(*members):
                ok = self.walk(e.body, {**env, **dict(zip(names, combo, strict=True))}) and ok
            return ok
        if isinstance(e, A.Binary) and e.op == "^":
            left = self.walk(e.left, env)
            return self.walk(e.right, env) and left
        if isinstance(e, A.Binary) and e.op in _FLIP:
            if self._action(e.left, ("int", "real")):
                return self._bound(e.left, e.op, e.right, env)
            if self._action(e.right, ("int", "real")):
                return self._bound(e.right, _FLIP[e.op], e.left, env)
        return False

    def _action(self, e: A.Expr, ranges: tuple[str, ...]) -> bool:
        if not isinstance(e, A.PVar) or e.primed:
            return False
        p = self.model.pvariables.get(e.name)
        return p is not None and p.kind == "action-fluent" and p.range in ranges

    def _at_most_one(self, e: A.Aggregation) -> bool:
        """forall_{?x..} [sum_{?y} b(?x.., ?y) <= 1] over all of b's groundings."""
        body = e.body
        if not (isinstance(body, A.Binary) and body.op in ("<=", "<")):
            return False
        total, limit = body.left, body.right
        if not (
            isinstance(limit, A.Const) and float(limit.value) == (1.0 if body.op == "<=" else 2.0)
        ):
            return False
        if not (isinstance(total, A.Aggregation) and total.op == "sum" and len(total.params) == 1):
            return False
        b = total.body
        if not self._action(b, ("bool",)) or not isinstance(b, A.PVar):
            return False
        p = self.model.pvariables[b.name]
        names = [v.name for v in (*e.params, *total.params)]
        types = [v.type for v in (*e.params, *total.params)]
        args = [a.name if isinstance(a, A.Var) else None for a in b.args]
        if args != names or tuple(types) != p.params or p.default is True:
            return False
        self.onehot.add(p.name)
        return True

    def _bound(self, var: A.Expr, op: str, other: A.Expr, env: dict[str, str]) -> bool:
        assert isinstance(var, A.PVar)
        p = self.model.pvariables[var.name]
        idx = self._index(p, var.args, env)
        value = self._constant(other, env)
        if idx is None or value is None or math.isnan(value):
            return False
        integral = p.range == "int"
        if op in ("<=", "<"):
            if integral:
                value = math.floor(value) - (1 if op == "<" and value == math.floor(value) else 0)
            elif op == "<":
                value = math.nextafter(value, -math.inf)
            self.high[p.name][idx] = min(self.high[p.name][idx], value)
        else:
            if integral:
                value = math.ceil(value) + (1 if op == ">" and value == math.ceil(value) else 0)
            elif op == ">":
                value = math.nextafter(value, math.inf)
            self.low[p.name][idx] = max(self.low[p.name][idx], value)
        return True

    def _index(
        self, p: PVariable, args: tuple[A.Expr, ...], env: dict[str, str]
    ) -> tuple[int, ...] | None:
        if len(args) != p.arity:
            return None
        idx = []
        for a, t in zip(args, p.params, strict=True):
            name = env.get(a.name) if isinstance(a, A.Var) else getattr(a, "name", None)
            if not isinstance(a, (A.Var, A.ObjectLit, A.EnumLit)) or name not in self.index.get(
                t, {}
            ):
                return None
            idx.append(self.index[t][name])
        return tuple(idx)

    def _constant(self, e: A.Expr, env: dict[str, str]) -> float | None:
        """The value of an expression of constants and non-fluents, or None."""
        if isinstance(e, A.Const):
            return float(e.value)
        if isinstance(e, A.Unary) and e.op in ("-", "+"):
            v = self._constant(e.operand, env)
            return None if v is None else (-v if e.op == "-" else v)
        if isinstance(e, A.Binary) and e.op in ("+", "-", "*", "/"):
            a, b = self._constant(e.left, env), self._constant(e.right, env)
            if a is None or b is None or (e.op == "/" and b == 0):
                return None
            return {"+": a + b, "-": a - b, "*": a * b}.get(e.op, a / b if b else 0.0)
        if isinstance(e, A.PVar) and not e.primed:
            p = self.model.pvariables.get(e.name)
            if p is None or p.kind != NON_FLUENT or p.range not in ("int", "real", "bool"):
                return None
            names = []
            for a in e.args:
                name = env.get(a.name) if isinstance(a, A.Var) else getattr(a, "name", None)
                if name is None:
                    return None
                names.append(name)
            if len(names) != p.arity:
                return None
            return float(self.model.value_of(e.name, tuple(names)))  # type: ignore[arg-type]
        return None
