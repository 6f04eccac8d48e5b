"""Message framing: where one message ends in a byte stream.

Normally every message is followed by one NUL byte, in both directions. In no-header mode
rddlsim sends bare documents without a terminator, so the reader has to find the end of
the root element by following the XML structure (what PROST's reader does). Both readers
are incremental (each byte is looked at about once however the stream is chunked) and
bounded: a message growing past ``max_size`` is an error, never an ever-growing buffer.
"""

from __future__ import annotations

import re
from enum import Enum
from typing import Final, Literal

from .codec import MAX_MESSAGE_SIZE
from .errors import LocalProtocolError, RemoteProtocolError

__all__ = ["MessageReader", "frame"]

_NUL: Final = b"\0"
# Bytes allowed around and between bare documents: whitespace, NUL (a peer that also
# terminates), and a UTF-8 byte order mark.
_JUNK: Final = b" \t\r\n\0"
_BOM: Final = b"\xef\xbb\xbf"
_TAG_SPECIAL: Final = re.compile(rb"[\"'>]")
_DECL_SPECIAL: Final = re.compile(rb"[\"'>\[\]]")


def frame(doc: bytes, *, nul: bool = True) -> bytes:
    """``doc`` as it goes on the wire: followed by a NUL byte unless ``nul`` is false."""
    return doc + _NUL if nul else doc


class _Lex(Enum):
    """Where the bare-mode scanner stands."""

    TEXT = "text"  # character data (or whitespace between prolog items)
    LT = "lt"  # just after '<', not yet known what follows
    TAG = "tag"  # inside a start or end tag
    COMMENT = "comment"  # inside <!-- ... -->
    PI = "pi"  # inside <? ... ?> (the XML declaration included)
    CDATA = "cdata"  # inside <![CDATA[ ... ]]>
    DECL = "decl"  # inside <!DOCTYPE ...> (brackets and quotes tracked)


class MessageReader:
    """Split an incoming byte stream into messages.

    ``mode="nul"``: a message is everything before the next NUL byte.
    ``mode="bare"``: a message is one XML document, from its first ``<`` to the end of
    its root element; whitespace, NULs and a byte order mark before it are skipped.

    Feed bytes with :meth:`feed`, the end of the stream with :meth:`feed_eof`, and take
    messages with :meth:`next_message` until it returns ``None``. It raises
    :class:`RemoteProtocolError` for a message longer than ``max_size``, for a stream that
    ends inside a message, and (bare mode) for bytes that cannot start or continue a
    document. After an error the reader keeps raising it.
    """

    def __init__(
        self, mode: Literal["nul", "bare"] = "nul", max_size: int = MAX_MESSAGE_SIZE
    ) -> None:
        if mode not in ("nul", "bare"):
            raise ValueError(f"mode must be 'nul' or 'bare', not {mode!r}")
        self.mode: Final = mode
        self.max_size: Final = max_size
        self._buf = bytearray()
        self._eof = False
        self._error: RemoteProtocolError | None = None
        # nul mode: how far the buffer is known to hold no NUL
        self._scanned = 0
        # bare mode: scanner state, positions are indexes into _buf
        self._started = False  # _buf[0] is the '<' that starts the current message
        self._lex = _Lex.TEXT
        self._pos = 0  # next index to look at
        self._tok = 0  # where the current markup token starts
        self._search = 0  # where to resume looking for a terminator
        self._depth = 0
        self._end_tag = False
        self._quote = 0  # quote byte we are inside of (0: none)
        self._brackets = 0

    # ------------------------------------------------------------------ public API

    @property
    def at_eof(self) -> bool:
        """True once :meth:`feed_eof` was called (buffered messages may remain)."""
        return self._eof

    @property
    def buffered(self) -> int:
        """Bytes received and not yet handed out (junk between bare documents included
        until the next :meth:`next_message` skips it)."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray) -> None:
        """Append received bytes. ``b""`` is ignored; use :meth:`feed_eof` for the end."""
        if not data:
            return
        if self._eof:
            raise LocalProtocolError("data fed after the end of the stream")
        self._buf += data

    def feed_eof(self) -> None:
        """The peer closed its side: no more bytes will come."""
        self._eof = True

    def discard(self) -> None:
        """Drop every buffered byte (e.g. what a peer sends after the session ended)."""
        self._buf.clear()
        self._scanned = 0
        self._reset_bare()

    def next_message(self) -> bytes | None:
        """The next complete message without its terminator, or ``None`` if more bytes
        are needed (or the stream ended cleanly at a message boundary)."""
        if self._error is not None:
            raise self._error
        try:
            if self.mode == "nul":
                return self._next_nul()
            return self._next_bare()
        except RemoteProtocolError as exc:
            self._error = exc
            # the stream is unusable from here on: free its bytes now (up to
            # max_size of them) rather than when the reader goes, which the
            # error's traceback, holding this frame, may put off until a
            # garbage collection
            self.discard()
            raise

    # ------------------------------------------------------------------ nul mode

    def _next_nul(self) -> bytes | None:
        buf = self._buf
        end = buf.find(_NUL, self._scanned)
        if end < 0:
            self._scanned = len(buf)
            self._check_incomplete(len(buf))
            return None
        if end > self.max_size:
            raise self._oversize(end)
        msg = bytes(buf[:end])
        del buf[: end + 1]
        self._scanned = 0
        return msg

    # ------------------------------------------------------------------ bare mode

    def _next_bare(self) -> bytes | None:
        buf = self._buf
        if not self._started and not self._skip_junk():
            return None
        n = len(buf)
        while self._pos < n:
            lex = self._lex
            if lex is _Lex.TEXT:
                lt = buf.find(b"<", self._pos)
                stop = n if lt < 0 else lt
                if self._depth == 0 and bytes(buf[self._pos : stop]).strip(_JUNK):
                    raise RemoteProtocolError(
                        "text outside the root element of a bare XML message",
                        message_text=bytes(buf[: stop + 1]),
                    )
                if lt < 0:
                    self._pos = n
                    break
                self._tok = lt
                self._pos = lt + 1
                self._lex = _Lex.LT
            elif lex is _Lex.LT:
                if not self._classify(n):
                    break
            elif lex is _Lex.COMMENT:
                if not self._find_end(b"-->", n):
                    break
            elif lex is _Lex.PI:
                if not self._find_end(b"?>", n):
                    break
            elif lex is _Lex.CDATA:
                if not self._find_end(b"]]>", n):
                    break
            elif lex is _Lex.DECL:
                if not self._scan_decl(n):
                    break
            else:  # _Lex.TAG
                done = self._scan_tag(n)
                if done is None:
                    break
                if done:
                    msg = bytes(buf[: self._pos])
                    if len(msg) > self.max_size:
                        raise self._oversize(len(msg))
                    del buf[: self._pos]
                    self._reset_bare()
                    return msg
        self._check_incomplete(n)
        return None

    def _skip_junk(self) -> bool:
        """Drop bytes before the next document; True when a document start is buffered."""
        buf = self._buf
        i, n = 0, len(buf)
        while i < n:
            if buf[i] in _JUNK:
                i += 1
            elif buf.startswith(_BOM, i):
                i += len(_BOM)
            elif n - i < len(_BOM) and _BOM.startswith(bytes(buf[i:])):
                break  # maybe a BOM cut short: wait for the rest
            else:
                break
        if i:
            del buf[:i]
        if not buf:
            return False
        if buf[0] != ord("<"):
            if buf[0] == _BOM[0] and len(buf) < len(_BOM) and not self._eof:
                return False
            raise RemoteProtocolError(
                f"a bare XML message must start with '<', got {bytes(buf[:1])!r}",
                message_text=bytes(buf[:200]),
            )
        self._started = True
        self._pos = 0
        self._lex = _Lex.TEXT
        self._depth = 0
        return True

    def _reset_bare(self) -> None:
        self._started = False
        self._lex = _Lex.TEXT
        self._pos = 0
        self._depth = 0
        self._quote = 0

    def _classify(self, n: int) -> bool:
        """After '<': decide the token kind; False if more bytes are needed."""
        buf, tok = self._buf, self._tok
        if n <= tok + 1:
            return False
        c = buf[tok + 1]
        if c == ord("?"):
            self._lex, self._search = _Lex.PI, tok + 2
        elif c == ord("!"):
            rest = bytes(buf[tok + 2 : tok + 9])
            if rest.startswith(b"--"):
                self._lex, self._search = _Lex.COMMENT, tok + 4
            elif rest.startswith(b"[CDATA["):
                self._lex, self._search = _Lex.CDATA, tok + 9
            elif (b"--".startswith(rest) or b"[CDATA[".startswith(rest)) and len(rest) < 7:
                return False  # could still become a comment or CDATA
            else:
                self._lex, self._pos, self._quote, self._brackets = _Lex.DECL, tok + 2, 0, 0
        else:
            self._end_tag = c == ord("/")
            self._lex, self._quote = _Lex.TAG, 0
            self._pos = tok + 2 if self._end_tag else tok + 1
        return True

    def _find_end(self, terminator: bytes, n: int) -> bool:
        """Inside a comment, PI or CDATA: look for its terminator."""
        end = self._buf.find(terminator, self._search)
        if end < 0:
            # the terminator may be split across feeds: look again from just before n
            self._search = max(self._search, n - len(terminator) + 1)
            self._pos = n
            return False
        self._pos = end + len(terminator)
        self._lex = _Lex.TEXT
        return True

    def _leave_quote(self, n: int) -> bool:
        """Inside a quoted value (of an attribute, or in a DOCTYPE): move past its closing
        quote; False when that is not buffered yet (everything up to `n` is consumed)."""
        end = self._buf.find(bytes((self._quote,)), self._pos)
        if end < 0:
            self._pos = n
            return False
        self._pos, self._quote = end + 1, 0
        return True

    def _scan_decl(self, n: int) -> bool:
        """Inside <!DOCTYPE ...>: find the '>' outside quotes and the internal subset."""
        buf = self._buf
        while self._pos < n:
            if self._quote:
                if not self._leave_quote(n):
                    return False
                continue
            m = _DECL_SPECIAL.search(buf, self._pos)
            if m is None:
                self._pos = n
                return False
            c = buf[m.start()]
            self._pos = m.start() + 1
            if c in b"\"'":
                self._quote = c
            elif c == ord("["):
                self._brackets += 1
            elif c == ord("]"):
                self._brackets -= 1
            elif self._brackets <= 0:  # '>'
                self._lex = _Lex.TEXT
                return True
        return False

    def _scan_tag(self, n: int) -> bool | None:
        """Inside a tag: None = need more bytes; True = the root element just ended."""
        buf = self._buf
        while self._pos < n:
            if self._quote:
                if not self._leave_quote(n):
                    return None
                continue
            m = _TAG_SPECIAL.search(buf, self._pos)
            if m is None:
                self._pos = n
                return None
            k = m.start()
            self._pos = k + 1
            if buf[k] != ord(">"):
                self._quote = buf[k]
                continue
            self._lex = _Lex.TEXT
            if self._end_tag:
                self._depth -= 1
                if self._depth < 0:
                    raise RemoteProtocolError(
                        "end tag without a start tag in a bare XML message",
                        message_text=bytes(buf[: k + 1]),
                    )
                return self._depth == 0
            if buf[k - 1] == ord("/") and k - 1 > self._tok:
                return self._depth == 0  # self-closing: depth unchanged
            self._depth += 1
            return False
        return None

    # ------------------------------------------------------------------ both modes

    def _check_incomplete(self, pending: int) -> None:
        """No complete message buffered: fail on oversize or on EOF inside a message."""
        if self.mode == "bare" and not self._started:
            pending = 0  # only junk was buffered, and it is gone
        if pending > self.max_size:
            raise self._oversize(pending)
        if self._eof and pending:
            raise RemoteProtocolError(
                f"connection closed mid-message ({pending} bytes of an unfinished message)",
                message_text=bytes(self._buf[:200]),
            )

    def _oversize(self, size: int) -> RemoteProtocolError:
        return RemoteProtocolError(
            f"message too long: {size} bytes and counting, the limit is {self.max_size}",
            message_text=bytes(self._buf[:200]),
        )
