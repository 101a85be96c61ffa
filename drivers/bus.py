"""The servo bus: ``dynamixel-sdk`` over pyserial, with every result checked.

``ServoBus`` wraps the SDK's ``PortHandler`` and ``Protocol2PacketHandler``.
What it adds to them (see docs/dynamixel.md for why):

- the port opened exclusively (pyserial ``exclusive=True``, an ``flock``): a
  second program on the same port is refused with a message that says so;
- any baud rate, 4.5 Mbps included (``getCFlagBaud`` accepts any rate and
  pyserial sets it with BOTHER), and packet timeouts from the adapter's real
  latency timer instead of the SDK's fixed 16 ms;
- the FTDI latency timer set to 1 ms through sysfs where there is one;
- every reply checked before its value is used: the SDK's result code, then
  the status packet itself (the id asked, the length asked: the SDK slices
  whatever arrived, CRC bytes included, into the value), then its ERR byte; a
  retry budget, and errors that name the servo, the register and the tries
  (``CommError``, ``ServoError``); a bad reply raises, it never reads as a
  number;
- signed decoding of 2- and 4-byte registers;
- group reads (fast sync read, or sync read) that keep each servo's ERR byte,
  which the SDK's ``GroupSyncRead`` discards, so the Alert bit is seen;
- the two packets of every stream frame, Sync Write and Fast Sync Read, built
  and checked by ``drivers.frame_packets`` (laid out once, one read of the
  reply, the same checks), not by the SDK's per-byte Python: the SDK does
  everything else (pings, reads, writes, sync read, reboot);
- split-phase group reads (``request_block``, then ``collect``): the request
  goes out right after a frame's goal and its reply is read and checked
  before the next frame's goal, so that a read-back's wire time overlaps the
  wait for the next deadline instead of delaying it. Any other transaction
  while a reply is outstanding first waits that reply out (or its timeout)
  and drops it: it is never taken for the answer to another request; but a
  Sync Write may go out behind a reply whose computed wire end has passed
  (``sync_write(behind=...)``), leaving it to ``collect``.
"""

from __future__ import annotations

import errno
import functools
import math
import os
import select
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

from trajgen.drivers.clock import sleep_until
from trajgen.drivers.control_table import (
    RETURN_DELAY_UNIT_S,
    SIGNED,
    X_SERIES_RULES,
    Model,
    Register,
    describe_hardware_error,
    layout,
)
from trajgen.drivers.defaults import DEFAULT_BAUD
from trajgen.drivers.errors import CommError, ServoError
from trajgen.drivers.frame_packets import FastSyncReadPacket, SyncWritePacket, frame_status
from trajgen.drivers.protocol import ALERT_BIT, StatusError
from trajgen.drivers.units import to_signed, to_unsigned
from trajgen.servo_table import TURNAROUND_S
from trajgen.validate import check_number

from .errors import BadArgument

# The SDK's fixed assumption, used where the port has no latency timer to read.
DEFAULT_LATENCY_MS = 16.0
_SYSFS_LATENCY = "/sys/bus/usb-serial/devices/{tty}/latency_timer"
# Longest wait (s) for reply bytes a lock-step responder has written (they are in the
# pty already; this only bounds a kernel that never passes them on).
_OWED_WAIT_S = 5.0
# Most rounds of waiting for a quiet bus after a failed try (each one reply timeout).
_MAX_DRAINS = 10
# Status packet layout (e-Manual, Protocol 2.0): ID at byte 4, LEN at 5..6.
_PKT_ID, _PKT_LENGTH = 4, 5
_STATUS_MIN_BYTES = 11  # header 4, ID, LEN 2, INST, ERR, CRC 2
# A Sync Read request without its ids (header 4, ID, LEN 2, INST, address 2, size 2, CRC 2),
# and a Sync Write's bytes besides its data (the same, and an id per servo).
_SYNC_READ_REQUEST_BYTES = 14
# LEN of a status packet without data: INST, ERR, CRC 2.
_STATUS_LENGTH_NO_DATA = 4
# The SDK's result codes (dynamixel_sdk.robotis_def), for the frame packets' own path.
_COMM_SUCCESS, _COMM_TX_FAIL, _COMM_RX_TIMEOUT, _COMM_RX_CORRUPT = 0, -1001, -3001, -3002
_RX_MAX_LENGTH = 1024  # the SDK's RXPACKET_MAX_LEN (Protocol 2.0)
#: Added to a reply's computed wire end before a packet may go out behind it
#: (``sync_write(behind=...)``), s: the request reaching the wire later than it was
#: written (a USB adapter sends in 125 us microframes at high speed; a pty's kernel
#: work can wait behind the load) and a servo answering a little later than computed.
WIRE_MARGIN_S = 150e-6


def _make_port(port_name: str, latency_ms: float, responder=None):
    """An SDK PortHandler accepting any baud rate, timing out on ``latency_ms``.

    With a ``responder`` (a lock-step virtual bus in this process, see
    ``ServoBus``), each packet written is answered before ``writePort``
    returns, and a read waits for the reply bytes the responder wrote, however
    long the kernel takes to pass them through the pty: the SDK's timeout,
    which starts after the write, can then only expire where no reply was sent.
    """
    from dynamixel_sdk import PortHandler

    class _Port(PortHandler):
        owed = 0  # reply bytes the responder wrote that have not been read yet
        settle = None  # called before any packet is sent (ServoBus: an outstanding reply)
        wire_free_s = -math.inf  # when the last byte written is off the wire (computed, s)

        def _on_wire(self, n_bytes: int) -> None:
            """``n_bytes`` were just handed over: they follow what is still on the wire."""
            now = time.monotonic()
            self.wire_free_s = max(now, self.wire_free_s) + n_bytes * self.tx_time_per_byte / 1e3

        def setupPort(self, cflag_baud):  # noqa: N802 (SDK name)
            # The SDK's own, with the port locked (flock) against a second program.
            import serial

            if self.is_open:
                self.closePort()
            self.ser = serial.Serial(
                port=self.port_name,
                baudrate=self.baudrate,
                bytesize=serial.EIGHTBITS,
                timeout=0,
                exclusive=True,
            )
            self.is_open = True
            self.ser.reset_input_buffer()
            self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
            return True

        def getCFlagBaud(self, baudrate):  # noqa: N802 (SDK name)
            return baudrate if baudrate > 0 else -1

        def clearPort(self):  # noqa: N802 (SDK name)
            if self.settle is not None:  # every packet sent (SDK or not) comes through here
                self.settle()
            self._wait_owed(self.owed)  # so that a stale reply is really dropped
            super().clearPort()
            self.owed = 0

        def writePort(self, packet):  # noqa: N802 (SDK name)
            written = self.ser.write(packet)
            self._on_wire(written)
            if responder is not None:
                self.owed += responder.answer(written)
            return written

        def readPort(self, length):  # noqa: N802 (SDK name)
            if self.owed:
                self._wait_owed(min(length, self.owed))
            elif not self.ser.in_waiting:
                # The SDK polls this in a loop with a zero timeout; wait here (up to
                # 1 ms, GIL released) for the first byte instead of spinning a core.
                select.select([self.ser.fileno()], [], [], 0.001)
            data = self.ser.read(length)
            self.owed = max(0, self.owed - len(data))
            return data

        def _wait_owed(self, n_bytes: int) -> None:
            """Wait until ``n_bytes`` are readable (bounded by ``_OWED_WAIT_S``)."""
            deadline = time.monotonic() + _OWED_WAIT_S
            while n_bytes and self.ser.in_waiting < n_bytes:
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                select.select([self.ser.fileno()], [], [], min(left, 0.001))

        def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
            self.packet_start_time = self.getCurrentTime()
            self.packet_timeout = self.timeout_ms(packet_length)

        def timeout_ms(self, packet_length: int) -> float:
            """The reply timeout (ms) for ``packet_length`` bytes (as the SDK counts them)."""
            return self.tx_time_per_byte * packet_length + 2.0 * latency_ms + 2.0

        def send(self, packet: bytes, *, flush: bool = True) -> int:
            """Write ``packet`` whole (``os.write``, no pyserial); returns the bytes written.

            Input is flushed first, as the SDK's ``txPacket`` does, unless not
            ``flush`` (a reply still to be read: ``ServoBus.sync_write(behind=...)``).
            """
            if flush:
                self.clearPort()
            fd, view, sent = self.ser.fileno(), memoryview(packet), 0
            while sent < len(packet):
                try:
                    sent += os.write(fd, view[sent:])
                except BlockingIOError:
                    select.select([], [fd], [], 0.001)
            self._on_wire(sent)
            if responder is not None:
                self.owed += responder.answer(sent)
            return sent

        def receive_status(self, expected: int, timeout_ms: float) -> tuple[int, bytes]:
            """One status packet framed as the SDK's ``rxPacket`` does, read in as few reads
            as the bytes allow (``expected`` at once); returns (SDK result code, packet).

            Timeout after ``timeout_ms`` (ms) from now, as the SDK's packet
            timeout: no byte is "no status packet", a part is "incorrect".
            Lock-step reply bytes the responder wrote are waited for however
            long the kernel takes (bounded by ``_OWED_WAIT_S``).
            """
            fd = self.ser.fileno()
            now = time.monotonic()
            deadline, owed_deadline = now + timeout_ms / 1e3, now + _OWED_WAIT_S
            buffer = bytearray()
            total = expected
            ready = False  # select said readable
            while True:
                try:
                    data = os.read(fd, max(expected, total) - len(buffer))
                except BlockingIOError:
                    data = b""
                if ready and not data:  # readable, yet nothing: gone (as pyserial says)
                    raise OSError(errno.EIO, "the port is readable but returns nothing (gone?)")
                ready = False
                if data:
                    self.owed = max(0, self.owed - len(data))
                    buffer += data
                    state, total = frame_status(buffer, _RX_MAX_LENGTH)
                    if state == "ok":
                        return _COMM_SUCCESS, bytes(buffer[:total])
                    if state == "crc":
                        return _COMM_RX_CORRUPT, b""
                    continue
                left = (owed_deadline if self.owed else deadline) - time.monotonic()
                if left <= 0:
                    return (_COMM_RX_CORRUPT if buffer else _COMM_RX_TIMEOUT), b""
                ready = bool(select.select([fd], [], [], left)[0])

    return _Port(port_name)


def _make_packet_handler():
    """An SDK Protocol 2.0 packet handler that keeps the last status packet it read.

    The SDK's read functions slice the data out of a status packet without
    looking at its length field: a well-formed reply (valid CRC) with too few
    data bytes hands the CRC, or nothing, to the caller as data. Keeping the
    packet where it arrives lets ``ServoBus`` check the id and the length
    before it trusts a value.
    """
    from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

    class _PacketHandler(Protocol2PacketHandler):
        last_rx: list[int] = []

        def rxPacket(self, port, fast_option):  # noqa: N802 (SDK name)
            rxpacket, result = super().rxPacket(port, fast_option)
            self.last_rx = rxpacket
            return rxpacket, result

    return _PacketHandler()


def reply_problem(packet: Sequence[int], servo_id: int, length_field: int) -> str | None:
    """Why a status packet (CRC already checked) cannot be trusted, or None.

    Parameters
    ----------
    packet : sequence of int
        The status packet, header to CRC, byte stuffing removed.
    servo_id : int
        The id the request addressed (``BROADCAST_ID`` for a fast sync read).
    length_field : int
        The LEN the reply must carry: INST + ERR + data + CRC, i.e. the number
        of data bytes asked plus 4 (a fast sync read: 1 + (data + 4) per servo).

    Returns
    -------
    str or None
        A message naming what arrived against what was asked.
    """
    if len(packet) < _STATUS_MIN_BYTES:
        return f"reply of {len(packet)} bytes, expected at least {_STATUS_MIN_BYTES}"
    if packet[_PKT_ID] != servo_id:
        return f"reply from id {packet[_PKT_ID]}, expected {servo_id}"
    length = packet[_PKT_LENGTH] | packet[_PKT_LENGTH + 1] << 8
    if length != length_field:
        return f"reply of length {length} (LEN field), expected {length_field}"
    return None


def _latency_path(port_name: str) -> str:
    """Where Linux exposes a USB serial adapter's latency timer for ``port_name``."""
    return _SYSFS_LATENCY.format(tty=os.path.basename(os.path.realpath(port_name)))


def set_ftdi_latency_timer(port_name: str, latency_ms: int = 1) -> int | None:
    """Set an FTDI adapter's latency timer through sysfs, where there is one.

    Parameters
    ----------
    port_name : str
        Serial device path, e.g. ``/dev/ttyUSB0`` (symlinks are followed).
    latency_ms : int
        Wanted latency timer (ms).

    Returns
    -------
    int or None
        The latency timer after the attempt (ms), or None when the port has no
        latency timer (not a USB serial adapter, e.g. a pseudo-terminal).
        Warns (``RuntimeWarning``) when it stays at 16 ms or more.
    """
    path = _latency_path(port_name)
    if not os.path.exists(path):
        return None
    try:
        with open(path, "w") as f:
            f.write(f"{latency_ms}\n")
    except OSError:
        pass  # not permitted: reported below through the value read back
    with open(path) as f:
        value = int(f.read().strip())
    if value >= 16:
        warnings.warn(
            f"{port_name}: FTDI latency timer is {value} ms (could not set {latency_ms} ms); "
            f"every read-back will wait about {value} ms. Fix: "
            f"echo {latency_ms} | sudo tee {path}",
            RuntimeWarning,
            stacklevel=2,
        )
    return value


@dataclass(frozen=True)
class BlockRead:
    """One group read of a register block from several servos.

    Attributes
    ----------
    registers : tuple of Register
        The registers read, in the order asked.
    errors : dict of int to int
        Per servo id (in the order read), its status ERR byte (bit 7 = Alert).
    table : list of list of int
        Per servo in the order read, each register's value in the order
        asked, decoded (signed where signed): for arrays, without a lookup
        per value.
    """

    registers: tuple[Register, ...]
    errors: dict[int, int]
    table: list[list[int]]

    @functools.cached_property
    def values(self) -> dict[int, dict[Register, int]]:
        """Per servo id, each register of the block (the ``table`` by id and register)."""
        rows = zip(self.errors, self.table, strict=True)
        return {i: dict(zip(self.registers, row, strict=True)) for i, row in rows}


@dataclass
class PendingRead:
    """A group read whose request is on the wire and whose reply is not read yet.

    Made by ``ServoBus.request_block``; ``ServoBus.collect`` reads and checks
    the reply. A sync read (not split) holds its ``block`` at once.

    Attributes
    ----------
    ids : tuple of int
        Servos, answering in this order.
    registers : tuple of Register
        The registers asked, in the order asked.
    sent_s : float
        When the request was handed to the port (``time.monotonic``, s).
    deadline_s : float
        When its reply times out (s, same clock): the reply timeout of the
        same read done at once, counted from ``sent_s``.
    wire_end_s : float
        When its reply's last byte is off the wire, as computed (s, same
        clock): the request's end on the wire (after what was sent before
        it), the servos' turnaround and Return Delay Time, and the reply's
        bytes at the baud rate (``ServoBus.reply_wire_end``).
    problem : str or None
        Why the request could not be sent (collect then retries), or None.
    block : BlockRead or None
        The result, where it is known already (a sync read).
    """

    ids: tuple[int, ...]
    registers: tuple[Register, ...]
    sent_s: float
    deadline_s: float
    problem: str | None = None
    wire_end_s: float = -math.inf
    block: BlockRead | None = None
    spec: object = None
    what: str = ""


class ServoBus:
    """A Protocol 2.0 bus on one serial port.

    Parameters
    ----------
    port : str
        Serial device path (``/dev/ttyUSB0``, or a pseudo-terminal).
    baud : int, optional
        Baud rate (bit/s), any rate the servos support (4.5 Mbps included).
    retries : int, optional
        Extra tries of a transaction that times out or gets a corrupt reply,
        before ``CommError``.
    latency_ms : float or None, optional
        Adapter latency (ms) used in reply timeouts; None reads the FTDI latency
        timer (after setting it to 1 ms) and falls back to 16 ms.
    responder : object, optional
        A lock-step virtual bus in this process (``VirtualBus.connect`` passes
        it): each packet written is answered in this thread (its
        ``answer(n_bytes)``) before the reply is awaited, so no reply timeout
        depends on another thread being scheduled in time. Its
        ``attach_client``/``detach_client`` are called on open and close.

    Raises
    ------
    ValueError
        If ``baud`` is not a positive int or ``retries`` is negative.

    Attributes
    ----------
    models : dict of int to Model
        Declared servos (``add_servo``).
    failed_tries : int
        Transaction tries that failed so far (timeouts, corrupt replies, port
        errors), retried or not.
    torque_written : dict of int to int
        Per servo id, the last Torque Enable value written to it through this
        bus (acknowledged or not): what the driver did to each servo's torque,
        for the per-servo outcome (``drivers.outcome``).
    driven : set of int
        Servos sent a Goal Position through this bus (write or sync write).
    latency_timer_ms : int or None
        The USB adapter's latency timer as read after ``open`` tried to set it
        to 1 ms (None: the port has none, e.g. not an FTDI adapter, a pty).
    lockstep : bool
        Whether a ``responder`` answers (simulated time: a stream on this bus
        runs on a ``SimulatedClock``).
    return_delay_s : float
        The servos' longest Return Delay Time (s), used in a reply's computed
        wire end: the register's largest value (508 us) until a caller that
        has read it says (``Streamer`` does at its start).

    Notes
    -----
    Servos are addressed by id; ``add_servo`` tells the bus a servo's model so
    that registers resolve to its addresses. Use as a context manager, or call
    ``open`` and ``close``.
    """

    def __init__(
        self,
        port: str,
        *,
        baud: int = DEFAULT_BAUD,
        retries: int = 2,
        latency_ms: float | None = None,
        responder=None,
    ) -> None:
        baud = check_number("baud", baud, integer=True, low=1)
        retries = check_number("retries", retries, integer=True, low=0)
        self.port_name = port
        self.baud = baud
        self.retries = retries
        self.latency_ms = latency_ms
        self.responder = responder
        self.lockstep = responder is not None
        self.latency_timer_ms: int | None = None
        self.models: dict[int, Model] = {}
        self.failed_tries = 0
        self.torque_written: dict[int, int] = {}
        self.driven: set[int] = set()
        self._port = None
        self._ph = None
        self._frame_packets: dict[tuple, object] = {}  # laid-out packets, by servos and registers
        self._pending: PendingRead | None = None  # a split-phase read whose reply is out
        self.return_delay_s = X_SERIES_RULES["Return Delay Time"].high * RETURN_DELAY_UNIT_S

    # -- port ------------------------------------------------------------

    def open(self) -> ServoBus:
        """Open the port at ``baud``; returns self.

        Raises
        ------
        CommError
            If the port cannot be opened or the baud rate set.
        """
        import serial

        self.latency_timer_ms = set_ftdi_latency_timer(self.port_name)
        if self.latency_ms is None:
            timer = self.latency_timer_ms
            self.latency_ms = DEFAULT_LATENCY_MS if timer is None else float(timer)
        self._port = _make_port(self.port_name, self.latency_ms, self.responder)
        self._ph = _make_packet_handler()
        try:
            ok = self._port.setBaudRate(self.baud)
        except (serial.SerialException, OSError, ValueError) as e:
            self._port = None
            if "exclusively lock" in str(e):
                raise CommError(
                    f"{self.port_name}: in use by another program (it holds the port's lock); "
                    "stop it first: two programs on one bus garble each other's packets"
                ) from e
            raise CommError(f"{self.port_name}: cannot open at {self.baud} baud: {e}") from e
        if not ok:
            self._port = None
            raise CommError(f"{self.port_name}: baud rate {self.baud} refused")
        if self.responder is not None:
            self.responder.attach_client()
        return self

    def close(self) -> None:
        """Close the port (no effect when closed)."""
        self._pending = None
        if self._port is not None:
            try:
                self._port.closePort()
            except OSError:
                pass  # already gone (unplugged)
            self._port = None
            if self.responder is not None:
                self.responder.detach_client()

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._port is not None

    def __enter__(self) -> ServoBus:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def _sdk(self, what: str, call, *args):
        """Run one SDK call, turning OS errors (unplugged port) into CommError."""
        import termios

        import serial

        if self._port is None:
            raise CommError(f"{self.port_name}: {what}: port is not open")
        try:
            return call(*args)
        except (serial.SerialException, OSError, termios.error) as e:
            self._port.is_using = False  # the SDK leaves it set after an exception
            self.failed_tries += 1
            raise CommError(f"{self.port_name}: {what}: port failed: {e}") from e
        except BaseException:  # Ctrl-C mid-transaction
            self._port.is_using = False
            raise

    def _result_text(self, result: int) -> str:
        return self._ph.getTxRxResult(result).removeprefix("[TxRxResult] ")

    def latency_advice(self) -> str:
        """ "" or a clause on the adapter's latency timer, when it slows every read-back."""
        timer = self.latency_timer_ms
        if timer is None or timer <= 1:
            return ""
        return (
            f"; {self.port_name}'s FTDI latency timer is {timer} ms and every read-back waits "
            f"for it: lower it with echo 1 | sudo tee {_latency_path(self.port_name)}"
        )

    # -- servos ------------------------------------------------------------

    def add_servo(self, servo_id: int, model: Model) -> None:
        """Declare the model of servo ``servo_id`` (register addresses follow it)."""
        self.models[servo_id] = model
        self._frame_packets.clear()

    def _address(self, servo_id: int, register: Register) -> tuple[int, int]:
        try:
            model = self.models[servo_id]
        except KeyError:
            raise BadArgument(
                f"Servo {servo_id} has no model; call add_servo({servo_id}, model) first."
            ) from None
        return layout(model)[register]

    def _check_status(self, servo_id: int, error: int, what: str) -> None:
        low = error & ~ALERT_BIT
        if low:
            try:
                name = StatusError(low).name.lower().replace("_", " ")
            except ValueError:
                name = f"code {low}"
            raise ServoError(f"servo {servo_id}: {what}: status error: {name} ({error:#04x})")
        if error & ALERT_BIT:
            self.raise_hardware_error(servo_id, during=what)

    def _problem(self, result: int, servo_id: int, length_field: int) -> str | None:
        """What is wrong with the transaction just done, or None if its reply is sound.

        Checks the SDK's result code, then the status packet it read (id and
        length, see ``reply_problem``).
        """
        if result != 0:
            return self._result_text(result)
        return reply_problem(self._ph.last_rx, servo_id, length_field)

    def _retry(self, who: str, what: str, attempt, *, done: int = 0, problem: str | None = None):
        """Run ``attempt()`` up to ``retries + 1 - done`` times; returns its value.

        ``attempt`` returns ``(value, problem)``, ``problem`` None on success or
        the reason the try failed (counted in ``failed_tries``). ``done``: tries
        of the budget already spent (and failed, the last for ``problem``).

        Raises
        ------
        CommError
            If every try failed, naming the last reason.
        """
        for _ in range(self.retries + 1 - done):
            value, problem = attempt()
            if problem is None:
                return value
            self.failed_tries += 1
            self._drain()
        raise CommError(f"{who}: {what} failed after {self.retries + 1} tries: {problem}")

    def _drain(self) -> None:
        """After a failed try: wait until the bus has been quiet for one reply timeout,
        dropping what arrives.

        A reply later than its timeout would otherwise be read as the answer to
        the next request: same id and length (another register of the same
        servo), the wrong value. Costs one timeout per failed try.
        """
        import termios

        import serial

        port = self._port
        if port is None:
            return
        quiet_s = (2.0 * self.latency_ms + 2.0) / 1e3
        try:
            for _ in range(_MAX_DRAINS):
                port.clearPort()
                if not select.select([port.ser.fileno()], [], [], quiet_s)[0]:
                    return
        except (serial.SerialException, OSError, ValueError, termios.error):
            pass  # the port failed (pyserial lets termios.error through): the next try says so

    def _unicast(self, servo_id: int, what: str, call, *args, data_bytes: int = 0):
        """One unicast transaction with retries; returns the SDK call's result tuple.

        The reply is checked for the id asked and ``data_bytes`` of data (the
        SDK's own checks are only CRC and, for some calls, the id); a servo
        that reports a CRC error in the request is retried like a corrupt reply.
        """

        def attempt():
            out = self._sdk(what, call, self._port, servo_id, *args)
            problem = self._problem(out[-2], servo_id, data_bytes + _STATUS_LENGTH_NO_DATA)
            if problem is None and out[-1] & ~ALERT_BIT == StatusError.CRC:
                problem = "the servo received a corrupt request (status: crc)"
            return out, problem

        return self._retry(f"servo {servo_id}", what, attempt)

    def raise_hardware_error(self, servo_id: int, *, during: str) -> None:
        """Read Hardware Error Status of a servo whose Alert bit is set, and raise.

        Raises
        ------
        ServoError
            Always: naming the hardware error bits (or the read failure).
        """
        address = self._address(servo_id, Register.HARDWARE_ERROR_STATUS)[0]
        try:
            value, _, _ = self._unicast(
                servo_id,
                "read Hardware Error Status",
                self._ph.read1ByteTxRx,
                address,
                data_bytes=1,
            )
        except CommError as e:
            raise ServoError(
                f"servo {servo_id}: Alert bit set during {during}; reading Hardware Error "
                f"Status failed: {e}"
            ) from e
        raise ServoError(
            f"servo {servo_id}: hardware error during {during}: {describe_hardware_error(value)} "
            f"(Hardware Error Status {value:#04x}); torque stays off until the servo is rebooted"
        )

    def ping(self, servo_id: int) -> int:
        """Ping one servo; returns its model number.

        Raises
        ------
        CommError
            If no valid reply (this id, 3 data bytes) arrives within the retry budget.
        ServoError
            If the servo's status reports an error. (Its Alert bit is not
            resolved here: the model, hence the register map, is not known yet.
            ``drivers.bringup`` reads Hardware Error Status next.)
        """
        number, _, error = self._unicast(servo_id, "ping", self._ph.ping, data_bytes=3)
        self._check_status(servo_id, error & ~ALERT_BIT, "ping")
        return number

    def scan(self) -> dict[int, tuple[int, int]]:
        """Broadcast ping: every servo that answers.

        Returns
        -------
        dict of int to (int, int)
            Servo id -> (model number, firmware version).

        Raises
        ------
        CommError
            If the port fails or a reply is corrupt (no reply gives an empty dict).
        """
        found, result = self._sdk("broadcast ping", self._ph.broadcastPing, self._port)
        if result not in (0, -3001):  # success, or no servo at all
            raise CommError(f"{self.port_name}: broadcast ping: {self._result_text(result)}")
        return {i: (int(m), int(f)) for i, (m, f) in sorted(found.items())}

    def read(self, servo_id: int, register: Register) -> int:
        """Read one register (signed where the register is signed).

        Raises
        ------
        CommError
            If no valid reply (this id, the register's size in data bytes)
            arrives within the retry budget.
        ServoError
            If the servo's status reports an error or a hardware error.
        """
        address, size = self._address(servo_id, register)
        what = f"read {register.value}"
        data, _, error = self._unicast(
            servo_id, what, self._ph.readTxRx, address, size, data_bytes=size
        )
        self._check_status(servo_id, error, what)
        value = int.from_bytes(bytes(data), "little")
        return to_signed(value, size) if register in SIGNED else value

    def write(self, servo_id: int, register: Register, value: int) -> None:
        """Write one register and wait for the servo's acknowledgement.

        Raises
        ------
        ValueError
            If ``value`` does not fit the register.
        CommError
            If no valid acknowledgement arrives within the retry budget.
        ServoError
            If the servo refuses the write (access, range, limit) or is in
            hardware error.
        """
        address, size = self._address(servo_id, register)
        data = list(to_unsigned(int(value), size).to_bytes(size, "little"))
        what = f"write {register.value} = {value}"
        if register is Register.TORQUE_ENABLE:
            self.torque_written[servo_id] = int(value)
        elif register is Register.GOAL_POSITION:
            self.driven.add(servo_id)
        _, error = self._unicast(servo_id, what, self._ph.writeTxRx, address, size, data)
        self._check_status(servo_id, error, what)

    def reboot(self, servo_id: int) -> None:
        """Reboot a servo (clears a hardware error; torque comes back off).

        Raises
        ------
        CommError
            If no valid reply arrives within the retry budget.
        """
        self._unicast(servo_id, "reboot", self._ph.reboot)

    def sync_write(
        self, register: Register, values: dict[int, int], *, behind: PendingRead | None = None
    ) -> None:
        """One Sync Write of ``register`` to several servos (no reply to wait for).

        Built by ``frame_packets.SyncWritePacket`` (byte-stuffed where the data
        holds ``FF FF FD``, which the SDK's TX path would drop).

        ``behind``: a split-phase read whose reply is outstanding. The packet
        then goes out once that reply's computed wire end (``reply_wire_end``)
        has passed, waiting for it if not, and leaves the reply to ``collect``
        (neither waited for nor dropped): the wire is free, only the host has
        not read the reply yet (an adapter's latency timer, a pty). A servo
        answering later than computed would collide with the packet on a
        half-duplex bus: the packet dropped by the servos' CRC check, the
        reply a failed try of ``collect``.

        Raises
        ------
        ValueError
            If a value does not fit the register.
        CommError
            If the port fails.
        """
        ids = tuple(values)
        key = ("sync write", register, ids)
        packet = self._frame_packets.get(key)
        if packet is None:
            address, size = self._address(ids[0], register)
            packet = self._frame_packets[key] = SyncWritePacket(address, size, ids)
        if register is Register.GOAL_POSITION:
            self.driven.update(ids)
        data = packet.encode(list(values.values()))
        what = f"sync write {register.value}"
        keep = behind is not None and behind is self._pending
        if keep:
            sleep_until(self.reply_wire_end(behind))
        if self._sdk(what, functools.partial(self._port.send, flush=not keep), data) != len(data):
            failed = self._result_text(_COMM_TX_FAIL)
            raise CommError(f"servos {list(ids)}: {what} failed: {failed}")

    def read_block(
        self, ids: Sequence[int], registers: Sequence[Register], *, fast: bool = True
    ) -> BlockRead:
        """One group read of a contiguous register block from several servos.

        Parameters
        ----------
        ids : sequence of int
            Servos, answering in this order.
        registers : sequence of Register
            Registers covering one contiguous block (any order).
        fast : bool, optional
            Fast Sync Read (one reply packet) if True, else Sync Read (one
            status packet per servo).

        Returns
        -------
        BlockRead
            Values and each servo's ERR byte. The caller decides what an ERR
            byte means; ``check_block`` raises on any error bit.

        Raises
        ------
        CommError
            If a reply is missing, corrupt, from another id or of another length
            than the block asked, after the retry budget.
        """
        ids, registers = tuple(ids), tuple(registers)
        spec, what = self._laid_out(ids, registers, fast)
        read = self._fast_group_read if fast else self._group_read
        errors, table = self._retry(f"servos {list(ids)}", what, lambda: read(spec, what))
        return BlockRead(registers, dict(zip(ids, errors, strict=True)), table)

    def request_block(
        self, ids: Sequence[int], registers: Sequence[Register], *, fast: bool = True
    ) -> PendingRead:
        """Send a group read's request and return without waiting for its reply.

        The first half of ``read_block`` (split phase): ``collect`` reads the
        reply and checks it exactly as ``read_block`` does. Meanwhile the
        caller may wait, compute or send packets that have no reply... but
        any packet sent through this bus first waits the reply out (up to its
        timeout) and drops it (``collect`` then raises ``CommError``): on a
        half-duplex bus a packet sent over a servo's reply garbles both, and a
        reply read after another request would be taken for its answer. A Sync
        Read (``fast=False``, one status packet per servo) is not split: it is
        read at once, and ``collect`` returns its result.

        Parameters and errors as ``read_block`` (a sync read raises here).
        """
        ids, registers = tuple(ids), tuple(registers)
        now = time.monotonic()
        if not fast:
            block = self.read_block(ids, registers, fast=False)
            return PendingRead(ids, registers, now, now, block=block)
        spec, what = self._laid_out(ids, registers, fast)
        port = self._port
        problem = None
        if self._sdk(what, port.send, spec.request) != len(spec.request):
            problem = self._result_text(_COMM_TX_FAIL)
        sent = time.monotonic()
        deadline = sent + port.timeout_ms((11 + spec.length) * len(spec.ids)) / 1e3
        wire_end = port.wire_free_s + self.reply_s(spec.reply_bytes)
        pending = PendingRead(
            ids, registers, sent, deadline, problem, wire_end, spec=spec, what=what
        )
        if problem is None:
            self._pending = pending
            port.settle = self._drop_pending
        return pending

    def collect(self, pending: PendingRead) -> BlockRead:
        """The reply to ``request_block``'s request, checked; retried at once where it is not sound.

        Waits for the reply until ``pending.deadline_s`` at most. Bytes already
        in when it is called are read first, however late the caller comes: no
        packet went out since the request (see ``request_block``), so they can
        only be its reply. A reply that is missing, later than the deadline,
        corrupt, from another id or of another length is never used: the try
        counts as failed, the bus is drained (a reply still on its way is
        dropped), and the rest of the retry budget is spent on ``read_block``
        tries.

        Raises
        ------
        CommError
            If no try got a sound reply, or the reply was dropped because
            another packet was sent first.
        """
        if pending.block is not None:
            return pending.block
        who, what, spec = f"servos {list(pending.ids)}", pending.what, pending.spec
        if pending.problem is None and self._pending is not pending:
            raise CommError(
                f"{who}: {what}: its reply was dropped (another packet was sent while it was due)"
            )
        problem = pending.problem
        if problem is None:
            self._clear_pending()
            left_ms = max(0.0, pending.deadline_s - time.monotonic()) * 1e3
            value, problem = self._fast_reply(spec, what, left_ms)
            if problem is None:
                errors, table = value
                return BlockRead(
                    pending.registers, dict(zip(pending.ids, errors, strict=True)), table
                )
        self.failed_tries += 1
        self._drain()
        # The split try was the first of the budget; the rest are tries of read_block.
        errors, table = self._retry(
            who, what, lambda: self._fast_group_read(spec, what), done=1, problem=problem
        )
        return BlockRead(pending.registers, dict(zip(pending.ids, errors, strict=True)), table)

    def read_bytes(self, ids: Sequence[int], registers: Sequence[Register], *, fast: bool = True):
        """Bytes a group read puts on the wire: its request and its reply (or replies)."""
        ids, registers = tuple(ids), tuple(registers)
        spec, _ = self._laid_out(ids, registers, fast)
        if fast:
            return len(spec.request) + spec.reply_bytes
        length = spec[2]
        return _SYNC_READ_REQUEST_BYTES + len(ids) * (1 + _STATUS_MIN_BYTES + length)

    def wire_s(self, n_bytes: int) -> float:
        """How long ``n_bytes`` take on the wire at ``baud`` (10 bits a byte), s."""
        return n_bytes * 10 / self.baud

    def reply_s(self, n_bytes: int) -> float:
        """From a request's end on the wire to the end of its reply of ``n_bytes`` (s): the
        servos' turnaround and Return Delay Time, then the bytes (one packet: a fast read)."""
        return TURNAROUND_S + self.return_delay_s + self.wire_s(n_bytes)

    def reply_wire_end(self, pending: PendingRead) -> float:
        """When (``time.monotonic``, s) a packet may go out behind ``pending``'s reply:
        its computed wire end (``PendingRead.wire_end_s``) and ``WIRE_MARGIN_S``."""
        return pending.wire_end_s + WIRE_MARGIN_S

    def await_reply(self, pending: PendingRead, until_s: float) -> bool:
        """Wait (the GIL and the core free) until ``pending``'s reply bytes are all in, or
        until ``until_s`` (``time.monotonic``, s); returns whether they are in.

        Nothing is read: ``collect`` reads and checks them. A stream waits here for its
        next deadline, so that the reply is taken as soon as it is in, and the host's core
        is free meanwhile for the kernel work that brings it (a pty's or a USB adapter's).
        """
        if pending.block is not None or self._pending is not pending:
            return True
        port = self._port
        fd, wanted = port.ser.fileno(), pending.spec.reply_bytes
        while port.ser.in_waiting < wanted:
            left = until_s - time.monotonic()
            if left <= 0:
                return False
            select.select([fd], [], [], left)
        return True

    def _clear_pending(self) -> None:
        self._pending = None
        if self._port is not None:
            self._port.settle = None

    def _drop_pending(self) -> None:
        """Another packet is about to go out while a split-phase reply is due: wait it out
        (its bytes, up to its timeout), then drain the bus, and drop it unread."""
        pending = self._pending
        self._clear_pending()
        if pending is None:
            return
        port = self._port
        fd, wanted = port.ser.fileno(), pending.spec.reply_bytes
        try:
            while port.ser.in_waiting < wanted:
                left = pending.deadline_s - time.monotonic()
                if left <= 0:
                    break
                select.select([fd], [], [], left)
        except OSError:
            return  # the port failed: the packet about to go out says so
        self._drain()

    def _laid_out(self, ids: tuple, registers: tuple, fast: bool):
        """A group read's packets or block (``_read_spec``) and its name, laid out once."""
        key = ("read", ids, registers, fast)
        laid_out = self._frame_packets.get(key)
        if laid_out is None:
            kind = "fast sync read" if fast else "sync read"
            what = f"{kind} of {', '.join(r.value for r in registers)}"
            laid_out = self._frame_packets[key] = (self._read_spec(ids, registers, fast), what)
        return laid_out

    def _read_spec(self, ids, registers, fast):
        """A fast sync read's packets (``FastSyncReadPacket``), or a sync read's block."""
        spans = [self._address(ids[0], r) for r in registers]
        start = min(a for a, _ in spans)
        length = max(a + s for a, s in spans) - start
        fields = [(a, s, r in SIGNED) for r, (a, s) in zip(registers, spans, strict=True)]
        if fast:
            return FastSyncReadPacket(start, fields, length, ids)
        return ids, start, length, fields

    def _fast_group_read(self, spec: FastSyncReadPacket, what: str):
        """One try of a fast sync read: ((errors, table), None), or (None, what went wrong).

        The reply is trusted only after ``frame_status`` (header, instruction,
        CRC) and ``FastSyncReadPacket.check`` (id, LEN, each part's id).
        """
        port = self._port
        if self._sdk(what, port.send, spec.request) != len(spec.request):
            return None, self._result_text(_COMM_TX_FAIL)
        # The SDK's timeout for this reply: (11 + data) bytes per servo.
        return self._fast_reply(spec, what, port.timeout_ms((11 + spec.length) * len(spec.ids)))

    def _fast_reply(self, spec: FastSyncReadPacket, what: str, timeout_ms: float):
        """A fast sync read's reply within ``timeout_ms``, checked: as ``_fast_group_read``."""
        result, packet = self._sdk(what, self._port.receive_status, spec.reply_bytes, timeout_ms)
        if result != _COMM_SUCCESS:
            return None, self._result_text(result)
        problem, errors, table = spec.check(packet)
        if problem is not None:
            return None, problem
        return (errors, table), None

    def _group_read(self, spec, what):
        """One try of a sync read (through the SDK): ((errors, table), None), or (None, what
        went wrong).

        Every servo's reply is checked for its id and the block's length in
        data bytes before its data is kept.
        """
        ids, start, length, fields = spec
        ph, port = self._ph, self._port
        result = self._sdk(what, ph.syncReadTx, port, start, length, list(ids), len(ids), False)
        if result != 0:
            return None, self._result_text(result)
        errors, table = [], []
        for servo_id in ids:
            data, result, error = self._sdk(what, ph.readRx, port, servo_id, length)
            problem = self._problem(result, servo_id, length + _STATUS_LENGTH_NO_DATA)
            if problem is not None:
                return None, f"servo {servo_id}: {problem}"
            errors.append(error)
            row = []
            for address, size, signed in fields:
                at = address - start
                value = int.from_bytes(bytes(data[at : at + size]), "little")
                row.append(to_signed(value, size) if signed else value)
            table.append(row)
        return (errors, table), None

    def check_block(self, block: BlockRead, what: str) -> None:
        """Raise ``ServoError`` for the first servo whose ERR byte is non-zero.

        An Alert bit is resolved by reading that servo's Hardware Error Status.
        """
        for servo_id, error in block.errors.items():
            self._check_status(servo_id, error, what)
