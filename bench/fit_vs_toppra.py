"""`fit_timing` against TOPP-RA on the same geometric path with the same torque model.

For each motion (the torque race's three, then seeded random look-arounds;
rest boundary, k = 2, 200 Hz, XM430-W350 x 3, 0.15 kg payload):

1. ``trajgen.sim.fit_timing`` fits the keyframe times (torque check incl.
   simulation, tight to 10 %); its joint path ``q(t)``, ``t`` in ``[0, T_ours]``,
   is the geometric path.
2. TOPP-RA (``toppra``) re-times that same path, sampled at 1 kHz into its
   cubic-spline path, from rest to rest (``sd_start = sd_end = 0``), with
   ``JointTorqueConstraint`` fed by our gimbal's inverse dynamics
   (``sim.dynamics.inverse_dynamics`` without Coulomb friction, which TOPP-RA
   adds itself from ``fs_coef`` = our ``frictionloss``) and
   ``JointVelocityConstraint``.

How the envelope is fed: TOPP-RA's torque constraint is a box, ours is the
torque-speed line ``|tau| <= margin tau_stall (1 - |w| / w0)``. TOPP-RA gets the
box ``|tau| <= margin tau_stall`` and ``|w| <= w0``. That ignores the drop of
available torque with speed (at half the no-load speed only half the torque is
there), so TOPP-RA's optimum is a lower bound on the true optimum under our
envelope, and its profile may leave our envelope (column "TOPP-RA in envelope").
Viscous damping (0.01 N m s/rad) enters TOPP-RA's ``b(s) sd^2`` term as if it
were quadratic in speed (at most 0.05 N m). Our check also simulates the servo
(torque limit steps, tracking), which TOPP-RA does not.

Usage::

    python bench/fit_vs_toppra.py [--random 3]
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


def keyframe_text(angles_deg: np.ndarray, pace_s: float) -> str:
    lines = ["[spline]", "k = 2", 'boundary = "rest"', "", "[stream]", f"rate_hz = {RATE_HZ:g}", ""]
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


def toppra_retime(trajectory, config):
    """TOPP-RA on the planned joint path; returns (duration, profile samples, toppra path)."""
    import toppra as ta
    import toppra.algorithm as algo
    import toppra.constraint as constraint

    from trajgen.sim.dynamics import inverse_dynamics
    from trajgen.sim.model import build_model

    model = build_model(config)
    s = (trajectory.t - trajectory.t[0]) / trajectory.duration_s
    path = ta.SplineInterpolator(s, trajectory.q)

    def inv_dyn(q, qd, qdd):
        return inverse_dynamics(
            model, np.atleast_2d(q), np.atleast_2d(qd), np.atleast_2d(qdd), coulomb=False
        )[0]

    stall = np.array([sv.stall_torque_nm for sv in config.servos])
    w0 = np.array([sv.no_load_speed_rad_s for sv in config.servos])
    box = config.torque_margin * stall
    friction = np.array(model.dof_frictionloss)
    constraints = [
        constraint.JointTorqueConstraint(
            inv_dyn,
            np.stack([-box, box], axis=1),
            friction,
            discretization_scheme=constraint.DiscretizationType.Interpolation,
        ),
        constraint.JointVelocityConstraint(np.stack([-w0, w0], axis=1)),
    ]
    instance = algo.TOPPRA(constraints, path, gridpoints=np.linspace(0, 1, 401))
    jnt = instance.compute_trajectory(0.0, 0.0)
    if jnt is None:
        raise RuntimeError("TOPP-RA found no parametrization")
    t = np.linspace(0.0, jnt.duration, 4001)
    return jnt.duration, t, jnt(t), jnt(t, 1), jnt(t, 2), model, stall, w0


def main(argv=None) -> int:
    import torque_race

    from trajgen.sim import fit_timing
    from trajgen.sim.check import resolve_source
    from trajgen.sim.dynamics import inverse_dynamics

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--random", type=int, default=3, help="random motions (default 3)")
    args = parser.parse_args(argv)
    cases = {**torque_race.motions(), **random_motions(args.random)}
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 cores)")
    print()
    print(
        "| motion | keyframes | ours (s) | TOPP-RA (s) | ours / TOPP-RA | TOPP-RA in envelope "
        "| TOPP-RA max qdd jump (rad/s^2) | TOPP-RA qdd at ends (rad/s^2) | ours: binding |"
    )
    print("|---|---:|---:|---:|---:|---|---:|---:|---|")
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, angles in cases.items():
            t0 = time.monotonic()
            path = Path(tmp) / "keys.toml"
            path.write_text(keyframe_text(angles, 1.5))
            fit = fit_timing(path)
            fitted = Path(tmp) / "fitted.toml"
            fitted.write_text(fit.toml())
            trajectory, config = resolve_source(fitted)
            try:
                duration, t, q, qd, qdd, model, stall, w0 = toppra_retime(trajectory, config)
            except RuntimeError as e:
                print(
                    f"| {name} | {len(angles)} | {fit.duration_s:.3f} | failed: {e} "
                    "| - | - | - | - | - |"
                )
                continue
            tau = inverse_dynamics(model, q, qd, qdd)
            within = bool(
                (np.abs(tau) <= config.torque_margin * stall * (1 - np.abs(qd) / w0) + 1e-9).all()
            )
            jump = float(np.abs(np.diff(qdd, axis=0)).max())
            ends = float(max(np.abs(qdd[0]).max(), np.abs(qdd[-1]).max()))
            ratio = fit.duration_s / duration
            ratios.append(ratio)
            bindings = sorted({s.binding.split(" (")[0] for s in fit.segments})
            print(
                f"| {name} | {len(angles)} | {fit.duration_s:.3f} | {duration:.3f} | "
                f"{ratio:.3f} | {'yes' if within else 'no'} | {jump:.1f} | {ends:.1f} | "
                f"{', '.join(bindings)} |",
                flush=True,
            )
            print(f"  {name}: {time.monotonic() - t0:.1f} s", file=sys.stderr)
    print()
    print(
        f"ours / TOPP-RA: median {np.median(ratios):.3f}, max {np.max(ratios):.3f} (goal <= 1.15)"
    )
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
