#!/usr/bin/env python3
"""A stand-in for PROST's `search` program, for testing the launcher.

Standard library only (no ippc imports): it runs as a real subprocess. It
takes PROST's command line and speaks the IPPC protocol exactly as PROST's
ipc_client.cc does, byte for byte (checked against the recorded PROST
sessions in tests/data/prost):

* session-request: XML declaration *without* a newline, `prost` as the
  client name, `<no-header/>`, a NUL;
* round-request and actions: declaration, newline, the element, a NUL;
  the round-request has its literal spaces; actions are one `<action>` per
  true action fluent with `<action-value>true</action-value>`, a noop is
  `<actions></actions>`;
* server messages are read as bare XML (no NUL) by tracking element depth.

Like PROST it writes the decoded task to `./parser_in_<pid>.rddl`, runs
`./rddl-parser-release` from its working directory through the shell, and
removes both temporary files. What it prints follows PROST's own lines
(taken from the recorded stdout), including `>>> END OF ROUND ...`,
`>>> END OF SESSION  -- TOTAL REWARD: ...` and `ERROR: ...` on stderr
followed by exit status 0, as PROST's SystemUtils::abort does.

Environment:
  FAKE_PROST_MODE          normal (default) | error | hang | crash
      error: after the session-init, print PROST's configuration error and
             exit 0 (as PROST does);
      hang:  connect, send the session request, start a child process, print
             `fake-prost: pid <pid> child <pid>` and never answer;
      crash: connect, send the session request, exit with status 3.
  FAKE_PROST_ACTIONS_FILE  one action per planning step, in PROST's
      `Submitted action:` form (`reboot(c5) `, `roll(d1) roll(d2) `,
      `noop()`; the prefix may be kept); noop once the file is used up.
  FAKE_PROST_ACTION        one action (same form) for every step.
  FAKE_PROST_IGNORE_TERM   1: the fake and its child ignore SIGTERM.
  FAKE_PROST_MAX_SECONDS   the fake (and its child) stop by themselves after
      this many seconds (default 60) whatever happens.
"""

from __future__ import annotations

import base64
import os
import re
import signal
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from typing import NoReturn

MAX_SECONDS = max(1, int(float(os.environ.get("FAKE_PROST_MAX_SECONDS", "60"))))
SEPARATOR = "-" * 44
SMALL_SEPARATOR = "-" * 22
PARSER_EXEC = "./rddl-parser-release "  # PROST's release build, trailing space included
DECLARATION = '<?xml version="1.0" encoding="UTF-8"?>'


def out(line: str = "") -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def abort(message: str) -> NoReturn:
    """PROST's SystemUtils::abort: the message on stderr, exit status 0."""
    sys.stderr.write("ERROR: " + message + "\n")
    sys.stderr.flush()
    sys.exit(0)


def segfault() -> NoReturn:
    """Where PROST dereferences the null node it gets at EOF: it dies of
    SIGSEGV (no core file)."""
    sys.stdout.flush()
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    except (ImportError, ValueError, OSError):
        pass
    signal.signal(signal.SIGSEGV, signal.SIG_DFL)
    os.kill(os.getpid(), signal.SIGSEGV)
    time.sleep(1)
    os._exit(139)


def usage() -> None:
    out("Usage: ./prost <rddl-parser-output | rddl-problem-name> [PROST <options>]")
    out("**************************************************************")
    out("                     PROST Planner Options")
    out("**************************************************************")


# ------------------------------------------------------------ the wire


class Connection:
    """Reads whole XML elements from a byte stream without terminators."""

    _TAG = re.compile(rb"<[^>]*>")

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.buf = b""

    def send(self, text: str) -> bool:
        try:
            self.sock.sendall(text.encode("utf-8"))
        except OSError:
            return False
        return True

    def _complete(self) -> bytes | None:
        depth = 0
        start = None
        for m in self._TAG.finditer(self.buf):
            tag = m.group()
            if tag.startswith((b"<?", b"<!")):
                continue
            if start is None:
                start = m.start()
            if tag.startswith(b"</"):
                depth -= 1
            elif not tag.endswith(b"/>"):
                depth += 1
            if depth <= 0:
                msg = self.buf[start : m.end()]
                self.buf = self.buf[m.end() :]
                return msg
        return None

    def read(self) -> ET.Element | None:
        """The next element, or None at EOF (as PROST's XMLNode::readNode)."""
        while True:
            msg = self._complete()
            if msg is not None:
                try:
                    return ET.fromstring(msg.decode("utf-8", errors="replace"))
                except ET.ParseError:
                    return None
            try:
                chunk = self.sock.recv(65536)
            except OSError:
                return None
            if not chunk:
                return None
            self.buf += chunk


def text_of(node: ET.Element, child: str) -> str | None:
    found = node.find(child)
    return None if found is None else (found.text or "")


def session_request(instance: str) -> str:
    return (
        DECLARATION
        + "<session-request>"
        + f"<problem-name>{instance}</problem-name>"
        + "<client-name>prost</client-name>"
        + "<input-language>rddl</input-language>"
        + "<no-header/>"
        + "</session-request>\0"
    )


ROUND_REQUEST = (
    DECLARATION + "\n<round-request> <execute-policy>yes</execute-policy> </round-request>\0"
)


def actions_message(names: list[str]) -> str:
    """ipc_client.cc's submitAction: `name(a, b)` -> name and trimmed args."""
    parts = [DECLARATION, "\n<actions>"]
    for full in names:
        cut = full.find("(")
        if cut < 0:
            parts.append(f"<action><action-name>{full}</action-name>")
        else:
            parts.append(f"<action><action-name>{full[:cut]}</action-name>")
            for param in full[cut + 1 : -1].split(","):
                parts.append(f"<action-arg>{param.strip()}</action-arg>")
        parts.append("<action-value>true</action-value></action>")
    parts.append("</actions>\0")
    return "".join(parts)


_ACTION_TOKEN = re.compile(r"[^\s()]+(?:\([^)]*\))?")


def parse_action_line(line: str) -> list[str]:
    """`Submitted action: roll(d1) roll(d2) ` -> ['roll(d1)', 'roll(d2)']."""
    line = line.strip()
    if line.startswith("Submitted action:"):
        line = line[len("Submitted action:") :]
    return [t for t in _ACTION_TOKEN.findall(line) if t != "noop()"]


def action_source() -> Callable[[], list[str]]:
    path = os.environ.get("FAKE_PROST_ACTIONS_FILE")
    fixed = os.environ.get("FAKE_PROST_ACTION")
    lines: list[str] = []
    if path:
        with open(path) as f:
            lines = [ln for ln in f.read().splitlines() if ln.strip()]

    def next_action() -> list[str]:
        if lines:
            return parse_action_line(lines.pop(0))
        if fixed:
            return parse_action_line(fixed)
        return []

    return next_action


def compact(names: list[str]) -> str:
    """ActionState::toCompactString."""
    return "noop()" if not names else "".join(n + " " for n in names)


def fmt(x: float) -> str:
    """C++ std::to_string(double)."""
    return f"{x:f}"


def atoi(text: str) -> int:
    m = re.match(r"\s*([+-]?\d+)", text)
    return int(m.group(1)) if m else 0


def atof(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return 0.0


# ------------------------------------------------------------- parser


def run_parser(task: str, parser_options: str) -> None:
    pid = os.getpid()
    task_file = f"./parser_in_{pid}.rddl"
    parser_out = f"parser_out_{pid}"
    with open(task_file, "w") as f:
        f.write(task + "\n")
    call = f"{PARSER_EXEC}{task_file} ./{parser_out} {parser_options}"
    sys.stdout.flush()
    result = subprocess.call(call, shell=True)
    if result != 0:
        abort("Error: " + PARSER_EXEC + " had an error")
    if not os.path.exists(parser_out):
        abort("Error: deleting temporary file failed")
    try:
        os.remove(task_file)
        os.remove(parser_out)
    except OSError:
        abort("Error: deleting temporary file failed")


# -------------------------------------------------------------- session


def main(argv: list[str]) -> int:
    signal.alarm(MAX_SECONDS)  # bounded whatever happens (SIGALRM ends the process)
    if os.environ.get("FAKE_PROST_IGNORE_TERM") == "1":
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    start = time.monotonic()
    if len(argv) < 3:
        usage()
        return 1
    instance = argv[1]
    host, port, parser_options = "localhost", 2323, ""
    planner_desc = ""
    all_read = False
    i = 2
    while i < len(argv):
        arg = argv[i]
        if not all_read and arg.startswith("["):
            all_read = True
        if all_read:
            planner_desc += arg + " "
        elif arg in ("-h", "--hostname"):
            i += 1
            host = argv[i]
        elif arg in ("-p", "--port"):
            i += 1
            port = atoi(argv[i]) & 0xFFFF
        elif arg == "--parser-options":
            i += 1
            parser_options = argv[i]
        else:
            sys.stderr.write(f"Unknown option: {arg}\n")
            usage()
            return 1
        i += 1

    mode = os.environ.get("FAKE_PROST_MODE", "normal")
    try:
        sock = socket.create_connection((socket.gethostbyname(host), port))
    except OSError:
        abort("Error: couldn't connect to server.")
    conn = Connection(sock)
    if not conn.send(session_request(instance)):
        abort("Error: writing to socket failed.")

    if mode == "crash":
        out("Parsing...")
        sys.exit(3)
    if mode == "hang":
        # The child inherits an ignored SIGTERM (dispositions survive exec).
        child = subprocess.Popen([sys.executable, "-c", f"import time; time.sleep({MAX_SECONDS})"])
        out(f"fake-prost: pid {os.getpid()} child {child.pid}")
        time.sleep(MAX_SECONDS)
        return 0

    init = conn.read()
    if init is None:
        abort("Error: initializing session failed.")
    task = text_of(init, "task")
    if task is None:
        abort("Error: server response does not contain task description.")
    task_text = base64.b64decode(task).decode("utf-8", errors="replace")
    run_parser(task_text, parser_options)
    rounds_text = text_of(init, "num-rounds")
    if rounds_text is None:
        abort("Error: server response insufficient.")
    num_rounds = atoi(rounds_text)
    if text_of(init, "time-allowed") is None:
        abort("Error: server response insufficient.")
    if mode == "error" or "-se" not in planner_desc.split():
        abort(
            "Error: search engine specification is insufficient. Rerun PROST "
            "without parameters to see detailed instructions."
        )
    m = re.search(r"horizon\s*=\s*(\d+)", task_text)
    horizon = int(m.group(1)) if m else 0
    out(f"THTS heuristic IDS: Setting max search depth to: {horizon}")

    next_action = action_source()
    state: list[str] = []

    def read_state(node: ET.Element) -> float:
        nonlocal state
        if text_of(node, "time-left") is None or text_of(node, "immediate-reward") is None:
            abort("Error: turn response message insufficient.")
        values = [text_of(f, "fluent-value") or "" for f in node.findall("observed-fluent")]
        if values:  # a POMDP's <no-observed-fluents/> leaves the state as it was
            state = ["1" if v == "true" else "0" if v == "false" else v for v in values]
        return atof(text_of(node, "immediate-reward") or "0")

    def finish_step(names: list[str], reward: float) -> None:
        out("Used RAM: 440964")
        out()
        out("THTS step statistics:")
        out("  Performed trials: 124281")
        out("  Search time: 1.000001")
        out("Submitted action: " + compact(names))
        out("Immediate reward: " + fmt(reward))

    for current in range(num_rounds):
        if not conn.send(ROUND_REQUEST):
            abort("Error: writing to socket failed.")
        node = conn.read()
        if node is None or node.tag != "round-init":
            abort("Error: round-request response insufficient.")
        time_left = text_of(node, "time-left")
        if time_left is None:
            abort("Error: round-request response insufficient.")
        remaining = atoi(time_left)
        out(SEPARATOR)
        out(f">>> STARTING ROUND {current + 1} -- REMAINING TIME {int(remaining / 1000)}s")
        node = conn.read()
        if node is None:
            segfault()
        read_state(node)
        step = 0
        while True:
            step += 1
            out(SEPARATOR)
            out(f"Planning step {step}/{horizon} in round {current + 1}/{num_rounds}")
            out("Current state: " + "".join(v + " " for v in state))
            names = next_action()
            if not conn.send(actions_message(names)):
                break  # PROST: submitAction returns false, the round loop goes on
            node = conn.read()
            if node is None:
                segfault()
            if node.tag == "round-end":
                reward_text = text_of(node, "immediate-reward")
                if reward_text is None:
                    abort("Error: round end message insufficient.")
                round_text = text_of(node, "round-reward")
                if round_text is None:
                    abort("Error: server communication failed.")
                finish_step(names, atof(reward_text or "0"))
                out()
                out(SEPARATOR)
                out(
                    f">>> END OF ROUND {current + 1} -- REWARD RECEIVED: {fmt(atof(round_text or '0'))}"
                )
                out(SMALL_SEPARATOR)
                out("THTS round statistics:")
                out("  Number of reward lock states: 0")
                out()
                break
            finish_step(names, read_state(node))

    node = conn.read()
    if node is None:
        segfault()
    if node.tag != "session-end":
        abort("Error: session end message insufficient.")
    total_text = text_of(node, "total-reward")
    if total_text is None:
        abort("Error: session end message insufficient.")
    total = atof(total_text or "0")
    out()
    out(SEPARATOR)
    out(">>> END OF SESSION  -- TOTAL REWARD: " + fmt(total))
    out(">>> END OF SESSION  -- AVERAGE REWARD: " + fmt(total / num_rounds if num_rounds else 0.0))
    sock.close()
    out("PROST complete running time: " + fmt(time.monotonic() - start))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
