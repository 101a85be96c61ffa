"""LeRobot's ``DynamixelMotorsBus`` on the virtual bus: an OMX-like chain of six
XL330-M288 on ids 11-16, the wrist (14, 15) driven by a plant, the gripper (16) in
Current-based Position (mode 5), as LeRobot's OMX follower configures it.

Skipped where ``lerobot`` is not installed: it needs PyTorch, so it is not in the
``dev`` extra (``pip install lerobot`` to run these).
"""

import pytest

pytest.importorskip("lerobot.motors.dynamixel", reason="needs lerobot (and PyTorch)")

from lerobot.motors import Motor, MotorNormMode  # noqa: E402
from lerobot.motors.dynamixel import DynamixelMotorsBus, OperatingMode  # noqa: E402

from trajgen.drivers.virtual.bus import VirtualBus  # noqa: E402
from trajgen.drivers.virtual.plant import FirstOrderPlant  # noqa: E402

ARM = {
    "shoulder_pan": 11,
    "shoulder_lift": 12,
    "elbow_flex": 13,
    "wrist_flex": 14,
    "wrist_roll": 15,
    "gripper": 16,
}


@pytest.fixture
def omx(monkeypatch):
    """A connected LeRobot bus on a lock-step virtual chain; (bus, virtual, plant)."""
    monkeypatch.setattr("dynamixel_sdk.port_handler.LATENCY_TIMER", 160)  # a busy machine
    plant = FirstOrderPlant(2, time_constant_s=0.0)
    virtual = VirtualBus(
        plant, ids=tuple(ARM.values()), plant_ids=(14, 15), models="XL330-M288", lockstep_dt_s=0.01
    ).start()
    motors = {name: Motor(i, "xl330-m288", MotorNormMode.RANGE_M100_100) for name, i in ARM.items()}
    motors["gripper"] = Motor(16, "xl330-m288", MotorNormMode.RANGE_0_100)
    bus = DynamixelMotorsBus(port=virtual.port, motors=motors)
    bus.connect()  # the handshake: every id pinged, model numbers compared
    yield bus, virtual, plant
    bus.disconnect(disable_torque=False)
    virtual.stop()


def test_the_handshake_finds_six_xl330s(omx):
    bus, virtual, _ = omx
    assert bus.is_connected
    assert bus.broadcast_ping() == dict.fromkeys(ARM.values(), 1200)  # XL330-M288


def test_omx_configuration_with_the_gripper_in_mode_5_is_accepted(omx):
    bus, virtual, _ = omx
    with bus.torque_disabled():
        bus.configure_motors()  # Return Delay Time 0
        for name in ARM:
            if name != "gripper":
                bus.write("Operating_Mode", name, OperatingMode.EXTENDED_POSITION.value)
        bus.write("Operating_Mode", "gripper", OperatingMode.CURRENT_POSITION.value)
    modes = bus.sync_read("Operating_Mode", normalize=False)
    assert modes == {name: 5 if name == "gripper" else 4 for name in ARM}
    assert bus.sync_read("Return_Delay_Time", normalize=False) == dict.fromkeys(ARM, 0)
    calibration = bus.read_calibration()  # sync reads of Homing Offset, limits, Drive Mode
    assert {c.id for c in calibration.values()} == set(ARM.values())
    assert all(c.range_min == 0 and c.range_max == 4095 for c in calibration.values())
    assert virtual.error is None


def test_sync_write_and_sync_read_move_the_wrist_and_the_gripper(omx):
    bus, virtual, plant = omx
    with bus.torque_disabled():
        bus.write("Operating_Mode", "gripper", OperatingMode.CURRENT_POSITION.value)
    bus.enable_torque()
    goals = {name: 2048 + 40 * k for k, name in enumerate(ARM)}
    bus.sync_write("Goal_Position", goals, normalize=False)
    for _ in range(30):  # 0.3 s of lock-step periods
        present = bus.sync_read("Present_Position", normalize=False)
    assert all(abs(present[name] - goals[name]) <= 1 for name in ARM), present
    assert plant.read()[0].tolist() == pytest.approx(
        [
            (goals["wrist_flex"] - 2048) * 3.141592653589793 / 2048,
            (goals["wrist_roll"] - 2048) * 3.141592653589793 / 2048,
        ]
    )
    assert virtual.error is None


def test_three_xm430_on_ids_1_to_3_as_before(monkeypatch):
    monkeypatch.setattr("dynamixel_sdk.port_handler.LATENCY_TIMER", 160)
    plant = FirstOrderPlant(3, time_constant_s=0.0)
    with VirtualBus(plant, lockstep_dt_s=0.01) as virtual:  # ids 1, 2, 3, XM430-W350
        names = ("pan", "tilt", "roll")
        motors = {
            n: Motor(i, "xm430-w350", MotorNormMode.RANGE_M100_100)
            for i, n in enumerate(names, start=1)
        }
        bus = DynamixelMotorsBus(port=virtual.port, motors=motors)
        bus.connect()
        try:
            assert bus.broadcast_ping() == {1: 1020, 2: 1020, 3: 1020}
            bus.enable_torque()
            bus.sync_write(
                "Goal_Position", {"pan": 2100, "tilt": 2000, "roll": 2048}, normalize=False
            )
            for _ in range(5):
                present = bus.sync_read("Present_Position", normalize=False)
            assert present == {"pan": 2100, "tilt": 2000, "roll": 2048}
        finally:
            bus.disconnect(disable_torque=False)
