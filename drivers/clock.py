"""Waiting for an absolute deadline: on the monotonic clock, or on a simulated one.

A streamer reads the time and waits through a clock object (``now()``,
``sleep_until(deadline_s)``). ``WALL_CLOCK`` is the host's monotonic clock, what
a stream to real servos runs on. ``SimulatedClock`` jumps to each deadline
instead of waiting for it: for a host driving a lock-step virtual bus, where
simulated time moves with the traffic and waiting out the wall clock would
only waste it. ``PacedClock`` is simulated time too, but never ahead of the
wall clock: for a lock-step stream that something outside it paces in real
time (``trajgen follow --virtual``, whose keyframe lines arrive live). No
frame on a simulated clock is ever late; on a paced one, a host too slow for
real time makes simulated time fall behind the wall clock, and says how far.
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
    #: Whether the wall clock paces it (a stream on it runs at the stream's priority).
    paced = True

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
    paced = False

    def __init__(self, start_s: float = 0.0) -> None:
        self.time_s = float(start_s)

    def now(self) -> float:
        """Its time (s): the last deadline waited for."""
        return self.time_s

    def sleep_until(self, deadline_s: float) -> None:
        """Move to ``deadline_s`` at once (never backwards)."""
        self.time_s = max(self.time_s, deadline_s)


WALL_CLOCK = WallClock()


#: How far (s) a ``PacedClock`` may fall behind the wall clock and still catch up.
MAX_BEHIND_S = 0.05


class PacedClock(SimulatedClock):
    """Simulated time paced by the wall clock: never ahead of it, behind it on a slow host.

    A deadline is simulated time, as on a ``SimulatedClock``: once reached,
    ``now()`` is the deadline, so no frame is ever late and no lateness bound can
    trip. But a deadline still ahead of the wall clock is waited for: where the
    host keeps up, the stream runs in real time. Where it does not (a busy host,
    a plant slower than real time), simulated time falls behind. Up to
    ``max_behind_s`` behind, the next deadlines come sooner until it has caught
    up (jitter); further, simulated time is shifted by the whole lag (counted in
    ``shifts`` and ``behind_s``) and goes on in real time from there, so that
    it never runs faster than real time for long.

    The wall clock is tied to simulated time at the first ``now()`` or
    ``sleep_until``, not at creation (bring-up before the stream takes a while).

    Parameters
    ----------
    start_s : float, optional
        Its simulated time (s) at creation.
    max_behind_s : float, optional
        Lag (s) behind the wall clock caught up; more is shifted off.
    wall : callable, optional
        The wall clock (s), default ``time.monotonic``.
    wait : callable, optional
        ``wait(wall_deadline_s)``: returns once ``wall()`` reaches it; default
        this module's ``sleep_until``.

    A stream on it runs at the stream's priority, as on the wall clock
    (``Streamer(realtime=True)``, ``drivers.priority``), so that it keeps the
    wall clock's pace where it can; it is not probed (no frame can be late).

    Attributes
    ----------
    lag_s : float
        How far (s) behind the wall clock the last deadline was reached.
    lag_max_s : float
        The most that was (s).
    shifts : int
        Times simulated time was shifted, more than ``max_behind_s`` behind.
    behind_s : float
        Simulated time lost to the wall clock in those shifts (s).
    """

    paced = True

    def __init__(
        self,
        start_s: float = 0.0,
        *,
        max_behind_s: float = MAX_BEHIND_S,
        wall=time.monotonic,
        wait=sleep_until,
    ) -> None:
        super().__init__(start_s)
        self.max_behind_s = float(max_behind_s)
        self._wall = wall
        self._wait = wait
        self._wall_at_zero: float | None = None  # wall time (s) of simulated time 0
        self.lag_s = 0.0
        self.lag_max_s = 0.0
        self.shifts = 0
        self.behind_s = 0.0

    def now(self) -> float:
        """Its simulated time (s): the last deadline waited for."""
        self._tie()
        return self.time_s

    def sleep_until(self, deadline_s: float) -> None:
        """Move to ``deadline_s`` (never backwards) once the wall clock is there too."""
        self._tie()
        self.time_s = max(self.time_s, deadline_s)
        due = self._wall_at_zero + self.time_s
        self._wait(due)
        lag = max(self._wall() - due, 0.0)
        self.lag_s = lag
        self.lag_max_s = max(self.lag_max_s, lag)
        if lag > self.max_behind_s:
            self._wall_at_zero += lag
            self.shifts += 1
            self.behind_s += lag

    @property
    def behind_now_s(self) -> float:
        """How far (s) simulated time is behind the wall clock: shifts and the last lag."""
        lag = 0.0 if self.lag_s > self.max_behind_s else self.lag_s
        return self.behind_s + lag

    def summary(self) -> dict:
        """``lag_max_s``, ``shifts``, ``behind_s`` and ``behind_now_s``, as plain numbers."""
        return {
            "lag_max_s": self.lag_max_s,
            "shifts": self.shifts,
            "behind_s": self.behind_s,
            "behind_now_s": self.behind_now_s,
        }

    def format(self) -> str:
        """A line for a terminal."""
        if not self.shifts:
            return (
                f"simulated time kept the wall clock's pace (at most "
                f"{1e3 * self.lag_max_s:.1f} ms behind, caught up)"
            )
        return (
            f"simulated time fell {self.behind_now_s:.3f} s behind the wall clock in "
            f"{self.shifts} shifts (this host ran the simulation slower than real time)"
        )

    def _tie(self) -> None:
        if self._wall_at_zero is None:
            self._wall_at_zero = self._wall() - self.time_s
