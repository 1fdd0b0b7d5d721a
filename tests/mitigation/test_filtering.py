"""A pipeline's filtering as data: its text, a CES's throws, and the refusals."""

import numpy as np
import pytest
from helpers import T0

from boresight.mitigation import CesScan, Deprojection, Filtering
from boresight.schedule import CES, Schedule, Site


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("p3", Filtering(poly_order=3)),
        ("p3+ground", Filtering(poly_order=3, ground_order=5)),
        ("ground2-split+p1", Filtering(poly_order=1, ground_order=2, ground_split=True)),
        ("groundbin0.5-split", Filtering(ground_bin_deg=0.5, ground_split=True)),
        ("none", Filtering()),
        (
            "p3+deproject(gain,pointing)",
            Filtering(poly_order=3, deprojection=Deprojection(("gain", "pointing"))),
        ),
        (
            "deproject(ellipticity+gain)",
            Filtering(deprojection=Deprojection(("gain", "ellipticity"))),
        ),
        ("deproject(bk)+ground", Filtering(ground_order=5, deprojection=Deprojection.parse("bk"))),
    ],
)
def test_a_filtering_reads_and_writes_its_text(text, expected):
    assert Filtering.parse(text) == expected
    assert Filtering.parse(str(expected)) == expected
    assert bool(expected) == (text != "none")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("p", "filter part"),
        ("p3+p1", "two poly parts"),
        ("ground+groundbin1", "two ground parts"),
        ("p3-split", "only a ground part"),
        ("groundbin0", "must be > 0"),
        ("p-1", "filter part"),
        ("p65", "poly_order"),
        ("deproject(gain)+deproject(width)", "two deproject parts"),
        ("deproject(gains)", "choose from gain, pointing"),
        ("deproject(gain,gain)", "one of them twice"),
    ],
)
def test_a_bad_filtering_is_refused_with_what_to_write(text, match):
    with pytest.raises(ValueError, match=match):
        Filtering.parse(text)


def test_a_split_without_a_ground_template_or_both_templates_are_refused():
    with pytest.raises(ValueError, match="needs a ground template"):
        Filtering(poly_order=1, ground_split=True)
    with pytest.raises(ValueError, match="not both"):
        Filtering(ground_order=3, ground_bin_deg=1.0)


def _schedule(turnaround_s=2.0, throw=20.0):
    ces = (CES(T0, 120.0, 50.0, -10.0, throw, turnaround_s=turnaround_s),)
    return Schedule(ces, Site(), 10.0)


@pytest.mark.parametrize("turnaround_s", [0.0, 2.0])
def test_a_ces_throws_meet_mid_turnaround_and_alternate_in_direction(turnaround_s):
    """TOAST's throws: a scan and half of each turnaround beside it; the first goes towards
    larger azimuth; every scan sample of a throw moves the way the throw says."""
    schedule = _schedule(turnaround_s)
    scan = CesScan.of(schedule.ces[0], schedule)
    starts, stops = scan.throws.T
    assert starts[0] == 0 and stops[-1] == scan.az.size and np.array_equal(starts[1:], stops[:-1])
    period = (20.0 + turnaround_s) * 10  # samples from one reversal to the next
    assert starts[1] == (20.0 + turnaround_s / 2) * 10  # the first throw has no turnaround before
    assert np.all(np.diff(starts[1:]) == period)
    if turnaround_s:  # each boundary halves a turnaround
        for b in starts[1:]:
            assert scan.turning[b - 10 : b + 10].all() and not scan.turning[b - 11]
    for j, (a, b) in enumerate(scan.throws):
        moving = np.diff(scan.az[a:b][~scan.turning[a:b]])
        assert np.all(moving > 0) if j % 2 == 0 else np.all(moving < 0)
        assert np.all(scan.direction[a:b] == (j % 2 == 0))


def test_a_ces_that_does_not_scan_is_refused():
    with pytest.raises(ValueError, match="does not scan"):
        CesScan.of(_schedule(throw=0.0).ces[0], _schedule(throw=0.0))
