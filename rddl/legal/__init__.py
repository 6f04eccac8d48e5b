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

1. *Grounding* (`ground`, `static`): the constraints become *elements*, small
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

from .search import ActionSpace, LegalActionsUnsupported, NoLegalAction, TooManyActions
from .solver import INT_SPAN, LegalActions, solver_for

__all__ = [
    "INT_SPAN",
    "ActionSpace",
    "LegalActions",
    "LegalActionsUnsupported",
    "NoLegalAction",
    "TooManyActions",
    "solver_for",
]
