"""Compute time per frame of the online stream (``stream_frames``), as a distribution.

The built-in example's keyframes (lookaround.toml, 8 s) streamed at 1 kHz and
2 kHz, with the default spline (``SmoothSpline``, evaluated one frame at a time
in floats) and with the file's own spline (``BlendingSpline``, evaluated with
numpy a block ahead; joint angles and rates per frame). Every ``next()`` is
timed on its own, the stream's own compute, not the wait for the period: back to
back by default, or with ``--paced`` one ``next()`` per period, paced as the
Dynamixel streamer paces its frames (``trajgen.drivers.clock.sleep_until``:
sleep, then spin the last half millisecond), so each frame starts with whatever
the wait left in the caches. The peer, in the same run: the same
frames computed the way ``stream_frames`` did before the per-frame path (a block
of 32 frames evaluated, inverted and differentiated with numpy, one block ahead,
in steps spread over the frames of the block before). Budget: 10% of the
period. A periodic stall shows up as a block position whose median is far
above the others.

    python bench/stream_latency.py                   # numpy
    TRAJGEN_NUMBA=1 python bench/stream_latency.py   # with the compiled kernel loaded
    python bench/stream_latency.py --paced           # one frame per period (8 s per row)
"""

import argparse
import gc
import os
import time

import numpy as np

from trajgen import GimbalKinematics, SmoothSpline, fast, load_keyframe_file
from trajgen.drivers.clock import sleep_until
from trajgen.gimbal import joint_rates
from trajgen.keyframes import BUILTIN_EXAMPLE
from trajgen.path import Steps
from trajgen.sampling import sample_times
from trajgen.stream import BLOCK_FRAMES, JointFrame, _evaluation_steps, stream_frames


def timed(frames, period_s: float | None = None) -> np.ndarray:
    """Seconds spent in each next() of an iterator; with ``period_s``, each next() is
    called at the start of its period (waiting until then if it is ahead)."""
    out = []
    it = iter(frames)
    due = time.monotonic()
    while True:
        if period_s is not None:
            sleep_until(due)
            due += period_s
        t0 = time.perf_counter()
        try:
            next(it)
        except StopIteration:
            return np.array(out)
        out.append(time.perf_counter() - t0)


def spread_blocks(spline, rate_hz):
    """The stream before the per-frame path: a block's evaluation, inverse kinematics
    and joint rates with numpy, one block ahead, in steps spread over the frames before."""
    kin, t = GimbalKinematics(), sample_times(spline.t_start, spline.t_end, rate_hz)
    last = [None]

    def block(tb):
        s = yield from _evaluation_steps(spline, tb)
        yield
        q = kin.inverse(s.q, tb, start=last[0])
        last[0] = q[-1]
        yield
        qd, qdd = joint_rates(q, s.omega, s.alpha)
        return list(zip(tb.tolist(), q, qd, qdd, strict=True))

    frames = Steps(block(t[:BLOCK_FRAMES])).finish()
    for a in range(0, len(t), BLOCK_FRAMES):
        b = a + BLOCK_FRAMES
        work = Steps(block(t[b : b + BLOCK_FRAMES])) if b < len(t) else None
        for j, (tj, q, qd, qdd) in enumerate(frames):
            yield JointFrame(a + j, tj, q, qd, qdd)
            if work is not None:
                work.step()
        if work is not None:
            frames = work.finish()


def row(name, dt, period):
    us = dt * 1e6
    by_position = [np.median(us[p::BLOCK_FRAMES]) for p in range(BLOCK_FRAMES)]
    over = np.mean(dt > 0.1 * period) * 100
    return (
        f"| {name} | {len(dt)} | {np.median(us):.1f} | {np.percentile(us, 99):.1f} "
        f"| {np.percentile(us, 99.9):.1f} | {us.max():.0f} | {over:.2f}% "
        f"| {max(by_position):.1f} / {np.median(by_position):.1f} |"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paced", action="store_true", help="one next() per period")
    paced = parser.parse_args().paced
    kf = load_keyframe_file(BUILTIN_EXAMPLE)
    splines = {
        "smooth (default)": SmoothSpline(kf.quats, kf.times),
        "blending (file)": kf.spline(),
    }
    kernel = "numba kernel (loaded)" if fast.use_compiled(1) else "numpy"
    if fast.use_compiled(1):
        splines["blending (file)"].evaluate(kf.times)  # load and compile before timing
    print(
        f"built-in example's keyframes, {kf.times[-1] - kf.times[0]:g} s; blending evaluation: "
        f"{kernel}; load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} (2 cores); "
        f"garbage collector {'on' if gc.isenabled() else 'off'}; "
        f"{'paced: one next() per period' if paced else 'back to back'}"
    )
    print()
    print(
        "| stream | frames | p50 us | p99 us | p99.9 us | max us | frames over 10% of period "
        "| slowest / median block position (median us) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for rate in (1000.0, 2000.0):
        period = 1.0 / rate
        for label, spline in splines.items():
            for name, make in (
                ("stream_frames", lambda s=spline, r=rate: stream_frames(s, r)),
                ("spread numpy blocks (before)", lambda s=spline, r=rate: spread_blocks(s, r)),
            ):
                timed(make())  # warm-up
                title = f"{rate:g} Hz (budget {100 * period * 1e3:.0f} us), {label}: {name}"
                print(row(title, timed(make(), period if paced else None), period), flush=True)
    print()
    print(f"load average after: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}")


if __name__ == "__main__":
    main()
