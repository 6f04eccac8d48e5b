"""The search kernels of the thts engine: the compiled step with mcts's C.

`Kernels` is the instance's compiled step (`rddl.sim.cstep.CStep`) built
with the planner's C sources after it (package data, csrc/): kernels.c, the
loops that call the step many times so that one call from Python does a
whole piece of work, and tree.c, the search itself (`ctree`).

* `probe`: every candidate action of a state under two fixed draw vectors,
  recording the probability at every Bernoulli and Discrete site and the
  standard deviation at every Normal site: which actions are deterministic,
  which deterministic actions are equivalent (the same successor, reward and
  end; stochastic actions are never merged);
* `ids_values`, `ids_values_enum`, `ids_values_cb`: PROST's IDS on the most-likely
  determinisation (every uniform 0.5, every normal 0) to a depth, with a
  cache of (depth, state) values kept across calls;
* `enum_setup`, `enumerate`: the legal joint actions of a state, built from
  the groundings legal alone and extended while legal;
* `walk`, `walk_enum`: roll-outs of noop or uniformly drawn actions.

The IDS cache and the legal-action walk's set-up are the library's (C
statics): `lock` is held around every call that uses them, so that two
sessions of one instance in one process's threads (a Dask worker's, say)
take turns there instead of racing (ctypes lets go of the GIL during a call).

Imports the compiled step (`rddl.sim.cstep`).
"""

from __future__ import annotations

import ctypes
import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...rddl.sim.cstep import CStep
from ...rddl.sim.scalar import ScalarStep

__all__ = ["CANDIDATES", "SOURCES", "Kernels", "kernel_source"]

log = logging.getLogger(__name__)

StateT = tuple[Any, ...]

_CSRC = Path(__file__).with_name("csrc")
SOURCES = ("kernels.c", "tree.c")
"""The planner's C files, in the order they follow the step in the unit."""


def kernel_source() -> str:
    """The planner's C text (package data), compiled after the step."""
    return "\n".join((_CSRC / name).read_text(encoding="utf-8") for name in SOURCES)


_LOCKS: dict[str, threading.RLock] = {}
_LOCKS_GUARD = threading.Lock()


def _library_lock(path: Path) -> threading.RLock:
    """One lock per loaded library: its IDS cache and legal-action walk (and
    the tree's use of them) are the library's, shared by every `Kernels` of
    that library in a process. Re-entrant: a C tree's search holds it while
    it calls back into Python, which may enumerate a state's actions."""
    with _LOCKS_GUARD:
        return _LOCKS.setdefault(str(path), threading.RLock())


_D = ctypes.POINTER(ctypes.c_double)
_I = ctypes.POINTER(ctypes.c_int)
_U64 = ctypes.POINTER(ctypes.c_uint64)
CANDIDATES = ctypes.CFUNCTYPE(ctypes.c_int, _D, _D, ctypes.c_int, _I)
"""The C type of a candidates callback (`cands_fn` in kernels.c)."""


class Kernels(CStep):
    """The compiled step with the search's kernels and tree (see the module
    docstring). Raises `CUnavailable` when it cannot be built."""

    def __init__(self, scalar: ScalarStep, seed: int = 0) -> None:
        super().__init__(scalar, seed, extra=kernel_source())
        lib = self.lib
        self.lock = _library_lock(self.path)
        """Held around every call that uses the library's IDS cache or
        legal-action walk (see the module docstring)."""
        lib.ippc_probe.argtypes = [_D, _D, ctypes.c_int, _D, _D, _D, _D, _D, _D, _I, _I, _I, _I]
        lib.ippc_ids_values.argtypes = [
            _D,
            _D,
            ctypes.c_int,
            _D,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_double,
            _D,
            ctypes.c_long,
        ]
        lib.ippc_ids_values.restype = ctypes.c_long
        lib.ippc_walk.argtypes = [_D, ctypes.c_int, _D, ctypes.c_int, _D, ctypes.c_double, _U64, _I]
        lib.ippc_walk.restype = ctypes.c_double
        lib.ippc_ids_clear.argtypes = []
        lib.ippc_enum_setup.argtypes = [_D, _I, _D, ctypes.c_int, ctypes.c_int, ctypes.c_int]
        lib.ippc_enum.argtypes = [_D, ctypes.c_int, _I, _D]
        lib.ippc_ids_values_enum.argtypes = [
            _D,
            _D,
            ctypes.c_int,
            ctypes.c_int,
            ctypes.c_double,
            _D,
            ctypes.c_long,
        ]
        lib.ippc_ids_values_enum.restype = ctypes.c_long
        lib.ippc_ids_values_cb.argtypes = [
            _D,
            _D,
            ctypes.c_int,
            ctypes.c_void_p,
            ctypes.c_int,
            ctypes.c_double,
            _D,
            ctypes.c_long,
        ]
        lib.ippc_ids_values_cb.restype = ctypes.c_long
        lib.ippc_walk_enum.argtypes = [_D, ctypes.c_int, ctypes.c_double, _U64, _I]
        lib.ippc_walk_enum.restype = ctypes.c_double
        self._enum_k = 0
        self._taken = ctypes.c_int()

    def probe(
        self, state: StateT, block: Any, n: int, draws: tuple[Any, Any, Any, Any]
    ) -> list[tuple[int, bool, StateT, float, bool, bool]]:
        """The kept actions of the `n` rows of `block` (see `ippc_probe`): per
        kept action its row, whether it is deterministic, the first probe's
        successor, reward and done, and whether both probes' rewards agree."""
        if n == 0:
            return []
        ns = self.ns
        n1 = (ctypes.c_double * (ns * n))()
        r1 = (ctypes.c_double * n)()
        d1 = (ctypes.c_int * n)()
        det = (ctypes.c_int * n)()
        same_r = (ctypes.c_int * n)()
        keep = (ctypes.c_int * n)()
        if (
            self.lib.ippc_probe(self._load(state), block, n, *draws, n1, r1, d1, det, same_r, keep)
            < 0
        ):
            raise MemoryError("ippc_probe")
        k = self.n_state
        return [
            (a, bool(det[a]), tuple(n1[a * ns : a * ns + k]), r1[a], bool(d1[a]), bool(same_r[a]))
            for a in range(n)
            if keep[a]
        ]

    def draw_block(self, uniforms: list[float], normals: list[float]) -> tuple[Any, Any]:
        """Fixed draws as C arrays (for `probe`)."""
        u = (ctypes.c_double * self.nu)(*(list(uniforms) + [0.5] * self.nu)[: self.nu])
        z = (ctypes.c_double * self.nz)(*(list(normals) + [0.0] * self.nz)[: self.nz])
        return u, z

    def ids_values(
        self,
        state: StateT,
        kept: Any,
        n_kept: int,
        cands: Any,
        n_cands: int,
        depth: int,
        gamma: float,
        token: int,
    ) -> tuple[list[float], int]:
        """IDS values of the `n_kept` actions of block `kept` (see
        `ippc_ids_values`), and the steps made. `token` (an int) names the
        candidates and gamma: a call with another token clears the cache."""
        out = (ctypes.c_double * max(1, n_kept))()
        with self.lock:
            steps = self.lib.ippc_ids_values(
                self._load(state), kept, n_kept, cands, n_cands, depth, gamma, out, token
            )
        return list(out[:n_kept]), int(steps)

    def enum_setup(self, grounds: list[tuple[int, float]], k: int, limit: int) -> None:
        """What `enumerate` may set: (action slot, value) pairs, at most `k` at
        once, counting up to `limit` joint actions."""
        n = len(grounds)
        pos = (ctypes.c_int * max(1, n))(*[g for g, _ in grounds])
        val = (ctypes.c_double * max(1, n))(*[float(v) for _, v in grounds])
        with self.lock:
            if self.lib.ippc_enum_setup(self.noop, pos, val, n, k, limit) < 0:
                raise MemoryError("ippc_enum_setup")
        self._enum_k = k

    def enumerate(self, state: StateT, cap: int) -> tuple[int, list[tuple[int, ...]]]:
        """The legal joint actions of `state` built by C (see `ippc_enum`):
        how many there are (-1: noop illegal, or more than the limit: the
        limit plus one), and the first `cap`, each as the indices (into
        `enum_setup`'s list) of the groundings it sets."""
        k = max(1, self._enum_k)
        g = (ctypes.c_int * (k * max(1, cap)))()
        with self.lock:
            n = int(self.lib.ippc_enum(self._load(state), cap, g, None))
        rows = []
        for i in range(min(max(n, 0), cap)):
            row = g[i * k : (i + 1) * k]
            rows.append(tuple(x for x in row if x >= 0) if self._enum_k else ())
        return n, rows

    def ids_values_enum(
        self, state: StateT, kept: Any, n_kept: int, depth: int, gamma: float, token: int
    ) -> tuple[list[float], int]:
        """`ids_values` with every state's candidates from `enumerate`."""
        out = (ctypes.c_double * max(1, n_kept))()
        with self.lock:
            steps = self.lib.ippc_ids_values_enum(
                self._load(state), kept, n_kept, depth, gamma, out, token
            )
        return list(out[:n_kept]), int(steps)

    def ids_values_cb(
        self,
        state: StateT,
        kept: Any,
        n_kept: int,
        candidates: Any,
        depth: int,
        gamma: float,
        token: int,
    ) -> tuple[list[float], int]:
        """`ids_values` with every state's candidates from `candidates`, a
        C callback (`ctree.CANDIDATES`: the tree's, asking the chooser)."""
        out = (ctypes.c_double * max(1, n_kept))()
        with self.lock:
            steps = self.lib.ippc_ids_values_cb(
                self._load(state),
                kept,
                n_kept,
                ctypes.cast(candidates, ctypes.c_void_p),
                depth,
                gamma,
                out,
                token,
            )
        return list(out[:n_kept]), int(steps)

    def candidates_callback(
        self,
        candidates: Callable[[StateT], list[int]],
        action_of: Callable[[int], tuple[Any, ...]],
    ) -> Any:
        """A C `cands_fn` (kernels.c) over Python: a state's legal candidates
        (library rows, from `candidates`, and their action vectors, from
        `action_of`). Keep the object alive while C may call it."""
        c = self
        k, na = c.n_state, c.na
        size = ctypes.sizeof(ctypes.c_double) * na

        def fn(s: Any, out: Any, cap: int, idx: Any) -> int:
            try:
                rows = candidates(tuple(s[:k]))
                if len(rows) > cap:
                    return -len(rows)
                base = ctypes.cast(out, ctypes.c_void_p).value or 0
                for i, r in enumerate(rows):
                    idx[i] = int(r)
                    ctypes.memmove(base + i * size, c.action(action_of(int(r))), size)
                return len(rows)
            except Exception:  # noqa: BLE001 - C cannot take it: a dead end, logged
                log.exception("mcts: the candidates of a state failed")
                return 0

        return CANDIDATES(fn)

    def ids_clear(self) -> None:
        with self.lock:
            self.lib.ippc_ids_clear()

    def walk(
        self, state: StateT, n: int, pool: Any, n_pool: int, gamma: float
    ) -> tuple[float, int, bool]:
        """A roll-out of up to `n` steps (noop when `n_pool` is 0): (its
        discounted return, the steps taken, whether the run ended)."""
        total = self.lib.ippc_walk(
            self._load(state),
            n,
            pool,
            n_pool,
            self.noop,
            gamma,
            ctypes.byref(self.rng),
            ctypes.byref(self._taken),
        )
        taken = int(self._taken.value)
        return float(total), abs(taken), taken < 0

    def walk_enum(self, state: StateT, n: int, gamma: float) -> tuple[float, int, bool]:
        """A roll-out of up to `n` steps whose actions are noop or one grounding
        of `enum_setup`'s legal in the state (see `ippc_walk_enum`), as `walk`."""
        with self.lock:
            total = self.lib.ippc_walk_enum(
                self._load(state), n, gamma, ctypes.byref(self.rng), ctypes.byref(self._taken)
            )
        taken = int(self._taken.value)
        return float(total), abs(taken), taken < 0
