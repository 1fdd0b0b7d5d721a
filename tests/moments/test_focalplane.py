"""A focal plane's per-pair statistics: on the axis the boresight's, each pair's own pointing,
rotation off the axis, and blocks of pairs on Dask."""

import numpy as np
import pytest

from boresight import moments, pointing
from boresight.instrument import focalplane
from boresight.moments import focalplane as focalplane_moments


def _hexagon_schedule():
    from helpers import toast_schedule

    return toast_schedule()


def test_a_focal_plane_on_the_axis_is_the_boresight_scan():
    """Pairs on the axis: the combination is the boresight's h_n with n_pairs times its hits, the
    scattered weights are |h_n|^2 / n_pairs, and each pair's means are the boresight's."""
    schedule = _hexagon_schedule()
    alone = moments.characterise_schedule(schedule, 32)
    planes = moments.characterise_focalplane(schedule, focalplane.on_axis((0, 45, 90)), 32)
    np.testing.assert_array_equal(planes.combined.hits, 3 * alone.hits)
    assert np.max(np.abs(planes.combined.h - alone.h)) < 1e-13
    np.testing.assert_array_equal(planes.combined.n_distinct, alone.n_distinct)
    expected = np.abs(alone.h) ** 2 / 3
    assert np.max(np.abs(planes.scattered() - expected)) < 1e-13
    w = alone.hits.astype(float)
    for row in planes.pair_means():
        assert row["hits"] == alone.hits.sum()
        for n in range(1, 5):
            assert np.isclose(row[f"abs_h{n}_sq"], np.sum(w * np.abs(alone.h[n]) ** 2) / w.sum())


def test_focal_plane_stats_equal_binning_each_pairs_own_pointing(monkeypatch):
    """The fused kernels against the streamed route (detector_pointing, then characterise), pair
    by pair and combined; one pair per block (the memory bound) changes nothing."""
    schedule = _hexagon_schedule()
    fp = focalplane.hexagon(7, 30.0)
    planes = moments.characterise_focalplane(schedule, fp, 32, per_pair=True)
    chunks = [np.concatenate(x, axis=1) for x in zip(*pointing.detector_pointing(schedule, fp))]
    pairs = [moments.characterise([tuple(c[i] for c in chunks)], 32) for i in range(7)]
    joined = moments.characterise([tuple(c.ravel() for c in chunks)], 32)
    np.testing.assert_array_equal(planes.combined.hits, joined.hits)
    assert np.max(np.abs(planes.combined.h - joined.h)) < 1e-12
    sum_sq = sum(p.hits.astype(float) ** 2 * np.abs(p.h) ** 2 for p in pairs)
    np.testing.assert_allclose(planes.sum_sq, sum_sq, rtol=1e-12, atol=1e-9)
    for i, p in enumerate(pairs):
        np.testing.assert_array_equal(planes.pair_hits[i], p.hits)
        assert np.max(np.abs(planes.pair_h[i] - p.h)) < 1e-12
    monkeypatch.setattr("boresight.moments.focalplane.PAIR_BLOCK_BYTES", 1)
    assert len(moments.pair_blocks(7, 32)) == 7
    blocked = moments.characterise_focalplane(schedule, fp, 32)
    np.testing.assert_allclose(blocked.sum_sq, planes.sum_sq, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(blocked.pair_weights, planes.pair_weights, rtol=1e-12)


def test_rotation_cancels_h2_only_on_the_axis():
    """A 0/90 repeat of a schedule cancels h_2 exactly for the pair on the boresight; a pair
    17.5 deg off it lands elsewhere at 90 deg and keeps much of its h_2 (the issue's TOAST
    table: 0.48-0.67 of 0.87-0.99)."""
    schedule = _hexagon_schedule()
    fp = focalplane.hexagon(37, 35.0).subset([0, 19])  # on the axis, and at a vertex
    assert fp.radius_deg[1] == pytest.approx(17.5)
    fixed = moments.characterise_focalplane(schedule, fp, 64).pair_means()
    turned = moments.characterise_focalplane(schedule.repeated([0.0, 90.0]), fp, 64)
    turned = turned.pair_means()
    assert turned[0]["abs_h2_sq"] < 1e-20 < 0.5 < fixed[0]["abs_h2_sq"]
    assert turned[1]["abs_h2_sq"] > 0.3 * fixed[1]["abs_h2_sq"]


@pytest.mark.slow
def test_focal_plane_blocks_on_dask_give_the_serial_result_to_the_bit(monkeypatch):
    """Blocks of pairs over groups of CESs as tasks on a local Dask cluster, at most 4 in flight,
    add up in (block, group) order: the same result as in this process to the bit, whichever
    worker finishes first; the groups' sums are the whole schedule's to rounding."""
    pytest.importorskip("dask.distributed")
    schedule = _hexagon_schedule().repeated((0.0, 90.0))  # four CESs to cut
    fp = focalplane.hexagon(7, 30.0)
    whole = moments.characterise_focalplane(schedule, fp, 32, per_pair=True)
    monkeypatch.setattr(
        "boresight.moments.focalplane.PAIR_BLOCK_BYTES", 3 * 12 * 32**2 * 88
    )  # 3 pairs a block on the whole sky
    monkeypatch.setattr("boresight.moments.focalplane.observed_pixels", lambda *a: 12 * 32**2)
    monkeypatch.setattr("boresight.moments.focalplane.GROUP_SAMPLES", schedule.n_samples // 4)
    assert len(moments.pair_blocks(7, 32)) == 3
    groups = focalplane_moments.time_groups(schedule)
    assert len(groups) == 3 and sum(n for _, n in groups) == schedule.n_samples  # 1, 2 and 1 CES
    serial = moments.characterise_focalplane(schedule, fp, 32)
    dask = moments.characterise_focalplane(schedule, fp, 32, scheduler=None, workers=2)
    np.testing.assert_array_equal(dask.combined.hits, serial.combined.hits)
    np.testing.assert_array_equal(dask.combined.h, serial.combined.h)
    np.testing.assert_array_equal(dask.combined.n_distinct, serial.combined.n_distinct)
    np.testing.assert_array_equal(dask.sum_sq, serial.sum_sq)
    np.testing.assert_array_equal(dask.pair_weights, serial.pair_weights)
    np.testing.assert_array_equal(serial.combined.hits, whole.combined.hits)
    np.testing.assert_array_equal(serial.combined.n_distinct, whole.combined.n_distinct)
    assert np.max(np.abs(serial.combined.h - whole.combined.h)) < 1e-13
    np.testing.assert_allclose(serial.sum_sq, whole.sum_sq, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(serial.pair_weights, whole.pair_weights, rtol=1e-12, atol=1e-9)
    grouped = moments.characterise_focalplane(schedule, fp, 32, per_pair=True)
    np.testing.assert_array_equal(grouped.observed, whole.observed)
    np.testing.assert_array_equal(grouped.observed_pair_hits, whole.observed_pair_hits)
    assert np.max(np.abs(grouped.observed_pair_h - whole.observed_pair_h)) < 1e-13
