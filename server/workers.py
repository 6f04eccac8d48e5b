"""`rddl-server --workers N`: one listener, sessions played in N processes.

A server of one process plays every session on one core. With workers, the
main process only listens: it accepts each connection, gives it the next
session number (the k-th accepted connection is session k with seed
seed + k - 1, exactly as in one process and in rddlsim), and hands the socket
to the worker process with the fewest open sessions, over a Unix socket
(SCM_RIGHTS). Each worker runs the same trio session code as a server of one
process, on its own copy of the instances.

Main process <-> worker messages (one SOCK_SEQPACKET record each):

    main -> worker   b"S" + session number (8 bytes, little endian), with the
                     connection's descriptor attached
    main -> worker   b"X" + session number      close that connection if it has no
                                                session yet (the cap is reached and
                                                it is the oldest idle one)
    worker -> main   b"R"                       ready (instances loaded)
                     b"E" + session number      that session ended
                     b"K" + session number      (after an X) it has its session: kept

What the workers share: the listening port's rddlsim log file (every
document is one O_APPEND write, so documents never interleave), the SQLite
database (WAL; each worker's sessions carry the worker's own owner token),
the transcripts' folder and file-name stamp, and one 8-byte counter the main
process keeps of the sessions open in the whole server (a worker busy-polls
its lone session's socket only while that count is 1).

A worker that dies is logged with its exit status; the main process marks
its open sessions interrupted in the database and starts another in its
place (a worker that dies before it is ready stops the server: it could not
load the instances; one that dies 5 times within a minute is not restarted,
and when that leaves no worker the server stops). A worker that does not read
its hand-overs (it hangs) is passed over once its control socket is full, so
the listener never waits on it. SIGINT/SIGTERM to the main process are passed on to the
workers, which record their open sessions as interrupted, as one process
does. A worker whose main process vanishes stops taking sessions and exits
when its open sessions end.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import mmap
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import trio

from .config import ServerConfig
from .limits import (
    EMPTY_CLOSE,
    LISTEN_BACKLOG,
    AcceptPacer,
    BufferBudget,
    Notices,
    closed_already,
    peer_host,
)
from .listener import make_room
from .registry import Registry

log = logging.getLogger(__name__)

_NUM = struct.Struct("<q")
_READY = b"R"
_START = b"S"
_END = b"E"
_CLOSE_IDLE = b"X"  # main -> worker: close that session's connection if it has no session
_KEPT = b"K"  # worker -> main: it has its session (not closed)
# a worker that has not reported ready after this long is taken for dead
READY_TIMEOUT = 300.0
# ... and a restarted one, after this long (the first start loaded the instances)
RESTART_READY_TIMEOUT = 120.0
# seconds a worker gets to record its sessions after SIGTERM before SIGKILL
STOP_GRACE = 10.0
# a worker that dies this many times within RESPAWN_WINDOW seconds is not restarted
MAX_RAPID_DEATHS = 5
RESPAWN_WINDOW = 60.0
# seconds the listener waits for a worker to take a connection when every
# worker's queue of hand-overs is full (overload) before it closes it
HANDOVER_WAIT = 10.0


class WorkerError(RuntimeError):
    """The worker processes could not be started."""


def supported() -> str | None:
    """Why worker processes cannot run here, or None."""
    if not hasattr(socket, "send_fds") or not hasattr(socket, "SOCK_SEQPACKET"):
        return "worker processes need Unix sockets that pass descriptors (Linux)"
    try:
        a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    except OSError as err:
        return f"worker processes need AF_UNIX SOCK_SEQPACKET sockets ({err})"
    a.close()
    b.close()
    return None


def default_workers() -> int:
    """`--workers auto`: one per core the process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


# ------------------------------------------------------------- the main process


class _Worker:
    """The main process's view of one worker."""

    def __init__(self, index: int, owner: str):
        self.index = index
        self.owner = owner
        self.proc: subprocess.Popen[bytes] | None = None
        self.ctrl: socket.socket | None = None
        self.open: set[int] = set()
        self.ready = trio.Event()
        self.alive = False
        self.deaths: list[float] = []
        self.given_up = False  # died too often: not restarted
        # with the web view: the socket its session records come back on
        self.events: socket.socket | None = None

    def __repr__(self) -> str:
        pid = self.proc.pid if self.proc is not None else None
        return f"worker {self.index} (pid {pid})"


class WorkerPool:
    """The worker processes of one server and the count of open sessions."""

    def __init__(self, config: ServerConfig, paths: list[str], n: int, port: int, live: Any = None):
        self.config = config
        # the web view's board (server.web.SessionBoard), or None
        self.live = live
        self.paths = paths
        self.port = port
        self.stamp = time.strftime("%Y%m%d-%H%M%S")
        base = f"{socket.gethostname()}:{os.getpid()}:{os.urandom(6).hex()}"
        self.workers = [_Worker(i, f"{base}:w{i}") for i in range(n)]
        self.next_id = 0
        self.stopping = False
        from .app import connection_table

        self.table = connection_table(config)
        self.notices = Notices(log)
        if live is not None:
            live.watch_notices(self.notices)  # (the view counts refused connections)
        # the shared count of open sessions: an unlinked temporary file, mapped
        self._count_file = tempfile.TemporaryFile(prefix="ippc-sessions-")
        self._count_file.write(b"\0" * _NUM.size)
        self._count_file.flush()
        self._map = mmap.mmap(self._count_file.fileno(), _NUM.size)

    # -- the shared count

    def _publish(self) -> None:
        _NUM.pack_into(self._map, 0, sum(len(w.open) for w in self.workers))

    @property
    def open_sessions(self) -> int:
        return int(_NUM.unpack_from(self._map, 0)[0])

    # -- processes

    def _spawn(self, w: _Worker) -> None:
        parent, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        fds = [child.fileno(), self._count_file.fileno()]
        events_child = None
        if self.live is not None:
            if w.events is not None:
                w.events.close()
            w.events, events_child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
            fds.append(events_child.fileno())
        spec = {
            "index": w.index,
            "owner": w.owner,
            "ctrl": child.fileno(),
            "count": self._count_file.fileno(),
            "port": self.port,
            "stamp": self.stamp,
            "paths": self.paths,
            "config": _config_to_json(self.config),
            "workers": len(self.workers),
            "log_level": logging.getLogger().getEffectiveLevel(),
            "live": events_child.fileno() if events_child is not None else None,
        }
        try:
            w.proc = subprocess.Popen(
                [
                    sys.executable,
                    "-c",
                    "from ippc.server.workers import worker_main; worker_main()",
                    json.dumps(spec),
                ],
                pass_fds=tuple(fds),
                stdin=subprocess.DEVNULL,
            )
        except OSError as err:
            parent.close()
            raise WorkerError(f"cannot start worker {w.index}: {err}") from None
        finally:
            child.close()
            if events_child is not None:
                events_child.close()
        parent.setblocking(False)
        w.ctrl = parent
        w.ready = trio.Event()
        w.alive = True

    async def run(self, *, task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> None:
        """Start the workers, report when all are ready, then watch them
        (restarting the ones that die) until cancelled; on the way out, stop
        them all."""
        try:
            async with trio.open_nursery() as nursery:
                for w in self.workers:
                    self._spawn(w)
                    nursery.start_soon(self._watch, w)
                with trio.move_on_after(READY_TIMEOUT) as scope:
                    for w in self.workers:
                        await w.ready.wait()
                if scope.cancelled_caught:
                    raise WorkerError(f"the workers were not ready after {READY_TIMEOUT:g} s")
                task_status.started()
        finally:
            with trio.CancelScope(shield=True):
                await self._stop_all()

    async def _watch(self, w: _Worker) -> None:
        """Read a worker's messages; when it dies, close its sessions and
        start another."""
        while True:
            async with trio.open_nursery() as watchdog:
                if w.deaths:  # a restart: nobody else waits for it to be ready
                    watchdog.start_soon(self._kill_unless_ready, w)
                if w.events is not None and self.live is not None:
                    from .web import receive_records

                    watchdog.start_soon(receive_records, w.events, self.live)
                await self._read(w)
                watchdog.cancel_scope.cancel()
            code = await self._reap(w)
            lost = sorted(w.open)
            w.open.clear()
            for sid in lost:
                self.table.remove(sid)
            self._publish()
            if self.stopping:
                return
            if not w.ready.is_set() and not w.deaths:
                raise WorkerError(
                    f"worker {w.index} exited ({_status(code)}) before it was ready; see its log above"
                )
            # (exit code 0: it was stopped by a signal of its own, not by ours)
            (log.warning if code == 0 else log.error)(
                "%r exited (%s) with %d open session(s) %s", w, _status(code), len(lost), lost
            )
            self._interrupt(w, f"worker process died ({_status(code)})")
            if self.live is not None and lost:
                self.live.interrupt_running(
                    f"worker process died ({_status(code)})", time.time(), lost
                )
            if not await self._restart(w):
                return

    async def _restart(self, w: _Worker) -> bool:
        """Start a dead worker again (after a pause that grows with its
        recent deaths); False when it died too often. A start that fails
        counts as a death. When no worker is left, the server stops: it
        could only accept connections and close them."""
        while True:
            now = time.monotonic()
            w.deaths = [t for t in w.deaths if now - t < RESPAWN_WINDOW] + [now]
            if len(w.deaths) >= MAX_RAPID_DEATHS:
                log.error(
                    "worker %d died %d times in %g s: not restarted",
                    w.index,
                    len(w.deaths),
                    RESPAWN_WINDOW,
                )
                w.given_up = True
                if all(x.given_up for x in self.workers):
                    raise WorkerError("every worker process died repeatedly; the server stops")
                return False
            await trio.sleep(0.2 * len(w.deaths))
            try:
                self._spawn(w)
            except WorkerError as err:
                log.error("%s", err)
                continue
            log.warning("worker %d restarted (pid %d)", w.index, w.proc.pid if w.proc else -1)
            return True

    async def _kill_unless_ready(self, w: _Worker) -> None:
        """A restarted worker that is not ready in time is killed (its
        death counts like any other); until then it is given no sessions."""
        with trio.move_on_after(RESTART_READY_TIMEOUT):
            await w.ready.wait()
            return
        proc = w.proc
        if proc is not None and proc.poll() is None:
            log.error("%r was not ready %g s after its restart: killed", w, RESTART_READY_TIMEOUT)
            proc.kill()

    async def _read(self, w: _Worker) -> None:
        ctrl = w.ctrl
        assert ctrl is not None
        while True:
            try:
                msg = ctrl.recv(64)
            except (BlockingIOError, InterruptedError):
                await trio.lowlevel.wait_readable(ctrl)
                continue
            except OSError:
                msg = b""
            if not msg:
                w.alive = False
                w.ctrl = None
                trio.lowlevel.notify_closing(ctrl)  # a hand-over waiting on it gives up
                ctrl.close()
                return
            kind = msg[:1]
            if kind == _READY:
                w.ready.set()
            elif kind == _END and len(msg) == 1 + _NUM.size:
                sid = _NUM.unpack_from(msg, 1)[0]
                w.open.discard(sid)
                self.table.remove(sid)
                self._publish()
            elif kind == _KEPT and len(msg) == 1 + _NUM.size:
                self.table.in_session(_NUM.unpack_from(msg, 1)[0])
            else:
                log.error("%r sent an unknown message %r", w, msg[:20])

    async def _reap(self, w: _Worker) -> int | None:
        """The exit status of a worker whose control socket closed."""
        proc = w.proc
        if proc is None:
            return None
        with trio.move_on_after(STOP_GRACE):
            while proc.poll() is None:
                await trio.sleep(0.05)
        if proc.poll() is None:
            proc.kill()
            with trio.move_on_after(2.0):
                while proc.poll() is None:
                    await trio.sleep(0.05)
        return proc.poll()

    def _interrupt(self, w: _Worker, reason: str) -> None:
        if self.config.db is None:
            return
        from .store import ResultStore

        try:
            with ResultStore(self.config.db, owner=w.owner) as store:
                store.interrupt_open(reason, time.time())
        except Exception as err:  # the database is the workers' too: never fatal here
            log.error("could not mark worker %d's sessions interrupted: %s", w.index, err)

    async def _stop_all(self) -> None:
        self.stopping = True
        live = [w for w in self.workers if w.proc is not None and w.proc.poll() is None]
        for w in live:
            try:
                w.proc.send_signal(signal.SIGTERM)  # type: ignore[union-attr]
            except OSError:
                pass
        deadline = time.monotonic() + STOP_GRACE
        for w in live:
            proc = w.proc
            assert proc is not None
            while proc.poll() is None and time.monotonic() < deadline:
                await trio.sleep(0.05)
            if proc.poll() is None:
                log.error("%r did not stop within %g s: killed", w, STOP_GRACE)
                proc.kill()
                proc.wait()
                self._interrupt(w, "server stopped (worker killed)")
        for w in self.workers:
            if w.ctrl is not None:
                trio.lowlevel.notify_closing(w.ctrl)
                w.ctrl.close()
                w.ctrl = None
            if w.events is not None:
                trio.lowlevel.notify_closing(w.events)
                w.events.close()
                w.events = None
        self._map.close()
        self._count_file.close()

    # -- handing out connections

    async def hand_over(self, sock: trio.socket.SocketType) -> None:
        """Number an accepted connection and pass it to the least busy
        worker (the connection is closed here either way). A connection the
        caps or `--allow` refuse is closed at once, without a number. When
        every worker's queue of hand-overs is full (overload) the listener
        waits for one to take it (up to HANDOVER_WAIT), accepting nothing
        meanwhile: new connections wait in the kernel's backlog."""
        try:
            host = peer_host(sock)
            refused = self.table.refusal(host)
            if refused is not None and self.table.full():
                if make_room(self.table, self.notices, self._close_idle, host):
                    refused = self.table.refusal(host)
            if refused is not None:
                self.notices.note(*refused)
                return
            self.next_id += 1
            sid = self.next_id
            if closed_already(sock):  # (numbered all the same, as rddlsim numbers it)
                self.notices.note(
                    EMPTY_CLOSE,
                    f"session {sid} ({host}): the client closed the connection before its"
                    " session-request",
                )
                return
            deadline = trio.current_time() + HANDOVER_WAIT
            while True:
                ready = sorted(
                    (w for w in self.workers if w.alive and w.ready.is_set()),
                    key=lambda w: (len(w.open), w.index),
                )
                for w in ready:
                    if await self._send(w, sid, sock.fileno()):
                        w.open.add(sid)
                        self.table.add(sid, host)
                        self._publish()
                        return
                if trio.current_time() >= deadline:
                    break
                await trio.sleep(0.005)
            if ready:
                self.notices.note(
                    "connections closed: overload, no worker took them in time",
                    f"session {sid}: overload: no worker took the connection within"
                    f" {HANDOVER_WAIT:g} s (every worker has a full queue of hand-overs);"
                    " connection closed",
                    logging.ERROR,
                )
            else:
                self.notices.note(
                    "connections closed: no worker process ready",
                    f"session {sid}: no worker process is ready (every one is"
                    " restarting or gone); connection closed",
                    logging.ERROR,
                )
        finally:
            sock.close()

    def _close_idle(self, sid: int) -> bool | None:
        """Ask the worker that plays `sid` to close its connection if it has
        no session yet (it answers with the session's end, or `_KEPT`): None;
        False when no live worker can be asked (the next is tried)."""
        for w in self.workers:
            if sid in w.open and w.ctrl is not None:
                try:
                    w.ctrl.send(_CLOSE_IDLE + _NUM.pack(sid))
                    return None
                except OSError:
                    return False
        return False

    async def _send(self, w: _Worker, sid: int, fd: int) -> bool:
        """Pass the connection to `w`; False when it cannot take it now: its
        queue of hand-overs is full (it is busy, or hangs: one stuck worker
        never stops the accept loop while another can take the connection)."""
        ctrl = w.ctrl
        if ctrl is None:
            return False
        try:
            socket.send_fds(ctrl, [_START + _NUM.pack(sid)], [fd])  # (EINTR is retried by Python)
            return True
        except BlockingIOError:
            pass
        except OSError as err:
            self.notices.note(
                f"hand-over failures: {err.strerror or err}",
                f"{w!r} cannot take session {sid}: {err}",
            )
        return False


async def serve_with_workers(
    config: ServerConfig,
    paths: list[str],
    n: int,
    *,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
    handle_signals: bool = False,
    pools: list[WorkerPool] | None = None,
    live: Any = None,
) -> None:
    """Listen on the configured address and play every session in one of `n`
    worker processes. Reports the bound port once every worker is ready;
    runs until cancelled (or a signal, with `handle_signals`). The pool is
    appended to `pools` if given (tests look into it). With `live` (a
    `server.web.SessionBoard`), the workers send their sessions' records
    back to it (the web view)."""
    listeners = await trio.open_tcp_listeners(config.port, host=config.host, backlog=LISTEN_BACKLOG)
    port = listeners[0].socket.getsockname()[1]
    pool = WorkerPool(config, paths, n, port, live)
    if pools is not None:
        pools.append(pool)
    try:
        async with trio.open_nursery() as nursery:
            if handle_signals:
                from .app import _watch_signals

                nursery.start_soon(_watch_signals, nursery.cancel_scope)
            await nursery.start(pool.run)
            nursery.start_soon(pool.notices.run)
            for listener in listeners:
                nursery.start_soon(_accept, listener, pool)
            task_status.started(port)
    finally:
        for listener in listeners:
            listener.socket.close()


async def _accept(listener: trio.SocketListener, pool: WorkerPool) -> None:
    sock = listener.socket
    pacer = AcceptPacer(pool.config.accept_rate)
    while True:
        await pacer.pace()
        try:
            conn, _ = await sock.accept()
        except OSError as err:  # e.g. too many open files: wait, go on
            pool.notices.note(
                f"accept failures: {err.strerror or err}", f"accept failed: {err}", logging.ERROR
            )
            await trio.sleep(0.1)
            continue
        await pool.hand_over(conn)


# ------------------------------------------------------------- a worker process


def worker_main() -> None:
    """The entry point of a worker process (started by `WorkerPool`)."""
    spec = json.loads(sys.argv[1])
    logging.basicConfig(
        level=spec["log_level"],
        format=f"%(asctime)s %(levelname)s %(name)s[w{spec['index']}]: %(message)s",
        stream=sys.stderr,
    )
    ctrl = socket.socket(fileno=spec["ctrl"])
    count = mmap.mmap(spec["count"], _NUM.size, access=mmap.ACCESS_READ)
    os.close(spec["count"])
    try:
        registry = Registry.load(*spec["paths"])
    except Exception as err:
        log.error("cannot load the instances: %s", err)
        sys.exit(2)
    config = _config_from_json(spec["config"])
    try:
        trio.run(_worker, config, registry, ctrl, count, spec)
    except KeyboardInterrupt:
        pass


async def _worker(
    config: ServerConfig,
    registry: Registry,
    ctrl: socket.socket,
    count: mmap.mmap,
    spec: dict[str, Any],
) -> None:
    from .app import close_services, open_services, play_connection

    board = events = None
    if spec.get("live") is not None:
        from .web import SessionBoard

        board = SessionBoard()
        events = socket.socket(fileno=spec["live"])
    svc = open_services(
        config, registry, spec["port"], owner=spec["owner"], stamp=spec["stamp"], live=board
    )
    svc.server_open = memoryview(count).cast("q")
    # the server's budget for unfinished messages, shared out evenly
    budget = svc.budget = BufferBudget(
        max(1, config.max_buffered // max(1, spec.get("workers", 1)))
    )
    ctrl.setblocking(False)
    # each session (once it plays), to close an idle one when the main
    # process asks (`_CLOSE_IDLE`)
    playing: dict[int, Any] = {}

    async def play(sid: int, sock: socket.socket) -> None:
        try:
            stream = trio.SocketStream(trio.socket.from_stdlib_socket(sock))
            await play_connection(svc, stream, sid, started=lambda s: playing.__setitem__(sid, s))
        except Exception:  # a fault of ours: this session only, the others go on
            log.exception("session %d ended by an internal error", sid)
        finally:
            playing.pop(sid, None)
            _tell(ctrl, _END + _NUM.pack(sid))

    def close_idle(sid: int) -> None:
        session = playing.get(sid)
        if session is None:
            return  # ended already (its end is on the way), or not started
        if session.requested:
            _tell(ctrl, _KEPT + _NUM.pack(sid))
        else:
            # (the session reads a duplicate of the descriptor: shut the
            # connection itself down, and its wait for a request ends)
            try:
                session.stream.socket.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    async def take_sessions(sessions: trio.Nursery) -> None:
        _tell(ctrl, _READY)  # (a main process gone already: the loop below ends at once)
        while True:
            try:
                msg, fds, _, _ = socket.recv_fds(ctrl, 64, 4)
            except (BlockingIOError, InterruptedError):
                await trio.lowlevel.wait_readable(ctrl)
                continue
            except OSError:
                msg, fds = b"", []
            socks = [socket.socket(fileno=fd) for fd in fds]
            if not msg:
                log.warning(
                    "the main process is gone: no new sessions; exiting when the open ones end"
                )
                return
            if msg[:1] == _CLOSE_IDLE and len(msg) == 1 + _NUM.size and not socks:
                close_idle(_NUM.unpack_from(msg, 1)[0])
                continue
            if msg[:1] != _START or len(msg) != 1 + _NUM.size or len(socks) != 1:
                for s in socks:
                    s.close()
                if msg[:1] == _START and len(msg) == 1 + _NUM.size:
                    # a hand-over whose descriptor did not arrive (the table is
                    # full): the client sees its connection close; say it ended
                    sid = _NUM.unpack_from(msg, 1)[0]
                    svc.notices.note(
                        "connections lost: their descriptor did not arrive (open-file limit?)",
                        f"session {sid}: its connection did not arrive"
                        " (the worker's open-file limit?); dropped",
                        logging.ERROR,
                    )
                    _tell(ctrl, _END + _NUM.pack(sid))
                else:
                    log.error("unexpected message from the main process %r", msg[:20])
                continue
            sessions.start_soon(play, _NUM.unpack_from(msg, 1)[0], socks[0])
            # one new connection per pass of the scheduler: a flood of them
            # waits in this socket (then in the listener's backlog) while the
            # sessions in progress take their turns
            await trio.lowlevel.checkpoint()

    async def on_signal(signals: Any, scope: trio.CancelScope) -> None:
        # every signal until the end: a second one (the terminal's SIGINT and
        # the main process's SIGTERM both come) must not cut the cleanup short
        async for signum in signals:
            log.info("signal %s: stopping", signal.Signals(signum).name)
            scope.cancel()

    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
        try:
            async with trio.open_nursery() as top:
                top.start_soon(on_signal, signals, top.cancel_scope)
                top.start_soon(svc.notices.run)
                top.start_soon(budget.run)
                if board is not None and events is not None:
                    from .web import forward_records

                    top.start_soon(forward_records, events, board)
                async with trio.open_nursery() as sessions:
                    sessions.start_soon(take_sessions, sessions)
                top.cancel_scope.cancel()  # no more sessions to come or to end
        finally:
            svc.server_open = None
            close_services(svc, "server stopped")
            if board is not None and events is not None:
                from .web import send_records

                send_records(events, board)  # the sessions just closed
                events.close()
            ctrl.close()


def _tell(ctrl: socket.socket, msg: bytes) -> None:
    """A notice to the main process; lost if it is gone or not reading
    (it then only miscounts open sessions)."""
    try:
        ctrl.send(msg)
    except OSError:
        pass


# ------------------------------------------------------------- helpers


def _config_to_json(config: ServerConfig) -> dict[str, Any]:
    return {
        k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(config).items()
    }


def _config_from_json(data: dict[str, Any]) -> ServerConfig:
    paths = {"log_dir", "db", "transcripts"}
    fields: dict[str, Any] = {
        k: (Path(v) if k in paths and v is not None else v) for k, v in data.items()
    }
    fields["allow"] = tuple(fields.get("allow", ()))
    return ServerConfig(**fields)


def _status(code: int | None) -> str:
    if code is None:
        return "status unknown"
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


__all__ = [
    "WorkerError",
    "WorkerPool",
    "default_workers",
    "serve_with_workers",
    "supported",
    "worker_main",
]
