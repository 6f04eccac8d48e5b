"""`rddl-server`: rddlsim's competition server, with its options named."""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Any

import click
import trio

from ..rddl import RDDLError
from ..web import WebOptions, serve_web, web_options, web_url
from .app import serve
from .config import (
    DEFAULT_BUSY_POLL_US,
    DEFAULT_MAX_BUFFERED,
    DEFAULT_MESSAGE_TIMEOUT,
    DEFAULT_PORT,
    DEFAULT_REQUEST_TIMEOUT,
    DEFAULT_ROUNDS,
    DEFAULT_TIMEOUT,
    ServerConfig,
)
from .options import check_connection_options, connection_options
from .registry import Registry
from .workers import WorkerError, default_workers, serve_with_workers, supported


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("rddl_dir", type=click.Path(exists=True, path_type=Path))
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to bind (rddlsim binds every interface; we bind loopback unless told).",
)
@click.option(
    "--port", default=DEFAULT_PORT, show_default=True, help="TCP port; 0 picks a free one."
)
@click.option("--rounds", default=DEFAULT_ROUNDS, show_default=True, help="Rounds per session.")
@click.option("--seed", default=0, show_default=True, help="Session k uses seed + k - 1.")
@click.option(
    "--timeout",
    default=DEFAULT_TIMEOUT,
    show_default=True,
    type=float,
    help="Session budget in seconds; 0 = not enforced.",
)
@click.option(
    "--individual-session",
    is_flag=True,
    help="Serve one connection, then exit (exit code 1 if it failed).",
)
@click.option(
    "--monitor-execution",
    is_flag=True,
    help="Round-requests without execute-policy yes play uncounted practice rounds.",
)
@click.option(
    "--log-dir",
    type=click.Path(file_okay=False, path_type=Path),
    help="Write rddlsim's log file logs-PORT.log here.",
)
@click.option(
    "--db",
    type=click.Path(dir_okay=False, path_type=Path),
    help="SQLite result database (sessions, rounds, steps).",
)
@click.option(
    "--transcripts",
    type=click.Path(file_okay=False, path_type=Path),
    help="Record every message of every session here (JSON lines).",
)
@click.option(
    "--idle-timeout",
    type=float,
    default=None,
    help="Close a session whose client is silent this many seconds (off by default, as rddlsim).",
)
@click.option(
    "--request-timeout",
    type=float,
    default=DEFAULT_REQUEST_TIMEOUT,
    show_default=True,
    help="Close a connection that has not sent its whole session-request this many seconds after connecting; 0 = off.",
)
@click.option(
    "--message-timeout",
    type=float,
    default=DEFAULT_MESSAGE_TIMEOUT,
    show_default=True,
    help="Close a session whose client has not finished a message this many seconds after its first byte; 0 = off.",
)
@connection_options
@click.option(
    "--max-buffered-mib",
    type=float,
    default=DEFAULT_MAX_BUFFERED / (1 << 20),
    show_default=True,
    help="MiB of unfinished messages over all sessions beyond 64 KiB each; a connection that needs more is closed.",
)
@click.option(
    "--busy-poll-us",
    type=float,
    default=DEFAULT_BUSY_POLL_US,
    show_default=True,
    help="Microseconds a lone session polls for its client's answer before it sleeps; 0 = off (always off with one CPU).",
)
@click.option(
    "--workers",
    default="auto",
    show_default=True,
    metavar="N|auto",
    help="Processes that play the sessions (one listener hands each connection to the least busy); auto = one per core (one process on one core, with --individual-session, or where workers cannot run). Sessions are numbered and seeded as with one.",
)
@web_options
@click.option("-q", "--quiet", is_flag=True, help="Log warnings only.")
def main(
    rddl_dir: Path,
    host: str,
    port: int,
    rounds: int,
    seed: int,
    timeout: float,
    individual_session: bool,
    monitor_execution: bool,
    log_dir: Path | None,
    db: Path | None,
    transcripts: Path | None,
    idle_timeout: float | None,
    request_timeout: float,
    message_timeout: float,
    max_connections: int | None,
    max_connections_per_address: int | None,
    allow: tuple[str, ...],
    max_buffered_mib: float,
    accept_rate: float,
    busy_poll_us: float,
    workers: str,
    web: int | None,
    web_host: str | None,
    quiet: bool,
) -> None:
    """Serve every RDDL instance under RDDL_DIR to IPPC clients (PROST,
    rddlsim's client, rddl-client) over rddlsim's protocol."""
    logging.basicConfig(
        level=logging.WARNING if quiet else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if rounds < 1:
        raise click.BadParameter("must be at least 1", param_hint="--rounds")
    if idle_timeout is not None and idle_timeout <= 0:
        raise click.BadParameter("must be positive", param_hint="--idle-timeout")
    for name, value in (
        ("--request-timeout", request_timeout),
        ("--message-timeout", message_timeout),
    ):
        if value < 0:
            raise click.BadParameter("must be 0 (off) or positive", param_hint=name)
    check_connection_options(max_connections, max_connections_per_address, allow, accept_rate)
    if max_buffered_mib <= 0:
        raise click.BadParameter("must be positive", param_hint="--max-buffered-mib")
    if not 0 <= busy_poll_us <= 10_000:
        raise click.BadParameter("must be between 0 and 10000", param_hint="--busy-poll-us")
    n_workers = _workers(workers, individual_session)
    web_opts = WebOptions.from_cli(web, web_host)
    if busy_poll_us and default_workers() < 2:
        # with one CPU the poll would only keep the client from answering
        logging.getLogger(__name__).info("one CPU: the busy poll is off")
        busy_poll_us = 0.0
    try:
        registry = Registry.load(rddl_dir)
    except RDDLError as err:
        raise click.ClickException(str(err)) from None
    if not len(registry):
        raise click.ClickException(f"no instance to serve under {rddl_dir}")
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
    if db is not None:
        _prepare_db(db)
    config = ServerConfig(
        host=host,
        port=port,
        rounds=rounds,
        seed=seed,
        timeout=timeout,
        individual_session=individual_session,
        monitor_execution=monitor_execution,
        log_dir=log_dir,
        db=db,
        transcripts=transcripts,
        idle_timeout=idle_timeout,
        busy_poll_us=busy_poll_us,
        request_timeout=request_timeout,
        message_timeout=message_timeout,
        max_connections=max_connections,
        max_connections_per_address=max_connections_per_address,
        allow=tuple(allow),
        max_buffered=int(max_buffered_mib * (1 << 20)),
        accept_rate=accept_rate,
    )

    async def run() -> str | None:
        async with trio.open_nursery() as nursery:
            board = None
            if web_opts is not None:
                from .web import ServerView, SessionBoard

                board = SessionBoard()
                view = ServerView(board)
                web_port = await nursery.start(serve_web, view.routes, web_opts)
                nursery.start_soon(view.run)
            if n_workers > 1:
                bound = await nursery.start(
                    _serve_workers_and_stop,
                    config,
                    str(rddl_dir),
                    n_workers,
                    nursery.cancel_scope,
                    board,
                )
            else:
                bound = await nursery.start(
                    _serve_and_stop, config, registry, nursery.cancel_scope, board
                )
            _listening[0] = True
            click.echo(f"listening on {host}:{bound}", err=False)
            if web_opts is not None:
                click.echo(f"web view on {web_url(web_opts, web_port)}", err=False)
            sys.stdout.flush()
            click.echo(
                f"serving {len(registry)} instance(s): {', '.join(registry.names()[:8])}"
                + (" ..." if len(registry) > 8 else ""),
                err=True,
            )
            click.echo(_limits_line(config), err=True)
        return _last_status[0]

    try:
        status = trio.run(run)
    except BaseException as exc:  # trio hands some errors over in exception groups
        leaf = _leaf(exc)
        if isinstance(leaf, KeyboardInterrupt):
            status = None
        elif isinstance(leaf, WorkerError):
            raise click.ClickException(str(leaf)) from None
        elif isinstance(leaf, OSError):
            what = "server failed" if _listening[0] else f"cannot listen on {host}:{port}"
            raise click.ClickException(f"{what}: {leaf}") from None
        else:
            raise
    if individual_session and status not in (None, "finished", "timeout"):
        sys.exit(1)


def _limits_line(config: ServerConfig) -> str:
    """What the server allows its clients (see docs/server-safety.md)."""
    total, per_address = config.connection_caps()

    def secs(value: float) -> str:
        return f"{value:g} s" if value > 0 else "no limit"

    return (
        f"limits: {total} connections ({per_address} per address"
        + (f", only from {', '.join(config.allow)}" if config.allow else "")
        + f"); session-request {secs(config.request_timeout)},"
        f" each message {secs(config.message_timeout)};"
        f" {config.max_buffered / (1 << 20):g} MiB of unfinished messages"
    )


_last_status: list[str | None] = [None]
_listening = [False]


def _prepare_db(db: Path) -> None:
    """Create (or check) the result database once, before any session or worker
    opens it: a bad file is refused here with one line, and the workers find it
    already in WAL mode with its schema."""
    import sqlite3

    from .store import ResultStore

    try:
        ResultStore(db).close()
    except (sqlite3.Error, OSError, RuntimeError) as err:
        raise click.ClickException(f"--db {db}: {err}") from None


def _leaf(exc: BaseException) -> BaseException:
    """The one error inside nested exception groups of one error each."""
    while isinstance(exc, BaseExceptionGroup) and len(exc.exceptions) == 1:
        exc = exc.exceptions[0]
    return exc


def _workers(value: str, individual_session: bool) -> int:
    """The number of worker processes; 1 = none (one process plays all)."""
    if value.strip().lower() == "auto":
        n = default_workers()
        why = "--individual-session" if individual_session else supported()
        if n > 1 and why is not None:
            logging.getLogger(__name__).info("--workers auto: one process (%s)", why)
            return 1
        return n
    try:
        n = int(value)
    except ValueError:
        raise click.BadParameter(
            f"{value!r} is not a number or 'auto'", param_hint="--workers"
        ) from None
    if n < 1:
        raise click.BadParameter("must be at least 1", param_hint="--workers")
    if n > 1 and individual_session:
        raise click.BadParameter(
            "--individual-session plays one session: use one worker", param_hint="--workers"
        )
    if n > 1 and (why := supported()) is not None:
        raise click.BadParameter(why, param_hint="--workers")
    return n


async def _serve_workers_and_stop(
    config: ServerConfig,
    path: str,
    n: int,
    outer: trio.CancelScope,
    board: Any = None,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
) -> None:
    await serve_with_workers(
        config, [path], n, task_status=task_status, handle_signals=True, live=board
    )
    outer.cancel()


async def _serve_and_stop(
    config: ServerConfig,
    registry: Registry,
    outer: trio.CancelScope,
    board: Any = None,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
) -> None:
    svc = await serve(config, registry, task_status=task_status, handle_signals=True, live=board)
    _last_status[0] = svc.last_status
    outer.cancel()
