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
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(driver, timeout, poll_frequency=0.1).until(predicate)


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
