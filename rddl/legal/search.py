"""The search over the domains left by propagation: leaves counted in
closed form, depth-first enumeration, exact uniform sampling and random
descents (see the package docstring), and `ActionSpace`, the legal joint
actions of one state as the search left them.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..sim_types import SimulationError
from .propagate import Domain, _Conflict, _Node, _Problem, _propagate


class NoLegalAction(SimulationError):
    """No joint action is legal in the state, not even noop."""


class LegalActionsUnsupported(SimulationError):
    """The action space cannot be enumerated (real-valued action fluents)."""


class TooManyActions(SimulationError):
    """More legal joint actions than the caller's limit."""


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
        polys = [
            [math.comb(len(vs), t) if t in allowed else 0 for t in range(len(vs) + 1)]
            for vs, allowed in self.groups
        ]
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
            weights = [
                poly[t] * (rest[j - t] if 0 <= j - t < len(rest) else 0)
                for t in range(min(j, len(poly) - 1) + 1)
            ]
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
            opts: list[tuple[int, list[tuple[int, int]]]] = []
            for t in sorted(allowed):
                if t <= len(vs):
                    opts.extend(
                        (t, [(v, 1) for v in combo]) for combo in itertools.combinations(vs, t)
                    )
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


def _descend(
    p: _Problem, root: _Node, rng: np.random.Generator, tries: int = 64
) -> list[int] | None:
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
            raise NoLegalAction(
                self.why_none or "no legal joint action in this state, not even noop"
            )

    def rows(self, limit: int) -> list[list[int]]:
        """Every legal joint action (noop first when it is one); raises
        `TooManyActions` when there are more than `limit` or the search
        did not finish."""
        if not self.complete:
            raise TooManyActions(
                f"the search for legal joint actions stopped after {self.nodes} nodes"
            )
        if self.count > limit:
            raise TooManyActions(
                f"{self.count} legal joint actions, more than the limit of {limit}"
            )
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
                leaf = (
                    self.leaves[_pick(rng, self._weights)]
                    if len(self.leaves) > 1
                    else self.leaves[0]
                )
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
