"""A keyframe file with every table checked, whatever the command; and its timing.

Every command refuses a mistake in any table alike (``[gimbal]``, ``[bus]``,
``[limits]``, not only the tables it uses), so a file that plans also
simulates and streams.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from trajgen.errors import TrajgenError
from trajgen.keyframes import JOINT_MINIMAX_S_PER_KEYFRAME, KeyframeFile, load_keyframe_file
from trajgen.sampling import MAX_SAMPLES, check_sample_count

#: Keyframe files above this many keyframes say so before the spline is built.
LARGE_FILE_KEYFRAMES = 100_000
#: With ``knots = "joint-minimax"``, files from this many keyframes say the cost first.
SLOW_BUILD_KEYFRAMES = 20


def _quiet(message: str) -> None:
    """A ``say`` that says nothing."""


@dataclass(frozen=True)
class CheckedFile:
    """A keyframe file with every table checked; its spline is built on first use.

    Attributes
    ----------
    keyframes : KeyframeFile
    gimbal : trajgen.sim.GimbalConfig
        From ``[gimbal]``.
    bus : trajgen.drivers.config.BusConfig
        From ``[bus]``.
    limits : trajgen.sim.limits.JointLimits
        From ``[limits]``.
    say : callable
        ``say(message)`` is told what a slow spline build will cost before it starts.
    progress : callable or None
        ``progress(label)`` returns the ``progress(fraction)`` callback of a slow build
        (``fraction`` in 0..1); None: no progress.
    """

    keyframes: KeyframeFile
    gimbal: object
    bus: object
    limits: object
    say: Callable[[str], None] = field(default=_quiet, repr=False, compare=False)
    progress: Callable | None = field(default=None, repr=False, compare=False)

    @property
    def spline(self):
        """The file's spline (built on first use; raises KeyframeFileError if refused).

        A slow build says its cost first (``say``) and reports its progress."""
        kf = self.keyframes
        n = len(kf.times)
        slow = kf.spline_options.get("knots") == "joint-minimax"
        if "_built_spline" in kf.__dict__:
            pass  # built already
        elif slow and n >= SLOW_BUILD_KEYFRAMES:
            self.say(
                f"knots = 'joint-minimax' through {n:,} keyframes: about "
                f"{n * JOINT_MINIMAX_S_PER_KEYFRAME:,.0f} s on an unloaded core "
                "('end-minimax' takes milliseconds)"
            )
        elif n > LARGE_FILE_KEYFRAMES:
            self.say(f"building the spline through {n:,} keyframes...")
        progress = None
        if slow and self.progress is not None:
            progress = self.progress("joint-minimax knots")
        return kf.spline(progress=progress)


def load_checked(
    path,
    *,
    spline: bool = True,
    any_axes: bool = False,
    say: Callable[[str], None] | None = None,
    progress: Callable | None = None,
) -> CheckedFile:
    """Load a keyframe file and check every table of it, whatever the command.

    A spline that is slow to build (``knots = "joint-minimax"``) is built here,
    its cost said first and its progress reported, unless ``spline`` is False
    (a command that does not plan the file's motion).

    Parameters
    ----------
    path : str or Path
    spline : bool
        Build a slow spline here (see above); default True.
    any_axes : bool
        Accept a ``[gimbal] axes`` / ``joints`` other than pan-tilt-roll (``plan``,
        ``sim``, ``fit``, ``sweep``, ``identify`` do so far); otherwise such a file is
        refused in one line (``trajgen.sim.model.gimbal_config_from_tables``).
    say, progress : callable, optional
        See :class:`CheckedFile`; default silent.

    Raises
    ------
    KeyframeFileError
        For any table, keyframe or field; one line naming file and field.
    """
    from trajgen.drivers.config import bus_config_from_tables
    from trajgen.sim.limits import limits_from_tables
    from trajgen.sim.model import gimbal_config_from_tables

    kf = load_keyframe_file(path)
    gimbal = gimbal_config_from_tables(kf.tables, kf.path, any_axes=any_axes)
    bus = bus_config_from_tables(kf.tables, kf.path)
    limits = limits_from_tables(kf.tables, kf.path)
    checked = CheckedFile(kf, gimbal, bus, limits, say or _quiet, progress)
    if spline and kf.spline_options.get("knots") == "joint-minimax":
        checked.spline  # noqa: B018 (built now, its cost said and its progress reported)
    return checked


def check_timing(kf: KeyframeFile, rate_hz: float, max_samples: int = MAX_SAMPLES) -> int:
    """Refuse a plan that cannot be sampled sensibly at ``rate_hz``; returns the sample count.

    Two keyframes closer than one sample period cannot both be followed by the
    stream (the motion between them falls between two samples), and a sample
    count above ``max_samples`` would not fit in memory.

    Raises
    ------
    KeyframeFileError
        Two keyframes closer than one period, naming them.
    PlanTooLarge
        Too many samples, with the count and the limit.
    """
    gaps = np.diff(kf.times)
    i = int(np.argmin(gaps))
    if gaps[i] < 1.0 / rate_hz:
        raise kf.error(
            f"keyframes {i + 1} and {i + 2}",
            f"{gaps[i]:.3g} s apart, less than one sample period ({1 / rate_hz:.3g} s at "
            f"{rate_hz:g} Hz): no stream can follow that; space them out or raise the rate",
        )
    try:
        return check_sample_count(kf.times[0], kf.times[-1], rate_hz, max_samples)
    except TrajgenError as e:
        raise type(e)(f"{kf.path}: {e}") from None
