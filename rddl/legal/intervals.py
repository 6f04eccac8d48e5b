"""Interval arithmetic over ground formulas: the bounds of a formula's
value when every action variable lies in an interval (truth values as
0/1, Kleene logic for the connectives). Sound: the true value of any
assignment within the intervals lies within the bounds.
"""

from __future__ import annotations

import math

import numpy as np

from .static import _NUMPY_FN, Ground


def interval(g: Ground, lo: list[float], hi: list[float]) -> tuple[float, float]:
    """Bounds of a ground formula's value with each action variable i in
    [lo[i], hi[i]] (truth values as 0/1)."""
    tag = g[0]
    if tag == "c":
        return g[1], g[1]
    if tag == "x":
        return lo[g[1]], hi[g[1]]
    if tag == "u":
        return g[1], g[2]
    if tag == "and":
        a, b = 1.0, 1.0
        for child in g[1:]:
            x, y = _truth(*interval(child, lo, hi))
            a, b = min(a, x), min(b, y)
            if b == 0:
                break
        return a, b
    if tag == "or":
        a, b = 0.0, 0.0
        for child in g[1:]:
            x, y = _truth(*interval(child, lo, hi))
            a, b = max(a, x), max(b, y)
            if a == 1:
                break
        return a, b
    if tag == "not":
        x, y = _truth(*interval(g[1], lo, hi))
        return 1 - y, 1 - x
    if tag in ("eq", "ne", "lt", "le", "gt", "ge"):
        a1, b1 = interval(g[1], lo, hi)
        a2, b2 = interval(g[2], lo, hi)
        return _compare(tag, a1, b1, a2, b2)
    if tag == "add":
        s, t = 0.0, 0.0
        for child in g[1:]:
            x, y = interval(child, lo, hi)
            s += x
            t += y
        return _fix(s, -math.inf), _fix(t, math.inf)
    if tag == "neg":
        x, y = interval(g[1], lo, hi)
        return -y, -x
    if tag == "mul":
        a1, b1 = interval(g[1], lo, hi)
        a2, b2 = interval(g[2], lo, hi)
        return _span([_times(a1, a2), _times(a1, b2), _times(b1, a2), _times(b1, b2)])
    if tag == "div":
        a1, b1 = interval(g[1], lo, hi)
        a2, b2 = interval(g[2], lo, hi)
        if a2 <= 0 <= b2:
            if a1 == b1 == a2 == b2 == 0:
                return math.nan, math.nan
            return -math.inf, math.inf
        return _span([a1 / a2, a1 / b2, b1 / a2, b1 / b2])
    if tag == "ite":
        c = _truth(*interval(g[1], lo, hi))
        if c[0] == 1:
            return interval(g[2], lo, hi)
        if c[1] == 0:
            return interval(g[3], lo, hi)
        a1, b1 = interval(g[2], lo, hi)
        a2, b2 = interval(g[3], lo, hi)
        return min(a1, a2), max(b1, b2)
    if tag in ("min", "max"):
        pairs = [interval(child, lo, hi) for child in g[1:]]
        if tag == "min":
            return min(p[0] for p in pairs), min(p[1] for p in pairs)
        return max(p[0] for p in pairs), max(p[1] for p in pairs)
    if tag == "abs":
        x, y = interval(g[1], lo, hi)
        if x >= 0:
            return x, y
        if y <= 0:
            return -y, -x
        return 0.0, max(-x, y)
    if tag == "fn":
        x, y = interval(g[2], lo, hi)
        return _monotone(g[1], x, y)
    return -math.inf, math.inf


def _truth(a: float, b: float) -> tuple[float, float]:
    """A number's interval read as a truth value (non-zero is true)."""
    if a == b:
        return (0.0, 0.0) if a == 0 else (1.0, 1.0)
    if a > 0 or b < 0:
        return 1.0, 1.0
    if 0 <= a and b <= 1 and a in (0, 1) and b in (0, 1):
        return a, b
    return 0.0, 1.0


def _compare(op: str, a1: float, b1: float, a2: float, b2: float) -> tuple[float, float]:
    if op == "eq" or op == "ne":
        if a1 == b1 == a2 == b2:
            yes = (1.0, 1.0)
        elif b1 < a2 or b2 < a1:
            yes = (0.0, 0.0)
        else:
            yes = (0.0, 1.0)
        return yes if op == "eq" else (1 - yes[1], 1 - yes[0])
    if op == "lt":
        return (1.0, 1.0) if b1 < a2 else (0.0, 0.0) if a1 >= b2 else (0.0, 1.0)
    if op == "le":
        return (1.0, 1.0) if b1 <= a2 else (0.0, 0.0) if a1 > b2 else (0.0, 1.0)
    if op == "gt":
        return (1.0, 1.0) if a1 > b2 else (0.0, 0.0) if b1 <= a2 else (0.0, 1.0)
    return (1.0, 1.0) if a1 >= b2 else (0.0, 0.0) if b1 < a2 else (0.0, 1.0)  # ge


def _fix(x: float, if_nan: float) -> float:
    return if_nan if x != x else x


def _times(a: float, b: float) -> float:
    if a == 0 or b == 0:
        return 0.0  # 0 * inf is 0 here: an unbounded factor times a zero
    return a * b


def _span(xs: list[float]) -> tuple[float, float]:
    clean = [x for x in xs if x == x]
    if len(clean) < len(xs):
        return -math.inf, math.inf
    return min(clean), max(clean)


def _monotone(name: str, x: float, y: float) -> tuple[float, float]:
    fn = _NUMPY_FN[name]
    with np.errstate(all="ignore"):
        a, b = float(fn(x)), float(fn(y))
    if a != a or b != b:
        return -math.inf, math.inf
    return a, b
