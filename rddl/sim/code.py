"""The function being written, and the passes over its text.

Owns `_Code` (the statements of one generated function, in nested blocks,
with its inputs, the values computed so far for reuse, and the uniform
slots of its Bernoulli draws), `_Node` (what the compiler knows about one
value of that function), the peephole passes `_Code.source` runs on the
statements (`_drop_unused`; for large batches `_in_place` and
`_free_dead`), and the small helpers that write shapes, axes and
transpositions as code text. Imports numpy and `state` only: the
compiler (`base`, `operators`, ...) and `build` write into a `_Code`; this
module calls none of them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from .state import Array

Scope = tuple[tuple[str, str], ...]  # ((var, type), ...)


@dataclass(eq=False)
class _Node:
    """A value in the function being written: the Python expression that
    names it there, and what is known about it when the simulator is built."""

    code: str
    shape: tuple[int, ...]  # the batch axis (last) has size 1 here; B at run time when `batched`
    dtype: np.dtype[Any]
    rtype: str  # 'bool', 'int', 'real', or an enum or object type
    batched: bool  # depends on the state, the actions or a draw
    value: Array | None = None  # known when the simulator is built
    owner: str | None = None  # the temporary whose memory it is, if this call allocated it
    bounds: tuple[Array, Array] | None = None  # elementwise, every value lies within
    unexpanded: _Node | None = None  # the value before axes of size 1 were inserted
    narrow: _Node | None = None  # the same values as uint8 (a count of few bools)


@dataclass(eq=False)
class _Slot:
    """Uniform 32-bit integers for one draw site, shaped (*shape, B): a view
    of the block of random bits that the step draws first."""

    name: str
    shape: tuple[int, ...]


@dataclass(eq=False)
class _Pool:
    """The uniform slots of one branch: `free`, those that branches
    exclusive with this one drew (so this one may draw them again), and
    `used`, those this branch draws, in order."""

    free: list[_Slot] = dataclasses.field(default_factory=list)
    used: list[_Slot] = dataclasses.field(default_factory=list)


class _Code:
    """The source of one generated function: its statements (in nested
    blocks), the inputs it reads, and the values computed so far in each
    open block (for reuse)."""

    def __init__(self, name: str, params: str, large: bool = False, one: bool = False):
        self.name = name
        self.params = params
        self.large = large
        self.one = one  # for a batch of exactly one (see `base._widen_constant`)
        self.inputs: dict[str, str] = {}  # local name -> expression reading it
        self.lines: list[str] = []
        self.depth = 1
        self.memo: list[dict[Any, _Node]] = [{}]
        self.count = 0
        self.draws: list[str] = []  # where each draw is, in order
        # uniform slots, in the order of the block of random bits; the
        # innermost branch's pool last (see `operators.alternatives`)
        self.slots: list[_Slot] = []
        self.pools: list[_Pool] = [_Pool()]
        # constants repeated along the batch: (constant, shape) -> local name
        self.spread: dict[tuple[str, tuple[int, ...]], str] = {}
        # each temporary's shape, dtype and owner (for writing in place)
        self.meta: dict[str, tuple[tuple[int, ...], np.dtype[Any], str | None, bool]] = {}

    def temp(self) -> str:
        self.count += 1
        return f"t{self.count}"

    def emit(self, line: str) -> None:
        self.lines.append("    " * self.depth + line)

    def uniform(self, shape: tuple[int, ...]) -> str:
        """The name of uniform 32-bit integers shaped (*shape, B) for a
        draw: a slot that an exclusive branch drew (the first of the same
        shape), else a new one."""
        pool = self.pools[-1]
        for i, slot in enumerate(pool.free):
            if slot.shape == shape:
                del pool.free[i]
                pool.used.append(slot)
                return slot.name
        slot = _Slot(f"u{len(self.slots) + 1}", shape)
        self.slots.append(slot)
        pool.used.append(slot)
        return slot.name

    def lookup(self, key: Any) -> _Node | None:
        for table in reversed(self.memo):
            hit = table.get(key)
            if hit is not None:
                return hit
        return None

    def store(self, key: Any, node: _Node) -> None:
        self.memo[-1][key] = node

    @contextlib.contextmanager
    def block(self, header: str) -> Iterator[None]:
        """Statements under `header` (an `if ...:`); what they compute is
        not reused after the block."""
        self.emit(header)
        start = len(self.lines)
        self.depth += 1
        self.memo.append({})
        try:
            yield
        finally:
            if len(self.lines) == start:
                self.emit("pass")
            self.memo.pop()
            self.depth -= 1

    def source(self) -> str:
        head = [f"def {self.name}({self.params}):"]
        head += [f"    {k} = {v}" for k, v in self.inputs.items()]
        if self.draws:
            head.append("    if rng is None:")
            head.append(f"        _no_rng({self.draws[0]!r})")
        if self.slots:
            # every uniform of the step at once, in slot order, batch last
            sizes = [int(np.prod(slot.shape)) for slot in self.slots]
            head.append(f"    _u = _uniforms(rng, {sum(sizes)} * B)")
            start = 0
            for slot, size in zip(self.slots, sizes, strict=True):
                view = f"_u[{start} * B:{start + size} * B]"
                if slot.shape:
                    view += f".reshape({_last_shape_code(slot.shape)})"
                head.append(f"    {slot.name} = {view}")
                start += size
        body = _drop_unused(self.lines)
        if self.large:
            body = _free_dead(_in_place(body, self.meta))
        return "\n".join(head + body) + "\n"


_TEMP = re.compile(r"\bt\d+\b")
_ASSIGN = re.compile(r"\s*(t\d+) = ")
_BINARY = re.compile(
    r"(\s*)(t\d+) = (_add|_sub|_mul|_div|_minimum|_maximum|_land|_lor)\((\w+), (\w+)\)$"
)
_UNARY = re.compile(
    r"(\s*)(t\d+) = (_abs|_neg|_square|_sqrt|_trunc|np\.(?:exp|log|sqrt|cos|sin|tan|arccos|arcsin|arctan|cosh|sinh|tanh))"
    r"\((t\d+)\)$"
)


_CALL = re.compile(r"\brng\b|\bk\d+\(")  # a draw, or a call that may raise


def _drop_unused(lines: list[str]) -> list[str]:
    """`lines` without the assignments whose value is never read (a view
    made before the compiler found a way around it, say), except draws
    and calls that may raise."""
    lines = list(lines)
    while True:
        used: set[str] = set()
        for line in lines:
            m = _ASSIGN.match(line)
            rest = line[m.end() :] if m else line
            used.update(_TEMP.findall(rest))
        keep = []
        for line in lines:
            m = _ASSIGN.match(line)
            if m and m.group(1) not in used and not _CALL.search(line):
                continue
            keep.append(line)
        if len(keep) == len(lines):
            break
        lines = keep
    # a block left empty gets a `pass`
    out: list[str] = []
    for i, line in enumerate(lines):
        out.append(line)
        if line.rstrip().endswith(":"):
            depth = len(line) - len(line.lstrip())
            following = lines[i + 1] if i + 1 < len(lines) else ""
            if len(following) - len(following.lstrip()) <= depth:
                out.append(" " * (depth + 4) + "pass")
    return out


def _in_place(
    lines: list[str], meta: dict[str, tuple[tuple[int, ...], np.dtype[Any], str | None, bool]]
) -> list[str]:
    """`lines` with binary operations written into an argument's memory
    where that argument is a temporary this function allocated, of the
    result's shape and type, not read afterwards (nor any view of it):
    fewer allocations, and memory that is still in cache."""
    last: dict[str, int] = {}
    for i, line in enumerate(lines):
        for name in _TEMP.findall(line):
            last[name] = i
    # the last line where any view of each buffer is read
    buffer_last: dict[str, int] = {}
    for name, (_, _, owner, _) in meta.items():
        if owner is not None and name in last:
            buffer_last[owner] = max(buffer_last.get(owner, -1), last[name])
    out = list(lines)
    for i, line in enumerate(lines):
        m = _BINARY.match(line)
        if m is None:
            m = _UNARY.match(line)
        if m is None or m.group(2) not in meta:
            continue
        shape, dtype, _, batched = meta[m.group(2)]
        args = m.groups()[3:]
        for arg in args:
            info = meta.get(arg)
            if info is None or not batched:
                continue
            a_shape, a_dtype, a_owner, a_batched = info
            if (
                a_owner == arg
                and a_batched
                and a_shape == shape
                and a_dtype == dtype
                and buffer_last.get(arg) == i
            ):
                # (from here on the buffer is the result's, and only its)
                out[i] = f"{m.group(1)}{m.group(2)} = {m.group(3)}({', '.join(args)}, out={arg})"
                break
    return out


def _free_dead(lines: list[str]) -> list[str]:
    """`lines` with `del` statements for temporaries after their last use:
    memory is then reused within the step instead of growing (and being
    handed back to the system) every step, which costs page faults at
    large batches."""
    depth = [(len(line) - len(line.lstrip())) // 4 for line in lines]
    defined: dict[str, tuple[int, int]] = {}
    last: dict[str, int] = {}
    for i, line in enumerate(lines):
        for name in _TEMP.findall(line):
            last[name] = i
        m = _ASSIGN.match(line)
        if m and m.group(1) not in defined:
            defined[m.group(1)] = (i, depth[i])
    frees: dict[int, dict[int, list[str]]] = {}
    for name, (_, level) in defined.items():
        p = last[name] + 1
        while p < len(lines) and depth[p] > level:
            p += 1
        if p < len(lines):
            frees.setdefault(p, {}).setdefault(level, []).append(name)
    out: list[str] = []
    for i, line in enumerate(lines):
        for level, names in sorted(frees.get(i, {}).items(), reverse=True):
            out.append("    " * level + "del " + ", ".join(names))
        out.append(line)
    return out


_DTYPES = {"bool": np.bool_, "int": np.int64, "real": np.float64}
_DTYPE_CODE = {
    np.dtype(np.bool_): "_bool",
    np.dtype(np.int64): "_i64",
    np.dtype(np.float64): "_f64",
}


@functools.lru_cache(maxsize=4096)
def _compiled(text: str) -> Any:
    """`text` (a Python expression) compiled, for `eval` (the compiler
    evaluates the same few templates many times)."""
    return compile(text, "<rddl expression>", "eval")


def _tuple_code(items: Iterable[str]) -> str:
    items = list(items)
    return "(" + ", ".join(items) + ("," if len(items) == 1 else "") + ")"


def _shape_code(shape: tuple[int, ...]) -> str:
    """`(B, 3, 4)`: a batch of arrays shaped `shape`."""
    return _tuple_code(["B", *map(str, shape)])


def _axis_code(axes: tuple[int, ...]) -> str:
    """An `axis=` argument: an int for one axis (numpy takes it faster)."""
    return str(axes[0]) if len(axes) == 1 else str(axes)


def _index_code(keep: list[bool]) -> str:
    """`[:, None, :]`: insert an axis where `keep` is False (before the batch axis)."""
    return "[" + ", ".join([*(":" if k else "None" for k in keep), ":"]) + "]"


def _last_shape_code(shape: tuple[int, ...]) -> str:
    """`(3, 4, B)`: a batch of arrays shaped `shape`, batch axis last."""
    return _tuple_code([*map(str, shape), "B"])


def _batch_last(rank: int) -> str:
    """Code that views an array of this rank with its first axis moved last."""
    if rank <= 1:
        return ""
    if rank == 2:
        return ".T"
    return f".transpose({(*range(1, rank), 0)})"


def _batch_first(rank: int) -> str:
    """Code that views an array of this rank with its last axis moved first."""
    if rank <= 1:
        return ""
    if rank == 2:
        return ".T"
    return f".transpose({(rank - 1, *range(rank - 1))})"


_LARGE_BATCH = 16  # batches from this size on step with code written for large batches
