"""The simulation engine: sky -> synthetic scan -> detectors and systematics -> PBR -> maps.

``simulate`` streams pixel chunks through the kernels of a backend (:mod:`boresight.kernels`):
hits, detector-B pointing, sky evaluation, pair differences and per-pixel normal equations (one
fused kernel on the GPU), then solves each pixel where the sums lie; memory is bounded by the
chunk. ``scan_moments`` runs the same hit generator to give the h_n maps.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from . import harmonics
from ._util import interrupts
from ._util.threads import numba_threads
from .constants import ARCMIN
from .evaluation import ENGINE_METHODS, SkyFields
from .instrument.beams import BeamConvolver, pair_beams
from .instrument.hwp import angle_jitter, plate_signals, reflected, reflected_systematics
from .instrument.pairs import Instrument, Systematics, response
from .kernels import get_backend

# CPU only (not of the contract): the 3x3 maps, and the pair differences a filter acts on
from .kernels.cpu import accumulate_detectors, bin_differences, pair_differences
from .kernels.fields import hit_offsets, pair_fields, sums_with_zero_qu
from .kernels.pixels import ang2pix_array
from .mapmaking import RCOND_MIN, Maps, check_mapmaker, solve, solve_iqu
from .mitigation import Filtering, ces_scans
from .mitigation.deprojection import template_alm
from .pointing import detector_pointing, pointing
from .sky import MAX_NSIDE
from .validation import integer

if TYPE_CHECKING:
    from collections.abc import Iterable

    from .instrument.focalplane import FocalPlane
    from .instrument.hwp import HWP
    from .scan import SyntheticScan
    from .schedule import Schedule
    from .sky import Sky


#: pixels per chunk: small on the CPU (cache-resident), large on a GPU (enough threads)
DEFAULT_CHUNK_PIXELS = {"cpu": 1 << 16, "gpu": 1 << 22}


def _pixel_list(pixels, npix):
    """Sorted unique int64 RING indices from ``pixels``, contiguous (the kernels' registered
    type): None (all), a boolean map of npix entries, or a 1-d array of integer indices in
    [0, npix). Anything else is a ValueError (a float 0/1 mask would otherwise read as the pixel
    indices 0 and 1)."""
    if pixels is None:
        return np.arange(npix, dtype=np.int64)
    pixels = np.asarray(pixels)
    if pixels.ndim != 1:
        raise ValueError(f"pixels must be 1-d (indices or a boolean map), got shape {pixels.shape}")
    if pixels.dtype == bool:
        if pixels.size != npix:
            raise ValueError(f"pixels: a boolean map of {pixels.size} entries, the sky has {npix}")
        return np.flatnonzero(pixels).astype(np.int64, copy=False)
    if not np.issubdtype(pixels.dtype, np.integer):
        raise ValueError(
            f"pixels must be integer RING indices or a boolean map, got dtype {pixels.dtype} "
            "(for a 0/1 mask pass mask > 0)"
        )
    pixels = np.ascontiguousarray(pixels, dtype=np.int64)  # a strided view would compile anew
    if pixels.size > 1 and not np.all(pixels[1:] > pixels[:-1]):
        pixels = np.unique(pixels)  # else already sorted and unique: no copy
    if pixels.size and (pixels[0] < 0 or pixels[-1] >= npix):
        raise ValueError(f"pixels: RING indices must lie in [0, {npix})")
    return pixels


def _check_nside(nside):
    if isinstance(nside, bool) or not isinstance(nside, (int, np.integer)):
        raise TypeError(f"nside must be an integer power of two, got {nside!r}")
    if not 1 <= nside <= MAX_NSIDE or nside & (nside - 1):
        raise ValueError(f"nside must be a power of two in [1, {MAX_NSIDE}], got {nside}")


def check_samples(
    theta: np.ndarray, phi: np.ndarray, psi: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One chunk of pointing samples as float64 arrays, checked at the boundary.

    Parameters
    ----------
    theta, phi, psi : array_like, shape (n,)
        Colatitude in [0, pi], longitude (any turn) and crossing angle [rad], all finite.

    Returns
    -------
    theta, phi, psi : numpy.ndarray, float64, shape (n,)
        phi in [0, 2 pi).

    Raises
    ------
    ValueError
        Unequal lengths, NaN or infinite values, theta outside [0, pi].
    """
    theta, phi, psi = (np.ascontiguousarray(x, dtype=np.float64) for x in (theta, phi, psi))
    if not theta.ndim == phi.ndim == psi.ndim == 1 or not theta.size == phi.size == psi.size:
        raise ValueError(
            f"theta, phi, psi must be 1-d of equal length, got {theta.shape}, {phi.shape}, "
            f"{psi.shape}"
        )
    if not (np.isfinite(phi).all() and np.isfinite(psi).all()):
        raise ValueError("phi and psi must be finite (a sample has NaN or infinite pointing)")
    if not ((theta >= 0) & (theta <= np.pi)).all():
        raise ValueError("theta must lie in [0, pi] (a sample has NaN or out-of-range pointing)")
    if phi.size and not (0.0 <= phi.min() and phi.max() < 2 * np.pi):
        phi = np.mod(phi, 2 * np.pi)  # the kernels' interpolation takes [0, 2 pi)
    return theta, phi, psi


def _chunks(pixels, chunk_pixels, progress, label):
    if chunk_pixels < 1:
        raise ValueError(f"chunk_pixels must be >= 1, got {chunk_pixels}")
    starts = range(0, pixels.size, chunk_pixels)
    for s in tqdm(starts, desc=label, unit="chunk", disable=not progress, leave=False):
        interrupts.check()
        yield s, pixels[s : s + chunk_pixels]


def _hits(kernels, scan, nside, chunk):
    n_phi, rng_rad, centre = scan.per_pixel(chunk, 12 * nside**2)
    offsets = hit_offsets(n_phi)
    theta, phi, psi = kernels.generate_hits(
        scan.seed, nside, chunk, offsets, rng_rad, centre, scan.in_pixel == "centre"
    )
    return offsets, theta, phi, psi


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
    binner = _Binner(
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
    pix = _pixel_list(pixels, npix)
    q, u = np.empty((2, pix.size))  # rows of one array: Maps.take_qu hands it on, no copy
    rcond = np.empty(pix.size)
    ncross = np.empty(pix.size, dtype=np.int64)
    if zero_qu:  # Q = U = 0's q, u; its hits and rcond are the sky's (the same c, s sums)
        q0, u0 = np.empty((2, pix.size))
    with numba_threads(nthreads):
        for s, chunk in _chunks(pix, chunk_pixels, progress, "simulate"):
            normal = binner.scan_normal(scan, nside, chunk, zero_qu)
            at = slice(s, s + chunk.size)
            if zero_qu:
                normal, normal0 = normal
                q0[at], u0[at] = (kernels.to_host(x) for x in solve(normal0, rcond_min)[:2])
            q[at], u[at], rcond[at], ncross[at] = _maps_from(
                kernels, normal, instrument.n_pairs, rcond_min
            )
    maps = Maps(nside, pix, q, u, ncross, rcond)
    return maps, Maps(nside, pix, q0, u0, ncross, rcond) if zero_qu else None


def _maps_from(kernels, normal, n_pairs, rcond_min):
    """(q, u, rcond, hits) host arrays from normal-equation sums, solved where they lie.

    c^2 + s^2 = 1 for every (sample, pair): the trace of each 2x2 system counts its samples.
    """
    hits = np.rint((normal[:, 0] + normal[:, 2]) / n_pairs).astype(np.int64)
    return tuple(kernels.to_host(x) for x in solve(normal, rcond_min) + (hits,))


def _check_mapmaker(mapmaker, backend):
    check_mapmaker(mapmaker)
    if mapmaker != "pairs" and backend != "cpu":
        raise ValueError(f"mapmaker {mapmaker!r} (a 3x3 system) runs on the CPU backend only")


def _normal(kernels, nside, mapmaker):
    """The full-sky normal-equation sums a stream's map-maker fills: (npix, 5) or (npix, 9)."""
    return kernels.zeros((12 * nside**2, 5 if mapmaker == "pairs" else 9))


def _stream_maps(kernels, nside, normal, mapmaker, *, n_pairs, rcond_min):
    """Maps on the observed pixels from a stream's full-sky sums (:func:`_normal`); hits count
    pair-samples whichever the map-maker."""
    if mapmaker == "pairs":
        q, u, rcond, hits = _maps_from(kernels, normal, n_pairs, rcond_min)
        seen = np.flatnonzero(hits)
        return Maps(nside, seen, q[seen], u[seen], hits[seen], rcond[seen])
    seen = np.flatnonzero(normal[:, 0])
    i, q, u, rcond = solve_iqu(normal[seen], rcond_min)
    per_pair_sample = n_pairs * (2 if mapmaker == "detectors" else 1)  # "single", "pairs-spin0": 1
    hits = np.rint(normal[seen, 0] / per_pair_sample).astype(np.int64)
    return Maps(nside, seen, q, u, hits, rcond, i_obs=i)


class _Binner:
    """Sky evaluation, detector-B pointing and pair-difference binning of one chunk of hits
    grouped by pixel: the part of the hot loop shared by synthetic scans and real sample streams."""

    def __init__(
        self, sky, instrument, systematics, rotations, evaluation, leak_template, nthreads, backend
    ):
        if evaluation not in ENGINE_METHODS:
            raise ValueError(f"evaluation must be one of {ENGINE_METHODS}, got {evaluation!r}")
        self.kernels = get_backend(backend)
        params = systematics.per_pair(instrument.n_pairs)
        self.rho, self.chi, self.leak, self.jitter = (
            params.rho,
            params.chi,
            params.leak,
            params.dg_jitter,
        )
        self.pointing = systematics.has_pointing
        self.beams = None
        if systematics.has_beams:
            self.pair_beams = pair_beams(params, sky.fwhm_arcmin * ARCMIN)
            self.beams = BeamConvolver(sky.alm, sky.fwhm_arcmin * ARCMIN, nthreads)
            self.angle_a, angle_b = params.angle_errors()
            self.angle_b = angle_b + 0.5 * np.pi
        self.fields = _sky_fields(sky, systematics, leak_template, evaluation, nthreads)
        # added systematics (boresight.instrument.added): each with its amplitudes and its field
        self.added = tuple(
            (one, amplitude, np.asarray(one.field(sky), dtype=np.float64))
            for one, amplitude in systematics.added_per_pair(instrument.n_pairs)
        )
        self.rot, self.ang = np.asarray(rotations, dtype=np.float64), instrument.pair_angles_rad
        self.response = response(self.rot, self.ang, params, systematics.per_repeat(self.rot.size))
        self.stack = self.kernels.to_device(self.fields.stack) if evaluation == "interp" else None
        self.evaluation, self.nthreads = evaluation, nthreads

    def _at(self, theta, phi):
        """The fields at points: the backend interpolates the stack on its device, ducc0
        evaluates the alm exactly on the CPU, or the maps' values in the points' pixels."""
        k = self.kernels
        if self.evaluation == "interp":
            return k.interpolate(self.stack, self.fields.nside, theta, phi)
        theta, phi = k.to_host(theta), k.to_host(phi)
        if self.evaluation == "pixel":
            return k.to_device(self.fields.in_pixel(ang2pix_array(self.fields.nside, theta, phi)))
        return self.fields.exact(theta, phi, self.nthreads)

    def _extra(self, theta, phi, psi, own_psi=None):
        """(2, H, K, M) extra signal of detectors A and B beyond the sky (their beams, the added
        systematics), or (2, 0, K, M) with neither."""
        out = self._beam_terms(theta, phi, psi, own_psi)
        if not self.added:
            return out
        k = self.kernels
        theta, phi, psi = k.to_host(theta), k.to_host(phi), k.to_host(psi)
        if out.shape[1] == 0:
            out = np.zeros((2, theta.size, self.rot.size, self.ang.size))
        for one, amplitude, field in self.added:
            out += one.signal(
                amplitude, field, theta, phi, psi, rotations=self.rot, angles=self.ang
            )
        return out

    def _beam_terms(self, theta, phi, psi, own_psi=None):
        """(2, H, K, M) extra signal of detectors A and B from their own beams, or (2, 0, K, M).
        ``own_psi``, behind a HWP: the pairs' own crossing angle, which turns the beams' shapes
        and B's offset, where ``psi`` (the reflected one) turns their polarisation
        (:meth:`boresight.instrument.beams.BeamConvolver.behind_hwp`; detectors at their nominal angles)."""
        k = self.kernels
        out = np.zeros((2, 0 if self.beams is None else theta.size, self.rot.size, self.ang.size))
        if self.beams is None:
            return out
        theta, phi, psi = k.to_host(theta), k.to_host(phi), k.to_host(psi)
        own = psi if own_psi is None else k.to_host(own_psi)
        if self.pointing:
            tb, pb = (
                k.to_host(x)
                for x in k.offset_points(theta, phi, own, self.rot, self.ang, self.rho, self.chi)
            )
        else:
            tb = np.broadcast_to(theta[:, None, None], out.shape[1:])
            pb = np.broadcast_to(phi[:, None, None], out.shape[1:])
        ta = np.broadcast_to(theta[:, None], out.shape[1:3]).ravel()
        pa = np.broadcast_to(phi[:, None], out.shape[1:3]).ravel()
        angle, shape = psi[:, None] + self.rot[None, :], own[:, None] + self.rot[None, :]
        for m, beams in enumerate(self.pair_beams):
            points = ((ta, pa), (np.ravel(tb[:, :, m]), np.ravel(pb[:, :, m])))
            for x, (beam, offset) in enumerate(zip(beams, (self.angle_a[m], self.angle_b[m]))):
                polarisation = (angle + self.ang[m] + offset).ravel()
                if own_psi is None:
                    value = self.beams.extra(beam, *points[x], polarisation)
                else:
                    turn = (shape + self.ang[m] + 0.5 * np.pi * x).ravel()
                    value = self.beams.behind_hwp(
                        beam, *points[x], shape=turn, delta=polarisation - turn
                    )
                out[x, :, :, m] = value.reshape(angle.shape)
        return out

    def _values(self, theta, phi, psi):
        return pair_fields(
            self._at,
            self.kernels.offset_points,
            self.fields.n_fields,
            theta,
            phi,
            psi,
            self.rot,
            self.ang,
            self.rho,
            self.chi,
            self.pointing,
        )

    def scan_normal(self, scan, nside, chunk, zero_qu=False):
        """(npix_chunk, 5) normal-equation sums of a synthetic scan over a chunk of pixels, on the
        backend's device: the backend's bin_scan for an interpolated sky and the sky's beam, else
        hits -> sky (and beams) at both detectors -> accumulate. With ``zero_qu``, a pair of them:
        also those of the same hits with the sky's Q = U = 0."""
        if self.evaluation == "interp" and self.beams is None and not self.added:
            n_phi, rng_rad, centre = scan.per_pixel(chunk, 12 * nside**2)
            return self.kernels.bin_scan(
                scan.seed,
                nside,
                chunk,
                n_phi,
                rng_rad,
                centre,
                scan.in_pixel == "centre",
                self.stack,
                self.rot,
                self.ang,
                self.response,
                self.rho,
                self.chi,
                self.leak,
                self.jitter,
                self.pointing,
                zero_qu,
            )
        offsets, theta, phi, psi = _hits(self.kernels, scan, nside, chunk)
        values_a, values_b = self._values(theta, phi, psi)
        beams = self._extra(theta, phi, psi)

        def sums(a, b):
            k = self.kernels
            return k.accumulate(
                offsets, psi, a, b, beams, self.response, self.leak, self.jitter, scan.seed, chunk
            )

        return sums_with_zero_qu(sums, values_a, values_b, zero_qu)

    def differences(self, theta, phi, psi, seed, first):
        """(c, s, d), each (M, H): every sample's map-maker weights and pair difference per pair,
        for a filter to act on (:func:`boresight.kernels.cpu.pair_differences`); CPU only."""
        values_a, values_b = self._values(theta, phi, psi)
        beams = self._extra(theta, phi, psi)
        args = (psi, values_a, values_b, beams, self.response, self.leak, self.jitter)
        return pair_differences(*args, seed, first)

    def templates(self, deprojection, theta, phi, psi, alm=None):
        """(T, H) templates of one pointing stream (:meth:`boresight.mitigation.Deprojection.
        templates_at`): T as this binner reads it, its derivatives exactly; or, given a template
        map's ``alm``, its T and derivatives exactly."""
        if alm is None:
            alm, value = self.fields.alm[0], self.kernels.to_host(self._at(theta, phi))[0]
        else:
            value = harmonics.evaluate(alm, theta, phi, nthreads=self.nthreads)
        return deprojection.templates_at(alm, value, theta, phi, psi, nthreads=self.nthreads)

    def for_pair(self, i):
        """This binner for pair i alone: its angle and its own drawn parameters."""
        one = copy.copy(self)
        keep = slice(i, i + 1)
        one.ang, one.rho, one.chi = self.ang[keep], self.rho[keep], self.chi[keep]
        one.leak, one.jitter = self.leak[keep], self.jitter[keep]
        one.added = tuple((s, amplitude[keep], field) for s, amplitude, field in self.added)
        one.response = np.ascontiguousarray(self.response[:, keep])
        if self.beams is not None:
            one.pair_beams = self.pair_beams[keep]
            one.angle_a, one.angle_b = self.angle_a[keep], self.angle_b[keep]
        return one

    def scatter(
        self,
        pixels,
        theta,
        phi,
        psi,
        normal,
        seed,
        first,
        *,
        mapmaker="pairs",
        seen=None,
        own_psi=None,
    ):
        """Add the normal-equation sums of hits in any order into the full-sky ``normal`` as
        ``mapmaker`` bins them (:data:`boresight.mapmaking.MAPMAKERS`, :func:`_normal`); the jitter of hit h is keyed
        by (seed, first + h). ``seen``, if given, maps the fields at the hits to what the pair
        sees there (a HWP's own signals, :func:`boresight.instrument.hwp.plate_signals`).
        ``own_psi``, if given, is the angle detector B's offset and the beams' shapes turn
        with, where ``psi`` is another (behind a HWP, the pair's own crossing angle beside its
        reflected one)."""
        values_a, values_b = self._values(theta, phi, psi if own_psi is None else own_psi)
        if seen is not None:
            values_a = seen(self.kernels.to_host(values_a))
        beams = self._extra(theta, phi, psi, own_psi)
        args = (pixels, psi, values_a, values_b, beams, self.response, self.leak, self.jitter)
        if mapmaker == "pairs":
            self.kernels.accumulate_scatter(*args, seed, first, normal)
        else:
            accumulate_detectors(*args, seed, first, normal, mapmaker=mapmaker)


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
    _check_mapmaker(mapmaker, backend)
    binner = _Binner(
        sky, instrument, systematics, (0.0,), evaluation, leak_template, nthreads, backend
    )
    normal = _normal(binner.kernels, sky.nside, mapmaker)
    first = 0  # the stream index of each chunk's first sample: the key of its jitter draws
    with numba_threads(nthreads):
        for chunk in sample_chunks:
            interrupts.check()
            theta, phi, psi = check_samples(*chunk)
            pix = ang2pix_array(sky.nside, theta, phi)
            binner.scatter(pix, theta, phi, psi, normal, systematics.seed, first, mapmaker=mapmaker)
            first += pix.size
    return _stream_maps(
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
    cleaning = _Cleaning(filtering, sky, schedule.frame)
    cleaning.check(schedule, backend, mapmaker, evaluation)
    binner = _Binner(
        sky, instrument, systematics, (0.0,), evaluation, leak_template, nthreads, backend
    )
    normal = _normal(binner.kernels, sky.nside, mapmaker)
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
                c, s, d = binner.differences(theta, phi, psi, systematics.seed, first)
                parts.append(cleaning.part(d, binner, theta, phi, psi, scan, schedule, sky.nside))
                c_s.append((c, s))
                first += psi.size
                bar.update(psi.size)
            cleaning.bin_block(parts, c_s, normal, block)
    return _stream_maps(
        binner.kernels, sky.nside, normal, mapmaker, n_pairs=instrument.n_pairs, rcond_min=rcond_min
    )


class _Cleaning:
    """What a pipeline does to each CES's pair differences before binning: its filters, then its
    templates (filtered as the data are) regressed per block of CESs and subtracted.

    A block's cleaned parts are held until its last CES (one CES by default), then regressed and
    binned: memory is one block's samples, whatever the schedule's length."""

    def __init__(self, filtering, sky, frame):
        self.filtering, self.deprojection = filtering, filtering.deprojection
        self.alm = None  # the templates' T: the sky's own, or a template map's
        if self.deprojection.template_map is not None:
            self.alm = template_alm(
                self.deprojection.template_map,
                nside=sky.nside,
                lmax=harmonics.alm_lmax(sky.alm.shape[-1]),
                frame=frame,
            )

    def check(self, schedule, backend, mapmaker, evaluation, hwp=None):
        """Refuse, before any work, what the pipeline cannot run; every CES against the filters
        (its :class:`~boresight.mitigation.CesScan` kept for :meth:`blocks`)."""
        if backend != "cpu" or mapmaker != "pairs" or hwp is not None:
            raise ValueError(
                f"filtering ({self.filtering}) runs on the CPU backend with the pairs' "
                f"map-maker and no plate, not backend {backend!r}, mapmaker {mapmaker!r}"
                + ("" if hwp is None else ", a HWP")
            )
        if self.deprojection.derivatives and evaluation != "exact":
            raise ValueError(
                f"deprojecting {self.deprojection} fits derivatives of T, which the TOD follows "
                f"only with evaluation 'exact', not {evaluation!r} (interpolated or pixelised "
                "maps differ from their derivatives)"
            )
        self.scans = ces_scans(self.filtering, schedule)

    def blocks(self, schedule):
        """(its name, [(a schedule of one CES of one repeat, its CesScan), ...]) per block of the
        deprojection (:meth:`boresight.mitigation.Deprojection.blocks`), in observing order,
        after :meth:`check`."""
        scans = self.scans
        for repeat in schedule.repeat_boresight_deg:
            for name, members in self.deprojection.blocks(schedule.ces):
                one = [
                    (
                        replace(
                            schedule,
                            ces=(schedule.ces[i],),
                            repeat_boresight_deg=(repeat,),
                            turnarounds="include",
                        ),
                        scans[i],
                    )
                    for i in members
                ]
                yield f"{name} at boresight {repeat:g} deg", one

    def part(self, d, binner, theta, phi, psi, scan, schedule, nside):
        """One CES's pair differences d (M, H) of one pointing stream, filtered, with what its
        block's regression and binning need."""
        if self.filtering.filters:
            d = self.filtering.apply(d, scan)
        templates = None
        if self.deprojection:
            templates = binner.templates(self.deprojection, theta, phi, psi, self.alm)
            if self.filtering.filters:
                templates = self.filtering.apply(templates, scan)
        keep = np.ones(d.shape[1], bool) if schedule.turnarounds == "include" else ~scan.turning
        pix = ang2pix_array(nside, theta[keep], phi[keep])
        return d, templates, ~scan.turning, keep, pix

    def bin_block(self, parts, c_s, normal, block):
        """A block's parts (:meth:`part`) and their weights (c, s) regressed together and binned
        into ``normal`` (a block of one CES without a copy)."""

        def joined(items, axis):
            return items[0] if len(items) == 1 else np.concatenate(items, axis=axis)

        d = joined([p[0] for p in parts], 1)
        if self.deprojection:
            templates = joined([p[1] for p in parts], -1)
            fit = joined([p[2] for p in parts], 0)
            d = self.deprojection.apply(d, templates, fit, block=block)
        keep = joined([p[3] for p in parts], 0)
        pix = joined([p[4] for p in parts], 0)
        c, s = (joined([x[k] for x in c_s], 1) for k in (0, 1))
        bin_differences(pix, c[:, keep], s[:, keep], d[:, keep], normal)


def simulate_focalplane(
    sky: Sky,
    schedule: Schedule,
    focalplane: FocalPlane,
    systematics: Systematics = Systematics(),
    *,
    evaluation: str = "interp",
    leak_template: np.ndarray | None = None,
    nthreads: int = 0,
    backend: str = "cpu",
    rcond_min: float = RCOND_MIN,
    chunk_samples: int = 1 << 20,
    hwp: HWP | None = None,
    mapmaker: str = "pairs",
    filtering: Filtering = Filtering(),
    progress: bool = False,
) -> Maps:
    """Maps from every pair of a focal plane on a schedule, each pair on its own samples
    (:func:`boresight.pointing.detector_pointing`), all binned into one map as the map-maker
    combines them.

    Behind a HWP each pair's pair difference is that of a bare pair at its reflected angle
    (:func:`boresight.instrument.hwp.reflected`), and the map-maker solves with that angle: exact for the
    sky and for what the pairs carry through the HWP (:data:`boresight.instrument.hwp.THROUGH_HWP`).

    Pair i has the focal plane's angle and the systematics' i-th draw (as pair i of
    ``Instrument(pair_angles_deg=focalplane.pair_angles_deg)``); the gain jitter of its sample k
    is keyed by (seed, i x samples + k), and a HWP angle's jitter at sample k by (seed, k) for
    every pair, so nothing depends on the chunks.

    Parameters
    ----------
    sky : boresight.sky.Sky
    schedule : boresight.schedule.Schedule
    focalplane : boresight.instrument.focalplane.FocalPlane
    systematics : boresight.instrument.pairs.Systematics
    evaluation, leak_template, nthreads, rcond_min, mapmaker
        As in :func:`simulate_samples`.
    backend : {"cpu"}
        The GPU backend does not take a focal plane yet.
    chunk_samples : int
        Pair-samples per chunk of pointing.
    hwp : boresight.instrument.hwp.HWP, optional
        A continuous or stepped HWP in front of every pair, with its own signals
        (:func:`boresight.instrument.hwp.plate_signals`) and angle offset (:func:`boresight.instrument.hwp.reflected_systematics`).
    filtering : boresight.mitigation.Filtering
        Each pair's pair differences filtered CES by CES before binning, as in
        :func:`simulate_schedule` (the throws and azimuth the boresight's): the pairs' map-maker,
        no plate. Pair i's sample k keeps its gain jitter's key (seed, i x samples + k). Each
        pair's templates are its own (its pointing and angle).
    progress : bool

    Returns
    -------
    boresight.mapmaking.Maps
        Hits count pair-samples; the (I, Q, U) map-makers give ``i`` as well.
    """
    if backend != "cpu":
        raise ValueError(f"backend {backend!r}: a focal plane's TOD runs on the CPU backend only")
    cleaning = _Cleaning(filtering, sky, schedule.frame)
    if filtering:
        cleaning.check(schedule, backend, mapmaker, evaluation, hwp)
    if hwp is not None:
        systematics = reflected_systematics(hwp, systematics, own_angles=True)
    _check_mapmaker(mapmaker, backend)
    gammas = np.radians(focalplane.gamma_deg)
    instrument = Instrument(pair_angles_deg=focalplane.pair_angles_deg)
    binner = _Binner(
        sky, instrument, systematics, (0.0,), evaluation, leak_template, nthreads, backend
    )
    pairs = [binner.for_pair(i) for i in range(focalplane.n_pairs)]
    normal = _normal(binner.kernels, sky.nside, mapmaker)
    first = 0
    total = schedule.n_samples * focalplane.n_pairs
    if filtering:
        with (
            numba_threads(nthreads),
            tqdm(total=total, unit="sample", unit_scale=True, disable=not progress) as bar,
        ):
            for block, members in cleaning.blocks(schedule):
                parts = [[] for _ in pairs]
                c_s = [[] for _ in pairs]
                for one, scan in members:
                    chunks = list(detector_pointing(one, focalplane, chunk_samples))
                    theta, phi, psi = (np.concatenate(x, axis=1) for x in zip(*chunks))
                    for i, pair in enumerate(pairs):
                        interrupts.check()
                        key = i * schedule.n_samples + first
                        c, s, d = pair.differences(theta[i], phi[i], psi[i], systematics.seed, key)
                        parts[i].append(
                            cleaning.part(
                                d, pair, theta[i], phi[i], psi[i], scan, schedule, sky.nside
                            )
                        )
                        c_s[i].append((c, s))
                    first += theta.shape[1]
                    bar.update(theta.size)
                for i in range(len(pairs)):
                    cleaning.bin_block(parts[i], c_s[i], normal, f"pair {i}, {block}")
        return _stream_maps(
            binner.kernels, sky.nside, normal, mapmaker, n_pairs=1, rcond_min=rcond_min
        )
    with (
        numba_threads(nthreads),
        tqdm(total=total, unit="sample", unit_scale=True, disable=not progress) as bar,
    ):
        for theta, phi, psi, *chi in detector_pointing(
            schedule, focalplane, chunk_samples, hwp=hwp
        ):
            jitter = None
            if chi and hwp.angle_jitter_deg:  # the plate's, one per sample for every pair
                jitter = angle_jitter(hwp, systematics.seed, first, theta.shape[1])
            for i, one in enumerate(pairs):
                interrupts.check()
                pix = ang2pix_array(sky.nside, theta[i], phi[i])
                key = i * schedule.n_samples + first
                angle = reflected(psi[i], chi[0], gammas[i]) if chi else psi[i]
                seen = None
                if chi and hwp.has_signals:
                    seen = functools.partial(
                        plate_signals, hwp, psi=psi[i], chi=chi[0], gamma=gammas[i], jitter=jitter
                    )
                one.scatter(
                    pix,
                    theta[i],
                    phi[i],
                    angle,
                    normal,
                    systematics.seed,
                    key,
                    mapmaker=mapmaker,
                    seen=seen,
                    own_psi=psi[i] if chi else None,
                )
            first += theta.shape[1]
            bar.update(theta.size)
    return _stream_maps(binner.kernels, sky.nside, normal, mapmaker, n_pairs=1, rcond_min=rcond_min)


def _sky_fields(sky, systematics, template, evaluation, nthreads):
    if not systematics.has_leak:
        return SkyFields(sky)
    if template is None:
        return SkyFields(sky, sky.maps[0], sky.alm[0])
    template = np.asarray(template, dtype=np.float64)
    if template.shape != (12 * sky.nside**2,):
        raise ValueError(
            f"leak_template must be a map of {12 * sky.nside**2} pixels, got shape {template.shape}"
        )
    if not np.isfinite(template).all():
        raise ValueError("leak_template contains NaN or infinite values")
    alm = (
        harmonics.map2alm(template, sky.lmax, spin=0, analysis="jacobi", nthreads=nthreads)
        if evaluation == "exact"
        else None
    )
    return SkyFields(sky, template, alm)


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
        to 6e-8 in half the memory (:func:`boresight.jobs.residual.compute_moments`).

    Returns
    -------
    h : numpy.ndarray, ``dtype``, shape (n_max + 1, npix)
        h_n per pixel, 0 where unobserved.
    crossings : numpy.ndarray, int64, shape (npix,)
        Hits per pixel times the number of rotations.
    """
    kernels = get_backend(backend)
    _check_nside(nside)
    integer("n_max", n_max, 0, 64)
    npix = 12 * nside**2
    pix = _pixel_list(pixels, npix)
    chunk_pixels = DEFAULT_CHUNK_PIXELS[backend] if chunk_pixels is None else chunk_pixels
    if np.dtype(dtype) not in (np.complex128, np.complex64):
        raise ValueError(f"dtype must be complex128 or complex64, got {dtype}")
    h = np.zeros((n_max + 1, npix), dtype=dtype)
    ncross = np.zeros(npix, dtype=np.int64)
    with numba_threads(nthreads):
        for _, chunk in _chunks(pix, chunk_pixels, progress, "scan moments"):
            offsets, _, _, psi = _hits(kernels, scan, nside, chunk)
            h[:, chunk] = kernels.to_host(
                kernels.moments(offsets, psi, scan.rotations_rad, n_max)
            ).T
            ncross[chunk] = np.diff(kernels.to_host(offsets)) * len(scan.rotations_deg)
    return h, ncross
