"""ippc.dispatch: the robot side (sensing, action handlers, the online dispatcher).

`run_blocking(fn, *args)` runs a blocking driver call from a handler in a
thread, under the action's timeout (see `ippc.dispatch.actions`)."""

from .actions import run_blocking

__all__ = ["run_blocking"]
