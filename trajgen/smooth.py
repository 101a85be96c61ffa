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
from .gimbal import angles_of
from .path import OrientationPath, check_times
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


#: Where (u in [0, 1]) each segment's joint jerk is sampled for ``knots="joint-minimax"``.
JOINT_SAMPLES = np.linspace(0.0, 1.0, 33)
#: Most passes of the knot-by-knot descent over all knots (``knots="joint-minimax"``).
JOINT_SWEEPS = 4
#: Widths (knots) of the windows the descent moves together, in turn.
JOINT_WIDTHS = (1, 2)
#: Backtracking: a rejected step is retried this many times at half the length.
JOINT_HALVINGS = 2
#: How far (rad) a step may take |tilt| beyond the keyframes' largest |tilt|.
TILT_MARGIN_RAD = np.radians(15.0)
#: Most samples (segments x JOINT_SAMPLES x perturbed copies) measured at once.
MEASURE_SAMPLES = 200_000
#: How far a step may take each joint's peak acceleration beyond the start path's.
ACCELERATION_SLACK = 1.035


def joint_motion(poly: np.ndarray, starts: np.ndarray, u: np.ndarray):
    """Joint accelerations, jerks and tilts along segments of a :class:`SmoothSpline`,
    exactly, by jets.

    Parameters
    ----------
    poly : ndarray, shape (k, 12, 8)
        Segment coefficients (:attr:`SmoothSpline.tangent_coefficients` layout).
    starts : ndarray, shape (k, 4)
        Each segment's first keyframe ``q_i``.
    u : ndarray, shape (S,)
        Where to sample, in [0, 1].

    Returns
    -------
    acceleration : ndarray, shape (k, 3, S)
        Second time derivatives (rad/s^2) of pan, tilt and roll (``Rz Ry Rx``,
        :mod:`trajgen.gimbal`); only cos and sin of the angles enter, so the branch
        of pan and roll does not matter.
    jerk : ndarray, shape (k, 3, S)
        Third time derivatives (rad/s^3).
    tilt : ndarray, shape (k, S)
        Tilt (rad).
    """
    k, S = len(poly), len(u)
    rows = np.einsum("irk,sk->ris", poly, u[:, None] ** np.arange(8))  # (12, k, S)
    # Taylor coefficients in time: the m-th time derivative over m!.
    c = rows.reshape(4, 3, k * S) / np.array([1.0, 1.0, 2.0, 6.0])[:, None, None]
    q = J.qmul(J.qexp(J.Jet(c)), np.repeat(starts, S, axis=0).T)
    angles = angles_of(
        *(J.Jet(q.c[:, m]) for m in range(4)), J.arctan2, lambda x, y: J.sqrt(x * x + y * y)
    )
    acceleration, jerk = (
        np.stack([x.derivative(order) for x in angles]).reshape(3, k, S).transpose(1, 0, 2)
        for order in (2, 3)
    )
    return acceleration, jerk, angles[1].value.reshape(k, S)


def minimax_step(c: np.ndarray, B: np.ndarray, iterations: int = 100) -> np.ndarray:
    """Per row, an ``x`` (near-)minimising ``max_s |c_s + B_s . x|``, by Lawson's
    iteratively reweighted least squares (weights ``w_s <- w_s |r_s|``, normalised),
    slightly damped.

    Parameters
    ----------
    c : ndarray, shape (k, m)
    B : ndarray, shape (k, m, d)
    iterations : int

    Returns
    -------
    ndarray, shape (k, d)
    """
    k, m, d = B.shape
    w = np.full((k, m), 1.0 / m)
    Bt = B.transpose(0, 2, 1)
    scale = np.maximum((B * B).sum(axis=(1, 2)) / m, 1e-300)
    # Damping, 1e-6 of the mean squared column: directions the samples hardly see get
    # no step (zero columns none), so the step does not hang on rounding (at 1e-12,
    # reordering the columns moved single race cases by up to 0.3x the bound).
    ridge = 1e-6 * scale[:, None, None] * np.eye(d)
    for _ in range(iterations):
        Btw = Bt * w[:, None, :]
        x = np.linalg.solve(Btw @ B + ridge, -(Btw @ c[..., None]))
        w = w * np.abs(c + (B @ x)[..., 0])
        w = np.maximum(w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300), 1e-15)
    return x[..., 0]


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


def knot_system(D: np.ndarray, h: np.ndarray, boundary: str = "rest"):
    """Blocks of the knot-rate system (docs/algorithm.md §8.2), symmetric positive definite.

    The unknowns at each free knot are ``(v, a)``; the rows are the snap condition
    (``S0_i - S1_{i-1} = 0``) and the jerk condition (``J1_{i-1} - J0_i = 0``), the
    gradient of the flat spline's integral of squared jerk, so the matrix is SPD and
    block elimination needs no pivoting.

    Parameters
    ----------
    D : ndarray, shape (n - 1, 3)
        Segment increments ``log(q_{i+1} q_i*)``.
    h : ndarray, shape (n - 1,)
        Segment durations (s).
    boundary : {"rest", "natural", "closed"}
        ``"rest"``: ``v = a = 0`` at both ends (free knots 1..n-2); ``"natural"``:
        free ends with zero jerk and snap (free knots 0..n-1); ``"closed"``: knot
        n-1 is knot 0 (free knots 0..n-2), and the last segment couples them.

    Returns
    -------
    diag : ndarray, shape (m, 2, 2)
    upper : ndarray, shape (m - 1, 2, 2), or (m, 2, 2) when closed
        Block coupling knot ``k`` to ``k + 1``; the lower blocks are its transposes.
        When closed the last one couples knot m - 1 to knot 0.
    rhs : ndarray, shape (m, 2, 3)
    """
    h = h[:, None, None]
    # Segment i's share of the diagonal block at its left / right knot, its
    # coupling block (rows: left knot, columns: right knot) and right-hand sides.
    left = np.concatenate([192 / h**3, 36 / h**2, 36 / h**2, 9 / h], axis=2).reshape(-1, 2, 2)
    right = left * np.array([[1, -1], [-1, 1]])
    upper = np.concatenate([168 / h**3, -24 / h**2, 24 / h**2, -3 / h], axis=2).reshape(-1, 2, 2)
    b_left = np.stack([360 * D / h[..., 0] ** 4, 60 * D / h[..., 0] ** 3], axis=1)
    b_right = b_left * np.array([1, -1])[:, None]
    n = len(D) + 1
    diag = np.zeros((n, 2, 2))
    diag[:-1] += left
    diag[1:] += right
    rhs = np.zeros((n, 2, 3))
    rhs[:-1] += b_left
    rhs[1:] += b_right
    if boundary == "rest":
        return diag[1:-1], upper[1:-1], rhs[1:-1]
    if boundary == "closed":
        diag[0] += diag[-1]
        rhs[0] += rhs[-1]
        return diag[:-1], upper, rhs[:-1]
    return diag, upper, rhs


def solve_block_tridiagonal(diag, upper, rhs) -> np.ndarray:
    """Solve a symmetric block-tridiagonal system with 2x2 blocks by block cyclic
    reduction, O(m) work in O(log m) vectorised steps.

    Each step eliminates the odd-numbered unknowns from the even-numbered rows
    (a Schur complement, symmetric positive definite again when the system is),
    solves the half-size system the same way, then recovers the odd unknowns. For
    an SPD system this is Gaussian elimination in another order: stable without
    pivoting.

    Parameters
    ----------
    diag : ndarray, shape (m, 2, 2)
    upper : ndarray, shape (m - 1, 2, 2)
        Super-diagonal blocks; the sub-diagonal blocks are their transposes.
    rhs : ndarray, shape (m, 2, c)

    Returns
    -------
    ndarray, shape (m, 2, c)
    """
    m = len(rhs)
    if m <= 1:
        return np.linalg.solve(diag, rhs) if m else rhs.copy()
    # Couplings of each row to the row after (``right``) and before (``left``),
    # zero past the ends.
    right = np.zeros_like(diag)
    right[:-1] = upper
    left = np.zeros_like(diag)
    left[1:] = upper.transpose(0, 2, 1)
    odd = slice(1, None, 2)
    inv = np.linalg.inv(diag[odd])
    to_left, to_right, rest = inv @ left[odd], inv @ right[odd], inv @ rhs[odd]
    # x_odd = rest - to_left x_before - to_right x_after; padded so that the even
    # rows at either end see zeros where they have no odd neighbour.
    pad = np.zeros((1, 2, 2))
    n_even = (m + 1) // 2
    before_left, before_right = (np.concatenate([pad, a])[:n_even] for a in (to_left, to_right))
    after_left, after_right = (np.concatenate([a, pad])[:n_even] for a in (to_left, to_right))
    before_rest = np.concatenate([np.zeros((1, *rhs.shape[1:])), rest])[:n_even]
    after_rest = np.concatenate([rest, np.zeros((1, *rhs.shape[1:]))])[:n_even]
    even = slice(0, None, 2)
    el, er = left[even], right[even]
    x_even = solve_block_tridiagonal(
        diag[even] - el @ before_right - er @ after_left,
        -(er @ after_right)[:-1],
        rhs[even] - el @ before_rest - er @ after_rest,
    )
    x = np.empty_like(rhs)
    x[even] = x_even
    after = np.concatenate([x_even[1:], np.zeros((1, *rhs.shape[1:]))])[: m // 2]
    x[odd] = rest - to_left @ x_even[: m // 2] - to_right @ after
    return x


def solve_block_cyclic(diag, upper, rhs) -> np.ndarray:
    """Solve a symmetric block-tridiagonal system with the corner blocks of a loop, O(m).

    ``A = T + E G E^T``: ``T`` the system without the corners (the block solve above), ``E``
    picks knots 0 and m - 1, ``G = [[0, W^T], [W, 0]]`` with ``W = upper[-1]`` (row
    knot m - 1, column knot 0). Woodbury: ``x = y - Z (I + G E^T Z)^-1 G E^T y``
    with ``T y = b``, ``T Z = E``, both from one block solve.

    Parameters
    ----------
    diag : ndarray, shape (m, 2, 2)
    upper : ndarray, shape (m, 2, 2)
    rhs : ndarray, shape (m, 2, c)

    Returns
    -------
    ndarray, shape (m, 2, c)
    """
    m, b, c = rhs.shape
    E = np.zeros((m, b, 2 * b))
    E[0, :, :b] = np.eye(b)
    E[-1, :, b:] += np.eye(b)
    solved = solve_block_tridiagonal(diag, upper[:-1], np.concatenate([rhs, E], axis=2))
    y, Z = solved[..., :c], solved[..., c:]
    G = np.zeros((2 * b, 2 * b))
    G[:b, b:], G[b:, :b] = upper[-1].T, upper[-1]
    EtZ = np.concatenate([Z[0], Z[-1]])  # (2b, 2b)
    Ety = np.concatenate([y[0], y[-1]])  # (2b, c)
    correction = np.linalg.solve(np.eye(2 * b) + G @ EtZ, G @ Ety)
    return y - np.einsum("kij,jc->kic", Z, correction)


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
        ``_joint_minimax``). It costs 0.1-1 s for 5-20 keyframes (linear in N:
        minutes for 10,000). Default: "end-minimax" when ``boundary`` is "rest"
        (the torque race chose it, docs/results.md), else "quintic".

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

    def __init__(self, quats, times, *, boundary="rest", knots=None):
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
            v, a, j, poly = self._joint_minimax(D, h, (v, a, j), poly)
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

    def _joint_minimax(self, D, h, knot_data, poly):
        """Knot data ``(v, a, j)`` (each (N, 3)) and segment coefficients ``poly``
        improved window by window to lower the peak joint jerk (``knots="joint-minimax"``).

        A knot's data enter only its two adjacent segments, so windows of
        ``width`` consecutive knots (:data:`JOINT_WIDTHS`) ``width + 1`` knots apart
        touch disjoint segments and are improved at once and independently. Per
        window: the sampled joint jerks of the segments it touches (:func:`joint_motion`
        at :data:`JOINT_SAMPLES`) are linearised in its knot data (forward differences),
        the linear model's minimax step is taken (:func:`minimax_step`), and the step
        is kept only if the true sampled peak jerk over those segments drops, their
        peak acceleration of each joint stays within :data:`ACCELERATION_SLACK` times
        the start path's (at least 1% of the busiest joint's; or does not grow),
        and their |tilt| within the keyframes' largest + :data:`TILT_MARGIN_RAD` (or
        does not grow); else it is halved, at most :data:`JOINT_HALVINGS` times. A
        window's peak only drops and the segments outside it stay, so the path's
        sampled peak joint jerk never rises: never worse than the start (end-minimax)
        on that objective. Passes repeat until no segment's peak drops by 0.1%,
        at most :data:`JOINT_SWEEPS` times. Rest ends keep ``v = a = 0``.
        """
        n = len(h) + 1
        x = np.stack(knot_data)  # (3, N, 3): [kind, knot, axis]
        starts = self.quats[:-1]

        def measure(xs):
            """Per segment, for each of the P sets of knot data ``xs`` (P, 3, N, 3): its
            peak |acceleration| per joint, its sampled jerks (3 S) and its peak |tilt|."""
            P = len(xs)
            poly = self._segment_coefficients(D, h, xs[:, 0], xs[:, 1], xs[:, 2])
            acc, jerk, tilt = joint_motion(poly, np.tile(starts, (P, 1)), JOINT_SAMPLES)
            return (
                np.abs(acc).max(axis=2).reshape(P, n - 1, 3),
                jerk.reshape(P, n - 1, -1),
                np.abs(tilt).max(axis=1).reshape(P, n - 1),
            )

        # A trial through gimbal lock gives NaN or inf, which no comparison accepts.
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            state = [m[0] for m in measure(x[None])]  # acceleration, jerk, tilt per segment
            # A joint that hardly moves may still reach 1% of the busiest joint's peak.
            peak_acc = state[0].max(axis=0)
            caps = (
                ACCELERATION_SLACK * np.maximum(peak_acc, 1e-2 * peak_acc.max()),
                np.abs(angles_of(*self.quats.T, np.arctan2, np.hypot)[1]).max() + TILT_MARGIN_RAD,
            )
            for _ in range(JOINT_SWEEPS):
                start_peak = np.abs(state[1]).max(axis=1)
                for width in JOINT_WIDTHS:
                    for offset in range(width + 1):
                        self._joint_window_step(x, state, measure, caps, width, offset)
                if (np.abs(state[1]).max(axis=1) > 0.999 * start_peak).all():
                    break
        # Segments whose knot data did not change keep their coefficients bit for bit.
        changed = (x != np.stack(knot_data)).any(axis=(0, 2))
        changed = changed[:-1] | changed[1:]
        poly = poly.copy()
        poly[changed] = self._segment_coefficients(D, h, *x)[changed]
        return *x, poly

    def _joint_window_step(self, x, state, measure, caps, width, offset):
        """One linearised minimax step for every window of ``width`` consecutive knots
        starting at ``offset`` modulo ``width + 1`` (windows touch disjoint segments).

        ``x`` (3, N, 3) knot data and ``state`` (per segment: peak |acceleration| (N -
        1,), sampled jerks (N - 1, 3 S), peak |tilt| (N - 1,)) are updated in place
        where a window's step is kept; ``caps``: the peak |acceleration| and |tilt| a
        step may reach.
        """
        n = x.shape[1]
        first = np.arange(offset, n, width + 1)
        if not len(first):
            return
        window = first[:, None] + np.arange(width)  # (K, width) knots
        valid = window < n
        window = np.minimum(window, n - 1)
        # Window k touches segments first[k] - 1 .. first[k] + width - 1: rows first[k]
        # .. first[k] + width of the per-segment arrays padded with one row before.
        rows = first[:, None] + np.arange(width + 1)

        def touched(per_segment):
            pad = np.zeros_like(per_segment[:1])
            padded = np.concatenate([pad, per_segment, *[pad] * width])
            return padded[rows].reshape(len(first), -1)

        # Coordinates (position in window, kind: 0 rate, 1 acceleration, 2 jerk, axis);
        # rest ends move only their jerk.
        coords = [(p, kind, axis) for p in range(width) for kind in range(3) for axis in range(3)]
        free = np.stack(
            [
                valid[:, p] & ((kind == 2) | ((window[:, p] > 0) & (window[:, p] < n - 1)))
                for p, kind, _ in coords
            ],
            axis=1,
        )  # (K, d)
        trials = np.repeat(x[None], len(coords), axis=0)
        deltas = np.array(
            [1e-6 * (1.0 + np.abs(x[kind, :, axis]).max()) for _, kind, axis in coords]
        )
        for col, (p, kind, axis) in enumerate(coords):
            trials[col, kind, window[free[:, col], p], axis] += deltas[col]
        jerk = touched(state[1])
        # Perturbed paths measured in chunks of at most MEASURE_SAMPLES samples.
        chunk = max(1, MEASURE_SAMPLES // (n * len(JOINT_SAMPLES)))
        moved = np.stack(
            [
                touched(m)
                for i in range(0, len(coords), chunk)
                for m in measure(trials[i : i + chunk])[1]
            ],
            axis=2,
        )  # (K, 3 S (width + 1), d)
        B = np.where(free[:, None], (moved - jerk[..., None]) / deltas, 0.0)
        step = minimax_step(jerk, B) * free
        peak = np.abs(jerk).max(axis=1)

        def joint_peak(acc):
            """Per window and joint, the peak |acceleration| over its segments (K, 3)."""
            return acc.reshape(len(first), width + 1, 3).max(axis=1)

        old_acc, old_tilt = joint_peak(touched(state[0])), touched(state[2]).max(axis=1)
        pending = np.ones(len(first), dtype=bool)
        for _ in range(JOINT_HALVINGS + 1):
            trial = x.copy()
            for col, (p, kind, axis) in enumerate(coords):
                trial[kind, window[pending, p], axis] += step[pending, col]
            new = [m[0] for m in measure(trial[None])]
            acc, tilt = joint_peak(touched(new[0])), touched(new[2]).max(axis=1)
            ok = (
                pending
                & (np.abs(touched(new[1])).max(axis=1) < peak)
                & ((acc <= caps[0]) | (acc <= old_acc)).all(axis=1)
                & ((tilt <= caps[1]) | (tilt <= old_tilt))
            )
            knots = window[ok][valid[ok]]
            x[:, knots] = trial[:, knots]
            segments = (rows[ok] - 1).ravel()
            segments = segments[(segments >= 0) & (segments < n - 1)]
            for old, changed in zip(state, new, strict=True):
                old[segments] = changed[segments]
            pending &= ~ok
            step /= 2
            if not pending.any():
                break

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
