"""RDDL as PDDL text: the names (`_Names`), and `_Translator`, the base of
the writer, which holds what one run of the writer collects (notes, static
predicates and their facts, constants) and translates conditions (`formula`,
with static predicates for what reads only non-fluents) and effects (`effect`,
`wrap`) of the knowledge base's operators. The determinisation of draws
(`determinisation.py`), the action costs (`costs.py`) and the two texts
(`writer.py`) build on it.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from ...rddl import ast as A
from ...rddl.model import ACTION, NON_FLUENT
from ...rddl.writer import write_expr
from ..evaluate import NotEvaluable
from ..exprs import TRUE, free_vars
from ..operators import Atom, Effect
from ..store import KBError

if TYPE_CHECKING:
    from ..view import KnowledgeView

MODES = ("most-likely", "all-outcomes")
EXOGENOUS_MODES = ("current", "most-likely", "outcomes")
_NAME = re.compile(r"[^A-Za-z0-9_-]")


class _Names:
    """RDDL names as PDDL names: letters, digits, '-' and '_', a letter
    first, and distinct without regard to case within one kind."""

    def __init__(self) -> None:
        self.map: dict[tuple[str, str], str] = {}
        self.used: dict[str, set[str]] = {}

    def __call__(self, kind: str, name: str) -> str:
        key = (kind, name)
        if key in self.map:
            return self.map[key]
        base = _NAME.sub("_", name.lstrip("@?")) or "x"
        if not base[0].isalpha():
            base = "n" + base
        used = self.used.setdefault(kind, set())
        out = base
        for n in itertools.count(1):
            if out.lower() not in used and out.lower() not in ("object", "either", "number"):
                break
            out = f"{base}_{n}"
        used.add(out.lower())
        self.map[key] = out
        return out


class _Translator:
    """Conditions and effects of the operators in PDDL, and what one writing
    collects on the way."""

    def __init__(self, kb: KnowledgeView, mode: str, exogenous: str = "current"):
        if mode not in MODES:
            raise KBError(
                f"unknown determinisation {mode!r} (one of {', '.join(MODES)})", "bad-params"
            )
        if exogenous not in EXOGENOUS_MODES:
            raise KBError(
                f"unknown exogenous {exogenous!r} (one of {', '.join(EXOGENOUS_MODES)})",
                "bad-params",
            )
        self.exogenous = exogenous
        self.kb = kb
        self.model = kb.model
        self.mode = mode
        self.names = _Names()
        self.notes: list[str] = []
        self.static_preds: list[str] = []  # declarations
        self.static_facts: list[str] = []
        self.cost_classes: dict[str, list[tuple[int, str]]] = {}  # op -> (cost, predicate)
        self.constants: set[str] = set()  # RDDL object names used in the domain
        self.uses_never = False
        self._static_cache: dict[tuple[str, tuple[tuple[str, str], ...]], str] = {}
        self.stored = kb._store.pvars
        self.action_names = frozenset(p.name for p in self.model.fluents(ACTION))
        self.objects_of_type: dict[str, tuple[str, ...]] = {
            t: info.members for t, info in self.model.types.items()
        }
        # every object and enum value gets its PDDL name up front (objects first)
        for info in self.model.types.values():
            for m in info.members:
                self.obj(m)

    # -- names

    def obj(self, name: str) -> str:
        return self.names("object", name)

    def pred(self, name: str) -> str:
        return self.names("predicate", name)

    def typ(self, name: str) -> str:
        return self.names("type", name)

    def var(self, name: str) -> str:
        return "?" + _NAME.sub("_", name.lstrip("?"))

    def note(self, where: str, what: str) -> None:
        line = f"{where}: {what}"
        if line not in self.notes:
            self.notes.append(line)

    # -- formulas

    def term(self, e: A.Expr) -> str | None:
        if isinstance(e, A.Var):
            return self.var(e.name)
        if isinstance(e, (A.ObjectLit, A.EnumLit)):
            self.constants.add(e.name)
            return self.obj(e.name)
        if isinstance(e, A.PVar) and not e.args and e.name not in self.model.pvariables:
            self.constants.add(e.name)
            return self.obj(e.name)
        return None

    def atom(self, a: Atom) -> str:
        args = [self.var(x) if x.startswith("?") else self._const(x) for x in a.args]
        return f"({' '.join([self.pred(a.fluent), *args])})"

    def _const(self, name: str) -> str:
        self.constants.add(name)
        return self.obj(name)

    def is_static(self, e: A.Expr) -> bool:
        for n in A.walk(e):
            if isinstance(n, A.PVar) and n.name in self.model.pvariables:
                if self.model.pvariables[n.name].kind != NON_FLUENT:
                    return False
        return True

    def formula(self, e: A.Expr, types: dict[str, str]) -> str | None:
        """`e` in PDDL, with `types` the types of its free variables; None
        where it cannot be written."""
        if e == TRUE:
            return "(and)"
        if e == A.Const(False):
            self.uses_never = True
            return "(ippc-never)"
        if isinstance(e, A.PVar) and not e.primed:
            p = self.stored.get(e.name)
            if p is not None and p.range == "bool":
                args = [self.term(a) for a in e.args]
                if all(a is not None for a in args):
                    return f"({' '.join([self.pred(e.name), *args])})"  # type: ignore[list-item]
        if isinstance(e, A.Unary) and e.op == "~":
            inner = self.formula(e.operand, types)
            return None if inner is None else f"(not {inner})"
        if isinstance(e, A.Binary) and e.op in ("^", "&", "|", "=>", "<=>"):
            left, right = self.formula(e.left, types), self.formula(e.right, types)
            if left is None or right is None:
                return self.static(e, types)
            if e.op in ("^", "&"):
                return f"(and {left} {right})"
            if e.op == "|":
                return f"(or {left} {right})"
            if e.op == "=>":
                return f"(imply {left} {right})"
            return f"(and (imply {left} {right}) (imply {right} {left}))"
        if isinstance(e, A.Binary) and e.op in ("==", "~="):
            out = self.equality(e.left, e.right) or self.equality(e.right, e.left)
            if out is not None:
                return out if e.op == "==" else f"(not {out})"
        if isinstance(e, A.Aggregation) and e.op in ("exists", "forall"):
            inner_types = {**types, **{p.name: p.type for p in e.params}}
            body = self.formula(e.body, inner_types)
            if body is not None:
                params = " ".join(f"{self.var(p.name)} - {self.typ(p.type)}" for p in e.params)
                return f"({e.op} ({params}) {body})"
        return self.static(e, types)

    def equality(self, a: A.Expr, b: A.Expr) -> str | None:
        ta, tb = self.term(a), self.term(b)
        if ta is not None and tb is not None:
            return f"(= {ta} {tb})"
        if isinstance(a, A.PVar) and not a.primed and tb is not None:
            p = self.stored.get(a.name)
            if p is not None and p.range not in ("bool", "int", "real"):
                args = [self.term(x) for x in a.args]
                if all(x is not None for x in args):
                    return f"({' '.join([self.pred(a.name), *args, tb])})"  # type: ignore[list-item]
        return None

    def static(self, e: A.Expr, types: dict[str, str]) -> str | None:
        """A condition on non-fluents only, decided now as a static predicate."""
        if not self.is_static(e) or any(
            isinstance(n, A.PVar)
            and n.name in self.model.pvariables
            and self.model.pvariables[n.name].kind == ACTION
            for n in A.walk(e)
        ):
            return None
        fv = sorted(free_vars(e))
        if any(v not in types for v in fv):
            return None
        key = (write_expr(e), tuple((v, types[v]) for v in fv))
        if key in self._static_cache:
            name = self._static_cache[key]
        else:
            name = self.names("predicate", f"ippc-static-{len(self._static_cache) + 1}")
            self._static_cache[key] = name
            params = " ".join(f"?x{i} - {self.typ(types[v])}" for i, v in enumerate(fv))
            self.static_preds.append(f"({name}{' ' + params if params else ''})")
            for binding in itertools.product(*(self.objects_of_type[types[v]] for v in fv)):
                try:
                    holds = bool(self.kb._evaluator(e, dict(zip(fv, binding, strict=True))))
                except NotEvaluable:
                    return None
                if holds:
                    self.static_facts.append(f"({' '.join([name, *map(self.obj, binding)])})")
        return f"({' '.join([name, *map(self.var, fv)])})"

    # -- effects

    def effect(self, op: str, e: Effect, types: dict[str, str]) -> str | None:
        body: str | None
        p = self.stored.get(e.atom.fluent)
        if e.kind in ("add", "delete"):
            body = self.atom(e.atom) if e.kind == "add" else f"(not {self.atom(e.atom)})"
        elif p is not None and p.range not in ("bool", "int", "real") and e.kind == "assign":
            value = None if e.value_expr is None else self.term(e.value_expr)
            if value is None:
                self.note(op, f"the value of {e.atom} is computed ({e.value}): left out")
                return None
            atom = self.atom(e.atom)[1:-1]
            old = self.var("ippc-old")
            body = f"(and (forall ({old} - {self.typ(p.range)}) (not ({atom} {old}))) ({atom} {value}))"
        else:
            self.note(op, f"a numeric effect ({e}): left out")
            return None
        inner = {**types, **{"?" + q.name: q.type for q in e.forall}}
        return self.wrap(op, body, e.condition_expr, e.forall, inner)

    def wrap(
        self, op: str, body: str, condition: A.Expr, forall: Iterable[Any], types: dict[str, str]
    ) -> str:
        if condition != TRUE:
            cond = self.formula(condition, types)
            if cond is None:
                self.note(op, f"the condition {write_expr(condition)} cannot be written: dropped")
            else:
                body = f"(when {cond} {body})"
        params = " ".join(f"{self.var(q.name)} - {self.typ(q.type)}" for q in forall)
        return f"(forall ({params}) {body})" if params else body
