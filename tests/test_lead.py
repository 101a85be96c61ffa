"""The led goals of trajgen.lead against hand-worked values, and their bounds."""

import numpy as np
import pytest

from trajgen.lead import (
    LEAD_CAP,
    LeadParams,
    LedFrames,
    check_lead,
    lead_cap,
    led_goals,
    led_trajectory,
    ramp,
    sent_q,
)
from trajgen.stream import JointTrajectory

RATE = 200.0
H = 0.5 / RATE  # half a stream period: goals are held for one period
KP, K2R, DAMP, FRIC, GRAV, INERTIA = 20.0, 0.8, 0.2, 0.03, 0.04, 0.05
TAU = (K2R + DAMP) / KP  # 0.05 s


def params(n=3, **kw):
    base = dict(
        kp_nm_rad=[KP] * n,
        back_emf_nm_s_rad=[K2R] * n,
        lag_s=[TAU] * n,
        frictionloss_nm=[FRIC] * n,
        enabled=True,
    )
    base.update(kw)
    return LeadParams(**base)


def torque(q, qd, qdd):
    """A hand-checkable plant: inertia, viscous damping, constant gravity; no Coulomb."""
    return INERTIA * qdd + DAMP * qd + GRAV


def linear(v=0.5, duration=1.0, start_moving=True):
    t = np.arange(int(duration * RATE) + 1) / RATE
    q = np.outer(v * t, np.ones(3))
    return JointTrajectory(t, q, np.full_like(q, v), np.zeros_like(q), RATE)


def sine(amplitude=1.0, hz=0.5, cycles=2):
    t = np.arange(int(cycles / hz * RATE) + 1) / RATE
    w = 2 * np.pi * hz
    one = np.ones(3)
    q = np.outer(amplitude * np.sin(w * t), one)
    qd = np.outer(amplitude * w * np.cos(w * t), one)
    qdd = np.outer(-amplitude * w**2 * np.sin(w * t), one)
    return JointTrajectory(t, q, qd, qdd, RATE)


def test_model_lead_matches_the_hand_worked_value_at_constant_speed():
    tr = linear(v=0.5)
    goals = led_goals(tr, "model", params(), torque=torque)
    i = 100  # mid-stream: both ramps at 1, nothing clipped
    # q(s) = q + v h; lead = (tau_id - gravity + K2R v) / kp = (D + K2R) v / kp; + gravity / kp
    expected = tr.q[i] + 0.5 * H + (DAMP + K2R) * 0.5 / KP + GRAV / KP
    np.testing.assert_allclose(goals.goal[i], expected, rtol=0, atol=1e-15)
    assert expected[0] - tr.q[i, 0] == pytest.approx(0.00125 + 0.025 + 0.002)


def test_model_lead_includes_the_inertia_term():
    tr = sine()
    goals = led_goals(tr, "model", params(), torque=torque)
    i = 30
    q, qd, qdd = tr.q[i], tr.qd[i], tr.qdd[i]
    q_s, qd_s = q + qd * H + 0.5 * qdd * H**2, qd + qdd * H
    expected = q_s + (INERTIA * qdd + (DAMP + K2R) * qd_s) / KP + GRAV / KP
    np.testing.assert_allclose(goals.goal[i], expected, atol=1e-15)


def test_advance_lead_is_the_plan_tau_plus_half_a_period_later():
    tr = linear(v=0.5)
    goals = led_goals(tr, "advance", params())
    i = 100
    np.testing.assert_allclose(goals.goal[i], tr.q[i] + 0.5 * (TAU + H), atol=1e-14)


def test_none_sends_the_plan():
    tr = sine()
    goals = led_goals(tr, "none", params())
    np.testing.assert_array_equal(goals.goal, tr.q)
    assert sent_q(tr) is tr.q
    np.testing.assert_array_equal(sent_q(led_trajectory(tr, goals)), tr.q)


def test_unknown_lead_and_model_without_torque_are_refused():
    with pytest.raises(ValueError, match="Expected `lead` to be one of"):
        check_lead("ahead")
    with pytest.raises(ValueError, match="Expected `torque`"):
        led_goals(linear(), "model", params())


def test_goals_stay_in_the_plans_range_at_reversals():
    # A velocity-only lead with a long lag overshoots each reversal by about
    # |qdd| tau^2 / 2 (here 0.1 s: ~0.05 rad); the goal must not.
    slow = params(lag_s=[0.1] * 3, back_emf_nm_s_rad=[2.0] * 3)
    tr = sine(amplitude=1.0, hz=0.5)

    def viscous(q, qd, qdd):
        return 0.0 * qd

    goals = led_goals(tr, "model", slow, torque=viscous)
    offset = FRIC / KP
    assert goals.goal.max() <= tr.q.max() + offset + 1e-12
    assert goals.goal.min() >= tr.q.min() - offset - 1e-12
    assert (goals.clipped > 0).all()  # the bound did act
    unbounded = tr.q + tr.qd * 2.0 / KP  # what it would have sent
    assert unbounded.max() > tr.q.max() + offset + 0.01


def test_goals_stay_inside_installed_limits():
    tr = sine(amplitude=1.0)
    limits = np.array([[-0.9, 0.95]] * 3)
    goals = led_goals(tr, "model", params(), torque=torque, limits_rad=limits)
    assert goals.goal.max() <= 0.95 and goals.goal.min() >= -0.9
    assert goals.goal.max() == 0.95  # the limit, not the plan, bounded it
    np.testing.assert_array_equal(goals.bounds, limits)


def test_the_lead_is_capped():
    tr = linear(v=0.5)

    def huge(q, qd, qdd):
        return 100.0 * qd

    goals = led_goals(tr, "model", params(), torque=huge)
    cap = LEAD_CAP * TAU * 0.5 + FRIC / KP
    np.testing.assert_allclose(lead_cap(tr.qd, params()), cap)
    i = 100
    # no gravity in this plant: the capped lead alone
    np.testing.assert_allclose(goals.goal[i], tr.q[i] + 0.5 * H + cap, atol=1e-15)


def test_ramp_in_for_a_plan_that_starts_moving_and_out_to_the_end():
    tr = linear(v=0.5, duration=1.0)
    goals = led_goals(tr, "model", params(), torque=torque)
    full = (DAMP + K2R) * 0.5 / KP
    lead = goals.goal - tr.q - 0.5 * H - GRAV / KP  # the ramped dynamic lead
    # first frame: no dynamic lead, only the half-period and the static term in full
    # (the lift before it brought that in: trajgen.lift)
    np.testing.assert_allclose(goals.goal[0], tr.q[0] + 0.5 * H + GRAV / KP, atol=1e-15)
    assert goals.lift is not None
    np.testing.assert_allclose(goals.lift.goal[-1], tr.q[0] + GRAV / KP, atol=1e-15)
    n_ramp = int(TAU * RATE)  # frames within tau of the start
    w = ramp(np.arange(n_ramp + 1) / n_ramp)
    np.testing.assert_allclose(lead[: n_ramp + 1, 0], full * w, atol=1e-15)
    assert np.all(np.diff(lead[: n_ramp + 1, 0]) > 0)
    np.testing.assert_allclose(lead[n_ramp:-n_ramp, 0], full)
    # the ramp out takes the dynamic part only; this plan ends moving, so the range
    # (the plan's end + the static offset) clips the last goals
    end = slice(-n_ramp - 1, None)
    h = np.minimum(H, tr.t[-1] - tr.t[end])
    unbounded = tr.q[end, 0] + 0.5 * h + full * w[::-1] + GRAV / KP
    top = tr.q[-1, 0] + (GRAV + FRIC) / KP
    np.testing.assert_allclose(goals.goal[end, 0], np.minimum(unbounded, top), atol=1e-15)
    assert (unbounded > top).sum() >= 3
    # last frame: the plan's end plus gravity; it stays inside the range + offset
    np.testing.assert_allclose(goals.goal[-1], tr.q[-1] + GRAV / KP, atol=1e-15)
    np.testing.assert_allclose(goals.bounds[:, 1], tr.q[-1] + (GRAV + FRIC) / KP)


def test_a_disabled_joint_gets_the_plan():
    tr = sine()
    goals = led_goals(tr, "model", params().without([1]), torque=torque)
    np.testing.assert_array_equal(goals.goal[:, 1], tr.q[:, 1])
    assert np.abs(goals.goal[:, 0] - tr.q[:, 0]).max() > 0.01


def test_led_trajectory_frames_carry_plan_and_goal():
    tr = sine()
    led = led_trajectory(tr, led_goals(tr, "model", params(), torque=torque))
    frames = list(led)
    np.testing.assert_array_equal(frames[7].q, tr.q[7])
    np.testing.assert_array_equal(frames[7].goal, led.goal[7])
    assert list(tr)[7].goal is None


def test_follow_frames_lead_from_each_frames_own_state():
    tr = sine()
    bounds = np.array([[-1.5, 1.5]] * 3)
    cap = lead_cap(tr.qd, params())
    live = list(LedFrames(iter(tr), RATE, "model", params(), bounds, cap, torque=torque))
    whole = led_goals(tr, "model", params(), torque=torque)
    n_ramp = int(TAU * RATE)
    # away from the end (a live plan has no ramp out), the same goals
    np.testing.assert_allclose(
        [f.goal for f in live[: -n_ramp - 1]], whole.goal[: -n_ramp - 1], atol=1e-15
    )
    np.testing.assert_array_equal(live[5].q, tr.q[5])  # the plan rides along
    # clipped to the given bounds
    tight = np.array([[-0.5, 0.5]] * 3)
    clipped = [f.goal for f in LedFrames(iter(tr), RATE, "model", params(), tight, cap, torque)]
    assert np.max(clipped) == 0.5 and np.min(clipped) == -0.5


def test_follow_advance_extrapolates_from_the_frame():
    tr = linear(v=0.5)
    bounds = np.array([[-1.0, 2.0]] * 3)
    cap = lead_cap(tr.qd, params())
    live = list(LedFrames(iter(tr), RATE, "advance", params(), bounds, cap))
    np.testing.assert_allclose(live[100].goal, tr.q[100] + 0.5 * (TAU + H), atol=1e-14)
    with pytest.raises(ValueError, match="Expected `torque`"):
        LedFrames(iter(tr), RATE, "model", params(), bounds, cap)


def test_params_are_checked():
    with pytest.raises(ValueError, match="Expected `kp_nm_rad` finite and >= 0"):
        params(kp_nm_rad=[0.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="Expected `lag_s` to have 3 entries"):
        params(lag_s=[0.1, 0.1])


def test_stream_table_lead_is_read_and_checked(tmp_path):
    from trajgen.errors import KeyframeFileError
    from trajgen.keyframes import load_keyframe_file

    keys = "[[keyframes]]\nt = 0\npan = 0\n[[keyframes]]\nt = 1\npan = 10\n"
    path = tmp_path / "k.toml"
    path.write_text('[stream]\nlead = "advance"\n' + keys)
    assert load_keyframe_file(path).lead == "advance"
    path.write_text(keys)
    assert load_keyframe_file(path).lead is None
    path.write_text('[stream]\nlead = "ahead"\n' + keys)
    with pytest.raises(
        KeyframeFileError,
        match=r"\[stream\] lead: expected one of model, advance, none, got 'ahead'",
    ):
        load_keyframe_file(path)
