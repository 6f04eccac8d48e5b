"""The compiler: RDDL expressions to numpy statements.

`_Compiler` is the whole compiler, assembled from its layers:

    base._CompilerBase        values, statements, constants, `compile`
      operators._Operators    references, operators, if/switch, functions
        aggregations._Aggregations   sum_, exists_... and contractions
      distributions._Distributions   the random draws

`compile(e, scope)` calls the method named after `e`'s AST class; a
construct that no layer compiles (`_MatrixOp`, `_VectorDistribution`) is
refused here with a `SimulationError`. Imports its layers (and `code`,
`state`) only; `build` drives it to write a simulator's functions, and
nothing else but `Simulator` (its constants and codes) uses it.
"""

from __future__ import annotations

from .. import ast as A
from .aggregations import _Aggregations
from .code import Scope, _Node
from .distributions import _Distributions
from .state import SimulationError


class _Compiler(_Aggregations, _Distributions):
    """Writes the generated functions of one model (see the package's
    docstring); `begin` starts a function, `compile` adds an expression's
    statements to it and returns its value."""

    def _unsupported(self, e: A.Expr, scope: Scope, hint: str | None) -> _Node:
        raise SimulationError(f"{e.loc}: {type(e).__name__} is not supported by the simulator")

    _MatrixOp = _unsupported
    _VectorDistribution = _unsupported
