"""The domain's state invariants, checked on the state a batch would make.

RDDL's `state-invariants` block lists formulas every reachable state
satisfies (the simulator checks them on every next state it computes). A
knowledge base fed by sensors can be told an impossible state (odometry
that puts a robot in two rooms); a planner given such a state plans for a
world that cannot exist. So the knowledge base checks every batch against
the invariants before it writes, and refuses the batch as a whole when it
would break one (`KnowledgeBase.apply`).

Theory of operation. Each invariant is split at its top-level conjunctions
and at the `forall`s that head a conjunct into *pieces*: a body and the
typed variables it is checked for, so a violation names its grounding
(`?r=r1`), not only the formula. A piece is evaluated with the knowledge
base's `Evaluator` (the simulator's semantics, one binding at a time) on a
lookup that reads the batch's new values first and the store after them.
Only the pieces that read a fluent the batch writes are evaluated. A batch
is refused for a grounding that holds now and would not hold after it: a
grounding already broken (an instance that starts outside the invariants,
a state restored from elsewhere) does not block the batches that leave it
as it is or repair it. A piece the evaluator cannot decide on a stored
state (it reads an intermediate fluent, an action or a draw) is logged once
when the knowledge base is built and not checked.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass

from ..rddl import ast as A
from ..rddl.model import STATE, Model, Value
from ..rddl.writer import write_expr
from .evaluate import Evaluator, Lookup, NotEvaluable

log = logging.getLogger(__name__)

__all__ = ["Invariants", "Violation"]

# boolean atoms a grounding may read besides a goal's, all of whose values
# `Invariants.impossible` tries (2**MAX_FREE evaluations at most)
MAX_FREE = 10


@dataclass(frozen=True)
class Piece:
    """One conjunct of a state invariant, checked for every binding of `params`."""

    invariant: A.Expr  # the whole invariant, for messages
    body: A.Expr
    params: tuple[A.TypedVar, ...]
    reads: frozenset[str]  # the stored fluents it reads


@dataclass(frozen=True)
class Violation:
    """A grounding of a state invariant that a batch would break."""

    loc: A.Loc
    text: str  # the whole invariant, in RDDL syntax
    binding: tuple[tuple[str, str], ...]  # (?var, object)

    @property
    def grounding(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in self.binding)

    def __str__(self) -> str:
        where = f" for {self.grounding}" if self.binding else ""
        return f"state invariant at {self.loc}{where}: {self.text}"


def _conjuncts(e: A.Expr) -> list[A.Expr]:
    if isinstance(e, A.Binary) and e.op in ("^", "&"):
        return [*_conjuncts(e.left), *_conjuncts(e.right)]
    return [e]


def _pieces(
    inv: A.Expr, part: A.Expr, params: tuple[A.TypedVar, ...], stored: Callable[[str], bool]
) -> list[Piece]:
    """`part` split at its conjunctions and leading foralls."""
    out = []
    for c in _conjuncts(part):
        if isinstance(c, A.Aggregation) and c.op == "forall":
            out.extend(_pieces(inv, c.body, params + c.params, stored))
            continue
        reads = frozenset(n.name for n in A.walk(c) if isinstance(n, A.PVar) and stored(n.name))
        out.append(Piece(inv, c, params, reads))
    return out


class Invariants:
    """The state invariants of a model, ready to check batches."""

    def __init__(self, model: Model, stored: Callable[[str], bool], lookup: Lookup):
        self.model = model
        self._stored = stored
        self.pieces: list[Piece] = []
        self.unchecked: list[str] = []
        current = Evaluator(model, lookup, stored)
        for inv in model.domain.state_invariants:
            for piece in _pieces(inv, inv, (), stored):
                why = self._why_not_checkable(piece, current)
                if why is None:
                    self.pieces.append(piece)
                else:
                    text = f"{inv.loc}: {write_expr(inv)}: not checked: {why}"
                    self.unchecked.append(text)
                    log.info("state invariant %s", text)

    def _why_not_checkable(self, piece: Piece, ev: Evaluator) -> str | None:
        for n in A.walk(piece.body):
            if A.is_draw(n):
                return "it draws a random value"
            if isinstance(n, A.PVar) and n.name in self.model.pvariables:
                if n.primed or not self._stored(n.name):
                    return f"it reads '{n.name}', which the knowledge base does not store"
        # One binding, to find constructs the evaluator does not know.
        envs = ev.bindings(piece.params, {})
        if envs:
            try:
                ev(piece.body, envs[0])
            except NotEvaluable as err:
                if "division by zero" not in str(err):
                    return str(err)
        return None

    def __bool__(self) -> bool:
        return bool(self.pieces)

    def reads_any(self, written: Collection[str]) -> bool:
        """Whether some checked invariant reads a fluent in `written`."""
        return any(not piece.reads.isdisjoint(written) for piece in self.pieces)

    def broken(
        self, before: Lookup, after: Lookup, written: Collection[str], limit: int = 5
    ) -> list[Violation]:
        """The groundings that hold under `before` and not under `after`
        (at most `limit`), among the pieces that read a fluent in `written`."""
        old = Evaluator(self.model, before, self._stored)
        new = Evaluator(self.model, after, self._stored)
        out: list[Violation] = []
        for piece in self.pieces:
            if not (piece.reads & set(written)):
                continue
            for env in new.bindings(piece.params, {}):
                if _holds(new, piece.body, env) is not False:
                    continue
                if _holds(old, piece.body, env) is False:
                    continue  # broken already: not this batch's doing
                binding = tuple((tv.name, env[tv.name]) for tv in piece.params)
                out.append(Violation(piece.invariant.loc, write_expr(piece.invariant), binding))
                if len(out) >= limit:
                    return out
        return out

    def impossible(
        self,
        fixed: Mapping[tuple[str, tuple[str, ...]], Value],
        lookup: Lookup,
        free: Callable[[str], bool],
        limit: int = 5,
    ) -> list[Violation]:
        """The groundings that no state with the values of `fixed` (a
        goal's facts) satisfies, as far as can be told: each grounding that
        reads a fixed value is tried with every value of the other boolean
        atoms it reads (`free(fluent)`: a boolean state fluent), up to
        MAX_FREE of them; one that reads a free numeric or enum fluent, or
        more atoms, is never called impossible. `lookup` gives the rest
        (the non-fluents)."""
        names = {name for name, _ in fixed}
        out: list[Violation] = []
        for piece in self.pieces:
            if piece.reads.isdisjoint(names):
                continue
            probe = Evaluator(self.model, lookup, self._stored)
            for env in probe.bindings(piece.params, {}):
                if self._unsatisfiable(piece, env, fixed, lookup, free):
                    binding = tuple((tv.name, env[tv.name]) for tv in piece.params)
                    out.append(Violation(piece.invariant.loc, write_expr(piece.invariant), binding))
                    if len(out) >= limit:
                        return out
        return out

    def _unsatisfiable(
        self,
        piece: Piece,
        env: dict[str, str],
        fixed: Mapping[tuple[str, tuple[str, ...]], Value],
        lookup: Lookup,
        free: Callable[[str], bool],
    ) -> bool:
        atoms: list[tuple[str, tuple[str, ...]]] = []
        while True:
            grown = False
            read_fixed = False
            for bits in range(1 << len(atoms)):
                assign = {a: bool(bits >> i & 1) for i, a in enumerate(atoms)}
                found: list[tuple[str, tuple[str, ...]]] = []
                undecidable = False

                def look(
                    fluent: str,
                    args: tuple[str, ...],
                    assign: dict[tuple[str, tuple[str, ...]], bool] = assign,
                    found: list[tuple[str, tuple[str, ...]]] = found,
                ) -> Value:
                    nonlocal read_fixed, undecidable
                    key = (fluent, tuple(args))
                    if key in fixed:
                        read_fixed = True
                        return fixed[key]
                    if key in assign:
                        return assign[key]
                    p = self.model.pvariables.get(fluent)
                    if p is not None and p.kind == STATE:
                        if free(fluent):
                            found.append(key)
                        else:
                            undecidable = True
                    return lookup(fluent, args)

                holds = _holds(Evaluator(self.model, look, self._stored), piece.body, env)
                if undecidable:
                    return False
                new = [k for k in dict.fromkeys(found) if k not in assign]
                if new:
                    atoms += new
                    if len(atoms) > MAX_FREE:
                        return False
                    grown = True
                    break
                if holds is not False:
                    return False  # a state with the goal's values satisfies it
            if not grown:
                return read_fixed

    def violated(self, lookup: Lookup, limit: int = 5) -> list[Violation]:
        """The groundings that do not hold under `lookup` (at most `limit`)."""
        ev = Evaluator(self.model, lookup, self._stored)
        out: list[Violation] = []
        for piece in self.pieces:
            for env in ev.bindings(piece.params, {}):
                if _holds(ev, piece.body, env) is False:
                    binding = tuple((tv.name, env[tv.name]) for tv in piece.params)
                    out.append(Violation(piece.invariant.loc, write_expr(piece.invariant), binding))
                    if len(out) >= limit:
                        return out
        return out


def _holds(ev: Evaluator, body: A.Expr, env: dict[str, str]) -> bool | None:
    """Whether `body` holds; None when it cannot be decided on this state
    (a division by zero): such a grounding never refuses a batch."""
    try:
        v = ev(body, env)
    except NotEvaluable:
        return None
    if isinstance(v, str):
        return None
    return bool(v)
