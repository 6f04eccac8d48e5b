"""The draw functions the generated code calls for the distributions
without a special path: `Uniform`, `Exponential`, `Poisson`, `Gamma`,
`Weibull`, `Beta`, `Binomial`, `NegativeBinomial`, `Pareto`, `Gumbel`,
`Laplace`, `Cauchy`, `Gompertz`, `Kumaraswamy`, `Geometric`, `Student`,
`ChiSquare` (`_sampler`), and the categorical draws of `Discrete` and
`UnnormDiscrete` whose probabilities are not all known when the simulator
is built (`_discrete_sampler`, `_discrete_over_sampler`).

Each checks its parameters and raises `SimulationError` naming the
distribution's place in the file and a bad value (`_bad`). Imports numpy
and `state` only; `distributions` makes them and names them in the code.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .state import Array, SimulationError


def _param_error(where: str, what: str, bad: Callable[[Array], Array]) -> Callable[[Array], None]:
    def fail(values: Array) -> None:
        v = np.asarray(values)
        mask = bad(v)
        if np.any(mask):
            raise SimulationError(f"{where} {what}: {_bad(v, mask)}")

    return fail


def _sampler(name: str, where: str) -> tuple[Callable[..., Array], str] | None:
    """A draw function (rng, shape, *params) that checks its parameters,
    and its value type; None for a distribution not simulated."""
    if name == "Uniform":

        def uniform(g: np.random.Generator, shape: tuple[int, ...], lo: Array, hi: Array) -> Array:
            if np.any(lo > hi):
                raise SimulationError(f"{where} lower bound above upper bound")
            return g.uniform(lo, hi, shape)

        return uniform, "real"
    if name == "Exponential":

        def exponential(g: np.random.Generator, shape: tuple[int, ...], s: Array) -> Array:
            if np.any(s <= 0):
                raise SimulationError(f"{where} mean must be positive: {_bad(s, s <= 0)}")
            return g.exponential(s, shape)

        return exponential, "real"
    if name == "Poisson":

        def poisson(g: np.random.Generator, shape: tuple[int, ...], lam: Array) -> Array:
            if np.any(lam < 0):
                raise SimulationError(f"{where} mean must not be negative: {_bad(lam, lam < 0)}")
            return g.poisson(lam, shape).astype(np.int64)

        return poisson, "int"
    two: dict[str, tuple[Callable[..., Array], str, Callable[[Array, Array], Array]]] = {
        "Gamma": (lambda g, a, b, s: g.gamma(a, b, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Weibull": (lambda g, a, b, s: b * g.weibull(a, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Beta": (lambda g, a, b, s: g.beta(a, b, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Binomial": (lambda g, n, p, s: g.binomial(n, p, s).astype(np.int64), "int", lambda n, p: (n < 0) | (p < 0) | (p > 1)),
        "NegativeBinomial": (lambda g, n, p, s: g.negative_binomial(n, p, s).astype(np.int64), "int", lambda n, p: (n <= 0) | (p <= 0) | (p > 1)),
        "Pareto": (lambda g, a, b, s: b * (1 + g.pareto(a, s)), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Gumbel": (lambda g, a, b, s: g.gumbel(a, b, s), "real", lambda a, b: b <= 0),
        "Laplace": (lambda g, a, b, s: g.laplace(a, b, s), "real", lambda a, b: b <= 0),
        "Cauchy": (lambda g, a, b, s: a + b * g.standard_cauchy(s), "real", lambda a, b: b <= 0),
        "Gompertz": (lambda g, a, b, s: np.log(1 - np.log(1 - g.random(s)) / a) / b, "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Kumaraswamy": (lambda g, a, b, s: (1 - (1 - g.random(s)) ** (1 / b)) ** (1 / a), "real", lambda a, b: (a <= 0) | (b <= 0)),
    }  # fmt: skip
    if name in two:
        draw2, out2, invalid2 = two[name]

        def sample2(g: np.random.Generator, shape: tuple[int, ...], a: Array, b: Array) -> Array:
            if np.any(invalid2(np.asarray(a), np.asarray(b))):
                raise SimulationError(f"{where} parameters outside its domain")
            return draw2(g, a, b, shape)

        return sample2, out2
    one: dict[str, tuple[Callable[..., Array], str, Callable[[Array], Array]]] = {
        "Geometric": (lambda g, p, s: g.geometric(p, s).astype(np.int64), "int", lambda p: (p <= 0) | (p > 1)),
        "Student": (lambda g, d, s: g.standard_t(d, s), "real", lambda d: d <= 0),
        "ChiSquare": (lambda g, d, s: g.chisquare(d, s), "real", lambda d: d <= 0),
    }  # fmt: skip
    if name in one:
        draw1, out1, invalid1 = one[name]

        def sample1(g: np.random.Generator, shape: tuple[int, ...], a: Array) -> Array:
            if np.any(invalid1(np.asarray(a))):
                raise SimulationError(f"{where} parameter outside its domain")
            return draw1(g, a, shape)

        return sample1, out1
    return None


def _stack_probabilities(ps: list[Array | None], shape: tuple[int, ...]) -> Array:
    """Discrete's probabilities along a last axis; the case without one
    takes what the others leave (never below 0)."""
    full = [
        np.broadcast_to(np.asarray(p, dtype=np.float64), shape) if p is not None else None
        for p in ps
    ]
    known = [p for p in full if p is not None]
    total_known = sum(known) if known else np.zeros(shape)
    return np.stack(
        [p if p is not None else np.maximum(1.0 - total_known, 0.0) for p in full], axis=-1
    )


def _fixed_categorical(
    ps: list[Array | None], shape: tuple[int, ...], normalise: bool
) -> tuple[Array, Array] | None:
    """Cumulative weights and their totals for probabilities known when the
    simulator is built, or None if they are not valid (the draw then raises
    at run time, as it should)."""
    with np.errstate(all="ignore"):
        stacked = _stack_probabilities(ps, shape)
        if np.any(stacked < -1e-12):
            return None
        total = stacked.sum(axis=-1)
        if normalise:
            weights = stacked / total[..., None]
        elif np.any(np.abs(total - 1.0) > 1e-6):
            return None
        else:
            weights = stacked
        if not np.all(np.isfinite(weights)):
            return None
        cum = np.cumsum(weights, axis=-1)
    return cum, cum[..., -1:].copy()


def _discrete_sampler(
    codes: Array, normalise: bool, where: str, draw_shape: tuple[int, ...]
) -> Callable[..., Array]:
    def discrete(rng: np.random.Generator, batch: int, ps: list[Array | None]) -> Array:
        stacked = _stack_probabilities(ps, (batch, *draw_shape))
        if np.any(stacked < -1e-12):
            raise SimulationError(f"{where} has a negative probability")
        return codes[_draw_categorical(stacked, normalise, where, rng)]  # type: ignore[no-any-return]

    return discrete


def _discrete_over_sampler(
    size: int, normalise: bool, where: str, full: tuple[int, ...]
) -> Callable[..., Array]:
    def discrete_over(rng: np.random.Generator, batch: int, weights: Array) -> Array:
        w = np.broadcast_to(np.asarray(weights, dtype=np.float64), (batch, *full, size))
        if np.any(w < 0):
            raise SimulationError(f"{where} has a negative probability")
        return _draw_categorical(w, normalise, where, rng)

    return discrete_over


def _draw_categorical(
    weights: Array, normalise: bool, where: str, rng: np.random.Generator | None
) -> Array:
    """One index per leading position, drawn with the probabilities along the
    last axis: normalised (UnnormDiscrete) or required to sum to 1."""
    total = weights.sum(axis=-1)
    if normalise:
        weights = weights / total[..., None]
    else:
        off = np.abs(total - 1.0)
        if np.any(off > 1e-6):
            worst = float(total.flat[int(np.argmax(off))])
            raise SimulationError(f"{where} probabilities sum to {worst}, not 1")
    if rng is None:
        raise SimulationError(f"{where}: a random draw needs a numpy Generator (rng)")
    cum = np.cumsum(weights, axis=-1)
    u = rng.random(weights.shape[:-1])[..., None] * cum[..., -1:]
    return np.minimum(np.sum(cum <= u, axis=-1), weights.shape[-1] - 1)  # type: ignore[no-any-return]


def _bad(values: Array, mask: Array) -> str:
    v = np.asarray(values)
    m = np.broadcast_to(mask, v.shape) if v.shape else mask
    bad = np.asarray(v)[m] if np.ndim(v) else v
    return repr(float(np.ravel(bad)[0])) if np.size(bad) else "?"
