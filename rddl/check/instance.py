"""Checking an instance against its checked domain, into a `Model`.

Owns `build_model`: the instance's objects (from the domain, the
non-fluents block and the instance; no duplicates, no objects for enum
types) and the members of each type, the domain's deferred object
references settled, the non-fluent and init-state values checked against
their pvariables (`_literal_value`), the horizon (or terminate-when,
typed like a constraint), discount and max-nondef-actions. May call
`base` and `expressions`.
"""

from __future__ import annotations

from collections.abc import Iterable

from .. import ast as A
from ..errors import Diagnostic
from ..model import NON_FLUENT, STATE, GroundKey, Model, TypeInfo, Value
from .base import DomainCheck, _a, _is_subtype, _literal_value, _Reporter, _show
from .expressions import _ExprChecker


def _objects_of(
    defs: Iterable[A.ObjectsDef],
    types: dict[str, A.TypeDef],
    rep: _Reporter,
    untyped: set[str],
) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    owner: dict[str, str] = {}
    for od in defs:
        td = types.get(od.type)
        if td is None:
            rep.error(od.loc, "unknown-type", f"objects for unknown type '{od.type}'")
            untyped.update(od.names)
            continue
        if td.kind == "enum":
            rep.error(
                od.loc, "type", f"'{od.type}' is an enum type; its values are fixed in the domain"
            )
            continue
        lst = out.setdefault(od.type, [])
        for i, name in enumerate(od.names):
            if name in owner:
                loc = od.name_locs[i] if i < len(od.name_locs) else od.loc
                if owner[name] == od.type:
                    msg = f"object '{name}' is listed twice in type '{od.type}'"
                else:
                    msg = f"object '{name}' is declared twice (as '{owner[name]}' and '{od.type}')"
                rep.error(loc, "duplicate-definition", msg)
                continue
            owner[name] = od.type
            lst.append(name)
    return out


def build_model(
    dcheck: DomainCheck,
    instance: A.Instance,
    non_fluents: A.NonFluents | None,
    texts: dict[str, str],
    domain_file: str,
    instance_file: str,
    non_fluents_file: str | None,
) -> tuple[Model | None, list[Diagnostic]]:
    """Check an instance against its (already checked) domain."""
    rep = _Reporter(texts)
    types = dcheck.types
    pvars = dcheck.pvariables

    object_defs: list[A.ObjectsDef] = list(dcheck.domain.objects)
    if non_fluents is not None:
        object_defs += non_fluents.objects
    object_defs += instance.objects
    untyped_objects: set[str] = set()
    objs = _objects_of(object_defs, types, rep, untyped_objects)

    # Members of each type: own objects, then those of subtypes, in order.
    members: dict[str, list[str]] = {}
    for name, td in types.items():
        members[name] = list(td.values) if td.kind == "enum" else list(objs.get(name, []))
    for name, td in types.items():
        if td.kind == "sub":
            parent = td.parent
            seen = {name}
            while parent is not None and parent in types and parent not in seen:
                seen.add(parent)
                for o in objs.get(name, []):
                    if o not in members[parent]:
                        members[parent].append(o)
                ptd = types[parent]
                parent = ptd.parent if ptd.kind == "sub" else None
    object_type: dict[str, str] = {}
    for tname, lst in objs.items():
        for o in lst:
            object_type[o] = tname

    # Deferred object references from the domain's expressions.
    for ref in dcheck.deferred:
        if ref.name in untyped_objects:
            continue  # declared under an unknown type, reported there
        if ref.name not in object_type:
            if ref.dollar:
                rep.error(ref.loc, "unknown-object", f"unknown object '${ref.name}'")
            else:
                rep.error(
                    ref.loc, "unknown-name", f"'{ref.name}' is neither a pvariable nor an object"
                )
        elif ref.numeric_use is not None:
            rep.error(
                ref.loc,
                "type",
                f"{ref.numeric_use} needs a number or bool, not the object '{ref.name}'",
            )
        elif (
            ref.expected is not None
            and ref.expected in types
            and not _is_subtype(object_type[ref.name], ref.expected, types)
        ):
            rep.error(
                ref.loc,
                "type",
                f"object '{ref.name}' is of type '{object_type[ref.name]}', not '{ref.expected}'",
            )

    enum_values: dict[str, list[str]] = {}
    for td in types.values():
        for v in td.values:
            enum_values.setdefault(v, []).append(td.name)

    def values_of(
        assigns: Iterable[A.Assignment], kinds: tuple[str, ...], section: str
    ) -> dict[GroundKey, Value]:
        out: dict[GroundKey, Value] = {}
        for asg in assigns:
            p = pvars.get(asg.name)
            if p is None:
                rep.error(asg.loc, "unknown-name", f"{section} sets unknown pvariable '{asg.name}'")
                continue
            if p.kind not in kinds:
                rep.error(
                    asg.loc,
                    "bad-assignment",
                    f"{section} can only set {' or '.join(kinds)}s; '{asg.name}' is {_a(p.kind)}",
                )
                continue
            if len(asg.args) != p.arity:
                rep.error(
                    asg.loc,
                    "arity",
                    f"'{asg.name}' takes {p.arity} argument(s), not {len(asg.args)}",
                )
                continue
            args: list[str] = []
            ok = True
            for i, (a, t) in enumerate(zip(asg.args, p.params, strict=True), start=1):
                td = types.get(t)
                if td is not None and td.kind == "enum":
                    v = a if a.startswith("@") else "@" + a
                    if v not in td.values:
                        rep.error(
                            asg.loc,
                            "type",
                            f"argument {i} of '{asg.name}': '{a}' is not a value of enum type '{t}'",
                        )
                        ok = False
                    args.append(v)
                    continue
                if a.startswith("@"):
                    rep.error(
                        asg.loc,
                        "type",
                        f"argument {i} of '{asg.name}' must be an object of type '{t}', not the enum value '{a}'",
                    )
                    ok = False
                elif a in untyped_objects or t not in types:
                    ok = False  # reported where the object or type is declared
                elif a not in object_type:
                    rep.error(
                        asg.loc,
                        "unknown-object",
                        f"argument {i} of '{asg.name}': unknown object '{a}'",
                    )
                    ok = False
                elif not _is_subtype(object_type[a], t, types):
                    rep.error(
                        asg.loc,
                        "type",
                        f"argument {i} of '{asg.name}': object '{a}' is of type '{object_type[a]}', not '{t}'",
                    )
                    ok = False
                args.append(a)
            value = _literal_value(
                asg.resolved_value(),
                p.range,
                types,
                enum_values,
                object_type,
                rep,
                f"the value of '{asg.name}'",
            )
            if not ok or value is None:
                continue
            key = (asg.name, tuple(args))
            if key in out and out[key] != value:
                # The IPPC files repeat some assignments with the same value,
                # which rddlsim accepts; two different values are a mistake.
                shown = f"{asg.name}({', '.join(args)})" if args else asg.name
                rep.error(
                    asg.loc,
                    "duplicate-definition",
                    f"{section} sets {shown} twice, to {_show(out[key])} and {_show(value)}",
                )
                continue
            out[key] = value
        return out

    nf_assigns: list[A.Assignment] = []
    if non_fluents is not None:
        nf_assigns += non_fluents.values
    if instance.non_fluent_values is not None:
        nf_assigns += instance.non_fluent_values
    nf_values = values_of(nf_assigns, (NON_FLUENT,), "non-fluents")
    init = values_of(instance.init_state or (), (STATE,), "init-state")

    horizon: int | None = None
    if instance.horizon is None:
        rep.error(instance.loc, "missing-horizon", f"instance '{instance.name}' has no horizon")
    elif isinstance(instance.horizon, int):
        if instance.horizon < 0:
            rep.error(instance.loc, "type", "the horizon must not be negative")
        horizon = instance.horizon
    elif not isinstance(instance.horizon, str):
        # terminate-when (expr): check it like a constraint (object
        # references it makes are this instance's, not the domain's)
        local = DomainCheck(dcheck.domain, [], types, pvars, dcheck.cpfs)
        ex = _ExprChecker(local, types, enum_values, pvars, rep)
        ex.expect_numeric(ex.infer(instance.horizon, {}), instance.horizon, "terminate-when")
    discount = 1.0 if instance.discount is None else float(instance.discount)
    if not 0.0 <= discount <= 1.0:
        rep.error(instance.loc, "type", f"the discount must be in [0, 1], not {discount}")
    mnd = instance.max_nondef_actions
    max_nondef = None if mnd is None or isinstance(mnd, str) else mnd

    if rep.diagnostics:
        return None, rep.diagnostics
    infos = {
        name: TypeInfo(
            name, "enum" if td.kind == "enum" else "object", td.parent, tuple(members[name]), td.loc
        )
        for name, td in types.items()
    }
    model = Model(
        name=instance.name,
        domain=dcheck.domain,
        instance=instance,
        non_fluents_block=non_fluents,
        types=infos,
        pvariables=dict(pvars),
        cpfs=dict(dcheck.cpfs),
        non_fluent_values=nf_values,
        init_state=init,
        horizon=horizon,
        discount=discount,
        max_nondef_actions=max_nondef,
        domain_file=domain_file,
        instance_file=instance_file,
        non_fluents_file=non_fluents_file,
    )
    return model, []
