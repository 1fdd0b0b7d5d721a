"""The C_ell-level prediction against the simulation for every systematic of the suppression map.

Each systematic of boresight.jobs.suppression.axis.CATALOGUE alone, no rotation, on both paper surveys
(their masks and synthetic scans, random in-pixel hits, the interpolated sky): the predicted
leaked power <dB, dB> of the residual pseudo-C_BB over the simulated one in bands of 32
multipoles from 40 to 2 Nside, through the residual pipeline (boresight.jobs.residual, with the
patch's own spectra). Ratios, not times: the numbers do not depend on the machine.

The prediction is the expectation over the hits' random places in their pixels. Where their
in-pixel scatter is most of the leaked power (the deep survey's ellipticity: about 80 % below
ell = 300), one draw of the hits scatters by about 6 % per band, so the simulated power is the mean
over HIT_SEEDS draws; the last column gives the worst band of any single draw.

Usage: python bench/bench_prediction.py [NSIDE]   (default 512; 7 arcmin sky beam)
"""

import sys

import numpy as np
from _table import report

from boresight import coupling, masks, predict, spectra
from boresight.cosmology import load_spectra
from boresight.jobs import residual, suppression
from boresight.scan import paper_scan
from boresight.sky import SkyConfig, make_sky

HIT_SEEDS = (0, 1, 2, 3)


def main(nside):
    theory = load_spectra()
    lmax = 2 * nside
    cfg = SkyConfig(nside=nside, lmax=3 * nside - 1, fwhm_arcmin=7.0, seed=1)
    sky = make_sky(cfg, theory)
    edges = spectra.linear_bins(40, lmax, 32)
    rows = []
    for survey in ("deep", "wide"):
        mask = masks.survey_mask(survey, nside)
        couplings = coupling.mask_coupling(mask, lmax)
        local = predict.local_cl(sky, mask, lmax, beams=True)
        prediction = predict.Prediction(theory, couplings, cfg.fwhm_arcmin, local, leaked=True)
        sims = {entry.name: [] for entry in suppression.CATALOGUE}
        predicted = {}
        for seed in HIT_SEEDS:
            scan = paper_scan(survey, seed=seed)
            ref, _ = residual.simulate_reference(sky, scan, mask, lmax)
            for entry in suppression.CATALOGUE:
                job = residual.residual(
                    sky,
                    scan,
                    entry.for_repeats(1),
                    mask,
                    lmax,
                    reference=ref,
                    prediction=prediction,
                )
                sims[entry.name].append(spectra.bin_spectrum(job.auto, edges)[1])
                predicted[entry.name] = spectra.bin_spectrum(job.predicted_cl, edges)[1]
        for entry in suppression.CATALOGUE:
            pred, sim = predicted[entry.name], np.array(sims[entry.name])
            ratio = pred / sim.mean(axis=0)
            single = pred / sim
            ok = bool(np.all(np.abs(ratio - 1) < 0.10))
            rows.append(
                dict(
                    survey=survey,
                    systematic=entry.name,
                    ratio_min=float(ratio.min()),
                    ratio_max=float(ratio.max()),
                    within_10_percent=ok,
                    one_draw_min=float(single.min()),
                    one_draw_max=float(single.max()),
                )
            )
    report(
        "prediction",
        f"Predicted / mean of {len(HIT_SEEDS)} simulated leaked powers, Nside {nside}, no "
        "rotation, bands of 32 from ell = 40",
        list(rows[0]),
        rows,
        "one draw: the same against each simulation alone",
    )


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 512)
