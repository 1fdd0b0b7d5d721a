"""GPU TOD core throughput (run on a machine with CuPy and a CUDA GPU).

Times the three hot kernels (hits, interpolation, pair-difference binning) on device arrays for the
paper's deep case with PBR (32 detector samples per pixel) over the full sky, with CUDA events, and
the whole engine.simulate call (host solve and transfers included). Bandwidth counts the bytes each
kernel must move at least: hit arrays written and read, four interpolation neighbours, outputs.
Usage: python bench/bench_gpu.py [NSIDE ...]
"""

import sys
import time

import cupy as cp
import numpy as np

from boresight import engine, instrument, sky, tod_gpu
from boresight.evaluation import SkyFields
from boresight.scan import SyntheticScan


def core(s, scan, nside, chunk):
    fields = SkyFields(s)
    stack = tod_gpu.to_device(fields.stack)
    rot, ang = scan.rotations_rad, np.radians([0.0, 45.0])
    dg, leak = np.array([0.01, -0.01]), np.zeros(2)
    pixels = np.arange(12 * nside**2, dtype=np.int64)
    start, stop = cp.cuda.Event(), cp.cuda.Event()
    total, nhit = 0.0, 0
    for s0 in range(0, pixels.size, chunk):
        pix = pixels[s0 : s0 + chunk]
        n_phi, rng_rad, centre = scan.per_pixel(pix, pixels.size)
        offsets = np.zeros(pix.size + 1, dtype=np.int64)
        np.cumsum(n_phi, out=offsets[1:])
        start.record()
        th, ph, psi = tod_gpu.generate_hits(scan.seed, nside, pix, offsets, rng_rad, centre, False)
        va = tod_gpu.interpolate(stack, nside, th, ph)
        tod_gpu.accumulate(offsets, psi, va, np.empty((3, 0, 2, 2)), rot, ang, dg, leak)
        stop.record()
        stop.synchronize()
        total += cp.cuda.get_elapsed_time(start, stop) / 1e3
        nhit += th.size
    return total, nhit


def main(nsides):
    dev = cp.cuda.runtime.getDeviceProperties(0)
    print(f"device: {dev['name'].decode()}")
    print(f"{'Nside':>6} {'core s':>8} {'det-samples/s':>14} {'GB/s':>7} {'simulate s':>11}")
    scan = SyntheticScan(n_phi=4, range_rad=0.719, rotations_deg=(0, 90), seed=1)
    for nside in nsides:
        s = sky.make_sky(sky.SkyConfig(nside=nside, lmax=min(3 * nside - 1, 4000), seed=1))
        chunk = 1 << 22
        core(s, scan, nside, chunk)  # compile and warm up
        t_core, nhit = core(s, scan, nside, chunk)
        samples = nhit * 2 * 4
        # Per hit: theta, phi, psi written then read (48 B), 3 fields out and in (48 B), 4 stack
        # neighbours (4 x 24 B, mostly cached); per pixel: offsets and 5 sums (48 B).
        nbytes = nhit * (48 + 48 + 96) + 12 * nside**2 * 48
        t0 = time.perf_counter()
        engine.simulate(
            s, scan, systematics=instrument.PAPER_GAIN, backend="gpu", chunk_pixels=chunk
        )
        t_sim = time.perf_counter() - t0
        print(
            f"{nside:>6} {t_core:>8.3f} {samples / t_core:>14.3e} {nbytes / t_core / 1e9:>7.0f} "
            f"{t_sim:>11.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [512, 1024, 2048])
