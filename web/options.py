"""`--web PORT` and `--web-host HOST`: the options rddl-server, rddl-batch
and rddl-dispatch share, and the limits of the web view."""

from __future__ import annotations

import ipaddress
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import click

DEFAULT_HOST = "127.0.0.1"


@dataclass(frozen=True)
class WebOptions:
    """Where the web view listens and what it allows a viewer.

    `port` 0 picks a free port. The limits: at most `max_connections` open
    connections (viewers included), a request's line and headers at most
    `max_request` bytes and complete within `header_timeout` seconds, every
    write done within `write_timeout` seconds, an event-stream comment every
    `heartbeat` seconds."""

    port: int = 0
    host: str = DEFAULT_HOST
    max_connections: int = 256
    max_request: int = 8192
    header_timeout: float = 10.0
    write_timeout: float = 10.0
    heartbeat: float = 15.0

    @classmethod
    def from_cli(cls, web: int | None, web_host: str | None) -> WebOptions | None:
        """The options of `--web`/`--web-host` (None: the view is off);
        raises click.BadParameter for a bad value."""
        if web is None:
            if web_host is not None:
                raise click.BadParameter("needs --web PORT", param_hint="--web-host")
            return None
        if not 0 <= web <= 65535:
            raise click.BadParameter("must be a TCP port (0 picks a free one)", param_hint="--web")
        host = DEFAULT_HOST if web_host is None else web_host.strip()
        if host != "localhost":
            try:
                ipaddress.ip_address(host)
            except ValueError:
                raise click.BadParameter(
                    f"{web_host!r} is not an IP address", param_hint="--web-host"
                ) from None
        return cls(port=web, host=host)


F = TypeVar("F", bound=Callable[..., Any])


def web_options(command: F) -> F:
    """Add `--web PORT` and `--web-host HOST` to a click command (its
    function takes `web` and `web_host`; pass them to `WebOptions.from_cli`)."""
    command = click.option(
        "--web-host",
        metavar="HOST",
        default=None,
        help="Address of the web view [default: 127.0.0.1]; another one is reachable from other machines (logged as a warning).",
    )(command)
    command = click.option(
        "--web",
        type=int,
        metavar="PORT",
        default=None,
        help="Serve a read-only live web view on this port (0 picks a free one); off by default.",
    )(command)
    return command


__all__ = ["DEFAULT_HOST", "WebOptions", "web_options"]
