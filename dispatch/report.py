"""What a dispatcher run is given and what it reports: `PlannerSpec`,
`LinkPolicy`, the server settings (`server_config`, `kb_socket_limits`)
and `RunReport` (for `ippc.dispatch.run`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..kb.jsonl import SocketLimits
from ..server.config import DEFAULT_ACCEPT_RATE, ServerConfig

__all__ = [
    "DEFAULT_GOAL_SESSIONS",
    "DEFAULT_ROUNDS",
    "LinkPolicy",
    "PlannerSpec",
    "RunReport",
    "kb_socket_limits",
    "server_config",
    "signal_exit_code",
]


#: Rounds a dispatcher session offers by default: when a round reaches the
#: horizon without the goal, the next one goes on from where the robot is.
DEFAULT_ROUNDS = 5
#: Sessions a goal is served without being reached before it is abandoned.
DEFAULT_GOAL_SESSIONS = 3


@dataclass(frozen=True)
class PlannerSpec:
    """Which planner to start: a built-in by name (with its options) or PROST."""

    name: str = "noop"
    options: Mapping[str, str] = field(default_factory=dict)
    prost: str | None = None  # PROST's search program (or its folder): use PROST
    no_header: bool = False  # a built-in planner asks for no-header framing (as PROST does)
    seed: int | None = None

    @property
    def label(self) -> str:
        return "prost" if self.prost is not None else self.name


@dataclass
class RunReport:
    """One dispatcher session, as `rddl-dispatch` reports it."""

    instance: str
    planner: str
    goal_reached: bool
    turns: int
    rounds: int
    reward: float  # the world's reward (simulated) or the dispatcher's (undiscounted sums)
    executed: list[dict[str, Any]]
    failed_actions: int
    planning_seconds: float
    execution_seconds: float  # on the dispatcher's clock (simulated seconds in the world)
    replans: int
    cost: float | None = None
    contradictions: int = 0
    session_status: str | None = None
    seed: int | None = None
    wall_seconds: float = 0.0
    planner_error: str | None = None
    dispatcher_reward: float = 0.0
    sessions: list[str] = field(default_factory=list)  # each session's status, in order
    planner_restarts: int = 0
    interrupted: str | None = None  # the signal that ended the run
    facts: list[list[Any]] = field(default_factory=list)  # the final knowledge, not-false
    journaled: int | None = None  # batches journaled in the result store
    executed_total: int | None = None  # actions over the run (`executed` keeps the last ones)
    goals: list[dict[str, Any]] = field(default_factory=list)  # served goals' outcomes

    @property
    def success(self) -> bool:
        return self.goal_reached

    def as_dict(self) -> dict[str, Any]:
        return {
            "instance": self.instance,
            "planner": self.planner,
            "seed": self.seed,
            "goal_reached": self.goal_reached,
            "turns": self.turns,
            "rounds": self.rounds,
            "reward": self.reward,
            "dispatcher_reward": self.dispatcher_reward,
            "executed": self.executed,
            "failed_actions": self.failed_actions,
            "replans": self.replans,
            "contradictions": self.contradictions,
            "planning_seconds": self.planning_seconds,
            "execution_seconds": self.execution_seconds,
            "cost": self.cost,
            "session_status": self.session_status,
            "wall_seconds": self.wall_seconds,
            "planner_error": self.planner_error,
            "sessions": self.sessions,
            "planner_restarts": self.planner_restarts,
            "interrupted": self.interrupted,
            "journaled": self.journaled,
            "executed_total": self.executed_total
            if self.executed_total is not None
            else len(self.executed),
            "facts": self.facts,
            "goals": self.goals,
        }

    def plan_lines(self) -> list[str]:
        """The executed plan, one line per action."""
        return [
            f"{e['turn']:>4}  {e['action']:<40} {e['outcome']}"
            + (f"  ({e['message']})" if e.get("message") else "")
            for e in self.executed
        ]


def server_config(
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    rounds: int = DEFAULT_ROUNDS,
    timeout: float = 0.0,
    db: Path | None = None,
    transcripts: Path | None = None,
    individual_session: bool = True,
    max_connections: int | None = None,
    max_connections_per_address: int | None = None,
    allow: tuple[str, ...] = (),
    accept_rate: float = DEFAULT_ACCEPT_RATE,
) -> ServerConfig:
    """rddl-server's settings for a dispatcher (no budget enforced by
    default; the listener's limits as rddl-server has them)."""
    return ServerConfig(
        host=host,
        port=port,
        rounds=rounds,
        timeout=timeout,
        individual_session=individual_session,
        db=db,
        transcripts=transcripts,
        max_connections=max_connections,
        max_connections_per_address=max_connections_per_address,
        allow=tuple(allow),
        accept_rate=accept_rate,
    )


@dataclass(frozen=True)
class LinkPolicy:
    """What the dispatcher does about its planner link.

    `silence`: seconds the planner may stay silent while the dispatcher
    waits for its message (a deadline on each receive, so a hung planner is
    detected while it hangs); None: the session budget when there is one
    (`ServerConfig.timeout`), else no limit; 0: no limit. `reconnect`: a
    dropped session (the planner hung up, died, went silent, or sent what
    cannot be read) is recorded `dropped` and the dispatcher waits for a
    planner to connect again, going on from the knowledge base as it is;
    False: the run ends there (its report says so). A planner the
    dispatcher started (`--planner`, `--prost`) is started again after
    `restart_delay` seconds, doubling up to `max_restart_delay` while
    attempts keep failing without playing a turn."""

    reconnect: bool = False
    silence: float | None = None
    restart_delay: float = 1.0
    max_restart_delay: float = 30.0

    def idle_timeout(self, config: ServerConfig) -> float | None:
        if self.silence is not None:
            return self.silence if self.silence > 0 else None
        return config.timeout if config.timeout > 0 else config.idle_timeout


#: Exit status of rddl-dispatch ended by a signal: 128 + the signal's number,
#: as a shell reports it (130 for SIGINT, 143 for SIGTERM).
def signal_exit_code(signum: int) -> int:
    return 128 + signum


def kb_socket_limits(config: ServerConfig) -> SocketLimits:
    """The knowledge base's socket's limits: the planner's port's --allow
    and --accept-rate, its connection caps when given (else the socket's
    own default, 64)."""
    default = SocketLimits()
    return SocketLimits(
        max_connections=config.max_connections or default.max_connections,
        max_connections_per_address=config.max_connections_per_address,
        allow=config.allow,
        accept_rate=config.accept_rate,
    )
