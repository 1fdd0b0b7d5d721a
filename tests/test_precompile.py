"""Compiling ahead of a run: the registered signatures are the ones a study calls, and the helper
processes' kernels reach this process through numba's cache."""

import os
import subprocess
import sys

import pytest

from boresight import precompile

PAPER_STUDY_ON_REGISTERED_KERNELS = """
from boresight import paper, precompile
names = precompile.kernels_for("cpu", pointing=True)
assert sorted(names) == sorted(precompile.KERNELS)
precompile.precompile(names)
paper.run_study(paper.preset(nside=16, lmax=47, seed=3))
for name in names:  # a call with other argument types would have added a signature
    assert precompile.KERNELS[name].dispatcher.signatures == [precompile.KERNELS[name].signature]
"""


def test_the_paper_study_calls_every_kernel_at_its_registered_signature():
    # a fresh process: its dispatchers hold only what precompile gave them
    proc = subprocess.run(
        [sys.executable, "-c", PAPER_STUDY_ON_REGISTERED_KERNELS], capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr


HELPER_SHARE = """
import sys
from boresight import precompile
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
