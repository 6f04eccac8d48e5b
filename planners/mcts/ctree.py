"""`CTree`: the `thts` engine's trials in C, beside the compiled step.

The search is written in C, in csrc/tree.c (package data, compiled into the
instance's library after the step and csrc/kernels.c by `ckernels.Kernels`);
this module drives it from Python: it makes a tree, hands it the candidate
actions (fixed rows, or a callback that asks the Python chooser for a
state's legal ones), runs its trials and reads the root's view. The
search, node for node:

* decision nodes in a transposition table keyed by (steps left, state),
  kept across the turns of a round (cleared at a new round, or when it
  holds more than `max_nodes` nodes);
* expansion: every candidate probed under the two fixed draw vectors,
  equivalent actions dropped, the exact last step, sinks solved at once
  (and the session's `blind_weight` switch); first values by IDS on
  the most-likely determinisation (scaled to the steps left) or by
  roll-outs (`rollout_policy`, `rollout_depth`, extrapolation);
* trials: UCB1 over the unsolved actions, the exploration scaled by the
  node's largest |Q|, ties broken at random; one sampled outcome per level;
  MaxMonteCarlo backups with the partial Bellman backup for actions with at
  most `bellman_outcomes` outcomes; solved labelling;
* time: trials until the budget less the slowest recent trial (a decaying
  maximum), or exactly `iterations` trials.

The draws come from the step's splitmix64 generator, seeded from the
planner's: a seed gives the same search. The tree lives in C memory owned
by the `CTree` (freed with it); a library holds any number of trees. Its
IDS cache is the library's: a search holds the library's lock
(`Kernels.lock`), so that two sessions of one instance in two threads of a
process (a Dask worker's) take turns instead of racing.

Imports the kernels (`ckernels`) and the node type of `thts`
(whose fields the root's view fills).
"""

from __future__ import annotations

import ctypes
import logging
import time
from collections.abc import Callable
from typing import Any

from .ckernels import Kernels
from .options import Settings
from .stats import SearchStats
from .thts import THTS, TNode

__all__ = ["CRoot", "CTree", "attach"]

_D = ctypes.POINTER(ctypes.c_double)
_I = ctypes.POINTER(ctypes.c_int)
_L = ctypes.POINTER(ctypes.c_long)
_POLICIES = {"random": 0, "noop": 1, "best": 2}
log = logging.getLogger(__name__)


class CRoot(TNode):
    """The view of a node of the C tree: its actions (as candidate rows),
    values, samples and labels, copied out after the search."""

    __slots__ = ("index",)

    def __init__(self, state: tuple[Any, ...], steps: int, index: int) -> None:
        super().__init__(state, steps, False)
        self.index = index


class CTree:
    """One session's search tree in C (see the module docstring)."""

    def __init__(
        self,
        c: Kernels,
        rows: list[int],
        acts: list[tuple[Any, ...]],
        pool: list[tuple[Any, ...]] | None,
        probes: tuple[list[float], list[float], list[float], list[float]],
        settings: Settings,
        gamma: float,
        seed: int,
        token: int,
        candidates: Callable[[tuple[Any, ...]], list[int]] | None = None,
        action_of: Callable[[int], tuple[Any, ...]] | None = None,
    ) -> None:
        lib = c.lib
        lib.ctree_new.restype = ctypes.c_void_p
        lib.ctree_new.argtypes = [
            _D,
            ctypes.c_int,
            _D,
            ctypes.c_int,
            _D,
            _D,
            _D,
            _L,
            ctypes.c_uint64,
            ctypes.c_void_p,
        ]
        lib.ctree_free.argtypes = [ctypes.c_void_p]
        lib.ctree_reset.argtypes = [ctypes.c_void_p]
        lib.ctree_set_ids.argtypes = [ctypes.c_void_p, ctypes.c_int]
        lib.ctree_set_enum.argtypes = [ctypes.c_void_p, ctypes.c_int]
        lib.ctree_root.argtypes = [ctypes.c_void_p, _D, ctypes.c_int]
        lib.ctree_root.restype = ctypes.c_long
        lib.ctree_search.argtypes = [
            ctypes.c_void_p,
            ctypes.c_long,
            ctypes.c_double,
            ctypes.c_long,
            _L,
        ]
        lib.ctree_info.argtypes = [
            ctypes.c_void_p,
            ctypes.c_long,
            ctypes.c_int,
            _I,
            _D,
            _L,
            _I,
            _D,
            _L,
        ]
        self.c = c
        self.lib = lib
        self.rows = rows
        self.dynamic = candidates is not None
        """Whether candidates come from `candidates(state)` (library rows,
        state-dependent legality) rather than the fixed `rows`."""
        self._callback: Any = None
        if candidates is not None:
            assert action_of is not None
            self._callback = c.candidates_callback(candidates, action_of)
        u1, z1, u2, z2 = probes
        flat = [*u1[: c.nu], *z1[: c.nz], *u2[: c.nu], *z2[: c.nz]]
        block = (ctypes.c_double * len(flat))(*flat)
        params = (ctypes.c_double * 5)(
            gamma,
            settings.init_weight,
            settings.exploration,
            settings.heuristic_weight,
            settings.blind_weight,
        )
        iparams = (ctypes.c_long * 10)(
            0,
            settings.bellman_outcomes,
            settings.rollout_depth,
            _POLICIES[settings.rollout_policy],
            int(settings.extrapolate),
            settings.max_nodes,
            token,
            int(settings.ids_deepen),
            int(settings.ids_smooth),
            int(settings.blind_future),
        )
        pool = pool or []
        self._ptr = lib.ctree_new(
            c.block(acts),
            len(acts),
            c.block(pool),
            len(pool),
            c.noop,
            block,
            params,
            iparams,
            seed & (2**64 - 1),
            ctypes.cast(self._callback, ctypes.c_void_p) if self._callback is not None else None,
        )
        if not self._ptr:
            raise MemoryError("ctree_new")
        self._info_buffers(max(1, len(acts)))
        self._value = ctypes.c_double()
        self._flags = (ctypes.c_long * 4)()
        self._stats = (ctypes.c_long * 5)()

    def __del__(self) -> None:
        ptr = getattr(self, "_ptr", None)
        if ptr:
            self.lib.ctree_free(ptr)
            self._ptr = None

    def _info_buffers(self, n: int) -> None:
        self._acts = (ctypes.c_int * n)()
        self._q = (ctypes.c_double * n)()
        self._n = (ctypes.c_long * n)()
        self._solved = (ctypes.c_int * n)()

    def set_ids_depth(self, depth: int) -> None:
        self.lib.ctree_set_ids(self._ptr, depth)

    def start_round(self) -> None:
        self.lib.ctree_reset(self._ptr)

    def root(self, state: tuple[Any, ...], steps: int) -> CRoot:
        """The root's view (a `TNode` whose fields are copied from C)."""
        s = self.c._load(state)
        index = self.lib.ctree_root(self._ptr, s, steps)
        if index < 0:
            raise MemoryError("ctree_root")
        node = CRoot(state, steps, index)
        self._read(node)
        return node

    def _read(self, node: CRoot) -> None:
        index = node.index
        while True:
            k = self.lib.ctree_info(
                self._ptr,
                index,
                len(self._acts),
                self._acts,
                self._q,
                self._n,
                self._solved,
                ctypes.byref(self._value),
                self._flags,
            )
            if k <= len(self._acts):
                break
            self._info_buffers(k)  # (state-dependent candidates: more than before)
        node.expanded = bool(self._flags[0])
        node.solved = bool(self._flags[1])
        node.value = self._value.value
        acts = self._acts[:k]
        node.rows = list(acts) if self.dynamic else [self.rows[i] for i in acts]
        node.q = list(self._q[:k])
        node.n = list(self._n[:k])
        node.asolved = [bool(x) for x in self._solved[:k]]
        self.size = int(self._flags[3])

    def search(
        self, root: TNode, deadline: float | None, iterations: int | None, turn: SearchStats
    ) -> None:
        """Trials from `root` until `deadline` (time.monotonic) or exactly
        `iterations`; the root's view is read afterwards."""
        assert isinstance(root, CRoot)
        index = root.index
        with self.c.lock:  # (the library's IDS cache: one search of it at a time)
            budget = 1e9 if deadline is None else max(0.0, deadline - time.monotonic())
            rc = self.lib.ctree_search(
                self._ptr, index, budget, -1 if iterations is None else iterations, self._stats
            )
        if rc < 0:
            raise MemoryError("ctree_search")
        turn.trials += int(self._stats[0])
        turn.leaves += int(self._stats[1])
        turn.ids_leaves += int(self._stats[2])
        turn.sim_steps += int(self._stats[3])
        turn.locks += int(self._stats[4])
        self._read(root)


def attach(search: THTS) -> bool:
    """Give `search` its tree in C (see the module docstring). Call it once
    the candidates are set up (`THTS.setup_enum`) and IDS's depth is known.
    Returns True (the tree always fits: static or state-dependent candidates)."""
    c = search.c
    seed = int(search.rng.integers(0, 2**63 - 1))
    common = (search.pool, search._probe_draws, search.st, search.gamma, seed, search._token)
    if search._static:
        rows = search._candidates(search.fast.encode_state(search.sim.initial_state(1)))
        search.tree = CTree(c, list(rows), [search._tuple(r) for r in rows], *common)
    else:
        # legality depends on the state: each new node asks the chooser (one
        # sample of candidates a state key)
        search.chooser.fixed_samples = True
        search.tree = CTree(
            c, [], [], *common, candidates=search._candidates, action_of=search._tuple
        )
    search.tree.set_ids_depth(search.ids_depth)
    if search._cenum:
        search.tree.lib.ctree_set_enum(search.tree._ptr, 1)
    return True
