"""The library session (``drivers.session.Session``): a stream or a follow loop
without the command line, each servo's state after every kind of stop."""

import math

import numpy as np
import pytest

from trajgen import BlendingSpline, plan_joint_trajectory
from trajgen import quat as Q
from trajgen.drivers.bringup import JointRange, check_plan, check_servos, inspect
from trajgen.drivers.bus import ServoBus
from trajgen.drivers.config import BusConfig
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import BringUpError
from trajgen.drivers.session import HOLDING, NOT_MOVED, RELEASED, UNKNOWN, UNTOUCHED, Session
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import Fault, VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant
from trajgen.follower import Follower
from trajgen.online import OnlineSpline

RATE_HZ = 100.0
IDS = (1, 2, 3)


def _path(tilt_deg=5.0, seconds=0.8):
    quats = Q.from_pan_tilt_roll(np.radians([0.0, 10.0, 0.0]), np.radians([0.0, tilt_deg, 0.0]), 0)
    return BlendingSpline(quats, [0.0, seconds / 2, seconds])


@pytest.mark.parametrize(("on_stop", "state"), [("hold", HOLDING), ("torque_off", RELEASED)])
def test_a_stream_runs_to_its_end_and_states_each_servo(on_stop, state):
    with VirtualBus(FirstOrderPlant(), lockstep_dt_s=1 / RATE_HZ) as virtual:
        session = Session(BusConfig(port=virtual.port), on_stop=on_stop, max_delay_s=None)
        outcome = session.stream_path(_path(), RATE_HZ)
        torque = [virtual.servos[i].torque_on for i in IDS]
        received = virtual.frames_received
    assert outcome.ok and outcome.stage == "" and outcome.signal is None
    assert outcome.servo_states == dict.fromkeys(IDS, state)
    assert outcome.stats.frames_sent == len(outcome.trajectory) == 81
    assert received == outcome.stats.frames_sent + outcome.stats.approach_frames
    assert torque == [on_stop == "hold"] * 3
    assert outcome.bring_up_summary()["tilt"]["servo"] == 2


def test_a_plan_outside_the_installed_limits_moves_no_servo():
    limits = {Register.MIN_POSITION_LIMIT: 2000, Register.MAX_POSITION_LIMIT: 2080}
    with VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01, registers={2: limits}) as virtual:
        outcome = Session(BusConfig(port=virtual.port)).stream_path(_path(), RATE_HZ)
        assert virtual.frames_received == 0
        assert not any(s.torque_on for s in virtual.servos.values())
    assert outcome.stage == "bring-up" and outcome.refused and outcome.stats is None
    assert outcome.servo_states == dict.fromkeys(IDS, NOT_MOVED)
    assert outcome.stopped_by.startswith("tilt leaves its position limits at t = 0.")


def test_set_limits_are_given_in_joint_radians_and_written_as_ticks():
    with VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01) as virtual:
        session = Session(BusConfig(port=virtual.port), set_limits_rad={1: (-0.35, 0.35)})
        assert session.set_limits == {2: (2048 - 228, 2048 + 228)}
        assert session.stream_path(_path(), RATE_HZ).ok
        tilt = virtual.servos[2]
        assert (tilt.get(Register.MIN_POSITION_LIMIT), tilt.get(Register.MAX_POSITION_LIMIT)) == (
            1820,
            2276,
        )
    with pytest.raises(ValueError, match=r"tilt limits: ticks -228\.\.2162 fall outside"):
        Session(set_limits_rad={1: (math.radians(-200), math.radians(10))})


def test_a_port_that_does_not_open_touches_nothing(tmp_path):
    outcome = Session(BusConfig(port=str(tmp_path / "tty"))).stream_path(_path(), RATE_HZ)
    assert outcome.stage == "open" and not outcome.ok and "cannot open" in outcome.stopped_by
    assert outcome.servo_states == dict.fromkeys(IDS, UNTOUCHED)


def test_a_port_lost_mid_stream_leaves_every_servo_unknown():
    faults = [Fault("close", at_frame=30)]
    with VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01, faults=faults) as virtual:
        session = Session(BusConfig(port=virtual.port))
        outcome = session.stream_path(_path(), RATE_HZ)
    assert outcome.stage == "stream" and outcome.stats.frames_sent < 81
    assert outcome.stop_errors and outcome.servo_states == dict.fromkeys(IDS, UNKNOWN)


def test_a_session_streams_to_a_plant_of_its_own():
    outcome = Session(plant=FirstOrderPlant()).stream_path(_path(), RATE_HZ)
    assert outcome.ok and outcome.virtual_error is None
    assert outcome.servo_states == dict.fromkeys(IDS, HOLDING)


def test_a_follow_loop_runs_without_the_command_line():
    spline = OnlineSpline([1.0, 0, 0, 0])
    follower = Follower(spline, RATE_HZ)
    lines = ['{"t": 0.5, "pan": 10}', "not json", '{"t": 1.0, "pan": -5, "mode": "extend"}']
    # Pan's range is more than a turn: Extended Position Mode, an EEPROM change asked for.
    session = Session(BusConfig(configure=True), plant=FirstOrderPlant(), max_delay_s=None)
    outcome = session.follow(follower, lines)
    assert outcome.ok and outcome.servo_states == dict.fromkeys(IDS, HOLDING)
    assert [k["line"] for k in follower.keyframes] == [1, 3] and len(follower.skipped) == 1
    traj = outcome.trajectory
    assert traj.t[-1] >= 1.0 and np.allclose(traj.qd[-1], 0.0, atol=1e-9)
    assert abs(traj.q[-1, 0] - math.radians(-5)) < 1e-9


def test_bring_up_checks_a_joint_range_not_a_fake_trajectory():
    limits = {Register.MIN_POSITION_LIMIT: 1000, Register.MAX_POSITION_LIMIT: 3000}
    with VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01, registers={1: limits}) as virtual:
        bus = ServoBus(virtual.port).open()
        try:
            check_servos(bus, JointMap(), BusConfig().models)
            installed = inspect(bus, JointMap())
        finally:
            bus.close()
    wide = JointRange(np.zeros(3), np.radians([[-170, 170], [-80, 80], [-170, 170]]))
    with pytest.raises(BringUpError, match=r"pan leaves its position limits within its joint"):
        check_plan(installed, JointMap(), wide)
    narrow = JointRange(np.zeros(3), np.radians([[-80, 80], [-80, 80], [-170, 170]]))
    modes, _ = check_plan(installed, JointMap(), narrow)
    trajectory = plan_joint_trajectory(_path(), RATE_HZ)
    assert modes == check_plan(installed, JointMap(), trajectory)[0] == (3, 3, 3)


def test_an_overloaded_servo_is_stated_apart_from_the_others():
    faults = [Fault("overload", at_frame=30, servo_id=2)]
    with VirtualBus(FirstOrderPlant(), lockstep_dt_s=0.01, faults=faults) as virtual:
        outcome = Session(BusConfig(port=virtual.port)).stream_path(_path(), RATE_HZ)
        torque = {i: virtual.servos[i].torque_on for i in IDS}
    assert outcome.stage == "stream" and "servo 2" in outcome.stopped_by
    assert torque == {1: True, 2: False, 3: True}
    assert outcome.servo_states[1] == outcome.servo_states[3] == HOLDING
    # Its replies carry the hardware error, so its Torque Enable is not taken from them.
    assert outcome.servo_states[2] == UNKNOWN
    assert any(m.startswith("state unknown: servo 2: hardware error") for m in outcome.stop_errors)
