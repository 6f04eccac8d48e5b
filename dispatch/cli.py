"""`rddl-dispatch`: the online dispatcher, an IPPC server whose environment is
a robot's knowledge base (or, with --simulate, a simulated world)."""

from __future__ import annotations

import json
import logging
import signal
import sys
from pathlib import Path
from typing import Any

import click
import trio

from ..client.cli import parse_planner_options
from ..client.options import budget_options
from ..kb import KBError, KnowledgeBase
from ..planners.base import PlannerError, make_planner
from ..rddl import RDDLError
from ..server.cli import check_connection_options, connection_options
from ..server.store import ResultStore, StoreError
from ..web import WebOptions, web_options, web_url
from .config import SensingConfig, SensingConfigError
from .dispatcher import DispatcherError
from .run import (
    DEFAULT_GOAL_SESSIONS,
    DEFAULT_ROUNDS,
    LinkPolicy,
    ListenError,
    PlannerSpec,
    RobotFileError,
    RunReport,
    build_robot,
    dispatch_session,
    executed_plan,
    server_config,
    signal_exit_code,
)
from .run import simulate as simulate_run


def print_report(report: RunReport) -> None:
    """The executed plan and the run's figures, as rddl-dispatch prints them."""
    click.echo(f"{report.instance}  planner {report.planner}")
    click.echo(f"{'turn':>4}  {'action':<40} outcome")
    for line in report.plan_lines():
        click.echo(line)
    goal = "goal reached" if report.goal_reached else "goal not reached"
    click.echo(
        f"{goal}: {report.turns} turns in {report.rounds} round(s), reward {report.reward:g}, "
        f"{report.failed_actions} failed action(s), planning {report.planning_seconds:.3f} s, "
        f"execution {report.execution_seconds:.1f} s"
    )
    goals = report.goals
    if len(goals) == 1 and goals[0].get("outcome") == "reached" and report.goal_reached:
        goals = []  # the line above says it all
    for g in goals:
        outcome = g.get("outcome") or ("reached" if g["reached"] else "not reached")
        if g.get("turn") is not None:
            outcome += f" at turn {g['turn']}"
        click.echo(
            f"goal {g['goal']}: {outcome} after {g['turns']} turns, "
            f"{g['actions']} action(s), {g['failed_actions']} failed"
        )
    if len(report.sessions) > 1 or report.planner_restarts:
        click.echo(
            f"sessions: {', '.join(report.sessions) or 'none'}; planner restarts: "
            f"{report.planner_restarts}"
        )
    if report.planner_error:
        click.echo(f"planner: {report.planner_error}", err=True)


@click.command(context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("domain", required=False, type=click.Path(exists=True, path_type=Path))
@click.argument("instance", required=False, type=click.Path(exists=True, path_type=Path))
@click.option(
    "--sensing",
    "sensing_path",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Sensing config (YAML): the sensed fluents, their streams and expressions.",
)
@click.option(
    "--robot",
    "robot_file",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Python file whose setup(robot) registers action handlers and sensor sources.",
)
@click.option("--simulate", is_flag=True, help="Run the whole loop in the simulated world.")
@click.option("--seed", default=0, show_default=True, help="Seed of the simulated world.")
@click.option(
    "--host",
    default="127.0.0.1",
    show_default=True,
    help="Address to listen on (and of the knowledge base's socket).",
)
@click.option(
    "--port",
    default=2323,
    show_default=True,
    help="TCP port for the planner; 0 picks a free one (--simulate always picks one).",
)
@connection_options
@click.option(
    "--planner",
    default=None,
    help="Start this built-in planner against the dispatcher (rddl-client's code).",
)
@click.option(
    "--planner-option", "planner_options", multiple=True, metavar="KEY=VALUE", help="Repeatable."
)
@click.option(
    "--prost",
    "prost_bin",
    type=click.Path(path_type=Path),
    default=None,
    help="Start PROST (its search program or folder) against the dispatcher.",
)
@click.option(
    "--no-header", is_flag=True, help="The built-in planner asks for no-header framing (as PROST)."
)
@budget_options(
    memory_help="Resident memory the --planner's process may hold before it is killed "
    "(default: 80% of the memory available at start; not with --simulate).",
    grace_default=30.0,
    grace_help="How long the --planner may play past the session's budget before its process "
    "is stopped (not with --simulate).",
)
@click.option(
    "--rounds",
    default=DEFAULT_ROUNDS,
    show_default=True,
    help="Rounds offered: at the horizon without the goal, the next round goes on.",
)
@click.option(
    "--timeout", default=0.0, show_default=True, help="Session budget in seconds; 0 = none."
)
@click.option(
    "--action-timeout", default=60.0, show_default=True, help="Seconds a handler has per action."
)
@click.option(
    "--kb-port",
    type=int,
    default=None,
    help="Serve the knowledge base's JSON-lines socket here (kb.*, sensing.*, handlers.*); 0 = any free port. It takes the same --allow and --accept-rate, and --max-connections (default 64 for it).",
)
@click.option("--no-stop-at-goal", is_flag=True, help="Play every round to its horizon.")
@click.option(
    "--on-planner-loss",
    type=click.Choice(["wait", "exit"]),
    default="wait",
    show_default=True,
    help="A dropped session: wait for a planner to connect again (and restart --planner/--prost), or end the run.",
)
@click.option(
    "--planner-silence",
    type=float,
    default=None,
    help="Seconds the planner may stay silent before its session is dropped [default: the --timeout budget; 0 = no limit].",
)
@click.option(
    "--watchdog",
    default=1.0,
    show_default=True,
    help="Warn, naming the handler, when the event loop is blocked this many seconds; 0 = off.",
)
@click.option(
    "--serve-goals",
    is_flag=True,
    help="Serve goals until stopped: each goal set at run time (kb.set_goal) gets a session; implies --on-planner-loss wait.",
)
@click.option(
    "--goal-sessions",
    type=click.IntRange(min=0),
    default=DEFAULT_GOAL_SESSIONS,
    show_default=True,
    help="With --serve-goals: sessions a goal is served without being reached before it is abandoned (a warning, and its outcome); 0 = never.",
)
@click.option(
    "--fresh",
    is_flag=True,
    help="Start from the instance's initial state, not from the facts journaled in --db.",
)
@click.option(
    "--db",
    type=click.Path(dir_okay=False, path_type=Path),
    help="SQLite result store (every turn, with outcomes).",
)
@click.option(
    "--json-out",
    type=click.Path(dir_okay=False, path_type=Path),
    help="Write the run's report as JSON to this file.",
)
@click.option(
    "--plan-of",
    "plan_of",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="Print the executed plan of a session recorded in this result store, and exit.",
)
@click.option(
    "--session",
    "session_id",
    type=int,
    default=None,
    help="With --plan-of: the session's id in the store (default: the last one).",
)
@click.option("-q", "--quiet", is_flag=True, help="Log warnings only.")
@web_options
def main(
    domain: Path | None,
    instance: Path | None,
    sensing_path: Path | None,
    robot_file: Path | None,
    simulate: bool,
    seed: int,
    host: str,
    port: int,
    max_connections: int | None,
    max_connections_per_address: int | None,
    allow: tuple[str, ...],
    accept_rate: float,
    planner: str | None,
    planner_options: tuple[str, ...],
    prost_bin: Path | None,
    no_header: bool,
    memory_mb: float | None,
    grace: float,
    rounds: int,
    timeout: float,
    action_timeout: float,
    kb_port: int | None,
    no_stop_at_goal: bool,
    on_planner_loss: str,
    planner_silence: float | None,
    watchdog: float,
    serve_goals: bool,
    goal_sessions: int,
    fresh: bool,
    db: Path | None,
    json_out: Path | None,
    plan_of: Path | None,
    session_id: int | None,
    quiet: bool,
    web: int | None,
    web_host: str | None,
) -> None:
    """Serve the knowledge base of DOMAIN and INSTANCE to an IPPC planner and
    execute the actions it sends (see docs/robot.md)."""
    logging.basicConfig(
        level=logging.WARNING if quiet else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if plan_of is not None:
        _print_plan(plan_of, session_id)
        return
    if domain is None or instance is None:
        raise click.UsageError("DOMAIN and INSTANCE are needed (or --plan-of DB)")
    if planner is not None and prost_bin is not None:
        raise click.BadParameter("give --planner or --prost, not both", param_hint="--prost")
    if rounds < 1:
        raise click.BadParameter("must be at least 1", param_hint="--rounds")
    if planner_silence is not None and planner_silence < 0:
        raise click.BadParameter("must be at least 0", param_hint="--planner-silence")
    if watchdog < 0:
        raise click.BadParameter("must be at least 0", param_hint="--watchdog")
    check_connection_options(max_connections, max_connections_per_address, allow, accept_rate)
    spec: PlannerSpec | None = None
    if planner is not None or prost_bin is not None:
        spec = PlannerSpec(
            name=planner or "prost",
            options=parse_planner_options(planner_options),
            prost=None if prost_bin is None else str(prost_bin),
            no_header=no_header,
            seed=seed,
        )
        _check_planner(spec)
    elif planner_options:
        raise click.BadParameter(
            "options for which planner? give --planner or --prost", param_hint="--planner-option"
        )
    if db is not None:
        _check_db(db)
    page = _page(WebOptions.from_cli(web, web_host))
    if simulate:
        if serve_goals:
            raise click.BadParameter(
                "goals are served to a robot (the simulated world plays one goal)",
                param_hint="--serve-goals",
            )
        if sensing_path is not None or robot_file is not None:
            raise click.BadParameter(
                "the simulated world senses and executes itself", param_hint="--simulate"
            )
        ctx = click.get_current_context()
        for name, hint in (("memory_mb", "--memory-budget"), ("grace", "--grace")):
            if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT:
                raise click.BadParameter(
                    "the simulated world plays its planner in its own loop, where no budget holds",
                    param_hint=hint,
                )
        try:
            report = simulate_run(
                domain,
                instance,
                seed=seed,
                planner=spec or PlannerSpec("noop"),
                rounds=rounds,
                db=db,
                timeout=timeout,
                action_timeout=action_timeout,
                stop_at_goal=not no_stop_at_goal,
                handle_signals=True,
                web=page,
                resume=not fresh,
            )
        except (RDDLError, KBError) as err:
            raise click.ClickException(str(err)) from None
        except DispatcherError as err:
            raise click.ClickException(f"{instance}: {err}") from None
        except BaseException as exc:
            _listen_error(exc)
            raise
    else:
        report = _robot(
            domain,
            instance,
            sensing_path,
            robot_file,
            spec,
            host=host,
            port=port,
            limits={
                "max_connections": max_connections,
                "max_connections_per_address": max_connections_per_address,
                "allow": allow,
                "accept_rate": accept_rate,
            },
            rounds=rounds,
            timeout=timeout,
            action_timeout=action_timeout,
            stop_at_goal=not no_stop_at_goal,
            db=db,
            kb_port=kb_port,
            link=LinkPolicy(reconnect=on_planner_loss == "wait", silence=planner_silence),
            watchdog=watchdog or None,
            resume=not fresh,
            serve_goals=serve_goals,
            goal_sessions=goal_sessions,
            web=page,
            memory_mb=memory_mb,
            grace=grace,
        )
    print_report(report)
    if json_out is not None:
        json_out.write_text(json.dumps(report.as_dict(), indent=2) + "\n")
    if report.interrupted is not None:
        click.echo(f"rddl-dispatch: interrupted by {report.interrupted}", err=True)
        raise SystemExit(signal_exit_code(signal.Signals[report.interrupted]))
    if report.session_status in (None, "dropped"):
        # the report is printed either way; the status says the session did not play out
        why = "no session was played" if report.session_status is None else "the session dropped"
        click.echo(f"rddl-dispatch: {why}", err=True)
        raise SystemExit(1)


def _check_planner(spec: PlannerSpec) -> None:
    """Make the planner once, so that an unknown name, a bad option or a
    missing PROST binary is refused before anything listens (the planner
    the run starts is made again, fresh)."""
    options = dict(spec.options)
    if spec.prost is not None:
        options["binary"] = spec.prost
    try:
        make_planner("prost" if spec.prost is not None else spec.name, options)
    except PlannerError as err:
        raise click.ClickException(str(err)) from None


def _check_db(db: Path) -> None:
    """Open (or create) the result store now: a bad file gets one line."""
    try:
        ResultStore(db).close()
    except (StoreError, OSError) as err:
        raise click.ClickException(f"--db {db}: {err}") from None


def _robot(
    domain: Path,
    instance: Path,
    sensing_path: Path | None,
    robot_file: Path | None,
    spec: PlannerSpec | None,
    **opts: Any,
) -> RunReport:
    try:
        kb = KnowledgeBase.from_files(domain, instance)
        config = SensingConfig.load(sensing_path, kb.model) if sensing_path is not None else None
        robot, dispatcher = build_robot(
            kb,
            config,
            robot_file=robot_file,
            action_timeout=opts["action_timeout"],
            stop_at_goal=opts["stop_at_goal"],
        )
    except (RDDLError, KBError, SensingConfigError, RobotFileError) as err:
        raise click.ClickException(str(err)) from None
    except DispatcherError as err:
        raise click.ClickException(f"{instance}: {err}") from None
    if not robot.handlers.names():
        logging.getLogger(__name__).warning(
            "no action handler registered (give --robot FILE): every action fails"
        )
    config_ = server_config(
        host=opts["host"],
        port=opts["port"],
        rounds=opts["rounds"],
        timeout=opts["timeout"],
        db=opts["db"],
        **opts["limits"],
    )

    def listening(bound: int) -> None:
        click.echo(f"listening on {opts['host']}:{bound}")
        sys.stdout.flush()

    def kb_listening(bound: int) -> None:
        click.echo(f"knowledge base on {opts['host']}:{bound}")
        sys.stdout.flush()

    try:
        return trio.run(
            lambda: dispatch_session(
                dispatcher,
                spec,
                config_,
                sensing_task=True,
                on_listening=listening,
                robot=robot,
                kb_port=opts["kb_port"],
                on_kb_listening=kb_listening,
                link=opts["link"],
                watchdog=opts["watchdog"],
                handle_signals=True,
                journal=True,
                resume=opts["resume"],
                serve_goals=opts["serve_goals"],
                goal_sessions=opts["goal_sessions"] or None,
                web=opts["web"],
                planner_memory_mb=opts["memory_mb"],
                planner_grace=opts["grace"],
            )
        )
    except BaseException as exc:  # trio hands some errors over in exception groups
        _listen_error(exc)
        raise


def _listen_error(exc: BaseException) -> None:
    """A socket that cannot listen, or Ctrl-C, out of trio's exception groups: as
    click's errors (anything else: nothing, the caller raises it)."""
    leaf = exc
    while isinstance(leaf, BaseExceptionGroup) and len(leaf.exceptions) == 1:
        leaf = leaf.exceptions[0]
    if isinstance(leaf, ListenError):
        raise click.ClickException(str(leaf)) from None
    if isinstance(leaf, KeyboardInterrupt):
        raise click.Abort() from None


def _page(options: WebOptions | None) -> Any:
    """The web page's task for `dispatch_session` (None: no --web); it says where
    it listens."""
    if options is None:
        return None
    from .web import web_task

    def listening(port: int) -> None:
        click.echo(f"web view on {web_url(options, port)}")
        sys.stdout.flush()

    return web_task(options, listening)


def _print_plan(db: Path, session: int | None) -> None:
    try:
        plan = executed_plan(db, session)
    except KeyError as err:
        raise click.ClickException(str(err.args[0])) from None
    except StoreError as err:
        raise click.ClickException(f"--plan-of {db}: {err}") from None
    for e in plan:
        line = f"{e['round']:>3} {e['turn']:>4}  {e['action']:<40} {e['outcome']}"
        if e.get("message"):
            line += f"  ({e['message']})"
        click.echo(line)


if __name__ == "__main__":
    main()
