"""The real-time virtual bus's plant clock: catch-up after a stall, the lag counters,
the child's scheduling. Driven by an injected clock except where a child process runs."""

import os
import signal
import time
import types

import numpy as np
import pytest

from trajgen.drivers import streamer
from trajgen.drivers.control_table import model_named
from trajgen.drivers.priority import PLANT_FIFO_PRIORITY, claim_core
from trajgen.drivers.units import rad_to_servo_ticks
from trajgen.drivers.virtual import simulation
from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.drivers.virtual.process import PlantProcess
from trajgen.drivers.virtual.simulation import LAG_COUNTED_S, Lag, WallSteps

STEP_S = 1e-3
V0 = model_named("XM430-W350").no_load_speed_rad_s  # rad/s


def _held(stall_at_s: float, stall_s: float, seconds: float, read_phase_s: float = 5e-4):
    """A child waking every 0.1 ms, held from ``stall_at_s`` for ``stall_s``; the
    simulated time (s) published at each 1 kHz read: [(read time (s), simulated (s))]."""
    wall = WallSteps(STEP_S, 0.0)
    reads, wake_s = [], 0.0
    for k in range(round(seconds / STEP_S)):
        read_s = k * STEP_S + read_phase_s
        while wake_s <= read_s:
            if not stall_at_s <= wake_s < stall_at_s + stall_s:
                wall.take(wake_s)
            wake_s += 1e-4
        reads.append((read_s, wall.done * STEP_S))
    return reads, wall


@pytest.mark.parametrize("phase_s", [0.0, 2.5e-4, 5e-4, 9.9e-4])
def test_catch_up_after_a_stall_is_bounded_and_ends(phase_s):
    stall_s = 0.04
    reads, wall = _held(0.2, stall_s, 0.6, phase_s)
    t, s = np.array(reads).T
    shown = np.diff(s)  # simulated time a client sees pass between two reads
    bound = simulation._CATCH_UP_BURST_S + simulation._CATCH_UP_RATE * np.diff(t) + 1e-9
    assert np.all(shown <= bound)
    assert shown.max() > STEP_S * 1.5  # it did catch up faster than real time
    behind = t - s
    assert behind.max() >= stall_s  # the stall held it back
    # caught up (within a step) within the stated rule: stall / (rate - 1), plus a step
    caught_s = 0.2 + stall_s + stall_s / (simulation._CATCH_UP_RATE - 1) + 2 * STEP_S
    assert np.all(behind[t > caught_s] <= STEP_S + 1e-9)
    assert wall.lag.max_s >= stall_s


def _fake_streamer():
    """What ``Streamer._plausible`` uses of its streamer: one pan servo of no-load speed V0."""
    joints = types.SimpleNamespace(
        to_rad=lambda ticks: np.asarray(ticks, dtype=float) * (2 * np.pi / 4096), ids=[1]
    )
    return types.SimpleNamespace(
        joints=joints,
        joint_names=["pan"],
        _last_position=None,
        _max_speed=np.array([streamer.GLITCH_SPEED_FACTOR * V0]),
        _glitches=np.zeros(1, dtype=int),
        stats=types.SimpleNamespace(position_glitches=0),
        _frame_no=0,
        _warn=lambda message: None,
    )


def _glitch_check(reads, speed_rad_s):
    """The streamer's own glitch check (``Streamer._plausible``) over a servo moving at
    ``speed_rad_s`` on the simulated time of ``reads``: the glitches it counted, and
    the ``ServoError`` it raised (or None)."""
    fake = _fake_streamer()
    for k, (read_s, sim_s) in enumerate(reads):
        fake._frame_no = k
        ticks = rad_to_servo_ticks(np.array([speed_rad_s * sim_s]))
        try:
            streamer.Streamer._plausible(fake, ticks, read_s)
        except streamer.ServoError as e:
            return fake.stats.position_glitches, e
    return fake.stats.position_glitches, None


@pytest.mark.parametrize("speed", [0.3, 0.8])
def test_catch_up_never_reads_as_an_encoder_fault(speed):
    for phase_s in (0.0, 5e-4, 9e-4):
        reads, _ = _held(0.2, 0.04, 0.6, phase_s)
        assert _glitch_check(reads, speed * V0) == (0, None)


def test_the_old_burst_read_as_a_jump(monkeypatch):
    """Why "Present Position implausible" fired: 10 ms of motion in one 1 ms read
    after a stall is faster than a servo can move, so the check rejects that read.
    (It then also rejected the next two, an "encoder fault", until the check kept
    each joint's last plausible time: the test below.)"""
    monkeypatch.setattr(simulation, "_CATCH_UP_BURST_S", 0.01)
    monkeypatch.setattr(simulation, "_CATCH_UP_RATE", 1.5)
    reads, _ = _held(0.2, 0.04, 0.6)
    glitches, error = _glitch_check(reads, 0.3 * V0)
    assert glitches >= 1 and error is None


def test_lag_counts_a_held_child():
    wall = WallSteps(STEP_S, 0.0)
    t = 0.0
    for k in range(100):  # on time: 1 ms wake-ups
        t = (k + 1) * STEP_S
        wall.take(t)
    assert wall.lag.max_s == pytest.approx(STEP_S) and wall.lag.over_s == 0.0
    t += 0.1  # held 100 ms
    while wall.behind_s(t) > STEP_S or t < 0.3:  # then woken every 0.1 ms
        wall.take(t)
        t += 1e-4
    assert wall.lag.max_s == pytest.approx(0.1, abs=1e-6)
    # the 100 ms held, then down by the burst and on to 20 ms at 0.25 ms per ms
    rate = simulation._CATCH_UP_RATE - 1
    expected = 0.1 + (0.1 - simulation._CATCH_UP_BURST_S - LAG_COUNTED_S) / rate
    assert wall.lag.over_s == pytest.approx(expected, abs=3e-3)
    total = sum(wall.lag.counts)
    assert total == pytest.approx(t - 1e-4 - STEP_S, abs=1e-6)
    assert Lag.quantile(wall.lag.counts, 0.5) > LAG_COUNTED_S  # most of it spent behind
    assert Lag.quantile(wall.lag.counts, 0.99) == pytest.approx(0.1, abs=1e-3)


def test_lag_is_not_counted_while_nobody_reads():
    wall = WallSteps(STEP_S, 0.0)
    wall.take(0.001)
    wall.take(0.2, unread=1.0)  # idle: stepped every 5 ms by design; nobody saw it
    assert wall.lag.max_s == pytest.approx(STEP_S) and sum(wall.lag.counts) == 0.0


def test_a_held_child_is_counted():
    """A child stopped (SIGSTOP) for 100 ms says so in its figures: the lag, the time
    over ``LAG_COUNTED_S``."""
    process = PlantProcess(FirstOrderPlant(), STEP_S, time.monotonic())
    try:
        deadline = time.monotonic() + 30.0
        # until it has caught up with the steps due while it was forked (not counted)
        while process.figures()[0] == 0.0 and time.monotonic() < deadline:
            time.sleep(0.005)
        os.kill(process._process.pid, signal.SIGSTOP)
        held = time.monotonic()
        time.sleep(0.1)
        os.kill(process._process.pid, signal.SIGCONT)
        deadline = held + 30.0  # the wait ends as soon as the child has noted it
        while process.figures()[0] < 0.1 and time.monotonic() < deadline:
            time.sleep(0.005)
        lag_max, over, cpu, counts = process.figures()
        assert lag_max >= 0.1
        assert over >= 0.1 - LAG_COUNTED_S
        assert cpu > 0.0 and sum(counts) > 0.0
    finally:
        process.stop()


def test_the_child_claims_a_core_where_permitted():
    """The child raises itself to ``SCHED_FIFO`` just below the serving thread where it
    may (read back); where it may not, it stays in the normal class."""
    permitted = claim_core_permitted()
    process = PlantProcess(FirstOrderPlant(), STEP_S, time.monotonic())
    try:
        deadline = time.monotonic() + 30.0  # ends as soon as the child has stepped
        while process.figures()[2] == 0.0 and time.monotonic() < deadline:
            time.sleep(0.005)
        expected = f"SCHED_FIFO {PLANT_FIFO_PRIORITY}" if permitted else "SCHED_OTHER nice "
        assert process.scheduling().startswith(expected)
    finally:
        process.stop()


def claim_core_permitted() -> bool:
    """Whether this process may raise a thread to ``SCHED_FIFO`` (tried in a child)."""
    pid = os.fork()
    if pid == 0:
        os._exit(0 if claim_core(PLANT_FIFO_PRIORITY).startswith("SCHED_FIFO ") else 1)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0


def test_the_bus_reports_its_held_plant_once_stopped():
    """``VirtualBus.lag()`` after ``stop``: the figures of its plant's process."""
    virtual = VirtualBus(FirstOrderPlant(), plant_process=True).start()
    try:
        deadline = time.monotonic() + 30.0  # each wait ends as soon as its condition holds
        while virtual.plant.figures()[0] == 0.0 and time.monotonic() < deadline:  # caught up
            time.sleep(0.005)
        os.kill(virtual.plant._process.pid, signal.SIGSTOP)
        time.sleep(0.05)
        os.kill(virtual.plant._process.pid, signal.SIGCONT)
        while virtual.plant.figures()[0] < 0.05 and time.monotonic() < deadline:
            time.sleep(0.005)
    finally:
        virtual.stop()
    lag_max, lag_p99, over = virtual.lag()
    assert lag_max >= 0.05 and over >= 0.05 - LAG_COUNTED_S
    assert 0.0 < lag_p99 <= lag_max + simulation._LAG_BIN_S


def test_one_rejected_read_never_turns_a_moving_servo_into_an_encoder_fault():
    """A single glitched read of a servo moving just under the check's speed: the next
    reads are compared with the last plausible read at its own time, so they pass
    (before, the reference time moved to the rejected read while its position stayed,
    and the next two reads were rejected too: an "encoder fault")."""
    speed = 0.9 * streamer.GLITCH_SPEED_FACTOR * V0
    fake = _fake_streamer()
    seen = []
    for k in range(40):
        t = 1e-3 * k
        angle = speed * t + (1.0 if k == 10 else 0.0)  # read 10 is off by 1 rad
        ticks = rad_to_servo_ticks(np.array([angle]))
        seen.append(streamer.Streamer._plausible(fake, ticks, t)[0])
    assert fake.stats.position_glitches == 1
    assert np.isnan(seen[10]) and not np.isnan(np.delete(seen, 10)).any()
