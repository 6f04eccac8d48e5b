"""What the generated code calls at run time.

Owns `_BUILTINS`, the globals of every generated function: numpy's ufuncs
and reductions under short names (`_add`, `_sum`, `_land`...), and the
helpers below: `_bidx` (batch indices for advanced indexing),
`_action_in` (an action array laid out batch last, or shared zeros),
`_spread` (a constant repeated along the batch), `_matmul_cols` (a matrix
product in single-threaded blocks), `_gather_sum` (a sum of row gathers),
`_pad_zero_row`, `_uniforms` (the raw 32-bit uniforms of the Bernoulli
draws) and `_no_rng` / `_missing` (the errors a step raises itself). Also
`_quietly`, which runs a step with numpy's floating-point warnings off.
Imports numpy and `state` only; the compiler names these helpers in the
code it writes and never calls them itself.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .state import Array, SimulationError


def _bidx_factory() -> Callable[[int, int], Array]:
    cache: dict[tuple[int, int], Array] = {}

    def bidx(batch: int, rank: int) -> Array:
        """Batch indices shaped to broadcast against rank-`rank` indices."""
        arr = cache.get((batch, rank))
        if arr is None:
            if len(cache) > 64:
                cache.clear()
            arr = np.arange(batch).reshape((1,) * (rank - 1) + (-1,))
            arr.flags.writeable = False
            cache[(batch, rank)] = arr
        return arr

    return bidx


def _action_in_factory() -> Callable[[Array, tuple[int, ...]], Array]:
    cache: dict[tuple[tuple[int, ...], str], Array] = {}

    def action_in(a: Array, axes: tuple[int, ...]) -> Array:
        """An action array (batch first) as a contiguous array with its
        axes in the order `axes` (batch last); where every value is zero,
        a shared read-only array of zeros."""
        # (count_nonzero is several times faster than any() on bools, and
        # twice as slow on numbers)
        if np.count_nonzero(a) if a.dtype == np.bool_ else a.any():
            return np.ascontiguousarray(a.transpose(axes))
        shape = tuple(a.shape[i] for i in axes)
        key = (shape, a.dtype.str)
        zeros = cache.get(key)
        if zeros is None:
            if len(cache) > 64:
                cache.clear()
            zeros = np.zeros(shape, a.dtype)
            zeros.flags.writeable = False
            cache[key] = zeros
        return zeros

    return action_in


# the largest constant (in elements per state) repeated along the batch for
# large batches (see `base._spread_constant`), and the largest such
# array (in bytes) made at run time: beyond the caches a second array costs
# more memory traffic than broadcasting saves
_SPREAD_CELLS = 4096
_SPREAD_BYTES = 1 << 20


def _spread_factory() -> Callable[[Array, tuple[int, ...]], Array]:
    cache: dict[tuple[int, tuple[int, ...]], tuple[Array, Array]] = {}

    def spread(k: Array, shape: tuple[int, ...]) -> Array:
        """The constant `k` repeated to `shape` (its batch axis, last), a
        contiguous read-only array made once per shape; `k` itself (to be
        broadcast) where that array would be large."""
        key = (id(k), shape)
        hit = cache.get(key)
        if hit is not None and hit[0] is k:
            return hit[1]
        if k.itemsize * int(np.prod(shape)) > _SPREAD_BYTES:
            out = k
        else:
            out = np.ascontiguousarray(np.broadcast_to(k, shape))
            out.flags.writeable = False
        if len(cache) > 256:
            cache.clear()
        # (the entry holds `k`: its id is not reused while it is cached)
        cache[key] = (k, out)
        return out

    return spread


# multiply-adds per BLAS call, at most: OpenBLAS runs a smaller product on
# one thread (its threshold is 4 * 65536); a threaded one stalls badly on a
# busy machine, and these products are small anyway
_BLAS_BLOCK = 200_000


def _matmul_cols(k: Array, f: Array) -> Array:
    """`k @ f` (2-D, or stacks of matrices), computed in blocks of columns
    of `f` small enough for one thread each."""
    cols = f.shape[-1]
    per_col = k.size
    if per_col * cols <= _BLAS_BLOCK or cols < 2:
        return np.matmul(k, f)  # type: ignore[no-any-return]
    out = np.empty((*f.shape[:-2], k.shape[-2], cols), dtype=np.result_type(k, f))
    step = max(1, _BLAS_BLOCK // per_col)
    for i in range(0, cols, step):
        np.matmul(k, f[..., i : i + step], out=out[..., i : i + step])
    return out


def _gather_sum(x: Array, rows: tuple[Array, ...]) -> Array:
    """`x[rows[0]] + x[rows[1]] + ...`, added in that order (the same
    values), into one new array: `take` gathers rows faster than indexing,
    and adding in place spares a temporary per row."""
    out = x.take(rows[0], axis=0)
    for r in rows[1:]:
        np.add(out, x.take(r, axis=0), out=out)
    return out


def _pad_zero_row(x: Array) -> Array:
    """`x` with a row of zeros added below."""
    out = np.empty((x.shape[0] + 1, *x.shape[1:]), dtype=x.dtype)
    out[:-1] = x
    out[-1] = 0
    return out


def _uniforms(rng: np.random.Generator, n: int) -> Array:
    """`n` independent uniform integers in [0, 2**32): the raw 64-bit
    outputs of `rng`'s bit generator, each cut in two (its low half
    first on a little-endian machine). Half the bits of `rng.random()`'s
    53-bit doubles, twice as many numbers per output, and no conversion:
    plenty for a Bernoulli (see `distributions._bernoulli`)."""
    return rng.bit_generator.random_raw((n + 1) >> 1).view(np.uint32)  # type: ignore[no-any-return]


# A Bernoulli(p) draw from a uniform integer u in [0, 2**32) is u < p * 2**32
# (computed exactly in float64): it fires with probability ceil(p * 2**32) /
# 2**32, within 2**-32 (2.3e-10) of p, never for p = 0 and always for p = 1.
_TWO_32 = 2.0**32


def _no_rng(where: str) -> None:
    raise SimulationError(f"{where}: a random draw needs a numpy Generator (rng)")


# The floating-point error state a step runs in: numpy's current state with
# divide, invalid and overflow ignored, exactly as `np.errstate(divide=
# "ignore", invalid="ignore", over="ignore")` sets it. That context manager
# costs a microsecond or more per step (it parses its arguments and builds
# the state afresh), about a twentieth of a small step, so on numpy >= 2 (the
# state is a context variable there) the state built for each current state
# is kept, and a step already in it (a step within a step's caller that
# set it) changes nothing.
def _error_state_api() -> tuple[Any, Any]:
    """numpy's context variable of the floating-point error state, and its
    function that builds a state from the current one; (None, None) where
    numpy has no such thing (1.x: `np.errstate` itself is used then)."""
    try:
        from numpy._core import umath
    except ImportError:
        return None, None
    var, make = getattr(umath, "_extobj_contextvar", None), getattr(umath, "_make_extobj", None)
    if var is None or make is None:
        return None, None
    return var, make


_ERR_VAR, _make_extobj = _error_state_api()
_QUIET: dict[Any, Any] = {}  # current state -> the quiet one built on it (itself for a quiet one)


def _quiet_state(current: Any) -> Any:
    """The quiet state built on `current` (which is the current one)."""
    quiet = _make_extobj(divide="ignore", invalid="ignore", over="ignore")
    if len(_QUIET) > 32:
        _QUIET.clear()
    # (the keys hold the states alive: an id is never reused while cached)
    _QUIET[current] = quiet
    _QUIET[quiet] = quiet
    return quiet


def _quietly(fn: Callable[..., Any], *args: Any) -> Any:
    """`fn(*args)` with divide, invalid and overflow floating-point errors
    ignored (as under `np.errstate(divide="ignore", invalid="ignore",
    over="ignore")`), the caller's state restored after."""
    if _ERR_VAR is None:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return fn(*args)
    current = _ERR_VAR.get()
    quiet = _QUIET.get(current)
    if quiet is None:
        quiet = _quiet_state(current)
    if quiet is current:
        return fn(*args)
    token = _ERR_VAR.set(quiet)
    try:
        return fn(*args)
    finally:
        _ERR_VAR.reset(token)


# names the generated code uses (globals of every generated function)
_BUILTINS: dict[str, Any] = {
    "np": np,
    "_bool": np.bool_,
    "_i64": np.int64,
    "_f64": np.float64,
    "_f32": np.float32,
    "_cnz": np.count_nonzero,
    "_land": np.logical_and,
    "_lor": np.logical_or,
    "_lnot": np.logical_not,
    "_bitand": np.bitwise_and,
    "_bitor": np.bitwise_or,
    "_u8": np.uint8,
    "_contiguous": np.ascontiguousarray,
    "_pad_zero_row": _pad_zero_row,
    "_gather_sum": _gather_sum,
    "_eq": np.equal,
    "_ne": np.not_equal,
    "_lt": np.less,
    "_le": np.less_equal,
    "_gt": np.greater,
    "_ge": np.greater_equal,
    "_add": np.add,
    "_sub": np.subtract,
    "_mul": np.multiply,
    "_div": np.true_divide,
    "_neg": np.negative,
    "_where": np.where,
    # reductions as `x.sum(axis=a, keepdims=k)` and the like make them:
    # `_sum(x, a)`, `_sum(x, a, None, None, k)`, `_all(x, a, _bool)`...
    "_sum": np.add.reduce,
    "_all": np.logical_and.reduce,
    "_any": np.logical_or.reduce,
    "_min_reduce": np.minimum.reduce,
    "_max_reduce": np.maximum.reduce,
    "_select": np.select,
    "_minimum": np.minimum,
    "_maximum": np.maximum,
    "_fmod": np.fmod,
    "_abs": np.abs,
    "_sign": np.sign,
    "_trunc": np.trunc,
    "_sqrt": np.sqrt,
    "_log": np.log,
    "_power": np.power,
    "_square": np.square,
    "_hypot": np.hypot,
    "_matmul": np.matmul,
    "_matmul_cols": _matmul_cols,
    "_empty": np.empty,
    "_zeros": np.zeros,
    "_searchsorted": np.searchsorted,
    "_broadcast_to": np.broadcast_to,
    "_no_rng": _no_rng,
    "_uniforms": _uniforms,
}


def _missing(name: str) -> None:
    raise SimulationError(f"'{name}' has no value where it is read")
