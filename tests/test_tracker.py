"""Tracker: untimed targets reached at the earliest arrival the joint limits allow."""

import math

import numpy as np
import pytest

from trajgen.errors import KinematicsError
from trajgen.gimbal import angles_of, forward
from trajgen.online import OnlineSpline
from trajgen.servo_table import RAD_PER_TICK
from trajgen.tracker import CLAMP_INSET_RAD, Tracker, look_at_angles

D = math.radians
LIMITS = np.array([[3.0] * 3, [20.0] * 3, [200.0] * 3])  # rad/s, rad/s^2, rad/s^3


def tracker(start=(0.0, 0.0, 0.0), **kw):
    return Tracker(OnlineSpline(forward(start), 0.0, k=2), LIMITS, **kw)


def one_sided(plan_before, plan_after, at):
    """Value and rates (orders 0..2) at ``at`` of the old path and of the new piece."""
    old = plan_before.evaluate(np.array([at]), max_order=2)
    q, (w, a) = plan_after.pieces[-1].space_rates(np.array([at]), 2)
    return (old.q[0], old.omega[0], old.alpha[0]), (q[0], w[0], a[0])


@pytest.mark.parametrize(
    ("point", "pan", "tilt"),
    [
        ([1, 0, 0], 0, 0),
        ([0, 1, 0], 90, 0),
        ([1, 0, -1], 0, 45),  # below: positive tilt looks down (Ry turns x towards -z)
        ([0, -2, 2], -90, -45),
        ([-1, 0, 0], 180, 0),
        ([1, 1, -math.sqrt(2)], 45, 45),
    ],
)
def test_look_at_hand_worked_angles(point, pan, tilt):
    a = look_at_angles(point)
    np.testing.assert_allclose(np.degrees(a), [pan, tilt, 0], atol=1e-12)
    # and the camera's x axis of forward() points at it
    q = forward(a)
    w, x, y, z = q
    axis = np.array([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)])
    np.testing.assert_allclose(axis, np.asarray(point) / np.linalg.norm(point), atol=1e-12)


def test_look_at_refuses_the_origin():
    with pytest.raises(ValueError, match="other than the gimbal's origin"):
        look_at_angles([0, 0, 0])


def test_look_at_target_is_reached():
    tr = tracker()
    r = tr.set_target(look_at=[1.0, 1.0, 0.0], at=0.0)
    q_end = tr.spline(np.array([r.arrival + 0.1]))[0]
    np.testing.assert_allclose(abs(q_end @ forward([D(45), 0, 0])), 1.0, atol=1e-12)


def test_earliest_arrival_keeps_the_limits_and_is_the_double_s_time():
    tr = tracker()
    r = tr.set_target(angles=[D(30), D(-10), 0], at=0.0)
    assert r.changed and (r.peaks <= LIMITS).all()
    # Pan 30 deg from rest, worked by hand: 3 rad/s is not reached; the peak speed vp
    # with the acceleration at 20 rad/s^2 for a while covers the distance when
    # vp (vp / A + A / J) = d, and the motion takes 2 (vp / A + A / J).
    v, a, j = LIMITS[:, 0]
    d = D(30)
    vp = (-a / j + math.sqrt((a / j) ** 2 + 4 * d / a)) / (2 / a)
    assert vp > a * a / j  # the acceleration does reach its limit
    assert r.arrival == pytest.approx(2 * (vp / a + a / j), abs=1e-9)
    np.testing.assert_allclose(r.peaks[:, 0], [vp, a, j], rtol=1e-8)
    q = tr.spline(np.array([r.arrival]))[0]
    np.testing.assert_allclose(abs(q @ forward([D(30), D(-10), 0])), 1.0, atol=1e-14)


def test_max_speed_caps_the_motion():
    free = tracker().set_target(angles=[D(60), 0, 0], at=0.0)
    slow = tracker().set_target(angles=[D(60), 0, 0], at=0.0, max_speed=1.0)
    assert slow.peaks[0, 0] <= 1.0 < free.peaks[0, 0]
    assert slow.arrival > free.arrival


def test_replacements_mid_motion_are_continuous():
    rng = np.random.default_rng(3)
    tr = tracker()
    at = 0.0
    for _ in range(8):
        target = [D(rng.uniform(-40, 40)), D(rng.uniform(-30, 30)), 0.0]
        before = tr.spline.snapshot()[1]
        r = tr.set_target(angles=target, at=at)
        after = tr.spline.snapshot()[1]
        (q0, w0, a0), (q1, w1, a1) = one_sided(before, after, at)
        np.testing.assert_allclose(q1, q0, atol=1e-12)
        np.testing.assert_allclose(w1, w0, atol=1e-9 * max(1.0, np.abs(w0).max()))
        np.testing.assert_allclose(a1, a0, atol=1e-9 * max(1.0, np.abs(a0).max()))
        assert r.changed and (r.peaks <= LIMITS).all()
        at += rng.uniform(0.05, 0.2)  # before arrival: a replacement in mid-motion


def test_dead_band_changes_nothing():
    tr = tracker()
    r = tr.set_target(angles=[D(20), 0, 0], at=0.0)
    version = tr.spline.version
    same = tr.set_target(angles=[D(20) + 0.9 * RAD_PER_TICK, -0.5 * RAD_PER_TICK, 0], at=0.1)
    assert not same.changed and tr.spline.version == version
    assert same.arrival == r.arrival
    moved = tr.set_target(angles=[D(20) + 1.5 * RAD_PER_TICK, 0, 0], at=0.1)
    assert moved.changed and tr.spline.version == version + 1


def test_dead_band_is_configurable():
    tr = tracker(dead_band_rad=D(1.0))
    tr.set_target(angles=[D(20), 0, 0], at=0.0)
    assert not tr.set_target(angles=[D(20.9), 0, 0], at=0.1).changed


def test_target_past_a_limit_is_clamped_and_reported():
    tr = tracker()
    r = tr.set_target(angles=[D(10), D(85), 0], at=0.0)  # lock margin 10 deg: tilt <= 80
    assert "tilt 85.0 -> 79.5 deg" in r.clamped
    np.testing.assert_allclose(r.goal[1], D(80) - CLAMP_INSET_RAD)
    q, *_ = tr.joint_motion(tr.spline, 0.0, r.arrival + 0.1, np.zeros(3))
    assert q[:, 1].max() <= D(80)


def test_pan_limit_clamps():
    from trajgen.gimbal import GimbalKinematics

    lim = ((-D(90), D(90)), (-D(90), D(90)), (-D(180), D(180)))
    tr = tracker(kinematics=GimbalKinematics(lim))
    r = tr.set_target(look_at=[-1.0, 0.1, 0.0], at=0.0)  # behind: pan ~174 deg
    assert r.clamped.startswith("clamped to the joint limits: pan 174.3 -> 90.0 deg")
    assert r.goal[0] == pytest.approx(D(90))


@pytest.mark.parametrize("k", [2, 3])
def test_path_through_the_lock_goes_around_it(k):
    # (0, 70, 0) to (180, 70, 180): the direct rotation is about y, over the nadir.
    start, goal = [0, D(70), 0], [D(180), D(70), D(180)]
    sp = OnlineSpline(forward(start), 0.0, k=k)
    direct = sp.prepare("retarget", forward([goal]), [2.0], at=0.0)
    tr = Tracker(sp, LIMITS)
    w, x, y, z = direct.path.evaluate(np.linspace(0, 2, 201), max_order=0).q.T
    tilt = angles_of(w, x, y, z, np.arctan2, np.hypot)[1]
    assert np.abs(tilt).max() > D(89)  # the direct path passes the lock
    r = tr.set_target(angles=goal, at=0.0)
    # k = 2: each joint's own motion, which keeps the tilt between its ends; k = 3:
    # orientation splices through via points
    assert r.vias == 0 if k == 2 else r.vias >= 1
    q, *_ = tr.joint_motion(tr.spline, 0.0, r.arrival + 0.1, np.array(start))
    assert np.abs(q[:, 1]).max() < D(80)
    np.testing.assert_allclose(np.abs(q[-1]), [D(180), D(70), D(180)], atol=1e-9)


def test_envelope_callback_slows_the_motion():
    def envelope(q, qd, qdd):
        return np.abs(qdd[:, 0]) <= 5.0  # a tighter torque-like bound on pan

    free = tracker().set_target(angles=[D(30), 0, 0], at=0.0)
    held = tracker(envelope=envelope).set_target(angles=[D(30), 0, 0], at=0.0)
    assert held.peaks[1, 0] <= 5.0 and held.arrival > free.arrival


class SteppedEnvelope:
    """An envelope with ``steps``: the tracker should run those, not call it."""

    def __init__(self):
        self.calls = self.steps_run = 0

    def __call__(self, q, qd, qdd):
        self.calls += 1
        return np.abs(qdd[:, 0]) <= 5.0

    def steps(self, q, qd, qdd):
        for _ in range(3):
            self.steps_run += 1
            yield
        return np.abs(qdd[:, 0]) <= 5.0


def count_steps(tr, **target):
    steps, n = tr.set_target_steps(**target), 0
    while True:
        try:
            next(steps)
            n += 1
        except StopIteration as end:
            return end.value, n


def test_an_envelope_with_steps_is_run_in_steps():
    plain = tracker(envelope=lambda q, qd, qdd: np.abs(qdd[:, 0]) <= 5.0)
    env = SteppedEnvelope()
    a, n_plain = count_steps(plain, angles=[D(30), 0, 0], at=0.0)
    b, n_stepped = count_steps(tracker(envelope=env), angles=[D(30), 0, 0], at=0.0)
    assert env.calls == 0 and env.steps_run > 3  # refused at full limits, then scaled
    assert n_stepped == n_plain + env.steps_run
    assert b.arrival == a.arrival and np.array_equal(b.peaks, a.peaks)


def test_unreachable_is_refused():
    tr = Tracker(OnlineSpline(forward([0, 0, 0]), 0.0), [[0.02] * 3, [1.0] * 3, [10.0] * 3])
    with pytest.raises(KinematicsError, match="within 60 s"):
        tr.set_target(angles=[D(90), 0, 0], at=0.0)


def test_exactly_one_target():
    with pytest.raises(ValueError, match="exactly one of"):
        tracker().set_target([1, 0, 0, 0], look_at=[1, 0, 0], at=0.0)
    with pytest.raises(ValueError, match="Expected `limits`"):
        Tracker(OnlineSpline([1, 0, 0, 0]), [[1, 2], [3, 4]])


def test_follow_lines_without_a_time_go_to_the_tracker():
    from trajgen.follower import Follower

    sp = OnlineSpline(forward([0, 0, 0]), 0.0)
    f = Follower(sp, 200.0, limits=LIMITS)
    f.feed('{"pan": 20, "tilt": -5}', 1)
    f.feed('{"look_at": [1, 1, 0], "max_speed": 60}', 2)
    assert [k["mode"] for k in f.keyframes] == ["track", "track"]
    assert f.tracker.goal == pytest.approx([D(45), 0, 0])
    assert f.keyframes[1]["t"] > f.keyframes[1]["at"] + 0.2
    f.feed('{"look_at": [1, 1, 0]}', 3)  # the same target: within the dead band
    assert len(f.keyframes) == 2
    f.feed('{"in": 1, "pan": -10}', 4)  # a timed line, then a target near its goal
    f.feed('{"pan": -10}', 5)
    assert len(f.keyframes) == 3
    with pytest.raises(ValueError, match=r"stdin: line 6: field 'max_speed': expected"):
        f.feed('{"pan": 3, "max_speed": 0}', 6)


def frame_peaks(tr, path, t0, t1, near):
    """Peak |speed|, |acceleration|, |jerk| (3, 3) of ``path`` at the frames in (t0, t1]."""
    _, qd, qdd, jerk = tr.joint_motion(path, t0, t1, near)
    return np.array([np.abs(x).max(axis=0) for x in (qd, qdd, jerk)])


@pytest.mark.parametrize("at", [0.1, 5.0])  # in motion, and at rest after the first target
def test_the_splice_family_is_the_retarget_at_every_lead(at):
    tr = tracker()
    tr.set_target(angles=[D(30), D(-10), 0], at=0.0)
    goal = forward([[D(-20), D(15), 0]])
    probe = tr.spline.prepare("retarget", goal, [at + 0.4], at=at)
    coefs, q_a = tr._family(probe.path.pieces[-1].splice, at >= tr.spline.t_end)
    for h in (0.25, 0.7, 2.0):
        other = tr.spline.prepare("retarget", goal, [at + h], at=at).path.pieces[-1].splice
        np.testing.assert_allclose(coefs(np.array([h]))[0], other.coef, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(other.q_a, q_a)


def test_a_30_hz_stream_keeps_the_limits_at_every_frame_and_each_change_is_c2():
    rng = np.random.default_rng(7)
    tr = tracker()
    at, changed = 0.0, 0
    for _ in range(45):
        target = [rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4), 0.0]
        before = tr.spline.snapshot()[1]
        r = tr.set_target(angles=target, at=at)
        if r.changed:
            changed += 1
            after = tr.spline.snapshot()[1]
            (q0, w0, a0), (q1, w1, a1) = one_sided(before, after, r.at)
            np.testing.assert_allclose(q1, q0, atol=1e-12)
            np.testing.assert_allclose(w1, w0, atol=1e-9 * max(1.0, np.abs(w0).max()))
            np.testing.assert_allclose(a1, a0, atol=1e-9 * max(1.0, np.abs(a0).max()))
            near = tr._unwrapped(after(np.array([r.at]))[0], r.goal)
            peaks = frame_peaks(tr, after, r.at, r.arrival, near)
            assert (peaks <= LIMITS).all(), peaks
            # r.peaks holds between frames too (the frames' jerk: differences over 2 us)
            assert (peaks <= r.peaks * (1 + 1e-6) + 1e-6).all()
        at += 1 / 30
    assert changed == 45


def test_a_reversal_just_after_a_start_is_taken_at_once_and_is_c2():
    # 10 ms into a 1 rad move its jerk is at the limit: a splice that kept the jerk
    # (C3) could not turn back within the limits; the joints' own motion is C2 only.
    tr = tracker()
    tr.set_target(angles=[1.0, 0, 0], at=0.0)
    before = tr.spline.snapshot()[1]
    r = tr.set_target(angles=[-1.0, 0, 0], at=0.01)
    assert r.changed and r.at == 0.01 and (r.peaks <= LIMITS).all()
    (q0, w0, a0), (q1, w1, a1) = one_sided(before, tr.spline.snapshot()[1], r.at)
    np.testing.assert_allclose(q1, q0, atol=1e-12)
    np.testing.assert_allclose(w1, w0, atol=1e-9 * max(1.0, np.abs(w0).max()))
    np.testing.assert_allclose(a1, a0, atol=1e-9 * max(1.0, np.abs(a0).max()))
    np.testing.assert_allclose(a0[2], 200.0 * 0.01, rtol=1e-6)  # braking starts from here
    near = tr._unwrapped(tr.spline(np.array([r.at]))[0], r.goal)
    assert (frame_peaks(tr, tr.spline, r.at, r.arrival, near) <= LIMITS * (1 + 1e-9)).all()


def test_a_target_the_motion_in_progress_cannot_keep_to_is_deferred():
    # A timed retarget moves pan at up to about 2 rad/s; a target capped at 0.5 rad/s
    # cannot start while pan moves faster: the old path is followed until it can.
    tr = tracker()
    tr.spline.retarget(forward([[1.0, 0, 0]]), [1.0], at=0.0)
    before = tr.spline.snapshot()[1]
    r = tr.set_target(angles=[-0.5, 0, 0], at=0.3, max_speed=0.5)
    assert r.changed and r.at > 0.3 and r.peaks[0, 0] <= 0.5
    speed = np.abs(tr.spline.evaluate(np.array([0.3, r.at]), max_order=1).omega[:, 2])
    assert speed[0] > 0.5 >= speed[1]
    (q0, w0, a0), (q1, w1, a1) = one_sided(before, tr.spline.snapshot()[1], r.at)
    np.testing.assert_allclose(w1, w0, atol=1e-9 * max(1.0, np.abs(w0).max()))
    np.testing.assert_allclose(a1, a0, atol=1e-9 * max(1.0, np.abs(a0).max()))
    # a target asked for before the deferred change starts from it
    assert tr.set_target(angles=[0.3, 0, 0], at=r.at - 0.1).at >= r.at


def test_a_noisy_30_hz_target_stream_through_the_follower_keeps_every_frame_in_limits():
    """A short version of bench/tracker_stream.py: a face that moves then stands still,
    reported at 30 Hz with noise, fed to a Follower while its 1 kHz stream runs (each
    change built in steps between frames): no frame beyond the limits (a change that
    were not C2 would give an unbounded jerk), and it settles on the last report."""
    import json
    import queue
    import threading

    from trajgen.follower import Follower

    rng = np.random.default_rng(11)
    t_lines = np.arange(0.1, 1.2, 1 / 30)
    walk = np.clip((t_lines - 0.1) / 0.6, 0.0, 1.0)  # walks 0.6 s, then stands
    face = np.array([2.0, 0.0, 0.0]) + np.outer(walk, [0.0, 1.2, -0.4])
    reports = face + rng.normal(0.0, 0.01, face.shape)
    spline = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    f = Follower(spline, 1000.0, limits=LIMITS)
    lines, i, errors = queue.Queue(), 0, []

    def reader():  # one thread feeds the lines in order, as `trajgen follow` reads them
        while (item := lines.get()) is not None:
            try:
                f.feed(*item)
            except ValueError as e:  # pragma: no cover - reported below
                errors.append(str(e))

    feeder = threading.Thread(target=reader)
    feeder.start()
    for frame in f.frames():
        if i < len(t_lines) and frame.t >= t_lines[i]:
            lines.put((json.dumps({"look_at": reports[i].tolist()}), i + 1))
            i += 1
            if i == len(t_lines):
                lines.put(None)
        if not spline.closed and i == len(t_lines) and not feeder.is_alive():
            spline.close()  # every line's change made
    assert errors == [] and len(f.keyframes) >= len(t_lines) - 5
    traj = f.trajectory()
    assert (np.abs(traj.qd) <= LIMITS[0]).all() and (np.abs(traj.qdd) <= LIMITS[1]).all()
    assert (np.abs(np.diff(traj.qdd, axis=0)) * 1000.0 <= LIMITS[2] * (1 + 1e-6)).all()
    assert np.abs(traj.qd).max() > 0.3  # it moved
    np.testing.assert_allclose(traj.q[-1], look_at_angles(reports[-1]), atol=RAD_PER_TICK)
    np.testing.assert_allclose(traj.qd[-1], 0.0, atol=1e-9)


def test_a_two_axis_head_points_at_a_point_within_its_limits():
    from trajgen.gimbal import GimbalKinematics
    from trajgen.quat import rotate

    kin = GimbalKinematics(axes="zy")  # pan-tilt head: look axis x
    limits = LIMITS[:, :2]
    tr = Tracker(OnlineSpline(kin.forward([0.0, 0.0]), 0.0, k=2), limits, kinematics=kin)
    point = np.array([1.0, 1.0, -math.sqrt(2.0)])
    r = tr.set_target(look_at=point, at=0.0)
    # hand-worked: pan atan2(1, 1) = 45 deg, tilt atan2(sqrt 2, sqrt 2) = 45 deg (down)
    np.testing.assert_allclose(np.degrees(r.goal), [45.0, 45.0], atol=1e-12)
    assert r.peaks.shape == (3, 2) and (r.peaks <= limits).all()
    q_end = tr.spline(np.array([r.arrival + 0.1]))[0]
    np.testing.assert_allclose(rotate(q_end, [1.0, 0.0, 0.0]), point / 2.0, atol=1e-12)
    # a replacement in mid-motion: C2 across it, the limits on its frames
    before = tr.spline.snapshot()[1]
    r2 = tr.set_target(look_at=[1.0, -0.5, 0.2], at=0.15)
    after = tr.spline.snapshot()[1]
    (q0, w0, a0), (q1, w1, a1) = one_sided(before, after, r2.at)
    np.testing.assert_allclose(w1, w0, atol=1e-9 * max(1.0, np.abs(w0).max()))
    np.testing.assert_allclose(a1, a0, atol=1e-9 * max(1.0, np.abs(a0).max()))
    near = tr._unwrapped(after(np.array([r2.at]))[0], r2.goal)
    assert (frame_peaks(tr, after, r2.at, r2.arrival, near) <= limits).all()
    q_end = tr.spline(np.array([r2.arrival + 0.1]))[0]
    d = np.array([1.0, -0.5, 0.2])
    np.testing.assert_allclose(rotate(q_end, [1.0, 0.0, 0.0]), d / np.linalg.norm(d), atol=1e-12)


def test_look_at_on_a_three_axis_gimbal_other_than_pan_tilt_roll_is_refused():
    from trajgen.gimbal import GimbalKinematics

    tr = Tracker(OnlineSpline([1.0, 0, 0, 0]), LIMITS, kinematics=GimbalKinematics(axes="zxy"))
    with pytest.raises(ValueError, match="`look_at` needs a pan-tilt-roll"):
        tr.set_target(look_at=[1.0, 0, 0], at=0.0)
