"""Turns per second of rddl-server over loopback, and memory per session.

Workload: sysadmin_inst_mdp__1, the IPPC 2011 SysAdmin instance 1 as the
rddlrepository package ships it (10 computers, horizon 40), copied with its
domain into a temporary folder that both servers load; 30 rounds = 1200 turns per session, a
minimal raw Python client that answers every turn with `<actions/>`, as
rddlsim's own throughput was measured (see PROTOCOL-rddlsim.md §11).

    python bench/server.py                 # 1, 10 and 50 clients
    python bench/server.py --clients 1 --rounds 5
    python bench/server.py --rddlsim-classpath '/path/to/rddlsim/bin:/path/to/lib/*'
    python bench/server.py --db            # the same with the SQLite result store
    python bench/server.py --reference /path/to/other/checkout   # ours / another version

The client (`NoopClients`) is the smallest thing that plays a session: plain
blocking sockets from the `socket` module with TCP_NODELAY, one `selectors`
loop for all connections (with one connection it reads directly, without the
selector), a bytearray per connection searched for the NUL terminator, the
root element read from the bytes after the 39-byte declaration, and replies
that are precomputed bytes. No XML parser, no trio, no threads. The very same
client plays against ours, against a server answering with canned bytes, and
against rddlsim, so the ratios compare servers, not clients.

Our server is measured twice: as one process (`ippc`, `--workers 1`) and
with `--workers` (default `auto`, one per core, which is also rddl-server's
default; `ippc-wN`). Every line of the table is
measured once per pass, all lines taking turns within the pass (one client
against each server, then 10 and 50 clients against each of ours), and a
line's figure is the median of `--repeat` passes, so that a load change on a
shared machine hits all of them alike. With `--rddlsim-classpath` (a build of
rddlsim you made outside this repository; it is started with a temporary
folder as its working directory, where it writes its log) the ratio is
against rddlsim measured in the same run, after a warm-up session (warm JVM),
and it is also printed within each pass (seconds apart) and best run to best
run. Without it, the ratio is against the figure quoted in the issue (420-670
turns/s for one client on a 2-core machine), which is not a same-run
reference: read it as such.

The canned-reply server is trio's streams and the kernel only (no XML, no
simulation): what a turn costs before any protocol work is done. Our server runs as a
separate process started as users start it (`rddl-server ... -q`); "cpu
us/turn" is the user + system CPU time of that process and its workers
divided by the turns.
Memory per session is the growth of the server's RSS with `--memory-sessions`
sessions held open at their first turn.

With `--reference CHECKOUT` (another checkout of ippc, e.g. `git worktree add
/tmp/ref COMMIT` or `git archive COMMIT | tar -x -C /tmp/ref`, with `make
install` run there) that checkout's rddl-server is started the same way with
its own venv (`ref`, `ref-wN`), and each line of ours is measured right next to
the reference's in every pass (ours first in even passes, the reference first
in odd ones). The printed ratios are ours over the reference's within each
pass, turns/s and server CPU per turn, median and extremes over the passes: on
a shared machine the CPU per turn is the steadier of the two, since waiting for
a core stretches the wall clock but not the CPU a turn takes.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import selectors
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypedDict

REPO = Path(__file__).resolve().parents[1]
INSTANCE = "sysadmin_inst_mdp__1"
DECL = b'<?xml version="1.0" encoding="UTF-8"?>\n'
QUOTED_RDDLSIM = (420.0, 670.0)

ROUND_REQUEST = DECL + b"<round-request/>\0"
ACTIONS = DECL + b"<actions/>\0"
_AFTER_DECL = len(DECL)


def session_request(name: str) -> bytes:
    return (
        DECL
        + b"<session-request><problem-name>"
        + INSTANCE.encode()
        + b"</problem-name><client-name>"
        + name.encode()
        + b"</client-name></session-request>\0"
    )


def root(msg: bytes) -> bytes:
    """The root element's name (after an optional declaration)."""
    start = msg.find(b"<", msg.find(b"?>") + 2 if msg.startswith(b"<?") else 0)
    end = start + 1
    while end < len(msg) and msg[end] not in b"/> \t\r\n":
        end += 1
    return msg[start + 1 : end]


class _Conn:
    """One noop session: its socket, inbound bytes and progress."""

    __slots__ = ("sock", "buf", "rounds_left", "turns", "held", "done", "canned")

    def __init__(self, sock: socket.socket, canned: dict[str, bytes] | None):
        self.sock = sock
        self.buf = bytearray()
        self.rounds_left = -1  # until session-init
        self.turns = 0
        self.held = False
        self.done = False
        self.canned = canned

    def on_message(self, msg: bytes, hold: bool) -> bytes | None:
        """What to send back for `msg` (None: nothing)."""
        canned = self.canned
        if canned is None and not hold and msg.startswith(b"<turn>", _AFTER_DECL):
            self.turns += 1  # the common case, first
            return ACTIONS
        kind = root(msg)
        if kind == b"turn":
            if canned is not None:
                canned.setdefault("turn", msg)
            self.turns += 1
            if hold and self.turns == 1:
                self.held = True
                return None
            return ACTIONS
        if kind == b"round-end":
            if canned is not None:
                canned["round-end"] = msg
            self.rounds_left -= 1
            return ROUND_REQUEST if self.rounds_left > 0 else None
        if kind == b"round-init":
            if canned is not None:
                canned["round-init"] = msg
            return None
        if kind == b"session-init":
            if canned is not None:
                canned["session-init"] = msg
            m = re.search(rb"<num-rounds>(\d+)</num-rounds>", msg)
            assert m, msg[:200]
            self.rounds_left = int(m.group(1))
            return ROUND_REQUEST
        if kind == b"session-end":
            if canned is not None:
                canned["session-end"] = msg
            self.done = True
            return None
        raise RuntimeError(f"unexpected message {msg[:120]!r}")


class NoopClients:
    """`n` noop sessions at once against 127.0.0.1:`port` (see the module
    docstring). `run()` plays them to the end and returns the turns played.
    With `hold`, every session stops at its first turn until `release()`."""

    def __init__(
        self,
        port: int,
        n: int,
        *,
        name: str = "bench",
        hold: bool = False,
        canned: dict[str, bytes] | None = None,
    ):
        self.conns: list[_Conn] = []
        self.hold = hold
        for i in range(n):
            sock = socket.create_connection(("127.0.0.1", port))
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn = _Conn(sock, canned)
            self.conns.append(conn)
            sock.sendall(session_request(f"{name}{i}"))

    def _feed(self, conn: _Conn, data: bytes) -> None:
        if not data:
            raise EOFError("the server closed the connection")
        buf = conn.buf
        if not buf and data.find(b"\0") == len(data) - 1:
            # the common case: exactly one whole message
            reply = conn.on_message(data[:-1], self.hold)
            if reply is not None:
                conn.sock.sendall(reply)
            return
        buf += data
        start = 0
        out = []
        while (end := buf.find(b"\0", start)) >= 0:
            reply = conn.on_message(bytes(buf[start:end]), self.hold)
            if reply is not None:
                out.append(reply)
            start = end + 1
        if start:
            del buf[:start]
        if out:
            conn.sock.sendall(out[0] if len(out) == 1 else b"".join(out))

    def run(self, until_held: bool = False) -> int:
        """Play until every session ended (or, with `until_held`, until every
        session waits at its held first turn)."""
        live = [c for c in self.conns if not c.done]
        if len(live) == 1 and not until_held:
            conn = live[0]
            recv = conn.sock.recv
            while not conn.done:
                self._feed(conn, recv(65536))
        else:
            with selectors.DefaultSelector() as sel:
                for c in live:
                    sel.register(c.sock, selectors.EVENT_READ, c)
                pending = len(live)
                while pending:
                    for key, _ in sel.select():
                        c = key.data
                        self._feed(c, c.sock.recv(65536))
                        if c.done or (until_held and c.held):
                            sel.unregister(c.sock)
                            pending -= 1
        if not until_held:
            for c in self.conns:
                c.sock.close()
        return sum(c.turns for c in self.conns)

    def release(self) -> None:
        """Answer the held first turns."""
        self.hold = False
        for c in self.conns:
            if c.held:
                c.held = False
                c.sock.sendall(ACTIONS)


LAST_CLIENT_CPU = [0.0]  # CPU seconds of this process (the client) in the last play()


def play(port: int, n: int, canned: dict[str, bytes] | None = None) -> tuple[int, float]:
    """`n` whole noop sessions at once: (turns, seconds), connects included.
    The client's own CPU time is left in LAST_CLIENT_CPU[0]."""
    c0 = time.process_time()
    t0 = time.perf_counter()
    turns = NoopClients(port, n, canned=canned).run()
    secs = time.perf_counter() - t0
    LAST_CLIENT_CPU[0] = time.process_time() - c0
    return turns, secs


# --------------------------------------------------- calls per turn

# rddl-server under cProfile: SIGUSR1 starts counting, SIGUSR2 stops and
# writes the counts to the file named by the first argument
PROFILED = """
import cProfile, os, signal, sys
out = sys.argv.pop(1)
prof = cProfile.Profile()
def dump(*_):
    prof.disable()
    prof.dump_stats(out + ".tmp")
    os.replace(out + ".tmp", out)
signal.signal(signal.SIGUSR1, lambda *_: prof.enable())
signal.signal(signal.SIGUSR2, dump)
from ippc.server.cli import main
main()
"""


def calls_per_turn(
    python: str, rddl: Path, rounds: int, clients: list[int], out: Path
) -> tuple[int, dict[str, float]]:
    """Python function calls per turn of rddl-server (one process), by
    function: the server runs under cProfile, counting from after a first
    session (which compiles the instance) until `clients` sessions have
    been played. Exact counts, whatever the machine's load: what a change
    adds to each turn's work, and where."""
    import pstats
    import signal

    cmd = [python, "-c", PROFILED, str(out), str(rddl), "--port", "0", "--rounds", str(rounds)]
    proc = subprocess.Popen(
        cmd + ["--timeout", "0", "-q", "--workers", "1"], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline().rsplit(":", 1)[1])
        play(port, 1)
        proc.send_signal(signal.SIGUSR1)
        time.sleep(0.5)  # (the handler runs when the server's loop wakes up)
        turns = sum(play(port, n)[0] for n in clients)
        proc.send_signal(signal.SIGUSR2)
        deadline = time.monotonic() + 30
        while not out.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        stop(proc)
    counts: dict[str, float] = {}
    for (path, _, fn), (_, ncalls, *_rest) in pstats.Stats(str(out)).stats.items():  # type: ignore[attr-defined]
        where = "" if path == "~" else f"{Path(path).parent.name}/{Path(path).name}:"
        name = where + re.sub(r" at 0x[0-9a-f]+", "", fn)
        counts[name] = counts.get(name, 0.0) + ncalls / turns
    return turns, counts


def print_calls(args: argparse.Namespace, ref_python: str | None) -> None:
    """--calls: function calls per turn of ours (and of the reference)."""
    clients = sorted(set(args.clients))
    with tempfile.TemporaryDirectory(prefix="ippc-bench-") as tmp:
        folder = Path(tmp)
        rddl = bench_rddl(folder)
        turns, ours = calls_per_turn(sys.executable, rddl, args.rounds, clients, folder / "o")
        print(
            f"rddl-server --workers 1, {turns} turns ({'+'.join(map(str, clients))} clients x"
            f" {args.rounds} rounds, after a first session): {sum(ours.values()):.1f}"
            " Python function calls per turn"
        )
        if ref_python is None:
            return
        rturns, ref = calls_per_turn(ref_python, rddl, args.rounds, clients, folder / "r")
    total, rtotal = sum(ours.values()), sum(ref.values())
    print(
        f"reference {args.reference}: {rtotal:.1f} calls per turn ({rturns} turns);"
        f" ours / reference {total / rtotal:.3f}"
    )
    diffs = sorted(
        ((ours.get(k, 0.0) - ref.get(k, 0.0), k) for k in set(ours) | set(ref)),
        key=lambda d: -abs(d[0]),
    )
    shown = [(d, k) for d, k in diffs if abs(d) >= 0.05][:25]
    print("calls per turn that differ (ours - reference; functions by file and name):")
    for d, k in shown:
        print(f"  {d:+7.2f}  {k}  ({ours.get(k, 0.0):.2f} vs {ref.get(k, 0.0):.2f})")


# --------------------------------------------------- the transport's floor


async def echo_server(canned_file: str) -> None:
    """Answers like rddl-server with canned bytes (no XML, no simulation):
    what trio and the kernel cost per turn, the floor under any trio server."""
    import trio

    canned = {
        k: bytes.fromhex(v) + b"\0" for k, v in json.loads(Path(canned_file).read_text()).items()
    }
    rounds = int(re.search(rb"<num-rounds>(\d+)<", canned["session-init"]).group(1))  # type: ignore[union-attr]

    async def handler(stream: trio.SocketStream) -> None:
        buf = bytearray()

        async def recv() -> None:
            nonlocal buf
            while (i := buf.find(b"\0")) < 0:
                data = await stream.receive_some(1 << 16)
                if not data:
                    raise EOFError
                buf += data
            del buf[: i + 1]

        await recv()
        await stream.send_all(canned["session-init"])
        for _ in range(rounds):
            await recv()
            await stream.send_all(canned["round-init"] + canned["turn"])
            for h in range(40):
                await recv()
                await stream.send_all(canned["turn"] if h < 39 else canned["round-end"])
        await stream.send_all(canned["session-end"])

    listeners = await trio.open_tcp_listeners(0, host="127.0.0.1")
    print(f"listening on 127.0.0.1:{listeners[0].socket.getsockname()[1]}", flush=True)
    await trio.serve_listeners(handler, listeners)


# --------------------------------------------------- processes


def _tree(pid: int) -> list[int]:
    """A process and its descendants (worker processes of rddl-server)."""
    out = [pid]
    for p in out:
        try:
            for task in Path(f"/proc/{p}/task").iterdir():
                out += [int(x) for x in (task / "children").read_text().split()]
        except OSError:
            pass
    return out


def cpu_seconds(pid: int) -> float:
    """CPU time so far of a process and its descendants: the nanoseconds
    on a CPU of each of their threads (/proc/PID/task/TID/schedstat), or,
    where the kernel has no schedstat, user + system time in clock ticks
    (10 ms steps: too coarse for one session's CPU)."""
    total = 0.0
    for p in _tree(pid):
        try:
            tasks = list(Path(f"/proc/{p}/task").iterdir())
            total += sum(int((t / "schedstat").read_text().split()[0]) for t in tasks) / 1e9
            continue
        except (OSError, ValueError, IndexError):
            pass
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def memory_per_session(port: int, pid: int, n: int) -> float:
    """RSS growth of the server per open session (n sessions held open at
    their first turn), then those sessions played to the end."""
    base = rss_kb(pid)
    clients = NoopClients(port, n, name="mem", hold=True)
    clients.run(until_held=True)
    time.sleep(0.5)
    during = rss_kb(pid)
    clients.release()
    clients.run()
    return (during - base) / n


def bench_rddl(folder: Path) -> Path:
    """A folder holding SysAdmin's IPPC 2011 domain and instance 1 from rddlrepository."""
    from importlib import resources

    source = (
        Path(str(resources.files("rddlrepository"))) / "archive/competitions/IPPC2011/SysAdmin/MDP"
    )
    out = folder / "rddl"
    out.mkdir()
    for name in ("domain.rddl", "instance1.rddl"):
        (out / name).write_bytes((source / name).read_bytes())
    return out


def start_ours(
    rddl: Path,
    rounds: int,
    db: Path | None = None,
    workers: int = 1,
    *,
    python: str = sys.executable,
    log_dir: Path | None = None,
    stderr: Path | None = None,
    nofile: int | None = None,
) -> tuple[subprocess.Popen[str], int]:
    """rddl-server as a user starts it, in a process of its own (`python`:
    another checkout's interpreter, see --reference), on a free port; its
    log goes to `stderr` at INFO (else only warnings, `-q`), its open-file
    limit is `nofile` if given. Returns the process and its port."""
    cmd = [
        python,
        "-c",
        "from ippc.server.cli import main; main()",
        str(rddl),
        "--port",
        "0",
        "--rounds",
        str(rounds),
        "--timeout",
        "0",
        "--workers",
        str(workers),
    ]
    if stderr is None:
        cmd.append("-q")
    if db is not None:
        cmd += ["--db", str(db)]
    if log_dir is not None:
        cmd += ["--log-dir", str(log_dir)]
    err = open(stderr, "w") if stderr is not None else None  # noqa: SIM115 (the child's)
    try:
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
            preexec_fn=None if nofile is None else _open_file_limit(nofile),
        )
    finally:
        if err is not None:
            err.close()
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("listening on"):
        proc.kill()
        see = f"; see {stderr}" if stderr is not None else ""
        raise SystemExit(f"rddl-server ({python}) did not start: {line!r}{see}")
    return proc, int(line.rsplit(":", 1)[1])


def _open_file_limit(nofile: int) -> Callable[[], None]:
    def pre() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

    return pre


def reference_python(checkout: Path) -> str:
    """The interpreter of another checkout of ippc (its `make install`
    venv), whose rddl-server --reference measures."""
    python = checkout / ".venv" / "bin" / "python"
    if not python.exists():
        raise SystemExit(
            f"--reference {checkout}: no {python} (run `make install` in that checkout first)"
        )
    return str(python)


def start_canned(canned: dict[str, bytes], folder: Path) -> tuple[subprocess.Popen[str], int]:
    canned_file = folder / "canned.json"
    canned_file.write_text(json.dumps({k: v.hex() for k, v in canned.items()}))
    proc = subprocess.Popen(
        [sys.executable, __file__, "--echo-server", str(canned_file)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    return proc, int(proc.stdout.readline().rsplit(":", 1)[1])


def start_rddlsim(
    classpath: str, rddl: Path, rounds: int, port: int, cwd: Path
) -> subprocess.Popen[bytes]:
    # rddlsim writes rddl-PORT.log into its working directory: a temporary one
    proc = subprocess.Popen(
        [
            "java",
            "-Xmx1g",
            "-cp",
            classpath,
            "rddl.competition.Server",
            str(rddl),
            str(port),
            str(rounds),
            "0",
            "0",
            "0",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=cwd,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            # that probe was a session of its own (rddlsim counts it); fine
            return proc
        except OSError:
            time.sleep(0.3)
    proc.kill()
    raise SystemExit("rddlsim's server did not start")


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def stop(proc: subprocess.Popen[str] | subprocess.Popen[bytes] | None) -> None:
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


class Row(TypedDict):
    """One line of the table: a server and a number of clients over the passes."""

    server: str
    clients: int
    turns: int
    runs: int
    turns_per_s: float
    min: float
    max: float
    server_cpu_us_per_turn: float
    client_cpu_us_per_turn: float


def _row(server: str, n: int, runs: list[tuple[float, float, float, int]]) -> Row:
    rates = [r for r, _, _, _ in runs]
    return {
        "server": server,
        "clients": n,
        "turns": runs[-1][3],
        "runs": len(runs),
        "turns_per_s": statistics.median(rates),
        "min": min(rates),
        "max": max(rates),
        "server_cpu_us_per_turn": statistics.median(c for _, c, _, _ in runs),
        "client_cpu_us_per_turn": statistics.median(c for _, _, c, _ in runs),
    }


def _against_reference(
    pairs: list[tuple[str, str | None]],
    runs: dict[tuple[str, int], list[tuple[float, float, float, int]]],
) -> list[dict[str, float | str | int]]:
    """Ours over the reference's for each pair and number of clients: the
    ratios of turns/s and of server CPU per turn within each pass (the two
    runs were seconds apart), their medians and extremes."""
    out: list[dict[str, float | str | int]] = []
    for key, ref in pairs:
        if ref is None:
            continue
        for (k, n), mine in sorted(runs.items(), key=lambda kv: kv[0][1]):
            if k != key:
                continue
            theirs = runs[ref, n]
            turns = [a[0] / b[0] for a, b in zip(mine, theirs, strict=True)]
            cpu = [a[1] / b[1] for a, b in zip(mine, theirs, strict=True)]
            out.append(
                {
                    "server": key,
                    "clients": n,
                    "turns_ratio": statistics.median(turns),
                    "turns_ratio_min": min(turns),
                    "turns_ratio_max": max(turns),
                    "cpu_ratio": statistics.median(cpu),
                    "cpu_ratio_min": min(cpu),
                    "cpu_ratio_max": max(cpu),
                    "cpu_us": statistics.median(a[1] for a in mine),
                    "cpu_us_ref": statistics.median(b[1] for b in theirs),
                }
            )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--clients", type=int, nargs="+", default=[1, 10, 50])
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--repeat", type=int, default=5, help="runs of every measurement (median)")
    ap.add_argument(
        "--workers",
        default="auto",
        help="--workers of the second rddl-server measured (auto: one per core; 1: measure one server only)",
    )
    ap.add_argument("--memory-sessions", type=int, default=50)
    ap.add_argument(
        "--db", action="store_true", help="run our server with --db (SQLite in a temporary folder)"
    )
    ap.add_argument("--rddlsim-classpath", default=os.environ.get("RDDLSIM_CP"))
    ap.add_argument(
        "--reference",
        metavar="CHECKOUT",
        help="another checkout of ippc with its venv (make install there): its rddl-server is"
        " measured in every pass right next to ours, and the ratios printed",
    )
    ap.add_argument(
        "--calls",
        action="store_true",
        help="instead of the rates: Python function calls per turn of rddl-server (cProfile;"
        " exact whatever the load), against --reference's if given",
    )
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--echo-server", metavar="CANNED", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.echo_server:
        import trio

        trio.run(echo_server, args.echo_server)
        return
    if args.workers == "auto":
        from ippc.server.workers import default_workers

        workers = default_workers()
    else:
        workers = int(args.workers)

    ref_python = reference_python(Path(args.reference).resolve()) if args.reference else None
    if args.calls:
        print_calls(args, ref_python)
        return
    rows: list[Row] = []
    mem_ref: float | None = None
    with tempfile.TemporaryDirectory(prefix="ippc-bench-") as tmp:
        folder = Path(tmp)
        rddl = bench_rddl(folder)

        def db(name: str) -> Path | None:
            return folder / f"results-{name}.sqlite" if args.db else None

        proc, port = start_ours(rddl, args.rounds, db("ippc"))
        procs: list[subprocess.Popen[str] | subprocess.Popen[bytes]] = [proc]
        try:
            canned: dict[str, bytes] = {}
            play(port, 1, canned)  # compiles the instance, keeps one message of each kind
            # memory first, before the load runs leave freed memory for reuse
            mem = memory_per_session(port, proc.pid, args.memory_sessions)
            servers: dict[str, tuple[int, int]] = {"ippc": (port, proc.pid)}
            # (ours, the reference's) pairs measured one right after the other
            pairs: list[tuple[str, str | None]] = []
            for key, n_workers in [("ippc", 1)] + (
                [(f"ippc-w{workers}", workers)] if workers > 1 else []
            ):
                if key != "ippc":
                    wproc, wport = start_ours(rddl, args.rounds, db(key), n_workers)
                    procs.append(wproc)
                    servers[key] = (wport, wproc.pid)
                ref_key = None
                if ref_python is not None:
                    ref_key = key.replace("ippc", "ref")
                    rproc, rport = start_ours(
                        rddl, args.rounds, db(ref_key), n_workers, python=ref_python
                    )
                    procs.append(rproc)
                    servers[ref_key] = (rport, rproc.pid)
                    if n_workers == 1:
                        play(rport, 1)
                        mem_ref = memory_per_session(rport, rproc.pid, args.memory_sessions)
                pairs.append((key, ref_key))
            ours = [k for pair in pairs for k in pair if k is not None]
            eproc, eport = start_canned(canned, folder)
            procs.append(eproc)
            servers["canned"] = (eport, eproc.pid)
            if args.rddlsim_classpath:
                rport = free_port()
                jproc = start_rddlsim(args.rddlsim_classpath, rddl, args.rounds, rport, folder)
                procs.append(jproc)
                servers["rddlsim"] = (rport, jproc.pid)
            for p, _ in servers.values():
                if p != port:
                    play(p, 1)  # warm-up (JIT for rddlsim, compiling in the workers)
            # every measurement once per pass, `repeat` passes: a load change
            # on a shared machine hits all of them alike; ours and the
            # reference one right after the other, in turns first (ABBA)
            runs: dict[tuple[str, int], list[tuple[float, float, float, int]]] = {}
            others = [k for k in servers if k not in ours]
            for i in range(args.repeat):
                order = [
                    k
                    for pair in pairs
                    for k in (pair if i % 2 == 0 else pair[::-1])
                    if k is not None
                ]
                for n in sorted(set(args.clients) | {1}):
                    for key in order + others if n == 1 else order:
                        p, pid = servers[key]
                        cpu0 = cpu_seconds(pid)
                        turns, secs = play(p, n)
                        cpu = cpu_seconds(pid) - cpu0
                        runs.setdefault((key, n), []).append(
                            (
                                turns / secs,
                                1e6 * cpu / turns,
                                1e6 * LAST_CLIENT_CPU[0] / turns,
                                turns,
                            )
                        )
            for key in servers:
                rows.append(_row(key, 1, runs[key, 1]))
            for key in ours:
                rows += [_row(key, n, runs[key, n]) for n in sorted(set(args.clients)) if n > 1]
        finally:
            for pr in procs:
                stop(pr)
    against = _against_reference(pairs, runs)

    ref = next((r["turns_per_s"] for r in rows if r["server"] == "rddlsim"), None)
    if args.json:
        print(
            json.dumps(
                {
                    "rows": rows,
                    "memory_kb_per_session": mem,
                    "rddlsim_same_run": ref,
                    "db": args.db,
                    "workers": workers,
                    "runs": {f"{k}/{n}": v for (k, n), v in runs.items()},
                    "reference": args.reference,
                    "memory_kb_per_session_reference": mem_ref,
                    "against_reference": against,
                },
                indent=2,
            )
        )
        return
    print(
        f"workload: {INSTANCE}, {args.rounds} rounds x horizon 40 per session, noop raw client, loopback"
        + (", ippc with --db" if args.db else "")
    )
    print(
        f"median of {args.repeat} runs of each line, all lines taking turns in every pass (min-max in brackets)"
    )
    print(
        "ippc = rddl-server --workers 1 (one process)"
        + (f"; ippc-w{workers} = rddl-server --workers {workers}" if workers > 1 else "")
        + "; canned = a trio server that answers with fixed bytes (no XML, no simulation)"
    )
    print(
        f"{'server':8} {'clients':>7} {'turns':>8} {'turns/s':>9} {'(min-max)':>13} {'cpu us/turn':>11} {'client cpu':>10}  ratio to rddlsim (1 client)"
    )
    for r in rows:
        rate = r["turns_per_s"]
        if ref:
            ratio = f"{rate / ref:6.1f}x (same run)"
        else:
            lo, hi = QUOTED_RDDLSIM
            ratio = f"{rate / hi:5.1f}x-{rate / lo:.1f}x (quoted 420-670/s, not this run)"
        spread = f"({r['min']:.0f}-{r['max']:.0f})"
        print(
            f"{r['server']:8} {r['clients']:>7} {r['turns']:>8} {rate:>9.0f} {spread:>13} "
            f"{r['server_cpu_us_per_turn']:11.0f} {r['client_cpu_us_per_turn']:10.0f}  {ratio}"
        )
    if ("rddlsim", 1) in runs:
        # the same pass: seconds apart, so a change of the machine's speed
        # between passes cancels out
        for key in ours:
            within = [a[0] / b[0] for a, b in zip(runs[key, 1], runs["rddlsim", 1], strict=True)]
            best = max(r for r, _, _, _ in runs[key, 1]) / max(
                r for r, _, _, _ in runs["rddlsim", 1]
            )
            print(
                f"{key}: one client, ratio to rddlsim within each pass: "
                + ", ".join(f"{x:.1f}" for x in within)
                + f"  (median {statistics.median(within):.1f}x; best run to best run {best:.1f}x)"
            )
    for key in ours:
        line = [r for r in rows if r["server"] == key]
        if len(line) > 1:
            trend = " -> ".join(f"{r['turns_per_s']:.0f}" for r in line)
            holds = all(
                b["turns_per_s"] >= 0.9 * a["turns_per_s"]
                for a, b in zip(line, line[1:], strict=False)
            )
            print(
                f"{key}: aggregate as clients are added: {trend}  ({'holds' if holds else 'FALLS'}, 10% noise allowed)"
            )
    # the canned server does no work: its rate is what this host's loopback
    # and wake-ups allow any server in the same pass
    for key in ours:
        share = [a[0] / b[0] for a, b in zip(runs[key, 1], runs["canned", 1], strict=True)]
        print(
            f"{key}: one client, share of the canned-reply server's rate within each pass: "
            + ", ".join(f"{x:.2f}" for x in share)
        )
    floor = next(r["turns_per_s"] for r in rows if r["server"] == "canned")
    first = next(r["turns_per_s"] for r in rows if r["server"] == "ippc")
    print(
        f"one client: {first / floor:.2f} of the canned-reply server's rate ({floor:.0f} turns/s)"
    )
    print(
        f"memory per open session: {mem:.1f} KiB ({args.memory_sessions} sessions held at their first turn)"
        + (f"; reference {mem_ref:.1f} KiB" if mem_ref is not None else "")
    )
    if against:
        print(
            f"against the reference {args.reference} (ref = its rddl-server), ours / reference"
            " within each pass, median (min-max) over the passes:"
        )
        for a in against:
            print(
                f"  {a['server']:8} {a['clients']:>3} clients: turns/s {a['turns_ratio']:.3f}"
                f" ({a['turns_ratio_min']:.2f}-{a['turns_ratio_max']:.2f}),"
                f" server cpu per turn {a['cpu_ratio']:.3f}"
                f" ({a['cpu_ratio_min']:.2f}-{a['cpu_ratio_max']:.2f});"
                f" cpu us/turn {a['cpu_us']:.0f} vs {a['cpu_us_ref']:.0f}"
            )


if __name__ == "__main__":
    main()
