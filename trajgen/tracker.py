"""Untimed targets: go to an orientation or a point to look at, as early as the limits allow.

A vision loop reports where to look many times a second, without saying when to be
there. :class:`Tracker` turns each such target into a retarget of an
:class:`~trajgen.online.OnlineSpline` at the time ``at`` it is given, arriving at the
earliest time that keeps per-joint speed, acceleration and jerk limits (and, if given,
a torque-speed envelope). The path stays C^k (the spline's k: C2 for the default
k = 2) across every change, so a new target replaces the old one in mid-motion without
a jump.

The motion (k <= 2, finite limits): each joint goes from its present angle, speed and
acceleration (read off the path at ``at``: exact joint rates of its angular motion) to
rest at its goal in the least time its own limits allow, a seven-phase jerk-limited
profile (:func:`trajgen.tracker_profile.fastest`: jerk ``+-J`` or 0 in each phase, the
time-optimal motion that Ruckig also computes). The path is the joints' motion through
the gimbal's axes, ``forward(x(t))`` (:class:`~trajgen.joint_splice.JointSplice`),
played by the spline as a splice (:meth:`OnlineSpline.prepare_segment
<trajgen.online.OnlineSpline.prepare_segment>`). It is C2 across the change (angle,
speed and acceleration of every joint continuous, so orientation, angular velocity and
acceleration are), not C3: the jerk jumps there, as between the profile's phases. The
limits hold between frames as on them (the profile's peaks are exact); its frames are
checked against the lock margin, the joint limits and the envelope (where the envelope
refuses one, the speed and acceleration limits are scaled by ``ENVELOPE_SCALES`` in
turn). Where the motion in progress cannot keep the limits from ``at`` (faster than a
``max_speed`` asked, or decelerating too late to stay within the speed limit), the
change is tried again ``DEFER_S`` later, and at the old path's end (at rest), the old
path being followed meanwhile.

For ``k = 3`` (C3 asked; a jerk-limited profile is only C2) or a limit left infinite,
the older search applies: the retarget through one keyframe at lead ``h`` is one splice
``exp(r(u)) q_a``, ``u = (t - at) / h``, whose polynomial ``r`` is known in closed
form for every ``h`` once one retarget is built (:meth:`Tracker._family`). Candidate
leads on a geometric grid (``GRID_RATIO``) are checked together, ``GRID_CHUNK`` at a
time, at ``COARSE_SAMPLES`` points each; between the first that passes and the one
before it, leads ``ARRIVAL_TOLERANCE`` apart are checked together; the lead chosen is
built and checked at every frame of the stream. Joint jerk there is the central
difference of exact accelerations over +-``JERK_STEP_S``.

Noise: a target whose joint angles differ from the current goal's by less than the dead
band (default one encoder tick, :data:`trajgen.servo_table.RAD_PER_TICK`) changes
nothing. No filter is applied: a target that passes the dead band is planned to exactly.

Geometry (:mod:`trajgen.gimbal`): orientation ``Rz(pan) Ry(tilt) Rx(roll)``; the camera
looks along its body x axis, so a point ``p`` in the base frame (m) is looked at with
``pan = atan2(p_y, p_x)``, ``tilt = atan2(-p_z, hypot(p_x, p_y))`` (positive tilt looks
down, towards -z) and roll 0 (horizon level). Any ``GimbalKinematics`` plans (its
forward and inverse kinematics, exact joint rates, lock and wrapped joints); a two-axis
head (e.g. ``axes="zy"``) looks at ``p`` with its look axis along it, exactly
(:func:`trajgen.axes.direction_angles`); the limits are then (3, 2).

Limits: a target outside the joint limits or within the gimbal-lock margin is clamped,
joint by joint, to the nearest angle inside them (and reported in
:attr:`TargetResult.clamped`). A joint motion from rest keeps every joint between its
two ends, so it never comes nearer the lock than they are (a path that the orientation
splice would take over the zenith goes around it). For the orientation splices, a
direct path that would pass through the lock region is replaced by one through via
points on the straight joint-space line between the two ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import quat as Q
from .axes import direction_angles
from .errors import BadArgument, KinematicsError
from .gimbal import GimbalKinematics, angles_of
from .joint_splice import JointSplice
from .online_splice import exp_rates, hermite_matrix
from .path import run_steps
from .servo_table import RAD_PER_TICK
from .tracker_profile import JointProfile, fastest_steps
from .validate import check_number

__all__ = ["JERK_STEP_S", "TargetResult", "Tracker", "look_at_angles"]

#: Half step (s) of the central difference of exact joint accelerations giving jerk.
JERK_STEP_S = 1e-6

#: Relative width of the bracket at which the bisection on the arrival time stops:
#: the arrival chosen keeps the limits and one ``1 + ARRIVAL_TOLERANCE`` times earlier
#: breaks one (or is below the spline's minimum lead).
ARRIVAL_TOLERANCE = 0.01

#: Longest arrival (s) tried before a target is refused as unreachable under the limits.
MAX_ARRIVAL_S = 60.0

TWO_PI = 2.0 * math.pi

#: Via-point counts tried, in order, when the direct path crosses the lock margin.
VIA_COUNTS = (1, 2, 4, 8)

#: Points ``u = (t - at) / h`` in (0, 1] at which the coarse search samples each candidate
#: path (the chosen one is then checked at every frame of the stream).
COARSE_SAMPLES = 24

#: Ratio of neighbouring leads on the coarse search's grid of candidate arrivals.
GRID_RATIO = 1.25

#: Candidate leads evaluated together (one step of :meth:`Tracker.set_target_steps`).
GRID_CHUNK = 8

#: Delays (s) after ``at`` at which the change is tried again when no arrival from ``at``
#: keeps the limits (in motion, the path must start with the old path's rates to order
#: k + 1, e.g. a jerk at its limit); the old path, which keeps them, is followed meanwhile.
DEFER_S = (0.02, 0.05, 0.1, 0.2, 0.4, 0.8)

#: Factors on the speed and acceleration limits tried, in order, when a joint motion
#: keeps the limits but not the envelope (the torque it needs at speed).
ENVELOPE_SCALES = (1.0, 0.8, 0.64, 0.5, 0.35, 0.25, 0.15)

#: How far (rad) inside the lock margin a clamped tilt is put: room for the path between
#: via points, which cuts a little towards the lock.
CLAMP_INSET_RAD = math.radians(0.5)


def look_at_angles(point) -> np.ndarray:
    """Joint angles ``(pan, tilt, roll)`` (rad) that point the camera's x axis at ``point``.

    Parameters
    ----------
    point : array_like, shape (3,)
        A point (m) in the gimbal's base frame, not the origin.

    Returns
    -------
    ndarray, shape (3,)
        ``pan = atan2(y, x)`` in (-pi, pi], ``tilt = atan2(-z, hypot(x, y))`` in
        [-pi/2, pi/2] (positive looks down), roll 0.

    Raises
    ------
    ValueError, TypeError
        If ``point`` is not 3 finite numbers, or is the origin.
    """
    try:
        p = np.asarray(point, dtype=float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"Expected `look_at` to be 3 numbers, got {point!r}.") from e
    if p.shape != (3,) or not np.isfinite(p).all():
        raise BadArgument(f"Expected `look_at` to be 3 finite numbers (m), got {point!r}.")
    if not np.any(p):
        raise BadArgument("Expected `look_at` to be a point other than the gimbal's origin.")
    x, y, z = p
    return np.array([math.atan2(y, x), math.atan2(-z, math.hypot(x, y)), 0.0])


@dataclass(frozen=True)
class TargetResult:
    """What :meth:`Tracker.set_target` did.

    Attributes
    ----------
    changed : bool
        False when the target was within the dead band of the current goal.
    at : float
        Time (s) of the change: the one asked, or later where no arrival from it kept
        the limits (the old path followed until then).
    arrival : float
        Time (s) the path reaches the goal (the current goal's, when unchanged).
    goal : ndarray, shape (3,)
        Goal joint angles (rad), after clamping.
    clamped : str
        Why the target was clamped ("" if it was not).
    vias : int
        Via points the path goes through around the lock region (0: direct).
    peaks : ndarray, shape (3, 3) or None
        Peak |speed|, |acceleration|, |jerk| (rows) per joint (columns) of the new path
        from ``at``; None when unchanged.
    """

    changed: bool
    at: float
    arrival: float
    goal: np.ndarray
    clamped: str = ""
    vias: int = 0
    peaks: np.ndarray | None = None


def _as_limits(limits, n: int = 3) -> np.ndarray:
    """Limits as (3, n): rows speed, acceleration, jerk; columns the n joints."""
    if limits is None:
        return np.full((3, n), np.inf)
    if hasattr(limits, "as_array"):  # trajgen.sim.limits.JointLimits: pan, tilt, roll
        limits = limits.as_array()[:, :n]
    a = np.asarray(limits, dtype=float)
    if a.shape == (3,):
        a = np.repeat(a[:, None], n, axis=1)
    if a.shape != (3, n) or np.isnan(a).any() or (a <= 0).any():
        raise BadArgument(
            f"Expected `limits` to be (3, {n}) numbers > 0 (rows speed, acceleration, jerk; "
            f"columns the joints; inf for none), got {limits!r}."
        )
    return a


class Tracker:
    """Untimed targets on an :class:`~trajgen.online.OnlineSpline`, each reached as early
    as the joint limits allow.

    Parameters
    ----------
    spline : OnlineSpline
        The plan, changed in place (every change a retarget).
    limits : array_like, shape (3, 3), or JointLimits, optional
        Bounds on |speed| (rad/s), |acceleration| (rad/s^2), |jerk| (rad/s^3): rows,
        per joint pan, tilt, roll: columns; inf for none; a shape (3,) gives one
        bound per quantity for every joint. A ``trajgen.sim.limits.JointLimits`` (the
        file's ``[limits]``) is taken as is. Default: none (the spline's minimum lead).
    kinematics : GimbalKinematics, optional
        Axes, joint limits and lock margin (default pan-tilt-roll, ``"zyx"``); n joints
        (2 or 3): ``limits`` is (3, n), angles and goals (n,).
    dead_band_rad : float, optional
        A target whose joint angles all lie within this (rad) of the current goal's
        changes nothing. Default one encoder tick, 2 pi / 4096.
    envelope : callable, optional
        ``envelope(q, qd, qdd) -> bool array (N,)`` with joint angles, speeds and
        accelerations (N, 3) (rad, rad/s, rad/s^2): True where the servos can do it
        (e.g. a torque-speed envelope check). Every sample must pass. One with a
        ``steps`` method (the same arguments; a generator of steps whose value is
        that array, as ``trajgen.sim.check.EnvelopeCheck``) is run in steps.
    rate_hz : float, optional
        Stream rate (Hz): candidate paths are checked at its frame times
        ``t0 + n / rate_hz``, ``t0`` the spline's ``t_start`` when the tracker is
        made. Default 1000.
    start : array_like, shape (3,), optional
        Joint angles whose 2 pi branch pan and roll take (default: the spline's start
        in (-pi, pi]).

    Notes
    -----
    Cost: the joints' state at ``at``, a grid of the profile's candidates for every
    joint at once, each joint's roots and choice in floats, one check of its frames
    (lock margin, joint limits, envelope); ``bench/tracker_cost.py`` measures it.
    :meth:`set_target_steps` yields between them (a joint a step; the envelope's own
    steps, if it has them), for a caller that runs the work in steps between frames.
    """

    def __init__(
        self,
        spline,
        limits=None,
        *,
        kinematics: GimbalKinematics | None = None,
        dead_band_rad: float = RAD_PER_TICK,
        envelope=None,
        rate_hz: float = 1000.0,
        start=None,
    ):
        self.spline = spline
        self.kinematics = GimbalKinematics() if kinematics is None else kinematics
        self.limits = _as_limits(limits, self.kinematics.n_joints)
        #: Joints free modulo 2 pi (pan and roll for pan-tilt-roll).
        self._wrapped = list(self.kinematics.sequence.wrapped)
        self.dead_band_rad = check_number("dead_band_rad", dead_band_rad, low=0.0)
        self.envelope = envelope
        self.rate_hz = check_number("rate_hz", rate_hz, low=0.0, low_open=True)
        #: Time (s) of frame 0 of the stream's grid (the spline's start when built).
        self.frame_base = float(spline.t_start)
        self.goal = None if start is None else np.asarray(start, dtype=float)
        self._sync()

    def _sync(self) -> None:
        """Take the goal from the plan's end, where others changed it since (timed lines)."""
        q_end = self.spline(np.array([self.spline.t_end]))[0]
        self.goal = self._unwrapped(q_end, self.goal)
        self.arrival = float(self.spline.t_end)
        self._version = self.spline.version

    # -- targets ---------------------------------------------------------------

    def set_target(self, orientation=None, *, at, angles=None, look_at=None, max_speed=None):
        """Go to a target from time ``at``, arriving as early as the limits allow.

        Parameters
        ----------
        orientation : array_like, shape (4,), optional
            Target orientation (w, x, y, z), any norm and sign.
        at : float
            Time (s) of the change (the path up to it is kept), e.g. a little after
            the frame being streamed; the spline's previous change, if that is later
            (a change deferred, see below).
        angles : array_like, shape (3,), optional
            Target joint angles (pan, tilt, roll) (rad), instead of ``orientation``.
        look_at : array_like, shape (3,), optional
            A point (m) in the base frame to point the camera's x axis at, instead.
        max_speed : float, optional
            A cap (rad/s) on every joint's speed for this motion, below ``limits``.

        Returns
        -------
        TargetResult

        Raises
        ------
        ValueError, TypeError
            Bad arguments (naming them), not exactly one target, or ``at`` refused
            by the spline (before its previous change, or streamed already).
        KinematicsError
            If no arrival up to ``MAX_ARRIVAL_S`` keeps the limits and the lock margin.
        """
        return run_steps(
            self.set_target_steps(
                orientation, at=at, angles=angles, look_at=look_at, max_speed=max_speed
            )
        )

    def set_target_steps(self, orientation=None, *, at, angles=None, look_at=None, max_speed=None):
        """:meth:`set_target` as a generator of steps (one per candidate arrival, and
        steps inside each); its return value is the :class:`TargetResult`."""
        given = [x is not None for x in (orientation, angles, look_at)]
        if sum(given) != 1:
            raise BadArgument("Give exactly one of `orientation`, `angles` or `look_at`.")
        at = max(check_number("at", at), self.spline.last_change_at)
        speed = self.limits[0]
        if max_speed is not None:
            speed = np.minimum(speed, check_number("max_speed", max_speed, low=0.0, low_open=True))
        limits = np.vstack([speed, self.limits[1:]])
        n = self.kinematics.n_joints
        if look_at is not None:
            raw = look_at_angles(look_at)  # checks the point
            if n == 2:  # the look axis along the point, exactly (trajgen.axes)
                p = np.asarray(look_at, dtype=float)
                raw = direction_angles(self.kinematics.sequence.indices, p / np.linalg.norm(p))
            elif not self.kinematics.is_default:
                raise BadArgument(
                    '`look_at` needs a pan-tilt-roll ("zyx") or two-axis gimbal, got axes '
                    f"{self.kinematics.axes!r}."
                )
        elif angles is not None:
            raw = np.array(np.broadcast_to(np.asarray(angles, dtype=float), (n,)))
            if not np.isfinite(raw).all():
                raise BadArgument(
                    f"Expected `angles` to be {n} finite numbers (rad), got {angles!r}."
                )
        else:
            q = Q.as_quats(np.reshape(orientation, (1, 4)), "orientation")
            raw = self.kinematics.angles(q)[0]
        yield
        if self.spline.version != self._version:
            self._sync()
        goal, clamped = self._clamp(raw)
        if np.max(np.abs(goal - self.goal)) < self.dead_band_rad:
            return TargetResult(False, at, self.arrival, self.goal.copy(), clamped)
        yield
        found = yield from self._search(goal, at, limits)
        if found is None:
            now = self._unwrapped(self.spline(np.array([at]))[0], self.goal)
            raise KinematicsError(
                f"no path from {np.degrees(now).round(1).tolist()} deg to "
                f"{np.degrees(goal).round(1).tolist()} deg keeps the joint limits and the "
                f"gimbal-lock margin within {MAX_ARRIVAL_S:g} s"
            )
        change, at, h, vias, peaks = found
        yield
        self.spline.apply(change)
        self.goal, self.arrival, self._version = goal, at + h, self.spline.version
        return TargetResult(True, at, at + h, goal.copy(), clamped, vias, peaks)

    # -- the search ------------------------------------------------------------

    def _search(self, goal, at, limits):
        """``(change, at, h, vias, peaks)`` of the earliest arrival ``at + h`` at ``goal``
        (3,) from ``at``, or from a time after it where none from ``at`` keeps the limits
        (``DEFER_S``, and the old path's end, where it rests); None if there is none."""
        t_end = float(self.spline.t_end)
        tries = [at, *(at + d for d in DEFER_S if at + d < t_end)]
        if t_end > at:
            tries.append(t_end)
        if self.spline.k <= 2 and np.isfinite(limits).all():
            found = yield from self._joint_search(goal, tries, limits)
            if found != "orientation":
                return found
        for a in tries:
            now = self._unwrapped(self.spline(np.array([a]))[0], self.goal)
            found, blocked = yield from self._direct(goal, now, a, limits)
            if found is not None:
                return (found[0], a, found[1], 0, found[2])
            if blocked and a >= t_end:  # from rest, straight through the lock: go round
                for vias in VIA_COUNTS:
                    keys = [now + (goal - now) * (i + 1) / (vias + 1) for i in range(vias + 1)]
                    quats = self.kinematics.forward(np.array(keys))
                    found = yield from self._earliest(quats, keys, now, a, limits)
                    if found is not None:
                        return (found[0], a, found[1], vias, found[2])
        return None

    def _joint_search(self, goal, tries, limits):
        """``(change, at, h, 0, peaks)`` of each joint's fastest motion to ``goal`` (n,)
        (:func:`~trajgen.tracker_profile.fastest`) from the first time of ``tries`` where
        it keeps ``limits`` (the old path's speed and acceleration there may force it
        past them), the lock margin, the joint limits and the envelope (the speed and
        acceleration limits scaled by ``ENVELOPE_SCALES`` until it does); None if none
        does; ``"orientation"`` where the path at a time tried is not the joints' own
        orientation (a two-axis head after a twist about its look axis): the
        orientation splices apply."""
        kin = self.kinematics
        for a in tries:
            yield
            state = self._joint_state(a)
            if state is None:
                return "orientation"
            q_a, now, qd, qdd = state
            yield
            if kin.sequence.lock_distance(now) <= kin.lock_margin_rad:
                continue  # no joint rates at the lock; the old path leaves it
            for scale in ENVELOPE_SCALES:
                # a hair inside, so that rounding stays within the limits themselves
                scaled = limits * np.array([[scale], [scale], [1.0]]) * (1.0 - 1e-9)
                phases = yield from fastest_steps(now, qd, qdd, goal, scaled)
                yield
                profile = JointProfile(now, qd, qdd, *phases, goal)
                yield
                peaks = profile.peaks()
                if profile.duration > MAX_ARRIVAL_S:
                    return None
                if (peaks > limits).any():
                    break  # the motion in progress cannot stop within them from here
                verdict = yield from self._check_joints(profile, a)
                if verdict == "path":
                    break
                if verdict == "ok":
                    yield
                    segment = JointSplice(a, profile, kin.sequence.indices, q_a)
                    yield
                    change = self.spline.prepare_segment(segment, at=a)
                    return change, a, profile.duration, 0, peaks
        return None

    def _joint_state(self, t: float):
        """``(q, angles, speeds, accelerations)`` of the path at ``t`` (s): the orientation
        (4,) and the joints' (n,) motion, read off a joint motion in progress, else by
        the exact joint rates of the path's angular motion; None where the path's
        orientation is not one of the joints' (a two-axis head twisted about its look
        axis)."""
        _, plan = self.spline.snapshot()
        segment = plan.pieces[int(plan._segment(np.array([t]))[0][0])].splice
        if isinstance(segment, JointSplice) and segment.s <= t < segment.t_end:
            x, v, a, _ = np.array(segment.profile.state_at(t - segment.s)).T
            return segment.rates(t)[0], x, v, a
        if t >= plan.t_end:  # at rest
            q = plan.pieces[-1].q_end
            now = self._unwrapped(q, self.goal)
            return q, now, np.zeros_like(now), np.zeros_like(now)
        s = plan.evaluate(np.array([t]), max_order=2)
        now = self._unwrapped(s.q[0], self.goal)
        if abs(float(self.kinematics.forward(now) @ s.q[0])) < 1.0 - 1e-12:
            return None
        if self.kinematics.sequence.lock_distance(now) <= self.kinematics.lock_margin_rad:
            return s.q[0], now, np.zeros_like(now), np.zeros_like(now)  # refused by the caller
        qd, qdd = self.kinematics.joint_rates(now, s.omega[0], s.alpha[0])
        return s.q[0], now, qd, qdd

    def _check_joints(self, profile, at: float):
        """``"ok"``, ``"path"`` (a frame near the lock or past a joint limit) or
        ``"envelope"`` (a frame the envelope refuses) for the joint motion ``profile``
        from ``at``, at the stream's frames after ``at`` up to the first after its end:
        a generator of steps (the frames' states, then the envelope's, see
        :class:`Tracker`) whose value is the verdict."""
        base = self.frame_base
        n0 = math.floor((at - base) * self.rate_hz) + 1
        n1 = math.ceil((at + profile.duration - base) * self.rate_hz) + 1
        yield
        q, qd, qdd, _ = profile.state((base + np.arange(n0, n1 + 1) / self.rate_hz) - at)
        yield
        try:
            self.kinematics.check(q)
        except KinematicsError:
            return "path"
        if self.envelope is not None:
            yield
            steps = getattr(self.envelope, "steps", None)
            if steps is not None:
                ok = yield from steps(q, qd, qdd)
            else:
                ok = self.envelope(q, qd, qdd)
            if not np.all(ok):
                return "envelope"
        return "ok"

    def _direct(self, goal, now, at, limits):
        """The earliest lead ``h`` (s) of the direct path from ``now`` (3,) at ``at`` to
        ``goal``: a coarse search (:meth:`_coarse`, every candidate of a chunk of a
        geometric grid of leads at once, then bisection to ``ARRIVAL_TOLERANCE``), then
        the check at every frame of the one chosen (a little later, if a frame between
        the coarse samples breaks a limit). Returns ``((change, h, peaks) or None,
        blocked)``, ``blocked`` True if a candidate kept the limits but not the lock
        margin or the joint limits."""
        quats = self.kinematics.forward(goal[None])
        lo = self.spline.min_lead_s
        rest = at >= self.spline.t_end
        if rest:  # a rest-to-rest move: a lower bound on its lead
            d = np.abs(goal - now)
            with np.errstate(divide="ignore", invalid="ignore"):
                guess = np.nanmax(
                    [d / limits[0], 2 * np.sqrt(d / limits[1]), 2 * np.cbrt(d / limits[2])]
                )
            lo = max(lo, float(guess) if np.isfinite(guess) else lo)
        if lo > MAX_ARRIVAL_S:
            return None, False
        probe = yield from self.spline.prepare_steps("retarget", quats, [at + lo], at=at)
        family = self._family(probe.path.pieces[-1].splice, rest)
        grid = lo * GRID_RATIO ** np.arange(math.ceil(math.log(MAX_ARRIVAL_S / lo, GRID_RATIO)))
        good, bad, blocked = None, None, False
        for i in range(0, len(grid), GRID_CHUNK):
            yield
            ok, path_bad, _ = self._coarse(family, grid[i : i + GRID_CHUNK], now, limits)
            blocked |= bool(path_bad.any())
            if ok.any():
                j = i + int(np.argmax(ok))
                good, bad = grid[j], (grid[j - 1] if j > 0 else None)
                break
        if good is None:
            return None, blocked
        if bad is not None:  # between the two, all at once, ARRIVAL_TOLERANCE apart
            n = math.ceil(math.log(good / bad) / math.log1p(ARRIVAL_TOLERANCE))
            between = bad * (good / bad) ** (np.arange(1, n) / n)
            yield
            ok, _, _ = self._coarse(family, between, now, limits)
            if ok.any():
                good = between[int(np.argmax(ok))]
        h = good
        while h <= good * GRID_RATIO:
            result = yield from self._verified(family, quats, now, at, h, limits)
            if not isinstance(result, str):
                return (result[0], h, result[1]), blocked
            h *= 1 + ARRIVAL_TOLERANCE
        return None, blocked

    def _verified(self, family, quats, now, at, h, limits):
        """The change to ``quats`` at ``at + h``, checked at every frame of the stream:
        ``(change, peaks)``, or ``"limits"`` / ``"path"`` as :meth:`_attempt`. The
        frames are evaluated from ``family`` where the change's splice is the family's
        polynomial at ``h`` (to 1e-12), else as :meth:`_attempt` does."""
        change = yield from self.spline.prepare_steps("retarget", quats, [at + h], at=at)
        yield
        piece = change.path.pieces[-1]
        coefs, q_a = family
        if (
            piece.spline is not None
            or piece.splice is None
            or not np.array_equal(piece.splice.q_a, q_a)
            or not np.allclose(piece.splice.coef, coefs(np.array([h]))[0], rtol=0, atol=1e-12)
        ):
            return (yield from self._attempt(quats, now, at, h, limits))
        base = self.frame_base
        n0 = math.floor((at - base) * self.rate_hz) + 1
        n1 = math.floor((at + h - base) * self.rate_hz)
        u = (base + np.arange(n0, n1 + 1) / self.rate_hz - at) / h
        ok, path_bad, peaks = self._coarse(family, np.array([h]), now, limits, u=u)
        if ok[0]:
            return change, peaks[0]
        return "path" if path_bad[0] else "limits"

    def _family(self, splice, rest: bool):
        """``(coefs, q_a)``: ``coefs(hs)`` gives the splice polynomials (H, 2k + 3, 3)
        (power basis in ``u``, see :mod:`trajgen.online`) of the retargets at leads
        ``hs`` (H,) that ``splice`` (the retarget at one lead) is one of. From rest the
        polynomial does not depend on the lead; in motion its low coefficients are
        ``h^j P_j`` (``P_j`` the old path's Taylor coefficients, j = 0..k + 1) and its top
        ones solve the rest conditions at ``u = 1`` (``r(1) = R_0``, the goal's log)."""
        if rest:
            return (lambda hs: np.broadcast_to(splice.coef, (len(hs), *splice.coef.shape))), (
                splice.q_a
            )
        k = self.spline.k
        p = splice.coef[: k + 2] / splice.h ** np.arange(k + 2)[:, None]
        r0 = splice.coef.sum(axis=0)  # r(1)
        herm = hermite_matrix(k)
        low_taylor = np.array([[math.comb(i, j) for i in range(k + 2)] for j in range(k + 1)])

        def coefs(hs):
            low = hs[:, None, None] ** np.arange(k + 2)[None, :, None] * p
            rhs = -np.einsum("ab,hbi->hai", low_taylor, low)
            rhs[:, 0] += r0
            return np.concatenate([low, np.einsum("ab,hbi->hai", herm, rhs)], axis=1)

        return coefs, splice.q_a

    def _coarse(self, family, hs, now, limits, u=None):
        """Check the direct paths at leads ``hs`` (H,) (s) at ``COARSE_SAMPLES`` points
        each (or at ``u`` (n,), ``(t - at) / h``): ``(ok, path_bad, peaks)``, ``ok``
        (H,) True for the first (in the order given) that keeps ``limits``, the
        envelope, the lock margin and the joint limits; ``path_bad`` (H,) where a
        candidate kept ``limits`` but not the last two; ``peaks`` (H, 3, 3) the peak
        |speed|, |acceleration|, |jerk| (rows) per joint."""
        coefs, q_a = family
        c = coefs(hs)
        if u is None:
            u = np.arange(1, COARSE_SAMPLES + 1) / COARSE_SAMPLES
        n, m = len(u), len(hs)
        du = JERK_STEP_S / hs[:, None]
        uu = np.concatenate([np.broadcast_to(u, (m, n)), u - du, u + du], axis=1)  # (H, 3n)
        powers = np.empty((*uu.shape, c.shape[1]))
        powers[..., 0] = 1.0
        for j in range(1, c.shape[1]):
            np.multiply(powers[..., j - 1], uu, out=powers[..., j])
        r = []
        for _ in range(3):  # r and its first two time derivatives, each (3, H 3n)
            r.append(np.ascontiguousarray((powers[..., : c.shape[1]] @ c).reshape(-1, 3).T))
            c = c[:, 1:] * (np.arange(1.0, c.shape[1])[None, :, None] / hs[:, None, None])
        q, (omega, alpha) = exp_rates(r, q_a)
        a = self._unwrap_path(q.reshape(m, 3 * n, 4), now)
        nj = a.shape[-1]
        seq = self.kinematics.sequence
        locked = (seq.lock_distance(a) < 1e-9).any(axis=1)  # rates undefined there
        a[locked] = np.mean(seq.middle_range) * (np.arange(nj) == 1)
        qd, qdd = self.kinematics.joint_rates(a.reshape(-1, nj), omega, alpha)
        qd, qdd = qd.reshape(m, 3 * n, nj), qdd.reshape(m, 3 * n, nj)
        jerk = (qdd[:, 2 * n :] - qdd[:, n : 2 * n]) / (2 * JERK_STEP_S)
        peaks = np.stack(
            [np.abs(x).max(axis=1) for x in (qd[:, :n], qdd[:, :n], jerk)], axis=1
        )  # (H, 3, joints)
        ok, path_bad = np.zeros(m, bool), np.zeros(m, bool)
        for i in np.flatnonzero((peaks <= limits).all(axis=(1, 2))):
            if locked[i]:
                path_bad[i] = True
                continue
            try:
                self.kinematics.check(a[i, :n])
            except KinematicsError:
                path_bad[i] = True
                continue
            if self.envelope is None or np.all(self.envelope(a[i, :n], qd[i, :n], qdd[i, :n])):
                ok[i] = True
                break
        return ok, path_bad, peaks

    def _earliest(self, quats, keys, now, at, limits):
        """Bisect on the arrival lead ``h`` (s) for keyframes ``quats`` at equal steps of
        ``h``; ``(change, h, peaks)`` of the earliest that passes, or None if the path
        leaves the lock margin or the joint limits (whatever the lead)."""
        lo = self.spline.min_lead_s * len(keys)
        d = np.abs(np.asarray(keys[-1]) - now)
        with np.errstate(divide="ignore", invalid="ignore"):
            guess = np.nanmax(
                [d / limits[0], 2 * np.sqrt(d / limits[1]), 2 * np.cbrt(d / limits[2])]
            )
        h = max(lo, float(guess) if np.isfinite(guess) else lo)
        if h > MAX_ARRIVAL_S:  # a lower bound on any arrival (a rest-to-rest move)
            return None
        result = yield from self._attempt(quats, now, at, h, limits)
        if result == "path":
            return None
        best = (result, h) if not isinstance(result, str) else None
        if best is None:  # grow until a lead passes
            bad = h
            while best is None:
                h *= 2.0
                if h > MAX_ARRIVAL_S:
                    return None
                result = yield from self._attempt(quats, now, at, h, limits)
                if result == "path":
                    return None
                if isinstance(result, str):
                    bad = h
                else:
                    best = (result, h)
        else:  # shrink until a lead fails (or the minimum lead passes)
            bad = None
            while bad is None and best[1] > lo * (1 + 1e-12):
                h = max(lo, best[1] / 2.0)
                result = yield from self._attempt(quats, now, at, h, limits)
                if isinstance(result, str):
                    bad = h
                else:
                    best = (result, h)
        while bad is not None and best[1] > bad * (1 + ARRIVAL_TOLERANCE):
            h = math.sqrt(bad * best[1])
            result = yield from self._attempt(quats, now, at, h, limits)
            if isinstance(result, str):
                bad = h
            else:
                best = (result, h)
        (change, peaks), h = best
        return change, h, peaks

    def _attempt(self, quats, now, at, h, limits):
        """Build and check the path through ``quats`` at equal steps to ``at + h``:
        ``(change, peaks)`` if it keeps ``limits`` (and the envelope), ``"limits"`` if
        it does not, ``"path"`` if it leaves the lock margin or the joint limits."""
        n = len(quats)
        times = at + h * np.arange(1, n + 1) / n
        change = yield from self.spline.prepare_steps("retarget", quats, times, at=at)
        yield
        try:  # joint_motion raises at the lock itself, check() near it
            q, qd, qdd, jerk = self.joint_motion(change.path, at, times[-1], now)
            self.kinematics.check(q)
        except KinematicsError:
            return "path"
        peaks = np.array([np.abs(x).max(axis=0) for x in (qd, qdd, jerk)])
        if (peaks > limits).any():
            return "limits"
        if self.envelope is not None and not np.all(self.envelope(q, qd, qdd)):
            return "limits"
        return change, peaks

    def joint_motion(self, path, t0: float, t1: float, near):
        """Joint angles, speeds, accelerations and jerks (each (N, 3); rad, rad/s,
        rad/s^2, rad/s^3) of ``path`` at the stream's frame times in ``(t0, t1]``
        (and the first frame after ``t1``); pan and roll on the branch nearest ``near`` (3,)
        (rad) at the first frame."""
        base = self.frame_base
        n0 = math.floor((t0 - base) * self.rate_hz) + 1
        n1 = math.ceil((t1 - base) * self.rate_hz) + 1
        t = base + np.arange(n0, n1 + 1) / self.rate_hz
        ts = np.concatenate([t, t - JERK_STEP_S, t + JERK_STEP_S])
        s = path.evaluate(ts, max_order=2)
        q = self._unwrap_path(s.q, near)
        qd, qdd = self.kinematics.joint_rates(q, s.omega, s.alpha)
        m = len(t)
        jerk = (qdd[2 * m :] - qdd[m : 2 * m]) / (2 * JERK_STEP_S)
        return q[:m], qd[:m], qdd[:m], jerk

    # -- angles ----------------------------------------------------------------

    def _unwrap_path(self, quats, near) -> np.ndarray:
        """Angles (..., 3m, n) of three grids of m samples each (frames, frames - step,
        frames + step) of quaternions (..., 3m, 4) (a leading axis: several paths): the
        frames unwrapped sample to sample from the branch nearest ``near`` (n,), the
        others onto the branch of the frame they are next to."""
        if self.kinematics.is_default:
            w, x, y, z = np.moveaxis(quats, -1, 0)
            a = np.stack(angles_of(w, x, y, z, np.arctan2, np.hypot), axis=-1)
        else:
            a = self.kinematics.angles(quats.reshape(-1, 4)).reshape(*quats.shape[:-1], -1)
        m, cols = a.shape[-2] // 3, self._wrapped
        main = a[..., :m, :]
        main[..., cols] = np.unwrap(main[..., cols], axis=-2)
        main[..., cols] += TWO_PI * np.round((near[cols] - main[..., :1, cols]) / TWO_PI)
        for k in (1, 2):
            side = a[..., k * m : (k + 1) * m, :]
            side[..., cols] = main[..., cols] + _wrap(side[..., cols] - main[..., cols])
        return a

    def _unwrapped(self, q, near) -> np.ndarray:
        """Joint angles (n,) of orientation ``q`` (4,), the wrapped joints on the 2 pi
        branch nearest ``near`` (n,) (if given)."""
        a = self.kinematics.angles(np.reshape(q, (1, 4)))[0]
        if near is not None:
            cols = self._wrapped
            a[cols] += TWO_PI * np.round((near[cols] - a[cols]) / TWO_PI)
        return a

    def _clamp(self, raw):
        """The goal nearest ``raw`` (n,) inside the limits (the wrapped joints on the 2 pi
        branch nearest the current goal that fits), and a message if it had to be clamped."""
        kin = self.kinematics
        lim = np.array(kin.limits_rad)
        low, high = kin.sequence.locks
        inset = kin.lock_margin_rad + CLAMP_INSET_RAD
        lim[1] = np.clip(lim[1], low + inset, high - inset)
        goal = raw.copy()
        for j in self._wrapped:
            k = np.arange(-3, 4)
            cands = raw[j] + TWO_PI * (np.round((self.goal[j] - raw[j]) / TWO_PI) + k)
            inside = cands[(cands >= lim[j, 0]) & (cands <= lim[j, 1])]
            pool = inside if len(inside) else cands
            # nearest the current goal; of two as near, the one nearer 0
            goal[j] = pool[np.lexsort((np.abs(pool), np.round(np.abs(pool - self.goal[j]), 9)))[0]]
        clipped = np.clip(goal, lim[:, 0], lim[:, 1])
        moved = [
            f"{name} {math.degrees(goal[j]):.1f} -> {math.degrees(clipped[j]):.1f} deg"
            for j, name in enumerate(kin.joints)
            if clipped[j] != goal[j]
        ]
        return clipped, ("clamped to the joint limits: " + ", ".join(moved)) if moved else ""


def _wrap(a):
    """Angles (rad) wrapped into [-pi, pi)."""
    return (a + math.pi) % TWO_PI - math.pi
