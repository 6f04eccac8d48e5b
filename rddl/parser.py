"""RDDL text -> typed AST.

The grammar (`rddl.lark`, package data) is compiled once per process into a
LALR parser whose callbacks build the AST directly (no intermediate parse
tree), which keeps parsing fast on the large IPPC instance files.

Syntax errors are reported in a modeller's words: the file, line and column,
the token found, and what could have stood there ("expected ';'", "expected
an expression"), with a suggestion for misspelt keywords. When a file has an
error, each top-level block is parsed on its own as well, so that errors in
several blocks are all reported.
"""

from __future__ import annotations

import difflib
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

from lark import Lark, Token, Transformer, v_args
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from . import ast as A
from .errors import Diagnostic, RDDLSyntaxError, source_line
from .lexer import RDDLLexer

# Distributions written as `Name(args)`; every other `name(args)` in an
# expression is a pvariable.
DISTRIBUTIONS = frozenset(
    {
        "Bernoulli",
        "KronDelta",
        "DiracDelta",
        "Uniform",
        "Normal",
        "Exponential",
        "Poisson",
        "Weibull",
        "Gamma",
        "Binomial",
        "NegativeBinomial",
        "Beta",
        "Geometric",
        "Pareto",
        "Student",
        "Gumbel",
        "Laplace",
        "Cauchy",
        "Gompertz",
        "ChiSquare",
        "Kumaraswamy",
        "Dirichlet",
    }
)


def _tok_loc(file: str, tok: Token) -> A.Loc:
    return A.Loc(file, tok.line or 0, tok.column or 0)


def _strip_prime(name: str) -> tuple[str, bool]:
    if name.endswith("'"):
        return name[:-1], True
    return name, False


@v_args(inline=True)
class _Builder(Transformer):  # type: ignore[type-arg]
    """Builds AST nodes as the LALR parser reduces rules."""

    def __init__(self) -> None:
        super().__init__(visit_tokens=False)
        self.file = "<string>"

    def _at(self, first: Any) -> A.Loc:
        """The position of a rule: that of its first kept child."""
        if isinstance(first, tuple):  # the children of a rule
            first = first[0] if first else None
        if isinstance(first, Token):
            return A.Loc(self.file, first.line or 0, first.column or 0)
        loc = getattr(first, "loc", None)
        if isinstance(loc, A.Loc):
            return loc
        return A.Loc(self.file, 0, 0)

    # ------------------------------------------------------------ blocks

    def start(self, *blocks: Any) -> list[Any]:
        return list(blocks)

    def domain_block(self, name: Token, *sections: Any) -> A.Domain:
        fields: dict[str, Any] = {
            "requirements": None,
            "types": [],
            "pvariables": [],
            "cpfs": [],
            "cpfs_keyword": "cpfs",
            "reward": None,
            "state-action-constraints": [],
            "action-preconditions": [],
            "state-invariants": [],
            "termination": [],
            "objects": [],
        }
        for tag, value, *rest in sections:
            if tag == "requirements":
                fields["requirements"] = tuple(value)
            elif tag == "reward":
                fields["reward"] = value
            elif tag == "cpfs":
                fields["cpfs"].extend(value)
                fields["cpfs_keyword"] = rest[0]
            else:
                fields[tag].extend(value)
        return A.Domain(
            name=str(name),
            requirements=fields["requirements"],
            types=tuple(fields["types"]),
            pvariables=tuple(fields["pvariables"]),
            cpfs=tuple(fields["cpfs"]),
            cpfs_keyword=fields["cpfs_keyword"],
            reward=fields["reward"],
            state_action_constraints=tuple(fields["state-action-constraints"]),
            action_preconditions=tuple(fields["action-preconditions"]),
            state_invariants=tuple(fields["state-invariants"]),
            termination=tuple(fields["termination"]),
            objects=tuple(fields["objects"]),
            loc=self._at(name),
        )

    def requirements(self, *names: Token) -> tuple[str, list[str]]:
        return ("requirements", [str(n) for n in names])

    def types_section(self, *defs: A.TypeDef) -> tuple[str, list[A.TypeDef]]:
        return ("types", list(defs))

    def object_type(self, name: Token, _obj: Token) -> A.TypeDef:
        return A.TypeDef(str(name), "object", loc=self._at(name))

    def sub_type(self, name: Token, parent: Token) -> A.TypeDef:
        return A.TypeDef(str(name), "sub", parent=str(parent), loc=self._at(name))

    def enum_type(self, name: Token, *values: Token) -> A.TypeDef:
        return A.TypeDef(
            str(name), "enum", values=tuple(str(v) for v in values), loc=self._at(name)
        )

    def pvariables_section(self, *defs: A.PVarDef) -> tuple[str, list[A.PVarDef]]:
        return ("pvariables", list(defs))

    def pvar_def(
        self, name: Token, params: tuple[str, ...], kind: str, rng: str, *options: Any
    ) -> A.PVarDef:
        default = level = None
        for key, value in options:
            if key == "default":
                default = value
            else:
                level = value
        return A.PVarDef(
            name=str(name),
            params=params,
            kind=kind,
            range=rng,
            default=default,
            level=level,
            loc=self._at(name),
        )

    def pvar_params(self, *types: str) -> tuple[str, ...]:
        return tuple(types)

    def pvar_option(self, key: Token, value: A.Literal) -> tuple[str, A.Literal]:
        return (str(key), value)

    def type_spec(self, tok: Token) -> str:
        return str(tok)

    def pvar_kind(self, tok: Token) -> str:
        return str(tok)

    def cpfs_header(self, tok: Token) -> str:
        return str(tok)

    def constraint_kind(self, tok: Token) -> str:
        return str(tok)

    def cpfs_section(self, header: str, *cpfs: A.Cpf) -> tuple[str, list[A.Cpf], str]:
        return ("cpfs", list(cpfs), header)

    def cpf_def(self, name: Token, *rest: Any) -> A.Cpf:
        params = tuple(str(t) for t in rest[:-1])
        base, primed = _strip_prime(str(name))
        return A.Cpf(base, primed, params, rest[-1], loc=self._at(name))

    def reward_section(self, expr: A.Expr) -> tuple[str, A.Expr]:
        return ("reward", expr)

    def constraint_section(self, kind: str, *exprs: A.Expr) -> tuple[str, list[A.Expr]]:
        return (kind, list(exprs))

    def objects_section(self, *defs: A.ObjectsDef) -> tuple[str, list[A.ObjectsDef]]:
        return ("objects", list(defs))

    def objects_def(self, type_: Token, *names: Any) -> A.ObjectsDef:
        return A.ObjectsDef(
            str(type_),
            tuple(str(n) for n in names),
            tuple(self._at(n) for n in names),
            loc=self._at(type_),
        )

    def dollar_name(self, dollar: Token, name: Token) -> Token:
        # keep the position of the '$'; the name is what matters
        return Token("IDENT", str(name), dollar.start_pos, dollar.line, dollar.column)

    def non_fluents_block(self, _kw: Token, name: Token, *items: Any) -> A.NonFluents:
        domain = None
        objects: list[A.ObjectsDef] = []
        values: list[A.Assignment] = []
        for tag, value in items:
            if tag == "domain":
                domain = value
            elif tag == "objects":
                objects.extend(value)
            elif tag == "nf_values":
                values.extend(value)
        return A.NonFluents(str(name), domain, tuple(objects), tuple(values), self._at(name))

    def instance_block(self, name: Token, *items: Any) -> A.Instance:
        f: dict[str, Any] = {
            "domain": None,
            "non_fluents_ref": None,
            "objects": None,
            "nf_values": None,
            "init_state": None,
            "max_nondef": None,
            "horizon": None,
            "discount": None,
        }
        for tag, value in items:
            if tag in ("objects", "nf_values", "init_state"):
                f[tag] = (f[tag] or []) + list(value)
            else:
                f[tag] = value
        return A.Instance(
            name=str(name),
            domain=f["domain"],
            non_fluents=f["non_fluents_ref"],
            objects=tuple(f["objects"] or ()),
            non_fluent_values=None if f["nf_values"] is None else tuple(f["nf_values"]),
            init_state=None if f["init_state"] is None else tuple(f["init_state"]),
            max_nondef_actions=f["max_nondef"],
            horizon=f["horizon"],
            discount=f["discount"],
            loc=self._at(name),
        )

    def domain_ref(self, name: Token) -> tuple[str, str]:
        return ("domain", str(name))

    def non_fluents_ref(self, _kw: Token, name: Token) -> tuple[str, str]:
        return ("non_fluents_ref", str(name))

    def non_fluents_values(self, _kw: Token, *assigns: A.Assignment) -> tuple[str, Any]:
        return ("nf_values", list(assigns))

    def init_state(self, *assigns: A.Assignment) -> tuple[str, Any]:
        return ("init_state", list(assigns))

    def max_nondef_actions(self, tok: Token) -> tuple[str, int | str]:
        return ("max_nondef", A.POS_INF if tok.type == "POS_INF" else int(tok))

    def horizon(self, tok: Token) -> tuple[str, int | str]:
        return ("horizon", A.POS_INF if tok.type == "POS_INF" else int(tok))

    def horizon_terminate(self, expr: A.Expr) -> tuple[str, A.Expr]:
        return ("horizon", expr)

    def discount(self, tok: Token) -> tuple[str, float | int]:
        return ("discount", int(tok) if tok.type == "INT" else float(tok))

    def assignment(self, *children: Any) -> A.Assignment:
        negated = False
        parts = list(children)
        if isinstance(parts[0], Token) and parts[0].type == "NOT":
            negated = True
            parts.pop(0)
        name = str(parts.pop(0))
        value = None
        if parts and not isinstance(parts[-1], (str, Token)):
            value = parts.pop()
        return A.Assignment(
            name, tuple(str(p) for p in parts), value, negated, loc=self._at(children)
        )

    # ---------------------------------------------------------- literals

    def literal(self, tok: Any) -> A.Literal:
        loc = self._at(tok)
        if isinstance(tok, A.Const):
            return tok
        kind = tok.type
        if kind == "TRUE":
            return A.Const(True, loc)
        if kind == "FALSE":
            return A.Const(False, loc)
        if kind == "POS_INF":
            return A.Const(float("inf"), loc)
        if kind == "NEG_INF":
            return A.Const(float("-inf"), loc)
        if kind == "ENUM_VAL":
            return A.EnumLit(str(tok), loc)
        return A.ObjectLit(str(tok), False, loc)

    def dollar_literal(self, dollar: Token, name: Token) -> A.ObjectLit:
        return A.ObjectLit(str(name), True, self._at(dollar))

    def signed_number(self, *toks: Token) -> A.Const:
        sign = 1
        if len(toks) == 2:
            sign = -1 if toks[0] == "-" else 1
        num = toks[-1]
        value: int | float = int(num) if num.type == "INT" else float(num)
        return A.Const(sign * value, self._at(toks))

    # ------------------------------------------------------- expressions

    def binop(self, left: A.Expr, op: Token, right: A.Expr) -> A.Binary:
        text = "^" if op == "&" else str(op)
        return A.Binary(text, left, right, self._at(op))

    def unary(self, op: Token, operand: A.Expr) -> A.Unary:
        return A.Unary(str(op), operand, self._at(op))

    def bool_const(self, tok: Token) -> A.Const:
        return A.Const(tok.type == "TRUE", self._at(tok))

    def int_const(self, tok: Token) -> A.Const:
        return A.Const(int(tok), self._at(tok))

    def real_const(self, tok: Token) -> A.Const:
        return A.Const(float(tok), self._at(tok))

    def inf_const(self, tok: Token) -> A.Const:
        return A.Const(float("inf") if tok.type == "POS_INF" else float("-inf"), self._at(tok))

    def variable(self, tok: Token) -> A.Var:
        return A.Var(str(tok), self._at(tok))

    def enum_literal(self, tok: Token) -> A.EnumLit:
        return A.EnumLit(str(tok), self._at(tok))

    def object_literal(self, dollar: Token, tok: Token) -> A.ObjectLit:
        return A.ObjectLit(str(tok), True, self._at(dollar))

    def bare_name(self, tok: Token) -> A.PVar:
        name, primed = _strip_prime(str(tok))
        return A.PVar(name, (), primed, loc=self._at(tok))

    def call(self, tok: Token, *args: A.Expr) -> A.Expr:
        name, primed = _strip_prime(str(tok))
        loc = self._at(tok)
        if name in DISTRIBUTIONS and not primed:
            return A.Distribution(name, tuple(args), loc)
        return A.PVar(name, tuple(args), primed, loc=loc)

    def default_of(self, tok: Token, _kw: Token) -> A.PVar:
        name, primed = _strip_prime(str(tok))
        return A.PVar(name, (), primed, True, self._at(tok))

    def function(self, tok: Token, *args: A.Expr) -> A.Function:
        return A.Function(str(tok), tuple(args), self._at(tok))

    def matrix_op(
        self, tok: Token, _r: Token, row: Token, _c: Token, col: Token, body: A.Expr
    ) -> A.MatrixOp:
        return A.MatrixOp(str(tok), str(row), str(col), body, self._at(tok))

    def aggregation(
        self, tok: Token, params: tuple[A.TypedVar, ...], body: A.Expr
    ) -> A.Aggregation:
        return A.Aggregation(str(tok), params, body, self._at(tok))

    def typed_vars(self, *tvs: A.TypedVar) -> tuple[A.TypedVar, ...]:
        return tuple(tvs)

    def typed_var(self, var: Token, type_: Token) -> A.TypedVar:
        return A.TypedVar(str(var), str(type_), self._at(var))

    def if_expr(self, kw: Token, cond: A.Expr, then: A.Expr, else_: A.Expr) -> A.If:
        return A.If(cond, then, else_, self._at(kw))

    def switch_expr(self, kw: Token, subject: A.Expr, *cases: A.Case) -> A.Switch:
        return A.Switch(subject, tuple(cases), self._at(kw))

    def case(self, label: A.Expr, value: A.Expr) -> A.Case:
        return A.Case(label, value, self._at(label))

    def default_case(self, _kw: Token, value: A.Expr) -> A.Case:
        return A.Case(None, value, self._at(_kw))

    def discrete_case(self, *children: Any) -> A.DiscreteCase:
        loc = self._at(children[0])
        label, prob = children[-2], children[-1]
        if isinstance(label, Token) and label.type == "ENUM_VAL":
            lab: A.Expr = A.EnumLit(str(label), loc)
        else:
            # `$name` comes through the anonymous "$" as a bare IDENT too.
            lab = A.ObjectLit(str(label), False, loc)
        if isinstance(prob, Token) and prob.type == "OTHERWISE":
            return A.DiscreteCase(lab, None, loc)
        return A.DiscreteCase(lab, prob, loc)

    def discrete(self, word: Token, type_: Token, *cases: A.DiscreteCase) -> A.Discrete:
        return A.Discrete(str(word), str(type_), tuple(cases), None, self._at(word))

    def multinomial(
        self, word: Token, type_: Token, count: A.Expr, *cases: A.DiscreteCase
    ) -> A.Discrete:
        return A.Discrete(str(word), str(type_), tuple(cases), count, self._at(word))

    def discrete_over(
        self, word: Token, params: tuple[A.TypedVar, ...], body: A.Expr
    ) -> A.DiscreteOver:
        return A.DiscreteOver(str(word), params, body, self._at(word))

    def vector_dist(self, word: Token, *rest: Any) -> A.VectorDistribution:
        indices = tuple(str(r) for r in rest if isinstance(r, (str, Token)))
        args = tuple(r for r in rest if not isinstance(r, (str, Token)))
        return A.VectorDistribution(str(word), indices, args, self._at(word))

    def vector_free(self) -> str:
        return "_"

    def dirichlet(self, word: Token, type_: Token, alpha: A.Expr) -> A.Distribution:
        loc = self._at(word)
        return A.Distribution("Dirichlet", (A.PVar(str(type_), loc=loc), alpha), loc)


# ------------------------------------------------------------ the parser


@lru_cache(maxsize=1)
def _grammar() -> str:
    return resources.files(__package__).joinpath("rddl.lark").read_text(encoding="utf-8")


_BUILDER = _Builder()


@lru_cache(maxsize=1)
def _lark() -> Lark:
    return Lark(
        _grammar(),
        parser="lalr",
        lexer=RDDLLexer,
        maybe_placeholders=False,
        transformer=_BUILDER,
        cache=False,
    )


# Words for terminals in error messages.
_TERMINAL_WORDS = {
    "IDENT": "a name",
    "VAR": "a variable such as ?x",
    "ENUM_VAL": "an enum value such as @low",
    "INT": "an integer",
    "REAL": "a real number",
    "$END": "the end of the file",
}
_EXPRESSION_STARTERS = {"VAR", "INT", "REAL", "ENUM_VAL", "LPAR", "LSQB"}


def _describe_terminal(name: str) -> str:
    if name in _TERMINAL_WORDS:
        return _TERMINAL_WORDS[name]
    term = {t.name: t for t in _lark().terminals}.get(name)
    if term is not None and term.pattern.type == "str":
        return f"'{term.pattern.value}'"
    return name.lower()


def _describe_expected(expected: set[str]) -> str:
    names = set(expected)
    words: list[str] = []
    if len(names & _EXPRESSION_STARTERS) >= 3:
        words.append("an expression")
        names = {
            n
            for n in names
            if n not in _EXPRESSION_STARTERS
            and n
            not in {
                "IDENT",
                "NOT",
                "MINUS",
                "PLUS",
                "TRUE",
                "FALSE",
                "POS_INF",
                "NEG_INF",
                "IF",
                "SWITCH",
                "DOLLAR",
                "DISCRETE",
                "UNNORM_DISCRETE",
                "MULTINOMIAL",
                "MULTIVARIATE_NORMAL",
                "MULTIVARIATE_STUDENT",
                "DIRICHLET",
            }
        }
    words += sorted(_describe_terminal(n) for n in names)
    if not words:
        return "something else"
    if len(words) == 1:
        return words[0]
    return ", ".join(words[:-1]) + " or " + words[-1]


def _describe_token(tok: Token) -> str:
    if tok.type == "$END":
        return "end of file"
    if tok.type in _TERMINAL_WORDS:
        word = _TERMINAL_WORDS[tok.type].split(" such as")[0]
        word = word.split(" ", 1)[1] if " " in word else word  # "a name" -> "name"
        return f"{word} '{tok}'"
    return f"'{tok}'"


_KEYWORDS = (
    "domain",
    "instance",
    "non-fluents",
    "requirements",
    "types",
    "object",
    "pvariables",
    "non-fluent",
    "state-fluent",
    "interm-fluent",
    "derived-fluent",
    "observ-fluent",
    "action-fluent",
    "default",
    "level",
    "cpfs",
    "cdfs",
    "reward",
    "state-action-constraints",
    "action-preconditions",
    "state-invariants",
    "termination",
    "objects",
    "init-state",
    "max-nondef-actions",
    "horizon",
    "discount",
    "if",
    "then",
    "else",
    "switch",
    "case",
    "forall",
    "exists",
    "sum",
    "prod",
    "true",
    "false",
    "bool",
    "int",
    "real",
)


def _syntax_diagnostic(err: UnexpectedInput, file: str, text: str) -> Diagnostic:
    line = getattr(err, "line", 0) or 0
    column = getattr(err, "column", 0) or 0
    if isinstance(err, UnexpectedCharacters):
        pos = err.pos_in_stream or 0
        char = text[pos] if pos < len(text) else "?"
        if char == "'":
            msg = "unexpected \"'\": a prime goes right after a fluent name, as in running'(?x)"
        else:
            msg = f"unexpected character '{char}'"
        return Diagnostic(A.Loc(file, line, column), "syntax", msg, source_line(text, line))
    if isinstance(err, UnexpectedEOF):
        lines = text.splitlines() or [""]
        line, column = len(lines), len(lines[-1]) + 1
        msg = f"unexpected end of file; expected {_describe_expected(set(err.expected))}"
        return Diagnostic(A.Loc(file, line, column), "syntax", msg, source_line(text, line))
    assert isinstance(err, UnexpectedToken)
    tok = err.token
    expected = set(err.accepts or err.expected)
    if tok.type == "$END":
        lines = text.splitlines() or [""]
        line, column = len(lines), len(lines[-1]) + 1
        msg = f"unexpected end of file; expected {_describe_expected(expected)}"
        if "RBRACE" in expected:
            msg += " (is a '}' missing?)"
        return Diagnostic(A.Loc(file, line, column), "syntax", msg, source_line(text, line))
    # A keyword followed by more letters ("state-fluents") is lexed as the
    # keyword and a stray rest; report the whole word where it starts.
    start = tok.start_pos or 0
    if 0 < start < len(text) and _is_word_char(text[start - 1]) and _is_word_char(text[start]):
        begin = start
        while begin > 0 and _is_word_char(text[begin - 1]):
            begin -= 1
        end = start
        while end < len(text) and _is_word_char(text[end]):
            end += 1
        word = text[begin:end]
        line = text.count("\n", 0, begin) + 1
        column = begin - (text.rfind("\n", 0, begin) + 1) + 1
        msg = f"unknown word '{word}'"
        close = difflib.get_close_matches(word, _KEYWORDS, n=1, cutoff=0.75)
        if close:
            msg += f" (did you mean '{close[0]}'?)"
        return Diagnostic(A.Loc(file, line, column), "syntax", msg, source_line(text, line))
    msg = f"unexpected {_describe_token(tok)}; expected {_describe_expected(expected)}"
    if tok.type == "IDENT":
        close = difflib.get_close_matches(str(tok), _KEYWORDS, n=1, cutoff=0.75)
        if close and close[0] != str(tok):
            msg += f" (did you mean '{close[0]}'?)"
    return Diagnostic(A.Loc(file, line, column), "syntax", msg, source_line(text, line))


def _is_word_char(c: str) -> bool:
    return c.isalnum() or c in "-_"


def _block_spans(text: str) -> list[int]:
    """Offsets where top-level blocks start (a keyword at brace depth 0)."""
    starts = []
    depth = 0
    i = 0
    n = len(text)
    while i < n:
        c = text[i]
        if c == "/" and text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        if c == "{":
            depth += 1
        elif c == "}":
            depth = max(depth - 1, 0)
        elif depth == 0 and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] in "-_")):
            for kw in ("domain", "instance", "non-fluents"):
                if text.startswith(kw, i):
                    end = i + len(kw)
                    if end >= n or not (text[end].isalnum() or text[end] in "-_"):
                        starts.append(i)
                    break
        i += 1
    return starts


def _parse_text(text: str, file: str) -> list[Any]:
    lark = _lark()
    _BUILDER.file = file
    return lark.parse(text)  # type: ignore[return-value]


def parse(text: str, file: str = "<string>") -> A.RDDLFile:
    """Parse RDDL text; raise `RDDLSyntaxError` listing every block's error."""
    try:
        blocks = _parse_text(text, file)
    except UnexpectedInput as first:
        raise RDDLSyntaxError(_all_syntax_errors(text, file, first)) from None
    return _file_of(blocks, file)


def _all_syntax_errors(text: str, file: str, first: UnexpectedInput) -> list[Diagnostic]:
    diags = [_syntax_diagnostic(first, file, text)]
    seen = {(diags[0].line, diags[0].column)}
    starts = _block_spans(text)
    if len(starts) <= 1:
        return diags
    bounds = starts + [len(text)]
    for begin, end in zip(bounds, bounds[1:], strict=False):
        piece = text[begin:end]
        prefix_lines = text.count("\n", 0, begin)
        line_start = text.rfind("\n", 0, begin) + 1
        padded = "\n" * prefix_lines + " " * (begin - line_start) + piece
        try:
            _parse_text(padded, file)
        except UnexpectedInput as err:
            if isinstance(err, UnexpectedEOF) or (
                isinstance(err, UnexpectedToken) and err.token.type == "$END"
            ):
                # A block that runs into its end (a missing '}'): the
                # whole-file parse has reported it where the next block starts.
                continue
            d = _syntax_diagnostic(err, file, padded)
            if (d.line, d.column) not in seen:
                seen.add((d.line, d.column))
                diags.append(d)
    diags.sort(key=lambda d: (d.line, d.column))
    return diags


def _file_of(blocks: list[Any], file: str) -> A.RDDLFile:
    domains = tuple(b for b in blocks if isinstance(b, A.Domain))
    nfs = tuple(b for b in blocks if isinstance(b, A.NonFluents))
    insts = tuple(b for b in blocks if isinstance(b, A.Instance))
    return A.RDDLFile(file, domains, nfs, insts, A.Loc(file, 1, 1))


def parse_file(path: str | Path) -> A.RDDLFile:
    """Parse one `.rddl` file (UTF-8, or Latin-1 when it is not UTF-8)."""
    p = Path(path)
    data = p.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    return parse(text, str(p))


def parse_expr(text: str, file: str = "<expr>") -> A.Expr:
    """Parse a lone expression (handy in tests and tools)."""
    wrapped = "domain d { reward = " + text + " ; }"
    f = parse(wrapped, file)
    reward = f.domains[0].reward
    assert reward is not None
    return reward
