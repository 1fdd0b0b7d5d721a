"""Memory a job will need, estimated from Nside, lmax and the scan before anything is allocated.

A job whose estimate exceeds the machine's memory (the smaller of physical memory and a cgroup
limit) is refused with the estimate, unless the user forces it (``--no-memory-check``). The
per-pixel costs are measured peaks (``bench/bench_reproduce.py``, ``bench/bench_engine.py``) with a
margin, so the estimate errs high: it is a guard against a run that cannot fit, not a forecast.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

GIB = 2.0**30
#: peak bytes per HEALPix pixel of each job, from measured peaks (simulate: 4.8 GiB at Nside 2048
#: for the engine alone, x2 for the reference run and spectra; reproduce: 8.2 GiB at Nside 2048 and
#: 2.3 GiB at 1024 / lmax 2047 on 2026-11-23; 16.3 and 4.3 GiB before the maps were held on the
#: observed pixels)
BYTES_PER_PIXEL = {
    "simulate": 200.0,
    "reproduce": 200.0,
    "predict": 160.0,
    "scan-stats": 160.0,
    "compare-scans": 320.0,
    "suppression": 380.0,  # the reproduction's pattern: one survey, transforms queued
}


class MemoryLimitError(ValueError):
    """A job whose estimated memory exceeds what the machine has."""


def available_bytes() -> float:
    """The memory a job may use.

    Returns
    -------
    float
        Physical memory, or the cgroup (container) limit where that is smaller [bytes].
    """
    total = float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            total = min(total, float(text))
    return total


def estimate_bytes(
    job: str,
    nside: int,
    lmax: int,
    n_phi_max: int = 0,
    n_rotations: int = 1,
    n_pairs: int = 2,
    chunk_pixels: int = 0,
) -> float:
    """Estimated peak memory of a job.

    Full-sky arrays (per pixel), the sky's alm (3 x nalm complex) and one chunk of a synthetic
    scan's hits: per hit its position and angle, and the sky fields at detector A and at detector
    B of every pair and rotation.

    Parameters
    ----------
    job : str
        A key of :data:`BYTES_PER_PIXEL`.
    nside, lmax : int
    n_phi_max : int
        Most hits per pixel.
    n_rotations, n_pairs : int
    chunk_pixels : int
        Pixels per chunk of the engine.

    Returns
    -------
    float
        [bytes].
    """
    npix = 12.0 * nside**2
    nalm = (lmax + 1.0) * (lmax + 2.0) / 2.0
    hits = float(chunk_pixels) * float(n_phi_max)
    per_hit = 8.0 * (6.0 + 3.0 * n_rotations * n_pairs)
    return BYTES_PER_PIXEL[job] * npix + 48.0 * nalm + hits * per_hit


def require(job: str, estimate: float, check: bool = True) -> None:
    """Refuse a job whose estimate exceeds the machine's memory.

    Parameters
    ----------
    job : str
    estimate : float
        [bytes].
    check : bool
        False skips the check.

    Raises
    ------
    MemoryLimitError
        With the estimate and the machine's memory in GiB.
    """
    have = available_bytes()
    if check and estimate > have:
        raise MemoryLimitError(
            f"{job} needs about {estimate / GIB:.1f} GiB but this machine has "
            f"{have / GIB:.1f} GiB; lower the Nside, lmax or n_phi, or pass --no-memory-check"
        )


def n_phi_max(n_phi: int | np.ndarray) -> int:
    """The largest hit count per pixel.

    Parameters
    ----------
    n_phi : int or numpy.ndarray

    Returns
    -------
    int
    """
    return int(np.max(n_phi))
