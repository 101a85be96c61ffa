"""The virtual bus as any Dynamixel tool sees it: the official SDK, unmodified, on the pty.

Addresses below are the XM430-W350's (e-Manual); error codes the Protocol 2.0
status ERR values: 1 result fail, 2 instruction, 4 data range, 5 data length,
6 data limit, 7 access.
"""

import gc
import multiprocessing
import threading
import time

import pytest
from dynamixel_sdk import (
    BROADCAST_ID,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    PacketHandler,
    PortHandler,
)

from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.plant import FirstOrderPlant

TORQUE, LED, SRL, REGISTERED, HW_ERROR = 64, 65, 68, 69, 70
D_GAIN, P_GAIN, GOAL_PWM, PROFILE_VELOCITY, GOAL_POSITION = 80, 84, 100, 112, 116
TICK, MOVING, MOVING_STATUS, PRESENT_PWM, PRESENT_CURRENT = 120, 122, 123, 124, 126
PRESENT_POSITION, VELOCITY_TRAJECTORY, POSITION_TRAJECTORY = 132, 136, 140
INPUT_VOLTAGE, TEMPERATURE = 144, 146
RETURN_DELAY, OPERATING_MODE, MAX_POSITION_LIMIT = 9, 11, 48
INDIRECT_ADDRESS_1, INDIRECT_DATA_1, INDIRECT_ADDRESS_29 = 168, 224, 578
RESULT_FAIL, INSTRUCTION, DATA_RANGE, DATA_LENGTH, DATA_LIMIT, ACCESS = 1, 2, 4, 5, 6, 7


class Sdk:
    """The official SDK's port and packet handler on a virtual bus, with checked calls."""

    def __init__(self, virtual):
        self.virtual = virtual
        if virtual.lockstep_dt_s is None:
            self.port = PortHandler(virtual.port)
        else:  # lock-step: each packet answered in this thread as it is written (no wait for
            # the serving thread on a busy host); the SDK's packet handler reads the reply
            from trajgen.drivers.bus import _make_port

            self.port = _make_port(virtual.port, 160.0, responder=virtual)
            virtual.attach_client()
        assert self.port.openPort()
        assert self.port.setBaudRate(1_000_000)
        self.ph = PacketHandler(2.0)

    def write(self, servo_id, address, value, size):
        call = {1: self.ph.write1ByteTxRx, 2: self.ph.write2ByteTxRx, 4: self.ph.write4ByteTxRx}
        result, error = call[size](self.port, servo_id, address, value % (1 << (8 * size)))
        assert result == COMM_SUCCESS, self.ph.getTxRxResult(result)
        return error

    def read(self, servo_id, address, size, *, signed=False):
        call = {1: self.ph.read1ByteTxRx, 2: self.ph.read2ByteTxRx, 4: self.ph.read4ByteTxRx}
        value, result, error = call[size](self.port, servo_id, address)
        assert result == COMM_SUCCESS, self.ph.getTxRxResult(result)
        assert error == 0, self.ph.getRxPacketError(error)
        if signed and value >= 1 << (8 * size - 1):
            value -= 1 << (8 * size)
        return value

    def position(self, servo_id):
        return self.read(servo_id, PRESENT_POSITION, 4, signed=True)

    def close(self):
        self.port.closePort()
        self.virtual.stop()


def _sdk(plant=None, *, lockstep_dt_s=0.01, **kwargs):
    return Sdk(
        VirtualBus(plant or FirstOrderPlant(), lockstep_dt_s=lockstep_dt_s, **kwargs).start()
    )


@pytest.fixture
def sdk(monkeypatch):
    """Make SDK rigs. Their reply timeout is 10x the SDK's 34 ms: these tests check
    what the servos answer, on a machine that may be busy; the one test about
    reply time runs with the SDK's own timeout."""
    monkeypatch.setattr("dynamixel_sdk.port_handler.LATENCY_TIMER", 160)
    gc.collect()  # late in a long session, a full collection can outlast a reply timeout
    made = []

    def make(*args, **kwargs):
        made.append(_sdk(*args, **kwargs))
        return made[-1]

    yield make
    for s in made:
        s.close()


def _poll_until_at(s, servo_id, goal, *, polls=200, threshold=20):
    """Poll Present Position as ROBOTIS' read_write example does; the polls it took."""
    for k in range(polls):
        if abs(s.position(servo_id) - goal) <= threshold:
            return k
    raise AssertionError(f"servo {servo_id} never reached {goal}: at {s.position(servo_id)}")


def _raw(s, servo_id, instruction, params):
    """Send one instruction packet with ``params`` through the SDK: (result, status error)."""
    packet = [0] * 8 + list(params) + [0, 0]
    packet[4], packet[5], packet[7] = servo_id, len(params) + 3, instruction
    _, result, error = s.ph.txRxPacket(s.port, packet)
    return result, error


# -- time ------------------------------------------------------------------------


def _every_instruction(s):
    """{name: call() -> (result, status error)} for every instruction but the ones that
    reach the plant's own settings (``_plant_instructions``)."""
    bulk = GroupBulkRead(s.port, s.ph)
    assert bulk.addParam(1, PRESENT_POSITION, 4) and bulk.addParam(2, TICK, 2)
    return {
        "PING": lambda: s.ph.ping(s.port, 1)[1:],
        "READ": lambda: s.ph.read4ByteTxRx(s.port, 1, PRESENT_POSITION)[1:],
        "WRITE": lambda: s.ph.write4ByteTxRx(s.port, 1, GOAL_POSITION, 2100),
        "REG_WRITE": lambda: s.ph.regWriteTxRx(s.port, 1, LED, 1, [1]),
        # ACTION is broadcast (no status): its check is that the LED it lit reads 1.
        "ACTION": lambda: (s.ph.action(s.port, BROADCAST_ID), s.read(1, LED, 1) - 1),
        "BULK_READ": lambda: (bulk.txRxPacket(), 0),
        "FAST_BULK_READ": lambda: (bulk.fastBulkRead(), 0),
        "CLEAR": lambda: s.ph.clearMultiTurn(s.port, 2),  # at rest (torque off)
    }


def _plant_instructions(s):
    """{name: call()} of the instructions that change what the plant simulates (its
    settings: torque, the position loop)."""
    return {
        "WRITE Operating Mode": lambda: s.ph.write1ByteTxRx(s.port, 2, OPERATING_MODE, 4),
        "REBOOT": lambda: s.ph.reboot(s.port, 1),
        "FACTORY_RESET": lambda: s.ph.factoryReset(s.port, 1, 0x02),
    }


def test_real_time_no_instruction_makes_the_serving_thread_step_the_plant(sdk):
    # The plant in a thread of this process: after a pause (steps fall due), every
    # instruction is answered from the latest step; only the simulation thread steps.
    sim_plant = pytest.importorskip("trajgen.sim.plant")
    stepped_by = set()

    class Recording(sim_plant.GimbalPlant):
        def advance(self, dt_s):
            stepped_by.add(threading.current_thread().name)
            super().advance(dt_s)

    s = sdk(Recording(record=False), lockstep_dt_s=None)
    s.write(1, TORQUE, 1, 1)
    for name, call in {**_every_instruction(s), **_plant_instructions(s)}.items():
        time.sleep(0.05)
        assert call() == (COMM_SUCCESS, 0), name
    assert s.read(1, LED, 1) == 0  # ACTION lit it, REBOOT put it out
    assert stepped_by == {"virtual-bus_simulate"}
    assert s.virtual.sim_time_s <= s.virtual.wall_time_s  # never ahead of the wall clock


def test_real_time_replies_do_not_wait_for_a_simulation_held_back(sdk):
    # The plant in its own process, held inside a step (as by a host that does not run
    # it): every instruction is answered meanwhile, from the last step (the tick stands
    # still), settings included (the plant takes them when it steps again).
    sim_plant = pytest.importorskip("trajgen.sim.plant")
    fork = multiprocessing.get_context("fork")
    held, release = fork.Event(), fork.Event()

    class Held(sim_plant.GimbalPlant):
        def advance(self, dt_s):
            if self.time_s >= 0.05 and not release.is_set():
                held.set()
                release.wait()
            super().advance(dt_s)

    s = sdk(Held(record=False), lockstep_dt_s=None, plant_process=True)
    s.write(1, TORQUE, 1, 1)
    assert held.wait(timeout=60)  # a guard against a hang, not a time limit
    tick = s.read(1, TICK, 2)
    for name, call in {**_every_instruction(s), **_plant_instructions(s)}.items():
        assert call() == (COMM_SUCCESS, 0), name
    assert s.read(1, LED, 1) == 0  # ACTION lit it, REBOOT put it out
    assert s.read(1, TICK, 2) == tick  # still held: the same step
    release.set()
    assert any(s.read(1, TICK, 2) != tick for _ in range(100_000))  # it steps again
    assert s.virtual.sim_time_s <= s.virtual.wall_time_s  # never ahead of the wall clock
    assert s.virtual.error is None


def test_realtime_tick_counts_milliseconds_in_real_time(sdk):
    s = sdk(lockstep_dt_s=None)
    t0 = time.monotonic()
    first = s.read(1, TICK, 2)
    t1 = time.monotonic()
    time.sleep(0.2)
    t2 = time.monotonic()
    second = s.read(1, TICK, 2)
    t3 = time.monotonic()
    elapsed_ms = (second - first) % 32_768
    # The wall time between the two replies, however long a busy host took: the tick
    # counts it to the step (1 ms), less what a reply said the simulation lagged.
    lag_ms = 1e3 * s.virtual.stale_max_s
    assert 1e3 * (t2 - t1) - lag_ms - 1 <= elapsed_ms <= 1e3 * (t3 - t0) + lag_ms + 1


def test_lockstep_tick_counts_periods(sdk):
    s = sdk()  # 10 ms periods
    assert s.read(1, TICK, 2) == 0
    s.write(1, GOAL_POSITION, 2048, 4)  # a goal write ends a period
    assert s.read(1, TICK, 2) == 10
    assert s.read(1, TICK, 2) == 20  # a poll with no goal since the last ends another


# -- goals ---------------------------------------------------------------------------


@pytest.mark.parametrize("lockstep_dt_s", [0.01, None], ids=["lockstep", "realtime"])
def test_a_goal_sent_by_plain_write_moves_the_servo(sdk, lockstep_dt_s):
    s = sdk(FirstOrderPlant(time_constant_s=0.02), lockstep_dt_s=lockstep_dt_s)
    assert s.write(1, TORQUE, 1, 1) == 0
    assert s.write(1, GOAL_POSITION, 3000, 4) == 0
    if lockstep_dt_s is None:
        time.sleep(0.3)
    _poll_until_at(s, 1, 3000, threshold=1)


def test_goal_at_the_limit_settles_there_and_beyond_is_refused(sdk):
    sim_plant = pytest.importorskip("trajgen.sim.plant")
    s = sdk(sim_plant.GimbalPlant(), lockstep_dt_s=0.005)
    s.write(1, TORQUE, 1, 1)
    assert s.write(1, GOAL_POSITION, 4096, 4) == DATA_LIMIT  # Max Position Limit 4095
    assert s.write(1, GOAL_POSITION, 4095, 4) == 0
    trace = [s.position(1) for _ in range(600)]  # 3 s of polls
    # The firmware loop (P 800, D 0, drive saturated on a half-turn step) overshoots
    # by about 50 ticks (4 deg) before settling; the limit bounds goals, not motion.
    assert max(trace) <= 4095 + 70
    assert abs(trace[-1] - 4095) <= 5


def test_goal_limits_follow_the_limit_registers(sdk):
    s = sdk()
    assert s.write(2, MAX_POSITION_LIMIT, 3000, 4) == 0
    assert s.write(2, GOAL_POSITION, 3001, 4) == DATA_LIMIT
    assert s.write(2, OPERATING_MODE, 4, 1) == 0  # extended position: limits do not apply
    assert s.write(2, GOAL_POSITION, 5000, 4) == 0
    assert s.write(2, GOAL_POSITION, 2_000_000, 4) == DATA_RANGE  # beyond +-1,048,575


def test_goal_held_is_clamped_when_the_limits_narrow(sdk):
    s = sdk(FirstOrderPlant(time_constant_s=0.0))
    assert s.write(1, GOAL_POSITION, 3000, 4) == 0  # torque off: goals are accepted
    assert s.write(1, MAX_POSITION_LIMIT, 2500, 4) == 0
    assert s.read(1, GOAL_POSITION, 4) == 3000  # the register keeps what was written
    s.write(1, TORQUE, 1, 1)
    _poll_until_at(s, 1, 2500, threshold=0)  # the servo goes no further than the limit
    assert max(s.position(1) for _ in range(5)) == 2500
    s.write(1, TORQUE, 0, 1)
    s.write(1, OPERATING_MODE, 4, 1)  # extended position: no limits
    s.write(1, GOAL_POSITION, 9000, 4)
    s.write(1, OPERATING_MODE, 3, 1)  # back to position mode: the goal is clamped again
    s.write(1, TORQUE, 1, 1)
    _poll_until_at(s, 1, 2500, threshold=0)


# -- what a real servo refuses ----------------------------------------------------------


def test_refusals_carry_the_manuals_error_bits(sdk):
    s = sdk()
    assert s.write(1, GOAL_POSITION, 2048, 2) == DATA_LENGTH  # half of a 4-byte register
    assert s.write(1, PRESENT_POSITION, 5, 4) == ACCESS  # read-only
    assert s.write(1, 14, 0, 1) == ACCESS  # no register there
    assert s.write(1, PROFILE_VELOCITY, 40_000, 4) == DATA_RANGE  # 0..32,767
    assert s.write(1, GOAL_PWM, 900, 2) == DATA_LIMIT  # beyond PWM Limit 885
    assert s.write(1, TORQUE, 2, 1) == DATA_RANGE
    assert s.write(1, TORQUE, 1, 1) == 0
    assert s.write(1, RETURN_DELAY, 0, 1) == ACCESS  # EEPROM while torque is on
    assert s.write(1, TORQUE, 0, 1) == 0
    assert s.write(1, RETURN_DELAY, 0, 1) == 0
    assert s.read(1, RETURN_DELAY, 1) == 0
    data, result, error = s.ph.readTxRx(s.port, 1, 660, 10)  # past the table's end
    assert (result, error) == (COMM_SUCCESS, ACCESS)


def test_unknown_instruction_gets_the_instruction_error(sdk):
    s = sdk()
    assert _raw(s, 1, 0x7F, []) == (COMM_SUCCESS, INSTRUCTION)


def test_present_values_are_clamped_to_their_register_not_fatal(sdk):
    # 1e6 A per rad of error: Present Current would need far more than 16 bits.
    s = sdk(FirstOrderPlant(current_per_rad_a=1e6, time_constant_s=1.0))
    s.write(1, TORQUE, 1, 1)
    s.write(1, GOAL_POSITION, 4000, 4)
    assert s.read(1, PRESENT_CURRENT, 2, signed=True) == 32_767
    model, result, _ = s.ph.ping(s.port, 1)
    assert (model, result) == (1020, COMM_SUCCESS)  # the bus lives on


def test_status_return_level_decides_what_is_answered(sdk):
    s = sdk()
    s.ph.write1ByteTxRx(s.port, 1, SRL, 1)  # level 1: reads and pings only
    result, _ = s.ph.write1ByteTxRx(s.port, 1, LED, 1)
    assert result != COMM_SUCCESS  # no status for a write at level 1
    assert s.read(1, LED, 1) == 1  # but it was written, and reads are answered


# -- instructions ---------------------------------------------------------------------


def test_bulk_write_and_bulk_read(sdk):
    s = sdk()
    write = GroupBulkWrite(s.port, s.ph)
    assert write.addParam(1, TORQUE, 2, [1, 1])  # Torque Enable and LED in one go
    assert write.addParam(2, LED, 1, [1])
    assert write.txPacket() == COMM_SUCCESS
    read = GroupBulkRead(s.port, s.ph)
    assert read.addParam(1, TORQUE, 2)
    assert read.addParam(2, LED, 1)
    assert read.addParam(3, INPUT_VOLTAGE, 3)
    assert read.txRxPacket() == COMM_SUCCESS
    assert read.getData(1, TORQUE, 1) == 1 and read.getData(1, LED, 1) == 1
    assert read.getData(2, LED, 1) == 1
    assert read.getData(3, INPUT_VOLTAGE, 2) == 120  # 12.0 V
    assert read.getData(3, TEMPERATURE, 1) == 30
    assert read.fastBulkRead() == COMM_SUCCESS
    assert read.getData(3, INPUT_VOLTAGE, 2) == 120 and read.getData(2, LED, 1) == 1


def test_reg_write_waits_for_action(sdk):
    s = sdk(FirstOrderPlant(time_constant_s=0.0))
    s.write(1, TORQUE, 1, 1)
    result, error = s.ph.regWriteTxRx(s.port, 1, GOAL_POSITION, 4, [0xB8, 0x0B, 0, 0])  # 3000
    assert (result, error) == (COMM_SUCCESS, 0)
    assert s.read(1, REGISTERED, 1) == 1
    assert s.read(1, GOAL_POSITION, 4) == 2048
    assert s.ph.action(s.port, BROADCAST_ID) == COMM_SUCCESS
    assert s.read(1, REGISTERED, 1) == 0
    assert s.read(1, GOAL_POSITION, 4) == 3000
    _poll_until_at(s, 1, 3000, threshold=0)
    packet = [0] * 10
    packet[4], packet[5], packet[7] = 1, 3, 0x05  # ACTION to id 1 with nothing registered
    assert s.ph.txRxPacket(s.port, packet)[1] == COMM_SUCCESS  # the SDK does not wait
    s.port.setPacketTimeout(11)
    status, result = s.ph.rxPacket(s.port, False)  # so read the servo's status here
    assert result == COMM_SUCCESS and status[8] == INSTRUCTION
    assert s.ph.regWriteTxRx(s.port, 1, RETURN_DELAY, 1, [0]) == (COMM_SUCCESS, ACCESS)


def test_reboot_resets_ram_to_initial_values_and_keeps_eeprom(sdk):
    s = sdk()
    s.write(1, RETURN_DELAY, 10, 1)  # EEPROM
    for address, value, size in [
        (LED, 1, 1),
        (PROFILE_VELOCITY, 100, 4),
        (P_GAIN, 500, 2),
        (INDIRECT_ADDRESS_1, PRESENT_POSITION, 2),
        (TORQUE, 1, 1),
    ]:
        assert s.write(1, address, value, size) == 0
    assert s.virtual.plant.control[0]["Position P Gain"] == 500
    assert s.ph.reboot(s.port, 1) == (COMM_SUCCESS, 0)
    assert s.read(1, LED, 1) == 0
    assert s.read(1, PROFILE_VELOCITY, 4) == 0
    assert s.read(1, P_GAIN, 2) == 800
    assert s.read(1, INDIRECT_ADDRESS_1, 2) == INDIRECT_DATA_1
    assert s.read(1, TORQUE, 1) == 0
    assert s.read(1, RETURN_DELAY, 1) == 10
    assert s.virtual.plant.control[0]["Position P Gain"] == 800  # the plant was told


def test_factory_reset_with_its_option_byte(sdk):
    s = sdk()
    s.write(2, RETURN_DELAY, 0, 1)
    s.write(2, P_GAIN, 100, 2)
    assert s.ph.factoryReset(s.port, 2, 0x02) == (COMM_SUCCESS, 0)  # all but ID and baud rate
    assert s.read(2, RETURN_DELAY, 1) == 250
    assert s.read(2, P_GAIN, 2) == 800
    assert s.ph.factoryReset(s.port, 2, 0x05) == (COMM_SUCCESS, DATA_RANGE)  # no such option
    assert s.ph.factoryReset(s.port, BROADCAST_ID, 0xFF)[0] == COMM_SUCCESS  # ignored (fw >= 42)
    assert [s.ph.ping(s.port, i)[1] for i in (1, 2, 3)] == [COMM_SUCCESS] * 3
    assert s.ph.factoryReset(s.port, 3, 0xFF) == (COMM_SUCCESS, 0)  # ID back to 1
    assert s.ph.ping(s.port, 3)[1] != COMM_SUCCESS
    assert s.virtual.servos[3].servo_id == 1


def test_clear_resets_the_multi_turn_count(sdk):
    s = sdk(FirstOrderPlant(time_constant_s=0.0))
    s.write(1, OPERATING_MODE, 4, 1)  # extended position
    s.write(1, TORQUE, 1, 1)
    s.write(1, GOAL_POSITION, 2048 + 3 * 4096 + 100, 4)
    assert s.position(1) == 2048  # the state as the goal arrived
    assert s.position(1) == 2048 + 3 * 4096 + 100  # one period later: there, still moving
    assert s.ph.clearMultiTurn(s.port, 1) == (COMM_SUCCESS, RESULT_FAIL)
    s.position(1)  # one more period: at rest
    assert s.ph.clearMultiTurn(s.port, 1) == (COMM_SUCCESS, 0)
    assert s.position(1) == 2148
    assert s.read(1, GOAL_POSITION, 4) == 2148  # the same angle: the servo stays put
    assert s.ph.clearMultiTurn(s.port, 1) == (COMM_SUCCESS, 0)
    assert s.position(1) == 2148


def test_malformed_clear_and_read_are_refused(sdk):
    s = sdk()
    clear = [0x01, 0x44, 0x58, 0x4C, 0x22]
    assert _raw(s, 1, 0x10, clear) == (COMM_SUCCESS, 0)  # at rest: accepted
    assert _raw(s, 1, 0x10, clear[:4]) == (COMM_SUCCESS, DATA_LENGTH)
    assert _raw(s, 1, 0x10, [0x02, *clear[1:]]) == (COMM_SUCCESS, DATA_RANGE)  # reserved option
    assert _raw(s, 1, 0x02, [PRESENT_POSITION, 0, 4]) == (COMM_SUCCESS, DATA_LENGTH)  # READ


# -- control table -------------------------------------------------------------------


def test_indirect_address_and_data(sdk):
    s = sdk(FirstOrderPlant(time_constant_s=0.0))
    assert s.read(1, INDIRECT_ADDRESS_1, 2) == 224  # the manual's defaults
    assert s.read(1, INDIRECT_ADDRESS_1 + 2 * 27, 2) == 251
    assert s.read(1, INDIRECT_ADDRESS_29, 2) == 634
    assert s.write(1, INDIRECT_DATA_1, 7, 1) == 0  # pointing at itself: a plain byte
    assert s.read(1, INDIRECT_DATA_1, 1) == 7
    for k in range(4):  # Indirect Data 1..4 = Present Position, 5..8 = Goal Position
        assert s.write(1, INDIRECT_ADDRESS_1 + 2 * k, PRESENT_POSITION + k, 2) == 0
        assert s.write(1, INDIRECT_ADDRESS_1 + 2 * (4 + k), GOAL_POSITION + k, 2) == 0
    assert s.write(1, INDIRECT_ADDRESS_1, 30, 2) == DATA_RANGE  # targets are 64..661
    s.write(1, TORQUE, 1, 1)
    assert s.write(1, INDIRECT_DATA_1 + 4, 2500, 4) == 0  # a goal through Indirect Data
    assert s.read(1, GOAL_POSITION, 4) == 2500
    assert s.write(1, INDIRECT_DATA_1 + 4, 2500, 2) == DATA_LENGTH  # half of Goal Position
    _poll_until_at(s, 1, 2500, threshold=0)
    assert s.read(1, INDIRECT_DATA_1, 4) == 2500


def test_motion_registers(sdk):
    s = sdk(FirstOrderPlant(time_constant_s=0.05))
    assert s.read(1, MOVING, 1) == 0
    s.write(1, TORQUE, 1, 1)
    s.write(1, GOAL_POSITION, 3000, 4)
    s.position(1)
    assert s.read(1, MOVING, 1) == 1
    assert s.read(1, MOVING_STATUS, 1) & 1 == 0  # not in position
    assert s.read(1, POSITION_TRAJECTORY, 4) == 3000  # no profile: the step itself
    assert s.read(1, VELOCITY_TRAJECTORY, 4) == 0
    _poll_until_at(s, 1, 3000, threshold=0, polls=500)
    assert s.read(1, MOVING, 1) == 0
    assert s.read(1, MOVING_STATUS, 1) == 1  # in position, step profile
    s.write(1, PROFILE_VELOCITY, 100, 4)
    assert s.read(1, MOVING_STATUS, 1) == 0x11  # rectangular profile asked for


def test_present_pwm_is_the_p_loop_on_the_error(sdk):
    # A servo too slow to move in the test: the error stays at the step.
    s = sdk(FirstOrderPlant(time_constant_s=1e9))
    s.write(1, TORQUE, 1, 1)
    s.write(1, GOAL_POSITION, 2148, 4)  # 100 pulses of error
    assert s.read(1, PRESENT_PWM, 2, signed=True) == 625  # 800 / 128 * 100
    s.write(1, P_GAIN, 100, 2)
    assert s.read(1, PRESENT_PWM, 2, signed=True) == 78  # 100 / 128 * 100, rounded down
    s.write(1, GOAL_POSITION, 1048, 4)
    assert s.read(1, PRESENT_PWM, 2, signed=True) == -781
    s.write(1, P_GAIN, 16_000, 2)
    assert s.read(1, PRESENT_PWM, 2, signed=True) == -885  # PWM Limit
    s.write(1, GOAL_PWM, 300, 2)
    assert s.read(1, PRESENT_PWM, 2, signed=True) == -300  # Goal PWM caps it too
    assert s.virtual.plant.control[0]["Goal PWM"] == 300


def test_changing_operating_mode_resets_goal_pwm_gains_and_profile(sdk):
    s = sdk()
    for address, value, size in [(GOAL_PWM, 300, 2), (P_GAIN, 500, 2), (PROFILE_VELOCITY, 50, 4)]:
        assert s.write(1, address, value, size) == 0
    assert s.write(1, OPERATING_MODE, 4, 1) == 0
    assert s.read(1, GOAL_PWM, 2) == 885  # back to PWM Limit (e-Manual, Operating Mode)
    assert s.read(1, P_GAIN, 2) == 800
    assert s.read(1, PROFILE_VELOCITY, 4) == 0
    assert s.virtual.plant.control[0]["Goal PWM"] == 885  # the plant was told
    assert s.virtual.plant.control[0]["Operating Mode"] == 4


@pytest.mark.parametrize(
    "clock", [{}, {"lockstep_dt_s": None, "plant_process": True}], ids=["lockstep", "process"]
)
def test_what_the_plant_does_not_simulate_is_refused_and_the_bus_lives_on(sdk, clock):
    sim_firmware = pytest.importorskip("trajgen.sim.firmware")
    sim_plant = pytest.importorskip("trajgen.sim.plant")
    told = []
    s = sdk(
        sim_plant.GimbalPlant(record=False),
        unsupported=(sim_firmware.UnsupportedServoSetting,),
        on_refusal=lambda servo_id, reason: told.append((servo_id, reason)),
        **clock,
    )
    assert s.write(1, PROFILE_VELOCITY, 100, 4) == RESULT_FAIL
    assert s.read(1, PROFILE_VELOCITY, 4) == 0  # undone
    assert s.write(2, OPERATING_MODE, 1, 1) == RESULT_FAIL  # velocity mode
    assert s.read(2, OPERATING_MODE, 1) == 3
    assert [i for i, _ in told] == [1, 2]
    assert "Profile Velocity 100" in told[0][1] and "Operating Mode 1" in told[1][1]
    assert s.write(2, OPERATING_MODE, 4, 1) == 0  # extended position is simulated
    assert s.ph.ping(s.port, 1)[1:] == (COMM_SUCCESS, 0)
    assert s.virtual.error is None


def test_plant_is_told_the_control_registers_at_start(sdk):
    s = sdk(models="XL430-W250")
    assert s.virtual.plant.control[2]["Position P Gain"] == 640  # XL430's own default
    assert s.virtual.plant.control[2]["Position D Gain"] == 4000
    s.write(3, D_GAIN, 0, 2)
    s.write(3, OPERATING_MODE, 4, 1)  # changing mode resets the gains
    assert s.read(3, D_GAIN, 2) == 4000
    assert s.virtual.plant.control[2]["Operating Mode"] == 4
    assert s.virtual.plant.control[2]["Position D Gain"] == 4000


def test_hardware_error_survives_until_reboot(sdk):
    s = sdk()
    s.virtual.servos[2].raise_hardware_error(0x20)
    model, result, error = s.ph.ping(s.port, 2)
    assert error & 0x80  # Alert
    assert s.write(2, TORQUE, 1, 1) == RESULT_FAIL | 0x80
    s.ph.reboot(s.port, 2)
    assert s.read(2, HW_ERROR, 1) == 0


# -- the command ----------------------------------------------------------------------


def _trajgen(*args):
    import subprocess
    import sys

    return subprocess.Popen(
        [sys.executable, "-c", "import sys; from trajgen.cli import main; sys.exit(main())", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGINT"])
def test_virtual_bus_command_serves_until_a_signal(signal_name, monkeypatch):
    import signal

    # What the command serves, not how fast: 10x the SDK's reply timeout, for a busy host.
    monkeypatch.setattr("dynamixel_sdk.port_handler.LATENCY_TIMER", 160)

    proc = _trajgen("virtual-bus", "--ids", "4,5,6", "--models", "XL430-W250")
    try:
        port_name = proc.stdout.readline().strip()  # the first line is the port
        port = PortHandler(port_name)
        assert port.openPort() and port.setBaudRate(57_600)
        ph = PacketHandler(2.0)
        assert ph.ping(port, 5)[:2] == (1060, COMM_SUCCESS)
        assert ph.write1ByteTxRx(port, 5, TORQUE, 1) == (COMM_SUCCESS, 0)
        assert ph.write4ByteTxRx(port, 5, PROFILE_VELOCITY, 50) == (COMM_SUCCESS, RESULT_FAIL)
        assert ph.ping(port, 5)[1] == COMM_SUCCESS  # not simulated, refused; the bus lives on
        port.closePort()
    finally:
        proc.send_signal(getattr(signal, signal_name))
        out, err = proc.communicate(timeout=120)  # start-up on a busy host
    assert proc.returncode == 128 + getattr(signal, signal_name), err  # as every command
    assert "serving servos 4, 5, 6 (XL430-W250, XL430-W250, XL430-W250), real time" in err
    assert "servo 5 refused a write (Result Fail): tilt: Profile Velocity 50" in err
    assert f"stopped by {signal_name} after" in err


def test_virtual_bus_command_takes_the_files_bus_gains_and_rate_in_lockstep(tmp_path, monkeypatch):
    import signal

    monkeypatch.setattr("dynamixel_sdk.port_handler.LATENCY_TIMER", 160)  # a busy host

    path = tmp_path / "k.toml"
    path.write_text(
        "[bus]\nids = [7, 8, 9]\n\n[stream]\nrate_hz = 100\n\n"
        "[gimbal.tilt]\nposition_p_gain = 500\n\n"
        "[[keyframes]]\nt = 0.0\npan = 0\n\n[[keyframes]]\nt = 1.0\npan = 10\n"
    )
    proc = _trajgen("virtual-bus", str(path), "--lockstep")
    try:
        port = PortHandler(proc.stdout.readline().strip())
        assert port.openPort() and port.setBaudRate(57_600)
        ph = PacketHandler(2.0)
        assert ph.read2ByteTxRx(port, 8, P_GAIN) == (500, COMM_SUCCESS, 0)  # [gimbal.tilt]
        assert ph.read2ByteTxRx(port, 7, P_GAIN) == (800, COMM_SUCCESS, 0)  # the default
        assert ph.write4ByteTxRx(port, 9, GOAL_POSITION, 2048) == (COMM_SUCCESS, 0)
        assert ph.read2ByteTxRx(port, 9, TICK) == (10, COMM_SUCCESS, 0)  # one 100 Hz period
        port.closePort()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)  # start-up on a busy host
    assert proc.returncode == 130, err
    assert "serving servos 7, 8, 9 (XM430-W350, XM430-W350, XM430-W350), lock-step, 10 ms" in err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--models", "XM999"], "--models: expected model names separated by commas"),
        (["--ids", "1,1,2"], "--ids: expected distinct ids in 0..252"),
        (["--ids", "1,2"], "--ids 1,2: expected at least 3 ids, one per joint of the gimbal"),
        (["--models", "XL330-M288,XM430-W350"], "--models: expected 1 model or 3 (one per id)"),
        (["nonexistent.toml"], "nonexistent.toml"),
    ],
)
def test_virtual_bus_command_refuses_bad_input(args, message):
    proc = _trajgen("virtual-bus", *args)
    out, err = proc.communicate(timeout=120)  # start-up on a busy host
    assert proc.returncode == 2
    assert message in err
    assert out == ""  # no port was opened


def test_installed_registers_eeprom_survive_reboot_ram_does_not(sdk):
    s = sdk(registers={1: {"Max Position Limit": 3000, "LED": 1}})
    assert s.read(1, MAX_POSITION_LIMIT, 4) == 3000
    assert s.read(1, LED, 1) == 1
    assert s.ph.reboot(s.port, 1) == (COMM_SUCCESS, 0)
    assert s.read(1, MAX_POSITION_LIMIT, 4) == 3000
    assert s.read(1, LED, 1) == 0
    assert s.ph.factoryReset(s.port, 1, 0x01) == (COMM_SUCCESS, 0)
    assert s.read(1, MAX_POSITION_LIMIT, 4) == 4095
