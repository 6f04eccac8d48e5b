"""The knowledge base's journal in the result store: what a restarted
rddl-dispatch resumes from.

`KBJournal` subscribes to a knowledge base's journal
(`KnowledgeBase.subscribe_journal`) and writes every batch that changed
something, and every change of its goal, to the result store (`ResultStore.record_kb_batch`: the
batch in `kb_batches`, the latest value of each grounding in `kb_facts`,
one transaction, committed before the subscriber returns). `start()`
first journals the whole state as it is (source "start"). `restore()`
applies the facts journaled for the instance and the last goal set at run
time, in one batch (`KnowledgeBase.restore`, source "journal"), before the dispatcher serves its first turn: the process
goes on from what it knew, not from the instance's initial state. A saved
fact the knowledge base refuses (the domain changed since: a fluent or an
object that is gone) is logged and left out; the others are restored.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

from ..kb import KBError, KnowledgeBase, Update

__all__ = ["SOURCE", "KBJournal"]

log = logging.getLogger(__name__)

#: The source of the batch a restore applies.
SOURCE = "journal"


class KBJournal:
    """Journals `kb`'s batches under `instance` in `store` (a `ResultStore`)."""

    def __init__(self, kb: KnowledgeBase, store: Any, instance: str):
        self.kb = kb
        self.store = store
        self.instance = instance
        self.batches = 0  # journaled by this process
        self.failures = 0  # batches the store could not take
        self._unsubscribe: Callable[[], None] | None = None

    def restore(self) -> int:
        """Apply the journaled facts (and the goal, when a goal change was
        journaled) in one batch; how many groundings they changed."""
        facts = self.store.kb_facts(self.instance)
        has_goal, goal = self.store.kb_goal(self.instance)
        if not facts and not has_goal:
            return 0
        saved: dict[str, Any] = {
            "facts": [{"fluent": f, "args": list(a), "value": v} for f, a, v in facts]
        }
        if has_goal:
            saved["goal"] = goal
        try:
            changed = len(self.kb.restore(saved, SOURCE))
        except KBError as err:
            log.warning(
                "journal of %s: the saved knowledge as a whole is refused (%s); "
                "restoring it fact by fact",
                self.instance,
                err,
            )
            updates = [Update("set", f, tuple(a), v) for f, a, v in facts]
            changed = self._one_by_one(updates)
            if has_goal:
                try:
                    self.kb.restore({"goal": goal}, SOURCE)
                except KBError as goal_err:
                    log.warning("journal of %s: saved goal left out: %s", self.instance, goal_err)
        log.info(
            "knowledge base of %s resumed from the journal: %d saved fact(s)%s, %d changed",
            self.instance,
            len(facts),
            " and its goal" if has_goal else "",
            changed,
        )
        return changed

    def _one_by_one(self, updates: Sequence[Update]) -> int:
        changed = 0
        for up in updates:
            try:
                changed += len(self.kb.apply([up], SOURCE))
            except KBError as err:
                log.warning("journal of %s: saved fact left out: %s", self.instance, err)
        return changed

    def start(self) -> None:
        """Journal the knowledge as it is now (every state-fluent grounding,
        source "start": what was set before the journal started is kept
        too), then every batch from now on."""
        if self._unsubscribe is None:
            facts = [(f, tuple(a), v) for (f, a), v in self.kb.facts().items()]
            self.store.record_kb_batch(self.instance, "start", facts, time.time())
            self._unsubscribe = self.kb.subscribe_journal(self._record)

    def stop(self) -> None:
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None

    def _record(self, entry: dict[str, Any]) -> None:
        """One journal entry of the knowledge base (a batch, or a goal
        change), written at once (the knowledge base calls this under its
        lock, so entries are stored in the order they happened)."""
        try:
            if "goal" in entry:
                self.store.record_kb_batch(
                    self.instance,
                    entry["source"],
                    [],
                    time.time(),
                    goal=entry["goal"],
                    goal_changed=True,
                )
            else:
                self.store.record_kb_batch(
                    self.instance,
                    entry["source"],
                    [(c["fluent"], tuple(c["args"]), c["new"]) for c in entry["changes"]],
                    time.time(),
                )
        except Exception as err:  # noqa: BLE001 - a full disk must not stop the robot
            self.failures += 1
            if self.failures == 1 or self.failures % 1000 == 0:
                log.error(
                    "journal of %s: the result store refused an entry (%d so far): %s",
                    self.instance,
                    self.failures,
                    err,
                )
        else:
            self.batches += 1
