"""The knowledge base's methods on a JSON-lines server (`kb.*`).

`register_kb(server, kb)` offers every query and update of a
`KnowledgeBase` on a `JsonlServer`, so that a controller in any language
can use it; docs/knowledge-base.md lists them with a transcript. Names
follow ROSPlan's services (`kb.domain_name` for domain/name,
`kb.operator` for domain/operator_details, ...); params are JSON objects,
ground arguments are lists of names, values are JSON values (enum values
"@name").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import trio

from .goal import Goal
from .jsonl import DEFAULT_HOST, Connection, JsonlServer, RequestError, SocketLimits
from .knowledge_base import KnowledgeBase
from .store import Change, Update

SUBSCRIPTION = "kb.subscription"  # key of a connection's subscription in Connection.state
CHANGED_EVENT = "kb.changed"
GOAL_EVENT = "kb.goal_changed"
# a goal's outcome, once recorded (rddl-dispatch: reached, abandoned, removed, interrupted)
GOAL_OUTCOME_EVENT = "kb.goal_outcome"
GOAL_SUBSCRIPTION = "kb.goal_subscription"  # set in Connection.state when it hears of goals


def notify_subscribers(server: JsonlServer, event: str, fields: dict[str, Any]) -> None:
    """Send `event` to the connections subscribed to goal events
    (`kb.subscribe` with `goal` true, the default)."""
    for conn in list(server.connections):
        if conn.state.get(GOAL_SUBSCRIPTION):
            conn.send_event(event, fields)


def _param(
    params: dict[str, Any], key: str, kind: type | tuple[type, ...], default: Any = ...
) -> Any:
    """`params[key]` checked to be of `kind` (a bool is no number here)."""
    if key not in params or (params[key] is None and default is not ...):
        if default is ...:
            raise RequestError("bad-params", f"missing param '{key}'")
        return default
    value = params[key]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        names = " or ".join(k.__name__ for k in kinds)
        raise RequestError("bad-params", f"param '{key}' must be {names}, not {value!r}")
    return value


def _args(params: dict[str, Any], key: str = "args") -> tuple[str, ...]:
    args = _param(params, key, list, [])
    if not all(isinstance(a, str) for a in args):
        raise RequestError("bad-params", f"param '{key}' must be a list of names, not {args!r}")
    return tuple(args)


def _update(n: int, item: Any) -> Update:
    if not isinstance(item, dict):
        raise RequestError("bad-params", f"update {n + 1} must be an object, not {item!r}")
    try:
        op = _param(item, "op", str)
        fluent = _param(item, "fluent", str)
        args = _args(item)
    except RequestError as err:
        raise RequestError("bad-params", f"update {n + 1}: {err}") from None
    return Update(op, fluent, args, item.get("value"))  # type: ignore[arg-type]


def _changes(changes: list[Change]) -> list[dict[str, Any]]:
    return [c.to_json() for c in changes]


def register_kb(server: JsonlServer, kb: KnowledgeBase) -> None:
    """Offer `kb`'s queries and updates as `kb.*` methods on `server`."""

    def method(name: str) -> Callable[[Callable[[dict[str, Any], Connection], Any]], Any]:
        def deco(fn: Callable[[dict[str, Any], Connection], Any]) -> Any:
            server.register(name, fn)
            return fn

        return deco

    # -- domain

    @method("kb.domain_name")
    def domain_name(params: dict[str, Any], conn: Connection) -> Any:
        """the domain's name"""
        return kb.domain_name()

    @method("kb.types")
    def types(params: dict[str, Any], conn: Connection) -> Any:
        """object and enum types with their super-types"""
        return kb.types()

    @method("kb.predicates")
    def predicates(params: dict[str, Any], conn: Connection) -> Any:
        """bool state fluents and non-fluents with typed parameters and sensed flags"""
        return kb.predicates()

    @method("kb.functions")
    def functions(params: dict[str, Any], conn: Connection) -> Any:
        """numeric and enum state fluents and non-fluents"""
        return kb.functions()

    @method("kb.fluent_type")
    def fluent_type(params: dict[str, Any], conn: Connection) -> Any:
        """the value type of a fluent: {fluent}"""
        return kb.fluent_type(_param(params, "fluent", str))

    @method("kb.operators")
    def operators(params: dict[str, Any], conn: Connection) -> Any:
        """the operators' names and parameters (exogenous last)"""
        return [
            {"name": o.name, "parameters": [p.to_json() for p in o.parameters]}
            for o in kb.operators()
        ]

    @method("kb.operator")
    def operator(params: dict[str, Any], conn: Connection) -> Any:
        """one operator in full: {name}"""
        return kb.operator(_param(params, "name", str)).to_json()

    @method("kb.unsupported")
    def unsupported(params: dict[str, Any], conn: Connection) -> Any:
        """what the operators and the goal leave out, by construct and line"""
        return [u.to_json() for u in kb.unsupported()]

    @method("kb.metric")
    def metric(params: dict[str, Any], conn: Connection) -> Any:
        """the reward, maximised: its RDDL text and expression tree"""
        return kb.metric()

    @method("kb.instances")
    def instances(params: dict[str, Any], conn: Connection) -> Any:
        """the objects of a type, or of every type: {type?}"""
        return kb.instances(_param(params, "type", str, None))

    @method("kb.enum_values")
    def enum_values(params: dict[str, Any], conn: Connection) -> Any:
        """the values of an enum type: {type}"""
        return kb.enum_values(_param(params, "type", str))

    @method("kb.rddl_instance")
    def rddl_instance(params: dict[str, Any], conn: Connection) -> Any:
        """the RDDL non-fluents and instance blocks of the current state: {explicit?, name?}"""
        return kb.to_rddl_instance(
            _param(params, "name", str, None), explicit=_param(params, "explicit", bool, False)
        )

    @method("kb.pddl")
    def pddl(params: dict[str, Any], conn: Connection) -> Any:
        """a PDDL domain and problem by determinisation: {mode?, exogenous?}"""
        domain, problem = kb.to_pddl(
            _param(params, "mode", str, "most-likely"),
            _param(params, "exogenous", str, "current"),
        )
        return {"domain": domain, "problem": problem}

    # -- state

    @method("kb.get")
    def get(params: dict[str, Any], conn: Connection) -> Any:
        """the value of one grounding: {fluent, args}"""
        return kb.get(_param(params, "fluent", str), _args(params))

    @method("kb.facts")
    def facts(params: dict[str, Any], conn: Connection) -> Any:
        """every grounding and its value (false facts included): {fluent?, non_fluents?}"""
        fluent = _param(params, "fluent", str, None)
        nf = _param(params, "non_fluents", bool, False)
        return [
            {"fluent": name, "args": list(args), "value": value}
            for (name, args), value in kb.facts(fluent, non_fluents=nf).items()
        ]

    @method("kb.apply")
    def apply(params: dict[str, Any], conn: Connection) -> Any:
        """apply a batch of updates atomically: {updates: [{op, fluent, args, value?}], source?}"""
        items = _param(params, "updates", list)
        source = _param(params, "source", str, f"jsonl:{conn.peer}")
        updates = [_update(n, item) for n, item in enumerate(items)]
        return {"changes": _changes(kb.apply(updates, source))}

    @method("kb.subscribe")
    def subscribe(params: dict[str, Any], conn: Connection) -> Any:
        """send this connection kb.changed events after every change, kb.goal_changed after every goal change: {fluents?, goal?}"""
        names = _param(params, "fluents", list, None)
        goals = _param(params, "goal", bool, True)
        wanted = None
        if names is not None:
            for f in names:
                if not isinstance(f, str):
                    raise RequestError("bad-params", f"param 'fluents' must list names, not {f!r}")
                kb.is_sensed(f)  # an unknown name is an error now, not a silent nothing later
            wanted = frozenset(names)

        def tell(changes: list[Change], source: str) -> None:
            mine = changes if wanted is None else [c for c in changes if c.fluent in wanted]
            if mine and not conn.closed:  # (send_event is safe from any thread)
                conn.send_event(CHANGED_EVENT, {"source": source, "changes": _changes(mine)})

        def tell_goal(goal: Goal | None, source: str) -> None:
            if not conn.closed:
                conn.send_event(
                    GOAL_EVENT, {"source": source, "goal": None if goal is None else goal.to_json()}
                )

        old = conn.state.pop(SUBSCRIPTION, None)
        if old is not None:
            old()
        else:
            conn.on_close(_drop_subscription)
        stop_changes = kb.subscribe(tell)
        stop_goal = kb.subscribe_goal(tell_goal) if goals else None

        def stop() -> None:
            stop_changes()
            if stop_goal is not None:
                stop_goal()

        conn.state[SUBSCRIPTION] = stop
        conn.state[GOAL_SUBSCRIPTION] = goals
        return {"subscribed": sorted(wanted) if wanted is not None else "all"}

    @method("kb.unsubscribe")
    def unsubscribe(params: dict[str, Any], conn: Connection) -> Any:
        """stop the kb.changed events of this connection"""
        old = conn.state.pop(SUBSCRIPTION, None)
        conn.state.pop(GOAL_SUBSCRIPTION, None)
        if old is not None:
            old()
        return {"subscribed": old is not None}

    @method("kb.set_sensed")
    def set_sensed(params: dict[str, Any], conn: Connection) -> Any:
        """mark a fluent as sensed or not: {fluent, sensed?}"""
        kb.set_sensed(_param(params, "fluent", str), _param(params, "sensed", bool, True))
        return sorted(kb.sensed_fluents())

    @method("kb.sensed")
    def sensed(params: dict[str, Any], conn: Connection) -> Any:
        """the fluents marked as sensed"""
        return sorted(kb.sensed_fluents())

    # -- RDDL parameters

    def parameters() -> dict[str, Any]:
        return {
            "horizon": kb.horizon,
            "discount": kb.discount,
            "max_nondef_actions": kb.max_nondef_actions,
        }

    @method("kb.parameters")
    def get_parameters(params: dict[str, Any], conn: Connection) -> Any:
        """horizon, discount and max_nondef_actions (null: unbounded)"""
        return parameters()

    @method("kb.set_parameters")
    def set_parameters(params: dict[str, Any], conn: Connection) -> Any:
        """set any of horizon, discount, max_nondef_actions (all or none)"""
        known = ("horizon", "discount", "max_nondef_actions")
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise RequestError("bad-params", f"unknown param(s) {', '.join(unknown)}")
        before = parameters()
        try:
            for key in known:
                if key in params:
                    setattr(kb, key, params[key])
        except Exception:
            for key, value in before.items():  # valid a moment ago: all or none
                setattr(kb, key, value)
            raise
        return parameters()

    # -- goal and reward

    @method("kb.goal")
    def goal(params: dict[str, Any], conn: Connection) -> Any:
        """the goal: ground facts, the lifted formula, what is not in facts (null: none)"""
        g = kb.goal()
        return None if g is None else g.to_json()

    def goal_params(params: dict[str, Any]) -> list[Any]:
        goals = _param(params, "goals", list)
        for n, g in enumerate(goals, 1):
            if not isinstance(g, (str, dict)):
                raise RequestError(
                    "bad-params",
                    f"goal fact {n} is a text such as 'holding(r1)' or "
                    f"{{fluent, args, value}}, not {g!r}",
                )
        return goals

    def goal_reply(goal: Goal | None) -> Any:
        return None if goal is None else goal.to_json()

    def goal_method(name: str, change: Callable[..., Goal | None], doc: str) -> None:
        def handler(params: dict[str, Any], conn: Connection) -> Any:
            source = _param(params, "source", str, f"jsonl:{conn.peer}")
            return goal_reply(change(goal_params(params), source))

        server.register(name, handler, doc)

    goal_method(
        "kb.set_goal",
        kb.set_goal,
        "replace the goal by ground facts ([] for none): "
        '{goals: ["holding(r1)", {fluent, args, value}, ...], source?}',
    )
    goal_method("kb.add_goal", kb.add_goal, "add facts to the goal: {goals, source?}")
    goal_method("kb.remove_goal", kb.remove_goal, "remove facts from the goal: {goals, source?}")

    @method("kb.reset_goal")
    def reset_goal(params: dict[str, Any], conn: Connection) -> Any:
        """back to the domain's own goal: {source?}"""
        source = _param(params, "source", str, f"jsonl:{conn.peer}")
        return goal_reply(kb.reset_goal(source))

    @method("kb.snapshot")
    def snapshot(params: dict[str, Any], conn: Connection) -> Any:
        """the knowledge as plain data: {facts, goal}, what kb.restore takes"""
        return kb.snapshot()

    @method("kb.restore")
    def restore(params: dict[str, Any], conn: Connection) -> Any:
        """load saved knowledge in one atomic batch: {facts: [{fluent, args, value}], goal?, source?}"""
        saved: dict[str, Any] = {"facts": _param(params, "facts", list)}
        if "goal" in params:
            saved["goal"] = _param(params, "goal", list, None)
        source = _param(params, "source", str, "restore")
        return {"changes": _changes(kb.restore(saved, source))}

    @method("kb.goal_holds")
    def goal_holds(params: dict[str, Any], conn: Connection) -> Any:
        """whether the goal holds in the current state (null: no goal)"""
        return kb.goal_holds()

    @method("kb.immediate_reward")
    def immediate_reward(params: dict[str, Any], conn: Connection) -> Any:
        """R(s, a) on the current state: {actions: ["name(a, b)", ...]}"""
        actions = _param(params, "actions", list, [])
        for a in actions:
            if not isinstance(a, str):
                raise RequestError(
                    "bad-params", f"actions are strings like 'move(a, b)', not {a!r}"
                )
        return kb.immediate_reward(actions)


def _drop_subscription(conn: Connection) -> None:
    old = conn.state.pop(SUBSCRIPTION, None)
    if old is not None:
        old()


async def serve_kb(
    kb: KnowledgeBase,
    host: str = DEFAULT_HOST,
    port: int = 0,
    *,
    server: JsonlServer | None = None,
    limits: SocketLimits | None = None,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
) -> None:
    """Serve `kb` (on `server`, or a new one with `limits`) until cancelled;
    the bound port is reported through `task_status`."""
    server = server or JsonlServer("kb", limits)
    register_kb(server, kb)
    await server.serve(host, port, task_status=task_status)
