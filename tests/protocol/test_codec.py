"""ippc.protocol.codec against the recorded bytes of rddlsim, its Java client and PROST."""

from __future__ import annotations

import base64
import time
from pathlib import Path

import pytest
from ippc.protocol import (
    MAX_MESSAGE_SIZE,
    XML_DECLARATION,
    Actions,
    Fluent,
    LocalProtocolError,
    MalformedMessageError,
    RemoteProtocolError,
    ResourceNotification,
    ResourceRequest,
    RoundEnd,
    RoundInit,
    RoundRequest,
    SessionEnd,
    SessionInit,
    SessionRequest,
    Turn,
    decode,
    encode,
)

from .corpus import BROKEN, PROST_INSTANCES, RDDLSIM_SCENARIOS, load_prost, load_transcript

CLIENT_MESSAGES = (SessionRequest, RoundRequest, Actions, ResourceRequest)
SERVER_MESSAGES = (SessionInit, RoundInit, Turn, RoundEnd, SessionEnd, ResourceNotification)

# --------------------------------------------------------------------- the recordings


@pytest.mark.parametrize("name", RDDLSIM_SCENARIOS)
def test_every_rddlsim_message_decodes_and_server_bytes_reencode_exactly(
    recordings: Path, name: str
) -> None:
    t = load_transcript(recordings, name)
    checked = 0
    for direction, kinds in (("c2s", CLIENT_MESSAGES), ("s2c", SERVER_MESSAGES)):
        for idx, rec in enumerate(t.messages(direction)):
            broken = BROKEN.get((name, direction, idx))
            if broken is not None:
                with pytest.raises(RemoteProtocolError, match=broken):
                    decode(rec.doc)
                continue
            msg = decode(rec.doc)
            assert isinstance(msg, kinds), (direction, idx, msg)
            declared = rec.doc.startswith(XML_DECLARATION)
            if direction == "s2c" or t.java_client:
                # rddlsim's server and its Java client: byte for byte
                assert encode(msg, declaration=declared) == rec.doc, (direction, idx)
            else:
                # scripted clients send variants (pretty printing, no declaration, ...)
                assert decode(encode(msg)) == msg
            checked += 1
    assert checked > 0
    # every deliberately broken message of this scenario was met
    assert all(idx < len(t.messages(d)) for (n, d, idx) in BROKEN if n == name)


def test_no_header_session_has_bare_server_messages(recordings: Path) -> None:
    t = load_transcript(recordings, "py_prost_style_noheader")
    s2c = t.messages("s2c")
    assert s2c and all(not r.doc.startswith(b"<?xml") and not r.terminated for r in s2c)
    request = decode(t.messages("c2s")[0].doc)
    assert request == SessionRequest("sysadmin_inst_mdp__1", "prost", "rddl", no_header=True)
    # PROST's padded round-request
    assert decode(t.messages("c2s")[1].doc) == RoundRequest(True)


def test_decoded_values_are_raw_text(recordings: Path) -> None:
    t = load_transcript(recordings, "py_sysadmin_legal_variants")
    actions = [decode(r.doc) for r in t.messages("c2s")[2:7]]
    assert actions[0] == Actions((Fluent("reboot", ("c1",), "true"),))
    assert actions[1] == Actions((Fluent("reboot", ("$c2",), "TRUE"),))
    assert actions[3] == Actions(())  # <actions></actions>
    assert actions[4] == Actions((Fluent("reboot", ("c5",), "true"),))  # pretty printed
    sidewalk = load_transcript(recordings, "java_sidewalk")
    turn = decode(sidewalk.messages("s2c")[2].doc)
    assert isinstance(turn, Turn) and turn.fluents
    assert turn.fluents[0] == Fluent("yPos", ("p1",), "0")
    rover = load_transcript(recordings, "java_mars_rover_simerror")
    sent = decode(rover.messages("c2s")[2].doc)
    assert sent == Actions((Fluent("yMove", (), "0.9181647320338637"),))


def test_pomdp_first_turn_has_no_observations(recordings: Path) -> None:
    t = load_transcript(recordings, "java_sysadmin_pomdp")
    turns = [m for m in map(decode, (r.doc for r in t.messages("s2c"))) if isinstance(m, Turn)]
    firsts = [m for m in turns if m.turn_num == 1]
    assert len(firsts) == 2 and all(m.fluents is None for m in firsts)
    assert all(m.fluents for m in turns if m.turn_num > 1)
    assert encode(firsts[0], declaration=False).endswith(
        b"<immediate-reward>0.0</immediate-reward><no-observed-fluents/></turn>"
    )


def test_session_init_task_is_the_raw_rddl(recordings: Path) -> None:
    t = load_transcript(recordings, "java_sysadmin_mdp")
    init = decode(t.messages("s2c")[0].doc)
    assert isinstance(init, SessionInit)
    rddl = recordings / "rddlsim" / "rddl"
    expected = (
        (rddl / "sysadmin_mdp.rddl").read_bytes()
        + b"\n\n"
        + (rddl / "sysadmin_inst_mdp__1.rddl").read_bytes()
        + b"\n"
    )
    assert init.task == expected
    assert (init.session_id, init.num_rounds, init.time_allowed) == (1, 2, 1080000.0)


def test_round_end_and_session_end_fields(recordings: Path) -> None:
    t = load_transcript(recordings, "py_session_timeout")
    end, session_end = (decode(r.doc) for r in t.messages("s2c")[-2:])
    assert end == RoundEnd("sysadmin_inst_mdp__1", "pyclient", 0, 20.0, 2, -704, 10.0)
    assert session_end == SessionEnd("sysadmin_inst_mdp__1", 20.0, 1, "pyclient", 1, -712)


@pytest.mark.parametrize("name", PROST_INSTANCES)
def test_every_prost_message_decodes_and_server_bytes_reencode_exactly(
    recordings: Path, name: str
) -> None:
    cap = load_prost(recordings, name)
    kinds = {"c2s": CLIENT_MESSAGES, "s2c": SERVER_MESSAGES}
    counts = {"c2s": 0, "s2c": 0}
    for direction, data in cap.messages:
        doc = data[:-1] if data.endswith(b"\0") else data
        msg = decode(doc)
        assert isinstance(msg, kinds[direction])
        if direction == "s2c":
            assert encode(msg, declaration=False) == doc
        elif isinstance(msg, Actions):
            # PROST: only true booleans, one <action> per fluent
            assert all(a.value == "true" for a in msg.actions)
        counts[direction] += 1
    assert counts["c2s"] > 100 and counts["s2c"] > 100
    first = decode(cap.messages[0][1][:-1])
    assert first == SessionRequest(name, "prost", "rddl", no_header=True)


# --------------------------------------------------------------------- encoding details


def test_encode_empty_elements_like_xerces() -> None:
    assert encode(Actions()) == XML_DECLARATION + b"<actions/>"
    assert encode(RoundRequest()) == XML_DECLARATION + b"<round-request/>"
    assert encode(ResourceRequest(), declaration=False) == b"<resource-request/>"
    assert encode(RoundRequest(True), declaration=False) == (
        b"<round-request><execute-policy>yes</execute-policy></round-request>"
    )
    assert encode(RoundRequest(False), declaration=False) == (
        b"<round-request><execute-policy>no</execute-policy></round-request>"
    )
    assert encode(SessionRequest("i", "c", "rddl", True), declaration=False) == (
        b"<session-request><problem-name>i</problem-name><client-name>c</client-name>"
        b"<input-language>rddl</input-language><no-header/></session-request>"
    )
    # an element holding an empty text node is written with both tags (Xerces does)
    assert encode(SessionRequest("i", ""), declaration=False) == (
        b"<session-request><problem-name>i</problem-name><client-name></client-name>"
        b"</session-request>"
    )


def test_encode_values() -> None:
    turn = Turn(
        3,
        1079655.0,
        -1.0,
        (
            Fluent("running", ("c1",), True),
            Fluent("xPos", ("p2",), 0),
            Fluent("time", (), 1e-4),
            Fluent("at-phase", ("i1",), "@A"),
            Fluent("alive", ("x1", "y2"), False),
        ),
    )
    assert encode(turn, declaration=False) == (
        b"<turn><turn-num>3</turn-num><time-left>1079655.0</time-left>"
        b"<immediate-reward>-1.0</immediate-reward>"
        b"<observed-fluent><fluent-name>running</fluent-name><fluent-arg>c1</fluent-arg>"
        b"<fluent-value>true</fluent-value></observed-fluent>"
        b"<observed-fluent><fluent-name>xPos</fluent-name><fluent-arg>p2</fluent-arg>"
        b"<fluent-value>0</fluent-value></observed-fluent>"
        b"<observed-fluent><fluent-name>time</fluent-name>"
        b"<fluent-value>1.0E-4</fluent-value></observed-fluent>"
        b"<observed-fluent><fluent-name>at-phase</fluent-name><fluent-arg>i1</fluent-arg>"
        b"<fluent-value>@A</fluent-value></observed-fluent>"
        b"<observed-fluent><fluent-name>alive</fluent-name><fluent-arg>x1</fluent-arg>"
        b"<fluent-arg>y2</fluent-arg><fluent-value>false</fluent-value></observed-fluent>"
        b"</turn>"
    )
    assert encode(ResourceNotification(1079823.0)) == (
        XML_DECLARATION + b"<resource-notification><time-left>1079823.0</time-left>"
        b"<memory-left>enough</memory-left></resource-notification>"
    )


@pytest.mark.parametrize(
    ("text", "written"),
    [
        # as OpenJDK 17 + rddlsim's Xerces 2.6.1 + the US-ASCII writer produce them
        ("a&b<c>d\"e'f", b"a&amp;b&lt;c&gt;d\"e'f"),
        ("x\ry", b"x&#xd;y"),
        ("x\ny\tz", b"x\ny\tz"),
        ("]]>", b"]]&gt;"),
        (" sp ", b" sp "),
        ("\u00e9", b"?"),
        ("\u0085", b"?"),
        ("\u2028", b"?"),
        ("\x7f", b"\x7f"),
        ("\U0001f600", b"&#x1f600;"),
        ("", b""),
    ],
)
def test_encode_text_escaping_like_rddlsim(text: str, written: bytes) -> None:
    doc = encode(ResourceNotification(1.0, text), declaration=False)
    assert doc == (
        b"<resource-notification><time-left>1.0</time-left><memory-left>"
        + written
        + b"</memory-left></resource-notification>"
    )
    if text.isascii() or text == "\U0001f600":
        decoded = decode(doc)
        assert isinstance(decoded, ResourceNotification) and decoded.memory_left == text


@pytest.mark.parametrize("text", ["\x00", "\x01", "\x1f", "\ufffe", "\ud800"])
def test_encode_refuses_characters_xml_cannot_carry(text: str) -> None:
    # Xerces throws "is an invalid XML character" for these as well
    with pytest.raises(LocalProtocolError, match="cannot write"):
        encode(Actions((Fluent("a" + text, (), True),)))


def test_encode_refuses_non_messages_and_bad_values() -> None:
    with pytest.raises(LocalProtocolError):
        encode("turn")  # type: ignore[arg-type]
    with pytest.raises(LocalProtocolError, match="cannot format"):
        encode(Actions((Fluent("a", (), None),)))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("msg", "pattern"),
    [
        (RoundEnd("i", "c", 0, 1.0, 5, 1079615.0, 1.0), r"<time-left> must be an int, not float"),  # type: ignore[arg-type]
        (RoundInit(2**31, 0, 1.0), r"<round-num> 2147483648 does not fit a 32-bit"),
        (SessionEnd("i", 1.0, 1, "c", 1, 2**63), r"<time-left> \d+ does not fit a 64-bit"),
        (RoundInit(1, 0, "5.0"), r"<time-left> must be a number, not str"),  # type: ignore[arg-type]
        (SessionEnd(7, 1.0, 1, "c", 1, 1), r"<instance-name> must be a str, not int"),  # type: ignore[arg-type]
        (Actions((Fluent("a", (1,), True),)), r"<action-arg> must be a str"),  # type: ignore[arg-type]
    ],
)
def test_encode_refuses_wrong_field_types(msg: object, pattern: str) -> None:
    with pytest.raises(LocalProtocolError, match=pattern):
        encode(msg)  # type: ignore[arg-type]


def test_encode_accepts_numpy_numbers() -> None:
    np = pytest.importorskip("numpy")
    msg = RoundEnd("i", "c", np.int64(0), np.float64(1.5), np.int32(5), np.int64(-704), 1)
    assert encode(msg, declaration=False) == (
        b"<round-end><instance-name>i</instance-name><client-name>c</client-name>"
        b"<round-num>0</round-num><round-reward>1.5</round-reward><turns-used>5</turns-used>"
        b"<time-left>-704</time-left><immediate-reward>1.0</immediate-reward></round-end>"
    )


def test_task_is_base64_of_the_bytes() -> None:
    task = b"domain d {\r\n\x00\xff}"
    doc = encode(SessionInit(task, 3, 30, 1080000.0), declaration=False)
    assert base64.b64encode(task) in doc
    assert decode(doc) == SessionInit(task, 3, 30, 1080000.0)


def test_messages_accept_lists_and_store_tuples() -> None:
    a = Actions([Fluent("reboot", ["c1"], "true")])  # type: ignore[arg-type]
    assert a == Actions((Fluent("reboot", ("c1",), "true"),))
    assert hash(a) == hash(Actions((Fluent("reboot", ("c1",), "true"),)))
    assert Turn(1, 1.0, 0.0, []).fluents == ()  # type: ignore[arg-type]


# --------------------------------------------------------------------- decoding leniency


def test_decode_like_xerces_and_get_elements_by_tag_name() -> None:
    pretty = b"""<?xml version="1.0" encoding="UTF-8"?>
<round-end>
  <!-- order does not matter -->
  <immediate-reward>1.0E-4</immediate-reward>
  <wrapper><round-num>2</round-num></wrapper>
  <round-num>99</round-num>
  <turns-used>5</turns-used>
  <instance-name> padded </instance-name>
  <client-name><![CDATA[a<b]]></client-name>
  <round-reward> 12 </round-reward>
  <time-left>-3</time-left>
  <unknown-element>ignored</unknown-element>
</round-end>"""
    assert decode(pretty) == RoundEnd(" padded ", "a<b", 2, 12.0, 5, -3, 1e-4)


def test_decode_entities_and_character_references() -> None:
    doc = (
        b"<actions><action><action-name>a&amp;b</action-name><action-arg>&#65;</action-arg>"
        b"<action-value>&lt;x&gt;</action-value></action></actions>"
    )
    assert decode(doc) == Actions((Fluent("a&b", ("A",), "<x>"),))


def test_decode_round_request_execute_policy_like_rddlsim() -> None:
    assert decode(b"<round-request/>") == RoundRequest(None)
    assert decode(b"<round-request><execute-policy> yes\n</execute-policy></round-request>") == (
        RoundRequest(True)
    )
    assert decode(b"<round-request><execute-policy>YES</execute-policy></round-request>") == (
        RoundRequest(False)
    )
    assert decode(b"<round-request><execute-policy/></round-request>") == RoundRequest(False)


def test_decode_empty_text_is_empty_string() -> None:
    doc = b"<session-request><problem-name/><client-name></client-name></session-request>"
    assert decode(doc) == SessionRequest("", "")


# --------------------------------------------------------------------- decoding errors


@pytest.mark.parametrize(
    ("doc", "pattern"),
    [
        (
            b"<session-request><client-name>x</client-name></session-request>",
            r"<session-request>: required element <problem-name> is missing",
        ),
        (
            b"<session-request><problem-name>x</problem-name></session-request>",
            r"<client-name> is missing",
        ),
        (
            b"<round-init><round-num>1.0</round-num><round-left>0</round-left>"
            b"<time-left>5.0</time-left></round-init>",
            r"<round-init>: <round-num> is not an int: '1.0'",
        ),
        (
            b"<round-init><round-num>1</round-num><round-left>0</round-left>"
            b"<time-left>five</time-left></round-init>",
            r"<round-init>: <time-left> is not a double: 'five'",
        ),
        (
            b"<round-end><instance-name>i</instance-name><client-name>c</client-name>"
            b"<round-num>0</round-num><round-reward>1.0</round-reward><turns-used>1</turns-used>"
            b"<time-left>1079615.0</time-left><immediate-reward>1.0</immediate-reward></round-end>",
            r"<round-end>: <time-left> is not a long",
        ),
        (
            b"<session-init><task>!!!</task><session-id>1</session-id><num-rounds>1</num-rounds>"
            b"<time-allowed>1.0</time-allowed></session-init>",
            r"<task> is not base64",
        ),
        (
            b"<turn><turn-num>1</turn-num><time-left>1.0</time-left>"
            b"<immediate-reward>0.0</immediate-reward><observed-fluent><fluent-name>a"
            b"</fluent-name></observed-fluent></turn>",
            r"<observed-fluent> in <turn>: required element <fluent-value> is missing",
        ),
        (
            b"<actions><action><action-value>true</action-value></action></actions>",
            r"<action> in <actions>: required element <action-name> is missing",
        ),
        (b"<hello/>", r"unknown root element <hello>"),
        (b"<turn xmlns='urn:x'/>", r"unknown root element <\{urn:x\}turn>"),
        (b"", r"not well-formed"),
        (b"null", r"not well-formed"),
        (b"<actions>", r"not well-formed"),
        (b"<actions/><actions/>", r"not well-formed"),
        (b"<a>\xe9</a>", r"not well-formed"),
    ],
)
def test_decode_errors_name_root_and_field(doc: bytes, pattern: str) -> None:
    with pytest.raises(RemoteProtocolError, match=pattern) as info:
        decode(doc)
    assert info.value.message_text == doc[:200]


def test_malformed_is_its_own_error_class() -> None:
    with pytest.raises(MalformedMessageError):
        decode(b"<round-request")
    with pytest.raises(RemoteProtocolError) as info:
        decode(b"<hello/>")
    assert not isinstance(info.value, MalformedMessageError)


def test_error_text_is_cut_for_display() -> None:
    doc = b"<hello>" + b"x" * 1000 + b"</hello>"
    with pytest.raises(RemoteProtocolError) as info:
        decode(doc)
    err = info.value
    assert err.message_text == doc[:200] and err.message_size == len(doc)
    assert "(1015 bytes)" in str(err) and len(str(err)) < 600


# --------------------------------------------------------------------- hardening

BILLION_LAUGHS = b"""<?xml version="1.0"?>
<!DOCTYPE lolz [
 <!ENTITY lol "lol">
 <!ENTITY lol1 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol2 "&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;">
 <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
 <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
 <!ENTITY lol5 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
 <!ENTITY lol6 "&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;">
 <!ENTITY lol7 "&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;">
 <!ENTITY lol8 "&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;">
 <!ENTITY lol9 "&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;">
]>
<session-request><problem-name>&lol9;</problem-name><client-name>x</client-name></session-request>"""

EXTERNAL_ENTITY = b"""<?xml version="1.0"?>
<!DOCTYPE r [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>
<session-request><problem-name>&xxe;</problem-name><client-name>x</client-name></session-request>"""

PARAMETER_ENTITY = b"""<!DOCTYPE r [<!ENTITY % p SYSTEM "http://127.0.0.1:9/x.dtd"> %p;]>
<resource-request/>"""


@pytest.mark.parametrize("doc", [BILLION_LAUGHS, EXTERNAL_ENTITY, PARAMETER_ENTITY])
def test_doctype_is_rejected_before_anything_is_expanded(doc: bytes) -> None:
    start = time.perf_counter()
    with pytest.raises(RemoteProtocolError, match="document type declarations are not allowed"):
        decode(doc)
    assert time.perf_counter() - start < 0.5


def test_undeclared_entity_is_not_resolved() -> None:
    with pytest.raises(MalformedMessageError, match="xxe"):
        decode(b"<session-request><problem-name>&xxe;</problem-name></session-request>")


def test_declared_encoding_cannot_hide_a_doctype() -> None:
    utf16 = BILLION_LAUGHS.replace(b'version="1.0"', b'version="1.0" encoding="UTF-16"')
    doc = utf16.decode("ascii").encode("utf-16")
    assert b"<!DOCTYPE" not in doc
    with pytest.raises(MalformedMessageError):
        decode(doc)


def test_oversize_message_is_refused_quickly() -> None:
    body = b"<resource-request>" + b" " * MAX_MESSAGE_SIZE + b"</resource-request>"
    start = time.perf_counter()
    with pytest.raises(RemoteProtocolError, match="exceeds the 10485760-byte limit"):
        decode(body)
    assert time.perf_counter() - start < 0.5
    # right at the limit is fine (libxml2 still caps one text node at 10,000,000 bytes
    # unless huge_tree is on, so the padding is split over several elements)
    pad = b"<pad>" + b"x" * (1024 * 1024 - 11) + b"</pad>"
    head, tail = b"<resource-request>", b"</resource-request>"
    fill = MAX_MESSAGE_SIZE - len(head) - len(tail) - 9 * len(pad)
    just = head + 9 * pad + b"<p>" + b"y" * (fill - 7) + b"</p>" + tail
    assert len(just) == MAX_MESSAGE_SIZE
    assert decode(just) == ResourceRequest()
    with pytest.raises(MalformedMessageError, match="Text node too long"):
        decode(head + b"z" * 10_000_001 + tail)


def test_common_messages_fast_path_equals_the_parser(monkeypatch) -> None:
    import ippc.protocol.codec as codec_module

    common = dict(codec_module._COMMON)
    assert len(common) == 14
    monkeypatch.setattr(codec_module, "_COMMON", {})
    for data, fast in common.items():
        assert codec_module.decode(data) == fast, data
