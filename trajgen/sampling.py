"""Fixed-rate sample times."""

from __future__ import annotations

import math

import numpy as np


def sample_times(t_start: float, t_end: float, rate_hz: float) -> np.ndarray:
    """Times from ``t_start`` to ``t_end`` inclusive at ``rate_hz``.

    Samples fall at ``t_start + i / rate_hz``; the last one is at ``t_end`` even
    when the duration is not a whole number of periods (it is then closer than
    one period to the one before it).

    Returns
    -------
    ndarray, shape (M,)
        Increasing times (s), ``M >= 2``.

    Raises
    ------
    ValueError
        If ``rate_hz`` is not a positive finite number or ``t_end <= t_start``.
    """
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float, np.number)):
        raise TypeError(f"Expected `rate_hz` to be a number, got {type(rate_hz).__name__}.")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"Expected `rate_hz` > 0, got {rate_hz}.")
    if not t_end > t_start:
        raise ValueError(f"Expected t_end > t_start, got {t_start} .. {t_end}.")
    period = 1.0 / rate_hz
    # Whole periods that fit, with a tolerance so 2.0 s at 100 Hz gives 201 samples.
    n = math.floor((t_end - t_start) / period + 1e-9)
    t = t_start + np.arange(n + 1) * period
    if t_end - t[-1] > 1e-9 * period:
        t = np.append(t, t_end)
    else:
        t[-1] = t_end
    return t
