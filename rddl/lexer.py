"""A fast lexer for the RDDL grammar, plugged into lark's LALR parser.

lark's own lexers try terminal patterns one state-specific regex at a time;
on RDDL files that is close to half of the parse time. This lexer matches one
compiled regular expression with a group per token class and looks words up
in a table of the grammar's keywords, which it reads from the grammar itself
(so `rddl.lark` stays the one definition of the language).

Keywords are contextual, as with lark's contextual lexer: a word that is a
keyword is still a plain name (IDENT) where the parser cannot take the
keyword but can take a name, so a fluent may be called `level` or `row`.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

from lark import Token
from lark.exceptions import UnexpectedCharacters
from lark.lexer import Lexer, LexerState

_WORD = r"[A-Za-z](?:[A-Za-z0-9_\-]*[A-Za-z0-9])?'?"

# Token classes in the order they are tried; each mirrors a terminal of
# rddl.lark (IDENT, VAR, ENUM_VAL, REAL, INT, COMMENT, the ignored blanks).
_MASTER = re.compile(
    r"(?P<ws>[ \t\r\n\f]+)"
    r"|(?P<comment>//[^\n]*)"
    r"|(?P<VAR>\?[A-Za-z0-9_\-]*[A-Za-z0-9])"
    r"|(?P<ENUM_VAL>@[A-Za-z0-9_\-]*[A-Za-z0-9])"
    r"|(?P<REAL>(?:\d*\.\d+|\d+\.(?!\.))(?:[eE][+\-]?\d+)?|\d+[eE][+\-]?\d+)"
    r"|(?P<INT>\d+)"
    r"|(?P<word>" + _WORD + r")"
    r"|(?P<punct><=>|=>|==|~=|<=|>=|[-+*/^&|~<>=(){}\[\],;:.$_])"
)
_WORD_RE = re.compile(_WORD)


class RDDLLexer(Lexer):
    """lark custom lexer (interface 2: sees the parser's state)."""

    __future_interface__ = 2

    def __init__(self, lexer_conf: Any) -> None:
        self.keywords: dict[str, str] = {}
        self.punct: dict[str, str] = {}
        for term in lexer_conf.terminals:
            if term.pattern.type != "str":
                continue
            value = term.pattern.value
            if _WORD_RE.fullmatch(value):
                self.keywords[value] = term.name
            else:
                self.punct[value] = term.name
        self.terminals_by_name = lexer_conf.terminals_by_name

    def lex(self, lexer_state: LexerState, parser_state: Any) -> Iterator[Token]:
        text_slice = lexer_state.text
        text: str = text_slice.text  # type: ignore[assignment]
        pos = text_slice.start
        end = text_slice.end
        line = lexer_state.line_ctr.line
        line_start = pos - (lexer_state.line_ctr.column - 1)
        match = _MASTER.match
        keywords = self.keywords
        punct = self.punct
        states = parser_state.parse_conf.states
        stack = parser_state.state_stack
        while pos < end:
            m = match(text, pos, end)
            if m is None:
                raise UnexpectedCharacters(
                    text,
                    pos,
                    line,
                    pos - line_start + 1,
                    state=parser_state,
                    terminals_by_name=self.terminals_by_name,
                )
            kind = m.lastgroup
            value = m.group()
            start = pos
            pos = m.end()
            if kind == "ws":
                newlines = value.count("\n")
                if newlines:
                    line += newlines
                    line_start = start + value.rindex("\n") + 1
                continue
            if kind == "comment":
                continue
            if kind == "word":
                kind = keywords.get(value, "IDENT")
                if kind != "IDENT":
                    accepts = states[stack[-1]]
                    if kind not in accepts and "IDENT" in accepts:
                        kind = "IDENT"
            elif kind == "punct":
                kind = punct.get(value)  # type: ignore[assignment]
                if kind is None:  # a sign the grammar does not use
                    raise UnexpectedCharacters(
                        text,
                        start,
                        line,
                        start - line_start + 1,
                        state=parser_state,
                        terminals_by_name=self.terminals_by_name,
                    )
            column = start - line_start + 1
            yield Token(kind, value, start, line, column, line, column + len(value), pos)  # type: ignore[arg-type]
