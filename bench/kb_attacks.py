"""Hostile clients against the knowledge base's JSON-lines socket (`rddl-kb`,
the same server as `rddl-dispatch --kb-port`): whether the process lives,
what a well-behaved client keeps of its request rate, and the memory.

    python bench/attacks.py --kb                       # every attack
    python bench/attacks.py --kb --kb-attacks reset deep --window 3

`rddl-kb` serves the courier domain of tests/data/dispatch as a user starts
it (`rddl-kb DOMAIN INSTANCE --port 0 -q`, open-file limit `--nofile`). One
good client (a separate process, a plain blocking socket) sends `kb.get` and
waits for each reply, and counts them. The hostile connections come from
127.0.0.2, one kind at a time:

    reset     50 subscribers that never read, events made for them (another
              connection toggles a fact 300 times), then closed with
              SO_LINGER 0 (a reset)
    deep      10 connections sending 20 lines of 1,100 nested brackets each
    unread    5 connections pipelining 2,000 `kb.pddl` requests each
              (large replies) and never reading them
    pipeline  1 connection pipelining 6,000 `kb.pddl` requests, reading
    silent    200 connections that send nothing (the cap is 64)
    flood     connections opened and closed as fast as 4 threads can

Each row: the good client's requests/s during the attack against the window
before it (`kept`), whether the process still runs after it, and its RSS
before, at the end and 5 s after the attack's connections are closed.
"""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "tests" / "data" / "dispatch"
ATTACKER = "127.0.0.2"
ALL = ["reset", "deep", "unread", "pipeline", "silent", "flood"]
GET = b'{"id": 1, "method": "kb.get", "params": {"fluent": "robot-at", "args": ["r1", "hall"]}}\n'


def start_kb(nofile: int) -> tuple[subprocess.Popen[str], int]:
    """rddl-kb on a free port, its open-file limit `nofile`."""
    from server import _open_file_limit  # bench/server.py

    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from ippc.kb.cli import main; main()",
            str(DATA / "courier_domain.rddl"),
            str(DATA / "courier_one.rddl"),
            "--port",
            "0",
            "-q",
        ],
        stdout=subprocess.PIPE,
        text=True,
        preexec_fn=_open_file_limit(nofile),
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("listening on"):
        raise SystemExit(f"rddl-kb did not start: {line!r}")
    return proc, int(line.rsplit(":", 1)[1])


def good_kb_client(port: int) -> None:
    """Send kb.get and wait for each reply until killed; print the count so
    far every 0.1 s."""
    count = [0]

    def report() -> None:
        while True:
            time.sleep(0.1)
            print(count[0], flush=True)

    threading.Thread(target=report, daemon=True).start()
    while True:
        try:
            sock = socket.create_connection(("127.0.0.1", port), timeout=30)
            buf = b""
            while True:
                sock.sendall(GET)
                while b"\n" not in buf:
                    data = sock.recv(65536)
                    if not data:
                        raise EOFError
                    buf += data
                buf = buf[buf.index(b"\n") + 1 :]
                count[0] += 1
        except (OSError, EOFError):
            time.sleep(0.1)


def _connect(port: int) -> socket.socket | None:
    s = socket.socket()
    try:
        s.bind((ATTACKER, 0))
        s.settimeout(5)
        s.connect(("127.0.0.1", port))
        return s
    except OSError:
        s.close()
        return None


def _reset(s: socket.socket) -> None:
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    except OSError:
        pass
    s.close()


class KBAttack:
    """One kind of hostile connections, in threads until `stop` is set."""

    def __init__(self, kind: str, port: int):
        self.kind = kind
        self.port = port
        self.stop = threading.Event()
        self.socks: list[socket.socket] = []
        self.opened = 0
        self.threads: list[threading.Thread] = []

    def start(self) -> None:
        n = 4 if self.kind == "flood" else 1
        body = getattr(self, "_" + self.kind)
        self.threads = [threading.Thread(target=body, daemon=True) for _ in range(n)]
        for t in self.threads:
            t.start()

    def _open(self, n: int, first: bytes = b"") -> list[socket.socket]:
        out = []
        for _ in range(n):
            s = _connect(self.port)
            if s is None:
                continue
            self.opened += 1
            if first:
                try:
                    s.sendall(first)
                except OSError:
                    pass
            out.append(s)
        self.socks += out
        return out

    def _reset(self) -> None:
        subs = self._open(50, b'{"id": 1, "method": "kb.subscribe"}\n')
        writer = self._open(1)
        for i in range(300):
            if self.stop.is_set() or not writer:
                break
            value = b"true" if i % 2 else b"false"
            line = (
                b'{"id": 2, "method": "kb.apply", "params": {"updates": [{"op": "set",'
                b' "fluent": "present", "args": ["office"], "value": %s}]}}\n' % value
            )
            try:
                writer[0].sendall(line)
                writer[0].settimeout(5)
                writer[0].recv(65536)
            except OSError:
                break
        for s in subs:
            _reset(s)

    def _deep(self) -> None:
        line = b"[" * 1100 + b"\n"
        for s in self._open(10):
            try:
                s.sendall(line * 20)
            except OSError:
                pass

    def _unread(self) -> None:
        req = b'{"id": 1, "method": "kb.pddl"}\n' * 2000
        for s in self._open(5):
            threading.Thread(target=self._send_quietly, args=(s, req), daemon=True).start()

    @staticmethod
    def _send_quietly(s: socket.socket, data: bytes) -> None:
        try:
            s.settimeout(60)
            s.sendall(data)
        except OSError:
            pass

    def _pipeline(self) -> None:
        (s,) = self._open(1) or [None]
        if s is None:
            return
        threading.Thread(
            target=self._send_quietly, args=(s, b'{"id": 1, "method": "kb.pddl"}\n' * 6000)
        ).start()
        s.settimeout(1)
        while not self.stop.is_set():
            try:
                if not s.recv(1 << 20):
                    return
            except TimeoutError:
                continue
            except OSError:
                return

    def _silent(self) -> None:
        self._open(200)

    def _flood(self) -> None:
        while not self.stop.is_set():
            s = _connect(self.port)
            if s is not None:
                self.opened += 1
                s.close()

    def end(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(30)
        for s in self.socks:
            s.close()


def run_kb(args: Any) -> list[dict[str, Any]]:
    """Every attack of `args.kb_attacks` against one rddl-kb process."""
    from attacks import GoodClient, rss_mb  # bench/attacks.py

    from server import stop

    proc, port = start_kb(args.nofile)
    good = GoodClient(port, ["--good-kb-client", str(port)])
    rows: list[dict[str, Any]] = []
    print(
        f"{'server':<7} {'attack':<9} {'base r/s':>8} {'during':>7} {'kept':>5} "
        f"{'hostile':>7} {'alive':>5} {'rss MB before/end/+5s':>22}",
        flush=True,
    )
    try:
        time.sleep(2.0)
        for kind in args.kb_attacks:
            t0 = time.monotonic()
            time.sleep(args.window)
            base = good.rate(t0, time.monotonic())
            rss0 = rss_mb(proc.pid)
            attack = KBAttack(kind, port)
            attack.start()
            a0 = time.monotonic()
            time.sleep(args.window)
            during = good.rate(a0, time.monotonic())
            rss_end = rss_mb(proc.pid)
            attack.end()
            time.sleep(5.0)
            row = {
                "server": "rddl-kb",
                "attack": kind,
                "baseline_requests_s": round(base),
                "during_requests_s": round(during),
                "kept": round(during / base, 2) if base else None,
                "hostile_connections": attack.opened,
                "alive": proc.poll() is None,
                "rss_before_mb": round(rss0),
                "rss_end_mb": round(rss_end),
                "rss_5s_after_mb": round(rss_mb(proc.pid)),
            }
            rows.append(row)
            kept = "-" if row["kept"] is None else f"{row['kept']:.2f}"
            rss = f"{row['rss_before_mb']}/{row['rss_end_mb']}/{row['rss_5s_after_mb']}"
            print(
                f"{'rddl-kb':<7} {kind:<9} {row['baseline_requests_s']:>8} "
                f"{row['during_requests_s']:>7} {kept:>5} {attack.opened:>7} "
                f"{'yes' if row['alive'] else 'NO':>5} {rss:>22}",
                flush=True,
            )
            if not row["alive"]:
                print(f"rddl-kb exited (code {proc.returncode})", flush=True)
                break
    finally:
        good.close()
        stop(proc)
    if args.json:
        print(json.dumps(rows, indent=1))
    return rows
