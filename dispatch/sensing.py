"""Sensing: sensor messages -> values of sensed fluents -> the knowledge base.

Theory of operation (ROSPlan's sensing interface, without ROS). A
`SensingConfig` says, per sensed fluent, which streams feed it and how a
message gives its value. `Sensing` marks those fluents sensed in the
knowledge base, and then:

* every message that arrives on a stream (`feed`, a `publisher`, an async
  iterator or a polled callable given to `attach`, or `sensing.publish`
  over the JSON-lines socket) is evaluated at once by each sensor reading
  that stream; a value is kept only when it differs from the last value
  sensed for that grounding or from the knowledge base's (a message that
  repeats what is known costs nothing more);
* the kept values go to the knowledge base in one batch (`flush`, source
  "sensing"), at a fixed rate (`run`, `config.rate` batches per second) and
  whenever the dispatcher waits for sensing to settle (`settle`);
* when someone else (a handler, a remote client) changes a grounding that
  was sensed to another value, the sensed value is sent again at the next
  batch: sensed truth wins (ROSPlan re-sends after outside changes too).

A message that a sensor cannot evaluate (a missing field, a value of the
wrong type, an unknown object) is logged with the sensor's place in the
config and skipped; it never stops sensing or the dispatcher. `errors`
keeps the last ones for reports.
"""

from __future__ import annotations

import collections
import logging
from collections.abc import AsyncIterable, Awaitable, Callable, Iterable, Mapping
from typing import Any

import trio

from ..kb import Change, KnowledgeBase, Update
from ..rddl.model import Model, Value
from .clock import Clock, WallClock
from .config import SensingConfig, SensorSpec
from .expr import EvaluationError

__all__ = ["Sensing", "SensingError", "coerce_value"]

log = logging.getLogger(__name__)

Key = tuple[str, tuple[str, ...]]

SOURCE = "sensing"


class SensingError(ValueError):
    """A message a sensor cannot use, or a stream no sensor reads."""


def coerce_value(model: Model, fluent: str, value: Any) -> Value:
    """`value` as the knowledge base stores `fluent`'s values, or
    `SensingError` saying what was expected."""
    p = model.pvariables[fluent]
    item = getattr(value, "item", None)  # numpy scalars
    if callable(item) and not isinstance(value, str | bool | int | float):
        value = item()
    if p.range == "bool":
        if isinstance(value, bool):
            return value
        raise SensingError(f"{fluent} is a bool, the value is {value!r}")
    if p.range == "int":
        if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value):
            raise SensingError(f"{fluent} is an int, the value is {value!r}")
        return int(value)
    if p.range == "real":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SensingError(f"{fluent} is a real, the value is {value!r}")
        return float(value)
    members = model.objects(p.range)
    if isinstance(value, str):
        if value in members:
            return value
        if not value.startswith("@") and "@" + value in members:
            return "@" + value
    raise SensingError(f"{fluent} takes a {p.range} ({', '.join(members)}), the value is {value!r}")


class Sensing:
    """Sensed fluents of one knowledge base, fed by sensor streams."""

    def __init__(
        self,
        kb: KnowledgeBase,
        config: SensingConfig,
        *,
        clock: Clock | None = None,
        keep_errors: int = 50,
    ):
        self.kb = kb
        self.config = config
        self.model: Model = kb.model
        self.clock = clock or WallClock()
        self.period = 1.0 / config.rate
        self._by_stream: dict[str, list[SensorSpec]] = collections.defaultdict(list)
        for spec in config.sensors:
            for stream in spec.streams:
                self._by_stream[stream].append(spec)
        self._last: dict[Key, Value] = {}  # the last value sensed per grounding
        self._pending: dict[Key, Value] = {}  # to send at the next batch
        self.messages = 0  # messages received
        self.batches = 0  # batches that changed the knowledge base
        self.activity = 0  # values kept (changes seen), for `settle`
        self.errors: collections.deque[str] = collections.deque(maxlen=keep_errors)
        for fluent in sorted(config.fluents()):
            kb.set_sensed(fluent, True)
        self._unsubscribe = kb.subscribe(self._on_change)

    # -- messages in

    def streams(self) -> frozenset[str]:
        return frozenset(self._by_stream)

    def feed(self, stream: str, msg: Any) -> int:
        """Evaluate one message of `stream`; the number of groundings whose
        value it changed (sent at the next batch). A stream no sensor reads
        raises `SensingError`; a message a sensor cannot use is logged and
        skipped (see `errors`)."""
        specs = self._by_stream.get(stream)
        if specs is None:
            known = ", ".join(sorted(self._by_stream)) or "none"
            raise SensingError(f"no sensor reads stream {stream!r} (streams: {known})")
        self.messages += 1
        changed = 0
        for spec in specs:
            try:
                values = self._evaluate(spec, msg)
            except (SensingError, EvaluationError) as err:
                text = f"{spec.where}: {spec.fluent} from stream {stream!r}: {err}"
                self.errors.append(text)
                log.warning("sensing: %s", text)
                continue
            for key, value in values:
                if self._keep(key, value):
                    changed += 1
        return changed

    def publisher(self, stream: str) -> Callable[[Any], int]:
        """A function that feeds one message of `stream` (checked now)."""
        if stream not in self._by_stream:
            raise SensingError(f"no sensor reads stream {stream!r}")
        return lambda msg: self.feed(stream, msg)

    async def attach(
        self,
        stream: str,
        source: AsyncIterable[Any] | Callable[[], Any | Awaitable[Any]],
        *,
        period: float | None = None,
    ) -> None:
        """Feed `stream` from an async iterator until it ends, or from a
        callable polled every `period` seconds (default: the batch period)
        until cancelled. A callable may be async; returning None means no
        message this time."""
        if stream not in self._by_stream:
            raise SensingError(f"no sensor reads stream {stream!r}")
        if isinstance(source, AsyncIterable):
            async for msg in source:
                self.feed(stream, msg)
            return
        wait = self.period if period is None else period
        while True:
            msg = source()
            if isinstance(msg, Awaitable):
                msg = await msg
            if msg is not None:
                self.feed(stream, msg)
            await self.clock.sleep(wait)

    def _evaluate(self, spec: SensorSpec, msg: Any) -> list[tuple[Key, Value]]:
        env = {"msg": msg}
        fixed: list[str | None] = []
        for param in spec.params:
            if param.kind == "fixed":
                fixed.append(param.name)
            elif param.kind == "message":
                assert param.expr is not None
                fixed.append(self._object(param.expr.evaluate(env), param.type, spec))
            else:
                fixed.append(None)
        result = spec.value.evaluate(env)
        wild = spec.wildcards
        if not wild:
            return [((spec.fluent, tuple(fixed)), coerce_value(self.model, spec.fluent, result))]  # type: ignore[arg-type]
        pairs: Iterable[Any]
        if isinstance(result, Mapping):
            pairs = result.items()
        elif isinstance(result, list | tuple):
            pairs = result
        else:
            raise SensingError(
                f"with wildcard parameters the value must be a mapping or a list of pairs "
                f"(objects -> value), not {type(result).__name__}"
            )
        out: list[tuple[Key, Value]] = []
        for pair in pairs:
            try:
                objects, value = pair
            except (TypeError, ValueError):
                raise SensingError(f"{pair!r} is not a pair (objects, value)") from None
            names = self._split(objects, len(wild))
            args = list(fixed)
            for pos, name in zip(wild, names, strict=True):
                args[pos] = self._object(name, spec.params[pos].type, spec)
            out.append(((spec.fluent, tuple(args)), coerce_value(self.model, spec.fluent, value)))  # type: ignore[arg-type]
        return out

    @staticmethod
    def _split(objects: Any, n: int) -> list[Any]:
        if isinstance(objects, str):
            parts = objects.split(":") if n > 1 else [objects]
        elif isinstance(objects, list | tuple):
            parts = list(objects)
        else:
            parts = [objects]
        if len(parts) != n:
            raise SensingError(f"{objects!r} gives {len(parts)} object(s) for {n} wildcard(s)")
        return parts

    def _object(self, name: Any, type_name: str, spec: SensorSpec) -> str:
        members = self.model.objects(type_name)
        if isinstance(name, str) and name in members:
            return name
        raise SensingError(f"{name!r} is not an object of type {type_name}")

    def _keep(self, key: Key, value: Value) -> bool:
        last = self._last.get(key, _UNSET)
        self._last[key] = value
        if last == value and type(last) is type(value) and key not in self._pending:
            if self.kb.get(key[0], key[1]) == value:
                return False
        self._pending[key] = value
        self.activity += 1
        return True

    # -- values out

    def pending(self) -> int:
        """Values waiting for the next batch."""
        return len(self._pending)

    def flush(self) -> list[Change]:
        """Send the waiting values to the knowledge base as one batch; the
        changes it made."""
        if not self._pending:
            return []
        updates = [Update("set", f, args, v) for (f, args), v in self._pending.items()]
        self._pending = {}
        changes = self.kb.apply(updates, SOURCE)
        if changes:
            self.batches += 1
        return changes

    async def run(self, *, task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> None:
        """Send a batch every period until cancelled."""
        task_status.started()
        next_tick = self.clock.now()
        while True:
            next_tick += self.period
            await self.clock.sleep_until(next_tick)
            self.flush()

    async def settle(self, limit: float = 2.0) -> list[Change]:
        """Wait until sensing is quiet: send what is waiting, then wait a
        period; again while messages brought new values, at most `limit`
        seconds. The changes made meanwhile."""
        changes = self.flush()
        deadline = self.clock.now() + limit
        while True:
            before = self.activity
            await self.clock.sleep(min(self.period, max(0.0, deadline - self.clock.now())))
            changes += self.flush()
            if self.activity == before or self.clock.now() >= deadline:
                return changes

    def close(self) -> None:
        """Stop listening to the knowledge base (the fluents stay sensed)."""
        self._unsubscribe()

    def _on_change(self, changes: list[Change], source: str) -> None:
        if source == SOURCE:
            return
        for ch in changes:
            key = (ch.fluent, tuple(ch.args))
            sensed = self._last.get(key, _UNSET)
            if sensed is not _UNSET and sensed != ch.new:
                self._pending[key] = sensed  # type: ignore[assignment]


_UNSET: Any = object()
