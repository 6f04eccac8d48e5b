"""The example planner shown in the README (notes/planners-readme.md),
kept here verbatim so that test_example.py runs it."""

import numpy as np
from ippc.planners import Observation, Planner, WireFluent
from ippc.rddl.wire import WireCodec


class GreedyPlanner(Planner):
    """MDPs with boolean actions: the legal joint action with the best mean sampled reward."""

    name = "greedy"
    options = {"samples": "sampled steps per joint action (default 16)"}

    def act(self, obs: Observation) -> list[WireFluent]:
        sim, n = self.session.simulator, self.int_option("samples", 16, minimum=1)
        actions = sim.legal_actions(obs.state)  # every legal joint action, stacked
        k = len(next(iter(actions.values())))
        batch = obs.state[[0] * (k * n)]  # the state, k * n times
        step = sim.step(
            batch,
            {a: v.repeat(n, axis=0) for a, v in actions.items()},
            np.random.default_rng(self.session.seed),
        )
        best = int(step.reward.reshape(k, n).mean(axis=1).argmax())
        return WireCodec(sim).actions(actions, index=best)
