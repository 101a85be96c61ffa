"""The per-frame path of the stream (trajgen.frame_eval) against the numpy block path."""

import math
import re

import numpy as np
import pytest
from conftest import random_walk_keyframes
from hypothesis import given, settings
from hypothesis import strategies as st

from trajgen import SmoothSpline, load_keyframe_file
from trajgen import derivatives as dv
from trajgen.errors import KinematicsError
from trajgen.frame_eval import FrameKinematics, SmoothFrames, cos_sinc_sqrt
from trajgen.gimbal import GimbalKinematics, forward, joint_rates
from trajgen.jet import SERIES_BELOW
from trajgen.keyframes import BUILTIN_EXAMPLE
from trajgen.sampling import sample_times
from trajgen.spline import BlendingSpline
from trajgen.stream import plan_joint_trajectory, stream_frames

#: Limits wide enough for pan and roll to wrap several times.
WIDE = GimbalKinematics(((-1e3, 1e3), (-math.pi / 2, math.pi / 2), (-1e3, 1e3)))


def test_cos_sinc_matches_the_numpy_closed_forms_on_both_branches():
    x = np.concatenate(
        [
            [0.0, SERIES_BELOW, np.nextafter(SERIES_BELOW, 0.0)],
            np.linspace(0.0, 2 * SERIES_BELOW, 401),
            np.geomspace(1e-12, 60.0, 400),
        ]
    )
    # Derivatives in x itself: the chain rule with x' = 1, x'' = 0.
    C, S = dv.cos_sinc_sqrt([x, np.ones_like(x), np.zeros_like(x)])
    scalar = np.array([cos_sinc_sqrt(float(v)) for v in x])
    np.testing.assert_allclose(scalar[:, :3], np.array(C).T, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(scalar[:, 3:], np.array(S).T, rtol=1e-13, atol=1e-15)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 9),
    spread=st.floats(0.05, 1.5),
    boundary=st.sampled_from(["rest", "natural", "closed"]),
    quintic=st.booleans(),
)
def test_smooth_frames_equal_the_spline_at_any_time(seed, n, spread, boundary, quintic):
    q, t = random_walk_keyframes(seed, n, spread, boundary)
    # Either knot choice (the default at rest is end-minimax): the frames read the table.
    spline = SmoothSpline(q, t, boundary=boundary, knots="quintic" if quintic else None)
    rng = np.random.default_rng(seed)
    # Increasing times (the stream's case) with the keyframe times among them, then
    # the same times shuffled (every lookup leaves the segment).
    times = np.sort(np.concatenate([rng.uniform(t[0], t[-1], 200), t]))
    for order in (times, rng.permutation(times)):
        ref = spline.evaluate(order, max_order=2)
        frames = SmoothFrames(spline)
        got = [frames(float(ti)) for ti in order]
        for k, want in enumerate((ref.q, ref.omega, ref.alpha)):
            scale = 1.0 + np.abs(want).max()
            np.testing.assert_allclose(np.array([g[k] for g in got]), want, atol=1e-13 * scale)


def test_smooth_frames_refuse_times_outside_an_open_spline():
    spline = SmoothSpline(forward([[0.0, 0.0, 0.0], [1.0, 0.2, 0.0]]), [0.0, 2.0])
    frames = SmoothFrames(spline)
    np.testing.assert_allclose(frames(2.0 + 1e-13)[0], spline(2.0), atol=1e-15)
    for t in (-1e-9, 2.001, math.nan):
        with pytest.raises(ValueError, match=re.escape(f"Time {t!r} s is outside")):
            frames(t)
        with pytest.raises(ValueError):
            spline.evaluate([t])


def assert_same_stream(spline, rate_hz, kinematics=WIDE, start=None):
    """stream_frames equals plan_joint_trajectory frame by frame, or both refuse the
    path at the same frame with the same message."""
    try:
        traj = plan_joint_trajectory(spline, rate_hz, kinematics, start=start)
    except KinematicsError as e:
        message = str(e)
        frames = []
        with pytest.raises(KinematicsError, match=re.escape(message)):
            for frame in stream_frames(spline, rate_hz, kinematics, start=start):
                frames.append(frame)
        # Raised at the frame after the last one yielded, as the plan.
        t = sample_times(spline.t_start, spline.t_end, rate_hz)
        assert f"at t = {t[len(frames)]:.3f} s" in message
        return None
    frames = list(stream_frames(spline, rate_hz, kinematics, start=start))
    assert [f.index for f in frames] == list(range(len(traj)))
    assert [f.t for f in frames] == traj.t.tolist()
    for name in ("q", "qd", "qdd"):
        got = np.array([getattr(f, name) for f in frames])
        want = getattr(traj, name)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * (1 + np.abs(want).max()))
    return traj


def gimbal_keyframes(seed, n, boundary):
    """Random gimbal poses (tilt within +-50 deg) at random times."""
    rng = np.random.default_rng(seed)
    angles = rng.uniform([-3.0, -0.9, -3.0], [3.0, 0.9, 3.0], size=(n, 3))
    if boundary == "closed":
        angles = np.vstack([angles, angles[:1]])
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.3, 2.0, len(angles) - 1))])
    return forward(angles), t


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 7),
    boundary=st.sampled_from(["rest", "natural", "closed"]),
    quintic=st.booleans(),
    rate_hz=st.sampled_from([97.0, 250.0, 1000.0]),
    start=st.sampled_from([None, (-7.0, 0.0, 5.0), (20.0, 0.1, -13.0)]),
)
def test_stream_equals_the_plan_for_smooth_splines(seed, n, boundary, quintic, rate_hz, start):
    q, t = gimbal_keyframes(seed, max(n, 3) if boundary == "closed" else n, boundary)
    spline = SmoothSpline(q, t, boundary=boundary, knots="quintic" if quintic else None)
    assert_same_stream(spline, rate_hz, start=None if start is None else np.array(start))


@pytest.mark.parametrize("boundary", ["rest", "natural"])
def test_stream_of_the_builtin_example_equals_the_plan(boundary):
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    assert_same_stream(SmoothSpline(kf.quats, kf.times, boundary=boundary), 1000.0)
    assert_same_stream(kf.spline(), 1000.0)  # the file's own (blending) spline: block path


def test_smooth_stream_is_evaluated_per_frame():
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    spline = SmoothSpline(kf.quats, kf.times)
    want = plan_joint_trajectory(spline, 200.0)

    def refuse(*args, **kwargs):
        raise AssertionError("the per-frame path calls no numpy evaluation")

    spline.evaluate = spline.evaluation_steps = refuse
    frames = list(stream_frames(spline, 200.0))
    np.testing.assert_allclose(np.array([f.q for f in frames]), want.q, atol=1e-12)


def test_smooth_stream_refuses_gimbal_lock_at_the_same_frame_as_the_plan():
    # Tilt from 0 to 85 deg: the lock guard (80 deg) stops it part way.
    spline = SmoothSpline(forward([[0.0, 0.0, 0.0], [0.5, math.radians(85), 0.2]]), [0.0, 2.0])
    message = "within 10.0 deg of gimbal lock (limit 80.0 deg)"
    with pytest.raises(KinematicsError, match=re.escape(message)):
        plan_joint_trajectory(spline, 100.0)
    assert_same_stream(spline, 100.0, GimbalKinematics())


def test_smooth_stream_refuses_a_joint_limit_at_the_same_frame_as_the_plan():
    limits = ((-1.0, 1.0), (-math.pi / 2, math.pi / 2), (-math.pi, math.pi))
    spline = SmoothSpline(forward([[0.0, 0.0, 0.0], [1.5, 0.2, 0.0]]), [0.0, 2.0])
    with pytest.raises(KinematicsError, match=r"pan reaches .* outside its limits \[-57.3, 57.3\]"):
        plan_joint_trajectory(spline, 100.0, GimbalKinematics(limits))
    assert_same_stream(spline, 100.0, GimbalKinematics(limits))


def test_frame_kinematics_equal_inverse_and_joint_rates(rng):
    # A tumbling path sampled coarsely enough that pan and roll wrap between samples.
    n = 400
    angles = np.cumsum(rng.normal(scale=[0.6, 0.05, 0.6], size=(n, 3)), axis=0)
    angles[:, 1] = 1.2 * np.sin(angles[:, 1])
    q = forward(angles) * rng.choice([-1.0, 1.0], size=(n, 1)) * rng.uniform(0.5, 2, (n, 1))
    omega, alpha = rng.normal(size=(n, 3)), rng.normal(scale=10.0, size=(n, 3))
    t = np.arange(n) * 0.01
    for start in (None, np.array([13.0, 0.0, -20.0])):
        want = WIDE.inverse(q, t, start=start)
        want_qd, want_qdd = joint_rates(want, omega, alpha)
        kin = FrameKinematics(WIDE, start)
        got = [kin(t[i], q[i].tolist(), omega[i].tolist(), alpha[i].tolist()) for i in range(n)]
        np.testing.assert_allclose([g[0] for g in got], want, rtol=0, atol=1e-12)
        np.testing.assert_allclose([g[1] for g in got], want_qd, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose([g[2] for g in got], want_qdd, rtol=1e-12, atol=1e-11)


@pytest.mark.parametrize(
    "q, omega, alpha, message",
    [
        ([math.nan, 0, 0, 1], [0, 0, 0], [0, 0, 0], "`quats` row 0 is not finite"),
        ([0.0, 0, 0, 0], [0, 0, 0], [0, 0, 0], "`quats` row 0 has zero norm"),
        ([1.0, 0, 0, 0], [0, math.inf, 0], [0, 0, 0], "Expected `omega` to be finite"),
        ([1.0, 0, 0, 0], [0, 0, 0], [math.nan, 0, 0], "Expected `alpha` to be finite"),
    ],
)
def test_frame_kinematics_refuse_values_that_are_not_finite(q, omega, alpha, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        FrameKinematics(GimbalKinematics())(0.0, q, omega, alpha)


def test_blending_stream_equals_the_plan_with_wrapping(rng):
    keys = np.array([[0.0, 0.0, 0.0], [2.5, 0.3, 2.0], [5.5, -0.4, 4.5], [9.0, 0.2, 7.0]])
    spline = BlendingSpline(forward(keys), [0.0, 1.0, 2.0, 3.0])
    traj = assert_same_stream(spline, 500.0)
    assert np.abs(traj.q[:, [0, 2]]).max() > 2 * math.pi  # unwrapped past a whole turn


# ---------------------------------------------------------------- other axis sequences

#: Every axis sequence but the default (served by FrameKinematics itself).
OTHER_AXES = [
    a + b + c
    for a in "xyz"
    for b in "xyz"
    for c in ("", "x", "y", "z")
    if a != b and b != c and a + b + c != "zyx"
]


def _wide(kin_axes: str) -> GimbalKinematics:
    seq = GimbalKinematics(axes=kin_axes).sequence
    limits = [(-1e3, 1e3)] * seq.n
    limits[1] = seq.middle_range
    return GimbalKinematics(tuple(limits), axes=kin_axes)


@pytest.mark.parametrize("axes", OTHER_AXES)
def test_axes_frame_kinematics_equal_inverse_and_joint_rates(rng, axes):
    """Floats of one frame against the numpy arrays, wrapping included."""
    kin = _wide(axes)
    seq = kin.sequence
    n = 300
    angles = np.cumsum(rng.normal(scale=0.6, size=(n, seq.n)), axis=0)
    low, high = seq.middle_range
    middle, half = (low + high) / 2, (high - low) / 2
    angles[:, 1] = middle + 0.75 * half * np.sin(angles[:, 1])
    q = kin.forward(angles) * rng.choice([-1.0, 1.0], size=(n, 1)) * rng.uniform(0.5, 2, (n, 1))
    omega, alpha = rng.normal(size=(n, 3)), rng.normal(scale=10.0, size=(n, 3))
    t = np.arange(n) * 0.01
    for start in (None, np.full(seq.n, 13.0)):
        if start is not None:
            start[1] = middle
        want = kin.inverse(q, t, start=start)
        want_qd, want_qdd = kin.joint_rates(want, omega, alpha)
        frame = FrameKinematics(kin, start)
        assert type(frame).__name__ == "AxesFrameKinematics"
        got = [frame(t[i], q[i].tolist(), omega[i].tolist(), alpha[i].tolist()) for i in range(n)]
        assert all(len(g[0]) == seq.n and isinstance(g[0][0], float) for g in got)
        np.testing.assert_allclose([g[0] for g in got], want, rtol=0, atol=1e-12)
        np.testing.assert_allclose([g[1] for g in got], want_qd, rtol=1e-11, atol=1e-11)
        np.testing.assert_allclose([g[2] for g in got], want_qdd, rtol=1e-11, atol=1e-10)


@pytest.mark.parametrize(
    "axes, angles, message",
    [
        ("zy", (0.3, 1.45), "tilt reaches 83.1 deg at t = 0.500 s, within 10.0 deg of gimbal lock"),
        ("zxz", (0.3, 0.1, 0.2), "joint2 reaches 5.7 deg at t = 0.500 s, within 10.0 deg"),
        ("yx", (2.0, 0.1), "joint1 reaches 114.6 deg at t = 0.500 s, outside its limits"),
    ],
)
def test_axes_frame_kinematics_refuse_lock_and_limits_as_check(axes, angles, message):
    limits = None if axes != "yx" else ((-1.0, 1.0), (-1.5, 1.5))
    kin = GimbalKinematics(limits, axes=axes)
    q = kin.forward(np.array([angles]))[0].tolist()
    with pytest.raises(KinematicsError, match=re.escape(message)):
        kin.check(np.array([angles]), np.array([0.5]))
    with pytest.raises(KinematicsError, match=re.escape(message)):
        FrameKinematics(kin)(0.5, q, [0.0] * 3, [0.0] * 3)


@pytest.mark.parametrize(
    "q, omega, alpha, message",
    [
        ([math.nan, 0, 0, 1], [0, 0, 0], [0, 0, 0], "`quats` row 0 is not finite"),
        ([1.0, 0, 0, 0], [0, math.inf, 0], [0, 0, 0], "Expected `omega` to be finite"),
        ([1.0, 0, 0, 0], [0, 0, 0], [math.nan, 0, 0], "Expected `alpha` to be finite"),
    ],
)
def test_axes_frame_kinematics_refuse_values_that_are_not_finite(q, omega, alpha, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        FrameKinematics(GimbalKinematics(axes="yx"))(0.0, q, omega, alpha)
