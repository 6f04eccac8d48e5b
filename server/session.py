"""One client session, as rddlsim's server plays it, on one trio stream.

The protocol state machine (`ippc.protocol.ServerConnection`) decides what
may be sent and received; this module decides what to send: it looks up the
instance, steps the simulator, keeps the session clock, records every step
in the result store before the next message goes out, and ends the session
(only this one) with a log line when something goes wrong.

rddlsim's rules kept here: session k is seeded with seed + k - 1 and its
generator is not reseeded between rounds; the state is reset at every
round-init; turn 1 reports reward 0.0 and turn k the reward of transition
k - 1; the budget is checked after each transition only, and on expiry the
round ends and session-end follows; illegal actions end the round and keep
the session; under monitor-execution a round-request without
`execute-policy yes` plays an uncounted practice round.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from dataclasses import dataclass, field
from typing import Any

import trio

from ..protocol import (
    MAX_MESSAGE_SIZE,
    Actions,
    ConnectionClosed,
    MessageReader,
    ProtocolError,
    ResourceNotification,
    ResourceRequest,
    RoundEnd,
    RoundInit,
    RoundRequest,
    ServerConnection,
    SessionEnd,
    SessionInit,
    SessionRequest,
    encode,
)
from ..protocol import NEED_DATA as _NEED_DATA
from .config import ServerConfig
from .environment import Environment, Environments, Episode, SessionDropped, StepFailed
from .limits import BufferBudget, Notices
from .registry import UnknownInstance

log = logging.getLogger(__name__)


@dataclass
class Services:
    """What every session shares: settings, instances, result sinks."""

    config: ServerConfig
    registry: Environments  # a Registry, or rddl-dispatch's one environment
    store: Any = None  # server.store.ResultStore or None
    rddlsim_log: Any = None  # server.records.RddlsimLog or None
    transcripts: Any = None  # callable(session_id, meta) -> TranscriptWriter, or None
    next_id: int = 0
    last_status: str | None = None  # of the last session that ended
    open_sessions: dict[int, Any] = field(default_factory=dict)
    # In a worker process of `rddl-server --workers N`: a one-item view of the
    # number of sessions open in the whole server (written by the main
    # process); None in a server of one process.
    server_open: Any = None
    # bytes of unfinished messages beyond each connection's allowance, shared
    # by this process's sessions (None: made from the config)
    budget: BufferBudget | None = None
    # warnings about peers, counted once repeated (see server.limits.Notices)
    notices: Notices = field(default_factory=lambda: Notices(log))

    def __post_init__(self) -> None:
        if self.budget is None:
            self.budget = BufferBudget(self.config.max_buffered)

    def new_session_id(self) -> int:
        # rddlsim counts every accepted connection, failed ones included.
        self.next_id += 1
        return self.next_id


# Messages a session may take from its buffer without waiting before it yields.
_YIELD_EVERY = 32


class _Channel:
    """A stream, its protocol state machine, and the transcript."""

    def __init__(self, stream: trio.abc.Stream, services: Services, session_id: int, t0: float):
        self.stream = stream
        self.conn = ServerConnection(max_message_size=services.config.max_message_size)
        cfg = services.config
        self.idle_timeout = cfg.idle_timeout
        self.message_timeout = cfg.message_timeout or None
        # until the session-request is in (cleared by the session)
        self.request_timeout = cfg.request_timeout
        self.request_deadline: float | None = (
            time.monotonic() + cfg.request_timeout if cfg.request_timeout > 0 else None
        )
        self._msg_start: float | None = None  # when the unfinished message's first byte came
        assert services.budget is not None
        self._budget = services.budget
        self._charged = 0  # bytes of the shared budget this connection holds
        self.session_id = session_id
        self.t0 = t0
        self.transcript: Any = None
        # records kept until the transcript exists; None = no transcripts
        self._early: list[tuple[str, tuple[Any, ...], dict[str, Any]]] | None = (
            [] if services.transcripts is not None else None
        )
        # A second reader over the same inbound bytes finds the message
        # boundaries for the transcript (the state machine keeps its own).
        self._frames = MessageReader("nul", max_size=services.config.max_message_size + 1)
        self.last_message: bytes | None = None
        # A TCP stream is read and written through a plain non-blocking socket
        # on a dup of its descriptor, waiting with trio only when the kernel
        # says "would block": a turn costs one scheduler pass (the wait for
        # the client's answer) instead of trio's several per send and receive.
        # Any other stream goes through its own methods.
        self._raw: socket.socket | None = None
        self._fd = -1
        self._unwaited = 0  # messages handed out since the last wait in the event loop
        self._busy_poll = services.config.busy_poll_us * 1e-6  # seconds
        self._sessions = services.open_sessions
        self._server_open = services.server_open
        if isinstance(stream, trio.SocketStream):
            try:
                self._fd = stream.socket.fileno()
                self._raw = socket.socket(fileno=os.dup(self._fd))
                self._raw.setblocking(False)
            except OSError:
                self._raw = None

    def _t(self) -> float:
        return round(time.monotonic() - self.t0, 4)

    def start_transcript(self, transcript: Any) -> None:
        """From now on record to `transcript`, starting with what came
        before it existed (the session-request)."""
        self.transcript = transcript
        for kind, args, kwargs in self._early or ():
            getattr(transcript, kind)(*args, **kwargs)
        self._early = []

    def _write(self, kind: str, *args: Any, **kwargs: Any) -> None:
        if self.transcript is not None:
            getattr(self.transcript, kind)(*args, **kwargs)
        elif self._early is not None and len(self._early) < 16:
            self._early.append((kind, args, kwargs))

    def _record_inbound(self, data: bytes | bytearray) -> None:
        if self._early is None:
            return
        try:
            if data:
                self._frames.feed(data)
            else:
                self._frames.feed_eof()
            while (frame := self._frames.next_message()) is not None:
                self._write("message", "c2s", frame + b"\0", conn=self.session_id, t=self._t())
        except ProtocolError:
            self._write("note", "inbound bytes that are not a message (see the log)")
        if not data:
            self._write("eof", "c2s", conn=self.session_id, t=self._t())

    async def receive(self) -> Any:
        """The next message from the client (never NEED_DATA)."""
        while True:
            event = self.conn.next_event()
            if event is not _NEED_DATA:
                self._msg_start = None
                self._unwaited += 1
                if self._unwaited >= _YIELD_EVERY:
                    # messages a client wrote ahead are all buffered, or the busy
                    # poll found them: neither the plain-socket sends nor the poll
                    # yield, so yield here now and then (fairness, new connections
                    # are accepted, and a shutdown's cancellation gets in)
                    self._unwaited = 0
                    await trio.lowlevel.checkpoint()
                return event
            deadline = self._deadline()
            try:
                polled = self._poll_briefly()
                if polled is not None:
                    # no wait, no yield: counted with the buffered messages above
                    data: bytes | bytearray = polled
                elif deadline is not None or self.idle_timeout is not None:
                    self._unwaited = 0
                    with trio.move_on_after(self._wake_at(deadline) - time.monotonic()) as waited:
                        data = await self._receive_some()
                    if waited.cancelled_caught:
                        raise self._overdue()
                else:
                    self._unwaited = 0
                    data = await self._receive_some()
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as err:
                raise SessionDropped(f"connection lost: {err}") from None
            self._record_inbound(data)
            self.conn.receive_data(data)

    def _deadline(self) -> float | None:
        """When the client must have finished what it is sending (the
        session-request, an unfinished message), or None; raises when that
        is past. Charges the shared buffer budget for an unfinished message."""
        deadline = self.request_deadline
        pending = self.conn.buffered
        if pending:
            now = time.monotonic()
            if self._msg_start is None:
                self._msg_start = now  # its first bytes came with the feed just made
            if self.message_timeout is not None:
                end = self._msg_start + self.message_timeout
                deadline = end if deadline is None else min(deadline, end)
            if pending > self._budget.allowance or self._charged:
                held = self._budget.charge(self._charged, pending)
                if held is None:
                    raise SessionDropped(
                        f"buffer budget exhausted: {pending:,} bytes of an unfinished message"
                        f" would take the server's unfinished messages past"
                        f" {self._budget.limit:,} bytes (--max-buffered)"
                    )
                self._charged = held
        elif self._charged:
            self._budget.release(self._charged)
            self._charged = 0
        if deadline is not None and time.monotonic() >= deadline:
            raise self._overdue()
        return deadline

    def _wake_at(self, deadline: float | None) -> float:
        if self.idle_timeout is None:
            assert deadline is not None
            return deadline
        idle = time.monotonic() + self.idle_timeout
        return idle if deadline is None else min(idle, deadline)

    def _overdue(self) -> SessionDropped:
        """The error for the deadline that passed."""
        now = time.monotonic()
        if self.request_deadline is not None and now >= self.request_deadline:
            return SessionDropped(
                f"request deadline: no session-request within {self.request_timeout:g} s"
                " of connecting (--request-timeout)"
            )
        if self._msg_start is not None and self.message_timeout is not None:
            if now >= self._msg_start + self.message_timeout:
                return SessionDropped(
                    f"message deadline: unfinished {self.message_timeout:g} s after its first byte"
                    f" ({self.conn.buffered:,} bytes so far; --message-timeout)"
                )
        return SessionDropped(f"client silent for {self.idle_timeout:g} s (--idle-timeout)")

    def release_budget(self) -> None:
        """Give back the bytes of the shared budget this connection holds."""
        if self._charged:
            self._budget.release(self._charged)
            self._charged = 0

    def _poll_briefly(self) -> bytes | None:
        """What the client sends within the busy-poll window
        (`ServerConfig.busy_poll_us`), or None.

        Only while this is the server's one open session: a vCPU that goes
        idle in the event loop's wait between a turn and its answer comes
        back with cold caches, and the simulation step after it took about
        three times as long as when the process stayed on the CPU (measured:
        one noop client, +30-45 % turns/s and no more CPU per turn with
        100 us). With other sessions open, their clients are never kept
        waiting behind this poll."""
        raw = self._raw
        if raw is None or self._busy_poll <= 0.0 or len(self._sessions) > 1:
            return None
        if self._server_open is not None and self._server_open[0] > 1:
            return None  # a session in another worker process
        clock = time.perf_counter
        end = clock() + self._busy_poll
        recv = raw.recv
        while True:
            try:
                return recv(65536)
            except (BlockingIOError, InterruptedError):
                if clock() >= end:
                    return None

    async def _receive_some(self) -> bytes | bytearray:
        raw = self._raw
        if raw is None:
            return await self.stream.receive_some(65536)
        while True:
            # waiting first spares a recv that would fail: the client has
            # rarely answered already when we get here
            await trio.lowlevel.wait_readable(self._fd)
            try:
                return raw.recv(65536)
            except (BlockingIOError, InterruptedError):
                continue

    async def _send_all(self, data: bytes) -> None:
        raw = self._raw
        if raw is None:
            await self.stream.send_all(data)
            return
        view = memoryview(data)
        while view:
            try:
                n = raw.send(view)
            except (BlockingIOError, InterruptedError):
                await trio.lowlevel.wait_writable(self._fd)
                continue
            view = view[n:]

    def close_raw(self) -> None:
        """Close the dup of the socket (the stream itself is closed apart) and
        free what is buffered of the client's unfinished message."""
        self.conn.discard_buffered()
        self._frames.discard()
        self.release_budget()
        if self._raw is not None:
            self._raw.close()
            self._raw = None

    async def send(self, msg: Any) -> None:
        await self._emit(self.conn.send(msg), type(msg).__name__)

    async def send_turn(
        self, turn_num: int, time_left: float, reward: float, fluents_xml: str | None
    ) -> None:
        """A turn whose observed fluents are already written (see
        `ServerConnection.send_turn`)."""
        await self._emit(self.conn.send_turn(turn_num, time_left, reward, fluents_xml), "Turn")

    async def _emit(self, data: bytes, what: str) -> None:
        try:
            await self._send_all(data)
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as err:
            raise SessionDropped(f"connection lost while sending {what}: {err}") from None
        if self.transcript is not None or self._early is not None:
            self._write("message", "s2c", data, conn=self.session_id, t=self._t())


def _time_left_ms(start: float, allowed_ms: float) -> int:
    # rddlsim: timeAllowed - (now - start), in whole milliseconds.
    return int(allowed_ms - (time.monotonic() - start) * 1000.0)


@dataclass
class _Round:
    number: int  # round-init's round-num
    counted: bool
    reward: float = 0.0
    turns: int = 0
    immediate: float = 0.0
    status: str = "finished"


class Session:
    """One connection, from session-request to session-end."""

    def __init__(
        self, services: Services, stream: trio.abc.Stream, peer: str, session_id: int | None = None
    ):
        self.services = services
        self.config = services.config
        self.stream = stream
        self.peer = peer
        # (a worker process is given the number the main process counted)
        self.id = services.new_session_id() if session_id is None else session_id
        self.start = time.monotonic()
        self.channel = _Channel(stream, services, self.id, self.start)
        self.client_name = "?"
        self.instance_name = "?"
        self.db_id: int | None = None
        self.round_db_id: int | None = None
        self.rounds_used = 0
        self.total_reward = 0.0
        self.status = "open"
        self.requested = False  # a session-request came
        self._round = _Round(0, counted=False)
        self._episode: Episode | None = None
        self._stop = False  # the environment asked to end the session after this round

    # -- helpers

    def _ms(self) -> int:
        return _time_left_ms(self.start, self.config.time_allowed_ms)

    def _out_of_time(self) -> bool:
        return (
            self.config.enforce_timeout
            and (time.monotonic() - self.start) * 1000.0 > self.config.time_allowed_ms
        )

    def describe(self) -> str:
        return f"session {self.id} ({self.peer}, client {self.client_name!r}, instance {self.instance_name!r})"

    async def _expect(self, *types: type) -> Any:
        """The next message of one of `types`; resource-requests are
        answered on the way, as rddlsim answers them."""
        while True:
            event = await self.channel.receive()
            if isinstance(event, ConnectionClosed):
                raise SessionDropped("the client closed the connection")
            if isinstance(event, ResourceRequest):
                await self.channel.send(ResourceNotification(time_left=float(self._ms())))
                continue
            if isinstance(event, types):
                return event
            raise SessionDropped(
                f"expected {' or '.join(t.__name__ for t in types)}, got {type(event).__name__}"
            )

    # -- the session

    async def run(self) -> None:
        """Play the session; every failure ends this session only."""
        svc = self.services
        svc.open_sessions[self.id] = self
        try:
            await self._play()
            self.status = "finished" if self.status == "open" else self.status
        except SessionDropped as err:
            self._drop(str(err))
        except ProtocolError as err:
            self._drop(f"protocol error: {err}")
        except Exception as err:
            # A bug in an environment (a dispatcher's knowledge base or
            # sensing, a simulator error that is not a SimulationError) ends
            # this session, recorded with its reason, never the server and
            # its other sessions; the traceback goes to the log.
            log.error("%s: internal error", self.describe(), exc_info=True)
            self._drop(f"internal error: {type(err).__name__}: {err}")
        except trio.Cancelled:
            self._end_store("interrupted", "server shut down")
            raise
        finally:
            svc.open_sessions.pop(self.id, None)
            if self._episode is not None:
                self._episode.close()
            if self.channel.transcript is not None:
                self.channel._write("eof", "s2c", conn=self.id, t=self.channel._t())  # we close
                self.channel.transcript.close()
            self.channel.close_raw()
            try:
                await self.stream.aclose()
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                pass

    def _drop(self, why: str) -> None:
        self.status = "dropped"
        notices = self.services.notices
        # the cause is what the reason says before its first colon
        kind = why.partition(":")[0]
        if not self.requested:
            # never a session: no result, no rddlsim record; counted once repeated
            cause = f"connections closed before a session-request: {kind}"
        else:
            cause = f"sessions closed: {kind}"
        notices.note(cause, f"{self.describe()} closed: {why}")
        self._end_store("dropped", why)

    def _end_store(self, status: str, reason: str | None) -> None:
        store = self.services.store
        if store is None or self.db_id is None:
            return
        now = time.time()
        if self.round_db_id is not None:
            store.end_round(
                self.round_db_id,
                reward=self._round.reward,
                turns_used=self._round.turns,
                status=status,
                ended_at=now,
            )
            self.round_db_id = None
        store.end_session(
            self.db_id,
            total_reward=self.total_reward,
            rounds_used=self.rounds_used,
            status=status,
            reason=reason,
            ended_at=now,
        )
        self.db_id = None

    async def _play(self) -> None:
        cfg = self.config
        svc = self.services
        request = await self.channel.receive()
        if isinstance(request, ConnectionClosed):
            raise SessionDropped("the client closed the connection before its session-request")
        if not isinstance(request, SessionRequest):
            raise SessionDropped(f"expected a session-request, got {type(request).__name__}")
        self.channel.request_deadline = None
        self.requested = True
        if svc.rddlsim_log is not None:
            # rddlsim writes it on accepting; here only for a connection that
            # asked for a session, so a flood of empty connections writes nothing
            host, _, _ = self.peer.rpartition(":")
            svc.rddlsim_log.client_info("localhost" if host in ("127.0.0.1", "::1") else host, host)
        self.client_name = request.client_name
        self.instance_name = request.problem_name
        if request.input_language not in (None, "rddl"):
            raise SessionDropped(
                f"input-language {request.input_language!r} is not served (only rddl)"
            )
        try:
            instance = svc.registry.get(request.problem_name)
        except UnknownInstance as err:
            raise SessionDropped(str(err)) from None
        seed = cfg.seed + self.id - 1
        episode = await instance.open(seed)
        self._episode = episode
        if svc.transcripts is not None:
            self.channel.start_transcript(
                svc.transcripts(
                    self.id,
                    {
                        "instance": instance.name,
                        "client": self.client_name,
                        "session_id": self.id,
                        "seed": seed,
                        "no_header": request.no_header,
                        "server": "ippc rddl-server",
                    },
                )
            )
        await self.channel.send(
            SessionInit(
                task=instance.task,
                session_id=self.id,
                num_rounds=cfg.rounds,
                time_allowed=cfg.time_allowed_ms,
            )
        )
        if svc.store is not None:
            self.db_id = svc.store.start_session(
                server_session_id=self.id,
                instance=instance.name,
                client_name=self.client_name,
                seed=seed,
                num_rounds=cfg.rounds,
                time_allowed_ms=cfg.time_allowed_ms,
                peer=self.peer,
                no_header=request.no_header,
                started_at=time.time(),
            )
        log.info("%s started (seed %d)", self.describe(), seed)

        counted = 0
        out_of_time = False
        while counted < cfg.rounds and not out_of_time and not self._stop:
            req = await self._expect(RoundRequest)
            practice = cfg.monitor_execution and req.execute_policy is not True
            number = counted if practice else counted + 1
            rnd = _Round(number, counted=not practice)
            out_of_time = await self._play_round(instance, episode, rnd)
            if not practice:
                counted += 1
                self.total_reward += rnd.reward
            self.rounds_used = counted
        end = SessionEnd(
            instance_name=instance.name,
            total_reward=self.total_reward,
            rounds_used=counted,
            client_name=self.client_name,
            session_id=self.id,
            time_left=self._ms(),
        )
        status = "timeout" if out_of_time else "finished"
        self.status = status
        if svc.store is not None and self.db_id is not None:
            svc.store.end_session(
                self.db_id,
                total_reward=self.total_reward,
                rounds_used=counted,
                status=status,
                reason=None,
                ended_at=time.time(),
            )
            self.db_id = None
        await self.channel.send(end)
        self._log_document(encode(end))
        log.info(
            "%s ended: total reward %s over %d rounds (%s)",
            self.describe(),
            self.total_reward,
            counted,
            status,
        )

    def _log_document(self, doc: bytes) -> None:
        if self.services.rddlsim_log is not None:
            self.services.rddlsim_log.message(doc)

    async def _play_round(self, instance: Environment, episode: Episode, rnd: _Round) -> bool:
        """One round; returns whether the session ran out of time."""
        cfg = self.config
        store = self.services.store
        self._round = rnd
        await self.channel.send(
            RoundInit(
                round_num=rnd.number,
                round_left=cfg.rounds - rnd.number,
                time_left=float(self._ms()),
            )
        )
        if store is not None and self.db_id is not None:
            self.round_db_id = store.start_round(
                self.db_id, round_num=rnd.number, counted=rnd.counted, started_at=time.time()
            )
        episode.start_round()
        channel = self.channel
        discount = instance.model.discount
        horizon = instance.horizon
        cur_discount = 1.0
        out_of_time = False
        turn = episode.turn
        thinking = episode.thinking
        act = episode.act
        while True:
            sent, xml = turn()
            await channel.send_turn(rnd.turns + 1, float(self._ms()), rnd.immediate, xml)
            if store is not None:
                sent_at = time.time()
            # while the client thinks: what the environment can do without its actions
            thinking()
            actions = await self._expect(Actions)
            if store is not None:
                received_at = time.time()
            try:
                outcome = await act(actions)
            except StepFailed as err:
                raise SessionDropped(
                    f"simulation error in round {rnd.number}, turn {rnd.turns + 1}: {err}"
                ) from None
            if outcome.illegal is not None:
                if cfg.individual_session:
                    # rddlsim exits (code 1) here in individual-session mode
                    raise SessionDropped(
                        f"illegal actions in individual-session mode: {outcome.illegal}"
                    )
                log.info(
                    "%s round %d: illegal actions end the round: %s",
                    self.describe(),
                    rnd.number,
                    outcome.illegal,
                )
                rnd.status = "illegal-action"
                break
            reward = outcome.reward
            rnd.immediate = reward
            rnd.reward += cur_discount * reward
            cur_discount *= discount
            rnd.turns += 1
            if store is not None and self.round_db_id is not None:
                store.record_step(
                    self.round_db_id,
                    turn_num=rnd.turns,
                    state=[] if sent is None else sent,
                    actions=[(a.name, tuple(a.args), a.value) for a in actions.actions],
                    reward=reward,
                    turn_sent_at=sent_at,
                    actions_received_at=received_at,
                    outcome=outcome.record,
                    execution_seconds=outcome.execution_seconds,
                )
            if self._out_of_time():
                out_of_time = True
                rnd.status = "timeout"
                break
            if outcome.stop:
                self._stop = True
            if horizon is not None and rnd.turns >= horizon:
                break
            if outcome.end is not None:
                rnd.status = outcome.end
                break
        end = RoundEnd(
            instance_name=instance.name,
            client_name=self.client_name,
            round_num=rnd.number - 1,
            round_reward=rnd.reward,
            turns_used=rnd.turns,
            time_left=self._ms(),
            immediate_reward=rnd.immediate,
        )
        # recorded before the client hears of it, like every step
        if store is not None and self.round_db_id is not None:
            store.end_round(
                self.round_db_id,
                reward=rnd.reward,
                turns_used=rnd.turns,
                status=rnd.status,
                ended_at=time.time(),
            )
            self.round_db_id = None
        await self.channel.send(end)
        self._log_document(encode(end))
        return out_of_time


__all__ = ["Services", "Session", "SessionDropped", "MAX_MESSAGE_SIZE"]
