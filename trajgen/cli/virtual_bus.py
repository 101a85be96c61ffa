"""The ``trajgen virtual-bus`` command: the simulated gimbal as a servo chain on a pty.

This module imports quickly: MuJoCo and the virtual bus load inside
``run_virtual_bus``.
"""

from __future__ import annotations

import argparse
import signal
import threading

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    BadInput,
    add_file_argument,
    bad_input,
    exit_status_text,
    load_checked,
    servo_ids,
    tell,
)
from trajgen.cli.help_texts import VIRTUAL_BUS_DESCRIPTION
from trajgen.errors import TrajgenError
from trajgen.servo_table import DEFAULT_SERVO


def model_names(text: str) -> tuple[str, ...]:
    """argparse type: X-series model names separated by commas (one for every servo, or
    one per id)."""
    from trajgen.drivers.control_table import MODELS

    names = tuple(part.strip() for part in text.split(","))
    if not all(n in MODELS for n in names):
        raise argparse.ArgumentTypeError(
            f"expected model names separated by commas, among {', '.join(MODELS)}; got {text!r}"
        )
    return names


def register(subparsers) -> None:
    """Add the ``virtual-bus`` subcommand to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "virtual-bus",
        help="serve the simulated gimbal as Dynamixel servos on a pseudo-terminal",
        description=VIRTUAL_BUS_DESCRIPTION,
        epilog=exit_status_text("the simulation failed", signals=True),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_file_argument(p)
    p.add_argument(
        "--ids",
        type=servo_ids,
        metavar="ID,ID,...",
        help="the servos on the chain, any number: the gimbal's joints are the file's [bus] "
        "ids where they are all among them, else the first ones; the others idle "
        "(default: the file's [bus] ids, else 1,2,3)",
    )
    p.add_argument(
        "--models",
        type=model_names,
        metavar="MODEL[,MODEL...]",
        help=f"servo model of every servo, or one per id; default: the file's [bus] models "
        f"for the gimbal's joints, {DEFAULT_SERVO} for the others",
    )
    p.add_argument(
        "--lockstep",
        action="store_true",
        help="advance the simulation with the traffic instead of the wall clock",
    )
    p.set_defaults(func=run_virtual_bus)


def chain_of(ids, models, config) -> tuple[tuple[int, ...], tuple[int, ...], tuple[str, ...]]:
    """The servos to serve: ``(ids, plant_ids, models)`` from --ids, --models and the
    file's [bus] table (``BusConfig``).

    The gimbal's joints are the file's [bus] ids when all are among ``ids``, else the
    first ids; a servo's model is ``models`` (one for all, or one per id), else the
    file's for the gimbal's joints and the default for the others.

    Raises
    ------
    BadInput
        Fewer ids than the gimbal has joints, or a count of --models that is neither
        1 nor one per id.
    """
    file_ids = config.joints.ids
    ids = tuple(ids or file_ids)
    n = len(file_ids)
    if len(ids) < n:
        raise BadInput(
            f"--ids {','.join(map(str, ids))}: expected at least {n} ids, one per joint of "
            f"the gimbal ({', '.join(config.joint_names)})"
        )
    plant_ids = file_ids if set(file_ids) <= set(ids) else ids[:n]
    if models is None:
        by_id = dict(zip(plant_ids, config.models, strict=True))
        models = tuple(by_id.get(i, DEFAULT_SERVO) for i in ids)
    elif len(models) == 1:
        models = models * len(ids)
    elif len(models) != len(ids):
        raise BadInput(f"--models: expected 1 model or {len(ids)} (one per id), got {len(models)}")
    return ids, tuple(plant_ids), tuple(models)


def _tell_refusal(servo_id: int, reason: str) -> None:
    """Say on stderr why a servo answered a write with Result Fail."""
    tell(f"servo {servo_id} refused a write (Result Fail): {reason}")


def run_virtual_bus(args) -> int:
    """Run ``trajgen virtual-bus``; returns the exit status."""
    from trajgen.sim.firmware import UnsupportedServoSetting
    from trajgen.sim.plant import GimbalPlant

    try:
        checked = load_checked(args.file, spline=False, any_axes=True)
    except TrajgenError as e:
        return bad_input(e)
    kf, config = checked.keyframes, checked.bus
    # Served until stopped and never reported on: no step record kept.
    plant = GimbalPlant(checked.gimbal, record=False)
    from trajgen.drivers.priority import stream_priority
    from trajgen.drivers.virtual.bus import VirtualBus
    from trajgen.drivers.virtual.simulation import LAG_COUNTED_S

    try:
        ids, plant_ids, models = chain_of(args.ids, args.models, config)
    except BadInput as e:
        return bad_input(e)
    period_s = 1.0 / kf.stream_rate() if args.lockstep else None
    stop = threading.Event()
    received = []

    def on_signal(signum, frame):
        received.append(signum)
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    virtual = VirtualBus(
        plant,
        ids=ids,
        plant_ids=plant_ids,
        models=models,
        lockstep_dt_s=period_s,
        registers=dict(zip(plant_ids, plant.initial_registers(), strict=True)),  # the file's gains
        unsupported=(UnsupportedServoSetting,),
        on_refusal=_tell_refusal,
        plant_process=period_s is None,  # real time: no GIL shared with the simulation
    ).start()
    try:
        clock = (
            "real time, the simulation in its own process"
            if period_s is None
            else f"lock-step, {1e3 * period_s:g} ms periods"
        )
        idle = [i for i in ids if i not in plant_ids]
        # Its threads (serving, simulating) answer ahead of other programs where permitted,
        # from the first packet on: the port is told once they are raised.
        with stream_priority() as scheduling:
            print(virtual.port, flush=True)
            tell(
                f"serving servos {', '.join(map(str, ids))} ({', '.join(models)}), {clock}; "
                + (f"idle (not the gimbal's): {', '.join(map(str, idle))}; " if idle else "")
                + f"{scheduling}; Ctrl-C to stop"
            )
            while not stop.wait(0.2):
                if virtual.error is not None:
                    break
    finally:
        child = virtual.plant.scheduling() if period_s is None else ""  # while it runs
        virtual.stop()
        wall_s = virtual.wall_time_s  # once the simulation has stopped
        for s, handler in previous.items():
            signal.signal(s, handler)
    if virtual.error is not None:
        tell(f"simulation failed: {virtual.error}")
        return EXIT_FAILED
    name = signal.Signals(received[0]).name if received else "the end"
    tell(f"stopped by {name} after {virtual.sim_time_s:.3f} s simulated in {wall_s:.3f} s")
    if period_s is None:
        lag_max, lag_p99, over = virtual.lag()
        cpu_s = virtual.plant.figures()[2] / max(1, virtual.plant.steps())
        tell(
            f"the simulation's process ran at {child}, {1e6 * cpu_s:.0f} us of CPU per "
            f"step; simulated time behind the wall clock: at most "
            f"{1e3 * lag_max:.1f} ms, "
            f"{1e3 * lag_p99:.1f} ms at the 99th percentile, {over:.3f} s spent more than "
            f"{1e3 * LAG_COUNTED_S:g} ms behind"
            + (": the host was too busy to simulate in real time" if over > 0 else "")
        )
    if virtual.stale_replies:
        tell(
            f"{virtual.stale_replies} replies went out before the simulation had caught up "
            f"(at most {1e3 * virtual.stale_max_s:.1f} ms behind): the host was too busy to "
            "simulate in real time"
        )
    return 128 + received[0] if received else EXIT_OK
