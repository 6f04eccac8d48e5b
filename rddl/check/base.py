"""What the checker's parts share.

Owns the results (`DomainCheck`, the domain checked on its own, and
`DeferredObject`, a name the instance must supply as an object), the
`_Reporter` that collects diagnostics with their source lines,
`_literal_value` (a literal as the value of a pvariable of a given range:
defaults, non-fluents, init-state), `_is_subtype`, and the words of
messages (`_a`, `_show`). Imports the AST, the model and `errors` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .. import ast as A
from ..errors import Diagnostic, source_line
from ..model import PRIMITIVE_TYPES, PVariable, Value


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
