"""A run's manifest: each stage's seconds, the versions, the git revision and the machine; the
timer tells the log as each stage starts."""

import json
import logging
import time

from boresight import __version__
from boresight._util import provenance


def test_the_timer_records_each_stage_and_tells_the_log(caplog):
    log = logging.getLogger("boresight.test")
    timer = provenance.Timer(log)
    with caplog.at_level(logging.INFO, logger="boresight.test"):
        with timer("first"):
            time.sleep(0.05)
        with timer("second"):
            pass
    assert list(timer.stages) == ["first", "second"]
    assert 0.04 < timer.stages["first"] < 1.0 and timer.stages["second"] < 0.05
    assert [r.getMessage() for r in caplog.records] == ["first ...", "second ..."]


def test_the_manifest_says_what_made_the_result():
    made = provenance.manifest({"sky": {"nside": 16}}, {"sky": 3}, {"sky": 0.5}, {"bytes": 1})
    assert made["config"] == {"sky": {"nside": 16}} and made["seeds"] == {"sky": 3}
    assert made["versions"]["boresight"] == __version__
    assert {"numpy", "healpy", "ducc0", "numba", "python"} <= set(made["versions"])
    assert len(made["git_revision"]) in (40, 7) or made["git_revision"] == "unknown"
    assert made["wall_time_s"] == {"sky": 0.5} and made["estimate"] == {"bytes": 1}
    json.dumps(made)  # a manifest is plain JSON
