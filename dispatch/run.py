"""Running the dispatcher: serve it, start a planner against it, report.

`serve_dispatcher` serves a `Dispatcher` with rddl-server's listener and
session code (one session at a time; the result store, transcripts and the
session budget as rddl-server's options have them). `run_planner` plays a
planner against it once it listens: a built-in planner through
rddl-client's guarded session, in a child process with a time and a memory
budget (`ippc.dispatch.attempt`), so that planning never stalls the
dispatcher, its handlers or its sensors, or PROST through its launcher
(`ippc.planners.prost`). `dispatch_session`
does both and returns a `RunReport`; `simulate` does it all in the
simulated world (`ippc.dispatch.world`), callable from Python as from
`rddl-dispatch --simulate`.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import logging
import math
import signal
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import trio

from ..kb import KnowledgeBase
from ..kb.jsonl import JsonlServer
from ..kb.service import GOAL_OUTCOME_EVENT, notify_subscribers, register_kb
from ..planners.base import ExternalPlanner, Planner, PlannerError, find_planner, make_planner
from ..server.app import (
    accept_connections,
    close_services,
    connection_table,
    open_services,
    play_connection,
    serve,
)
from ..server.config import ServerConfig
from ..server.limits import LISTEN_BACKLOG, AcceptPacer
from ..server.session import Services, Session
from .attempt import DEFAULT_PLANNER_GRACE, play_external, play_guarded
from .dispatcher import Dispatcher
from .goals import GoalLedger
from .journal import KBJournal
from .remote import register_dispatch
from .report import (
    DEFAULT_GOAL_SESSIONS,
    DEFAULT_ROUNDS,
    LinkPolicy,
    PlannerSpec,
    RunReport,
    kb_socket_limits,
    server_config,
    signal_exit_code,
)
from .robot import Robot, RobotFileError, build_robot, build_simulation, load_robot_file
from .watchdog import LoopWatchdog

__all__ = [
    "DEFAULT_GOAL_SESSIONS",
    "DEFAULT_ROUNDS",
    "LinkPolicy",
    "PlannerSpec",
    "Robot",
    "RobotFileError",
    "RunReport",
    "build_robot",
    "build_simulation",
    "load_robot_file",
    "dispatch_session",
    "kb_socket_limits",
    "server_config",
    "serve_dispatcher",
    "signal_exit_code",
    "simulate",
]

log = logging.getLogger(__name__)


async def serve_dispatcher(
    dispatcher: Dispatcher,
    config: ServerConfig,
    services: Services | None = None,
    *,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
) -> Services:
    """Serve `dispatcher` until cancelled (or, with `individual_session`,
    until its one session ends); reports the bound port once listening.
    `services` (the result store) are the caller's and stay open."""
    return await serve(config, dispatcher, task_status=task_status, services=services)


async def run_planner(
    spec: PlannerSpec,
    host: str,
    port: int,
    instance: str,
    timeout: float | None = None,
    *,
    in_loop: bool = False,
    memory_mb: float | None = None,
    grace: float = DEFAULT_PLANNER_GRACE,
) -> str | None:
    """Play one session of `spec`'s planner against host:port; the error it
    ended with (why it was ended), or None. A built-in or plug-in planner
    plays in a child process (`attempt.play_guarded`: stopped `grace` s past
    its session's budget, killed over `memory_mb` MB, None: 80% of the
    memory available now), watched from a thread, so that nothing it does
    stalls the dispatcher's handlers, sensors or sockets; `in_loop`, it plays
    in the caller's trio loop instead (no budget holds: nothing else runs
    while it plans; no handover per turn, which the simulated world wants).
    PROST (`spec.prost`) runs as its own program."""
    made: Planner | ExternalPlanner | None = None  # None: made in the child
    if spec.prost is not None:
        made = make_planner("prost", {**spec.options, "binary": spec.prost})
    elif in_loop or issubclass(find_planner(spec.name), ExternalPlanner):
        made = make_planner(spec.name, dict(spec.options))
    if isinstance(made, ExternalPlanner):
        return await play_external(made, host, port, instance, timeout)
    from ..client.session import ClientConfig, ClientError, run_session

    config = ClientConfig(
        host=host,
        port=port,
        instance=instance,
        client_name=spec.name,
        no_header=spec.no_header,
        seed=spec.seed,
        timeout=timeout if timeout is not None else 600.0,
    )
    if made is not None:
        try:
            await run_session(config, made, spec.name)
        except ClientError as err:
            return str(err)
        return None
    return await play_guarded(config, spec, memory_mb, grace)


class _Run:
    """The state one `dispatch_session` shares between its tasks."""

    def __init__(self) -> None:
        self.over = False  # no further session: the run ends
        self.statuses: list[str] = []  # each session's final status, in order
        self.planner_errors: list[str] = []
        self.last_error: str | None = None  # of the last planner attempt
        self.restarts = 0
        self.interrupted: str | None = None  # the signal's name
        self.ended = trio.Event()  # set after each session; replaced by the next
        self.attempt: trio.CancelScope | None = None  # the planner attempt in progress
        self.turns_at_attempt = 0

        self.planner_done = trio.Event()
        self.serving = False  # serve goals until stopped
        self.ledger: GoalLedger | None = None  # every goal's outcome

    @property
    def goal(self) -> dict[str, Any] | None:
        """The goal being pursued (its record), None when there is none."""
        return self.ledger.current if self.ledger is not None else None

    def session_over(self, status: str | None) -> None:
        """A session ended with `status` (None: the run ends without one)."""
        if status is not None:
            self.statuses.append(status)
        ended, self.ended = self.ended, trio.Event()
        ended.set()


async def dispatch_session(
    dispatcher: Dispatcher,
    spec: PlannerSpec | None,
    config: ServerConfig,
    *,
    sensing_task: bool = False,
    planner_timeout: float | None = None,
    planner_in_loop: bool = False,
    planner_memory_mb: float | None = None,
    planner_grace: float = DEFAULT_PLANNER_GRACE,
    on_listening: Callable[[int], None] | None = None,
    robot: Robot | None = None,
    kb_port: int | None = None,
    on_kb_listening: Callable[[int], None] | None = None,
    link: LinkPolicy | None = None,
    watchdog: float | None = None,
    handle_signals: bool = False,
    journal: bool = False,
    resume: bool = True,
    serve_goals: bool = False,
    goal_sessions: int | None = DEFAULT_GOAL_SESSIONS,
    stop: trio.Event | None = None,
    web: Callable[..., Awaitable[Any]] | None = None,
) -> RunReport:
    """Serve `dispatcher`, start the planner once it listens (none: wait
    for one to connect), play until a session ends (with `link.reconnect`,
    a dropped session is followed by the next one), and report.
    `sensing_task` runs the dispatcher's sensing batches at their rate
    meanwhile (a robot; the simulated world needs none); `robot`'s tasks
    (sensor sources) run meanwhile too. With `kb_port`, the knowledge base's
    JSON-lines socket (the `kb.*` methods and the dispatcher's `sensing.*`
    and `handlers.*`, see `ippc.dispatch.remote`) is served on that port
    (0: any free one, reported through `on_kb_listening`) before the
    planner starts. `watchdog`: seconds the event loop may stay blocked
    before a warning names the handler (None: no watchdog). With
    `handle_signals`, SIGINT and SIGTERM cancel the current action, close
    the session as `interrupted` and return the report (its `interrupted`
    names the signal). With `journal` and a result store (`config.db`),
    every batch applied to the knowledge base is journaled there and, with
    `resume`, the facts journaled for this instance are restored first.
    With `serve_goals`, the run goes on until cancelled (or a signal):
    whenever the knowledge base has a goal that does not hold (set at run
    time with `kb.set_goal`, over the socket or from Python), a session
    serves it (the planner is started again for each); each goal's outcome
    is in the report's `goals`. A goal the session's rounds did not reach
    is served again while it does not hold, up to `goal_sessions` sessions
    (None: no limit); then it is abandoned (a WARNING) and the run waits
    for another goal. Every goal posed, changed or removed during the run
    gets one outcome (`ippc.dispatch.goals`): in the report's `goals`, in
    the result store (`goal_outcomes`) and, to the socket's subscribers, as
    a `kb.goal_outcome` event. Setting `stop`
    ends the run as a signal does (`interrupted` is then "stop"). `web`
    (`ippc.dispatch.web.web_task`) is started in the run's nursery with the
    dispatcher before the planner's socket listens: the web page.
    A built-in planner that `spec` names plays in a child process
    (`run_planner`): stopped `planner_grace` seconds past its session's
    budget, killed over `planner_memory_mb` MB (None: 80% of the memory
    available when the run starts); its error (why it was ended) is the
    attempt's, and the restart policy goes on as after any planner error.
    `planner_in_loop`: it plays in this trio loop instead (no budget holds)."""
    started = time.perf_counter()
    link = link or LinkPolicy()
    config = dataclasses.replace(
        config, individual_session=True, idle_timeout=link.idle_timeout(config)
    )
    run = _Run()
    if spec is not None and spec.prost is None and not planner_in_loop:
        from ..client.guard import default_memory_budget

        if planner_memory_mb is None:
            planner_memory_mb = default_memory_budget()  # of the memory available at start
    if serve_goals:
        run.serving = True
        link = dataclasses.replace(link, reconnect=True)
    svc = open_services(config, dispatcher, config.port)
    sockets: list[JsonlServer] = []  # the knowledge base's, once it listens
    store = svc.store

    def record(outcome: dict[str, Any]) -> None:
        if store is not None:
            store.record_goal_outcome(dispatcher.name, outcome)

    def notify(outcome: dict[str, Any]) -> None:
        for socket in sockets:
            notify_subscribers(socket, GOAL_OUTCOME_EVENT, {"outcome": outcome})

    run.ledger = GoalLedger(
        dispatcher,
        serving=serve_goals,
        max_sessions=goal_sessions if goal_sessions else None,
        record=record,
        notify=notify,
    )
    kb_journal: KBJournal | None = None
    if journal and svc.store is not None:
        kb_journal = KBJournal(dispatcher.kb, svc.store, dispatcher.name)
        if resume:
            kb_journal.restore()
        kb_journal.start()
    try:
        run.ledger.start()
        async with trio.open_nursery() as nursery:
            # warnings about the planner's sessions, counted per cause (rddl-server's)
            nursery.start_soon(svc.notices.run)
            nursery.start_soon(dispatcher.notices.run)  # sensing against the model
            if svc.budget is not None:  # frees the readers' buffers of ended sessions
                nursery.start_soon(svc.budget.run)
            if handle_signals:
                nursery.start_soon(_watch_signals, run, nursery.cancel_scope)
            if stop is not None:

                async def stopper(event: trio.Event = stop) -> None:
                    await event.wait()
                    log.warning(
                        "stop: cancelling the current action, closing the session as interrupted"
                    )
                    run.interrupted = "stop"
                    run.over = True
                    nursery.cancel_scope.cancel()

                nursery.start_soon(stopper)
            if watchdog is not None and watchdog > 0:
                handlers = dispatcher.handlers
                dog = LoopWatchdog(watchdog, lambda: ", ".join(list(handlers.running.values())))
                await nursery.start(dog.run)
            if sensing_task and dispatcher.sensing is not None:
                await nursery.start(dispatcher.sensing.run)
            if robot is not None:
                for fn, args in robot.tasks:
                    nursery.start_soon(_logged_task, fn, args)
            if kb_port is not None:
                socket = JsonlServer("rddl-dispatch", kb_socket_limits(config))
                register_kb(socket, dispatcher.kb)
                register_dispatch(
                    socket,
                    dispatcher.handlers,
                    dispatcher.sensing,
                    [p.name for p in dispatcher.sim.action_fluents],
                )
                try:
                    bound = await nursery.start(socket.serve, config.host, kb_port)
                except OSError as err:
                    raise ListenError(
                        "the knowledge base's socket, --kb-port", f"{config.host}:{kb_port}", err
                    ) from None
                sockets.append(socket)
                if on_kb_listening is not None:
                    on_kb_listening(bound)
            if web is not None:
                await nursery.start(web, dispatcher)
            try:
                port = await nursery.start(_sessions, dispatcher, config, svc, link, run)
            except OSError as err:
                raise ListenError(
                    "the planner's socket, --port", f"{config.host}:{config.port}", err
                ) from None
            if on_listening is not None:
                on_listening(port)
            if spec is not None:
                nursery.start_soon(
                    _planner_loop,
                    spec,
                    config.host,
                    port,
                    dispatcher,
                    (planner_timeout, planner_in_loop, planner_memory_mb, planner_grace),
                    link,
                    run,
                )

            async def finish() -> None:
                while not run.over:
                    await run.ended.wait()
                if spec is not None:
                    # the planner hears of the end (session-end) and leaves
                    with trio.move_on_after(5.0):
                        await run.planner_done.wait()
                nursery.cancel_scope.cancel()

            nursery.start_soon(finish)
    finally:
        # (a run cancelled from outside, not ended by itself, was interrupted)
        run.ledger.finish(interrupted=run.serving or run.interrupted is not None or not run.over)
        if kb_journal is not None:
            kb_journal.stop()
        reason = (
            f"rddl-dispatch stopped ({run.interrupted})"
            if run.interrupted
            else "rddl-dispatch stopped"
        )
        close_services(svc, reason)
    stats = dispatcher.stats
    status = run.statuses[-1] if run.statuses else None
    if run.interrupted is not None:
        status = "interrupted"
    error = run.last_error
    if error is not None and spec is not None:
        log.warning("planner %s: %s", spec.label, error)
    return RunReport(
        instance=dispatcher.name,
        planner=spec.label if spec is not None else "(connected)",
        goal_reached=stats.goal_reached,
        turns=stats.turns,
        rounds=stats.rounds,
        reward=stats.reward,
        dispatcher_reward=stats.reward,
        executed=[a.as_dict() for a in stats.executed],
        failed_actions=stats.failed_actions,
        planning_seconds=stats.planning_seconds,
        execution_seconds=stats.execution_seconds,
        replans=stats.replans,
        cost=stats.cost,
        contradictions=stats.contradictions,
        session_status=status,
        wall_seconds=time.perf_counter() - started,
        planner_error=error,
        sessions=list(run.statuses),
        planner_restarts=run.restarts,
        interrupted=run.interrupted,
        facts=final_facts(dispatcher.kb),
        journaled=kb_journal.batches if kb_journal is not None else None,
        executed_total=stats.executed_total,
        goals=list(run.ledger.outcomes),
    )


def final_facts(kb: KnowledgeBase) -> list[list[Any]]:
    """The knowledge base's state fluents as the report lists them:
    `[fluent, [args...], value]` for every grounding that is not false."""
    return [
        [fluent, list(args), value]
        for (fluent, args), value in kb.facts().items()
        if value is not False
    ]


async def _sessions(
    dispatcher: Dispatcher,
    config: ServerConfig,
    svc: Services,
    link: LinkPolicy,
    run: _Run,
    *,
    task_status: trio.TaskStatus[int] = trio.TASK_STATUS_IGNORED,
) -> None:
    """Play one session after another, one at a time, on one listening
    socket that stays open for the whole run: a planner that connects while
    a session plays (a restarted one, while the dropped session is torn
    down) waits and is served next. The listener is rddl-server's, with its
    limits (`config.allow`, the connection caps, counting the connections
    waiting to be served, and the accept rate: docs/server-safety.md)."""
    listeners = await trio.open_tcp_listeners(config.port, host=config.host, backlog=LISTEN_BACKLOG)
    port = listeners[0].socket.getsockname()[1]
    table = connection_table(config)
    pacer = AcceptPacer(config.accept_rate)
    keys = itertools.count(1)
    # (bounded by the table: a connection beyond its caps is refused at once)
    send, receive = trio.open_memory_channel[tuple[trio.SocketStream, int]](math.inf)

    def take(stream: trio.SocketStream, key: int) -> bool:
        send.send_nowait((stream, key))
        return False

    async with trio.open_nursery() as nursery:
        for listener in listeners:
            nursery.start_soon(accept_connections, listener, svc, table, pacer, keys, take)
        task_status.started(port)
        try:
            while not run.over:
                if run.serving and run.goal is None:
                    await _next_goal(dispatcher, run)
                stream, key = await receive.receive()
                served = run.goal  # the goal this session serves
                playing: list[Session] = []
                try:
                    session = await play_connection(svc, stream, started=playing.append)
                except trio.Cancelled:
                    # stopped while the session said goodbye: a session that had
                    # ended (its record written) still counts for the goal served
                    if playing and playing[0].status in ("finished", "timeout"):
                        _served(run, playing[0].status, served)
                    raise
                finally:
                    table.remove(key)
                if not session.requested:
                    # never a session (a port scan, a client that hung up or said
                    # nothing): counted in the log, not a planner lost; the run goes on
                    continue
                status = session.status if session.status != "open" else "dropped"
                _served(run, status, served)
                if run.serving:
                    if status == "dropped" and run.attempt is not None:
                        run.attempt.cancel()
                    run.session_over(status)
                    continue
                if status != "dropped" or not link.reconnect:
                    run.over = True
                else:
                    log.warning(
                        "the planner's session dropped: waiting for a planner to connect again on "
                        "%s:%d (going on from the knowledge base as it is)",
                        config.host,
                        port,
                    )
                    if run.attempt is not None:
                        run.attempt.cancel()  # a hung planner the dispatcher started: stop it
                run.session_over(status)
        finally:
            send.close()
            while True:  # connections still waiting: closed
                try:
                    stream, key = receive.receive_nowait()
                except (trio.WouldBlock, trio.EndOfChannel):
                    break
                stream.socket.close()
                table.remove(key)
        nursery.cancel_scope.cancel()


async def _next_goal(dispatcher: Dispatcher, run: _Run) -> None:
    """Wait until the knowledge base has a goal to serve (one that does
    not hold and was not abandoned: a new one set at run time, or the state
    changed under the old one), and start serving it."""
    kb = dispatcher.kb
    ledger = run.ledger
    assert ledger is not None
    token = trio.lowlevel.current_trio_token()
    wake = trio.Event()

    def poke(*_: Any) -> None:  # from any thread that changed the knowledge base
        try:
            token.run_sync_soon(wake.set)
        except trio.RunFinishedError:
            pass

    unsubscribe = [kb.subscribe(poke), kb.subscribe_goal(poke)]
    try:
        waited = False
        # (a goal posed meanwhile is opened by the ledger itself)
        while ledger.current is None and not ledger.wanted(kb.goal()):
            if not waited:
                log.info("serving goals: waiting for a goal that does not hold yet (kb.set_goal)")
                waited = True
            await wake.wait()
            wake = trio.Event()
    finally:
        for stop in unsubscribe:
            stop()
    if ledger.current is None:
        goal = kb.goal()
        assert goal is not None
        ledger.open(goal)
    dispatcher.stats.goal_reached = False
    if ledger.current is not None:
        log.info("serving goal %s (version %s)", ledger.current["goal"], ledger.current["version"])


def _served(run: _Run, status: str, served: dict[str, Any] | None) -> None:
    """A session of the goal being pursued ended: the ledger records its
    outcome once the goal is reached or has had its sessions (a dropped
    one is tried again)."""
    if run.ledger is not None:
        run.ledger.session_ended(status, served)


#: How `_play_planner` plays: the client's timeout, in the loop, memory budget, grace.
_HowToPlay = tuple[float | None, bool, float | None, float]


async def _planner_loop(
    spec: PlannerSpec,
    host: str,
    port: int,
    dispatcher: Dispatcher,
    how: _HowToPlay,
    link: LinkPolicy,
    run: _Run,
) -> None:
    """Run the planner; while the run goes on (its session dropped), start
    it again after a delay."""
    try:
        await _play_planner(spec, host, port, dispatcher, how, link, run)
    finally:
        run.planner_done.set()


async def _play_planner(
    spec: PlannerSpec,
    host: str,
    port: int,
    dispatcher: Dispatcher,
    how: _HowToPlay,
    link: LinkPolicy,
    run: _Run,
) -> None:
    timeout, in_loop, memory_mb, grace = how
    delay = link.restart_delay
    while not run.over:
        ended = run.ended
        turns = dispatcher.stats.turns
        error: str | None = None
        with trio.CancelScope() as attempt:
            run.attempt = attempt
            try:
                error = await run_planner(
                    spec,
                    host,
                    port,
                    dispatcher.name,
                    timeout,
                    in_loop=in_loop,
                    memory_mb=memory_mb,
                    grace=grace,
                )
            except PlannerError as err:
                error = str(err)
            except Exception as err:  # noqa: BLE001 - a planner's bug ends its session only
                while isinstance(err, ExceptionGroup) and len(err.exceptions) == 1:
                    err = err.exceptions[0]  # the planner's own error, not trio's wrapping
                log.error("planner %s raised", spec.label, exc_info=True)
                error = f"the planner raised {type(err).__name__}: {err}"
        run.attempt = None
        ended_at = trio.current_time()  # the restart delay counts from here
        if attempt.cancelled_caught and error is None:
            error = "stopped: its session dropped"
        run.last_error = error
        if error is not None:
            run.planner_errors.append(error)
        # the planner is done; its session ends with it (grace for the end)
        with trio.move_on_after(5.0):
            await ended.wait()
        if not ended.is_set():
            # no session ended: the planner never connected (or still plays)
            if not link.reconnect:
                run.over = True
                run.session_over(None)
                return
        if run.over:
            return
        if dispatcher.stats.turns > turns:
            delay = link.restart_delay  # it played: start again at once-ish
        if run.serving:
            # serving goals: a planner for the goal being served, or the next one
            while run.goal is None and not run.over:
                await trio.sleep(0.05)
            if error is None:  # its session played out
                delay = link.restart_delay
                continue
        run.restarts += 1
        # (the wait for its session's end, above, counts towards the delay:
        # the log says when the planner really starts again)
        waited = trio.current_time() - ended_at
        left = max(0.0, delay - waited)
        log.warning(
            "planner %s ended (%s): starting it again in %.1f s (%.1f s after it ended)",
            spec.label,
            error or "its session dropped",
            left,
            waited + left,
        )
        await trio.sleep(left)
        delay = min(delay * 2, link.max_restart_delay)


async def _watch_signals(run: _Run, scope: trio.CancelScope) -> None:
    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
        async for signum in signals:
            name = signal.Signals(signum).name
            log.warning(
                "%s: cancelling the current action, closing the session as interrupted", name
            )
            run.interrupted = name
            run.over = True
            scope.cancel()
            return


async def _logged_task(fn: Callable[..., Awaitable[Any]], args: tuple[Any, ...]) -> None:
    """A robot task (a sensor source): its end or its error is logged, and
    never ends the dispatcher."""
    name = getattr(fn, "__name__", repr(fn))
    try:
        await fn(*args)
    except Exception as err:  # noqa: BLE001 - a sensor source's bug stops that source only
        log.error("robot task %s failed: %s: %s", name, type(err).__name__, err)
    else:
        log.info("robot task %s ended", name)


class ListenError(OSError):
    """A socket of the dispatcher that cannot listen; `what` says which
    (the planner's, the knowledge base's), `where` the address asked for."""

    def __init__(self, what: str, where: str, err: OSError):
        super().__init__(err.errno, err.strerror or str(err))
        self.what = what
        self.where = where

    def __str__(self) -> str:
        return f"cannot listen on {self.where} ({self.what}): {self.strerror}"


def executed_plan(db: str | Path, session: int | None = None) -> list[dict[str, Any]]:
    """The executed plan of a dispatcher session in a result store (the
    last dispatcher session when `session` is None): one entry per
    dispatched action, with its round, turn, outcome and message. A store
    without such a session, or a `session` that rddl-server played (its
    steps have no outcomes), raises KeyError saying so."""
    from ..server.store import ResultStore

    with ResultStore(db) as store:
        sessions = store.sessions()
        if not sessions:
            raise KeyError(f"{db}: no session recorded")
        if session is not None:
            chosen = [store.session(session)]
        else:
            chosen = list(reversed(sessions))
        for row in chosen:
            plan = _plan_of(store, row["id"])
            if plan is not None:
                return plan
        if session is not None:
            raise KeyError(
                f"{db}: session {session} was not played by rddl-dispatch (no step has an outcome)"
            )
        raise KeyError(f"{db}: no rddl-dispatch session recorded ({len(sessions)} other(s))")


def _plan_of(store: Any, session: int) -> list[dict[str, Any]] | None:
    """The executed plan of one session; None when no step of it has an
    outcome (rddl-server's sessions)."""
    plan: list[dict[str, Any]] = []
    dispatched = False
    for rnd in store.rounds(session):
        for step in store.steps(rnd["id"]):
            outcome = step["outcome"]
            if outcome is None:
                continue  # a simulated step (rddl-server's)
            dispatched = True
            for entry in outcome.get("actions", []):
                plan.append({"session": session, **entry})
    return plan if dispatched else None


async def simulate_async(
    domain: str | Path,
    instance: str | Path,
    *,
    seed: int = 0,
    planner: PlannerSpec | None = None,
    rounds: int = DEFAULT_ROUNDS,
    db: Path | None = None,
    transcripts: Path | None = None,
    planner_timeout: float | None = None,
    timeout: float = 0.0,
    handle_signals: bool = False,
    web: Callable[..., Awaitable[Any]] | None = None,
    resume: bool = True,
    **world: Any,
) -> RunReport:
    """`simulate`, inside a trio run. `timeout` is the session budget in
    seconds (0: none; time-allowed is then rddlsim's default, 1080 s), which
    PROST spreads over its steps. With `db`, the knowledge base is
    journaled there as in a robot's run and, with `resume`, a run starts
    from the facts journaled for its instance: the simulated world starts
    in that state too (where the last run left the robot)."""
    kb = KnowledgeBase.from_files(domain, instance)
    restored = 0
    if db is not None and resume:
        from ..server.store import ResultStore

        with ResultStore(db) as store:
            restored = KBJournal(kb, store, kb.model.name).restore()
    the_world, dispatcher = build_simulation(kb, seed, **world)
    if restored:
        the_world.resume(kb.to_state())
        log.info(
            "simulated world: resumed from %d journaled batch(es) of %s", restored, kb.model.name
        )
    spec = planner or PlannerSpec()
    config = server_config(rounds=rounds, db=db, transcripts=transcripts, timeout=timeout)
    config = ServerConfig(**{**config.__dict__, "seed": seed})
    # simulated time: nothing needs to run while the planner thinks
    report = await dispatch_session(
        dispatcher,
        spec,
        config,
        planner_timeout=planner_timeout,
        planner_in_loop=True,
        handle_signals=handle_signals,
        journal=db is not None,
        resume=False,  # (restored above, before the world was built)
        web=web,
    )
    report.reward = the_world.reward
    report.seed = seed
    return report


def simulate(domain: str | Path, instance: str | Path, **options: Any) -> RunReport:
    """One whole simulated run (world, sensing, knowledge base, dispatcher,
    planner, handlers): the report of the session. `options` are those of
    `simulate_async`: `seed`, `planner` (a `PlannerSpec`), `rounds`, `db`,
    `transcripts`, `planner_timeout`, `timeout`, `web`, `resume`, and the world's `durations`, `costs`,
    `failures`, `sensed`, `exogenous`, `observe`, `action_timeout`,
    `stop_at_goal` (see `SimulatedWorld`)."""
    return trio.run(functools.partial(simulate_async, domain, instance, **options))
