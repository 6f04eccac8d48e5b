"""ippc.protocol: rddlsim's IPPC competition protocol, sans-I/O.

Message dataclasses (:mod:`.messages`), Java value formatting (:mod:`.values`), the XML
codec (:mod:`.codec`), NUL and no-header framing (:mod:`.framing`) and one state machine
per role (:mod:`.connection`). No sockets, no clock, no global state.
"""

from __future__ import annotations

from .codec import (
    MAX_MESSAGE_SIZE,
    XML_DECLARATION,
    ObservedFluentsWriter,
    decode,
    encode,
    encode_turn,
)
from .connection import (
    NEED_DATA,
    RESUME,
    TRANSITIONS,
    ClientConnection,
    ClientState,
    ConnectionClosed,
    Direction,
    Event,
    ServerConnection,
    ServerState,
)
from .errors import (
    LocalProtocolError,
    MalformedMessageError,
    ProtocolError,
    RemoteProtocolError,
)
from .framing import MessageReader, frame
from .messages import (
    MESSAGE_TYPES,
    ROOT_ELEMENTS,
    Actions,
    Fluent,
    FluentValue,
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
from .values import (
    format_value,
    java_double,
    parse_java_double,
    parse_java_int,
    parse_value,
)

__all__ = [
    "MAX_MESSAGE_SIZE",
    "MESSAGE_TYPES",
    "NEED_DATA",
    "RESUME",
    "ROOT_ELEMENTS",
    "TRANSITIONS",
    "XML_DECLARATION",
    "Actions",
    "ClientConnection",
    "ClientState",
    "ConnectionClosed",
    "Direction",
    "Event",
    "Fluent",
    "FluentValue",
    "LocalProtocolError",
    "MalformedMessageError",
    "Message",
    "MessageReader",
    "ObservedFluentsWriter",
    "ProtocolError",
    "RemoteProtocolError",
    "ResourceNotification",
    "ResourceRequest",
    "RoundEnd",
    "RoundInit",
    "RoundRequest",
    "ServerConnection",
    "ServerState",
    "SessionEnd",
    "SessionInit",
    "SessionRequest",
    "Turn",
    "decode",
    "encode",
    "encode_turn",
    "format_value",
    "frame",
    "java_double",
    "parse_java_double",
    "parse_java_int",
    "parse_value",
    "root_element",
]
