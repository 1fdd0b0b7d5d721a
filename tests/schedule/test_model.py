"""The schedule's data model: sample counts, boresight repeats as CESs of their own, and fields
checked against their limits with the field named."""

import pytest
from helpers import T0

from boresight.schedule import CES, Schedule

CES_A = CES(
    start_unix=T0, duration_s=600.0, elevation_deg=50.0, az_centre_deg=134.0, az_throw_deg=40.0
)
CES_B = CES(
    start_unix=T0 + 900,
    duration_s=300.0,
    elevation_deg=45.0,
    az_centre_deg=200.0,
    az_throw_deg=30.0,
    boresight_deg=10.0,
)


def test_samples_count_every_ces_once_per_repeat():
    schedule = Schedule((CES_A, CES_B), sample_rate_hz=20.0, repeat_boresight_deg=(0.0, 90.0))
    assert schedule.n_samples == 2 * (600 * 20 + 300 * 20)
    assert schedule.single().n_samples == 600 * 20 + 300 * 20
    assert schedule.single().repeat_boresight_deg == (0.0,)


def test_expanded_repeats_add_their_angle_to_each_ces():
    schedule = Schedule((CES_A, CES_B)).repeated([0.0, 90.0])
    angles = [c.boresight_deg for c in schedule.expanded()]
    assert angles == [0.0, 10.0, 90.0, 100.0]
    assert [c.start_unix for c in schedule.expanded()] == [T0, T0 + 900] * 2  # identical tracks


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("elevation_deg", 95.0, "elevation_deg"),
        ("duration_s", 0.0, "duration_s"),
        ("start_unix", float("nan"), "start_unix"),
        ("speed_deg_s", -1.0, "speed_deg_s"),
    ],
)
def test_a_bad_ces_field_is_named(field, value, message):
    fields = dict(
        start_unix=T0, duration_s=600.0, elevation_deg=50.0, az_centre_deg=134.0, az_throw_deg=40.0
    )
    with pytest.raises(ValueError, match=message):
        CES(**{**fields, field: value})


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(ces=()), "at least one CES"),
        (dict(ces=(CES_A,), frame="fk5"), "frame"),
        (dict(ces=(CES_A,), turnarounds="drop"), "turnarounds"),
        (dict(ces=(CES_A,), repeat_boresight_deg=()), "repeat_boresight_deg"),
        (dict(ces=(CES_A,), sample_rate_hz=0.0), "sample_rate_hz"),
    ],
)
def test_a_bad_schedule_is_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Schedule(**kwargs)
