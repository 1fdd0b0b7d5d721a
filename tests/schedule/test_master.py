"""SO's SAT master schedule: boresight reads the hand-written fixture as schedlib's own parser
does (its column handling reproduced here from ``parse_sequence_from_toast_sat``), writes files
that parser reads back equal, round-trips every field, and names the file, line and column of
every bad row."""

from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from boresight import cli
from boresight.schedule import (
    CES,
    Schedule,
    ScheduleError,
    load_schedule,
    master,
    schedule_format,
    toast,
)
from boresight.schedule.files import write_schedule

FIXTURE = Path(__file__).parent / "data" / "so_master_sat.txt"


def schedlib_blocks(path):
    """schedlib's ``parse_sequence_from_toast_sat`` (simonsobs/scheduler,
    src/schedlib/instrument.py) without its block classes: the same pandas call, the same
    columns, ``utils.str2datetime`` and ``_escape_string``; each block as a dict."""
    pd = pytest.importorskip("pandas")
    columns = ["start_utc", "stop_utc", "hwp_dir", "rotation", "az_min", "az_max", "el", "speed",
               "accel", "priority", "type", "pass", "sub", "uid", "patch"]  # fmt: skip

    def escape(text):
        for char, escaped in {"'": "\\'", '"': '\\"'}.items():
            text = text.replace(char, escaped)
        return text

    def str2datetime(text):
        ctime = (pd.Timestamp(text).tz_localize(None) - pd.Timestamp("1970-01-01")) // pd.Timedelta(
            "1s"
        )
        return datetime.fromtimestamp(int(ctime), tz=timezone.utc)

    with open(path) as f:
        for i, line in enumerate(f):  # noqa: B007 (i counts the comment lines, as schedlib)
            if not line.startswith("#"):
                break
    df = pd.read_csv(path, skiprows=i, delimiter="|", names=columns, comment="#")
    blocks = []
    for _, row in df.iterrows():
        block = dict(
            name=escape(row["patch"].strip()),
            t0=str2datetime(row["start_utc"]),
            t1=str2datetime(row["stop_utc"]),
            alt=row["el"],
            az=row["az_min"],
            boresight_angle=row["rotation"],
            hwp_dir=bool(row["hwp_dir"] == 1),
        )
        if escape(row["type"].strip()) != "None":
            block.update(
                kind="scan",
                az_speed=row["speed"],
                az_accel=row["accel"],
                throw=np.abs(row["az_max"] - row["az_min"]),
                priority=row["priority"],
                tag=escape(row["uid"].strip()),
            )
        else:
            block.update(kind="noobs", priority=20)
        blocks.append(block)
    return blocks


def boresight_blocks(schedule):
    """The same dicts from boresight's reading: its CESs and idle blocks in time order."""

    def utc(seconds):
        return datetime.fromtimestamp(seconds, tz=timezone.utc)

    blocks = []
    for c in schedule.ces:
        labels = dict(c.labels)
        blocks.append(
            dict(
                name=c.name,
                t0=utc(c.start_unix),
                t1=utc(c.start_unix + c.duration_s),
                alt=c.elevation_deg,
                az=c.az_centre_deg - c.az_throw_deg / 2,
                boresight_angle=c.boresight_deg,
                hwp_dir=c.hwp_dir == 1,
                kind="scan",
                az_speed=c.speed_deg_s,
                az_accel=2 * c.speed_deg_s / c.turnaround_s,
                throw=c.az_throw_deg,
                priority=float(labels["priority"]),
                tag=labels["uid"],
            )
        )
    for b in schedule.idle:
        f = dict(b.fields)
        blocks.append(
            dict(
                name=f["patch"],
                t0=utc(b.start_unix),
                t1=utc(b.stop_unix),
                alt=float(f["el"]),
                az=float(f["az_min"]),
                boresight_angle=float(f["rotation"]),
                hwp_dir=float(f["hwp_dir"]) == 1,
                kind="noobs",
                priority=20,
            )
        )
    return sorted(blocks, key=lambda b: b["t0"])


def assert_same_blocks(ours, theirs):
    assert len(ours) == len(theirs)
    for a, b in zip(ours, theirs):
        assert a.keys() == b.keys()
        for key in a:
            if isinstance(a[key], float):
                assert a[key] == pytest.approx(float(b[key]), rel=1e-12, abs=1e-12), key
            else:
                assert a[key] == b[key], key


def test_fixture_read_as_schedlib_reads_it():
    schedule = load_schedule(FIXTURE)
    assert schedule_format(FIXTURE) == "so-master"
    assert len(schedule.ces) == 6 and len(schedule.idle) == 1
    theirs = schedlib_blocks(FIXTURE)
    assert [b["kind"] for b in theirs].count("noobs") == 1
    assert_same_blocks(boresight_blocks(schedule), theirs)
    # the fields a design prices: the plate's direction and the angles, as written
    assert [c.hwp_dir for c in schedule.ces] == [1, 1, 1, 0, 0, 1]
    assert [c.boresight_deg for c in schedule.ces] == [0, 0, 45, 45, -45, -45]
    assert schedule.ces[-1].az_throw_deg == 30 and schedule.ces[-1].turnaround_s == 4.0


def test_round_trip_keeps_every_field(tmp_path):
    first = load_schedule(FIXTURE)
    out = tmp_path / "again.txt"
    write_schedule(first, out, "so-master")
    second = load_schedule(out)
    assert second.ces == first.ces  # every CES field and label equal
    assert second.idle == first.idle
    assert second.site == first.site
    third = tmp_path / "third.txt"
    write_schedule(second, third, "so-master")
    assert third.read_text() == out.read_text()
    assert_same_blocks(boresight_blocks(second), schedlib_blocks(out))  # schedlib reads ours


def test_written_from_another_format_is_read_by_schedlib(tmp_path):
    """A TOML-made schedule gets schedlib's labels (a text uid, type "cmb") and its acceleration
    from the turnaround time; schedlib reads the file to the same blocks."""
    ces = tuple(
        CES(start_unix=1.8e9 + 3600 * i, duration_s=3000.0, elevation_deg=50.0,
            az_centre_deg=120.0 + i, az_throw_deg=40.0, speed_deg_s=0.75, boresight_deg=15.0 * i,
            turnaround_s=3.0, hwp_dir=i % 2)
        for i in range(4)
    )  # fmt: skip
    out = tmp_path / "from_toml.txt"
    write_schedule(Schedule(ces), out, "so-master")
    back = load_schedule(out)
    assert [c.labels for c in back.ces][0] == (
        ("priority", "1"),
        ("type", "cmb"),
        ("uid", "boresight-000000"),
    )
    assert [replace(c, labels=()) for c in back.ces] == list(ces)
    assert_same_blocks(boresight_blocks(back), schedlib_blocks(out))


def test_what_it_cannot_write(tmp_path):
    ces = CES(1.8e9, 3000.0, 50.0, 120.0, 40.0, turnaround_s=2.0)
    with pytest.raises(ScheduleError, match="overlap.*repeat_boresight_deg"):
        master.write(Schedule((ces,), repeat_boresight_deg=(0.0, 90.0)), tmp_path / "r.txt")
    with pytest.raises(ScheduleError, match="turnaround_s = 0"):
        master.write(Schedule((replace(ces, turnaround_s=0.0),)), tmp_path / "t.txt")
    with pytest.raises(ScheduleError, match="column uid: '123'"):
        master.write(Schedule((replace(ces, labels=(("uid", "123"),)),)), tmp_path / "u.txt")
    assert not list(tmp_path.iterdir())  # nothing half-written


def _bad(tmp_path, line_no, old, new):
    lines = FIXTURE.read_text().splitlines()
    assert old in lines[line_no - 1]
    lines[line_no - 1] = lines[line_no - 1].replace(old, new, 1)
    path = tmp_path / "bad.txt"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.mark.parametrize(
    "line, old, new, message",
    [
        (5, "| south", "| south | extra", "line 5: 16 columns; a master schedule row has 15"),
        (5, " 1 |   0.00", " 2 |   0.00", "line 5, column hwp_dir: '2'; 1 .forward. or 0"),
        (5, "110.00 | 150.00", "110.00 | 100.00", "line 5, column az_max: 100.00 is below"),
        (5, "| 50.00 |", "| high |", "line 5, column el: 'high' is not a number"),
        (5, "2027-07-01 01:55:00", "2027-07-01 00:58:00", "line 5: stop_utc .* not after"),
        (6, "2027-07-01 02:00:00", "2027-07-01 01:30:00", "line 6: start_utc .* before .* line 5"),
        (6, "02:00:00 | 2027-07-01 02:55:00", "02:00:00 | 2027-07-01 02:5x:00", "column stop_utc"),
        (6, "uid-7f3c2a03", "4403", "line 6, column uid: '4403'; schedlib reads it as text"),
        (6, "| 0 | 2 |", "| 0 | 2.5 |", "line 6, column sub: '2.5' is not an integer"),
    ],
)
def test_bad_rows_named(tmp_path, line, old, new, message):
    path = _bad(tmp_path, line, old, new)
    with pytest.raises(ScheduleError, match=message) as err:
        load_schedule(path)
    assert path in str(err.value)


def test_told_apart_from_toast(tmp_path):
    """A master schedule is not a TOAST one, though both start with comments; TOAST's reader,
    called on it, says what it is."""
    assert master.is_master_schedule(FIXTURE)
    ces = (CES(1.8e9, 3000.0, 50.0, 120.0, 40.0, turnaround_s=2.0),)
    path = tmp_path / "toast.txt"
    toast.write(Schedule(ces), path)
    assert not master.is_master_schedule(path) and schedule_format(path) == "toast"
    with pytest.raises(ScheduleError, match="15 fields is SO's master schedule"):
        toast.read(FIXTURE)


def test_export_schedule_to_master(tmp_path):
    out = tmp_path / "master.txt"
    assert (
        cli.main(["-q", "export-schedule", str(FIXTURE), "--out", str(out), "--to", "so-master"])
        == 0
    )
    assert load_schedule(out).ces == load_schedule(FIXTURE).ces
