"""One emulated X-series servo: its control table and the rules on writing it.

The control table is a byte array laid out as the model's (addresses from the
SDK's model files). Rules emulated, from the e-Manual: read-only registers
refuse writes (access error); EEPROM (address < 64) refuses writes while torque
is on (access error); a tripped Bus Watchdog (-1) makes Goal Position refuse
writes (data range error) until 0 is written to it; Goal Position outside the
position limits in Position Mode is refused (data limit error); torque cannot
be enabled while a hardware error that Shutdown covers is latched (result
fail); a hardware error covered by Shutdown turns torque off.
"""

from __future__ import annotations

from trajgen.drivers.control_table import (
    EEPROM_END,
    POSITION_MODE,
    SIGNED,
    Model,
    Register,
    factory_defaults,
    layout,
)
from trajgen.drivers.protocol import StatusError
from trajgen.drivers.units import to_signed, to_unsigned

TABLE_SIZE = 1024

_READ_ONLY_NAMES = (
    "Model Number",
    "Model Information",
    "Firmware Version",
    "Registered Instruction",
    "Hardware Error Status",
    "Realtime Tick",
    "Moving",
    "Moving Status",
    "Present PWM",
    "Present Current",
    "Present Load",
    "Present Velocity",
    "Present Position",
    "Velocity Trajectory",
    "Position Trajectory",
    "Present Input Voltage",
    "Present Temperature",
)


def _read_only_bytes(model: Model) -> frozenset[int]:
    from dynamixel_easy_sdk.control_table import ControlTable

    table = ControlTable.getControlTable(model.number)
    out = set()
    for name in _READ_ONLY_NAMES:
        if name in table:
            item = table[name]
            out.update(range(item.address, item.address + item.size))
    return frozenset(out)


class VirtualServo:
    """The control table and register rules of one servo.

    Parameters
    ----------
    servo_id : int
        Its ID (0..252).
    model : Model
        Its model (addresses, defaults, current unit).
    firmware : int, optional
        Firmware Version register value.
    """

    def __init__(self, servo_id: int, model: Model, *, firmware: int = 48) -> None:
        self.model = model
        self.layout = layout(model)
        self.memory = bytearray(TABLE_SIZE)
        self._read_only = _read_only_bytes(model)
        for register, value in factory_defaults(model).items():
            self.set(register, value)
        self.set(Register.ID, servo_id)
        self.set(Register.FIRMWARE_VERSION, firmware)

    @property
    def servo_id(self) -> int:
        """Its ID."""
        return self.get(Register.ID)

    def get(self, register: Register) -> int:
        """A register's value (signed where signed)."""
        address, size = self.layout[register]
        value = int.from_bytes(self.memory[address : address + size], "little")
        return to_signed(value, size) if register in SIGNED else value

    def set(self, register: Register, value: int) -> None:
        """Store a register's value, bypassing the write rules (the servo itself)."""
        address, size = self.layout[register]
        self.memory[address : address + size] = to_unsigned(int(value), size).to_bytes(
            size, "little"
        )

    @property
    def torque_on(self) -> bool:
        """Whether Torque Enable is 1."""
        return self.get(Register.TORQUE_ENABLE) == 1

    @property
    def watchdog_tripped(self) -> bool:
        """Whether the Bus Watchdog reads -1."""
        return self.get(Register.BUS_WATCHDOG) == -1

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """READ: (status error, data)."""
        if address + length > TABLE_SIZE or length == 0:
            return StatusError.ACCESS, b""
        return 0, bytes(self.memory[address : address + length])

    def check_write(self, address: int, data: bytes) -> int:
        """The status error a WRITE of ``data`` at ``address`` would get (0: allowed)."""
        span = range(address, address + len(data))
        if not data or span.stop > TABLE_SIZE or any(a in self._read_only for a in span):
            return StatusError.ACCESS
        if address < EEPROM_END and self.torque_on:
            return StatusError.ACCESS
        goal_address, goal_size = self.layout[Register.GOAL_POSITION]
        if address <= goal_address < span.stop:
            if self.watchdog_tripped:
                return StatusError.DATA_RANGE
            if len(data) < goal_address - address + goal_size:
                return StatusError.DATA_LENGTH
            offset = goal_address - address
            goal = to_signed(int.from_bytes(data[offset : offset + goal_size], "little"), 4)
            limits = self.get(Register.MIN_POSITION_LIMIT), self.get(Register.MAX_POSITION_LIMIT)
            if self.get(Register.OPERATING_MODE) == POSITION_MODE and not (
                limits[0] <= goal <= limits[1]
            ):
                return StatusError.DATA_LIMIT
        torque_address = self.layout[Register.TORQUE_ENABLE][0]
        if address <= torque_address < span.stop and data[torque_address - address] == 1:
            if self.get(Register.HARDWARE_ERROR_STATUS) & self.get(Register.SHUTDOWN):
                return StatusError.RESULT_FAIL
        return 0

    def write(self, address: int, data: bytes) -> int:
        """WRITE if allowed; returns the status error (0: written)."""
        error = self.check_write(address, data)
        if error == 0:
            self.memory[address : address + len(data)] = data
        return error

    def raise_hardware_error(self, bits: int) -> None:
        """Latch hardware error ``bits``; torque goes off if Shutdown covers them."""
        self.set(Register.HARDWARE_ERROR_STATUS, self.get(Register.HARDWARE_ERROR_STATUS) | bits)
        if bits & self.get(Register.SHUTDOWN):
            self.set(Register.TORQUE_ENABLE, 0)

    def reboot(self) -> None:
        """REBOOT: clear hardware errors, torque off, Bus Watchdog 0."""
        self.set(Register.HARDWARE_ERROR_STATUS, 0)
        self.set(Register.TORQUE_ENABLE, 0)
        self.set(Register.BUS_WATCHDOG, 0)

    @property
    def alert(self) -> bool:
        """Whether the status ERR byte carries the Alert bit (a hardware error is latched)."""
        return self.get(Register.HARDWARE_ERROR_STATUS) != 0
