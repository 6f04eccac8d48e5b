"""rddlsim's log file and JSON-lines transcripts of the wire.

``RddlsimLog`` appends what rddlsim's ``Server.java`` appends to its log for each
session: a ``client-info`` document when the connection is accepted, then a copy of
every round-end and of the session-end. rddlsim writes each document as its serialiser
made it (the declaration, ``\\n``, the root element on one line) followed by a line
break, so a log is a sequence of two-line pairs::

    <?xml version="1.0" encoding="UTF-8"?>
    <client-info><client-hostname>localhost</client-hostname><client-ip>127.0.0.1</client-ip></client-info>
    <?xml version="1.0" encoding="UTF-8"?>
    <round-end>...</round-end>

rddlsim's evaluation tools (``rddl.evaluate.LogReader``) drop the first line, drop every
line that starts with the declaration and wrap the rest in ``<root>``; hence the
declaration must stand on its own line, which this class guarantees even for a document
given without one (a no-header session) or with the declaration glued to the root.

``TranscriptWriter`` writes the format of the shared rddlsim recordings (one JSON object
per line, the first one ``{"meta": {...}}``), and ``read_transcript`` reads both.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import os
import socket
import threading
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

__all__ = [
    "XML_DECLARATION",
    "RddlsimLog",
    "TranscriptWriter",
    "data_bytes",
    "read_transcript",
]

log = logging.getLogger(__name__)

#: The declaration rddlsim's serialiser writes (it always says UTF-8).
XML_DECLARATION = b'<?xml version="1.0" encoding="UTF-8"?>'

#: Decimal places of ``t`` in transcripts, as in the shared recordings.
T_DIGITS = 4


def _write_all(fd: int, data: bytes) -> None:
    # os.write may write less than asked (a signal, a full disk); keep going until done.
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


class _AppendFile:
    """A file opened for appending whose every ``append`` is one unbuffered write.

    With O_APPEND each write lands at the end even when several writers share the file,
    and nothing waits in a user-space buffer, so a killed process loses nothing it wrote.
    """

    def __init__(self, path: Path, *, exclusive: bool = False) -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | (os.O_EXCL if exclusive else 0)
        self._fd: int | None = os.open(path, flags, 0o644)
        self._lock = threading.Lock()

    def append(self, data: bytes) -> None:
        with self._lock:
            if self._fd is None:
                raise ValueError(f"{self.path} is closed")
            _write_all(self._fd, data)

    def close(self) -> None:
        with self._lock:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None


class RddlsimLog:
    """rddlsim's server log: ``client-info``, then every round-end and session-end.

    One object may serve every session of a server (calls are serialised; each document
    is one write, so documents of concurrent sessions never interleave within a line).
    The file is appended to, as rddlsim does, and each call reaches the file before it
    returns.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = _AppendFile(self.path)

    @staticmethod
    def default_path(log_dir: Path | None, port: int) -> Path:
        """rddlsim's file name: ``<log_dir>/logs-<port>.log``, or ``rddl-<port>.log`` in the
        current directory when no log folder is given."""
        if log_dir is None:
            return Path(f"rddl-{port}.log")
        return Path(log_dir) / f"logs-{port}.log"

    @staticmethod
    def canonical_hostname(ip: str) -> str:
        """The host name rddlsim logs for a client address, as Java's
        ``InetAddress.getCanonicalHostName``: the reverse-DNS name if it resolves back to
        the same address, else the address itself. This resolves names, so it blocks:
        call it in a worker thread from async code."""
        try:
            addr = ipaddress.ip_address(ip)
            name = socket.gethostbyaddr(str(addr))[0]
            infos = socket.getaddrinfo(name, None)
        except (OSError, ValueError):
            return ip
        if any(ipaddress.ip_address(str(info[4][0]).split("%")[0]) == addr for info in infos):
            return name
        return ip

    def client_info(self, hostname: str, ip: str) -> None:
        """Append the ``client-info`` document rddlsim writes when it accepts a connection."""
        body = (
            f"<client-info><client-hostname>{escape(hostname)}</client-hostname>"
            f"<client-ip>{escape(ip)}</client-ip></client-info>"
        )
        self._file.append(XML_DECLARATION + b"\n" + body.encode("utf-8") + b"\n")

    def message(self, doc: bytes) -> None:
        """Append a document the server sent (round-end, session-end): ``doc`` as on the
        wire, with or without its declaration, without the NUL terminator (a trailing
        NUL is dropped). It is written as the declaration line, the root element line."""
        body = bytes(doc)
        if body.endswith(b"\0"):
            body = body[:-1]
        if body.startswith(b"<?xml"):
            end = body.find(b"?>")
            if end < 0:
                raise ValueError("unterminated XML declaration in log message")
            body = body[end + 2 :]
        body = body.strip(b" \t\r\n")
        if b"\n" in body or b"\r" in body:
            # rddlsim's documents never hold a line break; one would split the document
            # over lines that LogReader treats one by one.
            log.warning("log message contains a line break: %r", body[:80])
        self._file.append(XML_DECLARATION + b"\n" + body + b"\n")

    def close(self) -> None:
        """Close the file (idempotent)."""
        self._file.close()

    def __enter__(self) -> RddlsimLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_DIRECTIONS = ("c2s", "s2c")


def _check_direction(direction: str) -> None:
    if direction not in _DIRECTIONS:
        raise ValueError(f"direction must be 'c2s' or 's2c', not {direction!r}")


class TranscriptWriter:
    """Writes a transcript in the JSON-lines format of the shared rddlsim recordings.

    The first line is ``{"meta": meta}``; then one line per message, end of stream or
    note, numbered by ``i`` from 0. Message bytes are stored as text by latin-1 decoding
    (so every byte survives; the protocol is ASCII), the NUL terminator included when it
    was on the wire. Every line reaches the file before the call returns. The file must
    not exist yet (a transcript is never appended to or overwritten); see
    :meth:`unique_path`.
    """

    def __init__(self, path: Path, meta: dict[str, Any]) -> None:
        self.path = Path(path)
        self._file = _AppendFile(self.path, exclusive=True)
        self._i = 0
        self._lock = threading.Lock()
        self._file.append(self._dump({"meta": meta}))

    @staticmethod
    def unique_path(directory: Path, stem: str) -> Path:
        """``directory/stem.jsonl``, or ``stem-2.jsonl``, ``stem-3.jsonl``... if taken."""
        directory = Path(directory)
        path = directory / f"{stem}.jsonl"
        n = 2
        while path.exists():
            path = directory / f"{stem}-{n}.jsonl"
            n += 1
        return path

    @staticmethod
    def _dump(obj: dict[str, Any]) -> bytes:
        # json's defaults (", " and ": " separators, ASCII escapes) are what the
        # recordings use, so lines come out byte for byte alike.
        return json.dumps(obj).encode("ascii") + b"\n"

    def _line(self, fields: dict[str, Any]) -> None:
        with self._lock:
            record = {"i": self._i, **fields}
            self._file.append(self._dump(record))
            self._i += 1

    @staticmethod
    def _t(t: float) -> float:
        return round(float(t), T_DIGITS)

    def message(
        self, direction: str, data: bytes, conn: int | None, t: float, partial: bool = False
    ) -> None:
        """One message: its bytes as sent (with the NUL if there was one). ``partial`` marks
        bytes that ended without a terminator at end of stream. ``conn`` None leaves the
        key out, as the single-connection recordings do."""
        _check_direction(direction)
        fields: dict[str, Any] = {"t": self._t(t)}
        if conn is not None:
            fields["conn"] = int(conn)
        fields["dir"] = direction
        fields["data"] = bytes(data).decode("latin-1")
        if partial:
            fields["partial"] = True
        self._line(fields)

    def eof(self, direction: str, conn: int | None, t: float) -> None:
        """That side of connection ``conn`` closed (``direction`` is who stopped sending)."""
        _check_direction(direction)
        fields: dict[str, Any] = {"t": self._t(t)}
        if conn is not None:
            fields["conn"] = int(conn)
        fields["dir"] = direction
        fields["event"] = "eof"
        self._line(fields)

    def note(self, text: str, t: float | None = None) -> None:
        """An annotation that was not on the wire."""
        fields: dict[str, Any] = {} if t is None else {"t": self._t(t)}
        fields["event"] = "note"
        fields["text"] = str(text)
        self._line(fields)

    def close(self) -> None:
        """Close the file (idempotent)."""
        self._file.close()

    def __enter__(self) -> TranscriptWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_transcript(path: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Read a transcript (ours or a shared recording): ``(meta, records)``.

    Records are the JSON objects as written. A last line cut short (the writer was killed
    in the middle of it) is skipped with a warning; any other bad line is a ValueError
    naming the line.
    """
    path = Path(path)
    raw = path.read_bytes()
    lines = raw.split(b"\n")
    torn = lines.pop() if lines else b""  # text after the last newline
    meta: dict[str, Any] | None = None
    records: list[dict[str, Any]] = []
    for lineno, line in enumerate(lines, 1):
        try:
            obj = json.loads(line)
        except ValueError as e:
            raise ValueError(f"{path}:{lineno}: not a JSON line: {e}") from None
        if not isinstance(obj, dict):
            raise ValueError(f"{path}:{lineno}: expected a JSON object")
        if lineno == 1:
            if set(obj) != {"meta"} or not isinstance(obj["meta"], dict):
                raise ValueError(f'{path}:1: the first line must be {{"meta": {{...}}}}')
            meta = obj["meta"]
        else:
            records.append(obj)
    if torn.strip():
        try:
            obj = json.loads(torn)
        except ValueError:
            log.warning("%s: last line is incomplete; skipped", path)
        else:
            if meta is None:
                meta = obj.get("meta") if isinstance(obj, dict) else None
            else:
                records.append(obj)
    if meta is None:
        raise ValueError(f"{path}: empty transcript (no meta line)")
    return meta, records


def data_bytes(record: dict[str, Any]) -> bytes:
    """The wire bytes of a message record (inverse of the writer's latin-1 decoding)."""
    return str(record["data"]).encode("latin-1")
