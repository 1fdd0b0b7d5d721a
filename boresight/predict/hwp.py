"""The prediction behind a half-wave plate, off the axis: the pairs' T leaks, pointing and beams read
through the plate's moments h_{n,m}, the plate's instrumental polarisation, its synchronous
signal and the jitter of its angle (:mod:`boresight.moments.hwp` gives the moments;
docs/conventions.md, "Half-wave plates: the angle and the weights through it", derives them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from ..constants import DEG
from ..instrument.pairs import Systematics
from ..mapmaking import check_mapmaker, solve_iqu
from ..moments.hwp import (
    IP_BEHIND_TERMS,
    IP_TERMS,
    JITTER_TERMS,
    SYNCHRONOUS_TERMS,
)
from . import field_products as fp_products
from .pair_fields import (
    behind_plate,
    derivative_maps,
    field_map,
    hit_mean,
    hit_weights,
    leak_fields,
    polarisation_offset_y,
    solve_pairs,
    spread_window,
    taylor,
)

if TYPE_CHECKING:
    from ..instrument.hwp import HWP
    from ..moments.focalplane import FocalPlaneStats
    from ..sky import Sky


def beam_parts_behind(stats, params):
    """Behind a HWP, the beams' terms as (pair parameters, part, moments of n, across): each a
    bare pair's filters of that part, whose h_n become sums of scale x h_{n,m}, the T part's
    with the fields' change across the pixel (:func:`_sky_beam_y`).

    A beam's shape turns with the pair's own crossing angle psi, its polarisation axis with
    a = psi' + 2 delta_h (the reflected angle, and the plate's angle offset); the map-maker
    demodulates with psi'. So the T part's h_n is h_{n,4}. The polarised part is
    Re(exp(-2 i (a - psi)) C), with C = S_0 + i S_45: S_0 the bare beam's, S_45 that of the beam
    whose polarisation axis is 45 deg further from its shape (polarisation angle + 45 deg,
    ellipticity angle - 45 deg). Its Y is (exp(-4 i delta_h) sum_n h_{n,0} (G_0,n + i G_45,n)
    + exp(4 i delta_h) sum_n h_{n,8} (G_0,n - i G_45,n)) / 2 (docs/conventions.md); detectors
    at their nominal angles (:func:`boresight.instrument.hwp.check_systematics`)."""
    nominal = params._replace(
        pol_angle=np.zeros_like(params.pol_angle), nonortho=np.zeros_like(params.nonortho)
    )
    quarter = 0.25 * np.pi
    turned = nominal._replace(
        pol_angle=nominal.pol_angle + quarter,
        ellipticity_angle_a=nominal.ellipticity_angle_a - quarter,
        ellipticity_angle_b=nominal.ellipticity_angle_b - quarter,
    )
    turn = np.exp(4j * stats.hwp.angle_offset_deg * DEG)

    def moments(*scales):
        def of(n):
            return tuple((scale, stats.behind(n, m)) for m, scale in scales)

        return of

    return [
        (nominal, "T", moments((4, 1.0)), True),
        (nominal, "P", moments((0, 0.5 / turn), (8, 0.5 * turn)), False),
        (turned, "P", moments((0, 0.5j / turn), (8, -0.5j * turn)), False),
    ]


def temperature_across(sky, stats, shares, weights, fields, *, template, nthreads):
    """Behind a HWP, the pairs' leaks of T (a gain's t2, an additive leak's s2 of the sky's T)
    read across each pixel to second order (:func:`taylor`, the moments of
    :data:`boresight.moments.T_BEHIND_TERMS`): behind a spinning plate their h_{2,4} are
    incoherent sums, for which the spread window's mean over the pixel does not hold. Returns the
    fields with T at the pixels' centres, and the rest of the series' part of Y (npix,)."""
    names = [n for n in ("t2", "s2") if n in fields and (n == "t2" or template is None)]
    series = taylor(fp_products.temperature(np.ones(sky.lmax + 1)))
    fields = dict(fields)
    for name in names:
        fields[name] = field_map(sky, series[None][1], nthreads).real
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for offset, (scale, field) in series.items():
        if offset is not None and names:
            value = field_map(sky, field, nthreads)
            for name in names:
                y += scale * hit_mean(shares[name], weights, stats.behind(2, 4, offset)) * value
    return fields, y


def pointing_behind_y(sky, stats, params, shares, weights, *, spread, nthreads):
    """Behind a HWP, the parts of a pointing offset's Y that its moments of
    :func:`boresight.moments.pointing_behind` add to the T gradient's terms (npix,) complex:
    those terms' first-order change across the pixels, (conj(delta) d G + delta dbar G) / 2
    weighted as each term is (:func:`boresight.predict.field_products.derivative`; d G* =
    conj(dbar G)), and what detector B reads of P off its place
    (:func:`polarisation_offset_y`)."""
    window = spread_window(sky) if spread else np.ones(sky.lmax + 1)
    up, down = derivative_maps(sky, fp_products.gradient(window), nthreads)

    def mean(name, n, offset):
        return hit_mean(shares[name], weights, stats.behind(n, 4, offset))

    y = 0.5 * (mean("g1", 1, "conj") * up + mean("g1", 1, "delta") * down)
    y += 0.5 * (mean("g3", 3, "conj") * np.conj(down) + mean("g3", 3, "delta") * np.conj(up))
    return y + polarisation_offset_y(
        sky, stats, params, weights, spread=spread, nthreads=nthreads, order=1
    )


def pair_mean_w(moments, terms, what, pair_angles_deg, *, k=4):
    """<exp(-k i gamma)> over the pairs on the axis, once the moments hold ``terms``; 1 for a
    focal plane's combined moments, which carry each pair's (``pair_angles_deg`` None)."""
    missing = [t for t in terms if t not in moments]
    if missing:
        raise ValueError(f"the HWP's {what} needs h_(n,m) {missing}")
    if pair_angles_deg is None:
        return 1.0
    return np.mean(np.exp(-1j * k * np.radians(np.asarray(pair_angles_deg, dtype=np.float64))))


#: with detector A alone (the "single" map-maker), those of its I row too, which a plate that
#: does not spin within a pixel's samples couples to P
SINGLE_IP_TERMS = IP_TERMS + ((0, 4), (2, 4))


#: below this rcond a pixel's 3x3 system has no solution (the map-maker flags it)
SINGULAR = 1e-12


def ip_delta_p(
    sky: Sky,
    moments: dict,
    hwp: HWP,
    pair_angles_deg,
    *,
    mapmaker: str = "pairs",
    spread: bool = True,
    nthreads: int = 0,
) -> np.ndarray:
    """The spurious P = Q + i U of a HWP's instrumental polarisation (:func:`boresight.instrument.hwp.plate_signals`)
    in the map of pairs on the axis, as ``mapmaker`` (:data:`boresight.mapmaking.MAPMAKERS`)
    makes it.

    A pair at gamma behind the plate sees a = psi - gamma + 2 chi and the plate's epsilon I
    exp(i (2 psi + phase)) on the sky, so with w_i = exp(-4 i gamma_i) averaged over the pairs::

      Y = epsilon T [exp(i phase) h_{2,0} + exp(-i phase) <w> h_{2,8}],   H_4 = <w> h_{4,8}
      dP = (Y - H_4 Y*) / (1 - ``|H_4|^2``)

    the 2x2 solve of :func:`delta_p`, for the pair differences and for both detectors' own maps
    (whose I rows cancel). A spinning plate leaves h_{2,8} and h_{4,8} near zero:
    dP = epsilon T exp(i phase) h_{2,0}, the crossing angles' own moment, which boresight
    rotation cancels as it cancels a bare pair's h_2 (0/90 to rounding).

    Detector A alone (``mapmaker="single"``) solves I beside P from its one angle per sample, and
    sees the IP as epsilon T cos(4 chi - 2 gamma - phase), so its 3x3 system per pixel
    (:func:`boresight.mapmaking.solve_iqu`) couples I to P through <exp(2 i a)> =
    <exp(-2 i gamma)> h_{2,4} and takes the IP's mean, Re[epsilon T exp(i phase)
    <exp(2 i gamma)> h_{0,4}*], in its I row: both near zero behind a spinning plate, not behind
    one that steps per CES.

    Pairs off the axis, each on its own samples, take the map-maker's combination of their
    moments, each weighted by its exp(-i m gamma / 2): those of chi - gamma / 2
    (``hwp_moments(..., focalplane=, relative=True)``), with ``pair_angles_deg`` None.

    Parameters
    ----------
    sky : boresight.sky.Sky
    moments : dict
        (n, m) -> (npix,) h_{n,m} with :data:`IP_TERMS` (:data:`SINGLE_IP_TERMS` for detector A
        alone; :func:`boresight.moments.hwp_moments`): of the boresight's samples, or a focal
        plane's relative ones.
    hwp : boresight.instrument.hwp.HWP
    pair_angles_deg : sequence of float, or None
        Detector A's angle gamma of each pair [deg], all on the axis sharing the samples; None
        for a focal plane's relative moments, which carry them.
    mapmaker : {"pairs", "detectors", "single"}
    spread, nthreads
        As in :func:`delta_p`.

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    check_mapmaker(mapmaker)
    if mapmaker == "pairs-spin0":
        raise ValueError(
            "the plate's leak through a map-maker that deprojects is not predicted yet"
        )
    single = mapmaker == "single"
    terms = SINGLE_IP_TERMS if single else IP_TERMS
    w = pair_mean_w(moments, terms, "instrumental polarisation", pair_angles_deg)
    t = leak_fields(sky, Systematics(), None, spread=spread, nthreads=nthreads)["t2"]
    phase = np.exp(1j * hwp.ip_phase_deg * DEG)
    y = hwp.ip * t * (phase * moments[2, 0] + np.conj(phase) * w * moments[2, 8])
    if not single:
        return solve_pairs(y, w * moments[4, 8])
    w2 = pair_mean_w(moments, terms, "instrumental polarisation", pair_angles_deg, k=2)
    z2, z4 = w2 * moments[2, 4], w * moments[4, 8]
    mean = np.real(hwp.ip * t * phase * np.conj(w2 * moments[0, 4]))
    ones = np.ones_like(t)
    normal = np.stack(
        [ones, z2.real, z2.imag, (1 + z4.real) / 2, z4.imag / 2, (1 - z4.real) / 2, mean]
        + [y.real / 2, y.imag / 2],
        axis=1,
    )  # per sample, as the map-maker's sums over them: unseen pixels solve to 0
    _, q, u, _ = solve_iqu(normal, rcond_min=SINGULAR)
    return np.where(q != hp.UNSEEN, q + 1j * u, 0.0)  # 0 where the map-maker has no solution


def ip_delta_p_across(sky: Sky, stats: FocalPlaneStats, hwp: HWP, *, nthreads: int = 0):
    """The spurious P of a HWP's instrumental polarisation in the pair differences' map of a focal
    plane, from each pair's own moments with T read across the pixel.

    Pair i on its own samples gives, with the moments of :func:`boresight.moments.
    moments_behind` (chi - gamma)::

      Y = epsilon sum_i (N_i / N) [exp(i phase) <T h_{2,0}> + exp(-i phase) exp(4 i gamma_i)
          <T h_{2,8}>],   H_4 = sum_i (N_i / N) exp(4 i gamma_i) h_{4,8}

    :func:`ip_delta_p`'s formula with T read at each pair's samples to second order in their
    offsets from the pixel's centre (:func:`taylor`) rather than as its mean over the pixel: few
    samples per pixel, and h_{2,8} an incoherent sum behind a spinning plate, make that mean
    10 % off on a short schedule (docs/conventions.md).

    Parameters
    ----------
    sky : boresight.sky.Sky
    stats : boresight.moments.FocalPlaneStats
        Behind the plate with the IP's moments (``characterise_focalplane(..., per_pair=True,
        hwp=, ip=True)``).
    hwp : boresight.instrument.hwp.HWP
        Its ``ip`` and ``ip_phase_deg``.
    nthreads : int

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    if not (behind_plate(stats) and stats.has_behind(IP_BEHIND_TERMS)):
        raise ValueError(
            "the IP across the pixel needs characterise_focalplane(..., hwp=, ip=True)"
        )
    weights = hit_weights(stats)
    turn = np.exp(4j * np.radians(np.asarray(stats.focalplane.gamma_deg, dtype=np.float64)))
    phase = np.exp(1j * hwp.ip_phase_deg * DEG)
    y = np.zeros(stats.combined.hits.size, dtype=np.complex128)
    for offset, (scale, field) in taylor(fp_products.temperature(np.ones(sky.lmax + 1))).items():
        h = phase * hit_mean(np.ones_like(turn), weights, stats.behind(2, 0, offset))
        h += np.conj(phase) * hit_mean(turn, weights, stats.behind(2, 8, offset))
        y += scale * h * field_map(sky, field, nthreads)
    return solve_pairs(hwp.ip * y, hit_mean(turn, weights, stats.pair_h[:, 4]))


def synchronous_delta_p(moments: dict, hwp: HWP, pair_angles_deg) -> np.ndarray:
    """The spurious P of a HWP's synchronous signal (:func:`boresight.instrument.hwp.plate_signals`) in the
    pair differences' map, the plate at its nominal angle.

    The 4 chi part is common to a pair and leaves its difference. The 2 chi part, A_2 cos(2 chi -
    2 gamma - phi_2), is its difference; with a = psi - gamma + 2 chi and w = exp(-4 i gamma)
    averaged over the pairs on the axis::

      Y = A_2 [exp(i phi_2) h_{2,2} + exp(-i phi_2) <w> h_{2,6}],   H_4 = <w> h_{4,8}

    solved as in :func:`delta_p`. Pairs off the axis, each on its own samples, take the
    map-maker's combination of their moments, each pair's h_{2,6} and h_{4,8} weighted by its own
    w (:func:`boresight.moments.hwp.synchronous_weights`), with ``pair_angles_deg`` None. A spinning plate takes every
    term to zero; a stepped one leaves h_{2,2} = exp(2 i chi_k) h_2 per step, which boresight
    rotation cancels with h_2.

    Parameters
    ----------
    moments : dict
        (n, m) -> (npix,) h_{n,m} with :data:`SYNCHRONOUS_TERMS`
        (:func:`boresight.moments.hwp_moments`): of the boresight's samples, or a focal
        plane's weighted ones.
    hwp : boresight.instrument.hwp.HWP
    pair_angles_deg : sequence of float, or None
        Detector A's angle gamma of each pair [deg], all on the axis sharing the samples; None
        for a focal plane's weighted moments, which carry them.

    Returns
    -------
    numpy.ndarray, complex128, shape (npix,)
        [muK], 0 off the observed pixels.
    """
    w = pair_mean_w(moments, SYNCHRONOUS_TERMS, "synchronous signal", pair_angles_deg)
    phase = np.exp(1j * hwp.synchronous_phase_deg[0] * DEG)
    a2 = hwp.synchronous_muk[0]
    y = a2 * (phase * moments[2, 2] + np.conj(phase) * w * moments[2, 6])
    return solve_pairs(y, w * moments[4, 8])


def angle_jitter_leak(
    sky: Sky, hits: np.ndarray, moments: dict, hwp: HWP, *, pair_angles_deg, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """What a HWP angle's white jitter (:func:`boresight.instrument.hwp.plate_signals`) leaves in the pair
    differences' map, over its draws: the spurious P of its mean, and the
    variance and white pseudo-C_BB of the rest.

    A jitter j of rms sigma turns the pair's P to P exp(-4 i j), whose mean over the draws is
    mu P, mu = exp(-8 sigma^2): the mean leaves dP = (mu - 1) P, whatever the moments. The rest,
    X = P e with e = exp(-4 i j) - mu, E``|e|^2`` = v = 1 - exp(-16 sigma^2) and E[e^2] = c =
    exp(-32 sigma^2) - exp(-16 sigma^2), is the same for every pair at a sample. With z =
    exp(4 i a) of a pair at gamma = 0, W = <exp(-4 i gamma)> over the pairs and n_t the samples
    of a pixel, Y = (1 / n_t) sum_t (X + X* W z), so over the draws, with P the pixel's and
    h = h_{4,8}, H_4 = W h::

      E``|Y|^2`` = (v ``|P|^2`` (1 + ``|W|^2``) + 2 Re(c P^2 W* h*)) / n_t
      E[Y^2] = (c P^2 + 2 v ``|P|^2`` W h + c* P*^2 W^2 h_{8,16}) / n_t
      E``|dP|^2`` = (E``|Y|^2`` (1 + ``|H_4|^2``) - 2 Re(H_4* E[Y^2])) / (1 - ``|H_4|^2``)^2

    through the 2x2 solve (as :func:`jitter_bb` has it for a gain's jitter), white from pixel to
    pixel; half of it is B. Pairs off the axis, each on its own samples, see a pixel at other
    times, so their draws there are independent: each sample is its own pair's, with its own
    exp(-4 i gamma), which moments of chi - gamma / 2 carry (``hwp_moments(..., focalplane=,
    relative=True)``, ``pair_angles_deg`` None): the same formulas with W = 1 and n_t every
    pair's samples (pairs sharing a pixel at one time, closer than a pixel, are left out).

    Parameters
    ----------
    sky : boresight.sky.Sky
    hits : numpy.ndarray, shape (npix,)
        The boresight's samples per pixel, or every pair's off the axis
        (:func:`boresight.moments.hwp_moments`).
    moments : dict
        (n, m) -> (npix,) h_{n,m} with :data:`JITTER_TERMS`.
    hwp : boresight.instrument.hwp.HWP
        Its ``angle_jitter_deg``; no angle offset (the offset's own is :func:`delta_p`'s).
    pair_angles_deg : sequence of float, or None
        Detector A's angle of each pair on the axis [deg]; None off the axis (above).
    mask : numpy.ndarray, shape (npix,)
        The weights of the solved pixels.

    Returns
    -------
    dp : numpy.ndarray, complex128, shape (npix,)
        The mean's [muK], 0 off the observed pixels.
    variance : numpy.ndarray, shape (npix,)
        E``|dP - dp|^2`` [muK^2], 0 off the mask.
    white : float
        Its pseudo-C_BB, the same at every multipole [muK^2].
    """
    w = pair_mean_w(moments, JITTER_TERMS, "angle jitter", pair_angles_deg)
    sigma = hwp.angle_jitter_deg * DEG
    mu, v = np.exp(-8.0 * sigma**2), -np.expm1(-16.0 * sigma**2)
    c = np.exp(-32.0 * sigma**2) - np.exp(-16.0 * sigma**2)
    p = sky.maps[1] + 1j * sky.maps[2]
    dp = np.where(hits > 0, (mu - 1.0) * p, 0.0)
    on = (mask != 0) & (hits > 0)
    p, n, h, h8 = p[on], hits[on], moments[4, 8][on], moments[8, 16][on]
    h4 = w * h
    yy = (v * np.abs(p) ** 2 * (1 + abs(w) ** 2) + 2 * np.real(c * p**2 * np.conj(w * h))) / n
    y2 = (c * p**2 + 2 * v * np.abs(p) ** 2 * h4 + np.conj(c * p**2) * w**2 * h8) / n
    h4_sq = np.abs(h4) ** 2
    variance = np.zeros(mask.size)
    variance[on] = (yy * (1 + h4_sq) - 2 * np.real(np.conj(h4) * y2)) / (1 - h4_sq) ** 2
    white = 0.5 * (4 * np.pi / mask.size) * np.sum(mask**2 * variance) / mask.size
    return dp, variance, float(white)
