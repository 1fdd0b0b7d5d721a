"""Every pair of a focal plane on its own samples, binned into one map, optionally behind a
HWP or filtered before binning.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from .._util import interrupts
from .._util.threads import numba_threads
from ..instrument.hwp import angle_jitter, plate_signals, reflected, reflected_systematics
from ..instrument.pairs import Instrument, Systematics

# CPU only (not of the contract): the 3x3 maps, and the pair differences a filter acts on
from ..kernels.pixels import ang2pix_array
from ..mapmaking import RCOND_MIN, Maps
from ..mitigation import Filtering
from ..pointing import detector_pointing
from .binner import Binner, check_backend_mapmaker, normal_sums, stream_maps
from .mitigation import Cleaning

if TYPE_CHECKING:
    from ..instrument.focalplane import FocalPlane
    from ..instrument.hwp import HWP
    from ..schedule import Schedule
    from ..sky import Sky


def simulate_focalplane(
    sky: Sky,
    schedule: Schedule,
    focalplane: FocalPlane,
    systematics: Systematics = Systematics(),
    *,
    evaluation: str = "interp",
    leak_template: np.ndarray | None = None,
    nthreads: int = 0,
    backend: str = "cpu",
    rcond_min: float = RCOND_MIN,
    chunk_samples: int = 1 << 20,
    hwp: HWP | None = None,
    mapmaker: str = "pairs",
    filtering: Filtering = Filtering(),
    progress: bool = False,
) -> Maps:
    """Maps from every pair of a focal plane on a schedule, each pair on its own samples
    (:func:`boresight.pointing.detector_pointing`), all binned into one map as the map-maker
    combines them.

    Behind a HWP each pair's pair difference is that of a bare pair at its reflected angle
    (:func:`boresight.instrument.hwp.reflected`), and the map-maker solves with that angle: exact for the
    sky and for what the pairs carry through the HWP (:data:`boresight.instrument.hwp.THROUGH_HWP`).

    Pair i has the focal plane's angle and the systematics' i-th draw (as pair i of
    ``Instrument(pair_angles_deg=focalplane.pair_angles_deg)``); the gain jitter of its sample k
    is keyed by (seed, i x samples + k), and a HWP angle's jitter at sample k by (seed, k) for
    every pair, so nothing depends on the chunks.

    Parameters
    ----------
    sky : boresight.sky.Sky
    schedule : boresight.schedule.Schedule
    focalplane : boresight.instrument.focalplane.FocalPlane
    systematics : boresight.instrument.pairs.Systematics
    evaluation, leak_template, nthreads, rcond_min, mapmaker
        As in :func:`simulate_samples`.
    backend : {"cpu"}
        The GPU backend does not take a focal plane yet.
    chunk_samples : int
        Pair-samples per chunk of pointing.
    hwp : boresight.instrument.hwp.HWP, optional
        A continuous or stepped HWP in front of every pair, with its own signals
        (:func:`boresight.instrument.hwp.plate_signals`) and angle offset (:func:`boresight.instrument.hwp.reflected_systematics`).
    filtering : boresight.mitigation.Filtering
        Each pair's pair differences filtered CES by CES before binning, as in
        :func:`simulate_schedule` (the throws and azimuth the boresight's): the pairs' map-maker,
        no plate. Pair i's sample k keeps its gain jitter's key (seed, i x samples + k). Each
        pair's templates are its own (its pointing and angle).
    progress : bool

    Returns
    -------
    boresight.mapmaking.Maps
        Hits count pair-samples; the (I, Q, U) map-makers give ``i`` as well.
    """
    if backend != "cpu":
        raise ValueError(f"backend {backend!r}: a focal plane's TOD runs on the CPU backend only")
    cleaning = Cleaning(filtering, sky, schedule.frame)
    if filtering:
        cleaning.check(schedule, backend=backend, mapmaker=mapmaker, evaluation=evaluation, hwp=hwp)
    if hwp is not None:
        systematics = reflected_systematics(hwp, systematics, own_angles=True)
    check_backend_mapmaker(mapmaker, backend)
    gammas = np.radians(focalplane.gamma_deg)
    instrument = Instrument(pair_angles_deg=focalplane.pair_angles_deg)
    binner = Binner(
        sky, instrument, systematics, (0.0,), evaluation, leak_template, nthreads, backend
    )
    pairs = [binner.for_pair(i) for i in range(focalplane.n_pairs)]
    normal = normal_sums(binner.kernels, sky.nside, mapmaker)
    first = 0
    total = schedule.n_samples * focalplane.n_pairs
    if filtering:
        with (
            numba_threads(nthreads),
            tqdm(total=total, unit="sample", unit_scale=True, disable=not progress) as bar,
        ):
            for block, members in cleaning.blocks(schedule):
                parts = [[] for _ in pairs]
                c_s = [[] for _ in pairs]
                for one, scan in members:
                    chunks = list(detector_pointing(one, focalplane, chunk_samples))
                    theta, phi, psi = (np.concatenate(x, axis=1) for x in zip(*chunks))
                    for i, pair in enumerate(pairs):
                        interrupts.check()
                        key = i * schedule.n_samples + first
                        c, s, d = pair.differences(
                            theta[i], phi[i], psi[i], seed=systematics.seed, first=key,
                            detectors=cleaning.detectors,
                        )  # fmt: skip
                        parts[i].append(
                            cleaning.part(
                                d,
                                pair,
                                theta[i],
                                phi[i],
                                psi[i],
                                scan=scan,
                                schedule=schedule,
                                nside=sky.nside,
                            )
                        )
                        c_s[i].append((c, s))
                    first += theta.shape[1]
                    bar.update(theta.size)
                for i in range(len(pairs)):
                    cleaning.bin_block(parts[i], c_s[i], normal, f"pair {i}, {block}")
        return stream_maps(
            binner.kernels, sky.nside, normal, mapmaker, n_pairs=1, rcond_min=rcond_min
        )
    with (
        numba_threads(nthreads),
        tqdm(total=total, unit="sample", unit_scale=True, disable=not progress) as bar,
    ):
        for theta, phi, psi, *chi in detector_pointing(
            schedule, focalplane, chunk_samples, hwp=hwp
        ):
            jitter = None
            if chi and hwp.angle_jitter_deg:  # the plate's, one per sample for every pair
                jitter = angle_jitter(hwp, systematics.seed, first, theta.shape[1])
            for i, one in enumerate(pairs):
                interrupts.check()
                pix = ang2pix_array(sky.nside, theta[i], phi[i])
                key = i * schedule.n_samples + first
                angle = reflected(psi[i], chi[0], gammas[i]) if chi else psi[i]
                seen = None
                if chi and hwp.has_signals:
                    seen = functools.partial(
                        plate_signals, hwp, psi=psi[i], chi=chi[0], gamma=gammas[i], jitter=jitter
                    )
                one.scatter(
                    pix,
                    theta[i],
                    phi[i],
                    angle,
                    normal,
                    seed=systematics.seed,
                    first=key,
                    mapmaker=mapmaker,
                    seen=seen,
                    own_psi=psi[i] if chi else None,
                )
            first += theta.shape[1]
            bar.update(theta.size)
    return stream_maps(binner.kernels, sky.nside, normal, mapmaker, n_pairs=1, rcond_min=rcond_min)
