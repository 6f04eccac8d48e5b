"""One-line expressions over sensor messages, in a restricted evaluator.

A sensing config says how a message becomes a value with a one-line Python
expression, as ROSPlan's sensing interface does (`msg.data > 0.5`,
`msg["waypoint"]`, `[(w, p > 0.5) for ...]` is *not* one). ROSPlan hands
the text to Python's `eval`; here the text is parsed with `ast` and every
node is checked against a short list when the config is loaded:

* names (only those the caller allows, `msg` for a message), literals
  (numbers, strings, True/False/None, tuples, lists, dicts, sets);
* attribute access (`msg.pose.x`; names starting with `_` are refused) and
  item access (`msg["w"]`, `msg.ranges[0]`, slices);
* comparisons (== != < <= > >= in, not in, is, is not), arithmetic
  (+ - * / // % and unary - +), boolean logic (and, or, not), and
  `a if cond else b`.

Anything else (calls, lambdas, comprehensions, `**`, f-strings, walrus,
starred items) is refused with the position inside the expression and the
reason. The accepted tree is turned into nested Python closures, so
evaluation never goes through `eval` or `compile` and costs a few function
calls per node. Attribute access on a mapping reads its key, so a JSON
message (`{"waypoint": "w1"}`) reads as `msg.waypoint` too.
"""

from __future__ import annotations

import ast
import operator
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["EvaluationError", "Expression", "ExpressionError", "compile_expression"]

Env = Mapping[str, Any]
_Fn = Callable[[Env], Any]


class ExpressionError(ValueError):
    """An expression the evaluator refuses; `line` and `column` (1-based)
    are the position inside the expression text, `reason` says why."""

    def __init__(self, text: str, line: int, column: int, reason: str):
        self.text = text
        self.line = line
        self.column = column
        self.reason = reason
        super().__init__(f"{reason} (at column {column} of {text!r})")


class EvaluationError(ValueError):
    """An accepted expression that fails on one message (a missing key, a
    type mismatch, a division by zero); the message names both."""


_COMPARE: dict[type[ast.cmpop], Callable[[Any, Any], Any]] = {
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.In: lambda a, b: a in b,
    ast.NotIn: lambda a, b: a not in b,
    ast.Is: operator.is_,
    ast.IsNot: operator.is_not,
}


def _number(x: Any) -> bool:
    return isinstance(x, int | float)  # bools included, as in Python arithmetic


def _mul(a: Any, b: Any) -> Any:
    # numbers only: "x" * 10**9 would build a gigabyte from one message
    return _numbers_only("*", a, b) * b


_BINARY: dict[type[ast.operator], Callable[[Any, Any], Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: _mul,
    ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv,
    ast.Mod: lambda a, b: _numbers_only("%", a, b) % b,
}


def _numbers_only(symbol: str, a: Any, b: Any) -> Any:
    # "%s" % x would be string formatting, not arithmetic
    if not (_number(a) and _number(b)):
        raise TypeError(
            f"{symbol} applies to numbers only, not {type(a).__name__} and {type(b).__name__}"
        )
    return a


_UNARY: dict[type[ast.unaryop], Callable[[Any], Any]] = {
    ast.Not: operator.not_,
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
}

# What each refused node is called in the error message.
_REFUSED = {
    ast.Call: "function calls are not allowed",
    ast.Lambda: "lambda is not allowed",
    ast.ListComp: "comprehensions are not allowed",
    ast.SetComp: "comprehensions are not allowed",
    ast.DictComp: "comprehensions are not allowed",
    ast.GeneratorExp: "generator expressions are not allowed",
    ast.NamedExpr: ":= is not allowed",
    ast.Starred: "* unpacking is not allowed",
    ast.JoinedStr: "f-strings are not allowed",
    ast.FormattedValue: "f-strings are not allowed",
    ast.Await: "await is not allowed",
    ast.Yield: "yield is not allowed",
    ast.YieldFrom: "yield is not allowed",
}


def _get_attr(obj: Any, name: str) -> Any:
    if isinstance(obj, Mapping):
        if name in obj:
            return obj[name]
        raise KeyError(name)
    return getattr(obj, name)


class _Compiler:
    def __init__(self, text: str, names: Collection[str]):
        self.text = text
        self.allowed = frozenset(names)
        self.used: set[str] = set()

    def fail(self, node: ast.AST, reason: str) -> ExpressionError:
        return ExpressionError(
            self.text, getattr(node, "lineno", 1), getattr(node, "col_offset", 0) + 1, reason
        )

    def compile(self, node: ast.AST) -> _Fn:  # noqa: C901 - one branch per node kind
        if isinstance(node, ast.Constant):
            value = node.value
            if not isinstance(value, bool | int | float | str | type(None)):
                raise self.fail(node, f"a {type(value).__name__} literal is not allowed")
            return lambda env: value
        if isinstance(node, ast.Name):
            name = node.id
            if name not in self.allowed:
                known = ", ".join(sorted(self.allowed)) or "none"
                raise self.fail(node, f"unknown name {name!r} (the names here: {known})")
            self.used.add(name)
            return lambda env: env[name]
        if isinstance(node, ast.Attribute):
            if node.attr.startswith("_"):
                # point at the attribute's name, not at the start of `a.b.c`
                at = ast.Constant(None, lineno=getattr(node, "end_lineno", 1) or 1)
                at.col_offset = (getattr(node, "end_col_offset", 0) or 0) - len(node.attr)
                raise self.fail(at, f"attribute {node.attr!r}: names starting with _ are refused")
            base = self.compile(node.value)
            attr = node.attr
            return lambda env: _get_attr(base(env), attr)
        if isinstance(node, ast.Subscript):
            base = self.compile(node.value)
            index = self.compile(node.slice)
            return lambda env: base(env)[index(env)]
        if isinstance(node, ast.Slice):
            parts = [
                None if p is None else self.compile(p) for p in (node.lower, node.upper, node.step)
            ]
            return lambda env: slice(*(None if p is None else p(env) for p in parts))
        if isinstance(node, ast.Compare):
            left = self.compile(node.left)
            ops = []
            for op, right in zip(node.ops, node.comparators, strict=True):
                fn = _COMPARE.get(type(op))
                if fn is None:  # pragma: no cover - every cmpop is listed
                    raise self.fail(node, f"comparison {type(op).__name__} is not allowed")
                ops.append((fn, self.compile(right)))

            def compare(env: Env) -> bool:
                a = left(env)
                for fn, right_fn in ops:
                    b = right_fn(env)
                    if not fn(a, b):
                        return False
                    a = b
                return True

            return compare
        if isinstance(node, ast.BinOp):
            fn = _BINARY.get(type(node.op))
            if fn is None:
                symbol = {ast.Pow: "**", ast.MatMult: "@", ast.LShift: "<<", ast.RShift: ">>"}.get(
                    type(node.op), type(node.op).__name__
                )
                raise self.fail(node, f"operator {symbol} is not allowed")
            a, b = self.compile(node.left), self.compile(node.right)
            return lambda env: fn(a(env), b(env))
        if isinstance(node, ast.UnaryOp):
            ufn = _UNARY.get(type(node.op))
            if ufn is None:
                raise self.fail(node, "operator ~ is not allowed")
            a = self.compile(node.operand)
            return lambda env: ufn(a(env))
        if isinstance(node, ast.BoolOp):
            operands = [self.compile(v) for v in node.values]
            if isinstance(node.op, ast.And):

                def all_of(env: Env) -> Any:
                    value: Any = True
                    for p in operands:
                        value = p(env)
                        if not value:
                            return value
                    return value

                return all_of

            def any_of(env: Env) -> Any:
                value: Any = False
                for p in operands:
                    value = p(env)
                    if value:
                        return value
                return value

            return any_of
        if isinstance(node, ast.IfExp):
            cond, then, else_ = (self.compile(n) for n in (node.test, node.body, node.orelse))
            return lambda env: then(env) if cond(env) else else_(env)
        if isinstance(node, ast.Tuple | ast.List | ast.Set):
            items = [self.compile(e) for e in node.elts]
            make: Callable[[Any], Any] = {ast.Tuple: tuple, ast.List: list, ast.Set: set}[
                type(node)
            ]
            return lambda env: make(i(env) for i in items)
        if isinstance(node, ast.Dict):
            if any(k is None for k in node.keys):
                raise self.fail(node, "** unpacking is not allowed")
            keys = [self.compile(k) for k in node.keys if k is not None]
            values = [self.compile(v) for v in node.values]
            return lambda env: {k(env): v(env) for k, v in zip(keys, values, strict=True)}
        reason = _REFUSED.get(type(node), f"{type(node).__name__} is not allowed")
        raise self.fail(node, reason)


@dataclass(frozen=True)
class Expression:
    """A checked expression; call `evaluate` with the names it may use."""

    text: str
    names: frozenset[str]  # the names it reads
    _fn: _Fn = field(repr=False, compare=False)

    def evaluate(self, env: Env) -> Any:
        """The value for these names; `EvaluationError` names what failed."""
        try:
            return self._fn(env)
        except (KeyError, IndexError) as err:
            raise EvaluationError(f"{self.text!r}: no {err} in the message") from None
        except RecursionError:
            # a message nested deeper than the interpreter's stack (a self-referencing
            # object, or a value thousands of levels deep)
            raise EvaluationError(f"{self.text!r}: the message is nested too deeply") from None
        except (TypeError, AttributeError, ValueError, ArithmeticError) as err:
            raise EvaluationError(f"{self.text!r}: {err}") from None


def compile_expression(text: str, names: Collection[str] = ("msg",)) -> Expression:
    """Parse and check `text` (one line); `ExpressionError` if refused."""
    if not isinstance(text, str):
        raise ExpressionError(
            str(text), 1, 1, f"an expression must be text, not {type(text).__name__}"
        )
    if "\n" in text.strip():
        raise ExpressionError(text, 1, 1, "an expression is one line")
    try:
        tree = ast.parse(text.strip(), mode="eval")
        compiler = _Compiler(text.strip(), names)
        fn = compiler.compile(tree.body)
    except SyntaxError as err:
        raise ExpressionError(
            text, err.lineno or 1, err.offset or 1, f"syntax error: {err.msg}"
        ) from None
    except (RecursionError, MemoryError):
        # Python's parser (or the compiler here) gives up on thousands of nested
        # operators: refused like any other expression it cannot take
        raise ExpressionError(text, 1, 1, "the expression is nested too deeply") from None
    return Expression(text.strip(), frozenset(compiler.used), fn)
