"""Compiling ahead of a run: the registered signatures are the ones a study calls, and the helper
processes' kernels reach this process through numba's cache."""

import os
import subprocess
import sys

import pytest
from helpers import EXAMPLES

from boresight._util import precompile
from boresight.schedule import Schedule, load_schedule

JOBS = ("study", "design", "validation", "schedule-stats", "focalplane-stats")

EVERY_JOB_ON_REGISTERED_KERNELS = r"""
import sys
from pathlib import Path
from boresight._util import precompile
from boresight.instrument import focalplane
from boresight.jobs import paper
from boresight.commands import design, scan_stats
from boresight.schedule import CES, Schedule, load_schedule, write_schedule
tmp = Path(sys.argv[1])
asked = set()  # the kernels the jobs precompile
real = precompile.precompile
precompile.precompile = lambda names, *args, **kw: asked.update(names) or real(names, *args, **kw)
paper.run_study(paper.preset(nside=16, lmax=47, seed=3))
# two 2-minute CESs of the deep example at 1 Hz, and a gain + pointing budget at Nside 16
base = load_schedule(Path(sys.argv[2]) / "schedule_deep_sat.toml")
ces = tuple(CES(**{**c.__dict__, "duration_s": 120.0}) for c in base.ces[:2])
write_schedule(Schedule(ces, base.site, 1.0), tmp / "s.toml", "toml")
(tmp / "b.toml").write_text(
    "[systematics]\ndg = [0.01, -0.01]\nrho_arcmin = 0.5\n"
    "[noise]\ndepth_uk_arcmin = 3.0\nfsky = 0.1\nfwhm_arcmin = 60.0\n"
    "[design]\nnside = 16\nsweeps = 1\nangles_deg = [0.0, 90.0]\n"
)
design.run(str(tmp / "b.toml"), str(tmp / "s.toml"), str(tmp / "d"))
scan_stats.run_schedule(str(tmp / "s.toml"), str(tmp / "h"), nside=16)
scan_stats.run_schedule(
    str(tmp / "s.toml"), str(tmp / "f"), nside=16, focalplane=focalplane.hexagon(7, 10.0)
)
for kernel in precompile.KERNELS.values():  # another argument type would add a signature
    assert kernel.dispatcher.signatures in ([], [kernel.signature]), kernel.name
    assert kernel.name in asked or not kernel.dispatcher.signatures, kernel.name  # called late
assert asked == set(precompile.KERNELS)
"""


def test_the_jobs_name_every_registered_kernel():
    named = {n for job in JOBS for n in precompile.kernels_for(job, "cpu", pointing=True)}
    assert named == set(precompile.KERNELS)
    assert "offset_points" not in precompile.kernels_for("validation", "cpu", pointing=False)
    assert "accumulate" not in precompile.kernels_for("study", "gpu", pointing=True)
    with pytest.raises(
        ValueError, match="allowed: study, design, validation, schedule-stats, focalplane-stats"
    ):
        precompile.kernels_for("sweep")


def test_a_schedule_in_integers_or_floats_calls_the_ces_kernels_at_one_signature():
    # a TOML schedule gives integer starts and durations, a TOAST one floats: numba would compile
    # each combination of types anew (2.2-2.4 s per kernel with an empty cache)
    from dataclasses import replace

    import numba

    from boresight import pointing

    base = load_schedule(EXAMPLES / "schedule_deep_sat.toml")
    as_int = [replace(c, start_unix=int(c.start_unix), turnaround_s=0) for c in base.ces[:2]]
    as_float = [replace(c, start_unix=c.start_unix + 0.5, turnaround_s=2.5) for c in base.ces[:2]]
    for ces, rate in ((as_int, 20), (as_float, 12.5)):
        schedule = Schedule(tuple(ces), base.site, rate)
        for args in pointing.chunk_arguments(schedule, chunk_samples=1 << 14):
            types = tuple(numba.typeof(a) for a in args)
            assert types == precompile.KERNELS["_ces_pointing"].signature
            extra = (numba.int64, numba.int64, numba.bool_)
            assert types + extra == precompile.KERNELS["ces_hits"].signature


@pytest.mark.slow
def test_every_job_calls_its_kernels_at_their_registered_signatures(tmp_path):
    # a fresh process, in which each job precompiles its kernels: a kernel called with other
    # argument types would compile a second signature
    proc = subprocess.run(
        [sys.executable, "-c", EVERY_JOB_ON_REGISTERED_KERNELS, str(tmp_path), str(EXAMPLES)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr


HELPER_SHARE = """
import sys
from boresight._util import precompile
precompile.HELPER_START_SECONDS = 0.0  # two small kernels, one each
names = ["offset_points", "_response"]
assert precompile._balance(names, 2) == [["offset_points"], ["_response"]]
assert precompile.missing(names) == names
assert precompile.precompile(names, nthreads=2) == names
assert precompile.missing(names) == []
helper_kernel = precompile.KERNELS["_response"]
stats = helper_kernel.dispatcher.stats
assert not stats.cache_misses and list(stats.cache_hits) == [helper_kernel.signature]
assert precompile.precompile(names, nthreads=2) == []
"""


@pytest.mark.slow
def test_a_helper_compiles_its_share_into_the_cache(tmp_path):
    # an empty cache; this process compiles offset_points, the helper _response, which this
    # process then loads from the cache (a hit, no miss)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    proc = subprocess.run(
        [sys.executable, "-c", HELPER_SHARE], env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr


def test_balance_gives_the_longest_kernels_first_to_the_process_free_soonest():
    names = list(precompile.KERNELS)
    shares = precompile._balance(names, 2)
    assert sorted(sum(shares, [])) == sorted(names)
    loads = [sum(precompile.KERNELS[n].seconds for n in s) for s in shares]
    loads[1] += precompile.HELPER_START_SECONDS
    longest = max(k.seconds for k in precompile.KERNELS.values())
    assert abs(loads[0] - loads[1]) <= longest  # greedy: within one kernel of each other
    by_time = sorted(names, key=lambda n: -precompile.KERNELS[n].seconds)
    assert precompile._balance(names, 1) == [by_time]
    assert len(precompile._balance(["_response"], 4)) == 1  # no helper for an empty share


def test_a_failing_helper_is_raised_with_its_error_output(monkeypatch):
    monkeypatch.setattr(precompile, "missing", lambda names: list(names))
    monkeypatch.setattr(precompile, "_compile", lambda name: None)

    def failing_helper(share):
        code = "import sys; sys.exit('no kernel ' + ' '.join(sys.argv[1:]))"
        return subprocess.Popen(
            [sys.executable, "-c", code, *share], stderr=subprocess.PIPE, text=True
        )

    monkeypatch.setattr(precompile, "_start_helper", failing_helper)
    # this process takes moments, the longer one; the helper gets _response and fails
    assert precompile._balance(["moments", "_response"], 2)[1] == ["_response"]
    with pytest.raises(RuntimeError, match="compiling _response failed:\nno kernel _response"):
        precompile.precompile(["moments", "_response"], nthreads=2)
