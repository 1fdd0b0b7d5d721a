"""CMB power spectra: the paper's Planck-2015 LCDM model from CAMB, and a cached copy.

Spectra are C_ell in muK^2 from ell = 0 (no ell(ell+1)/2pi factor). The lensing B-mode is scaled by
A_lens and the tensor spectra (computed at r = 1, n_t = 0) by r, so any (r, A_lens) is a linear
combination of the cached arrays. ``scripts/make_spectra.py`` regenerates the cached file.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

#: Paper section 3: best-fitting Planck 2015 6-parameter LCDM.
PAPER_COSMOLOGY = dict(H0=67.3, omega_b=0.0480, omega_cdm=0.261, tau=0.066, ns=0.968, As=2.19e-9)
CACHE_FILE = "planck2015_spectra.npz"
FIELDS = ("tt", "ee", "te", "bb_lens", "tt_tensor", "ee_tensor", "te_tensor", "bb_tensor")


@dataclass(frozen=True)
class Spectra:
    """Template spectra [muK^2], each an array indexed by ell = 0..lmax.

    Parameters
    ----------
    tt, ee, te : numpy.ndarray
        Lensed scalar spectra.
    bb_lens : numpy.ndarray
        The lensing B-mode at A_lens = 1.
    tt_tensor, ee_tensor, te_tensor, bb_tensor : numpy.ndarray
        The tensor contribution at r = 1.
    """

    tt: np.ndarray
    ee: np.ndarray
    te: np.ndarray
    bb_lens: np.ndarray
    tt_tensor: np.ndarray
    ee_tensor: np.ndarray
    te_tensor: np.ndarray
    bb_tensor: np.ndarray

    @property
    def lmax(self):
        return self.tt.size - 1

    def total(self, r: float = 0.0, a_lens: float = 1.0, lmax: int | None = None) -> np.ndarray:
        """The spectra of a model.

        Parameters
        ----------
        r : float
            Tensor-to-scalar ratio, >= 0.
        a_lens : float
            Lensing amplitude, >= 0.
        lmax : int, optional
            Default: the spectra's own.

        Returns
        -------
        numpy.ndarray, shape (4, lmax + 1)
            TT, EE, BB, TE [muK^2].
        """
        if r < 0 or a_lens < 0:
            raise ValueError(f"r and a_lens must be >= 0, got r={r}, a_lens={a_lens}")
        lmax = self.lmax if lmax is None else lmax
        if lmax > self.lmax:
            raise ValueError(
                f"lmax={lmax} exceeds the spectra's lmax={self.lmax}; "
                "compute them with boresight.cosmology.compute_spectra(lmax=...)"
            )
        s = slice(0, lmax + 1)
        return np.array(
            [
                self.tt[s] + r * self.tt_tensor[s],
                self.ee[s] + r * self.ee_tensor[s],
                a_lens * self.bb_lens[s] + r * self.bb_tensor[s],
                self.te[s] + r * self.te_tensor[s],
            ]
        )

    def bb(self, r: float = 0.0, a_lens: float = 0.0) -> np.ndarray:
        """The B-mode spectrum alone (the reference curves).

        Parameters
        ----------
        r : float
        a_lens : float

        Returns
        -------
        numpy.ndarray, shape (lmax + 1,)
            r * tensor + A_lens * lensing [muK^2].
        """
        return a_lens * self.bb_lens + r * self.bb_tensor


def compute_spectra(lmax: int = 6000, **cosmology) -> Spectra:
    """Run CAMB for the paper's cosmology.

    Parameters
    ----------
    lmax : int
    **cosmology
        Overrides of :data:`PAPER_COSMOLOGY` (H0, omega_b, omega_cdm, tau, ns, As).

    Returns
    -------
    Spectra
    """
    import camb

    p = {**PAPER_COSMOLOGY, **cosmology}
    h2 = (p["H0"] / 100.0) ** 2
    pars = camb.CAMBparams()
    pars.set_cosmology(H0=p["H0"], ombh2=p["omega_b"] * h2, omch2=p["omega_cdm"] * h2, tau=p["tau"])
    pars.InitPower.set_params(As=p["As"], ns=p["ns"], r=1.0, nt=0.0)
    pars.WantTensors = True
    pars.set_for_lmax(lmax + 500, lens_potential_accuracy=2)
    # CAMB computes tensors only to max_l_tensor (default 600: the spectra were 0 above it, and
    # 1 % low at ell = 300 from the cut-off). The cut-off's error falls with ell / max_l_tensor:
    # measured against a cut-off at 12000, 2e-3 at ell = max_l_tensor / 3, 2e-4 at / 6.
    pars.max_l_tensor = max(2 * lmax, lmax + 500)
    pars.max_eta_k_tensor = 2.0 * pars.max_l_tensor
    res = camb.get_results(pars)
    lensed = res.get_lensed_scalar_cls(lmax=lmax, CMB_unit="muK", raw_cl=True)
    tensor = res.get_tensor_cls(lmax=lmax, CMB_unit="muK", raw_cl=True)
    # CAMB column order: TT, EE, BB, TE.
    return Spectra(
        tt=lensed[:, 0],
        ee=lensed[:, 1],
        te=lensed[:, 3],
        bb_lens=lensed[:, 2],
        tt_tensor=tensor[:, 0],
        ee_tensor=tensor[:, 1],
        te_tensor=tensor[:, 3],
        bb_tensor=tensor[:, 2],
    )


def save_spectra(spectra: Spectra, path: str) -> None:
    """Write spectra as a .npz file.

    Parameters
    ----------
    spectra : Spectra
    path : str
    """
    np.savez_compressed(path, **{f: getattr(spectra, f) for f in FIELDS})


def load_spectra(path: str | None = None) -> Spectra:
    """The cached CAMB spectra shipped with the package (or a .npz file).

    Parameters
    ----------
    path : str, optional
        Default: ``boresight/data/``'s cache (regenerated by scripts/make_spectra.py).

    Returns
    -------
    Spectra
    """
    source = resources.files("boresight.data").joinpath(CACHE_FILE) if path is None else Path(path)
    with source.open("rb") as f:
        data = np.load(f)
        return Spectra(**{k: data[k] for k in FIELDS})
