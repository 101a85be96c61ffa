"""How many steps of the lines' changes the streaming thread runs between two frames."""

import numpy as np
import pytest

from trajgen import follower as follow
from trajgen.gimbal import forward
from trajgen.online import OnlineSpline


class Clock:
    """A stand-in for the module's ``time``: time passes only inside a step."""

    def __init__(self):
        self.now = 0.0

    def perf_counter(self):
        return self.now

    def monotonic(self):
        return self.now


def job(clock, n, step_s, ran):
    def steps():
        for i in range(n):
            clock.now += step_s
            ran.append(i)
            if i < n - 1:
                yield

    return follow._Job(steps(), "line 1")


@pytest.fixture
def clock(monkeypatch):
    c = Clock()
    monkeypatch.setattr(follow, "time", c)
    return c


def follower(rate_hz):
    return follow.Follower(OnlineSpline(forward([0.0, 0.0, 0.0]), 0.0, k=2), rate_hz)


@pytest.mark.parametrize(
    ("rate_hz", "step_s", "per_frame"),
    [
        (1000.0, 3e-4, 1),  # a step longer than the share: one a frame
        (1000.0, 1e-4, 2),  # 0.1 ms spent, 0.1 more fits in 0.25 ms; a third does not
        (100.0, 1.1e-4, 22),  # 2.5 ms: 22 steps spent 2.42 ms, and 2.42 + 0.11 passes it
    ],
)
def test_steps_run_while_a_share_of_the_period_leaves_room(clock, rate_hz, step_s, per_frame):
    f, ran = follower(rate_hz), []
    f._jobs.append(job(clock, 40, step_s, ran))
    counts = []
    while f._jobs:
        before = len(ran)
        f._step()
        counts.append(len(ran) - before)
    assert sum(counts) == 40
    assert counts[:-1] == [per_frame] * (len(counts) - 1)
    assert 1 <= counts[-1] <= per_frame


def test_queued_changes_share_a_frame_in_order(clock):
    f, ran_a, ran_b = follower(20.0), [], []
    a, b = job(clock, 5, 1e-4, ran_a), job(clock, 5, 1e-4, ran_b)
    f._jobs.extend([a, b])
    f._step()
    assert a.finished.is_set() and b.finished.is_set() and not f._jobs
    assert a.busy_s == pytest.approx(5e-4) and a.longest_s == pytest.approx(1e-4)


def test_no_share_runs_one_step_a_frame(clock, monkeypatch):
    monkeypatch.setattr(follow, "STEP_SHARE", 0.0)
    f, ran = follower(20.0), []
    f._jobs.append(job(clock, 4, 1e-4, ran))
    for expected in range(1, 5):
        f._step()
        assert len(ran) == expected
    assert not f._jobs and np.isclose(clock.now, 4e-4)
