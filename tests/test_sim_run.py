"""Running a joint stream: zero-order hold, start at rest, torque vs inverse dynamics, faults."""

from pathlib import Path

import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.sim.dynamics import inverse_dynamics, inverse_dynamics_split
from trajgen.sim.errors import SimulationError
from trajgen.sim.model import GimbalConfig, build_model, gimbal_mjcf
from trajgen.sim.run import (
    goal_ticks_rad,
    planned_path,
    run_batch,
    simulate,
    simulation_model,
    step_and_record,
    step_controls,
    step_frames,
)
from trajgen.stream import JointTrajectory

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_setpoints_are_held_for_one_stream_period():
    trajectory = quintic_trajectory([0.5, 0.2, 0.1], 0.5, rate_hz=200.0)
    record = simulate(trajectory)
    steps_per_frame = 5  # 1 ms physics, 5 ms stream period
    assert len(record.t) == steps_per_frame * len(trajectory.t)
    for i in (0, 17, len(trajectory.t) - 1):
        block = record.setpoint[i * steps_per_frame : (i + 1) * steps_per_frame]
        goal = goal_ticks_rad(trajectory.q[i])  # whole ticks, as Goal Position is
        np.testing.assert_array_equal(block, np.repeat(goal[None], 5, axis=0))
    assert np.abs(record.setpoint[::5] - trajectory.q).max() <= np.pi / 4096 + 1e-15
    np.testing.assert_allclose(np.diff(record.t), 0.001, atol=1e-12)


def test_run_starts_at_rest_where_servos_holding_the_first_goal_sag():
    from trajgen.sim.lead import lead_params

    trajectory = quintic_trajectory([0.5, -0.3, 0.2], 0.5, start_rad=(1.0, 0.2, -0.4))
    record = simulate(trajectory)
    config = GimbalConfig()
    held = goal_ticks_rad(trajectory.q[0])
    zero = np.zeros((1, 3))
    gravity = inverse_dynamics(build_model(), record.q[:1], zero, zero)[0]
    # the loop's torque holds gravity: kp (goal - q) = g(q), a sag of about 1 mrad on the tilt
    np.testing.assert_allclose(
        lead_params(config).kp_nm_rad * (held - record.q[0]), gravity, atol=1e-12
    )
    assert 5e-4 < np.abs(record.q[0] - held).max() < 2e-3
    np.testing.assert_array_equal(record.qd[0], 0.0)


def test_simulated_torque_is_what_moves_the_joints():
    # Inverse dynamics of the simulated motion itself (q, qd at each step and the
    # semi-implicit Euler acceleration (qd[k+1] - qd[k]) / dt) gives back the
    # actuator torque of each step: the record is consistent physics.
    trajectory = quintic_trajectory([1.0, 0.4, -0.6], 1.5, rate_hz=200.0)
    record = simulate(trajectory)
    qdd = np.diff(record.qd, axis=0) / record.timestep_s
    moving = np.all(np.abs(record.qd[:-1]) > 0.05, axis=1)  # away from friction's stick
    expected = inverse_dynamics(
        build_model(), record.q[:-1][moving], record.qd[:-1][moving], qdd[moving]
    )
    # (to 1e-4 N m: Euler integrates joint damping implicitly, inverse dynamics not)
    np.testing.assert_allclose(record.torque_nm[:-1][moving], expected, atol=1e-4)
    assert moving.sum() > 500


def test_stiff_gains_track_closely():
    # The largest P gain the register takes (16383: 386 N m/rad, 2 ms lag).
    trajectory = quintic_trajectory([1.0, 0.4, -0.6], 1.5, rate_hz=1000.0)
    stiff = GimbalConfig(joints=({"position_p_gain": 16383},) * 3)
    assert np.abs(simulate(trajectory, stiff).tracking_error_rad).max() < 4e-3


def test_default_gains_lag_a_ramp_by_speed_times_45_ms():
    # Pan at a constant 0.5 rad/s, streamed at 1 kHz. The firmware drives
    # V = 12 V x (800 / 128) e_pulses / 885 = 55.25 V/rad x e; the motor gives
    # (K / R)(V - K w) with K / R = 4.1 / 12 and K^2 / R = 4.1 / 4.817 = 0.8511,
    # so kp = 18.876 N m/rad. At steady speed w the error balances back-EMF,
    # gear damping (0.01) and Coulomb friction (0.03):
    # e = (0.8511 + 0.01) w / 18.876 + 0.03 / 18.876 = 0.02440 rad at 0.5 rad/s,
    # plus half a tick-free 1 ms hold (w x 0.5 ms) against the continuous plan.
    rate, w = 1000.0, 0.5
    t = np.arange(0.0, 2.0, 1.0 / rate)
    q = np.zeros((len(t), 3))
    q[:, 0] = w * t
    qd = np.zeros_like(q)
    qd[:, 0] = w
    record = simulate(JointTrajectory(t, q, qd, np.zeros_like(q), rate))
    steady = record.t > 1.0
    expected = (0.8511 + 0.01) * w / 18.876 + 0.03 / 18.876 + w * 0.5e-3
    lag = -record.tracking_error_rad[steady, 0]
    assert lag.mean() == pytest.approx(expected, rel=0.01)
    assert lag.mean() / w == pytest.approx(0.0488, abs=5e-4)  # about 45 ms, plus friction


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
    # The 5 ms frame from t = 0.025 s holds the bad goal; its first step warns.
    with pytest.raises(
        SimulationError, match=r"MuJoCo warning in the step at t = 0\.0250 s: mjWARN_BADCTRL"
    ):
        simulate(bad)
    # The same with progress reports (the run in 20 calls).
    with pytest.raises(SimulationError, match=r"at t = 0\.0250 s: mjWARN_BADCTRL"):
        simulate(bad, progress=lambda fraction: None)


def test_a_warning_in_the_last_step_of_one_run_of_a_batch_is_named(tmp_path, monkeypatch):
    # MuJoCo stops a run that warns; in the last step nothing follows to show it
    # stopped, so the warning counters alone must catch it, in the right run.
    monkeypatch.chdir(tmp_path)
    config = GimbalConfig()
    trajectory = quintic_trajectory([0.1, 0.0, 0.0], 0.1)
    step_t, ctrl = step_controls(trajectory, config.timestep_s)
    controls = np.stack([ctrl, ctrl, ctrl])
    controls[1, -1, 2] = 1e20
    models = [simulation_model(config)] * 3
    labels = ["first", "second", "third"]
    at = f"{step_t[-1]:.4f}"
    with pytest.raises(
        SimulationError, match=rf"^second: MuJoCo warning in the step at t = {at} s"
    ):
        run_batch(models, trajectory.q[0], step_t[0], step_t, controls, labels=labels)


def _per_step_loop(trajectory, config):
    """The per-frame ``mj_step`` loop ``simulate`` ran before it used ``run_batch``."""
    import mujoco

    from trajgen.sim.lead import sagged_start

    model = build_model(config)  # with MuJoCo's collision stage, as it was
    data = mujoco.MjData(model)
    step_t, frame = step_frames(trajectory, config.timestep_s)
    goals = goal_ticks_rad(trajectory.q)
    data.qpos[:] = sagged_start(trajectory, config, model)
    data.time = step_t[0]
    mujoco.mj_forward(model, data)
    q, qd, torque = (np.empty((len(step_t), 3)) for _ in range(3))
    bounds = np.append(np.flatnonzero(np.diff(frame, prepend=-1)), len(step_t))
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        data.ctrl[:] = goals[frame[a]]
        step_and_record(model, data, q[a:b], qd[a:b], torque[a:b])
    return q, qd, torque


@pytest.mark.parametrize("example", ["builtin", "sim_too_fast.toml"])
def test_simulate_equals_the_per_step_loop_bit_for_bit(example):
    from trajgen import BUILTIN_EXAMPLE
    from trajgen.sim.check import check_torque, resolve_source

    path = BUILTIN_EXAMPLE if example == "builtin" else EXAMPLES / example
    trajectory, config = resolve_source(str(path))
    q, qd, torque = _per_step_loop(trajectory, config)
    seen = []
    for record in (
        simulate(trajectory, config),
        simulate(trajectory, config, progress=seen.append),
    ):
        np.testing.assert_array_equal(record.q, q)
        np.testing.assert_array_equal(record.qd, qd)
        np.testing.assert_array_equal(record.torque_nm, torque)
    assert len(seen) == 20 and seen[-1] == 1.0
    # The built-in example passes, the other fails (at the torque limit).
    assert check_torque(str(path)).ok == (example == "builtin")


def test_the_simulation_model_refuses_geoms_that_collide(monkeypatch):
    import mujoco

    import trajgen.sim.run as run

    colliding = gimbal_mjcf().replace('contype="0" conaffinity="0"', "")
    monkeypatch.setattr(
        run, "build_model", lambda config: mujoco.MjModel.from_xml_string(colliding)
    )
    with pytest.raises(SimulationError, match="the gimbal model has geoms that can collide"):
        simulate(quintic_trajectory([0.1, 0.0, 0.0], 0.1))


def test_inverse_dynamics_split_equals_two_passes_bit_for_bit():
    trajectory = quintic_trajectory([1.0, -0.4, 0.6], 0.8, rate_hz=200.0)
    model = build_model()
    args = (model, trajectory.q, trajectory.qd, trajectory.qdd)
    tau, smooth = inverse_dynamics_split(*args)
    np.testing.assert_array_equal(tau, inverse_dynamics(*args))
    np.testing.assert_array_equal(smooth, inverse_dynamics(*args, coulomb=False))
    assert np.abs(tau - smooth).max() > 0.01  # the Coulomb friction is there
    # The stages the simulation model skips change nothing here either.
    lean = inverse_dynamics_split(simulation_model(GimbalConfig()), *args[1:])
    np.testing.assert_array_equal(lean[0], tau)
    np.testing.assert_array_equal(lean[1], smooth)


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
    # Fewer steps than reports: one report per step.
    seen.clear()
    t = np.array([0.0, 0.005])
    still = np.zeros((2, 3))
    record = simulate(JointTrajectory(t, still, still, still, 200.0), progress=seen.append)
    assert len(record.t) == 10
    assert seen == [k / 10 for k in range(1, 11)]


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
