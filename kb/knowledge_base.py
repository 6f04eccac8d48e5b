"""The knowledge base: an RDDL instance's domain and its current state.

`KnowledgeBase.from_files(domain, instance)` loads a domain and an
instance through `ippc.rddl` and answers ROSPlan's knowledge-base services
under their names (`domain_name`, `types`, `predicates`, `functions`,
`operators`, `operator`, `goal`, `metric`, `instances`, `enum_values`, the
RDDL parameters, `immediate_reward`), and keeps the state: every grounding
of every state fluent and non-fluent, closed world (a false fact is stored
as false), changed by batches of updates that are applied atomically (a
batch is validated whole, values and the domain's state invariants, before
anything is written), with subscribers told of every change and of who
made it. The goal is the domain's, or one set at run time (`set_goal`,
`add_goal`, `remove_goal`, `reset_goal`, as ROSPlan's goal updates);
journal subscribers see every applied batch and goal change as plain data,
and `restore` loads a saved state back (`ippc.kb.journal`).

Threads: every public method takes one lock, so sensing threads, a server
and the dispatcher may share one knowledge base. Subscribers are called
after the lock is released, in the thread that applied the batch, in the
order they subscribed; one that raises is logged and the others still run.
Journal subscribers are called under the lock, so they see the batches in
the order they were applied.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..rddl import ast as A
from ..rddl.loader import load_pair
from ..rddl.model import ACTION, NON_FLUENT, STATE, GroundKey, Model, PVariable, Value
from ..rddl.simulator import SimulationError, Simulator, State
from ..rddl.writer import write, write_expr
from .evaluate import Evaluator, NotEvaluable
from .goal import RUNTIME, Goal, GoalFact, GoalSource, find_goal, ground_goal
from .invariants import Invariants, Violation
from .journal import fact_updates
from .metric import expression_tree
from .operators import Operator, Parameter, parameter_names, translate
from .pddl import to_pddl
from .rddl_instance import rddl_instance
from .report import Unsupported
from .runtime_goals import GoalFacts, GoalSubscriber, RuntimeGoals
from .store import Change, KBError, Store, Update

log = logging.getLogger(__name__)

Subscriber = Callable[[list[Change], str], None]
JournalSubscriber = Callable[[dict[str, Any]], None]


class InvariantError(KBError):
    """A batch refused because the state after it would break a state
    invariant; `violations` names each invariant and grounding."""

    def __init__(self, message: str, violations: Sequence[Violation]):
        super().__init__(message, "invariant")
        self.violations = list(violations)


class KnowledgeBase(RuntimeGoals):
    """The symbolic state of one RDDL instance, with ROSPlan's queries."""

    def __init__(self, model: Model):
        self.model = model
        self._lock = threading.RLock()
        self._store = Store(model)
        self._subscribers: list[Subscriber] = []
        self._sensed: set[str] = set()
        self._horizon = model.horizon
        # one more at every change of state, goal, parameters or sensed
        # flags: the key of the generated problems' cache
        self._generation = 0
        self._generated: dict[tuple[Any, ...], Any] = {}
        self._discount = model.discount
        self._max_nondef = model.max_nondef_actions
        self._evaluator = Evaluator(model, self._store.get, self._store.pvars.__contains__)
        self._goal_source: GoalSource | None = find_goal(model)
        self._goal: Goal | None = None  # grounded on first use, again after non-fluents change
        self._simulator: Simulator | None = None  # built on first use, for R(s, a)
        self._term_simulators: dict[str, Simulator] = {}  # reward term -> its simulator
        self._operators, self._unsupported = translate(model)
        for u in self._unsupported:
            log.info("%s: not in operator form: %s", model.domain_name, u)
        self._runtime_goal: tuple[GoalFact, ...] | None = None  # None: the domain's goal
        self._goal_version = 0
        self._goal_subscribers: list[GoalSubscriber] = []
        self._journal: list[JournalSubscriber] = []
        self._seq = 0  # journal entries so far
        self._invariants = Invariants(model, self._store.pvars.__contains__, self._store.get)
        for v in self._invariants.violated(self._store.get):
            log.warning("%s: the initial state breaks a %s", model.name, v)

    # ---------------------------------------------------------------- loading

    @classmethod
    def from_files(cls, domain: str | Path, instance: str | Path) -> KnowledgeBase:
        """Load `domain` and `instance` (one instance in the file) through
        `ippc.rddl`; an error in either raises `RDDLError` with every
        problem found, by file, line and column."""
        return cls(load_pair(domain, instance))

    @classmethod
    def from_model(cls, model: Model) -> KnowledgeBase:
        """A knowledge base whose state starts at the model's initial state."""
        return cls(model)

    # ------------------------------------------------------- domain queries

    def domain_name(self) -> str:
        """The RDDL domain's name (ROSPlan's domain/name)."""
        return self.model.domain_name

    def types(self) -> list[dict[str, Any]]:
        """Every object and enum type with its super-type (ROSPlan's
        domain/types): {name, supertype ("object" at the top), kind, values
        (an enum's)}."""
        out = []
        for t in self.model.types.values():
            entry: dict[str, Any] = {
                "name": t.name,
                "supertype": t.parent or "object",
                "kind": t.kind,
            }
            if t.kind == "enum":
                entry["values"] = list(t.members)
            out.append(entry)
        return out

    def _signature(self, p: PVariable) -> dict[str, Any]:
        params = [
            Parameter(k, t).to_json()
            for k, t in zip(parameter_names(p.params), p.params, strict=True)
        ]
        return {
            "name": p.name,
            "parameters": params,
            "kind": p.kind,
            "type": p.range,
            "is_sensed": p.name in self._sensed,
        }

    def predicates(self) -> list[dict[str, Any]]:
        """Boolean state fluents and non-fluents with typed parameters and
        their sensed flag (ROSPlan's domain/predicates and predicate_details);
        `kind` tells a state fluent from a non-fluent, which ROSPlan lost."""
        with self._lock:
            return [self._signature(p) for p in self._store.pvars.values() if p.range == "bool"]

    def functions(self) -> list[dict[str, Any]]:
        """Numeric and enum state fluents and non-fluents (domain/functions)."""
        with self._lock:
            return [self._signature(p) for p in self._store.pvars.values() if p.range != "bool"]

    def fluent_type(self, fluent: str) -> str:
        """The value type of a pvariable: bool, int, real or a type name."""
        p = self.model.pvariables.get(fluent)
        if p is None:
            raise KBError(f"unknown fluent '{fluent}'", "unknown-fluent")
        return p.range

    def operators(self) -> list[Operator]:
        """One operator per action fluent, then the virtual `exogenous`
        operator (ROSPlan's domain/operators)."""
        return list(self._operators)

    def operator(self, name: str) -> Operator:
        """The operator of one action fluent, or `exogenous`
        (ROSPlan's domain/operator_details)."""
        for op in self._operators:
            if op.name == name:
                return op
        names = ", ".join(o.name for o in self._operators)
        raise KBError(f"no operator '{name}' (operators: {names})", "unknown-operator")

    def unsupported(self) -> list[Unsupported]:
        """Every part of the domain that the operators and the goal leave
        out, by construct and line (the planner still gets all of it)."""
        goal = self.goal()
        return [*self._unsupported, *(goal.unsupported if goal is not None else ())]

    def metric(self) -> dict[str, Any]:
        """The reward as the metric, maximised (ROSPlan's state/metric): its
        RDDL text and its expression tree with RDDL's own operators."""
        reward = self.model.reward
        return {
            "optimization": "maximize",
            "expression": None if reward is None else write_expr(reward),
            "tree": None if reward is None else expression_tree(reward),
        }

    def instances(self, type_name: str | None = None) -> list[str] | dict[str, list[str]]:
        """The objects of a type (its subtypes' included), or of every
        object type by name (ROSPlan's state/instances)."""
        if type_name is None:
            return {
                t.name: list(t.members) for t in self.model.types.values() if t.kind == "object"
            }
        info = self.model.types.get(type_name)
        if info is None or info.kind != "object":
            raise KBError(f"no object type '{type_name}'", "unknown-type")
        return list(info.members)

    def enum_values(self, type_name: str) -> list[str]:
        """The values of an enum type, "@name" (ROSPlan's domain/enumerable_type)."""
        info = self.model.types.get(type_name)
        if info is None or info.kind != "enum":
            raise KBError(f"no enum type '{type_name}'", "unknown-type")
        return list(info.members)

    # ------------------------------------------------------------------ state

    def get(self, fluent: str, args: Sequence[str] = ()) -> Value:
        """The value of `fluent(args)`: bool, int, float, or an enum value
        ("@name") or object name. KBError for an unknown fluent, a wrong
        number of arguments, or an object that is not of the parameter's type."""
        with self._lock:
            return self._store.get(fluent, tuple(args))

    def facts(
        self, fluent: str | None = None, *, non_fluents: bool = False
    ) -> dict[GroundKey, Value]:
        """Every grounding of `fluent`, or of every state fluent (and, with
        `non_fluents`, every non-fluent), with its value: false facts included."""
        with self._lock:
            st = self._store
            if fluent is not None:
                pvars = [st.pvar(fluent)]
            else:
                kinds = (STATE, NON_FLUENT) if non_fluents else (STATE,)
                pvars = [p for p in st.pvars.values() if p.kind in kinds]
            return {(p.name, args): v for p in pvars for args, v in st.items(p)}

    def is_state_fluent(self, fluent: str) -> bool:
        """Whether `fluent` is a state fluent (not a non-fluent); KBError if
        the knowledge base does not store it."""
        return self._store.pvar(fluent).kind == STATE

    def apply(
        self, updates: Iterable[Update], source: str, *, check_invariants: bool = True
    ) -> list[Change]:
        """Apply a batch of updates, all or nothing.

        A bad update raises KBError naming it (its position, its fluent and
        what is wrong: an unknown name, a value the fluent cannot hold, such
        as NaN or an int beyond 64 bits), and nothing changes. So does a
        batch after which the state would break one of the domain's state
        invariants that holds now (`InvariantError`, code "invariant",
        naming the invariant and its grounding), unless `check_invariants`
        is False (a tool that writes states no transition reaches). Returns
        the groundings whose value really changed (an update to the current
        value is no change); subscribers hear of the batch once, with
        `source`, if it changed anything. Changing a non-fluent is allowed
        (ROSPlan's clients fill distances in at start-up): the goal is
        grounded again."""
        with self._lock:
            writes = self._store.prepare(updates)
            if check_invariants:
                self._check_invariants(writes)
            changes = self._store.commit(writes)
            self._after_change(changes, source)
        self._notify(changes, source)
        return changes

    def _check_invariants(self, writes: list[Any]) -> None:
        """InvariantError when the state after `writes` breaks a state
        invariant that holds now (see `ippc.kb.invariants`)."""
        if not self._invariants:
            return
        written = {p.name for p, _, _ in writes}
        if not self._invariants.reads_any(written):
            return
        broken = self._invariants.broken(self._store.get, self._store.lookup_after(writes), written)
        if broken:
            raise InvariantError(
                "the batch would break the " + "; the ".join(str(v) for v in broken), broken
            )

    def check_invariants(self) -> list[Violation]:
        """The groundings of the state invariants that the current state
        breaks (at most 5; empty when it is a possible state)."""
        with self._lock:
            return self._invariants.violated(self._store.get)

    def subscribe(self, callback: Subscriber) -> Callable[[], None]:
        """Call `callback(changes, source)` after every batch that changed
        something; returns the function that unsubscribes it."""
        return self._listen(self._subscribers, callback)

    def _listen(self, listeners: list[Any], callback: Any) -> Callable[[], None]:
        with self._lock:
            listeners.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in listeners:
                    listeners.remove(callback)

        return unsubscribe

    def _notify(self, changes: list[Change], source: str) -> None:
        if not changes:
            return
        with self._lock:
            subscribers = list(self._subscribers)
        for cb in subscribers:
            try:
                cb(changes, source)
            except Exception:
                log.exception("knowledge-base subscriber %r failed on a change by %s", cb, source)

    def _after_change(self, changes: list[Change], source: str) -> None:
        """Under the lock, after a batch is written: caches, the journal."""
        if changes:
            self._changed()
        if any(self._store.pvars[c.fluent].kind == NON_FLUENT for c in changes):
            self._goal = None
            self._simulator = None  # it folds non-fluents into constants
            self._term_simulators = {}
        if changes:
            self._log({"source": source, "changes": [c.to_json() for c in changes]})

    # -- journal

    def subscribe_journal(self, callback: JournalSubscriber) -> Callable[[], None]:
        """Call `callback(entry)` for every applied batch that changed
        something and every goal change, with plain JSON-able data
        (`ippc.kb.journal` has the shapes): `{"seq", "source", "changes"}`
        or `{"seq", "source", "goal", "version"}`. It runs under the
        knowledge base's lock, so entries come in the order they happened:
        keep it short and never wait in it for another thread. Returns the
        function that unsubscribes it."""
        return self._listen(self._journal, callback)

    def _log(self, entry: dict[str, Any]) -> None:
        self._seq += 1
        entry = {"seq": self._seq, **entry}
        for cb in list(self._journal):
            try:
                cb(entry)
            except Exception:
                log.exception("knowledge-base journal subscriber %r failed", cb)

    def snapshot(self) -> dict[str, Any]:
        """The knowledge as plain data: `facts`, every grounding of every
        state fluent and the non-fluents that differ from the loaded files
        (`{"fluent", "args", "value"}`), and `goal`, the run-time goal's
        facts (None: the domain's own goal). What `restore` takes."""
        with self._lock:
            st = self._store
            facts: list[dict[str, Any]] = []
            for p in st.pvars.values():
                if p.kind == NON_FLUENT:
                    loaded = st.initial(p)
                    diff = np.argwhere(st.arrays[p.name] != loaded).tolist()
                    items = [
                        (st.args_of(p, tuple(i)), st.decode(p, st.arrays[p.name][tuple(i)]))
                        for i in diff
                    ]
                else:
                    items = list(st.items(p))
                facts.extend({"fluent": p.name, "args": list(a), "value": v} for a, v in items)
            goal = self._runtime_goal
            return {"facts": facts, "goal": None if goal is None else [f.to_json() for f in goal]}

    def restore(
        self, saved: Mapping[str, Any] | Iterable[Any], source: str = "restore"
    ) -> list[Change]:
        """Load saved knowledge in one atomic batch: a `snapshot()` (or a
        `journal.fold` of journal entries), or a list of facts
        (`{"fluent", "args", "value"}` or `(fluent, args, value)`). A
        "goal" key restores the goal too (None: the domain's). Checked as a
        whole before anything changes (KBError otherwise); subscribers and
        the journal hear of it as of any batch, with `source`. The changes."""
        has_goal = False
        goal_facts: tuple[GoalFact, ...] | None = None
        if isinstance(saved, Mapping):
            unknown = sorted(set(saved) - {"facts", "goal"})
            if unknown:
                raise KBError(
                    f"restore: unknown key(s) {', '.join(unknown)} (known: facts, goal)",
                    "bad-params",
                )
            facts = saved.get("facts") or []
            if "goal" in saved:
                has_goal = True
                if saved["goal"] is not None:
                    goal_facts = self._goal_facts(saved["goal"], allow_empty=True)
        else:
            facts = saved
        updates = fact_updates(facts)
        with self._lock:
            writes = self._store.prepare(updates)
            self._check_invariants(writes)
            changes = self._store.commit(writes)
            self._after_change(changes, source)
            goal = self._change_goal(goal_facts, source) if has_goal else None
        self._notify(changes, source)
        if has_goal:
            self._notify_goal(goal, source)
        return changes

    # -- sensed flags

    def set_sensed(self, fluent: str, sensed: bool = True) -> None:
        """Mark `fluent` as sensed (its value comes from sensing, so action
        handlers must not apply effects to it) or not."""
        with self._lock:
            p = self._store.pvar(fluent)
            if sensed:
                self._sensed.add(p.name)
            else:
                self._sensed.discard(p.name)
            self._changed()

    def is_sensed(self, fluent: str) -> bool:
        """Whether `fluent` is marked as sensed (KBError if unknown)."""
        with self._lock:
            return self._store.pvar(fluent).name in self._sensed

    def sensed_fluents(self) -> frozenset[str]:
        """The names of the fluents marked as sensed."""
        with self._lock:
            return frozenset(self._sensed)

    # -- bridges to the simulator

    def to_state(self) -> State:
        """The current state as a simulator `State` (a batch of one)."""
        with self._lock:
            return State(
                {p.name: self._store.arrays[p.name][None].copy() for p in self.model.fluents(STATE)}
            )

    def load_state(self, state: State, source: str) -> list[Change]:
        """Replace the state fluents by those of `state` (a batch of one, as
        the simulator makes it) in one batch; the changes."""
        if state.batch != 1:
            raise KBError(f"load_state takes a batch of one state, not {state.batch}", "bad-state")
        with self._lock:
            st = self._store
            new: dict[str, np.ndarray] = {}
            for p in self.model.fluents(STATE):
                if p.name not in state.values:
                    raise KBError(f"the state has no values for '{p.name}'", "bad-state")
                arr = np.asarray(state.values[p.name])[0]
                want = st.arrays[p.name]
                if arr.shape != want.shape:
                    raise KBError(
                        f"'{p.name}' has shape {arr.shape} in the state, not {want.shape}",
                        "bad-state",
                    )
                new[p.name] = arr.astype(want.dtype, copy=False)
            changes = st.replace(new)
            self._after_change(changes, source)
        self._notify(changes, source)
        return changes

    def to_model(self) -> Model:
        """The model of the current knowledge: the loaded model with the
        current non-fluent values, the current state as its initial state,
        and the current horizon, discount and max-nondef-actions."""
        with self._lock:
            st = self._store
            nf: dict[GroundKey, Value] = {}
            init: dict[GroundKey, Value] = {}
            for p in st.pvars.values():
                default = self.model.default_of(p)
                out = nf if p.kind == NON_FLUENT else init
                for args, v in st.items(p):
                    if v != default:
                        out[(p.name, args)] = v
            return dataclasses.replace(
                self.model,
                non_fluent_values=nf,
                init_state=init,
                horizon=self._horizon,
                discount=self._discount,
                max_nondef_actions=self._max_nondef,
            )

    # ------------------------------------------------------- RDDL parameters

    @property
    def horizon(self) -> int | None:
        """The horizon (None: unbounded, or rddlsim's terminate-when)."""
        return self._horizon

    @horizon.setter
    def horizon(self, value: int | None) -> None:
        if value is not None and (
            not isinstance(value, int) or isinstance(value, bool) or value < 1
        ):
            raise KBError(f"the horizon must be a positive integer, not {value!r}", "bad-value")
        self._horizon = value
        self._changed()

    @property
    def discount(self) -> float:
        """The discount factor."""
        return self._discount

    @discount.setter
    def discount(self, value: float) -> None:
        if (
            not isinstance(value, (int, float))
            or isinstance(value, bool)
            or not 0.0 <= float(value) <= 1.0
        ):
            raise KBError(f"the discount must be a number in [0, 1], not {value!r}", "bad-value")
        self._discount = float(value)
        self._changed()

    @property
    def max_nondef_actions(self) -> int | None:
        """How many actions may differ from their default per step (None: unbounded)."""
        return self._max_nondef

    @max_nondef_actions.setter
    def max_nondef_actions(self, value: int | None) -> None:
        if value is not None and (
            not isinstance(value, int) or isinstance(value, bool) or value < 1
        ):
            raise KBError(
                f"max-nondef-actions must be a positive integer or unbounded, not {value!r}",
                "bad-value",
            )
        self._max_nondef = value
        self._changed()

    # ------------------------------------------------------------------ goal

    def goal(self) -> Goal | None:
        """The goal (ROSPlan's state/goals): the ground facts it asks for on
        the current non-fluents, the lifted formula and what could not be
        put into facts; None when the domain has no goal."""
        with self._lock:
            if self._runtime_goal is not None:
                if not self._runtime_goal:
                    return None
                return Goal(None, None, RUNTIME, self._runtime_goal, (), self._goal_version)
            if self._goal_source is None:
                return None
            if self._goal is None or self._goal.version != self._goal_version:
                if self._goal is None:
                    self._goal = ground_goal(
                        self.model, self._goal_source, self._evaluator, self.is_state_fluent
                    )
                self._goal = dataclasses.replace(self._goal, version=self._goal_version)
            return self._goal

    def goal_holds(self) -> bool | None:
        """Whether the goal holds in the current state: the `goal` fluent is
        true, or its condition holds now (decided on the whole formula, not
        only the facts `goal()` lists). None when the domain has no goal."""
        with self._lock:
            if self._runtime_goal is not None:
                if not self._runtime_goal:
                    return None
                return all(self._fact_holds(f) for f in self._runtime_goal)
            where = self._goal_source
            if where is None:
                return None
            if where.fluent is not None and self._store.get(where.fluent) is True:
                return True
            if where.formula is None:
                return False
            try:
                return bool(self._evaluator(where.formula, {}))
            except NotEvaluable as err:
                raise KBError(f"the goal at {where.loc} cannot be decided: {err}") from None

    def _fact_holds(self, fact: GoalFact) -> bool:
        value = self._store.get(fact.fluent, fact.args)
        if isinstance(value, str) or isinstance(fact.value, str):
            return value == fact.value
        return float(value) == float(fact.value)

    # ---------------------------------------------------------------- reward

    def simulator(self) -> Simulator:
        """A simulator of the current non-fluents (built once, again after
        a non-fluent changes)."""
        with self._lock:
            if self._simulator is None:
                self._simulator = Simulator(self.to_model())
            return self._simulator

    def term_simulator(self, term: A.Expr) -> Simulator:
        """A simulator of the current non-fluents whose reward is `term`
        (one additive term of the reward, for PDDL action costs); cached."""
        key = write_expr(term)
        with self._lock:
            sim = self._term_simulators.get(key)
            if sim is None:
                model = self.to_model()
                model = dataclasses.replace(
                    model, domain=dataclasses.replace(model.domain, reward=term)
                )
                sim = self._term_simulators[key] = Simulator(model)
            return sim

    def parse_action(self, text: str) -> tuple[str, tuple[str, ...], Value]:
        """A grounded action written as ROSPlan's clients write it,
        "goto_waypoint(kenny, a, b)" (value true), or "name(args) = value"."""
        head, _, value_text = text.partition("=")
        head = head.strip()
        name, _, rest = head.partition("(")
        name = name.strip()
        args: tuple[str, ...] = ()
        if rest:
            if not rest.endswith(")"):
                raise KBError(f"bad action '{text}': expected name(arg, ...)", "bad-action")
            args = tuple(a.strip() for a in rest[:-1].split(",") if a.strip())
        p = self.model.pvariables.get(name)
        if p is None or p.kind != ACTION:
            raise KBError(f"'{name}' is not an action fluent (in '{text}')", "unknown-action")
        value: Value = True
        if value_text.strip():
            v = value_text.strip()
            if p.range == "bool":
                if v not in ("true", "false"):
                    raise KBError(f"bad value '{v}' for bool action '{name}'", "bad-value")
                value = v == "true"
            elif p.range == "int":
                value = int(v)
            elif p.range == "real":
                value = float(v)
            else:
                value = v
        return name, args, value

    def immediate_reward(self, actions: Iterable[str | tuple[str, Sequence[str], Value]]) -> float:
        """RDDL's R(s, a): the reward of taking `actions` in the CURRENT
        state (ROSPlan evaluated it on the state after the action). Actions
        are strings as ROSPlan's clients send them ("goto_waypoint(kenny, a,
        b)"; "noop" or nothing for no action) or (name, args, value) triples.
        A reward that reads the next state is taken on one sampled next
        state (seed 0), as the simulator computes it."""
        named: dict[tuple[str, tuple[str, ...]], Value] = {}
        for a in actions:
            if isinstance(a, str):
                if a.strip() in ("", "noop"):
                    continue
                name, args, value = self.parse_action(a)
            else:
                name, args, value = a[0], tuple(a[1]), a[2]
            named[(name, args)] = value
        with self._lock:
            sim = self.simulator()
            try:
                arrays = sim.actions_from_names(named)
                step = sim.step(self.to_state(), arrays, np.random.default_rng(0), check=False)
            except SimulationError as err:
                raise KBError(f"cannot evaluate the reward: {err}", "bad-action") from None
            return float(step.reward[0])

    # ------------------------------------------------------ problem generation

    def to_rddl_instance(
        self,
        name: str | None = None,
        non_fluents_name: str | None = None,
        *,
        explicit: bool = False,
    ) -> str:
        """RDDL text: a non-fluents block and an instance block of the current
        objects, non-fluents, state, horizon, discount and max-nondef-actions
        (fluent or non-fluent decided by the declarations). Only values that
        differ from their declared default are written, unless `explicit`.
        Names default to ROSPlan's: "<domain>__generated_instance" and
        "nf_" before it."""
        return self._generate(
            ("rddl", name, non_fluents_name, explicit),
            lambda: rddl_instance(self, name, non_fluents_name, explicit),
        )

    def to_pddl(self, mode: str = "most-likely", exogenous: str = "current") -> tuple[str, str]:
        """A classical PDDL (domain, problem) of the current knowledge by
        determinisation: `mode` "most-likely" or "all-outcomes"; the
        exogenous fluents at their current values, their most likely next
        values, or as outcome actions ("current", "most-likely",
        "outcomes"); action costs from the reward; the goal from `goal()`
        (KBError without one). See `ippc.kb.pddl`."""
        return self._generate(("pddl", mode, exogenous), lambda: to_pddl(self, mode, exogenous))

    def _changed(self) -> None:
        self._generation += 1
        self._generated = {}

    def _generate(self, key: tuple[Any, ...], make: Callable[[], Any]) -> Any:
        """`make()`, or what it gave for `key` since the knowledge last
        changed: a client asking for the same problem again (a pipelining
        one: thousands) costs a lookup, not a generation."""
        generation = self._generation
        hit = self._generated.get(key)
        if hit is not None and hit[0] == generation:
            return hit[1]
        out = make()
        if len(self._generated) < 64:
            self._generated[key] = (generation, out)
        return out

    def domain_rddl(self) -> str:
        """The domain block, as `ippc.rddl`'s writer writes it."""
        return write(self.model.domain)

    # ---------------------------------------------------------------- misc

    def __repr__(self) -> str:
        return f"KnowledgeBase({self.model.name!r}, domain={self.model.domain_name!r})"


__all__ = [
    "GoalFacts",
    "GoalSubscriber",
    "InvariantError",
    "JournalSubscriber",
    "KnowledgeBase",
    "Subscriber",
]
