"""Turns per second of rddl-server with its web view watched by many viewers.

Workload: bench/server.py's (SysAdmin instance 1 of IPPC 2011 from the
rddlrepository package, horizon 40, `--rounds` rounds, its minimal noop
client `NoopClients`). The server runs as users start it, as one process
(`--workers 1`: the sessions and the web view share one trio loop, the case
where a viewer could cost a session most; `--workers auto` measures the
default, where the sessions are played in worker processes and the view is
in the main one), and is measured three ways, all taking turns within each
pass:

- `no web`: without `--web` (the reference for the view's own cost);
- `web, 0 viewers`: `--web 0`, nobody watching;
- `web, N viewers`: `--web 0` with N viewers on the live page's event stream
  (`/events`), half of them reading everything, half never reading a byte
  (they connect, send their request and stop: each one's socket fills, then
  its queue, and it is dropped). The viewers are a process of their own.

A line's figure is the median of `--repeat` passes; the ratios are
`web, N viewers` over `web, 0 viewers` (what the viewers cost) and `web, 0
viewers` over `no web` (what the view costs).

    python bench/web.py                     # 1 client, 100 viewers, 3 passes
    python bench/web.py --clients 10 --viewers 200
    python bench/web.py --workers auto
    python bench/web.py --screenshot docs/  # the docs' screenshots (headless chromium)
"""

from __future__ import annotations

import argparse
import json
import re
import selectors
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
sys.path.insert(0, str(HERE))

from server import (  # noqa: E402  (bench/server.py's workload and process tools)
    NoopClients,
    bench_rddl,
    cpu_seconds,
    stop,
)

SERVER = [sys.executable, "-c", "from ippc.server.cli import main; main()"]


def start(
    rddl: Path, rounds: int, web: bool, extra: tuple[str, ...] = (), workers: str = "1"
) -> tuple[subprocess.Popen[str], int, int]:
    """rddl-server: its process, port and web port (0 without --web)."""
    cmd = [*SERVER, str(rddl), "--port", "0", "--rounds", str(rounds), "--timeout", "0"]
    cmd += ["--workers", workers, "-q", *extra]
    if web:
        cmd += ["--web", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("listening on"):
        proc.kill()
        raise SystemExit(f"rddl-server did not start: {line!r}")
    port = int(line.rsplit(":", 1)[1])
    web_port = 0
    if web:
        line = proc.stdout.readline()
        if not line.startswith("web view on"):
            proc.kill()
            raise SystemExit(f"no web view line: {line!r}")
        web_port = int(line.strip().rstrip("/").rsplit(":", 1)[1])
    return proc, port, web_port


# ------------------------------------------------------------------ viewers


def viewers_main(port: int, reading: int, idle: int) -> None:
    """The viewers' process: `reading` viewers that read their streams and
    `idle` ones that never read; prints `ready`, then runs until killed."""
    request = f"GET /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode()
    socks = []
    for i in range(reading + idle):
        s = socket.create_connection(("127.0.0.1", port))
        if i >= reading:
            # a small receive buffer: it fills sooner, as a stopped laptop's would
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.sendall(request)
        socks.append(s)
    print("ready", flush=True)
    sel = selectors.DefaultSelector()
    for s in socks[:reading]:
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ)
    received = 0
    while True:
        for key, _ in sel.select(timeout=1.0):
            sock = key.fileobj
            assert isinstance(sock, socket.socket)
            try:
                data = sock.recv(65536)
            except BlockingIOError:
                continue
            if not data:
                sel.unregister(sock)
            received += len(data)


def start_viewers(web_port: int, n: int) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, __file__, "--viewers-of", str(web_port), "--viewers", str(n)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    if proc.stdout.readline().strip() != "ready":
        proc.kill()
        raise SystemExit("the viewers did not start")
    return proc


# ------------------------------------------------------------------ the bench


def measure(
    rddl: Path, rounds: int, clients: int, web: bool, viewers: int, workers: str
) -> tuple[float, float]:
    """Turns per second of `clients` noop sessions at once, and the server's
    CPU time per turn (its processes; microseconds; less disturbed by a
    loaded machine)."""
    server, port, web_port = start(rddl, rounds, web, workers=workers)
    watchers = None
    try:
        if viewers:
            watchers = start_viewers(web_port, viewers)
            time.sleep(0.5)  # every viewer subscribed
        cpu0 = cpu_seconds(server.pid)
        t0 = time.perf_counter()
        turns = NoopClients(port, clients).run()
        secs = time.perf_counter() - t0
        cpu = cpu_seconds(server.pid) - cpu0
        return turns / secs, cpu / turns * 1e6
    finally:
        stop(watchers)
        stop(server)


def open_round(live: Any) -> int:
    """A session and its first round started on a `LiveStore`: the round's id."""
    sid = live.start_session(
        server_session_id=1,
        instance="i",
        client_name="c",
        seed=0,
        num_rounds=30,
        time_allowed_ms=1e6,
        peer="p",
        started_at=time.time(),
    )
    return int(live.start_round(sid, round_num=1, counted=True, started_at=time.time()))


def step_cost(n: int = 200_000) -> tuple[float, float]:
    """Microseconds a session's step spends on the view's notes: the
    result store's `record_step` through `LiveStore` (no database), against
    the same call to a store that does nothing, in this process."""
    from ippc.server.web import SessionBoard

    class Nothing:
        def record_step(self, round_: int, **kw: object) -> None:
            pass

    board = SessionBoard()
    live = board.wrap(None)
    rid = open_round(live)
    state = [("running", (f"c{i}",), True) for i in range(10)]
    actions = [("reboot", ("c1",), True)]
    out = []
    for store, key in ((Nothing(), 1), (live, rid)):
        t0 = time.perf_counter()
        for k in range(n):
            store.record_step(
                key,
                turn_num=k,
                state=state,
                actions=actions,
                reward=1.0,
                turn_sent_at=0.0,
                actions_received_at=0.0,
                outcome=None,
                execution_seconds=None,
            )
        out.append((time.perf_counter() - t0) / n * 1e6)
    return out[0], out[1]


def loop_steps(viewers: int, seconds: float = 5.0) -> int:
    """In this process: rddl-server's view (`ServerView`, `serve_web`) in a
    trio loop, with `viewers` viewers (another process) on its live page, and
    a task that notes a step of one session every millisecond, as a session
    sharing the loop would; how many steps it made in `seconds` (fewer: the
    viewers' updates held the loop)."""
    from functools import partial

    import trio
    from ippc.server.web import ServerView, SessionBoard
    from ippc.web import WebOptions, serve_web

    board = SessionBoard()
    view = ServerView(board)
    live = board.wrap(None)

    async def main() -> int:
        async with trio.open_nursery() as nursery:
            port = await nursery.start(partial(serve_web, view.routes, WebOptions()))
            nursery.start_soon(view.run)
            watchers = None
            if viewers:
                watchers = await trio.to_thread.run_sync(start_viewers, port, viewers)
            await trio.sleep(1.0)
            rid = open_round(live)
            end = trio.current_time() + seconds
            k = 0
            while trio.current_time() < end:
                k += 1
                live.record_step(rid, turn_num=k, state=[], actions=[], reward=1.0)
                await trio.sleep(0.001)
            stop(watchers)
            nursery.cancel_scope.cancel()
        return k

    return trio.run(main)


def load() -> str:
    try:
        with open("/proc/loadavg") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return "?"


def bench(args: argparse.Namespace) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        rddl = bench_rddl(Path(tmp))
        lines = {
            "no web": (False, 0),
            "web, 0 viewers": (True, 0),
            f"web, {args.viewers} viewers": (True, args.viewers),
        }
        runs: dict[str, list[float]] = {name: [] for name in lines}
        cpus: dict[str, list[float]] = {name: [] for name in lines}
        print(
            f"rddl-server --workers {args.workers}, {args.clients} noop client(s), {args.rounds} rounds of 40"
            f" turns each; {args.repeat} passes; load before: {load()}"
        )
        for k in range(args.repeat):
            for name, (web, viewers) in lines.items():
                rate, cpu = measure(rddl, args.rounds, args.clients, web, viewers, args.workers)
                runs[name].append(rate)
                cpus[name].append(cpu)
                print(
                    f"  pass {k + 1}: {name:<20} {rate:9.0f} turns/s {cpu:7.0f} cpu us/turn",
                    flush=True,
                )
        med = {name: statistics.median(v) for name, v in runs.items()}
        mcpu = {name: statistics.median(v) for name, v in cpus.items()}
        print(f"\n{'server':<22} {'turns/s':>9} {'cpu us/turn':>12}  (medians; turns/s runs)")
        for name, v in runs.items():
            print(
                f"{name:<22} {med[name]:9.0f} {mcpu[name]:12.0f}  {', '.join(f'{x:.0f}' for x in v)}"
            )
        viewed = f"web, {args.viewers} viewers"
        print(
            f"\nturns/s, {viewed} / web, 0 viewers: {med[viewed] / med['web, 0 viewers']:.3f}"
            f"   (cpu/turn: {mcpu[viewed] / mcpu['web, 0 viewers']:.3f})"
        )
        print(
            f"turns/s, web, 0 viewers / no web: {med['web, 0 viewers'] / med['no web']:.3f}"
            f"   (cpu/turn: {mcpu['web, 0 viewers'] / mcpu['no web']:.3f})"
        )
        nothing, live = step_cost()
        print(
            f"a step's notes for the view (LiveStore.record_step, no database): {live:.2f} us"
            f" (a call that does nothing: {nothing:.2f} us)"
        )
        steps = {n: [loop_steps(n) for _ in range(3)] for n in (0, args.viewers)}
        print(
            "a task noting a step every ms beside the view, steps in 5 s (3 runs):"
            + "".join(f"  {n} viewers: {', '.join(map(str, v))};" for n, v in steps.items())
        )
        print(f"load after: {load()}")


# ------------------------------------------------------------------ screenshots


def screenshots(folder: Path) -> None:
    """docs/web-server.png and docs/web-session.png: three sessions (one
    running slowly, one finished, one failed, under a hostile name) and a
    connection for an unknown instance, seen in headless chromium."""
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    server, port, web_port = start(REPO / "domains" / "print_jobs", 5, True, ("--timeout", "120"))
    slow_stop = threading.Event()
    try:
        # a finished session (full speed)
        _session(port, "print_jobs_inst_1", "planner-a", 0.0, threading.Event())
        # a failed one: an action the domain does not have
        failed = socket.create_connection(("127.0.0.1", port))
        messages = _Messages(failed)
        failed.sendall(_request("print_jobs_inst_2", "&lt;img src=x onerror=alert(1)&gt;"))
        messages.next()  # session-init
        failed.sendall(DECL + b"<round-request/>\0")
        messages.next()  # round-init
        messages.next()  # turn
        failed.sendall(
            DECL + b"<actions><action><action-name>teleport</action-name>"
            b"<action-arg>p1</action-arg><action-value>true</action-value></action></actions>\0"
        )
        failed.close()
        # a connection for an instance the server does not serve (counted as refused)
        unknown = socket.create_connection(("127.0.0.1", port))
        unknown.sendall(_request("no_such_instance", "typo"))
        unknown.settimeout(10)
        while unknown.recv(65536):
            pass
        unknown.close()
        # a running one, slowly
        thread = threading.Thread(
            target=_session,
            args=(port, "print_jobs_inst_3", "mcts (slow)", 0.2, slow_stop),
            daemon=True,
        )
        thread.start()
        time.sleep(4)

        options = Options()
        options.binary_location = "/usr/bin/chromium"
        for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1500,760"):
            options.add_argument(arg)
        driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
        try:
            driver.get(f"http://127.0.0.1:{web_port}/")
            WebDriverWait(driver, 20).until(
                lambda d: d.execute_script("return document.body.dataset.eventsSeen") is not None
            )
            time.sleep(2)
            driver.save_screenshot(str(folder / "web-server.png"))
            driver.set_window_size(1300, 1400)
            with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/sessions.json") as r:
                slow = [x["id"] for x in json.loads(r.read()) if x["client"] == "mcts (slow)"]
            driver.get(f"http://127.0.0.1:{web_port}/session/{slow[0]}")
            time.sleep(2.5)
            driver.save_screenshot(str(folder / "web-session.png"))
        finally:
            driver.quit()
        print(f"wrote {folder / 'web-server.png'} and {folder / 'web-session.png'}")
    finally:
        slow_stop.set()
        stop(server)


DECL = b'<?xml version="1.0" encoding="UTF-8"?>\n'


def _request(instance: str, client: str) -> bytes:
    return (
        DECL
        + f"<session-request><problem-name>{instance}</problem-name>"
        f"<client-name>{client}</client-name></session-request>\0".encode()
    )


class _Messages:
    """One NUL-terminated message at a time from a blocking socket."""

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.buf = b""

    def next(self) -> bytes:
        """The next message, or b"" once the server closed."""
        while b"\0" not in self.buf:
            data = self.sock.recv(65536)
            if not data:
                return b""
            self.buf += data
        msg, self.buf = self.buf.split(b"\0", 1)
        return msg


def _session(port: int, instance: str, name: str, think: float, done: threading.Event) -> None:
    """A noop session thinking `think` seconds a turn, to its end or until `done`."""
    sock = socket.create_connection(("127.0.0.1", port))
    messages = _Messages(sock)
    sock.sendall(_request(instance, name))
    init = messages.next()
    found = re.search(rb"<num-rounds>(\d+)</num-rounds>", init)
    rounds = int(found.group(1)) if found else 0
    try:
        for _ in range(rounds):
            if done.is_set():
                return
            sock.sendall(DECL + b"<round-request/>\0")
            messages.next()  # round-init
            while not done.is_set():
                msg = messages.next()
                if not msg or b"<round-end" in msg:
                    break
                if think:
                    time.sleep(think)
                sock.sendall(DECL + b"<actions/>\0")
            if not msg:
                return
        messages.next()  # session-end
    finally:
        sock.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clients", type=int, default=1, help="noop sessions at once")
    parser.add_argument("--rounds", type=int, default=30, help="rounds per session")
    parser.add_argument("--viewers", type=int, default=100, help="viewers (half never read)")
    parser.add_argument("--repeat", type=int, default=3, help="passes (median)")
    parser.add_argument(
        "--workers",
        default="1",
        help="rddl-server --workers (1: the view shares the sessions' loop)",
    )
    parser.add_argument("--screenshot", type=Path, metavar="FOLDER", help="take the screenshots")
    parser.add_argument("--viewers-of", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--loop-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.viewers_of:
        viewers_main(args.viewers_of, args.viewers - args.viewers // 2, args.viewers // 2)
    elif args.loop_only:
        for n in (0, args.viewers, 0, args.viewers):
            print(f"{n} viewers: {loop_steps(n)} steps in 5 s", flush=True)
    elif args.screenshot:
        screenshots(args.screenshot)
    else:
        bench(args)


if __name__ == "__main__":
    main()
