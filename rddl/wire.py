"""Between simulator tensors and the wire form of rddlsim's protocol.

A *wire fluent* is `(name, args, value)`: a pvariable name, its object (or
enum) arguments and a typed value (bool, int, float, or str for enum values
`@x` and objects). The server turns a `State` into the observed fluents of a
turn and the received actions into action arrays; the client does the
reverse. No XML here: `ippc.protocol` writes and reads the bytes.

rddlsim lists every grounding of every state fluent in a turn (defaults
included), fluents in the iteration order of a Java `HashMap` keyed by the
fluent name, groundings in declaration order with the last argument varying
fastest. `rddlsim_order` reproduces that order, so our turns are byte-equal
to rddlsim's.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .model import ACTION, OBSERV, STATE, Model, PVariable, Value
from .simulator import SimulationError, Simulator, State

WireFluent = tuple[str, tuple[str, ...], Value]


class WireError(ValueError):
    """Received fluents that cannot be used at all (an unknown action name,
    a value that does not parse): rddlsim drops the session."""


class IllegalActions(SimulationError):
    """Actions that rddlsim accepts as a message but refuses to simulate:
    the round ends, the session goes on."""


# ------------------------------------------------------- java hash order


def java_string_hash(s: str) -> int:
    """Java's `String.hashCode` as a signed 32-bit int."""
    h = 0
    for ch in s.encode("utf-16-be").decode("utf-16-be"):
        h = (31 * h + ord(ch)) & 0xFFFFFFFF
    return h - (1 << 32) if h & 0x80000000 else h


def _pvar_hash(name: str) -> int:
    # rddlsim's PVAR_NAME hashes its canonical name: '-' as '_', lower case.
    return java_string_hash(name.replace("-", "_").lower())


def _bucket(h: int, capacity: int) -> int:
    u = h & 0xFFFFFFFF
    return (u ^ (u >> 16)) & (capacity - 1)


def _capacity(n: int) -> int:
    # java.util.HashMap with the default capacity 16 and load factor 0.75,
    # doubling whenever the size passes the threshold.
    cap = 16
    while n > cap * 3 // 4:
        cap *= 2
    return cap


def _hashmap_order(names: Sequence[str]) -> list[str]:
    """The iteration order of a Java HashMap<PVAR_NAME, ...> into which
    `names` were put in this order (a bucket keeps insertion order)."""
    cap = _capacity(len(names))
    pos = {n: i for i, n in enumerate(names)}
    return sorted(names, key=lambda n: (_bucket(_pvar_hash(n), cap), pos[n]))


def rddlsim_order(model: Model, kind: str) -> list[PVariable]:
    """The pvariables of `kind` in the order rddlsim's server lists them.

    rddlsim's State puts each kind's fluents into its own HashMap while
    iterating over the domain's HashMap of all pvariables (filled in
    declaration order), so the order is: bucket in the small map, then
    bucket in the big map, then declaration order.
    """
    declared = [p.name for p in model.pvariables.values()]
    all_order = _hashmap_order(declared)
    of_kind = [n for n in all_order if model.pvariables[n].kind == kind]
    return [model.pvariables[n] for n in _hashmap_order(of_kind)]


def rddlsim_action_order(model: Model) -> list[PVariable]:
    """The action fluents in the order rddlsim's `State._alActionNames`
    holds them (and its random policy tries them): the iteration order of
    the domain's HashMap of all pvariables, filtered to the actions (a
    plain list, without the second HashMap of `rddlsim_order`)."""
    declared = [p.name for p in model.pvariables.values()]
    return [
        model.pvariables[n] for n in _hashmap_order(declared) if model.pvariables[n].kind == ACTION
    ]


def partially_observed(model: Model) -> bool:
    """Whether rddlsim serves observations rather than states: the domain
    declares the `partially-observed` requirement (as rddlsim decides)."""
    return "partially-observed" in (model.domain.requirements or ())


def value_kind(model: Model, p: PVariable) -> str:
    """How a wire value of `p` is parsed: bool, int, real, enum or object."""
    if p.range in ("bool", "int", "real"):
        return p.range
    info = model.types.get(p.range)
    return "enum" if info is not None and info.kind == "enum" else "object"


# ------------------------------------------------------------ encoder


@dataclass(frozen=True)
class _Layout:
    pvar: PVariable
    args: tuple[tuple[str, ...], ...]  # every grounding, last argument fastest
    labels: tuple[str, ...] | None  # enum/object members by code


class WireCodec:
    """Fast conversions for one simulator, built once per instance."""

    def __init__(self, sim: Simulator):
        self.sim = sim
        model = sim.model
        self.model = model
        self.pomdp = partially_observed(model)
        self._state = [self._layout(p) for p in rddlsim_order(model, STATE)]
        self._observ = [self._layout(p) for p in rddlsim_order(model, OBSERV)]
        self._by_name = {p.name: p for p in model.pvariables.values()}
        self._noop1 = sim.noop(1)
        for a in self._noop1.values():
            a.flags.writeable = False  # shared by every noop turn

    def _layout(self, p: PVariable) -> _Layout:
        args = tuple(names for names, _ in self.sim._ground(p))
        labels = self.model.types[p.range].members if p.range in self.model.types else None
        return _Layout(p, args, labels)

    # -- server side: tensors -> wire

    def _listing(
        self, layouts: list[_Layout], values: Mapping[str, np.ndarray], index: int
    ) -> list[WireFluent]:
        out: list[WireFluent] = []
        for lay in layouts:
            flat = np.asarray(values[lay.pvar.name][index]).reshape(-1).tolist()
            if lay.labels is not None:
                labels = lay.labels
                flat = [labels[int(v)] if 0 <= int(v) < len(labels) else "" for v in flat]
            elif lay.pvar.range == "real":
                flat = [float(v) for v in flat]
            out.extend((lay.pvar.name, a, v) for a, v in zip(lay.args, flat, strict=True))
        return out

    def state(self, state: State, index: int = 0) -> list[WireFluent]:
        """Every grounding of every state fluent, in rddlsim's order."""
        return self._listing(self._state, state.values, index)

    def observation(
        self, observation: Mapping[str, np.ndarray], index: int = 0
    ) -> list[WireFluent]:
        """Every grounding of every observ fluent, in rddlsim's order."""
        return self._listing(self._observ, observation, index)

    def turn_fluents(
        self, state: State, observation: Mapping[str, np.ndarray] | None, index: int = 0
    ) -> list[WireFluent] | None:
        """What a turn carries: the state (MDP), the observation (POMDP), or
        None for a POMDP's first turn (`<no-observed-fluents/>`)."""
        if not self.pomdp:
            return self.state(state, index)
        if observation is None:
            return None
        return self.observation(observation, index)

    def actions(self, actions: Mapping[str, np.ndarray], index: int = 0) -> list[WireFluent]:
        """The actions at `index` that differ from their default."""
        out: list[WireFluent] = []
        for p in self.sim.action_fluents:
            a = actions.get(p.name)
            if a is None:
                continue
            arr = np.asarray(a)[index]
            default = self.sim._defaults[p.name]
            diff = np.argwhere(arr != default)
            for idx in diff:
                t = tuple(int(i) for i in idx)
                args = tuple(
                    self.model.types[ty].members[i] for ty, i in zip(p.params, t, strict=True)
                )
                out.append((p.name, args, self.sim._decode(p, arr[t])))
        return out

    # -- both sides: wire -> tensors

    def _index(self, p: PVariable, args: tuple[str, ...]) -> tuple[int, ...] | None:
        """Tensor index of a grounding, None when rddlsim would store it
        without effect (wrong arity, unknown object)."""
        if len(args) != p.arity:
            return None
        codes = self.sim._compiler.codes
        idx = []
        for t, a in zip(p.params, args, strict=True):
            a = a if a.startswith("@") else a.removeprefix("$")
            code = codes[t].get(a)
            if code is None:
                return None
            idx.append(code)
        return tuple(idx)

    def _code(self, p: PVariable, value: Value) -> Value:
        codes = self.sim._compiler.codes
        if p.range in codes:
            text = str(value)
            if not text.startswith("@") and value_kind(self.model, p) == "object":
                text = text.removeprefix("$")
            # rddlsim accepts enum values outside the enum; they match nothing.
            return codes[p.range].get(text, -1)
        if p.range == "bool":
            return bool(value)
        if p.range == "int":
            return int(value)
        return float(value)

    def state_from(self, fluents: Iterable[WireFluent]) -> State:
        """A batch-1 state from typed wire fluents; fluents not listed keep
        the instance's initial value."""
        state = self.sim.initial_state(1)
        self._fill(state.values, fluents, STATE, "a state fluent")
        return state

    def observation_from(self, fluents: Iterable[WireFluent]) -> dict[str, np.ndarray]:
        """Batch-1 observ-fluent arrays (defaults where not listed)."""
        out = {p.name: self.sim._default_array(p)[None].copy() for p in self.sim.observ_fluents}
        self._fill(out, fluents, OBSERV, "an observ fluent")
        return out

    def _fill(
        self, arrays: dict[str, np.ndarray], fluents: Iterable[WireFluent], kind: str, what: str
    ) -> None:
        """Write typed wire fluents of `kind` into batch-1 `arrays`."""
        for name, args, value in fluents:
            p = self._by_name.get(name)
            if p is None or p.kind != kind:
                raise WireError(f"'{name}' is not {what} of {self.model.name}")
            idx = self._index(p, tuple(args))
            if idx is None:
                raise WireError(f"'{name}({','.join(args)})': unknown grounding")
            arrays[name][(0, *idx)] = self._code(p, value)

    def actions_from(self, fluents: Iterable[WireFluent]) -> DecodedActions:
        """Batch-1 action arrays from typed wire actions, as rddlsim's server
        reads them: an unknown name, or a non-action fluent sent with its
        default value (rddlsim exits there), is a `WireError`; a grounding with the
        wrong arity or an unknown object is stored without effect but counts
        toward max-nondef-actions when its value is not the default; a
        state fluent sent as an action with a non-default value makes the
        actions illegal."""
        fluents = list(fluents)
        if not fluents:
            return DecodedActions(self._noop1, 0, (), (), 0)
        arrays = self.sim.noop(1)
        extra = 0
        ignored: list[str] = []
        illegal: list[str] = []
        changed: dict[tuple[str, tuple[int, ...]], bool] = {}
        for name, args, value in fluents:
            args = tuple(args)
            p = self._by_name.get(name)
            if p is None:
                raise WireError(f"unknown action '{name}'")
            shown = f"{name}({','.join(args)})={value}"
            if p.kind != ACTION:
                if self._code(p, value) != self._code(p, self.model.default_of(p)):
                    illegal.append(f"{shown}: '{name}' is a {p.kind}, not an action")
                    continue
                # rddlsim's server process exits here; we end the session.
                raise WireError(f"{shown}: '{name}' is a {p.kind}, not an action")
            code = self._code(p, value)
            idx = self._index(p, args)
            default = self._code(p, self.model.default_of(p))
            if idx is None:
                ignored.append(f"{shown}: no such grounding, no effect")
                if code != default:
                    extra += 1
                continue
            arrays[name][(0, *idx)] = code
            changed[(name, idx)] = code != default  # the last value sent for a grounding wins
        nondefault = sum(changed.values()) + extra
        return DecodedActions(arrays, extra, tuple(ignored), tuple(illegal), nondefault)

    def check(self, state: State, decoded: DecodedActions) -> str | None:
        """Why the actions are illegal in `state` (max-nondef-actions,
        preconditions, state-action constraints), or None when legal."""
        if decoded.illegal:
            return decoded.illegal[0]
        limit = self.model.max_nondef_actions
        if limit is not None:
            n = decoded.nondefault
            if n > limit:
                return f"{n} actions differ from their default, max-nondef-actions is {limit}"
        if not self.sim._preconditions:
            return None
        try:
            self.sim._check_preconditions(state, decoded.arrays)
        except SimulationError as err:
            return str(err)
        return None


@dataclass(frozen=True)
class DecodedActions:
    """Received actions as arrays, plus what rddlsim would count or refuse."""

    arrays: dict[str, np.ndarray]
    extra_nondefault: int  # groundings without effect that still count
    ignored: tuple[str, ...]  # what was received but has no effect
    illegal: tuple[str, ...]  # why the actions cannot be simulated at all
    nondefault: int = 0  # groundings that differ from their default, as max-nondef-actions counts
