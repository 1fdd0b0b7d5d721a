"""Filters and templates applied CES by CES before binning: the maps equal the TOD filtered and
regressed by hand, then binned; they do not depend on the chunks; what a schedule cannot take is
refused before any work."""

from dataclasses import replace

import healpy as hp
import numpy as np
import pytest
from helpers import T0

from boresight import engine, pointing
from boresight.instrument import focalplane
from boresight.instrument.hwp import HWP
from boresight.instrument.pairs import Instrument, Systematics
from boresight.mitigation import CesScan, Filtering
from boresight.schedule import CES, Schedule, Site


def _filtered_schedule(turnarounds="include"):
    """Two 5-minute CESs at 10 Hz over 20 deg throws, turning around in 2 s, seen twice."""
    ces = tuple(
        CES(T0 + start, 300.0, 50.0, centre, 20.0, turnaround_s=2.0)
        for start, centre in ((0.0, 150.0), (900.0, 210.0))
    )
    return Schedule(ces, Site(), 10.0, repeat_boresight_deg=(0.0, 45.0), turnarounds=turnarounds)


@pytest.mark.parametrize("turnarounds", ["include", "exclude"])
@pytest.mark.parametrize(
    "text",
    [
        "p3",
        "p1+ground3-split",
        "groundbin2",
        "deproject(gain)",
        "p1+deproject(gain)",
        "p1+deproject(gain/1h)",
    ],
)
@pytest.mark.parametrize("where", ["boresight", "hexagon:7:10"])
def test_filtered_maps_are_the_tod_filtered_by_hand_and_binned(plain_sky, turnarounds, text, where):
    """An independent route: each pair difference written from the sky's maps in the samples'
    pixels, filtered CES by CES with the filters themselves, the T map in the samples' pixels
    (filtered alike) regressed from it with numpy's least squares off the turnarounds per CES or
    over both CESs (a block of an hour), binned with bincount, solved with numpy; the pairs on the boresight (simulate_schedule) or each at its
    place in a focal plane (simulate_focalplane)."""
    schedule, filtering = _filtered_schedule(turnarounds), Filtering.parse(text)
    dg = 0.01
    run = dict(evaluation="pixel", filtering=filtering)
    if where == "boresight":
        angles = np.radians([0.0, 45.0])
        maps = engine.simulate_schedule(
            plain_sky, schedule, Instrument(pair_angles_deg=(0.0, 45.0)), Systematics(dg=dg), **run
        )
    else:
        plane = focalplane.load_focalplane(where)
        angles = np.radians(plane.pair_angles_deg)
        maps = engine.simulate_focalplane(plain_sky, schedule, plane, Systematics(dg=dg), **run)
    npix = 12 * plain_sky.nside**2
    normal = np.zeros((5, npix))
    i_map, q_map, u_map = plain_sky.maps
    # the deprojection's blocks: each CES, or (a "/1h" block) both CESs, 15 minutes apart
    blocks = [m for _, m in filtering.deprojection.blocks(schedule.ces)]
    for repeat in schedule.repeat_boresight_deg:
        for block in blocks:
            held = []  # per CES: pix, c, s, filtered d and template, fit and keep masks
            for ces in (schedule.ces[k] for k in block):
                one = replace(
                    schedule, ces=(ces,), repeat_boresight_deg=(repeat,), turnarounds="include"
                )
                if where == "boresight":
                    theta, phi, psi = (
                        np.concatenate(x)[None] for x in zip(*pointing.pointing(one))
                    )
                else:
                    chunks = pointing.detector_pointing(one, plane)
                    theta, phi, psi = (np.concatenate(x, axis=1) for x in zip(*chunks))
                pix = hp.ang2pix(plain_sky.nside, theta, phi)  # (1 or pairs, H)
                c = np.cos(2 * (psi[:, None, :] + angles[None, :, None]))
                s = np.sin(2 * (psi[:, None, :] + angles[None, :, None]))
                if where != "boresight":  # pair m at its own place: its own samples alone
                    c, s = (np.einsum("mmh->mh", x)[:, None, :] for x in (c, s))
                i, q, u = (m[pix][:, None, :] for m in (i_map, q_map, u_map))
                d = 0.5 * (i + q * c + u * s - (1 - dg) * (i - q * c - u * s))
                scan = CesScan.of(ces, schedule)
                keep = ~scan.turning if turnarounds == "exclude" else np.ones(pix.shape[1], bool)
                rows = []
                for row in range(pix.shape[0]):
                    dr = filtering.apply(d[row], scan) if filtering.filters else d[row]
                    x = i_map[pix[row]][None]
                    x = filtering.apply(x, scan) if filtering.filters else x
                    rows.append((pix[row], c[row], s[row], dr, x))
                held.append((rows, ~scan.turning, keep))
            for row in range(len(held[0][0])):
                pix_r, c_r, s_r, dr, x = (
                    np.concatenate([h[0][row][k] for h in held], axis=-1) for k in range(5)
                )
                fit = np.concatenate([h[1] for h in held])
                keep = np.concatenate([h[2] for h in held])
                if filtering.deprojection:  # the T map in the samples' pixels, over the block
                    coefficients = np.linalg.lstsq(x[:, fit].T, dr[:, fit].T, rcond=None)[0]
                    dr = dr - coefficients.T @ x
                for j, term in enumerate((c_r**2, c_r * s_r, s_r**2)):
                    normal[j] += np.bincount(pix_r[keep], term[:, keep].sum(axis=0), npix)
                for j, term in ((3, c_r * dr), (4, s_r * dr)):
                    normal[j] += np.bincount(pix_r[keep], term[:, keep].sum(axis=0), npix)
    seen = maps.pixels
    a11, a12, a22, b1, b2 = normal[:, seen]
    det = a11 * a22 - a12**2
    q_ref, u_ref = (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det
    assert seen.size > 10 and np.array_equal(seen, np.flatnonzero(normal[0] + normal[2]))
    scale = np.max(np.abs(q_ref))
    assert np.max(np.abs(maps.q_obs - q_ref)) < 1e-10 * scale
    assert np.max(np.abs(maps.u_obs - u_ref)) < 1e-10 * scale


@pytest.mark.parametrize("text", ["p3", "p1+ground3-split", "groundbin2"])
@pytest.mark.parametrize("where", ["boresight", "hexagon:7:10"])
def test_the_detectors_map_maker_bins_each_detectors_filtered_tod(plain_sky, text, where):
    """mapmaker="detectors" with filters: each detector's own samples written from the sky's maps
    in the samples' pixels (A at (1, c, s), B at (1, -c, -s) with its gain error), filtered CES by
    CES, binned into each pixel's 3x3 system with bincount and solved with numpy, give I, Q and
    U; the filters being linear, Q and U are the filtered pair differences' to rounding."""
    schedule, filtering = _filtered_schedule("exclude"), Filtering.parse(text)
    dg = 0.01
    run = dict(evaluation="pixel", filtering=filtering)
    if where == "boresight":
        angles = np.radians([0.0, 45.0])
        simulate = lambda **kw: engine.simulate_schedule(  # noqa: E731
            plain_sky, schedule, Instrument(pair_angles_deg=(0.0, 45.0)), Systematics(dg=dg),
            **run, **kw,
        )  # fmt: skip
    else:
        plane = focalplane.load_focalplane(where)
        angles = np.radians(plane.pair_angles_deg)
        simulate = lambda **kw: engine.simulate_focalplane(  # noqa: E731
            plain_sky, schedule, plane, Systematics(dg=dg), **run, **kw
        )
    maps, pairs = simulate(mapmaker="detectors"), simulate()
    npix = 12 * plain_sky.nside**2
    normal = np.zeros((3, 4, npix))  # rows (1, c, s) x columns (1, c, s, d)
    i_map, q_map, u_map = plain_sky.maps
    for repeat in schedule.repeat_boresight_deg:
        for ces in schedule.ces:
            one = replace(
                schedule, ces=(ces,), repeat_boresight_deg=(repeat,), turnarounds="include"
            )
            if where == "boresight":
                theta, phi, psi = (np.concatenate(x)[None] for x in zip(*pointing.pointing(one)))
            else:
                chunks = pointing.detector_pointing(one, plane)
                theta, phi, psi = (np.concatenate(x, axis=1) for x in zip(*chunks))
            pix = hp.ang2pix(plain_sky.nside, theta, phi)
            c = np.cos(2 * (psi[:, None, :] + angles[None, :, None]))
            s = np.sin(2 * (psi[:, None, :] + angles[None, :, None]))
            if where != "boresight":
                c, s = (np.einsum("mmh->mh", x)[:, None, :] for x in (c, s))
            i, q, u = (m[pix][:, None, :] for m in (i_map, q_map, u_map))
            scan = CesScan.of(ces, schedule)
            keep = ~scan.turning
            for sign, gain in ((1.0, 1.0), (-1.0, 1.0 - dg)):  # detector A, then B
                d = gain * (i + sign * (q * c + u * s))
                for row in range(pix.shape[0]):
                    dr = filtering.apply(d[row], scan)
                    w = (np.ones_like(c[row]), sign * c[row], sign * s[row])
                    for a in range(3):
                        for b, term in enumerate((*w, dr)):
                            x = (w[a] * term)[:, keep].sum(axis=0)
                            normal[a, b] += np.bincount(pix[row][keep], x, npix)
    seen = maps.pixels
    iqu = np.linalg.solve(np.moveaxis(normal[:, :3, seen], 2, 0), normal[:, 3, seen].T[..., None])
    scale = np.max(np.abs(iqu[:, 1:]))
    for k, got in enumerate((maps.i_obs, maps.q_obs, maps.u_obs)):
        assert np.max(np.abs(got - iqu[:, k, 0])) < 1e-10 * np.max(np.abs(iqu[:, k])), k
    assert np.array_equal(pairs.pixels, seen) and np.array_equal(pairs.hits_obs, maps.hits_obs)
    assert np.max(np.abs(maps.q_obs - pairs.q_obs)) < 1e-10 * scale
    assert np.max(np.abs(maps.u_obs - pairs.u_obs)) < 1e-10 * scale
    assert np.allclose(maps.i_at(seen), maps.i_obs) and np.all(
        maps.i_at([0]) == 0
    )  # the north pole
    with pytest.raises(ValueError, match="do not see I"):
        pairs.i_at(seen)


def test_a_filtered_focal_plane_on_the_axis_is_the_filtered_boresight(plain_sky):
    """The paper's two pairs as a focal plane on the axis, filtered: the boresight's maps."""
    schedule, filtering = _filtered_schedule(), Filtering.parse("p3+ground-split")
    systematics = Systematics(dg=(0.01, -0.01), rho_arcmin=2.0, chi_deg=30.0)
    axis = engine.simulate_schedule(
        plain_sky, schedule, Instrument(), systematics, filtering=filtering
    )
    plane = engine.simulate_focalplane(
        plain_sky, schedule, focalplane.on_axis((0.0, 45.0)), systematics, filtering=filtering
    )
    assert np.array_equal(axis.pixels, plane.pixels)
    scale = np.max(np.abs(axis.q_obs))
    assert np.max(np.abs(plane.q_obs - axis.q_obs)) < 1e-10 * scale
    assert np.max(np.abs(plane.u_obs - axis.u_obs)) < 1e-10 * scale


def test_a_filter_of_order_0_removes_a_constant_leak_and_keeps_the_rest(plain_sky):
    """A constant additive leak is a constant in every pair difference: the mean per throw takes
    all of it, and, the filter being linear, nothing else changes."""
    schedule, ones = _filtered_schedule(), np.ones(12 * plain_sky.nside**2)
    instrument = Instrument(pair_angles_deg=(0.0, 45.0))

    def maps(leak, text):
        return engine.simulate_schedule(
            plain_sky,
            schedule,
            instrument,
            Systematics(dg=0.01, leak=leak),
            leak_template=ones,
            filtering=Filtering.parse(text),
        )

    raw, leaked = maps(0.0, "none"), maps(0.02, "none")
    assert np.max(np.abs(leaked.q_obs - raw.q_obs)) > 1e-3  # the leak is there unfiltered
    clean, filtered = maps(0.0, "p0"), maps(0.02, "p0")
    scale = np.max(np.abs(clean.q_obs))
    assert np.max(np.abs(filtered.q_obs - clean.q_obs)) < 1e-12 * scale
    assert np.max(np.abs(filtered.u_obs - clean.u_obs)) < 1e-12 * scale


@pytest.mark.parametrize("where", ["boresight", "hexagon:7:10"])
def test_the_bk_templates_take_constant_gains_and_offsets_on_a_t_only_sky(plain_sky, where):
    """T alone, gains and pointing offsets constant per pair: the BK templates, regressed per
    CES from each pair's own stream, leave the leak's third order in rho (ell rho ~ 1e-2 here);
    the gain alone (its template exactly the leak) to rounding."""
    sky, schedule = plain_sky.without_polarisation(), _filtered_schedule()
    systematics = Systematics(dg=0.01, rho_arcmin=1.0, chi_deg=30.0)
    plane = focalplane.load_focalplane(where) if where != "boresight" else None

    def maps(text, systematics):
        run = dict(evaluation="exact", filtering=Filtering.parse(text))
        if plane is None:
            return engine.simulate_schedule(sky, schedule, Instrument(), systematics, **run)
        return engine.simulate_focalplane(sky, schedule, plane, systematics, **run)

    gains = Systematics(dg=0.01)
    size = np.max(np.abs(maps("none", gains).q_obs))
    assert size > 1e-2
    assert np.max(np.abs(maps("deproject(gain)", gains).q_obs)) < 1e-13 * size
    size = np.max(np.abs(maps("none", systematics).q_obs))
    left = maps("deproject(bk)", systematics)
    assert np.max(np.abs(left.q_obs)) < 1e-5 * size
    assert np.max(np.abs(left.u_obs)) < 1e-5 * size
    first_order = maps("deproject(gain,pointing)", systematics)
    assert np.max(np.abs(first_order.q_obs)) > 1e-4 * size  # the offset's second order


def test_filtered_maps_do_not_depend_on_the_chunks_or_threads(plain_sky):
    schedule, filtering = _filtered_schedule(), Filtering.parse("p3+ground")
    systematics = Systematics(dg=0.01, dg_jitter=0.001, rho_arcmin=1.0)
    a = engine.simulate_schedule(
        plain_sky, schedule, Instrument(), systematics, filtering=filtering
    )
    b = engine.simulate_schedule(
        plain_sky,
        schedule,
        Instrument(),
        systematics,
        filtering=filtering,
        chunk_samples=999,
        nthreads=1,
    )
    assert np.array_equal(a.q_obs, b.q_obs) and np.array_equal(a.u_obs, b.u_obs)


@pytest.mark.parametrize(
    ("text", "options", "match"),
    [
        ("p3", dict(backend="gpu"), "CPU backend"),
        ("p3", dict(mapmaker="single"), "pairs' or the detectors' map-maker"),
        ("p3", dict(mapmaker="pairs-spin0"), "pairs' or the detectors' map-maker"),
        ("deproject(gain)", dict(mapmaker="detectors"), "templates from the pair differences"),
        ("p3", dict(hwp=HWP("continuous", frequency_hz=1.0)), "no plate"),
        ("p40", dict(sample_rate_hz=1.0), "samples per throw"),
        ("groundbin30", {}, "wider than the scan"),
        ("deproject(pointing)", dict(evaluation="interp"), "evaluation 'exact'"),
        (
            "deproject(gain)",
            dict(sample_rate_hz=0.1, duration_s=10.0),
            "1 template per CES; a CES of this schedule has 1 samples",
        ),
    ],
)
def test_a_filter_the_schedule_cannot_take_is_refused_before_any_work(
    plain_sky, text, options, match
):
    schedule = _filtered_schedule()
    if "sample_rate_hz" in options:  # 20 samples a throw
        schedule = replace(schedule, sample_rate_hz=options.pop("sample_rate_hz"))
    if "duration_s" in options:  # one sample a CES
        duration = options.pop("duration_s")
        ces = tuple(replace(c, duration_s=duration) for c in schedule.ces)
        schedule = replace(schedule, ces=ces)
    with pytest.raises(ValueError, match=match):
        if "hwp" in options:  # a focal plane behind a plate
            plane = focalplane.on_axis()
            engine.simulate_focalplane(
                plain_sky, schedule, plane, filtering=Filtering.parse(text), **options
            )
        engine.simulate_schedule(plain_sky, schedule, filtering=Filtering.parse(text), **options)
