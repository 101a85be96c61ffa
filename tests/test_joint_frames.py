"""A joint motion streams its own joints: the same frames as the orientation's round trip.

The stream reads an untimed target's joint motion (a JointSplice) off its joints
(:meth:`PlanFrames.joints`, :meth:`FrameKinematics.joints`) instead of evaluating its
orientation and taking the inverse kinematics of each frame. These tests hold that fast
path to the path it replaces: the inverse kinematics of the splice's orientation and
rates frame by frame, and the numpy plan of the same path (``plan_joint_trajectory``),
on angles, speeds, accelerations and the led goals, with the same unwrapping, the same
guard and the same error.
"""

import math

import numpy as np
import pytest

from trajgen.errors import KinematicsError
from trajgen.frame_eval import FrameKinematics
from trajgen.gimbal import GimbalKinematics, forward
from trajgen.joint_splice import JointSplice
from trajgen.lead import LeadParams, LedFrames
from trajgen.online import OnlineSpline
from trajgen.stream import JointFrame, plan_joint_trajectory, stream_frames
from trajgen.tracker import Tracker
from trajgen.tracker_profile import JointProfile, fastest

LIMITS = np.array([[3.0] * 3, [20.0] * 3, [200.0] * 3])  # rad/s, rad/s^2, rad/s^3
RATE_HZ = 1000.0


def profile(x0, v0, a0, goal):
    x0, v0, a0, goal = (np.asarray(x, dtype=float) for x in (x0, v0, a0, goal))
    return JointProfile(x0, v0, a0, *fastest(x0, v0, a0, goal, LIMITS[:, : len(x0)]), goal)


def tracked(kin, targets, seed, streamed=None):
    """An online spline closed after untimed targets (angles) at seeded times, some in
    the middle of the motion before; ``streamed`` (a list) gets each snapshot and the
    time from which a stream plays it."""
    rng = np.random.default_rng(seed)
    spline = OnlineSpline(kin.forward(np.zeros(kin.n_joints)), 0.0, k=2)
    tracker = Tracker(spline, LIMITS[:, : kin.n_joints], kinematics=kin)
    at = 0.0
    for goal in targets:
        r = tracker.set_target(angles=goal, at=at)
        assert r.changed
        if streamed is not None:
            streamed.append((r.at, spline.snapshot()[1]))
        at = r.at + rng.uniform(0.1, 1.1) * (r.arrival - r.at)
    spline.close()
    return spline


def assert_same(direct, reference, atol=1e-12):
    for a, b in zip(direct, reference, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=atol)


@pytest.mark.parametrize(
    "axes, targets",
    [
        ("zyx", [[3.0, 0.3, -0.4], [-2.9, -0.2, 0.5], [0.4, 0.6, 3.1], [-0.5, 0.1, -3.0]]),
        ("zy", [[2.5, 0.4], [-2.8, -0.3], [0.2, 0.9]]),
    ],
)
def test_each_frame_of_a_joint_motion_is_its_orientation_s_inverse_kinematics(
    axes, targets, monkeypatch
):
    # The pan passes +-pi: the fast path must unwrap as the inverse kinematics does.
    kin = GimbalKinematics(axes=axes)
    read_off = []  # the frames the fast path gave
    fast = FrameKinematics.joints

    def counted(self, *joints):
        out = fast(self, *joints)
        read_off.append(out is not None)
        return out

    monkeypatch.setattr(FrameKinematics, "joints", counted)
    snapshots = []
    spline = tracked(kin, targets, 4, snapshots)
    snapshots.append((spline.t_end + 0.01, None))
    k1, k2 = FrameKinematics(kin), FrameKinematics(kin)
    direct = by_orientation = None
    wrapped, i = 0, 0
    for (at, plan), (until, _) in zip(snapshots[:-1], snapshots[1:], strict=True):
        direct = plan.frames(0.0, RATE_HZ, direct)
        by_orientation = plan.frames(0.0, RATE_HZ, by_orientation)
        while (t := i / RATE_HZ) < until:
            if t >= at:
                a = direct.joints(t, k1)
                b = k2(t, *by_orientation(t))
                assert_same(a, b)
                wrapped += abs(a[0][0]) > math.pi
            i += 1
    assert wrapped > 0  # the pan left (-pi, pi]: the unwrapping was exercised
    assert sum(read_off) > 0.9 * i  # nearly every frame a joint motion's, read off it


@pytest.mark.parametrize("start", [None, [2 * math.pi, 0.0, -2 * math.pi]])
def test_the_stream_of_targets_equals_the_numpy_plan_and_its_led_goals(start):
    kin = GimbalKinematics(limits_rad=[(-12.0, 12.0), (-1.5, 1.5), (-12.0, 12.0)])
    spline = tracked(kin, [[0.8, -0.3, 0.2], [-0.6, 0.4, 0.0], [1.2, 0.1, -0.5]], seed=7)
    _, plan = spline.snapshot()
    reference = plan_joint_trajectory(plan, RATE_HZ, kin, start=start)
    frames = list(stream_frames(spline, RATE_HZ, kin, start=start))
    assert len(frames) == len(reference.t)
    for name in ("q", "qd", "qdd"):
        np.testing.assert_allclose(
            np.array([getattr(f, name) for f in frames]),
            getattr(reference, name),
            rtol=0,
            atol=1e-12,
        )
    # the led goals of both: the model lead (a gravity-like torque) and the advance lead
    params = LeadParams(
        kp_nm_rad=[4.0, 3.0, 2.0],
        back_emf_nm_s_rad=[0.1, 0.08, 0.05],
        lag_s=[0.045, 0.04, 0.03],
        frictionloss_nm=[0.01, 0.01, 0.005],
        enabled=True,
    )
    bounds = np.array([[-12.0, 12.0], [-1.5, 1.5], [-12.0, 12.0]])
    cap = np.full(3, 0.2)

    def torque(q, qd, qdd):
        return 0.3 * np.sin(q) + 0.02 * qd + 0.001 * qdd

    ref_frames = [
        JointFrame(i, t, q, qd, qdd)
        for i, (t, q, qd, qdd) in enumerate(
            zip(reference.t, reference.q, reference.qd, reference.qdd, strict=True)
        )
    ]
    for lead in ("model", "advance"):
        goals = [f.goal for f in LedFrames(frames, RATE_HZ, lead, params, bounds, cap, torque)]
        ref = [f.goal for f in LedFrames(ref_frames, RATE_HZ, lead, params, bounds, cap, torque)]
        np.testing.assert_allclose(goals, ref, rtol=0, atol=1e-12)
        assert np.ptp(np.array(goals) - reference.q, axis=0).max() > 1e-3  # a lead, not q


def test_a_joint_motion_past_a_limit_fails_as_the_inverse_kinematics_does():
    kin = GimbalKinematics(limits_rad=[(-1.0, 1.0), (-1.2, 1.2), (-1.0, 1.0)])
    spline = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    p = profile([0.0, 0.0, 0.0], [0.0] * 3, [0.0] * 3, [1.3, 0.2, 0.0])  # pan past 1 rad
    spline.apply(spline.prepare_segment(JointSplice(0.0, p, (2, 1, 0), forward([0, 0, 0])), at=0))
    spline.close()
    with pytest.raises(KinematicsError) as planned:
        plan_joint_trajectory(spline.snapshot()[1], RATE_HZ, kin)
    streamed = []
    with pytest.raises(KinematicsError) as live:
        for f in stream_frames(spline, RATE_HZ, kin):
            streamed.append(f)
    assert str(live.value) == str(planned.value)
    assert 0 < len(streamed) < p.duration * RATE_HZ
    assert streamed[-1].q[0] <= 1.0 < p.state(np.array([len(streamed) / RATE_HZ]))[0, 0, 0]


def test_a_joint_motion_on_other_axes_than_the_stream_s_goes_by_its_orientation():
    # a pan-tilt-roll joint motion streamed on an x-y-z gimbal: its joints are not the
    # stream's, so the frames are the inverse kinematics of its orientation
    kin = GimbalKinematics(axes="xyz")
    spline = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    p = profile([0.0, 0.0, 0.0], [0.0] * 3, [0.0] * 3, [0.5, -0.3, 0.2])
    spline.apply(spline.prepare_segment(JointSplice(0.0, p, (2, 1, 0), forward([0, 0, 0])), at=0))
    spline.close()
    reference = plan_joint_trajectory(spline.snapshot()[1], RATE_HZ, kin)
    frames = list(stream_frames(spline, RATE_HZ, kin))
    np.testing.assert_allclose([f.q for f in frames], reference.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose([f.qd for f in frames], reference.qd, rtol=0, atol=1e-11)
    assert np.abs(reference.q[-1] - [0.5, -0.3, 0.2]).max() > 0.01  # other joints indeed


def test_joint_frames_of_a_proper_euler_gimbal_match_the_round_trip():
    kin = GimbalKinematics(axes="xyx")
    # from pan 4 rad, back past pi; no start branch: the first frame's pan is wrapped
    x0 = np.array([4.0, 0.9, -0.3])
    p = profile(x0, [0.4, -0.5, 1.0], [2.0, 1.0, -3.0], [2.6, 1.4, -2.9])
    seg = JointSplice(1.0, p, kin.sequence.indices, kin.forward(x0))
    k1, k2 = FrameKinematics(kin), FrameKinematics(kin)
    for t in 1.0 + np.linspace(0.0, p.duration + 0.01, 400):
        a = k1.joints(*seg.joints_at(float(t)))
        assert a is not None
        assert_same(a, k2(float(t), *seg.frame(float(t))), atol=1e-11)
