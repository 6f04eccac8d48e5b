"""How big the search of a session may grow: the batch of the wave engine,
the candidates per node and the nodes of the tree, sized from the instance
against the memory budget (`ippc.planners.budget`), and the time a step of
the batched simulator takes, against the turn's time.

The budget is split in two halves: one for the simulator's batches (the
wave engine's descents and roll-outs, IDS's levels), sized with what one
step costs per state (`budget.step_cost`, temporaries included); one for
the search tree, sized with an estimate of one decision node (its state
twice, as the state and as its key, and its per-candidate lists). What the
options ask for is the upper bound: the sizing only lowers it.

May call `ippc.planners.budget` and the options; nothing else of the package.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from ...rddl.simulator import Simulator
from ..budget import StepCost, count_within, describe_bytes, rows_within, step_cost
from .options import Settings

log = logging.getLogger(__name__)

# Bytes a wave-engine node holds per candidate action (its row, its counts,
# sums, value and heuristic lists, its pending count and its outcome dict)
# and besides (the object, its lists and dicts): measured with tracemalloc
# on Elevators and SysAdmin trees, rounded up.
WAVE_NODE_PER_CANDIDATE = 240
WAVE_NODE_FIXED = 1200
# A thts node (Python tuples of the state's values, or the C tree's
# arrays): bytes per state value, and besides, with room for its candidates.
THTS_NODE_PER_VALUE = 80
THTS_NODE_FIXED = 4096
# IDS's levels hold at most this share of the batch half of the budget
IDS_SHARE = 0.5


@dataclasses.dataclass(frozen=True)
class Sizing:
    """What the sizing chose for a session, and from what."""

    budget: int  # bytes
    batch: int
    max_actions: int
    max_nodes: int
    cost: StepCost | None  # the batched step's cost (wave engine)
    node_bytes: int
    step_seconds_per_row: float | None  # the batched step's time per state (wave engine)


def size_wave(
    sim: Simulator, settings: Settings, budget: int, turn_seconds: float | None
) -> tuple[Settings, Sizing]:
    """`settings` with `batch`, `max_actions` and `max_nodes` lowered to fit
    `budget` bytes, and, when `turn_seconds` is known, `batch` and
    `max_actions` lowered so that a step of a whole batch takes at most a
    quarter of a turn (a turn always simulates at least one step of a leaf's
    roll-outs)."""
    cost = step_cost(sim)
    half = budget // 2
    batch = rows_within(half, cost, settings.batch)
    per_row = _seconds_per_row(sim, min(batch, 4))
    if turn_seconds is not None and per_row > 0.0:
        by_time = int(0.25 * turn_seconds / per_row)
        batch = max(1, min(batch, by_time))
    per_leaf = settings.modes * settings.rollouts
    # at least a choice between two actions, where the memory allows it
    least = min(settings.max_actions, 2 if rows_within(half, cost, 2 * per_leaf) > per_leaf else 1)
    max_actions = max(least, min(settings.max_actions, batch // per_leaf))
    n_values = sum(int(np.prod(v.shape[1:])) for v in sim.initial_state(1).values.values())
    node = (
        2 * cost.state
        + 112 * max(1, n_values // 64)
        + WAVE_NODE_PER_CANDIDATE * max_actions
        + WAVE_NODE_FIXED
    )
    max_nodes = count_within(half, node, settings.max_nodes)
    sized = dataclasses.replace(settings, batch=batch, max_actions=max_actions, max_nodes=max_nodes)
    return sized, Sizing(budget, batch, max_actions, max_nodes, cost, node, per_row)


def size_thts(n_values: int, settings: Settings, budget: int) -> tuple[Settings, Sizing]:
    """`settings` with `max_nodes` lowered so that the tree of a state of
    `n_values` values fits in half of `budget` bytes."""
    node = THTS_NODE_PER_VALUE * max(1, n_values) + THTS_NODE_FIXED
    max_nodes = count_within(budget // 2, node, settings.max_nodes)
    sized = dataclasses.replace(settings, max_nodes=max_nodes)
    return sized, Sizing(budget, settings.batch, settings.max_actions, max_nodes, None, node, None)


def ids_rows(sizing: Sizing) -> int:
    """Rows one IDS level may step at once (the `max_rows` of `IDS`)."""
    if sizing.cost is None:
        return 200_000
    return rows_within(int(IDS_SHARE * sizing.budget // 2), sizing.cost, 200_000)


def describe(sizing: Sizing, asked: Settings) -> str:
    """For the log: what was lowered and why."""
    parts = []
    if sizing.batch < asked.batch:
        parts.append(f"batch {asked.batch} -> {sizing.batch}")
    if sizing.max_actions < asked.max_actions:
        parts.append(f"max_actions {asked.max_actions} -> {sizing.max_actions}")
    if sizing.max_nodes < asked.max_nodes:
        parts.append(f"max_nodes {asked.max_nodes} -> {sizing.max_nodes}")
    cost = (
        ""
        if sizing.cost is None
        else f"; a step costs {describe_bytes(sizing.cost.per_row)} a state"
        + (
            ""
            if sizing.step_seconds_per_row is None
            else f" and {sizing.step_seconds_per_row * 1e3:.2f} ms"
        )
    )
    return (
        f"memory budget {describe_bytes(sizing.budget)} (option memory){cost}, "
        f"a node about {describe_bytes(sizing.node_bytes)}: "
        + (", ".join(parts) if parts else "nothing lowered")
    )


def _seconds_per_row(sim: Simulator, rows: int) -> float:
    """Seconds a noop step takes per state, on a batch of `rows` states
    (after one step of the same batch, so that compiling is not counted)."""
    rows = max(1, rows)
    rng = np.random.default_rng(0)
    state = sim.initial_state(rows)
    noop = sim.noop(rows)
    try:
        sim.step(state, noop, rng, check=False)
        t0 = time.perf_counter()
        sim.step(state, noop, rng, check=False)
        return (time.perf_counter() - t0) / rows
    except Exception as err:  # noqa: BLE001 - the search meets and reports it
        log.debug("mcts: timing a step of %d states failed: %s", rows, err)
        return 0.0
