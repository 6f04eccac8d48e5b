"""Errors of the RDDL front end.

One hierarchy: `RDDLError` is what callers catch; `RDDLSyntaxError` and
`RDDLSemanticError` say which stage found the problem. Each carries one or
more `Diagnostic`s, so that every problem in a file is reported at once.
A diagnostic names the file, line and column, says what is wrong in a
modeller's words, and can show the offending line with a caret under it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .ast import Loc


@dataclass(frozen=True)
class Diagnostic:
    """One problem at one place.

    `kind` is a stable short code that tests and tools can match on
    (e.g. "syntax", "unknown-name", "arity", "type", "missing-cpf").
    """

    loc: Loc
    kind: str
    message: str
    source_line: str | None = field(default=None, compare=False)

    @property
    def file(self) -> str:
        return self.loc.file

    @property
    def line(self) -> int:
        return self.loc.line

    @property
    def column(self) -> int:
        return self.loc.column

    def render(self, show_source: bool = True) -> str:
        head = f"{self.loc}: {self.kind}: {self.message}"
        if not show_source or not self.source_line:
            return head
        text = self.source_line.rstrip("\r\n").expandtabs(1)
        caret = " " * max(self.loc.column - 1, 0) + "^"
        return f"{head}\n    {text}\n    {caret}"

    def __str__(self) -> str:
        return self.render(show_source=False)


class RDDLError(Exception):
    """Base of every error the RDDL front end raises on bad input."""

    def __init__(self, diagnostics: list[Diagnostic] | Diagnostic | str):
        if isinstance(diagnostics, str):
            diagnostics = [Diagnostic(Loc("<input>", 0, 0), "error", diagnostics)]
        elif isinstance(diagnostics, Diagnostic):
            diagnostics = [diagnostics]
        self.diagnostics: list[Diagnostic] = list(diagnostics)
        super().__init__(self.render(show_source=False))

    @property
    def first(self) -> Diagnostic:
        return self.diagnostics[0]

    def render(self, show_source: bool = True) -> str:
        return "\n".join(d.render(show_source) for d in self.diagnostics)


class RDDLSyntaxError(RDDLError):
    """The text is not RDDL: a token or character that cannot stand there."""


class RDDLSemanticError(RDDLError):
    """The text parses but does not make sense: unknown names, wrong arity,
    type errors, missing or duplicate definitions."""


def source_line(text: str | None, line: int) -> str | None:
    """The `line`-th line (1-based) of `text`, or None."""
    if text is None or line < 1:
        return None
    lines = text.splitlines()
    if line > len(lines):
        return None
    return lines[line - 1]
