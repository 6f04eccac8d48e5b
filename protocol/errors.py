"""Exceptions of the IPPC wire protocol (h11 style).

``RemoteProtocolError`` means the peer broke the protocol (bad bytes, wrong message for
the state, oversize message, EOF mid-message); ``LocalProtocolError`` means our own code
tried something the protocol does not allow (a message that is illegal in the current
state, text that cannot be written as XML). Both carry the offending message, cut short
for display, so a log line can show what came over the wire.
"""

from __future__ import annotations

__all__ = [
    "LocalProtocolError",
    "MalformedMessageError",
    "ProtocolError",
    "RemoteProtocolError",
]

#: How many bytes of the offending message an exception keeps for display.
MESSAGE_TEXT_LIMIT = 200


class ProtocolError(Exception):
    """Base class of every protocol error.

    ``str(error)`` says what was expected, what came and why; ``message_text`` holds the
    first :data:`MESSAGE_TEXT_LIMIT` bytes of the offending message (``None`` when there is
    no single message to blame, e.g. an oversize stream).
    """

    message_text: bytes | None
    message_size: int | None

    def __init__(self, reason: str, *, message_text: bytes | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        if message_text is None:
            self.message_text = None
            self.message_size = None
        else:
            self.message_text = bytes(message_text[:MESSAGE_TEXT_LIMIT])
            self.message_size = len(message_text)

    def __str__(self) -> str:
        if self.message_text is None:
            return self.reason
        shown = repr(self.message_text)
        if self.message_size is not None and self.message_size > MESSAGE_TEXT_LIMIT:
            shown += f"... ({self.message_size} bytes)"
        return f"{self.reason} [message: {shown}]"


class LocalProtocolError(ProtocolError):
    """Our side tried to do something the protocol does not allow."""


class RemoteProtocolError(ProtocolError):
    """The peer sent something the protocol does not allow."""


class MalformedMessageError(RemoteProtocolError):
    """The peer's message is not a well-formed XML document at all.

    Kept apart from other remote errors because rddlsim answers a malformed message that
    arrives where a round-request is expected with a resource-notification (see
    :class:`ippc.protocol.ServerConnection`).
    """
