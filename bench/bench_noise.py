"""The yardstick: sigma(r) of boresight's built-in noise model against published forecasts.

The built-in model is white polarisation noise with an optional 1/f knee, no foregrounds, no
filtering and no delensing residual, summed over 30 <= ell <= 300 with lensing B at
A_lens = 1 (boresight.noise). Published sigma(r) fold those in, so they are larger: this table
says by how much for the SO small-aperture telescopes and for the design example's budget, which
is why `[noise]` also takes a given sigma_r or an N_ell^BB table.

Usage: python bench/bench_noise.py
"""

import numpy as np
from _table import report

from boresight import cosmology, noise
from boresight.predict import R_RANGE

#: (name, depth [muK arcmin], f_sky, FWHM [arcmin], ell_knee, published sigma(r), its source)
CASES = (
    ("SO SATs, baseline", 2.0, 0.1, 30.0, 0.0, 0.003,
     "Ade et al. 2019 (JCAP 02 056), baseline with foregrounds, r = 0"),
    ("SO SATs, baseline, 1/f knee ell = 50", 2.0, 0.1, 30.0, 50.0, 0.003,
     "the same"),
    ("the design example's budget", 3.0, 0.1, 30.0, 0.0, float("nan"), "none published"),
)  # fmt: skip


def main():
    theory = cosmology.load_spectra()
    edges = np.array([R_RANGE[0], R_RANGE[1] + 1])
    rows = []
    for name, depth, fsky, fwhm, knee, published, source in CASES:
        model = noise.SurveyNoise(fsky=fsky, fwhm_arcmin=fwhm, depth_uk_arcmin=depth, ell_knee=knee)
        sigma = noise.sigma_r(model, theory, edges)
        rows.append(
            dict(
                survey=name,
                depth_uk_arcmin=depth,
                fsky=fsky,
                ell_knee=knee,
                boresight_sigma_r=f"{sigma:.3g}",
                published_sigma_r=f"{published:.3g}",
                published_over_boresight=f"{published / sigma:.2f}",
                source=source,
            )
        )
    report(
        "noise_yardstick",
        "sigma(r): the built-in white + 1/f model against published forecasts",
        list(rows[0]),
        rows,
    )


if __name__ == "__main__":
    main()
