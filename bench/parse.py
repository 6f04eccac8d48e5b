"""Parse-and-check speed of ippc.rddl against pyRDDLGym on rddlrepository.

What it measures
    Every instance of the installed ``rddlrepository`` package: each folder
    holding a ``domain.rddl``, and each ``instance*.rddl`` beside it (sorted
    by path). For each (domain, instance) pair:

    ours                    ``ippc.rddl.check_pair(domain, instance)``: read
                            both files, parse them and check the instance
                            against its domain into a ``Model``.
    pyRDDLGym parse         ``RDDLReader(domain, instance).rddltxt`` (read
                            both files, strip comments) then
                            ``RDDLParser.parse`` of that text.
    pyRDDLGym parse+model   the above then ``RDDLLiftedModel(ast)``, the step
                            that resolves objects, variables and CPFs and is
                            the closest counterpart of our check.

    A second figure, ``ours by folder``, loads the same instances folder by
    folder with ``ippc.rddl.check_files(domain, *instances)``: each domain
    is parsed and checked once per folder, as a server loading a folder would.

How
    Each measurement is the best of ``--repeat`` runs (default 3) timed with
    ``time.perf_counter``, after one untimed run that also tells whether the
    instance fails; pyRDDLGym's parse and parse+model come from the same runs.
    ``gc.collect()`` runs before each timed run, outside the timing, and
    ``gc.freeze()`` after start-up keeps the imported modules out of every
    collection (for both sides alike). The pyRDDLGym parser is built once,
    before any timing (``pyRDDLGym.core.env`` builds one per environment);
    its lexer and yacc tables are reused for every parse. pyRDDLGym's console
    output and warnings and our log messages are silenced.

    An instance fails on our side if ``check_pair`` raises or returns a result
    with diagnostics, and on pyRDDLGym's if reading, parsing or model building
    raises. Failures are counted and listed, never fatal. Per-side figures
    cover the instances that side handled; the pyRDDLGym/ours ratios cover the
    instances both sides handled (higher = we are faster).

Usage
    python bench/parse.py [--limit N] [--repeat R] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import importlib.util
import io
import json
import logging
import statistics
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ippc.rddl import check_files, check_pair

DEFAULT_REPEAT = 3
SLOWEST_SHOWN = 5
FAILURES_SHOWN = 20
OURS = "ours parse+check"
PY_PARSE = "pyRDDLGym parse"
PY_MODEL = "pyRDDLGym parse+model"
OURS_FOLDERS = "ours by folder (check_files)"


@dataclass(frozen=True)
class Pair:
    """One instance file and the domain file beside it."""

    domain: Path
    instance: Path
    name: str  # path relative to the repository root, for display


@dataclass
class Timing:
    """Best-of-R seconds for one instance, or why it failed."""

    seconds: float | None = None
    error: str | None = None


@dataclass
class InstanceResult:
    pair: Pair
    ours: Timing
    py_parse: Timing | None = None  # None: pyRDDLGym not installed
    py_model: Timing | None = None


@dataclass
class Summary:
    instances: int
    median_ms: float
    p90_ms: float
    total_s: float

    @classmethod
    def of(cls, seconds: list[float]) -> Summary:
        if not seconds:
            return cls(0, float("nan"), float("nan"), 0.0)
        return cls(
            len(seconds),
            statistics.median(seconds) * 1e3,
            percentile(seconds, 90) * 1e3,
            sum(seconds),
        )


@dataclass
class FolderFigure:
    folders: int
    instances: int
    total_s: float
    failures: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------
# corpus


def repository_root() -> Path:
    """The folder of the installed rddlrepository package (not imported)."""
    spec = importlib.util.find_spec("rddlrepository")
    if spec is None or not spec.submodule_search_locations:
        sys.exit("rddlrepository is not installed (pip install rddlrepository)")
    return Path(next(iter(spec.submodule_search_locations)))


def corpus(root: Path) -> list[Pair]:
    """Every instance*.rddl beside a domain.rddl under `root`, sorted."""
    pairs: list[Pair] = []
    for domain in sorted(root.rglob("domain.rddl")):
        for instance in sorted(domain.parent.glob("instance*.rddl")):
            pairs.append(Pair(domain, instance, str(instance.relative_to(root))))
    return pairs


# --------------------------------------------------------------------------
# measuring


def best_of(repeat: int, run: Callable[[], object]) -> float:
    """Fastest of `repeat` timed calls of `run` (exceptions propagate)."""
    best = float("inf")
    for _ in range(repeat):
        gc.collect()
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return best


def describe(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:200]}"


def measure_ours(pair: Pair, repeat: int) -> Timing:
    try:
        results = check_pair(pair.domain, pair.instance)
    except Exception as exc:  # noqa: BLE001 - a benchmark must go on
        return Timing(error=describe(exc))
    bad = [r for r in results if not r.ok]
    if bad or not results:
        first = bad[0].diagnostics[0] if bad else None
        return Timing(
            error=str(first).replace(f"{pair.instance.parent}/", "") if first else "no result"
        )
    return Timing(best_of(repeat, lambda: check_pair(pair.domain, pair.instance)))


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Swallow pyRDDLGym's prints and warnings."""
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


class PyRDDLGym:
    """pyRDDLGym's reader, a parser built once, and its lifted model."""

    def __init__(self) -> None:
        from pyRDDLGym.core.compiler.model import RDDLLiftedModel
        from pyRDDLGym.core.parser.parser import RDDLParser
        from pyRDDLGym.core.parser.reader import RDDLReader

        self._reader = RDDLReader
        self._model = RDDLLiftedModel
        with quiet():
            self._parser = RDDLParser(lexer=None, verbose=False)
            self._parser.build()

    def parse(self, pair: Pair) -> Any:
        text = self._reader(str(pair.domain), str(pair.instance)).rddltxt
        return self._parser.parse(text)

    def model(self, ast: Any) -> Any:
        return self._model(ast)

    def measure(self, pair: Pair, repeat: int) -> tuple[Timing, Timing]:
        """(parse, parse+model) timings, each best of `repeat`. Both come
        from the same runs, so parse+model is never below parse."""
        with quiet():
            try:
                ast = self.parse(pair)
            except Exception as exc:  # noqa: BLE001
                failed = Timing(error=describe(exc))
                return failed, failed
            try:
                self.model(ast)
            except Exception as exc:  # noqa: BLE001
                return Timing(best_of(repeat, lambda: self.parse(pair))), Timing(
                    error=describe(exc)
                )
            best_parse = best_total = float("inf")
            for _ in range(repeat):
                gc.collect()
                start = time.perf_counter()
                ast = self.parse(pair)
                parsed = time.perf_counter()
                self.model(ast)
                done = time.perf_counter()
                best_parse = min(best_parse, parsed - start)
                best_total = min(best_total, done - start)
            return Timing(best_parse), Timing(best_total)


def load_pyrddlgym() -> PyRDDLGym | None:
    try:
        return PyRDDLGym()
    except ImportError:
        return None


def measure_folders(pairs: list[Pair], repeat: int, root: Path) -> FolderFigure:
    """Our total when checking each folder's domain and instances at once."""
    folders: dict[Path, list[Pair]] = {}
    for pair in pairs:
        folders.setdefault(pair.domain, []).append(pair)
    total = 0.0
    failures: list[str] = []
    for domain, members in folders.items():
        files = [domain, *(p.instance for p in members)]
        try:
            results = check_files(*files)
        except Exception as exc:  # noqa: BLE001
            failures.append(f"{members[0].name}: {describe(exc)}")
            continue
        prefix = f"{root}/"
        failures.extend(str(r.diagnostics[0]).replace(prefix, "") for r in results if not r.ok)
        total += best_of(repeat, functools.partial(check_files, *files))
    return FolderFigure(len(folders), len(pairs), total, failures)


# --------------------------------------------------------------------------
# figures


def percentile(values: list[float], pct: float) -> float:
    """Linear-interpolated percentile of a non-empty list."""
    ordered = sorted(values)
    k = (len(ordered) - 1) * pct / 100
    lo = int(k)
    hi = min(lo + 1, len(ordered) - 1)
    return ordered[lo] + (ordered[hi] - ordered[lo]) * (k - lo)


def ratio_figures(
    results: list[InstanceResult], side: Callable[[InstanceResult], Timing | None]
) -> dict[str, float | int]:
    """pyRDDLGym/ours on the instances both sides handled."""
    both = [
        (r.ours.seconds, t.seconds)
        for r in results
        if (t := side(r)) and t.seconds is not None and r.ours.seconds is not None
    ]
    if not both:
        return {"instances": 0, "median": float("nan"), "total": float("nan")}
    ours = [o for o, _ in both]
    theirs = [p for _, p in both]
    return {
        "instances": len(both),
        "median": statistics.median(theirs) / statistics.median(ours),
        "total": sum(theirs) / sum(ours),
    }


def figures(
    results: list[InstanceResult], folder: FolderFigure, repeat: int, elapsed: float, have_py: bool
) -> dict[str, Any]:
    def seconds(side: Callable[[InstanceResult], Timing | None]) -> list[float]:
        return [t.seconds for r in results if (t := side(r)) is not None and t.seconds is not None]

    def failures(side: Callable[[InstanceResult], Timing | None]) -> list[str]:
        return [
            f"{r.pair.name}: {t.error}"
            for r in results
            if (t := side(r)) is not None and t.error is not None
        ]

    sides: dict[str, Callable[[InstanceResult], Timing | None]] = {OURS: lambda r: r.ours}
    if have_py:
        sides[PY_PARSE] = lambda r: r.py_parse
        sides[PY_MODEL] = lambda r: r.py_model
    either = [
        r
        for r in results
        if any((t := s(r)) is not None and t.error is not None for s in sides.values())
    ]
    timed = sorted(
        (r for r in results if r.ours.seconds is not None),
        key=lambda r: r.ours.seconds or 0.0,
        reverse=True,
    )
    out: dict[str, Any] = {
        "instances": len(results),
        "repeat": repeat,
        "pyrddlgym": have_py,
        "summary": {name: vars(Summary.of(seconds(s))) for name, s in sides.items()},
        "ratios": {},
        "slowest_ours": [
            {"instance": r.pair.name, "ms": (r.ours.seconds or 0.0) * 1e3}
            for r in timed[:SLOWEST_SHOWN]
        ],
        "folders": {
            "folders": folder.folders,
            "instances": folder.instances,
            "total_s": folder.total_s,
            "failures": folder.failures,
        },
        "failures": {"either": len(either), **{name: failures(s) for name, s in sides.items()}},
        "elapsed_s": elapsed,
    }
    if have_py:
        out["ratios"] = {
            PY_PARSE: ratio_figures(results, sides[PY_PARSE]),
            PY_MODEL: ratio_figures(results, sides[PY_MODEL]),
        }
    return out


def print_table(fig: dict[str, Any]) -> None:
    print(f"rddlrepository: {fig['instances']} instances, best of {fig['repeat']} runs each")
    if not fig["pyrddlgym"]:
        print("pyRDDLGym not importable: measuring ours only")
    print()
    print(f"{'':30} {'instances':>9} {'median ms':>10} {'p90 ms':>9} {'total s':>9}")
    for name, s in fig["summary"].items():
        print(
            f"{name:30} {s['instances']:9d} {s['median_ms']:10.2f} {s['p90_ms']:9.2f} {s['total_s']:9.2f}"
        )
    fo = fig["folders"]
    print(
        f"{OURS_FOLDERS:30} {fo['instances']:9d} {'':>10} {'':>9} {fo['total_s']:9.2f}   ({fo['folders']} folders)"
    )
    if fig["ratios"]:
        print()
        print("pyRDDLGym / ours (higher = we are faster), on instances both handled:")
        for name, r in fig["ratios"].items():
            print(
                f"  {name:28} median {r['median']:6.2f}x   total {r['total']:6.2f}x   ({r['instances']} instances)"
            )
    print()
    print(f"slowest {SLOWEST_SHOWN} for us:")
    for s in fig["slowest_ours"]:
        print(f"  {s['ms']:9.2f} ms  {s['instance']}")
    print()
    fails = fig["failures"]
    counts = ", ".join(f"{name} {len(v)}" for name, v in fails.items() if name != "either")
    print(
        f"failures: {fails['either']} instances fail on some side ({counts}); folder loads: {len(fo['failures'])}"
    )
    for name, items in fails.items():
        if name == "either" or not items:
            continue
        print(f"  {name}:")
        for line in items[:FAILURES_SHOWN]:
            print(f"    {line}")
        if len(items) > FAILURES_SHOWN:
            print(f"    ... and {len(items) - FAILURES_SHOWN} more")
    for line in fo["failures"][:FAILURES_SHOWN]:
        print(f"  folder: {line}")
    print()
    print(f"run took {fig['elapsed_s']:.1f} s")


# --------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else None)
    ap.add_argument(
        "--limit", type=int, default=None, metavar="N", help="only the first N instances"
    )
    ap.add_argument(
        "--repeat",
        type=int,
        default=DEFAULT_REPEAT,
        metavar="R",
        help="best of R runs (default %(default)s)",
    )
    ap.add_argument(
        "--json", action="store_true", help="print one JSON object instead of the table"
    )
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat must be at least 1")

    logging.getLogger("ippc").setLevel(logging.CRITICAL)
    started = time.perf_counter()
    root = repository_root()
    pairs = corpus(root)[: args.limit]
    py = load_pyrddlgym()
    gc.collect()
    gc.freeze()  # start-up objects: never collected, so collections stay cheap
    results: list[InstanceResult] = []
    for pair in pairs:
        result = InstanceResult(pair, measure_ours(pair, args.repeat))
        if py is not None:
            result.py_parse, result.py_model = py.measure(pair, args.repeat)
        results.append(result)
    folder = measure_folders(pairs, args.repeat, root)
    fig = figures(results, folder, args.repeat, time.perf_counter() - started, py is not None)

    if args.json:
        print(json.dumps(fig, indent=2))
    else:
        print_table(fig)
    return 0


if __name__ == "__main__":
    sys.exit(main())
