"""The X-series firmware's position loop: register units, MuJoCo gains, the plant's registers."""

import math
import re

import mujoco
import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.sim.firmware import (
    PULSES_PER_RAD,
    PositionLoop,
    UnsupportedServoSetting,
    loop_from_registers,
)
from trajgen.sim.lead import sagged_start
from trajgen.sim.model import GimbalConfig, build_model, gimbal_mjcf
from trajgen.sim.plant import GimbalPlant
from trajgen.sim.run import goal_ticks_rad, simulate
from trajgen.sim.servos import XM430_W350


def test_pwm_by_hand():
    loop = PositionLoop()  # P 800, I 0, D 0, PWM Limit 885
    assert loop.pwm(100) == pytest.approx(800 / 128 * 100)  # 625
    assert loop.pwm(-100) == pytest.approx(-625)
    assert loop.pwm(200) == 885  # 1250, clipped at 100 %
    assert PositionLoop(pwm_limit=500).pwm(200) == 500
    assert PositionLoop(goal_pwm=300).pwm(-200) == -300
    assert PositionLoop(p_gain=0, i_gain=100).pwm(0, error_sum_pulses=65536) == pytest.approx(100)
    assert PositionLoop(p_gain=0, d_gain=160).pwm(0, error_change_pulses=3) == pytest.approx(30)
    assert PositionLoop(p_divisor=256).pwm(100) == pytest.approx(312.5)  # BAM's XL330 scale


def test_mujoco_gains_of_the_default_loop():
    # 800 / 128 PWM per pulse x 4096 / 2 pi pulses per rad x 12 V / 885 = 55.25 V/rad;
    # x K / R = 4.1 N m / 12 V = 18.876 N m/rad. Back-EMF K^2 / R = 4.1 / 4.817 = 0.8511.
    kp, ki, kd, vmax = PositionLoop().mujoco_controller(XM430_W350)
    assert 800 / 128 * PULSES_PER_RAD * 12 / 885 == pytest.approx(55.25, abs=0.01)
    assert kp == pytest.approx(18.876, abs=1e-3)
    assert ki == 0.0
    assert kd == pytest.approx(0.8511, abs=1e-4)
    assert vmax == 12.0
    assert PositionLoop(goal_pwm=354).mujoco_controller(XM430_W350)[3] == pytest.approx(4.8)


def _voltage_model():
    """The gimbal with raw voltage inputs instead of the native controller."""
    xml = re.sub(r' controller="[^"]*"', "", gimbal_mjcf())
    return mujoco.MjModel.from_xml_string(xml.replace('input="pos"', 'input="voltage"'))


def test_native_actuator_is_the_firmware_loop_driving_a_voltage():
    # A 1 kHz loop of PWM = clip(P / 128 e_pulses, +-885), V = 12 PWM / 885 into a
    # voltage-driven <dcmotor>, against the <dcmotor input="pos"> controller: one
    # step into saturation (0.8 rad: 44 V asked) and back.
    native = mujoco.MjModel.from_xml_string(gimbal_mjcf())
    voltage = _voltage_model()
    a, b = mujoco.MjData(native), mujoco.MjData(voltage)
    loop = PositionLoop()
    goals = np.array([[0.8, -0.3, 0.2], [0.0, 0.0, 0.0]])
    qs = []
    for goal in goals:
        for _ in range(400):
            a.ctrl[:] = goal
            b.ctrl[:] = 12.0 * loop.pwm((goal - b.qpos) * PULSES_PER_RAD) / 885
            mujoco.mj_step(native, a)
            mujoco.mj_step(voltage, b)
            qs.append((a.qpos.copy(), b.qpos.copy()))
    q_native, q_voltage = (np.array(x) for x in zip(*qs, strict=True))
    assert np.abs(q_native).max() > 0.7  # it moved, and saturated on the way
    np.testing.assert_allclose(q_native, q_voltage, atol=1e-12)


def test_registers_that_are_not_simulated_are_refused():
    with pytest.raises(UnsupportedServoSetting, match=r"tilt: Profile Velocity 50 is not simul"):
        loop_from_registers({"Profile Velocity": 50}, joint="tilt")
    with pytest.raises(UnsupportedServoSetting, match=r"Profile Acceleration 10"):
        loop_from_registers({"Profile Acceleration": 10})
    with pytest.raises(UnsupportedServoSetting, match=r"Operating Mode 16 is not simulated"):
        loop_from_registers({"Operating Mode": 16})
    with pytest.raises(ValueError, match=r"`p_gain` to be an integer in 0..16383, got 20000"):
        loop_from_registers({"Position P Gain": 20000})
    # Feed-forward acts on the profile only: accepted, and without effect.
    assert loop_from_registers({"Feedforward 1st Gain": 100}) == PositionLoop()
    assert loop_from_registers({"Operating Mode": 4, "PWM Limit": 600}).pwm_cap == 600


def _enabled_plant(**kwargs):
    plant = GimbalPlant(**kwargs)
    for joint in range(3):
        plant.set_torque_enabled(joint, True)
    return plant


def test_present_pwm_by_hand():
    plant = GimbalPlant()
    np.testing.assert_array_equal(plant.present_pwm(), 0.0)  # torque off
    plant = _enabled_plant()
    plant.set_goal([0.01, -0.02, 1.0])
    # At rest: V = 55.25 V/rad x error, over 12 V; roll asks 55 V and is capped.
    volts_per_rad = 800 / 128 * PULSES_PER_RAD * 12 / 885
    np.testing.assert_allclose(
        plant.present_pwm(), [volts_per_rad * 0.01 / 12, -volts_per_rad * 0.02 / 12, 1.0]
    )
    plant.set_control(2, {"Goal PWM": 354})
    assert plant.present_pwm()[2] == pytest.approx(0.4)


def test_plant_follows_its_registers():
    trajectory = quintic_trajectory([0.7, 0.0, 0.0], 1.5)

    def pan_lag(registers):
        plant = _enabled_plant()
        for joint in range(3):
            plant.set_control(joint, registers)
        for frame in trajectory:
            plant.set_goal(goal_ticks_rad(frame.q))
            plant.advance(1 / trajectory.rate_hz)
        return plant.report(trajectory).joints["pan"].max_tracking_error_rad

    default, doubled = pan_lag({"Position P Gain": 800}), pan_lag({"Position P Gain": 1600})
    assert doubled == pytest.approx(default / 2, rel=0.1)


def test_integral_gain_rebuilds_the_model_and_removes_the_gravity_offset():
    # A 1 kg camera 5 cm ahead of the tilt axis: gravity pulls tilt down by
    # (its torque) / kp, which only an integral term removes.
    plant = _enabled_plant(config=GimbalConfig(payload_kg=1.0, payload_offset_m=(0.05, 0, 0)))
    plant.set_goal([0.0, 0.0, 0.0])
    plant.advance(1.0)
    gravity_nm = plant._data.qfrc_bias[1]
    offset = plant.read()[0][1]
    assert abs(offset) > 0.01
    assert offset == pytest.approx(-gravity_nm / 18.876, rel=0.05)
    t = plant.time_s
    plant.set_control(1, {"Position I Gain": 2000})
    assert plant._model.na == 1  # the integrator's state
    assert plant.time_s == t and plant.read()[0][1] == offset
    plant.advance(3.0)
    assert abs(plant.read()[0][1]) < 0.1 * abs(offset)


def test_plant_and_sim_run_the_same_servo():
    trajectory = quintic_trajectory([0.9, -0.4, 0.3], 1.0, start_rad=(0.2, 0.1, 0.0))
    config = GimbalConfig(joints=({"position_p_gain": 1200, "armature": 0.03}, {}, {}))
    record = simulate(trajectory, config)
    # where `simulate` starts: sagged under the first goal
    plant = GimbalPlant(config, initial_rad=sagged_start(trajectory, config, build_model(config)))
    for joint in range(3):
        plant.set_torque_enabled(joint, True)
    for frame in trajectory:
        plant.set_goal(goal_ticks_rad(frame.q))
        plant.advance(1 / trajectory.rate_hz)
    plant.advance(0.0)
    replayed = plant.report(trajectory).record
    np.testing.assert_allclose(replayed.q, record.q, atol=1e-12)
    np.testing.assert_allclose(replayed.torque_nm, record.torque_nm, atol=1e-9)
    assert math.isclose(replayed.t[-1], record.t[-1], abs_tol=1e-9)
