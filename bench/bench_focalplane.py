"""Focal-plane throughput, honestly counted: CPU seconds of pointing every pair from its own
place and binning its hits and h_n (n = 0..4), against TOAST 3's operators for the same detectors
on the same schedule (SimGround; PointingDetectorSimple + PixelsHealpix) and against those plus a
per-detector binning of h_n as sotodlib's ``Hn`` does it (numpy's bincount of exp(i n psi);
sotodlib's own ``Hn`` does not run on TOAST 3.0.6's fake focal plane, whose noise model is in K
where Hn's cos/sin streams are unitless). One core each (numba's threads and TOAST's OpenMP at
1), each code's runs alternated with the others' REPEATS times in this one process and the least
CPU seconds kept; then boresight on every core, and the scale target: 1,094 detectors (TOAST's
547-pixel hexagon) over a day at 20 Hz.

Two rates, stated apart: per detector-sample (what a user gets: a pair's two detectors count
twice) and per pointing computed (boresight computes a pair's pointing once, TOAST each
detector's).

Usage: python bench/bench_focalplane.py [NSIDE] [REPEATS]
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


def _cpu(function, *args):
    """(CPU seconds of this process, wall seconds) of ``function(*args)``."""
    c0, t0 = time.process_time(), time.perf_counter()
    function(*args)
    return time.process_time() - c0, time.perf_counter() - t0


def _boresight(schedule, fp, nside, threads):
    numba.set_num_threads(threads)
    return _cpu(moments.characterise_focalplane, schedule, fp, nside)


def _pointing_only(schedule, fp, nside):
    """Seconds of the pointing alone, on one core: every pair's pixel, crossing angle and angle
    bin per sample (moments.ces_hits_pairs), nothing binned."""
    numba.set_num_threads(1)
    vectors = np.ascontiguousarray(fp.vectors())
    gammas, none = np.radians(fp.gamma_deg), np.zeros(0)
    nbins = 360  # characterise_focalplane's bins at its default tolerance of 1 deg

    def run():
        for _, _, args in ces_chunks(schedule, (1 << 20) // fp.n_pairs):
            moments.ces_hits_pairs(*args, nside, nbins, False, vectors, none, gammas)

    return _cpu(run)[0]


def _toast(schedule, n_pix, nside):
    """CPU seconds of each part of TOAST's chain over the schedule for its n_pix hexagon, and
    its detector-samples."""
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
    data = toast_.Data(toast_.mpi.Comm())
    sim = toast_.ops.SimGround(
        telescope=Telescope("sat", focalplane=fp, site=site), schedule=theirs
    )
    parts = {"SimGround": _cpu(sim.apply, data)[0]}
    detector = toast_.ops.PointingDetectorSimple()
    pixels = toast_.ops.PixelsHealpix(nside=nside, detector_pointing=detector)
    parts["PointingDetectorSimple + PixelsHealpix"] = _cpu(pixels.apply, data)[0]
    npix = 12 * nside**2
    hits, sums = np.zeros(npix), np.zeros((5, npix), complex)
    samples = 0

    def binning():
        nonlocal samples
        for ob in data.obs:
            for det in ob.local_detectors:
                pix = np.asarray(ob.detdata["pixels"][det])
                _, _, psi = qarray.to_iso_angles(ob.detdata["quats"][det])
                psi = psi - fp[det]["pol_angle"].to_value(u.rad)
                hits[:] += np.bincount(pix, minlength=npix)
                for n in range(5):
                    w = np.exp(1j * n * psi)
                    sums[n] += np.bincount(pix, w.real, npix) + 1j * np.bincount(pix, w.imag, npix)
                samples += pix.size

    parts["h_n binned as sotodlib's Hn (numpy)"] = _cpu(binning)[0]
    return parts, samples


def _row(code, detectors, samples, pointings, cpu, vs=None, *, wall=None):
    return {
        "code": code,
        "detectors": detectors,
        "detector-samples": f"{samples:.3g}",
        "pointings computed": f"{pointings:.3g}",
        "CPU [s]": f"{cpu:.2f}",
        "wall [s]": "" if wall is None else f"{wall:.2f}",
        "detector-samples / CPU-s": f"{samples / cpu:.3g}",
        "pointings / CPU-s": f"{pointings / cpu:.3g}",
        "boresight's rate / this": "" if vs is None else f"{vs:.2f}",
    }


def main(nside, repeats):
    cores = numba.get_num_threads()
    short = Schedule(CES_DAY[:2], sample_rate_hz=RATE)
    fp = focalplane.hexagon(37, 35.0)
    detectors = 2 * fp.n_pairs
    _boresight(Schedule(CES_DAY[:1], sample_rate_hz=1.0), fp, nside, cores)  # compile
    _pointing_only(Schedule(CES_DAY[:1], sample_rate_hz=1.0), fp, nside)
    best = {}
    samples = None

    def keep(name, cpu):
        best[name] = min(best.get(name, float("inf")), cpu)

    for _ in range(repeats):  # alternated: a load on the machine falls on every code alike
        keep("boresight", _boresight(short, fp, nside, 1)[0])
        keep("pointing", _pointing_only(short, fp, nside))
        try:
            parts, samples = _toast(short, 37, nside)
        except ImportError:
            continue
        for name, cpu in parts.items():
            keep(name, cpu)
    n_det, n_pairs = short.n_samples * detectors, short.n_samples * fp.n_pairs
    whole, pointing = n_det / best["boresight"], n_pairs / best["pointing"]
    rows = [
        _row("boresight, 1 core: pointing + binning", detectors, n_det, n_pairs, best["boresight"]),
        _row("boresight, 1 core: the pointing alone", detectors, n_det, n_pairs, best["pointing"]),
    ]
    if samples is not None:
        toast_parts = [n for n in best if n not in ("boresight", "pointing")]
        simground, detector_pointing, binning = toast_parts
        for name in toast_parts:  # TOAST points each detector: its pointings are its samples
            vs = pointing / (samples / best[name]) if name == detector_pointing else None
            rows.append(
                _row(f"TOAST 3, 1 core: {name}", detectors, samples, samples, best[name], vs)
            )
        operators = best[simground] + best[detector_pointing]
        rows.append(
            _row("TOAST 3, 1 core: its operators", detectors, samples, samples, operators,
                 whole / (samples / operators))
        )  # fmt: skip
        chain = operators + best[binning]
        rows.append(
            _row("TOAST 3 + h_n binned, 1 core", detectors, samples, samples, chain,
                 whole / (samples / chain))
        )  # fmt: skip
    cpu, wall = _boresight(short, fp, nside, cores)
    rows.append(
        _row(f"boresight, {cores} cores: pointing + binning", detectors, n_det, n_pairs, cpu,
             wall=wall)
    )  # fmt: skip
    big = focalplane.hexagon(547, 35.0)
    day = Schedule(CES_DAY, sample_rate_hz=RATE)
    cpu, wall = _boresight(day, big, nside, cores)
    rows.append(
        _row(f"boresight, {cores} cores: a day of 547 pairs", 2 * big.n_pairs,
             day.n_samples * 2 * big.n_pairs, day.n_samples * big.n_pairs, cpu, wall=wall)
    )  # fmt: skip
    report(
        "focalplane",
        f"Focal-plane pointing + binning of hits and h_n, Nside {nside}, {RATE:g} Hz",
        list(rows[0]),
        rows,
        notes=(
            "Two CESs of 55 min for TOAST's 37-pixel, 35 deg hexagon; then a day of 24 CESs for "
            "its 547-pixel hexagon. CPU seconds of this process, the least of "
            f"{repeats} runs of each code alternated, one core each (OMP_NUM_THREADS=1, numba "
            "on 1 thread). TOAST: SimGround (pyephem; the boresight's pointing), "
            "PointingDetectorSimple + PixelsHealpix (each detector's pointing and pixel), and "
            "the bench's numpy binning of h_n as sotodlib's Hn. boresight: "
            "moments.characterise_focalplane (hits, h_n, crossing-angle bitmaps and the "
            "scattered sums), a pair's pointing computed once for its two detectors; the "
            "pointing alone: each pair's pixel, crossing angle and angle bin per sample "
            "(moments.ces_hits_pairs). The last column: boresight's whole per detector-sample "
            "over TOAST's operators (and over them plus the binning), and boresight's pointing "
            "alone per pointing computed over TOAST's detector pointing."
        ),
    )


if __name__ == "__main__":
    main(
        int(sys.argv[1]) if len(sys.argv) > 1 else 64,
        int(sys.argv[2]) if len(sys.argv) > 2 else 3,
    )
