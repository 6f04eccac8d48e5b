"""Legal joint actions: enumerate, count and sample uniformly the joint
actions a state allows.

A joint action is legal in a state when at most max-nondef-actions action
groundings differ from their default and every action precondition and
state-action constraint holds (what `Simulator.check_actions` tests). Coin
flips over the groundings cannot find the legal actions of ChromaticDice
(`current-phase == @roll1 => forall_{?d} roll(?d)`: all five dice at once)
or of the exactly-one forms of EarthObservation and WildlifePreserve
(`forall_{?r} (sum_{?a} defend(?a, ?r)) == 1`); this module reasons about
the constraints instead, as a small constraint solver.

Theory of operation (for one state; `LegalActions` caches the result by
the values of the state fluents the constraints read):

1. *Grounding* (`legal_ground`): the constraints become *elements*, small
   ground formulas over the *action variables* (one per grounding of each
   action fluent, with a finite domain: {0, 1} for bool, the codes of an
   enum, a bounded range of ints).
2. *Propagation*: every element prunes the domains of its variables.
   A linear element (`sum_i c_i x_i + k <= 0`, `== 0`, `< 0`, `~= 0`, the
   usual form of "at most one", "exactly one", action budgets) is reasoned
   about by its bounds: a value that makes the element fail whatever the
   others do is removed. Any other element is evaluated in interval
   arithmetic (Kleene logic for the connectives) with each value of each of
   its variables in turn. max-nondef-actions is a global budget: once it is
   used up, every other variable is pinned to its default. Pruning repeats
   until nothing changes; an element that holds whatever the free
   variables do is *entailed* and dropped. So `forall_{?d} roll(?d)` pins
   every roll to true at once, and with one `defend(a, r)` chosen every
   other area of ranger r is pinned to false.
3. *Search*: depth-first, branching on a variable of the non-entailed
   element with the fewest free variables (its default value first), and
   propagating again below each branch. A node is a *leaf* when what is
   left can be counted in closed form: every element entailed, or the
   remaining ones all *cardinality* elements (unit coefficients over bool
   variables with default false, each set of variables disjoint from the
   others, as after AcademicAdvising's `sum_{?c} take-course(?c) <= 2`),
   with the free variables under the max-nondef budget. A leaf's joint
   actions are then counted exactly with a product of small polynomials
   (one per group and per free variable, in the number of non-default
   values) truncated at the budget.
4. *Counting, enumeration, uniform sampling*: the total is the sum over the
   leaves; enumeration expands the leaves; a uniform sample picks a leaf in
   proportion to its count and then a uniform member of it (the number of
   non-default values first, then which variables, then which values).
   Where the search tree itself exceeds `node_limit`, samples come from
   random descents instead (each branch chosen in proportion to a relaxed
   count of its subtree): legal, but only roughly uniform (`exact` is
   False).

Whatever this module returns is checked with `Simulator.check_actions`
(one batched call), so a difference between its interval rules and the
simulator can drop a candidate but never let an illegal one through; parts
it cannot judge before a step (interm fluents) are left to that check.
Real-valued action fluents cannot be enumerated (`LegalActionsUnsupported`).
A state without any legal joint action raises `NoLegalAction`, naming the
constraint that cannot hold.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import legal_ground as G
from .model import STATE
from .simulator import SimulationError, Simulator, State
from .writer import write_expr

log = logging.getLogger(__name__)

Array = np.ndarray
Domain = tuple[int, ...]

INT_SPAN = 5
"""An int action fluent whose range the constraints leave (nearly) open
takes the values within INT_SPAN of its default (as rddlsim's random policy
draws ints in 0..5)."""
_INT_VALUES = 256  # most values of an int action variable kept explicitly
_INT_LIMIT = 2**31


class NoLegalAction(SimulationError):
    """No joint action is legal in the state, not even noop."""


class LegalActionsUnsupported(SimulationError):
    """The action space cannot be enumerated (real-valued action fluents)."""


class TooManyActions(SimulationError):
    """More legal joint actions than the caller's limit."""


# ------------------------------------------------------------ intervals


def interval(g: G.Ground, lo: list[float], hi: list[float]) -> tuple[float, float]:
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
    fn = G._NUMPY_FN[name]
    with np.errstate(all="ignore"):
        a, b = float(fn(x)), float(fn(y))
    if a != a or b != b:
        return -math.inf, math.inf
    return a, b


# ------------------------------------------------------------- elements


@dataclass
class _Linear:
    coefs: dict[int, float]
    const: float
    op: str  # le, lt, eq, ne (ge and gt are turned around)


@dataclass
class _Problem:
    """One state's elements, ready for propagation."""

    elements: list[G.Element]
    linear: list[_Linear | None]
    vars: list[tuple[int, ...]]
    watch: list[list[int]]  # variable -> elements that read it
    domains: list[Domain]
    defaults: list[int]
    budget: int | None  # max-nondef-actions


def _as_linear(g: G.Ground) -> _Linear | None:
    if g[0] not in ("le", "lt", "ge", "gt", "eq", "ne"):
        return None
    left = G.linear(g[1])
    right = G.linear(g[2])
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


# --------------------------------------------------------------- leaves


@dataclass
class _Leaf:
    """A set of joint actions counted in closed form: fixed variables,
    cardinality groups and free variables under the remaining budget."""

    base: list[int]  # every variable's value (defaults for the free ones)
    groups: list[tuple[tuple[int, ...], frozenset[int]]]  # variables, allowed number of trues
    free: list[tuple[int, Domain]]  # variable, its domain (two values or more)
    budget: int | None
    unsure: bool
    polys: list[list[int]] = field(default_factory=list)
    suffix: list[list[int]] = field(default_factory=list)
    count: int = 0

    def __post_init__(self) -> None:
        polys = [[math.comb(len(vs), t) if t in allowed else 0 for t in range(len(vs) + 1)] for vs, allowed in self.groups]
        for v, d in self.free:
            has = int(self.base[v] in d)
            polys.append([has, len(d) - has])
        self.polys = polys
        suffix = [[1]]
        for poly in reversed(polys):
            suffix.append(_times_poly(poly, suffix[-1], self.budget))
        suffix.reverse()
        self.suffix = suffix
        total = suffix[0]
        self.count = sum(total) if self.budget is None else sum(total[: self.budget + 1])

    def sample(self, rng: np.random.Generator) -> list[int]:
        """A uniform member."""
        total = self.suffix[0]
        top = len(total) if self.budget is None else min(len(total), self.budget + 1)
        j = _pick(rng, total[:top])
        out = list(self.base)
        for k, poly in enumerate(self.polys):
            rest = self.suffix[k + 1]
            weights = [poly[t] * (rest[j - t] if 0 <= j - t < len(rest) else 0) for t in range(min(j, len(poly) - 1) + 1)]
            t = _pick(rng, weights)
            j -= t
            if k < len(self.groups):
                vs = self.groups[k][0]
                for i in rng.choice(len(vs), t, replace=False) if t else ():
                    out[vs[int(i)]] = 1
            elif t:
                v, d = self.free[k - len(self.groups)]
                others = [x for x in d if x != self.base[v]]
                out[v] = others[int(rng.integers(len(others)))]
        return out

    def members(self) -> list[list[int]]:
        """Every member (count of them)."""
        options: list[list[tuple[int, list[tuple[int, int]]]]] = []
        for vs, allowed in self.groups:
            opts = []
            for t in sorted(allowed):
                if t <= len(vs):
                    opts.extend((t, [(v, 1) for v in combo]) for combo in itertools.combinations(vs, t))
            options.append(opts)
        for v, d in self.free:
            opts = [(0, [])] if self.base[v] in d else []
            opts.extend((1, [(v, x)]) for x in d if x != self.base[v])
            options.append(opts)
        out: list[list[int]] = []
        budget = math.inf if self.budget is None else self.budget

        def walk(k: int, used: int, row: list[int]) -> None:
            if k == len(options):
                out.append(list(row))
                return
            for cost, sets in options[k]:
                if used + cost > budget:
                    continue
                for v, x in sets:
                    row[v] = x
                walk(k + 1, used + cost, row)
                for v, _ in sets:
                    row[v] = self.base[v]

        walk(0, 0, list(self.base))
        return out


def _times_poly(a: list[int], b: list[int], budget: int | None) -> list[int]:
    n = len(a) + len(b) - 1
    if budget is not None:
        n = min(n, budget + 1)
    out = [0] * n
    for i, x in enumerate(a):
        if x == 0 or i >= n:
            continue
        for j, y in enumerate(b):
            if i + j >= n:
                break
            out[i + j] += x * y
    return out


def _below(rng: np.random.Generator, n: int) -> int:
    """A uniform integer in [0, n) for any n > 0 (counts can exceed 2**63)."""
    if n < 2**62:
        return int(rng.integers(n))
    bits = n.bit_length()
    nbytes = (bits + 7) // 8
    while True:
        r = int.from_bytes(rng.bytes(nbytes), "little") >> (8 * nbytes - bits)
        if r < n:
            return r


def _pick(rng: np.random.Generator, weights: Sequence[int]) -> int:
    """An index drawn in proportion to integer weights."""
    total = sum(weights)
    r = _below(rng, total)
    for i, w in enumerate(weights):
        if r < w:
            return i
        r -= w
    raise AssertionError("weights changed while drawing")


# --------------------------------------------------------------- search


def _leaf(p: _Problem, node: _Node) -> _Leaf | None:
    """The node as a leaf, when what is left is countable in closed form."""
    groups: dict[frozenset[int], set[int]] = {}
    for e in node.active:
        lin = p.linear[e]
        if lin is None:
            return None
        free = [v for v in lin.coefs if len(node.dom[v]) > 1]
        if not free:
            continue
        c = lin.coefs[free[0]]
        for v in free:
            if lin.coefs[v] != c or node.dom[v] != (0, 1) or p.defaults[v] != 0:
                return None
        fixed = lin.const + sum(
            k * node.dom[v][0] for v, k in lin.coefs.items() if len(node.dom[v]) == 1
        )
        allowed = {t for t in range(len(free) + 1) if _holds(lin.op, fixed + c * t)}
        key = frozenset(free)
        groups[key] = groups[key] & allowed if key in groups else allowed
    seen: set[int] = set()
    for key in groups:
        if key & seen:
            return None
        seen |= key
    base = [d[0] if len(d) == 1 else p.defaults[v] for v, d in enumerate(node.dom)]
    used = sum(1 for v, d in enumerate(node.dom) if len(d) == 1 and d[0] != p.defaults[v])
    budget = None if p.budget is None else p.budget - used
    free_vars = [(v, d) for v, d in enumerate(node.dom) if len(d) > 1 and v not in seen]
    return _Leaf(
        base,
        [(tuple(sorted(k)), frozenset(a)) for k, a in groups.items()],
        free_vars,
        budget,
        node.unsure,
    )


def _holds(op: str, x: float) -> bool:
    if op == "le":
        return x <= 0
    if op == "lt":
        return x < 0
    if op == "eq":
        return x == 0
    return x != 0


def _branch(p: _Problem, node: _Node) -> int:
    """The variable to branch on: in the element with the fewest free
    variables, the one with the smallest domain."""
    best: tuple[int, int, int] | None = None
    for e in node.active:
        free = [v for v in p.vars[e] if len(node.dom[v]) > 1]
        if not free:
            continue
        v = min(free, key=lambda u: (len(node.dom[u]), u))
        key = (len(free), len(node.dom[v]), v)
        if best is None or key < best:
            best = key
    if best is None:  # (cannot happen: such a node is a leaf)
        return next(v for v, d in enumerate(node.dom) if len(d) > 1)
    return best[2]


def _ordered(p: _Problem, node: _Node, v: int) -> list[int]:
    d = p.defaults[v]
    values = list(node.dom[v])
    return ([d] if d in values else []) + [x for x in values if x != d]


def _children(p: _Problem, node: _Node) -> list[_Node]:
    v = _branch(p, node)
    out = []
    for value in _ordered(p, node, v):
        child = node.child(v, value)
        try:
            _propagate(p, child, p.watch[v])
        except _Conflict:
            continue
        out.append(child)
    return out


def _search(p: _Problem, root: _Node, node_limit: int) -> tuple[list[_Leaf], bool, int]:
    """The leaves under `root` (propagated already), whether the search
    finished within `node_limit` branching nodes, and how many it used."""
    leaves: list[_Leaf] = []
    stack = [root]
    nodes = 0
    while stack:
        node = stack.pop()
        leaf = _leaf(p, node)
        if leaf is not None:
            if leaf.count:
                leaves.append(leaf)
            continue
        nodes += 1
        if nodes > node_limit:
            return leaves, False, nodes
        stack.extend(reversed(_children(p, node)))
    return leaves, True, nodes


def _descend(p: _Problem, root: _Node, rng: np.random.Generator, tries: int = 64) -> list[int] | None:
    """A legal assignment by a random descent: each branch chosen in
    proportion to the count of its subtree with the elements left out."""
    for _ in range(tries):
        node = root
        while True:
            leaf = _leaf(p, node)
            if leaf is not None:
                if leaf.count:
                    return leaf.sample(rng)
                break
            children = _children(p, node)
            if not children:
                break
            weights = [_relaxed(p, c) for c in children]
            if not any(weights):
                break
            node = children[_pick(rng, weights)]
    return None


def _relaxed(p: _Problem, node: _Node) -> int:
    base = [d[0] if len(d) == 1 else p.defaults[v] for v, d in enumerate(node.dom)]
    used = sum(1 for v, d in enumerate(node.dom) if len(d) == 1 and d[0] != p.defaults[v])
    budget = None if p.budget is None else p.budget - used
    if budget is not None and budget < 0:
        return 0
    free = [(v, d) for v, d in enumerate(node.dom) if len(d) > 1]
    return _Leaf(base, [], free, budget, node.unsure).count


# ---------------------------------------------------------------- spaces


class ActionSpace:
    """The legal joint actions of one state, as the search left them: rows
    of action-variable values (`LegalActions.arrays` turns them into the
    simulator's arrays)."""

    def __init__(
        self,
        problem: _Problem | None,
        root: _Node | None,
        leaves: list[_Leaf],
        complete: bool,
        nodes: int,
        why_none: str | None,
    ) -> None:
        self._problem = problem
        self._root = root
        self.leaves = leaves
        self.complete = complete
        """The search finished: `count` is exact (up to `unsure`)."""
        self.nodes = nodes
        self.count = sum(leaf.count for leaf in leaves)
        """How many legal joint actions (a lower bound when not complete)."""
        self.unsure = any(leaf.unsure for leaf in leaves)
        """Some candidates depend on a part only the simulator can judge."""
        self.why_none = why_none
        self._weights = [leaf.count for leaf in leaves]

    @property
    def empty(self) -> bool:
        """No joint action is legal here."""
        return self.complete and self.count == 0

    @property
    def exact(self) -> bool:
        """Counts and samples are exact (uniform)."""
        return self.complete and not self.unsure

    def require(self) -> None:
        """Raise `NoLegalAction` (with the reason) when the space is empty."""
        if self.empty:
            raise NoLegalAction(self.why_none or "no legal joint action in this state, not even noop")

    def rows(self, limit: int) -> list[list[int]]:
        """Every legal joint action (noop first when it is one); raises
        `TooManyActions` when there are more than `limit` or the search
        did not finish."""
        if not self.complete:
            raise TooManyActions(f"the search for legal joint actions stopped after {self.nodes} nodes")
        if self.count > limit:
            raise TooManyActions(f"{self.count} legal joint actions, more than the limit of {limit}")
        out = [row for leaf in self.leaves for row in leaf.members()]
        assert self._problem is not None
        noop = list(self._problem.defaults)
        for i, row in enumerate(out):
            if row == noop:
                out.insert(0, out.pop(i))
                break
        return out

    def sample(self, rng: np.random.Generator, n: int) -> list[list[int]]:
        """n joint actions drawn uniformly (with replacement) from the legal
        ones (roughly uniformly when the search did not finish)."""
        self.require()
        if self.leaves and (self.complete or self._root is None):
            out = []
            for _ in range(n):
                leaf = self.leaves[_pick(rng, self._weights)] if len(self.leaves) > 1 else self.leaves[0]
                out.append(leaf.sample(rng))
            return out
        assert self._problem is not None and self._root is not None
        out = []
        for _ in range(n):
            row = _descend(self._problem, self._root, rng)
            if row is None:
                if out:
                    out.append(out[-1])
                    continue
                raise NoLegalAction(
                    f"no legal joint action found in this state (random descents failed; "
                    f"the search stopped after {self.nodes} nodes)"
                )
            out.append(row)
        return out


# ------------------------------------------------------------ the solver


class LegalActions:
    """Legal joint actions of one instance, state by state (see the module
    docstring). Spaces are cached by the values of the state fluents the
    constraints read (once per session when they read none).

    >>> legal = LegalActions(sim)
    >>> legal.enumerate(state)          # every legal joint action, noop first
    >>> legal.sample(state, rng, 10)    # ten uniform draws
    """

    def __init__(self, sim: Simulator, node_limit: int = 2000, cache_size: int = 4096) -> None:
        real = [p.name for p in sim.action_fluents if p.range == "real"]
        if real:
            raise LegalActionsUnsupported(
                f"real-valued action fluents cannot be enumerated: {', '.join(real)}"
            )
        self.sim = sim
        self.model = sim.model
        self.layout = G.Layout(sim.model)
        dom = sim.model.domain
        self.constraints = [*dom.action_preconditions, *dom.state_action_constraints]
        reads: set[str] = set()
        for expr in self.constraints:
            for node in G.A.walk(expr):
                if isinstance(node, G.A.PVar) and node.name in self.model.pvariables:
                    if self.model.pvariables[node.name].kind == STATE:
                        reads.add(node.name)
        self.reads = sorted(reads)
        """The state fluents the constraints read: the key of the cache."""
        self.node_limit = node_limit
        self.cache_size = cache_size
        self._dyn: dict[int, bool] = {}
        self._cache: OrderedDict[bytes, ActionSpace] = OrderedDict()
        self._non_fluents = self._non_fluent_arrays()
        self._dtypes = {
            p.name: np.bool_ if p.range == "bool" else np.int64 for p in self.layout.fluents
        }

    @staticmethod
    def supports(sim: Simulator) -> bool:
        """Whether the action space can be enumerated (no real actions)."""
        return all(p.range != "real" for p in sim.action_fluents)

    def _non_fluent_arrays(self) -> dict[str, Array]:
        out = {}
        for p in self.model.pvariables.values():
            if p.kind != "non-fluent":
                continue
            shape = tuple(len(self.model.types[t].members) for t in p.params)
            arr = np.full(shape, self.layout.encode(p, self.model.default_of(p)))
            for (name, args), value in self.model.non_fluent_values.items():
                if name == p.name:
                    idx = tuple(self.layout.codes[t][a] for t, a in zip(p.params, args, strict=True))
                    arr[idx] = self.layout.encode(p, value)
            out[p.name] = arr
        return out

    # -- spaces ------------------------------------------------------

    def key(self, state: State, index: int = 0) -> bytes:
        """The cache key of state `index`: the bytes of the fluents read."""
        return b"".join(np.ascontiguousarray(state.values[n][index]).tobytes() for n in self.reads)

    def space(self, state: State, index: int = 0) -> ActionSpace:
        """The legal joint actions of state `index` of the batch."""
        key = self.key(state, index)
        got = self._cache.get(key)
        if got is not None:
            self._cache.move_to_end(key)
            return got
        got = self._build(state, index)
        self._cache[key] = got
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return got

    def _build(self, state: State, index: int) -> ActionSpace:
        values = dict(self._non_fluents)
        for p in self.sim.state_fluents:
            values[p.name] = np.asarray(state.values[p.name][index])
        grounder = G.Grounder(self.layout, values, self._dyn)
        elements = list(grounder.elements(self.constraints))
        p = self._problem(elements)
        for e, el in enumerate(elements):
            if el.formula == G.FALSE:
                return ActionSpace(p, None, [], True, 0, self._why(p, e))
        root = _Node(list(p.domains), set(range(len(elements))), False)
        if any(not d for d in p.domains):
            v = next(i for i, d in enumerate(p.domains) if not d)
            return ActionSpace(p, None, [], True, 0, f"no value of {self.layout.var_name(v)} is allowed")
        try:
            _propagate(p, root, range(len(elements)))
        except _Conflict as err:
            return ActionSpace(p, None, [], True, 0, self._why(p, err.element))
        leaves, complete, nodes = _search(p, root, self.node_limit)
        why = None
        if complete and not leaves:
            why = (
                "no legal joint action in this state: the constraints cannot all hold at once "
                f"(searched {nodes} nodes); noop violates {self._noop_violation(p, root)}"
            )
        return ActionSpace(p, root, leaves, complete, nodes, why)

    def _problem(self, elements: list[G.Element]) -> _Problem:
        n = self.layout.size
        linear = [_as_linear(el.formula) for el in elements]
        vars_ = [tuple(sorted(G.variables(el.formula))) for el in elements]
        watch: list[list[int]] = [[] for _ in range(n)]
        for e, vs in enumerate(vars_):
            for v in vs:
                watch[v].append(e)
        defaults = [int(d) for d in self.layout.defaults]
        domains: list[Domain] = []
        for v in range(n):
            p = self.layout.fluent_of[v]
            if p.range == "bool":
                domains.append((0, 1))
            elif p.range in self.layout.codes:
                domains.append(tuple(range(len(self.model.types[p.range].members))))
            else:
                domains.append(self._int_domain(v, defaults[v], linear, vars_))
        return _Problem(elements, linear, vars_, watch, domains, defaults, self.model.max_nondef_actions)

    def _int_domain(self, v: int, default: int, linear: list[_Linear | None], vars_: list[tuple[int, ...]]) -> Domain:
        """An int action variable's values: the bounds its one-variable
        linear elements give, else INT_SPAN around its default."""
        lo, hi = -_INT_LIMIT, _INT_LIMIT - 1
        for lin, vs in zip(linear, vars_, strict=True):
            if lin is None or vs != (v,) or lin.op == "ne":
                continue
            c = lin.coefs[v]
            b = -lin.const / c  # c x + k op 0, with x op' b
            if lin.op == "eq":
                if b != math.floor(b):
                    return ()
                lo, hi = max(lo, int(b)), min(hi, int(b))
            elif lin.op == "le":
                if c > 0:
                    hi = min(hi, math.floor(b))
                else:
                    lo = max(lo, math.ceil(b))
            elif c > 0:  # lt
                hi = min(hi, math.ceil(b) - 1)
            else:
                lo = max(lo, math.floor(b) + 1)
        if hi < lo:
            return ()
        if hi - lo + 1 <= _INT_VALUES:
            return tuple(range(lo, hi + 1))
        centre = min(max(default, lo), hi)
        return tuple(range(max(lo, centre - INT_SPAN), min(hi, centre + INT_SPAN) + 1))

    def _why(self, p: _Problem, e: int | None) -> str:
        if e is None:
            return (
                "no legal joint action in this state: more than max-nondef-actions "
                f"({p.budget}) action groundings would have to differ from their default"
            )
        el = p.elements[e]
        expr = self.constraints[el.index]
        where = ", ".join(f"{v} = {o}" for v, o in el.env)
        text = write_expr(expr)
        text = text if len(text) <= 160 else text[:157] + "..."
        return (
            f"no legal joint action in this state: {expr.loc}: constraint cannot hold"
            f"{' where ' + where if where else ''}: {text}"
        )

    def _noop_violation(self, p: _Problem, root: _Node) -> str:
        lo = [float(d) for d in p.defaults]
        for e, el in enumerate(p.elements):
            if _truth(*interval(el.formula, lo, lo))[1] == 0:
                expr = self.constraints[el.index]
                return f"{expr.loc}: {write_expr(expr)[:160]}"
        return "max-nondef-actions" if p.budget is not None and p.budget < 0 else "nothing (noop is legal?)"

    # -- arrays --------------------------------------------------------

    def arrays(self, rows: Sequence[Sequence[int]]) -> dict[str, Array]:
        """Rows of action-variable values as the simulator's action arrays."""
        n = len(rows)
        mat = np.asarray(rows, dtype=np.int64).reshape(n, self.layout.size)
        out = {}
        for p in self.layout.fluents:
            off = self.layout.offset[p.name]
            cnt = self.layout.count(p.name)
            out[p.name] = mat[:, off : off + cnt].reshape(n, *self.layout.shape[p.name]).astype(self._dtypes[p.name])
        return out

    def _verified(self, state: State, index: int, rows: list[list[int]]) -> dict[str, Array]:
        """The rows that `Simulator.check_actions` finds legal, as arrays."""
        arrays = self.arrays(rows)
        if not rows:
            return arrays
        ok = self.sim.check_actions(state[[index] * len(rows)], arrays)
        if not ok.all():
            log.debug("legal actions: the simulator refused %d of %d candidates", int((~ok).sum()), len(rows))
            arrays = {k: v[ok] for k, v in arrays.items()}
        return arrays

    # -- what planners call ---------------------------------------------

    def enumerate(self, state: State, index: int = 0, limit: int = 100_000) -> dict[str, Array]:
        """Every legal joint action of state `index`, stacked along the
        batch axis, noop first when it is legal. Raises `NoLegalAction`
        when there is none, `TooManyActions` above `limit`."""
        space = self.space(state, index)
        space.require()
        return self._verified(state, index, space.rows(limit))

    def count(self, state: State, index: int = 0) -> int:
        """How many joint actions are legal in state `index` (exact when
        the space's search finished)."""
        return self.space(state, index).count

    def sample(self, state: State, rng: np.random.Generator, n: int = 1, index: int = 0) -> dict[str, Array]:
        """n legal joint actions of state `index` drawn uniformly (with
        replacement). Raises `NoLegalAction` when there is none."""
        space = self.space(state, index)
        rows = space.sample(rng, n)
        arrays = self._verified(state, index, rows)
        got = next(iter(arrays.values())).shape[0] if arrays else n
        for _ in range(8):
            if got >= n:
                break
            more = self._verified(state, index, space.sample(rng, n - got))
            arrays = {k: np.concatenate([arrays[k], more[k]]) for k in arrays}
            got = next(iter(arrays.values())).shape[0] if arrays else n
        if got < n:
            raise NoLegalAction(
                "no legal joint action found in this state: every candidate the constraints "
                "allow was refused by the simulator"
            )
        return arrays

    def candidates(self, state: State, rng: np.random.Generator, limit: int, index: int = 0) -> dict[str, Array]:
        """At most `limit` distinct legal joint actions of state `index`:
        all of them when there are few enough, else noop (when legal) and a
        uniform sample of the others."""
        space = self.space(state, index)
        space.require()
        if space.complete and space.count <= limit:
            return self._verified(state, index, space.rows(limit))
        noop = list(self.layout.defaults)
        rows: list[list[int]] = []
        seen: set[tuple[int, ...]] = set()
        noop_ok = bool(self.sim.check_actions(state[[index]], self.sim.noop(1))[0])
        if noop_ok:
            rows.append([int(x) for x in noop])
            seen.add(tuple(rows[0]))
        for _ in range(4):
            for row in space.sample(rng, 2 * limit):
                key = tuple(row)
                if key not in seen and len(rows) < limit:
                    seen.add(key)
                    rows.append(row)
            if len(rows) >= limit:
                break
        return self._verified(state, index, rows)

    def sample_batch(self, states: State, rng: np.random.Generator) -> dict[str, Array]:
        """One uniformly drawn legal joint action for every state of the
        batch. Raises `NoLegalAction` naming the first state without one."""
        batch = states.batch
        by_key: dict[bytes, list[int]] = {}
        for b in range(batch):
            by_key.setdefault(self.key(states, b), []).append(b)
        rows: list[list[int]] = [[] for _ in range(batch)]
        for members in by_key.values():
            space = self.space(states, members[0])
            if space.empty:
                raise NoLegalAction(f"state {members[0]} of the batch: {space.why_none}")
            for b, row in zip(members, space.sample(rng, len(members)), strict=True):
                rows[b] = row
        arrays = self.arrays(rows)
        ok = self.sim.check_actions(states, arrays)
        for b in np.flatnonzero(~ok):
            one = self.sample(states, rng, 1, int(b))
            for k in arrays:
                arrays[k][b] = one[k][0]
        return arrays
