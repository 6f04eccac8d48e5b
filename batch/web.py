"""rddl-batch's web page (``rddl-batch run ... --web PORT``): the run, live.

The page shows the planner x instance grid (each job's status, its round and turn while
it runs, its rounds and mean round reward once done), the jobs one per row (with the
reason of a failure), the IPPC scores so far (overall and per domain, as ``rddl-batch
score`` computes them) and the three figures ``rddl-batch report`` draws, as SVG drawn
by the server: the score per instance, the running mean of the round rewards per
instance, the time per turn per domain. Everything comes from `BatchLive`
(`batch.live`), never from polling the database.

Threads. rddl-batch's run loop is not trio: it waits on worker processes' futures (or a
Dask cluster's). So the page runs in a thread of its own with its own trio loop
(`BatchWeb`): the run loop's observer hands each event to that loop with
``TrioToken.run_sync_soon`` (trio's thread-safe queue into a loop: it never waits, so a
viewer can never slow the batch), and the page's handlers read `BatchLive.snapshot()`
(under its lock). The changes are gathered and sent four times a second (the last value
of each row and field), and nothing is built for them while nobody watches; the web core
(`ippc.web`) fans them out to the viewers, dropping one that falls behind.

Routes: ``/`` (the page), ``/events`` (its server-sent events), ``/snapshot.json``
(the whole picture as JSON), ``/figure/scores.svg``, ``/figure/times.svg`` and
``/figure/rewards/{instance}.svg``.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Mapping, Sequence
from typing import Any
from urllib.parse import quote

import trio

from ..web import (
    JSON,
    SVG,
    EventStream,
    Feed,
    Markup,
    Response,
    Routes,
    WebOptions,
    esc,
    field,
    fields_event,
    fmt_number,
    h,
    line_chart,
    live_table,
    not_found,
    page,
    rows_event,
    serve_web,
    to_json,
)
from ..web.chart import PALETTE
from ..web.pages import PageUpdates
from .live import BatchLive

__all__ = ["BatchWeb", "batch_routes", "bar_chart", "page_events"]

log = logging.getLogger(__name__)

TOPIC = "batch"

JOB_COLUMNS = [
    ("key", "job"),
    ("planner", "planner"),
    ("instance", "instance"),
    ("state", "state"),
    ("progress", "progress"),
    ("rounds", "rounds"),
    ("mean", "mean reward"),
    ("attempts", "attempts"),
    ("reason", "reason"),
]


# ------------------------------------------------------------------ cells


def _progress(job: Mapping[str, Any]) -> str:
    if job["status"] != "running":
        return ""
    if job.get("round") is None:
        return "starting"
    if job.get("turn") is None:
        return f"round {job['round']}"
    return f"round {job['round']}, turn {job['turn']}"


def _grid_cell(job: Mapping[str, Any]) -> str:
    """What the grid shows of one job."""
    status = job["status"]
    if status == "running":
        return f"running: {_progress(job)}"
    if status in ("finished", "timeout") and job.get("rounds"):
        text = f"{status}: {job['rounds']} rounds, mean {fmt_number(job.get('mean'))}"
        return text
    if status in ("failed", "interrupted") and job.get("reason"):
        return f"{status}: {job['reason']}"
    return str(status)


def _job_cells(job: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "key": job["key"],
        "planner": job["planner"],
        "instance": job["instance"],
        "state": job["status"],
        "progress": _progress(job),
        "rounds": job.get("rounds"),
        "mean": job.get("mean"),
        "attempts": job.get("attempts"),
        "reason": job.get("reason") or "",
    }


def _grid_key(planner: str, planners: Sequence[str]) -> str:
    """The grid's column field of a planner: its index (a label is any text)."""
    return f"p{planners.index(planner)}"


def _counts_text(counts: Mapping[str, int]) -> str:
    order = ("finished", "timeout", "running", "pending", "failed", "interrupted")
    parts = [f"{counts.get(k, 0)} {k}" for k in order if counts.get(k)]
    return f"{counts.get('total', 0)} jobs: " + (", ".join(parts) or "none yet")


def _score_rows(
    scores: Mapping[str, Any], planners: Sequence[str]
) -> list[tuple[str, str, dict[str, Any]]]:
    """The rows of the overall table (one per planner, with its rank) and of the
    per-domain table (one per domain, a planner's score and its 95% interval per
    column, as the report's table)."""
    rows: list[tuple[str, str, dict[str, Any]]] = []
    for rank, p in enumerate(scores.get("planners", []), 1):
        cells = {k: p[k] for k in ("planner", "score", "ci95", "instances")}
        rows.append(("overall", p["planner"], {"rank": rank, **cells}))
    domains: dict[str, dict[str, Any]] = {}
    for d in scores.get("domains", []):
        if d["planner"] not in planners:
            continue
        text = fmt_number(d["score"], 3)
        if d["ci95"] is not None:
            text += f" \u00b1 {fmt_number(d['ci95'], 2)}"
        cells = domains.setdefault(d["domain"], {"domain": d["domain"]})
        cells[_grid_key(d["planner"], planners)] = text
    rows += [("domains", name, cells) for name, cells in domains.items()]
    return rows


def _score_note(scores: Mapping[str, Any]) -> str:
    if "error" in scores:
        return f"no scores yet: {scores['error']}"
    skipped = scores.get("skipped") or {}
    if skipped:
        return "not scored yet: " + "; ".join(f"{i} ({w})" for i, w in skipped.items())
    return ""


# ------------------------------------------------------------- the events


def _fields(snap: Mapping[str, Any]) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "experiment": snap["experiment"],
        "state": snap["state"],
        "counts": _counts_text(snap["counts"]),
        "rules": snap["rules"],
        "scores-note": _score_note(snap["scores"]),
        "figures": snap["seq"],
    }
    return fields


def _rows(snap: Mapping[str, Any]) -> dict[str, list[tuple[str, Mapping[str, Any]]]]:
    """Every table's rows (key, cells) in the snapshot `snap`."""
    planners = snap["planners"]
    grid: dict[str, dict[str, Any]] = {
        i["name"]: {"instance": i["name"], "domain": i["domain"]} for i in snap["instances"]
    }
    for job in snap["jobs"]:
        grid.setdefault(job["instance"], {"instance": job["instance"]})[
            _grid_key(job["planner"], planners)
        ] = _grid_cell(job)
    tables: dict[str, list[tuple[str, Mapping[str, Any]]]] = {
        "grid": list(grid.items()),
        "jobs": [(job["key"], _job_cells(job)) for job in snap["jobs"]],
        "overall": [],
        "domains": [],
    }
    for table, key, cells in _score_rows(snap["scores"], planners):
        tables[table].append((key, cells))
    return tables


def page_events(live: BatchLive) -> list[dict[str, Any]]:
    """The events that draw the whole current page (a viewer's first ones)."""
    snap = live.snapshot()
    rows = [(t, key, cells) for t, entries in _rows(snap).items() for key, cells in entries]
    return [rows_event(rows, reset=True), fields_event(_fields(snap))]


class _Translator:
    """`BatchLive`'s events as the page's (rows of its tables, its fields)."""

    def __init__(self, live: BatchLive) -> None:
        self.live = live

    def __call__(self, event: Mapping[str, Any]) -> list[dict[str, Any]]:
        kind = event["type"]
        if kind == "job":
            job = event["job"]
            planners = self.live.planners()
            rows = [
                (
                    "grid",
                    job["instance"],
                    {_grid_key(job["planner"], planners): _grid_cell(job)},
                ),
                ("jobs", job["key"], _job_cells(job)),
            ]
            return [rows_event(rows), fields_event({"counts": _counts_text(event["counts"])})]
        if kind == "progress":
            job = self.live.job(event["key"])
            if job is None:
                return []
            planners = self.live.planners()
            rows = [
                (
                    "grid",
                    job["instance"],
                    {_grid_key(job["planner"], planners): _grid_cell(job)},
                ),
                ("jobs", job["key"], {"progress": _progress(job)}),
            ]
            return [rows_event(rows)]
        if kind == "scores":
            scores = event["scores"]
            return [
                rows_event(_score_rows(scores, self.live.planners())),
                fields_event({"scores-note": _score_note(scores), "figures": event["seq"]}),
            ]
        if kind == "batch":
            return [fields_event({"state": event["state"]})]
        return []


# ------------------------------------------------------------- the figures


def bar_chart(
    groups: Mapping[str, Mapping[str, float | None]],
    series: Sequence[str],
    *,
    title: str,
    y_label: str,
    y_max: float | None = None,
    width: int = 760,
    height: int = 300,
) -> Markup:
    """Grouped bars: one group per key of `groups` (instances, domains), one bar per
    name of `series` (planners) in each; every label escaped."""
    left, right, top, bottom = 64, 16, 28, 110
    legend_h = 16 * min(len(series), 8)
    plot_w, plot_h = width - left - right, height - top - bottom
    values = [v for g in groups.values() for v in g.values() if v is not None and math.isfinite(v)]
    hi = y_max if y_max is not None else max([0.0, *values]) or 1.0
    lo = min([0.0, *values])
    if hi == lo:
        hi = lo + 1.0
    names = list(groups)
    slot = plot_w / max(1, len(names))
    bar = slot * 0.8 / max(1, len(series))

    def y(v: float) -> float:
        return round(top + plot_h - plot_h * (v - lo) / (hi - lo), 1)

    parts = [
        f'<text x="{left}" y="16" font-family="sans-serif" font-size="13">{esc(title)}</text>',
        f'<rect x="{left}" y="{top}" width="{plot_w}" height="{plot_h}" fill="none" stroke="#888"/>',
    ]
    for k in range(5):
        v = lo + (hi - lo) * k / 4
        parts.append(
            f'<line x1="{left}" x2="{left + plot_w}" y1="{y(v)}" y2="{y(v)}" stroke="#ddd"/>'
            f'<text x="{left - 4}" y="{y(v) + 4}" text-anchor="end" font-family="sans-serif"'
            f' font-size="11">{esc(fmt_number(v, 3))}</text>'
        )
    parts.append(
        f'<text x="14" y="{top + plot_h / 2}" text-anchor="middle" font-family="sans-serif"'
        f' font-size="12" transform="rotate(-90 14 {top + plot_h / 2})">{esc(y_label)}</text>'
    )
    if not names:
        parts.append(
            f'<text x="{left + plot_w / 2}" y="{top + plot_h / 2}" text-anchor="middle"'
            f' font-family="sans-serif" font-size="12" fill="#666">no data yet</text>'
        )
    for i, name in enumerate(names):
        x0 = left + slot * i + slot * 0.1
        for k, s in enumerate(series):
            value = groups[name].get(s)
            if value is None or not math.isfinite(value):
                continue
            y0, y1 = sorted((y(value), y(max(lo, 0.0))))
            parts.append(
                f'<rect x="{round(x0 + bar * k, 1)}" y="{y0}" width="{round(bar, 1)}"'
                f' height="{round(max(y1 - y0, 0.5), 1)}" fill="{PALETTE[k % len(PALETTE)]}">'
                f"<title>{esc(name)}: {esc(s)} {esc(fmt_number(value))}</title></rect>"
            )
        cx = round(left + slot * (i + 0.5), 1)
        cy = top + plot_h + 8
        label = name if len(name) <= 28 else name[:27] + "\u2026"
        parts.append(
            f'<text x="{cx}" y="{cy}" text-anchor="end" font-family="sans-serif" font-size="10"'
            f' transform="rotate(-50 {cx} {cy})">{esc(label)}</text>'
        )
    for k, s in enumerate(series[:8]):
        ly = height + 16 * k + 4
        parts.append(
            f'<rect x="{left}" y="{ly}" width="10" height="10" fill="{PALETTE[k % len(PALETTE)]}"/>'
            f'<text x="{left + 16}" y="{ly + 9}" font-family="sans-serif" font-size="11">'
            f"{esc(s)}</text>"
        )
    total = height + legend_h
    return Markup(
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{total}"'
        f' viewBox="0 0 {width} {total}" role="img" aria-label="{esc(title)}">'
        f"<title>{esc(title)}</title>" + "".join(parts) + "</svg>\n"
    )


def _scores_svg(live: BatchLive) -> Markup:
    snap = live.snapshot()
    per = snap["figures"]["score_per_instance"]
    return bar_chart(
        per,
        [p for p in snap["planners"] if any(p in v for v in per.values())] or snap["planners"],
        title="Score per instance",
        y_label=f"IPPC score ({snap['rules']})",
        y_max=1.0,
    )


def _times_svg(live: BatchLive) -> Markup:
    snap = live.snapshot()
    groups: dict[str, dict[str, float | None]] = {}
    for entry in snap["figures"]["time_per_turn"].values():
        groups.setdefault(entry["domain"], {})[entry["planner"]] = entry["mean"] * 1000.0
    return bar_chart(groups, snap["planners"], title="Time per turn", y_label="ms per turn (mean)")


def _rewards_svg(live: BatchLive, instance: str) -> Markup:
    snap = live.snapshot()
    if instance not in {i["name"] for i in snap["instances"]}:
        raise not_found(f"instance {instance}")
    curves = snap["figures"]["reward_per_round"].get(instance, {})
    series = {p: [pt[1] for pt in curves[p]] for p in snap["planners"] if p in curves}
    return line_chart(
        series,
        title=instance,
        x_label="round",
        y_label="mean round reward so far",
        width=420,
        height=220,
    )


# ------------------------------------------------------------- the page


def _index(live: BatchLive) -> str:
    snap = live.snapshot()
    rows = _rows(snap)
    planners = snap["planners"]
    grid_cols = [("instance", "instance"), ("domain", "domain")] + [
        (_grid_key(p, planners), p) for p in planners
    ]
    figures = [
        h(
            "img",
            src=f"/figure/scores.svg?v={snap['seq']}",
            alt="score per instance",
            data_page_chart="/figure/scores.svg",
            data_version="figures",
        ),
        h(
            "img",
            src=f"/figure/times.svg?v={snap['seq']}",
            alt="time per turn",
            data_page_chart="/figure/times.svg",
            data_version="figures",
        ),
    ]
    rewards = [
        h(
            "img",
            src=f"/figure/rewards/{quote(i['name'], safe='')}.svg?v={snap['seq']}",
            alt=f"reward per round on {i['name']}",
            data_page_chart=f"/figure/rewards/{quote(i['name'], safe='')}.svg",
            data_version="figures",
        )
        for i in snap["instances"]
    ]
    return page(
        "rddl-batch",
        h(
            "p",
            "Experiment ",
            h("strong", field("experiment", snap["experiment"])),
            ": ",
            field("state", snap["state"]),
            ". ",
            field("counts", _counts_text(snap["counts"])),
            ".",
        ),
        h("h2", "Planner x instance"),
        live_table("grid", grid_cols, rows["grid"], state_field=None),
        h("h2", "IPPC scores so far (", field("rules", snap["rules"]), ")"),
        h("p", field("scores-note", _score_note(snap["scores"])), class_="muted"),
        live_table(
            "overall",
            [
                ("rank", "#"),
                ("planner", "planner"),
                ("score", "score"),
                ("ci95", "95% CI"),
                ("instances", "instances"),
            ],
            rows["overall"],
            state_field=None,
        ),
        h("h3", "Per domain"),
        live_table(
            "domains",
            [("domain", "domain")] + [(_grid_key(p, planners), p) for p in planners],
            rows["domains"],
            state_field=None,
        ),
        h("h2", "Figures"),
        h("div", figures, class_="figures"),
        h("h3", "Reward per round (running mean)"),
        h("div", rewards, class_="figures"),
        h("h2", "Jobs"),
        live_table("jobs", JOB_COLUMNS, rows["jobs"]),
        events="/events",
        nav={"rddl-batch": "/", "snapshot (JSON)": "/snapshot.json"},
    )


def batch_routes(live: BatchLive, feed: Feed) -> Routes:
    """The page's routes (see the module doc)."""
    routes = Routes()
    routes.add("/", lambda r: Response(_index(live)))
    routes.add("/events", lambda r: EventStream(feed, [TOPIC], lambda: page_events(live)))
    routes.add("/snapshot.json", lambda r: Response(to_json(live.snapshot()), content_type=JSON))
    routes.add("/figure/scores.svg", lambda r: Response(_scores_svg(live), content_type=SVG))
    routes.add("/figure/times.svg", lambda r: Response(_times_svg(live), content_type=SVG))
    routes.add(
        "/figure/rewards/{instance}.svg",
        lambda r: Response(_rewards_svg(live, r.params["instance"]), content_type=SVG),
    )
    return routes


class BatchWeb:
    """The page, served by a thread with its own trio loop (see the module doc):
    `start()` returns the port once it listens (or raises the `OSError` of a port it
    cannot have); `stop()` ends the viewers' streams (after the changes gathered so far)
    and the thread. The changes are sent to the viewers every `flush` seconds, gathered
    (`PageUpdates`)."""

    def __init__(
        self, live: BatchLive, options: WebOptions, *, grace: float = 1.0, flush: float = 0.25
    ) -> None:
        self.live = live
        self.options = options
        self.grace = grace
        self.flush = flush
        self._updates = PageUpdates()
        self.feed = Feed()
        self.port: int | None = None
        self._translate = _Translator(live)
        self._token: trio.lowlevel.TrioToken | None = None
        self._stop: trio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._main, name="batch-web", daemon=True)
        self._unsubscribe = live.subscribe(self._publish)

    def start(self) -> int:
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            self._unsubscribe()
            raise self._error
        assert self.port is not None
        return self.port

    def stop(self) -> None:
        self._unsubscribe()
        token, stop = self._token, self._stop
        if token is not None and stop is not None:
            try:
                token.run_sync_soon(stop.set)
            except trio.RunFinishedError:
                pass
        self._thread.join(self.grace + 5.0)

    def _publish(self, event: dict[str, Any]) -> None:
        """In the run loop's thread: hand the event to the page's loop, never waiting."""
        token = self._token
        if token is None:
            return
        try:
            token.run_sync_soon(self._send, event)
        except trio.RunFinishedError:
            pass

    def _send(self, event: dict[str, Any]) -> None:
        """In the page's loop: gathered until the next flush."""
        if not self.feed.watched(TOPIC):
            return
        for out in self._translate(event):
            self._updates.add(out)

    async def _flush(self) -> None:
        while True:
            await trio.sleep(self.flush)
            events = self._updates.take()
            if self.feed.watched(TOPIC):
                for event in events:
                    self.feed.publish(event, TOPIC)

    def _main(self) -> None:
        try:
            trio.run(self._serve)
        except BaseException as err:  # noqa: BLE001 - handed to start()
            while isinstance(err, BaseExceptionGroup) and len(err.exceptions) == 1:
                err = err.exceptions[0]
            if not self._ready.is_set():
                self._error = err
                self._ready.set()
            else:
                log.error("the web page stopped: %s: %s", type(err).__name__, err)

    async def _serve(self) -> None:
        self._stop = trio.Event()
        async with trio.open_nursery() as nursery:
            self.port = await nursery.start(
                serve_web, batch_routes(self.live, self.feed), self.options
            )
            self._token = trio.lowlevel.current_trio_token()
            nursery.start_soon(self._flush)
            self._ready.set()
            await self._stop.wait()
            for event in self._updates.take():  # (the last changes, then the end)
                self.feed.publish(event, TOPIC)
            self.feed.close()  # the viewers' streams end after what is queued
            with trio.move_on_after(self.grace):
                while self.feed.viewers:
                    await trio.sleep(0.05)
            nursery.cancel_scope.cancel()
