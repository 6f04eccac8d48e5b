"""A tiny IPPC server for the PROST launcher tests: it replays the server
side of a recorded PROST session (tests/data/prost/*.jsonl.gz) on
127.0.0.1 and checks that every client message equals the recorded one,
byte for byte. One connection, bounded in time, standard library only."""

from __future__ import annotations

import gzip
import json
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

Script = list[tuple[str, bytes]]  # ("c2s" | "s2c", exact bytes)


def load_recording(path: Path) -> Script:
    """Every message of a recorded session, in order."""
    script: Script = []
    with gzip.open(path, "rt") as f:
        for line in f:
            rec = json.loads(line)
            if "msg" in rec:
                script.append((rec["dir"], rec["msg"].encode("utf-8")))
    return script


def recorded_actions(stdout_gz: Path) -> list[str]:
    """PROST's `Submitted action:` lines, in order."""
    with gzip.open(stdout_gz, "rt") as f:
        return [ln.rstrip("\n") for ln in f if ln.startswith("Submitted action:")]


@dataclass
class ReplayServer:
    """Serve `script` to one client: send the s2c messages, expect the c2s
    ones exactly. Stops at the end of the script, on the first difference,
    on EOF or when `timeout` (seconds, for the whole session) passes."""

    script: Script
    timeout: float = 15.0
    linger: float = 2.0  # how long to wait for the client to close at the end
    received: list[bytes] = field(default_factory=list)
    mismatch: str | None = None
    finished: bool = False  # the whole script was played
    client_closed: bool = False
    error: str | None = None

    def __post_init__(self) -> None:
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.bind(("127.0.0.1", 0))
        self._listener.listen(1)
        self.port: int = self._listener.getsockname()[1]
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> ReplayServer:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.join()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(self.timeout + 5 if timeout is None else timeout)
        self._listener.close()

    def _run(self) -> None:
        deadline = time.monotonic() + self.timeout
        try:
            self._listener.settimeout(self.timeout)
            conn, _ = self._listener.accept()
        except OSError as err:
            self.error = f"no connection: {err}"
            return
        with conn:
            try:
                self._play(conn, deadline)
            except OSError as err:
                self.error = f"{type(err).__name__}: {err}"

    def _recv_exact(self, conn: socket.socket, n: int, deadline: float) -> bytes:
        data = b""
        while len(data) < n:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"timed out with {len(data)} of {n} bytes")
            conn.settimeout(left)
            chunk = conn.recv(n - len(data))
            if not chunk:
                self.client_closed = True
                break
            data += chunk
        return data

    def _play(self, conn: socket.socket, deadline: float) -> None:
        for i, (direction, data) in enumerate(self.script):
            if direction == "s2c":
                conn.sendall(data)
                continue
            got = self._recv_exact(conn, len(data), deadline)
            self.received.append(got)
            if got != data:
                self.mismatch = f"message {i}: expected {data!r}, got {got!r}"
                return
        self.finished = True
        # Wait (bounded) for the client to close, as rddlsim does.
        if self.linger <= 0:
            return
        conn.settimeout(max(0.1, min(self.linger, deadline - time.monotonic())))
        try:
            self.client_closed = conn.recv(1) == b""
        except OSError:
            pass


def short_session(script: Script, *, rounds_cut: bool = False) -> Script:
    """A one-round, one-turn session made of recorded messages: the
    session-init (num-rounds set to 1), round-init, the first turn, the
    recorded noop answer, a round-end and the session-end. With
    `rounds_cut`, the session-init keeps two rounds and the server answers
    the second round-request with session-end (as rddlsim does once the
    session's time is used up)."""
    c2s = [d for k, d in script if k == "c2s"]
    s2c = [d for k, d in script if k == "s2c"]
    noop = next(d for d in c2s if d.endswith(b"<actions></actions>\0"))
    init = s2c[0]
    start, end = init.index(b"<num-rounds>"), init.index(b"</num-rounds>")
    rounds = b"2" if rounds_cut else b"1"
    init = init[: start + len(b"<num-rounds>")] + rounds + init[end:]
    round_end = next(d for d in s2c if d.startswith(b"<round-end>"))
    session_end = next(d for d in s2c if d.startswith(b"<session-end>"))
    out: Script = [
        ("c2s", c2s[0]),
        ("s2c", init),
        ("c2s", c2s[1]),
        ("s2c", s2c[1]),  # round-init
        ("s2c", s2c[2]),  # turn 1
        ("c2s", noop),
        ("s2c", round_end),
    ]
    if rounds_cut:
        out.append(("c2s", c2s[1]))  # the next round-request
    out.append(("s2c", session_end))
    return out
