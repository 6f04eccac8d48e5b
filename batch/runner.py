"""Run an experiment: its jobs on this machine or on a Dask cluster, resumable.

`run_batch` registers the experiment's jobs in the result database, skips those already
done (finished, or timed out: their rounds count), hands the others to an executor and
imports each result as it comes back. The executors:

* local (``jobs = N``): N threads of this process, each handing one job at a time to a
  child process of its own (`batch.jobs.play_job`: the child is stopped at the session's
  budget plus the grace, or killed over its memory budget, and the batch goes on);
* a Dask distributed cluster (``cluster="tcp://HOST:PORT"``, or a ``distributed.Client``
  a caller made, such as a test's ``LocalCluster``): each task runs `play_job` on its
  worker, which plays the session in a child process there exactly as a local run does,
  and returns the recorded session, so the results are the same wherever a job ran.
  Jobs carry their RDDL texts: workers need ippc installed, not the experiment's files.

One run at a time per database: `run_batch` holds an exclusive lock on ``DB.lock`` (an
advisory ``flock``, released when the process ends, however it ends) while it plays, and a
second run on the same database is refused at once naming the first one's process, so no
job is played twice at once (a second run would also take the first's running jobs for
left over, and play them again).

An observer (`BatchObserver`, such as the web page's `batch.live.BatchLive`) hears
of the run, of each job handed out, of each local job's rounds and turns (from the job's child
process, through the thread that watches it), and of each result once it is in the
database. A `Progress` (`batch.progress`) hears of the same, for people. What it does
never stops the batch: its errors are logged.

Ctrl-C (KeyboardInterrupt) stops the batch: jobs not started are not started, jobs
running are stopped (their child processes are ended) and marked ``interrupted``, and every job
that finished is already in the database. Running again resumes.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ..client.guard import default_memory_budget
from .experiment import Experiment, ExperimentError
from .instances import ResolvedInstance, resolve_instances
from .jobs import HARD_LIMIT_GRACE, Job, JobResult, Reporter, build_jobs, mean_reward, play_job
from .progress import Progress
from .results import DONE, BatchStore

__all__ = ["BatchObserver", "BatchSummary", "ClusterError", "run_batch"]

log = logging.getLogger(__name__)


#: Seconds to wait for a Dask scheduler given by address before giving up.
SCHEDULER_TIMEOUT = 30.0


class ClusterError(RuntimeError):
    """The Dask scheduler given with ``cluster`` cannot be reached."""


@dataclass(frozen=True)
class BatchSummary:
    """What a run did."""

    total: int  # jobs in the experiment
    skipped: int  # already done before this run (finished or timed out)
    finished: int  # done in this run (finished or timed out)
    failed: int  # failed in this run
    interrupted: bool
    seconds: float
    failed_before: int = 0  # failed in an earlier run and not played again (no retry_failed)
    failures: list[tuple[str, str]] = field(default_factory=list)  # (job key, why) of this run


class BatchObserver(Protocol):
    """What `run_batch` tells an observer, in its own thread (`job_progress` comes from
    another thread of this process)."""

    def batch_started(self, experiment: str, jobs: list[Job], store: BatchStore) -> None: ...

    def job_started(self, job: Job) -> None: ...

    def job_progress(self, key: str, round_num: int, turn: int | None) -> None: ...

    def job_ended(self, result: JobResult) -> None: ...

    def jobs_interrupted(self, keys: Iterable[str], reason: str) -> None: ...

    def batch_ended(self, interrupted: bool) -> None: ...


def _tell(observer: BatchObserver | None, what: str, *args: Any) -> None:
    """Call `observer.what(*args)`; an error is logged, never raised into the batch."""
    if observer is None:
        return
    try:
        getattr(observer, what)(*args)
    except Exception:
        log.exception("the batch's observer failed in %s", what)


def _local(
    jobs: list[Job], n: int, started: Callable[[Job], None], report: Reporter | None = None
) -> Iterator[JobResult]:
    """Up to `n` jobs at once, each in a child process watched by a thread of ours."""
    cancel = threading.Event()
    pool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="batch-job")
    pending = list(jobs)
    running: dict[Future[JobResult], Job] = {}
    try:
        while pending or running:
            # hand out no more than can be played at once, so that "running" is true and
            # a Ctrl-C leaves the rest unstarted
            while pending and len(running) < n:
                job = pending.pop(0)
                running[pool.submit(play_job, job, report, cancel=cancel)] = job
                started(job)
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for fut in done:
                job = running.pop(fut)
                try:
                    yield fut.result()
                except Exception as err:  # a bug of ours in the watching thread
                    log.exception("job %s: its watcher failed", job.key)
                    now = time.time()
                    yield JobResult(
                        job.key, "failed", f"the job's watcher failed: {err!r}", now, now
                    )
    finally:
        cancel.set()  # the watchers end their children at once
        pool.shutdown(wait=True, cancel_futures=True)


def _dask(jobs: list[Job], cluster: Any, started: Callable[[Job], None]) -> Iterator[JobResult]:
    try:
        import distributed
    except ImportError:
        raise ExperimentError(
            ["--cluster needs Dask's distributed package: pip install 'ippc[batch]'"]
        ) from None
    own = isinstance(cluster, str)
    try:
        client = distributed.Client(cluster, timeout=f"{SCHEDULER_TIMEOUT:g}s") if own else cluster
    except (OSError, TimeoutError) as err:
        raise ClusterError(f"cannot reach the Dask scheduler at {cluster}: {err}") from None
    futures = []
    try:
        by_key = {}
        for job in jobs:
            fut = client.submit(
                play_job,
                job,
                pure=False,
                key=f"ippc-batch-{job.key}-{os.getpid()}-{time.time_ns()}",
            )
            by_key[fut.key] = job
            futures.append(fut)
            started(job)
        for fut in distributed.as_completed(futures):
            job = by_key[fut.key]
            try:
                yield fut.result()
            except Exception as err:
                now = time.time()
                yield JobResult(job.key, "failed", f"the Dask task failed: {err!r}", now, now)
    finally:
        unfinished = [f for f in futures if not f.done()]
        if unfinished:
            client.cancel(unfinished)
        if own:
            client.close()


@contextlib.contextmanager
def _run_lock(db: str | Path) -> Iterator[None]:
    """Hold ``DB.lock`` exclusively for the run; `ExperimentError` if another
    process holds it (its pid, written in the file, is named)."""
    if str(db) == ":memory:":
        yield
        return
    path = Path(f"{db}.lock")
    path.parent.mkdir(parents=True, exist_ok=True)  # as the store does for the database
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
            raise ExperimentError(
                [
                    f"{db}: another rddl-batch run (pid {holder}) is playing this database's "
                    "jobs; wait for it to end or stop it (Ctrl-C), then run again to resume"
                ]
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def run_batch(
    experiment: Experiment,
    db: str | Path,
    *,
    jobs: int | None = None,
    cluster: Any = None,
    server: tuple[str, int] | None = None,
    retry_failed: bool = False,
    log_dir: str | Path | None = None,
    progress: Progress | None = None,
    instances: list[ResolvedInstance] | None = None,
    observer: BatchObserver | None = None,
    memory_mb: float | None = None,
    grace: float = HARD_LIMIT_GRACE,
) -> BatchSummary:
    """Play every job of `experiment` not yet done, storing results in `db`.

    ``jobs`` sessions at once on this machine (default: the experiment's ``jobs``),
    or on ``cluster`` (a scheduler address or a ``distributed.Client``). ``server``
    plays against an existing server instead of one per job. Raises `ExperimentError`
    for instances that do not resolve, before anything runs (``instances``: already
    resolved by `check_experiment`). ``observer`` hears of the run as it goes (see the
    module doc); ``progress`` tells people (default: nothing is printed).

    Each job's child process is stopped ``grace`` seconds past its session's budget, or
    killed over ``memory_mb`` MB (default: 80% of the memory available now, shared by
    the jobs played at once; on a cluster, by each worker machine's cores)."""
    t0 = time.monotonic()
    if instances is None:
        instances = resolve_instances(experiment)
    if server is not None:
        commands = [p.label for p in experiment.planners if p.command is not None]
        if commands:
            raise ExperimentError(
                [
                    f"--server: planners given as commands ({', '.join(commands)}) need the batch's own server"
                ]
            )
    n = jobs or experiment.jobs
    if memory_mb is None and cluster is None:
        memory_mb = default_memory_budget(n)
    all_jobs = build_jobs(
        experiment,
        instances,
        log_dir=None if log_dir is None else str(log_dir),
        server=server,
        memory_mb=memory_mb,
        grace=grace,
    )
    with _run_lock(db), BatchStore(db) as store:
        conflicts = store.register(all_jobs)
        if conflicts:
            raise ExperimentError(
                [
                    f"{db}: experiment '{experiment.name}' is there with other seeds for "
                    f"{len(conflicts)} job(s) ({', '.join(conflicts[:3])}...): use another --db "
                    "or another experiment name"
                ]
            )
        if store.reset_running(experiment.name):
            log.info("jobs left running by an earlier batch are played again")
        status = {row.job_key: row.status for row in store.jobs(experiment.name)}
        again = DONE if retry_failed else (*DONE, "failed")
        todo = [j for j in all_jobs if status.get(j.key) not in again]
        skipped = sum(1 for j in all_jobs if status.get(j.key) in DONE)
        failed_before = len(all_jobs) - len(todo) - skipped
        prog = progress or Progress(stream=None)
        prog.start(total=len(all_jobs), done=skipped + failed_before, failed=failed_before)
        finished = failed = 0
        failures: list[tuple[str, str]] = []
        interrupted = False
        _tell(observer, "batch_started", experiment.name, all_jobs, store)
        by_key = {job.key: job for job in todo}

        def started(job: Job) -> None:
            store.mark(experiment.name, [job.key], "running")
            log.info("%s: started", job.key)
            prog.started(job.key)
            _tell(observer, "job_started", job)

        report: Reporter | None = None
        if observer is not None and cluster is None and todo:
            report = observer.job_progress
        if cluster is not None:
            results = _dask(todo, cluster, started)
        else:
            results = _local(todo, n, started, report)
        try:
            for result in results:
                if result.status == "interrupted":
                    raise KeyboardInterrupt  # a watcher saw the cancel: only on Ctrl-C
                store.import_result(experiment.name, result)
                mean = mean_reward(result)
                if result.status in DONE:
                    finished += 1
                    log.info(
                        "%s: %s, %d rounds, mean reward %s%s",
                        result.key,
                        result.status,
                        len(result.rounds),
                        "-" if mean is None else f"{mean:.4f}",
                        f" ({result.reason})" if result.reason else "",
                    )
                else:
                    failed += 1
                    failures.append((result.key, result.reason or result.status))
                    log.info("%s failed: %s", result.key, result.reason)
                job = by_key.get(result.key)
                prog.ended(
                    result.key,
                    result.status,
                    planner=job.planner.label if job else result.key.split("@")[0],
                    instance=job.instance if job else result.key.partition("@")[2],
                    mean=mean,
                    seconds=result.ended_at - result.started_at,
                    reason=result.reason,
                )
                _tell(observer, "job_ended", result)
        except KeyboardInterrupt:
            interrupted = True
            close = getattr(results, "close", None)
            if close is not None:
                close()  # stops the workers (the generators' finally)
            running = [r.job_key for r in store.jobs(experiment.name) if r.status == "running"]
            store.mark(experiment.name, running, "interrupted", "stopped by Ctrl-C")
            _tell(observer, "jobs_interrupted", running, "stopped by Ctrl-C")
        finally:
            prog.close()
            _tell(observer, "batch_ended", interrupted)
    return BatchSummary(
        len(all_jobs),
        skipped,
        finished,
        failed,
        interrupted,
        time.monotonic() - t0,
        failed_before,
        failures,
    )
