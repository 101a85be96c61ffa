"""The keyframe file's ``[bus]`` table: which port, baud rate and servos.

Keys (all optional)::

    [bus]
    port = "/dev/ttyUSB0"
    baud = 1000000
    ids = [1, 2, 3]            # pan, tilt, roll
    directions = [1, 1, -1]    # +1 or -1 per joint
    zeros = [2048, 2048, 2048] # tick at joint angle 0
    models = "XM430-W350"      # or one per joint; default: [gimbal] servo
    watchdog_s = 0.1           # Bus Watchdog period, 0.02 .. 2.54 s
    configure = false          # let bring-up change EEPROM settings (docs/safety.md)
    restore = false            # write back, on exit, what bring-up changed

Errors are ``trajgen.keyframes.KeyframeFileError`` with a one-line message
``"{path}: [bus] ids: expected ..., got ..."``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from trajgen.drivers.control_table import BAUD_RATES, WATCHDOG_UNIT_S
from trajgen.drivers.defaults import DEFAULT_BAUD
from trajgen.drivers.units import ZERO_TICK, JointMap
from trajgen.gimbal import JOINT_NAMES
from trajgen.servo_table import DEFAULT_SERVO, servo_spec
from trajgen.validate import check_keys, check_number, check_numbers

BUS_KEYS = (
    "port",
    "baud",
    "ids",
    "directions",
    "zeros",
    "models",
    "watchdog_s",
    "configure",
    "restore",
)


@dataclass(frozen=True)
class BusConfig:
    """Bus settings from a keyframe file (command-line flags override them).

    Attributes
    ----------
    port : str or None
        Serial device path.
    baud : int
        Baud rate (bit/s).
    joints : JointMap
        Ids, directions, zeros per joint.
    models : tuple of str, shape (3,)
        Expected servo model per joint.
    watchdog_s : float
        Bus Watchdog period (s).
    configure : bool
        Whether bring-up may change EEPROM settings (Operating Mode, Return
        Delay Time) it needs changed; False: it says what it would change and
        refuses where streaming needs the change.
    restore : bool
        Whether the settings bring-up changed are written back on exit.
    """

    port: str | None = None
    baud: int = DEFAULT_BAUD
    joints: JointMap = field(default_factory=JointMap)
    models: tuple[str, ...] = (DEFAULT_SERVO,) * 3
    watchdog_s: float = 0.1
    configure: bool = False
    restore: bool = False


def _error(path, key: str):
    """A factory for ``KeyframeFileError("{path}: [bus] {key}: {problem}")``."""
    from trajgen.errors import KeyframeFileError

    where = "[bus]" if not key else f"[bus] {key}"
    return lambda problem: KeyframeFileError(f"{path}: {where}: {problem}")


def _default_models(tables: dict) -> tuple[str, ...]:
    servo = tables.get("gimbal", {}).get("servo", DEFAULT_SERVO)
    if isinstance(servo, dict):
        return tuple(servo.get(j, DEFAULT_SERVO) for j in JOINT_NAMES)
    return (servo,) * 3


def bus_config_from_tables(tables: dict, path: str | Path) -> BusConfig:
    """Parse and check the ``[bus]`` table of a keyframe file.

    Parameters
    ----------
    tables : dict
        ``KeyframeFile.tables``.
    path : str or Path
        The file, for messages.

    Returns
    -------
    BusConfig
        Model names canonical (``"xm430-w350"`` becomes ``"XM430-W350"``).

    Raises
    ------
    KeyframeFileError
        If a key is unknown or a value has the wrong type or range; the baud
        rate must be one an X-series servo supports (``BAUD_RATES``).
    """
    table = tables.get("bus", {})
    if not isinstance(table, dict):
        raise _error(path, "")(f"expected a table, got {table!r}")
    check_keys(table, BUS_KEYS, error=_error(path, ""))
    port = table.get("port")
    if port is not None and (not isinstance(port, str) or not port):
        raise _error(path, "port")(f"expected a device path string, got {port!r}")
    baud = check_number(
        "baud", table.get("baud", DEFAULT_BAUD), integer=True, error=_error(path, "baud")
    )
    if baud not in BAUD_RATES.values():
        raise _error(path, "baud")(f"expected one of {baud_rates_text()}, got {baud}")
    ids = check_numbers(
        "ids",
        table.get("ids", [1, 2, 3]),
        3,
        integer=True,
        low=0,
        high=252,
        error=_error(path, "ids"),
    )
    if len(set(ids)) != 3:
        raise _error(path, "ids")(f"expected 3 distinct ids, got {list(ids)}")
    directions = check_numbers(
        "directions",
        table.get("directions", [1, 1, 1]),
        3,
        integer=True,
        error=_error(path, "directions"),
    )
    if not all(d in (1, -1) for d in directions):
        raise _error(path, "directions")(f"expected +1 or -1 each, got {list(directions)}")
    zeros = check_numbers(
        "zeros",
        table.get("zeros", [ZERO_TICK] * 3),
        3,
        integer=True,
        low=0,
        high=4095,
        error=_error(path, "zeros"),
    )
    joints = JointMap(ids, directions, zeros)
    models = table.get("models", _default_models(tables))
    models = (models,) * 3 if isinstance(models, str) else models
    if not isinstance(models, (list, tuple)) or len(models) != 3:
        raise _error(path, "models")(f"expected a model name or a list of 3, got {models!r}")
    try:
        models = tuple(servo_spec(name).name for name in models)
    except (TypeError, ValueError) as e:
        raise _error(path, "models")(str(e)) from None
    watchdog_s = check_number(
        "watchdog_s",
        table.get("watchdog_s", 0.1),
        low=WATCHDOG_UNIT_S,
        high=127 * WATCHDOG_UNIT_S,
        error=_error(path, "watchdog_s"),
    )
    flags = {}
    for key in ("configure", "restore"):
        value = table.get(key, False)
        if not isinstance(value, bool):
            raise _error(path, key)(f"expected true or false, got {value!r}")
        flags[key] = value
    return BusConfig(port, baud, joints, models, watchdog_s, **flags)


def baud_rates_text() -> str:
    """The supported baud rates, for messages: ``"9600, 57600, ..., 4500000"``."""
    return ", ".join(str(b) for b in BAUD_RATES.values())
