"""The joint stream: the one thing the drivers and the simulator consume.

A stream is a sequence of frames at a fixed rate, each ``(t, q, qd, qdd)`` for
the gimbal's three joints (pan, tilt, roll), in s, rad, rad/s, rad/s^2.
Plan it offline as arrays with :func:`plan_joint_trajectory`, or produce it
online, one frame per control cycle, with :func:`stream_frames`; both give the
same values.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from trajgen.frame_eval import FrameKinematics, SmoothFrames
from trajgen.gimbal import JOINT_NAMES, GimbalKinematics, as_angles  # noqa: F401 (JOINT_NAMES re-exported)
from trajgen.path import Steps
from trajgen.sampling import sample_times
from trajgen.smooth import SmoothSpline


@dataclass(frozen=True)
class JointFrame:
    """One control cycle's setpoint.

    Attributes
    ----------
    index : int
        Frame number from 0.
    t : float
        Time (s) from the start of the trajectory.
    q, qd, qdd : ndarray, shape (n,)
        Joint angle (rad), velocity (rad/s), acceleration (rad/s^2), in
        ``JOINT_NAMES`` order (the kinematics' ``joints`` for other axes): the plan.
    goal : ndarray, shape (3,), or None
        The goal to send (rad), led ahead of ``q`` by the servos' lag
        (``trajgen.lead``); None: send ``q``.
    """

    index: int
    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    goal: np.ndarray | None = None


@dataclass(frozen=True)
class JointTrajectory:
    """A planned joint stream as arrays (plan offline) and as frames (stream online).

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times (s), ``t[i] = t[0] + i / rate_hz`` except that the last
        sample is at the trajectory's end time.
    q, qd, qdd : ndarray, shape (N, n)
        Joint angles (rad, unwrapped), velocities (rad/s), accelerations (rad/s^2),
        one column per joint (3 for the default pan-tilt-roll).
    rate_hz : float
        Stream rate (Hz).
    goal : ndarray, shape (N, 3), or None
        The goals to send (rad), led ahead of ``q`` (``trajgen.lead``); None:
        send ``q``.
    lift : trajgen.lift.Lift or None
        Frames to send before the first while ``q[0]`` is held (the model
        lead's static term brought in, ``trajgen.lift``); None: none. Iterating
        the trajectory yields its own frames only.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    rate_hz: float
    goal: np.ndarray | None = None
    lift: object = None

    def __len__(self) -> int:
        return len(self.t)

    def __iter__(self) -> Iterator[JointFrame]:
        goal = self.goal
        for i in range(len(self.t)):
            yield JointFrame(
                i,
                float(self.t[i]),
                self.q[i],
                self.qd[i],
                self.qdd[i],
                None if goal is None else goal[i],
            )

    @property
    def duration_s(self) -> float:
        """Time (s) from the first frame to the last."""
        return float(self.t[-1] - self.t[0])


def plan_joint_trajectory(
    spline, rate_hz: float, kinematics: GimbalKinematics | None = None, *, start=None
) -> JointTrajectory:
    """Plan the joint stream of an orientation path offline, as arrays.

    Samples the path at ``rate_hz`` from ``t_start`` to ``t_end`` inclusive
    (:func:`trajgen.sampling.sample_times`), solves the inverse kinematics
    (pan and roll unwrapped) and converts the space-frame angular velocity and
    acceleration into joint rates exactly (:meth:`GimbalKinematics.joint_rates`).

    Parameters
    ----------
    spline : spline-like
        Anything with ``t_start``, ``t_end`` (s) and ``evaluate(t, max_order=2)``
        returning ``Samples(t, q, omega, alpha, jerk)`` with ``q`` (M, 4) and
        space-frame ``omega``, ``alpha`` (M, 3): a ``BlendingSpline`` or a
        ``trajgen.compare`` method.
    rate_hz : float
        Stream rate (Hz), > 0.
    kinematics : GimbalKinematics, optional
        Axes, joint limits and gimbal-lock margin; default ``GimbalKinematics()``.
        For a two-axis gimbal the joints point its look axis along the path's.
    start : array_like, shape (n,), optional
        Joint angles (rad) whose 2 pi branch the first frame's pan and roll
        take, e.g. the servos' present position.

    Returns
    -------
    JointTrajectory
        ``t`` (M,), ``q``, ``qd``, ``qdd`` (M, 3) in s, rad, rad/s, rad/s^2.

    Raises
    ------
    KinematicsError
        If the path comes near gimbal lock or leaves the joint limits (the
        message names the time, joint, angle and limit).
    TypeError
        If ``spline`` lacks the spline protocol or ``rate_hz`` is not a number.
    ValueError
        If ``rate_hz`` is not > 0 or ``start`` is not (n,).
    """
    kin, t, start = _prepare(spline, rate_hz, kinematics, start)
    samples = spline.evaluate(t, max_order=2)
    q = kin.inverse(samples.q, t, start=start)
    qd, qdd = kin.joint_rates(q, samples.omega, samples.alpha)
    return JointTrajectory(t, q, qd, qdd, float(rate_hz))


def stream_frames(
    spline, rate_hz: float, kinematics: GimbalKinematics | None = None, *, start=None
) -> Iterator[JointFrame]:
    """The joint stream produced online: one frame per ``next()``.

    Each frame's joint angles (pan and roll unwrapped from the frame before, with
    the same integer turn counts as :meth:`GimbalKinematics.inverse`), limit and
    lock guard and joint rates are computed for that frame alone, in Python floats
    (:class:`~trajgen.frame_eval.FrameKinematics`), so each ``next()`` costs about
    the same. The path itself is evaluated

    - for a :class:`~trajgen.smooth.SmoothSpline` (the default spline), one frame
      at a time in floats as well (:class:`~trajgen.frame_eval.SmoothFrames`);
    - for any other spline (a :class:`~trajgen.spline.BlendingSpline`, a
      ``trajgen.compare`` method, anything with the spline protocol),
      ``BLOCK_FRAMES`` frames at a time with numpy, one block ahead, the next
      block's evaluation spread in steps over the frames of the one before
      (:meth:`~trajgen.path.OrientationPath.evaluation_steps`); only the first
      block is evaluated at once.

    Frame ``i`` equals frame ``i`` of :func:`plan_joint_trajectory` with the same
    arguments (to rounding, ~1e-15 rad). Arguments are checked at the call; a path
    that nears gimbal lock or leaves a limit raises at the first offending frame,
    after the frames before it have been yielded.

    An online source (an :class:`~trajgen.online.OnlineSpline`, or anything with
    its ``snapshot``, ``commit``, ``closed`` and ``t_end``) may change while it
    is streamed: each frame is committed to the source before it is yielded, and
    a change made by another thread between two frames takes effect from the
    next one. Its frames run from ``t_start`` until the source is closed and
    ``t_end`` is reached, holding at rest meanwhile. Each frame is evaluated on
    its own from the source's snapshot (``snapshot()`` returns a path with
    ``frames(t0, rate_hz, previous)``, see :class:`~trajgen.online.PlanFrames`): a change's
    spliced segments in floats, blended ones with numpy a block at a time, a joint
    motion (an untimed target's) as its joints' own angles and rates.

    Parameters
    ----------
    spline, rate_hz, kinematics, start
        As for :func:`plan_joint_trajectory`; ``spline`` may be an online source.

    Returns
    -------
    Iterator[JointFrame]
        Frames ``0 .. M-1`` at ``t_start + i / rate_hz``, the last at ``t_end``
        (for an online source: the first at or after ``t_end`` once it is closed).

    Raises
    ------
    KinematicsError
        From ``next()``, at the first frame near gimbal lock or outside a limit.
    TypeError
        If ``spline`` lacks the spline protocol or ``rate_hz`` is not a number.
    ValueError
        If ``rate_hz`` is not > 0 or ``start`` is not (n,).
    """
    if all(hasattr(spline, name) for name in ("snapshot", "commit", "closed")):
        kin, _, start = _prepare(spline, rate_hz, kinematics, start, online=True)
        return _online_frames(spline, FrameKinematics(kin, start), float(rate_hz))
    kin, t, start = _prepare(spline, rate_hz, kinematics, start)
    if isinstance(spline, SmoothSpline):
        return _scalar_frames(SmoothFrames(spline), FrameKinematics(kin, start), t)
    return _frames(spline, FrameKinematics(kin, start), t)


def _frame(i: int, t: float, angles, qd, qdd) -> JointFrame:
    """Frame ``i`` at time ``t`` (s) from three triples of floats (rad, rad/s, rad/s^2)."""
    return JointFrame(i, float(t), np.array(angles), np.array(qd), np.array(qdd))


def _scalar_frames(path, kin: FrameKinematics, t: np.ndarray) -> Iterator[JointFrame]:
    """Generator behind :func:`stream_frames` for a path evaluated per frame."""
    for i in range(len(t)):
        ti = t.item(i)
        yield _frame(i, ti, *kin(ti, *path(ti)))


#: Frames per block when a spline is evaluated with numpy: a block is evaluated one
#: block ahead, in steps spread over the frames of the block before.
BLOCK_FRAMES = 32


def _frames(spline, kin: FrameKinematics, t: np.ndarray) -> Iterator[JointFrame]:
    """Generator behind :func:`stream_frames` for a spline evaluated a block at a time.

    Each ``next()`` hands out a frame of the current block (its kinematics done
    then) and then does one step of the next block's evaluation (see
    :meth:`~trajgen.path.OrientationPath.evaluation_steps`), so no frame pays for
    a whole block. Only the first block is evaluated at once.
    """
    samples = Steps(_evaluation_steps(spline, t[:BLOCK_FRAMES])).finish()
    for a in range(0, len(t), BLOCK_FRAMES):
        tb = t[a : a + BLOCK_FRAMES]
        b = a + BLOCK_FRAMES
        work = Steps(_evaluation_steps(spline, t[b : b + BLOCK_FRAMES])) if b < len(t) else None
        for j in range(len(tb)):
            tj = tb.item(j)
            q, w, dw = samples.q[j].tolist(), samples.omega[j].tolist(), samples.alpha[j].tolist()
            yield _frame(a + j, tj, *kin(tj, q, w, dw))
            if work is not None:
                work.step()
        if work is not None:
            samples = work.finish()


def _evaluation_steps(spline, tb):
    """The spline's evaluation at times ``tb`` in steps (its own, if it has
    ``evaluation_steps``; else one); returns the Samples."""
    steps = getattr(spline, "evaluation_steps", None)
    if steps is None:  # any object with the spline protocol's evaluate()
        return spline.evaluate(tb, max_order=2)
    return (yield from steps(tb, max_order=2))


def _online_frames(source, kin: FrameKinematics, rate_hz: float) -> Iterator[JointFrame]:
    """Generator behind :func:`stream_frames` for an online source: each frame from the
    snapshot current when it is due, committed before it is yielded."""
    t0, i, version, frames = source.t_start, 0, None, None
    while True:
        t = t0 + i / rate_hz
        latest, path = source.snapshot()
        if latest != version:
            version, frames = latest, path.frames(t0, rate_hz, frames)
        unwrapped = kin.state
        joints = frames.joints(t, kin)
        if not source.commit(t, version):  # changed meanwhile: this frame again
            kin.state = unwrapped
            continue
        yield _frame(i, t, *joints)
        i += 1
        if source.closed and t >= source.t_end:
            return


def _prepare(spline, rate_hz, kinematics, start, *, online=False):
    """Check the planners' arguments; return the kinematics, the times (M,) and start."""
    if not all(hasattr(spline, name) for name in ("t_start", "t_end", "evaluate")):
        raise TypeError(
            "Expected `spline` to have t_start, t_end and evaluate(t, max_order=2), "
            f"got {type(spline).__name__}."
        )
    if kinematics is None:
        kinematics = GimbalKinematics()
    elif not isinstance(kinematics, GimbalKinematics):
        raise TypeError(
            f"Expected `kinematics` to be a GimbalKinematics, got {type(kinematics).__name__}."
        )
    if start is not None:
        start = as_angles(start, "start", single=True, n=kinematics.n_joints)
    if online:
        return kinematics, sample_times(0.0, 1.0, rate_hz), start  # checks the rate
    return kinematics, sample_times(spline.t_start, spline.t_end, rate_hz), start
