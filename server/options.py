"""The listener's limits as click options (docs/server-safety.md): rddl-server's and
rddl-dispatch's `connection_options`, and `listener_options`, from which rddl-kb takes
the same options with its own defaults."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

from .config import DEFAULT_ACCEPT_RATE
from .limits import parse_networks

F = TypeVar("F", bound=Callable[..., Any])


def listener_options(
    *,
    max_connections: int | None,
    max_connections_help: str,
    accept_rate: float,
    accept_rate_help: str,
    per_address: bool,
) -> Callable[[F], F]:
    """A decorator adding a listener's limits to a click command: --max-connections,
    --max-connections-per-address (with `per_address`), --allow and --accept-rate.

    `max_connections` None: the command works the cap out itself (rddl-server's comes
    from the open-file limit); the numbers come as they are typed and
    `check_connection_options` checks them. A number: it is the shown default, and
    click's ranges check --max-connections (at least 1) and --accept-rate (at least 0)."""
    checked_later = max_connections is None
    options = [
        click.option(
            "--max-connections",
            type=int if checked_later else click.IntRange(min=1),
            default=max_connections,
            show_default=not checked_later,
            metavar="N" if checked_later else None,
            help=max_connections_help,
        )
    ]
    if per_address:
        options.append(
            click.option(
                "--max-connections-per-address",
                type=int,
                default=None,
                metavar="N",
                help="Open connections from one address at most [default: half of --max-connections].",
            )
        )
    options += [
        click.option(
            "--allow",
            multiple=True,
            metavar="CIDR",
            help="Accept connections only from this network (repeatable); default: any address.",
        ),
        click.option(
            "--accept-rate",
            type=float if checked_later else click.FloatRange(min=0),
            default=accept_rate,
            show_default=True,
            help=accept_rate_help,
        ),
    ]

    def decorate(f: F) -> F:
        for option in reversed(options):
            f = option(f)
        return f

    return decorate


connection_options = listener_options(
    max_connections=None,
    max_connections_help="Open connections at most; more are refused at once [default: from the open-file limit].",
    accept_rate=DEFAULT_ACCEPT_RATE,
    accept_rate_help="New connections a second the listener accepts at most (bursts of half that); more wait in the backlog; 0 = no limit.",
    per_address=True,
)
"""The listener's options of rddl-server and rddl-dispatch: --max-connections,
--max-connections-per-address, --allow and --accept-rate (check them with
`check_connection_options`)."""


def check_connection_options(
    max_connections: int | None,
    max_connections_per_address: int | None,
    allow: tuple[str, ...],
    accept_rate: float,
) -> None:
    """click.BadParameter for a bad value of `connection_options`."""
    for name, n in (
        ("--max-connections", max_connections),
        ("--max-connections-per-address", max_connections_per_address),
    ):
        if n is not None and n < 1:
            raise click.BadParameter("must be at least 1", param_hint=name)
    if accept_rate < 0:
        raise click.BadParameter("must be 0 (no limit) or positive", param_hint="--accept-rate")
    try:
        parse_networks(allow)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--allow") from None
