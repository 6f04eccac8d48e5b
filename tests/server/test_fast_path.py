"""The server's fast paths give what the general paths give: turns written by an
instance's `ObservedFluentsWriter` equal the general encoder's bytes on every served
instance and many states; the session's plain-socket transport delivers every byte of
a message larger than the socket buffers, works on any other stream too, and leaves no
descriptor behind."""

from __future__ import annotations

import gc
import os
import socket
import warnings
from pathlib import Path

import numpy as np
import pytest
import trio
import trio.testing
from ippc.protocol import (
    Fluent,
    ObservedFluentsWriter,
    SessionInit,
    SessionRequest,
    Turn,
)
from ippc.rddl.simulator import SimulationError, State
from ippc.server.config import ServerConfig
from ippc.server.registry import Instance, Registry
from ippc.server.session import Services, _Channel

from ..protocol.test_fast_turn import _at_first_turn
from .harness import RawClient, noop_session, running_server, session_request, shared_registry

DOMAINS = Path(__file__).resolve().parents[2] / "domains"


def _registries() -> list[Registry]:
    return [shared_registry(), Registry.load(DOMAINS)]


def test_turns_written_fast_equal_the_general_encoder_on_every_instance() -> None:
    checked = 0
    kinds: set[str] = set()
    for registry in _registries():
        for name in registry.names():
            instance = registry.get(name)
            sim, codec = instance.compiled_now()
            rng = np.random.default_rng(7)
            state = sim.initial_state(1)
            observation = None
            for turn in range(1, 31):
                sent = codec.turn_fluents(state, observation)
                fluents = None if sent is None else tuple(Fluent(*t) for t in sent)
                kinds.update(type(t[2]).__name__ for t in sent or ())
                # written (or found in the instance's cache: the second call), then compared
                for _ in range(2):
                    cached_sent, xml = instance.turn_fluents(codec, state, observation)
                    assert cached_sent == sent
                reward = float(turn) / 3.0
                for no_header in (False, True):
                    fast = _at_first_turn(no_header).send_turn(turn, 1079999.0, reward, xml)
                    slow = _at_first_turn(no_header).send(Turn(turn, 1079999.0, reward, fluents))
                    assert fast == slow, (name, turn)
                checked += 1
                try:
                    step = sim.step(state, sim.random_actions(state, rng), rng, check=False)
                except SimulationError:  # random actions can be out of a distribution's domain
                    step = sim.step(state, None, rng, check=False)
                state, observation = step.next_state, step.observation
                if bool(step.done[0]):
                    state, observation = sim.initial_state(1), None
    assert checked >= 30 * 10
    assert {"bool", "float"} <= kinds  # and str where an instance has enum or object fluents


def test_writer_is_shared_by_sessions_and_rebuilt_for_another_listing() -> None:
    instance = shared_registry().get("sysadmin_inst_mdp__1")
    sim, codec = instance.compiled_now()
    sent = codec.turn_fluents(sim.initial_state(1), None)
    assert sent is not None
    first = instance.fluents_writer(sent)
    assert instance.fluents_writer(sent) is first
    assert first.groundings == tuple((n, a) for n, a, _ in sent)
    other = instance.fluents_writer(sent[:3])
    assert other is not first and len(other) == 3


def test_turn_cache_is_keyed_by_values_and_types_and_bounded(monkeypatch) -> None:
    shared = shared_registry().get("sysadmin_inst_mdp__1")
    instance = Instance(shared.name, shared.model, shared.task)  # a fresh, empty cache
    sim, codec = instance.compiled_now()
    running = np.array([[True, False] * 5])
    as_bytes = running.astype(np.uint8)  # the same bytes, another type
    states = [
        State({"running": running}),
        State({"running": as_bytes}),
        State({"running": running.T.copy().T}),
    ]
    written = []
    for state in states * 2:
        expected = codec.turn_fluents(state, None)
        assert expected is not None
        sent, xml = instance.turn_fluents(codec, state, None)
        assert [type(v) for _, _, v in sent or ()] == [type(v) for _, _, v in expected]
        assert xml == ObservedFluentsWriter((n, a) for n, a, _ in expected).write(
            [v for _, _, v in expected]
        )
        written.append(xml)
    assert (
        "<fluent-value>true<" in written[0] and "<fluent-value>1<" in written[1]
    )  # True == 1 in Python
    assert len(instance._turns) == 2  # bool and uint8; the third state is the first again
    monkeypatch.setattr("ippc.server.registry.TURN_CACHE_CHARS", 0)
    other = State({"running": ~running})
    assert instance.turn_fluents(codec, other, None)[0] == codec.turn_fluents(other, None)
    assert len(instance._turns) == 2  # full: written, not kept


# ------------------------------------------------------------------ the transport


def _services() -> Services:
    return Services(ServerConfig(port=0), shared_registry())


@pytest.mark.trio
async def test_raw_send_delivers_a_message_larger_than_the_socket_buffers() -> None:
    payload = bytes(range(256)) * (16 * 1024)  # 4 MiB: many times any loopback buffer
    got = bytearray()
    listeners = await trio.open_tcp_listeners(0, host="127.0.0.1")
    port = listeners[0].socket.getsockname()[1]
    with trio.fail_after(30):
        async with trio.open_nursery() as nursery:

            async def slow_reader() -> None:
                stream = await trio.open_tcp_stream("127.0.0.1", port)
                async with stream:
                    while len(got) < len(payload):
                        data = await stream.receive_some(1 << 16)
                        if not data:
                            break
                        got.extend(data)
                        await trio.sleep(0.0005)  # slower than the writer: it must wait

            nursery.start_soon(slow_reader)
            server_stream = await listeners[0].accept()
            channel = _Channel(server_stream, _services(), 1, 0.0)
            assert channel._raw is not None  # a TCP stream takes the plain-socket path
            # no Nagle delay on what the server writes (trio sets it on accepted sockets)
            assert channel._raw.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
            await channel._send_all(payload)
            channel.close_raw()
    await server_stream.aclose()
    await listeners[0].aclose()
    assert bytes(got) == payload


@pytest.mark.trio
async def test_raw_receive_sees_every_byte_and_the_end() -> None:
    chunks = [os.urandom(n) for n in (1, 700, 65536, 200_000, 3)]
    listeners = await trio.open_tcp_listeners(0, host="127.0.0.1")
    port = listeners[0].socket.getsockname()[1]
    got = bytearray()
    with trio.fail_after(30):
        async with trio.open_nursery() as nursery:

            async def writer() -> None:
                stream = await trio.open_tcp_stream("127.0.0.1", port)
                async with stream:
                    for c in chunks:
                        await stream.send_all(c)
                        await trio.sleep(0.001)
                    await stream.send_eof()
                    await trio.sleep(0.2)

            nursery.start_soon(writer)
            server_stream = await listeners[0].accept()
            channel = _Channel(server_stream, _services(), 1, 0.0)
            while data := await channel._receive_some():
                got.extend(data)
            channel.close_raw()
    await server_stream.aclose()
    await listeners[0].aclose()
    assert bytes(got) == b"".join(chunks)


@pytest.mark.trio
async def test_other_streams_use_their_own_methods() -> None:
    left, right = trio.testing.memory_stream_pair()
    channel = _Channel(left, _services(), 1, 0.0)
    assert channel._raw is None
    with trio.fail_after(5):
        await channel._send_all(b"hello\0")
        assert await right.receive_some(100) == b"hello\0"
        await right.send_all(b"<actions/>\0")
        assert await channel._receive_some() == b"<actions/>\0"
    channel.close_raw()  # nothing to close: fine


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.trio
@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc")
async def test_sessions_leave_no_descriptor_behind() -> None:
    config = ServerConfig(port=0, rounds=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        await _play_sessions(config)
        gc.collect()
    # a socket left for the garbage collector to close says so
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]


async def _play_sessions(config: ServerConfig) -> None:
    async with running_server(config) as (port, _svc):
        await noop_session(port)  # warm: the instance is compiled, trio's threads exist
        await trio.sleep(0.05)
        before = _open_fds()
        for _ in range(5):
            result = await noop_session(port)
            assert len(result["rounds"]) == 1 and len(result["states"]) == 5  # horizon 5
        # a client that goes away in the middle of a session
        quitter = await RawClient.connect(port)
        await quitter.send(session_request())
        assert await quitter.recv() is not None  # session-init
        await quitter.close()
        with trio.fail_after(5):
            while _open_fds() > before:
                await trio.sleep(0.02)
        assert _open_fds() <= before


def _count_checkpoints(monkeypatch) -> list[int]:
    """Count trio.lowlevel.checkpoint calls from now on (in the one-item list
    returned)."""
    count = [0]
    original = trio.lowlevel.checkpoint

    async def counting() -> None:
        count[0] += 1
        await original()

    monkeypatch.setattr(trio.lowlevel, "checkpoint", counting)
    return count


@pytest.mark.trio
async def test_a_client_that_writes_far_ahead_does_not_hold_the_server(monkeypatch) -> None:
    # Plain-socket sends do not yield to trio; a session that finds many messages
    # already buffered yields every so often by itself.
    yields = _count_checkpoints(monkeypatch)
    n = 2000
    request = b'<?xml version="1.0" encoding="UTF-8"?>\n<resource-request/>\0'
    config = ServerConfig(port=0, rounds=1)
    async with running_server(config) as (port, _svc):
        flooder = await RawClient.connect(port)
        await flooder.send(session_request())
        assert await flooder.recv() is not None  # session-init
        with trio.fail_after(30):
            async with trio.open_nursery() as nursery:
                healthy: dict = {}

                async def play() -> None:
                    healthy.update(await noop_session(port))

                nursery.start_soon(play)
                await flooder.send(request * n)
                for _ in range(n):
                    msg = await flooder.recv()
                    assert msg is not None and b"<resource-notification>" in msg
        await flooder.close()
    assert len(healthy["states"]) == 5
    assert yields[0] >= n // 32 - 1


async def _tcp_channel_pair(
    services: Services,
) -> tuple[_Channel, trio.SocketStream, trio.SocketStream, trio.SocketListener]:
    listeners = await trio.open_tcp_listeners(0, host="127.0.0.1")
    port = listeners[0].socket.getsockname()[1]
    client = await trio.open_tcp_stream("127.0.0.1", port)
    server_stream = await listeners[0].accept()
    return _Channel(server_stream, services, 1, 0.0), server_stream, client, listeners[0]


@pytest.mark.trio
async def test_busy_poll_takes_what_arrives_and_gives_up_after_its_window() -> None:
    services = Services(ServerConfig(port=0, busy_poll_us=2000.0), shared_registry())
    with trio.fail_after(10):
        channel, server_stream, client, listener = await _tcp_channel_pair(services)
        # nothing comes: the poll ends after its window (2 ms), not before
        t0 = trio.current_time()
        assert channel._poll_briefly() is None
        assert 0.002 <= trio.current_time() - t0 < 1.0
        # bytes already there, or arriving during the window, are returned
        await client.send_all(b"<actions/>\0")
        got = b""
        for _ in range(100):
            got += channel._poll_briefly() or b""
            if got == b"<actions/>\0":
                break
            await trio.sleep(0.001)
        assert got == b"<actions/>\0"
        # with another session open the poll stands aside: the bytes stay for the wait
        await client.send_all(b"<round-request/>\0")
        await trio.sleep(0.05)
        services.open_sessions.update({1: object(), 2: object()})
        assert channel._poll_briefly() is None
        services.open_sessions.clear()
        # the end of the stream is an answer too
        await client.aclose()
        rest = b""
        while (data := channel._poll_briefly()) != b"":
            assert data is not None
            rest += data
        assert rest == b"<round-request/>\0"
        channel.close_raw()
    await server_stream.aclose()
    await listener.aclose()


@pytest.mark.trio
async def test_busy_poll_off_never_reads() -> None:
    services = Services(ServerConfig(port=0), shared_registry())
    assert services.config.busy_poll_us == 0.0  # off unless asked (rddl-server asks)
    with trio.fail_after(10):
        channel, server_stream, client, listener = await _tcp_channel_pair(services)
        await client.send_all(b"<actions/>\0")
        await trio.sleep(0.05)
        assert channel._poll_briefly() is None
        assert await channel._receive_some() == b"<actions/>\0"
        channel.close_raw()
        await client.aclose()
    await server_stream.aclose()
    await listener.aclose()


@pytest.mark.trio
async def test_sessions_with_busy_poll_play_as_without_it() -> None:
    results = []
    for poll in (0.0, 50.0):
        async with running_server(ServerConfig(port=0, rounds=2, busy_poll_us=poll)) as (
            port,
            _svc,
        ):
            with trio.fail_after(30):
                results.append(await noop_session(port))
    assert results[0] == results[1]
    assert len(results[0]["rounds"]) == 2 and results[0]["states"]


def test_lone_session_with_busy_poll_plays_a_client_outside_the_event_loop() -> None:
    # A client in another thread answers at once, so the poll finds most answers
    # without entering the event loop; the session plays to its end all the same
    # and the event loop's other tasks keep running.
    import threading

    rounds = 12
    config = ServerConfig(port=0, rounds=rounds, busy_poll_us=5000.0)
    ticks_during_session = 0
    turns: list[int] = []

    def client(port: int) -> None:
        with socket.create_connection(("127.0.0.1", port), timeout=20) as sock:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.sendall(session_request())
            buf = b""
            n = ends = 0
            while True:
                while b"\0" not in buf:
                    data = sock.recv(65536)
                    if not data:
                        turns.append(n)
                        return
                    buf += data
                msg, _, buf = buf.partition(b"\0")
                ends += b"<round-end>" in msg
                if b"<session-init>" in msg or (b"<round-end>" in msg and ends < rounds):
                    sock.sendall(b"<round-request/>\0")
                elif b"<turn>" in msg:
                    n += 1
                    sock.sendall(b"<actions/>\0")

    async def main() -> None:
        nonlocal ticks_during_session
        async with running_server(config) as (port, svc):
            thread = threading.Thread(target=client, args=(port,), daemon=True)
            with trio.fail_after(30):
                thread.start()
                while not turns:
                    if svc.open_sessions:
                        ticks_during_session += 1
                    await trio.sleep(0)
            thread.join(5)

    trio.run(main)
    assert turns == [rounds * 5]  # horizon 5
    assert ticks_during_session >= 1


@pytest.mark.trio
async def test_answers_found_by_the_busy_poll_still_yield_every_so_often(monkeypatch) -> None:
    # Each answer is on the socket before the session asks for it, so the poll
    # (not the event loop) finds every one; the channel still yields regularly.
    from ippc.protocol import ResourceNotification, ResourceRequest
    from ippc.server import session as session_module

    services = Services(ServerConfig(port=0, busy_poll_us=5000.0), shared_registry())
    request = b'<?xml version="1.0" encoding="UTF-8"?>\n<resource-request/>\0'
    n = 4 * session_module._YIELD_EVERY
    with trio.fail_after(20):
        channel, server_stream, client, listener = await _tcp_channel_pair(services)
        await client.send_all(session_request())
        assert isinstance(await channel.receive(), SessionRequest)
        await channel.send(SessionInit(b"task", 1, 1, 1000.0))
        yields = _count_checkpoints(monkeypatch)
        for _ in range(n):
            await client.send_all(request)
            assert isinstance(await channel.receive(), ResourceRequest)
            await channel.send(ResourceNotification(time_left=1000.0))
        monkeypatch.undo()
        channel.close_raw()
        await client.aclose()
    await server_stream.aclose()
    await listener.aclose()
    assert yields[0] >= n // session_module._YIELD_EVERY - 1
