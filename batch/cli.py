"""``rddl-batch``: run competition-style experiments, score them, write a report."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import Any

import click

from ..client.options import budget_options
from ..server.store import StoreError
from ..web import WebOptions, web_options, web_url
from .experiment import ExperimentError
from .instances import check_experiment
from .progress import format_duration
from .results import BatchStore, RoundRecord
from .scoring import RULES, ScoreError, ScoreTable, score

__all__ = ["main"]

DEFAULT_DB = Path("results.sqlite")
_DB = click.option(
    "--db",
    type=click.Path(dir_okay=False, path_type=Path),
    default=DEFAULT_DB,
    show_default=True,
    help="The SQLite result database (the schema rddl-server writes, with rddl-batch's jobs).",
)
# score and report: without --db but with --rddlsim-log, only the logs are read (a
# results.sqlite that happens to be in the folder is not mixed in)
_READ_DB = click.option(
    "--db",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help=f"The result database to score (default: {DEFAULT_DB}, unless --rddlsim-log is given).",
)
_RULES = click.option(
    "--rules",
    type=click.Choice(sorted(RULES)),
    default="ippc2014",
    show_default=True,
    help="Which competition's scoring rules (see docs/batch.md).",
)


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def main() -> None:
    """Competition-style experiments: planners x instances x rounds, IPPC scores, reports."""


def _open_store(db: Path) -> BatchStore:
    """The database, or a one-line error naming it (not SQLite, a newer schema)."""
    try:
        return BatchStore(db)
    except (StoreError, OSError) as err:
        raise click.ClickException(f"--db {db}: {err}") from None


def _host_port(value: str | None, what: str) -> tuple[str, int] | None:
    if value is None:
        return None
    host, sep, port = value.rpartition(":")
    if not sep or not port.isdigit():
        raise click.BadParameter(f"{value!r} is not HOST:PORT", param_hint=what)
    return host or "127.0.0.1", int(port)


@main.command()
@click.argument("experiment_file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@_DB
@click.option(
    "--jobs",
    "-j",
    type=click.IntRange(min=1),
    default=None,
    help="Sessions at once (default: the file's jobs).",
)
@click.option(
    "--cluster",
    metavar="tcp://HOST:PORT",
    default=None,
    help="Run the sessions on this Dask scheduler.",
)
@click.option(
    "--server",
    metavar="HOST:PORT",
    default=None,
    help="Play against this server instead of one per session.",
)
@click.option("--retry-failed", is_flag=True, help="Play failed sessions again too.")
@click.option(
    "--logs",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder for external planners' output (default: DB.logs beside the database).",
)
@budget_options(
    memory_help="Resident memory a job's process may hold before it is killed and the job "
    "failed (default: 80% of the memory available at start, shared by the jobs at once).",
    grace_default=60.0,
    grace_help="How long a session may run past its budget before its process is stopped and "
    "the job recorded as timed out.",
)
@click.option("-v", "--verbose", is_flag=True, help="Log every session.")
@web_options
@click.option(
    "--rules",
    type=click.Choice(sorted(RULES)),
    default="ippc2014",
    show_default=True,
    help="With --web: the scoring rules of the page's live scores.",
)
def run(
    experiment_file: Path,
    db: Path,
    jobs: int | None,
    cluster: str | None,
    server: str | None,
    retry_failed: bool,
    logs: Path | None,
    memory_mb: float | None,
    grace: float,
    verbose: bool,
    web: int | None,
    web_host: str | None,
    rules: str,
) -> None:
    """Play every planner on every instance of EXPERIMENT_FILE; again, to resume."""
    from .progress import Progress
    from .runner import ClusterError, run_batch

    _setup_logging(verbose)
    if cluster is not None and server is not None:
        raise click.UsageError("--cluster and --server do not go together")
    options = WebOptions.from_cli(web, web_host)
    page = summary = None
    try:
        experiment, instances = check_experiment(experiment_file)  # every problem at once
        observer = None
        if options is not None:
            page, observer = _start_page(options, rules)
        summary = run_batch(
            experiment,
            db,
            instances=instances,
            jobs=jobs,
            cluster=cluster,
            server=_host_port(server, "--server"),
            retry_failed=retry_failed,
            log_dir=logs or db.with_name(db.name + ".logs"),
            observer=observer,
            progress=Progress(stream=sys.stderr),
            memory_mb=memory_mb,
            grace=grace,
        )
    except ExperimentError as err:
        for problem in err.problems:
            click.echo(problem, err=True)
        raise SystemExit(2) from None
    except StoreError as err:
        raise click.ClickException(f"--db {db}: {err}") from None
    except ClusterError as err:
        raise click.ClickException(f"--cluster: {err}") from None
    finally:
        if page is not None and (summary is None or summary.interrupted):
            page.stop()  # (a run that ended keeps its page up: below)
    done = summary.skipped + summary.finished
    failed = f"{summary.failed} failed"
    if summary.failed_before:
        failed += (
            f" ({summary.failed_before} more failed before and were not played again:"
            " --retry-failed)"
        )
    click.echo(
        f"{experiment.name}: {done}/{summary.total} sessions done ({summary.finished} now, "
        f"{summary.skipped} before), {failed}, {format_duration(summary.seconds)}; "
        f"results in {db}"
    )
    if summary.interrupted:
        click.echo("interrupted: run the same command again to resume", err=True)
        raise SystemExit(130)
    if page is not None:
        page.keep_up(say=lambda line: click.echo(line, err=True))  # until Ctrl-C/SIGTERM
    if summary.failures:
        shown = summary.failures[:20]
        click.echo(f"{len(summary.failures)} job(s) failed:", err=True)
        for key, why in shown:
            click.echo(f"  {key}: {why}", err=True)
        if len(summary.failures) > len(shown):
            click.echo(f"  ... and {len(summary.failures) - len(shown)} more", err=True)
        click.echo(f"(their reasons are in {db}; --retry-failed plays them again)", err=True)
        raise SystemExit(1)


def _start_page(options: WebOptions, rules: str) -> tuple[Any, Any]:
    """The web page of a run (in a thread of its own, see batch/web.py) and its observer."""
    from .live import BatchLive
    from .web import BatchWeb

    live = BatchLive(rules)
    page = BatchWeb(live, options)
    try:
        port = page.start()
    except OSError as err:
        raise click.ClickException(
            f"--web: cannot listen on {options.host}:{options.port}: {err.strerror or err}"
        ) from None
    click.echo(f"web view on {web_url(options, port)}", err=True)
    return page, live


def _database(db: Path | None, logs: tuple[Path, ...]) -> Path | None:
    """The database score and report read: --db, else results.sqlite unless only
    rddlsim logs are given; None when there is none to read."""
    if db is None:
        return None if logs else DEFAULT_DB
    return db if db.exists() or not logs else None


def _records(
    db: Path | None, logs: tuple[Path, ...], experiment: str | None
) -> tuple[list[RoundRecord], list[tuple[str, str, str]]]:
    from .rddlsim_log import RddlsimLogError, read_rddlsim_log

    records: list[RoundRecord] = []
    expected: list[tuple[str, str, str]] = []
    if db is not None:
        if not db.exists():
            raise click.ClickException(f"--db {db}: no such file")
        with _open_store(db) as store:
            if experiment is not None and experiment not in store.experiments():
                known = ", ".join(store.experiments()) or "none"
                raise click.ClickException(
                    f"--experiment {experiment}: not in {db} (experiments there: {known})"
                )
            records += store.round_records(experiment)
            expected += store.expected(experiment)
    for path in logs:
        try:
            records += read_rddlsim_log(path)
        except RddlsimLogError as err:
            raise click.ClickException(str(err)) from None
    return records, expected


def _table(
    db: Path | None, logs: tuple[Path, ...], experiment: str | None, rules: str, rounds: int | None
) -> tuple[ScoreTable, list[RoundRecord]]:
    records, expected = _records(db, logs, experiment)
    try:
        return score(records, rules, expected_rounds=rounds, expected=expected), records
    except ScoreError as err:
        raise click.ClickException(str(err)) from None


_LOGS = click.option(
    "--rddlsim-log",
    "rddlsim_logs",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Also score the round-ends of this rddlsim log file (repeatable).",
)
_EXPERIMENT = click.option(
    "--experiment", default=None, help="Only this experiment of the database."
)
_ROUNDS = click.option(
    "--rounds",
    type=click.IntRange(min=1),
    default=None,
    help="Rounds per instance to score (default: the sessions' rounds, else 30).",
)


@main.command(name="score")
@_READ_DB
@_RULES
@_LOGS
@_EXPERIMENT
@_ROUNDS
@click.option("--json", "as_json", is_flag=True, help="Print the scores as JSON.")
def score_cmd(
    db: Path | None,
    rules: str,
    rddlsim_logs: tuple[Path, ...],
    experiment: str | None,
    rounds: int | None,
    as_json: bool,
) -> None:
    """Print IPPC scores per planner (overall and per domain)."""
    _setup_logging(False)
    db = _database(db, rddlsim_logs)
    table, _ = _table(db, rddlsim_logs, experiment, rules, rounds)
    if as_json:
        click.echo(json.dumps(table.as_json(), indent=2))
        return
    click.echo(f"IPPC scores ({rules}: {RULES[rules].source})")
    click.echo(f"{'planner':<16} {'score':>7} {'95% CI':>7} {'instances':>9}")
    for planner, mean, band, n in table.overall():
        click.echo(
            f"{planner:<16} {mean:>7.3f} {('-' if band is None else f'{band:.3f}'):>7} {n:>9}"
        )
    click.echo("")
    click.echo(f"{'domain':<28} {'planner':<16} {'score':>7} {'95% CI':>7}")
    for domain, planner, mean, band, _n in table.per_domain():
        click.echo(
            f"{domain:<28} {planner:<16} {mean:>7.3f} {('-' if band is None else f'{band:.3f}'):>7}"
        )
    for instance, why in table.skipped.items():
        click.echo(f"not scored: {instance}: {why}", err=True)


@main.command()
@_READ_DB
@_RULES
@_LOGS
@_EXPERIMENT
@_ROUNDS
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Folder for the report.",
)
@click.option("--title", default="rddl-batch report", show_default=True)
def report(
    db: Path | None,
    rules: str,
    rddlsim_logs: tuple[Path, ...],
    experiment: str | None,
    rounds: int | None,
    out: Path,
    title: str,
) -> None:
    """Write a Markdown report with score tables, CSV/JSON data and plots into --out."""
    from .report import write_report

    _setup_logging(False)
    db = _database(db, rddlsim_logs)
    table, records = _table(db, rddlsim_logs, experiment, rules, rounds)
    times: list[tuple[str, str, str, float]] = []
    if db is not None:
        with _open_store(db) as store:
            times = store.turn_times(experiment)
    try:
        path = write_report(table, records, times, out, title=title)
    except RuntimeError as err:
        raise click.ClickException(str(err)) from None
    click.echo(f"report written to {path}")


if __name__ == "__main__":
    main()
