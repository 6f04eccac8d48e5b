"""Semantic checks: AST -> `Model`, or every problem found.

Theory of operation. A domain is checked once, without objects: types,
pvariable declarations, cpfs and every expression are resolved and typed.
What cannot be decided without objects (a bare name that is not a pvariable
must be an object; a `$name` literal) is recorded as a deferred object
reference with the type the context expects. Each instance then supplies
its objects (inline or through its non-fluents block), which settles the
deferred references, and its values are checked against the declarations.

Types in expressions are strings: "bool", "int", "real", an enum or object
type name, or None where the type is unknown (after an error, or for the
vector forms), which suppresses follow-on errors. Numbers and bools mix
freely in arithmetic and logic as in rddlsim (true is 1); comparing a bool
with a real, mixing enum or object values with numbers, or values of two
unrelated enum or object types are errors.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from . import ast as A
from .errors import Diagnostic, source_line
from .model import (
    ACTION,
    DERIVED,
    INTERM,
    NON_FLUENT,
    OBSERV,
    PRIMITIVE_TYPES,
    STATE,
    GroundKey,
    Model,
    PVariable,
    TypeInfo,
    Value,
)

NUMERIC = ("bool", "int", "real")

AGGREGATIONS = {"sum", "prod", "avg", "min", "max", "forall", "exists", "argmax", "argmin", "det"}

# name -> (min args, max args, result): result "real", "int", "same" (join of args)
FUNCTIONS: dict[str, tuple[int, int, str]] = {
    **{
        f: (1, 1, "real")
        for f in (
            "exp",
            "ln",
            "sqrt",
            "cos",
            "sin",
            "tan",
            "acos",
            "asin",
            "atan",
            "cosh",
            "sinh",
            "tanh",
            "lngamma",
            "gamma",
            "digamma",
            "erf",
            "erfc",
            "logit",
            "sigmoid",
        )
    },
    **{f: (1, 1, "int") for f in ("floor", "ceil", "round", "sgn", "sign")},
    "abs": (1, 1, "same"),
    "min": (2, 2, "same"),
    "max": (2, 2, "same"),
    "pow": (2, 2, "real"),
    "log": (2, 2, "real"),
    "hypot": (2, 2, "real"),
    "fmod": (2, 2, "real"),
    "div": (2, 2, "int"),
    "mod": (2, 2, "same"),
}

# name -> (number of args, result type; "arg" = the type of the argument)
DISTRIBUTIONS: dict[str, tuple[int, str]] = {
    "Bernoulli": (1, "bool"),
    "KronDelta": (1, "arg"),
    "DiracDelta": (1, "real"),
    "Uniform": (2, "real"),
    "Normal": (2, "real"),
    "Exponential": (1, "real"),
    "Poisson": (1, "int"),
    "Weibull": (2, "real"),
    "Gamma": (2, "real"),
    "Binomial": (2, "int"),
    "NegativeBinomial": (2, "int"),
    "Beta": (2, "real"),
    "Geometric": (1, "int"),
    "Pareto": (2, "real"),
    "Student": (1, "real"),
    "Gumbel": (2, "real"),
    "Laplace": (2, "real"),
    "Cauchy": (2, "real"),
    "Gompertz": (2, "real"),
    "ChiSquare": (1, "real"),
    "Kumaraswamy": (2, "real"),
    "Dirichlet": (2, "vector"),
}

OBJECT_REF = "<object>"  # type of a bare name resolved to an object later

# Variables in scope and their types (None: unknown after an error).
Env = dict[str, str | None]


@dataclass
class DeferredObject:
    """A name in the domain that must be an object of the instance."""

    name: str
    expected: str | None  # the type the context asks for, if known
    loc: A.Loc
    dollar: bool
    numeric_use: str | None = None  # set when the context needs a number


@dataclass
class DomainCheck:
    """The result of checking a domain on its own."""

    domain: A.Domain
    diagnostics: list[Diagnostic]
    types: dict[str, A.TypeDef]
    pvariables: dict[str, PVariable]
    cpfs: dict[str, A.Cpf]
    deferred: list[DeferredObject] = field(default_factory=list)


class _Reporter:
    def __init__(self, texts: dict[str, str]):
        self.diagnostics: list[Diagnostic] = []
        self.texts = texts

    def error(self, loc: A.Loc, kind: str, message: str) -> None:
        self.diagnostics.append(
            Diagnostic(loc, kind, message, source_line(self.texts.get(loc.file), loc.line))
        )


# ------------------------------------------------------------ the domain


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


def _literal_value(
    lit: A.Literal,
    rng: str,
    types: dict[str, A.TypeDef],
    enum_values: dict[str, list[str]],
    objects: dict[str, str] | None,
    rep: _Reporter,
    what: str,
) -> Value | None:
    """The Python value of a literal for a pvariable of range `rng`."""
    if isinstance(lit, A.Const):
        v = lit.value
        if rng == "bool":
            if isinstance(v, bool):
                return v
            if type(v) is int and v in (0, 1):
                return bool(v)
            rep.error(lit.loc, "type", f"{what} must be true or false, not {_show(v)}")
            return None
        if rng == "int":
            if type(v) is int or isinstance(v, bool):
                return int(v)
            if isinstance(v, float) and v.is_integer():
                return int(v)
            rep.error(lit.loc, "type", f"{what} must be an integer, not {_show(v)}")
            return None
        if rng == "real":
            return float(v)
        if rng in types:
            rep.error(lit.loc, "type", f"{what} must be a value of type '{rng}', not {_show(v)}")
        return None
    if isinstance(lit, A.EnumLit):
        td = types.get(rng)
        if td is None or td.kind != "enum":
            kind = "an enum value" if lit.name in enum_values else "an unknown enum value"
            rep.error(lit.loc, "type", f"{what} is {kind} '{lit.name}' but the range is '{rng}'")
            return None
        if lit.name not in td.values:
            rep.error(
                lit.loc,
                "type",
                f"'{lit.name}' is not a value of enum type '{rng}' ({', '.join(td.values)})",
            )
            return None
        return lit.name
    # ObjectLit (also a bare name)
    name = lit.name
    td = types.get(rng)
    if td is not None and td.kind == "enum":
        # pyRDDLGym accepts enum values without their '@'.
        if "@" + name in td.values:
            return "@" + name
        rep.error(lit.loc, "type", f"'{name}' is not a value of enum type '{rng}'")
        return None
    if rng in PRIMITIVE_TYPES:
        rep.error(lit.loc, "type", f"{what} must be a {rng}, not the name '{name}'")
        return None
    if objects is not None and rng in types:
        if name not in objects:
            rep.error(lit.loc, "unknown-object", f"unknown object '{name}'")
            return None
        if not _is_subtype(objects[name], rng, types):
            rep.error(lit.loc, "type", f"object '{name}' is of type '{objects[name]}', not '{rng}'")
            return None
    return name


def _a(word: str) -> str:
    return ("an " if word[:1] in "aeiou" else "a ") + word


def _show(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(v)


def _is_subtype(t: str, parent: str, types: dict[str, A.TypeDef]) -> bool:
    seen = set()
    while t not in seen:
        if t == parent:
            return True
        seen.add(t)
        td = types.get(t)
        if td is None or td.kind != "sub" or td.parent is None:
            return False
        t = td.parent
    return False


class _ExprChecker:
    def __init__(
        self,
        check: DomainCheck,
        types: dict[str, A.TypeDef],
        enum_values: dict[str, list[str]],
        pvars: dict[str, PVariable],
        rep: _Reporter,
    ):
        self.check = check
        self.types = types
        self.enum_values = enum_values
        self.pvars = pvars
        self.rep = rep

    # -------------------------------------------------------- helpers

    def compatible(self, a: str | None, b: str | None) -> bool:
        if a is None or b is None:
            return True
        if a in NUMERIC and b in NUMERIC:
            return True
        if a == OBJECT_REF or b == OBJECT_REF:
            other = b if a == OBJECT_REF else a
            return other not in NUMERIC
        return _is_subtype(a, b, self.types) or _is_subtype(b, a, self.types)

    def join(self, a: str | None, b: str | None) -> str | None:
        if a is None or b is None:
            return None
        if a in NUMERIC and b in NUMERIC:
            if "real" in (a, b):
                return "real"
            if a == b == "bool":
                return "bool"
            return "int"
        if a == OBJECT_REF:
            return b
        if b == OBJECT_REF:
            return a
        if _is_subtype(a, b, self.types):
            return b
        if _is_subtype(b, a, self.types):
            return a
        return None

    def describe(self, t: str | None) -> str:
        if t is None:
            return "unknown"
        if t == OBJECT_REF:
            return "an object"
        if t in NUMERIC:
            return t
        td = self.types.get(t)
        kind = "enum" if td is not None and td.kind == "enum" else "object"
        return f"{kind} type '{t}'"

    def deferred_use(self, t: str | None, expr: A.Expr, use: str) -> bool:
        """A bare name used where a number is needed: whether it is unknown
        or an object is only known per instance, so decide there."""
        if t != OBJECT_REF:
            return False
        for ref in reversed(self.check.deferred):
            if ref.loc == expr.loc:
                ref.numeric_use = use
                return True
        return False

    def expect_numeric(self, t: str | None, expr: A.Expr, what: str) -> None:
        if self.deferred_use(t, expr, what):
            return
        if t is not None and t not in NUMERIC:
            self.rep.error(
                expr.loc,
                "type",
                f"{what} must be a number or bool, but this is a value of {self.describe(t)}",
            )

    def expect_assignable(self, t: str | None, rng: str, expr: A.Expr, what: str) -> None:
        if t is None:
            return
        if rng in NUMERIC:
            if t not in NUMERIC:
                self.rep.error(
                    expr.loc,
                    "type",
                    f"{what} must give a {rng}, but gives a value of {self.describe(t)}",
                )
            return
        if rng not in self.types:
            return
        if t in NUMERIC:
            self.rep.error(
                expr.loc,
                "type",
                f"{what} must give a value of {self.describe(rng)}, but gives a {t}",
            )
        elif not self.compatible(t, rng):
            self.rep.error(
                expr.loc,
                "type",
                f"{what} must give a value of {self.describe(rng)}, but gives a value of {self.describe(t)}",
            )

    def expect_arg(self, arg: A.Expr, t: str | None, param: str, owner: str, index: int) -> None:
        if t is None or param not in self.types:
            return  # an unknown parameter type is reported where it is declared
        if isinstance(arg, A.EnumLit):
            td = self.types.get(param)
            if td is None or td.kind != "enum":
                self.rep.error(
                    arg.loc,
                    "type",
                    f"argument {index} of '{owner}' must be an object of type '{param}', not the enum value '{arg.name}'",
                )
            elif arg.name not in td.values:
                self.rep.error(
                    arg.loc,
                    "type",
                    f"argument {index} of '{owner}': '{arg.name}' is not a value of enum type '{param}'",
                )
            return
        if t in NUMERIC:
            self.rep.error(
                arg.loc,
                "type",
                f"argument {index} of '{owner}' must be of type '{param}', not a {t}",
            )
            return
        if not self.compatible(t, param):
            self.rep.error(
                arg.loc,
                "type",
                f"argument {index} of '{owner}' must be of type '{param}', not {self.describe(t)}",
            )

    # -------------------------------------------------------- inference

    def infer(self, e: A.Expr, env: Env, expected: str | None = None) -> str | None:
        method = getattr(self, "_" + type(e).__name__)
        return method(e, env, expected)  # type: ignore[no-any-return]

    def _Const(self, e: A.Const, env: Env, expected: str | None) -> str | None:
        if isinstance(e.value, bool):
            return "bool"
        return "int" if isinstance(e.value, int) else "real"

    def _Var(self, e: A.Var, env: Env, expected: str | None) -> str | None:
        if e.name not in env:
            self.rep.error(e.loc, "unknown-variable", f"variable '{e.name}' is not bound here")
            return None
        return env[e.name]

    def _EnumLit(self, e: A.EnumLit, env: Env, expected: str | None) -> str | None:
        owners = self.enum_values.get(e.name)
        if not owners:
            self.rep.error(e.loc, "unknown-name", f"unknown enum value '{e.name}'")
            return None
        if expected in owners:
            return expected
        return owners[0]

    def _ObjectLit(self, e: A.ObjectLit, env: Env, expected: str | None) -> str | None:
        self.check.deferred.append(DeferredObject(e.name, expected, e.loc, e.dollar))
        return expected if expected in self.types else OBJECT_REF

    def _PVar(self, e: A.PVar, env: Env, expected: str | None) -> str | None:
        p = self.pvars.get(e.name)
        if p is None:
            if not e.args and not e.primed and not e.default:
                # A bare name that is no pvariable: an object (or, in
                # pyRDDLGym's style, an enum value without its '@').
                if (
                    expected is not None
                    and expected in self.types
                    and self.types[expected].kind == "enum"
                ):
                    if "@" + e.name in self.types[expected].values:
                        return expected
                self.check.deferred.append(DeferredObject(e.name, expected, e.loc, False))
                return expected if expected in self.types else OBJECT_REF
            self.rep.error(e.loc, "unknown-name", f"unknown pvariable '{e.name}'")
            for a in e.args:
                self.infer(a, env)
            return None
        if e.primed and p.kind != STATE:
            self.rep.error(
                e.loc,
                "bad-cpf",
                f"only state fluents have a next-state value; '{e.name}' is {_a(p.kind)}",
            )
        rng = p.range if p.range in NUMERIC or p.range in self.types else None
        if e.default:
            return rng
        if len(e.args) != p.arity:
            self.rep.error(
                e.loc, "arity", f"'{e.name}' takes {p.arity} argument(s), not {len(e.args)}"
            )
            for a in e.args:
                self.infer(a, env)
            return rng
        for i, (arg, param) in enumerate(zip(e.args, p.params, strict=True), start=1):
            t = self.infer(arg, env, param)
            self.expect_arg(arg, t, param, e.name, i)
        return rng

    def _Unary(self, e: A.Unary, env: Env, expected: str | None) -> str | None:
        t = self.infer(e.operand, env)
        if self.deferred_use(t, e.operand, f"'{e.op}'"):
            return None
        if t is not None and t not in NUMERIC:
            self.rep.error(
                e.loc, "type", f"'{e.op}' needs a number or bool, not a value of {self.describe(t)}"
            )
            return None
        if e.op == "~":
            return "bool"
        return "int" if t == "bool" else t

    def _Binary(self, e: A.Binary, env: Env, expected: str | None) -> str | None:
        op = e.op
        if op in ("==", "~="):
            lt = self.infer(e.left, env)
            rt = self.infer(e.right, env, lt if lt not in NUMERIC else None)
            if lt == OBJECT_REF and rt is not None and rt not in NUMERIC:
                lt = self.infer_again(e.left, env, rt)
            self._check_comparable(e, lt, rt)
            return "bool"
        lt = self.infer(e.left, env)
        rt = self.infer(e.right, env)
        if op in ("<", "<=", ">", ">="):
            self._check_comparable(e, lt, rt)
            for t, side in ((lt, e.left), (rt, e.right)):
                if t is not None and t not in NUMERIC:
                    self.rep.error(
                        side.loc,
                        "type",
                        f"'{op}' compares numbers, not values of {self.describe(t)}",
                    )
            return "bool"
        for t, side in ((lt, e.left), (rt, e.right)):
            if self.deferred_use(t, side, f"'{op}'"):
                return None
            if t is not None and t not in NUMERIC:
                self.rep.error(
                    side.loc,
                    "type",
                    f"'{op}' needs numbers or bools, not a value of {self.describe(t)}",
                )
                return None
        if op in ("^", "|", "=>", "<=>"):
            return "bool"
        if lt is None or rt is None:
            return None
        if op == "/":
            return "real"
        if "real" in (lt, rt):
            return "real"
        return "int"

    def infer_again(self, e: A.Expr, env: Env, expected: str) -> str | None:
        # Re-resolve a bare object name now that the other side's type is
        # known (drop the deferred reference made without it).
        if (
            isinstance(e, (A.PVar, A.ObjectLit))
            and self.check.deferred
            and self.check.deferred[-1].loc == e.loc
        ):
            self.check.deferred.pop()
        return self.infer(e, env, expected)

    def _check_comparable(self, e: A.Binary, lt: str | None, rt: str | None) -> None:
        if lt is None or rt is None:
            return
        if {lt, rt} == {"bool", "real"}:
            self.rep.error(e.loc, "type", f"'{e.op}' compares a bool with a real")
            return
        if (lt in NUMERIC) != (rt in NUMERIC) or not self.compatible(lt, rt):
            self.rep.error(
                e.loc,
                "type",
                f"'{e.op}' compares a value of {self.describe(lt)} with a value of {self.describe(rt)}",
            )

    def _bind(self, params: tuple[A.TypedVar, ...], env: Env) -> Env:
        inner: Env = dict(env)
        for tv in params:
            if tv.type not in self.types:
                self.rep.error(tv.loc, "unknown-type", f"unknown type '{tv.type}' for '{tv.name}'")
                inner[tv.name] = None
            else:
                inner[tv.name] = tv.type
        return inner

    def _Aggregation(self, e: A.Aggregation, env: Env, expected: str | None) -> str | None:
        inner = self._bind(e.params, env)
        t = self.infer(e.body, inner)
        op = e.op
        if op not in AGGREGATIONS:
            self.rep.error(
                e.loc,
                "unknown-name",
                f"unknown aggregation '{op}_' (expected one of {', '.join(sorted(AGGREGATIONS))})",
            )
            return None
        self.expect_numeric(t, e.body, f"the body of '{op}_'")
        if op in ("forall", "exists"):
            return "bool"
        if op in ("argmax", "argmin"):
            if len(e.params) != 1:
                self.rep.error(e.loc, "arity", f"'{op}_' takes exactly one variable")
                return None
            return e.params[0].type if e.params[0].type in self.types else None
        if op == "det":
            return "real"
        if op == "avg":
            return "real"
        if t == "bool" and op in ("sum", "prod"):
            return "int"
        if t == "bool" and op in ("min", "max"):
            return "bool"
        return t

    def _Function(self, e: A.Function, env: Env, expected: str | None) -> str | None:
        ts = [self.infer(a, env) for a in e.args]
        spec = FUNCTIONS.get(e.name)
        if spec is None:
            self.rep.error(e.loc, "unknown-name", f"unknown function '{e.name}[...]'")
            return None
        lo, hi, res = spec
        if not lo <= len(e.args) <= hi:
            n = str(lo) if lo == hi else f"{lo} to {hi}"
            self.rep.error(e.loc, "arity", f"'{e.name}' takes {n} argument(s), not {len(e.args)}")
            return None
        for t, a in zip(ts, e.args, strict=True):
            self.expect_numeric(t, a, f"an argument of '{e.name}'")
        if res == "same":
            out: str | None = "bool" if all(t == "bool" for t in ts) else "int"
            for t in ts:
                if t is None:
                    return None
                if t == "real":
                    out = "real"
            return "int" if out == "bool" and e.name in ("abs", "mod") else out
        return res

    def _MatrixOp(self, e: A.MatrixOp, env: Env, expected: str | None) -> str | None:
        for v in (e.row, e.col):
            if v not in env:
                self.rep.error(e.loc, "unknown-variable", f"variable '{v}' is not bound here")
        self.infer(e.body, env)
        return "real"

    def _If(self, e: A.If, env: Env, expected: str | None) -> str | None:
        ct = self.infer(e.cond, env)
        self.expect_numeric(ct, e.cond, "an if condition")
        a = self.infer(e.then, env, expected)
        b = self.infer(e.else_, env, expected if a is None or a in NUMERIC else a)
        return self._branches(e, a, b)

    def _branches(self, e: A.Expr, a: str | None, b: str | None) -> str | None:
        if a is None or b is None:
            return None
        j = self.join(a, b)
        if j is None:
            self.rep.error(
                e.loc,
                "type",
                f"the branches give a value of {self.describe(a)} and a value of {self.describe(b)}",
            )
        return j

    def _Switch(self, e: A.Switch, env: Env, expected: str | None) -> str | None:
        st = self.infer(e.subject, env)
        out: str | None = None
        first = True
        for case in e.cases:
            if case.label is not None:
                lt = self.infer(case.label, env, st if st not in NUMERIC else None)
                if (
                    st is not None
                    and lt is not None
                    and not ((st in NUMERIC and lt in NUMERIC) or self.compatible(st, lt))
                ):
                    self.rep.error(
                        case.label.loc,
                        "type",
                        f"case label of {self.describe(lt)} in a switch on {self.describe(st)}",
                    )
                elif isinstance(case.label, A.EnumLit) and st in self.types:
                    td = self.types[st]
                    if td.kind == "enum" and case.label.name not in td.values:
                        self.rep.error(
                            case.label.loc,
                            "type",
                            f"'{case.label.name}' is not a value of enum type '{st}'",
                        )
            vt = self.infer(case.value, env, expected)
            if first:
                out, first = vt, False
            elif out is not None and vt is not None:
                j = self.join(out, vt)
                if j is None:
                    self.rep.error(
                        case.value.loc,
                        "type",
                        f"switch cases give a value of {self.describe(out)} and a value of {self.describe(vt)}",
                    )
                out = j
            else:
                out = None
        return out

    def _Distribution(self, e: A.Distribution, env: Env, expected: str | None) -> str | None:
        n, res = DISTRIBUTIONS[e.name]
        if e.name == "Dirichlet":
            self.infer(e.args[1], env)
            return None
        if len(e.args) != n:
            self.rep.error(e.loc, "arity", f"{e.name} takes {n} argument(s), not {len(e.args)}")
            for a in e.args:
                self.infer(a, env)
            return None
        ts = [self.infer(a, env, expected if res == "arg" else None) for a in e.args]
        if res == "arg":
            return "int" if ts[0] == "bool" and expected == "int" else ts[0]
        for t, a in zip(ts, e.args, strict=True):
            self.expect_numeric(t, a, f"a parameter of {e.name}")
        return res

    def _Discrete(self, e: A.Discrete, env: Env, expected: str | None) -> str | None:
        td = self.types.get(e.type)
        if td is None:
            self.rep.error(e.loc, "unknown-type", f"{e.name} over unknown type '{e.type}'")
        if e.count is not None:
            self.expect_numeric(self.infer(e.count, env), e.count, f"the count of {e.name}")
        for dc in e.cases:
            if td is not None:
                if isinstance(dc.label, A.EnumLit):
                    if td.kind != "enum" or dc.label.name not in td.values:
                        self.rep.error(
                            dc.label.loc,
                            "type",
                            f"'{dc.label.name}' is not a value of type '{e.type}'",
                        )
                else:
                    assert isinstance(dc.label, A.ObjectLit)
                    if td.kind == "enum":
                        if "@" + dc.label.name not in td.values:
                            self.rep.error(
                                dc.label.loc,
                                "type",
                                f"'{dc.label.name}' is not a value of type '{e.type}'",
                            )
                    else:
                        self.check.deferred.append(
                            DeferredObject(dc.label.name, e.type, dc.label.loc, True)
                        )
            if dc.prob is not None:
                self.expect_numeric(self.infer(dc.prob, env), dc.prob, f"a probability of {e.name}")
        if e.name == "Multinomial":
            return None
        return e.type if td is not None else None

    def _DiscreteOver(self, e: A.DiscreteOver, env: Env, expected: str | None) -> str | None:
        inner = self._bind(e.params, env)
        self.expect_numeric(self.infer(e.body, inner), e.body, f"the weights of {e.name}_")
        if len(e.params) != 1:
            self.rep.error(e.loc, "arity", f"{e.name}_ takes exactly one variable")
            return None
        t = e.params[0].type
        return t if t in self.types else None

    def _VectorDistribution(
        self, e: A.VectorDistribution, env: Env, expected: str | None
    ) -> str | None:
        for a in e.args:
            if isinstance(a, A.PVar) and a.name in self.pvars:
                continue  # vector arguments are indexed by the free slots
            self.infer(a, env)
        return None


# ------------------------------------------------------------ instances


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
