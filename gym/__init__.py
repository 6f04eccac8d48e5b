"""ippc.gym: RDDL instances as Gymnasium environments, over ippc's simulator.

`RDDLEnv` is one instance as a `gymnasium.Env`; `RDDLVectorEnv` is n states
of one instance as a `gymnasium.vector.VectorEnv`, stepped in one batched
simulator call (not n environments in a loop). Importing this package
registers both as `ippc/RDDL-v0` (Gymnasium 1.x has no plugin discovery: the
registration is a `gymnasium.register` call made on import), so that

    import ippc.gym
    env = gymnasium.make("ippc/RDDL-v0", domain="SysAdmin_MDP_ippc2011", instance="1")
    envs = gymnasium.make_vec("ippc/RDDL-v0", num_envs=256,
                              vectorization_mode="vector_entry_point",
                              domain="SysAdmin_MDP_ippc2011", instance="1")

(or `gymnasium.make("ippc.gym:ippc/RDDL-v0", ...)`, which imports it).

Theory of operation. `load` turns the arguments into a checked `Model`;
`spaces` builds a `Dict` space keyed by grounded fluent names in pyRDDLGym's
spelling (`bounds` reads the Box bounds from the constraints) and translates
between its values and the simulator's batch-first arrays; `env` holds what
both environments share (`_Instance`: the simulator, the legality check of
actions, the text view) and `RDDLEnv`; `vector` holds `RDDLVectorEnv`, whose
states each draw from their own generator through `streams`, so that its
environment i is exactly an `RDDLEnv` with the same seed. `flat` gives flat
spaces (`FlatRDDLEnv`, registered as `ippc/RDDLFlat-v0`: a Box observation,
a Discrete action over the legal joint actions where they can be enumerated,
else MultiBinary or Box); `baselines` (not imported here: it needs
stable-baselines3) puts an RDDLVectorEnv behind SB3's VecEnv with those
spaces. docs/gym.md is the user's page.

May import `ippc.rddl` and gymnasium.
"""

from __future__ import annotations

import gymnasium

from .env import ILLEGAL_ACTIONS, IllegalActionError, RDDLEnv
from .flat import ACTION_SPACES, MAX_ACTIONS, FlatRDDLEnv, FlatSpaces
from .spaces import grounded_name
from .vector import STREAMS, RDDLVectorEnv

__all__ = [
    "ACTION_SPACES",
    "ENV_ID",
    "FLAT_ENV_ID",
    "MAX_ACTIONS",
    "FlatRDDLEnv",
    "FlatSpaces",
    "ILLEGAL_ACTIONS",
    "STREAMS",
    "IllegalActionError",
    "RDDLEnv",
    "RDDLVectorEnv",
    "grounded_name",
]

#: The id both environments are registered under.
ENV_ID = "ippc/RDDL-v0"
#: The id of `FlatRDDLEnv` (flat spaces, for stable-baselines3 and the like).
FLAT_ENV_ID = "ippc/RDDLFlat-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="ippc.gym.env:RDDLEnv",
        vector_entry_point="ippc.gym.vector:RDDLVectorEnv",
        # the horizon truncates inside the environment (a TimeLimit would not
        # know a POMDP's or an instance's horizon)
        max_episode_steps=None,
        nondeterministic=False,
    )

if FLAT_ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=FLAT_ENV_ID,
        entry_point="ippc.gym.flat:FlatRDDLEnv",
        max_episode_steps=None,
        nondeterministic=False,
    )
