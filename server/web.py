"""rddl-server's web view (`rddl-server ... --web PORT`): its pages over the sessions'
live picture (`server.live`: `SessionBoard`, fed by the `LiveStore` stand-in of the
result store, and by the worker processes' records).

`ServerView.run` takes the board's changed sessions every `ServerView.interval()`
seconds and publishes them to the web feed (`ippc.web.Feed`), whose viewers each have a
bounded queue; a viewer that falls behind is dropped, never waited for.

The pages: `/` every session (client, instance, round, turn, rewards so far, time used
of the budget, state and reason, a small chart of its round rewards with its scale),
the connections refused or closed before a session (counted by cause), live;
`/session/ID` one session: its facts, the chart of its round rewards, its rounds and
its last turns (the actions, the state's true fluents and what changed since the turn
before). Every name is text (see `ippc.web.html`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Iterator
from typing import Any

import trio

from ..web import (
    JSON,
    SVG,
    EventStream,
    Feed,
    Markup,
    Request,
    Response,
    Routes,
    fields_event,
    fmt_number,
    h,
    line_chart,
    live_table,
    not_found,
    page,
    rows_event,
    sparkline,
    to_json,
)
from ..web import (
    field as page_field,
)
from .live import (
    FAILED,
    FLUSH_INTERVAL,
    LAST_TURNS,
    LiveStore,
    SessionBoard,
    SessionRecord,
    forward_records,
    receive_records,
    send_records,
    state_of,
)

log = logging.getLogger(__name__)

# what one update to one viewer costs the loop, rounded up (a send on
# loopback took 0.1-0.4 ms on the loaded 2-core test machine; bench/web.py
# --loop-only; see `ServerView.interval`)
VIEWER_SEND = 0.001


# ------------------------------------------------------------- the pages


class ServerView:
    """rddl-server's pages over a board; `run` publishes its changes."""

    def __init__(self, board: SessionBoard, feed: Feed | None = None):
        self.board = board
        self.feed = feed or Feed()
        self.routes = Routes()
        self._published_turns: dict[int, int] = {}  # session id -> turns_total sent
        self._published_rounds: dict[int, int] = {}  # session id -> rounds_total sent
        self._published_refused = 0  # the board's refused_version sent
        self.routes.add("/", self.index)
        self.routes.add("/events", self.events)
        self.routes.add("/session/{id}", self.session_page)
        self.routes.add("/session/{id}/events", self.session_events)
        self.routes.add("/chart/session/{id}.svg", self.spark_svg)
        self.routes.add("/chart/session/{id}/rewards.svg", self.rewards_svg)
        self.routes.add("/sessions.json", self.sessions_json)

    # -- publishing

    async def run(self) -> None:
        """Publish the board's changes until cancelled (the running
        sessions' clocks at least every second), every `interval()` seconds."""
        last_clock = trio.current_time()
        while True:
            await trio.sleep(self.interval())
            now = trio.current_time()
            clock = now - last_clock >= 0.99
            if clock:
                last_clock = now
            self.publish(clock=clock)

    def interval(self) -> float:
        """Seconds between two updates: FLUSH_INTERVAL, longer with many
        viewers, so that their sends take about a tenth of the loop at most
        (VIEWER_SEND seconds each) whatever their number: 0.5 s up to 50
        viewers, 1 s with 100."""
        return max(FLUSH_INTERVAL, 10 * VIEWER_SEND * self.feed.viewers)

    def publish(self, clock: bool = False) -> None:
        changed, removed = self.board.flush()
        now = time.time()
        feed = self.feed
        if clock:
            ids = {r.id for r in changed}
            changed += [
                r for r in self.board.sessions.values() if r.status == "running" and r.id not in ids
            ]
        refused = self.board.refused_version != self._published_refused
        if feed.watched("sessions") and (changed or removed or refused):
            rows = [("sessions", r.id, self.cells(r, now)) for r in changed]
            if refused:
                rows += self.refused_rows()
            event = rows_event(rows)
            event["rows"] += [{"table": "sessions", "key": str(i), "remove": True} for i in removed]
            feed.publish(event, "sessions")
            feed.publish(fields_event(self.totals()), "sessions")
            self._published_refused = self.board.refused_version
        for rec in changed:
            topic = f"session:{rec.id}"
            if not feed.watched(topic):
                self._published_turns.pop(rec.id, None)
                self._published_rounds.pop(rec.id, None)
                continue
            feed.publish(fields_event(self.facts(rec, now)), topic)
            new = list(self._new_rows(rec))
            if new:
                feed.publish(rows_event(new), topic)
        for i in removed:
            self._published_turns.pop(i, None)
            self._published_rounds.pop(i, None)

    def _new_rows(self, rec: SessionRecord) -> Iterator[tuple[str, str, dict[str, Any]]]:
        """The rounds and turns of `rec` not published yet (and the round in play)."""
        sent_rounds = self._published_rounds.get(rec.id, 0)
        new_rounds = min(rec.rounds_total - sent_rounds, len(rec.rounds))
        if new_rounds > 0:
            yield from self.round_rows(rec, list(rec.rounds)[-new_rounds:])
        self._published_rounds[rec.id] = rec.rounds_total
        sent_turns = self._published_turns.get(rec.id, 0)
        new_turns = min(rec.turns_total - sent_turns, len(rec.last_turns))
        if new_turns > 0:
            yield from self.turn_rows(rec.turn_texts()[-new_turns:])
        self._published_turns[rec.id] = rec.turns_total

    # -- what the pages show

    def totals(self) -> dict[str, Any]:
        states = [state_of(r.status) for r in self.board.sessions.values()]
        return {
            "running": states.count("running"),
            "finished": states.count("finished"),
            "failed": states.count("failed"),
            "turns": self.board.turns,
            "refused": sum(self.board.refusals().values()),
        }

    def refused_rows(self) -> list[tuple[str, str, dict[str, Any]]]:
        """The rows of the refused connections' table (one per kind)."""
        return [
            ("refused", kind, {"kind": kind, "count": n})
            for kind, n in self.board.refusals().items()
        ]

    @staticmethod
    def cells(rec: SessionRecord, now: float) -> dict[str, Any]:
        rewards = rec.round_rewards
        last = rewards[-1] if rewards else None
        running = rec.status == "running"
        return {
            "id": rec.id,
            "client": rec.client,
            "instance": rec.instance,
            "round": f"{rec.round} / {rec.num_rounds}" + ("" if rec.counted else " (practice)"),
            "turn": rec.turn,
            "turns": rec.turns_total,
            "reward": fmt_number(rec.total_reward + (rec.round_reward if running else 0.0)),
            "last": fmt_number(last),
            "time": _time_used(rec, now),
            "state": state_of(rec.status),
            "status": rec.status + (f": {rec.reason}" if rec.reason else ""),
            "rounds": rec.rounds_total,
        }

    def facts(self, rec: SessionRecord, now: float) -> dict[str, Any]:
        cells = self.cells(rec, now)
        cells.update(
            peer=rec.peer,
            seed=rec.seed,
            round_reward=fmt_number(rec.round_reward),
            total=fmt_number(rec.total_reward),
            started=time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(rec.started_at)),
        )
        return cells

    @staticmethod
    def round_rows(
        rec: SessionRecord, rounds: Iterable[tuple[int, bool, float, int, str]]
    ) -> Iterator[tuple[str, str, dict[str, Any]]]:
        for n, counted, reward, turns, status in rounds:
            key = f"{n}" if counted else f"p{n}"
            yield (
                "rounds",
                key,
                {
                    "round": n if counted else f"{n} (practice)",
                    "reward": fmt_number(reward),
                    "turns": turns,
                    "status": status,
                    "state": "failed" if status in FAILED else "finished",
                },
            )

    @staticmethod
    def turn_rows(
        turns: Iterable[tuple[Any, ...]],
    ) -> Iterator[tuple[str, str, dict[str, Any]]]:
        """Rows of `SessionRecord.turn_texts()`."""
        for rnd, turn, reward, actions, true, changed in turns:
            yield (
                "turns",
                f"{rnd}.{turn}",
                {
                    "round": rnd,
                    "turn": turn,
                    "reward": fmt_number(reward),
                    "actions": actions,
                    "state": true,
                    "changed": changed,
                },
            )

    # -- routes

    NAV = {"sessions": "/"}
    COLUMNS = (
        ("id", "session"),
        ("client", "client"),
        ("instance", "instance"),
        ("round", "round"),
        ("turn", "turn"),
        ("reward", "reward so far"),
        ("last", "last round"),
        ("chart", "round rewards"),
        ("time", "time used"),
        ("status", "state"),
    )

    def _session(self, request: Request) -> SessionRecord:
        try:
            rec = self.board.sessions.get(int(request.params["id"]))
        except ValueError:
            rec = None
        if rec is None:
            raise not_found(f"session {request.params['id']}")
        return rec

    def index(self, request: Request) -> Response:
        now = time.time()
        recs = sorted(self.board.sessions.values(), key=lambda r: r.id)
        totals = self.totals()
        body = [
            h(
                "p",
                page_field("running", totals["running"]),
                " running, ",
                page_field("finished", totals["finished"]),
                " finished, ",
                page_field("failed", totals["failed"]),
                " failed; ",
                page_field("turns", totals["turns"]),
                " turns played; ",
                page_field("refused", totals["refused"]),
                " connections refused or closed before a session (below the sessions).",
            ),
            self._sessions_table(recs, now),
            h(
                "p",
                "Rewards are a session's counted rounds so far; the round in play adds its"
                " rewards as they come. The chart: the rewards of the counted rounds played"
                " out, from the lowest to the highest shown at its left.",
                class_="muted",
            ),
            h("h2", "Connections refused or closed before a session"),
            h(
                "p",
                "Refused by the listener (--allow, the caps), or closed before the session"
                " began (an unknown instance, no session-request): none of them is a"
                " session above. Counted since the server started.",
                class_="muted",
            ),
            live_table(
                "refused",
                (("kind", "why"), ("count", "connections")),
                [(k, c) for _, k, c in self.refused_rows()],
                state_field=None,
            ),
        ]
        return Response(page("rddl-server: sessions", *body, events="/events", nav=self.NAV))

    def _sessions_table(self, recs: list[SessionRecord], now: float) -> Markup:
        return live_table(
            "sessions",
            self.COLUMNS,
            [(str(r.id), self.cells(r, now)) for r in recs],
            links={"id": "/session/{key}"},
            charts={"chart": ("/chart/session/{key}.svg", "rounds")},
            newest_first=True,
        )

    def events(self, request: Request) -> EventStream:
        def snapshot() -> list[dict[str, Any]]:
            now = time.time()
            rows = [("sessions", r.id, self.cells(r, now)) for r in self.board.sessions.values()]
            rows.sort(key=lambda row: int(row[1]))
            rows += self.refused_rows()
            return [rows_event(rows, reset=True), fields_event(self.totals())]

        return EventStream(self.feed, ["sessions"], snapshot)

    def session_page(self, request: Request) -> Response:
        rec = self._session(request)
        now = time.time()
        facts = self.facts(rec, now)
        labels = (
            ("client", "client"),
            ("instance", "instance"),
            ("peer", "peer"),
            ("seed", "seed"),
            ("status", "state"),
            ("round", "round"),
            ("turn", "turn"),
            ("turns", "turns played"),
            ("round_reward", "this round so far"),
            ("total", "counted rounds' reward"),
            ("time", "time used"),
            ("started", "started"),
        )
        dl = h(
            "dl",
            [(h("dt", label), h("dd", page_field(name, facts[name]))) for name, label in labels],
            class_="facts",
        )
        chart = h(
            "img",
            src=f"/chart/session/{rec.id}/rewards.svg?v={rec.rounds_total}",
            alt="round rewards",
            data_page_chart=f"/chart/session/{rec.id}/rewards.svg",
            data_version="rounds",
            data_v=rec.rounds_total,
        )
        rounds = live_table(
            "rounds",
            (("round", "round"), ("reward", "reward"), ("turns", "turns"), ("status", "status")),
            [(k, c) for _, k, c in self.round_rows(rec, rec.rounds)],
            newest_first=True,
        )
        turns = live_table(
            "turns",
            (
                ("round", "round"),
                ("turn", "turn"),
                ("reward", "reward"),
                ("actions", "actions"),
                ("state", "state sent: true (or non-zero) fluents"),
                ("changed", "changed since the turn before"),
            ),
            [(k, c) for _, k, c in self.turn_rows(rec.turn_texts())],
            limit=LAST_TURNS,
            newest_first=True,
            state_field=None,
        )
        title = f"session {rec.id}: {rec.client} on {rec.instance}"
        body = [
            dl,
            h("h2", "Round rewards"),
            chart,
            h("h2", "Rounds"),
            rounds,
            h("h2", f"Last {LAST_TURNS} turns"),
            turns,
        ]
        return Response(page(title, *body, events=f"/session/{rec.id}/events", nav=self.NAV))

    def session_events(self, request: Request) -> EventStream:
        rec = self._session(request)

        def snapshot() -> list[dict[str, Any]]:
            now = time.time()
            rows = list(self.round_rows(rec, rec.rounds)) + list(self.turn_rows(rec.turn_texts()))
            if rec.id not in self._published_turns:
                # the first viewer: `publish` goes on from here (for a later
                # one it goes on from the last publish: rows its snapshot has
                # already come again, and replace themselves)
                self._published_rounds[rec.id] = rec.rounds_total
                self._published_turns[rec.id] = rec.turns_total
            return [rows_event(rows, reset=True), fields_event(self.facts(rec, now))]

        return EventStream(self.feed, [f"session:{rec.id}"], snapshot)

    def spark_svg(self, request: Request) -> Response:
        rec = self._session(request)
        first = next((r[0] for r in rec.rounds if r[1] and r[4] not in FAILED), 1)
        svg = sparkline(rec.round_rewards, label=f"session {rec.id}: round rewards", x_start=first)
        return Response(svg, content_type=SVG)

    def rewards_svg(self, request: Request) -> Response:
        rec = self._session(request)
        first = next((r[0] for r in rec.rounds if r[1] and r[4] not in FAILED), 1)
        svg = line_chart(
            {f"{rec.client} on {rec.instance}": rec.round_rewards},
            title=f"session {rec.id}: reward per round",
            x_start=first,
        )
        return Response(svg, content_type=SVG)

    def sessions_json(self, request: Request) -> Response:
        data = [r.to_json() for r in sorted(self.board.sessions.values(), key=lambda r: r.id)]
        return Response(to_json(data), content_type=JSON)


def _time_used(rec: SessionRecord, now: float) -> str:
    used = rec.elapsed(now)
    if rec.budget > 0:
        return f"{used:.1f} s of {rec.budget:g} s ({100 * used / rec.budget:.0f} %)"
    return f"{used:.1f} s"


__all__ = [
    "FLUSH_INTERVAL",
    "LiveStore",
    "ServerView",
    "SessionBoard",
    "SessionRecord",
    "forward_records",
    "receive_records",
    "send_records",
    "state_of",
]
