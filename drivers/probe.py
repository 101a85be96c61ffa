"""What one frame costs on this host and bus, measured before a stream starts.

A stream on the wall clock sends one goal per period and reads the servos back
every ``read_every`` frames. ``probe_cycle`` times a few read-backs (it writes
nothing: a goal write has no reply, the host only builds it and hands it to the
port, so its share is its wire time, given by the caller), and
``read_every_for`` decides from the median whether the rate can hold: the mean
cost per frame must fit ``BUDGET`` of a period. The next goal waits for the
wire, not for the reply (``Streamer._loop``: it goes out behind a reply whose
wire end has passed; a reply still not in after it is carried to the next
frames, up to ``REPLY_WAIT_S`` past its wire end, and checked as soon as it is
in, before anything else is sent), so a frame with a read-back must be off the
wire (its goal, request, reply: ``read_wire_s``) before the next frame counts
as a stall (half a period late), and its median reply must be in before the
goal after the one that stops carrying it would be a stall. From the tail too:
a read-back whose reply comes later than that stalls that goal, and the
stream's clock shifts by the lateness; the interval is raised until the probe's
reads would cost the stream at most ``LAG_SHARE`` of its rate that way. A rate
that cannot hold is refused before the first goal instead of tripping the
lateness bound or the Bus Watchdog mid-motion.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

#: Share of a period the mean cost of a frame may take (the rest: sleep overshoot,
#: the periodic watchdog and health polls, the host's own jitter).
BUDGET = 0.8
#: Frames timed by the probe (at 1 kHz and 3 servos, about 50 ms of traffic).
PROBE_FRAMES = 50
#: Share of its rate a stream may lose to read-backs too late for the next goal.
LAG_SHARE = 0.01
#: Read-back less often than this many frames is refused instead (telemetry too sparse).
MAX_READ_EVERY = 50
#: A frame is a stall when this many periods after its start it is not done with the bus:
#: half a period past the next deadline (the default stall bound).
STALL_PERIODS = 1.5
#: Longest a read-back's reply not in hand yet is carried past its computed wire end
#: (s), goals going out behind it meanwhile (``Streamer._loop``): a fault in that reply
#: is acted on at most this much (and the period that checks it) after it left the
#: wire, as a 200 Hz stream reading back every frame does; after it the next goal
#: waits for the reply (or its timeout).
REPLY_WAIT_S = 5e-3


@dataclass(frozen=True)
class CycleCost:
    """Median host-plus-bus time of the two halves of a frame (s).

    Attributes
    ----------
    write_s : float
        One Sync Write of Goal Position (no reply: its wire time).
    read_s : float
        One group read of the state block (request, replies, checks), median.
    frames : int
        Read-backs timed.
    reads_s : tuple of float
        Each read-back's time (s), as timed (empty: only the median is known).
    read_wire_s : float
        A read-back's own wire time (s): request, the servos' turnaround and
        Return Delay Time, reply, margin (``ServoBus.reply_s``); 0 if unknown.
    """

    write_s: float
    read_s: float
    frames: int
    reads_s: tuple[float, ...] = ()
    read_wire_s: float = 0.0

    def with_read_wire(self, read_wire_s: float) -> CycleCost:
        """The same cost, a read-back's wire time known (``read_wire_s``, s)."""
        return replace(self, read_wire_s=read_wire_s)

    def median_only(self) -> CycleCost:
        """The same cost without the single reads (what the median alone decides)."""
        return replace(self, reads_s=())

    def carried_s(self, period_s: float) -> float:
        """When, from the start of a read-back's frame (s), the last goal goes out behind
        its reply: the first deadline at least ``REPLY_WAIT_S`` past its wire end (the
        next deadline at least). A reply not in by then is waited for after that goal."""
        wire_end_s = self.write_s + self.read_wire_s
        return max(1, math.ceil((wire_end_s + REPLY_WAIT_S) / period_s - 1e-9)) * period_s

    def stall_bound_s(self, period_s: float) -> float:
        """How long after its frame started (s) a read-back's reply may come in without
        stalling a goal: the waited-for reply past half a period after the next deadline."""
        return self.carried_s(period_s) + STALL_PERIODS * period_s

    def late(self, period_s: float) -> tuple[int, float]:
        """How many probe reads would stall a goal at ``period_s``, and the mean shift (s)
        per read that costs (``stall_bound_s``: the stream shifts by how late the goal
        after the last one carried behind the reply goes)."""
        bound, carried = self.stall_bound_s(period_s), self.carried_s(period_s)
        shifts = [
            self.write_s + r - carried - period_s for r in self.reads_s if self.write_s + r > bound
        ]
        return len(shifts), sum(shifts) / len(self.reads_s) if self.reads_s else 0.0

    def describe(self) -> str:
        """One phrase with both figures in ms."""
        return (
            f"a goal write takes {1e3 * self.write_s:.2f} ms and a read-back "
            f"{1e3 * self.read_s:.2f} ms (median of {self.frames} probe reads)"
        )


def probe_cycle(
    read, write_s: float, frames: int = PROBE_FRAMES, clock=time.perf_counter
) -> CycleCost:
    """Time ``frames`` calls of ``read()``; their median, with ``write_s`` for the write.

    Parameters
    ----------
    read : callable
        One read-back (raises on a bus fault).
    write_s : float
        What a goal write costs (s), e.g. its wire time.
    frames : int, optional
        How many read-backs to time (>= 1).
    clock : callable, optional
        Seconds, monotonic.

    Returns
    -------
    CycleCost
    """
    reads = []
    for _ in range(frames):
        t0 = clock()
        read()
        reads.append(clock() - t0)
    return CycleCost(write_s, _median(reads), frames, tuple(reads))


def _median(values: Sequence[float]) -> float:
    ordered = sorted(values)
    n = len(ordered)
    return 0.5 * (ordered[(n - 1) // 2] + ordered[n // 2])


def read_every_for(cost: CycleCost, period_s: float, wanted: int = 1) -> int | None:
    """The least read-back interval (frames, >= ``wanted``) a period can carry, or None.

    Parameters
    ----------
    cost : CycleCost
    period_s : float
        The stream's period (s).
    wanted : int, optional
        The read-back interval asked for.

    Returns
    -------
    int or None
        ``k``: ``write + read / k <= BUDGET * period``, a frame with a
        read-back is off the wire within ``STALL_PERIODS`` periods and has
        the median reply in hand within ``CycleCost.stall_bound_s``, and the probe reads that
        would not (``CycleCost.late``) shift the stream by at most
        ``LAG_SHARE`` of its time at one read every ``k`` frames; None when
        no ``k`` up to ``MAX_READ_EVERY`` does (the goal writes alone do not
        fit, a read-back's wire or its median reply outlasts those bounds, or
        too many come too late).
    """
    spare = BUDGET * period_s - cost.write_s
    wire_s = cost.write_s + cost.read_wire_s
    if spare <= 0 or wire_s > STALL_PERIODS * period_s:
        return None
    if cost.write_s + cost.read_s > cost.stall_bound_s(period_s):
        return None
    shift_s = cost.late(period_s)[1]
    k = max(
        wanted,
        math.ceil(cost.read_s / spare - 1e-12),
        math.ceil(shift_s / (LAG_SHARE * period_s) - 1e-12),
    )
    return k if k <= MAX_READ_EVERY else None


def max_rate_hz(cost: CycleCost, read_every: int = 1) -> float:
    """The highest rate (Hz) that carries ``cost`` with read-back every ``read_every`` frames."""
    return min(BUDGET / (cost.write_s + cost.read_s / read_every), _peak_hz(cost))


def _peak_hz(cost: CycleCost) -> float:
    """The highest rate (Hz) at which a frame with a read-back is off the wire within
    ``STALL_PERIODS`` periods and has its (median) reply within ``CycleCost.stall_bound_s``
    (that bound is at least one more period, or ``REPLY_WAIT_S`` past the wire end and
    ``STALL_PERIODS`` more)."""
    wire_hz = STALL_PERIODS / (cost.write_s + cost.read_wire_s)
    in_hand_s = cost.write_s + cost.read_s
    carried_s = max(0.0, cost.read_s - cost.read_wire_s - REPLY_WAIT_S)
    shortest_s = min(in_hand_s / (1 + STALL_PERIODS), carried_s / STALL_PERIODS)
    return wire_hz if shortest_s <= 0 else min(wire_hz, 1.0 / shortest_s)
