"""A C3 orientation spline with globally chosen knot rates (docs/algorithm.md §8).

The blending spline's knot jerk is ``3 f''(0) |dw| / h^2``, ``dw`` the gap between
the two local curves' angular velocities at the knot. :class:`SmoothSpline`
removes the gap by choosing the angular rate and acceleration at every knot at
once, from the knot conditions of the flat C4 quintic spline (a block-tridiagonal
system solved in O(n)), then joins the knots with septic Hermite curves in the
tangent space of each segment's first keyframe, which makes the path C3 for any
knot data and the flat quintic spline when all keyframes share one axis.
Because any knot data give a C3 path, the knot choice is an option: ``knots =
"end-minimax"`` keeps the quintic's knot data but for the jerk at the two rest
ends, chosen to lower the peak jerk of the end segments, where the quintic choice
puts it; ``knots = "joint-minimax"`` then moves the knot data, a few knots at a
time, to lower the peak jerk of the gimbal's joints (the torque race in docs/results.md
measures all three).

Evaluation is closed form and vectorised: ``r(u)`` is a degree-7 polynomial per
segment and axis, and the derivatives of ``exp(r)`` follow from those of
``cos|r|`` and ``sin|r| / |r|`` as functions of ``x = r . r``.
"""

from __future__ import annotations

from fractions import Fraction
from math import comb

import numpy as np
from numpy.polynomial import polynomial as P

from . import derivatives as dv
from . import fast
from . import jet as J
from . import quat as Q
from .errors import BadArgument
from .path import OrientationPath, check_times
from .smooth_blocks import knot_system, solve_block_cyclic, solve_block_tridiagonal
from .smooth_joint_minimax import joint_minimax
from .spline import BOUNDARIES, check_closed
from .validate import check_choice

#: Knot choices: "quintic", the knot conditions of the flat C4 quintic spline (docs/
#: algorithm.md §8.2); "end-minimax", the same with the jerk at each rest end chosen to minimise
#: the peak jerk of its end segment; "joint-minimax", end-minimax's knot data improved
#: window by window to lower the peak joint-space jerk of the gimbal.
KNOTS = ("quintic", "end-minimax", "joint-minimax")

# Septic Hermite basis in the power basis (columns u^0..u^7): H_m^(k)(0) = delta_mk,
# H_m^(k)(1) = 0 for k = 0..3. Exact fractions, so that H_m(1 - u) expands exactly.
_H_EXACT = [
    [1, 0, 0, 0, -35, 84, -70, 20],
    [0, 1, 0, 0, -20, 45, -36, 10],
    [0, 0, Fraction(1, 2), 0, -5, 10, Fraction(-15, 2), 2],
    [0, 0, 0, Fraction(1, 6), Fraction(-2, 3), 1, Fraction(-2, 3), Fraction(1, 6)],
]


def _mirrored(h: list) -> np.ndarray:
    """Power-basis coefficients of ``(-1)^m H_m(1 - u)`` from those of ``H_m(u)``."""
    out = [[Fraction(0)] * len(row) for row in h]
    for m, row in enumerate(h):
        for j, c in enumerate(row):  # (1 - u)^j = sum_l C(j, l) (-u)^l
            for ell in range(j + 1):
                out[m][ell] += (-1) ** (m + ell) * comb(j, ell) * c
    return np.array(out, dtype=float)


_H = np.array(_H_EXACT, dtype=float)
_H_RIGHT = _mirrored(_H_EXACT)

#: Where (u in [0, 1]) an end segment's jerk is sampled for ``knots="end-minimax"``.
END_SAMPLES = np.linspace(0.0, 1.0, 33)


def _third_derivative_at(coefficients: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Third u-derivative of the power-basis polynomial ``coefficients`` at ``u``."""
    return P.polyval(u, P.polyder(coefficients, 3))


#: d^3/du^3 of H_3(u) and of -H_3(1 - u) at END_SAMPLES: how the end jerk enters.
_START_JERK = _third_derivative_at(_H[3], END_SAMPLES)
_STOP_JERK = _third_derivative_at(_H_RIGHT[3], END_SAMPLES)


def minimax_offset(c: np.ndarray, b: np.ndarray, prefer: np.ndarray) -> np.ndarray:
    """The ``x`` minimising ``max_s |c_s + b_s x|``, exactly, per column.

    The objective is convex and piecewise linear in ``x``; its minimum sits where two
    of the lines ``+-(c_s + b_s x)`` cross, so the crossings are the only candidates
    (O(S^2) of them). Where a whole interval is optimal (when the peak sits at a
    sample with ``b_s = 0``), the optimum nearest ``prefer`` is taken.

    Parameters
    ----------
    c : ndarray, shape (S, k)
        Values at the samples at ``x = 0``, one column per independent problem.
    b : ndarray, shape (S,)
        How each sample moves with ``x``.
    prefer : ndarray, shape (k,)
        Tie-break: among minimisers, the one nearest this.

    Returns
    -------
    ndarray, shape (k,)
    """
    s, t = np.triu_indices(len(b))
    with np.errstate(divide="ignore", invalid="ignore"):
        # c_s + b_s x = -(c_t + b_t x) and c_s + b_s x = c_t + b_t x.
        meet = -(c[s] + c[t]) / (b[s] + b[t])[:, None]
        cross = (c[t] - c[s]) / (b[s] - b[t])[:, None]
    candidates = np.concatenate([meet, cross, prefer[None]])  # (C, k)
    out = np.empty(c.shape[1])
    for col in range(c.shape[1]):
        x = candidates[:, col]
        x = x[np.isfinite(x)]
        peak = np.abs(c[:, col, None] + b[:, None] * x).max(axis=0)
        best = peak <= peak.min() * (1 + 1e-12)
        x = x[best]
        out[col] = x[np.argmin(np.abs(x - prefer[col]))]
    return out


def _with_time_derivatives(coef: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Segment coefficients of ``r_i(u)`` (n, 8, 3), ``[i, k, axis]`` multiplying
    ``u^k``, with those of its first three time derivatives (``d/dt = (1/h) d/du``),
    shape (n, 12, 8): ``[i, 3 m + axis, k]`` for the m-th derivative."""
    out = np.empty((4, *coef.shape))
    out[0] = coef
    power = np.arange(8.0)
    for m in range(1, 4):
        out[m, :, :-1] = out[m - 1, :, 1:] * power[1:, None] / h[:, None, None]
        out[m, :, -1] = 0.0
    return np.ascontiguousarray(out.transpose(1, 0, 3, 2).reshape(len(h), 12, 8))


class SmoothSpline(OrientationPath):
    """C3 orientation path through keyframes with globally chosen knot rates.

    The angular rates and accelerations at the knots are those of the flat C4
    quintic spline through the segment increments (one block-tridiagonal solve,
    O(N)); each segment is a septic Hermite curve ``exp(r(u)) q_i`` matching the
    knot jets of order 3 at both ends (docs/algorithm.md §8).

    Parameters
    ----------
    quats : array_like, shape (N, 4)
        Keyframe orientations, scalar first (w, x, y, z), any sign and norm
        (normalised here). N >= 2.
    times : array_like, shape (N,)
        Keyframe times (s), strictly increasing.
    boundary : {"rest", "natural", "closed"}, optional
        ``"rest"``: angular velocity and acceleration are zero at both ends (the
        jerk is not); ``"natural"``: free end rates chosen so that the flat spline's
        jerk and snap vanish at the ends (it starts moving); ``"closed"``: a loop
        whose last keyframe repeats the first, C3 all the way round (the knot
        solve is cyclic; times outside the range wrap). Default "rest".
    knots : {"quintic", "end-minimax", "joint-minimax"}, optional
        How the knot data are chosen. ``"quintic"``: the knot conditions of the
        flat C4 quintic spline (algorithm.md §8.2). ``"end-minimax"`` (``boundary="rest"``
        only): the same rates and accelerations everywhere and the same jerk at
        the interior knots, but the jerk at each rest end chosen, per axis of the
        space frame, to minimise the peak of that axis' tangent-space jerk over its
        end segment (sampled at :data:`END_SAMPLES`; exact, see
        :func:`minimax_offset`). It moves only the two end segments and never
        raises their sampled peak; it depends on the space frame's axes (the
        gimbal's: z is the pan axis). ``"joint-minimax"`` (``boundary="rest"``
        only): end-minimax's knot data, then rates, accelerations and jerks moved
        window by window to lower the peak jerk of the gimbal's joints (pan, tilt,
        roll, :mod:`trajgen.gimbal`), under guards on joint acceleration and tilt;
        the sampled peak joint jerk never exceeds end-minimax's (see
        :func:`trajgen.smooth_joint_minimax.joint_minimax`). It costs 0.1-1 s for
        5-20 keyframes (linear in N: minutes for thousands). Default: "end-minimax"
        when ``boundary`` is "rest" (the torque race chose it, docs/results.md), else
        "quintic".
    progress : callable, optional
        With ``knots="joint-minimax"``: called with the fraction of the optimisation
        done (0..1), a few dozen times over the build.

    Raises
    ------
    ValueError, TypeError
        For bad shapes or values, naming the argument and what arrived.

    Notes
    -----
    Unlike :class:`~trajgen.spline.BlendingSpline`, the spline is global: moving
    one keyframe moves every segment, with an effect that decays by 2-3x per knot
    (measured). Times outside ``[t_start, t_end]`` raise (they wrap when closed).

    References
    ----------
    ``docs/algorithm.md`` §8 states the construction.
    """

    def __init__(self, quats, times, *, boundary="rest", knots=None, progress=None):
        q = Q.as_quats(quats, "quats")
        n = len(q)
        if n < 2:
            raise BadArgument(f"Expected at least 2 keyframes, got {n}.")
        self.times = check_times(times, n)
        self.boundary = check_choice("boundary", boundary, BOUNDARIES)
        if knots is None:
            knots = "end-minimax" if boundary == "rest" else "quintic"
        #: The knot choice, one of :data:`KNOTS`.
        self.knots = check_choice("knots", knots, KNOTS)
        if knots != "quintic" and boundary != "rest":
            raise BadArgument(
                f"knots={knots!r} needs boundary='rest' (the ends it chooses the jerk "
                f"at), got boundary={boundary!r}."
            )
        if boundary == "natural" and n < 3:
            # One segment with free ends: every parabola has zero jerk and snap,
            # so the knot rates are not determined.
            raise BadArgument(f"boundary='natural' needs at least 3 keyframes, got {n}.")
        if boundary == "closed":
            check_closed(q)
        self.periodic = boundary == "closed"
        # docs/algorithm.md §1: one sign per consecutive pair, the shortest geodesic: q_i flips by
        # the product of the signs of q_j . q_{j-1} up to i.
        flips = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0
        q[1:] *= np.cumprod(np.where(flips, -1.0, 1.0))[:, None]
        self.quats = q
        h = np.diff(self.times)
        D = Q.log(Q.mul(q[1:], Q.conj(q[:-1])))
        v, a, j = self._knot_rates(D, h)
        poly = self._segment_coefficients(D, h, v, a, j)
        if knots != "quintic":
            j, poly = self._end_minimax(h, j, poly)
        if knots == "joint-minimax":
            v, a, j, poly = joint_minimax(
                q, D, h, (v, a, j), poly, self._segment_coefficients, progress
            )
        #: Knot angular rate, acceleration and jerk of the tangent-space jets (N, 3).
        self.knot_rates = (v, a, j)
        self._h = h
        self._poly = poly

    def _knot_rates(self, D, h):
        n = len(D) + 1
        system = knot_system(D, h, self.boundary)
        v, a = np.zeros((n, 3)), np.zeros((n, 3))
        if self.boundary == "rest":
            x = solve_block_tridiagonal(*system)
            v[1:-1], a[1:-1] = x[:, 0], x[:, 1]
        elif self.boundary == "closed":  # knot n - 1 is knot 0
            x = solve_block_cyclic(*system)
            v[:-1], a[:-1] = x[:, 0], x[:, 1]
            v[-1], a[-1] = v[0], a[0]
        else:
            x = solve_block_tridiagonal(*system)
            v, a = x[:, 0], x[:, 1]
        hc = h[:, None]
        # j_i = J0_i, j_{n-1} = J1_{n-2}.
        j = np.empty((n, 3))
        j[:-1] = (
            60 * D - (36 * v[:-1] + 24 * v[1:]) * hc - (9 * a[:-1] - 3 * a[1:]) * hc**2
        ) / hc**3
        j[-1] = (
            60 * D[-1] - (24 * v[-2] + 36 * v[-1]) * h[-1] + (9 * a[-1] - 3 * a[-2]) * h[-1] ** 2
        ) / h[-1] ** 3
        return v, a, j

    def _end_minimax(self, h, j, poly):
        """Knot jerks (N, 3) and segment coefficients with each rest end's jerk chosen
        minimax (``knots="end-minimax"``), from the quintic choice's ``j`` and ``poly``.

        ``r_i(u)`` is linear in the knot data ``L`` and ``R``. First segment: ``L_3 =
        j_0`` (``v = a = 0`` there), so ``r'''(u) = base(u) + j_0 H_3'''(u)``: one
        minimax in one variable per axis (:func:`minimax_offset`). Last segment: the
        end jerk enters only through ``R_3``, the third derivative of
        ``log(exp(j tau^3 / 6) exp(D))`` at ``tau = 0``, which is linear, ``R_3 = M j``:
        the minimax is taken over ``R_3``, then ``j = M^-1 R_3``. Neither choice can
        raise the sampled peak it minimises; the two end segments' coefficients change
        by the linear terms, all others stay. ``j`` and ``poly`` are updated in place.

        With two keyframes both ends share one segment, and choosing one end with
        the other held would stall (each end's peak sits at the other end). There
        ``j_0 = R_3`` is chosen as one unknown, the symmetric choice the flat optimum
        takes: peak jerk 38.6 D / T^3 against 60 for the quintic choice and 32 for
        the bang-bang bound.
        """
        step = Q.mul(self.quats[-1], Q.conj(self.quats[-2]))[:, None]  # (4, 1) = exp(D)
        none = np.zeros((3, 3))
        M = self._right_data(np.repeat(step, 3, axis=1), none, none, np.eye(3))[3].T
        powers = END_SAMPLES[:, None] ** np.arange(8)  # (S, 8)
        first, last = (poly[i, 9:12] @ powers.T for i in (0, -1))  # r''' (3, S)
        j0, r3 = j[0].copy(), M @ j[-1]
        if len(h) == 1:
            base = first.T - _START_JERK[:, None] * j0 - _STOP_JERK[:, None] * r3
            j[0] = new_r3 = minimax_offset(base, _START_JERK + _STOP_JERK, (j0 + r3) / 2)
        else:
            j[0] = minimax_offset(first.T - _START_JERK[:, None] * j0, _START_JERK, j0)
            base = last.T - _STOP_JERK[:, None] * r3
            new_r3 = minimax_offset(base, _STOP_JERK, r3)
        j[-1] = np.linalg.solve(M, new_r3)
        # r gains h^3 (L_3 change) H_3(u) and h^3 (R_3 change) (-H_3(1 - u)).
        for i, change, basis in ((0, j[0] - j0, _H[3]), (-1, new_r3 - r3, _H_RIGHT[3])):
            coef = h[i] ** 3 * basis[None, :, None] * change[None, None, :]  # (1, 8, 3)
            poly[i] += _with_time_derivatives(coef, h[[i]])[0]
        return j, poly

    @staticmethod
    def _right_data(step, v, a, j) -> np.ndarray:
        """``R_m``, m = 0..3, shape (4, k, 3): the time derivatives at ``tau = 0`` of
        ``log(exp(v tau + a tau^2 / 2 + j tau^3 / 6) step)``, by jets in ``tau``.

        ``step`` (4, k) is each segment's ``exp(D_i)``; ``v``, ``a``, ``j`` (k, 3) the
        knot data at its right end.
        """
        c = np.zeros((4, 3, len(v)))
        c[1], c[2], c[3] = v.T, a.T / 2, j.T / 6
        with np.errstate(over="ignore", invalid="ignore"):  # qlog's unused branch at w = 0
            R = J.qlog(J.qmul(J.qexp(J.Jet(c)), step))
        return np.stack([R.derivative(m).T for m in range(4)])

    def _segment_coefficients(self, D, h, v, a, j) -> np.ndarray:
        """Power-basis coefficients of ``r_i(u)`` and of its first three time
        derivatives, shape (n - 1, 12, 8): ``[i, 3 m + axis, k]`` multiplies ``u^k``
        in the m-th derivative. ``v``, ``a``, ``j`` are (n, 3), or (P, n, 3) for P
        sets of knot data at once (then the result is (P (n - 1), 12, 8), set by set)."""
        q = self.quats
        P = v.size // v.shape[-2] // 3
        # R_m: time derivatives at t_{i+1} of log(K_{i+1}(t) q_i*).
        step = np.tile(Q.mul(q[1:], Q.conj(q[:-1])).T, P)  # (4, P (n - 1)) = exp(D_i)
        left, right = (
            [d.reshape(P, -1, 3)[:, ends].reshape(-1, 3) for d in (v, a, j)]
            for ends in (slice(None, -1), slice(1, None))
        )
        R = self._right_data(step, *right)  # (4, P (n - 1), 3)
        R[0] = np.tile(D, (P, 1))  # the same value; keep the exact increment
        L = np.stack([np.zeros_like(left[0]), *left])
        h = np.tile(h, P)
        hm = h[None, :, None] ** np.arange(4)[:, None, None]  # (4, P (n - 1), 1)
        coef = np.einsum("mis,mk->iks", hm * L, _H) + np.einsum("mis,mk->iks", hm * R, _H_RIGHT)
        return _with_time_derivatives(coef, h)

    @property
    def tangent_coefficients(self) -> np.ndarray:
        """Power-basis coefficients of each segment's ``r_i(u)`` and of its time
        derivatives, shape (n - 1, 12, 8): ``[i, 3 m + axis, k]`` multiplies ``u^k``,
        ``u = (t - times[i]) / (times[i + 1] - times[i])``, in the m-th time derivative
        (m = 0..3, already scaled by ``1 / h^m``). On segment i the path is
        ``exp(r_i(u)) quats[i]``. Read-only; the per-frame stream
        (:mod:`trajgen.frame_eval`) evaluates it one time at a time."""
        view = self._poly.view()
        view.flags.writeable = False
        return view

    def _tangent(self, t, seg, max_order) -> np.ndarray:
        """``r_i(u)`` and its time derivatives 1..max_order at times ``t`` (M,) in
        segments ``seg`` (M,), shape (max_order + 1, 3, M)."""
        M = len(t)
        U = np.empty((8, M))  # powers of u
        U[0] = 1.0
        np.divide(t - self.times[seg], self._h[seg], out=U[1])
        for k in range(2, 8):
            np.multiply(U[k - 1], U[1], out=U[k])
        poly = self._poly[:, : 3 * (max_order + 1)]
        steps = np.diff(seg)
        starts = np.flatnonzero(steps) + 1
        if (steps >= 0).all() and 16 * len(starts) < M:
            # Sorted times, many samples per segment: one small matmul per segment.
            out = np.empty((poly.shape[1], M))
            bounds = [0, *starts.tolist(), M]
            for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
                out[:, lo:hi] = poly[seg[lo]] @ U[:, lo:hi]
        else:
            out = np.einsum("mrk,km->rm", poly[seg], U)
        return out.reshape(max_order + 1, 3, M)

    def _space_rates(self, t, seg, max_order):
        """Unit quaternions (M, 4) and space-frame angular derivatives of orders
        1..max_order (each (M, 3)), in closed form.

        ``q = E q_i`` with ``E = exp(r) = (C(x), S(x) r)``, ``x = r . r``, ``C`` and
        ``S`` the cosine and sinc of ``sqrt x``, and ``q_i`` fixed on a segment, so
        ``omega = 2 vec(E' E*)``, ``alpha = 2 vec(E'' E*)`` (``E' E'*`` is a scalar)
        and ``jerk = 2 vec(E''' E* + E'' E'*)``.
        """
        if fast.samplewise(len(t)):
            q, rates = fast.evaluate_smooth(self, t, seg)
            return q, list(rates[:max_order])
        r = list(self._tangent(t, seg, max_order))
        C, S = dv.cos_sinc_sqrt(dv.vdot(r, r))
        E = [np.concatenate([c[None], v]) for c, v in zip(C, dv.product(S, r), strict=True)]
        q = Q.mul(E[0].T, self.quats[seg])
        conj = [e * _CONJ for e in E[: 2 if max_order >= 3 else 1]]
        rates = [2.0 * dv.hamilton_vec(E[m], conj[0]).T for m in range(1, min(max_order, 2) + 1)]
        if max_order >= 3:
            jerk = dv.hamilton_vec(E[3], conj[0]) + dv.hamilton_vec(E[2], conj[1])
            rates.append(2.0 * jerk.T)
        return q, rates


_CONJ = np.array([1.0, -1.0, -1.0, -1.0])[:, None]
