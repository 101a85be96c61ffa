"""Comparison methods: exact at keyframes, exact derivatives, the continuity each claims."""

import numpy as np
import pytest

from trajgen import quat as Q
from trajgen.compare import (
    PiecewiseCircles,
    PiecewiseSlerp,
    ScipyRotationSpline,
    SphericalBezier,
    Squad,
)


def walk(seed, n=6, scale=0.4):
    rng = np.random.default_rng(seed)
    steps = Q.exp(rng.normal(scale=scale, size=(n, 3)))
    q = steps.copy()
    for i in range(1, n):
        q[i] = Q.mul(steps[i], q[i - 1])
    return q, np.arange(n, dtype=float)


def jump(path, times, order, e=1e-7):
    return max(np.linalg.norm(path(ti + e, order) - path(ti - e, order)) for ti in times[1:-1])


# method, continuity order of the orientation on even spacing
METHODS = [
    (PiecewiseSlerp, 0),
    (Squad, 1),
    (SphericalBezier, 1),
    (PiecewiseCircles, 1),
    (ScipyRotationSpline, 2),
]


@pytest.mark.parametrize("method,cont", METHODS, ids=lambda m: getattr(m, "__name__", str(m)))
def test_exact_at_keyframes_and_derivatives_match_differences(method, cont):
    q, t = walk(1)
    path = method(q, t)
    assert Q.distance(path(t), q).max() < 1e-12
    tt = np.linspace(0.01, t[-1] - 0.01, 301)
    h = 1e-5
    dq = (path(tt + h) - path(tt - h)) / (2 * h)
    np.testing.assert_allclose(path(tt, 1), 2 * Q.mul(dq, Q.conj(path(tt)))[:, 1:], atol=1e-7)
    alpha_fd = (path(tt + h, 1) - path(tt - h, 1)) / (2 * h)
    np.testing.assert_allclose(path(tt, 2), alpha_fd, atol=1e-5)


@pytest.mark.parametrize("method,cont", METHODS, ids=lambda m: getattr(m, "__name__", str(m)))
def test_continuity_class(method, cont):
    q, t = walk(2)
    path = method(q, t)
    # Orientation C^cont: angular derivatives of order < cont continuous, order cont jumps.
    for order in range(1, cont + 1):
        assert jump(path, t, order) < 1e-4
    if cont < 2:
        assert jump(path, t, cont + 1) > 1e-2


def test_scipy_rates_are_space_frame_and_no_jerk():
    q, t = walk(3)
    path = ScipyRotationSpline(q, t)
    tt = np.linspace(0.5, 4.5, 9)
    np.testing.assert_allclose(
        Q.rotate(path(tt), path(tt, 1, frame="body")), path(tt, 1), atol=1e-12
    )
    with pytest.raises(ValueError, match="no jerk"):
        path(1.0, 3)


@pytest.mark.parametrize("method", [m for m, _ in METHODS], ids=lambda m: m.__name__)
def test_bad_input(method):
    with pytest.raises(ValueError, match="at least 2 keyframes, got 1"):
        method([[1, 0, 0, 0]], [0.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        method([[1, 0, 0, 0], [1, 0, 0, 0]], [1.0, 1.0])
    path = method(*walk(4, n=3))
    with pytest.raises(ValueError, match="outside the path's range"):
        path(-1.0)
