"""The report of a batch: Markdown tables, CSV and JSON of every figure, PNG and SVG plots.

`write_report` writes into one folder:

* ``report.md``: the overall and per-domain IPPC scores, the per-instance table (mean
  reward, rounds, score) and the three figures;
* ``scores.json`` (as ``rddl-batch score --json``), ``scores.csv``, ``domains.csv``;
* ``score_per_instance.{png,svg,csv,json}``: each planner's score on each instance;
* ``reward_per_round.{png,svg,csv,json}``: per instance, each planner's running mean of
  the round rewards with its 95% band (1.96 standard errors), round by round;
* ``time_per_turn.{png,svg,csv,json}``: the seconds each planner took per turn (from
  the server's records: the turn sent to the actions received), mean per domain.

matplotlib is only needed here (the ``batch`` extra); it draws without a display (Agg).
"""

from __future__ import annotations

import csv
import json
import math
import statistics
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from .results import RoundRecord
from .scoring import ScoreTable, ci95

__all__ = ["write_report"]


def _write_csv(path: Path, header: list[str], rows: list[list[Any]]) -> None:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


def _fmt(x: float | None, digits: int = 3) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def reward_curves(
    records: list[RoundRecord], rules_counted_only: bool = False
) -> dict[str, dict[str, list[tuple[int, float, float | None]]]]:
    """instance -> planner -> [(round k, running mean of rounds 1..k, ci95 of them)]."""
    by: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        if r.counted or not rules_counted_only:
            by[r.instance][r.planner].append(r.reward)
    out: dict[str, dict[str, list[tuple[int, float, float | None]]]] = {}
    for inst, planners in by.items():
        out[inst] = {}
        for planner, rewards in planners.items():
            out[inst][planner] = [
                (k, statistics.fmean(rewards[:k]), ci95(rewards[:k]))
                for k in range(1, len(rewards) + 1)
            ]
    return out


def _pyplot() -> Any:
    try:
        import matplotlib
    except ImportError:
        raise RuntimeError(
            "the report's plots need matplotlib: pip install 'ippc[batch]'"
        ) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, out: Path, stem: str) -> list[str]:
    names = []
    for ext in ("png", "svg"):
        fig.savefig(out / f"{stem}.{ext}", dpi=110, bbox_inches="tight")
        names.append(f"{stem}.{ext}")
    return names


def write_report(
    table: ScoreTable,
    records: list[RoundRecord],
    turn_times: list[tuple[str, str, str, float]],
    out: str | Path,
    *,
    title: str = "rddl-batch report",
    settings: dict[str, Any] | None = None,
) -> Path:
    """Write the report into folder `out` (created); the path of ``report.md``."""
    plt = _pyplot()
    from matplotlib.ticker import MaxNLocator

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    planners = table.planners()
    instances = list(dict.fromkeys(s.instance for s in table.instances))

    # -- the tables
    (out / "scores.json").write_text(json.dumps(table.as_json(), indent=2) + "\n")
    _write_csv(
        out / "scores.csv",
        ["instance", "domain", "planner", "rounds", "mean", "score"],
        [[s.instance, s.domain, s.planner, s.rounds, s.mean, s.score] for s in table.instances],
    )
    _write_csv(
        out / "domains.csv",
        ["domain", "planner", "score", "ci95", "instances"],
        [list(row) for row in table.per_domain()],
    )

    # -- score per instance
    score_of = {(s.instance, s.planner): s.score for s in table.instances}
    _write_csv(
        out / "score_per_instance.csv",
        ["instance", *planners],
        [[i, *[score_of.get((i, p)) for p in planners]] for i in instances],
    )
    (out / "score_per_instance.json").write_text(
        json.dumps({i: {p: score_of.get((i, p)) for p in planners} for i in instances}, indent=2)
        + "\n"
    )
    fig, ax = plt.subplots(
        figsize=(max(8.0, 0.32 * len(instances) * max(1, len(planners)) / 2), 4.5)
    )
    width = 0.8 / max(1, len(planners))
    for k, planner in enumerate(planners):
        xs = [i + (k - (len(planners) - 1) / 2) * width for i in range(len(instances))]
        ax.bar(xs, [score_of.get((inst, planner), 0.0) for inst in instances], width, label=planner)
    ax.set_xticks(range(len(instances)))
    ax.set_xticklabels(instances, rotation=70, ha="right", fontsize=7)
    ax.set_ylim(0, 1.18)  # room for the legend above the bars
    ax.set_xlim(-0.6, len(instances) - 0.4)
    ax.set_ylabel(f"IPPC score ({table.rules})")
    ax.set_title("Score per instance")
    ax.legend(fontsize=8, ncols=min(len(planners), 6), loc="upper left")
    fig_scores = _save(fig, out, "score_per_instance")
    plt.close(fig)

    # -- reward per round
    curves = reward_curves(records, table.rules == "ippc2018")
    rows = [
        [inst, planner, k, mean, band]
        for inst in instances
        for planner, pts in curves.get(inst, {}).items()
        for k, mean, band in pts
    ]
    _write_csv(
        out / "reward_per_round.csv", ["instance", "planner", "round", "running_mean", "ci95"], rows
    )
    (out / "reward_per_round.json").write_text(json.dumps(curves, indent=1) + "\n")
    cols = min(5, max(1, len(instances)))
    nrows = max(1, math.ceil(len(instances) / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(3.2 * cols, 2.4 * nrows), squeeze=False)
    colors = {p: f"C{k % 10}" for k, p in enumerate(planners)}
    for idx, inst in enumerate(instances):
        ax = axes[idx // cols][idx % cols]
        for planner, pts in curves.get(inst, {}).items():
            ks = [p[0] for p in pts]
            means = [p[1] for p in pts]
            bands = [p[2] or 0.0 for p in pts]
            color = colors.get(planner, "k")
            ax.plot(ks, means, color=color, label=planner, lw=1.2)
            ax.fill_between(
                ks,
                [m - b for m, b in zip(means, bands, strict=True)],
                [m + b for m, b in zip(means, bands, strict=True)],
                color=color,
                alpha=0.18,
                lw=0,
            )
        ax.set_title(inst, fontsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=6)
    for idx in range(len(instances), nrows * cols):
        axes[idx // cols][idx % cols].axis("off")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncols=min(len(labels), 6), fontsize=8)
    fig.supxlabel("round", fontsize=8)
    fig.supylabel("mean round reward so far (95% band)", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig_rewards = _save(fig, out, "reward_per_round")
    plt.close(fig)

    # -- time per turn
    by: dict[tuple[str, str], list[float]] = defaultdict(list)
    for planner, _inst, domain, seconds in turn_times:
        by[(domain, planner)].append(seconds)
    domains = list(dict.fromkeys(d for d, _ in by)) or table.domains()
    stats = {
        f"{d}|{p}": {"mean": statistics.fmean(v), "ci95": ci95(v), "turns": len(v)}
        for (d, p), v in by.items()
    }
    _write_csv(
        out / "time_per_turn.csv",
        ["domain", "planner", "mean_seconds", "ci95", "turns"],
        [[d, p, statistics.fmean(v), ci95(v), len(v)] for (d, p), v in by.items()],
    )
    (out / "time_per_turn.json").write_text(json.dumps(stats, indent=2) + "\n")
    fig, ax = plt.subplots(figsize=(max(7.0, 1.1 * len(domains) * max(1, len(planners)) / 3), 4.0))
    for k, planner in enumerate(planners):
        xs = [i + (k - (len(planners) - 1) / 2) * width for i in range(len(domains))]
        ys = [
            statistics.fmean(by[(d, planner)]) * 1000 if by.get((d, planner)) else 0.0
            for d in domains
        ]
        ax.bar(xs, ys, width, label=planner)
    ax.set_xticks(range(len(domains)))
    ax.set_xticklabels(domains, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("ms per turn (mean)")
    if any(by.values()):
        ax.set_yscale("symlog", linthresh=1.0)
    ax.set_title("Time per turn")
    ax.legend(fontsize=8, ncols=min(len(planners), 6))
    fig_times = _save(fig, out, "time_per_turn")
    plt.close(fig)

    # -- the Markdown
    md = [
        f"# {title}",
        "",
        f"Written {time.strftime('%Y-%m-%d %H:%M %Z')}; scores under `{table.rules}`.",
    ]
    if settings:
        md += ["", "Settings: " + ", ".join(f"{k} = {v}" for k, v in settings.items()) + "."]
    md += ["", "## Overall", "", "| planner | score | 95% CI | instances |", "|---|---:|---:|---:|"]
    for planner, mean, band, n in table.overall():
        md.append(f"| {planner} | {mean:.3f} | {_fmt(band)} | {n} |")
    md += [
        "",
        "## Per domain",
        "",
        "| domain | " + " | ".join(planners) + " |",
        "|---|" + "---:|" * len(planners),
    ]
    dom = {(d, p): (m, c) for d, p, m, c, _ in table.per_domain()}
    for d in table.domains():
        cells = [
            "-"
            if (d, p) not in dom
            # one instance in the domain: no interval ("0.500", not "0.500 ± -")
            else f"{dom[(d, p)][0]:.3f}"
            + ("" if dom[(d, p)][1] is None else f" ± {dom[(d, p)][1]:.2f}")
            for p in planners
        ]
        md.append(f"| {d} | " + " | ".join(cells) + " |")
    md += [
        "",
        "## Per instance",
        "",
        "Mean reward over the rounds the rules keep (rounds in brackets), and the score.",
        "",
        "| instance | min | max | " + " | ".join(planners) + " |",
        "|---|---:|---:|" + "---:|" * len(planners),
    ]
    cell = {(s.instance, s.planner): s for s in table.instances}
    for inst in instances:
        lo, hi = table.bounds.get(inst, (None, None))
        cells = []
        for p in planners:
            s = cell.get((inst, p))
            cells.append("-" if s is None else f"{_fmt(s.mean, 2)} ({s.rounds}) **{s.score:.2f}**")
        md.append(f"| {inst} | {_fmt(lo, 2)} | {_fmt(hi, 2)} | " + " | ".join(cells) + " |")
    if table.skipped:
        md += ["", "Not scored: " + "; ".join(f"{i} ({w})" for i, w in table.skipped.items()) + "."]
    md += [
        "",
        "## Figures",
        "",
        f"![score per instance]({fig_scores[0]})",
        "",
        f"![reward per round]({fig_rewards[0]})",
        "",
        f"![time per turn]({fig_times[0]})",
        "",
        "Every figure's numbers are beside it as CSV and JSON; the scores are in `scores.json`.",
        "",
    ]
    path = out / "report.md"
    path.write_text("\n".join(md))
    return path
