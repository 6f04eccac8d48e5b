"""Typed syntax tree of RDDL files.

Every node is a frozen dataclass. Each carries a `loc` (file, line, column)
that is left out of equality and hashing, so that two parses of the same text
from different files, or a parse of the writer's output, compare equal.

Expressions keep their surface form where the writer needs it (an object
named with `$` or bare, a `Discrete_` body in brackets or parentheses are not
distinguished: they mean the same). A bare name inside an expression is a
`PVar` with no arguments; the checker decides whether it names an object.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class Loc:
    """A position in a source file: 1-based line and column."""

    file: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


NOWHERE = Loc("<nowhere>", 0, 0)


def _loc() -> Loc:
    return field(default=NOWHERE, compare=False, repr=False)  # type: ignore[return-value]


# ------------------------------------------------------------ expressions


@dataclass(frozen=True, slots=True)
class Const:
    """A literal: bool, int or float (pos-inf and neg-inf are floats)."""

    value: bool | int | float
    loc: Loc = _loc()

    # bool, int and real constants differ in RDDL even where Python's
    # True == 1 == 1.0; compare the kind of value as well.
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Const):
            return NotImplemented
        return type(self.value) is type(other.value) and (
            self.value == other.value or (self.value != self.value and other.value != other.value)
        )

    def __hash__(self) -> int:
        return hash((type(self.value), self.value))


@dataclass(frozen=True, slots=True)
class Var:
    """A parameter or quantified variable, `?x`."""

    name: str
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class EnumLit:
    """An enum value, `@low` (name kept with its `@`)."""

    name: str
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class ObjectLit:
    """An object constant, `$name` or a bare object name (kept without the
    `$`; `dollar` remembers the surface form for the writer)."""

    name: str
    dollar: bool = field(default=True, compare=False)
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class PVar:
    """A pvariable reference `name(args)`; `primed` for next-state `name'`.

    `default` marks rddlsim's `name.default` form (the declared default).
    """

    name: str
    args: tuple[Expr, ...] = ()
    primed: bool = False
    default: bool = False
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Unary:
    """`~e`, `-e` or `+e`."""

    op: str
    operand: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Binary:
    """An infix operation; `op` is one of ^ | => <=> == ~= < <= > >= + - * /.

    `&` is normalised to `^` (they mean the same in RDDL).
    """

    op: str
    left: Expr
    right: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class TypedVar:
    """`?x : type` in a quantifier or aggregation."""

    name: str
    type: str
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Aggregation:
    """`op_{?x : t, ...} body` for sum, prod, min, max, avg, forall, exists,
    argmax, argmin, and any other name (checked later)."""

    op: str
    params: tuple[TypedVar, ...]
    body: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Function:
    """A built-in function in brackets: `exp[x]`, `max[a, b]`, ..."""

    name: str
    args: tuple[Expr, ...]
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class MatrixOp:
    """pyRDDLGym's `cholesky[row=?r, col=?c][expr]` (also inverse, pinverse)."""

    name: str
    row: str
    col: str
    body: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class If:
    cond: Expr
    then: Expr
    else_: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Case:
    """One arm of a switch; `label` is None for `default`."""

    label: Expr | None
    value: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Switch:
    subject: Expr
    cases: tuple[Case, ...]
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Distribution:
    """A distribution with plain arguments: `Bernoulli(p)`, `Normal(m, v)`,
    `Dirichlet(type, alpha)` (the type is then an `PVar` with no arguments)."""

    name: str
    args: tuple[Expr, ...]
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class DiscreteCase:
    """`label : probability`; `prob` is None for `otherwise`."""

    label: Expr
    prob: Expr | None
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Discrete:
    """`Discrete(type, @a : p, ...)` / `UnnormDiscrete(...)`;
    `Multinomial(type, count, ...)` keeps its count in `count`."""

    name: str
    type: str
    cases: tuple[DiscreteCase, ...]
    count: Expr | None = None
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class DiscreteOver:
    """`Discrete_{?x : t, ...}(weights)`: a value of the typed variables drawn
    with the given (normalised, for Discrete) weights."""

    name: str
    params: tuple[TypedVar, ...]
    body: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class VectorDistribution:
    """pyRDDLGym's `MultivariateNormal[?x](mean(?x), cov(?x, ?y))` and kin;
    an index is a variable name, an enum value, or `_`."""

    name: str
    indices: tuple[str, ...]
    args: tuple[Expr, ...]
    loc: Loc = _loc()


Expr = (
    Const
    | Var
    | EnumLit
    | ObjectLit
    | PVar
    | Unary
    | Binary
    | Aggregation
    | Function
    | MatrixOp
    | If
    | Switch
    | Distribution
    | Discrete
    | DiscreteOver
    | VectorDistribution
)

# A constant in a default, non-fluents or init-state value: a Const, an
# EnumLit, or an ObjectLit (a bare object name is an ObjectLit too).
Literal = Const | EnumLit | ObjectLit


# ---------------------------------------------------------------- domain


@dataclass(frozen=True, slots=True)
class TypeDef:
    """`name : object;`, `name : parent;` or `name : {@a, @b};`.

    `kind` is "object", "enum" or "sub" (an object type under `parent`).
    """

    name: str
    kind: str
    parent: str | None = None
    values: tuple[str, ...] = ()
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class PVarDef:
    """A pvariable declaration.

    `kind` is one of non-fluent, state-fluent, interm-fluent, derived-fluent,
    observ-fluent, action-fluent; `range` is bool, int, real or a type name.
    """

    name: str
    params: tuple[str, ...]
    kind: str
    range: str
    default: Literal | None = None
    level: Literal | None = None
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Cpf:
    """`name'(?x, ...) = expr;` (primed for state fluents)."""

    name: str
    primed: bool
    params: tuple[str, ...]
    expr: Expr
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class ObjectsDef:
    """`type : {a, b, c};` in an objects section."""

    type: str
    names: tuple[str, ...]
    name_locs: tuple[Loc, ...] = field(default=(), compare=False, repr=False)
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Domain:
    name: str
    requirements: tuple[str, ...] | None
    types: tuple[TypeDef, ...]
    pvariables: tuple[PVarDef, ...]
    cpfs: tuple[Cpf, ...]
    cpfs_keyword: str
    reward: Expr | None
    state_action_constraints: tuple[Expr, ...]
    action_preconditions: tuple[Expr, ...]
    state_invariants: tuple[Expr, ...]
    termination: tuple[Expr, ...]
    objects: tuple[ObjectsDef, ...] = ()
    loc: Loc = _loc()


# --------------------------------------------------- non-fluents, instance


@dataclass(frozen=True, slots=True)
class Assignment:
    """`name(args) = value;`, `name(args);` (true) or `~name(args);` (false).

    `args` are object names (bare), `@enum` values, or `$`-less object names;
    `value` is None when the value is implied (`name;` or `~name;`) and
    `negated` marks the `~` form.
    """

    name: str
    args: tuple[str, ...]
    value: Literal | None
    negated: bool = False
    loc: Loc = _loc()

    def resolved_value(self) -> Literal:
        if self.value is not None:
            return self.value
        return Const(not self.negated, self.loc)


@dataclass(frozen=True, slots=True)
class NonFluents:
    name: str
    domain: str | None
    objects: tuple[ObjectsDef, ...]
    values: tuple[Assignment, ...]
    loc: Loc = _loc()


@dataclass(frozen=True, slots=True)
class Instance:
    """An instance block, in the 2011/2014 layout (a named non-fluents
    block) or the 2018 layout (objects and non-fluents inline).

    `horizon` is an int, `POS_INF` (the string "pos-inf") or an expression
    (rddlsim's `terminate-when`); `max_nondef_actions` is an int, "pos-inf"
    or None when left out.
    """

    name: str
    domain: str | None
    non_fluents: str | None
    objects: tuple[ObjectsDef, ...]
    non_fluent_values: tuple[Assignment, ...] | None
    init_state: tuple[Assignment, ...] | None
    max_nondef_actions: int | str | None
    horizon: int | str | Expr | None
    discount: float | int | None
    loc: Loc = _loc()


POS_INF = "pos-inf"


@dataclass(frozen=True, slots=True)
class RDDLFile:
    """Everything one file holds, blocks in file order."""

    path: str
    domains: tuple[Domain, ...] = ()
    non_fluents: tuple[NonFluents, ...] = ()
    instances: tuple[Instance, ...] = ()
    loc: Loc = _loc()


def walk(expr: Expr):  # type: ignore[no-untyped-def]
    """Yield `expr` and every sub-expression, parents first."""
    stack: list[Expr] = [expr]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(reversed(children(node)))


def is_draw(node: Expr) -> bool:
    """Whether the node itself draws a random value: every distribution but the
    deterministic KronDelta and DiracDelta."""
    if isinstance(node, (Discrete, DiscreteOver, VectorDistribution)):
        return True
    return isinstance(node, Distribution) and node.name not in ("KronDelta", "DiracDelta")


def has_draws(expr: Expr) -> bool:
    """Whether `expr` draws a random value anywhere."""
    return any(is_draw(node) for node in walk(expr))


def children(node: Expr) -> list[Expr]:
    """The direct sub-expressions of a node, left to right."""
    if isinstance(node, PVar):
        return list(node.args)
    if isinstance(node, Unary):
        return [node.operand]
    if isinstance(node, Binary):
        return [node.left, node.right]
    if isinstance(node, (Aggregation, DiscreteOver, MatrixOp)):
        return [node.body]
    if isinstance(node, (Function, Distribution, VectorDistribution)):
        return list(node.args)
    if isinstance(node, If):
        return [node.cond, node.then, node.else_]
    if isinstance(node, Switch):
        out: list[Expr] = [node.subject]
        for case in node.cases:
            if case.label is not None:
                out.append(case.label)
            out.append(case.value)
        return out
    if isinstance(node, Discrete):
        out = [] if node.count is None else [node.count]
        for dc in node.cases:
            out.append(dc.label)
            if dc.prob is not None:
                out.append(dc.prob)
        return out
    return []
