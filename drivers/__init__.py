"""Dynamixel X-series streaming on the official ``dynamixel-sdk``, and a virtual servo bus.

Modules: ``protocol`` (Protocol 2.0 packets), ``control_table`` (registers,
models), ``units`` (rad <-> ticks per joint), ``bus`` (the SDK wrapper),
``bringup`` (checks and configuration), ``streamer`` (the fixed-rate loop),
``session`` (a whole stream: open, bring up, stream, safe stop, outcome per
servo), ``signals`` (stop signals), ``telemetry``, ``config`` (the keyframe
file's [bus] table), ``virtual`` (the emulated bus).
Failures raise ``drivers.errors.DriverError`` subclasses.
"""
