"""A half-wave plate (HWP): its angle over a schedule, and what a detector sees through it.

The HWP's angle chi is measured in the focal plane, from its x axis, as TOAST's ``hwp_angle``.
An ideal HWP reflects the polarisation about its fast axis, so a detector at angle gamma in the
focal plane (a pair's angle; its partner at gamma + 90 deg) sees the sky as a bare detector at
2 chi - gamma would:

    d = I + Q cos 2a + U sin 2a,   a = psi - gamma + 2 chi   (a = psi + gamma without a HWP)

with psi boresight's crossing angle (the focal plane's orientation on the sky, COSMO) and Q, U in
HEALPix's COSMO convention. This is TOAST's ``StokesWeights`` with a HWP: its weights
(1, cos(2 alpha + 4 chi - 4 gamma), sin(2 alpha + 4 chi - 4 gamma)), with its detector angle
alpha = psi + gamma - pi, are these (``tests/instrument/test_hwp.py``, to 1e-10).

In spin language a pair difference sees the sky's P as Re[P exp(-2 i a)], and the map-maker
weighs it by exp(2 i a) = exp(2 i psi) exp(4 i chi) exp(-2 i gamma): with the moments
h_{n,m} = <exp(i n psi + i m chi)> (:func:`boresight.moments.hwp_moments`), the map-maker's
weights sit at (n, m) = (2, 4), its 2x2 system at (4, 8), and a leak that reaches a bare pair's
map through h_2 (a gain's or a leak's T) reaches it through h_{2,4} behind the plate. The sign of
m is the sense of chi: Takase et al. (2024) and SBM write the sky's polarisation at (2, -4) with
their own.

Two kinds of HWP:

* ``continuous``: chi = phase + 2 pi f t, t the sample's unix time (TOAST's ``SimGround`` with
  ``hwp_rpm`` = 60 f, up to its rounding of each observation's start to a whole sample);
* ``stepped``: one of ``angles_deg`` per CES, per day or per repeat of the CES set, in turn.

The repeats of a schedule's CES set reuse its times, so a continuous HWP turns through the same
angles in every repeat.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..constants import DEG
from ..kernels.rng import HWP_SALT, normal_array
from ..scan import SyntheticScan
from ..validation import ConfigError, number
from .added import refuse as refuse_added
from .pairs import AMPLITUDES, BEAM_KEYS, Instrument, Spread, is_nonzero

MODES = ("none", "continuous", "stepped")
#: what a stepped HWP steps with: each CES, each UTC day, each repeat of the CES set
STEPS = ("ces", "day", "repeat")
DAY_S = 86400.0


@dataclass(frozen=True)
class HWP:
    """A half-wave plate.

    Parameters
    ----------
    mode : {"none", "continuous", "stepped"}
    frequency_hz : float
        A continuous HWP's rotations per second (SO's small-aperture telescopes: 2).
    phase_deg : float
        A continuous HWP's angle at unix time 0 [deg].
    angles_deg : tuple of float
        A stepped HWP's angles, taken in turn [deg] (default: four steps of 22.5 deg, which
        cancel exp(4 i chi)).
    step : {"ces", "day", "repeat"}
        When a stepped HWP moves to its next angle.
    ip : float
        The plate's instrumental polarisation epsilon: a fraction of the intensity polarised in
        the focal plane at angle ``ip_phase_deg`` / 2 on the sky's side of the plate, so modulated
        at 4 chi in the TOD, epsilon I cos(4 chi - 2 gamma - phase) (:func:`plate_signals`).
    ip_phase_deg : float
        Its phase [deg].
    angle_offset_deg : float
        The plate's true angle less the angle the map-maker takes for it [deg]
        (:func:`reflected_systematics`).
    angle_jitter_deg : float
        The rms of a white jitter of its true angle about that, sample to sample [deg]: one
        deviate per sample, shared by every pair (:func:`angle_jitter`, :func:`plate_signals`).
    synchronous_muk : tuple of float
        The amplitudes (A_2, A_4) of its synchronous signal at 2 and 4 chi [muK]
        (:func:`plate_signals`).
    synchronous_phase_deg : tuple of float
        Their phases (phi_2, phi_4) [deg].
    """

    mode: str = "none"
    frequency_hz: float = 2.0
    phase_deg: float = 0.0
    angles_deg: tuple = (0.0, 22.5, 45.0, 67.5)
    step: str = "ces"
    ip: float = 0.0
    ip_phase_deg: float = 0.0
    angle_offset_deg: float = 0.0
    angle_jitter_deg: float = 0.0
    synchronous_muk: tuple = (0.0, 0.0)
    synchronous_phase_deg: tuple = (0.0, 0.0)

    def __post_init__(self):
        if self.mode not in MODES:
            raise ConfigError(f"hwp {self.mode!r}; allowed: {MODES}")
        if self.step not in STEPS:
            raise ConfigError(f"hwp step {self.step!r}; allowed: {STEPS}")
        for name, lo, hi in _BOUNDS:
            try:  # a bool, a string or a number past its bounds is refused, not taken as 1 or 0
                value = number(f"hwp {name}", getattr(self, name), lo, hi)
            except (TypeError, ValueError) as err:
                raise ConfigError(str(err)) from None
            object.__setattr__(self, name, value)
        if not self.frequency_hz > 0:
            raise ConfigError(f"hwp frequency_hz must be > 0, got {self.frequency_hz!r}")
        if not abs(self.angle_offset_deg) < 45.0:
            raise ConfigError(f"hwp angle offset {self.angle_offset_deg!r} deg: within (-45, 45)")
        if not self.angle_jitter_deg < 45.0:
            raise ConfigError(f"hwp angle jitter {self.angle_jitter_deg!r} deg: within [0, 45)")
        object.__setattr__(self, "angles_deg", _numbers("angles_deg", self.angles_deg, None))
        for name in ("synchronous_muk", "synchronous_phase_deg"):
            object.__setattr__(self, name, _numbers(name, getattr(self, name), 2))

    @property
    def present(self) -> bool:
        """Whether there is a plate (mode "none" is none)."""
        return self.mode != "none"

    @property
    def spinning(self) -> bool:
        """Whether the plate spins continuously."""
        return self.mode == "continuous"

    @property
    def stepped(self) -> bool:
        """Whether the plate steps through its angles."""
        return self.mode == "stepped"

    @property
    def steps_with_repeats(self) -> bool:
        """Whether a stepped plate moves to its next angle with each repeat of the CES set."""
        return self.stepped and self.step == "repeat"

    def label(self) -> str:
        """The plate in words, for tables: "continuous 2 Hz", "stepped per ces (0, 45 deg)"."""
        if self.spinning:
            return f"continuous {self.frequency_hz:g} Hz"
        angles = ", ".join(f"{a:g}" for a in self.angles_deg)
        return f"stepped per {self.step} ({angles} deg)"

    @property
    def has_signals(self) -> bool:
        """Whether the pairs see more through the plate than the sky at its angle: its own
        signals or its angle's jitter (:func:`plate_signals`)."""
        return bool(self.ip) or any(self.synchronous_muk) or self.angle_jitter_deg > 0.0


#: each number of a HWP and its bounds: angles and phases within ten turns (past that float
#: digits are lost to the modulo), frequencies to 1 kHz, an IP fraction within [-1, 1]
_BOUNDS = (
    ("frequency_hz", 0.0, 1e3),
    ("phase_deg", -3600.0, 3600.0),
    ("ip", -1.0, 1.0),
    ("ip_phase_deg", -3600.0, 3600.0),
    ("angle_offset_deg", -45.0, 45.0),
    ("angle_jitter_deg", 0.0, 45.0),
)
MAX_STEPS = 720  #: a stepped plate's angles at most (one every quarter degree of its half turn)
_LISTS = {  # bounds of each element of the lists
    "angles_deg": (-3600.0, 3600.0),
    "synchronous_muk": (-1e6, 1e6),
    "synchronous_phase_deg": (-3600.0, 3600.0),
}


def _numbers(name, values, count):
    """A HWP's list field as a tuple of floats: a list or tuple (a string is not one) of
    ``count`` numbers (one or more where None), each within :data:`_LISTS`."""
    lo, hi = _LISTS[name]
    if isinstance(values, (str, bytes)) or not isinstance(values, (list, tuple, np.ndarray)):
        raise ConfigError(f"hwp {name} = {values!r}: a list of numbers")
    if (count is None and len(values) == 0) or (count is not None and len(values) != count):
        want = "one or more numbers" if count is None else f"{count} numbers"
        raise ConfigError(f"hwp {name} = {values!r}: {want}")
    if len(values) > MAX_STEPS:  # 18,000 steps allocated 21.7 GiB in the design
        raise ConfigError(f"hwp {name}: {len(values)} values; at most {MAX_STEPS}")
    try:
        return tuple(number(f"hwp {name}", v, lo, hi) for v in values)
    except (TypeError, ValueError) as err:
        raise ConfigError(str(err)) from None


def check_sampling(hwp: HWP | None, sample_rate_hz: float) -> None:
    """Refuse, before any work, a continuous plate whose 4 chi turns by whole turns from sample
    to sample: its modulation aliases to a constant."""
    if hwp is None or not hwp.spinning:
        return
    per_sample = 4.0 * hwp.frequency_hz / sample_rate_hz
    if abs(per_sample - round(per_sample)) < 1e-6:
        raise ConfigError(
            f"a {hwp.frequency_hz:g} Hz HWP sampled at {sample_rate_hz:g} Hz turns 4 chi "
            "by whole turns from sample to sample: its modulation aliases to a constant; give "
            "another frequency or sample rate"
        )


def step_index(hwp: HWP, schedule, repeat: int, index: int) -> int:
    """Which of a stepped HWP's angles CES ``index`` of repeat ``repeat`` takes (before the modulo).

    Parameters
    ----------
    hwp : HWP
    schedule : boresight.schedule.Schedule
    repeat, index : int
        The repeat of the CES set and the CES's place in it (time order).

    Returns
    -------
    int
    """
    if hwp.step == "repeat":
        return repeat
    if hwp.step == "ces":
        return repeat * len(schedule.ces) + index
    first = math.floor(min(c.start_unix for c in schedule.ces) / DAY_S)
    days = math.floor(max(c.start_unix for c in schedule.ces) / DAY_S) - first + 1
    return repeat * days + math.floor(schedule.ces[index].start_unix / DAY_S) - first


def chunk_angles(hwp: HWP, schedule, repeat: int, index: int, *, first: int, n: int) -> np.ndarray:
    """The HWP's angle chi [rad] at samples first .. first + n - 1 of a CES, in [0, 2 pi).

    Parameters
    ----------
    hwp : HWP
        Continuous or stepped.
    schedule : boresight.schedule.Schedule
    repeat, index : int
        As :func:`step_index`.
    first, n : int
        The chunk's first sample in its CES, and its samples.

    Returns
    -------
    numpy.ndarray, float64, shape (n,)
    """
    if hwp.stepped:
        angle = hwp.angles_deg[step_index(hwp, schedule, repeat, index) % len(hwp.angles_deg)]
        return np.full(n, (angle * DEG) % (2 * np.pi))
    if not hwp.spinning:
        raise ValueError("a HWP angle needs a continuous or a stepped HWP")
    check_sampling(hwp, schedule.sample_rate_hz)
    # the whole turns of the CES's start are taken out first, so that 2 pi f t keeps its digits
    start = schedule.ces[index].start_unix
    turns = math.fmod(hwp.frequency_hz * start, 1.0)
    cycles = turns + hwp.frequency_hz * (first + np.arange(n)) / schedule.sample_rate_hz
    return (2 * np.pi * cycles + hwp.phase_deg * DEG) % (2 * np.pi)


#: the systematics a pair behind the HWP carries as a bare pair at its reflected angle does
#: (:func:`reflected`): those that do not depend on where the pair points
THROUGH_HWP = ("dg", "leak", "dg_jitter")
#: the systematics the HWP reflects: a detector at gamma + theta behind it sees a - theta
REFLECTED_BY_HWP = ("pol_angle_deg", "nonortho_deg")


#: the systematics that turn with the focal plane, not with the HWP: carried where each pair's
#: own crossing angle is known beside its reflected one (a schedule's pairs,
#: :func:`boresight.engine.simulate_focalplane` and :mod:`boresight.predict.focalplane`)
POINTING_BEHIND_HWP = ("rho_arcmin", "chi_deg")
#: the detectors' beams: their shapes turn with the focal plane, their polarisation with the
#: HWP; carried where a pointing offset is, on pairs without polarisation-angle errors
BEAMS_BEHIND_HWP = tuple(k for keys in BEAM_KEYS.values() for k in keys)


def check_systematics(systematics, *, own_angles: bool = False) -> None:
    """Refuse systematics the HWP's pairs do not yet carry (:data:`THROUGH_HWP`,
    :data:`REFLECTED_BY_HWP`, and with ``own_angles`` :data:`POINTING_BEHIND_HWP` and
    :data:`BEAMS_BEHIND_HWP`): a pointing offset or a beam turns with the focal plane, not with
    the HWP, so it needs the pairs' own crossing angles; a beam beside an angle error is not
    carried yet."""
    refuse_added(systematics, "a HWP")
    behind = POINTING_BEHIND_HWP + BEAMS_BEHIND_HWP if own_angles else ()
    carried = THROUGH_HWP + REFLECTED_BY_HWP + behind
    others = [k for k in AMPLITUDES if k not in carried and is_nonzero(getattr(systematics, k))]
    if others or is_nonzero(systematics.dg_repeat):
        where = "" if own_angles else " (pointing and beams only on a schedule's focal plane)"
        raise ValueError(
            f"{', '.join(others) or 'dg_repeat'} behind a HWP: not yet simulated or predicted "
            f"here; a HWP's pairs carry {', '.join(carried)}{where}"
        )
    angles = [k for k in REFLECTED_BY_HWP if is_nonzero(getattr(systematics, k))]
    if systematics.has_beams and angles:
        raise ValueError(
            f"beams with {', '.join(angles)} behind a HWP: not yet simulated or predicted; a "
            "HWP's pairs carry beams on detectors at their nominal angles"
        )


def _turned(value, sign: float, shift: float = 0.0):
    """sign x value + shift, for a number, one per pair, or a {mean, rms} Spread (its mean)."""
    if isinstance(value, Spread):
        return Spread(sign * value.mean + shift, value.rms)
    if np.ndim(value):
        return tuple(sign * float(x) + shift for x in value)
    return sign * float(value) + shift


def reflected_systematics(hwp: HWP, systematics, *, own_angles: bool = False):
    """The systematics of pairs behind the plate as the bare pairs at their reflected angles
    (:func:`reflected`) carry them, the plate's angle offset delta included.

    * A detector at gamma + theta behind the plate sees a = psi - gamma - theta + 2 chi: its
      angle error theta is -theta for the pair at its reflected angle, so ``pol_angle_deg`` and
      ``nonortho_deg`` change sign (a {mean, rms} draw keeps its rms and flips its mean: the
      same distribution, pair i's draw -mean + rms z_i).
    * The map-maker takes a = psi - gamma + 2 chi where the plate at chi + delta shows the pair
      a + 2 delta: a polarisation-angle error of 2 delta on both detectors of every pair. The
      maps' P turns by exp(-4 i delta) (E into B through h_0, which no rotation touches; a
      calibration's job).

    Parameters
    ----------
    hwp : HWP
    systematics : boresight.instrument.pairs.Systematics
        The pairs' own (:func:`check_systematics`).
    own_angles : bool
        Whether the caller carries pointing offsets and beams, which stay as they are: they turn
        with each pair's own crossing angle (:data:`POINTING_BEHIND_HWP`,
        :data:`BEAMS_BEHIND_HWP`).

    Returns
    -------
    boresight.instrument.pairs.Systematics
    """
    check_systematics(systematics, own_angles=own_angles)
    pol, nonortho = systematics.pol_angle_deg, systematics.nonortho_deg
    if hwp.angle_offset_deg == 0.0 and not (is_nonzero(pol) or is_nonzero(nonortho)):
        return systematics
    return replace(
        systematics,
        pol_angle_deg=_turned(pol, -1.0, 2.0 * hwp.angle_offset_deg),
        nonortho_deg=_turned(nonortho, -1.0),
    )


def reflected(psi: np.ndarray, chi: np.ndarray, gamma: float) -> np.ndarray:
    """The crossing angle at which a bare pair at angle ``gamma`` sees the sky as this pair does
    behind the HWP at ``chi``: psi + 2 chi - 2 gamma (so that its a = psi' + gamma is
    psi - gamma + 2 chi) [rad]."""
    return psi + 2.0 * chi - 2.0 * gamma


def mirrored(instrument: Instrument) -> Instrument:
    """The bare pairs at the reflected angles of pairs behind a HWP: a pair at gamma sees the
    sky as a bare pair at -gamma crossing at psi + 2 chi (:func:`reflected`); their order, and
    so the systematics' draws, kept."""
    return Instrument(pair_angles_deg=tuple(0.0 - a for a in instrument.pair_angles_deg))


def pairs_behind(hwp: HWP, systematics, instrument: Instrument | None):
    """What a prediction of pairs on the axis behind the plate takes: their systematics and
    pairs as the bare pairs at their reflected angles carry them (:func:`reflected_systematics`,
    :func:`mirrored`), and the plate's IP coefficient epsilon exp(i phase), which reaches the
    maps through the crossing angles' own h_2 (:func:`boresight.predict.expected_residual`).

    Parameters
    ----------
    hwp : HWP
        Without an angle jitter or a synchronous signal, which such a prediction does not carry.
    systematics : boresight.instrument.pairs.Systematics
    instrument : boresight.instrument.pairs.Instrument or None
        None: the paper's pairs.

    Returns
    -------
    systematics : boresight.instrument.pairs.Systematics
    instrument : boresight.instrument.pairs.Instrument
    ip : complex
    """
    if hwp.angle_jitter_deg > 0.0 or any(hwp.synchronous_muk):
        raise ValueError(
            "the exact expectation carries a HWP's instrumental polarisation and angle offset; "
            "its angle jitter and synchronous signal are not in it yet"
        )
    pairs = mirrored(Instrument() if instrument is None else instrument)
    ip = hwp.ip * complex(math.cos(hwp.ip_phase_deg * DEG), math.sin(hwp.ip_phase_deg * DEG))
    return reflected_systematics(hwp, systematics), pairs, ip


def behind(hwp: HWP, scan: SyntheticScan, instrument: Instrument):
    """A synthetic scan and its pairs behind a HWP, as the bare scan and pairs that see the sky
    alike (for what the pairs carry through the HWP, :data:`THROUGH_HWP`; their angle errors
    reflected by :func:`reflected_systematics`).

    a = psi - gamma + 2 chi is a bare pair at -gamma crossing at psi + 2 chi, so the pairs'
    angles are mirrored (their order, and so their systematics, kept) and:

    * continuous: chi is drawn uniformly per hit, so psi + 2 chi is uniform over the circle
      whatever psi: the scan's range becomes 2 pi (its hits and their places stay, and a
      rotation repeat keeps its hit's HWP angle);
    * stepped: repeat k of the scan's rotations has the HWP at ``angles_deg[k % len]``, so its
      rotation becomes rotation_k + 2 chi_k.

    Parameters
    ----------
    hwp : HWP
        Continuous, or stepped per repeat (a synthetic scan has no CESs or days).
    scan : boresight.scan.SyntheticScan
    instrument : boresight.instrument.pairs.Instrument

    Returns
    -------
    scan : boresight.scan.SyntheticScan
    instrument : boresight.instrument.pairs.Instrument
    """
    pairs = mirrored(instrument)
    if hwp.spinning:
        return replace(scan, range_rad=2 * np.pi, centre_rad=0.0), pairs
    if not hwp.stepped:
        raise ValueError("behind() needs a continuous or a stepped HWP")
    if hwp.step != "repeat":
        raise ConfigError(
            f"hwp step {hwp.step!r}: a synthetic scan has no CESs or days; its HWP steps per "
            "rotation repeat (step = 'repeat')"
        )
    angles = hwp.angles_deg
    rotations = tuple(r + 2 * angles[k % len(angles)] for k, r in enumerate(scan.rotations_deg))
    return replace(scan, rotations_deg=rotations), pairs


def angle_jitter(hwp: HWP, seed: int, first: int, n: int) -> np.ndarray:
    """The jitter of the plate's angle at samples first .. first + n - 1 of a schedule's stream
    [rad]: white normal deviates of rms ``angle_jitter_deg``, keyed by (seed, sample), so the
    same whatever the chunks and for every pair at one sample.

    Parameters
    ----------
    hwp : HWP
    seed, first, n : int

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    if hwp.angle_jitter_deg == 0.0:
        return np.zeros(n)
    return hwp.angle_jitter_deg * DEG * normal_array(seed, 0, HWP_SALT, n, first)


def plate_signals(
    hwp: HWP,
    values: np.ndarray,
    *,
    psi: np.ndarray,
    chi: np.ndarray,
    gamma: float,
    jitter: np.ndarray | None = None,
) -> np.ndarray:
    """The fields a pair at angle ``gamma`` behind the plate sees, with the plate's own signals.

    * Its instrumental polarisation: epsilon I polarised in the focal plane at phase / 2, that is
      epsilon I exp(i (2 psi + phase)) added to the sky's P = Q + i U (a focal-plane angle theta
      is psi + theta on the sky). Through the plate a detector at gamma sees it as
      epsilon I cos(4 chi - 2 gamma - phase), its partner the opposite: the pair difference keeps
      it, and it reaches the map through the crossing angles' h_{2,0} (docs/conventions.md).
    * Its angle's jitter j: the plate at chi + j reflects the pair's angle to a + 2 j, so the pair
      sees P exp(-4 i j) (the plate's IP with it) where the map-maker takes P. On average that
      is P exp(-8 sigma^2); the rest is white (:func:`boresight.predict.hwp.angle_jitter_leak`).
    * Its synchronous signal: A_2 cos(2 (chi - gamma) - phi_2) + A_4 cos(4 (chi - gamma) - phi_4)
      [muK] added to each detector, fixed to the instrument; at 90 deg the partner sees A_2 with
      the opposite sign and A_4 alike. The A_4 part is common to the pair (added to I); the A_2
      part is the pair's difference, added to Q, U along the detector's true angle a = psi' +
      gamma + 2 delta (so that Q cos 2a + U sin 2a is it).

    Parameters
    ----------
    hwp : HWP
    values : numpy.ndarray, shape (F, H)
        I, Q, U (and a leak's template) at the samples [muK].
    psi : numpy.ndarray, shape (H,)
        The pair's own crossing angle at each sample [rad] (not the reflected one).
    chi : numpy.ndarray, shape (H,)
        The plate's angle [rad].
    gamma : float
        The pair's angle in the focal plane [rad].
    jitter : numpy.ndarray, shape (H,), optional
        The plate's angle jitter at the samples [rad] (:func:`angle_jitter`); needed where
        ``angle_jitter_deg`` > 0.

    Returns
    -------
    numpy.ndarray, shape (F, H)
        A copy with the plate's signals added.
    """
    out = np.array(values, dtype=np.float64)
    psi, chi = np.asarray(psi), np.asarray(chi)
    if hwp.ip:
        angle = 2.0 * psi + hwp.ip_phase_deg * DEG
        out[1] += hwp.ip * out[0] * np.cos(angle)
        out[2] += hwp.ip * out[0] * np.sin(angle)
    if hwp.angle_jitter_deg > 0.0:
        if jitter is None:
            raise ValueError("a HWP with an angle jitter: give its jitter at the samples")
        turned = (out[1] + 1j * out[2]) * np.exp(-4j * np.asarray(jitter))
        out[1], out[2] = turned.real, turned.imag
    a2, a4 = hwp.synchronous_muk
    phi2, phi4 = (p * DEG for p in hwp.synchronous_phase_deg)
    if a4:
        out[0] += a4 * np.cos(4.0 * (chi - gamma) - phi4)
    if a2:
        difference = a2 * np.cos(2.0 * (chi - gamma) - phi2)
        a = reflected(psi, chi, gamma) + gamma + 2.0 * hwp.angle_offset_deg * DEG
        out[1] += difference * np.cos(2.0 * a)
        out[2] += difference * np.sin(2.0 * a)
    return out


def stokes_weights(psi: np.ndarray, gamma: float, chi: np.ndarray | None = None) -> np.ndarray:
    """The I, Q, U weights of a detector at angle ``gamma`` in the focal plane, behind an ideal
    HWP at ``chi`` (module docstring).

    Parameters
    ----------
    psi : numpy.ndarray
        boresight's crossing angle of the focal plane [rad].
    gamma : float
        The detector's angle in the focal plane [rad] (a pair's angle, or it + pi / 2).
    chi : numpy.ndarray, optional
        The HWP's angle in the focal plane [rad]; None without a HWP.

    Returns
    -------
    numpy.ndarray, shape (psi.size, 3)
        (1, cos 2a, sin 2a): d = I + Q cos 2a + U sin 2a.
    """
    psi = np.asarray(psi, dtype=np.float64)
    a = (psi if chi is None else reflected(psi, np.asarray(chi), gamma)) + gamma
    return np.stack([np.ones_like(a), np.cos(2 * a), np.sin(2 * a)], axis=-1)
