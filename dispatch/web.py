"""rddl-dispatch's web page (``rddl-dispatch ... --web PORT``): the robot, live.

The page shows the knowledge base's facts (every grounding of a state fluent that is not
false, and every one that changed; a change at most one turn old is marked), the goal
and whether it holds, the session (round, turn, whether the planner is thinking), the
actions (running ones with their handler's state and how long they have run, then how
each ended), sensing (messages, batches, values refused, the last errors), the notes
(actions that failed, replans, refused effects, contradictions) and the rewards so far,
with a chart of them. Everything comes from `DispatchLive` (`dispatch.live`): the
knowledge base's subscriptions, the dispatcher's and the handlers' watchers.

It runs in the dispatcher's own trio loop, started by `dispatch_session` before the
planner's socket (`web_task`): an event that comes from another thread (a robot's driver
thread writing the knowledge base) is handed to the loop with
``TrioToken.run_sync_soon``. The changes are gathered and sent to the viewers four times
a second (the last value of each row and field: a viewer gets at most two events a
flush, however fast the turns go), and nothing is built for them while nobody watches.
Publishing never waits (`ippc.web.Feed`), so a viewer can never slow the robot. Sensing's
counts and the running actions' times are told once a second.

Routes: ``/`` (the page), ``/events``, ``/snapshot.json`` and ``/figure/rewards.svg``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

import trio

from ..web import (
    JSON,
    SVG,
    EventStream,
    Feed,
    Response,
    Routes,
    WebOptions,
    field,
    fields_event,
    fmt_number,
    h,
    line_chart,
    live_table,
    page,
    rows_event,
    serve_web,
    to_json,
)
from ..web.pages import PageUpdates
from .dispatcher import Dispatcher
from .live import DispatchLive
from .run import ListenError

__all__ = ["dispatch_routes", "page_events", "web_task"]

log = logging.getLogger(__name__)

TOPIC = "dispatch"
#: Rows the page keeps of ended actions and of notes (the newest).
ACTIONS_SHOWN = 50
NOTES_SHOWN = 100

FACT_COLUMNS = [
    ("key", "fact"),
    ("value", "value"),
    ("mark", "changed"),
    ("source", "by"),
    ("when", "at"),
]
ACTION_COLUMNS = [
    ("id", "#"),
    ("turn", "turn"),
    ("action", "action"),
    ("state", "state"),
    ("seconds", "seconds"),
    ("message", "message"),
]
NOTE_COLUMNS = [("when", "at"), ("kind", "kind"), ("text", "what")]


def _clock(t: float | None) -> str:
    return "" if t is None else time.strftime("%H:%M:%S", time.localtime(t))


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return fmt_number(v)
    return "" if v is None else str(v)


def _fact_cells(fact: Mapping[str, Any], changed: bool) -> dict[str, Any]:
    return {
        "key": fact["key"],
        "value": _value(fact["value"]),
        "mark": "changed" if changed else "",
        "source": fact.get("source") or "",
        "when": _clock(fact.get("changed_at")),
    }


def _action_cells(a: Mapping[str, Any], now: float) -> dict[str, Any]:
    if a["status"] == "running":
        started = a.get("started_at")
        seconds: Any = round(now - started, 1) if started is not None else None
        timeout = a.get("timeout")
        message = "running" + ("" if timeout is None else f" (timeout {fmt_number(timeout)} s)")
    else:
        seconds = a.get("duration")
        message = a.get("message") or ""
    return {
        "id": a["id"],
        "turn": a.get("turn"),
        "action": a["action"],
        "state": a["status"],
        "seconds": seconds,
        "message": message,
    }


def _note_cells(n: Mapping[str, Any]) -> dict[str, Any]:
    return {"when": _clock(n.get("time")), "kind": n["kind"], "text": n["text"]}


def _session_text(s: Mapping[str, Any]) -> str:
    if s["state"] == "waiting":
        return "waiting for a planner"
    if s["state"] == "closed":
        return f"session {s['sessions']} closed"
    turn = "" if s.get("turn") is None else f", turn {s['turn']}"
    thinking = " (the planner is thinking)" if s.get("thinking") else ""
    return f"session {s['sessions']}: round {s['round']}{turn}{thinking}"


def _goal_text(g: Mapping[str, Any]) -> str:
    if g.get("error"):
        return f"cannot be decided: {g['error']}"
    facts = ", ".join(g.get("facts") or []) or "(none)"
    holds = {True: "holds", False: "does not hold", None: "-"}[g.get("holds")]
    return f"{facts}: {holds}"


def _reached_text(g: Mapping[str, Any]) -> str:
    """The run's outcome so far (as its report says it: goal reached or not)."""
    turn = g.get("reached_turn")
    return "not reached yet" if turn is None else f"goal reached (it held after turn {turn})"


def _counts_fields(c: Mapping[str, Any]) -> dict[str, Any]:
    """The actions' counts, as the Actions table's rows (every one it ever had)."""
    ended = ", ".join(f"{n} {st}" for st, n in c["by_status"].items())
    running = f", {c['running']} running" if c["running"] else ""
    noop = f"{c['noop']} noop dispatched on turns where no action ran (none sent, or refused)"
    if c["noop_not_succeeded"]:
        noop += f" ({c['noop_not_succeeded']} did not succeed)"
    return {
        "actions": f"{c['actions']} ({ended or 'none ended yet'}{running})",
        "not-succeeded": c["not_succeeded"],
        "noop": noop,
    }


def _sensing_fields(s: Mapping[str, Any] | None) -> dict[str, Any]:
    if s is None:
        return {"sensing": "no sensing", "sensing-error": ""}
    refused = sum(s["refused"].values())
    return {
        "sensing": f"{s['messages']} messages, {s['batches']} batches, {refused} values refused",
        "sensing-error": s["errors"][-1] if s["errors"] else "",
    }


def _stats_fields(st: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "reward": st["reward"],
        "turns": st["turns"],
        "rounds": st["rounds"],
        "replans": st["replans"],
        "contradictions": st["contradictions"],
    }


def _fields(snap: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "instance": snap["instance"],
        "domain": snap["domain"],
        "session": _session_text(snap["session"]),
        "goal": _goal_text(snap["goal"]),
        "reached": _reached_text(snap["goal"]),
        **_counts_fields(snap["counts"]),
        "handlers": ", ".join(snap["handlers"]) or "none",
        "chart": snap["stats"]["turns"],
        **_stats_fields(snap["stats"]),
        **_sensing_fields(snap["sensing"]),
    }


def _rows(snap: Mapping[str, Any]) -> dict[str, Sequence[tuple[str, Mapping[str, Any]]]]:
    now = snap["time"]
    actions = list(snap["ended"])[-ACTIONS_SHOWN:] + list(snap["running"])
    actions.sort(key=lambda a: a.get("order", 0))
    return {
        "facts": [(f["key"], _fact_cells(f, f["changed"])) for f in snap["facts"]],
        "actions": [(str(a["id"]), _action_cells(a, now)) for a in actions],
        "notes": [(str(n["id"]), _note_cells(n)) for n in snap["notes"]][-NOTES_SHOWN:],
    }


def page_events(live: DispatchLive) -> list[dict[str, Any]]:
    """The events that draw the whole current page (a viewer's first ones)."""
    snap = live.snapshot()
    rows = [(t, key, cells) for t, entries in _rows(snap).items() for key, cells in entries]
    return [rows_event(rows, reset=True), fields_event(_fields(snap))]


class _Translator:
    """`DispatchLive`'s events as the page's (rows of its tables, its fields), and
    which facts carry a change mark (cleared when their change gets too old)."""

    def __init__(self, live: DispatchLive) -> None:
        self.live = live
        self.marked: dict[str, dict[str, Any]] = {}  # fact key -> the fact, its epoch

    def __call__(self, event: Mapping[str, Any]) -> list[dict[str, Any]]:
        kind = event["type"]
        if kind == "facts":
            for f in event["facts"]:
                self.marked[f["key"]] = f
            rows = [("facts", f["key"], _fact_cells(f, True)) for f in event["facts"]]
            return [rows_event(rows)]
        if kind == "turn-sent":
            epoch = event["epoch"]
            old = [f for f in self.marked.values() if f["epoch"] < epoch - 1]
            for f in old:
                del self.marked[f["key"]]
            out = [fields_event({"session": _session_text(event["session"])})]
            if old:
                out.insert(0, rows_event([("facts", f["key"], _fact_cells(f, False)) for f in old]))
            return out
        if kind == "session":
            return [fields_event({"session": _session_text(event["session"])})]
        if kind == "goal":
            goal = event["goal"]
            return [fields_event({"goal": _goal_text(goal), "reached": _reached_text(goal)})]
        if kind == "action":
            a = event["action"]
            cells = _action_cells(a, event["time"])
            return [
                rows_event([("actions", str(a["id"]), cells)]),
                fields_event(_counts_fields(event["counts"])),
            ]
        if kind == "turn":
            st = event["stats"]
            session = _session_text(event["session"])
            return [fields_event({**_stats_fields(st), "chart": st["turns"], "session": session})]
        if kind == "note":
            n = event["note"]
            return [rows_event([("notes", str(n["id"]), _note_cells(n))])]
        if kind == "sensing":
            return [fields_event(_sensing_fields(event["sensing"]))]
        return []


def _rewards_svg(live: DispatchLive) -> str:
    turns = live.snapshot()["turns"]
    total, cumulative = 0.0, []
    for t in turns:
        total += t["reward"]
        cumulative.append(total)
    first = turns[0]["turn"] if turns else 1
    return line_chart(
        {"reward per turn": [t["reward"] for t in turns], "sum of the turns shown": cumulative},
        title="Rewards",
        x_label="turn",
        y_label="reward",
        x_start=first,
    )


def _stat(label: str, name: str, value: Any) -> list[Any]:
    return [h("dt", label), h("dd", field(name, value))]


def _index(live: DispatchLive) -> str:
    snap = live.snapshot()
    f = _fields(snap)
    rows = _rows(snap)
    summary = h(
        "dl",
        _stat("instance", "instance", f["instance"]),
        _stat("domain", "domain", f["domain"]),
        _stat("session", "session", f["session"]),
        _stat("goal", "goal", f["goal"]),
        _stat("the run's goal", "reached", f["reached"]),
        _stat("reward so far", "reward", f["reward"]),
        _stat("turns", "turns", f["turns"]),
        _stat("rounds", "rounds", f["rounds"]),
        _stat("the planner's actions", "actions", f["actions"]),
        _stat("of them, not succeeded", "not-succeeded", f["not-succeeded"]),
        _stat("noop turns", "noop", f["noop"]),
        _stat("replans", "replans", f["replans"]),
        _stat("contradictions", "contradictions", f["contradictions"]),
        _stat("sensing", "sensing", f["sensing"]),
        _stat("last sensing error", "sensing-error", f["sensing-error"]),
        _stat("handlers", "handlers", f["handlers"]),
        class_="facts",
    )
    chart = h(
        "img",
        src=f"/figure/rewards.svg?v={f['chart']}",
        alt="rewards per turn",
        data_page_chart="/figure/rewards.svg",
        data_version="chart",
    )
    return page(
        "rddl-dispatch",
        summary,
        h("h2", "Actions"),
        h(
            "p",
            "Every action the planner sent (dispatched to its handler, or refused as its"
            " precondition was false) and every noop dispatched on a turn where none ran;"
            f" the counts above are of every row, the table keeps the last {ACTIONS_SHOWN}.",
            class_="muted",
        ),
        live_table(
            "actions", ACTION_COLUMNS, rows["actions"], limit=ACTIONS_SHOWN, newest_first=True
        ),
        h("h2", "Failures, replans, contradictions"),
        live_table(
            "notes",
            NOTE_COLUMNS,
            rows["notes"],
            limit=NOTES_SHOWN,
            newest_first=True,
            state_field=None,
        ),
        h("h2", "Rewards"),
        chart,
        h("h2", "Knowledge base"),
        h(
            "p",
            "Every grounding of a state fluent that is not false, and every one that changed;"
            " changed: since the planner was sent the state before the last one.",
            class_="muted",
        ),
        live_table("facts", FACT_COLUMNS, rows["facts"], state_field=None),
        events="/events",
        nav={"rddl-dispatch": "/", "snapshot (JSON)": "/snapshot.json"},
    )


def dispatch_routes(live: DispatchLive, feed: Feed) -> Routes:
    """The page's routes (see the module doc)."""
    routes = Routes()
    routes.add("/", lambda r: Response(_index(live)))
    routes.add("/events", lambda r: EventStream(feed, [TOPIC], lambda: page_events(live)))
    routes.add("/snapshot.json", lambda r: Response(to_json(live.snapshot()), content_type=JSON))
    routes.add("/figure/rewards.svg", lambda r: Response(_rewards_svg(live), content_type=SVG))
    return routes


WebTask = Callable[..., Awaitable[None]]


def web_task(
    options: WebOptions,
    on_listening: Callable[[int], None] | None = None,
    *,
    flush: float = 0.25,
    tick: float = 1.0,
) -> WebTask:
    """What `dispatch_session(web=...)` starts in its nursery: serve the page of the
    dispatcher it is given until cancelled (`on_listening(port)` once it listens; a
    port it cannot have raises `ListenError`). The changes are sent to the viewers
    every `flush` seconds, gathered (`PageUpdates`); sensing's counts and the running
    actions' times every `tick` seconds."""

    async def serve(
        dispatcher: Dispatcher, *, task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED
    ) -> None:
        live = DispatchLive(dispatcher)
        feed = Feed()
        translate = _Translator(live)
        updates = PageUpdates()
        token = trio.lowlevel.current_trio_token()
        loop_thread = threading.get_ident()

        def send(event: dict[str, Any]) -> None:
            if feed.watched(TOPIC):
                for out in translate(event):
                    updates.add(out)
            elif event["type"] in ("facts", "turn-sent"):
                translate(event)  # (the marks, for the next viewer's updates)

        def publish(event: dict[str, Any]) -> None:
            if threading.get_ident() == loop_thread:
                send(event)
                return
            try:
                token.run_sync_soon(send, event)
            except trio.RunFinishedError:
                pass

        async def flusher() -> None:
            next_tick = trio.current_time() + tick
            while True:
                await trio.sleep(flush)
                if trio.current_time() >= next_tick:
                    next_tick += tick
                    live.tick()
                    running = live.running()
                    if running and feed.watched(TOPIC):
                        now = time.time()
                        for a in running:
                            cells = _action_cells(a, now)
                            updates.add(rows_event([("actions", str(a["id"]), cells)]))
                events = updates.take()
                if feed.watched(TOPIC):
                    for event in events:
                        feed.publish(event, TOPIC)

        unsubscribe = live.subscribe(publish)
        try:
            async with trio.open_nursery() as nursery:
                try:
                    port = await nursery.start(serve_web, dispatch_routes(live, feed), options)
                except OSError as err:
                    raise ListenError(
                        "the web page's socket, --web", f"{options.host}:{options.port}", err
                    ) from None
                if on_listening is not None:
                    on_listening(port)
                nursery.start_soon(flusher)
                task_status.started(port)
        finally:
            unsubscribe()
            live.close()
            feed.close()

    return serve
