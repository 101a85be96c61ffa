"""Waiting for an absolute deadline: on the monotonic clock, or on a simulated one.

A streamer reads the time and waits through a clock object (``now()``,
``sleep_until(deadline_s)``). ``WALL_CLOCK`` is the host's monotonic clock, what
a stream to real servos runs on. ``SimulatedClock`` jumps to each deadline
instead of waiting for it: for a host driving a lock-step virtual bus, where
simulated time moves with the traffic and waiting out the wall clock would
only waste it.
"""

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


class WallClock:
    """The host's monotonic clock (s)."""

    #: Whether waiting for a deadline takes that much of the host's time.
    real_time = True

    def now(self) -> float:
        """``time.monotonic()``."""
        return time.monotonic()

    def sleep_until(self, deadline_s: float) -> None:
        """Wait for ``deadline_s`` (see the module function)."""
        sleep_until(deadline_s)


class SimulatedClock:
    """A clock that jumps to each deadline instead of waiting for it.

    Parameters
    ----------
    start_s : float, optional
        Its time (s) at creation.
    """

    real_time = False

    def __init__(self, start_s: float = 0.0) -> None:
        self.time_s = float(start_s)

    def now(self) -> float:
        """Its time (s): the last deadline waited for."""
        return self.time_s

    def sleep_until(self, deadline_s: float) -> None:
        """Move to ``deadline_s`` at once (never backwards)."""
        self.time_s = max(self.time_s, deadline_s)


WALL_CLOCK = WallClock()
