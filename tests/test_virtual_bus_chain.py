"""A virtual bus of N servos on any ids, some driven by a plant and the rest idle,
through the official SDK (the pattern of tests/test_virtual_bus_sdk.py).

Addresses are the X-series' (the same on XL330, XC330 and XM430 for those used
here); model numbers and factory values are the e-Manual's, as written by hand
in tests/test_servo_table.py.
"""

import numpy as np
import pytest
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite
from test_virtual_bus_sdk import Sdk

from trajgen.drivers.virtual.bus import VirtualBus
from trajgen.drivers.virtual.chain import ChainPlant
from trajgen.drivers.virtual.plant import FirstOrderPlant

MODEL_NUMBER, OPERATING_MODE, CURRENT_LIMIT, VELOCITY_LIMIT = 0, 11, 38, 44
TORQUE, P_GAIN, GOAL_CURRENT, GOAL_POSITION, PRESENT_POSITION = 64, 84, 102, 116, 132
CURRENT_BASED_POSITION = 5
OMX = (11, 12, 13, 14, 15, 16)  # an OMX-like arm: five joints and a gripper


@pytest.fixture
def chain(monkeypatch):
    """Make SDK rigs on a lock-step virtual bus; closed at the end."""
    monkeypatch.setattr("dynamixel_sdk.port_handler.LATENCY_TIMER", 160)  # a busy machine
    made = []

    def make(plant=None, **kwargs):
        made.append(Sdk(VirtualBus(plant, lockstep_dt_s=0.01, **kwargs).start()))
        return made[-1]

    yield make
    for s in made:
        s.close()


def _sync_read(s, ids, address, size, *, fast=False):
    group = GroupSyncRead(s.port, s.ph, address, size)
    for i in ids:
        assert group.addParam(i)
    result = group.fastSyncRead() if fast else group.txRxPacket()
    assert result == COMM_SUCCESS, s.ph.getTxRxResult(result)
    for i in ids:
        assert group.isAvailable(i, address, size)
    return [group.getData(i, address, size) for i in ids]


def _sync_write(s, address, size, values: dict):
    group = GroupSyncWrite(s.port, s.ph, address, size)
    for i, v in values.items():
        assert group.addParam(i, list(int(v).to_bytes(size, "little", signed=True)))
    assert group.txPacket() == COMM_SUCCESS


def test_six_servos_answer_as_their_models_with_two_driven(chain):
    plant = FirstOrderPlant(2, time_constant_s=0.0)
    s = chain(plant, ids=OMX, models="XL330-M288", plant_ids=(14, 15))
    ids, _ = s.ph.broadcastPing(s.port)
    assert sorted(ids) == list(OMX)
    for i in OMX:
        number, result, error = s.ph.ping(s.port, i)
        assert (number, result, error) == (1200, COMM_SUCCESS, 0)  # XL330-M288
        assert s.read(i, P_GAIN, 2) == 400  # the XL330's factory P gain, not the XM430's 800
        assert s.read(i, CURRENT_LIMIT, 2) == 1750
        assert s.read(i, VELOCITY_LIMIT, 4) == 445
    assert s.ph.ping(s.port, 17)[1] != COMM_SUCCESS  # nobody else on the bus
    assert isinstance(s.virtual.plant, ChainPlant)
    assert s.virtual.plant.driven == (3, 4)


def test_goals_reach_the_plant_for_its_servos_and_the_idle_ones_follow(chain):
    plant = FirstOrderPlant(2, time_constant_s=0.0)
    s = chain(plant, ids=OMX, models="XL330-M288", plant_ids=(15, 14))  # any order
    for i in OMX:
        assert s.write(i, TORQUE, 1, 1) == 0
    goals = {i: 2048 + 100 * (k + 1) for k, i in enumerate(OMX)}
    _sync_write(s, GOAL_POSITION, 4, goals)
    # Lock-step: the read after a goal shows the moment it arrived; each poll after
    # that is one 10 ms period.
    assert _sync_read(s, OMX, PRESENT_POSITION, 4) == [2048] * 6
    for _ in range(20):
        present = _sync_read(s, OMX, PRESENT_POSITION, 4)
    # The plant's joint 0 is servo 15, joint 1 servo 14; it reached them at once (tau 0).
    want_rad = [(goals[i] - 2048) * 2 * np.pi / 4096 for i in (15, 14)]
    np.testing.assert_allclose(plant.read()[0], want_rad, rtol=0, atol=1e-12)
    assert present[3:5] == [goals[14], goals[15]]
    for i, p in zip(OMX, present, strict=True):
        assert abs(p - goals[i]) <= 1  # the idle ones follow theirs (tau 20 ms, 0.2 s)
    assert _sync_read(s, OMX, PRESENT_POSITION, 4, fast=True) == present


def test_a_gripper_in_current_based_position_mode_keeps_serving(chain):
    s = chain(FirstOrderPlant(2), ids=OMX, models="XL330-M288", plant_ids=(14, 15))
    gripper = 16
    assert s.write(gripper, OPERATING_MODE, CURRENT_BASED_POSITION, 1) == 0
    assert s.read(gripper, OPERATING_MODE, 1) == CURRENT_BASED_POSITION
    assert s.write(gripper, GOAL_CURRENT, 300, 2) == 0
    assert s.write(gripper, TORQUE, 1, 1) == 0
    assert s.write(gripper, GOAL_POSITION, 2600, 4) == 0
    for _ in range(60):  # 0.6 s simulated: the first-order servo closes on its goal
        position = s.position(gripper)
    assert abs(position - 2600) <= 2
    # ... and the others still answer and stream.
    for i in (14, 15):
        assert s.write(i, TORQUE, 1, 1) == 0
    _sync_write(s, GOAL_POSITION, 4, {14: 2100, 15: 2000})
    assert len(_sync_read(s, OMX, PRESENT_POSITION, 4, fast=True)) == 6
    assert s.virtual.error is None


def test_each_servo_has_its_own_model(chain):
    models = ("XL330-M288", "XL330-M077", "XC330-M288", "XM430-W350")
    numbers = (1200, 1190, 1240, 1020)  # e-Manual model numbers
    s = chain(FirstOrderPlant(2), ids=(21, 22, 23, 24), models=models)
    for i, number in zip((21, 22, 23, 24), numbers, strict=True):
        assert s.read(i, MODEL_NUMBER, 2) == number
    assert s.read(24, P_GAIN, 2) == 800  # XM430-W350 factory
    assert s.read(21, P_GAIN, 2) == 400  # XL330-M288 factory


def test_without_a_plant_every_servo_idles(chain):
    s = chain(None, ids=(5, 9), models=("XL330-M288", "XM430-W350"))
    assert s.write(9, TORQUE, 1, 1) == 0
    assert s.write(9, GOAL_POSITION, 1500, 4) == 0
    for _ in range(30):
        position = s.position(9)
    assert abs(position - 1500) <= 2
    assert s.position(5) == 2048  # torque off: it stays where it powered up


@pytest.mark.parametrize(
    "plant, kwargs, message",
    [
        (FirstOrderPlant(2), {"ids": (1, 2), "plant_ids": (1, 3)}, r"`plant_ids` to be 2 of"),
        (FirstOrderPlant(2), {"ids": (1, 2, 3), "plant_ids": (1,)}, r"got \(1,\)"),
        (None, {"ids": (1, 2), "plant_ids": (1,)}, r"Expected a `plant` for `plant_ids` \(1,\)"),
        (FirstOrderPlant(3), {"ids": (1, 2)}, r"at least one id per plant joint \(3\)"),
    ],
)
def test_bad_chains_are_refused(plant, kwargs, message):
    with pytest.raises(ValueError, match=message):
        VirtualBus(plant, **kwargs)


def test_chain_plant_refuses_bad_indices():
    with pytest.raises(ValueError, match=r"2 distinct indices in 0..3, got \[0, 0\]"):
        ChainPlant(FirstOrderPlant(2), 4, (0, 0))
    with pytest.raises(TypeError, match="Expected `plant` to be a Plant, got int"):
        ChainPlant(3, 4, (0,))


def test_the_command_serves_a_chain_of_six_the_gimbal_on_the_first_three(monkeypatch):
    import signal

    # What the servos answer, not when: 10x the SDK's reply timeout on a busy host.
    monkeypatch.setattr("dynamixel_sdk.port_handler.LATENCY_TIMER", 160)

    from dynamixel_sdk import PacketHandler, PortHandler
    from test_virtual_bus_sdk import _trajgen

    proc = _trajgen("virtual-bus", "--ids", ",".join(map(str, OMX)), "--models", "XL330-M288")
    try:
        port = PortHandler(proc.stdout.readline().strip())
        assert port.openPort() and port.setBaudRate(1_000_000)
        ph = PacketHandler(2.0)
        for i in OMX:
            assert ph.ping(port, i)[:2] == (1200, COMM_SUCCESS)
        # The gripper (16, idle) takes mode 5; a gimbal servo (11, simulated) refuses it.
        assert ph.write1ByteTxRx(port, 16, OPERATING_MODE, CURRENT_BASED_POSITION) == (
            COMM_SUCCESS,
            0,
        )
        assert ph.write1ByteTxRx(port, 11, OPERATING_MODE, CURRENT_BASED_POSITION) == (
            COMM_SUCCESS,
            1,  # Result Fail: the simulated gimbal has no current-based position loop
        )
        assert ph.read1ByteTxRx(port, 16, OPERATING_MODE) == (5, COMM_SUCCESS, 0)
        port.closePort()
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)  # start-up on a busy host
    assert proc.returncode == 143, err
    assert "serving servos 11, 12, 13, 14, 15, 16 (XL330-M288, " in err
    assert "idle (not the gimbal's): 14, 15, 16" in err
    assert "servo 11 refused a write (Result Fail)" in err


# Operating Mode (11) values each e-Manual page lists, written here from the pages (not
# read from the servo table): the XL430 models have no current sensing, so no current
# control (0) and no current-based position control (5).
EMANUAL_MODES = {
    "XM430-W350": {0, 1, 3, 4, 5, 16},
    "XH430-W350": {0, 1, 3, 4, 5, 16},
    "XM540-W270": {0, 1, 3, 4, 5, 16},
    "XH540-W270": {0, 1, 3, 4, 5, 16},
    "XL330-M288": {0, 1, 3, 4, 5, 16},
    "XL330-M077": {0, 1, 3, 4, 5, 16},
    "XC330-M288": {0, 1, 3, 4, 5, 16},
    "XL430-W250": {1, 3, 4, 16},
    "2XL430-W250": {1, 3, 4, 16},
}


def test_each_model_takes_exactly_its_own_operating_modes_through_the_sdk(chain):
    from trajgen.servo_table import SERVOS

    assert set(EMANUAL_MODES) == set(SERVOS)
    models = tuple(EMANUAL_MODES)
    ids = tuple(range(1, len(models) + 1))
    s = chain(None, ids=ids, models=models)
    data_range = 4  # status ERR "data range" (Protocol 2.0)
    for i, model in zip(ids, models, strict=True):
        assert set(SERVOS[model].operating_modes) == EMANUAL_MODES[model]
        for mode in range(17):
            error = s.write(i, OPERATING_MODE, mode, 1)
            if mode in EMANUAL_MODES[model]:
                assert error == 0, (model, mode)
                assert s.read(i, OPERATING_MODE, 1) == mode
            else:  # refused as a real servo does; the mode stays what it was
                assert error == data_range, (model, mode)
                assert s.read(i, OPERATING_MODE, 1) != mode
    assert s.virtual.error is None
