"""The live feed: events published by a service, fanned out to viewers.

Theory of operation. A service calls `Feed.publish(event, topic)` from its
trio thread whenever something changed; the call encodes the event to JSON
once, appends it to the queue of every viewer subscribed to that topic and
returns. It never waits and never raises: a viewer whose queue is full (it
does not read, or reads too slowly) is marked overflowed and its connection
is cancelled, so a viewer can cost a session nothing but the append. The
browser's EventSource reconnects by itself and gets a fresh snapshot, so a
dropped viewer loses no part of the picture, only the time to reconnect.

A viewer subscribes with the events that describe the current picture (its
snapshot, computed by the page at connect time), so it never sees a change
before the state it applies to.
"""

from __future__ import annotations

import json
import logging
import math
from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import trio

log = logging.getLogger(__name__)

DEFAULT_QUEUE = 256  # events a viewer may have unread before it is dropped


def to_json(value: Any) -> bytes:
    """JSON for a page or a stream: ASCII only (no raw line separator can end
    an event's `data:` line early), `<`, `>` and `&` as `\\u` escapes (no
    markup in any byte the view sends, whatever a client is called), NaN and
    infinities as null (JSON has no such numbers)."""
    text = json.dumps(_finite(value), separators=(",", ":"), ensure_ascii=True)
    return (
        text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026").encode("ascii")
    )


def encode_event(event: Mapping[str, Any]) -> bytes:
    """One server-sent event: `data: <json>` and a blank line."""
    return b"data: " + to_json(event) + b"\n\n"


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


class Subscription:
    """One viewer's queue of encoded events (see `Feed.subscribe`)."""

    def __init__(self, feed: Feed, topics: frozenset[str], size: int):
        self.feed = feed
        self.topics = topics
        self.size = size
        self.queue: deque[bytes] = deque()
        self.overflowed = False
        self.closed = False
        self._wakeup = trio.Event()
        # cancelled when the viewer falls behind (set by the connection)
        self.scope: trio.CancelScope | None = None

    def _put(self, data: bytes) -> None:
        if self.overflowed:
            return
        if len(self.queue) >= self.size:
            self.overflowed = True
            self.queue.clear()
            self.feed.dropped += 1
            if self.scope is not None:
                self.scope.cancel()
        else:
            self.queue.append(data)
        self._wakeup.set()

    def put_nowait(self, event: Mapping[str, Any]) -> None:
        """Queue one event for this viewer only (its snapshot: not counted
        against the queue's bound, which is for what comes after)."""
        self.queue.append(encode_event(event))
        self._wakeup.set()

    async def next_batch(self) -> list[bytes]:
        """The events queued so far (waiting for at least one); an empty
        list once the viewer overflowed or the feed closed."""
        while not self.queue and not self.overflowed and not self.closed:
            await self._wakeup.wait()
            self._wakeup = trio.Event()
        if self.overflowed:
            return []
        batch = list(self.queue)
        self.queue.clear()
        return batch


class Feed:
    """Events for the viewers of one service, by topic.

    `publish` is the only call a service makes; it is meant for the trio
    thread of the service (from another thread use
    `trio.from_thread.run_sync(feed.publish, event)`). Counters for a page
    or a test: `viewers`, `published`, `dropped` (viewers dropped because
    they fell behind)."""

    def __init__(self, *, queue_size: int = DEFAULT_QUEUE):
        if queue_size < 1:
            raise ValueError("queue_size must be at least 1")
        self.queue_size = queue_size
        self._subs: dict[str, set[Subscription]] = {}
        self.published = 0
        self.dropped = 0
        self._failures = 0

    @property
    def viewers(self) -> int:
        return len({s for subs in self._subs.values() for s in subs})

    def watched(self, topic: str) -> bool:
        """Whether any viewer follows `topic` (a publisher may skip building
        events nobody reads)."""
        return bool(self._subs.get(topic))

    def publish(self, event: Mapping[str, Any], topic: str = "") -> None:
        """Send `event` (a JSON-able mapping) to the viewers of `topic`.
        Never blocks, never raises: an event that cannot be encoded is
        logged (once in a while) and skipped."""
        try:
            subs = self._subs.get(topic)
            if not subs:
                return
            data = encode_event(event)
            self.published += 1
            for sub in tuple(subs):
                sub._put(data)
        except Exception as err:  # the caller is a session: never its problem
            self._failures += 1
            if self._failures == 1 or self._failures % 1000 == 0:
                log.error(
                    "web feed: event on %r not sent (%d so far): %s: %s",
                    topic,
                    self._failures,
                    type(err).__name__,
                    err,
                )

    @contextmanager
    def subscribe(
        self, topics: Iterable[str], snapshot: Iterable[Mapping[str, Any]] = ()
    ) -> Iterator[Subscription]:
        """A viewer of `topics`, its queue starting with `snapshot` (the
        events that draw the current picture). Leave the block to
        unsubscribe."""
        sub = Subscription(self, frozenset(topics), self.queue_size)
        for event in snapshot:
            sub.put_nowait(event)
        for topic in sub.topics:
            self._subs.setdefault(topic, set()).add(sub)
        try:
            yield sub
        finally:
            sub.closed = True
            for topic in sub.topics:
                subs = self._subs.get(topic)
                if subs is not None:
                    subs.discard(sub)
                    if not subs:
                        del self._subs[topic]

    def close(self) -> None:
        """End every viewer's stream (the service is stopping)."""
        for subs in self._subs.values():
            for sub in subs:
                sub.closed = True
                sub._wakeup.set()


__all__ = ["DEFAULT_QUEUE", "Feed", "Subscription", "encode_event", "to_json"]
