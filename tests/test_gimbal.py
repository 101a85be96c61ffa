"""Pan-tilt-roll kinematics: forward, inverse (unwrapping, refusals), joint rates."""

import math
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trajgen import quat
from trajgen.gimbal import (
    DEFAULT_LIMITS_RAD,
    GimbalKinematics,
    KinematicsError,
    forward,
    jacobian,
    joint_rates,
)
from trajgen.stream import JOINT_NAMES

WIDE = ((-1e3, 1e3), (-math.pi / 2, math.pi / 2), (-1e3, 1e3))


@pytest.fixture
def rng():
    return np.random.default_rng(20260521)


def random_angles(rng, n, max_tilt_deg=79.0):
    """Random (pan, tilt, roll) in (-pi, pi) x (-max_tilt, max_tilt) x (-pi, pi)."""
    bound = [math.pi, math.radians(max_tilt_deg), math.pi]
    return rng.uniform(-np.array(bound), bound, size=(n, 3))


# A smooth joint path: each joint is c0 + c1 t + A sin(w t + phi), so its first
# and second derivatives are known exactly. Pan crosses +pi near t = 0.7 s.
JOINT_PATH = np.array(
    [  # c0, c1, A, w, phi
        [2.0, 0.6, 1.5, 0.8, 0.0],
        [0.0, 0.0, 0.9, 1.1, 0.3],
        [0.0, 0.0, 0.7, 1.7, 1.0],
    ]
)


def joint_path(t):
    """Angles, velocities and accelerations (N, 3) of JOINT_PATH at times t (N,)."""
    c0, c1, amp, w, phi = JOINT_PATH.T
    arg = np.multiply.outer(t, w) + phi
    q = c0 + np.multiply.outer(t, c1) + amp * np.sin(arg)
    qd = c1 + amp * w * np.cos(arg)
    qdd = -amp * w * w * np.sin(arg)
    return q, qd, qdd


def angular_motion(q, qd, qdd):
    """Space-frame omega, alpha (N, 3) of Rz Ry Rx by the quaternion product rule.

    Independent of the Jacobian: each factor is f(a) = (cos a/2, sin a/2 e), with
    f' = a'/2 (-sin a/2, cos a/2 e) and f'' = a''/2 (...) - a'^2/4 f; then
    omega = 2 vec(Q' Q*) and alpha = 2 vec(Q'' Q* + Q' Q'*).
    """
    factors = []
    for j, axis in enumerate(np.eye(3)[[2, 1, 0]]):
        half = q[:, j] / 2
        f = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axis], axis=1)
        df_unit = np.concatenate([-np.sin(half)[:, None], np.cos(half)[:, None] * axis], axis=1)
        df = qd[:, j, None] / 2 * df_unit
        ddf = qdd[:, j, None] / 2 * df_unit - qd[:, j, None] ** 2 / 4 * f
        factors.append((f, df, ddf))
    (a, da, dda), (b, db, ddb), (c, dc, ddc) = factors

    def m(x, y, z):
        return quat.mul(quat.mul(x, y), z)

    big_q = m(a, b, c)
    dq = m(da, b, c) + m(a, db, c) + m(a, b, dc)
    ddq = m(dda, b, c) + m(a, ddb, c) + m(a, b, ddc)
    ddq = ddq + 2 * (m(da, db, c) + m(da, b, dc) + m(a, db, dc))
    omega = 2 * quat.mul(dq, quat.conj(big_q))[:, 1:]
    alpha = 2 * (quat.mul(ddq, quat.conj(big_q)) + quat.mul(dq, quat.conj(dq)))[:, 1:]
    return omega, alpha


def wrap(x):
    """Angles to [-pi, pi)."""
    return (x + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------- forward


def test_forward_matches_scipy_intrinsic_zyx(rng):
    angles = rng.uniform(-4, 4, size=(4, 50, 3))
    q = forward(angles)
    assert q.shape == (4, 50, 4)
    ref = Rotation.from_euler("ZYX", angles.reshape(-1, 3)).as_quat(scalar_first=True)
    dots = np.abs(np.sum(q.reshape(-1, 4) * ref, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)


def test_forward_points_the_camera_by_hand():
    x = np.array([1.0, 0.0, 0.0])
    a = 0.4
    # Pan turns the camera axis about z; positive tilt (about y) points it down;
    # roll turns about the camera axis itself.
    np.testing.assert_allclose(quat.rotate(forward([a, 0, 0]), x), [np.cos(a), np.sin(a), 0])
    np.testing.assert_allclose(quat.rotate(forward([0, a, 0]), x), [np.cos(a), 0, -np.sin(a)])
    np.testing.assert_allclose(quat.rotate(forward([0, 0, a]), x), x)
    np.testing.assert_allclose(
        quat.rotate(forward([0, 0, a]), [0, 1, 0]), [0, np.cos(a), np.sin(a)], atol=1e-15
    )


@pytest.mark.parametrize(
    "angles, error, message",
    [
        ([0.1, 0.2], ValueError, "Expected `angles` to have shape (..., 3), got (2,)."),
        (1.0, ValueError, "Expected `angles` to have shape (..., 3), got ()."),
        ([0.1, np.nan, 0.0], ValueError, "Expected `angles` to be finite, got nan."),
        ("abc", TypeError, "Expected `angles` to be numeric, got str."),
    ],
)
def test_forward_rejects_bad_angles(angles, error, message):
    with pytest.raises(error, match=re.escape(message)):
        forward(angles)


# ---------------------------------------------------------------- inverse


def test_inverse_round_trip(rng):
    angles = random_angles(rng, 2000)
    kin = GimbalKinematics(WIDE)
    back = kin.inverse(forward(angles))
    # Unrelated random samples get unwrapped against each other: equal mod 2 pi.
    np.testing.assert_allclose(wrap(back - angles), 0.0, atol=1e-12)
    np.testing.assert_allclose(back[:, 1], angles[:, 1], atol=1e-12)
    # Second opinion: scipy's intrinsic ZYX angles (tilt in [-pi/2, pi/2] too).
    ref = Rotation.from_quat(forward(angles), scalar_first=True).as_euler("ZYX")
    np.testing.assert_allclose(wrap(back - ref), 0.0, atol=1e-10)
    # One sample at a time, angles in (-pi, pi) come back as they went in.
    for a in angles[:20]:
        np.testing.assert_allclose(kin.inverse(forward(a)[None])[0], a, atol=1e-12)


def test_inverse_is_the_same_for_q_and_minus_q(rng):
    angles = random_angles(rng, 500)
    kin = GimbalKinematics(WIDE)
    q = forward(angles)
    signs = rng.choice([-1.0, 1.0], size=(len(q), 1))
    np.testing.assert_array_equal(kin.inverse(-q), kin.inverse(q))
    np.testing.assert_allclose(kin.inverse(signs * q), kin.inverse(q), atol=1e-15)


def test_inverse_near_lock_is_accurate():
    # Just inside a 1 deg margin, where arcsin would lose half the digits.
    angles = np.array([[0.3, math.radians(88.9), -0.2], [0.3, -math.radians(88.9), -0.2]])
    back = GimbalKinematics(lock_margin_rad=math.radians(1.0)).inverse(forward(angles))
    np.testing.assert_allclose(back, angles, atol=1e-12)


def test_inverse_unwraps_pan_and_roll_across_pi():
    t = np.linspace(0.0, 2.0, 201)
    deg = np.stack([179.0 + t, 10 * np.sin(t), -179.0 - 3 * t], axis=1)  # both cross +-180
    angles = np.radians(deg)
    q = forward(angles)
    back = GimbalKinematics(WIDE).inverse(q, t)
    np.testing.assert_allclose(back, angles, atol=1e-12)
    assert np.abs(np.diff(back, axis=0)).max() < math.radians(0.1)


def test_inverse_takes_the_branch_nearest_start():
    angles = np.radians([[-60.0, 20.0, 170.0], [-59.0, 21.0, 179.0], [-58.0, 22.0, 185.0]])
    kin = GimbalKinematics(WIDE)
    start = np.radians([300.0, 0.0, -190.0])  # pan one turn up, roll one turn down
    back = kin.inverse(forward(angles), start=start)
    expected = angles + np.radians([360.0, 0.0, -360.0])
    np.testing.assert_allclose(back, expected, atol=1e-12)
    # Half a turn away still picks the nearer branch.
    back = kin.inverse(forward(angles), start=np.radians([119.0, 0.0, 170.0]))
    np.testing.assert_allclose(back, angles, atol=1e-12)


def ramp(deg_per_s, offset_deg=(0.0, 0.0, 0.0), joint=1):
    """A path that moves one joint at a constant rate over 0..3 s at 100 Hz."""
    t = np.linspace(0.0, 3.0, 301)
    deg = np.tile(np.asarray(offset_deg, dtype=float), (len(t), 1))
    deg[:, joint] += deg_per_s * t
    return t, forward(np.radians(deg))


def test_inverse_refuses_gimbal_lock_with_time_and_margin():
    # tilt = 30 t deg passes 80 deg (90 - 10 deg margin) first at t = 2.67 s: 80.1 deg.
    t, q = ramp(30.0, offset_deg=(20.0, 0.0, -15.0))
    message = (
        "tilt reaches 80.1 deg at t = 2.670 s, within 10.0 deg of gimbal lock (limit 80.0 deg)"
    )
    with pytest.raises(KinematicsError, match=re.escape(message)):
        GimbalKinematics().inverse(q, t)
    # Without times the sample number stands in.
    with pytest.raises(KinematicsError, match=re.escape("80.1 deg at sample 267, within")):
        GimbalKinematics().inverse(q)
    # The first 2.66 s alone (79.8 deg) pass.
    GimbalKinematics().inverse(q[:267], t[:267])


def test_inverse_refuses_negative_lock_with_its_margin():
    # tilt = -30 t deg passes -85 deg (5 deg margin) first at t = 2.84 s: -85.2 deg.
    t, q = ramp(-30.0)
    message = (
        "tilt reaches -85.2 deg at t = 2.840 s, within 5.0 deg of gimbal lock (limit -85.0 deg)"
    )
    with pytest.raises(KinematicsError, match=re.escape(message)):
        GimbalKinematics(lock_margin_rad=math.radians(5.0)).inverse(q, t)


def test_kinematics_error_is_a_value_error():
    assert issubclass(KinematicsError, ValueError)


@pytest.mark.parametrize(
    "joint, rate, offset, limits_deg, start_deg, message",
    [
        # pan = 40 t deg passes 90 deg first at t = 2.26 s: 90.4 deg.
        (
            0,
            40.0,
            0.0,
            (-90, 90),
            None,
            "pan reaches 90.4 deg at t = 2.260 s, outside its limits [-90.0, 90.0] deg",
        ),
        # pan = 300 + 40 t deg (branch from start) passes the default 360 deg at t = 1.51 s.
        (
            0,
            40.0,
            300.0,
            None,
            (300, 0, 0),
            "pan reaches 360.4 deg at t = 1.510 s, outside its limits [-360.0, 360.0] deg",
        ),
        # tilt = -20 t deg passes -30 deg first at t = 1.51 s: -30.2 deg.
        (
            1,
            -20.0,
            0.0,
            (-30, 45),
            None,
            "tilt reaches -30.2 deg at t = 1.510 s, outside its limits [-30.0, 45.0] deg",
        ),
        # roll = 150 + 20 t deg, unwrapped, passes the default 180 deg at t = 1.51 s.
        (
            2,
            20.0,
            150.0,
            None,
            None,
            "roll reaches 180.2 deg at t = 1.510 s, outside its limits [-180.0, 180.0] deg",
        ),
    ],
)
def test_inverse_refuses_joint_limits(joint, rate, offset, limits_deg, start_deg, message):
    assert message.startswith(JOINT_NAMES[joint])
    offset_deg = np.zeros(3)
    offset_deg[joint] = offset
    t, q = ramp(rate, offset_deg, joint)
    limits = np.array(DEFAULT_LIMITS_RAD)
    if limits_deg is not None:
        limits[joint] = np.radians(limits_deg)
    start = None if start_deg is None else np.radians(start_deg)
    with pytest.raises(KinematicsError, match=re.escape(message)):
        GimbalKinematics(limits).inverse(q, t, start=start)


def test_lock_is_reported_before_a_limit_at_the_same_sample():
    t, q = ramp(30.0)
    limits = np.array(DEFAULT_LIMITS_RAD)
    limits[1] = np.radians([-70.0, 70.0])
    # tilt passes 70 deg (limit) at 2.34 s, before 80 deg (lock) at 2.67 s.
    with pytest.raises(KinematicsError, match=re.escape("tilt reaches 70.2 deg at t = 2.340 s")):
        GimbalKinematics(limits).inverse(q, t)
    with pytest.raises(KinematicsError, match="within 30.0 deg of gimbal lock"):
        GimbalKinematics(limits, lock_margin_rad=math.radians(30.0)).inverse(q, t)


@pytest.mark.parametrize(
    "quats, times, start, error, message",
    [
        (
            [1.0, 0, 0, 0],
            None,
            None,
            ValueError,
            "Expected `quats` to have shape (N, 4), got (4,).",
        ),
        (
            [[1.0, 0, 0, 0]] * 3,
            [0.0, 1.0],
            None,
            ValueError,
            "Expected `times` to have shape (3,) like `quats`, got (2,).",
        ),
        ([[1.0, 0, 0, 0]], ["a"], None, TypeError, "Expected `times` to be numeric, got list."),
        (
            [[1.0, 0, 0, 0]],
            None,
            [0.0, 0.0],
            ValueError,
            "Expected `start` to have shape (3,), got (2,).",
        ),
        (
            [[1.0, 0, 0, 0]],
            None,
            [0.0, np.inf, 0.0],
            ValueError,
            "Expected `start` to be finite, got inf.",
        ),
    ],
)
def test_inverse_rejects_bad_input(quats, times, start, error, message):
    with pytest.raises(error, match=re.escape(message)):
        GimbalKinematics().inverse(quats, times, start=start)


# ---------------------------------------------------------------- limits


def test_default_kinematics():
    kin = GimbalKinematics()
    assert kin.limits_rad == DEFAULT_LIMITS_RAD
    assert kin.lock_margin_rad == pytest.approx(math.radians(10.0))
    assert kin == GimbalKinematics(np.array(DEFAULT_LIMITS_RAD), math.radians(10.0))
    assert isinstance(kin.lock_margin_rad, float)


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        (
            {"limits_rad": [[0, 1], [0, 1]]},
            ValueError,
            "Expected `limits_rad` to have shape (3, 2), got (2, 2).",
        ),
        ({"limits_rad": "abc"}, TypeError, "Expected `limits_rad` to be numeric, got str."),
        (
            {"limits_rad": [[0, np.nan], [0, 1], [0, 1]]},
            ValueError,
            "Expected `limits_rad` to be finite, got [[0.0, nan]",
        ),
        (
            {"limits_rad": [[-1, 1], [0, 1], [2, 1]]},
            ValueError,
            "Expected `limits_rad` roll low < high, got [2, 1] rad.",
        ),
        (
            {"limits_rad": [[-1, 1], [-2, 1], [-1, 1]]},
            ValueError,
            "Expected `limits_rad` tilt within [-pi/2, pi/2], got [-2, 1] rad.",
        ),
        (
            {"lock_margin_rad": 0.0},
            ValueError,
            "Expected `lock_margin_rad` to be a finite number in (0, 1.5708), got 0.0.",
        ),
        (
            {"lock_margin_rad": 1.6},
            ValueError,
            "Expected `lock_margin_rad` to be a finite number in (0, 1.5708), got 1.6.",
        ),
        (
            {"lock_margin_rad": "0.1"},
            TypeError,
            "Expected `lock_margin_rad` to be a finite number in (0, 1.5708), got '0.1'.",
        ),
        (
            {"lock_margin_rad": True},
            TypeError,
            "Expected `lock_margin_rad` to be a finite number in (0, 1.5708), got True.",
        ),
    ],
)
def test_kinematics_rejects_bad_settings(kwargs, error, message):
    with pytest.raises(error, match=re.escape(message)):
        GimbalKinematics(**kwargs)


# ---------------------------------------------------------------- rates


def test_jacobian_columns_are_the_joint_axes(rng):
    angles = random_angles(rng, 200)
    jac = jacobian(angles)
    assert jac.shape == (200, 3, 3)
    np.testing.assert_allclose(np.linalg.det(jac), -np.cos(angles[:, 1]), atol=1e-12)
    # Each column is the angular velocity of a unit rate of its joint: check
    # against central differences of the forward kinematics.
    h = 1e-6
    q = forward(angles)
    for j in range(3):
        step = np.zeros(3)
        step[j] = h
        dq = (forward(angles + step) - forward(angles - step)) / (2 * h)
        omega = 2 * quat.mul(dq, quat.conj(q))[:, 1:]
        np.testing.assert_allclose(jac[:, :, j], omega, atol=1e-8)


def test_joint_rates_are_exact_on_a_known_path():
    t = np.linspace(0.0, 4.0, 2001)
    q, qd, qdd = joint_path(t)
    omega, alpha = angular_motion(q, qd, qdd)
    got_qd, got_qdd = joint_rates(q, omega, alpha)
    np.testing.assert_allclose(got_qd, qd, atol=1e-12)
    np.testing.assert_allclose(got_qdd, qdd, atol=1e-11)
    # And omega = J qd, the Jacobian's own statement.
    np.testing.assert_allclose(np.einsum("nij,nj->ni", jacobian(q), qd), omega, atol=1e-12)


def test_joint_rates_agree_with_finite_differences_of_inverse():
    t = np.linspace(0.0, 4.0, 41)
    h = 1e-3
    q, qd, qdd = joint_path(t)
    omega, alpha = angular_motion(q, qd, qdd)
    got_qd, got_qdd = joint_rates(q, omega, alpha)
    kin = GimbalKinematics()
    # IK of the orientations a step either side; pan crosses pi on the way.
    path = np.stack([joint_path(t + s)[0] for s in (-h, 0.0, h)], axis=1)  # (N, 3, 3)
    ik = kin.inverse(forward(path.reshape(-1, 3))).reshape(len(t), 3, 3)
    fd_qd = (ik[:, 2] - ik[:, 0]) / (2 * h)
    fd_qdd = (ik[:, 2] - 2 * ik[:, 1] + ik[:, 0]) / h**2
    np.testing.assert_allclose(got_qd, fd_qd, atol=1e-5)
    np.testing.assert_allclose(got_qdd, fd_qdd, atol=1e-4)


def test_joint_rates_of_a_pure_pan_and_a_pure_tilt_by_hand():
    # A rotation about the base z axis is pure pan, whatever tilt and roll are.
    angles = np.array([[0.3, 0.5, -0.4]])
    qd, qdd = joint_rates(angles, [[0.0, 0.0, 2.0]], [[0.0, 0.0, -1.0]])
    np.testing.assert_allclose(qd, [[2.0, 0.0, 0.0]], atol=1e-15)
    np.testing.assert_allclose(qdd, [[-1.0, 0.0, 0.0]], atol=1e-15)
    # With pan = 0 the tilt axis is y.
    angles = np.array([[0.0, 0.5, -0.4]])
    qd, qdd = joint_rates(angles, [[0.0, 1.5, 0.0]], [[0.0, 0.0, 0.0]])
    np.testing.assert_allclose(qd, [[0.0, 1.5, 0.0]], atol=1e-15)
    np.testing.assert_allclose(qdd, [[0.0, 0.0, 0.0]], atol=1e-15)


def test_joint_rates_reject_bad_input():
    ok = np.zeros((2, 3))
    message = (
        "Expected `angles`, `omega` and `alpha` to have the same shape, got (2, 3), (2, 3), (1, 3)."  # noqa: E501
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        joint_rates(ok, ok, ok[:1])
    with pytest.raises(ValueError, match=re.escape("Expected `omega` to have shape (..., 3)")):
        joint_rates(ok, np.zeros((2, 4)), ok)
    locked = np.array([[0.0, 0.0, 0.0], [0.1, -math.pi / 2, 0.2]])
    message = "joint rates are undefined at gimbal lock: |tilt| = 90 deg at index (1,)"
    with pytest.raises(KinematicsError, match=re.escape(message)):
        joint_rates(locked, ok, ok)
