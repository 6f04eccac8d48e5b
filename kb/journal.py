"""Plain data for a knowledge base's journal: facts, goals, folding.

A long-running dispatcher keeps what its knowledge base learnt in a result
store and resumes from it after a restart. The knowledge base hands every
applied batch and every goal change to its journal subscribers as plain,
JSON-able data (`KnowledgeBase.subscribe_journal`), and takes a saved state
back as one atomic batch (`KnowledgeBase.restore`). This module owns the
shapes of that data and the pure functions over it:

* a fact is ``{"fluent": f, "args": [...], "value": v}``;
* a journal entry is ``{"seq": n, "source": s, "changes": [change, ...]}``
  (a batch: each change ``{"fluent", "args", "old", "new"}``) or
  ``{"seq": n, "source": s, "goal": [fact, ...] | None, "version": v}`` (a
  goal change; None: back to the domain's own goal);
* a snapshot is ``{"facts": [fact, ...], "goal": [fact, ...] | None}``,
  with a "goal" key only when it says which goal was in force.

`fold` turns a run of entries into the snapshot that `restore` takes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from .store import KBError, Update

__all__ = ["fact_updates", "fold"]


def _fact_parts(n: int, fact: Any) -> tuple[str, tuple[str, ...], Any]:
    if isinstance(fact, Mapping):
        fluent, args, value = fact.get("fluent"), fact.get("args", ()), fact.get("value")
    elif isinstance(fact, (list, tuple)) and len(fact) == 3:
        fluent, args, value = fact
    else:
        raise KBError(
            f"fact {n + 1}: expected {{fluent, args, value}} or (fluent, args, value), "
            f"not {fact!r}",
            "bad-fact",
        )
    if not isinstance(fluent, str):
        raise KBError(f"fact {n + 1}: 'fluent' must be a name, not {fluent!r}", "bad-fact")
    if isinstance(args, str) or not isinstance(args, (list, tuple)):
        raise KBError(f"fact {n + 1}: 'args' must be a list of names, not {args!r}", "bad-fact")
    if value is None:
        raise KBError(f"fact {n + 1} ({fluent}): no value", "bad-fact")
    return fluent, tuple(args), value


def fact_updates(facts: Iterable[Any]) -> list[Update]:
    """`set` updates for facts given as dicts or (fluent, args, value)
    triples; KBError naming the first one that has neither shape."""
    return [Update("set", *_fact_parts(n, f)) for n, f in enumerate(facts)]


def fold(
    entries: Iterable[Mapping[str, Any]], base: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The snapshot after `entries` (journal entries, in order) on top of
    `base` (a snapshot, or nothing): the last value of every grounding they
    changed, and the last goal change. What `KnowledgeBase.restore` takes."""
    values: dict[tuple[str, tuple[str, ...]], Any] = {}
    goal: Any = ...
    if base is not None:
        for n, fact in enumerate(base.get("facts", ())):
            fluent, args, value = _fact_parts(n, fact)
            values[(fluent, args)] = value
        if "goal" in base:
            goal = base["goal"]
    for entry in entries:
        for ch in entry.get("changes", ()):
            values[(ch["fluent"], tuple(ch["args"]))] = ch["new"]
        if "goal" in entry:
            goal = entry["goal"]
    out: dict[str, Any] = {
        "facts": [{"fluent": f, "args": list(a), "value": v} for (f, a), v in values.items()]
    }
    if goal is not ...:
        out["goal"] = goal
    return out
