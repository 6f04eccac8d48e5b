"""The deterministic baseline: Fast Downward on the knowledge base's PDDL,
executing its plan and replanning when an action fails.

The paper's deterministic robot planned with Metric-FF on a PDDL model and
replanned from the sensed state whenever an action failed. This planner
does the same as an IPPC client (so it plays against `rddl-dispatch` and
the simulated world like any other planner):

1. On a turn with no plan, it loads the observed state into a knowledge
   base of the session's model and asks it for a determinised PDDL domain
   and problem (`KnowledgeBase.to_pddl`: exogenous fluents keep the values
   the robot last saw, action costs come from the reward). Nothing of the
   PDDL is written by hand.
2. Fast Downward (the build that the PyPI package `up-fast-downward` ships,
   run through its own driver script) finds a cost-optimal plan.
3. It predicts the state after each plan step with the RDDL model, the
   sampled (exogenous) fluents held at the values they had when it planned:
   what the plan expects, in the determinisation's own terms.
4. Each turn it sends the plan's next action. When the observed state
   differs from the prediction in a fluent that the robot's actions decide
   (the papers did not come: nobody helped, the printer was busy), the
   action failed, and it plans again from the observed state.

Why Fast Downward and not Metric-FF: both handle action costs, Fast
Downward comes from PyPI as a wheel with a prebuilt binary (`pip install
up-fast-downward`, nothing to compile, works offline once installed), and
its A* with an admissible heuristic returns cost-optimal plans, so the
baseline's route is the determinisation's best, not a heuristic's guess.
Fast Downward takes integer costs only; the knowledge base writes them in
hundredths.
"""

from __future__ import annotations

import importlib.util
import logging
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar

import numpy as np

from ..dispatch.dispatcher import draw_free_fluents
from ..kb import KnowledgeBase, Update
from ..planners.base import Observation, Planner, PlannerError, SessionInfo, WireFluent
from ..rddl.model import STATE
from ..rddl.simulator import State

__all__ = ["FastDownwardPlanner", "driver_path", "parse_plan", "run_fast_downward"]

log = logging.getLogger(__name__)

DEFAULT_SEARCH = "astar(blind())"
"""Blind A*: optimal with action costs and conditional effects, and the
print-fetching problems are small enough that a heuristic buys nothing."""

_PLAN_LINE = re.compile(r"^\(([^()]+)\)\s*$")
_COPY_SUFFIX = re.compile(r"(__[oc][0-9_]+)+$")


def driver_path() -> Path:
    """Fast Downward's driver script as the `up-fast-downward` package ships it."""
    # found without importing it: the package's __init__ imports unified_planning, which
    # the driver script does not need and which is not installed with it
    spec = importlib.util.find_spec("up_fast_downward")
    if spec is None or not spec.submodule_search_locations:
        raise PlannerError(
            "Fast Downward is not installed: pip install 'ippc[fast-downward]' "
            "(the PyPI package up-fast-downward), or give the driver with binary=PATH"
        )
    path = Path(spec.submodule_search_locations[0]) / "downward" / "fast-downward.py"
    if not path.is_file():
        raise PlannerError(f"up-fast-downward is installed but has no driver at {path}")
    return path


def parse_plan(text: str) -> list[tuple[str, tuple[str, ...]]]:
    """The actions of a Fast Downward plan file (`(name a b)` per line,
    `; cost = ...` comments), as (name, args)."""
    plan = []
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(";"):
            continue
        m = _PLAN_LINE.match(line)
        if m is None:
            raise PlannerError(f"Fast Downward plan: cannot read line {line!r}")
        name, *args = m.group(1).split()
        plan.append((name, tuple(args)))
    return plan


def run_fast_downward(
    domain: str,
    problem: str,
    *,
    search: str = DEFAULT_SEARCH,
    driver: Path | None = None,
    time_limit: float = 60.0,
) -> list[tuple[str, tuple[str, ...]]] | None:
    """A plan for the PDDL texts (None: Fast Downward proved there is none).
    Raises `PlannerError` when Fast Downward fails or runs out of time."""
    script = driver or driver_path()
    with tempfile.TemporaryDirectory(prefix="ippc-fd-") as tmp:
        folder = Path(tmp)
        (folder / "domain.pddl").write_text(domain, encoding="utf-8")
        (folder / "problem.pddl").write_text(problem, encoding="utf-8")
        cmd = [
            sys.executable,
            str(script),
            "--plan-file",
            "plan",
            "domain.pddl",
            "problem.pddl",
            "--search",
            search,
        ]
        try:
            done = subprocess.run(
                cmd, cwd=folder, capture_output=True, text=True, timeout=time_limit, check=False
            )
        except subprocess.TimeoutExpired:
            raise PlannerError(f"Fast Downward found no plan within {time_limit:g} s") from None
        plan_file = folder / "plan"
        if plan_file.is_file():
            return parse_plan(plan_file.read_text(encoding="utf-8"))
        # the driver's exit codes: 12 = search proved the task unsolvable
        if done.returncode in (11, 12):
            return None
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-8:])
        raise PlannerError(f"Fast Downward failed (exit {done.returncode}):\n{tail}")


class FastDownwardPlanner(Planner):
    """Plan with Fast Downward on the knowledge base's PDDL; execute; replan
    when an action fails (see the module doc)."""

    name = "fast-downward"
    options: ClassVar[dict[str, str]] = {
        "search": f"Fast Downward's search option (default {DEFAULT_SEARCH})",
        "mode": "the determinisation of to_pddl: most-likely (default) or all-outcomes",
        "binary": "Fast Downward's driver script (default: the one up-fast-downward ships)",
        "time_limit": "seconds one Fast Downward call may take (default 60)",
    }

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self.search = self.str_option("search", DEFAULT_SEARCH) or DEFAULT_SEARCH
        self.mode = self.str_option("mode", "most-likely") or "most-likely"
        if self.mode not in ("most-likely", "all-outcomes"):
            raise PlannerError(
                f"planner 'fast-downward': mode must be most-likely or all-outcomes, "
                f"not {self.mode!r}"
            )
        self.driver = self.path_option("binary") or driver_path()
        self.time_limit = self.float_option("time_limit", 60.0, minimum=0.1) or 60.0
        self.plans = 0  # Fast Downward calls
        self.replans = 0  # of which after a failed action
        self.planning_seconds = 0.0
        self._plan: list[tuple[str, tuple[str, ...]]] = []
        self._expected: list[State] = []

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        model = session.model
        sampled = {p.name for p in model.fluents(STATE)} - draw_free_fluents(model)
        self._sampled = sorted(sampled)
        self._decided = sorted({p.name for p in model.fluents(STATE)} - sampled)
        # model names by their lower case: PDDL is case-insensitive and
        # Fast Downward writes plans in lower case
        self._actions = {p.name.lower(): p.name for p in session.simulator.action_fluents}
        self._objects = {o.lower(): o for t in model.types.values() for o in t.members}
        # where the robot is: the boolean state fluents named *_at whose last argument is a
        # place (robot_at(r, w)); what the robot sees there it keeps when it forgets
        self._locations = {
            p.name for p in model.fluents(STATE) if p.name.endswith("_at") and p.arity >= 2
        }

    def start_round(self, round_num: int) -> None:
        self._plan, self._expected = [], []

    # -- one turn

    def act(self, obs: Observation) -> list[WireFluent]:
        assert self.session is not None and obs.state is not None, "an MDP session"
        if self._expected:
            if self._as_expected(obs.state, self._expected[0]):
                self._expected.pop(0)
            else:
                log.info("fast-downward: turn %d: the last action failed; replanning", obs.turn)
                self._plan, self._expected = [], []
                self.replans += 1
        if not self._plan:
            kb = KnowledgeBase.from_model(self.session.model)
            kb.load_state(obs.state, "observation")
            if kb.goal_holds():
                return []
            self._make_plan(kb, obs.state)
            if not self._plan and self._forget(kb):
                # What the robot saw elsewhere is redrawn every step: with no plan on it,
                # plan on the instance's start values there (it may find them changed).
                log.info("fast-downward: no plan on what was seen; forgetting it and replanning")
                self._make_plan(kb, kb.to_state())
        if not self._plan:
            return []  # no plan: stand still and try again next turn
        name, args = self._plan.pop(0)
        return [(name, args, True)]

    def _make_plan(self, kb: KnowledgeBase, state: State) -> None:
        started = time.perf_counter()
        domain, problem = kb.to_pddl(self.mode)
        plan = run_fast_downward(
            domain, problem, search=self.search, driver=self.driver, time_limit=self.time_limit
        )
        self.plans += 1
        self.planning_seconds += time.perf_counter() - started
        if plan is None:
            log.warning("fast-downward: the determinised task has no plan")
            self._plan, self._expected = [], []
            return
        self._plan = [self._rddl_action(name, args) for name, args in plan]
        self._expected = self._predict(state, self._plan)
        log.info(
            "fast-downward: plan %d: %s",
            self.plans,
            " ".join(f"{n}({','.join(a)})" for n, a in self._plan),
        )

    def _forget(self, kb: KnowledgeBase) -> bool:
        """Set the sampled fluents of every grounding that does not mention where the
        robot is back to the instance's initial values; whether anything changed."""
        assert self.session is not None
        model = self.session.model
        obs_facts = kb.facts()
        here = {
            args[-1]
            for (name, args), value in obs_facts.items()
            if value is True and name in self._locations
        }
        updates = []
        for (name, args), value in obs_facts.items():
            if name not in self._sampled or here & set(args):
                continue
            start = model.init_state.get((name, args), model.default_of(name))
            if start != value:
                updates.append(Update("set", name, args, start))
        if not updates:
            return False
        kb.apply(updates, "forget")
        return True

    def _rddl_action(self, name: str, args: Sequence[str]) -> tuple[str, tuple[str, ...]]:
        # copies of an operator: <op>__o<i>_<j> (all-outcomes), <op>__c<cost> (groundings
        # that cost differently)
        base = _COPY_SUFFIX.sub("", name)
        if base not in self._actions:
            raise PlannerError(f"Fast Downward's plan has {name!r}, which is no action fluent")
        try:
            objs = tuple(self._objects[a] for a in args)
        except KeyError as err:
            raise PlannerError(f"Fast Downward's plan names an unknown object {err}") from None
        return self._actions[base], objs

    def _predict(self, state: State, plan: list[tuple[str, tuple[str, ...]]]) -> list[State]:
        """The state after each step of `plan`, the sampled fluents held."""
        assert self.session is not None
        sim = self.session.simulator
        rng = np.random.default_rng(0)
        out, s = [], state
        for name, args in plan:
            actions = sim.actions_from_names({(name, args): True})
            nxt = sim.step(s, actions, rng, check=False).next_state
            values = dict(nxt.values)
            for f in self._sampled:
                values[f] = state.values[f].copy()
            s = State(values)
            out.append(s)
        return out

    def _as_expected(self, observed: State, expected: State) -> bool:
        return all(
            np.array_equal(np.asarray(observed.values[f]), np.asarray(expected.values[f]))
            for f in self._decided
        )

    def end_session(self, total_reward: float) -> None:
        log.info(
            "fast-downward: %d plans (%d after a failed action), %.3f s planning",
            self.plans,
            self.replans,
            self.planning_seconds,
        )
