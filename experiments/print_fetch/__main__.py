"""Run as `python -m ippc.experiments.print_fetch`."""

from __future__ import annotations

from .cli import main

main()
