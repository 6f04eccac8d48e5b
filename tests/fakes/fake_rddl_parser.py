#!/usr/bin/env python3
"""A stand-in for PROST's `rddl-parser` (standard library only).

Called by the fake search program (and by PROST) as
`./rddl-parser-release <task file> <output file> [options]`: it prints the
parser's progress lines as PROST's parser does and writes an output file
(a small summary here, not PROST's real task format).
"""

from __future__ import annotations

import re
import sys


def main(argv: list[str]) -> int:
    if len(argv) < 3:
        print("Usage: rddl-parser <rddlDesc> <outputFileName> [options]")
        return 1
    try:
        with open(argv[1]) as f:
            task = f.read()
    except OSError as err:
        print(f"ERROR: cannot read {argv[1]}: {err}", file=sys.stderr)
        return 1
    m = re.search(r"\binstance\s+([A-Za-z0-9_\-]+)", task)
    instance = m.group(1) if m else "unknown"
    h = re.search(r"horizon\s*=\s*(\d+)", task)
    # Real lines from PROST's parser output (recorded against rddlsim).
    for line in (
        "Parsing...",
        "...finished (0.000226974s).",
        "Instantiating...",
        "...finished (0.000230074s).",
        "Simplifying...",
        "...finished (0.096123s).",
        "Determinizing...",
        "...finished (4.98295e-05s).",
        "Generating hash keys...",
        "...finished (2.98023e-05s).",
        "Precomputing evaluatables...",
        "...finished (0.00674796s).",
        "Analyzing task...",
        "...finished (0.146416s).",
        f"Writing output for instance {instance} to {argv[2]} ...",
        "...finished (0.02405s).",
        "PROST parser complete running time: 0.0240569s",
    ):
        print(line)
    with open(argv[2], "w") as f:
        f.write(f"instance {instance}\nhorizon {h.group(1) if h else 0}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
