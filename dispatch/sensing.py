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
wrong type, an unknown object) and a value its fluent cannot hold (NaN;
infinity, unless the sensor allows it with `infinite: true`; an int beyond
64 bits; a real beyond a double) are refused: the value (or, when the
message gives nothing usable, the message) is skipped, the rest of the
message and the next messages go on, and nothing stops sensing or the
dispatcher. A batch the knowledge base refuses as a whole (it would break a
state invariant: odometry that puts a robot in two rooms) is tried again
stream by stream, so one stream's contradiction does not hold up another's
values; what is still refused is dropped. Every refusal is counted per
stream (`refused`) and kept in `errors` (the last ones); the log gets the
first refusal of a stream in full, and while refusals go on, one summary
line per stream per `WARNING_PERIOD` seconds (how many, and why, for which
groundings) instead of one line each.
"""

from __future__ import annotations

import collections
import logging
import math
from collections.abc import AsyncIterable, Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import trio

from ..kb import Change, KBError, KnowledgeBase, Update
from ..kb.store import INT_MAX, INT_MIN
from ..rddl.model import Model, Value
from .clock import Clock, WallClock
from .config import SensingConfig, SensorSpec
from .expr import EvaluationError

__all__ = ["WARNING_PERIOD", "Sensing", "SensingError", "coerce_value"]

log = logging.getLogger(__name__)

Key = tuple[str, tuple[str, ...]]

SOURCE = "sensing"
WARNING_PERIOD = 10.0  # seconds: at most one log line per stream per period


class SensingError(ValueError):
    """A message a sensor cannot use, or a stream no sensor reads. `kind`
    says why in a word or two for summaries ("NaN", "infinity", "out of
    range", "wrong type", "unknown object", "bad message", "invariant")."""

    def __init__(self, message: str, kind: str = "bad message"):
        super().__init__(message)
        self.kind = kind


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:50] + " ..."


def coerce_value(model: Model, fluent: str, value: Any, *, infinite: bool = False) -> Value:
    """`value` as the knowledge base stores `fluent`'s values, or
    `SensingError` saying what was expected: a bool for a bool fluent; an
    integral number within 64 bits for an int; a number for a real (NaN
    never, an infinity only with `infinite`, nothing beyond a double); a
    member's name for an enum or object fluent."""
    p = model.pvariables[fluent]
    item = getattr(value, "item", None)  # numpy scalars
    if callable(item) and not isinstance(value, str | bool | int | float):
        try:
            value = item()
        except (TypeError, ValueError):  # an array of several values
            pass
    if p.range == "bool":
        if isinstance(value, bool):
            return value
        raise SensingError(f"{fluent} is a bool, the value is {_show(value)}", "wrong type")
    if p.range in ("int", "real"):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SensingError(
                f"{fluent} is {'an int' if p.range == 'int' else 'a real'}, "
                f"the value is {_show(value)}",
                "wrong type",
            )
        if isinstance(value, float) and math.isnan(value):
            raise SensingError(f"{fluent} cannot hold NaN", "NaN")
        if isinstance(value, float) and math.isinf(value):
            if p.range == "int":
                raise SensingError(f"{fluent} is an int, the value is {value}", "infinity")
            if not infinite:
                raise SensingError(
                    f"{fluent} is given {value} (an infinity; the sensor allows it with "
                    "infinite: true)",
                    "infinity",
                )
            return value
        if p.range == "int":
            if isinstance(value, float) and not value.is_integer():
                raise SensingError(f"{fluent} is an int, the value is {value!r}", "wrong type")
            number = int(value)
            if not INT_MIN <= number <= INT_MAX:
                raise SensingError(
                    f"{fluent} is a 64-bit int, the value {_show(value)} is out of range",
                    "out of range",
                )
            return number
        try:
            return float(value)
        except OverflowError:  # an int beyond the largest double
            raise SensingError(
                f"{fluent} is a real (a double), the value {_show(value)} is out of range",
                "out of range",
            ) from None
    members = model.objects(p.range)
    if isinstance(value, str):
        if value in members:
            return value
        if not value.startswith("@") and "@" + value in members:
            return "@" + value
        raise SensingError(
            f"{fluent} takes a {p.range} ({', '.join(members)}), the value is {_show(value)}",
            "unknown object",
        )
    raise SensingError(
        f"{fluent} takes a {p.range} ({', '.join(members)}), the value is {_show(value)}",
        "wrong type",
    )


@dataclass
class _Window:
    """The refusals of one stream since its last log line."""

    start: float
    count: int = 0
    reasons: collections.Counter[str] = field(default_factory=collections.Counter)


class RefusalLog:
    """Log lines about refused sensor values, at most one per stream per
    `period` seconds: the first refusal in full, then, while refusals go
    on, a summary per period ("stream 'odometry': 212 refused in the last
    10 s (NaN for battery(r1): 200, ...)")."""

    def __init__(self, clock: Clock, period: float = WARNING_PERIOD):
        self.clock = clock
        self.period = period
        self._windows: dict[str, _Window] = {}
        self.lines = 0  # log lines written, for tests and reports

    def refuse(self, stream: str, reason: str, text: str) -> None:
        now = self.clock.now()
        self.tick(now)
        w = self._windows.get(stream)
        if w is None:
            self._windows[stream] = _Window(now)
            self.lines += 1
            log.warning("sensing: %s", text)
            return
        w.count += 1
        w.reasons[reason] += 1

    def tick(self, now: float | None = None) -> None:
        """Write the summaries of the periods that are over."""
        if not self._windows:
            return
        now = self.clock.now() if now is None else now
        for stream, w in list(self._windows.items()):
            if now < w.start + self.period:
                continue
            if not w.count:
                del self._windows[stream]  # quiet: the next refusal is told in full
                continue
            top = w.reasons.most_common(4)
            why = ", ".join(f"{r}: {n}" for r, n in top)
            more = len(w.reasons) - len(top)
            if more > 0:
                why += f", {more} other reason(s)"
            self.lines += 1
            log.warning(
                "sensing: stream %r: %d more value(s) refused in the last %.0f s (%s)",
                stream,
                w.count,
                now - w.start,
                why,
            )
            self._windows[stream] = _Window(now)  # still refusing: summaries go on


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
        self._origin: dict[Key, str] = {}  # the stream each pending value came from
        self.messages = 0  # messages received
        self.batches = 0  # batches that changed the knowledge base
        self.activity = 0  # values kept (changes seen), for `settle`
        self.errors: collections.deque[str] = collections.deque(maxlen=keep_errors)
        self.refused: collections.Counter[str] = collections.Counter()  # per stream
        self.refusals = RefusalLog(self.clock)
        for fluent in sorted(config.fluents()):
            kb.set_sensed(fluent, True)
        self._unsubscribe = kb.subscribe(self._on_change)
        # what one `publish` call kept and what was refused, while it runs
        self._collect: dict[str, list[Any]] | None = None

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
                values = self._evaluate(spec, msg, stream)
            except (SensingError, EvaluationError) as err:
                self._refuse(stream, spec, err)
                continue
            except Exception as err:  # a message no check foresaw: refused, never fatal
                log.debug("sensing: unexpected failure on a message", exc_info=True)
                self._refuse(stream, spec, SensingError(f"{type(err).__name__}: {err}"))
                continue
            for key, value in values:
                if self._keep(key, value, stream):
                    changed += 1
        return changed

    def publish(self, stream: str, msg: Any) -> dict[str, Any]:
        """Feed one message of `stream` and send what it changed to the
        knowledge base at once (with whatever else waits): what the
        knowledge base accepted (`accepted`: fluent, args, value) and what
        was refused, by the sensor or the knowledge base (`refused`: fluent,
        args or grounding, value when there is one, reason). `changed` is
        the number accepted. A stream no sensor reads raises SensingError."""
        collect: dict[str, list[Any]] = {"kept": [], "refused": []}
        self._collect = collect
        try:
            self.feed(stream, msg)
            self.flush()
        finally:
            self._collect = None
        refused = collect["refused"]
        gone = {(r["fluent"], tuple(r.get("args", ()))) for r in refused if "args" in r}
        accepted = []
        for (fluent, args), value in dict(collect["kept"]).items():
            if (fluent, args) in gone:
                continue
            if self.kb.get(fluent, args) == value:
                accepted.append({"fluent": fluent, "args": list(args), "value": value})
        return {"changed": len(accepted), "accepted": accepted, "refused": refused}

    def _refuse(
        self, stream: str, spec: SensorSpec, err: Exception, grounding: str | None = None
    ) -> None:
        kind = getattr(err, "kind", "bad message")
        grounding = grounding or getattr(err, "grounding", None)
        if self._collect is not None:
            self._collect["refused"].append(
                {"fluent": spec.fluent, "grounding": grounding or spec.fluent, "reason": str(err)}
            )
        text = f"{spec.where}: {spec.fluent} from stream {stream!r}: {err}"
        self.errors.append(text)
        self.refused[stream] += 1
        self.refusals.refuse(stream, f"{kind} for {grounding or spec.fluent}", text)

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

    def _evaluate(self, spec: SensorSpec, msg: Any, stream: str) -> list[tuple[Key, Value]]:
        """The groundings and values of one message; a value the fluent
        cannot hold, or a pair naming no object, is refused on its own
        (the rest of the message counts); SensingError or EvaluationError
        when the message gives nothing usable."""
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
            key: Key = (spec.fluent, tuple(fixed))  # type: ignore[arg-type]
            return [(key, self._value(spec, key, result))]
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
        refused: list[tuple[SensingError, str | None]] = []
        for pair in pairs:
            try:
                try:
                    objects, value = pair
                except (TypeError, ValueError):
                    raise SensingError(f"{_show(pair)} is not a pair (objects, value)") from None
                names = self._split(objects, len(wild))
                args = list(fixed)
                for pos, name in zip(wild, names, strict=True):
                    args[pos] = self._object(name, spec.params[pos].type, spec)
                key = (spec.fluent, tuple(args))  # type: ignore[arg-type]
                out.append((key, self._value(spec, key, value)))
            except SensingError as bad:
                refused.append((bad, getattr(bad, "grounding", None)))
        for error, grounding in refused:
            self._refuse(stream, spec, error, grounding)
        return out

    def _value(self, spec: SensorSpec, key: Key, value: Any) -> Value:
        try:
            return coerce_value(self.model, spec.fluent, value, infinite=spec.infinite)
        except SensingError as err:
            where = f"{key[0]}({', '.join(key[1])})" if key[1] else key[0]
            text = str(err)
            if text.startswith(key[0] + " "):  # "battery is ..." -> "battery(r1) is ..."
                text = where + text[len(key[0]) :]
            named = SensingError(text, err.kind)
            named.grounding = where  # type: ignore[attr-defined]
            raise named from None

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
        raise SensingError(f"{_show(name)} is not an object of type {type_name}", "unknown object")

    def _keep(self, key: Key, value: Value, stream: str) -> bool:
        last = self._last.get(key, _UNSET)
        self._last[key] = value
        if last == value and type(last) is type(value) and key not in self._pending:
            if self.kb.get(key[0], key[1]) == value:
                return False
        self._pending[key] = value
        self._origin[key] = stream
        self.activity += 1
        if self._collect is not None:
            self._collect["kept"].append((key, value))
        return True

    # -- values out

    def pending(self) -> int:
        """Values waiting for the next batch."""
        return len(self._pending)

    def flush(self) -> list[Change]:
        """Send the waiting values to the knowledge base as one batch; the
        changes it made."""
        self.refusals.tick()
        if not self._pending:
            return []
        pending, origin = self._pending, self._origin
        self._pending, self._origin = {}, {}
        try:
            changes = self.kb.apply(self._updates(pending), SOURCE)
        except KBError as err:
            by_stream: dict[str, list[Key]] = collections.defaultdict(list)
            for key in pending:
                by_stream[origin.get(key, "?")].append(key)
            if len(by_stream) == 1:
                ((stream, keys),) = by_stream.items()
                self._refuse_batch(stream, keys, err, pending)
                return []
            # one stream's contradiction must not hold up the others' values
            changes = []
            for stream, keys in by_stream.items():
                try:
                    changes += self.kb.apply(self._updates({k: pending[k] for k in keys}), SOURCE)
                except KBError as one:
                    self._refuse_batch(stream, keys, one, pending)
        if changes:
            self.batches += 1
        return changes

    @staticmethod
    def _updates(values: Mapping[Key, Value]) -> list[Update]:
        return [Update("set", f, args, v) for (f, args), v in values.items()]

    def _refuse_batch(
        self, stream: str, keys: list[Key], err: KBError, values: Mapping[Key, Value]
    ) -> None:
        """The knowledge base refused `stream`'s values (a broken state
        invariant): dropped, and forgotten as sensed (so they are not sent
        again when someone else writes those groundings)."""
        for key in keys:
            self._last.pop(key, None)
            if self._collect is not None:
                self._collect["refused"].append(
                    {
                        "fluent": key[0],
                        "args": list(key[1]),
                        "value": values[key],
                        "reason": str(err),
                    }
                )
        violations = getattr(err, "violations", None)
        if violations:
            v = violations[0]
            reason = f"{err.code} ({v.loc}{' for ' + v.grounding if v.binding else ''})"
        else:
            reason = err.code
        text = f"stream {stream!r}: {len(keys)} value(s) refused by the knowledge base: {err}"
        self.errors.append(text)
        self.refused[stream] += 1
        self.refusals.refuse(stream, reason, text)

    async def run(self, *, task_status: trio.TaskStatus[None] = trio.TASK_STATUS_IGNORED) -> None:
        """Send a batch every period until cancelled."""
        task_status.started()
        next_tick = self.clock.now()
        while True:
            next_tick += self.period
            await self.clock.sleep_until(next_tick)
            self.flush()  # (which writes the refusal summaries that are due)

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
                self._origin.setdefault(key, "(sensed again)")


_UNSET: Any = object()
