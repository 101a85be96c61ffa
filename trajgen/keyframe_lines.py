"""Keyframes as JSON lines: read with a length cap, parsed, checked.

One keyframe per line, as a tracker writes them to ``trajgen follow``::

    {"in": 0.8, "pan": 20, "tilt": 5}          reach this 0.8 s from now
    {"t": 12.5, "quat": [1, 0, 0, 0]}          ... at stream time 12.5 s
    {"in": 1, "pan": -10, "mode": "extend"}    after the keyframes still planned
    {"pan": 20, "tilt": 5, "max_speed": 90}    as early as the limits allow (untimed)
    {"look_at": [2.0, 0.5, -0.3]}              point the camera there (m), untimed

A gimbal of other axes (``[gimbal] axes``, :mod:`trajgen.keyframe_axes`) takes its
own joint names (``{"in": 1, "wrist_flex": 30}``); a two-axis one also ``"look"`` (a
direction) and ``"quat"``, of which only the look direction is kept (exactly: the
orientation planned through is the one the gimbal has pointing there).

:func:`capped_lines` reads lines as bytes and never holds more than
``MAX_LINE_BYTES`` of one (a 50 MB line or binary noise costs memory and time
in bounded pieces); :func:`parse_line` refuses, with a message naming the line
and the field, anything that is not a keyframe.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator

import numpy as np

from . import quat as Q
from .axes import AxisSequence, direction_angles
from .errors import KeyframeFileError
from .keyframe_axes import axis_keyframes, is_default
from .keyframes import check_keyframes
from .online import MODES
from .validate import check_keys, check_number

#: Longest line (bytes, newline included) parsed; a longer one is refused unread past
#: this. A keyframe line is under 200 bytes.
MAX_LINE_BYTES = 64 * 1024

#: Longest message (characters) about a refused line: what arrived is cut to fit.
MAX_MESSAGE_CHARS = 200

#: The fields a line may have.
LINE_KEYS = ("t", "in", "mode", "pan", "tilt", "roll", "quat", "look_at", "max_speed")


def line_keys(axes: AxisSequence | None = None) -> tuple[str, ...]:
    """The fields a line may have for a gimbal of ``axes`` (default pan-tilt-roll):
    :data:`LINE_KEYS` with the gimbal's joint names, and ``look`` for two axes."""
    if axes is None or is_default(axes):
        return LINE_KEYS
    look = ("look",) if axes.n == 2 else ()
    return ("t", "in", "mode", *axes.joints, "quat", *look, "look_at", "max_speed")


#: Fields only an untimed target (no ``t``, no ``in``) may have.
TARGET_KEYS = ("look_at", "max_speed")

#: ``mode`` of an untimed target, for :class:`trajgen.tracker.Tracker`.
TRACK = "track"


def capped_lines(file, max_bytes: int = MAX_LINE_BYTES) -> Iterator[bytes | str]:
    """The lines of ``file``, each cut at ``max_bytes + 1`` (the rest of a longer line
    is read and dropped in pieces of ``max_bytes``).

    Parameters
    ----------
    file : binary (or text) file
        Anything with ``readline(limit)``, e.g. ``sys.stdin.buffer``.
    max_bytes : int, optional
        Longest line kept whole.

    Yields
    ------
    bytes or str
        One per line, as ``file`` returns them; a line longer than ``max_bytes``
        comes as its first ``max_bytes + 1`` bytes (see :func:`decode_line`).
    """
    while True:
        line = file.readline(max_bytes + 1)
        if not line:
            return
        if len(line) > max_bytes and line[-1:] not in (b"\n", "\n"):
            while True:  # drop the rest of the line, a bounded piece at a time
                rest = file.readline(max_bytes)
                if not rest or rest[-1:] in (b"\n", "\n"):
                    break
        yield line


def decode_line(line: bytes | str, where: str, max_bytes: int = MAX_LINE_BYTES) -> str:
    """A line as text.

    Raises
    ------
    KeyframeFileError
        ``"{where}: longer than N bytes"`` or ``"{where}: not UTF-8 text ..."``.
    """
    if len(line) > max_bytes:
        raise KeyframeFileError(f"{where}: longer than {max_bytes} bytes; a keyframe line is short")
    if isinstance(line, str):
        return line
    try:
        return line.decode("utf-8")
    except UnicodeDecodeError as e:
        raise KeyframeFileError(
            f"{where}: not UTF-8 text (byte {line[e.start]:#04x} at column {e.start + 1})"
        ) from None


def parse_line(text: str, where: str, axes: AxisSequence | None = None):
    """One JSON line as a checked keyframe.

    Parameters
    ----------
    text : str
        The line.
    where : str
        What messages start with, e.g. ``"stdin: line 7"``.
    axes : AxisSequence, optional
        The gimbal's axes and joint names (default pan-tilt-roll): the angle fields.

    Returns
    -------
    mode : {"retarget", "extend", "track"}
        "track" for an untimed target (neither ``t`` nor ``in``).
    quat : ndarray, shape (4,), or dict
        Unit quaternion (w, x, y, z); for "track" a dict with ``quat`` (4,) or
        ``look_at`` (3,) (m), the other None, and ``max_speed`` (rad/s) or None.
    t : float or None
        Keyframe time (s): stream time, or from now when ``relative``; None for "track".
    relative : bool
        Whether the line gave ``"in"`` (from now) rather than ``"t"``.

    Raises
    ------
    KeyframeFileError
        ``"{where}: ..."``, naming the field that is wrong.
    """

    try:
        return _parse(text, where, AxisSequence() if axes is None else axes)
    except KeyframeFileError as e:
        # One keyframe a line: "keyframe 1" says nothing; a value 60 KB long is cut.
        message = str(e).replace(f"{where}: keyframe 1: ", f"{where}: ", 1)
        if len(message) > MAX_MESSAGE_CHARS:
            message = f"{message[: MAX_MESSAGE_CHARS - 5]}[...] ({len(message)} characters)"
        raise KeyframeFileError(message) from None


def _parse(text: str, where: str, axes: AxisSequence):
    def error(problem: str) -> KeyframeFileError:
        return KeyframeFileError(f"{where}: {problem}")

    try:
        entry = json.loads(text)
    except json.JSONDecodeError as e:
        raise error(f"invalid JSON: {e}") from None
    except RecursionError:
        raise error("invalid JSON: nested too deeply") from None
    except ValueError as e:  # an integer of more digits than Python converts
        raise error(f"invalid JSON: {e}") from None
    if not isinstance(entry, dict):
        raise error(f"expected a JSON object, got {text.strip()[:80]!r}")
    check_keys(entry, line_keys(axes), error=error, kind="field")
    if "t" not in entry and "in" not in entry:
        return _target(entry, where, error, axes)
    for key in TARGET_KEYS:
        if key in entry:
            raise error(f"field '{key}': only for a target without 't' or 'in'")
    mode = entry.get("mode", "retarget")
    if mode not in MODES:
        raise error(f"field 'mode': expected one of {MODES}, got {mode!r}")
    if ("t" in entry) == ("in" in entry):
        raise error("give exactly one of 't' (stream time) or 'in' (from now), s")
    name = "in" if "in" in entry else "t"
    t = check_number(name, entry[name], error=lambda p: error(f"field '{name}': {p} (seconds)"))
    keyframe = {k: v for k, v in entry.items() if k not in ("mode", "in")}
    keyframe["t"] = t
    return mode, _orientation(keyframe, where, axes), t, name == "in"


def _orientation(keyframe: dict, where: str, axes: AxisSequence):
    """The checked orientation (4,) a line's ``keyframe`` fields (``t`` among them) give:
    for a two-axis gimbal's ``quat``, the orientation pointing its look axis where the
    quaternion's points (:func:`trajgen.axes.direction_angles`, exact)."""
    two_axis_quat = axes.n == 2 and "quat" in keyframe
    if two_axis_quat and len(keyframe) > 2:
        raise KeyframeFileError(f"{where}: give either 'quat' or {'/'.join(axes.joints)}, not both")
    if not is_default(axes) and not two_axis_quat:
        keyframe = axis_keyframes([keyframe], axes, where)[0]
    _, q = check_keyframes([keyframe], where, minimum=1)
    if two_axis_quat:
        look = Q.rotate(q[0], axes.look)
        return axes.forward(direction_angles(axes.indices, look / np.linalg.norm(look)))
    return q[0]


def _target(entry: dict, where: str, error, axes: AxisSequence):
    """An untimed target line: ("track", {quat, look_at, max_speed}, None, False)."""
    if "mode" in entry:
        raise error("field 'mode': a target without 't' or 'in' is always tracked")
    target = {"quat": None, "look_at": None, "max_speed": None}
    if "max_speed" in entry:
        speed = check_number(
            "max_speed",
            entry["max_speed"],
            low=0.0,
            low_open=True,
            error=lambda p: error(f"field 'max_speed': {p} (deg/s)"),
        )
        target["max_speed"] = math.radians(speed)
    orientation = {k: v for k, v in entry.items() if k not in TARGET_KEYS}
    if "look_at" in entry:
        if axes.n == 3 and not is_default(axes):
            raise error(
                f"field 'look_at': a camera's look axis is defined for pan-tilt-roll and "
                f"two-axis gimbals, not axes {axes.sequence!r}; give 'quat' or "
                f"{'/'.join(axes.joints)}"
            )
        if orientation:
            raise error(f"field 'look_at': give it or {sorted(orientation)[0]!r}, not both")
        p = entry["look_at"]
        if not isinstance(p, list) or len(p) != 3:
            raise error(f"field 'look_at': expected [x, y, z] (m), got {json.dumps(p)[:80]}")
        target["look_at"] = [
            check_number("look_at", v, error=lambda m: error(f"field 'look_at': {m} (m)"))
            for v in p
        ]
        if not any(target["look_at"]):
            raise error("field 'look_at': the gimbal's origin has no direction")
        return TRACK, target, None, False
    if not orientation:
        angles = "'" + "'/'".join(axes.joints) + "'"
        raise error(f"give 't' or 'in' (s), or a target: {angles}, 'quat' or 'look_at'")
    target["quat"] = _orientation({**orientation, "t": 0.0}, where, axes)
    return TRACK, target, None, False
