"""How long the simulated pan servo takes to stop, in clear_multi_turn's exact sequence.

ROBOTIS' ``clear_multi_turn.py`` example (DynamixelSDK, Protocol 2.0) puts
servo 1 in Extended Position Mode, spins it towards goal 1,048,575, and on a
key press writes Goal Position = the last Present Position it read, sleeps
0.3 s and sends CLEAR, which the firmware refuses (Result Fail) while the
servo moves: Moving (122) is 1 while |Present Velocity| > Moving Threshold
(24, 10 x 0.229 rpm by default).

Two traces of that stop:

1. through the wire: ``trajgen virtual-bus`` (real time, the built-in gimbal)
   driven by dynamixel-sdk with the example's packets, polling Moving ..
   Present Position (122..135) back to back after the stop, sending CLEAR 0.3 s
   after the stop as the example does, and printing what it answers;
2. the plant alone (``GimbalPlant``, 1 ms steps, no bus): the same stop at
   full speed, Present Velocity every millisecond, for the default servo
   model and, to show what decides it, other ages of the goal (how old the
   example's last read is) and other values of the reflected rotor inertia
   (armature), the viscous damping and the friction. These are a sensitivity
   study, not a fit: the defaults are not changed by it.

With ``--port`` trace 1 runs on a real servo instead (ID 1 alone on the bus,
a bare XM430-W350 as the example assumes, free to turn): the measurement
that decides whether the simulated stop is right. Torque goes off and the
Operating Mode is restored at the end, whatever happens.

Run: .venv/bin/python bench/stop_settle.py [--port /dev/ttyUSB0 [--baud 57600]]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from trajgen.drivers.units import VELOCITY_UNIT_RAD_S, rad_to_servo_ticks, servo_ticks_to_rad
from trajgen.servo_table import EXTENDED_POSITION_MODE
from trajgen.sim.model import GimbalConfig, JointParams
from trajgen.sim.plant import GimbalPlant
from trajgen.sim.servos import DEFAULT_SERVO

OPERATING_MODE, TORQUE, GOAL, MOVING, PRESENT_POSITION = 11, 64, 116, 122, 132
EXTENDED_POSITION, FAR_GOAL = EXTENDED_POSITION_MODE, 1_048_575
# Moving Threshold's factory value (x 0.229 rpm).
MOVING_THRESHOLD = DEFAULT_SERVO.spec.defaults["Moving Threshold"]
SPIN_S, CLEAR_AFTER_S, TRACE_S = 1.5, 0.3, 1.0


def _signed(value: int, bits: int) -> int:
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def through_the_wire(port_name: str | None, baud: int) -> None:
    """Trace 1: the example's packets against `trajgen virtual-bus`, or a real servo."""
    proc = None
    if port_name is None:
        trajgen = shutil.which("trajgen", path=os.path.dirname(sys.executable)) or "trajgen"
        proc = subprocess.Popen(
            [trajgen, "virtual-bus"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        port_name = proc.stdout.readline().strip()
    port = PortHandler(port_name)
    ph = PacketHandler(2.0)
    mode = None
    try:
        assert port.openPort() and port.setBaudRate(baud), f"cannot open {port_name}"
        mode, result, error = ph.read1ByteTxRx(port, 1, OPERATING_MODE)
        assert (result, error) == (COMM_SUCCESS, 0), "servo 1 does not answer"
        assert ph.write1ByteTxRx(port, 1, OPERATING_MODE, EXTENDED_POSITION) == (COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 1, TORQUE, 1) == (COMM_SUCCESS, 0)
        assert ph.write4ByteTxRx(port, 1, GOAL, FAR_GOAL) == (COMM_SUCCESS, 0)
        end = time.monotonic() + SPIN_S
        while time.monotonic() < end:  # the example's loop until the key press
            present, result, _ = ph.read4ByteTxRx(port, 1, PRESENT_POSITION)
        stop_s = time.monotonic()
        assert ph.write4ByteTxRx(port, 1, GOAL, present) == (COMM_SUCCESS, 0)
        rows, clear = [], None
        while (t := time.monotonic() - stop_s) < TRACE_S:
            if clear is None and t >= CLEAR_AFTER_S:
                clear = (t, *ph.clearMultiTurn(port, 1))
                continue
            data, result, error = ph.readTxRx(port, 1, MOVING, 14)
            if result != COMM_SUCCESS or error:
                continue
            velocity = _signed(int.from_bytes(bytes(data[6:10]), "little"), 32)
            position = _signed(int.from_bytes(bytes(data[10:14]), "little"), 32)
            rows.append((t, data[0], velocity, position - present))
    finally:  # torque off and the mode the servo had, whatever happened
        if port.is_open:
            ph.write1ByteTxRx(port, 1, TORQUE, 0)
            if mode is not None:
                ph.write1ByteTxRx(port, 1, OPERATING_MODE, mode)
            port.closePort()
        if proc is not None:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=10)
    where = "trajgen virtual-bus, real time" if proc is not None else port_name
    print(f"1. through the wire ({where}, dynamixel-sdk)")
    print(f"   stop written at goal = last Present Position read ({present})")
    print("   t after stop (ms)  Moving  Present Velocity  Present - goal (ticks)")
    shown = 0.0
    for t, moving, velocity, error in rows:
        if t >= shown:
            print(f"   {1e3 * t:8.0f}            {moving}     {velocity:6d}            {error:6d}")
            shown += 0.025
    last_moving = max((t for t, m, _, _ in rows if m), default=0.0)
    t, result, error = clear
    verdict = "accepted" if error == 0 else ph.getRxPacketError(error)
    print(f"   CLEAR sent at {1e3 * t:.0f} ms: {ph.getTxRxResult(result)}; {verdict}")
    print(f"   Moving last read 1 at {1e3 * last_moving:.0f} ms ({len(rows)} polls)")


def stop_trace(joint: JointParams, goal_age_ms: int = 1) -> np.ndarray:
    """Trace 2: Present Velocity (units) every ms after the stop, pan from full speed.

    The goal is where the pan was ``goal_age_ms`` before the stop, as the
    example's last Present Position read is that old when it writes it.
    """
    config = GimbalConfig()
    joints = (joint, *config.joints[1:])
    plant = GimbalPlant(dataclasses.replace(config, joints=joints), record=False)
    plant.set_control(0, {"Operating Mode": EXTENDED_POSITION})
    plant.set_torque_enabled(0, True)
    plant.set_goal([float(servo_ticks_to_rad(FAR_GOAL)), 0.0, 0.0])
    positions = []
    for _ in range(int(SPIN_S / 1e-3)):
        positions.append(plant.read()[0][0])
        plant.advance(1e-3)
    ticks = int(rad_to_servo_ticks(positions[-goal_age_ms]))  # a whole tick, as written
    plant.set_goal([float(servo_ticks_to_rad(ticks)), 0.0, 0.0])
    velocity = []
    for _ in range(int(TRACE_S / 1e-3)):
        plant.advance(1e-3)
        velocity.append(round(plant.read()[1][0] / VELOCITY_UNIT_RAD_S))
    return np.array(velocity)


def settled_ms(velocity: np.ndarray) -> float:
    """First time (ms) after which |Present Velocity| stays <= Moving Threshold."""
    moving = np.flatnonzero(np.abs(velocity) > MOVING_THRESHOLD)
    return float("nan") if moving.size == 0 else float(moving[-1] + 2)


def plant_alone() -> None:
    """Trace 2 and the sensitivity table."""
    base = JointParams.of(DEFAULT_SERVO)
    velocity = stop_trace(base)
    print()
    print("2. the plant alone (GimbalPlant, pan, 1 ms steps), default servo model")
    print(
        f"   armature {base.armature} kg m^2, damping {base.damping} N m s/rad, "
        f"frictionloss {base.frictionloss} N m, P {base.position_p_gain}"
    )
    print(f"   speed 1 ms after the stop (full speed): {abs(int(velocity[0]))} units")
    print("   t after stop (ms)  Present Velocity (0.229 rpm units)")
    for k in range(0, 600, 25):
        print(f"   {k + 1:8d}            {int(velocity[k]):6d}")
    print(
        f"   |velocity| <= {MOVING_THRESHOLD} for good from {settled_ms(velocity):.0f} ms; "
        f"at 300 ms: {int(velocity[299])}, max |v| in 300..350 ms: "
        f"{int(np.abs(velocity[299:350]).max())}"
    )
    print()
    print("   max |Present Velocity| from 300 ms on (units; CLEAR is refused above 10),")
    print("   by armature (kg m^2) and age of the goal (ms: how old the last read is):")
    ages = (1, 3, 5, 10)
    print("   armature " + "".join(f"{a:>6d} ms" for a in ages))
    for armature in (0.045, 0.04, 0.035, 0.03, 0.02, 0.01):
        joint = dataclasses.replace(base, armature=armature)
        late = [int(np.abs(stop_trace(joint, goal_age_ms=a)[299:]).max()) for a in ages]
        print(f"   {armature:8g} " + "".join(f"{v:9d}" for v in late))
    print()
    print("   one parameter changed at a time (goal 1 ms old, the others default):")
    print("   parameter      value    settled (ms)  max |v| from 300 ms")
    cases = [("armature", a) for a in (0.045, 0.03, 0.02, 0.01)]
    cases += [("damping", d) for d in (0.01, 0.1, 0.3)]
    cases += [("frictionloss", f) for f in (0.03, 0.1)]
    for name, value in cases:
        v = stop_trace(dataclasses.replace(base, **{name: value}))
        late = int(np.abs(v[299:]).max())
        print(f"   {name:13s} {value:6g}    {settled_ms(v):8.0f}      {late:8d}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--port",
        help="trace a real servo (ID 1, alone on the bus, free to spin) instead of the "
        "virtual bus; it turns about one turn and a half at full speed",
    )
    parser.add_argument("--baud", type=int, default=57_600, help="baud rate (57600 default)")
    args = parser.parse_args()
    load = os.getloadavg()
    through_the_wire(args.port, args.baud)
    if args.port is None:
        plant_alone()
    after = os.getloadavg()
    print(f"\nload average {load[0]:.2f} before, {after[0]:.2f} after")


if __name__ == "__main__":
    main()
