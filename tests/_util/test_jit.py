"""numba's cache outside the package: NUMBA_CACHE_DIR, else a per-user folder, else a temporary
one, else none with one warning; an import never fails for want of a cache, and a run leaves no
file in the package's folders. Each case runs in a fresh process, since the folder is chosen once
per process."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import boresight

PACKAGE = Path(boresight.__file__).resolve().parent

# import a kernel module, run a cached kernel, report where the cache went and what warned
PROBE = r"""
import json, os, tempfile, warnings
tempfile.tempdir = os.environ.get("PROBE_TEMPDIR")  # gettempdir() would fall back to /tmp
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    import numpy as np
    from boresight._util import jit
    from boresight.kernels import rng
    rng.uniform_array(np.uint64(1), np.arange(3), np.zeros(3, dtype=np.int64), 0)
folder = jit.cache_dir()
print(json.dumps({
    "folder": None if folder is None else str(folder),
    "cached": rng.uniform_array._cache.cache_path if folder is not None else None,
    "warnings": [str(w.message) for w in caught if "numba's cache" in str(w.message)],
}))
"""


def _probe(tmp_path, **env):
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    base.update(env)
    proc = subprocess.run(
        [sys.executable, "-c", PROBE], env=base, cwd=tmp_path, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def _package_cache_files():
    return sorted(str(p) for p in PACKAGE.rglob("*.nb[ic]"))


def test_numba_cache_dir_is_used_when_set(tmp_path):
    out = _probe(tmp_path, NUMBA_CACHE_DIR=str(tmp_path / "given"))
    assert out["folder"] == str(tmp_path / "given")
    assert out["cached"].startswith(str(tmp_path / "given"))
    assert list((tmp_path / "given").rglob("*.nbi")), "nothing was cached there"


def test_the_per_user_folder_is_keyed_by_numba_and_python(tmp_path):
    import numba

    out = _probe(tmp_path, XDG_CACHE_HOME=str(tmp_path / "xdg"))
    key = f"numba-{numba.__version__}-py{sys.version_info.major}.{sys.version_info.minor}"
    assert out["folder"] == str(tmp_path / "xdg" / "boresight" / key)
    assert out["warnings"] == []


def _unwritable(tmp_path, **env):
    """A probe whose home and cache folders cannot be made, even by root (paths under a file)."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    blocked = {"HOME": "home", "XDG_CACHE_HOME": "xdg", "NUMBA_CACHE_DIR": "given"}
    return _probe(tmp_path, **{k: str(blocker / v) for k, v in blocked.items()}, **env)


def test_an_unwritable_home_falls_back_to_the_temporary_folder(tmp_path):
    out = _unwritable(tmp_path, PROBE_TEMPDIR=str(tmp_path / "tmp"))
    assert out["folder"].startswith(str(tmp_path / "tmp" / "boresight-"))
    assert out["warnings"] == []


def test_no_writable_folder_at_all_compiles_without_a_cache_and_warns_once(tmp_path):
    out = _unwritable(tmp_path, PROBE_TEMPDIR=str(tmp_path / "file" / "tmp"))
    assert out["folder"] is None
    assert len(out["warnings"]) == 1
    assert "NUMBA_CACHE_DIR" in out["warnings"][0]


def test_a_temporary_folder_of_another_user_is_not_used(tmp_path, monkeypatch):
    from boresight._util import jit

    if not hasattr(os, "getuid"):
        pytest.skip("no user ids here")
    owned = tmp_path / "theirs" / "key"
    owned.mkdir(parents=True)
    monkeypatch.setattr(os, "getuid", lambda: os.stat(owned.parent).st_uid + 1)
    assert not jit._writable(owned, owned=True)
    assert jit._writable(owned, owned=False)


def test_running_kernels_writes_nothing_into_the_package(tmp_path):
    before = _package_cache_files()
    _probe(tmp_path, NUMBA_CACHE_DIR=str(tmp_path / "c"))
    _probe(tmp_path, XDG_CACHE_HOME=str(tmp_path / "xdg"))
    assert _package_cache_files() == before == []
