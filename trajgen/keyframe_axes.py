"""Keyframe files for gimbals other than pan-tilt-roll: ``[gimbal] axes`` and ``joints``.

```toml
[gimbal]
axes = "zy"                 # any 2 or 3 of x, y, z (trajgen.axes); default "zyx"
joints = ["pan", "tilt"]    # optional names, one per axis

[[keyframes]]
t = 0.0
pan = 30.0                  # degrees, by joint name; each defaults to 0
tilt = -10.0

[[keyframes]]
t = 2.0
look = [1.0, 1.0, -0.2]     # two axes: where the camera looks (any length > 0)
```

A three-axis gimbal's keyframe may give ``quat = [w, x, y, z]`` instead of angles; a
two-axis gimbal cannot hold every orientation, so its keyframes give joint angles or a
look direction, never a quaternion. Each keyframe becomes the orientation the
gimbal has there (for two axes: the one pointing its look axis along ``look``,
exactly), and the file is then checked as any other
(:func:`trajgen.keyframes.load_keyframe_file`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .axes import AxisSequence, direction_angles
from .errors import BadArgument, KeyframeFileError
from .validate import check_keys, check_number

#: The ``[gimbal]`` keys read here (the simulator reads the rest of the table).
AXES_KEYS = ("axes", "joints")


def axes_from_table(table, path: Path) -> AxisSequence:
    """The ``[gimbal]`` table's ``axes`` and ``joints``, checked (default pan-tilt-roll).

    Raises
    ------
    KeyframeFileError
        ``"{path}: [gimbal] axes: ..."`` or ``"... joints: ..."`` naming the problem.
    """
    if not isinstance(table, dict):
        return AxisSequence()  # the simulator's check names a [gimbal] that is not a table
    axes = table.get("axes", "zyx")
    joints = table.get("joints")
    if joints is not None and not isinstance(joints, list):
        raise KeyframeFileError(
            f"{path}: [gimbal] joints: expected a list of names, got {joints!r}"
        )
    try:
        return AxisSequence(axes, None if joints is None else tuple(joints))
    except (BadArgument, TypeError) as e:
        key = "axes" if "`axes`" in str(e) else "joints"
        raise KeyframeFileError(f"{path}: [gimbal] {key}: {e}") from None


def is_default(seq: AxisSequence) -> bool:
    """Whether ``seq`` is today's pan-tilt-roll with its own joint names."""
    return seq == AxisSequence()


def axis_keyframes(entries, seq: AxisSequence, path: Path):
    """``[[keyframes]]`` by joint name (or ``look``) as ``{"t", "quat"}`` tables.

    Parameters
    ----------
    entries : list of dict or None
        The parsed ``[[keyframes]]``; anything but a list is passed through for
        the keyframe checks to refuse.
    seq : AxisSequence
        The gimbal's axes and joint names.
    path : Path
        For messages.

    Returns
    -------
    list of dict
        One table per keyframe: ``t`` as given and ``quat``, the gimbal's
        orientation there; or ``entries`` unchanged if not a list of tables.

    Raises
    ------
    KeyframeFileError
        An unknown field (naming it and the known ones), a number that is not one,
        a ``look`` that is not 3 numbers or is zero, a ``quat`` on a two-axis
        gimbal, or both angles and an orientation in one keyframe.
    """
    if not isinstance(entries, list):
        return entries
    orientation = "look" if seq.n == 2 else "quat"
    known = ("t", *seq.joints, orientation)
    out = []
    for i, kf in enumerate(entries):
        where = f"{path}: keyframe {i + 1}"
        if not isinstance(kf, dict):
            return entries  # refused, with its message, by the keyframe checks
        if seq.n == 2 and "quat" in kf:
            raise KeyframeFileError(
                f"{where}: field 'quat': a 2-axis gimbal ({seq.sequence}) cannot hold every "
                f"orientation; give 'look' = [x, y, z] or {'/'.join(seq.joints)} (degrees)"
            )
        check_keys(kf, known, error=lambda m, w=where: KeyframeFileError(f"{w}: {m}"), kind="field")
        angles = [k for k in seq.joints if k in kf]
        if angles and orientation in kf:
            raise KeyframeFileError(
                f"{where}: give either '{orientation}' or {'/'.join(seq.joints)}, not both"
            )
        entry = {k: kf[k] for k in ("t",) if k in kf}
        if orientation == "quat" and "quat" in kf:
            entry["quat"] = kf["quat"]
        elif orientation == "look" and "look" in kf:
            entry["quat"] = _look_quat(kf["look"], seq, where).tolist()
        elif not angles:
            raise KeyframeFileError(
                f"{where}: no orientation: give '{orientation}' or {'/'.join(seq.joints)} (degrees)"
            )
        else:
            deg = [check_number(k, kf.get(k, 0.0), error=_field(where, k)) for k in seq.joints]
            entry["quat"] = seq.forward(np.radians(deg)).tolist()
        out.append(entry)
    return out


def written_angles(entries: list, seq: AxisSequence) -> tuple[np.ndarray, np.ndarray]:
    """The joint angles keyframes (checked by :func:`axis_keyframes`) give by name.

    Returns
    -------
    written : ndarray, shape (N, n)
        Degrees as written, 0 for a joint not given and for a keyframe by ``look`` or
        ``quat``.
    has_angle : ndarray of bool, shape (N,)
        Keyframes given by joint angles.
    """
    has_angle = np.array([any(k in kf for k in seq.joints) for kf in entries], dtype=bool)
    written = np.array(
        [[float(kf.get(k, 0.0)) if has else 0.0 for k in seq.joints]
         for kf, has in zip(entries, has_angle, strict=True)]
    )  # fmt: skip
    return written.reshape(len(entries), seq.n), has_angle


def _field(where: str, key: str):
    return lambda problem: KeyframeFileError(f"{where}: field '{key}': {problem}")


def _look_quat(value, seq: AxisSequence, where: str) -> np.ndarray:
    """The orientation (4,) of a two-axis gimbal pointing along ``value`` ([x, y, z])."""
    error = _field(where, "look")
    if not isinstance(value, list) or len(value) != 3:
        raise error(f"expected [x, y, z], got {value!r}")
    d = np.array([check_number("look", x, error=error) for x in value])
    norm = float(np.linalg.norm(d))
    if not norm > 1e-12 or not math.isfinite(norm):
        raise error(f"expected a non-zero direction, got {value!r}")
    return seq.forward(direction_angles(seq.indices, d / norm))
