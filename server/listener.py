"""The accept loop every listening socket of the toolkit goes through:
rddl-server's port, rddl-dispatch's planner port, and the knowledge base's
JSON-lines socket (`rddl-dispatch --kb-port`, `rddl-kb`).

It knows nothing of what is played on a connection: it paces accepts
(`AcceptPacer`), asks a `ConnectionTable` whether the peer may come in
(`--allow`, the caps in total and per address), drops connections whose
peer hung up before they were accepted, and hands the rest to its caller.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator

import trio

from .limits import (
    IDLE_EVICTED,
    AcceptPacer,
    ConnectionTable,
    Notices,
    closed_already,
    peer_host,
)


async def accept_connections(
    listener: trio.SocketListener,
    notices: Notices,
    table: ConnectionTable,
    pacer: AcceptPacer,
    keys: Iterator[int],
    take: Callable[[trio.SocketStream, int], bool],
    on_empty: Callable[[str], None] | None = None,
    evict: Callable[[int], bool | None] | None = None,
) -> None:
    """Accept connections on `listener` until cancelled, under the limits:
    at most `pacer`'s rate, refused at once (closed, counted in `notices`)
    when `table` refuses their address or is full; a connection whose peer
    closed before it was accepted is closed and `on_empty(host)` told. Each
    connection let in is added to `table` under a key from `keys` and
    handed to `take(stream, key)`, which must remove the key from the table
    when the connection ends; `take` returns True to stop accepting.

    With `evict`, a connection that finds the cap in total reached makes
    room: the oldest connection that has had no session for a second
    (`ConnectionTable.oldest_idle`) is closed by `evict(key)` (False: it
    has its session by now, and the next oldest is tried; None: another
    process is asked to close it, and the next connection finds the room),
    so idle connections cannot keep a good client out until their
    deadline."""
    async with listener:
        while True:
            await pacer.pace()
            # (one accept per pass of the scheduler: a flood of new
            # connections waits in the kernel's backlog while the
            # connections in progress take their turns)
            try:
                stream = await listener.accept()
            except OSError as err:  # e.g. too many open files: wait, go on
                notices.note(
                    f"accept failures: {err.strerror or err}",
                    f"accept failed: {err}",
                    logging.ERROR,
                )
                await trio.sleep(0.1)
                continue
            host = peer_host(stream.socket)
            refused = table.refusal(host)
            if refused is not None and evict is not None and table.full():
                if make_room(table, notices, evict, host):
                    refused = table.refusal(host)
            if refused is not None:
                notices.note(*refused)
                stream.socket.close()
                continue
            if closed_already(stream.socket):
                if on_empty is not None:
                    on_empty(host)
                stream.socket.close()
                continue
            key = next(keys)
            table.add(key, host)
            if take(stream, key):
                return


def make_room(
    table: ConnectionTable, notices: Notices, evict: Callable[[int], bool | None], host: str
) -> bool:
    """Close the oldest idle connection (up to 8 tried) for a new one from
    `host`; whether there is room now. `evict(key)` closes it and says True,
    says False when it has its session, or None when it asked the process
    that holds it to close it if idle (the room comes when it has)."""
    for _ in range(8):
        key = table.oldest_idle()
        if key is None:
            return False
        done = evict(key)
        if done is False:
            table.in_session(key)
            continue
        notices.note(
            IDLE_EVICTED,
            f"connection {key} closed to make room for one from {host}: the cap of"
            f" {table.max_total} open connections was reached and it had no session",
        )
        if done is None:
            table.asked(key)
            return False
        table.evicting(key)
        return True
    return False


__all__ = ["accept_connections", "make_room"]
