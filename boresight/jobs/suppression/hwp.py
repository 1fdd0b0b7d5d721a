"""What boresight rotation still buys a telescope with a half-wave plate.

Each systematic of :data:`CASES` runs alone on a real schedule, every pair on its own samples
(:func:`boresight.engine.simulate_focalplane`, the sky read exactly at each sample), without a
plate and behind one, each row one run of the one job (:func:`boresight.jobs.residual.residual`)
against the no-systematic maps of the same plate and schedule, through the boresight schedules
of :data:`SCHEDULES` (the schedule's CES set repeated at each angle). For every row the leaked pseudo-C_BB of the TOD is binned in three
bands, set beside its prediction from the schedule's moments and divided by the leak without a
plate or rotation.

The terms each cure acts on (docs/conventions.md, "Half-wave plates"): a differential gain's and
an additive leak's T reach a bare pair's map through h_2 and a pair behind the plate's through
h_{2,4}, which a spinning plate averages away and boresight rotation cancels. A pointing
offset's T gradient reaches it through h_1 and h_3 bare, h_{1,4} and h_{3,4} behind the plate
(the offset turns with the crossing angle, not with the plate), which the spinning plate
averages away too, leaving what detector B reads of P off its place, through h_1. Where 0/180
cancels every odd n, what is left of it is its second order in rho, d^2 T turned by the offset's
angle through h_0 bare and h_{0,4} behind the plate (which the plate averages away). A pair's
polarisation-angle error turns the maps' P (h_0), reflected by the plate, and no plate or
rotation touches it. The plate's own
instrumental polarisation reaches it through h_{2,0}, the crossing angles' moment, which the plate
cannot touch and only the sky's and the boresight's rotation cancel. The plate's angle offset
turns the sky's P by 4 delta (h_0: no rotation touches it), and its angle's jitter leaves
(mu - 1) P and a white part that only more samples average down. Its synchronous signal's 2 chi
part reaches the map through h_{2,2} and h_{2,6}, which a spinning plate averages away.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from ... import harmonics, spectra
from ..._util import interrupts
from ...config import RunOptions
from ...instrument.focalplane import on_axis
from ...instrument.pairs import Instrument, Systematics
from ...moments import centroid_moments, characterise_focalplane
from ...moments.hwp import plate_moments
from ...predict import focalplane as predict_fp
from ...predict import hwp as predict_hwp
from ...validation import ConfigError
from ..residual import reference_from_maps, residual, simulate_maps

if TYPE_CHECKING:
    from ...instrument.focalplane import FocalPlane
    from ...instrument.hwp import HWP
    from ...schedule import Schedule
    from ...sky import Sky

#: the boresight schedules: the CES set once, and repeated at each further angle [deg]
SCHEDULES = ((0.0,), (0.0, 45.0), (0.0, 90.0), (0.0, 180.0))
#: the pixels whose maps enter the spectra
RCOND_FOOTPRINT = 0.05
#: the plate's instrumental polarisation where the plate states none
DEFAULT_IP = 1e-3
#: the plate's angle offset where the plate states none [deg]
DEFAULT_OFFSET_DEG = 0.1
#: the rms of the plate's angle jitter where the plate states none [deg]
DEFAULT_JITTER_DEG = 0.5
#: the plate's synchronous (A_2, A_4) where the plate states none [muK]
DEFAULT_SYNCHRONOUS_MUK = (1.0, 1.0)
MIN_NSIDE = 32  #: the lowest Nside whose bands (:func:`bands`) are in order


@dataclass(frozen=True)
class Case:
    """One systematic of the table.

    Parameters
    ----------
    name, amplitude : str
        For the table.
    bare, behind : str
        The moment its leak reaches the map through, without and behind the plate.
    systematics : Systematics
        The pairs' (none for the plate's own).
    plate : str
        Instead, the plate's own, only behind a plate: "ip" (its instrumental polarisation),
        "angle" (its angle offset), "jitter" (its angle's white jitter) or "synchronous" (its
        synchronous signal).
    """

    name: str
    amplitude: str
    bare: str
    behind: str
    systematics: Systematics = Systematics()
    plate: str = ""


CASES = (
    Case("differential gain", "dg = +-0.01", "T: h_2", "T: h_{2,4}", Systematics(dg=(0.01, -0.01))),
    Case("additive leak", "0.01 T", "T: h_2", "T: h_{2,4}", Systematics(leak=0.01)),
    Case(
        "pointing offset",
        "rho = 1 arcmin",
        "grad T: h_1, h_3; d^2 T: h_0",
        "grad T: h_{1,4}, h_{3,4}; grad P: h_1; d^2 T: h_{0,4}",
        Systematics(rho_arcmin=1.0, chi_deg=30.0),
    ),
    Case(
        "polarisation-angle error",
        "theta = 0.5 deg",
        "P: h_0 (turns P by -2 theta)",
        "P: h_0 (reflected: turns P by +2 theta)",
        Systematics(pol_angle_deg=0.5),
    ),
    Case(
        "detector beams",
        "e_A = 0.02, FWHM_B + 1 arcmin",
        "T: h_0, h_2, h_4",
        "T: h_{n,4}; P: h_{n,0}, h_{n,8}",
        Systematics(ellipticity_a=0.02, ellipticity_angle_a_deg=30.0, dfwhm_b_arcmin=1.0),
    ),
    Case("HWP instrumental polarisation", "epsilon", "-", "T: h_{2,0}", plate="ip"),
    Case("HWP angle offset", "delta", "-", "P: h_0 (turns P by 4 delta)", plate="angle"),
    Case(
        "HWP angle jitter",
        "sigma",
        "-",
        "P: (mu - 1) P and white v |P|^2 / N",
        plate="jitter",
    ),
    Case("HWP synchronous signal", "A_2, A_4", "-", "A_2: h_{2,2}, h_{2,6}", plate="synchronous"),
)


@dataclass(frozen=True)
class Result:
    """The table's rows and each row's leaked pseudo-C_BB per ell (for the figure).

    Parameters
    ----------
    rows : list of dict
    spectra : dict
        (case name, "none" or "plate", boresight label) -> (measured, predicted), (lmax + 1,)
        [muK^2] each.
    edges : numpy.ndarray
        The bands' edges.
    """

    rows: list
    spectra: dict
    edges: np.ndarray


def bands(nside: int) -> np.ndarray:
    """Three bands of 30 <= ell <= 2 Nside: [30, Nside), [Nside, 3 Nside / 2), [3 Nside / 2, 2
    Nside]."""
    return np.array([30, nside, 3 * nside // 2, 2 * nside + 1])


#: the narrowest beam, in pixels, at which the table's predictions hold to 10 %: behind a plate T
#: is read across the pixel to second order in the samples' offsets, which fails as the pixel
#: nears the beam (the deep example with a 2 Hz plate, the beams' row: 1.74-2.30 of the TOD at
#: 1.1 pixels, 1.08-1.10 at 2.2, 0.96-1.07 at 3.3, 1.02 at 4.4, 1.00 at 8.7)
MIN_BEAM_PIXELS = 4.0


def check_resolution(nside: int, fwhm_arcmin: float) -> None:
    """Refuse a sky whose beam is under :data:`MIN_BEAM_PIXELS` pixels, naming the finest
    setting of each flag that would do."""
    pixel = float(np.degrees(np.sqrt(4 * np.pi / (12 * nside**2)))) * 60
    if fwhm_arcmin >= MIN_BEAM_PIXELS * pixel:
        return
    if not fwhm_arcmin > 0:
        raise ConfigError(f"--fwhm-arcmin {fwhm_arcmin:g}: the sky's beam must be > 0")
    need = nside
    while fwhm_arcmin < MIN_BEAM_PIXELS * pixel * nside / need:
        need *= 2
    raise ConfigError(
        f"--fwhm-arcmin {fwhm_arcmin:g} at --nside {nside}: the HWP table's predictions hold to "
        f"10 % for a beam of {MIN_BEAM_PIXELS:g} pixels or more ({MIN_BEAM_PIXELS * pixel:.0f} "
        f"arcmin here); give --nside {need} or --fwhm-arcmin {np.ceil(MIN_BEAM_PIXELS * pixel):g}"
    )


def check_plate(hwp: HWP) -> None:
    """Refuse a plate the table cannot take: none, or one stepped per repeat of the CES set (the
    table's boresight schedules are those repeats)."""
    if not hwp.present:
        raise ConfigError("the HWP table needs a continuous or a stepped plate")
    if hwp.steps_with_repeats:
        raise ConfigError(
            "hwp step 'repeat': the table repeats the CES set at each boresight angle, which would "
            "step the plate with it; step per ces or per day"
        )


def tod_runs(schedules=SCHEDULES) -> int:
    """The TOD simulations of the table, counted in passes of the CES set: per boresight schedule
    (as many passes as its angles), a reference and every pair case without a plate, and a
    reference, every pair case and every case of the plate's own behind it."""
    pairs = sum(1 for case in CASES if not case.plate)
    plate = sum(1 for case in CASES if case.plate)
    return sum(len(r) for r in schedules) * ((1 + pairs) + (1 + pairs + plate))


def boresight_label(repeats) -> str:
    return "/".join(f"{r:g}" for r in repeats)


def run(
    schedule: Schedule,
    sky: Sky,
    hwp: HWP,
    *,
    schedules=SCHEDULES,
    focalplane: FocalPlane | None = None,
    progress: bool = False,
) -> Result:
    """Every case without a plate and behind ``hwp``, through each boresight schedule.

    Parameters
    ----------
    schedule : boresight.schedule.Schedule
        Its CES set; its own repeats are replaced by each of ``schedules``.
    sky : boresight.sky.Sky
        lmax >= 2 Nside.
    hwp : boresight.instrument.hwp.HWP
        Continuous or stepped; its ``ip``, ``angle_offset_deg``, ``angle_jitter_deg`` and
        ``synchronous_muk`` (with their phases) are the amplitudes of the plate's own cases
        (default :data:`DEFAULT_IP`, :data:`DEFAULT_OFFSET_DEG`, :data:`DEFAULT_JITTER_DEG`,
        :data:`DEFAULT_SYNCHRONOUS_MUK`).
    schedules : sequence of sequence of float
        Boresight angles of the CES set's repeats [deg].
    focalplane : boresight.instrument.focalplane.FocalPlane, optional
        The pairs (default the paper's Q and U pairs on the axis). Off the axis each pair's
        moments enter the plate's own cases as the map-maker combines them
        (:func:`plate_moments`), and its IP takes T across the pixel
        (:func:`boresight.predict.hwp.ip_delta_p_across`).
    progress : bool

    Returns
    -------
    Result
    """
    check_plate(hwp)
    pairs = on_axis((0.0, 45.0)) if focalplane is None else focalplane
    off_axis = bool(np.any(pairs.radius_deg > 0))
    # the plate's own signals and offset, each alone in its case
    ideal = dataclasses.replace(
        hwp, ip=0.0, angle_offset_deg=0.0, angle_jitter_deg=0.0, synchronous_muk=(0.0, 0.0)
    )
    own = {
        "ip": dataclasses.replace(ideal, ip=hwp.ip or DEFAULT_IP),
        "angle": dataclasses.replace(
            ideal, angle_offset_deg=hwp.angle_offset_deg or DEFAULT_OFFSET_DEG
        ),
        "jitter": dataclasses.replace(
            ideal, angle_jitter_deg=hwp.angle_jitter_deg or DEFAULT_JITTER_DEG
        ),
        "synchronous": dataclasses.replace(
            ideal,
            synchronous_muk=hwp.synchronous_muk
            if any(hwp.synchronous_muk)
            else DEFAULT_SYNCHRONOUS_MUK,
        ),
    }
    edges, lmax = bands(sky.nside), 2 * sky.nside
    names = [f"{lo}-{hi - 1}" for lo, hi in zip(edges[:-1], edges[1:])]
    rows, cls, first = [], {}, {}
    jobs = [(r, p) for r in schedules for p in ("none", "plate")]
    for repeats, which in tqdm(jobs, desc="HWP table", disable=not progress):
        interrupts.check()
        scan = dataclasses.replace(schedule, repeat_boresight_deg=tuple(repeats))
        plate = None if which == "none" else ideal
        run_ = RunOptions(evaluation="exact")
        ref = simulate_maps(
            sky, scan, Instrument(), Systematics(), run=run_, focalplane=pairs, hwp=plate
        )
        mask = (ref.rcond > RCOND_FOOTPRINT).astype(float)
        footprint = spectra.as_footprint(mask)
        reference = reference_from_maps(ref, footprint, lmax, run=run_)
        del ref
        # each row the one job against this schedule's reference
        job = dict(run=run_, reference=reference, focalplane=pairs)
        stats = characterise_focalplane(
            scan, pairs, sky.nside, per_pair=True, hwp=plate, pointing=True, beams=True,
            ip=plate is not None and off_axis,
        )  # fmt: skip
        moments = None  # the boresight's hits and h_{n,m}, once a plate's own case needs them
        offsets = None  # the bare pairs' samples' offsets from their pixel centres
        for case in CASES:
            if case.plate and plate is None:
                continue
            if case.plate:
                measured = residual(
                    sky, scan, Systematics(), footprint, lmax, hwp=own[case.plate], **job
                ).auto
            if case.plate and moments is None:
                moments = plate_moments(scan, ideal, sky.nside, pairs)
            white = 0.0
            if case.plate == "ip" and off_axis:
                dp = predict_hwp.ip_delta_p_across(sky, stats, own["ip"])
            elif case.plate == "ip":
                dp = predict_hwp.ip_delta_p(sky, moments.h, own["ip"], moments.pair_angles_deg)
            elif case.plate == "jitter":
                dp, _, white = predict_hwp.angle_jitter_leak(
                    sky,
                    moments.hits,
                    moments.h,
                    own["jitter"],
                    pair_angles_deg=moments.pair_angles_deg,
                    mask=mask,
                )
            elif case.plate == "synchronous":
                dp = predict_hwp.synchronous_delta_p(
                    moments.synchronous, own["synchronous"], moments.pair_angles_deg
                )
            elif case.plate == "angle":
                offset = dataclasses.replace(stats, hwp=own["angle"])
                dp = predict_fp.delta_p(sky, offset, Systematics())
            else:
                systematics = _on(pairs, case.systematics)
                measured = residual(sky, scan, systematics, footprint, lmax, hwp=plate, **job).auto
                if plate is None and offsets is None:
                    offsets = centroid_moments(scan, sky.nside, focalplane=pairs)
                dp = predict_fp.delta_p(
                    sky,
                    stats,
                    systematics,
                    offsets=offsets if plate is None else None,
                    second_order=True,
                )
            predicted = _pseudo_bb(footprint, dp, sky.nside) + white
            label = boresight_label(repeats)
            cls[case.name, which, label] = (measured, predicted)
            m, p = (spectra.bin_spectrum(x, edges)[1] for x in (measured, predicted))
            first.setdefault(case.name, m)
            row = {
                "systematic": case.name,
                "amplitude": _amplitude(case, own),
                "plate": "none" if plate is None else hwp.label(),
                "boresight": label,
                "through": case.bare if plate is None else case.behind,
            }
            for band, mb, pb, fb in zip(names, m, p, first[case.name]):
                row[f"leak {band}"] = float(mb)
                real = mb > ROUNDING  # a leak at rounding has no meaningful ratio: NaN
                row[f"predicted/TOD {band}"] = float(pb / mb) if real else float("nan")
                row[f"over first {band}"] = float(mb / fb) if real and fb > ROUNDING else np.nan
            rows.append(row)
    return Result(rows, cls, edges)


def _on(pairs, systematics):
    """A case's systematics on ``pairs``: a gain given per pair alternates its values over them
    (+-0.01 for the Q and U pairs, and on a focal plane)."""
    dg = systematics.dg
    if isinstance(dg, tuple) and len(dg) != pairs.n_pairs:
        return dataclasses.replace(
            systematics, dg=tuple(dg[i % len(dg)] for i in range(pairs.n_pairs))
        )
    return systematics


def _amplitude(case, own):
    if case.plate == "ip":
        return f"epsilon = {own['ip'].ip:g}"
    if case.plate == "angle":
        return f"delta = {own['angle'].angle_offset_deg:g} deg"
    if case.plate == "jitter":
        return f"sigma = {own['jitter'].angle_jitter_deg:g} deg"
    if case.plate == "synchronous":
        a2, a4 = own["synchronous"].synchronous_muk
        return f"A_2 = {a2:g}, A_4 = {a4:g} muK"
    return case.amplitude


def _pseudo_bb(footprint, dp, nside):
    """The masked pseudo-C_BB (lmax = 2 Nside,) of a spurious P map."""
    d = dp[footprint.pixels]
    b = footprint.alm(np.array([d.real, d.imag]), 2 * nside, 2)[1]
    return harmonics.alm2cl(b)


#: a leak below this is rounding [muK^2]: its ratios carry no meaning
ROUNDING = 1e-30


def markdown(rows: list[dict]) -> str:
    """The table, readable: the leak per band [muK^2], the prediction over the TOD and the leak
    over the first row of its systematic (no plate, no rotation; the plate's IP: behind it, no
    rotation)."""
    return leak_markdown(
        rows, "plate", (("predicted/TOD", "pred/TOD"), ("over first", "over first"))
    )


def leak_markdown(rows: list[dict], variant: str, ratios: tuple) -> str:
    """A table of leaks per band and their ratios, readable: a row per systematic, variant (its
    column ``variant``) and boresight schedule; a ratio of a leak at rounding shows as "-".

    Parameters
    ----------
    rows : list of dict
        With "systematic", "amplitude", ``variant``, "boresight", "through", "leak {band}" and
        "{ratio} {band}" for each ratio.
    variant : str
    ratios : tuple of (str, str)
        Each ratio's key and its header.

    Returns
    -------
    str
    """
    bands_ = [k[5:] for k in rows[0] if k.startswith("leak ")]
    head = ["systematic", variant, "boresight", "through"] + [f"leak {b}" for b in bands_]
    head += [f"{header} {b}" for _, header in ratios for b in bands_]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row["systematic"] + f" ({row['amplitude']})", row[variant], row["boresight"]]
        cells.append(row["through"])
        leaks = [row[f"leak {b}"] for b in bands_]
        cells += [f"{x:.2g}" for x in leaks]
        for kind, _ in ratios:
            for b, leak in zip(bands_, leaks):
                x = row[f"{kind} {b}"]
                cells.append("-" if leak < ROUNDING or not np.isfinite(x) else f"{x:.3g}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
