"""docs/gym.md's examples learn: the cross-entropy method's, whose illustrative
plotting block draws the learning curve the page shows (tests/test_docs_examples.py
runs the example itself and compares its printout with the page; this runs the plot
after it, in a scratch folder, so the committed figure is not rewritten by the tests),
and stable-baselines3's PPO through ippc.gym.baselines, with a short training budget,
where stable-baselines3 is installed."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from ..docs import REPO, blocks

PAGE = REPO / "docs" / "gym.md"


def test_the_example_learns_and_draws_its_curve(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    python = [b for b in blocks(PAGE.read_text(encoding="utf-8")) if b.lang == "python"]
    example = next(b for b in python if "def episode_returns" in b.text)
    plot = next(b for b in python if "savefig" in b.text)
    assert "savefig" in plot.text and "docs/gym-cem-sysadmin.png" in plot.text
    assert (REPO / "docs" / "gym-cem-sysadmin.png").stat().st_size > 10_000
    (tmp_path / "docs").mkdir()
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "__main__"}
    with contextlib.redirect_stdout(io.StringIO()):
        exec(compile(example.text, f"{PAGE}:{example.line}", "exec"), namespace)
        exec(compile(plot.text, f"{PAGE}:{plot.line}", "exec"), namespace)
    random_return, learned = namespace["random_return"], namespace["learned_return"]
    assert isinstance(random_return, float) and isinstance(learned, float)
    assert learned > random_return + 50  # SysAdmin #1: about 217 against 342
    png = (tmp_path / "docs" / "gym-cem-sysadmin.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 10_000


#: the PPO example's budget on the page, and the test's
FULL_BUDGET = "total_timesteps = 100_000"
TEST_BUDGET = "total_timesteps = 16_384"


def test_the_ppo_example_beats_random(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip(
        "stable_baselines3",
        reason="docs/gym.md's PPO example needs stable-baselines3: pip install 'ippc[rl]'",
    )
    text = PAGE.read_text(encoding="utf-8")
    python = [b for b in blocks(text) if b.lang == "python"]
    example = next(b for b in python if "from stable_baselines3 import PPO" in b.text)
    assert example.text.count(FULL_BUDGET) == 1
    monkeypatch.chdir(REPO)
    namespace: dict[str, object] = {"__name__": "__main__"}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = example.text.replace(FULL_BUDGET, TEST_BUDGET)
        exec(compile(code, f"{PAGE}:{example.line}", "exec"), namespace)
    lines = out.getvalue().splitlines()
    assert lines[0] == "Discrete(11) Box(0.0, 1.0, (10,), float32)"
    assert lines[1].startswith("random policy ")
    random_return, ppo_return = namespace["random_return"], namespace["ppo_return"]
    assert isinstance(random_return, float) and isinstance(ppo_return, float)
    # the same 256 seeded episodes as the page's full run: the random policy's return
    # does not depend on the training
    assert f"random policy {random_return:.1f}  PPO " in text
    assert ppo_return > random_return + 30  # 16,384 steps: 216.9 against 308.3 on 2026-12-03
