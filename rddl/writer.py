"""Typed AST -> canonical RDDL text.

`write(node)` turns any AST node back into RDDL: a whole `RDDLFile`, one
block (`Domain`, `NonFluents`, `Instance`), a block item, or an expression.
The output is canonical: four-space indentation, one item per line,
sections in a fixed order, and expressions on one line with only the
parentheses needed to read back as the same tree. For every AST the parser
produces, `parse(write(tree))` equals `tree` (locations aside) and
`write(parse(write(tree))) == write(tree)`.

Expression layout follows the grammar's precedence, loosest first:

* prefix forms (`if`, aggregations and quantifiers, `Discrete_{...}`),
  whose body extends as far right as it can, and so are always
  parenthesised when they are an operand;
* `<=>`, `=>`, `|`, `^`, comparisons, `+ -`, `* /` (all left-associative);
* unary `~ - +` (the tightest).

Besides what precedence requires, an operand that mixes two different
logical connectives is parenthesised (`(a ^ b) | c`) and nested unary
operators are spelt `-(-x)`, for the reader's sake.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from . import ast as A

__all__ = ["write", "write_expr", "write_literal", "format_number"]

INDENT = "    "

# Binding strength of binary operators (higher binds tighter).
_BINARY_PRECEDENCE: dict[str, int] = {
    "<=>": 1,
    "=>": 2,
    "|": 3,
    "^": 4,
    "&": 4,
    "==": 5,
    "~=": 5,
    "<": 5,
    "<=": 5,
    ">": 5,
    ">=": 5,
    "+": 6,
    "-": 6,
    "*": 7,
    "/": 7,
}
_PREFIX = 0  # if, aggregations, quantifiers, Discrete_{...}: body runs right
_UNARY = 8
_ATOM = 9
_LOGICAL = frozenset({"<=>", "=>", "|", "^", "&"})


# ---------------------------------------------------------------- numbers


def format_number(value: bool | int | float) -> str:
    """A number as RDDL spells it.

    Booleans are `true`/`false`, ints stay ints, infinities are
    `pos-inf`/`neg-inf`, and other floats are written positionally with the
    shortest digits that read back as the same float, always with a `.` and
    a digit after it (`1.0`, `0.00001`, never `1e-05`), so they read back
    as reals.
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            raise ValueError("RDDL has no spelling for NaN")
        if math.isinf(value):
            return "pos-inf" if value > 0 else "neg-inf"
        text = np.format_float_positional(value, unique=True, trim="0")
        if "." not in text:  # not reached with trim="0"; kept as a guard
            text += ".0"
        elif text.endswith("."):
            text += "0"
        return text
    raise TypeError(f"not an RDDL number: {value!r}")


def write_literal(lit: A.Literal) -> str:
    """A constant in a default, level, non-fluents or init-state value.

    Negative numbers are written with their sign (`-3.5`), as the grammar's
    signed numbers allow there.
    """
    if isinstance(lit, A.Const):
        return format_number(lit.value)
    if isinstance(lit, A.EnumLit):
        return lit.name
    if isinstance(lit, A.ObjectLit):
        return ("$" + lit.name) if lit.dollar else lit.name
    raise TypeError(f"not an RDDL literal: {type(lit).__name__}")


# ------------------------------------------------------------ expressions


def _precedence(expr: A.Expr) -> int:
    """How tightly `expr` binds when written without parentheses."""
    if isinstance(expr, A.Binary):
        return _BINARY_PRECEDENCE[expr.op]
    if isinstance(expr, A.Unary):
        return _UNARY
    if isinstance(expr, (A.If, A.Aggregation, A.DiscreteOver)):
        return _PREFIX
    if isinstance(expr, A.Const) and not isinstance(expr.value, bool):
        # A negative number (neg-inf aside) reads back as a unary minus
        # (the tree then differs, but at least the value is kept).
        if math.copysign(1.0, expr.value) < 0 and not math.isinf(expr.value):
            return _UNARY
    return _ATOM


def _paren(text: str) -> str:
    return "(" + text + ")"


def _operand(expr: A.Expr, op: str, right: bool) -> str:
    """An operand of binary `op`, parenthesised where re-reading needs it
    (or a reader would stumble over mixed logical connectives)."""
    text = write_expr(expr)
    prec = _precedence(expr)
    parent = _BINARY_PRECEDENCE[op]
    # Prefix forms (precedence 0) always land here: their body would run on.
    if prec < parent or (right and prec == parent):
        return _paren(text)
    if (
        isinstance(expr, A.Binary)
        and expr.op in _LOGICAL
        and op in _LOGICAL
        and _BINARY_PRECEDENCE[expr.op] != parent
    ):
        return _paren(text)
    return text


def _body(expr: A.Expr) -> str:
    """The body of an aggregation: bare when it is an atom, otherwise in
    parentheses (not needed, as the body runs right, but easier to read)."""
    text = write_expr(expr)
    return text if _precedence(expr) == _ATOM else _paren(text)


def _args(exprs: Iterable[A.Expr]) -> str:
    return ", ".join(write_expr(e) for e in exprs)


def _typed_vars(params: Iterable[A.TypedVar]) -> str:
    return ", ".join(f"{p.name} : {p.type}" for p in params)


def _pvar(expr: A.PVar) -> str:
    name = expr.name + ("'" if expr.primed else "")
    if expr.default:
        if expr.args:
            raise ValueError(f"{expr.name}.default cannot take arguments")
        return name + ".default"
    if expr.args:
        return f"{name}({_args(expr.args)})"
    return name


def _discrete_case(case: A.DiscreteCase) -> str:
    prob = "otherwise" if case.prob is None else write_expr(case.prob)
    return f"{write_expr(case.label)} : {prob}"


def _switch_case(case: A.Case) -> str:
    if case.label is None:
        return f"default : {write_expr(case.value)}"
    return f"case {write_expr(case.label)} : {write_expr(case.value)}"


def write_expr(expr: A.Expr) -> str:
    """An expression on one line, parenthesised so that it parses back to
    the same tree."""
    if isinstance(expr, A.Const):
        return format_number(expr.value)
    if isinstance(expr, (A.Var, A.EnumLit)):
        return expr.name
    if isinstance(expr, A.ObjectLit):
        return ("$" + expr.name) if expr.dollar else expr.name
    if isinstance(expr, A.PVar):
        return _pvar(expr)
    if isinstance(expr, A.Unary):
        operand = write_expr(expr.operand)
        if _precedence(expr.operand) <= _UNARY:
            operand = _paren(operand)
        return expr.op + operand
    if isinstance(expr, A.Binary):
        left = _operand(expr.left, expr.op, right=False)
        right = _operand(expr.right, expr.op, right=True)
        return f"{left} {expr.op} {right}"
    if isinstance(expr, A.Aggregation):
        return f"{expr.op}_{{{_typed_vars(expr.params)}}} {_body(expr.body)}"
    if isinstance(expr, A.DiscreteOver):
        return f"{expr.name}_{{{_typed_vars(expr.params)}}}({write_expr(expr.body)})"
    if isinstance(expr, A.Function):
        return f"{expr.name}[{_args(expr.args)}]"
    if isinstance(expr, A.MatrixOp):
        return f"{expr.name}[row={expr.row}, col={expr.col}][{write_expr(expr.body)}]"
    if isinstance(expr, A.If):
        return (
            f"if ({write_expr(expr.cond)}) then {write_expr(expr.then)} "
            f"else {write_expr(expr.else_)}"
        )
    if isinstance(expr, A.Switch):
        cases = ", ".join(_switch_case(c) for c in expr.cases)
        return f"switch ({write_expr(expr.subject)}) {{ {cases} }}"
    if isinstance(expr, A.Distribution):
        return f"{expr.name}({_args(expr.args)})"
    if isinstance(expr, A.Discrete):
        parts = [expr.type]
        if expr.count is not None:
            parts.append(write_expr(expr.count))
        parts.extend(_discrete_case(c) for c in expr.cases)
        return f"{expr.name}({', '.join(parts)})"
    if isinstance(expr, A.VectorDistribution):
        return f"{expr.name}[{', '.join(expr.indices)}]({_args(expr.args)})"
    raise TypeError(f"not an RDDL expression: {type(expr).__name__}")


# ----------------------------------------------------------------- items


def _type_def(td: A.TypeDef) -> str:
    if td.kind == "object":
        return f"{td.name} : object;"
    if td.kind == "enum":
        return f"{td.name} : {{{', '.join(td.values)}}};"
    if td.kind == "sub":
        if td.parent is None:
            raise ValueError(f"subtype {td.name} has no parent")
        return f"{td.name} : {td.parent};"
    raise ValueError(f"unknown type kind {td.kind!r} for {td.name}")


def _pvar_def(pd: A.PVarDef) -> str:
    head = pd.name + (f"({', '.join(pd.params)})" if pd.params else "")
    fields = [pd.kind, pd.range]
    if pd.default is not None:
        fields.append(f"default = {write_literal(pd.default)}")
    if pd.level is not None:
        fields.append(f"level = {write_literal(pd.level)}")
    return f"{head} : {{{', '.join(fields)}}};"


def _cpf(cpf: A.Cpf) -> str:
    head = cpf.name + ("'" if cpf.primed else "")
    if cpf.params:
        head += f"({', '.join(cpf.params)})"
    return f"{head} = {write_expr(cpf.expr)};"


def _objects_def(od: A.ObjectsDef) -> str:
    return f"{od.type} : {{{', '.join(od.names)}}};"


def _assignment(asg: A.Assignment) -> str:
    text = ("~" if asg.negated else "") + asg.name
    if asg.args:
        text += f"({', '.join(asg.args)})"
    if asg.value is not None:
        text += f" = {write_literal(asg.value)}"
    return text + ";"


def _section(header: str, items: Iterable[str]) -> list[str]:
    """`header { item; ... };` with one item per line (`header { };` when
    empty), unindented: the enclosing block indents it."""
    lines = [INDENT + item for item in items]
    if not lines:
        return [f"{header} {{ }};"]
    return [f"{header} {{", *lines, "};"]


def _block(header: str, sections: list[list[str]]) -> str:
    lines = [f"{header} {{"]
    for sec in sections:
        lines.extend(INDENT + line for line in sec)
    lines.append("}")
    return "\n".join(lines)


# ---------------------------------------------------------------- blocks


def _domain(d: A.Domain) -> str:
    sections: list[list[str]] = []
    if d.requirements is not None:
        sections.append([f"requirements = {{{', '.join(d.requirements)}}};"])
    if d.types:
        sections.append(_section("types", (_type_def(t) for t in d.types)))
    if d.pvariables:
        sections.append(_section("pvariables", (_pvar_def(p) for p in d.pvariables)))
    if d.cpfs or d.cpfs_keyword != "cpfs":
        sections.append(_section(d.cpfs_keyword, (_cpf(c) for c in d.cpfs)))
    if d.reward is not None:
        sections.append([f"reward = {write_expr(d.reward)};"])
    for kind, exprs in (
        ("state-action-constraints", d.state_action_constraints),
        ("action-preconditions", d.action_preconditions),
        ("state-invariants", d.state_invariants),
        ("termination", d.termination),
    ):
        if exprs:
            sections.append(_section(kind, (write_expr(e) + ";" for e in exprs)))
    if d.objects:
        sections.append(_section("objects", (_objects_def(o) for o in d.objects)))
    return _block(f"domain {d.name}", sections)


def _non_fluents(nf: A.NonFluents) -> str:
    sections: list[list[str]] = []
    if nf.domain is not None:
        sections.append([f"domain = {nf.domain};"])
    if nf.objects:
        sections.append(_section("objects", (_objects_def(o) for o in nf.objects)))
    if nf.values:
        sections.append(_section("non-fluents", (_assignment(a) for a in nf.values)))
    return _block(f"non-fluents {nf.name}", sections)


def _horizon(h: int | str | A.Expr) -> str:
    if isinstance(h, bool):
        raise TypeError("horizon cannot be a bool")
    if isinstance(h, int):
        return f"horizon = {h};"
    if h == A.POS_INF:
        return "horizon = pos-inf;"
    if isinstance(h, str):
        raise ValueError(f"unknown horizon {h!r}")
    return f"horizon = terminate-when ({write_expr(h)});"


def _instance(inst: A.Instance) -> str:
    sections: list[list[str]] = []
    if inst.domain is not None:
        sections.append([f"domain = {inst.domain};"])
    if inst.non_fluents is not None:
        sections.append([f"non-fluents = {inst.non_fluents};"])
    if inst.objects:
        sections.append(_section("objects", (_objects_def(o) for o in inst.objects)))
    if inst.non_fluent_values is not None:
        sections.append(_section("non-fluents", (_assignment(a) for a in inst.non_fluent_values)))
    if inst.init_state is not None:
        sections.append(_section("init-state", (_assignment(a) for a in inst.init_state)))
    if inst.max_nondef_actions is not None:
        m = inst.max_nondef_actions
        sections.append([f"max-nondef-actions = {m if isinstance(m, int) else A.POS_INF};"])
    if inst.horizon is not None:
        sections.append([_horizon(inst.horizon)])
    if inst.discount is not None:
        sections.append([f"discount = {format_number(inst.discount)};"])
    return _block(f"instance {inst.name}", sections)


def _file(f: A.RDDLFile) -> str:
    blocks = [
        *(_domain(d) for d in f.domains),
        *(_non_fluents(nf) for nf in f.non_fluents),
        *(_instance(i) for i in f.instances),
    ]
    return "\n\n".join(blocks) + "\n" if blocks else ""


# ------------------------------------------------------------ entry point


def write(
    node: A.RDDLFile
    | A.Domain
    | A.NonFluents
    | A.Instance
    | A.Expr
    | A.TypeDef
    | A.PVarDef
    | A.Cpf
    | A.ObjectsDef
    | A.Assignment
    | A.TypedVar
    | A.Case
    | A.DiscreteCase,
) -> str:
    """Canonical RDDL text for a file, a block, a block item or an expression.

    A file's blocks come in the order domains, non-fluents, instances,
    separated by a blank line, with a final newline; a single block or item
    comes without one.
    """
    if isinstance(node, A.RDDLFile):
        return _file(node)
    if isinstance(node, A.Domain):
        return _domain(node)
    if isinstance(node, A.NonFluents):
        return _non_fluents(node)
    if isinstance(node, A.Instance):
        return _instance(node)
    if isinstance(node, A.TypeDef):
        return _type_def(node)
    if isinstance(node, A.PVarDef):
        return _pvar_def(node)
    if isinstance(node, A.Cpf):
        return _cpf(node)
    if isinstance(node, A.ObjectsDef):
        return _objects_def(node)
    if isinstance(node, A.Assignment):
        return _assignment(node)
    if isinstance(node, A.TypedVar):
        return f"{node.name} : {node.type}"
    if isinstance(node, A.Case):
        return _switch_case(node)
    if isinstance(node, A.DiscreteCase):
        return _discrete_case(node)
    return write_expr(node)
