"""The server computes each step's action-free part while the client thinks
(`Simulator.prepare`); what the client sees is what `Simulator.step` gives,
also after illegal actions end a round (the draws made ahead are given back)."""

from __future__ import annotations

import numpy as np
import trio
from ippc.protocol import Actions, Fluent, encode
from ippc.server.config import ServerConfig
from lxml import etree

from .harness import (
    DECL,
    NOOP,
    ROUND_REQUEST,
    RawClient,
    running_server,
    session_request,
    shared_registry,
    strip_frame,
)

TWO_REBOOTS = (
    DECL
    + encode(
        Actions((Fluent("reboot", ("c1",), "true"), Fluent("reboot", ("c2",), "true"))),
        declaration=False,
    )
    + b"\0"
)
ONE_REBOOT = DECL + encode(Actions((Fluent("reboot", ("c3",), "true"),)), declaration=False) + b"\0"


def _running(turn: etree._Element) -> dict[str, bool]:
    return {
        f.findtext("fluent-arg") or "": f.findtext("fluent-value") == "true"
        for f in turn.findall("observed-fluent")
        if f.findtext("fluent-name") == "running"
    }


async def _play(port: int) -> tuple[list[list[dict[str, bool]]], list[float]]:
    """Round 1: a reboot, a noop, then two reboots (illegal: max-nondef-actions
    is 1). Round 2: a reboot, then noops. The states of each round's turns and
    the round rewards."""
    c = await RawClient.connect(port)
    await c.send(session_request("sysadmin_inst_mdp__1", "prep"))
    assert etree.fromstring(strip_frame(await c.recv())).tag == "session-init"
    states: list[list[dict[str, bool]]] = []
    rewards: list[float] = []
    for plan in ([ONE_REBOOT, NOOP, TWO_REBOOTS], [ONE_REBOOT]):
        await c.send(ROUND_REQUEST)
        assert etree.fromstring(strip_frame(await c.recv())).tag == "round-init"
        seen: list[dict[str, bool]] = []
        k = 0
        while True:
            msg = etree.fromstring(strip_frame(await c.recv()))
            if msg.tag == "round-end":
                rewards.append(float(msg.findtext("round-reward") or "nan"))
                break
            seen.append(_running(msg))
            await c.send(plan[k] if k < len(plan) else NOOP)
            k += 1
        states.append(seen)
    assert etree.fromstring(strip_frame(await c.recv())).tag == "session-end"
    await c.close()
    return states, rewards


def _expected() -> tuple[list[list[dict[str, bool]]], list[float]]:
    """The same session computed with `Simulator.step` alone (session 1: seed 0)."""
    inst = shared_registry().get("sysadmin_inst_mdp__1")
    sim, _ = inst.compiled_now()
    names = [f"c{i}" for i in range(1, 11)]
    rng = np.random.default_rng(0)

    def reboot(c: str) -> dict[str, np.ndarray]:
        a = np.zeros((1, 10), dtype=bool)
        a[0, names.index(c)] = True
        return {"reboot": a}

    states, rewards = [], []
    for plan in ([reboot("c3"), None], [reboot("c3")]):
        state = sim.initial_state(1)
        seen, total = [], 0.0
        for k in range(inst.horizon or 0):
            seen.append(dict(zip(names, map(bool, state.values["running"][0]), strict=True)))
            if k == len(plan) and len(plan) == 2:
                break  # round 1's third answer is illegal: no step, the round ends
            step = sim.step(state, plan[k] if k < len(plan) else None, rng)
            total += float(step.reward[0])
            state = step.next_state
        states.append(seen)
        rewards.append(total)
    return states, rewards


def test_states_and_rewards_as_step_gives_them_across_an_illegal_action() -> None:
    async def main() -> tuple[list[list[dict[str, bool]]], list[float]]:
        async with running_server(ServerConfig(port=0, rounds=2)) as (port, _):
            return await _play(port)

    states, rewards = trio.run(main)
    want_states, want_rewards = _expected()
    assert len(states[0]) == 3 and len(states[1]) == 5
    assert states == want_states
    assert rewards == want_rewards
