"""The standard form of a PDDL effect that strict parsers take (`and` only
at the top, one `forall` around one `when` around one literal): the writer
builds nested effects freely and passes each through `normal_effect`.
"""

from __future__ import annotations

import re

SExpr = str | list["SExpr"]


def _sexpr(text: str) -> SExpr:
    """A PDDL s-expression as nested lists of tokens."""
    stack: list[list[SExpr]] = [[]]
    for tok in re.findall(r"\(|\)|[^\s()]+", text):
        if tok == "(":
            stack.append([])
        elif tok == ")":
            done = stack.pop()
            stack[-1].append(done)
        else:
            stack[-1].append(tok)
    return stack[0][0]


def _show(e: SExpr) -> str:
    return e if isinstance(e, str) else "(" + " ".join(_show(x) for x in e) + ")"


def _flat(e: SExpr, conds: list[SExpr], params: list[SExpr]) -> list[str]:
    """The PDDL effect `e` as standard c-effects: `and` only at the top,
    one `forall` around one `when` around one literal (the writer builds
    nested forms freely; strict parsers refuse them)."""
    if isinstance(e, list) and e and e[0] == "and":
        return [x for sub in e[1:] for x in _flat(sub, conds, params)]
    if isinstance(e, list) and e and e[0] == "when":
        return _flat(e[2], [*conds, e[1]], params)
    if isinstance(e, list) and e and e[0] == "forall":
        return _flat(e[2], conds, [*params, *e[1]])  # type: ignore[misc]
    out = _show(e)
    if conds:
        cond = _show(conds[0]) if len(conds) == 1 else _show(["and", *conds])
        out = f"(when {cond} {out})"
    if params:
        out = f"(forall ({' '.join(_show(p) for p in params)}) {out})"
    return [out]


def normal_effect(text: str) -> str:
    """`text` (an effect) in the standard form `_flat` describes."""
    return "(and " + " ".join(_flat(_sexpr(text), [], [])) + ")"
