"""Building C text into a shared library, kept in a private cache.

`build(source)` compiles one C unit with the system's C compiler (`$CC`,
else `cc`, `gcc` or `clang`) and returns the path of the shared library,
named by a hash of the compiler and the text, so that a second session on
an instance loads the library the first one built.

The cache is a folder only its user can write: `$IPPC_CACHE/cstep`
(default `~/.cache/ippc/cstep`), created mode 0700. Before every build or
load the folder is checked: a real directory (not a symbolic link), owned
by the user, writable by nobody else, in a parent that nobody else can
replace it in (owned by the user or root, and not writable by others
unless sticky, as /tmp). A library is loaded only when it too is a regular
file owned by the user and writable by nobody else. A folder that fails
the check is refused, with one warning naming it and why, and the process
builds in a fresh private folder of its own instead (`tempfile.mkdtemp`,
mode 0700, removed at exit): code that another local user placed where
the cache would be is never loaded.

One process builds one text once at a time: a second build of the same
text (a session started while an earlier session's build, still running in
the background, compiles it) waits for the first and loads its library.

Compiler warnings are on (`-Wall -Wextra`); the C files of the package
compile without one (tests/rddl/test_cstep.py builds them with `-Werror`),
and any warning a build prints is logged at debug level.

Imports nothing of the package.
"""

from __future__ import annotations

import atexit
import hashlib
import logging
import os
import shutil
import stat
import subprocess
import tempfile
import threading
from pathlib import Path

__all__ = ["WARNINGS", "CUnavailable", "build", "cache_dir", "find_compiler", "private"]

log = logging.getLogger(__name__)

WARNINGS = ("-Wall", "-Wextra")
"""The warning flags of every build (CI adds `-Werror`)."""


class CUnavailable(Exception):
    """No compiled code: no compiler, a failed build, or (for a step) a
    construct the translator does not write."""


def find_compiler() -> str | None:
    """The C compiler to use: `$CC`, else the first of cc, gcc, clang."""
    env = os.environ.get("CC")
    if env:
        return shutil.which(env.split()[0]) and env  # type: ignore[return-value]
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return name
    return None


def _uid() -> int:
    """This process's user (a function, so that a test can pretend)."""
    return os.getuid()


class _Refused(Exception):
    """A cache folder or library that is not the user's alone."""


def private(path: Path, *, folder: bool = True) -> None:
    """Raise `_Refused` unless `path` is a directory (`folder`) or regular
    file, not a symbolic link, owned by this user and writable by nobody
    else."""
    try:
        st = os.lstat(path)
    except OSError as err:
        raise _Refused(f"{path}: {err.strerror}") from None
    kind = stat.S_ISDIR(st.st_mode) if folder else stat.S_ISREG(st.st_mode)
    if not kind:
        what = "a directory" if folder else "a regular file"
        raise _Refused(f"{path} is not {what}")
    if st.st_uid != _uid():
        raise _Refused(f"{path} is owned by uid {st.st_uid}, not this user ({_uid()})")
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise _Refused(f"{path} is writable by others (mode {stat.S_IMODE(st.st_mode):o})")


def _safe_parent(path: Path) -> None:
    """Raise `_Refused` when another user could replace `path` in its parent."""
    parent = path.parent
    try:
        st = os.stat(parent)
    except OSError as err:
        raise _Refused(f"{parent}: {err.strerror}") from None
    if st.st_uid not in (_uid(), 0):
        raise _Refused(f"{parent} is owned by uid {st.st_uid}")
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH) and not st.st_mode & stat.S_ISVTX:
        raise _Refused(f"{parent} is writable by others (mode {stat.S_IMODE(st.st_mode):o})")


_TEMP: Path | None = None
_TEMP_GUARD = threading.Lock()
_REFUSED: set[str] = set()  # folders already warned about
_BUILDING: dict[str, threading.Lock] = {}  # one lock per library, built or loaded under it
_BUILDING_GUARD = threading.Lock()


def _temporary() -> Path:
    """This process's private build folder (mode 0700, removed at exit)."""
    global _TEMP
    with _TEMP_GUARD:
        if _TEMP is not None:
            try:
                private(_TEMP)
                return _TEMP
            except _Refused:
                pass
        _TEMP = Path(tempfile.mkdtemp(prefix="ippc-cstep-"))
        atexit.register(shutil.rmtree, str(_TEMP), True)
        return _TEMP


def cache_dir() -> Path:
    """The folder to build and load in, checked now (see the module
    docstring): the user's cache, else a fresh private temporary folder."""
    root = os.environ.get("IPPC_CACHE")
    base = Path(root) if root else Path.home() / ".cache" / "ippc"
    folder = base / "cstep"
    try:
        try:
            if not folder.is_dir():
                base.mkdir(mode=0o700, parents=True, exist_ok=True)
                folder.mkdir(mode=0o700)
        except FileExistsError:
            pass  # (made by another process meanwhile, or not a folder: checked below)
        except OSError as err:
            raise _Refused(f"cannot create {folder}: {err.strerror}") from None
        private(folder)
        _safe_parent(folder)
        if not os.access(folder, os.W_OK | os.X_OK):
            raise _Refused(f"{folder} is not writable")
        return folder
    except _Refused as why:
        if str(folder) not in _REFUSED:
            _REFUSED.add(str(folder))
            log.warning(
                "compiled step: cache folder refused (%s); building in a private "
                "temporary folder instead",
                why,
            )
        return _temporary()


def build(source: str) -> Path:
    """The shared library of the C unit `source`: the cached one, else
    built now (raises `CUnavailable`)."""
    cc = find_compiler()
    if cc is None:
        raise CUnavailable("no C compiler (set CC, or install cc, gcc or clang)")
    digest = hashlib.sha256((cc + "\0" + source).encode()).hexdigest()[:24]
    with _BUILDING_GUARD:
        lock = _BUILDING.setdefault(digest, threading.Lock())
    with lock:
        return _build(cc, digest, source)


def _build(cc: str, digest: str, source: str) -> Path:
    """`build` with this library's lock held."""
    folder = cache_dir()
    lib = folder / f"step-{digest}.so"
    if lib.exists() or lib.is_symlink():
        try:
            private(lib, folder=False)
            return lib
        except _Refused as why:
            log.warning("compiled step: not loading %s (%s); building it again", lib, why)
            lib.unlink(missing_ok=True)
    src = folder / f"step-{digest}.{os.getpid()}.c"
    tmp = folder / f"step-{digest}.{os.getpid()}.so"
    src.write_text(source)
    # -O1: the step's expressions are long and flat; -O2 compiles several times
    # slower for a few percent
    cmd = [*cc.split(), "-O1", "-fPIC", "-shared", "-fno-math-errno", *WARNINGS]
    cmd += ["-o", str(tmp), str(src), "-lm"]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    except (OSError, subprocess.TimeoutExpired) as err:
        raise CUnavailable(f"{cc} failed: {err}") from None
    finally:
        src.unlink(missing_ok=True)
    if done.returncode != 0:
        tmp.unlink(missing_ok=True)
        raise CUnavailable(f"{cc} failed: {done.stderr.strip()[:400]}")
    if done.stderr.strip():
        log.debug("compiled step: %s said: %s", cc, done.stderr.strip()[:2000])
    os.chmod(tmp, 0o700)
    os.replace(tmp, lib)  # atomic: another process may build the same
    return lib
