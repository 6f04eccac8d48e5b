"""`MCTSPlanner`: the session, the turn, the roots (reused subtrees, the
transposition table, the POMDP belief) and the waves of trials that grow
the search graph (see the package docstring).

Calls the other modules of the package: `tree` for selection, backups
and the final choice, `rollouts` to expand new leaves, `actions` for
candidates and rollout actions.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import threading
import time
from typing import Any, ClassVar

import numpy as np

from ...rddl.model import Model
from ...rddl.sim.cstep import CUnavailable
from ...rddl.sim.scalar import ScalarStep, ScalarUnsupported
from ...rddl.simulator import SimulationError, Simulator, State
from ...rddl.wire import WireCodec, WireError
from ..base import Observation, Planner, PlannerError, SessionInfo, WireFluent
from ..budget import Background, guarded_turn, noop_legal
from .actions import ActionChooser, ActionLibrary, _row_keys
from .ckernels import Kernels
from .ctree import attach
from .deadline import Deadline
from .heuristic import IDS, RewardLocks, training_states
from .options import OPTIONS, Settings, read_settings
from .relevance import removable_inert, useless_actions
from .rollouts import Expander, _stack_states
from .startup import ENUM_SECONDS, IDS_SECONDS, Budgets, warm_up
from .stats import SearchStats
from .thts import THTS
from .tree import _Node, _Outcome, _Trial, backup, best, refresh, select

log = logging.getLogger(__name__)

Array = np.ndarray


class MCTSPlanner(Planner):
    """Trial-based tree search: the `thts` engine on the scalar step, else
    the `wave` search over the batched simulator (see the package docstring)."""

    name: ClassVar[str] = "mcts"
    options: ClassVar[dict[str, str]] = OPTIONS

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self.settings: Settings = read_settings(self)
        """The options, typed (a session lowers batch, max_actions and max_nodes to its
        memory budget: `budgets`)."""
        self._asked = self.settings
        self.budgets: Budgets | None = None
        """The last session's start-up allowance and memory sizing (options startup, memory)."""
        self.stats = SearchStats()
        """Counters over the whole session."""
        self.last_turn = SearchStats()
        """Counters of the last turn."""
        self.rng = np.random.default_rng(self.settings.seed)
        self._sim: Simulator | None = None
        self._model: Model | None = None
        self._codec: WireCodec | None = None
        self._chooser: ActionChooser | None = None
        self._expander: Expander | None = None
        self._state_names: list[str] = []
        self._root: _Node | None = None
        self._last: tuple[_Node, int] | None = None  # (root, chosen candidate) of the last turn
        # decision nodes by steps left and state, when `transpositions`
        self._table: dict[int, dict[bytes, _Node]] = {}
        self._belief: State | None = None  # POMDP particles
        self._last_action: dict[str, Array] | None = None
        self._discrete_obs = True
        self._thts: THTS | None = None
        self.engine = "wave"
        """The search this session runs: thts, or wave (asked for, or the fallback)."""
        self.compiled = False
        """Whether the thts engine runs its step in C this session (option compiled)."""
        self._pending: Background[tuple[THTS, ActionChooser, Settings] | None] | None = None
        """The compiled engine being built while the wave engine plays (a late C build)."""
        self._ended = threading.Event()  # set at the session's end: no set-up after it

    @property
    def library(self) -> ActionLibrary | None:
        """Every joint action the search has considered (None before a session)."""
        return None if self._chooser is None else self._chooser.lib

    # -- session ------------------------------------------------------

    def start_session(self, session: SessionInfo) -> None:
        super().start_session(session)
        seed = self.settings.seed if self.settings.seed is not None else session.seed
        self.rng = np.random.default_rng(seed)
        sim = self._sim = session.simulator
        self._model = session.model
        self._codec = WireCodec(sim)
        budgets = self.budgets = Budgets(self, session)
        self.settings = self._asked
        self._chooser = ActionChooser(sim, self.settings, self.rng)
        self._state_names = [p.name for p in sim.state_fluents]
        self._discrete_obs = all(p.range != "real" for p in sim.observ_fluents)
        self.stats = SearchStats()
        self._thts = None
        self._expander = None
        self.engine = "wave"
        self.compiled = False
        scalar = None
        if self.settings.engine == "thts":
            try:
                scalar = budgets.within(
                    "translating the instance into the scalar step",
                    lambda: ScalarStep(sim),
                    None,
                    "the wave engine",
                )
            except ScalarUnsupported as err:
                log.info("mcts: %s: no scalar step (%s); the wave search", session.instance, err)
        self._ended.set()  # (an earlier session's set-up, if any, is not wanted)
        self._pending, self._ended = None, threading.Event()
        if scalar is not None:
            self.settings = budgets.size_thts(sim, self._asked)
            self._thts = self._start_thts(session, scalar, seed)
        if self._thts is None:
            self.settings = self._chooser.settings = budgets.size_wave(sim, self._asked)
            if budgets.fits("warming up the batched step", 1.0, "the first turn compiles it"):
                warm_up(sim, self.settings.batch)
            ids, locks = budgets.heuristic(self.settings, lambda: self._heuristic(session))
            self._expander = Expander(sim, self._chooser, self.settings, self.rng, ids, locks)
        else:
            self.engine = "thts"
        log.info(
            "mcts: %s, %s, engine %s%s, seed %s",
            session.instance,
            self._chooser.describe(),
            self.engine,
            " (compiled step)" if self.compiled else "",
            seed,
        )

    def _start_thts(
        self, session: SessionInfo, scalar: ScalarStep, seed: int | None
    ) -> THTS | None:
        """The one place that decides the engine of a session with a scalar
        step: the `thts` engine (the C step with the search; None: the wave
        engine) where its build ends within the wait (`Budgets.compile_wait`);
        else the wave engine, for the session where there is no C step (no
        compiler, a failed build, `compiled=no`, `reward_locks`), and until the
        first turn after the build has ended where it is only late (`_switch`;
        docs/architecture.md, "mcts: one search engine")."""
        st = self.settings
        assert self.budgets is not None
        budgets = self.budgets
        if st.reward_locks:
            log.info(
                "mcts: %s: reward_locks: the wave engine (thts has no reward-lock check)",
                session.instance,
            )
            return None
        if st.compiled == "no":
            log.info("mcts: %s: compiled=no: the wave engine", session.instance)
            return None
        build = budgets.start_compile(scalar)
        if not build.wait(budgets.compile_wait(st)):
            what, why = "waiting for the C step's build", f"not built after {build.seconds():.2f} s"
            if st.compiled == "yes":
                raise PlannerError(
                    f"mcts: compiled=yes, but the C step is not built within the start-up "
                    f"allowance of {budgets.startup.seconds:g} s (option startup)"
                )
            if st.iterations is not None:
                budgets.startup.skip(what, f"{why}; the wave engine for the session (iterations)")
                return None
            budgets.startup.skip(
                what, f"{why}; the wave engine until it is, then the compiled engine (thts)"
            )
            ended = self._ended

            def later() -> tuple[THTS, ActionChooser, Settings] | None:
                kernels = build.result()
                if ended.is_set():
                    return None  # the session is over: no set-up
                fresh = budgets.afresh()  # (its allowance starts now)
                return *self._setup_thts(session, scalar, seed, st, kernels, fresh), st

            self._pending = Background("mcts: the compiled engine's set-up", later)
            return None
        try:
            kernels = build.result()
        except CUnavailable as err:
            if st.compiled == "yes":
                raise PlannerError(f"mcts: compiled=yes, but no C step: {err}") from None
            log.warning("mcts: %s: no C step (%s); the wave engine", session.instance, err)
            return None
        search, self._chooser = self._setup_thts(session, scalar, seed, st, kernels, budgets)
        self.compiled = True
        return search

    def _switch(self, turn: int) -> None:
        """From the first turn after a late C build and the compiled engine's
        set-up have ended (and no late wave turn still runs): the compiled
        engine. A build or set-up that failed leaves the wave engine."""
        pending = self._pending
        assert pending is not None and self.budgets is not None and self.session is not None
        if not pending.done() or self.budgets.turns.busy():
            return
        self._pending = None
        instance = self.session.instance
        try:
            built = pending.result()
        except Exception as err:  # noqa: BLE001 - CUnavailable, or a set-up that failed
            log.warning(
                "mcts: %s: no compiled engine (%s: %s); the wave engine for the session",
                instance,
                type(err).__name__,
                err,
            )
            return
        assert built is not None
        self._thts, self._chooser, self.settings = built
        self.engine, self.compiled = "thts", True
        self._expander, self._table, self._root, self._last = None, {}, None, None
        log.info(
            "mcts: %s: the C step is built (%.2f s after the session's start): the compiled "
            "engine (thts) from turn %d on",
            instance,
            self.budgets.startup.spent(),
            turn,
        )

    def _setup_thts(
        self,
        session: SessionInfo,
        scalar: ScalarStep,
        seed: int | None,
        st: Settings,
        cstep: Kernels,
        budgets: Budgets,
    ) -> tuple[THTS, ActionChooser]:
        """The `thts` engine over the built C step `cstep`, its chooser and
        settings: the candidates, and IDS's depth (fixed, or learned on
        random-walk states with their own generator, so the search's draws
        stay those of the seed), each within `budgets`' start-up allowance."""
        sim = session.simulator
        # Equivalent actions are pruned in every new node, so the candidates
        # are the legal joint actions up to 8 x max_actions (TriangleTireworld
        # #5 has 813, of which a state keeps a handful) before a sample.
        chooser = ActionChooser(
            sim,
            dataclasses.replace(st, max_actions=8 * st.max_actions),
            self.rng,
            inert=self._skipped(session, scalar, budgets),
        )
        search = THTS(sim, scalar, chooser, st, self.rng, self._discount(), cstep)
        # random-walk states (their own generator: the search's draws stay those of
        # the seed) to check the legal actions in C on and to learn IDS's depth on
        states: list[tuple[Any, ...]] = []
        if (st.heuristic == "ids" or not search._static) and budgets.fits(
            "random-walk states (to check the legal actions in C on, to learn IDS on)",
            ENUM_SECONDS + IDS_SECONDS,
            "the Python solver's candidates",
        ):
            rng = np.random.default_rng(None if seed is None else [seed, 1])
            train = training_states(sim, rng)
            states = [scalar.encode_state(train, i) for i in range(min(train.batch, 16))]
        if states and not budgets.fits(
            "checking the legal actions in C", ENUM_SECONDS, "the Python solver's candidates"
        ):
            states = []
        if search.setup_enum(states):
            log.info("mcts: %s: the legal actions of a state in C", session.instance)
        if st.heuristic == "ids":
            fixed = st.ids_depth or (5 if st.iterations is not None else 0)
            if fixed:
                search.ids_depth = fixed
            elif budgets.fits("learning IDS's depth", IDS_SECONDS, "roll-outs, no IDS"):
                walked = states

                def learn() -> int:
                    # (the depth that first takes too long is searched to its end: on
                    # HVAC 2023 #7 over 100 s, hence the worker thread and its deadline)
                    learning = walked
                    if not learning:
                        rng = np.random.default_rng(None if seed is None else [seed, 1])
                        train = training_states(sim, rng)
                        n = min(train.batch, 16)
                        learning = [scalar.encode_state(train, i) for i in range(n)]
                    return search.learn_ids(learning, session.model.horizon or 40, st.ids_timeout)

                depth = budgets.within("learning IDS's depth", learn, 0, "roll-outs, no IDS")
                search.ids_depth = depth
                log.info("mcts: %s: IDS depth %d", session.instance, depth)
        if attach(search):
            log.info("mcts: %s: the trials in C", session.instance)
        return search, chooser

    def _skipped(
        self, session: SessionInfo, scalar: ScalarStep, budgets: Budgets | None = None
    ) -> list[tuple[str, tuple[int, ...]]]:
        """The action groundings the thts search leaves at their default: those
        the step never reads, and with `prune_useless` those that can never pay
        (`relevance.useless_actions`, within `budgets`, else the session's)."""
        skipped = removable_inert(scalar)  # (those the constraints allow at their default)
        budgets = budgets or self.budgets
        if self._asked.prune_useless:
            assert budgets is not None
            useless: list[tuple[str, tuple[int, ...]]] = budgets.within(
                "the relevance analysis (prune_useless)",
                lambda: useless_actions(scalar),
                [],
                "every action grounding kept",
            )
            if useless:
                log.info(
                    "mcts: %s: %d of %d action groundings can never pay: left out",
                    session.instance,
                    len(useless),
                    len(scalar.action_keys),
                )
            skipped.extend(useless)
        return skipped

    def _heuristic(self, session: SessionInfo) -> tuple[IDS | None, RewardLocks | None]:
        """IDS (learned on random-walk states, PROST's learning phase) and
        the reward-lock check, as the options ask. Their own generator:
        the search's draws stay those of the seed."""
        st = self.settings
        if st.heuristic != "ids" and not st.reward_locks:
            return None, None
        sim = session.simulator
        seed = st.seed if st.seed is not None else session.seed
        rng = np.random.default_rng(None if seed is None else [seed, 1])
        ids: IDS | None = None
        try:
            ids = IDS.for_model(
                session.model,
                enumerate_limit=st.enumerate_limit,
                timeout=st.ids_timeout,
                clock=time.monotonic,
            )
            fixed = st.ids_depth or (5 if st.iterations is not None else 0)
            if st.heuristic == "ids" and fixed:
                # no learning: the depth does not depend on the machine's speed
                ids.max_depth = fixed
                ids.learned = True
            elif st.heuristic == "ids":
                n_acts = 1 if ids.table is None else len(next(iter(ids.table.values()), [0]))
                # the leaves of a wave are searched together: learn in groups as big
                group = max(1, min(32, st.batch // max(1, n_acts * st.rollouts * st.modes)))
                train = training_states(sim, rng)
                steps = session.model.horizon or 40
                # compile the determinised simulator's functions before they are timed
                depth, ids.max_depth = ids.max_depth, 2
                ids.estimate(
                    train, [steps] * train.batch, [ids.legal_table(train[0])] * train.batch
                )
                ids.max_depth = depth
                ids.learn(train, steps=steps, batch=group)
        except SimulationError as err:
            log.warning(
                "mcts: no IDS heuristic for %s (%s); rollouts instead", session.instance, err
            )
            ids = None
        locks = None
        if st.reward_locks and ids is not None and ids.table is not None:
            locks = RewardLocks(session.model, ids.table)
        if st.heuristic != "ids":
            ids = None
        return ids, locks

    def start_round(self, round_num: int) -> None:
        if self._thts is not None:
            self._thts.start_round()
        self._table = {}
        self._root = None
        self._last = None
        self._belief = None
        self._last_action = None

    def end_round(self, reward: float) -> None:
        log.info(
            "mcts: round reward %s; %d turns so far, %.0f simulated steps/s",
            reward,
            self.stats.turns,
            self.stats.steps_per_second,
        )

    def end_session(self, total_reward: float) -> None:
        self._ended.set()
        self._pending = None
        if self._thts is not None:
            gc.unfreeze()
        s = self.stats
        log.info(
            "mcts: session reward %s; %d turns, %d waves, %d trials, %d leaves, %d simulated "
            "steps in %.1f s (%.0f steps/s)",
            total_reward,
            s.turns,
            s.waves,
            s.trials,
            s.leaves,
            s.sim_steps,
            s.seconds,
            s.steps_per_second,
        )

    # -- a turn --------------------------------------------------------

    def act(self, obs: Observation) -> list[WireFluent]:
        if self._pending is not None:
            self._switch(obs.turn)
        # a turn in a worker thread (but the C tree's, which keeps its deadline): one
        # that runs past it (a slow root expansion) sends noop and finishes in the
        # background
        if self.settings.iterations is not None or self.budgets is None or self.compiled:
            return self._act(obs)
        deadline = obs.deadline
        if self.settings.time_per_step is not None:
            deadline = min(time.monotonic() + self.settings.time_per_step, obs.deadline)
        assert self._sim is not None
        return guarded_turn(
            self.budgets.turns,
            "mcts",
            obs.turn,
            deadline,
            lambda: self._act(obs),
            noop_legal(self._sim, obs.state),
        )

    def _act(self, obs: Observation) -> list[WireFluent]:
        if (
            self._sim is None
            or self._chooser is None
            or self._codec is None
            or self.session is None
        ):
            raise PlannerError("mcts: act() called before start_session()")
        st = self.settings
        started = time.monotonic()
        deadline = obs.deadline
        if st.time_per_step is not None:
            # never past the session's own budget either
            deadline = min(started + st.time_per_step, obs.deadline)
        turn = SearchStats(turns=1)
        lookahead = obs.steps_left if st.depth == 0 else min(st.depth, obs.steps_left)
        if self._thts is not None and obs.state is not None:
            return self._act_thts(obs, lookahead, started, deadline, turn)
        root, reused = self._make_root(obs, lookahead)
        turn.reused = int(reused)
        clock = Deadline(None if st.iterations is not None else deadline)
        # The cyclic collector's full passes walk the whole search graph (a
        # pause of a second on a big tree): none during the turn. The graph
        # holds no cycles, so reference counting frees what it drops; the
        # collector runs again between turns.
        collecting = gc.isenabled()
        gc.disable()
        try:
            if not root.expanded:
                self._expand([root], turn, clock)
            if len(root.acts) > 1:
                self._search(root, clock, turn)
                refresh(root, self._discount(), st.init_weight, st.bellman_outcomes)
        except SimulationError as err:
            # A model the search cannot simulate (e.g. a distribution given bad
            # parameters by some action) must not end the session: act on what
            # is known.
            log.warning("mcts: search stopped at turn %d: %s", obs.turn, err)
        finally:
            if collecting:
                gc.enable()
        if len(root.acts) == 0:
            log.warning(
                "mcts: turn %d: no legal joint action in this state; sending noop", obs.turn
            )
        choice = best(root)
        row = int(root.acts[choice]) if len(root.acts) else 0
        actions = self._chooser.lib.take(np.array([row]))
        self._last = (root, choice) if len(root.acts) else None
        self._last_action = actions
        self._root = root
        turn.seconds = time.monotonic() - started
        self.last_turn = turn
        self.stats.add(turn)
        if log.isEnabledFor(logging.DEBUG):
            q = root.qv
            log.debug(
                "mcts: turn %d (%d steps left): %d waves, %d trials, %d steps in %.3f s "
                "(%.0f steps/s); value %.3f; chose %s",
                obs.turn,
                obs.steps_left,
                turn.waves,
                turn.trials,
                turn.sim_steps,
                turn.seconds,
                turn.steps_per_second,
                float(q[choice]) if len(q) else 0.0,
                ", ".join(self._sim.actions_to_names(actions)) or "noop",
            )
        return self._codec.actions(actions, index=0)

    def _act_thts(
        self,
        obs: Observation,
        lookahead: int,
        started: float,
        deadline: float,
        turn: SearchStats,
    ) -> list[WireFluent]:
        """A turn of the `thts` engine (see `thts.py`)."""
        search = self._thts
        assert search is not None and obs.state is not None and self._codec is not None
        assert self._chooser is not None
        state = search.fast.encode_state(obs.state)
        root = search.root(state, lookahead)
        turn.reused = int(root.expanded)
        # (a margin for sending the action: the search stops a little early)
        stop = None if self.settings.iterations is not None else deadline - 0.002
        collecting = gc.isenabled()
        gc.disable()
        try:
            search.search(root, stop, self.settings.iterations, turn)
        finally:
            if collecting:
                # The search graph (acyclic: reference counting frees what
                # it drops) moves to the collector's permanent generation, so
                # that no full pass over it falls inside a later turn.
                gc.freeze()
                gc.enable()
        choice = search.best(root)
        row = root.rows[choice] if choice >= 0 else 0
        if choice < 0:
            log.warning(
                "mcts: turn %d: no legal joint action in this state; sending noop", obs.turn
            )
        actions = self._chooser.lib.take(np.array([row]))
        self._last_action = actions
        turn.seconds = time.monotonic() - started
        self.last_turn = turn
        self.stats.add(turn)
        if log.isEnabledFor(logging.DEBUG):
            log.debug(
                "mcts: turn %d (%d steps left): %d trials, %d leaves, %d steps in %.3f s; "
                "value %.3f%s; chose %s",
                obs.turn,
                obs.steps_left,
                turn.trials,
                turn.leaves,
                turn.sim_steps,
                turn.seconds,
                root.value,
                " (solved)" if root.solved else "",
                ", ".join(self._sim.actions_to_names(actions)) if self._sim else "",
            )
        return self._codec.actions(actions, index=0)

    def _expand(
        self, leaves: list[_Node], turn: SearchStats, clock: Deadline | None = None
    ) -> None:
        assert self._expander is not None
        self._expander.expand(leaves, turn, self._discount(), clock)

    def _discount(self) -> float:
        assert self._model is not None
        d = self._model.discount
        return 1.0 if d is None else float(d)

    # -- roots -----------------------------------------------------------

    def _make_root(self, obs: Observation, lookahead: int) -> tuple[_Node, bool]:
        """The root of this turn's search and whether it is reused: the
        subtree when the tree has the observed successor of the last turn's
        choice (with the same steps left), else a new node."""
        assert self._sim is not None
        if obs.state is None:
            states = self._believe(obs)
            return _Node(None, states, lookahead, False), False
        key = self._state_keys(obs.state)[0]
        if self.settings.transpositions:
            # nodes further from the end than the root are out of reach
            for steps in [k for k in self._table if k > lookahead]:
                del self._table[steps]
            if sum(len(bucket) for bucket in self._table.values()) > self.settings.max_nodes:
                self._table = {}
            bucket = self._table.setdefault(lookahead, {})
            node = bucket.get(key)
            if node is not None and not node.terminal:
                node.states = obs.state
                return node, node.expanded
            node = bucket[key] = _Node(key, obs.state, lookahead, False)
            return node, False
        if self._last is not None:
            node, choice = self._last
            outcome = node.children[choice].get(key) if node.children else None
            if (
                outcome is not None
                and outcome.node.steps == lookahead
                and not outcome.node.terminal
            ):
                child = outcome.node
                child.states = obs.state
                return child, True
        return _Node(key, obs.state, lookahead, False), False

    def _believe(self, obs: Observation) -> State:
        """The POMDP particles for this turn (see the module docstring)."""
        assert self._sim is not None and self._codec is not None
        sim = self._sim
        if obs.turn <= 1 or self._belief is None or self._last_action is None:
            self._belief = sim.initial_state(self.settings.particles)
            return self._belief
        n = self._belief.batch
        acts = {k: np.repeat(v, n, axis=0) for k, v in self._last_action.items()}
        try:
            out = sim.step(self._belief, acts, self.rng, check=False)
        except SimulationError as err:
            log.warning("mcts: belief update failed (%s); back to the initial state", err)
            self._belief = sim.initial_state(self.settings.particles)
            return self._belief
        nxt = out.next_state
        if obs.fluents is not None and out.observation is not None and self._discrete_obs:
            try:
                seen = self._codec.observation_from(
                    (n_, a, v) for (n_, a), v in obs.fluents.items()
                )
            except WireError as err:
                log.warning("mcts: cannot read the observation: %s", err)
                seen = None
            if seen is not None:
                match = np.ones(n, dtype=bool)
                for name, arr in seen.items():
                    sim_obs = out.observation[name].reshape(n, -1)
                    match &= (sim_obs == arr.reshape(1, -1)).all(axis=1)
                if match.any():
                    keep = np.flatnonzero(match)
                    nxt = nxt[self.rng.choice(keep, self.settings.particles)]
                else:
                    log.debug("mcts: no particle explains the observation; keeping them all")
        self._belief = nxt
        return nxt

    # -- search ----------------------------------------------------------

    def _state_keys(self, states: State) -> list[bytes]:
        return _row_keys([states.values[k] for k in self._state_names], states.batch)

    def _search(self, root: _Node, clock: Deadline, turn: SearchStats) -> None:
        """Waves of trials until the deadline (or `iterations` waves)."""
        n_acts = max(1, len(root.acts))
        trials = max(
            1, self.settings.batch // (n_acts * self.settings.rollouts * self.settings.modes)
        )
        iterations = self.settings.iterations
        nodes = sum(len(bucket) for bucket in self._table.values())
        waves = 0
        wave_time = 0.0
        while True:
            size = trials
            if iterations is not None:
                if waves >= iterations:
                    break
            elif waves > 0:
                # A wave cut short by the deadline leaves its leaves with
                # rollouts cut short too (their estimates extrapolated from a
                # step or two): start only what is likely to finish, a
                # smaller wave when the time left is less than a whole one.
                left = clock.left() - clock.reserve
                if left < 0.25 * wave_time or clock.passed(2.0):
                    break
                if left < wave_time:
                    size = max(1, int(trials * left / wave_time))
            t0 = time.monotonic()
            self._wave(root, size, turn, clock)
            waves += 1
            if self.budgets is not None and self.budgets.tree_full(
                nodes, turn, self.settings.max_nodes
            ):
                break
            took = time.monotonic() - t0
            if size == trials:
                # the slower of the last whole wave and a decaying average
                wave_time = max(took, 0.7 * wave_time + 0.3 * took)
        turn.waves += waves

    def _wave(self, root: _Node, n_trials: int, turn: SearchStats, clock: Deadline) -> None:
        """Descend `n_trials` trials together, expand their new leaves in one
        batch and back the values up. Near the deadline the descent stops
        (each trial backs up the value of the node it reached) and the
        rollouts are cut short."""
        assert self._sim is not None and self.library is not None and root.states is not None
        sim = self._sim
        rows = (
            self.rng.integers(0, root.states.batch, n_trials)
            if root.states.batch > 1
            else np.zeros(n_trials, dtype=np.int64)
        )
        states = root.states[rows]
        trials = [_Trial([], root, int(r)) for r in rows]
        active = list(range(n_trials))
        touched: list[_Node] = []
        st = self.settings
        levels = [0] * n_trials  # levels each trial has descended
        phases = st.new_nodes or st.trial_depth or (root.steps + 1)
        for phase in range(phases):
            leaves: dict[int, _Node] = {}
            stopped: list[int] = []  # trials that stopped at a new leaf
            first = True
            while active:
                clock.tick()
                if (phase > 0 or not first) and clock.passed():
                    break
                first = False
                choices = []
                acts = np.empty(len(active), dtype=np.int64)
                for j, i in enumerate(active):
                    node = trials[i].node
                    if not any(node.pending):
                        touched.append(node)
                    a = select(node, st.exploration, st.init_weight)
                    choices.append(a)
                    acts[j] = node.acts[a]
                out = sim.step(states, self.library.take(acts), self.rng, check=False)
                turn.sim_steps += len(active)
                turn.sim_calls += 1
                keys = self._state_keys(out.next_state)
                reward = out.reward.tolist()
                done = out.done.tolist()
                going: list[int] = []
                going_rows: list[int] = []
                for j, i in enumerate(active):
                    trial = trials[i]
                    node = trial.node
                    a = choices[j]
                    outcomes = node.children[a]
                    outcome = outcomes.get(keys[j])
                    if outcome is None:
                        outcome = outcomes[keys[j]] = _Outcome(
                            self._node(keys[j], out.next_state, j, node.steps - 1, bool(done[j]))
                        )
                    trial.path.append((node, a, outcome, float(reward[j])))
                    child = outcome.node
                    trial.node = child
                    levels[i] += 1
                    if child.terminal:
                        continue
                    if not child.expanded:
                        leaves[id(child)] = child
                        stopped.append(i)
                        continue
                    if levels[i] == st.trial_depth:
                        continue  # backs up the value the node has
                    going.append(i)
                    going_rows.append(j)
                active = going
                if going:
                    states = out.next_state[np.asarray(going_rows)]
            if not leaves:
                break
            clock.restart()
            t0 = time.monotonic()
            self._expand(list(leaves.values()), turn, clock)
            expanding = time.monotonic() - t0
            # (with `new_nodes` above 1) the trials go on below the leaves
            # they stopped at, now expanded, as PROST's trials do through
            # that many new decision nodes
            active = [
                i for i in stopped if not trials[i].node.terminal and levels[i] != st.trial_depth
            ]
            # another phase only if its expansion is likely to end in time:
            # one cut short leaves its leaves with rollouts of a step or two
            if not active or phase + 1 == phases or clock.left() < 2.0 * expanding:
                break
            states = _stack_states([trials[i].node.states for i in active], self._state_names)
        for node in touched:
            node.pending = [0] * len(node.pending)
        gamma = self._discount()
        t0 = time.monotonic()
        for trial in trials:
            backup(trial, gamma, st.init_weight, st.bellman_outcomes)
        clock.reserve = time.monotonic() - t0
        clock.restart()
        turn.trials += n_trials

    def _node(self, key: bytes, states: State, row: int, steps: int, done: bool) -> _Node:
        """The decision node of a sampled successor: the one the table has
        for this state and steps left, else a new one."""
        if not self.settings.transpositions:
            return _Node(key, states[row], steps, done)
        bucket = self._table.get(steps)
        if bucket is None:
            bucket = self._table[steps] = {}
        node = bucket.get(key)
        if node is None:
            node = bucket[key] = _Node(key, states[row], steps, done)
        return node
