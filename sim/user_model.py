"""The user's own gimbal model (MJCF or URDF) with trajgen's servos attached.

``[gimbal] model = "my_gimbal.xml"`` (or ``.urdf``) with ``joints = [...]``
naming the model's hinge joints from the base out. MuJoCo reads the file
(``mujoco.MjSpec.from_file``; it compiles URDF directly, dropping its
``<visual>`` elements as its ``discardvisual`` default does), and
:func:`user_spec` then, through ``MjSpec``:

- keeps every mass, inertia, body frame and joint axis of the file;
- sets each named joint's ``armature``, ``damping`` and ``frictionloss`` from
  its servo (``sim.servos``, or the ``[gimbal.<joint>]`` overrides);
- replaces the file's actuators and sensors with one ``<dcmotor>`` per joint
  (the servo's ratings and firmware loop, exactly as the built-in chain's,
  ``sim.model._motor``) and its torque sensor;
- holds every other joint of the file (a gripper, a second arm, a free base):
  deleted from the model, so its body is welded to its parent at the joint's
  reference pose, the pose the file draws (:func:`held_joints`; ``trajgen sim``
  names them);
- turns every geom contact-free (a gimbal's links do not touch; the
  simulation runs with contacts off);
- adds an ``overview`` camera (for ``--video``) if the file has none, and
  takes the physics time step from ``[gimbal]``.

The named joints' axes must be the ones ``[gimbal] axes`` declares: with every
named joint at 0, each hinge axis, composed down the chain's fixed rotations
and seen from the body the first joint is mounted on (the gimbal's base,
however the file places it in the world), must lie within
:data:`AXIS_TOLERANCE_DEG` of its letter, turning the same way. A tilt within
that is the model as built and is simulated as drawn; the plan's kinematics
keep the declared axes.

Refused, in one line naming it: a named joint that is missing or is not a
hinge, one whose axis is not the declared one (naming both), joints not named
base out, a body with zero or negative mass or inertia, and a mesh file that
is missing where the body's inertia would come from it. A missing mesh under a
body whose inertia the file states (``<inertial>``, as URDF always does) is
dropped: it carries no mass and contacts are off, so nothing simulated depends
on it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import BadArgument

#: Largest angle (deg) between a named joint's hinge axis in the model and the axis
#: ``[gimbal] axes`` declares for it (both in the gimbal's base frame, every joint at 0).
AXIS_TOLERANCE_DEG = 15.0


def _load(path: Path):
    import mujoco

    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as e:
        raise BadArgument(f"MuJoCo cannot read it: {_first_line(e)}") from None


def _first_line(error) -> str:
    text = str(error).strip()
    if text.startswith("Error: "):
        text = text[len("Error: ") :]
    return text.splitlines()[0] if text else type(error).__name__


def _moving(body) -> bool:
    """Whether ``body`` (an ``MjsBody``) or a body above it has a joint."""
    while body is not None and body.name != "world":
        if body.joints:
            return True
        body = body.parent
    return False


def _check_inertia(spec) -> None:
    """Refuse a body with zero or negative mass or inertia, naming it."""
    for body in spec.bodies:
        if body.name == "world" or not body.explicitinertial:
            continue
        name = body.name or f"#{body.id}"
        if body.mass < 0 or (body.mass == 0 and _moving(body)):
            raise BadArgument(f"body '{name}': mass {body.mass:g} kg; a moving link needs mass > 0")
        full = np.asarray(body.fullinertia, dtype=float)
        if np.isfinite(full[0]) and full.any():
            xx, yy, zz, xy, xz, yz = full
            moments = np.linalg.eigvalsh([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        else:
            moments = np.asarray(body.inertia, dtype=float)
        if (moments < 0).any() or (_moving(body) and (moments <= 0).any()):
            raise BadArgument(
                f"body '{name}': inertia with principal moments "
                f"{', '.join(f'{m:.3g}' for m in moments)} kg m^2; each must be > 0"
            )


def _drop_missing_meshes(spec, folder: Path) -> None:
    """Drop geoms whose mesh file is missing where the body states its inertia; refuse
    where the inertia would come from the geom."""
    mesh_dir = folder / (spec.meshdir or "")
    missing = {m.name for m in spec.meshes if m.file and not (mesh_dir / m.file).is_file()}
    if not missing:
        return
    files = {m.name: m.file for m in spec.meshes}
    for geom in list(spec.geoms):
        if geom.meshname not in missing:
            continue
        body = geom.parent
        if not body.explicitinertial:
            raise BadArgument(
                f"mesh file '{files[geom.meshname]}' not found, and body '{body.name}' takes "
                "its mass from it: ship the mesh or give the body an <inertial>"
            )
        spec.delete(geom)
    for mesh in list(spec.meshes):
        if mesh.name in missing:
            spec.delete(mesh)


def _check_joints(spec, names) -> None:
    """Refuse missing or non-hinge named joints."""
    import mujoco

    joints = {j.name: j for j in spec.joints}
    for name in names:
        if name not in joints:
            known = ", ".join(repr(n) for n in joints if n) or "none"
            raise BadArgument(f"no joint '{name}' in the model (its joints: {known})")
        kind = joints[name].type
        if kind != mujoco.mjtJoint.mjJNT_HINGE:
            what = kind.name.removeprefix("mjJNT_").lower()
            raise BadArgument(f"joint '{name}' is a {what} joint, not a hinge")


def _joint_label(joint) -> str:
    return joint.name or f"#{joint.id}"


def held_joints(config) -> tuple[str, ...]:
    """The joints of ``config.model`` the gimbal does not name, in the file's order:
    :func:`user_spec` welds each at its reference pose."""
    names = config.names
    return tuple(_joint_label(j) for j in _load(Path(config.model)).joints if j.name not in names)


def _hold_other_joints(spec, names) -> None:
    """Delete every joint not in ``names``: its body is then fixed to its parent at the
    pose the file draws (the joint's reference position). The file's keyframes go too
    (their joint vectors no longer fit)."""
    for joint in list(spec.joints):
        if joint.name not in names:
            spec.delete(joint)
    for key in list(spec.keys):
        spec.delete(key)


def _check_axes(model, config) -> None:
    """Refuse a named joint whose hinge axis is not the one ``config.axes`` declares
    (module docstring), naming the joint and both axes."""
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = 0.0  # only the named hinges are left: every joint at 0
    mujoco.mj_kinematics(model, data)
    base = model.body_parentid[model.jnt_bodyid[model.joint(config.names[0]).id]]
    to_base = data.xmat[base].reshape(3, 3).T
    sequence = config.axes.sequence
    for name, letter in zip(config.names, sequence, strict=True):
        axis = to_base @ data.xaxis[model.joint(name).id]
        want = np.eye(3)["xyz".index(letter)]
        off = float(np.degrees(np.arccos(np.clip(axis @ want, -1.0, 1.0))))
        if off > AXIS_TOLERANCE_DEG:
            shown = ", ".join(f"{v:.3g}" for v in axis + 0.0)
            raise BadArgument(
                f"joint '{name}' turns about ({shown}) in the gimbal's base frame, {off:.1f} "
                f"deg from +{letter}, its axis in [gimbal] axes = {sequence!r} (at most "
                f"{AXIS_TOLERANCE_DEG:g} deg, the same way round): fix the model's axis or "
                "the axes"
            )


def user_spec(config):
    """``config.model`` as a ``mujoco.MjSpec`` with the servos attached (module docstring).

    Parameters
    ----------
    config : GimbalConfig
        With ``model`` set; ``config.names`` are the model's hinge joints.

    Returns
    -------
    mujoco.MjSpec

    Raises
    ------
    trajgen.sim.errors.BadArgument
        One line naming what the model lacks (see the module docstring).
    """
    import mujoco

    from .model import _motor_parameters

    path = Path(config.model)
    spec = _load(path)
    names = config.names
    _check_joints(spec, names)
    _hold_other_joints(spec, names)
    _check_inertia(spec)
    _drop_missing_meshes(spec, path.parent)
    for actuator in list(spec.actuators):
        spec.delete(actuator)
    for sensor in list(spec.sensors):
        spec.delete(sensor)
    for geom in spec.geoms:
        geom.contype = geom.conaffinity = 0
    spec.option.timestep = config.timestep_s
    for j, name in enumerate(names):
        params = config.joints[j]
        joint = spec.joint(name)
        joint.armature = params.armature
        joint.damping = [params.damping, 0.0, 0.0]  # viscous only, as the built-in chain
        joint.frictionloss = params.frictionloss
        nominal, saturation, controller = _motor_parameters(config, j)
        actuator = spec.add_actuator(
            name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT, group=j
        )
        actuator.set_to_dcmotor(
            motorconst=[0.0, 0.0],
            resistance=0.0,
            nominal=nominal,
            saturation=saturation,
            controller=controller,
            ctrlspec=int(mujoco.mjtCtrlInput.mjINPUT_POS),
        )
        spec.add_sensor(
            name=f"{name}_torque",
            type=mujoco.mjtSensor.mjSENS_ACTUATORFRC,
            objtype=mujoco.mjtObj.mjOBJ_ACTUATOR,
            objname=name,
        )
    if not any(c.name == "overview" for c in spec.cameras):
        target = spec.joint(names[-1]).parent.name
        spec.worldbody.add_camera(
            name="overview",
            mode=mujoco.mjtCamLight.mjCAMLIGHT_TARGETBODY,
            targetbody=target,
            pos=[0.22, -0.26, 0.24],
        )
    return spec


def user_model(config):
    """Compile :func:`user_spec` into a ``mujoco.MjModel`` whose joint, dof and actuator
    ``j`` are ``config.names[j]``.

    Raises
    ------
    trajgen.sim.errors.BadArgument
        If the model cannot carry the servos, or MuJoCo refuses it (first line of
        its message), or its joints are not in the order named (base out), or a
        joint's axis is not the declared one.
    """
    spec = user_spec(config)
    try:
        model = spec.compile()
    except ValueError as e:
        raise BadArgument(f"MuJoCo refuses it: {_first_line(e)}") from None
    order = [model.joint(j).name for j in range(model.njnt)]
    if order != list(config.names):
        raise BadArgument(
            f"joints {list(config.names)} must be named base out, as the model has them: {order}"
        )
    _check_axes(model, config)
    return model


def check_user_model(config, *, error) -> None:
    """Compile ``config.model`` once, raising ``error(problem)`` for what it refuses.

    Parameters
    ----------
    config : GimbalConfig
    error : callable
        ``error(message)`` returns the exception to raise (e.g. a
        ``KeyframeFileError`` naming the keyframe file and ``[gimbal] model``).
    """
    try:
        user_model(config)
    except BadArgument as e:
        raise error(f"{Path(config.model).name}: {e}") from None
