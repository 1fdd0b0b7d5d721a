"""The cached spectra are the paper's cosmology and CAMB's, tensors to the spectra's lmax."""

import numpy as np
import pytest
from helpers import rel_max

from boresight import cosmology


def test_cached_spectra_are_the_paper_cosmology(theory):
    """Published numbers of Planck-2015-like LCDM: first TT peak near l=220 at ~5800 muK^2."""
    ell = np.arange(theory.lmax + 1)
    dl = ell * (ell + 1) / (2 * np.pi)
    assert 215 <= np.argmax(dl * theory.tt) <= 225
    assert 5500 < np.max(dl * theory.tt) < 6100
    assert 800 < np.argmax(dl * theory.bb_lens) < 1100  # lensing B-mode peak
    assert np.all(theory.bb_tensor[2:300] > 0) and theory.bb_lens[0] == 0


@pytest.mark.slow
def test_cache_matches_camb():
    pytest.importorskip("camb")
    fresh = cosmology.compute_spectra(lmax=1000)
    cached = cosmology.load_spectra()
    for name in cosmology.FIELDS:
        top = 501 if name.endswith("tensor") else 1001  # fresh tensors: cut off at 2000
        a, b = getattr(fresh, name)[2:top], getattr(cached, name)[2:top]
        assert rel_max(a, b) < 1e-3, name  # CAMB accuracy settings are the same; versions vary


def test_tensor_spectra_reach_the_spectra_lmax():
    """No cliff: CAMB's tensors used to stop at its default max_l_tensor = 600 (the r curves of
    fig2 and fig4 fell to 0 there). The shipped C_BB^tensor is positive and smooth to lmax, and a
    CAMB run with its own cut-off at 5000 agrees with it to 1e-3 up to ell = 1000."""
    camb = pytest.importorskip("camb")
    shipped = cosmology.load_spectra()
    bb = shipped.bb_tensor
    assert bb.size == shipped.lmax + 1 and np.all(bb[2:] > 0)
    assert np.max(np.abs(np.diff(np.log(bb[10:])))) < 0.2  # the cut-off was a jump of 674
    p = cosmology.PAPER_COSMOLOGY
    h2 = (p["H0"] / 100.0) ** 2
    pars = camb.CAMBparams()
    pars.set_cosmology(H0=p["H0"], ombh2=p["omega_b"] * h2, omch2=p["omega_cdm"] * h2, tau=p["tau"])
    pars.InitPower.set_params(As=p["As"], ns=p["ns"], r=1.0, nt=0.0)
    pars.WantTensors, pars.WantScalars = True, False
    pars.set_for_lmax(5000)
    pars.max_l_tensor, pars.max_eta_k_tensor = 5000, 10000.0
    other = camb.get_results(pars).get_tensor_cls(lmax=1000, CMB_unit="muK", raw_cl=True)[:, 2]
    assert np.max(np.abs(other[2:] / bb[2:1001] - 1)) < 1e-3
