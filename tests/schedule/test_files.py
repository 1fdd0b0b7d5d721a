"""boresight's schedule files (TOML, CSV): written and read back, turnarounds left out alike on
every path, formats told apart by content, and bad files named by row and key."""

import math
from dataclasses import replace

import numpy as np
import pytest
from helpers import (
    CSV_HEADER,
    CSV_ROW,
    FUZZ,
    STUDY,
    T0,
    VALID_CES,
    cells,
    ces_values,
    mostly,
    numbers,
    toast_text,
)
from hypothesis import event, given
from hypothesis import strategies as st

from boresight import moments as scanstats
from boresight import pointing
from boresight.config import ConfigError
from boresight.schedule import (
    CES,
    CES_LIMITS,
    CES_REQUIRED,
    Schedule,
    ScheduleError,
    is_schedule,
    load_schedule,
    schedule_format,
    write_schedule,
)
from boresight.schedule.files import SCHEDULE_KEYS


def test_schedule_files(tmp_path):
    (tmp_path / "s.toml").write_text(
        "sample_rate_hz = 5.0\nrepeat_boresight_deg = [0.0, 90.0]\n[site]\nlat_deg = -22.96\n"
        "[[ces]]\nstart_unix = 1.79e9\nduration_s = 60\nelevation_deg = 45\n"
        "az_centre_deg = 180\naz_throw_deg = 20\n"
    )
    sched = load_schedule(str(tmp_path / "s.toml"))
    assert sched.repeat_boresight_deg == (0.0, 90.0) and sched.n_samples == 600
    psi = np.concatenate([c[2] for c in pointing.pointing(sched)])
    assert np.allclose(psi[300:] - psi[:300], np.pi / 2)  # the repeat: same track, rotated
    (tmp_path / "s.csv").write_text(
        "start_unix,duration_s,elevation_deg,az_centre_deg,az_throw_deg\n1.79e9,60,45,180,20\n"
    )
    assert load_schedule(str(tmp_path / "s.csv")).ces[0].az_throw_deg == 20
    with pytest.raises(ValueError, match="elevation_deg"):
        CES(start_unix=0, duration_s=1, elevation_deg=95, az_centre_deg=0, az_throw_deg=1)


def test_turnarounds_are_left_out_of_every_path_alike(tmp_path):
    """``turnarounds = "exclude"``: the pointing stream, the fused characterisation and the
    design's unit moments keep the same samples, those ces_samples does not flag; a TOML
    schedule keeps its frame and turnarounds through writing and reading."""
    ces = CES(T0, 300.0, 50.0, 180.0, 20.0, speed_deg_s=1.0, turnaround_s=4.0)
    every = Schedule((ces,), sample_rate_hz=10.0, frame="galactic")
    kept = replace(every, turnarounds="exclude")
    _, _, _, turning = pointing.ces_samples(ces, every)
    assert 0.1 < turning.mean() < 0.5  # 2 x 4 s of every 2 x (20 + 4) s
    streamed = sum(chunk[0].size for chunk in pointing.pointing(kept))
    assert streamed == (~turning).sum() == scanstats.characterise_schedule(kept, 32).hits.sum()
    assert scanstats.unit_moments(kept, 32).hits.sum() == streamed
    assert scanstats.characterise_schedule(every, 32).hits.sum() == turning.size
    write_schedule(kept, tmp_path / "k.toml", "toml")
    back = load_schedule(str(tmp_path / "k.toml"))
    assert (back.frame, back.turnarounds) == ("galactic", "exclude")
    assert load_schedule(str(tmp_path / "k.toml"), frame="icrs").frame == "icrs"
    with pytest.raises(ScheduleError, match="turnarounds"):
        load_schedule(str(tmp_path / "k.toml"), turnarounds="drop")


@st.composite
def csv_schedules(draw):
    """CSV schedules: mostly well-formed rows, sometimes a junk cell, column or row length."""
    header = list(CES_REQUIRED) + draw(
        st.lists(st.sampled_from([*VALID_CES, "colour"]), max_size=3, unique=True)
    )
    header = list(dict.fromkeys(header))
    if draw(st.integers(0, 9)) == 0:
        header = header[1:]
    rows = []
    for _ in range(draw(st.integers(1, 3))):
        row = [
            (
                repr(draw(mostly(VALID_CES.get(col, st.floats(0, 1)), st.nothing() | cells)))
                if draw(st.integers(0, 19))
                else draw(cells)
            )
            for col in header
        ]
        if draw(st.integers(0, 19)) == 0:
            row = row[:-1]
        rows.append(row)
    return ",".join(header) + "\n" + "".join(",".join(r) + "\n" for r in rows)


def _check_schedule(path):
    try:
        schedule = load_schedule(path)
    except ConfigError as err:
        assert "\n" not in str(err)
        event("schedule refused")
        return
    event("schedule loaded")
    if schedule.n_samples <= 20_000:  # characterise what is cheap: finite statistics
        stats = scanstats.characterise_schedule(schedule, 8)
        assert np.isfinite(stats.h).all() and stats.hits.sum() == schedule.n_samples


@FUZZ
@given(text=csv_schedules())
def test_any_csv_schedule_loads_or_names_its_error(text, tmp_path_factory):
    path = tmp_path_factory.mktemp("s") / "s.csv"
    path.write_text(text)
    _check_schedule(path)


@FUZZ
@given(
    ces=st.lists(
        st.dictionaries(st.sampled_from([*CES_LIMITS, "colour"]), ces_values, max_size=9),
        max_size=2,
    ),
    top=st.dictionaries(st.sampled_from([*SCHEDULE_KEYS[2:], "repeat"]), numbers, max_size=2),
)
def test_any_toml_schedule_loads_or_names_its_error(ces, top, tmp_path_factory):
    def value(v):
        if isinstance(v, float) and not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return repr(v) if not isinstance(v, str) else f'"{v}"'

    text = "".join(f"{k} = {value(v)}\n" for k, v in top.items())
    for c in ces:
        c = {**dict.fromkeys(CES_REQUIRED, 10), **c}
        text += "[[ces]]\n" + "".join(f"{k} = {value(v)}\n" for k, v in c.items())
    path = tmp_path_factory.mktemp("s") / "s.toml"
    path.write_text(text)
    _check_schedule(path)


@pytest.mark.parametrize(
    "text, where",
    [
        ("start_unix,duration_s,elevation_deg,az_centre_deg\n1790028800,60,50,133\n", "missing"),
        (CSV_HEADER.replace("\n", ",colour\n") + CSV_ROW.replace("\n", ",red\n"), "colour"),
        (CSV_HEADER + "1790028800,60,50\n", "line 2"),
        (CSV_HEADER + "2026-01-01,60,50,133.6,60,1\n", "start_unix"),
    ],
)
def test_bad_csv_schedules_name_the_row(tmp_path, text, where):
    path = tmp_path / "s.csv"
    path.write_text(text)
    with pytest.raises(ScheduleError, match=where):
        load_schedule(path)


@pytest.mark.parametrize(
    "text, where",
    [
        (
            "[[ces]]\nstart_unix = 1\nduration_s = 60\nelevation_deg = 50\naz_centre_deg = 1\n"
            "az_throw_deg = 10\ncolour = 1\n",
            "colour",
        ),
        (
            "[[ces]]\nstart_unix = 2026-01-01T00:00:00\nduration_s = 60\nelevation_deg = 50\n"
            "az_centre_deg = 1\naz_throw_deg = 10\n",
            "start_unix",
        ),
        (
            "repeat_boresight = [0, 90]\n[[ces]]\nstart_unix = 1\nduration_s = 60\n"
            "elevation_deg = 50\naz_centre_deg = 1\naz_throw_deg = 10\n",
            "repeat_boresight",
        ),
        ("this is = not [toml", "not valid TOML"),
    ],
)
def test_bad_toml_schedules_name_the_key(tmp_path, text, where):
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(ScheduleError, match=where):
        load_schedule(path)


def test_formats_are_told_apart_by_content_not_comments(tmp_path):
    """A TOML study or schedule whose first comment mentions "Site" is TOML; a TOAST file with a
    UTF-8 byte-order mark is TOAST's; a TOML file with one reads."""
    from boresight.config import load_study

    study = tmp_path / "study.toml"
    study.write_text("# Site: Atacama, a study of the deep field\n" + STUDY)
    assert not is_schedule(str(study)) and load_study(str(study)).sky.nside == 16
    schedule, toast_path = toast_text(tmp_path)
    toml_schedule = tmp_path / "schedule.toml"
    write_schedule(schedule, toml_schedule, "toml")
    toml_schedule.write_text("# Site | Telescope | lat | lon | alt\n" + toml_schedule.read_text())
    assert schedule_format(str(toml_schedule)) == "toml"
    assert load_schedule(str(toml_schedule)).ces == schedule.ces
    bom = tmp_path / "bom.txt"
    bom.write_bytes(b"\xef\xbb\xbf" + toast_path.read_bytes())
    assert schedule_format(str(bom)) == "toast"
    assert load_schedule(str(bom)).ces == load_schedule(str(toast_path)).ces
    study_bom = tmp_path / "study_bom.toml"
    study_bom.write_bytes(b"\xef\xbb\xbf" + STUDY.encode())
    assert load_study(str(study_bom)).sky.nside == 16
