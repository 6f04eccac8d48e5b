"""`SearchStats`: the counters of the search (waves, trials, leaves,
simulated transitions), per turn and per session. No dependencies."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class SearchStats:
    """Counters of the search, readable while a session runs (the bench
    reads `steps_per_second`)."""

    turns: int = 0
    waves: int = 0
    trials: int = 0
    leaves: int = 0  # decision nodes expanded
    ids_leaves: int = 0  # of them, those IDS estimated
    locks: int = 0  # of them, reward locks (solved at once)
    reused: int = 0  # turns whose root came from the last turn's tree
    sim_steps: int = 0  # state transitions simulated (every row of every batched step)
    sim_calls: int = 0  # batched simulator calls
    seconds: float = 0.0  # time spent searching

    @property
    def steps_per_second(self) -> float:
        """Simulated state transitions per second of search."""
        return self.sim_steps / self.seconds if self.seconds > 0 else 0.0

    def add(self, other: SearchStats) -> None:
        """Add another set of counters to these."""
        self.turns += other.turns
        self.waves += other.waves
        self.trials += other.trials
        self.leaves += other.leaves
        self.ids_leaves += other.ids_leaves
        self.locks += other.locks
        self.reused += other.reused
        self.sim_steps += other.sim_steps
        self.sim_calls += other.sim_calls
        self.seconds += other.seconds
