"""The robot's side of a run: what a robot file wires up (`Robot`,
`load_robot_file`, `build_robot`) and the simulated world's wiring
(`build_simulation`), for `ippc.dispatch.run`."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..kb import KnowledgeBase
from .actions import Handlers
from .clock import Clock, WallClock
from .config import SensingConfig
from .dispatcher import Dispatcher
from .sensing import Sensing
from .world import PerAction, SimulatedWorld

__all__ = [
    "Robot",
    "RobotFileError",
    "build_robot",
    "build_simulation",
    "load_robot_file",
]


@dataclass
class Robot:
    """What a robot file's `setup(robot)` wires up: handlers by action name
    (`robot.handler("goto")` as a decorator, or `robot.handlers.register`),
    sensor sources (`robot.sensing.publisher(stream)`, or a task started with
    `robot.start_soon(fn, *args)` that feeds them), and the knowledge base."""

    kb: KnowledgeBase
    handlers: Handlers
    sensing: Sensing | None
    clock: Clock
    tasks: list[tuple[Callable[..., Awaitable[Any]], tuple[Any, ...]]] = field(default_factory=list)

    def handler(self, action: str) -> Callable[[Any], Any]:
        """Register the decorated async function as `action`'s handler."""

        def register(fn: Any) -> Any:
            self.handlers.register(action, fn)
            return fn

        return register

    def start_soon(self, fn: Callable[..., Awaitable[Any]], *args: Any) -> None:
        """Run `fn(*args)` while the dispatcher runs (a sensor source)."""
        self.tasks.append((fn, args))


class RobotFileError(ValueError):
    """A robot file that cannot be loaded; the message says why."""


def _place(path: Path, err: BaseException) -> str:
    """``file:line`` of the last frame of `err`'s traceback that is in the
    robot file (where its code went wrong), else the file's name."""
    import traceback

    target = str(path.resolve())
    line = None
    for frame in traceback.extract_tb(err.__traceback__):
        if frame.filename and str(Path(frame.filename).resolve()) == target:
            line = frame.lineno
    return f"{path}:{line}" if line is not None else str(path)


def load_robot_file(path: str | Path) -> Callable[[Robot], Any]:
    """The `setup(robot)` function of a Python file."""
    import importlib.util

    path = Path(path)
    spec = importlib.util.spec_from_file_location(f"ippc_robot_{path.stem}", path)
    if spec is None or spec.loader is None:
        raise RobotFileError(f"{path}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except FileNotFoundError:
        raise RobotFileError(f"{path}: no such file") from None
    except SyntaxError as err:
        where = f"{path}:{err.lineno or 1}:{err.offset or 1}"
        raise RobotFileError(f"{where}: SyntaxError: {err.msg}") from None
    except Exception as err:
        raise RobotFileError(f"{_place(path, err)}: {type(err).__name__}: {err}") from err
    setup = getattr(module, "setup", None)
    if not callable(setup):
        raise RobotFileError(f"{path}: defines no setup(robot) function")
    return setup  # type: ignore[no-any-return]


def build_robot(
    kb: KnowledgeBase,
    config: SensingConfig | None,
    *,
    robot_file: str | Path | None = None,
    action_timeout: float | None = 60.0,
    settle_limit: float = 2.0,
    stop_at_goal: bool = True,
) -> tuple[Robot, Dispatcher]:
    """A dispatcher on the wall clock with sensing from `config` and the
    handlers and sensor sources a robot file's `setup(robot)` registers."""
    clock = WallClock()
    sensing = Sensing(kb, config, clock=clock) if config is not None else None
    handlers = Handlers(clock=clock, timeout=action_timeout)
    robot = Robot(kb, handlers, sensing, clock)
    if robot_file is not None:
        setup = load_robot_file(robot_file)
        try:
            setup(robot)
        except Exception as err:
            where = _place(Path(robot_file), err)
            raise RobotFileError(f"{where}: setup failed: {type(err).__name__}: {err}") from err
    dispatcher = Dispatcher(
        kb, handlers, sensing, clock=clock, settle_limit=settle_limit, stop_at_goal=stop_at_goal
    )
    return robot, dispatcher


def build_simulation(
    kb: KnowledgeBase,
    seed: int = 0,
    *,
    durations: PerAction = 1.0,
    costs: PerAction | None = None,
    failures: Any = None,
    sensed: Any = None,
    exogenous: Any = None,
    observe: Any = None,
    action_timeout: float | None = 60.0,
    stop_at_goal: bool = True,
) -> tuple[SimulatedWorld, Dispatcher]:
    """The simulated world and a dispatcher wired to it (sensing reads the
    world's streams; the world's handlers execute every action)."""
    world = SimulatedWorld(
        kb.model,
        seed,
        sensed=sensed,
        durations=durations,
        costs=costs,
        failures=failures,
        exogenous=exogenous,
        observe=observe,
    )
    clock: Clock = world.clock
    sensing = Sensing(kb, world.sensing_config(), clock=clock)
    world.connect(sensing.feed)
    sensing.flush()  # what the sensors see at the start is known before the first turn
    handlers: Handlers = world.handlers(timeout=action_timeout)
    dispatcher = Dispatcher(kb, handlers, sensing, clock=clock, stop_at_goal=stop_at_goal)
    return world, dispatcher
