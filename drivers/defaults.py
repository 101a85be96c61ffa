"""Driver defaults a keyframe file or a command-line flag may override.

Kept free of numpy and the SDK so the command line can show them in ``--help``
without loading the driver.
"""

#: Baud rate (bit/s) the driver opens the port at ([bus] baud, --baud). The
#: servos leave the factory at 57,600 (Baud Rate register value 1).
DEFAULT_BAUD = 1_000_000

#: Default bound (s) on how far the stream may fall behind its plan in total.
MAX_DELAY_S = 1.0
