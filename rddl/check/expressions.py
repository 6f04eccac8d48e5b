"""The type of every expression.

Owns `_ExprChecker`, which infers an expression's type in an environment
of typed variables (`Env`) by calling the method named after its AST class
(`_PVar`, `_Binary`, `_Aggregation`, `_Distribution`...), reports what does
not type (through `base._Reporter`), and records the names that must be
objects of the instance (`base.DeferredObject`, typed `OBJECT_REF` until
then). Also the tables of what RDDL offers: `AGGREGATIONS`, `FUNCTIONS`
(arity and result type) and `DISTRIBUTIONS`. May call `base`.
"""

from __future__ import annotations

from .. import ast as A
from ..model import STATE, PVariable
from .base import DeferredObject, DomainCheck, _a, _is_subtype, _Reporter

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
