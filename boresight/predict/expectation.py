"""The exact expected residual of a schedule's own h_n maps over the sky's realisations.

The map-maker's spurious polarisation (:func:`boresight.predict.delta_p`) is, per pixel,

    dP = t2 h_2 T + s2 h_2 S + g1 h_1 grad T + g3 h_3 conj(grad T) + p4 h_4 P* + p0 P
         + sum_n h_n G_n (beams),

a sum of weights w c_k h_{n_k} times the sky's fields, so its expected masked pseudo-C_BB is the
bilinear sum of :mod:`boresight.predict.field_products`, with no assumption on how h_n varies.
The paper's C_ell-level prediction (:func:`boresight.predict.residual_pseudo_bb`) takes h_n as
white plus a coherent part; this one does not, which is what a real schedule's striped h_n needs.
Adding the sky's own P (coefficient 1) gives the cross terms with its E and B (TE, EE): the total
residual, pseudo-C_BB(P + dP) - pseudo-C_BB(P), against the leaked power pseudo-C_BB(dP) alone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import healpy as hp
import numpy as np

from ..constants import ARCMIN
from ..evaluation import METHODS
from ..instrument.added import refuse as refuse_added
from ..instrument.hwp import pairs_behind
from . import field_products as fp
from .beam_fields import beam_filters
from .coefficients import MOMENT_NAMES, coefficient_moments, coefficients, jitter_variance
from .terms import deprojected_by, ordered
from .windows import hit_spread_window, interpolation_window

if TYPE_CHECKING:
    from ..cosmology import Spectra
    from ..instrument.hwp import HWP
    from ..instrument.pairs import Instrument, Systematics

#: the spin-moment n and field of each coefficient of :data:`MOMENT_NAMES`, in that order
#: (:data:`boresight.predict.terms.TERMS`)
#: the refusal of every prediction read exactly across the pixel behind a plate (bare pairs only)
OFFSETS_BEHIND_HWP = "the samples' offsets behind a HWP: not yet predicted"
TERM_FIELDS = {term.name: (term.n, term.field) for term in ordered(MOMENT_NAMES)}


class ExpectedResidual(NamedTuple):
    """Expected masked pseudo-C_BB [muK^2], (lmax + 1,) each: the leaked power
    pseudo-C_BB(dP), and the residual pseudo-C_BB(P + dP) - pseudo-C_BB(P) with its cross terms
    with the sky."""

    leaked: np.ndarray
    residual: np.ndarray


def fields_by_kind(window, gradient_window):
    """The sky's fields by name, to one band."""
    return {
        "temperature": fp.temperature(window),
        "template": fp.temperature(window),
        "gradient": fp.gradient(gradient_window),
        "conjugate gradient": fp.gradient(gradient_window, conjugate=True),
        "conjugate polarisation": fp.polarisation(window, conjugate=True),
        "polarisation": fp.polarisation(window),
    }


class LeakModel(NamedTuple):
    """The terms of the spurious polarisation: term k is w h_{n_k} c_k F_k (h_{-n} = conj h_n).

    Parameters
    ----------
    term_n : tuple of int
        Each term's moment; its weight's spin.
    fields : tuple of boresight.predict.field_products.SkyField
    second, pseudo : numpy.ndarray, complex128, shape (K, K)
        E[c c^H] and E[c c^T] over the focal plane's draws (1 for the beams' terms, whose filters
        carry their coefficients, and for the sky's own P where included).
    readings : tuple of _Reading
        How the hits read each term's field.
    sky_cl : numpy.ndarray, shape (4, band + 1)
        The beam-smoothed TT, EE, BB, TE [muK^2].
    with_sky : bool
        Whether the last term is the sky's own P.
    jitter : float
        <sigma^2> / n_samples of the gain jitter, which adds white noise of variance
        jitter sigma_T^2 / N_hits per pixel whatever the angles (0: none).
    """

    term_n: tuple
    fields: tuple
    second: np.ndarray
    pseudo: np.ndarray
    readings: tuple
    sky_cl: np.ndarray
    with_sky: bool = False
    jitter: float = 0.0

    @property
    def n_leak(self) -> int:
        """The terms of the leak (all but the sky's P)."""
        return len(self.term_n) - int(self.with_sky)

    def scatter(self, mask: np.ndarray) -> float:
        """The white pseudo-C_BB [muK^2] of the hits' departures from their pixels' means, of the
        h_0 terms (the sky's own P scatters alike with and without the systematics: not a leak).
        Terms with n != 0 weigh each departure by exp(i n psi), which the rotations that null
        h_n cancel sample by sample (a 0/180 repeat nulls the pointing's scatter with its h_1):
        left out, at 0.2 % of the unrotated deep example's pointing delta_r."""
        scatter = sum(
            self.readings[k].scatter(self.fields[k], self.sky_cl, self.second[k, k].real, mask)
            for k in range(self.n_leak)
            if self.term_n[k] == 0
        )
        return scatter + self._jitter(mask)

    def _jitter(self, mask):
        """The gain jitter's white pseudo-C_BB: Omega_pix / 2 <w^2 jitter sigma_T^2 / N_hits>."""
        if not self.jitter:
            return 0.0
        hits = self.readings[0].hits
        if hits is None:
            raise ValueError("a gain jitter's prediction needs the hits per pixel")
        ell = np.arange(self.sky_cl.shape[1])
        variance_t = np.sum((2 * ell + 1) / (4 * np.pi) * self.sky_cl[0])
        seen = hits > 0
        inverse = np.sum(mask[seen] ** 2 / hits[seen]) / mask.size
        return 0.5 * (4 * np.pi / mask.size) * self.jitter * variance_t * inverse


def leak_model(
    systematics: Systematics,
    theory: Spectra,
    fwhm_arcmin: float,
    band: int,
    nside: int,
    *,
    n_max: int = 4,
    instrument: Instrument | None = None,
    hits: np.ndarray | None = None,
    with_sky: bool = False,
    evaluation: str = "interp",
    plate_ip: complex = 0.0,
    deprojected: tuple = (),
) -> LeakModel:
    """The leak's terms of a budget (:func:`expected_residual` says how each enters).

    Parameters
    ----------
    systematics, theory, fwhm_arcmin, instrument, hits
        As :func:`expected_residual`.
    band, nside : int
        The sky's band limit; the maps' resolution.
    n_max : int
        The highest moment the beams' terms may use.
    with_sky : bool
        Add the sky's own P (coefficient 1) as the last term.
    evaluation : {"interp", "exact"}
        How the engine reads the values of the sky's fields (:func:`sky_fields`).
    plate_ip : complex
        epsilon exp(i phase) of a HWP's instrumental polarisation in front of pairs whose
        4 x angles cancel: the term epsilon exp(i phase) T through the crossing angles' own h_2
        (h_{2,0}, :func:`boresight.predict.hwp.ip_delta_p`), put just before the sky's
        P. Here ``systematics`` and ``instrument`` are the pairs' as the bare pairs at their
        reflected angles carry them (:func:`boresight.instrument.hwp.reflected_systematics`,
        :func:`boresight.instrument.hwp.mirrored`), whose h_n are those of psi + 2 chi. 0: none.
    deprojected : tuple of str
        Template sets a pipeline deprojects (:class:`boresight.mitigation.Deprojection`'s
        ``templates``): the leaks of T they fit go (:func:`boresight.predict.terms.deprojected_by`).

    Returns
    -------
    LeakModel
    """
    refuse_added(systematics, "the exact expectation")
    if abs(coefficients(systematics, instrument).m4) > 1e-9:
        raise ValueError("the exact expectation needs pairs whose 4 x angles cancel (m_4 = 0)")
    sky_cl = smoothed_spectra(theory, fwhm_arcmin, band)
    fields, value, exact = read = sky_fields(nside, band, hits=hits, evaluation=evaluation)
    terms = budget_terms(systematics, read)
    mean, second, pseudo = coefficient_moments(systematics, instrument)
    gone = deprojected_by(deprojected)
    kept = [k for k, name in enumerate(MOMENT_NAMES) if name in terms and name not in gone]
    ns = [terms[MOMENT_NAMES[k]][0] for k in kept]
    field_list = [fields[terms[MOMENT_NAMES[k]][1]] for k in kept]
    readings = [terms[MOMENT_NAMES[k]][2] for k in kept]
    second, pseudo, mean = second[np.ix_(kept, kept)], pseudo[np.ix_(kept, kept)], mean[kept]
    fixed = []
    if systematics.has_beams:
        filters = beam_filters(systematics, instrument, (0.0,), fwhm_arcmin, band, n_max=n_max)
        for n, filt in filters.items():
            if np.any(filt):
                ns.append(n)
                field_list.append(fp.SkyField(2 - n, filt * exact.window))  # n > 2: conj(H_n)
                readings.append(exact)
                fixed.append(1.0)
    if plate_ip:
        ns.append(2)
        field_list.append(fields["temperature"])
        readings.append(value)
        fixed.append(complex(plate_ip))
    if with_sky:
        ns.append(0)
        field_list.append(fields["polarisation"])
        readings.append(value)
        fixed.append(1.0)
    second, pseudo, mean = _with_fixed(second, pseudo, mean, fixed)
    coefs = coefficients(systematics, instrument)
    jitter = jitter_variance(systematics, coefs, expected=True) / coefs.n_samples
    return LeakModel(
        tuple(ns), tuple(field_list), second, pseudo, tuple(readings), sky_cl, with_sky, jitter
    )


class _OffsetTerms(NamedTuple):
    """The leak terms' first-order changes across their pixels: each term's weight alm, spin,
    field, and the leak term whose coefficient it shares."""

    alms: list
    spins: list
    fields: list
    parents: list


def offset_weights(offsets: np.ndarray, n: int) -> tuple:
    """The first-order weights of a leak term h_n F across its pixels: (1/N) sum exp(i n psi)
    conj(delta) on d F (weight spin n - 1) and (1/N) sum exp(i n psi) delta on dbar F (spin
    n + 1), from :func:`boresight.moments.centroid_moments`' ``offsets`` (..., 2, >= ``|n|`` + 1,
    npix); h_-n's are the conjugates of h_n's other one."""
    n_have = offsets.shape[-2] - 1
    if abs(n) > n_have:
        raise ValueError(f"offsets hold n <= {n_have}, a term needs {abs(n)}")
    if n >= 0:
        return offsets[..., 1, n, :], offsets[..., 0, n, :]
    return np.conj(offsets[..., 0, -n, :]), np.conj(offsets[..., 1, -n, :])


def _offset_terms(model, offsets, mask, lw, nthreads):
    """For every leak term k, h_n F: its :func:`offset_weights` / 2 on F's raising and lowering
    derivatives."""
    out = _OffsetTerms([], [], [], [])
    for k in range(model.n_leak):
        n = model.term_n[k]
        for weight, raising in zip(offset_weights(offsets, n), (True, False)):
            spin = n - 1 if raising else n + 1
            w = fp.Weight(spin, 0.5 * mask * weight, None)
            out.alms.append(fp.weight_alm(w, lw, nthreads))
            out.spins.append(spin)
            out.fields.append(fp.derivative(model.fields[k], raising=raising))
            out.parents.append(k)
    return out


def smoothed_spectra(theory: Spectra, fwhm_arcmin: float, band: int) -> np.ndarray:
    """The sky's TT, EE, BB, TE (4, band + 1) [muK^2], smoothed by the beam."""
    tt, ee, bb, te = theory.total(lmax=band)
    beam = hp.gauss_beam(fwhm_arcmin * ARCMIN, lmax=band, pol=True)
    return np.array([tt * beam[:, 0] ** 2, ee * beam[:, 1] ** 2, bb * beam[:, 2] ** 2,
                     te * beam[:, 0] * beam[:, 1]])  # fmt: skip


def sky_fields(
    nside: int, band: int, *, hits: np.ndarray | None = None, evaluation: str = "interp"
) -> tuple:
    """The sky's fields by kind ("temperature", "template", "gradient", "conjugate gradient",
    "polarisation", "conjugate polarisation"), each as the hits read it (:class:`_Reading`),
    and the two readings: of the values (the engine's ``evaluation``, "interp" or "exact") and
    exact."""
    if evaluation not in METHODS:
        raise ValueError(f"evaluation must be one of {METHODS}, got {evaluation!r}")
    kinds = ("exact" if evaluation == "exact" else "value", "exact")
    value, exact = (_Reading(hits, nside, band, kind) for kind in kinds)
    return fields_by_kind(value.window, exact.window), value, exact


def budget_terms(systematics: Systematics, read: tuple) -> dict:
    """The leak's terms a budget switches on, by coefficient name (:data:`MOMENT_NAMES` order):
    (moment n, the kind of field it multiplies, the field's :class:`_Reading`), from ``read``,
    the output of :func:`sky_fields`; the pointing's gradient is read exactly, the other fields
    by value."""
    _, value, exact = read
    out = {}
    for name in MOMENT_NAMES:
        if _kept(name, systematics):
            n, kind = TERM_FIELDS[name]
            out[name] = (n, kind, exact if "gradient" in kind else value)
    return out


def expected_residual(
    h: np.ndarray,
    mask: np.ndarray,
    systematics: Systematics,
    theory: Spectra,
    fwhm_arcmin: float,
    *,
    lmax: int,
    band: int | None = None,
    instrument: Instrument | None = None,
    hits: np.ndarray | None = None,
    evaluation: str = "interp",
    offsets: np.ndarray | None = None,
    hwp: HWP | None = None,
    plate_h: np.ndarray | None = None,
    nthreads: int = 0,
    deprojected: tuple = (),
) -> ExpectedResidual:
    """The exact expected leaked and total residual pseudo-C_BB of a schedule's h_n maps.

    Parameters given as {mean, rms} enter by their moments over the focal plane's draws
    (:func:`boresight.predict.coefficient_moments`): the coherent part through the mean
    coefficients and the scattered part through their variance over N pairs. The beams enter
    by their filters (:func:`boresight.predict.beam_filters`) to the moments ``h`` holds. The
    leak's template is the sky's T. The map-maker's h_4 coupling must vanish (m_4 = 0,
    :func:`boresight.predict.supports`).

    Parameters
    ----------
    h : numpy.ndarray, complex, shape (n_max + 1, npix)
        h_0..h_n_max (n_max >= 4) of the schedule (0 off the footprint).
    mask : numpy.ndarray, shape (npix,)
        The analysis mask (RING).
    systematics : boresight.instrument.pairs.Systematics
    theory : boresight.cosmology.Spectra
    fwhm_arcmin : float
        The sky's beam.
    lmax : int
        The pseudo-spectra's band limit.
    band : int, optional
        The sky's band limit (default lmax).
    instrument : boresight.instrument.pairs.Instrument, optional
    hits : numpy.ndarray, shape (npix,), optional
        Samples per pixel, for hits spread over their pixels as a schedule's are, read as the
        engine reads them (bilinear interpolation of the maps, the beams' fields exactly): each
        field's pixel mean takes its window (:class:`_Reading`) and, for the h_0 terms, each
        hit's departure from it adds white power of variance sigma_in^2 / N_hits per pixel
        (:meth:`LeakModel.scatter`). Default: every field read at the pixel centres (exact).
    evaluation : {"interp", "exact"}
        The engine's ``evaluation`` of the values of T, P and the leak's template with ``hits``:
        bilinear interpolation of the maps, or the band-limited sky at each hit; the pointing's
        gradient is read exactly either way.
    offsets : numpy.ndarray, complex, shape (2, >= n_max + 1, npix), optional
        The samples' offsets from their pixel centres weighted as the h_n are
        (:func:`boresight.moments.centroid_moments`), for a sky read exactly at each sample.
        Each leak term h_n F then gains F's first-order change across the pixel,
        (conj(delta) d F + delta dbar F) / 2 averaged as h_n is: two more terms of the same
        coefficient, on F's spin-raising and lowering derivatives
        (:func:`boresight.predict.field_products.derivative`). A real scan crosses a pixel along
        a few lines, at places that depend on the crossing angle, and so on structure at the
        pixel scale a leak reads more than its pixel centre (docs/conventions.md).
    hwp : boresight.instrument.hwp.HWP, optional
        A HWP in front of the pairs (:func:`boresight.instrument.hwp.pairs_behind`): ``h`` is then of their
        reflected angle psi + 2 chi, ``systematics`` and ``instrument`` their own, and the
        plate's IP reaches the maps through ``plate_h``'s h_2, the crossing angles' own.
        Not with ``offsets``.
    plate_h : numpy.ndarray, complex, shape (>= 3, npix), optional
        The crossing angles' own h_n (h_{n,0}), where the plate has an IP.
    nthreads : int
    deprojected : tuple of str
        Template sets the pipeline deprojects, fitted from the sky itself (:func:`leak_model`):
        the leaks of T they fit go, the rest is as without them.

    Returns
    -------
    ExpectedResidual
    """
    band = lmax if band is None else band
    plate_ip = 0.0
    if hwp is not None and hwp.present:
        if offsets is not None:
            raise ValueError(OFFSETS_BEHIND_HWP)
        systematics, instrument, plate_ip = pairs_behind(hwp, systematics, instrument)
        if plate_ip and plate_h is None:
            raise ValueError("a HWP's IP: give plate_h, the crossing angles' own h_n")
    n_max = h.shape[0] - 1
    if n_max < 4:
        raise ValueError(f"h must hold h_0..h_4 at least, got {h.shape[0]} moments")
    nside = hp.npix2nside(h.shape[1])
    model = leak_model(
        systematics, theory, fwhm_arcmin, band, nside, n_max=n_max, instrument=instrument,
        hits=hits, with_sky=True, evaluation=evaluation, plate_ip=plate_ip,
        deprojected=deprojected,
    )  # fmt: skip
    lw = lmax + band
    alms = {}
    for n in set(abs(n) for n in model.term_n):  # h_-n's weight has the (E, B) of h_n's conjugate
        alms[n] = fp.weight_alm(fp.Weight(n, mask * h[n], None), lw, nthreads)
    spins, fields = list(model.term_n), list(model.fields)
    term_alms = [alms[abs(n)] for n in spins]
    k = model.n_leak  # the sky's P is the last term
    if plate_ip:  # the plate's IP term, just before it
        term_alms[k - 1] = fp.weight_alm(fp.Weight(2, mask * plate_h[2], None), lw, nthreads)
    second, pseudo = model.second, model.pseudo
    if offsets is not None:
        extra = _offset_terms(model, offsets, mask, lw, nthreads)
        rows = list(range(k)) + extra.parents + list(range(k, len(spins)))
        second, pseudo = second[np.ix_(rows, rows)], pseudo[np.ix_(rows, rows)]
        spins = spins[:k] + extra.spins + spins[k:]
        fields = fields[:k] + extra.fields + fields[k:]
        term_alms = term_alms[:k] + extra.alms + term_alms[k:]
        k += len(extra.parents)
    total = fp.expected_pseudo_cl_alm(
        term_alms, spins, fields, model.sky_cl, lmax, second=second, pseudo=pseudo
    ).bb
    leaked = fp.expected_pseudo_cl_alm(
        term_alms[:k], spins[:k], fields[:k], model.sky_cl, lmax,
        second=second[:k, :k], pseudo=pseudo[:k, :k],
    ).bb  # fmt: skip
    alone = fp.expected_pseudo_cl_alm(term_alms[k:], spins[k:], fields[k:], model.sky_cl, lmax).bb
    scatter = model.scatter(mask)
    return ExpectedResidual(leaked + scatter, total - alone + scatter)


def _kept(name, systematics):
    """Whether the coefficient's term is on."""
    if name == "s2":
        return systematics.has_leak
    if name in ("g1", "g3"):
        return systematics.has_pointing
    return True


def _with_fixed(second, pseudo, mean, fixed):
    """The moments with deterministic coefficients ``fixed`` appended (1 for the beams' terms,
    whose filters carry their coefficients, and for the sky's P; a HWP's IP's own):
    E[c c'^*] = E c conj(c') for those."""
    k = mean.size
    out_mean = np.concatenate([mean, np.asarray(fixed, dtype=np.complex128)])
    out_second = np.outer(out_mean, np.conj(out_mean))
    out_pseudo = np.outer(out_mean, out_mean)
    out_second[:k, :k], out_pseudo[:k, :k] = second, pseudo
    return out_second, out_pseudo, out_mean


class _Reading:
    """How the hits read a kind of field: "value" (bilinear interpolation of the maps: T, P,
    the leak's template) or "exact" (the beams' fields, evaluated at the hit, and the pointing's
    gradient: the engine's f(x + rho) - f(x) of the interpolated maps follows the TOD with the
    exact reading's window, where :func:`interpolation_window`'s gradient window was measured 1.4x
    too low in the TOD's leaked power, docs/conventions.md). ``window`` (band + 1,) is the amplitude window of
    the pixel mean, the square root of the pair window of
    :func:`boresight.predict.interpolation_window` or :func:`boresight.predict.hit_spread_window`;
    1 at pixel centres (``hits`` None)."""

    def __init__(self, hits, nside, band, kind):
        self.hits = hits
        if hits is None:
            self.window, self.point = np.ones(band + 1), np.ones(band + 1)
            return
        if kind == "exact":
            pair, self.point = hit_spread_window(nside, band), np.ones(band + 1)
        else:
            pair, self.point = interpolation_window(nside, band)
        self.pair = pair
        self.window = np.sqrt(pair)

    def scatter(self, field, sky_cl, power, mask):
        """The white pseudo-C_BB (a number) of a term of E``|c|^2`` = ``power`` from each hit's
        departure from its pixel's mean: Omega_pix / 2 <w^2 / N_hits> sigma_in^2, sigma_in^2 =
        sum_l (2l + 1) / 4 pi C^FF_l (point - pair) of the unwindowed field."""
        if self.hits is None:
            return 0.0
        window = np.where(self.window > 0, self.window, 1.0)
        unwindowed = fp.SkyField(field.spin, field.filters / window)
        c, _ = fp.field_cross_spectra([unwindowed], sky_cl)
        ell = np.arange(c.shape[-1])
        sigma2 = np.sum((2 * ell + 1) / (4 * np.pi) * c[0, 0].real * (self.point - self.pair))
        seen = self.hits > 0
        inverse = np.sum(mask[seen] ** 2 / self.hits[seen]) / mask.size
        return 0.5 * (4 * np.pi / mask.size) * inverse * sigma2 * power
