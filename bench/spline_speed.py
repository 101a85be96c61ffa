"""Benchmark 1: construct + evaluate q, angular velocity and acceleration at 15,001 samples.

16 random keyframes (seeded), 1,000 samples per segment, against scipy's
RotationSpline doing the same work in the same run (interleaved, median of 9).
Target in the issue: at least 3x scipy's samples per second.

    python bench/spline_speed.py
"""

import numpy as np
from scipy.spatial.transform import Rotation, RotationSpline
from timing import interleaved_medians, random_keyframes

from trajgen import BlendingSpline


def main():
    quats, times = random_keyframes(16)
    t = np.linspace(times[0], times[-1], 15 * 1000 + 1)

    def scipy_spline():
        s = RotationSpline(times, Rotation.from_quat(quats, scalar_first=True))
        return s(t).as_quat(scalar_first=True), s(t, 1), s(t, 2)

    def ours(**options):
        def run():
            s = BlendingSpline(quats, times, k=2, **options).evaluate(t, max_order=2)
            return s.q, s.omega, s.alpha

        return run

    contenders = {
        "scipy RotationSpline": scipy_spline,
        "BlendingSpline k=2 local=auto (default)": ours(),
        "BlendingSpline k=2 local=circle": ours(local="circle"),
        "BlendingSpline k=2 local=parabola": ours(local="parabola"),
    }
    med = interleaved_medians(contenders, repeats=9)
    base = med["scipy RotationSpline"]
    print(f"{len(t)} samples, 16 random keyframes, q + omega + alpha, median of 9 (interleaved)")
    print("| method | time (ms) | M samples/s | speed vs scipy |")
    print("|---|---|---|---|")
    for name, sec in med.items():
        print(f"| {name} | {sec * 1e3:.1f} | {len(t) / sec / 1e6:.2f} | {base / sec:.2f}x |")


if __name__ == "__main__":
    main()
