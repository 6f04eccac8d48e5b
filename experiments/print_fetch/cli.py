"""`python -m ippc.experiments.print_fetch`: the print-fetching study's commands."""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import click

from .office import EXPERIMENTS, write_instances
from .report import read_rows, write_report
from .run import DOMAIN_FOLDER, RunRow, approaches, run_many

REPORT_FOLDER = Path("reports") / "print_fetch"


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def main() -> None:
    """The paper's print-fetching robot study (docs/print-fetch.md)."""


@main.command()
@click.option(
    "--folder",
    type=click.Path(file_okay=False, path_type=Path),
    default=DOMAIN_FOLDER,
    show_default=True,
    help="Where to write the instance files.",
)
def instances(folder: Path) -> None:
    """Write the experiments' RDDL instances from the office's numbers."""
    folder.mkdir(parents=True, exist_ok=True)
    for path in write_instances(folder):
        click.echo(f"wrote {path}")


def _numbers(text: str) -> list[int]:
    try:
        numbers = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise click.BadParameter(f"{text!r}: experiment numbers, e.g. 1,2,3,4") from None
    bad = [n for n in numbers if n not in EXPERIMENTS]
    if bad:
        raise click.BadParameter(
            f"no experiment {bad[0]} (there are {', '.join(map(str, EXPERIMENTS))})"
        )
    return numbers


@main.command()
@click.option(
    "--experiments",
    "which",
    default="1,2,3,4",
    show_default=True,
    help="Which experiments, by number.",
)
@click.option(
    "--runs",
    default=30,
    show_default=True,
    type=click.IntRange(1),
    help="Runs per approach in experiments 1-3.",
)
@click.option(
    "--prior-runs",
    default=500,
    show_default=True,
    type=click.IntRange(1),
    help="Runs per approach in experiment 4 (the world sampled from the prior).",
)
@click.option(
    "--approach",
    "names",
    multiple=True,
    help="An approach (fast-downward, replan, mcts, prost); repeatable. "
    "Default: all, prost when a binary is given.",
)
@click.option(
    "--prost",
    type=click.Path(exists=True, path_type=Path),
    default=None,
    help="PROST's search program (default $PROST_BIN; without one no PROST runs).",
)
@click.option(
    "--workers",
    default=1,
    show_default=True,
    type=click.IntRange(1),
    help="Processes running runs at once.",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=REPORT_FOLDER,
    show_default=True,
    help="The report's folder.",
)
@click.option("--no-plots", is_flag=True, help="Tables and CSV only.")
def run(which: str, runs: int, prior_runs: int, names: tuple[str, ...], prost: Path | None,
        workers: int, out: Path, no_plots: bool) -> None:  # fmt: skip
    """Run the experiments and write the report."""
    numbers = _numbers(which)
    binary = str(prost) if prost is not None else os.environ.get("PROST_BIN") or None
    try:
        chosen = approaches(names or None, prost=binary)
    except ValueError as err:
        raise click.UsageError(str(err)) from None
    jobs = [
        (n, a.name, i)
        for n in numbers
        for a in chosen
        for i in range(prior_runs if EXPERIMENTS[n].world is None else runs)
    ]
    click.echo(
        f"{len(jobs)} runs: experiments {which}, approaches "
        f"{', '.join(a.name for a in chosen)}, {workers} worker(s)"
    )
    started = time.perf_counter()
    done = [0]

    def progress(row: RunRow) -> None:
        done[0] += 1
        if done[0] % 50 == 0 or done[0] == len(jobs):
            click.echo(f"  {done[0]}/{len(jobs)} runs, {time.perf_counter() - started:.0f} s")
        if row.error:
            click.echo(f"  experiment {row.experiment} {row.approach} run {row.run}: {row.error}",
                       err=True)  # fmt: skip

    rows = run_many(jobs, prost=binary, workers=workers, progress=progress)
    seconds = time.perf_counter() - started
    out.mkdir(parents=True, exist_ok=True)
    # how long the runs took, for `report` to say again
    (out / "run.json").write_text(
        json.dumps({"seconds": round(seconds, 1), "workers": workers, "runs": len(rows)}) + "\n"
    )
    path = write_report(rows, out, seconds=seconds, workers=workers, plots=not no_plots)
    click.echo(f"report: {path} ({seconds:.0f} s)")


@main.command()
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=REPORT_FOLDER,
    show_default=True,
    help="The report's folder (holding runs_detail.csv).",
)
@click.option("--no-plots", is_flag=True, help="Tables and CSV only.")
def report(out: Path, no_plots: bool) -> None:
    """Write the report again from the folder's runs_detail.csv."""
    source = out / "runs_detail.csv"
    if not source.is_file():
        raise click.UsageError(f"{source}: no such file (run the experiments first)")
    meta = out / "run.json"
    timing = json.loads(meta.read_text()) if meta.is_file() else {}
    path = write_report(
        read_rows(source),
        out,
        seconds=timing.get("seconds"),
        workers=timing.get("workers"),
        plots=not no_plots,
    )
    click.echo(f"report: {path}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
