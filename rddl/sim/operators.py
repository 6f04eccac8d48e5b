"""Compiling RDDL's operators: constants, object and enum names, pvariable
references, arithmetic and logic, comparisons, `if` and `switch`, and the
built-in functions (`exp`, `min`, `pow`...).

Owns `_Operators`, the layer of the compiler (over `base._CompilerBase`)
with one method per AST class of these constructs (`_Const`, `_PVar`,
`_Binary`, `_If`, `_Switch`, `_Function`...), `binary` (the value of an
arithmetic or logical operator given its operands' values, which
`aggregations` also uses) and the uniform slots of branches: `branch`
(statements compiled only for their type) and `alternatives` (branches of
which each element takes one, which may draw the same uniforms). A
comparison or arithmetic on a count of bools kept as uint8 (`_Node.narrow`)
stays in uint8 where that gives the same values.

May call `base`, `code`, `bounds`, `runtime._missing` and `state`.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator

import numpy as np

from .. import ast as A
from ..model import PVariable
from .base import _CompilerBase
from .bounds import (
    _bounds_add,
    _bounds_div,
    _bounds_either,
    _bounds_exp,
    _bounds_max,
    _bounds_min,
    _bounds_mul,
    _bounds_neg,
    _bounds_sub,
)
from .code import _DTYPES, Scope, _Node, _Pool, _Slot
from .runtime import _missing
from .state import SimulationError

_UNARY_FUNCTIONS = {
    "exp": "np.exp", "ln": "np.log", "sqrt": "np.sqrt", "cos": "np.cos", "sin": "np.sin",
    "tan": "np.tan", "acos": "np.arccos", "asin": "np.arcsin", "atan": "np.arctan",
    "cosh": "np.cosh", "sinh": "np.sinh", "tanh": "np.tanh",
}  # fmt: skip

_COMPARISONS = {"<": "_lt", "<=": "_le", ">": "_gt", ">=": "_ge", "^": "_land", "|": "_lor"}


def _join(a: str, b: str) -> str:
    if a == b:
        return a
    nums = ("bool", "int", "real")
    if a in nums and b in nums:
        return "real" if "real" in (a, b) else "int"
    return a


class _Operators(_CompilerBase):
    """The compiler's methods for operators, references, branches and
    functions (see the module's docstring)."""

    def _Const(self, e: A.Const, scope: Scope, hint: str | None) -> _Node:
        v = e.value
        if isinstance(v, bool):
            return self.scalar(v, scope, "bool", np.bool_)
        if isinstance(v, int):
            return self.scalar(v, scope, "int", np.int64)
        return self.scalar(v, scope, "real", np.float64)

    def _Var(self, e: A.Var, scope: Scope, hint: str | None) -> _Node:
        # A variable used as a value: the code of the object it ranges over.
        pos = [i for i, (v, _) in enumerate(scope) if v == e.name]
        i = pos[-1]
        t = scope[i][1]
        shape = [1] * self.rank(scope)
        shape[i] = self.sizes[t]
        return self.const(np.arange(self.sizes[t], dtype=np.int64).reshape(shape), t)

    def _EnumLit(self, e: A.EnumLit, scope: Scope, hint: str | None) -> _Node:
        code, t = self.code_of(e.name, hint)
        return self.scalar(code, scope, t, np.int64)

    def _ObjectLit(self, e: A.ObjectLit, scope: Scope, hint: str | None) -> _Node:
        code, t = self.code_of(e.name, hint)
        return self.scalar(code, scope, t, np.int64)

    def _literal_code(self, a: A.Expr, t: str) -> int | None:
        """The code of an argument that names an object or enum value."""
        if isinstance(a, (A.EnumLit, A.ObjectLit)) or (
            isinstance(a, A.PVar) and a.name not in self.model.pvariables
        ):
            name = a.name
            if isinstance(a, A.PVar) and t in self.codes and "@" + name in self.codes[t]:
                name = "@" + name
            return self.code_of(name, t)[0]
        return None

    def ref(self, p: PVariable, primed: bool) -> _Node:
        key = p.name + ("'" if primed else "")
        hit = self.values.get(key)
        if hit is None:
            # read before it is computed (or where it has no value): rddlsim
            # has no value to give either
            node = self.emit_value(
                f"{self.global_name(_missing)}({key!r})",
                (*self.shape_of(p), 1),
                _DTYPES.get(p.range, np.int64),
                p.range,
            )
            self.values[key] = (node, None)
            return node
        node, source = hit
        if source is not None:
            self.code.inputs.setdefault(node.code, source)
        return node

    def _PVar(self, e: A.PVar, scope: Scope, hint: str | None) -> _Node:
        p = self.model.pvariables.get(e.name)
        if p is None:  # a bare object name (or an enum value without '@')
            name = e.name
            if hint in self.codes and "@" + name in self.codes[hint]:
                name = "@" + name
            return self._ObjectLit(A.ObjectLit(name, loc=e.loc), scope, hint)
        if e.default:
            default = self.model.default_of(p)
            if p.range in self.codes:
                return self.scalar(self.codes[p.range][default], scope, p.range, np.int64)  # type: ignore[index]
            return self.scalar(default, scope, p.range, None)
        base = self.ref(p, e.primed)
        names = [v for v, _ in scope]
        # Fast path: each argument a distinct variable or a literal -> a view.
        index: list[str] = []
        positions: list[int] = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, A.Var):
                positions.append(max(i for i, v in enumerate(names) if v == a.name))
                index.append(":")
                continue
            code = self._literal_code(a, t)
            if code is None:
                break
            index.append(str(code))
        if len(index) == len(e.args) and len(set(positions)) == len(positions):
            node = base
            if any(i != ":" for i in index):
                node = self.op("{0}[" + ", ".join([*index, ":"]) + "]", [node], p.range, view=True)
            order = sorted(range(len(positions)), key=lambda i: positions[i])
            if order != list(range(len(positions))):
                axes = (*order, len(order))
                node = self.op(f"{{0}}.transpose({axes})", [node], p.range, view=True)
            present = set(positions)
            if len(present) < len(scope):
                node = self.expand(node, [i in present for i in range(len(scope))])
            return node
        # General path: advanced indexing with broadcast index arrays.
        rank = self.rank(scope)
        indices: list[_Node] = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, A.Var):
                indices.append(self._Var(a, scope, None))
                continue
            code = self._literal_code(a, t)
            if code is not None:
                indices.append(self.scalar(code, scope, t, np.int64))
            else:
                indices.append(self.compile(a, scope, t))
        if base.batched:
            b = f"_bidx(B, {rank})"
        else:
            b = self.global_name(np.zeros((1,) * rank, dtype=np.int64))
        parts = ", ".join([f"{{{i + 1}}}" for i in range(len(indices))] + [b])
        return self.op("{0}[(" + parts + ")]", [base, *indices], p.range)

    def _Unary(self, e: A.Unary, scope: Scope, hint: str | None) -> _Node:
        x = self.numeric(e.operand, scope)
        if e.op == "~":
            return self.op("_lnot({0})", [x], "bool")
        if e.op == "-":
            if x.rtype == "bool":
                return self.op("_neg({0}.astype(_i64))", [x], "int", bounds=_bounds_neg)
            return self.op("_neg({0})", [x], x.rtype, bounds=_bounds_neg)
        return x

    def _Binary(self, e: A.Binary, scope: Scope, hint: str | None) -> _Node:
        if e.op in ("==", "~="):
            left = self.compile(e.left, scope)
            lt = left.rtype
            right = self.compile(e.right, scope, lt)
            rt = right.rtype
            if (
                lt != rt
                and (lt in self.codes) != (rt in self.codes)
                or (lt in self.codes and rt in self.codes and lt != rt)
            ):
                # mixed forms: compare as numbers where an enum is numeric
                left = self.to_numeric(left)
                right = (
                    self.to_numeric(right)
                    if self.is_random(e.right)
                    else self.numeric(e.right, scope)
                )
            pair = self.narrowed(left, right)
            return self.op("_eq({0}, {1})" if e.op == "==" else "_ne({0}, {1})", pair, "bool")
        left = self.numeric(e.left, scope)
        right = self.numeric(e.right, scope)
        return self.binary(e, left, right)

    def narrowed(self, left: _Node, right: _Node) -> list[_Node]:
        """The operands of a comparison: a count kept as uint8 (`narrow`)
        and an integer constant within [0, 255] compared as uint8 (the
        same outcome, on an eighth of the memory), else as they are."""
        for x, k in ((left, right), (right, left)):
            if x.narrow is None or k.value is None or k.value.dtype.kind not in "iu":
                continue
            if k.value.size and 0 <= k.value.min() and k.value.max() <= 255:
                k8 = self.const(k.value.astype(np.uint8), k.rtype)
                return [x.narrow, k8] if x is left else [k8, x.narrow]
        return [left, right]

    def binary(self, e: A.Binary, left: _Node, right: _Node) -> _Node:
        """`left op right` for an arithmetic or logical operator."""
        op = e.op
        lt, rt = left.rtype, right.rtype
        args = [left, right]
        if op in ("^", "|"):
            return self.logic(_COMPARISONS[op], left, right)
        if op in _COMPARISONS:
            return self.op(f"{_COMPARISONS[op]}({{0}}, {{1}})", self.narrowed(left, right), "bool")
        if op == "=>":
            return self.logic("_lor", self.lnot(left), right)
        if op == "<=>":
            return self.op("_eq({0}.astype(_bool), {1}.astype(_bool))", args, "bool")
        out = "real" if "real" in (lt, rt) or op == "/" else "int"
        if op in ("+", "-", "*", "/"):
            args = self.narrowed_arithmetic(args)
        if op == "+":
            if lt == rt == "bool":
                return self.op("{0}.astype(_i64) + {1}", args, "int", bounds=_bounds_add)
            return self.narrow_result(
                self.op("_add({0}, {1})", args, out, bounds=_bounds_add), "_add", args
            )
        if op == "-":
            if lt == "bool":
                return self.op("{0}.astype(_i64) - {1}", args, out, bounds=_bounds_sub)
            return self.narrow_result(
                self.op("_sub({0}, {1})", args, out, bounds=_bounds_sub), "_sub", args
            )
        if op == "*":
            if lt == rt == "bool":
                return self.op("_land({0}, {1}).astype(_i64)", args, "int")
            return self.narrow_result(
                self.op("_mul({0}, {1})", args, out, bounds=_bounds_mul), "_mul", args
            )
        if op == "/":
            return self.op("_div({0}, {1})", args, "real", bounds=_bounds_div)
        raise SimulationError(f"{e.loc}: unknown operator '{op}'")

    @staticmethod
    def narrowed_arithmetic(args: list[_Node]) -> list[_Node]:
        """The operands of arithmetic with a float64 value: an integer kept
        as uint8 too (`narrow`) taken as uint8. numpy converts it to float64
        either way, exactly (the same values), and reads an eighth of the
        memory (and skips the int64 array, if nothing else reads it)."""
        for i in (0, 1):
            x, other = args[i], args[1 - i]
            narrow = x.narrow
            if other.dtype == np.float64 and narrow is not None:
                if narrow.bounds is None:
                    narrow.bounds = x.bounds  # (the same values)
                return [narrow, other] if i == 0 else [other, narrow]
        return args

    def narrow_result(self, node: _Node, ufunc: str, args: list[_Node]) -> _Node:
        """`node`, the int64 value of `ufunc` (`_add`, `_sub`, `_mul`) of a
        count kept as uint8 (`narrow`) and an integer constant, with its
        uint8 form too where its bounds prove it within [0, 255] (so that
        uint8 arithmetic makes the same values). (Both are written; the
        one not read is dropped from the function.)"""
        if (
            node.dtype != np.int64
            or node.narrow is not None
            or node.value is not None
            or not self.large
        ):
            return node
        b = node.bounds
        if b is None or b[0].min(initial=0) < 0 or b[1].max(initial=0) > 255:
            return node
        narrow: list[_Node] = []
        for x in args:
            if x.narrow is not None:
                narrow.append(x.narrow)
            elif x.value is not None and x.value.dtype.kind in "iub" and x.value.size:
                if x.value.min() < 0 or x.value.max() > 255:
                    return node
                narrow.append(self.const(x.value.astype(np.uint8), x.rtype))
            else:
                return node
        if all(x.value is not None for x in narrow):
            return node
        small = self.op(f"{ufunc}({{0}}, {{1}})", narrow, node.rtype)
        if small.dtype == np.uint8:
            small.bounds = b  # (the same values)
            node.narrow = small
        return node

    def _If(self, e: A.If, scope: Scope, hint: str | None) -> _Node:
        cond = self.numeric(e.cond, scope)
        pick: bool | None = None
        if cond.value is not None and cond.value.size:
            if cond.value.all():
                pick = True
            elif not cond.value.any():
                pick = False
        if pick is None:
            # each element takes one branch: the branches may draw the same
            # uniforms (one draw per grounding, as rddlsim evaluates only
            # the branch taken)
            with self.alternatives() as alternative:
                with alternative():
                    then = self.compile(e.then, scope, hint)
                with alternative():
                    else_ = self.compile(
                        e.else_, scope, hint if then.rtype not in _DTYPES else then.rtype
                    )
            t = _join(then.rtype, else_.rtype)
            if cond.dtype == then.dtype == else_.dtype == np.bool_:
                # a constant true or false branch: one logical operation
                # (np.where broadcasting a constant is much slower)
                for node, other in ((then, else_), (else_, then)):
                    if node.value is None or not node.value.size:
                        continue
                    if node.value.all():
                        if node is then:
                            return self.logic("_lor", cond, other, t)
                        return self.logic("_lor", self.lnot(cond), other, t)
                    if not node.value.any():
                        if node is then:
                            return self.logic("_land", self.lnot(cond), other, t)
                        return self.logic("_land", cond, other, t)
                if self.large:
                    # np.where is slow on large bool arrays: logical operations
                    yes = self.logic("_land", cond, then, t)
                    no = self.logic("_land", self.lnot(cond), else_, t)
                    return self.logic("_lor", yes, no, t)
            return self.op("_where({0}, {1}, {2})", [cond, then, else_], t, bounds=_bounds_either)
        # the condition is the same everywhere: the other branch only for
        # its type (it draws nothing: only the branch taken draws)
        with self.branch(keep=pick):
            then = self.compile(e.then, scope, hint)
        with self.branch(keep=not pick):
            else_ = self.compile(e.else_, scope, hint if then.rtype not in _DTYPES else then.rtype)
        t = _join(then.rtype, else_.rtype)
        node = self.cast(then if pick else else_, np.result_type(then.dtype, else_.dtype))
        return node if node.rtype == t else dataclasses.replace(node, rtype=t)

    @contextlib.contextmanager
    def branch(self, keep: bool) -> Iterator[None]:
        """Statements that are kept, or compiled only to be thrown away."""
        if keep:
            yield
            return
        code = self.code
        start, count, slots = len(code.lines), len(code.draws), len(code.slots)
        code.memo.append({})
        code.pools.append(_Pool())
        try:
            yield
        finally:
            code.pools.pop()
            code.memo.pop()
            del code.lines[start:]
            del code.draws[count:]
            del code.slots[slots:]

    @contextlib.contextmanager
    def alternatives(self) -> Iterator[Callable[[], contextlib.AbstractContextManager[None]]]:
        """Branches of which each element of the batch takes one (an `if`'s,
        a `switch`'s cases): `with alternative():` around each. A branch
        may draw again the uniforms that the branches before it drew, and
        those that branches exclusive with the enclosing one drew (an
        element's value reads each uniform at most once either way); the
        enclosing branch may not draw any of them again."""
        code = self.code
        outer = code.pools[-1]
        drawn: list[_Slot] = []  # by any of the branches, in order

        @contextlib.contextmanager
        def alternative() -> Iterator[None]:
            free = drawn + [s for s in outer.free if not any(s is d for d in drawn)]
            pool = _Pool(free=free)
            code.pools.append(pool)
            try:
                yield
            finally:
                code.pools.pop()
                drawn.extend(s for s in pool.used if not any(s is d for d in drawn))

        yield alternative
        outer.free = [s for s in outer.free if not any(s is d for d in drawn)]
        outer.used.extend(drawn)

    def _Switch(self, e: A.Switch, scope: Scope, hint: str | None) -> _Node:
        subject = self.compile(e.subject, scope)
        t: str | None = None
        labels: list[_Node] = []
        for case in e.cases:
            if case.label is not None:
                labels.append(self.compile(case.label, scope, subject.rtype))
        # values in the order rddlsim's evaluation draws them: the labelled
        # cases, then the default
        values: list[_Node] = []
        default: _Node | None = None
        types: list[str] = []
        with self.alternatives() as alternative:
            for case in e.cases:
                if case.label is not None:
                    with alternative():
                        values.append(self.compile(case.value, scope, hint))
            for case in e.cases:
                if case.label is None:
                    with alternative():
                        default = self.compile(case.value, scope, hint)
        it = iter(values)
        for case in e.cases:
            types.append((default if case.label is None else next(it)).rtype)  # type: ignore[union-attr]
        for vt in types:
            t = vt if t is None else _join(t, vt)
        fallback = default if default is not None else values[-1]
        if not labels:
            return fallback
        conds = [self.op("_eq({0}, {1})", [subject, lab], "bool") for lab in labels]
        n = len(conds)
        template = (
            "_select(["
            + ", ".join(f"{{{i}}}" for i in range(n))
            + "], ["
            + ", ".join(f"{{{n + i}}}" for i in range(n))
            + f"], {{{2 * n}}})"
        )
        return self.op(template, [*conds, *values, fallback], t or "real")

    # -- functions ---------------------------------------------------

    def _Function(self, e: A.Function, scope: Scope, hint: str | None) -> _Node:
        args = [self.numeric(a, scope) for a in e.args]
        types = [a.rtype for a in args]
        name = e.name
        # (no cast of a value that is float64 already: a call less, and a
        # plain `f(t)` may be written in place, see `_in_place`)
        as_f64 = "{0}" if args and args[0].dtype == np.float64 else "{0}.astype(_f64, copy=False)"
        if name in _UNARY_FUNCTIONS:
            rising = _bounds_exp if name == "exp" else None
            return self.op(f"{_UNARY_FUNCTIONS[name]}({as_f64})", args[:1], "real", bounds=rising)
        if name in ("floor", "ceil", "round"):
            return self.op(f"np.{name}({{0}}).astype(_i64)", args[:1], "int")
        if name in ("sgn", "sign"):
            return self.op("_sign({0}).astype(_i64)", args[:1], "int")
        if name == "abs":
            return self.op("_abs({0})", args[:1], "int" if types[0] == "bool" else types[0])
        pair = args[:2]
        out = "real" if "real" in types else "int"
        if name == "min":
            return self.op("_minimum({0}, {1})", pair, out, bounds=_bounds_min)
        if name == "max":
            return self.op("_maximum({0}, {1})", pair, out, bounds=_bounds_max)
        if name == "pow":
            if pair[1].value is not None and pair[1].value.size and (pair[1].value == 2).all():
                # x * x, correctly rounded as pow(x, 2) is: the same values, faster
                return self.op(f"_square({as_f64})", pair[:1], "real")
            return self.op(f"_power({as_f64}, {{1}})", pair, "real")
        if name == "log":
            return self.op("_log({0}) / _log({1})", pair, "real")
        if name == "hypot":
            return self.op("_hypot({0}, {1})", pair, "real")
        if name in ("mod", "fmod"):
            return self.op("_fmod({0}, {1})", pair, "real" if name == "fmod" else out)
        if name == "div":
            return self.op("_trunc(_div({0}, {1})).astype(_i64)", pair, "int")
        raise SimulationError(f"{e.loc}: function '{name}' is not supported by the simulator")
