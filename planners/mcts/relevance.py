"""Action groundings that can never pay: a relevance analysis of the scalar
step (`ippc.rddl.sim.scalar.ScalarStep`'s generated source).

A state grounding is *relevant* when the reward, the termination or a
constraint reads it, or when the next value of a relevant grounding does
(the closure over the transition). An action grounding is *useful* when the
next value of a relevant grounding reads it, or when setting it can raise
the reward. Both sets are found together, from the assumption that no action
grounding is useful: the source is folded with the useless groundings at
their default (so a term like ``-1.0 * (a7 and s34)``, the cost of retaking
course 7, reads no state while course 7 is never taken), the relevant
groundings are closed over the folded transition, the groundings the
relevant ones read (unfolded) join the useful ones, and so on until nothing
changes.

Whatever a useless grounding does, it touches only state that cannot reach
the reward or a constraint, and it can only lower the reward: a joint action
that sets one is worth at most the same joint action without it, *provided
that one is legal too*. The constraint rule sees to that: each conjunct of
the preconditions and state-action constraints (`_Polarity`) must be proven
to stay true when a useless bool grounding it reads goes back to its default
(a grounding whose default is false may only appear where setting it can
make the conjunct false, never where it can make it true: `sum(take) <= 3`
and `take => ~passed` allow it, `move => permit` does not allow `permit`,
`x == y` allows neither). A conjunct not proven so, or one that reads a
useless grounding that is not bool, makes every grounding it reads useful,
and the fixpoint goes on from there (`ship => label`, `label => weigh`:
label and then weigh). The same rule decides which of the groundings the
step never reads may be left out (`removable_inert`). Where noop may be
illegal somewhere (a constraint that does not fold to true with every action
at its default), nothing is left out as useless either.

In AcademicAdvising the useful courses are the program requirements and
their prerequisites, transitively (6 of 27 on IPPC 2018's instance 4); the
others only cost. The search leaves the useless groundings at their default,
as it does the groundings the step never reads (`ScalarStep.inert_actions`).

The reward test is interval arithmetic per additive term of the reward: a
term that reads a useless grounding must be at most, with the grounding set
to anything, what it is at the default (bool state and action groundings in
[0, 1], draws of Uniform in [0, 1), everything else unbounded); a term that
fails makes its groundings useful.
"""

from __future__ import annotations

import ast
import math
import operator
import re
import time
from collections.abc import Callable, Iterable
from typing import Any

from ...rddl import ast as A
from ...rddl.sim.scalar import _HELPERS, ScalarStep

_STATE = re.compile(r"s(\d+)$")
_ACTION = re.compile(r"a(\d+)$")

INF = math.inf

_BIN: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv,
    ast.Mod: operator.mod,
    ast.Pow: operator.pow,
}
_CMP: dict[type, Callable[[Any, Any], Any]] = {
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
}


class _Const:
    """A folded value known without the state (see `_Folder`)."""

    __slots__ = ("value",)

    def __init__(self, value: Any):
        self.value = value


class _Folder:
    """The groundings an expression of the step reads once some action
    groundings are fixed: `deps(node)` is a `_Const` when the expression is
    known without the state, else the set of names (sN, aN) it reads.
    Locals (interm and next-state values, temporaries) are followed into
    their definitions."""

    def __init__(self, defs: dict[str, ast.expr], fixed: dict[str, Any], ns: dict[str, Any]):
        self.defs = defs
        self.fixed = fixed
        self.ns = ns
        self.memo: dict[str, _Const | frozenset[str]] = {}

    def name(self, ident: str) -> _Const | frozenset[str]:
        got = self.memo.get(ident)
        if got is not None:
            return got
        if ident in self.fixed:
            out: _Const | frozenset[str] = _Const(self.fixed[ident])
        elif ident in self.defs:
            self.memo[ident] = frozenset()  # (no cycles in straight-line code)
            out = self.deps(self.defs[ident])
        elif _STATE.match(ident) or _ACTION.match(ident):
            out = frozenset([ident])
        elif ident in self.ns:
            out = _Const(self.ns[ident])
        else:
            out = frozenset()
        self.memo[ident] = out
        return out

    def deps(self, node: ast.expr) -> _Const | frozenset[str]:
        if isinstance(node, ast.Constant):
            return _Const(node.value)
        if isinstance(node, ast.Name):
            return self.name(node.id)
        if isinstance(node, ast.IfExp):
            test = self.deps(node.test)
            if isinstance(test, _Const):
                return self.deps(node.body if test.value else node.orelse)
            body, orelse = self.deps(node.body), self.deps(node.orelse)
            if isinstance(body, _Const) and isinstance(orelse, _Const):
                if type(body.value) is type(orelse.value) and body.value == orelse.value:
                    return body  # either way the same
            return _union(test, body, orelse)
        if isinstance(node, ast.BoolOp):
            is_and = isinstance(node.op, ast.And)
            parts: list[_Const | frozenset[str]] = []
            known: _Const | None = None
            for v in node.values:
                d = self.deps(v)
                if isinstance(d, _Const) and not parts:
                    # a leading known operand decides or drops out
                    if bool(d.value) != is_and:
                        return d
                    known = d
                    continue
                parts.append(d)
            if not parts:
                assert known is not None
                return known
            if len(parts) == 1:
                return parts[0]
            return _union(*parts)
        if isinstance(node, ast.UnaryOp):
            d = self.deps(node.operand)
            if isinstance(d, _Const):
                return _try(lambda: _unary(node.op, d.value), d)
            return d
        if isinstance(node, ast.BinOp):
            left, right = self.deps(node.left), self.deps(node.right)
            fn = _BIN.get(type(node.op))
            if isinstance(left, _Const) and isinstance(right, _Const) and fn is not None:
                return _try(lambda: fn(left.value, right.value), left, right)
            return _union(left, right)
        if isinstance(node, ast.Compare):
            ds = [self.deps(node.left), *(self.deps(c) for c in node.comparators)]
            if all(isinstance(d, _Const) for d in ds) and all(type(o) in _CMP for o in node.ops):
                vals = [d.value for d in ds]  # type: ignore[union-attr]
                return _try(
                    lambda: all(
                        _CMP[type(o)](x, y)
                        for o, x, y in zip(node.ops, vals, vals[1:], strict=False)
                    ),
                    *ds,
                )
            return _union(*ds)
        if isinstance(node, ast.Call):
            fn_d = self.deps(node.func)
            args = [self.deps(a) for a in node.args]
            if (
                isinstance(fn_d, _Const)
                and callable(fn_d.value)
                and not node.keywords
                and all(isinstance(a, _Const) for a in args)
            ):
                return _try(lambda: fn_d.value(*(a.value for a in args)), *args)  # type: ignore[union-attr]
            return _union(*args)
        if isinstance(node, ast.Subscript):
            base, index = self.deps(node.value), self.deps(node.slice)
            if isinstance(base, _Const) and isinstance(index, _Const):
                return _try(lambda: base.value[index.value], base, index)
            return _union(base, index)
        if isinstance(node, ast.Tuple | ast.List):
            return _union(*(self.deps(e) for e in node.elts))
        found: list[_Const | frozenset[str]] = [
            self.deps(c) for c in ast.iter_child_nodes(node) if isinstance(c, ast.expr)
        ]
        return _union(*found)


def _unary(op: ast.unaryop, v: Any) -> Any:
    if isinstance(op, ast.Not):
        return not v
    if isinstance(op, ast.USub):
        return -v
    if isinstance(op, ast.UAdd):
        return +v
    return ~v


def _try(fn: Callable[[], Any], *parts: _Const | frozenset[str]) -> _Const | frozenset[str]:
    try:
        return _Const(fn())
    except Exception:  # noqa: BLE001 - an error at run time: not foldable
        return _union(*parts)


def _union(*parts: _Const | frozenset[str]) -> frozenset[str]:
    out: set[str] = set()
    for p in parts:
        if not isinstance(p, _Const):
            out |= p
    return frozenset(out)


class _Intervals:
    """Bounds of an expression of the step (lo, hi): bool state and action
    groundings in [0, 1] (actions in `fixed` at their value), draws of
    Uniform in [0, 1), everything unknown unbounded."""

    def __init__(
        self,
        defs: dict[str, ast.expr],
        fixed: dict[str, Any],
        ns: dict[str, Any],
        boolean: set[str],
    ):
        self.defs = defs
        self.fixed = fixed
        self.ns = ns
        self.boolean = boolean
        self.memo: dict[str, tuple[float, float]] = {}

    def name(self, ident: str) -> tuple[float, float]:
        got = self.memo.get(ident)
        if got is not None:
            return got
        if ident in self.fixed:
            v = float(self.fixed[ident])
            out = (v, v)
        elif ident in self.defs:
            self.memo[ident] = (-INF, INF)
            out = self.of(self.defs[ident])
        elif ident in self.boolean:
            out = (0.0, 1.0)
        elif ident in self.ns and isinstance(self.ns[ident], int | float):
            v = float(self.ns[ident])
            out = (v, v)
        else:
            out = (-INF, INF)
        self.memo[ident] = out
        return out

    def of(self, node: ast.expr) -> tuple[float, float]:
        got = self._of(node)
        lo, hi = got
        if math.isnan(lo) or math.isnan(hi):
            return (-INF, INF)
        return got

    def _of(self, node: ast.expr) -> tuple[float, float]:
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool | int | float):
                v = float(node.value)
                return (v, v)
            return (-INF, INF)
        if isinstance(node, ast.Name):
            return self.name(node.id)
        if isinstance(node, ast.IfExp):
            t = self.of(node.test)
            if t == (0.0, 0.0):
                return self.of(node.orelse)
            if t[0] > 0 or t[1] < 0:
                return self.of(node.body)
            return _hull(self.of(node.body), self.of(node.orelse))
        if isinstance(node, ast.BoolOp):
            # `x and y` is its first falsy operand, else its last (`or`: the
            # first truthy one): a sure operand that cannot stop it drops out
            is_and = isinstance(node.op, ast.And)
            out: tuple[float, float] | None = None
            last = len(node.values) - 1
            for k, operand in enumerate(node.values):
                iv = self.of(operand)
                falsy = iv == (0.0, 0.0)
                truthy = iv[0] > 0 or iv[1] < 0
                stops = falsy if is_and else truthy
                passes = truthy if is_and else falsy
                if passes and k < last:
                    continue
                out = iv if out is None else _hull(out, iv)
                if stops:
                    break
            assert out is not None
            return out
        if isinstance(node, ast.UnaryOp):
            lo, hi = self.of(node.operand)
            if isinstance(node.op, ast.Not):
                return (0.0, 1.0)
            if isinstance(node.op, ast.USub):
                return (-hi, -lo)
            if isinstance(node.op, ast.UAdd):
                return (lo, hi)
            return (-INF, INF)
        if isinstance(node, ast.BinOp):
            a, b = self.of(node.left), self.of(node.right)
            if isinstance(node.op, ast.Add):
                return (a[0] + b[0], a[1] + b[1])
            if isinstance(node.op, ast.Sub):
                return (a[0] - b[1], a[1] - b[0])
            if isinstance(node.op, ast.Mult):
                return _mul(a, b)
            if isinstance(node.op, ast.Div) and (b[0] > 0 or b[1] < 0):
                return _mul(a, (1 / b[1], 1 / b[0]) if b[0] != 0 and b[1] != 0 else (-INF, INF))
            return (-INF, INF)
        if isinstance(node, ast.Compare):
            return (0.0, 1.0)
        if isinstance(node, ast.Call):
            if isinstance(node.func, ast.Name) and node.func.id == "bool":
                return (0.0, 1.0)
            return (-INF, INF)
        if isinstance(node, ast.Subscript):
            if isinstance(node.value, ast.Name) and node.value.id == "U":
                return (0.0, 1.0)
            return (-INF, INF)
        return (-INF, INF)


def _hull(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    return (min(a[0], b[0]), max(a[1], b[1]))


def _mul(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    products = []
    for x in a:
        for y in b:
            if (x == 0 and math.isinf(y)) or (y == 0 and math.isinf(x)):
                products.append(0.0)
            else:
                products.append(x * y)
    return (min(products), max(products))


def _terms(node: ast.expr, sign: int = 1) -> Iterable[tuple[int, ast.expr]]:
    """The additive terms of an expression, with their signs."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add | ast.Sub):
        yield from _terms(node.left, sign)
        yield from _terms(node.right, sign if isinstance(node.op, ast.Add) else -sign)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        yield from _terms(node.operand, -sign)
    else:
        yield sign, node


# -- the constraint rule ------------------------------------------------------

POS, NEG = 1, 2
BOTH = POS | NEG


def _flip(bits: int) -> int:
    return ((bits & POS) << 1) | ((bits & NEG) >> 1)


def _join(*parts: dict[str, int]) -> dict[str, int]:
    out: dict[str, int] = {}
    for p in parts:
        for k, v in p.items():
            out[k] = out.get(k, 0) | v
    return out


class _Polarity:
    """How an expression of the legal function moves with each action
    grounding it reads: `of(node)` maps aN to POS (never falls as aN rises),
    NEG (never rises), or BOTH (not proven either way). Value order, with
    False < True; bool operators count as min/max only over boolean operands,
    products and quotients only where the other side's sign is known."""

    def __init__(
        self, defs: dict[str, ast.expr], ns: dict[str, Any], boolean: set[str], free: _Folder
    ):
        self.defs = defs
        self.ns = ns
        self.boolean = boolean
        self.free = free
        self.bounds = _Intervals(defs, {}, ns, boolean)
        self.memo: dict[str, dict[str, int]] = {}
        self.bool_memo: dict[str, bool] = {}

    def unknown(self, node: ast.expr) -> dict[str, int]:
        """BOTH for every action grounding `node` reads."""
        return {x: BOTH for x in _names(self.free.deps(node)) if _ACTION.match(x)}

    def is_bool(self, node: ast.expr) -> bool:
        if isinstance(node, ast.Compare):
            return True
        if isinstance(node, ast.Constant):
            return isinstance(node.value, bool)
        if isinstance(node, ast.UnaryOp):
            return isinstance(node.op, ast.Not)
        if isinstance(node, ast.BoolOp):
            return all(self.is_bool(v) for v in node.values)
        if isinstance(node, ast.IfExp):
            return self.is_bool(node.body) and self.is_bool(node.orelse)
        if isinstance(node, ast.Call):
            return isinstance(node.func, ast.Name) and node.func.id == "bool"
        if isinstance(node, ast.Name):
            if node.id in self.boolean:
                return True
            if node.id in self.defs:
                got = self.bool_memo.get(node.id)
                if got is None:
                    self.bool_memo[node.id] = False  # (no cycles in straight-line code)
                    got = self.bool_memo[node.id] = self.is_bool(self.defs[node.id])
                return got
        return False

    def truth(self, node: ast.expr) -> dict[str, int] | None:
        """The polarity of `node`'s truth value, where it follows its value
        (boolean, or never negative); None where it may not."""
        if self.is_bool(node) or self.bounds.of(node)[0] >= 0:
            return self.of(node)
        return None

    def of(self, node: ast.expr) -> dict[str, int]:
        if isinstance(node, ast.Constant):
            return {}
        if isinstance(node, ast.Name):
            ident = node.id
            if _ACTION.match(ident) and ident not in self.defs:
                return {ident: POS}
            if ident in self.defs:
                got = self.memo.get(ident)
                if got is None:
                    self.memo[ident] = {}
                    got = self.memo[ident] = self.of(self.defs[ident])
                return got
            return {}
        if isinstance(node, ast.IfExp):
            test = self.free.deps(node.test)
            if isinstance(test, _Const):
                return self.of(node.body if test.value else node.orelse)
            return _join(self.of(node.body), self.of(node.orelse), self.unknown(node.test))
        if isinstance(node, ast.BoolOp):
            if all(self.is_bool(v) for v in node.values):
                return _join(*(self.of(v) for v in node.values))
            return self.unknown(node)
        if isinstance(node, ast.UnaryOp):
            if isinstance(node.op, ast.Not):
                got = self.truth(node.operand)
                return self.unknown(node) if got is None else _flipped(got)
            if isinstance(node.op, ast.USub):
                return _flipped(self.of(node.operand))
            if isinstance(node.op, ast.UAdd):
                return self.of(node.operand)
            return self.unknown(node)
        if isinstance(node, ast.BinOp):
            return self._binop(node)
        if isinstance(node, ast.Compare):
            out: dict[str, int] = {}
            operands = [node.left, *node.comparators]
            for op, left, right in zip(node.ops, operands, operands[1:], strict=False):
                if isinstance(op, ast.Lt | ast.LtE):
                    out = _join(out, _flipped(self.of(left)), self.of(right))
                elif isinstance(op, ast.Gt | ast.GtE):
                    out = _join(out, self.of(left), _flipped(self.of(right)))
                else:
                    out = _join(out, self.unknown(left), self.unknown(right))
            return out
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords:
            fn = node.func.id
            if fn == "bool" and len(node.args) == 1:
                got = self.truth(node.args[0])
                return self.unknown(node) if got is None else got
            if fn in ("int", "float", "_floor", "_ceil") and len(node.args) == 1:
                return self.of(node.args[0])
            if fn in ("min", "max"):
                return _join(*(self.of(a) for a in node.args))
        return self.unknown(node)

    def _binop(self, node: ast.BinOp) -> dict[str, int]:
        left, right = node.left, node.right
        if isinstance(node.op, ast.Add):
            return _join(self.of(left), self.of(right))
        if isinstance(node.op, ast.Sub):
            return _join(self.of(left), _flipped(self.of(right)))
        if isinstance(node.op, ast.Mult):
            pl, pr = self.of(left), self.of(right)
            bl, br = self.bounds.of(left), self.bounds.of(right)
            out: dict[str, int] = {}
            for side, other in ((pl, br), (pr, bl)):
                for k, v in side.items():
                    if other[0] >= 0:
                        bits = v
                    elif other[1] <= 0:
                        bits = _flip(v)
                    else:
                        bits = BOTH
                    out[k] = out.get(k, 0) | bits
            same_sign = (bl[0] >= 0 and br[0] >= 0) or (bl[1] <= 0 and br[1] <= 0)
            if not same_sign:
                for k in pl.keys() & pr.keys():
                    out[k] = BOTH
            return out
        if isinstance(node.op, ast.Div | ast.FloorDiv):
            if not self.unknown(right):
                lo, hi = self.bounds.of(right)
                if lo > 0:
                    return self.of(left)
                if hi < 0:
                    return _flipped(self.of(left))
        return self.unknown(node)


def _flipped(p: dict[str, int]) -> dict[str, int]:
    return {k: _flip(v) for k, v in p.items()}


def _conjuncts(node: ast.expr, defs: dict[str, ast.expr]) -> Iterable[ast.expr]:
    """The parts of a conjunction (through `bool(...)` and locals)."""
    if isinstance(node, ast.BoolOp) and isinstance(node.op, ast.And):
        for v in node.values:
            yield from _conjuncts(v, defs)
    elif (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "bool"
        and len(node.args) == 1
        and not node.keywords
        and isinstance(node.args[0], ast.BoolOp)
    ):
        yield from _conjuncts(node.args[0], defs)
    elif isinstance(node, ast.Name) and isinstance(defs.get(node.id), ast.BoolOp):
        yield from _conjuncts(defs[node.id], defs)
    else:
        yield node


def useless_actions(
    fast: ScalarStep, time_limit: float = 2.0, clock: Callable[[], float] = time.monotonic
) -> list[tuple[str, tuple[int, ...]]]:
    """The action groundings of the step that can never pay (see the module
    docstring), without those the step never reads; none when the analysis
    takes longer than `time_limit` seconds."""
    started = clock()
    tree = ast.parse(fast.source)
    fn = tree.body[0]
    assert isinstance(fn, ast.FunctionDef)
    defs: dict[str, ast.expr] = {}
    returned: ast.expr | None = None
    for stmt in fn.body:
        if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1:
            target = stmt.targets[0]
            if isinstance(target, ast.Name):
                defs[target.id] = stmt.value
        elif isinstance(stmt, ast.Return):
            returned = stmt.value
    if returned is None or not isinstance(returned, ast.Tuple) or "r" not in defs:
        return []
    nxt = returned.elts[0]
    if not isinstance(nxt, ast.Tuple) or len(nxt.elts) != len(fast.state_keys):
        return []
    next_of = list(nxt.elts)
    legal = _read_constraints(fast)
    if legal is None:
        return []  # constraints the analysis cannot read: nothing is pruned
    constraints, cdefs = legal
    ns = _namespace(fast)
    n_actions = len(fast.action_keys)
    noop = _Folder(cdefs, {f"a{j}": fast.noop[j] for j in range(n_actions)}, ns)
    for expr in constraints:
        d = noop.deps(expr)
        if not (isinstance(d, _Const) and d.value):
            # noop may be illegal somewhere: a joint action without its useless
            # groundings might be too, so nothing is left out
            return []
    # the inert groundings the constraints allow at their default are left
    # out already; the others are judged as the rest
    inert = set(removable_inert(fast))
    candidates = {f"a{j}" for j in range(n_actions) if fast.action_keys[j] not in inert}
    defaults = {f"a{j}": fast.noop[j] for j in range(n_actions)}
    boolean = _boolean(fast)
    parts = _constraint_parts(constraints, cdefs, ns, boolean)
    done = defs.get("done", ast.Constant(False))
    # unfolded (no action fixed): what each next value, the termination and
    # each reward term read, and the bounds of those terms that read an action
    free = _Folder(defs, {}, ns)
    reads = [_names(free.deps(e)) for e in next_of]
    done_reads = _names(free.deps(done))
    high = _Intervals(defs, {}, ns, boolean)
    acting_terms = []
    for sign, term in _terms(defs["r"]):
        read = _names(free.deps(term))
        if any(_ACTION.match(x) for x in read):
            acting_terms.append((sign, term, read, high.of(term)))
    useful: set[str] = set()
    while True:
        if clock() - started > time_limit:
            return []
        useless = candidates - useful
        fixed = {a: defaults[a] for a in useless}
        folder = _Folder(defs, fixed, ns)
        cfolder = _Folder(cdefs, fixed, ns)
        seeds: set[str] = set()
        for f, expr in [
            (folder, defs["r"]),
            (folder, done),
            *((cfolder, c) for c in constraints),
        ]:
            seeds |= {x for x in _names(f.deps(expr)) if _STATE.match(x)}
        relevant: set[int] = set()
        todo = [int(x[1:]) for x in seeds]
        while todo:
            i = todo.pop()
            if i in relevant:
                continue
            relevant.add(i)
            nxt_reads = _names(folder.deps(next_of[i]))
            todo.extend(
                int(x[1:]) for x in nxt_reads if _STATE.match(x) and int(x[1:]) not in relevant
            )
        grown = done_reads & useless
        for i in relevant:
            grown |= reads[i] & useless
        low = _Intervals(defs, fixed, ns, boolean)
        for sign, term, read, (lo1, hi1) in acting_terms:
            mentioned = read & useless
            if not mentioned:
                continue
            lo0, hi0 = low.of(term)
            # the most the term can gain (by its sign) from setting them
            gain = (hi1 - lo0) if sign > 0 else (hi0 - lo1)
            if not gain <= 0:
                grown |= mentioned
        if not grown:
            # a constraint not proven to allow a useless grounding at its
            # default keeps every grounding it reads (see the module
            # docstring); asked once the rest is settled, so that a grounding
            # useful for its own sake does not count as left out
            grown = frozenset(_kept_by(parts, useless, defaults, boolean) & useless)
            if not grown:
                break
        useful |= grown
    keys = fast.action_keys
    return [keys[int(a[1:])] for a in sorted(candidates - useful, key=lambda x: int(x[1:]))]


def _names(d: _Const | frozenset[str]) -> frozenset[str]:
    """The names a folded value reads (none when it is known)."""
    return frozenset() if isinstance(d, _Const) else d


def _range(fast: ScalarStep, name: str) -> str:
    p = fast.sim.model.pvariables.get(name)
    return "" if p is None else str(p.range)


def _read_constraints(fast: ScalarStep) -> tuple[list[ast.expr], dict[str, ast.expr]] | None:
    """The legal function's returned expressions and its locals ([] where
    there is no constraint); None where there are constraints the analysis
    cannot read (`ScalarStep.legal_error`)."""
    constraints: list[ast.expr] = []
    cdefs: dict[str, ast.expr] = {}  # the constraints' own locals (their names may be the step's)
    if fast.legal_source is None:
        return None if fast.constrained else (constraints, cdefs)
    lfn = ast.parse(fast.legal_source).body[0]
    assert isinstance(lfn, ast.FunctionDef)
    for stmt in lfn.body:
        if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1:
            target = stmt.targets[0]
            if isinstance(target, ast.Name):
                cdefs[target.id] = stmt.value
        elif isinstance(stmt, ast.Return) and stmt.value is not None:
            constraints.append(stmt.value)
    return constraints, cdefs


def _namespace(fast: ScalarStep) -> dict[str, Any]:
    ns: dict[str, Any] = dict(_HELPERS)
    ns.update(fast.tables)
    ns["bool"] = bool
    ns["abs"] = abs
    ns["min"] = min
    ns["max"] = max
    ns["int"] = int
    ns["float"] = float
    return ns


def _boolean(fast: ScalarStep) -> set[str]:
    """The step's names (sN, aN) of bool groundings."""
    return {
        f"s{i}" for i, (name, _) in enumerate(fast.state_keys) if _range(fast, name) == "bool"
    } | {f"a{j}" for j, (name, _) in enumerate(fast.action_keys) if _range(fast, name) == "bool"}


def _constraint_parts(
    constraints: list[ast.expr], cdefs: dict[str, ast.expr], ns: dict[str, Any], boolean: set[str]
) -> list[tuple[frozenset[str], dict[str, int]]]:
    """Each conjunct of the constraints: the action groundings it reads, and
    how its truth moves with each of them (`_Polarity`)."""
    free = _Folder(cdefs, {}, ns)
    polarity = _Polarity(cdefs, ns, boolean, free)
    out = []
    for expr in constraints:
        for part in _conjuncts(expr, cdefs):
            read = frozenset(x for x in _names(free.deps(part)) if _ACTION.match(x))
            if not read:
                continue
            got = polarity.truth(part)
            out.append((read, polarity.unknown(part) if got is None else got))
    return out


def _kept_by(
    parts: list[tuple[frozenset[str], dict[str, int]]],
    removable: set[str],
    defaults: dict[str, Any],
    boolean: set[str],
) -> set[str]:
    """Every action grounding read by a conjunct that reads one of
    `removable` and is not proven to stay true when it is reset to its
    default: a bool grounding whose default is false may only lower the
    conjunct's truth as it rises (NEG), one whose default is true only raise
    it (POS); any other grounding is never proven."""
    kept: set[str] = set()
    for read, moves in parts:
        for u in read & removable:
            if u not in boolean:
                break
            wrong = POS if not defaults[u] else NEG
            if moves.get(u, BOTH) & wrong:
                break
        else:
            continue
        kept |= read
    return kept


def removable_inert(fast: ScalarStep) -> list[tuple[str, tuple[int, ...]]]:
    """The groundings of `ScalarStep.inert_actions` (the step never reads
    them) that the constraints allow at their default wherever they allow
    them set: left out, a legal joint action stays legal. An inert grounding
    that a constraint reads otherwise (`move => permit`, with a `permit`
    that costs nothing) is kept, with every grounding that constraint reads."""
    inert = list(fast.inert_actions)
    if not inert:
        return []
    legal = _read_constraints(fast)
    if legal is None:
        # constraints the analysis cannot read: only groundings of fluents
        # that no constraint names
        dom = fast.sim.model.domain
        named: set[str] = set()
        todo: list[A.Expr] = [*dom.action_preconditions, *dom.state_action_constraints]
        while todo:
            e = todo.pop()
            if isinstance(e, A.PVar):
                named.add(e.name)
            todo.extend(A.children(e))
        return [key for key in inert if key[0] not in named]
    constraints, cdefs = legal
    index = {key: j for j, key in enumerate(fast.action_keys)}
    removable = {f"a{index[key]}" for key in inert}
    defaults = {f"a{j}": fast.noop[j] for j in range(len(fast.action_keys))}
    boolean = _boolean(fast)
    parts = _constraint_parts(constraints, cdefs, _namespace(fast), boolean)
    kept = _kept_by(parts, removable, defaults, boolean)
    return [key for key in inert if f"a{index[key]}" not in kept]


def downward_closed(fast: ScalarStep, skipped: Iterable[tuple[str, tuple[int, ...]]] = ()) -> bool:
    """Whether every part of a legal joint action is legal, proven: each
    conjunct of the constraints stays true as any bool grounding it reads
    (but those in `skipped`, which stay at their default) goes back to its
    default (max-nondef-actions only counts fewer). Where this holds, the
    legal joint actions are found by growing the ones legal alone, as the C
    walk of `ippc_enum` does; elsewhere (`move => permit`: move alone is
    illegal, move and permit legal) that walk would miss some."""
    legal = _read_constraints(fast)
    if legal is None:
        return False
    constraints, cdefs = legal
    left = set(skipped)
    removable = {f"a{j}" for j, key in enumerate(fast.action_keys) if key not in left}
    defaults = {f"a{j}": fast.noop[j] for j in range(len(fast.action_keys))}
    boolean = _boolean(fast)
    parts = _constraint_parts(constraints, cdefs, _namespace(fast), boolean)
    return not _kept_by(parts, removable, defaults, boolean)
