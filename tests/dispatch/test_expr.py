"""The restricted evaluator of sensing expressions."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from ippc.dispatch.expr import EvaluationError, ExpressionError, compile_expression


@pytest.mark.parametrize(
    ("text", "msg", "expected"),
    [
        ("msg.x > 0.5", {"x": 0.7}, True),
        ("msg['w'] in ('a', 'b')", {"w": "b"}, True),
        ("msg.pose.x * 2 - 1", {"pose": {"x": 3}}, 5),
        ("not msg.busy and msg.n >= 2", {"busy": False, "n": 2}, True),
        ("msg.ranges[1:3]", {"ranges": [0, 1, 2, 3]}, [1, 2]),
        ("{msg.at: True}", {"at": "lab"}, {"lab": True}),
        ("[(msg.a, msg.b < 1)]", {"a": "x", "b": 0}, [("x", True)]),
        ("'near' if msg.d < 1.5 else 'far'", {"d": 1.0}, "near"),
        ("msg.n // 3 + msg.n % 3", {"n": 7}, 3),
        ("-msg.v", {"v": 2.5}, -2.5),
        ("1 < msg.v < 3", {"v": 2}, True),
        ("msg.v is None", {"v": None}, True),
    ],
)
def test_accepted_expressions_evaluate(text: str, msg: object, expected: object) -> None:
    assert compile_expression(text).evaluate({"msg": msg}) == expected


def test_attribute_access_reads_objects_as_well_as_mappings() -> None:
    expr = compile_expression("msg.data.value")
    assert expr.evaluate({"msg": SimpleNamespace(data=SimpleNamespace(value=4))}) == 4
    assert expr.names == frozenset({"msg"})


@pytest.mark.parametrize(
    ("text", "reason", "column"),
    [
        ("len(msg.x)", "function calls are not allowed", 1),
        ("msg.x.__class__", "names starting with _ are refused", 7),
        ("2 ** msg.x", "operator ** is not allowed", 1),
        ("[x for x in msg]", "comprehensions are not allowed", 1),
        ("lambda: 1", "lambda is not allowed", 1),
        ("os.system", "unknown name 'os'", 1),
        ("msg.a + (y := 2)", ":= is not allowed", 10),
        ("f'{msg}'", "f-strings are not allowed", 1),
        ("msg.x +", "syntax error", 1),
        ("~msg.x", "operator ~ is not allowed", 1),
        ("[*msg]", "* unpacking is not allowed", 2),
    ],
)
def test_refused_expressions_say_why_and_where(text: str, reason: str, column: int) -> None:
    with pytest.raises(ExpressionError) as info:
        compile_expression(text)
    assert reason in info.value.reason
    assert info.value.column == column


def test_evaluation_errors_name_the_expression() -> None:
    with pytest.raises(EvaluationError, match=r"'msg.x': no 'x' in the message"):
        compile_expression("msg.x").evaluate({"msg": {}})
    with pytest.raises(EvaluationError, match="division by zero"):
        compile_expression("1 / msg.x").evaluate({"msg": {"x": 0}})
    # repetition of text or lists is refused (one message could build gigabytes)
    with pytest.raises(EvaluationError, match=r"\* applies to numbers only"):
        compile_expression("msg.s * 1000000000").evaluate({"msg": {"s": "a"}})
    with pytest.raises(EvaluationError, match="% applies to numbers only"):
        compile_expression("msg.s % 1").evaluate({"msg": {"s": "%s"}})


@pytest.mark.parametrize("text", ["msg" + ".a" * 5000, "not " * 5000 + "msg", "-" * 5000 + "1"])
def test_an_expression_nested_too_deeply_is_refused_not_a_crash(text: str) -> None:
    # Python's parser gives up with RecursionError on these: a refusal like the others
    with pytest.raises(ExpressionError) as info:
        compile_expression(text)
    assert info.value.reason == "the expression is nested too deeply"


def test_a_message_that_recurses_fails_its_evaluation_only() -> None:
    class Endless:
        def __getattr__(self, name: str) -> object:
            return getattr(self, name)  # an object whose attributes never end

    with pytest.raises(EvaluationError, match="nested too deeply"):
        compile_expression("msg.x").evaluate({"msg": Endless()})
