"""Property-based tests: valid messages survive encode -> decode, and arbitrary or mangled
bytes make the codec, the readers and both connections raise ProtocolError and nothing
else, always finishing."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ippc.protocol import (
    MESSAGE_TYPES,
    NEED_DATA,
    Actions,
    ClientConnection,
    ConnectionClosed,
    Fluent,
    Message,
    MessageReader,
    ProtocolError,
    RemoteProtocolError,
    ResourceNotification,
    ResourceRequest,
    RoundEnd,
    RoundInit,
    RoundRequest,
    ServerConnection,
    SessionEnd,
    SessionInit,
    SessionRequest,
    Turn,
    decode,
    encode,
    format_value,
    frame,
)
from ippc.protocol.connection import TRANSITIONS, Direction

from .corpus import RDDLSIM_SCENARIOS, load_transcript

# ====================================================================== strategies

# Printable ASCII plus tab, newline and carriage return: XML-special characters included
# (they are escaped and come back), non-ASCII and control characters left out (rddlsim's
# writer turns the former into '?' and XML cannot carry the latter).
TEXT_CHARS = st.characters(min_codepoint=0x20, max_codepoint=0x7E) | st.sampled_from("\t\n\r")
text = st.text(TEXT_CHARS, max_size=12)
name = st.text(TEXT_CHARS, min_size=1, max_size=12)
int32 = st.integers(-(2**31), 2**31 - 1)
int64 = st.integers(-(2**63), 2**63 - 1)
double = st.floats(allow_nan=False)
fluents = st.lists(
    st.builds(Fluent, name, st.lists(name, max_size=3).map(tuple), text), max_size=6
).map(tuple)

messages: st.SearchStrategy[Message] = st.one_of(
    st.builds(SessionRequest, text, text, st.none() | text, st.booleans()),
    st.builds(SessionInit, st.binary(max_size=200), int32, int32, double),
    st.builds(RoundRequest, st.sampled_from([None, True, False])),
    st.builds(RoundInit, int32, int32, double),
    st.builds(Turn, int32, double, double, st.none() | fluents),
    st.builds(Actions, fluents),
    st.builds(RoundEnd, text, text, int32, double, int32, int64, double),
    st.builds(SessionEnd, text, double, int32, text, int32, int64),
    st.just(ResourceRequest()),
    st.builds(ResourceNotification, double, text),
)


@given(messages, st.booleans())
def test_valid_messages_round_trip(msg: Message, declaration: bool) -> None:
    doc = encode(msg, declaration=declaration)
    assert doc.isascii()
    assert decode(doc) == msg


@given(st.lists(messages, min_size=1, max_size=5), st.sampled_from([b"", b"\n", b"\0", b" \n"]))
def test_messages_survive_both_framings(batch: list[Message], junk: bytes) -> None:
    nul = MessageReader("nul")
    nul.feed(b"".join(frame(encode(m)) for m in batch))
    bare = MessageReader("bare")
    bare.feed(b"".join(junk + encode(m, declaration=False) for m in batch))
    for reader in (nul, bare):
        reader.feed_eof()
        got = []
        while (doc := reader.next_message()) is not None:
            got.append(decode(doc))
        assert got == batch


typed_value = st.booleans() | int32 | double | name


@given(name, st.lists(name, max_size=3), typed_value)
def test_typed_values_come_back_as_their_java_text(n: str, args: list[str], value: object) -> None:
    sent = Actions((Fluent(n, tuple(args), value),))  # type: ignore[arg-type]
    got = decode(encode(sent))
    assert got == Actions((Fluent(n, tuple(args), format_value(value)),))


# ====================================================================== fuzzing helpers


@st.composite
def mangled(draw: st.DrawFn, seeds: list[bytes]) -> bytes:
    """A real message or stream with a few random edits."""
    data = bytearray(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["delete", "insert", "replace", "duplicate", "truncate"]))
        pos = draw(st.integers(0, len(data)))
        if op == "delete":
            del data[pos : pos + draw(st.integers(1, 8))]
        elif op == "insert":
            data[pos:pos] = draw(
                st.binary(min_size=1, max_size=8)
                | st.sampled_from([b"<", b">", b"/>", b"\0", b"<!--", b"<!DOCTYPE x>", b"&"])
            )
        elif op == "replace" and pos < len(data):
            data[pos] = draw(st.integers(0, 255))
        elif op == "duplicate":
            data[pos:pos] = data[pos : pos + draw(st.integers(1, 40))]
        else:
            del data[pos:]
    return bytes(data)


SEED_MESSAGES = [
    encode(SessionRequest("sysadmin_inst_mdp__1", "me", "rddl", True)),
    encode(RoundRequest(True)),
    encode(Actions((Fluent("reboot", ("c1",), "true"), Fluent("walk", ("p1",), "@left")))),
    encode(Turn(1, 5.0, 0.0, (Fluent("running", ("c1",), "true"),))),
    encode(Turn(1, 5.0, 0.0, None), declaration=False),
    encode(RoundEnd("i", "c", 0, 1.0, 5, -704, 1.0)),
    encode(SessionEnd("i", 1.0, 1, "c", 1, 7)),
    encode(SessionInit(b"domain", 1, 2, 1080000.0)),
    encode(ResourceNotification(1.0)),
    b"<a x='>'><![CDATA[</a>]]><!-- c --><?p ?></a>",
]

XMLISH = st.lists(
    st.sampled_from(
        [
            b"<a>",
            b"</a>",
            b"<b/>",
            b"<!--",
            b"-->",
            b"<?x",
            b"?>",
            b"<![CDATA[",
            b"]]>",
            b"'",
            b'"',
            b">",
            b"<",
            b"/",
            b"\0",
            b"\n",
            b" ",
            b"text",
            b"<!DOCTYPE a [",
            b"]",
            b"\xef\xbb\xbf",
            b'<?xml version="1.0"?>',
            b"<actions/>",
        ]
    ),
    max_size=30,
).map(b"".join)

fuzz_bytes = st.binary(max_size=300) | XMLISH | mangled(SEED_MESSAGES)
chunk_sizes = st.lists(st.integers(1, 64), min_size=1, max_size=8)


def chunks(data: bytes, sizes: list[int]) -> list[bytes]:
    out, pos, i = [], 0, 0
    while pos < len(data):
        size = sizes[i % len(sizes)]
        out.append(data[pos : pos + size])
        pos, i = pos + size, i + 1
    return out


# ====================================================================== codec and readers


@given(fuzz_bytes)
def test_decode_raises_only_protocol_errors(data: bytes) -> None:
    try:
        msg = decode(data)
    except ProtocolError as exc:
        assert isinstance(exc, RemoteProtocolError)
        return
    assert isinstance(msg, MESSAGE_TYPES)


def read_all(mode: str, data: bytes, sizes: list[int]) -> tuple[list[bytes], bool]:
    """Messages read from ``data`` fed in chunks, and whether the reader raised."""
    reader = MessageReader(mode, max_size=200)  # type: ignore[arg-type]
    got: list[bytes] = []
    try:
        for piece in chunks(data, sizes):
            reader.feed(piece)
            for _ in range(len(piece) + 2):  # every message consumes at least one byte
                msg = reader.next_message()
                if msg is None:
                    break
                got.append(msg)
            else:
                raise AssertionError("reader returned more messages than bytes")
            assert reader.buffered <= 200 + 64
        reader.feed_eof()
        for _ in range(len(data) + 2):
            msg = reader.next_message()
            if msg is None:
                break
            got.append(msg)
        else:
            raise AssertionError("reader returned more messages than bytes")
    except ProtocolError as exc:
        assert isinstance(exc, RemoteProtocolError)
        return got, True
    assert reader.buffered == 0
    return got, False


@settings(max_examples=300)
@given(st.sampled_from(["nul", "bare"]), fuzz_bytes, chunk_sizes)
def test_reader_raises_only_protocol_errors_and_ignores_chunking(
    mode: str, data: bytes, sizes: list[int]
) -> None:
    whole = read_all(mode, data, [max(1, len(data))])
    assert read_all(mode, data, sizes) == whole
    assert read_all(mode, data, [1]) == whole
    if mode == "bare":
        assert all(m.startswith(b"<") and m.endswith(b">") for m in whole[0])
    else:
        assert all(b"\0" not in m for m in whole[0])


# ====================================================================== connections


def reply_for(state: object) -> Message | None:
    """A message the local side may send in ``state`` (to push the fuzzed session on)."""
    for (s, d, cls), _ in TRANSITIONS.items():
        if s is state and d is Direction.SEND:
            return {
                SessionInit: SessionInit(b"d", 1, 2, 5.0),
                RoundInit: RoundInit(1, 1, 5.0),
                Turn: Turn(1, 5.0, 0.0, ()),
                ResourceNotification: ResourceNotification(5.0),
                SessionRequest: None,
                RoundRequest: RoundRequest(),
                Actions: Actions(),
            }.get(cls)
    return None


def pump(conn: ServerConnection | ClientConnection, data: bytes, sizes: list[int]) -> None:
    """Feed ``data`` and pull events, answering whenever it is our turn; every step is
    bounded, so a hang shows up as an assertion, not as a stuck test."""
    pieces = [*chunks(data, sizes), b""]
    steps = 0
    for piece in pieces:
        conn.receive_data(piece)
        while True:
            steps += 1
            assert steps < 4 * len(data) + 50, "no progress"
            reply = reply_for(conn.state)
            if reply is not None:
                conn.send(reply)
                continue
            ev = conn.next_event()
            if ev is NEED_DATA or isinstance(ev, ConnectionClosed):
                break


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(fuzz_bytes, chunk_sizes, st.sampled_from(["server", "client", "client-bare"]))
def test_connections_raise_only_protocol_errors(data: bytes, sizes: list[int], role: str) -> None:
    if role == "server":
        conn: ServerConnection | ClientConnection = ServerConnection(max_message_size=400)
    else:
        conn = ClientConnection(no_header=role == "client-bare", max_message_size=400)
        conn.send(SessionRequest("i", "c", None, role == "client-bare"))
    try:
        pump(conn, data, sizes)
    except ProtocolError as exc:
        assert isinstance(exc, RemoteProtocolError)
        assert conn.state.name == "ERROR"


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_server_survives_a_real_session_with_garbage_spliced_in(
    recordings: Path, data: st.DataObject
) -> None:
    t = load_transcript(recordings, data.draw(st.sampled_from(RDDLSIM_SCENARIOS)))
    stream = b"".join(r.data or b"" for r in t.records if r.dir == "c2s" and r.conn == 0)
    garbage = data.draw(fuzz_bytes)
    cut = data.draw(st.integers(0, len(stream)))
    conn = ServerConnection(max_message_size=4000)
    try:
        pump(conn, stream[:cut] + garbage + stream[cut:], data.draw(chunk_sizes))
    except ProtocolError as exc:
        assert isinstance(exc, RemoteProtocolError)
        assert conn.state.name == "ERROR"


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_client_survives_a_real_session_with_garbage_spliced_in(
    recordings: Path, data: st.DataObject
) -> None:
    name = data.draw(st.sampled_from(RDDLSIM_SCENARIOS))
    t = load_transcript(recordings, name)
    stream = b"".join(r.data or b"" for r in t.records if r.dir == "s2c" and r.conn == 0)
    garbage = data.draw(fuzz_bytes)
    cut = data.draw(st.integers(0, len(stream)))
    bare = name == "py_prost_style_noheader"
    conn = ClientConnection(no_header=bare, max_message_size=40000)
    conn.send(SessionRequest("i", "c", None, bare))
    try:
        pump(conn, stream[:cut] + garbage + stream[cut:], data.draw(chunk_sizes))
    except ProtocolError as exc:
        assert isinstance(exc, RemoteProtocolError)
        assert conn.state.name == "ERROR"


def test_fuzz_strategies_produce_real_messages() -> None:
    # the seeds are real messages, so mangling starts from somewhere meaningful
    assert all(dataclasses.is_dataclass(decode(s)) for s in SEED_MESSAGES[:-1])
