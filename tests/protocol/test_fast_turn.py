"""The server's fast turn path (`ObservedFluentsWriter`, `encode_turn`,
`ServerConnection.send_turn`) writes exactly the bytes, and makes exactly the moves
and errors, of the general path (`encode(Turn(...))`, `ServerConnection.send`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from ippc.protocol import (
    Actions,
    Fluent,
    LocalProtocolError,
    ObservedFluentsWriter,
    RoundInit,
    RoundRequest,
    ServerConnection,
    ServerState,
    SessionInit,
    SessionRequest,
    Turn,
    encode,
    encode_turn,
)

TEXT_CHARS = st.characters(min_codepoint=0x20, max_codepoint=0x7E) | st.sampled_from("\t\n\r")
name = st.text(TEXT_CHARS, min_size=1, max_size=10)
value = (
    st.booleans()
    | st.integers(-(2**31), 2**31 - 1)
    | st.floats()
    | st.text(TEXT_CHARS, max_size=8)
    | st.sampled_from(["@low", "@high", "c1", "$c2", "a&b<c>", "\u00e9t\u00e9", "\U0001f600"])
)
grounding = st.tuples(name, st.lists(name, max_size=3).map(tuple))


def general(
    turn_num: object,
    time_left: object,
    reward: object,
    fluents: tuple[Fluent, ...] | None,
    declaration: bool = True,
) -> bytes:
    return encode(Turn(turn_num, time_left, reward, fluents), declaration=declaration)  # type: ignore[arg-type]


@given(
    st.lists(st.tuples(grounding, value), max_size=12),
    st.integers(-(2**31), 2**31 - 1),
    st.floats(),
    st.floats(),
    st.booleans(),
)
def test_writer_and_encode_turn_equal_the_general_encoder(
    pairs: list[tuple[tuple[str, tuple[str, ...]], object]],
    turn_num: int,
    time_left: float,
    reward: float,
    declaration: bool,
) -> None:
    writer = ObservedFluentsWriter(g for g, _ in pairs)
    values = [v for _, v in pairs]
    fluents = tuple(Fluent(n, a, v) for (n, a), v in pairs)  # type: ignore[arg-type]
    fast = encode_turn(turn_num, time_left, reward, writer.write(values), declaration=declaration)  # type: ignore[arg-type]
    assert fast == general(turn_num, time_left, reward, fluents, declaration)


def test_writer_values_of_every_kind() -> None:
    groundings = [
        ("running", ("c1",)),
        ("running", ("c2",)),
        ("level", ()),
        ("mode", ("r1", "r2")),
        ("where", ("robot",)),
        ("count", ("x",)),
    ]
    writer = ObservedFluentsWriter(groundings)
    assert len(writer) == 6
    cases = [
        [True, False, 0.5, "@on", "$room", 3],
        [False, True, -0.0, "@off", "a&b", -7],
        [True, True, math.nan, "@x", "<y>", 0],
        [False, False, math.inf, "", "\r", 2**31 - 1],
        [True, False, 1e7, "z", "\u00e9", -(2**31)],
        [True, False, 1e-4, "z", "w", 5],
        # numpy scalars take the general formatting (np.True_ is not True)
        [np.True_, np.False_, np.float64(2.5), np.str_("@on"), "r", np.int64(4)],
    ]
    for values in cases:
        fluents = tuple(Fluent(n, a, v) for (n, a), v in zip(groundings, values, strict=True))
        for declaration in (True, False):
            assert encode_turn(
                7, 1079999.0, 8.0, writer.write(values), declaration=declaration
            ) == general(7, 1079999.0, 8.0, fluents, declaration)


def test_no_observed_fluents_and_no_groundings() -> None:
    assert encode_turn(1, 5.0, 0.0, None) == general(1, 5.0, 0.0, None)
    assert encode_turn(1, 5.0, 0.0, None, declaration=False) == general(1, 5.0, 0.0, None, False)
    empty = ObservedFluentsWriter([])
    assert encode_turn(1, 5.0, 0.0, empty.write([])) == general(1, 5.0, 0.0, ())


@pytest.mark.parametrize(
    "turn_num, time_left, reward",
    [
        (np.int64(3), 5.0, 1.0),  # not an int: the general path writes it
        (True, 5.0, 1.0),  # a bool is an int to operator.index: "1"
        (3, 5, 1),  # ints where doubles go: "5.0"
        (3, np.float64(1e7), np.float32(0.1)),
        (3, 1080000.0, -1e-300),
        (2**31 - 1, -0.0, math.inf),
    ],
)
def test_encode_turn_falls_back_for_other_number_types(
    turn_num: object, time_left: object, reward: object
) -> None:
    fluents = (Fluent("f", ("a",), True),)
    xml = ObservedFluentsWriter([("f", ("a",))]).write([True])
    assert encode_turn(turn_num, time_left, reward, xml) == general(
        turn_num, time_left, reward, fluents
    )  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "turn_num, time_left, reward",
    [
        (2**31, 1.0, 1.0),
        (-(2**31) - 1, 1.0, 1.0),
        ("5", 1.0, 1.0),
        (5.0, 1.0, 1.0),
        (1, "x", 1.0),
        (1, 1.0, None),
    ],
)
def test_encode_turn_refuses_what_encode_refuses(
    turn_num: object, time_left: object, reward: object
) -> None:
    with pytest.raises(LocalProtocolError) as general_error:
        general(turn_num, time_left, reward, ())
    with pytest.raises(LocalProtocolError) as fast_error:
        encode_turn(turn_num, time_left, reward, "")  # type: ignore[arg-type]
    assert str(fast_error.value) == str(general_error.value)


def test_writer_refuses_a_wrong_number_of_values_and_bad_text() -> None:
    writer = ObservedFluentsWriter([("f", ("a",)), ("f", ("b",))])
    with pytest.raises(LocalProtocolError, match="1 values for 2 observed fluents"):
        writer.write([True])
    with pytest.raises(LocalProtocolError, match="invalid XML character|cannot write"):
        writer.write([True, "bad\x01"])
    with pytest.raises(LocalProtocolError):
        ObservedFluentsWriter([("f\x00", ())])
    with pytest.raises(LocalProtocolError):
        writer.write([True, object()])


# ------------------------------------------------------------------ the state machine


def _at_first_turn(no_header: bool) -> ServerConnection:
    conn = ServerConnection()
    conn.receive_data(encode(SessionRequest("i", "c", None, no_header)) + b"\0")
    conn.next_event()
    conn.send(SessionInit(b"task", 1, 2, 1000.0))
    conn.receive_data(encode(RoundRequest()) + b"\0")
    conn.next_event()
    conn.send(RoundInit(1, 1, 1000.0))
    return conn


@pytest.mark.parametrize("no_header", [False, True])
def test_send_turn_equals_send_and_moves_alike(no_header: bool) -> None:
    groundings = [("running", (f"c{i}",)) for i in range(1, 4)]
    writer = ObservedFluentsWriter(groundings)
    fast, slow = _at_first_turn(no_header), _at_first_turn(no_header)
    for turn, values in enumerate([[True, True, False], [False, True, True]], start=1):
        fluents = tuple(Fluent(n, a, v) for (n, a), v in zip(groundings, values, strict=True))
        got = fast.send_turn(turn, 999.0, 0.5, writer.write(values))
        assert got == slow.send(Turn(turn, 999.0, 0.5, fluents))
        assert got.endswith(b"</turn>") if no_header else got.endswith(b"</turn>\0")
        assert fast.state is slow.state is ServerState.AWAIT_ACTIONS
        for conn in (fast, slow):
            conn.receive_data(encode(Actions()) + b"\0")
            assert conn.next_event() == Actions()
            assert conn.state is ServerState.SEND_TURN_OR_ROUND_END


def test_send_turn_refused_where_send_turn_is() -> None:
    fresh = ServerConnection()
    with pytest.raises(LocalProtocolError) as slow:
        fresh.send(Turn(1, 1.0, 0.0, ()))
    with pytest.raises(LocalProtocolError) as fast:
        fresh.send_turn(1, 1.0, 0.0, "")
    assert str(fast.value) == str(slow.value)
    assert fresh.state is ServerState.AWAIT_SESSION_REQUEST
    conn = _at_first_turn(False)
    with pytest.raises(LocalProtocolError, match="cannot encode turn|does not fit"):
        conn.send_turn(2**40, 1.0, 0.0, "")
    assert conn.state is ServerState.SEND_TURN  # nothing sent, nothing moved
    with pytest.raises(LocalProtocolError, match="cannot encode turn"):
        conn.send_turn(1, 1.0, 0.0, "\u00e9")  # not what a writer writes: not ASCII
    assert conn.state is ServerState.SEND_TURN
    conn.send_turn(1, 1.0, 0.0, None)
    assert conn.state is ServerState.AWAIT_ACTIONS
