"""One emulated X-series servo: its control table and the rules on writing it.

The control table is a byte array laid out as the model's (addresses from the
SDK's model files, access, initial values and ranges from the e-Manual, see
``drivers.control_table.rules``). Rules emulated, from the e-Manual:

- a write must cover whole registers (data length error), of registers that
  exist and are writable (access error); EEPROM (address < 64) refuses writes
  while torque is on (access error);
- a value outside its register's range is refused (data range error), an
  Operating Mode the model does not have too (:func:`accepts_mode`), a goal
  outside the limit register that bounds it (Goal Position within the position
  limits in Position Mode, Goal PWM / Current / Velocity within PWM / Current /
  Velocity Limit) too (data limit error);
- a tripped Bus Watchdog (-1) makes the goal registers refuse writes (data
  range error) until 0 is written to it;
- torque cannot be enabled while a hardware error that Shutdown covers is
  latched (result fail); such an error turns torque off;
- Indirect Data n reads and writes the byte Indirect Address n points at;
- changing Operating Mode resets the gains and the profile, and Goal PWM /
  Goal Current to PWM Limit / Current Limit;
- REBOOT resets the RAM area (address >= 64) to its initial values, keeping
  the EEPROM; FACTORY_RESET resets both (keeping ID, or ID and Baud Rate).

Values the servo stores itself (present values) are clamped to their register
size, so no simulated quantity can overflow a register.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping, Sequence

from trajgen.drivers.control_table import (
    EEPROM_END,
    LIMITED_BY,
    MODE_RESETS,
    POSITION_MODE,
    Model,
    Register,
    RegisterRule,
    control_items,
    rules,
)
from trajgen.drivers.protocol import StatusError
from trajgen.drivers.units import TICKS_PER_REV

#: Goal registers a tripped Bus Watchdog locks.
_GOALS = ("Goal PWM", "Goal Current", "Goal Velocity", "Goal Position")

#: What changing Operating Mode resets (``control_table.MODE_RESETS``, and Goal
#: Current on the models that have it; Goal PWM / Goal Current go to their limits).
_MODE_RESETS = (*(r.value for r in MODE_RESETS), "Goal Current")

#: The present-value registers the simulation fills (``store_present``), in address
#: order: one contiguous block (120..143) on every X-series model. Present Current
#: is Present Load on the XL430s (same address, another unit).
PRESENT_REGISTERS = (
    "Realtime Tick",
    "Moving",
    "Moving Status",
    "Present PWM",
    "Present Current",
    "Present Velocity",
    "Present Position",
    "Velocity Trajectory",
    "Position Trajectory",
)
#: struct codes of a register by (size in bytes, signed).
_STRUCT_CODE = {(1, False): "B", (1, True): "b", (2, False): "H", (2, True): "h"}
_STRUCT_CODE.update({(4, False): "I", (4, True): "i"})

#: FACTORY_RESET options (Protocol 2.0): what each keeps.
FACTORY_RESET_KEEPS = {0xFF: (), 0x01: ("ID",), 0x02: ("ID", "Baud Rate")}


class VirtualServo:
    """The control table and register rules of one servo.

    Parameters
    ----------
    servo_id : int
        Its ID (0..252).
    model : Model
        Its model (addresses, rules, current unit).
    firmware : int, optional
        Firmware Version register value.
    registers : mapping of str or Register to int, optional
        Values stored before power-up, as someone configured the servo
        (installed position limits, a gain...): EEPROM ones survive a reboot,
        RAM ones last until it; FACTORY_RESET forgets both.

    Attributes
    ----------
    memory : bytearray
        The control table's bytes (Indirect Data bytes hold their own value;
        reads and writes through them are redirected by ``read``/``write``).
    turn_offset_ticks : int
        Whole turns (in ticks) that CLEAR or REBOOT removed from Present
        Position: Present Position = plant ticks + Homing Offset - this.
    pending : tuple of (int, bytes) or None
        The write a REG_WRITE registered, until ACTION.

    Raises
    ------
    KeyError
        If ``registers`` names a register the model does not have.
    """

    def __init__(
        self,
        servo_id: int,
        model: Model,
        *,
        firmware: int = 48,
        registers: Mapping[Register | str, int] | None = None,
    ) -> None:
        self.model = model
        self.items = control_items(model)
        self.rules: dict[str, RegisterRule] = rules(model)
        self.table_end = max(a + s for a, s in self.items.values())
        self.memory = bytearray(self.table_end)
        self._owner: dict[int, str] = {}
        for name, (address, size) in self.items.items():
            for a in range(address, address + size):
                self._owner[a] = name
        self._direct_layouts: dict[tuple[int, int], tuple | None] = {}
        self._indirect: dict[int, str] = {}  # Indirect Data byte -> its Indirect Address name
        for name, (address, _) in self.items.items():
            if name.startswith("Indirect Data "):
                self._indirect[address] = "Indirect Address " + name.rsplit(" ", 1)[1]
        # name or Register -> (address, size, signed, lowest, highest value it holds)
        self._layout: dict[Register | str, tuple[int, int, bool, int, int]] = {}
        for name, (address, size) in self.items.items():
            signed = self.rules[name].signed
            bits = 8 * size
            span = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
            self._layout[name] = (address, size, signed, *span)
        if "Present Load" in self.items:  # XL430: Present Current's address, another unit
            self._layout["Present Current"] = self._layout["Present Load"]
        for register in Register:
            if register.value in self._layout:
                self._layout[register] = self._layout[register.value]
        # name or Register -> (unpack_from, pack_into, address): one C call per access
        self._codec = {}
        for key, (address, size, signed, _, _) in self._layout.items():
            packing = struct.Struct("<" + _STRUCT_CODE[size, signed])
            self._codec[key] = (packing.unpack_from, packing.pack_into, address)
        self._present_start, self._present_struct, self._present_spans = self._present_layout()
        # register -> (unpack_from, address) of each register bounding it (LIMITED_BY), where
        # the model has them all
        self._bounds = {
            name: tuple((self._codec[n][0], self._codec[n][2]) for n in limits)
            for name, limits in LIMITED_BY.items()
            if name in self.items and all(n in self.items for n in limits)
        }
        self.firmware = firmware
        self.turn_offset_ticks = 0
        self.pending: tuple[int, bytes] | None = None
        installed = {
            k.value if isinstance(k, Register) else k: int(v) for k, v in (registers or {}).items()
        }
        unknown = set(installed) - set(self.items)
        if unknown:
            raise KeyError(f"{model.name} has no register {sorted(unknown)[0]!r}")
        installed.setdefault("ID", servo_id)
        self._load(self.items, installed)

    # -- registers ----------------------------------------------------------

    def get(self, register: Register | str) -> int:
        """A register's value (signed where signed)."""
        unpack, _, address = self._codec[register]
        return unpack(self.memory, address)[0]

    def set(self, register: Register | str, value: int) -> None:
        """Store a value, bypassing the write rules (the servo itself).

        The value is clamped to what the register can hold.
        """
        _, _, _, low, high = self._layout[register]
        _, pack, address = self._codec[register]
        pack(self.memory, address, min(max(int(value), low), high))

    def _present_layout(self) -> tuple[int, struct.Struct, tuple[tuple[int, int], ...]]:
        """Where ``PRESENT_REGISTERS`` start, their packing, each one's (lowest, highest).

        Raises
        ------
        KeyError
            If the model's table does not hold them as one block in that order.
        """
        start = address = self._layout[PRESENT_REGISTERS[0]][0]
        codes, spans = [], []
        for name in PRESENT_REGISTERS:
            at, size, signed, low, high = self._layout[name]
            if at != address:
                raise KeyError(f"{self.model.name}: {name!r} at {at}, expected {address}")
            codes.append(_STRUCT_CODE[size, signed])
            spans.append((low, high))
            address += size
        return start, struct.Struct("<" + "".join(codes)), tuple(spans)

    def store_present(self, values: Sequence[int]) -> None:
        """Store every one of ``PRESENT_REGISTERS`` at once (the servo itself, as ``set``).

        Parameters
        ----------
        values : sequence of int, shape (9,)
            In ``PRESENT_REGISTERS`` order, register units; each is clamped to what
            its register can hold.
        """
        try:  # ints that fit: as they are (the common case, one C call)
            self._present_struct.pack_into(self.memory, self._present_start, *values)
            return
        except struct.error:
            pass
        clamped = [
            min(max(int(v), low), high)
            for v, (low, high) in zip(values, self._present_spans, strict=True)
        ]
        self._present_struct.pack_into(self.memory, self._present_start, *clamped)

    def _load(self, names: Iterable[str], installed: Mapping[str, int]) -> None:
        """Set ``names`` to their installed or initial values."""
        for name in names:
            rule = self.rules[name]
            if name in installed:
                self.set(name, installed[name])
            elif rule.initial is not None:
                self.set(name, rule.initial)
        self.set("Model Number", self.model.number)
        self.set("Firmware Version", self.firmware)
        if "Goal PWM" in names:
            self.set("Goal PWM", installed.get("Goal PWM", self.get("PWM Limit")))
        if "Goal Current" in names and "Current Limit" in self.items:
            self.set("Goal Current", installed.get("Goal Current", self.get("Current Limit")))

    @property
    def servo_id(self) -> int:
        """Its ID (the ID register)."""
        return self.get("ID")

    @property
    def torque_on(self) -> bool:
        """Whether Torque Enable is 1."""
        return self.get("Torque Enable") == 1

    @property
    def watchdog_tripped(self) -> bool:
        """Whether the Bus Watchdog reads -1."""
        return self.get("Bus Watchdog") == -1

    @property
    def position_mode(self) -> bool:
        """Whether Operating Mode is Position Mode (goals within the position limits)."""
        return self.get("Operating Mode") == POSITION_MODE

    @property
    def alert(self) -> bool:
        """Whether the status ERR byte carries the Alert bit (a hardware error is latched)."""
        return self.get("Hardware Error Status") != 0

    # -- reading and writing --------------------------------------------------

    def target(self, address: int) -> int:
        """The byte that ``address`` stands for (through Indirect Data)."""
        pointer = self._indirect.get(address)
        return address if pointer is None else self.get(pointer)

    def direct(self, address: int, length: int) -> bool:
        """Whether ``length`` bytes at ``address`` hold no Indirect Data byte (each is itself)."""
        return self._indirect.keys().isdisjoint(range(address, address + length))

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """READ: (status error, data); Indirect Data bytes read their targets."""
        if length == 0 or address + length > self.table_end:
            return StatusError.ACCESS, b""
        if self.direct(address, length):
            return 0, bytes(self.memory[address : address + length])
        return 0, bytes(self.memory[self.target(a)] for a in range(address, address + length))

    def _covers(self, targets: Sequence[int]) -> tuple[int, tuple[str, ...], bool, bool]:
        """What a write to the bytes ``targets`` covers: (status error, registers, EEPROM,
        alone).

        The error is for the layout alone: a byte of no register or of a read-only
        one (access), part of a register (data length); 0 with the registers in
        address order, whether one is in the EEPROM area, and whether none of them
        bounds another (``LIMITED_BY``: each is then checked against the table as it
        is).
        """
        names: list[str] = []
        for a in targets:
            name = self._owner.get(a)
            if name is None:
                return StatusError.ACCESS, (), False, False
            if name not in names:
                names.append(name)
        covered = set(targets)
        for name in names:
            start, size = self.items[name]
            if not covered.issuperset(range(start, start + size)):
                return StatusError.DATA_LENGTH, (), False, False
            if not self.rules[name].writable:
                return StatusError.ACCESS, (), False, False
        eeprom = any(self.items[n][0] < EEPROM_END for n in names)
        alone = not any(set(LIMITED_BY.get(n, ())) & set(names) for n in names)
        return 0, tuple(names), eeprom, alone

    def _direct_layout(
        self, address: int, length: int
    ) -> tuple[int, tuple[str, ...], bool, bool] | None:
        """``_covers`` of a write of ``length`` bytes at ``address`` (within the table), or
        None if they hold an Indirect Data byte; worked out once per (address, length)."""
        key = (address, length)
        if key not in self._direct_layouts:
            direct = self.direct(address, length)
            covers = self._covers(range(address, address + length)) if direct else None
            self._direct_layouts[key] = covers
        return self._direct_layouts[key]

    def check_write(self, address: int, data: bytes) -> tuple[int, bytearray | None, set[str]]:
        """What a WRITE of ``data`` at ``address`` would do.

        Returns
        -------
        error : int
            The status error (0: allowed).
        after : bytearray or None
            The control table as the write leaves it (Indirect Data resolved to
            its targets); None if refused.
        names : set of str
            The registers written.
        """
        error, after, names = self._check(address, data)
        if not error and after is None:  # a direct write checked in place
            after = self.memory.copy()
            after[address : address + len(data)] = data
        return error, after, names

    def _check(self, address: int, data: bytes) -> tuple[int, bytearray | None, set[str]]:
        """``check_write``, but ``after`` None for an allowed direct write of registers
        that bound none of each other (checked against the table as it is: no copy)."""
        n = len(data)
        if not n:
            return StatusError.DATA_LENGTH, None, set()
        if address + n > self.table_end:
            return StatusError.ACCESS, None, set()
        layout = self._direct_layout(address, n)
        if layout is not None:
            error, names, eeprom, alone = layout
            after = None if alone else self.memory.copy()
            if after is not None:
                after[address : address + n] = data
        else:
            targets = [self.target(address + k) for k in range(n)]
            error, names, eeprom, _ = self._covers(targets)
            after = self.memory.copy()
            for a, byte in zip(targets, data, strict=True):
                after[a] = byte
        if error:
            return error, None, set()
        if eeprom and self.torque_on:
            return StatusError.ACCESS, None, set()
        for name in names:
            unpack, _, at = self._codec[name]
            if after is None:
                error = self._check_value(name, unpack(data, at - address)[0], self.memory)
            else:
                error = self._check_value(name, unpack(after, at)[0], after)
            if error:
                return error, None, set()
        return 0, after, set(names)

    def _check_value(self, name: str, value: int, after: bytearray) -> int:
        """The status error of register ``name`` taking ``value``, the table then ``after``."""
        rule = self.rules[name]
        if name in _GOALS and self.watchdog_tripped:
            return StatusError.DATA_RANGE
        if rule.low is not None and not rule.low <= value <= rule.high:
            return StatusError.DATA_RANGE
        if name == "Operating Mode" and not accepts_mode(self.model, value):
            return StatusError.DATA_RANGE
        limits = self._bounds.get(name)
        if limits is not None:
            bounds = [unpack(after, at)[0] for unpack, at in limits]
            if name == "Goal Position":
                if self.get("Operating Mode") == POSITION_MODE and not (
                    bounds[0] <= value <= bounds[1]
                ):
                    return StatusError.DATA_LIMIT
            elif abs(value) > bounds[0]:
                return StatusError.DATA_LIMIT
        if name == "Torque Enable" and value == 1:
            if self.get("Hardware Error Status") & self.get("Shutdown"):
                return StatusError.RESULT_FAIL
        return 0

    def write(self, address: int, data: bytes) -> tuple[int, set[str]]:
        """WRITE if allowed: (status error, registers written); 0 means written."""
        error, after, names = self._check(address, data)
        if error:
            return error, set()
        old_mode = self.get("Operating Mode")
        if after is None:
            self.memory[address : address + len(data)] = data
        else:
            self.memory[:] = after
        if "Operating Mode" in names and self.get("Operating Mode") != old_mode:
            resets = [n for n in _MODE_RESETS if n in self.items]
            self._load(resets, {})
            names |= set(resets)
        return 0, names

    # -- what the servo does by itself -------------------------------------------

    def raise_hardware_error(self, bits: int) -> None:
        """Latch hardware error ``bits``; torque goes off if Shutdown covers them."""
        self.set("Hardware Error Status", self.get("Hardware Error Status") | bits)
        if bits & self.get("Shutdown"):
            self.set("Torque Enable", 0)

    def wrap_turns(self, plant_ticks: int) -> None:
        """Drop whole turns from Present Position (CLEAR, power-up): it reads 0..4095."""
        present = plant_ticks + self.get("Homing Offset") - self.turn_offset_ticks
        self.turn_offset_ticks += present - present % TICKS_PER_REV

    def present_ticks(self, plant_ticks: int) -> int:
        """Present Position for the plant at ``plant_ticks`` (servo frame, 2048 = 0 rad)."""
        return plant_ticks + self.get("Homing Offset") - self.turn_offset_ticks

    def plant_ticks(self, register_ticks: int) -> int:
        """The plant position (ticks) a position register value stands for."""
        return register_ticks - self.get("Homing Offset") + self.turn_offset_ticks

    def reboot(self, plant_ticks: int) -> None:
        """REBOOT: RAM registers back to their initial values, Present Position in one turn.

        Goal Position becomes the present position (the servo holds still when
        torque comes back on).
        """
        self._load([n for n, (a, _) in self.items.items() if a >= EEPROM_END], {})
        self.pending = None
        self.wrap_turns(plant_ticks)
        self.set("Goal Position", self.present_ticks(plant_ticks))

    def factory_reset(self, option: int, plant_ticks: int) -> None:
        """FACTORY_RESET with ``option`` (a key of ``FACTORY_RESET_KEEPS``), then reboot."""
        kept = {n: self.get(n) for n in FACTORY_RESET_KEEPS[option]}
        self._load(self.items, kept)
        self.reboot(plant_ticks)


def accepts_mode(model, mode: int) -> bool:
    """Whether servo ``model`` (a servo-table entry) takes Operating Mode ``mode``: one of
    its page's modes (``ServoSpec.operating_modes``; an XL430-W250 has no current-based
    modes). A real servo answers any other with a data range error."""
    return mode in model.operating_modes
