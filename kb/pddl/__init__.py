"""A classical PDDL domain and problem from the knowledge base, by
determinisation, so that a classical planner (Fast Downward, Metric-FF's
kin) can plan for an RDDL domain that has a goal.

Theory of operation. The domain is written from the operators
(`ippc.kb.operators`), the problem from the current state, both in one pass:

* types: the object types with their super-types, and each enum type, whose
  values become constants ("@low" -> `low`);
* predicates: every boolean state fluent and non-fluent; an enum- or
  object-valued fluent `f(args)` becomes `(f args ?value)`, true for its one
  current value; numeric fluents are left out (classical PDDL has none), and
  so are conditions and effects on them (reported in the domain's header);
* an action per operator: its
  positive and negative conditions, its other conditions translated
  (quantifiers, connectives, equality of objects); a condition that reads
  only non-fluents and constants (a comparison of numbers, `BUSY_RATE(?w) >
  0.5`) is decided now, for every grounding of its variables, and becomes a
  static predicate with those facts in the problem;
* effects: add, delete, conditional (`when`) and universal (`forall`)
  effects; an enum assignment deletes the old value and adds the new one;
* probabilistic effects: in mode "most-likely", each draw's most likely
  outcome (the first of the most likely on a tie, as
  `ippc.planners.determinise` decides, so a Bernoulli of 0.5 happens),
  decided for every grounding of the probability's variables on the current
  knowledge, through static predicates where the choice differs between
  groundings; in mode "all-outcomes", one action per combination of outcomes
  of the operator's draws, named `<op>__o<i>_<j>...` (one outcome number per
  draw, from 1), each with that outcome's effects (at most 64 combinations an
  operator; further draws take their most likely outcome);
* the exogenous operator (what the world does by itself) is no action: with
  `exogenous="current"` (the default, the baseline of ROSPlan's experiments)
  the fluents it changes keep their current values (what the robot last
  sensed); with "most-likely" they start at the world's most likely next
  values (somebody is at the printer whose OCCUPATION_RATE is 0.94); with
  "outcomes" each outcome of each of its draws is an action of cost 0 the
  planner may count on (`exogenous__<fluent>__o<i>`, not to be dispatched);
* action costs from the reward, for every ground action at the current
  state s, in one batched simulator step per additive term of the reward
  (`a - b` has the terms a and -b) that reads action fluents: the term's
  value with noop minus its value with the action alone, at least 0 (a
  reward term is no cost; a term whose noop value is below every legal
  action's, the anti-noop penalty, is taken against the best legal action
  instead); summed over the terms, in hundredths (Fast Downward wants
  integers), as `(increase (total-cost) c)`; where the groundings of an
  operator cost differently, one action per cost, `<action>__c<cost>`, each
  for the groundings a static predicate lists (strict parsers take any cost
  function but total-cost for a numeric fluent, which Fast Downward
  refuses); the problem minimises total-cost. Terms that read the state are
  taken at the current state;
* the goal: the knowledge base's goal facts, or its whole formula where the
  facts cannot say it (a choice between alternatives); a domain without a
  goal raises `KBError`.

What cannot be written (a condition on a number that changes, a numeric
effect, an action fluent that is not boolean) is listed in a comment at the
top of the domain text, by operator, and the condition is dropped (the
planner may then plan an action the knowledge base refuses: the dispatcher
checks every action against the RDDL preconditions).
"""

from __future__ import annotations

from .costs import COST_SCALE, MAX_GROUND_ACTIONS, reward_terms
from .normal_form import normal_effect
from .translate import EXOGENOUS_MODES, MODES
from .writer import MAX_VARIANTS, REQUIREMENTS, to_pddl

__all__ = [
    "COST_SCALE",
    "EXOGENOUS_MODES",
    "MAX_GROUND_ACTIONS",
    "MAX_VARIANTS",
    "MODES",
    "REQUIREMENTS",
    "normal_effect",
    "reward_terms",
    "to_pddl",
]
