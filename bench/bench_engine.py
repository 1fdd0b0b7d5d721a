"""Engine throughput: the paper's deep case with PBR at Nside 512, 1024, 2048.

Each hit gives 2 rotations x 2 pairs x 2 detectors; N_phi = 4 makes 32 detector samples per pixel.
Every configuration runs in its own process so that its peak RSS is its own. The naive baseline is
what a first script would do (healpy.get_interp_val per field, numpy.bincount per pixel) on the
same work, timed on a slice of the sky. Usage: python bench/bench_engine.py [NSIDE ...]
"""

import json
import subprocess
import sys

from _table import report

CHILD = r"""
import json, resource, sys, time
import numpy as np, healpy as hp
from boresight import engine, sky, scan as scanmod, instrument
nside, backend = int(sys.argv[1]), sys.argv[2]
s = sky.make_sky(sky.SkyConfig(nside=nside, lmax=min(3 * nside - 1, 4000), seed=1))
sc = scanmod.SyntheticScan(n_phi=4, range_rad=0.719, rotations_deg=(0, 90), seed=1)
sysm = instrument.PAPER_GAIN
engine.simulate(s, sc, systematics=sysm, pixels=np.arange(1000), backend=backend)  # compile
t0 = time.perf_counter()
m = engine.simulate(s, sc, systematics=sysm, backend=backend)
t_engine = time.perf_counter() - t0
npix = 12 * nside**2
samples = npix * 4 * 2 * 4
# Naive baseline on a slice: same hits, healpy interpolation, bincount map-making.
n_slice = min(npix, 1 << 18)
pix = np.repeat(np.arange(n_slice), 4)
rng = np.random.default_rng(0)
t0 = time.perf_counter()
th, ph = hp.pix2ang(nside, pix)
th = th + (rng.random(pix.size) - 0.5) * hp.nside2resol(nside)
th = np.clip(th, 0, np.pi)
ph = ph + (rng.random(pix.size) - 0.5) * hp.nside2resol(nside) / np.maximum(np.sin(th), 1e-3)
psi = (rng.random(pix.size) - 0.5) * 0.719
i, q, u = (hp.get_interp_val(s.maps[f], th, ph) for f in range(3))
acc = np.zeros((5, n_slice))
for alpha in (0, np.pi / 2):
    for pair, dg in ((0, 0.01), (np.pi / 4, -0.01)):
        a = 2 * (psi + alpha + pair)
        c, sn = np.cos(a), np.sin(a)
        d = 0.5 * ((i + q * c + u * sn) - (1 - dg) * (i - q * c - u * sn))
        for k, w in enumerate((c * c, c * sn, sn * sn, c * d, sn * d)):
            acc[k] += np.bincount(pix, weights=w, minlength=n_slice)
det = acc[0] * acc[2] - acc[1] ** 2
qn = (acc[2] * acc[3] - acc[1] * acc[4]) / det
t_naive = time.perf_counter() - t0
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print(json.dumps(dict(nside=nside, t_engine=t_engine, rate=samples / t_engine,
                      naive_rate=n_slice * 32 / t_naive, rss_gib=rss)))
"""


def main(nsides, backend="cpu"):
    rows = []
    for nside in nsides:
        out = subprocess.run(
            [sys.executable, "-c", CHILD, str(nside), backend],
            capture_output=True,
            text=True,
            check=True,
        )
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(
            dict(
                nside=r["nside"],
                engine_s=r["t_engine"],
                detector_samples_per_s=r["rate"],
                naive_per_s=r["naive_rate"],
                speed_up=r["rate"] / r["naive_rate"],
                peak_rss_gib=r["rss_gib"],
            )
        )
    report(
        f"engine_{backend}",
        f"Engine throughput, the paper's deep case with 0/90 rotation, backend {backend}",
        list(rows[0]),
        rows,
        "naive: healpy.get_interp_val and numpy.bincount on the same hits, on a slice of the sky",
    )


if __name__ == "__main__":
    args = sys.argv[1:]
    backend = "gpu" if "--gpu" in args else "cpu"
    nsides = [int(a) for a in args if a != "--gpu"] or [512, 1024, 2048]
    main(nsides, backend)
