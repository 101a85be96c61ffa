"""Truncated Taylor series ("jets") in time: exact derivatives by automatic differentiation.

A :class:`Jet` of order K holds ``c[n] = f^(n)(t) / n!`` for ``n = 0..K``, shape
``(K + 1, ...)``. Arithmetic on jets is arithmetic on the series truncated at
order K, so a curve written once with jets yields its value and its first K time
derivatives exactly (to rounding), with no step size to choose.

Vector-valued jets keep the components on axis 1, ``(K + 1, 4, M)`` for M
quaternions (contiguous components make the products fast);
:func:`qmul`, :func:`qexp` and :func:`qlog` mirror :mod:`trajgen.quat` and take
stable series branches near the identity, where ``|v|`` itself is not smooth.
"""

from __future__ import annotations

from functools import cache
from math import factorial

import numpy as np

from .errors import BadArgument

#: Squared size below which exp/log use their series (|angle| < 0.1 rad).
SERIES_BELOW = 1e-2

#: Values per coefficient below which a product is one ``einsum`` rather than a loop
#: of small products (3-20x faster for one sample, as when a path is spliced online;
#: slower for long arrays).
EINSUM_BELOW = 64


@cache
def _cauchy(k: int) -> np.ndarray:
    """``T[j, m, n] = 1`` where ``j + m = n``: the Cauchy product of two order-k series."""
    n = np.arange(k + 1)
    return (n[:, None, None] + n[None, :, None] == n[None, None, :]).astype(float)


class Jet:
    """Truncated Taylor series; ``c`` has shape (K + 1, ...)."""

    __slots__ = ("c",)
    __array_ufunc__ = None  # make ``ndarray * Jet`` defer to Jet.__rmul__

    def __init__(self, c: np.ndarray):
        self.c = c

    @classmethod
    def variable(cls, t: np.ndarray, order: int) -> Jet:
        """The jet of ``t`` itself (derivative 1)."""
        c = np.zeros((order + 1, *np.shape(t)))
        c[0] = t
        if order >= 1:
            c[1] = 1.0
        return cls(c)

    @classmethod
    def constant(cls, x: np.ndarray, order: int) -> Jet:
        """A jet with zero derivatives."""
        x = np.asarray(x, dtype=float)
        c = np.zeros((order + 1, *x.shape))
        c[0] = x
        return cls(c)

    @property
    def order(self) -> int:
        return self.c.shape[0] - 1

    @property
    def value(self) -> np.ndarray:
        return self.c[0]

    def derivative(self, n: int) -> np.ndarray:
        """The n-th time derivative, ``n! c[n]``."""
        return factorial(n) * self.c[n]

    def d(self) -> Jet:
        """The jet of the time derivative (one order lower)."""
        n = np.arange(1, self.order + 1).reshape((-1,) + (1,) * (self.c.ndim - 1))
        return Jet(n * self.c[1:])

    def __getitem__(self, index) -> Jet:
        if not isinstance(index, tuple):
            index = (index,)
        return Jet(self.c[(slice(None), *index)])

    def __neg__(self) -> Jet:
        return Jet(-self.c)

    def __add__(self, other) -> Jet:
        if isinstance(other, Jet):
            k = min(self.order, other.order)
            return Jet(self.c[: k + 1] + other.c[: k + 1])
        c = self.c.copy()
        c[0] = c[0] + other
        return Jet(c)

    __radd__ = __add__

    def __sub__(self, other) -> Jet:
        return self + (-other)

    def __rsub__(self, other) -> Jet:
        return (-self) + other

    def __mul__(self, other) -> Jet:
        if not isinstance(other, Jet):
            return Jet(self.c * np.asarray(other, dtype=float))
        k = min(self.order, other.order)
        a, b = self.c, other.c
        if a[0].size * b[0].size < EINSUM_BELOW:  # bounds the broadcast size, cheaply
            return Jet(np.einsum("jmn,j...,m...->n...", _cauchy(k), a[: k + 1], b[: k + 1]))
        out = np.empty((k + 1, *np.broadcast_shapes(a.shape[1:], b.shape[1:])))
        tmp = np.empty(out.shape[1:])
        for n in range(k + 1):
            np.multiply(a[0], b[n], out=out[n])
            for j in range(1, n + 1):
                out[n] += np.multiply(a[j], b[n - j], out=tmp)
        return Jet(out)

    __rmul__ = __mul__

    def __truediv__(self, other) -> Jet:
        if isinstance(other, Jet):
            return self * reciprocal(other)
        return Jet(self.c / np.asarray(other, dtype=float))

    def __rtruediv__(self, other) -> Jet:
        return reciprocal(self) * other


def compose(a: Jet, d: list[np.ndarray]) -> Jet:
    """``phi(a)`` from ``d[j] = phi^(j)(a.value)``, j = 0..K (Faa di Bruno, K <= 4).

    Order 4 serves :class:`trajgen.online.OnlineSpline`, which splices a C^3 path
    onto the old one's jet to one order more than the continuity it keeps.
    """
    K = a.order
    if K > 4:
        raise BadArgument(f"Jets are implemented up to order 4, got {K}.")
    x = a.c
    c = np.empty(x.shape)
    c[0] = d[0]
    if K >= 1:
        c[1] = d[1] * x[1]
    if K >= 2:
        c[2] = d[1] * x[2] + 0.5 * d[2] * x[1] ** 2
    if K >= 3:
        c[3] = d[1] * x[3] + d[2] * x[1] * x[2] + d[3] / 6.0 * x[1] ** 3
    if K >= 4:
        c[4] = (
            d[1] * x[4]
            + d[2] * (x[1] * x[3] + 0.5 * x[2] ** 2)
            + 0.5 * d[3] * x[1] ** 2 * x[2]
            + d[4] / 24.0 * x[1] ** 4
        )
    return Jet(c)


def sin_cos(a: Jet) -> tuple[Jet, Jet]:
    """``(sin a, cos a)``."""
    s, c = np.sin(a.value), np.cos(a.value)
    return compose(a, [s, c, -s, -c, s]), compose(a, [c, -s, -c, s, c])


def sqrt(a: Jet) -> Jet:
    """``sqrt(a)`` for ``a.value > 0``."""
    r = np.sqrt(a.value)
    x = a.value
    return compose(a, [r, 0.5 / r, -0.25 / (r * x), 0.375 / (r * x**2), -0.9375 / (r * x**3)])


def reciprocal(a: Jet) -> Jet:
    """``1 / a`` for ``a.value != 0``."""
    x = 1.0 / a.value
    return compose(a, [x, -(x**2), 2.0 * x**3, -6.0 * x**4, 24.0 * x**5])


def power(a: Jet, p: np.ndarray) -> Jet:
    """``a ** p`` for ``a.value > 0`` (or ``>= 0`` with an integer ``p``); ``p`` broadcasts."""
    x = a.value
    d, falling = [], np.ones_like(np.asarray(p, dtype=float))
    for j in range(a.order + 1):
        # p (p-1) ... (p-j+1) x^(p-j); for an integer p the factor is 0 once j > p.
        d.append(falling * x ** np.where(falling == 0, 0.0, p - j))
        falling = falling * (p - j)
    return compose(a, d)


def arctan2(y: Jet, x: Jet) -> Jet:
    """``atan2(y, x)`` away from the origin; derivative ``(x y' - y x') / (x^2 + y^2)``."""
    value = np.arctan2(y.value, x.value)
    K = y.order
    c = np.empty_like(y.c)
    c[0] = value
    if K >= 1:
        rate = (x * y.d() - y * x.d()) / (x * x + y * y)
        for n in range(1, K + 1):
            c[n] = rate.c[n - 1] / n
    return Jet(c)


def polyval(coeffs: np.ndarray, x: Jet) -> Jet:
    """``sum_j coeffs[j] x^j`` by Horner; ``coeffs`` shape (D + 1, ...) broadcasts with x."""
    coeffs = np.asarray(coeffs, dtype=float)
    out = Jet.constant(np.broadcast_to(coeffs[-1], x.value.shape), x.order)
    for cj in coeffs[-2::-1]:
        out = out * x + cj
    return out


def dot(a: Jet, b: Jet) -> Jet:
    """Inner product of vector jets over their component axis."""
    return Jet((a * b).c.sum(axis=1))


def scale(s: Jet, v) -> Jet:
    """Scalar jet (K + 1, ...) times a vector jet (K + 1, D, ...) or a constant (D, ...)."""
    if isinstance(v, Jet):
        return Jet(s.c[:, None]) * v
    return Jet(s.c[:, None] * v)


def _parts(q) -> list:
    """Components of a quaternion jet (K + 1, 4, ...) as jets, of a constant (4, ...) as arrays."""
    return [Jet(q.c[:, i]) for i in range(4)] if isinstance(q, Jet) else list(q)


def qmul(p, q) -> Jet:
    """Hamilton product; each factor a quaternion jet (K + 1, 4, ...) or a constant (4, ...)."""
    pw, px, py, pz = _parts(p)
    qw, qx, qy, qz = _parts(q)
    parts = [
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ]
    return Jet(np.stack([x.c for x in parts], axis=1))


def qconj(q: Jet) -> Jet:
    """Conjugate of a quaternion jet (K + 1, 4, ...)."""
    sign = np.array([1.0, -1.0, -1.0, -1.0]).reshape((4,) + (1,) * (q.c.ndim - 2))
    return Jet(q.c * sign)


# Series in x = a^2: cos a and sin(a)/a; and atan(z)/z in x = z^2.
_COS = np.array([(-1) ** n / factorial(2 * n) for n in range(6)])
_SINC = np.array([(-1) ** n / factorial(2 * n + 1) for n in range(6)])
_ATANC = np.array([(-1) ** n / (2 * n + 1) for n in range(9)])


def _where(mask: np.ndarray, a: Jet, b: Jet) -> Jet:
    return Jet(np.where(mask, a.c, b.c))


def qexp(v: Jet) -> Jet:
    """``(cos |v|, sin|v| v/|v|)`` for a 3-vector jet (K + 1, 3, ...) -> (K + 1, 4, ...)."""
    x = dot(v, v)
    small = x.value < SERIES_BELOW
    if small.all():  # one branch only where every sample takes it (few samples, often)
        cos_a, sinc = polyval(_COS, x), polyval(_SINC, x)
    else:
        # Evaluate both branches on safe inputs, then pick per sample.
        xs = Jet(np.where(small, 1.0, x.c))
        a = sqrt(xs)
        s, c = sin_cos(a)
        cos_a, sinc = c, s / a
        if small.any():
            cos_a = _where(small, polyval(_COS, x), cos_a)
            sinc = _where(small, polyval(_SINC, x), sinc)
    return Jet(np.concatenate([cos_a.c[:, None], scale(sinc, v).c], axis=1))


def qlog(q: Jet) -> Jet:
    """Inverse of :func:`qexp` for unit quaternion jets with ``w > 0`` near the identity.

    ``atan2(s, w) / s`` is written as ``atan(z) / (z w)`` with ``z = s / w``, a series
    in ``z^2`` for small ``z``, so the identity (where ``s = |xyz|`` is not smooth)
    is exact and finite.
    """
    w = Jet(q.c[:, 0])
    xyz = Jet(q.c[:, 1:])
    s2 = dot(xyz, xyz)
    small = (s2.value < SERIES_BELOW * w.value**2) & (w.value > 0)
    # Each branch is evaluated (on safe inputs) only if some sample takes it.
    if small.any():
        w_safe = Jet(np.where(small | (np.abs(w.c) > 0), w.c, 1.0))
        z2 = s2 / (w_safe * w_safe)
        series = polyval(_ATANC, z2) / w_safe
        if small.all():
            return scale(series, xyz)
    s = sqrt(Jet(np.where(small, 1.0, s2.c)))
    general = arctan2(s, w) / s
    return scale(_where(small, series, general) if small.any() else general, xyz)
