"""The sensing config: which fluents are sensed, from which stream, how.

In ROSPlan's terms (its sensing interface's YAML), a config maps each
sensed predicate or function to where its value comes from::

    rate: 10                         # batches sent to the knowledge base per second
    sensors:
      robot_at:                      # a state fluent of the domain
        stream: odometry             # the sensor stream it reads (one name or a list)
        params: [kenny, '*']         # a fixed object, or '*' (filled from the message)
        value: "{msg.waypoint: True}"
      battery_low:
        stream: battery
        params: [kenny]
        value: msg.percent < 20      # one line over the message `msg`

Each parameter is an object name (fixed; it must be an object of the
parameter's type), a wildcard `'*'` (or `'_'`), or `{msg: EXPR}`, an
expression that gives the object from the message. With no wildcard the
value expression gives the fluent's value; with wildcards it gives the
values of several groundings at once, as a mapping (or a list of pairs)
from the wildcards' objects (one name, `"a:b"` for two, or a tuple) to
values. `params` left out means every parameter is a wildcard. A fluent may
have a list of such entries (several sources). `infinite: true` lets a real
fluent's entry give +-infinity (refused otherwise, as NaN always is).

Expressions run in the restricted evaluator of `ippc.dispatch.expr`. The
loader checks everything against the model: an unknown fluent, a
non-fluent, a wrong number of parameters, an object not of the type, an
expression that is not allowed, an unknown key; each error names the file,
line and column, and all of them are reported at once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..rddl.model import STATE, Model
from .expr import Expression, ExpressionError, compile_expression

__all__ = ["WILDCARDS", "ParamSpec", "SensingConfig", "SensingConfigError", "SensorSpec"]

WILDCARDS = ("*", "_")
DEFAULT_RATE = 10.0


class SensingConfigError(ValueError):
    """A config that cannot be used; `problems` lists `file:line:col: reason`."""

    def __init__(self, problems: Sequence[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a sensed fluent: fixed, wildcard or from the message."""

    kind: str  # "fixed" | "wildcard" | "message"
    type: str  # the parameter's type
    name: str | None = None  # for "fixed"
    expr: Expression | None = None  # for "message"


@dataclass(frozen=True)
class SensorSpec:
    """How one stream's messages give the values of one sensed fluent."""

    fluent: str
    streams: tuple[str, ...]
    params: tuple[ParamSpec, ...]
    value: Expression
    where: str  # "file:line:col" of the entry, for run-time messages
    infinite: bool = False  # a real fluent may be sensed as +-infinity

    @property
    def wildcards(self) -> tuple[int, ...]:
        """Positions of the wildcard parameters."""
        return tuple(i for i, p in enumerate(self.params) if p.kind == "wildcard")


@dataclass(frozen=True)
class SensingConfig:
    """A checked sensing config."""

    sensors: tuple[SensorSpec, ...]
    rate: float = DEFAULT_RATE
    source: str = "<config>"

    def fluents(self) -> frozenset[str]:
        """The sensed fluents."""
        return frozenset(s.fluent for s in self.sensors)

    def streams(self) -> frozenset[str]:
        """Every stream some sensor reads."""
        return frozenset(name for s in self.sensors for name in s.streams)

    @classmethod
    def load(cls, path: str | Path, model: Model) -> SensingConfig:
        """Read and check the YAML file at `path`."""
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as err:
            raise SensingConfigError([f"{path}: cannot read the sensing config: {err}"]) from None
        return cls.loads(text, model, str(path))

    @classmethod
    def loads(cls, text: str, model: Model, source: str = "<config>") -> SensingConfig:
        """Check YAML text (`source` names it in errors)."""
        try:
            import yaml
        except ImportError:  # pragma: no cover - pyyaml is in the robot extra
            raise SensingConfigError(
                [f"{source}: reading a YAML config needs pyyaml: pip install 'ippc[robot]'"]
            ) from None
        try:
            node = yaml.compose(text, Loader=yaml.SafeLoader)
        except yaml.YAMLError as err:
            mark = getattr(err, "problem_mark", None)
            where = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark else source
            problem = getattr(err, "problem", None) or str(err)
            raise SensingConfigError([f"{where}: not valid YAML: {problem}"]) from None
        if node is None:
            raise SensingConfigError([f"{source}: the sensing config is empty"])
        return _Loader(source, model).config(_Node.of(node, source))

    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], model: Model, source: str = "<dict>"
    ) -> SensingConfig:
        """Check a config given as Python data (the YAML's shape)."""
        return _Loader(source, model).config(_Node.plain(data, source))


class _Node:
    """A YAML node (or a plain value) with its position."""

    __slots__ = ("value", "line", "column", "source", "plain_text")

    def __init__(self, value: Any, line: int, column: int, source: str, plain_text: bool = False):
        self.value = value  # dict of _Node -> _Node, list of _Node, or a scalar
        self.line = line
        self.column = column
        self.source = source
        self.plain_text = plain_text  # a plain one-line scalar: columns map into the file

    @property
    def where(self) -> str:
        if self.line <= 0:
            return self.source
        return f"{self.source}:{self.line}:{self.column}"

    @classmethod
    def of(cls, node: Any, source: str) -> _Node:
        import yaml

        line, column = node.start_mark.line + 1, node.start_mark.column + 1
        if isinstance(node, yaml.MappingNode):
            return cls(
                {cls.of(k, source): cls.of(v, source) for k, v in node.value}, line, column, source
            )
        if isinstance(node, yaml.SequenceNode):
            return cls([cls.of(v, source) for v in node.value], line, column, source)
        value = yaml.SafeLoader("").construct_object(node)
        plain = node.style is None and node.start_mark.line == node.end_mark.line
        return cls(value, line, column, source, plain)

    @classmethod
    def plain(cls, data: Any, source: str) -> _Node:
        if isinstance(data, Mapping):
            return cls(
                {cls.plain(k, source): cls.plain(v, source) for k, v in data.items()}, 0, 0, source
            )
        if isinstance(data, list | tuple):
            return cls([cls.plain(v, source) for v in data], 0, 0, source)
        return cls(data, 0, 0, source)

    def get(self, key: str) -> _Node | None:
        assert isinstance(self.value, dict)
        for k, v in self.value.items():
            if k.value == key:
                return v
        return None


class _Loader:
    def __init__(self, source: str, model: Model):
        self.source = source
        self.model = model
        self.problems: list[str] = []

    def problem(self, node: _Node, reason: str) -> None:
        self.problems.append(f"{node.where}: {reason}")

    def config(self, root: _Node) -> SensingConfig:
        if root.value is None:
            raise SensingConfigError([f"{self.source}: the sensing config is empty"])
        if not isinstance(root.value, dict):
            raise SensingConfigError(
                [f"{root.where}: a sensing config is a mapping with 'sensors' (and 'rate')"]
            )
        rate = DEFAULT_RATE
        sensors: list[SensorSpec] = []
        seen_sensors = False
        for key, value in root.value.items():
            if key.value == "rate":
                if (
                    isinstance(value.value, bool)
                    or not isinstance(value.value, int | float)
                    or not value.value > 0
                ):
                    self.problem(
                        value,
                        f"rate must be a positive number (batches per second), not {value.value!r}",
                    )
                else:
                    rate = float(value.value)
            elif key.value in ("sensors", "topics"):  # topics: ROSPlan's name
                seen_sensors = True
                sensors.extend(self.sensors(value))
            else:
                self.problem(key, f"unknown key {key.value!r} (known: rate, sensors)")
        if not seen_sensors:
            self.problem(root, "no 'sensors' mapping (sensed fluent -> stream, params, value)")
        if self.problems:
            raise SensingConfigError(self.problems)
        return SensingConfig(tuple(sensors), rate, self.source)

    def sensors(self, node: _Node) -> list[SensorSpec]:
        if not isinstance(node.value, dict):
            self.problem(node, "'sensors' must map each sensed fluent to its source")
            return []
        out: list[SensorSpec] = []
        for name_node, entry in node.value.items():
            name = name_node.value
            p = self.model.pvariables.get(str(name))
            if p is None:
                self.problem(
                    name_node, f"{name!r} is not a fluent of domain {self.model.domain_name}"
                )
                continue
            if p.kind != STATE:
                self.problem(name_node, f"{name!r} is a {p.kind}; only state fluents are sensed")
                continue
            entries = entry.value if isinstance(entry.value, list) else [entry]
            if not entries:
                self.problem(entry, f"{name}: an empty list of sources")
            for e in entries:
                spec = self.sensor(str(name), e)
                if spec is not None:
                    out.append(spec)
        return out

    def sensor(self, fluent: str, node: _Node) -> SensorSpec | None:
        if not isinstance(node.value, dict):
            self.problem(node, f"{fluent}: expected a mapping with stream, params and value")
            return None
        ok = True
        for key in node.value:
            if key.value not in (
                "stream",
                "streams",
                "topic",
                "params",
                "value",
                "operation",
                "infinite",
            ):
                self.problem(
                    key,
                    f"{fluent}: unknown key {key.value!r} (known: stream, params, value, infinite)",
                )
                ok = False
        infinite = False
        inf_node = node.get("infinite")
        if inf_node is not None:
            if not isinstance(inf_node.value, bool):
                self.problem(
                    inf_node, f"{fluent}: infinite is true or false, not {inf_node.value!r}"
                )
                ok = False
            elif inf_node.value and self.model.pvariables[fluent].range != "real":
                self.problem(
                    inf_node,
                    f"{fluent}: infinite: true, but {fluent} is "
                    f"{self.model.pvariables[fluent].range}: only a real fluent holds infinity",
                )
                ok = False
            else:
                infinite = inf_node.value
        stream_node = node.get("stream") or node.get("streams") or node.get("topic")
        streams: tuple[str, ...] = ()
        if stream_node is None:
            self.problem(node, f"{fluent}: no 'stream' (the sensor stream it reads)")
            ok = False
        else:
            raw = stream_node.value
            items = raw if isinstance(raw, list) else [stream_node]
            names = [i.value for i in items]
            if not names or not all(isinstance(n, str) and n.strip() for n in names):
                self.problem(stream_node, f"{fluent}: a stream is a name or a list of names")
                ok = False
            else:
                streams = tuple(n.strip() for n in names)
        params = self.params(fluent, node.get("params"), node)
        if params is None:
            ok = False
        value_node = node.get("value") or node.get("operation")
        if value_node is None:
            self.problem(node, f"{fluent}: no 'value' (an expression over the message msg)")
            return None
        value = self.expression(fluent, "value", value_node)
        if value is None or not ok or params is None:
            return None
        return SensorSpec(fluent, streams, params, value, node.where, infinite)

    def params(self, fluent: str, node: _Node | None, entry: _Node) -> tuple[ParamSpec, ...] | None:
        p = self.model.pvariables[fluent]
        if node is None:
            return tuple(ParamSpec("wildcard", t) for t in p.params)
        items = node.value if isinstance(node.value, list) else None
        if items is None:
            self.problem(node, f"{fluent}: params is a list (one entry per parameter)")
            return None
        if len(items) != p.arity:
            self.problem(
                node,
                f"{fluent} has {p.arity} parameter(s) ({', '.join(p.params) or 'none'}), "
                f"params lists {len(items)}",
            )
            return None
        out: list[ParamSpec] = []
        good = True
        for item, type_name in zip(items, p.params, strict=True):
            if isinstance(item.value, dict):
                expr_node = item.get("msg")
                if expr_node is None or len(item.value) != 1:
                    self.problem(item, f"{fluent}: a parameter from the message is {{msg: EXPR}}")
                    good = False
                    continue
                expr = self.expression(fluent, "parameter", expr_node)
                if expr is None:
                    good = False
                    continue
                out.append(ParamSpec("message", type_name, expr=expr))
            elif isinstance(item.value, str) and item.value in WILDCARDS:
                out.append(ParamSpec("wildcard", type_name))
            elif isinstance(item.value, str):
                if item.value not in self.model.objects(type_name):
                    self.problem(
                        item, f"{fluent}: {item.value!r} is not an object of type {type_name}"
                    )
                    good = False
                    continue
                out.append(ParamSpec("fixed", type_name, name=item.value))
            else:
                self.problem(item, f"{fluent}: a parameter is an object name, '*' or {{msg: EXPR}}")
                good = False
        return tuple(out) if good else None

    def expression(self, fluent: str, what: str, node: _Node) -> Expression | None:
        text = node.value
        if isinstance(text, bool | int | float):
            text = repr(text)  # a constant value (YAML read `true` as a bool)
        if not isinstance(text, str):
            self.problem(node, f"{fluent}: the {what} is a one-line expression over msg")
            return None
        try:
            return compile_expression(text, ("msg",))
        except ExpressionError as err:
            where = node.where
            if node.plain_text and node.line > 0 and err.line == 1:
                # a plain scalar: the expression's column is a column of the file
                where = f"{node.source}:{node.line}:{node.column + err.column - 1}"
            text = err.text if len(err.text) <= 120 else err.text[:100] + " ..."
            self.problems.append(f"{where}: {fluent}: {what} {err.reason}: {text!r}")
            return None
