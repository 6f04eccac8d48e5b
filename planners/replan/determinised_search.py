"""The determinised search of `replan`: the state and action helpers, the
candidate joint actions of a real-valued action space (`joint_actions`), the
plan types (`PlanStep`, `SearchResult`, `SearchProblem`), the noop roll-outs
that value a plan (`continuation`) and the anytime best-first search itself
(`search`), as the package docstring describes them. It works on simulators
and states only and knows nothing of sessions or the wire; the planner class
(`planner.py`) calls it.
"""

from __future__ import annotations

import heapq
import itertools
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ...rddl.legal import LegalActions, NoLegalAction
from ...rddl.simulator import SimulationError, Simulator, State

Array = np.ndarray
Actions = dict[str, Array]

DEFAULT_MAX_ACTIONS = 1000
DEFAULT_EXPAND = 8
MAX_NODES = 200_000  # bound on the search tree's size
MAX_STATE_BYTES = 200_000_000  # bound on the memory the tree's states take
_WORST = -1e300  # value of a plan whose reward is not a number


# ------------------------------------------------------------ states


def concat_states(states: list[State]) -> State:
    """The states of several batches, one after the other."""
    if len(states) == 1:
        return states[0]
    return State({k: np.concatenate([s.values[k] for s in states]) for k in states[0].values})


def state_keys(state: State) -> list[bytes]:
    """A hashable key per state of the batch (its values' bytes)."""
    batch = state.batch
    parts = [
        np.ascontiguousarray(v).reshape(batch, -1).view(np.uint8)
        for _, v in sorted(state.values.items())
    ]
    if not parts:
        return [b""] * batch
    flat = np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
    return [row.tobytes() for row in flat]


def same_state(a: State, b: State, index: int = 0) -> bool:
    """Whether state `index` of `a` equals state 0 of `b` (reals within
    1e-6 relative: they went through the wire as text)."""
    for name, x in b.values.items():
        y = a.values.get(name)
        if y is None:
            return False
        y = y[index]
        x = x[0]
        if np.issubdtype(x.dtype, np.floating):
            if not np.allclose(x, y, rtol=1e-6, atol=1e-9, equal_nan=True):
                return False
        elif not np.array_equal(x, y):
            return False
    return True


def _gather(states: list[State], rows: list[int]) -> State:
    """State `rows[i]` of `states[i]`, for every i, as one batch."""
    return State(
        {
            k: np.concatenate([s.values[k][r : r + 1] for s, r in zip(states, rows, strict=True)])
            for k in states[0].values
        }
    )


def _take(actions: Mapping[str, Array], rows: Array | list[int]) -> Actions:
    return {k: v[rows] for k, v in actions.items()}


def _concat_actions(parts: list[Actions]) -> Actions:
    if len(parts) == 1:
        return parts[0]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


# ------------------------------------------------------------ actions


def joint_actions(sim: Simulator, limit: int) -> tuple[Actions, bool]:
    """Candidate joint actions, stacked along the batch axis (noop first),
    and whether the list stops short of max-nondef-actions.

    Every set of 1, 2, ... non-default action groundings, up to
    max-nondef-actions, for as long as the total stays within `limit`
    (a size that would pass the limit is left out as a whole). Booleans are
    flipped; an enum grounding takes each other value; int and real ones
    their default +- 1. Legality in a state is checked later."""
    model = sim.model
    noop = sim.noop(1)
    options: list[tuple[str, tuple[int, ...], object]] = []
    grounding_of: list[int] = []
    groundings = 0
    for p in sim.action_fluents:
        default = noop[p.name][0]
        for idx in np.ndindex(default.shape):
            d = default[idx].item()
            if p.range == "bool":
                values: list[object] = [not d]
            elif p.range in model.types:
                values = [c for c in range(len(model.types[p.range].members)) if c != d]
            elif p.range == "int":
                values = [d - 1, d + 1]
            else:
                values = [d - 1.0, d + 1.0]
            for v in values:
                options.append((p.name, idx, v))
                grounding_of.append(groundings)
            groundings += 1
    limit_k = (
        groundings
        if model.max_nondef_actions is None
        else min(model.max_nondef_actions, groundings)
    )
    combos: list[tuple[int, ...]] = [()]
    truncated = False
    for k in range(1, limit_k + 1):
        level: list[tuple[int, ...]] = []
        for combo in itertools.combinations(range(len(options)), k):
            if len({grounding_of[i] for i in combo}) < k:
                continue  # two values for one grounding
            level.append(combo)
            if len(combos) + len(level) > limit:
                break
        if len(combos) + len(level) > limit:
            truncated = True
            break
        combos.extend(level)
    actions = sim.noop(len(combos))
    for row, combo in enumerate(combos):
        for i in combo:
            name, idx, value = options[i]
            actions[name][(row, *idx)] = value
    return actions, truncated


# ------------------------------------------------------------ plans


@dataclass(frozen=True)
class PlanStep:
    """One step of a plan: the joint action (batch-1 arrays), the state it
    is predicted to lead to (batch 1) and the predicted reward."""

    actions: Actions
    state: State
    reward: float


@dataclass(frozen=True)
class SearchResult:
    """What one search found."""

    steps: list[PlanStep]  # the plan, `depth` steps (fewer when a goal ends it)
    value: float  # its predicted (discounted) reward
    complete: bool  # the search ran out of nodes (not cut by deadline or size)
    expansions: int  # nodes expanded
    nodes: int  # nodes generated
    depth: int
    seconds: float
    kept_incumbent: bool = False  # the plan given to refine was still the best


@dataclass
class SearchProblem:
    """What a search works with, built once per session."""

    sim: Simulator  # the determinised model
    world: Simulator  # the real model: sampled outcomes (all-outcomes), random actions
    candidates: Actions  # joint actions, stacked (noop first)
    truncated: bool  # the candidates stop short of max-nondef-actions
    discount: float
    rng: np.random.Generator
    outcomes: int = 0  # sampled outcomes per action (all-outcomes); 0: most-likely only
    expand: int = DEFAULT_EXPAND
    max_nodes: int = MAX_NODES
    solver: LegalActions | None = None  # each node's own legal joint actions (else `candidates`)
    max_actions: int = DEFAULT_MAX_ACTIONS

    def legal_children(self, parents: State) -> tuple[State, Actions, Array, bool]:
        """The legal joint actions of every parent, stacked, with their
        parents' states and indices, from the solver (at most `max_actions`
        each: all of them, else noop and a uniform sample), and whether any
        parent had more than that."""
        assert self.solver is not None
        per: list[Actions] = []
        owner: list[Array] = []
        cut = False
        for i in range(parents.batch):
            try:
                acts = self.solver.candidates(parents, self.rng, self.max_actions, i)
            except NoLegalAction:
                continue  # a dead end: no children
            space = self.solver.space(parents, i)
            cut = cut or not (space.complete and space.count <= self.max_actions)
            per.append(acts)
            owner.append(np.full(next(iter(acts.values())).shape[0], i))
        if not per:
            empty = np.zeros(0, dtype=np.int64)
            return parents[empty], {k: v[:0] for k, v in self.world.noop(1).items()}, empty, cut
        rows = np.concatenate(owner)
        return parents[rows], _concat_actions(per), rows, cut

    @property
    def n_candidates(self) -> int:
        return int(next(iter(self.candidates.values())).shape[0]) if self.candidates else 1


def unchanged(a: State, b: State) -> Array:
    """A (batch,) mask of the rows where `a` and `b` hold the same state."""
    same = np.ones(a.batch, dtype=bool)
    for name, x in a.values.items():
        y = b.values[name]
        same &= (x == y).reshape(a.batch, -1).all(axis=1)
    return same


def continuation(
    sim: Simulator,
    state: State,
    lengths: Array,
    start: Array,
    discount: float,
    rng: np.random.Generator | None,
) -> Array:
    """The discounted reward of doing nothing for `lengths[i]` steps from
    state i (whose first step has weight discount**start[i]); a termination
    ends the sum.

    The model is deterministic and stationary, so a state that noop leaves
    as it is stays so, with the same reward every step: such a row is
    summed up at once and leaves the batch (in many domains the noop
    trajectory settles after a few steps), as does a row that has
    terminated or run its length."""
    total = np.zeros(state.batch)
    rows = np.nonzero(np.asarray(lengths) > 0)[0]
    left = np.asarray(lengths, dtype=np.int64)[rows]
    first = np.asarray(start, dtype=np.float64)[rows]
    if len(rows) < state.batch:
        state = state[rows]
    t = 0
    while len(rows):
        out = sim.step(state, None, rng, check=False)  # type: ignore[arg-type]
        reward = np.asarray(out.reward, dtype=np.float64)
        weight = discount ** (first + t) if discount != 1.0 else 1.0
        total[rows] += weight * reward
        left -= 1
        done = np.asarray(out.done, dtype=bool)
        fixed = ~done & (left > 0) & unchanged(state, out.next_state)
        if fixed.any():
            if discount == 1.0:
                total[rows[fixed]] += reward[fixed] * left[fixed]
            else:
                w = discount ** (first[fixed] + t + 1)
                total[rows[fixed]] += (
                    reward[fixed] * w * (1.0 - discount ** left[fixed]) / (1.0 - discount)
                )
        alive = ~done & (left > 0) & ~fixed
        t += 1
        state = out.next_state
        if not alive.all():
            keep = np.nonzero(alive)[0]
            rows, left, first = rows[keep], left[keep], first[keep]
            if len(rows):
                state = state[keep]
    return total


def _noop_steps(
    sim: Simulator,
    state: State,
    steps: int,
    first: int,
    discount: float,
    rng: np.random.Generator | None,
) -> tuple[list[PlanStep], float]:
    """`steps` noop steps from `state` (batch 1) as plan steps, and their
    discounted reward; stops at a termination."""
    out_steps: list[PlanStep] = []
    total = 0.0
    noop = sim.noop(1)
    t = 0
    while t < steps:
        out = sim.step(state, None, rng, check=False)  # type: ignore[arg-type]
        r = float(out.reward[0])
        total += discount ** (first + t) * r
        out_steps.append(PlanStep(noop, out.next_state, r))
        t += 1
        if bool(out.done[0]):
            break
        if bool(unchanged(state, out.next_state)[0]):
            # a fixed point of noop: the same step again until the end
            while t < steps:
                total += discount ** (first + t) * r
                out_steps.append(out_steps[-1])
                t += 1
            break
        state = out.next_state
    return out_steps, total


def search(
    problem: SearchProblem,
    root: State,
    depth: int,
    deadline: float,
    incumbent: list[PlanStep] | None = None,
) -> SearchResult:
    """Best-first search for the plan of highest reward over `depth` steps
    from `root` (batch 1) in the determinised simulator, until the
    deadline (a `time.monotonic()` value) or the end of the tree.

    `incumbent`: a plan to keep unless a better one is found (refining a
    plan that still holds)."""
    t0 = time.monotonic()
    sim, gamma, rng = problem.sim, problem.discount, problem.rng
    depth = max(1, depth)
    # node tables (parallel lists); node 0 is the root
    batches: list[tuple[State, Actions, Array]] = [(root, sim.noop(1), np.zeros(1))]
    where: list[tuple[int, int]] = [(0, 0)]
    parent = [-1]
    level = [0]
    g = [0.0]
    term = [False]  # a termination holds in the node's state
    root_key = state_keys(root)[0]
    keys = [root_key]
    root_q = float(continuation(sim, root, np.array([depth]), np.array([0]), gamma, rng)[0])
    q = [root_q if math.isfinite(root_q) else _WORST]
    seen: dict[tuple[int, bytes], float] = {(0, root_key): 0.0}
    # every node keeps its state twice (the batch and the key): bound the memory too
    max_nodes = min(problem.max_nodes, max(1000, MAX_STATE_BYTES // max(1, 2 * len(root_key))))
    noop_legal = bool(problem.world.check_actions(root, sim.noop(1))[0])
    best = 0 if noop_legal else -1
    best_q = q[0] if noop_legal else -math.inf
    heap: list[tuple[float, int, int]] = [(-q[0], 0, 0)]
    expansions = 0
    per_round = 0.0  # the slowest expansion round so far
    n_cand = problem.n_candidates
    cut = False
    over_limit = False  # some node had more legal joint actions than max_actions
    while heap:
        now = time.monotonic()
        if expansions and now + 2.0 * per_round > deadline:
            cut = True
            break
        if len(parent) >= max_nodes:
            cut = True
            break
        started = now
        chosen: list[int] = []
        while heap and len(chosen) < problem.expand:
            _, _, node = heapq.heappop(heap)
            if seen[(level[node], keys[node])] > g[node]:
                continue  # its state was reached again with more reward: a better node
            chosen.append(node)
        if not chosen:
            continue
        parents = _gather([batches[where[n][0]][0] for n in chosen], [where[n][1] for n in chosen])
        m = len(chosen)
        if problem.solver is not None:
            # each node's own legal joint actions
            states, acts, owner, cut_here = problem.legal_children(parents)
            over_limit = over_limit or cut_here
        else:
            # every candidate in every chosen node, the legal ones kept
            states = parents[np.repeat(np.arange(m), n_cand)]
            acts = {
                k: np.tile(v, (m,) + (1,) * (v.ndim - 1)) for k, v in problem.candidates.items()
            }
            owner = np.repeat(np.arange(m), n_cand)
            legal = np.asarray(problem.world.check_actions(states, acts), dtype=bool)
            rows = np.nonzero(legal)[0]
            states, acts, owner = states[rows], _take(acts, rows), owner[rows]
        if problem.solver is None and problem.truncated:
            try:
                extra = problem.world.random_actions(parents, rng)
            except SimulationError:
                extra = None
            if extra is not None:
                states = concat_states([states, parents])
                acts = _concat_actions([acts, extra])
                owner = np.concatenate([owner, np.arange(m)])
        expansions += m
        if states.batch == 0:
            per_round = max(per_round, time.monotonic() - started)
            continue
        out = sim.step(states, acts, rng, check=False)
        nexts, rewards, dones = (
            [out.next_state],
            [np.asarray(out.reward, dtype=np.float64)],
            [out.done],
        )
        kid_acts, kid_owner = [acts], [owner]
        if problem.outcomes > 0:
            rep = np.tile(np.arange(states.batch), problem.outcomes)
            sampled = problem.world.step(states[rep], _take(acts, rep), rng, check=False)
            nexts.append(sampled.next_state)
            rewards.append(np.asarray(sampled.reward, dtype=np.float64))
            dones.append(sampled.done)
            kid_acts.append(_take(acts, rep))
            kid_owner.append(owner[rep])
        nxt = concat_states(nexts)
        reward = np.concatenate(rewards)
        done = np.concatenate(dones).astype(bool)
        kacts = _concat_actions(kid_acts)
        kowner = np.concatenate(kid_owner)
        par = np.array(chosen)[kowner]
        dpar = np.array([level[p] for p in par])
        gpar = np.array([g[p] for p in par])
        gkid = gpar + (gamma**dpar if gamma != 1.0 else 1.0) * reward
        gkid = np.where(np.isfinite(gkid), gkid, _WORST)
        # keep a child only if its state is new at its depth, or reached
        # with more reward than before
        keep: list[int] = []
        kid_keys = state_keys(nxt)
        for i, key in enumerate(kid_keys):
            k = (int(dpar[i]) + 1, key)
            old = seen.get(k)
            if old is None or gkid[i] > old:
                seen[k] = float(gkid[i])
                keep.append(i)
        if keep:
            rows = np.array(keep)
            kept = nxt[rows]
            kdepth = dpar[rows] + 1
            lengths = np.where(done[rows], 0, depth - kdepth)
            h = continuation(sim, kept, lengths, kdepth, gamma, rng)
            qk = gkid[rows] + h
            qk = np.where(np.isfinite(qk), qk, _WORST)
            b = len(batches)
            batches.append((kept, _take(kacts, rows), reward[rows]))
            for j, i in enumerate(keep):
                node = len(parent)
                where.append((b, j))
                parent.append(int(par[i]))
                level.append(int(kdepth[j]))
                g.append(float(gkid[i]))
                term.append(bool(done[i]))
                keys.append(kid_keys[i])
                q.append(float(qk[j]))
                if q[node] > best_q:
                    best, best_q = node, q[node]
                if kdepth[j] < depth and not done[i]:
                    heapq.heappush(heap, (-q[node], int(kdepth[j]), node))
        per_round = max(per_round, time.monotonic() - started)
    truncated = over_limit if problem.solver is not None else problem.truncated
    complete = not cut and not truncated and problem.outcomes == 0
    # the plan: the path to the best node, then noop to the depth
    steps: list[PlanStep] = []
    if best >= 0:
        path = []
        node = best
        while node > 0:
            path.append(node)
            node = parent[node]
        for node in reversed(path):
            b, row = where[node]
            st, ac, rw = batches[b]
            steps.append(PlanStep(_take(ac, [row]), st[[row]], float(rw[row])))
        b, row = where[best]
        if not term[best]:
            last = batches[b][0][[row]]
            more, _ = _noop_steps(sim, last, depth - level[best], level[best], gamma, rng)
            steps.extend(more)
    value = best_q
    kept_incumbent = False
    if incumbent:
        inc_steps, inc_value = _incumbent(sim, incumbent, depth, gamma, rng)
        if not steps or inc_value >= value - 1e-9 * max(1.0, abs(value)):
            steps, value, kept_incumbent = inc_steps, inc_value, True
    return SearchResult(
        steps=steps,
        value=value,
        complete=complete,
        expansions=expansions,
        nodes=len(parent),
        depth=depth,
        seconds=time.monotonic() - t0,
        kept_incumbent=kept_incumbent,
    )


def _incumbent(
    sim: Simulator, plan: list[PlanStep], depth: int, gamma: float, rng: np.random.Generator | None
) -> tuple[list[PlanStep], float]:
    """A plan kept from the last search, cut or extended (with noop) to
    `depth` steps, and its predicted reward from now."""
    steps = list(plan[:depth])
    value = sum(gamma**t * s.reward for t, s in enumerate(steps))
    if len(steps) < depth and len(steps) == len(plan):
        more, extra = _noop_steps(sim, steps[-1].state, depth - len(steps), len(steps), gamma, rng)
        steps.extend(more)
        value += extra
    return steps, value
