"""Stream to servos with the library session: here a virtual bus around the simulated gimbal.

``Session`` runs what ``trajgen stream`` runs: open the port, bring the servos
up (every check before any servo is changed; the plan made again from where
the servos are), stream one sync write per frame with the present state read
back, and stop safely (hold, or torque off) however the stream ends. Given a
``plant`` instead of a port, it streams through the same driver, SDK and serial
layer to a virtual servo bus on a pseudo-terminal, in lock-step with a MuJoCo
gimbal. For real servos: ``Session(BusConfig(port="/dev/ttyUSB0"))`` and no plant.

Run: .venv/bin/python examples/04_stream_virtual.py [--file examples/raster.toml]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from trajgen import BUILTIN_EXAMPLE, load_keyframe_file, plan_joint_trajectory
from trajgen.drivers.config import bus_config_from_tables
from trajgen.drivers.session import Session
from trajgen.sim import GimbalPlant, gimbal_config_from_tables


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", type=Path, default=BUILTIN_EXAMPLE, help="default: built-in")
    options = parser.parse_args()

    keyframes = load_keyframe_file(options.file)
    rate_hz = keyframes.stream_rate()
    spline = keyframes.spline()
    bus = bus_config_from_tables(keyframes.tables, keyframes.path)  # ids, models, watchdog

    # The simulated gimbal powers up parked at the first frame, with the file's gains.
    first = plan_joint_trajectory(spline, rate_hz).q[0]
    gimbal = gimbal_config_from_tables(keyframes.tables, keyframes.path)
    plant = GimbalPlant(gimbal, initial_rad=first)

    session = Session(bus, plant=plant, plant_registers=plant.initial_registers(), on_stop="hold")
    outcome = session.stream_path(spline, rate_hz)
    print(outcome.stats.format())
    print(f"servos: {outcome.servo_states}  (stopped by: {outcome.stopped_by or 'the end'})")
    if not outcome.ok:
        return 1
    report = plant.report(outcome.trajectory)  # what the virtual servos did with the stream
    print(report.format())
    return 0 if report.ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
