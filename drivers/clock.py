"""Waiting for an absolute deadline on the monotonic clock."""

from __future__ import annotations

import time

# Below this much time left, stop sleeping and spin (sleep overshoots ~0.1 ms).
_SPIN_S = 5e-4


def sleep_until(deadline_s: float) -> None:
    """Return at ``time.monotonic() >= deadline_s``, sleeping most of the way.

    The last half millisecond spins with ``time.sleep(0)``, which releases the
    GIL, so a thread in the same process (the virtual bus) keeps running.
    """
    while True:
        remaining = deadline_s - time.monotonic()
        if remaining <= 0:
            return
        time.sleep(remaining - 0.6 * _SPIN_S if remaining > _SPIN_S else 0)
