"""A ring of joint frames in memory shared with a forked process: one producer, one consumer.

The planner process (:mod:`trajgen.follow_process`) puts frames; the streaming process
takes them. Neither takes a lock: each side writes only its own counters (``put`` the
frames written and the end, ``take`` the frames taken and a stop), and a slot is
written whole before its sequence number and the written counter say it is there; a
slot's sequence number is checked again after it is copied. The memory is an anonymous
shared mapping made before the fork (nothing to name or clean up). Numpy and the
standard library only.
"""

from __future__ import annotations

import mmap

import numpy as np

from .errors import BadArgument
from .stream import JointFrame

# counters (int64): frames put, frames taken (the producer's), the consumer's
_WRITTEN, _TAKEN, _ENDED, _STOP = 0, 1, 2, 3  # frames put, taken; end flag; stop flag
_HEAD = 8  # int64 words before the slots (one cache line)


class RingEmpty(Exception):
    """No frame to take yet (the producer has not put the next one)."""


class FrameRing:
    """``capacity`` fixed-size frame records (index, t, q, qd, qdd, goal; float64).

    Parameters
    ----------
    n_joints : int
    capacity : int
        Frames the producer may be ahead of the consumer.
    goals : bool
        Whether frames carry a ``goal`` (led goals, ``trajgen.lead``); without, the
        frames taken have ``goal`` None.
    """

    def __init__(self, n_joints: int, capacity: int, *, goals: bool):
        if capacity < 1:
            raise BadArgument(f"Expected a capacity of at least 1, got {capacity}.")
        self.n_joints, self.capacity, self.goals = int(n_joints), int(capacity), bool(goals)
        # per slot: sequence number (k + 1 once frame k is in it), index, t, q, qd, qdd, goal
        self._width = 3 + 4 * self.n_joints
        self._map = mmap.mmap(-1, 8 * (_HEAD + self.capacity * self._width))
        self._counters = np.frombuffer(self._map, np.int64, _HEAD)
        self._slots = np.frombuffer(self._map, np.float64, offset=8 * _HEAD).reshape(
            self.capacity, self._width
        )

    # -- producer ------------------------------------------------------------

    def room(self) -> int:
        """Frames that can be put now."""
        return self.capacity - int(self._counters[_WRITTEN] - self._counters[_TAKEN])

    def put(self, frame: JointFrame) -> None:
        """Write the next frame (the caller checked :meth:`room`)."""
        k = int(self._counters[_WRITTEN])
        if k - int(self._counters[_TAKEN]) >= self.capacity:
            raise OverflowError("the frame ring is full")
        n = self.n_joints
        slot = self._slots[k % self.capacity]
        slot[1] = frame.index
        slot[2] = frame.t
        slot[3 : 3 + n] = frame.q
        slot[3 + n : 3 + 2 * n] = frame.qd
        slot[3 + 2 * n : 3 + 3 * n] = frame.qdd
        if self.goals:
            slot[3 + 3 * n :] = frame.goal
        slot[0] = k + 1  # the frame is whole: its number, then the counter
        self._counters[_WRITTEN] = k + 1

    def end(self) -> None:
        """No frame follows those put."""
        self._counters[_ENDED] = 1

    @property
    def stopped(self) -> bool:
        """Whether the consumer asked for no more frames (:meth:`stop`)."""
        return bool(self._counters[_STOP])

    # -- consumer ------------------------------------------------------------

    @property
    def taken(self) -> int:
        """Frames taken so far (the index of the next frame to take)."""
        return int(self._counters[_TAKEN])

    @property
    def ended(self) -> bool:
        """Whether every frame has been put (some may still be waiting to be taken)."""
        return bool(self._counters[_ENDED])

    def stop(self) -> None:
        """Ask the producer to put no more frames."""
        self._counters[_STOP] = 1

    def take(self) -> JointFrame:
        """The next frame, copied out of its slot.

        Raises
        ------
        RingEmpty
            If the producer has not put it yet.
        """
        k = int(self._counters[_TAKEN])
        if k >= int(self._counters[_WRITTEN]):
            raise RingEmpty
        record = self._slots[k % self.capacity].copy()
        if record[0] != k + 1:  # cannot be, with stores seen in their order: say so
            raise RuntimeError(f"frame ring: slot of frame {k} holds frame {record[0] - 1:.0f}")
        self._counters[_TAKEN] = k + 1
        n = self.n_joints
        return JointFrame(
            int(record[1]),
            float(record[2]),
            record[3 : 3 + n],
            record[3 + n : 3 + 2 * n],
            record[3 + 2 * n : 3 + 3 * n],
            record[3 + 3 * n :] if self.goals else None,
        )
