"""Which servo model drives each joint: the keyframe file's ``[gimbal]`` keys, read once.

```toml
[gimbal]
joints = ["pan", "tilt"]
servo = "XL330-M288"               # every joint; or a table by joint:
# servo = {pan = "XC330-M288", tilt = "XL330-M077"}
[gimbal.tilt]
servo = "XL330-M077"               # [gimbal.<joint>] servo wins over [gimbal] servo
```

A joint no key names gets :data:`trajgen.servo_table.DEFAULT_SERVO`. The simulator
(``trajgen.sim.model``: the servos it simulates) and the drivers (``[bus] models``'
default: the servos bring-up expects) both read the choice here, so the bus expects
the servos the simulator checked the plan on.
"""

from __future__ import annotations

from pathlib import Path

from .errors import KeyframeFileError
from .servo_table import DEFAULT_SERVO, servo_spec
from .validate import check_keys


def joint_servos(table, joints, path) -> tuple[str, ...]:
    """The servo model of each joint, by the ``[gimbal]`` table's keys.

    Parameters
    ----------
    table : dict
        The ``[gimbal]`` table (anything else: every joint the default servo).
    joints : sequence of str
        The gimbal's joint names, base out (``[gimbal] joints``).
    path : str or Path
        The keyframe file, for messages.

    Returns
    -------
    tuple of str
        One canonical model name (``trajgen.servo_table.SERVOS``) per joint.

    Raises
    ------
    KeyframeFileError
        ``"{path}: [gimbal] servo: unknown model 'XM999' (known: ...)"``, likewise for
        ``[gimbal] servo.<joint>`` and ``[gimbal.<joint>] servo``; a ``[gimbal] servo``
        that is neither a name nor a table by joint, or whose table names another joint.
    """
    table = table if isinstance(table, dict) else {}
    servo = table.get("servo", DEFAULT_SERVO)
    if isinstance(servo, dict):
        check_keys(
            servo, tuple(joints), error=_error(path, "[gimbal] servo"), kind="joint"
        )  # fmt: skip
    elif not isinstance(servo, str):
        raise _error(path, "[gimbal] servo")(
            f"expected a model name or a table per joint, got {servo!r}"
        )
    names = []
    for joint in joints:
        own = table.get(joint)
        if isinstance(own, dict) and "servo" in own:
            names.append(_model(own["servo"], f"[gimbal.{joint}] servo", path))
        elif isinstance(servo, dict):
            names.append(_model(servo.get(joint, DEFAULT_SERVO), f"[gimbal] servo.{joint}", path))
        else:
            names.append(_model(servo, "[gimbal] servo", path))
    return tuple(names)


def _model(name, where: str, path) -> str:
    """The canonical name of model ``name`` (any case, blanks around it)."""
    if not isinstance(name, str):
        raise _error(path, where)(f"expected a model name, got {name!r}")
    try:
        return servo_spec(name).name
    except ValueError as e:
        raise _error(path, where)(str(e)) from None


def _error(path, where: str):
    return lambda problem: KeyframeFileError(f"{Path(path)}: {where}: {problem}")
