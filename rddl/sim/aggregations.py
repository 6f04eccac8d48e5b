"""Compiling aggregations (`sum_`, `prod_`, `exists_`, `forall_`, `min_`,
`max_`, `avg_`, `argmax_`, `argmin_`) and their contractions.

Owns `_Aggregations`, the layer of the compiler (over `operators._Operators`)
that compiles `_Aggregation`: a reduction over the aggregation's axes,
except where the body has a shape that allows better:

- `_distribute`: a sum of a sum or difference as two sums;
- `_contract`: `sum` or `exists` over a product (or conjunction) with
  factors known when the simulator is built (a relation: CONNECTED,
  NEIGHBOR...) as one matrix product with that constant, or, where the
  relation pairs each value with few others (`_sparse`, at most
  `_SPARSE_MAX`), as a few row gathers (`runtime._gather_sum`);
- `_eliminate`: a variable only one factor depends on summed (or
  quantified) in that factor first;
- a short axis (2 to 8 values) combined slice by slice.

May call `operators` (`binary`, and all of `base`), `code`, `bounds`,
`runtime`'s constants and `state`.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from .. import ast as A
from .bounds import Bounds, _bounded, _bounds_mul
from .code import _DTYPES, _LARGE_BATCH, Scope, _axis_code, _Node, _tuple_code
from .operators import _Operators
from .runtime import _BLAS_BLOCK
from .state import Array, SimulationError

_SPARSE_MAX = 12  # row gathers, at most, instead of a matrix product in a contraction


def _leaves(e: A.Expr, chain: str) -> list[A.Expr]:
    """The operands of a chain of one binary operator, left to right."""
    if isinstance(e, A.Binary) and e.op == chain:
        return _leaves(e.left, chain) + _leaves(e.right, chain)
    return [e]


class _Aggregations(_Operators):
    """The compiler's methods for aggregations (see the module's docstring)."""

    def _Aggregation(self, e: A.Aggregation, scope: Scope, hint: str | None) -> _Node:
        inner = scope + tuple((p.name, p.type) for p in e.params)
        n, k = len(scope), len(e.params)
        sizes = tuple(self.sizes[p.type] for p in e.params)
        op = e.op
        if op == "sum" and not self.is_random(e.body):
            split = self._distribute(e)
            if split is not None:
                return self.compile(split, scope, hint)
        body: _Node | None = None
        chain = e.body.op if isinstance(e.body, A.Binary) else None
        if (
            op in ("sum", "exists")
            and chain in ("^", "*")
            and not (op == "exists" and chain == "*")
        ):
            assert isinstance(e.body, A.Binary) and chain is not None
            leaves = _leaves(e.body, chain)
            nodes = [self.numeric(leaf, inner) for leaf in leaves]
            if 0 not in sizes:
                out = self._contract(op, chain, nodes, n, k, sizes)
                if out is None:
                    out = self._eliminate(op, chain, nodes, n, k, sizes)
                if out is not None:
                    return out
            body = self._rebuild(e.body, chain, iter(nodes))
        if body is None:
            body = self.numeric(e.body, inner)
        bt = body.rtype
        # the aggregation's variables: the axes just before the batch axis
        axes = _axis_code(tuple(range(n, n + k)))
        if 0 in sizes or op in ("prod", "avg", "argmax", "argmin"):
            # as the definition says: over every grounding of the variables
            full = f"_broadcast_to({{0}}, {{0}}.shape[:{n}] + {sizes} + {{0}}.shape[-1:])"
            if op == "sum":
                return self.op(
                    f"np.sum({full}, axis={axes})", [body], "int" if bt == "bool" else bt
                )
            if op == "prod":
                return self.op(
                    f"np.prod({full}, axis={axes})", [body], "int" if bt == "bool" else bt
                )
            if op == "avg":
                return self.op(f"np.mean({full}, axis={axes})", [body], "real")
            if op in ("min", "max"):
                return self.op(f"np.{op}({full}, axis={axes})", [body], bt)
            if op == "forall":
                return self.op(f"np.all({full}, axis={axes})", [body], "bool")
            if op == "exists":
                return self.op(f"np.any({full}, axis={axes})", [body], "bool")
            if op in ("argmax", "argmin"):
                return self.op(f"np.{op}({full}, axis={n})", [body], e.params[0].type)
        size = int(np.prod(body.shape))
        if (
            k == 1
            and op in ("sum", "min", "max", "forall", "exists")
            and body.shape[n] > 1
            and (body.shape[n] <= 2 or (body.shape[n] <= 8 and size >= 2048))
        ):
            # a short axis: its slices combined, not a reduction (numpy
            # reduces a short axis in many short loops, slowly)
            parts = [
                "{0}[" + ", ".join([":"] * n + [str(j), ":"]) + "]" for j in range(body.shape[n])
            ]
            if op == "sum":
                if body.dtype == np.bool_:
                    parts[0] += ".astype(_i64)"
                return self.op(" + ".join(parts), [body], "int" if bt == "bool" else bt)
            ufunc = {"min": "_minimum", "max": "_maximum", "forall": "_land", "exists": "_lor"}[op]
            text = parts[0]
            for part in parts[1:]:
                text = f"{ufunc}({text}, {part})"
            return self.op(text, [body], bt if op in ("min", "max") else "bool")
        if op == "sum":
            out = self.total(body, tuple(range(n, n + k)), "int" if bt == "bool" else bt)
            # the body does not depend on some of the variables: each value counts that often
            times = 1
            for j in range(k):
                if body.shape[n + j] == 1:
                    times *= sizes[j]
            return out if times == 1 else self.op(f"{{0}} * {times}", [out], out.rtype)
        if op in ("min", "max"):
            return self.op(f"_{op}_reduce({{0}}, {axes})", [body], bt)
        if op == "forall":
            return self.op(f"_all({{0}}, {axes}, _bool)", [body], "bool")
        if op == "exists":
            return self.op(f"_any({{0}}, {axes}, _bool)", [body], "bool")
        raise SimulationError(f"{e.loc}: aggregation '{op}_' is not supported by the simulator")

    def _eliminate(
        self, op: str, chain: str, nodes: list[_Node], n: int, k: int, sizes: tuple[int, ...]
    ) -> _Node | None:
        """`sum` or `exists` over k variables of a product (or conjunction)
        where a variable only one factor depends on is summed (or
        quantified) in that factor first: `sum_{?c, ?i} a(?c, ?i) * b(?p, ?i)`
        is `sum_{?i} (sum_{?c} a(?c, ?i)) * b(?p, ?i)`, without the tensor
        over every (?p, ?c, ?i). None where no variable is like that."""
        if chain == "^" and any(x.dtype != np.bool_ for x in nodes):
            return None
        if chain == "*" and any(x.dtype.kind not in "bif" or x.rtype not in _DTYPES for x in nodes):
            return None
        nodes = list(nodes)
        changed = False
        times = 1
        for j in range(k):
            a = n + j
            deps = [i for i, x in enumerate(nodes) if x.shape[a] > 1]
            if len(deps) == 1:
                i = deps[0]
                if op == "exists":
                    nodes[i] = self.op(
                        f"_any({{0}}, {a}, _bool, None, True)", [nodes[i]], nodes[i].rtype
                    )
                else:
                    nodes[i] = self.total(nodes[i], (a,), nodes[i].rtype, keepdims=True)
                changed = True
            elif not deps:
                times *= sizes[j]
        if not changed:
            return None
        axes = _axis_code(tuple(range(n, n + k)))
        real = chain == "*" and any(x.rtype == "real" for x in nodes)
        f = nodes[0]
        for x in nodes[1:]:
            if op == "exists":
                f = self.logic("_land", f, x)
            else:  # (counts times bools: a product)
                f = self.op("_mul({0}, {1})", [f, x], "real" if real else "int", bounds=_bounds_mul)
        if op == "exists":
            return self.op(f"_any({{0}}, {axes}, _bool)", [f], "bool")
        out = self.total(f, tuple(range(n, n + k)), "real" if real else "int")
        return out if times == 1 else self.op(f"{{0}} * {times}", [out], out.rtype)

    def _distribute(self, e: A.Aggregation) -> A.Expr | None:
        """A sum over a sum or difference as the sum or difference of two
        sums (`sum (a - b)` = `sum a - sum b`; in a product, `sum K * (a - b)`
        = `sum K * a - sum K * b`), where that lets a part become a matrix
        product or a count; None where it does not help."""
        body = e.body

        def agg(b: A.Expr) -> A.Aggregation:
            return A.Aggregation(op="sum", params=e.params, body=b, loc=e.loc)

        if isinstance(body, A.Binary) and body.op in ("+", "-"):
            return A.Binary(op=body.op, left=agg(body.left), right=agg(body.right), loc=body.loc)
        if not (isinstance(body, A.Binary) and body.op == "*"):
            return None
        leaves = _leaves(body, "*")
        split = [
            x
            for x in leaves
            if isinstance(x, A.Binary) and x.op in ("+", "-") and not self.is_static(x)
        ]
        if len(split) != 1 or not any(self.is_static(x) for x in leaves):
            return None
        target = split[0]
        assert isinstance(target, A.Binary)

        def replace(x: A.Expr, new: A.Expr) -> A.Expr:
            if x is target:
                return new
            if isinstance(x, A.Binary) and x.op == "*":
                return A.Binary(
                    op="*", left=replace(x.left, new), right=replace(x.right, new), loc=x.loc
                )
            return x

        return A.Binary(
            op=target.op,
            left=agg(replace(body, target.left)),
            right=agg(replace(body, target.right)),
            loc=target.loc,
        )

    def _rebuild(self, e: A.Expr, chain: str, nodes: Iterator[_Node]) -> _Node:
        """The value of a chain of `chain` operators from its leaves' values."""
        if isinstance(e, A.Binary) and e.op == chain:
            left = self._rebuild(e.left, chain, nodes)
            right = self._rebuild(e.right, chain, nodes)
            return self.binary(e, left, right)
        return next(nodes)

    def _contract(
        self, op: str, chain: str, nodes: list[_Node], n: int, k: int, sizes: tuple[int, ...]
    ) -> _Node | None:
        """`sum` or `exists` over k variables (the axes n..n+k-1) of the
        product (or conjunction) of `nodes`, where some factors are known
        when the simulator is built (a relation: CONNECTED, NEIGHBOR...):
        a product of the fluent factors with that constant matrix, or, where
        the relation pairs each value with few others, a few row gathers.
        None where the pattern does not apply."""
        known = [x for x in nodes if x.value is not None]
        fluent = [x for x in nodes if x.value is None]
        if not known or not fluent:
            return None
        if chain == "^":
            if any(x.dtype != np.bool_ for x in nodes):
                return None
        elif any(x.dtype.kind not in "bif" or x.rtype not in _DTYPES for x in nodes):
            return None
        # fluent factors that do not depend on the variables summed over
        # multiply the sum instead of every term
        outer = [x for x in fluent if all(x.shape[n + j] == 1 for j in range(k))]
        if outer and len(outer) < len(fluent):
            inner_nodes = [x for x in nodes if not any(x is o for o in outer)]
            out = self._contract(op, chain, inner_nodes, n, k, sizes)
            if out is None:
                return None
            for x in outer:
                x = self.op("{0}[..." + ", 0" * k + ", :]", [x], x.rtype, view=True)
                if op == "exists":
                    out = self.logic("_land", out, x)
                else:
                    rtype = "real" if "real" in (out.rtype, x.rtype) else "int"
                    out = self.op("_mul({0}, {1})", [out, x], rtype, bounds=_bounds_mul)
            return out
        with np.errstate(all="ignore"):
            first_value = known[0].value
            assert first_value is not None
            kv: Array = first_value
            for x in known[1:]:
                assert x.value is not None
                kv = np.logical_and(kv, x.value) if chain == "^" else kv * x.value
        f = fluent[0]
        for x in fluent[1:]:
            if chain == "^":
                f = self.logic("_land", f, x)
            else:
                f = self.op("_mul({0}, {1})", [f, x], "real", bounds=_bounds_mul)
        real = any(x.rtype == "real" for x in nodes) and chain == "*"
        fs, ks = f.shape[:-1], kv.shape[:-1]
        # bounds of a sum of integers (exact, whatever the order of the additions)
        sum_bounds: Bounds | None = None
        fb = self.bounds_of(f)
        if op == "sum" and fb is not None and f.dtype.kind in "bi" and np.all(np.mod(kv, 1) == 0):
            with np.errstate(all="ignore"):
                ends = [kv * fb[0], kv * fb[1]]
                ends = [np.broadcast_to(x, x.shape[:n] + sizes + x.shape[n + k :]) for x in ends]
                lo = np.minimum(ends[0], ends[1]).sum(axis=tuple(range(n, n + k)))
                hi = np.maximum(ends[0], ends[1]).sum(axis=tuple(range(n, n + k)))
            sum_bounds = (lo.astype(np.float64), hi.astype(np.float64))
        contracted, k_only, f_only = [], [], []
        times = 1
        for j in range(k):
            a = n + j
            if fs[a] > 1 and ks[a] > 1:
                contracted.append(a)
            elif ks[a] > 1:
                k_only.append(a)
            elif fs[a] > 1:
                f_only.append(a)
            else:
                times *= sizes[j]
        # variables only one side depends on: reduce them on that side first
        if k_only:
            ax = tuple(k_only)
            kv = np.asarray(
                kv.any(axis=ax, keepdims=True) if op == "exists" else kv.sum(axis=ax, keepdims=True)
            )
        if f_only:
            if op == "exists":
                f = self.op(
                    f"_any({{0}}, {_axis_code(tuple(f_only))}, _bool, None, True)", [f], f.rtype
                )
            else:
                f = self.total(f, tuple(f_only), f.rtype, keepdims=True)
        if not contracted:
            # nothing left to sum over both: a product, its bound variables dropped
            knode = self.const(kv, "real")
            if op == "exists":
                out = self.logic("_land", f, knode)
            else:
                if not real and f.dtype == np.bool_ and kv.dtype == np.bool_:
                    knode = self.const(kv.astype(np.int64), "int")
                out = self.op("_mul({0}, {1})", [f, knode], "real" if real else "int")
                if not real and out.dtype != np.int64:
                    out = self.op("{0}.astype(_i64)", [out], "int")
                if times != 1:
                    out = self.op(f"{{0}} * {times}", [out], out.rtype)
            out = self.op("{0}[..." + ", 0" * k + ", :]", [out], out.rtype, view=True)
            return _bounded(out, sum_bounds)
        shared = [i for i in range(n) if fs[i] > 1 and ks[i] > 1]
        f_out = [i for i in range(n) if fs[i] > 1 and ks[i] == 1]
        k_out = [i for i in range(n) if ks[i] > 1 and fs[i] == 1]
        size = [max(fs[i], ks[i]) for i in range(n + k)]
        S, C, KO = (
            int(np.prod([size[i] for i in ax], dtype=np.int64))
            for ax in (shared, contracted, k_out)
        )
        # the constant side as (S, KO, C) matrices, the fluent side as
        # (S, C, columns): f's axes in the order shared, contracted, f_out, batch
        first = shared + k_out + contracted
        rest = [i for i in range(n + k) if i not in first]
        kmat = kv[..., 0].transpose(first + rest).reshape(S, KO, C)
        f_axes = shared + contracted + f_out
        fperm = f_axes + [i for i in range(n + k) if i not in f_axes] + [n + k]
        # (axes of size 1 may stay anywhere: the reshape below drops them)
        in_place = [i for i in range(n + k) if fs[i] > 1] == f_axes
        fx = "{0}" if in_place else f"{{0}}.transpose({tuple(fperm)})"
        if in_place and f.unexpanded is not None:
            f = f.unexpanded  # (the same memory order of the same axes)
        sparse = self._sparse(kmat[0], unit=op == "sum") if S == 1 and self.large else None
        if sparse is not None:
            # a relation with few pairs per value (neighbours, successors, a
            # 0/1 relation): a few row gathers, not a product over every pair;
            # the gathered rows index a zero row added below the others where
            # a value has fewer pairs
            cols, padded = sparse
            flat = self.op(f"{fx}.reshape({C}, -1)", [f], f.rtype, view=True)
            if padded:
                flat = self.op("_pad_zero_row({0})", [flat], f.rtype)
            rows = [
                self.const(c, "int").code for c in cols
            ]  # (the same text for the same relation)
            if f.dtype == np.bool_:
                # counts of bools, added as bytes (at most _SPARSE_MAX of
                # them); an exists is a count above 0, so that an exists and
                # a sum over the same relation share the count
                flat = self.op("{0}.view(_u8)", [flat], "int", view=True)
                count = self.op(f"_gather_sum({{0}}, {_tuple_code(rows)})", [flat], "int")
                if op == "exists":
                    out = self.op("{0} > 0", [count], "bool")
                else:
                    out = self.op("{0}.astype(_i64)", [count], "int")
                    if out.value is None and out.narrow is None:
                        out.narrow = count
            elif op == "sum":
                out = self.op(f"_gather_sum({{0}}, {_tuple_code(rows)})", [flat], f.rtype)
            else:
                out = self.op(f"{{0}}[{rows[0]}]", [flat], f.rtype)
                for r in rows[1:]:
                    out = self.op(f"_lor({{0}}, {{1}}[{r}])", [out, flat], f.rtype)
                if op == "sum" and not real and out.dtype != np.int64:
                    out = self.op("{0}.astype(_i64)", [out], "int")
        else:
            # counts of bools are exact in float32 (below 2**24); a sum stays
            # float64 (exact for integers below 2**53, which int sums are
            # here): no cast back, the values are those of the int sum
            # (float64 for both sum and exists, so that an exists and a sum
            # over the same relation share one product)
            dt, dcode = np.float64, "_f64"
            matmul = "_matmul_cols"
            FO = int(np.prod([size[i] for i in f_out], dtype=np.int64))
            if not self.large and S * KO * C * FO * _LARGE_BATCH <= _BLAS_BLOCK:
                matmul = "_matmul"
            shape = f"{C}, -1" if S == 1 else f"{S}, {C}, -1"
            if (
                matmul == "_matmul"
                and op == "exists"
                and f.dtype == np.bool_
                and kv.dtype == np.bool_
            ):
                # small: numpy's boolean product is the exists itself (no casts)
                mat = self.const(
                    np.ascontiguousarray(kmat[0] if S == 1 else kmat, dtype=bool), "bool"
                ).code
                out = self.op(f"_matmul({mat}, {fx}.reshape({shape}))", [f], "bool")
            else:
                mat = self.const(
                    np.ascontiguousarray(kmat[0] if S == 1 else kmat, dtype=dt), "real"
                ).code
                text = f"{matmul}({mat}, {fx}.reshape({shape}).astype({dcode}, copy=False))"
                out = self.op(text, [f], "real" if real else "int")
                if op == "exists":
                    out = self.op("{0} > 0", [out], "bool")
        if times != 1 and op == "sum":
            out = self.op(f"{{0}} * {times}", [out], out.rtype)
        # (shared, k_out, f_out, batch) -> scope order, batch last
        axes_now = shared + k_out + f_out
        # (the product's columns are f_out's values times the batch: a
        # reshape, unless there are no f_out axes and it has the shape already)
        if f_out or out.shape[:-1] != tuple(size[i] for i in axes_now):
            out = self.op(
                "{0}.reshape(" + _tuple_code([*(str(size[i]) for i in axes_now), "-1"]) + ")",
                [out],
                out.rtype,
                view=True,
            )
        ordered = sorted(axes_now)
        if axes_now != ordered:
            perm = (*(axes_now.index(i) for i in ordered), len(ordered))
            out = self.op(f"{{0}}.transpose({perm})", [out], out.rtype, view=True)
        if len(ordered) < n:
            kept = set(ordered)
            out = self.expand(out, [i in kept for i in range(n)])
        return _bounded(out, sum_bounds)

    @staticmethod
    def _sparse(kmat: Array, unit: bool) -> tuple[list[Array], bool] | None:
        """For a (KO, C) matrix with at most a few nonzeros per row (all 1
        if `unit`): the column of each row's j-th nonzero, C (a zero row
        added below) where a row has fewer; and whether any has fewer.
        None where the matrix is not like that."""
        nonzero = kmat != 0
        if unit and not (kmat[nonzero] == 1).all():
            return None
        counts = nonzero.sum(axis=1)
        most = int(counts.max()) if counts.size else 0
        if most == 0 or most > _SPARSE_MAX or most * 2 > kmat.shape[1]:
            return None
        cols = [np.full(kmat.shape[0], kmat.shape[1], dtype=np.intp) for _ in range(most)]
        for o in range(kmat.shape[0]):
            for j, c in enumerate(np.nonzero(nonzero[o])[0]):
                cols[j][o] = c
        return cols, bool((counts < most).any())
