"""Exceptions of the drivers package.

``DriverError`` is the base of every domain failure; a bad argument value is a
:class:`BadArgument`, which is also the core's ``trajgen.errors.BadArgument``.
Messages name the servo ids, the register and the number of tries; the
underlying exception is chained with ``from``.
"""

from __future__ import annotations

from trajgen.errors import BadArgument as _CoreBadArgument


class DriverError(Exception):
    """Base class of every failure raised by ``drivers``."""


class BadArgument(DriverError, _CoreBadArgument):
    """A driver call's argument with a wrong value or shape; also a ``trajgen.BadArgument``."""


class PacketError(DriverError, ValueError):
    """Bytes that are not a well-formed Protocol 2.0 packet."""


class CommError(DriverError, ConnectionError):
    """Transport failure: no reply, a corrupt reply, or the port went away."""


class ServoError(DriverError, RuntimeError):
    """A servo reported an error: an error bit in its status, or a hardware error."""


class WatchdogTripped(ServoError):
    """A servo's Bus Watchdog expired; it refuses new goals until cleared."""


class ServoReset(ServoError):
    """A servo's torque went off by itself mid-stream: it rebooted, lost power or shut down."""


class BringUpError(DriverError):
    """The servos on the bus do not match the configuration (missing, wrong model)."""


class OutsideLimits(DriverError):
    """A goal would leave a servo's installed position limits; it is not sent."""


class StreamLagging(DriverError):
    """The stream fell further behind its plan than allowed (host stalls, a slow bus)."""


class Interrupted(KeyboardInterrupt):
    """A stop signal (SIGINT, SIGTERM, SIGHUP) arrived; handled like Ctrl-C.

    Parameters
    ----------
    signum : int
        The signal number; the command line exits with ``128 + signum``.
    """

    def __init__(self, signum: int) -> None:
        import signal

        self.signum = signum
        self.name = signal.Signals(signum).name
        super().__init__(f"interrupted by {self.name}")
