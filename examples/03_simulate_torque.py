"""Simulate and check torque: a keyframe file on the MuJoCo gimbal, judged per joint.

The file's joint stream is sent, frame by frame and rounded to whole ticks as
Goal Position is, to simulated Dynamixel servos (their own position loop, the
file's [gimbal] masses and gains); the report compares the torque each joint
needed with the servo's 12 V torque-speed envelope and the tracking error with
its budget (the report lists each reason it fails). The built-in look-around
passes; ``examples/sim_too_fast.toml`` fails on purpose.

Run: .venv/bin/python examples/03_simulate_torque.py
     [--file examples/sim_too_fast.toml --expect-fail]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from trajgen import BUILTIN_EXAMPLE
from trajgen.sim import check_torque


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", type=Path, default=BUILTIN_EXAMPLE, help="default: built-in")
    parser.add_argument("--rate", type=float, help="stream rate (Hz); default the file's")
    parser.add_argument("--expect-fail", action="store_true", help="exit 0 when the check fails")
    options = parser.parse_args()

    report = check_torque(options.file, rate_hz=options.rate)
    print(report.format())
    return 0 if report.ok != options.expect_fail else 1


if __name__ == "__main__":
    raise SystemExit(main())
