"""What an untimed target costs: CPU per ``Tracker.set_target``, against a timed line.

A 30 Hz vision loop gives the tracker 33 ms per target at most (and the stream
thread that runs its steps needs most of that for itself). This bench feeds a
``Tracker`` (per-joint limits 3 rad/s, 20 rad/s^2, 200 rad/s^3, k = 2, 1 kHz
frame grid) seeded random targets in two regimes:

- ``stream``: a target every 1/30 s, each replacing the last in mid-motion (the
  vision-loop case: the path must continue from the old one's rates);
- ``from rest``: a target every 1.5 s, each after the last has arrived.

and prints the CPU time (``time.process_time``) per target, p50 / p99 / max, the
longest single step of ``Tracker.set_target_steps`` (``trajgen follow`` runs one
step between two frames of its stream, so a step longer than a frame period
would make a frame late), the steps per target, how often the change was
deferred (the motion in progress could not keep the limits from ``at``) and the
arrival leads. The peer, measured in the same run on the same plans, is the
timed-keyframe path of ``trajgen follow``: one ``OnlineSpline.prepare`` of a
retarget 0.5 s ahead and the joint-limit / lock-margin check ``Follower`` makes
on its frames (``GimbalKinematics.inverse`` of the new path at 1 kHz). Load
average printed beside the figures.

``--envelope`` adds the default gimbal's torque-speed envelope check
(``trajgen.sim.check.envelope_check``: the numpy inverse dynamics of every frame of
the new motion, MuJoCo's on the frames it cannot decide), as ``trajgen follow``
passes it.

``--realtime SECONDS`` also streams ``trajgen follow``'s ``Follower`` at 1 kHz on
the monotonic clock, from a moving plan: with a second thread feeding it an untimed
target every 1/30 s (as the lines of a vision loop); with that thread feeding lines
within the dead band (the reading thread's own cost); and without (the peer, the same
plan streamed unchanged); ``ROUNDS`` runs of each alternated over SECONDS. It prints
each frame's lateness (how long after its deadline it was ready), the frames more
than a period late, the streaming thread's CPU time per frame (``time.thread_time``:
the frame and the changes' steps before it, which the host's other load inflates
much less), and the targets' change costs and longest steps (wall time, as
``trajgen follow`` reports them).

Run: .venv/bin/python bench/tracker_cost.py [--targets 150] [--seed 1] [--envelope]
     [--realtime 10]
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import threading
import time

import numpy as np

from trajgen.drivers.clock import sleep_until
from trajgen.follower import Follower
from trajgen.gimbal import GimbalKinematics, forward
from trajgen.online import OnlineSpline
from trajgen.path import sample_times
from trajgen.tracker import Tracker

LIMITS = np.array([[3.0] * 3, [20.0] * 3, [200.0] * 3])  # rad/s, rad/s^2, rad/s^3
RATE_HZ = 1000.0


def stepped(steps):
    """Run a generator of steps to its end: its value, and each step's CPU time (s)."""
    times = []
    while True:
        c0 = time.process_time()
        try:
            next(steps)
        except StopIteration as stop:
            times.append(time.process_time() - c0)
            return stop.value, times
        times.append(time.process_time() - c0)


def timed_peer(spline, goal, at, kinematics):
    """The timed-line change ``follow`` makes: a retarget 0.5 s ahead, checked on frames."""
    change = spline.prepare("retarget", forward(goal[None]), [at + 0.5], at=at)
    t = sample_times(at, change.path.t_end, RATE_HZ)[1:]
    kinematics.inverse(change.path.evaluate(t, max_order=0).q, t)


def run(period_s: float, n: int, seed: int, envelope=None) -> dict:
    rng = np.random.default_rng(seed)
    tracker = Tracker(
        OnlineSpline(forward([0, 0, 0]), 0.0, k=2), LIMITS, rate_hz=RATE_HZ, envelope=envelope
    )
    kinematics = GimbalKinematics()
    cost, peer, longest, steps, deferred, leads = [], [], [], [], 0, []
    t = 0.0
    for _ in range(n):
        goal = np.array([*rng.uniform(-0.6, 0.6, 2), 0.0])
        c0 = time.process_time()
        timed_peer(tracker.spline, goal, t, kinematics)
        c1 = time.process_time()
        r, times = stepped(tracker.set_target_steps(angles=goal, at=t))
        c2 = time.process_time()
        peer.append(c1 - c0)
        cost.append(c2 - c1)
        longest.append(max(times))
        steps.append(len(times))
        deferred += r.at > t
        leads.append(r.arrival - r.at)
        assert (r.peaks <= LIMITS).all()
        t += period_s
    return {
        "cost": np.array(cost),
        "peer": np.array(peer),
        "longest": np.array(longest),
        "steps": np.array(steps),
        "deferred": deferred,
        "leads": np.array(leads),
    }


#: The runs of ``--realtime``: what the second thread feeds the stream every 1/30 s.
KINDS = {
    "peer: no lines (no second thread)": None,
    "the same target, within the dead band": "still",
    "untimed targets at 30 Hz": "targets",
}


def paced(seconds: float, kind, seed: int, envelope=None):
    """``Follower.frames()`` at 1 kHz on the monotonic clock for ``seconds``, from a plan
    through random keyframes every 0.6 s; a second thread feeds an untimed line every
    1/30 s (``kind`` ``"targets"``: random pan and tilt; ``"still"``: the plan's end,
    within the dead band, so that only the lines' parsing and a dead-band check remain;
    None: no thread). Returns each frame's lateness (s), the streaming thread's CPU
    time (s) for it (the frame and the changes' steps before it) and the follower."""
    rng = np.random.default_rng(seed)
    spline = OnlineSpline(forward([0, 0, 0]), 0.0, k=2)
    times = np.arange(0.6, seconds + 1.0, 0.6)
    angles = np.column_stack([rng.uniform(-0.6, 0.6, (len(times), 2)), np.zeros(len(times))])
    spline.extend(forward(angles), times, at=0.0)
    follower = Follower(spline, RATE_HZ, limits=LIMITS, envelope=envelope)
    stop = threading.Event()

    def feeder():
        while not stop.wait(1 / 30):
            pan, tilt = np.degrees(
                rng.uniform(-0.6, 0.6, 2) if kind == "targets" else angles[-1, :2]
            )
            try:
                follower.feed(json.dumps({"pan": pan, "tilt": tilt}))
            except ValueError:  # the stream ended before its change was made
                return

    thread = threading.Thread(target=feeder, daemon=True)
    if kind is not None:
        thread.start()
    lateness, cpu = [], []
    frames = follower.frames()
    start = time.monotonic() + 0.01
    while True:
        c0 = time.thread_time()
        frame = next(frames)  # the frame, and the steps of changes before it
        cpu.append(time.thread_time() - c0)
        deadline = start + frame.t
        sleep_until(deadline)
        lateness.append(time.monotonic() - deadline)
        if frame.t >= seconds:
            break
    frames.close()
    stop.set()
    if kind is not None:
        thread.join()
    return np.array(lateness), np.array(cpu), follower


#: Runs of each kind in ``--realtime``, alternated, so that all see the same spells of
#: the host's load.
ROUNDS = 3


def realtime(seconds: float, seed: int, envelope=None) -> None:
    each = seconds / ROUNDS
    print(f"\nstreaming at 1 kHz in real time, {ROUNDS} x {each:.3g} s per kind, alternated")
    runs = {name: [] for name in KINDS}
    for r in range(ROUNDS):
        for name, kind in KINDS.items():
            late, cpu, follower = paced(each, kind, seed + r, envelope)
            runs[name].append((late, cpu, follower.change_costs_s, follower.change_steps_s))
            del follower  # its frames: no run's garbage collections scan an earlier run's
            gc.collect()
    for name, parts in runs.items():
        late = np.concatenate([x[0] for x in parts])
        cpu = np.concatenate([x[1] for x in parts])
        costs = [c for x in parts for c in x[2]]
        steps = [s for x in parts for s in x[3]]
        over = int((late > 1.0 / RATE_HZ).sum())
        print(f"  {name}: {len(late)} frames, {over} more than 1 ms late")
        print(f"    lateness                {ms(late)}")
        print(f"    thread CPU per frame    {ms(cpu)}")
        if costs:
            print(f"    change cost (wall)      {ms(np.array(costs))}, n = {len(costs)}")
            print(f"    longest step (wall)     {ms(np.array(steps))}")
    print(f"  load average {os.getloadavg()[0]:.2f} (1 min)")


def ms(x) -> str:
    p50, p99, top = 1e3 * np.median(x), 1e3 * np.percentile(x, 99), 1e3 * x.max()
    return f"p50 {p50:6.2f}  p99 {p99:6.2f}  max {top:6.2f} ms"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=150, help="targets per regime")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--envelope",
        action="store_true",
        help="also check the default gimbal's torque-speed envelope (MuJoCo), as follow does",
    )
    parser.add_argument(
        "--realtime",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="also stream at 1 kHz in real time for SECONDS, with targets and without",
    )
    args = parser.parse_args()
    envelope = None
    if args.envelope:
        from trajgen.sim.check import envelope_check
        from trajgen.sim.model import GimbalConfig

        envelope = envelope_check(GimbalConfig())
        print("with the default gimbal's torque-speed envelope (trajgen.sim.check)")
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} (1, 5 min)")
    for name, period in (("stream (30 Hz, in motion)", 1 / 30), ("from rest (1.5 s)", 1.5)):
        out = run(period, args.targets, args.seed, envelope)
        ratio = np.median(out["cost"]) / np.median(out["peer"])
        print(f"\n{name}, {args.targets} targets")
        print(f"  tracker set_target CPU  {ms(out['cost'])}")
        print(f"  peer: timed retarget    {ms(out['peer'])}")
        print(f"  ratio (p50 / p50)       {ratio:.2f}x the timed line")
        print(f"  longest step            {ms(out['longest'])}")
        print(
            f"  steps per target        median {np.median(out['steps']):.0f}, "
            f"max {out['steps'].max()}; deferred {out['deferred']} of {args.targets}; "
            f"lead median {np.median(out['leads']):.3f} s"
        )
        print(f"  load average {os.getloadavg()[0]:.2f} (1 min)")
    if args.realtime > 0:
        realtime(args.realtime, args.seed, envelope)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
