"""rddlsim's server log files, read as rddlsim's own ``rddl.evaluate.LogReader`` reads them.

A log (``rddlsim``'s ``logs-PORT.log``, or ``rddl-server --log-dir``'s, which writes the
same format: `ippc.server.records.RddlsimLog`) is a sequence of XML documents, each
written as the declaration line and the root element on the next line. LogReader drops
the first line, drops every line that starts with the declaration, wraps the rest in a
``<root>`` element and reads the ``round-end`` children: ``client-name``,
``instance-name``, ``round-reward`` and, in IPPC 2014's logs, ``time-used`` (ms). A
round-end without a client name is skipped, as LogReader skips it.
"""

from __future__ import annotations

import logging
from pathlib import Path

from lxml import etree

from .instances import domain_of
from .results import RoundRecord

__all__ = ["RddlsimLogError", "read_rddlsim_log"]

log = logging.getLogger(__name__)

_DECLARATION = '<?xml version="1.0" encoding="UTF-8"?>'


class RddlsimLogError(ValueError):
    """A log file that is not rddlsim's format; the message names the file and line."""


def read_rddlsim_log(path: str | Path) -> list[RoundRecord]:
    """Every round-end of the log, in the order written, as `RoundRecord` (the client
    name is the planner; each client's rounds on an instance form one sequence, as
    LogReader's lists do)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as err:
        raise RddlsimLogError(f"{path}: cannot read: {err}") from None
    kept: list[tuple[int, str]] = [
        (n, line) for n, line in enumerate(lines[1:], 2) if not line.startswith(_DECLARATION)
    ]
    text = "<root>\n" + "\n".join(line for _, line in kept) + "\n</root>"
    try:
        root = etree.fromstring(
            text.encode("utf-8"), etree.XMLParser(resolve_entities=False, no_network=True)
        )
    except etree.XMLSyntaxError as err:
        # the wrapped text has one extra line at the top; map back to the file's line
        index = (err.lineno or 2) - 2
        file_line = kept[index][0] if 0 <= index < len(kept) else (err.lineno or 1)
        raise RddlsimLogError(f"{path}:{file_line}: not an rddlsim log: {err.msg}") from None
    out: list[RoundRecord] = []
    for node in root:
        if node.tag != "round-end":
            continue
        fields = {child.tag: (child.text or "").strip() for child in node}
        client = fields.get("client-name")
        instance = fields.get("instance-name", "")
        if not client:
            log.warning("%s:%s: round-end without a client name; skipped", path, node.sourceline)
            continue
        try:
            reward = float(fields["round-reward"])
            used = float(fields["time-used"]) if fields.get("time-used") else None
        except (KeyError, ValueError):
            raise RddlsimLogError(
                f"{path}:{_file_line(kept, node.sourceline)}: round-end without a numeric round-reward"
            ) from None
        out.append(RoundRecord(client, instance, domain_of(instance), reward, True, used))
    return out


def _file_line(kept: list[tuple[int, str]], wrapped_line: int | None) -> int:
    index = (wrapped_line or 2) - 2
    return kept[index][0] if 0 <= index < len(kept) else (wrapped_line or 1)
