"""The torque-rate-bounded time-optimal profile along a path, on a fine grid: the fit's peer.

TOPP-RA has no bound on the torque rate, so its time is not what a motion under
the bound ``R`` can reach. This is that optimum, by direct transcription (the
bench's peer, not a motion: like TOPP-RA's profile it holds its limits at its
gridpoints only, and its jerk steps). Unknowns: the path speed ``y_i = s'`` at
gridpoints ``s_0 < ... < s_N`` of the path time; on each interval ``s''`` is
constant, ``u_i = (y_{i+1}^2 - y_i^2) / (2 ds_i)`` (TOPP's form, ``x = s'^2``
linear in ``s``). At each interval's midpoint, with ``x_m`` and ``y_m`` the
means of ``y^2`` and ``y`` at its ends, the torque (:mod:`sim.retime_path`)

    ``tau_m = A u_i + B x_m + C + D y_m + F``

keeps the envelope ``+-tau_m +- slope q_s y_m <= budget`` (both signs of both
terms), and between neighbouring midpoints the torque rate, Coulomb friction
left out as the check does, ``|tau_{m+1} - tau_m| y_{i+1} <= R (ds_i + ds_{i+1}) / 2``
(the difference over the time between them). The time
``T = sum 2 ds_i / (y_i + y_{i+1})`` is minimised by a sequential LP (HiGHS;
analytic sparse gradients; ``log T`` plus ``rho x`` the largest violation, in a
trust region, a step kept when that falls), as :mod:`sim.retime` does for the
fit's B-spline law.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .retime import trust_step
from .retime_path import PathDynamics

#: Penalty on the largest relative violation, against log T.
_RHO = 2.0
_MAX_ITERATIONS = 300
#: The iteration stops once the LP predicts less than this fall of the merit function.
_PREDICTED_TOL = 1e-6
#: Smallest path speed (the ends, where the path itself is at rest, may go to it).
_Y_MIN = 1e-6


@dataclass(frozen=True)
class Optimum:
    """The profile of :func:`rate_bounded_optimum`.

    Attributes
    ----------
    duration_s : float
        Its time (s).
    s : ndarray, shape (N + 1,)
        Gridpoints (path time from 0, s).
    speed : ndarray, shape (N + 1,)
        Path speed ``s'`` there.
    violation : float
        Largest relative violation of a limit at the gridpoints (<= 0: none).
    iterations : int
    """

    duration_s: float
    s: np.ndarray
    speed: np.ndarray
    violation: float
    iterations: int


class _Grid:
    """The transcription's rows and their Jacobian on fixed gridpoints ``s`` (N + 1,)."""

    def __init__(self, dyn: PathDynamics, s: np.ndarray, torque_rate_nm_s: float):
        self.s, self.ds = s, np.diff(s)
        mid = 0.5 * (s[1:] + s[:-1])
        tab = dyn.table(mid)  # (N, 6, 3)
        self.a, self.b, self.c, self.d, self.qs = (tab[:, i, :] for i in range(5))
        self.friction = dyn.friction * np.sign(self.qs)
        self.budget, self.slope, self.rate = dyn.budget, dyn.slope, float(torque_rate_nm_s)
        self.w = 0.5 * (self.ds[1:] + self.ds[:-1])  # (N - 1,)
        # At the two ends: the torque at the end gridpoint, with its interval's s''.
        self.ends = dyn.table(s[[0, -1]])  # (2, 6, 3)

    def time(self, y: np.ndarray) -> tuple[float, np.ndarray]:
        """``T`` and its gradient (N + 1,)."""
        pair = y[1:] + y[:-1]
        t = float((2.0 * self.ds / pair).sum())
        g = np.zeros_like(y)
        part = -2.0 * self.ds / pair**2
        g[1:] += part
        g[:-1] += part
        return t, g

    def rows(self, y: np.ndarray):
        """Relative rows (``<= 0`` keeps the limit), flat, and their sparse Jacobian in ``y``."""
        from scipy.sparse import coo_matrix

        n = len(self.ds)
        y0, y1 = y[:-1], y[1:]
        u = (y1**2 - y0**2) / (2.0 * self.ds)
        x, ym = 0.5 * (y0**2 + y1**2), 0.5 * (y0 + y1)
        tau = self.a * u[:, None] + self.b * x[:, None] + self.c + self.d * ym[:, None]  # (N, 3)
        # d tau / d y_i and d y_{i+1}, (N, 3) each.
        t0 = self.a * (-y0 / self.ds)[:, None] + self.b * y0[:, None] + 0.5 * self.d
        t1 = self.a * (y1 / self.ds)[:, None] + self.b * y1[:, None] + 0.5 * self.d
        values, data, rows, cols = [], [], [], []
        row = 0
        idx = np.arange(n)
        for s1 in (1.0, -1.0):
            for s2 in (1.0, -1.0):
                for j in range(3):
                    h = (
                        s1 * (tau[:, j] + self.friction[:, j])
                        + s2 * self.slope[j] * self.qs[:, j] * ym
                    ) / self.budget[j] - 1.0
                    g0 = (s1 * t0[:, j] + 0.5 * s2 * self.slope[j] * self.qs[:, j]) / self.budget[j]
                    g1 = (s1 * t1[:, j] + 0.5 * s2 * self.slope[j] * self.qs[:, j]) / self.budget[j]
                    values.append(h)
                    r = row + idx
                    rows += [r, r]
                    cols += [idx, idx + 1]
                    data += [g0, g1]
                    row += n
        # Torque rate: |tau_b - tau_a| <= R dt between neighbouring midpoints, and from
        # each end gridpoint to its interval's midpoint (the torque the motion starts
        # from and ends in), dt the time between them (half intervals: ds / (y + y')).
        half = self.ds / (y0 + y1)  # (N,) time over half an interval
        d_half0 = d_half1 = -self.ds / (y0 + y1) ** 2  # its gradient on y_i, y_i+1
        ends = []
        for end, i, other in ((0, 0, 1), (1, n, n - 1)):
            a, b, c, d = (self.ends[end, k, :] for k in range(4))
            mid = min(i, other)
            sign = 1.0 if end else -1.0  # u of the end interval: (y_1^2 - y_0^2) / (2 ds)
            tau_end = a * u[mid] + b * y[i] ** 2 + c + d * y[i]
            grad_i = a * sign * y[i] / self.ds[mid] + 2.0 * b * y[i] + d
            ends.append((tau_end, grad_i, -a * sign * y[other] / self.ds[mid]))
        m = np.arange(n - 1)
        # (later tau, earlier tau, their gradients on (y_m, y_m+1, y_m+2), dt, its gradient)
        pairs = [
            (
                tau[1:],
                tau[:-1],
                (-t0[:-1], t0[1:] - t1[:-1], t1[1:]),
                half[:-1] + half[1:],
                (d_half0[:-1], d_half1[:-1] + d_half0[1:], d_half1[1:]),
                (m, m + 1, m + 2),
            ),
            (  # start: midpoint 0 after gridpoint 0 (tau_end's gradient is on y_0 alone)
                tau[:1],
                ends[0][0][None],
                (t0[:1] - ends[0][1][None], t1[:1] - ends[0][2][None], np.zeros((1, 3))),
                half[:1],
                (d_half0[:1], d_half1[:1], np.zeros(1)),
                (np.array([0]), np.array([1]), np.array([1])),
            ),
            (  # end: gridpoint N after midpoint N - 1
                ends[1][0][None],
                tau[-1:],
                (ends[1][2][None] - t0[-1:], ends[1][1][None] - t1[-1:], np.zeros((1, 3))),
                half[-1:],
                (d_half0[-1:], d_half1[-1:], np.zeros(1)),
                (np.array([n - 1]), np.array([n]), np.array([n])),
            ),
        ]
        for later, earlier, grads, dt, dts, where in pairs:
            k = np.arange(len(dt))
            for s1 in (1.0, -1.0):
                for j in range(3):
                    diff = later[:, j] - earlier[:, j]
                    values.append(s1 * diff / (self.rate * dt) - 1.0)
                    for grad, ddt, col in zip(grads, dts, where, strict=True):
                        rows.append(row + k)
                        cols.append(col)
                        data.append(s1 * (grad[:, j] / dt - diff * ddt / dt**2) / self.rate)
                    row += len(dt)
        jac = coo_matrix(
            (np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))),
            shape=(row, len(y)),
        ).tocsr()
        return np.concatenate(values), jac


def rate_bounded_optimum(
    dyn: PathDynamics, s: np.ndarray, speed: np.ndarray, torque_rate_nm_s: float
) -> Optimum:
    """The shortest time along the path under the envelope and the torque-rate bound.

    Parameters
    ----------
    dyn : PathDynamics
        The path's tables (:func:`sim.retime_path.path_dynamics`).
    s : ndarray, shape (N + 1,)
        Gridpoints, path time from 0 to ``dyn.s_span``, increasing.
    speed : ndarray, shape (N + 1,)
        A start: path speed ``s'`` (> 0) at the gridpoints, e.g. a fitted law's.
    torque_rate_nm_s : float
        ``R`` (N m/s).

    Returns
    -------
    Optimum
    """
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix, diags, hstack

    grid = _Grid(dyn, np.asarray(s, dtype=float), torque_rate_nm_s)
    # Unknowns x = s'^2 (s'' is linear in them; only the s' terms are not).
    x = np.maximum(np.asarray(speed, dtype=float), _Y_MIN) ** 2

    def merit(x_):
        y_ = np.sqrt(x_)
        t_, g_ = grid.time(y_)
        h_, jac_ = grid.rows(y_)
        chain = 0.5 / y_
        return (
            np.log(t_) + _RHO * max(0.0, float(h_.max())),
            t_,
            g_ * chain,
            h_,
            jac_ @ diags(chain),
        )

    phi, t, g, h, jac = merit(x)
    radius, n = 0.2, len(x)
    iterations = 0
    for _ in range(_MAX_ITERATIONS):
        iterations += 1
        # Every row: the torque rate, a second difference of x over the grid, moves far
        # for a small step, so no row may be left out as slack.
        a_ub = hstack([jac, csr_matrix(-np.ones((h.size, 1)))]).tocsr()
        cost = np.append(g / t, _RHO)
        box = [(max(-radius * xi, _Y_MIN**2 - xi), radius * xi) for xi in x] + [(0.0, None)]
        lp = linprog(cost, A_ub=a_ub, b_ub=-h, bounds=box, method="highs")
        if lp.status != 0:
            radius *= 0.3
            if radius < 1e-6:
                break
            continue
        dx = lp.x[:n]
        predicted = phi - (np.log(t) + g @ dx / t + _RHO * lp.x[n])
        if predicted < _PREDICTED_TOL:
            break
        trial = merit(x + dx)
        ratio = (phi - trial[0]) / predicted
        kept, radius = trust_step(ratio, radius, 1.0)
        if kept:
            x = x + dx
            phi, t, g, h, jac = trial
        elif radius < 1e-6:
            break
    return Optimum(t, grid.s, np.sqrt(x), float(h.max()), iterations)
