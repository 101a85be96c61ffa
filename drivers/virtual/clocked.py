"""A virtual bus on the host's own simulated clock: host stalls as simulated events.

``ClockedBus`` is a ``VirtualBus`` whose time is a clock it shares with the
host (a ``drivers.clock.SimulatedClock``, what a ``Streamer`` waits on): each
packet first brings the plant to the clock's time, in whole steps of
``sim_step_s``, and the Bus Watchdog runs on that time, checked after every
step (a servo trips at the step where more than its period has passed
without a packet to it, and stops where it is). Nothing in it reads the wall
clock, so a host that advances the clock by 80 ms between two frames has
stalled for 80 ms on both sides, on any machine however busy: the streamer
finds the frame late, the servos saw 80 ms without a packet. Packets are
answered in the client's own thread, as in lock-step (``connect``).

Unlike lock-step (``VirtualBus(lockstep_dt_s=...)``, one period per goal or
poll whatever the clock says), time here is what the host's clock says: a
goal write or a poll ends no period of its own.
"""

from __future__ import annotations

import math

from trajgen.drivers.virtual.bus import VirtualBus

from ..errors import BadArgument

# A real-time VirtualBus underneath (lockstep_dt_s None: no period per goal or poll,
# replies from the state ``_publish`` stores), with these in place of the simulation
# thread and the wall clock: ``_now``, ``_handle`` (the plant brought to the clock's
# time first), ``_note_staleness``, ``_simulate``, ``attach_client`` and ``connect``.

# Steps closer than this fraction of a step to a whole number of them count as whole.
_STEP_ROUNDING = 1e-9


class ClockedBus(VirtualBus):
    """A ``VirtualBus`` on a shared simulated clock (see the module docstring).

    Parameters
    ----------
    plant : Plant or None, optional
        As for ``VirtualBus``.
    clock : object with ``now()``
        The host's clock (s), e.g. a ``drivers.clock.SimulatedClock``; simulated
        time on the bus is its time since ``start``.
    **kwargs
        As for ``VirtualBus`` (not ``lockstep_dt_s``: the clock decides).
    """

    def __init__(self, plant=None, *, clock, **kwargs) -> None:
        if kwargs.get("plant_process"):
            raise BadArgument("Expected no `plant_process` on a ClockedBus (the clock moves it).")
        super().__init__(plant, **kwargs)
        self.clock = clock
        self._clock_start_s = clock.now()

    def start(self) -> ClockedBus:
        """Open the pty; packets are answered by a client of this process (``connect``)."""
        self._clock_start_s = self.clock.now()
        super().start()
        return self

    def connect(self, **kwargs):
        """A driver bus on this port (not yet open) whose packets it answers in its own thread.

        Parameters
        ----------
        **kwargs
            Passed to ``ServoBus``. A stream on it should wait on this bus's ``clock``.
        """
        from trajgen.drivers.bus import ServoBus

        return ServoBus(self.port, responder=self, **kwargs)

    def attach_client(self) -> None:
        """From now on, the client in this process answers its packets (``answer``)."""
        with self._io_lock:
            self._client_answers = True

    # -- time: the clock's, never the wall clock's --------------------------

    def _now(self) -> float:
        """The clock's time (s): what the Bus Watchdog runs on."""
        return self.clock.now()

    def _simulate(self) -> None:
        """No simulation thread: the plant moves when a packet comes, to the clock's time."""

    def _handle(self, raw: bytes, arrival_s: float):
        """Bring the plant to the clock's time, then answer the packet as it arrived then."""
        self._catch_up_to_clock()
        return super()._handle(raw, self._now())

    def _note_staleness(self, arrival_s: float) -> None:
        """Never stale: every reply carries the state at the clock's time."""

    def _catch_up_to_clock(self) -> None:
        """Step the plant to the clock's time (lock held), tripping Bus Watchdogs on the
        way (each in the step its period ends), and publish the state replies carry."""
        target = self._now() - self._clock_start_s
        while True:
            steps = math.floor((target - self.sim_time_s) / self.sim_step_s + _STEP_ROUNDING)
            if steps <= 0:
                break
            trip = self._next_trip_s() - self._clock_start_s
            if trip < target:  # up to the step in which the first watchdog trips
                first = math.floor((trip - self.sim_time_s) / self.sim_step_s) + 1
                steps = min(steps, max(first, 1))
            self._advance(steps * self.sim_step_s)  # sim_time_s too
            self._steps_done += steps
            self._check_watchdogs(self._clock_start_s + self.sim_time_s)
        self._publish()
