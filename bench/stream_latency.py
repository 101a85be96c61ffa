"""Compute time per frame of the online stream (``stream_frames``), as a distribution.

The built-in example (lookaround.toml) streamed at 1 kHz and 2 kHz; every
``next()`` is timed on its own (no sleeping between frames, so the figures are
the stream's own compute, not the wait for the period). Against the same
frames computed the way the stream used to, a whole block (32 frames) in the
frame that needs it, in the same run. Budget: 10% of the period. A periodic
stall shows up as a block position whose median is far above the others.

    python bench/stream_latency.py            # numpy
    TRAJGEN_NUMBA=1 python bench/stream_latency.py   # with the compiled kernel loaded
"""

import os
import time

import numpy as np

from trajgen import GimbalKinematics, fast, load_keyframe_file
from trajgen.gimbal import joint_rates
from trajgen.keyframes import BUILTIN_EXAMPLE
from trajgen.sampling import sample_times
from trajgen.stream import BLOCK_FRAMES, stream_frames


def timed(frames) -> np.ndarray:
    """Seconds spent in each next() of an iterator."""
    out = []
    it = iter(frames)
    while True:
        t0 = time.perf_counter()
        try:
            next(it)
        except StopIteration:
            return np.array(out)
        out.append(time.perf_counter() - t0)


def whole_blocks(spline, rate_hz):
    """The previous design: a block evaluated, inverted and differentiated when first needed."""
    kin, t, previous = GimbalKinematics(), sample_times(spline.t_start, spline.t_end, rate_hz), None
    for a in range(0, len(t), BLOCK_FRAMES):
        tb = t[a : a + BLOCK_FRAMES]
        s = spline.evaluate(tb, max_order=2)
        q = kin.inverse(s.q, tb, start=previous)
        qd, qdd = joint_rates(q, s.omega, s.alpha)
        previous = q[-1]
        yield from zip(tb, q, qd, qdd, strict=True)


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
    spline = load_keyframe_file(BUILTIN_EXAMPLE).spline()
    kernel = "numba kernel (loaded)" if fast.use_compiled(1) else "numpy"
    if fast.use_compiled(1):
        spline.evaluate(spline.times)  # load and compile before timing
    print(
        f"built-in example, {spline.t_end - spline.t_start:g} s; evaluation: {kernel}; "
        f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} (2 cores)"
    )
    print()
    print(
        "| stream | frames | p50 us | p99 us | p99.9 us | max us | frames over 10% of period "
        "| slowest / median block position (median us) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for rate in (1000.0, 2000.0):
        period = 1.0 / rate
        for name, make in (
            ("stream_frames", lambda r=rate: stream_frames(spline, r)),
            ("whole block in one frame (before)", lambda r=rate: whole_blocks(spline, r)),
        ):
            timed(make())  # warm-up
            label = f"{rate:g} Hz (budget {100 * period * 1e3:.0f} us): {name}"
            print(row(label, timed(make()), period))


if __name__ == "__main__":
    main()
