"""The checked model of one RDDL instance.

A `Model` is what the rest of ippc works from: the domain, its non-fluents
and the instance merged, every object and enum value resolved, every
pvariable's signature and default known, and the instance's values in
plain Python (bool, int, float; enum values as "@name" strings, objects as
their names). The ASTs it came from stay attached for the compiler and the
writer.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

from . import ast as A

Value = bool | int | float | str

PRIMITIVE_TYPES = ("bool", "int", "real")

STATE = "state-fluent"
ACTION = "action-fluent"
NON_FLUENT = "non-fluent"
INTERM = "interm-fluent"
DERIVED = "derived-fluent"
OBSERV = "observ-fluent"
PVAR_KINDS = (NON_FLUENT, STATE, INTERM, DERIVED, OBSERV, ACTION)

# Value a pvariable takes when neither its declaration nor the instance says.
TYPE_DEFAULTS: dict[str, Value] = {"bool": False, "int": 0, "real": 0.0}


@dataclass(frozen=True)
class TypeInfo:
    """An object or enum type with its members, in declaration order.

    For an object type, `members` includes the objects of its subtypes.
    """

    name: str
    kind: str  # "object" or "enum"
    parent: str | None
    members: tuple[str, ...]
    loc: A.Loc = field(default=A.NOWHERE, compare=False)


@dataclass(frozen=True)
class PVariable:
    name: str
    kind: str
    params: tuple[str, ...]
    range: str
    default: Value | None
    level: int | None
    loc: A.Loc = field(default=A.NOWHERE, compare=False)

    @property
    def arity(self) -> int:
        return len(self.params)


GroundKey = tuple[str, tuple[str, ...]]


@dataclass(frozen=True)
class Model:
    """One instance, checked. Build it with `ippc.rddl.load`."""

    name: str
    domain: A.Domain
    instance: A.Instance
    non_fluents_block: A.NonFluents | None
    types: Mapping[str, TypeInfo]
    pvariables: Mapping[str, PVariable]
    cpfs: Mapping[str, A.Cpf]
    non_fluent_values: Mapping[GroundKey, Value]
    init_state: Mapping[GroundKey, Value]
    horizon: int | None  # None: pos-inf or terminate-when
    discount: float
    max_nondef_actions: int | None  # None: unbounded
    domain_file: str
    instance_file: str
    non_fluents_file: str | None

    # ------------------------------------------------------------ views

    @property
    def domain_name(self) -> str:
        return self.domain.name

    @property
    def reward(self) -> A.Expr | None:
        return self.domain.reward

    @property
    def is_pomdp(self) -> bool:
        return any(p.kind == OBSERV for p in self.pvariables.values())

    def fluents(self, kind: str) -> list[PVariable]:
        """Pvariables of one kind, in declaration order."""
        return [p for p in self.pvariables.values() if p.kind == kind]

    def objects(self, type_name: str) -> tuple[str, ...]:
        """Members of an object or enum type (objects of subtypes included)."""
        info = self.types.get(type_name)
        return () if info is None else info.members

    def groundings(self, pvar: str | PVariable) -> Iterator[tuple[str, ...]]:
        """Every argument tuple of a pvariable, in row-major order."""
        p = self.pvariables[pvar] if isinstance(pvar, str) else pvar
        return itertools.product(*(self.objects(t) for t in p.params))

    def default_of(self, pvar: str | PVariable) -> Value:
        p = self.pvariables[pvar] if isinstance(pvar, str) else pvar
        if p.default is not None:
            return p.default
        if p.range in TYPE_DEFAULTS:
            return TYPE_DEFAULTS[p.range]
        members = self.objects(p.range)
        return members[0] if members else ""

    def value_of(self, pvar: str, args: tuple[str, ...] = ()) -> Value:
        """The initial value: instance value if given, else the default."""
        key = (pvar, tuple(args))
        if key in self.init_state:
            return self.init_state[key]
        if key in self.non_fluent_values:
            return self.non_fluent_values[key]
        return self.default_of(pvar)

    def files(self) -> list[str]:
        """The files this model was read from (domain first, no repeats)."""
        out: list[str] = []
        for f in (self.domain_file, self.non_fluents_file, self.instance_file):
            if f and f not in out:
                out.append(f)
        return out

    def __repr__(self) -> str:
        return (
            f"Model({self.name!r}, domain={self.domain.name!r}, "
            f"pvariables={len(self.pvariables)}, horizon={self.horizon})"
        )
