"""ippc.rddl.check: semantic checks, AST -> `Model`, or every problem found.

Theory of operation. A domain is checked once, without objects: types,
pvariable declarations, cpfs and every expression are resolved and typed.
What cannot be decided without objects (a bare name that is not a pvariable
must be an object; a `$name` literal) is recorded as a deferred object
reference with the type the context expects. Each instance then supplies
its objects (inline or through its non-fluents block), which settles the
deferred references, and its values are checked against the declarations.

Types in expressions are strings: "bool", "int", "real", an enum or object
type name, or None where the type is unknown (after an error, or for the
vector forms), which suppresses follow-on errors. Numbers and bools mix
freely in arithmetic and logic as in rddlsim (true is 1); comparing a bool
with a real, mixing enum or object values with numbers, or values of two
unrelated enum or object types are errors.

The package, one job per module:

    base         what the parts share: `DomainCheck`, `DeferredObject`, the
                 diagnostics `_Reporter`, literal values, subtypes
    domain       `check_domain`: types, pvariables, cpfs, then every expression
    expressions  `_ExprChecker`: the type of every expression
    instance     `build_model`: an instance's objects and values -> `Model`

`ippc.rddl.checker` re-exports these names (the loader imports them from there).
"""

from __future__ import annotations

from .base import DeferredObject, DomainCheck
from .domain import check_domain
from .instance import build_model

__all__ = ["DeferredObject", "DomainCheck", "build_model", "check_domain"]
