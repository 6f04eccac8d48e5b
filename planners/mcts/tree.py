"""The search graph and its arithmetic: decision nodes (`_Node`), sampled
outcomes (`_Outcome`), trials (`_Trial`), UCB1 selection, the
MaxMonteCarlo backup with its partial Bellman refresh, and the final
choice at the root (see the package docstring).

Pure Python over the nodes' lists (with a handful of actions per node the
scalar updates and the UCB1 loop are faster than numpy calls); calls
nothing of the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...rddl.simulator import State

Array = np.ndarray

_EMPTY_INT = np.zeros(0, dtype=np.int64)


class _Outcome:
    """A sampled successor of a chance node: the node, how often it was
    sampled, the rewards seen on the way and the value last backed up."""

    __slots__ = ("node", "count", "rsum", "value")

    def __init__(self, node: _Node):
        self.node = node
        self.count = 0
        self.rsum = 0.0  # rewards seen on the way to it, summed
        self.value = 0.0


class _Node:
    """A decision node: states (one, or the particles of a POMDP root),
    steps left, candidate actions (library rows) and per-action statistics."""

    __slots__ = (
        "key",
        "states",
        "steps",
        "terminal",
        "acts",
        "h",
        "cnt",
        "tot",
        "qv",
        "nsum",
        "pending",
        "children",
        "value",
        "expanded",
    )

    def __init__(self, key: bytes | None, states: State | None, steps: int, terminal: bool):
        self.key = key
        self.states = states
        self.steps = steps
        self.terminal = terminal or steps <= 0
        self.acts: Array = _EMPTY_INT  # library rows
        self.h: list[float] = []  # heuristic estimate (rollouts)
        self.cnt: list[float] = []  # trials backed up through it
        self.tot: list[float] = []  # sum of (reward + discount * successor value)
        self.qv: list[float] = []  # value estimate
        self.nsum = 0.0  # sum over the actions of (init_weight + cnt)
        self.pending: list[int] = []  # trials of this wave under it
        self.children: list[dict[bytes, _Outcome]] = []
        self.value = 0.0
        self.expanded = False

    def q(self) -> Array:
        """Each candidate's value estimate."""
        return np.array(self.qv)


@dataclass
class _Trial:
    path: list[tuple[_Node, int, _Outcome, float]]
    node: _Node  # where it is now
    row: int  # the root particle it started from


def _bellman_total(outcomes: dict[bytes, _Outcome], gamma: float) -> float:
    """An action's `tot` from its outcomes' current node values (each
    outcome's kept value refreshed on the way): the sum of the rewards seen
    plus discount x times sampled x value."""
    tot = 0.0
    for o in outcomes.values():
        o.value = o.node.value
        tot += o.rsum + gamma * o.count * o.value
    return tot


def select(node: _Node, exploration: float, init_weight: float) -> int:
    """UCB1 with the node's largest |Q| as the scale of exploration; the
    wave's pending trials count as visits (and the chosen one gets one)."""
    qv = node.qv
    pending = node.pending
    if len(qv) == 1:
        pending[0] += 1
        return 0
    cnt = node.cnt
    scale = max(abs(max(qv)), abs(min(qv))) or 1.0
    coef = exploration * scale * math.sqrt(math.log(node.nsum + sum(pending)))
    a = 0
    best = -math.inf
    for i, q in enumerate(qv):
        u = q + coef / math.sqrt(init_weight + cnt[i] + pending[i])
        if u > best:
            best = u
            a = i
    pending[a] += 1
    return a


def backup(trial: _Trial, gamma: float, init_weight: float, bellman_outcomes: int) -> None:
    """MaxMonteCarlo backup along the trial's path.

    `tot[a]` is the sum over a's sampled outcomes of (rewards seen +
    discount x times sampled x the outcome node's value). With at most
    `bellman_outcomes` distinct outcomes, every outcome's value is read
    afresh from its node (a partial Bellman backup, as PROST's): with
    transpositions a node's value also changes through other paths, and a
    stale copy would keep an action that leads there looking as bad as it
    first did. With more outcomes only the one sampled is refreshed, to
    keep a backup cheap."""
    w = init_weight
    value = trial.node.value if trial.node.expanded else 0.0
    for node, a, outcome, reward in reversed(trial.path):
        outcome.count += 1
        outcome.rsum += reward
        outcomes = node.children[a]
        if len(outcomes) <= bellman_outcomes:
            tot = _bellman_total(outcomes, gamma)
        else:
            before = (outcome.count - 1) * outcome.value
            outcome.value = value
            tot = node.tot[a] + reward + gamma * (outcome.count * value - before)
        node.tot[a] = tot
        cnt = node.cnt[a] = node.cnt[a] + 1.0
        node.nsum += 1.0
        node.qv[a] = (w * node.h[a] + tot) / (w + cnt)
        node.value = value = max(node.qv)


def refresh(node: _Node, gamma: float, init_weight: float, bellman_outcomes: int) -> None:
    """Every action's value of `node` from its outcomes' current values
    (before the root's choice: some were last backed up long ago)."""
    w = init_weight
    for a, outcomes in enumerate(node.children):
        if not outcomes or len(outcomes) > bellman_outcomes:
            continue
        tot = node.tot[a] = _bellman_total(outcomes, gamma)
        node.qv[a] = (w * node.h[a] + tot) / (w + node.cnt[a])
    if node.qv:
        node.value = max(node.qv)


def best(root: _Node) -> int:
    """The candidate with the highest value (most visits among equals)."""
    if len(root.acts) == 0:
        return 0
    top = max(root.qv)
    slack = 1e-9 * max(1.0, abs(top))
    chosen = [i for i, q in enumerate(root.qv) if q >= top - slack]
    return max(chosen, key=lambda i: root.cnt[i])
