"""The polynomial filter against TOAST 3's own PolyFilter operator on TOAST's own ground
simulation (its throws, its flags), and against what a projection must satisfy."""

import numpy as np
import pytest

from boresight.mitigation import legendre_templates, poly_filter


def test_it_equals_toasts_polyfilter_on_toasts_throws_and_flags():
    """TOAST builds a ground observation (SimGround's throws, its flagged samples and
    detectors); its PolyFilter(view="throw") filters random streams in place; boresight filters
    copies with the same intervals and flags: equal to 1e-10 of the streams' rms."""
    astropy_units = pytest.importorskip("astropy.units")
    pytest.importorskip("toast")
    from toast import ops
    from toast.observation import default_values as defaults
    from toast.tests.helpers.ground import create_ground_data

    data = create_ground_data(
        None, schedule_hours=1, sample_rate=10.0 * astropy_units.Hz, turnarounds_invalid=True
    )
    rng = np.random.default_rng(5)
    copies = {}
    for ob in data.obs:
        for det in ob.local_detectors:
            signal = rng.normal(size=ob.n_local_samples) + np.linspace(0, 50, ob.n_local_samples)
            ob.detdata[defaults.det_data][det] = signal
            copies[ob.name, det] = signal.copy()
    flag_bits = dict(
        det_flag_mask=defaults.det_mask_invalid,
        shared_flag_mask=defaults.shared_mask_invalid,
    )
    flagged = {}
    for ob in data.obs:  # what PolyFilter leaves out of each detector's fit
        shared = (np.asarray(ob.shared[defaults.shared_flags]) & flag_bits["shared_flag_mask"]) != 0
        for det in ob.local_detectors:
            own = (ob.detdata[defaults.det_flags][det] & flag_bits["det_flag_mask"]) != 0
            flagged[ob.name, det] = shared | own
    ops.PolyFilter(order=3, view="throw", det_mask=0, **flag_bits).apply(data)
    checked = 0
    for ob in data.obs:
        # half-open, as the compiled kernel the operator runs by default reads them (TOAST's
        # numpy kernel reads last as inclusive and differs from it by up to 5 sigma at the
        # throws' ends)
        throws = np.array([(i.first, i.last) for i in ob.intervals["throw"]])
        assert len(throws) > 20
        for det in ob.local_detectors:
            want = np.asarray(ob.detdata[defaults.det_data][det])
            got = poly_filter(
                copies[ob.name, det], order=3, intervals=throws, flags=flagged[ob.name, det]
            )
            assert np.max(np.abs(got - want)) < 1e-10 * np.std(want)
            checked += 1
    assert checked > 10 and any(f.any() for f in flagged.values())


def test_a_polynomial_up_to_the_order_is_removed_and_the_rest_is_orthogonal():
    rng = np.random.default_rng(2)
    n, order = 500, 3
    x = np.linspace(-3, 7, n)
    poly = 2.0 - 0.5 * x + 0.1 * x**2 - 0.01 * x**3
    assert np.max(np.abs(poly_filter(poly, order=order, intervals=[[0, n]]))) < 1e-11
    noise = rng.normal(size=n)
    flags = rng.random(n) < 0.2
    out = poly_filter(noise + poly, order=order, intervals=[[0, n]], flags=flags)
    templates = legendre_templates(n, order)
    assert np.max(np.abs(templates[~flags].T @ out[~flags])) < 1e-10  # normal equations hold
    again = poly_filter(out, order=order, intervals=[[0, n]], flags=flags)
    assert np.max(np.abs(again - out)) < 1e-12  # a projection: twice is once


def test_intervals_are_independent_and_what_lies_outside_is_untouched():
    rng = np.random.default_rng(3)
    signal = rng.normal(size=(2, 300))
    out = poly_filter(signal, order=1, intervals=[[10, 100], [120, 300]])
    np.testing.assert_array_equal(out[:, :10], signal[:, :10])
    np.testing.assert_array_equal(out[:, 100:120], signal[:, 100:120])
    alone = poly_filter(signal[:, 10:100], order=1, intervals=[[0, 90]])
    assert np.max(np.abs(out[:, 10:100] - alone)) < 1e-13
    flags = np.zeros(300, dtype=bool)
    flags[10:100] = True  # nothing to fit: left whole
    np.testing.assert_array_equal(
        poly_filter(signal, order=1, intervals=[[10, 100]], flags=flags), signal
    )


def test_legendre_templates_are_legendres_at_the_samples_centres():
    n = 7
    x = -1 + (2 * np.arange(n) + 1) / n
    want = np.polynomial.legendre.legvander(x, 4)
    assert np.max(np.abs(legendre_templates(n, 4) - want)) < 1e-14


@pytest.mark.parametrize(
    ("intervals", "flags", "order", "match"),
    [
        ([[0, 20]], None, 1, "intervals"),
        ([[5, 5]], None, 1, "intervals"),
        ([[0, 6], [5, 9]], None, 1, "intervals"),
        ([[0, 5]], np.zeros(4, dtype=bool), 1, "flags"),
        ([[0, 5]], None, -1, "order"),
    ],
)
def test_bad_input_is_refused(intervals, flags, order, match):
    with pytest.raises(ValueError, match=match):
        poly_filter(np.zeros(10), order=order, intervals=intervals, flags=flags)
