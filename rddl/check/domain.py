"""Checking a domain on its own, without objects.

Owns `check_domain`: types (duplicates, unknown parents, cycles),
pvariable declarations (parameter and range types, defaults, levels),
cpfs (one per fluent that needs one, primed where it must be, with the
right number of parameters), then the type of every cpf, the reward and
the constraints through `expressions._ExprChecker`. May call `base` and
`expressions`.
"""

from __future__ import annotations

from .. import ast as A
from ..model import ACTION, DERIVED, INTERM, NON_FLUENT, OBSERV, PRIMITIVE_TYPES, STATE, PVariable
from .base import DomainCheck, _a, _literal_value, _Reporter
from .expressions import _ExprChecker


def check_domain(domain: A.Domain, texts: dict[str, str] | None = None) -> DomainCheck:
    """Check a domain's declarations, cpfs and expressions."""
    rep = _Reporter(texts or {})
    types: dict[str, A.TypeDef] = {}
    enum_values: dict[str, list[str]] = {}
    for td in domain.types:
        if td.name in types or td.name in PRIMITIVE_TYPES:
            rep.error(td.loc, "duplicate-definition", f"type '{td.name}' is defined twice")
            continue
        types[td.name] = td
        if td.kind == "enum":
            seen: set[str] = set()
            for v in td.values:
                if v in seen:
                    rep.error(
                        td.loc,
                        "duplicate-definition",
                        f"enum value '{v}' appears twice in type '{td.name}'",
                    )
                seen.add(v)
                enum_values.setdefault(v, []).append(td.name)
    for td in domain.types:
        if td.kind == "sub" and td.parent is not None:
            parent = types.get(td.parent)
            if parent is None:
                rep.error(
                    td.loc, "unknown-type", f"type '{td.name}' extends unknown type '{td.parent}'"
                )
            elif parent.kind == "enum":
                rep.error(td.loc, "type", f"type '{td.name}' cannot extend enum type '{td.parent}'")
    _check_type_cycles(types, rep)

    pvars: dict[str, PVariable] = {}
    for pd in domain.pvariables:
        if pd.name in pvars:
            rep.error(
                pd.loc,
                "duplicate-definition",
                f"pvariable '{pd.name}' is defined twice (first at line {pvars[pd.name].loc.line})",
            )
            continue
        for ptype in pd.params:
            if ptype not in types:
                if ptype in PRIMITIVE_TYPES:
                    rep.error(
                        pd.loc,
                        "type",
                        f"parameter of '{pd.name}' has type '{ptype}'; parameters must be object or enum types",
                    )
                else:
                    rep.error(
                        pd.loc,
                        "unknown-type",
                        f"parameter of '{pd.name}' has unknown type '{ptype}'",
                    )
        if pd.range not in PRIMITIVE_TYPES and pd.range not in types:
            rep.error(pd.loc, "unknown-type", f"'{pd.name}' has unknown range type '{pd.range}'")
        default = None
        if pd.default is not None:
            default = _literal_value(
                pd.default, pd.range, types, enum_values, None, rep, f"default of '{pd.name}'"
            )
        level = None
        if pd.level is not None:
            lv = pd.level
            if isinstance(lv, A.Const) and type(lv.value) is int and lv.value >= 0:
                level = lv.value
            else:
                rep.error(
                    pd.level.loc if pd.level.loc.line else pd.loc,
                    "type",
                    f"level of '{pd.name}' must be a non-negative integer",
                )
        pvars[pd.name] = PVariable(pd.name, pd.kind, pd.params, pd.range, default, level, pd.loc)

    cpfs: dict[str, A.Cpf] = {}
    for cpf in domain.cpfs:
        target = pvars.get(cpf.name)
        shown = cpf.name + ("'" if cpf.primed else "")
        if cpf.name in cpfs:
            rep.error(
                cpf.loc,
                "duplicate-definition",
                f"'{shown}' has two cpfs (first at line {cpfs[cpf.name].loc.line})",
            )
            continue
        cpfs[cpf.name] = cpf
        if target is None:
            rep.error(cpf.loc, "unknown-name", f"cpf for undeclared pvariable '{shown}'")
            continue
        if target.kind in (NON_FLUENT, ACTION):
            rep.error(
                cpf.loc, "bad-cpf", f"'{cpf.name}' is {_a(target.kind)} and cannot have a cpf"
            )
        elif target.kind == STATE and not cpf.primed:
            rep.error(
                cpf.loc,
                "bad-cpf",
                f"the cpf of state fluent '{cpf.name}' must be written {cpf.name}'",
            )
        elif target.kind != STATE and cpf.primed:
            rep.error(
                cpf.loc,
                "bad-cpf",
                f"only state fluents are primed; '{cpf.name}' is {_a(target.kind)}",
            )
        if len(cpf.params) != target.arity:
            rep.error(
                cpf.loc,
                "arity",
                f"'{cpf.name}' takes {target.arity} parameter(s), its cpf has {len(cpf.params)}",
            )
        if len(set(cpf.params)) != len(cpf.params):
            rep.error(
                cpf.loc, "duplicate-definition", f"the cpf of '{cpf.name}' repeats a parameter"
            )
    for p in pvars.values():
        if p.kind in (STATE, INTERM, DERIVED, OBSERV) and p.name not in cpfs:
            shown = p.name + ("'" if p.kind == STATE else "")
            rep.error(p.loc, "missing-cpf", f"{p.kind} '{p.name}' has no cpf ({shown}(...) = ...)")

    check = DomainCheck(domain, rep.diagnostics, types, pvars, cpfs)
    ex = _ExprChecker(check, types, enum_values, pvars, rep)
    for cpf in domain.cpfs:
        target = pvars.get(cpf.name)
        env: dict[str, str | None] = {}
        if target is not None:
            # bind what the cpf declares (unknown types where the counts differ)
            for i, var in enumerate(cpf.params):
                env[var] = target.params[i] if i < target.arity else None
        else:
            env = {var: None for var in cpf.params}
        t = ex.infer(cpf.expr, env)
        if target is not None:
            ex.expect_assignable(t, target.range, cpf.expr, f"the cpf of '{cpf.name}'")
    if domain.reward is not None:
        t = ex.infer(domain.reward, {})
        ex.expect_numeric(t, domain.reward, "the reward")
    for section in (
        domain.state_action_constraints,
        domain.action_preconditions,
        domain.state_invariants,
        domain.termination,
    ):
        for expr in section:
            t = ex.infer(expr, {})
            ex.expect_numeric(t, expr, "a constraint")
    return check


def _check_type_cycles(types: dict[str, A.TypeDef], rep: _Reporter) -> None:
    for td in types.values():
        seen = {td.name}
        cur = td
        while cur.kind == "sub" and cur.parent in types:
            cur = types[cur.parent]
            if cur.name in seen:
                rep.error(td.loc, "type", f"type '{td.name}' is its own ancestor")
                break
            seen.add(cur.name)
