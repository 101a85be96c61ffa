"""The torque check: verdicts, the physics of planned torque, the report, the pytest helper."""

import json

import mujoco
import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen import quat, sim
from trajgen.sim.check import check_torque, resolve_source
from trajgen.sim.dynamics import inverse_dynamics
from trajgen.sim.model import GimbalConfig, build_model
from trajgen.spline import BlendingSpline

GENTLE = ([1.0, 0.4, -0.3], 2.0)  # rad, s: peak speed 0.94 rad/s


def _look_around_spline(time_scale=1.0):
    angles_deg = np.array(
        [(0, 0, 0), (40, 10, 0), (60, -15, 5), (0, 20, 0), (-30, 0, 0), (0, 0, 0)]
    )
    times = np.array([0.0, 1.5, 3.0, 4.5, 6.0, 7.0]) * time_scale
    return BlendingSpline(quat.from_pan_tilt_roll(*np.radians(angles_deg).T), times)


def test_a_gentle_move_passes():
    report = check_torque(quintic_trajectory(*GENTLE))
    assert report.ok
    assert report.reasons == ()
    for joint in report.joints.values():
        assert joint.ok
        assert joint.worst_planned_margin_nm > 0
        assert joint.steps_at_limit == 0
        assert joint.max_tracking_error_rad < 0.05


def test_the_same_move_ten_times_faster_fails_on_the_envelope():
    amplitude, duration = GENTLE
    report = check_torque(quintic_trajectory(amplitude, duration / 10))
    assert not report.ok
    assert not report.joints["pan"].ok
    assert report.joints["pan"].worst_planned_margin_nm < 0
    assert report.joints["pan"].steps_at_limit > 0
    # Past the no-load speed there is no envelope left to exceed: the reason says so.
    assert any(
        r.startswith("pan: planned speed") and "exceeds the XM430-W350's no-load speed" in r
        for r in report.reasons
    )
    assert any(r.startswith("pan: tracking error") for r in report.reasons)


def test_speed_alone_can_fail_the_envelope():
    # Near no-load speed the envelope leaves almost no torque, even for a light load.
    servo = GimbalConfig().servos[0]
    report = check_torque(quintic_trajectory([0.95 * servo.no_load_speed_rad_s, 0, 0], 1.875))
    assert report.joints["pan"].peak_speed_rad_s == pytest.approx(
        0.95 * servo.no_load_speed_rad_s, rel=1e-3
    )
    assert not report.joints["pan"].ok


def test_pure_pan_torque_is_inertia_times_acceleration_plus_friction():
    model = build_model()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    inertia = np.zeros((3, 3))
    mujoco.mj_fullM(model, data, inertia)
    # The rotor's reflected inertia dominates; the links add a little.
    servo = GimbalConfig().servos[0]
    assert servo.armature < inertia[0, 0] < servo.armature + 0.005
    accel = np.array([1.0, 2.0, 4.0, 8.0])
    qdd = np.column_stack([accel, np.zeros(4), np.zeros(4)])
    tau = inverse_dynamics(model, np.zeros((4, 3)), np.zeros((4, 3)), qdd)[:, 0]
    # Linear in acceleration with slope I_zz; the offset is the Coulomb friction.
    slope, offset = np.polyfit(accel, tau, 1)
    assert slope == pytest.approx(inertia[0, 0], rel=1e-9)
    assert offset == pytest.approx(servo.frictionloss, rel=1e-6)
    # At constant speed only friction remains: viscous part grows with speed.
    speed = np.array([0.5, 1.0, 2.0])
    qd = np.column_stack([speed, np.zeros(3), np.zeros(3)])
    tau_w = inverse_dynamics(model, np.zeros((3, 3)), qd, np.zeros((3, 3)))[:, 0]
    np.testing.assert_allclose(np.diff(tau_w), servo.damping * np.diff(speed), rtol=1e-6)


def test_planned_pan_torque_of_a_quintic_scales_with_the_square_of_speed_up():
    # Same path in half the time: accelerations x4, so the inertial torque x4.
    slow = check_torque(quintic_trajectory([1.0, 0, 0], 2.0)).planned_torque_nm[:, 0]
    fast = check_torque(quintic_trajectory([1.0, 0, 0], 1.0)).planned_torque_nm[:, 0]
    friction = GimbalConfig().servos[0].frictionloss
    inertial_slow = np.abs(slow).max() - friction
    inertial_fast = np.abs(fast).max() - friction
    assert inertial_fast / inertial_slow == pytest.approx(4.0, rel=0.05)


def test_json_has_the_documented_keys_and_plain_types():
    report = check_torque(quintic_trajectory(*GENTLE))
    data = json.loads(json.dumps(report.to_json_dict()))
    assert data["ok"] is True
    assert set(data["joints"]) == {"pan", "tilt", "roll"}
    for joint in data["joints"].values():
        for key in (
            "peak_torque_nm",
            "peak_planned_torque_nm",
            "max_tracking_error_rad",
            "peak_torque_rate_nm_s",
            "rms_torque_nm",
            "worst_planned_margin_nm",
            "steps_at_limit",
            "servo",
            "ok",
        ):
            assert key in joint
    assert data["joints"]["pan"]["peak_planned_torque_nm"] == pytest.approx(
        report.joints["pan"].peak_planned_torque_nm
    )


def test_format_is_a_table_with_the_verdict_and_reasons():
    amplitude, duration = GENTLE
    text = check_torque(quintic_trajectory(amplitude, duration / 10)).format()
    assert text.startswith("torque check: FAILED")
    for name in ("pan", "tilt", "roll", "XM430-W350"):
        assert name in text
    assert "  - pan: planned " in text


def test_servo_choice_trades_torque_for_speed():
    # XM540-W270: 10.6 N m stall, 3.1 rad/s no load; XL430-W250: 1.5 N m, 6.4 rad/s.
    # Tracking aside (the budget is wide open): torque alone decides here.
    xl430 = GimbalConfig(servos="XL430-W250", max_tracking_error_rad=1.0)
    xm540 = GimbalConfig(servos="XM540-W270", max_tracking_error_rad=1.0)
    short_hard = quintic_trajectory([0.2, 0.0, 0.0], 0.15)  # 39 rad/s^2, 2.5 rad/s peak
    assert not check_torque(short_hard, config=xl430).ok
    assert check_torque(short_hard, config=xm540).ok
    long_fast = quintic_trajectory([1.0, 0.0, 0.0], 0.5)  # 23 rad/s^2, 3.75 rad/s peak
    assert check_torque(long_fast, config=xl430).ok
    assert not check_torque(long_fast, config=xm540).ok


def test_assert_torque_ok_as_a_user_would_with_a_spline():
    # With default gains (P 800) and the plan sent as it is, pan lags 3.0 deg at
    # its 1.1 rad/s peak, over the default 2.9 deg budget; raising P (on the servos
    # and in the file's [gimbal.pan] etc.) halves the lag; the default led goals
    # remove it at P 800.
    with pytest.raises(sim.TorqueLimitExceeded, match=r"pan: tracking error 0\.05.*lead none"):
        sim.assert_torque_ok(_look_around_spline(), lead="none")
    stiffer = sim.GimbalConfig(joints=({"position_p_gain": 1600},) * 3)
    assert sim.assert_torque_ok(_look_around_spline(), config=stiffer, lead="none").ok
    report = sim.assert_torque_ok(_look_around_spline())
    assert report.ok and report.lead == "model"
    assert report.joints["pan"].max_tracking_error_rad < 0.002
    assert report.rate_hz == 200.0
    with pytest.raises(
        sim.TorqueLimitExceeded, match=r"torque check failed \(\d+ reasons\):\n  - pan: planned"
    ) as e:
        sim.assert_torque_ok(_look_around_spline(time_scale=0.1))
    assert not e.value.report.ok


def test_assert_torque_ok_with_a_trajectory_and_a_config():
    config = GimbalConfig(payload_kg=0.3, torque_margin=0.5)
    report = sim.assert_torque_ok(quintic_trajectory(*GENTLE), config=config)
    assert report.torque_margin == 0.5


def test_resolve_source_refuses_what_it_cannot_use():
    with pytest.raises(TypeError, match=r"`source` to be a keyframe file path, .* got int"):
        resolve_source(42)
    with pytest.raises(ValueError, match=r"`rate_hz` to match the trajectory's 200.0 Hz, got 100"):
        resolve_source(quintic_trajectory(*GENTLE), rate_hz=100)


def test_report_columns_never_run_together():
    from trajgen.sim.check import _cell

    for value in (0.0, -5.711, 334.27, -123456789.0, 1.5e300, -1e11):
        for width, decimals in ((8, 3), (9, 2), (8, 0)):
            text = _cell(value, width, decimals)
            assert len(text) == width and text[0] == " " and text.strip(), (value, text)
            # at least one significant digit survives
            assert float(text) == pytest.approx(value, rel=0.5, abs=10**-decimals)
