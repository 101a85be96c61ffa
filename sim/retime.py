"""The fastest smooth time law along a fixed path: a sequential LP on a quintic B-spline.

Time law ``s(t) = S sigma(t / T)``, ``sigma`` a clamped quintic B-spline on
``[0, 1]`` (coefficients ``c``, the first 0 and the last 1, strictly
increasing). With ``v = 1 / T``, ``s' = S v sigma'``, ``s'' = S v^2 sigma''``,
``s''' = S v^3 sigma'''``: linear in ``c`` for a given ``T``. Every limit is a
polynomial in ``(s', s'', s''')`` whose coefficients depend on the path time
``s`` alone (:mod:`sim.retime_path`):

- torque envelope: ``+-tau +- slope q_s s' <= budget`` (both signs of both
  terms: ``|q_s|`` without a kink), ``tau = A s'' + B s'^2 + C + D s' + F``;
- torque rate (Coulomb friction left out, as the check does):
  ``d tau / dt = A s''' + (A_s + 2 B) s' s'' + B_s s'^3 + C_s s' + D s'' + D_s s'^2``;
- ``[limits]``: speed ``q_s s'``, acceleration ``q_ss s'^2 + q_s s''``, jerk
  ``q_sss s'^3 + 3 q_ss s' s'' + q_s s'''``, each within +-its bound.

They are imposed at a fixed grid of normalised times ``tau_k``; the path time
there, ``s_k = S sigma(tau_k)``, moves with ``c``, so the gradients carry the
tables' ``s``-derivatives too. All gradients are analytic (sparse, six
B-spline coefficients per row). The problem, ``min log T`` over ``(c, log T)``,
is solved by a sequential LP (scipy's HiGHS): each step minimises the
linearised ``log T`` plus ``rho x`` the largest linearised violation (an exact
l-infinity penalty), within a trust region, over the rows within 30 % of their
bound; a step is kept if the true penalty function falls.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from trajgen.timelaw import DEGREE

from .errors import SimError
from .limits import JointLimits
from .retime_path import PathDynamics

#: B-spline coefficients of sigma per path segment.
COEFFICIENTS_PER_SEGMENT = 16
#: Constraint points per knot interval of sigma.
POINTS_PER_INTERVAL = 4
#: ... and in the first and last ``_END_INTERVALS``, where the path is near rest and the
#: torque rate can rise steeply between points.
POINTS_PER_END_INTERVAL = 24
_END_INTERVALS = 3
#: Points per path segment of the initial speed profile.
PROFILE_POINTS_PER_SEGMENT = 128
#: Penalty on the largest relative violation, against log T.
_RHO = 2.0
#: Rows further than this (relative) inside their bound are left out of an LP.
_ACTIVE = 0.3
_MAX_ITERATIONS = 150
#: The iteration stops once the LP predicts less than this fall of the penalty function.
_PREDICTED_TOL = 1e-4
#: Smallest gap between neighbouring coefficients, as a fraction of their mean gap.
_MIN_GAP = 1e-3

#: The limit families, as reported in the fit's table (the joint follows in brackets).
FAMILIES = ("torque envelope", "torque rate", "speed limit", "acceleration limit", "jerk limit")


@dataclass
class LawBounds:
    """The limits the law is optimised under, some of them learned from simulation.

    Attributes
    ----------
    limits : JointLimits
    torque_rate_nm_s : float
        Bound R on |d tau / dt| (N m/s) per joint.
    s_grid : ndarray, shape (G,)
        Path times (from 0) at which the learned bounds are kept.
    budget_scale : ndarray, shape (G,)
        Factor <= 1 on the torque budget near each of ``s_grid``.
    speed_cap : ndarray, shape (G, 3)
        Speed cap (rad/s) per joint near each of ``s_grid`` (inf: none).
    """

    limits: JointLimits
    torque_rate_nm_s: float
    s_grid: np.ndarray
    budget_scale: np.ndarray
    speed_cap: np.ndarray

    def index(self, s: np.ndarray) -> np.ndarray:
        """Index (M,) into ``s_grid`` of the point nearest each path time ``s`` (M,)."""
        return np.rint(np.interp(s, self.s_grid, np.arange(len(self.s_grid)))).astype(int)


def knots_for(s_keys: np.ndarray) -> np.ndarray:
    """Clamped quintic knots on [0, 1]: ``COEFFICIENTS_PER_SEGMENT`` coefficients per segment.

    Interior knots are spread uniformly over each segment's share of the path
    time (``s_keys`` (N,) from 0), so a short segment gets as many as a long one.
    """
    n_seg = len(s_keys) - 1
    n_coef = COEFFICIENTS_PER_SEGMENT * n_seg
    inner = n_coef - DEGREE - 1
    where = np.arange(1, inner + 1) * n_seg / (inner + 1)
    inner_knots = np.interp(where, np.arange(n_seg + 1), s_keys / s_keys[-1])
    return np.concatenate([np.zeros(DEGREE + 1), inner_knots, np.ones(DEGREE + 1)])


def greville(knots: np.ndarray) -> np.ndarray:
    """The coefficients of ``sigma(tau) = tau`` on ``knots`` (Greville abscissae)."""
    n = len(knots) - DEGREE - 1
    return np.array([knots[i + 1 : i + DEGREE + 1].mean() for i in range(n)])


def _grid(knots: np.ndarray) -> np.ndarray:
    """Constraint points: ``POINTS_PER_INTERVAL`` per knot interval, uniform in each."""
    breaks = np.unique(knots)
    points = np.full(len(breaks) - 1, POINTS_PER_INTERVAL)
    points[:_END_INTERVALS] = points[-_END_INTERVALS:] = POINTS_PER_END_INTERVAL
    pieces = [
        a + (b - a) * np.arange(m) / m
        for a, b, m in zip(breaks[:-1], breaks[1:], points, strict=True)
    ]
    return np.append(np.concatenate(pieces), 1.0)


class LawProblem:
    """Rows and their analytic Jacobian for the time law on a path (see the module docstring).

    Parameters
    ----------
    dynamics : PathDynamics
    bounds : LawBounds
    knots : ndarray
        Knots of sigma (:func:`knots_for`).
    """

    def __init__(self, dynamics: PathDynamics, bounds: LawBounds, knots: np.ndarray):
        from scipy.interpolate import BSpline

        self.dyn, self.bounds, self.knots = dynamics, bounds, knots
        self.n_coef = len(knots) - DEGREE - 1
        self.tau = _grid(knots)
        eye = np.eye(self.n_coef)
        basis = BSpline(knots, eye, DEGREE)
        from scipy.sparse import csr_matrix

        # sigma^(m)(tau_k) = B[m] @ c, each (K, n) with at most six entries a row.
        self.B = []
        for m in range(4):
            dense = basis.derivative(m)(self.tau) if m else basis(self.tau)
            dense[np.abs(dense) < 1e-14] = 0.0
            self.B.append(csr_matrix(dense))
        limits = bounds.limits.as_array()
        joints = range(len(bounds.limits.joints))
        self._families = [
            ("torque envelope", j, (a, b)) for j in joints for a in (1, -1) for b in (1, -1)
        ]
        self._families += [("torque rate", j, (a,)) for j in joints for a in (1, -1)]
        for name, row in zip(FAMILIES[2:], limits, strict=True):
            for j in joints:
                if np.isfinite(row[j]) or (
                    name == "speed limit" and np.isfinite(bounds.speed_cap[:, j]).any()
                ):
                    self._families += [(name, j, (a,)) for a in (1, -1)]

    def family_names(self) -> list[str]:
        """One label per family of rows, e.g. ``"torque envelope (tilt)"``."""
        names = self.bounds.limits.joints
        return [f"{name} ({names[j]})" for name, j, _ in self._families]

    def rows(self, c: np.ndarray, z: float):
        """Relative rows ``h`` (F, K) (``<= 0`` keeps the limit) and the parts of their gradient.

        Parameters
        ----------
        c : ndarray, shape (n,)
            All coefficients of sigma.
        z : float
            ``log T``.
        """
        S, v = self.dyn.s_span, np.exp(-z)
        sig = [B @ c for B in self.B]
        s = np.clip(S * sig[0], 0.0, S)
        d1, d2, d3 = S * v * sig[1], S * v * v * sig[2], S * v**3 * sig[3]
        mono = np.stack([np.ones_like(d1), d1, d1 * d1, d1**3, d2, d1 * d2, d3])  # (7, K)
        coef, dcoef = self.coefficients(s)
        h = np.einsum("fmk,mk->fk", coef, mono) - 1.0
        return h, (coef, dcoef, mono, d1, d2, v, S)

    def coefficients(self, s: np.ndarray):
        """Every row's coefficients (F, 7, K) at path times ``s`` (K,), over its bound.

        On the monomials ``1, s', s'^2, s'^3, s'', s' s'', s'''`` in that order;
        returned with their derivatives in ``s`` (F, 7, K).
        """
        dyn = self.dyn
        t0, t1, t2 = (dyn.table(s, nu) for nu in range(3))  # (K, 6, 3)
        local = self.bounds.index(s)
        limits = self.bounds.limits.as_array()
        n_f, k = len(self._families), len(s)
        coef, dcoef = np.zeros((n_f, 7, k)), np.zeros((n_f, 7, k))
        bound = np.empty((n_f, k))
        for f, (name, j, signs) in enumerate(self._families):
            a, b, cc, d, qs, qss = (t0[:, i, j] for i in range(6))
            a1, b1, c1, d1_, qs1, qss1 = (t1[:, i, j] for i in range(6))
            a2, b2, c2, d2_, _, qss2 = (t2[:, i, j] for i in range(6))
            x, dx = coef[f], dcoef[f]
            if name == "torque envelope":
                s1, s2 = signs
                scale = self.bounds.budget_scale[local]
                friction = dyn.friction[j] * np.sign(qs)
                x[0], x[1], x[2], x[4] = (
                    s1 * (cc + friction),
                    s1 * d + s2 * scale * dyn.slope[j] * qs,
                    s1 * b,
                    s1 * a,
                )
                dx[0], dx[1], dx[2], dx[4] = (
                    s1 * c1,
                    s1 * d1_ + s2 * scale * dyn.slope[j] * qs1,
                    s1 * b1,
                    s1 * a1,
                )
                bound[f] = scale * dyn.budget[j]
                continue
            s1 = signs[0]
            if name == "torque rate":
                x[1], x[2], x[3], x[4], x[5], x[6] = c1, d1_, b1, d, a1 + 2 * b, a
                dx[1], dx[2], dx[3], dx[4], dx[5], dx[6] = c2, d2_, b2, d1_, a2 + 2 * b1, a1
                bound[f] = self.bounds.torque_rate_nm_s
            elif name == "speed limit":
                x[1], dx[1] = qs, qs1
                bound[f] = np.minimum(limits[0, j], self.bounds.speed_cap[local, j])
            elif name == "acceleration limit":
                x[2], x[4], dx[2], dx[4] = qss, qs, qss1, qs1
                bound[f] = limits[1, j]
            else:  # jerk
                x[3], x[5], x[6] = qss1, 3 * qss, qs
                dx[3], dx[5], dx[6] = qss2, 3 * qss1, qs1
                bound[f] = limits[2, j]
            coef[f] *= s1
            dcoef[f] *= s1
        coef /= bound[:, None, :]
        dcoef /= bound[:, None, :]
        return coef, dcoef

    def jacobian(self, parts, rows: np.ndarray):
        """Gradient of the flat rows ``rows`` (indices into ``h.ravel()``) in ``(c, z)``: sparse
        (len(rows), n) for ``c`` and dense (len(rows),) for ``z``."""
        from scipy.sparse import diags

        coef, dcoef, mono, d1, d2, v, S = parts
        n_k = mono.shape[1]
        f, k = np.divmod(rows, n_k)
        cf, dcf, mo = coef[f, :, k], dcoef[f, :, k], mono[:, k].T  # (R, 7)
        g0 = (dcf * mo).sum(axis=1)
        g1 = cf[:, 1] + 2 * cf[:, 2] * d1[k] + 3 * cf[:, 3] * d1[k] ** 2 + cf[:, 5] * d2[k]
        g2 = cf[:, 4] + cf[:, 5] * d1[k]
        g3 = cf[:, 6]
        jc = S * (
            diags(g0) @ self.B[0][k]
            + diags(v * g1) @ self.B[1][k]
            + diags(v * v * g2) @ self.B[2][k]
            + diags(v**3 * g3) @ self.B[3][k]
        )
        powers = np.array([0, 1, 2, 3, 2, 3, 3])
        jz = -(cf * mo * powers).sum(axis=1)
        return jc, jz

    def start(self, c: np.ndarray) -> float:
        """The smallest ``log T`` (to 0.1 %) at which ``c`` keeps every row: a start for the LP."""
        hi = np.log(self.dyn.s_span) + 1.0
        while self.rows(c, hi)[0].max() > 0:
            hi += 1.0
            if hi > np.log(self.dyn.s_span) + 12:
                raise SimError("no duration keeps the limits")
        lo = hi - 1.0
        while self.rows(c, lo)[0].max() <= 0 and lo > np.log(self.dyn.s_span) - 12:
            lo -= 1.0
        while hi - lo > 1e-3:
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if self.rows(c, mid)[0].max() <= 0 else (mid, hi)
        return hi


def trust_step(ratio: float, radius: float, largest: float) -> tuple[bool, float]:
    """A trust-region step's fate from ``ratio``, its actual over its predicted fall of the
    merit function: kept if above 0.1; the next radius doubled (to ``largest``) after a
    step above 0.75, cut to 0.3x after a rejected one."""
    if ratio > 0.1:
        return True, min(radius * 2.0, largest) if ratio > 0.75 else radius
    return False, radius * 0.3


def optimise(problem: LawProblem, c: np.ndarray, z: float, say: Callable[[str], None]):
    """Sequential LP from ``(c, z)``: the coefficients and ``log T`` of the fastest law found.

    Returns
    -------
    c : ndarray, shape (n,)
    z : float
    iterations : int
    violation : float
        The largest relative row at the result (<= 0 when every limit holds on the grid).
    """
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix, hstack, vstack

    n = problem.n_coef
    n_free = n - 2
    gap = 1.0 / (n - 1)
    # Monotone: c[i + 1] - c[i] >= min_gap, as -(dc[i + 1] - dc[i]) <= c[i + 1] - c[i] - min_gap.
    diff = np.zeros((n - 1, n))
    diff[np.arange(n - 1), np.arange(n - 1)] = 1.0
    diff[np.arange(n - 1), np.arange(1, n)] = -1.0
    mono_rows = csr_matrix(np.hstack([diff[:, 1:-1], np.zeros((n - 1, 2))]))
    radius = 1.0

    def merit(c_, z_):
        h, parts = problem.rows(c_, z_)
        return z_ + _RHO * max(0.0, float(h.max())), h, parts

    phi, h, parts = merit(c, z)
    # Rows a rejected step broke stay in every later LP.
    sticky = np.zeros(h.size, dtype=bool)
    iterations = 0
    for iterations in range(1, _MAX_ITERATIONS + 1):
        flat = h.ravel()
        active = np.flatnonzero((flat > -_ACTIVE) | sticky)
        jc, jz = problem.jacobian(parts, active)
        a_rows = hstack(
            [jc[:, 1:-1], csr_matrix(jz[:, None]), csr_matrix(-np.ones((len(active), 1)))]
        )
        a_ub = vstack([a_rows, mono_rows]).tocsr()
        b_ub = np.concatenate([-flat[active], np.diff(c) - _MIN_GAP * gap])
        cost = np.zeros(n_free + 2)
        cost[n_free], cost[n_free + 1] = 1.0, _RHO
        box = [(-radius * gap, radius * gap)] * n_free + [
            (-0.2 * radius, 0.2 * radius),
            (0.0, None),
        ]
        lp = linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=box, method="highs")
        if lp.status != 0:
            radius *= 0.3
            if radius < 1e-6:
                break
            continue
        step = lp.x
        predicted = phi - (z + step[n_free] + _RHO * step[n_free + 1])
        if predicted < _PREDICTED_TOL:
            break
        trial_c = c.copy()
        trial_c[1:-1] += step[:n_free]
        trial_z = z + step[n_free]
        trial_phi, trial_h, trial_parts = merit(trial_c, trial_z)
        ratio = (phi - trial_phi) / predicted
        sticky |= trial_h.ravel() > 0
        kept, radius = trust_step(ratio, radius, 8.0)
        if kept:
            c, z, phi, h, parts = trial_c, trial_z, trial_phi, trial_h, trial_parts
        elif radius < 1e-6:
            break
        if iterations % 10 == 0:
            say(f"  law {iterations}: {np.exp(z):.3f} s, worst {max(0.0, float(h.max())):.1%} over")
    return c, z, iterations, float(h.max())


def initial_law(dynamics: PathDynamics, bounds: LawBounds):
    """A start for :func:`optimise`: a speed profile under the limits, fitted by sigma.

    The largest path speed ``s'`` each point allows at ``s'' = s''' = 0``, then a
    forward and a backward pass bounding ``d(s'^2)/ds = 2 s''`` by the
    acceleration the rows allow at that speed (the classic numerical-integration
    profile, without the torque rate and jerk rows); its clock ``t(s)`` is fitted
    by sigma in least squares, on knots placed by the keyframes' share of ``t``.

    Returns
    -------
    knots : ndarray
    c : ndarray
        Coefficients of sigma (strictly increasing, 0 to 1).
    z : float
        ``log T`` of the profile (the caller rescales it until every row holds).
    """
    from scipy.interpolate import make_lsq_spline

    s_keys, S = dynamics.s_keys, dynamics.s_span
    problem = LawProblem(dynamics, bounds, knots_for(s_keys))
    n_seg = len(s_keys) - 1
    s = S * np.interp(
        np.linspace(0.0, n_seg, PROFILE_POINTS_PER_SEGMENT * n_seg + 1),
        np.arange(n_seg + 1),
        s_keys / S,
    )
    coef, _ = problem.coefficients(s)  # (F, 7, K)
    speed = np.geomspace(1e-3, 1e3, 241)
    poly = (
        coef[:, 0, :, None]
        + coef[:, 1, :, None] * speed
        + coef[:, 2, :, None] * speed**2
        + coef[:, 3, :, None] * speed**3
    )  # (F, K, V)
    feasible = (poly <= 0.0 + 1.0).all(axis=0)  # (K, V)
    first_bad = np.where(feasible.all(axis=1), len(speed), np.argmin(feasible, axis=1))
    top = speed[np.maximum(first_bad - 1, 0)] ** 2  # s'^2 at s'' = 0

    def accel(k, x, sign):
        d = np.sqrt(x)
        room = 1.0 - (coef[:, 0, k] + coef[:, 1, k] * d + coef[:, 2, k] * x + coef[:, 3, k] * d * x)
        a4 = sign * coef[:, 4, k]
        with np.errstate(divide="ignore", invalid="ignore"):
            limit = np.where(a4 > 1e-12, np.maximum(room, 0.0) / a4, np.inf)
        return float(limit.min())

    x = top.copy()
    ds = np.diff(s)
    for k in range(len(s) - 1):
        x[k + 1] = min(x[k + 1], x[k] + 2.0 * accel(k, x[k], 1.0) * ds[k])
    for k in range(len(s) - 1, 0, -1):
        x[k - 1] = min(x[k - 1], x[k] + 2.0 * accel(k, x[k], -1.0) * ds[k - 1])
    d = np.sqrt(np.maximum(x, speed[0] ** 2))
    t = np.concatenate([[0.0], np.cumsum(ds * 2.0 / (d[1:] + d[:-1]))])
    duration = float(t[-1])
    tau = t / duration
    knots = knots_for(np.interp(s_keys, s, tau) * S)
    try:
        c = make_lsq_spline(tau, s / S, knots, k=DEGREE).c
    except (ValueError, np.linalg.LinAlgError):
        c = greville(knots)
    c[0], c[-1] = 0.0, 1.0
    gap = _MIN_GAP * 10.0 / (len(c) - 1)
    if (np.diff(c) < gap).any():  # keep sigma increasing: blend towards sigma = tau
        lin = greville(knots)
        for w in (0.9, 0.7, 0.5, 0.3, 0.0):
            trial = w * c + (1 - w) * lin
            if (np.diff(trial) >= gap).all():
                c = trial
                break
    return knots, c, float(np.log(duration))
