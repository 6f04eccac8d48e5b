"""A vectorised RDDL simulator: `Model` -> numpy.

Theory of operation. Every pvariable is a tensor with one axis per
parameter (sized by its type's members) and a batch axis, so a whole batch
of states is stepped at once. Enum and object values are integer codes
(their index in the range type's members). Arrays go in and out batch
first, shaped (batch, *params); inside a step they are batch *last*,
(*params, batch), and the arrays a step returns are batch-first views of
batch-last memory: numpy's loops then run along the batch, which is what
makes large batches fast (reductions over a relation's small axes,
gathers of neighbours, are row operations).

The compiler turns the transition, and separately the action constraints,
into the source of one Python function of numpy operations, `exec`ed once:
a step is one call, with no Python loop over groundings and no walk of the
expression tree. An expression is compiled in a *scope* (the typed
variables free at that point: a cpf's parameters, then those of enclosing
aggregations), and its value is an array of rank len(scope) + 1: axis i the
i-th scope variable, the last axis the batch; any axis may have size 1
where the value does not depend on it, and broadcasting does the rest.
While it writes the function the compiler knows every value's shape and
dtype (it runs each operation once on stand-ins), and

* folds every subexpression that reads only non-fluents and constants into
  a constant, computed once when the simulator is built (a condition that
  is the same everywhere picks its branch);
* compiles an expression that does not draw in the smallest scope its
  variables need, and computes an expression that occurs twice once;
* turns `sum` and `exists` over a product or conjunction with a constant
  factor (CONNECTED(?y, ?x), NEIGHBOR(...)) into a matrix product, or a few
  row gathers where the relation pairs each value with few others; sums a
  variable that one factor alone depends on in that factor first; splits a
  sum of a sum or difference into two sums;
* checks a distribution's parameters when the simulator is built where they
  are constants, not at all where elementwise bounds carried through the
  arithmetic prove them valid, and otherwise with one comparison per
  parameter over the whole array.

The step is compiled for small batches (fewest numpy calls) and, on the
first large batch, again for large ones (least memory traffic: contiguous
layouts, gathers instead of products, logical operations instead of
np.where, results written in place, temporaries freed early). Both make
the same draws in the same order and compute the same values.

Random draws: one independent draw per batch element and per grounding of
every variable in scope, whatever the parameters depend on (Bernoulli and
Normal drawn batch last, (*scope, batch) in C order, as the step lays
values out; the others batch first, (batch, *scope)); nothing that draws
is ever folded or computed once for two draws, so the same seed gives the
same trajectory. The uniforms of every Bernoulli are drawn first, at once:
raw 64-bit outputs of the caller's bit generator, each cut into two 32-bit
integers u, one slot of them per draw site in the order of the expression
tree (left to right, inner first); Bernoulli(p) is u < p * 2**32, computed
exactly, so it fires with probability within 2**-32 of p (never for p = 0,
always for p = 1) at half the bits and none of the conversion of
`rng.random()`'s doubles, which cost more than the rest of the step on
large batches. A Bernoulli whose p is 0 everywhere (or 1 everywhere) when
the simulator is built draws nothing. The other distributions draw after
them, in the order of the tree, through the Generator's own methods. As
rddlsim, which evaluates only the branch taken, the branches of an `if`
or a `switch` (which each element takes one of) draw the same uniforms:
each element reads a uniform through one branch only, so one draw per
grounding is made where rddlsim makes one, yet the stream does not depend
on the branches taken; a condition that is the same everywhere draws for
its branch alone.

Semantics follow rddlsim: interm and derived fluents in level order (then
declaration order), then next-state cpfs, then observations (which may read
the next state); the reward of the transition sees the current state, the
actions, the intermediates and the next state; actions not given take their
default; `/` is real division; bools count as 0/1 in arithmetic; enum values
with integer names (@1) count as that integer in arithmetic;
action-preconditions and state-action-constraints are checked on the
current state and actions before the step, max-nondef-actions counts the
actions that differ from their default, and state-invariants are checked on
the next state. `termination` (pyRDDLGym) ends an episode when it holds.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import itertools
import logging
import re
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import ast as A
from .model import ACTION, DERIVED, INTERM, NON_FLUENT, OBSERV, STATE, Model, PVariable, Value
from .prestep import POST_NAME, PRE_NAME, split_step_source

log = logging.getLogger(__name__)

Array = np.ndarray


class SimulationError(Exception):
    """A step cannot be taken: a constraint is violated, or a distribution
    was given parameters outside its domain. The message names the
    constraint (with its place in the file), the grounding and the actions."""


# ------------------------------------------------------------- state


class State:
    """A batch of states: one array per state fluent, batch axis first.

    Cheap to copy (`copy`) and to index (`state[i]`, `state[mask]`).
    """

    __slots__ = ("values",)

    def __init__(self, values: dict[str, Array]):
        self.values = values

    @property
    def batch(self) -> int:
        for v in self.values.values():
            return v.shape[0]  # type: ignore[no-any-return]
        return 1

    def copy(self) -> State:
        return State({k: v.copy() for k, v in self.values.items()})

    def __getitem__(self, index: Any) -> State:
        out = {}
        for k, v in self.values.items():
            x = v[index]
            if isinstance(index, (int, np.integer)):
                x = x[None]
            out[k] = x
        return State(out)

    def __repr__(self) -> str:
        return f"State(batch={self.batch}, fluents={len(self.values)})"


@dataclass(frozen=True)
class Step:
    """The outcome of `Simulator.step` for a batch."""

    next_state: State
    reward: Array  # (batch,)
    observation: dict[str, Array] | None  # observ fluents, POMDPs only
    done: Array  # (batch,) bool: termination holds in the next state


class Prepared:
    """The part of one state's next step that its actions do not decide
    (`Simulator.prepare`), waiting for them (`Simulator.finish`)."""

    __slots__ = ("state", "values", "rng_state")

    def __init__(self, state: State, values: tuple[Any, ...], rng_state: Any):
        self.state = state
        self.values = values
        self.rng_state = rng_state  # the bit generator's state before the draws


class _Env:
    """A state and actions, as `_check_preconditions` takes them."""

    __slots__ = ("state", "actions", "rng", "batch")

    def __init__(
        self,
        state: State,
        actions: Mapping[str, Array],
        rng: np.random.Generator | None,
        batch: int,
    ):
        self.state = state
        self.actions = actions
        self.rng = rng
        self.batch = batch


Scope = tuple[tuple[str, str], ...]  # ((var, type), ...)

_new = object.__new__
_UNBUILT = object()


def _broadcasts_to(shape: tuple[int, ...], target: tuple[int, ...]) -> bool:
    """Whether an array of `shape` broadcasts against one of `target`
    without changing `target`."""
    try:
        return np.broadcast_shapes(shape, target) == target
    except ValueError:
        return False


def _make_step(
    nxt: dict[str, Array], reward: Array, obs: dict[str, Array] | None, done: Array
) -> Step:
    # what Step(State(nxt), reward, obs, done) makes, without the frozen
    # dataclass's setattr calls: a step is short
    out = _new(Step)
    fields = out.__dict__
    fields["next_state"] = State(nxt)
    fields["reward"] = reward
    fields["observation"] = obs
    fields["done"] = done
    return out


def _int_enum_value(name: str) -> int | None:
    body = name[1:]
    try:
        return int(body)
    except ValueError:
        return None


# ------------------------------------------------------ generated code


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
        self.one = one  # for a batch of exactly one (see `_Compiler._widen_constant`)
        self.inputs: dict[str, str] = {}  # local name -> expression reading it
        self.lines: list[str] = []
        self.depth = 1
        self.memo: list[dict[Any, _Node]] = [{}]
        self.count = 0
        self.draws: list[str] = []  # where each draw is, in order
        # uniform slots, in the order of the block of random bits; the
        # innermost branch's pool last (see `_Compiler.alternatives`)
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


# the largest constant (in elements) made for a batch of one out of a smaller one
_WIDEN_LIMIT = 4096
_UFUNC_CALL = re.compile(r"(_\w+)\(\{0\}, \{1\}\)$")  # a template `_add({0}, {1})`
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


def _is_draw(e: A.Expr) -> bool:
    if isinstance(e, (A.Discrete, A.DiscreteOver, A.VectorDistribution)):
        return True
    return isinstance(e, A.Distribution) and e.name not in ("KronDelta", "DiracDelta")


# ---------------------------------------------------------- compiler


def _bidx_factory() -> Callable[[int, int], Array]:
    cache: dict[tuple[int, int], Array] = {}

    def bidx(batch: int, rank: int) -> Array:
        """Batch indices shaped to broadcast against rank-`rank` indices."""
        arr = cache.get((batch, rank))
        if arr is None:
            if len(cache) > 64:
                cache.clear()
            arr = np.arange(batch).reshape((1,) * (rank - 1) + (-1,))
            arr.flags.writeable = False
            cache[(batch, rank)] = arr
        return arr

    return bidx


def _action_in_factory() -> Callable[[Array, tuple[int, ...]], Array]:
    cache: dict[tuple[tuple[int, ...], str], Array] = {}

    def action_in(a: Array, axes: tuple[int, ...]) -> Array:
        """An action array (batch first) as a contiguous array with its
        axes in the order `axes` (batch last); where every value is zero,
        a shared read-only array of zeros."""
        # (count_nonzero is several times faster than any() on bools, and
        # twice as slow on numbers)
        if np.count_nonzero(a) if a.dtype == np.bool_ else a.any():
            return np.ascontiguousarray(a.transpose(axes))
        shape = tuple(a.shape[i] for i in axes)
        key = (shape, a.dtype.str)
        zeros = cache.get(key)
        if zeros is None:
            if len(cache) > 64:
                cache.clear()
            zeros = np.zeros(shape, a.dtype)
            zeros.flags.writeable = False
            cache[key] = zeros
        return zeros

    return action_in


# the largest constant (in elements per state) repeated along the batch for
# large batches (see `_Compiler._spread_constant`), and the largest such
# array (in bytes) made at run time: beyond the caches a second array costs
# more memory traffic than broadcasting saves
_SPREAD_CELLS = 4096
_SPREAD_BYTES = 1 << 20


def _spread_factory() -> Callable[[Array, tuple[int, ...]], Array]:
    cache: dict[tuple[int, tuple[int, ...]], tuple[Array, Array]] = {}

    def spread(k: Array, shape: tuple[int, ...]) -> Array:
        """The constant `k` repeated to `shape` (its batch axis, last), a
        contiguous read-only array made once per shape; `k` itself (to be
        broadcast) where that array would be large."""
        key = (id(k), shape)
        hit = cache.get(key)
        if hit is not None and hit[0] is k:
            return hit[1]
        if k.itemsize * int(np.prod(shape)) > _SPREAD_BYTES:
            out = k
        else:
            out = np.ascontiguousarray(np.broadcast_to(k, shape))
            out.flags.writeable = False
        if len(cache) > 256:
            cache.clear()
        # (the entry holds `k`: its id is not reused while it is cached)
        cache[key] = (k, out)
        return out

    return spread


# multiply-adds per BLAS call, at most: OpenBLAS runs a smaller product on
# one thread (its threshold is 4 * 65536); a threaded one stalls badly on a
# busy machine, and these products are small anyway
_BLAS_BLOCK = 200_000


def _matmul_cols(k: Array, f: Array) -> Array:
    """`k @ f` (2-D, or stacks of matrices), computed in blocks of columns
    of `f` small enough for one thread each."""
    cols = f.shape[-1]
    per_col = k.size
    if per_col * cols <= _BLAS_BLOCK or cols < 2:
        return np.matmul(k, f)  # type: ignore[no-any-return]
    out = np.empty((*f.shape[:-2], k.shape[-2], cols), dtype=np.result_type(k, f))
    step = max(1, _BLAS_BLOCK // per_col)
    for i in range(0, cols, step):
        np.matmul(k, f[..., i : i + step], out=out[..., i : i + step])
    return out


def _gather_sum(x: Array, rows: tuple[Array, ...]) -> Array:
    """`x[rows[0]] + x[rows[1]] + ...`, added in that order (the same
    values), into one new array: `take` gathers rows faster than indexing,
    and adding in place spares a temporary per row."""
    out = x.take(rows[0], axis=0)
    for r in rows[1:]:
        np.add(out, x.take(r, axis=0), out=out)
    return out


def _pad_zero_row(x: Array) -> Array:
    """`x` with a row of zeros added below."""
    out = np.empty((x.shape[0] + 1, *x.shape[1:]), dtype=x.dtype)
    out[:-1] = x
    out[-1] = 0
    return out


def _uniforms(rng: np.random.Generator, n: int) -> Array:
    """`n` independent uniform integers in [0, 2**32): the raw 64-bit
    outputs of `rng`'s bit generator, each cut in two (its low half
    first on a little-endian machine). Half the bits of `rng.random()`'s
    53-bit doubles, twice as many numbers per output, and no conversion:
    plenty for a Bernoulli (see `_Compiler._Distribution`)."""
    return rng.bit_generator.random_raw((n + 1) >> 1).view(np.uint32)  # type: ignore[no-any-return]


# A Bernoulli(p) draw from a uniform integer u in [0, 2**32) is u < p * 2**32
# (computed exactly in float64): it fires with probability ceil(p * 2**32) /
# 2**32, within 2**-32 (2.3e-10) of p, never for p = 0 and always for p = 1.
_TWO_32 = 2.0**32


def _no_rng(where: str) -> None:
    raise SimulationError(f"{where}: a random draw needs a numpy Generator (rng)")


# The floating-point error state a step runs in: numpy's current state with
# divide, invalid and overflow ignored, exactly as `np.errstate(divide=
# "ignore", invalid="ignore", over="ignore")` sets it. That context manager
# costs a microsecond or more per step (it parses its arguments and builds
# the state afresh), about a twentieth of a small step, so on numpy >= 2 (the
# state is a context variable there) the state built for each current state
# is kept, and a step already in it (a step within a step's caller that
# set it) changes nothing.
def _error_state_api() -> tuple[Any, Any]:
    """numpy's context variable of the floating-point error state, and its
    function that builds a state from the current one; (None, None) where
    numpy has no such thing (1.x: `np.errstate` itself is used then)."""
    try:
        from numpy._core import umath
    except ImportError:
        return None, None
    var, make = getattr(umath, "_extobj_contextvar", None), getattr(umath, "_make_extobj", None)
    if var is None or make is None:
        return None, None
    return var, make


_ERR_VAR, _make_extobj = _error_state_api()
_QUIET: dict[Any, Any] = {}  # current state -> the quiet one built on it (itself for a quiet one)


def _quiet_state(current: Any) -> Any:
    """The quiet state built on `current` (which is the current one)."""
    quiet = _make_extobj(divide="ignore", invalid="ignore", over="ignore")
    if len(_QUIET) > 32:
        _QUIET.clear()
    # (the keys hold the states alive: an id is never reused while cached)
    _QUIET[current] = quiet
    _QUIET[quiet] = quiet
    return quiet


def _quietly(fn: Callable[..., Any], *args: Any) -> Any:
    """`fn(*args)` with divide, invalid and overflow floating-point errors
    ignored (as under `np.errstate(divide="ignore", invalid="ignore",
    over="ignore")`), the caller's state restored after."""
    if _ERR_VAR is None:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return fn(*args)
    current = _ERR_VAR.get()
    quiet = _QUIET.get(current)
    if quiet is None:
        quiet = _quiet_state(current)
    if quiet is current:
        return fn(*args)
    token = _ERR_VAR.set(quiet)
    try:
        return fn(*args)
    finally:
        _ERR_VAR.reset(token)


# names the generated code uses (globals of every generated function)
_BUILTINS: dict[str, Any] = {
    "np": np,
    "_bool": np.bool_,
    "_i64": np.int64,
    "_f64": np.float64,
    "_f32": np.float32,
    "_cnz": np.count_nonzero,
    "_land": np.logical_and,
    "_lor": np.logical_or,
    "_lnot": np.logical_not,
    "_bitand": np.bitwise_and,
    "_bitor": np.bitwise_or,
    "_u8": np.uint8,
    "_contiguous": np.ascontiguousarray,
    "_pad_zero_row": _pad_zero_row,
    "_gather_sum": _gather_sum,
    "_eq": np.equal,
    "_ne": np.not_equal,
    "_lt": np.less,
    "_le": np.less_equal,
    "_gt": np.greater,
    "_ge": np.greater_equal,
    "_add": np.add,
    "_sub": np.subtract,
    "_mul": np.multiply,
    "_div": np.true_divide,
    "_neg": np.negative,
    "_where": np.where,
    # reductions as `x.sum(axis=a, keepdims=k)` and the like make them:
    # `_sum(x, a)`, `_sum(x, a, None, None, k)`, `_all(x, a, _bool)`...
    "_sum": np.add.reduce,
    "_all": np.logical_and.reduce,
    "_any": np.logical_or.reduce,
    "_min_reduce": np.minimum.reduce,
    "_max_reduce": np.maximum.reduce,
    "_select": np.select,
    "_minimum": np.minimum,
    "_maximum": np.maximum,
    "_fmod": np.fmod,
    "_abs": np.abs,
    "_sign": np.sign,
    "_trunc": np.trunc,
    "_sqrt": np.sqrt,
    "_log": np.log,
    "_power": np.power,
    "_square": np.square,
    "_hypot": np.hypot,
    "_matmul": np.matmul,
    "_matmul_cols": _matmul_cols,
    "_empty": np.empty,
    "_zeros": np.zeros,
    "_searchsorted": np.searchsorted,
    "_broadcast_to": np.broadcast_to,
    "_no_rng": _no_rng,
    "_uniforms": _uniforms,
}

_UNARY_FUNCTIONS = {
    "exp": "np.exp", "ln": "np.log", "sqrt": "np.sqrt", "cos": "np.cos", "sin": "np.sin",
    "tan": "np.tan", "acos": "np.arccos", "asin": "np.arcsin", "atan": "np.arctan",
    "cosh": "np.cosh", "sinh": "np.sinh", "tanh": "np.tanh",
}  # fmt: skip

_COMPARISONS = {"<": "_lt", "<=": "_le", ">": "_gt", ">=": "_ge", "^": "_land", "|": "_lor"}


class _Compiler:
    """Writes the generated functions of one model (see the module's
    docstring); `begin` starts a function, `compile` adds an expression's
    statements to it and returns its value."""

    def __init__(self, model: Model):
        self.model = model
        self.sizes = {t: len(info.members) for t, info in model.types.items()}
        self.codes = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }
        self.object_type: dict[str, str] = {}
        for t, info in model.types.items():
            if info.kind == "object" and (info.parent is None or info.parent not in model.types):
                for m in info.members:
                    self.object_type.setdefault(m, t)
        for t, info in model.types.items():
            for m in info.members:
                self.object_type.setdefault(m, t)
        # value of each enum member when used as a number (@1 -> 1), else its code
        self.numeric_of_code: dict[str, Array] = {}
        for t, info in model.types.items():
            if info.kind == "enum":
                ints = [_int_enum_value(m) for m in info.members]
                if all(v is not None for v in ints):
                    self.numeric_of_code[t] = np.array(ints, dtype=np.int64)
        self.ns: dict[str, Any] = dict(_BUILTINS)
        self.ns["_bidx"] = _bidx_factory()
        self.ns["_action_in"] = _action_in_factory()
        self.ns["_spread"] = _spread_factory()
        self._consts: dict[Any, _Node] = {}
        self._aux_count = 0
        self._tables: dict[str, str] = {}
        self._random: dict[int, tuple[A.Expr, bool]] = {}
        self._free: dict[int, tuple[A.Expr, frozenset[str]]] = {}
        self._static: dict[int, tuple[A.Expr, bool]] = {}
        self.code = _Code("_unused", "")
        self.context = 0  # which meaning pvariable names have (see `values`)
        self.sources: dict[str, str] = {}
        # what a pvariable reference means in the function being written:
        # "name" / "name'" -> (node, input expression or None)
        self.values: dict[str, tuple[_Node, str | None]] = {}

    # -- helpers -----------------------------------------------------

    def shape_of(self, p: PVariable) -> tuple[int, ...]:
        return tuple(self.sizes[t] for t in p.params)

    def scope_shape(self, scope: Scope) -> tuple[int, ...]:
        return tuple(self.sizes[t] for _, t in scope)

    @staticmethod
    def rank(scope: Scope) -> int:
        return 1 + len(scope)

    def code_of(self, name: str, type_hint: str | None) -> tuple[int, str]:
        """Code and type of an enum value or object name."""
        if type_hint is not None and type_hint in self.codes and name in self.codes[type_hint]:
            return self.codes[type_hint][name], type_hint
        if name.startswith("@"):
            for t, codes in self.codes.items():
                if name in codes:
                    return codes[name], t
        owner = self.object_type.get(name)
        if owner is None:
            raise SimulationError(f"unknown object or enum value '{name}'")
        return self.codes[owner][name], owner

    def aux(self, value: Any) -> str:
        """A name for `value` in the generated code's globals."""
        self._aux_count += 1
        name = f"k{self._aux_count}"
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        self.ns[name] = value
        return name

    def const(self, value: Any, rtype: str, dtype: Any = None) -> _Node:
        """A value known when the simulator is built (never written to)."""
        arr = np.array(value, dtype=dtype)
        key = None
        if arr.size <= 4096:
            key = (arr.dtype.str, arr.shape, arr.tobytes(), rtype)
            hit = self._consts.get(key)
            if hit is not None:
                return hit
        node = _Node(self.aux(arr), arr.shape, arr.dtype, rtype, False, value=arr)
        if key is not None:
            self._consts[key] = node
        return node

    def scalar(self, value: Any, scope: Scope, rtype: str, dtype: Any) -> _Node:
        return self.const(np.asarray(value, dtype=dtype).reshape((1,) * self.rank(scope)), rtype)

    def begin(self, name: str, params: str, large: bool = False, one: bool = False) -> _Code:
        """Start a function; `large`: for large batches (where memory
        traffic costs more than the number of numpy calls); `one`: for a
        batch of exactly one."""
        self.code = _Code(name, params, large, one)
        return self.code

    @property
    def large(self) -> bool:
        return self.code.large

    def build(self, code: _Code) -> Callable[..., Any]:
        return self.define(code.name, code.source())

    def define(self, name: str, source: str) -> Callable[..., Any]:
        """The function `name` of generated `source`, compiled in the
        generated code's namespace (its source kept in `sources`)."""
        self.sources[name] = source
        log.debug("generated %s:\n%s", name, source)
        exec(compile(source, f"<rddl {self.model.name}: {name}>", "exec"), self.ns)  # noqa: S102
        return self.ns.pop(name)  # type: ignore[no-any-return]

    def op(
        self,
        template: str,
        args: list[_Node],
        rtype: str,
        view: bool = False,
        bounds: Callable[..., tuple[Array, Array] | None] | None = None,
    ) -> _Node:
        """The value of `template` (a Python expression with {0}, {1}...
        for the arguments): folded when every argument is known, else one
        statement (or a value computed before with the same text).

        `view`: the value may share the first argument's memory (and has
        its bounds, rearranged the same way); `bounds`: computes the
        value's bounds from the arguments' (see `bounds_of`)."""
        text = template.format(*(a.code for a in args))
        if all(a.value is not None for a in args):
            try:
                with np.errstate(all="ignore"):
                    value = eval(_compiled(text), self.ns)  # noqa: S307
            except Exception:  # noqa: BLE001 - it raises at run time then, as it should
                pass
            else:
                return self.const(value, rtype)
        if len(args) == 2 and (args[0].value is None) != (args[1].value is None):
            cast = self._cast_constant(template, args)
            if cast is not None:
                args = cast
            if self.code.one:
                wide = self._widen_constant(template, args)
                if wide is not None:
                    args = wide
            elif self.code.large:
                spread = self._spread_constant(template, args)
                if spread is not None:
                    args = spread
            text = template.format(*(a.code for a in args))
        key = ("op", text)
        hit = self.code.lookup(key)
        if hit is not None:
            return hit
        shape, dtype = self._probe(template, args)
        name = self.code.temp()
        self.code.emit(f"{name} = {text}")
        owner = args[0].owner if view else name
        node = _Node(name, shape, dtype, rtype, any(a.batched for a in args), owner=owner)
        self.code.meta[name] = (shape, dtype, owner, node.batched)
        if view and len(args) == 1 and args[0].narrow is not None:
            # (the same rearrangement of the uint8 values, computed if used)
            node.narrow = self.op(template, [args[0].narrow], rtype, view=True)
        if view and len(args) == 1:
            b = self.bounds_of(args[0])
            if b is not None and args[0].dtype.kind != "b":  # (a bool's bounds go without saying)
                try:
                    with np.errstate(all="ignore"):
                        code = _compiled(template.format("_x"))
                        lo = eval(
                            code, self.ns, {"_x": np.broadcast_to(b[0], args[0].shape), "B": 1}
                        )  # noqa: S307
                        hi = eval(
                            code, self.ns, {"_x": np.broadcast_to(b[1], args[0].shape), "B": 1}
                        )  # noqa: S307
                    node.bounds = (np.asarray(lo), np.asarray(hi))
                except (ValueError, TypeError):
                    pass  # a view that is not a rearrangement (of the bytes, say): no bounds
        elif bounds is not None:
            given = [self.bounds_of(a) for a in args]
            if all(b is not None for b in given):
                with np.errstate(all="ignore"):
                    found = bounds(*given)
                # (finite, and small enough that int64 arithmetic cannot wrap)
                if found is not None and all((np.abs(x) < 2.0**52).all() for x in found):
                    node.bounds = (
                        np.asarray(found[0], dtype=np.float64),
                        np.asarray(found[1], dtype=np.float64),
                    )
        self.code.store(key, node)
        return node

    def _cast_constant(self, template: str, args: list[_Node]) -> list[_Node] | None:
        """For `_ufunc({0}, {1})` with one constant argument of another
        dtype than the ufunc's loop takes it in (`_add(k, x)`, k int64 and x
        float64): the arguments with the constant cast to that dtype once,
        when the simulator is built. The same values (the ufunc would make
        this very cast every call), without the per-call casting, which
        costs small steps about a microsecond per operation. None where
        nothing is to cast."""
        m = _UFUNC_CALL.match(template)
        if m is None:
            return None
        ufunc = self.ns.get(m.group(1))
        if not isinstance(ufunc, np.ufunc) or ufunc.nin != 2 or ufunc.nout != 1:
            return None
        i = 0 if args[0].value is not None else 1
        k = args[i]
        assert k.value is not None
        given = (args[0].dtype, args[1].dtype)
        try:
            loop = ufunc.resolve_dtypes((*given, None))
        except (TypeError, ValueError, AttributeError):
            return None
        want = np.dtype(loop[i])
        # (a safe cast only: exact, and it leaves the loop as it was)
        if k.dtype == want or not np.can_cast(k.dtype, want, "safe"):
            return None
        out = list(args)
        out[i] = self.const(k.value.astype(want), k.rtype)
        try:
            if tuple(ufunc.resolve_dtypes((out[0].dtype, out[1].dtype, None))) != tuple(loop):
                return None
        except (TypeError, ValueError):
            return None
        return out

    def _constant_operand(
        self, template: str, args: list[_Node]
    ) -> tuple[str, int, _Node, _Node] | None:
        """For an elementwise `_ufunc({0}, {1})` of two operands, one of them
        a constant: (the ufunc's name, the constant's position, the constant,
        the other operand); None for anything else."""
        m = _UFUNC_CALL.match(template)
        if m is None:
            return None
        ufunc = self.ns.get(m.group(1))
        if (
            not isinstance(ufunc, np.ufunc)
            or ufunc.nin != 2
            or ufunc.nout != 1
            or ufunc.signature is not None
        ):
            return None
        i = 0 if args[0].value is not None else 1
        k, x = args[i], args[1 - i]
        assert k.value is not None
        return m.group(1), i, k, x

    def _widen_constant(self, template: str, args: list[_Node]) -> list[_Node] | None:
        """In the code for a batch of one, for an elementwise
        `_ufunc({0}, {1})` of a constant and a value of more elements: the
        arguments with the constant broadcast to the value's shape when the
        simulator is built. The same values, and operands of one shape,
        which numpy adds in its fast loop: a broadcast costs a small
        operation about half a microsecond, two to three times its cost.
        (Not for batches of more than one: the constant would then be
        broadcast along the batch anyway.) None where nothing is to widen."""
        found = self._constant_operand(template, args)
        if found is None:
            return None
        _, i, k, x = found
        assert k.value is not None
        # (the value's shape here is its shape at run time: its batch axis,
        # last, is 1 here and 1 then)
        if (
            not x.batched
            or not x.shape
            or x.shape[-1] != 1
            or k.shape == x.shape
            or x.dtype.kind not in "biuf"
        ):
            return None
        if int(np.prod(x.shape)) > _WIDEN_LIMIT:
            return None
        if not _broadcasts_to(k.shape, x.shape):
            return None
        out = list(args)
        out[i] = self.const(np.broadcast_to(k.value, x.shape), k.rtype)
        return out

    def _spread_constant(self, template: str, args: list[_Node]) -> list[_Node] | None:
        """In the code for large batches, for an elementwise `_ufunc({0},
        {1})` of a constant and a batched value of as many groundings or
        more: the constant as numpy runs fastest against the value. That
        is a scalar where every value of the constant is the same (numpy's
        scalar loops), except for `_minimum` and `_maximum`, whose scalar
        loops are slow; otherwise the constant repeated along the batch
        into a contiguous array of the value's shape, made once per batch
        size (`_spread`): numpy broadcasts a column along a row of the
        batch two to three times slower than it reads a second array.
        The same values either way. None where nothing is to change."""
        found = self._constant_operand(template, args)
        if found is None:
            return None
        name, i, k, x = found
        assert k.value is not None
        if not x.batched or not x.shape or x.shape[-1] != 1 or x.dtype.kind not in "biuf":
            return None
        if k.dtype.kind not in "biuf" or k.value.ndim != len(x.shape) or not k.value.size:
            return None
        if not _broadcasts_to(k.shape, x.shape):
            return None
        cells = int(np.prod(x.shape))
        flat = k.value.reshape(-1)
        same = (
            bool((flat == flat[0]).all()) and not np.isnan(flat[0])
            if k.dtype.kind == "f"
            else bool((flat == flat[0]).all())
        )
        slow_scalar = name in ("_minimum", "_maximum")
        out = list(args)
        if same and not slow_scalar:
            if k.shape == (1,) * len(k.shape):
                return None
            out[i] = self.const(flat[:1].reshape((1,) * len(k.shape)), k.rtype)
            return out
        if cells > _SPREAD_CELLS:
            return None
        if k.shape == (1,) * len(k.shape) and not slow_scalar:
            return None
        b = self.bounds_of(k)
        out[i] = _Node(self.spread(k.code, x.shape), x.shape, k.dtype, k.rtype, False, bounds=b)
        return out

    def spread(self, const: str, shape: tuple[int, ...]) -> str:
        """The local name of the constant named `const` repeated along the
        batch to `shape` (batch axis last, 1 here), made at the top of the
        function being written (see `_spread_constant`)."""
        code = self.code
        key = (const, shape)
        name = code.spread.get(key)
        if name is None:
            name = code.spread[key] = f"w{len(code.spread) + 1}"
            code.inputs[name] = f"_spread({const}, {_last_shape_code(shape[:-1])})"
        return name

    @staticmethod
    def bounds_of(node: _Node) -> tuple[Array, Array] | None:
        """Elementwise bounds of a value, where known: sound for the
        operations that carry them (IEEE rounding is monotone, and the
        bounds are computed with the same operations as the values)."""
        if node.bounds is not None:
            return node.bounds
        if node.value is not None and node.value.dtype.kind in "bif":
            v = node.value.astype(np.float64)
            if np.isfinite(v).all():
                return v, v
            return None
        if node.dtype == np.bool_:
            return np.zeros((1,) * len(node.shape)), np.ones((1,) * len(node.shape))
        return None

    def _probe(self, template: str, args: list[_Node]) -> tuple[tuple[int, ...], np.dtype[Any]]:
        """Shape and dtype of `template`'s value, found by running it once
        on stand-ins (zeros, batch of one) for the values not known."""
        local: dict[str, Any] = {"B": 1}
        names = []
        for i, a in enumerate(args):
            if a.value is not None:
                names.append(a.code)
            else:
                local[f"_d{i}"] = np.zeros(a.shape, a.dtype)
                names.append(f"_d{i}")
        with np.errstate(all="ignore"):
            out = np.asarray(eval(_compiled(template.format(*names)), self.ns, local))  # noqa: S307
        return out.shape, out.dtype

    def emit_value(self, text: str, shape: tuple[int, ...], dtype: Any, rtype: str) -> _Node:
        """A statement whose value is never folded or reused (a draw)."""
        name = self.code.temp()
        self.code.emit(f"{name} = {text}")
        self.code.meta[name] = (shape, np.dtype(dtype), name, True)
        return _Node(name, shape, np.dtype(dtype), rtype, True, owner=name)

    def expand(self, node: _Node, keep: list[bool]) -> _Node:
        """`node` (over the kept scope variables) over the whole scope."""
        out = self.op("{0}" + _index_code(keep), [node], node.rtype, view=True)
        if out.value is None and out.unexpanded is None:
            out.unexpanded = node
        return out

    def cast(self, node: _Node, dtype: Any) -> _Node:
        dtype = np.dtype(dtype)
        if node.dtype == dtype:
            return node
        # (truncation is monotone: the bounds truncated)
        bound = _bounds_trunc if dtype.kind in "iu" else _bounds_same
        return self.op(f"{{0}}.astype({_DTYPE_CODE[dtype]})", [node], node.rtype, bounds=bound)

    def logic(self, ufunc: str, a: _Node, b: _Node, rtype: str = "bool") -> _Node:
        """`_land` or `_lor` of two values. For large batches, where one is a
        bool constant, on uint8 views: numpy's bool loops are slow (about
        20 times) when an operand is broadcast along a long inner loop."""
        if self.large and a.dtype == b.dtype == np.bool_ and (a.value is None) != (b.value is None):
            const, other = (a, b) if a.value is not None else (b, a)
            assert const.value is not None
            u8 = self.aux(const.value.view(np.uint8))
            bit = "_bitand" if ufunc == "_land" else "_bitor"
            return self.op(f"{bit}({{0}}.view(_u8), {u8}).view(_bool)", [other], rtype)
        return self.op(f"{ufunc}({{0}}, {{1}})", [a, b], rtype)

    def batch_last(self, text: str, rank: int) -> str:
        """Code for the batch-first array `text` viewed batch last; for large
        batches copied so (operations on mixed layouts are slow)."""
        if rank <= 1:
            return text
        if self.large:
            return f"_contiguous(({text}){_batch_last(rank)})"
        return f"({text}){_batch_last(rank)}"

    def total(
        self, node: _Node, axes: tuple[int, ...], rtype: str, keepdims: bool = False
    ) -> _Node:
        """`node` summed over `axes` (as np.sum: bools counted as int64).
        For large batches, bools are counted in bytes where fewer than 256
        are added (several times faster than adding them as int64)."""
        # (the ufunc's reduce called as `x.sum(axis=...)` calls it, without
        # numpy's Python-level wrapper: a step makes many small reductions)
        keep = ", None, True" if keepdims else ""
        count = int(np.prod([node.shape[a] for a in axes]))
        if self.large and node.dtype == np.bool_ and count < 256:
            return self.op(
                f"_sum({{0}}.view(_u8), {_axis_code(axes)}, _u8{keep}).astype(_i64)", [node], rtype
            )
        if keepdims:
            return self.op(f"_sum({{0}}, {_axis_code(axes)}, None{keep})", [node], rtype)
        return self.op(f"_sum({{0}}, {_axis_code(axes)})", [node], rtype)

    def lnot(self, a: _Node) -> _Node:
        return self.op("_lnot({0})", [a], "bool")

    def table(self, t: str) -> str:
        if t not in self._tables:
            self._tables[t] = self.aux(self.numeric_of_code[t])
        return self._tables[t]

    def fail(self, func: Callable[..., None], *args: str) -> None:
        """A statement that calls `func` (which raises) with values by name."""
        self.code.emit(f"{self.aux(func)}({', '.join(args)})")

    # -- what an expression depends on --------------------------------

    # (the caches below are keyed by id and keep the expression alive, so
    # that an id is never reused by another expression)

    def is_random(self, e: A.Expr) -> bool:
        hit = self._random.get(id(e))
        if hit is None:
            hit = (e, _is_draw(e) or any(self.is_random(c) for c in A.children(e)))
            self._random[id(e)] = hit
        return hit[1]

    def free_vars(self, e: A.Expr) -> frozenset[str]:
        hit = self._free.get(id(e))
        if hit is None:
            if isinstance(e, A.Var):
                found = frozenset((e.name,))
            else:
                found = frozenset().union(*(self.free_vars(c) for c in A.children(e)))
                if isinstance(e, (A.Aggregation, A.DiscreteOver)):
                    found = found - {p.name for p in e.params}
            hit = self._free[id(e)] = (e, found)
        return hit[1]

    def is_static(self, e: A.Expr) -> bool:
        """Reads only non-fluents and constants (so it folds), and draws nothing."""
        hit = self._static.get(id(e))
        if hit is None:
            static = not self.is_random(e)
            if static and isinstance(e, A.PVar):
                p = self.model.pvariables.get(e.name)
                static = p is None or e.default or p.kind == NON_FLUENT
            static = static and all(self.is_static(c) for c in A.children(e))
            hit = self._static[id(e)] = (e, static)
        return hit[1]

    # -- expressions -------------------------------------------------

    def compile(self, e: A.Expr, scope: Scope, hint: str | None = None) -> _Node:
        """The value of `e` in `scope` (statements added to the function)."""
        method = getattr(self, "_" + type(e).__name__)
        if self.is_random(e):
            return method(e, scope, hint)  # type: ignore[no-any-return]
        # a pure expression: in the scope of the variables it reads, once
        names = [v for v, _ in scope]
        used = sorted(
            {
                max(i for i, v in enumerate(names) if v == name)
                for name in self.free_vars(e)
                if name in names
            }
        )
        if len(used) < len(scope):
            node = self.compile(e, tuple(scope[i] for i in used), hint)
            kept = set(used)
            return self.expand(node, [i in kept for i in range(len(scope))])
        key = ("expr", self.context, e, scope, hint)
        hit = self.code.lookup(key)
        if hit is None:
            hit = method(e, scope, hint)
            self.code.store(key, hit)
        return hit

    def numeric(self, e: A.Expr, scope: Scope) -> _Node:
        """Compile for use as a number (enum @1..@n -> their integers)."""
        return self.to_numeric(self.compile(e, scope))

    def to_numeric(self, node: _Node) -> _Node:
        if node.rtype in self.numeric_of_code:
            return self.op(self.table(node.rtype) + "[{0}]", [node], "int")
        return node

    def _Const(self, e: A.Const, scope: Scope, hint: str | None) -> _Node:
        v = e.value
        if isinstance(v, bool):
            return self.scalar(v, scope, "bool", np.bool_)
        if isinstance(v, int):
            return self.scalar(v, scope, "int", np.int64)
        return self.scalar(v, scope, "real", np.float64)

    def _Var(self, e: A.Var, scope: Scope, hint: str | None) -> _Node:
        # A variable used as a value: the code of the object it ranges over.
        pos = [i for i, (v, _) in enumerate(scope) if v == e.name]
        i = pos[-1]
        t = scope[i][1]
        shape = [1] * self.rank(scope)
        shape[i] = self.sizes[t]
        return self.const(np.arange(self.sizes[t], dtype=np.int64).reshape(shape), t)

    def _EnumLit(self, e: A.EnumLit, scope: Scope, hint: str | None) -> _Node:
        code, t = self.code_of(e.name, hint)
        return self.scalar(code, scope, t, np.int64)

    def _ObjectLit(self, e: A.ObjectLit, scope: Scope, hint: str | None) -> _Node:
        code, t = self.code_of(e.name, hint)
        return self.scalar(code, scope, t, np.int64)

    def _literal_code(self, a: A.Expr, t: str) -> int | None:
        """The code of an argument that names an object or enum value."""
        if isinstance(a, (A.EnumLit, A.ObjectLit)) or (
            isinstance(a, A.PVar) and a.name not in self.model.pvariables
        ):
            name = a.name
            if isinstance(a, A.PVar) and t in self.codes and "@" + name in self.codes[t]:
                name = "@" + name
            return self.code_of(name, t)[0]
        return None

    def ref(self, p: PVariable, primed: bool) -> _Node:
        key = p.name + ("'" if primed else "")
        hit = self.values.get(key)
        if hit is None:
            # read before it is computed (or where it has no value): rddlsim
            # has no value to give either
            node = self.emit_value(
                f"{self.aux(_missing)}({key!r})",
                (*self.shape_of(p), 1),
                _DTYPES.get(p.range, np.int64),
                p.range,
            )
            self.values[key] = (node, None)
            return node
        node, source = hit
        if source is not None:
            self.code.inputs.setdefault(node.code, source)
        return node

    def _PVar(self, e: A.PVar, scope: Scope, hint: str | None) -> _Node:
        p = self.model.pvariables.get(e.name)
        if p is None:  # a bare object name (or an enum value without '@')
            name = e.name
            if hint in self.codes and "@" + name in self.codes[hint]:
                name = "@" + name
            return self._ObjectLit(A.ObjectLit(name, loc=e.loc), scope, hint)
        if e.default:
            default = self.model.default_of(p)
            if p.range in self.codes:
                return self.scalar(self.codes[p.range][default], scope, p.range, np.int64)  # type: ignore[index]
            return self.scalar(default, scope, p.range, None)
        base = self.ref(p, e.primed)
        names = [v for v, _ in scope]
        # Fast path: each argument a distinct variable or a literal -> a view.
        index: list[str] = []
        positions: list[int] = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, A.Var):
                positions.append(max(i for i, v in enumerate(names) if v == a.name))
                index.append(":")
                continue
            code = self._literal_code(a, t)
            if code is None:
                break
            index.append(str(code))
        if len(index) == len(e.args) and len(set(positions)) == len(positions):
            node = base
            if any(i != ":" for i in index):
                node = self.op("{0}[" + ", ".join([*index, ":"]) + "]", [node], p.range, view=True)
            order = sorted(range(len(positions)), key=lambda i: positions[i])
            if order != list(range(len(positions))):
                axes = (*order, len(order))
                node = self.op(f"{{0}}.transpose({axes})", [node], p.range, view=True)
            present = set(positions)
            if len(present) < len(scope):
                node = self.expand(node, [i in present for i in range(len(scope))])
            return node
        # General path: advanced indexing with broadcast index arrays.
        rank = self.rank(scope)
        indices: list[_Node] = []
        for a, t in zip(e.args, p.params, strict=True):
            if isinstance(a, A.Var):
                indices.append(self._Var(a, scope, None))
                continue
            code = self._literal_code(a, t)
            if code is not None:
                indices.append(self.scalar(code, scope, t, np.int64))
            else:
                indices.append(self.compile(a, scope, t))
        if base.batched:
            b = f"_bidx(B, {rank})"
        else:
            b = self.aux(np.zeros((1,) * rank, dtype=np.int64))
        parts = ", ".join([f"{{{i + 1}}}" for i in range(len(indices))] + [b])
        return self.op("{0}[(" + parts + ")]", [base, *indices], p.range)

    def _Unary(self, e: A.Unary, scope: Scope, hint: str | None) -> _Node:
        x = self.numeric(e.operand, scope)
        if e.op == "~":
            return self.op("_lnot({0})", [x], "bool")
        if e.op == "-":
            if x.rtype == "bool":
                return self.op("_neg({0}.astype(_i64))", [x], "int", bounds=_bounds_neg)
            return self.op("_neg({0})", [x], x.rtype, bounds=_bounds_neg)
        return x

    def _Binary(self, e: A.Binary, scope: Scope, hint: str | None) -> _Node:
        if e.op in ("==", "~="):
            left = self.compile(e.left, scope)
            lt = left.rtype
            right = self.compile(e.right, scope, lt)
            rt = right.rtype
            if (
                lt != rt
                and (lt in self.codes) != (rt in self.codes)
                or (lt in self.codes and rt in self.codes and lt != rt)
            ):
                # mixed forms: compare as numbers where an enum is numeric
                left = self.to_numeric(left)
                right = (
                    self.to_numeric(right)
                    if self.is_random(e.right)
                    else self.numeric(e.right, scope)
                )
            pair = self.narrowed(left, right)
            return self.op("_eq({0}, {1})" if e.op == "==" else "_ne({0}, {1})", pair, "bool")
        left = self.numeric(e.left, scope)
        right = self.numeric(e.right, scope)
        return self.binary(e, left, right)

    def narrowed(self, left: _Node, right: _Node) -> list[_Node]:
        """The operands of a comparison: a count kept as uint8 (`narrow`)
        and an integer constant within [0, 255] compared as uint8 (the
        same outcome, on an eighth of the memory), else as they are."""
        for x, k in ((left, right), (right, left)):
            if x.narrow is None or k.value is None or k.value.dtype.kind not in "iu":
                continue
            if k.value.size and 0 <= k.value.min() and k.value.max() <= 255:
                k8 = self.const(k.value.astype(np.uint8), k.rtype)
                return [x.narrow, k8] if x is left else [k8, x.narrow]
        return [left, right]

    def binary(self, e: A.Binary, left: _Node, right: _Node) -> _Node:
        """`left op right` for an arithmetic or logical operator."""
        op = e.op
        lt, rt = left.rtype, right.rtype
        args = [left, right]
        if op in ("^", "|"):
            return self.logic(_COMPARISONS[op], left, right)
        if op in _COMPARISONS:
            return self.op(f"{_COMPARISONS[op]}({{0}}, {{1}})", self.narrowed(left, right), "bool")
        if op == "=>":
            return self.logic("_lor", self.lnot(left), right)
        if op == "<=>":
            return self.op("_eq({0}.astype(_bool), {1}.astype(_bool))", args, "bool")
        out = "real" if "real" in (lt, rt) or op == "/" else "int"
        if op in ("+", "-", "*", "/"):
            args = self.narrowed_arithmetic(args)
        if op == "+":
            if lt == rt == "bool":
                return self.op("{0}.astype(_i64) + {1}", args, "int", bounds=_bounds_add)
            return self.narrow_result(
                self.op("_add({0}, {1})", args, out, bounds=_bounds_add), "_add", args
            )
        if op == "-":
            if lt == "bool":
                return self.op("{0}.astype(_i64) - {1}", args, out, bounds=_bounds_sub)
            return self.narrow_result(
                self.op("_sub({0}, {1})", args, out, bounds=_bounds_sub), "_sub", args
            )
        if op == "*":
            if lt == rt == "bool":
                return self.op("_land({0}, {1}).astype(_i64)", args, "int")
            return self.narrow_result(
                self.op("_mul({0}, {1})", args, out, bounds=_bounds_mul), "_mul", args
            )
        if op == "/":
            return self.op("_div({0}, {1})", args, "real", bounds=_bounds_div)
        raise SimulationError(f"{e.loc}: unknown operator '{op}'")

    @staticmethod
    def narrowed_arithmetic(args: list[_Node]) -> list[_Node]:
        """The operands of arithmetic with a float64 value: an integer kept
        as uint8 too (`narrow`) taken as uint8. numpy converts it to float64
        either way, exactly (the same values), and reads an eighth of the
        memory (and skips the int64 array, if nothing else reads it)."""
        for i in (0, 1):
            x, other = args[i], args[1 - i]
            narrow = x.narrow
            if other.dtype == np.float64 and narrow is not None:
                if narrow.bounds is None:
                    narrow.bounds = x.bounds  # (the same values)
                return [narrow, other] if i == 0 else [other, narrow]
        return args

    def narrow_result(self, node: _Node, ufunc: str, args: list[_Node]) -> _Node:
        """`node`, the int64 value of `ufunc` (`_add`, `_sub`, `_mul`) of a
        count kept as uint8 (`narrow`) and an integer constant, with its
        uint8 form too where its bounds prove it within [0, 255] (so that
        uint8 arithmetic makes the same values). (Both are written; the
        one not read is dropped from the function.)"""
        if (
            node.dtype != np.int64
            or node.narrow is not None
            or node.value is not None
            or not self.large
        ):
            return node
        b = node.bounds
        if b is None or b[0].min(initial=0) < 0 or b[1].max(initial=0) > 255:
            return node
        narrow: list[_Node] = []
        for x in args:
            if x.narrow is not None:
                narrow.append(x.narrow)
            elif x.value is not None and x.value.dtype.kind in "iub" and x.value.size:
                if x.value.min() < 0 or x.value.max() > 255:
                    return node
                narrow.append(self.const(x.value.astype(np.uint8), x.rtype))
            else:
                return node
        if all(x.value is not None for x in narrow):
            return node
        small = self.op(f"{ufunc}({{0}}, {{1}})", narrow, node.rtype)
        if small.dtype == np.uint8:
            small.bounds = b  # (the same values)
            node.narrow = small
        return node

    def _If(self, e: A.If, scope: Scope, hint: str | None) -> _Node:
        cond = self.numeric(e.cond, scope)
        pick: bool | None = None
        if cond.value is not None and cond.value.size:
            if cond.value.all():
                pick = True
            elif not cond.value.any():
                pick = False
        if pick is None:
            # each element takes one branch: the branches may draw the same
            # uniforms (one draw per grounding, as rddlsim evaluates only
            # the branch taken)
            with self.alternatives() as alternative:
                with alternative():
                    then = self.compile(e.then, scope, hint)
                with alternative():
                    else_ = self.compile(
                        e.else_, scope, hint if then.rtype not in _DTYPES else then.rtype
                    )
            t = _join(then.rtype, else_.rtype)
            if cond.dtype == then.dtype == else_.dtype == np.bool_:
                # a constant true or false branch: one logical operation
                # (np.where broadcasting a constant is much slower)
                for node, other in ((then, else_), (else_, then)):
                    if node.value is None or not node.value.size:
                        continue
                    if node.value.all():
                        if node is then:
                            return self.logic("_lor", cond, other, t)
                        return self.logic("_lor", self.lnot(cond), other, t)
                    if not node.value.any():
                        if node is then:
                            return self.logic("_land", self.lnot(cond), other, t)
                        return self.logic("_land", cond, other, t)
                if self.large:
                    # np.where is slow on large bool arrays: logical operations
                    yes = self.logic("_land", cond, then, t)
                    no = self.logic("_land", self.lnot(cond), else_, t)
                    return self.logic("_lor", yes, no, t)
            return self.op("_where({0}, {1}, {2})", [cond, then, else_], t, bounds=_bounds_either)
        # the condition is the same everywhere: the other branch only for
        # its type (it draws nothing: only the branch taken draws)
        with self.branch(keep=pick):
            then = self.compile(e.then, scope, hint)
        with self.branch(keep=not pick):
            else_ = self.compile(e.else_, scope, hint if then.rtype not in _DTYPES else then.rtype)
        t = _join(then.rtype, else_.rtype)
        node = self.cast(then if pick else else_, np.result_type(then.dtype, else_.dtype))
        return node if node.rtype == t else dataclasses.replace(node, rtype=t)

    @contextlib.contextmanager
    def branch(self, keep: bool) -> Iterator[None]:
        """Statements that are kept, or compiled only to be thrown away."""
        if keep:
            yield
            return
        code = self.code
        start, count, slots = len(code.lines), len(code.draws), len(code.slots)
        code.memo.append({})
        code.pools.append(_Pool())
        try:
            yield
        finally:
            code.pools.pop()
            code.memo.pop()
            del code.lines[start:]
            del code.draws[count:]
            del code.slots[slots:]

    @contextlib.contextmanager
    def alternatives(self) -> Iterator[Callable[[], contextlib.AbstractContextManager[None]]]:
        """Branches of which each element of the batch takes one (an `if`'s,
        a `switch`'s cases): `with alternative():` around each. A branch
        may draw again the uniforms that the branches before it drew, and
        those that branches exclusive with the enclosing one drew (an
        element's value reads each uniform at most once either way); the
        enclosing branch may not draw any of them again."""
        code = self.code
        outer = code.pools[-1]
        drawn: list[_Slot] = []  # by any of the branches, in order

        @contextlib.contextmanager
        def alternative() -> Iterator[None]:
            free = drawn + [s for s in outer.free if not any(s is d for d in drawn)]
            pool = _Pool(free=free)
            code.pools.append(pool)
            try:
                yield
            finally:
                code.pools.pop()
                drawn.extend(s for s in pool.used if not any(s is d for d in drawn))

        yield alternative
        outer.free = [s for s in outer.free if not any(s is d for d in drawn)]
        outer.used.extend(drawn)

    def _Switch(self, e: A.Switch, scope: Scope, hint: str | None) -> _Node:
        subject = self.compile(e.subject, scope)
        t: str | None = None
        labels: list[_Node] = []
        for case in e.cases:
            if case.label is not None:
                labels.append(self.compile(case.label, scope, subject.rtype))
        # values in the order rddlsim's evaluation draws them: the labelled
        # cases, then the default
        values: list[_Node] = []
        default: _Node | None = None
        types: list[str] = []
        with self.alternatives() as alternative:
            for case in e.cases:
                if case.label is not None:
                    with alternative():
                        values.append(self.compile(case.value, scope, hint))
            for case in e.cases:
                if case.label is None:
                    with alternative():
                        default = self.compile(case.value, scope, hint)
        it = iter(values)
        for case in e.cases:
            types.append((default if case.label is None else next(it)).rtype)  # type: ignore[union-attr]
        for vt in types:
            t = vt if t is None else _join(t, vt)
        fallback = default if default is not None else values[-1]
        if not labels:
            return fallback
        conds = [self.op("_eq({0}, {1})", [subject, lab], "bool") for lab in labels]
        n = len(conds)
        template = (
            "_select(["
            + ", ".join(f"{{{i}}}" for i in range(n))
            + "], ["
            + ", ".join(f"{{{n + i}}}" for i in range(n))
            + f"], {{{2 * n}}})"
        )
        return self.op(template, [*conds, *values, fallback], t or "real")

    # -- aggregations ------------------------------------------------

    def _Aggregation(self, e: A.Aggregation, scope: Scope, hint: str | None) -> _Node:
        inner = scope + tuple((p.name, p.type) for p in e.params)
        n, k = len(scope), len(e.params)
        sizes = tuple(self.sizes[p.type] for p in e.params)
        op = e.op
        if op == "sum" and not self.is_random(e.body):
            split = self._distribute(e)
            if split is not None:
                return self.compile(split, scope, hint)
        body: _Node | None = None
        chain = e.body.op if isinstance(e.body, A.Binary) else None
        if (
            op in ("sum", "exists")
            and chain in ("^", "*")
            and not (op == "exists" and chain == "*")
        ):
            assert isinstance(e.body, A.Binary) and chain is not None
            leaves = _leaves(e.body, chain)
            nodes = [self.numeric(leaf, inner) for leaf in leaves]
            if 0 not in sizes:
                out = self._contract(op, chain, nodes, n, k, sizes)
                if out is None:
                    out = self._eliminate(op, chain, nodes, n, k, sizes)
                if out is not None:
                    return out
            body = self._rebuild(e.body, chain, iter(nodes))
        if body is None:
            body = self.numeric(e.body, inner)
        bt = body.rtype
        # the aggregation's variables: the axes just before the batch axis
        axes = _axis_code(tuple(range(n, n + k)))
        if 0 in sizes or op in ("prod", "avg", "argmax", "argmin"):
            # as the definition says: over every grounding of the variables
            full = f"_broadcast_to({{0}}, {{0}}.shape[:{n}] + {sizes} + {{0}}.shape[-1:])"
            if op == "sum":
                return self.op(
                    f"np.sum({full}, axis={axes})", [body], "int" if bt == "bool" else bt
                )
            if op == "prod":
                return self.op(
                    f"np.prod({full}, axis={axes})", [body], "int" if bt == "bool" else bt
                )
            if op == "avg":
                return self.op(f"np.mean({full}, axis={axes})", [body], "real")
            if op in ("min", "max"):
                return self.op(f"np.{op}({full}, axis={axes})", [body], bt)
            if op == "forall":
                return self.op(f"np.all({full}, axis={axes})", [body], "bool")
            if op == "exists":
                return self.op(f"np.any({full}, axis={axes})", [body], "bool")
            if op in ("argmax", "argmin"):
                return self.op(f"np.{op}({full}, axis={n})", [body], e.params[0].type)
        size = int(np.prod(body.shape))
        if (
            k == 1
            and op in ("sum", "min", "max", "forall", "exists")
            and body.shape[n] > 1
            and (body.shape[n] <= 2 or (body.shape[n] <= 8 and size >= 2048))
        ):
            # a short axis: its slices combined, not a reduction (numpy
            # reduces a short axis in many short loops, slowly)
            parts = [
                "{0}[" + ", ".join([":"] * n + [str(j), ":"]) + "]" for j in range(body.shape[n])
            ]
            if op == "sum":
                if body.dtype == np.bool_:
                    parts[0] += ".astype(_i64)"
                return self.op(" + ".join(parts), [body], "int" if bt == "bool" else bt)
            ufunc = {"min": "_minimum", "max": "_maximum", "forall": "_land", "exists": "_lor"}[op]
            text = parts[0]
            for part in parts[1:]:
                text = f"{ufunc}({text}, {part})"
            return self.op(text, [body], bt if op in ("min", "max") else "bool")
        if op == "sum":
            out = self.total(body, tuple(range(n, n + k)), "int" if bt == "bool" else bt)
            # the body does not depend on some of the variables: each value counts that often
            times = 1
            for j in range(k):
                if body.shape[n + j] == 1:
                    times *= sizes[j]
            return out if times == 1 else self.op(f"{{0}} * {times}", [out], out.rtype)
        if op in ("min", "max"):
            return self.op(f"_{op}_reduce({{0}}, {axes})", [body], bt)
        if op == "forall":
            return self.op(f"_all({{0}}, {axes}, _bool)", [body], "bool")
        if op == "exists":
            return self.op(f"_any({{0}}, {axes}, _bool)", [body], "bool")
        raise SimulationError(f"{e.loc}: aggregation '{op}_' is not supported by the simulator")

    def _eliminate(
        self, op: str, chain: str, nodes: list[_Node], n: int, k: int, sizes: tuple[int, ...]
    ) -> _Node | None:
        """`sum` or `exists` over k variables of a product (or conjunction)
        where a variable only one factor depends on is summed (or
        quantified) in that factor first: `sum_{?c, ?i} a(?c, ?i) * b(?p, ?i)`
        is `sum_{?i} (sum_{?c} a(?c, ?i)) * b(?p, ?i)`, without the tensor
        over every (?p, ?c, ?i). None where no variable is like that."""
        if chain == "^" and any(x.dtype != np.bool_ for x in nodes):
            return None
        if chain == "*" and any(x.dtype.kind not in "bif" or x.rtype not in _DTYPES for x in nodes):
            return None
        nodes = list(nodes)
        changed = False
        times = 1
        for j in range(k):
            a = n + j
            deps = [i for i, x in enumerate(nodes) if x.shape[a] > 1]
            if len(deps) == 1:
                i = deps[0]
                if op == "exists":
                    nodes[i] = self.op(
                        f"_any({{0}}, {a}, _bool, None, True)", [nodes[i]], nodes[i].rtype
                    )
                else:
                    nodes[i] = self.total(nodes[i], (a,), nodes[i].rtype, keepdims=True)
                changed = True
            elif not deps:
                times *= sizes[j]
        if not changed:
            return None
        axes = _axis_code(tuple(range(n, n + k)))
        real = chain == "*" and any(x.rtype == "real" for x in nodes)
        f = nodes[0]
        for x in nodes[1:]:
            if op == "exists":
                f = self.logic("_land", f, x)
            else:  # (counts times bools: a product)
                f = self.op("_mul({0}, {1})", [f, x], "real" if real else "int", bounds=_bounds_mul)
        if op == "exists":
            return self.op(f"_any({{0}}, {axes}, _bool)", [f], "bool")
        out = self.total(f, tuple(range(n, n + k)), "real" if real else "int")
        return out if times == 1 else self.op(f"{{0}} * {times}", [out], out.rtype)

    def _distribute(self, e: A.Aggregation) -> A.Expr | None:
        """A sum over a sum or difference as the sum or difference of two
        sums (`sum (a - b)` = `sum a - sum b`; in a product, `sum K * (a - b)`
        = `sum K * a - sum K * b`), where that lets a part become a matrix
        product or a count; None where it does not help."""
        body = e.body

        def agg(b: A.Expr) -> A.Aggregation:
            return A.Aggregation(op="sum", params=e.params, body=b, loc=e.loc)

        if isinstance(body, A.Binary) and body.op in ("+", "-"):
            return A.Binary(op=body.op, left=agg(body.left), right=agg(body.right), loc=body.loc)
        if not (isinstance(body, A.Binary) and body.op == "*"):
            return None
        leaves = _leaves(body, "*")
        split = [
            x
            for x in leaves
            if isinstance(x, A.Binary) and x.op in ("+", "-") and not self.is_static(x)
        ]
        if len(split) != 1 or not any(self.is_static(x) for x in leaves):
            return None
        target = split[0]
        assert isinstance(target, A.Binary)

        def replace(x: A.Expr, new: A.Expr) -> A.Expr:
            if x is target:
                return new
            if isinstance(x, A.Binary) and x.op == "*":
                return A.Binary(
                    op="*", left=replace(x.left, new), right=replace(x.right, new), loc=x.loc
                )
            return x

        return A.Binary(
            op=target.op,
            left=agg(replace(body, target.left)),
            right=agg(replace(body, target.right)),
            loc=target.loc,
        )

    def _rebuild(self, e: A.Expr, chain: str, nodes: Iterator[_Node]) -> _Node:
        """The value of a chain of `chain` operators from its leaves' values."""
        if isinstance(e, A.Binary) and e.op == chain:
            left = self._rebuild(e.left, chain, nodes)
            right = self._rebuild(e.right, chain, nodes)
            return self.binary(e, left, right)
        return next(nodes)

    def _contract(
        self, op: str, chain: str, nodes: list[_Node], n: int, k: int, sizes: tuple[int, ...]
    ) -> _Node | None:
        """`sum` or `exists` over k variables (the axes n..n+k-1) of the
        product (or conjunction) of `nodes`, where some factors are known
        when the simulator is built (a relation: CONNECTED, NEIGHBOR...):
        a product of the fluent factors with that constant matrix, or, where
        the relation pairs each value with few others, a few row gathers.
        None where the pattern does not apply."""
        known = [x for x in nodes if x.value is not None]
        fluent = [x for x in nodes if x.value is None]
        if not known or not fluent:
            return None
        if chain == "^":
            if any(x.dtype != np.bool_ for x in nodes):
                return None
        elif any(x.dtype.kind not in "bif" or x.rtype not in _DTYPES for x in nodes):
            return None
        # fluent factors that do not depend on the variables summed over
        # multiply the sum instead of every term
        outer = [x for x in fluent if all(x.shape[n + j] == 1 for j in range(k))]
        if outer and len(outer) < len(fluent):
            inner_nodes = [x for x in nodes if not any(x is o for o in outer)]
            out = self._contract(op, chain, inner_nodes, n, k, sizes)
            if out is None:
                return None
            for x in outer:
                x = self.op("{0}[..." + ", 0" * k + ", :]", [x], x.rtype, view=True)
                if op == "exists":
                    out = self.logic("_land", out, x)
                else:
                    rtype = "real" if "real" in (out.rtype, x.rtype) else "int"
                    out = self.op("_mul({0}, {1})", [out, x], rtype, bounds=_bounds_mul)
            return out
        with np.errstate(all="ignore"):
            first_value = known[0].value
            assert first_value is not None
            kv: Array = first_value
            for x in known[1:]:
                assert x.value is not None
                kv = np.logical_and(kv, x.value) if chain == "^" else kv * x.value
        f = fluent[0]
        for x in fluent[1:]:
            if chain == "^":
                f = self.logic("_land", f, x)
            else:
                f = self.op("_mul({0}, {1})", [f, x], "real", bounds=_bounds_mul)
        real = any(x.rtype == "real" for x in nodes) and chain == "*"
        fs, ks = f.shape[:-1], kv.shape[:-1]
        # bounds of a sum of integers (exact, whatever the order of the additions)
        sum_bounds: Bounds | None = None
        fb = self.bounds_of(f)
        if op == "sum" and fb is not None and f.dtype.kind in "bi" and np.all(np.mod(kv, 1) == 0):
            with np.errstate(all="ignore"):
                ends = [kv * fb[0], kv * fb[1]]
                ends = [np.broadcast_to(x, x.shape[:n] + sizes + x.shape[n + k :]) for x in ends]
                lo = np.minimum(ends[0], ends[1]).sum(axis=tuple(range(n, n + k)))
                hi = np.maximum(ends[0], ends[1]).sum(axis=tuple(range(n, n + k)))
            sum_bounds = (lo.astype(np.float64), hi.astype(np.float64))
        contracted, k_only, f_only = [], [], []
        times = 1
        for j in range(k):
            a = n + j
            if fs[a] > 1 and ks[a] > 1:
                contracted.append(a)
            elif ks[a] > 1:
                k_only.append(a)
            elif fs[a] > 1:
                f_only.append(a)
            else:
                times *= sizes[j]
        # variables only one side depends on: reduce them on that side first
        if k_only:
            ax = tuple(k_only)
            kv = np.asarray(
                kv.any(axis=ax, keepdims=True) if op == "exists" else kv.sum(axis=ax, keepdims=True)
            )
        if f_only:
            if op == "exists":
                f = self.op(
                    f"_any({{0}}, {_axis_code(tuple(f_only))}, _bool, None, True)", [f], f.rtype
                )
            else:
                f = self.total(f, tuple(f_only), f.rtype, keepdims=True)
        if not contracted:
            # nothing left to sum over both: a product, its bound variables dropped
            knode = self.const(kv, "real")
            if op == "exists":
                out = self.logic("_land", f, knode)
            else:
                if not real and f.dtype == np.bool_ and kv.dtype == np.bool_:
                    knode = self.const(kv.astype(np.int64), "int")
                out = self.op("_mul({0}, {1})", [f, knode], "real" if real else "int")
                if not real and out.dtype != np.int64:
                    out = self.op("{0}.astype(_i64)", [out], "int")
                if times != 1:
                    out = self.op(f"{{0}} * {times}", [out], out.rtype)
            out = self.op("{0}[..." + ", 0" * k + ", :]", [out], out.rtype, view=True)
            return _bounded(out, sum_bounds)
        shared = [i for i in range(n) if fs[i] > 1 and ks[i] > 1]
        f_out = [i for i in range(n) if fs[i] > 1 and ks[i] == 1]
        k_out = [i for i in range(n) if ks[i] > 1 and fs[i] == 1]
        size = [max(fs[i], ks[i]) for i in range(n + k)]
        S, C, KO = (
            int(np.prod([size[i] for i in ax], dtype=np.int64))
            for ax in (shared, contracted, k_out)
        )
        # the constant side as (S, KO, C) matrices, the fluent side as
        # (S, C, columns): f's axes in the order shared, contracted, f_out, batch
        first = shared + k_out + contracted
        rest = [i for i in range(n + k) if i not in first]
        kmat = kv[..., 0].transpose(first + rest).reshape(S, KO, C)
        f_axes = shared + contracted + f_out
        fperm = f_axes + [i for i in range(n + k) if i not in f_axes] + [n + k]
        # (axes of size 1 may stay anywhere: the reshape below drops them)
        in_place = [i for i in range(n + k) if fs[i] > 1] == f_axes
        fx = "{0}" if in_place else f"{{0}}.transpose({tuple(fperm)})"
        if in_place and f.unexpanded is not None:
            f = f.unexpanded  # (the same memory order of the same axes)
        sparse = self._sparse(kmat[0], unit=op == "sum") if S == 1 and self.large else None
        if sparse is not None:
            # a relation with few pairs per value (neighbours, successors, a
            # 0/1 relation): a few row gathers, not a product over every pair;
            # the gathered rows index a zero row added below the others where
            # a value has fewer pairs
            cols, padded = sparse
            flat = self.op(f"{fx}.reshape({C}, -1)", [f], f.rtype, view=True)
            if padded:
                flat = self.op("_pad_zero_row({0})", [flat], f.rtype)
            rows = [
                self.const(c, "int").code for c in cols
            ]  # (the same text for the same relation)
            if f.dtype == np.bool_:
                # counts of bools, added as bytes (at most _SPARSE_MAX of
                # them); an exists is a count above 0, so that an exists and
                # a sum over the same relation share the count
                flat = self.op("{0}.view(_u8)", [flat], "int", view=True)
                count = self.op(f"_gather_sum({{0}}, {_tuple_code(rows)})", [flat], "int")
                if op == "exists":
                    out = self.op("{0} > 0", [count], "bool")
                else:
                    out = self.op("{0}.astype(_i64)", [count], "int")
                    if out.value is None and out.narrow is None:
                        out.narrow = count
            elif op == "sum":
                out = self.op(f"_gather_sum({{0}}, {_tuple_code(rows)})", [flat], f.rtype)
            else:
                out = self.op(f"{{0}}[{rows[0]}]", [flat], f.rtype)
                for r in rows[1:]:
                    out = self.op(f"_lor({{0}}, {{1}}[{r}])", [out, flat], f.rtype)
                if op == "sum" and not real and out.dtype != np.int64:
                    out = self.op("{0}.astype(_i64)", [out], "int")
        else:
            # counts of bools are exact in float32 (below 2**24); a sum stays
            # float64 (exact for integers below 2**53, which int sums are
            # here): no cast back, the values are those of the int sum
            # (float64 for both sum and exists, so that an exists and a sum
            # over the same relation share one product)
            dt, dcode = np.float64, "_f64"
            matmul = "_matmul_cols"
            FO = int(np.prod([size[i] for i in f_out], dtype=np.int64))
            if not self.large and S * KO * C * FO * _LARGE_BATCH <= _BLAS_BLOCK:
                matmul = "_matmul"
            shape = f"{C}, -1" if S == 1 else f"{S}, {C}, -1"
            if (
                matmul == "_matmul"
                and op == "exists"
                and f.dtype == np.bool_
                and kv.dtype == np.bool_
            ):
                # small: numpy's boolean product is the exists itself (no casts)
                mat = self.const(
                    np.ascontiguousarray(kmat[0] if S == 1 else kmat, dtype=bool), "bool"
                ).code
                out = self.op(f"_matmul({mat}, {fx}.reshape({shape}))", [f], "bool")
            else:
                mat = self.const(
                    np.ascontiguousarray(kmat[0] if S == 1 else kmat, dtype=dt), "real"
                ).code
                text = f"{matmul}({mat}, {fx}.reshape({shape}).astype({dcode}, copy=False))"
                out = self.op(text, [f], "real" if real else "int")
                if op == "exists":
                    out = self.op("{0} > 0", [out], "bool")
        if times != 1 and op == "sum":
            out = self.op(f"{{0}} * {times}", [out], out.rtype)
        # (shared, k_out, f_out, batch) -> scope order, batch last
        axes_now = shared + k_out + f_out
        # (the product's columns are f_out's values times the batch: a
        # reshape, unless there are no f_out axes and it has the shape already)
        if f_out or out.shape[:-1] != tuple(size[i] for i in axes_now):
            out = self.op(
                "{0}.reshape(" + _tuple_code([*(str(size[i]) for i in axes_now), "-1"]) + ")",
                [out],
                out.rtype,
                view=True,
            )
        ordered = sorted(axes_now)
        if axes_now != ordered:
            perm = (*(axes_now.index(i) for i in ordered), len(ordered))
            out = self.op(f"{{0}}.transpose({perm})", [out], out.rtype, view=True)
        if len(ordered) < n:
            kept = set(ordered)
            out = self.expand(out, [i in kept for i in range(n)])
        return _bounded(out, sum_bounds)

    @staticmethod
    def _sparse(kmat: Array, unit: bool) -> tuple[list[Array], bool] | None:
        """For a (KO, C) matrix with at most a few nonzeros per row (all 1
        if `unit`): the column of each row's j-th nonzero, C (a zero row
        added below) where a row has fewer; and whether any has fewer.
        None where the matrix is not like that."""
        nonzero = kmat != 0
        if unit and not (kmat[nonzero] == 1).all():
            return None
        counts = nonzero.sum(axis=1)
        most = int(counts.max()) if counts.size else 0
        if most == 0 or most > _SPARSE_MAX or most * 2 > kmat.shape[1]:
            return None
        cols = [np.full(kmat.shape[0], kmat.shape[1], dtype=np.intp) for _ in range(most)]
        for o in range(kmat.shape[0]):
            for j, c in enumerate(np.nonzero(nonzero[o])[0]):
                cols[j][o] = c
        return cols, bool((counts < most).any())

    # -- functions ---------------------------------------------------

    def _Function(self, e: A.Function, scope: Scope, hint: str | None) -> _Node:
        args = [self.numeric(a, scope) for a in e.args]
        types = [a.rtype for a in args]
        name = e.name
        # (no cast of a value that is float64 already: a call less, and a
        # plain `f(t)` may be written in place, see `_in_place`)
        as_f64 = "{0}" if args and args[0].dtype == np.float64 else "{0}.astype(_f64, copy=False)"
        if name in _UNARY_FUNCTIONS:
            rising = _bounds_exp if name == "exp" else None
            return self.op(f"{_UNARY_FUNCTIONS[name]}({as_f64})", args[:1], "real", bounds=rising)
        if name in ("floor", "ceil", "round"):
            return self.op(f"np.{name}({{0}}).astype(_i64)", args[:1], "int")
        if name in ("sgn", "sign"):
            return self.op("_sign({0}).astype(_i64)", args[:1], "int")
        if name == "abs":
            return self.op("_abs({0})", args[:1], "int" if types[0] == "bool" else types[0])
        pair = args[:2]
        out = "real" if "real" in types else "int"
        if name == "min":
            return self.op("_minimum({0}, {1})", pair, out, bounds=_bounds_min)
        if name == "max":
            return self.op("_maximum({0}, {1})", pair, out, bounds=_bounds_max)
        if name == "pow":
            if pair[1].value is not None and pair[1].value.size and (pair[1].value == 2).all():
                # x * x, correctly rounded as pow(x, 2) is: the same values, faster
                return self.op(f"_square({as_f64})", pair[:1], "real")
            return self.op(f"_power({as_f64}, {{1}})", pair, "real")
        if name == "log":
            return self.op("_log({0}) / _log({1})", pair, "real")
        if name == "hypot":
            return self.op("_hypot({0}, {1})", pair, "real")
        if name in ("mod", "fmod"):
            return self.op("_fmod({0}, {1})", pair, "real" if name == "fmod" else out)
        if name == "div":
            return self.op("_trunc(_div({0}, {1})).astype(_i64)", pair, "int")
        raise SimulationError(f"{e.loc}: function '{name}' is not supported by the simulator")

    # -- distributions -----------------------------------------------

    def _Distribution(self, e: A.Distribution, scope: Scope, hint: str | None) -> _Node:
        name = e.name
        if name == "KronDelta":
            return self.compile(e.args[0], scope, hint)
        if name == "DiracDelta":
            x = self.numeric(e.args[0], scope)
            return self.op("{0}.astype(_f64, copy=False)", [x], "real", view=True)
        params = [self.numeric(a, scope) for a in e.args]
        where = f"{e.loc}: {name}"
        # one independent draw per batch element and per grounding of every
        # variable in scope, whatever the parameters depend on
        full = self.scope_shape(scope)
        # drawn batch first, as (B, *full) in C order, whatever the layout
        # here: the stream does not depend on how values are laid out
        shape = _shape_code(full)
        rank = 1 + len(full)
        first = _batch_first(rank)
        if name == "Bernoulli":
            (p,) = params
            self._check(p, lambda v: (v < 0) | (v > 1), "_cnz(_lt({0}, 0.0)) or _cnz(_gt({0}, 1.0))",
                        _param_error(where, "probability outside [0, 1]", lambda v: (v < 0) | (v > 1)))  # fmt: skip
            return self._bernoulli(p, full, where)
        if name == "Normal":
            m, v = params
            self._check(
                v,
                lambda x: x < 0,
                "_cnz(_lt({0}, 0))",
                _param_error(where, "variance is negative", lambda x: x < 0),
            )
            sd = self.op("_sqrt({0})", [v], "real")
            self.code.draws.append(where)
            # loc + scale * z: what rng.normal(loc, scale) computes, draw for
            # draw, without its slow per-element broadcasting loop; drawn
            # batch last, as laid out here
            z = self.emit_value(
                f"rng.standard_normal({_last_shape_code(full)})", (*full, 1), np.float64, "real"
            )
            if self.large:
                # (two operations, each written in place, with its constant
                # as numpy takes it fastest: see `_spread_constant`)
                return self.op(
                    "_add({0}, {1})", [m, self.op("_mul({0}, {1})", [sd, z], "real")], "real"
                )
            return self.op("_add({0}, _mul({1}, {2}))", [m, sd, z], "real")
        sampler = _sampler(name, where)
        if sampler is None:
            raise SimulationError(f"{where} is not supported by the simulator")
        draw, out = sampler
        self.code.draws.append(where)
        args = ", ".join(p.code + first for p in params)
        dtype = np.int64 if out == "int" else np.float64
        return self.emit_value(
            self.batch_last(f"{self.aux(draw)}(rng, {shape}, {args})", rank), (*full, 1), dtype, out
        )

    def _bernoulli(self, p: _Node, full: tuple[int, ...], where: str) -> _Node:
        """Bernoulli(p) (p checked), one draw per batch element and per
        grounding of the scope (`full`): a uniform integer u of a slot
        compared with p * 2**32 (see `_uniforms` for the precision). Where
        p is known, the threshold is folded, in uint32 where it fits; where
        it is 0 (or 1) everywhere, nothing is drawn."""
        rank = len(full) + 1
        if p.value is not None:
            v = np.asarray(p.value, dtype=np.float64)
            if v.size and ((v == 0).all() or (v == 1).all()):
                # (the same in every state: a constant, and the stream does
                # not depend on the states either)
                return self.const(np.full((1,) * rank, bool(v.flat[0])), "bool")
        self.code.draws.append(where)
        u = self.code.uniform(full)
        if p.value is None:
            two_32 = self.const(np.full((1,) * rank, _TWO_32), "real")
            scaled_p = self.op("_mul({0}, {1})", [p, two_32], "real")
            return self.emit_value(f"_lt({u}, {scaled_p.code})", (*full, 1), np.bool_, "bool")
        scaled = np.asarray(p.value, dtype=np.float64) * _TWO_32
        limit = np.ceil(scaled)
        valid = bool(((scaled >= 0) & (scaled <= _TWO_32)).all())  # (else it raises before)
        k: Array
        if valid and limit.max(initial=0) <= 2**32 - 1:
            # u < limit, in uint32
            cmp, k = "_lt", limit.astype(np.uint32)
        elif valid and limit.min(initial=1) >= 1:
            # u <= limit - 1, in uint32 (p = 1 somewhere, never 0)
            cmp, k = "_le", (limit - 1).astype(np.uint32)
        else:
            cmp, k = "_lt", scaled
        name = self.aux(k)
        if self.large and k.size and k.ndim == rank:
            # (as `_spread_constant` does for other operations)
            flat = k.reshape(-1)
            if (flat == flat[0]).all():
                name = self.aux(flat[:1].reshape((1,) * rank))
            elif int(np.prod(full, dtype=np.int64)) <= _SPREAD_CELLS:
                name = self.spread(name, (*full, 1))
        return self.emit_value(f"{cmp}({u}, {name})", (*full, 1), np.bool_, "bool")

    def _check(
        self, x: _Node, bad: Callable[[Array], Array], test: str, fail: Callable[[Array], None]
    ) -> None:
        """A parameter check: when the simulator is built if `x` is known
        (a statement that raises at run time only if it fails), else one
        test over the whole array at run time."""
        if x.value is not None:
            with np.errstate(all="ignore"):
                failed = bool(np.any(bad(x.value)))
            if failed:
                self.fail(fail, x.code)
            return
        b = self.bounds_of(x)
        if b is not None and not np.any(bad(b[0])) and not np.any(bad(b[1])):
            return  # every value it can take is valid (for an interval condition)
        with self.code.block(f"if {test.format(x.code)}:"):
            self.fail(fail, x.code)

    def _Discrete(self, e: A.Discrete, scope: Scope, hint: str | None) -> _Node:
        if e.count is not None:
            raise SimulationError(f"{e.loc}: {e.name} is not supported by the simulator")
        t = e.type
        labels = []
        probs: list[_Node | None] = []
        for dc in e.cases:
            name = dc.label.name  # type: ignore[union-attr]
            if t in self.codes and name not in self.codes[t] and "@" + name in self.codes[t]:
                name = "@" + name
            labels.append(self.code_of(name, t)[0])
            probs.append(None if dc.prob is None else self.numeric(dc.prob, scope))
        codes = np.array(labels, dtype=np.int64)
        normalise = e.name == "UnnormDiscrete"
        where = f"{e.loc}: {e.name}"
        draw_shape = self.scope_shape(scope)
        shape = _shape_code(draw_shape)
        rank = 1 + len(draw_shape)
        to_first = _batch_first(rank)
        self.code.draws.append(where)
        out_shape = (*draw_shape, 1)
        if all(p is None or p.value is not None for p in probs):
            # computed batch first, as the draws are made
            values = [None if p is None else np.asarray(p.value)[..., 0][None] for p in probs]
            fixed = _fixed_categorical(values, (1, *draw_shape), normalise)
            if fixed is not None:
                cum, total = fixed
                k = cum.shape[-1]
                table = "" if np.array_equal(codes, np.arange(k)) else self.aux(codes)
                flat = cum.reshape(-1, k)
                if (flat == flat[0]).all() and (np.diff(flat[0]) >= 0).all():
                    # the same distribution everywhere: a sorted search
                    idx = f"_searchsorted({self.aux(flat[0].copy())}, rng.random({shape}) * {self.aux(total.reshape(-1)[0].copy())}, 'right')"
                else:
                    idx = f"_sum({self.aux(cum)} <= rng.random({shape})[..., None] * {self.aux(total)}, -1)"
                text = f"_minimum({idx}, {k - 1})"
                if table:
                    text = f"{table}[{text}]"
                return self.emit_value(self.batch_last(text, rank), out_shape, np.int64, t)
        sampler = _discrete_sampler(codes, normalise, where, draw_shape)
        args = ", ".join("None" if p is None else p.code + to_first for p in probs)
        return self.emit_value(
            self.batch_last(f"{self.aux(sampler)}(rng, B, [{args}])", rank), out_shape, np.int64, t
        )

    def _DiscreteOver(self, e: A.DiscreteOver, scope: Scope, hint: str | None) -> _Node:
        if len(e.params) != 1:
            raise SimulationError(f"{e.loc}: {e.name}_ takes one variable")
        inner = scope + ((e.params[0].name, e.params[0].type),)
        w = self.numeric(e.body, inner)
        size = self.sizes[e.params[0].type]
        where = f"{e.loc}: {e.name}_"
        full = self.scope_shape(scope)
        sampler = _discrete_over_sampler(size, e.name == "UnnormDiscrete", where, full)
        self.code.draws.append(where)
        # the weights batch first, the variable's axis last, as the draws are made
        text = self.batch_last(
            f"{self.aux(sampler)}(rng, B, {w.code}{_batch_first(len(full) + 2)})", len(full) + 1
        )
        return self.emit_value(text, (*full, 1), np.int64, e.params[0].type)

    def _unsupported(self, e: A.Expr, scope: Scope, hint: str | None) -> _Node:
        raise SimulationError(f"{e.loc}: {type(e).__name__} is not supported by the simulator")

    _MatrixOp = _unsupported
    _VectorDistribution = _unsupported


# Bounds of operations from their arguments' ((lo, hi) pairs), computed with
# the same floating-point operations as the values; None where unknown.

Bounds = tuple[Array, Array]


def _bounds_add(a: Bounds, b: Bounds) -> Bounds:
    return a[0] + b[0], a[1] + b[1]


def _bounds_sub(a: Bounds, b: Bounds) -> Bounds:
    return a[0] - b[1], a[1] - b[0]


def _bounds_mul(a: Bounds, b: Bounds) -> Bounds:
    c = [a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1]]
    return np.minimum(np.minimum(c[0], c[1]), np.minimum(c[2], c[3])), np.maximum(
        np.maximum(c[0], c[1]), np.maximum(c[2], c[3])
    )


def _bounds_div(a: Bounds, b: Bounds) -> Bounds | None:
    if not ((b[0] > 0) | (b[1] < 0)).all():
        return None  # the divisor may be 0
    c = [a[0] / b[0], a[0] / b[1], a[1] / b[0], a[1] / b[1]]
    return np.minimum(np.minimum(c[0], c[1]), np.minimum(c[2], c[3])), np.maximum(
        np.maximum(c[0], c[1]), np.maximum(c[2], c[3])
    )


def _bounds_same(a: Bounds) -> Bounds:
    return a


def _bounds_trunc(a: Bounds) -> Bounds:
    return np.trunc(a[0]), np.trunc(a[1])


def _bounds_neg(a: Bounds) -> Bounds:
    return -a[1], -a[0]


def _bounds_min(a: Bounds, b: Bounds) -> Bounds:
    return np.minimum(a[0], b[0]), np.minimum(a[1], b[1])


def _bounds_max(a: Bounds, b: Bounds) -> Bounds:
    return np.maximum(a[0], b[0]), np.maximum(a[1], b[1])


def _bounds_either(cond: Bounds, a: Bounds, b: Bounds) -> Bounds:
    return np.minimum(a[0], b[0]), np.maximum(a[1], b[1])


def _bounds_exp(a: Bounds) -> Bounds:
    # exp is not correctly rounded: a few ulps of slack each way
    lo, hi = np.exp(a[0]), np.exp(a[1])
    for _ in range(4):
        lo, hi = np.nextafter(lo, -np.inf), np.nextafter(hi, np.inf)
    return np.maximum(lo, 0.0), hi


def _bounded(node: _Node, bounds: Bounds | None) -> _Node:
    if bounds is not None and all((np.abs(x) < 2.0**52).all() for x in bounds):
        node.bounds = bounds
    return node


def _leaves(e: A.Expr, chain: str) -> list[A.Expr]:
    """The operands of a chain of one binary operator, left to right."""
    if isinstance(e, A.Binary) and e.op == chain:
        return _leaves(e.left, chain) + _leaves(e.right, chain)
    return [e]


def _missing(name: str) -> None:
    raise SimulationError(f"'{name}' has no value where it is read")


def _param_error(where: str, what: str, bad: Callable[[Array], Array]) -> Callable[[Array], None]:
    def fail(values: Array) -> None:
        v = np.asarray(values)
        mask = bad(v)
        if np.any(mask):
            raise SimulationError(f"{where} {what}: {_bad(v, mask)}")

    return fail


def _sampler(name: str, where: str) -> tuple[Callable[..., Array], str] | None:
    """A draw function (rng, shape, *params) that checks its parameters,
    and its value type; None for a distribution not simulated."""
    if name == "Uniform":

        def uniform(g: np.random.Generator, shape: tuple[int, ...], lo: Array, hi: Array) -> Array:
            if np.any(lo > hi):
                raise SimulationError(f"{where} lower bound above upper bound")
            return g.uniform(lo, hi, shape)

        return uniform, "real"
    if name == "Exponential":

        def exponential(g: np.random.Generator, shape: tuple[int, ...], s: Array) -> Array:
            if np.any(s <= 0):
                raise SimulationError(f"{where} mean must be positive: {_bad(s, s <= 0)}")
            return g.exponential(s, shape)

        return exponential, "real"
    if name == "Poisson":

        def poisson(g: np.random.Generator, shape: tuple[int, ...], lam: Array) -> Array:
            if np.any(lam < 0):
                raise SimulationError(f"{where} mean must not be negative: {_bad(lam, lam < 0)}")
            return g.poisson(lam, shape).astype(np.int64)

        return poisson, "int"
    two: dict[str, tuple[Callable[..., Array], str, Callable[[Array, Array], Array]]] = {
        "Gamma": (lambda g, a, b, s: g.gamma(a, b, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Weibull": (lambda g, a, b, s: b * g.weibull(a, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Beta": (lambda g, a, b, s: g.beta(a, b, s), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Binomial": (lambda g, n, p, s: g.binomial(n, p, s).astype(np.int64), "int", lambda n, p: (n < 0) | (p < 0) | (p > 1)),
        "NegativeBinomial": (lambda g, n, p, s: g.negative_binomial(n, p, s).astype(np.int64), "int", lambda n, p: (n <= 0) | (p <= 0) | (p > 1)),
        "Pareto": (lambda g, a, b, s: b * (1 + g.pareto(a, s)), "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Gumbel": (lambda g, a, b, s: g.gumbel(a, b, s), "real", lambda a, b: b <= 0),
        "Laplace": (lambda g, a, b, s: g.laplace(a, b, s), "real", lambda a, b: b <= 0),
        "Cauchy": (lambda g, a, b, s: a + b * g.standard_cauchy(s), "real", lambda a, b: b <= 0),
        "Gompertz": (lambda g, a, b, s: np.log(1 - np.log(1 - g.random(s)) / a) / b, "real", lambda a, b: (a <= 0) | (b <= 0)),
        "Kumaraswamy": (lambda g, a, b, s: (1 - (1 - g.random(s)) ** (1 / b)) ** (1 / a), "real", lambda a, b: (a <= 0) | (b <= 0)),
    }  # fmt: skip
    if name in two:
        draw2, out2, invalid2 = two[name]

        def sample2(g: np.random.Generator, shape: tuple[int, ...], a: Array, b: Array) -> Array:
            if np.any(invalid2(np.asarray(a), np.asarray(b))):
                raise SimulationError(f"{where} parameters outside its domain")
            return draw2(g, a, b, shape)

        return sample2, out2
    one: dict[str, tuple[Callable[..., Array], str, Callable[[Array], Array]]] = {
        "Geometric": (lambda g, p, s: g.geometric(p, s).astype(np.int64), "int", lambda p: (p <= 0) | (p > 1)),
        "Student": (lambda g, d, s: g.standard_t(d, s), "real", lambda d: d <= 0),
        "ChiSquare": (lambda g, d, s: g.chisquare(d, s), "real", lambda d: d <= 0),
    }  # fmt: skip
    if name in one:
        draw1, out1, invalid1 = one[name]

        def sample1(g: np.random.Generator, shape: tuple[int, ...], a: Array) -> Array:
            if np.any(invalid1(np.asarray(a))):
                raise SimulationError(f"{where} parameter outside its domain")
            return draw1(g, a, shape)

        return sample1, out1
    return None


def _stack_probabilities(ps: list[Array | None], shape: tuple[int, ...]) -> Array:
    """Discrete's probabilities along a last axis; the case without one
    takes what the others leave (never below 0)."""
    full = [
        np.broadcast_to(np.asarray(p, dtype=np.float64), shape) if p is not None else None
        for p in ps
    ]
    known = [p for p in full if p is not None]
    total_known = sum(known) if known else np.zeros(shape)
    return np.stack(
        [p if p is not None else np.maximum(1.0 - total_known, 0.0) for p in full], axis=-1
    )


def _fixed_categorical(
    ps: list[Array | None], shape: tuple[int, ...], normalise: bool
) -> tuple[Array, Array] | None:
    """Cumulative weights and their totals for probabilities known when the
    simulator is built, or None if they are not valid (the draw then raises
    at run time, as it should)."""
    with np.errstate(all="ignore"):
        stacked = _stack_probabilities(ps, shape)
        if np.any(stacked < -1e-12):
            return None
        total = stacked.sum(axis=-1)
        if normalise:
            weights = stacked / total[..., None]
        elif np.any(np.abs(total - 1.0) > 1e-6):
            return None
        else:
            weights = stacked
        if not np.all(np.isfinite(weights)):
            return None
        cum = np.cumsum(weights, axis=-1)
    return cum, cum[..., -1:].copy()


def _discrete_sampler(
    codes: Array, normalise: bool, where: str, draw_shape: tuple[int, ...]
) -> Callable[..., Array]:
    def discrete(rng: np.random.Generator, batch: int, ps: list[Array | None]) -> Array:
        stacked = _stack_probabilities(ps, (batch, *draw_shape))
        if np.any(stacked < -1e-12):
            raise SimulationError(f"{where} has a negative probability")
        return codes[_draw_categorical(stacked, normalise, where, rng)]  # type: ignore[no-any-return]

    return discrete


def _discrete_over_sampler(
    size: int, normalise: bool, where: str, full: tuple[int, ...]
) -> Callable[..., Array]:
    def discrete_over(rng: np.random.Generator, batch: int, weights: Array) -> Array:
        w = np.broadcast_to(np.asarray(weights, dtype=np.float64), (batch, *full, size))
        if np.any(w < 0):
            raise SimulationError(f"{where} has a negative probability")
        return _draw_categorical(w, normalise, where, rng)

    return discrete_over


def _draw_categorical(
    weights: Array, normalise: bool, where: str, rng: np.random.Generator | None
) -> Array:
    """One index per leading position, drawn with the probabilities along the
    last axis: normalised (UnnormDiscrete) or required to sum to 1."""
    total = weights.sum(axis=-1)
    if normalise:
        weights = weights / total[..., None]
    else:
        off = np.abs(total - 1.0)
        if np.any(off > 1e-6):
            worst = float(total.flat[int(np.argmax(off))])
            raise SimulationError(f"{where} probabilities sum to {worst}, not 1")
    if rng is None:
        raise SimulationError(f"{where}: a random draw needs a numpy Generator (rng)")
    cum = np.cumsum(weights, axis=-1)
    u = rng.random(weights.shape[:-1])[..., None] * cum[..., -1:]
    return np.minimum(np.sum(cum <= u, axis=-1), weights.shape[-1] - 1)  # type: ignore[no-any-return]


def _order_cpfs(model: Model) -> list[str]:
    """Keys of every cpf ("name" or "name'" for next state) in evaluation order."""
    rank = {INTERM: 0, DERIVED: 0, STATE: 1, OBSERV: 2}
    keys: dict[str, tuple[int, int, int]] = {}
    for i, p in enumerate(model.pvariables.values()):
        if p.kind in rank and p.name in model.cpfs:
            key = p.name + ("'" if p.kind == STATE else "")
            keys[key] = (rank[p.kind], p.level if p.level is not None else 0, i)
    deps: dict[str, set[str]] = {}
    for key in keys:
        cp = model.cpfs[key.rstrip("'")]
        found = set()
        for node in A.walk(cp.expr):
            if isinstance(node, A.PVar):
                ref = node.name + ("'" if node.primed else "")
                if ref in keys and ref != key:
                    found.add(ref)
                elif node.name in keys and not node.primed and ref != key:
                    found.add(node.name)
        deps[key] = found
    order: list[str] = []
    done: set[str] = set()
    pending = sorted(keys, key=lambda k: keys[k])
    while pending:
        for k in pending:
            if deps[k] <= done:
                order.append(k)
                done.add(k)
                pending.remove(k)
                break
        else:
            cycle = ", ".join(pending)
            raise SimulationError(f"the cpfs of {cycle} depend on each other in a cycle")
    return order


_WINDOW = 32  # candidates per state tested in one batched call in random_actions
_TRIAL_BUDGET = 4_000_000  # action values copied per state and batched call, at most
# rddlsim's RandomConcurrentPolicy takes at most this many actions (its
# MAX_CONCURRENT_ACTIONS), whatever max-nondef-actions allows
RANDOM_MAX_CONCURRENT = 20
_SPARSE_MAX = 12  # row gathers, at most, instead of a matrix product in a contraction
_LARGE_BATCH = 16  # batches from this size on step with code written for large batches


class _Order:
    """A random order of n items for each state of a batch: the items by
    increasing random key (ties by index), found only as far as it is read
    (a partial sort), as the random policy reads few of them."""

    def __init__(self, keys: Array):
        self.keys = keys
        self.known = np.zeros((keys.shape[0], 0), dtype=np.intp)

    def at(self, rows: Any, positions: Any) -> Any:
        """The items at `positions` of the order of the states `rows`."""
        needed = int(np.max(positions)) + 1 if np.size(positions) else 0
        if needed > self.known.shape[1]:
            n = self.keys.shape[1]
            m = min(n, max(needed, 2 * self.known.shape[1], 64))
            if m >= n:
                self.known = np.argsort(self.keys, axis=1, kind="stable")
            else:
                part = np.argpartition(self.keys, m - 1, axis=1)[:, :m]
                within = np.lexsort((part, np.take_along_axis(self.keys, part, axis=1)), axis=-1)
                self.known = np.take_along_axis(part, within, axis=1)
        return self.known[rows, positions]


def _comb(n: int, k: int) -> int:
    from math import comb

    return comb(n, k)


def _text(expr: A.Expr, limit: int = 160) -> str:
    from .writer import write_expr

    text = write_expr(expr)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _join(a: str, b: str) -> str:
    if a == b:
        return a
    nums = ("bool", "int", "real")
    if a in nums and b in nums:
        return "real" if "real" in (a, b) else "int"
    return a


def _bad(values: Array, mask: Array) -> str:
    v = np.asarray(values)
    m = np.broadcast_to(mask, v.shape) if v.shape else mask
    bad = np.asarray(v)[m] if np.ndim(v) else v
    return repr(float(np.ravel(bad)[0])) if np.size(bad) else "?"


# --------------------------------------------------------- simulator


class Simulator:
    """The forward model of one RDDL instance, stepping batches of states.

    >>> sim = Simulator(model)
    >>> s = sim.initial_state(batch=4)
    >>> out = sim.step(s, sim.noop(4), np.random.default_rng(0))
    """

    def __init__(self, model: Model):
        self.model = model
        self._c = _Compiler(model)
        self.state_fluents = model.fluents(STATE)
        self.action_fluents = model.fluents(ACTION)
        self.observ_fluents = model.fluents(OBSERV)
        self.non_fluents = model.fluents(NON_FLUENT)
        self.interm_fluents = [p for p in model.pvariables.values() if p.kind in (INTERM, DERIVED)]

        self._nf_values = {p.name: self._initial_array(p)[None] for p in self.non_fluents}
        self._defaults = {p.name: self._default_array(p) for p in self.action_fluents}
        self._initial = {p.name: self._initial_array(p) for p in self.state_fluents}
        self._action_names = [p.name for p in self.action_fluents]
        self._noop_views: dict[int, dict[str, Array]] = {}

        # Every cpf in an order that respects what it reads: by level and
        # kind (interm, next state, observation) where possible, as rddlsim
        # does, and by dependency where a domain reads a fluent computed
        # later (pyRDDLGym's levels-free style).
        self._cpf_order = _order_cpfs(model)
        dom = model.domain
        self._preconditions = [*dom.action_preconditions, *dom.state_action_constraints]
        self._invariants = list(dom.state_invariants)
        self._terminations = list(dom.termination)
        self._nf_nodes = {
            p.name: (self._c.const(self._nf_values[p.name][0][..., None], p.range), None)
            for p in self.non_fluents
        }
        self._lock = threading.Lock()  # the compiler is not reentrant
        self._step_small = self._build_step(large=False)
        # compiled when first needed
        self._compiled: dict[str, Callable[..., Any]] = {}
        self._step_one: Callable[..., Any] | None = None  # (`_step_fn(1)`)

    # -- values ------------------------------------------------------

    def _dtype(self, p: PVariable) -> Any:
        return _DTYPES.get(p.range, np.int64)

    def _encode(self, p: PVariable, value: Value) -> Any:
        if p.range in self._c.codes:
            return self._c.codes[p.range][value]  # type: ignore[index]
        return value

    def _default_array(self, p: PVariable) -> Array:
        shape = self._c.shape_of(p)
        return np.full(shape, self._encode(p, self.model.default_of(p)), dtype=self._dtype(p))

    def _initial_array(self, p: PVariable) -> Array:
        arr = self._default_array(p)
        values = self.model.non_fluent_values if p.kind == NON_FLUENT else self.model.init_state
        for (name, args), value in values.items():
            if name == p.name:
                idx = tuple(self._c.codes[t][a] for t, a in zip(p.params, args, strict=True))
                arr[idx] = self._encode(p, value)
        return arr

    def initial_state(self, batch: int = 1) -> State:
        """The instance's initial state, repeated `batch` times."""
        # laid out batch last in memory, as `step` makes its states
        return State(
            {
                k: np.moveaxis(np.repeat(v[..., None], batch, axis=-1), -1, 0)
                for k, v in self._initial.items()
            }
        )

    def noop(self, batch: int = 1) -> dict[str, Array]:
        """Every action at its default, for a batch."""
        return {k: np.repeat(v[None], batch, axis=0) for k, v in self._defaults.items()}

    # -- compiling -----------------------------------------------------

    def _bind(self, state: Mapping[str, _Node] | None = None) -> None:
        """What pvariable names mean in the function being written: the
        non-fluents' values, the state (`S`, or the given next state) and
        the actions (`A`)."""
        c = self._c
        c.context += 1
        c.values = dict(self._nf_nodes)

        # arrays come batch first (B, *params); the generated code works
        # batch last (*params, B): a view, and no copy where the array was
        # made by a step (its memory is batch last)
        # (for large batches made contiguous: operations on arrays of mixed
        # layouts are several times slower, and a copy costs about one)
        def read(source: str, arity: int) -> str:
            text = source + _batch_last(arity + 1)
            return f"_contiguous({text})" if c.large and arity else text

        for i, p in enumerate(self.state_fluents):
            if state is not None:
                c.values[p.name] = (state[p.name], None)
            else:
                node = _Node(f"s{i}", (*c.shape_of(p), 1), np.dtype(self._dtype(p)), p.range, True)
                c.values[p.name] = (node, read(f"S[{p.name!r}]", p.arity))
        for i, p in enumerate(self.action_fluents):
            node = _Node(f"a{i}", (*c.shape_of(p), 1), np.dtype(self._dtype(p)), p.range, True)
            source = read(f"A[{p.name!r}]", p.arity)
            if c.large and p.arity and not self._defaults[p.name].any():
                # (an action left at its default everywhere, as most are in
                # most steps, is not worth a transposing copy)
                source = f"_action_in(A[{p.name!r}], {(*range(1, p.arity + 1), 0)})"
            c.values[p.name] = (node, source)

    def _output(self, node: _Node, shape: tuple[int, ...], dtype: Any, used: set[str]) -> _Node:
        """`node` as an array of its own, shaped (*shape, B): the value
        itself where this step allocated it and nothing else returns it,
        else a copy."""
        c = self._c
        dtype = np.dtype(dtype)
        full = (*shape, 1)
        if (
            node.batched
            and node.shape == full
            and node.dtype == dtype
            and node.owner
            and node.owner not in used
        ):
            used.add(node.owner)
            if not c.large:
                return node
            # batch last in memory too (a copy only where it is not)
            name = c.code.temp()
            c.code.emit(f"{name} = _contiguous({node.code})")
            return _Node(name, full, dtype, node.rtype, True, owner=node.owner)
        name = c.code.temp()
        if node.batched and node.shape == full:
            order = ", order='C'" if c.large else ""
            c.code.emit(f"{name} = {node.code}.astype({_DTYPE_CODE[dtype]}{order})")
        else:
            c.code.emit(f"{name} = _empty({_last_shape_code(shape)}, {_DTYPE_CODE[dtype]})")
            c.code.emit(f"{name}[...] = {node.code}")
        used.add(name)
        return _Node(name, full, dtype, node.rtype, True, owner=name)

    def _emit_constraints(self) -> None:
        """Statements that raise `SimulationError` for the first violated
        constraint: max-nondef-actions, then the preconditions in order."""
        c = self._c
        limit = self.model.max_nondef_actions
        if limit is not None and self.action_fluents:
            terms = []
            for p in self.action_fluents:
                a = c.ref(p, False)
                d = self._defaults[p.name]
                if p.range == "bool" and not d.any():
                    terms.append(f"_cnz({a.code})")
                else:
                    terms.append(f"_cnz(_ne({a.code}, {c.aux(d[..., None])}))")
            # the total over the batch bounds each state's count
            with c.code.block(f"if {' + '.join(terms)} > {limit}:"):
                c.fail(self._fail_nondef, "A", "B")
        for k, expr in enumerate(self._preconditions):
            holds = c.numeric(expr, ())
            if holds.value is not None:
                if not np.asarray(holds.value, dtype=bool).all():
                    c.fail(self._fail_precondition, str(k), holds.code, "A", "B")
                continue
            with c.code.block(f"if _cnz({holds.code}) != {holds.code}.size:"):
                c.fail(self._fail_precondition, str(k), holds.code, "A", "B")

    def _step_fn(self, batch: int) -> Callable[..., Any]:
        """The step function for this batch size (all make the same draws
        and compute the same values)."""
        if batch == 1:
            return self._step_one or self._function("_step_one")
        if batch < _LARGE_BATCH:
            return self._step_small
        return self._function("_step_large")

    def _build_step(self, large: bool, one: bool = False) -> Callable[..., Any]:
        c = self._c
        model = self.model
        name = "_step_large" if large else "_step_one" if one else "_step"
        code = c.begin(name, "S, A, B, rng, check", large, one)
        self._bind()
        if self._preconditions or model.max_nondef_actions is not None:
            with code.block("if check:"):
                self._emit_constraints()
        used: set[str] = set()
        nxt: dict[str, _Node] = {}
        obs: dict[str, _Node] = {}
        for key in self._cpf_order:
            p = model.pvariables[key.rstrip("'")]
            cp = model.cpfs[p.name]
            scope = tuple(zip(cp.params, p.params, strict=True))
            node = c.compile(cp.expr, scope, p.range)
            shape = c.shape_of(p)
            dtype = np.dtype(self._dtype(p))
            if p.kind == STATE:
                node = nxt[p.name] = self._output(node, shape, dtype, used)
                c.values[key] = (node, None)
            elif p.kind == OBSERV:
                node = obs[p.name] = self._output(node, shape, dtype, used)
                c.values[p.name] = (node, None)
            else:
                # an intermediate value: its type, over every grounding
                node = c.cast(node, dtype)
                if node.shape[:-1] != shape:
                    dims = ", ".join([*map(str, shape), "{0}.shape[-1]"])
                    node = c.op(f"_broadcast_to({{0}}, ({dims},))", [node], p.range, view=True)
                c.values[p.name] = (node, None)
        if model.reward is not None:
            reward = self._output(c.numeric(model.reward, ()), (), np.float64, used).code
        else:
            reward = "_zeros(B)"
        self._bind({p.name: nxt[p.name] for p in self.state_fluents})
        if self._invariants:
            with code.block("if check:"):
                for k, expr in enumerate(self._invariants):
                    holds = c.numeric(expr, ())
                    if holds.value is not None:
                        if not np.asarray(holds.value, dtype=bool).all():
                            c.fail(self._fail_invariant, str(k), holds.code, "B")
                        continue
                    with code.block(f"if _cnz({holds.code}) != {holds.code}.size:"):
                        c.fail(self._fail_invariant, str(k), holds.code, "B")
        code.emit("done = _zeros(B, _bool)")
        for expr in self._terminations:
            holds = c.numeric(expr, ())
            code.emit(f"_lor(done, {holds.code}, out=done)")
        # returned batch first: views of the batch-last arrays
        states = (
            "{"
            + ", ".join(
                f"{p.name!r}: {nxt[p.name].code}{_batch_first(p.arity + 1)}"
                for p in self.state_fluents
            )
            + "}"
        )
        observed = "None"
        if self.observ_fluents:
            pv = model.pvariables
            observed = (
                "{"
                + ", ".join(
                    f"{k!r}: {v.code}{_batch_first(pv[k].arity + 1)}" for k, v in obs.items()
                )
                + "}"
            )
        code.emit(f"return {states}, {reward}, {observed}, done")
        return c.build(code)

    def _function(self, name: str) -> Callable[..., Any]:
        """A generated function, compiled on first use: `_step_large`,
        `_step_one`, `_legal`, `_legal_large` or `_check`."""
        fn = self._compiled.get(name)
        if fn is None:
            with self._lock:
                fn = self._compiled.get(name)
                if fn is None:
                    if name == "_step_large":
                        fn = self._build_step(large=True)
                    elif name == "_step_one":
                        fn = self._step_one = self._build_step(large=False, one=True)
                    else:
                        fn = self._build_constraints(
                            name, explain=name == "_check", large=name.endswith("_large")
                        )
                    self._compiled[name] = fn
        return fn

    def _legal_fn(self, batch: int) -> Callable[..., Any]:
        """The function of the preconditions' mask for this batch size."""
        return self._function("_legal" if batch < _LARGE_BATCH else "_legal_large")

    def _build_constraints(
        self, name: str, explain: bool, large: bool = False
    ) -> Callable[..., Any]:
        """`explain`: a function that raises for the first violated
        constraint (max-nondef-actions included); else one that returns
        the mask of the states where every precondition holds."""
        c = self._c
        code = c.begin(name, "S, A, B", large)
        self._bind()
        if explain:
            self._emit_constraints()
            code.emit("return None")
            return c.build(code)
        code.emit("ok = np.ones(B, _bool)")
        for expr in self._preconditions:
            holds = c.numeric(expr, ())
            code.emit(f"_land(ok, {holds.code}, out=ok)")
        code.emit("return ok")
        return c.build(code)

    def source(self) -> str:
        """The generated code of the step, for reading (and debugging)."""
        return "\n".join(self._c.sources.values())

    # -- failures (called from the generated code) ---------------------

    def _fail_nondef(self, actions: Mapping[str, Array], batch: int) -> None:
        limit = self.model.max_nondef_actions
        n = self.count_nondefault(actions, batch)
        if limit is not None and np.any(n > limit):
            i = int(np.argmax(n > limit))
            raise SimulationError(
                f"{int(n[i])} actions differ from their default, max-nondef-actions is {limit}: "
                f"{', '.join(self.actions_to_names(actions, i)) or 'noop'}"
            )

    def _fail_precondition(
        self, k: int, holds: Array, actions: Mapping[str, Array], batch: int
    ) -> None:
        expr = self._preconditions[k]
        ok = np.broadcast_to(np.asarray(holds, dtype=bool).reshape(-1), (batch,))
        i = int(np.argmin(ok))
        acts = ", ".join(self.actions_to_names(actions, i)) or "noop"
        raise SimulationError(
            f"{expr.loc}: constraint violated (state {i} of the batch): {_text(expr)}; actions: {acts}"
        )

    def _fail_invariant(self, k: int, holds: Array, batch: int) -> None:
        expr = self._invariants[k]
        ok = np.broadcast_to(np.asarray(holds, dtype=bool).reshape(-1), (batch,))
        raise SimulationError(
            f"{expr.loc}: state invariant violated (state {int(np.argmin(ok))} of the batch): {_text(expr)}"
        )

    # -- the step ----------------------------------------------------

    def _noop_view(self, batch: int) -> dict[str, Array]:
        views = self._noop_views.get(batch)
        if views is None:
            if len(self._noop_views) > 16:
                self._noop_views.clear()
            views = {k: np.broadcast_to(v, (batch, *v.shape)) for k, v in self._defaults.items()}
            self._noop_views[batch] = views
        return views

    def _actions(self, actions: Mapping[str, Array] | None, batch: int) -> dict[str, Array]:
        """Every action fluent's array, shaped (batch, *params): the given
        ones, and (read-only) defaults for the others."""
        if not actions:
            return self._noop_view(batch)
        out = {}
        views = None
        for name in self._action_names:
            a = actions.get(name)
            if a is None:
                if views is None:
                    views = self._noop_view(batch)
                a = views[name]
            elif type(a) is not np.ndarray or a.ndim == 0 or a.shape[0] != batch:
                a = np.asarray(a)
                if a.ndim and a.shape[0] != batch:
                    a = np.broadcast_to(a, (batch, *a.shape[1:]))
            out[name] = a
        return out

    def _env(
        self, state: State, actions: Mapping[str, Array], rng: np.random.Generator | None
    ) -> _Env:
        return _Env(state, actions, rng, state.batch)

    def count_nondefault(self, actions: Mapping[str, Array], batch: int) -> Array:
        """How many grounded actions differ from their default, per state."""
        n = np.zeros(batch, dtype=np.int64)
        for p in self.action_fluents:
            a = actions.get(p.name)
            if a is None:
                continue
            diff = np.asarray(a) != self._defaults[p.name]
            n += diff.reshape(diff.shape[0], -1).sum(axis=1)
        return n

    def check_actions(self, state: State, actions: Mapping[str, Array]) -> Array:
        """A (batch,) mask of the states where the actions are legal:
        max-nondef-actions, action-preconditions, state-action-constraints."""
        batch = state.batch
        ok = np.ones(batch, dtype=bool)
        limit = self.model.max_nondef_actions
        if limit is not None:
            ok &= self.count_nondefault(actions, batch) <= limit
        ok &= _quietly(self._legal_fn(batch), state.values, self._actions(actions, batch), batch)
        return ok

    def step(
        self,
        state: State,
        actions: Mapping[str, Array] | None,
        rng: np.random.Generator,
        check: bool = True,
    ) -> Step:
        """One transition for every state of the batch.

        `actions` maps action fluent names to arrays shaped (batch, *params)
        (missing names take their default). With `check`, an illegal action
        or a violated state invariant raises `SimulationError`.
        """
        values = state.values
        batch = 1
        for v in values.values():
            batch = v.shape[0]
            break
        if batch == 1:
            fn = self._step_one or self._function("_step_one")
        elif batch < _LARGE_BATCH:
            fn = self._step_small
        else:
            fn = self._function("_step_large")
        return _make_step(*_quietly(fn, values, self._actions(actions, batch), batch, rng, check))

    # -- a step in two parts (see `prestep`) -------------------------

    def _split_one(self) -> tuple[Callable[..., Any], Callable[..., Any]] | None:
        """The pre and post parts of the one-state step, or None."""
        got: Any = self._compiled.get("_split_one", _UNBUILT)
        if got is _UNBUILT:
            self._step_one or self._function("_step_one")
            with self._lock:
                got = self._compiled.get("_split_one", _UNBUILT)
                if got is _UNBUILT:
                    got = None
                    split = split_step_source(self._c.sources["_step_one"])
                    if split is not None:
                        pre_src, post_src, _ = split
                        got = (
                            self._c.define(PRE_NAME, pre_src),
                            self._c.define(POST_NAME, post_src),
                        )
                    self._compiled["_split_one"] = got
        return got  # type: ignore[no-any-return]

    def prepare(self, state: State, rng: np.random.Generator) -> Prepared | None:
        """Compute ahead what the next step of `state` (one state) does not
        need its actions for: its random draws, and every value that depends
        on the state and the draws alone. `finish` completes the step when
        the actions are known; `unprepare` gives the draws back if it never
        happens. `finish(prepare(state, rng), actions)` equals `step(state,
        actions, rng)` exactly, and leaves `rng` where the step leaves it.

        None (and `rng` untouched) for a batch of several states, when every
        part of the step needs the actions, or when the part computed ahead
        raised: `step` then computes (or raises) as usual."""
        split = self._split_one()
        if split is None or state.batch != 1:
            return None
        bitgen = rng.bit_generator
        saved = bitgen.state
        try:
            values = _quietly(split[0], state.values, 1, rng)
        except Exception:  # noqa: BLE001 - the step itself raises it, in its place
            bitgen.state = saved
            return None
        return Prepared(state, values, saved)

    def finish(
        self, prepared: Prepared, actions: Mapping[str, Array] | None, check: bool = True
    ) -> Step:
        """The step `prepared` was made for, with these actions (as `step`
        takes them). A step that raises may leave the generator further on
        than `step` would have (its draws were made ahead)."""
        split = self._split_one()
        assert split is not None
        return _make_step(
            *_quietly(
                split[1],
                prepared.state.values,
                self._actions(actions, 1),
                1,
                check,
                *prepared.values,
            )
        )

    @staticmethod
    def unprepare(prepared: Prepared, rng: np.random.Generator) -> None:
        """Put `rng` back where it was before `prepare` drew for a step that
        will not happen (so the next step draws what it would have drawn)."""
        rng.bit_generator.state = prepared.rng_state

    def _check_preconditions(self, env: _Env, actions: Mapping[str, Array], batch: int) -> None:
        """Raise `SimulationError` for the first constraint the actions
        violate (max-nondef-actions, then the preconditions in order)."""
        _quietly(self._function("_check"), env.state.values, self._actions(actions, batch), batch)

    # -- action choice ---------------------------------------------

    def _groundings(self) -> list[tuple[PVariable, tuple[int, ...]]]:
        return [(p, idx) for p in self.action_fluents for _, idx in self._ground(p)]

    def _random_value(self, p: PVariable, rng: np.random.Generator, n: int) -> Array:
        """n values of action `p` that differ from its default."""
        default = self._encode(p, self.model.default_of(p))
        if p.range == "bool":
            return np.full(n, not default)
        if p.range in self._c.codes:
            size = len(self._c.codes[p.range])
            if size < 2:
                return np.full(n, default)
            draw = rng.integers(0, size - 1, n)
            return draw + (draw >= default)  # type: ignore[no-any-return]
        if p.range == "int":
            step = rng.integers(1, 6, n)
            return default + np.where(rng.random(n) < 0.5, -step, step)  # type: ignore[no-any-return]
        return default + rng.uniform(-1.0, 1.0, n)  # type: ignore[no-any-return]

    def random_actions(self, state: State, rng: np.random.Generator) -> dict[str, Array]:
        """Random legal actions for every state of the batch, as rddlsim's
        RandomConcurrentPolicy picks them: each action fluent in turn, its
        groundings in a random order; each grounding is taken with
        probability 1/2 (with a random non-default value) and kept only if
        the constraints and max-nondef-actions still hold; at most
        max-nondef-actions are taken, and (as rddlsim's policy does, for
        max-nondef-actions = pos-inf) at most `RANDOM_MAX_CONCURRENT`."""
        batch = state.batch
        actions = self.noop(batch)
        limit = RANDOM_MAX_CONCURRENT
        if self.model.max_nondef_actions is not None:
            limit = min(limit, self.model.max_nondef_actions)
        if not self._preconditions:
            return self._random_unconstrained(actions, batch, limit, rng)
        taken = np.zeros(batch, dtype=np.int64)
        for p, flat, order, heads in self._coin_flips(actions, batch, rng):
            n = flat.shape[1]
            values = self._random_value(p, rng, batch * n).reshape(batch, n)
            candidates = [np.nonzero(heads[b])[0] for b in range(batch)]  # positions in the order
            self._take_legal(state, actions, p, flat, order, values, candidates, taken, limit)
        ok = self.check_actions(state, actions)
        if not ok.all():
            raise SimulationError(
                f"no legal action in state {int(np.argmin(ok))} of the batch, not even noop"
            )
        return actions

    def _take_legal(
        self,
        state: State,
        actions: dict[str, Array],
        p: PVariable,
        flat: Array,
        order: _Order,
        values: Array,
        candidates: list[Array],
        taken: Array,
        limit: int,
    ) -> None:
        """The sequential rule (try each candidate in turn, keep it if the
        actions taken so far plus it are legal), a window of candidates per
        state at a time, every state's window in one batched legality test.

        A state's window is tested one of two ways. While candidates are
        refused the set of actions does not change, so each candidate is
        tested alone against it and the first legal one is the one taken
        ("scan"). While candidates are taken the set after k of them is the
        k-th prefix, so the prefixes are tested and the first illegal one is
        the first candidate refused ("run"). A state switches to the other
        way when its window ends the way the other one handles better.
        """
        batch = len(candidates)
        pos = np.zeros(batch, dtype=np.int64)
        run = np.zeros(batch, dtype=bool)
        # every trial copies every action array: fewer candidates per window
        # where they are large
        per_state = sum(int(v[0].size) for v in actions.values())
        width = max(2, min(_WINDOW, _TRIAL_BUDGET // max(1, per_state)))
        scan_width = max(2, min(2 * _WINDOW, _TRIAL_BUDGET // max(1, per_state)))
        while True:
            active = [b for b in range(batch) if pos[b] < len(candidates[b]) and taken[b] < limit]
            if not active:
                return
            rows_b, set_row, set_pos = [], [], []
            windows: list[Array] = []
            first = 0
            for b in active:
                js = candidates[b][pos[b] : pos[b] + (width if run[b] else scan_width)]
                m = len(js)
                windows.append(js)
                rows_b.append(np.full(m, b))
                if run[b]:  # row i: the first i + 1 candidates
                    r, c = np.tril_indices(m)
                    set_row.append(first + r)
                    set_pos.append(js[c])
                else:  # row i: candidate i alone
                    set_row.append(first + np.arange(m))
                    set_pos.append(js)
                first += m
            rb = np.concatenate(rows_b)
            sr, sp = np.concatenate(set_row), np.concatenate(set_pos)
            trial = {k: v[rb] for k, v in actions.items()}  # (fancy indexing copies)
            tflat = trial[p.name].reshape(len(rb), -1)
            tflat[sr, order.at(rb[sr], sp)] = values[rb[sr], sp]
            legal = self.check_actions(state[rb], trial)
            start = 0
            for b, js in zip(active, windows, strict=True):
                m = len(js)
                ok = legal[start : start + m]
                start += m
                if run[b]:
                    refused = np.nonzero(~ok)[0]
                    k = int(refused[0]) if len(refused) else m
                    k_taken = min(k, limit - int(taken[b]))
                    for j in js[:k_taken]:
                        flat[b, order.at(b, j)] = values[b, j]
                    taken[b] += k_taken
                    pos[b] += k + 1 if k < m else k
                    run[b] = k == m
                else:
                    found = np.nonzero(ok)[0]
                    if len(found):
                        j = js[found[0]]
                        flat[b, order.at(b, j)] = values[b, j]
                        taken[b] += 1
                        pos[b] += found[0] + 1
                        run[b] = True
                    else:
                        pos[b] += m

    def _coin_flips(
        self, actions: dict[str, Array], batch: int, rng: np.random.Generator
    ) -> Iterable[tuple[PVariable, Array, _Order, Array]]:
        """Per action fluent with groundings: its flattened action array (a
        view to write into), a random order of its groundings per state, and
        a fair coin flip per position in that order."""
        for p in self.action_fluents:
            flat = actions[p.name].reshape(batch, -1)
            n = flat.shape[1]
            if n == 0:
                continue
            yield p, flat, _Order(rng.random((batch, n))), rng.random((batch, n)) < 0.5

    def _random_unconstrained(
        self, actions: dict[str, Array], batch: int, limit: int | None, rng: np.random.Generator
    ) -> dict[str, Array]:
        """The same choice without constraints to check, all at once: in each
        fluent's random order, the coin flips that come up, up to the limit
        (counted across fluents in declaration order)."""
        taken = np.zeros(batch, dtype=np.int64)
        for p, flat, order, heads in self._coin_flips(actions, batch, rng):
            if limit is not None:
                rank = taken[:, None] + np.cumsum(heads, axis=1)
                heads &= rank <= limit
            rows = np.nonzero(heads)
            flat[rows[0], order.at(rows[0], rows[1])] = self._random_value(p, rng, len(rows[0]))
            taken += heads.sum(axis=1)
        return actions

    def legal_actions(self, state: State, index: int = 0, limit: int = 100_000) -> dict[str, Array]:
        """Every legal joint action of a boolean action space in one state,
        stacked along the batch axis (noop first when legal): all sets of at
        most max-nondef-actions groundings set to their non-default value,
        filtered by the preconditions. Raises if there are more than `limit`."""
        grounds = self._groundings()
        for p, _ in grounds:
            if p.range != "bool":
                raise SimulationError(
                    f"legal_actions enumerates boolean actions only; '{p.name}' is {p.range}"
                )
        k_max = (
            len(grounds)
            if self.model.max_nondef_actions is None
            else min(self.model.max_nondef_actions, len(grounds))
        )
        count = sum(_comb(len(grounds), k) for k in range(k_max + 1))
        if count > limit:
            raise SimulationError(
                f"{count} candidate joint actions, more than the limit of {limit}"
            )
        combos = [
            c for k in range(k_max + 1) for c in itertools.combinations(range(len(grounds)), k)
        ]
        actions = self.noop(len(combos))
        for row, combo in enumerate(combos):
            for g in combo:
                p, idx = grounds[g]
                actions[p.name][(row, *idx)] = not self._defaults[p.name][idx]
        one = state[index]
        many = one[[0] * len(combos)]
        ok = self.check_actions(many, actions)
        return {k: v[ok] for k, v in actions.items()}

    # -- wire form ---------------------------------------------------

    def _decode(self, p: PVariable, x: Any) -> Value:
        if p.range in self._c.codes:
            return self.model.types[p.range].members[int(x)]
        if p.range == "bool":
            return bool(x)
        if p.range == "int":
            return int(x)
        return float(x)

    def _ground(self, p: PVariable) -> Iterable[tuple[tuple[str, ...], tuple[int, ...]]]:
        members = [self.model.types[t].members for t in p.params]
        for idx in itertools.product(*(range(len(m)) for m in members)):
            yield tuple(m[i] for m, i in zip(members, idx, strict=True)), idx

    def state_to_names(self, state: State, index: int = 0) -> dict[str, Value]:
        """The state at `index` as {'name(arg1,arg2)': value} (every grounding)."""
        out: dict[str, Value] = {}
        for p in self.state_fluents:
            arr = state.values[p.name][index]
            for args, idx in self._ground(p):
                out[_wire_name(p.name, args)] = self._decode(p, arr[idx])
        return out

    def actions_to_names(self, actions: Mapping[str, Array], index: int = 0) -> list[str]:
        """The non-default actions at `index` as 'name(args) = value' strings."""
        out = []
        for p in self.action_fluents:
            a = actions.get(p.name)
            if a is None:
                continue
            arr = np.asarray(a)[index]
            default = self._defaults[p.name]
            for args, idx in self._ground(p):
                if arr[idx] != default[idx]:
                    out.append(
                        f"{_wire_name(p.name, args)} = {_wire_value(self._decode(p, arr[idx]))}"
                    )
        return out

    def actions_from_names(
        self,
        named: Iterable[Mapping[tuple[str, tuple[str, ...]], Value]]
        | Mapping[tuple[str, tuple[str, ...]], Value],
    ) -> dict[str, Array]:
        """Action arrays from {(name, (args...)): value} maps, one per batch
        element (a single map gives a batch of one)."""
        batches = [named] if isinstance(named, Mapping) else list(named)
        out = self.noop(len(batches))
        for b, mapping in enumerate(batches):
            for (name, args), value in mapping.items():
                p = self.model.pvariables.get(name)
                if p is None or p.kind != ACTION:
                    raise SimulationError(f"'{name}' is not an action fluent")
                if len(args) != p.arity:
                    raise SimulationError(f"'{name}' takes {p.arity} argument(s), not {len(args)}")
                try:
                    idx = tuple(self._c.codes[t][a] for t, a in zip(p.params, args, strict=True))
                except KeyError as err:
                    raise SimulationError(f"'{name}{args}': unknown object {err}") from None
                if p.range in self._c.codes:
                    v = (
                        value
                        if isinstance(value, str) and value in self._c.codes[p.range]
                        else "@" + str(value).lstrip("@")
                    )
                    if v not in self._c.codes[p.range]:
                        raise SimulationError(f"'{name}': '{value}' is not a value of '{p.range}'")
                    out[name][(b, *idx)] = self._c.codes[p.range][v]
                else:
                    out[name][(b, *idx)] = value
        return out


def _wire_name(name: str, args: tuple[str, ...]) -> str:
    return f"{name}({','.join(args)})" if args else name


def _wire_value(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)
