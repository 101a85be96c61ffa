"""Benchmark 1: construct + evaluate q, angular velocity and acceleration, against scipy.

16 random keyframes (seeded), 15,001 samples (1,000 per segment), default
options (k = 2, local="auto", boundary="rest"). Two ways of asking, each
against scipy's RotationSpline doing the same work in the same run
(interleaved, median of 9):

- one call, ``s.evaluate(t, max_order=2)``;
- the scipy way, ``s(t), s(t, 1), s(t, 2)``.

Targets (issue 10), numpy only: >= 2x scipy for the first, >= 1.5x for the second.
With numba (``TRAJGEN_NUMBA=1``, the compiled kernel): >= 8x on large evaluations
(``--large`` adds 150,001 and 1,500,001 samples).

    TRAJGEN_NUMBA=0 python bench/spline_speed.py
    TRAJGEN_NUMBA=1 python bench/spline_speed.py --large
"""

import argparse
import os

import numpy as np
from scipy.spatial.transform import Rotation, RotationSpline
from timing import interleaved_medians, random_keyframes

from trajgen import BlendingSpline, fast


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--large", action="store_true", help="also 150,001 and 1,500,001 samples")
    args = parser.parse_args()
    quats, times = random_keyframes(16)
    kernel = "numba kernel" if fast.use_compiled(15001) else "numpy"
    print(f"evaluation: {kernel}; 16 random keyframes; median of interleaved runs")
    print()
    print("| samples | method | scipy (ms) | ours (ms) | M samples/s | speed vs scipy | load avg |")
    print("|---|---|---|---|---|---|---|")
    sizes = (15_001, 150_001, 1_500_001) if args.large else (15_001,)
    for m in sizes:
        t = np.linspace(times[0], times[-1], m)

        def scipy_three(t=t):
            s = RotationSpline(times, Rotation.from_quat(quats, scalar_first=True))
            return s(t).as_quat(scalar_first=True), s(t, 1), s(t, 2)

        def ours_evaluate(t=t):
            s = BlendingSpline(quats, times).evaluate(t, max_order=2)
            return s.q, s.omega, s.alpha

        def ours_three(t=t):
            s = BlendingSpline(quats, times)
            return s(t), s(t, 1), s(t, 2)

        repeats = 9 if m < 1e6 else 3
        med = interleaved_medians(
            {"scipy": scipy_three, "evaluate": ours_evaluate, "three": ours_three}, repeats
        )
        load = os.getloadavg()[0]
        for name, label in (
            ("evaluate", "`evaluate(t, max_order=2)`"),
            ("three", "`s(t), s(t, 1), s(t, 2)`"),
        ):
            print(
                f"| {m:,} | {label} | {med['scipy'] * 1e3:.1f} | {med[name] * 1e3:.1f} "
                f"| {m / med[name] / 1e6:.2f} | {med['scipy'] / med[name]:.2f}x | {load:.2f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
