"""ippc.planners.mpc: sampling-based model-predictive control (the cross-entropy
method or MPPI) over the batched simulator, for real, int, bool and enum actions
(the IPPC 2023 domains). See docs/planners-mpc.md."""

from __future__ import annotations

from .planner import MPCPlanner

__all__ = ["MPCPlanner"]
