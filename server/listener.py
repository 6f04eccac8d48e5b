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

from .limits import AcceptPacer, ConnectionTable, Notices, closed_already, peer_host


async def accept_connections(
    listener: trio.SocketListener,
    notices: Notices,
    table: ConnectionTable,
    pacer: AcceptPacer,
    keys: Iterator[int],
    take: Callable[[trio.SocketStream, int], bool],
    on_empty: Callable[[str], None] | None = None,
) -> None:
    """Accept connections on `listener` until cancelled, under the limits:
    at most `pacer`'s rate, refused at once (closed, counted in `notices`)
    when `table` refuses their address or is full; a connection whose peer
    closed before it was accepted is closed and `on_empty(host)` told. Each
    connection let in is added to `table` under a key from `keys` and
    handed to `take(stream, key)`, which must remove the key from the table
    when the connection ends; `take` returns True to stop accepting."""
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


__all__ = ["accept_connections"]
