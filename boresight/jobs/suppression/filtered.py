"""What boresight rotation buys a pipeline that filters before binning.

Each systematic of :data:`CASES` runs alone on a real schedule's CES set, the paper's Q and U
pairs on the boresight or every pair of a focal plane from its own place, through the boresight
schedules of :data:`boresight.jobs.suppression.hwp.SCHEDULES`, in two pipelines: the maps binned
from the raw pair differences, and from the pair differences a pipeline filtered first
(:class:`boresight.mitigation.Filtering`, :func:`boresight.engine.simulate_schedule`). Every row is
one run of the one job (:func:`boresight.jobs.residual.residual`) against the no-systematic maps of
the same pipeline and schedule, so the filter acts on the leak as on the sky: its leaked
pseudo-C_BB <dB, dB> is binned in three bands, divided by the same schedule's raw leak (what the
filter takes) and by its own pipeline's leak without rotation (what rotation buys in that
pipeline). The spectra share the raw unrotated reference's footprint, its pixels with a
reciprocal condition number above :data:`~boresight.jobs.suppression.hwp.RCOND_FOOTPRINT`.

The filter takes signal as well as leak. Its transfer function on the CES set once
(:func:`boresight.jobs.transfer.transfer_function`, SOOPERCOOL's estimator, :data:`N_SIMS` pairs
of pure skies; pure T skies too, through each detector's filtered TOD, for F_ell^TT, where the
pipeline does not deproject) gives F_ell^BB per band, and each filtered row's leak over raw
divided by it is the leak's bias on r in the filtered pipeline, whose spectra are corrected by
F_ell^BB, over its bias in the raw one ("corrected over raw"). A filtered leak is measured here,
not predicted: its prediction from h_n is still to come (a design for a filtering pipeline
simulates each unit's, :mod:`boresight.design.filtered`).

Each row's delta_r (:func:`boresight.predict.delta_r` of its leak, corrected by F_ell^BB in the
filtered pipeline, against the tensor template through the footprint) is read against its
pipeline's sigma(r) (:func:`boresight.noise.sigma_r`, over the table's bands): a survey's noise
(by default a white :data:`DEPTH_UK_ARCMIN` over the footprint's sky fraction, with the sky's
beam), raw, and filtered with N_ell / F_ell^BB, its E purified ("sigma_r"); beside it, the
filtered sigma(r) where the sky's E that the filter moves into B, T^(EE->BB) C_ell^EE / F_ell^BB,
is not purified ("sigma_r unpurified"; a few pure skies estimate T^(EE->BB) no better than its
error, which the verdict prints), and the r that E fakes there ("delta_r of its E in B", the raw
unrotated sky's pseudo-C_EE times T^(EE->BB) per band over F_ell^BB, and its error from
T^(EE->BB)'s). The noise is the raw survey's read through the filter's
transfer of the sky: a filter takes part of the noise too, so these are upper bounds; beside
them, for a pipeline that filters without templates, "sigma_r its noise filtered" reads
N_ell K_BB / F_ell^BB, with K_BB what the filter keeps of a white noise's BB per band ("N_BB kept
<band>", :func:`boresight.jobs.transfer.noise_transfer`).

A pipeline that deprojects templates of T (:class:`boresight.mitigation.Deprojection`) runs here
as one that filters; its transfer function's skies carry a T of their own. The no-systematic
maps of the table's sky (T, E and B correlated as CAMB's) give what each pipeline keeps of the
sky's own E and B per band over the raw pipeline's (``Result.kept``): the filter's loss and what
the templates take through the TE correlation (a spin-2 template, ellipticity, fits E).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from ... import harmonics, predict, spectra
from ..._util import interrupts
from ...config import RunOptions
from ...cosmology import load_spectra
from ...coupling import mask_coupling
from ...instrument.pairs import Instrument, Spread, Systematics
from ...mitigation import Filtering, ces_scans
from ...noise import SurveyNoise, sigma_r
from ...predict.template_cost import template_cost
from ..compare_scans import on_focalplane
from ..residual import reference_from_maps, residual, simulate_maps
from ..transfer import NoiseTransfer, Transfer, noise_transfer, transfer_function
from ..transforms import Transforms
from .axis import CATALOGUE, Entry
from .hwp import RCOND_FOOTPRINT, ROUNDING, SCHEDULES, bands, boresight_label, leak_markdown

if TYPE_CHECKING:
    from ...instrument.focalplane import FocalPlane
    from ...schedule import Schedule
    from ...sky import Sky

#: the systematics of the table, by their name in the suppression map's catalogue: a leak of T
#: through h_2, of grad T through h_1 and h_3, of T through h_2 with its own template, and of P
#: through h_0
CASES = tuple(e for e in CATALOGUE if e.name in ("gain", "pointing", "leak", "angle"))
#: a focal plane's own systematics, drawn per pair (``Systematics.seed`` 1): gains scattered about
#: zero and pointing offsets of scattered size and direction, so that no two pairs leak alike and
#: a rotation cancels only what each pair's own h_n lets it (the cases of the hexagon's table)
SCATTERED = (
    Entry(
        "gain",
        "dg = {mean 0, rms 0.01} per pair",
        "h_2 T, h_4 P*",
        Systematics(dg=Spread(0.0, 0.01), seed=1),
    ),
    Entry(
        "pointing",
        "rho = {mean 0.1, rms 0.05} arcmin, chi = {mean 0, rms 90} deg per pair",
        "h_1, h_3 grad T",
        Systematics(rho_arcmin=Spread(0.1, 0.05), chi_deg=Spread(0.0, 90.0), seed=1),
    ),
)
#: the raw pipeline's label
RAW = "raw"
#: the pairs of pure skies of the table's transfer function
N_SIMS = 4
#: boresight schedules whose leaks (summed over the bands) lie within this factor leak alike
ALIKE = 1.01
#: the table's default survey: a white polarisation depth [muK arcmin] (an SO-SAT-like level,
#: ``examples/budget_deep_sat.toml``'s) over the footprint's sky fraction
DEPTH_UK_ARCMIN = 3.0


@dataclass
class Result:
    """The table's rows and each row's leaked pseudo-C_BB per ell (for the figure).

    Parameters
    ----------
    rows : list of dict
    spectra : dict
        (systematic, pipeline: "raw" or the filtering's text, boresight label) -> leaked
        pseudo-C_BB (lmax + 1,) [muK^2].
    edges : numpy.ndarray
        The bands' edges.
    transfer : boresight.jobs.transfer.Transfer
        The filter's transfer function on the CES set once, in those bands.
    noise : boresight.noise.SurveyNoise
        The survey whose sigma(r) each row's delta_r is read against.
    template : numpy.ndarray
        The pseudo-C_BB of tensors at r = 1 through the footprint (lmax + 1,) [muK^2], each
        row's delta_r's template.
    sky_ee : numpy.ndarray
        The raw unrotated no-systematic maps' pseudo-C_EE (lmax + 1,) [muK^2], whose share the
        filter moves into B fakes "delta_r of its E in B".
    kept : list of dict
        Per pipeline and boresight schedule, the pseudo-C_EE and C_BB of the no-systematic maps
        per band over the raw pipeline's on the same schedule ("EE kept <band>", "BB kept
        <band>"); for a pipeline that only deprojects templates of the sky itself, beside them
        the spin rule's prediction ("EE kept predicted <band>", "BB kept predicted <band>").
    noise_kept : boresight.jobs.transfer.NoiseTransfer, optional
        What a filter keeps of white noise per band (none for a pipeline that deprojects), whose
        B part gives each filtered row's "sigma_r its noise filtered".
    """

    rows: list
    spectra: dict
    edges: np.ndarray
    transfer: Transfer
    noise: SurveyNoise
    template: np.ndarray
    sky_ee: np.ndarray
    kept: list
    noise_kept: NoiseTransfer | None = None


def run(
    schedule: Schedule,
    sky: Sky,
    filtering: Filtering,
    *,
    schedules=SCHEDULES,
    cases: tuple[Entry, ...] = CASES,
    run_options: RunOptions = RunOptions(),
    n_sims: int = N_SIMS,
    focalplane: FocalPlane | None = None,
    noise: SurveyNoise | None = None,
    depth_uk_arcmin: float = DEPTH_UK_ARCMIN,
    progress: bool = False,
) -> Result:
    """Every case raw and filtered, through each boresight schedule, and the filter's transfer
    function.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
        Its CES set; its own repeats are replaced by each of ``schedules``.
    sky : boresight.sky.Sky
        lmax >= 2 Nside.
    filtering : boresight.mitigation.Filtering
        Not none.
    schedules : sequence of sequence of float
        Boresight angles of the CES set's repeats [deg].
    cases : tuple of boresight.jobs.suppression.axis.Entry
        The systematics, each a row per pipeline and schedule (default :data:`CASES`;
        :data:`SCATTERED` draws a focal plane's gains and pointing per pair).
    run_options : boresight.config.RunOptions
    n_sims : int
        The transfer function's pairs of pure skies.
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        The pairs, each on its own samples (default the paper's Q and U pairs on the axis); a
        value given per Q and U pair goes to each pair by its angle
        (:func:`boresight.jobs.compare_scans.on_focalplane`).
    noise : boresight.noise.SurveyNoise, optional
        The survey of each row's sigma(r), with N_ell (default: ``depth_uk_arcmin`` white over the
        footprint's sky fraction, the sky's beam).
    depth_uk_arcmin : float
        Without ``noise``: the survey's white polarisation depth [muK arcmin].
    progress : bool

    Returns
    -------
    Result

    Raises
    ------
    ValueError
        No filter, or one the schedule cannot take (before any work).
    """
    if not filtering:
        raise ValueError("the filtered table needs a filter (e.g. p3+ground)")
    if filtering.deprojection.derivatives and run_options.evaluation != "exact":
        raise ValueError(
            f"deprojecting {filtering.deprojection} fits derivatives of T: run with evaluation "
            f"'exact', not {run_options.evaluation!r}"
        )
    ces_scans(filtering, schedule)  # a filter the CESs cannot take, before any work
    edges = bands(sky.nside)
    lmax = 2 * sky.nside
    names = [f"{lo}-{hi - 1}" for lo, hi in zip(edges[:-1], edges[1:])]
    pipelines = {RAW: Filtering(), str(filtering): filtering}
    rows, cls, first, kept, sky_power = [], {}, {}, [], {}
    sky_ee = None
    jobs = [(r, p) for r in schedules for p in pipelines]
    with Transforms() as transforms:
        footprint = None
        for repeats, pipeline in tqdm(jobs, desc="filtered table", disable=not progress):
            interrupts.check()
            scan = dataclasses.replace(schedule, repeat_boresight_deg=tuple(repeats))
            label = boresight_label(repeats)
            options = dict(run=run_options, filtering=pipelines[pipeline], focalplane=focalplane)
            ref_maps = simulate_maps(sky, scan, Instrument(), Systematics(), **options)
            if pipeline == RAW:  # the raw unrotated maps' footprint, shared by every row
                if footprint is None:
                    mask = (ref_maps.rcond > RCOND_FOOTPRINT).astype(float)
                    footprint = spectra.as_footprint(mask)
            reference = reference_from_maps(
                ref_maps, footprint, lmax, run=run_options, transforms=transforms
            )
            alm = footprint.alm(ref_maps.qu_at(footprint.pixels), lmax, 2)
            if pipeline == RAW and sky_ee is None:  # the raw unrotated sky's pseudo-C_EE
                sky_ee = harmonics.alm2cl(alm[0])
            power = [spectra.bin_spectrum(harmonics.alm2cl(a), edges)[1] for a in alm]
            sky_power[pipeline, label] = power
            row = {"pipeline": pipeline, "boresight": label}
            for field, mine, raw in zip("EB", power, sky_power[RAW, label]):
                row |= {f"{field * 2} kept {b}": float(x / y) for b, x, y in zip(names, mine, raw)}
            kept.append(row)
            for case in cases:
                systematics = case.systematics
                if focalplane is not None:
                    systematics = on_focalplane(systematics, focalplane)
                leak = residual(
                    sky,
                    scan,
                    systematics,
                    footprint,
                    lmax,
                    reference=reference,
                    transforms=transforms,
                    **options,
                ).auto
                cls[case.name, pipeline, label] = leak
                m = spectra.bin_spectrum(leak, edges)[1]
                raw = cls.get((case.name, RAW, label))
                r = spectra.bin_spectrum(raw, edges)[1]
                first.setdefault((case.name, pipeline), m)
                row = {
                    "systematic": case.name,
                    "amplitude": case.amplitude,
                    "pipeline": pipeline,
                    "boresight": label,
                    "through": case.coupling,
                }
                for band, mb, rb, fb in zip(names, m, r, first[case.name, pipeline]):
                    real = mb > ROUNDING  # a leak at rounding has no meaningful ratio: NaN
                    row[f"leak {band}"] = float(mb)
                    row[f"over raw {band}"] = float(mb / rb) if rb > ROUNDING else np.nan
                    row[f"over unrotated {band}"] = (
                        float(mb / fb) if real and fb > ROUNDING else np.nan
                    )
                rows.append(row)
    coupling = mask_coupling(mask, lmax, run_options.nthreads, band=sky.lmax)
    _predict_kept(kept, filtering, coupling, edges, names, sky)
    once = dataclasses.replace(schedule, repeat_boresight_deg=(0.0,))
    transfer = transfer_function(
        once,
        filtering,
        footprint,
        edges,
        nside=sky.nside,
        fwhm_arcmin=sky.fwhm_arcmin,
        n_sims=n_sims,
        run=run_options,
        focalplane=focalplane,
        intensity=not filtering.deprojection,  # the T block: each detector's TOD filtered
    )
    f_bb = transfer.entry("BB", "BB")
    f_tt = transfer.entry("TT", "TT") if "TT" in transfer.fields else None
    noise_kept = None
    if not filtering.deprojection:  # what the filter keeps of the noise itself
        noise_kept = noise_transfer(
            once,
            filtering,
            footprint,
            edges,
            nside=sky.nside,
            n_sims=n_sims,
            run=run_options,
            focalplane=focalplane,
        )
    theory = load_spectra()
    template = predict.tensor_template(
        coupling,
        theory,
        sky.fwhm_arcmin,
        sky.nside,
    )
    if noise is None:
        noise = SurveyNoise(
            fsky=float(np.mean(mask)), fwhm_arcmin=sky.fwhm_arcmin, depth_uk_arcmin=depth_uk_arcmin
        )
    kept_bb = np.clip(f_bb, 1e-12, 1.0)  # an estimate above 1 (its noise) keeps the whole band
    raw_sigma = sigma_r(noise, theory, edges)
    sigma = {  # (E purified, E leaked into B as the transfer function says)
        RAW: (raw_sigma, raw_sigma),
        str(filtering): (
            sigma_r(noise, theory, edges, transfer_bb=kept_bb),
            sigma_r(noise, theory, edges, transfer_bb=kept_bb, e_to_b=transfer.entry("BB", "EE")),
        ),
    }
    if noise_kept is not None:  # the noise filtered too: N_ell K_BB / F_BB, E purified
        own = sigma_r(noise, theory, edges, transfer_bb=kept_bb, noise_kept=noise_kept.entry("BB"))
    per_ell = spectra.per_ell(kept_bb, edges, lmax, outside=1.0)  # F_BB of each multipole
    # unpurified, the E the filter moves into B fakes an r of its own: T^(EE->BB) times the sky's
    # pseudo-C_EE, corrected by F_BB (and the same with T's error)
    e_in_b = [
        predict.delta_r(sky_ee * spectra.per_ell(t, edges, lmax, outside=0.0) / per_ell, template)
        for t in (transfer.entry("BB", "EE"), transfer.entry_error("BB", "EE"))
    ]
    for row in rows:
        raw = row["pipeline"] == RAW
        for band, f in zip(names, f_bb):
            row[f"F_BB {band}"] = 1.0 if raw else float(f)
            row[f"corrected over raw {band}"] = row[f"over raw {band}"] / row[f"F_BB {band}"]
        if f_tt is not None:  # what the filter keeps of T, beside what it keeps of B
            row |= {f"F_TT {b}": 1.0 if raw else float(f) for b, f in zip(names, f_tt)}
        if noise_kept is not None:  # and of the noise's B
            kept_noise = zip(names, noise_kept.entry("BB"))
            row |= {f"N_BB kept {b}": 1.0 if raw else float(k) for b, k in kept_noise}
        leak = cls[row["systematic"], row["pipeline"], row["boresight"]]
        row["delta_r"] = predict.delta_r(leak if raw else leak / per_ell, template)
        row["sigma_r"], row["sigma_r unpurified"] = sigma[row["pipeline"]]
        if noise_kept is not None:
            row["sigma_r its noise filtered"] = raw_sigma if raw else own
        row["delta_r over sigma_r"] = row["delta_r"] / row["sigma_r"]
        row["delta_r of its E in B"] = 0.0 if raw else e_in_b[0]
        row["delta_r of its E in B error"] = 0.0 if raw else e_in_b[1]
    return Result(rows, cls, edges, transfer, noise, template, sky_ee, kept, noise_kept)


def _predict_kept(kept, filtering, coupling, edges, names, sky):
    """Beside what a pipeline that only deprojects templates of the sky itself keeps of the sky's
    E and B, the share the spin rule predicts (:mod:`boresight.predict.template_cost`: a spin-2
    template's definite share of E through C^TE, read through the footprint; the blocks' chance
    projection left out): "EE kept predicted <band>", "BB kept predicted <band>"."""
    deprojection = filtering.deprojection
    if filtering.filters or not deprojection or deprojection.template_map is not None:
        return
    lmax = 2 * sky.nside
    cost = template_cost(
        load_spectra(), lmax=lmax, fwhm_arcmin=sky.fwhm_arcmin, templates=deprojection.templates
    )
    pair = cost.pseudo_kept(coupling, edges)
    for row in kept:  # the raw pipeline keeps the whole sky
        for field, predicted in zip("EB", pair):
            values = np.ones_like(predicted) if row["pipeline"] == RAW else predicted
            row |= {f"{field * 2} kept predicted {b}": float(x) for b, x in zip(names, values)}


def tod_runs(schedules=SCHEDULES, cases=CASES, *, deprojects=False) -> int:
    """The TOD simulations of the table, counted in passes of the CES set: per boresight schedule
    (as many passes as its angles) and pipeline, a reference and every case; and the transfer
    function's pure T, E and B skies and the noise's realisations, raw and filtered (E and B
    alone for a pipeline that ``deprojects``)."""
    skies = 2 if deprojects else 4  # T, E, B and the noise's own, or E and B
    return sum(len(r) for r in schedules) * 2 * (1 + len(cases)) + 2 * skies * N_SIMS


def verdict(
    rows: list[dict],
    kept: list[dict] = (),
    *,
    noise: SurveyNoise | None = None,
    transfer: Transfer | None = None,
) -> str:
    """What the filter changes, in a few lines: its F_BB per band (and, given ``kept``, what it
    keeps of the sky's E and B without rotation); sigma(r) of each pipeline (its survey named
    when ``noise`` is given; with ``transfer``, the E it moves into B per band and its error);
    per systematic, what it keeps of the unrotated raw leak and of its bias on r (the leak
    corrected by F_BB), band by band, its delta_r without rotation in each pipeline over that
    pipeline's sigma(r), and the boresight schedule that leaks least (summed over the bands) in
    each pipeline."""
    pipelines = list(dict.fromkeys(r["pipeline"] for r in rows))
    bands_ = [k[5:] for k in rows[0] if k.startswith("leak ")]
    filtered_row = next(r for r in rows if r["pipeline"] != RAW)
    raw_first = next(r for r in rows if r["pipeline"] == RAW)
    f_bb = "/".join(_two(filtered_row[f"F_BB {b}"]) for b in bands_)
    f_tt = ""
    if f"F_TT {bands_[0]}" in filtered_row:
        f_tt = f", F_TT = {'/'.join(_two(filtered_row[f'F_TT {b}']) for b in bands_)} of its T"
    lines = [
        f"What the filter {pipelines[-1]} changes (leaked pseudo-C_BB, bands {'/'.join(bands_)}; "
        f"it keeps F_BB = {f_bb} of the sky's B{f_tt}):"
    ]
    sky = next((k for k in kept if k["pipeline"] != RAW), None)
    if sky is not None:
        ee, bb = ("/".join(_two(sky[f"{f} kept {b}"]) for b in bands_) for f in ("EE", "BB"))
        lines.append(f"  the sky's own E and B, without rotation: keeps {ee} of EE, {bb} of BB")
        if f"EE kept predicted {bands_[0]}" in sky:
            ee, bb = (
                "/".join(_two(sky[f"{f} kept predicted {b}"]) for b in bands_) for f in ("EE", "BB")
            )
            lines.append(
                f"  the spin rule predicts {ee} of EE, {bb} of BB (a spin-2 template's share of E "
                "through C^TE; the blocks' chance projection left out)"
            )
    survey = "" if noise is None else f" ({noise.summary()})"
    moved = ""
    if transfer is not None:
        into = zip(transfer.entry("BB", "EE"), transfer.entry_error("BB", "EE"))
        moved = f", where it moves {'/'.join(_share(t, e) for t, e in into)} of E into B"
    lines.append(
        f"  sigma(r){survey}: {_g(raw_first['sigma_r'])} raw, {_g(filtered_row['sigma_r'])} "
        f"filtered (N_ell / F_BB, E purified); {_g(filtered_row['sigma_r unpurified'])} with "
        f"the E it leaks into B unpurified{moved}, which alone fakes delta_r = "
        f"{_g(filtered_row['delta_r of its E in B'])} +- "
        f"{_g(filtered_row['delta_r of its E in B error'])}"
    )
    if "sigma_r its noise filtered" in filtered_row:
        k = "/".join(_two(filtered_row[f"N_BB kept {b}"]) for b in bands_)
        lines.append(
            f"  the filter keeps {k} of a white noise's BB too: with its noise filtered, "
            f"N_ell K_BB / F_BB, sigma(r) is {_g(filtered_row['sigma_r its noise filtered'])} "
            "(E purified; N_ell / F_BB above is its upper bound)"
        )
    for name in dict.fromkeys(r["systematic"] for r in rows):
        mine = [r for r in rows if r["systematic"] == name]
        unrotated = next(r for r in mine if r["pipeline"] != RAW)  # the first schedule's
        kept = [unrotated[f"over raw {b}"] for b in bands_]
        bias = [unrotated[f"corrected over raw {b}"] for b in bands_]
        best, alike = {}, True
        for pipeline in pipelines:
            leaks = {
                r["boresight"]: sum(r[f"leak {b}"] for b in bands_)
                for r in mine
                if r["pipeline"] == pipeline
            }
            best[pipeline] = min(leaks, key=leaks.get)
            alike &= max(leaks.values()) < ALIKE * min(leaks.values())
        kept_text, bias_text = ("/".join(_two(k) for k in x) for x in (kept, bias))
        if alike:
            choice = "no boresight schedule changes it in either pipeline"
        else:
            same = "the same" if len(set(best.values())) == 1 else "a different"
            choice = (
                f"least leak with {best[RAW]} raw, {best[pipelines[-1]]} filtered ({same} schedule)"
            )
        raw_row = next(r for r in mine if r["pipeline"] == RAW)  # the first schedule's
        r_text = ", ".join(
            f"{_g(r['delta_r'])} {label} ({_g(r['delta_r over sigma_r'])} sigma)"
            for r, label in ((raw_row, "raw"), (unrotated, "filtered"))
        )
        lines.append(
            f"  {name}: keeps {kept_text} of the raw leak without rotation, {bias_text} of its "
            f"bias on r once corrected by F_BB (delta_r {r_text}); {choice}"
        )
    return "\n".join(lines)


def _two(x):
    return "-" if not np.isfinite(x) else f"{x:.2f}"


def _g(x):
    return "-" if not np.isfinite(x) else f"{x:.3g}"


def _share(x, error):
    return f"{100 * x:.1f} +- {100 * error:.1f} %"


def markdown(rows: list[dict]) -> str:
    """The table, readable: the leak per band [muK^2], over the same schedule's raw leak, that over
    the filter's F_BB, and over its own pipeline's unrotated leak."""
    filtered_row = next(r for r in rows if r["pipeline"] != RAW)
    bands_ = [k[5:] for k in rows[0] if k.startswith("leak ")]
    f_bb = [filtered_row[f"F_BB {b}"] for b in bands_]
    note = (
        "\nleak: the leaked pseudo-C_BB <dB, dB> of the residual in each band [muK^2]; over raw: "
        "over the same boresight schedule's leak binned from the raw pair differences (what the "
        "filter takes); corrected over raw: that over the filter's F_BB, the leak's bias on r "
        "in the filtered pipeline over the raw one's; over unrotated: over its own pipeline's "
        "leak without rotation (what rotation buys in that pipeline). F_BB per band: "
        + ", ".join(f"{b}: {_two(f)}" for b, f in zip(bands_, f_bb))
        + (
            "; F_TT: " + ", ".join(f"{b}: {_two(filtered_row[f'F_TT {b}'])}" for b in bands_)
            if f"F_TT {bands_[0]}" in filtered_row
            else ""
        )
        + ".\n"
    )
    kinds = ("over raw", "corrected over raw", "over unrotated")
    r_note = (
        "\ndelta_r: the r the leak fakes (corrected by F_BB in the filtered pipeline), against "
        "its pipeline's sigma(r) (filtered: N_ell / F_BB, its E purified; the CSV's "
        "'sigma_r unpurified' adds the E the filter leaks into B).\n"
    )
    return (
        leak_markdown(rows, "pipeline", tuple((k, k) for k in kinds))
        + note
        + r_markdown(rows)
        + r_note
    )


def r_markdown(rows: list[dict]) -> str:
    """delta_r of each row and its pipeline's sigma(r), a row per systematic, pipeline and
    boresight schedule."""
    head = ["systematic", "pipeline", "boresight", "delta_r", "sigma(r)", "delta_r / sigma(r)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row["systematic"], row["pipeline"], row["boresight"]]
        cells += [_g(row[k]) for k in ("delta_r", "sigma_r", "delta_r over sigma_r")]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n" + "\n".join(lines) + "\n"
