"""The ground filter against TOAST 3's own GroundFilter operator on TOAST's own ground
simulation (its azimuths, throws and flags), and against what a projection must satisfy."""

import numpy as np
import pytest

from boresight.mitigation import azimuth_phase, ground_filter, ground_templates

CASES = {
    "legendre": dict(filter_order=5, trend_order=5),
    "split": dict(filter_order=3, trend_order=2, split_template=True),
    "detrend": dict(filter_order=4, trend_order=3, detrend=True),
    "bins": dict(filter_order=None, trend_order=3, bin_width_deg=2.0),
    "bins split": dict(filter_order=None, trend_order=None, bin_width_deg=3.0, split_template=True),
}


@pytest.fixture(scope="module")
def toast_ground():
    """TOAST's ground simulation (turnarounds flagged), its streams random plus a drift and a
    signal synchronous with azimuth; a fresh copy per case."""
    units = pytest.importorskip("astropy.units")
    pytest.importorskip("toast")
    from toast.observation import default_values as defaults
    from toast.tests.helpers.ground import create_ground_data

    def make():
        data = create_ground_data(
            None, schedule_hours=1, sample_rate=10.0 * units.Hz, turnarounds_invalid=True
        )
        rng = np.random.default_rng(8)
        for ob in data.obs:
            az = np.asarray(ob.shared[defaults.azimuth])
            for det in ob.local_detectors:
                drift = np.linspace(0, 20, ob.n_local_samples)
                ob.detdata[defaults.det_data][det] = (
                    rng.normal(size=az.size) + drift + 30 * np.cos(3 * az)
                )
        return data

    return make


@pytest.mark.parametrize("case", list(CASES))
def test_it_equals_toasts_groundfilter_on_toasts_ces(toast_ground, case):
    """Each CES of TOAST's simulation, each detector: TOAST's GroundFilter in place against
    boresight on a copy with the same azimuth, throws and flags, to 1e-10 of the streams' rms."""
    units = pytest.importorskip("astropy.units")
    from toast import ops
    from toast.observation import default_values as defaults

    options = dict(CASES[case])
    width = options.pop("bin_width_deg", None)
    data = toast_ground()
    before, inputs = {}, {}
    for ob in data.obs:
        n = ob.n_local_samples
        shared = (np.asarray(ob.shared[defaults.shared_flags]) & defaults.shared_mask_invalid) != 0
        split = []
        for name in (defaults.throw_leftright_interval, defaults.throw_rightleft_interval):
            mask = np.zeros(n, dtype=bool)
            for ival in ob.intervals[name]:
                mask[ival.first : ival.last] = True
            split.append(mask)
        for det in ob.local_detectors:
            own = (ob.detdata[defaults.det_flags][det] & defaults.det_mask_invalid) != 0
            before[ob.name, det] = np.array(ob.detdata[defaults.det_data][det])
            inputs[ob.name, det] = (np.asarray(ob.shared[defaults.azimuth]), shared | own, split)
    ops.GroundFilter(
        shared_flag_mask=defaults.shared_mask_invalid,
        det_flag_mask=defaults.det_mask_invalid,
        det_mask=0,
        bin_width=None if width is None else width * units.deg,
        **options,
    ).apply(data)
    checked = 0
    for ob in data.obs:
        for det in ob.local_detectors:
            az, flags, split = inputs[ob.name, det]
            want = np.asarray(ob.detdata[defaults.det_data][det])
            got = ground_filter(
                before[ob.name, det],
                az=az,
                filter_order=options["filter_order"],
                bin_width_rad=None if width is None else np.radians(width),
                trend_order=options["trend_order"],
                detrend=options.get("detrend", False),
                split=split if options.get("split_template") else None,
                flags=flags,
            )
            assert np.max(np.abs(got - want)) < 1e-10 * np.std(want)
            checked += 1
    assert checked > 10
    if options.get("detrend"):  # the last detector's azimuth-synchronous part and drift: gone
        ground = np.cos(3 * az)
        assert abs(np.corrcoef(before[ob.name, det], ground)[0, 1]) > 0.5
        assert abs(np.corrcoef(want, ground)[0, 1]) < 0.05 and np.std(want) < 1.2


def test_a_template_in_the_span_is_removed_and_the_trend_kept():
    rng = np.random.default_rng(1)
    n = 2000
    az = np.radians(40 + 10 * np.sin(np.linspace(0, 30 * np.pi, n)))
    p = azimuth_phase(az)
    ground = 3 + 2 * p - 0.5 * (1.5 * p**2 - 0.5)
    trend = np.linspace(-1, 1, n, endpoint=False)
    out = ground_filter(ground + 4 * trend, az=az, filter_order=2, trend_order=1)
    assert np.max(np.abs(out - 4 * trend)) < 1e-10  # the trend is fitted, not subtracted
    out = ground_filter(ground + 4 * trend, az=az, filter_order=2, trend_order=1, detrend=True)
    assert np.max(np.abs(out)) < 1e-10
    flags = rng.random(n) < 0.3
    noisy = rng.normal(size=n)
    once = ground_filter(noisy, az=az, filter_order=3, trend_order=None, flags=flags)
    twice = ground_filter(once, az=az, filter_order=3, trend_order=None, flags=flags)
    assert np.max(np.abs(twice - once)) < 1e-12  # a projection
    templates, n_trend = ground_templates(az, filter_order=3, trend_order=None)
    assert n_trend == 0 and np.max(np.abs(templates[:, ~flags] @ once[~flags])) < 1e-9


def test_the_phase_unwraps_azimuths_across_zero_and_round():
    az = np.radians(np.array([-10.0, 0.0, 10.0]))
    np.testing.assert_allclose(azimuth_phase(az), [-1, 0, 1], atol=1e-15)
    full = np.radians(np.array([-170.0, 0.0, 200.0]))  # more than a turn: taken modulo 2 pi
    np.testing.assert_allclose(azimuth_phase(full), np.radians([190.0, 0.0, 200.0]) / np.pi - 1)


@pytest.mark.parametrize(
    ("options", "match"),
    [
        (dict(filter_order=None), "one of them"),
        (dict(filter_order=3, bin_width_rad=0.1), "one of them"),
        (dict(filter_order=None, bin_width_rad=0.0), "bin_width_rad"),
        (dict(filter_order=3, split=(np.ones(5, bool),)), "split"),
        (dict(filter_order=3, flags=np.zeros(4, bool)), "flags"),
    ],
)
def test_bad_input_is_refused(options, match):
    with pytest.raises(ValueError, match=match):
        ground_filter(np.zeros(10), az=np.linspace(0, 1, 10), **options)
