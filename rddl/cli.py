"""`rddl`: the command line of the RDDL front end.

Thin by design: each command parses its options and calls a library
function that tests call too.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from .errors import RDDLError
from .loader import CheckResult, check_files


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="ippc")
def main() -> None:
    """Parse, check, format and simulate RDDL."""


def _result_json(r: CheckResult) -> dict[str, object]:
    return {
        "name": r.name,
        "kind": r.kind,
        "file": r.file,
        "ok": r.ok,
        "errors": [
            {
                "file": d.file,
                "line": d.line,
                "column": d.column,
                "kind": d.kind,
                "message": d.message,
            }
            for d in r.diagnostics
        ],
    }


def run_check(paths: list[str], as_json: bool, verbose: bool) -> int:
    """Check `paths`; print one line per instance and a summary; return the exit code."""
    try:
        results = check_files(*paths)
    except RDDLError as err:
        raise click.ClickException(err.render()) from None
    failed = sum(1 for r in results if not r.ok)
    if as_json:
        click.echo(
            json.dumps(
                {
                    "results": [_result_json(r) for r in results],
                    "checked": len(results),
                    "ok": len(results) - failed,
                    "failed": failed,
                },
                indent=2,
            )
        )
        return 1 if failed else 0
    if not results:
        click.echo("no .rddl files found", err=True)
        return 1
    width = max(len(r.name) for r in results)
    for r in results:
        label = r.name if r.kind == "instance" else f"{r.name} ({r.kind})"
        if r.ok:
            note = "" if r.kind == "instance" else "  no instance uses it"
            click.echo(f"ok    {label:<{width}}  {r.file}{note}")
        else:
            d = r.diagnostics[0]
            more = f"  (+{len(r.diagnostics) - 1} more)" if len(r.diagnostics) > 1 else ""
            click.echo(f"FAIL  {label:<{width}}  {d}{more}")
            if verbose:
                for diag in r.diagnostics:
                    click.echo("      " + diag.render().replace("\n", "\n      "))
    instances = sum(1 for r in results if r.kind == "instance")
    click.echo(
        f"{len(results)} checked ({instances} instances): {len(results) - failed} ok, {failed} failed"
    )
    return 1 if failed else 0


@main.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path(exists=True))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object for machines.")
@click.option("-v", "--verbose", is_flag=True, help="Show every error with its source line.")
def check(paths: tuple[str, ...], as_json: bool, verbose: bool) -> None:
    """Check RDDL files and folders: one line per instance, exit 1 on any error.

    Instances are paired with their domain and non-fluents by name across
    all the files given, as rddlsim does across a folder.
    """
    sys.exit(run_check(list(paths), as_json, verbose))


@main.command()
@click.argument("file", type=click.Path(exists=True, dir_okay=False))
def fmt(file: str) -> None:
    """Print the canonical RDDL text of FILE."""
    from .parser import parse_file
    from .writer import write

    try:
        parsed = parse_file(Path(file))
    except RDDLError as err:
        raise click.ClickException(err.render()) from None
    click.echo(write(parsed), nl=False)


@main.command()
@click.argument("domain", type=click.Path(exists=True, dir_okay=False))
@click.argument("instance", type=click.Path(exists=True, dir_okay=False))
@click.option("--policy", type=click.Choice(["noop", "random"]), default="noop", show_default=True)
@click.option("--episodes", type=click.IntRange(min=1), default=10, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option(
    "--horizon",
    type=click.IntRange(min=1),
    default=None,
    help="Steps per episode (default: the instance's).",
)
@click.option("--instance-name", default=None, help="Which instance, when the file holds several.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def sim(
    domain: str,
    instance: str,
    policy: str,
    episodes: int,
    seed: int,
    horizon: int | None,
    instance_name: str | None,
    as_json: bool,
) -> None:
    """Simulate episodes of a policy on DOMAIN + INSTANCE files.

    Prints the mean and standard deviation of the return (discounted, as
    rddlsim's round reward), the steps simulated and steps per second.
    """
    from .loader import load_pair
    from .rollout import run_episodes
    from .simulator import SimulationError

    try:
        model = load_pair(domain, instance, instance_name)
        stats = run_episodes(model, policy, episodes, seed, horizon)
    except (RDDLError, SimulationError) as err:
        text = err.render() if isinstance(err, RDDLError) else str(err)
        raise click.ClickException(text) from None
    if as_json:
        click.echo(json.dumps(stats.as_dict()))
        return
    click.echo(f"instance          {stats.instance}")
    click.echo(f"policy            {policy} ({episodes} episodes, seed {seed})")
    click.echo(f"mean return       {stats.mean_return:.4f}")
    click.echo(f"std return        {stats.std_return:.4f}")
    click.echo(f"steps             {stats.steps}")
    click.echo(f"steps per second  {stats.steps_per_second:.0f}")


if __name__ == "__main__":  # pragma: no cover
    main()
