"""Signals noted and acted on between chunks of work: each raises once, at the next check, as
Interrupted with the shell's exit code; a second Ctrl-C before a check raises at once; the old
handlers come back after the block. The command line end to end: tests/cli/test_signals.py."""

import os
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from boresight._util import interrupts


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_is_noted_then_raised_once_at_the_next_check(signum, code):
    with interrupts.handled():
        os.kill(os.getpid(), signum)
        assert interrupts.pending()
        with pytest.raises(interrupts.Interrupted) as stop:
            interrupts.check()
        assert stop.value.exit_code == code and stop.value.signum == signum
        interrupts.check()  # raised once: a job that keeps its work may go on


def test_a_second_ctrl_c_before_a_check_raises_at_once():
    with interrupts.handled():
        os.kill(os.getpid(), signal.SIGINT)
        with pytest.raises(interrupts.Interrupted):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)  # the handler raises inside this call


def test_the_previous_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM)
    with interrupts.handled():
        assert signal.getsignal(signal.SIGTERM) is not before
    assert signal.getsignal(signal.SIGTERM) is before


def test_waiting_for_a_background_job_checks_for_signals():
    release = threading.Event()
    with ThreadPoolExecutor(1) as pool, interrupts.handled():
        future = pool.submit(release.wait, 10)
        threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGTERM)).start()
        t0 = time.perf_counter()
        with pytest.raises(interrupts.Interrupted):
            interrupts.result(future)
        assert time.perf_counter() - t0 < 2  # not after the job's 10 s
        release.set()
        assert interrupts.result(pool.submit(lambda: 7)) == 7
