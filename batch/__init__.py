"""ippc.batch: competition-style experiments (planners x instances x rounds) with IPPC
scores, resumable, on one machine or a Dask cluster, and a report.

    from ippc.batch import load_experiment, run_batch, score
    experiment = load_experiment("examples/small.toml")
    run_batch(experiment, "results.sqlite")

The command line is ``rddl-batch run|score|report`` (`ippc.batch.cli`); docs/batch.md
describes the experiment files, the rule sets and the report.
"""

from __future__ import annotations

from .experiment import (
    BASELINES,
    Experiment,
    ExperimentError,
    PlannerSpec,
    load_experiment,
    parse_experiment,
)
from .instances import ResolvedInstance, check_experiment, resolve_instances
from .jobs import Job, JobResult, build_jobs, run_job, stable_seed
from .rddlsim_log import read_rddlsim_log
from .results import BatchStore, RoundRecord
from .runner import BatchSummary, run_batch
from .scoring import RULES, ScoreError, ScoreTable, score

__all__ = [
    "BASELINES",
    "RULES",
    "BatchStore",
    "BatchSummary",
    "Experiment",
    "ExperimentError",
    "Job",
    "JobResult",
    "PlannerSpec",
    "ResolvedInstance",
    "RoundRecord",
    "ScoreError",
    "ScoreTable",
    "build_jobs",
    "check_experiment",
    "load_experiment",
    "parse_experiment",
    "read_rddlsim_log",
    "resolve_instances",
    "run_batch",
    "run_job",
    "score",
    "stable_seed",
]
