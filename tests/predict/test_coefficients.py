"""The prediction's coefficients: its expectation over a drawn focal plane, coherent plus rms^2 / N
and the mean over many planes; the C_ell level needs 4x angles that cancel."""

import numpy as np
import pytest

from boresight import masks, predict
from boresight.instrument.pairs import PAPER_GAIN, Instrument, Spread, Systematics


def test_expected_focal_plane_power_is_coherent_plus_rms2_over_n():
    """A linear term's power over the draws is |mean x <e^{2ia}>|^2 + rms^2 / N exactly: 0.5 mu^2 +
    rms^2 / 2 for the paper's two pairs, and so on for uniform planes of N pairs."""
    paper = predict.expected_power(Systematics(dg=Spread(0.02, 0.01)))
    assert paper.t2 == pytest.approx(0.5 * 0.02**2 + 0.01**2 / 2, rel=1e-12)
    for n in (4, 16, 64):
        inst = Instrument("uniform", n)
        power = predict.expected_power(Systematics(leak=Spread(0.3, 0.01)), inst)
        coherent = abs(0.3 * np.mean(np.exp(2j * inst.pair_angles_rad))) ** 2
        assert power.s2 == pytest.approx(coherent + 0.01**2 / n, rel=1e-12)


@pytest.mark.parametrize("n", [4, 16])
def test_expected_power_is_the_mean_over_many_focal_planes(n):
    """Gauss-Hermite expectation against the mean of 1500 drawn focal planes (an independent route:
    the per-pair draws of rng.normal_array), within 4 standard errors, for every term."""
    inst = Instrument("uniform", n)
    table = dict(
        dg=Spread(0.005, 0.01),
        pol_angle_deg=Spread(0.5, 1.0),
        nonortho_deg=Spread(0.0, 1.0),
        rho_arcmin=Spread(0.1, 0.05),
        chi_deg=Spread(10.0, 30.0),
    )
    power = predict.expected_power(Systematics(**table), inst)
    draws = [predict.coefficients(Systematics(**table, seed=s), inst) for s in range(1500)]
    samples = {
        "t2": [abs(c.t2) ** 2 for c in draws],
        "g1": [abs(c.g1) ** 2 for c in draws],
        "g3": [abs(c.g3) ** 2 for c in draws],
        "p4": [abs(c.p4) ** 2 for c in draws],
        "re_p0": [c.p0.real for c in draws],
        "im_p0_2": [c.p0.imag**2 for c in draws],
        "im_p0": [c.p0.imag for c in draws],
        "re_im_p0": [c.p0.real * c.p0.imag for c in draws],
    }
    for name, x in samples.items():
        error = np.std(x) / np.sqrt(len(x))
        assert abs(getattr(power, name) - np.mean(x)) < 4 * error, name


def test_cl_prediction_needs_cancelling_4x_angles(small_sky, theory):
    """Pairs at (0, 30) deg couple h_4 into the map-maker (m_4 != 0): the C_ell level refuses them,
    unless a repeat cancels h_4 (0/45 deg rotation)."""
    from boresight.instrument.pairs import Instrument

    inst = Instrument((0.0, 30.0))
    assert not predict.supports(inst) and predict.supports(inst, (0.0, 45.0))
    mask = masks.survey_mask("deep", small_sky.nside)
    h = np.zeros((5, mask.size), dtype=complex)
    with pytest.raises(ValueError, match="m_4"):
        predict.systematic_cl(h, mask, PAPER_GAIN, theory, 60, fwhm_arcmin=7.0, instrument=inst)
