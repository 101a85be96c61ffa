"""The ``knots="joint-minimax"`` optimiser of :class:`~trajgen.smooth.SmoothSpline`.

Knot rates, accelerations and jerks are moved window by window to lower the peak
jerk of the gimbal's joints (pan, tilt, roll), under guards on joint
acceleration and tilt: :func:`joint_motion` measures a candidate exactly by jets,
:func:`minimax_step` takes a linearised minimax step, and :func:`joint_minimax`
runs the passes. It costs 0.1-1 s for 5-20 keyframes, linear in N.
"""

from __future__ import annotations

import numpy as np

from . import jet as J
from .gimbal import angles_of

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


def joint_minimax(quats, D, h, knot_data, poly, segment_coefficients, progress=None):
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

    Parameters
    ----------
    quats : ndarray, shape (N, 4)
        The keyframes (signs aligned pair by pair).
    D : ndarray, shape (N - 1, 3)
        Segment increments ``log(q_{i+1} q_i*)``.
    h : ndarray, shape (N - 1,)
        Segment durations (s).
    knot_data : tuple of 3 ndarray, each (N, 3)
        Rate, acceleration and jerk at the knots to start from (end-minimax's).
    poly : ndarray, shape (N - 1, 12, 8)
        Their segment coefficients.
    segment_coefficients : callable
        ``(D, h, v, a, j) -> poly``, the spline's (``SmoothSpline._segment_coefficients``).
    progress : callable, optional
        Called with the fraction done (0..1) after each pass over the windows of one
        width and offset (at most :data:`JOINT_SWEEPS` x 5 calls).

    Returns
    -------
    v, a, j : ndarray, each (N, 3)
    poly : ndarray, shape (N - 1, 12, 8)
    """
    n = len(h) + 1
    x = np.stack(knot_data)  # (3, N, 3): [kind, knot, axis]
    starts = quats[:-1]

    def measure(xs):
        """Per segment, for each of the P sets of knot data ``xs`` (P, 3, N, 3): its
        peak |acceleration| per joint, its sampled jerks (3 S) and its peak |tilt|."""
        P = len(xs)
        poly = segment_coefficients(D, h, xs[:, 0], xs[:, 1], xs[:, 2])
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
            np.abs(angles_of(*quats.T, np.arctan2, np.hypot)[1]).max() + TILT_MARGIN_RAD,
        )
        steps, done = JOINT_SWEEPS * sum(width + 1 for width in JOINT_WIDTHS), 0
        for _ in range(JOINT_SWEEPS):
            start_peak = np.abs(state[1]).max(axis=1)
            for width in JOINT_WIDTHS:
                for offset in range(width + 1):
                    _window_step(x, state, measure, caps, width, offset)
                    done += 1
                    if progress is not None:
                        progress(done / steps)
            if (np.abs(state[1]).max(axis=1) > 0.999 * start_peak).all():
                break
    if progress is not None and done < steps:
        progress(1.0)  # the passes stopped early: nothing more to gain
    # Segments whose knot data did not change keep their coefficients bit for bit.
    changed = (x != np.stack(knot_data)).any(axis=(0, 2))
    changed = changed[:-1] | changed[1:]
    poly = poly.copy()
    poly[changed] = segment_coefficients(D, h, *x)[changed]
    return *x, poly


def _window_step(x, state, measure, caps, width, offset):
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
    deltas = np.array([1e-6 * (1.0 + np.abs(x[kind, :, axis]).max()) for _, kind, axis in coords])
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
