"""What one frame costs on this host and bus, measured before a stream starts.

A stream on the wall clock sends one goal per period and reads the servos back
every ``read_every`` frames. ``probe_cycle`` times a few read-backs (it writes
nothing: a goal write has no reply, the host only builds it and hands it to the
port, so its share is its wire time, given by the caller), and
``read_every_for`` decides from the median whether the rate can hold: the mean
cost per frame must fit ``BUDGET`` of a period. The next goal waits for the
wire, not for the reply (``Streamer._loop``: it goes out behind a reply whose
wire end has passed, and the reply is checked right after it), so a frame with
a read-back must be off the wire (its goal, request, reply: ``read_wire_s``)
before the next frame counts as a stall (half a period late), and its reply
must be in before the frame after that does (the reply is collected before
anything else is sent). From the tail too: a read-back whose reply comes later
than that stalls that goal, and the stream's clock shifts by the lateness; the
interval is raised until the probe's reads would cost the stream at most
``LAG_SHARE`` of its rate that way. A rate that cannot hold is refused before
the first goal instead of tripping the lateness bound or the Bus Watchdog
mid-motion.
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

    def late(self, period_s: float) -> tuple[int, float]:
        """How many probe reads would stall a goal at ``period_s``, and the mean shift (s)
        per read that costs.

        The goal after a read-back's frame goes out behind its reply; the one
        after that waits for it: a reply in more than ``1 + STALL_PERIODS``
        periods after its frame started stalls it."""
        bound = (1 + STALL_PERIODS) * period_s
        shifts = [self.write_s + r - 2 * period_s for r in self.reads_s if self.write_s + r > bound]
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
        the median reply in hand within one more, and the probe reads that
        would not (``CycleCost.late``) shift the stream by at most
        ``LAG_SHARE`` of its time at one read every ``k`` frames; None when
        no ``k`` up to ``MAX_READ_EVERY`` does (the goal writes alone do not
        fit, a read-back's wire or its median reply outlasts those bounds, or
        too many come too late).
    """
    spare = BUDGET * period_s - cost.write_s
    if spare <= 0 or _peak_hz(cost) * period_s < 1:
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
    ``STALL_PERIODS`` periods and has its (median) reply within one more."""
    wire_hz = STALL_PERIODS / (cost.write_s + cost.read_wire_s)
    return min(wire_hz, (1 + STALL_PERIODS) / (cost.write_s + cost.read_s))
