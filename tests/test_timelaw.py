"""trajgen.timelaw: the B-spline time law and the retimed path (C3, exact derivatives)."""

import numpy as np
import pytest

from trajgen import quat as Q
from trajgen.keyframes import KeyframeFileError, load_keyframe_file
from trajgen.smooth import SmoothSpline
from trajgen.stream import plan_joint_trajectory, stream_frames
from trajgen.timelaw import RetimedPath, TimeLaw, bspline_values


def _knots(n_coef, rng):
    inner = np.sort(rng.uniform(0.05, 0.95, n_coef - 6))
    return np.concatenate([np.zeros(6), inner, np.ones(6)])


def _law(rng, n_coef=12, t0=0.3, duration=2.0, s0=1.0, span=3.0):
    knots = _knots(n_coef, rng)
    c = np.concatenate([[0.0], np.sort(rng.uniform(0.0, 1.0, n_coef - 2)), [1.0]])
    return TimeLaw(knots, c, t0, duration, s0, span)


def _path(rng, n=5, t0=1.0, span=3.0):
    pan_tilt_roll = np.radians(rng.uniform([-60, -30, -10], [60, 30, 10], size=(n, 3)))
    quats = Q.from_pan_tilt_roll(*pan_tilt_roll.T)
    times = t0 + np.concatenate([[0.0], np.cumsum(rng.uniform(0.5, 1.5, n - 1))])
    times = t0 + (times - t0) * span / (times[-1] - t0)
    return SmoothSpline(quats, times)


def test_bspline_values_match_scipy(rng):
    from scipy.interpolate import BSpline

    knots = _knots(15, rng)
    c = rng.normal(size=15)
    x = np.concatenate([rng.uniform(0, 1, 200), np.unique(knots)])
    np.testing.assert_allclose(bspline_values(knots, c, 5, x), BSpline(knots, c, 5)(x), atol=1e-13)
    law = TimeLaw(knots, np.linspace(0, 1, 15), 0.0, 1.0, 0.0, 1.0)
    for m in range(4):
        expected = BSpline(knots, np.linspace(0, 1, 15), 5).derivative(m)(x) if m else None
        if m:
            np.testing.assert_allclose(
                law.sigma(x, m), expected, atol=1e-9 * np.abs(expected).max()
            )


def test_law_derivatives_and_inverse(rng):
    law = _law(rng)
    t = np.linspace(law.t_start, law.t_end, 2001)
    s, s1, s2, s3 = law(t)
    assert s[0] == pytest.approx(law.s_start) and s[-1] == pytest.approx(law.s_start + law.s_span)
    assert (s1 > 0).all()
    h = t[1] - t[0]
    for lower, upper in ((s, s1), (s1, s2), (s2, s3)):
        np.testing.assert_allclose(
            np.gradient(lower, h)[2:-2], upper[2:-2], rtol=0, atol=2e-3 * np.abs(upper).max()
        )
    np.testing.assert_allclose(law.inverse(s), t, atol=1e-12)


def test_retimed_path_derivatives_are_exact(rng):
    """Angular velocity, acceleration and jerk of q(s(t)) against finite differences."""
    path = _path(rng)
    law = _law(rng, s0=path.t_start, span=path.t_end - path.t_start)
    retimed = RetimedPath(path, law)
    t = np.linspace(law.t_start + 0.05, law.t_end - 0.05, 401)
    h = 1e-4
    at = retimed.evaluate(t, max_order=3)
    plus, minus = retimed.evaluate(t + h, max_order=3), retimed.evaluate(t - h, max_order=3)
    # omega from the quaternion: w = 2 q' q* (space frame).
    dq = (plus.q - minus.q) / (2 * h)
    omega = 2.0 * Q.mul(dq, Q.conj(at.q))[:, 1:]
    np.testing.assert_allclose(omega, at.omega, atol=1e-6 * np.abs(at.omega).max())
    for lower, upper in (("omega", "alpha"), ("alpha", "jerk")):
        fd = (getattr(plus, lower) - getattr(minus, lower)) / (2 * h)
        exact = getattr(at, upper)
        np.testing.assert_allclose(fd, exact, atol=1e-5 * np.abs(exact).max())


def test_retimed_motion_is_c3_across_knots_and_keyframes(rng):
    """Jerk continuous at every knot of sigma and every keyframe: no step from either side."""
    path = _path(rng)
    law = _law(rng, s0=path.t_start, span=path.t_end - path.t_start)
    retimed = RetimedPath(path, law)
    inner = np.unique(law.knots)[1:-1]
    joints = np.concatenate([law.t_start + inner * law.duration_s, retimed.times[1:-1]])
    eps = 1e-9
    left, right = (
        retimed.evaluate(joints - eps, max_order=3),
        retimed.evaluate(joints + eps, max_order=3),
    )
    scale = np.abs(
        retimed.evaluate(np.linspace(law.t_start, law.t_end, 500), max_order=3).jerk
    ).max()
    np.testing.assert_allclose(left.jerk, right.jerk, atol=1e-5 * scale)


def test_keyframes_are_passed_in_order_at_rest_ends(rng):
    path = _path(rng)
    law = _law(rng, s0=path.t_start, span=path.t_end - path.t_start)
    retimed = RetimedPath(path, law)
    assert (np.diff(retimed.times) > 0).all()
    dots = np.abs(
        np.einsum(
            "ij,ij->i",
            retimed.evaluate(retimed.times, max_order=0).q,
            path.evaluate(path.times, max_order=0).q,
        )
    )
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)
    ends = retimed.evaluate([retimed.t_start, retimed.t_end], max_order=2)
    assert np.abs(ends.omega).max() < 1e-12 and np.abs(ends.alpha).max() < 1e-9


def test_stream_frames_equal_the_plan(rng):
    path = _path(rng)
    retimed = RetimedPath(path, _law(rng, s0=path.t_start, span=path.t_end - path.t_start))
    plan = plan_joint_trajectory(retimed, 100.0)
    frames = list(stream_frames(retimed, 100.0))
    np.testing.assert_allclose(np.array([f.q for f in frames]), plan.q, atol=1e-12)
    np.testing.assert_allclose(np.array([f.qdd for f in frames]), plan.qdd, atol=1e-9)


@pytest.mark.parametrize(
    ("knots", "coefficients", "match"),
    [
        ([0] * 6 + [1] * 6, [0, 0.2, 0.2, 0.6, 0.8, 1], "strictly increasing from 0 to 1"),
        ([0] * 6 + [1] * 6, [0, 0.2, 0.4, 0.6, 0.8, 0.9], "strictly increasing from 0 to 1"),
        ([0] * 5 + [0.5] + [1] * 6, [0, 0.2, 0.4, 0.6, 0.8, 1], "6 zeros first"),
        ([0] * 6 + [1] * 5, [0, 0.2, 0.4, 0.6, 0.8, 1], "6 knots more than coefficients"),
    ],
)
def test_bad_law_is_refused(knots, coefficients, match):
    with pytest.raises(ValueError, match=match):
        TimeLaw(knots, coefficients, 0.0, 1.0, 0.0, 1.0)


TIMED = """\
[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = {t1}
pan = 40.0

[[keyframes]]
t = 1.2
pan = 10.0

[timing]
path_times = [0.0, 1.0, 3.0]
duration_s = 1.2
knots = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]
coefficients = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]
"""


def test_timing_table_is_read_into_a_retimed_path(tmp_path):
    # sigma(tau) = tau: path time 1.0 of 3.0 is reached at 1.2 / 3 = 0.4 s.
    path = tmp_path / "timed.toml"
    path.write_text(TIMED.format(t1=0.4))
    kf = load_keyframe_file(path)
    spline = kf.spline()
    assert isinstance(spline, RetimedPath)
    np.testing.assert_allclose(spline.times, [0.0, 0.4, 1.2], atol=1e-12)
    assert spline.t_end == pytest.approx(1.2)
    # The same path as the spline at path_times, three times as fast.
    base = SmoothSpline(kf.quats, [0.0, 1.0, 3.0])
    t = np.linspace(0.0, 1.2, 7)
    np.testing.assert_allclose(
        spline.evaluate(t).omega, 2.5 * base.evaluate(t * 2.5).omega, atol=1e-12
    )


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            TIMED.format(t1=0.5),
            r"keyframe 2: field 't': 0.5 s, but the \[timing\] law passes it at 0.400000 s",
        ),
        (
            TIMED.format(t1=0.4).replace("duration_s = 1.2\n", ""),
            r"\[timing\]: 'duration_s' is missing",
        ),
        (
            TIMED.format(t1=0.4).replace("[0.0, 1.0, 3.0]", "[0.0, 3.0]"),
            r"\[timing\] path_times: expected 3 increasing",
        ),
        (
            TIMED.format(t1=0.4).replace("0.2, 0.4", "0.4, 0.2"),
            r"\[timing\]: Expected coefficients strictly increasing",
        ),
        (TIMED.format(t1=0.4) + "speed = 1\n", r"\[timing\] unknown key 'speed'"),
    ],
)
def test_bad_timing_table(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(KeyframeFileError, match=match):
        load_keyframe_file(path)


FITTED_ANGLES = [(0.0, 0.0, 0.0), (50.0, 20.0, 5.0), (-20.0, -10.0, 0.0), (10.0, 5.0, 0.0)]


def _fitted_file(tmp_path, rng, duration=1.2):
    """A keyframe file with a [timing] table (an uneven law, as `trajgen fit` writes one)."""
    path_times = [0.0, 1.0, 2.2, 3.0]
    angles = np.radians(FITTED_ANGLES)
    base = SmoothSpline(Q.from_pan_tilt_roll(*angles.T), path_times)
    knots = np.concatenate([np.zeros(6), [0.2, 0.35, 0.5, 0.65, 0.8], np.ones(6)])
    c = np.concatenate([[0.0], np.sort(rng.uniform(0.02, 0.98, 9)), [1.0]])
    law = TimeLaw(knots, c, 0.0, duration, 0.0, 3.0)
    times = RetimedPath(base, law).times
    text = '[spline]\nmethod = "smooth"\n\n'
    for t, (pan, tilt, roll) in zip(times.tolist(), FITTED_ANGLES, strict=True):
        text += f"[[keyframes]]\nt = {t!r}\npan = {pan}\ntilt = {tilt}\nroll = {roll}\n\n"
    text += (
        f"[timing]\npath_times = {path_times}\nduration_s = {duration}\n"
        f"knots = {knots.tolist()}\ncoefficients = {c.tolist()}\n"
    )
    path = tmp_path / "fitted.toml"
    path.write_text(text)
    return load_keyframe_file(path)


def _arrays(frames):
    return (np.array([getattr(f, name) for f in frames]) for name in ("t", "q", "qd", "qdd"))


def test_follow_plays_a_fitted_file_as_stream_does(tmp_path, rng):
    from trajgen.follower import Follower, online_spline

    kf = _fitted_file(tmp_path, rng)
    follower = Follower(online_spline(kf), 200.0)
    follower.spline.close()  # no change: the whole fitted motion
    t, q, qd, qdd = _arrays(list(follower.frames()))
    t0, q0, qd0, qdd0 = _arrays(list(stream_frames(kf.spline(), 200.0)))
    assert len(t) == len(t0) == 241
    # The same frames, to rounding (the online clock is t0 + i / rate, the offline one
    # sample_times': they differ by an ulp; at t_end the online plan holds its rest
    # exactly, the law's own evaluation leaves ~1e-10 rad/s^2 there).
    for got, want in ((t, t0), (q, q0), (qd, qd0), (qdd, qdd0)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)
    assert np.abs(qd0).max() > 1.0  # a real motion, not a rest


def test_a_retarget_splices_onto_the_fitted_law(tmp_path, rng):
    from trajgen.follower import online_spline

    kf = _fitted_file(tmp_path, rng)
    fitted = kf.spline()
    spline = online_spline(kf)
    at, goal = 0.5, Q.from_pan_tilt_roll(0.3, 0.1, 0.0)
    spline.retarget(goal[None], [1.3], at=at)
    before = np.linspace(0.0, at, 50)
    for order in range(3):
        np.testing.assert_allclose(spline(before, order), fitted(before, order), atol=1e-12)
    # C2 across `at` (k = 2): the splice matches the law's jet there.
    for order in range(3):
        np.testing.assert_allclose(spline(at + 1e-9, order), fitted(at, order), atol=1e-5)
    assert Q.distance(spline(1.3), goal) < 1e-9
    np.testing.assert_allclose(spline(1.3, 1), 0.0, atol=1e-9)


def test_an_extend_keeps_the_whole_fitted_motion(tmp_path, rng):
    from trajgen.follower import online_spline

    kf = _fitted_file(tmp_path, rng)
    fitted = kf.spline()
    spline = online_spline(kf)
    goal = Q.from_pan_tilt_roll(0.3, 0.1, 0.0)
    spline.extend(goal[None], [2.0], at=0.5)
    during = np.linspace(0.0, fitted.t_end, 80)
    for order in range(3):  # (at t_end the plan holds the rest exactly, the law to ~1e-10)
        np.testing.assert_allclose(spline(during, order), fitted(during, order), atol=1e-9)
    assert Q.distance(spline(2.0), goal) < 1e-9
    assert np.linalg.norm(spline(1.6, 1)) > 0.1  # then on, from its rest, to the goal


def test_from_path_refuses_k3_and_a_bare_object(tmp_path, rng):
    from trajgen.online import OnlineSpline

    kf = _fitted_file(tmp_path, rng)
    with pytest.raises(ValueError, match=r"Expected `k` to be an integer in 1\.\.2, got 3"):
        OnlineSpline.from_path(kf.spline(), k=3)
    with pytest.raises(TypeError, match="Expected `path` to have times, quats and evaluate"):
        OnlineSpline.from_path(object())
