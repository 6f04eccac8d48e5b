"""Time to the first action and peak memory of every built-in planner, on the
largest instance of each IPPC 2011/2014/2018/2023 domain, at 0.1 s a step.

What it measures
    For each planner (default: every built-in one that runs inside the client,
    i.e. all but the external PROST launcher) and each instance (default: the
    highest-numbered instance of each domain of IPPC 2011, 2014, 2018 and 2023
    in the installed ``rddlrepository``, MDP versions), one child process
    loads the instance, builds the planner with its default options (mcts and
    replan with ``time_per_step`` = the step budget) and plays the first turn
    as the client does: ``start_session`` (the start-up) then ``act`` on the
    initial state with the turn's deadline. The child reports

    - ``load``: seconds to parse the files and compile the simulator (the
      client's work, before the planner starts);
    - ``first``: seconds from ``start_session`` to the first action returned
      (the start-up and the first turn's search);
    - ``budget``: the start-up allowance plus the step and the stated margin
      (``ippc.planners.budget.MARGIN``): ``first`` within it is marked ok;
    - ``rss``: peak resident memory of the child (``ru_maxrss`` of
      ``os.wait4``), and ``base``, its peak after loading the instance and
      before the planner; ``rss - base`` is what the planner took, against the
      default memory budget printed beside it;
    - the number of WARNING lines the planner logged (its fallbacks) and the
      error, if the planner refused the instance (exact does on most).

    A child that runs past ``--kill-after`` seconds is killed and reported as
    such. Children get ``RLIMIT_DATA`` of ``--data-limit`` GiB so that a
    planner that allocates without bound cannot take a shared machine with
    it (their default memory budget, a quarter of MemAvailable, is well below).

Usage
    python bench/planner_budgets.py                          # everything, about 40 minutes
    python bench/planner_budgets.py --years 2011 --planners mcts,replan --out part.jsonl
    python bench/planner_budgets.py --table part.jsonl rerun.jsonl   # the table (reruns win)
    python bench/planner_budgets.py --recsim                 # RecSim 2023 #7 with mcts only
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

YEARS = ("2011", "2014", "2018", "2023")
STEP = 0.1


def largest_instances(years: tuple[str, ...]) -> list[tuple[str, Path, Path]]:
    """(name, domain.rddl, instance.rddl) of the highest-numbered MDP
    instance of each domain of these IPPC years in rddlrepository."""
    import rddlrepository

    root = Path(rddlrepository.__file__).parent / "archive" / "competitions"
    out = []
    for year in years:
        for folder in sorted((root / f"IPPC{year}").iterdir()):
            if not folder.is_dir() or folder.name.startswith("__"):
                continue
            insts = [
                p
                for p in folder.rglob("instance*.rddl")
                if "POMDP" not in p.parts and (p.parent / "domain.rddl").exists()
            ]
            if not insts:
                continue
            best = max(insts, key=lambda p: int("".join(c for c in p.stem if c.isdigit()) or 0))
            number = "".join(c for c in best.stem if c.isdigit())
            out.append((f"{folder.name}_{year}#{number}", best.parent / "domain.rddl", best))
    return out


def builtin_planners() -> list[str]:
    """The built-in planners that run inside the client."""
    from ippc.planners.base import BUILTIN_PLANNERS, find_planner

    return [n for n in BUILTIN_PLANNERS if not find_planner(n).external]


# ------------------------------------------------------------------ child


def child(planner: str, domain: str, instance: str, step: float) -> None:
    """One planner's first turn on one instance; prints one JSON line."""
    logging.basicConfig(
        level=logging.WARNING, stream=sys.stderr, format="%(levelname)s %(message)s"
    )
    warnings: list[str] = []

    class Count(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.levelno >= logging.WARNING:
                warnings.append(record.getMessage())

    logging.getLogger().addHandler(Count())
    from ippc.planners import make_planner
    from ippc.planners.base import Observation, SessionInfo
    from ippc.planners.budget import DEFAULT_STARTUP, MARGIN, MIB, memory_budget
    from ippc.rddl import load_pair
    from ippc.rddl.simulator import Simulator

    result: dict[str, Any] = {"planner": planner, "instance": instance}
    t0 = time.monotonic()
    model = load_pair(Path(domain), Path(instance))
    sim = Simulator(model)
    result["load"] = time.monotonic() - t0
    result["base"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    result["memory_budget"] = memory_budget(None) / MIB
    options = {"time_per_step": str(step)} if planner in ("mcts", "replan") else {}
    p = make_planner(planner, options)
    startup = DEFAULT_STARTUP
    if planner == "exact":
        from ippc.planners.exact import DEFAULT_STARTUP as EXACT_STARTUP

        startup = EXACT_STARTUP
    result["budget"] = startup + step + MARGIN
    horizon = model.horizon or 40
    session = SessionInfo(
        instance=Path(instance).stem,
        model=model,
        simulator=sim,
        rounds=1,
        time_allowed=horizon * step,
        seed=1,
    )
    t1 = time.monotonic()
    try:
        p.start_session(session)  # type: ignore[union-attr]
        result["startup"] = time.monotonic() - t1
        p.start_round(1)  # type: ignore[union-attr]
        t2 = time.monotonic()
        obs = Observation(None, sim.initial_state(1), 1, horizon, horizon * step, 0.0, t2 + step)
        action = p.act(obs)  # type: ignore[union-attr]
        result["act"] = time.monotonic() - t2
        result["first"] = time.monotonic() - t1
        result["action"] = len(action)
    except Exception as err:  # noqa: BLE001 - reported, not raised
        result["error"] = f"{type(err).__name__}: {err}"[:300]
        result["first"] = time.monotonic() - t1
    result["warnings"] = len(warnings)
    result["warning_text"] = [w[:200] for w in warnings[:3]]
    engine = getattr(p, "engine", None)
    if engine is not None:
        result["engine"] = engine + (" (C)" if getattr(p, "compiled", False) else "")
    print(json.dumps(result), flush=True)


# ------------------------------------------------------------------ parent


def run_one(
    planner: str,
    name: str,
    domain: Path,
    instance: Path,
    step: float,
    kill_after: float,
    data_gib: float,
) -> dict[str, Any]:
    """Run one child; its JSON with the peak RSS the kernel counted."""
    cmd = [sys.executable, __file__, "--child", planner, str(domain), str(instance), str(step)]
    limit = int(data_gib * (1 << 30))

    def limits() -> None:
        resource.setrlimit(resource.RLIMIT_DATA, (limit, limit))
        os.nice(10)

    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="ippc-budgets-") as cache:
        env["IPPC_CACHE"] = cache  # a cold compile cache: the first session as a competitor's
        t0 = time.monotonic()
        proc = subprocess.Popen(
            cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            preexec_fn=limits,  # noqa: PLW1509 - the child is this script
            env=env,
        )
        killed = False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() - t0 > kill_after:
                proc.send_signal(signal.SIGKILL)
                killed = True
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out = proc.stdout.read().decode() if proc.stdout else ""
    row: dict[str, Any] = {"planner": planner, "instance": name}
    for line in out.splitlines():
        if line.startswith("{"):
            row.update(json.loads(line))
    row["instance"] = name
    row["rss"] = usage.ru_maxrss / 1024
    row["wall"] = time.monotonic() - t0
    if killed:
        row["error"] = f"killed after {kill_after:g} s"
    elif "first" not in row:
        row["error"] = f"child exited with {proc.returncode} and no report"
    return row


def table(rows: list[dict[str, Any]]) -> str:
    """A markdown table of the rows."""
    head = (
        "| instance | planner | load s | first action s | within budget | peak RSS MiB | "
        "planner's MiB | memory budget MiB | warnings | note |\n"
        "|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    for r in rows:
        first = r.get("first")
        ok = (
            "killed"
            if "killed" in r.get("error", "")
            else ("yes" if first is not None and first <= r.get("budget", 0.0) else "**no**")
        )
        took = r.get("rss", 0.0) - r.get("base", 0.0)
        mem_ok = took <= r.get("memory_budget", float("inf"))
        note = r.get("error") or r.get("engine") or ""
        if r.get("warning_text") and not r.get("error"):
            note = (note + "; " if note else "") + r["warning_text"][0][:90]
        lines.append(
            f"| {r['instance']} | {r['planner']} | {r.get('load', 0.0):.1f} | "
            f"{'' if first is None else f'{first:.2f}'} | {ok} | {r.get('rss', 0.0):.0f} | "
            f"{took:.0f}{'' if mem_ok else ' **over**'} | {r.get('memory_budget', 0.0):.0f} | "
            f"{r.get('warnings', 0)} | {note.replace('|', '/')} |"
        )
    return "\n".join(lines)


def compact(rows: list[dict[str, Any]]) -> str:
    """One row per instance, one column per planner: seconds to the first
    action / peak RSS in MiB; **bold** past the budget; "refused" where the
    planner declined the instance; the footnotes say what the planners skipped."""
    planners: list[str] = []
    by_instance: dict[str, dict[str, dict[str, Any]]] = {}
    for r in rows:
        if r["planner"] not in planners:
            planners.append(r["planner"])
        by_instance.setdefault(r["instance"], {})[r["planner"]] = r
    lines = [
        "| instance | " + " | ".join(planners) + " |",
        "|---|" + "---|" * len(planners),
    ]
    for name, got in by_instance.items():
        cells = []
        for p in planners:
            r = got.get(p)
            if r is None:
                cells.append("")
                continue
            first = r.get("first")
            late = first is None or first > r.get("budget", 0.0)
            took = f"{first:.2f} s" if first is not None else "-"
            cell = f"{took} / {r.get('rss', 0.0):.0f}"
            if "killed" in r.get("error", ""):
                cell = f"killed / {r.get('rss', 0.0):.0f}"
            elif r.get("error"):
                cell += " refused" if p == "exact" else " error"
            if late and not r.get("error"):
                cell = f"**{cell}**"
            cells.append(cell)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--child", nargs=4, metavar=("PLANNER", "DOMAIN", "INSTANCE", "STEP"))
    ap.add_argument("--years", default=",".join(YEARS), help="IPPC years, comma-separated")
    ap.add_argument("--domains", default="", help="only these domains (comma-separated names)")
    ap.add_argument("--planners", default="", help="comma-separated (default: every built-in)")
    ap.add_argument("--step", type=float, default=STEP, help="seconds a step (default 0.1)")
    ap.add_argument(
        "--kill-after", type=float, default=150.0, help="seconds before a child is killed"
    )
    ap.add_argument("--data-limit", type=float, default=12.0, help="RLIMIT_DATA of a child, GiB")
    ap.add_argument("--out", type=Path, help="append each row as a JSON line to this file")
    ap.add_argument(
        "--table", type=Path, nargs="+", help="print the table of these JSON-line files"
    )
    ap.add_argument("--recsim", action="store_true", help="RecSim 2023 #7 with mcts only")
    ap.add_argument("--wide", action="store_true", help="--table: one row per planner and instance")
    args = ap.parse_args()
    if args.child:
        planner, domain, instance, step = args.child
        child(planner, domain, instance, float(step))
        return
    if args.table:
        rows = [json.loads(line) for f in args.table for line in f.read_text().splitlines() if line]
        # a later row of the same planner and instance (a rerun) replaces the earlier one
        latest = {(r["instance"], r["planner"]): r for r in rows}
        print((table if args.wide else compact)(list(latest.values())))
        return
    years = tuple(y.strip() for y in args.years.split(",") if y.strip())
    instances = largest_instances(("2023",) if args.recsim else years)
    if args.recsim:
        instances = [i for i in instances if i[0].startswith("RecSim_2023#7")]
    if args.domains:
        wanted = {d.strip() for d in args.domains.split(",")}
        instances = [i for i in instances if i[0].split("_")[0] in wanted]
    planners = (
        ["mcts"]
        if args.recsim
        else ([p.strip() for p in args.planners.split(",") if p.strip()] or builtin_planners())
    )
    print(
        f"# {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load {os.getloadavg()[0]:.2f}",
        file=sys.stderr,
    )
    rows = []
    for name, domain, instance in instances:
        for planner in planners:
            row = run_one(
                planner, name, domain, instance, args.step, args.kill_after, args.data_limit
            )
            rows.append(row)
            print(
                f"{name} {planner}: first {row.get('first', float('nan')):.2f} s, "
                f"rss {row['rss']:.0f} MiB {row.get('error', '')}",
                file=sys.stderr,
                flush=True,
            )
            if args.out:
                with args.out.open("a") as fh:
                    fh.write(json.dumps(row) + "\n")
    print(
        f"# done {time.strftime('%H:%M UTC', time.gmtime())}, load {os.getloadavg()[0]:.2f}",
        file=sys.stderr,
    )
    print((table if args.wide else compact)(rows))


if __name__ == "__main__":
    main()
