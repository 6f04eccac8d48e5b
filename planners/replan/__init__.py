"""Determinise-and-replan: the deterministic baseline planner (`replan`).

In the spirit of FF-Replan and the Metric-FF baseline of ROSPlan's RDDL
paper: plan on a deterministic version of the model, execute the plan, and
plan again when the world does not do what the plan predicted.

Theory of operation.

* Determinisation (`planners/determinise.py`). At the start of a session
  the model is rewritten into its *most-likely* determinisation (every
  random draw replaced by its most likely outcome: ``Bernoulli(p)`` by
  ``p >= 0.5``, ``Discrete`` by its most likely value, ``Normal`` by its
  mean, ...) and a second `Simulator` is compiled from it. With
  ``determinisation=all-outcomes`` the search may also choose the outcome
  of an action, as if the outcome were part of the action (see below).

* Search. From the current state, a best-first search over joint actions
  in the determinised simulator maximises the (discounted) reward over the
  next `depth` steps (the steps left in the round, or `max_depth`). Every
  node is a complete plan: the actions that lead to it, then noop until
  the depth; its value `q` is the reward of that whole plan, exactly (the
  model is deterministic), computed with a noop roll-out of the
  determinised simulator. The search expands the node of highest `q` (ties:
  the shallower, then the older), so it starts from "do nothing" and keeps
  improving on the best plan it knows; the best plan so far is always a
  valid answer, which makes the search anytime: it stops at the turn's
  deadline and returns the best plan found. A state reached again at the
  same depth with no more reward is pruned. Termination (pyRDDLGym's
  `termination`, rddlsim's `terminate-when`) ends a branch: a goal is
  reached there and no reward follows, so in a goal domain (a cost every
  step until the goal) the search looks for the shortest way there.

* Batches. The children of a node (its legal joint actions) are one batched
  simulator step, and `expand` nodes are expanded together in one step;
  the roll-outs of all the children are batched too, and a roll-out row
  stops as soon as noop leaves its state unchanged (a fixed point: the
  model is deterministic and stationary, so the rest is that step's reward
  again), which in most domains happens within a few steps.

* Legal actions only. The children of a node are its state's legal joint
  actions (`ippc.rddl.legal`: max-nondef-actions, action preconditions,
  state-action constraints; bool, enum and int action fluents): all of them
  when there are at most `max_actions`, else noop (when legal) and a
  uniform sample of `max_actions` (the search is then not exhaustive), so
  ChromaticDice's "all five dice at once" is a child like any other. For
  real-valued action spaces, which cannot be enumerated, the candidates are
  enumerated once per session (noop, then every set of 1, 2, ...
  non-default groundings up to max-nondef-actions, each real action at its
  default +- 1, for as long as there are at most `max_actions`), each
  expansion keeps the ones `Simulator.check_actions` finds legal, and when
  the enumeration stops short each expansion adds one random legal joint
  action (`Simulator.random_actions`) per node.

* Replanning. The plan predicts the state of every turn. Each turn the
  observed state is compared with the prediction (exactly for bool, int and
  enum fluents, within 1e-6 relative for reals); a difference is a
  *surprise*: the planner counts a replan (`replans`) and searches from the
  observed state. Otherwise it executes the next step of the plan without
  searching, except that when the last search was cut short by the deadline
  (the plan may not be the best one) it uses the turn's time to search
  again from the current state and keeps the old plan unless it finds a
  better one (`refinements`; option `refine`). A plan that runs out (when
  `max_depth` is below the steps left) is followed by a new search.

* all-outcomes. FF-Replan's all-outcomes determinisation turns every
  outcome of every action into an action of its own, so the planner picks
  the outcome it likes. In a factored RDDL model every grounding of every
  draw is a separate choice, so the outcomes of one joint action are all
  the combinations of them (2^n for n Bernoulli draws): too many to list.
  This planner's all-outcomes mode lets the search pick among the most
  likely outcome and `outcomes` outcomes sampled from the real model, each
  a child of its own; the roll-outs behind them stay most-likely. For a
  reward-maximising search this is optimism: the search follows the
  luckiest outcome it has seen (the computer that reboots by itself, the
  passenger who arrives just when the elevator is there), plans that rely
  on luck look best, and they fail more often, so the planner replans
  more. It is there to compare with; most-likely is the default.

* POMDPs. The planner does not see the state, so it plans from the state
  its own plan predicts (the initial state in the first turn) and never
  notices a surprise: open-loop plans, new ones when a plan runs out.

Counters (attributes, over the planner's life): `searches`, `replans`,
`refinements`, `expansions`, `planning_seconds`; `last_search` is the
`SearchResult` of the last search. The totals of each round and session
are logged at info level.
"""

from __future__ import annotations

from .determinised_search import (
    DEFAULT_EXPAND,
    DEFAULT_MAX_ACTIONS,
    MAX_NODES,
    MAX_STATE_BYTES,
    Actions,
    Array,
    PlanStep,
    SearchProblem,
    SearchResult,
    concat_states,
    continuation,
    joint_actions,
    same_state,
    search,
    state_keys,
    unchanged,
)
from .planner import (
    DEFAULT_DEPTH_NO_HORIZON,
    DEFAULT_OUTCOMES,
    DETERMINISATIONS,
    ReplanPlanner,
)

__all__ = [
    "DEFAULT_DEPTH_NO_HORIZON",
    "DEFAULT_EXPAND",
    "DEFAULT_MAX_ACTIONS",
    "DEFAULT_OUTCOMES",
    "DETERMINISATIONS",
    "MAX_NODES",
    "MAX_STATE_BYTES",
    "Actions",
    "Array",
    "PlanStep",
    "ReplanPlanner",
    "SearchProblem",
    "SearchResult",
    "concat_states",
    "continuation",
    "joint_actions",
    "same_state",
    "search",
    "state_keys",
    "unchanged",
]
