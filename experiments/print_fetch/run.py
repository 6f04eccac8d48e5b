"""Runs of the print-fetching experiments: one approach, one experiment, one seed.

Every run is one whole `rddl-dispatch --simulate` session (`ippc.dispatch.run.simulate`):
the knowledge base starts from the experiment's instance, the simulated office
(`world.OfficeWorld`) plays the robot's actions and sensors, and the approach's planner
connects to the dispatcher over the IPPC protocol. The run ends when the papers are
delivered or after the horizon (one round: a run that has not delivered in 20 steps
failed).

The approaches:

| name | what plays | |
|---|---|---|
| `fast-downward` | the deterministic baseline (`ippc.experiments.fast_downward`): Fast Downward on the knowledge base's PDDL, replanning when an action fails | the paper's Metric-FF baseline |
| `replan` | ippc's built-in determinise-and-replan planner (most-likely outcomes) | a second deterministic baseline |
| `mcts` | ippc's built-in UCT planner on the RDDL model | probabilistic |
| `prost` | PROST through its launcher (only when a PROST binary is given) | the paper's probabilistic planner |
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

from ...dispatch.run import PlannerSpec, RunReport, simulate
from ...rddl import load
from ...rddl.model import Model
from .office import EXPERIMENTS, PRINTERS, Experiment
from .world import OfficeWorld, non_fluent

__all__ = [
    "APPROACHES",
    "DOMAIN_FOLDER",
    "Approach",
    "RunRow",
    "approaches",
    "run_many",
    "run_one",
]

log = logging.getLogger(__name__)

DOMAIN_FOLDER = Path(__file__).resolve().parents[2] / "domains" / "print_fetch"

#: seconds of search per turn for the built-in planners (and PROST's share of its budget)
TIME_PER_STEP = 0.25


@dataclass(frozen=True)
class Approach:
    """A planner and how it is started."""

    name: str
    planner: str  # a registered planner's name, or "prost"
    options: tuple[tuple[str, str], ...] = ()

    def spec(self, seed: int, prost: str | None, log: Path | None = None) -> PlannerSpec:
        """The dispatcher's planner spec for one run (`log`: PROST's output file)."""
        if self.planner == "prost":
            if prost is None:
                raise ValueError("the prost approach needs a PROST binary")
            # IPC 2014's configuration with the built-ins' search time per step
            options = {"config": f"[Prost -s {seed} -se [IPC2014 -t {TIME_PER_STEP}]]"}
            if log is not None:
                options["log"] = str(log)
            return PlannerSpec(prost=prost, options={**options, **dict(self.options)})
        return PlannerSpec(self.planner, dict(self.options), seed=seed)


APPROACHES: dict[str, Approach] = {
    "fast-downward": Approach("fast-downward", "fast-downward"),
    "replan": Approach("replan", "replan", (("time_per_step", str(TIME_PER_STEP)),)),
    # extrapolate=no: the mean reward of a cut-short rollout is not spread over the steps
    # left (it makes a one-step-away delivery look no better than standing still).
    # The default engine (thts, its trials in C where a C compiler is found): the Python
    # thts engine with IDS delivered nothing in 20 steps in experiment 1's run 0; the
    # compiled one delivers in every run (docs/print-fetch.md).
    "mcts": Approach(
        "mcts",
        "mcts",
        (("time_per_step", str(TIME_PER_STEP)), ("extrapolate", "no")),
    ),
    "prost": Approach("prost", "prost"),
}


def approaches(names: Iterable[str] | None = None, prost: str | None = None) -> list[Approach]:
    """The approaches by name (default: all, PROST only with a binary)."""
    if names is None:
        chosen = [a for a in APPROACHES if a != "prost" or prost is not None]
    else:
        chosen = list(names)
    unknown = [n for n in chosen if n not in APPROACHES]
    if unknown:
        raise ValueError(
            f"unknown approach(es) {', '.join(unknown)}: choose from {', '.join(APPROACHES)}"
        )
    if "prost" in chosen and prost is None:
        raise ValueError("the prost approach needs a PROST binary (--prost or $PROST_BIN)")
    return [APPROACHES[n] for n in chosen]


@dataclass(frozen=True)
class RunRow:
    """One run, as the report counts it (the first ten fields are runs.csv's columns)."""

    experiment: int
    approach: str
    run: int
    success: bool
    first_printer: str  # the first printer the robot drove to ("" if none)
    distance_m: float
    execution_s: float  # simulated seconds: the sum of the executed actions' durations
    planning_s: float  # wall seconds the planner took, summed over its turns
    failed_actions: int
    replans: int  # turns planned after an action that failed
    steps: int
    seed: int
    reward: float  # the world's reward (RDDL), undiscounted
    error: str = ""  # the planner's error, if it ended with one

    #: runs.csv's columns, as the issue names them
    CSV_COLUMNS = (
        "experiment",
        "approach",
        "run",
        "success",
        "first_printer",
        "distance_m",
        "execution_s",
        "planning_s",
        "failed_actions",
        "replans",
    )

    def as_dict(self) -> dict[str, Any]:
        """Every field, JSON-able."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunRow:
        """The row of `as_dict` (or of a CSV row with every field)."""
        kinds = {f.name: f.type for f in fields(cls)}
        out: dict[str, Any] = {}
        for name, kind in kinds.items():
            value = data[name] if name in data else ""
            if kind == "int":
                out[name] = int(value)
            elif kind == "float":
                out[name] = float(value)
            elif kind == "bool":
                out[name] = value if isinstance(value, bool) else str(value) == "True"
            else:
                out[name] = str(value)
        return cls(**out)


def seed_of(experiment: int, run: int) -> int:
    """The seed of one run: the same for every approach (the same world in experiment 4)."""
    return 1000 * experiment + run


def _metrics(report: RunReport, model: Model) -> tuple[str, float]:
    """(first printer driven to, metres driven) from the executed actions."""
    first, metres = "", 0.0
    for entry in report.executed:
        action = str(entry["action"])
        if not action.startswith("goto_waypoint(") or entry["outcome"] != "succeeded":
            continue
        _, a, b = action[action.index("(") + 1 : -1].split(",")
        metres += non_fluent(model, "DISTANCE", (a, b))
        if not first and b in PRINTERS:
            first = b
    return first, metres


def run_one(
    experiment: Experiment,
    approach: Approach,
    run: int,
    *,
    prost: str | None = None,
    folder: Path = DOMAIN_FOLDER,
) -> RunRow:
    """One run of `approach` on `experiment` (seeded by `seed_of`)."""
    seed = seed_of(experiment.number, run)
    instance = folder / f"exp{experiment.number}.rddl"
    model = load(folder / "domain.rddl", instance)[experiment.instance]
    world = OfficeWorld(experiment, model)
    with tempfile.TemporaryDirectory(prefix="ippc-print-fetch-") as tmp:
        report = simulate(
            folder / "domain.rddl",
            instance,
            seed=seed,
            planner=approach.spec(seed, prost, log=Path(tmp) / "prost.log"),
            rounds=1,
            **world.world_options(),  # type: ignore[arg-type]
        )
    first, metres = _metrics(report, model)
    return RunRow(
        experiment=experiment.number,
        approach=approach.name,
        run=run,
        success=report.goal_reached,
        first_printer=first,
        distance_m=round(metres, 4),
        execution_s=round(report.execution_seconds, 4),
        planning_s=round(report.planning_seconds, 4),
        failed_actions=report.failed_actions,
        replans=report.replans,
        steps=report.turns,
        seed=seed,
        reward=round(report.reward, 4),
        error=report.planner_error or "",
    )


def _run_job(job: tuple[int, str, int, str | None, str]) -> RunRow:
    number, name, run, prost, folder = job
    return run_one(EXPERIMENTS[number], APPROACHES[name], run, prost=prost, folder=Path(folder))


def run_many(
    jobs: Sequence[tuple[int, str, int]],
    *,
    prost: str | None = None,
    workers: int = 1,
    folder: Path = DOMAIN_FOLDER,
    progress: Any = None,
) -> list[RunRow]:
    """Every (experiment, approach, run) of `jobs`, in `workers` processes
    (1: in this one); rows in the order of `jobs`. `progress(row)` is called
    after each run."""
    full = [(e, a, r, prost, str(folder)) for e, a, r in jobs]
    rows: list[RunRow] = []
    if workers <= 1:
        for job in full:
            rows.append(_run_job(job))
            if progress is not None:
                progress(rows[-1])
        return rows
    import multiprocessing

    # spawn: a fresh interpreter per worker (trio, threads and PROST's process groups
    # do not survive a fork of a process that has run them)
    with multiprocessing.get_context("spawn").Pool(workers) as pool:
        for row in pool.imap(_run_job, full):
            rows.append(row)
            if progress is not None:
                progress(row)
    return rows
