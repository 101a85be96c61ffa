"""The ``trajgen stream`` command.

This module imports quickly: dynamixel-sdk, pyserial and MuJoCo load inside
``run_stream``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from trajgen.cli.common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    add_file_argument,
    bad_input,
    baud_rate,
    open_bus,
    positive_float,
    servo_ids,
)

STREAM_DESCRIPTION = """\
Plan the joint stream of a keyframe file and stream it to Dynamixel X-series
servos at a fixed rate: bring-up (ping and model check, Return Delay 0, operating
mode, no profile, torque on, Bus Watchdog), a smooth move from the present
position to the first frame, then one sync write of Goal Position per frame with
present position, velocity and current read back. Prints the rate achieved,
period jitter (p50, p99, max), overruns and communication errors.

The file's [bus] table may set port, baud, ids, directions, zeros, models and
watchdog_s; flags override it. On any stop the servos hold their last goal
(--torque-off releases them); the telemetry written so far is kept.

--virtual runs the same driver, SDK and serial layer against a virtual servo bus
on a pseudo-terminal, backed by the MuJoCo gimbal of `trajgen sim` (the file's
[gimbal] table; ideal assembly: direction +1, zero 2048), advancing one stream
period per frame received, and then prints the torque report.

exit status: 0 ok, 1 stream fault or torque check failed, 2 bad input,
130 interrupted (servos hold their last goal)."""


def register(subparsers) -> None:
    """Add the ``stream`` and ``scan`` subcommands to an argparse ``subparsers``."""
    p = subparsers.add_parser(
        "stream",
        help="stream a keyframe file to Dynamixel servos (or a virtual bus)",
        description=STREAM_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_stream_arguments(p)
    p.set_defaults(func=run_stream)


def add_stream_arguments(p) -> None:
    """The file, bus, rate, output and --virtual options (shared with ``trajgen follow``)."""
    add_file_argument(p)
    p.add_argument("--port", help="serial device, e.g. /dev/ttyUSB0; default [bus] port")
    p.add_argument(
        "--baud", type=baud_rate, help="baud rate (up to 4500000); default [bus] baud, else 1000000"
    )
    p.add_argument(
        "--ids", type=servo_ids, metavar="P,T,R", help="servo ids of pan, tilt, roll; default 1,2,3"
    )
    p.add_argument(
        "--rate",
        type=positive_float,
        metavar="HZ",
        help="stream rate (Hz); default the file's [stream] rate_hz, else 200",
    )
    p.add_argument(
        "--telemetry", metavar="OUT", help="write per-frame telemetry to OUT (.csv or .npz)"
    )
    p.add_argument("--json", metavar="OUT.json", help="write the statistics (and report) as JSON")
    p.add_argument(
        "--torque-off", action="store_true", help="release the servos when the stream stops"
    )
    p.add_argument(
        "--virtual",
        action="store_true",
        help="stream to a virtual bus backed by the simulated gimbal (no --port needed)",
    )
    p.add_argument("--plot", metavar="OUT.png", help="with --virtual: plot the torque report")


def run_stream(args) -> int:
    """Run ``trajgen stream``; returns the exit status."""
    try:
        return _stream(args)
    except KeyboardInterrupt:
        print("trajgen: interrupted: the servos hold their last goal", file=sys.stderr)
        return EXIT_INTERRUPTED


def _plan(args):
    """Everything that can fail on bad input, before any hardware is touched."""
    from trajgen.drivers.config import bus_config_from_tables
    from trajgen.drivers.units import JointMap
    from trajgen.keyframes import load_keyframe_file
    from trajgen.stream import plan_joint_trajectory

    # ``trajgen excite`` passes an already planned source (``cli.excite.ExcitationFile``).
    kf = args.file if hasattr(args.file, "spline") else load_keyframe_file(args.file)
    config = bus_config_from_tables(kf.tables, kf.path)
    joints = config.joints
    if args.virtual:
        if args.port:
            raise ValueError("--port and --virtual exclude each other")
        joints = JointMap(joints.ids)  # the simulated gimbal is assembled ideally
    elif args.plot:
        raise ValueError("--plot needs --virtual (it plots the simulated torque report)")
    elif not (args.port or config.port):
        raise ValueError("no serial port: give --port, set [bus] port, or use --virtual")
    if args.ids:
        joints = JointMap(args.ids, joints.directions, joints.zeros)
    if args.telemetry and not args.telemetry.endswith((".csv", ".npz")):
        raise ValueError(f"--telemetry: expected a .csv or .npz path, got {args.telemetry!r}")
    if args.telemetry and not Path(args.telemetry).resolve().parent.is_dir():
        raise ValueError(f"--telemetry: no such directory for {args.telemetry!r}")
    rate = args.rate or kf.rate_hz or 200.0
    trajectory = plan_joint_trajectory(kf.spline(), rate)
    return kf, config, joints, rate, trajectory


def _bring_up(bus, kf, config, joints, rate):
    """Check the servos, re-plan from their present position, configure them.

    Planning with ``start`` = the present joint angles puts pan and roll on the
    2 pi branch nearest to where the servos are, so the move to the first
    frame never unwinds a turn.
    """
    import numpy as np

    from trajgen.drivers.bringup import check_servos, configure, operating_mode_for
    from trajgen.drivers.control_table import Register
    from trajgen.stream import plan_joint_trajectory

    check_servos(bus, joints, config.models)
    ticks = np.array([bus.read(i, Register.PRESENT_POSITION) for i in joints.ids])
    trajectory = plan_joint_trajectory(kf.spline(), rate, start=joints.to_rad(ticks))
    mode = operating_mode_for(joints.to_ticks(trajectory.q))
    configure(bus, joints, operating_mode=mode, watchdog_s=config.watchdog_s)
    return trajectory


def _stream(args) -> int:
    from trajgen.drivers.clock import WALL_CLOCK, SimulatedClock
    from trajgen.drivers.errors import DriverError
    from trajgen.drivers.streamer import Streamer

    try:
        kf, config, joints, rate, trajectory = _plan(args)
    except (ValueError, TypeError, OSError) as e:  # KeyframeFileError, KinematicsError
        return bad_input(e)

    virtual = plant = None
    if args.virtual:
        try:
            virtual, plant = start_virtual(kf, config, joints, rate, trajectory.q[0])
        except (ValueError, TypeError) as e:
            return bad_input(e)
        port = virtual.port
    else:
        port = args.port or config.port

    streamer = None
    status = EXIT_OK
    try:
        try:
            bus = open_bus(port, args.baud or config.baud)
        except DriverError as e:
            return bad_input(e)
        try:
            trajectory = _bring_up(bus, kf, config, joints, rate)
            streamer = Streamer(
                bus,
                joints,
                telemetry=args.telemetry,
                on_stop="torque_off" if args.torque_off else "hold",
                # Lock-step: simulated time moves with the frames, so do not wait for them.
                clock=WALL_CLOCK if virtual is None else SimulatedClock(),
            )
            streamer.run(trajectory)
        except DriverError as e:
            print(f"trajgen: stream failed: {e}", file=sys.stderr)
            status = EXIT_FAILED
        except ValueError as e:  # re-planning from the present position (KinematicsError)
            return bad_input(e)
        finally:
            bus.close()
            if streamer is not None and streamer.stats is not None:
                print(streamer.stats.format())
                for message in streamer.stop_errors:
                    print(f"trajgen: warning: safe stop: {message}", file=sys.stderr)
    finally:
        if virtual is not None:
            virtual.stop()
            if virtual.error is not None:
                print(f"trajgen: virtual bus stopped: {virtual.error}", file=sys.stderr)
    if args.telemetry and streamer is not None:
        print(f"telemetry: {args.telemetry}")

    result = {"stream": None if streamer is None else streamer.stats.to_json_dict()}
    if plant is not None and status == EXIT_OK:
        status, _ = torque_report(plant, trajectory, args, result)
    return write_json(args, result, status)


def start_virtual(kf, config, joints, rate, first_q):
    """The simulated gimbal of the file's [gimbal] table, powered up at ``first_q``
    (rad, as a gimbal parked at the first frame would be), behind a virtual bus in
    lock-step with the stream; returns ``(virtual_bus, plant)``."""
    from trajgen.drivers.virtual.bus import VirtualBus
    from trajgen.sim.model import gimbal_config_from_tables
    from trajgen.sim.plant import GimbalPlant

    plant = GimbalPlant(gimbal_config_from_tables(kf.tables, kf.path), initial_rad=first_q)
    virtual = VirtualBus(
        plant,
        ids=joints.ids,
        models=config.models,
        lockstep_dt_s=1.0 / rate,
        # The servos power up with the gains the file states ([gimbal.<joint>]).
        registers=dict(zip(joints.ids, plant.initial_registers(), strict=True)),
    )
    return virtual.start(), plant


def torque_report(plant, trajectory, args, result: dict):
    """Print (and plot with --plot) the torque report of ``trajectory`` as streamed to
    ``plant``; add it to ``result``; return the exit status and the report (or None)."""
    from trajgen.sim.errors import SimError

    try:
        report = plant.report(trajectory)
    except SimError as e:
        print(f"trajgen: simulation failed: {e}", file=sys.stderr)
        return EXIT_FAILED, None
    print(report.format())
    result["torque"] = report.to_json_dict()
    status = EXIT_OK if report.ok else EXIT_FAILED
    if args.plot:
        from trajgen.sim.plot import plot_report

        try:
            print(f"plot: {plot_report(report, args.plot)}")
        except (OSError, ValueError) as e:
            return bad_input(e), report
    return status, report


def write_json(args, result: dict, status: int) -> int:
    """Write ``result`` to --json if given; return ``status`` (or bad input)."""
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8") as f:
                json.dump(result, f, indent=2)
        except OSError as e:
            return bad_input(e)
        print(f"json: {args.json}")
    return status
