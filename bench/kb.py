"""Problem generation speed of ippc.kb on the largest IPPC instances.

What it measures
    The ``--count`` largest instance files (by size) of the installed
    ``rddlrepository`` package that ippc.rddl loads, and the print-fetching
    instance of tests/data/kb (the one with a goal, for PDDL). For each:

    load (reference)   ``ippc.rddl.load_pair(domain, instance)``: read, parse
                       and check the pair into a Model; the reference every
                       other figure is divided by, measured in the same run.
    kb                 ``KnowledgeBase.from_model(model)``: the store of every
                       grounding and the operator translation.
    rddl               ``kb.to_rddl_instance()``: the non-fluents and
                       instance blocks of the current state (values that
                       differ from their default).
    rddl explicit      ``kb.to_rddl_instance(explicit=True)``: every
                       grounding written, as ROSPlan's generator did.
    pddl               ``kb.to_pddl()`` (most-likely determinisation), when
                       the domain has a goal; "-" otherwise.

    ROSPlan's users waited 13 s for one RDDL problem on large instances
    (0.5 s after its 2023 batching change, ROSPLAN.md section 2).

How
    Best of ``--repeat`` runs (default 3) with ``time.perf_counter``, after
    one untimed run; ``gc.collect()`` before each timed run, outside the
    timing; log messages silenced.

Usage
    python bench/kb.py [--count N] [--repeat R]
"""

from __future__ import annotations

import argparse
import gc
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import rddlrepository
from ippc.kb import KBError, KnowledgeBase
from ippc.rddl import RDDLError, load_pair


def best(fn: Callable[[], Any], repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        gc.collect()
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def largest(count: int) -> list[tuple[Path, Path]]:
    root = Path(rddlrepository.__file__).parent
    pairs = [
        (dom, inst)
        for dom in root.rglob("domain.rddl")
        for inst in dom.parent.glob("instance*.rddl")
    ]
    pairs.sort(key=lambda p: p[1].stat().st_size, reverse=True)
    out = []
    for dom, inst in pairs:
        try:
            load_pair(dom, inst)
        except RDDLError:
            continue
        out.append((dom, inst))
        if len(out) == count:
            break
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    logging.disable(logging.CRITICAL)
    root = Path(rddlrepository.__file__).parent
    print(
        f"{'instance':58} {'groundings':>10} {'load ms':>9} {'kb':>6} {'rddl':>6} "
        f"{'explicit':>8} {'pddl':>6}   (ratios to load)"
    )
    # the print-fetching domain of the tests: small, but it has a goal (PDDL)
    data = Path(__file__).resolve().parents[1] / "tests" / "data" / "kb"
    extra = [(data / "turtlebot_printing_domain.rddl", data / "turtlebot_printing_instance.rddl")]
    for dom, inst in [*largest(args.count), *extra]:
        model = load_pair(dom, inst)
        kb = KnowledgeBase.from_model(model)
        ground = len(kb.facts(non_fluents=True))
        t_load = best(lambda: load_pair(dom, inst), args.repeat)  # noqa: B023
        t_kb = best(lambda: KnowledgeBase.from_model(model), args.repeat)  # noqa: B023
        t_rddl = best(kb.to_rddl_instance, args.repeat)
        t_exp = best(lambda: kb.to_rddl_instance(explicit=True), args.repeat)  # noqa: B023
        pddl = "-"
        if kb.goal() is not None:
            try:
                pddl = f"{best(kb.to_pddl, args.repeat) / t_load:6.2f}"
            except KBError:
                pddl = "n/a"
        shown = inst.relative_to(root) if inst.is_relative_to(root) else Path(inst.name)
        name = str(shown)[-58:]
        print(
            f"{name:58} {ground:>10} {t_load * 1e3:>9.1f} {t_kb / t_load:>6.2f} "
            f"{t_rddl / t_load:>6.2f} {t_exp / t_load:>8.2f} {pddl:>6}   "
            f"(rddl {t_rddl * 1e3:.1f} ms)"
        )


if __name__ == "__main__":
    main()
