"""The knowledge base's state: a closed-world store of every grounding.

Theory of operation. Every state fluent and every non-fluent of the model
is one numpy array with one axis per parameter, sized by its type's members
(the layout of `ippc.rddl.simulator.State`, without the batch axis), so
every grounding has a value at all times: a fact that is false is stored as
false, not left out. Booleans are numpy bools, ints int64, reals float64,
enum and object values the index of the value in its type's members (the
simulator's codes). Names go in and out as on the wire: objects by name,
enum values as "@name".

`apply` validates a whole batch of updates before it writes anything, so a
batch is applied entirely or not at all; it reports the groundings whose
value really changed. The store itself does not notify anyone (the
`KnowledgeBase` does, outside its lock).
"""

from __future__ import annotations

import difflib
import itertools
import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..rddl.model import NON_FLUENT, STATE, Model, PVariable, Value

Array = np.ndarray

UpdateOp = Literal["add", "remove", "set"]
UPDATE_OPS: tuple[str, ...] = ("add", "remove", "set")

_DTYPES: dict[str, Any] = {"bool": np.bool_, "int": np.int64, "real": np.float64}
INT_MIN, INT_MAX = -(2**63), 2**63 - 1  # what an int fluent can hold (int64, as the simulator)


class KBError(Exception):
    """A query or update the knowledge base refuses; the message names the
    fluent, the grounding or the update, and what is wrong with it.

    `code` is a short stable word for programs ("unknown-fluent", "arity",
    "unknown-object", "bad-value", "bad-op", "not-stored", ...)."""

    def __init__(self, message: str, code: str = "bad-request"):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class Update:
    """One requested change: `add` makes a boolean fact true, `remove` makes
    it false, `set` gives any fluent a value (enum values as "@name")."""

    op: UpdateOp
    fluent: str
    args: tuple[str, ...] = ()
    value: Value | None = None

    def __post_init__(self) -> None:
        # Lists arrive from JSON; a tuple keeps the update hashable.
        if not isinstance(self.args, tuple):
            object.__setattr__(self, "args", tuple(self.args))

    @classmethod
    def add(cls, fluent: str, *args: str) -> Update:
        """`fluent(args)` becomes true."""
        return cls("add", fluent, tuple(args))

    @classmethod
    def remove(cls, fluent: str, *args: str) -> Update:
        """`fluent(args)` becomes false."""
        return cls("remove", fluent, tuple(args))

    @classmethod
    def set(cls, fluent: str, args: Sequence[str], value: Value) -> Update:
        """`fluent(args)` takes `value`."""
        return cls("set", fluent, tuple(args), value)

    def __str__(self) -> str:
        ground = f"{self.fluent}({', '.join(self.args)})" if self.args else self.fluent
        return f"{self.op} {ground}" + ("" if self.value is None else f" = {self.value!r}")


@dataclass(frozen=True)
class Change:
    """One grounding whose value changed, from `old` to `new`."""

    fluent: str
    args: tuple[str, ...]
    old: Value
    new: Value

    def to_json(self) -> dict[str, Any]:
        """The change as the JSON-lines protocol sends it."""
        return {"fluent": self.fluent, "args": list(self.args), "old": self.old, "new": self.new}


def ground_name(fluent: str, args: Sequence[str]) -> str:
    """`fluent(a, b)`, or `fluent` for no arguments (for messages)."""
    return f"{fluent}({', '.join(args)})" if args else fluent


class Store:
    """Values of every grounding of the state fluents and non-fluents of a
    model (see the module's docstring). Not thread-safe: the
    `KnowledgeBase` serialises access."""

    def __init__(self, model: Model):
        self.model = model
        self.pvars: dict[str, PVariable] = {
            p.name: p for p in model.pvariables.values() if p.kind in (STATE, NON_FLUENT)
        }
        self.codes: dict[str, dict[str, int]] = {
            t: {m: i for i, m in enumerate(info.members)} for t, info in model.types.items()
        }
        self.arrays: dict[str, Array] = {}
        for p in self.pvars.values():
            self.arrays[p.name] = self._initial(p)

    # -- layout --------------------------------------------------------

    def dtype(self, p: PVariable) -> Any:
        return _DTYPES.get(p.range, np.int64)

    def shape(self, p: PVariable) -> tuple[int, ...]:
        return tuple(len(self.model.objects(t)) for t in p.params)

    def default_code(self, p: PVariable) -> Any:
        return self.encode(p, self.model.default_of(p))

    def initial(self, p: PVariable) -> Array:
        """`p`'s values as the loaded files give them (a new array)."""
        return self._initial(p)

    def _initial(self, p: PVariable) -> Array:
        arr = np.full(self.shape(p), self.default_code(p), dtype=self.dtype(p))
        given = self.model.non_fluent_values if p.kind == NON_FLUENT else self.model.init_state
        for (name, args), value in given.items():
            if name == p.name:
                arr[self.index(p, args)] = self.encode(p, value)
        return arr

    # -- names <-> codes -----------------------------------------------

    def pvar(self, fluent: str) -> PVariable:
        """The stored pvariable named `fluent`, or a KBError that says why not."""
        p = self.pvars.get(fluent)
        if p is not None:
            return p
        other = self.model.pvariables.get(fluent)
        if other is not None:
            raise KBError(
                f"'{fluent}' is an {other.kind}: the knowledge base stores state fluents "
                "and non-fluents only",
                "not-stored",
            )
        close = difflib.get_close_matches(fluent, list(self.pvars), n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise KBError(f"unknown fluent '{fluent}'{hint}", "unknown-fluent")

    def index(self, p: PVariable, args: Sequence[str]) -> tuple[int, ...]:
        """The array index of `p(args)`, or a KBError naming the bad argument."""
        if isinstance(args, str) or len(args) != p.arity:
            given = 1 if isinstance(args, str) else len(args)
            raise KBError(
                f"'{p.name}' takes {p.arity} argument(s) ({', '.join(p.params) or 'none'}), "
                f"not {given}",
                "arity",
            )
        out = []
        for i, (t, a) in enumerate(zip(p.params, args, strict=True)):
            codes = self.codes.get(t, {})
            if not isinstance(a, str):
                raise KBError(
                    f"argument {i + 1} of '{p.name}' must be a name of type '{t}', not {a!r}",
                    "unknown-object",
                )
            code = codes.get(a)
            if code is None and not a.startswith("@"):
                code = codes.get("@" + a)  # an enum value written without its '@'
            if code is None:
                raise KBError(
                    f"argument {i + 1} of '{p.name}': '{a}' is not an object of type '{t}' "
                    f"(members: {', '.join(self.model.objects(t)) or 'none'})",
                    "unknown-object",
                )
            out.append(code)
        return tuple(out)

    def encode(self, p: PVariable, value: Any) -> Any:
        """The stored code of `value` for fluent `p`, or a KBError."""
        where = f"'{p.name}' ({p.range})"
        if p.range == "bool":
            if isinstance(value, (bool, np.bool_)):
                return bool(value)
            raise KBError(f"{where} takes true or false, not {value!r}", "bad-value")
        if p.range == "int":
            number: int | None = None
            if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
                number = int(value)
            elif isinstance(value, (float, np.floating)) and math.isfinite(value):
                if float(value).is_integer():
                    number = int(value)
            if number is None:
                raise KBError(f"{where} takes an integer, not {value!r}", "bad-value")
            if not INT_MIN <= number <= INT_MAX:
                raise KBError(
                    f"{where} takes a 64-bit integer ({INT_MIN} to {INT_MAX}), not {value!r}",
                    "out-of-range",
                )
            return number
        if p.range == "real":
            if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
                value, (bool, np.bool_)
            ):
                try:
                    number_f = float(value)
                except OverflowError:  # an int beyond the largest double
                    raise KBError(
                        f"{where} takes a 64-bit float, not {value!r}", "out-of-range"
                    ) from None
                if math.isnan(number_f):
                    raise KBError(f"{where} takes a number, not NaN", "bad-value")
                return number_f
            raise KBError(f"{where} takes a number, not {value!r}", "bad-value")
        codes = self.codes.get(p.range, {})
        if isinstance(value, str):
            code = codes.get(value)
            if code is None and not value.startswith("@"):
                code = codes.get("@" + value)
            if code is not None:
                return code
        raise KBError(
            f"{where} takes one of {', '.join(self.model.objects(p.range))}, not {value!r}",
            "bad-value",
        )

    def decode(self, p: PVariable, code: Any) -> Value:
        """The name-level value of a stored code."""
        if p.range == "bool":
            return bool(code)
        if p.range == "int":
            return int(code)
        if p.range == "real":
            return float(code)
        return self.model.objects(p.range)[int(code)]

    def args_of(self, p: PVariable, index: Sequence[int]) -> tuple[str, ...]:
        return tuple(self.model.objects(t)[i] for t, i in zip(p.params, index, strict=True))

    # -- reading -------------------------------------------------------

    def get(self, fluent: str, args: Sequence[str] = ()) -> Value:
        p = self.pvar(fluent)
        return self.decode(p, self.arrays[p.name][self.index(p, args)])

    def items(self, p: PVariable) -> Iterator[tuple[tuple[str, ...], Value]]:
        """Every grounding of `p` with its value, last argument fastest."""
        arr = self.arrays[p.name]
        members = [self.model.objects(t) for t in p.params]
        if p.range == "bool":
            values: list[Any] = [bool(x) for x in arr.ravel().tolist()]
        elif p.range in _DTYPES:
            values = arr.ravel().tolist()  # int and float already
        else:
            names = self.model.objects(p.range)
            values = [names[c] for c in arr.ravel().tolist()]
        yield from zip(itertools.product(*members), values, strict=True)

    # -- writing -------------------------------------------------------

    def prepare(self, updates: Iterable[Update]) -> list[tuple[PVariable, tuple[int, ...], Any]]:
        """Validate a batch; the writes it makes (the last one wins where
        two updates name the same grounding). Raises KBError naming the
        first bad update, having written nothing."""
        writes: dict[tuple[str, tuple[int, ...]], tuple[PVariable, tuple[int, ...], Any]] = {}
        for n, u in enumerate(updates):
            try:
                if not isinstance(u, Update):
                    raise KBError(f"not an Update: {u!r}", "bad-update")
                p = self.pvar(u.fluent)
                idx = self.index(p, u.args)
                if u.op in ("add", "remove"):
                    if p.range != "bool":
                        raise KBError(
                            f"'{u.op}' needs a bool fluent; '{p.name}' is {p.range} (use 'set')",
                            "bad-op",
                        )
                    if u.value is not None:
                        raise KBError(f"'{u.op}' takes no value", "bad-value")
                    code: Any = u.op == "add"
                elif u.op == "set":
                    if u.value is None:
                        raise KBError("'set' needs a value", "bad-value")
                    code = self.encode(p, u.value)
                else:
                    raise KBError(
                        f"unknown op {u.op!r} (expected one of {', '.join(UPDATE_OPS)})", "bad-op"
                    )
            except KBError as err:
                raise KBError(f"update {n + 1} ({u}): {err}", err.code) from None
            writes[(p.name, idx)] = (p, idx, code)
        return list(writes.values())

    def commit(self, writes: Iterable[tuple[PVariable, tuple[int, ...], Any]]) -> list[Change]:
        """Write validated values; the changes they made. Should a write
        fail all the same, the ones before it are undone and the error
        raised: nothing is half applied."""
        changes = []
        undo: list[tuple[Array, tuple[int, ...], Any]] = []
        try:
            for p, idx, code in writes:
                arr = self.arrays[p.name]
                if arr[idx] == code:
                    continue
                old = self.decode(p, arr[idx])
                undo.append((arr, idx, arr[idx].copy()))
                arr[idx] = code
                changes.append(Change(p.name, self.args_of(p, idx), old, self.decode(p, code)))
        except BaseException:
            for arr, idx, before in reversed(undo):
                arr[idx] = before
            raise
        return changes

    def lookup_after(
        self, writes: Iterable[tuple[PVariable, tuple[int, ...], Any]]
    ) -> Callable[[str, tuple[str, ...]], Value]:
        """A lookup of the values the store would hold after `writes`
        (validated), without writing them."""
        pending = {(p.name, idx): (p, code) for p, idx, code in writes}

        def get(fluent: str, args: tuple[str, ...]) -> Value:
            p = self.pvar(fluent)
            idx = self.index(p, args)
            hit = pending.get((p.name, idx))
            if hit is not None:
                return self.decode(hit[0], hit[1])
            return self.decode(p, self.arrays[p.name][idx])

        return get

    def replace(self, new: Mapping[str, Array]) -> list[Change]:
        """Replace whole arrays (already validated, same shapes and dtypes);
        the changes, found with one comparison per fluent."""
        changes = []
        for name, arr in new.items():
            p = self.pvars[name]
            cur = self.arrays[name]
            diff = np.argwhere(cur != arr)
            for row in diff.tolist():
                idx = tuple(row)
                changes.append(
                    Change(
                        name,
                        self.args_of(p, idx),
                        self.decode(p, cur[idx]),
                        self.decode(p, arr[idx]),
                    )
                )
            if len(diff):
                self.arrays[name] = arr.copy()
        return changes
