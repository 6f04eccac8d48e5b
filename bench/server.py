"""Turns per second of rddl-server over loopback, and memory per session.

Workload (the issue's): sysadmin_inst_mdp__1 from the shared rddl-bench
folder (10 computers, horizon 40), 30 rounds = 1200 turns per session, a
minimal raw Python client that answers every turn with `<actions/>`, as
rddlsim's own throughput was measured (see PROTOCOL-rddlsim.md §11).

    python bench/server.py                 # 1, 10 and 50 clients
    python bench/server.py --clients 1 --rounds 5
    python bench/server.py --rddlsim-classpath /path/to/rddlsim/bin:/path/to/lib/*

With `--rddlsim-classpath` (a build of rddlsim you made outside this
repository) the same workload also runs against rddlsim's Java server in
the same run and the table shows the ratio. Without it, the ratio is
against the figure quoted in the issue (420-670 turns/s for one client on
a 2-core machine), which is not a same-run reference: read it as such.

The server runs as a separate process (as users run it); the clients run
in this process, one trio task each.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import trio

REPO = Path(__file__).resolve().parents[1]
BENCH_RDDL = REPO.parent / "shared" / "rddlsim-transcripts" / "rddl-bench"
INSTANCE = "sysadmin_inst_mdp__1"
DECL = b'<?xml version="1.0" encoding="UTF-8"?>\n'
QUOTED_RDDLSIM = (420.0, 670.0)


def session_request(name: str) -> bytes:
    return (
        DECL
        + b"<session-request><problem-name>"
        + INSTANCE.encode()
        + b"</problem-name><client-name>"
        + name.encode()
        + b"</client-name></session-request>\0"
    )


class Raw:
    """The smallest client: NUL framing, the root element, nothing more."""

    def __init__(self, stream: trio.SocketStream):
        self.stream = stream
        self.buf = bytearray()

    async def recv(self) -> bytes:
        while True:
            i = self.buf.find(b"\0")
            if i >= 0:
                msg = bytes(self.buf[:i])
                del self.buf[: i + 1]
                return msg
            data = await self.stream.receive_some(1 << 16)
            if not data:
                raise EOFError("server closed")
            self.buf += data


async def one_session(port: int, name: str, hold: trio.Event | None = None, canned: dict[str, bytes] | None = None) -> int:
    """A whole noop session; returns the turns played (and, with `canned`,
    keeps one server message of each kind)."""
    stream = await trio.open_tcp_stream("127.0.0.1", port)
    turns = 0
    async with stream:
        c = Raw(stream)
        await stream.send_all(session_request(name))
        init = await c.recv()
        if canned is not None:
            canned["session-init"] = init
        m = re.search(rb"<num-rounds>(\d+)</num-rounds>", init)
        assert m, init[:200]
        for _ in range(int(m.group(1))):
            await stream.send_all(DECL + b"<round-request/>\0")
            rinit = await c.recv()
            while b"<round-end>" not in (msg := await c.recv()):
                if canned is not None:
                    canned.setdefault("turn", msg)
                turns += 1
                if hold is not None:
                    await hold.wait()
                    hold = None
                await stream.send_all(DECL + b"<actions/>\0")
            if canned is not None:
                canned["round-init"], canned["round-end"] = rinit, msg
        end = await c.recv()
        assert b"<session-end>" in end
        if canned is not None:
            canned["session-end"] = end
    return turns


# --------------------------------------------------- the transport's floor


async def echo_server(canned_file: str) -> None:
    """Answers like rddl-server with canned bytes (no XML, no simulation):
    what trio and the kernel cost per turn, the floor under any Python server."""
    canned = {k: bytes.fromhex(v) + b"\0" for k, v in json.loads(Path(canned_file).read_text()).items()}
    rounds = int(re.search(rb"<num-rounds>(\d+)<", canned["session-init"]).group(1))  # type: ignore[union-attr]

    async def handler(stream: trio.SocketStream) -> None:
        c = Raw(stream)
        await c.recv()
        await stream.send_all(canned["session-init"])
        for _ in range(rounds):
            await c.recv()
            await stream.send_all(canned["round-init"] + canned["turn"])
            for h in range(40):
                await c.recv()
                await stream.send_all(canned["turn"] if h < 39 else canned["round-end"])
        await stream.send_all(canned["session-end"])

    listeners = await trio.open_tcp_listeners(0, host="127.0.0.1")
    print(f"listening on 127.0.0.1:{listeners[0].socket.getsockname()[1]}", flush=True)
    await trio.serve_listeners(handler, listeners)


async def run_clients(port: int, n: int) -> tuple[int, float]:
    total = 0
    t0 = time.perf_counter()

    async def go(i: int) -> None:
        nonlocal total
        played = await one_session(port, f"bench{i}")  # not `total += await`: that reads total first
        total += played

    async with trio.open_nursery() as nursery:
        for i in range(n):
            nursery.start_soon(go, i)
    return total, time.perf_counter() - t0


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


async def memory_per_session(port: int, pid: int, n: int) -> float:
    """RSS growth of the server per open session (n sessions held open
    at their first turn)."""
    hold = trio.Event()
    base = rss_kb(pid)
    async with trio.open_nursery() as nursery:
        for i in range(n):
            nursery.start_soon(one_session, port, f"mem{i}", hold)
        await trio.sleep(2.0)
        during = rss_kb(pid)
        hold.set()
    return (during - base) / n


def start_ours(rounds: int) -> tuple[subprocess.Popen[str], int]:
    proc = subprocess.Popen(
        [sys.executable, "-c", "from ippc.server.cli import main; main()", str(BENCH_RDDL),
         "--port", "0", "--rounds", str(rounds), "--timeout", "0", "-q"],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("listening on"):
        proc.kill()
        raise SystemExit(f"rddl-server did not start: {line!r}")
    return proc, int(line.rsplit(":", 1)[1])


def start_rddlsim(classpath: str, rounds: int, port: int) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen(
        ["java", "-Xmx1g", "-cp", classpath, "rddl.competition.Server", str(BENCH_RDDL), str(port), str(rounds), "0", "0", "0"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    import socket

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
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clients", type=int, nargs="+", default=[1, 10, 50])
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--memory-sessions", type=int, default=50)
    ap.add_argument("--rddlsim-classpath", default=os.environ.get("RDDLSIM_CP"))
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--echo-server", metavar="CANNED", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.echo_server:
        trio.run(echo_server, args.echo_server)
        return
    if not BENCH_RDDL.is_dir():
        raise SystemExit(f"missing {BENCH_RDDL} (the shared folder beside the checkout)")

    rows = []
    proc, port = start_ours(args.rounds)
    canned: dict[str, bytes] = {}
    try:
        trio.run(one_session, port, "warm-up", None, canned)  # compiles the instance, keeps samples
        # memory first, before the load runs leave freed memory for reuse
        mem = trio.run(memory_per_session, port, proc.pid, args.memory_sessions)
        for n in args.clients:
            cpu0 = cpu_seconds(proc.pid)
            turns, secs = trio.run(run_clients, port, n)
            cpu = cpu_seconds(proc.pid) - cpu0
            rows.append({"server": "ippc", "clients": n, "turns": turns, "seconds": secs, "turns_per_s": turns / secs,
                         "server_cpu_us_per_turn": 1e6 * cpu / turns})
    finally:
        proc.terminate()
        proc.wait(10)

    # the same client against canned replies: the floor of the transport
    canned_file = Path(os.environ.get("TMPDIR", "/tmp")) / f"ippc-bench-canned-{os.getpid()}.json"
    canned_file.write_text(json.dumps({k: v.hex() for k, v in canned.items()}))
    eproc = subprocess.Popen([sys.executable, __file__, "--echo-server", str(canned_file)], stdout=subprocess.PIPE, text=True)
    try:
        assert eproc.stdout is not None
        eport = int(eproc.stdout.readline().rsplit(":", 1)[1])
        trio.run(run_clients, eport, 1)
        turns, secs = trio.run(run_clients, eport, 1)
        floor = turns / secs
        rows.append({"server": "canned", "clients": 1, "turns": turns, "seconds": secs, "turns_per_s": floor})
    finally:
        eproc.kill()
        eproc.wait(10)
        canned_file.unlink(missing_ok=True)

    ref_one: float | None = None
    if args.rddlsim_classpath:
        rport = free_port()
        jproc = start_rddlsim(args.rddlsim_classpath, args.rounds, rport)
        try:
            trio.run(run_clients, rport, 1)
            turns, secs = trio.run(run_clients, rport, 1)
            ref_one = turns / secs
            rows.append({"server": "rddlsim", "clients": 1, "turns": turns, "seconds": secs, "turns_per_s": ref_one})
        finally:
            jproc.kill()
            jproc.wait(10)

    if args.json:
        print(json.dumps({"rows": rows, "memory_kb_per_session": mem, "rddlsim_same_run": ref_one}, indent=2))
        return
    print(f"workload: {INSTANCE}, {args.rounds} rounds x horizon 40 per session, noop raw client, loopback")
    print("canned = a server that answers with fixed bytes (no XML, no simulation): the floor")
    print(f"{'server':8} {'clients':>7} {'turns':>8} {'seconds':>8} {'turns/s':>9} {'cpu us/turn':>11}  ratio to rddlsim (1 client)")
    for r in rows:
        if ref_one:
            ratio = f"{r['turns_per_s'] / ref_one:6.1f}x (same run)"
        else:
            lo, hi = QUOTED_RDDLSIM
            ratio = f"{r['turns_per_s'] / hi:5.1f}x-{r['turns_per_s'] / lo:.1f}x (quoted 420-670/s, not this run)"
        cpu = f"{r['server_cpu_us_per_turn']:11.0f}" if "server_cpu_us_per_turn" in r else f"{'-':>11}"
        print(f"{r['server']:8} {r['clients']:>7} {r['turns']:>8} {r['seconds']:>8.2f} {r['turns_per_s']:>9.0f} {cpu}  {ratio}")
    ours = [r for r in rows if r["server"] == "ippc"]
    if len(ours) > 1:
        trend = " >= ".join(f"{r['turns_per_s']:.0f}" for r in ours)
        holds = all(b["turns_per_s"] >= 0.9 * a["turns_per_s"] for a, b in zip(ours, ours[1:], strict=False))
        print(f"aggregate as clients are added: {trend}  ({'holds' if holds else 'FALLS'}, 10% noise allowed)")
    one = next(r for r in ours if r["clients"] == 1)
    print(f"one client: {one['turns_per_s'] / floor:.2f} of the canned-reply floor ({floor:.0f} turns/s: "
          "trio + kernel + this client, no XML, no simulation)")
    print(f"memory per open session: {mem:.0f} KiB ({args.memory_sessions} sessions held at their first turn)")


if __name__ == "__main__":
    main()
