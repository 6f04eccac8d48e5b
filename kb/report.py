"""What the knowledge base could not put into operator or goal form.

The planner always receives the complete RDDL, so nothing is lost for
planning; but a client that reads operators or goal facts must know what
they leave out. Every such part is recorded here, by name and source line,
and logged once when the knowledge base is built (ROSPlan dropped some of
these silently).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..rddl import ast as A


@dataclass(frozen=True)
class Unsupported:
    """One part of the domain left out of the operator or goal form.

    `where` names the construct ("cpf robot_at", "precondition of
    goto_waypoint", "goal"), `reason` says why, `loc` is its source position.
    """

    where: str
    reason: str
    loc: A.Loc = field(default=A.NOWHERE)

    def __str__(self) -> str:
        return f"{self.loc}: {self.where}: {self.reason}"

    def to_json(self) -> dict[str, Any]:
        return {
            "where": self.where,
            "reason": self.reason,
            "file": self.loc.file,
            "line": self.loc.line,
            "column": self.loc.column,
        }
