"""GPU TOD core throughput (run on a machine with CuPy and a CUDA GPU).

Times the fused kernel ``gpu.bin_scan`` (hits, interpolated sky, pair differences and
normal equations; no per-hit arrays) over the full sky with CUDA events, for the paper's two
cases with PBR: deep + gain (N_phi 4, 2 rotations, 2 pairs: 32 detector samples per pixel) and
wide + pointing (N_phi 2: 16 samples per pixel, detector B interpolated separately), then the
whole engine.simulate call (upload, solve on the GPU, download of q, u, rcond, hits).
Bandwidth counts the bytes the kernel must move: per pixel its index, N_phi, R, centre (32 B),
its sky fields (24 B; the neighbours are shared) and 5 sums (40 B).
Usage: python bench/bench_gpu.py [NSIDE ...]
"""

import sys
import time

import cupy as cp
import numpy as np
from _table import report

from boresight import engine, instrument
from boresight.engine.binner import Binner
from boresight.kernels import gpu
from boresight.scan import SyntheticScan
from boresight.sky import SkyConfig, make_sky

CASES = {
    "deep + gain": (
        SyntheticScan(n_phi=4, range_rad=0.719, rotations_deg=(0, 90), seed=1),
        instrument.PAPER_GAIN,
    ),
    "wide + pointing": (
        SyntheticScan(n_phi=2, range_rad=0.169, rotations_deg=(0, 180), seed=1),
        instrument.PAPER_POINTING,
    ),
}


def core(sky, scan, systematics):
    """Seconds of bin_scan over the full sky (inputs already on the GPU) and its sample count.

    The kernel gets the arguments the engine gives it (its binner's per-pair parameters)."""
    nside, npix = sky.nside, 12 * sky.nside**2
    inst = instrument.Instrument()
    b = Binner(sky, inst, systematics, scan.rotations_rad, "interp", None, 0, "gpu")
    n_phi, rng, centre = scan.per_pixel(np.arange(npix), npix)
    args = [cp.arange(npix, dtype=cp.int64), cp.asarray(n_phi), cp.asarray(rng), cp.asarray(centre)]
    start, stop = cp.cuda.Event(), cp.cuda.Event()
    start.record()
    gpu.bin_scan(
        scan.seed,
        nside,
        *args,
        scan.in_pixel == "centre",
        b.stack,
        b.rot,
        b.ang,
        b.response,
        b.rho,
        b.chi,
        b.leak,
        b.jitter,
        b.pointing,
        False,
    )
    stop.record()
    stop.synchronize()
    samples = int(n_phi.sum()) * len(scan.rotations_deg) * inst.n_pairs * 2
    return cp.cuda.get_elapsed_time(start, stop) / 1e3, samples


def main(nsides):
    dev = cp.cuda.runtime.getDeviceProperties(0)
    rows = []
    for nside in nsides:
        sky = make_sky(SkyConfig(nside=nside, lmax=min(3 * nside - 1, 4000), seed=1))
        for name, (scan, systematics) in CASES.items():
            core(sky, scan, systematics)  # compile and warm up
            t_core, samples = min(core(sky, scan, systematics) for _ in range(3))
            nbytes = 12 * nside**2 * (32 + 24 + 40)
            t0 = time.perf_counter()
            engine.simulate(sky, scan, systematics=systematics, backend="gpu")
            t_sim = time.perf_counter() - t0
            rows.append(
                dict(
                    case=name,
                    nside=nside,
                    core_s=t_core,
                    detector_samples_per_s=samples / t_core,
                    gb_per_s=nbytes / t_core / 1e9,
                    simulate_s=t_sim,
                )
            )
    report(
        "gpu",
        f"GPU TOD core throughput on {dev['name'].decode()}",
        list(rows[0]),
        rows,
        "core: the fused bin_scan kernel timed with CUDA events; simulate: the whole call",
    )


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [512, 1024, 2048])
