"""ippc.planners: the planner interface, the built-in planners and the
PROST launcher.

A planner is found by name (`find_planner`, `make_planner`): the entry
points of the group `ippc.planners`, ippc's own built-ins among them::

    from ippc.planners import make_planner
    planner = make_planner("random", {"seed": "1"})

Built-ins: `noop` (`NoopPlanner`), `random` (`RandomPlanner`, rddlsim's
RandomConcurrentPolicy), `uniform` (`UniformPlanner`), `mcts`, `replan`,
`exact` (value iteration on small instances), `prost`
(`ProstPlanner`, an `ExternalPlanner` that runs a PROST binary).
"""

from __future__ import annotations

from .base import (
    BUILTIN_PLANNERS,
    ENTRY_POINT_GROUP,
    ExternalPlanner,
    ExternalResult,
    Observation,
    Planner,
    PlannerError,
    SessionInfo,
    WireFluent,
    find_planner,
    make_planner,
    planner_names,
)
from .basic import NoopPlanner, RandomPlanner, UniformPlanner
from .prost import DEFAULT_CONFIG, ProstOutput, ProstPlanner, parse_prost_output

__all__ = [
    "BUILTIN_PLANNERS",
    "DEFAULT_CONFIG",
    "ENTRY_POINT_GROUP",
    "ExternalPlanner",
    "ExternalResult",
    "NoopPlanner",
    "Observation",
    "Planner",
    "PlannerError",
    "ProstOutput",
    "ProstPlanner",
    "RandomPlanner",
    "SessionInfo",
    "UniformPlanner",
    "WireFluent",
    "find_planner",
    "make_planner",
    "parse_prost_output",
    "planner_names",
]
