"""The residual B-mode of a real CES schedule beside its synthetic twin (paper section 3.1): one
pass and with the schedule's boresight repeats, each as the real scan and as the twin with its
(N_phi, R), on the mask where every reference is valid (:func:`compare_scans`)."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING

import numpy as np

from .. import engine, moments
from ..instrument.pairs import PAPER_GAIN, PAPER_POINTING, Instrument, Systematics
from ..spectra import Footprint, log_bins
from ..validation import require_finite
from .residual import band_rows, reference_from_maps, residual, simulate_maps

if TYPE_CHECKING:
    from .._util.provenance import Timer
    from ..instrument.focalplane import FocalPlane
    from ..moments.axis import ScanStats
    from ..schedule import Schedule
    from ..sky import Sky

#: the systematic each choice of ``systematic`` runs
SYSTEMATICS = {"gain": PAPER_GAIN, "pointing": PAPER_POINTING}
FIRST_BIN_ELL = 10  #: the first band's lowest ell


@dataclass
class Comparison:
    """What :func:`compare_scans` found.

    Parameters
    ----------
    stats : boresight.moments.ScanStats
        The real schedule's crossings, N_phi, R and h_n.
    observed : numpy.ndarray, bool, shape (npix,)
    rows : list of dict
        The binned residuals of the four scans (compare.csv).
    table : list of dict
        The survey means of ``|h_n|^2`` of the real scan and the twin (scan_stats.csv).
    """

    stats: ScanStats
    observed: np.ndarray
    rows: list
    table: list


def on_focalplane(systematics: Systematics, focalplane: FocalPlane) -> Systematics:
    """The paper's systematic on a focal plane's pairs: a value given per pair for its Q and U
    pairs (0 and 45 deg) goes to each pair by its angle, the Q pair's where cos 4 gamma > 0."""
    q_like = np.cos(4 * np.radians(focalplane.gamma_deg)) > 0
    per_pair = {}
    for f in fields(systematics):
        value = getattr(systematics, f.name)
        if isinstance(value, tuple) and len(value) == 2:
            per_pair[f.name] = tuple(float(value[0] if q else value[1]) for q in q_like)
    return replace(systematics, **per_pair)


def compare_scans(
    schedule: Schedule,
    sky: Sky,
    systematic: str,
    *,
    timer: Timer,
    tolerance_deg: float = 1.0,
    seed: int = 1,
    focalplane: FocalPlane | None = None,
) -> Comparison:
    """The residual B-mode of ``schedule`` beside its synthetic twin, at the sky's Nside and
    lmax = 2 Nside: one pass of the CES set and the whole schedule with its boresight repeats,
    each as the real scan (every pair of ``focalplane`` from its own place, default the paper's
    pairs on the boresight) and as the twin, which takes (N_phi, R) of one pass (``seed``) and
    repeats it at the schedule's angles. Writes nothing."""
    if systematic not in SYSTEMATICS:
        raise ValueError(f"systematic {systematic!r}; allowed: {tuple(SYSTEMATICS)}")
    nside = sky.nside
    if sky.lmax < 2 * nside:
        raise ValueError(
            f"the sky's lmax {sky.lmax} is under the comparison's 2 Nside = {2 * nside}"
        )

    def characterise(scan):
        if focalplane is None:
            return moments.characterise_schedule(scan, nside, tolerance_deg)
        return moments.characterise_focalplane(scan, focalplane, nside, tolerance_deg).combined

    with timer("characterise the schedule"):
        stats = characterise(schedule)
        # The twin takes (N_phi, R) of one pass of the CES set and repeats it at the schedule's
        # boresight angles, as the paper built its synthetic scans.
        single = characterise(schedule.single())
        twin = replace(
            single.synthetic_twin(seed=seed),
            rotations_deg=schedule.repeat_boresight_deg,
        )
        obs = stats.observed
    # One pass of the CES set, and the whole schedule with its boresight repeats, each as the
    # real scan and as its twin: the paper compared the unrotated scans.
    cases = {
        "real_one_pass": schedule.single(),
        "twin_one_pass": replace(twin, rotations_deg=(0.0,)),
        "real": schedule,
        "twin": twin,
    }
    # Validity depends on the crossing angles alone, so the references fix the common mask.
    refs, focal = {}, {name: focalplane if name.startswith("real") else None for name in cases}
    for name, scan in cases.items():
        with timer(f"reference {name.replace('_', ' ')}"):
            refs[name] = simulate_maps(
                sky, scan, Instrument(), Systematics(), pixels=obs, focalplane=focal[name]
            )
    mask = obs.copy()
    for ref in refs.values():
        mask &= ref.valid
    footprint = Footprint(mask.astype(float))
    lmax = 2 * nside
    curves, chosen = {}, SYSTEMATICS[systematic]
    for name, scan in cases.items():
        with timer(f"residual {name.replace('_', ' ')}"):
            reference = reference_from_maps(refs[name], footprint, lmax)
            curves[f"residual_{name}_bb"] = residual(
                sky,
                scan,
                chosen if focal[name] is None else on_focalplane(chosen, focalplane),
                footprint,
                lmax,
                reference=reference,
                focalplane=focal[name],
            ).total
    rows = band_rows(log_bins(FIRST_BIN_ELL, lmax, 12), curves)
    require_finite("the residual spectra", list(curves.values()))
    twin_h, _ = engine.scan_moments(twin, nside, pixels=obs)
    table = [
        dict(scan="real", **stats.survey_means()),
        dict(
            scan="twin",
            pixels=int(obs.sum()),
            **{
                f"mean_abs_h{n}_sq": float(np.mean(np.abs(twin_h[n, obs]) ** 2))
                for n in range(1, 5)
            },
        ),
    ]
    return Comparison(stats=stats, observed=obs, rows=rows, table=table)
