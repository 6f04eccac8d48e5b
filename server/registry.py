"""The instances a server serves: every RDDL file under a folder, by name.

Each instance carries the task rddlsim sends in session-init, built as
rddlsim builds it: the bytes of the file that declares the domain, a line
separator twice, the bytes of the file that declares the instance, one line
separator. Simulators are compiled on first use and shared by sessions
(a `Simulator` holds no per-session state).
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trio

from ..protocol import ObservedFluentsWriter
from ..rddl import check_files
from ..rddl.model import Model
from ..rddl.simulator import Simulator, State
from ..rddl.wire import WireCodec, WireFluent
from .environment import Environment, Episode, SimulatedEpisode

log = logging.getLogger(__name__)

#: Characters of turn elements an instance keeps for states that come back.
TURN_CACHE_CHARS = 8 * 1024 * 1024

# What a problem-name may look like; anything else (a path, a NUL, ...) is
# refused before it is looked up.
_NAME = re.compile(r"^[A-Za-z0-9_\-.]+$")


@dataclass
class Instance(Environment):
    """One servable instance: a simulated environment (rddlsim's)."""

    name: str
    model: Model
    task: bytes
    _compiled: tuple[Simulator, WireCodec] | None = field(default=None, repr=False)
    _lock: trio.Lock | None = field(default=None, repr=False)
    # writes the observed fluents of this instance's turns; shared by the sessions
    _writer: ObservedFluentsWriter | None = field(default=None, repr=False)
    # turns already written, by the bytes of the arrays they were written from
    _turns: dict[tuple[tuple[str, bytes], ...], tuple[list[WireFluent] | None, str | None]] = field(
        default_factory=dict, repr=False
    )
    _turn_chars: int = field(default=0, repr=False)
    _key_names: tuple[str, ...] = field(default=(), repr=False)

    async def open(self, seed: int) -> Episode:
        """A simulated episode with the session's generator (`seed`)."""
        sim, codec = await self.compiled()
        return SimulatedEpisode(self, sim, codec, seed)

    async def compiled(self) -> tuple[Simulator, WireCodec]:
        """The simulator and wire codec, compiled once (in a worker thread,
        so a big instance does not stall other sessions)."""
        if self._compiled is None:
            if self._lock is None:
                self._lock = trio.Lock()
            async with self._lock:
                if self._compiled is None:
                    self._compiled = await trio.to_thread.run_sync(self._compile)
        return self._compiled

    def compiled_now(self) -> tuple[Simulator, WireCodec]:
        """As `compiled`, synchronously."""
        if self._compiled is None:
            self._compiled = self._compile()
        return self._compiled

    def fluents_writer(self, sent: Sequence[WireFluent]) -> ObservedFluentsWriter:
        """The writer for turns that list the groundings of `sent` (a
        `WireCodec.turn_fluents` listing: always the same groundings in the
        same order for one instance), built at the first turn."""
        writer = self._writer
        if writer is None or len(writer) != len(sent):
            writer = ObservedFluentsWriter([(name, args) for name, args, _ in sent])
            self._writer = writer
        return writer

    def turn_fluents(
        self, codec: WireCodec, state: State, observation: Mapping[str, np.ndarray] | None
    ) -> tuple[list[WireFluent] | None, str | None]:
        """What a turn lists in `state` (MDP) or with `observation` (POMDP):
        `codec.turn_fluents(...)` and its observed-fluent elements as the
        instance's writer writes them (None, None for a POMDP's first turn).

        States repeat (sysadmin's ten computers have 1024), so turns are
        kept by the bytes and types of the arrays the listing is made of,
        up to `TURN_CACHE_CHARS` characters of elements per instance; after
        that new states are written every time."""
        source = observation if codec.pomdp else state.values
        if source is None:
            return None, None
        names = self._key_names
        if len(names) != len(source):
            names = self._key_names = tuple(sorted(source))
        key: tuple[tuple[str, bytes], ...] | None
        try:
            key = tuple([(a.dtype.char, a.tobytes()) for a in [source[n] for n in names]])
        except KeyError:  # another set of fluents than the last time: not cached
            key = None
        if key is not None:
            hit = self._turns.get(key)
            if hit is not None:
                return hit
        sent = codec.turn_fluents(state, observation)
        xml = None if sent is None else self.fluents_writer(sent).write([t[2] for t in sent])
        # object arrays hold pointers, not values: never a key
        if (
            key is not None
            and self._turn_chars < TURN_CACHE_CHARS
            and all(c != "O" for c, _ in key)
        ):
            self._turns[key] = (sent, xml)
            self._turn_chars += len(xml or "") + 64
        return sent, xml

    def _compile(self) -> tuple[Simulator, WireCodec]:
        sim = Simulator(self.model)
        return sim, WireCodec(sim)


def build_task(model: Model) -> bytes:
    """rddlsim's session-init task: domain file bytes + "\\n\\n" + instance
    file bytes + "\\n" (so a file holding both is sent twice, as rddlsim does).
    """
    sep = os.linesep.encode()
    dom = Path(model.domain_file).read_bytes()
    inst = Path(model.instance_file).read_bytes()
    return dom + sep + sep + inst + sep


class UnknownInstance(LookupError):
    """A problem-name that the server does not serve; the message says why."""


class Registry:
    """Instances by name, loaded from files and folders."""

    def __init__(self, instances: dict[str, Instance], broken: dict[str, str] | None = None):
        self.instances = instances
        self.broken = broken or {}  # name (or file) -> the first error

    @classmethod
    def load(cls, *paths: str | os.PathLike[str]) -> Registry:
        """Every instance under `paths` that checks; those that do not are
        kept in `broken` with their first error and logged."""
        instances: dict[str, Instance] = {}
        broken: dict[str, str] = {}
        for res in check_files(*paths):
            if res.kind != "instance":
                if not res.ok:
                    broken[res.file] = res.diagnostics[0].render()
                continue
            if res.model is None or not res.ok:
                broken[res.name] = (
                    res.diagnostics[0].render() if res.diagnostics else "does not check"
                )
                continue
            instances[res.name] = Instance(res.name, res.model, build_task(res.model))
        for name, why in broken.items():
            log.warning("not serving %s: %s", name, why)
        return cls(instances, broken)

    def __len__(self) -> int:
        return len(self.instances)

    def names(self) -> list[str]:
        return sorted(self.instances)

    def get(self, name: str) -> Instance:
        """The instance called `name`; `UnknownInstance` says why not."""
        if not _NAME.match(name) or name in (".", ".."):
            raise UnknownInstance(
                f"problem-name {name!r} is not an instance name (it looks like a path or has odd characters)"
            )
        inst = self.instances.get(name)
        if inst is None:
            why = self.broken.get(name)
            if why is not None:
                raise UnknownInstance(f"instance {name!r} does not check: {why}")
            raise UnknownInstance(f"unknown instance {name!r} ({len(self.instances)} served)")
        return inst
