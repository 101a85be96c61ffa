"""Led goals on the simulated gimbal: the goals simulated are the goals sent, the error is
against the plan, the old lag comes back without a lead, and the P scale is fitted."""

import argparse
from pathlib import Path

import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.cli import excite, identify
from trajgen.keyframes import BUILTIN_EXAMPLE, load_keyframe_file
from trajgen.sim.check import check_torque, lag_time_s
from trajgen.sim.lead import lead_params, lead_trajectory
from trajgen.sim.model import GimbalConfig, gimbal_config_from_tables
from trajgen.sim.run import goal_ticks_rad, planned_path, simulation_model, step_frames

ROOT = Path(__file__).resolve().parents[1]


def test_lead_params_are_the_firmware_loops():
    # XM430-W350 at 12 V, P 800 / 128: kp 18.9 N m/rad, K^2/R = 4.1 / 4.817 N m s/rad.
    config = GimbalConfig()
    p = lead_params(config)
    np.testing.assert_allclose(p.kp_nm_rad, 800 / 128 * 12 / 885 * 4096 / (2 * np.pi) * 4.1 / 12)
    np.testing.assert_allclose(p.back_emf_nm_s_rad, 4.1 / (46 * 2 * np.pi / 60), rtol=2e-3)
    np.testing.assert_allclose(p.lag_s, [lag_time_s(config, j) for j in range(3)])
    assert 0.044 < p.lag_s[0] < 0.047
    half = lead_params(GimbalConfig(p_divisor=256.0))
    np.testing.assert_allclose(half.kp_nm_rad, p.kp_nm_rad / 2)


def test_sim_runs_the_goals_sent_and_judges_the_plan():
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    config = gimbal_config_from_tables(kf.tables, kf.path)
    report = check_torque(kf, config=config)
    assert report.lead == "model" and report.ok
    traj, rec = report.trajectory, report.record
    # The setpoints are the led goals in whole ticks, the lift's first, held per frame ...
    _, frame = step_frames(traj, config.timestep_s)
    sent = np.vstack([traj.lift.goal, traj.goal])
    np.testing.assert_array_equal(rec.with_lift().setpoint, goal_ticks_rad(sent)[frame])
    assert len(rec.lift.t) == round(traj.lift.duration_s / config.timestep_s)
    assert np.abs(traj.goal - traj.q).max() > 0.02
    # ... the same goals a stream sends (one function) ...
    sent, _, _ = lead_trajectory(traj, config, "model")
    np.testing.assert_array_equal(sent.goal, traj.goal)
    # ... and the error is against the plan, not the goal.
    np.testing.assert_array_equal(rec.planned, planned_path(traj, rec.t))
    for joint in report.joints.values():
        assert joint.max_tracking_error_rad < 0.002
    assert np.abs(rec.hold_error_rad).max() > 0.02  # the servo is well behind its goal


def test_without_lead_the_old_lag_is_back_and_torque_is_not_raised():
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    none = check_torque(kf, lead="none")
    model = check_torque(kf, lead="model")
    advance = check_torque(kf, lead="advance")
    assert none.joints["pan"].max_tracking_error_rad > 0.035  # speed x 45 ms
    assert 0.002 < advance.joints["pan"].max_tracking_error_rad < 0.01
    assert model.joints["pan"].max_tracking_error_rad < 0.002
    for name in ("pan", "tilt", "roll"):
        assert model.joints[name].peak_torque_nm <= 1.05 * none.joints[name].peak_torque_nm
    np.testing.assert_array_equal(none.trajectory.goal, none.trajectory.q)


def test_no_lead_on_a_joint_whose_plan_fails_the_torque_check():
    fast = quintic_trajectory([1.5, 0.05, 0.0], 0.3)  # pan far past the envelope
    report = check_torque(fast, lead="model")
    assert any(r.startswith("pan: planned") for r in report.reasons)
    assert report.lead_notes == ("pan: no lead (the plan fails the torque check)",)
    traj = report.trajectory
    np.testing.assert_array_equal(traj.goal[:, 0], traj.q[:, 0])
    assert np.abs(traj.goal[:, 1] - traj.q[:, 1]).max() > 0


def _run(module, argv):
    parser = argparse.ArgumentParser(prog="trajgen")
    module.register(parser.add_subparsers())
    args = parser.parse_args([str(a) for a in argv])
    return args.func(args)


def test_identify_fits_the_p_scale(tmp_path, capsys):
    # Servos whose firmware divides P by 256 (BAM's XL330), logged with their P 800;
    # fitted from the e-Manual's 128: the scale comes out, the register stays.
    keys = (
        "\n[stream]\nrate_hz = 200\n[[keyframes]]\nt = 0.0\npan = 10.0\n"
        "[[keyframes]]\nt = 1.0\npan = 20.0\n"
    )
    truth = tmp_path / "truth.toml"
    truth.write_text("[gimbal]\np_divisor = 256\n" + keys)
    nominal = tmp_path / "nominal.toml"
    nominal.write_text(keys)
    log = tmp_path / "excite.csv"
    assert _run(excite, ["excite", truth, "--virtual", "--telemetry", log, "--seconds", 4]) == 0
    fitted = tmp_path / "fitted.toml"
    assert _run(identify, ["identify", nominal, log, "--out", fitted, "--p-scale"]) == 0
    capsys.readouterr()
    kf = load_keyframe_file(fitted)
    config = gimbal_config_from_tables(kf.tables, kf.path)
    for j in range(3):
        assert config.joints[j].position_p_gain == 800
        assert config.loop(j).p_divisor == pytest.approx(256.0, rel=0.05)
    assert "p_divisor = " in fitted.read_text()


def test_bus_u2d2_pan_goals_are_previewed_inside_the_plans_range():
    # The XM540 pan's model lead wants a goal past the plan's range on its way into
    # the reversal; the preview keeps every goal inside and acts only around it.
    from dataclasses import replace

    from trajgen.lead import led_goals
    from trajgen.lead_preview import pulse_response
    from trajgen.sim.check import resolve_source
    from trajgen.sim.lead import torque_function
    from trajgen.sim.run import simulation_model

    kf = load_keyframe_file(ROOT / "examples" / "bus_u2d2.toml")
    config = gimbal_config_from_tables(kf.tables, kf.path)
    trajectory, _ = resolve_source(kf, config=config)
    model = simulation_model(config)
    led, goals, notes = lead_trajectory(trajectory, config, "model", model=model)
    assert notes == ()
    pan, b = goals.goal[:, 0], goals.bounds[0]
    assert goals.wanted[:, 0].max() > b[1] + 0.004  # what the lead asked for
    assert pan.max() <= b[1] and pan.min() >= b[0]
    offset = config.joints[0].frictionloss / lead_params(config).kp_nm_rad[0]  # no gravity on pan
    np.testing.assert_allclose(b[1], trajectory.q[:, 0].max() + offset, atol=1e-12)
    plain = led_goals(
        trajectory,
        "model",
        replace(lead_params(config, model), inertia_kg_m2=None),
        torque=torque_function(model),
    )
    moved = np.flatnonzero(pan != plain.goal[:, 0])
    wanted = goals.wanted[:, 0]
    clipped = np.flatnonzero((wanted > b[1]) | (wanted < b[0]))
    assert len(moved) > len(clipped) > 0
    # Only within a settling time of the loop (its windows' reach) of a clip.
    params = lead_params(config, model)
    reach = len(
        pulse_response(
            params.kp_nm_rad[0],
            params.kp_nm_rad[0] * params.lag_s[0],
            params.inertia_kg_m2[0],
            1.0 / trajectory.rate_hz,
        )
    )
    assert np.abs(moved[:, None] - clipped[None, :]).min(axis=1).max() <= reach
    assert len(moved) < 0.8 * len(pan)
    np.testing.assert_array_equal(goals.goal[:, 1:], plain.goal[:, 1:])  # tilt, roll unclipped


def test_the_lead_takes_each_joints_own_table():
    """[gimbal.<joint>] (as `trajgen identify` writes it) sets that joint's lead only."""
    tables = {
        "gimbal": {
            "tilt": {
                "position_p_gain": 1600,
                "p_divisor": 256.0,
                "frictionloss": 0.05,
                "damping": 0.1,
                "armature": 0.06,
            }
        }
    }
    config = gimbal_config_from_tables(tables, "k.toml")
    base, p = lead_params(GimbalConfig()), lead_params(config, simulation_model(config))
    # P 1600 / 256 is P 800 / 128: the same stiffness; the rest is the tilt's own
    np.testing.assert_allclose(p.kp_nm_rad, base.kp_nm_rad)
    np.testing.assert_allclose(p.lag_s[1], (base.back_emf_nm_s_rad[1] + 0.1) / p.kp_nm_rad[1])
    np.testing.assert_allclose(
        p.frictionloss_nm, [base.frictionloss_nm[0], 0.05, base.frictionloss_nm[2]]
    )
    np.testing.assert_allclose(p.lag_s[[0, 2]], base.lag_s[[0, 2]])
    default = lead_params(GimbalConfig(), simulation_model(GimbalConfig()))
    assert p.inertia_kg_m2[1] > default.inertia_kg_m2[1] + 0.01  # the armature
    np.testing.assert_allclose(p.inertia_kg_m2[[0, 2]], default.inertia_kg_m2[[0, 2]])
