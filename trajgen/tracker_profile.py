"""Jerk-limited joint motions for untimed targets, and the path segment that plays one.

Part of :mod:`trajgen.tracker`. Each joint goes from its present angle, speed and
acceleration to rest at its goal in the least time that keeps ``|speed| <= V``,
``|acceleration| <= A`` and ``|jerk| <= J`` (a double-S, or seven-phase, profile:
jerk ``+-J`` or 0 in each phase), independently of the other joints;
:class:`~trajgen.joint_splice.JointSplice` is the orientation path of the joints'
motion, ``forward(x(t))`` through the gimbal's axis sequence, played by
:class:`~trajgen.online.OnlineSpline` as a splice (the same interface as
:class:`~trajgen.online_splice.Splice`).

The profile (:func:`fastest`): change the speed from ``(v0, a0)`` to a peak ``vp``
with zero acceleration, cruise at ``vp``, change it from ``(vp, 0)`` to rest. Each
speed change is the fastest one (a ramp of the acceleration at ``J`` to a peak, a
plateau at ``A`` if the peak would pass it, a ramp back); the distance it covers grows
with ``vp``, so ``vp`` is either ``+-V`` with a cruise, or the one peak speed whose two
changes cover the distance to go with no cruise (a root, found by regula falsi). The
seven phases are piecewise cubic in time: angle, speed and acceleration are continuous
(C2), the jerk is piecewise constant; the orientation path ``forward(x(t))`` is C2 in
time wherever the joints' motion is, and its angular velocity, acceleration and jerk are
exact (:func:`~trajgen.joint_splice.joint_frame`).
"""

from __future__ import annotations

import bisect

import numpy as np

from .joint_splice import JointSplice as JointSplice  # its home was here: imports kept
from .path import run_steps

#: Phases of a joint's profile: a hold of the acceleration, a speed change (3), a
#: cruise, a speed change to rest (3).
PHASES = 8

#: Peak speeds per joint at which the distance covered is first evaluated, over [-V, V].
PEAK_GRID = 17

#: Iterations (at most) of the regula falsi on the peak speed, and the distance (rad) at
#: which it stops.
ROOT_ITERATIONS = 60
ROOT_TOLERANCE_RAD = 1e-14


def _speed_change(vs, a_s, ve, acc, jerk):
    """The fastest change of speed from ``vs`` at acceleration ``a_s`` to ``ve`` at zero
    acceleration with ``|a| <= acc``, ``|j| <= jerk`` (arrays that broadcast): phase
    durations (..., 3) (s) and jerks (..., 3) (rad/s^3)."""
    stop = vs + a_s * np.abs(a_s) / (2.0 * jerk)  # the speed where the acceleration is back to 0
    sg = np.where(ve >= stop, 1.0, -1.0)
    peak2 = 0.5 * (2.0 * jerk * sg * (ve - vs) + a_s * a_s)
    top = np.minimum(np.sqrt(np.maximum(peak2, 0.0)), acc)
    ap = sg * top
    t1 = np.maximum((ap - a_s) * sg / jerk, 0.0)
    t3 = top / jerk
    ramps = 0.5 * (a_s + ap) * t1 + 0.5 * ap * t3
    safe = np.where(top > 0.0, ap, 1.0)
    t2 = np.where(top > 0.0, np.maximum((ve - vs - ramps) / safe, 0.0), 0.0)
    jerks = np.stack(np.broadcast_arrays(sg * jerk, 0.0 * sg, -sg * jerk), axis=-1)
    return np.stack(np.broadcast_arrays(t1, t2, t3), axis=-1), jerks


def _integrate(x, v, a, durations, jerks):
    """States (x, v, a), each (..., P + 1), at the knots of phases of constant jerk
    (durations and jerks (..., P)) from ``(x, v, a)`` (...)."""
    xs, vs, as_ = [x], [v], [a]
    for k in range(durations.shape[-1]):
        d, j = durations[..., k], jerks[..., k]
        x = x + d * (v + d * (a / 2.0 + d * j / 6.0))
        v = v + d * (a + d * j / 2.0)
        a = a + d * j
        xs.append(x)
        vs.append(v)
        as_.append(a)
    return np.stack(xs, axis=-1), np.stack(vs, axis=-1), np.stack(as_, axis=-1)


def _phases(v0, a0, j0, hold, vp, cruise, acc, jerk):
    """Durations and jerks (..., 8) of the profile that first runs jerk ``j0`` for
    ``hold`` (s), then changes the speed to ``vp``, cruises for ``cruise`` (s) and stops."""
    v1 = v0 + hold * (a0 + hold * j0 / 2.0)
    d1, j1 = _speed_change(v1, a0 + hold * j0, vp, acc, jerk)
    d3, j3 = _speed_change(vp, 0.0, 0.0, acc, jerk)
    shape = np.broadcast_shapes(d1.shape[:-1], d3.shape[:-1])
    d1, j1, d3, j3 = (np.broadcast_to(x, (*shape, 3)) for x in (d1, j1, d3, j3))
    h = np.broadcast_to(hold, shape)[..., None]
    c = np.broadcast_to(cruise, shape)[..., None]
    first = np.broadcast_to(j0, shape)[..., None]
    return (
        np.concatenate([h, d1, c, d3], axis=-1),
        np.concatenate([first, j1, np.zeros_like(c), j3], axis=-1),
    )


def _distance(v0, a0, j0, hold, vp, acc, jerk):
    """Displacement (rad) of :func:`_phases`' profile without its cruise, in closed form
    (the phases of :func:`_speed_change` integrated where they are computed; the stop
    from ``(vp, 0)`` is symmetric, so it covers ``vp`` times half its duration)."""
    x = hold * (v0 + hold * (a0 / 2.0 + hold * j0 / 6.0))
    v = v0 + hold * (a0 + hold * j0 / 2.0)
    a = a0 + hold * j0
    stop = v + a * np.abs(a) / (2.0 * jerk)
    sg = np.where(vp >= stop, 1.0, -1.0)
    top = np.minimum(np.sqrt(np.maximum(0.5 * (2.0 * jerk * sg * (vp - v) + a * a), 0.0)), acc)
    ap = sg * top
    t1 = np.maximum((ap - a) * sg / jerk, 0.0)
    t3 = top / jerk
    j1 = sg * jerk
    x = x + t1 * (v + t1 * (a / 2.0 + t1 * j1 / 6.0))
    v = v + t1 * (a + t1 * j1 / 2.0)
    t2 = np.maximum((vp - v - 0.5 * ap * t3) / np.where(top > 0.0, ap, 1.0), 0.0) * (top > 0.0)
    x = x + t2 * (v + t2 * ap / 2.0)
    v = v + t2 * ap
    x = x + t3 * (v + t3 * (ap / 2.0 - t3 * j1 / 6.0))
    speed = np.abs(vp)
    top = np.minimum(np.sqrt(jerk * speed), acc)
    return x + vp * (
        top / jerk + 0.5 * np.maximum(speed / np.where(top > 0, top, 1.0) - top / jerk, 0.0)
    )


def _root_steps(fun, grid, f):
    """Every root of ``fun`` between neighbours of ``grid`` (..., G) where ``f`` (its
    values there) changes sign, by regula falsi (Illinois): (..., G - 1), NaN where
    there is none. A generator of steps (one an iteration); its value is the roots."""
    lo, hi, flo, fhi = grid[..., :-1], grid[..., 1:], f[..., :-1], f[..., 1:]
    found = (np.sign(flo) != np.sign(fhi)) | (flo == 0.0)
    at_lo = flo == 0.0
    hi, fhi = np.where(at_lo, lo, hi), np.where(at_lo, 0.0, fhi)
    flo, fhi = np.where(found, flo, 1.0), np.where(found, fhi, -1.0)
    side = np.zeros(lo.shape)
    mid = hi
    for _ in range(ROOT_ITERATIONS):
        den = fhi - flo
        mid = np.where(den != 0.0, hi - fhi * (hi - lo) / np.where(den != 0.0, den, 1.0), hi)
        fm = fun(mid)
        if np.all(~found | (np.abs(fm) < ROOT_TOLERANCE_RAD)):
            break
        yield
        same = np.sign(fm) == np.sign(flo)  # the root lies between mid and hi
        flo = np.where(same, fm, np.where(side < 0, flo / 2.0, flo))
        fhi = np.where(same, np.where(side > 0, fhi / 2.0, fhi), fm)
        lo, hi = np.where(same, mid, lo), np.where(same, hi, mid)
        side = np.where(same, 1.0, -1.0)
    return np.where(found, mid, np.nan)


def fastest(x0, v0, a0, goal, limits):
    """Each joint's fastest motion to rest at its goal within the limits: see
    :func:`fastest_steps`."""
    return run_steps(fastest_steps(x0, v0, a0, goal, limits))


def fastest_steps(x0, v0, a0, goal, limits):
    """Each joint's fastest motion to rest at its goal within the limits, as a generator
    of steps (one an iteration of the root search; each well under a millisecond);
    its value is the motion.

    Parameters
    ----------
    x0, v0, a0 : ndarray, shape (n,)
        Angles (rad), speeds (rad/s) and accelerations (rad/s^2) now.
    goal : ndarray, shape (n,)
        Goal angles (rad).
    limits : ndarray, shape (3, n)
        ``V``, ``A``, ``J`` per joint (rad/s, rad/s^2, rad/s^3), finite and > 0.

    Returns
    -------
    (ndarray, ndarray)
        Phase durations (s) and jerks (rad/s^3), each (n, 8). A start beyond ``V`` or
        ``A`` gives a profile beyond them too (:meth:`JointProfile.peaks` tells).

    Notes
    -----
    The candidates, each joint on its own, all solved at once: a peak speed ``vp`` whose
    two speed changes cover the distance (roots over a grid of ``vp`` in [-V, V]); a
    cruise at ``+V`` or ``-V``; and, for a distance between a full stop's and that of a
    stop after the acceleration is first brought to zero (a gap the first family
    bridges only with a pause at zero acceleration), a first phase that keeps the
    acceleration, or turns it towards zero, for a time (roots over that time) before a
    full stop. The fastest within the limits wins.
    """
    n = len(x0)
    vmax, acc, jerk = (x[:, None, None] for x in limits)
    v, a, dist = v0[:, None, None], a0[:, None, None], (goal - x0)[:, None, None]
    unit = np.linspace(-1.0, 1.0, PEAK_GRID)
    # Families (axis 1): peak speed; hold the acceleration; turn it towards zero.
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(a != 0.0, (np.sign(a) * vmax - v) / a, 1.0)
    spans = np.concatenate(
        [2.0 * vmax, np.clip(room, 0.0, 1.0), np.abs(a) / jerk + 0.0 * vmax], axis=1
    )
    grid = spans * ((unit + 1.0) / 2.0) + np.array([-1.0, 0.0, 0.0])[:, None] * vmax
    is_peak = np.array([1.0, 0.0, 0.0])[:, None]
    j0 = np.concatenate([0.0 * a, 0.0 * a, -np.sign(a) * jerk], axis=1)

    def shortfall(p):
        return dist - _distance(v, a, j0, p * (1.0 - is_peak), p * is_peak, acc, jerk)

    f = shortfall(grid)
    yield
    roots = (yield from _root_steps(shortfall, grid, f)).reshape(n, -1)
    yield  # (n, 3 (G - 1))
    cruise_v = np.concatenate([-vmax, vmax], axis=1)[:, :, 0]  # (n, 2)
    params = np.concatenate([roots, np.zeros((n, 2))], axis=1)
    fam = np.concatenate([np.repeat(np.arange(3), PEAK_GRID - 1), [0, 0]])
    hold = np.where(fam == 0, 0.0, params)
    vp = np.where(fam == 0, params, 0.0)
    vp[:, -2:] = cruise_v
    cruise = np.zeros_like(vp)
    cruise[:, -2:] = f[:, 0, [0, -1]] / cruise_v
    valid = ~np.isnan(params) & (cruise >= 0.0)
    hold, vp = np.nan_to_num(hold), np.nan_to_num(vp)
    jj = np.where(fam == 2, -np.sign(a0)[:, None] * limits[2][:, None], 0.0)
    v, a, vmax, acc, jerk = (x[:, :, 0] for x in (v, a, vmax, acc, jerk))
    d, j = _phases(v, a, jj, hold, vp, cruise, acc, jerk)
    total = np.where(valid, d.sum(axis=-1), np.inf)
    rows = np.arange(n)
    best = np.argmin(total, axis=1)
    fits = _fits(v[:, 0], a[:, 0], d[rows, best], j[rows, best], vmax[:, 0], acc[:, 0])
    if not fits.all():  # the fastest breaks a limit (from a start that must): the fastest that
        yield  # does not, if any
        keep = _fits(v, a, d, j, vmax, acc)
        other = np.argmin(np.where(keep, total, np.inf), axis=1)
        best = np.where(~fits & keep[rows, other], other, best)
    return d[rows, best], j[rows, best]


def _fits(v0, a0, d, j, vmax, acc):
    """Whether phases (durations ``d``, jerks ``j``, (..., P)) from speed ``v0`` and
    acceleration ``a0`` keep ``|v| <= vmax`` and ``|a| <= acc`` (to rounding)."""
    zero = np.zeros(d.shape[:-1])
    _, vk, ak = _integrate(zero, v0 + zero, a0 + zero, d, j)
    tol = 1.0 + 1e-9
    return (_peak_speed(vk, ak, d, j) <= vmax * tol) & (np.abs(ak).max(axis=-1) <= acc * tol)


def _peak_speed(vk, ak, d, j):
    """Peak |speed| of phases of constant jerk: at the knots (speeds ``vk``,
    accelerations ``ak``, (..., P + 1)) and where the acceleration passes zero inside a
    phase (durations ``d``, jerks ``j``, (..., P))."""
    v, a = vk[..., :-1], ak[..., :-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(j != 0.0, -a / np.where(j != 0.0, j, 1.0), -1.0)
    inside = (t > 0.0) & (t < d)
    v_in = np.where(inside, v + a * t + 0.5 * j * t * t, 0.0)
    return np.maximum(np.abs(vk).max(axis=-1), np.abs(v_in).max(axis=-1))


class JointProfile:
    """Piecewise-cubic joint angles: each joint's phases from a start state, then rest.

    Parameters
    ----------
    x0, v0, a0 : ndarray, shape (n,)
        Start angles (rad), speeds (rad/s), accelerations (rad/s^2).
    durations, jerks : ndarray, shape (n, P)
        Each joint's phases of constant jerk (s, rad/s^3).
    goal : ndarray, shape (n,)
        Where each joint rests after its last phase (rad): its angle there to rounding.
    """

    def __init__(self, x0, v0, a0, durations, jerks, goal):
        x, v, a = _integrate(x0, v0, a0, durations, jerks)
        x[:, -1], v[:, -1], a[:, -1] = goal, 0.0, 0.0  # rest exactly at the goal
        #: Knot times (n, P + 1) (s, from the start), states there, jerk after (n, P + 1).
        self.knots = np.concatenate([np.zeros((len(x0), 1)), np.cumsum(durations, axis=1)], 1)
        self.x, self.v, self.a = x, v, a
        self.j = np.concatenate([jerks, np.zeros((len(x0), 1))], axis=1)
        self.goal = np.asarray(goal, dtype=float)
        self.duration = float(self.knots[:, -1].max())
        self._rows = [
            (
                self.knots[i].tolist(),
                x[i].tolist(),
                v[i].tolist(),
                a[i].tolist(),
                self.j[i].tolist(),
            )
            for i in range(len(x0))
        ]

    def state(self, tau: np.ndarray):
        """Angles, speeds, accelerations, jerks (each (M, n)) at times ``tau`` (M,) (s
        from the start; rest at the goal after each joint's last phase)."""
        out = np.empty((4, len(tau), len(self.goal)))
        for i in range(len(self.goal)):
            k = np.clip(np.searchsorted(self.knots[i], tau, side="right") - 1, 0, None)
            d = np.where(k == self.knots.shape[1] - 1, 0.0, tau - self.knots[i, k])
            x, v, a, j = self.x[i, k], self.v[i, k], self.a[i, k], self.j[i, k]
            out[0, :, i] = x + d * (v + d * (a / 2.0 + d * j / 6.0))
            out[1, :, i] = v + d * (a + d * j / 2.0)
            out[2, :, i] = a + d * j
            out[3, :, i] = j
        return out

    def state_at(self, tau: float) -> list[tuple[float, float, float, float]]:
        """:meth:`state` at one time, in floats: ``(x, v, a, j)`` per joint."""
        out = []
        for knots, x, v, a, j in self._rows:
            k = max(bisect.bisect_right(knots, tau) - 1, 0)
            d = 0.0 if k == len(knots) - 1 else tau - knots[k]
            out.append(
                (
                    x[k] + d * (v[k] + d * (a[k] / 2.0 + d * j[k] / 6.0)),
                    v[k] + d * (a[k] + d * j[k] / 2.0),
                    a[k] + d * j[k],
                    j[k],
                )
            )
        return out

    def peaks(self) -> np.ndarray:
        """Peak |speed|, |acceleration|, |jerk| (rows) per joint (columns), exactly: the
        speeds at the knots and where the acceleration passes zero inside a phase."""
        dt = np.diff(self.knots, axis=1)
        speed = _peak_speed(self.v, self.a, dt, self.j[:, :-1])
        jerk = np.where(dt > 0.0, np.abs(self.j[:, :-1]), 0.0).max(axis=1)
        return np.stack([speed, np.abs(self.a).max(axis=1), jerk])
