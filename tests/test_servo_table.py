"""The servo table is the one source of servo facts, and it says what the e-Manual says.

The reference figures below are written out by hand from the ROBOTIS e-Manual
pages (URL per model; ratings in bold on the "Specifications" table, factory
values from the "Initial Value" column of the control table), independently of
``trajgen.servo_table``: the table and this test are not the same object.
"""

from __future__ import annotations

import ast
import io
import math
import tokenize
from pathlib import Path

import pytest

from trajgen import servo_table as T
from trajgen.drivers.control_table import Register, control_items, layout, model_named, rules
from trajgen.sim.firmware import PositionLoop, loop_from_registers
from trajgen.sim.model import GimbalConfig, build_model
from trajgen.sim.servos import SERVOS as SIM_SERVOS
from trajgen.sim.servos import servo_by_name

ROOT = Path(__file__).resolve().parents[1]

# name: (url, model number, volts, stall N m, stall A, no-load rpm, P, I, D, mA per unit or None)
EMANUAL = {
    "XM430-W350": ("https://emanual.robotis.com/docs/en/dxl/x/xm430-w350/",
                   1020, 12.0, 4.1, 2.3, 46, 800, 0, 0, 2.69),
    "XL430-W250": ("https://emanual.robotis.com/docs/en/dxl/x/xl430-w250/",
                   1060, 12.0, 1.5, 1.4, 61, 640, 0, 4000, None),
    "XH430-W350": ("https://emanual.robotis.com/docs/en/dxl/x/xh430-w350/",
                   1000, 12.0, 3.4, 1.3, 30, 900, 0, 0, 2.69),
    "XM540-W270": ("https://emanual.robotis.com/docs/en/dxl/x/xm540-w270/",
                   1120, 12.0, 10.6, 4.4, 30, 800, 0, 0, 2.69),
    "XH540-W270": ("https://emanual.robotis.com/docs/en/dxl/x/xh540-w270/",
                   1100, 12.0, 9.9, 4.9, 39, 800, 0, 0, 2.69),
    "XL330-M288": ("https://emanual.robotis.com/docs/en/dxl/x/xl330-m288/",
                   1200, 5.0, 0.52, 1.47, 103, 400, 0, 0, 1.0),
    "XL330-M077": ("https://emanual.robotis.com/docs/en/dxl/x/xl330-m077/",
                   1190, 5.0, 0.215, 1.47, 383, 400, 400, 0, 1.0),
    "XC330-M288": ("https://emanual.robotis.com/docs/en/dxl/x/xc330-m288/",
                   1240, 5.0, 0.93, 1.80, 81, 1100, 0, 500, 1.0),
    "2XL430-W250": ("https://emanual.robotis.com/docs/en/dxl/x/2xl430-w250/",
                    1090, 12.0, 1.5, 1.4, 61, 640, 0, 2000, None),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(EMANUAL))
def test_entry_says_what_the_emanual_says(name):
    url, number, volts, stall_nm, stall_a, rpm, p, i, d, milliamps = EMANUAL[name]
    spec = T.SERVOS[name]
    assert (spec.url, spec.number, spec.voltage_v) == (url, number, volts)
    assert (spec.stall_torque_nm, spec.stall_current_a, spec.no_load_speed_rpm) == (
        stall_nm,
        stall_a,
        rpm,
    )
    assert spec.no_load_speed_rad_s == pytest.approx(rpm * 2 * math.pi / 60, rel=1e-15)
    gains = [spec.defaults[f"Position {g} Gain"] for g in "PID"]
    assert gains == [p, i, d]
    if milliamps is None:
        assert spec.present_load and spec.current_a(1000) == pytest.approx(stall_a)
    else:
        assert spec.current_unit_a == pytest.approx(milliamps / 1000, rel=1e-12)


def test_the_table_lists_every_model_the_issue_asks_for():
    assert set(T.SERVOS) == set(EMANUAL)
    assert T.SERVOS["2XL430-W250"].axes == 2
    assert all(s.axes == 1 for n, s in T.SERVOS.items() if n != "2XL430-W250")
    assert T.DEFAULT_SERVO == "XM430-W350"


@pytest.mark.parametrize("spec", T.SERVOS.values(), ids=list(T.SERVOS))
def test_every_entry_is_complete(spec):
    assert spec.name == spec.name.upper() and spec.url.endswith(f"/{spec.name.lower()}/")
    assert tuple(spec.defaults) == T.DEFAULT_REGISTERS
    for name, value in spec.defaults.items():
        assert value is None if name == "Current Limit" and spec.present_load else value >= 0
    for value in (spec.stall_torque_nm, spec.stall_current_a, spec.no_load_speed_rpm):
        assert value > 0
    for value in (spec.mass_kg, spec.gear_ratio, spec.armature, spec.damping, spec.frictionloss):
        assert value > 0
    assert len(spec.size_mm) == 3 and min(spec.size_mm) > 0
    assert spec.torque_constant_nm_a is None or spec.torque_constant_nm_a > 0
    assert spec.defaults["PWM Limit"] == T.PWM_FULL_SCALE
    for low, high in spec.ranges.values():
        assert low <= high
    assert T.servo_spec(f"  {spec.name.lower()} ") is spec
    assert T.servo_numbered(spec.number) is spec


def test_model_numbers_are_distinct_and_lookups_fail_with_the_known_names():
    numbers = [s.number for s in T.SERVOS.values()]
    assert len(set(numbers)) == len(numbers)
    with pytest.raises(ValueError, match=r"unknown model 'MX-28' \(known: XM430-W350, "):
        T.servo_spec("MX-28")
    with pytest.raises(TypeError, match=r"Expected a servo model name, got 1020"):
        T.servo_spec(1020)
    assert T.servo_numbered(29) is None
    assert T.hardware_error_mask("overload") == 0x20  # e-Manual: bit 5
    with pytest.raises(ValueError, match=r"unknown hardware error 'fire' \(known: input"):
        T.hardware_error_mask("fire")


def test_x_series_facts():
    # e-Manual X-series pages: 4096 pulse/rev, 0.229 rev/min, PWM 0.113 % (885 = 100 %),
    # gains 0 ~ 16,383, Bus Watchdog 20 ms.
    assert (T.TICKS_PER_REV, T.ZERO_TICK, T.PWM_FULL_SCALE, T.GAIN_MAX) == (4096, 2048, 885, 16383)
    assert math.degrees(T.RAD_PER_TICK) == pytest.approx(0.088, abs=2e-4)  # printed rounded
    assert T.VELOCITY_UNIT_RAD_S == pytest.approx(0.229 * 2 * math.pi / 60, rel=1e-15)
    assert 100 / T.PWM_FULL_SCALE == pytest.approx(0.113, abs=1e-3)
    assert (T.P_DIVISOR, T.I_DIVISOR, T.D_DIVISOR) == (128, 65536, 16)
    assert T.BAUD_RATES[3] == 1_000_000 and T.WATCHDOG_UNIT_S == 0.02


# -- The SDK's shipped control tables ------------------------------------------


@pytest.mark.parametrize("spec", T.SERVOS.values(), ids=list(T.SERVOS))
def test_register_addresses_are_the_sdks(spec):
    from dynamixel_easy_sdk.control_table import ControlTable

    assert ControlTable.getModelName(spec.number) == spec.name.lower().replace("-", "_") + ".model"
    table = ControlTable.getControlTable(spec.number)
    assert ("Present Load" in table) == spec.present_load
    assert ("Current Limit" in table) == (spec.defaults["Current Limit"] is not None)
    for register, (address, size) in layout(spec).items():
        load = spec.present_load and register is Register.PRESENT_CURRENT
        item = table["Present Load" if load else register.value]
        assert (item.address, item.size) == (address, size)
    items = control_items(spec)
    for name, item in table.items():
        if name in items and not name.startswith("Indirect"):
            assert items[name] == (item.address, item.size), name


def test_330_indirect_data_follows_the_emanual_not_the_sdk_file():
    # The XL330 e-Manual page: Indirect Address 1..20 at 168..206, Indirect
    # Data 1..20 at 208..227. The SDK's xl330_m288.model says Indirect Data 1 at
    # 224, the XM430's address: a copy slip the virtual servo does not follow.
    from dynamixel_easy_sdk.control_table import ControlTable

    spec = T.SERVOS["XL330-M288"]
    assert ControlTable.getControlTable(spec.number)["Indirect Data 1"].address == 224
    items = control_items(spec)
    assert items["Indirect Data 1"] == (208, 1) and items["Indirect Data 20"] == (227, 1)
    assert items["Indirect Address 20"] == (206, 2) and "Indirect Address 21" not in items
    assert rules(spec)["Indirect Address 1"].high == 227
    assert control_items(T.SERVOS["XM430-W350"])["Indirect Data 56"] == (661, 1)


# -- Every package reads the same entry ----------------------------------------


@pytest.mark.parametrize("name", sorted(EMANUAL))
def test_driver_and_simulator_read_the_entry(name):
    spec = T.SERVOS[name]
    assert model_named(name) is spec
    servo = servo_by_name(name)
    assert servo is SIM_SERVOS[name] and servo.spec is spec
    assert (servo.stall_torque_nm, servo.no_load_speed_rad_s, servo.voltage_v) == (
        spec.stall_torque_nm,
        spec.no_load_speed_rad_s,
        spec.voltage_v,
    )
    assert servo.position_p_gain == spec.defaults["Position P Gain"]
    initial = {n: r.initial for n, r in rules(spec).items()}
    for register, value in spec.defaults.items():
        assert initial.get(register) == value
    assert initial["Present Input Voltage"] == round(spec.voltage_v * 10)
    # The simulated motor runs at the entry's rated voltage.
    model = build_model(GimbalConfig(servos=(servo,) * 3))
    assert model.actuator_gainprm[0, 7] == pytest.approx(spec.voltage_v)


def test_firmware_loop_defaults_are_the_default_servos_registers():
    factory = T.SERVOS[T.DEFAULT_SERVO].defaults
    loop = PositionLoop()
    assert (loop.p_gain, loop.i_gain, loop.d_gain) == tuple(
        factory[f"Position {g} Gain"] for g in "PID"
    )
    assert loop_from_registers({}) == loop
    assert (loop.pwm_limit, loop.goal_pwm) == (T.PWM_FULL_SCALE, T.PWM_FULL_SCALE)


def test_the_existing_four_keep_their_simulation_parameters():
    # Menagerie OP3 (XM430-W350): armature 0.045, frictionloss 0.03; the others
    # by gear ratio squared and stall torque, as before the table was merged.
    xm = SIM_SERVOS["XM430-W350"]
    assert (T._REF_GEAR, T._REF_STALL_NM) == (xm.gear_ratio, xm.stall_torque_nm)
    assert (xm.armature, xm.frictionloss, xm.damping) == (0.045, 0.03, 0.01)
    assert SIM_SERVOS["XH430-W350"].armature == 0.045
    assert SIM_SERVOS["XL430-W250"].armature == pytest.approx(0.045 * (258.5 / 353.5) ** 2)
    assert SIM_SERVOS["XM540-W270"].armature == pytest.approx(0.045 * (272.5 / 353.5) ** 2)
    assert SIM_SERVOS["XM540-W270"].frictionloss == pytest.approx(0.03 * 10.6 / 4.1)
    assert SIM_SERVOS["XL430-W250"].position_d_gain == 4000


# -- Nothing else restates a fact of the table ---------------------------------

#: Numbers that are servo facts: none may be written outside the table.
FACT_NUMBERS = {885, 16383, 4096, 2048, 0.229, 0.00269, 2.69, 1193, 0.088, 0.0239691227}
#: Literals that equal a fact by coincidence: (path, source line).
COINCIDENCES = {
    ("trajgen/spline.py", "CHUNK = 4096"),  # samples per evaluation chunk
    ("drivers/virtual/transport.py", "data = os.read(self._master, 4096)"),  # pty read size
}
#: Names each defined at module level in exactly one module.
ONE_DEFINITION = (
    "TICKS_PER_REV",
    "ZERO_TICK",
    "RAD_PER_TICK",
    "PWM_FULL_SCALE",
    "GAIN_MAX",
    "P_DIVISOR",
    "I_DIVISOR",
    "D_DIVISOR",
    "VELOCITY_UNIT_RAD_S",
    "WATCHDOG_UNIT_S",
    "BAUD_RATES",
    "HARDWARE_ERROR_BITS",
    "CONTROL_REGISTERS",
    "DEFAULT_BAUD",
    "MAX_DELAY_S",
    "BOUNDARIES",
)


def _sources():
    for package in ("trajgen", "drivers", "sim", "bench"):
        for path in sorted((ROOT / package).rglob("*.py")):
            yield path.relative_to(ROOT).as_posix(), path.read_text(encoding="utf-8")


def test_no_package_restates_a_servo_number():
    found = []
    for rel, text in _sources():
        if rel == "trajgen/servo_table.py":
            continue
        lines = text.splitlines()
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type != tokenize.NUMBER or ast.literal_eval(tok.string) not in FACT_NUMBERS:
                continue
            if (rel, lines[tok.start[0] - 1].strip()) not in COINCIDENCES:
                found.append(f"{rel}:{tok.start[0]}: {tok.string}")
    assert not found, "servo facts written outside trajgen/servo_table.py: " + ", ".join(found)


def test_no_package_redefines_a_shared_name():
    where: dict[str, list[str]] = {name: [] for name in ONE_DEFINITION}
    for rel, text in _sources():
        for node in ast.parse(text).body:
            targets = node.targets if isinstance(node, ast.Assign) else []
            if isinstance(node, ast.AnnAssign):
                targets = [node.target]
            for target in targets:
                if isinstance(target, ast.Name) and target.id in where:
                    where[target.id].append(rel)
    twice = {name: paths for name, paths in where.items() if len(paths) != 1}
    assert not twice, f"defined in other than one module: {twice}"
    # The simulator's DEFAULT_SERVO is its view of the table's, not a second choice.
    from trajgen.sim.servos import DEFAULT_SERVO

    assert DEFAULT_SERVO.spec is T.SERVOS[T.DEFAULT_SERVO]


def test_overload_bit_is_not_spelled_out_in_the_driver_or_simulator():
    found = []
    for rel, text in _sources():
        if not rel.startswith(("drivers/", "sim/")):
            continue
        for tok in tokenize.generate_tokens(io.StringIO(text).readline):
            if tok.type == tokenize.NUMBER and tok.string.lower() == "0x20":
                found.append(f"{rel}:{tok.start[0]}")
    assert not found, found


@pytest.mark.parametrize("name", ["XL330-M288", "XL330-M077", "XC330-M288", "XH540-W270"])
def test_virtual_bus_serves_a_new_model_from_its_entry(name):
    # Through ServoBus -> dynamixel-sdk -> pty: the virtual servo answers with
    # the entry's Model Number and factory values, at the SDK's addresses.
    from dynamixel_sdk import PacketHandler, PortHandler

    from trajgen.drivers.bringup import check_servos
    from trajgen.drivers.bus import ServoBus
    from trajgen.drivers.errors import BringUpError
    from trajgen.drivers.units import JointMap
    from trajgen.drivers.virtual.bus import VirtualBus
    from trajgen.drivers.virtual.plant import FirstOrderPlant

    spec = T.SERVOS[name]
    items = control_items(spec)
    with VirtualBus(FirstOrderPlant(), models=name, lockstep_dt_s=0.01) as virtual:
        with ServoBus(virtual.port) as bus:
            assert bus.ping(1) == spec.number
            check_servos(bus, JointMap(), [name] * 3)
            with pytest.raises(BringUpError, match=rf"model number {spec.number} \({name}\), exp"):
                check_servos(bus, JointMap(), ["XM430-W350"] * 3)
        port, packets = PortHandler(virtual.port), PacketHandler(2.0)
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            for register in ("Position P Gain", "Position I Gain", "Velocity Limit", "Shutdown"):
                address, size = items[register]
                read = {
                    1: packets.read1ByteTxRx,
                    2: packets.read2ByteTxRx,
                    4: packets.read4ByteTxRx,
                }
                value, result, error = read[size](port, 2, address)
                assert (result, error) == (0, 0)
                assert value == spec.defaults[register], register
        finally:
            port.closePort()


def test_keyframe_files_take_every_model_per_joint():
    # [gimbal] servo (one name, or one per joint) and [bus] models read the same table.
    from trajgen.drivers.config import bus_config_from_tables
    from trajgen.sim.model import gimbal_config_from_tables

    names = sorted(T.SERVOS)
    for pan, tilt, roll in zip(names, names[1:] + names[:1], names[2:] + names[:2], strict=True):
        tables = {"gimbal": {"servo": {"pan": pan.lower(), "tilt": f" {tilt} ", "roll": roll}}}
        config = gimbal_config_from_tables(tables, "f.toml")
        assert [s.spec for s in config.servos] == [T.SERVOS[n] for n in (pan, tilt, roll)]
        assert bus_config_from_tables(tables, "f.toml").models == (pan, tilt, roll)
