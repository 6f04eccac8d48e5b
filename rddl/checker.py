"""The checker's import path: `from ippc.rddl.checker import check_domain`.

The checker is the package `ippc.rddl.check` (its docstring is the theory
of operation); this module re-exports the names the loader uses.
"""

from __future__ import annotations

from .check import DeferredObject, DomainCheck, build_model, check_domain

__all__ = ["DeferredObject", "DomainCheck", "build_model", "check_domain"]
