"""Untimed steps: the tracker's time to within 1 deg of a target, against Ruckig's.

Ruckig (``pip install trajgen[ruckig]``) computes the time-optimal joint motion
to a target under per-joint speed, acceleration and jerk limits from any state;
it knows nothing of orientation, gimbal lock or torque. Both get the same
per-joint limits on pan and tilt (roll too, unused), the same start state and
the same goal:

- steps of several sizes from rest (pan, and pan + tilt together);
- the same steps in motion: 0.1 s into a move to another target, the tracker
  replaces it (``Tracker.set_target``) and Ruckig starts from the tracker's
  joint position, speed and acceleration at that instant; the move in progress
  is the tracker's own (``in motion``) or a timed line, a retarget through the
  other target 0.6 s ahead (``timed``: an orientation splice, not a joint motion).

Figure: time from the step to the moment after which every joint stays within
1 deg of the goal (the tracker's path sampled at its 1 kHz frames, Ruckig's
trajectory at the same times), and the ratio tracker / Ruckig (goal <= 1.3x). A
deferred change (no arrival from the step's time kept the limits) counts from
the step, not from the later change.

Run: .venv/bin/python bench/tracker_vs_ruckig.py [--limits 3,20,200]
"""

from __future__ import annotations

import argparse
import math
import os

import numpy as np

from trajgen.gimbal import forward, joint_rates
from trajgen.online import OnlineSpline
from trajgen.tracker import Tracker

D = math.radians
WITHIN_RAD = D(1.0)
RATE_HZ = 1000.0
#: A moving start: the first target, and how long after it the step replaces it.
FIRST_TARGET = np.array([D(-20.0), D(10.0), 0.0])
IN_MOTION_S = 0.1
#: The timed line's arrival (s) at the first target, for the ``timed`` start.
TIMED_LEAD_S = 0.6


def settle_time(t: np.ndarray, q: np.ndarray, goal: np.ndarray) -> float:
    """First time in ``t`` (N,) after which every joint of ``q`` (N, 3) stays within
    ``WITHIN_RAD`` of ``goal`` (3,)."""
    out = np.abs(q - goal).max(axis=1) > WITHIN_RAD
    if out[-1]:
        raise RuntimeError("not within 1 deg at the end of the samples")
    last = np.flatnonzero(out)
    return float(t[last[-1] + 1] if len(last) else t[0])


def tracker_step(limits, goal, start: str):
    """The tracker's settle time (s) from the step, its start state (q, qd, qdd) and
    whether the change was deferred; ``start`` "rest", "in motion" or "timed"."""
    tracker = Tracker(OnlineSpline(forward([0, 0, 0]), 0.0, k=2), limits, rate_hz=RATE_HZ)
    at = 0.0
    if start == "in motion":
        tracker.set_target(angles=FIRST_TARGET, at=0.0)
        at = IN_MOTION_S
    elif start == "timed":
        tracker.spline.retarget(forward(FIRST_TARGET[None]), [TIMED_LEAD_S], at=0.0)
        at = IN_MOTION_S
    near = tracker._unwrapped(tracker.spline(np.array([at]))[0], tracker.goal)
    s = tracker.spline.evaluate(np.array([at]), max_order=2)
    qd, qdd = joint_rates(near, s.omega[0], s.alpha[0])
    state = (near, qd, qdd)
    r = tracker.set_target(angles=goal, at=at)
    q, *_ = tracker.joint_motion(tracker.spline, at, r.arrival + 0.2, near)
    first = math.floor((at - tracker.frame_base) * RATE_HZ) + 1  # joint_motion's frames
    t = tracker.frame_base + (first + np.arange(len(q))) / RATE_HZ
    return settle_time(t, q, goal) - at, state, r.at > at, r


def ruckig_step(limits, state, goal):
    """Ruckig's settle time (s) from ``state`` (q, qd, qdd) to ``goal`` at rest."""
    from ruckig import InputParameter, Result, Ruckig, Trajectory

    otg = Ruckig(3)
    inp = InputParameter(3)
    inp.current_position, inp.current_velocity, inp.current_acceleration = (
        list(map(float, x)) for x in state
    )
    inp.target_position = list(map(float, goal))
    inp.target_velocity = [0.0] * 3
    inp.target_acceleration = [0.0] * 3
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = (list(map(float, r)) for r in limits)
    traj = Trajectory(3)
    if otg.calculate(inp, traj) not in (Result.Working, Result.Finished):
        raise RuntimeError("ruckig refused the input")
    t = np.arange(0.0, traj.duration + 0.2, 1.0 / RATE_HZ)
    q = np.array([traj.at_time(float(x))[0] if x < traj.duration else goal for x in t])
    return settle_time(t, q, goal), traj.duration


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--limits",
        default="3,20,200",
        help="speed rad/s, acceleration rad/s^2, jerk rad/s^3 per joint (default 3,20,200)",
    )
    args = parser.parse_args()
    v, a, j = (float(x) for x in args.limits.split(","))
    limits = np.array([[v] * 3, [a] * 3, [j] * 3])
    print(f"load average {os.getloadavg()[0]:.2f} (1 min)")
    print(f"limits per joint: {v:g} rad/s, {a:g} rad/s^2, {j:g} rad/s^3")
    steps = [
        ("pan 5", [5, 0]),
        ("pan 15", [15, 0]),
        ("pan 30", [30, 0]),
        ("pan 60", [60, 0]),
        ("pan 30 + tilt 30", [30, 30]),
        ("pan -30 + tilt 15", [-30, 15]),
    ]
    print(f"{'step (deg)':<20} {'start':<10} {'tracker s':>10} {'ruckig s':>9} {'ratio':>6}  note")
    ratios = {}
    for start in ("rest", "in motion", "timed"):
        for name, (pan, tilt) in steps:
            goal = np.array([D(pan), D(tilt), 0.0])
            t_tr, state, deferred, r = tracker_step(limits, goal, start)
            t_rk, _ = ruckig_step(limits, state, goal)
            ratio = t_tr / t_rk
            ratios.setdefault(start, []).append(ratio)
            asked = 0.0 if start == "rest" else IN_MOTION_S
            note = f"deferred {r.at - asked:.3f} s" if deferred else ""
            print(f"{name:<20} {start:<10} {t_tr:10.3f} {t_rk:9.3f} {ratio:6.3f}  {note}")
    for start, rs in ratios.items():
        print(f"{start}: ratio median {np.median(rs):.3f}, worst {max(rs):.3f} (goal <= 1.3)")
    print(f"load average {os.getloadavg()[0]:.2f} (1 min) at the end")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
