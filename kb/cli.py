"""`rddl-kb`: a knowledge base on its own, served over JSON lines."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import click
import trio

from ..rddl import RDDLError
from ..server.limits import parse_networks
from ..server.options import listener_options
from .jsonl import DEFAULT_HOST, SocketLimits
from .knowledge_base import KnowledgeBase
from .service import serve_kb


def load(domain: Path, instance: Path) -> KnowledgeBase:
    """The knowledge base of DOMAIN and INSTANCE, or a ClickException with
    every problem of the files by file, line and column."""
    try:
        return KnowledgeBase.from_files(domain, instance)
    except RDDLError as err:
        raise click.ClickException(str(err)) from None


async def run(kb: KnowledgeBase, host: str, port: int, limits: SocketLimits | None = None) -> None:
    """Serve `kb` and say where, until interrupted."""
    async with trio.open_nursery() as nursery:
        bound = await nursery.start(functools.partial(serve_kb, kb, host, port, limits=limits))
        click.echo(f"listening on {host}:{bound}", nl=True)


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("domain", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("instance", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--host", default=DEFAULT_HOST, show_default=True, help="Address to bind.")
@click.option("--port", default=3235, show_default=True, help="TCP port; 0 picks a free one.")
@click.option(
    "--rddl", "write_rddl", is_flag=True, help="Print the RDDL instance of the state and exit."
)
@click.option(
    "--pddl",
    type=click.Choice(["most-likely", "all-outcomes"]),
    help="Print the PDDL domain and problem (this determinisation) and exit.",
)
@click.option(
    "--exogenous",
    type=click.Choice(["current", "most-likely", "outcomes"]),
    default="current",
    show_default=True,
    help="With --pddl: what the world's own fluents do (see docs/knowledge-base.md).",
)
@listener_options(
    max_connections=SocketLimits.max_connections,
    max_connections_help="Open connections at most; more are refused at once.",
    accept_rate=SocketLimits.accept_rate,
    accept_rate_help="New connections a second accepted at most; 0 = no limit.",
    per_address=False,
)
@click.option(
    "--max-buffered",
    type=click.IntRange(min=1),
    default=SocketLimits.max_buffered,
    show_default=True,
    help="Bytes of queued replies and unread input over all connections; past it the connection holding the most is closed.",
)
@click.option("-q", "--quiet", is_flag=True, help="Log warnings only.")
def main(
    domain: Path,
    instance: Path,
    host: str,
    port: int,
    write_rddl: bool,
    pddl: str | None,
    exogenous: str,
    max_connections: int,
    allow: tuple[str, ...],
    accept_rate: float,
    max_buffered: int,
    quiet: bool,
) -> None:
    """Serve the knowledge base of DOMAIN and INSTANCE (RDDL files) over
    JSON lines on HOST:PORT (docs/knowledge-base.md lists the methods)."""
    logging.basicConfig(
        level=logging.WARNING if quiet else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    try:
        parse_networks(allow)
    except ValueError as err:
        raise click.BadParameter(str(err), param_hint="--allow") from None
    limits = SocketLimits(
        max_connections=max_connections,
        allow=allow,
        accept_rate=accept_rate,
        max_buffered=max_buffered,
    )
    kb = load(domain, instance)
    if write_rddl:
        click.echo(kb.to_rddl_instance(), nl=False)
        return
    if pddl:
        from .store import KBError

        try:
            d, p = kb.to_pddl(pddl, exogenous)
        except KBError as err:
            raise click.ClickException(str(err)) from None
        click.echo(d + "\n" + p, nl=False)
        return
    try:
        trio.run(run, kb, host, port, limits)
    except KeyboardInterrupt:
        pass


if __name__ == "__main__":
    main()
