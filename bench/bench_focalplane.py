"""Focal-plane throughput: detector-samples per second of pointing every pair from its own place
and binning its hits and h_n (n = 0..4), against TOAST 3's chain for the same detectors on the
same schedule: SimGround + PointingDetectorSimple + PixelsHealpix, then the per-detector binning
of sotodlib's Hn (numpy's bincount of exp(i n psi)). Like for like: one core each (numba's
threads and TOAST's OpenMP at 1), boresight also on every core. Then the scale target: 1,094
detectors (TOAST's 547-pixel hexagon) over a day at 20 Hz.

A detector-sample is one detector's sample; a pair's two detectors share their pointing, which
boresight computes once and TOAST twice.

Usage: python bench/bench_focalplane.py [NSIDE]
"""

import dataclasses
import os
import sys
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")  # TOAST's kernels on one core, set before import

import numba
import numpy as np
from _table import report
from bench_ground import CES as DAY

from boresight import moments
from boresight.instrument import focalplane
from boresight.pointing import ces_chunks
from boresight.schedule import Schedule
from boresight.schedule import toast as toast_files

RATE = 20.0
#: bench_ground's day of 24 CESs, the boresight stepping 0, 45, 90 deg from CES to CES
CES_DAY = tuple(dataclasses.replace(c, boresight_deg=45.0 * (i % 3)) for i, c in enumerate(DAY))


def _boresight(schedule, fp, nside, threads):
    numba.set_num_threads(threads)
    t0 = time.perf_counter()
    moments.characterise_focalplane(schedule, fp, nside)
    return time.perf_counter() - t0


def _pointing_only(schedule, fp, nside):
    """Seconds of the pointing alone, on one core: every pair's pixel, crossing angle and angle
    bin per sample (moments.ces_hits_pairs), nothing binned."""
    numba.set_num_threads(1)
    vectors = np.ascontiguousarray(fp.vectors())
    gammas, none = np.radians(fp.gamma_deg), np.zeros(0)
    nbins = 360  # characterise_focalplane's bins at its default tolerance of 1 deg
    t0 = time.perf_counter()
    for _, _, args in ces_chunks(schedule, (1 << 20) // fp.n_pairs):
        moments.ces_hits_pairs(*args, nside, nbins, False, vectors, none, gammas)
    return time.perf_counter() - t0


def _toast(schedule, n_pix, nside):
    """Seconds of TOAST's chain over the schedule for its n_pix hexagon, and its detectors."""
    import toast as toast_
    import toast.ops
    from astropy import units as u
    from toast import qarray
    from toast.instrument import GroundSite, Telescope
    from toast.instrument_sim import fake_hexagon_focalplane
    from toast.schedule import GroundSchedule

    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "schedule.txt")
        toast_files.write(schedule, path)
        theirs = GroundSchedule()
        theirs.read(path)
    fp = fake_hexagon_focalplane(n_pix=n_pix, width=35 * u.deg, sample_rate=RATE * u.Hz)
    site = GroundSite(theirs.site_name, theirs.site_lat, theirs.site_lon, theirs.site_alt)
    t0 = time.perf_counter()
    data = toast_.Data(toast_.mpi.Comm())
    toast_.ops.SimGround(
        telescope=Telescope("sat", focalplane=fp, site=site), schedule=theirs
    ).apply(data)
    detector = toast_.ops.PointingDetectorSimple()
    toast_.ops.PixelsHealpix(nside=nside, detector_pointing=detector).apply(data)
    npix = 12 * nside**2
    hits, sums = np.zeros(npix), np.zeros((5, npix), complex)
    samples = 0
    for ob in data.obs:
        for det in ob.local_detectors:
            pix = np.asarray(ob.detdata["pixels"][det])
            _, _, psi = qarray.to_iso_angles(ob.detdata["quats"][det])
            psi = psi - fp[det]["pol_angle"].to_value(u.rad)
            hits += np.bincount(pix, minlength=npix)
            for n in range(5):
                w = np.exp(1j * n * psi)
                sums[n] += np.bincount(pix, w.real, npix) + 1j * np.bincount(pix, w.imag, npix)
            samples += pix.size
    return time.perf_counter() - t0, samples


def _row(code, detectors, samples, seconds, cores=1):
    return dict(
        code=code,
        detectors=detectors,
        detector_samples=samples,
        seconds=seconds,
        per_core_per_s=samples / seconds / cores,
    )


def main(nside):
    cores = numba.get_num_threads()
    short = Schedule(CES_DAY[:2], sample_rate_hz=RATE)
    fp = focalplane.hexagon(37, 35.0)
    detectors = 2 * fp.n_pairs
    _boresight(Schedule(CES_DAY[:1], sample_rate_hz=1.0), fp, nside, cores)  # compile
    n_det = short.n_samples * detectors
    rows = [
        _row(f"boresight, {n} core{'s' * (n > 1)}", detectors, n_det, t, n)
        for n in (1, cores)
        for t in (_boresight(short, fp, nside, n),)
    ]
    t = _pointing_only(short, fp, nside)
    rows.append(_row("boresight, 1 core: the pointing alone", detectors, n_det, t))
    try:
        t_toast, samples = _toast(short, 37, nside)
    except ImportError:
        t_toast = samples = None
    if t_toast is not None:
        rows.append(_row("TOAST 3, 1 core", detectors, samples, t_toast))
        for row in rows[:-1]:
            row["ratio_to_toast"] = row["per_core_per_s"] / rows[-1]["per_core_per_s"]
    big = focalplane.hexagon(547, 35.0)
    day = Schedule(CES_DAY, sample_rate_hz=RATE)
    t = _boresight(day, big, nside, cores)
    n_big = day.n_samples * 2 * big.n_pairs
    rows.append(_row(f"boresight, {cores} cores: a day", 2 * big.n_pairs, n_big, t, cores))
    if t_toast is not None:  # TOAST's per-core rate of the short run: a day of it would take 10 min
        rows[-1]["ratio_to_toast"] = rows[-1]["per_core_per_s"] / (samples / t_toast)
    report(
        "focalplane",
        f"Focal-plane pointing + binning of hits and h_n, Nside {nside}, {RATE:g} Hz",
        ["code", "detectors", "detector_samples", "seconds", "per_core_per_s", "ratio_to_toast"],
        rows,
        notes=(
            "Two CESs of 55 min for TOAST's 37-pixel, 35 deg hexagon; then a day of 24 CESs for "
            "its 547-pixel hexagon. TOAST: SimGround (pyephem), PointingDetectorSimple, "
            "PixelsHealpix and numpy binning as sotodlib's Hn, OMP_NUM_THREADS=1. boresight: "
            "moments.characterise_focalplane (hits, h_n, crossing-angle bitmaps and the "
            "scattered sums), pointing computed once per pair; the pointing alone: each pair's "
            "pixel, crossing angle and angle bin per sample (moments.ces_hits_pairs), the "
            "floor of the whole."
        ),
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 64)
