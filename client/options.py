"""`--memory-budget MB` and `--grace SECONDS`: the limits of a planner's guarded
process (`client/guard.py`), as rddl-client and rddl-batch take them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

F = TypeVar("F", bound=Callable[..., Any])


def budget_options(*, memory_help: str, grace_default: float, grace_help: str) -> Callable[[F], F]:
    """A decorator adding `--memory-budget MB` (parameter `memory_mb`: float or None,
    at least 1) and `--grace SECONDS` (parameter `grace`: float, at least 0) to a click
    command. Each CLI says in its own words what the limits stop (a planner, a job)."""

    def decorate(f: F) -> F:
        f = click.option(
            "--grace",
            type=click.FloatRange(min=0),
            default=grace_default,
            show_default=True,
            metavar="SECONDS",
            help=grace_help,
        )(f)
        return click.option(
            "--memory-budget",
            "memory_mb",
            type=click.FloatRange(min=1),
            default=None,
            metavar="MB",
            help=memory_help,
        )(f)

    return decorate
