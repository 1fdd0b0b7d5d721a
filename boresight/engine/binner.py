"""The engine's hot loop: one chunk of hits or samples through a kernel backend.

:class:`Binner` evaluates the sky (and the pairs' beams and added systematics) at each hit,
turns detector B by its pointing error, and bins the pair differences into per-pixel normal
equations; :func:`stream_maps` solves a stream's full-sky sums on the pixels it observed. The
synthetic scans, sample streams and focal planes (:mod:`boresight.engine.axis`,
:mod:`boresight.engine.focalplane`) all bin through it.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from .. import harmonics
from .._util import interrupts
from ..constants import ARCMIN
from ..evaluation import ENGINE_METHODS, SkyFields
from ..instrument.beams import BeamConvolver, pair_beams
from ..instrument.pairs import response
from ..kernels import get_backend

# CPU only (not of the contract): the 3x3 maps, and the pair differences a filter acts on
from ..kernels.cpu import accumulate_detectors, pair_differences, pair_samples
from ..kernels.fields import hit_offsets, pair_fields, sums_with_zero_qu
from ..kernels.pixels import ang2pix_array
from ..mapmaking import Maps, check_mapmaker, solve, solve_iqu
from ..sky import MAX_NSIDE

if TYPE_CHECKING:
    pass


DEFAULT_CHUNK_PIXELS = {"cpu": 1 << 16, "gpu": 1 << 22}


def pixel_list(pixels, npix):
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


def check_nside(nside):
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


def pixel_chunks(pixels, chunk_pixels, progress, label):
    if chunk_pixels < 1:
        raise ValueError(f"chunk_pixels must be >= 1, got {chunk_pixels}")
    starts = range(0, pixels.size, chunk_pixels)
    for s in tqdm(starts, desc=label, unit="chunk", disable=not progress, leave=False):
        interrupts.check()
        yield s, pixels[s : s + chunk_pixels]


def scan_hits(kernels, scan, nside, chunk):
    n_phi, rng_rad, centre = scan.per_pixel(chunk, 12 * nside**2)
    offsets = hit_offsets(n_phi)
    theta, phi, psi = kernels.generate_hits(
        scan.seed, nside, chunk, offsets, rng_rad, centre, scan.in_pixel == "centre"
    )
    return offsets, theta, phi, psi


def maps_from(kernels, normal, n_pairs, rcond_min):
    """(q, u, rcond, hits) host arrays from normal-equation sums, solved where they lie.

    c^2 + s^2 = 1 for every (sample, pair): the trace of each 2x2 system counts its samples.
    """
    hits = np.rint((normal[:, 0] + normal[:, 2]) / n_pairs).astype(np.int64)
    return tuple(kernels.to_host(x) for x in solve(normal, rcond_min) + (hits,))


def check_backend_mapmaker(mapmaker, backend):
    check_mapmaker(mapmaker)
    if mapmaker != "pairs" and backend != "cpu":
        raise ValueError(f"mapmaker {mapmaker!r} (a 3x3 system) runs on the CPU backend only")


def normal_sums(kernels, nside, mapmaker):
    """The full-sky normal-equation sums a stream's map-maker fills: (npix, 5) or (npix, 9)."""
    return kernels.zeros((12 * nside**2, 5 if mapmaker == "pairs" else 9))


def stream_maps(kernels, nside, normal, mapmaker, *, n_pairs, rcond_min):
    """Maps on the observed pixels from a stream's full-sky sums (:func:`normal_sums`); hits count
    pair-samples whichever the map-maker."""
    if mapmaker == "pairs":
        q, u, rcond, hits = maps_from(kernels, normal, n_pairs, rcond_min)
        seen = np.flatnonzero(hits)
        return Maps(nside, seen, q[seen], u[seen], hits[seen], rcond[seen])
    seen = np.flatnonzero(normal[:, 0])
    i, q, u, rcond = solve_iqu(normal[seen], rcond_min)
    per_pair_sample = n_pairs * (2 if mapmaker == "detectors" else 1)  # "single", "pairs-spin0": 1
    hits = np.rint(normal[seen, 0] / per_pair_sample).astype(np.int64)
    return Maps(nside, seen, q, u, hits, rcond, i_obs=i)


class Binner:
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
        offsets, theta, phi, psi = scan_hits(self.kernels, scan, nside, chunk)
        values_a, values_b = self._values(theta, phi, psi)
        beams = self._extra(theta, phi, psi)

        def sums(a, b):
            k = self.kernels
            return k.accumulate(
                offsets, psi, a, b, beams, self.response, self.leak, self.jitter, scan.seed, chunk
            )

        return sums_with_zero_qu(sums, values_a, values_b, zero_qu)

    def differences(self, theta, phi, psi, *, seed, first, detectors=False):
        """(c, s, d), each (M, H): every sample's map-maker weights and pair difference per pair,
        for a filter to act on (:func:`boresight.kernels.cpu.pair_differences`); with
        ``detectors``, d (2M, H) is detector A's samples of every pair, then B's
        (:func:`boresight.kernels.cpu.pair_samples`), for the detectors' map-maker. CPU only."""
        values_a, values_b = self._values(theta, phi, psi)
        beams = self._extra(theta, phi, psi)
        args = (psi, values_a, values_b, beams, self.response, self.leak, self.jitter)
        return (pair_samples if detectors else pair_differences)(*args, seed, first)

    def templates(self, deprojection, theta, phi, psi, *, alm=None):
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
        *,
        seed,
        first,
        mapmaker="pairs",
        seen=None,
        own_psi=None,
    ):
        """Add the normal-equation sums of hits in any order into the full-sky ``normal`` as
        ``mapmaker`` bins them (:data:`boresight.mapmaking.MAPMAKERS`, :func:`normal_sums`); the jitter of hit h is keyed
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
