"""What changing the plan while moving costs: OnlineSpline changes, frames, latency, peaks.

1. Cost of one change (mid-motion retarget, in a blended segment and inside a
   splice, from rest, extend at a kept keyframe; one new keyframe as ``follow``
   sends, and two) against the 1 ms period of a 1 kHz stream and against
   building a BlendingSpline through (q(at), the new keyframes) (the peer), same
   run; and the joint-limit / lock-guard check ``follow`` adds.
2. Cost per stream frame of an OnlineSpline (blended and spliced segments)
   against the offline BlendingSpline's stream (peer).
3. A 1 kHz stream of ``trajgen follow``'s frames (its ``Follower``) paced on the
   monotonic clock, a second thread feeding it a keyframe line every 0.3-1 s
   (a retarget 0.65 s ahead, checked against the joint limits as ``follow``
   does): latency from the line to the first frame that reflects it, the cost
   of each change, and frame lateness against the same stream of the same
   moving plan without the lines (peer); with numpy evaluation, and with the
   compiled kernel loaded as ``trajgen follow`` does where numba is installed.
4. Peaks after mid-motion retargets by lead time, relative to the old plan's
   (the lead-time table of the design notes, measured again).

Run: .venv/bin/python bench/online_cost.py [--seconds 6] [--repeats 40] [--sections 1234]
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import threading
import time

import numpy as np

from trajgen import fast
from trajgen import follower as follow
from trajgen import quat as Q
from trajgen.drivers.clock import sleep_until
from trajgen.follower import CHECK_STEP_FRAMES as CHECK_FRAMES
from trajgen.follower import Follower, load_compiled_kernel
from trajgen.online import OnlineSpline
from trajgen.spline import BlendingSpline
from trajgen.stream import stream_frames

DEG = np.pi / 180


def random_quats(rng, n, spread_deg=40.0):
    return Q.from_pan_tilt_roll(*(rng.uniform(-spread_deg, spread_deg, (3, n)) * DEG))


def moving_spline(rng, k=2):
    """An OnlineSpline mid-way through a 4-keyframe plan, and a time in its middle."""
    s = OnlineSpline(random_quats(rng, 1)[0], 0.0, k=k)
    s.extend(random_quats(rng, 4), np.cumsum(rng.uniform(0.5, 1.0, 4)), at=0.0)
    return s, float(rng.uniform(0.3, s.times[2]))


def ms(x):
    """min / p50 / p90 / max in ms (the min is the closest to an idle machine)."""
    q = [np.min(x), np.median(x), np.percentile(x, 90), np.max(x)]
    return " / ".join(f"{1e3 * v:.2f}" for v in q)


def one_change(rng, kind, n_keys):
    """A spline, the change to make (method, keyframes, times, at) and the peer's keyframes."""
    s, at = moving_spline(rng)
    q = random_quats(rng, n_keys)
    lead = 0.5 + 0.5 * np.arange(n_keys)
    if kind == "extend at a kept keyframe":
        at = float(s.times[1]) - 0.05
        method, t = s.extend, s.t_end + lead
    elif kind == "retarget from rest":
        at = s.t_end + 0.5
        method, t = s.retarget, at + lead
    else:
        if kind == "retarget inside a splice":  # the usual case in `follow`: a change
            s.retarget(random_quats(rng, 1), [at + 0.6], at=at)  # before the last one ended
            at += float(rng.uniform(0.05, 0.5))
        method, t = s.retarget, at + lead
    return s, (method, q, t, at), (np.vstack([s(at), q]), np.r_[at, t])


CHANGES = (
    ("retarget mid-motion", 1),
    ("retarget inside a splice", 1),
    ("retarget from rest", 1),
    ("extend at a kept keyframe", 1),
    ("retarget mid-motion", 2),
    ("retarget from rest", 2),
)


def timed_steps(steps) -> list[float]:
    """Run a generator of steps to its end; the time (s) of each ``next()``."""
    spans = []
    while True:
        start = time.perf_counter()
        try:
            next(steps)
        except StopIteration:
            spans.append(time.perf_counter() - start)
            return spans
        spans.append(time.perf_counter() - start)


def change_costs(rng, n, label):
    rows = []
    for kind, n_keys in CHANGES:
        cost, longest, peer = [], [], []
        for _ in range(n):
            twin = copy.deepcopy(rng)
            s, (method, q, t, at), keys = one_change(rng, kind, n_keys)
            start = time.perf_counter()
            method(q, t, at=at)
            cost.append(time.perf_counter() - start)
            # The same change in steps (prepare_steps, then apply), as `follow` makes it.
            s, (method, q, t, at), _ = one_change(twin, kind, n_keys)
            spans = timed_steps(s.prepare_steps(method.__name__, q, t, at=at))
            longest.append(max(spans))
            start = time.perf_counter()
            BlendingSpline(*keys)
            peer.append(time.perf_counter() - start)
        name = f"{kind}, {n_keys} keyframe{'s' if n_keys > 1 else ''}"
        rows.append((name, cost, longest, peer))
    # What `trajgen follow` adds: the joint-limit and lock-guard check of the new path.
    check, check_step = [], []
    for _ in range(n):
        s, (_, q, t, at), _ = one_change(rng, "retarget inside a splice", 1)
        follower = Follower(s, 1000.0)
        follower._last_q = np.zeros(3)
        s.retarget(q, t, at=at)
        _, path = s.snapshot()
        spans = timed_steps(follower._check_steps(path, at))
        check.append(sum(spans))
        check_step.append(max(spans))
    print(f"## 1. Cost of one change (k = 2), {label}\n")
    print(f"load average: {os.getloadavg()}\n")
    print(
        "| change | cost ms min / p50 / p90 / max | longest step of `prepare_steps`, ms "
        "| peer: BlendingSpline build, ms | p50 ratio |"
    )
    print("|---|---|---|---|---|")
    for kind, cost, longest, peer in rows:
        ratio = np.median(cost) / np.median(peer)
        print(f"| {kind} | {ms(cost)} | {ms(longest)} | {ms(peer)} | {ratio:.2f}x |")
    print(
        f"| `follow`'s check of a new path (joint limits, lock guard), {CHECK_FRAMES} frames "
        f"per two steps | {ms(check)} | {ms(check_step)} | | |"
    )
    worst = max(np.median(c) for _, c, _, _ in rows)
    step = max(np.median(x) for _, _, x, _ in rows)
    print(
        f"\nWorst median change: {1e3 * worst:.2f} ms, {worst / 1e-3:.2f} periods at 1 kHz; "
        f"worst median longest step: {1e3 * step:.2f} ms.\n"
    )


def frame_costs(rng, n):
    """Per-frame cost of ``stream_frames`` on an OnlineSpline, back to back."""
    s, _ = moving_spline(rng)
    offline = BlendingSpline(s._plan.pieces[-1].spline.quats, s._plan.pieces[-1].spline.times)
    spliced = OnlineSpline(random_quats(rng, 1)[0])  # what `follow` streams after a line
    spliced.retarget(random_quats(rng, 1), [offline.t_end], at=0.0)
    print("## 2. Stream frames (joint angles, rates, accelerations), back to back\n")
    print(f"{n} frames at 1 kHz per row; load average: {os.getloadavg()}\n")
    print("| stream | us per frame p50 / p99 / max |")
    print("|---|---|")
    rows = (
        ("OnlineSpline, blended segments (numpy, 16 frames at a time)", s),
        ("OnlineSpline, a spliced segment (Python floats)", spliced),
        ("peer: the same BlendingSpline offline (numpy, blocks spread in steps)", offline),
    )
    for name, path in rows:
        frames = stream_frames(path, 1000.0)
        cost = []
        for _ in range(n):
            start = time.perf_counter()
            next(frames)
            cost.append(time.perf_counter() - start)
        tail = " / ".join(f"{1e6 * v:.1f}" for v in np.percentile(cost, [50, 99, 100]))
        print(f"| {name} | {tail} |")
    print()


#: Frames after a line arrives (s) that its change may delay: building and checking it,
#: and the stream evaluating its block again.
WINDOW_S = 0.01


def paced_stream(seconds, rate_hz, changes, rng):
    """Stream ``trajgen follow``'s frames for ``seconds`` at ``rate_hz`` on the monotonic
    clock, from a plan that moves all the way, a second thread feeding it a line every
    0.3-1 s (``changes``) or only noting when it would have (the peer); returns the
    deadlines and lateness (s) per frame, the times the lines were due, and the
    follower (its latencies and change costs)."""
    # The same moving plan in every run (keyframes every 0.6 s to the end): the peer
    # streams as much motion as the runs whose lines change it.
    keys = np.random.default_rng(3)
    s = OnlineSpline([1.0, 0, 0, 0])
    times = np.arange(0.6, seconds + 1.0, 0.6)
    s.extend(random_quats(keys, len(times), 30.0), times, at=0.0)
    follower = Follower(s, rate_hz)
    frames = follower.frames()
    deadlines, lateness, asked = [], [], []
    stop = threading.Event()

    def changer():
        while not stop.wait(rng.uniform(0.3, 1.0)):
            pan, tilt = rng.uniform(-30.0, 30.0, 2)
            asked.append(time.monotonic())
            if changes:
                follower.feed(json.dumps({"in": 0.65, "pan": pan, "tilt": tilt}))

    thread = threading.Thread(target=changer, daemon=True)
    thread.start()
    start = time.monotonic() + 0.01
    for frame in frames:
        deadline = start + frame.t
        sleep_until(deadline)
        deadlines.append(deadline)
        lateness.append(time.monotonic() - deadline)
        if frame.t >= seconds:
            break
    stop.set()
    thread.join()
    return np.array(deadlines), np.array(lateness), np.array(asked), follower


def streaming(seconds, rng, label):
    print(f"## 3. `trajgen follow` at 1 kHz, a line every 0.3-1 s from another thread, {label}\n")
    print(f"{seconds:g} s per run; load average: {os.getloadavg()}\n")
    print(
        "Late: more than one period (1 ms) late; *near a line*: due within "
        f"{1e3 * WINDOW_S:g} ms after a line arrived (for the peer, after the time a "
        "line would have arrived), which is what a change can delay; the rest is the "
        "machine.\n"
    )
    print(
        "| run | frames | lateness ms p50 / p99 / max | late | late near a line "
        "| change cost ms (all steps) | longest step ms | latency ms |"
    )
    print("|---|---|---|---|---|---|---|---|")
    runs = (
        ("peer: no changes", False, None),
        (f"changes (switch interval {1e3 * follow.SWITCH_INTERVAL_S:g} ms)", True, None),
        ("changes, Python's default switch interval 5 ms", True, 5e-3),
    )
    default = follow.SWITCH_INTERVAL_S
    for name, changes, switch in runs:
        follow.SWITCH_INTERVAL_S = default if switch is None else switch
        try:
            due, late, asked, follower = paced_stream(seconds, 1000.0, changes, rng)
        finally:
            follow.SWITCH_INTERVAL_S = default
        near = np.zeros(len(due), bool)
        for a in asked:
            near |= (due >= a) & (due < a + WINDOW_S)
        cost, lat = follower.change_costs_s, follower.latencies_s
        step = ms(follower.change_steps_s) if cost else "-"
        cost = f"{ms(cost)} (n = {len(cost)})" if cost else "-"
        lat = ms(lat) if lat else "-"
        tail = " / ".join(f"{1e3 * v:.2f}" for v in np.percentile(late, [50, 99, 100]))
        late_near = f"{int((late[near] > 1e-3).sum())} of {int(near.sum())}"
        print(
            f"| {name} | {len(late)} | {tail} | {int((late > 1e-3).sum())} | {late_near} "
            f"| {cost} | {step} | {lat} |"
        )
    print()


def lead_peaks(rng, n):
    print("## 4. Peaks after a mid-motion retarget, relative to the old plan (k = 2)\n")
    print("| lead s | angular velocity p50 [p90] | acceleration | jerk |")
    print("|---|---|---|---|")
    for lead in (0.2, 0.3, 0.5, 1.0):
        ratios = []
        for _ in range(n):
            s, at = moving_spline(rng)
            old_t = np.linspace(s.t_start, s.t_end, 400)
            old = [np.linalg.norm(s(old_t, o), axis=-1).max() for o in (1, 2, 3)]
            s.retarget(random_quats(rng, 2), at + lead + np.array([0.0, 0.7]), at=at)
            new_t = np.linspace(at, s.t_end, 400)
            new = [np.linalg.norm(s(new_t, o), axis=-1).max() for o in (1, 2, 3)]
            ratios.append(np.array(new) / np.array(old))
        r = np.array(ratios)
        cells = [f"{np.median(r[:, i]):.1f} [{np.percentile(r[:, i], 90):.1f}]" for i in range(3)]
        print(f"| {lead} | " + " | ".join(cells) + " |")
    print()


def load_kernel() -> bool:
    """Load the compiled kernel (as `trajgen follow` does where numba is installed)."""
    start = time.perf_counter()
    if not load_compiled_kernel():
        return False
    print(f"(compiled kernel loaded in {time.perf_counter() - start:.1f} s)\n")
    return True


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0, help="length of each paced stream")
    parser.add_argument("--repeats", type=int, default=40, help="random cases per figure")
    parser.add_argument(
        "--sections", default="1234", help="which sections to run, e.g. 1 (default: all)"
    )
    args = parser.parse_args()
    run = set(args.sections)
    print("# OnlineSpline: cost of a change, frames, latency, peaks\n")
    cpu = platform.processor() or platform.machine()
    print(f"{cpu}, {os.cpu_count()} cores, numba installed: {fast.ENABLED}")
    print(f"load average before: {os.getloadavg()}\n")
    # One seed per section: the paced stream draws on another thread at its own pace.
    for label in ("numpy evaluation", "compiled kernel loaded"):
        if label.startswith("compiled") and not ({"1", "3"} & run and load_kernel()):
            break
        if "1" in run:
            change_costs(np.random.default_rng(11), args.repeats, label)
        if "3" in run:
            streaming(args.seconds, np.random.default_rng(13), label)
    if "2" in run:
        frame_costs(np.random.default_rng(12), 1500)
    if "4" in run:
        lead_peaks(np.random.default_rng(14), 4 * args.repeats)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
