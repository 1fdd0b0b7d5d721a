"""The jobs behind the CLI, callable from Python: reproduce, simulate, predict_study, scan_stats,
compare_scans. Each runs the one residual job (:mod:`boresight.residual`) where it simulates.

Each writes into a staging directory that replaces ``out_dir`` only when the job has finished, so
an interrupted job leaves nothing behind, and an existing directory is kept unless ``force``.
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import replace
from typing import TYPE_CHECKING

import healpy as hp
import numpy as np

from . import (
    coupling,
    engine,
    interrupts,
    io,
    masks,
    paper,
    plots,
    precompile,
    predict,
    provenance,
    report,
    residual,
    resources,
    sky,
    spectra,
)
from .config import as_dict
from .cosmology import load_spectra

if TYPE_CHECKING:
    from collections.abc import Callable

    from .config import Study
    from .schedule import ScanMotion


def require_finite(what, values):
    """Refuse to report NaN or infinity as a result.

    Parameters
    ----------
    what : str
        The result's name, for the message.
    values : array_like

    Raises
    ------
    ValueError
    """
    if not np.isfinite(values).all():
        raise ValueError(f"{what} holds NaN or infinite values; nothing was written")


def reproduce(
    out_dir: str,
    study: Study = paper.preset(quick=True),
    force: bool = False,
    log: Callable = print,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list:
    """Run the paper's study and write figures, results.csv, report.md and manifest.json.

    ``study``: :func:`boresight.paper.preset` or :func:`boresight.paper.from_raw`. Returns the list
    of :class:`boresight.report.Claim` with computed verdicts.
    """
    io.check_output_dir(out_dir, force, study.inputs)
    nside = study.sky.nside
    estimate = resources.study_estimate("reproduce", study)
    resources.require(estimate, checks, log)
    results, stages = paper.run_study(study, log=log, progress=progress)
    rows = paper.tidy_rows(results, study)
    claims = report.evaluate_claims(results, rows, study)
    with io.staged_dir(out_dir, force, study.inputs) as stage:
        t0 = time.perf_counter()
        for name, angles, stem in (
            ("pointing_wide", [None, 180.0], "fig1_pointing_wide"),
            ("gain_deep", [None, 90.0], "fig2_gain_deep"),
            ("pointing_wide", [None, 180.0, 179.0, 160.0], "fig3_pointing_angles"),
            ("gain_deep", [None, 90.0, 89.0, 70.0], "fig4_gain_angles"),
        ):
            res = results[name]
            table = paper.band_table(res, rows, study)
            plots.residual_figure(res, table, study, angles, stage / stem)
        fig_nside = min(nside, 256)
        for survey, title, stem in (
            ("wide", "SO-like wide (LAT) footprint", "fig5_wide_mask"),
            ("deep", "SO-like deep (SAT) footprint", "fig6_deep_mask"),
        ):
            plots.footprint_figure(masks.survey_mask(survey, fig_nside), title, stage / stem)
        io.write_csv(stage / "results.csv", rows, paper.CSV_COLUMNS)
        stages["outputs"] = round(time.perf_counter() - t0, 3)
        io.write_text(stage / "report.md", report.report_markdown(claims, study, stages))
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                as_dict(study),
                {"sky": study.sky.seed, "scan": study.scan.seed},
                stages,
                estimate.as_dict(),
            ),
        )
    return claims


def simulate(
    study: Study,
    out_dir: str,
    force: bool = False,
    log: Callable = print,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """Simulate a study with and without its systematics and predict its residual.

    Writes FITS maps (I, Q, U, HITS, RCOND), spectra.csv (per multipole: the residual, its parts,
    the prediction and the pseudo-spectra of the maps with the systematic), bands.csv (the same
    band columns as a reproduction's results.csv), figures and manifest.json. Returns the
    per-multipole rows.
    """
    io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("simulate", study)
    resources.require(estimate, checks, log)
    timer = provenance.Timer(log)
    lmax, nthreads = study.output.lmax, study.run.nthreads
    kernels = precompile.kernels_for("study", study.run.backend, study.systematics.has_pointing)
    precompile.precompile(kernels, nthreads, timer)
    with timer("simulate and predict"):
        job, the_sky, mask = residual.from_study(study, keep_maps=True, progress=progress)
        ref, sim = job.maps
    with timer("spectra"):
        columns = job.columns()
        i_map = np.where(sim.valid, the_sky.maps[0], 0.0)
        maps = np.array([i_map, *sim.qu])
        pseudo = spectra.pseudo_spectra(maps, mask, lmax, nthreads, study.run.analysis)
    require_finite("the residual spectrum", job.total)
    require_finite("the pseudo-spectra", pseudo)
    columns.update({f"pseudo_{n}": pseudo[i] for i, n in enumerate(spectra.ORDER)})
    rows = [
        {"ell": ell, **{k: np.nan if v is None else v[ell] for k, v in columns.items()}}
        for ell in range(lmax + 1)
    ]
    bands = residual.band_rows(study.output.edges(), job.columns())
    with io.staged_dir(out_dir, force, study.inputs) as stage:
        if study.output.maps:
            for name, m in (("maps_systematics.fits", sim), ("maps_reference.fits", ref)):
                io.write_maps(
                    stage / name,
                    [np.where(m.valid, the_sky.maps[0], hp.UNSEEN), m.q, m.u, m.hits, m.rcond],
                    ["I", "Q", "U", "HITS", "RCOND"],
                    ["uK", "uK", "uK", "", ""],
                    comments=[
                        "I is the input sky's I where Q, U are valid: pair differences do not",
                        "measure I. HITS: hits x rotations; RCOND: 2x2 reciprocal condition.",
                    ],
                )
            both = sim.valid & ref.valid
            spurious = [
                np.where(both, a - b, hp.UNSEEN) for a, b in ((sim.q, ref.q), (sim.u, ref.u))
            ]
            plots.map_figure(spurious, ["Q spurious", "U spurious"], stage / "maps_spurious.png")
        io.write_csv(stage / "spectra.csv", rows, ["ell", *columns])
        io.write_csv(stage / "bands.csv", bands, list(bands[0]))
        plots.spectrum_figure(bands, stage / "residual")
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                study.raw,
                {"sky": study.sky.seed, "scan": study.scan.seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    return rows


def predict_study(
    study: Study,
    out_dir: str | None = None,
    force: bool = False,
    log: Callable = print,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """The analytic prediction of a study's residual pseudo-C_BB, without a simulation.

    Parameters
    ----------
    study : boresight.config.Study
        Its sky must be the theory's (no sky.maps).
    out_dir : str, optional
        Write prediction.csv and manifest.json there.
    force : bool
    log : callable
    checks : boresight.resources.Checks
        The memory and time checks to make.

    Returns
    -------
    list of dict
        ell, predicted_bb [muK^2] for ell = 0..output.lmax.
    """
    if study.sky_maps is not None:
        raise ValueError("predict uses the theory spectra; remove sky.maps from the config")
    if out_dir is not None:
        io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("predict", study)
    resources.require(estimate, checks, log)
    nside, lmax = study.sky.nside, study.output.lmax
    mask = masks.from_config(study.mask, nside)
    n_max = residual.n_max_for(study.systematics)
    mom = residual.moments(study.scan, nside, mask > 0, study.run, n_max)
    couplings = coupling.mask_coupling(mask, lmax, study.run.nthreads, band=study.sky.lmax)
    pred = predict.residual_pseudo_bb(
        mom.h,
        mask,
        couplings,
        study.systematics,
        load_spectra(),
        study.sky.fwhm_arcmin,
        study.instrument,
        rotations_deg=mom.rotations_deg,
        crossings=mom.crossings,
    )
    require_finite("the predicted spectrum", pred)
    rows = [dict(ell=ell, predicted_bb=pred[ell]) for ell in range(lmax + 1)]
    if out_dir is not None:
        with io.staged_dir(out_dir, force, study.inputs) as stage:
            io.write_csv(stage / "prediction.csv", rows, ["ell", "predicted_bb"])
            io.write_json(
                stage / "manifest.json",
                provenance.manifest(study.raw, {"scan": study.scan.seed}, {}, estimate.as_dict()),
            )
    return rows


def scan_stats(
    study: Study,
    out_dir: str,
    force: bool = False,
    n_max: int = 4,
    log: Callable = print,
    checks: resources.Checks = resources.Checks(),
    layout: str = "boresight",
    prefix: str = "hn",
) -> list[dict]:
    """Write the h_n, hit, N_phi and R maps of a study's scan, and their survey means.

    Parameters
    ----------
    study : boresight.config.Study
    out_dir : str
    force : bool
    n_max : int
        Highest moment written.
    log : callable
    checks : boresight.resources.Checks
        The memory and time checks to make.
    layout : {"boresight", "so"}
        The h_n maps as one FITS table ``hn_maps.fits`` (RE_H1.., IM_H1..), or in the SO/SMARTIES
        layout of :mod:`boresight.so_maps`.
    prefix : str
        File name prefix of the SO layout.

    Returns
    -------
    list of dict
        n, mean_abs_h2, mean_re, mean_im for n = 1..n_max.
    """
    _check_layout(layout, prefix)
    io.check_output_dir(out_dir, force, study.inputs)
    estimate = resources.study_estimate("scan-stats", study)
    resources.require(estimate, checks, log)
    nside = study.sky.nside
    obs = masks.from_config(study.mask, nside) > 0
    h, ncross = engine.scan_moments(study.scan, nside, pixels=obs, nthreads=study.run.nthreads)
    n_phi, r, _ = study.scan.per_pixel(np.arange(12 * nside**2), 12 * nside**2)
    return _write_scan_stats(
        out_dir, force, study.inputs, h, obs, ncross, n_phi, r, n_max, layout, prefix,
        config=as_dict(study), estimate=estimate,
    )


def schedule_stats(
    schedule_path: str,
    out_dir: str,
    nside: int = 128,
    motion: ScanMotion | None = None,
    force: bool = False,
    tolerance_deg: float = 1.0,
    log: Callable = print,
    checks: resources.Checks = resources.Checks(),
    layout: str = "boresight",
    prefix: str = "hn",
    frame: str | None = None,
    turnarounds: str | None = None,
    progress: bool = False,
) -> list[dict]:
    """:func:`scan_stats` of a CES schedule file (boresight's TOML or CSV, or TOAST's).

    Parameters
    ----------
    schedule_path : str
    out_dir : str
    nside : int
    motion : boresight.schedule.toast.ScanMotion, optional
        For a TOAST schedule: scan rate, acceleration and sample rate.
    force : bool
    tolerance_deg : float
        Crossing angles closer than this count as one in N_phi.
    log : callable
    checks : boresight.resources.Checks
        The memory and time checks to make.
    layout, prefix
        As in :func:`scan_stats`.
    frame, turnarounds : str, optional
        The sky frame of the maps and what the turnarounds' samples do
        (:class:`boresight.schedule.Schedule`; default: the file's).
    progress : bool
        Show a progress bar over the schedule's samples.

    Returns
    -------
    list of dict
        As :func:`scan_stats`.
    """
    from . import scanstats
    from .schedule import load_schedule

    _check_layout(layout, prefix)
    schedule = load_schedule(
        schedule_path, motion, frame=frame, turnarounds=turnarounds
    )
    sky.SkyConfig(nside=nside, lmax=2 * nside)  # validates nside
    io.check_output_dir(out_dir, force, [schedule_path])
    estimate = resources.schedule_estimate("schedule-stats", schedule, nside)
    resources.require(estimate, checks, log)
    timer = provenance.Timer(log)
    precompile.precompile(precompile.kernels_for("schedule-stats"), timer=timer)
    with timer("characterise the schedule"):
        stats = scanstats.characterise_schedule(schedule, nside, tolerance_deg, progress=progress)
    return _write_scan_stats(
        out_dir,
        force,
        [schedule_path],
        stats.h,
        stats.observed,
        stats.hits,
        stats.n_distinct,
        stats.range_rad,
        scanstats.N_MAX,
        layout,
        prefix,
        frame=schedule.frame,
        config={
            "schedule": schedule_path,
            "nside": nside,
            "turnarounds": schedule.turnarounds,
            "tolerance_deg": tolerance_deg,
        },
        estimate=estimate,
    )


LAYOUTS = ("boresight", "so")


def _check_layout(layout, prefix):
    if layout not in LAYOUTS:
        raise ValueError(f"the h_n layout must be one of {LAYOUTS}, got {layout!r}")
    if not prefix or not all(c.isalnum() or c in "_-." for c in prefix):
        raise ValueError(f"--prefix {prefix!r} must be letters, digits, '_', '-' or '.'")
    longest = len(os.fsencode(f"{prefix}_cos_4.fits"))
    if longest > io.MAX_NAME_BYTES:
        raise ValueError(
            f"--prefix is {len(prefix)} characters: its files' names would be {longest} bytes, "
            f"at most {io.MAX_NAME_BYTES} are allowed"
        )


def _write_scan_stats(out_dir, force, inputs, h, obs, crossings, n_phi, r, n_max, layout, prefix,
                      frame="icrs", config=None, estimate=None):
    """The survey means, the h_n maps in the chosen layout, the scan maps, a figure and the
    manifest. In the SO layout every output, hn_summary.csv included, is in TOAST/SO's psi
    convention (odd h_n change sign); the manifest's ``psi_convention`` says which."""
    from . import so_maps

    convention = "toast" if layout == "so" else "boresight"
    turn = so_maps.to_so if layout == "so" else (lambda hn, n: hn)
    rows = [
        dict(
            n=n,
            mean_abs_h2=float(np.mean(np.abs(h[n][obs]) ** 2)),
            mean_re=float(np.mean(turn(h[n][obs], n).real)),
            mean_im=float(np.mean(turn(h[n][obs], n).imag)),
        )
        for n in range(1, n_max + 1)
    ]
    require_finite("the h_n summary", [list(row.values()) for row in rows])
    with io.staged_dir(out_dir, force, inputs) as stage:
        if layout == "so":
            so_maps.write(stage, prefix, h, crossings, range(1, n_max + 1), frame=frame)
        else:
            parts = [("RE", np.real), ("IM", np.imag)]
            io.write_maps(
                stage / "hn_maps.fits",
                [np.where(obs, f(h[n]), hp.UNSEEN) for _, f in parts for n in range(1, n_max + 1)],
                [f"{p}_H{n}" for p, _ in parts for n in range(1, n_max + 1)],
                [""] * (2 * n_max),
                [BORESIGHT_CONVENTION],
                frame=frame,
            )
        io.write_maps(
            stage / "scan_maps.fits",
            [crossings, np.where(obs, n_phi, 0), np.where(obs, r, 0)],
            ["CROSSINGS", "N_PHI", "RANGE_RAD"],
            ["", "", "rad"],
            frame=frame,
        )
        io.write_csv(stage / "hn_summary.csv", rows, list(rows[0]))
        plots.map_figure(
            [np.where(obs, np.abs(h[n]) ** 2, hp.UNSEEN) for n in (1, 2)],
            ["|h_1|^2", "|h_2|^2"],
            stage / "hn_maps.png",
            unit="",
        )
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {**(config or {}), "frame": frame, "psi_convention": convention},
                {},
                {},
                estimate.as_dict() if estimate else None,
            ),
        )
    return rows


#: the header COMMENT of boresight-layout h_n maps
BORESIGHT_CONVENTION = "h_n = RE + i IM of <exp(i n psi)>, psi in boresight's convention"


def compare_scans(
    schedule_path: str,
    out_dir: str,
    nside: int = 128,
    systematic: str = "gain",
    fwhm_arcmin: float = 30.0,
    seed: int = 1,
    tolerance_deg: float = 1.0,
    force: bool = False,
    log: Callable = print,
    checks: resources.Checks = resources.Checks(),
    motion: ScanMotion | None = None,
    frame: str | None = None,
    turnarounds: str | None = None,
) -> list[dict]:
    """The residual B-mode of a real schedule beside its synthetic twin (paper section 3.1).

    Writes scan_maps.fits (crossings, N_phi, R, ``|h_1..4|^2``), scan_stats.csv (survey means of the
    real scan and the twin), compare.csv and compare.png/pdf. Returns the binned rows.
    ``motion`` sets the scan rate, acceleration and sample rate of a TOAST schedule; ``frame`` and
    ``turnarounds`` replace the schedule file's (:class:`boresight.schedule.Schedule`).
    """
    from . import scanstats
    from .schedule import load_schedule
    from .instrument import PAPER_GAIN, PAPER_POINTING, Instrument, Systematics

    systematics = {"gain": PAPER_GAIN, "pointing": PAPER_POINTING}.get(systematic)
    if systematics is None:
        raise ValueError(f"systematic must be 'gain' or 'pointing', got {systematic!r}")
    schedule = load_schedule(
        schedule_path, motion, frame=frame, turnarounds=turnarounds
    )
    sky.SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=fwhm_arcmin, seed=seed)  # validate
    io.check_output_dir(out_dir, force, [schedule_path])
    # the real scan once and with its repeats, each with and without the systematic
    estimate = resources.schedule_estimate("compare-scans", schedule, nside, tod_runs=4)
    resources.require(estimate, checks, log)
    timer = provenance.Timer(log)
    with timer("characterise the schedule"):
        stats = scanstats.characterise_schedule(schedule, nside, tolerance_deg)
        # The twin takes (N_phi, R) of one pass of the CES set and repeats it at the schedule's
        # boresight angles, as the paper built its synthetic scans.
        single = scanstats.characterise_schedule(schedule.single(), nside, tolerance_deg)
        twin = replace(
            single.synthetic_twin(seed=seed), rotations_deg=schedule.repeat_boresight_deg
        )
        obs = stats.observed
    the_sky = sky.make_sky(
        sky.SkyConfig(nside=nside, lmax=2 * nside, fwhm_arcmin=fwhm_arcmin, seed=seed)
    )
    # One pass of the CES set, and the whole schedule with its boresight repeats, each as the
    # real scan and as its twin: the paper compared the unrotated scans.
    cases = {
        "real_one_pass": schedule.single(),
        "twin_one_pass": replace(twin, rotations_deg=(0.0,)),
        "real": schedule,
        "twin": twin,
    }
    # Validity depends on the crossing angles alone, so the references fix the common mask.
    refs = {}
    for name, scan in cases.items():
        with timer(f"reference {name.replace('_', ' ')}"):
            refs[name] = residual.simulate(the_sky, scan, Instrument(), Systematics(), obs)
    mask = obs.copy()
    for ref in refs.values():
        mask &= ref.valid
    footprint = spectra.Footprint(mask.astype(float))
    lmax = 2 * nside
    edges = spectra.log_bins(10, lmax, 12)
    curves = {}
    for name, scan in cases.items():
        with timer(f"residual {name.replace('_', ' ')}"):
            reference = residual.reference_from_maps(refs[name], footprint, lmax)
            curves[f"residual_{name}_bb"] = residual.residual(
                the_sky, scan, systematics, footprint, lmax, reference_=reference
            ).total
    rows = residual.band_rows(edges, curves)
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
    with io.staged_dir(out_dir, force, [schedule_path]) as stage:
        cols = [stats.hits, stats.n_distinct, stats.range_rad] + [
            np.where(obs, np.abs(stats.h[n]) ** 2, hp.UNSEEN) for n in range(1, 5)
        ]
        io.write_maps(
            stage / "scan_maps.fits",
            cols,
            ["CROSSINGS", "N_PHI", "RANGE_RAD", "ABS_H1_SQ", "ABS_H2_SQ", "ABS_H3_SQ", "ABS_H4_SQ"],
            ["", "", "rad", "", "", "", ""],
            frame=schedule.frame,
        )
        io.write_csv(stage / "scan_stats.csv", table, list(table[0]))
        io.write_csv(stage / "compare.csv", rows, list(rows[0]))
        plots.compare_figure(rows, systematic, stage / "compare")
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {
                    "schedule": schedule_path,
                    "frame": schedule.frame,
                    "turnarounds": schedule.turnarounds,
                    "nside": nside,
                    "systematic": systematic,
                    "fwhm_arcmin": fwhm_arcmin,
                    "tolerance_deg": tolerance_deg,
                },
                {"sky": seed, "twin": seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    return rows


def design_schedule(
    budget_path: str,
    schedule_path: str,
    out_dir: str,
    force: bool = False,
    motion: ScanMotion | None = None,
    validate: bool = True,
    log: Callable = print,
    progress: bool = False,
    frame: str | None = None,
    turnarounds: str | None = None,
    checks: resources.Checks = resources.Checks(),
) -> dict:
    """``boresight design``: choose a boresight angle per unit of a schedule against a budget.

    Writes the optimised schedule in the input's format (``schedule_designed.*``), a table of
    every strategy (``strategies.csv``: predicted delta_r, delta_r / sigma(r), changes of angle
    and ``<|h_n|^2>``), the optimiser's history (``history.csv``), the residual spectra of each
    strategy with the noise and r references (``design.png``/``.pdf``), ``|h_n|^2`` maps before
    and after (``hn_before_after.png``), and with ``validate`` a TOD simulation of the budget on
    the designed and the unrotated schedule (``validation.csv``). Ctrl-C or SIGTERM during the
    search keeps the best schedule found so far, during the validation the finished design without
    it; the manifest says which, and the :class:`boresight.interrupts.Interrupted` raised after the
    outputs are written says what was kept.

    Parameters
    ----------
    budget_path, schedule_path, out_dir : str
    force : bool
    motion : boresight.schedule.toast.ScanMotion, optional
        For a TOAST schedule.
    validate : bool
        Run the TOD simulation.
    log : callable
    progress : bool
    frame, turnarounds : str, optional
        Replace the schedule file's (:class:`boresight.schedule.Schedule`).
    checks : boresight.resources.Checks
        The memory and time checks to make.

    Returns
    -------
    dict
        sigma_r, the strategies' rows and the designed angles per unit.
    """
    from . import design, noise
    from .schedule import load_schedule, schedule_format, write_schedule
    from .cosmology import load_spectra

    budget = design.load_budget(budget_path)
    opts = budget.design
    schedule = load_schedule(
        schedule_path, motion, frame=frame, turnarounds=turnarounds
    )
    fmt = schedule_format(schedule_path)
    inputs = [budget_path, schedule_path]
    io.check_output_dir(out_dir, force, inputs)
    estimate = resources.schedule_estimate(
        "design",
        schedule,
        opts.nside,
        n_pairs=budget.instrument.n_pairs,
        tod_runs=4 if validate else 0,  # the designed and the unrotated schedule, each twice
        systematics=budget.systematics,
        instrument=budget.instrument,
        fwhm_arcmin=budget.noise.fwhm_arcmin,
    )
    resources.require(estimate, checks, log)
    timer = provenance.Timer(log)
    kernels = precompile.kernels_for("design")
    if validate:
        kernels += precompile.kernels_for("validation", pointing=budget.systematics.has_pointing)
    precompile.precompile(kernels, timer=timer)
    spectra_ = load_spectra()
    with timer("per-unit spin moments"):
        moments = design.unit_moments(schedule, opts.nside, opts.group)
    with timer("objective"):
        obj = design.objective(
            moments,
            budget.systematics,
            spectra_,
            budget.noise.fwhm_arcmin,
            opts.change_cost,
            instrument=budget.instrument,
        )
    sigma_r = noise.sigma_r(
        budget.noise, spectra_, np.array([predict.R_RANGE[0], predict.R_RANGE[1] + 1])
    )
    strategies = design.baselines(moments.n_units, opts.angles_deg, opts.seed)
    allowed = set(opts.angles_deg)
    startable = {k: v for k, v in strategies.items() if set(v) <= allowed}
    start = (
        min(startable.values(), key=obj)
        if startable
        else np.full(moments.n_units, opts.angles_deg[0])
    )
    log(f"{moments.n_units} units, {moments.pixels.size} pixels; sigma(r) = {sigma_r:.3g}")
    if not obj.terms:
        log(
            "the budget's systematics do not depend on the boresight angles (h_0 and white "
            "terms only): every schedule has the same predicted delta_r"
        )
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=opts.sweeps * moments.n_units, desc="design", unit="unit")
    with timer("coordinate descent"):
        found = design.optimise(
            obj, opts.angles_deg, start, opts.sweeps, opts.seed, bar.update if bar else None
        )
    if bar:
        bar.close()
    strategies["optimised"] = found.angles_deg
    rows, h_maps = [], {}
    for name, angles in strategies.items():
        h = moments.h(angles)
        h_maps[name] = h
        dr = obj.delta_r_of(h)
        rows.append(
            dict(
                strategy=name,
                delta_r=dr,
                delta_r_over_sigma_r=dr / sigma_r,
                changes=obj.changes(angles),
                **{f"mean_abs_h{n}_sq": float(np.mean(np.abs(h[n]) ** 2)) for n in range(1, 5)},
            )
        )
    require_finite("the strategies' delta_r", [r["delta_r"] for r in rows])
    validation, stopped, checked = [], found.interrupted, "skipped"
    if validate and stopped is None:
        try:
            with timer("TOD simulation of the designed and unrotated schedules"):
                predicted = {row["strategy"]: row["delta_r"] for row in rows}
                validation = _validate_design(budget, moments, obj, schedule, strategies, predicted)
            checked = "done"
        except interrupts.Interrupted as err:  # the search is done: keep it, without validation
            stopped, checked = err, "interrupted"
    mask = moments.mask
    curves = {
        name: predict.residual_pseudo_bb(
            moments.full_sky(h),
            mask,
            obj.coupling,
            budget.systematics,
            spectra_,
            budget.noise.fwhm_arcmin,
            budget.instrument,
            crossings=moments.full_sky(moments.hits),
            expected=design.drawn(budget.systematics),
        )
        for name, h in h_maps.items()
    }
    designed = moments.schedule(schedule, found.angles_deg)
    suffix = {"toml": ".toml", "csv": ".csv", "toast": ".txt"}[fmt]
    with io.staged_dir(out_dir, force, inputs) as stage:
        write_schedule(designed, stage / f"schedule_designed{suffix}", fmt)
        io.write_csv(stage / "strategies.csv", rows, list(rows[0]))
        io.write_csv(stage / "history.csv", found.history, ["sweep", "objective", "moves"])
        io.write_csv(
            stage / "units.csv",
            [
                dict(unit=u, first_ces=idx[0], n_ces=len(idx), angle_deg=a)
                for u, (idx, a) in enumerate(zip(moments.units, found.angles_deg))
            ],
            ["unit", "first_ces", "n_ces", "angle_deg"],
        )
        if validation:
            io.write_csv(stage / "validation.csv", validation, list(validation[0]))
        plots.design_figure(curves, obj, budget.noise, sigma_r, spectra_, stage / "design")
        # the moment of the largest angle-dependent term (h_2 where every term is h_0 or white)
        dominant = max(obj.terms, key=lambda n: obj.alpha[n] + obj.beta[n], default=2)
        plots.map_figure(
            [
                np.where(mask > 0, np.abs(moments.full_sky(h_maps[k][dominant])) ** 2, hp.UNSEEN)
                for k in ("none", "optimised")
            ],
            [f"|h_{dominant}|^2, no rotation", f"|h_{dominant}|^2, optimised"],
            stage / "hn_before_after.png",
            unit="",
        )
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {
                    "budget": budget_path,
                    "schedule": schedule_path,
                    "frame": schedule.frame,
                    "turnarounds": schedule.turnarounds,
                    "design": dataclasses.asdict(budget.design),
                    "sigma_r": sigma_r,
                    "search_interrupted": found.interrupted is not None,
                    "validation": checked,
                },
                {"design": opts.seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    if stopped is not None:
        stopped.kept = (
            f"the best schedule found so far is in {out_dir}"
            if found.interrupted is not None
            else f"the finished design is in {out_dir}, without its TOD validation"
        )
        raise stopped
    return dict(
        sigma_r=sigma_r, strategies=rows, angles_deg=found.angles_deg, validation=validation
    )


def _validate_design(budget, moments, obj, schedule, strategies, predicted):
    """Simulated against predicted delta_r of the designed and the unrotated schedule.

    The simulation runs the budget's systematics through the TOD engine on the schedule's own
    samples, at the design's Nside with lmax = 2 Nside; its delta_r is that of the leaked power
    (the prediction's quantity) and, for reference, of the whole residual with its cross term.
    A budget with {mean, rms} parameters simulates one draw of its focal plane (``seed``), which
    scatters about the predicted expectation.
    """
    nside, lmax = moments.nside, 2 * moments.nside
    the_sky = sky.make_sky(
        sky.SkyConfig(nside=nside, lmax=lmax, fwhm_arcmin=budget.noise.fwhm_arcmin)
    )
    out = []
    for name in ("optimised", "none"):
        scan = moments.schedule(schedule, strategies[name])
        res = residual.residual(
            the_sky, scan, budget.systematics, moments.mask, lmax, instrument=budget.instrument
        )
        simulated = predict.delta_r(res.auto, obj.template) + obj.const
        out.append(
            dict(
                strategy=name,
                predicted_delta_r=predicted[name],
                simulated_delta_r=simulated,
                simulated_delta_r_with_cross_term=predict.delta_r(res.total, obj.template),
                ratio=simulated / predicted[name] if predicted[name] else float("nan"),
            )
        )
    return out


def suppression_map(
    sky_config: sky.SkyConfig,
    survey: str,
    out_dir: str,
    force: bool = False,
    log: Callable = print,
    progress: bool = False,
    checks: resources.Checks = resources.Checks(),
) -> list[dict]:
    """``boresight suppression``: every systematic of :data:`boresight.suppression.CATALOGUE`
    alone through 0, 0/45, 0/90 and 0/180 deg rotation.

    Writes ``suppression.csv`` (a row per systematic and schedule: the suppression of the
    simulated and the predicted residual in three multipole bands, and the delta_r each fakes),
    ``suppression.md`` (the same, readable), ``suppression.png``/``.pdf`` and ``manifest.json``.

    Parameters
    ----------
    sky_config : boresight.sky.SkyConfig
    survey : {"deep", "wide"}
    out_dir : str
    force : bool
    log : callable
    progress : bool
    checks : boresight.resources.Checks
        The memory and time checks to make.

    Returns
    -------
    list of dict
        The table's rows.
    """
    from . import suppression
    from .config import ConfigError, OutputOptions, Study, check_systematics
    from .instrument import Instrument

    if sky_config.nside < suppression.MIN_NSIDE:
        raise ConfigError(
            f"--nside = {sky_config.nside}: the suppression map's first band starts at ell = "
            f"{suppression.bands(1 << 20)[0]}, beyond lmax = 2 Nside = {2 * sky_config.nside}; "
            f"give a power of two >= {suppression.MIN_NSIDE}"
        )
    for entry in suppression.CATALOGUE:  # every entry, before the first is simulated
        try:
            check_systematics(
                entry.systematics, Instrument(), (0.0, 90.0), sky_config.fwhm_arcmin
            )
        except ValueError as err:
            raise ConfigError(
                f"--fwhm-arcmin = {sky_config.fwhm_arcmin:g}: the {entry.name} entry "
                f"({entry.amplitude}): {err}"
            ) from None
    study = Study(sky=sky_config, output=OutputOptions(lmax=2 * sky_config.nside, lmin=2))
    estimate = suppression.estimate(study)
    resources.require(estimate, checks, log)
    io.check_output_dir(out_dir, force)
    timer = provenance.Timer(log)
    with timer("sky"):
        the_sky = sky.make_sky(sky_config)
    with timer("simulations and predictions"):
        result = suppression.run(the_sky, survey, log=log, progress=progress)
    rows = suppression.table(result, sky_config.nside)
    require_finite("the simulated suppressions", [r["delta_r_sim"] for r in rows])
    with io.staged_dir(out_dir, force) as stage:
        io.write_csv(stage / "suppression.csv", rows, list(rows[0]))
        (stage / "suppression.md").write_text(suppression.markdown(rows))
        plots.suppression_figure(result, sky_config.nside, stage / "suppression")
        io.write_json(
            stage / "manifest.json",
            provenance.manifest(
                {"survey": survey, "sky": dataclasses.asdict(sky_config)},
                {"sky": sky_config.seed},
                timer.stages,
                estimate.as_dict(),
            ),
        )
    return rows
