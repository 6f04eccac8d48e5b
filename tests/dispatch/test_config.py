"""Loading and checking sensing configs."""

from __future__ import annotations

from pathlib import Path

import pytest
from ippc.dispatch.config import SensingConfig, SensingConfigError
from ippc.kb import KnowledgeBase

GOOD = """\
rate: 20
sensors:
  robot-at:
    stream: odometry
    params: [r1, '*']
    value: "{msg.room: True}"
  present:
    - stream: [desk-camera, door-sensor]
      params: [{msg: msg.room}]
      value: msg.seen
  holding:
    stream: gripper
    value: "{'r1': msg.closed}"
"""


def test_a_good_config_loads(tmp_path: Path, kb: KnowledgeBase) -> None:
    path = tmp_path / "sensing.yaml"
    path.write_text(GOOD)
    config = SensingConfig.load(path, kb.model)
    assert config.rate == 20.0
    assert config.fluents() == {"robot-at", "present", "holding"}
    assert config.streams() == {"odometry", "desk-camera", "door-sensor", "gripper"}
    by = {s.fluent: s for s in config.sensors}
    assert [p.kind for p in by["robot-at"].params] == ["fixed", "wildcard"]
    assert by["robot-at"].params[0].name == "r1"
    assert by["present"].params[0].kind == "message"
    assert by["holding"].wildcards == (0,)  # params left out: every one a wildcard
    assert by["robot-at"].where == f"{path}:4:5"


@pytest.mark.parametrize(
    ("text", "problems"),
    [
        (
            "sensors:\n  robot_at:\n    stream: s\n    value: msg.v\n",
            ["2:3: 'robot_at' is not a fluent"],
        ),
        ("sensors:\n  DESK:\n    stream: s\n    value: msg.v\n", ["2:3: 'DESK' is a non-fluent"]),
        (
            "sensors:\n  robot-at:\n    stream: s\n    params: [r1]\n    value: msg.v\n",
            ["4:13: robot-at has 2 parameter(s) (robot, room), params lists 1"],
        ),
        (
            "sensors:\n  robot-at:\n    stream: s\n    params: [r9, '*']\n    value: msg.v\n",
            ["4:14: robot-at: 'r9' is not an object of type robot"],
        ),
        (
            "sensors:\n  delivered:\n    stream: s\n    value: len(msg)\n",
            ["4:12: delivered: value function calls are not allowed: 'len(msg)'"],
        ),
        (
            "sensors:\n  delivered:\n    stream: s\n    value: msg.a and __import__('os')\n",
            ["4:22: delivered: value function calls are not allowed"],
        ),
        ("sensors:\n  delivered:\n    value: msg.v\n", ["3:5: delivered: no 'stream'"]),
        (
            "sensors:\n  delivered:\n    stream: s\n    value: msg.v\n    topicz: x\n",
            ["5:5: delivered: unknown key 'topicz'"],
        ),
        ("rate: -1\nsensors: {}\n", ["1:7: rate must be a positive number"]),
        (
            # nested too deeply for Python's parser: refused, quoted short
            "sensors:\n  delivered:\n    stream: s\n    value: " + "not " * 3000 + "msg.v\n",
            ["4:12: delivered: value the expression is nested too deeply: 'not not "],
        ),
        ("rates: 1\n", ["1:1: unknown key 'rates'", "1:1: no 'sensors' mapping"]),
        ("sensors: [1, 2\n", ["not valid YAML"]),
        ("", ["the sensing config is empty"]),
        (
            # two problems in one file: both reported
            "sensors:\n  goal:\n    stream: s\n    value: msg.a()\n  holding:\n    stream: s\n"
            "    params: [{msg: msg.r, x: 1}]\n    value: msg.v\n",
            ["4:12: goal: value function calls", "7:14: holding: a parameter from the message"],
        ),
    ],
)
def test_bad_configs_name_file_line_and_reason(
    tmp_path: Path, kb: KnowledgeBase, text: str, problems: list[str]
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(SensingConfigError) as info:
        SensingConfig.load(path, kb.model)
    found = info.value.problems
    assert len(found) == len(problems), found
    for got, want in zip(found, problems, strict=True):
        assert got.startswith(str(path)), got
        assert want in got, got
        assert len(got) < len(str(path)) + 300, got  # an expression is quoted, not copied whole


def test_a_missing_file_is_a_config_error(tmp_path: Path, kb: KnowledgeBase) -> None:
    with pytest.raises(SensingConfigError, match="cannot read the sensing config"):
        SensingConfig.load(tmp_path / "nope.yaml", kb.model)


def test_a_dict_config_is_checked_the_same_way(kb: KnowledgeBase) -> None:
    config = SensingConfig.from_dict(
        {"sensors": {"present": {"stream": "cam", "value": "msg.seen"}}}, kb.model
    )
    assert config.fluents() == {"present"} and config.rate == 10.0
    with pytest.raises(SensingConfigError, match=r"<dict>: present: value syntax error"):
        SensingConfig.from_dict(
            {"sensors": {"present": {"stream": "cam", "value": "msg."}}}, kb.model
        )
