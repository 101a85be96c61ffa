"""``follow``'s planning in a process of its own, the stream fed by a ring of frames.

:class:`PlannedFrames` forks a planner process that runs a
:class:`~trajgen.follower.Follower`: it reads and parses the keyframe lines, builds each
change whole (no slicing into steps between frames: no stream waits on it), evaluates the
frames (and their led goals, ``trajgen.lead``) and puts them into a
:class:`~trajgen.frame_ring.FrameRing` at most ``depth`` frames ahead of the frame being
streamed. The streaming process only takes frames from the ring: the lines, the
planning and the garbage they make no longer hold its interpreter. A frame not in the
ring at its deadline is waited for (a late frame or a stall, as a slow plan in process
makes); no frame is ever made up.

A line's change time counts from the last frame the planner made, up to ``depth``
frames after the one being streamed: ``DEPTH_S`` is added to every line's latency
(docs/tracking_targets.md).
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time

import numpy as np

from trajgen.frame_ring import FrameRing, RingEmpty

from .errors import DriverError
from .priority import PLANNER_FIFO_PRIORITY, claim_core
from .signals import STOP_SIGNALS

#: How far (s) the planner runs ahead of the frame being streamed: room for a change's
#: whole build (2.3-2.6 ms CPU for an untimed target, bench/tracker_cost.py) and the
#: host's scheduling hiccups, well inside a change's own lead (``CHANGE_MARGIN_S``).
DEPTH_S = 0.02

#: How long (s) the stream's process waits for the planner's last words at the end.
GOODBYE_S = 10.0


class PlannerFailed(DriverError):
    """The planner process failed or died: the stream ends in the safe stop."""


def depth_frames(rate_hz: float) -> int:
    """Frames the planner may be ahead: ``DEPTH_S`` at ``rate_hz``, two at least."""
    return max(2, math.ceil(DEPTH_S * rate_hz - 1e-9))


class PlannedFrames:
    """A follower's frames made in a forked planner process; iterate once.

    Parameters
    ----------
    follower : trajgen.follower.Follower
        Copied into the planner by the fork; what the planner recorded (keyframes
        taken, lines refused, costs, ``fault``) is copied back at the end, and its
        latencies are measured here, to the frame that leaves this iterator.
        Its ``spline`` here is not changed.
    lines : iterable of str or bytes, or callable
        As for ``Session.follow`` (read in the planner; refused lines' messages are
        the follower's ``on_skip``'s there, at once).
    start : array_like, shape (n,), optional
        As for ``Follower.frames``.
    lead : callable, optional
        ``lead(frames) -> frames with goals`` (``trajgen.sim.lead.Leader.frames``),
        run in the planner; its ``lift``, if any, is this iterator's once the first
        frame is taken.

    Raises
    ------
    PlannerFailed
        While iterating: the planner raised (its message) or died.
    """

    def __init__(self, follower, lines, start=None, *, lead=None):
        self.follower = follower
        self.rate_hz = follower.rate_hz
        self.lift = None
        self.ring = FrameRing(
            follower.kinematics.n_joints, depth_frames(self.rate_hz), goals=bool(lead)
        )
        self._times: list[float] = []  # time.monotonic() each frame left the iterator
        self._done = False
        self._conn, write = _pipe()
        parent = os.getpid()
        self.pid = os.fork()
        if self.pid == 0:  # the planner
            self._conn.close()
            _plan(follower, lines, start, lead, self.ring, write, parent)  # never returns
        write.close()

    def __iter__(self):
        ring, follower = self.ring, self.follower
        wait = 0.1 / self.rate_hz
        while True:
            try:
                frame = ring.take()
            except RingEmpty:
                if ring.ended:
                    try:
                        frame = ring.take()  # the last one, put just before the end
                    except RingEmpty:
                        self._finish()
                        return
                else:
                    self._check_alive()
                    time.sleep(wait)
                    continue
            if not self._times:  # the planner said what comes before the first frame
                self.lift = self._receive("lift")
            self._times.append(time.monotonic())
            follower._frames.append(frame)
            yield frame

    def close(self) -> None:
        """Stop the planner (if it still runs): it is asked to end and hand over what it
        recorded; terminated if it does not within ``GOODBYE_S``; always reaped."""
        try:
            self.ring.stop()
            if not self._done:
                try:
                    self._finish()
                except PlannerFailed:
                    pass  # the stream ended already; nothing more of it to tell
        finally:
            self._reap()

    # -- between the processes -----------------------------------------------

    def _receive(self, kind: str):
        """The planner's next message, which must be ``kind``; its payload."""
        if not self._conn.poll(GOODBYE_S):
            raise PlannerFailed(f"the planner process sent nothing for {GOODBYE_S:g} s")
        try:
            message = self._conn.recv()
        except EOFError:
            raise PlannerFailed("the planner process ended without its records") from None
        if message[0] == "failed":
            self._results(message[2])
            raise PlannerFailed(f"the planner process failed: {message[1]}")
        if message[0] != kind:
            raise PlannerFailed(f"the planner process sent {message[0]!r}, not {kind!r}")
        return message[1]

    def _finish(self) -> None:
        """The planner's records, once it put its last frame or was asked to stop."""
        self._done = True
        self._results(self._receive("done"))

    def _results(self, records: dict) -> None:
        f = self.follower
        for name, value in records.items():
            setattr(f, name, value)
        # Latency: from a line's arrival to the first frame after its change leaving here.
        t = np.array([frame.t for frame in f._frames])
        f.latencies_s = [
            self._times[i] - arrival
            for arrival, at in f.arrivals
            if (i := int(np.searchsorted(t, at, side="right"))) < len(t)
        ]

    def _check_alive(self) -> None:
        """Raise if the planner exited with its frames not all put (a crash, a kill)."""
        if self.pid is not None and os.waitpid(self.pid, os.WNOHANG)[0]:
            self.pid = None  # reaped
            if not self.ring.ended:
                raise PlannerFailed("the planner process died before its last frame")

    def _reap(self) -> None:
        """Wait for the planner to exit (``GOODBYE_S`` at most, then kill it)."""
        if self.pid is None:
            return
        pid, self.pid = self.pid, None
        deadline = time.monotonic() + GOODBYE_S
        while not os.waitpid(pid, os.WNOHANG)[0]:
            if time.monotonic() > deadline:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                return
            time.sleep(0.001)


def _pipe():
    from multiprocessing import Pipe  # lazily: `import trajgen` stays numpy-only

    return Pipe(duplex=False)


#: The planner's name in ``ps`` and ``/proc/PID/comm`` (Linux).
PLANNER_NAME = b"trajgen-plan"


def _name_and_tie(parent: int) -> None:
    """On Linux: name this process ``PLANNER_NAME`` and have the kernel send it SIGTERM
    when the stream's thread that forked it ends (``prctl``); elsewhere nothing (the
    planner then notices its parent gone while it waits for room in the ring)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(15, PLANNER_NAME, 0, 0, 0)  # PR_SET_NAME
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


#: What the planner's Follower hands back at the end (attributes of ``Follower``).
RECORDS = ("keyframes", "skipped", "change_costs_s", "change_steps_s", "arrivals", "fault")


def _plan(follower, lines, start, lead, ring: FrameRing, conn, parent: int) -> None:
    """The planner process: the follower's frames into ``ring`` until they end, the
    stream's process stops it (``FrameRing.stop``) or goes away; then its records to
    ``conn``, and exit (``os._exit``: nothing of the parent's runs here at exit)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the stream's to handle
    for s in STOP_SIGNALS[1:]:
        signal.signal(s, signal.SIG_DFL)  # the stream's process may terminate this one
    _name_and_tie(parent)
    # The stream preempts it; the host's other work does not starve the ring (the reading
    # thread it starts keeps the normal class: SCHED_RESET_ON_FORK). Not permitted: as is.
    claim_core(PLANNER_FIFO_PRIORITY)
    if os.getppid() != parent:  # gone before the tie was made
        os._exit(1)
    status = 0
    try:
        follower.step_share = math.inf  # each change whole: no stream waits on this thread
        source = lines(follower) if callable(lines) else lines
        threading.Thread(target=follower.read, args=(source,), daemon=True).start()
        frames = follower.frames(start=start)
        if lead is not None:
            frames = lead(frames)
        nap = 0.5 / follower.rate_hz
        for k, frame in enumerate(frames):
            while not ring.room() and not ring.stopped:
                if os.getppid() != parent:  # the stream's process is gone
                    os._exit(1)
                time.sleep(nap)
            if ring.stopped:
                break
            ring.put(frame)
            if k == 0:  # after the frame: the stream's process reads this once it took it
                conn.send(("lift", getattr(frames, "lift", None)))
        ring.end()  # first: the stream's process reads what follows once it sees the end
        conn.send(("done", {name: getattr(follower, name) for name in RECORDS}))
    except BaseException as e:
        status = 1
        ring.end()
        records = {name: getattr(follower, name) for name in RECORDS}
        conn.send(("failed", f"{type(e).__name__}: {e}", records))
    finally:
        conn.close()
        os._exit(status)
