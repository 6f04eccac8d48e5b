"""An RDDL instance from the knowledge base's current state.

ROSPlan's generator wrote one `non-fluents` block and one `instance` block,
every fact explicitly, asked the knowledge base once per fact (13 s on large
instances until a 2023 change batched the queries), and told fluents from
non-fluents by guessing: a name that some translated effect mentions was a
state fluent, any other a non-fluent, so a state fluent whose cpf the
translator skipped was written into the non-fluents block and the planner's
parser refused the file.

Here the declarations decide (the store keeps each pvariable's kind), the
whole state is read in one pass over the store's arrays (a comparison with
the default per fluent), and only values that differ from the declared
default are written, which is what RDDL means by a value left out (with
`explicit`, every grounding is written, as ROSPlan did). Objects are listed
under their own type (not again under a super-type); enum values are
named, not numbered. The text parses with `ippc.rddl` into a model with the
same values (the tests round-trip IPPC instances), and is what
`KnowledgeBase.to_model` describes.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..rddl import ast as A
from ..rddl.model import NON_FLUENT, STATE, PVariable
from ..rddl.writer import write

if TYPE_CHECKING:
    from .view import KnowledgeView


def _literal(p: PVariable, code: object, names: tuple[str, ...] | None) -> A.Literal:
    if p.range == "bool":
        return A.Const(bool(code))
    if p.range == "int":
        return A.Const(int(code))  # type: ignore[call-overload]
    if p.range == "real":
        return A.Const(float(code))  # type: ignore[arg-type]
    assert names is not None
    name = names[int(code)]  # type: ignore[call-overload]
    return A.EnumLit(name) if name.startswith("@") else A.ObjectLit(name, False)


def _assignments(kb: KnowledgeView, p: PVariable, explicit: bool) -> list[A.Assignment]:
    store = kb._store
    arr = store.arrays[p.name]
    default = store.default_code(p)
    names = kb.model.objects(p.range) if p.range not in ("bool", "int", "real") else None
    if explicit:
        idx = np.argwhere(np.ones(arr.shape, dtype=bool)) if arr.ndim else np.zeros((1, 0), int)
    else:
        idx = np.argwhere(arr != default) if arr.ndim else np.zeros((int(arr != default), 0), int)
    if not len(idx):
        return []
    members = [kb.model.objects(t) for t in p.params]
    values = arr[tuple(idx.T)] if arr.ndim else np.array([arr[()]] * len(idx))
    out = []
    for row, code in zip(idx.tolist(), values.tolist(), strict=True):
        args = tuple(members[i][j] for i, j in enumerate(row))
        lit = _literal(p, code, names)
        if p.range == "bool":  # `name(args);` and `~name(args);` as ROSPlan's readers expect
            out.append(A.Assignment(p.name, args, None, negated=not lit.value))  # type: ignore[union-attr]
        else:
            out.append(A.Assignment(p.name, args, lit))
    return out


def _one_default(kb: KnowledgeView, kind: str) -> list[A.Assignment]:
    """One grounding at its default, so that a section is never empty
    (some planners' parsers refuse `init-state { };`)."""
    for p in kb._store.pvars.values():
        if p.kind != kind:
            continue
        members = [kb.model.objects(t) for t in p.params]
        if any(not m for m in members):
            continue
        args = tuple(m[0] for m in members)
        code = kb._store.default_code(p)
        names = kb.model.objects(p.range) if p.range not in ("bool", "int", "real") else None
        lit = _literal(p, code, names)
        if p.range == "bool":
            return [A.Assignment(p.name, args, None, negated=not lit.value)]  # type: ignore[union-attr]
        return [A.Assignment(p.name, args, lit)]
    return []


def _objects(kb: KnowledgeView) -> tuple[A.ObjectsDef, ...]:
    """Each object once, under its own (most specific) type, in the model's
    order; objects the domain declares itself stay there."""
    model = kb.model
    in_domain = {n for od in model.domain.objects for n in od.names}
    listed: set[str] = set(in_domain)
    children: dict[str, list[str]] = {}
    for t in model.types.values():
        if t.parent is not None:
            children.setdefault(t.parent, []).append(t.name)
    out = []

    def below(t: str) -> set[str]:
        names: set[str] = set()
        for c in children.get(t, []):
            names |= set(model.objects(c))
        return names

    for t in model.types.values():
        if t.kind != "object":
            continue
        sub = below(t.name)
        own = [m for m in t.members if m not in sub and m not in listed]
        if own:
            listed.update(own)
            out.append(A.ObjectsDef(t.name, tuple(own)))
    return tuple(out)


def rddl_instance(
    kb: KnowledgeView,
    name: str | None = None,
    non_fluents_name: str | None = None,
    explicit: bool = False,
) -> str:
    """The RDDL text of a non-fluents block and an instance block for the
    current knowledge (see the module's docstring)."""
    model = kb.model
    domain = model.domain_name
    name = name or f"{domain}__generated_instance"
    nf_name = non_fluents_name or f"nf_{name}"
    with kb._lock:
        nf_values: list[A.Assignment] = []
        init: list[A.Assignment] = []
        for p in kb._store.pvars.values():
            (nf_values if p.kind == NON_FLUENT else init).extend(_assignments(kb, p, explicit))
        if not init:
            init = _one_default(kb, STATE)
        if not nf_values:
            nf_values = _one_default(kb, NON_FLUENT)
        horizon: int | str | A.Expr = A.POS_INF
        if kb.horizon is not None:
            horizon = kb.horizon
        elif model.instance.horizon is not None and not isinstance(model.instance.horizon, int):
            horizon = model.instance.horizon  # pos-inf, or rddlsim's terminate-when
        nf = A.NonFluents(nf_name, domain, _objects(kb), tuple(nf_values))
        inst = A.Instance(
            name,
            domain,
            nf_name,
            (),
            None,
            tuple(init),
            A.POS_INF if kb.max_nondef_actions is None else kb.max_nondef_actions,
            horizon,
            kb.discount,
        )
        return write(A.RDDLFile("<generated>", (), (nf,), (inst,)))
