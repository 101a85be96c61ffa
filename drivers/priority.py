"""The streaming thread's claim on the host while it streams on the wall clock.

Two things delay a frame in a Python process that also parses input, plans,
writes telemetry or simulates a plant on other threads (``trajgen follow``):

- the operating system runs other processes (a loaded machine) when the
  stream thread's sleep ends: ``SCHED_FIFO`` for the stream thread lets it
  run as soon as it wakes, ahead of every normal-priority process (Linux;
  needs ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO``, else it is said so and the
  stream goes on as before);
- another thread of the process holds the GIL: it hands it over only after
  the interpreter's switch interval (5 ms by default), so a waking stream
  thread can wait that long. The interval is shortened while streaming.

``stream_priority`` does both for the process's threads and restores both after.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator

# The stream thread's real-time priority (1..99): low, above every normal process,
# below the kernel's own real-time threads.
FIFO_PRIORITY = 10
# Helper processes that must keep time but yield to the stream: just below the stream
# and the virtual bus's serving thread, above every normal process. The virtual bus's
# plant (``drivers.virtual.process``) and ``follow``'s planner (``drivers.follow_process``).
PLANT_FIFO_PRIORITY = PLANNER_FIFO_PRIORITY = FIFO_PRIORITY - 1
# The GIL switch interval while streaming (s): a waking stream thread waits at most
# about this long for another thread to hand the GIL over.
SWITCH_INTERVAL_S = 5e-4


def _raise(tid: int, fifo_priority: int) -> tuple[int, os.sched_param]:
    """Raise thread ``tid`` (0: the calling one) to ``SCHED_FIFO``; returns what it had."""
    before = os.sched_getscheduler(tid), os.sched_getparam(tid)
    # Threads and processes started later get the normal class (reset on fork).
    fifo = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
    os.sched_setscheduler(tid, fifo, os.sched_param(fifo_priority))
    return before


def claim_core(fifo_priority: int) -> str:
    """Raise the calling thread to ``SCHED_FIFO`` for good (a process of its own that
    keeps time); what was done, or why not (it then stays as it was)."""
    try:
        _raise(0, fifo_priority)
    except (AttributeError, OSError) as e:  # not Linux, or not permitted
        return f"SCHED_FIFO not permitted ({_reason(e)})"
    return f"SCHED_FIFO {fifo_priority}"


def scheduling_of(pid: int) -> str:
    """Process ``pid``'s scheduling class, e.g. ``"SCHED_FIFO 9"`` or ``"SCHED_OTHER
    nice 0"`` (``"unknown"`` where it cannot be read)."""
    try:
        policy = os.sched_getscheduler(pid) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        if policy in (os.SCHED_FIFO, os.SCHED_RR):
            name = "SCHED_FIFO" if policy == os.SCHED_FIFO else "SCHED_RR"
            return f"{name} {os.sched_getparam(pid).sched_priority}"
        return f"SCHED_OTHER nice {os.getpriority(os.PRIO_PROCESS, pid)}"
    except (AttributeError, OSError):
        return "unknown"


def _reason(error: Exception) -> str:
    return error.strerror if isinstance(error, OSError) and error.strerror else str(error)


@contextlib.contextmanager
def stream_priority(
    fifo_priority: int = FIFO_PRIORITY, switch_interval_s: float = SWITCH_INTERVAL_S
) -> Iterator[str]:
    """Raise this process's threads to ``SCHED_FIFO`` and shorten the GIL switch interval.

    Every Python thread alive on entry is raised, not only the caller: a
    thread that holds the GIL (a line reader, a plant) must not wait behind
    other processes while the stream thread waits for the GIL. Threads and
    processes started inside keep the normal class (``SCHED_RESET_ON_FORK``).

    Parameters
    ----------
    fifo_priority : int
        ``SCHED_FIFO`` priority (1..99).
    switch_interval_s : float
        GIL switch interval (s) while inside (never lengthened).

    Yields
    ------
    str
        What was done, e.g. ``"SCHED_FIFO 10 (3 threads), GIL switch interval
        0.5 ms"``, or why the scheduling class could not be raised
        ("SCHED_FIFO not permitted (...)").
    """
    interval = sys.getswitchinterval()
    sys.setswitchinterval(min(interval, switch_interval_s))
    gil = f"GIL switch interval {1e3 * sys.getswitchinterval():.2g} ms"
    raised: dict[int, tuple[int, os.sched_param]] = {}
    try:
        raised[0] = _raise(0, fifo_priority)
        me = threading.get_native_id()
        for thread in threading.enumerate():
            tid = thread.native_id
            if tid is not None and tid != me and thread.is_alive():
                with contextlib.suppress(OSError):  # it ended meanwhile
                    raised[tid] = _raise(tid, fifo_priority)
        how = f"SCHED_FIFO {fifo_priority} ({len(raised)} threads), {gil}"
    except (AttributeError, OSError) as e:  # not Linux, or not permitted
        how = f"SCHED_FIFO not permitted ({_reason(e)}); {gil}"
    try:
        yield how
    finally:
        sys.setswitchinterval(interval)
        for tid, (policy, param) in raised.items():
            with contextlib.suppress(OSError):  # a thread that has ended
                os.sched_setscheduler(tid, policy, param)
