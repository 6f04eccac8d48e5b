"""rddl-dispatch's knowledge-base socket under hostile clients: the robot's
run goes on and reaches its goal (real sockets on 127.0.0.1)."""

from __future__ import annotations

import socket
import struct

import pytest
import trio
from ippc.kb.jsonl import JsonlClient

from .test_remote import play, robot_controller


def reset(stream: trio.SocketStream) -> None:
    sock = stream.socket
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


@pytest.mark.trio
async def test_resets_and_deep_nesting_do_not_end_the_run() -> None:
    good = robot_controller()
    replies: list[bytes] = []

    async def controller(client: JsonlClient, ready: trio.Event) -> None:
        port = client.stream.socket.getpeername()[1]
        # a subscriber that never reads its events, reset once the robot moves
        sub = await trio.open_tcp_stream("127.0.0.1", port)
        await sub.send_all(b'{"id": 1, "method": "kb.subscribe", "params": {}}\n')
        deep = await trio.open_tcp_stream("127.0.0.1", port)
        await deep.send_all(b"[" * 1100 + b"\n")
        while b"\n" not in b"".join(replies):
            replies.append(await deep.receive_some(65536))
        reset(deep)

        async def later() -> None:
            await trio.sleep(0.3)
            reset(sub)

        async with trio.open_nursery() as nursery:
            nursery.start_soon(later)
            await good(client, ready)

    report = await play(controller)
    assert report.goal_reached
    assert b'"too-deep"' in b"".join(replies)
    assert [e["action"] for e in report.executed][-1] == "drop(r1)"


def test_the_kb_socket_takes_the_planner_ports_allow_and_rate() -> None:
    from ippc.dispatch.run import kb_socket_limits, server_config

    limits = kb_socket_limits(server_config(allow=("10.0.0.0/8",), accept_rate=7.0))
    assert (limits.allow, limits.accept_rate, limits.max_connections) == (
        ("10.0.0.0/8",),
        7.0,
        64,
    )
    assert kb_socket_limits(server_config(max_connections=5)).max_connections == 5
