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
import math

import numpy as np

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


class _Floats:
    """The numpy functions :func:`_distance` uses, on Python floats (on one number a
    few times faster than numpy's)."""

    sqrt, abs, maximum, minimum = math.sqrt, abs, max, min

    @staticmethod
    def where(condition, a, b):
        return a if condition else b


def _speed_change(vs, a_s, ve, acc, jerk):
    """The fastest change of speed from ``vs`` at acceleration ``a_s`` to ``ve`` at zero
    acceleration with ``|a| <= acc``, ``|j| <= jerk`` (floats): phase durations (s) and
    jerks (rad/s^3), 3 each."""
    stop = vs + a_s * abs(a_s) / (2.0 * jerk)  # the speed where the acceleration is back to 0
    sg = 1.0 if ve >= stop else -1.0
    top = min(math.sqrt(max(0.5 * (2.0 * jerk * sg * (ve - vs) + a_s * a_s), 0.0)), acc)
    ap = sg * top
    t1 = max((ap - a_s) * sg / jerk, 0.0)
    t3 = top / jerk
    ramps = 0.5 * (a_s + ap) * t1 + 0.5 * ap * t3
    t2 = max((ve - vs - ramps) / ap, 0.0) if top > 0.0 else 0.0
    return [t1, t2, t3], [sg * jerk, 0.0, -sg * jerk]


def _phases(v0, a0, j0, hold, vp, cruise, acc, jerk):
    """Durations and jerks (8 each, floats) of the profile that first runs jerk ``j0``
    for ``hold`` (s), then changes the speed to ``vp``, cruises for ``cruise`` (s) and
    stops."""
    v1 = v0 + hold * (a0 + hold * j0 / 2.0)
    d1, j1 = _speed_change(v1, a0 + hold * j0, vp, acc, jerk)
    d3, j3 = _speed_change(vp, 0.0, 0.0, acc, jerk)
    return [hold, *d1, cruise, *d3], [j0, *j1, 0.0, *j3]


def _distance(v0, a0, j0, hold, vp, acc, jerk, xp=np):
    """Displacement (rad) of :func:`_phases`' profile without its cruise, in closed form
    (the phases of :func:`_speed_change` integrated where they are computed; the stop
    from ``(vp, 0)`` is symmetric, so it covers ``vp`` times half its duration): arrays
    that broadcast, or floats with ``xp=_Floats``."""
    x = hold * (v0 + hold * (a0 / 2.0 + hold * j0 / 6.0))
    v = v0 + hold * (a0 + hold * j0 / 2.0)
    a = a0 + hold * j0
    stop = v + a * xp.abs(a) / (2.0 * jerk)
    sg = xp.where(vp >= stop, 1.0, -1.0)
    top = xp.minimum(xp.sqrt(xp.maximum(0.5 * (2.0 * jerk * sg * (vp - v) + a * a), 0.0)), acc)
    ap = sg * top
    t1 = xp.maximum((ap - a) * sg / jerk, 0.0)
    t3 = top / jerk
    j1 = sg * jerk
    x = x + t1 * (v + t1 * (a / 2.0 + t1 * j1 / 6.0))
    v = v + t1 * (a + t1 * j1 / 2.0)
    t2 = xp.maximum((vp - v - 0.5 * ap * t3) / xp.where(top > 0.0, ap, 1.0), 0.0) * (top > 0.0)
    x = x + t2 * (v + t2 * ap / 2.0)
    v = v + t2 * ap
    x = x + t3 * (v + t3 * (ap / 2.0 - t3 * j1 / 6.0))
    speed = xp.abs(vp)
    top = xp.minimum(xp.sqrt(jerk * speed), acc)
    return x + vp * (
        top / jerk + 0.5 * xp.maximum(speed / xp.where(top > 0, top, 1.0) - top / jerk, 0.0)
    )


def _root(fun, lo, hi, flo, fhi):
    """The root of ``fun`` (floats) between ``lo`` and ``hi``, where its values ``flo``,
    ``fhi`` differ in sign, by regula falsi (Illinois)."""
    side, mid = 0, hi
    for _ in range(ROOT_ITERATIONS):
        mid = hi - fhi * (hi - lo) / (fhi - flo) if fhi != flo else hi
        fm = fun(mid)
        if abs(fm) < ROOT_TOLERANCE_RAD:
            break
        if (fm > 0.0) == (flo > 0.0):  # the root lies between mid and hi
            lo, flo = mid, fm
            fhi = fhi / 2.0 if side > 0 else fhi
            side = 1
        else:
            hi, fhi = mid, fm
            flo = flo / 2.0 if side < 0 else flo
            side = -1
    return mid


def fastest(x0, v0, a0, goal, limits):
    """Each joint's fastest motion to rest at its goal within the limits: see
    :func:`fastest_steps`."""
    return run_steps(fastest_steps(x0, v0, a0, goal, limits))


def fastest_steps(x0, v0, a0, goal, limits):
    """Each joint's fastest motion to rest at its goal within the limits, as a generator
    of steps (the candidates' grid in two, then one joint a step; each well under a
    millisecond); its value is the motion.

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
    The candidates, each joint on its own: a peak speed ``vp`` whose two speed changes
    cover the distance (roots over a grid of ``vp`` in [-V, V]); a cruise at ``+V`` or
    ``-V``; and, for a distance between a full stop's and that of a stop after the
    acceleration is first brought to zero (a gap the first family bridges only with a
    pause at zero acceleration), a first phase that keeps the acceleration, or turns it
    towards zero, for a time (roots over that time) before a full stop. The distance
    is evaluated on every joint's grid at once (numpy); each root is refined, and the
    candidates compared, in floats (a handful per joint). The fastest within the limits
    wins.
    """
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
    yield
    f = dist - _distance(v, a, j0, grid * (1.0 - is_peak), grid * is_peak, acc, jerk)
    grid, f, j0 = grid.tolist(), f.tolist(), j0[:, :, 0].tolist()
    durations, jerks = [], []
    for i, state in enumerate(zip(v0.tolist(), a0.tolist(), (goal - x0).tolist(), strict=True)):
        yield
        d, j = _joint_fastest(*state, *limits[:, i].tolist(), grid[i], f[i], j0[i])
        durations.append(d)
        jerks.append(j)
    return np.array(durations), np.array(jerks)


def _joint_fastest(v, a, dist, vmax, acc, jerk, grid, short, j0):
    """One joint's fastest motion (durations, jerks: 8 floats each) from speed ``v`` and
    acceleration ``a`` over ``dist`` (rad), given each family's grid (3 lists of
    ``PEAK_GRID``), the distance short of ``dist`` there and its first jerk (3)."""
    if dist == 0.0 and v == 0.0 and a == 0.0:  # at rest on its goal already
        return [0.0] * PHASES, [0.0] * PHASES
    found = []  # (hold, first jerk, vp, cruise) of each candidate
    for fam in range(3):
        g, fv, jf = grid[fam], short[fam], j0[fam]
        if fam and g[0] == g[-1]:  # no time to hold or turn: the first family's stop
            continue

        def shortfall(p, jf=jf, fam=fam):
            hold, vp = (0.0, p) if fam == 0 else (p, 0.0)
            return dist - _distance(v, a, jf, hold, vp, acc, jerk, _Floats)

        for k in range(PEAK_GRID - 1):
            if fv[k] == 0.0 or fv[k + 1] == 0.0:
                p = g[k] if fv[k] == 0.0 else g[k + 1]
            elif (fv[k] > 0.0) != (fv[k + 1] > 0.0):
                p = _root(shortfall, g[k], g[k + 1], fv[k], fv[k + 1])
            else:
                continue
            found.append((0.0, jf, p, 0.0) if fam == 0 else (p, jf, 0.0, 0.0))
    for vp, rest in ((-vmax, short[0][0]), (vmax, short[0][-1])):
        if rest / vp >= 0.0:  # a cruise at the speed limit covers the rest
            found.append((0.0, 0.0, vp, rest / vp))
    phases = sorted(
        (sum(d), d, j)
        for d, j in (
            _phases(v, a, jf, hold, vp, cruise, acc, jerk) for hold, jf, vp, cruise in found
        )
    )
    # the fastest that keeps the limits; the fastest, if none can from this start
    best = next((p for p in phases if _keeps(v, a, p[1], p[2], vmax, acc)), phases[0])
    return best[1], best[2]


def _keeps(v, a, durations, jerks, vmax, acc):
    """Whether phases (``durations``, ``jerks``, floats) from speed ``v`` and acceleration
    ``a`` keep ``|speed| <= vmax`` and ``|acceleration| <= acc`` (to rounding): at the
    start, the knots, and where the acceleration passes zero inside a phase."""
    tol = 1.0 + 1e-9
    vmax, acc = vmax * tol, acc * tol
    if abs(v) > vmax or abs(a) > acc:
        return False
    for d, j in zip(durations, jerks, strict=True):
        if j != 0.0 and 0.0 < -a / j < d and abs(v - a * a / (2.0 * j)) > vmax:
            return False
        v, a = v + d * (a + d * j / 2.0), a + d * j
        if abs(v) > vmax or abs(a) > acc:
            return False
    return True


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
        n = len(goal)
        self.goal = np.asarray(goal, dtype=float)
        #: Per joint, in floats: knot times (s, from the start), angle, speed,
        #: acceleration there, and the jerk after each knot (0 after the last).
        self._rows = []
        starts = (np.asarray(s, dtype=float).tolist() for s in (x0, v0, a0))
        for i, (x, v, a) in enumerate(zip(*starts, strict=True)):
            ts, xs, vs, as_ = [0.0], [x], [v], [a]
            js = [*np.asarray(jerks[i]).tolist(), 0.0]
            for d, j in zip(np.asarray(durations[i]).tolist(), js[:-1], strict=True):
                x = x + d * (v + d * (a / 2.0 + d * j / 6.0))
                v = v + d * (a + d * j / 2.0)
                a = a + d * j
                ts.append(ts[-1] + d)
                xs.append(x)
                vs.append(v)
                as_.append(a)
            xs[-1], vs[-1], as_[-1] = float(self.goal[i]), 0.0, 0.0  # rest exactly at the goal
            self._rows.append((ts, xs, vs, as_, js))
        #: Knot times (n, P + 1) (s, from the start), states there, jerk after (n, P + 1).
        self.knots, self.x, self.v, self.a, self.j = (
            np.array([row[k] for row in self._rows]).reshape(n, -1) for k in range(5)
        )
        self.duration = float(self.knots[:, -1].max())
        self._flat = [a.ravel() for a in (self.knots, self.x, self.v, self.a, self.j)]

    def state(self, tau: np.ndarray):
        """Angles, speeds, accelerations, jerks (each (M, n)) at times ``tau`` (M,) (s
        from the start; rest at the goal after each joint's last phase)."""
        tau = np.asarray(tau, dtype=float)
        n, p = self.knots.shape
        # (M, n): the phase, that of the last knot at or before tau (0 before the start)
        k = np.stack([np.searchsorted(kn[1:], tau, side="right") for kn in self.knots], axis=1)
        at = k + p * np.arange(n)
        knot, x, v, a, j = (np.take(f, at) for f in self._flat)
        d = np.where(k == p - 1, 0.0, tau[:, None] - knot)
        return np.stack(
            [
                x + d * (v + d * (a / 2.0 + d * j / 6.0)),
                v + d * (a + d * j / 2.0),
                a + d * j,
                j,
            ]
        )

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
