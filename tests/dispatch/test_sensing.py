"""Sensing: messages -> sensed values -> batches to the knowledge base."""

from __future__ import annotations

import pytest
import trio
from ippc.dispatch.clock import SimulatedClock
from ippc.dispatch.config import SensingConfig
from ippc.dispatch.sensing import Sensing, SensingError
from ippc.kb import KnowledgeBase, Update

CONFIG = {
    "rate": 10,
    "sensors": {
        "present": {"stream": "camera", "params": ["*"], "value": "msg.seen"},
        "robot-at": [
            {  # where the robot is: every room at once
                "stream": "odometry",
                "params": ["r1", "*"],
                "value": "{'hall': msg.room == 'hall', 'office': msg.room == 'office', "
                "'lab': msg.room == 'lab'}",
            },
            {  # one room's beacon: is the robot here?
                "stream": "beacon",
                "params": ["r1", {"msg": "msg.room"}],
                "value": "msg.here",
            },
        ],
    },
}


def make(kb: KnowledgeBase) -> Sensing:
    return Sensing(kb, SensingConfig.from_dict(CONFIG, kb.model), clock=SimulatedClock())


def test_sensed_fluents_are_marked_and_changes_go_in_one_batch(kb: KnowledgeBase) -> None:
    seen: list[tuple[int, str]] = []
    kb.subscribe(lambda changes, source: seen.append((len(changes), source)))
    sensing = make(kb)
    assert kb.sensed_fluents() == {"present", "robot-at"}
    assert sensing.feed("camera", {"seen": {"office": True, "lab": False}}) == 2
    assert sensing.feed("odometry", {"room": "office"}) == 3  # the first values of three
    assert kb.get("present", ("office",)) is False  # nothing before the batch
    changes = sensing.flush()
    assert {(c.fluent, c.args, c.new) for c in changes} == {
        ("present", ("office",), True),
        ("robot-at", ("r1", "office"), True),
        ("robot-at", ("r1", "hall"), False),
    }  # present(lab) and robot-at(r1, lab) were false already: no change
    assert seen == [(3, "sensing")]  # one batch
    assert kb.get("present", ("office",)) is True


def test_a_repeated_value_is_not_sent_again(kb: KnowledgeBase) -> None:
    sensing = make(kb)
    sensing.feed("camera", {"seen": [("office", True)]})
    sensing.flush()
    assert sensing.feed("camera", {"seen": [("office", True)]}) == 0
    assert sensing.pending() == 0
    assert sensing.feed("camera", {"seen": [("office", False)]}) == 1


def test_a_sensed_value_is_sent_again_after_someone_else_changed_it(kb: KnowledgeBase) -> None:
    sensing = make(kb)
    sensing.feed("camera", {"seen": {"office": True}})
    sensing.flush()
    kb.apply([Update("set", "present", ("office",), False)], "handler:pickup")
    assert sensing.pending() == 1
    sensing.flush()
    assert kb.get("present", ("office",)) is True  # sensed truth wins


def test_bad_messages_are_logged_and_skipped(kb: KnowledgeBase) -> None:
    sensing = make(kb)
    assert sensing.feed("camera", {"nothing": 1}) == 0
    assert sensing.feed("camera", {"seen": {"kitchen": True}}) == 0
    assert sensing.feed("camera", {"seen": {"office": "yes"}}) == 0
    assert sensing.feed("camera", {"seen": 3}) == 0
    assert sensing.feed("beacon", {"room": "mars", "here": True}) == 0
    errors = list(sensing.errors)
    assert len(errors) == 5
    assert "no 'seen' in the message" in errors[0]
    assert "'kitchen' is not an object of type room" in errors[1]
    assert "present(office) is a bool, the value is 'yes'" in errors[2]
    assert "must be a mapping or a list of pairs" in errors[3]
    assert "'mars' is not an object of type room" in errors[4]
    assert all(e.startswith("<dict>") for e in errors)
    assert sensing.pending() == 0 and kb.get("present", ("office",)) is False
    # ... and the next good message still counts
    assert sensing.feed("camera", {"seen": {"office": True}}) == 1


def test_an_unknown_stream_is_an_error(kb: KnowledgeBase) -> None:
    sensing = make(kb)
    with pytest.raises(SensingError, match="no sensor reads stream 'lidar'"):
        sensing.feed("lidar", {})
    with pytest.raises(SensingError):
        sensing.publisher("lidar")


@pytest.mark.trio
async def test_async_iterators_and_polled_callables_feed_streams(kb: KnowledgeBase) -> None:
    sensing = make(kb)

    async def camera():  # type: ignore[no-untyped-def]
        for seen in (False, True):
            yield {"seen": {"office": seen}}

    await sensing.attach("camera", camera())
    assert sensing.messages == 2 and sensing.pending() == 1
    polls = iter([None, {"room": "lab"}])
    with trio.move_on_after(5):
        async with trio.open_nursery() as nursery:
            nursery.start_soon(sensing.attach, "odometry", lambda: next(polls, None))
            while sensing.messages < 3:
                await trio.sleep(0)
            nursery.cancel_scope.cancel()
    sensing.flush()
    assert kb.get("present", ("office",)) is True
    assert kb.get("robot-at", ("r1", "lab")) is True


@pytest.mark.trio
async def test_batches_go_out_at_the_configured_rate(kb: KnowledgeBase) -> None:
    sensing = Sensing(kb, SensingConfig.from_dict(CONFIG, kb.model))  # the wall clock
    async with trio.open_nursery() as nursery:
        await nursery.start(sensing.run)
        sensing.feed("camera", {"seen": {"office": True}})
        assert kb.get("present", ("office",)) is False
        with trio.fail_after(2):
            while not kb.get("present", ("office",)):
                await trio.sleep(0.01)
        nursery.cancel_scope.cancel()
    assert sensing.batches == 1


@pytest.mark.trio
async def test_settle_waits_while_messages_bring_changes(kb: KnowledgeBase) -> None:
    clock = SimulatedClock()
    sensing = Sensing(kb, SensingConfig.from_dict(CONFIG, kb.model), clock=clock)
    sensing.feed("camera", {"seen": {"office": True}})
    changes = await sensing.settle(limit=1.0)
    assert [c.args for c in changes] == [("office",)]
    assert clock.now() == pytest.approx(0.1)  # one quiet period
