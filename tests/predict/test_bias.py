"""delta_r: the template's own amplitude is r, the fit is linear, and the reference curves are
the theory's tensor and lensing B through the mask."""

import numpy as np
import pytest

from boresight import coupling, masks, predict


@pytest.fixture(scope="module")
def deep(theory):
    mask = masks.survey_mask("deep", 32)
    couplings = coupling.mask_coupling(mask, 64, band=95)
    return couplings, predict.tensor_template(couplings, theory, 30.0, 32)


def test_delta_r_of_r_times_the_template_is_r_and_linear(deep):
    _, template = deep
    assert predict.delta_r(0.01 * template, template, 30, 60) == pytest.approx(0.01, rel=1e-12)
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, template.size)) * template.max()
    both = predict.delta_r(a + 2 * b, template, 30, 60)
    assert both == pytest.approx(
        predict.delta_r(a, template, 30, 60) + 2 * predict.delta_r(b, template, 30, 60)
    )


def test_reference_curves_scale_with_r_and_the_lensing_amplitude(deep, theory):
    couplings, template = deep
    r_only = predict.reference_bb(couplings, theory, 30.0, 32, r=0.05, a_lens=0.0)
    np.testing.assert_allclose(r_only, 0.05 * template, rtol=1e-12, atol=0)
    lensing = predict.reference_bb(couplings, theory, 30.0, 32, a_lens=1.0)
    half = predict.reference_bb(couplings, theory, 30.0, 32, a_lens=0.5)
    np.testing.assert_allclose(half, 0.5 * lensing, rtol=1e-12, atol=0)
    assert np.all(lensing[2:] > 0)


def test_an_empty_range_is_refused(deep):
    with pytest.raises(ValueError, match="empty multipole range"):
        predict.delta_r(deep[1], deep[1], 60, 40)


def test_delta_r_of_a_zero_template_is_an_error_not_nan():
    with pytest.raises(ValueError, match="the template is zero"):
        predict.delta_r(np.ones(400), np.zeros(400))


def test_delta_r_is_its_weights_on_the_spectrum():
    """delta_r of any residual is the weights' sum over it (what the design objectives hold),
    the weights zero outside R_RANGE."""
    from boresight.predict import R_RANGE, delta_r, delta_r_weights

    rng = np.random.default_rng(0)
    template, residual = rng.uniform(0.1, 1.0, (2, 257))
    weights = delta_r_weights(template, 256)
    assert np.sum(weights * residual) == pytest.approx(delta_r(residual, template), rel=1e-13)
    assert not weights[: R_RANGE[0]].any() and weights.size == 257
