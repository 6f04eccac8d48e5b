"""Constraint propagation over the elements of one state.

Every element prunes the domains of its variables: a linear element
(`sum_i c_i x_i + k op 0`) by its bounds, any other by evaluating it in
interval arithmetic with each value of each of its variables in turn;
max-nondef-actions pins every variable to its default once the budget is
used up. `_propagate` repeats until nothing changes and raises `_Conflict`
(naming the element) when a domain empties or an element must fail.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from .ground import Element, linear
from .intervals import _truth, interval
from .static import Ground

Domain = tuple[int, ...]


@dataclass
class _Linear:
    coefs: dict[int, float]
    const: float
    op: str  # le, lt, eq, ne (ge and gt are turned around)


@dataclass
class _Problem:
    """One state's elements, ready for propagation."""

    elements: list[Element]
    linear: list[_Linear | None]
    vars: list[tuple[int, ...]]
    watch: list[list[int]]  # variable -> elements that read it
    domains: list[Domain]
    defaults: list[int]
    budget: int | None  # max-nondef-actions


def _as_linear(g: Ground) -> _Linear | None:
    if g[0] not in ("le", "lt", "ge", "gt", "eq", "ne"):
        return None
    left = linear(g[1])
    right = linear(g[2])
    if left is None or right is None:
        return None
    coefs = dict(left[0])
    for k, v in right[0].items():
        coefs[k] = coefs.get(k, 0) - v
    coefs = {k: v for k, v in coefs.items() if v != 0}
    const = left[1] - right[1]
    op = g[0]
    if op in ("ge", "gt"):
        coefs = {k: -v for k, v in coefs.items()}
        const = -const
        op = "le" if op == "ge" else "lt"
    return _Linear(coefs, const, op)


# ---------------------------------------------------------- propagation


class _Conflict(Exception):
    def __init__(self, element: int | None) -> None:
        super().__init__(element)
        self.element = element  # None: max-nondef-actions


class _Node:
    """Domains of every variable and the elements not yet entailed."""

    __slots__ = ("dom", "lo", "hi", "active", "unsure")

    def __init__(self, dom: list[Domain], active: set[int], unsure: bool) -> None:
        self.dom = dom
        self.lo = [float(d[0]) for d in dom]
        self.hi = [float(d[-1]) for d in dom]
        self.active = active
        self.unsure = unsure  # an element that only check_actions can judge

    def child(self, var: int, value: int) -> _Node:
        dom = list(self.dom)
        dom[var] = (value,)
        node = _Node.__new__(_Node)
        node.dom = dom
        node.lo = list(self.lo)
        node.hi = list(self.hi)
        node.lo[var] = node.hi[var] = float(value)
        node.active = set(self.active)
        node.unsure = self.unsure
        return node

    def set(self, var: int, values: Domain) -> None:
        self.dom[var] = values
        self.lo[var] = float(values[0])
        self.hi[var] = float(values[-1])


def _propagate(p: _Problem, node: _Node, todo: Iterable[int]) -> None:
    """Prune `node` until nothing changes; raises `_Conflict`."""
    queue = list(todo)
    queued = set(queue)
    while True:
        while queue:
            e = queue.pop()
            queued.discard(e)
            if e not in node.active:
                continue
            changed = _revise(p, node, e)
            for v in changed:
                for f in p.watch[v]:
                    if f not in queued and f in node.active:
                        queued.add(f)
                        queue.append(f)
        if p.budget is None:
            return
        forced = sum(1 for v, d in enumerate(node.dom) if p.defaults[v] not in d)
        if forced > p.budget:
            raise _Conflict(None)
        if forced < p.budget:
            return
        pinned = []
        for v, d in enumerate(node.dom):
            if len(d) > 1:  # (the default is in it: else it counts as forced)
                node.set(v, (p.defaults[v],))
                pinned.append(v)
        if not pinned:
            return
        for v in pinned:
            for f in p.watch[v]:
                if f not in queued and f in node.active:
                    queued.add(f)
                    queue.append(f)


def _revise(p: _Problem, node: _Node, e: int) -> list[int]:
    """Prune the domains with element e; the variables whose domain shrank."""
    lin = p.linear[e]
    if lin is not None:
        return _revise_linear(lin, node, e)
    formula = p.elements[e].formula
    lo, hi = node.lo, node.hi
    a, b = _truth(*interval(formula, lo, hi))
    if b == 0:
        raise _Conflict(e)
    if a == 1:
        node.active.discard(e)
        return []
    free = [v for v in p.vars[e] if len(node.dom[v]) > 1]
    if not free:
        node.active.discard(e)  # only the simulator can tell (an opaque part)
        node.unsure = True
        return []
    changed = []
    for v in free:
        keep = []
        saved = lo[v], hi[v]
        for value in node.dom[v]:
            lo[v] = hi[v] = float(value)
            if _truth(*interval(formula, lo, hi))[1] > 0:
                keep.append(value)
        lo[v], hi[v] = saved
        if not keep:
            raise _Conflict(e)
        if len(keep) < len(node.dom[v]):
            node.set(v, tuple(keep))
            changed.append(v)
    return changed


def _revise_linear(lin: _Linear, node: _Node, e: int) -> list[int]:
    low: dict[int, float] = {}
    high: dict[int, float] = {}
    tmin = tmax = lin.const
    for v, c in lin.coefs.items():
        a, b = c * node.lo[v], c * node.hi[v]
        if a > b:
            a, b = b, a
        low[v], high[v] = a, b
        tmin += a
        tmax += b
    op = lin.op
    if op == "le":
        if tmin > 0:
            raise _Conflict(e)
        if tmax <= 0:
            node.active.discard(e)
            return []
    elif op == "lt":
        if tmin >= 0:
            raise _Conflict(e)
        if tmax < 0:
            node.active.discard(e)
            return []
    elif op == "eq":
        if tmin > 0 or tmax < 0:
            raise _Conflict(e)
        if tmin == tmax == 0:
            node.active.discard(e)
            return []
    else:  # ne
        if tmin > 0 or tmax < 0:
            node.active.discard(e)
            return []
        free = [v for v in lin.coefs if len(node.dom[v]) > 1]
        if not free:
            raise _Conflict(e)  # every variable fixed, and the sum is 0
        if len(free) > 1:
            return []
        v = free[0]
        rest = tmin - low[v]
        keep = tuple(x for x in node.dom[v] if rest + lin.coefs[v] * x != 0)
        if not keep:
            raise _Conflict(e)
        if len(keep) < len(node.dom[v]):
            node.set(v, keep)
            return [v]
        return []
    changed = []
    for v, c in lin.coefs.items():
        d = node.dom[v]
        if len(d) == 1:
            continue
        base_min = tmin - low[v]
        base_max = tmax - high[v]
        if op == "le":
            keep = tuple(x for x in d if base_min + c * x <= 0)
        elif op == "lt":
            keep = tuple(x for x in d if base_min + c * x < 0)
        else:
            keep = tuple(x for x in d if base_min + c * x <= 0 <= base_max + c * x)
        if not keep:
            raise _Conflict(e)
        if len(keep) < len(d):
            node.set(v, keep)
            changed.append(v)
    return changed
