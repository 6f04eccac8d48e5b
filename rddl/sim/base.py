"""The compiler's machinery, which every construct's compilation uses.

Owns `_CompilerBase`: the model's types as integer codes, the generated
code's namespace (`ns`: `runtime._BUILTINS` plus the constants it names
`k1`, `k2`...), the function being written (`code`, a `code._Code`), and
the one way a value is made: `op` writes one statement for an operation
(or folds it into a constant when every argument is known, or reuses a
statement with the same text), finds its shape and dtype by running it
once on stand-ins (`_probe`), carries elementwise bounds (`bounds`), and
lays a constant operand out as numpy runs it fastest (`_cast_constant`,
`_widen_constant`, `_spread_constant`). Also what an expression depends on
(`is_random`, `free_vars`, `is_static`) and `compile`, which compiles an
expression in the smallest scope it needs, once, by calling the method
named after its AST class (`_PVar`, `_If`, `_Aggregation`...), which the
subclasses in `operators`, `aggregations` and `distributions` define.

May call `code`, `runtime` (the namespace's helpers), `bounds` and
`state`; never the subclasses' methods but through `compile`.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from typing import Any

import numpy as np

from .. import ast as A
from ..model import NON_FLUENT, Model, PVariable
from ..sim_types import int_enum_value as _int_enum_value
from .bounds import _bounds_same, _bounds_trunc
from .code import (
    _DTYPE_CODE,
    Scope,
    _axis_code,
    _batch_last,
    _Code,
    _compiled,
    _index_code,
    _last_shape_code,
    _Node,
)
from .runtime import _BUILTINS, _SPREAD_CELLS, _action_in_factory, _bidx_factory, _spread_factory
from .state import Array, SimulationError

log = logging.getLogger("ippc.rddl.simulator")


def _broadcasts_to(shape: tuple[int, ...], target: tuple[int, ...]) -> bool:
    """Whether an array of `shape` broadcasts against one of `target`
    without changing `target`."""
    try:
        return np.broadcast_shapes(shape, target) == target
    except ValueError:
        return False


# the largest constant (in elements) made for a batch of one out of a smaller one
_WIDEN_LIMIT = 4096
_UFUNC_CALL = re.compile(r"(_\w+)\(\{0\}, \{1\}\)$")  # a template `_add({0}, {1})`


class _CompilerBase:
    """Writes the generated functions of one model (see the package's
    docstring); `begin` starts a function, `compile` adds an expression's
    statements to it and returns its value."""

    def __init__(self, model: Model):
        self.model = model
        self.sizes = {t: len(info.members) for t, info in model.types.items()}
        self.codes = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }
        self.object_type: dict[str, str] = {}
        for t, info in model.types.items():
            if info.kind == "object" and (info.parent is None or info.parent not in model.types):
                for m in info.members:
                    self.object_type.setdefault(m, t)
        for t, info in model.types.items():
            for m in info.members:
                self.object_type.setdefault(m, t)
        # value of each enum member when used as a number (@1 -> 1), else its code
        self.numeric_of_code: dict[str, Array] = {}
        for t, info in model.types.items():
            if info.kind == "enum":
                ints = [_int_enum_value(m) for m in info.members]
                if all(v is not None for v in ints):
                    self.numeric_of_code[t] = np.array(ints, dtype=np.int64)
        self.ns: dict[str, Any] = dict(_BUILTINS)
        self.ns["_bidx"] = _bidx_factory()
        self.ns["_action_in"] = _action_in_factory()
        self.ns["_spread"] = _spread_factory()
        self._consts: dict[Any, _Node] = {}
        self._global_count = 0
        self._tables: dict[str, str] = {}
        self._random: dict[int, tuple[A.Expr, bool]] = {}
        self._free: dict[int, tuple[A.Expr, frozenset[str]]] = {}
        self._static: dict[int, tuple[A.Expr, bool]] = {}
        self.code = _Code("_unused", "")
        self.context = 0  # which meaning pvariable names have (see `values`)
        self.sources: dict[str, str] = {}
        # what a pvariable reference means in the function being written:
        # "name" / "name'" -> (node, input expression or None)
        self.values: dict[str, tuple[_Node, str | None]] = {}

    # -- helpers -----------------------------------------------------

    def shape_of(self, p: PVariable) -> tuple[int, ...]:
        return tuple(self.sizes[t] for t in p.params)

    def scope_shape(self, scope: Scope) -> tuple[int, ...]:
        return tuple(self.sizes[t] for _, t in scope)

    @staticmethod
    def rank(scope: Scope) -> int:
        return 1 + len(scope)

    def code_of(self, name: str, type_hint: str | None) -> tuple[int, str]:
        """Code and type of an enum value or object name."""
        if type_hint is not None and type_hint in self.codes and name in self.codes[type_hint]:
            return self.codes[type_hint][name], type_hint
        if name.startswith("@"):
            for t, codes in self.codes.items():
                if name in codes:
                    return codes[name], t
        owner = self.object_type.get(name)
        if owner is None:
            raise SimulationError(f"unknown object or enum value '{name}'")
        return self.codes[owner][name], owner

    def global_name(self, value: Any) -> str:
        """A name (`k1`, `k2`...) for `value` in the generated code's globals
        (a constant array, made read-only, or a function it calls)."""
        self._global_count += 1
        name = f"k{self._global_count}"
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        self.ns[name] = value
        return name

    def const(self, value: Any, rtype: str, dtype: Any = None) -> _Node:
        """A value known when the simulator is built (never written to)."""
        arr = np.array(value, dtype=dtype)
        key = None
        if arr.size <= 4096:
            key = (arr.dtype.str, arr.shape, arr.tobytes(), rtype)
            hit = self._consts.get(key)
            if hit is not None:
                return hit
        node = _Node(self.global_name(arr), arr.shape, arr.dtype, rtype, False, value=arr)
        if key is not None:
            self._consts[key] = node
        return node

    def scalar(self, value: Any, scope: Scope, rtype: str, dtype: Any) -> _Node:
        return self.const(np.asarray(value, dtype=dtype).reshape((1,) * self.rank(scope)), rtype)

    def begin(self, name: str, params: str, large: bool = False, one: bool = False) -> _Code:
        """Start a function; `large`: for large batches (where memory
        traffic costs more than the number of numpy calls); `one`: for a
        batch of exactly one."""
        self.code = _Code(name, params, large, one)
        return self.code

    @property
    def large(self) -> bool:
        return self.code.large

    def build(self, code: _Code) -> Callable[..., Any]:
        return self.define(code.name, code.source())

    def define(self, name: str, source: str) -> Callable[..., Any]:
        """The function `name` of generated `source`, compiled in the
        generated code's namespace (its source kept in `sources`)."""
        self.sources[name] = source
        log.debug("generated %s:\n%s", name, source)
        exec(compile(source, f"<rddl {self.model.name}: {name}>", "exec"), self.ns)  # noqa: S102
        return self.ns.pop(name)  # type: ignore[no-any-return]

    def op(
        self,
        template: str,
        args: list[_Node],
        rtype: str,
        view: bool = False,
        bounds: Callable[..., tuple[Array, Array] | None] | None = None,
    ) -> _Node:
        """The value of `template` (a Python expression with {0}, {1}...
        for the arguments): folded when every argument is known, else one
        statement (or a value computed before with the same text).

        `view`: the value may share the first argument's memory (and has
        its bounds, rearranged the same way); `bounds`: computes the
        value's bounds from the arguments' (see `bounds_of`)."""
        text = template.format(*(a.code for a in args))
        if all(a.value is not None for a in args):
            try:
                with np.errstate(all="ignore"):
                    value = eval(_compiled(text), self.ns)  # noqa: S307
            except Exception:  # noqa: BLE001 - it raises at run time then, as it should
                pass
            else:
                return self.const(value, rtype)
        if len(args) == 2 and (args[0].value is None) != (args[1].value is None):
            cast = self._cast_constant(template, args)
            if cast is not None:
                args = cast
            if self.code.one:
                wide = self._widen_constant(template, args)
                if wide is not None:
                    args = wide
            elif self.code.large:
                spread = self._spread_constant(template, args)
                if spread is not None:
                    args = spread
            text = template.format(*(a.code for a in args))
        key = ("op", text)
        hit = self.code.lookup(key)
        if hit is not None:
            return hit
        shape, dtype = self._probe(template, args)
        name = self.code.temp()
        self.code.emit(f"{name} = {text}")
        owner = args[0].owner if view else name
        node = _Node(name, shape, dtype, rtype, any(a.batched for a in args), owner=owner)
        self.code.meta[name] = (shape, dtype, owner, node.batched)
        if view and len(args) == 1 and args[0].narrow is not None:
            # (the same rearrangement of the uint8 values, computed if used)
            node.narrow = self.op(template, [args[0].narrow], rtype, view=True)
        if view and len(args) == 1:
            b = self.bounds_of(args[0])
            if b is not None and args[0].dtype.kind != "b":  # (a bool's bounds go without saying)
                try:
                    with np.errstate(all="ignore"):
                        code = _compiled(template.format("_x"))
                        lo = eval(
                            code, self.ns, {"_x": np.broadcast_to(b[0], args[0].shape), "B": 1}
                        )  # noqa: S307
                        hi = eval(
                            code, self.ns, {"_x": np.broadcast_to(b[1], args[0].shape), "B": 1}
                        )  # noqa: S307
                    node.bounds = (np.asarray(lo), np.asarray(hi))
                except (ValueError, TypeError):
                    pass  # a view that is not a rearrangement (of the bytes, say): no bounds
        elif bounds is not None:
            given = [self.bounds_of(a) for a in args]
            if all(b is not None for b in given):
                with np.errstate(all="ignore"):
                    found = bounds(*given)
                # (finite, and small enough that int64 arithmetic cannot wrap)
                if found is not None and all((np.abs(x) < 2.0**52).all() for x in found):
                    node.bounds = (
                        np.asarray(found[0], dtype=np.float64),
                        np.asarray(found[1], dtype=np.float64),
                    )
        self.code.store(key, node)
        return node

    def _cast_constant(self, template: str, args: list[_Node]) -> list[_Node] | None:
        """For `_ufunc({0}, {1})` with one constant argument of another
        dtype than the ufunc's loop takes it in (`_add(k, x)`, k int64 and x
        float64): the arguments with the constant cast to that dtype once,
        when the simulator is built. The same values (the ufunc would make
        this very cast every call), without the per-call casting, which
        costs small steps about a microsecond per operation. None where
        nothing is to cast."""
        m = _UFUNC_CALL.match(template)
        if m is None:
            return None
        ufunc = self.ns.get(m.group(1))
        if not isinstance(ufunc, np.ufunc) or ufunc.nin != 2 or ufunc.nout != 1:
            return None
        i = 0 if args[0].value is not None else 1
        k = args[i]
        assert k.value is not None
        given = (args[0].dtype, args[1].dtype)
        try:
            loop = ufunc.resolve_dtypes((*given, None))
        except (TypeError, ValueError, AttributeError):
            return None
        want = np.dtype(loop[i])
        # (a safe cast only: exact, and it leaves the loop as it was)
        if k.dtype == want or not np.can_cast(k.dtype, want, "safe"):
            return None
        out = list(args)
        out[i] = self.const(k.value.astype(want), k.rtype)
        try:
            if tuple(ufunc.resolve_dtypes((out[0].dtype, out[1].dtype, None))) != tuple(loop):
                return None
        except (TypeError, ValueError):
            return None
        return out

    def _constant_operand(
        self, template: str, args: list[_Node]
    ) -> tuple[str, int, _Node, _Node] | None:
        """For an elementwise `_ufunc({0}, {1})` of two operands, one of them
        a constant: (the ufunc's name, the constant's position, the constant,
        the other operand); None for anything else."""
        m = _UFUNC_CALL.match(template)
        if m is None:
            return None
        ufunc = self.ns.get(m.group(1))
        if (
            not isinstance(ufunc, np.ufunc)
            or ufunc.nin != 2
            or ufunc.nout != 1
            or ufunc.signature is not None
        ):
            return None
        i = 0 if args[0].value is not None else 1
        k, x = args[i], args[1 - i]
        assert k.value is not None
        return m.group(1), i, k, x

    def _widen_constant(self, template: str, args: list[_Node]) -> list[_Node] | None:
        """In the code for a batch of one, for an elementwise
        `_ufunc({0}, {1})` of a constant and a value of more elements: the
        arguments with the constant broadcast to the value's shape when the
        simulator is built. The same values, and operands of one shape,
        which numpy adds in its fast loop: a broadcast costs a small
        operation about half a microsecond, two to three times its cost.
        (Not for batches of more than one: the constant would then be
        broadcast along the batch anyway.) None where nothing is to widen."""
        found = self._constant_operand(template, args)
        if found is None:
            return None
        _, i, k, x = found
        assert k.value is not None
        # (the value's shape here is its shape at run time: its batch axis,
        # last, is 1 here and 1 then)
        if (
            not x.batched
            or not x.shape
            or x.shape[-1] != 1
            or k.shape == x.shape
            or x.dtype.kind not in "biuf"
        ):
            return None
        if int(np.prod(x.shape)) > _WIDEN_LIMIT:
            return None
        if not _broadcasts_to(k.shape, x.shape):
            return None
        out = list(args)
        out[i] = self.const(np.broadcast_to(k.value, x.shape), k.rtype)
        return out

    def _spread_constant(self, template: str, args: list[_Node]) -> list[_Node] | None:
        """In the code for large batches, for an elementwise `_ufunc({0},
        {1})` of a constant and a batched value of as many groundings or
        more: the constant as numpy runs fastest against the value. That
        is a scalar where every value of the constant is the same (numpy's
        scalar loops), except for `_minimum` and `_maximum`, whose scalar
        loops are slow; otherwise the constant repeated along the batch
        into a contiguous array of the value's shape, made once per batch
        size (`_spread`): numpy broadcasts a column along a row of the
        batch two to three times slower than it reads a second array.
        The same values either way. None where nothing is to change."""
        found = self._constant_operand(template, args)
        if found is None:
            return None
        name, i, k, x = found
        assert k.value is not None
        if not x.batched or not x.shape or x.shape[-1] != 1 or x.dtype.kind not in "biuf":
            return None
        if k.dtype.kind not in "biuf" or k.value.ndim != len(x.shape) or not k.value.size:
            return None
        if not _broadcasts_to(k.shape, x.shape):
            return None
        cells = int(np.prod(x.shape))
        flat = k.value.reshape(-1)
        same = (
            bool((flat == flat[0]).all()) and not np.isnan(flat[0])
            if k.dtype.kind == "f"
            else bool((flat == flat[0]).all())
        )
        slow_scalar = name in ("_minimum", "_maximum")
        out = list(args)
        if same and not slow_scalar:
            if k.shape == (1,) * len(k.shape):
                return None
            out[i] = self.const(flat[:1].reshape((1,) * len(k.shape)), k.rtype)
            return out
        if cells > _SPREAD_CELLS:
            return None
        if k.shape == (1,) * len(k.shape) and not slow_scalar:
            return None
        b = self.bounds_of(k)
        out[i] = _Node(self.spread(k.code, x.shape), x.shape, k.dtype, k.rtype, False, bounds=b)
        return out

    def spread(self, const: str, shape: tuple[int, ...]) -> str:
        """The local name of the constant named `const` repeated along the
        batch to `shape` (batch axis last, 1 here), made at the top of the
        function being written (see `_spread_constant`)."""
        code = self.code
        key = (const, shape)
        name = code.spread.get(key)
        if name is None:
            name = code.spread[key] = f"w{len(code.spread) + 1}"
            code.inputs[name] = f"_spread({const}, {_last_shape_code(shape[:-1])})"
        return name

    @staticmethod
    def bounds_of(node: _Node) -> tuple[Array, Array] | None:
        """Elementwise bounds of a value, where known: sound for the
        operations that carry them (IEEE rounding is monotone, and the
        bounds are computed with the same operations as the values)."""
        if node.bounds is not None:
            return node.bounds
        if node.value is not None and node.value.dtype.kind in "bif":
            v = node.value.astype(np.float64)
            if np.isfinite(v).all():
                return v, v
            return None
        if node.dtype == np.bool_:
            return np.zeros((1,) * len(node.shape)), np.ones((1,) * len(node.shape))
        return None

    def _probe(self, template: str, args: list[_Node]) -> tuple[tuple[int, ...], np.dtype[Any]]:
        """Shape and dtype of `template`'s value, found by running it once
        on stand-ins (zeros, batch of one) for the values not known."""
        local: dict[str, Any] = {"B": 1}
        names = []
        for i, a in enumerate(args):
            if a.value is not None:
                names.append(a.code)
            else:
                local[f"_d{i}"] = np.zeros(a.shape, a.dtype)
                names.append(f"_d{i}")
        with np.errstate(all="ignore"):
            out = np.asarray(eval(_compiled(template.format(*names)), self.ns, local))  # noqa: S307
        return out.shape, out.dtype

    def emit_value(self, text: str, shape: tuple[int, ...], dtype: Any, rtype: str) -> _Node:
        """A statement whose value is never folded or reused (a draw)."""
        name = self.code.temp()
        self.code.emit(f"{name} = {text}")
        self.code.meta[name] = (shape, np.dtype(dtype), name, True)
        return _Node(name, shape, np.dtype(dtype), rtype, True, owner=name)

    def expand(self, node: _Node, keep: list[bool]) -> _Node:
        """`node` (over the kept scope variables) over the whole scope."""
        out = self.op("{0}" + _index_code(keep), [node], node.rtype, view=True)
        if out.value is None and out.unexpanded is None:
            out.unexpanded = node
        return out

    def cast(self, node: _Node, dtype: Any) -> _Node:
        dtype = np.dtype(dtype)
        if node.dtype == dtype:
            return node
        # (truncation is monotone: the bounds truncated)
        bound = _bounds_trunc if dtype.kind in "iu" else _bounds_same
        return self.op(f"{{0}}.astype({_DTYPE_CODE[dtype]})", [node], node.rtype, bounds=bound)

    def logic(self, ufunc: str, a: _Node, b: _Node, rtype: str = "bool") -> _Node:
        """`_land` or `_lor` of two values. For large batches, where one is a
        bool constant, on uint8 views: numpy's bool loops are slow (about
        20 times) when an operand is broadcast along a long inner loop."""
        if self.large and a.dtype == b.dtype == np.bool_ and (a.value is None) != (b.value is None):
            const, other = (a, b) if a.value is not None else (b, a)
            assert const.value is not None
            u8 = self.global_name(const.value.view(np.uint8))
            bit = "_bitand" if ufunc == "_land" else "_bitor"
            return self.op(f"{bit}({{0}}.view(_u8), {u8}).view(_bool)", [other], rtype)
        return self.op(f"{ufunc}({{0}}, {{1}})", [a, b], rtype)

    def batch_last(self, text: str, rank: int) -> str:
        """Code for the batch-first array `text` viewed batch last; for large
        batches copied so (operations on mixed layouts are slow)."""
        if rank <= 1:
            return text
        if self.large:
            return f"_contiguous(({text}){_batch_last(rank)})"
        return f"({text}){_batch_last(rank)}"

    def total(
        self, node: _Node, axes: tuple[int, ...], rtype: str, keepdims: bool = False
    ) -> _Node:
        """`node` summed over `axes` (as np.sum: bools counted as int64).
        For large batches, bools are counted in bytes where fewer than 256
        are added (several times faster than adding them as int64)."""
        # (the ufunc's reduce called as `x.sum(axis=...)` calls it, without
        # numpy's Python-level wrapper: a step makes many small reductions)
        keep = ", None, True" if keepdims else ""
        count = int(np.prod([node.shape[a] for a in axes]))
        if self.large and node.dtype == np.bool_ and count < 256:
            return self.op(
                f"_sum({{0}}.view(_u8), {_axis_code(axes)}, _u8{keep}).astype(_i64)", [node], rtype
            )
        if keepdims:
            return self.op(f"_sum({{0}}, {_axis_code(axes)}, None{keep})", [node], rtype)
        return self.op(f"_sum({{0}}, {_axis_code(axes)})", [node], rtype)

    def lnot(self, a: _Node) -> _Node:
        return self.op("_lnot({0})", [a], "bool")

    def table(self, t: str) -> str:
        if t not in self._tables:
            self._tables[t] = self.global_name(self.numeric_of_code[t])
        return self._tables[t]

    def fail(self, func: Callable[..., None], *args: str) -> None:
        """A statement that calls `func` (which raises) with values by name."""
        self.code.emit(f"{self.global_name(func)}({', '.join(args)})")

    # -- what an expression depends on --------------------------------

    # (the caches below are keyed by id and keep the expression alive, so
    # that an id is never reused by another expression)

    def is_random(self, e: A.Expr) -> bool:
        hit = self._random.get(id(e))
        if hit is None:
            hit = (e, A.is_draw(e) or any(self.is_random(c) for c in A.children(e)))
            self._random[id(e)] = hit
        return hit[1]

    def free_vars(self, e: A.Expr) -> frozenset[str]:
        hit = self._free.get(id(e))
        if hit is None:
            if isinstance(e, A.Var):
                found = frozenset((e.name,))
            else:
                found = frozenset().union(*(self.free_vars(c) for c in A.children(e)))
                if isinstance(e, (A.Aggregation, A.DiscreteOver)):
                    found = found - {p.name for p in e.params}
            hit = self._free[id(e)] = (e, found)
        return hit[1]

    def is_static(self, e: A.Expr) -> bool:
        """Reads only non-fluents and constants (so it folds), and draws nothing."""
        hit = self._static.get(id(e))
        if hit is None:
            static = not self.is_random(e)
            if static and isinstance(e, A.PVar):
                p = self.model.pvariables.get(e.name)
                static = p is None or e.default or p.kind == NON_FLUENT
            static = static and all(self.is_static(c) for c in A.children(e))
            hit = self._static[id(e)] = (e, static)
        return hit[1]

    # -- expressions -------------------------------------------------

    def compile(self, e: A.Expr, scope: Scope, hint: str | None = None) -> _Node:
        """The value of `e` in `scope` (statements added to the function)."""
        method = getattr(self, "_" + type(e).__name__)
        if self.is_random(e):
            return method(e, scope, hint)  # type: ignore[no-any-return]
        # a pure expression: in the scope of the variables it reads, once
        names = [v for v, _ in scope]
        used = sorted(
            {
                max(i for i, v in enumerate(names) if v == name)
                for name in self.free_vars(e)
                if name in names
            }
        )
        if len(used) < len(scope):
            node = self.compile(e, tuple(scope[i] for i in used), hint)
            kept = set(used)
            return self.expand(node, [i in kept for i in range(len(scope))])
        key = ("expr", self.context, e, scope, hint)
        hit = self.code.lookup(key)
        if hit is None:
            hit = method(e, scope, hint)
            self.code.store(key, hit)
        return hit

    def numeric(self, e: A.Expr, scope: Scope) -> _Node:
        """Compile for use as a number (enum @1..@n -> their integers)."""
        return self.to_numeric(self.compile(e, scope))

    def to_numeric(self, node: _Node) -> _Node:
        if node.rtype in self.numeric_of_code:
            return self.op(self.table(node.rtype) + "[{0}]", [node], "int")
        return node
