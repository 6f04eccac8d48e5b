"""rddl-server's web view in a real headless Chromium (Debian's chromium and
chromium-driver): the page, loaded during a running session, shows the turn
count advance without reloading, shows a hostile client name as text, and
breaks no rule of its Content-Security-Policy."""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from functools import partial
from typing import Any

import pytest
import trio

from ..conftest import REPO
from .harness import noop_session

pytestmark = pytest.mark.alone  # a browser and a server process, with deadlines

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
HOSTILE = "<img src=x onerror=alert(1)>"
XML_HOSTILE = "&lt;img src=x onerror=alert(1)&gt;"
SERVER = [sys.executable, "-c", "from ippc.server.cli import main; main()"]


def browser() -> Any:
    """A headless Chromium through chromedriver, or skip."""
    webdriver = pytest.importorskip("selenium.webdriver", reason="pip install selenium")
    if not (shutil.which(CHROMIUM) and shutil.which(CHROMEDRIVER)):
        pytest.skip(
            f"needs {CHROMIUM} and {CHROMEDRIVER}: apt-get install chromium chromium-driver"
        )
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = CHROMIUM
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--window-size=1280,900",
    ):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(30)
    return driver


def start_server(*args: str) -> tuple[subprocess.Popen[str], int, int]:
    """`rddl-server domains/print_jobs --web 0` (`args`, or one process and
    30 rounds): its process, port and web port."""
    proc = subprocess.Popen(
        [*SERVER, str(REPO / "domains" / "print_jobs"), "--port", "0", "--web", "0", "-q"]
        + list(args or ("--workers", "1", "--rounds", "30")),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    port = web = 0
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (port and web):
        line = proc.stdout.readline()
        if line.startswith("listening on"):
            port = int(line.rsplit(":", 1)[1])
        elif line.startswith("web view on http://127.0.0.1:"):
            web = int(line.rstrip().rstrip("/").rsplit(":", 1)[1])
        elif not line and proc.poll() is not None:
            break
    if not (port and web):
        proc.kill()
        raise AssertionError(f"no address lines: {proc.stderr.read() if proc.stderr else ''}")
    return proc, port, web


@pytest.fixture
def server() -> Iterator[tuple[int, int]]:
    proc, port, web = start_server()
    try:
        yield port, web
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def slow_session(port: int, client: str, stall: float) -> threading.Thread:
    """A noop session in a thread, `stall` seconds of thinking a turn."""

    def play() -> None:
        try:
            trio.run(partial(noop_session, port, "print_jobs_inst_1", client, stall=stall))
        except Exception:  # the server is stopped at the end of the test, mid-session
            pass

    thread = threading.Thread(target=play, daemon=True)
    thread.start()
    return thread


def wait(driver: Any, predicate: Any, timeout: float = 20.0) -> Any:
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.support.ui import WebDriverWait

    # (a row found a moment ago is gone when a stream's snapshot rebuilds the table)
    return WebDriverWait(
        driver, timeout, poll_frequency=0.1, ignored_exceptions=[StaleElementReferenceException]
    ).until(predicate)


def cell(driver: Any, key: str, name: str) -> str:
    from selenium.webdriver.common.by import By

    rows = driver.find_elements(
        By.CSS_SELECTOR, f'tbody[data-table="sessions"] tr[data-key="{key}"]'
    )
    if not rows:
        return ""
    found = rows[0].find_elements(By.CSS_SELECTOR, f'[data-field="{name}"]')
    return found[0].text if found else ""


def test_the_page_follows_a_running_session(server: tuple[int, int]) -> None:
    from selenium.webdriver.common.by import By

    port, web = server
    driver = browser()
    try:
        driver.get(f"http://127.0.0.1:{web}/")  # before any session: the row comes live
        assert driver.find_element(By.ID, "conn") is not None
        session = slow_session(port, XML_HOSTILE, 0.05)
        wait(driver, lambda d: cell(d, "1", "turn").isdigit())
        first = int(cell(driver, "1", "turn"))
        turns_first = driver.find_element(By.CSS_SELECTOR, '[data-page-field="turns"]').text
        # the count advances without a reload (the same document: its marker stays)
        driver.execute_script("document.body.dataset.marker = 'same page'")
        wait(
            driver, lambda d: cell(d, "1", "turn").isdigit() and cell(d, "1", "turn") != str(first)
        )
        wait(
            driver,
            lambda d: (
                d.find_element(By.CSS_SELECTOR, '[data-page-field="turns"]').text != turns_first
            ),
        )
        assert driver.execute_script("return document.body.dataset.marker") == "same page"
        assert int(driver.execute_script("return document.body.dataset.eventsSeen")) >= 2
        # the hostile name is text in the cell, never an element
        assert cell(driver, "1", "client") == HOSTILE
        assert driver.find_elements(By.CSS_SELECTOR, 'img[src="x"]') == []
        row = driver.find_element(By.CSS_SELECTOR, 'tr[data-key="1"]')
        assert row.get_attribute("data-state") == "running"
        assert driver.title == "rddl-server: sessions"

        # the session's page: its last turns come in live too
        driver.find_element(By.CSS_SELECTOR, 'tr[data-key="1"] a').click()
        wait(driver, lambda d: d.title.startswith("session 1:"))
        assert HOSTILE in driver.title
        key = lambda d: (  # noqa: E731
            d.find_elements(By.CSS_SELECTOR, 'tbody[data-table="turns"] tr')[0].get_attribute(
                "data-key"
            )
            if d.find_elements(By.CSS_SELECTOR, 'tbody[data-table="turns"] tr')
            else None
        )
        wait(driver, lambda d: key(d) is not None)
        newest = key(driver)
        wait(driver, lambda d: key(d) != newest)
        assert len(driver.find_elements(By.CSS_SELECTOR, 'tbody[data-table="turns"] tr')) <= 20
        assert driver.find_elements(By.CSS_SELECTOR, 'img[src="x"]') == []
        # nothing broke the page's Content-Security-Policy, nothing failed to load
        severe = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
        assert severe == [], severe
        session.join(0.1)
    finally:
        driver.quit()


def _fluent_text(name: str, args: list[str], value: str) -> tuple[str, str]:
    """(the page's name of a fluent, its value as the page writes it)."""
    return (f"{name}({', '.join(args)})" if args else name), value


async def _recorded_session(port: int, instance: str) -> dict[str, Any]:
    """A whole noop session with raw bytes, keeping every turn's observed fluents
    (name, value as sent) and the round rewards."""
    from lxml import etree

    from .harness import NOOP, ROUND_REQUEST, RawClient, session_request, strip_frame

    c = await RawClient.connect(port)
    out: dict[str, Any] = {"rounds": [], "turns": []}
    try:
        await c.send(session_request(instance, "recorder"))
        init = etree.fromstring(strip_frame(await c.recv()))
        assert init.tag == "session-init", init.tag
        for rnd in range(1, int(init.findtext("num-rounds")) + 1):
            await c.send(ROUND_REQUEST)
            await c.recv()  # round-init
            while True:
                msg = etree.fromstring(strip_frame(await c.recv()))
                if msg.tag == "round-end":
                    out["rounds"].append(float(msg.findtext("round-reward")))
                    break
                fluents = [
                    _fluent_text(
                        x.findtext("fluent-name"),
                        [a.text or "" for a in x.findall("fluent-arg")],
                        x.findtext("fluent-value"),
                    )
                    for x in msg.findall("observed-fluent")
                ]
                out["turns"].append((rnd, int(msg.findtext("turn-num")), fluents))
                await c.send(NOOP)
        await c.recv()  # session-end
    finally:
        await c.close()
    return out


def _expected_state(fluents: list[tuple[str, str]]) -> str:
    """The page's state cell: the fluents that are true (or not 0) as sent."""
    shown = []
    for name, value in fluents:
        if value == "true":
            shown.append(name)
        elif value != "false" and value not in ("0", "0.0"):
            shown.append(f"{name}={value}")
    return " ".join(shown) or "(none)"


def _expected_changes(before: list[tuple[str, str]], now: list[tuple[str, str]]) -> str:
    old = dict(before)
    changed = [f"{n}: {old.get(n)} \u2192 {v}" for n, v in now if old.get(n) != v]
    return " ".join(changed) or "(no change)"


def test_state_column_refusals_and_chart_scale() -> None:
    """The session page's turns show the state's true fluents and what changed since
    the turn before, as the client received them; the connections refused by a cap
    or for an unknown instance (in a worker process) are counted on the page; the
    sessions' small reward charts carry their scale."""
    import urllib.request

    from selenium.webdriver.common.by import By

    from .harness import RawClient, session_request

    proc, port, web = start_server("--workers", "2", "--rounds", "2")
    proc2, port2, web2 = start_server(
        "--workers", "1", "--rounds", "2", "--max-connections-per-address", "1"
    )
    driver = browser()
    try:
        recorded = trio.run(_recorded_session, port, "print_jobs_inst_1")

        async def refused() -> None:
            # an unknown instance (played by a worker process: counted there, sent on)
            c = await RawClient.connect(port)
            await c.send(session_request("no_such_instance", "x"))
            await c.expect_eof()
            await c.close()
            # over the cap of one connection per address (refused by the listener)
            first = await RawClient.connect(port2)
            await first.send(session_request("print_jobs_inst_1", "holder"))
            await first.recv()  # session-init: the connection is in
            second = await RawClient.connect(port2)
            await second.expect_eof()
            await second.close()
            await first.close()

        trio.run(refused)

        driver.get(f"http://127.0.0.1:{web}/")
        wait(driver, lambda d: cell(d, "1", "status") == "finished")

        def refused_rows(d: Any) -> dict[str, str]:
            return dict(  # (one look: the rows as they are at one moment)
                d.execute_script(
                    "return [...document.querySelectorAll('tbody[data-table=\"refused\"] tr')]"
                    ".map(tr => [tr.querySelector('[data-field=\"kind\"]').textContent,"
                    " tr.querySelector('[data-field=\"count\"]').textContent]);"
                )
            )

        def refused_total(d: Any) -> str:
            return str(
                d.execute_script(
                    "return document.querySelector('[data-page-field=\"refused\"]').textContent"
                )
            )

        wait(driver, lambda d: refused_rows(d) == {"unknown instance": "1"})
        assert refused_total(driver) == "1"
        driver.get(f"http://127.0.0.1:{web2}/")
        wait(driver, lambda d: refused_rows(d) == {"cap of 1 per address reached": "1"})
        assert refused_total(driver) == "1"
        wait(driver, lambda d: cell(d, "1", "client") == "holder")  # (it held the cap)

        # the chart in the sessions' table: its scale is the rewards' highest and lowest
        driver.get(f"http://127.0.0.1:{web}/")
        wait(driver, lambda d: cell(d, "1", "status") == "finished")
        # (looked up each time: the stream's first event rebuilds the rows)
        spark = "return document.querySelector('tr[data-key=\"1\"] img.spark').naturalWidth"
        wait(driver, lambda d: (d.execute_script(spark) or 0) > 0)
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/chart/session/1.svg") as reply:
            svg = reply.read().decode()
        hi, lo = max(recorded["rounds"]), min(recorded["rounds"])
        from ippc.web import fmt_number

        if hi != lo:
            assert f">{fmt_number(hi, 3)}</text>" in svg and f">{fmt_number(lo, 3)}</text>" in svg
        assert ">1</text>" in svg and ">2</text>" in svg  # the first and last round

        # the session's page: its last 20 turns (round 2), state and changes as sent
        driver.get(f"http://127.0.0.1:{web}/session/1")
        rows_css = 'tbody[data-table="turns"] tr'
        # (after the stream's snapshot, which rebuilds the rows: then one look at them)
        wait(driver, lambda d: d.execute_script("return document.body.dataset.eventsSeen"))
        wait(driver, lambda d: len(d.find_elements(By.CSS_SELECTOR, rows_css)) == 20)
        shown = {
            key: (state, changed)
            for key, state, changed in driver.execute_script(
                f"return [...document.querySelectorAll('{rows_css}')].map(tr => [tr.dataset.key,"
                " tr.querySelector('[data-field=\"state\"]').textContent,"
                " tr.querySelector('[data-field=\"changed\"]').textContent]);"
            )
        }
        turns = recorded["turns"]
        checked = 0
        for k, (rnd, turn, fluents) in enumerate(turns):
            key = f"{rnd}.{turn}"
            if key not in shown:
                continue
            state, changed = shown[key]
            assert state == _expected_state(fluents), key
            assert "false" not in state.split("=")[-1:]  # no false fluent listed
            if turn == 1:
                assert changed == "(the round's first turn)"
            else:
                assert changed == _expected_changes(turns[k - 1][2], fluents), key
            checked += 1
        assert checked == 20
        assert any(v[1] not in ("(no change)", "(the round's first turn)") for v in shown.values())
        severe = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
        assert severe == [], severe
    finally:
        driver.quit()
        for p in (proc, proc2):
            p.terminate()
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
