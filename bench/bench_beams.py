"""Detector beams through ducc0 totalconvolve: the cost of the convolution cube, and the C_ell-level
prediction against the simulation at Nside 512.

1. Per Nside (lmax = 3 Nside - 1, a 7 arcmin sky beam) and beam (FWHM + 1 %, kmax 2; and e = 0.03,
   kmax from boresight.instrument.beams.truncate): the cube's build time, the interpolation rate and the peak
   RSS of a fresh process that builds it and evaluates 4 million samples.
2. Nside 512, the paper's scans (random in-pixel hits), both masks: predicted / simulated leaked
   power of each beam systematic in the bands of 32 multipoles from 40 to 1024 (= 2 Nside).

Usage: python bench/bench_beams.py [NSIDE ...]   (cube table; default 256 512 1024)
       python bench/bench_beams.py --cl           (the prediction table only)
"""

import json
import subprocess
import sys

import numpy as np
from _table import report

CUBE = """
import json, resource, time, numpy as np
from boresight import harmonics
from boresight.instrument import beams
from boresight.constants import ARCMIN
nside, e, dfwhm = {nside}, {e}, {dfwhm}
lmax = 3 * nside - 1
rng = np.random.default_rng(0)
n = harmonics.n_alm(lmax)
alm = rng.normal(size=(3, n)) + 1j * rng.normal(size=(3, n))
alm[:, : lmax + 1] = alm[:, : lmax + 1].real
conv = beams.BeamConvolver(alm, 7 * ARCMIN)
beam = beams.Beam((7 + dfwhm) * ARCMIN, e)
t0 = time.perf_counter()
conv._cube(beam)
build = time.perf_counter() - t0
diff = beams.beam_alm(beam, lmax) - beams.beam_alm(conv.nominal, lmax)
kmax = beams.truncate(diff, lmax, beams.KMAX_LIMIT)[1]
m = 4_000_000
th, ph = np.arccos(rng.uniform(-1, 1, m)), rng.uniform(0, 2 * np.pi, m)
psi = rng.uniform(-np.pi, np.pi, m)
t0 = time.perf_counter()
conv.extra(beam, th, ph, psi)
rate = m / (time.perf_counter() - t0) / 1e6
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print(json.dumps(dict(nside=nside, lmax=lmax, beam="e = " + str(e) if e else "FWHM + 1 %",
                      kmax=int(kmax), cube_build_s=build, msamples_per_s=rate, peak_rss_gib=rss)))
"""


def cube_table(nsides):
    rows = []
    for nside in nsides:
        for e, dfwhm in ((0.0, 0.07), (0.03, 0.0)):
            code = CUBE.format(nside=nside, e=e, dfwhm=dfwhm)
            out = subprocess.run(
                [sys.executable, "-c", code], check=True, capture_output=True, text=True
            )
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    report(
        "beams_cube",
        "Detector beams: ducc0 totalconvolve's cube, built and read at 4 million samples",
        list(rows[0]),
        rows,
        "each row a fresh process: its peak RSS is the cube's",
    )


def cl_table(nside=512):
    from boresight import coupling, engine, masks, predict, spectra
    from boresight.cosmology import load_spectra
    from boresight.instrument.pairs import Systematics
    from boresight.scan import paper_scan
    from boresight.sky import SkyConfig, make_sky

    theory = load_spectra()
    lmax = 2 * nside
    cfg = SkyConfig(nside=nside, lmax=3 * nside - 1, fwhm_arcmin=7.0, seed=1)
    sky = make_sky(cfg, theory)
    edges = spectra.linear_bins(40, lmax, 32)
    cases = {
        "width, FWHM_B + 0.5'": Systematics(dfwhm_b_arcmin=0.5),
        "ellipticity e_B = 0.03": Systematics(ellipticity_b=0.03, ellipticity_angle_b_deg=30.0),
    }
    rows = []
    for survey in ("deep", "wide"):
        mask = masks.survey_mask(survey, nside)
        obs = mask > 0
        scan = paper_scan(survey)
        ref = engine.simulate(sky, scan, pixels=obs)
        h, crossings = engine.scan_moments(scan.one_repeat(), nside, predict.BEAM_N_MAX, pixels=obs)
        couplings = coupling.mask_coupling(mask, lmax)
        local = predict.local_cl(sky, mask, lmax, beams=True)
        prediction = predict.Prediction(theory, couplings, cfg.fwhm_arcmin, local, leaked=True)
        for name, sysm in cases.items():
            sim = engine.simulate(sky, scan, systematics=sysm, pixels=obs)
            auto = spectra.residual_bb_parts(sim.qu, ref.qu, mask, lmax)[1]
            pred = predict.residual_pseudo_bb(
                h, mask, prediction, sysm, crossings=crossings, in_pixel="random"
            )
            centres, p = spectra.bin_spectrum(pred, edges)
            ratio = p / spectra.bin_spectrum(auto, edges)[1]
            worst = int(np.argmax(np.abs(ratio - 1)))
            rows.append(
                dict(
                    survey=survey,
                    systematic=name,
                    ratio_min=float(ratio.min()),
                    ratio_max=float(ratio.max()),
                    worst_band_ell=float(centres[worst]),
                    within_10_percent=bool(np.all(np.abs(ratio - 1) < 0.1)),
                )
            )
    report(
        "beams_prediction",
        f"Beams: predicted / simulated leaked power at Nside {nside}, bands of 32 from ell = 40",
        list(rows[0]),
        rows,
    )


if __name__ == "__main__":
    args = sys.argv[1:]
    if args == ["--cl"]:
        cl_table()
    else:
        cube_table([int(a) for a in args] or [256, 512, 1024])
        cl_table()
