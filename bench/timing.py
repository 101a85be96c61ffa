"""Shared timing helper for the benchmarks: interleaved runs, median wall time."""

import time

import numpy as np


def interleaved_medians(fns: dict, repeats: int = 9) -> dict:
    """Median seconds per call of each function, running them in turn ``repeats`` times.

    Interleaving spreads the machine's noise (other processes, frequency changes)
    evenly over the contenders, so their ratio means more than their absolute times.
    """
    times = {name: [] for name in fns}
    for fn in fns.values():  # warm-up: imports, caches, first-call costs
        fn()
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(v)) for name, v in times.items()}


def random_keyframes(n: int, seed: int = 0):
    """``n`` uniformly random orientations (w, x, y, z) at times 0, 1, ..., n - 1 s."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True), np.arange(n, dtype=float)
