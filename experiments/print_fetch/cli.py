"""`python -m ippc.experiments.print_fetch`: the print-fetching study's commands."""

from __future__ import annotations

from pathlib import Path

import click

from .office import write_instances

DOMAIN_FOLDER = Path(__file__).resolve().parents[2] / "domains" / "print_fetch"


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
def main() -> None:
    """The paper's print-fetching robot study (docs/print-fetch.md)."""


@main.command()
@click.option(
    "--folder",
    type=click.Path(file_okay=False, path_type=Path),
    default=DOMAIN_FOLDER,
    show_default=True,
    help="Where to write the instance files.",
)
def instances(folder: Path) -> None:
    """Write the experiments' RDDL instances from the office's numbers."""
    folder.mkdir(parents=True, exist_ok=True)
    for path in write_instances(folder):
        click.echo(f"wrote {path}")
