"""What a timing fit returns (per-segment durations, the binding limits, the file to write),
and the refusal both fits share."""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from trajgen.sim.errors import SimError
from trajgen.sim.limits import JointLimits


def keyframe_source(source):
    """``source`` as a :class:`~trajgen.keyframes.KeyframeFile` (a path is loaded).

    Raises
    ------
    TypeError
        If ``source`` is neither a path nor a keyframe file.
    """
    from trajgen.keyframes import load_keyframe_file

    if isinstance(source, (str, os.PathLike)):
        source = load_keyframe_file(source)
    if not (hasattr(source, "quats") and hasattr(source, "tables")):
        raise TypeError(
            f"Expected `source` to be a keyframe file path or KeyframeFile, got "
            f"{type(source).__name__}."
        )
    return source


class FitError(SimError):
    """No timing of these keyframes passes the check (the message says why)."""


@dataclass(frozen=True)
class SegmentFit:
    """One segment's old and new duration and what limits it.

    Attributes
    ----------
    index : int
        Segment number from 1: it runs from keyframe ``index`` to ``index + 1``.
    old_s, new_s : float
        Durations (s) before and after the fit.
    binding : str
        The limit that stops it going faster, e.g. ``"torque envelope (tilt)"``.
    """

    index: int
    old_s: float
    new_s: float
    binding: str


@dataclass(frozen=True)
class FitResult:
    """What :func:`~trajgen.sim.fit_timing` (or ``fit_durations``) found.

    Attributes
    ----------
    times : ndarray, shape (N,)
        Fitted keyframe times (s): when the motion passes each keyframe.
    old_times : ndarray, shape (N,)
        The input's keyframe times (s).
    segments : tuple of SegmentFit
    report : TorqueReport
        The torque check of the fitted motion (passes, unless fitted with
        ``simulate=False``).
    faster_reasons : tuple of str
        Why the same motion ``faster`` times as fast fails (the check's and the
        limits' reasons); empty would mean the fit is not tight.
    limits : JointLimits
    document : dict
        The input file's TOML document with the new keyframe times (and the
        ``[timing]`` table of a retimed fit): write it with :meth:`toml`.
    iterations : int
        Optimiser iterations over all rounds.
    faster : float
        The speed-up that must fail for the fit to be tight (1.05: 5 % faster).
    law : TimeLaw or None
        The retimed fit's time law (None for a fit of keyframe times alone).
    path : OrientationPath or None
        The fitted motion as a path (``plan_joint_trajectory(result.path, rate)``).
    """

    times: np.ndarray
    old_times: np.ndarray
    segments: tuple
    report: object = field(repr=False)
    faster_reasons: tuple
    limits: JointLimits
    document: dict = field(repr=False)
    iterations: int
    faster: float = 1.1
    law: object = field(default=None, repr=False)
    path: object = field(default=None, repr=False)

    @property
    def tight(self) -> bool:
        """True when the same motion ``faster`` times as fast fails the check."""
        return bool(self.faster_reasons)

    @property
    def duration_s(self) -> float:
        return float(self.times[-1] - self.times[0])

    @property
    def old_duration_s(self) -> float:
        return float(self.old_times[-1] - self.old_times[0])

    def toml(self) -> str:
        """The fitted keyframe file as TOML text (every other table of the input kept)."""
        from trajgen.toml_writer import dumps

        return dumps(self.document)

    def format(self) -> str:
        """A readable table: per segment old and new duration and the binding limit."""
        lines = [
            f"fit: {self.old_duration_s:.3f} s -> {self.duration_s:.3f} s "
            f"({self.old_duration_s / self.duration_s:.2f}x as fast)",
            f"{'segment':<9}{'keyframes':<11}{'old (s)':>9}{'new (s)':>9}  binding limit",
        ]
        for s in self.segments:
            lines.append(
                f"{s.index:<9}{f'{s.index} -> {s.index + 1}':<11}{s.old_s:9.3f}{s.new_s:9.3f}"
                f"  {s.binding}"
            )
        percent = f"{self.faster - 1:.0%}"
        if self.tight:
            lines.append(f"tight: {percent} faster fails: {self.faster_reasons[0]}")
        else:
            lines.append(f"NOT tight: {percent} faster still passes")
        return "\n".join(lines)


def segment_fits(old_times: np.ndarray, times: np.ndarray, binding) -> tuple:
    """One :class:`SegmentFit` per segment of keyframe ``old_times`` and ``times`` (N,), s,
    with ``binding`` (N - 1 str)."""
    return tuple(
        SegmentFit(i + 1, float(old), float(new), binding[i])
        for i, (old, new) in enumerate(zip(np.diff(old_times), np.diff(times), strict=True))
    )


def refuse_unholdable_keyframes(source, model, config) -> None:
    """Raise FitError if a keyframe is near gimbal lock or a pose the servos cannot hold
    against gravity (``torque_margin x`` stall)."""
    from trajgen import gimbal
    from trajgen.sim.dynamics import inverse_dynamics

    try:
        q = config.kinematics().inverse(source.quats, source.times)
    except gimbal.KinematicsError as e:
        raise FitError(f"no timing can help: at a keyframe, {e}") from e
    zero = np.zeros_like(q)
    hold = np.abs(inverse_dynamics(model, q, zero, zero, coulomb=False))
    stall = np.array([s.stall_torque_nm for s in config.servos])
    avail = config.torque_margin * stall
    over = hold > avail
    if over.any():
        i, j = np.argwhere(over)[0]
        raise FitError(
            f"keyframe {i + 1}: the {config.names[j]} servo cannot hold this pose against "
            f"gravity: it needs {hold[i, j]:.3f} N m, {config.torque_margin:g} x stall "
            f"is {avail[j]:.3f} N m ({config.servos[j].name}, payload "
            f"{config.payload_kg:g} kg)"
        )


def retimed_document(path, times: np.ndarray) -> dict:
    """The file's TOML document (``tomllib``) with keyframe ``i``'s ``t`` set to ``times[i]``."""
    document = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    for entry, t in zip(document["keyframes"], times, strict=True):
        entry["t"] = float(t)
    return document
