"""Jobs: one session of one planner on one instance, with its seeds, and how it is played.

`play_job` is what the batch hands out (to a thread of this process, or to a Dask
worker): it runs `run_job` in a child process of its own (`ippc.client.guard`), so that
the session's budget and the job's memory budget hold whatever the planner does: a
child still running `grace` seconds past its session's budget is stopped and the job
recorded as ``timeout``; one over its memory budget is killed and the job recorded as
``failed``, its reason beginning ``out of memory``. `run_job` starts an
in-process ``rddl-server`` on 127.0.0.1 for the job's one instance, with the job's server
seed and the experiment's rounds and session budget, records the session in an in-memory
`ResultStore`, plays it with the planner (a registered planner driven by
``rddl-client``'s `run_session`; an `ExternalPlanner` such as PROST; or an external
command) and returns everything recorded as a plain, picklable `JobResult`. The batch's
parent process is the only writer of the result database (`batch.results`), so workers
on other machines need no shared file system; a job carries the text of its RDDL files
too, so that a worker anywhere plays it without the experiment's folder.

Seeds are derived from the experiment's seed, the instance and the planner label only
(`stable_seed`), so that a job played again (after a kill, on another machine) plays the
same session: the server seed depends on the instance alone, so every planner meets the
same random draws for the same actions (common random numbers).
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import trio

from ..rddl.loader import read_text
from ..server.store import ResultStore, encode_fluents
from .experiment import Experiment, PlannerSpec, fill_command
from .instances import ResolvedInstance

__all__ = [
    "Job",
    "JobResult",
    "ProgressQueue",
    "Reporter",
    "build_jobs",
    "mean_reward",
    "play_job",
    "run_job",
    "stable_seed",
]

log = logging.getLogger(__name__)

#: Seconds a job's process may take to start, load and check its instance before its
#: session begins (on top of the session's limit): the batch's own work, not the planner's.
LOAD_ALLOWANCE = 300.0

#: Seconds a session may run past its budget before the job is stopped from outside
#: (the server ends a session at its budget; this catches a client that hangs).
HARD_LIMIT_GRACE = 60.0


def stable_seed(*parts: object) -> int:
    """A seed in [0, 2**31) from the parts' text: the same on every machine and run
    (Python's ``hash`` is salted per process)."""
    digest = hashlib.sha256("\x1f".join(str(p) for p in parts).encode()).digest()
    return int.from_bytes(digest[:4], "big") & 0x7FFFFFFF


@dataclass(frozen=True)
class Job:
    """One session to play; everything a worker needs (no open files, no models)."""

    experiment: str
    planner: PlannerSpec
    instance: str
    domain: str
    files: tuple[str, ...]
    paired: bool
    rounds: int
    timeout: float
    server_seed: int
    planner_seed: int
    log_dir: str | None = None  # where an external command's output goes
    server: tuple[str, int] | None = None  # play against this server instead of our own
    texts: tuple[str, ...] = ()  # the text of each of `files`, for workers without them
    memory_mb: float | None = None  # the job's memory budget (None: the worker's default)
    grace: float = HARD_LIMIT_GRACE  # seconds past the session budget before it is stopped

    @property
    def key(self) -> str:
        return f"{self.planner.label}@{self.instance}"


@dataclass
class JobResult:
    """What a job produced: the session as the server recorded it, or why it failed."""

    key: str
    status: str  # finished | timeout | failed
    reason: str | None
    started_at: float
    ended_at: float
    session: dict[str, Any] | None = None
    # each round's row with its steps under "steps" (rows as ResultStore returns them,
    # state and actions as JSON text)
    rounds: list[dict[str, Any]] = field(default_factory=list)


def build_jobs(
    experiment: Experiment,
    instances: list[ResolvedInstance],
    *,
    log_dir: str | None = None,
    server: tuple[str, int] | None = None,
    memory_mb: float | None = None,
    grace: float = HARD_LIMIT_GRACE,
) -> list[Job]:
    """Every planner x instance of the experiment, instance by instance (so that the
    baselines of an instance finish early and partial scores mean something). Each
    job carries its files' absolute paths and texts."""
    jobs = []
    texts: dict[str, str] = {}
    for inst in instances:
        server_seed = stable_seed(experiment.seed, "server", inst.name)
        # only the files this instance is read from (a folder's spec names them all)
        files = tuple(
            str(Path(f).resolve()) for f in (inst.files if inst.paired else inst.model.files())
        )
        for f in files:
            if f not in texts:
                texts[f] = read_text(Path(f))
        for spec in experiment.planners:
            jobs.append(
                Job(
                    experiment=experiment.name,
                    planner=spec,
                    instance=inst.name,
                    domain=inst.domain,
                    files=files,
                    paired=inst.paired,
                    rounds=experiment.rounds,
                    timeout=spec.timeout or experiment.timeout,
                    server_seed=server_seed,
                    planner_seed=stable_seed(experiment.seed, "planner", spec.label, inst.name),
                    log_dir=log_dir,
                    server=server,
                    texts=tuple(texts[f] for f in files),
                    memory_mb=memory_mb,
                    grace=grace,
                )
            )
    return jobs


def mean_reward(result: JobResult) -> float | None:
    """The mean reward of a result's counted rounds (None: no round ended)."""
    rewards = [
        float(r["reward"])
        for r in result.rounds
        if r.get("counted", True) and r.get("reward") is not None
    ]
    return sum(rewards) / len(rewards) if rewards else None


# ---------------------------------------------------------------- in the worker

#: What a job tells of its session's progress: (job key, round, turn); turn None when
#: the round has just begun. Best effort: it must never slow or fail the job.
Reporter = Callable[[str, int, int | None], None]


class ProgressQueue:
    """A `Reporter` for worker processes: puts ``(key, round, turn)`` on a queue the
    batch's parent reads (a ``multiprocessing.Manager`` queue: it pickles into a
    worker), at most once per `period` seconds per job besides each round's start,
    never waiting (a full or closed queue loses the report, not the job)."""

    def __init__(self, queue: Any, period: float = 0.25) -> None:
        self.queue = queue
        self.period = period
        self._last = -math.inf

    def __call__(self, key: str, round_num: int, turn: int | None) -> None:
        if turn is not None:
            # a round's start is always told, and does not hold back the turns after it:
            # a job whose rounds last less than `period` still shows its turns
            now = time.monotonic()
            if now - self._last < self.period:
                return
            self._last = now
        try:
            self.queue.put_nowait((key, round_num, turn))
        except Exception:  # noqa: BLE001 - progress is best effort
            log.debug("progress of %s not reported", key, exc_info=True)


class _ReportingStore(ResultStore):
    """The job's in-memory store, telling `report` of each round and turn it records."""

    def __init__(
        self, key: str, report: Reporter, on_session: Callable[[], None] | None = None
    ) -> None:
        super().__init__(":memory:", owner=f"batch:{key}")
        self._key = key
        self._report = report
        self._on_session = on_session
        self._round_num: dict[int, int] = {}

    def start_session(self, *args: Any, **kwargs: Any) -> int:
        sid = super().start_session(*args, **kwargs)
        if self._on_session is not None:
            try:
                self._on_session()
            except Exception:  # noqa: BLE001 - best effort, as the reports
                log.debug("session start of %s not reported", self._key, exc_info=True)
        return sid

    def start_round(self, session: int, *, round_num: int, counted: bool, started_at: float) -> int:
        rid = super().start_round(
            session, round_num=round_num, counted=counted, started_at=started_at
        )
        self._round_num[rid] = round_num
        self._tell(round_num, None)
        return rid

    def record_step(self, round_: int, *, turn_num: int, **values: Any) -> None:
        super().record_step(round_, turn_num=turn_num, **values)
        self._tell(self._round_num.get(round_, 0), turn_num)

    def _tell(self, round_num: int, turn: int | None) -> None:
        try:
            self._report(self._key, round_num, turn)
        except Exception:  # noqa: BLE001 - progress is best effort
            log.debug("progress of %s not reported", self._key, exc_info=True)


def _registry(job: Job) -> Any:
    if not job.texts:
        for f in job.files:
            if not Path(f).is_file():
                raise ValueError(
                    f"{f}: no such file on this machine ({socket.gethostname()}); the job "
                    f"needs it for instance {job.instance}"
                )
        return _registry_from(job, job.files)
    with tempfile.TemporaryDirectory(prefix="ippc-job-") as tmp:
        paths = []
        for i, (name, text) in enumerate(zip(job.files, job.texts, strict=True)):
            folder = Path(tmp) / str(i)
            folder.mkdir()
            path = folder / Path(name).name
            path.write_text(text, encoding="utf-8")
            paths.append(str(path))
        try:
            return _registry_from(job, tuple(paths))
        except ValueError as err:  # name the experiment's files, not the copies
            text = str(err)
            for copy, name in zip(paths, job.files, strict=True):
                text = text.replace(copy, name)
            raise ValueError(text) from None


def _registry_from(job: Job, files: tuple[str, ...]) -> Any:
    from ..rddl import check_files, check_pair
    from ..server.registry import Instance, Registry, build_task

    results = check_pair(*files) if job.paired else check_files(*files)
    for res in results:
        if res.kind == "instance" and res.name == job.instance:
            if res.model is None:
                why = res.diagnostics[0].render() if res.diagnostics else "does not check"
                raise ValueError(f"instance {job.instance} does not check: {why}")
            return Registry(
                {job.instance: Instance(job.instance, res.model, build_task(res.model))}
            )
    raise ValueError(f"instance {job.instance} is no longer in {', '.join(job.files)}")


def play_job(
    job: Job, report: Reporter | None = None, *, cancel: threading.Event | None = None
) -> JobResult:
    """Play the job in a child process that is stopped at the session's budget plus
    the job's grace, or killed over its memory budget (see the module doc); never
    raises for what the job does. `report` hears of its rounds and turns; `cancel` set
    stops the child and gives status ``interrupted``."""
    from ..client.guard import default_memory_budget, run_guarded

    started = time.time()
    memory = job.memory_mb
    if memory is None:
        memory = default_memory_budget(os.cpu_count() or 1)
        job = replace(job, memory_mb=memory)  # the planner sizes itself from it
    limit = job.timeout + job.grace
    # loading and checking the instance comes first and is not the session's time: the
    # limit starts again when the server opens the session
    session_at: list[float] = []

    def heard(msg: Any) -> float | None:
        if msg[0] == "session":
            session_at.append(time.monotonic())
            return limit
        if msg[0] == "progress" and report is not None:
            try:
                report(job.key, msg[1], msg[2])
            except Exception:  # noqa: BLE001 - progress is best effort
                log.debug("progress of %s not reported", job.key, exc_info=True)
        return None

    log_path = _log_path(job, "session")
    out = run_guarded(
        "ippc.batch.jobs:_job_in_child",
        job,
        seconds=limit + LOAD_ALLOWANCE,
        memory_mb=memory,
        on_message=heard,
        log_path=log_path,
        cancel=cancel,
    )
    ended = time.time()
    if out.status == "ok":
        result: JobResult = out.value
        return result
    if out.status == "timeout":
        if session_at:
            why = (
                f"the session was still running {time.monotonic() - session_at[0]:.0f} s after "
                f"it began (its budget {job.timeout:g} s, plus {job.grace:g} s grace); the "
                "planner's process was stopped and none of its rounds recorded"
            )
        else:
            why = (
                f"no session had begun {out.seconds:.0f} s after the job started (loading the "
                f"instance: limit {limit + LOAD_ALLOWANCE:g} s); stopped"
            )
        return JobResult(job.key, "timeout", why, started, ended)
    if out.status == "interrupted":
        return JobResult(job.key, "interrupted", "stopped by Ctrl-C", started, ended)
    reason = out.reason or "the planner's process failed"
    if out.status == "memory":
        reason += "; none of its rounds recorded"
    if log_path is not None and out.status != "ok":
        reason += f" (log: {log_path})"
    return JobResult(job.key, "failed", reason, started, ended)


def _job_in_child(job: Job, send: Callable[[Any], None]) -> JobResult:
    """`run_job` in the guard's child: progress and the session's start go to `send`."""
    queue = _SendQueue(send)
    return run_job(job, ProgressQueue(queue), on_session=lambda: send(("session",)))


class _SendQueue:
    """A queue's ``put_nowait`` over the guard's `send`, for `ProgressQueue`."""

    def __init__(self, send: Callable[[Any], None]) -> None:
        self._send = send

    def put_nowait(self, item: tuple[str, int, int | None]) -> None:
        self._send(("progress", item[1], item[2]))


def run_job(
    job: Job,
    report: Reporter | None = None,
    *,
    on_session: Callable[[], None] | None = None,
) -> JobResult:
    """Play the job's session in this process (see the module doc); never raises for a
    failed session. `report` hears of each round and turn of a session played against
    the job's own server (one played against ``--server`` is not seen turn by turn);
    `on_session` of the session's start."""
    started = time.time()
    try:
        if job.server is not None:
            if on_session is not None:
                on_session()
            return _run_against(job, started)
        return _run_own_server(job, started, report, on_session)
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as err:
        # Ctrl-C that arrives while trio runs a task reaches us inside an exception
        # group: it is still Ctrl-C (the batch stops), not a failed job
        if isinstance(err, BaseExceptionGroup) and err.subgroup(KeyboardInterrupt) is not None:
            raise KeyboardInterrupt from None
        if not isinstance(err, Exception):
            raise
        # a bug or a broken instance must not stop the batch
        log.debug("job %s failed", job.key, exc_info=True)
        return JobResult(job.key, "failed", _leaf_text(err), started, time.time())


def _run_own_server(
    job: Job,
    started: float,
    report: Reporter | None = None,
    on_session: Callable[[], None] | None = None,
) -> JobResult:
    from ..server.app import serve
    from ..server.config import ServerConfig
    from ..server.session import Services

    registry = _registry(job)
    config = ServerConfig(
        host="127.0.0.1",
        port=0,
        rounds=job.rounds,
        seed=job.server_seed,
        timeout=job.timeout,
        individual_session=True,
    )
    store = (
        ResultStore(":memory:", owner=f"batch:{job.key}")
        if report is None and on_session is None
        else _ReportingStore(job.key, report or (lambda *_: None), on_session)
    )
    services = Services(config, registry, store=store)
    try:

        async def play() -> str | None:
            async with trio.open_nursery() as nursery:
                port = await nursery.start(partial(serve, config, registry, services=services))
                problem = await _play_client(job, "127.0.0.1", port)
                nursery.cancel_scope.cancel()
            return problem

        problem = trio.run(play)
        return _result_from_store(job, store, problem, started)
    finally:
        store.close()


async def _play_client(job: Job, host: str, port: int) -> str | None:
    """Play the session with the job's planner; a problem the client saw, or None."""
    hard = job.timeout + HARD_LIMIT_GRACE
    spec = job.planner
    if spec.command is not None:
        return await _play_command(job, host, port, hard)
    from ..client.session import ClientConfig, ClientError, run_session
    from ..planners.base import ExternalPlanner, PlannerError, find_planner, make_planner

    options = dict(spec.options)
    assert spec.planner is not None
    cls = find_planner(spec.planner)
    if "seed" in cls.options and "seed" not in options:
        options["seed"] = str(job.planner_seed)
    _planner_memory(job, cls.options, options)
    try:
        agent = make_planner(spec.planner, options)
    except PlannerError as err:
        return str(err)
    if isinstance(agent, ExternalPlanner):
        log_path = _log_path(job)
        res = await trio.to_thread.run_sync(
            partial(
                agent.run_session,
                host=host,
                port=port,
                instance=job.instance,
                client_name=None,
                timeout=hard,
                log_path=log_path,
            )
        )
        return res.error
    config = ClientConfig(
        host=host,
        port=port,
        instance=job.instance,
        client_name=spec.label,
        seed=job.planner_seed,
        timeout=hard,
    )
    try:
        with trio.fail_after(hard):
            await run_session(config, agent, spec.label)
    except trio.TooSlowError:
        return f"the session was still running {hard:g} s after it started; stopped"
    except (ClientError, PlannerError) as err:
        return str(err)
    except Exception as err:  # a bug in the planner: this session fails, with its words
        log.debug("planner %s raised", spec.label, exc_info=True)
        return f"the planner raised {_leaf_text(err)}"
    return None


#: Share of a job's memory budget given to a planner that sizes its working memory
#: (its option ``memory``, MiB) when the experiment does not set it: the rest is the
#: process itself (Python, the server, the compiled instance).
PLANNER_MEMORY_SHARE = 0.75


def _planner_memory(job: Job, declared: dict[str, str], options: dict[str, str]) -> None:
    """Give a planner that declares a ``memory`` option its share of the job's budget."""
    if job.memory_mb is not None and "memory" in declared and "memory" not in options:
        options["memory"] = f"{max(1.0, PLANNER_MEMORY_SHARE * job.memory_mb):.0f}"


def _leaf_text(err: BaseException) -> str:
    """``Type: message`` of an error, looking inside exception groups of one error
    (trio's nurseries wrap what their tasks raise)."""
    while isinstance(err, BaseExceptionGroup) and len(err.exceptions) == 1:
        err = err.exceptions[0]
    return f"{type(err).__name__}: {err}"


def _log_path(job: Job, what: str = "") -> Path | None:
    """The job's log file in its log folder: the planner's own output (an external
    command, PROST), or with `what` the guarded process's log (``KEY.session.log``)."""
    if job.log_dir is None:
        return None
    folder = Path(job.log_dir)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:  # a worker elsewhere, where the batch's folder cannot be made
        return None
    safe = "".join(c if c.isalnum() or c in "._-@" else "_" for c in job.key)
    return folder / (f"{safe}.{what}.log" if what else f"{safe}.log")


async def _play_command(job: Job, host: str, port: int, hard: float) -> str | None:
    assert job.planner.command is not None
    argv = fill_command(
        job.planner.command,
        {
            "host": host,
            "port": port,
            "instance": job.instance,
            "seed": job.planner_seed,
            "rounds": job.rounds,
            "timeout": f"{job.timeout:g}",
            "name": job.planner.label,
        },
    )
    log_path = _log_path(job)
    out = open(log_path, "wb") if log_path is not None else subprocess.DEVNULL  # noqa: SIM115

    async def stop(process: trio.Process) -> None:
        # SIGINT first: rddl-client turns it into KeyboardInterrupt and stops what it
        # launched (PROST's own process group); then the whole group gets SIGKILL.
        for sig, wait in ((signal.SIGINT, 5.0), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(process.pid, sig)
            except (ProcessLookupError, PermissionError):
                return
            with trio.move_on_after(wait):
                await process.wait()
                return

    try:
        with trio.move_on_after(hard) as scope:
            proc = await trio.run_process(
                argv,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                check=False,
                start_new_session=True,
                deliver_cancel=stop,
            )
    except OSError as err:
        return f"cannot start {argv[0]}: {err}"
    finally:
        if log_path is not None:
            out.close()  # type: ignore[union-attr]
    where = f" (output: {log_path})" if log_path is not None else ""
    if scope.cancelled_caught:
        return f"the command was still running {hard:g} s after it started; stopped{where}"
    if proc.returncode != 0:
        return f"the command exited with status {proc.returncode}{where}"
    return None


def _result_from_store(job: Job, store: Any, problem: str | None, started: float) -> JobResult:
    sessions = store.sessions()
    ended = time.time()
    if not sessions:
        why = problem or "no session was played (the planner never asked for the instance)"
        return JobResult(job.key, "failed", why, started, ended)
    session = sessions[-1]
    rounds = []
    for rnd in store.rounds(session["id"]):
        steps = store.steps(rnd["id"])
        for step in steps:
            step["state"] = encode_fluents(step["state"])
            step["actions"] = encode_fluents(step["actions"])
        rnd["steps"] = steps
        rounds.append(rnd)
    status = session["status"]
    if status == "finished":
        # the session ended well; a client that complained afterwards is only noted
        return JobResult(job.key, "finished", problem, started, ended, session, rounds)
    if status == "timeout":
        reason = (
            f"the session's budget of {job.timeout:g} s ran out after "
            f"{session['rounds_used']} of {job.rounds} rounds"
        )
        return JobResult(job.key, "timeout", reason, started, ended, session, rounds)
    why = session.get("reason") or status
    if problem:
        why = f"{why}; the client: {problem}"
    return JobResult(job.key, "failed", why, started, ended, session, rounds)


def _run_against(job: Job, started: float) -> JobResult:
    """Play against an existing server (``--server``): only what the client sees is
    recorded (round rewards and turns, no steps)."""
    from ..client.session import ClientConfig, ClientError, run_session
    from ..planners.base import ExternalPlanner, PlannerError, find_planner, make_planner

    assert job.server is not None and job.planner.planner is not None
    host, port = job.server
    options = dict(job.planner.options)
    declared = find_planner(job.planner.planner).options
    if "seed" in declared and "seed" not in options:
        options["seed"] = str(job.planner_seed)
    _planner_memory(job, declared, options)
    agent = make_planner(job.planner.planner, options)
    hard = job.timeout + HARD_LIMIT_GRACE
    if isinstance(agent, ExternalPlanner):
        res = agent.run_session(
            host=host,
            port=port,
            instance=job.instance,
            client_name=None,
            timeout=hard,
            log_path=_log_path(job),
        )
        # PROST's log gives round rewards only, not turns or times
        rewards: list[tuple[float, int | None, float | None]] = [
            (r, None, None) for r in res.rounds
        ]
        error = res.error
        total = res.total_reward
    else:
        config = ClientConfig(
            host=host,
            port=port,
            instance=job.instance,
            client_name=job.planner.label,
            seed=job.planner_seed,
            timeout=hard,
        )
        try:
            out = trio.run(run_session, config, agent, job.planner.label)
        except (ClientError, PlannerError) as err:
            return JobResult(job.key, "failed", str(err), started, time.time())
        rewards = [(r.reward, r.turns, r.seconds) for r in out.rounds if not r.training]
        error, total = None, out.total_reward
    ended = time.time()
    session = {
        "server_session_id": 0,
        "instance": job.instance,
        "client_name": job.planner.label,
        "seed": -1,  # the server chose it
        "num_rounds": job.rounds,
        "time_allowed_ms": job.timeout * 1000.0,
        "peer": f"{host}:{port}",
        "no_header": False,
        "started_at": started,
        "ended_at": ended,
        "status": "finished" if error is None else "dropped",
        "total_reward": total,
        "rounds_used": len(rewards),
        "reason": error,
        "owner": f"batch:{job.key}:remote",
    }
    rounds = []
    t = started
    for i, (reward, turns, seconds) in enumerate(rewards, 1):
        t1 = t + (seconds or 0.0)
        rounds.append(
            {
                "round_num": i,
                "counted": True,
                "started_at": t,
                "ended_at": t1,
                "status": "finished",
                "reward": reward,
                "turns_used": turns,
                "steps": [],
            }
        )
        t = t1
    status = "finished" if error is None else "failed"
    return JobResult(job.key, status, error, started, ended, session, rounds)
