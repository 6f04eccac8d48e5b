"""The `replan` planner class: its options, the session's determinised
`SearchProblem`, and each turn's choice between following the plan,
refining it and replanning on a surprise (see the package docstring). The
search it calls is in `determinised_search.py`.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import ClassVar

import numpy as np

from ...rddl.legal import LegalActions, NoLegalAction, solver_for
from ...rddl.simulator import SimulationError, Simulator, State
from ...rddl.wire import WireCodec
from ..base import Observation, Planner, PlannerError, SessionInfo, WireFluent
from ..budget import (
    DEFAULT_STARTUP,
    MEMORY_HELP,
    OneAtATime,
    count_within,
    describe_bytes,
    guarded_turn,
    memory_budget,
    noop_legal,
    rows_within,
    state_bytes,
    step_cost,
)
from ..determinise import determinise
from .determinised_search import (
    DEFAULT_EXPAND,
    DEFAULT_MAX_ACTIONS,
    MAX_NODES,
    Actions,
    PlanStep,
    SearchProblem,
    SearchResult,
    _take,
    joint_actions,
    same_state,
    search,
)

# the logger keeps the name it had when replan was one module
log = logging.getLogger("ippc.planners.replan")

DETERMINISATIONS = ("most-likely", "all-outcomes")
DEFAULT_DEPTH_NO_HORIZON = 40  # plan length when the instance has no horizon
DEFAULT_OUTCOMES = 4


class ReplanPlanner(Planner):
    """Determinise, plan with a best-first search over the determinised
    simulator, execute, replan on surprise (see the module's docstring)."""

    name: ClassVar[str] = "replan"
    options: ClassVar[dict[str, str]] = {
        "determinisation": "most-likely (default: each random draw takes its most likely outcome) "
        "or all-outcomes (the search may also pick among sampled outcomes of each action, "
        "optimistically)",
        "time_per_step": "seconds of search per turn at most (default: the turn's deadline, "
        "the session's time left spread over the steps left)",
        "max_depth": "plan length and lookahead in steps (default: the steps left in the round; "
        f"{DEFAULT_DEPTH_NO_HORIZON} when the instance has no horizon)",
        "expand": f"nodes expanded together in one batched simulator step (default {DEFAULT_EXPAND})",
        "outcomes": "all-outcomes: outcomes sampled per action besides the most likely one "
        f"(default {DEFAULT_OUTCOMES})",
        "max_actions": "most candidate joint actions per state (default "
        f"{DEFAULT_MAX_ACTIONS}); beyond it the largest sets are left out and one random legal "
        "joint action per node is tried instead",
        "refine": "while the plan holds, search again from the current state when the last "
        "search was cut short by the deadline, keeping the plan unless a better one turns up "
        "(default true)",
        "seed": "integer seed for sampled outcomes and random actions (default: the client's "
        "--seed, else unseeded)",
        "startup": "seconds the session's start (the determinised model compiled, the "
        "candidates enumerated) may take before the first turn; a start not done by then "
        "goes on in the background while the turns send noop, with a warning (default "
        f"{DEFAULT_STARTUP:g})",
        "memory": MEMORY_HELP,
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        mode = (self.str_option("determinisation", "most-likely") or "most-likely").strip().lower()
        if mode not in DETERMINISATIONS:
            raise self._option_error("determinisation", mode, " or ".join(DETERMINISATIONS))
        self.determinisation = mode
        self.time_per_step = self.float_option("time_per_step", None, minimum=0.0)
        self.max_depth = self.int_option("max_depth", None, minimum=1)
        self.expand = self.int_option("expand", DEFAULT_EXPAND, minimum=1) or DEFAULT_EXPAND
        outcomes = self.int_option("outcomes", DEFAULT_OUTCOMES, minimum=1)
        self.outcomes = (outcomes or DEFAULT_OUTCOMES) if mode == "all-outcomes" else 0
        self.max_actions = (
            self.int_option("max_actions", DEFAULT_MAX_ACTIONS, minimum=1) or DEFAULT_MAX_ACTIONS
        )
        self.refine = self.bool_option("refine", True)
        self.seed = self.int_option("seed")
        startup = self.float_option("startup", DEFAULT_STARTUP, minimum=0.0)
        assert startup is not None
        self.startup = startup
        self.memory_mib = self.float_option("memory", None, minimum=1.0)
        self._building: threading.Thread | None = None
        self._built: dict[str, object] = {}  # the background start's problem or error
        self._turns = OneAtATime("replan: a turn")
        # counters over the planner's life
        self.searches = 0
        self.replans = 0
        self.refinements = 0
        self.expansions = 0
        self.planning_seconds = 0.0
        self.last_search: SearchResult | None = None
        self.problem: SearchProblem | None = None
        self._codec: WireCodec | None = None
        self._plan: list[PlanStep] = []
        self._plan_complete = True
        self._expected: State | None = None
        self._round = (0, 0, 0, 0.0)  # counters at the start of the round

    # -- session -----------------------------------------------------

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        self.problem = None
        self._turns = OneAtATime("replan: a turn")
        self._codec = WireCodec(session.simulator)
        built: dict[str, object] = {}

        def build() -> None:
            try:
                built["problem"] = self._build(session)
            except BaseException as err:  # noqa: BLE001 - raised in the thread's turn
                built["error"] = err

        worker = threading.Thread(target=build, name="replan: start-up", daemon=True)
        worker.start()
        worker.join(self.startup)
        self._built, self._building = built, worker
        if worker.is_alive():
            log.warning(
                "replan: %s: start-up: the determinised search is not built within the "
                "start-up allowance of %g s (option startup); noop until it is",
                session.instance,
                self.startup,
            )
        else:
            self._ready()

    def _ready(self) -> bool:
        """Whether the search problem is built (raising the build's error)."""
        if self.problem is not None:
            return True
        if self._building is not None and self._building.is_alive():
            return False
        if "error" in self._built:
            raise self._built.pop("error")  # type: ignore[misc]
        problem = self._built.get("problem")
        if isinstance(problem, SearchProblem):
            self.problem = problem
        return self.problem is not None

    def _build(self, session: SessionInfo) -> SearchProblem:
        """The session's search problem, sized to the memory budget."""
        t0 = time.monotonic()
        world = session.simulator
        try:
            det = Simulator(determinise(session.model))
        except SimulationError as err:
            raise PlannerError(f"replan: cannot simulate the determinised model: {err}") from err
        solver = solver_for(world) if LegalActions.supports(world) else None
        if solver is None:
            candidates, truncated = joint_actions(world, self.max_actions)
        else:  # every node asks the solver for its own
            candidates, truncated = world.noop(1), False
        seed = self.seed if self.seed is not None else session.seed
        expand, max_actions, max_nodes = self._sized(session, det)
        problem = SearchProblem(
            sim=det,
            world=world,
            candidates=candidates,
            truncated=truncated,
            discount=session.model.discount,
            rng=np.random.default_rng(seed),
            outcomes=self.outcomes,
            expand=expand,
            max_nodes=max_nodes,
            solver=solver,
            max_actions=max_actions,
        )
        log.info(
            "replan: %s, %s determinisation, %s%s, built in %.3f s",
            session.instance,
            self.determinisation,
            "legal joint actions per node"
            if solver is not None
            else f"{problem.n_candidates} candidate joint actions",
            " (truncated: plus random ones)" if truncated else "",
            time.monotonic() - t0,
        )
        return problem

    def _sized(self, session: SessionInfo, det: Simulator) -> tuple[int, int, int]:
        """(expand, max_actions, max_nodes) lowered to the memory budget: an
        expansion's children (expand x max_actions states) stepped in half
        of it, the search tree's states (twice: the batch and the key) in
        the other half."""
        budget = memory_budget(self.memory_mib)
        cost = step_cost(det)
        rows = rows_within(budget // 2, cost, self.expand * self.max_actions)
        expand = max(1, min(self.expand, rows // self.max_actions))
        max_actions = max(2, min(self.max_actions, rows // expand))
        node = 2 * state_bytes(det) + 600
        max_nodes = count_within(budget // 2, node, MAX_NODES)
        lowered = [
            f"{name} {asked} -> {got}"
            for name, asked, got in (
                ("expand", self.expand, expand),
                ("max_actions", self.max_actions, max_actions),
                ("nodes", MAX_NODES, max_nodes),
            )
            if got < asked
        ]
        log.info(
            "replan: %s: memory budget %s (option memory); a step costs %s a state: %s",
            session.instance,
            describe_bytes(budget),
            describe_bytes(cost.per_row),
            ", ".join(lowered) if lowered else "nothing lowered",
        )
        return expand, max_actions, max_nodes

    def start_round(self, round_num: int) -> None:
        self._plan = []
        self._plan_complete = True
        self._expected = None
        self._round = (self.searches, self.replans, self.refinements, self.planning_seconds)

    def end_round(self, reward: float) -> None:
        s, r, f, t = self._round
        log.info(
            "replan: round reward %s; %d searches, %d replans, %d refinements, %.3f s planning",
            reward,
            self.searches - s,
            self.replans - r,
            self.refinements - f,
            self.planning_seconds - t,
        )

    def end_session(self, total_reward: float) -> None:
        log.info(
            "replan: session reward %s; %d searches, %d replans, %d refinements, %d expansions, "
            "%.3f s planning",
            total_reward,
            self.searches,
            self.replans,
            self.refinements,
            self.expansions,
            self.planning_seconds,
        )

    # -- turns -------------------------------------------------------

    def _depth(self, obs: Observation) -> int:
        assert self.session is not None
        if self.session.model.horizon is None:
            return self.max_depth or DEFAULT_DEPTH_NO_HORIZON
        steps = max(1, obs.steps_left)
        return min(steps, self.max_depth) if self.max_depth else steps

    def _search(
        self,
        state: State,
        obs: Observation,
        deadline: float,
        incumbent: list[PlanStep] | None,
        why: str,
    ) -> None:
        assert self.problem is not None
        result = search(self.problem, state, self._depth(obs), deadline, incumbent)
        self.searches += 1
        self.expansions += result.expansions
        self.planning_seconds += result.seconds
        self.last_search = result
        self._plan = list(result.steps)
        self._plan_complete = result.complete or (result.kept_incumbent and self._plan_complete)
        log.debug(
            "replan: turn %d (%s): %d expansions, %d nodes, depth %d, value %.4g%s%s, %.3f s",
            obs.turn,
            why,
            result.expansions,
            result.nodes,
            result.depth,
            result.value,
            ", complete" if result.complete else "",
            ", plan kept" if result.kept_incumbent else "",
            result.seconds,
        )

    def act(self, obs: Observation) -> list[WireFluent]:
        if self.session is None or self._codec is None:
            raise PlannerError("replan: act() called before start_session()")
        # the turn in a worker thread: one that runs past its deadline (a slow
        # first expansion) sends noop and finishes in the background
        deadline = obs.deadline
        if self.time_per_step is not None:
            deadline = min(deadline, time.monotonic() + self.time_per_step)
        return guarded_turn(
            self._turns,
            "replan",
            obs.turn,
            deadline,
            lambda: self._act(obs),
            noop_legal(self.session.simulator, obs.state),
        )

    def _act(self, obs: Observation) -> list[WireFluent]:
        assert self.session is not None and self._codec is not None
        if not self._ready():
            log.warning(
                "replan: turn %d: the determinised search is still being built; noop", obs.turn
            )
            return []
        assert self.problem is not None
        now = time.monotonic()
        deadline = obs.deadline
        if self.time_per_step is not None:
            deadline = min(deadline, now + self.time_per_step)
        world = self.problem.world
        if obs.state is not None:
            state = obs.state
        elif self._expected is not None:
            state = self._expected  # POMDP: what the plan predicted
        else:
            state = world.initial_state(1)
        why = None
        incumbent = None
        if (
            obs.state is not None
            and self._expected is not None
            and not same_state(obs.state, self._expected)
        ):
            self.replans += 1
            self._plan = []
            why = "surprise"
            log.debug("replan: turn %d: the state is not the predicted one", obs.turn)
        elif not self._plan:
            why = "start" if self._expected is None else "plan ended"
        elif self.refine and not self._plan_complete:
            why = "refine"
            incumbent = self._plan
        if why is not None and now < deadline:
            if why == "refine":
                self.refinements += 1
            self._search(state, obs, deadline, incumbent, why)
        chosen = self._next_legal(state, obs, deadline)
        if chosen is None:
            self._expected = None
            return []
        return self._codec.actions(chosen, 0)

    def _next_legal(self, state: State, obs: Observation, deadline: float) -> Actions | None:
        """The plan's next joint action if it is legal in `state` (else a
        new search, else noop or the first legal candidate); sets the
        prediction for the next turn."""
        assert self.problem is not None
        world = self.problem.world
        if self._plan:
            step = self._plan.pop(0)
            if bool(world.check_actions(state, step.actions)[0]):
                self._expected = step.state
                return step.actions
            # a noop continuation can be illegal where the domain demands an action
            log.debug("replan: turn %d: the plan's action is not legal here; searching", obs.turn)
            if time.monotonic() < deadline:
                self._search(state, obs, deadline, None, "illegal plan step")
                if self._plan:
                    step = self._plan.pop(0)
                    if bool(world.check_actions(state, step.actions)[0]):
                        self._expected = step.state
                        return step.actions
        self._plan = []
        noop = world.noop(1)
        if bool(world.check_actions(state, noop)[0]):
            return None
        if self.problem.solver is not None:
            try:
                some = self.problem.solver.candidates(state, self.problem.rng, 1)
            except NoLegalAction as err:
                log.warning("replan: turn %d: %s; sending noop", obs.turn, err)
                return None
            return _take(some, [0])
        cands = self.problem.candidates
        n = self.problem.n_candidates
        legal = np.nonzero(world.check_actions(state[[0] * n], cands))[0]
        if len(legal):
            return _take(cands, [int(legal[0])])
        log.warning("replan: turn %d: no legal joint action found; sending noop", obs.turn)
        return None
