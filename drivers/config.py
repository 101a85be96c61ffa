"""The keyframe file's ``[bus]`` table: which port, baud rate and servos.

Keys (all optional)::

    [bus]
    port = "/dev/ttyUSB0"
    baud = 1000000
    ids = [1, 2, 3]            # one per joint of [gimbal] joints (pan, tilt, roll)
    directions = [1, 1, -1]    # +1 or -1 per joint
    zeros = [2048, 2048, 2048] # tick at joint angle 0
    models = "XM430-W350"      # or one per joint; default: [gimbal.<joint>] servo,
                               # else [gimbal] servo, else XM430-W350
    watchdog_s = 0.1           # Bus Watchdog period, 0.02 .. 2.54 s
    configure = false          # let bring-up change EEPROM settings (docs/safety.md)
    restore = false            # write back, on exit, what bring-up changed

The joints are the file's ``[gimbal] joints`` (``trajgen.keyframe_axes``): 2 or 3
of them, in the order of ``[gimbal] axes``; every per-joint list has one entry
per joint, and ``ids`` default to 1, 2(, 3).

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
from trajgen.gimbal_servos import joint_servos
from trajgen.keyframe_axes import axes_from_table
from trajgen.servo_table import DEFAULT_SERVO, servo_spec
from trajgen.validate import check_keys, check_number, check_numbers

from .errors import BadArgument

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
    models : tuple of str, shape (n,)
        Expected servo model per joint (bring-up checks each servo's Model Number).
    watchdog_s : float
        Bus Watchdog period (s).
    configure : bool
        Whether bring-up may change EEPROM settings (Operating Mode, Return
        Delay Time) it needs changed; False: it says what it would change and
        refuses where streaming needs the change.
    restore : bool
        Whether the settings bring-up changed are written back on exit.
    joint_names : tuple of str, shape (n,)
        The joints' names, in the order of ``joints`` (messages, telemetry columns).

    Raises
    ------
    ValueError
        If ``models`` or ``joint_names`` do not have one entry per joint.
    """

    port: str | None = None
    baud: int = DEFAULT_BAUD
    joints: JointMap = field(default_factory=JointMap)
    models: tuple[str, ...] = (DEFAULT_SERVO,) * 3
    watchdog_s: float = 0.1
    configure: bool = False
    restore: bool = False
    joint_names: tuple[str, ...] = JOINT_NAMES

    def __post_init__(self) -> None:
        n = len(self.joints)
        for name in ("models", "joint_names"):
            if len(getattr(self, name)) != n:
                raise BadArgument(
                    f"Expected one of `{name}` per joint ({n}), got {list(getattr(self, name))}."
                )


def _error(path, key: str):
    """A factory for ``KeyframeFileError("{path}: [bus] {key}: {problem}")``."""
    from trajgen.errors import KeyframeFileError

    where = "[bus]" if not key else f"[bus] {key}"
    return lambda problem: KeyframeFileError(f"{path}: {where}: {problem}")


def _per_joint_error(path, key: str, names: tuple[str, ...]):
    """As :func:`_error`, naming the joints the list is for."""
    error = _error(path, key)
    return lambda problem: error(f"{problem} (one per joint: {', '.join(names)})")


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
    names = axes_from_table(tables.get("gimbal", {}), Path(path)).joints
    n = len(names)
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
        table.get("ids", list(range(1, n + 1))),
        n,
        integer=True,
        low=0,
        high=252,
        error=_per_joint_error(path, "ids", names),
    )
    if len(set(ids)) != n:
        raise _error(path, "ids")(f"expected {n} distinct ids, got {list(ids)}")
    directions = check_numbers(
        "directions",
        table.get("directions", [1] * n),
        n,
        integer=True,
        error=_per_joint_error(path, "directions", names),
    )
    if not all(d in (1, -1) for d in directions):
        raise _error(path, "directions")(f"expected +1 or -1 each, got {list(directions)}")
    zeros = check_numbers(
        "zeros",
        table.get("zeros", [ZERO_TICK] * n),
        n,
        integer=True,
        low=0,
        high=4095,
        error=_per_joint_error(path, "zeros", names),
    )
    joints = JointMap(ids, directions, zeros)
    models = table.get("models")
    if models is None:  # the servos the simulator simulates (trajgen.gimbal_servos)
        models = joint_servos(tables.get("gimbal", {}), names, path)
    models = (models,) * n if isinstance(models, str) else models
    if not isinstance(models, (list, tuple)) or len(models) != n:
        raise _error(path, "models")(f"expected a model name or a list of {n}, got {models!r}")
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
    return BusConfig(port, baud, joints, models, watchdog_s, **flags, joint_names=names)


def baud_rates_text() -> str:
    """The supported baud rates, for messages: ``"9600, 57600, ..., 4500000"``."""
    return ", ".join(str(b) for b in BAUD_RATES.values())
