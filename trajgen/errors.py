"""The core's error classes.

Every domain failure of ``trajgen`` is a :class:`TrajgenError`. It subclasses
``ValueError`` because each one is bad input (a keyframe file, a path the gimbal
cannot follow, a plan too large to hold), so code that catches ``ValueError``
keeps working, while the command line catches ``TrajgenError`` alone and lets a
bug's ``ValueError`` show as one. ``trajgen.sim`` (``SimError``) and
``trajgen.drivers`` (``DriverError``) have their own bases.
"""

from __future__ import annotations


class TrajgenError(ValueError):
    """Base class of trajgen's domain failures; the message is one line."""


class KeyframeFileError(TrajgenError):
    """A keyframe file that cannot be used; the message names file, table or keyframe, field."""


class KinematicsError(TrajgenError):
    """A path the gimbal cannot follow: gimbal lock or a joint limit."""


class PlanTooLarge(TrajgenError):
    """A plan whose sample count would not fit in memory; the message gives count and limit."""
