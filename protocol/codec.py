"""XML codec: messages <-> the bytes rddlsim puts on the wire (one document, no framing).

Encoding reproduces rddlsim's writer (Xerces 2.6 ``XMLSerializer`` on a DOM, then a
US-ASCII ``OutputStreamWriter``) byte for byte: the declaration and one ``\\n``, then the
root element, no whitespace between elements, ``<x/>`` for an element without children
but ``<x></x>`` for one holding an empty text; ``&``, ``<``, ``>`` escaped (quotes are
not), ``\\r`` as ``&#xd;``, characters beyond the BMP as ``&#x...;``, every other
non-ASCII character as ``?``.

Decoding follows rddlsim's reader (Xerces DOM + ``getElementsByTagName``): declaration
optional, whitespace and element order free, fields found by descendant search (the first
one wins), text used untrimmed. It is hardened where rddlsim is not: no DTD at all, no
entity expansion, no network, a size cap, UTF-8 only.
"""

from __future__ import annotations

import base64
import binascii
import re
from collections.abc import Callable
from typing import Final

from lxml import etree

from .errors import LocalProtocolError, MalformedMessageError, RemoteProtocolError
from .messages import (
    ROOT_ELEMENTS,
    Actions,
    Fluent,
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
)
from .values import _java_trim, format_value, java_double, parse_java_double, parse_java_int

__all__ = ["MAX_MESSAGE_SIZE", "XML_DECLARATION", "decode", "encode"]

#: rddlsim's inbound buffer (``Server.MAX_BYTES``): the largest message we accept.
MAX_MESSAGE_SIZE: Final = 10 * 1024 * 1024

#: What rddlsim and its Java client put before every root element (39 bytes).
XML_DECLARATION: Final = b'<?xml version="1.0" encoding="UTF-8"?>\n'

# ---------------------------------------------------------------------------- encoding

# Anything that is not plain printable-or-tab/newline ASCII (or is XML-special) needs the
# slow path; the common case (names, numbers, base64) passes through untouched.
_NEEDS_ESCAPE = re.compile(r"[^\t\n\x20-\x25\x27-\x3b\x3d\x3f-\x7f]")
_INVALID_XML_CHAR = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")


def _escape(text: str) -> str:
    """Text content as Xerces' serializer writes it, already mapped to US-ASCII."""
    if not _NEEDS_ESCAPE.search(text):
        return text
    bad = _INVALID_XML_CHAR.search(text)
    if bad:
        # Xerces refuses these too ("is an invalid XML character"): XML 1.0 cannot carry them.
        raise LocalProtocolError(
            f"cannot write {bad.group()!r} (U+{ord(bad.group()):04X}) in XML text {text[:80]!r}"
        )
    out = []
    for ch in text:
        if ch == "&":
            out.append("&amp;")
        elif ch == "<":
            out.append("&lt;")
        elif ch == ">":
            out.append("&gt;")
        elif ch == "\r":
            out.append("&#xd;")
        elif ch > "\uffff":
            out.append(f"&#x{ord(ch):x};")
        elif ch > "\x7f":
            out.append("?")  # the US-ASCII writer's replacement
        else:
            out.append(ch)
    return "".join(out)


def _leaf(out: list[str], tag: str, text: str) -> None:
    # A text node, even an empty one, makes Xerces write a start and an end tag.
    out.append(f"<{tag}>{_escape(text)}</{tag}>")


def _fluent(out: list[str], kind: str, fluent: Fluent) -> None:
    # kind is "fluent" (observed-fluent) or "action" (action)
    wrapper = "observed-fluent" if kind == "fluent" else "action"
    out.append(f"<{wrapper}>")
    _leaf(out, f"{kind}-name", fluent.name)
    for arg in fluent.args:
        _leaf(out, f"{kind}-arg", arg)
    try:
        text = format_value(fluent.value)
    except TypeError as exc:
        raise LocalProtocolError(f"{wrapper} {fluent.name}: {exc}") from None
    _leaf(out, f"{kind}-value", text)
    out.append(f"</{wrapper}>")


def _body(msg: Message) -> list[str]:
    """The root element as a list of string pieces."""
    out: list[str] = []
    if isinstance(msg, Turn):
        out.append("<turn>")
        _leaf(out, "turn-num", str(msg.turn_num))
        _leaf(out, "time-left", java_double(msg.time_left))
        _leaf(out, "immediate-reward", java_double(msg.immediate_reward))
        if msg.fluents is None:
            out.append("<no-observed-fluents/>")
        else:
            for fluent in msg.fluents:
                _fluent(out, "fluent", fluent)
        out.append("</turn>")
    elif isinstance(msg, Actions):
        if not msg.actions:
            out.append("<actions/>")
        else:
            out.append("<actions>")
            for action in msg.actions:
                _fluent(out, "action", action)
            out.append("</actions>")
    elif isinstance(msg, SessionRequest):
        out.append("<session-request>")
        _leaf(out, "problem-name", msg.problem_name)
        _leaf(out, "client-name", msg.client_name)
        if msg.input_language is not None:
            _leaf(out, "input-language", msg.input_language)
        if msg.no_header:
            out.append("<no-header/>")
        out.append("</session-request>")
    elif isinstance(msg, SessionInit):
        out.append("<session-init>")
        _leaf(out, "task", base64.b64encode(msg.task).decode("ascii"))
        _leaf(out, "session-id", str(msg.session_id))
        _leaf(out, "num-rounds", str(msg.num_rounds))
        _leaf(out, "time-allowed", java_double(msg.time_allowed))
        out.append("</session-init>")
    elif isinstance(msg, RoundRequest):
        if msg.execute_policy is None:
            out.append("<round-request/>")
        else:
            out.append("<round-request>")
            _leaf(out, "execute-policy", "yes" if msg.execute_policy else "no")
            out.append("</round-request>")
    elif isinstance(msg, RoundInit):
        out.append("<round-init>")
        _leaf(out, "round-num", str(msg.round_num))
        _leaf(out, "round-left", str(msg.round_left))
        _leaf(out, "time-left", java_double(msg.time_left))
        out.append("</round-init>")
    elif isinstance(msg, RoundEnd):
        out.append("<round-end>")
        _leaf(out, "instance-name", msg.instance_name)
        _leaf(out, "client-name", msg.client_name)
        _leaf(out, "round-num", str(msg.round_num))
        _leaf(out, "round-reward", java_double(msg.round_reward))
        _leaf(out, "turns-used", str(msg.turns_used))
        _leaf(out, "time-left", str(msg.time_left))
        _leaf(out, "immediate-reward", java_double(msg.immediate_reward))
        out.append("</round-end>")
    elif isinstance(msg, SessionEnd):
        out.append("<session-end>")
        _leaf(out, "instance-name", msg.instance_name)
        _leaf(out, "total-reward", java_double(msg.total_reward))
        _leaf(out, "rounds-used", str(msg.rounds_used))
        _leaf(out, "client-name", msg.client_name)
        _leaf(out, "session-id", str(msg.session_id))
        _leaf(out, "time-left", str(msg.time_left))
        out.append("</session-end>")
    elif isinstance(msg, ResourceRequest):
        out.append("<resource-request/>")
    elif isinstance(msg, ResourceNotification):
        out.append("<resource-notification>")
        _leaf(out, "time-left", java_double(msg.time_left))
        _leaf(out, "memory-left", msg.memory_left)
        out.append("</resource-notification>")
    else:
        raise LocalProtocolError(f"not a protocol message: {msg!r}")
    return out


def encode(msg: Message, *, declaration: bool = True) -> bytes:
    """The XML document for ``msg`` exactly as rddlsim writes it (no terminator).

    With ``declaration`` the document starts with :data:`XML_DECLARATION`. Raises
    :class:`LocalProtocolError` for text XML cannot carry (control characters) or a value
    that is not a fluent value.
    """
    doc = "".join(_body(msg)).encode("ascii")
    return XML_DECLARATION + doc if declaration else doc


# ---------------------------------------------------------------------------- decoding


def _parser() -> etree.XMLParser:
    # A fresh parser per document: lxml parsers are not thread-safe and this keeps the
    # module free of global state. Forcing UTF-8 means a declared encoding cannot smuggle a
    # DOCTYPE past the byte scan in decode().
    return etree.XMLParser(
        encoding="utf-8",
        resolve_entities=False,
        no_network=True,
        load_dtd=False,
        dtd_validation=False,
        huge_tree=False,
        collect_ids=False,
        remove_blank_text=False,
    )


class _Fields:
    """Field access on one parsed message, with errors that name root and field."""

    __slots__ = ("root", "name", "data")

    def __init__(self, root: etree._Element, data: bytes) -> None:
        self.root = root
        self.name = str(root.tag)
        self.data = data

    def error(self, reason: str) -> RemoteProtocolError:
        return RemoteProtocolError(f"<{self.name}>: {reason}", message_text=self.data)

    def first(self, tag: str, within: etree._Element | None = None) -> str | None:
        """Text of the first descendant ``tag`` (``""`` if empty), ``None`` if absent."""
        for el in (self.root if within is None else within).iterdescendants(tag):
            return el.text or ""
        return None

    def text(self, tag: str, within: etree._Element | None = None) -> str:
        value = self.first(tag, within)
        if value is None:
            where = f"<{self.name}>" if within is None else f"<{within.tag}> in <{self.name}>"
            raise RemoteProtocolError(
                f"{where}: required element <{tag}> is missing", message_text=self.data
            )
        return value

    def all(self, tag: str, within: etree._Element) -> tuple[str, ...]:
        return tuple(el.text or "" for el in within.iterdescendants(tag))

    def has(self, tag: str) -> bool:
        for _ in self.root.iterdescendants(tag):
            return True
        return False

    def integer(self, tag: str, *, bits: int = 32) -> int:
        text = self.text(tag)
        try:
            return parse_java_int(text, bits=bits)
        except ValueError:
            kind = "an int" if bits == 32 else "a long"
            raise self.error(f"<{tag}> is not {kind}: {text[:80]!r}") from None

    def double(self, tag: str) -> float:
        text = self.text(tag)
        try:
            return parse_java_double(text)
        except ValueError:
            raise self.error(f"<{tag}> is not a double: {text[:80]!r}") from None


def _fluents(f: _Fields, wrapper: str, kind: str) -> tuple[Fluent, ...]:
    out = []
    for el in f.root.iterdescendants(wrapper):
        out.append(
            Fluent(
                f.text(f"{kind}-name", el),
                f.all(f"{kind}-arg", el),
                f.text(f"{kind}-value", el),
            )
        )
    return tuple(out)


def _session_request(f: _Fields) -> SessionRequest:
    return SessionRequest(
        problem_name=f.text("problem-name"),
        client_name=f.text("client-name"),
        input_language=f.first("input-language"),
        no_header=f.has("no-header"),
    )


def _session_init(f: _Fields) -> SessionInit:
    task_text = f.text("task")
    try:
        # Java's encoder writes no line breaks; tolerate whitespace anyway, nothing else.
        task = base64.b64decode("".join(task_text.split()), validate=True)
    except (binascii.Error, ValueError):
        raise f.error(f"<task> is not base64: {task_text[:80]!r}") from None
    return SessionInit(
        task=task,
        session_id=f.integer("session-id"),
        num_rounds=f.integer("num-rounds"),
        time_allowed=f.double("time-allowed"),
    )


def _round_request(f: _Fields) -> RoundRequest:
    text = f.first("execute-policy")
    if text is None:
        return RoundRequest(None)
    # rddlsim trims this one (String.trim) before comparing with "yes".
    return RoundRequest(_java_trim(text) == "yes")


def _round_init(f: _Fields) -> RoundInit:
    return RoundInit(
        round_num=f.integer("round-num"),
        round_left=f.integer("round-left"),
        time_left=f.double("time-left"),
    )


def _turn(f: _Fields) -> Turn:
    fluents = None if f.has("no-observed-fluents") else _fluents(f, "observed-fluent", "fluent")
    return Turn(
        turn_num=f.integer("turn-num"),
        time_left=f.double("time-left"),
        immediate_reward=f.double("immediate-reward"),
        fluents=fluents,
    )


def _actions(f: _Fields) -> Actions:
    return Actions(_fluents(f, "action", "action"))


def _round_end(f: _Fields) -> RoundEnd:
    return RoundEnd(
        instance_name=f.text("instance-name"),
        client_name=f.text("client-name"),
        round_num=f.integer("round-num"),
        round_reward=f.double("round-reward"),
        turns_used=f.integer("turns-used"),
        time_left=f.integer("time-left", bits=64),
        immediate_reward=f.double("immediate-reward"),
    )


def _session_end(f: _Fields) -> SessionEnd:
    return SessionEnd(
        instance_name=f.text("instance-name"),
        total_reward=f.double("total-reward"),
        rounds_used=f.integer("rounds-used"),
        client_name=f.text("client-name"),
        session_id=f.integer("session-id"),
        time_left=f.integer("time-left", bits=64),
    )


def _resource_notification(f: _Fields) -> ResourceNotification:
    memory = f.first("memory-left")
    return ResourceNotification(
        time_left=f.double("time-left"), memory_left="enough" if memory is None else memory
    )


_DECODERS: Final[dict[str, Callable[[_Fields], Message]]] = {
    ROOT_ELEMENTS[SessionRequest]: _session_request,
    ROOT_ELEMENTS[SessionInit]: _session_init,
    ROOT_ELEMENTS[RoundRequest]: _round_request,
    ROOT_ELEMENTS[RoundInit]: _round_init,
    ROOT_ELEMENTS[Turn]: _turn,
    ROOT_ELEMENTS[Actions]: _actions,
    ROOT_ELEMENTS[RoundEnd]: _round_end,
    ROOT_ELEMENTS[SessionEnd]: _session_end,
    ROOT_ELEMENTS[ResourceRequest]: lambda f: ResourceRequest(),
    ROOT_ELEMENTS[ResourceNotification]: _resource_notification,
}


def decode(data: bytes) -> Message:
    """Parse one message (declaration optional, no terminator).

    Raises :class:`MalformedMessageError` (a :class:`RemoteProtocolError`) if ``data`` is
    not a well-formed UTF-8 XML document, and :class:`RemoteProtocolError` for a DOCTYPE,
    an oversize message, an unknown root element, a missing required field or an
    unparsable number in a server message.
    """
    data = bytes(data)
    if len(data) > MAX_MESSAGE_SIZE:
        raise RemoteProtocolError(
            f"message of {len(data)} bytes exceeds the {MAX_MESSAGE_SIZE}-byte limit",
            message_text=data,
        )
    # No DTD ever: it is the door to entity bombs and external entities, and no peer
    # sends one. The parser reads UTF-8 only, so the bytes must show it literally.
    if b"<!DOCTYPE" in data:
        raise RemoteProtocolError("document type declarations are not allowed", message_text=data)
    try:
        root = etree.fromstring(data, _parser())
    except etree.XMLSyntaxError as exc:
        raise MalformedMessageError(f"not well-formed XML: {exc}", message_text=data) from None
    if root.getroottree().docinfo.doctype:  # belt and braces; the scan above catches it
        raise RemoteProtocolError("document type declarations are not allowed", message_text=data)
    tag = root.tag
    decoder = _DECODERS.get(tag) if isinstance(tag, str) else None
    if decoder is None:
        raise RemoteProtocolError(
            f"unknown root element <{tag}>; expected one of "
            + ", ".join(f"<{name}>" for name in _DECODERS),
            message_text=data,
        )
    return decoder(_Fields(root, data))
