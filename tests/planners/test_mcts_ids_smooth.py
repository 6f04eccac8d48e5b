"""Option `ids_smooth` of the thts engine: a node's IDS estimate is the mean
of its values a step at the depth and one less (from depth 3 on), in the
Python tree and in the C tree alike, so that it does not swing with the
parity of the depth where a reward comes every other step. On by default."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from .test_exact import model_of
from .test_mcts import observe
from .test_mcts_actions_c import needs_cc
from .test_mcts_sinks import acts_values
from .test_mcts_thts import planner_on, root_of

# `on` flips every step and pays 1; `take` pays 0.5 more, whenever.
PARITY = """
domain tiny_parity {
    requirements = { concurrent, reward-deterministic };
    pvariables {
        on : { state-fluent, bool, default = true };
        take : { action-fluent, bool, default = false };
    };
    cpfs {
        on' = ~on;
    };
    reward = (if (on) then 1 else 0) + 0.5 * take;
}
instance tiny_parity_inst {
    domain = tiny_parity;
    max-nondef-actions = 1;
    horizon = 8;
    discount = 1.0;
}
"""

# noop's IDS value from `on` with d steps: 1, then take every step after:
# 1.5 at depth 2, 3 at depth 3, 3.5 at depth 4. Scaled to the 8 steps left:
# depth 3 gives 8 and depth 4 gives 7; the means a step of (3, 2) and (4, 3)
# give 0.5 * (3/3 + 1.5/2) * 8 = 7 and 0.5 * (3.5/4 + 3/3) * 8 = 7.5. Depth 2 is
# not smoothed (depth 1 is the immediate reward alone): 1.5 * 8/2 = 6 either way.
EXPECTED = {
    ("2", "no"): 6.0,
    ("2", "yes"): 6.0,
    ("3", "no"): 8.0,
    ("4", "no"): 7.0,
    ("3", "yes"): 7.0,
    ("4", "yes"): 7.5,
}


def root_values(
    tmp_path: Path, compiled: str, depth: str, **options: str
) -> tuple[Any, dict[str, float]]:
    """The root and its actions' values after one trial from `on` at a fixed
    IDS depth (8 steps left)."""
    model = model_of(tmp_path, PARITY, "tiny_parity_inst")
    # (take's values differ from noop's only by its first step's reward: with
    # blind_future these would be roll-outs' values)
    planner, sim = planner_on(
        model,
        iterations="1",
        seed="1",
        compiled=compiled,
        ids_depth=depth,
        blind_future="no",
        **options,
    )
    state = sim.initial_state(1)
    planner.act(observe(sim, state, 1, 8))
    root = root_of(planner, state, 8)
    return root, acts_values(planner, sim, root)


@pytest.mark.parametrize("compiled", ["no", pytest.param("yes", marks=needs_cc)])
@pytest.mark.parametrize("depth,smooth", sorted(EXPECTED))
def test_the_smoothed_estimate_is_the_mean_a_step_of_two_depths(
    tmp_path: Path, compiled: str, depth: str, smooth: str
) -> None:
    root, values = root_values(tmp_path, compiled, depth, ids_smooth=smooth)
    assert set(values) == {"noop", "take"}
    # the one trial went through take (0.5 a step better): noop keeps its estimate
    assert dict(zip(root.rows, root.n, strict=True))[root.rows[0]] == 0
    assert values["noop"] == pytest.approx(EXPECTED[depth, smooth], abs=1e-9)
    assert np.isfinite(values["take"])


@pytest.mark.parametrize("compiled", ["no", pytest.param("yes", marks=needs_cc)])
@pytest.mark.parametrize("depth", ["3", "4"])
def test_smoothing_is_the_default(tmp_path: Path, compiled: str, depth: str) -> None:
    """Without the option the estimate is the smoothed one (recon 2011's
    estimates swung with the parity of the learned depth without it)."""
    _, values = root_values(tmp_path, compiled, depth)
    assert values["noop"] == pytest.approx(EXPECTED[depth, "yes"], abs=1e-9)
    assert values["noop"] != pytest.approx(EXPECTED[depth, "no"], abs=1e-9)
