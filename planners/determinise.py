"""Determinisation of an RDDL model: every random draw replaced by one
deterministic choice (the *most-likely* determinisation).

`determinise(model)` returns a new `Model` whose cpfs and reward have no
random draws left, so that a `Simulator` built from it steps without a
random generator and the same state and actions always give the same
successor. The model is rewritten on the AST, one distribution node at a
time (the rest of the expression is kept as it is, positions included, so
that a simulator error still points into the original file):

===================================  ======================================
distribution                         deterministic choice
===================================  ======================================
``Bernoulli(p)``                     ``p >= 0.5`` (a tie counts as true)
``Discrete(t, @a : p, ...)``         the value with the largest probability
                                     (the first of them on a tie; the
                                     ``otherwise`` case gets 1 - the rest);
                                     ``UnnormDiscrete`` the same
``Discrete_{?x : t}(w)``             ``argmax_{?x : t} w`` (first on a tie)
``Normal(m, v)``                     ``m`` (mean and mode)
``Uniform(a, b)``                    ``(a + b) / 2`` (the mean)
``Exponential(s)``                   ``s`` (the mean; `s` is the scale)
``Gamma(k, s)``                      ``k * s`` (the mean)
``Beta(a, b)``                       ``a / (a + b)`` (the mean)
``ChiSquare(d)``                     ``d`` (the mean)
``Student(d)``, ``Laplace(m, b)``,   the location (``0``, ``m``, ``m``)
``Cauchy(m, b)``
``Gumbel(m, b)``                     ``m + 0.5772 b`` (the mean)
``Weibull(k, s)``, ``Pareto(a, m)``, the median (these have no mean, or none
``Gompertz(a, b)``,                  in closed form with RDDL's functions)
``Kumaraswamy(a, b)``
``Poisson(l)``                       ``floor[l]`` (the mode)
``Binomial(n, p)``                   ``min[floor[(n + 1) p], n]`` (the mode)
``NegativeBinomial(n, p)``           ``max[floor[(n - 1)(1 - p) / p], 0]``
                                     (the mode, counting failures)
``Geometric(p)``                     ``1`` (the mode, trials to a success)
``KronDelta``, ``DiracDelta``        unchanged (already deterministic)
===================================  ======================================

For integer draws the most likely value is the mode; for real-valued ones
the notion does not help (every single value has probability 0), so the
mean stands in, or the median where the mean does not exist.
Distributions the simulator does not run (``Multinomial``, ``Dirichlet``,
vector distributions) are left as they are: a simulator cannot be built
from the model either way.

A `terminate-when` horizon (rddlsim) becomes a `termination` condition of
the determinised domain, so that the determinised simulator reports `done`
when the goal is reached and a search can treat it as a goal.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

from ..rddl import ast as A
from ..rddl.model import Model

EULER_GAMMA = 0.5772156649015329


def model_has_draws(model: Model) -> bool:
    """Whether any cpf or the reward of `model` draws a random value."""
    exprs = [cpf.expr for cpf in model.cpfs.values()]
    if model.reward is not None:
        exprs.append(model.reward)
    return any(A.has_draws(e) for e in exprs)


def determinise(model: Model) -> Model:
    """`model` with every random draw replaced by its most likely outcome
    (see the module's docstring for the rule per distribution)."""
    rewrite = _MostLikely(model)
    cpfs = {
        name: dataclasses.replace(cpf, expr=rewrite(cpf.expr)) for name, cpf in model.cpfs.items()
    }
    reward = None if model.reward is None else rewrite(model.reward)
    termination = tuple(model.domain.termination)
    horizon = model.instance.horizon
    if horizon is not None and not isinstance(horizon, (int, str)):
        termination += (horizon,)  # terminate-when: the goal of the instance
    domain = dataclasses.replace(
        model.domain,
        cpfs=tuple(cpfs[c.name] if c.name in cpfs else c for c in model.domain.cpfs),
        reward=reward,
        termination=termination,
    )
    return dataclasses.replace(model, domain=domain, cpfs=cpfs)


# ------------------------------------------------------------- the rewrite


def _c(value: float, loc: A.Loc) -> A.Const:
    return A.Const(float(value), loc)


def _bin(op: str, left: A.Expr, right: A.Expr, loc: A.Loc) -> A.Expr:
    return A.Binary(op, left, right, loc)


def _fn(name: str, loc: A.Loc, *args: A.Expr) -> A.Expr:
    return A.Function(name, tuple(args), loc)


def _real(expr: A.Expr, loc: A.Loc) -> A.Expr:
    # DiracDelta is the simulator's cast to real: the cpf keeps a real value
    # even where the chosen expression is an int (the mean of Uniform(0, 2)).
    return A.Distribution("DiracDelta", (expr,), loc)


def _int(expr: A.Expr, loc: A.Loc) -> A.Expr:
    return A.Distribution("KronDelta", (expr,), loc)


def _pow(base: A.Expr, exponent: A.Expr, loc: A.Loc) -> A.Expr:
    return _fn("pow", loc, base, exponent)


def _inverse(x: A.Expr, loc: A.Loc) -> A.Expr:
    return _bin("/", _c(1.0, loc), x, loc)


# name -> (arguments, location) -> the deterministic expression
_RULES: dict[str, Callable[[tuple[A.Expr, ...], A.Loc], A.Expr]] = {
    "Bernoulli": lambda a, loc: _bin(">=", a[0], _c(0.5, loc), loc),
    "Normal": lambda a, loc: _real(a[0], loc),
    "Uniform": lambda a, loc: _real(_bin("/", _bin("+", a[0], a[1], loc), _c(2.0, loc), loc), loc),
    "Exponential": lambda a, loc: _real(a[0], loc),
    "Gamma": lambda a, loc: _real(_bin("*", a[0], a[1], loc), loc),
    "Beta": lambda a, loc: _real(_bin("/", a[0], _bin("+", a[0], a[1], loc), loc), loc),
    "ChiSquare": lambda a, loc: _real(a[0], loc),
    "Student": lambda a, loc: _c(0.0, loc),
    "Laplace": lambda a, loc: _real(a[0], loc),
    "Cauchy": lambda a, loc: _real(a[0], loc),
    "Gumbel": lambda a, loc: _real(
        _bin("+", a[0], _bin("*", _c(EULER_GAMMA, loc), a[1], loc), loc), loc
    ),
    # medians: s (ln 2)^(1/k); m 2^(1/a); ln(1 + ln 2 / a) / b; (1 - 2^(-1/b))^(1/a)
    "Weibull": lambda a, loc: _real(
        _bin("*", a[1], _pow(_c(math.log(2.0), loc), _inverse(a[0], loc), loc), loc), loc
    ),
    "Pareto": lambda a, loc: _real(
        _bin("*", a[1], _pow(_c(2.0, loc), _inverse(a[0], loc), loc), loc), loc
    ),
    "Gompertz": lambda a, loc: _real(
        _bin(
            "/",
            _fn(
                "ln",
                loc,
                _bin("+", _c(1.0, loc), _bin("/", _c(math.log(2.0), loc), a[0], loc), loc),
            ),
            a[1],
            loc,
        ),
        loc,
    ),
    "Kumaraswamy": lambda a, loc: _real(
        _pow(
            _bin("-", _c(1.0, loc), _pow(_c(0.5, loc), _inverse(a[1], loc), loc), loc),
            _inverse(a[0], loc),
            loc,
        ),
        loc,
    ),
    "Poisson": lambda a, loc: _fn("floor", loc, a[0]),
    "Binomial": lambda a, loc: _int(
        _fn(
            "min",
            loc,
            _fn("floor", loc, _bin("*", _bin("+", a[0], _c(1.0, loc), loc), a[1], loc)),
            a[0],
        ),
        loc,
    ),
    "NegativeBinomial": lambda a, loc: _int(
        _fn(
            "max",
            loc,
            _fn(
                "floor",
                loc,
                _bin(
                    "/",
                    _bin(
                        "*",
                        _bin("-", a[0], _c(1.0, loc), loc),
                        _bin("-", _c(1.0, loc), a[1], loc),
                        loc,
                    ),
                    a[1],
                    loc,
                ),
            ),
            A.Const(0, loc),
        ),
        loc,
    ),
    "Geometric": lambda a, loc: A.Const(1, loc),
}

DETERMINISED = frozenset(_RULES) | {"Discrete", "UnnormDiscrete", "KronDelta", "DiracDelta"}
"""The distributions `determinise` replaces (or keeps, being deterministic)."""


class _MostLikely:
    """Rebuilds an expression bottom-up with every draw replaced."""

    def __init__(self, model: Model):
        self.model = model

    def __call__(self, e: A.Expr) -> A.Expr:
        f = self
        if isinstance(e, (A.Const, A.Var, A.EnumLit, A.ObjectLit)):
            return e
        if isinstance(e, A.PVar):
            return dataclasses.replace(e, args=tuple(f(a) for a in e.args)) if e.args else e
        if isinstance(e, A.Unary):
            return dataclasses.replace(e, operand=f(e.operand))
        if isinstance(e, A.Binary):
            return dataclasses.replace(e, left=f(e.left), right=f(e.right))
        if isinstance(e, (A.Aggregation, A.MatrixOp)):
            return dataclasses.replace(e, body=f(e.body))
        if isinstance(e, A.Function):
            return dataclasses.replace(e, args=tuple(f(a) for a in e.args))
        if isinstance(e, A.If):
            return dataclasses.replace(e, cond=f(e.cond), then=f(e.then), else_=f(e.else_))
        if isinstance(e, A.Switch):
            cases = tuple(
                dataclasses.replace(
                    c, label=None if c.label is None else f(c.label), value=f(c.value)
                )
                for c in e.cases
            )
            return dataclasses.replace(e, subject=f(e.subject), cases=cases)
        if isinstance(e, A.Distribution):
            args = tuple(f(a) for a in e.args)
            rule = _RULES.get(e.name)
            if rule is None:  # KronDelta, DiracDelta, or one the simulator lacks
                return dataclasses.replace(e, args=args)
            return rule(args, e.loc)
        if isinstance(e, A.Discrete):
            return self.discrete(e)
        if isinstance(e, A.DiscreteOver):
            return A.Aggregation("argmax", e.params, f(e.body), e.loc)
        return e  # VectorDistribution: not simulated

    def discrete(self, e: A.Discrete) -> A.Expr:
        if e.count is not None or not e.cases:  # Multinomial: not simulated
            return e
        info = self.model.types.get(e.type)
        enum = info is not None and info.kind == "enum"
        labels: list[A.Expr] = []
        for dc in e.cases:
            name = getattr(dc.label, "name", "")
            if enum:
                labels.append(A.EnumLit(name if name.startswith("@") else "@" + name, dc.label.loc))
            else:
                labels.append(A.ObjectLit(name, True, dc.label.loc))
        given = [None if dc.prob is None else self(dc.prob) for dc in e.cases]
        probs: list[A.Expr] = []
        for p in given:
            if p is None:  # otherwise: what the others leave
                rest: A.Expr = _c(0.0, e.loc)
                for q in given:
                    if q is not None:
                        rest = _bin("+", rest, q, e.loc)
                p = _bin("-", _c(1.0, e.loc), rest, e.loc)
            probs.append(p)
        # The first case whose probability is at least every later one's is
        # the first of the most likely ones (an earlier case at least as
        # likely would have been chosen before it).
        out: A.Expr = labels[-1]
        for i in range(len(labels) - 2, -1, -1):
            cond: A.Expr | None = None
            for j in range(i + 1, len(labels)):
                test = _bin(">=", probs[i], probs[j], e.loc)
                cond = test if cond is None else _bin("^", cond, test, e.loc)
            assert cond is not None
            out = A.If(cond, labels[i], out, e.loc)
        return out
