"""Per-frame evaluation of an online spline's snapshot, in floats.

Part of :mod:`trajgen.online`: what :func:`trajgen.stream.stream_frames`
evaluates once per frame of a stream of an :class:`~trajgen.online.OnlineSpline`.
"""

from __future__ import annotations

import bisect
import math
from typing import TYPE_CHECKING

import numpy as np

from .path import Steps

if TYPE_CHECKING:
    from .frame_eval import FrameKinematics
    from .online_plan import Piece, Plan


class PlanFrames:
    """One snapshot of an :class:`OnlineSpline` at one stream time per call, in floats.

    What :func:`trajgen.stream.stream_frames` evaluates per frame: a spliced segment
    in floats (:meth:`Splice.frame`, a few microseconds), a hold as its constant,
    and a blended segment (a BlendingSpline's, which has no per-frame form) with
    numpy, ``BLOCK_FRAMES`` stream times at a time, the next block's evaluation
    spread in steps over the frames of the one before (as ``stream_frames`` does
    for an offline BlendingSpline). The part holding a time is
    looked up with the numpy evaluation's own rules, only when the time leaves the
    current part (or lies on its boundary), so every frame equals ``evaluate``'s.

    Parameters
    ----------
    plan : the path from :meth:`OnlineSpline.snapshot`
    t0 : float
        The stream's first time (s); its times are ``t0 + i / rate_hz``.
    rate_hz : float
        The stream's rate (Hz), > 0.
    previous : PlanFrames, optional
        The same stream's evaluator of an earlier snapshot: its blocks of the pieces
        this plan keeps are used, not evaluated again.
    """

    #: Stream times evaluated at once in a blended segment.
    BLOCK_FRAMES = 16

    def __init__(self, plan: Plan, t0: float, rate_hz: float, previous: PlanFrames | None = None):
        self._plan, self._t0, self._rate = plan, t0, rate_hz
        self._starts = plan.starts.tolist()
        self._lo, self._hi = math.inf, -math.inf  # the current part's open interval
        self._part = None
        self._joint_part = None  # the current part's segment, where it is a joint motion
        # The current block, (piece, first frame, times (B,), q (B, 4), omega, alpha), and
        # the next, (piece, first frame, Steps evaluating it). Blocks are a piece's, and
        # pieces are immutable and shared by the plans before and after a change: an
        # earlier snapshot's blocks stay valid where their piece is kept.
        self._block = previous._block if previous else None
        self._ahead = previous._ahead if previous else None

    def __call__(self, t: float) -> tuple[tuple, tuple, tuple]:
        """Orientation (w, x, y, z), space-frame angular velocity (rad/s) and
        acceleration (rad/s^2) at stream time ``t`` (s), each a tuple of floats."""
        if not self._lo < t < self._hi:
            self._enter(t)
        return self._part(t)

    def joints(self, t: float, kin: FrameKinematics) -> tuple[tuple, tuple, tuple]:
        """Joint angles (rad), speeds (rad/s) and accelerations (rad/s^2) at stream time
        ``t`` (s): ``kin(t, *self(t))``, except in a joint motion on ``kin``'s own axes
        (a segment with ``joints_at`` and ``indices``, such as
        :class:`~trajgen.joint_splice.JointSplice`), whose joints are read off it
        (:meth:`FrameKinematics.joints`: the same frame, to rounding, without the
        orientation's round trip through the inverse kinematics)."""
        if not self._lo < t < self._hi:
            self._enter(t)
        segment = self._joint_part
        if segment is not None and segment.indices == kin.indices:
            joints = kin.joints(*segment.joints_at(t))
            if joints is not None:
                return joints
        return kin(t, *self._part(t))

    def _enter(self, t: float) -> None:
        """Make the part holding ``t`` the current one, by the rules of ``Plan._segment``
        and ``Piece._parts`` (in floats)."""
        plan, starts = self._plan, self._starts
        if t < starts[0]:
            plan._segment(np.array([t]))  # raises before the kept range (beyond rounding)
        j = max(bisect.bisect_left(starts, t) - 1, 0)
        piece = plan.pieces[j]
        lo = starts[j]
        hi = starts[j + 1] if j + 1 < len(starts) else math.inf
        splice, t_end = piece.splice, piece.t_end
        self._joint_part = None
        if t >= t_end:  # the hold
            q, zero = tuple(piece.q_end.tolist()), (0.0, 0.0, 0.0)
            lo, self._part = max(lo, t_end), lambda _: (q, zero, zero)
        elif splice is not None and t < (end := float(splice.times[1])):
            hi, self._part = min(hi, end), splice.frame
            if hasattr(splice, "joints_at"):
                self._joint_part = splice
        else:
            times = piece.spline.times
            seg = min(max(bisect.bisect_right(times, t) - 1, 0), len(times) - 2)
            lo = max(lo, float(times[seg]))
            hi = min(hi, float(times[seg + 1]))
            self._part = lambda x: self._blended(piece, x)
        self._lo, self._hi = lo, hi

    def _blended(self, piece: Piece, t: float) -> tuple[tuple, tuple, tuple]:
        i = round((t - self._t0) * self._rate)
        block = self._block
        if block is None or block[0] is not piece or not 0 <= i - block[1] < self.BLOCK_FRAMES:
            ahead = self._ahead
            if ahead is not None and ahead[0] is piece and ahead[1] == i:
                samples = ahead[2].finish()
                q, omega, alpha = samples.q, samples.omega, samples.alpha
            else:  # the first block of this segment: at once
                q, (omega, alpha) = piece.space_rates(self._block_times(i), 2)
            block = self._block = (piece, i, self._block_times(i), q, omega, alpha)
            # The next block, a step per frame of this one.
            times = np.clip(self._block_times(i + self.BLOCK_FRAMES), *piece.spline.times[[0, -1]])
            steps = piece.spline.evaluation_steps(times, max_order=2)
            self._ahead = (piece, i + self.BLOCK_FRAMES, Steps(steps))
        else:
            self._ahead[2].step()
        _, first, times, q, omega, alpha = block
        k = i - first
        if times[k] != t:  # not on the stream's grid: this time alone
            q1, (w1, a1) = piece.space_rates(np.array([t]), 2)
            return tuple(q1[0].tolist()), tuple(w1[0].tolist()), tuple(a1[0].tolist())
        return tuple(q[k].tolist()), tuple(omega[k].tolist()), tuple(alpha[k].tolist())

    def _block_times(self, i: int) -> np.ndarray:
        """Stream times (s) of frames ``i .. i + BLOCK_FRAMES - 1``."""
        return self._t0 + np.arange(i, i + self.BLOCK_FRAMES) / self._rate
