"""The listener: one trio task per connection, nothing shared but the
read-only instances and the result sinks.

`serve(config, registry)` runs until cancelled (or, with
`individual_session`, until its one session ends). Tests start it with
`nursery.start(serve, config, registry)`, which returns the bound port.
"""

from __future__ import annotations

import itertools
import logging
import signal
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import trio

from .config import ServerConfig
from .environment import Environments
from .limits import (
    EMPTY_CLOSE,
    LISTEN_BACKLOG,
    AcceptPacer,
    ConnectionTable,
    parse_networks,
)
from .listener import accept_connections as listen
from .session import Services, Session

log = logging.getLogger(__name__)


def open_services(
    config: ServerConfig,
    registry: Environments,
    port: int,
    *,
    owner: str | None = None,
    stamp: str | None = None,
    live: Any = None,
) -> Services:
    """The result store, rddlsim's log file and the transcript factory the
    configuration asks for. `owner` names the store's sessions (see
    `ResultStore`), `stamp` starts the transcripts' file names (default: now);
    the worker processes of one server share the stamp. `live` (a
    `server.web.SessionBoard`, for the web view) is told everything the
    store is."""
    from .records import RddlsimLog, TranscriptWriter
    from .store import ResultStore

    store = ResultStore(config.db, owner=owner) if config.db is not None else None
    if store is not None:
        # sessions a killed process of this host left open: closed as killed
        store.close_killed(time.time())
    if live is not None:
        store = live.wrap(store)
    rlog = (
        RddlsimLog(RddlsimLog.default_path(config.log_dir, port))
        if config.log_dir is not None
        else None
    )
    transcripts: Callable[[int, dict[str, Any]], Any] | None = None
    if config.transcripts is not None:
        folder = Path(config.transcripts)
        folder.mkdir(parents=True, exist_ok=True)
        stamp = stamp or time.strftime("%Y%m%d-%H%M%S")

        def transcripts(session_id: int, meta: dict[str, Any]) -> Any:
            stem = f"{stamp}-p{port}-s{session_id}-{meta.get('instance', 'unknown')}"
            return TranscriptWriter(TranscriptWriter.unique_path(folder, stem), meta)

    services = Services(config, registry, store=store, rddlsim_log=rlog, transcripts=transcripts)
    if live is not None:
        live.watch_notices(services.notices)  # (the view counts refused connections)
    return services


def close_services(services: Services, reason: str, close: bool = True) -> None:
    """Record sessions still open as interrupted; with `close`, close the
    store and the log (services passed in by a caller stay open)."""
    if services.store is not None:
        n = services.store.interrupt_open(reason, time.time())
        if n:
            log.warning("%d open session(s) recorded as interrupted: %s", n, reason)
        if close:
            services.store.close()
    if services.rddlsim_log is not None and close:
        services.rddlsim_log.close()


async def serve(
    config: ServerConfig,
    registry: Environments,
    *,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
    services: Services | None = None,
    handle_signals: bool = False,
    live: Any = None,
) -> Services:
    """Accept connections and play a session on each.

    Reports the bound port through `task_status` once listening. Returns the
    services (with the last session's status) when it stops: cancelled, a
    signal with `handle_signals`, or the end of the one session of
    `individual_session`. With `live` (a `server.web.SessionBoard`), the
    sessions' results are noted there too (the web view).
    """
    listeners = await trio.open_tcp_listeners(config.port, host=config.host, backlog=LISTEN_BACKLOG)
    port = listeners[0].socket.getsockname()[1]
    owned = services is None
    svc = services or open_services(config, registry, port, live=live)
    table = connection_table(config)
    keys = itertools.count(1)
    reason = "server stopped"
    try:
        async with trio.open_nursery() as nursery:
            if handle_signals:
                nursery.start_soon(_watch_signals, nursery.cancel_scope)
            nursery.start_soon(svc.notices.run)
            if svc.budget is not None:
                nursery.start_soon(svc.budget.run)

            # each connection's cancel scope and session, to close an idle
            # one when the cap is reached (`evict`)
            playing: dict[int, tuple[trio.CancelScope, list[Session]]] = {}

            async def handler(stream: trio.SocketStream, key: int) -> None:
                scope = trio.CancelScope()
                started: list[Session] = []
                playing[key] = (scope, started)
                try:
                    with scope:
                        await play_connection(svc, stream, started=started.append)
                finally:
                    playing.pop(key, None)
                    table.remove(key)
                if config.individual_session:
                    nursery.cancel_scope.cancel()

            def evict(key: int) -> bool:
                scope, started = playing.get(key, (None, []))
                if scope is None or (started and started[0].requested):
                    return False
                scope.cancel()
                return True

            pacer = AcceptPacer(config.accept_rate)

            def take(stream: trio.SocketStream, key: int) -> bool:
                nursery.start_soon(handler, stream, key)
                return config.individual_session

            for listener in listeners:
                nursery.start_soon(
                    accept_connections, listener, svc, table, pacer, keys, take, evict
                )
            task_status.started(port)
    finally:
        close_services(svc, reason, close=owned)
    return svc


async def accept_connections(
    listener: trio.SocketListener,
    svc: Services,
    table: ConnectionTable,
    pacer: AcceptPacer,
    keys: Iterator[int],
    take: Callable[[trio.SocketStream, int], bool],
    evict: Callable[[int], bool] | None = None,
) -> None:
    """`server.listener.accept_connections` with `svc`'s notices (and
    `evict`, to close idle connections to make room); a
    connection closed before its session-request is numbered as rddlsim
    numbers it, and counted. (rddl-server's listener and rddl-dispatch's.)"""

    def empty(host: str) -> None:
        sid = svc.new_session_id()
        svc.notices.note(
            EMPTY_CLOSE,
            f"session {sid} ({host}): the client closed the connection before its session-request",
        )

    await listen(listener, svc.notices, table, pacer, keys, take, empty, evict)


def connection_table(config: ServerConfig) -> ConnectionTable:
    """The caps and the allowed networks the configuration asks for."""
    total, per_address = config.connection_caps()
    log.debug(
        "at most %d connections open, %d per address%s",
        total,
        per_address,
        f"; only from {', '.join(config.allow)}" if config.allow else "",
    )
    return ConnectionTable(total, per_address, parse_networks(config.allow))


async def play_connection(
    svc: Services,
    stream: trio.SocketStream,
    session_id: int | None = None,
    started: Callable[[Session], object] | None = None,
) -> Session:
    """Play the session of one accepted connection to its end (numbered by
    `svc` unless `session_id` is given). `started` gets the session before it
    plays: a caller cancelled while the session says goodbye (its status and
    record already final) still knows how it ended."""
    try:
        host, cport = stream.socket.getpeername()[:2]
        peer = f"{host}:{cport}"
    except OSError:
        peer = "?"
    session = Session(svc, stream, peer, session_id)
    if started is not None:
        started(session)
    await session.run()
    svc.last_status = session.status
    return session


async def _watch_signals(scope: trio.CancelScope) -> None:
    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
        async for signum in signals:
            log.info("signal %s: shutting down", signal.Signals(signum).name)
            scope.cancel()
            return
