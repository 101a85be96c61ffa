"""Servo data and the simulated motor's torque-speed envelope."""

import math

import mujoco
import numpy as np
import pytest

from trajgen.sim.model import GimbalConfig, build_model
from trajgen.sim.run import at_torque_limit
from trajgen.sim.servos import SERVOS, XM430_W350, servo_by_name


def test_xm430_ratings_in_si_units():
    # e-Manual: 4.1 N m and 2.3 A stall, 46 rpm no load, at 12 V.
    assert XM430_W350.no_load_speed_rad_s == pytest.approx(46 * 2 * math.pi / 60)
    assert XM430_W350.no_load_speed_rad_s == pytest.approx(4.817, abs=1e-3)
    assert XM430_W350.torque_constant_nm_a == pytest.approx(4.1 / 2.3)


def test_envelope_is_the_torque_speed_line():
    w0 = XM430_W350.no_load_speed_rad_s
    assert XM430_W350.tau_max(0.0) == pytest.approx(4.1)
    assert XM430_W350.tau_max(w0 / 2) == pytest.approx(2.05)
    assert XM430_W350.tau_max(-w0 / 2) == pytest.approx(2.05)
    assert XM430_W350.tau_max(w0) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(XM430_W350.tau_max(np.array([0.0, w0])), [4.1, 0.0], atol=1e-12)


def test_every_model_has_positive_parameters():
    assert {"XM430-W350", "XL430-W250", "XH430-W350", "XM540-W270"} <= set(SERVOS)
    for servo in SERVOS.values():
        for value in (servo.stall_torque_nm, servo.no_load_speed_rad_s, servo.armature):
            assert value > 0


def test_lookup_is_case_insensitive_and_names_the_known_models():
    assert servo_by_name("xm540-w270") is SERVOS["XM540-W270"]
    with pytest.raises(ValueError, match=r"unknown model 'XM999' \(known: XM430-W350, "):
        servo_by_name("XM999")
    with pytest.raises(TypeError, match=r"Expected a servo model name, got 430"):
        servo_by_name(430)


@pytest.mark.parametrize("name", sorted(SERVOS))
def test_simulated_motor_at_full_drive_follows_the_envelope(name):
    # Command a far-away target: the drive saturates at the rated voltage and the torque
    # delivered must be tau_stall (1 - w / w0) at every speed the joint passes.
    servo = SERVOS[name]
    config = GimbalConfig(servos=(servo,) * 3)
    model = build_model(config)
    data = mujoco.MjData(model)
    data.ctrl[0] = 100.0
    speed, torque = [], []
    for _ in range(1500):
        speed.append(data.qvel[0])
        mujoco.mj_step(model, data)
        torque.append(data.actuator_force[0])
    speed, torque = np.array(speed), np.array(torque)
    assert speed.max() > 0.5 * servo.no_load_speed_rad_s
    np.testing.assert_allclose(torque, servo.tau_max(speed), rtol=1e-9, atol=1e-12)
    qd = np.column_stack([speed, np.zeros_like(speed), np.zeros_like(speed)])
    tau = np.column_stack([torque, np.zeros_like(torque), np.zeros_like(torque)])
    assert at_torque_limit(config, qd, tau)[:, 0].all()
    assert not at_torque_limit(config, qd, 0.5 * tau)[:, 0].any()
