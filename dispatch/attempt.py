"""One attempt of a planner that rddl-dispatch started, off the dispatcher's loop.

A built-in (or plug-in) planner plays in a child process of its own through
rddl-client's guarded session (`ippc.client.session.run_session_guarded`,
`ippc.client.guard`), the way rddl-client and rddl-batch run one: its start-up,
its search and its memory are the child's, so a planner that never returns or
allocates without bound costs its child alone. The child is watched from a
worker thread (the guard blocks while it watches); the dispatcher's loop, its
handlers, sensors and sockets go on meanwhile. An external planner (PROST) is
its own program already: its blocking launcher runs in a thread too.
"""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING

import trio

from ..planners.base import ExternalPlanner

if TYPE_CHECKING:
    from ..client.session import ClientConfig
    from .report import PlannerSpec

__all__ = ["DEFAULT_PLANNER_GRACE", "play_external", "play_guarded"]

log = logging.getLogger(__name__)

#: Seconds a guarded planner may play past its session's budget before its process
#: is stopped (rddl-client's --grace default).
DEFAULT_PLANNER_GRACE = 30.0
#: Seconds to wait, past the guard's own SIGTERM grace, for a stopped child's end.
_STOP_WAIT = 15.0
#: What `run_session_guarded`'s error ends with when our own cancel stopped the child.
_STOPPED_BY_US = ": stopped"


async def play_external(
    external: ExternalPlanner, host: str, port: int, instance: str, timeout: float | None
) -> str | None:
    """One session of an external planner (PROST's launcher) in a thread; the
    error it ended with, or None."""

    def play() -> str | None:
        result = external.run_session(
            host=host,
            port=port,
            instance=instance,
            client_name=None,
            timeout=timeout,
            log_path=None,
        )
        return result.error

    try:
        # cancelled (its session dropped, the run ends): the program is
        # stopped at once (below), and its thread ends with it
        return await trio.to_thread.run_sync(play, abandon_on_cancel=True)
    finally:
        external.cancel()


async def play_guarded(
    config: ClientConfig, spec: PlannerSpec, memory_mb: float | None, grace: float
) -> str | None:
    """One session of the planner `spec.name` (made from `spec.options` in the
    child) in a guarded child process; the error it ended with, or None.

    The child is stopped once the session's budget plus `grace` has passed
    since session-init (before it: `config.timeout` plus `grace`) and killed
    over `memory_mb` MB (None: `default_memory_budget()`, 80% of the memory
    available now). Cancelled, the child is stopped and its end awaited
    (shielded, bounded); when the guard had already ended it for a cause of
    its own (time, memory, a failure), that cause is returned instead of the
    cancellation raised, so that the caller records why."""
    from ..client.guard import TERM_GRACE, default_memory_budget
    from ..client.session import ClientError, run_session_guarded

    if memory_mb is None:
        memory_mb = default_memory_budget()
    stop = threading.Event()
    outcome: list[str | None] = []  # the thread's, once it returns
    level = logging.getLogger("ippc").getEffectiveLevel()

    def play() -> None:
        try:
            run_session_guarded(
                config,
                spec.name,
                dict(spec.options),
                memory_mb=memory_mb,
                grace=grace,
                log_level=level,
                cancel=stop,
            )
        except ClientError as err:
            outcome.append(str(err))
            return
        outcome.append(None)

    try:
        await trio.to_thread.run_sync(play, abandon_on_cancel=True)
    except trio.Cancelled:
        stop.set()
        # the guard stops the child within its poll and TERM_GRACE: wait for that,
        # so that no planner's process outlives its attempt unseen
        with trio.CancelScope(shield=True, deadline=trio.current_time() + TERM_GRACE + _STOP_WAIT):
            while not outcome:
                await trio.sleep(0.05)
        if not outcome:
            log.error("planner %s: its process did not end after it was stopped", spec.name)
        elif outcome[0] is not None and not outcome[0].endswith(_STOPPED_BY_US):
            # ended already by the guard (its time, its memory) or failed on its
            # own: that is why the attempt ended, not the cancel
            return outcome[0]
        raise
    finally:
        stop.set()
    return outcome[0] if outcome else None
