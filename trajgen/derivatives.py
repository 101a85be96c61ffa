"""Closed-form time derivatives, order by order: the arithmetic of the blending spline's hot path.

A *derivative list* ``[x, x', x'', ...]`` holds a quantity and its first K time
derivatives (K <= 3), each an array: scalars (M,), vectors (3, M), quaternions
(4, M), components first. Only the orders asked for are computed; each rule
below (Leibniz, quotient, Faa di Bruno) is written out per order instead of
through truncated series objects (:mod:`trajgen.jet`), which keeps the number of
array operations and temporaries low.

Functions that are singular or inaccurate at zero angle take series branches
there, with the threshold of :mod:`trajgen.jet` (``SERIES_BELOW``), each branch
evaluated only on its own samples.
"""

from __future__ import annotations

from collections.abc import Generator
from math import comb

import numpy as np

from .jet import _COS, _SINC, SERIES_BELOW
from .path import run_steps

__all__ = [
    "chain",
    "cos_sin",
    "cos_sinc_sqrt",
    "hamilton",
    "hamilton_vec",
    "product",
    "quotient",
    "slerp_steps",
    "vdot",
]


def product(a: list, b: list) -> list:
    """Leibniz rule: derivatives of ``a * b`` (elementwise, broadcasting), to the shorter order."""
    K = min(len(a), len(b)) - 1
    out = [a[0] * b[0]]
    for n in range(1, K + 1):
        acc = a[0] * b[n]
        acc += a[n] * b[0]
        for j in range(1, n):
            # The binomial on the scalar factor when one side is a vector (fewer operations);
            # the attribute, not np.ndim: a function call per term counts on one sample.
            x, y = (
                (comb(n, j) * a[j], b[n - j])
                if getattr(a[j], "ndim", 0) <= getattr(b[n - j], "ndim", 0)
                else (a[j], comb(n, j) * b[n - j])
            )
            acc += x * y
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


def hamilton_vec(p: np.ndarray, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The vector part (3, ...) of the Hamilton product ``p q`` (components first)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    if out is None:
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


def hamilton(p: np.ndarray, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Hamilton product of quaternions stored components first, (4, ...) x (4, ...)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    if out is None:
        out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    w = out[0]
    np.multiply(pw, qw, out=w)
    w -= px * qx
    w -= py * qy
    w -= pz * qz
    hamilton_vec(p, q, out=out[1:])
    return out


#: (coefficients, K) -> what :func:`_series_rows` returns.
_ROWS: dict = {}


def _series_rows(coef: np.ndarray, K: int) -> tuple[np.ndarray, tuple]:
    """Rows n = 0..K: the coefficients of the n-th x-derivative of the power series ``coef``,
    padded with zeros to ``len(coef)``, as an array (K + 1, len(coef)) and as tuples of floats
    in Horner order; cached (the series are module constants)."""
    key = (coef.tobytes(), K)
    if key not in _ROWS:
        d = np.zeros((K + 1, len(coef)))
        d[0] = coef
        for n in range(1, K + 1):
            d[n, :-n] = d[n - 1, 1 : len(coef) - n + 1] * np.arange(1, len(coef) - n + 1)
        _ROWS[key] = d, tuple(tuple(row[::-1].tolist()) for row in d)
    return _ROWS[key]


def _series(coef: np.ndarray, x: np.ndarray, K: int) -> list:
    """A power series in ``x`` and its first K derivatives with respect to ``x``.

    One Horner pass for all K + 1 of them over the rows of :func:`_series_rows` (few
    samples take the series, so the number of array operations is what counts). One
    sample (``x`` a float, or an array (1,)) runs the same operations, in the same order,
    on Python floats: the same bits at a fraction of the cost of ~20 array operations.
    """
    d, backwards = _series_rows(coef, K)
    if np.ndim(x) == 0:  # one sample as a float (see _floats): floats out
        out = []
        for row in backwards:
            acc = row[0]
            for c in row[1:]:
                acc = acc * x + c
            out.append(acc)
        return out
    if len(x) == 1:
        return [np.array([v]) for v in _series(coef, float(x[0]), K)]
    acc = np.repeat(d[:, -1:], len(x), axis=1)
    for j in range(len(coef) - 2, -1, -1):
        acc *= x
        acc += d[:, j : j + 1]
    return list(acc)


def _split(small: np.ndarray, fn_small, fn_large, args: list, K: int) -> list:
    """``fn_small(*args, K)`` where ``small`` and ``fn_large`` elsewhere, each on its subset only.

    ``args`` are lists of arrays (M,); the functions return lists of arrays (M,).
    """
    return run_steps(_split_steps(small, fn_small, fn_large, args, K))


def _split_steps(small, fn_small, fn_large, args, K):
    """:func:`_split` as a generator of steps (one per branch)."""
    if small.all() or not small.any():
        values = (fn_small if small.all() else fn_large)(*args, K)
        if isinstance(values, Generator):
            values = yield from values
        return values
    out = None
    for mask, fn in ((small, fn_small), (~small, fn_large)):
        idx = np.flatnonzero(mask)
        values = fn(*[[x[idx] for x in arg] for arg in args], K)
        if isinstance(values, Generator):  # a branch with steps of its own
            values = yield from values
        if out is None:
            out = [np.empty(len(small)) for _ in values]
        for o, v in zip(out, values, strict=True):
            o[idx] = v
        yield
    return out


def _floats(x: list) -> list:
    """A derivative list of one sample, arrays (1,), as Python floats.

    A change to an online path evaluates the old path at one time: a few hundred
    operations on one sample, each ~1 us of fixed cost as an array operation. The
    scalar parts run on floats instead: the same operations in the same order give the
    same bits (IEEE arithmetic; numpy's functions run the same loop on a float as on an
    array), ``tests/test_evaluation.py`` checks one sample against its row of a batch.
    """
    return [float(v[0]) for v in x]


def _arrays(x: list) -> list:
    """The inverse of :func:`_floats`: arrays (1,)."""
    return [np.array([v], dtype=float) for v in x]


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


def cos_sinc_sqrt(x: list) -> tuple[list, list]:
    """``cos sqrt(x)`` and ``sin sqrt(x) / sqrt(x)`` for ``x >= 0`` (a squared angle), with a
    series below ``SERIES_BELOW`` (as :func:`trajgen.jet.qexp`)."""
    K = len(x) - 1
    if K == 0:  # values alone are accurate down to 0 without the series
        a = np.sqrt(x[0])
        return [np.cos(a)], [np.sin(a) / np.where(a > 0, a, 1.0) + (a == 0)]
    if len(x[0]) == 1:  # one sample: on floats
        x = _floats(x)
        d = (_cos_sinc_series if x[0] < SERIES_BELOW else _cos_sinc_closed)(x[:1], K)
        return _arrays(chain(d[: K + 1], x)), _arrays(chain(d[K + 1 :], x))
    d = _split(x[0] < SERIES_BELOW, _cos_sinc_series, _cos_sinc_closed, [x[:1]], K)
    return chain(d[: K + 1], x), chain(d[K + 1 :], x)


def cos_sin(theta: list) -> tuple[list, list]:
    """``cos theta`` and ``sin theta``."""
    c, s = np.cos(theta[0]), np.sin(theta[0])
    K = len(theta) - 1
    ns = -s if K >= 1 else None  # only the orders asked for
    nc = -c if K >= 2 else None
    return chain([c, ns, nc, s][: K + 1], theta), chain([s, c, ns, nc][: K + 1], theta)


def sin(theta: list) -> list:
    """``sin theta``."""
    s = np.sin(theta[0])
    K = len(theta) - 1
    if K == 0:
        return [s]
    c = np.cos(theta[0])
    return chain([s, c, -s if K >= 2 else None, -c if K >= 3 else None][: K + 1], theta)


#: phi^2 as a power series in z = |p - q|^2 for points p, q of S^3 at angle phi:
#: phi = 2 asin(sqrt(z) / 2), phi^2 = 2 sum_{n >= 1} z^n / (n^2 C(2n, n)).
_PHI2 = np.array([0.0] + [2.0 / (n * n * comb(2 * n, n)) for n in range(1, 9)])


def slerp_steps(p: list, q: list, f: list):
    """The point dividing the S^3 arc from ``p`` to ``q`` in ratio ``f : 1 - f``.

    A generator of steps (for a caller that spreads the work, see
    :meth:`trajgen.path.OrientationPath.evaluation_steps`); its return value is
    the result. ``p``, ``q`` are derivative lists of unit quaternions (4, M), ``f`` of scalars
    (M,). The classical form ``(sin((1 - f) phi) p + sin(f phi) q) / sin(phi)``,
    ``phi`` the angle between ``p`` and ``q``; it equals ``exp(f log(q p*)) p``
    (docs/algorithm.md §3). The angle is taken from the chord ``z = |q - p|^2``, which is
    accurate where the two points meet (at the knots); below ``SERIES_BELOW`` the
    weights are series in ``phi^2`` (``sin(f phi) / sin(phi) = f sinc(f phi) / sinc(phi)``).
    """
    K = min(len(p), len(q), len(f)) - 1
    d = [b - a for a, b in zip(p, q, strict=True)]
    z = vdot(d, d)
    yield
    if K == 0:  # values alone are accurate down to 0 without the series
        phi = 2.0 * np.arcsin(0.5 * np.sqrt(z[0]))
        at_knot = phi == 0
        inv = 1.0 / np.where(at_knot, 1.0, np.sin(phi))
        wa = np.where(at_knot, 1.0 - f[0], np.sin((1.0 - f[0]) * phi) * inv)
        wb = np.where(at_knot, f[0], np.sin(f[0] * phi) * inv)
        return [wa[None] * p[0] + wb[None] * q[0]]
    if len(z[0]) == 1:  # one sample: the weights on floats
        z, f = _floats(z), _floats(f)
        branch = _slerp_weights_series if z[0] < SERIES_BELOW else _slerp_weights_closed
        w = yield from branch(z, f, K)
    else:
        w = yield from _split_steps(
            z[0] < SERIES_BELOW, _slerp_weights_series, _slerp_weights_closed, [z, f], K
        )
    return [x + y for x, y in zip(product(w[: K + 1], p), product(w[K + 1 :], q), strict=True)]


def _complement(f: list) -> list:
    return [1.0 - f[0]] + [-x for x in f[1:]]


def _slerp_weights_series(z, f, K):
    """The weights near zero angle, as series; a generator of steps (see slerp_steps)."""
    phi2 = chain(_series(_PHI2, z[0], K), z)
    sinc = chain(_series(_SINC, phi2[0], K), phi2)
    out = []
    for g in (_complement(f), f):
        yield
        y = product(product(g, g), phi2)
        out += product(g, quotient(chain(_series(_SINC, y[0], K), y), sinc))
    return out


def _slerp_weights_closed(z, f, K):
    """The weights where the angle is away from 0; a generator of steps (see slerp_steps)."""
    x = z[0]
    d = [2.0 * np.arcsin(0.5 * np.sqrt(x))]  # phi(z) and its z-derivatives, as far as asked
    if K >= 1:
        r = 1.0 / np.sqrt(x * (4.0 - x))
        d.append(r)
    if K >= 2:
        r3 = r * r * r
        d.append(-(2.0 - x) * r3)
    if K >= 3:
        d.append(r3 + 3.0 * (2.0 - x) ** 2 * r3 * r * r)
    phi = chain(d, z)
    sin_phi = sin(phi)
    out = []
    for g in (_complement(f), f):
        yield
        out += quotient(sin(product(g, phi)), sin_phi)
    return out
