"""`rddl-client`: play a session against any IPPC server with any planner."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import click
import trio

from ..planners.base import ExternalPlanner, PlannerError, find_planner, make_planner
from .guard import default_memory_budget
from .options import budget_options
from .session import ClientConfig, ClientError, SessionResult, run_session, run_session_guarded


def parse_planner_options(pairs: tuple[str, ...]) -> dict[str, str]:
    """--planner-option KEY=VALUE pairs as a dict (rddl-dispatch reads them too)."""
    out: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise click.BadParameter(f"{pair!r} is not KEY=VALUE", param_hint="--planner-option")
        out[key.strip()] = value
    return out


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", default=2323, show_default=True)
@click.option(
    "--instance", required=True, help="Instance name (the session-request's problem-name)."
)
@click.option(
    "--planner",
    default="noop",
    show_default=True,
    help="noop, random, prost, or any registered planner.",
)
@click.option(
    "--name",
    "client_name",
    default=None,
    help="Client name sent to the server (default: the planner's name).",
)
@click.option(
    "--planner-option",
    "planner_options",
    multiple=True,
    metavar="KEY=VALUE",
    help="Planner option; repeatable.",
)
@click.option(
    "--rounds-training",
    default=0,
    show_default=True,
    help="Practice rounds first (execute-policy no; counted only by a server in monitor-execution mode).",
)
@click.option(
    "--no-header",
    is_flag=True,
    help="Ask for rddlsim's no-header mode (bare XML from the server, as PROST asks).",
)
@click.option(
    "--rddl",
    "rddl_paths",
    multiple=True,
    type=click.Path(exists=True, path_type=Path),
    help="Load the model from these files/folders instead of the server's task.",
)
@click.option("--seed", type=int, default=None, help="Seed for the planner.")
@click.option(
    "--json-out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write the results as JSON here.",
)
@click.option(
    "--timeout",
    type=float,
    default=600.0,
    show_default=True,
    help="Seconds to wait for any server message (and for an external planner's whole session).",
)
@click.option(
    "--prost",
    "prost_bin",
    type=click.Path(path_type=Path),
    default=None,
    help="PROST's search binary (else $PROST_BIN).",
)
@budget_options(
    memory_help="Resident memory the planner's process may hold before it is killed "
    "(default: 80% of the memory available at start).",
    grace_default=30.0,
    grace_help="How long the planner may play past the session's budget before its process is stopped.",
)
@click.option(
    "--in-process",
    is_flag=True,
    help="Run a built-in planner in this process (no time or memory limit holds then).",
)
@click.option("-q", "--quiet", is_flag=True)
def main(
    host: str,
    port: int,
    instance: str,
    planner: str,
    client_name: str | None,
    planner_options: tuple[str, ...],
    rounds_training: int,
    no_header: bool,
    rddl_paths: tuple[Path, ...],
    seed: int | None,
    json_out: Path | None,
    timeout: float,
    prost_bin: Path | None,
    memory_mb: float | None,
    grace: float,
    in_process: bool,
    quiet: bool,
) -> None:
    """Play one session of INSTANCE on an IPPC server (ours, rddlsim, or a
    robot's dispatcher) with a planner, and print the round rewards.

    A built-in planner plays in a child process that is stopped once the session's
    budget (from session-init) plus --grace has passed, or killed over --memory-budget:
    the exit status is 1 with the reason."""
    logging.basicConfig(
        level=logging.WARNING if quiet else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    options = parse_planner_options(planner_options)
    try:
        declared = find_planner(planner).options
    except PlannerError as err:
        raise click.ClickException(str(err)) from None
    if prost_bin is not None and "binary" not in declared:
        raise click.BadParameter(f"only for --planner prost (not {planner})", param_hint="--prost")
    # --seed and --prost are shortcuts for the planner options of those names
    if seed is not None and "seed" in declared:
        options.setdefault("seed", str(seed))
    if prost_bin is not None:
        options.setdefault("binary", str(prost_bin))
    try:
        agent = make_planner(planner, options)
    except PlannerError as err:
        raise click.ClickException(str(err)) from None
    name = client_name or planner

    if isinstance(agent, ExternalPlanner):
        res = agent.run_session(
            host=host,
            port=port,
            instance=instance,
            client_name=client_name,
            timeout=timeout,
            log_path=None,
        )
        for i, r in enumerate(res.rounds, 1):
            click.echo(f"round {i:3d}  reward {r:12.4f}")
        click.echo(
            f"total reward {res.total_reward:.4f}  ({res.seconds:.1f} s, log {res.log_path})"
        )
        if json_out is not None:
            rounds = [
                {"round": i, "reward": r, "turns": None, "seconds": None, "training": False}
                for i, r in enumerate(res.rounds, 1)
            ]
            data = {
                "instance": instance,
                "planner": planner,
                "client_name": name,
                "total_reward": res.total_reward,
                "mean_round_reward": (sum(res.rounds) / len(res.rounds)) if res.rounds else None,
                "rounds": rounds,
                "exit_code": res.exit_code,
                "error": res.error,
            }
            json_out.write_text(json.dumps(data, indent=2) + "\n")
        if not res.ok:
            raise click.ClickException(f"{planner}: {res.error}")
        return

    config = ClientConfig(
        host=host,
        port=port,
        instance=instance,
        client_name=name,
        no_header=no_header,
        rounds_training=rounds_training,
        rddl=rddl_paths,
        seed=seed,
        timeout=timeout,
    )
    if in_process:
        try:
            result = trio.run(run_session, config, agent, planner)
        except ClientError as err:
            raise click.ClickException(str(err)) from None
        except PlannerError as err:
            raise click.ClickException(f"planner {planner}: {err}") from None
    else:
        del agent  # made again in the child: the options are checked
        try:
            result = run_session_guarded(
                config,
                planner,
                options,
                memory_mb=memory_mb if memory_mb is not None else default_memory_budget(),
                grace=grace,
                log_level=logging.WARNING if quiet else logging.INFO,
            )
        except ClientError as err:
            raise click.ClickException(str(err)) from None
    print_result(result)
    if json_out is not None:
        json_out.write_text(json.dumps(result.as_dict(), indent=2) + "\n")


def print_result(result: SessionResult) -> None:
    click.echo(
        f"{result.instance}  planner {result.planner}  client {result.client_name}  session {result.session_id}"
    )
    click.echo(f"{'round':>5}  {'reward':>12}  {'turns':>5}  {'seconds':>8}")
    for r in result.rounds:
        mark = "  training" if r.training else ("  (ended early)" if r.ended_early else "")
        click.echo(f"{r.round:>5}  {r.reward:>12.4f}  {r.turns:>5}  {r.seconds:>8.3f}{mark}")
    click.echo(
        f"total reward {result.total_reward:.4f}  mean round reward "
        f"{result.mean_round_reward:.4f}  ({result.seconds:.2f} s)"
    )
