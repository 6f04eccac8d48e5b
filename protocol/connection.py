"""Sans-I/O state machines for both ends of an IPPC session.

Theory of operation
-------------------
A session is a strict conversation: at any moment exactly one side may speak, and what it
may say depends only on where the conversation stands. So each role has a small set of
states (``ServerState``, ``ClientState``) and :data:`TRANSITIONS`, one dict, owns every
legal move: ``(state, direction, message class) -> next state``, direction being ``SEND``
(we write it) or ``RECV`` (the peer wrote it). Nothing else in this module decides what is
legal; the connection classes only look moves up in that table (h11 / wsproto style).

A connection never touches a socket or a clock. The transport feeds received bytes with
``receive_data`` (``b""`` = the peer closed), pulls typed events with ``next_event``
(a message dataclass, ``ConnectionClosed``, or ``NEED_DATA``) and writes whatever ``send``
returns. Received bytes are split into messages by a :class:`MessageReader` (NUL
terminated; bare XML documents for a client that asked for ``<no-header/>``), decoded by
the codec, and checked against the table.

Errors: a move the table does not allow, or bytes that are not a message, raise
``RemoteProtocolError`` when the peer made them (the state becomes ``ERROR`` and stays
there) and ``LocalProtocolError`` when our own code tried them (nothing is sent and the
state does not change). The resource-request detour is the one move that returns to
where it came from, so its target in the table is :data:`RESUME` and the connection
remembers the state to resume.

Kept from rddlsim on purpose: a frame that is not well-formed XML arriving where the
server waits for a round-request is taken as a resource-request (rddlsim answers it with
a resource-notification). Changed on purpose: no-header is per connection (rddlsim's flag
is process-wide), and nothing here ever exits a process.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import Enum
from typing import Final, Generic, Literal, TypeAlias, TypeVar

from .codec import MAX_MESSAGE_SIZE, decode, encode, encode_turn
from .errors import LocalProtocolError, MalformedMessageError, RemoteProtocolError
from .framing import MessageReader, frame
from .messages import (
    ROOT_ELEMENTS,
    Actions,
    Message,
    ResourceNotification,
    ResourceRequest,
    RoundEnd,
    RoundInit,
    RoundRequest,
    SessionEnd,
    SessionInit,
    SessionRequest,
    Turn,
    root_element,
)

__all__ = [
    "NEED_DATA",
    "RESUME",
    "TRANSITIONS",
    "ClientConnection",
    "ClientState",
    "ConnectionClosed",
    "Direction",
    "Event",
    "ServerConnection",
    "ServerState",
]

logger = logging.getLogger(__name__)


class ServerState(Enum):
    """Where a server-side session stands (``SEND_*``: the server must write next)."""

    # Members are singletons compared by identity; hashing them by identity (in C) keeps
    # the TRANSITIONS lookups of every message cheap (Enum hashes its name in Python).
    __hash__ = object.__hash__

    AWAIT_SESSION_REQUEST = "await-session-request"
    SEND_SESSION_INIT = "send-session-init"
    AWAIT_ROUND_REQUEST = "await-round-request"
    SEND_ROUND_INIT = "send-round-init"
    SEND_TURN = "send-turn"
    AWAIT_ACTIONS = "await-actions"
    SEND_TURN_OR_ROUND_END = "send-turn-or-round-end"
    SEND_RESOURCE_NOTIFICATION = "send-resource-notification"
    CLOSED = "closed"
    ERROR = "error"


class ClientState(Enum):
    """Where a client-side session stands (``SEND_*``: the client must write next)."""

    __hash__ = object.__hash__  # see ServerState

    SEND_SESSION_REQUEST = "send-session-request"
    AWAIT_SESSION_INIT = "await-session-init"
    SEND_ROUND_REQUEST = "send-round-request"
    AWAIT_ROUND_INIT = "await-round-init"
    AWAIT_TURN = "await-turn"
    SEND_ACTIONS = "send-actions"
    AWAIT_TURN_OR_ROUND_END = "await-turn-or-round-end"
    AWAIT_RESOURCE_NOTIFICATION = "await-resource-notification"
    CLOSED = "closed"
    ERROR = "error"


class Direction(Enum):
    """Who writes the message of a transition, seen from the connection's own side."""

    __hash__ = object.__hash__  # see ServerState

    SEND = "send"
    RECV = "recv"


class _Sentinel(Enum):
    NEED_DATA = "NEED_DATA"
    RESUME = "RESUME"

    def __repr__(self) -> str:
        return self.value


#: ``next_event`` result: no complete message is buffered yet; feed more bytes.
NEED_DATA: Final = _Sentinel.NEED_DATA
#: Transition target meaning "back to the state before the resource-request".
RESUME: Final = _Sentinel.RESUME


@dataclass(frozen=True)
class ConnectionClosed:
    """The peer closed the connection at a message boundary."""


Event: TypeAlias = Message | ConnectionClosed | Literal[_Sentinel.NEED_DATA]

_S, _C, SEND, RECV = ServerState, ClientState, Direction.SEND, Direction.RECV

State: TypeAlias = ServerState | ClientState
Target: TypeAlias = ServerState | ClientState | Literal[_Sentinel.RESUME]

#: Every legal move of both roles: (state, direction, message class) -> next state.
TRANSITIONS: Final[dict[tuple[State, Direction, type[Message]], Target]] = {
    # ---- server
    (_S.AWAIT_SESSION_REQUEST, RECV, SessionRequest): _S.SEND_SESSION_INIT,
    (_S.SEND_SESSION_INIT, SEND, SessionInit): _S.AWAIT_ROUND_REQUEST,
    (_S.AWAIT_ROUND_REQUEST, RECV, RoundRequest): _S.SEND_ROUND_INIT,
    (_S.AWAIT_ROUND_REQUEST, RECV, ResourceRequest): _S.SEND_RESOURCE_NOTIFICATION,
    (_S.AWAIT_ROUND_REQUEST, SEND, SessionEnd): _S.CLOSED,  # last round done, or time-out
    (_S.SEND_ROUND_INIT, SEND, RoundInit): _S.SEND_TURN,
    (_S.SEND_TURN, SEND, Turn): _S.AWAIT_ACTIONS,
    (_S.SEND_TURN, SEND, RoundEnd): _S.AWAIT_ROUND_REQUEST,  # a zero-turn round
    (_S.AWAIT_ACTIONS, RECV, Actions): _S.SEND_TURN_OR_ROUND_END,
    (_S.AWAIT_ACTIONS, RECV, ResourceRequest): _S.SEND_RESOURCE_NOTIFICATION,
    (_S.SEND_TURN_OR_ROUND_END, SEND, Turn): _S.AWAIT_ACTIONS,
    (_S.SEND_TURN_OR_ROUND_END, SEND, RoundEnd): _S.AWAIT_ROUND_REQUEST,
    (_S.SEND_RESOURCE_NOTIFICATION, SEND, ResourceNotification): RESUME,
    # ---- client
    (_C.SEND_SESSION_REQUEST, SEND, SessionRequest): _C.AWAIT_SESSION_INIT,
    (_C.AWAIT_SESSION_INIT, RECV, SessionInit): _C.SEND_ROUND_REQUEST,
    (_C.SEND_ROUND_REQUEST, SEND, RoundRequest): _C.AWAIT_ROUND_INIT,
    (_C.SEND_ROUND_REQUEST, SEND, ResourceRequest): _C.AWAIT_RESOURCE_NOTIFICATION,
    (_C.SEND_ROUND_REQUEST, RECV, SessionEnd): _C.CLOSED,  # server ended the session
    (_C.AWAIT_ROUND_INIT, RECV, RoundInit): _C.AWAIT_TURN,
    (_C.AWAIT_ROUND_INIT, RECV, SessionEnd): _C.CLOSED,  # e.g. PROST after a time-out
    (_C.AWAIT_TURN, RECV, Turn): _C.SEND_ACTIONS,
    (_C.AWAIT_TURN, RECV, RoundEnd): _C.SEND_ROUND_REQUEST,  # a zero-turn round
    (_C.SEND_ACTIONS, SEND, Actions): _C.AWAIT_TURN_OR_ROUND_END,
    (_C.SEND_ACTIONS, SEND, ResourceRequest): _C.AWAIT_RESOURCE_NOTIFICATION,
    (_C.AWAIT_TURN_OR_ROUND_END, RECV, Turn): _C.SEND_ACTIONS,
    (_C.AWAIT_TURN_OR_ROUND_END, RECV, RoundEnd): _C.SEND_ROUND_REQUEST,
    (_C.AWAIT_RESOURCE_NOTIFICATION, RECV, ResourceNotification): RESUME,
}


def _allowed(state: State, direction: Direction) -> list[type[Message]]:
    return [cls for (s, d, cls) in TRANSITIONS if s is state and d is direction]


def _names(classes: list[type[Message]]) -> str:
    return " or ".join(f"<{root_element(cls)}>" for cls in classes) or "nothing"


_StateT = TypeVar("_StateT", ServerState, ClientState)


class _Connection(Generic[_StateT]):
    """What both roles share: framing, decoding, and moving through TRANSITIONS."""

    _role: str

    def __init__(
        self,
        initial: _StateT,
        closed: _StateT,
        error: _StateT,
        reader_mode: Literal["nul", "bare"],
        max_size: int,
    ) -> None:
        self._state: _StateT = initial
        self._resume: _StateT | None = None
        self._reader = MessageReader(reader_mode, max_size)
        self._closed_state: _StateT = closed
        self._error_state: _StateT = error
        # states in which the peer may write something; in the others incoming bytes wait
        self._receiving: frozenset[State] = frozenset(
            s for (s, d, _) in TRANSITIONS if d is RECV and isinstance(s, type(initial))
        )

    @property
    def state(self) -> _StateT:
        """The current state."""
        return self._state

    @property
    def buffered(self) -> int:
        """Received bytes not yet handed out as events (an unfinished message, or
        messages written ahead): what a transport bounds and times."""
        return self._reader.buffered

    def discard_buffered(self) -> None:
        """Drop every received byte not yet handed out (a transport that gives the
        connection up frees them at once)."""
        self._reader.discard()

    def receive_data(self, data: bytes | bytearray) -> None:
        """Bytes received from the peer; ``b""`` means the peer closed the connection."""
        if data:
            self._reader.feed(data)
        else:
            self._reader.feed_eof()

    def next_event(self) -> Event:
        """The next event: a message, :class:`ConnectionClosed`, or :data:`NEED_DATA`.

        In a state where only we may write, received bytes stay buffered (a peer that
        writes ahead is not an error until its message is read in the wrong state). In
        the CLOSED state (session over) received bytes are dropped and the peer's EOF
        gives :class:`ConnectionClosed`.
        """
        if self._state is self._error_state:
            raise RemoteProtocolError(
                f"{self._role} connection is in the ERROR state; it cannot receive"
            )
        if self._state is self._closed_state:
            # The session is over: whatever still arrives is dropped (PROST, for one, sends a
            # round-request after a time-out's session-end); only the EOF is news.
            if self._reader.buffered:
                logger.debug(
                    "%s: dropping %d bytes received after the session ended",
                    self._role,
                    self._reader.buffered,
                )
                self._reader.discard()
            return ConnectionClosed() if self._reader.at_eof else NEED_DATA
        if self._state not in self._receiving:
            if self._reader.at_eof and self._reader.buffered == 0:
                return self._peer_closed()
            return NEED_DATA
        try:
            data = self._reader.next_message()
        except RemoteProtocolError:
            self._state = self._error_state
            raise
        if data is None:
            if self._reader.at_eof:
                return self._peer_closed()
            return NEED_DATA
        try:
            msg = decode(data)
        except MalformedMessageError as exc:
            msg = self._malformed(exc)
        except RemoteProtocolError:
            self._state = self._error_state
            raise
        target = TRANSITIONS.get((self._state, RECV, type(msg)))
        if target is None:
            expected = _names(_allowed(self._state, RECV))
            state = self._state
            self._state = self._error_state
            raise RemoteProtocolError(
                f"{self._role} in state {state.name} expected {expected} "
                f"but received <{root_element(msg)}>",
                message_text=data,
            )
        self._on_receive(msg)
        self._move(target)
        return msg

    def send(self, msg: Message) -> bytes:
        """The framed bytes that put ``msg`` on the wire; raises
        :class:`LocalProtocolError` if ``msg`` may not be sent now."""
        target = self._send_target(type(msg))
        wire = self._frame(msg)
        self._move(target)
        return wire

    def _send_target(self, cls: type[Message]) -> Target:
        """Where sending a ``cls`` now leads; LocalProtocolError if it is not allowed."""
        if self._state is self._error_state:
            raise LocalProtocolError(
                f"{self._role} connection is in the ERROR state; it cannot send"
            )
        target = TRANSITIONS.get((self._state, SEND, cls))
        if target is None:
            raise LocalProtocolError(
                f"{self._role} in state {self._state.name} cannot send "
                f"<{ROOT_ELEMENTS.get(cls, cls.__name__)}>;"
                f" allowed: {_names(_allowed(self._state, SEND))}"
            )
        return target

    # ------------------------------------------------------------------ hooks

    def _frame(self, msg: Message) -> bytes:
        raise NotImplementedError

    def _on_receive(self, msg: Message) -> None:
        """Role-specific bookkeeping for a received message (before the move)."""

    def _malformed(self, exc: MalformedMessageError) -> Message:
        """A frame that is not XML at all: an error unless the role has a quirk for it."""
        self._state = self._error_state
        raise exc

    def _peer_closed(self) -> ConnectionClosed:
        return ConnectionClosed()

    # ------------------------------------------------------------------ moves

    def _move(self, target: Target) -> None:
        """Go to ``target``, looked up in TRANSITIONS by the caller."""
        if target is RESUME:
            assert self._resume is not None  # set when the detour started
            self._state, self._resume = self._resume, None
            return
        if target in (_S.SEND_RESOURCE_NOTIFICATION, _C.AWAIT_RESOURCE_NOTIFICATION):
            self._resume = self._state
        assert isinstance(target, type(self._state))
        self._state = target


class ServerConnection(_Connection[ServerState]):
    """The server's side of one session (one TCP connection).

    Inbound messages are always NUL-terminated. Outbound ones are written like rddlsim:
    declaration, ``\\n``, document, NUL, unless this client's session-request carried
    ``<no-header/>``: then the bare document, no declaration, no NUL (rddlsim does that
    for every later session of the process too; we do it for this connection only).
    """

    _role = "server"

    def __init__(self, *, max_message_size: int = MAX_MESSAGE_SIZE) -> None:
        super().__init__(
            ServerState.AWAIT_SESSION_REQUEST,
            ServerState.CLOSED,
            ServerState.ERROR,
            "nul",
            max_message_size,
        )
        #: Set when the session-request asked for ``<no-header/>``.
        self.no_header = False

    def _on_receive(self, msg: Message) -> None:
        if isinstance(msg, SessionRequest):
            self.no_header = msg.no_header

    def _peer_closed(self) -> ConnectionClosed:
        self._state = ServerState.CLOSED
        return ConnectionClosed()

    def _malformed(self, exc: MalformedMessageError) -> Message:
        if self._state is ServerState.AWAIT_ROUND_REQUEST:
            # rddlsim quirk kept: its round-request reader treats any parse failure like a
            # resource-request and answers with a resource-notification.
            logger.debug(
                "malformed message where a round-request was expected, "
                "taken as a resource-request: %s",
                exc,
            )
            return ResourceRequest()
        return super()._malformed(exc)

    def _frame(self, msg: Message) -> bytes:
        try:
            if self.no_header:
                return frame(encode(msg, declaration=False), nul=False)
            return frame(encode(msg, declaration=True))
        except LocalProtocolError:
            raise
        except (TypeError, ValueError) as exc:
            raise LocalProtocolError(f"cannot encode {msg!r}: {exc}") from None

    def send_turn(
        self,
        turn_num: int,
        time_left: float,
        immediate_reward: float,
        fluents_xml: str | None,
    ) -> bytes:
        """``send(Turn(turn_num, time_left, immediate_reward, fluents))`` for a turn whose
        observed fluents are already written by an
        :class:`~ippc.protocol.codec.ObservedFluentsWriter` (``None`` for
        ``<no-observed-fluents/>``): the same checks, the same move, the same bytes,
        without building the fluents and the message (a server's every turn)."""
        target = self._send_target(Turn)
        try:
            if self.no_header:
                wire = encode_turn(
                    turn_num, time_left, immediate_reward, fluents_xml, declaration=False
                )
            else:
                wire = encode_turn(turn_num, time_left, immediate_reward, fluents_xml) + b"\0"
        except LocalProtocolError:
            raise
        except (TypeError, ValueError) as exc:
            raise LocalProtocolError(f"cannot encode turn {turn_num!r}: {exc}") from None
        self._move(target)
        return wire


class ClientConnection(_Connection[ClientState]):
    """The client's side of one session.

    ``no_header=True``: the session-request must carry ``<no-header/>``
    (``SessionRequest.no_header``) and the server's messages are then read as bare XML
    documents. Outbound messages are NUL-terminated; with ``declaration`` each starts with
    the XML declaration and ``\\n`` as rddlsim's Java client writes them.

    When the server closes the connection, ``next_event`` returns
    :class:`ConnectionClosed` and leaves the state alone: in :attr:`ClientState.CLOSED`
    that is the normal end, anywhere else the transport should treat it as an error.
    """

    _role = "client"

    def __init__(
        self,
        *,
        no_header: bool = False,
        declaration: bool = True,
        max_message_size: int = MAX_MESSAGE_SIZE,
    ) -> None:
        super().__init__(
            ClientState.SEND_SESSION_REQUEST,
            ClientState.CLOSED,
            ClientState.ERROR,
            "bare" if no_header else "nul",
            max_message_size,
        )
        self.no_header = no_header
        self.declaration = declaration

    def _frame(self, msg: Message) -> bytes:
        if isinstance(msg, SessionRequest) and msg.no_header != self.no_header:
            raise LocalProtocolError(
                f"session-request no_header={msg.no_header} but the connection was made "
                f"with no_header={self.no_header}"
            )
        try:
            return frame(encode(msg, declaration=self.declaration))
        except LocalProtocolError:
            raise
        except (TypeError, ValueError) as exc:
            raise LocalProtocolError(f"cannot encode {msg!r}: {exc}") from None
