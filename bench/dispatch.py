"""Simulated runs per second of rddl-dispatch, against rddl-server in the same run.

Workload: the courier domain of the robot side's tests
(tests/data/dispatch/courier_one.rddl, a goal domain, horizon 12), one
simulated run per seed: `ippc.dispatch.run.simulate` (knowledge base,
simulated world, sensing, dispatcher, the planner over loopback TCP),
which is what `rddl-dispatch --simulate` and the print-fetching experiments
run. The reference is the same planner playing the same instance against
rddl-server's session code in the same process (`server.app.serve` plus
`client.run_session`, one round per session, no knowledge base, no world):
what a turn costs before the robot side adds anything. Both take turns
within each pass; figures are medians of `--repeat` passes.

    python bench/dispatch.py                   # random and exact, 20 runs a pass
    python bench/dispatch.py --planner noop --runs 50

Soak (`--soak`): one dispatcher process serving a flaky robot for
`--turns` turns (default 50,000) on the wall clock, as rddl-dispatch runs
it (sensing at its rate, the knowledge base journaled in a real SQLite
store, --on-planner-loss wait): the courier delivers parcel after parcel
(a new parcel is put on the desk after each delivery). Its handlers hang
(timed out at the action timeout), block the event loop past it, fail,
raise, answer garbage, or hang in `run_blocking` (an abandoned thread);
its odometry contradicts itself and sends unknown rooms, NaN and strings;
its planner (a courier policy read off the state, a `Planner` played by
rddl-client's code in the loop, over TCP) hangs up every few hundred turns, or goes silent until --planner-silence drops it, and
connects again. Prints dispatches per minute and the process's memory
(RSS, and Python's own allocations by tracemalloc with --trace) after a
warm-up and at the end, and the outcome counts.

    python bench/dispatch.py --soak            # 50,000 turns
    python bench/dispatch.py --soak --turns 5000 --trace
"""

from __future__ import annotations

import argparse
import logging
import statistics
import time
from pathlib import Path
from typing import ClassVar

import trio

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data" / "dispatch"
DOMAIN = DATA / "courier_domain.rddl"
INSTANCE = DATA / "courier_one.rddl"


def dispatch_pass(planner: str, runs: int) -> tuple[float, int]:
    from ippc.dispatch.run import PlannerSpec, simulate

    turns = 0
    start = time.perf_counter()
    for seed in range(runs):
        turns += simulate(DOMAIN, INSTANCE, seed=seed, planner=PlannerSpec(planner), rounds=1).turns
    return time.perf_counter() - start, turns


def server_pass(planner: str, runs: int) -> tuple[float, int]:
    from ippc.client.session import ClientConfig, run_session
    from ippc.planners.base import Planner, make_planner
    from ippc.server.app import serve
    from ippc.server.config import ServerConfig
    from ippc.server.registry import Registry

    if not isinstance(make_planner(planner, {}), Planner):
        # an external planner (PROST) connects by itself: not a client-side planner
        raise SystemExit(f"--planner {planner}: the server pass needs a built-in planner")

    async def one(seed: int) -> int:
        agent = make_planner(planner, {})
        assert isinstance(agent, Planner)
        registry = Registry.load(DOMAIN, INSTANCE)
        config = ServerConfig(port=0, rounds=1, seed=seed, timeout=0, individual_session=True)
        async with trio.open_nursery() as nursery:
            port = await nursery.start(serve, config, registry)
            result = await run_session(
                ClientConfig(port=port, instance="courier_one", seed=seed),
                agent,
                planner,
            )
        return sum(r.turns for r in result.rounds)

    turns = 0
    start = time.perf_counter()
    for seed in range(runs):
        turns += trio.run(one, seed)
    return time.perf_counter() - start, turns


ROOMS = ("hall", "office", "lab")
SOAK_SENSING = {
    "rate": 1000,
    "sensors": {
        "robot-at": {"stream": "odometry", "params": ["r1", "*"], "value": "msg.at"},
        "present": {"stream": "camera", "params": ["*"], "value": "msg.seen"},
    },
}


def rss_mb() -> float:
    """The process's resident memory now (Linux /proc), in MB."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    import os

    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


class FlakyRobot:
    """The courier's true state and its misbehaving handlers and sensors."""

    def __init__(self, robot, rng, action_timeout: float) -> None:  # type: ignore[no-untyped-def]
        self.robot = robot
        self.rng = rng
        self.room = "hall"
        self.holding = False
        self.timeout = action_timeout
        self.deliveries = 0
        self.parcel_due = False
        self.misbehaved: dict[str, int] = {}
        self.release = __import__("threading").Event()

    def _misbehave(self) -> str | None:
        x = self.rng.random()
        for what, p in (
            ("hang", 0.01),
            ("block", 0.005),
            ("blocking-thread", 0.005),
            ("fail", 0.03),
            ("raise", 0.01),
            ("garbage", 0.01),
        ):
            if x < p:
                self.misbehaved[what] = self.misbehaved.get(what, 0) + 1
                return what
            x -= p
        return None

    async def act(self, d) -> object:  # type: ignore[no-untyped-def]
        from ippc.dispatch.actions import Status, run_blocking

        what = self._misbehave()
        if what == "hang":
            await trio.sleep_forever()
        elif what == "block":
            time.sleep(self.timeout * 1.5)  # blocks the loop past the timeout
        elif what == "blocking-thread":
            await run_blocking(self.release.wait, 0.2)  # abandoned at the timeout
        elif what == "fail":
            return Status.FAILED
        elif what == "raise":
            raise RuntimeError("gripper fault")
        elif what == "garbage":
            return {"status": "maybe"}
        await trio.sleep(0)
        name = d.name
        if name == "move":
            self.room = d.params["r2"]
        elif name == "pickup" and self.room == "office":
            self.holding = True
        elif name == "drop" and self.holding:
            self.holding = False
            if self.room == "lab":
                self.deliveries += 1
                self.parcel_due = True  # after the turn: the dispatcher applies the drop's effects
        self.odometry()
        return Status.SUCCEEDED

    def new_parcel(self) -> None:
        from ippc.kb import Update

        self.robot.kb.apply(
            [
                Update.set("delivered", (), False),
                Update.set("goal", (), False),
                Update.set("holding", ("r1",), False),
            ],
            "operator",
        )

    def odometry(self) -> None:
        self.robot.sensing.feed("odometry", {"at": {r: r == self.room for r in ROOMS}})

    async def sensors(self) -> None:
        rng = self.rng
        feed = self.robot.sensing.feed
        while True:
            if self.parcel_due and self.robot.kb.get("delivered") is True:
                self.parcel_due = False
                self.new_parcel()
            x = rng.random()
            if x < 0.05:  # contradicting: two rooms at once
                feed("odometry", {"at": {"hall": True, "lab": True}})
            elif x < 0.08:
                feed("odometry", {"at": {"mars": True}})  # an unknown room
            elif x < 0.10:
                feed("odometry", {"at": {"hall": float("nan")}})
            elif x < 0.12:
                feed("odometry", {"at": "garbage"})
            else:
                self.odometry()
            feed("camera", {"seen": {"office": bool(rng.random() < 0.8)}})
            await trio.sleep(0.005)


def soak(turns: int, trace: bool, seed: int) -> None:
    import tempfile
    import tracemalloc

    import numpy as np
    from ippc.client.session import ClientConfig, ClientError, run_session
    from ippc.dispatch.actions import Status
    from ippc.dispatch.config import SensingConfig
    from ippc.dispatch.run import LinkPolicy, build_robot, dispatch_session, server_config
    from ippc.kb import KnowledgeBase
    from ippc.planners.base import Planner
    from ippc.protocol import SessionRequest, encode

    kb = KnowledgeBase.from_files(DOMAIN, INSTANCE)
    if trace:  # after the parser is built (lark's grammar analysis is slow under it)
        tracemalloc.start(10)
    action_timeout = 0.02
    robot, dispatcher = build_robot(
        kb,
        SensingConfig.from_dict(SOAK_SENSING, kb.model),
        action_timeout=action_timeout,
        settle_limit=0.003,
        stop_at_goal=False,
    )
    rng = np.random.default_rng(seed)
    flaky = FlakyRobot(robot, rng, action_timeout)
    robot.handlers.register("*", flaky.act)
    robot.start_soon(flaky.sensors)
    folder = tempfile.mkdtemp(prefix="soak-")
    db = Path(folder) / "soak.db"
    config = server_config(rounds=1_000_000, db=db)
    link = LinkPolicy(reconnect=True, silence=10.0 if trace else 1.0)
    ports: list[int] = []
    figures: dict[str, float] = {}
    planner_sessions = {"played": 0, "hung up": 0, "silent": 0}

    class HangUp(Exception):
        pass

    class CourierPolicy(Planner):
        """The courier's plan read off each turn's state (cheap, so that the
        dispatcher is what the soak measures), hanging up after `turns`."""

        name: ClassVar[str] = "courier-policy"
        options: ClassVar[dict[str, str]] = {}

        def __init__(self, turns_left: int) -> None:
            super().__init__()
            self.turns_left = turns_left

        def act(self, obs):  # type: ignore[no-untyped-def]
            self.turns_left -= 1
            if self.turns_left < 0:
                raise HangUp()
            f = obs.fluents or {}
            at = [r for r in ROOMS if f.get(("robot-at", ("r1", r)))]
            if len(at) != 1 or f.get(("delivered", ())):
                return []  # an impossible state, or nothing to do: wait
            room, holding = at[0], bool(f.get(("holding", ("r1",))))
            target = "lab" if holding else "office"
            if room == target:
                return [("drop" if holding else "pickup", ("r1",), True)]
            step = target if room == "hall" else "hall"
            return [("move", ("r1", room, step), True)]

    async def planners() -> None:
        while not ports:
            await trio.sleep(0.01)
        while True:
            if rng.random() < 0.03:  # a planner that connects and goes silent
                planner_sessions["silent"] += 1
                stream = await trio.open_tcp_stream("127.0.0.1", ports[0])
                await stream.send_all(encode(SessionRequest("courier_one", "silent")) + b"\0")
                with trio.move_on_after(5):
                    while await stream.receive_some(65536):
                        pass
                await stream.aclose()
                continue
            agent = CourierPolicy(int(rng.integers(100, 1000)))
            planner_sessions["played"] += 1
            try:
                await run_session(
                    ClientConfig(port=ports[0], instance="courier_one", timeout=60.0),
                    agent,
                    "courier-policy",
                )
            except (ClientError, HangUp):
                pass
            except BaseExceptionGroup as group:  # trio wraps the planner's error
                if not group.subgroup((HangUp, ClientError)):
                    raise
            planner_sessions["hung up"] += 1

    async def monitor(cancel: trio.CancelScope) -> None:
        warm = min(1000, turns // 10)
        while dispatcher.stats.turns < warm:
            await trio.sleep(0.05)
        import gc

        gc.collect()
        figures["t0"] = time.perf_counter()
        figures["turns0"] = dispatcher.stats.turns
        figures["rss0"] = rss_mb()
        if trace:
            figures["py0"] = tracemalloc.get_traced_memory()[0] / 1e6
            figures["snap0"] = tracemalloc.take_snapshot()  # type: ignore[assignment]
        print(
            f"after {figures['turns0']:.0f} turns (warm-up): RSS {figures['rss0']:.1f} MB"
            + (f", Python {figures['py0']:.2f} MB" if trace else ""),
            flush=True,
        )
        next_report = figures["turns0"] + 10_000
        while dispatcher.stats.turns < turns:
            await trio.sleep(0.2)
            if dispatcher.stats.turns >= next_report:
                next_report += 10_000
                mins = (time.perf_counter() - figures["t0"]) / 60
                done = dispatcher.stats.turns - figures["turns0"]
                print(
                    f"  {dispatcher.stats.turns} turns, {done / mins:.0f} turns/min, "
                    f"RSS {rss_mb():.1f} MB",
                    flush=True,
                )
        gc.collect()
        figures["t1"] = time.perf_counter()
        figures["turns1"] = dispatcher.stats.turns
        figures["dispatches"] = dispatcher.stats.executed_total
        figures["rss1"] = rss_mb()
        if trace:
            figures["py1"] = tracemalloc.get_traced_memory()[0] / 1e6
            snap1 = tracemalloc.take_snapshot()
            top = snap1.compare_to(figures["snap0"], "lineno")[:8]  # type: ignore[arg-type]
            print("largest growth (tracemalloc):")
            for stat in top:
                print(f"  {stat}")
        cancel.cancel()

    async def main() -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(
                lambda: dispatch_session(
                    dispatcher,
                    None,
                    config,
                    sensing_task=True,
                    on_listening=ports.append,
                    robot=robot,
                    link=link,
                    watchdog=1.0,
                    journal=True,
                )
            )
            nursery.start_soon(planners)
            nursery.start_soon(monitor, nursery.cancel_scope)

    print(f"soak: courier_one, a flaky robot, {turns} turns, store {db}", flush=True)
    started = time.perf_counter()
    trio.run(main)
    flaky.release.set()
    stats = dispatcher.stats
    minutes = (figures["t1"] - figures["t0"]) / 60
    measured = figures["turns1"] - figures["turns0"]
    outcomes: dict[str, int] = {}
    for e in stats.executed:
        outcomes[e.outcome] = outcomes.get(e.outcome, 0) + 1
    print(
        f"{stats.turns} turns, {stats.executed_total} dispatches in "
        f"{time.perf_counter() - started:.0f} s: {figures['dispatches'] / ((figures['t1'] - started) / 60):.0f} "
        f"dispatches/min ({measured / minutes:.0f} turns/min after the warm-up)"
    )
    print(
        f"memory: RSS {figures['rss0']:.1f} MB after the warm-up, {figures['rss1']:.1f} MB at the end: "
        f"{figures['rss1'] - figures['rss0']:+.2f} MB over {measured:.0f} turns "
        f"({(figures['rss1'] - figures['rss0']) * 1e3 / measured:+.3f} KB/turn)"
    )
    if trace:
        print(
            f"Python allocations (tracemalloc): {figures['py0']:.2f} MB -> {figures['py1']:.2f} MB "
            f"({(figures['py1'] - figures['py0']) * 1e3 / measured:+.3f} KB/turn)"
        )
    print(
        f"failed actions {stats.failed_actions} ({100 * stats.failed_actions / max(1, stats.executed_total):.0f}%), "
        f"misbehaviour injected {dict(sorted(flaky.misbehaved.items()))}, "
        f"deliveries {flaky.deliveries}, planner sessions {planner_sessions}, "
        f"sessions recorded {len(robot.kb.facts()) and dispatcher.stats.rounds} rounds"
    )
    print(f"outcomes of the last {len(stats.executed)} actions: {dict(sorted(outcomes.items()))}")
    assert Status.SUCCEEDED.value in outcomes


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--planner", nargs="+", default=["random", "exact"])
    ap.add_argument("--runs", type=int, default=20, help="runs (sessions) per pass")
    ap.add_argument("--repeat", type=int, default=3, help="passes (median)")
    ap.add_argument("--soak", action="store_true", help="the soak run (see above)")
    ap.add_argument("--turns", type=int, default=50_000, help="turns of the soak run")
    ap.add_argument("--trace", action="store_true", help="the soak run under tracemalloc")
    ap.add_argument("--seed", type=int, default=0, help="the soak's flaky robot's seed")
    args = ap.parse_args()
    logging.disable(logging.CRITICAL)
    if args.soak:
        soak(args.turns, args.trace, args.seed)
        return
    logging.disable(logging.WARNING)
    print(f"workload: courier_one (horizon 12), {args.runs} runs a pass, median of {args.repeat}")
    print(f"{'planner':<8} {'what':<13} {'runs/s':>8} {'turns/s':>8} {'turns/run':>9}  ratio")
    for planner in args.planner:
        rows: dict[str, list[tuple[float, int]]] = {"rddl-dispatch": [], "rddl-server": []}
        for _ in range(args.repeat):
            rows["rddl-dispatch"].append(dispatch_pass(planner, args.runs))
            rows["rddl-server"].append(server_pass(planner, args.runs))
        rates = {}
        for what, runs in rows.items():
            seconds = statistics.median(s for s, _ in runs)
            turns = statistics.median(t for _, t in runs)
            rates[what] = args.runs / seconds
            print(
                f"{planner:<8} {what:<13} {args.runs / seconds:>8.1f} {turns / seconds:>8.0f} "
                f"{turns / args.runs:>9.1f}  "
                + (
                    ""
                    if what == "rddl-dispatch"
                    else f"rddl-dispatch at {rates['rddl-dispatch'] / rates[what]:.2f}x its runs/s"
                )
            )
    print("(a dispatcher run stops at the goal; a rddl-server session plays to the horizon)")


if __name__ == "__main__":
    main()
