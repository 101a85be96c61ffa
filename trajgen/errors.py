"""The core's error classes.

Every domain failure of ``trajgen`` is a :class:`TrajgenError`, and so is every
bad argument value of a library call (:class:`BadArgument`). It subclasses
``ValueError`` because each one is bad input (a keyframe file, an argument, a
path the gimbal cannot follow, a plan too large to hold), so code that catches
``ValueError`` keeps working, while the command line catches ``TrajgenError`` alone and lets a
bug's ``ValueError`` show as one. ``trajgen.sim`` (``SimError``) and
``trajgen.drivers`` (``DriverError``) have their own bases.
"""

from __future__ import annotations


class TrajgenError(ValueError):
    """Base class of trajgen's domain failures; the message is one line."""


class BadArgument(TrajgenError):
    """A library call's argument with a wrong value or shape (a time, a shape, ``k``,
    ``boundary``...); the message names the argument and what arrived.

    A wrong *type* stays a ``TypeError``: it is a bug of the calling code more often
    than bad input.
    """


class NoCircleError(TrajgenError):
    """Three keyframes admit no usable circle (a reversal)."""


class KeyframeFileError(TrajgenError):
    """A keyframe file that cannot be used; the message names file, table or keyframe, field."""


class KinematicsError(TrajgenError):
    """A path the gimbal cannot follow: gimbal lock or a joint limit."""


class PlanTooLarge(TrajgenError):
    """A plan whose sample count would not fit in memory; the message gives count and limit."""
