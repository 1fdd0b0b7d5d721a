"""The schedule of a real telescope: a site, constant-elevation scans (CES) and boresight repeats.

Each CES sweeps the azimuth between centre - throw / 2 and centre + throw / 2 at constant speed,
reversing at each end in ``turnaround_s`` at constant deceleration (overshooting by
speed * turnaround / 4), at fixed elevation and boresight angle. A :class:`Schedule` is data:
:mod:`boresight.schedule.files` and :mod:`boresight.schedule.toast` read and write it, and
:mod:`boresight.pointing` turns it into the sky pointing of every sample.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from .. import frames, validation

#: what a schedule does with the samples of its turnarounds
TURNAROUNDS = ("include", "exclude")


#: Simons Observatory site, Cerro Toco, Atacama (deg, deg, m)
ATACAMA = (-22.958, -67.787, 5200.0)


@dataclass(frozen=True)
class Site:
    """An observatory position.

    Parameters
    ----------
    lat_deg : float
        Geodetic latitude [deg], in [-90, 90].
    lon_deg : float
        East longitude [deg].
    alt_m : float
        Altitude [m].
    name, telescope : str
        Labels kept from and written to TOAST schedules (no ``|`` or line breaks).
    """

    lat_deg: float = ATACAMA[0]
    lon_deg: float = ATACAMA[1]
    alt_m: float = ATACAMA[2]
    name: str = "site"
    telescope: str = "telescope"

    def __post_init__(self):
        validation.number("lat_deg", self.lat_deg, -90.0, 90.0)
        validation.number("lon_deg", self.lon_deg, -180.0, 360.0)
        validation.number("alt_m", self.alt_m, -500.0, 1e5)
        validation.label("site name", self.name)
        validation.label("telescope", self.telescope)


@dataclass(frozen=True)
class CES:
    """One constant-elevation scan; every field finite and within :data:`CES_LIMITS`.

    Parameters
    ----------
    start_unix : float
        Start [UTC seconds since 1970].
    duration_s : float
        Length [s], > 0.
    elevation_deg : float
        Elevation [deg], in (0, 90).
    az_centre_deg, az_throw_deg : float
        Centre and full width of the azimuth sweep [deg].
    speed_deg_s : float
        Azimuth speed of the mount [deg/s], > 0.
    boresight_deg : float
        Boresight rotation of this CES [deg].
    turnaround_s : float
        Time to reverse at each end, at constant deceleration [s].
    name : str
        Patch name (TOAST's), kept as metadata.
    scan_index, subscan_index : int
        TOAST's pass and sub-pass of the patch, kept as metadata.
    hwp_dir : int
        Direction of the half-wave plate's spin: 1 forward (SO's ``hwp_dir`` 1, counter-clockwise,
        positive frequency), 0 reversed. A change between CESs stops and restarts the plate
        (:mod:`boresight.design.operations`).
    labels : tuple of (str, str)
        Labels another format carries verbatim (SO's master schedule: its priority, type and uid);
        boresight's TOML and CSV leave them out.
    """

    start_unix: float
    duration_s: float
    elevation_deg: float
    az_centre_deg: float
    az_throw_deg: float
    speed_deg_s: float = 1.0
    boresight_deg: float = 0.0
    turnaround_s: float = 0.0  #: time to reverse at each end, at constant deceleration
    name: str = "ces"
    scan_index: int = 0
    subscan_index: int = 0
    hwp_dir: int = 1
    labels: tuple = ()

    def __post_init__(self):
        for name, (lo, hi) in CES_LIMITS.items():
            validation.number(f"CES {name}", getattr(self, name), lo, hi)
        validation.label("CES name", self.name)
        validation.integer("CES scan_index", self.scan_index, 0)
        validation.integer("CES subscan_index", self.subscan_index, 0)
        if self.hwp_dir not in (0, 1) or isinstance(self.hwp_dir, bool):
            raise ValueError(f"CES hwp_dir = {self.hwp_dir!r} must be 1 (forward) or 0 (reversed)")
        if not all(
            isinstance(pair, tuple) and len(pair) == 2 and all(isinstance(x, str) for x in pair)
            for pair in self.labels
        ):
            raise ValueError("CES labels must be (key, text) pairs of strings")
        if not 0 < self.elevation_deg < 90:
            raise ValueError(f"CES elevation_deg = {self.elevation_deg} must lie in (0, 90)")
        if self.duration_s <= 0 or self.speed_deg_s <= 0:
            raise ValueError("CES duration_s and speed_deg_s must be > 0")


#: allowed range of every CES field: start between 1970 and 2100, speeds and times of real mounts
CES_LIMITS = {
    "start_unix": (0.0, 4.1e9),
    "duration_s": (0.0, 1e7),
    "elevation_deg": (0.0, 90.0),
    "az_centre_deg": (-720.0, 720.0),
    "az_throw_deg": (0.0, 360.0),
    "speed_deg_s": (0.0, 100.0),
    "boresight_deg": (-3600.0, 3600.0),
    "turnaround_s": (0.0, 3600.0),
}


#: the CES fields a schedule must give (the others have defaults)
CES_REQUIRED = ("start_unix", "duration_s", "elevation_deg", "az_centre_deg", "az_throw_deg")


#: the CES labels a schedule may give (TOAST's patch name, pass and sub-pass; the HWP's direction)
CES_METADATA = ("name", "scan_index", "subscan_index", "hwp_dir")


@dataclass(frozen=True)
class Idle:
    """A time the telescope does not observe, kept from a file that lists it (SO's master
    schedule's "None" rows) and written back unchanged.

    Parameters
    ----------
    start_unix, stop_unix : float
        Its start and end [UTC seconds since 1970].
    fields : tuple of (str, str)
        The file's columns and their text, verbatim.
    """

    start_unix: float
    stop_unix: float
    fields: tuple = ()


@dataclass(frozen=True)
class Schedule:
    """A site, a set of CESs and the sample rate.

    Parameters
    ----------
    ces : tuple of CES
    site : Site
    sample_rate_hz : float
    dut1_s : float
        UT1 - UTC [s], in [-1, 1].
    repeat_boresight_deg : tuple of float
        The CES set is observed once per angle [deg] (identical sky tracks).
    frame : {"icrs", "galactic", "cirs"}
        The sky frame of its pointing (:mod:`boresight.frames`).
    turnarounds : {"include", "exclude"}
        Keep or leave out the samples of the turnarounds (TOAST's map-making leaves them out).
    idle : tuple of Idle
        The times its file lists as not observing (SO's master schedule), kept to write back.
    """

    ces: tuple
    site: Site = Site()
    sample_rate_hz: float = 20.0
    dut1_s: float = 0.0  #: UT1 - UTC [s]
    repeat_boresight_deg: tuple = (0.0,)  #: the CES set is observed once per angle [deg]
    frame: str = "icrs"
    turnarounds: str = "include"
    idle: tuple = ()

    def __post_init__(self):
        frames.check_frame(self.frame)
        if self.turnarounds not in TURNAROUNDS:
            raise ValueError(f"turnarounds = {self.turnarounds!r}; allowed: {TURNAROUNDS}")
        if not self.ces or not all(isinstance(c, CES) for c in self.ces):
            raise ValueError("a schedule needs at least one CES")
        validation.number("sample_rate_hz", self.sample_rate_hz, 1e-3, 1e4)
        validation.number("dut1_s", self.dut1_s, -1.0, 1.0)
        rep = validation.numbers_array(
            "repeat_boresight_deg", self.repeat_boresight_deg, -3600.0, 3600.0
        )
        if rep.ndim != 1 or rep.size == 0:
            raise ValueError("repeat_boresight_deg needs at least one angle")
        object.__setattr__(self, "repeat_boresight_deg", tuple(float(a) for a in rep))

    @property
    def n_samples(self):
        per_set = sum(int(c.duration_s * self.sample_rate_hz) for c in self.ces)
        return per_set * len(self.repeat_boresight_deg)

    def repeated(self, boresight_deg):
        """This CES set observed once per boresight angle in the list (identical sky tracks)."""
        return replace(self, repeat_boresight_deg=tuple(boresight_deg))

    def single(self):
        """The CES set observed once, without the boresight repeats."""
        return replace(self, repeat_boresight_deg=(0.0,))

    def expanded(self):
        """The CESs in observing order, each boresight repeat as CESs of their own.

        Returns
        -------
        tuple of CES
            The CES set once per repeat angle, ``boresight_deg`` = its own + the repeat's.
        """
        return tuple(
            replace(c, boresight_deg=c.boresight_deg + rep)
            for rep in self.repeat_boresight_deg
            for c in self.ces
        )
