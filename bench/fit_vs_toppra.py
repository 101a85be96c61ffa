"""The keyframe-times fit (``fit_durations``) against TOPP-RA on the same path and torque model.

The retiming fit that replaced it as ``trajgen fit`` is measured by
``bench/retime_vs_toppra.py`` (which reuses this module's TOPP-RA helpers).

For each motion (the torque race's three, one single segment, then seeded
random look-arounds; the file's default spline (``method = "smooth"``, its
default knots unless ``--knots``), rest boundary, 200 Hz, XM430-W350 x 3,
0.15 kg payload; tracking budget widened to 1 rad so that torque, which is all
TOPP-RA knows, decides rather than the servo's 45 ms lag):

1. ``trajgen.sim.fit_durations.fit_durations`` fits the keyframe times twice: with the full
   check (plan and simulated servo, "full check") and to the plan alone
   (``simulate=False``: the envelope, as TOPP-RA sees it, "plan only"). The
   plan-only fit's joint path is the geometric path given to TOPP-RA.
2. The floor of the construction (:func:`construction_floor`): the shortest
   plan-only time a global search over all segment durations finds
   (differential evolution, then Nelder-Mead, on
   ``trajgen.sim.fit_durations.uniform_time_function``). No timing of this spline does
   better, so ``floor / TOPP-RA`` is the part of the gap the spline itself
   causes, and ``ours / floor`` the part the optimiser leaves.
3. TOPP-RA (``toppra``) re-times that same path (the stream's 200 Hz samples in
   its cubic-spline path; 801 gridpoints over the path, collocation) from rest
   to rest (``sd_start = sd_end = 0``), fed our gimbal's inverse dynamics
   (``sim.dynamics.inverse_dynamics``) in two ways:

   - "box": ``JointTorqueConstraint`` with ``|tau| <= margin tau_stall``
     (Coulomb friction through ``fs_coef``) plus ``JointVelocityConstraint``
     ``|w| <= w0``. This ignores that the available torque falls with speed
     (at half the no-load speed only half is there), so it is a lower bound on
     the optimum under our envelope, and its profile leaves the envelope.
   - "envelope": our torque-speed line ``|tau| <= margin tau_stall (1 - |w| /
     w0)`` exactly, as a custom ``LinearConstraint`` (``envelope_constraint``):
     the ``sd`` term is replaced by its tangent at the last solution (an upper
     bound, so every cut is feasible), 3 rounds from the box solution (it
     settles after 2). Viscous damping is in the ``sd`` term too. This is the
     time-optimal second-order retiming of our path under our envelope; the
     fair anchor.

TOPP-RA's output trajectory (``compute_trajectory``, evaluated at 4001 times)
is checked against our envelope with our full inverse dynamics ("its envelope
use"); where it exceeds 1 (its constraint holds at gridpoints on its spline of
our samples, not everywhere), it is slowed uniformly until it fits ("stretched
into envelope"), and the ratio is taken against that.

Reversals: where the joint path turns back (the pan sweep), every timing stops,
so the path is split there (:func:`reversals`) and each reversal-free piece is
re-timed rest to rest; durations add up. Parametrization: by our time the
path's speed p'(s) goes to 0 at rest ends, and on some pieces TOPP-RA's
controllable set next to the end comes back empty (toppra returns None). Then
the piece is retried parametrized by joint-space arc length, regular at the
ends (a piece has no reversal, so no cusp). The table says per motion how many
pieces and which parametrization ("mixed": some of each).

Neither TOPP-RA run simulates the servo (torque-limit steps, tracking), which
our check does. Gridpoints: 801 vs 1601 changed the envelope optimum by about 1 %
on the look-around (1.578 vs 1.561 s; 3201: 1.564 s).

Usage::

    python bench/fit_vs_toppra.py [--random 3] [--only NAME] [--knots quintic]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

RATE_HZ = 200.0
TRACKING_BUDGET_RAD = 1.0


def keyframe_text(angles_deg: np.ndarray, pace_s: float, knots: str | None = None) -> str:
    lines = ["[spline]", 'boundary = "rest"', *([f'knots = "{knots}"'] if knots else [])]
    lines += ["", "[stream]", f"rate_hz = {RATE_HZ:g}", ""]
    # TOPP-RA knows torque, not servo lag: widen the tracking budget so torque decides.
    lines += ["[gimbal]", f"max_tracking_error_rad = {TRACKING_BUDGET_RAD}", ""]
    for i, (pan, tilt, roll) in enumerate(angles_deg):
        lines += [
            "[[keyframes]]",
            f"t = {i * pace_s}",
            f"pan = {pan}",
            f"tilt = {tilt}",
            f"roll = {roll}",
            "",
        ]
    return "\n".join(lines)


def random_motions(count: int, seed: int = 11) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = {}
    for i in range(count):
        look = rng.uniform([-70, -30, -10], [70, 30, 10], size=(int(rng.integers(4, 8)), 3))
        look[0] = look[-1] = 0.0
        out[f"random {i + 1}"] = look
    return out


def _inverse_dynamics_parts(config):
    """Our inverse dynamics as toppra calls it, and the friction it handles apart.

    Returns ``(inv_dyn, frictionloss (3,), damping (3,))``; ``inv_dyn(q, qd, qdd)``
    takes one (3,) sample and leaves out Coulomb friction and viscous damping.
    """
    from trajgen.sim.dynamics import inverse_dynamics
    from trajgen.sim.model import build_model

    model = build_model(config)
    friction = np.array(model.dof_frictionloss)
    damping = np.array(model.dof_damping)
    bare = build_model(config)
    bare.dof_damping[:] = 0.0

    def inv_dyn(q, qd, qdd):
        return inverse_dynamics(
            bare, np.atleast_2d(q), np.atleast_2d(qd), np.atleast_2d(qdd), coulomb=False
        )[0]

    return inv_dyn, friction, damping


def envelope_constraint(config, x0):
    """Our torque-speed envelope as a toppra LinearConstraint, cut at ``x0 = sd^2`` per gridpoint.

    Row per joint and sign: ``+-tau + e sd <= M`` with ``M = margin tau_stall``,
    ``e = M |p'| / w0 +- damping p'`` (negative ``e`` dropped, which only
    tightens). ``sd = sqrt(x)`` is concave, so its tangent at ``x0`` bounds it
    from above: ``sd <= (x + x0) / (2 sqrt(x0))``. Every cut is therefore
    inside the true envelope, and re-cutting at the last solution climbs to
    the envelope's optimum. ``x`` enters as a 4th component of toppra's
    ``v = a u + b x + c``.
    """
    from toppra.constraint import DiscretizationType, LinearConstraint
    from toppra.constraint.linear_constraint import canlinear_colloc_to_interpolate

    inv_dyn, friction, damping = _inverse_dynamics_parts(config)
    stall = np.array([s.stall_torque_nm for s in config.servos])
    w0 = np.array([s.no_load_speed_rad_s for s in config.servos])
    big_m = config.torque_margin * stall

    class Envelope(LinearConstraint):
        def __init__(self):
            super().__init__()
            self.dof = 3
            self.identical = False
            self.set_discretization_type(DiscretizationType.Interpolation)

        def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
            p, ps, pss = path(gridpoints), path(gridpoints, 1), path(gridpoints, 2)
            zero = np.zeros(3)
            c = np.array([inv_dyn(q, zero, zero) for q in p])
            a = np.array([inv_dyn(q, zero, d) for q, d in zip(p, ps, strict=True)]) - c
            b = np.array([inv_dyn(q, d, dd) for q, d, dd in zip(p, ps, pss, strict=True)]) - c
            c = c + friction * np.sign(ps)
            n = len(gridpoints)
            r0 = np.sqrt(np.maximum(x0, 1e-8))[:, None]
            k = big_m / w0 * np.abs(ps)
            e_plus = np.maximum(k + damping * ps, 0.0)
            e_minus = np.maximum(k - damping * ps, 0.0)
            a4 = np.hstack([a, np.zeros((n, 1))])
            b4 = np.hstack([b, np.ones((n, 1))])
            c4 = np.hstack([c, np.zeros((n, 1))])
            f = np.zeros((n, 6, 4))
            g = np.zeros((n, 6))
            for j in range(3):
                f[:, j, j], f[:, j, 3] = 1.0, e_plus[:, j] / (2 * r0[:, 0])
                f[:, 3 + j, j], f[:, 3 + j, 3] = -1.0, e_minus[:, j] / (2 * r0[:, 0])
                g[:, j] = big_m[j] - e_plus[:, j] * r0[:, 0] / 2
                g[:, 3 + j] = big_m[j] - e_minus[:, j] * r0[:, 0] / 2
            return canlinear_colloc_to_interpolate(
                a4, b4, c4, f, g, None, None, gridpoints, identical=False
            )

    return Envelope()


def _toppra_piece(
    trajectory, config, *, envelope: bool, arc_length: bool = False, grid: int = 801, cuts: int = 3
):
    """TOPP-RA on one reversal-free piece of the planned joint path, rest to rest.

    ``envelope=False``: the torque box ``margin tau_stall`` plus ``|w| <= w0``.
    ``envelope=True``: our torque-speed envelope by ``cuts`` rounds of tangent
    cuts (:func:`envelope_constraint`), started from the box solution.
    ``arc_length``: parametrize the path by joint-space arc length instead of
    our time (see the module docstring).

    Returns
    -------
    duration (s), and the profile at 4001 times: t, q, qd, qdd
    """
    import toppra as ta
    import toppra.algorithm as algo
    import toppra.constraint as constraint

    q = np.asarray(trajectory.q)
    if arc_length:
        step = np.linalg.norm(np.diff(q, axis=0), axis=1)
        keep = np.concatenate([[True], step > 1e-7])
        keep[-1] = True
        s = np.concatenate([[0.0], np.cumsum(step)])[keep]
        q = q[keep]
    else:
        s = (trajectory.t - trajectory.t[0]) / trajectory.duration_s
    path = ta.SplineInterpolator(s, q)
    gridpoints = np.linspace(0.0, s[-1], grid)
    inv_dyn, friction, damping = _inverse_dynamics_parts(config)
    stall = np.array([sv.stall_torque_nm for sv in config.servos])
    w0 = np.array([sv.no_load_speed_rad_s for sv in config.servos])
    box = config.torque_margin * stall
    # The box gets damping as a torque at the no-load speed (at most 0.05 N m).
    box_constraints = [
        constraint.JointTorqueConstraint(inv_dyn, np.stack([-box, box], axis=1) * 1.0, friction),
        constraint.JointVelocityConstraint(np.stack([-w0, w0], axis=1)),
    ]
    instance = algo.TOPPRA(box_constraints, path, gridpoints=gridpoints)
    _, sd, _ = instance.compute_parameterization(0.0, 0.0)
    if envelope:
        for _ in range(cuts):
            if sd is None or not np.isfinite(sd).all():
                break
            instance = algo.TOPPRA(
                [envelope_constraint(config, sd**2)], path, gridpoints=gridpoints
            )
            _, sd, _ = instance.compute_parameterization(0.0, 0.0)
    if sd is None or not np.isfinite(sd).all():
        raise RuntimeError("TOPP-RA found no parametrization")
    jnt = instance.compute_trajectory(0.0, 0.0)
    if jnt is None:
        raise RuntimeError("TOPP-RA found no parametrization")
    t = np.linspace(0.0, jnt.duration, 4001)
    return jnt.duration, t, jnt(t), jnt(t, 1), jnt(t, 2)


def reversals(trajectory) -> list[int]:
    """Samples where the joint path reverses: its velocity vector turns by over 90 degrees.

    There the path speed passes through zero (all joints stop at once), so any
    timing of the path comes to rest there. Returns the sample nearest each
    reversal (smallest joint-space speed), interior samples only.
    """
    qd = np.asarray(trajectory.qd)
    speed = np.linalg.norm(qd, axis=1)
    turning = np.flatnonzero(np.einsum("ij,ij->i", qd[:-2], qd[2:]) < 0) + 1
    cuts = sorted({k - 1 + int(np.argmin(speed[k - 1 : k + 2])) for k in turning})
    return [k for k in cuts if 0 < k < len(qd) - 1]


def toppra_retime(trajectory, config, *, envelope: bool):
    """TOPP-RA on the planned joint path, split at its reversals, each piece rest to rest.

    Each piece is parametrized by our time, or, where TOPP-RA finds no
    parametrization that way, by joint-space arc length (no cusp inside a
    reversal-free piece).

    Returns
    -------
    pieces : list of (duration (s), t, q, qd, qdd), one per piece
    parametrization : str
        "time", "arc length" or "mixed".
    """
    from trajgen.stream import JointTrajectory

    bounds = [0, *reversals(trajectory), len(trajectory.t) - 1]
    pieces, used = [], set()
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        piece = JointTrajectory(
            trajectory.t[a : b + 1],
            trajectory.q[a : b + 1],
            trajectory.qd[a : b + 1],
            trajectory.qdd[a : b + 1],
            trajectory.rate_hz,
        )
        # Gridpoints shared out by samples: about 801 over the whole path.
        grid = max(101, round(800 * (b - a) / (len(trajectory.t) - 1)) + 1)
        for arc in (False, True):
            try:
                pieces.append(
                    _toppra_piece(piece, config, envelope=envelope, arc_length=arc, grid=grid)
                )
                used.add("arc length" if arc else "time")
                break
            except RuntimeError:
                if arc:
                    raise
    return pieces, used.pop() if len(used) == 1 else "mixed"


def envelope_usage(config, q, qd, qdd) -> float:
    """Largest ``|tau| / (margin x envelope)`` of a profile (our full inverse dynamics)."""
    from trajgen.sim.dynamics import inverse_dynamics
    from trajgen.sim.model import build_model

    tau = inverse_dynamics(build_model(config), q, qd, qdd)
    stall = np.array([s.stall_torque_nm for s in config.servos])
    w0 = np.array([s.no_load_speed_rad_s for s in config.servos])
    avail = config.torque_margin * stall * (1 - np.abs(qd) / w0)
    return float(np.max(np.where(avail > 0, np.abs(tau) / avail, np.inf)))


def stretch_into_envelope(config, q, qd, qdd) -> float:
    """Smallest time stretch ``c >= 1`` that puts a profile inside our envelope.

    Slowing a profile by ``c`` divides speed by ``c`` and acceleration by ``c^2``
    on the same path; ``c`` is found by bisection on :func:`envelope_usage`.
    """

    def fits(c):
        return envelope_usage(config, q, qd / c, qdd / c**2) <= 1.0

    if fits(1.0):
        return 1.0
    hi = 1.5
    while not fits(hi):
        hi *= 1.5
    lo = hi / 1.5
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def construction_floor(path, durations: np.ndarray, *, seed: int = 0) -> tuple[float, float]:
    """The best plan-only time any per-segment timing of this spline reaches, by global search.

    Differential evolution (scipy) over the segment durations' ratios (log,
    within e^+-1.2 of ``durations``'s; the first segment fixed, since the
    uniformly scaled time does not depend on the overall scale), on the fast
    probe evaluation (``durations`` is in its first population), then
    Nelder-Mead from its best; both are judged exactly on the stream's samples.

    Returns
    -------
    floor (s), and the search's wall time (s)
    """
    from scipy.optimize import differential_evolution, minimize

    from trajgen.sim.fit_durations import uniform_time_function

    start = time.monotonic()
    probe = uniform_time_function(path, probe=True)
    exact = uniform_time_function(path)
    x0 = np.log(durations)

    def shaped(y):
        return np.exp(x0 + np.concatenate([[0.0], y]))

    n = len(durations) - 1
    if n == 0:  # nothing to search: the one duration only scales
        return exact(durations), time.monotonic() - start
    found = differential_evolution(
        lambda y: probe(shaped(y)),
        [(-1.2, 1.2)] * n,
        x0=np.zeros(n),
        seed=seed,
        popsize=15,
        maxiter=60,
        tol=1e-5,
        polish=False,
        init="sobol",
    )
    polished = minimize(
        lambda y: probe(shaped(y)),
        found.x,
        method="Nelder-Mead",
        options={"xatol": 1e-4, "fatol": 1e-5, "maxfev": 800},
    )
    floor = min(exact(shaped(found.x)), exact(shaped(polished.x)))
    return floor, time.monotonic() - start


def main(argv=None) -> int:
    import torque_race

    from trajgen.sim.check import resolve_source
    from trajgen.sim.fit_durations import fit_durations
    from trajgen.smooth import KNOTS

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--random", type=int, default=3, help="random motions (default 3)")
    parser.add_argument("--only", help="run only the motions whose name contains this")
    parser.add_argument(
        "--knots", choices=KNOTS, help="SmoothSpline's knot choice (default: the file default)"
    )
    args = parser.parse_args(argv)
    # One segment: with knots = "quintic" the spline is then the septic 35u^4 - 84u^5 +
    # 70u^6 - 20u^7, peak acceleration 7.5 D/T^2 against bang-bang's 4: where inertia
    # dominates the torque, its time is sqrt(7.5 / 4) = 1.37x the optimum whatever the
    # timing ("end-minimax" trades more acceleration for less jerk at the ends).
    single = {"one segment": np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0]])}
    cases = {**torque_race.motions(), **single, **random_motions(args.random)}
    if args.only:
        cases = {k: v for k, v in cases.items() if args.only in k}
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 cores)")
    print()
    print(
        "| motion | keys | ours, plan only (s) | fit time (s) | ours, full check (s) "
        "| floor (s) | TOPP-RA envelope (s) | its envelope use "
        "| TOPP-RA stretched into envelope (s) | ours plan only / TOPP-RA "
        "| floor / TOPP-RA | TOPP-RA box (s) | TOPP-RA pieces, path "
        "| TOPP-RA max qdd step (rad/s^2) | TOPP-RA qdd at ends (rad/s^2) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|")
    ratios, floor_ratios, shares = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name, angles in cases.items():
            t0 = time.monotonic()
            path = Path(tmp) / "keys.toml"
            path.write_text(keyframe_text(angles, 1.5, args.knots))
            full = fit_durations(path)
            fit_start = time.monotonic()
            fit = fit_durations(path, simulate=False)
            fit_s = time.monotonic() - fit_start
            floor, floor_s = construction_floor(path, np.diff(fit.times))
            fitted = Path(tmp) / "fitted.toml"
            fitted.write_text(fit.toml())
            trajectory, config = resolve_source(fitted)
            row, params = {}, {}
            for feed in ("envelope", "box"):
                try:
                    row[feed], params[feed] = toppra_retime(
                        trajectory, config, envelope=feed == "envelope"
                    )
                except RuntimeError as e:
                    row[feed] = str(e)
            env, box = row["envelope"], row["box"]
            box_cell = box if isinstance(box, str) else f"{sum(p[0] for p in box):.3f}"
            if isinstance(env, str):
                cells = [f"failed: {env}", "-", "-", "-", "-"]
                jump = ends = "-"
            else:
                duration = sum(p[0] for p in env)
                use = max(envelope_usage(config, *p[2:]) for p in env)
                stretched = sum(p[0] * stretch_into_envelope(config, *p[2:]) for p in env)
                ratio, floor_ratio = fit.duration_s / stretched, floor / stretched
                ratios.append(ratio)
                floor_ratios.append(floor_ratio)
                if ratio > 1:
                    shares.append((floor_ratio - 1) / (ratio - 1))
                cells = [
                    f"{duration:.3f}",
                    f"{use:.2f}",
                    f"{stretched:.3f}",
                    f"{ratio:.3f}",
                    f"{floor_ratio:.3f}",
                ]
                qdd = np.concatenate([p[4] for p in env])
                jump = f"{np.abs(np.diff(qdd, axis=0)).max():.1f}"
                ends = f"{max(np.abs(qdd[0]).max(), np.abs(qdd[-1]).max()):.1f}"
            pieces = f"{len(env)}, {params['envelope']}" if "envelope" in params else "-"
            print(
                f"| {name} | {len(angles)} | {fit.duration_s:.3f} | {fit_s:.1f} "
                f"| {full.duration_s:.3f} | {floor:.3f} | {' | '.join(cells)} | {box_cell} "
                f"| {pieces} | {jump} | {ends} |",
                flush=True,
            )
            print(
                f"  {name}: {time.monotonic() - t0:.1f} s (floor search {floor_s:.1f} s), "
                f"load {os.getloadavg()[0]:.2f}",
                file=sys.stderr,
            )
    print()
    if ratios:
        print(
            f"ours (plan only) / TOPP-RA (envelope, stretched into it): median "
            f"{np.median(ratios):.3f}, range {np.min(ratios):.3f} .. {np.max(ratios):.3f} "
            "(goal <= 1.15)"
        )
        print(
            f"floor / TOPP-RA: median {np.median(floor_ratios):.3f}, range "
            f"{np.min(floor_ratios):.3f} .. {np.max(floor_ratios):.3f}; share of the gap the "
            f"floor explains: median {np.median(shares):.0%}"
        )
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
