"""The simulated office of the print-fetching experiments.

`OfficeWorld` gives `ippc.dispatch`'s simulated world what the experiments
need beyond the model:

* what the world really does (`exogenous`): in experiments 1 to 3 each
  printer is "busy" or "free" and has "somebody" or "nobody" near it for the
  whole run, whatever the model's rates say; a busy printer is busy for one
  action only: the first step the robot spends at it (waiting there, or
  standing, or leaving) uses its busy period up, and afterwards it is free
  (the issue: "waiting there once, or leaving and coming back, finds it
  free"). In experiment 4 the world is the model's: both fluents are drawn
  from the paper's Table 1 every step.
* what the robot sees (`observe`): the people near it and the printer's
  status where it stands, every step, and nothing elsewhere. The knowledge
  base keeps what the robot last saw at the other waypoints (at the start the
  instance's optimistic guess: somebody at every printer, none busy).
* how long each action takes (`durations`), from the domain's own numbers:
  the distance over the robot's speed, the wait by its outcome in the state
  where it started (papers loaded, nobody to help, printer busy), the
  hand-over, and a minute for a step standing still.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ...dispatch.actions import GroundAction
from ...dispatch.world import SimulatedWorld
from ...rddl.model import NON_FLUENT, Model, Value
from ...rddl.simulator import State
from .office import Experiment

__all__ = ["SENSED", "OfficeWorld", "non_fluent"]

#: the fluents the robot senses (the rest the dispatcher knows from the model)
SENSED = ("somebody_at", "is_busy")


def non_fluent(model: Model, name: str, args: tuple[str, ...] = ()) -> float:
    """A numeric non-fluent of the instance (its default when not set)."""
    p = model.pvariables[name]
    if p.kind != NON_FLUENT:
        raise KeyError(f"{name} is not a non-fluent")
    value = model.non_fluent_values.get((name, args), model.default_of(p))
    return float(value)  # type: ignore[arg-type]


@dataclass
class OfficeWorld:
    """The world of one run of one experiment (build a new one per run)."""

    experiment: Experiment
    model: Model
    #: busy printers whose one busy action is over
    spent: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        self.points = self.model.objects("waypoint")
        self.robot = self.model.objects("robot")[0]

    # -- positions

    def where(self, state: State) -> str:
        """The robot's waypoint in `state`."""
        row = np.asarray(state.values["robot_at"][0, 0])
        return self.points[int(np.flatnonzero(row)[0])]

    def _at(self, state: State, fluent: str, w: str) -> bool:
        return bool(state.values[fluent][0, self.points.index(w)])

    # -- the hooks of ippc.dispatch's SimulatedWorld

    def exogenous(
        self,
        world: SimulatedWorld,
        before: State | None,
        after: State,
        actions: list[GroundAction],
    ) -> State:
        """The true next state: the experiment's printers (or the model's draws)."""
        printers = self.experiment.world
        if printers is None:
            return after
        if before is not None:
            here = self.where(before)
            if here in printers and printers[here].busy:
                self.spent.add(here)
        values = {k: v.copy() for k, v in after.values.items()}
        for p, what in printers.items():
            i = self.points.index(p)
            values["somebody_at"][0, i] = what.somebody
            values["is_busy"][0, i] = what.busy and p not in self.spent
        return State(values)

    def observe(
        self, world: SimulatedWorld, state: State
    ) -> Mapping[str, Mapping[tuple[str, ...], Value]]:
        """What the robot sees: both fluents where it stands."""
        here = self.where(state)
        return {fluent: {(here,): self._at(state, fluent, here)} for fluent in SENSED}

    def duration(self, action: GroundAction, world: SimulatedWorld) -> float:
        """Simulated seconds of one action (the domain's costs)."""
        m = self.model
        if action.name == "goto_waypoint":
            _, a, b = action.args
            return non_fluent(m, "SECONDS_PER_METRE") * non_fluent(m, "DISTANCE", (a, b))
        if action.name == "wait_load":
            before = world.previous_state
            assert before is not None, "a wait is timed after its step"
            p = action.args[1]
            if not self._at(before, "somebody_at", p):
                return non_fluent(m, "NOBODY_SECONDS")
            if self._at(before, "is_busy", p):
                return non_fluent(m, "BUSY_SECONDS")
            return non_fluent(m, "LOAD_SECONDS")
        if action.name == "wait_unload":
            return non_fluent(m, "UNLOAD_SECONDS")
        if action.name == "noop":
            return non_fluent(m, "IDLE_SECONDS")
        raise ValueError(f"no duration for {action}")

    def world_options(self) -> dict[str, object]:
        """The keyword arguments of `ippc.dispatch.run.simulate` for this world."""
        return {
            "exogenous": self.exogenous,
            "observe": self.observe,
            "sensed": list(SENSED),
            "durations": self.duration,
        }
