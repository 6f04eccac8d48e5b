"""What the live models and pages of rddl-batch and rddl-dispatch share.

`Listeners`: the callbacks of a live model (``subscribe`` / ``emit``), called after
the model's lock is released; one that raises is logged and the others still hear.

`PageUpdates`: a page's changes (the rows of its tables, its fields) gathered between
flushes: the last cells of each row and the last value of each field win, so a viewer
gets at most two events a flush however fast the service changes (`html.rows_event`,
`html.fields_event`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from typing import Any

from .html import fields_event, rows_event

__all__ = ["Listeners", "PageUpdates"]

log = logging.getLogger(__name__)

Listener = Callable[[dict[str, Any]], None]


class Listeners:
    """Callbacks hearing a live model's events (any thread may subscribe)."""

    def __init__(self, what: str) -> None:
        self.what = what  # for the log line of a callback that fails
        self._lock = threading.Lock()
        self._callbacks: list[Listener] = []

    def subscribe(self, callback: Listener) -> Callable[[], None]:
        """Call `callback(event)` for every event; returns the function that stops it."""
        with self._lock:
            self._callbacks.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._callbacks:
                    self._callbacks.remove(callback)

        return unsubscribe

    def emit(self, events: list[dict[str, Any]]) -> None:
        """Tell every callback every event, in order (call it without the model's lock)."""
        with self._lock:
            callbacks = list(self._callbacks)
        for event in events:
            for cb in callbacks:
                try:
                    cb(event)
                except Exception:  # a viewer's bug must never stop the service
                    log.exception("%s: a listener failed on %s", self.what, event.get("type"))


class PageUpdates:
    """Changes to a page gathered between flushes (see the module doc)."""

    def __init__(self) -> None:
        self.rows: dict[tuple[str, str], dict[str, Any]] = {}
        self.fields: dict[str, Any] = {}

    def add(self, event: Mapping[str, Any]) -> None:
        """A `rows` or `fields` event, merged into what is gathered."""
        if event["type"] == "rows":
            for row in event["rows"]:
                self.rows.setdefault((row["table"], row["key"]), {}).update(row.get("cells", {}))
        elif event["type"] == "fields":
            self.fields.update(event["fields"])

    def take(self) -> list[dict[str, Any]]:
        """The events of what was gathered (none: nothing changed); empties it."""
        out = []
        if self.rows:
            out.append(rows_event([(t, k, c) for (t, k), c in self.rows.items()]))
        if self.fields:
            out.append(fields_event(self.fields))
        self.rows, self.fields = {}, {}
        return out
