"""The dispatcher's methods on the knowledge base's JSON-lines socket.

A controller in any language connects to the socket that serves the
knowledge base (`ippc.kb.jsonl`, the `kb.*` methods) and also finds there:

* ``sensing.publish`` ``{"stream": "odometry", "msg": {...}}``: one sensor
  message, evaluated as an in-process one and sent to the knowledge base at
  once (`Sensing.publish`); the result says what the knowledge base
  accepted and what was refused (by the sensor, or by the knowledge base: a
  broken state invariant): ``{"changed": n, "accepted": [{fluent, args,
  value}], "refused": [{fluent, args, value, reason}]}``;
* ``sensing.streams``: the streams some sensor reads;
* ``handlers.register`` ``{"actions": ["move", "pickup"]}``: this connection
  handles these actions (an action name, ``"*"`` or ``"noop"``). Each
  dispatch then arrives as the event
  ``{"event": "dispatch.action", "id": 12, "turn": 3, "action": "move",
  "args": ["r1", "hall", "office"], "params": {"r": "r1", "r1": "hall",
  "r2": "office"}, "timeout": 60.0}``;
* ``handlers.result`` ``{"id": 12, "outcome": "succeeded", "message": "",
  "cost": 4.2}``: the outcome of dispatch 12 (succeeded, failed or
  precondition-false);
* ``handlers.unregister`` ``{"actions": [...]}``.

A dispatch that gets no result within the action timeout fails (timeout),
as an in-process handler does; a result for a dispatch nobody waits for any
more is an error reply; when the connection closes, its handlers are removed
and the dispatches it still owes fail at once. Bad requests get an error
reply and never end the socket or the dispatcher.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import Any

import trio

from ..kb.jsonl import Connection, JsonlServer, RequestError
from .actions import Dispatch, Handlers, Result, Status
from .sensing import Sensing, SensingError

__all__ = ["RemoteHandlers", "register_dispatch"]

log = logging.getLogger(__name__)

_OUTCOMES = {s.value: s for s in Status}


def _text(params: dict[str, Any], key: str) -> str:
    value = params.get(key)
    if not isinstance(value, str) or not value:
        raise RequestError("bad-params", f"'{key}' must be a non-empty string")
    return value


class RemoteHandlers:
    """Handlers that live on the other end of JSON-lines connections."""

    def __init__(self, handlers: Handlers, actions: Iterable[str]):
        self.handlers = handlers
        self.known = frozenset(actions) | {Handlers.ANY, Handlers.NOOP}
        # dispatch id -> (connection, event, result box)
        self._waiting: dict[int, tuple[Connection, trio.Event, list[Result]]] = {}

    def register(self, params: dict[str, Any], conn: Connection) -> dict[str, Any]:
        """handlers.register: this connection handles these actions."""
        actions = params.get("actions")
        if not isinstance(actions, list) or not actions:
            raise RequestError("bad-params", "'actions' must be a non-empty list of action names")
        for name in actions:
            if not isinstance(name, str) or name not in self.known:
                raise RequestError(
                    "bad-params", f"{name!r} is not an action of the domain (nor '*' or 'noop')"
                )
        owned: dict[str, Any] = conn.state.setdefault("dispatch.handlers", {})
        for name in actions:
            owned[name] = self.handlers.register(name, self._remote(conn))
        if not conn.state.get("dispatch.watched"):
            conn.state["dispatch.watched"] = True
            conn.on_close(self._closed)
        return {"registered": sorted(owned)}

    def unregister(self, params: dict[str, Any], conn: Connection) -> dict[str, Any]:
        """handlers.unregister: this connection stops handling these actions."""
        actions = params.get("actions")
        if not isinstance(actions, list):
            raise RequestError("bad-params", "'actions' must be a list of action names")
        owned: dict[str, Any] = conn.state.get("dispatch.handlers", {})
        for name in actions:
            remove = owned.pop(name, None)
            if remove is not None:
                remove()
        return {"registered": sorted(owned)}

    def result(self, params: dict[str, Any], conn: Connection) -> dict[str, Any]:
        """handlers.result: the outcome of one dispatch."""
        rid = params.get("id")
        if not isinstance(rid, int) or isinstance(rid, bool):
            raise RequestError("bad-params", "'id' must be the dispatch's id (an integer)")
        outcome = params.get("outcome")
        status = _OUTCOMES.get(outcome) if isinstance(outcome, str) else None
        if status is None:
            raise RequestError(
                "bad-params", f"'outcome' must be one of {', '.join(_OUTCOMES)}, not {outcome!r}"
            )
        message = params.get("message", "")
        cost = params.get("cost")
        if not isinstance(message, str):
            raise RequestError("bad-params", "'message' must be a string")
        if cost is not None and (isinstance(cost, bool) or not isinstance(cost, int | float)):
            raise RequestError("bad-params", "'cost' must be a number")
        waiting = self._waiting.get(rid)
        if waiting is None or waiting[0] is not conn:
            raise RequestError(
                "unknown-dispatch",
                f"no dispatch {rid} is waiting for this connection (timed out, answered, or never sent)",
            )
        _, event, box = waiting
        box.append(Result(status, message, None if cost is None else float(cost)))
        event.set()
        return {"ok": True}

    def _remote(self, conn: Connection) -> Any:
        async def handle(dispatch: Dispatch) -> Result:
            if conn.closed:
                return Result(Status.FAILED, f"the remote handler's connection {conn.peer} closed")
            event = trio.Event()
            box: list[Result] = []
            self._waiting[dispatch.id] = (conn, event, box)
            try:
                conn.send_event(
                    "dispatch.action",
                    {
                        "id": dispatch.id,
                        "turn": dispatch.turn,
                        "action": dispatch.name,
                        "args": list(dispatch.args),
                        "params": dict(dispatch.params),
                        "timeout": dispatch.timeout,
                    },
                )
                await event.wait()
            finally:
                self._waiting.pop(dispatch.id, None)
            if not box:
                return Result(Status.FAILED, f"the remote handler's connection {conn.peer} closed")
            return box[0]

        return handle

    def _closed(self, conn: Connection) -> None:
        for remove in conn.state.pop("dispatch.handlers", {}).values():
            remove()
        for rid, (owner, event, _) in list(self._waiting.items()):
            if owner is conn:
                event.set()  # the box stays empty: the dispatch fails
                self._waiting.pop(rid, None)
        log.info("remote handlers of %s removed (connection closed)", conn)


def register_dispatch(
    server: JsonlServer, handlers: Handlers, sensing: Sensing | None, actions: Iterable[str]
) -> RemoteHandlers:
    """Add the dispatcher's methods (`sensing.*`, `handlers.*`) to `server`;
    `actions` are the domain's action names."""
    remote = RemoteHandlers(handlers, actions)

    def publish(params: dict[str, Any], conn: Connection) -> dict[str, Any]:
        """sensing.publish: one sensor message {stream, msg}."""
        if sensing is None:
            raise RequestError("no-sensing", "this dispatcher has no sensing config")
        stream = _text(params, "stream")
        if "msg" not in params:
            raise RequestError("bad-params", "'msg' (the message) is missing")
        try:
            return sensing.publish(stream, params["msg"])
        except SensingError as err:
            raise RequestError("unknown-stream", str(err)) from None

    def streams(params: dict[str, Any], conn: Connection) -> list[str]:
        """sensing.streams: the streams some sensor reads."""
        return [] if sensing is None else sorted(sensing.streams())

    server.register("sensing.publish", publish)
    server.register("sensing.streams", streams)
    server.register("handlers.register", remote.register)
    server.register("handlers.unregister", remote.unregister)
    server.register("handlers.result", remote.result)
    return remote
