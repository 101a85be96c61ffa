"""The headline experiment: does blending remove the torque jumps of piecewise circles?

Every interpolation method gets the same keyframes and timing and is run through
the simulated XM430-W350 gimbal (``sim``: <dcmotor> at 12 V, armature 0.045
kg m^2, 200 Hz zero-order-hold stream with inverse-dynamics feed-forward, 1 ms
physics). Three motions (a pan sweep with reversals, a raster scan, a seeded
random look-around), each at a gentle and an aggressive pace; and 20 seeded
random look-arounds with uneven keyframe times.

Each case also gets the lower bound on peak torque rate of any rest-to-rest path
through the same keyframes at the same times (:func:`torque_rate_bound`, a
linear programme per joint solved with scipy's HiGHS), and every method is
reported as a ratio to it.

Per method and case: peak planned torque (N m, over the three joints), peak
planned torque rate (N m/s, without Coulomb friction; a torque jump at a knot
shows as jump x rate), the largest torque jump across a keyframe (the paper's
claim, measured directly), max simulated tracking error, path length / sum of
keyframe distances, speed at the start and the end, and the torque check's
verdict. Every run starts from rest
at the first frame, as a gimbal does; methods that start moving (scipy's
RotationSpline) pay for it in tracking error.

Usage::

    python bench/torque_race.py [--plot out/torque_race.png] [--jobs 2] [--quick]

Prints a markdown table to stdout and progress to stderr.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from math import factorial

import numpy as np

RATE_HZ = 200.0
PACES_S = {"gentle": 1.5, "aggressive": 0.5}  # seconds per keyframe
RANDOM_SEED = 7
#: The random set: this many look-arounds, keyframe gaps uniform in UNEVEN_GAPS_S.
RANDOM_CASES = 20
RANDOM_SET_SEED = 2026
UNEVEN_GAPS_S = (0.5, 2.5)
UNEVEN = "uneven"
#: How many of the random set ``--quick`` races.
QUICK_RANDOM = 5
#: The joint-space minimax-jerk plan (not an orientation spline): the bound as a plan.
JOINT_MINIMAX = "joint-space minimax jerk (LP)"
MINIMAX_KNOTS = "SmoothSpline minimax knots (LP)"
#: SmoothSpline's two knot choices (algorithm.md §8.5: quintic, and the rest ends' jerk minimax).
QUINTIC = "SmoothSpline quintic"
END_MINIMAX = "SmoothSpline end-minimax"
#: The knot-by-knot descent on the gimbal's joint jerk, from end-minimax's knot data.
JOINT_KNOTS = "SmoothSpline joint-minimax"
#: Weight of the mean |jerk| beside the peak in the joint-space plan: small, so the
#: peak comes first.
JOINT_TIE_BREAK = 0.01
#: Experiments raced beside the library's methods (they need scipy).
EXPERIMENTS = (MINIMAX_KNOTS, JOINT_MINIMAX)
#: Time step (s) of the grid on which the torque-rate bound is solved.
BOUND_STEP_S = 0.01


def motions() -> dict[str, np.ndarray]:
    """Keyframes per named motion as (N, 3) ``(pan, tilt, roll)`` in degrees."""
    sweep = [(0, 0, 0), (60, 0, 0), (-60, 0, 0), (60, 0, 0), (-60, 0, 0), (0, 0, 0)]
    raster = [
        (-40, -20, 0),
        (40, -20, 0),
        (40, 0, 0),
        (-40, 0, 0),
        (-40, 20, 0),
        (40, 20, 0),
        (0, 0, 0),
    ]
    rng = np.random.default_rng(RANDOM_SEED)
    look = rng.uniform([-70, -30, -10], [70, 30, 10], size=(8, 3))
    look[0] = look[-1] = 0.0
    return {
        "pan sweep": np.array(sweep, dtype=float),
        "raster": np.array(raster, dtype=float),
        "look-around": look,
    }


def random_motions() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The random set: name -> (angles (N, 3) deg, times (N,) s), uneven gaps."""
    rng = np.random.default_rng(RANDOM_SET_SEED)
    out = {}
    for i in range(RANDOM_CASES):
        n = int(rng.integers(5, 11))
        look = rng.uniform([-70, -30, -10], [70, 30, 10], size=(n, 3))
        look[0] = look[-1] = 0.0
        times = np.concatenate([[0.0], np.cumsum(rng.uniform(*UNEVEN_GAPS_S, n - 1))])
        out[f"random {i + 1:02d}"] = (look, np.round(times, 3))
    return out


def keyframes(motion: str, pace: str) -> tuple[np.ndarray, np.ndarray]:
    """Angles (N, 3) deg and times (N,) s of one case."""
    if pace == UNEVEN:
        return random_motions()[motion]
    angles = motions()[motion]
    return angles, np.arange(len(angles)) * PACES_S[pace]


def cases(quick: bool = False) -> list[tuple[str, str]]:
    """Every (motion, pace): the named motions at both paces, then the random set.

    ``quick``: the named motions at the gentle pace and the first QUICK_RANDOM of the
    random set, for iterating (the full race is the one to report).
    """
    if quick:
        named = [(m, "gentle") for m in motions()]
        return named + [(m, UNEVEN) for m in list(random_motions())[:QUICK_RANDOM]]
    named = [(m, p) for m in motions() for p in PACES_S]
    return named + [(m, UNEVEN) for m in random_motions()]


def raced_cases(results: list[Result]) -> list[tuple[str, str]]:
    """The (motion, pace) of ``results``, in the order they were run."""
    return list(dict.fromkeys((r.motion, r.pace) for r in results))


def methods(reparam: str = "rational") -> dict[str, tuple[str, dict]]:
    """Method label -> (class name, keywords); ``reparam`` goes to every BlendingSpline."""
    table = {
        "PiecewiseSlerp": ("PiecewiseSlerp", {}),
        "Squad": ("Squad", {}),
        "SphericalBezier": ("SphericalBezier", {}),
        "PiecewiseCircles": ("PiecewiseCircles", {}),
        "ScipyRotationSpline": ("ScipyRotationSpline", {}),
    }
    for k in (1, 2, 3):
        for local in ("circle", "parabola", "auto"):
            keywords = {"k": k, "local": local, "reparam": reparam}
            table[f"Blending k={k} {local}"] = ("BlendingSpline", keywords)
    table[QUINTIC] = ("SmoothSpline", {"knots": "quintic"})
    table[END_MINIMAX] = ("SmoothSpline", {"knots": "end-minimax"})
    table[JOINT_KNOTS] = ("SmoothSpline", {"knots": "joint-minimax"})
    table["SmoothSpline natural"] = ("SmoothSpline", {"boundary": "natural"})
    table[MINIMAX_KNOTS] = ("MinimaxKnotSpline", {})
    table[JOINT_MINIMAX] = ("", {})
    return table


@dataclass(frozen=True)
class Result:
    motion: str
    pace: str
    method: str
    peak_torque_nm: float = float("nan")
    peak_torque_rate_nm_s: float = float("nan")
    knot_jump_nm: float = float("nan")
    max_tracking_error_rad: float = float("nan")
    path_ratio: float = float("nan")
    start_speed_rad_s: float = float("nan")
    end_speed_rad_s: float = float("nan")
    ok: bool = False
    failed: str = ""  # which parts of the check failed: envelope, limit, tracking
    refused: str = ""


def build_path(class_name: str, keywords: dict, quats: np.ndarray, times: np.ndarray):
    """Construct one interpolation method over the keyframes."""
    import trajgen
    from trajgen import compare

    if class_name == "MinimaxKnotSpline":
        cls = _minimax_spline_class()
    else:
        cls = getattr(trajgen, class_name, None) or getattr(compare, class_name)
    return cls(quats, times, **keywords)


def _minimax_spline_class():
    """:class:`MinimaxKnotSpline`, built on first use (the class needs trajgen imported)."""
    from numpy.polynomial import polynomial as P

    from trajgen.smooth import _H, _H_RIGHT, SmoothSpline

    class MinimaxKnotSpline(SmoothSpline):
        """Experiment: :class:`~trajgen.SmoothSpline` with every knot's rate,
        acceleration and jerk (rest ends: jerk only) chosen by a linear programme per
        tangent-space axis, on the flat model (each segment's jerk linear in its two
        knots' data), sampled MINIMAX_SAMPLES times per segment.

        The objective is the peak over the whole path plus PER_SEGMENT times the
        duration-weighted mean of every segment's own peak. The global peak alone
        is degenerate: every segment other than the worst may then take jerk up to
        the worst one's level, and long segments use that freedom to wander (the
        first version of this experiment, with a mean |jerk| term instead, reached
        27x the bound on a random case). Pressing each segment's own peak keeps
        them tame; it does not make the flat model see the gimbal (see docs/results.md).
        """

        MINIMAX_SAMPLES = 40
        PER_SEGMENT = 10.0  # of 1, 10, 30 and 100 tried, 10 gave the lowest median

        def _knot_rates(self, D, h):
            from scipy.optimize import linprog
            from scipy.sparse import csr_matrix, hstack, identity, vstack

            n, S = len(D) + 1, self.MINIMAX_SAMPLES
            u = np.linspace(0.0, 1.0, S)
            # Third u-derivative of each basis function at the samples: (4, S).
            left = np.array([P.polyval(u, P.polyder(c, 3)) for c in _H])
            right = np.array([P.polyval(u, P.polyder(c, 3)) for c in _H_RIGHT])
            # Unknowns: (v, a, j) per knot, v and a fixed at zero at the rest ends.
            fixed = {0, 1, 3 * (n - 1), 3 * (n - 1) + 1}
            free = [k for k in range(3 * n) if k not in fixed]
            A = np.zeros((n - 1, S, 3 * n))
            for i in range(n - 1):
                for m in (1, 2, 3):  # m = 0: L_0 = 0, R_0 = D_i (the constant term)
                    A[i, :, 3 * i + m - 1] = h[i] ** (m - 3) * left[m]
                    A[i, :, 3 * (i + 1) + m - 1] = h[i] ** (m - 3) * right[m]
            A = csr_matrix(A.reshape(-1, 3 * n)[:, free])
            const = (right[0][None, :, None] * (D / h[:, None] ** 3)[:, None, :]).reshape(-1, 3)
            rows, nv, ns = A.shape[0], A.shape[1], n - 1
            # |jerk_s| <= z_seg(s) <= z; minimise z + PER_SEGMENT * sum(h_i z_i) / sum(h).
            seg = csr_matrix((np.ones(rows), (np.arange(rows), np.repeat(np.arange(ns), S))))
            none = csr_matrix((rows, 1))
            A_ub = vstack(
                [
                    hstack([A, -seg, none]),
                    hstack([-A, -seg, none]),
                    hstack([csr_matrix((ns, nv)), identity(ns), -np.ones((ns, 1))]),
                ]
            ).tocsr()
            cost = np.concatenate([np.zeros(nv), self.PER_SEGMENT * h / h.sum(), [1.0]])
            x = np.zeros((3 * n, 3))
            for axis in range(3):
                res = linprog(
                    cost,
                    A_ub=A_ub,
                    b_ub=np.concatenate([-const[:, axis], const[:, axis], np.zeros(ns)]),
                    bounds=[(None, None)] * nv + [(0, None)] * (ns + 1),
                    method="highs",
                )
                if res.status != 0:
                    raise RuntimeError(f"minimax knot LP failed: {res.message}")
                x[free, axis] = res.x[:nv]
            x = x.reshape(n, 3, 3)
            return x[:, 0], x[:, 1], x[:, 2]

    return MinimaxKnotSpline


def path_ratio(path, quats: np.ndarray) -> float:
    """Path length (integral of |omega| dt) over the sum of keyframe geodesic distances."""
    from trajgen import quat

    t = np.linspace(path.t_start, path.t_end, 20001)
    omega = path.evaluate(t, max_order=1).omega
    speed = np.linalg.norm(omega, axis=1)
    length = float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t)))
    return length / float(np.sum(quat.distance(quats[:-1], quats[1:])))


def knot_torque_jump(path) -> float:
    """Largest jump (N m, any joint) of the planned torque across an interior keyframe.

    The path is evaluated 1e-7 s either side of each interior keyframe time,
    converted to joint motion exactly (``trajgen.gimbal.joint_rates``), and run
    through inverse dynamics without Coulomb friction: a C1 path (piecewise
    circles, k = 1) jumps by the inertia times its acceleration jump; a C2 path
    should not jump at all. A C0 path (piecewise slerp) has a velocity step
    there, an impulse this cannot show; it shows as steps at the torque limit
    and tracking error instead.
    """
    from trajgen.gimbal import GimbalKinematics, joint_rates
    from trajgen.sim.dynamics import inverse_dynamics
    from trajgen.sim.model import build_model

    knots = np.asarray(path.times)[1:-1]
    eps = 1e-7
    t = np.concatenate([knots - eps, knots + eps])
    samples = path.evaluate(t, max_order=2)
    q = GimbalKinematics().inverse(samples.q)
    qd, qdd = joint_rates(q, samples.omega, samples.alpha)
    tau = inverse_dynamics(build_model(), q, qd, qdd, coulomb=False)
    return float(np.abs(tau[len(knots) :] - tau[: len(knots)]).max())


@dataclass(frozen=True)
class Bound:
    """Lower bound on the peak torque rate of any rest-to-rest path through one case's keys."""

    motion: str
    pace: str
    rate_nm_s: float  # max over the joints
    joint_rates_nm_s: tuple[float, float, float]
    inertia_kg_m2: tuple[float, float, float]


def joint_inertia(joint_angles: np.ndarray) -> np.ndarray:
    """Smallest diagonal of the joint-space inertia matrix (armature included) over the
    given poses (M, 3) rad, per joint (3,) kg m^2."""
    import mujoco

    from trajgen.sim.model import build_model

    model = build_model()
    data = mujoco.MjData(model)
    full = np.zeros((model.nv, model.nv))
    out = np.full(model.nv, np.inf)
    for q in joint_angles:
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        mujoco.mj_fullM(model, data, full)
        out = np.minimum(out, np.diag(full))
    return out


def _third_divided_difference(x: np.ndarray, nodes: list[int]) -> dict[int, float]:
    """``f[x_a, x_b, x_c, x_d]`` as coefficients of the node values ``f(x_k)``.

    A repeated node (only at the ends) stands for zero derivative data there: the
    path is at rest, ``f' = f'' = 0``.
    """

    def combine(p: dict, q: dict, scale: float) -> dict:
        out = {k: -v * scale for k, v in p.items()}
        for k, v in q.items():
            out[k] = out.get(k, 0.0) + v * scale
        return out

    level = [{k: 1.0} for k in nodes]
    ends = list(zip(nodes, nodes, strict=True))
    for _ in range(3):
        nxt, nxt_ends = [], []
        for (p, (a, _)), (q, (_, d)) in zip(
            zip(level[:-1], ends[:-1], strict=True),
            zip(level[1:], ends[1:], strict=True),
            strict=True,
        ):
            span = x[d] - x[a]
            nxt.append({} if span == 0 else combine(p, q, 1.0 / span))
            nxt_ends.append((a, d))
        level, ends = nxt, nxt_ends
    return level[0]


def min_peak_jerk(theta: np.ndarray, times: np.ndarray, step: float = BOUND_STEP_S) -> float:
    """Smallest peak |third derivative| (rad/s^3) of any function through ``theta`` (N,)
    at ``times`` (N,) with zero first and second derivatives at both ends.

    A relaxation, hence a true lower bound: for any such function every third
    divided difference over four consecutive grid nodes (each end taken three
    times, with its zero derivative data) equals ``f'''(xi) / 6`` somewhere between
    them, so ``w = 6 f[...]`` obeys ``|w| <= max |f'''|``. The linear programme
    minimises ``z`` subject to ``|w_l| <= z`` on a grid (every segment split into
    equal steps of at most ``step`` s) and to the node values, which the ``w``
    determine by forward substitution, passing through the keyframes and meeting
    the end's derivative data. The unknowns are the ``w`` themselves, not the node
    values: third differences of node values cancel to far below the solver's
    tolerances. scipy's HiGHS (interior point) solves it.
    """
    from scipy.linalg import solve_banded
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix, hstack, identity, vstack

    x, keys = _grid(times, step)
    K = len(x)
    hermite = [0, 0, *range(K), K - 1, K - 1]
    windows = [_third_divided_difference(x, hermite[w : w + 4]) for w in range(K + 1)]
    # Windows 0..K-2 each bring in one new node (1..K-1): B (theta - theta_0) = w, with
    # B lower triangular of bandwidth 3; node k is g_k . w with B^T g_k = e_k.
    upper = np.zeros((4, K - 1))  # B^T in solve_banded's upper form
    for w in range(K - 1):
        for k, v in windows[w].items():
            if k >= 1:
                upper[3 + (k - 1) - w, w] = 6 * v  # B[w, k-1] -> B^T[k-1, w]
    needed = sorted({*keys[1:], K - 3, K - 2, K - 1} - {0})
    unit = np.zeros((K - 1, len(needed)))
    unit[np.array(needed) - 1, np.arange(len(needed))] = 1.0
    G = dict(zip(needed, solve_banded((0, 3), upper, unit).T, strict=True))
    rows, rhs = [], []
    for i, k in enumerate(keys[1:], 1):
        rows.append(np.append(G[k], [0.0, 0.0])), rhs.append(theta[i] - theta[0])
    for w in (K - 1, K):  # the end windows: w_l = 6 f[...] of the nodes the w made
        row = sum(6 * v * G[k] for k, v in windows[w].items() if k >= 1)
        end = np.zeros(2)
        end[w - (K - 1)] = -1.0
        rows.append(np.append(row, end)), rhs.append(0.0)
    n = K + 1
    A_eq = hstack([csr_matrix(np.array(rows)), csr_matrix((len(rows), 1))])
    eye = identity(n, format="csr")
    minus_z = csr_matrix(-np.ones((n, 1)))
    A_ub = vstack([hstack([eye, minus_z]), hstack([-eye, minus_z])])
    cost = np.zeros(n + 1)
    cost[n] = 1.0
    res = linprog(
        cost,
        A_ub=A_ub,
        b_ub=np.zeros(2 * n),
        A_eq=A_eq,
        b_eq=rhs,
        bounds=[(None, None)] * n + [(0, None)],
        method="highs-ipm",  # simplex is 5-15x slower on these dense rows
    )
    if res.status != 0:
        raise RuntimeError(f"torque-rate bound LP failed: {res.message}")
    return float(res.x[n])


def torque_rate_bound(motion: str, pace: str) -> Bound:
    """Lower bound on the peak torque rate (N m/s) of any rest-to-rest path through the
    case's keyframes at its times, for the decoupled constant-inertia model
    ``tau_j = I_j theta_j''`` (see :func:`min_peak_jerk`; what it ignores is in docs/results.md).

    The joints' keyframe angles are the gimbal's inverse kinematics (the branch the
    plans use); ``I_j`` is the smallest diagonal inertia over the keyframe poses.
    """
    from trajgen import quat
    from trajgen.gimbal import GimbalKinematics

    angles, times = keyframes(motion, pace)
    theta = GimbalKinematics().inverse(quat.from_pan_tilt_roll(*np.radians(angles).T))
    inertia = joint_inertia(theta)
    rates = tuple(float(inertia[j] * min_peak_jerk(theta[:, j], times)) for j in range(3))
    return Bound(motion, pace, max(rates), rates, tuple(float(i) for i in inertia))


def _grid(times: np.ndarray, step: float) -> tuple[np.ndarray, list[int]]:
    """Grid nodes (K,): every segment split into equal steps of at most ``step`` s;
    and the node index of each keyframe."""
    nodes, keys = [float(times[0])], [0]
    for i in range(len(times) - 1):
        m = max(1, int(np.ceil((times[i + 1] - times[i]) / step - 1e-9)))
        nodes.extend(times[i] + (times[i + 1] - times[i]) * np.arange(1, m + 1) / m)
        keys.append(len(nodes) - 1)
    return np.array(nodes), keys


def _ramps(t: np.ndarray, x: np.ndarray, power: int) -> np.ndarray:
    """``((t - x_l)_+^p - (t - x_{l+1})_+^p) / p!``, shape (len(t), len(x) - 1): the
    response at ``t`` of a unit jerk on grid interval l, integrated 3 - p times."""
    d = np.maximum(t[:, None] - x[None, :], 0.0) ** power
    return (d[:, :-1] - d[:, 1:]) / factorial(power)


def joint_minimax_path(theta: np.ndarray, times: np.ndarray, t: np.ndarray, step: float):
    """The rest-to-rest joint path through ``theta`` at ``times`` with the smallest peak
    |jerk| among paths with piecewise-constant jerk on the grid: an achievable peak,
    so an upper bound on the least one (:func:`min_peak_jerk` is the lower bound).

    Returns its peak |jerk| (rad/s^3) and its angle, rate and acceleration at ``t``.
    """
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix, hstack, identity, vstack

    x, keys = _grid(times, step)
    end = x[-1:]
    rows = [_ramps(x[keys[1:]], x, 3), _ramps(end, x, 2), _ramps(end, x, 1)]
    rhs = np.concatenate([theta[1:] - theta[0], [0.0, 0.0]])
    n = len(x) - 1
    # Variables: the jerk J_l on each interval, z, and s_l >= |J_l| (s_l <= z).
    # Minimise z + JOINT_TIE_BREAK * mean(s): the mean picks one of the many
    # minimax plans (alone, the peak leaves the path free to wander).
    A_eq = hstack([csr_matrix(np.vstack(rows)), csr_matrix((len(rhs), n + 1))])
    eye = identity(n, format="csr")
    none = csr_matrix((n, 1))
    A_ub = vstack(
        [
            hstack([eye, none, -eye]),
            hstack([-eye, none, -eye]),
            hstack([csr_matrix((n, n)), csr_matrix(-np.ones((n, 1))), eye]),
        ]
    )
    res = linprog(
        np.concatenate([np.zeros(n), [1.0], np.full(n, JOINT_TIE_BREAK / n)]),
        A_ub=A_ub,
        b_ub=np.zeros(3 * n),
        A_eq=A_eq,
        b_eq=rhs,
        bounds=[(None, None)] * n + [(0, None)] * (n + 1),
        method="highs-ipm",
    )
    if res.status != 0:
        raise RuntimeError(f"joint minimax LP failed: {res.message}")
    jerk = res.x[:n]
    return (
        float(np.abs(jerk).max()),
        theta[0] + _ramps(t, x, 3) @ jerk,
        _ramps(t, x, 2) @ jerk,
        _ramps(t, x, 1) @ jerk,
    )


def run_joint_minimax(motion: str, pace: str) -> Result:
    """The joint-space minimax-jerk path (:func:`joint_minimax_path`) through one case, run
    through the same check as the splines: what the bound looks like as a plan."""
    from trajgen import quat
    from trajgen.gimbal import GimbalKinematics, forward
    from trajgen.sampling import sample_times
    from trajgen.sim.check import check_torque
    from trajgen.stream import JointTrajectory

    angles, times = keyframes(motion, pace)
    quats = quat.from_pan_tilt_roll(*np.radians(angles).T)
    theta = GimbalKinematics().inverse(quats)
    t = sample_times(times[0], times[-1], RATE_HZ)
    parts = [joint_minimax_path(theta[:, j], times, t, BOUND_STEP_S)[1:] for j in range(3)]
    q, qd, qdd = (np.stack([p[i] for p in parts], axis=1) for i in range(3))
    report = check_torque(JointTrajectory(t, q, qd, qdd, RATE_HZ))
    joints = report.joints.values()
    orientation = forward(q)
    length = float(quat.distance(orientation[:-1], orientation[1:]).sum())
    return Result(
        motion,
        pace,
        JOINT_MINIMAX,
        peak_torque_nm=max(j.peak_planned_torque_nm for j in joints),
        peak_torque_rate_nm_s=max(j.peak_torque_rate_nm_s for j in joints),
        max_tracking_error_rad=max(j.max_tracking_error_rad for j in joints),
        path_ratio=length / float(quat.distance(quats[:-1], quats[1:]).sum()),
        start_speed_rad_s=float(np.linalg.norm(qd[0])),
        end_speed_rad_s=float(np.linalg.norm(qd[-1])),
        ok=report.ok,
        failed=", ".join(_failed_parts(report.reasons)),
    )


def run_case(motion: str, pace: str, method: str, reparam: str = "rational") -> Result:
    """Plan, simulate and measure one method on one case; planning refusals are recorded."""
    if method == JOINT_MINIMAX:
        return run_joint_minimax(motion, pace)
    from trajgen import quat
    from trajgen.sim.check import check_torque
    from trajgen.sim.errors import SimError
    from trajgen.stream import plan_joint_trajectory

    angles, times = keyframes(motion, pace)
    quats = quat.from_pan_tilt_roll(*np.radians(angles).T)
    class_name, keywords = methods(reparam)[method]
    try:
        path = build_path(class_name, keywords, quats, times)
        trajectory = plan_joint_trajectory(path, RATE_HZ)
        report = check_torque(trajectory)
    except (ValueError, SimError) as e:
        return Result(motion, pace, method, refused=f"{type(e).__name__}: {e}".splitlines()[0])
    joints = report.joints.values()
    ends = np.linalg.norm(path.evaluate([path.t_start, path.t_end], max_order=1).omega, axis=1)
    return Result(
        motion,
        pace,
        method,
        peak_torque_nm=max(j.peak_planned_torque_nm for j in joints),
        peak_torque_rate_nm_s=max(j.peak_torque_rate_nm_s for j in joints),
        knot_jump_nm=knot_torque_jump(path),
        max_tracking_error_rad=max(j.max_tracking_error_rad for j in joints),
        path_ratio=path_ratio(path, quats),
        start_speed_rad_s=float(ends[0]),
        end_speed_rad_s=float(ends[1]),
        ok=report.ok,
        failed=", ".join(_failed_parts(report.reasons)),
    )


def _failed_parts(reasons) -> list[str]:
    parts = {"x envelope": "envelope", "torque limit": "limit", "tracking error": "tracking"}
    return [name for key, name in parts.items() if any(key in r for r in reasons)]


def _num(value: float, digits: int) -> str:
    return f"{value:.{digits}f}" if abs(value) < 1e4 else f"{value:.2e}"


#: The default method for offline plans (keyframe files), as the race in docs/results.md chose it.
DEFAULT = END_MINIMAX
#: The library methods whose goals the race reports (the default and the other knot choice).
CANDIDATES = (DEFAULT, JOINT_KNOTS, QUINTIC)
#: A start or end speed below this (rad/s) counts as starting / stopping at rest.
AT_REST_RAD_S = 1e-6


def at_rest(r: Result) -> bool:
    """The method started and stopped still on this case (measured, not declared)."""
    return not r.refused and max(r.start_speed_rad_s, r.end_speed_rad_s) < AT_REST_RAD_S


def _by_case(results: list[Result]) -> dict[tuple[str, str], list[Result]]:
    out: dict[tuple[str, str], list[Result]] = {}
    for r in results:
        out.setdefault((r.motion, r.pace), []).append(r)
    return out


def _case_title(motion: str, pace: str, times: np.ndarray) -> str:
    if pace == UNEVEN:
        return f"{motion} ({len(times)} keyframes, uneven gaps, {times[-1]:.2f} s)"
    return f"{motion}, {pace} ({PACES_S[pace]:g} s per keyframe)"


def markdown(results: list[Result], bounds: dict[tuple[str, str], Bound]) -> str:
    """One table per named case, a summary of the random set, and the default's goals."""
    out = []
    by_case = _by_case(results)
    for motion, pace in raced_cases(results):
        if pace == UNEVEN:
            continue
        bound = bounds[(motion, pace)]
        out.append(f"\n### {_case_title(motion, pace, keyframes(motion, pace)[1])}\n")
        out.append(
            f"Lower bound on the peak torque rate of any rest-to-rest path: "
            f"**{bound.rate_nm_s:.3f} N m/s** (pan / tilt / roll "
            + " / ".join(f"{x:.3f}" for x in bound.joint_rates_nm_s)
            + ").\n"
        )
        out.append(
            "| method | peak torque (N m) | peak torque rate (N m/s) | rate / bound "
            "| torque jump at knots (N m) | max tracking error (deg) "
            "| path / keyframe distance | start / end speed (rad/s) | check |"
        )
        out.append("|---|---:|---:|---:|---:|---:|---:|---:|---|")
        for r in by_case[(motion, pace)]:
            if r.refused:
                out.append(f"| {r.method} | - | - | - | - | - | - | - | refused: {r.refused} |")
                continue
            out.append(
                f"| {r.method} | {_num(r.peak_torque_nm, 3)} "
                f"| {_num(r.peak_torque_rate_nm_s, 3)} "
                f"| {_num(r.peak_torque_rate_nm_s / bound.rate_nm_s, 2)} "
                f"| {_num(r.knot_jump_nm, 3)} "
                f"| {np.degrees(r.max_tracking_error_rad):.2f} | {r.path_ratio:.3f} "
                f"| {r.start_speed_rad_s:.2f} / {r.end_speed_rad_s:.2f} "
                f"| {'ok' if r.ok else 'FAIL: ' + r.failed} |"
            )
    out.append(random_set_summary(results, bounds))
    out.append(random_set_cases(results, bounds))
    out.extend(goals(results, bounds, name) for name in CANDIDATES)
    return "\n".join(out)


def random_set_summary(results: list[Result], bounds: dict[tuple[str, str], Bound]) -> str:
    """Per method over the random set: ratio to the bound, wins, torque against the best."""
    by_case = {c: rs for c, rs in _by_case(results).items() if c[1] == UNEVEN}
    out = [
        f"\n### {len(by_case)} random look-arounds, uneven keyframe gaps "
        f"({UNEVEN_GAPS_S[0]:g}-{UNEVEN_GAPS_S[1]:g} s), seed {RANDOM_SET_SEED}\n",
        "Bounds (N m/s): " + ", ".join(f"{bounds[c].rate_nm_s:.3f}" for c in by_case) + ".\n",
        "Medians and worst cases over the set. *lowest rate*: cases where the method "
        "had the lowest peak torque rate of the library's methods that started and "
        "stopped at rest (not the experiments); *torque / best*: its peak torque over "
        "the lowest of those methods'.\n",
        "| method | rate / bound, median (max) | lowest rate | torque / best, median (max) "
        "| path / keyframe distance, median | max start / end speed (rad/s) "
        "| max tracking error (deg) | checks failed | refused |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    names = list(dict.fromkeys(r.method for rs in by_case.values() for r in rs))
    for name in names:
        ratio, torque, path, speed, error, wins, failed, refused = [], [], [], [], [], 0, 0, 0
        for case, rs in by_case.items():
            r = next(x for x in rs if x.method == name)
            if r.refused:
                refused += 1
                continue
            rest = [x for x in rs if at_rest(x) and x.method not in EXPERIMENTS]
            ratio.append(r.peak_torque_rate_nm_s / bounds[case].rate_nm_s)
            torque.append(r.peak_torque_nm / min(x.peak_torque_nm for x in rest))
            path.append(r.path_ratio)
            speed.append(max(r.start_speed_rad_s, r.end_speed_rad_s))
            error.append(np.degrees(r.max_tracking_error_rad))
            wins += r is min(rest, key=lambda x: x.peak_torque_rate_nm_s)
            failed += not r.ok
        if not ratio:
            out.append(f"| {name} | - | - | - | - | - | - | - | {refused} |")
            continue
        out.append(
            f"| {name} | {np.median(ratio):.2f} ({max(ratio):.2f}) | {wins} "
            f"| {np.median(torque):.2f} ({max(torque):.2f}) | {np.median(path):.3f} "
            f"| {max(speed):.2f} | {max(error):.2f} | {failed} | {refused} |"
        )
    return "\n".join(out)


#: Methods whose rate / bound the random set's per-case table shows.
PER_CASE = (
    "ScipyRotationSpline",
    "Blending k=2 auto",
    "Blending k=3 auto",
    QUINTIC,
    END_MINIMAX,
    JOINT_KNOTS,
    MINIMAX_KNOTS,
    JOINT_MINIMAX,
)


def random_set_cases(results: list[Result], bounds: dict[tuple[str, str], Bound]) -> str:
    """Per random case: the bound and a few methods' rate / bound (peak torque, N m)."""
    by_key = {(r.motion, r.pace, r.method): r for r in results}
    out = [
        "\nPer case: peak torque rate / bound (peak torque, N m); - = refused.\n",
        "| case | bound (N m/s) | " + " | ".join(PER_CASE) + " |",
        "|---|---:|" + "---:|" * len(PER_CASE),
    ]
    for motion, pace in raced_cases(results):
        if pace != UNEVEN:
            continue
        bound = bounds[(motion, pace)].rate_nm_s
        cells = []
        for name in PER_CASE:
            r = by_key[(motion, pace, name)]
            cells.append(
                "-"
                if r.refused
                else f"{r.peak_torque_rate_nm_s / bound:.2f} ({r.peak_torque_nm:.3f})"
            )
        out.append(f"| {motion} | {bound:.3f} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def goals(results: list[Result], bounds: dict[tuple[str, str], Bound], candidate: str) -> str:
    """Did ``candidate`` meet the race's goals on every case? Counts, then the misses.

    The method is compared with the other orientation splines that started and
    stopped at rest: the library's (every ``BlendingSpline`` variant and the other
    ``SmoothSpline`` knot choice), then those and the minimax-knot experiment. The
    joint-space minimax plan is the bound made a plan, and is counted apart.
    """
    misses, ratios, n = [], [], 0
    counts = dict.fromkeys(("library", "splines", "torque", "joint"), 0)
    for case, rs in _by_case(results).items():
        n += 1
        splines = [r for r in rs if at_rest(r) and r.method != JOINT_MINIMAX]
        library = [r for r in splines if r.method not in EXPERIMENTS]
        mine = next((r for r in library if r.method == candidate), None)
        where = f"- {case[0]}, {case[1]}:"
        if mine is None:
            misses.append(f"{where} {candidate} did not run from rest to rest")
            continue
        joint = next(r for r in rs if r.method == JOINT_MINIMAX)
        best_torque = min(r.peak_torque_nm for r in library)
        ratios.append(mine.peak_torque_rate_nm_s / bounds[case].rate_nm_s)
        for key, group in (("library", library), ("splines", splines)):
            best = min(group, key=lambda r: r.peak_torque_rate_nm_s)
            lowest = mine.peak_torque_rate_nm_s <= best.peak_torque_rate_nm_s  # ties count
            counts[key] += lowest
            if not lowest and (key == "library" or best not in library):
                misses.append(
                    f"{where} lower rate: {best.method}, {best.peak_torque_rate_nm_s:.3f} "
                    f"against {mine.peak_torque_rate_nm_s:.3f} N m/s"
                )
        counts["torque"] += mine.peak_torque_nm <= 1.1 * best_torque
        if mine.peak_torque_nm > 1.1 * best_torque:
            misses.append(
                f"{where} peak torque {mine.peak_torque_nm:.3f} N m > 1.1 x the best "
                f"library spline's {best_torque:.3f}"
            )
        counts["joint"] += mine.peak_torque_rate_nm_s <= joint.peak_torque_rate_nm_s
    within = sum(r <= 1.5 for r in ratios)
    return (
        f"\n### Goals for {candidate} on all {n} cases\n\n"
        f"- lowest peak torque rate of the library's rest-to-rest splines: "
        f"{counts['library']} of {n}\n"
        f"- lowest, counting the minimax-knot experiment too: {counts['splines']} of {n}\n"
        f"- within 1.5x of the bound: {within} of {n} (rate / bound from "
        f"{min(ratios):.2f} to {max(ratios):.2f}, median {np.median(ratios):.2f})\n"
        f"- peak torque within 10% of the best library spline: {counts['torque']} of {n}\n"
        f"- peak torque rate at or below the joint-space minimax plan's: "
        f"{counts['joint']} of {n}\n" + ("\nMisses:\n\n" + "\n".join(misses) if misses else "")
    )


def plot(results: list[Result], bounds: dict[tuple[str, str], Bound], path: str) -> None:
    """Bars per method for the named cases (torque, rate with the bound, tracking error),
    and the random set's ratios to the bound as box plots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    named = [(m, p) for m, p in raced_cases(results) if p != UNEVEN]
    names = list(methods())
    metrics = [
        ("peak torque (N m)", lambda r: r.peak_torque_nm),
        ("peak torque rate (N m/s)", lambda r: r.peak_torque_rate_nm_s),
        ("max tracking error (deg)", lambda r: np.degrees(r.max_tracking_error_rad)),
    ]
    fig = plt.figure(figsize=(22, 16))
    grid = fig.add_gridspec(len(metrics) + 1, len(named), height_ratios=[1, 1, 1, 0.9])
    by_key = {(r.motion, r.pace, r.method): r for r in results}
    y = np.arange(len(names))
    for col, (motion, pace) in enumerate(named):
        for row, (label, value) in enumerate(metrics):
            ax = fig.add_subplot(grid[row, col])
            values = np.array([value(by_key[(motion, pace, n)]) for n in names])
            colors = [
                "tab:green"
                if n == DEFAULT
                else "tab:red"
                if not by_key[(motion, pace, n)].ok
                else "tab:blue"
                for n in names
            ]
            ax.barh(y, np.nan_to_num(values, nan=0.0), color=colors)
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            low = np.nanmin(values) if np.isfinite(values).any() else 1.0
            if row == 1:
                low = min(low, bounds[(motion, pace)].rate_nm_s)
                ax.axvline(bounds[(motion, pace)].rate_nm_s, color="k", ls="--", lw=1)
            ax.set_xlim(left=low / 2)  # bars on a log axis start at its left edge
            for i, v in enumerate(values):
                text = " refused" if np.isnan(v) else f" {v:.3g}"
                ax.text(low / 2 if np.isnan(v) else v, y[i], text, va="center", fontsize=6)
            if row == 0:
                ax.set_title(f"{motion}, {pace}", fontsize=10)
            if col == 0:
                ax.set_ylabel(label)
                ax.set_yticks(y, names, fontsize=8)
            else:
                ax.set_yticks(y, [])
            ax.invert_yaxis()
    ax = fig.add_subplot(grid[len(metrics), :])
    randoms = [c for c in raced_cases(results) if c[1] == UNEVEN]
    data, labels = [], []
    for n in names:
        ratios = [
            by_key[(m, p, n)].peak_torque_rate_nm_s / bounds[(m, p)].rate_nm_s
            for m, p in randoms
            if not by_key[(m, p, n)].refused
        ]
        if ratios:
            data.append(ratios)
            labels.append(n)
    ax.boxplot(data, tick_labels=labels, whis=(0, 100))
    ax.axhline(1.0, color="k", ls="--", lw=1)
    ax.axhline(1.5, color="tab:green", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_ylabel("peak torque rate / bound")
    ax.set_title(f"{len(randoms)} random look-arounds, uneven gaps (whiskers: min-max)")
    ax.tick_params(axis="x", labelrotation=30, labelsize=8)
    fig.suptitle(
        "torque race (green: the default; red: fails the torque check; missing: refused; "
        "dashed: lower bound on the peak torque rate of any rest-to-rest path)"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--plot", metavar="OUT.png", help="also save a bar chart")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument(
        "--reparam",
        choices=("paper", "rational"),
        default="rational",
        help="BlendingSpline time-to-angle map on circles (default: the spline's, rational)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"race a subset (named motions at the gentle pace, {QUICK_RANDOM} random "
        "look-arounds) for iterating",
    )
    args = parser.parse_args(argv)
    runs = [(m, p, n, args.reparam) for m, p in cases(args.quick) for n in methods()]
    start = time.monotonic()
    results = []
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        pending = pool.map(torque_rate_bound, *zip(*cases(args.quick), strict=True))
        for i, result in enumerate(pool.map(run_case, *zip(*runs, strict=True)), 1):
            results.append(result)
            print(
                f"\r[{i}/{len(runs)}] {time.monotonic() - start:5.1f} s  "
                f"{result.motion}, {result.pace}: {result.method:<24}",
                end="",
                file=sys.stderr,
                flush=True,
            )
        bounds = {(b.motion, b.pace): b for b in pending}
    print(file=sys.stderr)
    print(
        f"BlendingSpline reparam = {args.reparam!r}; {RATE_HZ:g} Hz stream; XM430-W350 x 3; "
        f"bound grid {BOUND_STEP_S * 1e3:g} ms; {'quick subset; ' if args.quick else ''}"
        f"{time.monotonic() - start:.0f} s on 2 cores, "
        "load (1, 5, 15 min) " + " ".join(f"{x:.2f}" for x in os.getloadavg())
    )
    print(markdown(results, bounds))
    if args.plot:
        plot(results, bounds, args.plot)
        print(f"\nplot: {args.plot}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
