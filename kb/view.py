"""What the problem writers read of a knowledge base: `KnowledgeView`.

`kb/rddl_instance.py` and the `kb/pddl/` package write the knowledge base's state as an
RDDL instance or a PDDL problem, and `KnowledgeBase` offers them as its methods
(`to_rddl_instance`, `to_pddl`). So that the writers need not import the class that imports
them, they take this protocol, which `KnowledgeBase` satisfies (mypy checks it where the
methods pass `self`). The underscored members are the knowledge base's internals the
writers read in one pass under its lock.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from typing import Any, Protocol

from ..rddl import ast as A
from ..rddl.model import Model
from ..rddl.simulator import Simulator, State
from .evaluate import Evaluator
from .goal import Goal
from .operators import Operator
from .store import Store


class KnowledgeView(Protocol):
    """The part of `ippc.kb.KnowledgeBase` that the RDDL and PDDL writers use."""

    @property
    def model(self) -> Model: ...

    @property
    def _store(self) -> Store: ...

    @property
    def _lock(self) -> AbstractContextManager[Any]: ...

    @property
    def _evaluator(self) -> Evaluator: ...

    @property
    def horizon(self) -> int | None: ...

    @property
    def discount(self) -> float: ...

    @property
    def max_nondef_actions(self) -> int | None: ...

    def goal(self) -> Goal | None: ...

    def operators(self) -> list[Operator]: ...

    def operator(self, name: str) -> Operator: ...

    def to_state(self) -> State: ...

    def simulator(self) -> Simulator: ...

    def term_simulator(self, term: A.Expr) -> Simulator: ...
