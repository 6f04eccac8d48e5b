"""The messages of rddlsim's IPPC protocol, one frozen dataclass per message.

They are also the events a :class:`~ippc.protocol.ServerConnection` or
:class:`~ippc.protocol.ClientConnection` hands out. Field order follows the order in which
rddlsim writes the elements. Values of decoded fluents and actions are the raw text as
received (the codec does not know the declared ranges); :mod:`ippc.protocol.values`
interprets them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Final, TypeAlias

__all__ = [
    "MESSAGE_TYPES",
    "ROOT_ELEMENTS",
    "Actions",
    "Fluent",
    "FluentValue",
    "Message",
    "ResourceNotification",
    "ResourceRequest",
    "RoundEnd",
    "RoundInit",
    "RoundRequest",
    "SessionEnd",
    "SessionInit",
    "SessionRequest",
    "Turn",
    "root_element",
]

#: A fluent or action value: ``str`` is an enum value (``@x``), an object name, or the raw
#: text of a decoded message.
FluentValue: TypeAlias = bool | int | float | str


def _as_tuple(items: Iterable[object]) -> tuple[object, ...]:
    return items if isinstance(items, tuple) else tuple(items)


@dataclass(frozen=True, slots=True)
class Fluent:
    """One ``<observed-fluent>`` of a turn or one ``<action>`` of an actions message."""

    name: str
    args: tuple[str, ...] = ()
    value: FluentValue = True

    def __post_init__(self) -> None:
        # Accept any iterable of arguments (a list is the common slip) but store a tuple so
        # that the message stays hashable and compares equal to a decoded one.
        if not isinstance(self.args, tuple):
            object.__setattr__(self, "args", _as_tuple(self.args))


@dataclass(frozen=True, slots=True)
class SessionRequest:
    """Client -> server, first message: which instance to play and who is playing."""

    problem_name: str
    client_name: str
    input_language: str | None = None
    no_header: bool = False


@dataclass(frozen=True, slots=True)
class SessionInit:
    """Server -> client: the task (raw RDDL bytes; base64 on the wire) and the budget."""

    task: bytes = field(repr=False)
    session_id: int
    num_rounds: int
    time_allowed: float


@dataclass(frozen=True, slots=True)
class RoundRequest:
    """Client -> server: start the next round.

    ``execute_policy`` is ``None`` when the element is absent; a received ``yes`` (after
    Java's trim) is ``True``, anything else ``False``.
    """

    execute_policy: bool | None = None


@dataclass(frozen=True, slots=True)
class RoundInit:
    """Server -> client: a round starts (``round_left`` = rounds after this one)."""

    round_num: int
    round_left: int
    time_left: float


@dataclass(frozen=True, slots=True)
class Turn:
    """Server -> client: the state (or observations) before the next action.

    ``fluents`` is ``None`` exactly when the message carries ``<no-observed-fluents/>``
    (first turn of a POMDP round).
    """

    turn_num: int
    time_left: float
    immediate_reward: float
    fluents: tuple[Fluent, ...] | None = ()

    def __post_init__(self) -> None:
        if self.fluents is not None and not isinstance(self.fluents, tuple):
            object.__setattr__(self, "fluents", _as_tuple(self.fluents))


@dataclass(frozen=True, slots=True)
class Actions:
    """Client -> server: the actions for the current turn (empty = noop)."""

    actions: tuple[Fluent, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.actions, tuple):
            object.__setattr__(self, "actions", _as_tuple(self.actions))


@dataclass(frozen=True, slots=True)
class RoundEnd:
    """Server -> client: the round is over (``round_num`` is 0-based here, as in rddlsim)."""

    instance_name: str
    client_name: str
    round_num: int
    round_reward: float
    turns_used: int
    time_left: int
    immediate_reward: float


@dataclass(frozen=True, slots=True)
class SessionEnd:
    """Server -> client: the session is over; the server closes the connection next."""

    instance_name: str
    total_reward: float
    rounds_used: int
    client_name: str
    session_id: int
    time_left: int


@dataclass(frozen=True, slots=True)
class ResourceRequest:
    """Client -> server: how much time is left?"""


@dataclass(frozen=True, slots=True)
class ResourceNotification:
    """Server -> client: the answer to a resource-request (memory is always ``enough``)."""

    time_left: float
    memory_left: str = "enough"


Message: TypeAlias = (
    SessionRequest
    | SessionInit
    | RoundRequest
    | RoundInit
    | Turn
    | Actions
    | RoundEnd
    | SessionEnd
    | ResourceRequest
    | ResourceNotification
)

#: Every message class, in protocol order.
MESSAGE_TYPES: Final[tuple[type[Message], ...]] = (
    SessionRequest,
    SessionInit,
    RoundRequest,
    RoundInit,
    Turn,
    Actions,
    RoundEnd,
    SessionEnd,
    ResourceRequest,
    ResourceNotification,
)

#: The root element name of each message class.
ROOT_ELEMENTS: Final[dict[type[Message], str]] = {
    SessionRequest: "session-request",
    SessionInit: "session-init",
    RoundRequest: "round-request",
    RoundInit: "round-init",
    Turn: "turn",
    Actions: "actions",
    RoundEnd: "round-end",
    SessionEnd: "session-end",
    ResourceRequest: "resource-request",
    ResourceNotification: "resource-notification",
}


def root_element(message_type: type[Message] | Message) -> str:
    """The root element name of a message or message class (``Turn`` -> ``"turn"``)."""
    cls = message_type if isinstance(message_type, type) else type(message_type)
    return ROOT_ELEMENTS[cls]
