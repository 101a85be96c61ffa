"""Benchmark 3: construction time against the number of keyframes, against scipy.

Random keyframes (seeded) at 1 s spacing, default options; scipy's
RotationSpline built from the same keyframes in the same run (interleaved,
median). Construction is vectorised over keyframes, so time per keyframe should
stay flat from 1,000 keyframes up (linear growth). Target (issue 10): 10,000
keyframes >= 2x faster than scipy.

    python bench/construction.py
"""

import os

from scipy.spatial.transform import Rotation, RotationSpline
from timing import interleaved_medians, random_keyframes

from trajgen import BlendingSpline


def main():
    print("| keyframes | ours (ms) | per keyframe (us) | scipy (ms) | speed vs scipy | load avg |")
    print("|---|---|---|---|---|---|")
    for n in (10, 100, 1_000, 10_000, 100_000):
        quats, times = random_keyframes(n, seed=2)
        med = interleaved_medians(
            {
                "ours": lambda q=quats, t=times: BlendingSpline(q, t),
                "scipy": lambda q=quats, t=times: RotationSpline(
                    t, Rotation.from_quat(q, scalar_first=True)
                ),
            },
            repeats=5 if n < 100_000 else 3,
        )
        print(
            f"| {n:,} | {med['ours'] * 1e3:.2f} | {med['ours'] / n * 1e6:.1f} "
            f"| {med['scipy'] * 1e3:.2f} | {med['scipy'] / med['ours']:.1f}x "
            f"| {os.getloadavg()[0]:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
