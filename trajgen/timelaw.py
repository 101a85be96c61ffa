"""A time law along a path: the path kept, its clock replaced (``trajgen fit``'s retiming).

A :class:`TimeLaw` maps motion time ``t`` to path time
``s(t) = s_0 + S sigma((t - t_0) / T)``, ``sigma`` a clamped B-spline on
``[0, 1]`` with ``sigma(0) = 0``, ``sigma(1) = 1`` and strictly increasing
coefficients (so ``sigma' > 0``: the path is never stopped or run backwards).
A :class:`RetimedPath` plays a path (any :class:`~trajgen.path.OrientationPath`,
e.g. a :class:`~trajgen.smooth.SmoothSpline` built at its own keyframe times)
by that law: ``q(t) = p(s(t))``, its keyframes passed in order at the times
``s^-1(path.times)``. With a quintic (C4) ``sigma`` and a C3 path the motion is
C3. Its derivatives are exact, by the chain rule (Faa di Bruno) in the space
frame, ``w = w_p s'``, ``a = a_p s'^2 + w_p s''``,
``j = j_p s'^3 + 3 a_p s' s'' + w_p s'''`` (``w_p``, ``a_p``, ``j_p`` the path's
angular velocity, acceleration and jerk per unit of path time).

Numpy only: the B-spline is evaluated by de Boor's algorithm.
"""

from __future__ import annotations

import numpy as np

from .errors import BadArgument
from .path import OrientationPath, check_times
from .validate import check_number

#: The degree of the time law ``trajgen fit`` writes: quintic, so ``sigma`` is C4.
DEGREE = 5


def bspline_derivative(knots: np.ndarray, coefficients: np.ndarray, degree: int):
    """Knots, coefficients and degree of the derivative of a B-spline (de Boor).

    ``c'_i = p (c_{i+1} - c_i) / (k_{i+p+1} - k_{i+1})`` on the knots without
    their first and last entry, degree ``p - 1``.
    """
    p = degree
    span = knots[p + 1 : p + len(coefficients)] - knots[1 : len(coefficients)]
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(span > 0, p * np.diff(coefficients) / span, 0.0)
    return knots[1:-1], d, p - 1


def bspline_values(knots: np.ndarray, coefficients: np.ndarray, degree: int, x) -> np.ndarray:
    """A B-spline's values at ``x`` (M,) by de Boor's algorithm, vectorised over ``x``.

    Parameters
    ----------
    knots : ndarray, shape (n + degree + 1,)
    coefficients : ndarray, shape (n,)
    degree : int
    x : ndarray, shape (M,)
        Within ``[knots[degree], knots[n]]``.

    Returns
    -------
    ndarray, shape (M,)
    """
    p, n = degree, len(coefficients)
    x = np.asarray(x, dtype=float)
    k = np.clip(np.searchsorted(knots, x, side="right") - 1, p, n - 1)
    d = coefficients[k[:, None] + np.arange(-p, 1)[None, :]].astype(float)  # (M, p + 1)
    for r in range(1, p + 1):
        for j in range(p, r - 1, -1):
            left = knots[j + k - p]
            right = knots[j + 1 + k - r]
            with np.errstate(divide="ignore", invalid="ignore"):
                alpha = np.where(right > left, (x - left) / (right - left), 0.0)
            d[:, j] = (1.0 - alpha) * d[:, j - 1] + alpha * d[:, j]
    return d[:, p]


class TimeLaw:
    """Path time ``s(t) = s_0 + S sigma((t - t_0) / T)``, ``sigma`` a clamped B-spline.

    Parameters
    ----------
    knots : array_like, shape (n + degree + 1,)
        Non-decreasing, ``degree + 1`` zeros first and ``degree + 1`` ones last.
    coefficients : array_like, shape (n,)
        Strictly increasing from 0 to 1.
    t_start : float
        Motion time ``t_0`` (s) of the first keyframe.
    duration_s : float
        ``T`` (s), > 0.
    s_start, s_span : float
        ``s_0`` and ``S`` (s of path time), ``S > 0``.
    degree : int
        Default 5 (quintic).

    Raises
    ------
    ValueError
        If the knots are not clamped and non-decreasing, or the coefficients
        not strictly increasing from 0 to 1, or a length does not match.
    """

    def __init__(self, knots, coefficients, t_start, duration_s, s_start, s_span, degree=DEGREE):
        knots = np.asarray(knots, dtype=float)
        c = np.asarray(coefficients, dtype=float)
        p = int(degree)
        if c.ndim != 1 or knots.shape != (len(c) + p + 1,) or len(c) < p + 1:
            raise BadArgument(
                f"Expected {p + 1} or more coefficients and {p + 1} knots more than "
                f"coefficients, got {c.size} and {knots.size}."
            )
        if not (np.isfinite(knots).all() and np.isfinite(c).all()):
            raise BadArgument("Expected finite knots and coefficients.")
        if (
            (np.diff(knots) < 0).any()
            or (knots[: p + 1] != 0).any()
            or (knots[-p - 1 :] != 1).any()
        ):
            raise BadArgument(
                f"Expected non-decreasing knots with {p + 1} zeros first and {p + 1} ones last."
            )
        if c[0] != 0.0 or c[-1] != 1.0 or (np.diff(c) <= 0).any():
            raise BadArgument("Expected coefficients strictly increasing from 0 to 1.")
        self.knots, self.coefficients, self.degree = knots, c, p
        self.t_start = check_number("t_start", t_start)
        self.duration_s = check_number("duration_s", duration_s, low=0.0, low_open=True)
        self.s_start = check_number("s_start", s_start)
        self.s_span = check_number("s_span", s_span, low=0.0, low_open=True)
        # sigma and its derivatives up to the third, each (knots, coefficients, degree).
        self._derivatives = [(knots, c, p)]
        for _ in range(3):
            self._derivatives.append(bspline_derivative(*self._derivatives[-1]))

    @property
    def t_end(self) -> float:
        return self.t_start + self.duration_s

    def sigma(self, tau, order: int = 0) -> np.ndarray:
        """``sigma`` or its ``order``-th derivative (0..3) at normalised times ``tau`` (M,)."""
        knots, c, p = self._derivatives[order]
        tau = np.clip(np.asarray(tau, dtype=float), 0.0, 1.0)
        return bspline_values(knots, c, p, tau)

    def __call__(self, t, max_order: int = 3) -> list[np.ndarray]:
        """``[s, s', s'', s''']`` up to ``max_order`` at motion times ``t`` (M,).

        Units: s, 1, 1/s, 1/s^2 (path time over motion time).
        """
        tau = (np.asarray(t, dtype=float) - self.t_start) / self.duration_s
        scale = self.s_span
        out = []
        for m in range(max_order + 1):
            out.append(scale * self.sigma(tau, m))
            scale = scale / self.duration_s
        out[0] = out[0] + self.s_start
        return out

    def inverse(self, s) -> np.ndarray:
        """Motion times (M,) at which path times ``s`` (M,) are reached.

        ``sigma`` is tabulated at 16 points per knot interval and inverted by
        interpolation, then polished by Newton steps (``sigma' > 0``) to 1e-14
        of the normalised time; a bisection finishes any point Newton leaves.
        """
        target = np.clip((np.asarray(s, dtype=float) - self.s_start) / self.s_span, 0.0, 1.0)
        breaks = np.unique(self.knots)
        grid = np.append((breaks[:-1, None] + np.outer(np.diff(breaks), np.arange(16) / 16)), 1.0)
        tau = np.interp(target, self.sigma(grid), grid)
        for _ in range(8):
            step = (self.sigma(tau) - target) / self.sigma(tau, 1)
            tau = np.clip(tau - step, 0.0, 1.0)
            if np.abs(step).max(initial=0.0) < 1e-14:
                break
        else:
            lo, hi = np.zeros_like(target), np.ones_like(target)
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                below = self.sigma(mid) < target
                lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
            tau = 0.5 * (lo + hi)
        return self.t_start + self.duration_s * tau


class RetimedPath(OrientationPath):
    """A path played by a :class:`TimeLaw`: ``q(t) = path(s(t))``, same spline protocol.

    Parameters
    ----------
    path : OrientationPath
        The path in its own time (e.g. a SmoothSpline at its own keyframe times);
        ``path.t_start`` and ``path.t_end`` must be ``law.s_start`` and
        ``law.s_start + law.s_span``.
    law : TimeLaw

    Attributes
    ----------
    times : ndarray, shape (N,)
        Motion times (s) at which the path's keyframes are passed.
    quats : ndarray, shape (N, 4)
        The path's keyframes (``path.quats``), passed at ``times``.
    """

    def __init__(self, path: OrientationPath, law: TimeLaw):
        s0, s1 = law.s_start, law.s_start + law.s_span
        if not (np.isclose(path.t_start, s0, atol=1e-9) and np.isclose(path.t_end, s1, atol=1e-9)):
            raise BadArgument(
                f"Expected the time law to span the path's [{path.t_start}, {path.t_end}] s, "
                f"got [{s0}, {s1}] s."
            )
        self.path, self.law = path, law
        times = law.inverse(path.times)
        times[0], times[-1] = law.t_start, law.t_end
        self.times = check_times(times, len(path.times))
        self.quats = np.asarray(path.quats)

    def _space_rates(self, t, seg, max_order):
        s = self.law(t, max_order)
        s[0] = np.clip(s[0], self.path.t_start, self.path.t_end)
        p = self.path.evaluate(s[0], max_order=max_order)
        if max_order == 0:
            return p.q, []
        d1 = s[1][:, None]
        rates = [p.omega * d1]
        if max_order >= 2:
            d2 = s[2][:, None]
            rates.append(p.alpha * d1**2 + p.omega * d2)
        if max_order >= 3:
            rates.append(p.jerk * d1**3 + 3.0 * p.alpha * d1 * d2 + p.omega * s[3][:, None])
        return p.q, rates
