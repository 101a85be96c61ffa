"""The MJCF pan-tilt-roll gimbal and its configuration.

Layout (zero pose, world frame, z up): the pan servo stands on the base with its
horn up; the pan link carries a U bracket and the tilt servo (horn along y); the
tilt link carries the roll servo behind the camera (horn along x); the roll link
carries the camera, which looks along +x. The three axes meet at one point, so
the roll link's orientation is ``Rz(pan) Ry(tilt) Rx(roll)``, trajgen's
convention (``trajgen.quat.from_pan_tilt_roll``).

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

from trajgen.errors import KeyframeFileError
from trajgen.gimbal import JOINT_NAMES
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
    *JOINT_NAMES,
)
#: Keys of a ``[gimbal.<joint>]`` table.
JOINT_TABLE_KEYS = ("armature", "frictionloss", "damping", "position_p_gain", "p_divisor")

_PAN_HEIGHT_M = 0.05  # pan horn above the base plate
_TILT_HEIGHT_M = 0.07  # tilt (and roll) axis above the pan horn
_BRACKET_KG = 0.025
_CAMERA_SIZE_M = (0.06, 0.04, 0.04)


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
    servos : tuple of 3 ServoModel or str
        Servo per joint (pan, tilt, roll); names are looked up in
        ``sim.servos.SERVOS``. Default XM430-W350 on every joint.
    payload_kg : float
        Camera mass (kg), >= 0. Default 0.15.
    payload_offset_m : tuple of 3 float
        Camera centre of mass in the roll link frame (m), where the three axes
        meet at the origin and the camera looks along +x. Default (0.03, 0, 0).
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
    joints : tuple of 3 JointParams or dict, optional
        Per-joint parameters (pan, tilt, roll); a dict gives overrides of the
        servo's defaults (``JointParams.of``). Default: each servo's defaults.
    p_divisor : float
        ``KP = P / p_divisor`` in the firmware loop: 128 per the e-Manual (BAM
        measured 256 on an XL330; see ``sim.firmware``).

    Raises
    ------
    TypeError
        If a field has the wrong type.
    ValueError
        If a field is out of range or a servo name is unknown.
    """

    servos: tuple = (DEFAULT_SERVO, DEFAULT_SERVO, DEFAULT_SERVO)
    payload_kg: float = 0.15
    payload_offset_m: tuple = (0.03, 0.0, 0.0)
    torque_margin: float = 0.8
    max_tracking_error_rad: float = 0.05
    timestep_s: float = 0.001
    joints: tuple | None = None
    p_divisor: float = P_DIVISOR

    def __post_init__(self):
        servos = self.servos
        if isinstance(servos, (str, ServoModel)):
            servos = (servos,) * 3
        if not isinstance(servos, (tuple, list)) or len(servos) != 3:
            raise BadArgument(
                f"Expected `servos` to hold 3 servos (pan, tilt, roll), got {servos!r}."
            )
        resolved = tuple(s if isinstance(s, ServoModel) else servo_by_name(s) for s in servos)
        object.__setattr__(self, "servos", resolved)
        for name, bounds in _FIELD_BOUNDS.items():
            object.__setattr__(self, name, check_number(name, getattr(self, name), **bounds))
        offset = check_numbers("payload_offset_m", self.payload_offset_m, 3)
        object.__setattr__(self, "payload_offset_m", offset)
        joints = ({},) * 3 if self.joints is None else self.joints
        if not isinstance(joints, (tuple, list)) or len(joints) != 3:
            raise BadArgument(
                f"Expected `joints` to hold 3 entries (pan, tilt, roll), got {joints!r}."
            )
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
    "payload_kg": {"low": 0.0},
    "torque_margin": {"low": 0.0, "high": 1.0, "low_open": True},
    "max_tracking_error_rad": {"low": 0.0, "low_open": True},
    "timestep_s": {"low": 0.0, "high": 0.001, "low_open": True},
    "p_divisor": {"low": 0.0, "low_open": True},
}


def gimbal_config_from_tables(tables: dict, path, *, any_axes: bool = False) -> GimbalConfig:
    """Build a :class:`GimbalConfig` from a keyframe file's ``[gimbal]`` table.

    Keys (all optional): ``servo`` (a model name for every joint, or a table
    ``{pan = "...", tilt = "...", roll = "..."}`` where missing joints take the
    default XM430-W350), ``payload_kg``, ``payload_offset_m`` (3 numbers),
    ``torque_margin``, ``max_tracking_error_rad``, ``p_divisor``, and per-joint
    tables ``[gimbal.pan]``, ``[gimbal.tilt]``, ``[gimbal.roll]`` with
    ``armature`` (kg m^2), ``frictionloss`` (N m), ``damping`` (N m s/rad),
    ``position_p_gain`` (register units) and ``p_divisor`` (that servo's P
    scale), overriding the servo's defaults.

    Parameters
    ----------
    tables : dict
        The file's other top-level tables as parsed by ``tomllib``
        (``KeyframeFile.tables``); only ``tables["gimbal"]`` is read.
    path : str or Path
        The file, named in error messages.
    any_axes : bool
        Accept ``axes`` / ``joints`` other than pan-tilt-roll (``trajgen plan``);
        the simulated gimbal is pan-tilt-roll, so otherwise they are refused.

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
    check_keys(table, GIMBAL_TABLE_KEYS, error=lambda p: _file_error(path, f"[gimbal]: {p}"))
    kwargs = {"servos": _servos_from_table(table.get("servo", DEFAULT_SERVO.name), path)}
    kwargs["joints"] = tuple(_joint_from_table(table.get(j, {}), j, path) for j in JOINT_NAMES)
    for key in ("payload_kg", "torque_margin", "max_tracking_error_rad", "p_divisor"):
        if key in table:
            error = _field_error(path, key)
            kwargs[key] = check_number(key, table[key], error=error, **_FIELD_BOUNDS[key])
    if "payload_offset_m" in table:
        error = _field_error(path, "payload_offset_m")
        kwargs["payload_offset_m"] = check_numbers(
            "payload_offset_m", table["payload_offset_m"], 3, error=error
        )
    if not any_axes:
        _refuse_other_axes(table, path)
    return GimbalConfig(**kwargs)


def _refuse_other_axes(table: dict, path) -> None:
    """Refuse ``[gimbal] axes`` / ``joints`` other than pan-tilt-roll in one line: the
    simulated gimbal (and the drivers' joint map) is pan-tilt-roll."""
    axes = axes_from_table(table, path)
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
        f"{what}: the simulator and the drivers need pan-tilt-roll (axes = 'zyx'), "
        "not yet; trajgen plan takes any axes",
    )


def _joint_from_table(value, joint: str, path) -> dict:
    """The overrides of a ``[gimbal.<joint>]`` table, checked."""
    where = f"[gimbal.{joint}]"
    if not isinstance(value, dict):
        raise _file_error(path, f"{where}: expected a table, got {value!r}")
    check_keys(value, JOINT_TABLE_KEYS, error=lambda p: _file_error(path, f"{where}: {p}"))
    return {
        key: check_number(
            key,
            v,
            error=lambda problem, key=key: _file_error(path, f"{where} {key}: {problem}"),
            **_JOINT_BOUNDS[key],
        )
        for key, v in value.items()
    }


def _servos_from_table(value, path) -> tuple[ServoModel, ServoModel, ServoModel]:
    if isinstance(value, str):
        return (_servo_or_error(value, "servo", path),) * 3
    if isinstance(value, dict):
        check_keys(
            value,
            JOINT_NAMES,
            error=lambda p: _file_error(path, f"[gimbal] servo: {p}"),
            kind="joint",
        )
        return tuple(
            _servo_or_error(value.get(j, DEFAULT_SERVO.name), f"servo.{j}", path)
            for j in JOINT_NAMES
        )
    raise _file_error(
        path, f"[gimbal] servo: expected a model name or a table per joint, got {value!r}"
    )


def _servo_or_error(name, key, path) -> ServoModel:
    if not isinstance(name, str):
        raise _file_error(path, f"[gimbal] {key}: expected a model name, got {name!r}")
    try:
        return servo_by_name(name)
    except ValueError as e:
        raise _file_error(path, f"[gimbal] {key}: {e}") from e


def _file_error(path, message: str):
    return KeyframeFileError(f"{Path(path)}: {message}")


def _field_error(path, key: str):
    return lambda problem: _file_error(path, f"[gimbal] {key}: {problem}")


def gimbal_mjcf(config: GimbalConfig | None = None) -> str:
    """MJCF text of the gimbal described by ``config`` (default :class:`GimbalConfig`).

    Bodies ``pan_link``, ``tilt_link``, ``roll_link``; hinge joints and
    ``<dcmotor>`` actuators named ``pan``, ``tilt``, ``roll`` (actuator groups
    0, 1, 2, so each can be switched off with ``opt.disableactuator``) and
    their torque sensors (``<actuatorfrc>``, for ``mujoco.rollout``); site
    ``camera`` at the roll link's origin; every geom is contact-free.
    """
    config = GimbalConfig() if config is None else config
    pan, tilt, roll = config.servos
    f = _fmt
    # Tilt servo: on the pan link's side, horn on the tilt axis, housing along -y.
    tw, th, td = tilt.size_m
    tilt_servo_pos = (0.0, -(0.035 + td / 2), _TILT_HEIGHT_M - (th / 2 - tw / 2))
    # Roll servo: behind the camera, horn on the roll axis, housing along -x.
    rw, rh, rd = roll.size_m
    roll_servo_pos = (-(0.01 + rd / 2), 0.0, 0.0)
    pw, ph, pd = pan.size_m
    cam = config.payload_offset_m
    lens_pos = (cam[0] + _CAMERA_SIZE_M[0] / 2 + 0.008, cam[1], cam[2])
    payload = (
        f'<geom name="camera" type="box" size="{f(s / 2 for s in _CAMERA_SIZE_M)}" '
        f'pos="{f(cam)}" mass="{config.payload_kg!r}" rgba="0.1 0.1 0.1 1"/>'
        if config.payload_kg > 0
        else ""
    )

    def joint(name, axis, servo):
        p = config.joints[JOINT_NAMES.index(name)]
        return (
            f'<joint name="{name}" type="hinge" axis="{axis}" armature="{p.armature!r}" '
            f'damping="{p.damping!r}" frictionloss="{p.frictionloss!r}"/>'
        )

    def motor(name, group, servo):
        kp, ki, kd, vmax = config.loop(group).mujoco_controller(servo)
        return (
            f'<dcmotor name="{name}" joint="{name}" group="{group}" input="pos" '
            f'nominal="{servo.voltage_v!r} {servo.stall_torque_nm!r} '
            f'{servo.no_load_speed_rad_s!r}" '
            f'controller="{kp!r} {ki!r} {kd!r} 0 0 {vmax!r}" '
            f'saturation="{servo.stall_torque_nm!r} 0 0"/>'
        )

    return f"""<mujoco model="pan_tilt_roll_gimbal">
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
    <camera name="overview" mode="targetbody" target="tilt_link" pos="0.22 -0.26 0.24"/>
    <body name="base" pos="0 0 0">
      <geom name="pan_servo" type="box" size="{f((pw / 2, pd / 2, ph / 2))}"
            pos="0 0 {_PAN_HEIGHT_M - pd / 2!r}" euler="1.5707963267948966 0 0"
            mass="{pan.mass_kg!r}" rgba="0.15 0.15 0.15 1"/>
    </body>
    <body name="pan_link" pos="0 0 {_PAN_HEIGHT_M!r}">
      {joint("pan", "0 0 1", pan)}
      <geom name="pan_bracket_bottom" type="box" size="0.02 0.045 0.001" pos="0 0 0.0005"
            mass="{_BRACKET_KG / 3!r}"/>
      <geom name="pan_bracket_left" type="box" size="0.02 0.001 0.04" pos="0 0.045 0.04"
            mass="{_BRACKET_KG / 3!r}"/>
      <geom name="pan_bracket_right" type="box" size="0.02 0.001 0.04" pos="0 -0.045 0.04"
            mass="{_BRACKET_KG / 3!r}"/>
      <geom name="tilt_servo" type="box" size="{f((tw / 2, td / 2, th / 2))}"
            pos="{f(tilt_servo_pos)}" mass="{tilt.mass_kg!r}" rgba="0.15 0.15 0.15 1"/>
      <body name="tilt_link" pos="0 0 {_TILT_HEIGHT_M!r}">
        {joint("tilt", "0 1 0", tilt)}
        <geom name="tilt_bracket" type="box" size="0.001 0.03 0.02" pos="-0.009 0 0"
              mass="{_BRACKET_KG!r}"/>
        <geom name="roll_servo" type="box" size="{f((rd / 2, rw / 2, rh / 2))}"
              pos="{f(roll_servo_pos)}" mass="{roll.mass_kg!r}" rgba="0.15 0.15 0.15 1"/>
        <body name="roll_link" pos="0 0 0">
          {joint("roll", "1 0 0", roll)}
          <site name="camera" pos="0 0 0" size="0.004"/>
          <geom name="camera_plate" type="box" size="0.001 0.025 0.025" pos="0.001 0 0"
                mass="{_BRACKET_KG / 2!r}"/>
          {payload}
          <geom name="lens" type="cylinder" size="0.012 0.008" pos="{f(lens_pos)}"
                euler="0 1.5707963267948966 0" mass="0.001" rgba="0.2 0.3 0.8 1"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    {motor("pan", 0, pan)}
    {motor("tilt", 1, tilt)}
    {motor("roll", 2, roll)}
  </actuator>
  <sensor>
    <actuatorfrc name="pan_torque" actuator="pan"/>
    <actuatorfrc name="tilt_torque" actuator="tilt"/>
    <actuatorfrc name="roll_torque" actuator="roll"/>
  </sensor>
</mujoco>
"""


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def build_model(config: GimbalConfig | None = None):
    """Compile the gimbal into a ``mujoco.MjModel`` (joint and dof ``i`` = ``JOINT_NAMES[i]``).

    Raises
    ------
    ValueError
        If MuJoCo rejects the model (a bug here, not bad input).
    """
    import mujoco

    return mujoco.MjModel.from_xml_string(gimbal_mjcf(config))
