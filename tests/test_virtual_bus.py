"""The virtual servo bus, driven through ServoBus -> dynamixel-sdk -> pyserial -> pty."""

import math
import time

import numpy as np
import pytest

from trajgen.drivers import bus as drivers_bus
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.control_table import MODELS, Register
from trajgen.drivers.errors import BadArgument, CommError, ServoError
from trajgen.drivers.virtual.bus import Fault, VirtualBus, WireTiming
from trajgen.drivers.virtual.plant import FirstOrderPlant, Plant
from trajgen.sim.errors import SimulationError

XM430 = MODELS["XM430-W350"]
STATE = (Register.PRESENT_CURRENT, Register.PRESENT_VELOCITY, Register.PRESENT_POSITION)


def _open(plant=None, *, faults=(), timing=None, baud=1_000_000, models="XM430-W350"):
    virtual = VirtualBus(
        plant or FirstOrderPlant(),
        models=models,
        lockstep_dt_s=0.01,
        faults=faults,
        timing=timing,
    ).start()
    bus = virtual.connect(baud=baud).open()
    for servo_id in (1, 2, 3):
        bus.add_servo(servo_id, XM430)
    return virtual, bus


@pytest.fixture
def pair():
    virtual, bus = _open()
    yield virtual, bus
    bus.close()
    virtual.stop()


def _goals(bus, ticks):
    """Sync write goals, then ping: once the reply is in, the bus has handled the write."""
    bus.sync_write(Register.GOAL_POSITION, dict(zip((1, 2, 3), ticks, strict=True)))
    bus.ping(1)


def test_first_order_plant_is_a_plant():
    assert isinstance(FirstOrderPlant(), Plant)


def test_ping_and_scan(pair):
    virtual, bus = pair
    assert [bus.ping(i) for i in (1, 2, 3)] == [1020, 1020, 1020]
    assert bus.scan() == {1: (1020, 48), 2: (1020, 48), 3: (1020, 48)}


def test_factory_defaults_and_write_read_back(pair):
    _, bus = pair
    assert bus.read(1, Register.RETURN_DELAY_TIME) == 250
    assert bus.read(1, Register.OPERATING_MODE) == 3
    assert bus.read(1, Register.SHUTDOWN) == 52
    bus.write(1, Register.RETURN_DELAY_TIME, 0)
    assert bus.read(1, Register.RETURN_DELAY_TIME) == 0
    assert bus.read(2, Register.RETURN_DELAY_TIME) == 250


def test_eeprom_locked_while_torque_on(pair):
    _, bus = pair
    bus.write(2, Register.TORQUE_ENABLE, 1)
    with pytest.raises(
        ServoError, match=r"servo 2: write Operating Mode = 4: status error: access \(0x07\)"
    ):
        bus.write(2, Register.OPERATING_MODE, 4)
    bus.write(2, Register.TORQUE_ENABLE, 0)
    bus.write(2, Register.OPERATING_MODE, 4)
    assert bus.read(2, Register.OPERATING_MODE) == 4


def test_read_only_register_refuses_write(pair):
    _, bus = pair
    with pytest.raises(ServoError, match="servo 1: write Present Position = 5: .*access"):
        bus.write(1, Register.PRESENT_POSITION, 5)


def test_goal_outside_limits_is_refused_in_position_mode(pair):
    _, bus = pair
    with pytest.raises(ServoError, match="servo 3: write Goal Position = 5000: .*data limit"):
        bus.write(3, Register.GOAL_POSITION, 5000)


def test_signed_values_over_the_wire():
    # Plant at -4 rad: Present Position 2048 - 2608 = -560 (0xFFFFFDD0 unsigned).
    plant = FirstOrderPlant(initial_rad=np.array([-4.0, 0.5, 0.0]), time_constant_s=0.05)
    virtual, bus = _open(plant)
    try:
        expected = 2048 + round(-4.0 * 4096 / (2 * math.pi))
        assert expected < 0
        assert bus.read(1, Register.PRESENT_POSITION) == expected
        bus.write(2, Register.TORQUE_ENABLE, 1)
        _goals(bus, [expected, 2048, 2048])  # joint 2 moves from 0.5 rad to 0: negative speed
        _goals(bus, [expected, 2048, 2048])  # (the first period ends as this goal arrives)
        block = bus.read_block((1, 2, 3), STATE)
        assert block.values[1][Register.PRESENT_POSITION] == expected
        assert block.values[2][Register.PRESENT_VELOCITY] < 0
        assert block.values[2][Register.PRESENT_CURRENT] < 0
    finally:
        bus.close()
        virtual.stop()


def test_fast_and_plain_sync_read_agree():
    # Servos that reach their goal within one period: at rest after the third goal
    # write, so the plain read (a poll: one more period) sees what the fast one saw.
    virtual, bus = _open(FirstOrderPlant(time_constant_s=0.0))
    try:
        for servo_id in (1, 2, 3):
            bus.write(servo_id, Register.TORQUE_ENABLE, 1)
        for _ in range(3):
            _goals(bus, [2100, 2000, 2048])
        fast = bus.read_block((1, 2, 3), STATE, fast=True)
        plain = bus.read_block((1, 2, 3), STATE, fast=False)
    finally:
        bus.close()
        virtual.stop()
    assert fast == plain
    assert fast.errors == {1: 0, 2: 0, 3: 0}
    assert fast.values[1][Register.PRESENT_POSITION] == 2100


def test_lockstep_advances_one_period_per_goal_write(pair):
    virtual, bus = pair
    for k in range(7):
        _goals(bus, [2048 + k, 2048 - k, 2048])
    assert virtual.plant.time_s == pytest.approx(0.07)
    np.testing.assert_array_equal(virtual.goal_log[-1], [2054, 2042, 2048])
    bus.read(1, Register.PRESENT_POSITION)  # reads do not advance the plant
    assert virtual.plant.time_s == pytest.approx(0.07)


def test_failed_read_raises_never_zero():
    virtual, bus = _open(faults=[Fault("drop", servo_id=2)])
    try:
        assert bus.read(1, Register.PRESENT_POSITION) == 2048
        with pytest.raises(
            CommError,
            match=r"servo 2: read Present Position failed after 3 tries: There is no status",
        ):
            bus.read(2, Register.PRESENT_POSITION)
        with pytest.raises(CommError, match=r"servos \[1, 2, 3\]: fast sync read .* 3 tries"):
            bus.read_block((1, 2, 3), STATE)
        assert bus.failed_tries == 6
    finally:
        bus.close()
        virtual.stop()


def test_corrupt_reply_is_retried_then_raises():
    virtual, bus = _open(faults=[Fault("corrupt", servo_id=1, count=2)])
    try:
        # Two corrupt replies, then a good one: within the retry budget of 2.
        assert bus.read(1, Register.MODEL_NUMBER) == 1020
        assert bus.failed_tries == 2
    finally:
        bus.close()
        virtual.stop()
    virtual, bus = _open(faults=[Fault("corrupt", servo_id=1)])
    try:
        with pytest.raises(CommError, match="servo 1: read Model Number failed after 3 tries: "):
            bus.read(1, Register.MODEL_NUMBER)
    finally:
        bus.close()
        virtual.stop()


def test_overload_sets_alert_and_reboot_clears_it():
    virtual, bus = _open(faults=[Fault("overload", at_frame=1, servo_id=2)])
    try:
        for servo_id in (1, 2, 3):
            bus.write(servo_id, Register.TORQUE_ENABLE, 1)
        _goals(bus, [2048, 2048, 2048])
        assert not virtual.servos[2].torque_on  # Shutdown covers overload
        block = bus.read_block((1, 2, 3), STATE)
        assert block.errors == {1: 0, 2: 0x80, 3: 0}
        with pytest.raises(ServoError, match=r"servo 2: hardware error during .*: overload \(Har"):
            bus.check_block(block, "streaming")
        with pytest.raises(ServoError, match=r"servo 2: write Torque .*: result fail \(0x81\)"):
            bus.write(2, Register.TORQUE_ENABLE, 1)
        bus.reboot(2)
        assert bus.read(2, Register.HARDWARE_ERROR_STATUS) == 0
        bus.write(2, Register.TORQUE_ENABLE, 1)
        assert virtual.servos[2].torque_on
    finally:
        bus.close()
        virtual.stop()


def test_bus_watchdog_trips_on_simulated_time_and_blocks_goals_until_cleared(pair):
    virtual, bus = pair
    bus.write(1, Register.TORQUE_ENABLE, 1)
    bus.write(1, Register.BUS_WATCHDOG, 1)  # 20 ms
    time.sleep(0.1)  # wall time: in lock-step the servos do not see it
    assert bus.read(1, Register.BUS_WATCHDOG) == 1
    # Servo 2 polled four times: three 10 ms periods (the first poll ends none) with
    # nothing sent to servo 1.
    for _ in range(4):
        bus.read(2, Register.PRESENT_POSITION)
    assert virtual.sim_time_s == pytest.approx(0.03)
    assert bus.read(1, Register.BUS_WATCHDOG) == -1
    with pytest.raises(ServoError, match="servo 1: write Goal Position = 2100: .*data range"):
        bus.write(1, Register.GOAL_POSITION, 2100)
    bus.write(1, Register.BUS_WATCHDOG, 0)
    bus.write(1, Register.GOAL_POSITION, 2100)
    assert virtual.servos[1].get(Register.GOAL_POSITION) == 2100


@pytest.mark.parametrize("plant_process", [False, True], ids=["thread", "process"])
def test_bus_watchdog_trips_on_the_wall_clock_in_real_time(plant_process):
    virtual = VirtualBus(FirstOrderPlant(), plant_process=plant_process).start()
    try:
        with ServoBus(virtual.port) as bus:
            bus.add_servo(1, XM430)
            bus.write(1, Register.TORQUE_ENABLE, 1)
            bus.write(1, Register.BUS_WATCHDOG, 1)  # 20 ms
            time.sleep(0.1)  # at least five periods of silence, however busy the host
            assert bus.read(1, Register.BUS_WATCHDOG) == -1
    finally:
        virtual.stop()


def test_watchdog_stays_quiet_while_packets_flow(pair):
    _, bus = pair
    bus.write(1, Register.TORQUE_ENABLE, 1)
    bus.write(1, Register.BUS_WATCHDOG, 5)  # 100 ms
    for _ in range(20):
        time.sleep(0.01)  # however long the host takes between frames (lock-step)
        _goals(bus, [2048, 2048, 2048])
    assert bus.read(1, Register.BUS_WATCHDOG) == 5


def test_port_closing_raises_comm_error():
    virtual, bus = _open(faults=[Fault("close", at_frame=1)])
    try:
        bus.sync_write(Register.GOAL_POSITION, {1: 2048, 2: 2048, 3: 2048})
        with pytest.raises(CommError, match="read Model Number: port failed"):
            bus.read(1, Register.MODEL_NUMBER)
        with pytest.raises(CommError, match="port failed"):  # not "Port is in use!"
            bus.read(1, Register.MODEL_NUMBER)
    finally:
        bus.close()
        virtual.stop()


def test_wire_timing_lower_bounds():
    # 57600 baud: a ping (10 B) and its reply (14 B) take 24 * 10 / 57600 s = 4.17 ms,
    # plus Return Delay Time 250 * 2 us = 0.5 ms.
    timing = WireTiming(baud=57_600, adapter_latency_s=0.001)
    virtual, bus = _open(timing=timing, baud=57_600)
    try:
        floor_s = 24 * 10 / 57_600 + 0.0005 + 0.001
        elapsed = []
        for _ in range(5):
            start = time.monotonic()
            bus.ping(1)
            elapsed.append(time.monotonic() - start)
        assert min(elapsed) >= floor_s
        bus.write(1, Register.RETURN_DELAY_TIME, 0)
        start = time.monotonic()
        bus.ping(1)
        assert time.monotonic() - start >= floor_s - 0.0005
        assert virtual.bytes_sent > 0 and virtual.bytes_received > 0
    finally:
        bus.close()
        virtual.stop()


def test_opens_at_4_5_mbps(pair):
    virtual, first = pair
    first.close()  # the port is opened exclusively
    with ServoBus(virtual.port, baud=4_500_000) as bus:
        assert bus.ping(3) == 1020


def test_a_second_program_on_the_port_is_refused(pair):
    virtual, first = pair
    with pytest.raises(CommError, match=r"/dev/pts/\d+: in use by another program"):
        ServoBus(virtual.port).open()
    assert first.ping(1) == 1020  # the first one is not disturbed
    first.close()
    with ServoBus(virtual.port) as again:  # free once closed
        assert again.ping(1) == 1020


def test_bad_arguments():
    with pytest.raises(
        ValueError, match=r"Expected at least one id per plant joint \(3\), got `ids`"
    ):
        VirtualBus(FirstOrderPlant(), ids=(1, 2))
    with pytest.raises(ValueError, match="Expected a `servo_id` for a overload fault, got None"):
        Fault("overload")
    with pytest.raises(ValueError, match="Expected `kind` in"):
        Fault("explode")
    with pytest.raises(ValueError, match="Expected `baud` to be an integer >= 1, got 0"):
        ServoBus("/dev/null", baud=0)
    with pytest.raises(CommError, match="/nonexistent/tty: cannot open at 1000000 baud"):
        ServoBus("/nonexistent/tty", latency_ms=1.0).open()
    with pytest.raises(ValueError, match=r"Servo 9 has no model; call add_servo\(9, model\)"):
        ServoBus("/dev/null").read(9, Register.ID)


def test_first_order_plant_exact_response():
    plant = FirstOrderPlant(1, time_constant_s=0.1)
    plant.set_torque_enabled(0, True)
    plant.set_goal(np.array([1.0]))
    plant.advance(0.1)
    assert plant.read()[0][0] == pytest.approx(1 - math.exp(-1))
    plant.set_torque_enabled(0, False)
    plant.advance(1.0)
    assert plant.read()[0][0] == pytest.approx(1 - math.exp(-1))  # free: stays
    with pytest.raises(ValueError, match=r"Expected `initial_rad` of shape \(2,\), got \(3,\)"):
        FirstOrderPlant(2, initial_rad=np.zeros(3))
    with pytest.raises(ValueError, match="Expected `time_constant_s` >= 0, got -1"):
        FirstOrderPlant(time_constant_s=-1)


def test_ftdi_latency_timer_set_through_sysfs(tmp_path, monkeypatch):

    (tmp_path / "ttyUSB7").mkdir()
    timer = tmp_path / "ttyUSB7" / "latency_timer"
    timer.write_text("16\n")
    monkeypatch.setattr(drivers_bus, "_SYSFS_LATENCY", str(tmp_path / "{tty}" / "latency_timer"))
    assert drivers_bus.set_ftdi_latency_timer("/dev/ttyUSB7") == 1
    assert timer.read_text().strip() == "1"
    assert drivers_bus.set_ftdi_latency_timer("/dev/ttyS0") is None  # no timer: quiet


def test_ftdi_latency_timer_warns_when_stuck_at_16(tmp_path, monkeypatch):
    import builtins

    (tmp_path / "ttyUSB7").mkdir()
    timer = tmp_path / "ttyUSB7" / "latency_timer"
    timer.write_text("16\n")
    monkeypatch.setattr(drivers_bus, "_SYSFS_LATENCY", str(tmp_path / "{tty}" / "latency_timer"))

    def read_only(path, mode="r", *args, **kwargs):
        if "w" in mode:
            raise PermissionError(13, "Permission denied", str(path))
        return builtins.open(path, mode, *args, **kwargs)

    monkeypatch.setattr(drivers_bus, "open", read_only, raising=False)
    with pytest.warns(RuntimeWarning, match="/dev/ttyUSB7: FTDI latency timer is 16 ms"):
        assert drivers_bus.set_ftdi_latency_timer("/dev/ttyUSB7") == 16


def test_latency_timer_advice_names_the_sysfs_file(tmp_path, monkeypatch):
    monkeypatch.setattr(drivers_bus, "_SYSFS_LATENCY", str(tmp_path / "{tty}" / "latency_timer"))
    bus = ServoBus("/dev/ttyUSB7")
    assert bus.latency_advice() == ""  # not opened: no timer known
    bus.latency_timer_ms = 16  # as open() reads it from a timer it could not set
    assert bus.latency_advice() == (
        "; /dev/ttyUSB7's FTDI latency timer is 16 ms and every read-back waits for it: "
        f"lower it with echo 1 | sudo tee {tmp_path}/ttyUSB7/latency_timer"
    )
    bus.latency_timer_ms = 1
    assert bus.latency_advice() == ""


def test_lockstep_telemetry_holds_the_state_at_its_time_label(tmp_path):
    """Each row's present values are the servo's state when that row's goal was sent.

    Servos that reach a goal within one period: at the time of frame k they sit at
    frame k - 1's goal (the goal they had during the period that ends at frame k).
    """
    import csv

    from trajgen.drivers.streamer import Streamer
    from trajgen.drivers.units import JointMap
    from trajgen.stream import JointTrajectory

    t = np.arange(41) / 100.0
    q = np.stack([0.3 * np.sin(2 * np.pi * t), 0.2 * t, -0.1 * t], axis=1)
    zeros = np.zeros_like(q)
    trajectory = JointTrajectory(t, q, zeros, zeros, 100.0)
    plant = FirstOrderPlant(time_constant_s=0.0, initial_rad=q[0])
    with VirtualBus(plant, lockstep_dt_s=0.01) as virtual, virtual.connect() as bus:
        for servo_id in (1, 2, 3):
            bus.add_servo(servo_id, XM430)
            bus.write(servo_id, Register.TORQUE_ENABLE, 1)
        Streamer(bus, JointMap(), telemetry=tmp_path / "t.csv").run(trajectory)
    with open(tmp_path / "t.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(t)  # no approach: the plant starts at the first frame
    tick = 2 * math.pi / 4096
    for joint in ("pan", "tilt", "roll"):
        goal = np.array([float(r[f"goal_rad_{joint}"]) for r in rows])
        present = np.array([float(r[f"position_rad_{joint}"]) for r in rows])
        np.testing.assert_allclose(present[1:], goal[:-1], atol=tick / 2 + 1e-12)
        if joint == "pan":  # up to 12 ticks per frame: the new goal is clearly elsewhere
            assert np.max(np.abs(present[1:] - goal[1:])) > 5 * tick


def test_simulated_clock_jumps_to_deadlines_never_back(monkeypatch):
    from trajgen.drivers.clock import SimulatedClock

    def no_waiting(seconds):
        raise AssertionError(f"waited {seconds} s on the wall clock")

    monkeypatch.setattr(time, "sleep", no_waiting)
    monkeypatch.setattr(time, "monotonic", lambda: no_waiting("to read"))
    clock = SimulatedClock(1.0)
    clock.sleep_until(31.0)
    assert clock.now() == 31.0
    clock.sleep_until(5.0)
    assert clock.now() == 31.0


def test_lockstep_stream_on_a_simulated_clock_does_not_wait_out_the_motion(monkeypatch):
    import threading

    from trajgen.drivers.clock import SimulatedClock
    from trajgen.drivers.streamer import Streamer
    from trajgen.drivers.units import JointMap
    from trajgen.stream import JointTrajectory

    # Every wall-clock wait of the host's thread, recorded (the serving thread is idle).
    waits = []
    real_sleep = time.sleep

    def sleep(seconds):
        if threading.current_thread() is threading.main_thread():
            waits.append(seconds)
        real_sleep(seconds)

    monkeypatch.setattr(time, "sleep", sleep)
    t = np.arange(301) / 100.0  # 3 s of motion
    q = np.stack([0.2 * np.sin(t), 0.1 * t, 0 * t], axis=1)
    trajectory = JointTrajectory(t, q, np.zeros_like(q), np.zeros_like(q), 100.0)
    plant = FirstOrderPlant(initial_rad=q[0])
    with VirtualBus(plant, lockstep_dt_s=0.01) as virtual, virtual.connect() as bus:
        for servo_id in (1, 2, 3):
            bus.add_servo(servo_id, XM430)
            bus.write(servo_id, Register.TORQUE_ENABLE, 1)
        streamer = Streamer(bus, JointMap())
        assert isinstance(streamer.clock, SimulatedClock)  # lock-step: simulated by default
        stats = streamer.run(trajectory)
        np.testing.assert_array_equal(np.array(virtual.goal_log), JointMap().to_ticks(q))
    assert stats.frames_sent == 301
    # A period per frame, and the start-up polls: two position reads that agree.
    assert plant.time_s == pytest.approx(3.03)
    assert streamer.clock.now() == pytest.approx(3.01)  # first deadline one period in
    assert stats.stalls == 0 and stats.lateness_max_s == 0.0
    assert waits == []  # the 3 s of motion were never waited out on the wall clock


def test_real_time_reply_does_not_wait_for_a_simulation_far_behind():
    import threading

    class SlowPlant(FirstOrderPlant):
        """20 ms of wall time per 1 ms step: the simulation cannot keep real time."""

        advanced_by = {}

        def advance(self, dt_s):
            name = threading.current_thread().name
            self.advanced_by[name] = max(self.advanced_by.get(name, 0.0), dt_s)
            time.sleep(0.02)
            super().advance(dt_s)

    plant = SlowPlant()
    with VirtualBus(plant) as virtual, ServoBus(virtual.port, latency_ms=200.0) as bus:
        time.sleep(0.2)  # at least 200 steps due, at most 10 simulated
        assert bus.ping(1) == 1020  # XM430-W350
        stale, stale_s = virtual.stale_replies, virtual.stale_max_s
    # The reply was not held back for the 190+ steps missing: the serving thread
    # never steps the plant (it answers from the latest step), and the lag is said.
    assert "virtual-bus_serve" not in plant.advanced_by
    assert plant.advanced_by["virtual-bus_simulate"] <= 0.002 + 1e-12  # 2 steps a hold
    assert stale >= 1 and stale_s >= 0.1


def test_a_reply_later_than_its_timeout_is_never_read_as_the_next_ones():
    # Every reply 150 ms late against a 102 ms timeout (latency 50 ms): a late reply
    # to "read Min Position Limit" has the id and length of one to "read Max
    # Position Limit". Each read either fails or returns its own register.
    limits = {"Min Position Limit": 1000, "Max Position Limit": 3000}
    virtual = VirtualBus(
        FirstOrderPlant(), registers={1: limits}, faults=[Fault("delay", delay_s=0.15)]
    ).start()
    try:
        with ServoBus(virtual.port, latency_ms=50.0, retries=1) as bus:
            bus.add_servo(1, XM430)
            for register, value in (
                (Register.MIN_POSITION_LIMIT, 1000),
                (Register.MAX_POSITION_LIMIT, 3000),
                (Register.MIN_POSITION_LIMIT, 1000),
            ):
                try:
                    assert bus.read(1, register) == value
                except CommError as e:
                    assert "failed after 2 tries" in str(e)
    finally:
        virtual.stop()


def test_a_step_failing_in_the_plants_process_closes_the_bus():
    class Failing(FirstOrderPlant):
        def advance(self, dt_s):
            if self._goal[0] != 0.0:
                raise SimulationError("the plant failed on a goal")
            super().advance(dt_s)

    virtual = VirtualBus(Failing(), plant_process=True).start()
    try:
        with ServoBus(virtual.port, latency_ms=200.0, retries=0) as bus:
            bus.add_servo(1, XM430)
            with pytest.raises(CommError):  # the goal's reply may already miss it
                bus.write(1, Register.GOAL_POSITION, 2100)
                for _ in range(100_000):  # until the bus goes away
                    bus.read(1, Register.PRESENT_POSITION)
        assert isinstance(virtual.error, SimulationError)
        assert "failed on a goal" in str(virtual.error)
    finally:
        virtual.stop()


def test_the_plants_process_takes_goals_and_settings_in_order():
    virtual = VirtualBus(FirstOrderPlant(time_constant_s=0.0), plant_process=True).start()
    try:
        with ServoBus(virtual.port, latency_ms=200.0) as bus:
            bus.add_servo(1, XM430)
            bus.write(1, Register.GOAL_POSITION, 3000)  # before torque: goal kept
            bus.write(1, Register.TORQUE_ENABLE, 1)  # then the plant moves there
            assert any(bus.read(1, Register.PRESENT_POSITION) == 3000 for _ in range(100_000))
            bus.write(1, Register.TORQUE_ENABLE, 0)
            bus.write(1, Register.GOAL_POSITION, 1000)  # torque off: it stays
            since_s = virtual.sim_time_s
            while virtual.sim_time_s < since_s + 0.005:  # five steps and more
                assert bus.read(1, Register.PRESENT_POSITION) == 3000
    finally:
        virtual.stop()
    with pytest.raises(BadArgument, match="only in real time"):
        VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01, plant_process=True)
