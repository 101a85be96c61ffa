"""Fixed-rate sample times, and the limit on how many a plan may hold."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from .errors import BadArgument, PlanTooLarge
from .validate import check_number

#: The most samples a plan holds in memory by default: 5 million rows (about
#: 7 h at 200 Hz, 83 min at 1 kHz). Evaluating one sample with its angular
#: velocity and acceleration takes about 1 KiB of temporaries, so this keeps a
#: plan within a few GiB. ``trajgen plan`` writes CSV in blocks and may go
#: beyond it with ``--max-samples``.
MAX_SAMPLES = 5_000_000


def sample_count(t_start: float, t_end: float, rate_hz: float) -> float:
    """How many samples :func:`sample_times` gives (``inf`` if the count overflows).

    A float, so that an absurd plan (``t = 1e308``, ``rate 1e9``) can be
    refused with its count before anything is allocated.
    """
    periods = (float(t_end) - float(t_start)) * float(rate_hz)  # Python floats: inf, no warning
    if not math.isfinite(periods):
        return math.inf
    # Whole periods that fit, with a tolerance so 2.0 s at 100 Hz gives 201 samples;
    # one more sample at t_end when it is not on the grid.
    last = math.floor(periods + 1e-9)
    return last + 1.0 + float(periods - last > 1e-9)


def check_sample_count(
    t_start: float, t_end: float, rate_hz: float, max_samples: int = MAX_SAMPLES
) -> int:
    """The sample count of ``[t_start, t_end]`` at ``rate_hz``, refused above ``max_samples``.

    Raises
    ------
    PlanTooLarge
        With the count and the limit, before any array is allocated.
    """
    count = sample_count(t_start, t_end, rate_hz)
    if count > max_samples:
        shown = "more than 1e300" if not math.isfinite(count) else f"{count:.4g}"
        raise PlanTooLarge(
            f"{t_end - t_start:.6g} s at {rate_hz:g} Hz is {shown} samples, over the limit of "
            f"{max_samples:,} (lower the rate, or shorten the motion)"
        )
    return int(count)


def sample_times(
    t_start: float, t_end: float, rate_hz: float, *, max_samples: int = MAX_SAMPLES
) -> np.ndarray:
    """Times from ``t_start`` to ``t_end`` inclusive at ``rate_hz``.

    Samples fall at ``t_start + i / rate_hz``; the last one is at ``t_end`` even
    when the duration is not a whole number of periods (it is then closer than
    one period to the one before it).

    Parameters
    ----------
    t_start, t_end : float
        First and last time (s).
    rate_hz : float
        Sample rate (Hz), > 0.
    max_samples : int, optional
        Refuse plans longer than this (default :data:`MAX_SAMPLES`).

    Returns
    -------
    ndarray, shape (M,)
        Increasing times (s), ``M >= 2``.

    Raises
    ------
    TypeError, ValueError
        If ``rate_hz`` is not a positive finite number or ``t_end <= t_start``.
    PlanTooLarge
        If there would be more than ``max_samples`` samples.
    """
    return np.concatenate(
        list(sample_time_blocks(t_start, t_end, rate_hz, max_samples=max_samples, block=None))
    )


def sample_time_blocks(
    t_start: float,
    t_end: float,
    rate_hz: float,
    *,
    block: int | None = 100_000,
    max_samples: int = MAX_SAMPLES,
) -> Iterator[np.ndarray]:
    """:func:`sample_times` in consecutive pieces of at most ``block`` samples (None: one piece).

    For writing plans longer than memory allows, one piece at a time. Raises as
    :func:`sample_times`, before the first piece.
    """
    rate_hz = check_number("rate_hz", rate_hz, low=0.0, low_open=True)
    if not t_end > t_start:
        raise BadArgument(f"Expected t_end > t_start, got {t_start} .. {t_end}.")
    total = check_sample_count(t_start, t_end, rate_hz, max_samples)
    period = 1.0 / rate_hz
    step = total if block is None else block
    for first in range(0, total, step):
        t = t_start + np.arange(first, min(first + step, total)) * period
        if first + len(t) == total:
            t[-1] = t_end
        yield t
