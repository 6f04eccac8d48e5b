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
from dataclasses import dataclass, field
from pathlib import Path

import trio

from ..rddl import check_files
from ..rddl.model import Model
from ..rddl.simulator import Simulator
from ..rddl.wire import WireCodec

log = logging.getLogger(__name__)

# What a problem-name may look like; anything else (a path, a NUL, ...) is
# refused before it is looked up.
_NAME = re.compile(r"^[A-Za-z0-9_\-.]+$")


@dataclass
class Instance:
    """One servable instance."""

    name: str
    model: Model
    task: bytes
    _compiled: tuple[Simulator, WireCodec] | None = field(default=None, repr=False)
    # wire fluent -> protocol Fluent, shared by the sessions (values repeat)
    fluents: dict[tuple[object, ...], object] = field(default_factory=dict, repr=False)
    _lock: trio.Lock | None = field(default=None, repr=False)

    @property
    def horizon(self) -> int | None:
        return self.model.horizon

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
                broken[res.name] = res.diagnostics[0].render() if res.diagnostics else "does not check"
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
            raise UnknownInstance(f"problem-name {name!r} is not an instance name (it looks like a path or has odd characters)")
        inst = self.instances.get(name)
        if inst is None:
            why = self.broken.get(name)
            if why is not None:
                raise UnknownInstance(f"instance {name!r} does not check: {why}")
            raise UnknownInstance(f"unknown instance {name!r} ({len(self.instances)} served)")
        return inst
