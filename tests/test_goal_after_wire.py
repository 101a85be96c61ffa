"""A goal goes out once the wire is free, not once the last reply is in hand.

On the wall clock, ``Streamer._loop`` sends a goal behind a reply it has not
read yet once that reply's computed wire end has passed, then checks the reply
before anything else is sent. The virtual bus with wire timing models what
that risks: a host packet arriving while a reply is on the wire collides with
it (both garbled, ``VirtualBus.collisions``). What these tests pin: a normal
servo never collides; a servo answering later than computed ("late" fault)
collides, and the garbled reply is a failed try, never trusted; an unsound
reply checked after the next goal is never trusted either; Ctrl-C with a reply
outstanding ends in the stated state per servo. The rig's adapter latency
(0.6 ms after a reply's last byte, as a USB adapter's latency timer) keeps
every read-back reply out of the host's hands until after the next deadline,
so that every read-back frame's next goal goes out behind its reply.
"""

import time

import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.bus import WIRE_MARGIN_S, ServoBus
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import CommError, ServoError
from trajgen.drivers.frame_packets import sync_write_bytes
from trajgen.drivers.frame_reads import FrameReads, Read
from trajgen.drivers.probe import REPLY_WAIT_S, CycleCost, read_every_for
from trajgen.drivers.streamer import Streamer, StreamStats
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import Fault, VirtualBus, WireTiming
from trajgen.drivers.virtual.plant import FirstOrderPlant

MODELS = ("XM430-W350",) * 3
IDS = (1, 2, 3)
STATE_ADDRESS = 126
STATE = (Register.PRESENT_CURRENT, Register.PRESENT_VELOCITY, Register.PRESENT_POSITION)
BAUD = 1_000_000
ADAPTER_LATENCY_S = 0.3e-3
# Reply timeouts of about 200 ms and a Bus Watchdog of 1 s: a busy host's stalls (this
# emulator is a thread of the test's process) fail no read and trip no watchdog.
LATENCY_MS = 100


def _ramp(rate_hz, duration_s=0.3, q_end=(0.2, 0.1, 0.0)):
    return quintic_trajectory(q_end, duration_s, rate_hz)


@pytest.fixture
def rig():
    """make(faults, adapter latency, held_back, Streamer options) -> (virtual bus, open
    ServoBus after bring-up, trajectory, Streamer on the wall clock): real time, wire timing
    at 1 Mbps, Return Delay 0, no probe (its choice depends on the host: read back as
    asked). ``held_back``: the host never has a reply in hand at the next deadline (as
    behind an adapter that holds every reply back), so that every read-back frame's next
    goal goes out behind its reply whatever the host's load."""
    made = []

    def make(faults=(), adapter_latency_s=ADAPTER_LATENCY_S, held_back=False, **options):
        timing = WireTiming(baud=BAUD, adapter_latency_s=adapter_latency_s)
        plant = FirstOrderPlant(time_constant_s=0.01)
        virtual = VirtualBus(plant, timing=timing, faults=faults).start()
        bus = ServoBus(virtual.port, baud=BAUD, latency_ms=LATENCY_MS).open()
        made.append((virtual, bus))
        trajectory = _ramp(1000.0)
        setup = bring_up(bus, JointMap(), MODELS, trajectory, configure=True, watchdog_s=1.0)
        options = {"max_delay_s": None, "realtime": False, "probe_frames": 0} | options
        options |= {"poll_s": 10, "health_s": 10}  # no poll: every state read is split
        if held_back:  # no reply is ever in hand at the next deadline, however late it wakes
            bus.await_reply = lambda pending, until_s: False
            options["stall_s"] = 1.0  # and no late wake is a stall (it would collect first)
        streamer = Streamer(bus, JointMap(), start_ticks=setup.present_ticks, **options)
        return virtual, bus, trajectory, streamer

    yield make
    for virtual, bus in made:
        bus.close()
        virtual.stop()


def _arrived_after_each_reply(virtual) -> bool:
    """The emulator's record: every host packet came in at or after the end of the reply
    before it on the wire."""
    return all(arrival >= end for arrival, end in virtual.wire_log)


def test_a_normal_servo_never_collides_over_a_1_khz_stream_at_1_mbps(rig):
    virtual, _, trajectory, streamer = rig(telemetry_every=1)
    stats = streamer.run(trajectory)
    assert stats.fault == "" and stats.frames_sent == len(trajectory)
    # A read-back's reply is still in the adapter at the next deadline: that goal went
    # out behind it, once its wire end had passed (never over it), and that frame's own
    # read no longer fitted before the next deadline: deferred, one request at a time.
    assert stats.goals_behind > 0 and stats.reads_deferred > 0
    assert virtual.collisions == 0
    assert _arrived_after_each_reply(virtual)


def test_a_normal_servo_without_adapter_latency_never_collides_either(rig):
    virtual, _, trajectory, streamer = rig(adapter_latency_s=0.0, telemetry_every=1)
    stats = streamer.run(trajectory)
    assert stats.fault == ""
    assert virtual.collisions == 0
    assert _arrived_after_each_reply(virtual)


# The state reply of frame 30 starts 20 ms after its Return Delay Time: the goal sent at
# its computed wire end comes in while it is on the wire.
LATE = Fault("late", delay_s=20e-3, address=STATE_ADDRESS, at_frame=30, count=1)


def test_a_late_servo_collides_and_the_garbled_reply_is_retried_never_trusted(rig):
    virtual, bus, trajectory, streamer = rig(faults=[LATE], held_back=True, telemetry_every=3)
    log = _one_request_at_a_time(bus)
    stats = streamer.run(trajectory)
    assert virtual.collisions == 1
    assert not _arrived_after_each_reply(virtual)  # the emulator saw it come in too early
    # The reply's CRC was broken: a failed try, retried at once; the stream went on.
    assert stats.comm_errors == bus.failed_tries == 1
    assert stats.fault == "" and stats.frames_sent == len(trajectory)
    # The goals that collided were dropped by the servos (their CRC): the one that came
    # in over the reply, and any others in with it (a loaded host may send the goals
    # carried behind the reply in a burst); never more than went out behind it.
    sent = stats.approach_frames + len(trajectory)
    behind = max(len(times) for _, times in _behind_each_reply(log))
    assert 1 <= sent - virtual.frames_received <= behind


def test_a_late_servo_without_retries_ends_in_the_stated_state(rig):
    virtual, bus, trajectory, streamer = rig(faults=[LATE], held_back=True, telemetry_every=3)
    bus.retries = 0
    with pytest.raises(CommError, match="Incorrect status packet|corrupt"):
        streamer.run(trajectory)
    assert virtual.collisions == 1
    assert streamer.stop_errors == []
    servos = [virtual.servos[i] for i in IDS]  # hold: torque on, Bus Watchdog cleared
    assert all(s.torque_on for s in servos)
    assert [s.get(Register.BUS_WATCHDOG) for s in servos] == [0, 0, 0]


@pytest.mark.parametrize(
    ("fault", "match"),
    [
        (Fault("corrupt", address=STATE_ADDRESS, at_frame=30), "Incorrect status packet"),  # CRC
        (
            Fault("wrong_id", servo_id=2, reply_id=3, address=STATE_ADDRESS, at_frame=30),
            "part 1 from id 3",
        ),
        (Fault("short", servo_id=1, n_bytes=2, address=STATE_ADDRESS, at_frame=30), "length"),
    ],
)
def test_an_unsound_reply_checked_after_the_next_goal_is_never_trusted(rig, fault, match):
    # Every reply from frame 30 on is unsound: each try is refused, none used.
    virtual, bus, trajectory, streamer = rig(faults=[fault], held_back=True, telemetry_every=3)
    goals_behind = []  # per goal: sent behind a reply not read yet
    sync_write = bus.sync_write

    def noted(register, values, *, behind=None):
        goals_behind.append(behind is not None)
        sync_write(register, values, behind=behind)

    bus.sync_write = noted
    with pytest.raises(CommError, match=match):
        streamer.run(trajectory)
    # The stream stopped on a reply checked right after the goal that went out behind it.
    assert goals_behind[-1] is True
    assert all(virtual.servos[i].torque_on for i in IDS) and streamer.stop_errors == []


def test_ctrl_c_with_a_reply_outstanding_ends_in_the_stated_state(rig):
    virtual, bus, trajectory, streamer = rig(held_back=True, telemetry_every=3, on_stop="hold")
    sync_write, goals = bus.sync_write, []

    def interrupted(register, values, *, behind=None):
        sync_write(register, values, behind=behind)
        goals.append(dict(values))
        if behind is not None and len(goals) > 30:
            raise KeyboardInterrupt  # the goal went out behind a reply not read yet

    bus.sync_write = interrupted
    with pytest.raises(KeyboardInterrupt):
        streamer.run(trajectory)
    # The safe stop's writes waited the reply out and each got its own acknowledgement:
    # every servo holds its last goal, torque on, Bus Watchdog cleared.
    assert streamer.stop_errors == []
    servos = [virtual.servos[i] for i in IDS]
    assert all(s.torque_on for s in servos)
    assert [s.get(Register.BUS_WATCHDOG) for s in servos] == [0, 0, 0]
    assert [s.get(Register.GOAL_POSITION) for s in servos] == list(goals[-1].values())
    assert virtual.collisions == 0


def test_the_probe_judges_a_read_back_frame_by_its_wire_end():
    # 1 kHz at 1 Mbps: goal 0.29 ms, read-back wire 0.84 ms (0.15 ms margin in), replies in hand
    # 1.5 ms after the request (an adapter's latency): the next goal goes out behind them.
    cost = CycleCost(2.9e-4, 1.5e-3, 50, (1.5e-3,) * 50, read_wire_s=0.84e-3)
    assert read_every_for(cost, 1e-3) == 3  # the mean: 0.29 + 1.5 / 3 <= 0.8 ms
    # At 1.5 kHz a read-back frame is on the wire past the next deadline's stall bound.
    assert read_every_for(cost, 1 / 1500) is None
    # Replies in 2.4 ms (1.3 ms after their wire end) are carried behind the next goals:
    # no stall; the mean decides, 0.29 + 2.4 / 5 <= 0.8 ms.
    assert read_every_for(CycleCost(2.9e-4, 2.4e-3, 50, read_wire_s=0.84e-3), 1e-3) == 5
    # Replies in 9 ms: carried up to REPLY_WAIT_S (5 ms) past their wire end (1.13 ms), the
    # goal at the next deadline after that (7 ms) waits for them, and the one after it
    # (8 ms) goes more than half a period late: refused.
    assert read_every_for(CycleCost(2.9e-4, 9e-3, 50, read_wire_s=0.84e-3), 1e-3) is None
    # From the tail: 2 of 50 such replies shift the stream by 1.29 ms each over 50 reads.
    tail = CycleCost(2.9e-4, 1e-3, 50, (1e-3,) * 48 + (9e-3,) * 2, read_wire_s=0.84e-3)
    assert tail.late(1e-3) == (2, pytest.approx(2 * (9.29e-3 - 8e-3) / 50))


def test_deferred_reads_go_out_in_the_next_frame():
    state = Read("state", IDS, ("state",), 67)
    status = [Read("status", IDS, (r,), 31) for r in ("torque", "error", "watchdog")]
    # 10 us a byte, 0.8 ms a frame: the state read (0.67 ms) leaves no room for a part
    # (0.31 ms); a frame without it carries two parts. State every 2nd frame, the
    # poll queued at frames 2, 5, ...
    reads = FrameReads(state, status, [], lambda r: 1e-5 * r.n_bytes, 8e-4, 2, 3, 1000)
    assert reads.for_frame(0) == [state]
    reads.defer([state])  # owed: frame 1 carries it, though not a state frame
    assert reads.for_frame(1) == [state]
    # The next state read comes 2 frames after the one deferred, never in the frame
    # right after it (at 1 Mbps two read-back frames in a row would make each next goal
    # later than the last).
    assert reads.for_frame(2) == status[:2]
    reads.defer(status[:2])  # first in the queue again, before the third part
    assert reads.for_frame(3) == [state]
    assert reads.for_frame(4) == status[:2]
    assert reads.for_frame(5) == [state]
    assert reads.for_frame(6) == [status[2], status[0]]  # and the next poll's first part
    assert reads.deferred == 3
    # Laid out with no deferral, state reads are read_every apart from frame 0.
    plain = FrameReads(state, [], [], lambda r: 1e-5 * r.n_bytes, 8e-4, 3, 1000, 1000)
    assert [k for k in range(12) if plain.for_frame(k)] == [0, 3, 6, 9]


def test_poll_parts_fit_the_wire_before_the_next_deadline_whatever_the_host_adds(rig):
    # 1 kHz at 1 Mbps, a read-back in hand 0.3 ms after its wire time (the pty's figure
    # here): where goals go out behind a reply, a status poll part need only be off the
    # wire, with margin, before the next deadline. Laid out by wire and host time (the
    # old rule), no part fitted: the whole poll (142 bytes, 1.42 ms) went in one frame
    # and made the next goal a stall every 50 frames.
    _, bus, _, streamer = rig()
    bus.return_delay_s = 0.0  # bring-up's Return Delay 0, as the stream reads it at its start
    streamer.stats = StreamStats(rate_hz=1000.0, frames_planned=1)
    state_wire_s = bus.wire_s(bus.read_bytes(IDS, STATE))
    streamer.stats.probe_read_s = state_wire_s + 0.3e-3
    layout = streamer._frame_reads(1e-3)
    goal_s = bus.wire_s(sync_write_bytes(len(IDS), 4))
    status = {r for part in layout.status for r in part.registers}
    assert status == {Register.TORQUE_ENABLE, Register.HARDWARE_ERROR_STATUS, Register.BUS_WATCHDOG}
    assert len(layout.status) == 3  # a register at a time
    for part in (*layout.status, *layout.health):
        wire_end_s = goal_s + bus.wire_s(part.n_bytes) + bus.reply_s(0) + WIRE_MARGIN_S
        assert wire_end_s <= 1e-3
    # A lock-step bus (every reply in hand before the next packet) keeps the host's time
    # in a part's room: there the poll stays whole.
    bus.lockstep = True
    assert len(streamer._frame_reads(1e-3).status) == 1


def _one_request_at_a_time(bus) -> list:
    """Wrap ``bus.request_block`` and ``bus.sync_write``: fail if a request goes out while
    another's reply is outstanding; returns the log of goals, ``(PendingRead the goal went
    out behind or None, time.monotonic() once sent)``, and requests, ``("request",
    PendingRead)``, in order."""
    log = []
    request_block, sync_write = bus.request_block, bus.sync_write

    def request(*args, **kwargs):
        assert bus._pending is None, "a request went out while another's reply was outstanding"
        pending = request_block(*args, **kwargs)
        log.append(("request", pending))
        return pending

    def goal(register, values, *, behind=None):
        sync_write(register, values, behind=behind)
        log.append((behind, time.monotonic()))

    bus.request_block, bus.sync_write = request, goal
    return log


def _behind_each_reply(log) -> list[tuple]:
    """Per reply goals went out behind: (its PendingRead, the send times of those goals)."""
    groups = {}
    for who, when in log:
        if who != "request" and who is not None:
            groups.setdefault(id(who), (who, []))[1].append(when)
    return list(groups.values())


def _carried_within_the_bound(log) -> bool:
    """Every goal behind a reply but the last one went out before REPLY_WAIT_S past that
    reply's wire end: the stream stops carrying a reply there (whatever the host's load;
    the last goal is the one after which it was found past the bound)."""
    return all(
        t < pending.wire_end_s + REPLY_WAIT_S
        for pending, times in _behind_each_reply(log)
        for t in times[:-1]
    )


def test_a_reply_still_held_after_the_next_goal_is_carried_never_two_requests(rig, tmp_path):
    # The adapter holds every reply past the next deadline and past the goal that goes out
    # behind it: it is carried over the next frames until REPLY_WAIT_S past its wire end,
    # then checked; meanwhile goals go out behind it and the frames' reads wait.
    path = tmp_path / "run.csv"
    virtual, bus, trajectory, streamer = rig(held_back=True, telemetry_every=3, telemetry=path)
    log = _one_request_at_a_time(bus)
    stats = streamer.run(trajectory)
    assert stats.fault == "" and stats.frames_sent == len(trajectory)
    assert stats.replies_carried > 0 and stats.reads_deferred > 0
    assert stats.reply_check_max_s >= REPLY_WAIT_S  # held back: carried to the bound
    assert virtual.collisions == 0 and _arrived_after_each_reply(virtual)
    # Replies were carried behind several goals each, never past the bound.
    assert max(len(times) for _, times in _behind_each_reply(log)) > 1
    assert _carried_within_the_bound(log)
    # Every frame's telemetry row is written, in order, each read's state in its frame's row.
    table = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert list(table["frame"]) == list(range(stats.frames_sent + stats.approach_frames))
    read = np.isfinite(table["position_rad_pan"])
    assert read.sum() == stats.reads - stats.reads_skipped > 0


def test_a_hardware_error_in_a_carried_reply_stops_within_its_bound(rig):
    # From frame 60 servo 2 reports an overload in every reply's ERR byte. Its reply is
    # held back and carried: the stream stops on it, no goal sent behind it past
    # REPLY_WAIT_S after its wire end but the one after which it was checked, and every
    # servo ends in the stated state.
    overload = Fault("overload", servo_id=2, at_frame=60)
    virtual, bus, trajectory, streamer = rig(faults=[overload], held_back=True, telemetry_every=3)
    log = _one_request_at_a_time(bus)
    with pytest.raises(ServoError, match="servo 2"):
        streamer.run(trajectory)
    # It stopped on the last reply asked for (one request at a time), after the goals
    # carried behind it, none sent past the bound but the one after which it was checked.
    last = max(i for i, (who, _) in enumerate(log) if who == "request")
    assert all(who is log[last][1] for who, _ in log[last + 1 :])
    assert _carried_within_the_bound(log)
    # The others hold, torque on; servo 2's torque is off (its own shutdown), said.
    assert [virtual.servos[i].torque_on for i in IDS] == [True, False, True]
    assert len(streamer.stop_errors) == 1 and "servo 2: hardware error" in streamer.stop_errors[0]
    assert virtual.collisions == 0
