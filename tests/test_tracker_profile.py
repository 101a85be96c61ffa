"""The tracker's joint motions: each joint's fastest jerk-limited motion to rest, and the
orientation path that plays it (exact rates, C2 across every change)."""

import math

import numpy as np
import pytest

from trajgen import quat as Q
from trajgen.gimbal import GimbalKinematics, forward
from trajgen.joint_splice import JointSplice
from trajgen.online import OnlineSpline
from trajgen.online_frames import PlanFrames
from trajgen.tracker import Tracker
from trajgen.tracker_profile import JointProfile, fastest

LIMITS = np.array([[3.0] * 3, [20.0] * 3, [200.0] * 3])  # rad/s, rad/s^2, rad/s^3


def profile(x0, v0, a0, goal, limits=LIMITS):
    x0, v0, a0, goal = (np.asarray(x, dtype=float) for x in (x0, v0, a0, goal))
    limits = limits[:, : len(x0)]
    return JointProfile(x0, v0, a0, *fastest(x0, v0, a0, goal, limits), goal)


def test_rest_to_rest_at_the_speed_limit_is_the_hand_worked_double_s():
    # 2 rad at 3 rad/s, 20 rad/s^2, 200 rad/s^3: the acceleration ramps up in 0.1 s,
    # holds 0.05 s (3 = 20 * 0.05 + 20^2 / 200), ramps down: 0.25 s to full speed over
    # 3 * 0.25 / 2 = 0.375 rad, the same to stop, and (2 - 0.75) / 3 s at 3 rad/s.
    p = profile([0.0], [0.0], [0.0], [2.0])
    assert p.duration == pytest.approx(0.5 + 1.25 / 3.0, abs=1e-12)
    np.testing.assert_allclose(p.peaks()[:, 0], [3.0, 20.0, 200.0], rtol=1e-12)
    x, v, a, j = p.state(np.array([0.1, 0.25, 0.25 + 1.25 / 3.0]))[:, :, 0]
    np.testing.assert_allclose(a, [20.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(v, [1.0, 3.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(x[2], 2.0 - 0.375, atol=1e-9)


def test_random_starts_end_at_rest_on_the_goal_within_the_limits_and_are_c2():
    rng = np.random.default_rng(5)
    for _ in range(200):
        # starts that can keep the limits: the speed where the acceleration first
        # comes back to zero is within V
        v0, a0 = rng.uniform(-2.5, 2.5, 3), rng.uniform(-15, 15, 3)
        v0 = np.clip(v0, -3 + a0**2 / 400, 3 - a0**2 / 400)
        x0, goal = rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3)
        p = profile(x0, v0, a0, goal)
        assert (p.peaks() <= LIMITS * (1 + 1e-9)).all(), p.peaks()
        x, v, a, _ = p.state(np.array([0.0, p.duration, p.duration + 1.0]))
        np.testing.assert_allclose(x[0], x0, atol=1e-15)
        np.testing.assert_allclose(v[0], v0, atol=1e-15)
        np.testing.assert_allclose(a[0], a0, atol=1e-15)
        np.testing.assert_allclose(x[1:], [goal, goal], atol=1e-12)
        np.testing.assert_allclose(v[1:], 0.0, atol=1e-9)
        np.testing.assert_allclose(a[1:], 0.0, atol=1e-9)
        # angle, speed and acceleration continuous at every knot (the jerk jumps): across
        # each, they change by no more than their rate bound times the step
        knots = p.knots[p.knots < p.duration]
        d = 1e-7
        jump = np.abs(p.state(knots + d)[:3] - p.state(knots - d)[:3])  # (3, K, 3)
        bound = 2 * d * LIMITS[:, None, :] * (1 + 1e-6) + 1e-12
        assert (jump <= bound).all()


def test_a_start_moving_away_turns_back_without_a_pause():
    # moving away from the goal at 2 rad/s: brake, then go; no phase of zero
    # acceleration in the middle of the turn (the time-optimal shape)
    p = profile([0.0], [2.0], [0.0], [-0.5])
    v = p.state(np.linspace(0, p.duration, 2001))[1, :, 0]
    assert v.max() == pytest.approx(2.0 + 0.0, abs=1e-9) and v.min() < -1.0
    assert (np.diff(p.knots[0]) >= 0).all()


@pytest.mark.parametrize("axes", ["zyx", "zy", "xyx"])
def test_the_joint_splice_rates_are_exact(axes):
    kin = GimbalKinematics(axes=axes)
    n = kin.n_joints
    rng = np.random.default_rng(2)
    x0 = np.array([0.2, 0.4, -0.3][:n]) + (np.array([0, 0.9, 0][:n]) if axes == "xyx" else 0)
    p = profile(x0, rng.uniform(-1, 1, n), rng.uniform(-5, 5, n), x0 + rng.uniform(-1, 1, n))
    seg = JointSplice(1.0, p, kin.sequence.indices, kin.forward(x0))
    t = 1.0 + np.array([0.013, 0.1, 0.2, 0.3]) * p.duration / 0.31
    s = seg.evaluate(t, max_order=3)
    x = p.state(t - 1.0)[0]
    np.testing.assert_allclose(np.abs(np.sum(s.q * kin.forward(x), axis=1)), 1.0, atol=1e-14)
    np.testing.assert_allclose(
        s.omega,
        np.einsum("mij,mj->mi", kin.sequence.joint_axes(x), p.state(t - 1.0)[1]),
        atol=1e-12,
    )
    # each order against the difference of the one below, over +-1 us
    h = 1e-6
    up, down = seg.evaluate(t + h, max_order=2), seg.evaluate(t - h, max_order=2)
    w_fd = 2 * Q.mul((seg(t + h) - seg(t - h)) / (2 * h), Q.conj(s.q))[:, 1:]
    np.testing.assert_allclose(w_fd, s.omega, atol=1e-7)
    np.testing.assert_allclose((up.omega - down.omega) / (2 * h), s.alpha, atol=1e-6)
    np.testing.assert_allclose((up.alpha - down.alpha) / (2 * h), s.jerk, atol=1e-4)
    # the per-frame floats, the single-time rates and the jet agree with evaluate
    for i, ti in enumerate(t):
        q, w, a = seg.frame(float(ti))
        np.testing.assert_allclose(q, s.q[i], atol=1e-15)
        np.testing.assert_allclose(w, s.omega[i], atol=1e-12)
        np.testing.assert_allclose(a, s.alpha[i], atol=1e-11)
        q1, (w1, a1, j1) = seg.rates(float(ti))
        np.testing.assert_allclose(j1, s.jerk[i], atol=1e-10)
    jet = seg._jet(t, None, 3)
    np.testing.assert_allclose(jet.value.T, s.q, atol=1e-15)
    q_t, d = seg.taylor(float(t[1]), 3)
    w_taylor = 2 * d[1, 1:]  # d(tau) = q(t + tau) q(t)*: d'(0) = omega / 2
    np.testing.assert_allclose(w_taylor, s.omega[1], atol=1e-12)


def plan_sides(before, after, at):
    """Value and rates of orders 1..3 at ``at`` of the old path and of the new piece."""
    old = before.evaluate(np.array([at]), max_order=3)
    q, rates = after.pieces[-1].space_rates(np.array([at]), 3)
    return [old.q[0], *(r[0] for r in (old.omega, old.alpha, old.jerk))], [
        q[0],
        *(r[0] for r in rates),
    ]


def test_every_kind_of_change_around_a_joint_motion_is_continuous():
    """Tracker onto a timed line, tracker onto tracker (C2: the jerk may jump), a timed
    line onto a joint motion (the splice keeps its jerk: C3 there), exact rates."""
    sp = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    tr = Tracker(sp, LIMITS)
    sp.retarget(forward([[0.6, 0.2, 0.0]]), [0.8], at=0.0)
    for at, kind in ((0.2, "target"), (0.35, "target"), (0.5, "timed"), (0.65, "target")):
        before = sp.snapshot()[1]
        if kind == "target":
            r = tr.set_target(angles=[-0.4 if at < 0.3 else 0.5, 0.1, 0.0], at=at)
            assert r.at == at and r.changed
            assert isinstance(sp.snapshot()[1].pieces[-1].splice, JointSplice)
        else:
            sp.retarget(forward([[0.0, -0.2, 0.0]]), [at + 0.5], at=at)
        old, new = plan_sides(before, sp.snapshot()[1], at)
        scale = [1.0, *(max(1.0, np.abs(x).max()) for x in old[1:])]
        top = 4 if kind == "timed" else 3  # orders kept: C3 for the splice, C2 for a target
        for n in range(top):
            np.testing.assert_allclose(new[n], old[n], atol=1e-9 * scale[n], err_msg=f"{kind} {n}")


def test_the_stream_plays_a_joint_motion_frame_by_frame_as_evaluate_does():
    sp = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    tr = Tracker(sp, LIMITS)
    tr.set_target(angles=[0.5, -0.2, 0.0], at=0.0)
    tr.set_target(angles=[-0.3, 0.1, 0.0], at=0.137)
    _, plan = sp.snapshot()
    frames = PlanFrames(plan, 0.0, 1000.0)
    t = np.arange(0, 900) / 1000.0
    s = plan.evaluate(t, max_order=2)
    for i in range(0, 900, 7):
        q, w, a = frames(float(t[i]))
        np.testing.assert_allclose(q, s.q[i], atol=1e-14)
        np.testing.assert_allclose(w, s.omega[i], atol=1e-11)
        np.testing.assert_allclose(a, s.alpha[i], atol=1e-10)


def test_a_segment_must_start_at_the_change():
    sp = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    p = profile([0.0, 0.0, 0.0], [0.0] * 3, [0.0] * 3, [0.3, 0.0, 0.0])
    seg = JointSplice(0.5, p, (2, 1, 0), forward([0, 0, 0]))
    with pytest.raises(ValueError, match=r"starts at 0.5 s, not at `at` = 0.4 s"):
        sp.prepare_segment(seg, at=0.4)
    sp.apply(sp.prepare_segment(seg, at=0.5))
    assert sp.t_end == pytest.approx(0.5 + p.duration)
    np.testing.assert_allclose(abs(sp(sp.t_end + 1.0) @ forward([0.3, 0, 0])), 1.0, atol=1e-14)
    assert math.isclose(sp.last_change_at, 0.5)
