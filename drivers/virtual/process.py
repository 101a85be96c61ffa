"""The real-time virtual bus's plant in a process of its own, its state in shared memory.

In one process the serving thread and the simulation thread share one GIL:
a packet that arrives while the plant steps waits for it. ``PlantProcess``
forks the plant into a child process that steps it on the wall clock
(``WallSteps``: the same steps and catch-up rules as the simulation thread,
one step per millisecond whether read or not: it takes no turn of the serving
process's GIL, and the steps, not the wake-ups, cost its CPU) and publishes
each step's present values to memory both processes map; the
serving process never runs the plant. What goes across:

- the present values of the latest step, written by the child after each step
  into one of two slots in turn (a sequence count at the slot's start, odd
  while it is written) and read by the parent without waiting: a slot being
  rewritten is skipped for the other one, which is then the latest;
- the goals (rad), written by the parent the same way and taken by the child
  before each step and before each command;
- how far behind the wall clock the child ran (``WallSteps.lag``) and its CPU
  time, written by the child after each wake-up and read by the parent as they
  are (figures, not state);
- every other plant call (``set_control``, ``set_torque_enabled``) as a command
  on a pipe, which the child makes in order before its next step; no reply
  waits for it. The parent first makes the same call on its own copy of the
  plant (it is never stepped), so that a setting the plant does not simulate
  is refused there and then, as in one process, and never sent. A failure in
  the child (a step raised) comes back on the pipe and closes the bus.

The child raises itself to ``SCHED_FIFO`` just below the serving thread
(``drivers.priority.PLANT_FIFO_PRIORITY``) where permitted: in the normal
class, two CPU-bound processes beside it held it up to 257 ms behind the wall
clock in a 20 s run; raised, it stayed within 10 ms, and a 1 kHz client's
share of slots moved within the run-to-run spread (docs/realtime.md). It
ignores SIGINT (the parent stops it).
"""

from __future__ import annotations

import contextlib
import mmap
import multiprocessing
import signal
import struct
import time
from collections.abc import Mapping

import numpy as np

from trajgen.drivers.priority import PLANT_FIFO_PRIORITY, claim_core, scheduling_of
from trajgen.drivers.units import rad_to_servo_ticks

from ..errors import DriverError
from .plant import Plant
from .simulation import _LAG_BINS, WallSteps

# How long (s) the parent waits for the child to stop before it kills it.
_STOP_WAIT_S = 5.0
_COUNT = struct.Struct("<q")
# The child's figures: lag max (s), time over ``LAG_COUNTED_S`` (s), its CPU time (s),
# then the lag's bins (s each).
_FIGURES = struct.Struct("<3d")
_BIN = struct.Struct("<d")


class PlantProcessError(DriverError):
    """The plant's process ended or stopped answering."""


class _Slots:
    """Two slots of one ``struct`` layout in shared memory, written by one process in turn.

    Layout: the index of the latest slot (8 bytes), then each slot: a count
    (odd while the slot is written), then the values.
    """

    def __init__(self, memory: mmap.mmap, offset: int, layout: struct.Struct) -> None:
        self._memory = memory
        self._offset = offset
        self._layout = layout
        self._slot_b = _COUNT.size + layout.size
        self.writes = 0  # by this process

    @staticmethod
    def size_of(layout: struct.Struct) -> int:
        """The bytes two slots of ``layout`` take, with the latest slot's index."""
        return _COUNT.size + 2 * (_COUNT.size + layout.size)

    def write(self, values) -> None:
        """Store ``values`` in the slot not read last, then make it the latest."""
        self.writes += 1
        slot = self._offset + _COUNT.size + (self.writes % 2) * self._slot_b
        _COUNT.pack_into(self._memory, slot, 2 * self.writes - 1)
        self._layout.pack_into(self._memory, slot + _COUNT.size, *values)
        _COUNT.pack_into(self._memory, slot, 2 * self.writes)
        _COUNT.pack_into(self._memory, self._offset, self.writes % 2)

    def first(self) -> int:
        """The first value (an 8-byte int) of the latest slot: one read, never waits."""
        index = _COUNT.unpack_from(self._memory, self._offset)[0]
        return _COUNT.unpack_from(
            self._memory, self._offset + 2 * _COUNT.size + index * self._slot_b
        )[0]

    def read(self) -> tuple[int, tuple] | None:
        """(writes so far, the latest values), or None if both slots were being written
        meanwhile (never waits for the writer)."""
        for _ in range(3):
            index = _COUNT.unpack_from(self._memory, self._offset)[0]
            slot = self._offset + _COUNT.size + index * self._slot_b
            before = _COUNT.unpack_from(self._memory, slot)[0]
            values = self._layout.unpack_from(self._memory, slot + _COUNT.size)
            if before % 2 == 0 and _COUNT.unpack_from(self._memory, slot)[0] == before:
                return before // 2, values
        return None


class PlantProcess:
    """A plant stepped on the wall clock in a child process; a ``Plant`` to the parent.

    Parameters
    ----------
    plant : Plant
        The plant, as it is now: the child steps a copy of it; this one is never
        stepped again, only told every setting first (its refusals are the
        child's).
    step_s : float
        Its step (s): one per ``step_s`` of wall time (``WallSteps``).
    started_s : float
        ``time.monotonic()`` at simulated time 0.

    Attributes
    ----------
    n_joints : int
    """

    def __init__(self, plant: Plant, step_s: float, started_s: float) -> None:
        n = self.n_joints = plant.n_joints
        self.step_s = step_s
        # steps done, then per joint: ticks; velocity (rad/s), current (A), drive output
        self._state = struct.Struct(f"<q{n}q{3 * n}d")
        self._goal = struct.Struct(f"<{n}d")
        goals_at = _Slots.size_of(self._state)
        self._figures = goals_at + _Slots.size_of(self._goal)
        self._bins = self._figures + _FIGURES.size
        size = self._bins + _LAG_BINS * _BIN.size
        memory = mmap.mmap(-1, -(-size // mmap.PAGESIZE) * mmap.PAGESIZE)  # MAP_SHARED
        self._states = _Slots(memory, 0, self._state)
        self._goals = _Slots(memory, goals_at, self._goal)
        self._memory = memory
        self._latest = self._publish_of(plant, 0)
        self._states.write(self._latest)
        self._goals.write(np.asarray(plant.read()[0], dtype=float).tolist())
        self._shadow = plant
        self._conn, child = multiprocessing.Pipe()
        self._process = multiprocessing.get_context("fork").Process(
            target=_run,
            args=(plant, step_s, started_s, self, child),
            name="virtual-bus-plant",
            daemon=True,
        )
        self._process.start()
        child.close()

    def _publish_of(self, plant: Plant, steps: int) -> tuple:
        position, velocity, current = plant.read()
        return (
            steps,
            *rad_to_servo_ticks(position).tolist(),
            *np.asarray(velocity, dtype=float).tolist(),
            *np.asarray(current, dtype=float).tolist(),
            *np.asarray(plant.present_pwm(), dtype=float).tolist(),
        )

    # -- the parent's side: a Plant ---------------------------------------------

    def fileno(self) -> int:
        """The pipe the child reports a failure on (readable then): for ``select``."""
        return self._conn.fileno()

    def latest(self) -> tuple[int, list[int], list[float], list[float], list[float]]:
        """The latest step's (steps done, ticks, velocity (rad/s), current (A), drive output)."""
        read = self._states.read()
        if read is not None:
            self._latest = read[1]
        n = self.n_joints
        v = self._latest
        return (
            v[0],
            list(v[1 : 1 + n]),
            list(v[1 + n : 1 + 2 * n]),
            list(v[1 + 2 * n : 1 + 3 * n]),
            list(v[1 + 3 * n :]),
        )

    def figures(self) -> tuple[float, float, float, list[float]]:
        """The child's lag so far: (max (s), time over ``LAG_COUNTED_S`` (s), its CPU
        time (s), the lag's bins (s of wall time each; ``Lag.counts``))."""
        lag_max, over, cpu = _FIGURES.unpack_from(self._memory, self._figures)
        bins = struct.unpack_from(f"<{_LAG_BINS}d", self._memory, self._bins)
        return lag_max, over, cpu, list(bins)

    def scheduling(self) -> str:
        """The child's scheduling class, e.g. ``"SCHED_FIFO 9"`` (``scheduling_of``)."""
        return scheduling_of(self._process.pid)

    def steps(self) -> int:
        """Steps done by the latest step published (no more is read)."""
        return self._states.first()

    def set_goal(self, positions_rad: np.ndarray) -> None:
        """Goal angles (rad), shape (n_joints,): the child takes them before its next step."""
        self._goals.write([float(v) for v in positions_rad])

    def set_torque_enabled(self, joint: int, enabled: bool) -> None:
        """Torque on or off for one joint, from the child's next step on."""
        self._shadow.set_torque_enabled(joint, enabled)
        self._send("set_torque_enabled", joint, bool(enabled))

    def set_control(self, joint: int, registers: Mapping[str, int]) -> None:
        """The position-loop registers of one joint's servo, from the child's next step on.

        Raises
        ------
        Exception
            What the plant raises for them (its copy here is told first); then
            nothing is sent.
        """
        self._shadow.set_control(joint, registers)
        self._send("set_control", joint, dict(registers))

    def advance(self, dt_s: float) -> None:
        """Not here: the child steps the plant on the wall clock.

        Raises
        ------
        PlantProcessError
            Always.
        """
        raise PlantProcessError("the plant steps in its own process, on the wall clock")

    def read(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The latest step's position (rad), velocity (rad/s), current (A), each (n_joints,)."""
        from trajgen.drivers.units import servo_ticks_to_rad

        _, ticks, velocity, current, _ = self.latest()
        return servo_ticks_to_rad(np.array(ticks)), np.array(velocity), np.array(current)

    def present_pwm(self) -> np.ndarray:
        """The latest step's drive output as a fraction of the supply, shape (n_joints,)."""
        return np.array(self.latest()[4])

    def check(self) -> None:
        """Raise what ended the child, if it said so (the pipe is readable then).

        Raises
        ------
        Exception
            What the plant raised in the child, or ``PlantProcessError`` if the
            child ended otherwise.
        """
        if not self._conn.poll():
            return
        try:
            error = self._conn.recv()
        except (EOFError, OSError) as e:
            raise PlantProcessError("the plant's process has ended") from e
        raise error

    def stop(self) -> None:
        """Stop the child (it steps no more) and wait for it."""
        with contextlib.suppress(OSError, ValueError):
            self._conn.send(None)
        self._process.join(_STOP_WAIT_S)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        self._conn.close()
        self.latest()

    def _send(self, name: str, *args) -> None:
        """Have the child make the plant call ``name(*args)`` before its next step.

        Raises
        ------
        PlantProcessError
            If the child has ended.
        """
        try:
            self._conn.send((name, args))
        except (OSError, ValueError) as e:
            raise PlantProcessError("the plant's process has ended") from e


def _run(plant: Plant, step_s: float, started_s: float, shared: PlantProcess, conn) -> None:
    """The child: step ``plant`` on the wall clock and publish each step; serve commands."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    claim_core(PLANT_FIFO_PRIORITY)  # where permitted; else the normal class, as forked
    shared._conn.close()
    wall = WallSteps(step_s, started_s)
    memory, figures, bins = shared._memory, shared._figures, shared._bins
    goal_count = [shared._goals.writes]  # the goals the plant has: those before the fork

    def take_goals() -> None:
        read = shared._goals.read()
        if read is not None and read[0] != goal_count[0]:
            goal_count[0] = read[0]
            plant.set_goal(np.array(read[1]))

    unread = float("inf")  # the steps due while it was forked, run at once: nobody read
    try:
        while True:
            take_goals()
            now = time.monotonic()
            steps = wall.take(now, unread=unread)
            if wall.behind_s(now) < step_s:  # caught up: from now on, as read
                unread = 0.0
            if steps:
                plant.advance(steps * step_s)
                shared._states.write(shared._publish_of(plant, wall.done))
            lag = wall.lag
            _BIN.pack_into(memory, bins + _BIN.size * wall.lag_bin, lag.counts[wall.lag_bin])
            _FIGURES.pack_into(memory, figures, lag.max_s, lag.over_s, time.thread_time())
            now = time.monotonic()
            if not conn.poll(max(0.0, wall.wake_s(now, unread=0.0) - now)):
                continue
            command = conn.recv()
            if command is None:
                return
            take_goals()  # the parent wrote them before this command
            name, args = command
            getattr(plant, name)(*args)
    except (EOFError, OSError):
        return  # the parent has gone
    except Exception as e:  # the plant failed: the parent closes the bus
        with contextlib.suppress(OSError):
            conn.send(e)
