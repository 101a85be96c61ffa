"""The bounded preview: led goals that anticipate where a bound clips them.

Where the model lead (``trajgen.lead``) asks for a goal past its bound (at a
reversal the lead overshoots the plan's own range by about
``|qdd| (tau^2/2 - J/kp)``), clipping that goal leaves the servo short. This
module spreads the correction over the frames around the clip instead. Against
the servo loop's own linear model (the firmware's P loop into a DC motor, the
model the lead comes from, ``docs/lead.md``), a deviation ``dg`` of the goal
from the unbounded model lead moves the servo off the plan by ``e``, with

    J e'' + c e' + kp e = kp dg(t),   c = K^2/R + b = kp tau,

``dg`` held for one stream period per frame. ``e`` at the frame times is
``H dg``, ``H`` the lower-triangular Toeplitz matrix of the loop's pulse
response (exact zero-order-hold discretisation). Per joint, over each window
of frames around a clip, the goals solve the box-constrained least squares

    minimise ||H dg||^2 + REGULARISATION ||D dg||^2,   lo - g* <= dg <= hi - g*,

``g*`` the unbounded goals, ``[lo, hi]`` their bounds per frame and ``D dg``
the deviation's steps from frame to frame (from 0 before the window and back to
0 after it): each step of a goal is a torque step of ``kp`` times it, so the
penalty keeps the peak torque at that of the clipped lead. Frames
before the clip then push a little harder, so the servo arrives without a goal
past the bound. Every goal stays inside its bounds; where nothing is clipped
the goals are untouched. It is a pure function of the plan, numpy only.
"""

from __future__ import annotations

import numpy as np

#: Weight of the deviation's frame-to-frame steps ``||D dg||^2`` against the error
#: ``||e||^2`` (both rad^2). On bus_u2d2 (``docs/lead.md``) 3 keeps the peak torque
#: below no lead's (0.98x) for 2.57 mrad; 0.01 gives 2.51 mrad at 1.3x.
REGULARISATION = 3.0
#: The pulse response is cut where it falls below this fraction of its peak; that
#: length is also how far a window reaches before and after a clip.
RESPONSE_CUTOFF = 1e-3


def expm(a: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small square matrix: scaling and squaring of a
    degree-16 Taylor series (exact to rounding for the loop's 3 x 3 blocks)."""
    a = np.asarray(a, dtype=float)
    norm = np.abs(a).sum(axis=1).max()
    squarings = max(0, int(np.ceil(np.log2(norm))) + 1) if norm > 0.5 else 0
    a = a / 2.0**squarings
    result = term = np.eye(len(a))
    for k in range(1, 17):
        term = term @ a / k
        result = result + term
    for _ in range(squarings):
        result = result @ result
    return result


def pulse_response(kp: float, c: float, inertia: float, period_s: float) -> np.ndarray:
    """The servo's error at frames 1, 2, ... after a unit goal deviation held over frame 0.

    Parameters
    ----------
    kp : float
        Loop stiffness (N m/rad).
    c : float
        Loop damping ``K^2/R + b`` (N m s/rad).
    inertia : float
        Joint inertia (kg m^2).
    period_s : float
        Stream period (s).

    Returns
    -------
    ndarray, shape (L,)
        ``h[k]`` = error (rad per rad) at ``t = (k + 1) T``, cut where ``|h|`` stays
        below ``RESPONSE_CUTOFF`` of its peak (at least 2 entries).
    """
    a = np.array([[0.0, 1.0, 0.0], [-kp / inertia, -c / inertia, kp / inertia], [0.0, 0.0, 0.0]])
    step = expm(a * period_s)
    ad, bd = step[:2, :2], step[:2, 2]
    x, h = bd.copy(), [bd[0]]
    peak, quiet = abs(bd[0]), 0
    while quiet < 8 and len(h) < 100_000:  # the loop is stable: it decays
        x = ad @ x
        h.append(x[0])
        peak = max(peak, abs(x[0]))
        quiet = quiet + 1 if abs(x[0]) < RESPONSE_CUTOFF * peak else 0
    return np.array(h[: max(2, len(h) - quiet)])


def box_least_squares(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``x`` minimising ``||a x - b||^2`` subject to ``lo <= x <= hi`` (a primal active set).

    ``a`` must have full column rank (the preview's step penalty gives it). From
    a feasible start, each step solves the free variables with the others held at
    their bounds, walks towards that solution until a bound blocks it (and holds
    the blocking variable there), or, once the free solution is feasible, frees the
    held variable whose bound most resists (its gradient points inside). Strictly
    convex, so the optimum is unique; the iteration count is capped.

    Parameters
    ----------
    a : ndarray, shape (m, k)
    b : ndarray, shape (m,)
    lo, hi : ndarray, shape (k,)
        ``lo <= hi``.

    Returns
    -------
    ndarray, shape (k,)
    """
    q, r = a.T @ a, a.T @ b
    x = np.clip(np.zeros(len(lo)), lo, hi)
    held = (x == lo) | (x == hi)
    scale = np.abs(q).max()
    for _ in range(10 * len(x) + 20):
        free = ~held
        target = x.copy()
        if free.any():
            rhs = r[free] - q[np.ix_(free, held)] @ x[held]
            target[free] = np.linalg.solve(q[np.ix_(free, free)], rhs)
        step = target - x
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(step > 0, (hi - x) / step, np.where(step < 0, (lo - x) / step, np.inf))
        room = np.where(free, room, np.inf)
        alpha = min(1.0, room.min()) if room.size else 1.0
        x = np.clip(x + alpha * step, lo, hi)
        if alpha < 1.0:
            blocked = free & (room <= alpha)
            # at the bound exactly: roundoff would leave it inside, never released
            x[blocked] = np.where(step[blocked] > 0, hi[blocked], lo[blocked])
            held |= blocked
            continue
        gradient = q @ x - r  # half the gradient; at a held bound it must point outwards
        pull = np.where(x <= lo, -gradient, np.where(x >= hi, gradient, 0.0))
        pull = np.where(held & (lo < hi), pull, 0.0)
        j = int(np.argmax(pull))
        if pull[j] <= 1e-12 * scale * (1.0 + np.abs(x).max()):
            return x
        held[j] = False
    return x


def preview_goals(goal, lo, hi, period_s: float, kp, c, inertia) -> tuple[np.ndarray, np.ndarray]:
    """Bounded goals that anticipate their clips, per joint (see the module docstring).

    Parameters
    ----------
    goal : ndarray, shape (N, n)
        The unbounded goals ``g*`` (rad).
    lo, hi : ndarray, shape (N, n)
        Each frame's bounds (rad), ``lo <= hi``.
    period_s : float
        Stream period (s).
    kp, c, inertia : array_like, shape (n,)
        Each joint's loop stiffness (N m/rad), damping (N m s/rad) and inertia (kg m^2).

    Returns
    -------
    goal : ndarray, shape (N, n)
        Inside ``[lo, hi]``; equal to ``g*`` outside the windows around a clip.
    changed : ndarray of int, shape (n,)
        Frames per joint whose goal differs from ``g*``.
    """
    goal = np.asarray(goal, dtype=float)
    out = np.clip(goal, lo, hi)
    for j in range(goal.shape[1]):
        clip_frames = np.flatnonzero(out[:, j] != goal[:, j])
        if not len(clip_frames):
            continue
        h = pulse_response(float(kp[j]), float(c[j]), float(inertia[j]), period_s)
        for first, last in _windows(clip_frames, len(h), len(goal)):
            d_lo = lo[first:last, j] - goal[first:last, j]
            d_hi = hi[first:last, j] - goal[first:last, j]
            out[first:last, j] = goal[first:last, j] + _solve_window(h, d_lo, d_hi)
        out[:, j] = np.clip(out[:, j], lo[:, j], hi[:, j])  # rounding of the solve
    return out, (out != goal).sum(axis=0)


def _windows(frames: np.ndarray, reach: int, n_frames: int):
    """``(first, last)`` frame ranges: each clip widened by ``reach`` both ways, overlaps merged."""
    windows: list[list[int]] = []
    for f in frames:
        first, last = max(0, int(f) - reach), min(n_frames, int(f) + reach + 1)
        if windows and first <= windows[-1][1]:
            windows[-1][1] = max(windows[-1][1], last)
        else:
            windows.append([first, last])
    return [tuple(w) for w in windows]


def _solve_window(h: np.ndarray, d_lo: np.ndarray, d_hi: np.ndarray) -> np.ndarray:
    """The goal deviations of one window: the error over the window and the response's
    tail after it, least squares, each deviation inside ``[d_lo, d_hi]``."""
    k = len(d_lo)
    rows = k + len(h)
    response = np.zeros((rows, k))
    for m in range(k):  # column m: the error the deviation at frame m causes
        response[m : m + len(h), m] = h
    steps = np.eye(k + 1, k) - np.eye(k + 1, k, -1)  # dg_m - dg_(m-1), from 0 and back to 0
    a = np.vstack([response, np.sqrt(REGULARISATION) * steps])
    return box_least_squares(a, np.zeros(rows + k + 1), d_lo, d_hi)
