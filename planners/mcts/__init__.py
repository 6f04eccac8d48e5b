"""`mcts`: trial-based tree search (THTS, as PROST's).

Two engines (option `engine`). `thts`, the default, searches one trial at
a time on the grounded one-state step of `ippc.rddl.sim.scalar` compiled
to C, with probed equivalent-action pruning, an exact last step, solved
labelling and IDS on the most-likely determinisation: its module `thts` is
its theory of operation, and the search itself is C (csrc/tree.c over
csrc/kernels.c), written once. Where that step cannot be written or built
(`ScalarUnsupported`, a POMDP, no C compiler, `compiled = no`) or
`reward_locks` is on, a session runs `wave`, described below.

Theory of operation of `wave`. Every turn the planner grows a search graph from the
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

Legal joint actions: a new node's candidates are its state's legal joint
actions (`ippc.rddl.legal`: max-nondef-actions, action preconditions,
state-action constraints, for bool, enum and int action fluents), all of
them when there are at most `max_actions`, else noop (when legal) and a
uniform sample of the others; they are cached by the values of the state
fluents the constraints read, so a domain whose constraints read no state
finds them once per session. Real-valued action spaces, which cannot be
enumerated, get rddlsim-style random actions instead
(`Simulator.random_actions`), deduplicated, plus noop when it is legal.
Rollouts draw uniformly from the boolean joint actions enumerated once per
session when there are at most `enumerate_limit` (rejecting the illegal
ones), else from `Simulator.random_actions`, which falls back on a uniform
legal draw where its coin flips find nothing (ChromaticDice's five dice at
once). A node where nothing is legal is a dead end; a root where nothing is
legal sends noop, with a warning.

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

The package, one job per module: `options` (the options and their typed
`Settings`), `stats` (the counters), `tree` (nodes, UCB1, backups, the
final choice), `actions` (the action library, candidates, rollout actions),
`rollouts` (expanding leaves with batched rollouts), `heuristic` (the
wave engine's batched IDS), `locks` (reward locks), `rows` (a batch's row
keys), `ckernels` (the compiled step with the search's C), `thts` (the
single-state engine's Python side), `ctree` (driving its tree in C) and
`planner` (the session, the turn, the roots and
the waves of trials).
"""

from __future__ import annotations

from .actions import (
    ActionChooser,
    ActionLibrary,
    enumerate_boolean,
    pvariables_read,
    state_dependent,
)
from .options import OPTIONS, ROLLOUT_POLICIES, Settings
from .planner import MCTSPlanner
from .rollouts import _horizon_factor
from .stats import SearchStats

__all__ = [
    "OPTIONS",
    "ROLLOUT_POLICIES",
    "ActionChooser",
    "ActionLibrary",
    "MCTSPlanner",
    "SearchStats",
    "Settings",
    "_horizon_factor",
    "enumerate_boolean",
    "pvariables_read",
    "state_dependent",
]
