"""rddlsim's log file and the JSON-lines transcripts."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from ippc.server.records import (
    XML_DECLARATION,
    RddlsimLog,
    TranscriptWriter,
    data_bytes,
    read_transcript,
)

DECL = '<?xml version="1.0" encoding="UTF-8"?>'

# The log rddlsim's own Server.java (commit 97684e1, bound to loopback, log folder given)
# wrote for one session: client "alpha", 2 rounds of sysadmin_inst_mdp__1 (horizon 5).
RDDLSIM_LOG = (
    DECL + "\n"
    "<client-info><client-hostname>localhost</client-hostname>"
    "<client-ip>127.0.0.1</client-ip></client-info>\n" + DECL + "\n"
    "<round-end><instance-name>sysadmin_inst_mdp__1</instance-name><client-name>alpha"
    "</client-name><round-num>0</round-num><round-reward>43.25</round-reward><turns-used>5"
    "</turns-used><time-left>1079768</time-left><immediate-reward>8.25</immediate-reward>"
    "</round-end>\n" + DECL + "\n"
    "<round-end><instance-name>sysadmin_inst_mdp__1</instance-name><client-name>alpha"
    "</client-name><round-num>1</round-num><round-reward>43.25</round-reward><turns-used>5"
    "</turns-used><time-left>1079656</time-left><immediate-reward>8.25</immediate-reward>"
    "</round-end>\n" + DECL + "\n"
    "<session-end><instance-name>sysadmin_inst_mdp__1</instance-name><total-reward>86.5"
    "</total-reward><rounds-used>2</rounds-used><client-name>alpha</client-name><session-id>1"
    "</session-id><time-left>1079653</time-left></session-end>\n"
).encode()


def rddlsim_docs() -> list[bytes]:
    """The three documents of RDDLSIM_LOG after client-info, as the server sent them."""
    lines = RDDLSIM_LOG.split(b"\n")
    return [lines[k] + b"\n" + lines[k + 1] for k in (2, 4, 6)]


def log_reader(log: bytes) -> dict[str, dict[str, list[float]]]:
    """What rddlsim's rddl.evaluate.LogReader makes of a log: it drops the first line and
    every line that starts with the declaration, wraps the rest in <root> and collects
    the round-reward of every round-end by client and instance."""
    lines = log.decode().split("\n")
    if lines and lines[-1] == "":
        lines.pop()  # readLine() yields no empty line after the last newline
    kept = [ln for ln in lines[1:] if not ln.startswith(DECL)]
    root = ET.fromstring("<root>\n" + "\n".join(kept) + "\n</root>")
    out: dict[str, dict[str, list[float]]] = {}
    for node in root:
        if node.tag == "round-end":
            client = node.findtext("client-name")
            instance = node.findtext("instance-name")
            assert client is not None and instance is not None
            out.setdefault(client, {}).setdefault(instance, []).append(
                float(node.findtext("round-reward") or "nan")
            )
    return out


def test_default_path_as_rddlsim() -> None:
    assert RddlsimLog.default_path(None, 2323) == Path("rddl-2323.log")
    assert RddlsimLog.default_path(Path("/var/log/ippc"), 4001) == Path(
        "/var/log/ippc/logs-4001.log"
    )


def test_log_is_byte_identical_to_rddlsims(tmp_path: Path) -> None:
    path = RddlsimLog.default_path(tmp_path / "logs", 2323)
    with RddlsimLog(path) as log:
        log.client_info("localhost", "127.0.0.1")
        for doc in rddlsim_docs():
            log.message(doc)
    assert path.read_bytes() == RDDLSIM_LOG
    assert log_reader(path.read_bytes()) == {"alpha": {"sysadmin_inst_mdp__1": [43.25, 43.25]}}


@pytest.mark.parametrize("form", ["wire", "nul", "no-header", "glued", "crlf"])
def test_every_form_of_a_document_is_logged_as_rddlsim_does(tmp_path: Path, form: str) -> None:
    doc = rddlsim_docs()[0]
    body = doc.split(b"\n", 1)[1]
    given = {
        "wire": doc,
        "nul": doc + b"\0",
        "no-header": body,  # what a no-header session puts on the wire
        "glued": XML_DECLARATION + body,  # declaration without its newline, as PROST writes
        "crlf": XML_DECLARATION + b"\r\n" + body,
    }[form]
    path = tmp_path / "x.log"
    with RddlsimLog(path) as log:
        log.message(given)
    assert path.read_bytes() == doc + b"\n"


def test_log_appends_and_escapes(tmp_path: Path) -> None:
    path = tmp_path / "rddl-2323.log"
    with RddlsimLog(path) as log:
        log.client_info("localhost", "127.0.0.1")
    with RddlsimLog(path) as log:  # a restarted server appends, as rddlsim does
        log.client_info("a<b&c>", "::1")
    assert path.read_bytes() == (
        (
            DECL + "\n<client-info><client-hostname>localhost</client-hostname>"
            "<client-ip>127.0.0.1</client-ip></client-info>\n"
            + DECL
            + "\n<client-info><client-hostname>a&lt;b&amp;c&gt;</client-hostname>"
            "<client-ip>::1</client-ip></client-info>\n"
        ).encode()
    )
    assert log_reader(path.read_bytes()) == {}


def test_log_reaches_the_file_on_every_call(tmp_path: Path) -> None:
    path = tmp_path / "x.log"
    log = RddlsimLog(path)
    log.client_info("localhost", "127.0.0.1")
    assert path.read_bytes().count(b"\n") == 2
    log.message(rddlsim_docs()[0])
    assert path.read_bytes().count(b"\n") == 4  # read while still open: nothing buffered
    log.close()
    log.close()
    with pytest.raises(ValueError, match="closed"):
        log.message(rddlsim_docs()[0])


def test_interleaved_sessions_stay_readable(tmp_path: Path) -> None:
    path = tmp_path / "x.log"
    docs = rddlsim_docs()
    other = [d.replace(b"alpha", b"beta").replace(b"43.25", b"7.5") for d in docs]
    with RddlsimLog(path) as log:
        log.client_info("localhost", "127.0.0.1")
        log.client_info("localhost", "127.0.0.1")
        for a, b in zip(docs, other, strict=True):
            log.message(a)
            log.message(b)
    assert log_reader(path.read_bytes()) == {
        "alpha": {"sysadmin_inst_mdp__1": [43.25, 43.25]},
        "beta": {"sysadmin_inst_mdp__1": [7.5, 7.5]},
    }


def test_canonical_hostname_of_loopback() -> None:
    assert RddlsimLog.canonical_hostname("not an address") == "not an address"
    name = RddlsimLog.canonical_hostname("127.0.0.1")
    assert name == "127.0.0.1" or "localhost" in name


# ---------------------------------------------------------------- transcripts


def shared_transcripts(recordings: Path) -> list[Path]:
    paths = sorted((recordings / "rddlsim" / "transcripts").glob("*.jsonl"))
    assert len(paths) >= 30
    return paths


def rewrite(records: list[dict], writer: TranscriptWriter) -> None:
    for r in records:
        if "data" in r:
            writer.message(
                r["dir"], data_bytes(r), r.get("conn"), r["t"], partial=r.get("partial", False)
            )
        elif r.get("event") == "eof":
            writer.eof(r["dir"], r.get("conn"), r["t"])
        elif r.get("event") == "note":
            writer.note(r["text"], r.get("t"))
        else:
            raise AssertionError(f"unknown record {r}")


def test_read_every_shared_transcript_and_write_it_back(recordings: Path, tmp_path: Path) -> None:
    renumbered = []
    for path in shared_transcripts(recordings):
        meta, records = read_transcript(path)
        assert meta["server_args"][0] == "<dir>"
        assert records, path.name
        out = tmp_path / path.name
        with TranscriptWriter(out, meta) as writer:
            rewrite(records, writer)
        theirs = path.read_bytes().splitlines()
        ours = out.read_bytes().splitlines()
        assert len(ours) == len(theirs)
        if ours == theirs:
            continue
        # only a trimmed recording skips numbers; everything else must be byte-identical
        renumbered.append(path.name)
        assert ours[0] == theirs[0]
        for a, b in zip(ours[1:], theirs[1:], strict=True):
            da, db = json.loads(a), json.loads(b)
            da.pop("i")
            db.pop("i")
            assert da == db
    assert renumbered == ["java_client_early_round_end_deadlock.jsonl"]


def test_shared_transcript_bytes_survive(recordings: Path) -> None:
    meta, records = read_transcript(
        recordings / "rddlsim" / "transcripts" / "java_sysadmin_mdp.jsonl"
    )
    assert meta["scenario"] == "java_sysadmin_mdp"
    first = records[0]
    assert (first["i"], first["dir"]) == (0, "c2s")
    assert data_bytes(first) == (
        XML_DECLARATION + b"\n<session-request><problem-name>sysadmin_inst_mdp__1"
        b"</problem-name><client-name>javaclient</client-name></session-request>\0"
    )
    assert all(data_bytes(r).endswith(b"\0") for r in records if "data" in r)


def test_writer_format(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    w = TranscriptWriter(path, {"scenario": "ours", "server_args": ["<dir>"]})
    w.message("c2s", b"<a/>\0", 0, 0.0)
    assert path.read_bytes().count(b"\n") == 2  # on disk before close
    w.message("s2c", b"<round-end>\xff\x01</round-end>", 0, 1.234567)
    w.message("c2s", b"<actions><act", 0, 2.5, partial=True)
    w.eof("c2s", 0, 2.50001)
    w.note("second connection", 3.0)
    w.note("no time")
    w.message("c2s", b"x", None, 4.0)
    w.close()
    w.close()
    assert path.read_text("ascii").splitlines() == [
        '{"meta": {"scenario": "ours", "server_args": ["<dir>"]}}',
        '{"i": 0, "t": 0.0, "conn": 0, "dir": "c2s", "data": "<a/>\\u0000"}',
        '{"i": 1, "t": 1.2346, "conn": 0, "dir": "s2c", "data": "<round-end>\\u00ff\\u0001'
        '</round-end>"}',
        '{"i": 2, "t": 2.5, "conn": 0, "dir": "c2s", "data": "<actions><act", "partial": true}',
        '{"i": 3, "t": 2.5, "conn": 0, "dir": "c2s", "event": "eof"}',
        '{"i": 4, "t": 3.0, "event": "note", "text": "second connection"}',
        '{"i": 5, "event": "note", "text": "no time"}',
        '{"i": 6, "t": 4.0, "dir": "c2s", "data": "x"}',
    ]
    meta, records = read_transcript(path)
    assert meta == {"scenario": "ours", "server_args": ["<dir>"]}
    assert data_bytes(records[1]) == b"<round-end>\xff\x01</round-end>"
    assert records[2]["partial"] is True
    with pytest.raises(ValueError, match="closed"):
        w.note("late")


def test_writer_refuses_bad_direction_and_existing_file(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    with TranscriptWriter(path, {}) as w, pytest.raises(ValueError, match="direction"):
        w.message("up", b"", 0, 0.0)
    with pytest.raises(FileExistsError):
        TranscriptWriter(path, {})
    assert TranscriptWriter.unique_path(tmp_path, "t") == tmp_path / "t-2.jsonl"
    assert TranscriptWriter.unique_path(tmp_path, "u") == tmp_path / "u.jsonl"
    assert path.read_bytes() == b'{"meta": {}}\n'


def test_reader_skips_a_torn_last_line_only(tmp_path: Path) -> None:
    path = tmp_path / "t.jsonl"
    path.write_bytes(
        b'{"meta": {"a": 1}}\n{"i": 0, "t": 0.0, "dir": "c2s", "data": "x"}\n{"i": 1, "t": 0.1, "di'
    )
    meta, records = read_transcript(path)
    assert meta == {"a": 1} and [r["i"] for r in records] == [0]
    path.write_bytes(b'{"meta": {}}\n{"i": 0, "t"\n{"i": 1}\n')
    with pytest.raises(ValueError, match="t.jsonl:2"):
        read_transcript(path)
    path.write_bytes(b'{"i": 0}\n')
    with pytest.raises(ValueError, match="meta"):
        read_transcript(path)
    path.write_bytes(b"")
    with pytest.raises(ValueError, match="empty"):
        read_transcript(path)
