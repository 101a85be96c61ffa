"""Closed-form time derivatives, order by order: the arithmetic of the blending spline's hot path.

A *derivative list* ``[x, x', x'', ...]`` holds a quantity and its first K time
derivatives (K <= 3), each an array: scalars (M,), vectors (3, M), quaternions
(4, M), components first. Only the orders asked for are computed; each rule
below (Leibniz, quotient, Faa di Bruno) is written out per order instead of
through truncated series objects (:mod:`trajgen.jet`), which keeps the number of
array operations and temporaries low.

The quaternion exp and log take series branches near the identity, as in
:mod:`trajgen.jet` and with the same thresholds, so the two agree to rounding.
"""

from __future__ import annotations

from math import comb

import numpy as np

from .jet import _ATANC, _COS, _SINC, SERIES_BELOW

__all__ = ["chain", "exp", "hamilton", "hamilton_vec", "log", "product", "qproduct", "quotient"]


def product(a: list, b: list) -> list:
    """Leibniz rule: derivatives of ``a * b`` (elementwise, broadcasting), to the shorter order."""
    K = min(len(a), len(b)) - 1
    out = [a[0] * b[0]]
    for n in range(1, K + 1):
        acc = a[0] * b[n]
        acc += a[n] * b[0]
        for j in range(1, n):
            acc += comb(n, j) * a[j] * b[n - j]
        out.append(acc)
    return out


def quotient(a: list, b: list) -> list:
    """Derivatives of ``a / b``: ``q_n = (a_n - sum_{j=1..n} C(n, j) b_j q_{n-j}) / b_0``."""
    K = min(len(a), len(b)) - 1
    inv = 1.0 / b[0]
    q = [a[0] * inv]
    for n in range(1, K + 1):
        acc = a[n]
        for j in range(1, n + 1):
            acc = acc - comb(n, j) * b[j] * q[n - j]
        q.append(acc * inv)
    return q


def chain(d: list, x: list) -> list:
    """Faa di Bruno: derivatives of ``phi(x(t))`` from ``d[j] = phi^(j)(x)`` (K <= 3)."""
    K = len(x) - 1
    out = [d[0]]
    if K >= 1:
        out.append(d[1] * x[1])
    if K >= 2:
        out.append(d[1] * x[2] + d[2] * (x[1] * x[1]))
    if K >= 3:
        out.append(d[1] * x[3] + 3.0 * d[2] * (x[1] * x[2]) + d[3] * (x[1] * x[1] * x[1]))
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Inner product over the component axis (axis 0)."""
    out = a[0] * b[0]
    for i in range(1, len(a)):
        out += a[i] * b[i]
    return out


def vdot(a: list, b: list) -> list:
    """Derivatives of the inner product over the component axis (axis 0)."""
    K = min(len(a), len(b)) - 1
    out = []
    for n in range(K + 1):
        acc = _dot(a[0], b[n])
        for j in range(1, n + 1):
            term = _dot(a[j], b[n - j])
            acc += comb(n, j) * term if 0 < j < n else term
        out.append(acc)
    return out


def hamilton(p: np.ndarray, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Hamilton product of quaternions stored components first, (4, ...) x (4, ...)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    if out is None:
        out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    w, x, y, z = out
    np.multiply(pw, qw, out=w)
    w -= px * qx
    w -= py * qy
    w -= pz * qz
    np.multiply(pw, qx, out=x)
    x += px * qw
    x += py * qz
    x -= pz * qy
    np.multiply(pw, qy, out=y)
    y -= px * qz
    y += py * qw
    y += pz * qx
    np.multiply(pw, qz, out=z)
    z += px * qy
    z -= py * qx
    z += pz * qw
    return out


def hamilton_vec(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The vector part (3, ...) of the Hamilton product ``p q`` (components first)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    out = np.empty((3, *np.broadcast_shapes(pw.shape, qw.shape)))
    x, y, z = out
    np.multiply(pw, qx, out=x)
    x += px * qw
    x += py * qz
    x -= pz * qy
    np.multiply(pw, qy, out=y)
    y -= px * qz
    y += py * qw
    y += pz * qx
    np.multiply(pw, qz, out=z)
    z += px * qy
    z -= py * qx
    z += pz * qw
    return out


def qproduct(p: list, q: list) -> list:
    """Leibniz rule for the Hamilton product of quaternion derivative lists (4, M)."""
    K = min(len(p), len(q)) - 1
    out = []
    for n in range(K + 1):
        acc = hamilton(p[0], q[n])
        term = np.empty_like(acc) if n else None
        for j in range(1, n + 1):
            hamilton(p[j], q[n - j], term)
            if 0 < j < n:
                term *= comb(n, j)
            acc += term
        out.append(acc)
    return out


def _series(coef: np.ndarray, x: np.ndarray, K: int) -> list:
    """A power series in ``x`` and its first K derivatives with respect to ``x``."""
    out = []
    c = coef
    for _ in range(K + 1):
        acc = np.full_like(x, c[-1])
        for cj in c[-2::-1]:
            acc *= x
            acc += cj
        out.append(acc)
        c = c[1:] * np.arange(1, len(c))
    return out


def _split(small: np.ndarray, fn_small, fn_large, args: list, K: int) -> list:
    """``fn_small(*args, K)`` where ``small`` and ``fn_large`` elsewhere, each on its subset only.

    ``args`` are lists of arrays (M,); the functions return lists of arrays (M,).
    """
    if small.all():
        return fn_small(*args, K)
    if not small.any():
        return fn_large(*args, K)
    parts = []
    for mask in (small, ~small):
        idx = np.flatnonzero(mask)
        parts.append((idx, [[x[idx] for x in arg] for arg in args]))
    out = None
    for (idx, sub), fn in zip(parts, (fn_small, fn_large), strict=True):
        values = fn(*sub, K)
        if out is None:
            out = [np.empty(len(small)) for _ in values]
        for o, v in zip(out, values, strict=True):
            o[idx] = v
    return out


def _cos_sinc_series(x, K):
    return _series(_COS, x[0], K) + _series(_SINC, x[0], K)


def _cos_sinc_closed(x, K):
    """``cos sqrt(x)``, ``sin sqrt(x) / sqrt(x)`` and their x-derivatives, for x away from 0."""
    x = x[0]
    a = np.sqrt(x)
    c = np.cos(a)
    s = np.sin(a) / a
    cs, ss = [c], [s]
    if K >= 1:
        inv2x = 0.5 / x
        ss.append((c - s) * inv2x)  # S' = (C - S) / 2x, C' = -S / 2
        cs.append(-0.5 * s)
        for n in range(2, K + 1):  # 2x S^(n) = C^(n-1) - (2n - 1) S^(n-1); C^(n) = -S^(n-1) / 2
            ss.append((cs[n - 1] - (2 * n - 1) * ss[n - 1]) * inv2x)
            cs.append(-0.5 * ss[n - 1])
    return cs + ss


def exp(v: list) -> list:
    """``exp(v) = (cos |v|, sin|v| v / |v|)`` for a 3-vector derivative list (3, M) -> (4, M).

    Series in ``x = |v|^2`` below ``SERIES_BELOW`` (as :func:`trajgen.jet.qexp`).
    """
    K = len(v) - 1
    x = vdot(v, v)
    d = _split(x[0] < SERIES_BELOW, _cos_sinc_series, _cos_sinc_closed, [x[:1]], K)
    cos_a, sinc = chain(d[: K + 1], x), chain(d[K + 1 :], x)
    out = []
    for c, sv in zip(cos_a, product(sinc, v), strict=True):
        e = np.empty((4, *c.shape))
        e[0], e[1:] = c, sv
        out.append(e)
    return out


def log(q: list) -> list:
    """Inverse of :func:`exp` for unit quaternion derivative lists (4, M) -> (3, M).

    ``atan2(s, w) / s`` (``s = |xyz|``) on most samples; near the identity
    (``s^2 < SERIES_BELOW w^2``, ``w > 0``) the series ``atan(z) / (z w)`` in
    ``z^2 = s^2 / w^2``, as :func:`trajgen.jet.qlog`.
    """
    K = len(q) - 1
    w = [x[0] for x in q]
    xyz = [x[1:] for x in q]
    s2 = vdot(xyz, xyz)
    small = (s2[0] < SERIES_BELOW * w[0] ** 2) & (w[0] > 0)
    scale = _split(small, _log_scale_series, _log_scale_atan2, [w, s2], K)
    return product(scale, xyz)


def _log_scale_series(w, s2, K):
    """``atan(z) / (z w)``, ``z^2 = s2 / w^2``, as a series."""
    z2 = quotient(s2, product(w, w))
    return quotient(chain(_series(_ATANC, z2[0], K), z2), w)


def _log_scale_atan2(w, s2, K):
    """``atan2(s, w) / s`` with ``s = sqrt(s2)``."""
    s = np.sqrt(s2[0])
    ss = chain([s, 0.5 / s, -0.25 / (s * s2[0]), 0.375 / (s * s2[0] ** 2)], s2)
    phi = [np.arctan2(s, w[0])]
    if K >= 1:
        # phi' = (w s' - s w') / (w^2 + s^2), differentiated by the quotient rule.
        num = [w[0] * ss[1] - s * w[1]]
        if K >= 2:
            num.append(w[0] * ss[2] - s * w[2])
        if K >= 3:
            num.append(w[0] * ss[3] - s * w[3] + w[1] * ss[2] - ss[1] * w[2])
        den = [x + y for x, y in zip(product(w[:K], w[:K]), product(ss[:K], ss[:K]), strict=True)]
        phi += quotient(num, den)
    return quotient(phi, ss)
