"""Exact finite-horizon values of small MDPs, by value iteration over the
reachable states: the yardstick a planner's quality is measured against.

A planner's mean round reward over a few rounds says little on its own: on
IPPC's Elevators #1 the optimal policy's round reward has a standard
deviation of about 12.6, so five rounds of a perfect planner land anywhere
in about +-11 of its expectation. On an instance small enough to enumerate,
`solve` gives the exact expected value of every reachable state for every
number of steps left, and `regret` prices a single decision: the expected
return lost by taking that action instead of the best one. Summed over the
decisions of a round, regrets are an unbiased estimate of how far the
planner's expected round reward lies below the optimum, with far less noise
than the rewards themselves (the luck of the world cancels out).

What can be solved: every state fluent boolean, no real-valued action
fluent (boolean joint actions are enumerated when there are at most
`max_actions` of them with at most max-nondef-actions set, and filtered by
max-nondef-actions, the preconditions and the state-action constraints in
each state; otherwise, and for enum and int actions, the table holds the
legal joint actions of the reachable states, from `ippc.rddl.legal`, grown
and explored again until every reachable state's legal actions are in it), every state cpf built from Bernoulli (of a probability without draws),
KronDelta and deterministic bool expressions with if, switch (on a subject
without draws), ~, ^, |, =>, <=>, exists and forall, nested as deep as the
domain likes (each draw node is an independent draw, so the probability
that the cpf is true composes; see `_probability`), interm and derived fluents and the
reward without draws, no `termination`, no observations, a finite horizon.
The next-state fluents of a transition are then independent given the state
and the actions (the factored model of IPPC's boolean domains), so a
successor's probability is a product over the fluents whose probability is
neither 0 nor 1. Anything else raises `ExactUnsupported` naming the reason.

How: the probability that each state fluent is true next is compiled as a
real-valued state fluent of a rewritten model (each draw replaced by its
probability of true), so the simulator's own code evaluates it, batched,
for every reachable state and joint action; rewards come from the same
step. States are found breadth first from the initial state.
"""

from __future__ import annotations

import dataclasses
import logging
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..rddl import ast as A
from ..rddl.legal import LegalActions, NoLegalAction, TooManyActions, solver_for
from ..rddl.loader import load_pair
from ..rddl.model import Model
from ..rddl.simulator import Simulator, State
from ..rddl.wire import WireCodec
from ..rddl.writer import write
from .base import Observation, Planner, PlannerError, SessionInfo, WireFluent
from .budget import (
    DEFAULT_MEMORY_FRACTION,
    StartupOverrun,
    describe_bytes,
    memory_budget,
    rows_within,
    run_within,
    step_cost,
)
from .mcts import enumerate_boolean

log = logging.getLogger(__name__)

Array = np.ndarray[Any, Any]

PROB_SUFFIX = "__prob-true"
"""Appended to a state fluent's name for its probability in the rewritten model."""

TRANSITION_BYTES = 75
"""Peak bytes a (state, action, successor) triple takes while it is found."""

DEFAULT_STARTUP = 60.0
"""Seconds `exact` may take to solve an instance by default (option startup)."""


class ExactUnsupported(Exception):
    """The model is outside what `solve` enumerates (the message says why)."""


# ------------------------------------------------------------ the rewrite


def _where(e: A.Expr | A.Loc) -> str:
    loc = e if isinstance(e, A.Loc) else getattr(e, "loc", None)
    return f" at {loc.line}:{loc.column}" if loc is not None and loc.line else ""


def _indicator(cond: A.Expr, loc: A.Loc) -> A.Expr:
    return A.If(cond, A.Const(1.0, loc), A.Const(0.0, loc), loc)


def _c(x: float, loc: A.Loc) -> A.Expr:
    return A.Const(x, loc)


def _times(a: A.Expr, b: A.Expr, loc: A.Loc) -> A.Expr:
    return A.Binary("*", a, b, loc)


def _not(p: A.Expr, loc: A.Loc) -> A.Expr:
    return A.Binary("-", _c(1.0, loc), p, loc)


def _probability(e: A.Expr, fluent: str) -> A.Expr:
    """A real expression: the probability that the bool cpf `e` is true.

    Every draw node of an expression is its own independent draw, so the
    probability composes: P(a ^ b) = P(a) P(b), P(~a) = 1 - P(a), an `if` on
    a random condition mixes its branches by the condition's probability,
    and `exists`/`forall` over draws are products over their objects."""
    loc = e.loc
    if not A.has_draws(e):
        return _indicator(e, loc)
    if isinstance(e, A.Distribution) and e.name == "Bernoulli":
        (p,) = e.args
        if A.has_draws(p):
            raise ExactUnsupported(f"{fluent}: a Bernoulli whose probability draws{_where(e)}")
        return A.Distribution("DiracDelta", (p,), loc)  # the simulator's cast to real
    if isinstance(e, A.Distribution) and e.name == "KronDelta":
        return _probability(e.args[0], fluent)
    if isinstance(e, A.If):
        then, else_ = _probability(e.then, fluent), _probability(e.else_, fluent)
        if not A.has_draws(e.cond):
            return dataclasses.replace(e, then=then, else_=else_)
        pc = _probability(e.cond, fluent)
        return A.Binary("+", _times(pc, then, loc), _times(_not(pc, loc), else_, loc), loc)
    if isinstance(e, A.Switch):
        if A.has_draws(e.subject) or any(
            c.label is not None and A.has_draws(c.label) for c in e.cases
        ):
            raise ExactUnsupported(f"{fluent}: a switch whose subject or labels draw{_where(e)}")
        cases = tuple(dataclasses.replace(c, value=_probability(c.value, fluent)) for c in e.cases)
        return dataclasses.replace(e, cases=cases)
    if isinstance(e, A.Unary) and e.op == "~":
        return _not(_probability(e.operand, fluent), loc)
    if isinstance(e, A.Binary) and e.op in ("^", "|", "=>", "<=>"):
        a, b = _probability(e.left, fluent), _probability(e.right, fluent)
        if e.op == "^":
            return _times(a, b, loc)
        if e.op == "|":
            return _not(_times(_not(a, loc), _not(b, loc), loc), loc)
        if e.op == "=>":
            return _not(_times(a, _not(b, loc), loc), loc)
        both = _times(a, b, loc)
        neither = _times(_not(a, loc), _not(b, loc), loc)
        return A.Binary("+", both, neither, loc)
    if isinstance(e, A.Aggregation) and e.op in ("exists", "forall"):
        body = _probability(e.body, fluent)
        if e.op == "forall":
            return A.Aggregation("prod", e.params, body, loc)
        return _not(A.Aggregation("prod", e.params, _not(body, loc), loc), loc)
    raise ExactUnsupported(
        f"{fluent}: a draw inside {type(e).__name__.lower()}"
        f"{' ' + repr(getattr(e, 'op', '')) if getattr(e, 'op', None) else ''}{_where(e)} "
        "(enumerated: Bernoulli and KronDelta under if, switch, ~, ^, |, =>, <=>, exists, forall)"
    )


def check_supported(model: Model) -> None:
    """Raise `ExactUnsupported` when `solve` cannot enumerate `model`."""
    if model.is_pomdp:
        raise ExactUnsupported("a POMDP (observations are not enumerated)")
    if model.horizon is None:
        raise ExactUnsupported("no finite horizon")
    if model.domain.termination:
        raise ExactUnsupported("a termination condition")
    for p in model.pvariables.values():
        if p.kind == "state-fluent" and p.range != "bool":
            raise ExactUnsupported(f"state fluent {p.name} is {p.range}, not bool")
        if p.kind == "action-fluent" and p.range == "real":
            raise ExactUnsupported(f"action fluent {p.name} is real-valued")
        if p.kind in ("interm-fluent", "derived-fluent"):
            cpf = model.cpfs.get(p.name)
            if cpf is not None and A.has_draws(cpf.expr):
                raise ExactUnsupported(f"{p.kind} {p.name} draws")
    if model.reward is not None and A.has_draws(model.reward):
        raise ExactUnsupported("the reward draws")
    if model.reward is not None:
        for node in A.walk(model.reward):
            if isinstance(node, A.PVar) and node.primed:
                raise ExactUnsupported(f"the reward reads the next state ({node.name}')")
    for p in model.pvariables.values():
        if p.kind == "state-fluent":
            cpf = model.cpfs.get(p.name)
            if cpf is not None:
                for node in A.walk(cpf.expr):
                    if isinstance(node, A.PVar) and node.primed:
                        # its value is another fluent's draw of this step:
                        # the fluents are no longer independent
                        raise ExactUnsupported(
                            f"{p.name}' reads the next state ({node.name}'){_where(node)}"
                        )
                _probability(cpf.expr, p.name)


def probability_model(model: Model) -> Model:
    """`model` with one more real state fluent per bool state fluent X,
    `X__prob-true`, whose next value is the probability that X is true next
    (from the current state and actions). The original cpfs stay."""
    check_supported(model)
    dom = model.domain
    decls = list(dom.pvariables)
    cpfs = list(dom.cpfs)
    by_name = {c.name: c for c in dom.cpfs}
    for d in dom.pvariables:
        if d.kind != "state-fluent":
            continue
        cpf = by_name.get(d.name)
        name = d.name + PROB_SUFFIX
        decls.append(A.PVarDef(name, d.params, "state-fluent", "real", A.Const(0.0, d.loc)))
        if cpf is None:  # the checker requires one; a model built by hand may lack it
            raise ExactUnsupported(f"state fluent {d.name} has no cpf")
        expr = _probability(cpf.expr, d.name)
        cpfs.append(A.Cpf(name, True, cpf.params, expr, d.loc))
    domain = dataclasses.replace(dom, pvariables=tuple(decls), cpfs=tuple(cpfs))
    with tempfile.TemporaryDirectory(prefix="ippc-exact-") as tmp:
        dfile, ifile = Path(tmp, "domain.rddl"), Path(tmp, "instance.rddl")
        dfile.write_text(write(domain) + "\n")
        blocks = [model.non_fluents_block, model.instance]
        ifile.write_text("\n\n".join(write(b) for b in blocks if b is not None) + "\n")
        return load_pair(dfile, ifile, model.instance.name)


# ------------------------------------------------------------ the solution


@dataclass
class Solution:
    """Exact values of `model` over its reachable states.

    `q[k]` is a (states, actions) array of the expected return of taking
    each joint action with `k` steps left and acting optimally after
    (-inf where the action is illegal); `v[k]` its row maximum; `k` runs
    from 0 to the horizon.
    """

    model: Model
    simulator: Simulator
    bits: Array  # (states, n_bits) bool: the reachable states, in the order found
    actions: dict[str, Array]  # the enumerated joint actions, (n_actions, *params)
    legal: Array  # (states, n_actions) bool
    reward: Array  # (states, n_actions)
    q: list[Array]
    v: list[Array]
    transitions: int  # stored (state, action, successor) triples

    @property
    def initial_value(self) -> float:
        """The optimal expected round reward from the initial state."""
        return float(self.v[len(self.v) - 1][0])

    def index(self, state: State, row: int = 0) -> int:
        """The number of the state at `row` of a batch (KeyError if it was never reached)."""
        code = _codes(_state_bits(self.simulator, state)[row : row + 1])[0]
        return self._index[int(code)]

    def indices(self, state: State) -> Array:
        """The numbers of every state of a batch."""
        codes = _codes(_state_bits(self.simulator, state))
        return np.array([self._index[int(c)] for c in codes.tolist()], dtype=np.int64)

    def best(self, steps_left: int, state: State) -> dict[str, Array]:
        """An optimal joint action for every state of a batch (the first of equals)."""
        choice = self.q[steps_left][self.indices(state)].argmax(axis=1)
        return {k: v[choice] for k, v in self.actions.items()}

    def action_index(self, actions: Mapping[str, Array], row: int = 0) -> int:
        """The number of the joint action at `row` of a batch."""
        return self._action_keys[_action_key(actions, self._action_names, row)]

    def regret(self, steps_left: int, state: State, actions: Mapping[str, Array]) -> float:
        """Expected return lost by taking `actions` in `state` with
        `steps_left` steps left, against the best action (0 when it is one)."""
        s, a = self.index(state), self.action_index(actions)
        q = self.q[steps_left][s]
        return float(q.max() - q[a])

    def policy_value(self, choose: Array) -> float:
        """Expected round reward from the initial state of the policy that
        takes joint action `choose[s]` in state `s` (whatever the steps left)."""
        v = np.zeros(len(self.bits))
        rows = np.arange(len(self.bits))
        if not self.legal[rows, choose].all():
            raise ValueError("the policy takes an illegal action")
        gamma = self.model.discount
        for _ in range(len(self.v) - 1):
            flat = rows * self.legal.shape[1] + choose
            v = self.reward[rows, choose] + gamma * self._expect(v)[flat]
        return float(v[0])

    # filled by solve()
    _index: dict[int, int] = dataclasses.field(default_factory=dict)
    _action_names: list[str] = dataclasses.field(default_factory=list)
    _action_keys: dict[bytes, int] = dataclasses.field(default_factory=dict)
    _starts: Array | None = None
    _succ: Array | None = None
    _prob: Array | None = None

    def _expect(self, v: Array) -> Array:
        """E[v(next)] for every (state, action) pair, flat (state-major)."""
        assert self._starts is not None and self._succ is not None and self._prob is not None
        return np.add.reduceat(self._prob * v[self._succ], self._starts)


def _state_bits(sim: Simulator, state: State) -> Array:
    names = [p.name for p in sim.state_fluents if not p.name.endswith(PROB_SUFFIX)]
    n = state.batch
    return np.concatenate([state.values[k].reshape(n, -1) for k in names], axis=1).astype(bool)


def _action_key(actions: Mapping[str, Array], names: list[str], row: int) -> bytes:
    """The bytes of the joint action at `row` of a batch (its arrays in `names` order)."""
    return b"".join(np.ascontiguousarray(actions[n][row : row + 1]).tobytes() for n in names)


def table_bytes(n_states: int, n_actions: int, n_bits: int, horizon: int, transitions: int) -> int:
    """Bytes a solution of this size takes: per state its bits, its actions'
    legality, rewards and one Q-value per step left, one value per step left;
    per transition its peak while found (`TRANSITION_BYTES`)."""
    per_state = n_bits + n_actions * (1 + 8 + 8 * (horizon + 1)) + 8 * (horizon + 1)
    return n_states * per_state + transitions * TRANSITION_BYTES


def _codes(bits: Array) -> Array:
    weights = np.left_shift(np.int64(1), np.arange(bits.shape[1], dtype=np.int64))
    return bits.astype(np.int64) @ weights


def solve(
    model: Model,
    *,
    max_states: int = 50_000,
    max_actions: int = 4096,
    max_branching: int = 14,
    max_transitions: int = 20_000_000,
    memory: int | None = None,
) -> Solution:
    """Value iteration over the states reachable from the initial state.

    Raises `ExactUnsupported` when the model is outside what is enumerated
    (see the module docstring) or too large: more than `max_states`
    reachable states, `max_actions` joint actions, `max_branching`
    uncertain fluents in one transition, `max_transitions` (state,
    action, successor) triples in all, or (with `memory`, in bytes) a table
    larger than that (`table_bytes`): the exploration stops as soon as the
    states and transitions found so far need more, and nothing larger is
    allocated.
    """
    pm = probability_model(model)
    world = Simulator(model)
    sim = Simulator(pm)
    originals = [p for p in sim.state_fluents if not p.name.endswith(PROB_SUFFIX)]
    if any(p.range != "bool" for p in originals):
        raise ExactUnsupported("a state fluent that is not bool")
    shapes = {p.name: sim.initial_state(1).values[p.name].shape[1:] for p in originals}
    n_bits = sum(int(np.prod(s)) for s in shapes.values())
    if n_bits > 62:
        raise ExactUnsupported(f"{n_bits} state bits (at most 62 are encoded)")
    acts = enumerate_boolean(world, max_actions)
    solver = None
    if acts is None:
        # too many joint actions to list blindly (or non-bool ones): the legal
        # ones of the states found, grown until every reachable state's are in
        if not LegalActions.supports(world):
            raise ExactUnsupported("real-valued action fluents")
        solver = solver_for(world)
        try:
            acts = solver.enumerate(world.initial_state(1), limit=max_actions)
        except (NoLegalAction, TooManyActions) as err:
            raise ExactUnsupported(str(err)) from None
    while True:
        try:
            return _explore(
                model,
                world,
                sim,
                shapes,
                n_bits,
                acts,
                solver,
                max_states,
                max_branching,
                max_transitions,
                memory,
            )
        except _MoreActions as more:
            acts = _union(world, acts, more.actions)
            n = next(iter(acts.values())).shape[0]
            if n > max_actions:
                raise ExactUnsupported(f"more than {max_actions} legal joint actions") from None
            log.debug("exact: %s: %d joint actions, exploring again", model.name, n)


class _MoreActions(Exception):
    """A reachable state has legal joint actions the table lacks."""

    def __init__(self, actions: dict[str, Array]) -> None:
        super().__init__("more legal joint actions")
        self.actions = actions


def _union(world: Simulator, a: dict[str, Array], b: dict[str, Array]) -> dict[str, Array]:
    """The joint actions of `a`, then those of `b` not in `a`."""
    names = [p.name for p in world.action_fluents]
    seen = {_action_key(a, names, i) for i in range(next(iter(a.values())).shape[0])}
    extra = [
        i for i in range(next(iter(b.values())).shape[0]) if _action_key(b, names, i) not in seen
    ]
    return {k: np.concatenate([a[k], b[k][extra]]) for k in a}


def _explore(
    model: Model,
    world: Simulator,
    sim: Simulator,
    shapes: dict[str, tuple[int, ...]],
    n_bits: int,
    acts: dict[str, Array],
    solver: LegalActions | None,
    max_states: int,
    max_branching: int,
    max_transitions: int,
    memory: int | None = None,
) -> Solution:
    """Breadth-first exploration and value iteration with the joint actions
    `acts`; with `solver`, raises `_MoreActions` when a reachable state has
    legal joint actions that `acts` lacks."""
    n_act = next(iter(acts.values())).shape[0] if acts else 1

    def states_of(bits: Array) -> State:
        values: dict[str, Array] = {}
        col = 0
        init = sim.initial_state(len(bits)).values
        for p in sim.state_fluents:
            if p.name.endswith(PROB_SUFFIX):
                values[p.name] = init[p.name]
                continue
            w = int(np.prod(shapes[p.name]))
            values[p.name] = bits[:, col : col + w].reshape(len(bits), *shapes[p.name]).copy()
            col += w
        return State(values)

    originals = [p for p in sim.state_fluents if not p.name.endswith(PROB_SUFFIX)]
    prob_names = [p.name + PROB_SUFFIX for p in originals]
    rng = np.random.default_rng(0)  # the original cpfs still draw; their values are unused

    start_bits = _state_bits(sim, sim.initial_state(1))
    # known state codes, sorted, with their numbers (numbered as found)
    known_codes = _codes(start_bits)
    known_ids = np.zeros(1, dtype=np.int64)
    all_bits = [start_bits]
    legal_rows: list[Array] = []
    reward_rows: list[Array] = []
    row_parts: list[Array] = []  # global row (state * n_act + action) of each transition
    succ_codes: list[Array] = []
    prob_parts: list[Array] = []
    n_transitions = 0
    combos_cache: dict[int, Array] = {}
    frontier, first = start_bits, 0  # states numbered first, first + 1, ...
    rows = 65536
    if memory is not None:
        # a chunk's step (every state with every action) takes at most a quarter
        rows = rows_within(memory // 4, step_cost(sim), rows)
    chunk = max(1, rows // n_act)
    horizon = model.horizon or 1

    def check_memory(n_states: int) -> None:
        if memory is None:
            return
        need = table_bytes(n_states, n_act, n_bits, horizon, n_transitions)
        if need > memory:
            raise ExactUnsupported(
                f"its table needs more than the memory budget of {describe_bytes(memory)} "
                f"(option memory): at least {describe_bytes(need)} for the {n_states} states "
                f"x {n_act} joint actions x {horizon} steps and {n_transitions} transitions "
                "found so far"
            )

    check_memory(1)
    while len(frontier):
        new_codes: list[Array] = []
        for lo in range(0, len(frontier), chunk):
            part = frontier[lo : lo + chunk]
            m = len(part)
            states = states_of(np.repeat(part, n_act, axis=0))
            batch_acts = {k: np.tile(v, (m,) + (1,) * (v.ndim - 1)) for k, v in acts.items()}
            world_states = State({p.name: states.values[p.name] for p in world.state_fluents})
            legal = world.check_actions(world_states, batch_acts)
            if solver is not None:
                found = legal.reshape(m, n_act).sum(axis=1)
                for i in range(m):
                    if solver.count(world_states, i * n_act) > found[i]:
                        raise _MoreActions(solver.enumerate(world_states, i * n_act))
            out = sim.step(states, batch_acts, rng, check=False)
            probs = np.concatenate(
                [out.next_state.values[k].reshape(m * n_act, -1) for k in prob_names], axis=1
            )
            legal_rows.append(legal.reshape(m, n_act))
            reward_rows.append(np.asarray(out.reward, dtype=float).reshape(m, n_act))
            unsure = (probs > 0.0) & (probs < 1.0)
            base = _codes(probs >= 1.0)
            n_unsure = unsure.sum(axis=1)
            rows0 = (first + lo) * n_act
            for u in np.unique(n_unsure).tolist():
                if u > max_branching:
                    raise ExactUnsupported(
                        f"{u} uncertain fluents in one transition (at most {max_branching})"
                    )
                combos = combos_cache.get(u)
                if combos is None:
                    grid = (np.arange(1 << u)[:, None] >> np.arange(u)[None, :]) & 1
                    combos = combos_cache[u] = grid.astype(bool)
                wide = combos.astype(np.int64)
                group = np.flatnonzero(n_unsure == u)
                step_rows = max(1, (1 << 22) >> u)  # at most ~4M successors at a time
                for g in range(0, len(group), step_rows):
                    rows = group[g : g + step_rows]
                    # the uncertain positions of each row, in increasing order
                    pos = np.nonzero(unsure[rows])[1].reshape(len(rows), u)
                    p = probs[rows[:, None], pos]  # (rows, u)
                    pr = np.ones((len(rows), 1 << u))
                    for j in range(u):
                        pr *= np.where(combos[None, :, j], p[:, j : j + 1], 1.0 - p[:, j : j + 1])
                    weights = np.left_shift(np.int64(1), pos)  # (rows, u)
                    codes = base[rows][:, None] + weights @ wide.T
                    keep = pr > 0.0
                    n_transitions += int(keep.sum())
                    if n_transitions > max_transitions:
                        raise ExactUnsupported(f"more than {max_transitions} transitions")
                    check_memory(first + lo + len(part))
                    row_parts.append(np.broadcast_to((rows0 + rows)[:, None], codes.shape)[keep])
                    succ_codes.append(codes[keep])
                    prob_parts.append(pr[keep])
                    new_codes.append(np.unique(codes[keep]))
        # number the successors never seen before, in code order
        cand = np.unique(np.concatenate(new_codes)) if new_codes else np.zeros(0, np.int64)
        at = np.searchsorted(known_codes, cand).clip(max=len(known_codes) - 1)
        fresh = cand[known_codes[at] != cand]
        first = int(known_ids.max()) + 1
        if first + len(fresh) > max_states:
            raise ExactUnsupported(f"more than {max_states} reachable states")
        check_memory(first + len(fresh))
        fresh_ids = first + np.arange(len(fresh), dtype=np.int64)
        order = np.argsort(np.concatenate([known_codes, fresh]), kind="stable")
        known_codes = np.concatenate([known_codes, fresh])[order]
        known_ids = np.concatenate([known_ids, fresh_ids])[order]
        frontier = ((fresh[:, None] >> np.arange(n_bits)[None, :]) & 1).astype(bool)
        if len(frontier):
            all_bits.append(frontier)
    bits = np.concatenate(all_bits)
    legal_all = np.concatenate(legal_rows)
    reward = np.concatenate(reward_rows)
    n_states = len(bits)
    rows_all = np.concatenate(row_parts)
    order = np.argsort(rows_all, kind="stable")
    succ = known_ids[np.searchsorted(known_codes, np.concatenate(succ_codes)[order])]
    succ = succ.astype(np.int32 if n_states < 2**31 else np.int64)
    prob = np.concatenate(prob_parts)[order]
    del succ_codes, prob_parts
    sizes = np.bincount(rows_all, minlength=n_states * n_act)
    if (sizes == 0).any():
        raise AssertionError("a transition without successors")  # probabilities sum to 1
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    index = dict(zip(known_codes.tolist(), known_ids.tolist(), strict=True))
    if not legal_all.any(axis=1).all():
        raise ExactUnsupported("a reachable state where no joint action is legal")
    sol = Solution(
        model=model,
        simulator=world,
        bits=bits,
        actions=acts,
        legal=legal_all,
        reward=reward,
        q=[np.zeros((n_states, n_act))],
        v=[np.zeros(n_states)],
        transitions=len(succ),
    )
    sol._index = index
    sol._action_names = [p.name for p in world.action_fluents]
    sol._action_keys = {_action_key(acts, sol._action_names, i): i for i in range(n_act)}
    sol._starts, sol._succ, sol._prob = starts, succ, prob
    gamma = model.discount
    assert model.horizon is not None
    for _ in range(model.horizon):
        q = reward + gamma * sol._expect(sol.v[-1]).reshape(n_states, n_act)
        q = np.where(legal_all, q, -np.inf)
        sol.q.append(q)
        sol.v.append(q.max(axis=1))
    log.info(
        "exact: %s: %d states, %d joint actions, %d transitions",
        model.name,
        n_states,
        n_act,
        len(succ),
    )
    return sol


# ------------------------------------------------------------ the planner


class ExactPlanner(Planner):
    """Plays the optimal policy of a small instance: `solve` at the start of
    the session, then, every turn, the best joint action for the state and
    the steps left (the first of equals). A reference for other planners:
    nothing plays better in expectation."""

    name: ClassVar[str] = "exact"
    options: ClassVar[dict[str, str]] = {
        "max_states": "refuse instances with more reachable states (default 50000)",
        "max_transitions": "refuse instances with more (state, action, successor) triples "
        "(default 20000000; peak memory about 75 bytes each)",
        "memory": "MiB the solution's table may take; an instance whose table would need "
        "more is refused before it is allocated (default: "
        f"{DEFAULT_MEMORY_FRACTION:g} of MemAvailable at the start of the session)",
        "startup": "seconds the solve may take at the start of the session; an instance not "
        f"solved by then is refused (default {DEFAULT_STARTUP:g})",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        max_states = self.int_option("max_states", 50_000, minimum=1)
        max_transitions = self.int_option("max_transitions", 20_000_000, minimum=1)
        assert max_states is not None and max_transitions is not None
        self.max_states, self.max_transitions = max_states, max_transitions
        self.memory_mib = self.float_option("memory", None, minimum=1.0)
        startup = self.float_option("startup", DEFAULT_STARTUP, minimum=0.0)
        assert startup is not None
        self.startup = startup
        self.solution: Solution | None = None
        self._codec: WireCodec | None = None

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        started = time.monotonic()
        memory = memory_budget(self.memory_mib)
        try:
            self.solution = run_within(
                lambda: solve(
                    session.model,
                    max_states=self.max_states,
                    max_transitions=self.max_transitions,
                    memory=memory,
                ),
                self.startup,
                "solving",
            )
        except ExactUnsupported as err:
            raise PlannerError(f"cannot solve {session.instance}: {err}") from None
        except StartupOverrun:
            raise PlannerError(
                f"cannot solve {session.instance}: not solved within the start-up "
                f"allowance of {self.startup:g} s (option startup)"
            ) from None
        self._codec = WireCodec(session.simulator)
        log.info(
            "exact: %s solved in %.1f s: %d states, optimum %.4f",
            session.instance,
            time.monotonic() - started,
            len(self.solution.bits),
            self.solution.initial_value,
        )

    def act(self, obs: Observation) -> list[WireFluent]:
        if self.solution is None or self._codec is None:
            raise PlannerError("exact: act() called before start_session()")
        if obs.state is None:
            raise PlannerError("exact: no state to act on (a POMDP)")
        steps = max(1, min(obs.steps_left, len(self.solution.q) - 1))
        try:
            best = self.solution.best(steps, obs.state)
        except KeyError:
            # the solved model never reaches this state: the server's model differs
            log.warning("exact: turn %d: a state the solution never reached; noop", obs.turn)
            return []
        return self._codec.actions(best, index=0)
