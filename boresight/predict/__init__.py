"""Analytic prediction of the spurious polarisation from the spin moments h_n (paper eqs. 5-10).

A sample j of pair m in rotation repeat k has the assumed angle phi_j = psi_j + alpha_k + a_m.
Its pair difference departs from the ideal Re[P* e^{2 i phi}] by (docs/conventions.md)::

  dd = 1/2 dg_km T + 1/2 l_m S - 1/2 rho_m Re[G e^{-i beta}] + Re[P* e^{2 i phi} gamma_km]

with dg_km = dg_m + dg_repeat_k, beta = phi + chi_m, G = dT/dtheta + i dT/dphi / sin(theta) and
gamma_km = (e^{2i(delta - eps/2)} + (1 - dg_km) e^{2i(delta + eps/2)}) / 2 - 1 (angle errors
delta, eps). The least-squares map-maker turns Y = 2 <e^{2 i phi} dd> into
dP = (Y - H_4 Y*) / (1 - ``|H_4|^2``) with H_4 = m_4 h_4, and to first order in rho::

  Y = t_2 h_2 T + s_2 h_2 S + g_1 h_1 G + g_3 h_3 G* + p_0 P + p_4 h_4 P*

where h_n = <exp(i n psi)> over one repeat's crossings of a pixel and every coefficient is a mean
over (k, m) (:func:`coefficients`): t_2 = <dg e^{2i(alpha+a)}>, s_2 = <l e^{2i(alpha+a)}>,
g_1 = -1/2 <rho e^{i(alpha+a-chi)}>, g_3 = -1/2 <rho e^{i(3(alpha+a)+chi)}>, p_0 = <conj gamma>,
p_4 = <gamma e^{4i(alpha+a)}>, m_4 = <e^{4i(alpha+a)}>. For the paper's pairs at (0, 45) deg and
no repeat these are the paper's eq. 5-9 (its eq. 6 is the complex conjugate of these forms: its
h_n and gradient use the opposite orientation; amplitudes are identical). Gain, leak and angle
terms are exact for pixel-centre hits; pointing is first order in rho.

Detector beams (:mod:`boresight.instrument.beams`): detector X's extra signal is a sum over its beam's
azimuthal moments k of spin-k fields F_k of the sky (T, E and B) times e^{-i k psi_X}, so Y gains
the terms h_n G_n, n = 2 -+ k (:func:`beam_filters`): the width's nabla^2 T and the ellipticity's
eth-bar^2 P at h_2 (joining the gain's h_2 T), the ellipticity's eth^2 T at h_0 (which no rotation
changes) and h_4, its eth^2 P at h_{-2} and h_6, and higher orders in e beyond. Exact to the
moments h holds (:data:`BEAM_N_MAX` covers every term of first order in e).

Power spectra: each term c h_n F contributes C^EE = C^BB = ``|c|^2`` / 2 * [coh_n C^FF_l +
(``<|h_n|^2>`` - coh_n) Omega_pix sigma_F^2]: a coherent part from h_n smoothed over blocks of
pixels (what Wallis et al. 2017 write as ``<|h_n|^2>`` C^FF) and a white part from the
pixel-to-pixel scatter of h_n. A beam pair h_n G_n + h_{-n} G_{-n} splits its coherent part
unequally: B takes ``|g_n - (-1)^n conj(g_-n)|^2`` and E the sum (docs/conventions.md). The
h_0 term rotates and rescales the sky's own polarisation, u P with u = 1 + p_0. Gain jitter of
rms sigma adds white noise of variance ``<sigma^2>`` T^2 / N_samples per pixel. Masked
pseudo-C_ell follow through M^{BB,BB} and M^{BB,EE} (paper eq. 10). The C_ell level needs m_4 = 0
(pairs whose 4 x angles cancel, e.g. (0, 45) deg or any "uniform" focal plane of 2 or more pairs,
or a repeat that cancels h_4); the map level has no such limit.

The package, in the order a prediction is made:

* :mod:`~boresight.predict.coefficients`: the coefficient of every term, and its expectation over
  a focal plane's drawn pairs;
* :mod:`~boresight.predict.windows`: what hits spread over their pixels, read exactly or by
  interpolation, do to a field;
* :mod:`~boresight.predict.sky_spectra`: the spectra of the sky's fields, the theory's or one
  sky's own inside the mask;
* :mod:`~boresight.predict.beam_fields`: the detectors' beam terms;
* :mod:`~boresight.predict.maps`: the map-level prediction, ``delta_p``;
* :mod:`~boresight.predict.cl`: the C_ell-level prediction, ``systematic_cl`` and
  ``residual_pseudo_bb``;
* :mod:`~boresight.predict.field_products`: the exact expected pseudo-C_ell of fixed spin
  weights times the sky's Gaussian fields (any h_n, no white approximation);
* :mod:`~boresight.predict.expectation`: that expectation for a schedule's own h_n maps, the
  leaked power and the total residual with its cross terms (``expected_residual``);
* :mod:`~boresight.predict.bias`: delta_r and the reference curves;
* :mod:`~boresight.predict.focalplane`: the map-level prediction and its expectation (coherent
  and scattered) for pairs off the axis, each with its own h_n;
* :mod:`~boresight.predict.deprojection`: the noise price of map-domain deprojection;
* :mod:`~boresight.predict.template_error`: what TOD template deprojection leaves of a leak (the
  template's error and the fit's share), as the spectrum a prediction reads in place of T's.
"""

from ..constants import N_MAX
from .beam_fields import BEAM_N_MAX, beam_filters, beam_h0_bb, beam_power, beam_spectra
from .bias import R_RANGE, delta_r, delta_r_weights, reference_bb, tensor_template
from .cl import (
    COHERENT_BLOCK,
    PixelBlocks,
    Prediction,
    Term,
    leak_terms,
    residual_pseudo_bb,
    signal_bb,
    systematic_cl,
)
from .coefficients import (
    M4_TOLERANCE,
    MOMENT_NAMES,
    QUADRATURE_NODES,
    Coefficients,
    ExpectedPower,
    coefficient_moments,
    coefficients,
    deprojected,
    expected_coefficients,
    expected_power,
    jitter_variance,
    rotation_suppression,
    supports,
)
from .expectation import ExpectedResidual, LeakModel, expected_residual, leak_model
from .maps import delta_p
from .sky_spectra import BEAM_APODIZATION_DEG, FieldSpectra, field_spectra, local_cl
from .windows import SPREAD_PIXELS, hit_spread_window, interpolation_window, pixel_window

__all__ = [
    "BEAM_APODIZATION_DEG",
    "BEAM_N_MAX",
    "COHERENT_BLOCK",
    "M4_TOLERANCE",
    "MOMENT_NAMES",
    "N_MAX",
    "QUADRATURE_NODES",
    "R_RANGE",
    "SPREAD_PIXELS",
    "Coefficients",
    "ExpectedPower",
    "ExpectedResidual",
    "FieldSpectra",
    "LeakModel",
    "PixelBlocks",
    "Prediction",
    "Term",
    "beam_filters",
    "beam_h0_bb",
    "beam_power",
    "beam_spectra",
    "coefficient_moments",
    "coefficients",
    "delta_p",
    "deprojected",
    "delta_r",
    "delta_r_weights",
    "expected_coefficients",
    "expected_power",
    "expected_residual",
    "field_spectra",
    "hit_spread_window",
    "interpolation_window",
    "jitter_variance",
    "leak_model",
    "leak_terms",
    "local_cl",
    "pixel_window",
    "reference_bb",
    "residual_pseudo_bb",
    "rotation_suppression",
    "signal_bb",
    "supports",
    "systematic_cl",
    "tensor_template",
]
