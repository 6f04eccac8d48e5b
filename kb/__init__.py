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
from .knowledge_base import KnowledgeBase, Subscriber
from .report import Unsupported
from .store import Change, KBError, Update, Value

__all__ = [
    "Change",
    "Goal",
    "GoalFact",
    "KBError",
    "KnowledgeBase",
    "Subscriber",
    "Unsupported",
    "Update",
    "Value",
]
