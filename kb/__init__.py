"""ippc.kb: the knowledge base of the robot side, after ROSPlan's.

::

    from ippc.kb import KnowledgeBase, Update

    kb = KnowledgeBase.from_files("domain.rddl", "instance.rddl")
    kb.apply([Update.add("robot_at", "kenny", "phdarea")], source="sensing")
    kb.get("robot_at", ("kenny", "phdarea"))    # True

See docs/knowledge-base.md for the queries, the JSON-lines protocol and
problem generation.
"""

from __future__ import annotations

from .goal import Goal, GoalFact
from .invariants import Violation
from .knowledge_base import InvariantError, KnowledgeBase, Subscriber
from .operators import (
    EXOGENOUS,
    Atom,
    Effect,
    Operator,
    Outcome,
    Parameter,
    ProbabilisticEffect,
    parameter_names,
)
from .report import Unsupported
from .store import Change, KBError, Update, Value

__all__ = [
    "EXOGENOUS",
    "Atom",
    "Change",
    "Effect",
    "Operator",
    "Outcome",
    "Parameter",
    "ProbabilisticEffect",
    "parameter_names",
    "Goal",
    "GoalFact",
    "InvariantError",
    "KBError",
    "KnowledgeBase",
    "Subscriber",
    "Unsupported",
    "Update",
    "Value",
    "Violation",
]
