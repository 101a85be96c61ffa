"""The stream thread's scheduling while it streams on the wall clock (drivers.priority)."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from trajgen.drivers import priority
from trajgen.drivers.priority import stream_priority

linux_only = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="Linux only")


@linux_only
def test_stream_priority_raises_the_threads_alive_and_restores_everything():
    interval, policy = sys.getswitchinterval(), os.sched_getscheduler(0)
    release, seen = threading.Event(), {}
    waiting = threading.Thread(target=release.wait)  # alive before: raised with the caller
    waiting.start()

    def started_inside():
        seen["started inside"] = os.sched_getscheduler(0)

    reset = getattr(os, "SCHED_RESET_ON_FORK", 0)
    with stream_priority(fifo_priority=3, switch_interval_s=2e-4) as how:
        assert sys.getswitchinterval() == pytest.approx(2e-4)
        inside = os.sched_getscheduler(0), os.sched_getscheduler(waiting.native_id)
        t = threading.Thread(target=started_inside)
        t.start()
        t.join()
    assert sys.getswitchinterval() == interval
    assert os.sched_getscheduler(0) == policy
    assert os.sched_getscheduler(waiting.native_id) == policy
    release.set()
    waiting.join()
    assert seen["started inside"] == policy  # reset on fork: not raised
    if how.startswith("SCHED_FIFO 3"):
        assert [p & ~reset for p in inside] == [os.SCHED_FIFO, os.SCHED_FIFO]
        n = len(threading.enumerate()) + 1  # and the waiting thread, ended since
        assert how == f"SCHED_FIFO 3 ({n} threads), GIL switch interval 0.2 ms"
    else:  # a host that does not permit it says so
        assert how.startswith("SCHED_FIFO not permitted (") and inside == (policy, policy)


def test_stream_priority_says_when_the_system_refuses(monkeypatch):
    def refuse(*args):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(priority.os, "sched_setscheduler", refuse, raising=False)
    monkeypatch.setattr(priority.os, "sched_getscheduler", lambda pid: 0, raising=False)
    monkeypatch.setattr(priority.os, "sched_getparam", lambda pid: None, raising=False)
    interval = sys.getswitchinterval()
    with stream_priority() as how:
        assert (
            how == "SCHED_FIFO not permitted (Operation not permitted); GIL switch interval 0.5 ms"
        )
    assert sys.getswitchinterval() == interval
