"""Keyframe files (TOML): orientations at times, spline options, and tables for other packages.

```toml
[spline]            # optional
method = "smooth"   # SmoothSpline (default) or "blending" (BlendingSpline)
boundary = "rest"   # k, local, reparam (and "closed") are the blending spline's;
                    # a file giving them without `method` gets method = "blending"

[stream]            # optional
rate_hz = 200

[[keyframes]]
t = 0.0             # seconds
pan = 0.0           # degrees: q = Rz(pan) Ry(tilt) Rx(roll); each defaults to 0
tilt = 0.0
roll = 0.0

[[keyframes]]
t = 1.5
quat = [1.0, 0.0, 0.0, 0.0]   # (w, x, y, z), instead of pan / tilt / roll
```

Other top-level tables (``[gimbal]`` for the simulator, ``[bus]`` for the
drivers) are kept raw in :attr:`KeyframeFile.tables` for their packages to check.
Keyframes are counted from 1 in messages, as a person reading the file would.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import quat as Q
from .smooth import SmoothSpline
from .spline import BOUNDARIES, LOCALS, REPARAMS, BlendingSpline

#: The built-in example: a gentle pan/tilt look-around.
BUILTIN_EXAMPLE = Path(__file__).with_name("data") / "lookaround.toml"

SPLINE_KEYS = ("method", "k", "boundary", "local", "reparam")
#: ``[spline] method`` -> spline class. The default is chosen by the torque race
#: (README, "The torque race"): the lowest peak torque rate of the rest-to-rest methods.
METHODS = {"smooth": SmoothSpline, "blending": BlendingSpline}
DEFAULT_METHOD = "smooth"
#: Keys only the blending spline takes; a file giving one without ``method`` gets it.
BLENDING_ONLY = ("k", "local", "reparam")
KEYFRAME_KEYS = ("t", "pan", "tilt", "roll", "quat")
#: Top-level tables, and the package that checks each.
TABLES = {
    "spline": "trajgen",
    "keyframes": "trajgen",
    "stream": "trajgen",
    "gimbal": "sim",
    "bus": "drivers",
}


class KeyframeFileError(ValueError):
    """A keyframe file that cannot be used; the message is one line naming file and field."""


@dataclass(frozen=True)
class KeyframeFile:
    """A parsed, validated keyframe file.

    Attributes
    ----------
    path : Path
    times : ndarray, shape (N,)
        Keyframe times (s).
    quats : ndarray, shape (N, 4)
        Keyframe orientations (w, x, y, z).
    spline_options : dict
        Keywords for the spline class (everything in ``[spline]`` but ``method``).
    rate_hz : float or None
        The ``[stream]`` rate, if given.
    tables : dict
        Every other top-level table, as parsed (``tables.get("gimbal", {})``).
    """

    path: Path
    times: np.ndarray
    quats: np.ndarray
    spline_options: dict
    rate_hz: float | None = None
    tables: dict = field(default_factory=dict)
    #: ``[spline] method``: "smooth" or "blending".
    method: str = DEFAULT_METHOD

    def spline(self) -> SmoothSpline | BlendingSpline:
        """The file's spline (already checked to build when the file was loaded)."""
        return METHODS[self.method](self.quats, self.times, **self.spline_options)

    def error(self, where: str, problem: str) -> KeyframeFileError:
        """A :class:`KeyframeFileError` for this file: ``"{path}: {where}: {problem}"``."""
        return KeyframeFileError(f"{self.path}: {where}: {problem}")


def _number(value, where: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise KeyframeFileError(f"{path}: {where}: expected a finite number, got {value!r}")
    return float(value)


def load_keyframe_file(path) -> KeyframeFile:
    """Read and check a keyframe file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    KeyframeFile

    Raises
    ------
    KeyframeFileError
        Missing or unreadable file, invalid TOML, an unknown table or key, a
        missing or mistyped field, times not increasing, or keyframes the spline
        refuses; the message names the file, the keyframe and the field.
    """
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise KeyframeFileError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise KeyframeFileError(f"{path}: cannot read: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise KeyframeFileError(f"{path}: invalid TOML: {e}") from None

    for name in data:
        if name not in TABLES:
            raise KeyframeFileError(f"{path}: unknown table [{name}] (known: {', '.join(TABLES)})")
    options = _spline_options(data.get("spline", {}), path)
    method = options.pop("method", DEFAULT_METHOD)
    rate_hz = _stream_rate(data.get("stream", {}), path)
    times, quats = _keyframes(data.get("keyframes"), path)
    try:
        METHODS[method](quats, times, **options)
    except (ValueError, TypeError) as e:
        raise KeyframeFileError(f"{path}: {e}") from None
    tables = {k: v for k, v in data.items() if TABLES[k] != "trajgen"}
    return KeyframeFile(path, times, quats, options, rate_hz, tables, method)


def _table(value, name: str, path: Path) -> dict:
    if not isinstance(value, dict):
        raise KeyframeFileError(f"{path}: [{name}] must be a table, got {value!r}")
    return value


def _spline_options(table, path: Path) -> dict:
    table = _table(table, "spline", path)
    for key, value in table.items():
        if key not in SPLINE_KEYS:
            raise KeyframeFileError(
                f"{path}: [spline] unknown key '{key}' (known: {', '.join(SPLINE_KEYS)})"
            )
        if key == "k" and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise KeyframeFileError(f"{path}: [spline] k: expected an integer >= 1, got {value!r}")
        allowed = {
            "method": tuple(METHODS),
            "boundary": BOUNDARIES,
            "local": LOCALS,
            "reparam": REPARAMS,
        }.get(key)
        if allowed and value not in allowed:
            raise KeyframeFileError(
                f"{path}: [spline] {key}: expected one of {', '.join(allowed)}, got {value!r}"
            )
    blending_only = [k for k in BLENDING_ONLY if k in table]
    if table.get("boundary") == "closed":
        blending_only.append("boundary = 'closed'")
    if blending_only and table.get("method") == "smooth":
        raise KeyframeFileError(
            f"{path}: [spline] {blending_only[0]}: applies to method = 'blending' only"
        )
    if blending_only and "method" not in table:  # a file written for the blending spline
        table = {"method": "blending", **table}
    return dict(table)


def _stream_rate(table, path: Path) -> float | None:
    table = _table(table, "stream", path)
    for key in table:
        if key != "rate_hz":
            raise KeyframeFileError(f"{path}: [stream] unknown key '{key}' (known: rate_hz)")
    if "rate_hz" not in table:
        return None
    rate = _number(table["rate_hz"], "[stream] rate_hz", path)
    if rate <= 0:
        raise KeyframeFileError(f"{path}: [stream] rate_hz: expected > 0, got {rate:g}")
    return rate


def _keyframes(entries, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if entries is None:
        raise KeyframeFileError(f"{path}: no [[keyframes]] (at least 2 are needed)")
    if not isinstance(entries, list) or len(entries) < 2:
        count = len(entries) if isinstance(entries, list) else "not a list of tables"
        raise KeyframeFileError(f"{path}: [[keyframes]]: at least 2 are needed, got {count}")
    times, quats = [], []
    for i, kf in enumerate(entries, start=1):
        where = f"keyframe {i}"
        if not isinstance(kf, dict):
            raise KeyframeFileError(f"{path}: {where}: expected a table, got {kf!r}")
        for key in kf:
            if key not in KEYFRAME_KEYS:
                raise KeyframeFileError(
                    f"{path}: {where}: unknown field '{key}' (known: {', '.join(KEYFRAME_KEYS)})"
                )
        if "t" not in kf:
            raise KeyframeFileError(f"{path}: {where}: field 't' is missing (seconds)")
        t = _number(kf["t"], f"{where}: field 't'", path)
        if times and t <= times[-1]:
            raise KeyframeFileError(
                f"{path}: {where}: field 't': {t:g} s is not after keyframe {i - 1}'s "
                f"{times[-1]:g} s"
            )
        angles = [k for k in ("pan", "tilt", "roll") if k in kf]
        if "quat" in kf:
            if angles:
                raise KeyframeFileError(
                    f"{path}: {where}: give either 'quat' or pan/tilt/roll, not both"
                )
            q = kf["quat"]
            if not isinstance(q, list) or len(q) != 4:
                raise KeyframeFileError(
                    f"{path}: {where}: field 'quat': expected [w, x, y, z], got {q!r}"
                )
            q = np.array([_number(x, f"{where}: field 'quat'", path) for x in q])
            if np.linalg.norm(q) < 1e-12:
                raise KeyframeFileError(f"{path}: {where}: field 'quat': zero quaternion")
        elif angles:
            pan, tilt, roll = (
                math.radians(_number(kf.get(k, 0.0), f"{where}: field '{k}'", path))
                for k in ("pan", "tilt", "roll")
            )
            q = Q.from_pan_tilt_roll(pan, tilt, roll)
        else:
            raise KeyframeFileError(
                f"{path}: {where}: no orientation: give 'quat' or pan/tilt/roll (degrees)"
            )
        times.append(t)
        quats.append(q)
    return np.array(times), Q.as_quats(np.array(quats))
