"""Compiling the numba kernels a run calls before it calls them, on several cores at once.

With an empty numba cache (a new install, a new numba) each kernel compiles on its first call, one
after another on one core, while the other cores wait (``bench/bench_cold_start.py`` measures
it). :func:`precompile` shares the kernels that the cache lacks between this process and helper
processes (``python -m boresight._util.precompile NAME ...``); ``python -m boresight._util.precompile``
alone compiles every kernel. Each helper writes its
kernels to numba's cache, and this process then loads them from there. With a warm cache it only
checks the cache, a few milliseconds per kernel.

:data:`KERNELS` holds the argument types a job passes to each kernel; :func:`kernels_for` names the
kernels of each job: a study (``reproduce``, ``simulate``), ``design`` with its TOD validation,
and ``scan-stats`` of a schedule. ``tests/_util/test_precompile.py`` runs each job in a process whose
kernels may compile no other types.
"""

from __future__ import annotations

import contextlib
import heapq
import importlib
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from numba import types as nt

from . import interrupts
from .jit import cache_dir
from .threads import default_threads

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .provenance import Timer

__all__ = ["Kernel", "KERNELS", "kernels_for", "missing", "precompile"]

_F1, _I1, _C1 = nt.float64[::1], nt.int64[::1], nt.complex128[::1]
_C2 = nt.complex128[:, ::1]
_H1, _H2 = nt.complex64[::1], nt.complex64[:, ::1]  # a study's h_n (moments.compute_moments)
_P1 = nt.int32[::1]  # a footprint's NEST parents (spectra.Footprint.parents)
_F2, _F3, _F4 = nt.float64[:, ::1], nt.float64[:, :, ::1], nt.float64[:, :, :, ::1]
_STRIDED = nt.float64[:]  # a row of the sky's interleaved (npix, F) stack

#: Seconds a helper process takes to start and import boresight, before it compiles anything.
HELPER_START_SECONDS = 1.2


@dataclass(frozen=True)
class Kernel:
    """One cached numba kernel and the argument types a job calls it with.

    Parameters
    ----------
    module, name : str
        It is ``boresight.<module>.<name>``.
    signature : tuple of numba types
    seconds : float
        Its relative compile time, measured once; it only balances the processes.
    """

    module: str
    name: str
    signature: tuple
    seconds: float

    @property
    def dispatcher(self):
        """The numba dispatcher (imports its module)."""
        return getattr(importlib.import_module(f"boresight.{self.module}"), self.name)


_CHUNK = (nt.int64, nt.int64, _F1, _F1)  # a CES chunk: chunk_arguments' tuple
_U2 = nt.uint64[:, ::1]

#: Every kernel a job calls, by name, with the argument types it is called with.
KERNELS = {
    k.name: k
    for k in (
        Kernel(
            "kernels.cpu",
            "accumulate",
            (_I1, _F1, _F2, _F4, _F4, _F3, _F1, _F1, nt.int64, _I1),
            3.2,
        ),
        Kernel("kernels.pixels", "interpolate_interleaved", (_F2, nt.int64, _F1, _F1), 3.1),
        Kernel(
            "kernels.cpu", "generate_hits", (nt.int64, nt.int64, _I1, _I1, _F1, _F1, nt.bool_), 2.4
        ),
        Kernel("kernels.cpu", "moments", (_I1, _F1, _F1, nt.int64), 1.9),
        Kernel("predict.windows", "_legendre_sums", (_F1, _F1, _F2), 1.4),
        Kernel(
            "predict.maps",
            "_delta_p",
            (nt.bool_, _I1, _H2, *[_STRIDED] * 3, *[_F1] * 3, *[_C1] * 3),
            1.3,
        ),
        Kernel("kernels.cpu", "offset_points", (_F1,) * 7, 0.7),
        Kernel("instrument.pairs", "_response", (_F1,) * 6, 0.4),
        Kernel("masks", "_inside", (_F1,) * 4 + (nt.float64,), 1.3),
        Kernel("predict.cl", "_block_sums", (_H1, _I1, _F1, _P1, nt.int64), 0.9),
        Kernel("moments.axis", "ces_hits", (*_CHUNK, nt.int64, nt.int64, nt.bool_), 2.2),
        Kernel("moments.units", "_rotate_and_sum", (_I1, _I1, _C2, _C2, _C2), 0.8),
        Kernel(
            "design.operations",
            "_timeline",
            (*[_F1] * 3, _I1, _F1, _F1, nt.float64, nt.float64, _F1, _F1, nt.int64[:, ::1]),
            0.5,
        ),
        Kernel("predict.field_products", "_recurse", (_F1, *[nt.int64] * 3, _F1, _F2), 0.6),
        Kernel("design.exact", "_apply", (_F3, _I1, _F1, _C2, nt.int64, nt.int64, _C2), 0.6),
        Kernel("moments.axis", "_bin", (_I1, _F1, _F1, nt.int32[::1], _C2, _I1, _U2, _I1), 1.1),
        Kernel("moments.axis", "_runs", (_U2, nt.int64, _I1, _I1, nt.int64), 2.8),
        Kernel(
            "moments.axis",
            "ces_hits_pairs",
            (*_CHUNK, nt.int64, nt.int64, nt.bool_, _F2, _F1, _F1),
            2.4,
        ),
        Kernel(
            "moments.axis",
            "bin_pairs",
            (nt.int64[:, ::1], nt.int64[:, ::1], _F2, _F2, nt.int32[:, ::1], _C2, _I1, _U2)
            + (nt.complex128[:, :, ::1], nt.int64[:, ::1], _I1),
            1.0,
        ),
        Kernel("moments.axis", "pixel_ranges", (_I1, nt.int64, nt.int64), 0.3),
        Kernel("moments.observed", "_assign", (_I1, nt.int32[::1], _I1, nt.int64), 0.3),
        Kernel(
            "moments.focalplane",
            "_in_order",
            (nt.complex128[:, :, ::1], nt.int64[:, ::1], _I1),
            0.5,
        ),
        Kernel(
            "moments.focalplane",
            "_pair_sums",
            (nt.complex128[:, :, ::1], nt.int64[:, ::1], nt.int64, nt.bool_),
            0.8,
        ),
        Kernel("pointing", "_ces_pointing", _CHUNK, 2.4),
        Kernel("kernels.pixels", "ang2pix_array", (nt.int64, _F1, _F1), 1.6),
        Kernel(
            "kernels.cpu",
            "_scatter",  # accumulate_scatter's and accumulate_detectors' kernel, by its mode
            (_I1, _F1, _F2, _F4, _F4, _F3, _F1, _F1, nt.int64, nt.int64, nt.int64, _F2),
            1.6,
        ),
    )
}

#: Per job: (the kernels it calls on every backend, those of the CPU engine only).
_JOBS = {
    "study": (
        ("_legendre_sums", "_delta_p", "_response", "_inside", "_block_sums"),
        ("accumulate", "interpolate_interleaved", "generate_hits", "moments"),
    ),
    "design": (("ces_hits", "_rotate_and_sum", "_recurse", "_apply", "_timeline"), ()),
    "validation": (
        ("_ces_pointing", "ang2pix_array", "_response"),
        ("interpolate_interleaved", "_scatter"),
    ),
    "schedule-stats": (("ces_hits", "_bin", "_runs", "pixel_ranges"), ()),
    "focalplane-stats": (
        ("ces_hits", "ces_hits_pairs", "_assign", "bin_pairs", "_in_order", "_pair_sums")
        + ("_runs", "pixel_ranges"),
        (),
    ),
}


def kernels_for(job: str, backend: str = "cpu", pointing: bool = False) -> list[str]:
    """The kernels a job calls.

    Parameters
    ----------
    job : {"study", "design", "validation", "schedule-stats", "focalplane-stats"}
        A study's simulation and prediction (``simulate``, ``reproduce``); ``design``'s search;
        its TOD simulation of a schedule's own samples; ``scan-stats`` of a schedule, on the
        boresight or over a focal plane.
    backend : {"cpu", "gpu"}
        The engine's backend: the GPU runs its own kernels.
    pointing : bool
        Whether any pair has a pointing offset (detector B's pointing is a kernel of its own).

    Returns
    -------
    list of str
        Names in :data:`KERNELS`.
    """
    if job not in _JOBS:
        raise ValueError(f"job {job!r}; allowed: {', '.join(_JOBS)}")
    every_backend, cpu_engine = _JOBS[job]
    names = list(every_backend)
    if backend == "cpu" and cpu_engine:
        names += cpu_engine + (("offset_points",) if pointing else ())
    return names


def missing(names: Sequence[str]) -> list[str]:
    """The kernels that neither this process nor numba's cache holds at their signature.

    Parameters
    ----------
    names : sequence of str
        Names in :data:`KERNELS`.

    Returns
    -------
    list of str
    """
    out = []
    for name in names:
        kernel = KERNELS[name]
        dispatcher = kernel.dispatcher
        if kernel.signature in dispatcher.overloads:
            continue
        # numba has no public "is it cached" query; its dispatcher asks the cache this way
        if dispatcher._cache.load_overload(kernel.signature, dispatcher.targetctx) is None:
            out.append(name)
    return out


def precompile(names: Sequence[str], nthreads: int = 0, timer: Timer | None = None) -> list[str]:
    """Have every kernel of ``names`` ready in this process, compiling those that the cache lacks
    on up to ``nthreads`` processes at once.

    This process compiles a share itself; each helper process compiles its share into numba's
    cache, from which this process loads it once the helpers are done. The kernels that the cache
    holds are loaded from it.

    Parameters
    ----------
    names : sequence of str
        Names in :data:`KERNELS`, e.g. from :func:`kernels_for`.
    nthreads : int
        Processes at most, 0 for all cores.
    timer : boresight._util.provenance.Timer, optional
        Times the compilation as a stage of its own, when there is any.

    Returns
    -------
    list of str
        The kernels that were compiled (none with a warm cache).

    Raises
    ------
    RuntimeError
        A helper process failed (its error output is in the message).
    """
    todo = missing(names)
    for name in names:
        if name not in todo:
            _compile(name)  # loads it from the cache
    if not todo:
        return []
    workers = min(nthreads if nthreads > 0 else default_threads(), len(todo))
    # helpers share their kernels through the cache: with none, this process compiles alone
    shares = _balance(todo, workers if sys.executable and cache_dir() is not None else 1)
    label = f"compile {len(todo)} numba kernels on {len(shares)} cores (first run only)"
    with timer(label) if timer else contextlib.nullcontext():
        helpers = [_start_helper(share) for share in shares[1:]]
        try:
            for name in shares[0]:
                interrupts.check()
                _compile(name)
            for helper, share in zip(helpers, shares[1:]):
                err = _wait(helper)
                if helper.returncode:
                    raise RuntimeError(f"compiling {', '.join(share)} failed:\n{err}")
        except BaseException:
            for helper in helpers:
                helper.kill()
                helper.wait()
            raise
        for share in shares[1:]:  # loaded from the cache the helpers wrote
            for name in share:
                _compile(name)
    return todo


def _balance(names, workers):
    """Shares of ``names`` for this process and ``workers - 1`` helpers: each kernel, longest
    first, to the process that would finish soonest. Empty shares are dropped."""
    starts = [0.0] + [HELPER_START_SECONDS] * (workers - 1)
    heap = [(start, i) for i, start in enumerate(starts)]
    shares = [[] for _ in starts]
    for name in sorted(names, key=lambda n: -KERNELS[n].seconds):
        load, i = heapq.heappop(heap)
        shares[i].append(name)
        heapq.heappush(heap, (load + KERNELS[name].seconds, i))
    return [shares[0]] + [s for s in shares[1:] if s]


def _start_helper(share):
    """A process that compiles ``share`` into numba's cache, importing this boresight.

    ``python -m`` puts its working folder first on the path, so the helper runs in the folder
    that holds this package: from a checkout's root it would otherwise import the checkout, not
    the installed copy that this process runs.
    """
    package_root = Path(__file__).resolve().parent.parent
    return subprocess.Popen(
        [sys.executable, "-m", "boresight._util.precompile", *share],
        cwd=package_root,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait(helper):
    """A helper's error output once it has finished, checking for Ctrl-C while it runs."""
    while True:
        interrupts.check()
        try:
            return helper.communicate(timeout=interrupts.POLL_SECONDS)[1]
        except subprocess.TimeoutExpired:
            continue


def _compile(name):
    """Compile (or load from the cache) one kernel at its signature, unless this process has it."""
    kernel = KERNELS[name]
    dispatcher = kernel.dispatcher
    if kernel.signature not in dispatcher.overloads:
        dispatcher.compile(kernel.signature)


if __name__ == "__main__":
    # ``python -m boresight._util.precompile``: every kernel, on all cores (CI before the tests); with
    # kernel names, a helper process of precompile() compiling its share
    if len(sys.argv) > 1:
        for arg in sys.argv[1:]:
            _compile(arg)
    else:
        compiled = precompile(list(KERNELS))
        print(f"{len(compiled)} of {len(KERNELS)} numba kernels compiled; the rest were cached")
