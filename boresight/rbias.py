"""The bias on the tensor-to-scalar ratio r that a residual B-mode spectrum implies.

Estimator: the least-squares amplitude of the tensor template over a multipole range,
    delta_r = sum_l R_l T_l / sum_l T_l^2,   lmin <= l <= lmax,
with R_l the residual pseudo-C_BB and T_l the pseudo-C_BB of tensors at r = 1 through the same
mask, beam and pixel window (predict.reference_bb). Uniform weights: for the deep survey's
30 <= l <= 300 the template's shape dominates the weights that cosmic variance would give.
"""

import numpy as np

from . import predict

R_RANGE = (30, 300)  #: the deep survey's primordial range


def tensor_template(coupling, spectra, fwhm_arcmin, nside):
    """Pseudo-C_BB [muK^2] of tensors at r = 1 through the mask's coupling matrix."""
    return predict.reference_bb(coupling, spectra, fwhm_arcmin, nside, r=1.0)


def delta_r(residual, template, lmin=R_RANGE[0], lmax=R_RANGE[1]):
    """Tensor-to-scalar ratio a residual pseudo-C_BB would fake (least-squares amplitude)."""
    lmax = min(lmax, residual.size - 1, template.size - 1)
    if lmin >= lmax:
        raise ValueError(f"empty multipole range [{lmin}, {lmax}] for delta_r")
    s = slice(lmin, lmax + 1)
    return float(np.sum(residual[s] * template[s]) / np.sum(template[s] ** 2))
