"""ippc.rddl: the RDDL language.

Parse, check and write RDDL files::

    from ippc.rddl import load
    models = load("domains/print_jobs")      # files or folders
    model = models["print_jobs_inst_1"]

`parse`/`parse_file` give the typed AST (`ippc.rddl.ast`); `load` pairs
instances with their domain and non-fluents and checks them into `Model`s;
`write` turns an AST back into canonical RDDL text. Every problem in the
input raises an `RDDLError` whose diagnostics name file, line and column.
"""

from __future__ import annotations

from .errors import Diagnostic, RDDLError, RDDLSemanticError, RDDLSyntaxError
from .loader import CheckResult, check_files, check_pair, load, load_model, load_pair, rddl_files
from .model import Model, PVariable, TypeInfo
from .parser import parse, parse_expr, parse_file

__all__ = [
    "CheckResult",
    "Model",
    "PVariable",
    "TypeInfo",
    "check_files",
    "check_pair",
    "load_pair",
    "load",
    "load_model",
    "rddl_files",
    "Diagnostic",
    "RDDLError",
    "RDDLSemanticError",
    "RDDLSyntaxError",
    "parse",
    "parse_expr",
    "parse_file",
]
