"""Pairs on the boresight: a synthetic scan's pixels, a stream of real samples, or a
schedule whose CESs a pipeline filters before binning; and the scan's spin moments h_n.

``simulate`` streams pixel chunks through the kernels of a backend: hits, detector-B pointing,
sky evaluation, pair differences and per-pixel normal equations (one fused kernel on the GPU),
then solves each pixel where the sums lie; memory is bounded by the chunk. ``scan_moments`` runs
the same hit generator to give the h_n maps.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from .._util import interrupts
from .._util.threads import numba_threads
from ..instrument.pairs import Instrument, Systematics
from ..kernels import get_backend

# CPU only (not of the contract): the 3x3 maps, and the pair differences a filter acts on
from ..kernels.pixels import ang2pix_array
from ..mapmaking import RCOND_MIN, Maps, solve
from ..mitigation import Filtering
from ..pointing import pointing
from ..validation import integer
from .binner import (
    DEFAULT_CHUNK_PIXELS,
    Binner,
    check_backend_mapmaker,
    check_nside,
    check_samples,
    maps_from,
    normal_sums,
    pixel_chunks,
    pixel_list,
    scan_hits,
    stream_maps,
)
from .mitigation import Cleaning

if TYPE_CHECKING:
    from collections.abc import Iterable

    from ..scan import SyntheticScan
    from ..schedule import Schedule
    from ..sky import Sky


def simulate(
    sky: Sky,
    scan: SyntheticScan,
    instrument: Instrument = Instrument(),
    systematics: Systematics = Systematics(),
    *,
    pixels: np.ndarray | None = None,
    evaluation: str = "interp",
    leak_template: np.ndarray | None = None,
    chunk_pixels: int | None = None,
    nthreads: int = 0,
    backend: str = "cpu",
    rcond_min: float = RCOND_MIN,
    progress: bool = False,
) -> Maps:
    """Simulate the pair-differenced TOD of a synthetic scan over a sky and make Q, U maps.

    Parameters
    ----------
    sky : boresight.sky.Sky
        Beam-smoothed I, Q, U [muK] (maps and alm).
    scan : boresight.scan.SyntheticScan
        Crossing angles per pixel and the boresight-rotation schedule.
    instrument : boresight.instrument.pairs.Instrument
        Polarisation angles of the detector pairs.
    systematics : boresight.instrument.pairs.Systematics
        Differential gain, pointing and additive leak per pair.
    pixels : numpy.ndarray, optional
        RING indices (int, (n,)) or a boolean map (npix,) of the pixels to observe (default: all).
        A float 0/1 mask is refused: pass ``mask > 0``.
    evaluation : {"interp", "exact"}
        Bilinear interpolation of the maps, or exact band-limited evaluation of the alm.
    leak_template : numpy.ndarray, optional
        (npix,) map the additive leak scales [muK] (default: the sky's I).
    chunk_pixels : int, optional
        Pixels per chunk (default: the backend's); the result does not depend on it.
    nthreads : int
        CPU threads, 0 for all cores; the result does not depend on it.
    backend : {"cpu", "gpu"}
        Kernel backend (:mod:`boresight.backend`).
    rcond_min : float
        Pixels whose 2x2 system has a smaller reciprocal condition number are flagged invalid.
    progress : bool
        Show a progress bar over chunks.

    Returns
    -------
    boresight.mapmaking.Maps
        On ``pixels``: q, u [muK] (UNSEEN where invalid), hits (int) and rcond.
    """
    maps, _ = _simulate(
        sky,
        scan,
        instrument,
        systematics,
        False,
        pixels=pixels,
        evaluation=evaluation,
        leak_template=leak_template,
        chunk_pixels=chunk_pixels,
        nthreads=nthreads,
        backend=backend,
        rcond_min=rcond_min,
        progress=progress,
    )
    return maps


def simulate_with_zero_qu(
    sky: Sky,
    scan: SyntheticScan,
    instrument: Instrument = Instrument(),
    systematics: Systematics = Systematics(),
    **options,
) -> tuple[Maps, Maps]:
    """:func:`simulate`, and the maps of the same hits over the sky with Q = U = 0, in one pass.

    The second maps are the numbers of simulating ``sky.without_polarisation()`` (the paper's
    check that a residual comes from the polarised sky); their hits and rcond are the first's.

    Parameters
    ----------
    sky, scan, instrument, systematics, **options
        As in :func:`simulate`.

    Returns
    -------
    maps, zero_qu_maps : boresight.mapmaking.Maps

    Raises
    ------
    ValueError
        With detector beams, whose signal is the polarised sky's.
    """
    return _simulate(sky, scan, instrument, systematics, True, **options)


def _simulate(
    sky,
    scan,
    instrument,
    systematics,
    zero_qu,
    *,
    pixels=None,
    evaluation="interp",
    leak_template=None,
    chunk_pixels=None,
    nthreads=0,
    backend="cpu",
    rcond_min=RCOND_MIN,
    progress=False,
):
    """(the sky's maps, Q = U = 0's maps or None)."""
    if zero_qu and systematics.has_beams:
        raise ValueError(
            "zero_qu does not apply to detector beams (their signal is the polarised sky's): "
            "simulate sky.without_polarisation() instead"
        )
    binner = Binner(
        sky,
        instrument,
        systematics,
        scan.rotations_rad,
        evaluation,
        leak_template,
        nthreads,
        backend,
    )
    kernels, nside, npix = binner.kernels, sky.nside, 12 * sky.nside**2
    if chunk_pixels is None:
        chunk_pixels = DEFAULT_CHUNK_PIXELS[backend]
    pix = pixel_list(pixels, npix)
    q, u = np.empty((2, pix.size))  # rows of one array: Maps.take_qu hands it on, no copy
    rcond = np.empty(pix.size)
    ncross = np.empty(pix.size, dtype=np.int64)
    if zero_qu:  # Q = U = 0's q, u; its hits and rcond are the sky's (the same c, s sums)
        q0, u0 = np.empty((2, pix.size))
    with numba_threads(nthreads):
        for s, chunk in pixel_chunks(pix, chunk_pixels, progress, "simulate"):
            normal = binner.scan_normal(scan, nside, chunk, zero_qu)
            at = slice(s, s + chunk.size)
            if zero_qu:
                normal, normal0 = normal
                q0[at], u0[at] = (kernels.to_host(x) for x in solve(normal0, rcond_min)[:2])
            q[at], u[at], rcond[at], ncross[at] = maps_from(
                kernels, normal, instrument.n_pairs, rcond_min
            )
    maps = Maps(nside, pix, q, u, ncross, rcond)
    return maps, Maps(nside, pix, q0, u0, ncross, rcond) if zero_qu else None


def simulate_samples(
    sky: Sky,
    sample_chunks: Iterable,
    instrument: Instrument = Instrument(),
    systematics: Systematics = Systematics(),
    *,
    evaluation: str = "interp",
    leak_template: np.ndarray | None = None,
    nthreads: int = 0,
    backend: str = "cpu",
    rcond_min: float = RCOND_MIN,
    mapmaker: str = "pairs",
) -> Maps:
    """Maps from streams of real samples, e.g. ``boresight.pointing.pointing(schedule)``.

    The normal equations of all chunks add up before the per-pixel solve, so memory is one chunk
    plus the (npix, 5) sums. Each sample's terms are added into its pixel's sums in sample order
    (a GPU sorts each chunk by pixel first), so CPU and GPU agree to rounding.

    Parameters
    ----------
    sky : boresight.sky.Sky
    sample_chunks : iterable of (theta, phi, psi)
        Arrays (n,) [rad] of each chunk, in any order; checked by :func:`check_samples`.
    instrument, systematics, leak_template, nthreads, backend, rcond_min
        As in :func:`simulate`.
    evaluation : {"interp", "exact", "pixel"}
        As in :func:`simulate`, or each map's value in the sample's pixel (TOAST's
        ``ScanHealpixMap``).
    mapmaker : {"pairs", "detectors", "single", "pairs-spin0"}
        Pair differences -> Q, U; each detector's own samples -> I, Q, U; or pair differences ->
        a free spin-0 field (``Maps.i_obs``) beside Q, U (:data:`boresight.mapmaking.MAPMAKERS`),
        on the CPU backend.

    Returns
    -------
    boresight.mapmaking.Maps
    """
    check_backend_mapmaker(mapmaker, backend)
    binner = Binner(
        sky, instrument, systematics, (0.0,), evaluation, leak_template, nthreads, backend
    )
    normal = normal_sums(binner.kernels, sky.nside, mapmaker)
    first = 0  # the stream index of each chunk's first sample: the key of its jitter draws
    with numba_threads(nthreads):
        for chunk in sample_chunks:
            interrupts.check()
            theta, phi, psi = check_samples(*chunk)
            pix = ang2pix_array(sky.nside, theta, phi)
            binner.scatter(
                pix, theta, phi, psi, normal, seed=systematics.seed, first=first, mapmaker=mapmaker
            )
            first += pix.size
    return stream_maps(
        binner.kernels,
        sky.nside,
        normal,
        mapmaker,
        n_pairs=instrument.n_pairs,
        rcond_min=rcond_min,
    )


def simulate_schedule(
    sky: Sky,
    schedule: Schedule,
    instrument: Instrument = Instrument(),
    systematics: Systematics = Systematics(),
    *,
    filtering: Filtering = Filtering(),
    evaluation: str = "interp",
    leak_template: np.ndarray | None = None,
    nthreads: int = 0,
    backend: str = "cpu",
    rcond_min: float = RCOND_MIN,
    mapmaker: str = "pairs",
    chunk_samples: int = 1 << 20,
    progress: bool = False,
) -> Maps:
    """Maps of a schedule's pairs on the boresight, their pair differences filtered before
    binning as a pipeline filters them.

    Without a filter, :func:`simulate_samples` of the schedule's pointing. With one, each CES
    (once per boresight repeat) is simulated whole, its pair differences filtered
    (:meth:`boresight.mitigation.Filtering.apply`) and binned with the weights of the unfiltered
    samples, as a naive map-maker bins filtered TOD; memory is one CES's samples. The gain jitter
    of sample k of the stream is keyed by (seed, k) as in :func:`simulate_samples`, counting the
    turnarounds' samples, which are filtered and, where the schedule leaves them out, not binned.

    Parameters
    ----------
    sky, instrument, systematics, evaluation, leak_template, nthreads, backend, rcond_min, mapmaker
        As in :func:`simulate_samples`.
    schedule : boresight.schedule.Schedule
    filtering : boresight.mitigation.Filtering
        The pipeline's filters and deprojection (none by default); with one, the CPU backend
        and the pairs' map-maker. Its templates (:attr:`~boresight.mitigation.Filtering.
        deprojection`) are regressed from each pair difference per CES after the filters,
        filtered as the data are; derivatives of T need ``evaluation="exact"``.
    chunk_samples : int
        Samples per chunk of pointing.
    progress : bool

    Returns
    -------
    boresight.mapmaking.Maps

    Raises
    ------
    ValueError
        A filter or deprojection on another backend or map-maker, or that a CES cannot take
        (:meth:`boresight.mitigation.CesScan.check`), before any work; a CES whose templates
        cannot be fitted (too few samples, collinear templates), naming it.
    """
    run = dict(
        evaluation=evaluation,
        leak_template=leak_template,
        nthreads=nthreads,
        backend=backend,
        rcond_min=rcond_min,
        mapmaker=mapmaker,
    )
    if not filtering:
        return simulate_samples(
            sky, pointing(schedule, chunk_samples), instrument, systematics, **run
        )
    cleaning = Cleaning(filtering, sky, schedule.frame)
    cleaning.check(schedule, backend=backend, mapmaker=mapmaker, evaluation=evaluation)
    binner = Binner(
        sky, instrument, systematics, (0.0,), evaluation, leak_template, nthreads, backend
    )
    normal = normal_sums(binner.kernels, sky.nside, mapmaker)
    first = 0
    with (
        numba_threads(nthreads),
        tqdm(total=schedule.n_samples, unit="sample", unit_scale=True, disable=not progress) as bar,
    ):
        for block, members in cleaning.blocks(schedule):
            parts, c_s = [], []
            for one, scan in members:
                theta, phi, psi = (np.concatenate(x) for x in zip(*pointing(one, chunk_samples)))
                interrupts.check()
                c, s, d = binner.differences(
                    theta, phi, psi, seed=systematics.seed, first=first,
                    detectors=cleaning.detectors,
                )  # fmt: skip
                parts.append(
                    cleaning.part(
                        d, binner, theta, phi, psi, scan=scan, schedule=schedule, nside=sky.nside
                    )
                )
                c_s.append((c, s))
                first += psi.size
                bar.update(psi.size)
            cleaning.bin_block(parts, c_s, normal, block)
    return stream_maps(
        binner.kernels, sky.nside, normal, mapmaker, n_pairs=instrument.n_pairs, rcond_min=rcond_min
    )


def scan_moments(
    scan: SyntheticScan,
    nside: int,
    n_max: int = 4,
    *,
    pixels: np.ndarray | None = None,
    chunk_pixels: int | None = None,
    nthreads: int = 0,
    backend: str = "cpu",
    progress: bool = False,
    dtype: type = np.complex128,
) -> tuple[np.ndarray, np.ndarray]:
    """The spin moments h_n = <exp(i n psi)> over each pixel's hits, rotations included.

    Parameters
    ----------
    scan : boresight.scan.SyntheticScan
    nside : int
        HEALPix Nside, a power of two.
    n_max : int
        Highest moment.
    pixels : numpy.ndarray, optional
        RING indices or a boolean map of the pixels (default: all).
    chunk_pixels, nthreads, backend, progress
        As in :func:`simulate`.
    dtype : numpy.complex128 or numpy.complex64
        Of h, summed in complex128 either way: complex64 keeps each h_n (of modulus at most 1)
        to 6e-8 in half the memory (:func:`boresight.moments.axis.compute_moments`).

    Returns
    -------
    h : numpy.ndarray, ``dtype``, shape (n_max + 1, npix)
        h_n per pixel, 0 where unobserved.
    crossings : numpy.ndarray, int64, shape (npix,)
        Hits per pixel times the number of rotations.
    """
    kernels = get_backend(backend)
    check_nside(nside)
    integer("n_max", n_max, 0, 64)
    npix = 12 * nside**2
    pix = pixel_list(pixels, npix)
    chunk_pixels = DEFAULT_CHUNK_PIXELS[backend] if chunk_pixels is None else chunk_pixels
    if np.dtype(dtype) not in (np.complex128, np.complex64):
        raise ValueError(f"dtype must be complex128 or complex64, got {dtype}")
    h = np.zeros((n_max + 1, npix), dtype=dtype)
    ncross = np.zeros(npix, dtype=np.int64)
    with numba_threads(nthreads):
        for _, chunk in pixel_chunks(pix, chunk_pixels, progress, "scan moments"):
            offsets, _, _, psi = scan_hits(kernels, scan, nside, chunk)
            h[:, chunk] = kernels.to_host(
                kernels.moments(offsets, psi, scan.rotations_rad, n_max)
            ).T
            ncross[chunk] = np.diff(kernels.to_host(offsets)) * len(scan.rotations_deg)
    return h, ncross
