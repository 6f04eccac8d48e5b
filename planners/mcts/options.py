"""The options of `mcts`: their one-line help (what `--planner-option`
accepts) and `Settings`, the typed values the other modules read.

May call the planner's option readers (`ippc.planners.base`); nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..base import Planner

ROLLOUT_POLICIES = ("random", "noop", "best")
HEURISTICS = ("ids", "rollout")
ENGINES = ("thts", "wave")
COMPILED = ("auto", "yes", "no")

OPTIONS: dict[str, str] = {
    "engine": "the search: thts (one trial at a time on the grounded one-state step, "
    "rddl.sim.scalar; where that step cannot be written, or for a POMDP, wave instead) or "
    "wave (waves of trials over the batched simulator) (default thts)",
    "compiled": "engine thts: the step and the search's inner loops (probing, IDS, "
    "roll-outs) in C, built when the session starts with the system's C compiler ($CC, else "
    "cc, gcc or clang; cached in $IPPC_CACHE, default ~/.cache/ippc): auto (when a compiler "
    "is found and the instance translates, else the Python step), yes (the session fails "
    "otherwise) or no (default auto)",
    "time_per_step": "seconds of search per turn (default: the client's deadline, the "
    "session's remaining time spread over its remaining steps)",
    "iterations": "search exactly this many waves (engine wave) or trials (engine thts) per "
    "turn, whatever the time (for reproducible runs; default: search until the deadline)",
    "exploration": "UCB1 exploration constant, scaled by the node's largest |Q| (default 2)",
    "rollout_depth": "steps of a leaf rollout (default 10; 0: to the lookahead limit)",
    "depth": "lookahead limit of the search in steps (default 0: the steps left in the "
    "round); the tree and the rollouts never look further",
    "batch": "rows of a leaf-evaluation batch: trials per wave are chosen so that their "
    "leaves' candidates x rollouts fill about this many (default 1024)",
    "rollouts": "rollouts per candidate action of a new leaf (default 1)",
    "extrapolate": "a rollout cut short by rollout_depth counts as its mean reward per "
    "step over all the steps left (default yes; else as the rewards it saw)",
    "trial_depth": "most decision levels a trial descends through nodes already in the "
    "tree before it backs up the value of the node it reached (default 10; 0: no limit)",
    "new_nodes": "new decision nodes a trial may reach in one wave: it stops at the first new "
    "node, and after that node is expanded with the others of the wave goes on below it, "
    "this many times (PROST's -ndn; default 1; 0: as deep as trial_depth allows)",
    "rollout_policy": "policy after a leaf's first action: random (uniform legal joint "
    "actions), noop, or best (both; the better mean counts) (default best)",
    "init_weight": "visits the heuristic estimate of a new action counts as (default 1)",
    "heuristic": "how a new node's actions get their first values: rollout, or ids (PROST's "
    "iterative deepening search on the most-likely determinisation, with rollouts where it "
    "is too slow or values every action alike) (default ids with engine thts, else rollout)",
    "heuristic_weight": "the ids estimate is multiplied by this (PROST's is 0.5; default 1, "
    "the scale of the rollouts that stand in where ids cannot tell the actions apart)",
    "blind_weight": "engine thts: where ids values every action of a new node alike, in a "
    "session that has met a sink (a state no action can change), those values times this "
    "stand in for the roll-outs, so that a state which may still lead somewhere ranks above "
    "a sink it can avoid (PROST's heuristic weight; default 0.5; 0: always roll-outs)",
    "ids_timeout": "seconds of ids search per new node, which sets its depth in a learning "
    "phase at the start of the session (default 0.003)",
    "ids_deepen": "the ids search of a node deepens from 2 and stops at the first depth where "
    "an action beats noop, as PROST's does, instead of searching at its whole depth at once "
    "(default no: it scored lower on TriangleTireworld 2014)",
    "ids_smooth": "engine thts: a node's ids estimate is the mean of its values a step at "
    "the depth and one less (depths of 3 and more), so that it does not swing with the "
    "depth's parity (default yes; no: the value at the depth alone)",
    "blind_future": "engine thts: where every action but noop costs more now than noop and "
    "the ids estimates differ only by that first step's reward (no goal within ids's depth), "
    "roll-outs instead, even once a sink was met (default yes)",
    "ids_depth": "fixed depth of the ids search instead of the learned one (default 0: "
    "learned, except with iterations, where it is 5 so that a seed gives the same search "
    "on any machine)",
    "prune_useless": "engine thts: leave at their default the action groundings that can "
    "never pay (they touch only state the reward cannot depend on, and cost or nothing; "
    "AcademicAdvising's courses that lead to no requirement) (default yes)",
    "reward_locks": "a new node whose reward can no longer change (a dead end or a goal) "
    "is solved at once (the check costs up to 0.1 s a state; default no)",
    "max_actions": "most candidate joint actions per decision node: all the legal ones when "
    "there are no more, else noop and a uniform sample of the others; engine thts: 8 times as "
    "many, before equivalent ones are pruned (default 128)",
    "enumerate_limit": "rollouts draw from the boolean joint actions enumerated once per "
    "session when there are at most this many, else from rddlsim-style coin flips "
    "(default 4096)",
    "particles": "belief particles for POMDPs (default 64)",
    "transpositions": "share one node between all paths that reach the same state with "
    "the same steps left, within a turn and across the turns of a round (default yes)",
    "bellman_outcomes": "back up an action from the current values of all its sampled "
    "outcomes when it has at most this many (a partial Bellman backup), else from the one "
    "sampled (default 64; 0: never)",
    "max_nodes": "forget the tree (but the root) when it holds more decision nodes than "
    "this (default 200000)",
    "seed": "integer seed (default: the client's --seed, else unseeded)",
}


@dataclass(frozen=True)
class Settings:
    """Every option of `mcts`, typed, with its default."""

    engine: str = "thts"
    compiled: str = "auto"
    time_per_step: float | None = None
    iterations: int | None = None
    exploration: float = 2.0
    rollout_depth: int = 10
    depth: int = 0
    batch: int = 1024
    rollouts: int = 1
    trial_depth: int = 10
    new_nodes: int = 1
    extrapolate: bool = True
    rollout_policy: str = "best"
    init_weight: float = 1.0
    heuristic: str = "rollout"
    heuristic_weight: float = 1.0
    blind_weight: float = 0.5
    ids_timeout: float = 0.003
    ids_depth: int = 0
    ids_deepen: bool = False
    ids_smooth: bool = True
    blind_future: bool = True
    prune_useless: bool = True
    reward_locks: bool = False
    max_actions: int = 128
    enumerate_limit: int = 4096
    particles: int = 64
    transpositions: bool = True
    max_nodes: int = 200_000
    bellman_outcomes: int = 64
    seed: int | None = None

    @property
    def modes(self) -> int:
        """Rollouts per first action and rollout: 2 for `best` (random and noop)."""
        return 2 if self.rollout_policy == "best" else 1


def read_settings(planner: Planner) -> Settings:
    """The settings from the planner's string options (a bad one raises
    `PlannerError` naming it)."""

    def whole(key: str, default: int, minimum: int) -> int:
        value = planner.int_option(key, default, minimum=minimum)
        assert value is not None
        return value

    def number(key: str, default: float, minimum: float = 0.0) -> float:
        value = planner.float_option(key, default, minimum=minimum)
        assert value is not None
        return value

    policy = (planner.str_option("rollout_policy", "best") or "best").strip().lower()
    if policy not in ROLLOUT_POLICIES:
        raise planner._option_error(
            "rollout_policy", policy, "one of " + ", ".join(ROLLOUT_POLICIES)
        )
    engine = (planner.str_option("engine", "thts") or "thts").strip().lower()
    if engine not in ENGINES:
        raise planner._option_error("engine", engine, "one of " + ", ".join(ENGINES))
    compiled = (planner.str_option("compiled", "auto") or "auto").strip().lower()
    compiled = {"true": "yes", "1": "yes", "on": "yes", "false": "no", "0": "no", "off": "no"}.get(
        compiled, compiled
    )
    if compiled not in COMPILED:
        raise planner._option_error("compiled", compiled, "one of " + ", ".join(COMPILED))
    # the measured best of each engine: IDS for thts (as PROST's), roll-outs for wave
    default_h = "ids" if engine == "thts" else "rollout"
    heuristic = (planner.str_option("heuristic", default_h) or default_h).strip().lower()
    if heuristic not in HEURISTICS:
        raise planner._option_error("heuristic", heuristic, "one of " + ", ".join(HEURISTICS))
    return Settings(
        engine=engine,
        compiled=compiled,
        time_per_step=planner.float_option("time_per_step", None, minimum=0.0),
        iterations=planner.int_option("iterations", None, minimum=1),
        exploration=number("exploration", 2.0),
        rollout_depth=whole("rollout_depth", 10, 0),
        depth=whole("depth", 0, 0),
        batch=whole("batch", 1024, 1),
        rollouts=whole("rollouts", 1, 1),
        trial_depth=whole("trial_depth", 10, 0),
        new_nodes=whole("new_nodes", 1, 0),
        extrapolate=planner.bool_option("extrapolate", True),
        rollout_policy=policy,
        init_weight=number("init_weight", 1.0, minimum=1e-9),
        heuristic=heuristic,
        heuristic_weight=number("heuristic_weight", 1.0),
        blind_weight=number("blind_weight", 0.5),
        ids_timeout=number("ids_timeout", 0.003, minimum=1e-6),
        ids_depth=whole("ids_depth", 0, 0),
        ids_deepen=planner.bool_option("ids_deepen", False),
        ids_smooth=planner.bool_option("ids_smooth", True),
        blind_future=planner.bool_option("blind_future", True),
        prune_useless=planner.bool_option("prune_useless", True),
        reward_locks=planner.bool_option("reward_locks", False),
        max_actions=whole("max_actions", 128, 1),
        enumerate_limit=whole("enumerate_limit", 4096, 1),
        particles=whole("particles", 64, 1),
        transpositions=planner.bool_option("transpositions", True),
        max_nodes=whole("max_nodes", 200_000, 1),
        bellman_outcomes=whole("bellman_outcomes", 64, 0),
        seed=planner.int_option("seed"),
    )
