"""The splines one sample at a time, in scalars: what the compiled kernel compiles.

The arithmetic of the numpy paths (:meth:`trajgen.spline.BlendingSpline._blend_steps`,
``SmoothSpline._space_rates``), restated per sample: the local curves as scalar
combinations of their basis quaternions
(:meth:`trajgen.local_curves.LocalCurves.derivatives`) and the blend as the
slerp of :func:`trajgen.derivatives.slerp_steps`, with the same series branches.
A derivative list is a 4-tuple ``(x, x', x'', x''')`` of floats; all four
orders are computed.

Plain Python, so it serves two ways (:mod:`trajgen.fast` chooses): compiled by
numba in :mod:`trajgen.fast_kernel`, which compiles every function here, and
as it is for an evaluation of a few samples, where it beats numpy's fixed cost
per call (a blending-spline sample: 75 us, against 520 us for numpy's blend of
one sample, quiet machine). Keep to what numba compiles: scalars, tuples,
array indexing, ``math``.
"""

from __future__ import annotations

import math

from .derivatives import _PHI2
from .jet import _COS, _SINC, SERIES_BELOW
from .local_curves import CIRCLE, G_POLY, G_RATIONAL, PARABOLA, POINT

#: Functions numba inlines into their callers (no reference counting, per sample,
#: of the arrays they are passed); the others it compiles as calls.
INLINE = ("combine", "sample", "space_rates", "smooth_sample", "exp_of")


def prod(a, b):
    """Leibniz rule."""
    return (
        a[0] * b[0],
        a[0] * b[1] + a[1] * b[0],
        a[0] * b[2] + 2.0 * a[1] * b[1] + a[2] * b[0],
        a[0] * b[3] + 3.0 * (a[1] * b[2] + a[2] * b[1]) + a[3] * b[0],
    )


def quot(a, b):
    """Derivatives of a / b."""
    inv = 1.0 / b[0]
    q0 = a[0] * inv
    q1 = (a[1] - b[1] * q0) * inv
    q2 = (a[2] - 2.0 * b[1] * q1 - b[2] * q0) * inv
    q3 = (a[3] - 3.0 * b[1] * q2 - 3.0 * b[2] * q1 - b[3] * q0) * inv
    return (q0, q1, q2, q3)


def chain(d0, d1, d2, d3, x):
    """Faa di Bruno: phi(x(t)) from phi's derivatives d0..d3 at x[0]."""
    return (
        d0,
        d1 * x[1],
        d1 * x[2] + d2 * x[1] * x[1],
        d1 * x[3] + 3.0 * d2 * x[1] * x[2] + d3 * x[1] * x[1] * x[1],
    )


def series(coef, x):
    """A power series in x and its first three x-derivatives."""
    p0 = p1 = p2 = p3 = 0.0
    for j in range(len(coef) - 1, -1, -1):
        p3 = p3 * x + 3.0 * p2
        p2 = p2 * x + 2.0 * p1
        p1 = p1 * x + p0
        p0 = p0 * x + coef[j]
    return p0, p1, p2, p3


def cos_sin(th):
    c, s = math.cos(th[0]), math.sin(th[0])
    return chain(c, -s, -c, s, th), chain(s, c, -s, -c, th)


def cos_sinc_sqrt(x):
    """cos sqrt(x) and sin sqrt(x) / sqrt(x) (x a squared angle)."""
    if x[0] < SERIES_BELOW:
        c0, c1, c2, c3 = series(_COS, x[0])
        s0, s1, s2, s3 = series(_SINC, x[0])
    else:
        a = math.sqrt(x[0])
        c0, s0 = math.cos(a), math.sin(a) / a
        inv2x = 0.5 / x[0]
        s1 = (c0 - s0) * inv2x
        c1 = -0.5 * s0
        s2 = (c1 - 3.0 * s1) * inv2x
        c2 = -0.5 * s1
        s3 = (c2 - 5.0 * s2) * inv2x
        c3 = -0.5 * s2
    return chain(c0, c1, c2, c3, x), chain(s0, s1, s2, s3, x)


def curve(c, t, tab):
    """Curve ``c`` at time ``t``: its four components, each a derivative list."""
    k = int(tab[c, 0])
    zero = (0.0, 0.0, 0.0, 0.0)
    a0, a1, a2 = (1.0, 0.0, 0.0, 0.0), zero, zero
    if k == PARABOLA:
        tau = t - tab[c, 2]
        aa, ab, bb = tab[c, 11], tab[c, 12], tab[c, 13]
        x = (
            tau * tau * (aa + tau * (2.0 * ab + tau * bb)),
            tau * (2.0 * aa + tau * (6.0 * ab + 4.0 * bb * tau)),
            2.0 * aa + tau * (12.0 * ab + 12.0 * bb * tau),
            12.0 * ab + 24.0 * bb * tau,
        )
        a0, sinc = cos_sinc_sqrt(x)
        a1 = prod(sinc, (tau, 1.0, 0.0, 0.0))
        a2 = prod(sinc, (tau * tau, 2.0 * tau, 2.0, 0.0))
    elif k != POINT:
        rate = tab[c, 4]
        s = (t - tab[c, 1]) * rate
        if k == CIRCLE:
            gk = int(tab[c, 6])
            if gk == G_RATIONAL:
                b = tab[c, 7]
                inv = 1.0 / (1.0 + b * s)
                g1 = (1.0 + b) * inv * inv
                g2 = -2.0 * b * g1 * inv
                g = ((1.0 + b) * s * inv, g1, g2, -3.0 * b * g2 * inv)
            elif gk == G_POLY:
                c0, c1, c2, c3 = tab[c, 7], tab[c, 8], tab[c, 9], tab[c, 10]
                g = (
                    c0 + s * (c1 + s * (c2 + s * c3)),
                    c1 + s * (2.0 * c2 + 3.0 * c3 * s),
                    2.0 * c2 + 6.0 * c3 * s,
                    6.0 * c3,
                )
            else:  # G_POWER; at s = 0 the derivatives are taken at 1e-12 (see _g_power)
                al = tab[c, 7]
                xs = max(s, 1e-12)
                g = (
                    0.0 if s < 1e-12 else xs**al,
                    al * xs ** (al - 1.0),
                    al * (al - 1.0) * xs ** (al - 2.0),
                    al * (al - 1.0) * (al - 2.0) * xs ** (al - 3.0),
                )
            sc = tab[c, 5]
            th = (sc * g[0], sc * rate * g[1], sc * rate**2 * g[2], sc * rate**3 * g[3])
            a1, a2 = cos_sin(th)
        else:  # GEODESIC
            s_i = (tab[c, 2] - tab[c, 1]) * rate
            up = tab[c, 14] > 0
            x = (s - s_i) / (1.0 - s_i) if up else (s_i - s) / s_i
            dx = rate / (1.0 - s_i) if up else -rate / s_i
            p = tab[c, 15]
            h0 = h1 = h2 = h3 = 0.0
            if x > 0.0:  # x^p and its derivatives; p (p-1) ... is 0 past an integer p
                f1, f2, f3 = p, p * (p - 1.0), p * (p - 1.0) * (p - 2.0)
                h0 = x**p
                h1 = f1 * x ** (p - 1.0) * dx if f1 != 0.0 else 0.0
                h2 = f2 * x ** (p - 2.0) * dx * dx if f2 != 0.0 else 0.0
                h3 = f3 * x ** (p - 3.0) * dx * dx * dx if f3 != 0.0 else 0.0
            if not up:
                h0, h1, h2, h3 = 1.0 - h0, -h1, -h2, -h3
            L = tab[c, 16]
            a0, a1 = cos_sin((L * h0, L * h1, L * h2, L * h3))
    return (
        combine(a0, a1, a2, tab, c, 0),
        combine(a0, a1, a2, tab, c, 1),
        combine(a0, a1, a2, tab, c, 2),
        combine(a0, a1, a2, tab, c, 3),
    )


def combine(a0, a1, a2, tab, c, i):
    """Component i of a0 K_0 + a1 K_1 + a2 K_2, K the basis of curve c."""
    k0, k1, k2 = tab[c, 17 + i], tab[c, 21 + i], tab[c, 25 + i]
    return (
        a0[0] * k0 + a1[0] * k1 + a2[0] * k2,
        a0[1] * k0 + a1[1] * k1 + a2[1] * k2,
        a0[2] * k0 + a1[2] * k1 + a2[2] * k2,
        a0[3] * k0 + a1[3] * k1 + a2[3] * k2,
    )


def slerp_weights(z, f):
    """The slerp weights of p and q (see trajgen.derivatives.slerp_steps)."""
    g = (1.0 - f[0], -f[1], -f[2], -f[3])
    if z[0] < SERIES_BELOW:
        p0, p1, p2, p3 = series(_PHI2, z[0])
        phi2 = chain(p0, p1, p2, p3, z)
        s0, s1, s2, s3 = series(_SINC, phi2[0])
        sinc = chain(s0, s1, s2, s3, phi2)
        y = prod(prod(g, g), phi2)
        s0, s1, s2, s3 = series(_SINC, y[0])
        wa = prod(g, quot(chain(s0, s1, s2, s3, y), sinc))
        y = prod(prod(f, f), phi2)
        s0, s1, s2, s3 = series(_SINC, y[0])
        wb = prod(f, quot(chain(s0, s1, s2, s3, y), sinc))
    else:
        x = z[0]
        r = 1.0 / math.sqrt(x * (4.0 - x))
        r3 = r * r * r
        phi = chain(
            2.0 * math.asin(0.5 * math.sqrt(x)),
            r,
            -(2.0 - x) * r3,
            r3 + 3.0 * (2.0 - x) ** 2 * r3 * r * r,
            z,
        )
        sin_phi = cos_sin(phi)[1]
        wa = quot(cos_sin(prod(g, phi))[1], sin_phi)
        wb = quot(cos_sin(prod(f, phi))[1], sin_phi)
    return wa, wb


def sample(m, t, seg, times, inv_h, left, right, blend, tab, out_q, out_w):
    """Sample m: unit quaternion into out_q[m], omega, alpha, jerk into out_w[:, m]."""
    i = seg[m]
    tm = t[m]
    cl = curve(left[i], tm, tab)
    cr = curve(right[i], tm, tab)
    # The blend polynomial and its derivatives at u, times (du/dt)^n.
    rate = inv_h[i]
    u = (tm - times[i]) * rate
    f0 = f1 = f2 = f3 = 0.0
    for j in range(blend.shape[1] - 1, -1, -1):
        f3 = f3 * u + 3.0 * f2
        f2 = f2 * u + 2.0 * f1
        f1 = f1 * u + f0
        f0 = f0 * u + blend[i, j]
    f = (f0, f1 * rate, f2 * rate * rate, f3 * rate * rate * rate)
    z = (0.0, 0.0, 0.0, 0.0)
    for c in range(4):
        a, b = cl[c], cr[c]
        d = (b[0] - a[0], b[1] - a[1], b[2] - a[2], b[3] - a[3])
        z = add(z, prod(d, d))
    wa, wb = slerp_weights(z, f)
    Q = (
        add(prod(wa, cl[0]), prod(wb, cr[0])),
        add(prod(wa, cl[1]), prod(wb, cr[1])),
        add(prod(wa, cl[2]), prod(wb, cr[2])),
        add(prod(wa, cl[3]), prod(wb, cr[3])),
    )
    norm = math.sqrt(Q[0][0] ** 2 + Q[1][0] ** 2 + Q[2][0] ** 2 + Q[3][0] ** 2)
    for c in range(4):
        out_q[m, c] = Q[c][0] / norm
    space_rates(Q, m, out_w)


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3])


def space_rates(Q, m, out_w):
    """omega = 2 vec(Q' Q*), alpha = 2 vec(Q" Q*), jerk = 2 vec(Q"' Q* + Q" Q'*) of a
    unit quaternion's derivative lists ``Q``, into ``out_w[:, m]``."""
    for n in range(1, 4):
        x, y, w = vec_mul_conj(Q, n, 0)
        out_w[n - 1, m, 0] = 2.0 * x
        out_w[n - 1, m, 1] = 2.0 * y
        out_w[n - 1, m, 2] = 2.0 * w
    x, y, w = vec_mul_conj(Q, 2, 1)
    out_w[2, m, 0] += 2.0 * x
    out_w[2, m, 1] += 2.0 * y
    out_w[2, m, 2] += 2.0 * w


def hamilton(p, q):
    """Hamilton product of two quaternions, each 4 scalars (w, x, y, z)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def vec_mul_conj(Q, a, b):
    """vec(Q^(a) Q^(b)*): the vector part of a Hamilton product with a conjugate."""
    pw, px, py, pz = Q[0][a], Q[1][a], Q[2][a], Q[3][a]
    qw, qx, qy, qz = Q[0][b], -Q[1][b], -Q[2][b], -Q[3][b]
    return (
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def evaluate_range(a, b, t, seg, times, inv_h, left, right, blend, tab, out_q, out_w):
    """Samples a..b-1."""
    for m in range(a, b):
        sample(m, t, seg, times, inv_h, left, right, blend, tab, out_q, out_w)


# SmoothSpline (trajgen.smooth): q = E q_i, E = exp(r_i(u)) = (C(x), S(x) r), x = r . r,
# the arithmetic of SmoothSpline._space_rates one sample at a time.


def horner7(poly, i, row, u):
    """Row ``row`` of segment ``i``'s coefficient table (powers u^0..u^7) at ``u``."""
    p = poly[i, row, 7]
    for k in range(6, -1, -1):
        p = p * u + poly[i, row, k]
    return p


def tangent(poly, i, axis, u):
    """``r_i``'s component ``axis`` and its first three time derivatives at ``u``."""
    return (
        horner7(poly, i, axis, u),
        horner7(poly, i, 3 + axis, u),
        horner7(poly, i, 6 + axis, u),
        horner7(poly, i, 9 + axis, u),
    )


def smooth_sample(m, t, seg, times, poly, quats, out_q, out_w):
    """Sample m: unit quaternion into out_q[m], omega, alpha, jerk into out_w[:, m]."""
    i = seg[m]
    u = (t[m] - times[i]) / (times[i + 1] - times[i])
    E = exp_of(tangent(poly, i, 0, u), tangent(poly, i, 1, u), tangent(poly, i, 2, u))
    q = hamilton(
        (E[0][0], E[1][0], E[2][0], E[3][0]), (quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3])
    )
    for c in range(4):
        out_q[m, c] = q[c]
    space_rates(E, m, out_w)


def exp_of(rx, ry, rz):
    """``E = exp(r) = (C(x), S(x) r)``, ``x = r . r``, from the three derivative lists
    of a vector ``r``: the unit quaternion's four."""
    C, S = cos_sinc_sqrt(add(add(prod(rx, rx), prod(ry, ry)), prod(rz, rz)))
    return (C, prod(S, rx), prod(S, ry), prod(S, rz))


def smooth_range(a, b, t, seg, times, poly, quats, out_q, out_w):
    """Samples a..b-1 of a SmoothSpline."""
    for m in range(a, b):
        smooth_sample(m, t, seg, times, poly, quats, out_q, out_w)
