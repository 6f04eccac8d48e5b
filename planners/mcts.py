"""`mcts`: UCT-style trial-based tree search over the batched simulator.

Theory of operation. Every turn the planner grows a search graph from the
current state with the compiled simulator as its model, in the spirit of
PROST's trial-based heuristic tree search (THTS):

* *Decision nodes* hold a state, the number of steps left below it and the
  candidate joint actions that are legal there; each candidate is a *chance
  node* whose children are the sampled successor states (keyed by the bytes
  of the state). With `transpositions` (the default) every path that
  reaches the same state with the same steps left shares one decision node,
  within a turn and across the turns of a round, so small state spaces are
  searched as a graph and the node of the observed state is the next root.
* A *wave* runs many trials side by side. All trials descend from the root
  at once, one level per simulator call: each picks an action with UCB1 (a
  virtual visit per pending trial spreads the trials over the actions), one
  batched `Simulator.step` samples every trial's successor, and a trial
  stops at the first successor that is not expanded yet, at a terminal
  state (no steps left, or `termination`), or after `trial_depth` levels.
* The new leaves are *expanded* in one batch: for every leaf, every legal
  candidate action, and `rollouts` rollouts each, the first step takes that
  action and the rest follow the rollout policy for up to `rollout_depth`
  steps (never past the steps left), all as one batch of states stepped
  together. A rollout cut short by `rollout_depth` counts as its mean
  reward per step times the steps left (`extrapolate`), so that estimates
  at different depths are on one scale. The mean return of each (leaf,
  action) initialises the action's value, as PROST's heuristic initialises
  its Q-values; with the `best` rollout policy each action gets random and
  noop rollouts and the better mean counts.
* Values are backed up as in THTS's MaxMonteCarlo backup: a decision node
  is worth its best action; an action is worth the heuristic estimate
  (weighted as `init_weight` visits) averaged with its sampled successors'
  rewards plus discounted values, weighted by how often each was sampled.
  An action with at most `bellman_outcomes` distinct outcomes reads every
  outcome's value afresh from its node at each backup (a partial Bellman
  backup, as PROST's): with transpositions a node's value also changes
  through other paths. The root's actions are refreshed so before the
  choice.
* The action played is the root's best by value (most visits among equals).

Legal joint actions: boolean action spaces whose joint actions (at most
max-nondef-actions groundings set) number at most `enumerate_limit` are
enumerated once into an *action library*; a node's candidates are the
library entries legal in its state (max-nondef-actions, action
preconditions, state-action constraints, checked in one batched call; once
per session when the constraints read no state fluent), at most
`max_actions` of them (noop first, then a seeded random sample). Other
action spaces (int, enum or real actions, or too many combinations) get
candidates sampled with `Simulator.random_actions` in the node's state,
deduplicated, plus noop when it is legal. Rollouts draw uniformly from the
legal library entries (or use `Simulator.random_actions`).

Time: each turn ends at `Observation.deadline` (the client's uniform split
of the session budget), or `time_per_step` seconds after `act` starts when
that option is set, or after exactly `iterations` waves when that is set
(which makes the search independent of the machine's speed: with a seed,
the same observations then give the same actions). At least one wave runs.
`stats` and `last_turn` count waves, trials, expanded leaves and simulated
state transitions (`steps_per_second`).

POMDPs (no state in the observation): the planner keeps a particle belief,
`particles` copies of the initial state stepped with its own actions and,
when the observation fluents are discrete, kept only where their simulated
observation matches the one received (all of them when none does). The
root holds the particles, each trial starts from one of them, and the tree
below the root is searched as if the state were then known (a QMDP-like
approximation).
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..rddl import ast as A
from ..rddl.model import ACTION, NON_FLUENT, Model
from ..rddl.simulator import SimulationError, Simulator, State
from ..rddl.wire import WireCodec, WireError
from .base import Observation, Planner, PlannerError, SessionInfo, WireFluent

log = logging.getLogger(__name__)

Array = np.ndarray

ROLLOUT_POLICIES = ("random", "noop", "best")


# ------------------------------------------------------------ statistics


@dataclass
class SearchStats:
    """Counters of the search, readable while a session runs (the bench
    reads `steps_per_second`)."""

    turns: int = 0
    waves: int = 0
    trials: int = 0
    leaves: int = 0  # decision nodes expanded
    reused: int = 0  # turns whose root came from the last turn's tree
    sim_steps: int = 0  # state transitions simulated (every row of every batched step)
    sim_calls: int = 0  # batched simulator calls
    seconds: float = 0.0  # time spent searching

    @property
    def steps_per_second(self) -> float:
        """Simulated state transitions per second of search."""
        return self.sim_steps / self.seconds if self.seconds > 0 else 0.0

    def add(self, other: SearchStats) -> None:
        """Add another set of counters to these."""
        self.turns += other.turns
        self.waves += other.waves
        self.trials += other.trials
        self.leaves += other.leaves
        self.reused += other.reused
        self.sim_steps += other.sim_steps
        self.sim_calls += other.sim_calls
        self.seconds += other.seconds


# ------------------------------------------------------- action library


class ActionLibrary:
    """Every joint action the search has considered, as rows of one array
    per action fluent, so that the actions of a whole batch are one fancy
    index (`take`). Rows are unique; row 0 is noop."""

    def __init__(self, sim: Simulator):
        self.sim = sim
        self.names = [p.name for p in sim.action_fluents]
        noop = sim.noop(1)
        self.arrays: dict[str, Array] = {k: np.repeat(v, 16, axis=0) for k, v in noop.items()}
        self.size = 0
        self._index: dict[bytes, int] = {}
        self.add(noop)

    def _keys(self, actions: dict[str, Array], n: int) -> list[bytes]:
        return _row_keys([actions[k] for k in self.names], n)

    def add(self, actions: dict[str, Array]) -> Array:
        """The library rows of a batch of joint actions, adding new ones."""
        n = _batch_of(actions, self.names)
        keys = self._keys(actions, n)
        out = np.empty(n, dtype=np.int64)
        new: list[int] = []
        for i, key in enumerate(keys):
            row = self._index.get(key)
            if row is None:
                row = self._index[key] = self.size + len(new)
                new.append(i)
            out[i] = row
        if new:
            need = self.size + len(new)
            cap = next(iter(self.arrays.values())).shape[0] if self.arrays else need
            if need > cap:
                cap = max(need, 2 * cap)
                for k, v in self.arrays.items():
                    grown = np.empty((cap, *v.shape[1:]), dtype=v.dtype)
                    grown[: self.size] = v[: self.size]
                    self.arrays[k] = grown
            sel = np.asarray(new)
            for k in self.names:
                self.arrays[k][self.size : need] = actions[k][sel]
            self.size = need
        return out

    def take(self, rows: Array) -> dict[str, Array]:
        """The joint actions at these library rows, as a batch."""
        return {k: v[rows] for k, v in self.arrays.items()}


def _batch_of(actions: dict[str, Array], names: list[str]) -> int:
    for k in names:
        return int(actions[k].shape[0])
    return 1


def _row_keys(arrays: list[Array], n: int) -> list[bytes]:
    """One bytes key per batch row of these arrays (their raw contents)."""
    if not arrays:
        return [b""] * n
    parts = [np.ascontiguousarray(a).reshape(n, -1).view(np.uint8) for a in arrays]
    packed = np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
    width = packed.shape[1]
    blob = np.ascontiguousarray(packed).tobytes()
    return [blob[i * width : (i + 1) * width] for i in range(n)]


def enumerate_boolean(sim: Simulator, limit: int) -> dict[str, Array] | None:
    """Every joint action of a boolean action space with at most
    max-nondef-actions groundings set (noop first), regardless of the
    preconditions; None when an action is not boolean or there are more
    than `limit`."""
    noop1 = sim.noop(1)
    grounds: list[tuple[str, tuple[int, ...]]] = []
    for p in sim.action_fluents:
        if p.range != "bool":
            return None
        shape = noop1[p.name].shape[1:]
        grounds.extend((p.name, idx) for idx in np.ndindex(*shape))
    limit_nondef = sim.model.max_nondef_actions
    k_max = len(grounds) if limit_nondef is None else min(limit_nondef, len(grounds))
    count = sum(math.comb(len(grounds), k) for k in range(k_max + 1))
    if count > limit:
        return None
    actions = sim.noop(count)
    row = 0
    for k in range(k_max + 1):
        for combo in itertools.combinations(range(len(grounds)), k):
            for g in combo:
                name, idx = grounds[g]
                actions[name][(row, *idx)] = not noop1[name][(0, *idx)]
            row += 1
    return actions


def pvariables_read(expr: A.Expr) -> set[str]:
    """The names of every pvariable an expression reads."""
    out: set[str] = set()
    todo = [expr]
    while todo:
        e = todo.pop()
        if isinstance(e, A.PVar):
            out.add(e.name)
        todo.extend(A.children(e))
    return out


def state_dependent(model: Model, constraints: Iterable[A.Expr]) -> bool:
    """Whether any of these constraints reads something other than actions
    and non-fluents (a state, interm or observ fluent)."""
    for expr in constraints:
        for name in pvariables_read(expr):
            p = model.pvariables.get(name)
            if p is None or p.kind not in (ACTION, NON_FLUENT):
                return True
    return False


# ----------------------------------------------------------------- tree


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
        # Per candidate action, as Python lists: with a handful of actions,
        # the scalar updates and the UCB1 loop are faster than numpy calls.
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


_EMPTY_INT = np.zeros(0, dtype=np.int64)


def _bellman_total(outcomes: dict[bytes, _Outcome], gamma: float) -> float:
    """An action's `tot` from its outcomes' current node values (each
    outcome's kept value refreshed on the way): the sum of the rewards seen
    plus discount x times sampled x value."""
    tot = 0.0
    for o in outcomes.values():
        o.value = o.node.value
        tot += o.rsum + gamma * o.count * o.value
    return tot


@dataclass
class _Trial:
    path: list[tuple[_Node, int, _Outcome, float]]
    node: _Node  # where it is now
    row: int  # the root particle it started from


# -------------------------------------------------------------- planner


class MCTSPlanner(Planner):
    """UCT over the batched simulator (see the module docstring)."""

    name: ClassVar[str] = "mcts"
    options: ClassVar[dict[str, str]] = {
        "time_per_step": "seconds of search per turn (default: the client's deadline, the "
        "session's remaining time spread over its remaining steps)",
        "iterations": "search exactly this many waves per turn, whatever the time (for "
        "reproducible runs; default: search until the deadline)",
        "exploration": "UCB1 exploration constant, scaled by the node's largest |Q| (default 2)",
        "rollout_depth": "steps of a leaf rollout (default 10; 0: to the lookahead limit)",
        "depth": "lookahead limit of the search in steps (default 0: the steps left in the "
        "round); the tree and the rollouts never look further",
        "batch": "rows of a leaf-evaluation batch: trials per wave are chosen so that their "
        "leaves' candidates x rollouts fill about this many (default 1024)",
        "rollouts": "rollouts per candidate action of a new leaf (default 1)",
        "extrapolate": "a rollout cut short by rollout_depth counts as its mean reward per "
        "step over all the steps left (default yes; else as the rewards it saw)",
        "trial_depth": "most decision levels a trial descends through nodes already in the "
        "tree before it backs up the value of the node it reached (default 10; 0: no limit)",
        "rollout_policy": "policy after a leaf's first action: random (uniform legal joint "
        "actions), noop, or best (both; the better mean counts) (default best)",
        "init_weight": "visits the rollout estimate of a new action counts as (default 1)",
        "max_actions": "most candidate joint actions per decision node; noop and a seeded "
        "sample of the others when more are legal (default 128)",
        "enumerate_limit": "enumerate boolean joint actions when there are at most this "
        "many, else sample them (default 4096)",
        "particles": "belief particles for POMDPs (default 64)",
        "transpositions": "share one node between all paths that reach the same state with "
        "the same steps left, within a turn and across the turns of a round (default yes)",
        "bellman_outcomes": "back up an action from the current values of all its sampled "
        "outcomes when it has at most this many (a partial Bellman backup), else from the one "
        "sampled (default 64; 0: never)",
        "max_nodes": "forget the tree (but the root) when it holds more decision nodes than "
        "this (default 200000)",
        "seed": "integer seed (default: the client's --seed, else unseeded)",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self.time_per_step = self.float_option("time_per_step", None, minimum=0.0)
        self.iterations = self.int_option("iterations", None, minimum=1)
        self.exploration = self._float("exploration", 2.0)
        self.rollout_depth = self._int("rollout_depth", 10, 0)
        self.depth = self._int("depth", 0, 0)
        self.batch = self._int("batch", 1024, 1)
        self.rollouts = self._int("rollouts", 1, 1)
        self.trial_depth = self._int("trial_depth", 10, 0)
        self.extrapolate = self.bool_option("extrapolate", True)
        policy = self.str_option("rollout_policy", "best")
        assert policy is not None
        policy = policy.strip().lower()
        if policy not in ROLLOUT_POLICIES:
            raise self._option_error(
                "rollout_policy", policy, "one of " + ", ".join(ROLLOUT_POLICIES)
            )
        self.rollout_policy = policy
        self.init_weight = self._float("init_weight", 1.0, minimum=1e-9)
        self.max_actions = self._int("max_actions", 128, 1)
        self.enumerate_limit = self._int("enumerate_limit", 4096, 1)
        self.particles = self._int("particles", 64, 1)
        self.transpositions = self.bool_option("transpositions", True)
        self.max_nodes = self._int("max_nodes", 200_000, 1)
        self.bellman_outcomes = self._int("bellman_outcomes", 64, 0)
        self.seed: int | None = self.int_option("seed")

        self.stats = SearchStats()
        """Counters over the whole session."""
        self.last_turn = SearchStats()
        """Counters of the last turn."""
        self.rng = np.random.default_rng(self.seed)
        self._sim: Simulator | None = None
        self._model: Model | None = None
        self._codec: WireCodec | None = None
        self._lib: ActionLibrary | None = None
        self._enumerated: Array | None = None  # library rows of the enumerated joint actions
        self._state_names: list[str] = []
        self._constrained = False
        self._root: _Node | None = None
        self._last: tuple[_Node, int] | None = None  # (root, chosen candidate) of the last turn
        # decision nodes by steps left and state, when `transpositions`
        self._table: dict[int, dict[bytes, _Node]] = {}
        self._belief: State | None = None  # POMDP particles
        self._last_action: dict[str, Array] | None = None
        self._discrete_obs = True

    def _int(self, key: str, default: int, minimum: int) -> int:
        value = self.int_option(key, default, minimum=minimum)
        assert value is not None
        return value

    def _float(self, key: str, default: float, minimum: float = 0.0) -> float:
        value = self.float_option(key, default, minimum=minimum)
        assert value is not None
        return value

    # -- session ------------------------------------------------------

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        seed = self.seed if self.seed is not None else session.seed
        self.rng = np.random.default_rng(seed)
        sim = self._sim = session.simulator
        self._model = session.model
        self._codec = WireCodec(sim)
        self._lib = ActionLibrary(sim)
        self._state_names = [p.name for p in sim.state_fluents]
        dom = session.model.domain
        constraints = [*dom.action_preconditions, *dom.state_action_constraints]
        self._constrained = bool(constraints)
        enumerated = enumerate_boolean(sim, self.enumerate_limit)
        self._enumerated = None if enumerated is None else self._lib.add(enumerated)
        if (
            self._enumerated is not None
            and self._constrained
            and not state_dependent(session.model, constraints)
        ):
            # Constraints that read only actions and non-fluents (GameOfLife's,
            # Elevators') hold or fail alike in every state: filter the joint
            # actions once instead of in every node and rollout step.
            n = len(self._enumerated)
            ok = sim.check_actions(sim.initial_state(n), self._lib.take(self._enumerated))
            self._enumerated = self._enumerated[ok]
            self._constrained = False
        self._discrete_obs = all(p.range != "real" for p in sim.observ_fluents)
        self.stats = SearchStats()
        log.info(
            "mcts: %s, %s joint actions%s, seed %s",
            session.instance,
            len(self._enumerated) if self._enumerated is not None else "sampled",
            " (constrained)" if self._constrained else "",
            seed,
        )

    def start_round(self, round_num: int) -> None:
        self._table = {}
        self._root = None
        self._last = None
        self._belief = None
        self._last_action = None

    def end_round(self, reward: float) -> None:
        log.info(
            "mcts: round reward %s; %d turns so far, %.0f simulated steps/s",
            reward,
            self.stats.turns,
            self.stats.steps_per_second,
        )

    def end_session(self, total_reward: float) -> None:
        s = self.stats
        log.info(
            "mcts: session reward %s; %d turns, %d waves, %d trials, %d leaves, %d simulated "
            "steps in %.1f s (%.0f steps/s)",
            total_reward,
            s.turns,
            s.waves,
            s.trials,
            s.leaves,
            s.sim_steps,
            s.seconds,
            s.steps_per_second,
        )

    # -- a turn --------------------------------------------------------

    def act(self, obs: Observation) -> list[WireFluent]:
        if self._sim is None or self._lib is None or self._codec is None or self.session is None:
            raise PlannerError("mcts: act() called before start_session()")
        started = time.monotonic()
        if self.time_per_step is not None:
            deadline = started + self.time_per_step
        else:
            deadline = obs.deadline
        turn = SearchStats(turns=1)
        lookahead = obs.steps_left if self.depth == 0 else min(self.depth, obs.steps_left)
        root, reused = self._make_root(obs, lookahead)
        turn.reused = int(reused)
        try:
            if not root.expanded:
                self._expand([root], turn)
            if len(root.acts) > 1:
                self._search(root, deadline, turn)
                self._refresh(root, self._discount())
        except SimulationError as err:
            # A model the search cannot simulate (e.g. a distribution given bad
            # parameters by some action) must not end the session: act on what
            # is known.
            log.warning("mcts: search stopped at turn %d: %s", obs.turn, err)
        choice = self._best(root)
        row = int(root.acts[choice]) if len(root.acts) else 0
        actions = self._lib.take(np.array([row]))
        self._last = (root, choice) if len(root.acts) else None
        self._last_action = actions
        self._root = root
        turn.seconds = time.monotonic() - started
        self.last_turn = turn
        self.stats.add(turn)
        if log.isEnabledFor(logging.DEBUG):
            q = root.qv
            log.debug(
                "mcts: turn %d (%d steps left): %d waves, %d trials, %d steps in %.3f s "
                "(%.0f steps/s); value %.3f; chose %s",
                obs.turn,
                obs.steps_left,
                turn.waves,
                turn.trials,
                turn.sim_steps,
                turn.seconds,
                turn.steps_per_second,
                float(q[choice]) if len(q) else 0.0,
                ", ".join(self._sim.actions_to_names(actions)) or "noop",
            )
        return self._codec.actions(actions, index=0)

    def _best(self, root: _Node) -> int:
        """The candidate with the highest value (most visits among equals)."""
        if len(root.acts) == 0:
            return 0
        top = max(root.qv)
        slack = 1e-9 * max(1.0, abs(top))
        best = [i for i, q in enumerate(root.qv) if q >= top - slack]
        return max(best, key=lambda i: root.cnt[i])

    # -- roots -----------------------------------------------------------

    def _make_root(self, obs: Observation, lookahead: int) -> tuple[_Node, bool]:
        """The root of this turn's search and whether it is reused: the
        subtree when the tree has the observed successor of the last turn's
        choice (with the same steps left), else a new node."""
        assert self._sim is not None
        if obs.state is None:
            states = self._believe(obs)
            return _Node(None, states, lookahead, False), False
        key = self._state_keys(obs.state)[0]
        if self.transpositions:
            # nodes further from the end than the root are out of reach
            for steps in [k for k in self._table if k > lookahead]:
                del self._table[steps]
            if sum(len(bucket) for bucket in self._table.values()) > self.max_nodes:
                self._table = {}
            bucket = self._table.setdefault(lookahead, {})
            node = bucket.get(key)
            if node is not None and not node.terminal:
                node.states = obs.state
                return node, node.expanded
            node = bucket[key] = _Node(key, obs.state, lookahead, False)
            return node, False
        if self._last is not None:
            node, choice = self._last
            outcome = node.children[choice].get(key) if node.children else None
            if (
                outcome is not None
                and outcome.node.steps == lookahead
                and not outcome.node.terminal
            ):
                child = outcome.node
                child.states = obs.state
                return child, True
        return _Node(key, obs.state, lookahead, False), False

    def _believe(self, obs: Observation) -> State:
        """The POMDP particles for this turn (see the module docstring)."""
        assert self._sim is not None and self._codec is not None
        sim = self._sim
        if obs.turn <= 1 or self._belief is None or self._last_action is None:
            self._belief = sim.initial_state(self.particles)
            return self._belief
        n = self._belief.batch
        acts = {k: np.repeat(v, n, axis=0) for k, v in self._last_action.items()}
        try:
            out = sim.step(self._belief, acts, self.rng, check=False)
        except SimulationError as err:
            log.warning("mcts: belief update failed (%s); back to the initial state", err)
            self._belief = sim.initial_state(self.particles)
            return self._belief
        nxt = out.next_state
        if obs.fluents is not None and out.observation is not None and self._discrete_obs:
            try:
                seen = self._codec.observation_from(
                    (n_, a, v) for (n_, a), v in obs.fluents.items()
                )
            except WireError as err:
                log.warning("mcts: cannot read the observation: %s", err)
                seen = None
            if seen is not None:
                match = np.ones(n, dtype=bool)
                for name, arr in seen.items():
                    sim_obs = out.observation[name].reshape(n, -1)
                    match &= (sim_obs == arr.reshape(1, -1)).all(axis=1)
                if match.any():
                    keep = np.flatnonzero(match)
                    nxt = nxt[self.rng.choice(keep, self.particles)]
                else:
                    log.debug("mcts: no particle explains the observation; keeping them all")
        self._belief = nxt
        return nxt

    # -- search ----------------------------------------------------------

    def _state_keys(self, states: State) -> list[bytes]:
        return _row_keys([states.values[k] for k in self._state_names], states.batch)

    def _search(self, root: _Node, deadline: float, turn: SearchStats) -> None:
        """Waves of trials until the deadline (or `iterations` waves)."""
        n_acts = max(1, len(root.acts))
        trials = max(
            1, self.batch // (n_acts * self.rollouts * (2 if self.rollout_policy == "best" else 1))
        )
        wave_time = 0.0
        waves = 0
        while True:
            if self.iterations is not None:
                if waves >= self.iterations:
                    break
            elif waves > 0 and time.monotonic() + wave_time > deadline:
                break
            t0 = time.monotonic()
            self._wave(root, trials, turn)
            waves += 1
            # the slower of the last wave and a decaying average: stop early
            # rather than late
            took = time.monotonic() - t0
            wave_time = max(took, 0.7 * wave_time + 0.3 * took)
        turn.waves += waves

    def _select(self, node: _Node) -> int:
        """UCB1 with the node's largest |Q| as the scale of exploration;
        the wave's pending trials count as visits."""
        qv = node.qv
        pending = node.pending
        if len(qv) == 1:
            pending[0] += 1
            return 0
        w = self.init_weight
        cnt = node.cnt
        scale = max(abs(max(qv)), abs(min(qv))) or 1.0
        coef = self.exploration * scale * math.sqrt(math.log(node.nsum + sum(pending)))
        a = 0
        best = -math.inf
        for i, q in enumerate(qv):
            u = q + coef / math.sqrt(w + cnt[i] + pending[i])
            if u > best:
                best = u
                a = i
        pending[a] += 1
        return a

    def _wave(self, root: _Node, n_trials: int, turn: SearchStats) -> None:
        """Descend `n_trials` trials together, expand their new leaves in one
        batch and back the values up."""
        assert self._sim is not None and self._lib is not None and root.states is not None
        sim = self._sim
        rows = (
            self.rng.integers(0, root.states.batch, n_trials)
            if root.states.batch > 1
            else np.zeros(n_trials, dtype=np.int64)
        )
        states = root.states[rows]
        trials = [_Trial([], root, int(r)) for r in rows]
        active = list(range(n_trials))
        touched: list[_Node] = []
        leaves: dict[int, _Node] = {}
        level = 0
        while active:
            level += 1
            choices = []
            acts = np.empty(len(active), dtype=np.int64)
            for j, i in enumerate(active):
                node = trials[i].node
                if not any(node.pending):
                    touched.append(node)
                a = self._select(node)
                choices.append(a)
                acts[j] = node.acts[a]
            out = sim.step(states, self._lib.take(acts), self.rng, check=False)
            turn.sim_steps += len(active)
            turn.sim_calls += 1
            keys = self._state_keys(out.next_state)
            reward = out.reward.tolist()
            done = out.done.tolist()
            going: list[int] = []
            going_rows: list[int] = []
            for j, i in enumerate(active):
                trial = trials[i]
                node = trial.node
                a = choices[j]
                outcomes = node.children[a]
                outcome = outcomes.get(keys[j])
                if outcome is None:
                    outcome = outcomes[keys[j]] = _Outcome(
                        self._node(keys[j], out.next_state, j, node.steps - 1, bool(done[j]))
                    )
                trial.path.append((node, a, outcome, float(reward[j])))
                child = outcome.node
                trial.node = child
                if child.terminal:
                    continue
                if not child.expanded:
                    leaves[id(child)] = child
                    continue
                if level == self.trial_depth:
                    continue  # backs up the value the node has
                going.append(i)
                going_rows.append(j)
            active = going
            if going:
                states = out.next_state[np.asarray(going_rows)]
        for node in touched:
            node.pending = [0] * len(node.pending)
        if leaves:
            self._expand(list(leaves.values()), turn)
        gamma = self._discount()
        for trial in trials:
            self._backup(trial, gamma)
        turn.trials += n_trials

    def _node(self, key: bytes, states: State, row: int, steps: int, done: bool) -> _Node:
        """The decision node of a sampled successor: the one the table has
        for this state and steps left, else a new one."""
        if not self.transpositions:
            return _Node(key, states[row], steps, done)
        bucket = self._table.get(steps)
        if bucket is None:
            bucket = self._table[steps] = {}
        node = bucket.get(key)
        if node is None:
            node = bucket[key] = _Node(key, states[row], steps, done)
        return node

    def _discount(self) -> float:
        assert self._model is not None
        d = self._model.discount
        return 1.0 if d is None else float(d)

    def _backup(self, trial: _Trial, gamma: float) -> None:
        """MaxMonteCarlo backup along the trial's path.

        `tot[a]` is the sum over a's sampled outcomes of (rewards seen +
        discount x times sampled x the outcome node's value). With at most
        `bellman_outcomes` distinct outcomes, every outcome's value is read
        afresh from its node (a partial Bellman backup, as PROST's): with
        transpositions a node's value also changes through other paths, and
        a stale copy would keep an action that leads there looking as bad
        as it first did. With more outcomes only the one sampled is
        refreshed, to keep a backup cheap."""
        w = self.init_weight
        limit = self.bellman_outcomes
        value = trial.node.value if trial.node.expanded else 0.0
        for node, a, outcome, reward in reversed(trial.path):
            outcome.count += 1
            outcome.rsum += reward
            outcomes = node.children[a]
            if len(outcomes) <= limit:
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

    def _refresh(self, node: _Node, gamma: float) -> None:
        """Every action's value of `node` from its outcomes' current values
        (before the root's choice: some were last backed up long ago)."""
        w = self.init_weight
        for a, outcomes in enumerate(node.children):
            if not outcomes or len(outcomes) > self.bellman_outcomes:
                continue
            tot = node.tot[a] = _bellman_total(outcomes, gamma)
            node.qv[a] = (w * node.h[a] + tot) / (w + node.cnt[a])
        if node.qv:
            node.value = max(node.qv)

    # -- expansion: candidates and rollouts --------------------------------

    def _candidates(self, leaves: list[_Node]) -> list[Array]:
        """Each leaf's legal candidate joint actions (library rows)."""
        assert self._sim is not None and self._lib is not None
        sim = self._sim
        out: list[Array] = []
        if self._enumerated is not None:
            lib_rows = self._enumerated
            if not self._constrained:
                legal = [lib_rows] * len(leaves)
            else:
                # every (leaf, joint action) pair in one batched check
                n = len(lib_rows)
                states = _stack_states([leaf.states for leaf in leaves], self._state_names)
                many = states[np.repeat(np.arange(len(leaves)), n)]
                acts = self._lib.take(np.tile(lib_rows, len(leaves)))
                ok = sim.check_actions(many, acts).reshape(len(leaves), n)
                legal = [lib_rows[ok[i]] for i in range(len(leaves))]
            for rows in legal:
                out.append(self._trim(rows))
            return out
        # sampled candidates: rddlsim's random concurrent policy in each leaf
        per_leaf = max(2 * self.max_actions, 16)
        states = _stack_states([leaf.states for leaf in leaves], self._state_names)
        many = states[np.repeat(np.arange(len(leaves)), per_leaf)]
        drawn = self._lib.add(sim.random_actions(many, self.rng)).reshape(len(leaves), per_leaf)
        noop_ok = sim.check_actions(states, sim.noop(len(leaves)))
        for i in range(len(leaves)):
            rows = np.unique(drawn[i])
            if noop_ok[i] and rows[0] != 0:
                rows = np.concatenate([[0], rows])
            out.append(self._trim(rows))
        return out

    def _trim(self, rows: Array) -> Array:
        """At most `max_actions` candidates: noop (row 0) if there, then a
        seeded sample of the rest."""
        if len(rows) <= self.max_actions:
            return rows
        has_noop = rows[0] == 0
        rest = rows[1:] if has_noop else rows
        keep = self.max_actions - (1 if has_noop else 0)
        picked = np.sort(self.rng.choice(rest, keep, replace=False))
        return np.concatenate([rows[:1], picked]) if has_noop else picked

    def _expand(self, leaves: list[_Node], turn: SearchStats) -> None:
        """Give every leaf its candidates and their rollout estimates, all
        leaves' rollouts in one batch."""
        assert self._sim is not None and self._lib is not None
        cands = self._candidates(leaves)
        gamma = self._discount()
        m = self.rollouts
        modes = 2 if self.rollout_policy == "best" else 1
        # rows: for each leaf, each candidate, each mode, m rollouts
        leaf_of: list[Array] = []
        first: list[Array] = []
        depth: list[Array] = []
        steps: list[Array] = []
        start: list[Array] = []
        for i, (leaf, rows) in enumerate(zip(leaves, cands, strict=True)):
            k = len(rows) * modes * m
            if k == 0:
                continue
            assert leaf.states is not None
            leaf_of.append(np.full(k, i))
            first.append(np.repeat(rows, modes * m))
            d = leaf.steps if self.rollout_depth == 0 else min(self.rollout_depth, leaf.steps)
            depth.append(np.full(k, d))
            steps.append(np.full(k, leaf.steps))
            p = leaf.states.batch
            start.append(self.rng.integers(0, p, k) if p > 1 else np.zeros(k, dtype=np.int64))
        returns = np.zeros(0)
        if first:
            d_all = np.concatenate(depth)
            returns, ended = self._rollouts(
                leaves,
                np.concatenate(leaf_of),
                np.concatenate(start),
                np.concatenate(first),
                d_all,
                modes,
                gamma,
                turn,
            )
            if self.extrapolate and self.rollout_depth:
                # rollouts that reached a terminal state have their whole return
                factor = _horizon_factor(np.concatenate(steps), d_all, gamma)
                returns *= np.where(ended, 1.0, factor)
        offset = 0
        for leaf, rows in zip(leaves, cands, strict=True):
            a = len(rows)
            leaf.acts = rows
            leaf.cnt = [0.0] * a
            leaf.tot = [0.0] * a
            leaf.pending = [0] * a
            leaf.nsum = self.init_weight * a
            leaf.children = [{} for _ in range(a)]
            if a:
                block = returns[offset : offset + a * modes * m].reshape(a, modes, m).mean(axis=2)
                leaf.h = block.max(axis=1).tolist()
                leaf.qv = list(leaf.h)
                offset += a * modes * m
                leaf.value = max(leaf.h)
            else:
                # nothing is legal here (not even noop): a dead end
                leaf.h = []
                leaf.qv = []
                leaf.terminal = True
                leaf.value = 0.0
            leaf.expanded = True
        turn.leaves += len(leaves)

    def _rollouts(
        self,
        leaves: list[_Node],
        leaf_of: Array,
        start: Array,
        first: Array,
        depth: Array,
        modes: int,
        gamma: float,
        turn: SearchStats,
    ) -> tuple[Array, Array]:
        """Discounted returns of the rollouts (the first action given, then
        the rollout policy: noop for the rows of mode 1 when `modes` is 2,
        else `rollout_policy`) and which of them reached a terminal state."""
        assert self._sim is not None and self._lib is not None
        sim = self._sim
        n = len(first)
        per_leaf = [leaf.states for leaf in leaves]
        if all(s is not None and s.batch == 1 for s in per_leaf):
            states = _stack_states(per_leaf, self._state_names)[leaf_of]
        else:
            states = _gather_rows(per_leaf, leaf_of, start, self._state_names)
        m = self.rollouts
        if modes == 2:
            use_noop = (np.arange(n) // m) % 2 == 1
        elif self.rollout_policy == "noop":
            use_noop = np.ones(n, dtype=bool)
        else:
            use_noop = np.zeros(n, dtype=bool)
        returns = np.zeros(n)
        ended = np.zeros(n, dtype=bool)
        idx = np.arange(n)  # rows still rolling out, as rows of `returns`
        acts = self._lib.take(first)
        discount = 1.0
        t = 0
        while True:
            out = sim.step(states, acts, self.rng, check=False)
            turn.sim_steps += len(idx)
            turn.sim_calls += 1
            returns[idx] += discount * out.reward
            discount *= gamma
            t += 1
            ended[idx] = out.done
            alive = (~out.done) & (depth[idx] > t)
            if not alive.any():
                break
            if not alive.all():
                keep = np.flatnonzero(alive)
                idx = idx[keep]
                states = out.next_state[keep]
            else:
                states = out.next_state
            acts = self._policy(states, use_noop[idx])
        return returns, ended

    def _policy(self, states: State, use_noop: Array) -> dict[str, Array]:
        """The rollout policy's joint actions for a batch of states."""
        assert self._sim is not None and self._lib is not None
        sim = self._sim
        n = states.batch
        if use_noop.all():
            acts = sim.noop(n)
            if self._constrained:
                bad = ~sim.check_actions(states, acts)
                if bad.any():
                    acts = self._fix(states, acts, bad)
            return acts
        if self._enumerated is None:
            acts = sim.random_actions(states, self.rng)
        else:
            pool = self._enumerated
            rows = pool[self.rng.integers(0, len(pool), n)]
            acts = self._lib.take(rows)
            if self._constrained:
                bad = ~sim.check_actions(states, acts)
                for _ in range(4):
                    if not bad.any():
                        break
                    which = np.flatnonzero(bad)
                    redo = pool[self.rng.integers(0, len(pool), len(which))]
                    rows[which] = redo
                    sub = self._lib.take(redo)
                    ok = sim.check_actions(states[which], sub)
                    for k, v in sub.items():
                        acts[k][which[ok]] = v[ok]
                    bad[which[ok]] = False
                if bad.any():
                    noop = sim.noop(n)
                    for k, v in noop.items():
                        acts[k][bad] = v[bad]
                    still = bad & ~sim.check_actions(states, acts)
                    if still.any():
                        acts = self._fix(states, acts, still)
        if use_noop.any():
            noop = sim.noop(1)
            for k, v in noop.items():
                acts[k][use_noop] = v[0]
            if self._constrained:
                bad = use_noop & ~sim.check_actions(states, acts)
                if bad.any():
                    acts = self._fix(states, acts, bad)
        return acts

    def _fix(self, states: State, acts: dict[str, Array], bad: Array) -> dict[str, Array]:
        """rddlsim's random concurrent policy where the chosen actions are illegal."""
        assert self._sim is not None
        which = np.flatnonzero(bad)
        sub = self._sim.random_actions(states[which], self.rng)
        for k, v in sub.items():
            acts[k][which] = v
        return acts


def _horizon_factor(steps: Array, depth: Array, gamma: float) -> Array:
    """How much a return over `depth` steps is scaled to stand for `steps`
    steps at the same (discounted) mean reward per step."""
    if gamma >= 1.0:
        return steps / depth  # type: ignore[no-any-return]
    return (1.0 - gamma**steps) / (1.0 - gamma**depth)  # type: ignore[no-any-return]


def _stack_states(states: Iterable[State | None], names: list[str]) -> State:
    """One batch of the first state of each (batch-1) state."""
    listed = [s for s in states if s is not None]
    return State({k: np.concatenate([s.values[k][:1] for s in listed], axis=0) for k in names})


def _gather_rows(
    per_leaf: list[State | None], leaf_of: Array, start: Array, names: list[str]
) -> State:
    """Row `start[i]` of the states of leaf `leaf_of[i]`, for every i."""
    sizes = [0 if s is None else s.batch for s in per_leaf]
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    listed = [s for s in per_leaf if s is not None]
    flat = {k: np.concatenate([s.values[k] for s in listed], axis=0) for k in names}
    return State({k: v[offsets[leaf_of] + start] for k, v in flat.items()})
