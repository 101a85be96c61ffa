"""The ``trajgen follow`` command: stream a plan that keyframes arriving on stdin change.

:class:`Follower` is the part that does not touch hardware: it turns JSON lines
into checked changes of an :class:`~trajgen.online.OnlineSpline` and wraps its
joint stream, recording what was streamed, when each change reached the stream
and what it cost. A thread reads and parses the lines; the streaming thread
builds, checks and makes each change in steps between its frames (each step a
fraction of a millisecond), so that no thread competes with the stream for the
interpreter. ``run_follow`` adds the bus, the servos and the report, as
``trajgen stream`` does.
"""

from __future__ import annotations

import importlib
import json
import math
import sys
import threading
import time
from collections import deque
from types import SimpleNamespace

import numpy as np

from trajgen import fast
from trajgen.cli import stream as stream_command
from trajgen.cli.common import EXIT_FAILED
from trajgen.errors import KeyframeFileError, KinematicsError
from trajgen.gimbal import GimbalKinematics
from trajgen.keyframes import check_keyframes
from trajgen.online import MODES, ChangeTooLate, OnlineSpline
from trajgen.path import Steps
from trajgen.sampling import sample_times
from trajgen.spline import BlendingSpline
from trajgen.stream import JointTrajectory, stream_frames

#: Time (s) from the frame being streamed when a line arrives to the change it
#: makes: room to build and check the new path, in steps between frames of the stream
#: (a few periods at 1 kHz; see bench/online_cost.py). `Follower` allows more where the
#: steps need it.
CHANGE_MARGIN_S = 0.05

#: Interpreter thread switch interval (s) while following (Python's default is 5 ms):
#: how long the streaming thread may wait for the thread that parses the lines.
SWITCH_INTERVAL_S = 1e-4

#: Frames of a new path checked at a time: evaluated in one step of a change, checked
#: in the next (each step about 0.25 ms of numpy work, mostly fixed costs per call).
CHECK_STEP_FRAMES = 200

LINE_KEYS = ("t", "in", "mode", "pan", "tilt", "roll", "quat")

FOLLOW_DESCRIPTION = f"""\
Stream the keyframe file's plan as `trajgen stream` does, and change it while it
runs from JSON lines on stdin, one keyframe per line:

  {{"in": 0.8, "pan": 20, "tilt": 5}}          reach this 0.8 s from now
  {{"t": 12.5, "quat": [1, 0, 0, 0]}}          ... at stream time 12.5 s
  {{"in": 1, "pan": -10, "mode": "extend"}}    after the keyframes still planned

"mode": "retarget" (the default) drops the keyframes still ahead and goes
through the new one instead; "extend" keeps them and adds the new one after
them. A change is built and checked in steps, one between two frames of the
stream, and starts {CHANGE_MARGIN_S:g} s after the frame being streamed when it is
begun (longer where the steps need it: at low rates, or for a keyframe far
ahead); its keyframe must lie at least 0.2 s after that. Each line is checked as a keyframe
file checks a keyframe, and the new path against the gimbal's joint limits and
gimbal-lock margin; a bad line is reported on stderr and skipped, and the
stream goes on. The path is C^k across every change (k from the file's
[spline] table) and holds at rest when the keyframes run out. At the end of
stdin the stream ends once the last keyframe is reached.

Bring-up, stop signals, safe stop and report are those of `trajgen stream`;
bring-up checks the whole range the joint limits allow against the servos'
installed limits. --virtual streams in real time (the lines do), unlike
`trajgen stream --virtual`, and ends with the torque report of what was streamed.

exit status: 0 ok, 1 stream fault or torque check failed, 2 bad input,
128 + the signal number when stopped by SIGINT, SIGTERM or SIGHUP (the servos
hold their last goal, or are released with --torque-off)."""


def register(subparsers) -> None:
    """Add the ``follow`` subcommand to an argparse ``subparsers``."""
    import argparse

    p = subparsers.add_parser(
        "follow",
        help="stream a plan that keyframes arriving on stdin (JSON lines) change",
        description=FOLLOW_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    stream_command.add_stream_arguments(p)
    p.set_defaults(func=run_follow)


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
    """

    def __init__(
        self,
        spline: OnlineSpline,
        rate_hz: float,
        kinematics: GimbalKinematics | None = None,
        *,
        margin_s: float = CHANGE_MARGIN_S,
        source: str = "stdin",
    ):
        self.spline = spline
        self.rate_hz = float(rate_hz)
        self.kinematics = GimbalKinematics() if kinematics is None else kinematics
        self.margin_s = float(margin_s)
        self.source = source
        self.latencies_s: list[float] = []
        self.change_costs_s: list[float] = []
        self.change_steps_s: list[float] = []
        self.keyframes: list[dict] = []
        self.skipped: list[str] = []
        self._frames: list = []
        self._pending: list[tuple[float, float]] = []  # (arrival, at) of changes not yet seen
        self._lock = threading.Lock()
        self._jobs: deque[_Job] = deque()  # changes for the streaming thread to build
        self._streaming = False
        self._last_q = None
        #: Why the stream ended early ("" if it did not).
        self.fault = ""

    # -- lines -------------------------------------------------------------

    def read(self, lines, *, echo=sys.stderr) -> None:
        """Feed every line of ``lines`` (an iterable of str), then close the plan.

        Bad lines are reported to ``echo`` and skipped.
        """
        try:
            for number, text in enumerate(lines, start=1):
                if not text.strip():
                    continue
                try:
                    self.feed(text, number)
                except (ValueError, TypeError) as e:
                    self.skipped.append(str(e))
                    print(f"trajgen: follow: {e} (line skipped)", file=echo, flush=True)
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
        mode, q, t, relative = self._parse(text, where)
        now = self._now()
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
            self.keyframes.append(
                {"line": number, "mode": mode, "t": t, "quat": q.tolist(), "at": at, "now": now}
            )
            return
        raise self._error(where, "the stream ran past three attempts to change it (busy?)")

    def _parse(self, text: str, where: str):
        try:
            entry = json.loads(text)
        except json.JSONDecodeError as e:
            raise self._error(where, f"invalid JSON: {e}") from None
        if not isinstance(entry, dict):
            raise self._error(where, f"expected a JSON object, got {text.strip()!r}")
        for key in entry:
            if key not in LINE_KEYS:
                raise self._error(where, f"unknown field '{key}' (known: {', '.join(LINE_KEYS)})")
        mode = entry.get("mode", "retarget")
        if mode not in MODES:
            raise self._error(where, f"field 'mode': expected one of {MODES}, got {mode!r}")
        if ("t" in entry) == ("in" in entry):
            raise self._error(where, "give exactly one of 't' (stream time) or 'in' (from now), s")
        keyframe = {k: v for k, v in entry.items() if k not in ("mode", "in")}
        keyframe["t"] = entry.get("t", entry.get("in"))
        t, q = check_keyframes([keyframe], f"{self.source}: {where}", minimum=1)
        return mode, q[0], float(t[0]), "in" in entry

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
        """One step of the oldest line's change, if any (dropped from the queue once done)."""
        with self._lock:
            job = self._jobs[0] if self._jobs else None
        if job is not None and job.step():
            with self._lock:
                self._jobs.popleft()

    def trajectory(self) -> JointTrajectory:
        """What :meth:`frames` yielded, as arrays."""
        f = self._frames
        return JointTrajectory(
            np.array([x.t for x in f]),
            np.array([x.q for x in f]).reshape(-1, 3),
            np.array([x.qd for x in f]).reshape(-1, 3),
            np.array([x.qdd for x in f]).reshape(-1, 3),
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
    ``[spline] method`` is "smooth" gets the blending spline's defaults).

    Raises
    ------
    ValueError
        If the file's [spline] table asks for something the online plan does not
        do (a boundary other than "rest", k above 3) or its second keyframe is
        closer than 0.2 s to the first.
    """
    options = dict(kf.spline_options)
    options.pop("knots", None)  # the smooth spline's knot choice; follow plans the blending one
    if options.pop("boundary", "rest") != "rest":
        raise ValueError(f"{kf.path}: [spline] boundary: follow needs 'rest'")
    if options.get("k", 2) > 3:
        raise ValueError(f"{kf.path}: [spline] k: follow takes k in 1..3, got {options['k']}")
    spline = OnlineSpline(kf.quats[0], kf.times[0], **options)
    try:
        spline.extend(kf.quats[1:], kf.times[1:], at=kf.times[0])
    except ValueError as e:
        raise ValueError(f"{kf.path}: {e}") from None
    return spline


def run_follow(args) -> int:
    """Run ``trajgen follow`` on the lines of stdin; returns the exit status."""
    return follow(args, sys.stdin)[0]


def follow(args, lines):
    """``trajgen follow`` with keyframe lines from ``lines``: the stream command's
    stages (plan, open, bring up, stream, report, under the stop signals) with the
    file's plan streamed as an :class:`~trajgen.online.OnlineSpline` that the lines change.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``trajgen follow`` options.
    lines : iterable of str, or callable
        The JSON lines (read on a thread of their own while the stream runs),
        or a function of the :class:`Follower` that returns them (to time them
        against the stream).

    Returns
    -------
    status : int
        Exit status.
    follower : Follower or None
        What was streamed and the changes (None if the input was refused).
    report : TorqueReport or None
        With --virtual, the torque report of what was streamed.
    """
    from trajgen.drivers.clock import WALL_CLOCK

    made = {}

    def make_plan(args):
        p = stream_command.plan(args)
        made["follower"] = Follower(online_spline(p.kf), p.rate_hz)
        load_compiled_kernel()  # before the stream starts: evaluations then run compiled
        if p.kf.method != "blending":
            print(
                f"trajgen: note: {p.kf.path}: follow plans with the blending spline (changes "
                f"are spliced onto it), not the file's [spline] method = {p.kf.method!r}",
                file=sys.stderr,
            )
        return p

    def bring_up(bus, args, p):
        # The stream starts where the servos are and may go anywhere the joint limits
        # allow: bring-up checks that range against the servos' installed limits.
        corners = np.array(made["follower"].kinematics.limits_rad).T  # (2, 3)

        def envelope(present):
            return SimpleNamespace(
                t=np.array([0.0, np.nan, np.nan]), q=np.vstack([present, corners])
            )

        return stream_command.bring_up_servos(bus, args, p, plan_from=envelope)

    def stream(bus, args, p, setup, outcome):
        from trajgen.sim.lead import live_frames

        follower = made["follower"]
        source = lines(follower) if callable(lines) else lines

        threading.Thread(target=follower.read, args=(source,), daemon=True).start()
        try:
            stream_command.stream_plan(
                bus,
                args,
                p,
                setup,
                outcome,
                # Led goals from the live plan's own q, qd, qdd, inside the range
                # bring-up checked (the joint limits).
                frames=live_frames(
                    follower.frames(start=p.joints.to_rad(setup.present_ticks)),
                    p.gimbal,
                    p.lead,
                    p.rate_hz,
                    np.array(follower.kinematics.limits_rad),
                ),
                clock=WALL_CLOCK,  # the lines arrive in real time, with --virtual too
            )
        finally:
            p.trajectory = follower.trajectory()  # what was streamed, for the report
            print(follower.format())
        if follower.fault:
            outcome.stopped_by = f"a frame the gimbal cannot take: {follower.fault}"
            outcome.status = EXIT_FAILED

    def extra():
        return {"follow": made["follower"].summary()} if "follower" in made else {}

    outcome = stream_command.Outcome()
    status = stream_command.run_stages(args, outcome, (make_plan, bring_up, stream), extra)
    return status, made.get("follower"), outcome.torque_report
