"""Which instance an environment plays: `resolve_model`.

An environment is made from a `Model`, from files (a domain file and an
instance file, paired by file as rddlrepository and pyRDDLGym pair them; one
file holding both; a folder and an instance name, as rddl-server reads a
folder) or from an rddlrepository problem name and instance number
(`domain="SysAdmin_MDP_ippc2011", instance="10"`).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..rddl import load_model, load_pair
from ..rddl.model import Model

__all__ = ["resolve_model"]


def resolve_model(domain: str | os.PathLike[str] | Model, instance: str | int | None) -> Model:
    """The checked model of the instance that `domain` and `instance` name.

    * `domain` a `Model`: that model (`instance` must be None);
    * `domain` a folder: the instance of that name in the folder's files (or
      the only one there is, when `instance` is None);
    * `domain` a file: with `instance` a file, the pair; with `instance` None,
      the file's only instance; with `instance` a name, that instance of the file;
    * otherwise `domain` names an rddlrepository problem and `instance` its
      instance number.

    Raises `RDDLError` for files that do not check (with file, line and
    column), `FileNotFoundError` for a missing instance file, and
    `ValueError` for a name that is neither a file nor an rddlrepository problem.
    """
    if isinstance(domain, Model):
        if instance is not None:
            raise ValueError("give either a Model or a domain and an instance, not both")
        return domain
    path = Path(domain)
    if path.is_dir():
        return load_model(path, instance=None if instance is None else str(instance))
    if path.is_file():
        if instance is None:
            return load_model(path)
        ipath = Path(str(instance))
        if ipath.is_file():
            return load_pair(path, ipath)
        if ipath.suffix == ".rddl" or os.sep in str(instance):
            raise FileNotFoundError(f"no such instance file: {instance}")
        return load_model(path, instance=str(instance))
    if path.suffix == ".rddl" or os.sep in str(domain):
        raise FileNotFoundError(f"no such domain file or folder: {domain}")
    return _repository_model(str(domain), instance)


def _repository_model(name: str, instance: str | int | None) -> Model:
    try:
        from rddlrepository.core.manager import RDDLRepoManager
    except ImportError:
        raise ValueError(
            f"'{name}' is not a file or folder; as an rddlrepository problem name it needs "
            "the rddlrepository package (pip install rddlrepository)"
        ) from None
    manager = RDDLRepoManager()
    problems = manager.list_problems()
    if name not in problems:
        close = sorted(p for p in problems if p.lower().startswith(name.lower()[:6]))[:6]
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise ValueError(
            f"'{name}' is neither a file, a folder nor an rddlrepository problem{hint}"
        )
    info = manager.get_problem(name)
    available = [str(i) for i in info.list_instances()]
    if instance is None:
        raise ValueError(f"{name}: give the instance number (it has {', '.join(available)})")
    number = str(instance)
    if number not in available:
        raise ValueError(f"{name} has no instance {number} (it has {', '.join(available)})")
    return load_pair(info.get_domain(), info.get_instance(number))
