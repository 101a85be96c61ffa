"""SmoothSpline against scipy's RotationSpline: construct + q, omega, alpha at 15,001 samples.

16 random keyframes (seeded), 1,000 samples per segment, two ways of asking:
one ``evaluate(t, max_order=2)``, and ``s(t), s(t, 1), s(t, 2)`` as a scipy user
writes it. scipy does the same work in the same run (interleaved, median of 9).
Target (issue 10): at least 1x scipy on both patterns on a plain numpy install.
Then construction alone for 16 to 10,000 keyframes (no target; for the record).

    python bench/smooth_speed.py
"""

import os

import numpy as np
from scipy.spatial.transform import Rotation, RotationSpline
from timing import interleaved_medians, random_keyframes

from trajgen.smooth import SmoothSpline


def main():
    quats, times = random_keyframes(16)
    t = np.linspace(times[0], times[-1], 15 * 1000 + 1)

    def scipy_spline():
        s = RotationSpline(times, Rotation.from_quat(quats, scalar_first=True))
        return s(t).as_quat(scalar_first=True), s(t, 1), s(t, 2)

    def smooth_evaluate():
        s = SmoothSpline(quats, times).evaluate(t, max_order=2)
        return s.q, s.omega, s.alpha

    def smooth_calls():
        s = SmoothSpline(quats, times)
        return s(t), s(t, 1), s(t, 2)

    contenders = {
        "scipy RotationSpline, s(t), s(t, 1), s(t, 2)": scipy_spline,
        "SmoothSpline, evaluate(t, max_order=2)": smooth_evaluate,
        "SmoothSpline, s(t), s(t, 1), s(t, 2)": smooth_calls,
    }
    load = os.getloadavg()
    med = interleaved_medians(contenders, repeats=9)
    load_after = os.getloadavg()
    base = med["scipy RotationSpline, s(t), s(t, 1), s(t, 2)"]
    print(
        f"{len(t)} samples, 16 random keyframes, construct + q + omega + alpha, "
        f"median of 9 (interleaved); numpy {np.__version__}"
    )
    print(
        f"machine load (1, 5, 15 min): before {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, "
        f"after {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}; 2 cores\n"
    )
    print("| method | time (ms) | M samples/s | speed vs scipy |")
    print("|---|---|---|---|")
    for name, sec in med.items():
        print(f"| {name} | {sec * 1e3:.2f} | {len(t) / sec / 1e6:.2f} | {base / sec:.2f}x |")

    print("\nConstruction alone, random keyframes 1 s apart (median of 3, interleaved):\n")
    print("| keyframes | SmoothSpline (ms) | scipy RotationSpline (ms) | speed vs scipy |")
    print("|---|---|---|---|")
    for n in (16, 1000, 10000, 100000):
        quats, times = random_keyframes(n)
        med = interleaved_medians(
            {
                "smooth": lambda q=quats, t=times: SmoothSpline(q, t),
                "scipy": lambda q=quats, t=times: RotationSpline(
                    t, Rotation.from_quat(q, scalar_first=True)
                ),
            },
            repeats=3,
        )
        ratio = med["scipy"] / med["smooth"]
        print(f"| {n} | {med['smooth'] * 1e3:.1f} | {med['scipy'] * 1e3:.1f} | {ratio:.2f}x |")


if __name__ == "__main__":
    main()
