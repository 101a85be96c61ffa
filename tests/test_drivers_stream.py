"""Bring-up and streaming: ServoBus -> dynamixel-sdk -> pyserial -> pty -> virtual bus -> plant."""

import csv
import math
import time

import numpy as np
import pytest

from trajgen.drivers.bringup import bring_up, operating_mode_for, watchdog_units
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.clock import SimulatedClock
from trajgen.drivers.control_table import Register, model_named
from trajgen.drivers.errors import BringUpError, CommError, ServoError, WatchdogTripped
from trajgen.drivers.streamer import Streamer, min_jerk_ramp
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import Fault, VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.stream import JointTrajectory

RATE_HZ = 200.0
MODELS = ("XM430-W350",) * 3


def _trajectory(rng, duration_s=0.5, rate_hz=RATE_HZ, offset=(0.0, 0.0, 0.0)):
    """A smooth random joint path (sum of sines), arrays built directly."""
    t = np.arange(round(duration_s * rate_hz) + 1) / rate_hz
    amp = rng.uniform(0.1, 0.6, (3, 1))
    freq = rng.uniform(0.5, 2.0, (3, 1))
    phase = 2 * np.pi * freq * t
    q = (amp * np.sin(phase)).T + np.asarray(offset)
    qd = (amp * 2 * np.pi * freq * np.cos(phase)).T
    qdd = (-amp * (2 * np.pi * freq) ** 2 * np.sin(phase)).T
    return JointTrajectory(t, q, qd, qdd, rate_hz)


class _Rig:
    """A virtual bus with a plant, and an open driver bus on its pty."""

    def __init__(self, plant=None, *, faults=(), models=MODELS, ids=(1, 2, 3), fast=True):
        self.plant = plant or FirstOrderPlant(time_constant_s=0.01)
        self.virtual = VirtualBus(
            self.plant,
            ids=ids,
            models=models,
            lockstep_dt_s=1 / RATE_HZ,
            faults=faults,
            fast_sync_read=fast,
        ).start()
        self.bus = self.virtual.connect().open()  # answered in this thread, lock-step

    def close(self):
        self.bus.close()
        self.virtual.stop()


@pytest.fixture
def rig():
    made = []

    def make(*args, **kwargs):
        made.append(_Rig(*args, **kwargs))
        return made[-1]

    yield make
    for r in made:
        r.close()


def _stream(r, trajectory, joints, tmp_path, **kwargs):
    # Factory servos: --configure sets Return Delay Time 0 (and a mode a plan needs).
    bring_up(r.bus, joints, MODELS, trajectory, configure=True)
    streamer = Streamer(r.bus, joints, telemetry=tmp_path / "telemetry.csv", **kwargs)
    return streamer


def _telemetry(tmp_path):
    with open(tmp_path / "telemetry.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_every_goal_received_equals_the_plan(rig, rng, tmp_path):
    trajectory = _trajectory(rng)
    joints = JointMap(ids=(1, 2, 3), directions=(1, -1, 1), zeros=(2048, 1900, 2200))
    r = rig()
    # Simulated time (lock-step): a busy machine cannot fail it; wall-clock timing is
    # measured by bench/stream_rate.py.
    streamer = _stream(r, trajectory, joints, tmp_path, clock=SimulatedClock())
    stats = streamer.run(trajectory)
    received = np.array(list(r.virtual.goal_log)[-len(trajectory) :])
    # Servo frame -> joint angle, frame by frame, within one tick.
    received_rad = joints.to_rad(received)
    tick = 2 * math.pi / 4096
    assert np.max(np.abs(received_rad - trajectory.q)) <= tick
    assert len(r.virtual.goal_log) == stats.approach_frames + len(trajectory)
    # The stats are sane.
    assert stats.frames_sent == stats.frames_planned == len(trajectory)
    # Never faster than planned: stalls (a busy host) only stretch the stream, by at
    # most the total shift (which includes the approach's).
    duration_s = trajectory.t[-1] - trajectory.t[0]
    assert stats.achieved_rate_hz <= 1.01 * RATE_HZ
    assert stats.achieved_rate_hz >= 0.98 * RATE_HZ * duration_s / (duration_s + stats.delay_s)
    assert 0 <= stats.period_error_p50_s <= stats.period_error_p99_s <= stats.period_error_max_s
    assert stats.period_error_p50_s < 0.5 / RATE_HZ
    assert stats.overruns <= 0.05 * len(trajectory)
    # One telemetry read per frame (the start-up position reads are not telemetry).
    assert stats.reads == stats.approach_frames + len(trajectory)
    assert stats.fault == ""
    # Telemetry: one row per frame, present position lags the goal (first-order plant).
    rows = _telemetry(tmp_path)
    stream_rows = [row for row in rows if row["phase"] == "stream"]
    assert len(stream_rows) == len(trajectory)
    goal = np.array(
        [[float(row[f"goal_rad_{j}"]) for j in ("pan", "tilt", "roll")] for row in stream_rows]
    )
    np.testing.assert_allclose(goal, trajectory.q)
    position = np.array(
        [[float(row[f"position_rad_{j}"]) for j in ("pan", "tilt", "roll")] for row in stream_rows]
    )
    assert np.max(np.abs(position - trajectory.q)) < 0.1


def test_starts_with_a_smooth_move_to_the_first_frame(rig, rng, tmp_path):
    trajectory = _trajectory(rng, duration_s=0.2, offset=(0.4, -0.3, 0.2))
    start = np.array([-0.2, 0.1, 0.0])
    joints = JointMap()
    r = rig(FirstOrderPlant(initial_rad=start, time_constant_s=0.005))
    streamer = _stream(
        r, trajectory, joints, tmp_path, approach_speed_rad_s=2.0, clock=SimulatedClock()
    )
    stats = streamer.run(trajectory)
    approach = joints.to_rad(np.array(list(r.virtual.goal_log)[: stats.approach_frames]))
    distance = np.max(np.abs(trajectory.q[0] - start))
    # Peak speed 2 rad/s on a minimum-jerk ramp: duration 1.875 d / 2.
    assert stats.approach_frames == math.ceil(1.875 * distance / 2.0 * RATE_HZ)
    np.testing.assert_allclose(approach[-1], trajectory.q[0], atol=2 * math.pi / 4096)
    steps = np.diff(np.vstack([start, approach]), axis=0)
    assert np.max(np.abs(steps)) <= 2.0 / RATE_HZ + 2 * math.pi / 4096
    assert np.all(steps * (trajectory.q[0] - start) >= -2 * math.pi / 4096)  # monotone


def test_min_jerk_ramp_ends_exactly_and_respects_speed():
    t, q = min_jerk_ramp(np.zeros(2), np.array([1.0, -0.5]), 100.0, 0.5)
    assert t[-1] == pytest.approx(math.ceil(3.75 * 100) / 100)
    np.testing.assert_allclose(q[-1], [1.0, -0.5])
    assert np.max(np.abs(np.diff(q[:, 0]))) * 100 <= 0.5 + 1e-9
    assert min_jerk_ramp(np.ones(3), np.ones(3), 100.0, 0.5)[1].shape == (0, 3)


def test_stream_of_frames_with_rate(rig, rng, tmp_path):
    trajectory = _trajectory(rng, duration_s=0.2)
    r = rig()
    streamer = _stream(r, trajectory, JointMap(), tmp_path)
    stats = streamer.run(iter(list(trajectory)), rate_hz=RATE_HZ)
    assert stats.frames_sent == stats.frames_planned == len(trajectory)
    with pytest.raises(ValueError, match="Expected a positive `rate_hz`"):
        streamer.run(iter(list(trajectory)))
    with pytest.raises(ValueError, match="Expected a non-empty stream, got no frames"):
        streamer.run(iter([]), rate_hz=RATE_HZ)


def test_hold_on_finish_clears_watchdog_and_keeps_torque(rig, rng, tmp_path):
    trajectory = _trajectory(rng, duration_s=0.1)
    r = rig()
    _stream(r, trajectory, JointMap(), tmp_path).run(trajectory)
    for servo in r.virtual.servos.values():
        assert servo.torque_on
        assert servo.get(Register.BUS_WATCHDOG) == 0
        assert servo.get(Register.RETURN_DELAY_TIME) == 0
        assert servo.get(Register.OPERATING_MODE) == 3
    np.testing.assert_array_equal(r.virtual.goal_log[-1], JointMap().to_ticks(trajectory.q[-1]))


FAULTS = [
    (Fault("drop", at_frame=20, servo_id=2), CommError, "fast sync read .* 3 tries: There is no"),
    (Fault("corrupt", at_frame=20), CommError, "3 tries: Incorrect status packet"),
    # Replies 5 s late: after every try (each times out in about 34 ms) and the safe stop,
    # however slow the host; the late bytes are read by no one.
    (Fault("delay", at_frame=20, delay_s=5.0), CommError, "3 tries: There is no status packet"),
    (Fault("close", at_frame=20), CommError, "port failed"),
    (Fault("overload", at_frame=20, servo_id=3), ServoError, "servo 3: hardware error .*overload"),
    (Fault("watchdog", at_frame=20, servo_id=1), WatchdogTripped, "servo 1: Bus Watchdog tripped"),
]


@pytest.mark.parametrize(("fault", "error", "match"), FAULTS, ids=[f[0].kind for f in FAULTS])
@pytest.mark.parametrize("on_stop", ["hold", "torque_off"])
def test_fault_stops_safely_within_a_second(rig, rng, tmp_path, fault, error, match, on_stop):
    trajectory = _trajectory(rng, duration_s=1.0)
    r = rig(faults=[fault])
    streamer = _stream(r, trajectory, JointMap(), tmp_path, on_stop=on_stop)
    with pytest.raises(error, match=match):
        streamer.run(trajectory)
    stats = streamer.stats
    # Within one watchdog poll (50 ms of stream time) of the fault, on a busy host too:
    # the stream runs on simulated time.
    assert fault.at_frame <= stats.frames_sent <= fault.at_frame + 11
    assert stats.frames_sent < len(trajectory)
    assert stats.fault and stats.fault in str(streamer.stats.fault)
    # Telemetry up to the fault is on disk.
    rows = _telemetry(tmp_path)
    assert len(rows) == stats.frames_sent  # every goal sent has its row
    assert [int(row["frame"]) for row in rows] == list(range(len(rows)))
    # The servos hold their last goal, or are released.
    if fault.kind != "close":
        for servo_id, servo in r.virtual.servos.items():
            if on_stop == "torque_off":
                assert not servo.torque_on
            elif not (fault.kind == "overload" and servo_id == fault.servo_id):
                assert servo.torque_on
        if on_stop == "hold":
            sent = JointMap().to_ticks(trajectory.q[stats.frames_sent - 1])
            holding = [i for i in (1, 2, 3) if not (fault.kind == "watchdog" and i == 1)]
            for servo_id in holding:
                assert r.virtual.servos[servo_id].get(Register.GOAL_POSITION) == sent[servo_id - 1]


def test_ctrl_c_stops_safely(rig, rng, tmp_path):
    trajectory = _trajectory(rng, duration_s=0.5)
    r = rig()
    streamer = _stream(r, trajectory, JointMap(), tmp_path, on_stop="torque_off")

    def frames():
        for frame in trajectory:
            if frame.index == 30:
                raise KeyboardInterrupt
            yield frame

    with pytest.raises(KeyboardInterrupt):
        streamer.run(frames(), rate_hz=RATE_HZ)
    assert streamer.stats.frames_sent == 30
    assert streamer.stats.fault == "KeyboardInterrupt"
    assert len(_telemetry(tmp_path)) == 30
    assert not any(servo.torque_on for servo in r.virtual.servos.values())


def test_wrong_model_refuses_to_stream(rig, rng):
    trajectory = _trajectory(rng, duration_s=0.1)
    r = rig(models=("XM430-W350", "XL430-W250", "XM430-W350"))
    joints = JointMap()
    with pytest.raises(
        BringUpError,
        match=r"servo 2: model number 1060 \(XL430-W250\), expected 1020 \(XM430-W350\); refus",
    ):
        bring_up(r.bus, joints, MODELS, trajectory)
    assert r.virtual.frames_received == 0
    assert not any(servo.torque_on for servo in r.virtual.servos.values())


def test_missing_servo_refuses_to_stream(rig, rng):
    trajectory = _trajectory(rng, duration_s=0.1)
    r = rig()
    joints = JointMap(ids=(1, 2, 4))
    with pytest.raises(BringUpError, match="servo 4: no reply to ping at 1000000 baud"):
        bring_up(r.bus, joints, MODELS, trajectory)


def test_latched_hardware_error_refuses_bring_up(rig, rng):
    trajectory = _trajectory(rng, duration_s=0.1)
    r = rig()
    r.virtual.servos[2].raise_hardware_error(0x20)
    with pytest.raises(ServoError, match=r"servo 2: hardware error during read Hardware Error"):
        bring_up(r.bus, JointMap(), MODELS, trajectory)
    assert not any(servo.torque_on for servo in r.virtual.servos.values())


def test_extended_position_mode_for_multi_turn_range(rig, rng, tmp_path):
    trajectory = _trajectory(rng, duration_s=0.2, offset=(3.5, 0.0, 0.0))
    r = rig(FirstOrderPlant(initial_rad=np.array([3.5, 0.0, 0.0])))
    joints = JointMap()
    assert operating_mode_for(joints.to_ticks(trajectory.q)) == 4
    stats = _stream(r, trajectory, joints, tmp_path).run(trajectory)
    assert r.virtual.servos[1].get(Register.OPERATING_MODE) == 4
    assert stats.frames_sent == len(trajectory)
    assert np.max(np.concatenate(r.virtual.goal_log)) > 4095


def test_watchdog_units_and_argument_errors(rig):
    assert watchdog_units(0.1) == 5
    assert watchdog_units(0.02) == 1
    with pytest.raises(ValueError, match=r"Expected `watchdog_s` in 0.02..2.54 s, got 3"):
        watchdog_units(3)
    r = rig()
    with pytest.raises(ValueError, match="Expected `telemetry_every` to be an integer >= 1, got 0"):
        Streamer(r.bus, JointMap(), telemetry_every=0)
    with pytest.raises(
        ValueError, match=r"Expected `on_stop` to be one of \('hold', 'torque_off'\), got 'x'"
    ):
        Streamer(r.bus, JointMap(), on_stop="x")


def test_npz_telemetry(rig, rng, tmp_path):
    trajectory = _trajectory(rng, duration_s=0.1)
    r = rig()
    bring_up(r.bus, JointMap(), MODELS, trajectory)
    Streamer(r.bus, JointMap(), telemetry=tmp_path / "t.npz", telemetry_every=2).run(trajectory)
    data = np.load(tmp_path / "t.npz")
    assert len(data["frame"]) == len(trajectory)
    np.testing.assert_allclose(data["goal_rad_tilt"], trajectory.q[:, 1])
    assert np.all(np.isnan(data["position_rad_pan"][1::2]))  # not read: NaN, never 0
    assert np.all(np.isfinite(data["position_rad_pan"][::2]))


def test_simulated_gimbal_tracks_and_passes_torque_check(rng, tmp_path):
    sim_plant = pytest.importorskip("trajgen.sim.plant")
    t = np.arange(201) / RATE_HZ
    s = t / t[-1]
    h = 10 * s**3 - 15 * s**4 + 6 * s**5
    amplitude = np.array([0.5, -0.3, 0.2])
    q = h[:, None] * amplitude
    qd = ((30 * s**2 - 60 * s**3 + 30 * s**4) / t[-1])[:, None] * amplitude
    qdd = ((60 * s - 180 * s**2 + 120 * s**3) / t[-1] ** 2)[:, None] * amplitude
    trajectory = JointTrajectory(t, q, qd, qdd, RATE_HZ)
    plant = sim_plant.GimbalPlant()
    r = _Rig(plant)
    try:
        bring_up(r.bus, JointMap(), MODELS, trajectory)
        stats = Streamer(r.bus, JointMap(), clock=SimulatedClock()).run(trajectory)
        received = JointMap().to_rad(np.array(r.virtual.goal_log))
    finally:
        r.close()
    assert stats.approach_frames == 0
    assert np.max(np.abs(received - q)) <= 2 * math.pi / 4096
    report = plant.report(trajectory)
    assert report.ok, report.format()


def test_falls_back_to_sync_read_without_fast_sync_read(rig, rng, tmp_path):
    trajectory = _trajectory(rng, duration_s=0.2)
    r = rig(fast=False)
    with pytest.warns(
        RuntimeWarning,
        match=r"fast sync read failed \(servos \[1, 2, 3\]: .*"
        r"There is no status packet!\); reading back by sync read",
    ):
        stats = _stream(r, trajectory, JointMap(), tmp_path).run(trajectory)
    assert stats.read_method == "sync read"
    assert "There is no status packet" in stats.read_fallback
    assert stats.comm_errors == 3  # the probe: one fast sync read, three tries
    assert stats.frames_sent == len(trajectory)
    rows = _telemetry(tmp_path)
    assert all(row["position_rad_pan"] != "" for row in rows)


def test_real_time_mode_advances_with_the_wall_clock():
    plant = FirstOrderPlant()
    with VirtualBus(plant) as virtual, ServoBus(virtual.port) as bus:
        t0 = time.monotonic()
        bus.ping(1)
        before = plant.time_s
        t1 = time.monotonic()
        time.sleep(0.2)
        t2 = time.monotonic()
        bus.ping(1)
        after = plant.time_s
        t3 = time.monotonic()
        # The simulation thread keeps the plant on the wall clock (a reply never steps
        # it): never ahead of it, and behind it by no more than a reply said it was
        # (stale_max_s; below 6 ms a reply is not counted stale), however busy the host.
        lag_s = max(virtual.stale_max_s, 0.006)
        assert (t2 - t1) - lag_s - 0.001 <= after - before <= (t3 - t0) + lag_s + 0.001


class _SlowPlant(FirstOrderPlant):
    """A first-order plant that takes ``step_s`` of wall time per step: a host far
    slower than the plan (a period is 5 ms)."""

    def __init__(self, step_s, **kwargs):
        super().__init__(**kwargs)
        self.step_s = step_s

    def advance(self, dt_s):
        time.sleep(self.step_s)
        super().advance(dt_s)


def _hog(stop):
    """Burn CPU (and hold the GIL in switch-interval slices) until ``stop`` is set."""
    while not stop.is_set():
        sum(range(10_000))


def test_lockstep_stream_is_the_same_on_a_slow_busy_host(rng, tmp_path):
    import threading

    trajectory = _trajectory(rng, duration_s=0.3, offset=(0.2, -0.1, 0.1))
    runs = []
    for name, step_s in (("quick", 0.0), ("slow", 0.02)):
        stop = threading.Event()
        hog = threading.Thread(target=_hog, args=(stop,), daemon=True)
        r = _Rig(_SlowPlant(step_s, time_constant_s=0.01))
        try:
            if step_s:
                hog.start()
            out = tmp_path / name
            out.mkdir()
            stats = _stream(r, trajectory, JointMap(), out).run(trajectory)
            goals = np.array(r.virtual.goal_log)
        finally:
            stop.set()
            r.close()
        runs.append((goals, (out / "telemetry.csv").read_text(), stats.to_json_dict()))
    (goals, rows, stats), (slow_goals, slow_rows, slow_stats) = runs
    # 20 ms of host time per 5 ms period, a CPU hog beside it: on the wall clock the
    # stream would fall seconds behind and trip its Bus Watchdog. In lock-step the
    # goals, every telemetry row (times included) and the statistics are the same.
    assert stats["frames_sent"] == len(trajectory) and stats["approach_frames"] > 0
    np.testing.assert_array_equal(slow_goals, goals)
    assert slow_rows == rows
    assert slow_stats == stats
    assert stats["stalls"] == 0 and stats["fault"] == ""


# -- the probe before a wall-clock stream ---------------------------------------------


def test_read_every_fits_the_period():
    from trajgen.drivers.probe import CycleCost, max_rate_hz, read_every_for

    # 1 kHz: 0.1 ms write + 0.3 ms read fit 0.8 ms every frame.
    assert read_every_for(CycleCost(1e-4, 3e-4, 20), 1e-3) == 1
    # 500 Hz with a 2 ms read-back: 1.5 ms spare a frame, so every 2nd frame.
    assert read_every_for(CycleCost(1e-4, 2e-3, 20), 2e-3) == 2
    assert read_every_for(CycleCost(1e-4, 2e-3, 20), 2e-3, wanted=5) == 5
    # A 16 ms read-back (FTDI latency timer at its default) at 200 Hz: its reply is carried
    # behind the goals at 5 and 10 ms (REPLY_WAIT_S past its wire end reached there), the
    # goal at 15 ms goes 1.1 ms late, within half a period: every 5th frame fits the mean.
    assert read_every_for(CycleCost(1e-4, 16e-3, 20), 5e-3) == 5
    # At 500 Hz the goal after the last one carried (at 6 ms) would go 8.1 ms late: refused.
    assert read_every_for(CycleCost(1e-4, 16e-3, 20), 2e-3) is None
    # Writes alone past the budget.
    assert read_every_for(CycleCost(9e-4, 1e-4, 20), 1e-3) is None
    # Every frame read back: 0.8 of the period carries 16.1 ms at 49.7 Hz at most.
    assert max_rate_hz(CycleCost(1e-4, 16e-3, 20)) == pytest.approx(0.8 / 16.1e-3)
    assert max_rate_hz(CycleCost(1e-4, 16e-3, 20), read_every=4) == pytest.approx(2.5 / 16.1e-3)


def test_read_every_is_raised_until_late_read_backs_cost_under_1_percent_of_the_rate():
    from trajgen.drivers.probe import LAG_SHARE, CycleCost, read_every_for

    # 1 kHz: 48 of 50 reads take 0.3 ms, 2 take 7.9 ms: a frame with one of those ends
    # 8.0 ms after its start; the goals at 1..6 ms go out behind the reply (carried up to
    # REPLY_WAIT_S, 5 ms, past its wire end), the one at 6 ms then waits for it, and the
    # one due at 7 ms is stalled by 1 ms. That is 0.04 ms a read on average: read back
    # every 4 frames at least for 1 % of the period (0.01 ms).
    reads = (3e-4,) * 48 + (7.9e-3,) * 2
    cost = CycleCost(1e-4, 3e-4, 50, reads)
    assert cost.late(1e-3) == (2, pytest.approx(2 * 1e-3 / 50))
    assert LAG_SHARE == 0.01
    assert read_every_for(cost, 1e-3) == 4
    assert read_every_for(cost, 1e-3, wanted=10) == 10
    assert read_every_for(cost.median_only(), 1e-3) == 1  # the median alone: every frame
    # At 100 Hz the same reads stall nothing.
    assert read_every_for(cost, 1e-2) == 1
    # Half the reads late: more than 50 frames between read-backs would be needed.
    assert read_every_for(CycleCost(1e-4, 3e-4, 4, (3e-4, 3e-4, 8e-3, 8e-3)), 1e-3) is None
    # Replies 2.9 ms late, carried behind the next goals, stall nothing: every frame.
    assert read_every_for(CycleCost(1e-4, 3e-4, 50, (3e-4,) * 48 + (2.9e-3,) * 2), 1e-3) == 1


def test_probe_lowers_the_read_back_rate_it_cannot_carry(rig, rng, tmp_path, monkeypatch):
    from trajgen.drivers import streamer as streamer_module
    from trajgen.drivers.clock import WALL_CLOCK
    from trajgen.drivers.probe import PROBE_FRAMES, CycleCost

    timed = []

    def probe_cycle(read, write_s, frames):  # the reads run; their cost is the test's
        for _ in range(frames):
            read()
        timed.append((frames, write_s))
        return CycleCost(write_s=2e-4, read_s=8e-3, frames=frames)

    monkeypatch.setattr(streamer_module, "probe_cycle", probe_cycle)
    trajectory = _trajectory(rng, duration_s=0.2, rate_hz=100.0)
    r = rig()
    start = bring_up(r.bus, JointMap(), MODELS, trajectory, configure=True).present_ticks
    goals_before = r.virtual.frames_received
    streamer = Streamer(
        r.bus,
        JointMap(),
        telemetry=tmp_path / "telemetry.csv",
        clock=WALL_CLOCK,
        start_ticks=start,
        max_delay_s=None,
    )
    with pytest.warns(
        RuntimeWarning,
        match=r"reading the servos back every 2 frames instead of every 1: .*"
        r"a read-back 8\.00 ms .* 100 Hz leaves 10\.00 ms a frame",
    ):
        stats = streamer.run(trajectory)
    # 29 bytes of Sync Write at 1 Mbps; the probe wrote nothing.
    assert timed == [(PROBE_FRAMES, pytest.approx(290e-6))] and stats.read_every == 2
    assert r.virtual.frames_received - goals_before == stats.approach_frames + len(trajectory)
    assert stats.reads == math.ceil(stats.approach_frames / 2) + math.ceil(len(trajectory) / 2)
    assert "probe before the stream: goal write 0.200 ms, read-back 8.000 ms" in stats.format()


def test_probe_refuses_a_rate_the_adapter_latency_cannot_carry():
    from trajgen.drivers.errors import StreamLagging
    from trajgen.drivers.virtual.bus import WireTiming

    t = np.arange(41) / RATE_HZ
    q = np.zeros((len(t), 3))
    trajectory = JointTrajectory(t, q, q, q, RATE_HZ)
    # Real time, every reply 16 ms late (an FTDI adapter at its default latency timer):
    # a read-back takes at least that, whatever the host's load; 200 Hz leaves 5 ms.
    timing = WireTiming(baud=1_000_000, adapter_latency_s=0.016)
    with VirtualBus(FirstOrderPlant(), timing=timing) as virtual:
        with ServoBus(virtual.port, latency_ms=100.0) as bus:
            for servo_id in (1, 2, 3):
                bus.add_servo(servo_id, model_named("XM430-W350"))
                bus.write(servo_id, Register.TORQUE_ENABLE, 1)
            streamer = Streamer(bus, JointMap(), probe_frames=3)
            with pytest.raises(
                StreamLagging,
                match=r"before the first goal: a goal write takes 0\.29 ms and a read-back "
                r"\d+\.\d\d ms \(median of 3 probe reads\), and 200 Hz leaves 5\.00 ms a "
                r"frame: this host and bus cannot keep it .*; nothing was moved",
            ):
                streamer.run(trajectory)
        assert virtual.frames_received == 0
    assert streamer.stats.frames_sent == 0 and streamer.stats.probe_read_s >= 0.016
