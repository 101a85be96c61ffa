"""The retiming fit against TOPP-RA and against today's keyframe-times fit, and its cost.

Motions: the torque race's three, the examples (``examples/*.toml`` that start
and end at rest; ``wrist_loop`` is a closed loop and is skipped), and seeded
random look-arounds (4-7 keyframes). The race's and the random motions are
written as in ``bench/fit_vs_toppra.py`` (smooth spline, rest ends, 200 Hz,
XM430-W350 x 3, tracking budget 1 rad so that torque decides); the examples are
used as they are (their own ``[gimbal]`` table and spline, which the retiming
replaces by the C3 smooth spline through the same keyframes).

Per motion:

- ``ours, plan only``: ``fit_timing(path, simulate=False)`` (envelope x
  margin, torque rate R = 300 N m/s, ``[limits]``), and its wall time;
- TOPP-RA on the same joint path (the fit's SmoothSpline in its own time,
  ``bench/fit_vs_toppra.py``'s ``toppra_retime``: our envelope as a
  LinearConstraint, split at reversals): its raw duration (it leaves the
  envelope between gridpoints and has no torque-rate bound) and stretched
  uniformly into the envelope; ``ours / raw`` is the goal's ratio;
- ``R-bounded optimum``: the time-optimal profile under the envelope and the
  torque-rate bound R on a grid of ``OPTIMUM_POINTS`` points
  (``trajgen.sim.retime_optimum``: a direct transcription in ``s'^2``, sequential
  LP on HiGHS, started from our plan), TOPP-RA's peer where the bound binds:
  like TOPP-RA's raw profile it holds its limits at its gridpoints only;
  ``ours / optimum``;
- ``3x points``: the same fit with three times the control points and 1.5x
  the constraint points per interval (``--dense``): how much a richer law
  would gain;
- ``ours, full check``: ``fit_timing(path)`` (plan and simulated servo, the
  public ``check_torque``), and ``today's fit``
  (``trajgen.sim.fit_durations.fit_durations``, the keyframe-times fit this
  replaces) measured in the same run; ``ours / today``;
- the full-check result's peak planned torque rate at 1 kHz (Coulomb friction
  left out, as the check does) and its jerk continuity: the largest jerk
  change between samples at 1 kHz over that at 10 kHz (a jerk step keeps its
  size, a continuous jerk falls tenfold).

Then the cost: random look-arounds of 8, 16, 24 and 40 keyframes fitted plan
only and with the full check, wall time per fit with the load beside it, and
the fitted exponent of time against keyframes (least squares in log-log).

Usage::

    python bench/retime_vs_toppra.py [--random 10] [--only NAME] [--dense]
        [--no-scaling | --scaling-only]

Times are wall (CPU of this process) in seconds.
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

ROOT = Path(__file__).resolve().parent.parent
R_NM_S = 300.0
#: Gridpoints of the R-bounded optimum (uniform in our plan's time).
OPTIMUM_POINTS = 800
SCALING_KEYFRAMES = (8, 16, 24, 40)


def _load() -> str:
    return f"load {os.getloadavg()[0]:.1f}"


class _Clock:
    """Wall and CPU time (s) of this process since it was made: on a loaded machine the
    CPU time is the cost, the wall time what a user waits."""

    def __init__(self):
        self.wall, self.cpu = time.monotonic(), time.process_time()

    def __str__(self) -> str:
        return f"{time.monotonic() - self.wall:.1f} ({time.process_time() - self.cpu:.1f})"

    @property
    def seconds(self) -> tuple[float, float]:
        return time.monotonic() - self.wall, time.process_time() - self.cpu


def cases(n_random: int, tmp: Path) -> dict[str, Path]:
    import torque_race
    from fit_vs_toppra import keyframe_text, random_motions

    from trajgen.keyframes import load_keyframe_file

    out = {}
    for name, angles in {**torque_race.motions(), **random_motions(n_random)}.items():
        path = tmp / f"{name.replace(' ', '_')}.toml"
        path.write_text(keyframe_text(angles, 1.5))
        out[name] = path
    for path in sorted((ROOT / "examples").glob("*.toml")):
        kf = load_keyframe_file(path)
        if kf.spline_options.get("boundary", "rest") != "rest":
            print(f"skipped {path.name}: boundary {kf.spline_options['boundary']!r}, not rest")
            continue
        out[f"example {path.stem}"] = path
    return out


def toppra_times(result, config) -> tuple[float, float]:
    """TOPP-RA's raw and stretched-into-envelope durations on the fit's path."""
    from fit_vs_toppra import stretch_into_envelope, toppra_retime

    from trajgen.stream import plan_joint_trajectory

    path = plan_joint_trajectory(result.path.path, 200.0)
    pieces, _ = toppra_retime(path, config, envelope=True)
    raw = sum(p[0] for p in pieces)
    stretched = sum(p[0] * stretch_into_envelope(config, *p[2:]) for p in pieces)
    return raw, stretched


def rate_bounded_optimum(result, config) -> float:
    """The R-bounded time-optimal duration (s) on the fit's path, from our plan's profile."""
    from trajgen.sim.retime_optimum import rate_bounded_optimum
    from trajgen.sim.retime_path import path_dynamics
    from trajgen.sim.run import simulation_model

    dyn = path_dynamics(result.path.path, simulation_model(config), config)
    law = result.law
    s, speed = law(np.linspace(law.t_start, law.t_end, OPTIMUM_POINTS + 1), 1)
    s = np.clip(s - law.s_start, 0.0, dyn.s_span)
    s[0], s[-1] = 0.0, dyn.s_span
    return rate_bounded_optimum(dyn, s, speed, R_NM_S).duration_s


def dense_optimum(path) -> float:
    """The plan-only fit with three times the control and constraint points (s)."""
    import trajgen.sim.retime as retime
    from trajgen.sim import fit_timing

    saved = retime.COEFFICIENTS_PER_SEGMENT, retime.POINTS_PER_INTERVAL
    retime.COEFFICIENTS_PER_SEGMENT = 3 * saved[0]
    retime.POINTS_PER_INTERVAL = 6
    try:
        return fit_timing(path, simulate=False).duration_s
    finally:
        retime.COEFFICIENTS_PER_SEGMENT, retime.POINTS_PER_INTERVAL = saved


def smoothness(result, config) -> tuple[float, float]:
    """Peak planned torque rate (N m/s) at 1 kHz and the 1 kHz / 10 kHz jerk-step ratio."""
    from trajgen.sim.dynamics import inverse_dynamics_split
    from trajgen.sim.run import simulation_model
    from trajgen.stream import plan_joint_trajectory

    fine = plan_joint_trajectory(result.path, 1000.0)
    _, smooth = inverse_dynamics_split(simulation_model(config), fine.q, fine.qd, fine.qdd)
    rate = float((np.abs(np.diff(smooth, axis=0)) / np.diff(fine.t)[:, None]).max())
    steps = [
        np.abs(np.diff(result.path.sample(hz, max_order=3).jerk, axis=0)).max()
        for hz in (1000.0, 10000.0)
    ]
    return rate, float(steps[0] / steps[1])


def compare(names_paths, dense: bool) -> None:
    from trajgen.sim import fit_timing
    from trajgen.sim.fit_durations import fit_durations
    from trajgen.sim.model import gimbal_config_from_tables

    print(
        "| motion | keys | ours plan only (s) | fit wall (CPU) s | TOPP-RA raw (s) "
        "| TOPP-RA stretched (s) | ours / raw | ours / stretched | R-bounded optimum (s) "
        "| ours / optimum | 3x points (s) "
        "| ours full check (s) | fit wall (CPU) s | today's fit (s) | fit wall (CPU) s "
        "| ours / today | peak torque rate 1 kHz (N m/s) | jerk step 1k / 10k | load |"
    )
    print("|---|" + "---:|" * 17 + "---|")
    raw_ratios, optimum_ratios, today_ratios, rates, jerks = [], [], [], [], []
    for name, path in names_paths.items():
        clock = _Clock()
        plan = fit_timing(path, simulate=False)
        plan_s = str(clock)
        from trajgen.keyframes import load_keyframe_file

        config = gimbal_config_from_tables(load_keyframe_file(path).tables, path)
        try:
            raw, stretched = toppra_times(plan, config)
            raw_cells = f"{raw:.3f} | {stretched:.3f} | {plan.duration_s / raw:.3f} | " + (
                f"{plan.duration_s / stretched:.3f}"
            )
            raw_ratios.append(plan.duration_s / raw)
        except RuntimeError as e:
            raw_cells = f"failed: {e} | - | - | -"
        clock = _Clock()
        best = rate_bounded_optimum(plan, config)
        optimum_ratios.append(plan.duration_s / best)
        raw_cells += f" | {best:.3f} ({clock}) | {plan.duration_s / best:.3f}"
        optimum = f"{dense_optimum(path):.3f}" if dense else "-"
        clock = _Clock()
        full = fit_timing(path)
        full_s = str(clock)
        clock = _Clock()
        try:
            today = fit_durations(path)
            today_cell = f"{today.duration_s:.3f}"
            ratio = full.duration_s / today.duration_s
            today_ratios.append(ratio)
            ratio_cell = f"{ratio:.3f}"
        except Exception as e:  # noqa: BLE001 - a refusal is a figure too
            today_cell, ratio_cell = f"refused: {e}", "-"
        today_s = str(clock)
        rate, jerk = smoothness(full, config)
        rates.append(rate)
        jerks.append(jerk)
        ok = "" if full.report.ok else " (FAILED)"
        print(
            f"| {name} | {len(plan.times)} | {plan.duration_s:.3f} | {plan_s} | {raw_cells} "
            f"| {optimum} | {full.duration_s:.3f}{ok} | {full_s} | {today_cell} "
            f"| {today_s} | {ratio_cell} | {rate:.0f} | {jerk:.1f} | {_load()} |",
            flush=True,
        )
    print()
    if raw_ratios:
        print(
            f"ours plan only / TOPP-RA raw: median {np.median(raw_ratios):.3f}, max "
            f"{np.max(raw_ratios):.3f} (goals: median <= 1.03, every motion <= 1.05)"
        )
    if optimum_ratios:
        print(
            f"ours plan only / R-bounded optimum: median {np.median(optimum_ratios):.3f}, max "
            f"{np.max(optimum_ratios):.3f}"
        )
    if today_ratios:
        print(
            f"ours full check / today's fit: median {np.median(today_ratios):.3f}, max "
            f"{np.max(today_ratios):.3f} (goal: median <= 0.85)"
        )
    print(f"peak torque rate at 1 kHz: max {np.max(rates):.0f} N m/s (goal <= {R_NM_S:g})")
    print(f"jerk step 1 kHz / 10 kHz: min {np.min(jerks):.1f} (goal >= 5)")


def scaling(tmp: Path) -> None:
    from fit_vs_toppra import keyframe_text

    from trajgen.sim import fit_timing

    rng = np.random.default_rng(7)
    warm = tmp / "warm.toml"  # imports (scipy, MuJoCo) paid before the clock starts
    warm.write_text(keyframe_text(np.array([[0.0, 0, 0], [30, 10, 0], [0, 0, 0]]), 1.5))
    fit_timing(warm)
    print()
    print(
        "| keyframes | plan only, wall (CPU) s | full check, wall (CPU) s "
        "| fitted duration (s) | load |"
    )
    print("|---:|---:|---:|---:|---|")
    timings = {"plan only": [], "full check": []}
    for n in SCALING_KEYFRAMES:
        look = rng.uniform([-70, -30, -10], [70, 30, 10], size=(n, 3))
        look[0] = look[-1] = 0.0
        path = tmp / f"scale{n}.toml"
        path.write_text(keyframe_text(look, 1.5))
        clock = _Clock()
        fit_timing(path, simulate=False)
        plan = clock.seconds
        clock = _Clock()
        full = fit_timing(path)
        full_s = clock.seconds
        timings["plan only"].append(plan)
        timings["full check"].append(full_s)
        print(
            f"| {n} | {plan[0]:.1f} ({plan[1]:.1f}) | {full_s[0]:.1f} ({full_s[1]:.1f}) "
            f"| {full.duration_s:.3f} | {_load()} |",
            flush=True,
        )
    x = np.log(SCALING_KEYFRAMES)
    for label, values in timings.items():
        wall, cpu = (np.polyfit(x, np.log(np.array(values)[:, k]), 1)[0] for k in (0, 1))
        print(f"{label}: wall time ~ n^{wall:.2f}, CPU time ~ n^{cpu:.2f} (goal <= 1.5)")
    print("goals: 8 keyframes <= 5 s, 40 keyframes <= 60 s on 2 cores")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--random", type=int, default=10, help="random motions (default 10)")
    parser.add_argument("--only", help="run only the motions whose name contains this")
    parser.add_argument("--no-scaling", action="store_true", help="skip the cost table")
    parser.add_argument("--scaling-only", action="store_true", help="only the cost table")
    parser.add_argument("--dense", action="store_true", help="add the R-bounded optimum column")
    args = parser.parse_args(argv)
    print(f"{_load()} before (2 cores); lead goals in the check: {_has_lead()}")
    with tempfile.TemporaryDirectory() as tmp:
        found = cases(args.random, Path(tmp))
        if args.only:
            found = {k: v for k, v in found.items() if args.only in k}
        if not args.scaling_only:
            compare(found, args.dense)
        if not args.no_scaling:
            scaling(Path(tmp))
    print(f"{_load()} after")
    return 0


def _has_lead() -> str:
    """Whether the check in this tree sends led goals (the tracking issue's change)."""
    import inspect

    import trajgen.sim.run as run

    return "yes" if "lead" in inspect.getsource(run) else "no"


if __name__ == "__main__":
    raise SystemExit(main())
