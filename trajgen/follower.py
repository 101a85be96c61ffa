"""Following live keyframes: an online plan that JSON lines change while it streams.

:class:`Follower` turns keyframe lines (:mod:`trajgen.keyframe_lines`) into
checked changes of an :class:`~trajgen.online.OnlineSpline` and wraps its joint
stream, recording what was streamed, when each change reached the stream and
what it cost. One thread reads and parses the lines (:meth:`Follower.read`); the
streaming thread builds, checks and makes each change in steps between its
frames (:meth:`Follower.frames`; each step a fraction of a millisecond), so that
no thread competes with the stream for the interpreter. Numpy only: the servos
are ``trajgen.drivers.session.Session.follow``'s, a simulation anything that
takes the frames.
"""

from __future__ import annotations

import importlib
import math
import sys
import threading
import time
from collections import deque

import numpy as np

from . import fast
from .errors import KeyframeFileError, KinematicsError
from .gimbal import GimbalKinematics
from .keyframe_lines import MAX_LINE_BYTES, TRACK, decode_line, parse_line
from .online import ChangeTooLate, OnlineSpline
from .path import Steps
from .sampling import sample_times
from .spline import BlendingSpline
from .stream import JointTrajectory, stream_frames
from .tracker import Tracker

#: Time (s) from the frame being streamed when a line arrives to the change it
#: makes: room to build and check the new path, in steps between frames of the stream
#: (a few periods at 1 kHz; see bench/online_cost.py). `Follower` allows more where the
#: steps need it.
CHANGE_MARGIN_S = 0.05

#: Frames an untimed target's change is given before its ``at`` (at least
#: ``margin_s``): the tracker's search takes 16-26 steps (bench/tracker_cost.py: the
#: target, the motion in progress, the candidates' grid, a joint each, the profile, its
#: frames, the envelope's inverse dynamics a body at a time, the change), one a frame
#: or more (``STEP_SHARE``); doubled on each new attempt.
TARGET_STEPS = 20

#: Share of a frame period the streaming thread spends on changes' steps between two
#: frames: one step at least, more while the next (as long as the last) still fits.
STEP_SHARE = 0.25

#: Interpreter thread switch interval (s) while following (Python's default is 5 ms):
#: how long the streaming thread may wait for the thread that parses the lines.
SWITCH_INTERVAL_S = 1e-4

#: Frames of a new path checked at a time: evaluated in one step of a change, checked
#: in the next (each step about 0.25 ms of numpy work, mostly fixed costs per call).
CHECK_STEP_FRAMES = 200


class _Job(Steps):
    """A line's change as a generator of steps, run by whichever thread gets to it;
    a refused line's error is kept for the reading thread."""

    def __init__(self, steps, where: str):
        super().__init__(steps)
        self.where = where  # "line N", for messages
        self.finished = threading.Event()
        self.error: Exception | None = None
        self.busy_s = 0.0  # time (s) spent in its steps
        self.longest_s = 0.0  # its longest step (s)

    def cancel(self, error: Exception) -> None:
        """End it unrun, with ``error`` for the reading thread."""
        self._steps.close()
        self.error, self.done = error, True
        self.finished.set()

    def step(self) -> bool:
        started = time.perf_counter()
        try:
            return super().step()
        except Exception as e:
            self.error, self.done = e, True
            if not isinstance(e, (ValueError, TypeError)):
                raise  # not a refused line but a fault: it ends the stream too
            return True
        finally:
            spent = time.perf_counter() - started
            self.busy_s += spent
            self.longest_s = max(self.longest_s, spent)
            if self.done:
                self.finished.set()


class Follower:
    """An online plan fed with keyframes as JSON lines, streamed as joint frames.

    Parameters
    ----------
    spline : OnlineSpline
        The plan; it is changed in place.
    rate_hz : float
        Stream rate (Hz).
    kinematics : GimbalKinematics, optional
        Joint limits and gimbal-lock margin every new path is checked against.
    margin_s : float, optional
        Time (s) from the frame being streamed to a change.
    source : str, optional
        Name of the line source in messages.
    on_skip : callable, optional
        Called (on the reading thread) with the message of each line refused;
        the line is skipped and the stream goes on.
    limits : array_like, shape (3, 3), or JointLimits, optional
        Per-joint speed, acceleration, jerk bounds for untimed targets (lines with
        neither ``t`` nor ``in``), which a :class:`~trajgen.tracker.Tracker` reaches as
        early as these allow; see there. Default: none.
    envelope : callable, optional
        ``envelope(q, qd, qdd) -> bool (N,)``: where the servos can make the motion
        (e.g. ``trajgen.sim.check.envelope_check``), kept by untimed targets too.

    Attributes
    ----------
    latencies_s : list of float
        Per accepted line: wall time (s) from its arrival to the first frame
        that reflects it leaving :meth:`frames` (the servo gets it within one
        period after).
    change_costs_s : list of float
        Per accepted line: time (s) to build and check the change (all its steps).
    change_steps_s : list of float
        Per accepted line: its longest step (s), what the streaming thread paid
        between two frames.
    keyframes : list of dict
        Accepted keyframes: line number, mode, ``t``, ``quat``, ``at`` (the
        change time) and ``now`` (stream time when the line arrived).
    skipped : list of str
        Messages of the lines refused.
    arrivals : list of tuple
        Per accepted line: ``(arrival, at)``, its arrival (``time.monotonic()``, s) and
        its change time (stream s), for latencies measured where the frames are sent
        (``trajgen.follow_process``).
    step_share : float
        Share of a period :meth:`frames` spends on changes' steps between two frames
        (``STEP_SHARE``; ``math.inf``: every queued change whole, where no stream waits
        on this thread, as in ``trajgen.follow_process``).
    """

    def __init__(
        self,
        spline: OnlineSpline,
        rate_hz: float,
        kinematics: GimbalKinematics | None = None,
        *,
        margin_s: float = CHANGE_MARGIN_S,
        source: str = "stdin",
        on_skip=None,
        limits=None,
        envelope=None,
    ):
        self.spline = spline
        self.rate_hz = float(rate_hz)
        self.kinematics = GimbalKinematics() if kinematics is None else kinematics
        self.margin_s = float(margin_s)
        self.source = source
        self.on_skip = on_skip
        self.latencies_s: list[float] = []
        self.change_costs_s: list[float] = []
        self.change_steps_s: list[float] = []
        self.keyframes: list[dict] = []
        self.skipped: list[str] = []
        self.arrivals: list[tuple[float, float]] = []
        self.step_share = STEP_SHARE
        self._frames: list = []
        self._pending: list[tuple[float, float]] = []  # (arrival, at) of changes not yet seen
        self._lock = threading.Lock()
        self._jobs: deque[_Job] = deque()  # changes for the streaming thread to build
        self._streaming = False
        self._last_q = None
        #: Why the stream ended early ("" if it did not).
        self.fault = ""
        #: Untimed targets' planner: each such line is a retarget at the earliest arrival.
        self.tracker = Tracker(
            spline, limits, kinematics=self.kinematics, envelope=envelope, rate_hz=rate_hz
        )

    # -- lines -------------------------------------------------------------

    def read(self, lines) -> None:
        """Feed every line of ``lines``, then close the plan.

        Parameters
        ----------
        lines : iterable of str or bytes
            The lines, e.g. ``keyframe_lines.capped_lines(sys.stdin.buffer)``:
            bytes are decoded here, and a line longer than ``MAX_LINE_BYTES`` is
            refused without being parsed.

        Notes
        -----
        Lines are numbered as they come (blank ones too), so messages name the
        line a person counts in the input.
        """
        try:
            for number, line in enumerate(lines, start=1):
                try:
                    text = decode_line(line, self._where(number), MAX_LINE_BYTES)
                    if text.strip():
                        self.feed(text, number)
                except (ValueError, TypeError) as e:
                    self.skipped.append(str(e))
                    if self.on_skip is not None:
                        self.on_skip(str(e))
        finally:
            self.spline.close()

    def feed(self, text: str, number: int = 1) -> None:
        """Apply one JSON line to the plan; returns once the change is made.

        The line is parsed here; while the stream runs, :meth:`frames` builds and
        checks the change in steps, each between two frames (else it is built here).

        Raises
        ------
        KeyframeFileError
            For a line that is not a keyframe (``"{source}: line N: ..."``).
        ValueError
            For a keyframe the plan refuses (too close, before the last one for
            ``"extend"``, outside the joint limits or near gimbal lock).
        """
        arrival = time.monotonic()
        where = f"line {number}"
        mode, q, t, relative = parse_line(text, self._where(number), self.kinematics.sequence)
        now = self._now()
        if mode == TRACK:
            job = _Job(self._target_steps(q, where, arrival, now, number), where)
        else:
            t = now + t if relative else t
            self._change_time(t, now, where)  # now, so that a line too late fails fast
            job = _Job(self._change_steps(mode, q, t, where, arrival, now, number), where)
        with self._lock:
            streaming = self._streaming
            if streaming:
                self._jobs.append(job)
        if not streaming:
            job.finish()
        job.finished.wait()
        if job.error is not None:
            raise job.error
        self.change_costs_s.append(job.busy_s)
        self.change_steps_s.append(job.longest_s)

    def _change_time(self, t: float, now: float, where: str) -> float:
        """The change time ``at`` (s) for a keyframe at ``t`` (s): ``margin_s`` after
        the last frame streamed, or more where the change's steps need longer; raises
        if the keyframe is too close to it."""
        steps = 2 + 2 * math.ceil((t - now) * self.rate_hz / CHECK_STEP_FRAMES)
        at = max(self.spline.committed, self.spline.t_start)
        at += max(self.margin_s, (steps + 1) / self.rate_hz)
        at = max(at, self.spline.last_change_at)  # a change may not precede the last
        if t - at < self.spline.min_lead_s:
            raise self._error(
                where,
                f"keyframe at t = {t:.4g} s is {t - now:.3g} s ahead of the stream "
                f"(t = {now:.4g} s): it must be at least "
                f"{self.spline.min_lead_s + at - now:.3g} s ahead",
            )
        return at

    def _change_steps(self, mode, q, t, where, arrival, now, number):
        """A line's change as a generator of steps, each of which the streaming thread
        runs between two frames: build it (:meth:`OnlineSpline.prepare_steps`); check
        it, ``CHECK_STEP_FRAMES`` frames of the new path per two steps; make it."""
        for _ in range(3):
            at = self._change_time(t, self._now(), where)
            try:
                change = yield from self.spline.prepare_steps(mode, q[None], [t], at=at)
            except ChangeTooLate:
                continue
            except ValueError as e:  # a keyframe the plan refuses
                raise self._error(where, str(e)) from None
            yield
            try:
                yield from self._check_steps(change.path, at)
                self.spline.apply(change)
            except ChangeTooLate:
                continue  # the stream passed `at`, or another change came: again, later
            except ValueError as e:  # KinematicsError
                raise self._error(where, str(e)) from None
            with self._lock:
                self._pending.append((arrival, at))
            self.arrivals.append((arrival, at))
            self.keyframes.append(
                {"line": number, "mode": mode, "t": t, "quat": q.tolist(), "at": at, "now": now}
            )
            return
        raise self._error(where, "the stream ran past three attempts to change it (busy?)")

    def _target_steps(self, target, where, arrival, now, number):
        """An untimed target line's change, in steps: the tracker's search for the earliest
        arrival (each candidate checked against the limits, the lock margin and the joint
        limits on the stream's grid), made at ``margin_s`` or more after the stream."""
        for attempt in range(3):
            # room for the search's steps, one a frame (more on each attempt)
            at = max(self.spline.committed, self.spline.t_start)
            at += max(self.margin_s, (TARGET_STEPS * 2**attempt + 1) / self.rate_hz)
            try:
                result = yield from self.tracker.set_target_steps(
                    target["quat"],
                    look_at=target["look_at"],
                    max_speed=target["max_speed"],
                    at=at,
                )
            except ChangeTooLate:
                continue  # the stream passed `at`, or another change came: again, later
            except ValueError as e:  # KinematicsError: no path keeps the limits
                raise self._error(where, str(e)) from None
            if result.changed:
                at = result.at  # later than asked where no arrival from there kept the limits
                with self._lock:
                    self._pending.append((arrival, at))
                    self.arrivals.append((arrival, at))
                self.keyframes.append(
                    {
                        "line": number,
                        "mode": TRACK,
                        "t": result.arrival,
                        "quat": self.kinematics.forward(result.goal).tolist(),
                        "at": at,
                        "now": now,
                        "clamped": result.clamped,
                    }
                )
            return
        raise self._error(where, "the stream ran past three attempts to change it (busy?)")

    def _where(self, number: int) -> str:
        return f"{self.source}: line {number}"

    def _error(self, where: str, problem: str) -> KeyframeFileError:
        return KeyframeFileError(f"{self.source}: {where}: {problem}")

    def _now(self) -> float:
        committed = self.spline.committed
        return self.spline.t_start if committed == -math.inf else committed

    def _check_steps(self, path, at: float):
        """The check of a new path, in steps: joint limits and gimbal lock at the stream's
        frame times after ``at`` to its end (the frame at ``at`` is the old path's,
        checked already), ``CHECK_STEP_FRAMES`` frames at a time, evaluated in one step
        and checked in the next (each step's cost is mostly its numpy calls).

        Raises
        ------
        KinematicsError
            At the first frame near gimbal lock or outside a limit.
        """
        t = sample_times(at, max(path.t_end, at + 1.0 / self.rate_hz), self.rate_hz)[1:]
        start = self._last_q
        for i in range(0, len(t), CHECK_STEP_FRAMES):
            chunk = t[i : i + CHECK_STEP_FRAMES]
            q = path.evaluate(chunk, max_order=0).q
            yield
            start = self.kinematics.inverse(q, chunk, start=start)[-1]
            if i + CHECK_STEP_FRAMES < len(t):
                yield

    # -- frames ------------------------------------------------------------

    def frames(self, start=None):
        """The joint stream (``trajgen.stream.stream_frames`` of the plan), recorded.

        Parameters
        ----------
        start : array_like, shape (3,), optional
            Joint angles whose 2 pi branch the first frame's pan and roll take.
        """
        frames = stream_frames(self.spline, self.rate_hz, self.kinematics, start=start)
        # Lines are parsed on the reading thread, which holds the interpreter meanwhile:
        # let the streaming thread take it back within a fraction of a period.
        switch = sys.getswitchinterval()
        sys.setswitchinterval(min(switch, SWITCH_INTERVAL_S))
        with self._lock:
            self._streaming = True
        try:
            while True:
                self._step()
                try:
                    frame = next(frames)
                except StopIteration:
                    return
                except KinematicsError as e:
                    # Every change was checked on the stream's grid, so this is a path that
                    # passed its check between samples: end here, the servos hold the last goal.
                    self.fault = str(e)
                    return
                with self._lock:
                    self._last_q = frame.q
                    if self._pending:
                        now = time.monotonic()
                        seen = [p for p in self._pending if frame.t > p[1]]
                        self.latencies_s += [now - arrival for arrival, _ in seen]
                        self._pending = [p for p in self._pending if p not in seen]
                self._frames.append(frame)
                yield frame
        finally:
            sys.setswitchinterval(switch)
            with self._lock:
                self._streaming, jobs = False, list(self._jobs)
                self._jobs.clear()
            for job in jobs:  # the stream ended: those lines change nothing
                job.cancel(self._error(job.where, "the stream ended before its change was made"))

    def _step(self) -> None:
        """Steps of the oldest lines' changes, if any (each dropped from the queue once
        done): one, and more while ``step_share`` of a period leaves room for another."""
        budget = self.step_share / self.rate_hz
        start = time.perf_counter()
        while True:
            with self._lock:
                job = self._jobs[0] if self._jobs else None
            if job is None:
                return
            began = time.perf_counter()
            if job.step():
                with self._lock:
                    self._jobs.popleft()
            now = time.perf_counter()
            if 2.0 * now - began - start >= budget:  # spent so far + the last step's length
                return

    def trajectory(self) -> JointTrajectory:
        """What :meth:`frames` yielded, as arrays."""
        f, n = self._frames, self.kinematics.n_joints
        return JointTrajectory(
            np.array([x.t for x in f]),
            np.array([x.q for x in f]).reshape(-1, n),
            np.array([x.qd for x in f]).reshape(-1, n),
            np.array([x.qdd for x in f]).reshape(-1, n),
            self.rate_hz,
        )

    # -- summary -----------------------------------------------------------

    def summary(self) -> dict:
        """Counts, latency, change cost and longest step (s; p50 and max), accepted keyframes."""

        def stats(x):
            return {"p50": float(np.median(x)), "max": float(np.max(x)), "n": len(x)} if x else None

        return {
            "accepted": len(self.keyframes),
            "skipped": len(self.skipped),
            "latency_s": stats(self.latencies_s),
            "change_cost_s": stats(self.change_costs_s),
            "change_step_s": stats(self.change_steps_s),
            "keyframes": self.keyframes,
            "skipped_lines": self.skipped,
        }

    def format(self) -> str:
        """A line for a terminal."""
        s = self.summary()

        def ms(d):
            return (
                "n/a" if d is None else f"p50 {1e3 * d['p50']:.1f} ms, max {1e3 * d['max']:.1f} ms"
            )

        return (
            f"follow: {s['accepted']} keyframes accepted, {s['skipped']} lines skipped; "
            f"line to frame {ms(s['latency_s'])}; change cost {ms(s['change_cost_s'])} "
            f"in steps between frames, the longest {ms(s['change_step_s'])}"
        )


def load_compiled_kernel() -> bool:
    """Load the blending spline's compiled kernel (:mod:`trajgen.fast`) now, where numba
    is installed and ``TRAJGEN_NUMBA`` is not 0; returns whether it is loaded.

    Then every later evaluation of the blending spline runs compiled, those of the
    stream's blended frames and of the old path where a change splices onto it (a step
    the streaming thread runs between two frames): a few microseconds per sample
    instead of about 0.5 ms per call (bench/online_cost.py). Loading costs a second or
    so (longer the first time, while numba fills its cache).
    """
    if not fast.ENABLED:
        return False
    try:
        importlib.import_module("trajgen.fast_kernel")
    except ImportError:  # a broken numba install: numpy evaluates, as without numba
        return False
    BlendingSpline([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [1.0, 0, 0, 0]], [0.0, 1.0, 2.0]).evaluate(0.5)
    return True


def online_spline(kf) -> OnlineSpline:
    """The plan of a keyframe file as an OnlineSpline: at rest at its first keyframe,
    extended by the others (the same path as the file's BlendingSpline; a file whose
    ``[spline] method`` is "smooth" gets the blending spline's defaults). A file
    fitted by ``trajgen fit`` (a ``[timing]`` table) is played as fitted
    (:meth:`OnlineSpline.from_path`: its frames are ``trajgen stream``'s until a
    change; a retarget splices onto it, an extend goes on after its end).

    Raises
    ------
    KeyframeFileError
        If the file's [spline] table asks for something the online plan does not
        do (a boundary other than "rest", k above 3) or its second keyframe is
        closer than 0.2 s to the first.
    """
    if getattr(kf, "timing", None) is not None:  # a file retimed by `trajgen fit`
        return OnlineSpline.from_path(kf.spline())
    options = dict(kf.spline_options)
    options.pop("knots", None)  # the smooth spline's knot choice; follow plans the blending one
    if options.pop("boundary", "rest") != "rest":
        raise KeyframeFileError(f"{kf.path}: [spline] boundary: follow needs 'rest'")
    if options.get("k", 2) > 3:
        raise KeyframeFileError(
            f"{kf.path}: [spline] k: follow takes k in 1..3, got {options['k']}"
        )
    spline = OnlineSpline(kf.quats[0], kf.times[0], **options)
    try:
        spline.extend(kf.quats[1:], kf.times[1:], at=kf.times[0])
    except ValueError as e:
        raise KeyframeFileError(f"{kf.path}: {e}") from None
    return spline
