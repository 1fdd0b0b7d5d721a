"""numba's compile decorator for boresight's cached kernels, with the cache outside the package.

numba caches a kernel beside its source, in ``__pycache__``, whenever that folder is writable. In
an installed package that writes into site-packages files that ``pip uninstall`` does not know
of: after a reinstall the leftover folders form a namespace package that shadows the real one.
And a read-only install run by a user with no writable home fails at import ("no locator
available"). :func:`njit` is ``numba.njit(cache=True)`` with the cache in :func:`cache_dir`,
chosen once per process, first that is writable:

1. ``NUMBA_CACHE_DIR``, when set (numba's own setting);
2. a per-user folder, ``$XDG_CACHE_HOME/boresight`` or ``~/.cache/boresight``, one subfolder per
   numba and Python version;
3. the same subfolder under the temporary directory, in a folder of this user's own;
4. none: kernels compile in every process, and one warning says so.

The choice is written to numba's configuration and to ``NUMBA_CACHE_DIR`` of this process's
environment, so helper processes (:mod:`boresight._util.precompile`) share the folder. numba keys each
file inside it by the source file's full path and time stamp, so two installs never read each
other's kernels.
"""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import warnings
from pathlib import Path

import numba

__all__ = ["cache_dir", "njit"]


def _version_key() -> str:
    return f"numba-{numba.__version__}-py{sys.version_info.major}.{sys.version_info.minor}"


def _user_cache() -> Path | None:
    base = os.environ.get("XDG_CACHE_HOME")
    if not base:
        try:
            base = str(Path.home() / ".cache")
        except (RuntimeError, KeyError):  # no HOME and no password entry
            return None
    return Path(base) / "boresight" / _version_key()


def _temporary_cache() -> Path:
    owner = os.getuid() if hasattr(os, "getuid") else os.getpid()
    return Path(tempfile.gettempdir()) / f"boresight-{owner}" / _version_key()


def _writable(path: Path, *, owned: bool = False) -> bool:
    """Whether numba can write kernels into ``path`` (made if missing); with ``owned``, only a
    folder of this user's (a shared temporary directory is writable by others)."""
    try:
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
        if owned and hasattr(os, "getuid") and path.parent.stat().st_uid != os.getuid():
            return False
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


@functools.cache
def cache_dir() -> Path | None:
    """The folder numba caches boresight's kernels in, or None when no folder is writable."""
    given = os.environ.get("NUMBA_CACHE_DIR")
    candidates = [(Path(given), False)] if given else []
    user = _user_cache()
    candidates += [(user, False)] if user is not None else []
    candidates.append((_temporary_cache(), True))
    for path, owned in candidates:
        if _writable(path, owned=owned):
            os.environ["NUMBA_CACHE_DIR"] = str(path)
            numba.config.CACHE_DIR = str(path)
            return path
    warnings.warn(
        "boresight: no writable folder for numba's cache (tried "
        + ", ".join(str(p) for p, _ in candidates)
        + "); kernels compile anew in every process. Set NUMBA_CACHE_DIR to a writable folder.",
        RuntimeWarning,
        stacklevel=2,
    )
    return None


def njit(*args, **options):
    """``numba.njit`` with ``cache=True`` in :func:`cache_dir`, or uncached when there is none."""
    return numba.njit(*args, cache=cache_dir() is not None, **options)
