"""Any axis sequence: forward and inverse kinematics, lock guard, unwrap, joint rates."""

import itertools
import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from trajgen import gimbal, quat
from trajgen.axes import AxisSequence
from trajgen.gimbal import GimbalKinematics, KinematicsError
from trajgen.smooth import SmoothSpline
from trajgen.stream import plan_joint_trajectory, stream_frames

SEQUENCES = [
    "".join(p)
    for n in (2, 3)
    for p in itertools.product("xyz", repeat=n)
    if all(a != b for a, b in zip(p, p[1:], strict=False))
]
THREE = [s for s in SEQUENCES if len(s) == 3]
TWO = [s for s in SEQUENCES if len(s) == 2]
MARGIN = 0.2  # rad kept from lock by the random angles


def test_there_are_eighteen_sequences():
    assert len(THREE) == 12 and len(TWO) == 6
    kinds = {s: AxisSequence(s).kind for s in SEQUENCES}
    assert sorted(s for s, k in kinds.items() if k == "proper-euler") == [
        "xyx",
        "xzx",
        "yxy",
        "yzy",
        "zxz",
        "zyz",
    ]


@pytest.fixture
def rng():
    return np.random.default_rng(20261201)


def random_angles(rng, seq: AxisSequence, n: int) -> np.ndarray:
    """Random angles (n, k): wrapped joints in (-pi, pi), the middle MARGIN from lock."""
    a = rng.uniform(-math.pi, math.pi, size=(n, seq.n))
    low, high = seq.middle_range
    a[:, 1] = rng.uniform(low + MARGIN, high - MARGIN, size=n)
    return a


def wrap(x):
    return (x + np.pi) % (2 * np.pi) - np.pi


def wide(seq: AxisSequence):
    """Limits that never bind."""
    lim = [(-1e3, 1e3)] * seq.n
    lim[1] = seq.middle_range
    return tuple(lim)


# ---------------------------------------------------------------- forward


@pytest.mark.parametrize("axes", THREE)
def test_forward_matches_scipy_intrinsic(rng, axes):
    seq = AxisSequence(axes)
    a = rng.uniform(-4, 4, size=(300, 3))
    ref = Rotation.from_euler(axes.upper(), a).as_quat(scalar_first=True)
    got = GimbalKinematics(axes=axes).forward(a)
    np.testing.assert_allclose(np.abs(np.sum(got * ref, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(seq.forward(a), got, atol=0)


R = math.radians


@pytest.mark.parametrize(
    "axes, angles_deg, body, space",
    [
        # Pan 90 deg turns the camera (x) onto y; tilt 90 deg points it down (-z).
        ("zy", (90, 0), (1, 0, 0), (0, 1, 0)),
        ("zy", (0, 90), (1, 0, 0), (0, 0, -1)),
        ("zy", (90, 45), (1, 0, 0), (0, math.sqrt(0.5), -math.sqrt(0.5))),
        # Flex-roll: flex about y carries the look axis z toward x; roll about the
        # flexed x carries it toward -y.
        ("yx", (90, 0), (0, 0, 1), (1, 0, 0)),
        ("yx", (0, 90), (0, 0, 1), (0, -1, 0)),
        # x-y-z: Rx(90) Ry(90) Rz(90) x = Rx(90) Ry(90) y = Rx(90) y = z.
        ("xyz", (90, 90, 90), (1, 0, 0), (0, 0, 1)),
        # z-x-z: Rz(90) Rx(90) z = Rz(90) (-y) = x, and the body x stays on y.
        ("zxz", (90, 90, 0), (0, 0, 1), (1, 0, 0)),
        ("zxz", (90, 90, 0), (1, 0, 0), (0, 1, 0)),
        # z-y-z: Rz(0) Ry(90) Rz(90) x = Ry(90) y = y.
        ("zyz", (0, 90, 90), (1, 0, 0), (0, 1, 0)),
    ],
)
def test_forward_by_hand(axes, angles_deg, body, space):
    q = GimbalKinematics(axes=axes).forward(np.radians(angles_deg))
    np.testing.assert_allclose(quat.rotate(q, np.array(body, float)), space, atol=1e-15)


@pytest.mark.parametrize(
    "axes, look", [("zy", "x"), ("yz", "x"), ("zx", "y"), ("xz", "y"), ("yx", "z"), ("xy", "z")]
)
def test_two_axis_look_axis_is_the_third(axes, look):
    seq = AxisSequence(axes)
    np.testing.assert_array_equal(seq.look, np.eye(3)["xyz".index(look)])
    np.testing.assert_array_equal(seq.look_direction(np.zeros(2)), seq.look)


# ---------------------------------------------------------------- inverse


@pytest.mark.parametrize("axes", SEQUENCES)
def test_round_trip_every_sequence(rng, axes):
    seq = AxisSequence(axes)
    kin = GimbalKinematics(wide(seq), axes=axes)
    a = random_angles(rng, seq, 2000)
    q = kin.forward(a)
    # Closed form per sample: angles as they went in, to 1e-12.
    np.testing.assert_allclose(kin.angles(q), a, atol=1e-12)
    # q and -q alike.
    np.testing.assert_allclose(kin.angles(-q), a, atol=1e-12)
    # Unwrapped against each other: equal modulo 2 pi, the middle angle exactly.
    back = kin.inverse(q)
    np.testing.assert_allclose(wrap(back - a), 0.0, atol=1e-12)
    np.testing.assert_allclose(back[:, 1], a[:, 1], atol=1e-12)
    # Orientation -> angles -> orientation, and for two axes the look direction.
    np.testing.assert_allclose(quat.distance(kin.forward(back), q), 0.0, atol=1e-7)
    np.testing.assert_allclose(kin.look_direction(back), kin.look_direction(a), atol=1e-12)


@pytest.mark.parametrize("axes", THREE)
def test_inverse_agrees_with_scipy(rng, axes):
    seq = AxisSequence(axes)
    a = random_angles(rng, seq, 500)
    q = seq.forward(a)
    ref = Rotation.from_quat(q, scalar_first=True).as_euler(axes.upper())
    np.testing.assert_allclose(
        wrap(GimbalKinematics(wide(seq), axes=axes).inverse(q) - ref), 0.0, atol=1e-10
    )


@pytest.mark.parametrize("axes", TWO)
def test_two_axis_inverse_of_any_orientation_points_exactly(rng, axes):
    # Orientations with a turn about the look axis the gimbal cannot make: the
    # angles point the look axis exactly where the orientation does.
    seq = AxisSequence(axes)
    q = quat.as_quats(rng.normal(size=(1000, 4)))
    d = quat.rotate(q, seq.look)
    keep = np.abs(d[:, seq.indices[0]]) < math.cos(MARGIN)  # away from lock
    a = GimbalKinematics(wide(seq), axes=axes).inverse(q[keep])
    np.testing.assert_allclose(seq.look_direction(a), d[keep], atol=1e-14)


@given(
    axes=st.sampled_from(SEQUENCES),
    values=st.lists(st.floats(-0.999, 0.999), min_size=3, max_size=3),
)
@settings(max_examples=300, deadline=None)
def test_round_trip_property(axes, values):
    seq = AxisSequence(axes)
    a = math.pi * np.array(values[: seq.n])
    low, high = seq.middle_range
    a[1] = low + MARGIN + (high - low - 2 * MARGIN) * (values[1] + 1) / 2
    back = GimbalKinematics(wide(seq), axes=axes).angles(seq.forward(a)[None])[0]
    np.testing.assert_allclose(back, a, atol=1e-12)


@given(axes=st.sampled_from(THREE), seed=st.integers(0, 2**32 - 1))
@settings(max_examples=100, deadline=None)
def test_inverse_then_forward_is_identity_property(axes, seed):
    # Any orientation away from lock comes back from its angles.
    rng = np.random.default_rng(seed)
    seq = AxisSequence(axes)
    q = quat.as_quats(rng.normal(size=(1, 4)))
    a = seq.angles(q)
    if seq.lock_distance(a)[0] < MARGIN:
        return
    assert quat.distance(seq.forward(a), q)[0] < 1e-7


# ---------------------------------------------------------------- unwrap


@pytest.mark.parametrize("axes", SEQUENCES)
def test_unwrap_is_continuous_across_pi(axes):
    seq = AxisSequence(axes)
    t = np.linspace(0.0, 2.0, 401)
    a = np.zeros((len(t), seq.n))
    mid = sum(seq.middle_range) / 2
    a[:, 0] = np.radians(170.0) + 1.2 * t  # first joint crosses +180 deg
    a[:, 1] = mid + 0.3 * np.sin(t)
    if seq.n == 3:
        a[:, 2] = -np.radians(170.0) - 1.5 * t  # last joint crosses -180 deg
    kin = GimbalKinematics(wide(seq), axes=axes)
    back = kin.inverse(kin.forward(a), t)
    np.testing.assert_allclose(back, a, atol=1e-12)
    assert np.abs(np.diff(back, axis=0)).max() < 0.01
    # A start one turn up puts the whole path a turn up.
    start = a[0].copy()
    start[0] += 2 * math.pi
    shifted = kin.inverse(kin.forward(a), t, start=start)
    np.testing.assert_allclose(shifted[:, 0], a[:, 0] + 2 * math.pi, atol=1e-12)


# ---------------------------------------------------------------- lock


def middle_ramp(axes, begin, rate):
    """A path moving the middle joint only, begin + rate t (rad), over 0..3 s at 100 Hz."""
    seq = AxisSequence(axes)
    t = np.linspace(0.0, 3.0, 301)
    a = np.full((len(t), seq.n), 0.3)
    a[:, 1] = begin + rate * t
    return t, seq.forward(a)


@pytest.mark.parametrize(
    "axes, begin_deg, rate_deg, message",
    [
        # Tait-Bryan: 30 t deg passes 80 deg (90 - 10) first at t = 2.67 s.
        (
            "xyz",
            0,
            30,
            "joint2 reaches 80.1 deg at t = 2.670 s, within 10.0 deg of gimbal lock "
            "(limit 80.0 deg)",
        ),
        (
            "zyx",
            0,
            -30,
            "tilt reaches -80.1 deg at t = 2.670 s, within 10.0 deg of gimbal lock "
            "(limit -80.0 deg)",
        ),
        # Two axes: looking along the first axis.
        (
            "zy",
            0,
            30,
            "tilt reaches 80.1 deg at t = 2.670 s, within 10.0 deg of gimbal lock (limit 80.0 deg)",
        ),
        (
            "yx",
            0,
            -30,
            "joint2 reaches -80.1 deg at t = 2.670 s, within 10.0 deg of gimbal "
            "lock (limit -80.0 deg)",
        ),
        # Proper Euler: lock at 0 and at 180 deg.
        (
            "zxz",
            90,
            -30,
            "joint2 reaches 9.9 deg at t = 2.670 s, within 10.0 deg of gimbal lock "
            "(limit 10.0 deg)",
        ),
        (
            "yzy",
            90,
            30,
            "joint2 reaches 170.1 deg at t = 2.670 s, within 10.0 deg of gimbal "
            "lock (limit 170.0 deg)",
        ),
    ],
)
def test_lock_is_refused_with_time_and_limit(axes, begin_deg, rate_deg, message):
    t, q = middle_ramp(axes, math.radians(begin_deg), math.radians(rate_deg))
    kin = GimbalKinematics(axes=axes)
    with pytest.raises(KinematicsError, match=re.escape(message)):
        kin.inverse(q, t)
    kin.inverse(q[:267], t[:267])  # up to 2.66 s passes


@pytest.mark.parametrize("axes", ["xyz", "zy", "zxz"])
def test_joint_rates_refuse_exact_lock(axes):
    seq = AxisSequence(axes)
    a = np.full((2, seq.n), 0.2)
    a[1, 1] = seq.locks[1]
    lock = "0 or 180" if seq.kind == "proper-euler" else "90"
    message = f"joint rates are undefined at gimbal lock: |joint2| = {lock} deg at index (1,)"
    if axes == "zy":
        message = message.replace("joint2", "tilt")
    with pytest.raises(KinematicsError, match=re.escape(message)):
        GimbalKinematics(axes=axes).joint_rates(a, np.zeros((2, 3)), np.zeros((2, 3)))


# ---------------------------------------------------------------- rates


def joint_path(t, n):
    """Angles, velocities, accelerations (N, n): c0 + A sin(w t + phi) per joint."""
    c0 = np.array([2.0, 0.3, -0.5])[:n]
    amp = np.array([1.5, 0.5, 0.7])[:n]
    w = np.array([0.8, 1.1, 1.7])[:n]
    phi = np.array([0.0, 0.3, 1.0])[:n]
    arg = np.multiply.outer(t, w) + phi
    return c0 + amp * np.sin(arg), amp * w * np.cos(arg), -amp * w * w * np.sin(arg)


def angular_motion(axes, q, qd, qdd):
    """Space-frame omega, alpha (N, 3) of the product of axis rotations by the product
    rule on its quaternion factors (independent of the Jacobian)."""
    factors = []
    for j, c in enumerate(axes):
        e = np.eye(3)["xyz".index(c)]
        half = q[:, j] / 2
        f = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * e], axis=1)
        du = np.concatenate([-np.sin(half)[:, None], np.cos(half)[:, None] * e], axis=1)
        factors.append(
            (f, qd[:, j, None] / 2 * du, qdd[:, j, None] / 2 * du - qd[:, j, None] ** 2 / 4 * f)
        )

    def product(orders):
        """Product of the factors, each differentiated ``orders[j]`` times."""
        out = factors[0][orders[0]]
        for derivatives, k in zip(factors[1:], orders[1:], strict=True):
            out = quat.mul(out, derivatives[k])
        return out

    n = len(axes)
    unit = [tuple(int(i == j) for i in range(n)) for j in range(n)]
    big = product((0,) * n)
    dq = sum(product(u) for u in unit)
    ddq = sum(product(tuple(2 * x for x in u)) for u in unit)
    ddq = ddq + 2 * sum(
        product(tuple(int(i in (a, b)) for i in range(n)))
        for a, b in itertools.combinations(range(n), 2)
    )
    omega = 2 * quat.mul(dq, quat.conj(big))[:, 1:]
    alpha = 2 * (quat.mul(ddq, quat.conj(big)) + quat.mul(dq, quat.conj(dq)))[:, 1:]
    return omega, alpha


@pytest.mark.parametrize("axes", SEQUENCES)
def test_joint_rates_are_exact_on_a_known_path(axes):
    seq = AxisSequence(axes)
    t = np.linspace(0.0, 4.0, 801)
    q, qd, qdd = joint_path(t, seq.n)
    if seq.kind == "proper-euler":
        q[:, 1] += 1.3  # keep the middle angle in (0, pi), away from lock
    omega, alpha = angular_motion(axes, q, qd, qdd)
    kin = GimbalKinematics(wide(seq), axes=axes)
    got_qd, got_qdd = kin.joint_rates(q, omega, alpha)
    np.testing.assert_allclose(got_qd, qd, atol=1e-12)
    np.testing.assert_allclose(got_qdd, qdd, atol=1e-11)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", kin.jacobian(q), qd), omega, atol=1e-12)


@pytest.mark.parametrize("axes", TWO)
def test_two_axis_rates_follow_the_look_direction_of_any_path(rng, axes):
    # A path with roll the gimbal cannot make: a zyx gimbal's. The two-axis joint
    # rates must be the derivatives of the two-axis inverse kinematics of its look
    # direction (central differences), and ignore any spin about that direction.
    seq = AxisSequence(axes)
    t = np.linspace(0.0, 4.0, 41)
    h = 1e-4
    scale = np.array([1.0, 0.5, 1.0])
    q3, qd3, qdd3 = (x * scale for x in joint_path(t, 3))
    omega, alpha = angular_motion("zyx", q3, qd3, qdd3)
    orient = gimbal.forward(q3)
    kin = GimbalKinematics(wide(seq), axes=axes)
    d = quat.rotate(orient, seq.look)
    assert seq.lock_distance(seq.angles(orient)).min() > MARGIN
    a = kin.inverse(orient)
    qd, qdd = kin.joint_rates(a, omega, alpha)
    side = [kin.inverse(gimbal.forward(joint_path(t + s, 3)[0] * scale)) for s in (-h, h)]
    np.testing.assert_allclose(qd, (side[1] - side[0]) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(qdd, (side[1] - 2 * a + side[0]) / h**2, atol=1e-3)
    # Spin about d at rate s(t) = 0.7 + 0.2 t changes omega by s d and alpha by
    # s' d + s (omega x d): the look direction moves the same, so do the joints.
    s = (0.7 + 0.2 * t)[:, None]
    spun = kin.joint_rates(a, omega + s * d, alpha + 0.2 * d + s * np.cross(omega, d))
    np.testing.assert_allclose(spun[0], qd, atol=1e-12)
    np.testing.assert_allclose(spun[1], qdd, atol=1e-11)


# ---------------------------------------------------------------- the default


def test_default_is_todays_pan_tilt_roll_bit_for_bit(rng):
    a = rng.uniform(-3, 3, size=(500, 3))
    a[:, 1] *= 0.4
    kin = GimbalKinematics()
    assert kin == GimbalKinematics(axes="zyx", joints=("pan", "tilt", "roll"))
    assert kin.joints == gimbal.JOINT_NAMES and kin.limits_rad == gimbal.DEFAULT_LIMITS_RAD
    q = gimbal.forward(a)
    np.testing.assert_array_equal(kin.forward(a), q)
    np.testing.assert_array_equal(kin.jacobian(a), gimbal.jacobian(a))
    omega, alpha = rng.normal(size=(2, 500, 3))
    for got, want in zip(
        kin.joint_rates(a, omega, alpha), gimbal.joint_rates(a, omega, alpha), strict=True
    ):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(kin.angles(q), gimbal._closed_form(quat.as_quats(q)))
    # The general formulas of trajgen.axes agree with today's closed forms.
    seq = AxisSequence("zyx")
    np.testing.assert_allclose(np.abs(np.sum(seq.forward(a) * q, axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(seq.angles(quat.as_quats(q)), kin.angles(q), atol=1e-12)
    np.testing.assert_allclose(seq.joint_axes(a), gimbal.jacobian(a), atol=1e-12)
    for got, want in zip(
        seq.joint_rates(a, omega, alpha), kin.joint_rates(a, omega, alpha), strict=True
    ):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


# ---------------------------------------------------------------- stream


@pytest.mark.parametrize("axes", ["zy", "yx", "xyz", "zxz"])
def test_stream_frames_equal_the_planned_arrays(rng, axes):
    seq = AxisSequence(axes)
    a = random_angles(rng, seq, 6) * 0.6
    if seq.kind == "proper-euler":
        a[:, 1] = rng.uniform(1.0, 2.0, size=6)
    kin = GimbalKinematics(wide(seq), axes=axes)
    spline = SmoothSpline(kin.forward(a), np.arange(6.0) * 1.5)
    plan = plan_joint_trajectory(spline, 100.0, kin, start=a[0])
    assert plan.q.shape == (len(plan.t), seq.n)
    frames = list(stream_frames(spline, 100.0, kin, start=a[0]))
    assert len(frames) == len(plan)
    for name in ("q", "qd", "qdd"):
        got = np.array([getattr(f, name) for f in frames])
        np.testing.assert_allclose(got, getattr(plan, name), atol=1e-12)
    # At the keyframes the joints are the keyframe angles (orientations exact on
    # the spline), so the look direction is exact.
    at = plan.t.searchsorted(spline.times)
    np.testing.assert_allclose(plan.q[at], a, atol=1e-9)


# ---------------------------------------------------------------- refusals


@pytest.mark.parametrize(
    "kwargs, error, message",
    [
        ({"axes": "zyxz"}, ValueError, "Expected `axes` to be 2 or 3 letters from x, y, z"),
        ({"axes": "z"}, ValueError, "Expected `axes` to be 2 or 3 letters from x, y, z"),
        ({"axes": "zaq"}, ValueError, "(e.g. 'zyx', 'zy'), got 'zaq'."),
        (
            {"axes": "zzy"},
            ValueError,
            "Expected `axes` 'zzy' to turn about different axes in neighbouring joints, got zz.",
        ),
        ({"axes": 3}, TypeError, "Expected `axes` to be a string like 'zyx', got int."),
        (
            {"axes": "zy", "joints": ["pan"]},
            ValueError,
            "Expected `joints` to name the 2 axes of 'zy', got 1: ['pan'].",
        ),
        (
            {"axes": "zy", "joints": ["pan", "pan"]},
            ValueError,
            "Expected `joints` to be distinct non-empty names, got ['pan', 'pan'].",
        ),
        ({"axes": "zy", "joints": "pt"}, TypeError, "Expected `joints` to be a list of names"),
        (
            {"axes": "zy", "limits_rad": [[0, 1]] * 3},
            ValueError,
            "Expected `limits_rad` to have shape (2, 2), got (3, 2).",
        ),
        (
            {"axes": "zxz", "limits_rad": [[-1, 1], [-0.1, 1], [-1, 1]]},
            ValueError,
            "Expected `limits_rad` joint2 within [0, pi], got [-0.1, 1] rad.",
        ),
    ],
)
def test_bad_axes_and_joints_are_refused(kwargs, error, message):
    with pytest.raises(error, match=re.escape(message)):
        GimbalKinematics(**kwargs)


def test_joint_names_are_used_in_messages():
    kin = GimbalKinematics(axes="YX", joints=["wrist_flex", "wrist_roll"])
    assert kin.axes == "yx" and kin.joints == ("wrist_flex", "wrist_roll")
    assert kin.limits_rad == ((-2 * math.pi, 2 * math.pi), (-math.pi / 2, math.pi / 2))
    t, q = middle_ramp("yx", 0.0, math.radians(30.0))
    with pytest.raises(
        KinematicsError, match=re.escape("wrist_roll reaches 80.1 deg at t = 2.670 s")
    ):
        kin.inverse(q, t)


def knot_jerk_gaps(spline, kin, h=1e-4):
    """Per interior knot, the largest difference (rad/s^3) between the joint jerk just
    before and just after it: one-sided second-order differences of the exact joint
    accelerations on either side."""
    gaps = []
    for tk in spline.times[1:-1]:
        t = tk + h * np.arange(-2.0, 3.0)
        s = spline.evaluate(t, max_order=2)
        qdd = kin.joint_rates(kin.inverse(s.q), s.omega, s.alpha)[1]
        left = (3 * qdd[2] - 4 * qdd[1] + qdd[0]) / (2 * h)
        right = (-3 * qdd[2] + 4 * qdd[3] - qdd[4]) / (2 * h)
        gaps.append(np.abs(right - left).max())
    return np.array(gaps)


@pytest.mark.parametrize("axes", ["zy", "yx"])
def test_two_axis_joint_jerk_is_continuous_at_every_knot(rng, axes):
    # Keyframes as joint angles of a two-axis gimbal; the smooth spline through
    # their orientations gives a C3 joint stream (the blending spline, C2 with a
    # jerk gap at its knots, is the control the measure must catch).
    from trajgen.spline import BlendingSpline

    seq = AxisSequence(axes)
    a = rng.uniform([-1.5, -1.0], [1.5, 1.0], size=(7, 2))
    kin = GimbalKinematics(axes=axes)
    quats, times = kin.forward(a), np.arange(7.0)
    smooth = knot_jerk_gaps(SmoothSpline(quats, times), kin)
    blending = knot_jerk_gaps(BlendingSpline(quats, times), kin)
    assert smooth.max() < 1e-4, smooth
    assert blending.max() > 1e-2, blending
    # The look direction passes exactly through every keyframe's.
    spline = SmoothSpline(quats, times)
    d = quat.rotate(spline.evaluate(times).q, seq.look)
    e = kin.look_direction(a)
    err = np.arctan2(np.linalg.norm(np.cross(d, e), axis=1), np.sum(d * e, axis=1))
    assert err.max() < 1e-9


# ---------------------------------------------------------------- keyframe files

HEAD = """\
[gimbal]
axes = "zy"
joints = ["yaw", "pitch"]

[[keyframes]]
t = 0.0
yaw = 0.0

[[keyframes]]
t = 1.0
yaw = 50.0
pitch = 20.0

[[keyframes]]
t = 2.5
look = [1.0, -2.0, 0.5]

[[keyframes]]
t = 4.0
yaw = -190.0
pitch = -35.0

[[keyframes]]
t = 5.0
yaw = -160.0
pitch = 0.0
"""


def keyframe_looks():
    """The look directions (5, 3) the HEAD file asks for, worked out by hand."""

    def pointing(yaw, pitch):
        y, p = math.radians(yaw), math.radians(pitch)
        return [math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), -math.sin(p)]

    look = np.array([1.0, -2.0, 0.5]) / math.sqrt(5.25)
    return np.array([pointing(0, 0), pointing(50, 20), look, pointing(170, -35), pointing(200, 0)])


def test_a_two_axis_file_gives_the_gimbals_orientations(tmp_path):
    from trajgen.keyframes import load_keyframe_file

    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    kf = load_keyframe_file(f)
    assert kf.axes == AxisSequence("zy", ("yaw", "pitch"))
    np.testing.assert_allclose(quat.rotate(kf.quats, kf.axes.look), keyframe_looks(), atol=1e-15)
    # Angle keyframes are the gimbal's own orientation, roll and all.
    np.testing.assert_allclose(kf.quats[1], kf.axes.forward(np.radians([50.0, 20.0])), atol=0)


def test_plan_of_a_two_axis_file_points_exactly_at_every_keyframe(tmp_path, capsys):
    from trajgen.cli import main

    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    out = tmp_path / "head.csv"
    assert main(["plan", str(f), "--rate", "100", "--out", str(out)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    assert header[11:] == [
        "look_x",
        "look_y",
        "look_z",
        "yaw_rad",
        "pitch_rad",
        "yaw_rad_s",
        "pitch_rad_s",
        "yaw_rad_s2",
        "pitch_rad_s2",
    ]
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    at = np.searchsorted(rows[:, 0], [0.0, 1.0, 2.5, 4.0, 5.0])
    want = keyframe_looks()
    for got in (rows[at, 11:14], AxisSequence("zy").look_direction(rows[at, 14:16])):
        err = np.arctan2(np.linalg.norm(np.cross(got, want), axis=1), np.sum(got * want, axis=1))
        assert err.max() < 1e-9
    # The yaw is unwrapped: from the look keyframe (yaw -63.4 deg) the shorter way
    # round is through -180 deg, to -190 deg as written, then -160 deg: never a jump.
    np.testing.assert_allclose(np.degrees(rows[at[-2:], 14]), [-190.0, -160.0], atol=1e-9)
    assert np.abs(np.diff(rows[:, 14])).max() < 0.05


def test_joint_jerk_of_a_two_axis_file_is_continuous_at_every_knot(tmp_path):
    from trajgen.keyframes import load_keyframe_file

    f = tmp_path / "head.toml"
    f.write_text(HEAD)
    kf = load_keyframe_file(f)
    kin = GimbalKinematics(axes=kf.axes.sequence, joints=kf.axes.joints)
    assert knot_jerk_gaps(kf.spline(), kin).max() < 1e-4


@pytest.mark.parametrize(
    "gimbal, keyframe, message",
    [
        (
            'axes = "zy"',
            "pitch = 3.0",
            "keyframe 1: unknown field 'pitch' (known: t, pan, tilt, look)",
        ),
        (
            'axes = "zy"\njoints = ["yaw", "pitch"]',
            "pan = 3.0",
            "keyframe 1: unknown field 'pan' (known: t, yaw, pitch, look)",
        ),
        (
            'axes = "zy"',
            "roll = 3.0",
            "keyframe 1: unknown field 'roll' (known: t, pan, tilt, look)",
        ),
        (
            'axes = "zy"',
            "quat = [1.0, 0.0, 0.0, 0.0]",
            "keyframe 1: field 'quat': a 2-axis gimbal (zy) cannot hold every orientation; give "
            "'look' = [x, y, z] or pan/tilt (degrees)",
        ),
        (
            'axes = "zy"',
            "look = [0.0, 0.0, 0.0]",
            "keyframe 1: field 'look': expected a non-zero direction, got [0.0, 0.0, 0.0]",
        ),
        ('axes = "zy"', "look = [1.0, 0.0]", "keyframe 1: field 'look': expected [x, y, z]"),
        (
            'axes = "zy"',
            "pan = 1.0\nlook = [1.0, 0.0, 0.0]",
            "keyframe 1: give either 'look' or pan/tilt, not both",
        ),
        ('axes = "zy"', "pan = 'a'", "keyframe 1: field 'pan': "),
        (
            'axes = "xyz"',
            "look = [1.0, 0.0, 0.0]",
            "keyframe 1: unknown field 'look' (known: t, joint1, joint2, joint3, quat)",
        ),
        ('axes = "zq"', "pan = 1.0", "[gimbal] axes: Expected `axes` to be 2 or 3 letters"),
        (
            'axes = "zy"\njoints = ["a"]',
            "a = 1.0",
            "[gimbal] joints: Expected `joints` to name the 2 axes of 'zy', got 1: ['a'].",
        ),
        (
            'axes = "zy"\njoints = "a"',
            "a = 1.0",
            "[gimbal] joints: expected a list of names, got 'a'",
        ),
    ],
)
def test_bad_two_axis_keyframes_are_refused_naming_the_key(tmp_path, gimbal, keyframe, message):
    from trajgen.errors import KeyframeFileError
    from trajgen.keyframes import load_keyframe_file

    f = tmp_path / "bad.toml"
    f.write_text(
        f"[gimbal]\n{gimbal}\n\n[[keyframes]]\nt = 0.0\n{keyframe}\n\n[[keyframes]]\nt = 1.0\n"
    )
    with pytest.raises(KeyframeFileError, match=re.escape(f"{f}: {message}")):
        load_keyframe_file(f)


@pytest.mark.parametrize(
    ("yaws", "message"),
    [
        (
            (170.0, -160.0),
            "keyframe 4: field 'yaw': 170 deg: the path reaches this orientation with yaw at "
            "-190 deg; write that, or add keyframes on the way (less than half a turn per "
            "joint between two)",
        ),
        (
            (-190.0, 200.0),
            "keyframe 5: field 'yaw': 200 deg: 390 deg from keyframe 4's -190: the path turns "
            "the shorter way between two keyframes",
        ),
    ],
)
def test_a_two_axis_files_angles_are_reached_as_written_or_refused(tmp_path, yaws, message):
    """The rule of pan-tilt-roll files, for every gimbal: a joint angle the path would
    reach a turn away from the one written (the path turns the shorter way) is refused."""
    from trajgen.errors import KeyframeFileError
    from trajgen.keyframes import load_keyframe_file

    f = tmp_path / "head.toml"
    f.write_text(HEAD.replace("yaw = -190.0", f"yaw = {yaws[0]}").replace(
        "yaw = -160.0", f"yaw = {yaws[1]}"
    ))  # fmt: skip
    with pytest.raises(KeyframeFileError, match="^" + re.escape(f"{f}: {message}")):
        load_keyframe_file(f)


def test_an_explicit_default_gimbal_is_todays(tmp_path):
    from trajgen.keyframes import load_keyframe_file

    plain = (
        "[[keyframes]]\nt = 0.0\npan = 10.0\n\n[[keyframes]]\nt = 1.0\ntilt = 20.0\nroll = 5.0\n"
    )
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text(plain)
    b.write_text('[gimbal]\naxes = "ZYX"\njoints = ["pan", "tilt", "roll"]\n\n' + plain)
    ka, kb = load_keyframe_file(a), load_keyframe_file(b)
    np.testing.assert_array_equal(ka.quats, kb.quats)
    assert ka.axes == kb.axes == AxisSequence()


def test_the_pan_tilt_head_example_plans(tmp_path):
    from pathlib import Path

    from trajgen.cli import main

    example = Path(__file__).parents[1] / "examples" / "pan_tilt_head.toml"
    out = tmp_path / "head.csv"
    assert main(["plan", str(example), "--out", str(out)]) == 0
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert rows.shape[1] == 11 + 3 + 6
