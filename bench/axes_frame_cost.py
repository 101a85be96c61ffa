"""Compute time per frame of the online stream for axis sequences other than ``"zyx"``.

``stream_frames`` serves the default pan-tilt-roll gimbal with float closed forms
(``trajgen.frame_eval.FrameKinematics``); any other axis sequence goes through
``AxesFrameKinematics``, the numpy formulas of ``GimbalKinematics`` on one frame.
This prints the median and 99th percentile of one ``next()`` (the spline, a
``SmoothSpline`` evaluated per frame in floats, plus the joints) for each, the
peer being ``"zyx"`` in the same run, and the machine load. The keyframes are
the same joint angles (within each sequence's range), 8 keyframes over 7 s.

    python bench/axes_frame_cost.py [--rate 1000]
"""

import argparse
import os
import time

import numpy as np

from trajgen import GimbalKinematics, SmoothSpline
from trajgen.stream import stream_frames


def frame_times(axes: str, rate_hz: float) -> np.ndarray:
    """Seconds spent in each next() of the stream of one sequence."""
    kin = GimbalKinematics(axes=axes)
    rng = np.random.default_rng(7)
    angles = rng.uniform(-0.6, 0.6, size=(8, kin.n_joints))
    if kin.sequence.kind == "proper-euler":
        angles[:, 1] += 1.5  # middle angle in (0, pi), away from lock
    spline = SmoothSpline(kin.forward(angles), np.arange(8.0))
    frames = stream_frames(spline, rate_hz, kin)
    out = []
    while True:
        start = time.perf_counter()
        try:
            next(frames)
        except StopIteration:
            break
        out.append(time.perf_counter() - start)
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=1000.0, help="stream rate (Hz)")
    args = parser.parse_args()
    print(f"load average (1, 5, 15 min): {os.getloadavg()}; {args.rate:g} Hz, 7 s of frames")
    print("| axes | frames | median (us) | p99 (us) | median / zyx |")
    print("| --- | --- | --- | --- | --- |")
    peer = None
    for axes in ("zyx", "zy", "yx", "xyz", "zxz"):
        t = frame_times(axes, args.rate) * 1e6
        median = float(np.median(t))
        peer = median if peer is None else peer
        print(
            f"| {axes} | {len(t)} | {median:.1f} | {np.percentile(t, 99):.1f} | "
            f"{median / peer:.2f} |"
        )
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
