"""Which group reads each stream frame carries, so that no frame holds more wire than it has.

A frame is one Sync Write of Goal Position, then the reads due at it: the state
read-back (present current, velocity, position) every ``read_every`` frames,
the status poll (Torque Enable, Hardware Error Status, Bus Watchdog) every
``poll_every`` frames and the health poll (supply voltage, temperature) every
``health_every``. The streamer sends the last read of a frame split-phase
(``ServoBus.request_block``: its reply is collected before the next goal, or
on the wall clock after it or a few more, ``Streamer._loop``), the others at
once; a frame whose goal went out behind a reply not checked yet defers its
reads, or those that no longer fit before the next deadline
(``FrameReads.defer``). At 1 kHz and
1 Mbps the status poll of three servos is 142 bytes, 1.42 ms of wire: in one
frame it would make the next goal late. So the
polls are laid out in parts that fit a frame's room (``parts``: a register at
a time, then fewer servos at a time), queued when due, and carried by the
next frames whose wire leaves room for them (``FrameReads``); a part that
found no room for ``poll_every`` frames goes out anyway. The state read is
never deferred: how often it fits is the probe's choice (``drivers.probe``).
At low rates everything fits one frame, in the order above, as it always was.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Read:
    """One group read a frame may carry.

    Attributes
    ----------
    kind : {"state", "status", "health"}
        What it is for.
    ids : tuple of int
        Servos read.
    registers : tuple
        Registers read (``drivers.control_table.Register``).
    n_bytes : int
        Its request and reply bytes on the wire.
    """

    kind: str
    ids: tuple[int, ...]
    registers: tuple
    n_bytes: int


def parts(
    kind: str,
    ids: Sequence[int],
    registers: Sequence,
    size: Callable[[tuple, tuple], int],
    room: float,
    *,
    by_register: bool = True,
) -> list[Read]:
    """The read of ``registers`` from ``ids``: one ``Read`` if it fits ``room`` bytes, else parts.

    Parts: a register at a time (where ``by_register``), then half the servos
    at a time, as far as that makes them fit (a part that cannot fit however
    small is not split: more parts would only cost more).

    Parameters
    ----------
    size : callable
        ``size(ids, registers)``: bytes of that read on the wire (request and reply).
    room : float
        Bytes a frame has for one read.
    """
    ids, registers = tuple(ids), tuple(registers)
    whole = Read(kind, ids, registers, size(ids, registers))
    if whole.n_bytes <= room or size(ids[:1], registers[:1]) > room:
        return [whole]
    if by_register and len(registers) > 1:
        return [p for r in registers for p in parts(kind, ids, (r,), size, room)]
    if len(ids) == 1:
        return [whole]
    half = (len(ids) + 1) // 2
    split = {"by_register": by_register}
    return parts(kind, ids[:half], registers, size, room, **split) + parts(
        kind, ids[half:], registers, size, room, **split
    )


class FrameReads:
    """The reads of each frame of one stream phase, in the order they go out.

    Parameters
    ----------
    state : Read
        The state read-back.
    status, health : sequence of Read
        The parts of the status and the health poll.
    cost : callable
        ``cost(read)``: how long a read holds the bus (s): its wire time and
        what the host and adapter add to each read.
    room_s : float
        Time a frame has for its reads (s): its budget less the goal write.
    read_every, poll_every, health_every : int
        Frames between state reads, status polls and health polls (>= 1).

    Attributes
    ----------
    skipped : int
        State reads left out for a poll part that had waited ``read_every``
        frames for room beside them.
    deferred : int
        Reads put off to the next frame (``defer``).
    """

    def __init__(
        self,
        state: Read,
        status: Sequence[Read],
        health: Sequence[Read],
        cost: Callable[[Read], float],
        room_s: float,
        read_every: int,
        poll_every: int,
        health_every: int,
    ) -> None:
        self.state, self.status, self.health = state, tuple(status), tuple(health)
        self.cost, self.room_s = cost, room_s
        self.read_every, self.poll_every, self.health_every = read_every, poll_every, health_every
        self.skipped = self.deferred = 0
        # The frame of the next state read: ``read_every`` after the last one due (or the
        # next frame, where that one was deferred): never two closer than ``read_every``.
        self._next_state = 0
        self._frame = 0  # the frame last laid out (``for_frame``)
        self._queue: deque[Read] = deque()  # poll parts due, not yet carried
        self._head_since = 0  # the frame since which the queue's first part waits first

    def for_frame(self, k: int) -> list[Read]:
        """The reads frame ``k`` (0 first) carries.

        The state read when due (``read_every`` frames after the last one was
        due, or the frame after one deferred), then queued poll parts while
        they fit ``room_s`` beside it. A frame without reads takes the first
        part whether it fits or not; a part that has waited first in the
        queue for ``read_every`` frames takes the state read's place (at
        ``read_every`` 1 no frame is free of it).
        """
        self._frame = k
        carried = [self.state] if k >= self._next_state else []
        if carried:
            self._next_state = k + self.read_every
        if not self._queue:
            self._head_since = k
        if k % self.poll_every == self.poll_every - 1:
            self._queue.extend(self.status)
        if k % self.health_every == self.health_every // 2:
            self._queue.extend(self.health)
        used = sum(self.cost(r) for r in carried)
        while self._queue:
            part = self._queue[0]
            if carried and used + self.cost(part) > self.room_s:
                if carried != [self.state] or k - self._head_since < self.read_every:
                    break
                carried, used = [], 0.0  # it waited long enough: this frame is the poll's
                self.skipped += 1
            self._queue.popleft()
            self._head_since = k
            carried.append(part)
            used += self.cost(part)
        return carried

    def defer(self, reads: Sequence[Read]) -> None:
        """Put off ``reads`` (the last frame's, from ``for_frame``) to the next frame: its
        poll parts first in the queue again, and a state read there, the next one
        ``read_every`` frames after it."""
        self.deferred += len(reads)
        for read in reversed(reads):
            if read.kind == "state":
                self._next_state = self._frame + 1
            else:
                self._queue.appendleft(read)
