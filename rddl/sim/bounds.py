"""Elementwise interval bounds of values, carried through the arithmetic.

Owns `Bounds` (a (lo, hi) pair of arrays) and the `_bounds_*` functions
that compute an operation's bounds from its arguments' with the same
floating-point operations as the values (so they are sound: IEEE rounding
is monotone), `None` where unknown. The compiler uses them to skip a
distribution's parameter check where every value it can take is valid,
and to keep a count in uint8 where it provably fits. Imports numpy and
`code._Node` only.
"""

from __future__ import annotations

import numpy as np

from .code import _Node
from .state import Array

Bounds = tuple[Array, Array]


def _bounds_add(a: Bounds, b: Bounds) -> Bounds:
    return a[0] + b[0], a[1] + b[1]


def _bounds_sub(a: Bounds, b: Bounds) -> Bounds:
    return a[0] - b[1], a[1] - b[0]


def _bounds_mul(a: Bounds, b: Bounds) -> Bounds:
    c = [a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1]]
    return np.minimum(np.minimum(c[0], c[1]), np.minimum(c[2], c[3])), np.maximum(
        np.maximum(c[0], c[1]), np.maximum(c[2], c[3])
    )


def _bounds_div(a: Bounds, b: Bounds) -> Bounds | None:
    if not ((b[0] > 0) | (b[1] < 0)).all():
        return None  # the divisor may be 0
    c = [a[0] / b[0], a[0] / b[1], a[1] / b[0], a[1] / b[1]]
    return np.minimum(np.minimum(c[0], c[1]), np.minimum(c[2], c[3])), np.maximum(
        np.maximum(c[0], c[1]), np.maximum(c[2], c[3])
    )


def _bounds_same(a: Bounds) -> Bounds:
    return a


def _bounds_trunc(a: Bounds) -> Bounds:
    return np.trunc(a[0]), np.trunc(a[1])


def _bounds_neg(a: Bounds) -> Bounds:
    return -a[1], -a[0]


def _bounds_min(a: Bounds, b: Bounds) -> Bounds:
    return np.minimum(a[0], b[0]), np.minimum(a[1], b[1])


def _bounds_max(a: Bounds, b: Bounds) -> Bounds:
    return np.maximum(a[0], b[0]), np.maximum(a[1], b[1])


def _bounds_either(cond: Bounds, a: Bounds, b: Bounds) -> Bounds:
    return np.minimum(a[0], b[0]), np.maximum(a[1], b[1])


def _bounds_exp(a: Bounds) -> Bounds:
    # exp is not correctly rounded: a few ulps of slack each way
    lo, hi = np.exp(a[0]), np.exp(a[1])
    for _ in range(4):
        lo, hi = np.nextafter(lo, -np.inf), np.nextafter(hi, np.inf)
    return np.maximum(lo, 0.0), hi


def _bounded(node: _Node, bounds: Bounds | None) -> _Node:
    if bounds is not None and all((np.abs(x) < 2.0**52).all() for x in bounds):
        node.bounds = bounds
    return node
