"""Loading: files and folders -> checked `Model`s by instance name.

As rddlsim does across a folder, every instance is paired with its domain
and its non-fluents block by name, wherever in the given files they are.
When several files define a domain (or non-fluents block) of the same name,
the one in the instance's own folder wins; two different definitions of one
name in the same folder are an error. Each domain is parsed and checked
once, however many instances use it.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from . import ast as A
from .checker import DomainCheck, build_model, check_domain
from .errors import Diagnostic, RDDLError, RDDLSemanticError, RDDLSyntaxError, source_line
from .model import Model
from .parser import parse

log = logging.getLogger(__name__)


@dataclass
class CheckResult:
    """The outcome for one instance (or, where `instance` is None, for a
    file that did not parse or a domain that no given instance uses)."""

    name: str
    kind: str  # "instance", "domain" or "file"
    file: str
    model: Model | None = None
    diagnostics: list[Diagnostic] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.diagnostics


def rddl_files(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The `.rddl` files named, and those under the folders named, sorted."""
    out: list[Path] = []
    for p in paths:
        path = Path(p)
        if path.is_dir():
            out.extend(sorted(q for q in path.rglob("*.rddl") if q.is_file()))
        elif path.exists():
            out.append(path)
        else:
            raise RDDLError(Diagnostic(A.Loc(str(path), 0, 0), "no-file", "no such file or folder"))
    seen: set[Path] = set()
    unique = []
    for f in out:
        r = f.resolve()
        if r not in seen:
            seen.add(r)
            unique.append(f)
    return unique


def read_text(path: Path) -> str:
    """A RDDL file's text: UTF-8, else Latin-1 (some IPPC files hold a cp1252
    dash, byte 0x96, in a comment)."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


class _Index:
    """Blocks by name, remembering their files."""

    def __init__(self) -> None:
        self.domains: dict[str, list[tuple[A.Domain, str]]] = {}
        self.non_fluents: dict[str, list[tuple[A.NonFluents, str]]] = {}
        self.instances: list[tuple[A.Instance, str]] = []
        self.unparsed: list[str] = []

    def add(self, parsed: A.RDDLFile) -> None:
        for d in parsed.domains:
            self.domains.setdefault(d.name, []).append((d, parsed.path))
        for n in parsed.non_fluents:
            self.non_fluents.setdefault(n.name, []).append((n, parsed.path))
        for i in parsed.instances:
            self.instances.append((i, parsed.path))


def _domain_checker(texts: dict[str, str]) -> Callable[[A.Domain], DomainCheck]:
    """Check each domain once, however many instances use it."""
    done: dict[int, DomainCheck] = {}

    def domain_check(d: A.Domain) -> DomainCheck:
        if id(d) not in done:
            done[id(d)] = check_domain(d, texts)
        return done[id(d)]

    return domain_check


def _mentions_domain(text: str, name: str) -> bool:
    return re.search(r"\bdomain\s+" + re.escape(name) + r"\s*\{", text) is not None


def _pick(candidates: list[tuple[object, str]], near: str) -> tuple[list[tuple[object, str]], bool]:
    """Candidates for a name as seen from file `near`: those in that very
    file if any, else those in its folder, else all. The flag says whether
    the chosen ones disagree."""
    same_file = [c for c in candidates if os.path.abspath(c[1]) == os.path.abspath(near)]
    folder = os.path.dirname(os.path.abspath(near))
    local = [c for c in candidates if os.path.dirname(os.path.abspath(c[1])) == folder]
    chosen = same_file or local or candidates
    if len(chosen) == 1:
        return chosen, False
    first = chosen[0][0]
    return chosen, any(c[0] != first for c in chosen[1:])  # equality ignores positions


def check_files(*paths: str | os.PathLike[str]) -> list[CheckResult]:
    """Parse and check everything under `paths`; one result per instance,
    per unparsable file, and per domain that no instance uses."""
    files = rddl_files(paths)
    texts: dict[str, str] = {}
    index = _Index()
    results: list[CheckResult] = []
    _parse_into(files, texts, index, results)

    domain_check = _domain_checker(texts)

    used_domains: set[int] = set()
    for inst, ifile in index.instances:
        result, used = _check_instance(inst, ifile, index, texts, domain_check, None)
        if used is not None:
            used_domains.add(used)
        results.append(result)

    for name, entries in index.domains.items():
        for d, dfile in entries:
            if id(d) in used_domains:
                continue
            dc = domain_check(d)
            # Without an instance, objects are unknown: drop nothing else.
            results.append(CheckResult(name, "domain", dfile, None, list(dc.diagnostics)))
    return results


def _check_instance(
    inst: A.Instance,
    ifile: str,
    index: _Index,
    texts: dict[str, str],
    domain_check: Callable[[A.Domain], DomainCheck],
    forced: tuple[A.Domain, str] | None,
) -> tuple[CheckResult, int | None]:
    """Pair one instance with its domain and non-fluents, and check it.

    `forced` gives the domain explicitly (a domain file and an instance file
    named as a pair); otherwise the domain is looked up by name."""
    diags: list[Diagnostic] = []

    def err(kind: str, message: str, loc: A.Loc = inst.loc) -> None:
        diags.append(Diagnostic(loc, kind, message, source_line(texts.get(loc.file), loc.line)))

    if forced is not None:
        domain, dfile = forced
        if inst.domain != domain.name:
            log.warning(
                "%s: instance '%s' names domain '%s' but is paired with domain '%s' from %s",
                ifile,
                inst.name,
                inst.domain,
                domain.name,
                dfile,
            )
    else:
        if inst.domain is None:
            err("unknown-domain", f"instance '{inst.name}' names no domain (domain = ...;)")
            return CheckResult(inst.name, "instance", ifile, None, diags), None
        cands = index.domains.get(inst.domain, [])
        if not cands:
            unread = [f for f in index.unparsed if _mentions_domain(texts.get(f, ""), inst.domain)]
            if unread:
                err(
                    "unknown-domain",
                    f"instance '{inst.name}' names domain '{inst.domain}', whose file {unread[0]} has syntax errors",
                )
            else:
                err(
                    "unknown-domain",
                    f"instance '{inst.name}' names domain '{inst.domain}', which is in none of the files given",
                )
            return CheckResult(inst.name, "instance", ifile, None, diags), None
        chosen, clash = _pick(cands, ifile)  # type: ignore[arg-type]
        if clash:
            where = ", ".join(sorted({c[1] for c in chosen}))
            err("duplicate-definition", f"domain '{inst.domain}' is defined differently in {where}")
            return CheckResult(inst.name, "instance", ifile, None, diags), None
        domain, dfile = chosen[0]  # type: ignore[assignment]
    assert isinstance(domain, A.Domain)
    dcheck = domain_check(domain)
    diags.extend(dcheck.diagnostics)

    nf: A.NonFluents | None = None
    nffile: str | None = None
    if inst.non_fluents is not None:
        ncands = index.non_fluents.get(inst.non_fluents, [])
        if not ncands:
            err(
                "unknown-non-fluents",
                f"instance '{inst.name}' names non-fluents '{inst.non_fluents}', which are in none of the files given",
            )
        else:
            nchosen, nclash = _pick(ncands, ifile)  # type: ignore[arg-type]
            if nclash:
                where = ", ".join(sorted({c[1] for c in nchosen}))
                err(
                    "duplicate-definition",
                    f"non-fluents '{inst.non_fluents}' are defined differently in {where}",
                )
            else:
                nf, nffile = nchosen[0]  # type: ignore[assignment]
                assert isinstance(nf, A.NonFluents)
                if forced is None and nf.domain is not None and nf.domain != inst.domain:
                    err(
                        "unknown-domain",
                        f"non-fluents '{nf.name}' are for domain '{nf.domain}', but instance '{inst.name}' is for '{inst.domain}'",
                        nf.loc,
                    )
    if inst.non_fluents is not None and nf is None:
        # Its objects and values are missing: checking the instance's own
        # values now would only repeat that.
        return CheckResult(inst.name, "instance", ifile, None, diags), id(domain)
    # Check the instance even when the domain has errors, so that all
    # problems are reported at once.
    model, idiags = build_model(dcheck, inst, nf, texts, dfile, ifile, nffile)
    diags.extend(idiags)
    return CheckResult(inst.name, "instance", ifile, None if diags else model, diags), id(domain)


def _parse_into(
    files: list[Path], texts: dict[str, str], index: _Index, results: list[CheckResult]
) -> None:
    for f in files:
        text = read_text(f)
        texts[str(f)] = text
        try:
            index.add(parse(text, str(f)))
        except RDDLError as err:
            index.unparsed.append(str(f))
            results.append(CheckResult(f.name, "file", str(f), None, err.diagnostics))


def check_pair(
    domain_file: str | os.PathLike[str], instance_file: str | os.PathLike[str]
) -> list[CheckResult]:
    """Check the instances of `instance_file` against the domain of
    `domain_file`, paired by file as rddlrepository and pyRDDLGym pair them
    (a different domain name in the instance is logged, not fatal). Non-fluents
    blocks are looked up by name in both files."""
    texts: dict[str, str] = {}
    index = _Index()
    results: list[CheckResult] = []
    dpath, ipath = Path(domain_file), Path(instance_file)
    _parse_into(
        rddl_files([dpath, ipath]) if dpath != ipath else rddl_files([dpath]), texts, index, results
    )
    if results:
        return results
    domains = [d for entries in index.domains.values() for d in entries if Path(d[1]) == dpath]
    if len(domains) != 1:
        loc = A.Loc(str(dpath), 1, 1)
        results.append(
            CheckResult(
                dpath.name,
                "file",
                str(dpath),
                None,
                [
                    Diagnostic(
                        loc,
                        "unknown-domain",
                        f"expected one domain block in this file, found {len(domains)}",
                    )
                ],
            )
        )
        return results
    instances = [(i, f) for i, f in index.instances if Path(f) == ipath]
    if not instances:
        loc = A.Loc(str(ipath), 1, 1)
        results.append(
            CheckResult(
                ipath.name,
                "file",
                str(ipath),
                None,
                [Diagnostic(loc, "no-instance", "no instance block in this file")],
            )
        )
        return results
    domain_check = _domain_checker(texts)

    for inst, ifile in instances:
        results.append(_check_instance(inst, ifile, index, texts, domain_check, domains[0])[0])
    return results


def load_pair(
    domain_file: str | os.PathLike[str],
    instance_file: str | os.PathLike[str],
    instance: str | None = None,
) -> Model:
    """The model of an instance file checked against a given domain file."""
    return _models_or_raise(check_pair(domain_file, instance_file), instance)


def _models_or_raise(results: list[CheckResult], instance: str | None) -> Model:
    models = _collect(results)
    if instance is not None:
        if instance not in models:
            raise RDDLError(
                f"no instance '{instance}' (instances found: {', '.join(sorted(models)) or 'none'})"
            )
        return models[instance]
    if len(models) != 1:
        raise RDDLError(f"expected one instance, found: {', '.join(sorted(models)) or 'none'}")
    return next(iter(models.values()))


def load(*paths: str | os.PathLike[str]) -> dict[str, Model]:
    """Load every instance under `paths` (files or folders) as a `Model`.

    Raises `RDDLSyntaxError` or `RDDLSemanticError` with every problem found.
    """
    return _collect(check_files(*paths))


def _collect(results: list[CheckResult]) -> dict[str, Model]:
    models: dict[str, Model] = {}
    diags: list[Diagnostic] = []
    syntax = False
    seen: set[tuple[str, int, int, str]] = set()
    for r in results:
        for d in r.diagnostics:
            key = (d.file, d.line, d.column, d.message)
            if key not in seen:
                seen.add(key)
                diags.append(d)
                syntax = syntax or d.kind == "syntax"
        if r.model is not None:
            if r.name in models and models[r.name].instance != r.model.instance:
                d = Diagnostic(
                    r.model.instance.loc,
                    "duplicate-definition",
                    f"instance '{r.name}' is defined in both {models[r.name].instance_file} and {r.file}",
                )
                diags.append(d)
            models[r.name] = r.model
    if diags:
        raise (RDDLSyntaxError if syntax else RDDLSemanticError)(diags)
    return models


def load_model(*paths: str | os.PathLike[str], instance: str | None = None) -> Model:
    """Load exactly one model: the instance named, or the only one there is."""
    return _models_or_raise(check_files(*paths), instance)
