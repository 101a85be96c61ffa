"""Dynamixel X-series streaming on the official ``dynamixel-sdk``, and a virtual servo bus.

Modules: ``protocol`` (Protocol 2.0 packets), ``control_table`` (registers,
models), ``units`` (rad <-> ticks per joint), ``bus`` (the SDK wrapper),
``bringup`` (checks, the changes it makes and restores), ``streamer`` (the
fixed-rate loop), ``health`` (voltage and temperature against the servo's
limits), ``outcome`` (each servo's state, read back after a stop),
``telemetry``, ``config`` (the keyframe file's [bus] table), ``session`` (a
whole run), ``virtual`` (the emulated bus: ``bus``, ``transport``,
``simulation``, ``handlers``, ``faults``).
Failures raise ``drivers.errors.DriverError`` subclasses.
"""
