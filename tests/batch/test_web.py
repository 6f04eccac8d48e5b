"""rddl-batch's web page over real sockets on 127.0.0.1: the page, its event stream
during a real run, the figures, the JSON snapshot, the escaping of hostile names, and
the CLI's --web."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import h11
import pytest
import trio
from ippc.batch import load_experiment, run_batch
from ippc.batch.live import BatchLive
from ippc.batch.web import BatchWeb
from ippc.web import WebOptions

from ..chromium import console_errors, headless_chromium
from ..conftest import RDDLSIM_RDDL, REPO
from ..web.httpclient import events, fetch

HOSTILE = "<img src=x onerror=alert(1)>"
ESCAPED = "&lt;img src=x onerror=alert(1)&gt;"

EXPERIMENT = f"""
name = "web {HOSTILE}"
rounds = 2
timeout = 120
seed = 5
instances = [
    "{REPO / "domains" / "print_jobs" / "instance1.rddl"}",
    "{RDDLSIM_RDDL / "sysadmin_inst_mdp__1.rddl"}",
]

# 0.05 s a step: a round lasts 1-2 s, several of the page's flushes (4 a second),
# so a viewer sees "running: round 1, turn N" also when the machine is busy (with
# 2 trials a step a whole job could fall between two flushes under CI's load)
[planners.mcts]
planner = "mcts"
options = {{ time_per_step = "0.05" }}

[planners.broken]
command = ["/no/such/folder/{HOSTILE}", "{{port}}"]
"""


def experiment_file(folder: Path, *, print_jobs_last: bool = False) -> Path:
    """The experiment above (with `print_jobs_last`, its two instances swapped: the
    longer jobs, print_jobs's, come when each planner has a job done already)."""
    path = folder / "web.toml"
    text = EXPERIMENT
    if print_jobs_last:
        first, second = (
            f'"{REPO / "domains" / "print_jobs" / "instance1.rddl"}",',
            f'"{RDDLSIM_RDDL / "sysadmin_inst_mdp__1.rddl"}",',
        )
        text = text.replace(first, "@@").replace(second, first).replace("@@", second)
    path.write_text(text)
    return path


def cells_of(event: dict[str, Any], table: str) -> dict[str, dict[str, Any]]:
    return {r["key"]: r.get("cells", {}) for r in event.get("rows", []) if r["table"] == table}


@pytest.mark.trio
async def test_the_page_follows_a_run_and_escapes_what_it_shows(tmp_path: Path) -> None:
    path = experiment_file(tmp_path)
    live = BatchLive("ippc2014")
    page = BatchWeb(live, WebOptions(port=0))
    port = page.start()
    try:
        before = await fetch(port, "/")
        assert before.status == 200 and "rddl-batch" in before.text
        async with events(port, "/events") as stream:
            assert stream.reply.status == 200
            assert stream.reply.headers["content-type"].startswith("text/event-stream")
            first = await stream.next()
            assert first["type"] == "rows" and first["reset"] is True
            seen: list[dict[str, Any]] = []

            async def play() -> None:
                await trio.to_thread.run_sync(
                    lambda: run_batch(
                        load_experiment(path), tmp_path / "db.sqlite", jobs=1, observer=live
                    )
                )

            async with trio.open_nursery() as nursery:
                nursery.start_soon(play)
                while True:
                    event = await stream.next(timeout=120)
                    seen.append(event)
                    if event["type"] == "fields" and event["fields"].get("state") == "finished":
                        break
            # the grid and the jobs changed as the jobs ran, turn by turn
            # (a job's cell: its text, its state's colour, a link to the job's page)
            grid = [
                v
                for e in seen
                for c in cells_of(e, "grid").values()
                for v in c.values()
                if isinstance(v, dict)
            ]
            assert any(
                v["text"].startswith("running: round 1, turn ") and v["state"] == "running"
                for v in grid
            )
            assert any(
                v["text"].startswith("finished: 2 rounds, mean ") and v["state"] == "finished"
                for v in grid
            )
            assert all(v["href"].startswith("/job/") for v in grid)
            jobs = [(k, c) for e in seen for k, c in cells_of(e, "jobs").items()]
            failed = [c for k, c in jobs if k.startswith("broken@") and c.get("state") == "failed"]
            assert failed and HOSTILE in failed[0]["reason"]  # as text, for textContent
            overall = [c for e in seen for c in cells_of(e, "overall").values()]
            assert {c["planner"] for c in overall} == {"noop", "random", "mcts", "broken"}
            figures = [e["fields"]["figures"] for e in seen if "figures" in e.get("fields", {})]
            # redrawn as the jobs finish, in order; the page sends a field's last value a
            # flush (0.25 s), so jobs that end within one flush show as one redraw (a
            # fresh-clone CI run saw 5 for the 8 jobs once mcts solved print_jobs's roots)
            assert len(set(figures)) >= 3 and figures == sorted(figures)
        snap = live.snapshot()
        assert snap["counts"]["finished"] == 6 and snap["counts"]["failed"] == 2
        # the page as it is now, every name escaped
        index = await fetch(port, "/")
        assert index.status == 200
        assert HOSTILE not in index.text
        assert f"web {ESCAPED}" in index.text and ESCAPED in index.text
        assert "finished: 2 rounds, mean" in index.text
        assert index.headers["content-security-policy"].startswith("default-src 'none'")
        raw = await fetch(port, "/snapshot.json")
        assert raw.status == 200 and raw.headers["content-type"] == "application/json"
        assert b"<" not in raw.body and b">" not in raw.body
        assert raw.json() == json.loads(json.dumps(live.snapshot() | {"seq": raw.json()["seq"]}))
        assert raw.json()["experiment"] == f"web {HOSTILE}"
        for figure in (
            "/figure/scores.svg",
            "/figure/times.svg",
            "/figure/rewards/print_jobs_inst_1.svg",
            "/figure/rewards/sysadmin_inst_mdp__1.svg",
        ):
            svg = await fetch(port, figure)
            assert svg.status == 200 and svg.headers["content-type"] == "image/svg+xml", figure
            assert svg.text.startswith("<svg") and HOSTILE not in svg.text
            assert "mcts" in svg.text
        assert (await fetch(port, "/figure/rewards/nowhere.svg")).status == 404
        # a new viewer gets the whole picture first
        async with events(port, "/events") as stream:
            snapshot = await stream.next()
            assert cells_of(snapshot, "jobs")["broken@print_jobs_inst_1"]["state"] == "failed"
            fields = await stream.next()
            assert fields["fields"]["experiment"] == f"web {HOSTILE}"
            assert fields["fields"]["state"] == "finished"
            # stopping the page ends its viewers' streams
            await trio.to_thread.run_sync(page.stop)
            # (ended: whole, or cut after the last event)
            with pytest.raises((EOFError, h11.RemoteProtocolError)):
                while True:
                    await stream.next(timeout=10)
    finally:
        page.stop()


@pytest.mark.trio
async def test_a_viewer_that_does_not_read_is_dropped_and_the_batch_goes_on(
    tmp_path: Path,
) -> None:
    live = BatchLive()
    # flushed every 5 ms (an event or two a turn) into a feed bound of 4 events
    page = BatchWeb(live, WebOptions(port=0), flush=0.005)
    page.feed.queue_size = 4
    port = page.start()
    try:
        # a viewer that asks for the events and never reads them, with a small receive
        # buffer (so that the kernel's buffers do not take the whole run's events)
        sock = trio.socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
        with sock:
            with trio.fail_after(10):
                await sock.connect(("127.0.0.1", port))
                request = f"GET /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n"
                await sock.send(request.encode())
                while not page.feed.viewers:
                    await trio.sleep(0.01)
            t0 = time.monotonic()
            summary = await trio.to_thread.run_sync(
                lambda: run_batch(
                    load_experiment(experiment_file(tmp_path)),
                    tmp_path / "db.sqlite",
                    jobs=1,
                    observer=live,
                )
            )
            assert summary.finished == 6 and time.monotonic() - t0 < 120
            assert page.feed.dropped == 1 and page.feed.viewers == 0
    finally:
        page.stop()


def test_a_port_that_is_taken_is_refused(tmp_path: Path) -> None:
    first = BatchWeb(BatchLive(), WebOptions(port=0))
    port = first.start()
    try:
        second = BatchWeb(BatchLive(), WebOptions(port=port))
        with pytest.raises(OSError):
            second.start()
    finally:
        first.stop()


@pytest.mark.alone  # worker processes
def test_rddl_batch_run_with_web(tmp_path: Path) -> None:
    path = experiment_file(tmp_path)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ippc.batch.cli",
            "run",
            str(path),
            "--db",
            str(tmp_path / "db.sqlite"),
            "--jobs",
            "2",
            "--web",
            "0",
            "--rules",
            "ippc2011",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline().decode()
        assert line.startswith("web view on http://127.0.0.1:"), line
        port = int(line.rsplit(":", 1)[1].strip().rstrip("/"))

        async def look() -> dict[str, Any]:
            with trio.fail_after(60):
                while True:  # until the run has registered its jobs
                    snap: dict[str, Any] = (await fetch(port, "/snapshot.json")).json()
                    if snap["jobs"]:
                        break
                    await trio.sleep(0.1)
            page = await fetch(port, "/")
            assert page.status == 200 and ESCAPED in page.text
            return snap

        snap = trio.run(look)
        assert snap["rules"] == "ippc2011" and snap["experiment"] == f"web {HOSTILE}"
        # the run ends; its page stays up, and says so, until the process is stopped
        deadline = time.monotonic() + 180
        while True:
            line = proc.stderr.readline().decode()
            assert line or proc.poll() is None, "rddl-batch ended without keeping its page"
            if line.startswith("the run is over; the web view stays up on"):
                break
            assert time.monotonic() < deadline, "the run did not end in 180 s"
        assert f"http://127.0.0.1:{port}/ until you stop rddl-batch (Ctrl-C)" in line

        async def after() -> dict[str, Any]:
            snap: dict[str, Any] = (await fetch(port, "/snapshot.json")).json()
            page = await fetch(port, "/")
            assert page.status == 200 and "this page stays up until" in page.text
            return snap

        snap = trio.run(after)
        assert snap["state"] == "finished" and snap["counts"]["finished"] == 6
        assert snap["kept"].startswith("The run is over; this page stays up until")
        time.sleep(1.0)
        assert proc.poll() is None  # still up
        # SIGTERM, as a service manager stops it (the keep-up loop's own handler); Ctrl-C
        # takes the KeyboardInterrupt path, which one fresh-clone run saw hang on exit
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 1, err  # (two jobs failed: the run's own exit status)
        assert b"6/8 sessions done" in out
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)


def test_web_options_are_checked() -> None:
    from click.testing import CliRunner
    from ippc.batch.cli import main

    result = CliRunner().invoke(main, ["run", "nothing.toml", "--web-host", "127.0.0.1"])
    assert result.exit_code == 2
    result = CliRunner().invoke(
        main, ["run", str(REPO / "examples" / "small.toml"), "--web-host", "x"]
    )
    assert result.exit_code == 2 and "--web" in result.output


GRID_JS = """
const text = f => { const el = document.querySelector('[data-page-field="' + f + '"]');
                    return el ? el.textContent : null; };
const grid = document.querySelector('tbody[data-table="grid"]');
if (!grid || !document.querySelector('tbody[data-table="overall"]')) return null;
const heads = [...grid.parentElement.querySelectorAll('thead th')].map(th => th.textContent);
const cells = [];
for (const tr of grid.children) {
  const tds = [...tr.children];
  for (const td of tds) {
    if (!td.dataset.field.startsWith('p')) continue;
    const a = td.querySelector('a');
    cells.push({planner: heads[tds.indexOf(td)], instance: tr.dataset.key,
                state: td.dataset.state || null, text: td.textContent,
                href: a ? a.getAttribute('href') : null,
                background: getComputedStyle(td).backgroundColor});
  }
}
const overall = {};
for (const tr of document.querySelector('tbody[data-table="overall"]').children) {
  const get = f => tr.querySelector('[data-field="' + f + '"]').textContent;
  overall[tr.dataset.key] = {instances: get('instances'), unscored: get('unscored'),
                             score: get('score')};
}
return {cells: cells, overall: overall, kept: text("kept"), counts: text("counts")};
"""

DONE = ("finished", "timeout", "failed")


@pytest.mark.alone  # a browser and worker processes
def test_chromium_sees_jobs_end_and_the_hostile_name_as_text(tmp_path: Path) -> None:
    """In Chromium: the grid's cells coloured by the job's state and linking to the
    job's page (its session's rounds as the database has them), a running job shown as
    running beside the scores so far (not a 0 among them), the page kept up after the
    run, the hostile name as text."""
    import sqlite3
    from urllib.parse import quote

    from ippc.web import fmt_number

    browser = headless_chromium()
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.common.by import By

    path = experiment_file(tmp_path, print_jobs_last=True)
    db = tmp_path / "db.sqlite"
    cmd = [sys.executable, "-m", "ippc.batch.cli", "run", str(path), "--db"]
    cmd += [str(db), "--jobs", "1", "--web", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert line.startswith("web view on http://127.0.0.1:"), line
        url = line.split(" on ", 1)[1].strip()
        # (opened before the run has its planners: the page loads itself again once
        # it has them, as its grid's columns are theirs)
        browser.get(url)
        running_seen = 0
        deadline = time.monotonic() + 180
        while True:
            assert time.monotonic() < deadline, "the run did not end in 180 s"
            assert proc.poll() is None, proc.communicate()
            # one look at the grid and the scores together (live.js applies an event whole)
            try:
                view = browser.execute_script(GRID_JS)
            except WebDriverException:  # (between two loads of the page)
                view = None
            if view is None:
                time.sleep(0.1)
                continue
            if view["kept"]:
                break
            for c in view["cells"]:
                if c["state"] != "running":
                    continue
                assert c["text"].startswith("running"), c
                mine = [d for d in view["cells"] if d["planner"] == c["planner"]]
                done = sum(1 for d in mine if d["state"] in DONE)
                row = view["overall"][c["planner"]]
                # running, not a 0 in the scores: its instances scored are its jobs done
                assert "1 running" in row["unscored"], (c, row)
                assert row["instances"] == str(done), (c, row)
                if done:
                    running_seen += 1
            time.sleep(0.1)
        assert running_seen > 0, "never saw a job run beside a score of its planner"
        assert view["kept"] == (
            "The run is over; this page stays up until rddl-batch is stopped (Ctrl-C)."
        )
        assert "8 jobs: 6 finished, 2 failed" in view["counts"]
        # the grid: every cell coloured by its job's state, a link to the job's page
        view = browser.execute_script(GRID_JS)
        states = {(c["planner"], c["instance"]): c["state"] for c in view["cells"]}
        assert len(states) == 8
        for (planner, _instance), state in states.items():
            assert state == ("failed" if planner == "broken" else "finished")
        colours = {c["state"]: c["background"] for c in view["cells"]}
        assert colours == {"finished": "rgb(228, 239, 248)", "failed": "rgb(253, 233, 223)"}
        for c in view["cells"]:
            assert c["href"] == "/job/" + quote(f"{c['planner']}@{c['instance']}", safe="")
        assert all(row["unscored"] == "" for row in view["overall"].values())
        # a job's page: its session's rounds, as the database has them
        browser.execute_script(
            "document.querySelector('a[href=\"/job/mcts%40print_jobs_inst_1\"]').click()"
        )
        deadline = time.monotonic() + 20
        while browser.title != "job mcts@print_jobs_inst_1":
            assert time.monotonic() < deadline, f"the link led to {browser.title!r}"
            time.sleep(0.1)
        with sqlite3.connect(db) as conn:
            rewards = [
                r[0]
                for r in conn.execute(
                    "SELECT r.reward FROM jobs j JOIN rounds r ON r.session_id = j.session_id"
                    " WHERE j.job_key = 'mcts@print_jobs_inst_1' ORDER BY r.id"
                )
            ]
        assert len(rewards) == 2
        # (after the stream's first events, which rebuild the rows: then one look)
        deadline = time.monotonic() + 20
        while not browser.execute_script("return document.body.dataset.eventsSeen"):
            assert time.monotonic() < deadline, "the job's page got no event in 20 s"
            time.sleep(0.1)
        shown, state = browser.execute_script(
            "return [[...document.querySelectorAll("
            '\'tbody[data-table="rounds"] [data-field="reward"]\')].map(td => td.textContent),'
            " document.querySelector('[data-page-field=\"job-state\"]').textContent];"
        )
        assert shown == [fmt_number(r) for r in rewards]
        assert state == "finished"
        browser.back()
        # live.js applied the events (no reload); the hostile name is text, not an element
        name = browser.find_element(By.CSS_SELECTOR, '[data-page-field="experiment"]').text
        assert name == f"web {HOSTILE}"
        assert browser.find_elements(By.CSS_SELECTOR, 'img[src="x"]') == []
        # nothing broke the page's Content-Security-Policy, no script error, no failed load
        assert console_errors(browser) == []
        assert proc.poll() is None  # the page stays up until the process is stopped
    finally:
        browser.quit()
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
