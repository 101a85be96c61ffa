"""Stop signals: SIGINT, SIGTERM and SIGHUP raised as ``Interrupted`` where it is safe.

A streaming session arms them around the stretch that touches the servos, so a
signal there stops the stream (and the servos stop safely); outside it
(planning, reporting) a signal is remembered and acted on at the next ``arm``;
while the safe stop runs, a second signal is ignored so that the stop completes.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

from .errors import Interrupted

#: The signals a session stops on (exit status ``128 + signum``: 130, 143, 129).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP as :class:`~trajgen.drivers.errors.Interrupted`,
    raised only while ``armed``.

    Attributes
    ----------
    received : int or None
        The first stop signal received, if any.
    """

    def __init__(self) -> None:
        self.received: int | None = None
        self._armed = False

    def _handle(self, signum, frame) -> None:
        first = self.received is None
        self.received = signum if first else self.received
        if self._armed and first:
            self._armed = False
            raise Interrupted(signum)

    @contextmanager
    def installed(self):
        """Handle the stop signals inside the block (the previous handlers after it).

        Off the main thread (where Python cannot set handlers) nothing is installed.
        """
        if threading.current_thread() is not threading.main_thread():
            yield self
            return
        previous = {s: signal.signal(s, self._handle) for s in STOP_SIGNALS}
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)

    @contextmanager
    def armed(self):
        """Raise ``Interrupted`` for a stop signal inside the block (at once for one
        received before it)."""
        if self.received is not None:
            raise Interrupted(self.received)
        self._armed = True
        try:
            yield
        finally:
            self._armed = False
