"""Server settings: rddlsim's command-line arguments as named options."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .limits import default_max_connections

DEFAULT_PORT = 2323
DEFAULT_ROUNDS = 30
DEFAULT_TIMEOUT = 1080  # seconds: rddlsim's 18 minutes
DEFAULT_TIME_ALLOWED_MS = 1_080_000.0
DEFAULT_BUSY_POLL_US = 1000.0  # rddl-server's --busy-poll-us
DEFAULT_REQUEST_TIMEOUT = 30.0  # seconds from connecting to a whole session-request
DEFAULT_MESSAGE_TIMEOUT = 30.0  # seconds from a message's first byte to its last
DEFAULT_MAX_BUFFERED = 64 * 1024 * 1024  # bytes of unfinished messages, over all sessions
DEFAULT_ACCEPT_RATE = 200.0  # new connections a second the listener takes at most


@dataclass(frozen=True)
class ServerConfig:
    """What `rddl-server` is told; the defaults are rddlsim's."""

    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    rounds: int = DEFAULT_ROUNDS
    seed: int = 0
    # seconds; 0 = not enforced (time-allowed is still reported as rddlsim's default)
    timeout: float = DEFAULT_TIMEOUT
    individual_session: bool = False
    monitor_execution: bool = False
    log_dir: Path | None = None
    db: Path | None = None
    transcripts: Path | None = None
    idle_timeout: float | None = (
        None  # seconds a client may stay silent; None = forever, as rddlsim
    )
    max_message_size: int = 10 * 1024 * 1024
    # microseconds a lone session polls its socket for the client's answer
    # before it sleeps in the event loop (see _Channel._poll_briefly); 0 = never.
    # Off here: a client in the same process could not answer during the poll.
    # `rddl-server`, a process of its own, turns it on.
    busy_poll_us: float = 0.0
    # Safe defaults against slow and hostile peers (see docs/server-safety.md);
    # 0 turns a deadline off.
    request_timeout: float = DEFAULT_REQUEST_TIMEOUT
    message_timeout: float = DEFAULT_MESSAGE_TIMEOUT
    # open connections in total and per peer address; None = derived from the
    # open-file limit (server.limits.default_max_connections), per address half that
    max_connections: int | None = None
    max_connections_per_address: int | None = None
    # networks (CIDR) a peer must be in; empty = every address
    allow: tuple[str, ...] = ()
    # bytes of unfinished messages beyond each connection's 64 KiB, over all
    # sessions (split evenly between worker processes)
    max_buffered: int = DEFAULT_MAX_BUFFERED
    # new connections a second the listener accepts (bursts of half that); 0 = no limit
    accept_rate: float = DEFAULT_ACCEPT_RATE

    @property
    def enforce_timeout(self) -> bool:
        return self.timeout > 0

    def connection_caps(self) -> tuple[int, int]:
        """(in total, per address): the options, or what the open-file limit allows."""
        total = self.max_connections or default_max_connections(self.transcripts is not None)
        per = self.max_connections_per_address or max(1, total // 2)
        return total, min(per, total)

    @property
    def time_allowed_ms(self) -> float:
        return float(self.timeout * 1000) if self.timeout > 0 else DEFAULT_TIME_ALLOWED_MS
