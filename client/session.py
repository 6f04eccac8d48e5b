"""Play one IPPC session against any server with a `Planner`.

The protocol state machine (`ippc.protocol.ClientConnection`) checks the
order of messages; this module connects, decodes the task into a model,
keeps its own clock of the session budget, hands the planner a deadline
for every turn and collects the results. A server that closes, stalls
(`timeout`) or sends garbage raises `ClientError` with what happened.
"""

from __future__ import annotations

import logging
import os
import statistics
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import trio

from ..planners.base import Observation, Planner, SessionInfo
from ..protocol import (
    NEED_DATA,
    Actions,
    ClientConnection,
    ConnectionClosed,
    Fluent,
    ProtocolError,
    RoundEnd,
    RoundInit,
    RoundRequest,
    SessionEnd,
    SessionInit,
    SessionRequest,
    Turn,
)
from ..protocol.values import parse_value
from ..rddl import RDDLError, load_model
from ..rddl.model import Model, Value
from ..rddl.simulator import Simulator
from ..rddl.wire import WireCodec, WireError, value_kind

log = logging.getLogger(__name__)


class ClientError(Exception):
    """The session could not be played to its end; the message says where."""


@dataclass(frozen=True)
class ClientConfig:
    host: str = "127.0.0.1"
    port: int = 2323
    instance: str = ""
    client_name: str = "ippc"
    no_header: bool = False
    rounds_training: int = 0
    rddl: Sequence[Path] = ()
    seed: int | None = None
    timeout: float | None = 600.0  # seconds to wait for any server message


@dataclass
class RoundResult:
    round: int
    reward: float
    turns: int
    seconds: float
    training: bool = False
    ended_early: str | None = None  # why the server ended it before the horizon


@dataclass
class SessionResult:
    instance: str
    planner: str
    client_name: str
    total_reward: float
    mean_round_reward: float
    rounds: list[RoundResult] = field(default_factory=list)
    session_id: int | None = None
    seconds: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return d


def model_from_task(task: bytes, instance: str) -> Model:
    """The model of `instance` from session-init's task (the domain and
    instance files as rddlsim sends them)."""
    with tempfile.TemporaryDirectory(prefix="ippc-task-") as tmp:
        path = Path(tmp) / "task.rddl"
        path.write_bytes(task)
        try:
            return load_model(path, instance=instance)
        except RDDLError as err:
            raise ClientError(f"the server's task for {instance!r} does not load: {err}") from None


class _Link:
    """Stream + ClientConnection with a stall timeout."""

    def __init__(self, stream: trio.abc.Stream, conn: ClientConnection, timeout: float | None):
        self.stream = stream
        self.conn = conn
        self.timeout = timeout
        self.pending = 0  # bytes received since the last complete message
        self.conn_no_header = bool(getattr(conn, "no_header", False))

    async def send(self, msg: Any) -> None:
        try:
            await self.stream.send_all(self.conn.send(msg))
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as err:
            raise ClientError(
                f"the server closed the connection while we sent {type(msg).__name__}: {err}"
            ) from None

    async def receive(self, waiting_for: str) -> Any:
        while True:
            try:
                event = self.conn.next_event()
            except ProtocolError as err:
                raise ClientError(
                    f"bad message from the server while waiting for {waiting_for}: {err}"
                ) from None
            if event is not NEED_DATA:
                self.pending = 0
                if isinstance(event, ConnectionClosed):
                    raise ClientError(
                        f"the server closed the connection while we waited for {waiting_for}"
                    )
                return event
            try:
                if self.timeout is not None:
                    with trio.fail_after(self.timeout):
                        data = await self.stream.receive_some(65536)
                else:
                    data = await self.stream.receive_some(65536)
            except trio.TooSlowError:
                hint = ""
                if self.pending and not self.conn_no_header:
                    hint = (
                        f"; the server sent {self.pending} bytes but no complete NUL-terminated "
                        "message (rddlsim keeps no-header mode for every client once one asked "
                        "for it): try --no-header"
                    )
                raise ClientError(
                    f"no answer from the server for {self.timeout:g} s while waiting for {waiting_for}{hint}"
                ) from None
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as err:
                raise ClientError(
                    f"connection lost while waiting for {waiting_for}: {err}"
                ) from None
            self.pending += len(data)
            self.conn.receive_data(data)


def _typed(
    codec: WireCodec, fluents: tuple[Fluent, ...]
) -> dict[tuple[str, tuple[str, ...]], Value]:
    model = codec.model
    out: dict[tuple[str, tuple[str, ...]], Value] = {}
    for f in fluents:
        p = model.pvariables.get(f.name)
        if p is None:
            raise ClientError(
                f"the server sent fluent {f.name!r}, which {model.name} does not declare"
            )
        try:
            out[(f.name, tuple(f.args))] = parse_value(str(f.value), value_kind(model, p))
        except ValueError:
            raise ClientError(
                f"the server sent {f.name}({','.join(f.args)}) = {f.value!r}, not a {p.range}"
            ) from None
    return out


async def run_session(
    config: ClientConfig,
    planner: Planner,
    planner_name: str = "",
    on_init: Callable[[float], None] | None = None,
) -> SessionResult:
    """Connect, play every round with `planner`, return the results. `on_init` hears
    the session's budget in seconds as soon as session-init arrives (before the
    planner starts)."""
    started = time.monotonic()
    try:
        with trio.fail_after(config.timeout or 60.0):
            stream = await trio.open_tcp_stream(config.host, config.port)
    except (OSError, trio.TooSlowError) as err:
        raise ClientError(f"cannot connect to {config.host}:{config.port}: {err}") from None
    async with stream:
        link = _Link(stream, ClientConnection(no_header=config.no_header), config.timeout)
        await link.send(
            SessionRequest(
                problem_name=config.instance,
                client_name=config.client_name,
                no_header=config.no_header,
            )
        )
        init = await link.receive("session-init")
        if not isinstance(init, SessionInit):
            raise ClientError(f"expected session-init, got {type(init).__name__}")
        if on_init is not None:  # loading and compiling the model is the session's time
            on_init(init.time_allowed / 1000.0)
        if config.rddl:
            try:
                model = load_model(*config.rddl, instance=config.instance)
            except RDDLError as err:
                raise ClientError(f"--rddl: {err}") from None
        else:
            model = model_from_task(init.task, config.instance)
        sim = await trio.to_thread.run_sync(Simulator, model)
        codec = WireCodec(sim)
        allowed_s = init.time_allowed / 1000.0
        planner.start_session(
            SessionInfo(
                instance=config.instance,
                model=model,
                simulator=sim,
                rounds=init.num_rounds,
                time_allowed=allowed_s,
                seed=config.seed,
            )
        )
        result = SessionResult(
            config.instance,
            planner_name or type(planner).__name__,
            config.client_name,
            0.0,
            0.0,
            session_id=init.session_id,
        )
        horizon = model.horizon or 0
        plan = [True] * config.rounds_training + [False] * init.num_rounds
        total: float | None = None
        counted = 0
        for index, training in enumerate(plan):
            await link.send(RoundRequest(execute_policy=not training))
            event = await link.receive("round-init")
            if isinstance(event, SessionEnd):
                total = event.total_reward
                break
            if not isinstance(event, RoundInit):
                raise ClientError(f"expected round-init, got {type(event).__name__}")
            if training and event.round_num != counted:
                # Only a server in monitor-execution mode plays practice rounds (their
                # round-num repeats the last counted one); anywhere else it counts.
                log.warning(
                    "round-init %d: the server counts this round although we asked for "
                    "training (is it in monitor-execution mode?)",
                    event.round_num,
                )
                training = False
            if not training:
                counted += 1
            rounds_left = len(plan) - index
            rnd = await _play_round(
                link, planner, codec, event, training, horizon, rounds_left, started, allowed_s
            )
            result.rounds.append(rnd)
            log.info(
                "round %d: reward %.4f in %d turns%s",
                rnd.round,
                rnd.reward,
                rnd.turns,
                " (training)" if training else "",
            )
        if total is None:
            event = await link.receive("session-end")
            if not isinstance(event, SessionEnd):
                raise ClientError(f"expected session-end, got {type(event).__name__}")
            total = event.total_reward
        planner.end_session(total)
        scored = [r.reward for r in result.rounds if not r.training]
        result.total_reward = total
        result.mean_round_reward = statistics.fmean(scored) if scored else 0.0
        result.seconds = time.monotonic() - started
        return result


async def _play_round(
    link: _Link,
    planner: Planner,
    codec: WireCodec,
    init: RoundInit,
    training: bool,
    horizon: int,
    rounds_left: int,
    started: float,
    allowed_s: float,
) -> RoundResult:
    t0 = time.monotonic()
    planner.start_round(init.round_num)
    turns = 0
    while True:
        event = await link.receive("a turn or round-end")
        if isinstance(event, RoundEnd):
            ended_early = (
                None
                if (horizon and event.turns_used >= horizon)
                else "the server ended the round early"
            )
            planner.end_round(event.round_reward)
            return RoundResult(
                init.round_num,
                event.round_reward,
                event.turns_used,
                time.monotonic() - t0,
                training,
                ended_early,
            )
        if not isinstance(event, Turn):
            raise ClientError(f"expected a turn, got {type(event).__name__}")
        turns += 1
        steps_left = max(1, horizon - event.turn_num + 1) if horizon else 1
        # our own clock and the server's: whichever says less
        own_left = allowed_s - (time.monotonic() - started)
        time_left = min(own_left, event.time_left / 1000.0)
        # PROST's uniform time manager: what is left, spread over the steps left in
        # the session, less a reserve for the messages and the server's own steps
        # (a planner that uses all its time must not push the session past its budget).
        steps_in_session = steps_left + max(0, rounds_left - 1) * max(horizon, 1)
        reserve = max(0.1, 0.02 * allowed_s)
        deadline = time.monotonic() + max(0.0, time_left - reserve) / steps_in_session
        fluents = None
        state = None
        if event.fluents is not None:
            fluents = _typed(codec, event.fluents)
            if not codec.pomdp:
                try:
                    state = codec.state_from((n, a, v) for (n, a), v in fluents.items())
                except WireError as err:
                    raise ClientError(f"turn {event.turn_num}: {err}") from None
        obs = Observation(
            fluents=fluents,
            state=state,
            turn=event.turn_num,
            steps_left=steps_left,
            time_left=event.time_left / 1000.0,
            immediate_reward=event.immediate_reward,
            deadline=deadline,
        )
        chosen = planner.act(obs)
        await link.send(Actions(tuple(Fluent(n, tuple(a), v) for n, a, v in chosen)))


def run_session_guarded(
    config: ClientConfig,
    planner: str,
    options: dict[str, str],
    *,
    memory_mb: float | None,
    grace: float = 30.0,
    log_level: int = logging.INFO,
    cancel: threading.Event | None = None,
) -> SessionResult:
    """`run_session` with the registered planner `planner` made from `options` in a
    child process (`client.guard`), blocking: the child is stopped once the session's
    budget plus `grace` has passed since session-init (before it: the config's timeout
    plus `grace`) or killed over `memory_mb` MB. `ClientError` says what ended it (for
    a planner the caller cannot stop: a thread of an event loop can call this)."""
    from .guard import run_guarded

    budget: list[float] = []

    def heard(msg: Any) -> float | None:
        if msg[0] == "init":
            budget.append(msg[1])
            return float(msg[1]) + grace
        return None

    options = dict(options)
    if memory_mb is not None:
        from ..planners.base import find_planner

        # a planner that sizes its working memory gets most of the budget (the rest
        # is the process: Python, the model, the simulator)
        if "memory" in find_planner(planner).options and "memory" not in options:
            options["memory"] = f"{max(1.0, 0.75 * memory_mb):.0f}"
    out = run_guarded(
        "ippc.client.session:_session_in_child",
        (config, planner, options),
        seconds=(config.timeout or 600.0) + grace,
        memory_mb=memory_mb,
        on_message=heard,
        log_level=log_level,
        cancel=cancel,
    )
    if out.status == "ok":
        if isinstance(out.value, str):
            raise ClientError(out.value)
        result: SessionResult = out.value
        return result
    if out.status == "timeout" and budget:
        raise ClientError(
            f"planner {planner}: still playing {out.seconds:.1f} s after session-init, past "
            f"the session's budget of {budget[0]:g} s plus {grace:g} s grace; its process "
            "was stopped"
        )
    if out.status == "timeout":
        raise ClientError(
            f"no session-init {out.seconds:.1f} s after we started (timeout "
            f"{config.timeout:g} s plus {grace:g} s grace); stopped"
        )
    raise ClientError(f"planner {planner}: {out.reason}")


def _session_in_child(
    arg: tuple[ClientConfig, str, dict[str, str]], send: Callable[[Any], None]
) -> SessionResult | str:
    """The guard's child: make the planner and play; a user-facing error as text."""
    from ..planners.base import PlannerError, make_planner

    config, planner, options = arg
    try:
        agent = make_planner(planner, options)
        return trio.run(run_session, config, agent, planner, lambda s: send(("init", s)))
    except ClientError as err:
        return str(err)
    except PlannerError as err:
        return f"planner {planner}: {err}"


def default_client_name() -> str:
    return f"ippc-{os.getpid()}"
