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
import functools
import operator
import re
from collections.abc import Callable, Iterable, Sequence
from typing import Final

from lxml import etree

from .errors import LocalProtocolError, MalformedMessageError, RemoteProtocolError
from .messages import (
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
)
from .values import _java_trim, format_value, java_double, parse_java_double, parse_java_int

__all__ = [
    "MAX_MESSAGE_SIZE",
    "XML_DECLARATION",
    "ObservedFluentsWriter",
    "decode",
    "encode",
    "encode_turn",
]

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
    if not isinstance(text, str):
        raise LocalProtocolError(f"<{tag}> must be a str, not {type(text).__name__} {text!r}")
    # A text node, even an empty one, makes Xerces write a start and an end tag.
    out.append(f"<{tag}>{_escape(text)}</{tag}>")


def _int(out: list[str], tag: str, value: object, *, bits: int = 32) -> None:
    # Java peers read these with Integer.valueOf / Long.valueOf: a float ("5.0") or an
    # out-of-range number would break them, so refuse it here rather than on their side.
    try:
        number = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise LocalProtocolError(
            f"<{tag}> must be an int, not {type(value).__name__} {value!r}"
        ) from None
    if not -(2 ** (bits - 1)) <= number < 2 ** (bits - 1):
        raise LocalProtocolError(f"<{tag}> {number} does not fit a {bits}-bit Java integer")
    out.append(f"<{tag}>{number}</{tag}>")


def _dbl(out: list[str], tag: str, value: object) -> None:
    try:
        if isinstance(value, str | bytes):
            raise TypeError
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise LocalProtocolError(
            f"<{tag}> must be a number, not {type(value).__name__} {value!r}"
        ) from None
    out.append(f"<{tag}>{java_double(number)}</{tag}>")


@functools.lru_cache(maxsize=1 << 16)
def _fluent_head(kind: str, name: str, args: tuple[str, ...]) -> str:
    # Everything of a fluent before its value: the same in every turn, so
    # built (and checked) once per grounding.
    wrapper = "observed-fluent" if kind == "fluent" else "action"
    out = [f"<{wrapper}>"]
    _leaf(out, f"{kind}-name", name)
    for arg in args:
        _leaf(out, f"{kind}-arg", arg)
    out.append(f"<{kind}-value>")
    return "".join(out)


_FLUENT_TAIL = {"fluent": "</fluent-value></observed-fluent>", "action": "</action-value></action>"}


def _fluent(out: list[str], kind: str, fluent: Fluent) -> None:
    # kind is "fluent" (observed-fluent) or "action" (action)
    try:
        head = _fluent_head(kind, fluent.name, fluent.args)
    except TypeError:  # unhashable args: let _leaf say what is wrong
        head = _fluent_head.__wrapped__(kind, fluent.name, tuple(fluent.args))
    value = fluent.value
    if value is True:
        text = "true"
    elif value is False:
        text = "false"
    else:
        try:
            text = format_value(value)
        except TypeError as exc:
            wrapper = "observed-fluent" if kind == "fluent" else "action"
            raise LocalProtocolError(f"{wrapper} {fluent.name}: {exc}") from None
        if not isinstance(text, str):
            raise LocalProtocolError(f"{kind}-value must be a str, not {type(text).__name__}")
        text = _escape(text)
    out.append(head)
    out.append(text)
    out.append(_FLUENT_TAIL[kind])


def _turn_head(out: list[str], turn_num: int, time_left: float, immediate_reward: float) -> None:
    out.append("<turn>")
    _int(out, "turn-num", turn_num)
    _dbl(out, "time-left", time_left)
    _dbl(out, "immediate-reward", immediate_reward)


class ObservedFluentsWriter:
    """The ``<observed-fluent>`` elements of turns that list one fixed sequence of
    groundings, only the values changing from turn to turn (what a server sends: every
    grounding of every state fluent, always in the same order).

    Each element's markup is built once; :meth:`write` only picks or formats the values.
    ``encode_turn(n, t, r, writer.write(values))`` is byte for byte
    ``encode(Turn(n, t, r, tuple(Fluent(name, args, v) ...)))``.
    """

    __slots__ = ("groundings", "_heads", "_true", "_false")

    def __init__(self, groundings: Iterable[tuple[str, Iterable[str]]]) -> None:
        self.groundings: tuple[tuple[str, tuple[str, ...]], ...] = tuple(
            (name, tuple(args)) for name, args in groundings
        )
        tail = _FLUENT_TAIL["fluent"]
        self._heads = [_fluent_head("fluent", name, args) for name, args in self.groundings]
        self._true = [head + "true" + tail for head in self._heads]
        self._false = [head + "false" + tail for head in self._heads]

    def __len__(self) -> int:
        return len(self._heads)

    def write(self, values: Sequence[FluentValue]) -> str:
        """The elements for ``values`` (one per grounding, in order)."""
        if len(values) != len(self._heads):
            raise LocalProtocolError(
                f"{len(values)} values for {len(self._heads)} observed fluents"
            )
        out = []
        true, false = self._true, self._false
        for i, value in enumerate(values):
            if value is True:
                out.append(true[i])
            elif value is False:
                out.append(false[i])
            else:
                name, args = self.groundings[i]
                _fluent(out, "fluent", Fluent(name, args, value))
        return "".join(out)


def encode_turn(
    turn_num: int,
    time_left: float,
    immediate_reward: float,
    fluents_xml: str | None,
    *,
    declaration: bool = True,
) -> bytes:
    """A turn whose observed fluents are already written (:class:`ObservedFluentsWriter`);
    ``None`` for ``<no-observed-fluents/>``. The bytes :func:`encode` writes for the same
    turn."""
    if (
        type(turn_num) is int
        and -0x8000_0000 <= turn_num <= 0x7FFF_FFFF
        and type(time_left) is float
        and type(immediate_reward) is float
    ):
        # the values every server turn has: what _turn_head writes for them, in one go
        head = (
            f"<turn><turn-num>{turn_num}</turn-num><time-left>{java_double(time_left)}"
            f"</time-left><immediate-reward>{java_double(immediate_reward)}</immediate-reward>"
        )
    else:
        out: list[str] = []
        _turn_head(out, turn_num, time_left, immediate_reward)
        head = "".join(out)
    body = "<no-observed-fluents/>" if fluents_xml is None else fluents_xml
    doc = (head + body + "</turn>").encode("ascii")
    return XML_DECLARATION + doc if declaration else doc


def _body(msg: Message) -> list[str]:
    """The root element as a list of string pieces."""
    out: list[str] = []
    if isinstance(msg, Turn):
        _turn_head(out, msg.turn_num, msg.time_left, msg.immediate_reward)
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
        _int(out, "session-id", msg.session_id)
        _int(out, "num-rounds", msg.num_rounds)
        _dbl(out, "time-allowed", msg.time_allowed)
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
        _int(out, "round-num", msg.round_num)
        _int(out, "round-left", msg.round_left)
        _dbl(out, "time-left", msg.time_left)
        out.append("</round-init>")
    elif isinstance(msg, RoundEnd):
        out.append("<round-end>")
        _leaf(out, "instance-name", msg.instance_name)
        _leaf(out, "client-name", msg.client_name)
        _int(out, "round-num", msg.round_num)
        _dbl(out, "round-reward", msg.round_reward)
        _int(out, "turns-used", msg.turns_used)
        _int(out, "time-left", msg.time_left, bits=64)
        _dbl(out, "immediate-reward", msg.immediate_reward)
        out.append("</round-end>")
    elif isinstance(msg, SessionEnd):
        out.append("<session-end>")
        _leaf(out, "instance-name", msg.instance_name)
        _dbl(out, "total-reward", msg.total_reward)
        _int(out, "rounds-used", msg.rounds_used)
        _leaf(out, "client-name", msg.client_name)
        _int(out, "session-id", msg.session_id)
        _int(out, "time-left", msg.time_left, bits=64)
        out.append("</session-end>")
    elif isinstance(msg, ResourceRequest):
        out.append("<resource-request/>")
    elif isinstance(msg, ResourceNotification):
        out.append("<resource-notification>")
        _dbl(out, "time-left", msg.time_left)
        _leaf(out, "memory-left", msg.memory_left)
        out.append("</resource-notification>")
    else:
        raise LocalProtocolError(f"not a protocol message: {msg!r}")
    return out


def encode(msg: Message, *, declaration: bool = True) -> bytes:
    """The XML document for ``msg`` exactly as rddlsim writes it (no terminator).

    With ``declaration`` the document starts with :data:`XML_DECLARATION`. Raises
    :class:`LocalProtocolError` for text XML cannot carry (control characters), a value
    that is not a fluent value, a non-integer or out-of-range number where Java reads an
    int or long, or a field of the wrong type.
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
    name_tag, arg_tag, value_tag = f"{kind}-name", f"{kind}-arg", f"{kind}-value"
    out = []
    for el in f.root.iterdescendants(wrapper):
        # One pass over the descendants (a turn can hold thousands of fluents) with the
        # getElementsByTagName rules: first name, every arg, first value.
        name: str | None = None
        value: str | None = None
        args = []
        for sub in el.iterdescendants(name_tag, arg_tag, value_tag):
            tag = sub.tag
            if tag == arg_tag:
                args.append(sub.text or "")
            elif tag == name_tag:
                if name is None:
                    name = sub.text or ""
            elif value is None:
                value = sub.text or ""
        if name is None:
            f.text(name_tag, el)  # raises: names the missing element
        if value is None:
            f.text(value_tag, el)
        out.append(Fluent(name or "", tuple(args), value or ""))
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


# The messages clients send most, exactly as they send them: decoded without
# a parser (a noop every turn is the common case of a competition).
_COMMON: Final[dict[bytes, Message]] = {
    decl + body: msg
    for decl in (b"", XML_DECLARATION)
    for body, msg in (
        (b"<actions/>", Actions()),
        (b"<actions></actions>", Actions()),
        (b"<round-request/>", RoundRequest()),
        (b"<round-request></round-request>", RoundRequest()),
        (
            b"<round-request><execute-policy>yes</execute-policy></round-request>",
            RoundRequest(execute_policy=True),
        ),
        (
            b"<round-request> <execute-policy>yes</execute-policy> </round-request>",
            RoundRequest(execute_policy=True),
        ),
        (b"<resource-request/>", ResourceRequest()),
    )
}


def decode(data: bytes) -> Message:
    """Parse one message (declaration optional, no terminator).

    Raises :class:`MalformedMessageError` (a :class:`RemoteProtocolError`) if ``data`` is
    not a well-formed UTF-8 XML document, and :class:`RemoteProtocolError` for a DOCTYPE,
    an oversize message, an unknown root element, a missing required field or an
    unparsable number in a server message.
    """
    data = bytes(data)
    fast = _COMMON.get(data)
    if fast is not None:
        return fast
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
