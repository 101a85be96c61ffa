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

Errors are ``trajgen.keyframes.KeyframeFileError`` with a one-line message
``"{path}: [bus] ids: expected ..., got ..."``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from trajgen.drivers.control_table import MODELS, WATCHDOG_UNIT_S
from trajgen.drivers.units import ZERO_TICK, JointMap

BUS_KEYS = ("port", "baud", "ids", "directions", "zeros", "models", "watchdog_s")
DEFAULT_MODEL = "XM430-W350"


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
    """

    port: str | None = None
    baud: int = 1_000_000
    joints: JointMap = field(default_factory=JointMap)
    models: tuple[str, ...] = (DEFAULT_MODEL,) * 3
    watchdog_s: float = 0.1


def _error(path, key: str, problem: str):
    from trajgen.keyframes import KeyframeFileError

    where = "[bus]" if not key else f"[bus] {key}"
    return KeyframeFileError(f"{path}: {where}: {problem}")


def _int_list(table: dict, key: str, path, default: tuple[int, ...]) -> tuple[int, ...]:
    value = table.get(key, list(default))
    if (
        not isinstance(value, list)
        or len(value) != 3
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)
    ):
        raise _error(path, key, f"expected a list of 3 integers, got {value!r}")
    return tuple(value)


def _default_models(tables: dict) -> tuple[str, ...]:
    servo = tables.get("gimbal", {}).get("servo", DEFAULT_MODEL)
    if isinstance(servo, str):
        return (servo,) * 3
    if isinstance(servo, dict):
        return tuple(str(servo.get(j, DEFAULT_MODEL)) for j in ("pan", "tilt", "roll"))
    return (DEFAULT_MODEL,) * 3


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

    Raises
    ------
    KeyframeFileError
        If a key is unknown or a value has the wrong type or range.
    """
    table = tables.get("bus", {})
    if not isinstance(table, dict):
        raise _error(path, "", f"expected a table, got {table!r}")
    for key in table:
        if key not in BUS_KEYS:
            raise _error(path, key, f"unknown key (known: {', '.join(BUS_KEYS)})")
    port = table.get("port")
    if port is not None and not isinstance(port, str):
        raise _error(path, "port", f"expected a device path string, got {port!r}")
    baud = table.get("baud", 1_000_000)
    if isinstance(baud, bool) or not isinstance(baud, int) or baud <= 0:
        raise _error(path, "baud", f"expected a positive integer, got {baud!r}")
    ids = _int_list(table, "ids", path, (1, 2, 3))
    directions = _int_list(table, "directions", path, (1, 1, 1))
    zeros = _int_list(table, "zeros", path, (ZERO_TICK,) * 3)
    if len(set(ids)) != 3 or not all(0 <= i <= 252 for i in ids):
        raise _error(path, "ids", f"expected 3 distinct ids in 0..252, got {list(ids)}")
    if not all(d in (1, -1) for d in directions):
        raise _error(path, "directions", f"expected +1 or -1 each, got {list(directions)}")
    joints = JointMap(ids, directions, zeros)
    models = table.get("models", _default_models(tables))
    models = (models,) * 3 if isinstance(models, str) else models
    if not isinstance(models, (list, tuple)) or len(models) != 3:
        raise _error(path, "models", f"expected a model name or a list of 3, got {models!r}")
    for name in models:
        if name not in MODELS:
            raise _error(path, "models", f"unknown model {name!r} (known: {', '.join(MODELS)})")
    watchdog_s = table.get("watchdog_s", 0.1)
    if (
        isinstance(watchdog_s, bool)
        or not isinstance(watchdog_s, (int, float))
        or not WATCHDOG_UNIT_S <= watchdog_s <= 127 * WATCHDOG_UNIT_S
    ):
        raise _error(path, "watchdog_s", f"expected a number in 0.02..2.54, got {watchdog_s!r}")
    return BusConfig(port, baud, joints, tuple(models), float(watchdog_s))
