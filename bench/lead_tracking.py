"""Tracking error with led goals: none / advance / model on the simulated gimbal.

Each motion (the files in ``examples/``, the built-in look-around and seeded
random look-arounds whose plans pass the torque check) is planned at its
``[stream]`` rate, its goals led three ways (``trajgen.lead``: the same
function ``trajgen stream`` sends and ``trajgen sim`` simulates) and run
through the simulated servos (``sim.check.check_torque``: the firmware loop,
goals in whole ticks held one period, 1 ms physics). Per motion and lead:
max and RMS tracking error of the worst joint against the plan (mrad), peak
simulated torque over the three joints as a ratio to no lead (the named peer,
same run), goals outside their bounds, and the verdict. The last lines give
the machine load. The simulated servos start where they sag under their first
goal (``sim.lead.sagged_start``); the model lead's lift (``trajgen.lift``) is
sent before the plan and reported apart (its length, the error during it, the
error at the plan's first frame); the error above is from the plan's start.

For the model lead it also prints, per motion, the cost of computing the
goals per frame (``trajgen.lead.led_goals`` with the bounded preview, against
the plain clip as the peer, same run, inverse dynamics included), and, for each
joint whose goals a bound clips, the loop-model floor: the least max error that
any goals inside the bounds can give against the servo loop's linear model
(a linear programme, ``scipy.optimize.linprog``), beside what that model
predicts for the plain clip and for the preview.

Usage::

    python bench/lead_tracking.py [--random 6] [--seed 7] [--p-divisor 128] [--only NAME]

``--only bus_u2d2 --random 0`` reruns one example (its loop-model floor included).

``--p-divisor 256`` simulates servos whose firmware divides P by 256 while the
lead still assumes the configured 128 (how much the lead depends on the P
scale; ``docs/lead.md``).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LEADS = ("none", "advance", "model")


def motions(n_random: int, seed: int):
    """(name, source, config) for every motion: files, then random look-arounds."""
    from trajgen.keyframes import BUILTIN_EXAMPLE, load_keyframe_file
    from trajgen.quat import from_pan_tilt_roll
    from trajgen.sim.check import check_planned_torque
    from trajgen.sim.model import GimbalConfig, gimbal_config_from_tables
    from trajgen.smooth import SmoothSpline
    from trajgen.stream import plan_joint_trajectory

    for path in [*sorted((ROOT / "examples").glob("*.toml")), BUILTIN_EXAMPLE]:
        kf = load_keyframe_file(path)
        yield path.stem, kf, gimbal_config_from_tables(kf.tables, kf.path, any_axes=True)
    rng = np.random.default_rng(seed)
    made = tries = 0
    while made < n_random and tries < 20 * max(n_random, 1):
        tries += 1
        n = int(rng.integers(4, 8))
        times = np.concatenate([[0.0], np.cumsum(rng.uniform(1.0, 2.0, n - 1))])
        pan = np.radians(rng.uniform(-60, 60, n))
        tilt = np.radians(rng.uniform(-25, 25, n))
        roll = np.radians(rng.uniform(-15, 15, n))
        spline = SmoothSpline(from_pan_tilt_roll(pan, tilt, roll), times)
        trajectory = plan_joint_trajectory(spline, 200.0)
        config = GimbalConfig()
        if check_planned_torque(trajectory, config):
            continue  # infeasible: not what the lead is for
        made += 1
        yield f"random{made}", trajectory, config


def run(name, source, config, p_divisor):
    from trajgen.lift import sent_goals
    from trajgen.sim.check import check_torque

    rows = {}
    for lead in LEADS:
        report = check_torque(
            source, config=config, lead=lead, servo_config=_real(config, p_divisor)
        )
        rec = report.record  # from the plan's first frame; the lift's steps apart
        err = np.abs(rec.tracking_error_rad)
        worst = int(np.argmax(err.max(axis=0)))
        goal = sent_goals(report.trajectory)[1]  # the lift's goals too
        b = report.goal_bounds_rad
        outside = int(((goal < b[:, 0] - 1e-12) | (goal > b[:, 1] + 1e-12)).sum())
        rows[lead] = {
            "max_mrad": 1e3 * err[:, worst].max(),
            "rms_mrad": 1e3 * np.sqrt(np.mean(err[:, worst] ** 2)),
            "joint": config.names[worst],
            "peak_nm": float(np.abs(rec.with_lift().torque_nm).max()),
            "outside": outside,
            "ok": report.ok,
            "starts_moving": bool(np.abs(report.trajectory.qd[0]).max() > 1e-9),
        }
        if report.lift_s:
            lifted = max(report.joints.values(), key=lambda j: j.max_lift_error_rad)
            print(
                f"  {name} {lead}: lift {report.lift_s:.3f} s; during it the servo is up to "
                f"{1e3 * lifted.max_lift_error_rad:.2f} mrad ({lifted.name}) off the held "
                f"first point (its sag); at the plan's start "
                f"{1e3 * np.abs(rec.tracking_error_rad[0]).max():.3f} mrad",
                flush=True,
            )
    from trajgen.sim.check import resolve_source

    trajectory, _ = resolve_source(source, config=config)
    with_preview, clip = lead_cost(trajectory, config)
    print(
        f"  {name}: model goals {1e6 * with_preview:.1f} us/frame with the preview, "
        f"{1e6 * clip:.1f} plain clip (ratio {with_preview / clip:.2f}), "
        f"{len(trajectory.t)} frames",
        flush=True,
    )
    for joint, floor, clipped, preview in loop_floor(trajectory, config):
        print(
            f"  {name} {joint}: clipped; loop-model max error: floor {1e3 * floor:.2f} mrad, "
            f"plain clip {1e3 * clipped:.2f}, preview {1e3 * preview:.2f}",
            flush=True,
        )
    base = rows["none"]["peak_nm"]
    for lead in LEADS:
        r = rows[lead]
        print(
            f"| {name} | {lead} | {r['max_mrad']:.2f} / {r['rms_mrad']:.2f} ({r['joint']}) | "
            f"{r['peak_nm']:.3f} | {r['peak_nm'] / base:.3f} | {r['outside']} | "
            f"{'OK' if r['ok'] else 'FAILED'} |",
            flush=True,
        )
    return rows


def lead_cost(trajectory, config, rounds=3):
    """Seconds per frame of the model lead's goals: (with the preview, plain clip)."""
    import time

    from trajgen.lead import led_goals
    from trajgen.sim.lead import lead_params, torque_function
    from trajgen.sim.run import simulation_model

    model = simulation_model(config)
    torque = torque_function(model)
    previewed = lead_params(config, model)
    plain = dataclasses.replace(previewed, inertia_kg_m2=None)
    out = []
    for params in (previewed, plain):
        best = np.inf
        for _ in range(rounds):
            start = time.perf_counter()
            led_goals(trajectory, "model", params, torque=torque)
            best = min(best, time.perf_counter() - start)
        out.append(best / len(trajectory.t))
    return out


def loop_floor(trajectory, config):
    """Per clipped joint: (name, floor, clip, preview) max error in rad against the loop's
    linear model (``trajgen.lead_preview``): the least any goals inside the range can
    give (a linear programme over each window), and what the plain clip and the
    preview give."""
    from scipy.optimize import linprog

    from trajgen.lead_preview import _windows, pulse_response
    from trajgen.sim.lead import lead_params, lead_trajectory
    from trajgen.sim.run import simulation_model

    model = simulation_model(config)
    _, goals, _ = lead_trajectory(trajectory, config, "model", model=model)
    params = lead_params(config, model)
    period = 1.0 / trajectory.rate_hz
    rows = []
    for j, name in enumerate(config.names):
        wanted, lo, hi = goals.wanted[:, j], goals.bounds[j, 0], goals.bounds[j, 1]
        frames = np.flatnonzero((wanted < lo) | (wanted > hi))
        if not len(frames):
            continue
        kp, inertia = params.kp_nm_rad[j], params.inertia_kg_m2[j]
        h = pulse_response(kp, kp * params.lag_s[j], inertia, period)
        floor = 0.0
        for first, last in _windows(frames, len(h), len(wanted)):
            k = last - first
            response = np.zeros((k + len(h), k))
            for m in range(k):
                response[m : m + len(h), m] = h
            ones = np.ones((len(response), 1))
            a_ub = np.block([[response, -ones], [-response, -ones]])
            box = [(lo - w, hi - w) for w in wanted[first:last]] + [(0.0, None)]
            c = np.r_[np.zeros(k), 1.0]
            result = linprog(c, A_ub=a_ub, b_ub=np.zeros(2 * len(response)), bounds=box)
            floor = max(floor, result.x[-1])
        clip = np.abs(np.convolve(np.clip(wanted, lo, hi) - wanted, h)).max()
        preview = np.abs(np.convolve(goals.goal[:, j] - wanted, h)).max()
        rows.append((name, floor, clip, preview))
    return rows


def _real(config, p_divisor):
    """The servos as simulated: ``config`` with its P divisor replaced (None: as is)."""
    return None if p_divisor is None else dataclasses.replace(config, p_divisor=p_divisor)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--random", type=int, default=6, help="random look-arounds (default 6)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--p-divisor",
        type=float,
        help="simulate servos with this P divisor while the lead assumes the file's",
    )
    parser.add_argument("--only", help="run only the motions whose name contains this")
    args = parser.parse_args(argv)
    print(f"load before: {os.getloadavg()}", file=sys.stderr)
    print(
        "| motion | lead | max / RMS error, worst joint (mrad) | peak torque (N m) | "
        "vs none | goals outside bounds | verdict |"
    )
    print("|---|---|---|---|---|---|---|")
    summary = {lead: [] for lead in LEADS}
    ratios, moving = [], []
    for name, source, config in motions(args.random, args.seed):
        if args.only and args.only not in name:
            continue
        print(f"{name}...", file=sys.stderr, flush=True)
        rows = run(name, source, config, args.p_divisor)
        if name == "sim_too_fast":
            continue  # infeasible by design: the lead is switched off where the plan fails
        if rows["none"]["starts_moving"]:
            moving.append(name)  # the gimbal starts at rest: a catch-up no goal avoids
            continue
        for lead in LEADS:
            summary[lead].append(rows[lead]["max_mrad"])
        ratios.append(rows["model"]["peak_nm"] / rows["none"]["peak_nm"])
    n = len(ratios)
    for lead in LEADS if n else ():
        print(
            f"{lead}: max error over {n} feasible rest-to-rest motions "
            f"{max(summary[lead]):.2f} mrad (median {np.median(summary[lead]):.2f})"
        )
    if n:
        print(f"model peak torque / none: {min(ratios):.3f} .. {max(ratios):.3f}")
    print(f"left out of the summary (the plan starts moving): {', '.join(moving) or 'none'}")
    print(f"load after (1, 5, 15 min): {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
