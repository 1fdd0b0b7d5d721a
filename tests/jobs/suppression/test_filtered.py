"""What boresight rotation buys a pipeline that filters before binning: the table end to end on a
short real schedule, its physics against the identities a linear filter keeps, and the command's
one clear errors."""

import csv
import json
import re

import numpy as np
import pytest
from helpers import T0

from boresight import noise
from boresight.cli import main
from boresight.cosmology import load_spectra
from boresight.instrument import focalplane
from boresight.jobs.suppression import filtered
from boresight.mitigation import Filtering
from boresight.schedule import load_schedule
from boresight.sky import SkyConfig, make_sky

NSIDE = 32
FILTER = "p1+ground3"


def _schedule_file(path):
    """Four 20-minute CESs at 2 Hz over 40 deg throws (80 samples a throw), rising and setting."""
    path.write_text(
        "sample_rate_hz = 2.0\n"
        + "".join(
            f"[[ces]]\nstart_unix = {T0 + 43200 * i}\nduration_s = 1200\nelevation_deg = 50\n"
            f"az_centre_deg = {134 if i % 2 else 226}\naz_throw_deg = 40\nturnaround_s = 4\n"
            for i in range(4)
        )
    )
    return str(path)


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    d = tmp_path_factory.mktemp("filtered_table")
    schedule = load_schedule(_schedule_file(d / "s.toml"))
    sky = make_sky(SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=120.0, seed=3))
    return filtered.run(schedule, sky, Filtering.parse(FILTER))


@pytest.fixture(scope="module")
def table(result):
    return {(r["systematic"], r["pipeline"], r["boresight"]): r for r in result.rows}


def _leak(row):
    return np.array([v for k, v in row.items() if k.startswith("leak ")])


@pytest.mark.parametrize("pipeline", ["raw", "p1+ground3"])
def test_rotation_cancels_in_a_filtered_pipeline_what_it_cancels_raw(table, pipeline):
    """The filter is linear and the same on every repeat: the additive leak, which 0/90 turns
    into its opposite, still cancels to rounding, and the pointing offset's first order, which
    0/180 turns into its opposite, to its second order."""
    leak = _leak(table["leak", pipeline, "0"])
    assert np.all(_leak(table["leak", pipeline, "0/90"]) < 1e-20 * leak)
    pointing = _leak(table["pointing", pipeline, "0"])
    assert np.all(_leak(table["pointing", pipeline, "0/180"]) < 1e-4 * pointing)


def test_no_boresight_schedule_touches_an_angle_error_filtered_or_not(table):
    """A polarisation-angle error turns the sky's P through h_0: the same leak whatever the
    boresight does, in each pipeline."""
    for pipeline in ("raw", FILTER):
        base = _leak(table["angle", pipeline, "0"])
        for label in ("0/45", "0/90", "0/180"):
            assert np.allclose(_leak(table["angle", pipeline, label]), base, rtol=1e-6)


def test_the_filter_takes_most_of_every_leak_on_the_largest_scales(table):
    """A polynomial per throw and a ground template remove the scan-direction modes, which hold
    the low multipoles: each unrotated leak keeps less than the raw one in the first band, and
    less there than in the last. (Not less in every band: the filtered leak is binned naively,
    and the filter mixes its E into B, which can raise a band: the pointing offset's last band
    here.)"""
    for name in ("gain", "pointing", "leak", "angle"):
        row = table[name, FILTER, "0"]
        kept = np.array([v for k, v in row.items() if k.startswith("over raw ")])
        assert kept[0] < 0.9 and kept[0] < kept[-1], (name, kept)
        raw = table[name, "raw", "0"]
        assert np.allclose(kept, _leak(row) / _leak(raw))


def test_the_corrected_leak_is_the_leak_over_the_filters_f_bb(result, table):
    """Every filtered row's F_BB is the table's transfer function's, the raw rows' 1, and the
    corrected ratio is the ratio over it. Beside it F_TT, the T block of the 9x9 matrix (pure T
    skies through each detector's filtered TOD): the filter acts on T as on Q and U, so F_TT is
    F_BB within the realisations' spread."""
    f_tt = result.transfer.entry("TT", "TT")
    f_bb = result.transfer.entry("BB", "BB")
    spread = np.hypot(*(result.transfer.entry_error(x, x) for x in ("TT", "BB")))
    assert np.all(np.abs(f_tt - f_bb) < 3 * spread + 0.02), (f_tt, f_bb, spread)
    for row in table.values():
        for band, tt, bb in zip(("30-31", "32-47", "48-64"), f_tt, f_bb):
            f = row[f"F_BB {band}"]
            assert (f == 1.0) if row["pipeline"] == "raw" else (f == bb and 0.0 < f < 1.0)
            assert row[f"F_TT {band}"] == (1.0 if row["pipeline"] == "raw" else tt)
            assert row[f"corrected over raw {band}"] == pytest.approx(
                row[f"over raw {band}"] / f, nan_ok=True
            )  # NaN where the raw leak cancels to rounding


def test_each_rows_delta_r_is_its_corrected_leaks_against_its_pipelines_sigma_r(result, table):
    """delta_r of a raw row is the least-squares amplitude of the tensor template in its leak
    (over 30 <= ell <= 2 Nside here); of a filtered row, in its leak over F_BB band by band. Each
    pipeline's sigma(r) is the survey's Fisher sum: raw, and with N_ell / F_BB and the E the
    filter moves into B (the transfer function's BB <- EE), so larger filtered."""
    template = result.template
    assert np.all(template[30:] > 0)
    s = slice(30, 2 * NSIDE + 1)
    f_bb = result.transfer.entry("BB", "BB")
    per_ell = np.ones(2 * NSIDE + 1)
    for lo, hi, f in zip(result.edges[:-1], result.edges[1:], f_bb):
        per_ell[lo:hi] = f
    theory = load_spectra()
    sigma_raw = noise.sigma_r(result.noise, theory, result.edges)
    sigma_filtered = noise.sigma_r(result.noise, theory, result.edges, transfer_bb=f_bb)
    unpurified = noise.sigma_r(
        result.noise,
        theory,
        result.edges,
        transfer_bb=f_bb,
        e_to_b=result.transfer.entry("BB", "EE"),
    )
    assert unpurified >= sigma_filtered > sigma_raw
    for (name, pipeline, label), row in table.items():
        leak = result.spectra[name, pipeline, label] / (1.0 if pipeline == "raw" else per_ell)
        expected = np.sum(leak[s] * template[s]) / np.sum(template[s] ** 2)
        assert row["delta_r"] == pytest.approx(expected, rel=1e-10)
        sigma = sigma_raw if pipeline == "raw" else sigma_filtered
        assert row["sigma_r"] == pytest.approx(sigma, rel=1e-12)
        assert row["sigma_r unpurified"] == pytest.approx(
            sigma_raw if pipeline == "raw" else unpurified, rel=1e-12
        )
        assert row["delta_r over sigma_r"] == pytest.approx(expected / sigma, rel=1e-10)
    # unpurified, the E the filter moves into B fakes its own r: T^(EE->BB) per band times the
    # raw unrotated sky's pseudo-C_EE, over F_BB; the raw rows' is 0, the filtered rows' one value
    assert np.all(result.sky_ee[30:] > 0)
    for entry, key in ((result.transfer.entry, ""), (result.transfer.entry_error, " error")):
        t = np.zeros(2 * NSIDE + 1)
        for lo, hi, v in zip(result.edges[:-1], result.edges[1:], entry("BB", "EE")):
            t[lo:hi] = v
        leak = result.sky_ee * t / per_ell
        want = np.sum(leak[s] * template[s]) / np.sum(template[s] ** 2)
        for row in table.values():
            got = row[f"delta_r of its E in B{key}"]
            assert got == (0.0 if row["pipeline"] == "raw" else pytest.approx(want, rel=1e-10))
    # the default survey: DEPTH_UK_ARCMIN over the footprint, the sky's beam
    assert result.noise.depth == filtered.DEPTH_UK_ARCMIN and result.noise.fwhm_arcmin == 120.0
    assert 0.0 < result.noise.fsky < 1.0


def test_the_filter_keeps_most_of_a_white_noise_where_it_takes_the_sky(result, table):
    """White noise through the same pipelines (a gain jitter on a uniform T, the same draws raw
    and filtered): the filter takes (p + 1) / n of a throw's noise, so on the footprint's
    pseudo-spectrum, where a band's white noise comes mostly from the smaller scales the mask
    couples in, it keeps 0.9 or more of it in the band where it keeps 0.1 of the sky's B. Each
    filtered row's "sigma_r its noise filtered" reads N_ell K_BB / F_BB, within 5 % of the
    N_ell / F_BB bound here; a raw row's is the raw sigma(r)."""
    kept = result.noise_kept.entry("BB")
    error = result.noise_kept.entry_error("BB")
    f_bb = result.transfer.entry("BB", "BB")
    assert result.noise_kept.n_sims == filtered.N_SIMS and np.all(error < 0.1), error
    assert np.all(kept > 0.8) and np.all(kept < 1.0 + 3 * error), (kept, error)
    assert kept[0] > f_bb[0] + 0.5, (kept, f_bb)
    own = noise.sigma_r(
        result.noise,
        load_spectra(),
        result.edges,
        transfer_bb=np.clip(f_bb, 1e-12, 1.0),
        noise_kept=kept,
    )
    for row in table.values():
        k = [row[f"N_BB kept {b}"] for b in ("30-31", "32-47", "48-64")]
        if row["pipeline"] == "raw":
            assert k == [1.0] * 3 and row["sigma_r its noise filtered"] == row["sigma_r"]
        else:
            assert k == list(kept) and row["sigma_r its noise filtered"] == own
            assert abs(own / row["sigma_r"] - 1.0) < 0.05, (own, row["sigma_r"])
    assert "of a white noise's BB too: with its noise filtered" in filtered.verdict(
        list(table.values())
    )


def test_the_verdict_names_what_the_filter_keeps_and_the_best_schedules(table):
    text = filtered.verdict(list(table.values()))
    assert text.startswith(f"What the filter {FILTER} changes")
    assert "it keeps F_BB = " in text and "of its bias on r once corrected by F_BB" in text
    assert "angle: keeps" in text and "no boresight schedule changes it" in text
    assert "leak: keeps" in text and "least leak with 0/90 raw, 0/90 filtered" in text


def test_the_command_writes_the_table_the_figure_and_the_verdict(tmp_path, capsys):
    path = _schedule_file(tmp_path / "s.toml")
    out = tmp_path / "out"
    args = ["-q", "suppression", "--out", str(out), "--nside", "32", "--schedule", path]
    flags = ["--fwhm-arcmin", "120", "--filter", "p3+ground-split", "--depth-uk-arcmin", "6"]
    assert main([*args, *flags]) == 0
    rows = list(csv.DictReader(open(out / "filtered_suppression.csv")))
    assert len(rows) == 4 * 2 * 4  # boresight schedules x pipelines x systematics
    assert {r["pipeline"] for r in rows} == {"raw", "p3+ground5-split"}
    assert (out / "filtered_suppression.png").is_file() and (out / "transfer.png").is_file()
    transfer = np.load(out / "transfer.npz")
    assert transfer["matrix"].shape == (9, 9, 3)  # SOOPERCOOL's 9x9, the T block in it
    assert list(transfer["field_pairs"]) == [a + b for a in "TEB" for b in "TEB"]
    assert len(list(csv.DictReader(open(out / "transfer.csv")))) == 81 * 3
    assert all("F_TT 30-31" in r for r in rows)
    assert "over unrotated" in (out / "filtered_suppression.md").read_text()
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["filter"] == "p3+ground5-split"
    assert manifest["config"]["noise"]["depth_uk_arcmin"] == 6.0
    text = capsys.readouterr().out
    assert "What the filter p3+ground5-split changes" in text and " of its T):" in text
    assert "sigma(r) (6 muK arcmin, fsky " in text and "E purified" in text
    assert " with the E it leaks into B unpurified, where it moves " in text and " % of E" in text
    assert ", which alone fakes delta_r = " in text
    assert "(delta_r " in text and " sigma), " in text
    assert "| delta_r / sigma(r) |" in (out / "filtered_suppression.md").read_text()
    assert all(float(r["sigma_r"]) > 0 for r in rows)


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--filter", "p3"], "give --schedule"),
        (["--filter", "p3", "--hwp", "continuous", "--schedule", "S"], "give one of them"),
        (["--filter", "p3", "--hwp-ip", "1e-3", "--schedule", "S"], "without a plate"),
        (["--filter", "p3+x", "--schedule", "S"], "filter part 'x'"),
        (["--filter", "none", "--schedule", "S"], "give a filter"),
        (["--filter", "p9", "--schedule", "SHORT"], "samples per throw"),
        (["--filter", "groundbin50", "--schedule", "S"], "wider than the scan"),
        (["--schedule", "S"], "--schedule and --focalplane go with --filter"),
        (["--deproject", "gain"], "--deproject: give --schedule"),
        (["--deproject", "gains", "--schedule", "S"], "choose from gain, pointing"),
        (["--deproject", "none", "--schedule", "S"], "give a filter (e.g. p3+ground) or"),
        (
            ["--filter", "deproject(gain)", "--deproject", "gain", "--schedule", "S"],
            "give one of them",
        ),
        (["--deproject", "gain/2d", "--schedule", "S"], "write ces or <hours>h"),
        (["--deproject-template", "T", "--filter", "p1", "--schedule", "S"], "give --deproject"),
        (["--deproject", "gain", "--deproject-template", "NO", "--schedule", "S"], "no such"),
        (["--deproject", "gain", "--deproject-template", "T8", "--schedule", "S"], "Nside 8"),
        (["--depth-uk-arcmin", "3"], "with --filter or --deproject only"),
        (["--scattered"], "--scattered: with --filter or --deproject only"),
        (["--filter", "p1", "--schedule", "S", "--depth-uk-arcmin", "-1"], "give a depth"),
        (["--filter", "p1", "--schedule", "S", "--depth-uk-arcmin", "nan"], "give a depth"),
    ],
)
def test_the_command_refuses_a_filter_it_cannot_run_before_any_work(tmp_path, capsys, flags, words):
    path = _schedule_file(tmp_path / "s.toml")
    short = tmp_path / "short.toml"  # 4 deg throws: 8 samples a scan, between turnarounds
    short.write_text(open(path).read().replace("az_throw_deg = 40", "az_throw_deg = 4"))
    import healpy as hp

    for name, nside in (("t.fits", 32), ("t8.fits", 8)):
        hp.write_map(tmp_path / name, np.ones(12 * nside**2), dtype=np.float64)
    files = {"S": path, "SHORT": str(short), "T": str(tmp_path / "t.fits")}
    files |= {"T8": str(tmp_path / "t8.fits"), "NO": str(tmp_path / "none.fits")}
    flags = [files.get(f, f) for f in flags]
    out = tmp_path / "bad"
    assert main(["-q", "suppression", "--out", str(out), "--nside", "32", *flags]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and not out.exists(), err


def test_the_command_takes_a_focal_plane(tmp_path):
    """--focalplane with --filter: the table and the transfer function of its pairs, each on its
    own samples; the manifest names them. --scattered draws the gain and the pointing per pair
    (the rows and the manifest say how) in place of the paper's four systematics."""
    path = _schedule_file(tmp_path / "s.toml")
    out = tmp_path / "out"
    args = ["-q", "suppression", "--out", str(out), "--nside", "32", "--schedule", path]
    flags = ["--fwhm-arcmin", "120", "--filter", "p1", "--focalplane", "hexagon:7:10"]
    assert main([*args, *flags, "--scattered"]) == 0
    rows = list(csv.DictReader(open(out / "filtered_suppression.csv")))
    assert len(rows) == 4 * 2 * 2
    assert {r["amplitude"] for r in rows} == {c.amplitude for c in filtered.SCATTERED}
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["config"]["focalplane"]) == 7, manifest["config"]
    assert manifest["config"]["systematics"]["gain"] == "dg = {mean 0, rms 0.01} per pair"
    f_bb = [float(v) for r in rows if r["pipeline"] != "raw" for k, v in r.items() if "F_BB" in k]
    assert all(0.0 < f < 1.0 for f in f_bb)


@pytest.mark.parametrize("where", ["hexagon", "axis"])
def test_a_gain_drawn_per_pair_off_the_axis_escapes_rotation_but_not_deprojection(tmp_path, where):
    """The hexagon's table (``cases=SCATTERED``): a gain drawn per pair leaks through each pair's
    own h_2, so 0/90 cancels its leak of T only where every pair's h_2 turns to its opposite, on
    the axis (what is left, 3e-5, is its leak of P through h_4, which 0/90 keeps); 10 deg off
    it, each pair's scan differs at 0 and 90 deg and 0/90 leaves about half. The gain template
    takes the leak of T wherever the pair sits: what is left is the gain's leak of the sky's P
    (h_4 P*), 2e-5 of raw here, rotated or not."""
    hexagon = focalplane.hexagon(7, 10.0)
    plane = hexagon if where == "hexagon" else focalplane.on_axis(hexagon.pair_angles_deg)
    schedule = load_schedule(_schedule_file(tmp_path / "s.toml"))
    sky = make_sky(SkyConfig(nside=NSIDE, lmax=2 * NSIDE, fwhm_arcmin=120.0, seed=3))
    result = filtered.run(
        schedule,
        sky,
        Filtering.parse("deproject(gain)"),
        schedules=((0.0,), (0.0, 90.0)),
        cases=filtered.SCATTERED[:1],
        n_sims=2,
        focalplane=plane,
    )
    table = {(r["pipeline"], r["boresight"]): r for r in result.rows}
    assert len(table) == 4 and {r["systematic"] for r in result.rows} == {"gain"}
    rotated = _leak(table["raw", "0/90"]) / _leak(table["raw", "0"])
    if where == "axis":
        assert np.all(rotated < 1e-4), rotated
    else:
        assert np.all(rotated > 0.3), rotated
    for label in ("0", "0/90"):
        kept = _leak(table["deproject(gain)", label]) / _leak(table["raw", "0"])
        assert np.all(kept < 1e-4), (label, kept)


def test_the_table_needs_a_filter():
    with pytest.raises(ValueError, match="needs a filter"):
        filtered.run(None, None, Filtering())
    with pytest.raises(ValueError, match="evaluation 'exact'"):
        filtered.run(None, None, Filtering.parse("deproject(pointing)"))


def test_the_command_deprojects_and_says_what_the_templates_take(tmp_path, capsys):
    """--deproject bk alone: the BK templates take the gain's and the pointing's leak of T (what
    is left, 1e-5 of it, is the gain's own P and the offset's third order) and the additive leak,
    whose template is T, to rounding; an angle error leaks the sky's P, which the templates take
    as they take the sky's E (sky_kept.csv, the same fraction to 2 %). Beside what is kept of the
    sky, the spin rule's prediction (its accuracy is tests/predict/test_template_cost.py's)."""
    path = _schedule_file(tmp_path / "s.toml")
    out = tmp_path / "out"
    args = ["-q", "suppression", "--out", str(out), "--nside", "32", "--schedule", path]
    assert main([*args, "--fwhm-arcmin", "120", "--deproject", "bk"]) == 0
    rows = list(csv.DictReader(open(out / "filtered_suppression.csv")))
    mine = {r["systematic"]: r for r in rows if r["pipeline"] != "raw" and r["boresight"] == "0"}
    assert {r["pipeline"] for r in rows} == {"raw", "deproject(bk)"}

    def over_raw(name):
        return np.array([float(v) for k, v in mine[name].items() if k.startswith("over raw")])

    assert np.all(over_raw("gain") < 1e-4) and np.all(over_raw("pointing") < 1e-4)
    assert np.all(over_raw("leak") < 1e-20)
    kept = list(csv.DictReader(open(out / "sky_kept.csv")))
    assert len(kept) == 8 and all(
        float(v) == 1.0 for r in kept if r["pipeline"] == "raw" for k, v in r.items() if "kept" in k
    )
    unrotated = next(r for r in kept if r["pipeline"] != "raw" and r["boresight"] == "0")
    bands = [k[8:] for k in unrotated if re.match(r"EE kept \d", k)]
    ee = np.array([float(unrotated[f"EE kept {b}"]) for b in bands])
    predicted = np.array([float(unrotated[f"EE kept predicted {b}"]) for b in bands])
    assert np.all(ee < 0.9)  # a definite share of E goes with the templates
    np.testing.assert_allclose(over_raw("angle"), ee, rtol=0.02)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["evaluation"] == "exact"
    printed = capsys.readouterr().out
    assert "the sky's own E and B, without rotation: keeps" in printed
    # beside it the spin rule's share (here, a 120 arcmin sky below ell 65, about 1 %: the E the
    # templates take on this small footprint is the blocks' chance projection, 35-57 %)
    assert np.all(np.abs(predicted - 1.0) < 0.02) and np.all(predicted != 1.0)
    assert "the spin rule predicts 0.99/0.99/1.01 of EE" in printed
