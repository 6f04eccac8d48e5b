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

import json
import logging
import signal
import threading
import zlib
from collections.abc import Callable, Mapping, Sequence
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
    cell,
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
    web_url,
)
from ..web.chart import bar_chart
from ..web.pages import PageUpdates
from .live import STATUSES, BatchLive

__all__ = ["BatchWeb", "batch_routes", "bar_chart", "job_events", "page_events"]

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


def job_path(key: str) -> str:
    """The path of a job's page (its session)."""
    return "/job/" + quote(key, safe="")


def _grid_value(job: Mapping[str, Any]) -> dict[str, Any]:
    """A grid cell: the job's text, coloured by its status, a link to its page."""
    return cell(_grid_cell(job), state=job["status"], href=job_path(job["key"]))


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


def _unscored(jobs: Sequence[Mapping[str, Any]]) -> dict[tuple[str, str | None], dict[str, int]]:
    """Per (planner, None) and (planner, domain): its jobs not scored yet, by status."""
    out: dict[tuple[str, str | None], dict[str, int]] = {}
    for job in jobs:
        if job["status"] in ("running", "pending", "interrupted"):
            for key in ((job["planner"], None), (job["planner"], job.get("domain"))):
                counts = out.setdefault(key, {})
                counts[job["status"]] = counts.get(job["status"], 0) + 1
    return out


def _unscored_text(counts: Mapping[str, int] | None) -> str:
    if not counts:
        return ""
    order = ("running", "pending", "interrupted")
    return ", ".join(f"{counts[k]} {k}" for k in order if counts.get(k))


def _score_rows(
    scores: Mapping[str, Any], planners: Sequence[str], jobs: Sequence[Mapping[str, Any]] = ()
) -> list[tuple[str, str, dict[str, Any]]]:
    """The rows of the overall table (one per planner, with its rank, and its jobs not
    scored yet: running, pending) and of the per-domain table (one per domain, a
    planner's score and its 95% interval per column, as the report's table; a planner
    with jobs not scored yet there says so: `running` rather than a 0)."""
    unscored = _unscored(jobs)
    rows: list[tuple[str, str, dict[str, Any]]] = []
    ranked = list(scores.get("planners", []))
    for rank, p in enumerate(ranked, 1):
        cells = {k: p[k] for k in ("planner", "score", "ci95", "instances")}
        cells["unscored"] = _unscored_text(unscored.get((p["planner"], None)))
        rows.append(("overall", p["planner"], {"rank": rank, **cells}))
    scored = {p["planner"] for p in ranked}
    for planner in planners:
        if planner not in scored:
            rows.append(
                (
                    "overall",
                    planner,
                    {
                        "rank": "",
                        "planner": planner,
                        "score": "not scored yet",
                        "ci95": None,
                        "instances": 0,
                        "unscored": _unscored_text(unscored.get((planner, None))),
                    },
                )
            )
    domains: dict[str, dict[str, Any]] = {}
    for d in scores.get("domains", []):
        if d["planner"] not in planners:
            continue
        text = fmt_number(d["score"], 3)
        if d["ci95"] is not None:
            text += f" \u00b1 {fmt_number(d['ci95'], 2)}"
        more = _unscored_text(unscored.get((d["planner"], d["domain"])))
        if more:
            text += f" (+{more})"
        cells = domains.setdefault(d["domain"], {"domain": d["domain"]})
        cells[_grid_key(d["planner"], planners)] = text
    for (planner, domain), counts in unscored.items():
        if domain is None or planner not in planners:
            continue
        cells = domains.setdefault(domain, {"domain": domain})
        cells.setdefault(_grid_key(planner, planners), _unscored_text(counts))
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


def _layout(planners: Sequence[str], instances: Sequence[Any]) -> str:
    """What the grid's columns and rows were built for (a short digest)."""
    names = [*planners, "|", *(i["name"] if isinstance(i, Mapping) else i for i in instances)]
    return f"{zlib.crc32(json.dumps(names).encode()):08x}"


def _fields(snap: Mapping[str, Any]) -> dict[str, Any]:
    fields: dict[str, Any] = {
        "layout": _layout(snap["planners"], snap["instances"]),
        "experiment": snap["experiment"],
        "state": snap["state"],
        "kept": snap.get("kept") or "",
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
        ] = _grid_value(job)
    tables: dict[str, list[tuple[str, Mapping[str, Any]]]] = {
        "grid": list(grid.items()),
        "jobs": [(job["key"], _job_cells(job)) for job in snap["jobs"]],
        "overall": [],
        "domains": [],
    }
    for table, key, cells in _score_rows(snap["scores"], planners, snap["jobs"]):
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
                    {_grid_key(job["planner"], planners): _grid_value(job)},
                ),
                ("jobs", job["key"], _job_cells(job)),
            ]
            rows += _score_rows(self.live.scores(), planners, self.live.jobs())
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
                    {_grid_key(job["planner"], planners): _grid_value(job)},
                ),
                ("jobs", job["key"], {"progress": _progress(job)}),
            ]
            return [rows_event(rows)]
        if kind == "scores":
            scores = event["scores"]
            fields = {"scores-note": _score_note(scores), "figures": event["seq"]}
            if event.get("why") == "batch":  # the run began: its planners and instances
                snap = self.live.snapshot()
                fields["layout"] = _layout(snap["planners"], snap["instances"])
            return [
                rows_event(_score_rows(scores, self.live.planners(), self.live.jobs())),
                fields_event(fields),
            ]
        if kind == "batch":
            return [fields_event({"state": event["state"], "kept": event.get("kept") or ""})]
        return []


# ------------------------------------------------------------- the figures


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
        h("p", field("kept", snap.get("kept") or ""), class_="kept-line"),
        h("h2", "Planner x instance"),
        h(
            "p",
            "Each cell is a job, coloured by its state; it links to the job's session: ",
            [h("span", s, data_state=s) for s in STATUSES],
            class_="legend muted",
        ),
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
                ("instances", "instances scored"),
                ("unscored", "not scored yet"),
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
        live_table("jobs", JOB_COLUMNS, rows["jobs"], links={"key": "/job/{key}"}),
        events="/events",
        layout=_layout(planners, snap["instances"]),
        nav={"rddl-batch": "/", "snapshot (JSON)": "/snapshot.json"},
    )


# ------------------------------------------------------------- a job's page

JOB_FACTS = (
    ("planner", "planner"),
    ("instance", "instance"),
    ("domain", "domain"),
    ("job-state", "state"),
    ("job-progress", "progress"),
    ("attempts", "attempts"),
    ("job-reason", "reason"),
    ("job-rounds", "rounds played"),
    ("job-mean", "mean round reward"),
)
SESSION_LABELS = (
    ("server_session_id", "session number"),
    ("client_name", "client"),
    ("seed", "seed"),
    ("num_rounds", "rounds to play"),
    ("rounds_used", "rounds played"),
    ("time_allowed_ms", "time allowed (ms)"),
    ("total_reward", "total reward"),
    ("status", "status"),
    ("reason", "reason"),
)
ROUND_COLUMNS = [
    ("round", "round"),
    ("reward", "reward"),
    ("turns", "turns"),
    ("status", "status"),
    ("seconds", "seconds"),
]


def _job(live: BatchLive, key: str) -> dict[str, Any]:
    job = live.job(key)
    if job is None:
        raise not_found(f"job {key}")
    return job


def _job_fields(job: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "planner": job["planner"],
        "instance": job["instance"],
        "domain": job.get("domain") or "",
        "job-state": job["status"],
        "job-progress": _progress(job),
        "attempts": job.get("attempts"),
        "job-reason": job.get("reason") or "",
        "job-rounds": job.get("rounds"),
        "job-mean": job.get("mean"),
        "job-chart": f"{job['status']}-{job.get('rounds')}",
    }


def _round_rows(session: Mapping[str, Any] | None) -> list[tuple[str, dict[str, Any]]]:
    rows = []
    for k, r in enumerate((session or {}).get("rounds", ())):
        cells = {
            "round": r["round"] if r["counted"] else f"{r['round']} (practice)",
            "reward": r["reward"],
            "turns": r["turns"],
            "status": r["status"],
            "seconds": r["seconds"],
            "state": "failed" if r["status"] in ("dropped", "interrupted") else "finished",
        }
        rows.append((str(k), cells))
    return rows


def job_events(live: BatchLive, key: str) -> list[dict[str, Any]]:
    """The events that draw a job's page (a viewer's first ones, and after each change)."""
    job = _job(live, key)
    rows = [("rounds", k, c) for k, c in _round_rows(live.session(key))]
    return [rows_event(rows, reset=True), fields_event(_job_fields(job))]


def _job_page(live: BatchLive, key: str) -> str:
    job = _job(live, key)
    fields = _job_fields(job)
    got = live.session(key)
    facts = h(
        "dl",
        [(h("dt", label), h("dd", field(name, fields[name]))) for name, label in JOB_FACTS],
        class_="facts",
    )
    if got is None:
        session = h(
            "p",
            "No session in the database yet: it is there once the job is done"
            " (a job that failed before its session began has none).",
            class_="muted",
        )
    else:
        facts_s = got["session"]
        session = h(
            "dl",
            [(h("dt", label), h("dd", facts_s.get(name))) for name, label in SESSION_LABELS],
            class_="facts",
        )
    chart = h(
        "img",
        src=f"{job_path(key)}/rewards.svg?v={quote(fields['job-chart'])}",
        alt="reward per round",
        data_page_chart=f"{job_path(key)}/rewards.svg",
        data_version="job-chart",
    )
    return page(
        f"job {key}",
        facts,
        h("h2", "Session"),
        session,
        h("h2", "Reward per round"),
        chart,
        h("h2", "Rounds"),
        live_table("rounds", ROUND_COLUMNS, _round_rows(got)),
        events=f"{job_path(key)}/events",
        nav={"rddl-batch": "/", "snapshot (JSON)": "/snapshot.json"},
    )


def _job_rewards_svg(live: BatchLive, key: str) -> Markup:
    _job(live, key)
    got = live.session(key)
    rounds = [r for r in (got or {}).get("rounds", ()) if r["counted"]]
    return line_chart(
        {key: [r["reward"] for r in rounds]},
        title=f"{key}: reward per round",
        x_start=rounds[0]["round"] if rounds and rounds[0]["round"] is not None else 1,
        width=560,
        height=240,
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
    routes.add("/job/{key}", lambda r: Response(_job_page(live, r.params["key"])))
    routes.add("/job/{key}/events", lambda r: _job_stream(live, feed, r.params["key"]))
    routes.add(
        "/job/{key}/rewards.svg",
        lambda r: Response(_job_rewards_svg(live, r.params["key"]), content_type=SVG),
    )
    return routes


def _job_stream(live: BatchLive, feed: Feed, key: str) -> EventStream:
    _job(live, key)
    return EventStream(feed, [job_topic(key)], lambda: job_events(live, key))


def job_topic(key: str) -> str:
    """The feed's topic of a job's page."""
    return f"job:{key}"


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
        self._jobs_changed: set[str] = set()  # jobs whose pages are watched and changed
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

    def keep_up(
        self, *, say: Callable[[str], object] | None = None, stopped: threading.Event | None = None
    ) -> None:
        """After the run: keep the page up, and say so on the page, in the log and with
        `say` (the CLI's stderr), until the process gets Ctrl-C (SIGINT) or SIGTERM (or
        `stopped` is set); then stop it. A short run ends before a browser can open its
        page: this is what lets one look at it."""
        url = web_url(self.options, self.port) if self.port is not None else "the web view"
        self.live.page_kept(
            "The run is over; this page stays up until rddl-batch is stopped (Ctrl-C)."
        )
        line = f"the run is over; the web view stays up on {url} until you stop rddl-batch (Ctrl-C)"
        log.info("%s", line)
        if say is not None:
            say(line)
        stop = stopped or threading.Event()
        old = None
        try:
            old = signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())
        except ValueError:  # not the main thread: Ctrl-C and `stopped` only
            pass
        try:
            while not stop.wait(0.5):
                pass
        except KeyboardInterrupt:
            pass
        finally:
            if old is not None:
                signal.signal(signal.SIGTERM, old)
            self.stop()

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
        """In the page's loop: gathered until the next flush (a job's page: its
        whole picture again, at most once a flush)."""
        if event["type"] in ("job", "progress"):
            key = event["job"]["key"] if event["type"] == "job" else event["key"]
            if self.feed.watched(job_topic(key)):
                self._jobs_changed.add(key)
        if not self.feed.watched(TOPIC):
            return
        for out in self._translate(event):
            self._updates.add(out)

    def _publish_jobs(self) -> None:
        changed, self._jobs_changed = self._jobs_changed, set()
        for key in changed:
            if self.feed.watched(job_topic(key)):
                for event in job_events(self.live, key):
                    self.feed.publish(event, job_topic(key))

    async def _flush(self) -> None:
        while True:
            await trio.sleep(self.flush)
            events = self._updates.take()
            if self.feed.watched(TOPIC):
                for event in events:
                    self.feed.publish(event, TOPIC)
            self._publish_jobs()

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
            self._publish_jobs()
            self.feed.close()  # the viewers' streams end after what is queued
            with trio.move_on_after(self.grace):
                while self.feed.viewers:
                    await trio.sleep(0.05)
            nursery.cancel_scope.cancel()
