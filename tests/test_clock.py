"""``drivers.clock.PacedClock``: simulated time that the wall clock paces, on a fake wall."""

import pytest

from trajgen.drivers.clock import PacedClock


class FakeWall:
    """A wall clock that moves only when told: ``cost(s)`` is the host's work, ``wait``
    jumps to a deadline (and records it)."""

    def __init__(self, start_s=100.0):
        self.t = start_s
        self.waits = []

    def __call__(self):
        return self.t

    def wait(self, due_s):
        self.waits.append(due_s)
        self.t = max(self.t, due_s)

    def cost(self, seconds):
        self.t += seconds


def _clock(wall, **kwargs):
    return PacedClock(wall=wall, wait=wall.wait, **kwargs)


def test_a_host_that_keeps_up_runs_in_real_time():
    wall = FakeWall()
    clock = _clock(wall)
    wall.cost(3.0)  # bring-up before the stream: not counted, the clock ties at first use
    assert clock.now() == 0.0
    for k in range(1, 101):
        wall.cost(0.001)  # 1 ms of work per 5 ms frame
        clock.sleep_until(0.005 * k)
        assert clock.now() == pytest.approx(0.005 * k)
        assert wall() == pytest.approx(103.0 + 0.005 * k)  # waited for the wall clock
    assert clock.lag_max_s == 0.0 and clock.shifts == 0 and clock.behind_now_s == 0.0
    assert "kept the wall clock's pace" in clock.format()


def test_jitter_is_caught_up_and_a_long_stall_shifted_off():
    wall = FakeWall(0.0)
    clock = _clock(wall, max_behind_s=0.05)
    clock.now()
    clock.sleep_until(0.005)
    wall.cost(0.02)  # 20 ms of work: the next deadline is 15 ms late
    clock.sleep_until(0.010)
    assert clock.now() == 0.010 and clock.lag_s == pytest.approx(0.015)
    clock.sleep_until(0.015)  # due at 15 ms wall, passed already: no wait, still behind
    assert clock.lag_s == pytest.approx(0.010) and clock.shifts == 0
    clock.sleep_until(0.030)  # caught up: waits again
    assert wall() == pytest.approx(0.030) and clock.lag_s == 0.0
    wall.cost(0.2)  # a stall of 200 ms: more than 50 ms behind, shifted off
    clock.sleep_until(0.035)
    assert clock.now() == 0.035 and clock.shifts == 1
    assert clock.behind_s == pytest.approx(0.195) and clock.behind_now_s == pytest.approx(0.195)
    clock.sleep_until(0.040)  # real time again from there, 195 ms behind the wall clock
    assert wall() == pytest.approx(0.040 + 0.195)
    assert clock.lag_max_s == pytest.approx(0.195)
    assert "fell 0.195 s behind the wall clock in 1 shifts" in clock.format()
    assert clock.summary() == pytest.approx(
        {"lag_max_s": 0.195, "shifts": 1, "behind_s": 0.195, "behind_now_s": 0.195}
    )


def test_it_never_goes_back():
    wall = FakeWall()
    clock = _clock(wall, start_s=2.0)
    clock.sleep_until(1.0)
    assert clock.now() == 2.0 and wall.waits == [100.0]
