"""What the server allows its peers: who may connect, how many at once, how
much memory their unfinished messages may hold, and how often their faults
are logged.

A competition server runs for days among clients nobody controls. The
listener asks a `ConnectionTable` before it gives a connection a session
(`--allow`, the cap in total and per address; a refused connection is closed
at once and costs nothing else). A session's bytes wait in its protocol
reader until a message is complete; up to `BUFFER_ALLOWANCE` of them are the
connection's own (every message a planner sends fits), the rest is drawn
from one `BufferBudget` shared by the process's sessions, and the connection
that cannot draw is closed. `Notices` logs each kind of hostile or broken
peer once, and then a count per interval instead of a line per event.
"""

from __future__ import annotations

import ctypes
import ipaddress
import logging
import resource
import socket
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger(__name__)

# descriptors a server needs besides its connections: listener, worker
# control sockets, the database (and its WAL files), logs, Python's own
FD_HEADROOM = 64
# bytes of an unfinished message that are a connection's own, outside the
# shared budget: more than any message a planner sends (actions, requests)
BUFFER_ALLOWANCE = 64 * 1024
# connections the kernel queues for the listener: with the accept pacing, a
# flood beyond it waits in its own connects (rddlsim's Java listener: 50)
LISTEN_BACKLOG = 128
# seconds a connection without a session is safe from being closed to make
# room for a new one when the cap is reached (a client sends its
# session-request at once; one that has not after this is idle)
IDLE_GRACE = 1.0
# seconds between summaries of repeated notices
NOTICE_INTERVAL = 10.0
# notices of one cause logged in full per interval before they are counted
NOTICE_BURST = 3

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def open_file_limit() -> int:
    """The soft limit on open descriptors of this process (RLIMIT_NOFILE)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft <= 0:
        return 1 << 20
    return int(soft)


def default_max_connections(transcripts: bool = False, limit: int | None = None) -> int:
    """The connection cap that fits the open-file limit: each connection
    holds two descriptors in the process that plays it (its socket and the
    dup the session reads through), three with transcripts, and
    `FD_HEADROOM` stay for everything else."""
    limit = open_file_limit() if limit is None else limit
    per_connection = 3 if transcripts else 2
    return max(1, (limit - FD_HEADROOM) // per_connection)


def parse_networks(values: Iterable[str]) -> tuple[Network, ...]:
    """`--allow` values as networks; ValueError names a bad one."""
    out = []
    for v in values:
        try:
            out.append(ipaddress.ip_network(v.strip(), strict=False))
        except ValueError:
            raise ValueError(
                f"{v!r} is not a network (CIDR such as 10.0.0.0/8 or ::1/128)"
            ) from None
    return tuple(out)


def peer_host(sock: Any) -> str:
    """The peer address of a connected socket without its port ("?" when
    the peer is gone already)."""
    try:
        return str(sock.getpeername()[0])
    except OSError:
        return "?"


class AcceptPacer:
    """At most `rate` new connections a second (bursts of `burst`): under a
    flood the rest wait in the kernel's backlog, and once that is full the
    flooder's own connects wait (its SYNs are not answered), so the flood
    costs the machine what `rate` connections cost, while the sessions in
    progress take their turns. rate 0: no pacing."""

    def __init__(self, rate: float, burst: float | None = None):
        self.rate = rate
        self.burst = burst if burst is not None else max(1.0, rate / 2)
        self._tokens = self.burst
        self._last = time.monotonic()

    async def pace(self) -> None:
        """Take one connection's token, sleeping until there is one."""
        if self.rate <= 0:
            return
        import trio

        now = time.monotonic()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
        self._last = now
        self._tokens -= 1.0
        if self._tokens < 0:
            await trio.sleep(-self._tokens / self.rate)


def closed_already(sock: Any) -> bool:
    """Whether the peer of a just-accepted connection has closed it already
    (its end of stream is queued, nothing before it): such a connection,
    the bulk of a connect-and-drop flood, is counted and closed by the
    listener without costing a session anything."""
    try:
        # (a plain socket object over the same descriptor: trio's recv is async)
        raw = socket.socket(fileno=sock.fileno())
    except OSError:
        return True
    try:
        return raw.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except (BlockingIOError, InterruptedError):
        return False
    except OSError:
        return True  # reset by the peer
    finally:
        raw.detach()  # the descriptor stays the caller's


IDLE_EVICTED = (
    "connections closed to make room: the cap was reached and they had no session"
    " after 1 s (the oldest first)"
)

EMPTY_CLOSE = (
    "connections closed before a session-request:"
    " the client closed the connection before its session-request"
)


def _address(host: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        addr = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return None
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        return addr.ipv4_mapped
    return addr


@dataclass
class ConnectionTable:
    """The connections a listener has given sessions, by key (the session
    number) and by peer address; it decides who else may come in."""

    max_total: int
    max_per_address: int
    allow: tuple[Network, ...] = ()
    # seconds a connection may stay without a session before it may be
    # closed to make room for a new one (see `oldest_idle`)
    min_idle_age: float = IDLE_GRACE
    _by_key: dict[int, str] = field(default_factory=dict)
    _per_address: Counter[str] = field(default_factory=Counter)
    _opened: dict[int, float] = field(default_factory=dict)  # key -> monotonic time
    _in_session: set[int] = field(default_factory=set)
    _evicting: set[int] = field(default_factory=set)
    _asked: set[int] = field(default_factory=set)  # asked to close if idle, no answer yet

    @property
    def open(self) -> int:
        return len(self._by_key)

    def full(self) -> bool:
        """Whether the cap in total is reached (connections being closed
        to make room do not count)."""
        return len(self._by_key) - len(self._evicting) >= self.max_total

    def in_session(self, key: int) -> None:
        """Connection `key` has its session: never closed to make room."""
        if key in self._by_key:
            self._in_session.add(key)
        self._evicting.discard(key)
        self._asked.discard(key)

    def oldest_idle(self, now: float | None = None) -> int | None:
        """The connection open the longest (at least `min_idle_age`) that
        has no session yet and is not being closed already, or None."""
        now = time.monotonic() if now is None else now
        for key, since in self._opened.items():  # (in the order they came)
            if now - since < self.min_idle_age:
                return None
            if key not in self._in_session | self._evicting | self._asked:
                return key
        return None

    def asked(self, key: int) -> None:
        """Connection `key` is asked to close if it is idle (in another
        process): not asked again; its place counts until it closes."""
        if key in self._by_key:
            self._asked.add(key)

    def evicting(self, key: int) -> None:
        """Connection `key` is being closed to make room: its place counts
        as free from now on."""
        if key in self._by_key:
            self._evicting.add(key)

    def refusal(self, host: str) -> tuple[str, str] | None:
        """Why a connection from `host` is refused now, as (cause, detail),
        or None when it may come in."""
        if self.allow:
            addr = _address(host)
            if addr is None or not any(addr in net for net in self.allow):
                why = "address not in --allow"
                return (f"connections refused: {why}", f"connection from {host} refused: {why}")
        if self.full():
            why = f"cap of {self.max_total} open connections reached"
            return (f"connections refused: {why}", f"connection from {host} refused: {why}")
        if self._per_address[host] >= self.max_per_address:
            why = f"cap of {self.max_per_address} per address reached"
            return (f"connections refused: {why}", f"connection from {host} refused: {why}")
        return None

    def add(self, key: int, host: str) -> None:
        self._by_key[key] = host
        self._per_address[host] += 1
        self._opened[key] = time.monotonic()

    def remove(self, key: int) -> None:
        host = self._by_key.pop(key, None)
        self._opened.pop(key, None)
        self._in_session.discard(key)
        self._evicting.discard(key)
        self._asked.discard(key)
        if host is None:
            return
        self._per_address[host] -= 1
        if self._per_address[host] <= 0:
            del self._per_address[host]


def _malloc_trim() -> Callable[[], object] | None:
    """glibc's malloc_trim(0), or None where there is none (musl, macOS)."""
    try:
        libc = ctypes.CDLL(None)
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    return lambda: trim(0)


class BufferBudget:
    """Bytes of unfinished messages beyond each connection's allowance, in
    total over the sessions of one process.

    Memory given back (measured with one process, 3 waves of 60 connections
    sending 10,000,000 bytes without a terminator): the readers' buffers are
    freed when their session ends or their stream fails (not when a garbage
    collection breaks the cycle through the stored error's traceback, which
    kept 1.7 GB); what the C heap then keeps as free pages (12 MB in that
    run) `run` returns to the system with glibc's malloc_trim, at most once
    per `TRIM_INTERVAL` after such bytes were released.
    """

    TRIM_INTERVAL = 1.0

    def __init__(self, limit: int, allowance: int = BUFFER_ALLOWANCE):
        self.limit = limit
        self.allowance = allowance
        self.used = 0
        self.released = 0  # bytes released since the last trim
        self.trims = 0

    def charge(self, held: int, pending: int) -> int | None:
        """A connection that held `held` bytes of the budget now has
        `pending` bytes buffered: the bytes it holds now, or None when the
        budget cannot give them (it then holds what it held)."""
        want = pending - self.allowance
        if want <= 0:
            self.release(held)
            return 0
        grow = want - held
        if grow > 0 and self.used + grow > self.limit:
            return None
        self.used += grow
        return want

    def release(self, held: int) -> None:
        self.used -= held
        self.released += held

    def trim(self) -> None:
        """Return the C heap's free pages to the system now."""
        self.released = 0
        self.trims += 1
        if _TRIM is not None:
            _TRIM()

    async def run(self) -> None:
        """Trim after releases, at most once per TRIM_INTERVAL, until cancelled."""
        import trio

        while True:
            await trio.sleep(self.TRIM_INTERVAL)
            if self.released:
                self.trim()


_TRIM = _malloc_trim()


class Notices:
    """Warnings about peers, logged once per cause and then counted: the
    first `burst` of a cause in an interval in full, the rest as one line
    per interval ("1,234 connections refused ... in the last 10 s")."""

    def __init__(
        self,
        logger: logging.Logger | None = None,
        interval: float = NOTICE_INTERVAL,
        burst: int = NOTICE_BURST,
        clock: Callable[[], float] | None = None,
    ):
        self.log = logger or log
        self.interval = interval
        self.burst = burst
        self._clock = clock or time.monotonic
        self._window_start = self._clock()
        self._shown: Counter[str] = Counter()
        self._hidden: Counter[str] = Counter()
        self.totals: Counter[str] = Counter()  # every notice since the start, by cause
        # told every cause noted (the web view counts the refused connections)
        self.watchers: list[Callable[[str], object]] = []

    def note(self, cause: str, detail: str, level: int = logging.WARNING) -> None:
        """One event of `cause`; `detail` is its full line."""
        self.totals[cause] += 1
        for watch in self.watchers:
            watch(cause)
        now = self._clock()
        if now - self._window_start >= self.interval:
            self.flush(now)
        if self._shown[cause] < self.burst:
            self._shown[cause] += 1
            more = (
                f" (more of these are counted, one line per {self.interval:g} s)"
                if self._shown[cause] == self.burst
                else ""
            )
            self.log.log(level, "%s%s", detail, more)
        else:
            self._hidden[cause] += 1

    def flush(self, now: float | None = None) -> None:
        """Log the counts of the interval that ends now and start another."""
        now = self._clock() if now is None else now
        span = now - self._window_start
        for cause, n in sorted(self._hidden.items()):
            what, _, why = cause.partition(": ")
            self.log.warning(
                "%s %s in the last %d s%s",
                f"{n:,}",
                what,
                max(1, round(span)),
                f": {why}" if why else "",
            )
        self._hidden.clear()
        self._shown.clear()
        self._window_start = now

    async def run(self) -> None:
        """Flush every interval until cancelled (then once more)."""
        import trio

        try:
            while True:
                await trio.sleep(self.interval)
                if self._hidden or self._shown:
                    self.flush()
        finally:
            if self._hidden:
                self.flush()


__all__ = [
    "BUFFER_ALLOWANCE",
    "LISTEN_BACKLOG",
    "AcceptPacer",
    "BufferBudget",
    "ConnectionTable",
    "Notices",
    "default_max_connections",
    "open_file_limit",
    "parse_networks",
    "peer_host",
]
