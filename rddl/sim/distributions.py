"""Compiling the random draws: `Bernoulli`, `Normal`, `Discrete` and
`UnnormDiscrete` (over listed cases or `_` over a variable), the other
distributions through `samplers`, and `KronDelta` / `DiracDelta`.

Owns `_Distributions`, the layer of the compiler (over `base._CompilerBase`)
with one method per distribution AST class, `_bernoulli` (a uniform slot
compared with p * 2**32, see the package's docstring), and `_check`: a
parameter check made when the simulator is built, proved needless by the
parameter's bounds, or one test over the whole array at run time. Every
draw is one statement (`emit_value`) that is never folded or reused.

May call `base`, `code`, `samplers` (the draw functions the generated code
calls), `runtime`'s constants and `state`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import ast as A
from .base import _CompilerBase
from .code import Scope, _batch_first, _last_shape_code, _Node, _shape_code
from .runtime import _SPREAD_CELLS, _TWO_32
from .samplers import (
    _discrete_over_sampler,
    _discrete_sampler,
    _fixed_categorical,
    _param_error,
    _sampler,
)
from .state import Array, SimulationError


class _Distributions(_CompilerBase):
    """The compiler's methods for random draws (see the module's docstring)."""

    def _Distribution(self, e: A.Distribution, scope: Scope, hint: str | None) -> _Node:
        name = e.name
        if name == "KronDelta":
            return self.compile(e.args[0], scope, hint)
        if name == "DiracDelta":
            x = self.numeric(e.args[0], scope)
            return self.op("{0}.astype(_f64, copy=False)", [x], "real", view=True)
        params = [self.numeric(a, scope) for a in e.args]
        where = f"{e.loc}: {name}"
        # one independent draw per batch element and per grounding of every
        # variable in scope, whatever the parameters depend on
        full = self.scope_shape(scope)
        # drawn batch first, as (B, *full) in C order, whatever the layout
        # here: the stream does not depend on how values are laid out
        shape = _shape_code(full)
        rank = 1 + len(full)
        first = _batch_first(rank)
        if name == "Bernoulli":
            (p,) = params
            self._check(p, lambda v: (v < 0) | (v > 1), "_cnz(_lt({0}, 0.0)) or _cnz(_gt({0}, 1.0))",
                        _param_error(where, "probability outside [0, 1]", lambda v: (v < 0) | (v > 1)))  # fmt: skip
            return self._bernoulli(p, full, where)
        if name == "Normal":
            m, v = params
            self._check(
                v,
                lambda x: x < 0,
                "_cnz(_lt({0}, 0))",
                _param_error(where, "variance is negative", lambda x: x < 0),
            )
            sd = self.op("_sqrt({0})", [v], "real")
            self.code.draws.append(where)
            # loc + scale * z: what rng.normal(loc, scale) computes, draw for
            # draw, without its slow per-element broadcasting loop; drawn
            # batch last, as laid out here
            z = self.emit_value(
                f"rng.standard_normal({_last_shape_code(full)})", (*full, 1), np.float64, "real"
            )
            if self.large:
                # (two operations, each written in place, with its constant
                # as numpy takes it fastest: see `_spread_constant`)
                return self.op(
                    "_add({0}, {1})", [m, self.op("_mul({0}, {1})", [sd, z], "real")], "real"
                )
            return self.op("_add({0}, _mul({1}, {2}))", [m, sd, z], "real")
        sampler = _sampler(name, where)
        if sampler is None:
            raise SimulationError(f"{where} is not supported by the simulator")
        draw, out = sampler
        self.code.draws.append(where)
        args = ", ".join(p.code + first for p in params)
        dtype = np.int64 if out == "int" else np.float64
        return self.emit_value(
            self.batch_last(f"{self.global_name(draw)}(rng, {shape}, {args})", rank),
            (*full, 1),
            dtype,
            out,
        )

    def _bernoulli(self, p: _Node, full: tuple[int, ...], where: str) -> _Node:
        """Bernoulli(p) (p checked), one draw per batch element and per
        grounding of the scope (`full`): a uniform integer u of a slot
        compared with p * 2**32 (see `_uniforms` for the precision). Where
        p is known, the threshold is folded, in uint32 where it fits; where
        it is 0 (or 1) everywhere, nothing is drawn."""
        rank = len(full) + 1
        if p.value is not None:
            v = np.asarray(p.value, dtype=np.float64)
            if v.size and ((v == 0).all() or (v == 1).all()):
                # (the same in every state: a constant, and the stream does
                # not depend on the states either)
                return self.const(np.full((1,) * rank, bool(v.flat[0])), "bool")
        self.code.draws.append(where)
        u = self.code.uniform(full)
        if p.value is None:
            two_32 = self.const(np.full((1,) * rank, _TWO_32), "real")
            scaled_p = self.op("_mul({0}, {1})", [p, two_32], "real")
            return self.emit_value(f"_lt({u}, {scaled_p.code})", (*full, 1), np.bool_, "bool")
        scaled = np.asarray(p.value, dtype=np.float64) * _TWO_32
        limit = np.ceil(scaled)
        valid = bool(((scaled >= 0) & (scaled <= _TWO_32)).all())  # (else it raises before)
        k: Array
        if valid and limit.max(initial=0) <= 2**32 - 1:
            # u < limit, in uint32
            cmp, k = "_lt", limit.astype(np.uint32)
        elif valid and limit.min(initial=1) >= 1:
            # u <= limit - 1, in uint32 (p = 1 somewhere, never 0)
            cmp, k = "_le", (limit - 1).astype(np.uint32)
        else:
            cmp, k = "_lt", scaled
        name = self.global_name(k)
        if self.large and k.size and k.ndim == rank:
            # (as `_spread_constant` does for other operations)
            flat = k.reshape(-1)
            if (flat == flat[0]).all():
                name = self.global_name(flat[:1].reshape((1,) * rank))
            elif int(np.prod(full, dtype=np.int64)) <= _SPREAD_CELLS:
                name = self.spread(name, (*full, 1))
        return self.emit_value(f"{cmp}({u}, {name})", (*full, 1), np.bool_, "bool")

    def _check(
        self, x: _Node, bad: Callable[[Array], Array], test: str, fail: Callable[[Array], None]
    ) -> None:
        """A parameter check: when the simulator is built if `x` is known
        (a statement that raises at run time only if it fails), else one
        test over the whole array at run time."""
        if x.value is not None:
            with np.errstate(all="ignore"):
                failed = bool(np.any(bad(x.value)))
            if failed:
                self.fail(fail, x.code)
            return
        b = self.bounds_of(x)
        if b is not None and not np.any(bad(b[0])) and not np.any(bad(b[1])):
            return  # every value it can take is valid (for an interval condition)
        with self.code.block(f"if {test.format(x.code)}:"):
            self.fail(fail, x.code)

    def _Discrete(self, e: A.Discrete, scope: Scope, hint: str | None) -> _Node:
        if e.count is not None:
            raise SimulationError(f"{e.loc}: {e.name} is not supported by the simulator")
        t = e.type
        labels = []
        probs: list[_Node | None] = []
        for dc in e.cases:
            name = dc.label.name  # type: ignore[union-attr]
            if t in self.codes and name not in self.codes[t] and "@" + name in self.codes[t]:
                name = "@" + name
            labels.append(self.code_of(name, t)[0])
            probs.append(None if dc.prob is None else self.numeric(dc.prob, scope))
        codes = np.array(labels, dtype=np.int64)
        normalise = e.name == "UnnormDiscrete"
        where = f"{e.loc}: {e.name}"
        draw_shape = self.scope_shape(scope)
        shape = _shape_code(draw_shape)
        rank = 1 + len(draw_shape)
        to_first = _batch_first(rank)
        self.code.draws.append(where)
        out_shape = (*draw_shape, 1)
        if all(p is None or p.value is not None for p in probs):
            # computed batch first, as the draws are made
            values = [None if p is None else np.asarray(p.value)[..., 0][None] for p in probs]
            fixed = _fixed_categorical(values, (1, *draw_shape), normalise)
            if fixed is not None:
                cum, total = fixed
                k = cum.shape[-1]
                table = "" if np.array_equal(codes, np.arange(k)) else self.global_name(codes)
                flat = cum.reshape(-1, k)
                if (flat == flat[0]).all() and (np.diff(flat[0]) >= 0).all():
                    # the same distribution everywhere: a sorted search
                    idx = f"_searchsorted({self.global_name(flat[0].copy())}, rng.random({shape}) * {self.global_name(total.reshape(-1)[0].copy())}, 'right')"
                else:
                    idx = f"_sum({self.global_name(cum)} <= rng.random({shape})[..., None] * {self.global_name(total)}, -1)"
                text = f"_minimum({idx}, {k - 1})"
                if table:
                    text = f"{table}[{text}]"
                return self.emit_value(self.batch_last(text, rank), out_shape, np.int64, t)
        sampler = _discrete_sampler(codes, normalise, where, draw_shape)
        args = ", ".join("None" if p is None else p.code + to_first for p in probs)
        return self.emit_value(
            self.batch_last(f"{self.global_name(sampler)}(rng, B, [{args}])", rank),
            out_shape,
            np.int64,
            t,
        )

    def _DiscreteOver(self, e: A.DiscreteOver, scope: Scope, hint: str | None) -> _Node:
        if len(e.params) != 1:
            raise SimulationError(f"{e.loc}: {e.name}_ takes one variable")
        inner = scope + ((e.params[0].name, e.params[0].type),)
        w = self.numeric(e.body, inner)
        size = self.sizes[e.params[0].type]
        where = f"{e.loc}: {e.name}_"
        full = self.scope_shape(scope)
        sampler = _discrete_over_sampler(size, e.name == "UnnormDiscrete", where, full)
        self.code.draws.append(where)
        # the weights batch first, the variable's axis last, as the draws are made
        text = self.batch_last(
            f"{self.global_name(sampler)}(rng, B, {w.code}{_batch_first(len(full) + 2)})",
            len(full) + 1,
        )
        return self.emit_value(text, (*full, 1), np.int64, e.params[0].type)
