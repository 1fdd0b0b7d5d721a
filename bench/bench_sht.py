"""Spherical-harmonic transforms at the paper's size: ducc0 on the CPU against s2fft on a GPU.

The reproduction spends its time in map -> alm transforms of masked spin-2 maps (HEALPix: one
adjoint synthesis with ring weights at lmax <= 2 Nside, or 3 Jacobi iterations: 4 adjoint and 3
forward syntheses). This prints the time of one spin-0
and one spin-2 adjoint synthesis with ducc0 on all cores (and per map when 4 go in one call)
and, where s2fft and a JAX GPU are importable, with s2fft's recursion-based JAX transform in
float64 (first call, which compiles, and steady state), plus s2fft's spin-0 agreement with ducc0.
Usage: python bench/bench_sht.py [NSIDE [LMAX]]   (default 2048 4000)
"""

import os
import sys
import time

import ducc0
import healpy as hp
import numpy as np
from _table import report

from boresight import harmonics


def timed(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _row(name, spin, first, t):
    return dict(
        library=name, spin=spin, first_call_s=None if np.isnan(first) else first, steady_s=t
    )


def ducc0_rows(nside, lmax, maps):
    rows = []
    geom = harmonics.healpix_geometry(nside)
    for spin, m in ((0, maps[:1]), (2, maps[1:])):
        t, _ = timed(
            lambda m=m, spin=spin: ducc0.sht.adjoint_synthesis(
                map=m, lmax=lmax, spin=spin, nthreads=os.cpu_count(), **geom
            )
        )
        rows.append(_row(f"ducc0 ({os.cpu_count()} threads)", spin, np.nan, t))
    batch = np.broadcast_to(maps[1:], (4,) + maps[1:].shape)  # ducc0's ntrans: 4 maps, one call
    t, _ = timed(
        lambda: ducc0.sht.adjoint_synthesis(
            map=batch, lmax=lmax, spin=2, nthreads=os.cpu_count(), **geom
        )
    )
    rows.append(_row("  4 maps per call, per map", 2, np.nan, t / 4))
    for label, analysis in (("ring weights", "ring_weights"), ("3 iterations", "jacobi")):
        t, _ = timed(
            lambda a=analysis: harmonics.map2alm(
                maps[1:], lmax, spin=2, analysis=a, nthreads=os.cpu_count()
            ),
            1,
        )
        rows.append(_row(f"  map2alm, {label}", 2, np.nan, t))
    return rows


def ring_subset_rows(nside, lmax, maps):
    """A survey-masked map: one ring-weight pass over every ring (zeros included) against
    map2alm, which reads only the rings that hold data."""
    from boresight import masks

    geom = harmonics.healpix_geometry(nside)
    weights = 4 * np.pi / maps.shape[-1] * harmonics.ring_weights(nside)
    rows = []
    for survey in ("wide", "deep"):
        masked = maps[1:] * masks.survey_mask(survey, nside)
        starts = geom["ringstart"].astype(np.int64)
        share = np.mean(np.logical_or.reduceat(np.any(masked, axis=0), starts))
        every, _ = timed(
            lambda m=masked: ducc0.sht.adjoint_synthesis(
                map=m, lmax=lmax, spin=2, ringfactor=weights, nthreads=os.cpu_count(), **geom
            ),
            1,
        )
        subset, _ = timed(
            lambda m=masked: harmonics.map2alm(
                m, lmax, spin=2, analysis="ring_weights", nthreads=0
            ),
            1,
        )
        rows.append(
            dict(mask=survey, rings_with_data=float(share), all_rings_s=every, map2alm_s=subset)
        )
    return rows


def s2fft_rows(nside, lmax, maps):
    try:
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        import jax

        jax.config.update("jax_enable_x64", True)
        import s2fft

        if jax.devices()[0].platform != "gpu":
            return None, []
    except Exception as err:  # noqa: BLE001 - any import or device failure means: not measured
        print(f"s2fft not measured: {str(err)[:200]}")
        return None, []
    flm0, rows = None, []
    for spin, f in ((0, maps[0]), (2, maps[1] + 1j * maps[2])):
        f_dev = jax.device_put(f)

        def run(f_dev=f_dev, spin=spin):
            out = s2fft.forward(
                f_dev,
                2 * nside,  # s2fft's HEALPix FFT fails for other band limits (seen with 4001)
                spin=spin,
                nside=nside,
                sampling="healpix",
                method="jax",
                reality=spin == 0,
            )
            return out.block_until_ready()

        try:
            t0 = time.perf_counter()
            out = run()
            first = time.perf_counter() - t0
            t, out = timed(run)
        except Exception as err:  # noqa: BLE001 - out of memory, unsupported size: not measured
            print(f"s2fft spin {spin} failed: {str(err)[:200]}")
            continue
        rows.append(_row(f"s2fft jax (GPU, L={2 * nside})", spin, first, t))
        if spin == 0:
            flm0 = np.asarray(out)
    return flm0, rows


def main(nside, lmax):
    rng = np.random.default_rng(1)
    alm = rng.normal(size=(3, harmonics.n_alm(lmax))) + 0j
    alm[:, : lmax + 1] = alm[:, : lmax + 1].real
    maps = np.empty((3, 12 * nside**2))
    maps[0] = harmonics.alm2map(alm[0], nside)
    maps[1:] = harmonics.alm2map(alm[1:], nside, spin=2)
    rows = ducc0_rows(nside, lmax, maps)
    flm0, gpu_rows = s2fft_rows(nside, lmax, maps)
    notes = ""
    if flm0 is not None:
        ref = harmonics.map2alm(maps[0], lmax, iterations=0)
        ell, em = hp.Alm.getlm(lmax)
        mine = flm0[ell, 2 * nside - 1 + em]
        scale = np.vdot(ref, mine) / np.vdot(mine, mine)  # normalisation conventions differ
        err = np.max(np.abs(mine * scale - ref)) / np.max(np.abs(ref))
        notes = f"s2fft spin-0 vs ducc0 (after one overall scale {abs(scale):.4g}): {err:.2e}"
    report(
        "sht",
        f"One adjoint synthesis (map -> alm) at Nside {nside}, lmax {lmax}",
        ["library", "spin", "first_call_s", "steady_s"],
        rows + gpu_rows,
        notes,
    )
    masked = ring_subset_rows(nside, lmax, maps)
    report(
        "sht_masked",
        f"A survey-masked spin-2 map at Nside {nside}: every ring against the rings with data",
        list(masked[0]),
        masked,
    )


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    main(*(args + [2048, 4000][len(args) :]))
