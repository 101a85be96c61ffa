"""Running a joint stream: zero-order hold, start at rest, torque vs inverse dynamics, faults."""

import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.sim.dynamics import inverse_dynamics
from trajgen.sim.errors import SimulationError
from trajgen.sim.model import build_model, gimbal_mjcf
from trajgen.sim.run import planned_path, simulate
from trajgen.stream import JointTrajectory


def test_setpoints_are_held_for_one_stream_period():
    trajectory = quintic_trajectory([0.5, 0.2, 0.1], 0.5, rate_hz=200.0)
    record = simulate(trajectory)
    steps_per_frame = 5  # 1 ms physics, 5 ms stream period
    assert len(record.t) == steps_per_frame * len(trajectory.t)
    for i in (0, 17, len(trajectory.t) - 1):
        block = record.setpoint[i * steps_per_frame : (i + 1) * steps_per_frame]
        np.testing.assert_array_equal(block, np.repeat(trajectory.q[i][None], 5, axis=0))
    np.testing.assert_allclose(np.diff(record.t), 0.001, atol=1e-12)


def test_run_starts_at_rest_at_the_first_frame():
    trajectory = quintic_trajectory([0.5, -0.3, 0.2], 0.5, start_rad=(1.0, 0.2, -0.4))
    record = simulate(trajectory)
    np.testing.assert_array_equal(record.q[0], [1.0, 0.2, -0.4])
    np.testing.assert_array_equal(record.qd[0], 0.0)


def test_simulated_torque_agrees_with_inverse_dynamics_when_tracking_is_good():
    # A 1 kHz stream (one setpoint per physics step) on all three joints.
    trajectory = quintic_trajectory([1.0, 0.4, -0.6], 1.5, rate_hz=1000.0)
    record = simulate(trajectory)
    assert np.abs(record.tracking_error_rad).max() < 1e-3
    n = len(trajectory.t)
    expected = inverse_dynamics(build_model(), trajectory.q, trajectory.qd, trajectory.qdd)
    difference = record.torque_nm[:n] - expected
    peak = np.abs(expected).max(axis=0)
    assert np.all(np.sqrt(np.mean(difference**2, axis=0)) < 0.01 * peak)
    assert np.all(np.abs(difference).max(axis=0) < 0.05 * peak)


def test_zero_order_hold_lag_is_about_half_a_period_of_motion():
    trajectory = quintic_trajectory([1.0, 0.0, 0.0], 2.0, rate_hz=100.0)
    record = simulate(trajectory, feedforward=False)
    peak_speed = 1.875 * 1.0 / 2.0
    error = np.abs(record.tracking_error_rad[:, 0]).max()
    # The servo follows a staircase: never more than a period's motion behind.
    assert 0.1 * peak_speed / 100.0 < error < peak_speed / 100.0


def test_planned_path_is_exact_at_samples_and_between_them_for_a_cubic():
    t = np.linspace(0.0, 1.0, 11)
    q = np.column_stack([t**3, t**2, t])
    qd = np.column_stack([3 * t**2, 2 * t, np.ones_like(t)])
    trajectory = JointTrajectory(t, q, qd, np.zeros_like(q), 10.0)
    fine = np.linspace(0.0, 1.0, 101)
    expected = np.column_stack([fine**3, fine**2, fine])
    np.testing.assert_allclose(planned_path(trajectory, fine), expected, atol=1e-12)


def test_a_mujoco_warning_fails_the_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs warnings to ./MUJOCO_LOG.TXT
    trajectory = quintic_trajectory([0.1, 0.0, 0.0], 0.1)
    q = trajectory.q.copy()
    q[5:, 0] = 1e20  # finite, but MuJoCo flags it as a huge control
    bad = JointTrajectory(trajectory.t, q, trajectory.qd, trajectory.qdd, trajectory.rate_hz)
    with pytest.raises(
        SimulationError, match=r"MuJoCo warning between t = 0\.0250 and 0\.0300 s: mjWARN_BADCTRL"
    ):
        simulate(bad, feedforward=False)


def test_contacts_inside_the_gimbal_are_refused():
    # Give the geoms their default collision flags: the base (world) and the pan
    # link overlap, which is what happens when contype/conaffinity are forgotten.
    import mujoco

    colliding = mujoco.MjModel.from_xml_string(
        gimbal_mjcf().replace('contype="0" conaffinity="0"', "")
    )
    zeros = np.zeros((1, 3))
    with pytest.raises(SimulationError, match=r"contact\(s\) inside the gimbal at sample 0"):
        inverse_dynamics(colliding, zeros, zeros, zeros)


def test_progress_is_reported_up_to_one():
    seen = []
    simulate(quintic_trajectory([0.2, 0.0, 0.0], 0.5), progress=seen.append)
    assert seen[-1] == 1.0
    assert len(seen) >= 10
    assert seen == sorted(seen)


@pytest.mark.parametrize(
    ("trajectory", "error", "match"),
    [
        ("not a trajectory", TypeError, r"`trajectory` to be a JointTrajectory, got str"),
        (
            JointTrajectory(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), 1.0),
            ValueError,
            r"`trajectory.t` to have shape \(N,\), N >= 2, got \(1,\)",
        ),
        (
            JointTrajectory(
                np.arange(2.0), np.zeros((2, 2)), np.zeros((2, 3)), np.zeros((2, 3)), 1
            ),
            ValueError,
            r"`trajectory.q` to have shape \(2, 3\), got \(2, 2\)",
        ),
        (
            JointTrajectory(
                np.arange(2.0), np.zeros((2, 3)), np.full((2, 3), np.nan), np.zeros((2, 3)), 1
            ),
            ValueError,
            r"`trajectory.qd` to be finite",
        ),
    ],
)
def test_bad_trajectories_are_refused(trajectory, error, match):
    with pytest.raises(error, match=match):
        simulate(trajectory)


def test_inverse_dynamics_checks_shapes():
    with pytest.raises(ValueError, match=r"`qd` to have shape \(N, 3\), got \(4,\)"):
        inverse_dynamics(build_model(), np.zeros((4, 3)), np.zeros(4), np.zeros((4, 3)))
