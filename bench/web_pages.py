"""The screenshots of rddl-batch's and rddl-dispatch's web pages, taken with headless
Chromium while each command runs (as a user starts it, in a process of its own), and
the pages' cost to a dispatcher watched by many viewers.

    python bench/web_pages.py --screenshot docs/   # docs/web-batch.png, docs/web-dispatch.png
    python bench/web_pages.py                      # the dispatcher's turns/s, with viewers

The batch: three small instances (tests/data) played by the baselines and mcts, two
at once; the picture is taken once some jobs are done and others run. The dispatcher:
the courier robot (tests/data/dispatch) with handlers that take 0.6 s an action, a
gripper that fails its first pickup and a sender who turns up at the desk after a
while; the picture is taken once the robot has replanned after the failure.

The measurement: the dispatcher (courier, the exact planner, handlers that answer at
once on the wall clock) plays `--turns` turns without ``--web``, with ``--web`` and
nobody watching, and with `--viewers` viewers on the page's event stream (half reading
everything, half never reading a byte: they are dropped); each line is the median of
`--repeat` passes, with the ratios against ``--web`` unwatched and against no web.
Needs Debian's chromium and chromium-driver and selenium for the screenshots only.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
DATA = REPO / "tests" / "data"
DOMAIN = DATA / "dispatch" / "courier_domain.rddl"
ONE = DATA / "dispatch" / "courier_one.rddl"

EXPERIMENT = f"""
name = "web-demo"
rounds = 3
timeout = 300
seed = 11
jobs = 2
instances = [
    "{REPO / "domains" / "print_jobs" / "instance1.rddl"}",
    "{DATA / "rddlsim" / "rddl" / "sysadmin_inst_mdp__1.rddl"}",
    "{DATA / "rddlsim" / "rddl" / "game_of_life_inst_mdp__1.rddl"}",
]

[planners.mcts]
planner = "mcts"
options = {{ iterations = "120", batch = "32" }}
"""

ROBOT = """
import trio
from ippc.dispatch.actions import Result, Status
from ippc.kb import Update

def setup(robot):
    failed = []

    @robot.handler("*")
    async def act(d):
        await trio.sleep(0.6)
        if d.action.name == "pickup" and not failed:
            failed.append(d.action)
            return Result(Status.FAILED, "the gripper slipped")
        return True

    @robot.handler("noop")
    async def wait(d):
        await trio.sleep(0.6)
        return True

    async def sender():
        await trio.sleep(5)
        robot.kb.apply([Update("set", "present", ("office",), True)], "desk-sensor")

    robot.start_soon(sender)
"""

FAST_ROBOT = """
def setup(robot):
    @robot.handler("*")
    async def act(d):
        return True
"""


def _start(cmd: list[str], folder: Path) -> tuple[subprocess.Popen[str], str]:
    """Start a command with --web 0; the page's address, from its 'web view on' line."""
    out = open(folder / "out.txt", "w")  # noqa: SIM115 - closed with the process
    err = open(folder / "err.txt", "w")  # noqa: SIM115
    proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, start_new_session=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        for name in ("out.txt", "err.txt"):
            m = re.search(r"web view on (http://\S+)", (folder / name).read_text())
            if m:
                return proc, m.group(1)
        if proc.poll() is not None:
            raise SystemExit(f"{cmd[2]} ended: {(folder / 'err.txt').read_text()[-2000:]}")
        time.sleep(0.1)
    raise SystemExit(f"{cmd[2]} printed no 'web view on' line in 60 s")


def _snapshot(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url + "snapshot.json", timeout=10) as reply:  # noqa: S310
        return json.loads(reply.read())  # type: ignore[no-any-return]


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def _browser() -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage"):
        options.add_argument(arg)
    options.add_argument("--window-size=1200,900")
    options.binary_location = "/usr/bin/chromium"
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)


def _shoot(url: str, path: Path) -> None:
    browser = _browser()
    try:
        browser.get(url)
        time.sleep(2.0)  # the event stream's snapshot and the charts
        height = browser.execute_script("return document.body.scrollHeight")
        browser.set_window_size(1200, min(int(height) + 40, 3000))
        time.sleep(0.5)
        browser.save_screenshot(str(path))
        print(
            f"wrote {path} ({browser.execute_script('return document.body.dataset.eventsSeen')} events)"
        )
    finally:
        browser.quit()


def screenshots(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        exp = work / "web-demo.toml"
        exp.write_text(EXPERIMENT)
        cmd = [sys.executable, "-m", "ippc.batch.cli", "run", str(exp), "--db"]
        cmd += [str(work / "demo.sqlite"), "--web", "0"]
        proc, url = _start(cmd, work)
        try:
            deadline = time.monotonic() + 300
            while time.monotonic() < deadline:
                counts = _snapshot(url)["counts"]
                if counts.get("finished", 0) >= 5 and counts.get("running", 0) >= 1:
                    break
                time.sleep(0.2)
            _shoot(url, folder / "web-batch.png")
        finally:
            _stop(proc)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        robot = work / "robot.py"
        robot.write_text(ROBOT)
        cmd = [sys.executable, "-m", "ippc.dispatch.cli", str(DOMAIN), str(ONE)]
        cmd += ["--robot", str(robot), "--planner", "exact", "--port", "0", "--web", "0"]
        cmd += ["--no-stop-at-goal"]  # (the robot goes on after the goal: the page stays)
        proc, url = _start(cmd, work)
        try:
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                snap = _snapshot(url)
                if snap["stats"]["replans"] >= 1 and snap["stats"]["turns"] >= 10:
                    break
                time.sleep(0.05)
            _shoot(url, folder / "web-dispatch.png")
        finally:
            _stop(proc)


# ----------------------------------------------------------------- the measurement


def _viewers(url: str, n: int, stop: threading.Event) -> list[socket.socket]:
    """n viewers of the page's event stream: half read everything, half never read."""
    host, port = re.match(r"http://([^:/]+):(\d+)/", url).groups()  # type: ignore[union-attr]
    request = f"GET /events HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode()
    socks = []
    for k in range(n):
        s = socket.create_connection((host, int(port)), timeout=10)
        s.sendall(request)
        socks.append(s)
        if k % 2 == 0:

            def drain(sock: socket.socket = s) -> None:
                sock.settimeout(0.5)
                while not stop.is_set():
                    try:
                        if not sock.recv(65536):
                            return
                    except TimeoutError:
                        continue
                    except OSError:
                        return

            threading.Thread(target=drain, daemon=True).start()
    return socks


def one_pass(turns: int, web: bool, viewers: int) -> tuple[float, float, float]:
    """The dispatcher's turns per second over `turns` turns, its CPU milliseconds a
    turn (its process's user and system time: what the machine's load does not
    change), and the CPU seconds the viewers took (this process)."""
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        robot = work / "robot.py"
        robot.write_text(FAST_ROBOT)
        rounds = max(1, turns // 12)
        cmd = [sys.executable, "-m", "ippc.dispatch.cli", str(DOMAIN), str(ONE)]
        cmd += ["--robot", str(robot), "--planner", "exact", "--port", "0", "--rounds"]
        cmd += [str(rounds), "--no-stop-at-goal", "-q", "--json-out", str(work / "r.json")]
        cmd += ["--web", "0"] if web else []
        stop = threading.Event()
        socks: list[socket.socket] = []
        before = resource.getrusage(resource.RUSAGE_SELF)
        if web:
            proc, url = _start(cmd, work)
            socks = _viewers(url, viewers, stop)
        else:
            proc = subprocess.Popen(
                cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True
            )
        try:
            _, _, usage = os.wait4(proc.pid, 0)  # (its own CPU time, reaped here)
            proc.returncode = 0
        finally:
            stop.set()
            for s in socks:
                s.close()
            _stop(proc)
        after = resource.getrusage(resource.RUSAGE_SELF)
        viewers_cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        report = json.loads((work / "r.json").read_text())
        n = float(report["turns"])
        cpu_ms = (usage.ru_utime + usage.ru_stime) * 1000.0 / n
        return n / float(report["wall_seconds"]), cpu_ms, viewers_cpu


def measure(turns: int, viewers: int, repeat: int) -> None:
    results: dict[str, list[tuple[float, float, float]]] = {
        "no web": [],
        "web, 0 viewers": [],
        f"web, {viewers} viewers": [],
    }
    for _ in range(repeat):  # the three ways within each pass (the load drifts)
        results["no web"].append(one_pass(turns, False, 0))
        results["web, 0 viewers"].append(one_pass(turns, True, 0))
        results[f"web, {viewers} viewers"].append(one_pass(turns, True, viewers))
    rate = {k: statistics.median(r[0] for r in v) for k, v in results.items()}
    cpu = {k: statistics.median(r[1] for r in v) for k, v in results.items()}
    seen = {k: statistics.median(r[2] for r in v) for k, v in results.items()}
    load = os.getloadavg()[0]
    print(f"rddl-dispatch, courier_one, exact planner, {turns} turns a pass, median of {repeat}")
    print(f"(load average at the end: {load:.1f})")
    print(f"  {'':<22} {'turns/s':>8} {'CPU ms/turn':>12} {'viewers CPU s':>14}")
    for k in results:
        print(f"  {k:<22} {rate[k]:8.1f} {cpu[k]:12.3f} {seen[k]:14.2f}")
    w0, wn = "web, 0 viewers", f"web, {viewers} viewers"
    print(
        f"  {w0} / no web: turns/s {rate[w0] / rate['no web']:.3f}, CPU a turn {cpu[w0] / cpu['no web']:.3f}"
    )
    print(f"  {wn} / {w0}: turns/s {rate[wn] / rate[w0]:.3f}, CPU a turn {cpu[wn] / cpu[w0]:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--screenshot", type=Path, metavar="FOLDER", help="take the screenshots")
    parser.add_argument("--turns", type=int, default=600, help="turns a pass (600)")
    parser.add_argument("--viewers", type=int, default=50, help="viewers watching (50)")
    parser.add_argument("--repeat", type=int, default=3, help="passes (3)")
    args = parser.parse_args()
    if args.screenshot:
        screenshots(args.screenshot)
    else:
        measure(args.turns, args.viewers, args.repeat)


if __name__ == "__main__":
    main()
