"""`SimulatorParts`: what the step builders and the action choosers read of a `Simulator`.

`simulator.py` imports `build` and `actions` and passes them itself; so that they need not
import `simulator.py` back, they take this protocol, which `Simulator` satisfies (mypy
checks it where the simulator passes `self`). It extends what the legal-action solver
uses (`ippc.rddl.legal.solver.SimulatorView`) with the simulator's internals: its
compiler, the constraints and cpfs in order, and the `_fail_*` methods the generated code
calls.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Protocol

from .. import ast as A
from ..legal.solver import SimulatorView
from ..model import PVariable, Value
from .code import _Node
from .compiler import _Compiler
from .state import Array


class SimulatorParts(SimulatorView, Protocol):
    """The part of a `Simulator` that `build` and `actions` read."""

    @property
    def observ_fluents(self) -> list[PVariable]: ...

    @property
    def _compiler(self) -> _Compiler: ...

    @property
    def _nf_nodes(self) -> Mapping[str, tuple[_Node, None]]: ...

    @property
    def _defaults(self) -> Mapping[str, Array]: ...

    @property
    def _cpf_order(self) -> list[str]: ...

    @property
    def _preconditions(self) -> list[A.Expr]: ...

    @property
    def _invariants(self) -> list[A.Expr]: ...

    @property
    def _terminations(self) -> list[A.Expr]: ...

    def _dtype(self, p: PVariable) -> Any: ...

    def _encode(self, p: PVariable, value: Value) -> Any: ...

    def _ground(self, p: PVariable) -> Iterable[tuple[tuple[str, ...], tuple[int, ...]]]: ...

    def _fail_nondef(self, actions: Mapping[str, Array], batch: int) -> None: ...

    def _fail_precondition(
        self, k: int, holds: Array, actions: Mapping[str, Array], batch: int
    ) -> None: ...

    def _fail_invariant(self, k: int, holds: Array, batch: int) -> None: ...
