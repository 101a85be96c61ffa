"""The splice of an online change: a segment ``exp(r(u)) q_a`` that takes over from
the old path at ``s`` to order k + 1 and meets the new spline at ``T_1`` to order k.

Part of :mod:`trajgen.online` (see its docstring for the construction): the
spliced segment (:class:`Splice`, evaluated as jets, in closed form, per frame in
floats) and the series it is built from (the old path's Taylor coefficients from
its rates, ``exp`` and ``log`` near the identity, the local curve's ``log`` at
``T_1``, the Hermite solve for the top coefficients).
"""

from __future__ import annotations

import math
from functools import cached_property
from math import comb, factorial

import numpy as np

from . import derivatives as D
from . import jet as J
from . import per_sample as P
from .errors import BadArgument
from .frame_eval import exp_frame
from .path import OrientationPath
from .spline import CONJ

#: ``C(j, n)`` for the Taylor shift of a splice's polynomial (degree 2k + 2 <= 8), (9, 9).
BINOMIAL = np.array([[comb(j, n) for j in range(9)] for n in range(9)], float)


class Splice(OrientationPath):
    """A spliced segment: ``exp(r(u)) q_a``, ``u = (t - s) / h``, ``r`` a polynomial in ``u``."""

    def __init__(self, s: float, h: float, q_a: np.ndarray, coef: np.ndarray):
        self.s, self.h = s, h
        self.q_a = q_a  # (4,)
        self.coef = coef  # (2k + 3, 3), power basis in u
        self.times = np.array([s, s + h])

    def _jet(self, t: np.ndarray, seg, order: int) -> J.Jet:
        u = (J.Jet.variable(t, order) - self.s) * (1.0 / self.h)
        r = J.Jet(np.stack([J.polyval(self.coef[:, i], u).c for i in range(3)], axis=1))
        return J.qmul(J.qexp(r), self.q_a)

    def taylor(self, t: float, order: int) -> tuple[np.ndarray, np.ndarray]:
        """``q(t)`` (4,) and the Taylor coefficients (order + 1, 4) of ``q(t + tau) q(t)*``:
        ``r`` shifted to ``t`` and ``exp`` as one series (no array of samples)."""
        # r^(n)(t) / n! = h^-n sum_j C(j, n) u^(j - n) coef_j: the polynomial shifted to u.
        u = (t - self.s) / self.h
        n, j = np.ogrid[: order + 1, : len(self.coef)]
        shift = BINOMIAL[: order + 1, : len(self.coef)] * u ** np.maximum(j - n, 0)
        r = (shift @ self.coef) * (1.0 / self.h) ** n  # (order + 1, 3)
        e = qexp_series(J.Jet(r))  # (order + 1, 4)
        e0 = e[:1].T  # (4, 1)
        return D.hamilton(e0, self.q_a[:, None])[:, 0], D.hamilton(e.T, e0 * CONJ).T

    def _space_rates(self, t, seg, max_order):
        """The same path as :meth:`_jet`, in closed form (as the spline's blends): ``r`` and
        its time derivatives from the powers of ``u``, ``exp`` by the rules of
        :mod:`trajgen.derivatives`; the rates are those of ``exp(r)`` (``q_a`` is fixed)."""
        u = (t - self.s) * (1.0 / self.h)
        powers = u[:, None] ** np.arange(len(self.coef))  # (M, 2k + 3)
        r = [(powers[:, : len(c)] @ c).T for c in self._derivative_coefs[: max_order + 1]]
        return exp_rates(r, self.q_a)

    def frame(self, t: float) -> tuple[tuple, tuple, tuple]:
        """Orientation, angular velocity (rad/s) and acceleration (rad/s^2) at one time
        ``t`` (s), in floats (:func:`~trajgen.frame_eval.exp_frame`): the per-frame
        counterpart of :meth:`_space_rates`."""
        return exp_frame(*self._r_values(t, 3), self._q_a_floats)

    def rates(self, t: float) -> tuple[np.ndarray, list[np.ndarray]]:
        """``q`` (4,) and the space-frame angular velocity, acceleration and jerk (each
        (3,)) at one time ``t`` (s), in floats (:mod:`trajgen.per_sample`)."""
        v = self._r_values(t, 4)
        E = P.exp_of(*(tuple(v[3 * n + i] for n in range(4)) for i in range(3)))
        out = np.empty((3, 1, 3))
        P.space_rates(E, 0, out)
        q = P.hamilton(tuple(e[0] for e in E), self._q_a_floats)
        return np.array(q), list(out[:, 0])

    def _r_values(self, t: float, orders: int) -> list[float]:
        """``r`` and its first ``orders - 1`` time derivatives per axis at ``t`` (s), by
        Horner, order-major (``r_x, r_y, r_z, r'_x, ...``)."""
        u = (t - self.s) * (1.0 / self.h)
        values = []
        for row in self._rows[: 3 * orders]:
            acc = 0.0
            for c in row:
                acc = acc * u + c
            values.append(acc)
        return values

    @cached_property
    def _rows(self) -> list[list[float]]:
        """Power-basis coefficients of ``r`` and its time derivatives up to order 3 per
        axis (12 rows, order-major), highest power first."""
        return [c[::-1, i].tolist() for c in self._derivative_coefs for i in range(3)]

    @cached_property
    def _q_a_floats(self) -> list[float]:
        return self.q_a.tolist()

    @cached_property
    def _derivative_coefs(self) -> list[np.ndarray]:
        """Power-basis coefficients in ``u`` of ``d^n r / dt^n``, n = 0..3, each (D - n, 3)."""
        out, c = [self.coef], self.coef
        for _ in range(3):
            c = c[1:] * (np.arange(1.0, len(c))[:, None] / self.h)
            out.append(c)
        return out


def exp_rates(r: list, q_a: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Unit quaternions (M, 4) and space-frame rates of orders 1..K (each (M, 3)) of
    ``exp(r(t)) q_a`` from ``[r, dr/dt, ...]`` (K + 1 arrays (3, M), K <= 3; any
    ``r`` per sample, e.g. several splices at once) and ``q_a`` (4,)."""
    cos_a, sinc = D.cos_sinc_sqrt(D.vdot(r, r))
    e = [np.concatenate([ca[None], v]) for ca, v in zip(cos_a, D.product(sinc, r), strict=True)]
    _, rates = rates_of(e)
    q = D.hamilton(e[0], q_a[:, None])
    return (q / np.sqrt(D.vdot([q], [q])[0])).T, rates


def rates_of(derivs: list) -> tuple[np.ndarray, list[np.ndarray]]:
    """Unit quaternions (M, 4) and space-frame rates of orders 1..K, each (M, 3), from the
    derivative list ``[Q, Q', ...]`` (each (4, M)) of a unit quaternion path, K <= 3:
    ``omega = 2 vec(Q' Q*)``, ``alpha = 2 vec(Q'' Q*)``, ``jerk = 2 vec(Q''' Q* + Q'' Q'*)``."""
    q = derivs[0] / np.sqrt(D.vdot(derivs[:1], derivs[:1])[0])
    q_conj = q * CONJ
    rates = [2.0 * D.hamilton_vec(d, q_conj) for d in derivs[1:]]
    if len(rates) >= 3:
        rates[2] += 2.0 * D.hamilton_vec(derivs[2], derivs[1] * CONJ)
    return q.T, [x.T for x in rates]


def taylor_from_rates(rates: list) -> np.ndarray:
    """Taylor coefficients (K + 1, 4) of ``d(tau) = q(t + tau) q(t)*`` from the space-frame
    rates ``omega, alpha, jerk`` at ``t`` (each (3,), K = len(rates) <= 3), using
    ``d' = omega d / 2`` (``omega`` as a pure quaternion) differentiated: ``d(0) = 1``,
    ``d^(n+1) = 1/2 sum_j C(n, j) omega^(j) d^(n-j)``. Plain floats: a handful of
    quaternion products, each far cheaper than a numpy call."""
    w = [(0.0, *map(float, x)) for x in rates]
    d = [(1.0, 0.0, 0.0, 0.0)]
    for n in range(len(rates)):
        acc = [0.0, 0.0, 0.0, 0.0]
        for j in range(n + 1):
            c = 0.5 * comb(n, j)
            for i, x in enumerate(P.hamilton(w[j], d[n - j])):
                acc[i] += c * x
        d.append(tuple(acc))
    return np.array(d) / np.array([factorial(n) for n in range(len(d))])[:, None]


def qexp_series(r: J.Jet) -> np.ndarray:
    """:func:`trajgen.jet.qexp` for one vector series ``r`` (K + 1, 3), K <= 4: Taylor
    coefficients (K + 1, 4) of ``(cos |r|, sin|r| r / |r|)``, with only the branch
    (series or closed form in ``x = |r|^2``) that its value needs."""
    x = J.dot(r, r)
    K = x.order
    x0 = np.atleast_1d(x.value)
    both = (D._cos_sinc_series if x0[0] < J.SERIES_BELOW else D._cos_sinc_closed)([x0], K)
    cos_a = J.compose(x, [v[0] for v in both[: K + 1]])
    sinc = J.compose(x, [v[0] for v in both[K + 1 :]])
    return np.concatenate([cos_a.c[:, None], J.scale(sinc, r).c], axis=1)


def log_near_identity(d: np.ndarray) -> np.ndarray:
    """Taylor coefficients (K + 1, 3) of ``log d(tau)`` from those (K + 1, 4) of a unit
    quaternion ``d`` with ``d(0) = 1``, K <= 4.

    ``log d = atan(|y|) y / |y|`` with ``y = vec(d) / w(d)``, and ``atan(x) / x =
    1 - x^2 / 3 + O(x^4)``: as ``y = O(tau)``, the ``x^4`` term is ``O(tau^5)``.
    """
    if len(d) > 5:
        raise BadArgument(f"Expected at most 5 Taylor coefficients, got {len(d)}.")
    y = J.scale(J.reciprocal(J.Jet(d[:, 0])), J.Jet(d[:, 1:]))
    return (y - J.scale(J.dot(y, y), y) * (1.0 / 3.0)).c


def log_of_curve(tab: np.ndarray, c: int, t: float, q_a: np.ndarray) -> np.ndarray:
    """Taylor coefficients (4, 3) at ``t`` (s) of ``log(C(t) q_a*)``, ``C`` curve ``c`` of
    a local-curve table (:attr:`~trajgen.local_curves.LocalCurves.kernel_table`) with
    ``C(t) . q_a >= 0``, in floats: the curve by :func:`trajgen.per_sample.curve`, the
    ``log`` as :func:`trajgen.jet.qlog` writes it, ``atan(z) / (z w)`` with
    ``z^2 = |xyz|^2 / w^2`` (a series in ``z^2`` near the identity)."""
    curve = P.curve(c, t, tab)  # w, x, y, z, each (value, d/dt, d2/dt2, d3/dt3)
    a = (float(q_a[0]), -float(q_a[1]), -float(q_a[2]), -float(q_a[3]))
    d = list(zip(*(P.hamilton(tuple(x[n] for x in curve), a) for n in range(4)), strict=True))
    w, xyz = d[0], d[1:]
    s2 = P.add(P.add(P.prod(xyz[0], xyz[0]), P.prod(xyz[1], xyz[1])), P.prod(xyz[2], xyz[2]))
    z2 = P.quot(s2, P.prod(w, w))
    if z2[0] < J.SERIES_BELOW:
        atanc = P.series(J._ATANC, z2[0])
    else:  # atan(sqrt y) / sqrt y = H(y): 2 y H' = 1 / (1 + y) - H, differentiated
        y = z2[0]
        c0, inv2y = 1.0 / (1.0 + y), 0.5 / y
        h0 = math.atan(math.sqrt(y)) / math.sqrt(y)
        h1 = (c0 - h0) * inv2y
        h2 = (-c0 * c0 - 3.0 * h1) * inv2y
        atanc = (h0, h1, h2, (2.0 * c0**3 - 5.0 * h2) * inv2y)
    g = P.quot(P.chain(*atanc, z2), w)
    taylor = np.array([P.prod(g, v) for v in xyz]).T  # (4, 3) time derivatives
    return taylor / np.array([1.0, 1.0, 2.0, 6.0])[:, None]


def hermite_matrix(k: int) -> np.ndarray:
    """Inverse of the map from the top coefficients ``a_{k+2..2k+2}`` of ``r(u)`` to its
    Taylor coefficients of orders 0..k at ``u = 1``."""
    m = np.array([[comb(k + 2 + i, j) for i in range(k + 1)] for j in range(k + 1)], float)
    return np.linalg.inv(m)
