"""Loading the recorded sessions (rddlsim transcripts and PROST captures) for the tests.

Scenario names are listed at import time (for parametrisation); the files themselves are
opened through the ``recordings`` fixture of tests/conftest.py (tests/data).
"""

from __future__ import annotations

import functools
import gzip
import json
from dataclasses import dataclass
from pathlib import Path

from ippc.protocol import XML_DECLARATION

from ..conftest import DATA as _DATA

_TRANSCRIPTS = _DATA / "rddlsim" / "transcripts"
_PROST = _DATA / "prost"

#: Every rddlsim scenario (file stem).
RDDLSIM_SCENARIOS: list[str] = sorted(p.stem for p in _TRANSCRIPTS.glob("*.jsonl"))
#: Every PROST capture (instance name).
PROST_INSTANCES: list[str] = sorted(
    p.name.removesuffix(".c2s.raw") for p in _PROST.glob("*.c2s.raw")
)
assert RDDLSIM_SCENARIOS and PROST_INSTANCES, f"the recordings are missing from {_DATA}"

#: rddlsim scenarios whose messages are deliberately not well-formed or not decodable:
#: (scenario, direction, index of the message within that direction) -> expected error text.
BROKEN: dict[tuple[str, str, int], str] = {
    ("py_disconnect_mid_message", "c2s", 3): "not well-formed",
    ("py_input_language_pddl", "s2c", 0): "not well-formed",
    ("py_malformed_action", "c2s", 2): "not well-formed",
    ("py_malformed_session_request", "c2s", 0): "not well-formed",
    ("py_malformed_session_request", "c2s", 1): "unknown root element <hello>",
    ("py_resource_request", "c2s", 2): "not well-formed",
    ("py_wrong_arg_count_and_unknown_object", "c2s", 6): "<action-value> is missing",
}


@dataclass(frozen=True)
class Record:
    """One line of a transcript: a message (``data``) or an EOF of one direction."""

    index: int
    conn: int
    dir: str  # "c2s" or "s2c"
    data: bytes | None  # exact bytes, terminator included when it was on the wire
    partial: bool = False

    @property
    def eof(self) -> bool:
        return self.data is None

    @property
    def doc(self) -> bytes:
        """The XML document: the data without its NUL terminator."""
        assert self.data is not None
        return self.data[:-1] if self.data.endswith(b"\0") else self.data

    @property
    def terminated(self) -> bool:
        return self.data is not None and self.data.endswith(b"\0")


@dataclass(frozen=True)
class Transcript:
    name: str
    meta: dict[str, object]
    records: list[Record]

    @property
    def java_client(self) -> bool:
        return self.name.startswith("java_")

    def conns(self) -> dict[int, list[Record]]:
        out: dict[int, list[Record]] = {}
        for rec in self.records:
            out.setdefault(rec.conn, []).append(rec)
        return out

    def messages(self, direction: str) -> list[Record]:
        return [r for r in self.records if r.dir == direction and r.data is not None]


@functools.cache
def load_transcript(recordings: Path, name: str) -> Transcript:
    path = recordings / "rddlsim" / "transcripts" / f"{name}.jsonl"
    meta: dict[str, object] = {}
    records: list[Record] = []
    with path.open(encoding="utf-8") as fh:
        for n, line in enumerate(fh):
            obj = json.loads(line)
            if n == 0:
                meta = obj["meta"]
                continue
            if obj.get("event") == "note":
                continue
            conn = int(obj.get("conn", 0))
            if "data" in obj:
                # "Everything is ASCII": latin-1 maps each code point to its byte.
                data = obj["data"].encode("latin-1")
                records.append(Record(obj["i"], conn, obj["dir"], data, bool(obj.get("partial"))))
            elif obj.get("event") == "eof":
                records.append(Record(obj["i"], conn, obj["dir"], None))
    return Transcript(name, meta, records)


@dataclass(frozen=True)
class ProstCapture:
    name: str
    messages: list[tuple[str, bytes]]  # (direction, exact bytes) in order
    c2s_raw: bytes
    s2c_raw: bytes


@functools.cache
def load_prost(recordings: Path, name: str) -> ProstCapture:
    base = recordings / "prost"
    with gzip.open(base / f"{name}.jsonl.gz", "rt", encoding="utf-8") as fh:
        messages = [(o["dir"], o["msg"].encode("latin-1")) for o in map(json.loads, fh)]
    with gzip.open(base / f"{name}.s2c.raw.gz", "rb") as fh:
        s2c = fh.read()
    return ProstCapture(name, messages, (base / f"{name}.c2s.raw").read_bytes(), s2c)


def strip_declaration(doc: bytes) -> tuple[bool, bytes]:
    """(had the exact rddlsim declaration, the rest)."""
    if doc.startswith(XML_DECLARATION):
        return True, doc[len(XML_DECLARATION) :]
    return False, doc
