"""A step in two parts: what the state alone decides, before the actions come.

A server sends a turn and then waits for the client's actions; only then can it
step. Much of a step does not read the actions: the random draws, and every
value computed from the state and the draws alone (in SysAdmin, each
computer's chance to keep running). `split_step_source` cuts the source of a
generated one-state step function (`_step_one`, see `Simulator`) into

    pre(S, B, rng)                   the statements that read neither the
                                     actions nor the `check` flag; returns the
                                     values the rest needs
    post(S, A, B, check, *values)    the others, in their order

so that `post(S, A, B, check, *pre(S, B, rng))` computes exactly what
`step(S, A, B, rng, check)` computes: the same operations on the same values
in the same order, and the same draws from `rng` in the same order. Nothing
is guessed about the actions; the pre part is exact whatever they are.

Statements keep their order within each part; a statement moves ahead of
statements of the post part only when that cannot change what any statement
sees:

- a statement that reads the actions, `check`, or a value of the post part
  is in the post part (and so are `return` and whatever it assigns);
- once a post statement writes into an array in place (an `out=` argument, a
  subscript or attribute store, an augmented assignment), every later
  statement is in the post part: a later reader must see the write;
- after the first post statement, a statement that writes in place is in the
  post part: an earlier post reader must not see its write;
- once a statement that draws from `rng` is in the post part, so is every
  later one that draws (the draws keep their order).

Sources that assign a name twice are not split (None), nor are those with
nothing to move.

Works on the source text alone (Python's `ast`) and imports nothing of the
package; `Simulator.prepare` / `finish` compile and call the two parts.
"""

from __future__ import annotations

import ast
import threading

# CPython 3.11 keeps the AST constructor's recursion depth in one counter per
# interpreter, not per thread: two threads in ast.parse at once (simulators built
# side by side, as rddl-batch's sessions on the threads of a Dask worker do) can
# fail with "SystemError: AST constructor recursion depth mismatch" (CPython
# gh-106905). Parses here take turns.
_PARSE_LOCK = threading.Lock()

__all__ = ["split_step_source"]

PRE_NAME = "_pre_one"
POST_NAME = "_post_one"


def _reads(node: ast.AST) -> set[str]:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}


def _assigns(node: ast.AST) -> list[str]:
    return [
        n.id for n in ast.walk(node) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)
    ]


def _writes_in_place(node: ast.AST) -> bool:
    for n in ast.walk(node):
        if isinstance(n, ast.AugAssign):
            return True
        if isinstance(n, (ast.Subscript, ast.Attribute)) and isinstance(n.ctx, ast.Store):
            return True
        if isinstance(n, ast.keyword) and n.arg == "out":
            return True
    return False


def split_step_source(source: str) -> tuple[str, str, list[str]] | None:
    """(pre source, post source, names pre hands to post) for the source of
    a generated step function `def NAME(S, A, B, rng, check): ...`, or None
    when it is not worth or not safe to split (see the module docstring)."""
    with _PARSE_LOCK:
        tree = ast.parse(source)
    if len(tree.body) != 1 or not isinstance(tree.body[0], ast.FunctionDef):
        return None
    fn = tree.body[0]
    if [a.arg for a in fn.args.args] != ["S", "A", "B", "rng", "check"]:
        return None
    assigned: list[str] = []
    for stmt in fn.body:
        assigned += _assigns(stmt)
    if len(assigned) != len(set(assigned)) or {"S", "A", "B", "rng", "check"} & set(assigned):
        return None
    post_names = {"A", "check"}
    pre: list[ast.stmt] = []
    post: list[ast.stmt] = []
    all_post = False  # a post statement wrote in place
    draws_post = False  # a post statement drew from rng
    for stmt in fn.body:
        reads = _reads(stmt)
        in_place = _writes_in_place(stmt)
        draws = "rng" in reads
        late = (
            all_post
            or isinstance(stmt, ast.Return)
            or bool(reads & post_names)
            or (in_place and bool(post))
            or (draws and draws_post)
        )
        if late:
            post.append(stmt)
            post_names.update(_assigns(stmt))
            all_post = all_post or in_place
            draws_post = draws_post or draws
        else:
            pre.append(stmt)
    if not pre or not any(isinstance(s, ast.Assign) for s in pre):
        return None
    defined_pre = set()
    for stmt in pre:
        defined_pre.update(_assigns(stmt))
    needed: set[str] = set()
    for stmt in post:
        needed |= _reads(stmt)
    handed = sorted(defined_pre & needed)
    ret = ", ".join(handed)
    pre_src = _function(
        PRE_NAME,
        ["S", "B", "rng"],
        [*map(ast.unparse, pre), f"return ({ret}{',' if len(handed) == 1 else ''})"],
    )
    post_src = _function(
        POST_NAME, ["S", "A", "B", "check", *handed], [ast.unparse(s) for s in post]
    )
    return pre_src, post_src, handed


def _function(name: str, params: list[str], statements: list[str]) -> str:
    body = "\n".join("    " + line for text in statements for line in text.splitlines())
    return f"def {name}({', '.join(params)}):\n{body}\n"
