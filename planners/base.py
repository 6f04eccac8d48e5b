"""The planner interface, planner options and the planner registry.

Two kinds of planners play an IPPC session:

* `Planner`: driven turn by turn by `ippc.client`. The client decodes every
  turn into an `Observation` and sends back what `act` returns: the action
  fluents that differ from their default, as wire fluents `(name, args, value)`.
* `ExternalPlanner`: a program that connects to the server by itself (PROST).
  The client only starts it, waits for it and reports what it printed.

Planners are found by name (`find_planner`): every entry point in the group
`ippc.planners` (ippc's own built-ins are declared there too, so a third-party
package plugs in the same way), with the built-ins as a fallback when the
package metadata is missing (a source checkout that was never installed).

Options come from the command line as strings (`--planner-option KEY=VALUE`).
A planner declares the keys it takes in `options` (key -> one-line help); the
base class refuses unknown keys and offers typed readers (`int_option`,
`float_option`, `bool_option`, ...) that turn a bad value into a
`PlannerError` naming the planner, the key and what was expected.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import logging
import threading
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from ..rddl.model import Model, Value
from ..rddl.simulator import Simulator, State

log = logging.getLogger(__name__)

WireFluent = tuple[str, tuple[str, ...], Value]
"""(pvariable name, object or enum arguments, typed value), as on the wire."""

ENTRY_POINT_GROUP = "ippc.planners"

# The built-ins by name, used when the installed package metadata does not
# list them (an uninstalled checkout) and as the reference for duplicates.
BUILTIN_PLANNERS: dict[str, str] = {
    "noop": "ippc.planners.basic:NoopPlanner",
    "random": "ippc.planners.basic:RandomPlanner",
    "uniform": "ippc.planners.basic:UniformPlanner",
    "prost": "ippc.planners.prost:ProstPlanner",
    "mcts": "ippc.planners.mcts:MCTSPlanner",
    "replan": "ippc.planners.replan:ReplanPlanner",
    "exact": "ippc.planners.exact:ExactPlanner",
    "mpc": "ippc.planners.mpc:MPCPlanner",
}


class PlannerError(Exception):
    """A planner cannot be found, configured or run: an unknown name, a bad
    option, a missing or broken external binary."""


@dataclass(frozen=True)
class SessionInfo:
    """What a planner learns at the start of a session."""

    instance: str
    model: Model  # decoded from the task, or loaded from --rddl
    simulator: Simulator  # compiled once by the client, shared with the planner
    rounds: int
    time_allowed: float  # seconds (the server's time-allowed / 1000)
    seed: int | None  # --seed, for reproducible planners


@dataclass(frozen=True)
class Observation:
    """One turn as the planner sees it."""

    fluents: dict[tuple[str, tuple[str, ...]], Value] | None  # None: POMDP first turn
    state: State | None  # batch-1 simulator state (MDPs); None for POMDPs
    turn: int  # 1-based turn in the round
    steps_left: int  # horizon - turn + 1
    time_left: float  # seconds, as the server said in this turn
    immediate_reward: float  # reward of the previous transition (0.0 in turn 1)
    deadline: float  # time.monotonic() value by which act() should return


# ------------------------------------------------------------------ options


def _describe(cls: type) -> str:
    return getattr(cls, "name", cls.__name__)


def _parse_int(value: str) -> int:
    return int(value.strip(), 10)


def _parse_float(value: str) -> float:
    number = float(value.strip())
    if number != number:  # NaN is never a useful setting
        raise ValueError(value)
    return number


_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def _parse_bool(value: str) -> bool:
    text = value.strip().lower()
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    raise ValueError(value)


class _Configurable:
    """Option handling shared by `Planner` and `ExternalPlanner`."""

    name: ClassVar[str]
    options: ClassVar[dict[str, str]] = {}

    def __init__(self, **options: str) -> None:
        # '-' and '_' are the same in keys, so `--planner-option log-file=x`
        # and `log_file=x` both work.
        given: dict[str, str] = {}
        for key, value in options.items():
            norm = key.strip().replace("-", "_")
            if norm not in self.options:
                valid = ", ".join(sorted(self.options)) or "none"
                raise PlannerError(
                    f"planner '{_describe(type(self))}' has no option '{key}' (valid options: {valid})"
                )
            if not isinstance(value, str):
                raise PlannerError(
                    f"planner '{_describe(type(self))}': option '{norm}' must be given as a string, "
                    f"got {type(value).__name__}"
                )
            given[norm] = value
        self.option_values: dict[str, str] = given
        """The options as given (normalised keys, string values)."""

    def _given(self, key: str) -> bool:
        if key not in self.options:  # a typo in the planner, not the user's fault
            raise KeyError(f"{type(self).__name__} reads option '{key}' but does not declare it")
        return key in self.option_values

    def _option_error(self, key: str, value: str, expected: str) -> PlannerError:
        return PlannerError(
            f"planner '{_describe(type(self))}': option '{key}' must be {expected}, got '{value}'"
        )

    def str_option(self, key: str, default: str | None = None) -> str | None:
        """The option's text, or `default` when it was not given."""
        return self.option_values[key] if self._given(key) else default

    def int_option(
        self, key: str, default: int | None = None, minimum: int | None = None
    ) -> int | None:
        """The option as an integer (at least `minimum`), or `default`."""
        if not self._given(key):
            return default
        text = self.option_values[key]
        try:
            number = _parse_int(text)
        except ValueError:
            raise self._option_error(key, text, "an integer") from None
        if minimum is not None and number < minimum:
            raise self._option_error(key, text, f"an integer >= {minimum}")
        return number

    def float_option(
        self, key: str, default: float | None = None, minimum: float | None = None
    ) -> float | None:
        """The option as a number (at least `minimum`), or `default`."""
        if not self._given(key):
            return default
        text = self.option_values[key]
        try:
            number = _parse_float(text)
        except ValueError:
            raise self._option_error(key, text, "a number") from None
        if minimum is not None and number < minimum:
            raise self._option_error(key, text, f"a number >= {minimum:g}")
        return number

    def bool_option(self, key: str, default: bool) -> bool:
        """The option as a yes/no flag (1/0, true/false, yes/no, on/off)."""
        if not self._given(key):
            return default
        text = self.option_values[key]
        try:
            return _parse_bool(text)
        except ValueError:
            raise self._option_error(key, text, "one of true/false, yes/no, on/off, 1/0") from None

    def path_option(self, key: str, default: Path | None = None) -> Path | None:
        """The option as a path (`~` expanded), or `default`."""
        if not self._given(key):
            return default
        text = self.option_values[key]
        if not text.strip():
            raise self._option_error(key, text, "a path")
        return Path(text.strip()).expanduser()


# ----------------------------------------------------------------- planners


class Planner(_Configurable, ABC):
    """A planner that the client drives turn by turn.

    Subclasses set `name`, declare their `options` (key -> one-line help) and
    implement `act`; the other hooks are optional. Every option value arrives
    as a string; unknown keys raise `PlannerError` naming the valid ones.
    """

    name: ClassVar[str]
    options: ClassVar[dict[str, str]] = {}
    external: ClassVar[bool] = False

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self.session: SessionInfo | None = None
        """The current session (set by `start_session`)."""

    def start_session(self, session: SessionInfo) -> None:
        """A session starts: the model, its compiled simulator, the number of
        rounds and the time budget. Subclasses that override this should
        call `super().start_session(session)`."""
        self.session = session

    def start_round(self, round_num: int) -> None:
        """Round `round_num` (1-based) starts."""

    @abstractmethod
    def act(self, obs: Observation) -> list[WireFluent]:
        """The actions for this turn: every action fluent grounding whose
        value differs from its default (`[]` is noop)."""

    def end_round(self, reward: float) -> None:
        """The round ended with this total reward (as the server counted it)."""

    def end_session(self, total_reward: float) -> None:
        """The session ended with this total reward."""


@dataclass(frozen=True)
class ExternalResult:
    """What an external planner's run produced."""

    exit_code: int  # the process's exit status; negative: killed by that signal
    rounds: list[float]  # round rewards as the planner reported them
    total_reward: float | None  # the session total as the planner reported it
    seconds: float  # wall time from launch to end
    log_path: Path | None  # where its stdout and stderr went
    error: str | None  # why the run failed; None when it finished cleanly

    @property
    def ok(self) -> bool:
        """The run finished cleanly (no error)."""
        return self.error is None


class ExternalPlanner(_Configurable, ABC):
    """A planner program that connects to the server itself.

    `run_session` blocks until the program is done (or the timeout passes)
    and never leaves a process behind. `cancel` may be called from another
    thread (the client runs `run_session` in a worker thread) to stop it
    early.
    """

    name: ClassVar[str]
    options: ClassVar[dict[str, str]] = {}
    external: ClassVar[bool] = True

    def __init__(self, **options: str) -> None:
        super().__init__(**options)
        self._cancelled = threading.Event()

    def cancel(self) -> None:
        """Ask a running `run_session` (in another thread) to stop the
        program now; it returns an `ExternalResult` with an error."""
        self._cancelled.set()

    @abstractmethod
    def run_session(
        self,
        *,
        host: str,
        port: int,
        instance: str,
        client_name: str | None,
        timeout: float | None,
        log_path: Path | None,
    ) -> ExternalResult:
        """Play one whole session against the server at host:port."""


# ----------------------------------------------------------------- registry


def _entry_points() -> dict[str, list[Any]]:
    """Entry points of the group by name (several packages may claim one)."""
    try:
        found = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    except Exception as err:  # broken metadata must not hide the built-ins
        log.warning("cannot read entry points of group %s: %s", ENTRY_POINT_GROUP, err)
        return {}
    out: dict[str, list[Any]] = {}
    for ep in found:
        out.setdefault(ep.name, []).append(ep)
    return out


def planner_names() -> list[str]:
    """Every planner name that `find_planner` knows, sorted."""
    return sorted(set(BUILTIN_PLANNERS) | set(_entry_points()))


def _load_target(target: str) -> Any:
    module_name, _, attr = target.partition(":")
    obj: Any = importlib.import_module(module_name)
    for part in attr.split(".") if attr else ():
        obj = getattr(obj, part)
    return obj


def _check_planner_class(name: str, where: str, obj: Any) -> type[Planner] | type[ExternalPlanner]:
    if isinstance(obj, type) and issubclass(obj, (Planner, ExternalPlanner)):
        return obj
    raise PlannerError(
        f"planner '{name}' ({where}) is not a Planner or ExternalPlanner subclass: {obj!r}"
    )


def find_planner(name: str) -> type[Planner] | type[ExternalPlanner]:
    """The planner class registered under `name`.

    Entry points of the group `ippc.planners` come first; when several
    packages claim the same name, ippc's own declaration wins for the
    built-in names and the first one otherwise (with a warning). Raises
    `PlannerError` listing the known names for an unknown one, and naming
    the entry point when it cannot be loaded.
    """
    eps = _entry_points().get(name, [])
    if eps:
        chosen = eps[0]
        if len(eps) > 1:
            own = [ep for ep in eps if ep.value == BUILTIN_PLANNERS.get(name)]
            chosen = own[0] if own else eps[0]
            log.warning(
                "planner name '%s' is declared by %d entry points (%s); using %s",
                name,
                len(eps),
                ", ".join(ep.value for ep in eps),
                chosen.value,
            )
        try:
            obj = chosen.load()
        except Exception as err:
            raise PlannerError(
                f"planner '{name}': entry point '{chosen.value}' cannot be loaded: "
                f"{type(err).__name__}: {err}"
            ) from err
        return _check_planner_class(name, f"entry point '{chosen.value}'", obj)
    if name in BUILTIN_PLANNERS:
        target = BUILTIN_PLANNERS[name]
        try:
            obj = _load_target(target)
        except Exception as err:
            raise PlannerError(
                f"built-in planner '{name}' ({target}) cannot be loaded: {err}"
            ) from err
        return _check_planner_class(name, target, obj)
    raise PlannerError(f"unknown planner '{name}' (known planners: {', '.join(planner_names())})")


def make_planner(name: str, options: Mapping[str, str]) -> Planner | ExternalPlanner:
    """An instance of the planner `name`, configured with string options."""
    cls = find_planner(name)
    return cls(**dict(options))
