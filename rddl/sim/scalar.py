"""The one-state step over Python scalars, for tree search.

A tree search steps one state with one action at a time; the batched step
(`Simulator.step`) spends most of such a step in numpy's per-call cost, a
microsecond or so per operation whatever the array's size. `ScalarStep`
writes the transition of one instance as one Python function over plain
scalars, grounded: one local variable per grounding of every state, action,
interm and next-state fluent, every aggregation unrolled over its objects,
and every subexpression that reads only non-fluents and constants folded
when the function is written (a sum over `CONNECTED(?d, ?c) ^ running(?d)`
keeps only the terms of the computers that are connected). States and
actions are tuples of Python values in a fixed order of groundings
(`state_keys`, `action_keys`); `encode_state` / `decode_state` convert from
and to the simulator's `State`.

Random draws: the function draws one block of uniforms (`rng.random(n)`)
and one of standard normals per call, one number per draw site and
grounding, in the order the sites are written; a Bernoulli(p) is `u < p`, a
Normal(m, v) is `m + sqrt(v) z`, a Discrete picks the first case whose
cumulative probability exceeds u. The draws are not the batched step's
(which draws raw 32-bit integers in its own layout), so the same seed gives
another trajectory; every draw is independent as there, so the successor
*distribution* is the same (`tests/rddl/test_scalar.py` compares the two).

What it does not do: the constraint checks (max-nondef-actions,
preconditions, state invariants: a search calls it with actions it knows
are legal, as `Simulator.step(..., check=False)`), parameter checks of the
distributions, and observations. A model outside what it writes raises
`ScalarUnsupported` when the step is built, naming the construct: the
caller keeps the batched step. Written: bool, int, real, enum and object
fluents; constants, variables, object and enum literals; every operator;
if and switch; sum, prod, avg, min, max, exists, forall; abs, sgn, exp,
ln, sqrt, pow, floor, ceil, round, min, max, the trigonometric functions;
Bernoulli, Normal, Discrete over listed cases, KronDelta, DiracDelta.
Enums whose values are numbers (@1, @2...) count as those numbers in
arithmetic, as in the batched step. Not written: fluent arguments computed
at run time (`at(next(?x))`), argmin/argmax, the other
distributions, matrix and vector constructs.

Imports the model, the AST and `state`; reads the simulator's arrays and
codes (non-fluents, defaults, the cpf order).
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import ast as A
from ..model import DERIVED, INTERM, OBSERV, STATE
from .state import Array, State

if TYPE_CHECKING:
    from .simulator import Simulator

__all__ = ["ScalarStep", "ScalarUnsupported"]


class ScalarUnsupported(Exception):
    """The model has a construct the scalar step does not write, or its
    grounded function would be too long (`MAX_SOURCE`)."""


# the longest grounded function written (characters), and the most terms
# of one unrolled aggregation: beyond them writing and compiling the
# function costs seconds, and the batched step does as well
MAX_SOURCE = 400_000
MAX_TERMS = 20_000


def _div(x: float, y: float) -> float:
    if y == 0:
        if x == 0 or x != x:
            return math.nan
        return math.copysign(math.inf, x) * (math.copysign(1.0, y))
    return x / y


def _ln(x: float) -> float:
    if x > 0:
        return math.log(x)
    return -math.inf if x == 0 else math.nan


def _sqrt(x: float) -> float:
    return math.sqrt(x) if x >= 0 else math.nan


def _pow(x: float, y: float) -> float:
    """C's pow (and numpy's power) over floats: nan for a negative base to a
    fractional power, a signed infinity on overflow or for 0 to a negative
    power."""
    x, y = float(x), float(y)
    try:
        return math.pow(x, y)
    except OverflowError:
        odd = y.is_integer() and y % 2 == 1
        return -math.inf if x < 0 and odd else math.inf
    except ValueError:
        if x == 0 and y < 0:
            odd = y.is_integer() and y % 2 == 1
            return math.copysign(math.inf, x) if odd else math.inf
        return math.nan


def _sgn(x: float) -> float:
    return (x > 0) - (x < 0)


def _round(x: float) -> float:
    return float(np.round(x))


def _exp(x: float) -> float:
    try:
        return math.exp(x)
    except OverflowError:
        return math.inf


def _discrete(u: float, probs: tuple[float, ...]) -> int:
    acc = 0.0
    for i, p in enumerate(probs):
        acc += p
        if u < acc:
            return i
    return len(probs) - 1


_HELPERS: dict[str, Any] = {
    "_div": _div,
    "_ln": _ln,
    "_sqrt": _sqrt,
    "_pow": _pow,
    "_sgn": _sgn,
    "_round": _round,
    "_exp": _exp,
    "_discrete": _discrete,
    "_floor": math.floor,
    "_ceil": math.ceil,
    "_cos": math.cos,
    "_sin": math.sin,
    "_tan": math.tan,
    "_acos": math.acos,
    "_asin": math.asin,
    "_atan": math.atan,
    "_cosh": math.cosh,
    "_sinh": math.sinh,
    "_tanh": math.tanh,
    "_inf": math.inf,
    "_nan": math.nan,
}

_UNARY = {
    "exp": "_exp", "ln": "_ln", "sqrt": "_sqrt", "floor": "_floor", "ceil": "_ceil",
    "round": "_round", "sgn": "_sgn", "abs": "abs", "cos": "_cos", "sin": "_sin",
    "tan": "_tan", "acos": "_acos", "asin": "_asin", "atan": "_atan", "cosh": "_cosh",
    "sinh": "_sinh", "tanh": "_tanh",
}  # fmt: skip

_NUMERIC = ("bool", "int", "real")


class _V:
    """A value being written: a constant (`const`), or Python source
    (`code`), with its RDDL type ('bool', 'int', 'real', or an enum or
    object type, whose values are codes)."""

    __slots__ = ("code", "const", "rtype")

    def __init__(self, rtype: str, code: str | None = None, const: Any = None):
        self.code = code
        self.const = const
        self.rtype = rtype

    @property
    def known(self) -> bool:
        return self.code is None

    def text(self) -> str:
        if self.code is not None:
            return self.code
        c = self.const
        if isinstance(c, float):
            if math.isnan(c):
                return "_nan"
            if math.isinf(c):
                return "_inf" if c > 0 else "(-_inf)"
        return repr(c)


def _num_type(a: str, b: str) -> str:
    return "real" if "real" in (a, b) else "int"


class _Writer:
    """Writes the scalar step of one simulator's model."""

    def __init__(self, sim: Simulator):
        model = sim.model
        self.sim = sim
        self.model = model
        c = sim._compiler
        # enums whose values count as numbers (@1, @2...): code -> number
        self.numeric_of_code = {t: tuple(int(x) for x in v) for t, v in c.numeric_of_code.items()}
        self.tables: dict[str, tuple[int, ...]] = {}
        if sim.observ_fluents:
            raise ScalarUnsupported("observations (a POMDP)")
        self.codes = c.codes
        self.members = {t: info.members for t, info in model.types.items()}
        self.lines: list[str] = []
        self.n_uniforms = 0
        self.n_normals = 0
        self.temps = 0
        # (name, primed) -> array of local names per grounding
        self.locals: dict[tuple[str, bool], Array] = {}
        self.nf = {p.name: sim._initial_array(p) for p in sim.non_fluents}
        self.defaults = {p.name: sim._default_array(p) for p in model.pvariables.values()}
        self.state_keys: list[tuple[str, tuple[int, ...]]] = []
        self.action_keys: list[tuple[str, tuple[int, ...]]] = []
        for p in sim.state_fluents:
            names = np.empty(c.shape_of(p), dtype=object)
            for idx in np.ndindex(*names.shape):
                names[idx] = f"s{len(self.state_keys)}"
                self.state_keys.append((p.name, idx))
            self.locals[(p.name, False)] = names
        for p in sim.action_fluents:
            names = np.empty(c.shape_of(p), dtype=object)
            for idx in np.ndindex(*names.shape):
                names[idx] = f"a{len(self.action_keys)}"
                self.action_keys.append((p.name, idx))
            self.locals[(p.name, False)] = names

    # -- values ------------------------------------------------------------

    def temp(self, v: _V) -> _V:
        """`v` in a local of its own (a value read more than once)."""
        if v.known:
            return v
        self.temps += 1
        name = f"t{self.temps}"
        self.lines.append(f"    {name} = {v.code}")
        return _V(v.rtype, name)

    def num(self, v: _V) -> _V:
        """`v` as a number: an enum value whose values are numbers (@3) as
        that number, as the batched step reads it in arithmetic."""
        table = self.numeric_of_code.get(v.rtype)
        if table is None:
            return v
        if v.known:
            return _V("int", const=table[int(v.const)])
        name = f"_N{list(self.numeric_of_code).index(v.rtype)}"
        self.tables[name] = table
        return _V("int", f"{name}[{v.code}]")

    def code_of(self, name: str, hint: str | None) -> tuple[int, str]:
        return self.sim._compiler.code_of(name, hint)  # type: ignore[no-any-return]

    def literal(self, a: A.Expr, t: str) -> int | None:
        """The code of an argument that names an object or enum value (the batched compiler's rule)."""
        return self.sim._compiler._literal_code(a, t)  # type: ignore[no-any-return]

    # -- expressions ---------------------------------------------------------

    def ev(self, e: A.Expr, env: Mapping[str, tuple[str, int]], hint: str | None = None) -> _V:
        if isinstance(e, A.Const):
            v = e.value
            t = "bool" if isinstance(v, bool) else "int" if isinstance(v, int) else "real"
            return _V(t, const=v)
        if isinstance(e, A.Var):
            t, i = env[e.name]
            return _V(t, const=i)
        if isinstance(e, (A.EnumLit, A.ObjectLit)):
            code, t = self.code_of(e.name, hint)
            return _V(t, const=code)
        if isinstance(e, A.PVar):
            return self.pvar(e, env, hint)
        if isinstance(e, A.Unary):
            x = self.num(self.ev(e.operand, env))
            if e.op == "~":
                return _V("bool", const=not x.const) if x.known else _V("bool", f"(not {x.code})")
            if e.op == "-":
                t = "int" if x.rtype == "bool" else x.rtype
                return _V(t, const=-x.const) if x.known else _V(t, f"(-{x.code})")
            return x
        if isinstance(e, A.Binary):
            return self.binary(e, env)
        if isinstance(e, A.If):
            cond = self.num(self.ev(e.cond, env))
            if cond.known:
                return self.ev(e.then if cond.const else e.else_, env, hint)
            yes = self.ev(e.then, env, hint)
            no = self.ev(e.else_, env, hint)
            rtype = _join(yes.rtype, no.rtype)
            return _V(rtype, f"({yes.text()} if {cond.code} else {no.text()})")
        if isinstance(e, A.Switch):
            return self.switch(e, env, hint)
        if isinstance(e, A.Aggregation):
            return self.aggregation(e, env)
        if isinstance(e, A.Function):
            return self.function(e, env)
        if isinstance(e, A.Distribution):
            return self.distribution(e, env, hint)
        if isinstance(e, A.Discrete):
            return self.discrete(e, env)
        raise ScalarUnsupported(f"{e.loc}: {type(e).__name__}")

    def pvar(self, e: A.PVar, env: Mapping[str, tuple[str, int]], hint: str | None) -> _V:
        p = self.model.pvariables.get(e.name)
        if p is None:
            name = e.name
            if hint in self.codes and "@" + name in self.codes[hint]:
                name = "@" + name
            obj, t = self.code_of(name, hint)
            return _V(t, const=obj)
        if e.default:
            d = self.model.default_of(p)
            if p.range in self.codes:
                return _V(p.range, const=self.codes[p.range][d])  # type: ignore[index]
            return _V(p.range, const=d)
        idx: list[int] = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, A.Var):
                idx.append(env[a.name][1])
                continue
            code: int | None = self.literal(a, t)
            if code is None:
                v = self.ev(a, env, t)
                if not v.known:
                    raise ScalarUnsupported(f"{a.loc}: an argument computed at run time")
                code = int(v.const)
            idx.append(code)
        if p.name in self.nf:
            value = self.nf[p.name][tuple(idx)]
            return _V(p.range, const=value.item())
        names = self.locals.get((p.name, e.primed))
        if names is None:
            raise ScalarUnsupported(f"{e.loc}: '{e.name}' read before it is computed")
        return _V(p.range, str(names[tuple(idx)]))

    def binary(self, e: A.Binary, env: Mapping[str, tuple[str, int]]) -> _V:
        op = e.op
        if op in ("^", "&", "|", "=>", "<=>"):
            x = self.num(self.ev(e.left, env))
            y = self.num(self.ev(e.right, env))
            if op in ("^", "&"):
                if x.known:
                    return _as_bool(y) if x.const else _V("bool", const=False)
                if y.known:
                    return _as_bool(x) if y.const else _V("bool", const=False)
                return _V("bool", f"({_as_bool(x).code} and {_as_bool(y).code})")
            if op == "|":
                if x.known:
                    return _V("bool", const=True) if x.const else _as_bool(y)
                if y.known:
                    return _V("bool", const=True) if y.const else _as_bool(x)
                return _V("bool", f"({_as_bool(x).code} or {_as_bool(y).code})")
            if op == "=>":
                if x.known:
                    return _as_bool(y) if x.const else _V("bool", const=True)
                if y.known and y.const:
                    return _V("bool", const=True)
                return _V("bool", f"((not {x.code}) or {_as_bool(y).text()})")
            if x.known and y.known:
                return _V("bool", const=bool(x.const) == bool(y.const))
            return _V("bool", f"(bool({x.text()}) == bool({y.text()}))")
        if op in ("==", "~="):
            x = self.ev(e.left, env)
            y = self.ev(e.right, env, x.rtype)
            lt, rt = x.rtype, y.rtype
            if (lt != rt and (lt in self.codes) != (rt in self.codes)) or (
                lt in self.codes and rt in self.codes and lt != rt
            ):
                # mixed forms: compared as numbers where an enum is numeric
                x = self.num(x)
                y = self.num(self.ev(e.right, env))
            if x.known and y.known:
                same = x.const == y.const
                return _V("bool", const=same if op == "==" else not same)
            py = "==" if op == "==" else "!="
            return _V("bool", f"({x.text()} {py} {y.text()})")
        x = self.num(self.ev(e.left, env))
        y = self.num(self.ev(e.right, env))
        if op in ("<", "<=", ">", ">="):
            if x.known and y.known:
                return _V("bool", const=bool(eval(f"{x.const!r} {op} {y.const!r}")))  # noqa: S307
            return _V("bool", f"({x.text()} {op} {y.text()})")
        if op in ("+", "-", "*", "/"):
            t = "real" if op == "/" else _num_type(x.rtype, y.rtype)
            if x.known and y.known:
                a, b = x.const, y.const
                if op == "+":
                    return _V(t, const=a + b)
                if op == "-":
                    return _V(t, const=a - b)
                if op == "*":
                    return _V(t, const=a * b)
                return _V(t, const=_div(float(a), float(b)))
            if op == "/":
                if y.known and y.const != 0:
                    return _V("real", f"({x.text()} / {float(y.const)!r})")
                return _V("real", f"_div({x.text()}, {y.text()})")
            return _V(t, f"({x.text()} {op} {y.text()})")
        raise ScalarUnsupported(f"{e.loc}: operator {op}")

    def switch(self, e: A.Switch, env: Mapping[str, tuple[str, int]], hint: str | None) -> _V:
        subject = self.temp(self.ev(e.subject, env))
        default: _V | None = None
        cases: list[tuple[_V, _V]] = []
        for case in e.cases:
            value = self.ev(case.value, env, hint)
            if case.label is None:
                default = value
                continue
            code = self.literal(case.label, subject.rtype)
            label = _V(subject.rtype, const=code) if code is not None else self.ev(case.label, env)
            if subject.known and label.known:
                if subject.const == label.const:
                    return value
                continue
            cases.append((label, value))
        out = default if default is not None else _V("real", "_nan")
        for label, value in reversed(cases):
            out = _V(
                _join(value.rtype, out.rtype),
                f"({value.text()} if {subject.text()} == {label.text()} else {out.text()})",
            )
        return out

    def aggregation(self, e: A.Aggregation, env: Mapping[str, tuple[str, int]]) -> _V:
        op = e.op
        if op in ("argmin", "argmax"):
            raise ScalarUnsupported(f"{e.loc}: {op}")
        names = [tv.name for tv in e.params]
        types = [tv.type for tv in e.params]
        count = math.prod(len(self.members[t]) for t in types)
        if count > MAX_TERMS:
            raise ScalarUnsupported(f"{e.loc}: an aggregation of {count} terms")
        terms: list[_V] = []
        for combo in itertools.product(*(range(len(self.members[t])) for t in types)):
            inner = dict(env)
            for n, t, i in zip(names, types, combo, strict=True):
                inner[n] = (t, i)
            terms.append(self.num(self.ev(e.body, inner)))
        count = len(terms)
        if op in ("exists", "forall"):
            want = op == "exists"  # the value that decides
            parts = []
            for term in terms:
                if term.known:
                    if bool(term.const) == want:
                        return _V("bool", const=want)
                    continue
                parts.append(str(term.code))
            if not parts:
                return _V("bool", const=not want)
            joiner = " or " if want else " and "
            return _V("bool", "(" + joiner.join(f"bool({p})" for p in parts) + ")")
        rtype = "int"
        for term in terms:
            rtype = _num_type(rtype, term.rtype)
        if op in ("sum", "avg"):
            known = sum(term.const for term in terms if term.known)
            parts = [str(term.code) for term in terms if not term.known]
            if op == "avg":
                rtype = "real"
            if not parts:
                total = _V(rtype, const=known)
            else:
                text = " + ".join(str(p) for p in parts)
                if known != 0 or len(parts) == 1:
                    text = f"{text} + {known!r}"
                total = _V(rtype, f"({text})")
            if op == "avg":
                if total.known:
                    return _V("real", const=total.const / count if count else math.nan)
                return _V("real", f"({total.code} / {float(count)!r})")
            return total
        if op == "prod":
            known = 1
            parts = []
            for term in terms:
                if term.known:
                    known *= term.const
                else:
                    parts.append(str(term.code))
            if not parts:
                return _V(rtype, const=known)
            return _V(rtype, "(" + " * ".join([*parts, repr(known)]) + ")")
        if op in ("min", "max"):
            if count == 0:
                return _V("real", const=math.inf if op == "min" else -math.inf)
            if all(t.known for t in terms):
                f = min if op == "min" else max
                return _V(rtype, const=f(t.const for t in terms))
            return _V(rtype, f"{op}(" + ", ".join(t.text() for t in terms) + ")")
        raise ScalarUnsupported(f"{e.loc}: aggregation {op}")

    def function(self, e: A.Function, env: Mapping[str, tuple[str, int]]) -> _V:
        args = [self.num(self.ev(a, env)) for a in e.args]
        name = e.name
        if name in ("min", "max") and len(args) == 2:
            t = _num_type(args[0].rtype, args[1].rtype)
            return _V(t, f"{name}({args[0].text()}, {args[1].text()})")
        if name in ("pow", "power") and len(args) == 2:
            return _V("real", f"_pow({args[0].text()}, {args[1].text()})")
        if name in _UNARY and len(args) == 1:
            x = args[0]
            t = "real"
            if name in ("abs", "sgn"):
                t = "int" if x.rtype in ("bool", "int") else "real"
            elif name in ("floor", "ceil", "round"):
                t = "int"
            return _V(t, f"{_UNARY[name]}({x.text()})")
        raise ScalarUnsupported(f"{e.loc}: function {name}")

    def distribution(
        self, e: A.Distribution, env: Mapping[str, tuple[str, int]], hint: str | None
    ) -> _V:
        name = e.name
        if name == "KronDelta":
            return self.ev(e.args[0], env, hint)
        if name == "DiracDelta":
            x = self.num(self.ev(e.args[0], env))
            return _V("real", const=float(x.const)) if x.known else _V("real", f"float({x.code})")
        if name == "Bernoulli":
            p = self.num(self.ev(e.args[0], env))
            if p.known and p.const in (0, 1):
                return _V("bool", const=bool(p.const))
            k = self.n_uniforms
            self.n_uniforms += 1
            return _V("bool", f"(U[{k}] < {p.text()})")
        if name == "Normal":
            m = self.num(self.ev(e.args[0], env))
            v = self.num(self.ev(e.args[1], env))
            k = self.n_normals
            self.n_normals += 1
            return _V("real", f"({m.text()} + _sqrt({v.text()}) * Z[{k}])")
        raise ScalarUnsupported(f"{e.loc}: distribution {name}")

    def discrete(self, e: A.Discrete, env: Mapping[str, tuple[str, int]]) -> _V:
        if e.count is not None or e.name != "Discrete":
            raise ScalarUnsupported(f"{e.loc}: {e.name}")
        codes: list[int] = []
        probs: list[str] = []
        for case in e.cases:
            code = self.literal(case.label, e.type)
            if code is None or case.prob is None:
                raise ScalarUnsupported(f"{e.loc}: a Discrete case that is not a value")
            codes.append(code)
            probs.append(self.num(self.ev(case.prob, env)).text())
        k = self.n_uniforms
        self.n_uniforms += 1
        table = "(" + ", ".join(map(str, codes)) + ",)"
        return _V(e.type, f"{table}[_discrete(U[{k}], ({', '.join(probs)},))]")

    # -- the function ----------------------------------------------------------

    def cast(self, v: _V, rng: str) -> str:
        """The value as the fluent's range stores it."""
        if v.known:
            c = v.const
            if rng == "bool":
                return repr(bool(c))
            if rng == "real":
                return _V("real", const=float(c)).text()
            return repr(int(c))
        if rng == "bool":
            return v.code if v.rtype == "bool" else f"bool({v.code})"  # type: ignore[return-value]
        if rng == "real":
            return v.code if v.rtype == "real" else f"float({v.code})"  # type: ignore[return-value]
        if rng == "int" or rng in self.codes:
            return v.code if v.rtype == rng or v.rtype == "int" else f"int({v.code})"  # type: ignore[return-value]
        return v.code  # type: ignore[return-value]

    def write(self) -> str:
        model, sim = self.model, self.sim
        body: list[str] = []
        self.lines = body
        n_next = 0
        size = 0
        next_names: list[str] = []
        for key in sim._cpf_order:
            p = model.pvariables[key.rstrip("'")]
            if p.kind == OBSERV:
                continue
            cp = model.cpfs[p.name]
            primed = p.kind == STATE
            shape = sim._compiler.shape_of(p)
            names = np.empty(shape, dtype=object)
            prefix = "n" if primed else "i"
            for idx in np.ndindex(*shape):
                env = {v: (t, i) for v, t, i in zip(cp.params, p.params, idx, strict=True)}
                value = self.ev(cp.expr, env, p.range)
                local = f"{prefix}{n_next}"
                n_next += 1
                line = f"    {local} = {self.cast(value, p.range)}"
                body.append(line)
                size += len(line)
                if size > MAX_SOURCE:
                    raise ScalarUnsupported(
                        f"the grounded function is longer than {MAX_SOURCE} characters"
                    )
                names[idx] = local
            self.locals[(p.name, primed)] = names
            if p.kind not in (STATE, INTERM, DERIVED):
                raise ScalarUnsupported(f"a cpf of kind {p.kind}")
        for p in sim.state_fluents:
            found = self.locals.get((p.name, True))
            if found is None:
                # (no cpf: the simulator keeps the default)
                found = self.locals[(p.name, False)]
            next_names.extend(str(found[idx]) for idx in np.ndindex(*found.shape))
        if model.reward is not None:
            reward = self.cast(self.num(self.ev(model.reward, {})), "real")
        else:
            reward = "0.0"
        body.append(f"    r = {reward}")
        # termination reads the next state as the current one
        for p in sim.state_fluents:
            primed_names = self.locals.get((p.name, True))
            if primed_names is not None:
                self.locals[(p.name, False)] = primed_names
        done = []
        for expr in sim._terminations:
            v = self.num(self.ev(expr, {}))
            done.append(v.text())
        body.append(f"    done = {' or '.join(f'bool({d})' for d in done) if done else 'False'}")
        head = ["def _scalar_step(S, A, rng):"]
        if self.state_keys:
            head.append(f"    ({', '.join(f's{i}' for i in range(len(self.state_keys)))},) = S")
        if self.action_keys:
            head.append(f"    ({', '.join(f'a{i}' for i in range(len(self.action_keys)))},) = A")
        if self.n_uniforms:
            head.append(f"    U = rng.random({self.n_uniforms}).tolist()")
        if self.n_normals:
            head.append(f"    Z = rng.standard_normal({self.n_normals}).tolist()")
        ret = f"    return ({', '.join(next_names)}{',' if len(next_names) == 1 else ''}), r, done"
        return "\n".join([*head, *body, ret]) + "\n"


def write_legal(sim: Simulator) -> tuple[str, dict[str, tuple[int, ...]]] | None:
    """`_scalar_legal(S, A)`: whether the model's action preconditions and
    state-action constraints hold for one state and one joint action (not
    max-nondef-actions), as Python source over the step's scalars, with the
    tables it reads; None when the model has no such constraint. Raises `ScalarUnsupported` as
    the step's writer does (or where a constraint reads an interm fluent
    or draws)."""
    constraints = sim._preconditions
    if not constraints:
        return None
    writer = _Writer(sim)
    body: list[str] = []
    writer.lines = body
    parts: list[str] = []
    for expr in constraints:
        v = _as_bool(writer.num(writer.ev(expr, {})))
        if v.known:
            if not v.const:
                parts = ["False"]
                break
            continue
        parts.append(str(v.code))
    if writer.n_uniforms or writer.n_normals:
        raise ScalarUnsupported("a constraint that draws")
    head = ["def _scalar_legal(S, A):"]
    if writer.state_keys:
        head.append(f"    ({', '.join(f's{i}' for i in range(len(writer.state_keys)))},) = S")
    if writer.action_keys:
        head.append(f"    ({', '.join(f'a{i}' for i in range(len(writer.action_keys)))},) = A")
    ret = f"    return {' and '.join(f'bool({p})' for p in parts) if parts else 'True'}"
    return "\n".join([*head, *body, ret]) + "\n", dict(writer.tables)


def _as_bool(v: _V) -> _V:
    if v.known:
        return _V("bool", const=bool(v.const))
    return v if v.rtype == "bool" else _V("bool", f"bool({v.code})")


def _join(a: str, b: str) -> str:
    if a == b:
        return a
    if a in _NUMERIC and b in _NUMERIC:
        return "real" if "real" in (a, b) else "int"
    return a


class ScalarStep:
    """The transition of one instance as one Python function over scalars
    (see the module docstring).

    >>> fast = ScalarStep(sim)
    >>> s = fast.encode_state(sim.initial_state(1))
    >>> nxt, reward, done = fast.step(s, fast.noop, rng)
    """

    def __init__(self, sim: Simulator):
        writer = _Writer(sim)
        self.source = writer.write()
        self.sim = sim
        self.state_keys = writer.state_keys
        self.action_keys = writer.action_keys
        self.draws = writer.n_uniforms + writer.n_normals
        self.n_uniforms = writer.n_uniforms
        self.n_normals = writer.n_normals
        self.tables = dict(writer.tables)
        """The lookup tables the source reads by name (enum values as numbers)."""
        self.legal_source: str | None = None
        """`_scalar_legal(S, A)`'s source (None: no constraint, or not written)."""
        self.legal: Callable[[tuple[Any, ...], tuple[Any, ...]], bool] | None = None
        """`legal(state, actions)`: the preconditions and state-action
        constraints (not max-nondef-actions); None where the model has none
        (`constrained` False) or they could not be written (`legal_error`)."""
        self.constrained = bool(sim._preconditions)
        self.legal_error: str | None = None
        written = None
        try:
            written = write_legal(sim)
        except ScalarUnsupported as err:
            self.legal_error = str(err)
        if written is not None:
            self.legal_source, legal_tables = written
            # (the same names as the step's: one table per numeric enum type)
            self.tables.update(legal_tables)
            lns: dict[str, Any] = dict(_HELPERS)
            lns.update(self.tables)
            code = compile(self.legal_source, f"<rddl {sim.model.name}: _scalar_legal>", "exec")
            exec(code, lns)  # noqa: S102
            self.legal = lns["_scalar_legal"]
        ns: dict[str, Any] = dict(_HELPERS)
        ns.update(writer.tables)
        code = compile(self.source, f"<rddl {sim.model.name}: _scalar_step>", "exec")
        exec(code, ns)  # noqa: S102
        self.step: Callable[
            [tuple[Any, ...], tuple[Any, ...], np.random.Generator],
            tuple[tuple[Any, ...], float, bool],
        ] = ns["_scalar_step"]
        """`step(state, actions, rng)` -> (next state, reward, done)."""
        self.noop = self.encode_actions(sim.noop(1))
        """Every action at its default."""
        body = self.source.split(" = A\n", 1)[-1] if self.action_keys else ""
        read = {int(m) for m in re.findall(r"\ba(\d+)\b", body)}
        self.inert_actions: list[tuple[str, tuple[int, ...]]] = [
            key for i, key in enumerate(self.action_keys) if i not in read
        ]
        """The action groundings the step never reads once the non-fluents are
        folded in (TriangleTireworld's `move-car` between locations with no
        road): whatever their value, the next state and the reward are
        noop's, so a joint action that sets one is worth the same one
        without it (PROST's parser drops them likewise)."""
        self._state_shapes = {p.name: sim._compiler.shape_of(p) for p in sim.state_fluents}
        self._state_dtypes = {p.name: sim._dtype(p) for p in sim.state_fluents}

    def encode_state(self, state: State, row: int = 0) -> tuple[Any, ...]:
        """Row `row` of a batch of states as the tuple `step` takes."""
        return tuple(state.values[name][(row, *idx)].item() for name, idx in self.state_keys)

    def encode_actions(self, actions: Mapping[str, Array], row: int = 0) -> tuple[Any, ...]:
        """Row `row` of a batch of joint actions (missing fluents at their
        default) as the tuple `step` takes."""
        out = []
        for name, idx in self.action_keys:
            a = actions.get(name)
            if a is None:
                out.append(self.sim._defaults[name][idx].item())
            else:
                out.append(np.asarray(a)[(row, *idx)].item())
        return tuple(out)

    def decode_state(self, values: tuple[Any, ...]) -> State:
        """A tuple of `step` as a `State` of one."""
        arrays = {
            name: np.empty((1, *shape), dtype=self._state_dtypes[name])
            for name, shape in self._state_shapes.items()
        }
        for (name, idx), v in zip(self.state_keys, values, strict=True):
            arrays[name][(0, *idx)] = v
        return State(arrays)
