"""Benchmark 3: construction time against the number of keyframes (should grow linearly).

python bench/construction.py
"""

from timing import interleaved_medians, random_keyframes

from trajgen import BlendingSpline


def main():
    print("| keyframes | construct (ms) | per keyframe (us) |")
    print("|---|---|---|")
    for n in (10, 100, 1_000, 10_000):
        quats, times = random_keyframes(n, seed=2)
        med = interleaved_medians(
            {"build": lambda q=quats, t=times: BlendingSpline(q, t)}, repeats=5
        )
        print(f"| {n} | {med['build'] * 1e3:.2f} | {med['build'] / n * 1e6:.1f} |")


if __name__ == "__main__":
    main()
