"""The knot-rate system of :class:`~trajgen.smooth.SmoothSpline` and its O(n) solvers.

:func:`knot_system` builds the symmetric positive definite block-tridiagonal
system of the flat C4 quintic spline's knot conditions (docs/algorithm.md §8.2);
:func:`solve_block_tridiagonal` solves it by block cyclic reduction and
:func:`solve_block_cyclic` the closed loop's, with its two corner blocks, by
Woodbury's identity.
"""

from __future__ import annotations

import numpy as np


def knot_system(D: np.ndarray, h: np.ndarray, boundary: str = "rest"):
    """Blocks of the knot-rate system (docs/algorithm.md §8.2), symmetric positive definite.

    The unknowns at each free knot are ``(v, a)``; the rows are the snap condition
    (``S0_i - S1_{i-1} = 0``) and the jerk condition (``J1_{i-1} - J0_i = 0``), the
    gradient of the flat spline's integral of squared jerk, so the matrix is SPD and
    block elimination needs no pivoting.

    Parameters
    ----------
    D : ndarray, shape (n - 1, 3)
        Segment increments ``log(q_{i+1} q_i*)``.
    h : ndarray, shape (n - 1,)
        Segment durations (s).
    boundary : {"rest", "natural", "closed"}
        ``"rest"``: ``v = a = 0`` at both ends (free knots 1..n-2); ``"natural"``:
        free ends with zero jerk and snap (free knots 0..n-1); ``"closed"``: knot
        n-1 is knot 0 (free knots 0..n-2), and the last segment couples them.

    Returns
    -------
    diag : ndarray, shape (m, 2, 2)
    upper : ndarray, shape (m - 1, 2, 2), or (m, 2, 2) when closed
        Block coupling knot ``k`` to ``k + 1``; the lower blocks are its transposes.
        When closed the last one couples knot m - 1 to knot 0.
    rhs : ndarray, shape (m, 2, 3)
    """
    h = h[:, None, None]
    # Segment i's share of the diagonal block at its left / right knot, its
    # coupling block (rows: left knot, columns: right knot) and right-hand sides.
    left = np.concatenate([192 / h**3, 36 / h**2, 36 / h**2, 9 / h], axis=2).reshape(-1, 2, 2)
    right = left * np.array([[1, -1], [-1, 1]])
    upper = np.concatenate([168 / h**3, -24 / h**2, 24 / h**2, -3 / h], axis=2).reshape(-1, 2, 2)
    b_left = np.stack([360 * D / h[..., 0] ** 4, 60 * D / h[..., 0] ** 3], axis=1)
    b_right = b_left * np.array([1, -1])[:, None]
    n = len(D) + 1
    diag = np.zeros((n, 2, 2))
    diag[:-1] += left
    diag[1:] += right
    rhs = np.zeros((n, 2, 3))
    rhs[:-1] += b_left
    rhs[1:] += b_right
    if boundary == "rest":
        return diag[1:-1], upper[1:-1], rhs[1:-1]
    if boundary == "closed":
        diag[0] += diag[-1]
        rhs[0] += rhs[-1]
        return diag[:-1], upper, rhs[:-1]
    return diag, upper, rhs


def solve_block_tridiagonal(diag, upper, rhs) -> np.ndarray:
    """Solve a symmetric block-tridiagonal system with 2x2 blocks by block cyclic
    reduction, O(m) work in O(log m) vectorised steps.

    Each step eliminates the odd-numbered unknowns from the even-numbered rows
    (a Schur complement, symmetric positive definite again when the system is),
    solves the half-size system the same way, then recovers the odd unknowns. For
    an SPD system this is Gaussian elimination in another order: stable without
    pivoting.

    Parameters
    ----------
    diag : ndarray, shape (m, 2, 2)
    upper : ndarray, shape (m - 1, 2, 2)
        Super-diagonal blocks; the sub-diagonal blocks are their transposes.
    rhs : ndarray, shape (m, 2, c)

    Returns
    -------
    ndarray, shape (m, 2, c)
    """
    m = len(rhs)
    if m <= 1:
        return np.linalg.solve(diag, rhs) if m else rhs.copy()
    # Couplings of each row to the row after (``right``) and before (``left``),
    # zero past the ends.
    right = np.zeros_like(diag)
    right[:-1] = upper
    left = np.zeros_like(diag)
    left[1:] = upper.transpose(0, 2, 1)
    odd = slice(1, None, 2)
    inv = np.linalg.inv(diag[odd])
    to_left, to_right, rest = inv @ left[odd], inv @ right[odd], inv @ rhs[odd]
    # x_odd = rest - to_left x_before - to_right x_after; padded so that the even
    # rows at either end see zeros where they have no odd neighbour.
    pad = np.zeros((1, 2, 2))
    n_even = (m + 1) // 2
    before_left, before_right = (np.concatenate([pad, a])[:n_even] for a in (to_left, to_right))
    after_left, after_right = (np.concatenate([a, pad])[:n_even] for a in (to_left, to_right))
    before_rest = np.concatenate([np.zeros((1, *rhs.shape[1:])), rest])[:n_even]
    after_rest = np.concatenate([rest, np.zeros((1, *rhs.shape[1:]))])[:n_even]
    even = slice(0, None, 2)
    el, er = left[even], right[even]
    x_even = solve_block_tridiagonal(
        diag[even] - el @ before_right - er @ after_left,
        -(er @ after_right)[:-1],
        rhs[even] - el @ before_rest - er @ after_rest,
    )
    x = np.empty_like(rhs)
    x[even] = x_even
    after = np.concatenate([x_even[1:], np.zeros((1, *rhs.shape[1:]))])[: m // 2]
    x[odd] = rest - to_left @ x_even[: m // 2] - to_right @ after
    return x


def solve_block_cyclic(diag, upper, rhs) -> np.ndarray:
    """Solve a symmetric block-tridiagonal system with the corner blocks of a loop, O(m).

    ``A = T + E G E^T``: ``T`` the system without the corners (the block solve above), ``E``
    picks knots 0 and m - 1, ``G = [[0, W^T], [W, 0]]`` with ``W = upper[-1]`` (row
    knot m - 1, column knot 0). Woodbury: ``x = y - Z (I + G E^T Z)^-1 G E^T y``
    with ``T y = b``, ``T Z = E``, both from one block solve.

    Parameters
    ----------
    diag : ndarray, shape (m, 2, 2)
    upper : ndarray, shape (m, 2, 2)
    rhs : ndarray, shape (m, 2, c)

    Returns
    -------
    ndarray, shape (m, 2, c)
    """
    m, b, c = rhs.shape
    E = np.zeros((m, b, 2 * b))
    E[0, :, :b] = np.eye(b)
    E[-1, :, b:] += np.eye(b)
    solved = solve_block_tridiagonal(diag, upper[:-1], np.concatenate([rhs, E], axis=2))
    y, Z = solved[..., :c], solved[..., c:]
    G = np.zeros((2 * b, 2 * b))
    G[:b, b:], G[b:, :b] = upper[-1].T, upper[-1]
    EtZ = np.concatenate([Z[0], Z[-1]])  # (2b, 2b)
    Ety = np.concatenate([y[0], y[-1]])  # (2b, c)
    correction = np.linalg.solve(np.eye(2 * b) + G @ EtZ, G @ Ety)
    return y - np.einsum("kij,jc->kic", Z, correction)
