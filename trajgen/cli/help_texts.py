"""The long ``--help`` descriptions of the commands that need more than a paragraph
(``stream``, ``sweep``, ``virtual-bus``), and what gives exit status 1 where several
commands share it; each command module passes its own to ``add_parser``."""

#: What gives exit status 1 (the stream and every command that streams).
STREAM_FAILED = "a stream fault, a refused bring-up, or (with --virtual) a failed torque check"

STREAM_DESCRIPTION = """\
Plan the joint stream of a keyframe file and stream it to Dynamixel X-series
servos at a fixed rate: bring-up (ping and model check; every servo checked
for a latched hardware error, its Drive Mode, position limits and present
position before any is changed; Return Delay 0, operating mode, no profile,
torque on, Bus Watchdog), a smooth move from the present position to the first
frame, then one sync write of Goal Position per frame with present position,
velocity and current read back. Prints the rate achieved, period jitter (p50,
p99, max), stalls and communication errors.

Safety: a plan that leaves a joint's installed position limits is refused
before torque on (limits are never widened; --set-limits is the only way to
write them; Drive Mode is never written); a joint farther than --max-approach
from the first frame is refused; after a host stall the rest of the stream is
shifted in time, never replayed faster, and the stream fails once it is more
than --max-delay behind its plan.

The file's [bus] table may set port, baud, ids, directions, zeros, models and
watchdog_s; flags override it. On any stop (end, fault, Ctrl-C, SIGTERM,
SIGHUP) the servos hold their last goal (--torque-off releases them); the
telemetry and --json report written so far are kept.

--virtual runs the same driver, SDK and serial layer against a virtual servo bus
on a pseudo-terminal, backed by the MuJoCo gimbal of `trajgen sim` (the file's
[gimbal] table; ideal assembly: direction +1, zero 2048), advancing one stream
period per frame received, and then prints the torque report.

Units: angles in degrees on the command line and in the file (joint degrees for
--set-limits and --max-approach), seconds for --max-delay."""

SWEEP_DESCRIPTION = """\
Run `trajgen sim`'s torque check on every combination of payload mass, payload
offset, servo model per joint and time scale, on MuJoCo batch threads (or on a
Dask cluster with --dask), and print pass/fail with the worst planned margin
(margin x envelope - |planned torque|, N m) per variant. Unset axes keep the file's
[gimbal] values; the time scale multiplies the keyframe times (0.5 = twice as fast).

examples:
  trajgen sweep shot.toml --payload-kg 0.1,0.3,0.6 --time-scale 0.5,1
  trajgen sweep shot.toml --servo pan=XM430-W350,XM540-W270 --offset-m 0.03,0,0 \\
      --offset-m 0.06,0,0.02 --plot sweep.png

The number of variants and the motion they simulate are printed before the
first one starts; more than --max-variants is refused before any work.

A failed variant is a row of the table, not a failure of the command."""

VIRTUAL_BUS_DESCRIPTION = """\
Serve the simulated gimbal of a keyframe file (its [gimbal] table; the built-in
one by default) as Dynamixel X-series servos on a pseudo-terminal, for
any Protocol 2.0 tool: the official dynamixel-sdk, LeRobot's motor bus, a ROS 2
hardware interface, your own scripts. Prints the port path as its first line,
then serves until SIGINT (Ctrl-C) or SIGTERM.

The servos start at rest at 0 rad (tick 2048) with torque off and their
factory registers, but for the position gains of the file's [gimbal.<joint>]
tables (the file's [bus] ids and models apply; any [gimbal] axes, 2 or 3
joints). --ids puts more servos on the chain (say 11,12,13,14,15,16 for an arm
with a gripper): those that are not the gimbal's joints idle as servos do,
answering, holding torque and following their goals in any Operating Mode they
accept (a gripper in Current-based Position, mode 5). Real time by default: the
simulation runs on the wall clock whether packets arrive or not. --lockstep
advances it only with the traffic: one period of the file's [stream] rate (200
Hz by default) per packet that writes Goal Position, and per poll of the present
values with no goal written since the previous one.

The gimbal's simulated servos run the firmware's position loop in Position and
Extended Position Mode with no profile. A write to them that asks for anything
else (another Operating Mode, a non-zero Profile Velocity or Acceleration) is
refused with Result Fail, and the reason is printed on stderr.

It serves until stopped, so a signal is how it ends: exit status 128 + the
signal number (130 Ctrl-C, 143 SIGTERM), as for every other command."""
