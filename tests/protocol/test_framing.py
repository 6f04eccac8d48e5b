"""ippc.protocol.framing: message boundaries in NUL-terminated and bare (no-header) streams."""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ippc.protocol import (
    MAX_MESSAGE_SIZE,
    LocalProtocolError,
    MessageReader,
    RemoteProtocolError,
    frame,
)

from .corpus import PROST_INSTANCES, RDDLSIM_SCENARIOS, load_prost, load_transcript


def drain(reader: MessageReader) -> list[bytes]:
    out = []
    while (msg := reader.next_message()) is not None:
        out.append(msg)
    return out


def feed_chunked(reader: MessageReader, data: bytes, sizes: Iterable[int]) -> list[bytes]:
    """Feed ``data`` in chunks of the given sizes (cycled), collecting messages as they
    complete, then EOF."""
    out: list[bytes] = []
    pos = 0
    for size in itertools.cycle(sizes):
        if pos >= len(data):
            break
        reader.feed(data[pos : pos + size])
        pos += size
        out += drain(reader)
    reader.feed_eof()
    out += drain(reader)
    return out


def streams(recordings: Path, name: str) -> list[tuple[str, bytes, list[bytes], bool]]:
    """(mode, stream bytes, expected messages, ends mid-message) per connection and
    direction of a transcript."""
    t = load_transcript(recordings, name)
    out = []
    for recs in t.conns().values():
        for direction in ("c2s", "s2c"):
            msgs = [r for r in recs if r.dir == direction and r.data is not None]
            if not msgs:
                continue
            bare = not msgs[0].terminated and not msgs[0].partial
            mode = "bare" if bare else "nul"
            # an unterminated last message in a NUL stream was cut short by an EOF
            cut = [r.partial or (mode == "nul" and not r.terminated) for r in msgs]
            complete = [r.doc for r, c in zip(msgs, cut, strict=True) if not c]
            partial = any(cut)
            out.append((mode, b"".join(r.data or b"" for r in msgs), complete, partial))
    return out


def check_stream(
    mode: str, data: bytes, expected: list[bytes], partial: bool, sizes: Iterable[int]
) -> None:
    reader = MessageReader(mode)  # type: ignore[arg-type]
    if partial:
        with pytest.raises(RemoteProtocolError, match="closed mid-message"):
            feed_chunked(reader, data, sizes)
        return
    assert feed_chunked(reader, data, sizes) == expected
    assert reader.at_eof and reader.buffered == 0


# --------------------------------------------------------------------- the recordings


@pytest.mark.parametrize("name", RDDLSIM_SCENARIOS)
def test_rddlsim_streams_byte_by_byte(recordings: Path, name: str) -> None:
    found = streams(recordings, name)
    assert found
    for mode, data, expected, partial in found:
        check_stream(mode, data, expected, partial, [1])


def test_no_header_transcript_is_read_in_bare_mode(recordings: Path) -> None:
    modes = {mode for mode, *_ in streams(recordings, "py_prost_style_noheader")}
    assert modes == {"nul", "bare"}


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    name=st.sampled_from(RDDLSIM_SCENARIOS),
    sizes=st.lists(st.integers(1, 2000), min_size=1, max_size=20),
)
def test_rddlsim_streams_in_random_chunks(recordings: Path, name: str, sizes: list[int]) -> None:
    for mode, data, expected, partial in streams(recordings, name):
        check_stream(mode, data, expected, partial, sizes)


@pytest.mark.parametrize("name", PROST_INSTANCES)
def test_prost_streams_in_big_chunks(recordings: Path, name: str) -> None:
    cap = load_prost(recordings, name)
    s2c = [m for d, m in cap.messages if d == "s2c"]
    c2s = [m[:-1] for d, m in cap.messages if d == "c2s"]
    assert feed_chunked(MessageReader("bare"), cap.s2c_raw, [4096, 7, 1, 100000]) == s2c
    assert feed_chunked(MessageReader("nul"), cap.c2s_raw, [4096, 3, 1]) == c2s


def test_prost_s2c_stream_byte_by_byte(recordings: Path) -> None:
    # the smallest capture, whole; the others are covered by the slow test below
    cap = load_prost(recordings, "sysadmin_inst_mdp__1")
    s2c = [m for d, m in cap.messages if d == "s2c"]
    assert feed_chunked(MessageReader("bare"), cap.s2c_raw, [1]) == s2c


@pytest.mark.slow
@pytest.mark.parametrize("name", PROST_INSTANCES)
def test_prost_streams_byte_by_byte(recordings: Path, name: str) -> None:
    cap = load_prost(recordings, name)
    s2c = [m for d, m in cap.messages if d == "s2c"]
    c2s = [m[:-1] for d, m in cap.messages if d == "c2s"]
    assert feed_chunked(MessageReader("bare"), cap.s2c_raw, [1]) == s2c
    assert feed_chunked(MessageReader("nul"), cap.c2s_raw, [1]) == c2s


@settings(max_examples=10, deadline=None)
@given(sizes=st.lists(st.integers(1, 5000), min_size=1, max_size=10))
def test_prost_s2c_stream_in_random_chunks(recordings: Path, sizes: list[int]) -> None:
    cap = load_prost(recordings, "chromatic-dice_inst_mdp__01")
    s2c = [m for d, m in cap.messages if d == "s2c"][:40]
    stream = b"".join(s2c)
    assert cap.s2c_raw.startswith(stream)
    assert feed_chunked(MessageReader("bare"), stream, sizes) == s2c


# --------------------------------------------------------------------- NUL mode


def test_frame() -> None:
    assert frame(b"<a/>") == b"<a/>\0"
    assert frame(b"<a/>", nul=False) == b"<a/>"


def test_nul_mode_basics() -> None:
    r = MessageReader()
    assert r.mode == "nul" and r.max_size == MAX_MESSAGE_SIZE
    r.feed(b"<a/>\0<b/>\0\0<c")
    assert drain(r) == [b"<a/>", b"<b/>", b""]
    assert r.buffered == 2 and not r.at_eof
    r.feed(b"/>\0")
    assert drain(r) == [b"<c/>"]
    r.feed(b"")  # ignored: EOF is feed_eof()
    assert not r.at_eof
    r.feed_eof()
    assert r.next_message() is None and r.at_eof and r.buffered == 0


def test_nul_mode_eof_mid_message() -> None:
    r = MessageReader()
    r.feed(b"<actions><action><action-na")
    assert r.next_message() is None
    r.feed_eof()
    with pytest.raises(RemoteProtocolError, match=r"closed mid-message \(27 bytes"):
        r.next_message()
    with pytest.raises(RemoteProtocolError):  # and it stays broken
        r.next_message()


def test_data_after_eof_is_a_local_error() -> None:
    r = MessageReader()
    r.feed_eof()
    with pytest.raises(LocalProtocolError):
        r.feed(b"x")


@pytest.mark.parametrize("mode", ["nul", "bare"])
def test_endless_message_is_refused_without_growing(mode: str) -> None:
    r = MessageReader(mode, max_size=1000)  # type: ignore[arg-type]
    r.feed(b"<round-request>")
    with pytest.raises(RemoteProtocolError, match="message too long"):
        for _ in range(200):
            r.feed(b"x" * 10)
            assert r.next_message() is None
            assert r.buffered <= 1000
    assert r.buffered <= 1010


def test_endless_message_default_limit() -> None:
    r = MessageReader()
    chunk = b"y" * (1024 * 1024)
    with pytest.raises(RemoteProtocolError, match="limit is 10485760"):
        for _ in range(12):
            r.feed(chunk)
            assert r.next_message() is None
    assert r.buffered <= MAX_MESSAGE_SIZE + len(chunk)


def test_complete_but_oversize_message_is_refused() -> None:
    r = MessageReader(max_size=10)
    r.feed(b"<a>0123456789</a>\0")
    with pytest.raises(RemoteProtocolError, match="too long"):
        r.next_message()
    r = MessageReader("bare", max_size=10)
    r.feed(b"<a>0123456789</a>")
    with pytest.raises(RemoteProtocolError, match="too long"):
        r.next_message()
    r = MessageReader(max_size=10)
    r.feed(b"0123456789\0")
    assert r.next_message() == b"0123456789"


# --------------------------------------------------------------------- bare mode


@pytest.mark.parametrize(
    ("stream", "messages"),
    [
        (b"<a/>", [b"<a/>"]),
        (b"<a></a><b/>", [b"<a></a>", b"<b/>"]),
        (b"\n\0 \t\r<a/>\0\n<b/>\0", [b"<a/>", b"<b/>"]),
        (b"\xef\xbb\xbf<a/>", [b"<a/>"]),
        (
            b'<?xml version="1.0" encoding="UTF-8"?>\n<a><b/></a>',
            [b'<?xml version="1.0" encoding="UTF-8"?>\n<a><b/></a>'],
        ),
        (b"<!-- </a> --><a>x</a>", [b"<!-- </a> --><a>x</a>"]),
        (b"<a><![CDATA[</a><b>]]></a>", [b"<a><![CDATA[</a><b>]]></a>"]),
        (b"<a x='>' y=\"/>\"><a/></a><c/>", [b"<a x='>' y=\"/>\"><a/></a>", b"<c/>"]),
        (b"<a><?pi </a> ?></a>", [b"<a><?pi </a> ?></a>"]),
        (b"<a><a><a/></a></a>", [b"<a><a><a/></a></a>"]),
        (b"<a/ >", [b"<a/ >"]),  # not self-closing: waits for more (see test below)
        (
            b'<!DOCTYPE a [<!ENTITY e "x>y">]><a>&e;</a>',
            [b'<!DOCTYPE a [<!ENTITY e "x>y">]><a>&e;</a>'],
        ),
        (
            b"<turn><turn-num>1</turn-num></turn><round-end></round-end>",
            [b"<turn><turn-num>1</turn-num></turn>", b"<round-end></round-end>"],
        ),
    ],
)
def test_bare_mode_boundaries(stream: bytes, messages: list[bytes]) -> None:
    if stream == b"<a/ >":
        r = MessageReader("bare")
        r.feed(stream)
        assert r.next_message() is None  # a start tag: the root is still open
        r.feed(b"</a>")
        assert r.next_message() == b"<a/ ></a>"
        return
    for sizes in ([1], [2], [3], [len(stream)]):
        assert feed_chunked(MessageReader("bare"), stream, sizes) == messages


@pytest.mark.parametrize(
    ("stream", "pattern"),
    [
        (b"null", "must start with '<'"),
        (b"<a/>junk<b/>", "must start with '<'"),
        (b"</a>", "end tag without a start tag"),
        (b"<?xml version='1.0'?> x <a/>", "text outside the root element"),
        (b"<a>", "closed mid-message"),
        (b"<a><!-- -", "closed mid-message"),
        (b"<a x='>", "closed mid-message"),
        (b"\xef\xbb", "must start with '<'"),
    ],
)
def test_bare_mode_errors(stream: bytes, pattern: str) -> None:
    r = MessageReader("bare")
    with pytest.raises(RemoteProtocolError, match=pattern):
        feed_chunked(r, stream, [1])


def test_bare_mode_clean_eof_after_junk() -> None:
    r = MessageReader("bare")
    assert feed_chunked(r, b"<a/>\n\0 \n", [1]) == [b"<a/>"]
    assert r.buffered == 0


@pytest.mark.parametrize(
    "opening", [b"<a>", b"<a><!--", b"<a><![CDATA[", b"<a><?p", b"<a b='", b"<!DOCTYPE a ["]
)
def test_bare_mode_endless_token_is_refused(opening: bytes) -> None:
    r = MessageReader("bare", max_size=500)
    r.feed(opening)
    with pytest.raises(RemoteProtocolError, match="too long"):
        for _ in range(100):
            r.feed(b"q" * 10)
            assert r.next_message() is None
    assert r.buffered <= 510


def test_mode_is_checked() -> None:
    with pytest.raises(ValueError):
        MessageReader("lines")  # type: ignore[arg-type]
