"""The MJCF gimbal (2 or 3 joints, any axis sequence) and its configuration.

Layout (zero pose, world frame, z up), for axes ``a1 a2 [a3]`` (``trajgen.axes``;
the default ``"zyx"`` is pan-tilt-roll): the first servo stands on the base with
its horn along ``a1``, 50 mm up; the first link carries a U bracket (a plate
across ``a1``, two side plates across ``a2``) and the second servo (horn along
``a2``), whose axis is 70 mm along ``a1`` from the first horn; with three axes
the second link carries the third servo behind the camera (horn along ``a3``)
and the third axis passes through the same point. The last link carries the
camera, which looks along its look axis (body x for three axes,
``AxisSequence.look`` for two). The last two axes meet, so the last link's
orientation is ``R_a1 R_a2 [R_a3]`` of the joint angles, as
``trajgen.gimbal.GimbalKinematics`` has it; for ``"zyx"`` that is
``Rz(pan) Ry(tilt) Rx(roll)`` (``trajgen.quat.from_pan_tilt_roll``). Brackets
and the offsets between axes scale with the housing width of the servo they
hold (relative to the XM430 the 25 g brackets were drawn for); ``"zyx"`` on
three XM430-W350 is today's gimbal, bit for bit.

Instead of this built-in chain the ``[gimbal]`` table may name the user's own
model (``model = "my_gimbal.xml"`` or ``.urdf``; ``sim.user_model``): its masses
and inertias are used, the servos are attached to its hinge joints.

Masses and inertias: servos are uniform boxes of their datasheet size and mass
(``sim.servos``); brackets are 2 mm aluminium plates (about 25 g each, an
estimate close to ROBOTIS FR12 brackets); the camera is a uniform 60 x 40 x 40 mm
box of ``payload_kg``. Each joint's reflected rotor inertia (``armature``, about
0.045 kg m^2 for an XM430) dwarfs the links (below 1e-3 kg m^2 about any axis).

Each joint is driven by a ``<dcmotor>`` at its servo's rated voltage
(``nominal = "volts stall no_load"`` from ``trajgen.servo_table``,
so the compiler derives the motor constant and resistance from the ratings)
whose on-board controller is the servo firmware's position loop on the goal
position alone (``input="pos"``, gains from the Position P/I/D Gain registers,
drive capped at the PWM Limit; see ``sim.firmware``). At full drive the
delivered torque obeys the torque-speed envelope ``tau <= tau_stall (1 - |w| / w0)``
exactly. Braking against the motion, where a voltage-limited motor could exceed
its stall torque, the torque is clamped at the stall torque (``saturation``),
standing in for the servo's current limit.

Each joint's ``armature``, ``frictionloss``, ``damping`` and P gain default to
its servo's (``sim.servos``) and can be set per joint (:class:`JointParams`,
the keyframe file's ``[gimbal.pan]`` etc.), e.g. to values fitted by
``trajgen identify``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from trajgen.axes import AxisSequence
from trajgen.errors import KeyframeFileError
from trajgen.gimbal_servos import joint_servos
from trajgen.keyframe_axes import axes_from_table, is_default
from trajgen.servo_table import GAIN_MAX
from trajgen.sim.firmware import P_DIVISOR, PositionLoop
from trajgen.sim.servos import DEFAULT_SERVO, ServoModel, servo_by_name
from trajgen.validate import check_keys, check_number, check_numbers

from .errors import BadArgument

GIMBAL_TABLE_KEYS = (
    "servo",
    "payload_kg",
    "payload_offset_m",
    "torque_margin",
    "max_tracking_error_rad",
    "p_divisor",
    "axes",  # read by trajgen.keyframe_axes
    "joints",
    "model",
)
#: Keys of a ``[gimbal.<joint>]`` table.
JOINT_TABLE_KEYS = ("armature", "frictionloss", "damping", "position_p_gain", "p_divisor")

_PAN_HEIGHT_M = 0.05  # pan horn above the base plate
_TILT_HEIGHT_M = 0.07  # tilt (and roll) axis above the pan horn
_BRACKET_KG = 0.025
_CAMERA_SIZE_M = (0.06, 0.04, 0.04)  # along the look axis, then across it
_BRACKET_SERVO = "XM430-W350"  # the servo the brackets and offsets above were drawn for


@dataclass(frozen=True)
class JointParams:
    """One joint's physical parameters and position-loop gains.

    Parameters
    ----------
    armature : float
        Reflected rotor inertia (kg m^2), > 0.
    frictionloss : float
        Coulomb friction (N m), >= 0.
    damping : float
        Viscous friction (N m s/rad), >= 0, besides the motor's back-EMF.
    position_p_gain, position_i_gain, position_d_gain : int
        Position P / I / D Gain registers (register units, as on the servo), 0..16383.
    p_divisor : float or None
        This servo's P scale, ``KP = P / p_divisor`` (> 0), e.g. fitted by
        ``trajgen identify --p-scale``; None: the gimbal's ``p_divisor``.

    Raises
    ------
    TypeError, ValueError
        If a field has the wrong type or is out of range.
    """

    armature: float
    frictionloss: float
    damping: float
    position_p_gain: int
    position_i_gain: int = 0
    position_d_gain: int = 0
    p_divisor: float | None = None

    def __post_init__(self):
        for name, bounds in _JOINT_BOUNDS.items():
            if name == "p_divisor" and self.p_divisor is None:
                continue
            object.__setattr__(self, name, check_number(name, getattr(self, name), **bounds))

    @classmethod
    def of(cls, servo: ServoModel, **overrides) -> JointParams:
        """The servo's defaults (``sim.servos``) with ``overrides`` applied."""
        params = cls(
            armature=servo.armature,
            frictionloss=servo.frictionloss,
            damping=servo.damping,
            position_p_gain=servo.position_p_gain,
            position_i_gain=servo.position_i_gain,
            position_d_gain=servo.position_d_gain,
        )
        return replace(params, **overrides)


#: Ranges of JointParams' fields, shared by the class and the [gimbal.<joint>] tables.
_JOINT_BOUNDS = {
    "armature": {"low": 0.0, "low_open": True},
    "frictionloss": {"low": 0.0},
    "damping": {"low": 0.0},
    **{f"position_{g}_gain": {"low": 0, "high": GAIN_MAX, "integer": True} for g in "pid"},
    "p_divisor": {"low": 0.0, "low_open": True},
}


@dataclass(frozen=True)
class GimbalConfig:
    """What the simulated gimbal is made of and how it is checked.

    Parameters
    ----------
    servos : ServoModel or str, or a tuple of one per joint
        Servo per joint (base out); names are looked up in
        ``sim.servos.SERVOS``. One model means that model on every joint.
        Default XM430-W350 on every joint.
    payload_kg : float
        Camera mass (kg), >= 0. Default 0.15.
    payload_offset_m : tuple of 3 float, optional
        Camera centre of mass in the last link's frame (m), where the last axes
        meet at the origin. Default 30 mm along the look axis (``(0.03, 0, 0)``
        for three axes, whose camera looks along +x).
    torque_margin : float
        Fraction of the torque-speed envelope the planned torque may use, in
        (0, 1]. Default 0.8.
    max_tracking_error_rad : float
        Largest simulated deviation from the planned path (rad) that passes.
        Default 0.05 (about 3 degrees). With default gains (P 800) an X-series
        servo lags a moving goal by about speed x 45 ms, so this holds up to
        about 1.1 rad/s (``sim.check.lag_time_s``).
    timestep_s : float
        Physics time step (s), in (0, 0.001]. Default 0.001.
    joints : tuple of JointParams or dict, optional
        Per-joint parameters, one per joint; a dict gives overrides of the
        servo's defaults (``JointParams.of``). Default: each servo's defaults.
    p_divisor : float
        ``KP = P / p_divisor`` in the firmware loop: 128 per the e-Manual (BAM
        measured 256 on an XL330; see ``sim.firmware``).
    axes : AxisSequence or str
        The joints' axis sequence and names (``trajgen.axes``); default
        ``"zyx"``, pan-tilt-roll.
    model : str or Path, optional
        The user's own MJCF (``.xml``) or URDF (``.urdf``) file, whose hinge
        joints named by ``axes.joints`` the servos drive (``sim.user_model``);
        default None, the built-in chain (:func:`gimbal_mjcf`). ``payload_kg``
        and ``payload_offset_m`` do not apply to it.

    Raises
    ------
    TypeError
        If a field has the wrong type.
    ValueError
        If a field is out of range, a servo name is unknown, or ``servos`` /
        ``joints`` do not hold one entry per joint.
    """

    servos: tuple | str | ServoModel = DEFAULT_SERVO
    payload_kg: float = 0.15
    payload_offset_m: tuple | None = None
    torque_margin: float = 0.8
    max_tracking_error_rad: float = 0.05
    timestep_s: float = 0.001
    joints: tuple | None = None
    p_divisor: float = P_DIVISOR
    axes: AxisSequence | str = AxisSequence()
    model: Path | None = None

    def __post_init__(self):
        axes = self.axes if isinstance(self.axes, AxisSequence) else AxisSequence(self.axes)
        object.__setattr__(self, "axes", axes)
        n, names = axes.n, ", ".join(axes.joints)
        servos = self.servos
        if isinstance(servos, (str, ServoModel)):
            servos = (servos,) * n
        if not isinstance(servos, (tuple, list)) or len(servos) != n:
            raise BadArgument(f"Expected `servos` to hold {n} servos ({names}), got {servos!r}.")
        resolved = tuple(s if isinstance(s, ServoModel) else servo_by_name(s) for s in servos)
        object.__setattr__(self, "servos", resolved)
        for name, bounds in _FIELD_BOUNDS.items():
            object.__setattr__(self, name, check_number(name, getattr(self, name), **bounds))
        offset = self.payload_offset_m
        if offset is None:
            offset = tuple(0.03 * float(v) for v in axes.look)
        offset = check_numbers("payload_offset_m", offset, 3, **_OFFSET_BOUNDS)
        object.__setattr__(self, "payload_offset_m", offset)
        if self.model is not None:
            object.__setattr__(self, "model", Path(self.model))
        joints = ({},) * n if self.joints is None else self.joints
        if not isinstance(joints, (tuple, list)) or len(joints) != n:
            raise BadArgument(f"Expected `joints` to hold {n} entries ({names}), got {joints!r}.")
        resolved = []
        for servo, joint in zip(self.servos, joints, strict=True):
            if isinstance(joint, dict):
                joint = JointParams.of(servo, **joint)
            elif not isinstance(joint, JointParams):
                raise TypeError(
                    f"Expected `joints` entries to be JointParams or dicts, got {joint!r}."
                )
            resolved.append(joint)
        object.__setattr__(self, "joints", tuple(resolved))

    @property
    def names(self) -> tuple[str, ...]:
        """Joint names, base out (``axes.joints``), e.g. ``("pan", "tilt", "roll")``."""
        return self.axes.joints

    @property
    def n_joints(self) -> int:
        """Number of joints, 2 or 3."""
        return self.axes.n

    def kinematics(self, **kwargs):
        """The gimbal's ``trajgen.gimbal.GimbalKinematics`` (its axes and joint names);
        ``kwargs`` (``limits_rad``, ``lock_margin_rad``) are passed on."""
        from trajgen.gimbal import GimbalKinematics

        return GimbalKinematics(axes=self.axes.sequence, joints=self.axes.joints, **kwargs)

    def loop(self, joint: int) -> PositionLoop:
        """Joint ``joint``'s position loop with its configured gains (full PWM)."""
        params = self.joints[joint]
        return PositionLoop(
            params.position_p_gain,
            params.position_i_gain,
            params.position_d_gain,
            p_divisor=self.p_divisor if params.p_divisor is None else params.p_divisor,
        )


#: Ranges of GimbalConfig's number fields, shared by the class and the [gimbal] table.
_FIELD_BOUNDS = {
    # a payload over 100 kg is a slip of the keyboard (1e300 overflows MuJoCo's inertia)
    "payload_kg": {"low": 0.0, "high": 100.0},
    "torque_margin": {"low": 0.0, "high": 1.0, "low_open": True},
    "max_tracking_error_rad": {"low": 0.0, "low_open": True},
    "timestep_s": {"low": 0.0, "high": 0.001, "low_open": True},
    "p_divisor": {"low": 0.0, "low_open": True},
}
#: Range of each coordinate of ``payload_offset_m`` (m): a payload beyond a metre from the
#: roll axis is a slip of the keyboard (1e300 overflows MuJoCo's inertia), not a gimbal.
_OFFSET_BOUNDS = {"low": -1.0, "high": 1.0}


def gimbal_config_from_tables(tables: dict, path, *, any_axes: bool = False) -> GimbalConfig:
    """Build a :class:`GimbalConfig` from a keyframe file's ``[gimbal]`` table.

    Keys (all optional): ``axes`` and ``joints`` (``trajgen.keyframe_axes``;
    default pan-tilt-roll), ``servo`` (a model name for every joint, or a table
    ``{pan = "...", tilt = "..."}`` by joint name where missing joints take the
    default XM430-W350), ``model`` (the user's MJCF or URDF file, relative to
    the keyframe file; ``joints`` then names its hinge joints), ``payload_kg``,
    ``payload_offset_m`` (3 numbers), ``torque_margin``,
    ``max_tracking_error_rad``, ``p_divisor``, and a table per joint
    ``[gimbal.<joint>]`` with ``servo`` (that joint's model), ``armature``
    (kg m^2), ``frictionloss`` (N m), ``damping`` (N m s/rad),
    ``position_p_gain`` (register units) and ``p_divisor`` (that servo's P
    scale), overriding the servo's defaults.

    Parameters
    ----------
    tables : dict
        The file's other top-level tables as parsed by ``tomllib``
        (``KeyframeFile.tables``); only ``tables["gimbal"]`` is read.
    path : str or Path
        The file, named in error messages; ``model`` is relative to its folder.
    any_axes : bool
        Accept ``axes`` / ``joints`` other than pan-tilt-roll (every command that
        takes them passes True); otherwise they are refused in one line.

    Returns
    -------
    GimbalConfig

    Raises
    ------
    trajgen.keyframes.KeyframeFileError
        One line naming the file, the table and the field, e.g.
        ``"f.toml: [gimbal] servo: unknown model 'XM999' (known: ...)"``.
    """
    table = tables.get("gimbal", {})
    if not isinstance(table, dict):
        raise _file_error(path, f"[gimbal]: expected a table, got {table!r}")
    axes = axes_from_table(table, path)
    names = axes.joints
    check_keys(
        table, (*GIMBAL_TABLE_KEYS, *names), error=lambda p: _file_error(path, f"[gimbal]: {p}")
    )
    per_joint = [_joint_table(table.get(j, {}), j, path) for j in names]
    servos = tuple(servo_by_name(name) for name in joint_servos(table, names, path))
    kwargs = {"servos": servos, "axes": axes}
    kwargs["joints"] = tuple(
        _joint_from_table(t, j, path) for j, t in zip(names, per_joint, strict=True)
    )
    for key in ("payload_kg", "torque_margin", "max_tracking_error_rad", "p_divisor"):
        if key in table:
            error = _field_error(path, key)
            kwargs[key] = check_number(key, table[key], error=error, **_FIELD_BOUNDS[key])
    if "payload_offset_m" in table:
        error = _field_error(path, "payload_offset_m")
        kwargs["payload_offset_m"] = check_numbers(
            "payload_offset_m", table["payload_offset_m"], 3, error=error, **_OFFSET_BOUNDS
        )
    if "model" in table:
        kwargs["model"] = _model_path(table["model"], path)
        for key in ("payload_kg", "payload_offset_m"):
            if key in table:
                raise _file_error(
                    path,
                    f"[gimbal] {key}: your own model's payload is in its file "
                    f"(model = {table['model']!r}); leave {key} out",
                )
    if not any_axes:
        _refuse_other_axes(axes, path)
    config = GimbalConfig(**kwargs)
    if config.model is not None:
        from .user_model import check_user_model

        check_user_model(
            config, error=lambda problem: _file_error(path, f"[gimbal] model: {problem}")
        )
    return config


def _model_path(value, path) -> Path:
    """``[gimbal] model``: an existing ``.xml`` or ``.urdf`` file, relative to the keyframe file."""
    if not isinstance(value, str) or not value:
        raise _file_error(path, f"[gimbal] model: expected a file name, got {value!r}")
    model = Path(path).parent / value
    if model.suffix.lower() not in (".xml", ".urdf"):
        raise _file_error(
            path, f"[gimbal] model: {value!r}: expected an MJCF (.xml) or URDF (.urdf) file"
        )
    if not model.is_file():
        raise _file_error(path, f"[gimbal] model: {value!r}: no such file ({model})")
    return model


def _refuse_other_axes(axes: AxisSequence, path) -> None:
    """Refuse ``[gimbal] axes`` / ``joints`` other than pan-tilt-roll in one line, for a
    caller that takes pan-tilt-roll only (``any_axes=False``)."""
    if is_default(axes):
        return
    if axes.n == 2:
        what = f"[gimbal] axes = {axes.sequence!r}: 2-axis gimbals"
    elif axes.sequence != "zyx":
        what = f"[gimbal] axes = {axes.sequence!r}: axes other than 'zyx'"
    else:
        what = f"[gimbal] joints = {list(axes.joints)}: joint names other than pan, tilt, roll"
    raise _file_error(
        path,
        f"{what}: this caller takes pan-tilt-roll (axes = 'zyx') only (any_axes=False); "
        "pass any_axes=True for a caller that takes any axes, as every trajgen command does",
    )


def _joint_table(value, joint: str, path) -> dict:
    """A ``[gimbal.<joint>]`` table, checked for its keys."""
    where = f"[gimbal.{joint}]"
    if not isinstance(value, dict):
        raise _file_error(path, f"{where}: expected a table, got {value!r}")
    keys = (*JOINT_TABLE_KEYS, "servo")
    check_keys(value, keys, error=lambda p: _file_error(path, f"{where}: {p}"))
    return value


def _joint_from_table(value: dict, joint: str, path) -> dict:
    """The overrides of a ``[gimbal.<joint>]`` table (checked by :func:`_joint_table`)."""
    where = f"[gimbal.{joint}]"
    return {
        key: check_number(
            key,
            v,
            error=lambda problem, key=key: _file_error(path, f"{where} {key}: {problem}"),
            **_JOINT_BOUNDS[key],
        )
        for key, v in value.items()
        if key != "servo"
    }


def _file_error(path, message: str):
    return KeyframeFileError(f"{Path(path)}: {message}")


def _field_error(path, key: str):
    return lambda problem: _file_error(path, f"[gimbal] {key}: {problem}")


def gimbal_mjcf(config: GimbalConfig | None = None) -> str:
    """MJCF text of the built-in gimbal described by ``config`` (default :class:`GimbalConfig`).

    Bodies ``<joint>_link`` (``pan_link``, ``tilt_link``, ``roll_link`` for the
    default); hinge joints and ``<dcmotor>`` actuators named as the joints
    (actuator group ``j`` for joint ``j``, so each can be switched off with
    ``opt.disableactuator``) and their torque sensors (``<actuatorfrc>``, for
    ``mujoco.rollout``); site ``camera`` at the last link's origin; every geom
    is contact-free. ``config.model`` is not read here (see :func:`build_model`).
    """
    config = GimbalConfig() if config is None else config
    seq, names, servos = config.axes, config.names, config.servos
    axis = [_unit(i) for i in seq.indices]
    f = _fmt
    # Brackets and offsets scale with the housing width of the servo they hold.
    ref_width = servo_by_name(_BRACKET_SERVO).size_m[0]
    scale = [s.size_m[0] / ref_width for s in servos]
    height = _TILT_HEIGHT_M * scale[1]

    def joint(j):
        p = config.joints[j]
        return (
            f'<joint name="{names[j]}" type="hinge" axis="{f(axis[j])}" '
            f'armature="{p.armature!r}" damping="{p.damping!r}" '
            f'frictionloss="{p.frictionloss!r}"/>'
        )

    def servo_box(j, pos):
        """Servo ``j``'s housing: depth along its axis, height along the first axis
        (the second for a last axis parallel to the first)."""
        w, h, d = servos[j].size_m
        up = seq.indices[1] if seq.indices[j] == seq.indices[0] else seq.indices[0]
        half = _box({seq.indices[j]: d / 2, up: h / 2}, w / 2)
        return (
            f'<geom name="{names[j]}_servo" type="box" size="{f(half)}" pos="{f(pos)}" '
            f'mass="{servos[j].mass_kg!r}" rgba="0.15 0.15 0.15 1"/>'
        )

    def plate(name, normal, pos, sizes, rest, mass):
        half = _box({normal: 0.001, **sizes}, rest)
        return f'<geom name="{name}" type="box" size="{f(half)}" pos="{f(pos)}" mass="{mass!r}"/>'

    a1, a2 = seq.indices[:2]
    s1 = scale[1]
    first = (
        plate(
            f"{names[0]}_bracket_bottom",
            a1,
            0.0005 * axis[0],
            {a2: 0.045 * s1},
            0.02 * s1,
            _BRACKET_KG / 3 * s1**2,
        ),
        plate(
            f"{names[0]}_bracket_left",
            a2,
            0.045 * s1 * axis[1] + 0.04 * s1 * axis[0],
            {a1: 0.04 * s1},
            0.02 * s1,
            _BRACKET_KG / 3 * s1**2,
        ),
        plate(
            f"{names[0]}_bracket_right",
            a2,
            -0.045 * s1 * axis[1] + 0.04 * s1 * axis[0],
            {a1: 0.04 * s1},
            0.02 * s1,
            _BRACKET_KG / 3 * s1**2,
        ),
        servo_box(
            1,
            height * axis[0]
            - (0.035 * s1 + servos[1].size_m[2] / 2) * axis[1]
            - (servos[1].size_m[1] / 2 - servos[1].size_m[0] / 2) * axis[0],
        ),
    )
    links = [first]
    if seq.n == 3:
        a3, s2 = seq.indices[2], scale[2]
        links.append(
            (
                plate(
                    f"{names[1]}_bracket",
                    a3,
                    -0.009 * s2 * axis[2],
                    {a2: 0.03 * s2},
                    0.02 * s2,
                    _BRACKET_KG * s2**2,
                ),
                servo_box(2, -(0.01 * s2 + servos[2].size_m[2] / 2) * axis[2]),
            )
        )
    look = int(np.argmax(seq.look))
    cam = config.payload_offset_m
    lens_pos = list(cam)
    lens_pos[look] = cam[look] + _CAMERA_SIZE_M[0] / 2 + 0.008
    camera_half = _box({look: _CAMERA_SIZE_M[0] / 2}, _CAMERA_SIZE_M[1] / 2)
    last = [
        '<site name="camera" pos="0 0 0" size="0.004"/>',
        plate("camera_plate", look, 0.001 * seq.look, {}, 0.025, _BRACKET_KG / 2),
    ]
    if config.payload_kg > 0:
        last.append(
            f'<geom name="camera" type="box" size="{f(camera_half)}" '
            f'pos="{f(cam)}" mass="{config.payload_kg!r}" rgba="0.1 0.1 0.1 1"/>'
        )
    last.append(
        f'<geom name="lens" type="cylinder" size="0.012 0.008" pos="{f(lens_pos)}" '
        f'euler="{_CYLINDER_ALONG[look]}" mass="0.001" rgba="0.2 0.3 0.8 1"/>'
    )
    links.append(tuple(last))
    offsets = [(0.0, 0.0, _PAN_HEIGHT_M), height * axis[0]] + [np.zeros(3)] * (seq.n - 2)
    body = ""
    for j in reversed(range(seq.n)):
        pad = "  " * (j + 3)
        inner = "\n".join(pad + "  " + g for g in (joint(j), *links[j])) + "\n"
        body = (
            f'{pad}<body name="{names[j]}_link" pos="{f(offsets[j])}">\n{inner}{body}{pad}</body>\n'
        )
    motors = "\n".join(f"    {_motor(config, j)}" for j in range(seq.n))
    sensors = "\n".join(f'    <actuatorfrc name="{n}_torque" actuator="{n}"/>' for n in names)
    base_servo = servo_box(0, (0.0, 0.0, _PAN_HEIGHT_M - servos[0].size_m[2] / 2))
    return f"""<mujoco model="{"_".join(names)}_gimbal">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{config.timestep_s!r}"/>
  <default>
    <geom contype="0" conaffinity="0" rgba="0.55 0.57 0.6 1"/>
  </default>
  <visual>
    <global offwidth="640" offheight="480"/>
  </visual>
  <worldbody>
    <light pos="0.3 -0.3 0.6" dir="-0.4 0.4 -1"/>
    <geom name="floor" type="plane" size="0.3 0.3 0.01" rgba="0.85 0.85 0.8 1"/>
    <camera name="overview" mode="targetbody" target="{names[1]}_link" pos="0.22 -0.26 0.24"/>
    <body name="base" pos="0 0 0">
      {base_servo}
    </body>
{body}  </worldbody>
  <actuator>
{motors}
  </actuator>
  <sensor>
{sensors}
  </sensor>
</mujoco>
"""


#: ``euler`` that turns a cylinder's axis (z) onto x, y or z.
_CYLINDER_ALONG = ("0 1.5707963267948966 0", "-1.5707963267948966 0 0", "0 0 0")


def _motor_parameters(config: GimbalConfig, j: int) -> tuple[list, list, list]:
    """Joint ``j``'s ``<dcmotor>`` ``nominal`` (volts, stall torque, no-load speed),
    ``saturation`` (the stall torque clamp) and ``controller`` (the firmware loop)."""
    servo = config.servos[j]
    kp, ki, kd, vmax = config.loop(j).mujoco_controller(servo)
    nominal = [servo.voltage_v, servo.stall_torque_nm, servo.no_load_speed_rad_s]
    return nominal, [servo.stall_torque_nm, 0.0, 0.0], [kp, ki, kd, 0.0, 0.0, vmax]


def _motor(config: GimbalConfig, j: int) -> str:
    """Joint ``j``'s ``<dcmotor>`` element: the servo's ratings and its firmware loop."""
    name = config.names[j]
    nominal, saturation, controller = _motor_parameters(config, j)
    return (
        f'<dcmotor name="{name}" joint="{name}" group="{j}" input="pos" '
        f'nominal="{_fmt(nominal)}" controller="{_fmt(controller)}" '
        f'saturation="{_fmt(saturation)}"/>'
    )


def _unit(i: int) -> np.ndarray:
    e = np.zeros(3)
    e[i] = 1.0
    return e


def _box(half_sizes: dict, rest: float) -> tuple:
    """Half sizes along x, y, z: ``half_sizes[axis]`` where given, else ``rest``."""
    return tuple(half_sizes.get(i, rest) for i in range(3))


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def build_model(config: GimbalConfig | None = None):
    """Compile the gimbal into a ``mujoco.MjModel``: joint, dof and actuator ``j`` are
    ``config.names[j]``; the built-in chain, or ``config.model`` with the servos
    attached (``sim.user_model.user_model``).

    Raises
    ------
    ValueError
        If MuJoCo rejects the built-in model (a bug here, not bad input).
    SimError
        If the user's model cannot carry the servos (``sim.user_model``).
    """
    import mujoco

    config = GimbalConfig() if config is None else config
    if config.model is not None:
        from .user_model import user_model

        return user_model(config)
    return mujoco.MjModel.from_xml_string(gimbal_mjcf(config))
