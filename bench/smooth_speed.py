"""SmoothSpline against scipy's RotationSpline: construct + q, omega, alpha at 15,001 samples.

16 random keyframes (seeded), 1,000 samples per segment, two ways of asking:
one ``evaluate(t, max_order=2)``, and ``s(t), s(t, 1), s(t, 2)`` as a scipy user
writes it. scipy does the same work in the same run (interleaved, median of 9).
Targets (issue 10): at least 1x scipy on both patterns on a plain numpy install;
with the fast extra (``TRAJGEN_NUMBA=1``, the compiled kernel) at least 8x on
large evaluations (``--large`` adds 150,001 and 1,500,001 samples, median of 3).
Then construction alone for 16 to 100,000 keyframes (target: 2x at 10,000).

    TRAJGEN_NUMBA=0 python bench/smooth_speed.py
    TRAJGEN_NUMBA=1 python bench/smooth_speed.py --large
"""

import argparse
import os

import numpy as np
from scipy.spatial.transform import Rotation, RotationSpline
from timing import interleaved_medians, random_keyframes

from trajgen import fast
from trajgen.smooth import SmoothSpline


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--large", action="store_true", help="also 150,001 and 1,500,001 samples")
    sizes = (15_001, 150_001, 1_500_001) if parser.parse_args().large else (15_001,)
    for samples in sizes:
        evaluation(samples, repeats=9 if samples < 100_000 else 3)
    construction()


def evaluation(samples: int, repeats: int) -> None:
    """Construct + q, omega, alpha at ``samples`` samples: SmoothSpline against scipy."""
    quats, times = random_keyframes(16)
    t = np.linspace(times[0], times[-1], samples)
    kernel = "numba kernel" if fast.use_compiled(samples) else "numpy"

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
    med = interleaved_medians(contenders, repeats=repeats)
    load_after = os.getloadavg()
    base = med["scipy RotationSpline, s(t), s(t, 1), s(t, 2)"]
    print(
        f"\n{len(t)} samples, 16 random keyframes, construct + q + omega + alpha, "
        f"median of {repeats} (interleaved); evaluation: {kernel}; numpy {np.__version__}"
    )
    print(
        f"machine load (1, 5, 15 min): before {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, "
        f"after {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}; 2 cores\n"
    )
    print("| method | time (ms) | M samples/s | speed vs scipy |")
    print("|---|---|---|---|")
    for name, sec in med.items():
        print(f"| {name} | {sec * 1e3:.2f} | {len(t) / sec / 1e6:.2f} | {base / sec:.2f}x |")


def construction() -> None:
    """Construction alone, SmoothSpline against scipy, 16 to 100,000 keyframes."""
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
