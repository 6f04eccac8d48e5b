"""The report of the print-fetching experiments, generated from the runs.

`write_report(rows, out)` writes into `out`:

* ``runs.csv``: one row per run with the issue's columns (experiment, approach, run,
  success, first_printer, distance_m, execution_s, planning_s, failed_actions, replans);
* ``runs_detail.csv``: the same runs with every field (steps, seed, reward, error), from
  which ``python -m ippc.experiments.print_fetch report`` writes the report again;
* ``summary.csv``: per experiment and approach, the runs, the successes, and the mean and
  95% confidence half-width of each measure;
* ``first_printer.csv``: per experiment and approach, how often each printer was the first
  the robot drove to, with 95% Wilson intervals;
* ``distance.{png,svg}``, ``execution.{png,svg}``, ``planning.{png,svg}``: box plots per
  experiment and approach; ``first_printer.{png,svg}``: experiment 4's distribution;
* ``report.md``: the setup, the tables and the figures.

Nothing in it is typed in: every number comes from the rows and from the model's and the
office's constants. matplotlib draws the figures (the ``batch`` extra), without a display.
"""

from __future__ import annotations

import csv
import math
import statistics
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

# rddl-batch's report helpers: matplotlib without a display, PNG + SVG per figure
from ...batch.report import _pyplot
from ...batch.report import _save as save_figure
from ...batch.scoring import ci95
from .office import EXPERIMENTS, PRINTERS, WAYPOINTS
from .run import TIME_PER_STEP, RunRow

__all__ = ["read_rows", "wilson", "write_report"]

MEASURES = (
    ("distance_m", "distance", "travel distance (m)"),
    ("execution_s", "execution", "simulated execution time (s)"),
    ("planning_s", "planning", "planning time, summed over the run's turns (s)"),
)


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a proportion (95% by default)."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def _write_csv(path: Path, header: Sequence[str], rows: list[list[Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


def read_rows(path: Path) -> list[RunRow]:
    """The runs of a ``runs_detail.csv``."""
    with path.open(newline="", encoding="utf-8") as f:
        return [RunRow.from_dict(row) for row in csv.DictReader(f)]


def _groups(rows: list[RunRow]) -> dict[tuple[int, str], list[RunRow]]:
    out: dict[tuple[int, str], list[RunRow]] = defaultdict(list)
    for r in rows:
        out[(r.experiment, r.approach)].append(r)
    return dict(out)


def _mean_ci(values: list[float]) -> tuple[float, float | None]:
    return (statistics.fmean(values) if values else math.nan, ci95(values))


def _fmt(mean: float, half: float | None, digits: int = 1) -> str:
    if math.isnan(mean):
        return "-"
    return f"{mean:.{digits}f}" + ("" if half is None else f" ± {half:.{digits}f}")


def _save(plt: Any, fig: Any, out: Path, stem: str) -> None:
    save_figure(fig, out, stem)  # PNG and SVG, as rddl-batch's report writes them
    plt.close(fig)


def _box_plots(rows: list[RunRow], out: Path, approaches: list[str], numbers: list[int]) -> None:
    plt = _pyplot()
    groups = _groups(rows)
    for field, stem, label in MEASURES:
        fig, axes = plt.subplots(1, len(numbers), figsize=(3.2 * len(numbers), 3.4), squeeze=False)
        for ax, number in zip(axes[0], numbers, strict=True):
            data = [[getattr(r, field) for r in groups.get((number, a), [])] for a in approaches]
            ax.boxplot(data, showmeans=True)
            ax.set_xticks(range(1, len(approaches) + 1), approaches, rotation=30, ha="right")
            ax.set_title(f"experiment {number}")
            ax.grid(axis="y", alpha=0.3)
        axes[0][0].set_ylabel(label)
        fig.tight_layout()
        _save(plt, fig, out, stem)


def _first_printer_plot(
    counts: dict[str, Counter[str]], totals: dict[str, int], out: Path, number: int
) -> None:
    plt = _pyplot()
    printers = list(PRINTERS)
    names = list(counts)
    fig, ax = plt.subplots(figsize=(6, 3.4))
    width = 0.8 / max(1, len(names))
    for i, name in enumerate(names):
        n = totals[name]
        shares = [counts[name][p] / n if n else 0.0 for p in printers]
        lows, highs = zip(*(wilson(counts[name][p], n) for p in printers), strict=True)
        # (at a share of 0 or 1 the interval's end equals it up to rounding: never below 0)
        err = [
            [max(0.0, s - lo) for s, lo in zip(shares, lows, strict=True)],
            [max(0.0, hi - s) for s, hi in zip(shares, highs, strict=True)],
        ]
        xs = [j + (i - (len(names) - 1) / 2) * width for j in range(len(printers))]
        ax.bar(xs, shares, width, yerr=err, capsize=3, label=f"{name} (n={n})")
    ax.set_xticks(range(len(printers)), printers)
    ax.set_ylim(0, 1)
    ax.set_ylabel("share of runs (95% Wilson interval)")
    ax.set_title(f"experiment {number}: the first printer the robot drives to")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    _save(plt, fig, out, "first_printer")


def write_report(
    rows: list[RunRow],
    out: str | Path,
    *,
    seconds: float | None = None,
    workers: int | None = None,
    plots: bool = True,
) -> Path:
    """Write the report of `rows` into folder `out` (created); the path of
    ``report.md``. `seconds` and `workers`: how long the runs took, on how
    many processes (said in the report when given)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    numbers = sorted({r.experiment for r in rows})
    approaches = list(dict.fromkeys(r.approach for r in rows))
    groups = _groups(rows)

    _write_csv(
        out / "runs.csv",
        RunRow.CSV_COLUMNS,
        [[getattr(r, c) for c in RunRow.CSV_COLUMNS] for r in rows],
    )
    detail = list(rows[0].as_dict()) if rows else list(RunRow.CSV_COLUMNS)
    _write_csv(out / "runs_detail.csv", detail, [list(r.as_dict().values()) for r in rows])

    summary_header = ["experiment", "approach", "runs", "successes"]
    for field in ("steps", "distance_m", "execution_s", "planning_s", "failed_actions", "replans"):
        summary_header += [f"{field}_mean", f"{field}_ci95"]
    summary: list[list[Any]] = []
    lines = [
        "# The print-fetching robot: experiments",
        "",
        "Generated by `python -m ippc.experiments.print_fetch` from the runs in `runs.csv` "
        "(docs/print-fetch.md explains the setup and compares the results with the paper).",
        "",
        "## Setup",
        "",
        f"- Office: {', '.join(f'{w} {xy}' for w, xy in WAYPOINTS.items())} (metres).",
        "- Printers (busy rate, somebody-nearby rate): "
        + ", ".join(f"{p} ({b}, {s})" for p, (b, s) in PRINTERS.items())
        + ".",
        f"- Search time per turn: {TIME_PER_STEP} s for `mcts`, `replan` and PROST; "
        "Fast Downward runs to a cost-optimal plan.",
        "- One round per run, horizon 20; a run succeeds when the papers are delivered.",
    ]
    for number in numbers:
        e = EXPERIMENTS[number]
        if e.world is None:
            world = "sampled from the rates every step"
        else:
            world = ", ".join(
                f"{p} {'busy' if w.busy else 'free'}/{'somebody' if w.somebody else 'nobody'}"
                for p, w in e.world.items()
            )
        lines.append(f"- Experiment {number}: {e.start} → {e.destination}; world: {world}.")
    if seconds is not None:
        lines.append(
            f"- {len(rows)} runs in {seconds:.0f} s of wall time"
            + (f" on {workers} worker process(es)." if workers else ".")
        )
    lines += [
        "",
        "## Results",
        "",
        "Mean ± 95% confidence half-width (1.96 standard errors) over the runs.",
        "",
        "| exp | approach | runs | success | steps | distance (m) | execution (s) "
        "| planning (s) | failed actions | replans |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for number in numbers:
        for name in approaches:
            group = groups.get((number, name), [])
            if not group:
                continue
            wins = sum(r.success for r in group)
            row: list[Any] = [number, name, len(group), wins]
            cells = []
            for field in (
                "steps",
                "distance_m",
                "execution_s",
                "planning_s",
                "failed_actions",
                "replans",
            ):
                mean, half = _mean_ci([float(getattr(r, field)) for r in group])
                row += [round(mean, 4), None if half is None else round(half, 4)]
                digits = 2 if field in ("planning_s", "failed_actions", "replans") else 1
                cells.append(_fmt(mean, half, digits))
            summary.append(row)
            lines.append(
                f"| {number} | {name} | {len(group)} | {wins}/{len(group)} | "
                + " | ".join(cells)
                + " |"
            )
    _write_csv(out / "summary.csv", summary_header, summary)

    # the first printer: every experiment in the CSV, experiment 4 in the text and plot
    first_rows: list[list[Any]] = []
    for number in numbers:
        for name in approaches:
            group = groups.get((number, name), [])
            if not group:
                continue
            counts = Counter(r.first_printer for r in group)
            for p in [*PRINTERS, ""]:
                lo, hi = wilson(counts[p], len(group))
                first_rows.append(
                    [
                        number,
                        name,
                        p or "none",
                        counts[p],
                        len(group),
                        counts[p] / len(group),
                        lo,
                        hi,
                    ]
                )
    _write_csv(
        out / "first_printer.csv",
        ["experiment", "approach", "printer", "runs", "of", "share", "ci95_low", "ci95_high"],
        first_rows,
    )
    lines += ["", "## The first printer", ""]
    prior = [n for n in numbers if EXPERIMENTS[n].world is None]
    for number in prior or numbers[-1:]:
        lines += [
            f"Experiment {number}: the share of runs in which each printer was the first the "
            "robot drove to (95% Wilson interval).",
            "",
            "| approach | runs | " + " | ".join(PRINTERS) + " | none |",
            "|---|---|" + "---|" * (len(PRINTERS) + 1),
        ]
        counts_by: dict[str, Counter[str]] = {}
        totals: dict[str, int] = {}
        for name in approaches:
            group = groups.get((number, name), [])
            if not group:
                continue
            counts = Counter(r.first_printer for r in group)
            counts_by[name], totals[name] = counts, len(group)
            cells = []
            for p in [*PRINTERS, ""]:
                lo, hi = wilson(counts[p], len(group))
                cells.append(f"{counts[p] / len(group):.3f} [{lo:.3f}, {hi:.3f}]")
            lines.append(f"| {name} | {len(group)} | " + " | ".join(cells) + " |")
        if plots and counts_by:
            _first_printer_plot(counts_by, totals, out, number)
            lines += ["", "![first printer](first_printer.svg)"]
        lines.append("")
    lines += ["## Figures", ""]
    if plots and rows:
        _box_plots(rows, out, approaches, numbers)
        for _, stem, label in MEASURES:
            lines += [
                f"{label.capitalize()}, per experiment and approach:",
                "",
                f"![{stem}]({stem}.svg)",
                "",
            ]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
