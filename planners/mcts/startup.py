"""The budgets of an `mcts` session: its start-up allowance and its memory
(`ippc.planners.budget`), as the planner applies them.

Start-up, in the order the planner meets it, and what each step falls back
on when the allowance (option `startup`) runs short:

* the relevance analysis (`prune_useless`) runs in a worker thread with the
  time left as its deadline; late, every action grounding is kept;
* the C step's translation and compile start in the background as soon as
  there is a scalar step (`start_compile`), and the session waits for them
  `COMPILE_SHARE` of the start-up time left (`compile_wait`); late, the
  wave engine plays while the build goes on, and the first turn after it
  (and the compiled engine's set-up, with an allowance of its own) has
  ended switches to the compiled engine (the planner's `_switch`). With
  `iterations` (a run that must not depend on the machine's speed) or
  `compiled=yes` the whole allowance is waited for, and a late build means
  the wave engine for the session (`compiled=yes`: the session fails);
* the legal actions in C (`setup_enum`) and IDS's learning phase run only
  when at least `ENUM_SECONDS` / `IDS_SECONDS` are left, else the Python
  solver's candidates, and roll-outs instead of IDS;
* the wave engine's IDS is built and learned in a worker thread; late,
  roll-outs.

Every skip is a WARNING naming what was skipped and why. Memory (option
`memory`): the batch, the candidates per node and the nodes of the tree
are sized from the instance (`sizing`), and the wave engine's search stops
growing the tree within a turn when it holds that many nodes.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from ...rddl.sim.scalar import ScalarStep
from ...rddl.simulator import Simulator
from ..base import Planner, SessionInfo
from ..budget import (
    DEFAULT_STARTUP,
    Background,
    OneAtATime,
    Startup,
    StartupOverrun,
    memory_budget,
)
from . import sizing as _sizing
from .ckernels import Kernels
from .options import Settings

if TYPE_CHECKING:
    from .heuristic import IDS, RewardLocks
    from .stats import SearchStats

log = logging.getLogger(__name__)

T = TypeVar("T")

ENUM_SECONDS = 1.0
"""Start-up seconds that must be left to check the legal actions in C."""
IDS_SECONDS = 1.0
"""Start-up seconds that must be left to learn IDS's depth."""
COMPILE_SHARE = 0.5
"""Share of the start-up time left that a session waits for the C step's
build before the wave engine starts instead: the rest is the wave engine's
own set-up (its warm-up, its IDS), so that a cold compile cache does not
hold up the first action."""


class Budgets:
    """One session's start-up allowance and memory sizing."""

    def __init__(self, planner: Planner, session: SessionInfo) -> None:
        seconds = planner.float_option("startup", None, minimum=0.0)
        mib = planner.float_option("memory", None, minimum=1.0)
        self.startup = Startup(
            "mcts", session.instance, DEFAULT_STARTUP if seconds is None else seconds
        )
        self.memory = memory_budget(mib)
        self.sizing: _sizing.Sizing | None = None
        self.turns = OneAtATime("mcts: a turn")
        """The session's turns, each in a worker thread (`budget.guarded_turn`)."""
        self._warned_full = False
        # a turn's expected seconds, for the wave engine's batch: the option,
        # else the session's time spread over its steps
        horizon = max(1, session.model.horizon or 40)
        self.turn_seconds = session.time_allowed / max(1, session.rounds * horizon)

    def within(self, what: str, fn: Callable[[], T], instead: T, why_late: str) -> T:
        """`fn()` within the start-up time left, else `instead` (with a
        warning: `what` skipped, `why_late` what is done instead)."""
        try:
            return self.startup.run(what, fn)
        except StartupOverrun as err:
            self.startup.skip(what, f"{err}; {why_late}")
            return instead

    def start_compile(self, scalar: ScalarStep) -> Background[Kernels]:
        """The C step's translation and build (the compiler a subprocess),
        started now in the background; its result is the thts engine's
        `Kernels` (or `CUnavailable`)."""
        build = _c_builder()
        return Background("mcts: compiling the C step", lambda: build(scalar))

    def compile_wait(self, settings: Settings) -> float:
        """Seconds to wait for the C step's build before starting the wave
        engine instead: `COMPILE_SHARE` of the start-up time left, or all of
        it where the engine must not change during the session (`iterations`,
        `compiled=yes`)."""
        left = max(0.0, self.startup.left())
        if settings.iterations is not None or settings.compiled == "yes":
            return left
        return COMPILE_SHARE * left

    def afresh(self) -> Budgets:
        """These budgets with a start-up allowance that starts again now:
        for the compiled engine's set-up after a late build, which runs
        beside the wave engine's turns instead of before the first action."""
        fresh = copy.copy(self)
        fresh.startup = Startup(self.startup.who, self.startup.instance, self.startup.seconds)
        return fresh

    def heuristic(
        self, settings: Settings, build: Callable[[], tuple[IDS | None, RewardLocks | None]]
    ) -> tuple[IDS | None, RewardLocks | None]:
        """The wave engine's IDS and reward-lock check (`build`), within the
        start-up time left (else neither, with a warning), IDS's levels
        sized to the memory budget."""
        if settings.heuristic != "ids" and not settings.reward_locks:
            return None, None
        ids, locks = self.within(
            "IDS and the reward-lock check (their joint actions, IDS's learning phase)",
            build,
            (None, None),
            "roll-outs instead",
        )
        if ids is not None:
            ids.max_rows = min(ids.max_rows, self.ids_rows())
        return ids, locks

    def fits(self, what: str, seconds: float, why_late: str) -> bool:
        """Whether `seconds` of start-up are left for `what` (else a warning)."""
        if self.startup.fits(seconds):
            return True
        self.startup.skip(
            what, f"less than {seconds:g} s of the start-up allowance left; {why_late}"
        )
        return False

    def size_thts(self, sim: Simulator, settings: Settings) -> Settings:
        """`settings` with the tree sized for the thts engine."""
        n_values = sum(
            int(v.size // max(1, v.shape[0])) for v in sim.initial_state(1).values.values()
        )
        sized, self.sizing = _sizing.size_thts(n_values, settings, self.memory)
        self._log(settings)
        return sized

    def size_wave(self, sim: Simulator, settings: Settings) -> Settings:
        """`settings` with the batch, candidates and tree sized for the wave engine."""
        turn = settings.time_per_step if settings.time_per_step is not None else self.turn_seconds
        sized, self.sizing = _sizing.size_wave(
            sim, settings, self.memory, None if settings.iterations is not None else turn
        )
        self._log(settings)
        return sized

    def ids_rows(self) -> int:
        """Rows an IDS level may step at once."""
        return 200_000 if self.sizing is None else _sizing.ids_rows(self.sizing)

    def _log(self, asked: Settings) -> None:
        assert self.sizing is not None
        log.info("mcts: %s: %s", self.startup.instance, _sizing.describe(self.sizing, asked))

    def tree_full(self, nodes: int, turn: SearchStats, max_nodes: int) -> bool:
        """Whether the wave engine's tree (`nodes` at the start of the turn,
        plus the leaves the turn expanded) has reached `max_nodes`: the
        search stops growing it (logged once a session)."""
        if nodes + turn.leaves < max_nodes:
            return False
        if not self._warned_full:
            self._warned_full = True
            log.warning(
                "mcts: %s: the tree holds %d nodes, as many as the memory budget allows "
                "(max_nodes); the turn's search stops there (logged once a session)",
                self.startup.instance,
                nodes + turn.leaves,
            )
        return True


def _c_builder() -> Callable[[ScalarStep], Kernels]:
    """What builds the thts engine's C step (a function, so that a test can
    make the build slow or make it fail)."""
    return Kernels


def warm_up(sim: Simulator, largest: int = 4096) -> None:
    """Compile the simulator's functions for every batch size the search
    uses now rather than in the first turn's search, so that the first
    turn keeps its deadline too (a failure is left for the search)."""
    rng = np.random.default_rng(0)  # not the search's: seeded runs stay the same
    for batch in sorted({1, 2, min(4096, largest)}):
        state = sim.initial_state(batch)
        noop = sim.noop(batch)
        try:
            sim.check_actions(state, noop)
            sim.step(state, noop, rng, check=False)
        except Exception as err:  # noqa: BLE001 - the search meets and reports it
            log.debug("mcts: warm-up step of %d states failed: %s", batch, err)
