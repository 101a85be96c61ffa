"""What changing the plan while moving costs: OnlineSpline changes, frames, latency, peaks.

1. Cost of one change (extend at a kept keyframe, mid-motion retarget, from
   rest) against the 1 ms period of a 1 kHz stream and against building the
   offline BlendingSpline through the same keyframes (the peer), same run.
2. Cost of one online frame block against the same block of a BlendingSpline.
3. A 1 kHz stream of ``stream_frames(OnlineSpline)`` paced on the monotonic
   clock, with a second thread changing the plan every 0.3-1 s at
   ``at = committed + margin``: latency from the change request to the first
   frame that reflects it, and frame lateness, against the same stream without
   changes (peer).
4. Peaks after mid-motion retargets by lead time, relative to the old plan's
   (the lead-time table of the design notes, measured again).

Run: .venv/bin/python bench/online_cost.py [--seconds 6]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import threading
import time

import numpy as np

from trajgen import fast
from trajgen import quat as Q
from trajgen.drivers.clock import sleep_until
from trajgen.online import ChangeTooLate, OnlineSpline
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


def change_costs(rng, n):
    rows = []
    for kind in ("extend at a kept keyframe", "retarget mid-motion", "retarget from rest"):
        cost, peer = [], []
        for _ in range(n):
            s, at = moving_spline(rng)
            q = random_quats(rng, 2)
            if kind.startswith("extend"):
                at = float(s.times[1]) - 0.05
                t = s.t_end + np.array([0.5, 1.0])
                method = s.extend
            elif kind.endswith("rest"):
                at = s.t_end + 0.5
                t = at + np.array([0.5, 1.0])
                method = s.retarget
            else:
                t = at + np.array([0.5, 1.0])
                method = s.retarget
            keys_q, keys_t = np.vstack([s(at), q]), np.r_[at, t]
            start = time.perf_counter()
            method(q, t, at=at)
            cost.append(time.perf_counter() - start)
            start = time.perf_counter()
            BlendingSpline(keys_q, keys_t)
            peer.append(time.perf_counter() - start)
        rows.append((kind, cost, peer))
    print("## 1. Cost of one change (k = 2)\n")
    print("| change | cost ms min / p50 / p90 / max | peer: BlendingSpline build, ms | p50 ratio |")
    print("|---|---|---|---|")
    for kind, cost, peer in rows:
        print(f"| {kind} | {ms(cost)} | {ms(peer)} | {np.median(cost) / np.median(peer):.1f}x |")
    worst = max(np.median(c) for _, c, _ in rows)
    print(
        f"\nWorst median change: {1e3 * worst:.2f} ms = {worst / 1e-3:.1f} periods at 1 kHz: "
        "changes are built off the streaming thread and swapped in at a frame boundary.\n"
    )


def frame_costs(rng, n):
    s, _ = moving_spline(rng)
    offline = BlendingSpline(s._plan.pieces[-1].spline.quats, s._plan.pieces[-1].spline.times)
    print("## 2. Evaluating frames (orientation, rate, acceleration)\n")
    print("| frames per call | OnlineSpline ms | peer: BlendingSpline ms | ratio |")
    print("|---|---|---|---|")
    for m in (1, 16):
        t = np.linspace(offline.t_start + 0.1, offline.t_end - 0.1, m)
        times = []
        for path in (s, offline):
            path.evaluate(t)
            start = time.perf_counter()
            for _ in range(n):
                path.evaluate(t, max_order=2)
            times.append((time.perf_counter() - start) / n)
        print(f"| {m} | {1e3 * times[0]:.3f} | {1e3 * times[1]:.3f} | {times[0] / times[1]:.2f}x |")
    print()


def paced_stream(seconds, rate_hz, changes, rng, margin_s):
    """Stream for ``seconds`` at ``rate_hz``; return lateness (s) per frame and latencies."""
    s = OnlineSpline([1.0, 0, 0, 0])
    s.extend(random_quats(rng, 1), [0.5], at=0.0)
    frames = stream_frames(s, rate_hz)
    lateness, latency, pending = [], [], []
    stop = threading.Event()
    lock = threading.Lock()

    def changer():
        while not stop.wait(rng.uniform(0.3, 1.0)):
            asked = time.perf_counter()
            q = random_quats(rng, 1, 30.0)
            while True:
                at = s.committed + margin_s
                try:
                    s.retarget(q, [at + 0.6], at=at)
                    break
                except ChangeTooLate:
                    continue
            with lock:
                pending.append((asked, at))

    thread = threading.Thread(target=changer, daemon=True)
    if changes:
        thread.start()
    start = time.monotonic() + 0.01
    for frame in frames:
        deadline = start + frame.t
        sleep_until(deadline)
        lateness.append(time.monotonic() - deadline)
        with lock:
            seen = [p for p in pending if frame.t > p[1]]
            latency += [time.perf_counter() - asked for asked, _ in seen]
            pending[:] = [p for p in pending if p not in seen]
        if frame.t >= seconds:
            break
    stop.set()
    return np.array(lateness), np.array(latency)


def streaming(seconds, rng, margin_s):
    print(f"## 3. A 1 kHz stream with changes every 0.3-1 s from another thread ({seconds:g} s)\n")
    print(f"Change at `at = committed + {1e3 * margin_s:g} ms`; latency: request to first frame.\n")
    print("| run | frames | lateness ms p50 / p99 / max | late > 1 period | latency ms |")
    print("|---|---|---|---|---|")
    default = sys.getswitchinterval()
    runs = (
        ("peer: no changes", False, default),
        (f"changes, GIL switch interval {1e3 * default:g} ms", True, default),
        ("changes, GIL switch interval 0.5 ms", True, 5e-4),
    )
    for label, changes, switch in runs:
        sys.setswitchinterval(switch)
        try:
            late, lat = paced_stream(seconds, 1000.0, changes, rng, margin_s)
        finally:
            sys.setswitchinterval(default)
        latency = f"{ms(lat)} (n = {len(lat)})" if len(lat) else "-"
        tail = " / ".join(f"{1e3 * v:.2f}" for v in np.percentile(late, [50, 99, 100]))
        print(f"| {label} | {len(late)} | {tail} | {int((late > 1e-3).sum())} | {latency} |")
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


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0, help="length of each paced stream")
    parser.add_argument("--repeats", type=int, default=40, help="random cases per figure")
    args = parser.parse_args()
    print("# OnlineSpline: cost of a change, frames, latency, peaks\n")
    cpu = platform.processor() or platform.machine()
    print(f"{cpu}, {os.cpu_count()} cores, numba kernel for blended segments: {fast.ENABLED}")
    print(f"load average before: {os.getloadavg()}\n")
    # One seed per section: the paced stream draws on another thread at its own pace.
    change_costs(np.random.default_rng(11), args.repeats)
    frame_costs(np.random.default_rng(12), 50)
    streaming(args.seconds, np.random.default_rng(13), margin_s=0.05)
    lead_peaks(np.random.default_rng(14), 4 * args.repeats)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
