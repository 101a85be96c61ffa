"""Issue 7 on the virtual bus: bad replies, installed settings, stalls, signals, bring-up order.

Each test injects one fault and asserts what reached the servos (goals, writes
to the limit registers, torque) and what the caller was told.
"""

import csv
import math
import time

import numpy as np
import pytest

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import (
    BringUpError,
    CommError,
    OutsideLimits,
    ServoError,
    StreamLagging,
    WatchdogTripped,
)
from trajgen.drivers.streamer import RunningQuantiles, Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import Fault, VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.stream import JointTrajectory

RATE_HZ = 200.0
MODELS = ("XM430-W350",) * 3
PRESENT_POSITION, PRESENT_BLOCK = 132, 126  # read addresses: one register, the state block
# Registers a host can write: EEPROM and RAM up to Goal Position (Realtime Tick at 120 and
# the present values after it change by themselves).
WRITABLE = slice(0, 120)


def _ramp(q_end, duration_s=0.3, q_start=(0.0, 0.0, 0.0)):
    """A minimum-jerk joint move from ``q_start`` to ``q_end`` (rad)."""
    t = np.arange(round(duration_s * RATE_HZ) + 1) / RATE_HZ
    s = (t / duration_s)[:, None]
    h = 10 * s**3 - 15 * s**4 + 6 * s**5
    q = np.asarray(q_start) + h * (np.asarray(q_end) - np.asarray(q_start))
    return JointTrajectory(t, q, np.gradient(q, t, axis=0), np.zeros_like(q), RATE_HZ)


@pytest.fixture
def rig():
    """make(**VirtualBus options) -> (virtual bus, open ServoBus), closed after the test."""
    made = []

    def make(plant=None, **kwargs):
        kwargs.setdefault("lockstep_dt_s", 1 / RATE_HZ)
        virtual = VirtualBus(plant or FirstOrderPlant(time_constant_s=0.01), **kwargs).start()
        bus = ServoBus(virtual.port).open()
        made.append((virtual, bus))
        return virtual, bus

    yield make
    for virtual, bus in made:
        bus.close()
        virtual.stop()


def _memory(virtual):
    return {i: bytes(s.memory[WRITABLE]) for i, s in virtual.servos.items()}


def _torque(virtual):
    return [s.torque_on for s in virtual.servos.values()]


# -- 1. every reply checked: id, length, error byte ---------------------------


@pytest.mark.parametrize(
    ("fault", "call", "match"),
    [
        (
            Fault("short", servo_id=1, n_bytes=2),
            lambda bus: bus.read(1, Register.PRESENT_POSITION),
            r"servo 1: read Present Position failed after 3 tries: "
            r"reply of length 6 \(LEN field\), expected 8",
        ),
        (
            Fault("short", servo_id=1),
            lambda bus: bus.read(1, Register.PRESENT_POSITION),
            r"reply of length 4 \(LEN field\), expected 8",
        ),
        (
            Fault("short", servo_id=1, n_bytes=1),
            lambda bus: bus.ping(1),
            r"servo 1: ping failed after 3 tries: reply of length 6 \(LEN field\), expected 7",
        ),
        (
            Fault("wrong_id", servo_id=1, reply_id=2),
            lambda bus: bus.read(1, Register.PRESENT_POSITION),
            # The SDK skips a reply from another id and then times out.
            r"servo 1: read Present Position failed after 3 tries: There is no status packet",
        ),
        (
            Fault("short", servo_id=2, n_bytes=4),
            lambda bus: bus.read_block((1, 2, 3), (Register.PRESENT_POSITION,), fast=False),
            r"servos \[1, 2, 3\]: sync read of Present Position failed after 3 tries: "
            r"servo 2: reply of length 4 \(LEN field\), expected 8",
        ),
        (
            Fault("short", servo_id=2, n_bytes=2),
            lambda bus: bus.read_block((1, 2, 3), (Register.PRESENT_POSITION,), fast=True),
            r"fast sync read of Present Position failed after 3 tries: "
            r"reply of length 23 \(LEN field\), expected 25",
        ),
        (
            Fault("wrong_id", servo_id=2, reply_id=7),
            lambda bus: bus.read_block((1, 2, 3), (Register.PRESENT_POSITION,), fast=True),
            r"fast sync read of Present Position failed after 3 tries: "
            r"reply part 1 from id 7, expected 2",
        ),
    ],
    ids=["short", "empty", "ping", "wrong-id", "sync-read", "fast-short", "fast-wrong-id"],
)
def test_unsound_reply_is_a_comm_error_never_a_value(rig, fault, call, match):
    virtual, bus = rig(faults=[fault])
    for servo_id in (1, 2, 3):
        bus.add_servo(servo_id, virtual.servos[servo_id].model)
    with pytest.raises(CommError, match=match):
        call(bus)
    assert bus.failed_tries == 3


def test_one_short_reply_is_retried_and_the_true_value_used(rig):
    virtual, bus = rig(faults=[Fault("short", servo_id=1, n_bytes=2, count=1)])
    bus.add_servo(1, virtual.servos[1].model)
    virtual.servos[1].set(Register.PRESENT_POSITION, 2048)
    assert bus.read(1, Register.PRESENT_POSITION) == 2048
    assert bus.failed_tries == 1


def test_short_present_position_in_bring_up_never_becomes_a_goal(rig):
    # The case: a short Present Position reply read as 3233 while the servo
    # sat at 2048, and torque came on. Now: a comm error, and nothing is changed.
    virtual, bus = rig(faults=[Fault("short", servo_id=1, n_bytes=2, address=PRESENT_POSITION)])
    before = _memory(virtual)
    with pytest.raises(CommError, match=r"servo 1: read Present Position failed after 3 tries"):
        bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.1, 0.0)))
    assert _memory(virtual) == before  # no goal, no torque, no setting written
    assert not any(_torque(virtual))


def test_short_present_position_once_in_bring_up_uses_the_true_position(rig):
    plant = FirstOrderPlant(initial_rad=np.array([0.3, 0.0, 0.0]), time_constant_s=0.01)
    faults = [Fault("short", servo_id=1, n_bytes=2, address=PRESENT_POSITION, count=1)]
    virtual, bus = rig(plant, faults=faults)
    setup = bring_up(bus, JointMap(), MODELS, _ramp((0.4, 0.1, 0.0), q_start=(0.3, 0, 0)))
    true_tick = JointMap().to_ticks(np.array([0.3, 0.0, 0.0]))[0]
    assert setup.present_ticks[0] == true_tick
    assert virtual.servos[1].get(Register.GOAL_POSITION) == true_tick
    assert all(_torque(virtual))
    assert bus.failed_tries == 1


def test_empty_sync_read_reply_for_one_servo_never_becomes_a_goal(rig, tmp_path):
    # The case: with plain sync read an empty reply read as tick 0 and the
    # first goal sent that servo to -180 deg. Now: a comm error, then a safe stop.
    trajectory = _ramp((0.2, 0.1, 0.0))
    faults = [Fault("short", servo_id=2, address=PRESENT_BLOCK)]
    virtual, bus = rig(faults=faults, fast_sync_read=False)
    bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(bus, JointMap(), telemetry=tmp_path / "t.csv", fast_read=False)
    with pytest.raises(CommError, match=r"servo 2: reply of length 4 \(LEN field\), expected 14"):
        streamer.run(trajectory)
    assert virtual.frames_received == 0  # no goal went out
    assert virtual.servos[2].get(Register.GOAL_POSITION) == 2048
    assert all(_torque(virtual))  # holding where they were
    assert "servo 2: reply of length 4" in streamer.stats.fault


def test_wrong_id_in_fast_sync_read_mid_stream_stops_safely(rig, tmp_path):
    trajectory = _ramp((0.2, 0.1, 0.0), duration_s=0.5)
    faults = [Fault("wrong_id", servo_id=2, address=PRESENT_BLOCK, at_frame=20)]
    virtual, bus = rig(faults=faults)
    bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(bus, JointMap(), telemetry=tmp_path / "t.csv", on_stop="torque_off")
    with pytest.raises(CommError, match=r"reply part 1 from id 3, expected 2"):
        streamer.run(trajectory)
    assert virtual.frames_received == 20  # the read after frame 20 failed: nothing after it
    assert not any(_torque(virtual))
    with open(tmp_path / "t.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 20 and rows[-1]["position_rad_tilt"] == ""  # not read: empty, never 0


def test_present_position_far_from_the_first_frame_is_refused(rig):
    plant = FirstOrderPlant(initial_rad=np.array([0.0, 1.0, 0.0]))
    virtual, bus = rig(plant)
    before = _memory(virtual)
    with pytest.raises(
        BringUpError,
        match=r"tilt is at 57\.3 deg, 57\.3 deg from the plan's first frame \(0\.0 deg\); "
        r"more than the 45\.0 deg allowed",
    ):
        bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.1, 0.0)))
    assert _memory(virtual) == before


def test_streamer_checks_present_position_against_the_first_frame(rig):
    trajectory = _ramp((0.3, 0.0, 0.0), q_start=(0.2, 0.0, 0.0))
    virtual, bus = rig()
    bring_up(bus, JointMap(), MODELS, trajectory)  # 0.2 rad away: within 45 deg
    streamer = Streamer(bus, JointMap(), max_approach_rad=0.1)
    with pytest.raises(BringUpError, match=r"pan is at 0\.0 deg, 11\.5 deg from the plan's first"):
        streamer.run(trajectory)
    assert virtual.frames_received == 0


# -- 2. installed position limits and Drive Mode -----------------------------


def test_plan_leaving_installed_limits_is_refused_before_any_change(rig):
    # Tilt limited to 1800..2300 (-21.8..22.1 deg); the plan goes to 30 deg at t = 0.3 s.
    limits = {Register.MIN_POSITION_LIMIT: 1800, Register.MAX_POSITION_LIMIT: 2300}
    virtual, bus = rig(registers={2: limits, 1: {Register.TORQUE_ENABLE: 1}})
    before = _memory(virtual)
    with pytest.raises(
        BringUpError,
        match=r"tilt leaves its position limits at t = 0\.\d+ s: 2[2-9]\.\d deg \(tick 23\d\d\) "
        r"is past the Max Position Limit 2300 \(22\.1 deg\) of servo 2; change the plan, or "
        r"change the limits with --set-limits; refusing to stream",
    ):
        bring_up(bus, JointMap(), MODELS, _ramp((0.0, math.radians(30), 0.0)))
    assert _memory(virtual) == before  # limits, torque (servo 1 still on), everything
    assert _torque(virtual) == [True, False, False]


def test_limits_and_drive_mode_are_kept_and_guard_the_stream(rig):
    # Reverse direction (Drive Mode bit 0) and narrow limits on tilt, as installed.
    installed = {
        Register.MIN_POSITION_LIMIT: 1800,
        Register.MAX_POSITION_LIMIT: 2300,
        Register.DRIVE_MODE: 1,
    }
    trajectory = _ramp((0.2, math.radians(20), 0.0))
    virtual, bus = rig(registers={2: installed})
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    tilt = virtual.servos[2]
    assert (tilt.get(Register.MIN_POSITION_LIMIT), tilt.get(Register.MAX_POSITION_LIMIT)) == (
        1800,
        2300,
    )
    assert tilt.get(Register.DRIVE_MODE) == 1
    assert virtual.servos[1].get(Register.DRIVE_MODE) == 0
    np.testing.assert_array_equal(setup.goal_bounds_ticks[1], [1800, 2300])
    # A frame source that leaves the limits mid-stream (e.g. online) is stopped before it.
    frames = list(trajectory) + list(_ramp((0.2, math.radians(40), 0.0), q_start=(0.2, 0.35, 0)))
    streamer = Streamer(bus, JointMap(), goal_bounds_ticks=setup.goal_bounds_ticks)
    with pytest.raises(
        OutsideLimits, match=r"tilt: goal tick 23\d\d at t = .* is outside 1800\.\.2300 .*; not"
    ):
        streamer.run(frames, rate_hz=RATE_HZ)
    assert max(goal[1] for goal in virtual.goal_log) <= 2300


def test_set_limits_is_the_only_way_to_change_them(rig):
    limits = {Register.MIN_POSITION_LIMIT: 1800, Register.MAX_POSITION_LIMIT: 2300}
    virtual, bus = rig(registers={2: limits})
    trajectory = _ramp((0.0, math.radians(30), 0.0))
    bring_up(bus, JointMap(), MODELS, trajectory, set_limits={2: (1500, 2800)})
    tilt = virtual.servos[2]
    assert tilt.get(Register.MIN_POSITION_LIMIT) == 1500
    assert tilt.get(Register.MAX_POSITION_LIMIT) == 2800
    assert virtual.servos[1].get(Register.MAX_POSITION_LIMIT) == 4095  # untouched
    with pytest.raises(ValueError, match=r"Expected `set_limits` .* got 2: \(100, 5000\)"):
        bring_up(bus, JointMap(), MODELS, trajectory, set_limits={2: (100, 5000)})


def test_time_based_profile_is_refused_and_drive_mode_never_written(rig):
    virtual, bus = rig(registers={3: {Register.DRIVE_MODE: 0x05}})
    before = _memory(virtual)
    with pytest.raises(
        BringUpError, match=r"servo 3 \(roll\): Drive Mode 0x05 selects the time-based profile"
    ):
        bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.1, 0.0)))
    assert _memory(virtual) == before


def test_multi_turn_joint_with_installed_limits_is_refused(rig):
    plant = FirstOrderPlant(initial_rad=np.array([3.0, 0.0, 0.0]))
    limits = {Register.MIN_POSITION_LIMIT: 100, Register.MAX_POSITION_LIMIT: 4000}
    virtual, bus = rig(plant, registers={1: limits})
    with pytest.raises(BringUpError, match=r"pan needs more than one turn .* servo 1 has limits"):
        bring_up(bus, JointMap(), MODELS, _ramp((3.5, 0.0, 0.0), q_start=(3.0, 0, 0)))
    assert virtual.servos[1].get(Register.OPERATING_MODE) == 3


# -- 3. stalls ----------------------------------------------------------------


def _stalling(trajectory, stalls):
    """The trajectory's frames, the host pausing ``stalls[k]`` s before frame k."""
    for frame in trajectory:
        time.sleep(stalls.get(frame.index, 0.0))
        yield frame


def _sent_intervals(path):
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["phase"] == "stream"]
    return np.diff([float(r["sent_s"]) for r in rows])


def test_stall_shifts_the_stream_instead_of_replaying_it(rig, tmp_path):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=0.5)
    virtual, bus = rig()
    bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(bus, JointMap(), telemetry=tmp_path / "t.csv")
    stats = streamer.run(_stalling(trajectory, {30: 0.08}), rate_hz=RATE_HZ)
    assert stats.frames_sent == len(trajectory)
    # The pause began after frame 29 went out and was read back (< one period).
    assert stats.stalls >= 1 and stats.stall_max_s >= 0.08 - 1 / RATE_HZ
    assert stats.delay_s >= 0.08 - 1 / RATE_HZ
    # Never two goals closer than half a period: no burst after the stall.
    intervals = _sent_intervals(tmp_path / "t.csv")
    assert intervals.min() >= 0.5 / RATE_HZ
    assert intervals.max() >= 0.08 - 1 / RATE_HZ
    goals = JointMap().to_rad(np.array(list(virtual.goal_log)))
    np.testing.assert_allclose(goals, trajectory.q, atol=2 * math.pi / 4096)
    assert "stalls: " in stats.format() and "behind its plan" in stats.format()


def test_stall_longer_than_the_watchdog_stops_before_the_next_goal(rig):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=0.5)
    virtual, bus = rig()
    bring_up(bus, JointMap(), MODELS, trajectory, watchdog_s=0.1)
    streamer = Streamer(bus, JointMap())
    with pytest.raises(
        WatchdogTripped, match=r"tripped .* after a \d+\.\d ms stall, before frame 30"
    ):
        streamer.run(_stalling(trajectory, {30: 0.2}), rate_hz=RATE_HZ)
    assert virtual.frames_received == 30
    assert streamer.stats.stalls >= 1 and streamer.stats.stall_max_s >= 0.2 - 1 / RATE_HZ


def test_lateness_past_the_bound_fails_the_stream(rig):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=1.0)
    virtual, bus = rig()
    bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(bus, JointMap(), max_delay_s=0.1, on_stop="torque_off")
    stalls = {k: 0.03 for k in range(10, len(trajectory), 10)}
    with pytest.raises(
        StreamLagging, match=r"the stream fell 0\.1\d\d s behind its plan \(bound 0\.1 s\)"
    ):
        streamer.run(_stalling(trajectory, stalls), rate_hz=RATE_HZ)
    assert streamer.stats.stalls >= 4
    assert virtual.frames_received < len(trajectory)
    assert not any(_torque(virtual))


# -- 5. bring-up checks every servo before changing any -----------------------


def test_latched_error_on_one_servo_leaves_the_healthy_ones_untouched(rig):
    registers = {
        1: {Register.TORQUE_ENABLE: 1},
        2: {Register.TORQUE_ENABLE: 1},
        3: {Register.HARDWARE_ERROR_STATUS: 0x20},
    }
    virtual, bus = rig(registers=registers)
    before = _memory(virtual)
    with pytest.raises(ServoError, match=r"servo 3: hardware error .*: overload"):
        bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.1, 0.0)))
    assert _torque(virtual) == [True, True, False]  # not left limp
    assert _memory(virtual) == before


# -- 6. constant memory -------------------------------------------------------


def test_running_quantiles_match_numpy(rng):
    values = rng.lognormal(mean=-9, sigma=1.5, size=20_000)
    running = RunningQuantiles()
    for v in values:
        running.add(float(v))
    for q in (0.5, 0.99):
        assert running.quantile(q) == pytest.approx(np.quantile(values, q), rel=0.025)
    assert running.max == values.max()
    assert math.isnan(RunningQuantiles().quantile(0.5))


def test_goal_log_is_bounded(rig):
    virtual, bus = rig(goal_log_size=10)
    bus.add_servo(1, virtual.servos[1].model)
    for tick in range(2000, 2050):
        bus.sync_write(Register.GOAL_POSITION, {1: tick})
    bus.read(1, Register.GOAL_POSITION)  # the bus has handled every packet before this reply
    assert virtual.frames_received == 50
    assert 10 <= len(virtual.goal_log) < 20 and virtual.goal_log[-1][0] == 2049


def test_present_position_outside_the_limits_is_refused_before_any_change(rig):
    plant = FirstOrderPlant(initial_rad=np.array([0.0, 0.5, 0.0]))  # tilt at tick 2374
    limits = {Register.MIN_POSITION_LIMIT: 1800, Register.MAX_POSITION_LIMIT: 2300}
    virtual, bus = rig(plant, registers={2: limits})
    before = _memory(virtual)
    with pytest.raises(
        BringUpError,
        match=r"servo 2 \(tilt\) reads Present Position 2374 \(28\.7 deg\), outside its "
        r"position limits 1800\.\.2300",
    ):
        bring_up(bus, JointMap(), MODELS, _ramp((0.0, 0.3, 0.0), q_start=(0.0, 0.3, 0.0)))
    assert _memory(virtual) == before


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (
            {"max_delay_s": 0},
            ValueError,
            r"Expected `max_delay_s` to be a finite number > 0, got 0",
        ),
        ({"stall_s": -1.0}, ValueError, r"Expected `stall_s` to be a finite number > 0, got -1"),
        ({"max_approach_rad": "1"}, TypeError, r"Expected `max_approach_rad` to be a finite"),
        (
            {"goal_bounds_ticks": [[0, 4095]]},
            ValueError,
            r"Expected `goal_bounds_ticks` of shape \(3, 2\), got \(1, 2\)",
        ),
    ],
)
def test_streamer_safety_options_are_checked(rig, kwargs, error, match):
    _, bus = rig()
    with pytest.raises(error, match=match):
        Streamer(bus, JointMap(), **kwargs)


def test_reply_faults_name_their_servo():
    with pytest.raises(ValueError, match=r"Expected a `servo_id` for a short fault, got None"):
        Fault("short")
