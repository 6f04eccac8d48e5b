"""The options of `mcts`, each defined once: `TABLE` holds every option's
name, kind, default and help; the one-line help that `--planner-option`
lists (`OPTIONS`), the typed `Settings` and their defaults, and the parser
(`read_settings`) are all derived from it.

Ten options are public (`PUBLIC`): the ones a user chooses between runs.
The others are experimental (`EXPERIMENTAL`): tuning knobs of the search,
kept so that a measurement can vary them; their defaults are the measured
ones and may change without notice (docs/planners.md lists both tables).

May call the planner's option readers (`ippc.planners.base`); nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from ..base import Planner

ROLLOUT_POLICIES = ("random", "noop", "best")
HEURISTICS = ("ids", "rollout")
ENGINES = ("thts", "wave")
COMPILED = ("auto", "yes", "no")

_BOOL_WORDS = {"true": "yes", "1": "yes", "on": "yes", "false": "no", "0": "no", "off": "no"}


@dataclass(frozen=True)
class Option:
    """One option: its kind ("int", "float", "bool" or "choice"), its default
    (None: not set), the least value it takes (numbers), its choices and its
    help (without the default: `line` adds it)."""

    name: str
    kind: str
    default: Any
    help: str
    minimum: float | None = None
    choices: tuple[str, ...] = ()
    public: bool = False
    default_text: str | None = None  # how the help shows the default, when not its value

    def line(self) -> str:
        """The one-line help, ending with the default."""
        if self.default_text is not None:
            shown = self.default_text
        elif isinstance(self.default, bool):
            shown = "yes" if self.default else "no"
        else:
            shown = str(self.default)
        return f"{self.help} (default {shown})"


TABLE: tuple[Option, ...] = (
    # ------------------------------------------------------------------ public
    Option(
        "time_per_step",
        "float",
        None,
        "seconds of search per turn",
        minimum=0.0,
        public=True,
        default_text="the client's deadline, the session's remaining time spread over its "
        "remaining steps",
    ),
    Option(
        "iterations",
        "int",
        None,
        "search exactly this many trials (engine thts) or waves (engine wave) per turn, "
        "whatever the time, for reproducible runs",
        minimum=1,
        public=True,
        default_text="search until the deadline",
    ),
    Option(
        "seed",
        "int",
        None,
        "integer seed",
        public=True,
        default_text="the client's --seed, else unseeded",
    ),
    Option(
        "depth",
        "int",
        0,
        "lookahead limit of the search in steps; the tree and the roll-outs never look "
        "further (0: the steps left in the round)",
        minimum=0,
        public=True,
    ),
    Option(
        "exploration",
        "float",
        2.0,
        "UCB1 exploration constant, scaled by the node's largest |Q|",
        minimum=0.0,
        public=True,
    ),
    Option(
        "heuristic",
        "choice",
        "ids",
        "how a new node's actions get their first values: ids (PROST's iterative deepening "
        "search on the most-likely determinisation, with roll-outs where it is too slow or "
        "values every action alike) or rollout",
        choices=HEURISTICS,
        public=True,
        default_text="ids with engine thts, rollout with engine wave",
    ),
    Option(
        "compiled",
        "choice",
        "auto",
        "engine thts: the step and the search in C, built when the session starts with the "
        "system's C compiler ($CC, else cc, gcc or clang; cached in a private folder, "
        "$IPPC_CACHE or ~/.cache/ippc): auto (when a compiler is found and the instance "
        "translates, else the wave engine), yes (the session fails otherwise) or no (the "
        "wave engine)",
        choices=COMPILED,
        public=True,
    ),
    Option(
        "max_actions",
        "int",
        128,
        "most candidate joint actions per decision node: all the legal ones when there are "
        "no more, else noop and a uniform sample of the others (engine thts: 8 times as many "
        "before equivalent ones are pruned)",
        minimum=1,
        public=True,
    ),
    Option(
        "max_nodes",
        "int",
        200_000,
        "forget the tree (but the root) when it holds more decision nodes than this",
        minimum=1,
        public=True,
    ),
    Option("particles", "int", 64, "belief particles for POMDPs", minimum=1, public=True),
    Option(
        "startup",
        "float",
        None,
        "seconds the session's start may take before the first turn's search (relevance "
        "analysis, C compile, legal actions in C, IDS); what does not fit is skipped with a "
        "warning (docs/planners-budgets.md)",
        minimum=0.0,
        public=True,
        default_text="10, or $IPPC_STARTUP where it is set",
    ),
    Option(
        "memory",
        "float",
        None,
        "MiB the search may take: the batch, the candidates per node and the tree's nodes "
        "are lowered to fit it (docs/planners-budgets.md)",
        minimum=1.0,
        public=True,
        default_text="a quarter of MemAvailable at the start of the session",
    ),
    # ------------------------------------------------------------ experimental
    Option(
        "engine",
        "choice",
        "thts",
        "the search: thts (one trial at a time on the grounded one-state step; where that "
        "step cannot be written, or for a POMDP, wave instead) or wave (waves of trials over "
        "the batched simulator)",
        choices=ENGINES,
    ),
    Option("rollout_depth", "int", 10, "steps of a leaf roll-out (0: to the lookahead limit)", 0),
    Option(
        "batch",
        "int",
        1024,
        "engine wave: rows of a leaf-evaluation batch (trials per wave are chosen so that "
        "their leaves' candidates x roll-outs fill about this many)",
        1,
    ),
    Option("rollouts", "int", 1, "roll-outs per candidate action of a new leaf", 1),
    Option(
        "extrapolate",
        "bool",
        True,
        "a roll-out cut short by rollout_depth counts as its mean reward per step over all "
        "the steps left (no: as the rewards it saw)",
    ),
    Option(
        "trial_depth",
        "int",
        10,
        "most decision levels a trial descends through nodes already in the tree before it "
        "backs up (0: no limit)",
        0,
    ),
    Option(
        "new_nodes",
        "int",
        1,
        "engine wave: new decision nodes a trial may reach in one wave (PROST's -ndn; 0: as "
        "deep as trial_depth allows)",
        0,
    ),
    Option(
        "rollout_policy",
        "choice",
        "best",
        "policy after a leaf's first action: random (uniform legal joint actions), noop, or "
        "best (both; the better mean counts)",
        choices=ROLLOUT_POLICIES,
    ),
    Option("init_weight", "float", 1.0, "visits a new action's first estimate counts as", 1e-9),
    Option(
        "heuristic_weight",
        "float",
        1.0,
        "the ids estimate is multiplied by this (PROST's is 0.5)",
        0.0,
    ),
    Option(
        "blind_weight",
        "float",
        0.5,
        "engine thts: where ids values every action of a new node alike, in a session that "
        "has met a sink, those values times this stand in for the roll-outs (0: always "
        "roll-outs)",
        0.0,
    ),
    Option(
        "ids_timeout",
        "float",
        0.003,
        "seconds of ids search per new node, which sets its depth in a learning phase at the "
        "start of the session",
        1e-6,
    ),
    Option(
        "ids_depth",
        "int",
        0,
        "fixed depth of the ids search instead of the learned one (0: learned, except with "
        "iterations, where it is 5 so that a seed gives the same search on any machine)",
        0,
    ),
    Option(
        "ids_deepen",
        "bool",
        False,
        "the ids search deepens from 2 and stops at the first depth where an action beats "
        "noop, as PROST's does",
    ),
    Option(
        "ids_smooth",
        "bool",
        True,
        "engine thts: a node's ids estimate is the mean of its values at the depth and one "
        "less (depths of 3 and more)",
    ),
    Option(
        "blind_future",
        "bool",
        True,
        "engine thts: where every action but noop costs more now than noop and the ids "
        "estimates differ only by that first reward, roll-outs instead",
    ),
    Option(
        "prune_useless",
        "bool",
        True,
        "engine thts: leave at their default the action groundings that can never pay "
        "(planners/mcts/relevance.py)",
    ),
    Option(
        "reward_locks",
        "bool",
        False,
        "engine wave: a new node whose reward can no longer change (a dead end or a goal) "
        "is solved at once (the check costs up to 0.1 s a state); with engine thts the "
        "session runs the wave engine",
    ),
    Option(
        "enumerate_limit",
        "int",
        4096,
        "roll-outs draw from the boolean joint actions enumerated once per session when "
        "there are at most this many, else from rddlsim-style coin flips",
        1,
    ),
    Option(
        "transpositions",
        "bool",
        True,
        "share one node between all paths that reach the same state with the same steps "
        "left, within a turn and across the turns of a round",
    ),
    Option(
        "bellman_outcomes",
        "int",
        64,
        "back up an action from the current values of all its sampled outcomes when it has "
        "at most this many (a partial Bellman backup; 0: never)",
        0,
    ),
)

BY_NAME: dict[str, Option] = {o.name: o for o in TABLE}
PUBLIC: tuple[str, ...] = tuple(o.name for o in TABLE if o.public)
EXPERIMENTAL: tuple[str, ...] = tuple(o.name for o in TABLE if not o.public)

OPTIONS: dict[str, str] = {o.name: o.line() for o in TABLE}
"""The one-line help of every option, as `--planner-option` lists it."""


@dataclass(frozen=True)
class Settings:
    """Every option of `mcts`, typed. Built by `read_settings`, never
    with defaults of its own: `TABLE` holds them."""

    engine: str
    compiled: str
    time_per_step: float | None
    iterations: int | None
    exploration: float
    rollout_depth: int
    depth: int
    batch: int
    rollouts: int
    trial_depth: int
    new_nodes: int
    extrapolate: bool
    rollout_policy: str
    init_weight: float
    heuristic: str
    heuristic_weight: float
    blind_weight: float
    ids_timeout: float
    ids_depth: int
    ids_deepen: bool
    ids_smooth: bool
    blind_future: bool
    prune_useless: bool
    reward_locks: bool
    max_actions: int
    enumerate_limit: int
    particles: int
    transpositions: bool
    max_nodes: int
    bellman_outcomes: int
    seed: int | None

    @property
    def modes(self) -> int:
        """Rollouts per first action and rollout: 2 for `best` (random and noop)."""
        return 2 if self.rollout_policy == "best" else 1


def _read(planner: Planner, option: Option, default: Any) -> Any:
    key = option.name
    if option.kind == "int":
        return planner.int_option(key, default, minimum=option.minimum)
    if option.kind == "float":
        return planner.float_option(key, default, minimum=option.minimum)
    if option.kind == "bool":
        return planner.bool_option(key, default)
    text = (planner.str_option(key, default) or default).strip().lower()
    text = _BOOL_WORDS.get(text, text) if option.choices == COMPILED else text
    if text not in option.choices:
        raise planner._option_error(key, text, "one of " + ", ".join(option.choices))
    return text


def read_settings(planner: Planner) -> Settings:
    """The settings from the planner's string options (a bad one raises
    `PlannerError` naming it)."""
    engine = _read(planner, BY_NAME["engine"], BY_NAME["engine"].default)
    values: dict[str, Any] = {"engine": engine}
    for option in TABLE:
        if option.name in values:
            continue
        default = option.default
        if option.name == "heuristic":
            # the measured best of each engine: IDS for thts (as PROST's), roll-outs for wave
            default = "ids" if engine == "thts" else "rollout"
        values[option.name] = _read(planner, option, default)
    names = {f.name for f in fields(Settings)}
    return Settings(**{k: v for k, v in values.items() if k in names})
