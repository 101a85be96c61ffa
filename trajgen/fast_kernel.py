"""The numba kernel behind :mod:`trajgen.fast` (imported only when it is used).

Jets are tuples of four Taylor coefficients (order 3), which numba keeps on the
stack; each function mirrors its numpy counterpart in :mod:`trajgen.jet` and
:mod:`trajgen.local_curves`, and the samples run in parallel.
"""

from __future__ import annotations

import math

import numba

from .jet import _ATANC, _COS, _SINC, SERIES_BELOW
from .local_curves import CIRCLE, G_POLY, G_POWER, PARABOLA, POINT

njit = numba.njit(cache=True, fastmath=True, error_model="numpy")


@njit
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3])


@njit
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3])


@njit
def scl(a, s):
    return (a[0] * s, a[1] * s, a[2] * s, a[3] * s)


@njit
def addc(a, c):
    return (a[0] + c, a[1], a[2], a[3])


@njit
def mul(a, b):
    return (
        a[0] * b[0],
        a[0] * b[1] + a[1] * b[0],
        a[0] * b[2] + a[1] * b[1] + a[2] * b[0],
        a[0] * b[3] + a[1] * b[2] + a[2] * b[1] + a[3] * b[0],
    )


@njit
def compose(a, d0, d1, d2, d3):
    return (
        d0,
        d1 * a[1],
        d1 * a[2] + 0.5 * d2 * a[1] ** 2,
        d1 * a[3] + d2 * a[1] * a[2] + d3 / 6.0 * a[1] ** 3,
    )


@njit
def sin_cos(a):
    s, c = math.sin(a[0]), math.cos(a[0])
    return compose(a, s, c, -s, -c), compose(a, c, -s, -c, s)


@njit
def jsqrt(a):
    r = math.sqrt(a[0])
    return compose(a, r, 0.5 / r, -0.25 / (r * a[0]), 0.375 / (r * a[0] ** 2))


@njit
def recip(a):
    x = 1.0 / a[0]
    return compose(a, x, -(x**2), 2.0 * x**3, -6.0 * x**4)


@njit
def power(a, p):
    # p (p-1) ... (p-j+1) x^(p-j); for an integer p the factor is 0 once j > p.
    x = a[0]
    f1, f2, f3 = p, p * (p - 1), p * (p - 1) * (p - 2)
    d1 = f1 * x ** (p - 1) if f1 != 0.0 else 0.0
    d2 = f2 * x ** (p - 2) if f2 != 0.0 else 0.0
    d3 = f3 * x ** (p - 3) if f3 != 0.0 else 0.0
    return compose(a, x**p, d1, d2, d3)


@njit
def deriv(a):
    return (a[1], 2.0 * a[2], 3.0 * a[3], 0.0)


@njit
def atan2(y, x):
    rate = mul(sub(mul(x, deriv(y)), mul(y, deriv(x))), recip(add(mul(x, x), mul(y, y))))
    return (math.atan2(y[0], x[0]), rate[0], rate[1] / 2.0, rate[2] / 3.0)


@njit
def polyval(coef, x):
    out = (coef[len(coef) - 1], 0.0, 0.0, 0.0)
    for j in range(len(coef) - 2, -1, -1):
        out = addc(mul(out, x), coef[j])
    return out


@njit
def qmul(p, q):
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        sub(sub(sub(mul(pw, qw), mul(px, qx)), mul(py, qy)), mul(pz, qz)),
        sub(add(add(mul(pw, qx), mul(px, qw)), mul(py, qz)), mul(pz, qy)),
        add(add(sub(mul(pw, qy), mul(px, qz)), mul(py, qw)), mul(pz, qx)),
        add(sub(add(mul(pw, qz), mul(px, qy)), mul(py, qx)), mul(pz, qw)),
    )


@njit
def qconj(q):
    return (q[0], scl(q[1], -1.0), scl(q[2], -1.0), scl(q[3], -1.0))


@njit
def const(x):
    return (x, 0.0, 0.0, 0.0)


@njit
def qconst(q4):
    return (const(q4[0]), const(q4[1]), const(q4[2]), const(q4[3]))


@njit
def qexp(v0, v1, v2):
    x = add(add(mul(v0, v0), mul(v1, v1)), mul(v2, v2))
    if x[0] < SERIES_BELOW:
        cos_a, sinc = polyval(_COS, x), polyval(_SINC, x)
    else:
        a = jsqrt(x)
        s, cos_a = sin_cos(a)
        sinc = mul(s, recip(a))
    return (cos_a, mul(sinc, v0), mul(sinc, v1), mul(sinc, v2))


@njit
def qlog(q):
    w, x, y, z = q
    s2 = add(add(mul(x, x), mul(y, y)), mul(z, z))
    if s2[0] < SERIES_BELOW * w[0] ** 2 and w[0] > 0:
        rw = recip(w)
        scale = mul(polyval(_ATANC, mul(s2, mul(rw, rw))), rw)
    else:
        s = jsqrt(s2)
        scale = mul(atan2(s, w), recip(s))
    return mul(scale, x), mul(scale, y), mul(scale, z)


@njit
def curve(c, t, tab):
    kind, tw, q, centre, radius, e1, e2, a3, g_kind, g_coef, A, B, rise, pw = tab
    tj = (t, 1.0, 0.0, 0.0)
    k = kind[c]
    if k == POINT:
        return qconst(q[c])
    if k == PARABOLA:
        tau = addc(tj, -tw[c, 1])
        tau2 = mul(tau, tau)
        v0 = add(scl(tau, A[c, 0]), scl(tau2, B[c, 0]))
        v1 = add(scl(tau, A[c, 1]), scl(tau2, B[c, 1]))
        v2 = add(scl(tau, A[c, 2]), scl(tau2, B[c, 2]))
        return qmul(qexp(v0, v1, v2), qconst(q[c]))
    s = scl(addc(tj, -tw[c, 0]), 1.0 / (tw[c, 2] - tw[c, 0]))
    if k == CIRCLE:
        gk = g_kind[c]
        if gk == G_POLY:
            g = polyval(g_coef[c], s)
        elif gk == G_POWER:
            at_zero = s[0] < 1e-12
            g = power((max(s[0], 1e-12), s[1], s[2], s[3]), g_coef[c, 0])
            if at_zero:
                g = (0.0, g[1], g[2], g[3])
        else:
            b = g_coef[c, 0]
            g = mul(scl(s, 1.0 + b), recip(addc(scl(s, b), 1.0)))
        sn, cs = sin_cos(scl(g, a3[c]))
        r = radius[c]
        return (
            add(scl(cs, r * e1[c, 0]), addc(scl(sn, r * e2[c, 0]), centre[c, 0])),
            add(scl(cs, r * e1[c, 1]), addc(scl(sn, r * e2[c, 1]), centre[c, 1])),
            add(scl(cs, r * e1[c, 2]), addc(scl(sn, r * e2[c, 2]), centre[c, 2])),
            add(scl(cs, r * e1[c, 3]), addc(scl(sn, r * e2[c, 3]), centre[c, 3])),
        )
    # GEODESIC
    s_i = (tw[c, 1] - tw[c, 0]) / (tw[c, 2] - tw[c, 0])
    if rise[c] > 0:
        x = scl(addc(s, -s_i), 1.0 / (1.0 - s_i))
    else:
        x = scl(addc(scl(s, -1.0), s_i), 1.0 / s_i)
    if x[0] > 0:
        xp = power(x, pw[c])
    else:
        xp = const(0.0)
    h = xp if rise[c] > 0 else addc(scl(xp, -1.0), 1.0)
    return qmul(qexp(scl(h, A[c, 0]), scl(h, A[c, 1]), scl(h, A[c, 2])), qconst(q[c]))


def _kernel(t, seg, times, left, right, blend, tab, out_q, out_w):
    for m in numba.prange(len(t)):
        i = seg[m]
        cl = curve(left[i], t[m], tab)
        cr = curve(right[i], t[m], tab)
        u = ((t[m] - times[i]) / (times[i + 1] - times[i]), 1.0 / (times[i + 1] - times[i]))
        f = polyval(blend[i], (u[0], u[1], 0.0, 0.0))
        v0, v1, v2 = qlog(qmul(cr, qconj(cl)))
        Q = qmul(qexp(mul(f, v0), mul(f, v1), mul(f, v2)), cl)
        norm = math.sqrt(Q[0][0] ** 2 + Q[1][0] ** 2 + Q[2][0] ** 2 + Q[3][0] ** 2)
        for j in range(4):
            out_q[m, j] = Q[j][0] / norm
        # omega = 2 vec(Q' Q*), space frame; its Taylor coefficients n = 0..2.
        Qd = (deriv(Q[0]), deriv(Q[1]), deriv(Q[2]), deriv(Q[3]))
        W = qmul(Qd, qconj(Q))
        for j in range(3):
            out_w[0, m, j] = 2.0 * W[j + 1][0]
            out_w[1, m, j] = 2.0 * W[j + 1][1]
            out_w[2, m, j] = 4.0 * W[j + 1][2]


evaluate = numba.njit(cache=True, parallel=True, fastmath=True, error_model="numpy")(_kernel)
