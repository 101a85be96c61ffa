"""The joint stream: planned arrays and the online iterator."""

import itertools
import math
import re
from typing import NamedTuple

import numpy as np
import pytest

from trajgen import quat
from trajgen.gimbal import GimbalKinematics, KinematicsError, forward
from trajgen.spline import BlendingSpline
from trajgen.stream import (
    JointFrame,
    JointTrajectory,
    plan_joint_trajectory,
    stream_frames,
)


class Samples(NamedTuple):
    t: np.ndarray
    q: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    jerk: np.ndarray | None


class UniformRotation:
    """A fake spline: constant angular velocity ``rate * axis`` from ``q0``.

    ``q(t) = exp(rate (t - t_start) axis / 2) q0``, omega = rate axis, alpha = 0.
    It records the times of every ``evaluate`` call.
    """

    def __init__(self, axis, rate, q0, t_start, t_end):
        self.axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
        self.rate = rate
        self.q0 = np.asarray(q0, dtype=float)
        self.t_start = t_start
        self.t_end = t_end
        self.calls = []

    def evaluate(self, t, *, max_order=2, frame="space"):
        t = np.asarray(t, dtype=float)
        self.calls.append(t.copy())
        if frame != "space" or max_order != 2:
            raise AssertionError("the stream needs space-frame omega and alpha")
        q = quat.mul(quat.from_axis_angle(self.axis, self.rate * (t - self.t_start)), self.q0)
        omega = np.broadcast_to(self.rate * self.axis, q.shape[:-1] + (3,)).copy()
        return Samples(t, q, omega, np.zeros_like(omega), None)


#: Limits wide enough for pan and roll to wrap several times.
WIDE = GimbalKinematics(((-1e3, 1e3), (-math.pi / 2, math.pi / 2), (-1e3, 1e3)))


def pan_sweep(t_end=3.5):
    """Pan at 1 rad/s from 2.5 rad with tilt 0.3, roll -0.2: crosses +pi at 0.64 s.

    It stays inside the default limits (pan +-2 pi) up to t = 2 pi - 2.5 = 3.78 s.
    """
    return UniformRotation([0, 0, 1], 1.0, forward([2.5, 0.3, -0.2]), 0.0, t_end)


def tumble():
    """A rotation about a skew axis: all three joints move, pan and roll wrap."""
    q0 = forward([3.0, 0.2, 3.0])
    return UniformRotation([0.6, -0.3, 1.0], 1.3, q0, 0.25, 2.75)


def test_plan_of_a_pure_pan_is_exact():
    traj = plan_joint_trajectory(pan_sweep(), 100.0)
    assert isinstance(traj, JointTrajectory)
    assert traj.rate_hz == 100.0
    # Hand-derived: pan = 2.5 + t (unwrapped past pi), tilt and roll fixed.
    expected = np.stack([2.5 + traj.t, np.full_like(traj.t, 0.3), np.full_like(traj.t, -0.2)], 1)
    np.testing.assert_allclose(traj.q, expected, atol=1e-12)
    np.testing.assert_allclose(traj.qd, np.tile([1.0, 0.0, 0.0], (len(traj), 1)), atol=1e-12)
    np.testing.assert_allclose(traj.qdd, 0.0, atol=1e-12)


@pytest.mark.parametrize(
    "t_start, t_end, rate_hz, count",
    [
        (0.0, 3.5, 100.0, 351),  # 350 whole periods
        (0.5, 2.0, 100, 151),
        (0.0, 1.505, 100.0, 152),  # 150 periods, then t_end 5 ms later
        (0.0, 1.0, 3.0, 4),  # 0, 1/3, 2/3 and t_end = 1
    ],
)
def test_frame_count_and_times(t_start, t_end, rate_hz, count):
    spline = UniformRotation([0, 0, 1], 0.5, [1.0, 0, 0, 0], t_start, t_end)
    traj = plan_joint_trajectory(spline, rate_hz)
    assert len(traj) == count
    assert traj.t[0] == t_start
    assert traj.t[-1] == t_end
    np.testing.assert_allclose(np.diff(traj.t)[:-1], 1.0 / rate_hz, rtol=1e-12)
    assert 0 < traj.t[-1] - traj.t[-2] <= 1.0 / rate_hz + 1e-12
    assert traj.duration_s == pytest.approx(t_end - t_start)
    frames = list(stream_frames(spline, rate_hz))
    assert [f.index for f in frames] == list(range(count))
    assert [f.t for f in frames] == traj.t.tolist()


@pytest.mark.parametrize("start", [None, np.array([-7.0, 0.0, 5.0])])
def test_iterator_agrees_with_arrays(start):
    spline = tumble()
    traj = plan_joint_trajectory(spline, 250.0, WIDE, start=start)
    frames = list(stream_frames(spline, 250.0, WIDE, start=start))
    assert len(frames) == len(traj)
    assert all(isinstance(f, JointFrame) for f in frames)
    for name in ("q", "qd", "qdd"):
        online = np.array([getattr(f, name) for f in frames])
        np.testing.assert_allclose(online, getattr(traj, name), rtol=0, atol=1e-12)
    # Pan and roll crossed +-pi (so the carried unwrapping was exercised) ...
    wrapped = (traj.q[:, [0, 2]] + math.pi) % (2 * math.pi) - math.pi
    assert (np.abs(np.diff(wrapped, axis=0)).max(axis=0) > 6.0).all()
    assert np.abs(np.diff(traj.q, axis=0)).max() < 0.1
    # ... and the arrays' frames are the same frames.
    assert [f.t for f in traj] == [f.t for f in frames]


def test_plan_rates_match_finite_differences_on_a_tumble():
    traj = plan_joint_trajectory(tumble(), 1000.0, WIDE)
    h = traj.t[1] - traj.t[0]
    fd_qd = (traj.q[2:-1] - traj.q[:-3]) / (2 * h)
    fd_qdd = (traj.q[2:-1] - 2 * traj.q[1:-2] + traj.q[:-3]) / h**2
    # Tilt reaches 77 deg, where the joint rates change fast: relative tolerance.
    np.testing.assert_allclose(traj.qd[1:-2], fd_qd, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(traj.qdd[1:-2], fd_qdd, rtol=1e-4, atol=1e-4)


def test_start_picks_the_branch_of_the_first_frame():
    start = np.array([2.5 - 2 * math.pi, 0.0, -0.2 + 2 * math.pi])
    traj = plan_joint_trajectory(pan_sweep(), 50.0, WIDE, start=start)
    np.testing.assert_allclose(traj.q[0], [2.5 - 2 * math.pi, 0.3, -0.2 + 2 * math.pi])
    first = next(stream_frames(pan_sweep(), 50.0, WIDE, start=start))
    np.testing.assert_allclose(first.q, traj.q[0], atol=1e-12)


def test_iterator_works_at_most_one_block_ahead():
    from trajgen.stream import BLOCK_FRAMES

    spline = pan_sweep()
    frames = stream_frames(spline, 100.0)
    assert spline.calls == []
    next(frames)
    assert len(spline.calls) == 1  # the first block, before the first frame
    for i in range(1, 3 * BLOCK_FRAMES):
        next(frames)
        # Frame i is out; the next block is worked while this one is handed out.
        assert len(spline.calls) == i // BLOCK_FRAMES + 1 + (i % BLOCK_FRAMES > 0)
    for b, times in enumerate(spline.calls):
        np.testing.assert_allclose(times, (np.arange(BLOCK_FRAMES) + b * BLOCK_FRAMES) / 100.0)


def test_plan_evaluates_once_with_max_order_2():
    spline = pan_sweep(t_end=1.0)
    plan_joint_trajectory(spline, 10.0)
    assert len(spline.calls) == 1
    np.testing.assert_allclose(spline.calls[0], np.arange(11) / 10.0)


def lock_tilt():
    """Tilt about y at 0.5 rad/s from 0: tilt = 0.5 t, past 80 deg at t = 2.7925 s."""
    return UniformRotation([0, 1, 0], 0.5, [1.0, 0, 0, 0], 0.0, 4.0)


def test_plan_and_iterator_refuse_gimbal_lock_at_the_same_frame():
    # 100 Hz: the first frame past 80 deg (t > 1.39626 * 2 s) is t = 2.80 s, 80.2 deg.
    message = (
        "tilt reaches 80.2 deg at t = 2.800 s, within 10.0 deg of gimbal lock (limit 80.0 deg)"
    )
    with pytest.raises(KinematicsError, match=re.escape(message)):
        plan_joint_trajectory(lock_tilt(), 100.0)
    frames = stream_frames(lock_tilt(), 100.0)
    passed = []
    with pytest.raises(KinematicsError, match=re.escape(message)):
        for frame in frames:
            passed.append(frame)
    assert len(passed) == 280
    assert passed[-1].t == pytest.approx(2.79)


def test_custom_kinematics_limits_apply():
    limits = ((-math.pi, math.pi), (-math.pi / 2, math.pi / 2), (-math.pi, math.pi))
    kin = GimbalKinematics(limits)
    # pan = 2.5 + t passes 180 deg at t = pi - 2.5 = 0.642 s; at 50 Hz the first frame
    # after that is t = 0.66 s, where pan = 3.16 rad = 181.05 deg.
    message = "pan reaches 181.1 deg at t = 0.660 s, outside its limits [-180.0, 180.0] deg"
    with pytest.raises(KinematicsError, match=re.escape(message)):
        plan_joint_trajectory(pan_sweep(), 50.0, kin)
    with pytest.raises(KinematicsError, match=re.escape(message)):
        list(stream_frames(pan_sweep(), 50.0, kin))


@pytest.mark.parametrize(
    "rate_hz, error, message",
    [
        (0.0, ValueError, "Expected `rate_hz` to be a finite number > 0, got 0.0."),
        (-100, ValueError, "Expected `rate_hz` to be a finite number > 0, got -100."),
        (math.nan, ValueError, "Expected `rate_hz` to be a finite number > 0, got nan."),
        (math.inf, ValueError, "Expected `rate_hz` to be a finite number > 0, got inf."),
        ("100", TypeError, "Expected `rate_hz` to be a finite number > 0, got '100'."),
        (True, TypeError, "Expected `rate_hz` to be a finite number > 0, got True."),
    ],
)
def test_rate_is_validated_at_the_call(rate_hz, error, message):
    with pytest.raises(error, match=re.escape(message)):
        plan_joint_trajectory(pan_sweep(), rate_hz)
    # The iterator checks before its first next().
    with pytest.raises(error, match=re.escape(message)):
        stream_frames(pan_sweep(), rate_hz)


@pytest.mark.parametrize("make", [plan_joint_trajectory, stream_frames])
def test_other_arguments_are_validated_at_the_call(make):
    message = "Expected `spline` to have t_start, t_end and evaluate(t, max_order=2), got list."
    with pytest.raises(TypeError, match=re.escape(message)):
        make([1, 2, 3], 100.0)
    message = "Expected `kinematics` to be a GimbalKinematics, got dict."
    with pytest.raises(TypeError, match=re.escape(message)):
        make(pan_sweep(), 100.0, {"lock_margin_rad": 0.1})
    message = "Expected `start` to have shape (3,), got (2,)."
    with pytest.raises(ValueError, match=re.escape(message)):
        make(pan_sweep(), 100.0, start=[0.0, 0.0])


def test_blending_spline_stream_passes_through_keyframes_at_rest():
    # Keyframes given as joint angles: the planned joints must come back to them.
    keys_deg = [[0, 0, 0], [40, 10, 0], [-30, -20, 5], [120, 15, 0], [170, 0, 0], [90, 30, -10]]
    keys = np.radians(keys_deg)
    times = [0.0, 1.5, 3.0, 4.5, 6.0, 8.0]
    spline = BlendingSpline(forward(keys), times)
    traj = plan_joint_trajectory(spline, 100.0)
    at_keys = np.searchsorted(traj.t, np.array(times) - 1e-9)
    np.testing.assert_allclose(traj.t[at_keys], times, atol=1e-12)
    np.testing.assert_allclose(traj.q[at_keys], keys, atol=1e-9)
    # boundary="rest": the joints start and stop still.
    np.testing.assert_allclose(traj.qd[[0, -1]], 0.0, atol=1e-9)
    np.testing.assert_allclose(traj.qdd[[0, -1]], 0.0, atol=1e-9)
    online = list(itertools.islice(stream_frames(spline, 100.0), 60))
    for name in ("q", "qd", "qdd"):
        got = np.array([getattr(f, name) for f in online])
        np.testing.assert_allclose(got, getattr(traj, name)[:60], rtol=0, atol=1e-12)
