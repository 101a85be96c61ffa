"""SmoothSpline against docs/algorithm.md §8: exactness, C3, rest ends, the knot solve."""

import numpy as np
import pytest
from conftest import random_walk_keyframes
from hypothesis import given, settings
from hypothesis import strategies as st

from trajgen import quat as Q
from trajgen.smooth import END_SAMPLES, SmoothSpline, minimax_offset
from trajgen.smooth_blocks import knot_system, solve_block_cyclic, solve_block_tridiagonal


def ptr(*rows_deg):
    """Quaternions from (pan, tilt, roll) rows in degrees."""
    a = np.radians(np.array(rows_deg, dtype=float))
    return Q.from_pan_tilt_roll(a[:, 0], a[:, 1], a[:, 2])


def random_keys(rng, n=7):
    q = Q.as_quats(rng.normal(size=(n, 4)))
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.3, 2.5, n - 1))])
    return q, t


def one_sided(s, order):
    """Derivative ``order`` at each interior knot from the segment before and after."""
    knots = s.times[1:-1]
    seg = np.arange(len(knots))
    before = s._space_rates(knots, seg, order)
    after = s._space_rates(knots, seg + 1, order)
    if order == 0:
        return before[0], after[0]
    return before[1][order - 1], after[1][order - 1]


# --- an independent reference: the flat C4 quintic spline, fitted numerically ----------


def quintic(h, p0, v0, a0, p1, v1, a1):
    """Power coefficients (6,) of the quintic with the given end data on [0, h]."""
    rows = []
    for x in (0.0, h):
        rows.append([x**k for k in range(6)])
        rows.append([k * x ** (k - 1) if k >= 1 else 0.0 for k in range(6)])
        rows.append([k * (k - 1) * x ** (k - 2) if k >= 2 else 0.0 for k in range(6)])
    return np.linalg.solve(np.array(rows), [p0, v0, a0, p1, v1, a1])


def dense_knot_rates(D, h):
    """Interior (v, a) of the flat C4 quintic spline with rest ends, by a dense solve.

    The residual (jerk and snap jumps at the interior knots) is affine in the
    unknowns: its matrix is found column by column from numerically fitted quintics.
    """
    n = len(D) + 1

    def residual(z):
        v = np.concatenate([[0.0], z[0::2], [0.0]])
        a = np.concatenate([[0.0], z[1::2], [0.0]])
        c = [quintic(h[i], 0.0, v[i], a[i], D[i], v[i + 1], a[i + 1]) for i in range(n - 1)]
        out = []
        for i in range(1, n - 1):
            cl, cr, hl = c[i - 1], c[i], h[i - 1]
            jerk_l = 6 * cl[3] + 24 * cl[4] * hl + 60 * cl[5] * hl**2
            snap_l = 24 * cl[4] + 120 * cl[5] * hl
            out += [jerk_l - 6 * cr[3], snap_l - 24 * cr[4]]
        return np.array(out)

    m = 2 * (n - 2)
    r0 = residual(np.zeros(m))
    A = np.column_stack([residual(e) - r0 for e in np.eye(m)])
    z = np.linalg.solve(A, -r0)
    return z[0::2], z[1::2]


def test_knot_solve_matches_dense_reference_on_uneven_times(rng):
    n = 9
    D = rng.normal(scale=0.5, size=(n - 1, 3))
    h = rng.uniform(0.1, 3.0, n - 1)
    x = solve_block_tridiagonal(*knot_system(D, h))
    for axis in range(3):
        v, a = dense_knot_rates(D[:, axis], h)
        np.testing.assert_allclose(x[:, 0, axis], v, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(x[:, 1, axis], a, rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("n", [3, 4, 5, 6, 9, 12, 35, 102])
def test_block_solve_matches_numpy_solve_on_the_assembled_matrix(n, rng):
    """Block cyclic reduction on knot systems of odd and even sizes (1 to 100 knots)."""
    diag, upper, rhs = knot_system(rng.normal(size=(n - 1, 3)), rng.uniform(0.2, 2.0, n - 1))
    m = len(diag)
    A = np.zeros((2 * m, 2 * m))
    for k in range(m):
        A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = diag[k]
        if k < m - 1:
            A[2 * k : 2 * k + 2, 2 * k + 2 : 2 * k + 4] = upper[k]
            A[2 * k + 2 : 2 * k + 4, 2 * k : 2 * k + 2] = upper[k].T
    assert np.linalg.eigvalsh(A).min() > 0  # symmetric positive definite
    expected = np.linalg.solve(A, rhs.reshape(2 * m, 3)).reshape(m, 2, 3)
    np.testing.assert_allclose(solve_block_tridiagonal(diag, upper, rhs), expected, rtol=1e-10)


def test_cyclic_solve_matches_numpy_solve_on_the_assembled_matrix(rng):
    for n in (3, 4, 9):  # n = 3: the loop's two knots couple twice
        diag, upper, rhs = knot_system(
            rng.normal(size=(n - 1, 3)), rng.uniform(0.2, 2.0, n - 1), "closed"
        )
        m = len(diag)
        A = np.zeros((2 * m, 2 * m))
        for k in range(m):
            A[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] += diag[k]
            nxt = (k + 1) % m
            A[2 * k : 2 * k + 2, 2 * nxt : 2 * nxt + 2] += upper[k]
            A[2 * nxt : 2 * nxt + 2, 2 * k : 2 * k + 2] += upper[k].T
        assert np.linalg.eigvalsh(A).min() > 0
        expected = np.linalg.solve(A, rhs.reshape(2 * m, 3)).reshape(m, 2, 3)
        np.testing.assert_allclose(solve_block_cyclic(diag, upper, rhs), expected, rtol=1e-9)


def closed_keys(rng, n=6):
    q, t = random_keys(rng, n)
    q[-1] = -q[0]  # the same orientation, the other sign
    return q, t


def test_closed_loop_is_c3_round_the_seam_and_wraps(rng):
    q, t = closed_keys(rng)
    s = SmoothSpline(q, t, boundary="closed")
    assert Q.distance(s(t), q).max() < 1e-13
    end = s._space_rates(t[-1:], np.array([len(t) - 2]), 3)
    start = s._space_rates(t[:1], np.array([0]), 3)
    assert Q.distance(end[0], start[0]).max() < 1e-13
    for a, b in zip(end[1], start[1], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-11 * (1 + np.abs(a).max()))
    period = t[-1] - t[0]
    tt = np.linspace(t[0], t[-1], 50)
    assert Q.distance(s(tt + 2 * period), s(tt)).max() < 1e-12
    np.testing.assert_allclose(s(tt - period, 3), s(tt, 3), atol=1e-9)


def test_single_axis_is_the_flat_quintic_spline(rng):
    """All keyframes about one axis: the rotation angle is twice the flat quintic spline."""
    n = 7
    angles = np.concatenate([[0.0], np.cumsum(rng.uniform(-1.2, 1.2, n - 1))])
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.3, 2.5, n - 1))])
    s = SmoothSpline(Q.from_axis_angle(axis, angles), t, knots="quintic")
    D, h = np.diff(angles) / 2, np.diff(t)
    v, a = dense_knot_rates(D, h)
    v, a = np.concatenate([[0], v, [0]]), np.concatenate([[0], a, [0]])
    tt = np.linspace(t[0], t[-1], 2001)
    seg = np.clip(np.searchsorted(t, tt, side="right") - 1, 0, n - 2)
    p, dp = np.empty_like(tt), np.empty_like(tt)
    P = np.polynomial.polynomial
    for i in range(n - 1):
        c = quintic(h[i], 0.0, v[i], a[i], D[i], v[i + 1], a[i + 1])
        x = tt[seg == i] - t[i]
        p[seg == i] = angles[i] / 2 + P.polyval(x, c)
        dp[seg == i] = P.polyval(x, P.polyder(c))
    assert Q.distance(s(tt), Q.from_axis_angle(axis, 2 * p)).max() < 1e-11
    np.testing.assert_allclose(s(tt, 1), 2 * dp[:, None] * axis, atol=1e-10)


def test_exact_at_keyframes_unit_norm_and_rest_ends(rng):
    q, t = random_keys(rng)
    s = SmoothSpline(q, t)
    assert Q.distance(s(t), q).max() < 1e-13
    S = s.evaluate(np.linspace(t[0], t[-1], 5001), max_order=3)
    np.testing.assert_allclose(np.linalg.norm(S.q, axis=1), 1.0, atol=1e-15)
    for x in (S.omega, S.alpha):
        assert np.abs(x[[0, -1]]).max() < 1e-12 * (1 + np.abs(x).max())
    assert np.abs(S.jerk[[0, -1]]).max() > 1e-3  # rest means v = a = 0, not jerk


@pytest.mark.parametrize("boundary", ["rest", "natural", "closed"])
def test_c3_at_every_knot(rng, boundary):
    q, t = closed_keys(rng, 8) if boundary == "closed" else random_keys(rng, 8)
    s = SmoothSpline(q, t, boundary=boundary)
    for order in range(4):
        before, after = one_sided(s, order)
        scale = 1 + np.abs(before).max()
        assert np.abs(before - after).max() < 1e-11 * scale, order
        assert np.abs(before).max() > 0


def test_natural_ends_have_zero_flat_jerk(rng):
    q, t = random_keys(rng)
    s = SmoothSpline(q, t, boundary="natural")
    v, _, j = s.knot_rates
    assert np.abs(j[[0, -1]]).max() < 1e-10 * np.abs(j).max()
    assert np.abs(v[[0, -1]]).min() > 1e-3  # it starts moving
    assert Q.distance(s(t), q).max() < 1e-13


def test_derivatives_match_finite_differences(rng):
    q, t = random_keys(rng)
    s = SmoothSpline(q, t)
    tt = np.linspace(t[0] + 1e-3, t[-1] - 1e-3, 301)
    e = 1e-6
    dq = (s(tt + e) - s(tt - e)) / (2 * e)
    omega_fd = 2 * Q.mul(dq, Q.conj(s(tt)))[:, 1:]
    for frame in ("space", "body"):
        if frame == "body":
            omega_fd = Q.rotate(Q.conj(s(tt)), omega_fd)
        np.testing.assert_allclose(s(tt, 1, frame=frame), omega_fd, atol=1e-8)
        for order in (2, 3):
            fd = (s(tt + e, order - 1, frame=frame) - s(tt - e, order - 1, frame=frame)) / (2 * e)
            scale = np.abs(fd).max()
            np.testing.assert_allclose(s(tt, order, frame=frame), fd, atol=1e-7 * scale)


def test_sign_of_keyframes_does_not_matter(rng):
    q, t = random_keys(rng)
    flipped = q * np.where(rng.uniform(size=len(q)) < 0.5, -1.0, 1.0)[:, None]
    a, b = SmoothSpline(q, t), SmoothSpline(flipped, t)
    tt = np.linspace(t[0], t[-1], 777)
    assert Q.distance(a(tt), b(tt)).max() < 1e-14
    for order in (1, 2, 3):
        np.testing.assert_allclose(a(tt, order), b(tt, order), atol=1e-12)


def path_ratio(s, q):
    tt = np.linspace(s.t_start, s.t_end, 20001)
    speed = np.linalg.norm(s(tt, 1), axis=1)
    return np.trapezoid(speed, tt) / Q.distance(q[:-1], q[1:]).sum()


def test_reversals_and_half_turns_do_not_loop():
    sweep = ptr([0, 0, 0], [30, 0, 0], [0, 0, 0], [30, 0, 0], [0, 0, 0])
    s = SmoothSpline(sweep, [0, 1, 2, 3, 4.0])
    assert path_ratio(s, sweep) < 1.3
    # pan stays within the keyframes' range give or take a little overshoot
    pan = 2 * np.arctan2(s(np.linspace(0, 4, 401))[:, 3], s(np.linspace(0, 4, 401))[:, 0])
    assert np.degrees(pan).min() > -5 and np.degrees(pan).max() < 35
    half = ptr([0, 0, 0], [180, 0, 0], [360, 0, 0], [180, 0, 0])
    s = SmoothSpline(half, [0, 1, 2, 3.0])
    assert Q.distance(s([0, 1, 2, 3.0]), half).max() < 1e-12
    assert path_ratio(s, half) < 1.3
    assert np.isfinite(s.evaluate(np.linspace(0, 3, 301), max_order=3).jerk).all()


def test_two_keyframes_and_scalar_times():
    q = ptr([0, 0, 0], [40, 10, 0])
    s = SmoothSpline(q, [0.0, 2.0])
    assert Q.distance(s([0.0, 2.0]), q).max() < 1e-14
    assert s(1.0).shape == (4,)
    assert s(1.0, 3).shape == (3,)
    assert s(np.ones((2, 3)), 2).shape == (2, 3, 3)
    assert path_ratio(s, q) == pytest.approx(1.0, abs=1e-6)  # the geodesic


def test_unsorted_and_sparse_times_give_the_same_values(rng):
    q, t = random_keys(rng)
    s = SmoothSpline(q, t)
    tt = rng.uniform(t[0], t[-1], 500)
    dense = s.evaluate(np.sort(tt), max_order=3)
    shuffled = s.evaluate(tt, max_order=3)
    order = np.argsort(tt)
    for a, b in zip(dense[1:], shuffled[1:], strict=True):
        np.testing.assert_allclose(a, b[order], atol=1e-13)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 9),
    spread=st.floats(0.05, 1.5),
    boundary=st.sampled_from(["rest", "natural", "closed", "rest end-minimax"]),
)
def test_property_random_keyframes(seed, n, spread, boundary):
    boundary, _, knots = boundary.partition(" ")
    if boundary == "natural":  # one segment with free ends is undetermined (refused)
        n = max(n, 3)
    q, t = random_walk_keyframes(seed, n, spread, boundary)
    s = SmoothSpline(q, t, boundary=boundary, knots=knots or "quintic")
    S = s.evaluate(np.linspace(t[0], t[-1], 301), max_order=3)
    assert all(np.isfinite(x).all() for x in S[1:])
    if knots:  # never a higher sampled peak jerk on an end segment, any axis
        quintic = SmoothSpline(q, t, knots="quintic")
        for i in (0, n - 2):
            ours, theirs = end_segment_jerk(s, i).max(1), end_segment_jerk(quintic, i).max(1)
            assert (ours <= theirs + 1e-9 * (1 + theirs)).all()
    # At u = 1 the degree-7 polynomial's rounding grows with the knot rates.
    assert Q.distance(s(t), q).max() < 1e-11
    np.testing.assert_allclose(np.linalg.norm(S.q, axis=-1), 1.0, atol=1e-14)
    if boundary == "rest":
        assert np.abs(S.omega[[0, -1]]).max() < 1e-10 * (1 + np.abs(S.omega).max())
    for order in range(1, 4 if n > 2 else 1):
        before, after = one_sided(s, order)
        assert np.abs(before - after).max() <= 1e-9 * (1 + np.abs(before).max())


@pytest.mark.parametrize(
    "kwargs,exc,match",
    [
        (dict(quats=np.ones(4)), ValueError, r"`quats` to have shape \(N, 4\), got \(4,\)"),
        (dict(quats=[[1, 0, 0, 0]]), ValueError, "at least 2 keyframes, got 1"),
        (dict(times=[0.0, 1.0, 1.0]), ValueError, r"strictly increasing, got times\[1\] = 1.0"),
        (dict(times=[0.0, 1.0]), ValueError, r"`times` to have shape \(3,\)"),
        (dict(boundary="free"), ValueError, "`boundary` to be one of .* got 'free'"),
        (dict(boundary="closed"), ValueError, "last keyframe to repeat the first; they are 20 deg"),
        (dict(knots="minimax"), ValueError, "`knots` to be one of .* got 'minimax'"),
        (
            dict(knots="end-minimax", boundary="natural"),
            ValueError,
            "knots='end-minimax' needs boundary='rest' .* got boundary='natural'",
        ),
        (
            dict(knots="joint-minimax", boundary="natural"),
            ValueError,
            "knots='joint-minimax' needs boundary='rest' .* got boundary='natural'",
        ),
    ],
)
def test_bad_input_raises_with_a_message_naming_it(kwargs, exc, match):
    args = dict(quats=ptr([0, 0, 0], [10, 0, 0], [20, 0, 0]), times=[0.0, 1.0, 2.0])
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        SmoothSpline(args.pop("quats"), args.pop("times"), **args)


def test_evaluation_outside_the_range_raises():
    s = SmoothSpline(ptr([0, 0, 0], [10, 0, 0]), [0.0, 1.0])
    with pytest.raises(ValueError, match=r"Time 1.5 s is outside the path's range \[0.0, 1.0\]"):
        s(1.5)


# --- keyframe files: [spline] method ------------------------------------------------

KEYS = """
[[keyframes]]
t = 0.0
pan = 0.0

[[keyframes]]
t = 1.0
pan = 30.0

[[keyframes]]
t = 2.5
tilt = 20.0
"""


@pytest.mark.parametrize(
    "spline,cls,options",
    [
        ("", "SmoothSpline", {}),
        (
            "[spline]\nmethod = 'smooth'\nboundary = 'natural'\n",
            "SmoothSpline",
            {"boundary": "natural"},
        ),
        ("[spline]\nknots = 'end-minimax'\n", "SmoothSpline", {"knots": "end-minimax"}),
        ("[spline]\nknots = 'joint-minimax'\n", "SmoothSpline", {"knots": "joint-minimax"}),
        ("[spline]\nmethod = 'blending'\n", "BlendingSpline", {}),
        ("[spline]\nk = 3\n", "BlendingSpline", {"k": 3}),  # written for the blending spline
    ],
)
def test_keyframe_file_selects_the_method(tmp_path, spline, cls, options):
    from trajgen.keyframes import load_keyframe_file

    path = tmp_path / "keys.toml"
    path.write_text(spline + KEYS)
    kf = load_keyframe_file(path)
    assert type(kf.spline()).__name__ == cls
    assert kf.spline_options == options


@pytest.mark.parametrize(
    "spline,match",
    [
        ("method = 'fast'", r"\[spline\] method: expected one of smooth, blending, got 'fast'"),
        ("method = 'smooth'\nk = 2", r"\[spline\] k: applies to method = 'blending' only"),
        ("method = 'smooth'\nreparam = 'paper'", r"\[spline\] reparam: applies to method"),
        (
            "knots = 'lp'",
            r"\[spline\] knots: expected one of quintic, end-minimax, joint-minimax, got 'lp'",
        ),
        ("method = 'blending'\nknots = 'quintic'", r"knots: applies to method = 'smooth' only"),
        ("k = 2\nknots = 'quintic'", r"knots: applies to method = 'smooth' only"),
        (
            "boundary = 'closed'\nknots = 'end-minimax'",
            r"knots: 'end-minimax' needs boundary = 'rest', got 'closed'",
        ),
        (
            "boundary = 'natural'\nknots = 'joint-minimax'",
            r"knots: 'joint-minimax' needs boundary = 'rest', got 'natural'",
        ),
    ],
)
def test_keyframe_file_method_errors(tmp_path, spline, match):
    from trajgen.keyframes import KeyframeFileError, load_keyframe_file

    path = tmp_path / "keys.toml"
    path.write_text(f"[spline]\n{spline}\n" + KEYS)
    with pytest.raises(KeyframeFileError, match=match):
        load_keyframe_file(path)


# --- knots = "end-minimax": the rest ends' jerk chosen minimax --------------------------


def end_segment_jerk(s, i):
    """|r'''| (3, S) of segment ``i`` at END_SAMPLES, from its exact coefficients."""
    return np.abs(s._poly[i, 9:12] @ (END_SAMPLES[:, None] ** np.arange(8)).T)


def test_minimax_offset_matches_a_brute_force_search(rng):
    grid = np.linspace(-20, 20, 200001)
    for _ in range(10):
        S, k = int(rng.integers(2, 12)), 3
        c, b = rng.normal(size=(S, k)), rng.normal(size=S)
        x = minimax_offset(c, b, np.zeros(k))
        for col in range(k):
            peak = np.abs(c[:, col, None] + b[:, None] * grid).max(0)
            best = np.abs(c[:, col] + b * x[col]).max()
            assert best <= peak.min() + 1e-12
            assert best >= peak.min() - 2e-4 * (1 + abs(b).max())  # the grid's step


def test_minimax_offset_takes_the_optimum_nearest_the_preference():
    # The peak 2 sits where b = 0, so every x in [-1, 1] is optimal (|1 + x| <= 2 and
    # |1 - x| <= 2 there); the one nearest `prefer` is taken.
    c = np.array([[2.0], [1.0], [1.0]])
    b = np.array([0.0, 1.0, -1.0])
    assert minimax_offset(c, b, np.array([0.3]))[0] == pytest.approx(0.3)
    assert minimax_offset(c, b, np.array([5.0]))[0] == pytest.approx(1.0)


def test_end_minimax_changes_only_the_end_jerks_and_end_segments(rng):
    q, t = random_keys(rng, 8)
    a, b = SmoothSpline(q, t, knots="quintic"), SmoothSpline(q, t, knots="end-minimax")
    for x, y in zip(a.knot_rates[:2], b.knot_rates[:2], strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.knot_rates[2][1:-1], b.knot_rates[2][1:-1])
    assert np.abs(a.knot_rates[2][[0, -1]] - b.knot_rates[2][[0, -1]]).max() > 1e-3
    np.testing.assert_array_equal(a._poly[1:-1], b._poly[1:-1])
    for i in (0, len(t) - 2):
        assert (end_segment_jerk(b, i).max(1) <= end_segment_jerk(a, i).max(1) + 1e-12).all()
        assert end_segment_jerk(b, i).max() < end_segment_jerk(a, i).max()


def test_end_minimax_is_exact_c3_and_at_rest(rng):
    q, t = random_keys(rng, 8)
    s = SmoothSpline(q, t, knots="end-minimax")
    assert Q.distance(s(t), q).max() < 1e-13
    S = s.evaluate(np.linspace(t[0], t[-1], 5001), max_order=3)
    np.testing.assert_allclose(np.linalg.norm(S.q, axis=1), 1.0, atol=1e-15)
    for x in (S.omega, S.alpha):
        assert np.abs(x[[0, -1]]).max() < 1e-12 * (1 + np.abs(x).max())
    # At a rest end the space-frame jerk is the knot jerk it chose (r is half the
    # rotation vector, hence the 2).
    np.testing.assert_allclose(S.jerk[[0, -1]], 2 * s.knot_rates[2][[0, -1]], atol=1e-9)
    for order in range(4):
        before, after = one_sided(s, order)
        assert np.abs(before - after).max() < 1e-11 * (1 + np.abs(before).max()), order


def test_end_minimax_derivatives_match_finite_differences_and_sign_does_not_matter(rng):
    q, t = random_keys(rng)
    s = SmoothSpline(q, t, knots="end-minimax")
    tt = np.linspace(t[0] + 1e-3, t[-1] - 1e-3, 301)
    e = 1e-6
    dq = (s(tt + e) - s(tt - e)) / (2 * e)
    np.testing.assert_allclose(s(tt, 1), 2 * Q.mul(dq, Q.conj(s(tt)))[:, 1:], atol=1e-8)
    for order in (2, 3):
        fd = (s(tt + e, order - 1) - s(tt - e, order - 1)) / (2 * e)
        np.testing.assert_allclose(s(tt, order), fd, atol=1e-7 * np.abs(fd).max())
    flipped = q * np.where(rng.uniform(size=len(q)) < 0.5, -1.0, 1.0)[:, None]
    other = SmoothSpline(flipped, t, knots="end-minimax")
    assert Q.distance(s(tt), other(tt)).max() < 1e-13  # rounding: a sign slip gives O(1)
    np.testing.assert_allclose(s(tt, 3), other(tt, 3), atol=1e-10)


def test_end_minimax_two_keyframes_reach_the_best_symmetric_septic():
    # One axis, rest to rest in T: the quintic choice is the minimum-jerk quintic
    # 10u^3 - 15u^4 + 6u^5, peak jerk 60 D / T^3 at the ends (bang-bang, the bound:
    # 32; the septic with zero end jerk: 52.5). With the end jerks free, the best
    # symmetric septic is found here by brute force over the end jerk x (units
    # D / T^3): the least peak over u of |r'''| for
    # r = D (-H0(1 - u)) + x (H3(u) - H3(1 - u)), both mirrored terms as _H_RIGHT holds them.
    from numpy.polynomial import polynomial as P

    from trajgen.smooth import _H, _H_RIGHT

    D, T = np.radians(50.0), 2.0
    q = ptr([0, 0, 0], [50, 0, 0])
    quintic, best = (
        SmoothSpline(q, [0.0, T], knots="quintic"),
        SmoothSpline(q, [0.0, T], knots="end-minimax"),
    )
    tt = np.linspace(0, T, 20001)
    peak = [np.abs(s(tt, 3)).max() * T**3 / D for s in (quintic, best)]
    assert peak[0] == pytest.approx(60.0, rel=1e-6)
    u = np.linspace(0, 1, 2001)
    d3 = [P.polyval(u, P.polyder(c, 3)) for c in (_H_RIGHT[0], _H[3] + _H_RIGHT[3])]
    x = np.linspace(0, 60, 3001)[:, None]
    brute = np.abs(d3[0] + x * d3[1]).max(axis=1).min()
    assert peak[1] == pytest.approx(brute, rel=2e-3)  # END_SAMPLES is 33 points of u
    assert peak[1] / 32 < 1.25


def test_end_minimax_coefficients_are_the_segment_formula_of_its_knot_data(rng):
    # The end segments are patched by the linear terms; a rebuild from the knot data
    # (what a per-frame evaluator does) must give the same coefficients.
    for n in (2, 3, 7):
        q, t = random_keys(rng, n)
        s = SmoothSpline(q, t, knots="end-minimax")
        D = Q.log(Q.mul(s.quats[1:], Q.conj(s.quats[:-1])))
        rebuilt = s._segment_coefficients(D, np.diff(t), *s.knot_rates)
        np.testing.assert_allclose(s._poly, rebuilt, rtol=1e-12, atol=1e-12 * np.abs(rebuilt).max())


@pytest.mark.parametrize(
    "boundary,knots", [("rest", "end-minimax"), ("natural", "quintic"), ("closed", "quintic")]
)
def test_default_knot_choice_is_end_minimax_at_rest_else_quintic(rng, boundary, knots):
    q, t = closed_keys(rng) if boundary == "closed" else random_keys(rng)
    default, named = (
        SmoothSpline(q, t, boundary=boundary),
        SmoothSpline(q, t, boundary=boundary, knots=knots),
    )
    assert default.knots == knots
    np.testing.assert_array_equal(default._poly, named._poly)


def test_natural_needs_three_keyframes():
    """One segment with free ends leaves the knot rates undetermined: refused."""
    q = Q.exp(np.array([[0.0, 0.0, 0.0], [0.3, 0.1, 0.0]]))
    with pytest.raises(ValueError, match="natural.*at least 3 keyframes"):
        SmoothSpline(q, [0.0, 1.0], boundary="natural")
    SmoothSpline(q, [0.0, 1.0])  # the rest boundary is determined


# --- knots = "joint-minimax": knot data chosen for the gimbal's joint jerk ---------------


def gimbal_keys(rng, n=7):
    """Keyframes of a look-around (pan +-70, tilt +-40, roll +-10 deg), rest at 0 at both
    ends, uneven gaps: the kind of motion the torque race plans."""
    a = rng.uniform([-70, -40, -10], [70, 40, 10], size=(n, 3))
    a[0] = a[-1] = 0.0
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(0.5, 2.5, n - 1))])
    return ptr(*a), t


def sampled_joint_motion(s):
    """Per segment: peak |joint acceleration| per joint (n - 1, 3), peak |joint jerk|
    (n - 1,) and peak |tilt| (n - 1,), at JOINT_SAMPLES, from the exact coefficients."""
    from trajgen.smooth_joint_minimax import JOINT_SAMPLES, joint_motion

    acc, jerk, tilt = joint_motion(s._poly, s.quats[:-1], JOINT_SAMPLES)
    return np.abs(acc).max(axis=2), np.abs(jerk).max(axis=(1, 2)), np.abs(tilt).max(axis=1)


def test_joint_motion_matches_differences_of_the_exact_joint_accelerations(rng):
    from trajgen.gimbal import GimbalKinematics, joint_rates
    from trajgen.smooth_joint_minimax import joint_motion

    q, t = gimbal_keys(rng)
    s = SmoothSpline(q, t)
    u = np.linspace(0.05, 0.95, 7)
    acc, jerk, tilt = joint_motion(s._poly, s.quats[:-1], u)
    tt = (t[:-1, None] + np.diff(t)[:, None] * u).ravel()
    e = 1e-5
    joint_acc = []
    for x in (tt - e, tt, tt + e):
        S = s.evaluate(x, max_order=2)
        joint_acc.append(joint_rates(GimbalKinematics().inverse(S.q), S.omega, S.alpha)[1])
    angles = GimbalKinematics().inverse(s(tt))
    np.testing.assert_allclose(tilt.ravel(), angles[:, 1], atol=1e-13)
    exact_acc = acc.transpose(0, 2, 1).reshape(-1, 3)
    np.testing.assert_allclose(exact_acc, joint_acc[1], atol=1e-10 * np.abs(joint_acc[1]).max())
    fd = (joint_acc[2] - joint_acc[0]) / (2 * e)
    exact = jerk.transpose(0, 2, 1).reshape(-1, 3)
    np.testing.assert_allclose(exact, fd, atol=1e-6 * np.abs(fd).max())


def test_minimax_step_matches_the_exact_one_variable_minimax_and_a_grid(rng):
    from trajgen.smooth_joint_minimax import minimax_step

    c, b = rng.normal(size=(4, 30)), rng.normal(size=(4, 30))
    x = minimax_step(c, b[..., None])[:, 0]
    for k in range(4):
        exact = minimax_offset(c[k, :, None], b[k], np.zeros(1))[0]
        best = np.abs(c[k] + b[k] * exact).max()
        assert np.abs(c[k] + b[k] * x[k]).max() <= best * (1 + 1e-3)
    # Two variables against a grid search.
    c, B = rng.normal(size=(1, 40)), rng.normal(size=(1, 40, 2))
    x = minimax_step(c, B)[0]
    g = np.linspace(-3, 3, 601)
    X = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    grid = np.abs(c[0] + X @ B[0].T).max(axis=1).min()
    assert np.abs(c[0] + B[0] @ x).max() <= grid * (1 + 1e-3)


def test_joint_minimax_is_exact_c3_and_at_rest(rng):
    q, t = gimbal_keys(rng)
    s = SmoothSpline(q, t, knots="joint-minimax")
    assert Q.distance(s(t), q).max() < 1e-13
    v, a, _ = s.knot_rates
    assert not np.abs(np.concatenate([v[[0, -1]], a[[0, -1]]])).any()
    S = s.evaluate(np.linspace(t[0], t[-1], 5001), max_order=3)
    np.testing.assert_allclose(np.linalg.norm(S.q, axis=1), 1.0, atol=1e-15)
    for x in (S.omega, S.alpha):
        assert np.abs(x[[0, -1]]).max() < 1e-12 * (1 + np.abs(x).max())
    for order in range(4):
        before, after = one_sided(s, order)
        assert np.abs(before - after).max() < 1e-11 * (1 + np.abs(before).max()), order
    # The coefficients are the segment formula of its knot data.
    D = Q.log(Q.mul(s.quats[1:], Q.conj(s.quats[:-1])))
    rebuilt = s._segment_coefficients(D, np.diff(t), *s.knot_rates)
    np.testing.assert_allclose(s._poly, rebuilt, rtol=1e-12, atol=1e-12 * np.abs(rebuilt).max())


def test_joint_minimax_is_never_worse_than_end_minimax_and_keeps_its_guards(rng):
    from trajgen.gimbal import angles_of
    from trajgen.smooth_joint_minimax import ACCELERATION_SLACK, TILT_MARGIN_RAD

    lower = 0
    for _ in range(4):
        q, t = gimbal_keys(rng, int(rng.integers(4, 9)))
        start, best = (SmoothSpline(q, t, knots=k) for k in ("end-minimax", "joint-minimax"))
        (acc0, jerk0, tilt0), (acc, jerk, tilt) = map(sampled_joint_motion, (start, best))
        # The path's sampled peak joint jerk does not rise (a segment's may, when its
        # window's peak, in a neighbour, drops).
        assert jerk.max() <= jerk0.max() * (1 + 1e-12)
        lower += jerk.max() < 0.97 * jerk0.max()
        # Per joint, the peak acceleration stays within the slack (or the start's own).
        cap = ACCELERATION_SLACK * np.maximum(acc0.max(0), 1e-2 * acc0.max())
        assert (acc.max(0) <= np.maximum(cap, acc0.max(0)) * (1 + 1e-12)).all()
        keyframe_tilt = np.abs(angles_of(*q.T, np.arctan2, np.hypot)[1]).max()
        assert tilt.max() <= max(keyframe_tilt + TILT_MARGIN_RAD, tilt0.max()) + 1e-12
    assert lower >= 2  # it does something: the peak drops by 3% or more on most cases


def test_joint_minimax_is_deterministic_and_sign_invariant(rng):
    q, t = gimbal_keys(rng, 6)
    a, b = (SmoothSpline(q, t, knots="joint-minimax") for _ in range(2))
    np.testing.assert_array_equal(a._poly, b._poly)
    flipped = q * np.where(rng.uniform(size=len(q)) < 0.5, -1.0, 1.0)[:, None]
    c = SmoothSpline(flipped, t, knots="joint-minimax")
    tt = np.linspace(t[0], t[-1], 301)
    assert Q.distance(a(tt), c(tt)).max() < 1e-12


def test_joint_minimax_leaves_a_motion_it_cannot_improve_bit_for_bit():
    # A lone pan move: its peak jerk sits at both rest ends, where end-minimax already
    # balanced it; no step lowers it, and nothing else changes.
    q = ptr([0, 0, 0], [50, 0, 0])
    a, b = (SmoothSpline(q, [0.0, 2.0], knots=k) for k in ("end-minimax", "joint-minimax"))
    np.testing.assert_array_equal(a._poly, b._poly)


def test_joint_minimax_reports_its_progress_and_ends_at_one(rng):
    q, t = gimbal_keys(rng, 5)
    done = []
    with_progress = SmoothSpline(q, t, knots="joint-minimax", progress=done.append)
    assert done and done[-1] == 1.0 and done == sorted(done) and 0 < done[0] <= 1
    # The progress callback changes nothing of the result.
    np.testing.assert_array_equal(
        with_progress.tangent_coefficients,
        SmoothSpline(q, t, knots="joint-minimax").tangent_coefficients,
    )
