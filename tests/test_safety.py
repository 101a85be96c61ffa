"""Issue 7 on the virtual bus: bad replies, installed settings, stalls, signals, bring-up order.

Each test injects one fault and asserts what reached the servos (goals, writes
to the limit registers, torque) and what the caller was told.
"""

import csv
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from trajgen.drivers.bringup import bring_up, read_position_checked
from trajgen.drivers.clock import SimulatedClock
from trajgen.drivers.control_table import Register, model_named
from trajgen.drivers.errors import (
    BringUpError,
    CommError,
    OutsideLimits,
    ServoError,
    ServoReset,
    StreamLagging,
    WatchdogTripped,
)
from trajgen.drivers.outcome import servo_outcomes
from trajgen.drivers.streamer import RunningQuantiles, Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import Fault, VirtualBus
from trajgen.drivers.virtual.clocked import ClockedBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.stream import JointTrajectory

RATE_HZ = 200.0
MODEL_XM430 = model_named("XM430-W350")
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
    """make(plant, clock, **VirtualBus options) -> (virtual bus, open ServoBus), closed after
    the test: lock-step, or with a ``clock`` a ``ClockedBus`` on it."""
    made = []

    def make(plant=None, clock=None, **kwargs):
        plant = plant or FirstOrderPlant(time_constant_s=0.01)
        if clock is None:
            kwargs.setdefault("lockstep_dt_s", 1 / RATE_HZ)
            virtual = VirtualBus(plant, **kwargs).start()
        else:  # the host's simulated clock is the servos' time too
            virtual = ClockedBus(plant, clock=clock, **kwargs).start()
        bus = virtual.connect().open()  # answered in this thread
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


def test_a_chain_at_another_baud_rate_is_refused_naming_the_rate(rig):
    """Servos at 57,600 bit/s hear a 1 Mbps host as noise: nothing answers, nothing moves,
    and the message names the rate the port ran at and the baud rate as a cause."""
    virtual, bus = rig(baud=57_600)
    assert bus.baud == 1_000_000
    before = _memory(virtual)
    with pytest.raises(
        BringUpError,
        match=r"servo 1: no reply to ping at 1000000 baud on .*check id, baud rate, power",
    ):
        bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.0, 0.0)))
    assert _memory(virtual) == before
    assert virtual.frames_received == 0 and not any(_torque(virtual))


def test_a_chain_at_the_ports_baud_rate_is_brought_up(rig):
    """The control for the test above: the same chain at the port's rate answers."""
    virtual, bus = rig(baud=1_000_000)
    bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.0, 0.0)))
    assert all(s.get("Baud Rate") == 3 for s in virtual.servos.values())


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
    streamer = Streamer(
        bus, JointMap(), goal_bounds_ticks=setup.goal_bounds_ticks, clock=SimulatedClock()
    )
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


def _stalling(trajectory, clock, stalls):
    """The trajectory's frames, the host stalling ``stalls[k]`` s before frame k.

    A stall is simulated time: ``clock`` (the streamer's, and the ``ClockedBus``'s)
    moves on with no packet sent, so the servos see the silence and the streamer
    finds the frame late, whatever the machine's load."""
    for frame in trajectory:
        clock.time_s += stalls.get(frame.index, 0.0)
        yield frame


def _sent_intervals(path):
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["phase"] == "stream"]
    return np.diff([float(r["sent_s"]) for r in rows])


def test_stall_shifts_the_stream_instead_of_replaying_it(rig, tmp_path):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=0.5)
    clock = SimulatedClock()
    virtual, bus = rig(clock=clock)
    bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(bus, JointMap(), telemetry=tmp_path / "t.csv", clock=clock)
    stats = streamer.run(_stalling(trajectory, clock, {30: 0.08}), rate_hz=RATE_HZ)
    assert stats.frames_sent == len(trajectory)
    # The pause began after frame 29 went out at its deadline: frame 30 is 75 ms late,
    # the only stall, and the rest of the stream is shifted by it.
    assert stats.stalls == 1
    assert stats.stall_max_s == pytest.approx(0.08 - 1 / RATE_HZ)
    assert stats.delay_s == pytest.approx(0.08 - 1 / RATE_HZ)
    # No burst after the stall: every goal a period after the last but the one 80 ms on.
    intervals = _sent_intervals(tmp_path / "t.csv")
    assert np.sum(np.abs(intervals - 1 / RATE_HZ) > 1e-9) == 1
    assert intervals[29] == pytest.approx(0.08)
    goals = JointMap().to_rad(np.array(list(virtual.goal_log)))
    np.testing.assert_allclose(goals, trajectory.q, atol=2 * math.pi / 4096)
    assert "stalls: " in stats.format() and "behind its plan" in stats.format()
    # The stalled frame's reply came in late too; the report is JSON (`--json`).
    assert json.loads(json.dumps(stats.to_json_dict()))["reply_stalls"] == 1


def test_a_stall_report_is_json_when_frame_times_are_numpy_floats(rig):
    """Frame times of an online plan may be numpy floats: the stall counts stay ints."""
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=0.2)
    clock = SimulatedClock()
    virtual, bus = rig(clock=clock)
    bring_up(bus, JointMap(), MODELS, trajectory)
    frames = (replace(f, t=np.float64(f.t)) for f in _stalling(trajectory, clock, {10: 0.08}))
    stats = Streamer(bus, JointMap(), clock=clock).run(frames, rate_hz=RATE_HZ)
    assert stats.stalls == 1
    assert json.loads(json.dumps(stats.to_json_dict()))["reply_stalls"] == 1


def test_stall_longer_than_the_watchdog_stops_before_the_next_goal(rig):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=0.5)
    clock = SimulatedClock()
    virtual, bus = rig(clock=clock)
    bring_up(bus, JointMap(), MODELS, trajectory, watchdog_s=0.1)
    streamer = Streamer(bus, JointMap(), clock=clock)
    with pytest.raises(
        WatchdogTripped, match=r"tripped .* after a 195\.0 ms stall, before frame 30"
    ):
        streamer.run(_stalling(trajectory, clock, {30: 0.2}), rate_hz=RATE_HZ)
    assert virtual.frames_received == 30
    assert streamer.stats.stalls == 1
    assert streamer.stats.stall_max_s == pytest.approx(0.2 - 1 / RATE_HZ)


def test_a_stall_shorter_than_the_watchdog_trips_nothing(rig):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=0.5)
    clock = SimulatedClock()
    virtual, bus = rig(clock=clock)
    bring_up(bus, JointMap(), MODELS, trajectory, watchdog_s=0.1)
    stats = Streamer(bus, JointMap(), clock=clock).run(
        _stalling(trajectory, clock, {30: 0.09}), rate_hz=RATE_HZ
    )
    assert stats.frames_sent == len(trajectory) and stats.stalls == 1
    # The safe stop at the end cleared the watchdogs (0), which had not tripped (-1).
    assert all(s.get(Register.BUS_WATCHDOG) == 0 for s in virtual.servos.values())


def test_lateness_past_the_bound_fails_the_stream(rig):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=1.0)
    clock = SimulatedClock()
    virtual, bus = rig(clock=clock)
    bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(bus, JointMap(), max_delay_s=0.1, on_stop="torque_off", clock=clock)
    stalls = {k: 0.03 for k in range(10, len(trajectory), 10)}
    # Each stall puts the stream 25 ms behind; the fifth passes the bound.
    with pytest.raises(
        StreamLagging, match=r"the stream fell 0\.125 s behind its plan \(bound 0\.1 s\) after 5 "
    ):
        streamer.run(_stalling(trajectory, clock, stalls), rate_hz=RATE_HZ)
    assert streamer.stats.stalls == 5
    assert virtual.frames_received == 50 < len(trajectory)
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


# -- issue 21: settings, ids, reboots, glitches, a second program, power -------

EEPROM = slice(0, 64)


def _eeprom(virtual):
    return {i: bytes(s.memory[EEPROM]) for i, s in virtual.servos.items()}


def _streamer(bus, setup, **kwargs):
    """A streamer wired as the session wires it, on simulated time (no wall-clock limits)."""
    return Streamer(
        bus,
        JointMap(),
        goal_bounds_ticks=setup.goal_bounds_ticks,
        start_ticks=setup.present_ticks,
        power_limits=setup.power_limits,
        clock=SimulatedClock(),
        **kwargs,
    )


def _refused(virtual, bus, match, **options):
    """Bring-up of a small plan is refused with ``match`` and nothing is written."""
    before = _memory(virtual)
    with pytest.raises(BringUpError, match=match):
        bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.1, 0.0)), **options)
    assert _memory(virtual) == before


@pytest.mark.parametrize(
    ("mode", "name"), [(1, "velocity control"), (0, "current control"), (16, "PWM control")]
)
def test_a_mode_that_cannot_stream_is_refused_naming_servo_register_value(rig, mode, name):
    virtual, bus = rig(registers={2: {Register.OPERATING_MODE: mode}})
    _refused(
        virtual,
        bus,
        rf"servo 2 \(tilt\): Operating Mode \(register 11\) is {mode} \({name}\), which "
        r"cannot stream this plan .*pass --configure \(or \[bus\] configure = true\)",
    )


def test_extended_and_current_based_position_modes_stream_as_installed(rig):
    registers = {
        1: {Register.OPERATING_MODE: 4, Register.RETURN_DELAY_TIME: 254},
        2: {Register.OPERATING_MODE: 5},
    }
    virtual, bus = rig(registers=registers)
    before = _eeprom(virtual)
    with pytest.warns(
        RuntimeWarning, match=r"Return Delay Time \(register 9\) kept on servo 1: 254 \(508 us\)"
    ):
        setup = bring_up(bus, JointMap(), MODELS, _ramp((0.2, 0.1, 0.0)))
    assert setup.operating_modes == (4, 5, 3)
    assert _eeprom(virtual) == before  # no EEPROM byte written: mode and delay kept
    assert {c.register for c in setup.changes} == {Register.BUS_WATCHDOG}
    stats = _streamer(bus, setup).run(_ramp((0.2, 0.1, 0.0)))
    assert stats.frames_sent == 61 and all(_torque(virtual))


def test_configure_says_what_it_changes_keeps_the_gains_and_restore_writes_it_back(rig):
    installed = {
        Register.OPERATING_MODE: 1,
        Register.RETURN_DELAY_TIME: 254,
        Register.TORQUE_ENABLE: 1,
        "Position P Gain": 600,
        "Profile Velocity": 50,
    }
    virtual, bus = rig(registers={1: installed})
    trajectory = _ramp((0.2, 0.1, 0.0))
    with pytest.warns(RuntimeWarning) as said:
        setup = bring_up(bus, JointMap(), MODELS, trajectory, configure=True)
    messages = [str(w.message) for w in said]
    assert any(
        m.startswith("bring-up changes servo 1 (pan): Operating Mode 1 -> 3 (EEPROM)")
        for m in messages
    )
    assert any("Return Delay Time 254 -> 0 (EEPROM)" in m for m in messages)
    assert any("Profile Velocity 50 -> 0 (RAM)" in m for m in messages)
    assert any(
        m.startswith("servo 1 (pan): torque off for the EEPROM write of Operating Mode")
        for m in messages
    )
    pan = virtual.servos[1]
    assert pan.get(Register.OPERATING_MODE) == 3 and pan.get(Register.RETURN_DELAY_TIME) == 0
    assert pan.get("Position P Gain") == 600  # the mode change reset it; written back
    assert pan.torque_on
    streamer = _streamer(bus, setup, on_stop="torque_off", restore=setup.changes)
    streamer.run(trajectory)
    assert streamer.stop_errors == []
    assert pan.get(Register.OPERATING_MODE) == 1
    assert pan.get(Register.RETURN_DELAY_TIME) == 254
    assert pan.get("Position P Gain") == 600 and pan.get("Profile Velocity") == 50


def test_restore_while_holding_leaves_eeprom_and_says_so(rig):
    virtual, bus = rig(registers={1: {Register.RETURN_DELAY_TIME: 254}})
    trajectory = _ramp((0.2, 0.1, 0.0))
    setup = bring_up(bus, JointMap(), MODELS, trajectory, configure=True)
    streamer = _streamer(bus, setup, restore=setup.changes)
    streamer.run(trajectory)
    assert len(streamer.stop_errors) == 3  # every servo's Return Delay Time
    assert (
        "servo 1 (pan): Return Delay Time not restored to 254 (left at 0): EEPROM is written "
        "only with torque off, and the servo holds its goal (stop with torque off to restore it)"
    ) in streamer.stop_errors
    assert virtual.servos[1].get(Register.RETURN_DELAY_TIME) == 0
    assert all(_torque(virtual))  # holding: never released to restore


class _Loaded(FirstOrderPlant):
    """A plant whose servos draw 0.5 A holding (a load against gravity)."""

    def read(self):
        q, qd, current = super().read()
        return q, qd, current + 0.5 * self._torque


def test_a_loaded_servo_is_never_released_for_an_eeprom_write(rig):
    registers = {1: {Register.OPERATING_MODE: 1, Register.TORQUE_ENABLE: 1}}
    virtual, bus = rig(_Loaded(time_constant_s=0.01), registers=registers)
    _refused(
        virtual,
        bus,
        r"servo 1 \(pan\) holds a load \(torque on, Present Current 0\.50 A\): writing "
        r"Operating Mode, Return Delay Time \(EEPROM\) needs torque off, which would let it drop",
        configure=True,
    )
    assert virtual.servos[1].torque_on


def test_secondary_id_of_another_streamed_servo_is_refused_before_any_write(rig):
    virtual, bus = rig(registers={1: {"Secondary(Shadow) ID": 3}})
    _refused(
        virtual,
        bus,
        r"servo 1 \(pan\): Secondary ID \(register 12\) is 3, the id of servo 3 \(roll\): "
        r"it would execute every write meant for servo 3",
    )


def test_the_virtual_servo_acts_on_its_secondary_id_without_answering(rig):
    virtual, bus = rig(registers={1: {"Secondary(Shadow) ID": 3}})
    bus.add_servo(3, virtual.servos[3].model)
    bus.write(3, Register.GOAL_POSITION, 2100)  # one reply: from servo 3 only
    assert [virtual.servos[i].get(Register.GOAL_POSITION) for i in (1, 2, 3)] == [2100, 2048, 2100]


@pytest.mark.parametrize(
    ("level", "match"),
    [
        (1, r"servo 2 \(tilt\): Status Return Level \(register 68\) is 1: it does not acknowledge"),
        (0, r"servo 2 answers ping but not a read .*Status Return Level \(register 68\) is "),
    ],
)
def test_status_return_level_below_2_is_named(rig, level, match):
    virtual, bus = rig(registers={2: {Register.STATUS_RETURN_LEVEL: level}})
    _refused(virtual, bus, match)
    outcome = servo_outcomes(bus, JointMap())
    assert [o.state for o in outcome] == ["never torqued"] * 3 or level == 0
    if level == 0:
        assert outcome[1].state == "unknown"
        assert "answers ping but not reads: its Status Return Level" in outcome[1].detail


def test_two_servos_on_one_id_are_named(rig):
    # The third servo was given id 1 too, and sits elsewhere: their replies collide.
    plant = FirstOrderPlant(initial_rad=np.array([0.0, 0.0, 0.3]))
    virtual, bus = rig(plant, registers={3: {"ID": 1}})
    joints = JointMap((1, 2), (1, 1), (2048, 2048))
    with pytest.raises(BringUpError, match=r"servo 1: .*as when two servos share this id"):
        bring_up(bus, joints, MODELS[:2], _ramp((0.2, 0.1), q_start=(0.0, 0.0)))


def test_a_reboot_mid_stream_is_noticed_within_a_poll_and_named(rig):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=1.0)
    virtual, bus = rig(faults=[Fault("reboot", servo_id=2, at_frame=80)])
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = _streamer(bus, setup)  # poll_s 0.05: every 10 frames at 200 Hz
    with pytest.raises(
        ServoReset,
        match=r"servo 2 \(tilt\) reset itself before frame \d+: Torque Enable 0 \(was 1\), Bus "
        r"Watchdog 0 \(was 5\): it rebooted",
    ):
        streamer.run(trajectory)
    assert 80 <= virtual.frames_received <= 80 + 10
    states = [o.state for o in servo_outcomes(bus, JointMap())]
    assert states == ["holding", "off by itself", "holding"]


def test_one_glitched_position_read_in_bring_up_never_becomes_a_goal(rig):
    plant = FirstOrderPlant(initial_rad=np.array([0.3, 0.0, 0.0]), time_constant_s=0.01)
    glitch = Fault("glitch", servo_id=1, address=PRESENT_POSITION, offset_ticks=228, count=1)
    virtual, bus = rig(plant, faults=[glitch])
    setup = bring_up(bus, JointMap(), MODELS, _ramp((0.4, 0.1, 0.0), q_start=(0.3, 0, 0)))
    true_tick = JointMap().to_ticks(np.array([0.3, 0.0, 0.0]))[0]
    assert setup.installed[0].present == true_tick
    assert setup.present_ticks[0] == true_tick
    assert virtual.servos[1].get(Register.GOAL_POSITION) == true_tick


class _Flickering:
    """A bus whose Present Position alternates between two values 30 deg apart."""

    def __init__(self):
        self.models = {1: MODEL_XM430}
        self.reads = 0

    def read(self, servo_id, register):
        self.reads += 1
        return 2048 + 342 * (self.reads % 2)


def test_a_position_that_never_reads_twice_the_same_is_refused():
    with pytest.raises(
        BringUpError,
        match=r"servo 1: Present Position reads 2390, 2048, 2390, 2048: no two reads in a row "
        r"agree .*; refusing to use it as a goal",
    ):
        read_position_checked(_Flickering(), 1)


def test_a_glitched_first_read_of_the_streamer_never_becomes_a_goal(rig):
    trajectory = _ramp((0.2, 0.1, 0.0))
    glitch = Fault("glitch", servo_id=1, address=PRESENT_BLOCK, offset_ticks=228, count=1)
    virtual, bus = rig(faults=[glitch])
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    _streamer(bus, setup).run(trajectory)
    first = virtual.goal_log[0]
    assert abs(first[0] - 2048) <= 1  # started from the goal held at torque on, not 20 deg off


def test_a_180_deg_jump_mid_stream_is_flagged_and_kept_out_of_the_telemetry(rig, tmp_path):
    trajectory = _ramp((0.2, 0.1, 0.0))
    glitch = Fault(
        "glitch", servo_id=2, address=PRESENT_BLOCK, offset_ticks=2048, at_frame=30, count=1
    )
    virtual, bus = rig(faults=[glitch])
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = _streamer(bus, setup, telemetry=tmp_path / "t.csv")
    with pytest.warns(
        RuntimeWarning,
        match=r"servo 2 \(tilt\): Present Position jumped \+180\.\d deg in one read at frame 30",
    ):
        stats = streamer.run(trajectory)
    assert stats.position_glitches == 1 and stats.frames_sent == len(trajectory)
    with open(tmp_path / "t.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    tilt = [r["position_rad_tilt"] for r in rows]
    assert tilt.count("") == 1 and max(abs(float(v)) for v in tilt if v) < 0.2


def test_a_position_glitching_on_every_read_stops_the_stream(rig):
    trajectory = _ramp((0.2, 0.1, 0.0))
    glitch = Fault("glitch", servo_id=3, address=PRESENT_BLOCK, offset_ticks=900, at_frame=20)
    virtual, bus = rig(faults=[glitch])
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    with (
        pytest.warns(RuntimeWarning, match="jumped"),
        pytest.raises(ServoError, match=r"servo 3 \(roll\): Present Position implausible 3 reads"),
    ):
        _streamer(bus, setup).run(trajectory)


def test_heat_is_read_warned_and_stops_the_stream_before_the_servo_shuts_down(rig, tmp_path):
    trajectory = _ramp((0.2, 0.1, 0.0), duration_s=2.0)
    faults = [
        Fault("set", servo_id=2, register="Present Temperature", value=72, at_frame=100),
        Fault("set", servo_id=2, register="Present Temperature", value=78, at_frame=250),
    ]
    virtual, bus = rig(faults=faults)
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = _streamer(bus, setup, telemetry=tmp_path / "t.csv")
    with (
        pytest.warns(RuntimeWarning, match=r"servo 2 \(tilt\): temperature 72 deg C, within 10"),
        pytest.raises(
            ServoError,
            match=r"servo 2 \(tilt\): temperature 78 deg C, within 3 deg C of its Temperature "
            r"Limit 80 deg C \(where it shuts down\)",
        ),
    ):
        streamer.run(trajectory)
    assert 250 <= virtual.frames_received <= 250 + 100  # health_s 0.5: every 100 frames
    assert virtual.servos[2].torque_on  # stopped while it still obeys: holding
    with open(tmp_path / "t.csv", newline="") as f:
        temps = [r["temperature_c_tilt"] for r in csv.DictReader(f)]
    assert "30.0" in temps and "72.0" in temps


def test_a_supply_under_the_min_voltage_limit_is_refused_at_bring_up(rig):
    registers = {2: {"Present Input Voltage": 85, "Min Voltage Limit": 95}}
    virtual, bus = rig(registers=registers)
    _refused(
        virtual,
        bus,
        r"servo 2 \(tilt\): input voltage 8\.5 V, at or under its Min Voltage Limit 9\.5",
    )


def test_outcome_names_each_servos_state(rig):
    trajectory = _ramp((0.2, 0.1, 0.0))
    virtual, bus = rig(registers={3: {Register.TORQUE_ENABLE: 1}})
    bus.add_servo(3, virtual.servos[3].model)
    for i in (1, 2):
        bus.add_servo(i, virtual.servos[i].model)
    states = servo_outcomes(bus, JointMap())
    assert [o.state for o in states] == ["never torqued", "never torqued", "untouched"]
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    _streamer(bus, setup).run(trajectory)
    bus.write(1, Register.TORQUE_ENABLE, 0)
    states = servo_outcomes(bus, JointMap())
    assert [o.state for o in states] == ["released", "holding", "holding"]
    assert states[1].format() == "tilt (servo 2): torque on, holding its goal 5.7 deg"
    assert states[0].to_json_dict()["goal_deg"] is None


# -- issue 21: what already worked still works ---------------------------------


def test_homing_offset_is_a_zero_in_the_joint_map(rig):
    trajectory = _ramp((0.2, 0.1, 0.0))
    virtual, bus = rig(registers={2: {"Homing Offset": 100}})
    joints = JointMap(zeros=(2048, 2148, 2048))
    setup = bring_up(bus, joints, MODELS, trajectory)
    stats = Streamer(bus, joints, start_ticks=setup.present_ticks, clock=SimulatedClock()).run(
        trajectory
    )
    assert stats.frames_sent == len(trajectory)
    np.testing.assert_array_equal(
        virtual.goal_log[-len(trajectory) :], joints.to_ticks(trajectory.q)
    )
    assert virtual.servos[2].get("Homing Offset") == 100


def test_an_extra_servo_on_the_bus_is_left_alone(rig):
    plant = FirstOrderPlant(n_joints=4, time_constant_s=0.01)
    virtual, bus = rig(plant, ids=(1, 2, 3, 4))
    before = bytes(virtual.servos[4].memory[WRITABLE])
    trajectory = _ramp((0.2, 0.1, 0.0))
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    _streamer(bus, setup).run(trajectory)
    assert bytes(virtual.servos[4].memory[WRITABLE]) == before
    assert not virtual.servos[4].torque_on


@pytest.mark.parametrize(("beyond", "ok"), [(0, True), (1, False)], ids=["exact", "off-by-one"])
def test_a_plan_to_exactly_the_limit_streams_and_one_tick_beyond_is_refused(rig, beyond, ok):
    limits = {Register.MIN_POSITION_LIMIT: 1800, Register.MAX_POSITION_LIMIT: 2300}
    virtual, bus = rig(registers={2: limits})
    tilt = (2300 + beyond - 2048) * 2 * math.pi / 4096
    trajectory = _ramp((0.0, tilt, 0.0))
    assert JointMap().to_ticks(trajectory.q)[:, 1].max() == 2300 + beyond
    if not ok:
        with pytest.raises(BringUpError, match=r"tick 2301\) is past the Max Position Limit 2300"):
            bring_up(bus, JointMap(), MODELS, trajectory)
        return
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    _streamer(bus, setup).run(trajectory)
    assert max(goal[1] for goal in virtual.goal_log) == 2300


def test_overheating_mid_stream_stops_naming_it(rig):
    trajectory = _ramp((0.2, 0.1, 0.0))
    fault = Fault("set", servo_id=2, register="Hardware Error Status", value=0x04, at_frame=30)
    virtual, bus = rig(faults=[fault])
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    with pytest.raises(ServoError, match=r"servo 2: hardware error during streaming: overheating"):
        _streamer(bus, setup).run(trajectory)
    assert virtual.frames_received == 30


def test_a_slow_reboot_within_the_retry_budget_is_still_noticed(rig):
    trajectory = _ramp((0.3, 0.2, 0.1), duration_s=1.0)
    faults = [
        Fault("reboot", servo_id=2, at_frame=50),
        Fault("drop", servo_id=2, at_frame=50, count=2),  # silent while it boots
    ]
    virtual, bus = rig(faults=faults)
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    with pytest.raises(ServoReset, match=r"servo 2 \(tilt\) reset itself"):
        _streamer(bus, setup).run(trajectory)
    assert bus.failed_tries == 2 and virtual.frames_received <= 50 + 10


def test_a_profile_in_progress_is_stopped_where_it_is_before_the_profile_goes(rig):
    # Torque on, moving slowly (a profile) towards a goal 30 deg away.
    plant = FirstOrderPlant(time_constant_s=5.0)
    installed = {Register.TORQUE_ENABLE: 1, "Profile Velocity": 20}
    virtual, bus = rig(plant, registers={1: installed})
    bus.add_servo(1, virtual.servos[1].model)
    bus.write(1, Register.GOAL_POSITION, 2390)  # what another program asked of it
    trajectory = _ramp((0.1, 0.0, 0.0))
    with pytest.warns(RuntimeWarning, match=r"servo 1: moving to Goal Position 2390 .*stopped"):
        setup = bring_up(bus, JointMap(), MODELS, trajectory)
    assert abs(setup.present_ticks[0] - 2048) <= 4  # where it was, not 30 deg on
    assert virtual.servos[1].get("Profile Velocity") == 0
    assert abs(virtual.servos[1].get(Register.GOAL_POSITION) - 2048) <= 4


def test_bus_table_configure_and_restore():
    from trajgen.drivers.config import bus_config_from_tables
    from trajgen.errors import KeyframeFileError

    config = bus_config_from_tables({"bus": {"configure": True, "restore": True}}, "f.toml")
    assert config.configure and config.restore
    assert not bus_config_from_tables({}, "f.toml").configure
    with pytest.raises(
        KeyframeFileError, match=r"f\.toml: \[bus\] restore: expected true or false"
    ):
        bus_config_from_tables({"bus": {"restore": 1}}, "f.toml")


def test_the_session_reads_back_each_servo_after_a_reboot(monkeypatch):
    from trajgen.drivers.config import BusConfig
    from trajgen.drivers.session import HOLDING, OFF_BY_ITSELF, Session

    faults = [Fault("reboot", servo_id=2, at_frame=60)]
    plant = FirstOrderPlant(time_constant_s=0.01)
    virtual = VirtualBus(plant, lockstep_dt_s=1 / RATE_HZ, faults=faults)
    # The session's own virtual bus, with the fault: answered in the stream's thread, so no
    # reply waits for a serving thread on a busy host.
    monkeypatch.setattr(Session, "_open_virtual", lambda self, rate_hz: virtual.start())
    session = Session(BusConfig(), plant=plant)
    path = _ramp((0.2, 0.1, 0.0), duration_s=1.0)
    outcome = session.run(lambda present: path, RATE_HZ, clock=SimulatedClock())
    assert "servo 2 (tilt) reset itself" in outcome.stopped_by
    assert outcome.servo_states == {1: HOLDING, 2: OFF_BY_ITSELF, 3: HOLDING}
    lines = [o.format() for o in outcome.servos]
    assert lines[1] == "tilt (servo 2): torque off by itself (it rebooted, lost power or shut down)"
    assert lines[0].startswith("pan (servo 1): torque on, holding its goal ")


def test_the_command_line_prints_each_servos_state(tmp_path, capsys):
    import argparse
    import json

    from trajgen.cli import stream

    path = tmp_path / "k.toml"
    path.write_text(
        "[stream]\nrate_hz = 100\n"
        "[[keyframes]]\nt = 0.0\npan = 0\n[[keyframes]]\nt = 0.3\npan = 5\n"
    )
    parser = argparse.ArgumentParser(prog="trajgen")
    stream.register(parser.add_subparsers())
    args = parser.parse_args(["stream", str(path), "--virtual", "--json", str(tmp_path / "r.json")])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "  pan (servo 1): torque on, holding its goal 5.0 deg" in out
    assert "  roll (servo 3): torque on, holding its goal 0.0 deg" in out
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["servo_outcomes"]["pan"]["state"] == "holding"
    assert result["servo_outcomes"]["pan"]["goal_deg"] == pytest.approx(5.0, abs=0.1)


class _Sagging(FirstOrderPlant):
    """A plant whose pan falls at 20 rad/s when released (a load its current hid)."""

    def advance(self, dt_s):
        super().advance(dt_s)
        if not self._torque[0]:
            self._q[0] -= 20.0 * dt_s


def test_a_servo_that_moves_while_released_is_caught_and_said(rig):
    registers = {1: {Register.OPERATING_MODE: 1, Register.TORQUE_ENABLE: 1}}
    virtual, bus = rig(_Sagging(time_constant_s=0.01), registers=registers)
    with pytest.warns(RuntimeWarning, match=r"servo 1 \(pan\) moved -\d+ ticks while released"):
        setup = bring_up(bus, JointMap(), MODELS, _ramp((0.0, 0.0, 0.0)), configure=True)
    assert virtual.servos[1].torque_on  # caught: torque back on where it fell to
    fell_to = virtual.servos[1].get(Register.GOAL_POSITION)
    assert fell_to < 2048 - 57 and setup.present_ticks[0] == fell_to
