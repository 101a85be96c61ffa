"""Split-phase group reads (``ServoBus.request_block`` / ``collect``) and the frame read layout.

A read's request goes out after a frame's goal and its reply is read before
the next goal. What these tests pin: a reply that is late, corrupt, from the
wrong id or of the wrong length is never trusted (the pty-emulated servo
misbehaves through ``drivers.virtual.faults``); a packet sent while a reply is
due never takes that reply for its own; a stop or a fault while a read is out
still ends in the stated safe state, per servo; and at 1 kHz on 1 Mbps no
frame carries more wire than its budget, while the status poll still runs.
"""

import numpy as np
import pytest
from conftest import quintic_trajectory

from trajgen.drivers.bringup import bring_up
from trajgen.drivers.clock import SimulatedClock
from trajgen.drivers.control_table import Register
from trajgen.drivers.errors import CommError, WatchdogTripped
from trajgen.drivers.frame_reads import FrameReads, Read, parts
from trajgen.drivers.probe import BUDGET
from trajgen.drivers.streamer import Streamer
from trajgen.drivers.units import JointMap
from trajgen.drivers.virtual.bus import Fault, VirtualBus
from trajgen.drivers.virtual.clocked import ClockedBus
from trajgen.drivers.virtual.plant import FirstOrderPlant

MODELS = ("XM430-W350",) * 3
IDS = (1, 2, 3)
STATE = (Register.PRESENT_CURRENT, Register.PRESENT_VELOCITY, Register.PRESENT_POSITION)
STATE_ADDRESS = 126


def _ramp(rate_hz, duration_s=0.3, q_end=(0.2, 0.1, 0.0)):
    return quintic_trajectory(q_end, duration_s, rate_hz)


@pytest.fixture
def rig():
    """make(**VirtualBus options) -> (virtual bus, open ServoBus, servos added), lock-step."""
    made = []

    def make(latency_ms=None, **kwargs):
        kwargs.setdefault("lockstep_dt_s", 0.005)
        virtual = VirtualBus(FirstOrderPlant(time_constant_s=0.01), **kwargs).start()
        bus = virtual.connect(latency_ms=latency_ms).open()
        made.append((virtual, bus))
        for i in IDS:
            bus.add_servo(i, virtual.servos[i].model)
        return virtual, bus

    yield make
    for virtual, bus in made:
        bus.close()
        virtual.stop()


def _truth(virtual):
    return [[virtual.servos[i].get(r) for r in STATE] for i in IDS]


def test_a_split_read_returns_what_a_read_at_once_returns(rig):
    virtual, bus = rig()
    at_once = bus.read_block(IDS, STATE)
    block = bus.collect(bus.request_block(IDS, STATE))
    assert block.table == at_once.table == _truth(virtual)
    assert block.errors == {1: 0, 2: 0, 3: 0}
    assert bus.failed_tries == 0


@pytest.mark.parametrize(
    ("fault", "match"),
    [
        (Fault("corrupt", address=STATE_ADDRESS), "Incorrect status packet"),
        (Fault("wrong_id", servo_id=2, reply_id=3, address=STATE_ADDRESS), "part 1 from id 3"),
        (Fault("short", servo_id=1, n_bytes=2, address=STATE_ADDRESS), "reply of length"),
        (Fault("drop", address=STATE_ADDRESS), "no status packet"),
    ],
)
def test_an_unsound_split_reply_is_never_a_value(rig, fault, match):
    virtual, bus = rig(faults=[fault])
    pending = bus.request_block(IDS, STATE)
    with pytest.raises(CommError, match=match) as raised:
        bus.collect(pending)
    assert f"after {bus.retries + 1} tries" in str(raised.value)  # the split try counts
    assert bus.failed_tries == bus.retries + 1


@pytest.mark.parametrize(
    "fault",
    [
        Fault("corrupt", address=STATE_ADDRESS, count=1),
        Fault("wrong_id", servo_id=3, reply_id=1, address=STATE_ADDRESS, count=1),
        Fault("short", servo_id=2, n_bytes=4, address=STATE_ADDRESS, count=1),
    ],
)
def test_one_unsound_split_reply_is_retried_and_the_true_value_used(rig, fault):
    virtual, bus = rig(faults=[fault])
    block = bus.collect(bus.request_block(IDS, STATE))
    assert block.table == _truth(virtual)
    assert bus.failed_tries == 1


def _wait_for(condition):
    """Until ``condition()`` (polled; a bound of 60 s only against a hang)."""
    import time

    give_up = time.monotonic() + 60.0
    while not condition() and time.monotonic() < give_up:
        time.sleep(0.005)


# A reply 1 s late, against a reply timeout of about 4 ms (an adapter latency of 1 ms):
# late on any host that does not stall the test for a second.
LATE = {"faults": [Fault("delay", delay_s=1.0, address=STATE_ADDRESS, count=1)], "latency_ms": 1}


def test_a_late_split_reply_is_never_taken_for_the_answer(rig):
    # The try fails, the bus is drained, the retry's own reply is used. Once the late
    # bytes are in (the bus wrote them), the next reads are still answered right: they
    # are dropped before each request, never read as a reply.
    virtual, bus = rig(**LATE)
    sent = virtual.bytes_sent
    block = bus.collect(bus.request_block(IDS, STATE))
    assert block.table == _truth(virtual)
    assert bus.failed_tries == 1
    _wait_for(lambda: virtual.bytes_sent >= sent + 2 * 50)  # the retry's reply, the late one
    assert virtual.bytes_sent == sent + 2 * 50
    assert bus.read(2, Register.BUS_WATCHDOG) == virtual.servos[2].get(Register.BUS_WATCHDOG)
    assert bus.read_block(IDS, (Register.TORQUE_ENABLE,)).table == [[0], [0], [0]]
    assert bus.failed_tries == 1


def test_a_packet_sent_while_a_reply_is_due_waits_it_out_and_drops_it(rig):
    virtual, bus = rig(faults=[Fault("delay", delay_s=0.05, address=STATE_ADDRESS, count=1)])
    pending = bus.request_block(IDS, STATE)
    bus.write(2, Register.BUS_WATCHDOG, 0)  # its acknowledgement, not the state reply
    assert bus.read(2, Register.BUS_WATCHDOG) == 0
    with pytest.raises(CommError, match="dropped"):
        bus.collect(pending)
    assert bus.read_block(IDS, STATE).table == _truth(virtual)


@pytest.mark.parametrize("on_stop", ["hold", "torque_off"])
def test_a_stop_signal_while_a_read_is_out_ends_in_the_stated_state(rig, monkeypatch, on_stop):
    # The state replies of frame 30 on come 60 ms late: Ctrl-C arrives while one is
    # still on its way. The safe stop's writes wait it out and each gets its own
    # acknowledgement: every servo holds (watchdog cleared) or is released.
    trajectory = _ramp(200.0)
    virtual, bus = rig(faults=[Fault("delay", delay_s=0.06, address=STATE_ADDRESS, at_frame=30)])
    setup = bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(  # no poll in the way: every state read is split
        bus, JointMap(), on_stop=on_stop, start_ticks=setup.present_ticks, poll_s=10, health_s=10
    )
    collect, calls = bus.collect, []

    def interrupted(pending):
        calls.append(virtual.frames_received)
        if virtual.frames_received >= 30:
            raise KeyboardInterrupt  # mid-read: the reply of frame 30 is out
        return collect(pending)

    monkeypatch.setattr(bus, "collect", interrupted)
    with pytest.raises(KeyboardInterrupt):
        streamer.run(trajectory)
    assert streamer.stop_errors == []
    assert virtual.frames_received == 30 == calls[-1]  # stopped with frame 30's reply out
    servos = [virtual.servos[i] for i in IDS]
    if on_stop == "hold":
        assert all(s.torque_on for s in servos)
        assert [s.get(Register.BUS_WATCHDOG) for s in servos] == [0, 0, 0]
    else:
        assert not any(s.torque_on for s in servos)


def test_a_fault_in_a_split_read_mid_stream_stops_safely(rig):
    trajectory = _ramp(200.0)
    virtual, bus = rig(faults=[Fault("drop", address=STATE_ADDRESS, at_frame=20)])
    bring_up(bus, JointMap(), MODELS, trajectory)
    streamer = Streamer(bus, JointMap(), on_stop="torque_off")
    with pytest.raises(CommError, match="no status packet"):
        streamer.run(trajectory)
    assert virtual.frames_received == 20  # the reply of frame 20 never came: no goal after it
    assert not any(virtual.servos[i].torque_on for i in IDS)
    assert streamer.stop_errors == []


class _TightClock(SimulatedClock):
    """Simulated time the streamer budgets as if it were the wall clock."""

    real_time = True


def _frame_bytes(virtual, bus):
    """Wrap ``bus.sync_write``: bytes on the bus between one goal and the next, per frame."""
    marks = []
    sync_write = bus.sync_write

    def marked(register, values, **kwargs):
        marks.append(virtual.bytes_received + virtual.bytes_sent)
        sync_write(register, values, **kwargs)

    bus.sync_write = marked
    return marks


def test_at_1_khz_and_1_mbps_no_frame_carries_more_wire_than_its_budget():
    clock = _TightClock()
    virtual = ClockedBus(FirstOrderPlant(time_constant_s=0.01), clock=clock).start()
    try:
        with virtual.connect() as bus:
            trajectory = _ramp(1000.0, duration_s=0.4)
            setup = bring_up(bus, JointMap(), MODELS, trajectory)
            streamer = Streamer(
                bus,
                JointMap(),
                telemetry_every=2,
                clock=clock,
                probe_frames=0,
                realtime=False,
                start_ticks=setup.present_ticks,
            )
            polls = []  # the registers each status read held
            status_of = streamer._status_of

            def seen(status, when):
                polls.append(set(next(iter(status.values()))))
                status_of(status, when)

            streamer._status_of = seen
            marks = _frame_bytes(virtual, bus)
            stats = streamer.run(trajectory)
    finally:
        virtual.stop()
    per_frame = np.diff(marks)
    goal_b = 14 + 5 * 3
    budget_b = BUDGET * 1e-3 * 1_000_000 / 10
    state_b = 17 + 50
    # A frame: its goal and either the state read (every 2nd frame, 0.96 ms of wire:
    # the probe's choice, not the layout's) or at most what fits its budget.
    assert per_frame.max() <= goal_b + state_b
    assert all(b == goal_b + state_b or b <= budget_b for b in per_frame)
    # The status poll (142 bytes in one read) went out a register at a time, and
    # every 50 frames (the last poll may be cut by the stream's end) each was read.
    assert stats.frames_sent == len(trajectory)
    status = {Register.TORQUE_ENABLE, Register.HARDWARE_ERROR_STATUS, Register.BUS_WATCHDOG}
    assert all(len(p) == 1 and p <= status for p in polls)
    whole = len(marks) // 50 - 1
    assert len(polls) >= 3 * whole
    assert all(set().union(*polls[3 * n : 3 * n + 3]) == status for n in range(whole))


def test_a_tripped_watchdog_is_still_caught_at_1_khz_on_1_mbps():
    clock = _TightClock()
    faults = [Fault("watchdog", servo_id=2, at_frame=120)]
    virtual = ClockedBus(FirstOrderPlant(time_constant_s=0.01), clock=clock, faults=faults).start()
    try:
        with virtual.connect() as bus:
            trajectory = _ramp(1000.0, duration_s=0.4)
            bring_up(bus, JointMap(), MODELS, trajectory)
            streamer = Streamer(
                bus, JointMap(), telemetry_every=2, clock=clock, probe_frames=0, realtime=False
            )
            with pytest.raises(WatchdogTripped, match="servo 2"):
                streamer.run(trajectory)
    finally:
        virtual.stop()
    # Within one poll period (50 frames) and the frames its parts take.
    assert 120 <= virtual.frames_received <= 120 + 50 + 20


def _layout(room_b, read_every, poll_every=50, health_every=500, extra_s=0.0, baud=1_000_000):
    def size(ids, registers):  # fast sync read: request 14 + n, reply 8 + n (data + 4)
        span = {Register.TORQUE_ENABLE: 1, Register.HARDWARE_ERROR_STATUS: 1}
        data = sum(span.get(r, 1) for r in registers) if len(registers) < 3 else 35
        return 14 + len(ids) + 8 + len(ids) * (data + 4)

    status = (Register.TORQUE_ENABLE, Register.HARDWARE_ERROR_STATUS, Register.BUS_WATCHDOG)
    health = (Register.PRESENT_INPUT_VOLTAGE, Register.PRESENT_TEMPERATURE)
    room_s = room_b * 10 / baud
    reads = FrameReads(
        Read("state", IDS, STATE, 67),
        parts("status", IDS, status, size, room_b - extra_s * baud / 10),
        parts("health", IDS, health, size, room_b - extra_s * baud / 10, by_register=False),
        lambda r: r.n_bytes * 10 / baud + extra_s,
        room_s,
        read_every,
        poll_every,
        health_every,
    )
    return reads, size


def test_the_polls_are_split_to_fit_and_all_go_out_within_a_poll_period():
    reads, size = _layout(room_b=51, read_every=2)  # 1 kHz, 1 Mbps: 80 bytes less the goal
    assert size(IDS, reads.status[0].registers) <= 51
    assert sorted({r for p in reads.status for r in p.registers}, key=str) == sorted(
        {Register.TORQUE_ENABLE, Register.HARDWARE_ERROR_STATUS, Register.BUS_WATCHDOG}, key=str
    )
    frames = [reads.for_frame(k) for k in range(520)]
    for k, carried in enumerate(frames):
        assert (carried[:1] == [reads.state]) == (k % 2 == 0)  # never skipped at 2
        polls = [r for r in carried if r.kind != "state"]
        if carried and carried[0] is reads.state:
            assert polls == []  # 67 bytes leave no room
        else:
            assert len(polls) <= 1
    status = [k for k, c in enumerate(frames) for r in c if r.kind == "status"]
    assert len(status) == 10 * len(reads.status)
    for poll in range(10):  # poll n falls due at frame 50 n + 49 and is done within 20 frames
        done = status[poll * len(reads.status) : (poll + 1) * len(reads.status)]
        assert 50 * poll + 49 <= done[0] and done[-1] < 50 * poll + 49 + 20
    assert reads.skipped == 0


def test_at_read_every_1_a_poll_part_takes_a_state_reads_place():
    reads, _ = _layout(room_b=200, read_every=1, extra_s=0.4e-3, baud=4_000_000)
    frames = [reads.for_frame(k) for k in range(100)]
    assert all(len(c) == 1 for c in frames)  # never two round trips in one frame
    polls = [k for k, c in enumerate(frames) if c[0].kind != "state"]
    assert reads.skipped == len(polls) > 0
    assert polls[0] in (49, 50)


def test_with_room_every_read_due_goes_in_its_frame_in_the_order_it_always_had():
    # Status due at frames 9, 19, 29, ...; health at 9, 27 (k % 18 == 9).
    reads, _ = _layout(room_b=float("inf"), read_every=1, poll_every=10, health_every=18)
    frames = [reads.for_frame(k) for k in range(40)]
    assert [r.kind for r in frames[9]] == ["state", "status", "health"]
    assert [r.kind for r in frames[19]] == ["state", "status"]
    assert [r.kind for r in frames[27]] == ["state", "health"]
    assert [r.kind for r in frames[0]] == ["state"]
    assert len(reads.status) == 1 and reads.status[0].ids == IDS  # one read, as before


def test_await_reply_says_whether_the_reply_is_in_and_never_reads_it(rig):
    import time

    virtual, bus = rig(**LATE)
    pending = bus.request_block(IDS, STATE)
    assert not bus.await_reply(pending, time.monotonic() + 0.002)  # 1 s late: not yet
    block = bus.collect(pending)  # past its timeout: a failed try, then a read at once
    assert block.table == _truth(virtual) and bus.failed_tries == 1
    pending = bus.request_block(IDS, STATE)  # lock-step: answered as it was sent, but
    # the pty hands the bytes over in the kernel's time: the wait ends once they are in
    assert bus.await_reply(pending, time.monotonic() + 10.0)
    assert bus.collect(pending).table == _truth(virtual) and bus.failed_tries == 1
