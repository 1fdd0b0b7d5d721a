"""What several test files share: the repository's paths, comparison helpers, Hypothesis
strategies of configs and schedules, and small input files."""

from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from boresight import cli
from boresight.schedule import CES, Schedule, Site, toast, write_schedule

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def rel_max(a, b):
    """Largest |a - b| relative to the largest |b|."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))


T0 = 1.79e9  # 2026-09-21, inside the IERS tables astropy ships


CENTRED = dict(n_phi=4, range_rad=0.9, in_pixel="centre", seed=3)


FUZZ = settings(
    max_examples=150,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def iqu(maps):
    """(3, n) I, Q, U of a 3x3 map-maker's maps on their pixels."""
    return np.array([maps.i_obs, maps.q_obs, maps.u_obs])


def mostly(valid, invalid):
    """Nine draws in ten from ``valid``: a study with several fields then still runs often."""
    return st.integers(0, 9).flatmap(lambda k: invalid if k == 9 else valid)


numbers = st.one_of(
    st.integers(-(2**65), 2**65),
    st.sampled_from([0, 1, 2, 3, 4, 8, 16, -1, 2**31]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 0.5, 1e-300, 1e300, -0.0]),
)


scalars = st.one_of(numbers, st.booleans(), st.text(max_size=8), st.just("junk.fits"))


values = st.one_of(
    scalars,
    st.lists(scalars, max_size=4),
    st.dictionaries(st.text(max_size=3), scalars, max_size=2),
)


cells = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10, 2 * 10**9).map(str),
    st.sampled_from(["", "2026-01-01", "x", "1e400", "50", "60", "1790028800"]),
)


VALID_CES = {
    "start_unix": st.floats(1.7e9, 1.8e9),
    "duration_s": st.floats(1, 60),
    "elevation_deg": st.floats(30, 70),
    "az_centre_deg": st.floats(-360, 360),
    "az_throw_deg": st.floats(0, 360),
    "speed_deg_s": st.floats(0.1, 3),
    "boresight_deg": st.floats(-180, 180),
    "turnaround_s": st.floats(0, 10),
}


ces_values = st.one_of(numbers, st.just("2026-01-01"), st.sampled_from([1, 50.0, 10.0, 1790028800]))


FUZZ_STUDY = (
    '[sky]\nnside = 16\nlmax = 47\n[mask]\nsurvey = "wide"\n[output]\nlmax = 40\nn_bands = 3\n'
)


STUDY = """
[sky]
nside = 16
lmax = 47
fwhm_arcmin = 240.0
[scan]
n_phi = 3
range_rad = 0.5
rotations_deg = [0.0, 90.0]
[systematics]
dg = [0.01, -0.01]
[mask]
survey = "wide"
[output]
lmax = 40
n_bands = 3
"""


CSV_HEADER = "start_unix,duration_s,elevation_deg,az_centre_deg,az_throw_deg,speed_deg_s\n"


CSV_ROW = "1790028800,60,50,133.6,60,1\n"


def sweep_file(tmp_path, parameters='pbr_angle_deg = [0, 90]\n"sky.seed" = [1]'):
    (tmp_path / "study.toml").write_text(STUDY)
    path = tmp_path / "sweep.toml"
    path.write_text(f'base = "study.toml"\n[parameters]\n{parameters}\n')
    return str(path)


def toast_text(tmp_path, name="in.txt", site="atacama", patch="deep"):

    def ces(patch):
        return (CES(1.79e9, 600.0, 50.0, 120.0, 20.0, 1.0, 0.0, 2.0, patch, 0, 0),)

    schedule = Schedule(ces(patch), Site(-22.96, -67.79, 5200.0, site, "sat"), 5.0)
    path = tmp_path / name  # a clean TOAST file to export from
    path.write_text(toast.text(Schedule(ces("deep"), Site(), 5.0)))
    return schedule, path


def toast_schedule():
    ces = (
        CES(9.466848e8 + 3000.5, 600.0, 50.0, 355.0, 20.0, 1.5, -45.0, 3.0, "field a", 2, 1),
        CES(9.466848e8 + 4000.0, 450.0, 60.0, 120.0, 10.0, 1.5, 30.0, 3.0, "b", 3, 0),
    )
    return Schedule(ces, Site(-22.9, -67.8, 5190.0, "chajnantor", "sat1"), 5.0)


def toast_december_schedule(directory, *, width_deg=10, hours=(3, 6)):
    """TOAST's own scheduler's CESs of one patch ``width_deg`` wide at RA 30, Dec -45 deg (of at
    most 10 minutes, 20 for a patch wider than 10 deg) at the Atacama site on 2026-12-01 between
    the UTC ``hours`` (where ICRS and the frame of date are 0.15 deg apart), written to
    ``directory / "schedule.txt"`` and read back as its GroundSchedule; the IERS tables are not
    downloaded. Needs toast."""
    from astropy.utils import iers
    from toast.schedule import GroundSchedule
    from toast.schedule_sim_ground import run_scheduler

    iers.conf.auto_download = False
    iers.conf.auto_max_age = None
    site = ["--site-name", "atacama", "--telescope", "SAT", "--site-lat", " -22.958"]
    site += ["--site-lon", " -67.787", "--site-alt", "5200"]
    patch = ["--patch", f"deep,1,30,-45,{width_deg}", "--el-min-deg", "45", "--el-max-deg", "60"]
    patch += ["--start", f"2026-12-01 {hours[0]:02d}:00:00"]
    patch += ["--stop", f"2026-12-01 {hours[1]:02d}:00:00"]
    patch += ["--ces-max-time-s", "600" if width_deg <= 10 else "1200"]
    patch += ["--sun-avoidance-angle-deg", "0", "--moon-avoidance-angle-deg", "0"]
    run_scheduler(opts=[*site, *patch, "--out", str(directory / "schedule.txt")])
    schedule = GroundSchedule()
    schedule.read(str(directory / "schedule.txt"))
    return schedule


def toast_binning(pixels, weights):
    """TOAST's ``BinMap`` of the default detector data, with these pixels and Stokes weights,
    its noise model "noise_model", the turnarounds' shared flags left out and invalid detector
    samples too, and those flags as keywords for a ``FilterBin`` around it (whose fit leaves out
    every non-science sample). Needs toast."""
    from toast import ops
    from toast.observation import default_values as defaults

    flags = dict(
        shared_flags=defaults.shared_flags,
        shared_flag_mask=defaults.shared_mask_nonscience,  # the turnarounds among them
        det_flags=defaults.det_flags,
    )
    binning = ops.BinMap(
        pixel_dist="pixel_dist",
        covariance="covariance",
        det_data=defaults.det_data,
        pixel_pointing=pixels,
        stokes_weights=weights,
        noise_model="noise_model",
        det_flag_mask=defaults.det_mask_invalid,
        **flags,
    )
    return binning, dict(flags, det_flag_mask=defaults.det_mask_nonscience)


def run_design(tmp_path, schedule, budget, *args):
    """Run `boresight design` on ``schedule`` (written as TOML) with ``budget``; its output."""
    src = tmp_path / "s.toml"
    write_schedule(schedule, str(src), "toml")
    out = tmp_path / "d"
    assert cli.main(["-q", "design", budget, str(src), "--out", str(out), *args]) == 0
    return out


def budget_file(tmp_path, nside=32, **tables):
    text = {
        "systematics": "dg = [0.01, -0.01]\nrho_arcmin = 0.5",
        "noise": "depth_uk_arcmin = 3.0\nfsky = 0.1\nfwhm_arcmin = 30.0",
        "design": f"nside = {nside}\nsweeps = 4",
    }
    text.update(tables)
    path = tmp_path / "budget.toml"
    path.write_text("\n".join(f"[{k}]\n{v}" for k, v in text.items() if v is not None))
    return str(path)


def night_schedule(site=Site(), rate=10.0, n=6, el=50.0):
    """n half-hour CESs an hour apart, rising then setting, at ``rate`` samples a second."""
    ces = tuple(
        CES(
            start_unix=T0 + i * 3600,
            duration_s=1800,
            elevation_deg=el,
            az_centre_deg=140 if i < n // 2 else 220,
            az_throw_deg=30,
        )
        for i in range(n)
    )
    return Schedule(ces, site, sample_rate_hz=rate)
