"""Benchmark 2: the paper's Table 3. Time per curve for 16 random orientations with m
in-betweens per segment (m = 8, 16, 32, 64), orientation only, construction included.

Kim & Nam measured (SGI Indigo XS24, microseconds): circular blending (k = 1) at
0.75-0.81x squad and 0.45-0.50x Shoemake's Bezier. We report our ratios beside theirs.

    python bench/paper_table3.py
"""

import numpy as np
from scipy.spatial.transform import Rotation, RotationSpline
from timing import interleaved_medians, random_keyframes

from trajgen import BlendingSpline
from trajgen.compare import SphericalBezier, Squad

# Table 3, SGI Indigo XS24 row (us): Bezier, squad, circular blending.
PAPER = {
    8: (14700, 9000, 7300),
    16: (26600, 16300, 12400),
    32: (50400, 30800, 23200),
    64: (97600, 59500, 44400),
}


def main():
    quats, times = random_keyframes(16, seed=1)
    print(
        "| m | Bezier (ms) | squad (ms) | circular blending k=1 (ms) | scipy (ms) "
        "| ours / squad (paper) | ours / Bezier (paper) |"
    )
    print("|---|---|---|---|---|---|---|")
    for m, (p_bez, p_squad, p_circ) in PAPER.items():
        t = np.linspace(times[0], times[-1], 15 * m + 1)
        med = interleaved_medians(
            {
                "bezier": lambda t=t: SphericalBezier(quats, times)(t),
                "squad": lambda t=t: Squad(quats, times)(t),
                "ours": lambda t=t: BlendingSpline(quats, times, k=1, local="circle")(t),
                "scipy": lambda t=t: RotationSpline(
                    times, Rotation.from_quat(quats, scalar_first=True)
                )(t).as_quat(),
            },
            repeats=15,
        )
        print(
            f"| {m} | {med['bezier'] * 1e3:.2f} | {med['squad'] * 1e3:.2f} | "
            f"{med['ours'] * 1e3:.2f} | {med['scipy'] * 1e3:.2f} | "
            f"{med['ours'] / med['squad']:.2f} ({p_circ / p_squad:.2f}) | "
            f"{med['ours'] / med['bezier']:.2f} ({p_circ / p_bez:.2f}) |"
        )


if __name__ == "__main__":
    main()
