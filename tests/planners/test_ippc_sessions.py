"""mcts, replan and random play a one-round session of instance 1 of every
IPPC 2011, 2014 and 2018 MDP domain of rddlrepository against our server,
and never send an illegal action (the server would end the round there).

random is rddlsim's RandomConcurrentPolicy: where that policy gives up it
ends the session with rddlsim's message, as the Java client does. It adds
one grounding at a time and keeps it only if the list so far is legal, so
it can never find ChromaticDice's first action (all five dice at once);
where noop is illegal and the coin flips skip every grounding
(EarthObservation's exactly-one slew, PushYourLuck's roll or cash out,
WildlifePreserve #1's one ranger defending exactly one area) it gives up by
chance, on some turns.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import trio
from ippc.client.session import ClientConfig, ClientError, SessionResult, run_session
from ippc.planners import PlannerError, make_planner
from ippc.planners.rddlsim_random import STUCK_MESSAGE
from ippc.rddl import load_pair
from ippc.server.app import serve
from ippc.server.config import ServerConfig
from ippc.server.registry import Registry

from ..conftest import IPPC_MDP_DOMAINS, ippc_files

CASES = [(year, domain) for year, domains in IPPC_MDP_DOMAINS.items() for domain in domains]

PLANNERS = {
    "mcts": {"time_per_step": "0.05", "seed": "1"},
    "replan": {"time_per_step": "0.05", "seed": "1"},
    "random": {"seed": "0"},
}

# where rddlsim's RandomConcurrentPolicy gives up at once, and where it may
RANDOM_STUCK_AT_ONCE = {("IPPC2018", "ChromaticDice")}
RANDOM_MAY_STICK = {
    ("IPPC2018", "EarthObservation"),
    ("IPPC2018", "PushYourLuck"),
    ("IPPC2018", "WildlifePreserve"),
}


def play(files: tuple[Path, Path], instance: str, planner: str) -> SessionResult | Exception:
    """One session of one round against our server, in this process (the
    planner's or the client's error, if it stops)."""

    async def main() -> SessionResult | Exception:
        registry = Registry.load(*files)
        config = ServerConfig(port=0, rounds=1, timeout=0)
        async with trio.open_nursery() as nursery:
            port = await nursery.start(serve, config, registry)
            try:
                with trio.fail_after(600):
                    return await run_session(
                        ClientConfig(port=port, instance=instance, seed=1),
                        make_planner(planner, PLANNERS[planner]),  # type: ignore[arg-type]
                        planner,
                    )
            except (PlannerError, ClientError) as err:
                return err
            finally:
                nursery.cancel_scope.cancel()

    return trio.run(main)


@pytest.mark.slow
@pytest.mark.parametrize("year,domain", CASES, ids=[f"{y}-{d}" for y, d in CASES])
def test_instance_one_is_played_legally(year: str, domain: str) -> None:
    files = ippc_files(year, domain)
    model = load_pair(*files)
    assert model.horizon is not None
    for planner in PLANNERS:
        result = play(files, model.name, planner)
        if planner == "random" and (year, domain) in RANDOM_STUCK_AT_ONCE:
            assert isinstance(result, PlannerError), result
            assert f"turn 1: {STUCK_MESSAGE}" in str(result)
            continue
        if planner == "random" and (year, domain) in RANDOM_MAY_STICK:
            if isinstance(result, PlannerError):
                assert STUCK_MESSAGE in str(result)
                continue
        assert isinstance(result, SessionResult), (planner, result)
        (one,) = result.rounds
        assert one.ended_early is None, (planner, one.ended_early)
        assert one.turns == model.horizon or model.domain.termination, (planner, one.turns)
