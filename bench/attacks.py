"""Hostile clients against rddl-server (and rddlsim's server): what a
well-behaved session keeps of its turn rate, and the server's memory.

    python bench/attacks.py                       # rddl-server, defaults, 2 workers
    python bench/attacks.py --rddlsim-classpath '/path/to/rddlsim/bin:/path/to/lib/*'
    python bench/attacks.py --attacks drip giant --window 5 --json

The server runs as a user starts it (`rddl-server DIR --db ... --log-dir ...
--workers 2 --timeout 0 -q`; rddlsim: `rddl.competition.Server DIR PORT ROUNDS
0 0 0`) with its open-file limit set to `--nofile` (256, the limit of the
issue's run). One good client (a separate process; raw sockets answering
every turn of SysAdmin instance 1 with `<actions/>`, as bench/server.py's
client does) plays one long session from 127.0.0.1 for the whole run and
counts its turns. The hostile connections come from 127.0.0.2 (another
address of loopback), one kind at a time:

    silent   200 connections that send nothing
    drip     100 connections that send a session-request one byte every 2 s
    half     100 connections that send half a session-request, then nothing
    giant    3 waves of 60 connections, each sending 10,000,000 bytes without
             a terminator, 1 s apart
    bomb     20 connections sending an entity-expansion session-request
    flood    connections opened and closed as fast as 4 threads can
    idle400  400 connections that send nothing, 40 from each of 127.0.0.2-11
             (the cap in total, from the open-file limit, fills)

With `--kb`, the knowledge base's JSON-lines socket instead (`rddl-kb`, the
server of `rddl-dispatch --kb-port`): the attacks of bench/kb_attacks.py.

For each attack: the good client's turns/s over the attack window against the
undisturbed window just before it (the ratio is what a session in progress
keeps), whether a new session from 127.0.0.1 starts during the attack (the
seconds to its session-init), how many hostile connections the server still
holds open `--hold` seconds after the attack started, and the RSS of the
server's processes (main and workers, summed) before the attack, at its end,
and 5 s later. Without a classpath rddlsim's rows are skipped with a message.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from kb_attacks import ALL as KB_ATTACKS  # noqa: E402  (bench/kb_attacks.py)
from kb_attacks import good_kb_client, run_kb  # noqa: E402

from server import (  # noqa: E402  (bench/server.py: the same instance, client and process tools)
    ACTIONS,
    DECL,
    INSTANCE,
    ROUND_REQUEST,
    _open_file_limit,
    _tree,
    bench_rddl,
    free_port,
    root,
    session_request,
    stop,
)
from server import start_ours as start_server  # noqa: E402

ATTACKER = "127.0.0.2"
ALL = ["silent", "drip", "half", "giant", "bomb", "flood", "idle400"]
BOMB = (
    b'<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol "lol">'
    + b"".join(
        b'<!ENTITY lol%d "%s">' % (i, (b"&lol%d;" % (i - 1) if i > 1 else b"&lol;") * 10)
        for i in range(1, 10)
    )
    + b"]><session-request><problem-name>&lol9;</problem-name>"
    b"<client-name>bomb</client-name></session-request>\0"
)


# ------------------------------------------------------------ the good client


def good_client(port: int) -> None:
    """Play noop sessions against 127.0.0.1:`port` until killed; print the
    turns played so far every 0.1 s (one number a line)."""
    count = [0]

    def report() -> None:
        while True:
            time.sleep(0.1)
            print(count[0], flush=True)

    threading.Thread(target=report, daemon=True).start()
    while True:
        try:
            sock = socket.create_connection(("127.0.0.1", port), timeout=60)
        except OSError:
            time.sleep(0.1)
            continue
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(None)
        sock.sendall(session_request("good"))
        buf = bytearray()
        try:
            while True:
                data = sock.recv(65536)
                if not data:
                    break
                buf += data
                out = []
                while (end := buf.find(b"\0")) >= 0:
                    msg = bytes(buf[:end])
                    del buf[: end + 1]
                    kind = root(msg)
                    if kind == b"turn":
                        count[0] += 1
                        out.append(ACTIONS)
                    elif kind in (b"session-init", b"round-end"):
                        out.append(ROUND_REQUEST)
                    elif kind == b"session-end":
                        raise EOFError
                if out:
                    sock.sendall(b"".join(out))
        except (OSError, EOFError):
            pass
        sock.close()


class GoodClient:
    """The good client's process and the (time, turns) samples it reports."""

    def __init__(self, port: int, command: list[str] | None = None):
        self.proc = subprocess.Popen(
            [sys.executable, __file__, *(command or ["--good-client", str(port)])],
            stdout=subprocess.PIPE,
            text=True,
        )
        self.samples: list[tuple[float, int]] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.samples.append((time.monotonic(), int(line)))

    def turns_at(self, t: float) -> float:
        s = self.samples
        before = [x for x in s if x[0] <= t]
        after = [x for x in s if x[0] >= t]
        if not before or not after:
            return float(s[-1][1] if s else 0)
        (t0, n0), (t1, n1) = before[-1], after[0]
        return n0 if t1 == t0 else n0 + (n1 - n0) * (t - t0) / (t1 - t0)

    def rate(self, a: float, b: float) -> float:
        return (self.turns_at(b) - self.turns_at(a)) / (b - a)

    def close(self) -> None:
        stop(self.proc)


# ------------------------------------------------------------ the attacks


def _connect(source: str = ATTACKER) -> socket.socket | None:
    s = socket.socket()
    try:
        s.bind((source, 0))
        s.settimeout(5)
        s.connect(("127.0.0.1", PORT[0]))
        s.settimeout(None)
        return s
    except OSError:
        s.close()
        return None


PORT = [0]


class Attack:
    """Hostile connections run in threads until `stop` is set; `socks`
    holds the ones still open on our side."""

    def __init__(self, kind: str):
        self.kind = kind
        self.stop = threading.Event()
        self.socks: list[socket.socket] = []
        self.threads: list[threading.Thread] = []
        self.opened = 0

    def start(self) -> None:
        body = getattr(self, "_" + self.kind)
        n = 4 if self.kind == "flood" else 1
        self.threads = [threading.Thread(target=body, daemon=True) for _ in range(n)]
        for t in self.threads:
            t.start()

    def _hold(self, n: int, first: bytes = b"") -> None:
        for _ in range(n):
            if self.stop.is_set():
                return
            s = _connect()
            if s is None:
                continue
            self.opened += 1
            if first:
                try:
                    s.sendall(first)
                except OSError:
                    pass
            self.socks.append(s)

    def _silent(self) -> None:
        self._hold(200)

    def _idle400(self) -> None:
        # 40 from each of 10 addresses: the cap in total fills, not the one
        # per address
        for i in range(400):
            if self.stop.is_set():
                return
            s = _connect(f"127.0.0.{2 + i % 10}")
            if s is not None:
                self.opened += 1
                self.socks.append(s)

    def _half(self) -> None:
        req = session_request("half")
        self._hold(100, req[: len(req) // 2])

    def _drip(self) -> None:
        self._hold(100)
        req = session_request("drip")
        i = 0
        while not self.stop.wait(2.0):
            for s in list(self.socks):
                try:
                    s.send(req[i % len(req) : i % len(req) + 1])
                except OSError:
                    pass
            i += 1

    def _giant(self) -> None:
        chunk = DECL + b"<session-request>" + b"x" * (1 << 20)
        for _wave in range(3):
            socks = []
            for _ in range(60):
                s = _connect()
                if s is not None:
                    self.opened += 1
                    socks.append(s)

            def send(s: socket.socket) -> None:
                sent = 0
                try:
                    while sent < 10_000_000:
                        sent += s.send(chunk[: 10_000_000 - sent])
                except OSError:
                    pass
                s.close()

            senders = [threading.Thread(target=send, args=(s,), daemon=True) for s in socks]
            for t in senders:
                t.start()
            for t in senders:
                t.join(60)
            time.sleep(1.0)

    def _bomb(self) -> None:
        for _ in range(20):
            s = _connect()
            if s is None:
                continue
            self.opened += 1
            try:
                s.sendall(BOMB)
            except OSError:
                pass
            self.socks.append(s)

    def _flood(self) -> None:
        while not self.stop.is_set():
            s = _connect()
            if s is not None:
                self.opened += 1
                s.close()

    def still_open(self) -> int:
        """Hostile connections the server has not closed (probed without blocking)."""
        n = 0
        for s in self.socks:
            try:
                s.setblocking(False)
                while True:
                    data = s.recv(65536)
                    if not data:
                        break
            except BlockingIOError:
                n += 1
            except OSError:
                pass
        return n

    def end(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(30)
        for s in self.socks:
            s.close()


def new_session_seconds(port: int, limit: float = 10.0) -> float | None:
    """Seconds from connecting (from 127.0.0.1) to session-init, None if it
    did not come within `limit`."""
    t0 = time.monotonic()
    try:
        s = socket.create_connection(("127.0.0.1", port), timeout=limit)
        s.settimeout(max(0.1, limit - (time.monotonic() - t0)))
        s.sendall(session_request("probe"))
        buf = b""
        while b"\0" not in buf:
            data = s.recv(65536)
            if not data:
                return None
            buf += data
        s.close()
        return time.monotonic() - t0 if b"session-init" in buf else None
    except OSError:
        return None


def rss_mb(pid: int) -> float:
    total = 0
    for p in _tree(pid):
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total / 1024


# ------------------------------------------------------------ the servers


def start_ours(rddl: Path, folder: Path, workers: int, nofile: int) -> tuple[Any, int, Path]:
    """rddl-server with --db and --log-dir in `folder`, its log in server.log."""
    log = folder / "server.log"
    proc, port = start_server(
        rddl,
        1000000,
        folder / "results.db",
        workers,
        log_dir=folder / "logs",
        stderr=log,
        nofile=nofile,
    )
    return proc, port, log


def start_rddlsim(classpath: str, rddl: Path, folder: Path, nofile: int) -> tuple[Any, int, Path]:
    port = free_port()
    log = folder / "rddlsim.out"
    proc = subprocess.Popen(
        ["java", "-Xmx2g", "-cp", classpath, "rddl.competition.Server"]
        + [str(rddl), str(port), "1000000", "0", "0", "0"],
        stdout=open(log, "w"),
        stderr=subprocess.STDOUT,
        cwd=folder,
        preexec_fn=_open_file_limit(nofile),
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return proc, port, log
        except OSError:
            time.sleep(0.3)
    proc.kill()
    raise SystemExit("rddlsim's server did not start")


def logs_mb(folder: Path) -> float:
    """The size of the server's logs (its stderr and rddlsim's log file; the
    result database is not a log)."""
    return (
        sum(
            p.stat().st_size
            for p in folder.rglob("*")
            if p.is_file() and p.suffix in (".log", ".out")
        )
        / 1e6
    )


def run_server(name: str, proc: Any, port: int, folder: Path, args: Any) -> list[dict[str, Any]]:
    PORT[0] = port
    good = GoodClient(port)
    rows = []
    try:
        time.sleep(2.0)  # the good session starts, the server warms up
        for kind in args.attacks:
            if proc.poll() is not None:
                print(f"{name}: the server exited (code {proc.returncode})", file=sys.stderr)
                break
            t0 = time.monotonic()
            time.sleep(args.window)
            t1 = time.monotonic()
            base = good.rate(t0, t1)
            rss0 = rss_mb(proc.pid)
            logs0 = logs_mb(folder)
            attack = Attack(kind)
            attack.start()
            a0 = time.monotonic()
            time.sleep(args.window / 2)
            probe = new_session_seconds(port)
            rest = args.window - (time.monotonic() - a0)
            if rest > 0:
                time.sleep(rest)
            a1 = time.monotonic()
            during = good.rate(a0, a1)
            if kind == "giant":  # all three waves sent and closed
                for t in attack.threads:
                    t.join(300)
            rss_end = rss_mb(proc.pid)
            if attack.socks:
                time.sleep(max(0.0, a0 + args.hold - time.monotonic()))
            held = attack.still_open()
            attack.end()
            time.sleep(5.0)
            rss_after = rss_mb(proc.pid)
            row = {
                "server": name,
                "attack": kind,
                "baseline_turns_s": round(base),
                "during_turns_s": round(during),
                "kept": round(during / base, 2) if base else None,
                "new_session_s": None if probe is None else round(probe, 2),
                "hostile_connections": attack.opened,
                "still_open_after_hold": held if attack.socks else None,
                "rss_before_mb": round(rss0),
                "rss_end_mb": round(rss_end),
                "rss_5s_after_mb": round(rss_after),
                "log_growth_mb": round(logs_mb(folder) - logs0, 2),
            }
            rows.append(row)
            print(_line(row), flush=True)
    finally:
        good.close()
    return rows


HEADER = (
    f"{'server':<10} {'attack':<7} {'base t/s':>8} {'during':>7} {'kept':>5} "
    f"{'new sess':>8} {'hostile':>7} {'open@hold':>9} {'rss MB before/end/+5s':>22} {'logs MB':>7}"
)


def _line(r: dict[str, Any]) -> str:
    new = "refused" if r["new_session_s"] is None else f"{r['new_session_s']:.2f}s"
    held = "-" if r["still_open_after_hold"] is None else str(r["still_open_after_hold"])
    kept = "-" if r["kept"] is None else f"{r['kept']:.2f}"
    rss = f"{r['rss_before_mb']}/{r['rss_end_mb']}/{r['rss_5s_after_mb']}"
    return (
        f"{r['server']:<10} {r['attack']:<7} {r['baseline_turns_s']:>8} {r['during_turns_s']:>7} "
        f"{kept:>5} {new:>8} {r['hostile_connections']:>7} {held:>9} {rss:>22} "
        f"{r['log_growth_mb']:>7}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--attacks", nargs="+", choices=ALL, default=ALL)
    ap.add_argument("--window", type=float, default=5.0, help="seconds of each measurement")
    ap.add_argument(
        "--hold",
        type=float,
        default=35.0,
        help="seconds after an attack starts at which its connections still open are counted",
    )
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--nofile", type=int, default=256, help="the servers' open-file limit")
    ap.add_argument("--rddlsim-classpath", default=os.environ.get("RDDLSIM_CP"))
    ap.add_argument("--json", action="store_true")
    ap.add_argument(
        "--kb",
        action="store_true",
        help="attack the knowledge base's JSON-lines socket (rddl-kb) instead (bench/kb_attacks.py)",
    )
    ap.add_argument("--kb-attacks", nargs="+", choices=KB_ATTACKS, default=KB_ATTACKS)
    ap.add_argument("--good-client", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--good-kb-client", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.good_client:
        good_client(args.good_client)
        return
    if args.good_kb_client:
        good_kb_client(args.good_kb_client)
        return
    try:
        socket.create_connection  # noqa: B018
        probe = socket.socket()
        probe.bind((ATTACKER, 0))
        probe.close()
    except OSError as err:
        raise SystemExit(f"cannot use {ATTACKER} as the attackers' address: {err}") from None
    if args.kb:
        print(f"rddl-kb, courier domain; window {args.window:g} s; open-file limit {args.nofile}")
        run_kb(args)
        return
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="ippc-attacks-") as tmp:
        rddl = bench_rddl(Path(tmp))
        print(f"instance {INSTANCE}; window {args.window:g} s; open-file limit {args.nofile}")
        print(HEADER, flush=True)
        ours = Path(tmp) / "ours"
        ours.mkdir()
        proc, port, log = start_ours(rddl, ours, args.workers, args.nofile)
        try:
            rows += run_server(f"ippc-w{args.workers}", proc, port, ours, args)
        finally:
            stop(proc)
        lines = log.read_text(errors="replace").splitlines()
        print(
            f"rddl-server's log: {len(lines)} lines; "
            f"'no worker process' lines: {sum('no worker process' in x for x in lines)}",
            flush=True,
        )
        if args.rddlsim_classpath:
            theirs = Path(tmp) / "rddlsim"
            theirs.mkdir()
            proc, port, _ = start_rddlsim(args.rddlsim_classpath, rddl, theirs, args.nofile)
            try:
                rows += run_server("rddlsim", proc, port, theirs, args)
            finally:
                stop(proc)
        else:
            print(
                "rddlsim: skipped (give its classpath with --rddlsim-classpath or RDDLSIM_CP;"
                " a build of rddlsim outside this repository)",
                flush=True,
            )
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
