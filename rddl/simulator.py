"""The simulator's import path: `from ippc.rddl.simulator import Simulator`.

The simulator is the package `ippc.rddl.sim` (its docstring is the theory
of operation); this module re-exports its public names, and the private
ones that tests and benchmarks reach for.
"""

from __future__ import annotations

from .sim.actions import RANDOM_MAX_CONCURRENT
from .sim.code import _LARGE_BATCH
from .sim.compiler import _Compiler
from .sim.runtime import _SPREAD_BYTES, _gather_sum, _quietly, _spread_factory
from .sim.simulator import Simulator
from .sim.state import Prepared, SimulationError, State, Step

__all__ = [
    "RANDOM_MAX_CONCURRENT",
    "Prepared",
    "SimulationError",
    "Simulator",
    "State",
    "Step",
    "_Compiler",
    "_LARGE_BATCH",
    "_SPREAD_BYTES",
    "_gather_sum",
    "_quietly",
    "_spread_factory",
]
