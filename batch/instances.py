"""The instances of an experiment: files, folders, globs and rddlrepository problems.

Each spec of an experiment's ``instances`` list is one of:

* a folder: every instance of every ``.rddl`` file under it, paired with its domain by name
  (as ``rddl-server`` serves a folder);
* a ``.rddl`` file, or a glob such as ``"domains/*/instance1.rddl"``: the instances in
  those files, with their domains and non-fluents found by name in the files of the same
  folders;
* an rddlrepository problem, ``NAME`` (all its instances) or ``NAME:1``, ``NAME:1-5``,
  ``NAME:1,3,7``, such as ``"SysAdmin_MDP_ippc2011:1-5"``: the problem's domain file and
  numbered instance files, paired by file as rddlrepository pairs them.

Relative paths are read from the experiment file's folder. Every instance is parsed and
checked here, before anything runs; each problem is reported with the line and column of
its spec.
"""

from __future__ import annotations

import glob
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..rddl import CheckResult, check_files, check_pair
from ..rddl.model import Model
from .experiment import Experiment, ExperimentError, load_experiment, sort_problems

__all__ = ["ResolvedInstance", "check_experiment", "domain_of", "resolve_instances"]

_REPO_SPEC = re.compile(r"^([A-Za-z0-9_\-]+)(?::([0-9,\-\s]+))?$")


@dataclass(frozen=True)
class ResolvedInstance:
    """One instance to play: its name (the session-request's problem-name), its domain's
    name and the files that hold it."""

    name: str
    domain: str
    files: tuple[str, ...]  # what to load: (domain file, instance file) or the spec's files
    paired: bool  # True: files are (domain, instance) paired by file (rddlrepository)
    model: Model


def domain_of(instance_name: str) -> str:
    """The domain of an instance named the IPPC way, as rddlsim's FinalEval derives it
    (``sysadmin_inst_mdp__3`` -> ``sysadmin_mdp``: the part before ``__`` without
    ``_inst``)."""
    return instance_name.split("__")[0].replace("_inst", "")


def _numbers(text: str) -> list[str] | None:
    out: list[str] = []
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        if "-" in part:
            lo, _, hi = part.partition("-")
            if not (lo.isdigit() and hi.isdigit()) or int(lo) > int(hi):
                return None
            out.extend(str(i) for i in range(int(lo), int(hi) + 1))
        elif part.isdigit():
            out.append(str(int(part)))
        else:
            return None
    return out


def _models(
    results: list[CheckResult], spec: str, line: str, problems: list[str]
) -> list[tuple[str, Model]]:
    found: list[tuple[str, Model]] = []
    for res in results:
        if res.kind == "domain" and res.ok:
            continue  # a domain no listed instance uses is fine
        if not res.ok or res.model is None:
            first = res.diagnostics[0].render() if res.diagnostics else "does not check"
            more = f" (and {len(res.diagnostics) - 1} more)" if len(res.diagnostics) > 1 else ""
            problems.append(f"{line}: instance spec '{spec}': {res.name}: {first}{more}")
            continue
        found.append((res.name, res.model))
    return found


def _repository_problem(
    name: str, numbers: str | None, spec: str, line: str, problems: list[str]
) -> list[ResolvedInstance]:
    try:
        from rddlrepository.core.manager import RDDLRepoManager
    except ImportError:
        problems.append(
            f"{line}: instance spec '{spec}' names an rddlrepository problem, but rddlrepository "
            "is not installed (pip install 'ippc[batch]')"
        )
        return []
    manager = RDDLRepoManager()
    if name not in manager.list_problems():
        close = [p for p in manager.list_problems() if p.lower().startswith(name.lower()[:6])][:6]
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        problems.append(
            f"{line}: instance spec '{spec}': no file, folder or rddlrepository problem of that name{hint}"
        )
        return []
    info = manager.get_problem(name)
    available = list(info.list_instances())
    wanted = available if numbers is None else _numbers(numbers)
    if wanted is None:
        problems.append(
            f"{line}: instance spec '{spec}': instance numbers must look like 1, 1-5 or 1,3,7"
        )
        return []
    out: list[ResolvedInstance] = []
    for number in wanted:
        if number not in available:
            problems.append(
                f"{line}: instance spec '{spec}': {name} has no instance {number} (it has {', '.join(available)})"
            )
            continue
        dfile, ifile = info.get_domain(), info.get_instance(number)
        for iname, model in _models(check_pair(dfile, ifile), spec, line, problems):
            out.append(ResolvedInstance(iname, model.domain_name, (dfile, ifile), True, model))
    return out


def resolve_instances(experiment: Experiment) -> list[ResolvedInstance]:
    """Every instance of the experiment, in the order given (a name listed twice is
    kept once); `ExperimentError` lists every spec that does not resolve or check."""
    problems: list[str] = []
    out: list[ResolvedInstance] = []
    where = str(experiment.path) if experiment.path is not None else "<experiment>"
    lines = experiment.instance_lines or tuple((1, 1) for _ in experiment.instances)
    for spec, (lineno, col) in zip(experiment.instances, lines, strict=True):
        line = f"{where}:{lineno}:{col}"
        path = Path(spec).expanduser()
        if not path.is_absolute():
            path = experiment.base_dir / path
        if any(ch in spec for ch in "*?["):
            matched = sorted(glob.glob(str(path), recursive=True))
            if not matched:
                problems.append(f"{line}: instance spec '{spec}': the glob matches no file")
                continue
            files = [Path(m) for m in matched]
        elif path.exists():
            files = [path]
        else:
            m = _REPO_SPEC.match(spec)
            if m is None or os.sep in spec:
                problems.append(f"{line}: instance spec '{spec}': no such file or folder")
                continue
            out.extend(_repository_problem(m.group(1), m.group(2), spec, line, problems))
            continue
        named = {str(f.resolve()) for f in files}
        if path.exists() and path.is_dir():
            results = check_files(*files)
        else:
            files = sorted(
                {g for f in files for g in f.resolve().parent.glob("*.rddl")}
                | {f.resolve() for f in files}
            )
            # a file names its instances; their domain (and non-fluents) may sit in
            # other files of the same folder, as rddlsim's folders hold them
            results = [
                r
                for r in check_files(*files)
                if str(Path(r.file).resolve()) in named and r.kind != "domain"
            ]
        found = _models(results, spec, line, problems)
        if not found and not any(p.startswith(f"{line}:") for p in problems):
            problems.append(f"{line}: instance spec '{spec}': holds no instance")
        for iname, model in found:
            out.append(
                ResolvedInstance(
                    iname, model.domain_name, tuple(str(f) for f in files), False, model
                )
            )
    if problems:
        raise ExperimentError(sort_problems(problems, where), experiment)
    seen: set[str] = set()
    unique: list[ResolvedInstance] = []
    for inst in out:
        if inst.name not in seen:
            seen.add(inst.name)
            unique.append(inst)
    return unique


def check_experiment(path: str | Path) -> tuple[Experiment, list[ResolvedInstance]]:
    """`load_experiment`, and its instances resolved and checked: one `ExperimentError`
    with every problem of the file and of its instances, in the order of the file."""
    try:
        experiment = load_experiment(path)
    except ExperimentError as err:
        if err.partial is None:
            raise
        problems = list(err.problems)
        try:
            resolve_instances(err.partial)
        except ExperimentError as more:
            problems += more.problems
        where = str(err.partial.path) if err.partial.path is not None else "<experiment>"
        raise ExperimentError(sort_problems(problems, where), err.partial) from None
    return experiment, resolve_instances(experiment)
